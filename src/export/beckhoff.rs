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

use super::entry::{FileSpec, Plan, Put, with_unit};
use super::report::{ErrFigures, Pending};
use super::{Ctx, Violation, fixed, shared};
use crate::preset::comp::CrossTable;
use crate::units::um_to_mm;

/// `kw.crosscomp.max_points` default: `last_index` must stay below it.
pub const CROSS_MAX_POINTS: usize = 1001;

/// Tenths of a micrometre per millimetre: the lists' length unit (unit 1).
const TENTH_UM_PER_MM: f64 = 10_000.0;

fn tenth_um(mm: f64) -> i64 {
    (mm * TENTH_UM_PER_MM).round() as i64
}

fn file(nr: usize) -> String {
    format!("achskw_{nr}.lis")
}

/// A `name value` line of axis `nr`'s list, the values in one column.
fn line(nr: usize, name: &str, value: impl std::fmt::Display) -> Put {
    Put::new(file(nr), "", format!("{name:<33} "), value.to_string())
}

/// The export's one list and its files.
pub(crate) fn render(ctx: &Ctx) -> Result<Plan, Vec<Violation>> {
    let p = ctx.preset;
    let mut files = Vec::new();
    let mut violations = Vec::new();
    let mut keep = vec![false; p.cross.len()];
    let mut entries = vec![
        Pending::undocumented("nc.rapid_mm_per_min", with_unit(p.nc.rapid_mm_per_min, "mm/min"))
            .note("axis dynamics live in the axis machine data, not in the compensation lists; no parameter is written"),
        Pending::undocumented("nc.accdec", format!("{:?}", p.nc.accdec.kind).to_lowercase())
            .note("axis dynamics live in the axis machine data, not in the compensation lists; no parameter is written"),
    ];
    for (i, a) in p.axes.iter().enumerate() {
        let nr = i + 1;
        files.push(FileSpec::new(
            file(nr),
            format!(
                "# TwinCAT CNC compensation value list exported by axisbench from preset '{}'\n# lengths in 0.1 um (unit 1)\n",
                p.name
            ),
            "",
        ));
        let cross = match cross_entry(ctx, i) {
            Ok(c) => c,
            Err(v) => {
                violations.push(v);
                None
            }
        };
        let ssfk = ssfk_entries(ctx, i);
        if !ssfk.is_empty() || cross.is_some() {
            entries.push(
                Pending::mapped(
                    format!("axes.{}.name", a.name),
                    format!("{} (axis {nr})", a.name),
                )
                .note("list header: logical axis number (P-COMP-00001) and name (P-COMP-00002)")
                .puts([
                    line(nr, "kopf.achs_nr", nr),
                    line(nr, "kopf.log_achs_name", a.name.to_uppercase()),
                ]),
            );
        }
        entries.extend(ssfk);
        if let Some((ci, e)) = cross {
            keep[ci] = true;
            entries.push(e);
        }
        entries.extend(shared::quadrant_omitted(
            ctx,
            i,
            "the ISG friction compensation (frict_comp.*) is a velocity-dependent current table, not a reversal pulse adapted to the stroke",
        ));
        entries.extend(shared::thermal_omitted(
            ctx,
            i,
            "the compensation lists are static",
        ));
        entries.extend(shared::servo_entries(
            ctx,
            i,
            "the axis machine data and the drive",
        ));
    }
    entries.extend(shared::cross_omitted(
        ctx,
        &keep,
        "a slave axis's list holds one kw.crosscomp table with one master axis",
    ));
    if violations.is_empty() {
        Ok(Plan { files, entries })
    } else {
        Err(violations)
    }
}

/// The bilateral leadscrew table of axis `i` rounded to 0.1 µm: (setpoint, pos, neg) with
/// neg = pos − Q; a zero table over the travel when only backlash is to be carried.
fn ssfk_table(ctx: &Ctx, i: usize) -> Vec<(i64, i64, i64)> {
    let a = &ctx.preset.axes[i];
    let b = &a.backlash;
    let q_mm = if b.enabled { um_to_mm(b.q_um) } else { 0.0 };
    let points: Vec<(f64, f64)> = if a.lead_error.enabled {
        super::pitch_table(&a.lead_error, ctx.axes[i].travel_mm, 1000, false).points
    } else {
        let (lo, hi) = ctx.axes[i].travel_mm;
        vec![(lo, 0.0), (hi, 0.0)]
    };
    points
        .iter()
        .map(|&(x, c)| {
            let c_mm = um_to_mm(c);
            (tenth_um(x), tenth_um(c_mm), tenth_um(c_mm - q_mm))
        })
        .collect()
}

/// Lines of the leadscrew table: the header and the setpoint and `.pos` columns, or the
/// `.neg` column.
fn ssfk_puts(nr: usize, t: &[(i64, i64, i64)], neg: bool) -> Vec<Put> {
    if neg {
        return t
            .iter()
            .enumerate()
            .map(|(n, r)| line(nr, &format!("kw.ssfk.table[{n}].neg"), r.2))
            .collect();
    }
    let mut out = vec![
        line(nr, "kw.ssfk.unit", 1),
        line(nr, "kw.ssfk.interval", 0),
        line(nr, "kw.ssfk.kw_startpos", t.first().map_or(0, |r| r.0)),
        line(nr, "kw.ssfk.kw_nr_max", t.len()),
        line(nr, "kw.ssfk.bilateral", 1),
    ];
    out.extend(
        t.iter()
            .enumerate()
            .map(|(n, r)| line(nr, &format!("kw.ssfk.table[{n}].setpoint"), r.0)),
    );
    out.extend(
        t.iter()
            .enumerate()
            .map(|(n, r)| line(nr, &format!("kw.ssfk.table[{n}].pos"), r.1)),
    );
    out
}

