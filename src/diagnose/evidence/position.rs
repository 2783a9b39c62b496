//! Periodic components against position: lead (pitch) error of a ball screw, cogging of a
//! linear motor, anything that repeats with every turn or pole pitch rather than in time.

use super::{
    centered_ss, detrend, dtft_power, golden_max, lstsq, median, ordered, padded_len, parabolic,
    positive, power_spectrum, strided_rows,
};
use std::f64::consts::TAU;

/// At most this many position bins: bounds memory and the FFT when the path is long
/// compared with the shortest period searched (the shortest period is then raised to 16
/// bins).
const POS_BINS: usize = 1 << 16;

/// At most this many harmonics are fitted.
const MAX_HARMONICS: usize = 8;

/// A periodic component of y as a function of position (lead/pitch error): its period and
/// harmonic coefficients, ready to become a compensation table.
#[derive(Debug, Clone, PartialEq)]
pub struct PositionPeriodic {
    /// Period in position, m.
    pub period_m: f64,
    /// Sine coefficients a_k of harmonics 1..=n: y ≈ Σ a_k sin(2πkx/p) + b_k cos(2πkx/p)
    /// + offset + slope·x.
    pub sin: Vec<f64>,
    /// Cosine coefficients b_k of harmonics 1..=n (see `sin`).
    pub cos: Vec<f64>,
    /// Constant term of the fit (y at x = 0 without the periodic part).
    pub offset: f64,
    /// Slope of the fit per metre of position (a linear scale error shows here).
    pub slope_per_m: f64,
    /// Amplitude of the fundamental: hypot(sin[0], cos[0]).
    pub amplitude: f64,
    /// Peak power over the median power of the position periodogram in the searched band
    /// (capped at 1e12).
    pub peak_ratio: f64,
    /// Share of the variance left after offset and slope that the harmonics explain, 0..1.
    pub explained: f64,
}

impl PositionPeriodic {
    /// The fitted value at position `x_m`: the harmonics, the offset and the slope.
    pub fn at(&self, x_m: f64) -> f64 {
        let ph = TAU * x_m / self.period_m;
        let harmonics: f64 = self
            .sin
            .iter()
            .zip(&self.cos)
            .enumerate()
            .map(|(k, (s, c))| {
                let (sk, ck) = ((k + 1) as f64 * ph).sin_cos();
                s * sk + c * ck
            })
            .sum();
        harmonics + self.offset + self.slope_per_m * x_m
    }
}

/// y sampled along a path x (non-uniform, revisiting positions): averages y in position
/// bins (width min_period_m/16, at most [`POS_BINS`] bins), interpolates empty bins,
/// removes a cubic trend (slow bows would leak into the longest periods), finds the period in [min_period_m, max_period_m] (at most half the travelled range) from the
/// zero-padded periodogram over position, refines it by the summed power of the
/// `harmonics` harmonics between bins (trying the highest peaks and their subharmonics, in
/// case a harmonic outgrows the fundamental, scored by the binned samples' fit: see
/// `search`), then fits `harmonics` harmonics + offset + slope by
/// least squares on the raw samples at that period (strided to [`super::ROW_CAP`] rows).
///
/// `harmonics` is clamped to 1..=8. Returns the best component even in noise: judge it by
/// `peak_ratio` and `explained`. None when lengths differ, the path does not move, y is
/// constant or the band is empty.
pub fn periodic_in_position(
    x_m: &[f64],
    y: &[f64],
    min_period_m: f64,
    max_period_m: f64,
    harmonics: usize,
) -> Option<PositionPeriodic> {
    if x_m.len() != y.len() || y.len() < 16 || !positive(min_period_m) {
        return None;
    }
    if !ordered(min_period_m, max_period_m) {
        return None;
    }
    let h = harmonics.clamp(1, MAX_HARMONICS);
    let (ys, scale) = super::normalized(y)?;
    let (x_lo, x_hi) = x_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let range = x_hi - x_lo;
    if !(range > 0.0 && range.is_finite()) {
        return None;
    }
    let mut width = min_period_m / 16.0;
    if range / width >= (POS_BINS - 1) as f64 {
        width = range / (POS_BINS - 1) as f64;
    }
    let nb = ((range / width).floor() as usize + 1).min(POS_BINS);
    let profile = bin_profile(x_m, &ys, x_lo, width, nb)?;
    let (det, _) = detrend(&profile.y)?;
    let min_p = (min_period_m / width).max(16.0);
    let max_p = (max_period_m / width).min(nb as f64 / 2.0);
    if !ordered(min_p, max_p) || !positive(centered_ss(&det)) {
        return None;
    }
    let (period_bins, peak_ratio) = search(&det, &profile, min_p, max_p, h)?;
    let period_m = period_bins * width;
    let fit = harmonic_fit(x_m, &ys, None, period_m, h, 1)?;
    let sin: Vec<f64> = fit.sin.iter().map(|v| v * scale).collect();
    let cos: Vec<f64> = fit.cos.iter().map(|v| v * scale).collect();
    let out = PositionPeriodic {
        period_m,
        amplitude: sin[0].hypot(cos[0]),
        sin,
        cos,
        offset: fit.offset * scale,
        slope_per_m: fit.slope * scale,
        peak_ratio,
        explained: fit.explained.clamp(0.0, 1.0),
    };
    let finite = [out.period_m, out.amplitude, out.offset, out.slope_per_m];
    finite.iter().all(|v| v.is_finite()).then_some(out)
}

