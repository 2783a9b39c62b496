//! Structural resonances: a narrow peak in a spectrum (a compliant coupling, a frame mode).

use super::{median, normalized, ordered, positive};
use rustfft::num_complex::Complex;
use std::f64::consts::TAU;

/// Longest Welch segment (frequency resolution 1/(8192·dt), 0.12 Hz at 1 kHz).
const SEG_MAX: usize = 8192;

/// Shortest Welch segment.
const SEG_MIN: usize = 64;

/// At most this many Welch segments are averaged (evenly spread over a long record).
const SEG_COUNT: usize = 64;

/// Half-power width of a Hann window's main lobe, in bins: removed (in quadrature) from a
/// peak's measured width before it becomes a damping ratio.
const HANN_WIDTH_BINS: f64 = 1.44;

/// A structural resonance: a narrow peak the model's rigid structure cannot produce.
#[derive(Debug, Clone, PartialEq)]
pub struct Resonance {
    /// Peak frequency (interpolated between bins), Hz.
    pub freq_hz: f64,
    /// Peak power over the median power of the band (white noise: ~2–3).
    pub peak_ratio: f64,
    /// With a reference: the ratio y/reference at the peak over its band median (≈ 1 when
    /// the reference itself has the peak, i.e. the command excites it, not the structure).
    pub ref_ratio: Option<f64>,
    /// Damping ratio from the half-power bandwidth, Δf / (2·f), with the Hann window's own
    /// width removed (approximate; widths below ~2 Welch bins are resolution-limited).
    pub damping_ratio: f64,
}

/// Looks for a resonance of y (sampled every dt_s) in [f_lo_hz, f_hi_hz]: Welch power
/// spectrum (Hann window, 50 % overlap, segments of a power of two ≤ n/8 within 64..8192
/// samples, at most 64 segments), the band's largest peak, its ratio to the band median,
/// and the frequency and damping ratio from a Lorentzian fitted to the peak (see
/// `lorentzian`; for a peak narrower than 5 bins: parabolic interpolation of the log power
/// and the half-power width, then the damping ratio is only an upper bound).
///
/// With a reference (e.g. the commanded acceleration), the peak is chosen after dividing
/// y's spectrum by the reference's excess over its own median (where the reference has a
/// peak, so a peak the command itself has does not win), and `ref_ratio` reports the
/// transfer ratio's peak over its median (a reference shorter than one segment, or
/// constant, is ignored: `ref_ratio` None). Returns the largest peak even in noise: judge it
/// by `peak_ratio`. None for a constant y, fewer than 64 samples, or a band with fewer
/// than 5 bins.
pub fn resonance(
    y: &[f64],
    dt_s: f64,
    f_lo_hz: f64,
    f_hi_hz: f64,
    reference: Option<&[f64]>,
) -> Option<Resonance> {
    let Band {
        nseg,
        df,
        k_lo,
        k_hi,
    } = Band::of(y.len(), dt_s, f_lo_hz, f_hi_hz)?;
    let py = welch(&normalized(y)?.0, nseg)?;
    let med = median(&mut py[k_lo..=k_hi].to_vec());
    if !positive(med) {
        return None;
    }
    let pr = reference
        .and_then(normalized)
        .and_then(|(r, _)| welch(&r, nseg));
    let (k, ref_ratio) = match &pr {
        Some(pr) => {
            let med_r = median(&mut pr[k_lo..=k_hi].to_vec());
            let floor = (med_r * 1e-6).max(f64::MIN_POSITIVE);
            let excess = |k: usize| (pr[k] / med_r.max(f64::MIN_POSITIVE)).max(1.0);
            let k = (k_lo..=k_hi)
                .max_by(|&a, &b| (py[a] / excess(a)).total_cmp(&(py[b] / excess(b))))?;
            let ratio = |k: usize| py[k] / pr[k].max(floor);
            let med_t = median(&mut (k_lo..=k_hi).map(ratio).collect::<Vec<_>>());
            let rr = if med_t > 0.0 { ratio(k) / med_t } else { 1e12 };
            (k, Some(rr.min(1e12)))
        }
        None => (
            (k_lo..=k_hi).max_by(|&a, &b| py[a].total_cmp(&py[b]))?,
            None,
        ),
    };
    let off = if k >= 1 && k + 1 < py.len() && py[k - 1] > 0.0 && py[k + 1] > 0.0 {
        super::parabolic(py[k - 1].ln(), py[k].ln(), py[k + 1].ln())
    } else {
        0.0
    };
    let (centre, width) = lorentzian(&py, k).unwrap_or((k as f64 + off, half_power_width(&py, k)));
    let freq_hz = centre * df;
    let res = HANN_WIDTH_BINS * HANN_WIDTH_BINS;
    let width = (width * width - res).max(0.25).sqrt() * df;
    let out = Resonance {
        freq_hz,
        peak_ratio: (py[k] / med).min(1e12),
        ref_ratio,
        damping_ratio: width / (2.0 * freq_hz),
    };
    (out.freq_hz.is_finite() && out.damping_ratio.is_finite()).then_some(out)
}