/// The leadscrew table's entries: the lead error (header, setpoints, `.pos`) and the
/// backlash (`.neg` = `.pos` − Q); without a lead error the backlash writes it all.
fn ssfk_entries(ctx: &Ctx, i: usize) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    let b = &a.backlash;
    if !a.lead_error.enabled && !b.enabled {
        return vec![];
    }
    let nr = i + 1;
    let t = ssfk_table(ctx, i);
    let mut out = Vec::new();
    if a.lead_error.enabled {
        let grid: Vec<(f64, f64)> = t
            .iter()
            .map(|r| (r.0 as f64 / TENTH_UM_PER_MM, r.1 as f64 * 0.1))
            .collect();
        let pt = super::PitchTable {
            residual_um: super::residual_um(&a.lead_error, &grid, ctx.axes[i].travel_mm),
            points: grid,
            equidistant: false,
        };
        let mut puts = ssfk_puts(nr, &t, false);
        if !b.enabled {
            puts.extend(ssfk_puts(nr, &t, true)); // .neg = .pos
        }
        out.push(shared::pitch_entry(ctx, i, &pt, puts));
    }
    if b.enabled {
        let mut puts = Vec::new();
        if !a.lead_error.enabled {
            puts.extend(ssfk_puts(nr, &t, false)); // a zero table carrying only Q
        }
        puts.extend(ssfk_puts(nr, &t, true));
        out.push(backlash_entry(ctx, i, puts));
        out.extend(shared::backlash_modes_as_lump(
            ctx,
            i,
            "The bilateral table",
        ));
    }
    out
}

/// The backlash amount, carried by the bilateral table's `.neg` column (0.1 µm).
fn backlash_entry(ctx: &Ctx, i: usize, puts: Vec<Put>) -> Pending {
    let a = &ctx.preset.axes[i];
    let b = &a.backlash;
    let q_r = tenth_um(um_to_mm(b.q_um)) as f64 * 0.1;
    let (field, value) = shared::backlash_q(a);
    let note = "per direction in the bilateral leadscrew table (kw.ssfk, bilateral 1): + direction as measured, − direction −Q (axisbench's one-sided convention, + as reference), switched at the reversal";
    if (q_r - b.q_um).abs() < 1e-9 {
        Pending::mapped(field, value).note(note).puts(puts)
    } else {
        Pending::approximated(field, value)
            .note(format!("{note}; rounded to 0.1 µm"))
            .puts(puts)
            .evaluated(ErrFigures::evaluated(
                "rounding to the list's 0.1 µm unit",
                (q_r - b.q_um).abs(),
            ))
    }
}

/// The cross compensation into axis `i`: one master per slave list, the first enabled
/// table; Ok(None) when there is none (or it is empty: the preset validation says so).
fn cross_entry(ctx: &Ctx, i: usize) -> Result<Option<(usize, Pending)>, Violation> {
    let p = ctx.preset;
    let into: Vec<(usize, &CrossTable)> = super::cross_into(p, &p.axes[i].name);
    let Some((ci, t)) = into.first().filter(|(_, t)| !t.points.is_empty()) else {
        return Ok(None);
    };
    if t.points.len() > CROSS_MAX_POINTS {
        return Err(Violation::new(
            format!("cross.{ci}.points"),
            format!(
                "{} points; kw.crosscomp.last_index must stay below max_points = {CROSS_MAX_POINTS} (P-COMP-00060)",
                t.points.len()
            ),
        ));
    }
    let nr = i + 1;
    let master = super::axis_index(p, &t.base_axis) + 1;
    let mut puts = vec![
        line(nr, "kw.crosscomp.unit", 1),
        line(nr, "kw.crosscomp.last_index", t.points.len() - 1),
        line(nr, "kw.crosscomp.master_ax_nr", master),
    ];
    let mut resid: f64 = 0.0;
    for (n, &(x, c)) in t.points.iter().enumerate() {
        let cr = tenth_um(um_to_mm(c));
        resid = resid.max((cr as f64 * 0.1 - c).abs());
        puts.push(line(
            nr,
            &format!("kw.crosscomp.table[{n}].setpoint"),
            tenth_um(x),
        ));
        puts.push(line(nr, &format!("kw.crosscomp.table[{n}].correction"), cr));
    }
    let field = format!("cross.{ci}");
    let value = shared::cross_value(t);
    let note = format!(
        "achskw_{nr}.lis kw.crosscomp with master axis {master}, in 0.1 µm; activated by P-AXIS-00047 lr_param.crosscomp = 1 in axis {nr}'s machine data"
    );
    let e = if resid < 1e-9 {
        Pending::mapped(field, value).note(note).puts(puts)
    } else {
        Pending::approximated(field, value)
            .note(format!("{note}; rounded to 0.1 µm"))
            .puts(puts)
            .evaluated(ErrFigures::evaluated(
                format!("rounding to 0.1 µm: {}", fixed(resid, 3)),
                resid,
            ))
    };
    Ok(Some((*ci, e)))
}
