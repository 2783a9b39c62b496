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

use super::report::{self, ErrFigures, Pending};
use super::{Ctx, Rendered, Violation, num};

/// Detection unit, mm (IS-B).
pub const DETECTION_UNIT_MM: f64 = 0.001;
pub const PITCH_POINTS_PER_AXIS: usize = 128;
pub const PITCH_DATA_TOTAL: usize = 1024;

fn du(mm: f64) -> i64 {
    (mm / DETECTION_UNIT_MM).round() as i64
}

pub(crate) fn render(ctx: &Ctx) -> Result<Rendered, Vec<Violation>> {
    let p = ctx.preset;
    let mut violations = Vec::new();
    let mut entries: Vec<Pending> = Vec::new();
    let n_axes = p.axes.len();
    let mut lines: Vec<String> = vec![format!(
        "; FANUC parameters exported by axisbench from preset '{}'\n; axis k = the preset's k-th axis ({}); detection unit 1 um (IS-B)\n; format: N<parameter> A<axis> P<value> ...; pitch error data: N<10000 + data number> P<value>",
        p.name,
        p.axes
            .iter()
            .map(|a| a.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    )];
    let axis_line = |no: u32, vals: &[String]| {
        let mut s = format!("N{no}");
        for (k, v) in vals.iter().enumerate() {
            s += &format!(" A{} P{v}", k + 1);
        }
        s
    };
    // 1420 / 1620 / 1825
    let rapid: Vec<String> = (0..n_axes)
        .map(|i| num(ctx.axes[i].limits.max_vel_mm_s * 60.0))
        .collect();
    lines.push(axis_line(1420, &rapid));
    let tau_ms = match p.nc.accdec.kind {
        crate::preset::AccDecKind::None => 0.0,
        crate::preset::AccDecKind::Linear => p.nc.accdec.tc1_s * 1e3,
        crate::preset::AccDecKind::Bell => p.nc.accdec.tc1_s.max(p.nc.accdec.tc2_s) * 1e3,
    };
    lines.push(axis_line(1620, &vec![num(tau_ms.round()); n_axes]));
    let gains: Vec<String> = p
        .axes
        .iter()
        .map(|a| format!("{}", (a.servo.kp_per_s * 100.0).round() as i64))
        .collect();
    lines.push(axis_line(1825, &gains));
    entries.push(Pending::derived(
        format!("nc.rapid_mm_per_min = {}", p.nc.rapid_mm_per_min),
        format!(
            "No. 1420 = {} mm/min (every axis)",
            rapid.first().cloned().unwrap_or_default()
        ),
        "the rapid traverse rate",
    ));
    entries.push(Pending::approximated(
        format!("nc.accdec ({:?}, τ1 = {} s, τ2 = {} s)", p.nc.accdec.kind, p.nc.accdec.tc1_s, p.nc.accdec.tc2_s),
        format!("No. 1620 = {} ms", num(tau_ms.round())),
        "linear acc/dec time constant for rapid traverse (rounded to 1 ms); a bell shape's second stage and the cutting-feed constants are not written. Not simulated: the trajectory is the NC's own",
    ));
    // Backlash 1851/1852.
    let mut bl: Vec<String> = Vec::new();
    for (i, a) in p.axes.iter().enumerate() {
        let q_mm = if a.backlash.enabled {
            a.backlash.q_um / 1000.0
        } else {
            0.0
        };
        let v = du(q_mm);
        if !(-9999..=9999).contains(&v) {
            violations.push(Violation::new(
                format!("axes[{}].backlash.q_um", a.name),
                format!(
                    "{} µm is {v} detection units; No. 1851 takes −9999…9999",
                    a.backlash.q_um
                ),
            ));
        }
        bl.push(v.to_string());
        entries.push(Pending::derived(
            format!("axes[{}].servo.kp_per_s = {}", a.name, a.servo.kp_per_s),
            format!("No. 1825 A{} = {}", i + 1, gains[i]),
            "servo loop gain in 0.01/s",
        ));
        if a.backlash.enabled {
            let err = (v as f64 * DETECTION_UNIT_MM - q_mm).abs() * 1e3;
            let target = format!(
                "No. 1851 A{} = {v}, No. 1852 A{} = {v} (1800#4 RBK = 0)",
                i + 1,
                i + 1
            );
            let setting = format!("axes[{}].backlash.q_um = {}", a.name, a.backlash.q_um);
            let note = "in detection units; output when the axis first moves against the reference return direction, as axisbench keeps the first direction at 0; 1852 holds the same amount for rapid traverse (the preset has one)";
            if err < 1e-9 {
                entries.push(Pending::mapped(setting, target, note));
            } else {
                entries.push(
                    Pending::approximated(
                        setting,
                        target,
                        &format!("{note}; rounded to the 1 µm detection unit"),
                    )
                    .evaluated(ErrFigures {
                        method: "rounding to the detection unit".into(),
                        correction_max_um: err,
                        correction_rms_um: None,
                        position_error_max_um: None,
                        constant_offset_um: 0.0,
                    }),
                );
            }
            entries.extend(report::backlash_modes_as_lump(ctx, i, "FANUC (No. 1851)"));
        }
    }
    lines.push(axis_line(1851, &bl));
    lines.push(axis_line(1852, &bl));
    // Pitch error compensation.
    let mut next_data = 0usize;
    let mut pitch_params: Vec<[String; 5]> = Vec::new();
    let mut data_lines: Vec<String> = Vec::new();
    for (i, a) in p.axes.iter().enumerate() {
        if !a.lead_error.enabled {
            pitch_params.push(["0".into(), "0".into(), "0".into(), "0".into(), "0".into()]);
            continue;
        }
        let (lo, hi) = ctx.axes[i].travel_mm;
        // An equidistant grid through the reference position 0 covering the travel.
        let pt = super::pitch_table(&a.lead_error, (lo, hi), PITCH_POINTS_PER_AXIS - 1, true);
        let step_raw = (hi - lo) / (pt.points.len().max(2) - 1) as f64;
        let step = (step_raw / DETECTION_UNIT_MM).ceil() * DETECTION_UNIT_MM;
        let k0 = (lo.min(0.0) / step).floor() as i64;
        let k1 = (hi.max(0.0) / step).ceil() as i64;
        let count = (k1 - k0 + 1) as usize;
        if count > PITCH_POINTS_PER_AXIS {
            violations.push(Violation::new(
                format!("axes[{}].lead_error", a.name),
                format!("the travel {lo}…{hi} mm with the reference position 0 needs {count} pitch points at {step} mm; at most {PITCH_POINTS_PER_AXIS} per axis"),
            ));
            continue;
        }
        let first = next_data;
        next_data += count;
        let ref_no = first as i64 - k0;
        let mut prev = 0i64;
        let mut grid = Vec::new();
        for (n, k) in (k0..=k1).enumerate() {
            let x = k as f64 * step;
            let c = du(-super::lead_error_um(&a.lead_error, x) * 1e-3);
            // Data of point n: change from point n−1 (the first point's change from 0).
            data_lines.push(format!("N{} P{}", 10000 + first + n, c - prev));
            prev = c;
            grid.push((x, c as f64 * DETECTION_UNIT_MM * 1e3));
        }
        pitch_params.push([
            ref_no.to_string(),
            first.to_string(),
            (first + count - 1).to_string(),
            "1".into(),
            num(step),
        ]);
        let resid = super::residual_um(&a.lead_error, &grid, (lo, hi));
        let table = super::PitchTable {
            points: grid,
            residual_um: resid,
            equidistant: true,
        };
        entries.push(report::pitch_entry(
            ctx,
            i,
            &table,
            format!(
                "No. 3620 A{ax} = {ref_no}, 3621 = {first}, 3622 = {last}, 3623 = 1, 3624 = {step} mm; data No. {first}…{last} (incremental, detection units)",
                ax = i + 1,
                last = first + count - 1,
                step = num(step),
            ),
        ));
    }
    if next_data > PITCH_DATA_TOTAL {
        violations.push(Violation::new(
            "axes[..].lead_error",
            format!("{next_data} pitch error data in all; the control holds {PITCH_DATA_TOTAL}"),
        ));
    }
    if next_data > 0 {
        for (j, no) in [3620, 3621, 3622, 3623, 3624].into_iter().enumerate() {
            let vals: Vec<String> = pitch_params.iter().map(|pp| pp[j].clone()).collect();
            lines.push(axis_line(no, &vals));
        }
        lines.push("; pitch error compensation data".into());
        lines.extend(data_lines);
    }
    for (i, a) in p.axes.iter().enumerate() {
        if a.quadrant.enabled {
            entries.push(
                Pending::undocumented(
                    format!("axes[{}].quadrant (adaptive short-stroke TFF, seed 003)", a.name),
                    "FANUC's reversal compensation (backlash acceleration) is a servo function whose parameter numbers are not documented here; nothing written. Simulated as omitted",
                )
                .sim(vec![report::Change::Quadrant { axis: i, params: None }], vec![i], false),
            );
        }
        if a.thermal.enabled {
            entries.push(
                Pending::undocumented(
                    report::thermal_setting(a),
                    "the thermal displacement compensation with re-measurement (seed 002) has no parameter numbers documented here; nothing written. Simulated as omitted",
                )
                .sim(vec![report::Change::Thermal { axis: i, frozen: false }], vec![i], false),
            );
        }
    }
    for (ci, t) in p.cross.iter().enumerate().filter(|(_, t)| t.enabled) {
        let comp = super::axis_index(p, &t.comp_axis);
        let keep: Vec<_> = p
            .cross
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != ci)
            .map(|(_, t)| t.clone())
            .collect();
        entries.push(
            Pending::undocumented(
                report::cross_setting(ci, t),
                "FANUC's straightness compensation has no parameter numbers documented here; nothing written. Simulated as omitted",
            )
            .sim(vec![report::Change::Cross { tables: keep }], vec![comp], false),
        );
    }
    let text = lines.join("\n") + "\n";
    if violations.is_empty() {
        Ok(Rendered {
            files: vec![("fanuc_parameters.txt".into(), text)],
            entries,
        })
    } else {
        Err(violations)
    }
}
