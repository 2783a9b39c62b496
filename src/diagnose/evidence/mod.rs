//! Signature tests for the diagnosis: pure signal-processing detectors, one per kind of
//! unmodelled effect. The diagnosis runs them on residuals (measured − simulated) and on the
//! measured signals to back a fitted effect with a figure that does not come from the fit
//! itself (a periodic residual against position for lead error, a grid of values for
//! quantization, a slow exponential for thermal drift, …).
//!
//! Everything is in SI units. The detectors never panic: inputs they cannot judge (empty,
//! too short, constant, inconsistent arguments) give `None` or an empty list. Inputs are
//! assumed finite (the caller checks); extreme magnitudes are handled by normalizing by the
//! largest |value| first, so sums of squares cannot overflow.
//!
//! Work is capped so that each detector takes a few milliseconds on a 60 000-sample record
//! and stays bounded on 1 000 000 samples; each function documents its caps. The common
//! ones are [`TIME_CAP`] samples for spectra in time and [`ROW_CAP`] rows for least squares.

mod drift;
mod grid;
mod periodic;
mod position;
mod regress;
mod resonance;
mod steps;

pub use drift::{Drift, drift};
pub use grid::{Grid, grid};
pub use periodic::{Periodic, WaveShape, periodic_in_time};
pub use position::{PositionPeriodic, periodic_in_position, refit_at_period, sharpen_period};
pub use regress::{Regression, minus_fit, regress};
pub use resonance::{
    RINGING_STEP_SHARE, RINGING_T, Resonance, Ringing, Tone, resonance, ringing, tone,
};
pub use steps::{Burst, Step, bursts, steps, steps_to_end};

use nalgebra::{DMatrix, DVector, SVD};
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use std::cell::RefCell;
use std::sync::Arc;

/// At most this many samples enter a spectrum in time (longer records are block-averaged,
/// or cut where averaging would hide the shortest period searched): bounds FFT time and
/// memory for 1M-sample records.
pub const TIME_CAP: usize = 1 << 16;

/// At most this many rows enter a least-squares fit (longer inputs are strided evenly):
/// bounds the SVD's time and memory; 32k rows leave the statistical error far below the
/// effects the diagnosis looks for.
pub const ROW_CAP: usize = 1 << 15;

/// Largest FFT length used anywhere (zero-padded periodograms).
const FFT_CAP: usize = 1 << 19;

/// v > 0, false for NaN: guards written with it reject NaN as well.
fn positive(v: f64) -> bool {
    v > 0.0
}

/// lo ≤ hi, false if either is NaN.
fn ordered(lo: f64, hi: f64) -> bool {
    lo <= hi
}

/// Largest |v|, or None when it is zero or not finite: the scale by which a detector
/// normalizes its input so that squares and sums cannot overflow.
fn scale_of(y: &[f64]) -> Option<f64> {
    let s = y.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    (s > 0.0 && s.is_finite()).then_some(s)
}

/// y divided by its largest |value| (see [`scale_of`]), with that scale.
fn normalized(y: &[f64]) -> Option<(Vec<f64>, f64)> {
    let s = scale_of(y)?;
    Some((y.iter().map(|v| v / s).collect(), s))
}

fn mean(y: &[f64]) -> f64 {
    if y.is_empty() {
        0.0
    } else {
        y.iter().sum::<f64>() / y.len() as f64
    }
}

/// Sum of squared deviations from the mean.
fn centered_ss(y: &[f64]) -> f64 {
    let m = mean(y);
    y.iter().map(|v| (v - m) * (v - m)).sum()
}

/// Median (reorders `v`); 0 for an empty slice.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

/// Degree of the polynomial removed before a spectrum: a straight line plus the bow and
/// S-shape of slow drifts, whose leakage would otherwise pile up at the longest periods.
/// Harmonics with ≥ 2 periods in the record lose at most a few percent to it.
const TREND_DEGREE: usize = 3;

/// y minus its least-squares cubic over the sample index (fitted on rows strided to
/// [`ROW_CAP`]), with the cubic's value at the middle of the record.
fn detrend(y: &[f64]) -> Option<(Vec<f64>, f64)> {
    let n = y.len();
    let half = ((n as f64 - 1.0) / 2.0).max(0.5);
    let x = |k: usize| (k as f64 - half) / half;
    let (rows, _) = strided_rows(n);
    let ys: Vec<f64> = rows.iter().map(|&r| y[r]).collect();
    let fit = lstsq(
        rows.len(),
        TREND_DEGREE + 1,
        |i, j| x(rows[i]).powi(j as i32),
        &ys,
    )?;
    let poly = |k: usize| {
        let xk = x(k);
        fit.coef.iter().rev().fold(0.0, |acc, c| acc * xk + c)
    };
    let det = y.iter().enumerate().map(|(k, v)| v - poly(k)).collect();
    Some((det, fit.coef[0]))
}

thread_local! {
    /// Planned FFTs are cached per thread: planning (twiddle factors) costs as much as a
    /// transform, and the detectors use a few power-of-two lengths (≤ [`FFT_CAP`], so the
    /// cache holds at most ~20 plans).
    static PLANNER: RefCell<FftPlanner<f64>> = RefCell::new(FftPlanner::new());
}

/// A forward FFT of length `len` from the per-thread planner.
fn fft_forward(len: usize) -> Arc<dyn Fft<f64>> {
    PLANNER.with(|p| p.borrow_mut().plan_fft_forward(len))
}

