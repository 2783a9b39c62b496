//! Time offset between two series: a delay the model lacks (a command path's latency, a
//! measurement's filter).

use super::{golden_max, normalized};
use rustfft::num_complex::Complex;

/// At most this many samples (the first ones) enter the lag search: bounds the FFT.
const LAG_CAP: usize = 1 << 17;

/// The lag that best aligns b onto a: b[k] ≈ g·a[k − samples]. Positive: b is a delayed
/// copy of a (b lags a).
#[derive(Debug, Clone, PartialEq)]
pub struct Lag {
    /// Lag in samples (fractional).
    pub samples: f64,
    /// Correlation of the first differences at that lag, −1..1 (negative: b ≈ −g·a).
    pub correlation: f64,
}

/// The fractional lag (samples) that best aligns b onto a: b[k] ≈ g·a[k − lag], within
/// ±max_lag (at most half the series).
///
/// Works on first differences of both series: motion signals (positions, velocities) are
/// dominated by slow content whose correlation peak is flat and which offsets and drifts
/// between the two series would bias; differencing removes offsets, turns drifts into
/// small constants and sharpens the peak. The price is noise: differencing amplifies
/// white noise, so for very noisy, slowly varying series low-pass them first.
///
/// Integer lag from the FFT cross-correlation normalized by the overlapping energies, then
/// refined (24 golden steps over ±1 sample) by maximizing the correlation of the
/// differences of b with those of a shifted by linear interpolation. The series are cut to
/// their common length and to the first 131 072 samples. None if either is constant or
/// shorter than 16 samples.
pub fn lag(a: &[f64], b: &[f64], max_lag: usize) -> Option<Lag> {
    let n = a.len().min(b.len()).min(LAG_CAP);
    if n < 16 {
        return None;
    }
    let (da, _) = normalized(&diff(&a[..n]))?;
    let (db, _) = normalized(&diff(&b[..n]))?;
    let nd = da.len();
    let lmax = max_lag.min(nd / 2) as isize;
    let c = cross(&da, &db);
    let nfft = c.len();
    let mut pa = vec![0.0; nd + 1];
    let mut pb = vec![0.0; nd + 1];
    for i in 0..nd {
        pa[i + 1] = pa[i] + da[i] * da[i];
        pb[i + 1] = pb[i] + db[i] * db[i];
    }
    let r_at = |l: isize| {
        let (ea, eb, cv) = if l >= 0 {
            let l = l as usize;
            (pa[nd - l], pb[nd] - pb[l], c[l])
        } else {
            let m = (-l) as usize;
            (pa[nd] - pa[m], pb[nd - m], c[nfft - m])
        };
        if ea > 0.0 && eb > 0.0 {
            cv / (ea * eb).sqrt()
        } else {
            0.0
        }
    };
    let l0 = (-lmax..=lmax).max_by(|&x, &y| r_at(x).abs().total_cmp(&r_at(y).abs()))?;
    // Fixed rows, valid for every lag in [l0 − 1, l0 + 1].
    let k_lo = (l0 + 2).max(0) as usize;
    let k_hi = (nd as isize + l0 - 2).min(nd as isize).max(0) as usize;
    if k_hi < k_lo + 4 {
        return None;
    }
    let corr = |lag: f64| shifted_corr(&da, &db, lag, k_lo, k_hi);
    let (lag_s, _) = golden_max(|l| corr(l).abs(), l0 as f64 - 1.0, l0 as f64 + 1.0, 24);
    let best = [(lag_s, corr(lag_s)), (l0 as f64, corr(l0 as f64))]
        .into_iter()
        .max_by(|x, y| x.1.abs().total_cmp(&y.1.abs()))?;
    (best.0.is_finite() && best.1.is_finite()).then_some(Lag {
        samples: best.0,
        correlation: best.1.clamp(-1.0, 1.0),
    })
}

fn diff(y: &[f64]) -> Vec<f64> {
    y.windows(2).map(|w| w[1] - w[0]).collect()
}

/// c[m] = Σ_k b[k]·a[k − m] for m ≥ 0 at index m, for m < 0 at index len + m. The inverse
/// transform is the forward one on the conjugate (one cached plan serves both).
fn cross(a: &[f64], b: &[f64]) -> Vec<f64> {
    let nfft = (2 * a.len()).next_power_of_two();
    let fft = super::fft_forward(nfft);
    let pad = |v: &[f64]| {
        let mut buf: Vec<Complex<f64>> = v.iter().map(|&x| Complex::new(x, 0.0)).collect();
        buf.resize(nfft, Complex::new(0.0, 0.0));
        buf
    };
    let (mut fa, mut fb) = (pad(a), pad(b));
    fft.process(&mut fa);
    fft.process(&mut fb);
    let mut prod: Vec<Complex<f64>> = fb
        .iter()
        .zip(&fa)
        .map(|(x, y)| (x * y.conj()).conj())
        .collect();
    fft.process(&mut prod);
    prod.iter().map(|z| z.re / nfft as f64).collect()
}

/// Correlation over rows k_lo..k_hi of b[k] with a at k − lag (linear interpolation);
/// the caller keeps k − lag within 0..len − 1 for every row.
fn shifted_corr(a: &[f64], b: &[f64], lag: f64, k_lo: usize, k_hi: usize) -> f64 {
    let shift = (-lag).floor();
    let f = -lag - shift;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    let lo = k_lo as isize + shift as isize;
    if lo < 0 || (k_hi as isize + shift as isize) as usize >= a.len() || k_hi > b.len() {
        return 0.0;
    }
    let lo = lo as usize;
    let n = k_hi.saturating_sub(k_lo);
    for ((&bk, &a0), &a1) in b[k_lo..k_hi]
        .iter()
        .zip(&a[lo..lo + n])
        .zip(&a[lo + 1..lo + n + 1])
    {
        let ai = a0 + (a1 - a0) * f;
        sab += ai * bk;
        saa += ai * ai;
        sbb += bk * bk;
    }
    if saa > 0.0 && sbb > 0.0 {
        sab / (saa * sbb).sqrt()
    } else {
        0.0
    }
}
