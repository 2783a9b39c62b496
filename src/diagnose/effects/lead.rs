//! Screw pitch (lead) error: a position error that is a function of the travel, periodic
//! along it (harmonics of a pitch the spectrum finds) or not (a table of knots along the
//! travel the record covered). Both are shaped by least squares on the position residual;
//! the criterion keeps the table only where it predicts better.

use super::{Candidate, Effect};
use crate::diagnose::DiagnoseError;
use crate::diagnose::criterion::Part;
use crate::diagnose::engine::Cand;
use crate::diagnose::evidence;
use crate::diagnose::fit::{Context, Detail, Evidence, Fixed, Shape, Variant};
use crate::preset::PosSource;
use crate::units::{m_to_mm, m_to_um, mm_to_m};

/// Harmonics fitted along the travel.
const HARMONICS: usize = 3;
/// Knot spacing of a table, per pitch the spectrum found, and its bounds in mm.
const KNOTS_PER_PITCH: f64 = 8.0;
const SPACING_MM: (f64, f64) = (2.0, 8.0);
/// Largest number of knots of a table (bounds the normal equations).
const MAX_KNOTS: usize = 400;
/// Weight of the second-difference penalty of a table, per unit of the mean number of
/// samples per knot: keeps knots that few samples see close to their neighbours.
const SMOOTHING: f64 = 0.05;
/// Samples the period is sharpened on at most (see `lead_period`).
const SHARPEN_ROWS: usize = 8192;
/// Commanded speed below which a sample counts as at rest in the direction term, m/s.
const DIR_SPEED_MPS: f64 = 1e-3;

/// Gives `c` the lead-error table `t` (position mm, error µm). A lead error the nominal did
/// not have starts from nothing: the preset's disabled cyclic and cumulative terms would
/// otherwise come on with the table.
pub fn set_table(c: &mut Cand, t: &[(f64, f64)]) {
    let l = &mut c.model.axis.lead_error;
    if !l.enabled {
        l.amplitude_um = 0.0;
        l.cumulative_um_per_m = 0.0;
    }
    l.enabled = true;
    l.table = t.to_vec();
}

/// The samples of `range` where the command does not accelerate (at most 1 % of its
/// largest acceleration): there the residual of a scale is the lead error itself.
fn quiet_rows(ctx: &Context, range: std::ops::Range<usize>) -> Vec<usize> {
    let sig = ctx.sig;
    let acc_max = sig.cmd_acc_mps2.iter().fold(0.0_f64, |m, a| m.max(a.abs()));
    range
        .filter(|&k| sig.cmd_acc_mps2[k].abs() <= 0.01 * acc_max)
        .collect()
}

/// The direction of travel the command gives sample `k`: a friction the model has in
/// another shape leaves the following error of each direction apart at the same place,
/// while a lead error is the same both ways; the table is fitted beside this term, which
/// is left out of the model.
fn travel_dir(ctx: &Context, k: usize) -> f64 {
    let v = ctx.sig.cmd_vel_mps.get(k).copied().unwrap_or(0.0);
    if v > DIR_SPEED_MPS {
        1.0
    } else if v < -DIR_SPEED_MPS {
        -1.0
    } else {
        0.0
    }
}

