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

use super::entry::{FileSpec, Plan, Put, with_unit};
use super::report::{Change, Pending};
use super::{Ctx, Violation, fixed, num, shared};
use crate::preset::comp::{CrossTable, OutputMode};
use crate::units::{s_to_ms, um_to_mm};

/// Entries a `.COM` table may hold.
pub const MAX_ENTRIES: usize = 256;

const CMA: &str = "CONFIG.CMA";
const MP: &str = "machine_parameters.txt";
/// Row key of a table's header line.
const HEADER: &str = "NR    ";

fn key(name: &str) -> String {
    name.to_uppercase()
}

fn signed(s: String) -> String {
    if s.starts_with('-') {
        s
    } else {
        format!("+{s}")
    }
}

/// Row key of row `n` of a table.
fn row(n: usize) -> String {
    format!("{n:<6}")
}

/// A column of a `.COM` table: header and one value (µm) per AXISPOS row.
struct Column {
    name: String,
    values_um: Vec<f64>,
}

impl Column {
    /// The column's cells in `file`: header, then one per row, in mm to 0.01 µm.
    fn puts(&self, file: &str) -> Vec<Put> {
        let mut out = vec![Put::new(file, "", HEADER, format!("{:>14}", self.name))];
        out.extend(self.values_um.iter().enumerate().map(|(n, v)| {
            Put::new(
                file,
                "",
                row(n),
                format!("{:>14}", signed(fixed(um_to_mm(*v), 5))),
            )
        }));
        out
    }
}

/// The export's one list and its files.
pub(crate) fn render(ctx: &Ctx) -> Result<Plan, Vec<Violation>> {
    let p = ctx.preset;
    let mut files = vec![
        FileSpec::new(CMA, "BEGIN CONFIG.CMA\n", "[END]\n"),
        FileSpec::new(
            MP,
            format!(
                "; HEIDENHAIN machine parameters exported by axisbench from preset '{}' (CfgAxisComp per axis)\n",
                p.name
            ),
            "",
        )
        .always(),
    ];
    let inputs: Vec<usize> = (0..p.axes.len())
        .filter(|&i| p.axes[i].lead_error.enabled || !crosses_from(ctx, i).is_empty())
        .collect();
    let mut violations = Vec::new();
    let mut entries = Vec::new();
    for (i, a) in p.axes.iter().enumerate() {
        if inputs.contains(&i) {
            let name = format!("{}.COM", key(&a.name));
            files.push(FileSpec::new(
                &name,
                format!("BEGIN {name} MM\n"),
                "[END]\n",
            ));
            match com_entries(ctx, i, inputs.last() == Some(&i)) {
                Ok(e) => entries.extend(e),
                Err(v) => violations.push(v),
            }
        }
        entries.extend(backlash_entries(ctx, i));
        entries.extend(shared::quadrant_omitted(
            ctx,
            i,
            "the TNC's reversal-peak compensation (MP_compStrength/MP_compWidth/MP_compTimeOffset) is a velocity-shaped pulse adapted to acceleration, not to the stroke; its units do not follow from M0/T0",
        ));
        entries.extend(shared::thermal_omitted(
            ctx,
            i,
            "a .COM table is static; thermal growth needs the PLC or KinematicsComp",
        ));
        entries.extend(shared::servo_entries(
            ctx,
            i,
            "the drive (machine parameters of the control loop)",
        ));
    }
    if violations.is_empty() {
        Ok(Plan { files, entries })
    } else {
        Err(violations)
    }
}

/// The enabled cross tables whose input (base) axis is axis `i`.
fn crosses_from<'a>(ctx: &'a Ctx, i: usize) -> Vec<(usize, &'a CrossTable)> {
    let name = &ctx.preset.axes[i].name;
    ctx.preset
        .cross
        .iter()
        .enumerate()
        .filter(|(_, t)| t.enabled && &t.base_axis == name)
        .collect()
}