/// `found` fitted again on other samples (x_m, y) at its period: harmonics, offset and
/// slope by least squares; the period and the peak ratio stay the search's. None when the
/// fit fails or is not finite.
pub fn refit_at_period(
    found: &PositionPeriodic,
    x_m: &[f64],
    y: &[f64],
) -> Option<PositionPeriodic> {
    if x_m.len() != y.len() || y.len() < 16 {
        return None;
    }
    let (ys, scale) = super::normalized(y)?;
    let fit = harmonic_fit(x_m, &ys, None, found.period_m, found.sin.len().max(1), 1)?;
    let sin: Vec<f64> = fit.sin.iter().map(|v| v * scale).collect();
    let cos: Vec<f64> = fit.cos.iter().map(|v| v * scale).collect();
    let out = PositionPeriodic {
        period_m: found.period_m,
        amplitude: sin[0].hypot(cos[0]),
        sin,
        cos,
        offset: fit.offset * scale,
        slope_per_m: fit.slope * scale,
        peak_ratio: found.peak_ratio,
        explained: fit.explained.clamp(0.0, 1.0),
    };
    let finite = [out.amplitude, out.offset, out.slope_per_m];
    finite.iter().all(|v| v.is_finite()).then_some(out)
}

/// `found`'s period sharpened on the samples (x_m, y) themselves: the period within
/// ±`rel_span` of it whose harmonics explain most of y, by a scan of `steps` periods and 16
/// golden steps around the best. The binned spectrum's peak can sit a few per cent off
/// when a red residual tilts it, and over tens of pitches a harmonic fit that far off loses
/// its phase. Returns the fit there (period and peak ratio: see [`refit_at_period`]), or
/// `found` as it is when no fit succeeds.
pub fn sharpen_period(
    found: &PositionPeriodic,
    x_m: &[f64],
    y: &[f64],
    rel_span: f64,
    steps: usize,
) -> PositionPeriodic {
    let h = found.sin.len().max(1);
    let Some((ys, _)) = super::normalized(y) else {
        return found.clone();
    };
    if x_m.len() != y.len() || y.len() < 16 || !positive(rel_span) || steps < 2 {
        return found.clone();
    }
    let score =
        |p: f64| harmonic_fit(x_m, &ys, None, p, h, 1).map_or(f64::NEG_INFINITY, |f| f.explained);
    let (lo, hi) = (
        found.period_m * (1.0 - rel_span),
        found.period_m * (1.0 + rel_span),
    );
    let step = (hi - lo) / (steps - 1) as f64;
    let best = (0..steps)
        .map(|i| lo + i as f64 * step)
        .map(|p| (p, score(p)))
        .fold((found.period_m, score(found.period_m)), |b, c| {
            if c.1 > b.1 { c } else { b }
        });
    // A best at either end of the span is no peak of its own: a fit that merely grows
    // toward a neighbouring period.
    if (best.0 - lo).abs() < 0.5 * step || (hi - best.0).abs() < 0.5 * step {
        return refit_at_period(found, x_m, y).unwrap_or_else(|| found.clone());
    }
    let (p, e) = golden_max(score, best.0 - step, best.0 + step, 16);
    let period_m = if e > best.1 && positive(p) { p } else { best.0 };
    let at = PositionPeriodic {
        period_m,
        ..found.clone()
    };
    refit_at_period(&at, x_m, y).unwrap_or_else(|| found.clone())
}

/// Refinement by least squares is skipped above this many bins (then there are so many
/// periods that the spectral estimate is already precise).
const LS_REFINE_BINS: usize = 8192;

