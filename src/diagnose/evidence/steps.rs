//! Level changes and bursts: a residual that jumps (a collision, a slipped coupling, a
//! re-referenced axis) or that flares up for a while (chatter, a loose part).

use super::{median, normalized, ordered, positive};

/// At most this many steps are reported: segmentation costs O(n) per accepted step.
const MAX_STEPS: usize = 100;

/// At most this many bursts are reported.
const MAX_BURSTS: usize = 10_000;

/// At most this many short-time RMS values enter the median.
const MEDIAN_CAP: usize = 1 << 16;

/// Largest significance reported (noise-free steps would otherwise be infinite).
const SIGNIFICANCE_CAP: f64 = 1e12;

/// A level change in y: the signature of an event that shifts the residual for good.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// Index of the first sample at the new level.
    pub index: usize,
    /// New level minus old level (means of the segments between neighbouring steps).
    pub jump: f64,
    /// t-like significance: |jump| / (noise std · sqrt(1/n1 + 1/n2)), n1 and n2 the
    /// lengths of the segments on either side; the noise std is robust (from the median
    /// absolute first difference), so it assumes noise that is roughly white.
    pub significance: f64,
}

/// Binary segmentation of y into constant levels: repeatedly splits the segment whose best
/// split is most significant, while that split's significance ≥ min_significance, keeping
/// steps ≥ min_gap samples apart (and from the ends); at most min(max_steps, 100) steps.
/// Jumps and significances are then re-estimated between neighbouring steps and steps that
/// fall below min_significance are dropped. Returned in index order.
///
/// Time is O(n · (steps + 1)). A slow trend or strongly correlated noise makes steps
/// appear where there are none (the noise std comes from first differences): high-pass or
/// detrend such a y first. Empty for a constant y or n < 2·min_gap.
pub fn steps(y: &[f64], min_gap: usize, min_significance: f64, max_steps: usize) -> Vec<Step> {
    steps_to_end(y, min_gap, min_gap, min_significance, max_steps)
}

/// [`steps`] with the last step allowed as close as `end_gap` samples to y's end (at most
/// `min_gap`). A diagnosis extrapolates the last level into the held-out part that follows
/// the end, so a change shortly before the end decides that level.
pub fn steps_to_end(
    y: &[f64],
    min_gap: usize,
    end_gap: usize,
    min_significance: f64,
    max_steps: usize,
) -> Vec<Step> {
    let gap = min_gap.max(1);
    let end_gap = end_gap.clamp(1, gap);
    let n = y.len();
    let cap = max_steps.min(MAX_STEPS);
    if n < gap.saturating_add(end_gap) || cap == 0 || min_significance.is_nan() {
        return vec![];
    }
    let Some((ys, scale)) = normalized(y) else {
        return vec![];
    };
    let sigma = noise_std(&ys);
    if !positive(sigma) {
        return vec![];
    }
    let mut prefix = Vec::with_capacity(n + 1);
    prefix.push(0.0);
    for v in &ys {
        prefix.push(prefix[prefix.len() - 1] + v);
    }
    let seg = Segments {
        prefix: &prefix,
        sigma,
        gap,
        end_gap,
    };
    // Open segments with their best split: (significance, start, end, split).
    let mut open: Vec<(f64, usize, usize, usize)> = seg.best(0, n).into_iter().collect();
    let mut cuts: Vec<usize> = vec![];
    while cuts.len() < cap {
        let Some(i) = (0..open.len()).max_by(|&a, &b| open[a].0.total_cmp(&open[b].0)) else {
            break;
        };
        let (t, a, b, k) = open.swap_remove(i);
        if !ordered(min_significance, t) {
            break;
        }
        cuts.push(k);
        open.extend(seg.best(a, k));
        open.extend(seg.best(k, b));
    }
    cuts.sort_unstable();
    let mut bounds = vec![0];
    bounds.extend(&cuts);
    bounds.push(n);
    bounds
        .windows(3)
        .filter_map(|w| {
            let (jump, t) = seg.split(w[0], w[1], w[2]);
            (t >= min_significance).then_some(Step {
                index: w[1],
                jump: jump * scale,
                significance: t.min(SIGNIFICANCE_CAP),
            })
        })
        .collect()
}

/// Noise std from the median absolute first difference (steps are rare, so they barely
/// move it); the RMS of the differences when more than half of them are zero.
fn noise_std(y: &[f64]) -> f64 {
    let mut d: Vec<f64> = y.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    let mad = median(&mut d) / 0.674_489_750_196_081_7 / std::f64::consts::SQRT_2;
    if mad > 0.0 {
        return mad;
    }
    let ms = d.iter().map(|v| v * v).sum::<f64>() / d.len().max(1) as f64;
    (ms / 2.0).sqrt()
}