/// The `.COM` table whose input is axis `i`: the AXISPOS grid (union of the points of its
/// lead-error table and the cross tables it drives, so every function stays exact) with
/// its CONFIG.CMA assignment, and one column per compensated axis. `last` = the last
/// input axis, which closes the CMA lines with the ACTIVE column.
fn com_entries(ctx: &Ctx, i: usize, last: bool) -> Result<Vec<Pending>, Violation> {
    let a = &ctx.preset.axes[i];
    let k = key(&a.name);
    let name = format!("{k}.COM");
    let pitch = a
        .lead_error
        .enabled
        .then(|| super::pitch_table(&a.lead_error, ctx.axes[i].travel_mm, MAX_ENTRIES, false));
    let crosses = crosses_from(ctx, i);
    let mut xs: Vec<f64> = pitch
        .iter()
        .flat_map(|t| t.points.iter().map(|p| p.0))
        .chain(
            crosses
                .iter()
                .flat_map(|(_, t)| t.points.iter().map(|p| p.0)),
        )
        .collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    if xs.len() > MAX_ENTRIES {
        return Err(Violation::new(
            format!("axes.{}", a.name),
            format!(
                "input of {name}: {} compensation points (lead-error table and cross tables {:?} on one AXISPOS grid); a .COM table holds at most {MAX_ENTRIES}",
                xs.len(),
                crosses.iter().map(|(ci, _)| *ci).collect::<Vec<_>>()
            ),
        ));
    }
    let mut grid_puts = vec![Put::new(&name, "", HEADER, format!("{:>14}", "AXISPOS"))];
    grid_puts.extend(
        xs.iter()
            .enumerate()
            .map(|(n, x)| Put::new(&name, "", row(n), format!("{:>14}", signed(fixed(*x, 4))))),
    );
    grid_puts.push(Put::new(CMA, "", HEADER, format!("{k:>12}")));
    grid_puts.push(Put::new(CMA, "", row(0), format!("{name:>12}")));
    if last {
        grid_puts.push(Put::new(CMA, "", HEADER, format!("{:>8}", "ACTIVE")));
        grid_puts.push(Put::new(CMA, "", row(0), format!("{:>8}", "*")));
    }
    let mut out = vec![
        Pending::derived(format!("axes.{}", a.name), format!("input axis {k}, {} points", xs.len()))
            .note(format!("the AXISPOS column of {name}: the union of the points of the tables on this input axis, so every function stays exact; CONFIG.CMA assigns {name} to input {k} (line 0 active)"))
            .puts(grid_puts),
    ];
    if let Some(pt) = &pitch {
        let onto_self: Vec<&CrossTable> = crosses
            .iter()
            .filter(|(_, t)| key(&t.comp_axis) == k)
            .map(|(_, t)| *t)
            .collect();
        out.push(pitch_column(ctx, i, pt, &xs, &name, &onto_self));
    }
    let own = pitch
        .is_some()
        .then(|| (k.clone(), format!("axes.{}.lead_error", a.name)));
    out.extend(cross_columns(&crosses, &xs, &name, own));
    Ok(out)
}

/// The lead-error column (the input axis's own), rounded to 0.01 µm; cross tables onto
/// the input axis itself (`extra`) add into it.
fn pitch_column(
    ctx: &Ctx,
    i: usize,
    pt: &super::PitchTable,
    xs: &[f64],
    file: &str,
    extra: &[&CrossTable],
) -> Pending {
    let a = &ctx.preset.axes[i];
    let pitch_um: Vec<f64> = xs
        .iter()
        .map(|&x| crate::table::interp(&pt.points, x))
        .collect();
    let col = Column {
        name: key(&a.name),
        values_um: xs
            .iter()
            .zip(&pitch_um)
            .map(|(&x, v)| {
                v + extra
                    .iter()
                    .map(|t| crate::table::interp(&t.points, x))
                    .sum::<f64>()
            })
            .collect(),
    };
    let grid: Vec<(f64, f64)> = xs
        .iter()
        .zip(&pitch_um)
        .map(|(&x, &v)| (x, (v * 100.0).round() / 100.0))
        .collect();
    let mut pt2 = pt.clone();
    pt2.residual_um = super::residual_um(&a.lead_error, &grid, ctx.axes[i].travel_mm);
    pt2.points = grid;
    shared::pitch_entry(ctx, i, &pt2, col.puts(file))
}

