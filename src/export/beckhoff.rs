//! Beckhoff TwinCAT CNC (ISG kernel): one ASCII compensation value list per axis
//! (`achskw_<n>.lis`).
//!
//! Sources: ISG / Beckhoff TF5200 "Axis compensation" documentation (FCT-C5, compensation
//! parameters P-COMP-…):
//! - list header: `kopf.achs_nr` (P-COMP-00001, logical axis number), `kopf.log_achs_name`
//!   (P-COMP-00002);
//! - cross (sag) compensation, `kw.crosscomp.*`: `unit` (P-COMP-00003; 1 = metric, lengths
//!   in 0.1 µm), `last_index` (P-COMP-00004; < `max_points` P-COMP-00060, default 1001),
//!   `master_ax_nr` (P-COMP-00005; the axis whose command position is the input),
//!   `table[i].setpoint` (P-COMP-00006, master position), `table[i].correction`
//!   (P-COMP-00007, slave correction), all in 0.1 µm; activated by P-AXIS-00047
//!   `lr_param.crosscomp = 1` in the slave axis's machine data. One master per list;
//! - leadscrew error compensation, `kw.ssfk.*`: `unit` (P-COMP-00017), `interval`
//!   (P-COMP-00018; 0 = the setpoints are given), `kw_startpos` (P-COMP-00019),
//!   `kw_nr_max` (P-COMP-00020), `bilateral` (P-COMP-00021; 1 = separate values for the
//!   positive and negative direction), `table[i].setpoint`, `.pos`, `.neg` in 0.1 µm.
//!
//! Choices: the per-direction backlash goes into the bilateral leadscrew table (the
//! negative-direction column carries −Q relative to the positive one, axisbench's convention
//! with + as the reference direction); values are rounded to whole 0.1 µm (SGN32 in builds
//! before V3.1.3132, so every build reads them).

use super::report::{self, Pending};
use super::{Ctx, Rendered, Violation, fixed};

/// `kw.crosscomp.max_points` default: `last_index` must stay below it.
pub const CROSS_MAX_POINTS: usize = 1001;

fn tenth_um(mm: f64) -> i64 {
    (mm * 1e4).round() as i64
}

