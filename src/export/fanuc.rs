//! FANUC Series 0i/30i: a parameter list (`fanuc_parameters.txt`, one `N<no> A<axis>
//! P<value>` line per axis-type parameter) and the pitch error compensation data.
//!
//! Sources:
//! - FANUC parameter manuals (Series 0i/0i Mate-C B-64120EN, Series 21i B-63090EN, Series
//!   30i B-64490EN): No. 1851 "backlash compensating value for each axis" (detection unit,
//!   −9999…9999; the first compensation is made when the machine first moves opposite to
//!   the reference position return direction after power-on), No. 1852 "backlash
//!   compensating value used for rapid traverse" (valid when No. 1800#4 RBK = 1), No. 1420
//!   rapid traverse rate (mm/min), No. 1620 linear acc/dec time constant for rapid traverse
//!   (ms), No. 1825 servo loop gain (0.01/s).
//! - Pitch error compensation: No. 3620 number of the compensation point of the reference
//!   position, No. 3621 / 3622 numbers of the most negative / positive points, No. 3623
//!   magnification, No. 3624 interval between points (equidistant; the reference position
//!   is a point); the data of point n is the change of the correction from point n−1 to n,
//!   in detection units (FANUC technical report A-77810E for the bidirectional variant,
//!   No. 3605#0, 3626, 3627, not used here).
//!
//! Anything else (quadrant/backlash acceleration, thermal, straightness) is reported as "no
//! documented parameter": FANUC has such functions, but their parameter numbers are not
//! documented here, so none is written.
//!
//! Choices: detection unit 1 µm (IS-B); a preset value is rounded to it; at most 128 pitch
//! points per axis and 1024 pitch data in all.

use super::entry::{FileSpec, Plan, Put, with_unit};
use super::report::{Change, ErrFigures, Pending};
use super::{Ctx, Violation, num, shared};
use crate::preset::AccDecKind;
use crate::units::{mm_to_um, s_to_ms, um_to_mm};

/// Detection unit, mm (IS-B).
pub const DETECTION_UNIT_MM: f64 = 0.001;
/// Pitch error compensation points one axis may use.
pub const PITCH_POINTS_PER_AXIS: usize = 128;
/// Pitch error compensation data the control holds in all.
pub const PITCH_DATA_TOTAL: usize = 1024;

const FILE: &str = "fanuc_parameters.txt";
const DATA_SECTION: &str = "; pitch error compensation data";

fn du(mm: f64) -> i64 {
    (mm / DETECTION_UNIT_MM).round() as i64
}

/// Axis `i`'s word `A<i+1> P<value>` on parameter line `no`.
fn word(no: u32, i: usize, value: impl std::fmt::Display) -> Put {
    Put::new(FILE, "", format!("N{no}"), format!(" A{} P{value}", i + 1))
}

