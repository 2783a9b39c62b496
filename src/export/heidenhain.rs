//! HEIDENHAIN TNC: nonlinear axis-error compensation tables (`*.COM`) with their
//! assignment table (`CONFIG.CMA`), and the backlash machine parameters.
//!
//! Sources:
//! - HEIDENHAIN Technical Manual MANUALplus 620 / TNC 640 family, "Nonlinear axis error
//!   compensation": a `*.COM` table has the column AXISPOS (compensation points of the
//!   input axis, from the machine datum) and one column per compensated axis (named as in
//!   CfgAxes/axisList) holding the compensation values; a `*.CMA` table assigns, per input
//!   axis column, the `*.COM` table to use, and the line marked `*` in ACTIVE is in force:
//!   "[axis in column of the .COM] = F(axis in the column of the .CMA)". Tables use the TNC
//!   table format: `BEGIN <name> MM`, a header line, fixed-width rows, `[END]`.
//! - TNC 407/415 Technical Manual (module 9095): a `.COM` table with more than 256 entries is
//!   rejected; this export keeps to that bound.
//! - Same manual, "Backlash": MP_backLash (mm) is added at every reversal; MP_filterTime is
//!   the time over which it is traversed (0 = at once). MP750.x/MP752.x on the iTNC 530.
//!
//! Choices: one `.COM` per input axis (its own lead error in its own column, the cross
//! tables it drives in the compensated axes' columns) on the union of all their points, so
//! every function stays exact; values to 0.01 µm.

use super::report::{self, Change, Pending};
use super::{Ctx, Rendered, Violation, fixed, num};
use crate::comp::backlash::{BacklashParams, OutputMode};

/// Entries a `.COM` table may hold.
pub const MAX_ENTRIES: usize = 256;

fn key(name: &str) -> String {
    name.to_uppercase()
}