/// A steady tone: one narrow peak holding most of a band's power.
#[derive(Debug, Clone, PartialEq)]
pub struct Tone {
    /// Peak frequency (bin centre), Hz.
    pub freq_hz: f64,
    /// Share of the band's power within ±5 % (and ±2 bins) of the peak: near 1 for a limit
    /// cycle, a few per cent for white noise.
    pub share: f64,
    /// Rms of y within that narrow band, in y's unit.
    pub rms: f64,
}

/// The band [f_lo_hz, f_hi_hz]'s largest peak in y's Welch power spectrum (as in
/// [`resonance`]), with the share of the band's power it holds and its rms. Where
/// `resonance` asks whether a peak stands out of the band's median (a lightly damped mode
/// excited now and then also does), this asks whether the band *is* that one peak, as it is
/// when a loop hunts. None under the same conditions as `resonance`.
pub fn tone(y: &[f64], dt_s: f64, f_lo_hz: f64, f_hi_hz: f64) -> Option<Tone> {
    let n = y.len();
    let Band {
        nseg,
        df,
        k_lo,
        k_hi,
    } = Band::of(n, dt_s, f_lo_hz, f_hi_hz)?;
    let (yn, scale) = normalized(y)?;
    let py = welch(&yn, nseg)?;
    let k = (k_lo..=k_hi).max_by(|&a, &b| py[a].total_cmp(&py[b]))?;
    let half = ((0.05 * k as f64).ceil() as usize).max(2);
    let peak: f64 = py[k.saturating_sub(half).max(k_lo)..=(k + half).min(k_hi)]
        .iter()
        .sum();
    let band: f64 = py[k_lo..=k_hi].iter().sum();
    let total: f64 = py.iter().sum();
    if !(positive(band) && positive(total)) {
        return None;
    }
    let m = yn.iter().sum::<f64>() / n as f64;
    let var = yn.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / n as f64;
    let out = Tone {
        freq_hz: k as f64 * df,
        share: peak / band,
        rms: scale * (var * peak / total).sqrt(),
    };
    (out.share.is_finite() && out.rms.is_finite()).then_some(out)
}

/// The Welch segment and the bins of a band [f_lo_hz, f_hi_hz] that [`resonance`] and
/// [`tone`] both search: one segment length per record length, so the two read the same
/// spectrum.
struct Band {
    nseg: usize,
    /// Bin spacing, Hz.
    df: f64,
    k_lo: usize,
    k_hi: usize,
}

impl Band {
    /// None for a record shorter than [`SEG_MIN`], a bad sample period, an empty band or
    /// one narrower than five bins.
    fn of(n: usize, dt_s: f64, f_lo_hz: f64, f_hi_hz: f64) -> Option<Band> {
        if n < SEG_MIN || !(positive(dt_s) && dt_s.is_finite()) || !ordered(0.0, f_lo_hz) {
            return None;
        }
        if !positive(f_hi_hz - f_lo_hz) {
            return None;
        }
        let nseg = prev_pow2(n / 8).clamp(SEG_MIN, SEG_MAX).min(prev_pow2(n));
        let df = 1.0 / (nseg as f64 * dt_s);
        let k_lo = ((f_lo_hz / df).ceil() as usize).max(1);
        let k_hi = ((f_hi_hz / df).floor() as usize).min(nseg / 2);
        (k_hi >= k_lo + 4).then_some(Band {
            nseg,
            df,
            k_lo,
            k_hi,
        })
    }
}

/// Largest power of two ≤ n (1 for n = 0).
fn prev_pow2(n: usize) -> usize {
    if n < 2 {
        1
    } else {
        1 << (usize::BITS - 1 - n.leading_zeros())
    }
}

