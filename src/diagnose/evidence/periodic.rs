//! Periodic components in time: a square wave (a disturbance switched on and off, a
//! stick-slip limit cycle) or a sine (unbalance, an oscillating loop).

use super::{
    LsFit, TIME_CAP, centered_ss, detrend, dtft_power, golden_max, lstsq, median, ordered,
    parabolic, positive, power_spectrum, strided_rows,
};
use std::f64::consts::TAU;

/// A periodic component found in a time series: the signature of an effect that repeats in
/// time rather than with position.
#[derive(Debug, Clone, PartialEq)]
pub struct Periodic {
    /// Period of the component, s.
    pub period_s: f64,
    /// Half the peak-to-peak of the fitted shape (for a square wave: half the step height).
    pub amplitude: f64,
    /// Mean level the wave rides on at the middle of the record (the square wave
    /// alternates between offset ± amplitude; a cubic trend is removed first).
    pub offset: f64,
    /// Which shape fits better.
    pub shape: WaveShape,
    /// Time of the first rising edge at or after t0_s (square), or of the first zero
    /// up-crossing (sine), s.
    pub first_rise_s: f64,
    /// Peak power over the median power of the periodogram in the searched band (white
    /// noise gives ~10–20 for 30k–60k samples; capped at 1e12).
    pub peak_ratio: f64,
    /// Share of the series' variance (after removing a cubic trend) the fitted wave
    /// explains, 0..1.
    pub explained: f64,
}

/// The shape of a periodic component: tells a switched disturbance (square) from a smooth
/// oscillation (sine).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WaveShape {
    /// A sinusoid.
    Sine,
    /// A two-level wave, high for `duty` of each period (0.1..0.9).
    Square {
        /// Fraction of the period spent at the high level.
        duty: f64,
    },
}

/// The series as the search sees it: block-averaged within [`TIME_CAP`], normalized,
/// without its cubic trend.
struct Prepared {
    det: Vec<f64>,
    /// Level of the trend at the middle of the record (normalized units).
    level: f64,
    scale: f64,
    dt_s: f64,
    /// Time of det[0] (a block's centre), s.
    t0_s: f64,
    /// The caller's t0, s.
    t0_caller_s: f64,
}

fn prepare(y: &[f64], t0_s: f64, dt_s: f64, min_period_s: f64) -> Option<Prepared> {
    let by_len = y.len().div_ceil(TIME_CAP).max(1);
    // Averaging blocks stay below 1/8 of the shortest period searched.
    let by_period = (min_period_s / (8.0 * dt_s)).floor();
    let by_period = if by_period.is_finite() && by_period >= 1.0 {
        by_period.min(by_len as f64) as usize
    } else {
        1
    };
    let m = by_len.min(by_period).max(1);
    let z: Vec<f64> = y
        .chunks_exact(m)
        .take(TIME_CAP)
        .map(|c| c.iter().sum::<f64>() / m as f64)
        .collect();
    let (zs, scale) = super::normalized(&z)?;
    let (det, level) = detrend(&zs)?;
    Some(Prepared {
        det,
        level,
        scale,
        dt_s: dt_s * m as f64,
        t0_s: t0_s + 0.5 * (m as f64 - 1.0) * dt_s,
        t0_caller_s: t0_s,
    })
}