/// One-sided power |X_k|² for k = 0..=nfft/2 of y zero-padded to `nfft` (y is cut to nfft).
fn power_spectrum(y: &[f64], nfft: usize) -> Vec<f64> {
    let mut buf: Vec<Complex<f64>> = y.iter().take(nfft).map(|&v| Complex::new(v, 0.0)).collect();
    buf.resize(nfft, Complex::new(0.0, 0.0));
    fft_forward(nfft).process(&mut buf);
    buf.iter()
        .take(nfft / 2 + 1)
        .map(|c| c.norm_sqr())
        .collect()
}

/// Zero-padded FFT length for n samples: 2× the next power of two, within [`FFT_CAP`]
/// (peaks are refined between bins afterwards).
fn padded_len(n: usize) -> usize {
    (n.max(2).next_power_of_two() * 2).min(FFT_CAP)
}

/// Vertex offset (−0.5..0.5 bins) of the parabola through three neighbouring values.
fn parabolic(left: f64, mid: f64, right: f64) -> f64 {
    let den = left - 2.0 * mid + right;
    if den < 0.0 {
        (0.5 * (left - right) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

/// Maximum of a unimodal `f` on [lo, hi] by golden-section search (`iters` steps).
fn golden_max(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64, iters: usize) -> (f64, f64) {
    const R: f64 = 0.618_033_988_749_894_8;
    let mut x1 = hi - R * (hi - lo);
    let mut x2 = lo + R * (hi - lo);
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..iters {
        if f1 >= f2 {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - R * (hi - lo);
            f1 = f(x1);
        } else {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + R * (hi - lo);
            f2 = f(x2);
        }
    }
    if f1 >= f2 { (x1, f1) } else { (x2, f2) }
}

/// |Σ y_k e^{−iωk}|² at ω rad/sample (the periodogram between FFT bins), by a rotating
/// phasor re-anchored every 1024 samples so rounding cannot accumulate.
fn dtft_power(y: &[f64], omega: f64) -> f64 {
    let mut acc = Complex::new(0.0, 0.0);
    let step = Complex::from_polar(1.0, -omega);
    for (c, chunk) in y.chunks(1024).enumerate() {
        let mut z = Complex::from_polar(1.0, -omega * (c * 1024) as f64);
        for &v in chunk {
            acc += z * v;
            z *= step;
        }
    }
    acc.norm_sqr()
}

/// Least-squares solution of a small problem.
struct LsFit {
    coef: Vec<f64>,
    /// Residual sum of squares.
    ss_res: f64,
    /// (XᵀX)⁻¹ diagonal: the coefficients' variances per unit residual variance; infinite
    /// for a coefficient the data cannot determine (a column dependent on the others).
    var_unit: Vec<f64>,
}

/// Solves y ≈ X·c (X: `rows` × `cols`, given by `x(row, col)`) after scaling each column
/// to unit RMS: nalgebra's Householder QR reduces the tall problem to R·c ≈ Qᵀy (cols ×
/// cols), which nalgebra's SVD then solves; singular values below 1e-10 of the largest
/// count as zero (minimum-norm solution). QR first keeps the SVD's rotations off the
/// 32k-row matrix.
fn lstsq(rows: usize, cols: usize, x: impl Fn(usize, usize) -> f64, y: &[f64]) -> Option<LsFit> {
    if cols == 0 || rows < cols || y.len() < rows {
        return None;
    }
    let mut a = DMatrix::from_fn(rows, cols, &x);
    let mut norms = vec![0.0; cols];
    for (j, norm) in norms.iter_mut().enumerate() {
        let peak = a.column(j).amax();
        let rms = if peak > 0.0 {
            (a.column(j).map(|v| (v / peak) * (v / peak)).sum() / rows as f64).sqrt() * peak
        } else {
            0.0
        };
        *norm = if rms > 0.0 && rms.is_finite() {
            rms
        } else {
            1.0
        };
        a.column_mut(j).scale_mut(1.0 / *norm);
    }
    let mut qtb = DVector::from_column_slice(&y[..rows]);
    let qr = a.qr();
    qr.q_tr_mul(&mut qtb);
    let r = qr.unpack_r();
    let top = qtb.rows(0, cols).into_owned();
    let svd = SVD::try_new_unordered(r.clone(), true, true, f64::EPSILON, 2000)?;
    let smax = svd.singular_values.max();
    if !(smax > 0.0 && smax.is_finite()) {
        return None;
    }
    let eps = smax * 1e-10;
    let sol = svd.solve(&top, eps).ok()?;
    let ss_res = qtb.rows(cols, rows - cols).norm_squared() + (&r * &sol - &top).norm_squared();
    let v_t = svd.v_t.as_ref()?;
    let var_unit = (0..cols)
        .map(|j| {
            let mut v = 0.0;
            for (i, &s) in svd.singular_values.iter().enumerate() {
                let w = v_t[(i, j)];
                if s > eps {
                    v += w * w / (s * s);
                } else if w.abs() > 1e-6 {
                    return f64::INFINITY;
                }
            }
            v / (norms[j] * norms[j])
        })
        .collect();
    let coef: Vec<f64> = sol.iter().zip(&norms).map(|(c, n)| c / n).collect();
    (ss_res.is_finite() && coef.iter().all(|c| c.is_finite())).then_some(LsFit {
        coef,
        ss_res,
        var_unit,
    })
}

/// Row indices 0, s, 2s, … with s chosen so that at most [`ROW_CAP`] rows remain.
fn strided_rows(n: usize) -> (Vec<usize>, usize) {
    let stride = n.div_ceil(ROW_CAP).max(1);
    ((0..n).step_by(stride).collect(), stride)
}
