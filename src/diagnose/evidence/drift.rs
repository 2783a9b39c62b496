//! Slow drift: a residual that creeps over the record (thermal growth of a screw or frame).

use super::{centered_ss, golden_max, lstsq, normalized, positive};

/// At most this many low-pass blocks are fitted.
const BLOCKS_MAX: usize = 4096;

/// At least this many blocks (shorter records get blocks shorter than 1 s).
const BLOCKS_MIN: usize = 16;

/// Number of time constants on the initial log grid.
const TAU_GRID: usize = 40;

/// Slow drift of y against time: how much, how fast, and whether a driver (e.g. the
/// dissipated energy) explains it better than time does.
#[derive(Debug, Clone, PartialEq)]
pub struct Drift {
    /// Exponential: its full amplitude d (the change as t → ∞); line: the fitted change
    /// over the record; driver: d × the driver's change over the record. In y's unit.
    pub magnitude: f64,
    /// The fitted change from the record's first to its last block, whatever the model
    /// (well determined even when d and τ of a slow exponential are not).
    pub change: f64,
    /// Time constant of the exponential, s; None for the line and the driver.
    pub tau_s: Option<f64>,
    /// True when y ≈ c + d·driver explains the drift best.
    pub by_driver: bool,
    /// Share of the low-passed y's variance the model explains, 0..1.
    pub explained: f64,
}

/// Slow drift of y against t_s (ascending): low-passes y by means over blocks of ~1 s
/// (between 16 and 4096 blocks), then fits y ≈ c + d·(1 − exp(−(t − t₀)/τ)) over 40
/// log-spaced τ from record/50 to 10× the record (refined by 20 golden steps in log τ),
/// the straight line y ≈ c + s·t, and, with a driver series of the same length,
/// y ≈ c + d·driver. The exponential wins over the line only if its extra parameter
/// lowers the residual by more than 4 residual variances (an F-test at ~2σ: a slow
/// exponential is nearly a line); the driver wins if it leaves less residual than the
/// chosen time model.
///
/// None when lengths differ, n < 16, time does not advance or y is constant.
pub fn drift(t_s: &[f64], y: &[f64], driver: Option<&[f64]>) -> Option<Drift> {
    let n = y.len();
    if t_s.len() != n || n < BLOCKS_MIN || driver.is_some_and(|d| d.len() != n) {
        return None;
    }
    let span = t_s[n - 1] - t_s[0];
    if !(span > 0.0 && span.is_finite()) {
        return None;
    }
    let (ys, scale) = normalized(y)?;
    let per_s = ((n - 1) as f64 / span).round();
    let per_s = if per_s.is_finite() && per_s >= 1.0 {
        per_s.min(n as f64) as usize
    } else {
        1
    };
    let b = per_s.max(n.div_ceil(BLOCKS_MAX)).min(n / BLOCKS_MIN).max(1);
    let blocks = |v: &[f64]| -> Vec<f64> { v.chunks_exact(b).map(super::mean).collect() };
    let tb: Vec<f64> = blocks(t_s).iter().map(|t| t - t_s[0]).collect();
    let yb = blocks(&ys);
    let m = yb.len();
    let ss_tot = centered_ss(&yb);
    if m < 4 || !positive(ss_tot) {
        return None;
    }
    let range = tb[m - 1] - tb[0];
    let line = lstsq(m, 2, |i, j| if j == 0 { 1.0 } else { tb[i] }, &yb)?;
    let slope = line.coef[1];
    let mut best = (
        line.ss_res,
        Drift {
            magnitude: slope * span,
            change: slope * range,
            tau_s: None,
            by_driver: false,
            explained: 0.0,
        },
    );
    if let Some((ss, d, tau)) = best_exponential(&tb, &yb, span) {
        let dof = m.saturating_sub(3).max(1) as f64;
        if line.ss_res - ss > 4.0 * ss / dof {
            let u = |t: f64| 1.0 - (-t / tau).exp();
            best = (
                ss,
                Drift {
                    magnitude: d,
                    change: d * (u(tb[m - 1]) - u(tb[0])),
                    tau_s: Some(tau),
                    by_driver: false,
                    explained: 0.0,
                },
            );
        }
    }
    if let Some((dn, _)) = driver.and_then(normalized) {
        let db = blocks(&dn);
        let fit = lstsq(m, 2, |i, j| if j == 0 { 1.0 } else { db[i] }, &yb);
        if let Some(fit) = fit.filter(|f| f.ss_res < best.0) {
            let change = fit.coef[1] * (db[m - 1] - db[0]);
            best = (
                fit.ss_res,
                Drift {
                    magnitude: change,
                    change,
                    tau_s: None,
                    by_driver: true,
                    explained: 0.0,
                },
            );
        }
    }
    let (ss, mut out) = best;
    out.explained = (1.0 - ss / ss_tot).clamp(0.0, 1.0);
    out.magnitude *= scale;
    out.change *= scale;
    (out.magnitude.is_finite() && out.change.is_finite()).then_some(out)
}

/// Best c + d·(1 − exp(−t/τ)) over τ: (residual SS, d, τ).
fn best_exponential(t: &[f64], y: &[f64], span: f64) -> Option<(f64, f64, f64)> {
    let fit = |log_tau: f64| {
        let tau = log_tau.exp();
        lstsq(
            t.len(),
            2,
            |i, j| {
                if j == 0 {
                    1.0
                } else {
                    1.0 - (-t[i] / tau).exp()
                }
            },
            y,
        )
        .map(|f| (f.ss_res, f.coef[1], tau))
    };
    let (lo, hi) = ((span / 50.0).ln(), (span * 10.0).ln());
    let step = (hi - lo) / (TAU_GRID - 1) as f64;
    let i_best = (0..TAU_GRID)
        .filter_map(|i| fit(lo + step * i as f64).map(|f| (i, f.0)))
        .min_by(|a, b| a.1.total_cmp(&b.1))?
        .0;
    let c = lo + step * i_best as f64;
    let (log_tau, _) = golden_max(
        |lt| fit(lt).map_or(f64::NEG_INFINITY, |f| -f.0),
        (c - step).max(lo),
        (c + step).min(hi),
        20,
    );
    let refined = fit(log_tau)?;
    let grid = fit(c)?;
    Some(if refined.0 <= grid.0 { refined } else { grid })
}