/// Period (bins) and peak ratio from the detrended profile: the [`SEARCH_PEAKS`] highest
/// periodogram peaks in [min_p, max_p] bins and their subharmonics, each refined by the
/// harmonics' summed power; the candidate whose harmonics explain most of the binned
/// samples (a count-weighted fit at the bins' mean positions, so the bins the profile only
/// interpolates count for nothing) wins. Beside a friction whose law the model lacks, a
/// subharmonic can hold the highest peak while the pitch itself explains more. For up to
/// [`LS_REFINE_BINS`] bins the winner is refined further by 16 golden steps on the
/// count-weighted fit of harmonics and a cubic (the trend fitted jointly, not removed first, so it cannot bias the period) at the
/// bins' mean positions (which weighs and places bins as the raw samples do: where the path
/// slows down, samples crowd to one side of a bin, and bin centres would stretch the scale).
fn search(det: &[f64], prof: &Profile, min_p: f64, max_p: f64, h: usize) -> Option<(f64, f64)> {
    let nb = det.len();
    let nfft = padded_len(nb);
    let spec = power_spectrum(det, nfft);
    let k_lo = ((nfft as f64 / max_p).ceil() as usize).max(1);
    let k_hi = ((nfft as f64 / min_p).floor() as usize).min(nfft / 2);
    if k_hi < k_lo + 2 {
        return None;
    }
    let med = median(&mut spec[k_lo..=k_hi].to_vec());
    let k_peak = (k_lo..=k_hi).max_by(|&a, &b| spec[a].total_cmp(&spec[b]))?;
    // (explained by the binned samples, period in bins, peak power)
    let mut best: Option<(f64, f64, f64)> = None;
    for k_top in top_peaks(&spec, k_lo, k_hi, SEARCH_PEAKS) {
        for sub in 1..=3usize {
            let c = (k_top as f64 / sub as f64).round() as usize;
            let (a, b) = (c.saturating_sub(sub + 1).max(k_lo), (c + sub + 1).min(k_hi));
            let Some(k) = (a..=b).max_by(|&i, &j| spec[i].total_cmp(&spec[j])) else {
                continue;
            };
            // A subharmonic counts only with a peak of its own.
            if sub > 1 && (spec[k] < 4.0 * med || spec[k] < 0.02 * spec[k_peak]) {
                continue;
            }
            let period = refine_period(det, &spec, k, nfft, h);
            let expl = harmonic_fit(&prof.x_bins, &prof.y, Some(&prof.counts), period, h, 3)
                .map_or(-1.0, |f| f.explained);
            if best.is_none_or(|b| expl > b.0) {
                best = Some((expl, period, spec[k]));
            }
        }
    }
    let (_, mut period, peak) = best?;
    if nb <= LS_REFINE_BINS {
        let f0 = 1.0 / period;
        let half = 0.5 / nfft as f64;
        let score = |f: f64| {
            harmonic_fit(&prof.x_bins, &prof.y, Some(&prof.counts), 1.0 / f, h, 3)
                .map_or(f64::NEG_INFINITY, |r| r.explained)
        };
        let (f, s) = golden_max(score, f0 - half, f0 + half, 16);
        if s >= score(f0) && positive(f) {
            period = 1.0 / f;
        }
    }
    let ratio = if positive(med) {
        (peak / med).min(1e12)
    } else {
        1e12
    };
    Some((period, ratio))
}

/// How many of the periodogram's highest local peaks [`search`] tries.
const SEARCH_PEAKS: usize = 6;

/// The `n` highest local maxima of `spec` in `lo..=hi`, highest first.
fn top_peaks(spec: &[f64], lo: usize, hi: usize, n: usize) -> Vec<usize> {
    let mut peaks: Vec<usize> = (lo..=hi)
        .filter(|&k| {
            let left = k == lo || spec[k] >= spec[k - 1];
            let right = k == hi || spec[k] >= spec[k + 1];
            left && right
        })
        .collect();
    peaks.sort_by(|&a, &b| spec[b].total_cmp(&spec[a]));
    peaks.truncate(n);
    peaks
}

/// Binned path: the mean of y per position bin (empty bins filled by linear interpolation,
/// ends: nearest), with each bin's sample count and mean position (in bins from x_lo).
struct Profile {
    y: Vec<f64>,
    counts: Vec<f64>,
    x_bins: Vec<f64>,
}

/// Averages y in position bins (see [`Profile`]).
fn bin_profile(x: &[f64], y: &[f64], x_lo: f64, width: f64, nb: usize) -> Option<Profile> {
    let mut sum = vec![0.0; nb];
    let mut sum_x = vec![0.0; nb];
    let mut cnt = vec![0usize; nb];
    for (&xi, &yi) in x.iter().zip(y) {
        let u = (xi - x_lo) / width;
        let b = (u as usize).min(nb - 1);
        sum[b] += yi;
        sum_x[b] += u;
        cnt[b] += 1;
    }
    let filled: Vec<usize> = (0..nb).filter(|&i| cnt[i] > 0).collect();
    let (&first, &last) = (filled.first()?, filled.last()?);
    let mut out = vec![0.0; nb];
    for w in filled.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (va, vb) = (sum[a] / cnt[a] as f64, sum[b] / cnt[b] as f64);
        for (i, o) in out.iter_mut().enumerate().take(b + 1).skip(a) {
            *o = va + (vb - va) * (i - a) as f64 / (b - a) as f64;
        }
    }
    let v_first = sum[first] / cnt[first] as f64;
    let v_last = sum[last] / cnt[last] as f64;
    out[..=first].fill(v_first);
    out[last..].fill(v_last);
    let x_bins = (0..nb)
        .map(|i| {
            if cnt[i] > 0 {
                sum_x[i] / cnt[i] as f64
            } else {
                i as f64 + 0.5
            }
        })
        .collect();
    Some(Profile {
        y: out,
        counts: cnt.iter().map(|&c| c as f64).collect(),
        x_bins,
    })
}