/// The export's one list and its file.
pub(crate) fn render(ctx: &Ctx) -> Result<Plan, Vec<Violation>> {
    let p = ctx.preset;
    let head = format!(
        "; FANUC parameters exported by axisbench from preset '{}'\n; axis k = the preset's k-th axis ({}); detection unit 1 um (IS-B)\n; format: N<parameter> A<axis> P<value> ...; pitch error data: N<10000 + data number> P<value>\n",
        p.name,
        p.axes
            .iter()
            .map(|a| a.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let files = vec![FileSpec::new(FILE, head, "").always()];
    let mut violations = Vec::new();
    let mut entries = limit_entries(ctx);
    for i in 0..p.axes.len() {
        match backlash_entries(ctx, i) {
            Ok(e) => entries.extend(e),
            Err(v) => violations.push(v),
        }
    }
    let (pitch, bad) = pitch_entries(ctx);
    entries.extend(pitch);
    violations.extend(bad);
    entries.extend(undocumented_entries(ctx));
    if violations.is_empty() {
        Ok(Plan { files, entries })
    } else {
        Err(violations)
    }
}

/// No. 1420 (rapid), 1620 (acc/dec time constant), 1825 (servo loop gain).
fn limit_entries(ctx: &Ctx) -> Vec<Pending> {
    let p = ctx.preset;
    let n = p.axes.len();
    let ad = &p.nc.accdec;
    let tau_ms = match ad.kind {
        AccDecKind::None => 0.0,
        AccDecKind::Linear => s_to_ms(ad.tc1_s),
        AccDecKind::Bell => s_to_ms(ad.tc1_s.max(ad.tc2_s)),
    };
    let mut out = vec![
        Pending::derived(
            "nc.rapid_mm_per_min",
            with_unit(p.nc.rapid_mm_per_min, "mm/min"),
        )
        .note("No. 1420: the rapid traverse rate (mm/min), every axis")
        .puts((0..n).map(|i| word(1420, i, num(ctx.axes[i].limits.max_vel_mm_s * 60.0)))),
        Pending::approximated(
            "nc.accdec",
            format!(
                "{}, τ1 = {}, τ2 = {}",
                format!("{:?}", ad.kind).to_lowercase(),
                with_unit(ad.tc1_s, "s"),
                with_unit(ad.tc2_s, "s")
            ),
        )
        .note("No. 1620: linear acc/dec time constant for rapid traverse (rounded to 1 ms); a bell shape's second stage and the cutting-feed constants are not written. Not simulated: the trajectory is the NC's own")
        .puts((0..n).map(|i| word(1620, i, num(tau_ms.round())))),
    ];
    for (i, a) in p.axes.iter().enumerate() {
        out.push(
            Pending::derived(
                format!("axes.{}.servo.kp_per_s", a.name),
                with_unit(a.servo.kp_per_s, "/s"),
            )
            .note("No. 1825: servo loop gain in 0.01/s")
            .put(word(1825, i, (a.servo.kp_per_s * 100.0).round() as i64)),
        );
    }
    out
}

/// No. 1851/1852 of axis `i` (0 without backlash), rounded to the detection unit.
fn backlash_entries(ctx: &Ctx, i: usize) -> Result<Vec<Pending>, Violation> {
    let a = &ctx.preset.axes[i];
    if !a.backlash.enabled {
        return Ok(vec![
            Pending::mapped(format!("axes.{}.backlash.enabled", a.name), "false")
                .note("no backlash compensation")
                .puts([word(1851, i, 0), word(1852, i, 0)]),
        ]);
    }
    let q_mm = um_to_mm(a.backlash.q_um);
    let v = du(q_mm);
    if !(-9999..=9999).contains(&v) {
        return Err(Violation::new(
            format!("axes.{}.backlash.q_um", a.name),
            format!(
                "{} µm is {v} detection units; No. 1851 takes −9999…9999",
                a.backlash.q_um
            ),
        ));
    }
    let err_um = mm_to_um((v as f64 * DETECTION_UNIT_MM - q_mm).abs());
    let (field, value) = shared::backlash_q(a);
    let note = "No. 1851 in detection units, output when the axis first moves against the reference return direction, as axisbench keeps the first direction at 0; No. 1852 holds the same amount for rapid traverse (1800#4 RBK = 0; the preset has one amount)";
    let puts = [word(1851, i, v), word(1852, i, v)];
    let e = if err_um < 1e-9 {
        Pending::mapped(field, value).note(note).puts(puts)
    } else {
        Pending::approximated(field, value)
            .note(format!("{note}; rounded to the 1 µm detection unit"))
            .puts(puts)
            .evaluated(ErrFigures::evaluated(
                "rounding to the detection unit",
                err_um,
            ))
    };
    let mut out = vec![e];
    out.extend(shared::backlash_modes_as_lump(ctx, i, "FANUC (No. 1851)"));
    Ok(out)
}

/// Pitch error compensation: No. 3620–3624 per axis and the incremental data, numbered on
/// from axis to axis; zeros for the axes without a lead error.
fn pitch_entries(ctx: &Ctx) -> (Vec<Pending>, Vec<Violation>) {
    let p = ctx.preset;
    if !p.axes.iter().any(|a| a.lead_error.enabled) {
        return (vec![], vec![]);
    }
    let mut out = Vec::new();
    let mut bad = Vec::new();
    let mut next_data = 0usize;
    for (i, a) in p.axes.iter().enumerate() {
        if !a.lead_error.enabled {
            out.push(
                Pending::mapped(format!("axes.{}.lead_error.enabled", a.name), "false")
                    .note("no pitch error compensation for this axis")
                    .puts((3620..=3624).map(|no| word(no, i, 0))),
            );
            continue;
        }
        match pitch_entry(ctx, i, next_data) {
            Ok((e, count)) => {
                out.push(e);
                next_data += count;
            }
            Err(v) => bad.push(v),
        }
    }
    if next_data > PITCH_DATA_TOTAL {
        bad.push(Violation::new(
            "axes.*.lead_error",
            format!("{next_data} pitch error data in all; the control holds {PITCH_DATA_TOTAL}"),
        ));
    }
    (out, bad)
}

/// Axis `i`'s pitch table on an equidistant grid through the reference position 0,
/// numbered from `first`; returns the entry and the number of data it uses.
fn pitch_entry(ctx: &Ctx, i: usize, first: usize) -> Result<(Pending, usize), Violation> {
    let a = &ctx.preset.axes[i];
    let (lo, hi) = ctx.axes[i].travel_mm;
    let pt = super::pitch_table(&a.lead_error, (lo, hi), PITCH_POINTS_PER_AXIS - 1, true);
    let step_raw = (hi - lo) / (pt.points.len().max(2) - 1) as f64;
    let step = (step_raw / DETECTION_UNIT_MM).ceil() * DETECTION_UNIT_MM;
    let k0 = (lo.min(0.0) / step).floor() as i64;
    let k1 = (hi.max(0.0) / step).ceil() as i64;
    let count = usize::try_from(k1.saturating_sub(k0).saturating_add(1)).unwrap_or(usize::MAX);
    if count > PITCH_POINTS_PER_AXIS {
        return Err(Violation::new(
            format!("axes.{}.lead_error", a.name),
            format!(
                "the travel {lo}…{hi} mm with the reference position 0 needs {count} pitch points at {step} mm; at most {PITCH_POINTS_PER_AXIS} per axis"
            ),
        ));
    }
    let ref_no = first as i64 - k0;
    let last = first + count - 1;
    let mut puts = vec![
        word(3620, i, ref_no),
        word(3621, i, first),
        word(3622, i, last),
        word(3623, i, 1),
        word(3624, i, num(step)),
    ];
    let mut prev = 0i64;
    let mut grid = Vec::new();
    for (n, k) in (k0..=k1).enumerate() {
        let x = k as f64 * step;
        let c = du(um_to_mm(-super::lead_error_um(&a.lead_error, x)));
        // Data of point n: change from point n−1 (the first point's change from 0).
        puts.push(Put::new(
            FILE,
            DATA_SECTION,
            format!("N{}", 10000 + first + n),
            format!(" P{}", c - prev),
        ));
        prev = c;
        grid.push((x, mm_to_um(c as f64 * DETECTION_UNIT_MM)));
    }
    let table = super::PitchTable {
        residual_um: super::residual_um(&a.lead_error, &grid, (lo, hi)),
        points: grid,
        equidistant: true,
    };
    let mut e = shared::pitch_entry(ctx, i, &table, puts);
    e.entry.note += &format!(
        "; No. 3620 = {ref_no} (reference point), 3621 = {first}, 3622 = {last}, 3623 = 1, 3624 = {} mm; data incremental, detection units",
        num(step)
    );
    Ok((e, count))
}

/// What FANUC has functions for, but no parameter numbers documented here.
fn undocumented_entries(ctx: &Ctx) -> Vec<Pending> {
    let p = ctx.preset;
    let mut out = Vec::new();
    for (i, a) in p.axes.iter().enumerate() {
        if a.quadrant.enabled {
            out.push(
                Pending::undocumented(format!("axes.{}.quadrant", a.name), shared::quadrant_value(&a.quadrant))
                    .note("FANUC's reversal compensation (backlash acceleration) is a servo function whose parameter numbers are not documented here; nothing written. Simulated as omitted")
                    .sim(vec![Change::Quadrant { axis: i, params: None }], vec![i], false),
            );
        }
        if a.thermal.enabled {
            out.push(
                Pending::undocumented(format!("axes.{}.thermal", a.name), shared::thermal_value(a))
                    .note("the thermal displacement compensation with re-measurement (thermal patent, SPEC §4) has no parameter numbers documented here; nothing written. Simulated as omitted")
                    .sim(vec![Change::Thermal { axis: i, frozen: false }], vec![i], false),
            );
        }
    }
    for (ci, t) in p.cross.iter().enumerate().filter(|(_, t)| t.enabled) {
        let comp = super::axis_index(p, &t.comp_axis);
        out.push(
            Pending::undocumented(format!("cross.{ci}"), shared::cross_value(t))
                .note("FANUC's straightness compensation has no parameter numbers documented here; nothing written. Simulated as omitted")
                .sim(
                    vec![Change::Cross {
                        tables: shared::without(&p.cross, ci),
                    }],
                    vec![comp],
                    false,
                ),
        );
    }
    out
}