/// Searches periods in [min_period_s, max_period_s] (at most half the record) in y sampled
/// every dt_s starting at t0_s: zero-padded periodogram, peak refined between bins, then a
/// sine and a square wave (duty 0.1..0.9, edges to a fraction of a sample) fitted at the best
/// period; the shape that explains more wins, and a square wave's period is refined by its
/// own fit (its edges time the period far better than the fundamental alone). Subharmonics
/// of the strongest peak are tried too, so a square wave of small duty, whose second
/// harmonic can outgrow its fundamental, is found at its true period.
///
/// A cubic trend is removed first. Records longer than [`TIME_CAP`] samples are
/// block-averaged (blocks shorter than 1/8 of min_period_s) and then cut to [`TIME_CAP`].
/// Returns the best component even in pure noise: judge it by `peak_ratio` and `explained`.
/// None when the arguments are inconsistent or the series is constant or too short.
pub fn periodic_in_time(
    y: &[f64],
    t0_s: f64,
    dt_s: f64,
    min_period_s: f64,
    max_period_s: f64,
) -> Option<Periodic> {
    let ok = dt_s > 0.0 && dt_s.is_finite() && t0_s.is_finite() && min_period_s > 0.0;
    if !ok || !ordered(min_period_s, max_period_s) || y.len() < 16 {
        return None;
    }
    let p = prepare(y, t0_s, dt_s, min_period_s)?;
    let n = p.det.len();
    let ss_tot = centered_ss(&p.det);
    if n < 16 || !positive(ss_tot) {
        return None;
    }
    // Periods in samples: at least 4 samples, at most half the record.
    let min_p = (min_period_s / p.dt_s).max(4.0);
    let max_p = (max_period_s / p.dt_s).min(n as f64 / 2.0);
    if !ordered(min_p, max_p) {
        return None;
    }
    let nfft = super::padded_len(n);
    let spec = power_spectrum(&p.det, nfft);
    let k_lo = ((nfft as f64 / max_p).ceil() as usize).max(1);
    let k_hi = ((nfft as f64 / min_p).floor() as usize).min(nfft / 2);
    if k_hi < k_lo + 2 {
        return None;
    }
    let band = &spec[k_lo..=k_hi];
    let med = median(&mut band.to_vec());
    let k_peak = k_lo + argmax(band)?;
    let mut best: Option<(Candidate, f64)> = None;
    for sub in 1..=3usize {
        let Some(k) = local_peak(&spec, k_peak as f64 / sub as f64, sub + 1, k_lo, k_hi) else {
            continue;
        };
        // A subharmonic counts only with a peak of its own.
        if sub > 1 && (spec[k] < 4.0 * med || spec[k] < 0.02 * spec[k_peak]) {
            continue;
        }
        if let Some(c) = candidate(&p.det, &spec, k, nfft, ss_tot)
            && best.as_ref().is_none_or(|b| c.explained > b.0.explained)
        {
            best = Some((c, spec[k]));
        }
    }
    let (mut c, peak_power) = best?;
    if let Fit::Square(sq) = c.fit {
        let (period, sq) = refine_square(&p.det, c.period, sq);
        c = Candidate {
            period,
            explained: sq.ss / ss_tot,
            fit: Fit::Square(sq),
        };
    }
    let peak_ratio = if med > 0.0 {
        (peak_power / med).min(1e12)
    } else {
        1e12
    };
    finish(&p, c, peak_ratio)
}

fn argmax(v: &[f64]) -> Option<usize> {
    v.iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map(|(i, _)| i)
}

/// The largest bin within ±`reach` of `at`, inside [lo, hi].
fn local_peak(spec: &[f64], at: f64, reach: usize, lo: usize, hi: usize) -> Option<usize> {
    let c = at.round() as usize;
    let a = c.saturating_sub(reach).max(lo);
    let b = (c + reach).min(hi);
    (a <= b).then(|| a + argmax(&spec[a..=b]).unwrap_or(0))
}

/// One trial period with its better-fitting shape.
struct Candidate {
    period: f64,
    explained: f64,
    fit: Fit,
}

enum Fit {
    Sine { a_sin: f64, b_cos: f64, c: f64 },
    Square(SquareFit),
}

fn candidate(det: &[f64], spec: &[f64], k: usize, nfft: usize, ss_tot: f64) -> Option<Candidate> {
    let off = if k >= 1 && k + 1 < spec.len() {
        parabolic(spec[k - 1], spec[k], spec[k + 1])
    } else {
        0.0
    };
    let bin = 1.0 / nfft as f64;
    let f0 = (k as f64 + off) * bin;
    // 20 golden steps shrink ±0.75 padded bin to ~1e-4 bin.
    let (f, _) = golden_max(
        |f| dtft_power(det, TAU * f),
        f0 - 0.75 * bin,
        f0 + 0.75 * bin,
        20,
    );
    if !positive(f) {
        return None;
    }
    let period = 1.0 / f;
    let sine = fit_sine(det, period);
    let square = fit_square(det, period);
    let sine_expl = sine.as_ref().map_or(-1.0, |s| 1.0 - s.ss_res / ss_tot);
    let square_expl = square.as_ref().map_or(-1.0, |s| s.ss / ss_tot);
    if let Some(sq) = square.filter(|_| square_expl > sine_expl) {
        return Some(Candidate {
            period,
            explained: square_expl,
            fit: Fit::Square(sq),
        });
    }
    let s = sine?;
    Some(Candidate {
        period,
        explained: sine_expl,
        fit: Fit::Sine {
            a_sin: s.coef[0],
            b_cos: s.coef[1],
            c: s.coef[2],
        },
    })
}

