//! Siemens SINUMERIK 840D sl: machine/setting data (`axisbench_md.ini`), the leadscrew
//! error compensation (`axisbench_eec.mpf`, `%_N_AX_EEC_INI`) and the sag/cross error
//! compensation tables (`axisbench_cec.mpf`, `%_N_NC_CEC_INI`) as part programs.
//!
//! Sources:
//! - SINUMERIK 840D sl Function Manual Extended Functions, K3 Compensations (6FC5397-1BP40-3BA1,
//!   03/2013), and the 808D/840D parameter manuals:
//!   - backlash: MD32450 $MA_BACKLASH[encoder] (mm, positive when the encoder leads the
//!     machine part; active after referencing, applied on reversal relative to it),
//!     MD32452 $MA_BACKLASH_FACTOR[parameter set] (0.01…100);
//!   - friction (quadrant error) compensation, K3 §4.6: MD32490 $MA_FRICT_COMP_MODE = 1
//!     (constant injection or adaptive characteristic), MD32500 $MA_FRICT_COMP_ENABLE,
//!     MD32510 $MA_FRICT_COMP_ADAPT_ENABLE, MD32520 $MA_FRICT_COMP_CONST_MAX (injection
//!     amplitude, mm/min), MD32540 $MA_FRICT_COMP_TIME (decay time constant, s), MD32550…
//!     MD32570 the acceleration points of the adaptation characteristic: the injection is a
//!     speed-setpoint pulse decaying exponentially, adapted to acceleration, not to stroke;
//!   - leadscrew error compensation, K3 §4.4.2: $AA_ENC_COMP[0,N,AXn], $AA_ENC_COMP_STEP,
//!     _MIN, _MAX, _IS_MODULO in `%_N_AX_EEC_INI`, MD38000 $MA_MM_ENC_COMP_MAX_POINTS,
//!     MD32700 $MA_ENC_COMP_ENABLE;
//!   - sag / cross error compensation (CEC), K3 §4.4.3–4.4.4: $AN_CEC[t,N],
//!     $AN_CEC_INPUT_AXIS[t], $AN_CEC_OUTPUT_AXIS[t], $AN_CEC_STEP[t], $AN_CEC_MIN[t],
//!     $AN_CEC_MAX[t], $AN_CEC_DIRECTION[t] (0 both, 1 only +, −1 only −: "position-
//!     dependent backlash compensation can be implemented using two tables"),
//!     $AN_CEC_MULT_BY_TABLE[t], $AN_CEC_IS_MODULO[t] in `%_N_NC_CEC_INI`; MD18342
//!     $MN_MM_CEC_MAX_POINTS[t], MD32710 $MA_CEC_ENABLE, SD41300 $SN_CEC_TABLE_ENABLE[t];
//!     tables are equidistant (STEP), values in mm;
//!   - temperature compensation, K3 §4.2: ΔK = SD43900 $SA_TEMP_COMP_ABS_VALUE +
//!     SD43910 $SA_TEMP_COMP_SLOPE·(P − SD43920 $SA_TEMP_COMP_REF_POSITION), enabled by
//!     MD32750 $MA_TEMP_COMP_TYPE (2 = position-dependent); the PLC or a synchronous
//!     action updates the setting data from temperatures, the control has no model;
//!   - MD32000 $MA_MAX_AX_VELO (mm/min), MD32300 $MA_MAX_AX_ACCEL (m/s²), MD32200
//!     $MA_POS_CTRLGAIN (servo gain factor Kv in (m/min)/mm = Kp·60/1000).
//!
//! Axis AXn is the preset's n-th axis (machine axis numbering from 1).

use super::entry::{FileSpec, Plan, Put, with_unit};
use super::report::{Change, ErrFigures, Pending};
use super::{Ctx, Violation, num, shared};
use crate::preset::comp::{Injection, PulseShape, QuadrantParams};
use crate::units::{
    kp_per_s_to_kv_m_per_min_per_mm, m_to_um, mm_per_s2_to_m_per_s2, ms_to_s, um_to_mm,
};