/// One column per compensated axis; several tables onto one axis from the same input add
/// up in one column, written by the first of them (`own` = the input axis's own column,
/// already written by the lead error, with its field).
fn cross_columns(
    crosses: &[(usize, &CrossTable)],
    xs: &[f64],
    file: &str,
    own: Option<(String, String)>,
) -> Vec<Pending> {
    let mut out: Vec<Pending> = Vec::new();
    // (column, the field whose row writes it)
    let mut written: Vec<(String, String)> = own.into_iter().collect();
    for (ci, t) in crosses {
        let ck = key(&t.comp_axis);
        let e = Pending::mapped(format!("cross.{ci}"), shared::cross_value(t));
        let same: Vec<&(usize, &CrossTable)> = crosses
            .iter()
            .filter(|(_, u)| key(&u.comp_axis) == ck)
            .collect();
        out.push(match written.iter().find(|(c, _)| *c == ck) {
            Some((_, by)) => e.note(format!(
                "added into column {ck} of {file}, which the row of {by} writes (tables onto one axis from one input add up)"
            )),
            None => {
                let col = Column {
                    name: ck.clone(),
                    values_um: xs
                        .iter()
                        .map(|&x| same.iter().map(|(_, u)| crate::table::interp(&u.points, x)).sum())
                        .collect(),
                };
                written.push((ck.clone(), format!("cross.{ci}")));
                e.note(format!("{file} column {ck} (AXISPOS = the input axis): same points, µm → mm to 0.01 µm; several tables onto one axis from the same input add up in one column"))
                    .puts(col.puts(file))
            }
        });
    }
    out
}

/// MP_backLash and MP_filterTime: a filter time only when both directions spread the
/// backlash over the same number of periods (the TNC traverses it alike both ways).
fn backlash_entries(ctx: &Ctx, i: usize) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    let b = &a.backlash;
    if !b.enabled {
        return vec![];
    }
    let k = key(&a.name);
    let mp = |name: &str, v: String, unit: &str| {
        Put::new(MP, "", format!("{k}: {name} = "), format!("{v} ; {unit}"))
    };
    let both_time = b.plus_to_minus.mode == OutputMode::Time
        && b.minus_to_plus.mode == OutputMode::Time
        && b.plus_to_minus.cycles_m == b.minus_to_plus.cycles_m;
    let filter_ms = s_to_ms(b.plus_to_minus.cycles_m as f64 * ctx.preset.timing.t2_s);
    let (field, value) = shared::backlash_q(a);
    let mut amount = Pending::mapped(field, value)
        .note("MP_backLash (mm), added at every reversal")
        .put(mp("MP_backLash", num(um_to_mm(b.q_um)), "mm"));
    if !both_time {
        amount = amount.put(mp("MP_filterTime", "0".into(), "ms"));
        let mut out = vec![amount];
        out.extend(shared::backlash_modes_as_lump(
            ctx,
            i,
            "the TNC (MP_filterTime = 0; a filter time spreads both directions alike)",
        ));
        return out;
    }
    let sim = Change::Backlash {
        axis: i,
        params: Some(b.clone()),
    };
    vec![
        amount,
        Pending::approximated(
            format!("axes.{}.backlash.plus_to_minus.mode", a.name),
            shared::direction_text(&b.plus_to_minus),
        )
        .note("the TNC traverses the backlash over MP_filterTime (M generation periods) in both directions")
        .put(mp("MP_filterTime", num(filter_ms), "ms"))
        .sim(vec![sim], vec![i], false),
        Pending::approximated(
            format!("axes.{}.backlash.minus_to_plus.mode", a.name),
            shared::direction_text(&b.minus_to_plus),
        )
        .note(format!(
            "the same MP_filterTime = {} as the row above (one filter time for both directions)",
            with_unit(filter_ms, "ms")
        )),
    ]
}