pub(crate) fn render(ctx: &Ctx) -> Result<Rendered, Vec<Violation>> {
    let p = ctx.preset;
    let mut violations = Vec::new();
    let mut files: Vec<(String, String)> = Vec::new();
    let mut entries: Vec<Pending> = Vec::new();
    let mut cma_cols: Vec<(String, String)> = Vec::new();
    let mut mp = format!(
        "; HEIDENHAIN machine parameters exported by axisbench from preset '{}' (CfgAxisComp per axis)\n",
        p.name
    );
    for (i, a) in p.axes.iter().enumerate() {
        let k = key(&a.name);
        // ---- the table whose input is this axis ----
        let pitch = a
            .lead_error
            .enabled
            .then(|| super::pitch_table(&a.lead_error, ctx.axes[i].travel_mm, MAX_ENTRIES, false));
        let crosses: Vec<(usize, &crate::comp::cross::CrossTable)> = p
            .cross
            .iter()
            .enumerate()
            .filter(|(_, t)| t.enabled && t.base_axis == a.name)
            .collect();
        if pitch.is_some() || !crosses.is_empty() {
            let mut xs: Vec<f64> = pitch
                .iter()
                .flat_map(|t| t.points.iter().map(|p| p.0))
                .collect();
            for (_, t) in &crosses {
                xs.extend(t.points.iter().map(|p| p.0));
            }
            xs.sort_by(f64::total_cmp);
            xs.dedup();
            if xs.len() > MAX_ENTRIES {
                violations.push(Violation::new(
                    format!("axes[{}] (input of {}.COM)", a.name, k),
                    format!(
                        "{} compensation points (lead-error table and cross tables {:?} on one AXISPOS grid); a .COM table holds at most {MAX_ENTRIES}",
                        xs.len(),
                        crosses.iter().map(|(ci, _)| *ci).collect::<Vec<_>>()
                    ),
                ));
                continue;
            }
            // Columns: compensated axes.
            let mut cols: Vec<(String, Vec<f64>)> = Vec::new();
            if let Some(pt) = &pitch {
                cols.push((
                    k.clone(),
                    xs.iter()
                        .map(|&x| crate::table::interp(&pt.points, x))
                        .collect(),
                ));
            }
            for (_, t) in &crosses {
                let ck = key(&t.comp_axis);
                let vals: Vec<f64> = xs
                    .iter()
                    .map(|&x| crate::table::interp(&t.points, x))
                    .collect();
                match cols.iter_mut().find(|c| c.0 == ck) {
                    Some(c) => c.1.iter_mut().zip(&vals).for_each(|(a, b)| *a += b),
                    None => cols.push((ck, vals)),
                }
            }
            let name = format!("{k}.COM");
            let mut s = format!("BEGIN {name} MM\n{:<6}{:>14}", "NR", "AXISPOS");
            for (c, _) in &cols {
                s += &format!("{c:>14}");
            }
            s += "\n";
            for (n, x) in xs.iter().enumerate() {
                s += &format!("{n:<6}{:>14}", signed(fixed(*x, 4)));
                for (_, v) in &cols {
                    s += &format!("{:>14}", signed(fixed(v[n] * 1e-3, 5)));
                }
                s += "\n";
            }
            s += "[END]\n";
            files.push((name.clone(), s));
            cma_cols.push((k.clone(), name.clone()));
            if let Some(pt) = &pitch {
                let grid: Vec<(f64, f64)> = xs
                    .iter()
                    .map(|&x| {
                        (
                            x,
                            (crate::table::interp(&pt.points, x) * 100.0).round() / 100.0,
                        )
                    })
                    .collect();
                let mut pt2 = pt.clone();
                pt2.points = grid.clone();
                pt2.residual_um = super::residual_um(&a.lead_error, &grid, ctx.axes[i].travel_mm);
                entries.push(report::pitch_entry(
                    ctx,
                    i,
                    &pt2,
                    format!("{name} column {k}, {} points", xs.len()),
                ));
            }
            for (ci, t) in &crosses {
                entries.push(Pending::mapped(
                    report::cross_setting(*ci, t),
                    format!("{name} column {} (AXISPOS = {})", key(&t.comp_axis), k),
                    "same points, µm → mm to 0.01 µm; several tables onto one axis from the same input add up in one column",
                ));
            }
        }
        // ---- backlash ----
        let b = &a.backlash;
        if b.enabled {
            let period = p.timing.t2_s;
            let both_time = b.plus_to_minus.mode == OutputMode::Time
                && b.minus_to_plus.mode == OutputMode::Time
                && b.plus_to_minus.cycles_m == b.minus_to_plus.cycles_m;
            let filter_ms = if both_time {
                b.plus_to_minus.cycles_m as f64 * period * 1e3
            } else {
                0.0
            };
            mp += &format!(
                "{k}: MP_backLash = {} ; mm\n{k}: MP_filterTime = {} ; ms\n",
                num(b.q_um / 1000.0),
                num(filter_ms)
            );
            entries.push(Pending::mapped(
                format!("axes[{}].backlash.q_um = {}", a.name, b.q_um),
                format!("{k}: MP_backLash = {} mm", num(b.q_um / 1000.0)),
                "added at every reversal",
            ));
            if both_time {
                entries.push(
                    Pending::approximated(
                        format!(
                            "axes[{}].backlash modes = time (M = {} cycles) both directions",
                            a.name, b.plus_to_minus.cycles_m
                        ),
                        format!("{k}: MP_filterTime = {} ms", num(filter_ms)),
                        "the TNC traverses the backlash over MP_filterTime (M generation periods) in both directions",
                    )
                    .sim(
                        vec![Change::Backlash {
                            axis: i,
                            params: Some(BacklashParams { ..b.clone() }),
                        }],
                        vec![i],
                        false,
                    ),
                );
            } else {
                entries.extend(report::backlash_modes_as_lump(
                    ctx,
                    i,
                    "the TNC (MP_filterTime = 0; a filter time spreads both directions alike)",
                ));
            }
        }
        entries.extend(report::quadrant_omitted(
            ctx,
            i,
            "the TNC's reversal-peak compensation (MP_compStrength/MP_compWidth/MP_compTimeOffset) is a velocity-shaped pulse adapted to acceleration, not to the stroke; its units do not follow from M0/T0",
        ));
        entries.extend(report::thermal_omitted(
            ctx,
            i,
            "a .COM table is static; thermal growth needs the PLC or KinematicsComp",
        ));
        entries.extend(report::servo_entries(
            ctx,
            i,
            "the drive (machine parameters of the control loop)",
        ));
    }
    if !cma_cols.is_empty() {
        let mut s = format!("BEGIN CONFIG.CMA\n{:<6}", "NR");
        for (c, _) in &cma_cols {
            s += &format!("{c:>12}");
        }
        s += &format!("{:>8}\n{:<6}", "ACTIVE", 0);
        for (_, f) in &cma_cols {
            s += &format!("{f:>12}");
        }
        s += &format!("{:>8}\n[END]\n", "*");
        files.push(("CONFIG.CMA".into(), s));
    }
    files.push(("machine_parameters.txt".into(), mp));
    if violations.is_empty() {
        Ok(Rendered { files, entries })
    } else {
        Err(violations)
    }
}

fn signed(s: String) -> String {
    if s.starts_with('-') {
        s
    } else {
        format!("+{s}")
    }
}
