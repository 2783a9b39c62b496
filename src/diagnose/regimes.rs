//! "Where": the regimes of motion read from the measured command, and residual statistics
//! per regime, per position/base/time bin, and for the worst time windows.

use serde::Serialize;

/// Phase of motion a sample belongs to, read from the commanded position: where in the
/// motion a residual sits points to its cause (friction at reversals, inertia in ramps).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Regime {
    /// Around a change from positive to negative speed (widened by [`REVERSAL_HALF_WINDOW_S`]
    /// each side).
    ReversalPosToNeg,
    /// Around a change from negative to positive speed (widened likewise).
    ReversalNegToPos,
    /// Speed magnitude rising (|acceleration| above 2 % of the command's peak acceleration).
    Acceleration,
    /// Speed magnitude falling (|deceleration| above 2 % of the command's peak acceleration).
    Deceleration,
    /// Moving at near-constant speed (|acceleration| within 2 % of the command's peak
    /// acceleration).
    ConstantFeed,
    /// Not moving: speed within 0.1 % of the command's peak speed.
    Standstill,
}

impl Regime {
    /// Every regime, in the order reports list them.
    pub const ALL: [Regime; 6] = [
        Regime::ReversalPosToNeg,
        Regime::ReversalNegToPos,
        Regime::Acceleration,
        Regime::Deceleration,
        Regime::ConstantFeed,
        Regime::Standstill,
    ];

    /// The snake_case name used in reports and the serialized report.
    pub fn name(self) -> &'static str {
        match self {
            Regime::ReversalPosToNeg => "reversal_pos_to_neg",
            Regime::ReversalNegToPos => "reversal_neg_to_pos",
            Regime::Acceleration => "acceleration",
            Regime::Deceleration => "deceleration",
            Regime::ConstantFeed => "constant_feed",
            Regime::Standstill => "standstill",
        }
    }
}

/// How long either side of a command reversal counts as "reversal".
pub const REVERSAL_HALF_WINDOW_S: f64 = 0.05;

/// Labels every sample of a command. Reversal windows win over the other regimes; the
/// thresholds are relative to the command's own peak speed and acceleration, so they work
/// for any machine size.
pub fn classify(cmd_m: &[f64], t3_s: f64) -> Vec<Regime> {
    let n = cmd_m.len();
    let mut v = vec![0.0; n];
    for i in 1..n.saturating_sub(1) {
        v[i] = (cmd_m[i + 1] - cmd_m[i - 1]) / (2.0 * t3_s);
    }
    if n >= 2 {
        v[0] = v[1];
        v[n - 1] = v[n - 2];
    }
    // Smooth over ~5 ms so that a quantized command does not flicker between regimes.
    let h = ((0.0025 / t3_s).round() as usize).max(1);
    let vs = moving_avg(&v, h);
    let mut a = vec![0.0; n];
    for i in 1..n.saturating_sub(1) {
        a[i] = (vs[i + 1] - vs[i - 1]) / (2.0 * t3_s);
    }
    let as_ = moving_avg(&a, h);
    let vmax = vs.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let amax = as_.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let v_eps = 1e-3 * vmax.max(1e-9);
    let a_eps = 0.02 * amax.max(1e-9);
    let mut out: Vec<Regime> = (0..n)
        .map(|i| {
            if vs[i].abs() <= v_eps {
                Regime::Standstill
            } else if as_[i].abs() <= a_eps {
                Regime::ConstantFeed
            } else if as_[i] * vs[i] > 0.0 {
                Regime::Acceleration
            } else {
                Regime::Deceleration
            }
        })
        .collect();
    let w = ((REVERSAL_HALF_WINDOW_S / t3_s).round() as usize).max(1);
    let mut last_dir = 0.0;
    let mut last_moving = 0usize;
    for (i, &v) in vs.iter().enumerate() {
        if v.abs() <= v_eps {
            continue;
        }
        let d = v.signum();
        if last_dir != 0.0 && d != last_dir {
            // The reversal is the span between the last sample of the old direction and the
            // first of the new one, widened on both sides.
            let lo = last_moving.saturating_sub(w);
            let hi = (i + w).min(n);
            let r = if last_dir > 0.0 {
                Regime::ReversalPosToNeg
            } else {
                Regime::ReversalNegToPos
            };
            out[lo..hi].iter_mut().for_each(|x| *x = r);
        }
        last_dir = d;
        last_moving = i;
    }
    out
}

fn moving_avg(x: &[f64], h: usize) -> Vec<f64> {
    let n = x.len();
    let mut pre = vec![0.0; n + 1];
    for i in 0..n {
        pre[i + 1] = pre[i] + x[i];
    }
    (0..n)
        .map(|i| {
            let lo = i.saturating_sub(h);
            let hi = (i + h + 1).min(n);
            (pre[hi] - pre[lo]) / (hi - lo) as f64
        })
        .collect()
}