/// LEC and CEC tables hold at most this many points here (MD38000 / MD18342 are sized to
/// the table; this bound keeps the static user memory sensible: 8 bytes per point).
pub const MAX_POINTS: usize = 2000;

const MD: &str = "axisbench_md.ini";
const EEC: &str = "axisbench_eec.mpf";
const CEC: &str = "axisbench_cec.mpf";
/// The section of the machine data that enables the CEC tables.
const CEC_SECTION: &str = "; sag/cross error compensation";

/// The machine-data section of axis `i`.
fn md_sec(ctx: &Ctx, i: usize) -> String {
    format!("; axis '{}'", ctx.preset.axes[i].name)
}

/// A line `key=value` of the machine data, in axis `i`'s section.
fn md(ctx: &Ctx, i: usize, key: &str, value: impl Into<String>) -> Put {
    Put::new(MD, md_sec(ctx, i), format!("{key}="), value)
}

/// The export's one list and its files.
pub(crate) fn render(ctx: &Ctx) -> Result<Plan, Vec<Violation>> {
    let p = ctx.preset;
    let files = vec![
        FileSpec::new(
            MD,
            format!(
                "; SINUMERIK 840D sl machine and setting data exported by axisbench from preset '{}'\n\
                 ; AXn = the preset's n-th axis; lengths in mm. See mapping_report.md.\n\
                 %_N_AXISBENCH_MD_INI\nCHANDATA(1)\n",
                p.name
            ),
            "M17\n",
        )
        .always(),
        FileSpec::new(
            EEC,
            "; leadscrew error compensation exported by axisbench\n%_N_AX_EEC_INI\nCHANDATA(1)\n",
            "M17\n",
        ),
        FileSpec::new(
            CEC,
            "; sag/cross error compensation exported by axisbench\n%_N_NC_CEC_INI\nCHANDATA(1)\n",
            "M17\n",
        ),
    ];
    let mut violations = Vec::new();
    let mut entries = limit_entries(ctx);
    for i in 0..p.axes.len() {
        entries.extend(backlash_entries(ctx, i));
        match lec_entry(ctx, i) {
            Ok(e) => entries.extend(e),
            Err(v) => violations.push(v),
        }
        entries.extend(quadrant_entries(ctx, i));
        entries.extend(thermal_entries(ctx, i));
        entries.extend(shared::servo_entries(
            ctx,
            i,
            "the SINAMICS drive (speed controller)",
        ));
    }
    let (cec, bad) = cec_entries(ctx);
    entries.extend(cec);
    violations.extend(bad);
    if violations.is_empty() {
        Ok(Plan { files, entries })
    } else {
        Err(violations)
    }
}

/// MD32000 (rapid), MD32300 (acceleration), MD32200 (position-loop gain) of every axis.
fn limit_entries(ctx: &Ctx) -> Vec<Pending> {
    let p = ctx.preset;
    let ax = |i: usize| format!("AX{}", i + 1);
    let mut out = vec![
        Pending::derived(
            "nc.rapid_mm_per_min",
            with_unit(p.nc.rapid_mm_per_min, "mm/min"),
        )
        .note("MD32000 $MA_MAX_AX_VELO: the rapid traverse, mm/min, every axis")
        .puts((0..p.axes.len()).map(|i| {
            md(
                ctx,
                i,
                &format!("$MA_MAX_AX_VELO[{}]", ax(i)),
                num(ctx.axes[i].limits.max_vel_mm_s * 60.0),
            )
        })),
    ];
    out.extend(shared::acceleration_entries(
        ctx,
        "MD32300 $MA_MAX_AX_ACCEL in m/s²; the NC plans with this acceleration (jerk limitation separately); the moving-average filter is not representable. Not simulated: the trajectory is the NC's own",
        &|i| {
            vec![md(
                ctx,
                i,
                &format!("$MA_MAX_AX_ACCEL[{}]", ax(i)),
                num(mm_per_s2_to_m_per_s2(ctx.axes[i].limits.max_acc_mm_s2)),
            )]
        },
    ));
    for (i, a) in p.axes.iter().enumerate() {
        out.push(
            Pending::derived(
                format!("axes.{}.servo.kp_per_s", a.name),
                with_unit(a.servo.kp_per_s, "/s"),
            )
            .note("MD32200: Kv factor in (m/min)/mm = Kp·60/1000; velocity-loop gains are drive (SINAMICS) parameters, not written")
            .put(md(
                ctx,
                i,
                &format!("$MA_POS_CTRLGAIN[0,{}]", ax(i)),
                num(kp_per_s_to_kv_m_per_min_per_mm(a.servo.kp_per_s)),
            )),
        );
    }
    out
}

