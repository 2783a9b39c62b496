//! Entries several targets share: the backlash output modes a target applies as a step,
//! compensations a target cannot carry (simulated as omitted), the pitch-error table row,
//! the servo gains.

use super::Ctx;
use super::entry::{Put, with_unit};
use super::report::{Change, ErrFigures, Pending};
use crate::preset::comp::{
    BacklashParams, CrossTable, DirectionParams, Injection, OutputMode, QuadrantParams,
};
use crate::preset::{AccDecKind, AxisParams};

/// A direction's output mode as the report states it: "distance (N = 4, B = 500 µm)".
pub(crate) fn direction_text(d: &DirectionParams) -> String {
    match d.mode {
        OutputMode::Lump => "lump".into(),
        OutputMode::Distance => format!("distance (N = {}, B = {} µm)", d.parts_n, d.step_b_um),
        OutputMode::Time => format!("time (M = {} cycles)", d.cycles_m),
        OutputMode::Function => format!(
            "function of {:?} ({} points)",
            d.function_basis,
            d.function.len()
        )
        .to_lowercase(),
    }
}

/// The two direction fields of an axis's backlash compensation.
pub(crate) fn directions(b: &BacklashParams) -> [(&'static str, &DirectionParams); 2] {
    [
        ("plus_to_minus", &b.plus_to_minus),
        ("minus_to_plus", &b.minus_to_plus),
    ]
}

/// `axes.<name>.backlash.q_um` and its value.
pub(crate) fn backlash_q(a: &AxisParams) -> (String, String) {
    (
        format!("axes.{}.backlash.q_um", a.name),
        with_unit(a.backlash.q_um, "µm"),
    )
}

/// Backlash output modes the target applies as one step at the reversal.
pub(crate) fn backlash_modes_as_lump(ctx: &Ctx, i: usize, control: &str) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    let b = &a.backlash;
    if !b.enabled {
        return vec![];
    }
    let lump = BacklashParams {
        plus_to_minus: DirectionParams {
            mode: OutputMode::Lump,
            ..b.plus_to_minus.clone()
        },
        minus_to_plus: DirectionParams {
            mode: OutputMode::Lump,
            ..b.minus_to_plus.clone()
        },
        ..b.clone()
    };
    directions(b)
        .into_iter()
        .map(|(name, d)| {
            let field = format!("axes.{}.backlash.{name}.mode", a.name);
            if d.mode == OutputMode::Lump {
                Pending::mapped(field, direction_text(d)).note(format!(
                    "{control} outputs the backlash amount in one step at the reversal, as lump does (the amount's row says where it is written)"
                ))
            } else {
                Pending::not_representable(field, direction_text(d))
                    .note(format!("{control} has no per-direction spreading of the backlash correction; nearest: the whole amount at the reversal (lump, both directions)"))
                    .sim(
                        vec![Change::Backlash {
                            axis: i,
                            params: Some(lump.clone()),
                        }],
                        vec![i],
                        false,
                    )
            }
        })
        .collect()
}

/// The quadrant compensation's settings in one line.
pub(crate) fn quadrant_value(q: &QuadrantParams) -> String {
    let m0 = match q.inject {
        Injection::Torque => with_unit(q.m0_torque_nm, "N·m"),
        Injection::Velocity => with_unit(q.m0_vel_mm_per_s, "mm/s"),
        Injection::Position => with_unit(q.m0_pos_um, "µm"),
    };
    format!(
        "adaptive = {}, inject {}, M0 = {m0}, T0 = {}, P0 = {}",
        q.adaptive,
        format!("{:?}", q.inject).to_lowercase(),
        with_unit(q.t0_ms, "ms"),
        with_unit(q.p0_mm, "mm")
    )
}

/// A quadrant compensation the target cannot carry: omitted, and simulated without it.
pub(crate) fn quadrant_omitted(ctx: &Ctx, i: usize, why: &str) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    if !a.quadrant.enabled {
        return vec![];
    }
    vec![
        Pending::not_representable(
            format!("axes.{}.quadrant", a.name),
            quadrant_value(&a.quadrant),
        )
        .note(format!("{why}; nearest: none (omitted)"))
        .sim(
            vec![Change::Quadrant {
                axis: i,
                params: None,
            }],
            vec![i],
            false,
        ),
    ]
}

/// A thermal correction the target cannot carry as a model: omitted, simulated without it.
pub(crate) fn thermal_omitted(ctx: &Ctx, i: usize, why: &str) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    if !a.thermal.enabled {
        return vec![];
    }
    vec![
        Pending::not_representable(format!("axes.{}.thermal", a.name), thermal_value(a))
            .note(format!("{why}; nearest: none (omitted)"))
            .sim(
                vec![Change::Thermal {
                    axis: i,
                    frozen: false,
                }],
                vec![i],
                false,
            ),
    ]
}

/// The thermal correction's settings in one line.
pub(crate) fn thermal_value(a: &AxisParams) -> String {
    let t = &a.thermal;
    format!(
        "source {:?}, E = a + k·|F| with a = {}, k = {}, judgement {:?}, x₀ = {}, x_m = {}",
        t.source,
        t.a,
        with_unit(t.k_per_um, "/µm"),
        t.judgement,
        with_unit(t.fixed_end_mm, "mm"),
        with_unit(t.measure_pos_mm, "mm")
    )
}