/// Period (in bins) maximizing the summed power of harmonics 1..=h near FFT bin k (20
/// golden steps over ±0.75 padded bin).
fn refine_period(det: &[f64], spec: &[f64], k: usize, nfft: usize, h: usize) -> f64 {
    let off = if k >= 1 && k + 1 < spec.len() {
        parabolic(spec[k - 1], spec[k], spec[k + 1])
    } else {
        0.0
    };
    let bin = 1.0 / nfft as f64;
    let f0 = (k as f64 + off) * bin;
    let power = |f: f64| {
        (1..=h)
            .filter(|&j| j as f64 * f < 0.5)
            .map(|j| dtft_power(det, TAU * j as f64 * f))
            .sum::<f64>()
    };
    let (f, _) = golden_max(power, f0 - 0.75 * bin, f0 + 0.75 * bin, 20);
    if f > 0.0 { 1.0 / f } else { 1.0 / f0 }
}

struct HarmonicFit {
    sin: Vec<f64>,
    cos: Vec<f64>,
    offset: f64,
    slope: f64,
    explained: f64,
}

/// Least squares of y on h harmonics of `period` in x plus a polynomial of `degree` in x
/// (centred and scaled for conditioning), on rows strided to [`super::ROW_CAP`]; with
/// `weights`, each row counts that many times (rows of weight 0 drop out). `explained` is
/// relative to the polynomial alone; offset and slope are those of x itself.
fn harmonic_fit(
    x: &[f64],
    y: &[f64],
    weights: Option<&[f64]>,
    period: f64,
    h: usize,
    degree: usize,
) -> Option<HarmonicFit> {
    let (rows, _) = strided_rows(x.len().min(y.len()));
    let rows: Vec<usize> = match weights {
        Some(w) => rows
            .into_iter()
            .filter(|&r| w.get(r).is_some_and(|&v| v > 0.0))
            .collect(),
        None => rows,
    };
    let sw: Vec<f64> = rows
        .iter()
        .map(|&r| weights.map_or(1.0, |w| w[r].sqrt()))
        .collect();
    let xs: Vec<f64> = rows.iter().map(|&r| x[r]).collect();
    let ys: Vec<f64> = rows.iter().zip(&sw).map(|(&r, s)| y[r] * s).collect();
    let xc = super::mean(&xs);
    let half = xs.iter().fold(0.0_f64, |m, v| m.max((v - xc).abs()));
    let half = if positive(half) { half } else { 1.0 };
    let w = TAU / period;
    // sin and cos of harmonics 1..=h per row, by the angle-addition recurrence.
    let mut trig = vec![0.0; rows.len() * 2 * h];
    for (i, row) in trig.chunks_exact_mut(2 * h).enumerate() {
        let (s1, c1) = (w * xs[i]).sin_cos();
        let (mut sk, mut ck) = (s1, c1);
        for pair in row.chunks_exact_mut(2) {
            pair[0] = sk * sw[i];
            pair[1] = ck * sw[i];
            (sk, ck) = (sk * c1 + ck * s1, ck * c1 - sk * s1);
        }
    }
    let poly = |i: usize, j: usize| ((xs[i] - xc) / half).powi(j as i32) * sw[i];
    let full = lstsq(
        rows.len(),
        2 * h + degree + 1,
        |i, j| {
            if j < 2 * h {
                trig[i * 2 * h + j]
            } else {
                poly(i, j - 2 * h)
            }
        },
        &ys,
    )?;
    let base = lstsq(rows.len(), degree + 1, poly, &ys)?;
    let explained = if base.ss_res > 0.0 {
        1.0 - full.ss_res / base.ss_res
    } else {
        0.0
    };
    let c = &full.coef;
    let slope = if degree >= 1 {
        c[2 * h + 1] / half
    } else {
        0.0
    };
    Some(HarmonicFit {
        sin: (0..h).map(|k| c[2 * k]).collect(),
        cos: (0..h).map(|k| c[2 * k + 1]).collect(),
        offset: c[2 * h] - slope * xc,
        slope,
        explained,
    })
}