/// MD32450/32452 backlash, or 0 when the axis has none.
fn backlash_entries(ctx: &Ctx, i: usize) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    let ax = format!("AX{}", i + 1);
    if !a.backlash.enabled {
        return vec![
            Pending::mapped(format!("axes.{}.backlash.enabled", a.name), "false")
                .note("no backlash compensation")
                .put(md(ctx, i, &format!("$MA_BACKLASH[0,{ax}]"), "0")),
        ];
    }
    let (field, value) = shared::backlash_q(a);
    let mut out = vec![
        Pending::mapped(field, value)
            .note("MD32450 (mm) with MD32452 factor 1; applied on reversal relative to the referencing direction, as axisbench keeps the first direction at 0")
            .puts([
                md(ctx, i, &format!("$MA_BACKLASH[0,{ax}]"), num(um_to_mm(a.backlash.q_um))),
                md(ctx, i, &format!("$MA_BACKLASH_FACTOR[0,{ax}]"), "1"),
            ]),
    ];
    out.extend(shared::backlash_modes_as_lump(ctx, i, "SINUMERIK"));
    out
}

/// The leadscrew error compensation table (`$AA_ENC_COMP`, equidistant) and its machine
/// data, or the violation when a measured table is too long.
fn lec_entry(ctx: &Ctx, i: usize) -> Result<Option<Pending>, Violation> {
    let a = &ctx.preset.axes[i];
    if !a.lead_error.enabled {
        return Ok(None);
    }
    if a.lead_error.amplitude_um == 0.0 && a.lead_error.table.len() > MAX_POINTS {
        return Err(Violation::new(
            format!("axes.{}.lead_error.table", a.name),
            format!(
                "{} points; an LEC table here holds at most {MAX_POINTS}",
                a.lead_error.table.len()
            ),
        ));
    }
    let ax = format!("AX{}", i + 1);
    let pt = super::pitch_table(&a.lead_error, ctx.axes[i].travel_mm, MAX_POINTS, true);
    let (Some(first), Some(last)) = (pt.points.first(), pt.points.last()) else {
        return Ok(None);
    };
    let step = pt.points.get(1).map_or(1.0, |p1| p1.0 - first.0);
    let sec = format!(
        "; axis '{}': leadscrew error compensation, {} points",
        a.name,
        pt.points.len()
    );
    let eec = |key: String, v: String| Put::new(EEC, sec.clone(), format!("{key}="), v);
    let mut puts: Vec<Put> = pt
        .points
        .iter()
        .enumerate()
        .map(|(n, (_, c))| eec(format!("$AA_ENC_COMP[0,{n},{ax}]"), num(um_to_mm(*c))))
        .collect();
    puts.extend([
        eec(format!("$AA_ENC_COMP_STEP[0,{ax}]"), num(step)),
        eec(format!("$AA_ENC_COMP_MIN[0,{ax}]"), num(first.0)),
        eec(format!("$AA_ENC_COMP_MAX[0,{ax}]"), num(last.0)),
        eec(format!("$AA_ENC_COMP_IS_MODULO[0,{ax}]"), "0".into()),
        md(
            ctx,
            i,
            &format!("$MA_MM_ENC_COMP_MAX_POINTS[0,{ax}]"),
            pt.points.len().to_string(),
        ),
        md(ctx, i, &format!("$MA_ENC_COMP_ENABLE[0,{ax}]"), "1"),
    ]);
    let mut e = shared::pitch_entry(ctx, i, &pt, puts);
    e.entry.note += "; K3 §4.4.2 leadscrew error compensation, values in mm, MD38000 sized to the table, MD32700 = 1";
    Ok(Some(e))
}