/// The period of the position residual along the travel, searched where the command holds
/// a feed and less each feed's mean residual (the dynamics' following error differs from
/// feed to feed and would show as long periods); the harmonics and the slope are then
/// fitted at that period on every sample.
fn lead_period(ctx: &Context) -> Option<evidence::PositionPeriodic> {
    let sig = ctx.sig;
    let n = sig.pos_m.len().min(sig.r_pos.len());
    let rows = quiet_rows(ctx, 0..n);
    if 2 * rows.len() < n {
        return evidence::periodic_in_position(
            &sig.pos_m[..n],
            &sig.r_pos[..n],
            mm_to_m(0.5),
            mm_to_m(60.0),
            HARMONICS,
        );
    }
    let feed_key = |k: usize| (m_to_mm(sig.cmd_vel_mps[k]) * 2.0).round() as i64;
    let mut means: std::collections::BTreeMap<i64, (f64, usize)> = Default::default();
    for &k in &rows {
        let e = means.entry(feed_key(k)).or_insert((0.0, 0));
        e.0 += sig.r_pos[k];
        e.1 += 1;
    }
    let (x, y): (Vec<f64>, Vec<f64>) = rows
        .iter()
        .map(|&k| {
            let (sum, count) = means.get(&feed_key(k)).copied().unwrap_or((0.0, 1));
            (sig.pos_m[k], sig.r_pos[k] - sum / count.max(1) as f64)
        })
        .unzip();
    let found = evidence::periodic_in_position(&x, &y, mm_to_m(0.5), mm_to_m(60.0), HARMONICS)?;
    let (lo, hi) = x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let span = (3.0 * found.period_m / (hi - lo)).min(0.05);
    // The period is sharpened on at most this many of the samples: its 57 harmonic fits
    // are most of the search, and a few thousand passes over the pitch fix it as well.
    let stride = x.len().div_ceil(SHARPEN_ROWS).max(1);
    let xs: Vec<f64> = x.iter().step_by(stride).copied().collect();
    let ys: Vec<f64> = y.iter().step_by(stride).copied().collect();
    let found = evidence::sharpen_period(&found, &xs, &ys, span, 41);
    let mut p = evidence::refit_at_period(&found, &sig.pos_m[..n], &sig.r_pos[..n])?;
    p.explained = found.explained;
    Some(p)
}

/// A table of knots along the travel of the quiet samples `rows`, fitted by penalised least
/// squares beside the direction offset, tapered to zero one knot beyond: the table
/// (position mm, error µm) and its effective number of parameters (the trace of the
/// smoother, which counts knots the penalty ties to their neighbours as less than one).
fn table_on(ctx: &Context, rows: &[usize], spacing_m: f64) -> Option<(Vec<(f64, f64)>, f64)> {
    let sig = ctx.sig;
    let (lo, hi) = rows
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &k| {
            (a.min(sig.pos_m[k]), b.max(sig.pos_m[k]))
        });
    if rows.len() < 100 || !(hi > lo && spacing_m > 0.0) {
        return None;
    }
    let m = (((hi - lo) / spacing_m).ceil() as usize).clamp(1, MAX_KNOTS - 1) + 1;
    let step = (hi - lo) / (m - 1) as f64;
    let mut ata = nalgebra::DMatrix::<f64>::zeros(m + 1, m + 1);
    let mut atb = nalgebra::DVector::<f64>::zeros(m + 1);
    for &k in rows {
        let u = ((sig.pos_m[k] - lo) / step).clamp(0.0, (m - 1) as f64);
        let i = (u.floor() as usize).min(m - 2);
        let f = u - i as f64;
        let s = travel_dir(ctx, k);
        for (a, wa) in [(i, 1.0 - f), (i + 1, f), (m, s)] {
            for (b, wb) in [(i, 1.0 - f), (i + 1, f), (m, s)] {
                ata[(a, b)] += wa * wb;
            }
            atb[a] += wa * sig.r_pos[k];
        }
    }
    let plain = ata.clone();
    let lambda = SMOOTHING * rows.len() as f64 / m as f64;
    for i in 1..m.saturating_sub(1) {
        let d = [(i - 1, 1.0), (i, -2.0), (i + 1, 1.0)];
        for (a, wa) in d {
            for (b, wb) in d {
                ata[(a, b)] += lambda * wa * wb;
            }
        }
    }
    for i in 0..=m {
        ata[(i, i)] += 1e-9 * lambda.max(1.0);
    }
    let chol = ata.cholesky()?;
    let x = chol.solve(&atb);
    // The direction column is left out of the model, so not counted.
    let hat = chol.solve(&plain);
    let dof = (0..m).map(|i| hat[(i, i)]).sum::<f64>();
    let mut table = vec![(m_to_mm(lo - step), 0.0)];
    table.extend((0..m).map(|i| (m_to_mm(lo + i as f64 * step), m_to_um(x[i]))));
    table.push((m_to_mm(hi + step), 0.0));
    (dof.is_finite() && table.iter().all(|(a, b)| a.is_finite() && b.is_finite()))
        .then_some((table, dof))
}