/// y ≈ a·sin(2πk/p) + b·cos(2πk/p) + c on rows strided to [`super::ROW_CAP`].
fn fit_sine(det: &[f64], period: f64) -> Option<LsFit> {
    let (rows, _) = strided_rows(det.len());
    let w = TAU / period;
    let y: Vec<f64> = rows.iter().map(|&r| det[r]).collect();
    let mut fit = lstsq(
        rows.len(),
        3,
        |i, j| {
            let ph = w * rows[i] as f64;
            match j {
                0 => ph.sin(),
                1 => ph.cos(),
                _ => 1.0,
            }
        },
        &y,
    )?;
    // Report the residual against all rows' variance scale (rows are a strided subset).
    let ss_rows = centered_ss(&y);
    let ss_all = centered_ss(det);
    if ss_rows > 0.0 {
        fit.ss_res *= ss_all / ss_rows;
    }
    Some(fit)
}

/// Square-wave fit at one period, in units of the folded phase (0..1).
#[derive(Clone, Copy)]
struct SquareFit {
    /// Phase of the rising edge (0..1) relative to sample 0.
    rise: f64,
    duty: f64,
    hi: f64,
    lo: f64,
    /// Sum of squares the two levels explain.
    ss: f64,
}

/// Scans the period ±0.2 Fourier bins around `period` (21 points, then 16 golden steps
/// between the best point's neighbours) for the best square fit.
fn refine_square(det: &[f64], period: f64, first: SquareFit) -> (f64, SquareFit) {
    let n = det.len() as f64;
    let f0 = 1.0 / period;
    let step = 0.02 / n;
    let score = |f: f64| fit_square(det, 1.0 / f).map_or(f64::NEG_INFINITY, |s| s.ss);
    let mut best = (f0, first.ss);
    for i in -10..=10 {
        let f = f0 + i as f64 * step;
        let s = score(f);
        if s > best.1 {
            best = (f, s);
        }
    }
    let (f, _) = golden_max(score, best.0 - step, best.0 + step, 16);
    let cands = [(f, fit_square(det, 1.0 / f)), (f0, Some(first))];
    cands
        .into_iter()
        .filter_map(|(f, s)| s.map(|s| (1.0 / f, s)))
        .max_by(|a, b| a.1.ss.total_cmp(&b.1.ss))
        .unwrap_or((period, first))
}

/// Folds det at `period` samples into `bins` phase bins: per-bin sums and counts.
fn fold(det: &[f64], period: f64, bins: usize) -> (Vec<f64>, Vec<f64>) {
    let mut sum = vec![0.0; bins];
    let mut cnt = vec![0.0; bins];
    let inv = 1.0 / period;
    for (k, v) in det.iter().enumerate() {
        let ph = (k as f64 * inv).fract();
        let b = ((ph * bins as f64) as usize).min(bins - 1);
        sum[b] += v;
        cnt[b] += 1.0;
    }
    (sum, cnt)
}