/// MD32490–32540 friction compensation for a velocity injection; other injections are
/// omitted (simulated without).
fn quadrant_entries(ctx: &Ctx, i: usize) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    let q = &a.quadrant;
    if !q.enabled {
        return vec![];
    }
    if q.inject != Injection::Velocity {
        return shared::quadrant_omitted(
            ctx,
            i,
            "SINUMERIK's friction compensation injects into the speed setpoint (MD32520 in mm/min); a torque or position pulse has no such parameter",
        );
    }
    let ax = format!("AX{}", i + 1);
    let puts = vec![
        md(ctx, i, &format!("$MA_FRICT_COMP_MODE[{ax}]"), "1"),
        md(ctx, i, &format!("$MA_FRICT_COMP_ENABLE[0,{ax}]"), "1"),
        md(ctx, i, &format!("$MA_FRICT_COMP_ADAPT_ENABLE[0,{ax}]"), "0"),
        md(
            ctx,
            i,
            &format!("$MA_FRICT_COMP_CONST_MAX[0,{ax}]"),
            num(q.m0_vel_mm_per_s * 60.0),
        ),
        md(
            ctx,
            i,
            &format!("$MA_FRICT_COMP_TIME[0,{ax}]"),
            num(ms_to_s(q.t0_ms)),
        ),
    ];
    let field = format!("axes.{}.quadrant", a.name);
    let value = shared::quadrant_value(q);
    if !q.adaptive && q.shape == PulseShape::Exponential {
        return vec![
            Pending::mapped(field, value)
                .note("MD32490 = 1, MD32500 = 1, MD32510 = 0, MD32520 (mm/min), MD32540 (s): a speed-setpoint pulse decaying with T0, constant amplitude")
                .puts(puts),
        ];
    }
    let siemens = QuadrantParams {
        adaptive: false,
        shape: PulseShape::Exponential,
        ..q.clone()
    };
    vec![
        Pending::approximated(field, value)
            .note("SINUMERIK injects a speed pulse decaying exponentially, with a fixed amplitude or one adapted to the acceleration at the reversal (MD32550–32570), not to the stroke length; nearest: M0 and T0 fixed (adaptation off), exponential")
            .puts(puts)
            .sim(
                vec![Change::Quadrant {
                    axis: i,
                    params: Some(siemens),
                }],
                vec![i],
                false,
            ),
    ]
}

/// SD43900/43910/43920 + MD32750: the preset's thermal correction frozen at the end of the
/// report's baseline run (the control has no model; the PLC updates the setting data).
fn thermal_entries(ctx: &Ctx, i: usize) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    if !a.thermal.enabled {
        return vec![];
    }
    let t = &a.thermal;
    let ax = format!("AX{}", i + 1);
    let lever_mm = t.measure_pos_mm - t.fixed_end_mm;
    // F' (µm) at the end of the baseline run, or 0 before any simulation.
    let end_um = m_to_um(ctx.thermal_end_m.get(i).copied().flatten().unwrap_or(0.0));
    let slope = um_to_mm(-end_um) / lever_mm;
    vec![
        Pending::not_representable(format!("axes.{}.thermal", a.name), shared::thermal_value(a))
            .note(format!(
                "SINUMERIK has no thermal model: SD43900/SD43910/SD43920 hold the correction K0 + tanβ·(P − P0), which the PLC must update from the model. Written: MD32750 = 2, SD43900 = 0, SD43910 $SA_TEMP_COMP_SLOPE = {} (the preset's correction at the end of the simulation, frozen), SD43920 = {} mm. Nearest approximation simulated: that slope held constant",
                num(slope),
                num(t.fixed_end_mm)
            ))
            .puts([
                md(ctx, i, &format!("$MA_TEMP_COMP_TYPE[{ax}]"), "2"),
                md(ctx, i, &format!("$SA_TEMP_COMP_ABS_VALUE[{ax}]"), "0"),
                md(ctx, i, &format!("$SA_TEMP_COMP_SLOPE[{ax}]"), num(slope)),
                md(ctx, i, &format!("$SA_TEMP_COMP_REF_POSITION[{ax}]"), num(t.fixed_end_mm)),
            ])
            .sim(
                vec![Change::Thermal {
                    axis: i,
                    frozen: true,
                }],
                vec![i],
                false,
            ),
    ]
}