/// The harmonics of `p` as a table every 1/24 of a pitch over the record's travel.
fn harmonics_table(ctx: &Context, p: &evidence::PositionPeriodic) -> Vec<(f64, f64)> {
    let pos = &ctx.eng.split.main.pos_m;
    let (lo, hi) = pos
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let step = p.period_m / 24.0;
    let n = (((hi - lo) / step).ceil() as usize + 3).min(9_000);
    let x0 = lo - step;
    (0..n)
        .map(|i| {
            let x = x0 + i as f64 * step;
            (m_to_mm(x), m_to_um(p.at(x) - p.offset - p.slope_per_m * x0))
        })
        .collect()
}

/// The screw's pitch error.
pub struct Lead;

impl Candidate for Lead {
    fn effect(&self) -> Effect {
        Effect::LeadError
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        if ctx.base.model.pos_source == PosSource::MotorEncoder {
            return Evidence::absent(
                "the record's position is the motor encoder, which a lead error does not move",
            );
        }
        match lead_period(ctx) {
            Some(p) => Evidence {
                detail: Some(Detail::new(p.clone())),
                ..Evidence::found(
                p.peak_ratio >= 12.0 && p.explained >= 0.1,
                format!(
                    "the position residual repeats every {:.3} mm of travel, {:.2} µm at the fundamental, {:.0}× the median of its spectrum, {:.0} % of it explained",
                    m_to_mm(p.period_m),
                    m_to_um(p.amplitude),
                    p.peak_ratio,
                    100.0 * p.explained
                ),
            )
            .with("pitch_mm", m_to_mm(p.period_m))
            .with("amplitude_um", m_to_um(p.amplitude))
            .with("peak_ratio", p.peak_ratio)
            .with("explained_share", p.explained)
            },
            None => Evidence::found(false, "the position residual has no period along the travel"),
        }
    }

    fn variants(&self, ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let mut out = vec![];
        if let Some(p) = ev.detail::<evidence::PositionPeriodic>() {
            let table = harmonics_table(ctx, p);
            let mut keys = vec!["pitch_mm".to_owned(), "cumulative_um_per_m".to_owned()];
            let mut theta = vec![m_to_mm(p.period_m), p.slope_per_m * 1e6];
            for (k, (s, c)) in p.sin.iter().zip(&p.cos).enumerate() {
                keys.push(format!("h{}_sin_um", k + 1));
                keys.push(format!("h{}_cos_um", k + 1));
                theta.extend([m_to_um(*s), m_to_um(*c)]);
            }
            out.push(Variant::fixed(
                "harmonics",
                "harmonics of the pitch the spectrum found, and a slope along the travel",
                Fixed {
                    shape: Shape::LeadTable(table),
                    keys,
                    n_params: 2 + 2 * p.sin.len(),
                    theta,
                },
                Part::Held,
            ));
        }
        let pitch_mm = ev.figures.get("pitch_mm").copied().unwrap_or(0.0);
        let spacing_mm = (pitch_mm / KNOTS_PER_PITCH).clamp(SPACING_MM.0, SPACING_MM.1);
        let rows = quiet_rows(ctx, 0..ctx.sig.pos_m.len().min(ctx.sig.r_pos.len()));
        if let Some((table, dof)) = table_on(ctx, &rows, mm_to_m(spacing_mm)) {
            out.push(Variant::fixed(
                "table",
                format!(
                    "a table of knots every {spacing_mm:.1} mm along the travel the record covered"
                ),
                Fixed {
                    shape: Shape::LeadTable(table.clone()),
                    keys: vec![
                        "knot_spacing_mm".into(),
                        "table_points".into(),
                        "effective_parameters".into(),
                    ],
                    theta: vec![spacing_mm, table.len() as f64, dof],
                    n_params: dof.ceil() as usize,
                },
                Part::Held,
            ));
        }
        Ok(out)
    }
}