/// Residual statistics of one regime: how much of the misfit lies in that phase of motion.
#[derive(Debug, Clone, Serialize)]
pub struct RegimeStat {
    /// The regime's [`Regime::name`].
    pub name: String,
    /// Fraction of the residual energy (Σr²) in this regime.
    pub share: f64,
    /// Residual RMS over the regime's samples, in the residual's unit (µm in a report).
    pub rms: f64,
    /// Largest |residual| in the regime, same unit.
    pub peak: f64,
    /// Number of samples labelled with the regime.
    pub samples: usize,
}

/// Share, RMS and peak of `r` per regime (regimes with no samples are left out).
pub fn per_regime(r: &[f64], labels: &[Regime]) -> Vec<RegimeStat> {
    let total: f64 = r.iter().map(|x| x * x).sum::<f64>().max(f64::MIN_POSITIVE);
    Regime::ALL
        .iter()
        .filter_map(|&g| {
            let (mut e, mut pk, mut n) = (0.0, 0.0f64, 0usize);
            for (x, _) in r.iter().zip(labels).filter(|(_, l)| **l == g) {
                e += x * x;
                pk = pk.max(x.abs());
                n += 1;
            }
            (n > 0).then(|| RegimeStat {
                name: g.name().to_owned(),
                share: e / total,
                rms: (e / n as f64).sqrt(),
                peak: pk,
                samples: n,
            })
        })
        .collect()
}

/// Residual statistics of one bin of position, base position or time: a misfit tied to a
/// place (lead error, sag) or a moment (drift) shows as uneven bins.
#[derive(Debug, Clone, Serialize)]
pub struct BinStat {
    /// Lower edge of the bin, in the key's unit (mm for positions, s for time).
    pub lo: f64,
    /// Upper edge of the bin, same unit.
    pub hi: f64,
    /// Fraction of the residual energy (Σr²) in this bin.
    pub share: f64,
    /// Residual RMS over the bin's samples (0 if empty), in the residual's unit (µm in a
    /// report).
    pub rms: f64,
    /// Largest |residual| in the bin, same unit.
    pub peak: f64,
    /// Number of samples whose key falls in the bin.
    pub samples: usize,
}

/// Residual statistics in `nbins` equal bins of `key` (position, base position or time).
pub fn per_bin(r: &[f64], key: &[f64], nbins: usize) -> Vec<BinStat> {
    let (lo, hi) = key
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) || nbins == 0 {
        return vec![];
    }
    let total: f64 = r.iter().map(|x| x * x).sum::<f64>().max(f64::MIN_POSITIVE);
    let w = (hi - lo) / nbins as f64;
    let mut acc = vec![(0.0, 0.0f64, 0usize); nbins];
    for (&x, &k) in r.iter().zip(key) {
        let b = (((k - lo) / w) as usize).min(nbins - 1);
        acc[b].0 += x * x;
        acc[b].1 = acc[b].1.max(x.abs());
        acc[b].2 += 1;
    }
    acc.into_iter()
        .enumerate()
        .map(|(i, (e, pk, n))| BinStat {
            lo: lo + i as f64 * w,
            hi: lo + (i + 1) as f64 * w,
            share: e / total,
            rms: if n > 0 { (e / n as f64).sqrt() } else { 0.0 },
            peak: pk,
            samples: n,
        })
        .collect()
}

/// A short time span with a large residual peak: points at the individual events where the
/// model fails worst.
#[derive(Debug, Clone, Serialize)]
pub struct Window {
    /// Start time of the window, s (record time).
    pub t_start: f64,
    /// End time of the window, s.
    pub t_end: f64,
    /// Largest |residual| in the window, in the residual's unit (µm in a report).
    pub peak: f64,
}

/// The `count` windows of length `len` samples with the highest peak |r|, worst first,
/// none overlapping.
pub fn worst_windows(r: &[f64], t0_s: f64, t3_s: f64, len: usize, count: usize) -> Vec<Window> {
    let len = len.max(1);
    let mut blocks: Vec<(usize, f64)> = r
        .chunks(len)
        .enumerate()
        .map(|(b, c)| (b, c.iter().fold(0.0f64, |m, x| m.max(x.abs()))))
        .collect();
    blocks.sort_by(|a, b| b.1.total_cmp(&a.1));
    let mut taken: Vec<usize> = Vec::new();
    let mut out = Vec::new();
    for (b, pk) in blocks {
        if out.len() >= count {
            break;
        }
        // Skip neighbours of a window already taken: one event, one entry.
        if taken.iter().any(|&t| t.abs_diff(b) <= 1) {
            continue;
        }
        taken.push(b);
        let i0 = b * len;
        let i1 = ((b + 1) * len).min(r.len());
        out.push(Window {
            t_start: t0_s + i0 as f64 * t3_s,
            t_end: t0_s + i1 as f64 * t3_s,
            peak: pk,
        });
    }
    out
}