/// The CEC tables (one per enabled cross table, equidistant) and their machine data.
fn cec_entries(ctx: &Ctx) -> (Vec<Pending>, Vec<Violation>) {
    let p = ctx.preset;
    let mut out = Vec::new();
    let mut bad = Vec::new();
    let mut t = 0usize;
    for (ci, table) in p.cross.iter().enumerate() {
        if !table.enabled {
            continue;
        }
        if table.points.len() > MAX_POINTS {
            bad.push(Violation::new(
                format!("cross.{ci}.points"),
                format!(
                    "{} points; a CEC table here holds at most {MAX_POINTS}",
                    table.points.len()
                ),
            ));
            continue;
        }
        if let Some(e) = cec_entry(ctx, ci, t) {
            out.push(e);
            t += 1;
        }
    }
    (out, bad)
}

/// Cross table `ci` as CEC table `t`; None for an empty table (the preset validation
/// reports it).
fn cec_entry(ctx: &Ctx, ci: usize, t: usize) -> Option<Pending> {
    let p = ctx.preset;
    let table = &p.cross[ci];
    let inp = super::axis_index(p, &table.base_axis) + 1;
    let out = super::axis_index(p, &table.comp_axis) + 1;
    let (pts, step, resid_um) = super::equidistant(&table.points, MAX_POINTS);
    let (first, last) = (pts.first()?, pts.last()?);
    let sec = format!(
        "; cross[{ci}]: {} = f({})",
        table.comp_axis, table.base_axis
    );
    let cec = |key: String, v: String| Put::new(CEC, sec.clone(), format!("{key}="), v);
    let mdl = |key: String, v: String| Put::new(MD, CEC_SECTION, format!("{key}="), v);
    let mut puts: Vec<Put> = pts
        .iter()
        .enumerate()
        .map(|(n, (_, v))| cec(format!("$AN_CEC[{t},{n}]"), num(um_to_mm(*v))))
        .collect();
    puts.extend([
        cec(format!("$AN_CEC_INPUT_AXIS[{t}]"), format!("(AX{inp})")),
        cec(format!("$AN_CEC_OUTPUT_AXIS[{t}]"), format!("(AX{out})")),
        cec(format!("$AN_CEC_STEP[{t}]"), num(step)),
        cec(format!("$AN_CEC_MIN[{t}]"), num(first.0)),
        cec(format!("$AN_CEC_MAX[{t}]"), num(last.0)),
        cec(format!("$AN_CEC_DIRECTION[{t}]"), "0".into()),
        cec(format!("$AN_CEC_MULT_BY_TABLE[{t}]"), "0".into()),
        cec(format!("$AN_CEC_IS_MODULO[{t}]"), "0".into()),
        mdl(format!("$MN_MM_CEC_MAX_POINTS[{t}]"), pts.len().to_string()),
        mdl(format!("$MA_CEC_ENABLE[AX{out}]"), "1".into()),
        mdl(format!("$SN_CEC_TABLE_ENABLE[{t}]"), "1".into()),
    ]);
    let field = format!("cross.{ci}");
    let value = shared::cross_value(table);
    Some(if resid_um == 0.0 {
        Pending::mapped(field, value)
            .note("CEC table (K3 §4.4.3): equidistant already; values µm → mm; ends held as in axisbench; MD18342, MD32710 = 1, SD41300 = 1")
            .puts(puts)
    } else {
        Pending::approximated(field, value)
            .note("CEC tables are equidistant: resampled at the smallest spacing; MD18342, MD32710 = 1, SD41300 = 1")
            .puts(puts)
            .evaluated(ErrFigures::evaluated(
                "evaluated along the table: original vs resampled interpolation",
                resid_um,
            ))
    })
}