/// Welch power spectrum (bins 0..=nseg/2) of y with a Hann window, segment means removed.
fn welch(y: &[f64], nseg: usize) -> Option<Vec<f64>> {
    if y.len() < nseg || nseg < 2 {
        return None;
    }
    let hop = nseg / 2;
    let natural = (y.len() - nseg) / hop + 1;
    let count = natural.min(SEG_COUNT);
    let span = y.len() - nseg;
    let window: Vec<f64> = (0..nseg)
        .map(|i| 0.5 - 0.5 * (TAU * i as f64 / nseg as f64).cos())
        .collect();
    let fft = super::fft_forward(nseg);
    let mut acc = vec![0.0; nseg / 2 + 1];
    let mut buf = vec![Complex::new(0.0, 0.0); nseg];
    for s in 0..count {
        let start = if count == natural {
            s * hop
        } else {
            span * s / (count - 1).max(1)
        };
        let seg = &y[start..start + nseg];
        let m = seg.iter().sum::<f64>() / nseg as f64;
        for ((b, v), w) in buf.iter_mut().zip(seg).zip(&window) {
            *b = Complex::new((v - m) * w, 0.0);
        }
        fft.process(&mut buf);
        for (a, b) in acc.iter_mut().zip(&buf) {
            *a += b.norm_sqr();
        }
    }
    Some(acc.iter().map(|a| a / count as f64).collect())
}

/// Centre and half-power width (bins) of a Lorentzian P₀ / (1 + ((f − f₀)/γ)²), the shape
/// of a lightly damped mode's power near its peak, fitted around bin k where the (3-bin
/// smoothed) power exceeds a tenth of its peak (±3 half-widths): P·(c₀ + c₁u + c₂u²) ≈ 1 by least squares
/// (the linearized fit, weighted by P as the Welch estimate's error is relative). Averages
/// over all those bins, where walking down to the half-power points would stop at the
/// first noisy dip. None with fewer than 5 bins (a peak narrower than the resolution).
fn lorentzian(p: &[f64], k: usize) -> Option<(f64, f64)> {
    let smooth = |i: usize| {
        let lo = i.saturating_sub(1);
        let hi = (i + 1).min(p.len() - 1);
        p[lo..=hi].iter().sum::<f64>() / (hi - lo + 1) as f64
    };
    let tenth = 0.1 * smooth(k);
    let mut i = k;
    while i > 0 && k - i < 4096 && smooth(i - 1) > tenth {
        i -= 1;
    }
    let mut j = k;
    while j + 1 < p.len() && j - k < 4096 && smooth(j + 1) > tenth {
        j += 1;
    }
    if j < i + 4 {
        return None;
    }
    let rows = j - i + 1;
    let u = |r: usize| (i + r) as f64 - k as f64;
    let fit = super::lstsq(
        rows,
        3,
        |r, c| p[i + r] * u(r).powi(c as i32),
        &vec![1.0; rows],
    )?;
    let (c0, c1, c2) = (fit.coef[0], fit.coef[1], fit.coef[2]);
    if !super::positive(c2) {
        return None;
    }
    let centre = -c1 / (2.0 * c2);
    let inv_peak = c0 - c1 * c1 / (4.0 * c2);
    let gamma = (inv_peak / c2).sqrt();
    let inside = centre >= u(0) && centre <= u(rows - 1);
    (inside && inv_peak > 0.0 && gamma.is_finite()).then_some((k as f64 + centre, 2.0 * gamma))
}

/// Width in bins between the half-power points around bin k (linear interpolation;
/// the spectrum's ends where the power never halves).
fn half_power_width(p: &[f64], k: usize) -> f64 {
    let half = 0.5 * p[k];
    let mut i = k;
    while i > 0 && p[i - 1] > half {
        i -= 1;
    }
    let left = if i > 0 {
        (i - 1) as f64 + (half - p[i - 1]) / (p[i] - p[i - 1])
    } else {
        0.0
    };
    let mut j = k;
    while j + 1 < p.len() && p[j + 1] > half {
        j += 1;
    }
    let right = if j + 1 < p.len() {
        j as f64 + (p[j] - half) / (p[j] - p[j + 1])
    } else {
        (p.len() - 1) as f64
    };
    (right - left).max(0.0)
}

