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

use super::report::{self, Change, ErrFigures, Pending};
use super::{Ctx, Rendered, Violation, num};
use crate::comp::quadrant::{Injection, PulseShape, QuadrantParams};

/// LEC and CEC tables hold at most this many points here (MD38000 / MD18342 are sized to
/// the table; this bound keeps the static user memory sensible: 8 bytes per point).
pub const MAX_POINTS: usize = 2000;

pub(crate) fn render(ctx: &Ctx) -> Result<Rendered, Vec<Violation>> {
    let p = ctx.preset;
    let mut violations = Vec::new();
    let mut md = format!(
        "; SINUMERIK 840D sl machine and setting data exported by axisbench from preset '{}'\n\
         ; AXn = the preset's n-th axis; lengths in mm. See mapping_report.md.\n\
         %_N_AXISBENCH_MD_INI\nCHANDATA(1)\n",
        p.name
    );
    let mut eec = String::new();
    let mut cec_tables: Vec<String> = Vec::new();
    let mut entries: Vec<Pending> = Vec::new();
    for (i, a) in p.axes.iter().enumerate() {
        let ax = format!("AX{}", i + 1);
        let lim = &ctx.axes[i].limits;
        md += &format!("; axis '{}'\n", a.name);
        md += &format!("$MA_MAX_AX_VELO[{ax}]={}\n", num(lim.max_vel_mm_s * 60.0));
        md += &format!("$MA_MAX_AX_ACCEL[{ax}]={}\n", num(lim.max_acc_mm_s2 * 1e-3));
        md += &format!(
            "$MA_POS_CTRLGAIN[0,{ax}]={}\n",
            num(a.servo.kp_per_s * 0.06)
        );
        entries.push(Pending::derived(
            format!(
                "nc.rapid_mm_per_min = {} (axis {})",
                p.nc.rapid_mm_per_min, a.name
            ),
            format!(
                "MD32000 $MA_MAX_AX_VELO[{ax}] = {}",
                num(lim.max_vel_mm_s * 60.0)
            ),
            "the rapid traverse, mm/min",
        ));
        entries.push(Pending::approximated(
            format!(
                "nc.accdec = {:?}, τ1 = {} s, τ2 = {} s (axis {})",
                p.nc.accdec.kind, p.nc.accdec.tc1_s, p.nc.accdec.tc2_s, a.name
            ),
            format!("MD32300 $MA_MAX_AX_ACCEL[{ax}] = {} m/s²", num(lim.max_acc_mm_s2 * 1e-3)),
            &format!("{}; the NC plans with this acceleration (jerk limitation separately); the moving-average filter is not representable. Not simulated: the trajectory is the NC's own", lim.acc_basis),
        ));
        entries.push(Pending::derived(
            format!("axes[{}].servo.kp_per_s = {}", a.name, a.servo.kp_per_s),
            format!("MD32200 $MA_POS_CTRLGAIN[0,{ax}] = {}", num(a.servo.kp_per_s * 0.06)),
            "Kv factor in (m/min)/mm = Kp·60/1000; velocity-loop gains are drive (SINAMICS) parameters, not written",
        ));
        // ---- backlash ----
        if a.backlash.enabled {
            let q = a.backlash.q_um / 1000.0;
            md += &format!(
                "$MA_BACKLASH[0,{ax}]={}\n$MA_BACKLASH_FACTOR[0,{ax}]=1\n",
                num(q)
            );
            entries.push(Pending::mapped(
                format!("axes[{}].backlash.q_um = {}", a.name, a.backlash.q_um),
                format!("MD32450 $MA_BACKLASH[0,{ax}] = {} mm, MD32452 $MA_BACKLASH_FACTOR[0,{ax}] = 1", num(q)),
                "applied on reversal relative to the referencing direction, as axisbench keeps the first direction at 0",
            ));
            entries.extend(report::backlash_modes_as_lump(ctx, i, "SINUMERIK"));
        } else {
            md += &format!("$MA_BACKLASH[0,{ax}]=0\n");
        }
        // ---- leadscrew error compensation ----
        if a.lead_error.enabled {
            if a.lead_error.amplitude_um == 0.0 && a.lead_error.table.len() > MAX_POINTS {
                violations.push(Violation::new(
                    format!("axes[{}].lead_error.table", a.name),
                    format!(
                        "{} points; an LEC table here holds at most {MAX_POINTS}",
                        a.lead_error.table.len()
                    ),
                ));
            }
            let pt = super::pitch_table(&a.lead_error, ctx.axes[i].travel_mm, MAX_POINTS, true);
            let step = if pt.points.len() > 1 {
                pt.points[1].0 - pt.points[0].0
            } else {
                1.0
            };
            eec += &format!(
                "; axis '{}': leadscrew error compensation, {} points\n",
                a.name,
                pt.points.len()
            );
            for (n, (_, c)) in pt.points.iter().enumerate() {
                eec += &format!("$AA_ENC_COMP[0,{n},{ax}]={}\n", num(c / 1000.0));
            }
            let (lo, hi) = (pt.points[0].0, pt.points[pt.points.len() - 1].0);
            eec += &format!(
                "$AA_ENC_COMP_STEP[0,{ax}]={}\n$AA_ENC_COMP_MIN[0,{ax}]={}\n$AA_ENC_COMP_MAX[0,{ax}]={}\n$AA_ENC_COMP_IS_MODULO[0,{ax}]=0\n",
                num(step),
                num(lo),
                num(hi)
            );
            md += &format!(
                "$MA_MM_ENC_COMP_MAX_POINTS[0,{ax}]={}\n$MA_ENC_COMP_ENABLE[0,{ax}]=1\n",
                pt.points.len()
            );
            entries.push(report::pitch_entry(
                ctx,
                i,
                &pt,
                format!("axisbench_eec.mpf: $AA_ENC_COMP[0,0…{},{ax}], STEP {} mm; MD38000 = {}, MD32700 = 1", pt.points.len() - 1, num(step), pt.points.len()),
            ));
        }
        // ---- friction (quadrant) compensation ----
        let q = &a.quadrant;
        if q.enabled {
            if q.inject == Injection::Velocity {
                let max_mm_min = q.m0_vel_mm_per_s * 60.0;
                md += &format!(
                    "$MA_FRICT_COMP_MODE[{ax}]=1\n$MA_FRICT_COMP_ENABLE[0,{ax}]=1\n$MA_FRICT_COMP_ADAPT_ENABLE[0,{ax}]=0\n$MA_FRICT_COMP_CONST_MAX[0,{ax}]={}\n$MA_FRICT_COMP_TIME[0,{ax}]={}\n",
                    num(max_mm_min),
                    num(q.t0_ms * 1e-3)
                );
                let siemens = QuadrantParams {
                    adaptive: false,
                    shape: PulseShape::Exponential,
                    ..q.clone()
                };
                let exact = !q.adaptive && q.shape == PulseShape::Exponential;
                let target = format!(
                    "MD32490 = 1, MD32500 = 1, MD32510 = 0, MD32520 $MA_FRICT_COMP_CONST_MAX = {} mm/min, MD32540 $MA_FRICT_COMP_TIME = {} s",
                    num(max_mm_min),
                    num(q.t0_ms * 1e-3)
                );
                let setting = format!(
                    "axes[{}].quadrant (velocity injection M0 = {} mm/s, T0 = {} ms, {:?}, adaptive = {})",
                    a.name, q.m0_vel_mm_per_s, q.t0_ms, q.shape, q.adaptive
                );
                entries.push(if exact {
                    Pending::mapped(setting, target, "a speed-setpoint pulse decaying with T0, constant amplitude")
                } else {
                    Pending::approximated(
                        setting,
                        target,
                        "SINUMERIK injects a speed pulse decaying exponentially, with a fixed amplitude or one adapted to the acceleration at the reversal (MD32550–32570), not to the stroke length; nearest: M0 and T0 fixed (adaptation off), exponential",
                    )
                    .sim(vec![Change::Quadrant { axis: i, params: Some(siemens) }], vec![i], false)
                });
            } else {
                entries.extend(report::quadrant_omitted(
                    ctx,
                    i,
                    "SINUMERIK's friction compensation injects into the speed setpoint (MD32520 in mm/min); a torque or position pulse has no such parameter",
                ));
            }
        }
        // ---- thermal ----
        if a.thermal.enabled {
            let t = &a.thermal;
            let lever_mm = t.measure_pos_mm - t.fixed_end_mm;
            let end_um = ctx_thermal_end(ctx, i);
            let slope = -end_um * 1e-3 / lever_mm;
            md += &format!(
                "$MA_TEMP_COMP_TYPE[{ax}]=2\n$SA_TEMP_COMP_ABS_VALUE[{ax}]=0\n$SA_TEMP_COMP_SLOPE[{ax}]={}\n$SA_TEMP_COMP_REF_POSITION[{ax}]={}\n",
                num(slope),
                num(t.fixed_end_mm)
            );
            entries.push(
                Pending::not_representable(
                    report::thermal_setting(a),
                    &format!(
                        "SINUMERIK has no thermal model: SD43900/SD43910/SD43920 hold the correction K0 + tanβ·(P − P0), which the PLC must update from the model. Written: MD32750 = 2, SD43900 = 0, SD43910 $SA_TEMP_COMP_SLOPE = {} (the preset's correction at the end of the simulation, frozen), SD43920 = {} mm. Nearest approximation simulated: that slope held constant",
                        num(slope),
                        num(t.fixed_end_mm)
                    ),
                )
                .sim(vec![Change::Thermal { axis: i, frozen: true }], vec![i], false),
            );
        }
        entries.extend(report::servo_entries(
            ctx,
            i,
            "the SINAMICS drive (speed controller)",
        ));
    }
    // ---- CEC tables ----
    let mut t = 0usize;
    for (ci, table) in p.cross.iter().enumerate() {
        if !table.enabled {
            continue;
        }
        let inp = super::axis_index(p, &table.base_axis) + 1;
        let out = super::axis_index(p, &table.comp_axis) + 1;
        if table.points.len() > MAX_POINTS {
            violations.push(Violation::new(
                format!("cross[{ci}].points"),
                format!(
                    "{} points; a CEC table here holds at most {MAX_POINTS}",
                    table.points.len()
                ),
            ));
            continue;
        }
        let (pts, step, resid_um) = super::equidistant(&table.points, MAX_POINTS);
        if pts.is_empty() {
            continue; // an empty table is reported by the preset validation
        }
        let mut s = format!(
            "; cross[{ci}]: {} = f({})\n",
            table.comp_axis, table.base_axis
        );
        for (n, (_, v)) in pts.iter().enumerate() {
            s += &format!("$AN_CEC[{t},{n}]={}\n", num(v / 1000.0));
        }
        let (lo, hi) = (pts[0].0, pts[pts.len() - 1].0);
        s += &format!(
            "$AN_CEC_INPUT_AXIS[{t}]=(AX{inp})\n$AN_CEC_OUTPUT_AXIS[{t}]=(AX{out})\n$AN_CEC_STEP[{t}]={}\n$AN_CEC_MIN[{t}]={}\n$AN_CEC_MAX[{t}]={}\n$AN_CEC_DIRECTION[{t}]=0\n$AN_CEC_MULT_BY_TABLE[{t}]=0\n$AN_CEC_IS_MODULO[{t}]=0\n",
            num(step),
            num(lo),
            num(hi)
        );
        cec_tables.push(s);
        md += &format!(
            "$MN_MM_CEC_MAX_POINTS[{t}]={}\n$MA_CEC_ENABLE[AX{out}]=1\n$SN_CEC_TABLE_ENABLE[{t}]=1\n",
            pts.len()
        );
        let target = format!(
            "axisbench_cec.mpf table {t}: $AN_CEC[{t},0…{}], INPUT (AX{inp}), OUTPUT (AX{out}), STEP {} mm, {}…{} mm; MD18342[{t}] = {}, MD32710 = 1, SD41300[{t}] = 1",
            pts.len() - 1,
            num(step),
            num(lo),
            num(hi),
            pts.len()
        );
        let setting = report::cross_setting(ci, table);
        if resid_um == 0.0 {
            entries.push(Pending::mapped(
                setting,
                target,
                "equidistant already; values µm → mm; ends held as in axisbench",
            ));
        } else {
            entries.push(
                Pending::approximated(
                    setting,
                    target,
                    "CEC tables are equidistant: resampled at the smallest spacing",
                )
                .evaluated(ErrFigures {
                    method: "evaluated along the table: original vs resampled interpolation".into(),
                    correction_max_um: resid_um,
                    correction_rms_um: None,
                    position_error_max_um: None,
                    constant_offset_um: 0.0,
                }),
            );
        }
        t += 1;
    }
    md += "M17\n";
    let mut files = vec![("axisbench_md.ini".to_owned(), md)];
    if !eec.is_empty() {
        files.push((
            "axisbench_eec.mpf".into(),
            format!("; leadscrew error compensation exported by axisbench\n%_N_AX_EEC_INI\nCHANDATA(1)\n{eec}M17\n"),
        ));
    }
    if !cec_tables.is_empty() {
        files.push((
            "axisbench_cec.mpf".into(),
            format!(
                "; sag/cross error compensation exported by axisbench\n%_N_NC_CEC_INI\nCHANDATA(1)\n{}M17\n",
                cec_tables.concat()
            ),
        ));
    }
    if violations.is_empty() {
        Ok(Rendered { files, entries })
    } else {
        Err(violations)
    }
}

/// F' (µm) of the axis's thermal correction at the end of the report's baseline run, or 0
/// before any simulation (the violations-only pass).
fn ctx_thermal_end(ctx: &Ctx, i: usize) -> f64 {
    ctx.thermal_end_m.get(i).copied().flatten().unwrap_or(0.0) * 1e6
}