struct Segments<'a> {
    prefix: &'a [f64],
    sigma: f64,
    gap: usize,
    /// The gap kept before y's end.
    end_gap: usize,
}

impl Segments<'_> {
    /// Jump (mean of [k, b) minus mean of [a, k)) and its significance.
    fn split(&self, a: usize, k: usize, b: usize) -> (f64, f64) {
        let (n1, n2) = ((k - a) as f64, (b - k) as f64);
        let m1 = (self.prefix[k] - self.prefix[a]) / n1;
        let m2 = (self.prefix[b] - self.prefix[k]) / n2;
        let jump = m2 - m1;
        (
            jump,
            jump.abs() / (self.sigma * (1.0 / n1 + 1.0 / n2).sqrt()),
        )
    }

    /// The most significant split of [a, b) leaving ≥ gap samples on each side (≥ end_gap
    /// before y's end). With s1 the sum of [a, k), T of [a, b) and n = b − a, the
    /// significance squared is (s1·n − T·n1)² / (n1·n2·n·σ²): one division per candidate.
    fn best(&self, a: usize, b: usize) -> Option<(f64, usize, usize, usize)> {
        let p = self.prefix;
        let after = if b + 1 == p.len() {
            self.end_gap
        } else {
            self.gap
        };
        if b < a.saturating_add(self.gap).saturating_add(after) {
            return None;
        }
        let n = (b - a) as f64;
        let total = p[b] - p[a];
        let (mut best_k, mut best_v) = (a + self.gap, f64::NEG_INFINITY);
        for k in a + self.gap..=b - after {
            let n1 = (k - a) as f64;
            let num = (p[k] - p[a]) * n - total * n1;
            let v = num * num / (n1 * (n - n1));
            if v > best_v {
                best_v = v;
                best_k = k;
            }
        }
        let t = (best_v / n).sqrt() / self.sigma;
        Some((if t.is_finite() { t } else { 0.0 }, a, b, best_k))
    }
}

/// A burst: a stretch where y's short-time RMS exceeds `factor` × its median, the
/// signature of an intermittent effect (chatter, a collision, a loose part).
#[derive(Debug, Clone, PartialEq)]
pub struct Burst {
    /// First sample of the burst.
    pub start: usize,
    /// One past the last sample of the burst.
    pub end: usize,
    /// Mean of y over the burst.
    pub mean: f64,
    /// RMS of y (about zero) over the burst.
    pub rms: f64,
}

/// Finds bursts: windows of ~`window` samples (4 hops of ⌈window/4⌉ samples, so the
/// windows step by a quarter window) whose RMS about zero exceeds `factor` × the median
/// window RMS; overlapping windows merge into one burst. The median comes from at most 65 536
/// windows (strided). At most 10 000 bursts, in order. With a median of zero (y mostly
/// zero), any window with energy is a burst. Empty for an all-zero y, factor ≤ 0 or no
/// samples.
pub fn bursts(y: &[f64], window: usize, factor: f64) -> Vec<Burst> {
    let n = y.len();
    if n == 0 || !positive(factor) {
        return vec![];
    }
    let Some((ys, scale)) = normalized(y) else {
        return vec![];
    };
    let hop = window.clamp(1, n).div_ceil(4);
    let energy: Vec<(f64, usize)> = ys
        .chunks(hop)
        .map(|c| (c.iter().map(|v| v * v).sum(), c.len()))
        .collect();
    let span = energy.len().min(4);
    let rms: Vec<f64> = energy
        .windows(span)
        .map(|w| {
            let (e, c) = w.iter().fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
            (e / c as f64).sqrt()
        })
        .collect();
    let stride = rms.len().div_ceil(MEDIAN_CAP).max(1);
    let thr = factor * median(&mut rms.iter().step_by(stride).copied().collect::<Vec<_>>());
    // Runs of windows above the threshold, as sample ranges, merged where they overlap.
    let mut runs: Vec<(usize, usize)> = vec![];
    let mut j = 0;
    while j < rms.len() && runs.len() < MAX_BURSTS {
        if rms[j] <= thr {
            j += 1;
            continue;
        }
        let first = j;
        while j < rms.len() && rms[j] > thr {
            j += 1;
        }
        // Windows first..j cover hops first..j-1+span.
        let (start, end) = (first * hop, ((j - 1 + span) * hop).min(n));
        match runs.last_mut() {
            Some(last) if start <= last.1 => last.1 = end,
            _ => runs.push((start, end)),
        }
    }
    runs.into_iter()
        .map(|(start, end)| {
            let seg = &ys[start..end];
            let len = seg.len().max(1) as f64;
            Burst {
                start,
                end,
                mean: seg.iter().sum::<f64>() / len * scale,
                rms: (seg.iter().map(|v| v * v).sum::<f64>() / len).sqrt() * scale,
            }
        })
        .collect()
}