pub(crate) fn render(ctx: &Ctx) -> Result<Rendered, Vec<Violation>> {
    let p = ctx.preset;
    let mut violations = Vec::new();
    let mut files = Vec::new();
    let mut entries: Vec<Pending> = Vec::new();
    let mut keep = vec![false; p.cross.len()];
    entries.push(Pending::undocumented(
        "nc.rapid_mm_per_min, nc.accdec, axes[..].servo",
        "axis dynamics and gains live in the axis machine data, not in the compensation lists; no parameter is written",
    ));
    for (i, a) in p.axes.iter().enumerate() {
        let nr = i + 1;
        let mut s = format!(
            "# TwinCAT CNC compensation value list exported by axisbench from preset '{}'\n# lengths in 0.1 um (unit 1)\nkopf.achs_nr                      {nr}\nkopf.log_achs_name                {}\n",
            p.name,
            a.name.to_uppercase()
        );
        let mut used = false;
        // ---- leadscrew table (pitch + per-direction backlash) ----
        let b = &a.backlash;
        let q_mm = if b.enabled { b.q_um / 1000.0 } else { 0.0 };
        if a.lead_error.enabled || b.enabled {
            let points: Vec<(f64, f64)> = if a.lead_error.enabled {
                super::pitch_table(&a.lead_error, ctx.axes[i].travel_mm, 1000, false).points
            } else {
                let (lo, hi) = ctx.axes[i].travel_mm;
                vec![(lo, 0.0), (hi, 0.0)]
            };
            let rounded: Vec<(i64, i64, i64)> = points
                .iter()
                .map(|&(x, c)| (tenth_um(x), tenth_um(c * 1e-3), tenth_um(c * 1e-3 - q_mm)))
                .collect();
            s += &format!(
                "kw.ssfk.unit                      1\nkw.ssfk.interval                  0\nkw.ssfk.kw_startpos               {}\nkw.ssfk.kw_nr_max                 {}\nkw.ssfk.bilateral                 1\n",
                rounded[0].0,
                rounded.len()
            );
            for (n, r) in rounded.iter().enumerate() {
                s += &format!("kw.ssfk.table[{n}].setpoint{:>16}\n", r.0);
            }
            for (n, r) in rounded.iter().enumerate() {
                s += &format!("kw.ssfk.table[{n}].pos{:>21}\n", r.1);
            }
            for (n, r) in rounded.iter().enumerate() {
                s += &format!("kw.ssfk.table[{n}].neg{:>21}\n", r.2);
            }
            used = true;
            if b.enabled {
                let q_r = tenth_um(q_mm) as f64 * 0.1;
                let entry = format!(
                    "achskw_{nr}.lis kw.ssfk bilateral: .neg − .pos = {} (0.1 µm)",
                    -tenth_um(q_mm)
                );
                let setting = format!("axes[{}].backlash.q_um = {}", a.name, b.q_um);
                let note = "per direction in the bilateral leadscrew table: + direction as measured, − direction −Q (axisbench's one-sided convention, + as reference), switched at the reversal";
                if (q_r - b.q_um).abs() < 1e-9 {
                    entries.push(Pending::mapped(setting, entry, note));
                } else {
                    entries.push(
                        Pending::approximated(
                            setting,
                            entry,
                            &format!("{note}; rounded to 0.1 µm"),
                        )
                        .evaluated(super::ErrFigures {
                            method: "rounding to the list's 0.1 µm unit".into(),
                            correction_max_um: (q_r - b.q_um).abs(),
                            correction_rms_um: None,
                            position_error_max_um: None,
                            constant_offset_um: 0.0,
                        }),
                    );
                }
                entries.extend(report::backlash_modes_as_lump(
                    ctx,
                    i,
                    "The bilateral table",
                ));
            }
            if a.lead_error.enabled {
                let grid: Vec<(f64, f64)> = rounded
                    .iter()
                    .map(|r| (r.0 as f64 * 1e-4, r.1 as f64 * 0.1))
                    .collect();
                let pt = super::PitchTable {
                    residual_um: super::residual_um(&a.lead_error, &grid, ctx.axes[i].travel_mm),
                    points: grid,
                    equidistant: false,
                };
                entries.push(report::pitch_entry(
                    ctx,
                    i,
                    &pt,
                    format!(
                        "achskw_{nr}.lis kw.ssfk.table[0…{}] (.pos; .neg = .pos − Q)",
                        rounded.len() - 1
                    ),
                ));
            }
        }
        // ---- cross compensation: one master per slave list ----
        let into: Vec<(usize, &crate::comp::cross::CrossTable)> = super::cross_into(p, &a.name);
        if let Some((ci, t)) = into.first().filter(|(_, t)| !t.points.is_empty()) {
            if t.points.len() > CROSS_MAX_POINTS {
                violations.push(Violation::new(
                    format!("cross[{ci}].points"),
                    format!(
                        "{} points; kw.crosscomp.last_index must stay below max_points = {CROSS_MAX_POINTS} (P-COMP-00060)",
                        t.points.len()
                    ),
                ));
            } else {
                let master = super::axis_index(p, &t.base_axis) + 1;
                s += &format!(
                    "kw.crosscomp.unit                 1\nkw.crosscomp.last_index           {}\nkw.crosscomp.master_ax_nr         {master}\n",
                    t.points.len() - 1
                );
                let mut resid: f64 = 0.0;
                for (n, &(x, c)) in t.points.iter().enumerate() {
                    let cr = tenth_um(c * 1e-3);
                    resid = resid.max((cr as f64 * 0.1 - c).abs());
                    s += &format!(
                        "kw.crosscomp.table[{n}].setpoint{:>13}\nkw.crosscomp.table[{n}].correction{:>11}\n",
                        tenth_um(x),
                        cr
                    );
                }
                used = true;
                keep[*ci] = true;
                let target = format!(
                    "achskw_{nr}.lis kw.crosscomp (master_ax_nr {master}, {} points); P-AXIS-00047 lr_param.crosscomp = 1 for axis {nr}",
                    t.points.len()
                );
                let setting = report::cross_setting(*ci, t);
                if resid < 1e-9 {
                    entries.push(Pending::mapped(setting, target, "same points in 0.1 µm"));
                } else {
                    entries.push(
                        Pending::approximated(setting, target, "rounded to 0.1 µm").evaluated(
                            super::ErrFigures {
                                method: format!("rounding to 0.1 µm: {}", fixed(resid, 3)),
                                correction_max_um: resid,
                                correction_rms_um: None,
                                position_error_max_um: None,
                                constant_offset_um: 0.0,
                            },
                        ),
                    );
                }
            }
        }
        if used {
            files.push((format!("achskw_{nr}.lis"), s));
        }
        entries.extend(report::quadrant_omitted(
            ctx,
            i,
            "the ISG friction compensation (frict_comp.*) is a velocity-dependent current table, not a reversal pulse adapted to the stroke",
        ));
        entries.extend(report::thermal_omitted(
            ctx,
            i,
            "the compensation lists are static",
        ));
    }
    entries.extend(report::cross_omitted(
        ctx,
        &keep,
        "a slave axis's list holds one kw.crosscomp table with one master axis",
    ));
    if violations.is_empty() {
        Ok(Rendered { files, entries })
    } else {
        Err(violations)
    }
}
