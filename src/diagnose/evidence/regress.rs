//! Linear regression on named signature columns (friction: sign(v), v, Stribeck term, …).

use super::{centered_ss, lstsq, strided_rows};

/// Least-squares regression result: how much of y each signature column carries, and how
/// sure that is.
#[derive(Debug, Clone, PartialEq)]
pub struct Regression {
    /// One coefficient per column, in the order given.
    pub coef: Vec<f64>,
    /// One standard error per coefficient: from the residual variance, inflated by
    /// sqrt(correlation length in used rows); infinite for a coefficient the data cannot
    /// determine (its column is zero or a combination of the others).
    pub stderr: Vec<f64>,
    /// Share of y's variance (about its mean) explained, 0..1.
    pub explained: f64,
}

/// y less the fit `Σ columns[j]·coef[j]` of a [`Regression`], over the pairs of columns
/// and coefficients: passing only the first columns keeps the other fitted terms in y. A
/// column shorter than y counts as zero past its end.
pub fn minus_fit(y: &[f64], columns: &[&[f64]], coef: &[f64]) -> Vec<f64> {
    y.iter()
        .enumerate()
        .map(|(k, v)| {
            v - columns
                .iter()
                .zip(coef)
                .map(|(c, b)| c.get(k).map_or(0.0, |x| x * b))
                .sum::<f64>()
        })
        .collect()
}

/// Least-squares regression of y on the given columns (each as long as y; add a column of
/// ones for an intercept), solved by nalgebra's SVD on columns scaled to unit RMS
/// (dependent columns get the minimum-norm solution and infinite standard errors).
///
/// Rows are strided evenly to at most [`super::ROW_CAP`] (32 768); `corr_len` is the
/// residual's correlation length in original samples, so the standard errors are inflated
/// by sqrt(max(1, corr_len / stride)) (neighbouring rows carry less than independent
/// information). None without columns, with columns of another length than y, or with
/// fewer rows than columns + 1.
pub fn regress(columns: &[&[f64]], y: &[f64], corr_len: f64) -> Option<Regression> {
    let p = columns.len();
    let n = y.len();
    if p == 0 || columns.iter().any(|c| c.len() != n) {
        return None;
    }
    let (rows, stride) = strided_rows(n);
    let m = rows.len();
    if m < p + 1 {
        return None;
    }
    let (ys, scale) = match super::normalized(&rows.iter().map(|&r| y[r]).collect::<Vec<_>>()) {
        Some(v) => v,
        // All-zero y: every coefficient is zero, explained nothing.
        None => (vec![0.0; m], 1.0),
    };
    let fit = lstsq(m, p, |i, j| columns[j][rows[i]], &ys)?;
    let dof = (m - p) as f64;
    let sigma2 = fit.ss_res / dof;
    let inflate = if corr_len.is_finite() {
        (corr_len / stride as f64).max(1.0)
    } else {
        1.0
    };
    let stderr = fit
        .var_unit
        .iter()
        .map(|&v| {
            if v.is_finite() {
                (v * sigma2 * inflate).sqrt() * scale
            } else {
                f64::INFINITY
            }
        })
        .collect();
    let ss_tot = centered_ss(&ys);
    let explained = if ss_tot > 0.0 {
        (1.0 - fit.ss_res / ss_tot).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let coef: Vec<f64> = fit.coef.iter().map(|c| c * scale).collect();
    coef.iter().all(|c| c.is_finite()).then_some(Regression {
        coef,
        stderr,
        explained,
    })
}