/// The force residual's average answer to the command's acceleration steps: a payload on a
/// spring lags an acceleration step, so the motor first needs less force than the rigid
/// model says, then more as the payload catches up and swings past. Filtered by the
/// position loop, that is a dip and an overshoot over some tens of ms, which a spectrum of
/// the whole record (steps are rare) does not show but an average locked to the steps does.
#[derive(Debug, Clone, PartialEq)]
pub struct Ringing {
    /// Steps averaged.
    pub events: usize,
    /// The dip: the average's most negative value (per step sign) before the overshoot
    /// that pairs best with a dip (see [`RINGING_T`]), N (or y's unit) …
    pub dip: f64,
    /// … in standard errors of the average (the spread across steps).
    pub dip_t: f64,
    /// Its time after the step, s.
    pub dip_s: f64,
    /// The overshoot after the dip, in y's unit …
    pub rise: f64,
    /// … and in standard errors.
    pub rise_t: f64,
    /// Its time after the step, s.
    pub rise_s: f64,
}

/// Standard errors the dip and the overshoot after it must each reach for a ringing to
/// count: a dip alone is what a loop's own settling leaves after a step; a spring's ringing
/// has both, and six and four standard errors are far in the Gaussian tails (the report's
/// flag; a signature orders and skips, never names).
pub const RINGING_T: (f64, f64) = (6.0, 4.0);

/// Steps of `acc` (one sample to the next) at least this share of its largest step.
pub const RINGING_STEP_SHARE: f64 = 0.3;

/// Averages `y` over the `window_s` after each step of `acc` (both sampled every `dt_s`),
/// each segment signed by its step and less its mean over the 10 samples before the step.
/// Steps closer than a window to the previous one are skipped. None with fewer than 8
/// steps, a window under 10 samples, or `y` and `acc` of different lengths.
pub fn ringing(y: &[f64], acc: &[f64], dt_s: f64, window_s: f64) -> Option<Ringing> {
    const PRE: usize = 10;
    if y.len() != acc.len() || !(positive(dt_s) && positive(window_s)) {
        return None;
    }
    let win = (window_s / dt_s).round();
    if !(10.0..=1e5).contains(&win) {
        return None;
    }
    let win = win as usize;
    let steps: Vec<f64> = acc.windows(2).map(|w| w[1] - w[0]).collect();
    let biggest = steps.iter().fold(0.0_f64, |m, d| m.max(d.abs()));
    if !(positive(biggest) && biggest.is_finite()) {
        return None;
    }
    let mut sum = vec![0.0; win];
    let mut sum2 = vec![0.0; win];
    let mut events = 0usize;
    let mut next_free = PRE;
    for (i, d) in steps.iter().enumerate() {
        let e = i + 1;
        if d.abs() < RINGING_STEP_SHARE * biggest || e < next_free || e + win > y.len() {
            continue;
        }
        next_free = e + win;
        let base = y[e - PRE..e].iter().sum::<f64>() / PRE as f64;
        let sign = d.signum();
        for (j, (s, s2)) in sum.iter_mut().zip(&mut sum2).enumerate() {
            let v = sign * (y[e + j] - base);
            *s += v;
            *s2 += v * v;
        }
        events += 1;
    }
    if events < 8 {
        return None;
    }
    let n = events as f64;
    let stat: Vec<(f64, f64)> = sum
        .iter()
        .zip(&sum2)
        .map(|(s, s2)| {
            let m = s / n;
            let var = ((s2 / n - m * m) * n / (n - 1.0)).max(0.0);
            let se = (var / n).sqrt().max(f64::MIN_POSITIVE);
            (m, m / se)
        })
        .collect();
    // The overshoot that best pairs with a dip before it (each judged against its own
    // threshold of [`RINGING_T`]), not the window's deepest dip: within the window the
    // command's next step (the end of the ramp) brings a dip of its own, which can be
    // deeper than the first and has no overshoot left after it.
    let mut best: Option<(f64, usize, usize)> = None;
    let mut k_min = 0usize;
    for k in 1..win {
        if stat[k - 1].1 < stat[k_min].1 {
            k_min = k - 1;
        }
        let q = (-stat[k_min].1 / RINGING_T.0).min(stat[k].1 / RINGING_T.1);
        if best.is_none_or(|(b, _, _)| q > b) {
            best = Some((q, k_min, k));
        }
    }
    let (_, k_dip, k_rise) = best?;
    Some(Ringing {
        events,
        dip: stat[k_dip].0,
        dip_t: stat[k_dip].1,
        dip_s: k_dip as f64 * dt_s,
        rise: stat[k_rise].0,
        rise_t: stat[k_rise].1,
        rise_s: k_rise as f64 * dt_s,
    })
}
