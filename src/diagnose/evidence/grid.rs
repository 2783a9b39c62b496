//! Quantization: values that lie on a grid (encoder counts, a DAC's steps).

use super::{lstsq, positive};
use std::f64::consts::TAU;

/// At most this many values (strided evenly) are sorted to find candidate quanta; the
/// share on the grid is then counted over all values.
const GRID_SAMPLE: usize = 1 << 16;

/// At most this many values (strided) score each candidate quantum before the best one is
/// checked on all values.
const GRID_CHECK: usize = 4096;

/// Share of values that must lie on a grid for it to count.
const MIN_ON_GRID: f64 = 0.9;

/// A grid the values lie on: v ≈ offset + k·quantum. The signature of quantization the
/// model lacks (or of a resolution the preset states wrongly).
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Grid spacing, in the values' unit.
    pub quantum: f64,
    /// Grid phase, 0 ≤ offset < quantum.
    pub offset: f64,
    /// Share of all values within ±tol·quantum of a grid line.
    pub on_grid: f64,
    /// Share expected on the grid by chance for values spread uniformly: 2·tol.
    pub by_chance: f64,
}

/// Finds the coarsest quantum ≥ min_quantum that the values lie on (within ±tol·quantum,
/// e.g. tol = 0.02; tol must lie in (0, 0.25)).
///
/// Candidate quanta are the most common difference between consecutive distinct sorted
/// values (within ±tol), the smallest one and their 2 %, 10 % and 30 % quantiles, each
/// divided by 1..=8, taken over all distinct values and again over the values that occur
/// more than once (off-grid values rarely recur, so these show the grid through scattered
/// outliers); differences below tol·min_quantum count as equal values. Candidates
/// are tried coarsest first on a strided subset of 4096 values; the first that puts ≥ 90 % there on a grid has its quantum and offset refined by
/// least squares of the values on their grid indices and is reported if ≥ 90 % of all
/// values lie on it. None for fewer than 10 values or 3 distinct ones, or if no quantum
/// fits. Weak where values are few and spread over many quanta (no difference is then a
/// small multiple of the quantum).
pub fn grid(values: &[f64], min_quantum: f64, tol: f64) -> Option<Grid> {
    if values.len() < 10 || !(min_quantum > 0.0 && min_quantum.is_finite()) {
        return None;
    }
    if !(tol > 0.0 && tol < 0.25) {
        return None;
    }
    let stride = values.len().div_ceil(GRID_SAMPLE).max(1);
    let mut sorted: Vec<f64> = values.iter().step_by(stride).copied().collect();
    sorted.sort_unstable_by(f64::total_cmp);
    let same = tol * min_quantum;
    // Distinct values with how often each occurs.
    let mut counted: Vec<(f64, usize)> = Vec::with_capacity(sorted.len());
    for &v in &sorted {
        match counted.last_mut() {
            Some(l) if v - l.0 <= same => l.1 += 1,
            _ => counted.push((v, 1)),
        }
    }
    let distinct: Vec<f64> = counted.iter().map(|c| c.0).collect();
    if distinct.len() < 3 {
        return None;
    }
    // Values that recur: a grid's values do, scattered off-grid values rarely.
    let recurring: Vec<f64> = counted.iter().filter(|c| c.1 > 1).map(|c| c.0).collect();
    let mut bases = bases_of(&distinct, tol);
    if recurring.len() >= 3 {
        bases.extend(bases_of(&recurring, tol));
    }
    let mut cands: Vec<f64> = bases
        .iter()
        .flat_map(|&b| (1..=8).map(move |j| b / j as f64))
        .filter(|&q| q >= min_quantum * (1.0 - tol) && q.is_finite())
        .collect();
    cands.sort_unstable_by(|a, b| b.total_cmp(a));
    cands.dedup_by(|a, b| (*a - *b).abs() <= tol * *b);
    let cstride = values.len().div_ceil(GRID_CHECK).max(1);
    let check: Vec<f64> = values.iter().step_by(cstride).copied().collect();
    for q in cands {
        let off = circular_offset(&check, q);
        if share_on(&check, q, off, tol) < MIN_ON_GRID {
            continue;
        }
        let (q2, off2) = refine(&distinct, q, off, tol).unwrap_or((q, off));
        let on_grid = share_on(values, q2, off2, tol);
        if on_grid >= MIN_ON_GRID && q2 >= min_quantum * (1.0 - tol) {
            return Some(Grid {
                quantum: q2,
                offset: off2,
                on_grid,
                by_chance: 2.0 * tol,
            });
        }
    }
    None
}