/// Best two-level fit at `period` samples: high over [rise, rise + duty) of each period.
/// Coarse search on 128 phase bins, then a fine one (up to 16384 bins, ≥ 8 per sample)
/// near the coarse edges, one edge at a time; each edge is finally put in the middle of the
/// empty phase bins around it (where samples leave the edge's place undetermined).
fn fit_square(det: &[f64], period: f64) -> Option<SquareFit> {
    if !ordered(2.0, period) || !period.is_finite() {
        return None;
    }
    let fine = ((8.0 * period).ceil() as usize)
        .next_power_of_two()
        .clamp(64, 16384);
    let coarse = fine.min(128);
    let ratio = fine / coarse;
    let (sum, cnt) = fold(det, period, fine);
    let mut ps = vec![0.0; 2 * fine + 1];
    let mut pc = vec![0.0; 2 * fine + 1];
    for i in 0..2 * fine {
        ps[i + 1] = ps[i] + sum[i % fine];
        pc[i + 1] = pc[i] + cnt[i % fine];
    }
    let (tot_s, tot_c) = (ps[fine], pc[fine]);
    // Explained sum of squares of the split high = [r, e), low = the rest (fine units).
    let score = |r: usize, e: usize| {
        let (s_hi, c_hi) = (ps[e] - ps[r], pc[e] - pc[r]);
        let (s_lo, c_lo) = (tot_s - s_hi, tot_c - c_hi);
        if c_hi < 1.0 || c_lo < 1.0 {
            return f64::NEG_INFINITY;
        }
        s_hi * s_hi / c_hi + s_lo * s_lo / c_lo - tot_s * tot_s / tot_c
    };
    let (w_min, w_max) = (fine.div_ceil(10), fine * 9 / 10);
    let mut best = (0usize, w_min, f64::NEG_INFINITY);
    for i in 0..coarse {
        for j in coarse.div_ceil(10)..=coarse * 9 / 10 {
            let s = score(i * ratio, i * ratio + j * ratio);
            if s > best.2 {
                best = (i * ratio, j * ratio, s);
            }
        }
    }
    // Fine search: each edge in turn within ±2 coarse bins, the other held (the edges are
    // far apart, so the optimum is nearly separable); two rounds.
    let reach = 2 * ratio as isize;
    for _ in 0..2 {
        for moving_rise in [true, false] {
            let (r0, e0) = (best.0 as isize, (best.0 + best.1) as isize);
            for d in -reach..=reach {
                let (r, e) = if moving_rise {
                    (r0 + d, e0)
                } else {
                    (r0, e0 + d)
                };
                let w = e - r;
                if w < w_min as isize || w > w_max as isize {
                    continue;
                }
                let r = r.rem_euclid(fine as isize) as usize;
                let s = score(r, r + w as usize);
                if s > best.2 {
                    best = (r, w as usize, s);
                }
            }
        }
    }
    let (r, w, ss) = best;
    if !ss.is_finite() {
        return None;
    }
    let (s_hi, c_hi) = (ps[r + w] - ps[r], pc[r + w] - pc[r]);
    let (hi, lo) = (s_hi / c_hi, (tot_s - s_hi) / (tot_c - c_hi));
    let rise = plateau_mid(&cnt, r) / fine as f64;
    let fall = plateau_mid(&cnt, r + w) / fine as f64;
    let duty = (fall - rise).rem_euclid(1.0);
    Some(if hi >= lo {
        SquareFit {
            rise: rise.rem_euclid(1.0),
            duty,
            hi,
            lo,
            ss,
        }
    } else {
        SquareFit {
            rise: fall.rem_euclid(1.0),
            duty: 1.0 - duty,
            hi: lo,
            lo: hi,
            ss,
        }
    })
}

/// Middle of the run of empty bins around the boundary before bin `b` (mod the bin count):
/// the edge may sit anywhere there without changing the fit.
fn plateau_mid(cnt: &[f64], b: usize) -> f64 {
    let n = cnt.len();
    let mut left = 0;
    while left < n && cnt[(b + 2 * n - 1 - left) % n] == 0.0 {
        left += 1;
    }
    let mut right = 0;
    while right < n && cnt[(b + right) % n] == 0.0 {
        right += 1;
    }
    b as f64 + 0.5 * (right as f64 - left as f64)
}

/// Converts the winning candidate to physical units.
fn finish(p: &Prepared, c: Candidate, peak_ratio: f64) -> Option<Periodic> {
    let period_s = c.period * p.dt_s;
    let (amplitude, offset, shape, phase) = match c.fit {
        Fit::Sine { a_sin, b_cos, c } => {
            // a·sin θ + b·cos θ = R·sin(θ + φ): up-crossing where θ = −φ (mod 2π).
            let phi = b_cos.atan2(a_sin);
            let amp = a_sin.hypot(b_cos);
            (
                amp,
                p.level + c,
                WaveShape::Sine,
                (-phi / TAU).rem_euclid(1.0),
            )
        }
        Fit::Square(s) => (
            0.5 * (s.hi - s.lo),
            p.level + 0.5 * (s.hi + s.lo),
            WaveShape::Square { duty: s.duty },
            s.rise,
        ),
    };
    // det[0] sits at p.t0_s, at most half a block after the caller's t0.
    let mut first = p.t0_s + phase * period_s;
    if first - period_s >= p.t0_caller_s {
        first -= period_s;
    }
    let out = Periodic {
        period_s,
        amplitude: amplitude * p.scale,
        offset: offset * p.scale,
        shape,
        first_rise_s: first,
        peak_ratio,
        explained: c.explained.clamp(0.0, 1.0),
    };
    let finite = [out.period_s, out.amplitude, out.offset, out.first_rise_s];
    finite.iter().all(|v| v.is_finite()).then_some(out)
}