/// Cross tables: the ones `keep` says the target carries are mapped by the caller; the rest
/// are reported omitted, each simulated with every other table as in the preset.
pub(crate) fn cross_omitted(ctx: &Ctx, keep: &[bool], why: &str) -> Vec<Pending> {
    ctx.preset
        .cross
        .iter()
        .enumerate()
        .filter(|(i, t)| t.enabled && !keep.get(*i).copied().unwrap_or(false))
        .map(|(i, t)| {
            let comp = super::axis_index(ctx.preset, &t.comp_axis);
            Pending::not_representable(format!("cross.{i}"), cross_value(t))
                .note(format!("{why}; nearest: none (omitted)"))
                .sim(
                    vec![Change::Cross {
                        tables: without(&ctx.preset.cross, i),
                    }],
                    vec![comp],
                    false,
                )
        })
        .collect()
}

/// The cross tables without table `i`.
pub(crate) fn without(tables: &[CrossTable], i: usize) -> Vec<CrossTable> {
    tables
        .iter()
        .enumerate()
        .filter(|(j, _)| *j != i)
        .map(|(_, t)| t.clone())
        .collect()
}

/// A cross table's settings in one line.
pub(crate) fn cross_value(t: &CrossTable) -> String {
    format!(
        "{} = f({}), {} points {}…{} mm",
        t.comp_axis,
        t.base_axis,
        t.points.len(),
        t.points.first().map_or(0.0, |p| p.0),
        t.points.last().map_or(0.0, |p| p.0)
    )
}

/// The lead error's settings in one line.
pub(crate) fn lead_error_value(a: &AxisParams) -> String {
    let l = &a.lead_error;
    format!(
        "amplitude {}, period {}, cumulative {}, table of {} points",
        with_unit(l.amplitude_um, "µm"),
        with_unit(l.period_mm, "mm"),
        with_unit(l.cumulative_um_per_m, "µm/m"),
        l.table.len()
    )
}

/// The pitch table entry: derived from the measured lead error, residual evaluated; the
/// caller gives the lines the table becomes.
pub(crate) fn pitch_entry(
    ctx: &Ctx,
    i: usize,
    table: &super::PitchTable,
    puts: Vec<Put>,
) -> Pending {
    let a = &ctx.preset.axes[i];
    let (lo, hi) = ctx.axes[i].travel_mm;
    let note = format!(
        "The measured lead error is a property of the screw, which axisbench's NC does not compensate; every control compensates it with a pitch-error table, so the export writes the table that cancels it (correction = −error) at {} points over the travel {lo}…{hi} mm{} (the scenario's travel and the measured table; outside it the end values are held)",
        table.points.len(),
        if table.equidistant {
            ", equidistant"
        } else {
            ""
        }
    );
    let exact = table.residual_um <= 1e-9;
    let field = format!("axes.{}.lead_error", a.name);
    let p = if exact {
        Pending::derived(field, lead_error_value(a))
    } else {
        Pending::approximated(field, lead_error_value(a))
    };
    p.note(note).puts(puts).evaluated(ErrFigures::evaluated(
        format!(
            "evaluated along {lo}…{hi} mm: lead error + table correction, linear interpolation between table points"
        ),
        table.residual_um,
    ))
}

/// Servo gains: the drive's, never in the NC data a compensation export writes.
pub(crate) fn servo_entries(ctx: &Ctx, i: usize, where_: &str) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    let s = &a.servo;
    vec![
        Pending::not_representable(
            format!("axes.{}.servo", a.name),
            format!(
                "Kp = {}, Kv = {}, Ki = {}, vff = {}, aff = {}",
                with_unit(s.kp_per_s, "/s"),
                with_unit(s.kv_n_s_per_m, "N·s/m"),
                with_unit(s.ki_per_s, "/s"),
                s.vff,
                s.aff
            ),
        )
        .note(format!(
            "the loop gains belong to {where_}, which this export does not write; they set the following-error limits derived above"
        )),
    ]
}

/// The acceleration limit of every axis: one entry for the acc/dec filter it comes from,
/// or one per axis from its torque limit when there is no filter. `puts(i)` gives the
/// lines axis `i`'s limit becomes; `rule` says how the target uses it.
pub(crate) fn acceleration_entries(
    ctx: &Ctx,
    rule: &str,
    puts: &dyn Fn(usize) -> Vec<Put>,
) -> Vec<Pending> {
    let p = ctx.preset;
    let ad = &p.nc.accdec;
    if ad.kind == AccDecKind::None {
        return p
            .axes
            .iter()
            .enumerate()
            .map(|(i, a)| {
                Pending::approximated(
                    format!("axes.{}.servo.torque_limit_nm", a.name),
                    with_unit(a.servo.torque_limit_nm, "N·m"),
                )
                .note(format!("{}. {rule}", ctx.axes[i].limits.acc_basis))
                .puts(puts(i))
            })
            .collect();
    }
    let basis = ctx
        .axes
        .first()
        .map(|d| d.limits.acc_basis.clone())
        .unwrap_or_default();
    vec![
        Pending::approximated(
            "nc.accdec",
            format!(
                "{}, τ1 = {}, τ2 = {}",
                format!("{:?}", ad.kind).to_lowercase(),
                with_unit(ad.tc1_s, "s"),
                with_unit(ad.tc2_s, "s")
            ),
        )
        .note(format!("{basis}. {rule}"))
        .puts((0..p.axes.len()).flat_map(puts)),
    ]
}