/// Candidate grid steps from sorted distinct values: the most common difference between
/// neighbours, the smallest, and their 2 %, 10 % and 30 % quantiles.
fn bases_of(v: &[f64], tol: f64) -> Vec<f64> {
    let mut diffs: Vec<f64> = v.windows(2).map(|w| w[1] - w[0]).collect();
    if diffs.is_empty() {
        return vec![];
    }
    diffs.sort_unstable_by(f64::total_cmp);
    let quantile = |q: f64| diffs[((diffs.len() - 1) as f64 * q) as usize];
    vec![
        mode(&diffs, tol),
        diffs[0],
        quantile(0.02),
        quantile(0.1),
        quantile(0.3),
    ]
}

/// The most common difference (sorted `d`): middle of the densest cluster of relative
/// width 2·tol. Off-grid values split grid steps at random places; the grid step itself
/// still clusters.
fn mode(d: &[f64], tol: f64) -> f64 {
    let (mut best, mut at) = (0, 0);
    let mut j = 0;
    for i in 0..d.len() {
        j = j.max(i);
        while j < d.len() && d[j] <= d[i] * (1.0 + 2.0 * tol) {
            j += 1;
        }
        if j - i > best {
            best = j - i;
            at = (i + j - 1) / 2;
        }
    }
    d[at]
}

/// Position within the quantum (0..q) of v, via its fractional grid index.
fn phase(v: f64, q: f64) -> f64 {
    let r = v / q;
    r - r.floor()
}

/// Grid offset (0..q) as the circular mean of the values' phases.
fn circular_offset(v: &[f64], q: f64) -> f64 {
    let (s, c) = v.iter().fold((0.0, 0.0), |(s, c), &x| {
        let (ps, pc) = (TAU * phase(x, q)).sin_cos();
        (s + ps, c + pc)
    });
    (s.atan2(c) / TAU).rem_euclid(1.0) * q
}

/// Share of v within ±tol·q of offset + k·q.
fn share_on(v: &[f64], q: f64, off: f64, tol: f64) -> f64 {
    let offp = off / q;
    let on = v
        .iter()
        .filter(|&&x| {
            let d = phase(x, q) - offp;
            (d - d.round()).abs() <= tol
        })
        .count();
    on as f64 / v.len().max(1) as f64
}

/// Quantum and offset by least squares of the on-grid values on their grid indices.
fn refine(v: &[f64], q: f64, off: f64, tol: f64) -> Option<(f64, f64)> {
    let base = *v.first()?;
    let k0 = ((base - off) / q).round();
    let mut ks = vec![];
    let mut ys = vec![];
    for &x in v {
        let d = phase(x, q) - off / q;
        if (d - d.round()).abs() <= tol {
            ks.push(((x - off) / q).round() - k0);
            ys.push(x - base);
        }
    }
    let fit = lstsq(ks.len(), 2, |i, j| if j == 0 { 1.0 } else { ks[i] }, &ys)?;
    let q2 = fit.coef[1];
    if !positive(q2) || (q2 / q - 1.0).abs() > tol {
        return None;
    }
    let off2 = (base + fit.coef[0]).rem_euclid(q2);
    Some((q2, if off2 >= q2 { 0.0 } else { off2 }))
}
