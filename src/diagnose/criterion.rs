//! The one rule the diagnosis decides by.
//!
//! Every decision compares two models, A and B (B is A with one more thing: an effect, a
//! richer variant of one, a channel shift), both fitted on the fitting part only. B wins
//! over A when
//!
//! 1. **consistency:** cut the scoring part (the held-out part, or, for a force at times
//!    no state predicts, the fitting part it was shaped on) into [`BLOCKS`] contiguous
//!    blocks; in each, B's gain is the log-likelihood ratio of a Gaussian residual whose
//!    variance the block itself gives, ½·Σ ln(MS_A/MS_B) over the channels (position and,
//!    when recorded, force), so each channel counts by how much it changes against its own
//!    level there, and a residual B has nothing to do with cancels out. B must gain in
//!    every informative block but at most [`MISSES`] (informative: B changes the
//!    prediction there by more than one parameter's worth), and its mean gain must exceed
//!    its penalty: the Bayesian information criterion, ln(n)/2n per parameter on the
//!    part's effective samples (n over the residual's correlation length);
//! 2. **size:** on the fitting part, what B explains — the structured residual (mean
//!    square less the channel's white noise, each channel over the calibrated model's
//!    mean square there) that A leaves and B does not — exceeds [`FLOOR_SHARE`] times the
//!    floor.
//!
//! The floor is 0 while the diagnosis searches (calibration shifts, variants, forward
//! selection). When it names effects, it is what the fullest model still leaves
//! structured on the fitting part ([`Scale::floor`]): what calibration and every effect
//! together do not explain is a misfit no single effect should claim a share of, and an
//! effect is named only when it explains more than that remainder.
//!
//! The constants below are the selection's only tuning constants; each says where it
//! comes from.

use super::engine::{Eval, corr_length, rms};

/// Contiguous blocks the scoring part is cut into. Ten: with [`MISSES`] = 2, a term whose
/// held-out gain is noise (as likely below zero as above in each block) gains in at least
/// eight of ten blocks with probability 56/1024 ≈ 5.5 % (a binomial tail at p = ½); its
/// held-out mean gain must also clear its penalty, and it must explain more of the fitting
/// part than the floor to be named, which a term fitted to noise does not.
pub const BLOCKS: usize = 10;

/// Informative blocks that may fail to gain: two, for blocks where the effect is hardly
/// excited (a compliance in a block of constant feed) and the noise or another effect's
/// misfit decides the sign.
pub const MISSES: usize = 2;

/// How many times the structured remainder of the fullest model an effect must explain to
/// be named. One: a term that fits part of a misfit it does not describe (a spring
/// shaping a friction law's error, a disturbance tracing a filter's lag) takes a part of
/// that misfit and leaves the rest, so it explains less than the fullest model leaves; an
/// effect that is there explains more than all that remains.
pub const FLOOR_SHARE: f64 = 1.0;

/// A signature term below this many standard errors is no sign of the effect, and its fit
/// is skipped (the signature may skip a fit, never name an effect). Two: a term that is
/// there at its own size reads below two standard errors about as often as a Gaussian
/// falls two deviations short, 2.3 % of records.
pub const ABSENT_T: f64 = 2.0;

/// Fewest samples a block holds; a shorter scoring part has fewer blocks.
const MIN_BLOCK: usize = 20;

/// Which part of the records a comparison is scored on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Part {
    /// The held-out part (the end of the record, or a validation record).
    Held,
    /// The fitting part: for a disturbance at times no state predicts.
    Fit,
}

/// How each channel is weighed and how much of it is noise, read once from the calibrated
/// model's residual on the fitting part.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Scale {
    /// Mean square of the calibrated position residual, m².
    pub var_pos: f64,
    /// Mean square of the calibrated force residual, N² (None without force).
    pub var_force: Option<f64>,
    /// White noise of the position residual, m² (its unstructured part).
    pub noise_pos: f64,
    /// White noise of the force residual, N².
    pub noise_force: Option<f64>,
    /// Samples over which the calibrated residual stays correlated (for the report).
    pub corr_len: f64,
}

/// White-noise variance of `r`: the median absolute first difference, read as that of a
/// Gaussian (1.4826·MAD), halved (a difference carries two samples' noise). The median
/// ignores the few large differences a structured residual has at its edges.
pub fn noise_variance(r: &[f64]) -> f64 {
    let mut d: Vec<f64> = r.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    if d.is_empty() {
        return 0.0;
    }
    let mid = d.len() / 2;
    let (_, m, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
    let sigma = 1.4826 * *m;
    0.5 * sigma * sigma
}

/// Cuts `n` samples into at most [`BLOCKS`] contiguous blocks of nearly equal length.
pub fn blocks(n: usize) -> Vec<std::ops::Range<usize>> {
    let k = (n / MIN_BLOCK).clamp(1, BLOCKS);
    (0..k).map(|i| (i * n / k)..((i + 1) * n / k)).collect()
}

impl Scale {
    /// The scale of the calibrated residual `ev` (fitting part), whose correlation length
    /// is `corr_len` samples, of a position sensor that rounds to `quantum_m` (0: none):
    /// its rounding is noise of at least q²/12.
    pub fn new(ev: &Eval, corr_len: f64, quantum_m: f64) -> Scale {
        let ms = |v: &[f64]| rms(v).powi(2);
        Scale {
            var_pos: ms(&ev.fit_pos).max(1e-30),
            var_force: ev.fit_force.as_deref().map(|f| ms(f).max(1e-18)),
            noise_pos: noise_variance(&ev.fit_pos).max(quantum_m * quantum_m / 12.0),
            noise_force: ev.fit_force.as_deref().map(noise_variance),
            corr_len: corr_len.max(1.0),
        }
    }

    /// The residual of `ev` on `part`, by channel.
    fn part(ev: &Eval, part: Part) -> (&[f64], Option<&[f64]>) {
        match part {
            Part::Held => (&ev.hold_pos, ev.hold_force.as_deref()),
            Part::Fit => (&ev.fit_pos, ev.fit_force.as_deref()),
        }
    }

    /// Mean square of each channel of `pos`, `force` in the samples `r` (force: None when
    /// not recorded).
    fn ms(pos: &[f64], force: Option<&[f64]>, r: std::ops::Range<usize>) -> (f64, Option<f64>) {
        let ms = |v: &[f64]| rms(&v[r.start.min(v.len())..r.end.min(v.len())]).powi(2);
        (ms(pos), force.map(ms))
    }

    /// The loss of per-channel mean squares `m`: each channel's mean square, less its noise
    /// when `structured`, over the calibrated model's, averaged over the channels.
    fn loss(&self, m: (f64, Option<f64>), structured: bool) -> f64 {
        let noise = |n: f64| if structured { n } else { 0.0 };
        let p = (m.0 - noise(self.noise_pos)) / self.var_pos;
        match (m.1, self.var_force, self.noise_force) {
            (Some(f), Some(var), Some(nf)) => 0.5 * (p + (f - noise(nf)) / var),
            _ => p,
        }
    }

    /// What `ev` leaves structured on `part` (its mean square less the noise, per channel
    /// over the calibrated model's, averaged), and at least the sampling error of that mean
    /// square (√(2/n) of its level on the part's effective samples: how well the noise it
    /// is compared with is known). On the fitting part of the fullest model: the floor an
    /// effect must explain more than to be named.
    pub fn floor(&self, ev: &Eval, part: Part) -> f64 {
        let (pos, force) = Scale::part(ev, part);
        let m = Scale::ms(pos, force, 0..pos.len());
        let tau = corr_length(pos).max(1.0);
        let n_eff = (pos.len() as f64 / tau).max(2.0);
        let sampling = (2.0 / n_eff).sqrt() * self.loss(m, false);
        self.loss(m, true).max(sampling)
    }

    /// The whole loss of `ev` on `part`, noise included (1 on the calibrated fitting part):
    /// the level the report's shrink figures compare.
    pub fn level(&self, ev: &Eval, part: Part) -> f64 {
        let (pos, force) = Scale::part(ev, part);
        self.loss(Scale::ms(pos, force, 0..pos.len()), false)
    }

    /// The penalty per parameter on a part of `n` samples whose residual stays correlated
    /// over `corr_len` samples, as a share of the level: the Bayesian information
    /// criterion's ln(n)/n on the part's effective samples. Halved, it is the penalty per
    /// parameter of a log-likelihood gain per sample.
    pub fn penalty(n: usize, corr_len: f64) -> f64 {
        let n_eff = (n as f64 / corr_len.max(1.0)).max(2.0);
        n_eff.ln() / n_eff
    }
}

/// One comparison, with the figures that decided it.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Judgement {
    /// The part the consistency was scored on.
    pub part: Part,
    /// B's log-likelihood gain over A in each block, per sample.
    pub gains: Vec<f64>,
    /// Blocks where B changes the prediction by more than one parameter's worth.
    pub informative: usize,
    /// Informative blocks where B gains.
    pub improved: usize,
    /// Mean gain over the blocks, per sample.
    pub gain: f64,
    /// The penalty of B's added parameters on the scoring part, per sample.
    pub penalty: f64,
    /// What B explains on the fitting part (loss units).
    pub explained: f64,
    /// The floor it had to exceed (loss units).
    pub floor: f64,
    /// Whether B wins.
    pub passes: bool,
}

impl Judgement {
    /// The gain less the penalty: what B adds held out, and the ranking key.
    pub fn net(&self) -> f64 {
        self.gain - self.penalty
    }

    /// The figures in words, for the report.
    pub fn text(&self) -> String {
        format!(
            "gains in {} of {} informative blocks of the {} part, {:.4} per sample less a penalty of {:.4}; explains {:.4} of the fitting part against a floor of {:.4}",
            self.improved,
            self.informative,
            match self.part {
                Part::Held => "held-out",
                Part::Fit => "fitting",
            },
            self.gain,
            self.penalty,
            self.explained,
            self.floor
        )
    }
}

/// Judges B (`b`) against A (`a`), consistency scored on `part`: B adds `extra_params`
/// parameters and must explain more than `floor` (see the module's documentation).
pub fn judge(
    scale: &Scale,
    a: &Eval,
    b: &Eval,
    part: Part,
    extra_params: usize,
    floor: f64,
) -> Judgement {
    let (pa, fa) = Scale::part(a, part);
    let (pb, fb) = Scale::part(b, part);
    let n = pa.len().min(pb.len());
    let bl = blocks(n);
    // The noise of a gain is set by what B leaves: its correlation length on this part (of
    // the channel that decorrelates first; a position residual, an integral, stays
    // correlated over the motion even where the force residual is white).
    let tau = fb
        .map_or(f64::INFINITY, |f| corr_length(&f[..n.min(f.len())]))
        .min(corr_length(&pb[..n]))
        .clamp(1.0, (n / bl.len().max(1)).max(1) as f64);
    let pi = Scale::penalty(n, tau);
    let diff = |x: &[f64], y: &[f64]| -> Vec<f64> { x.iter().zip(y).map(|(u, v)| u - v).collect() };
    let d_pos = diff(pa, pb);
    let d_force = match (fa, fb) {
        (Some(x), Some(y)) => Some(diff(x, y)),
        _ => None,
    };
    let ln_ratio = |x: f64, y: f64| {
        if x > 0.0 && y > 0.0 {
            (x / y).ln()
        } else {
            0.0
        }
    };
    let mut gains = Vec::new();
    let (mut informative, mut improved) = (0, 0);
    for r in bl {
        let ma = Scale::ms(pa, fa, r.clone());
        let mb = Scale::ms(pb, fb, r.clone());
        let md = Scale::ms(&d_pos, d_force.as_deref(), r);
        let mut g = 0.5 * ln_ratio(ma.0, mb.0);
        let mut change = if ma.0 > 0.0 { md.0 / ma.0 } else { 0.0 };
        if let (Some(x), Some(y), Some(d)) = (ma.1, mb.1, md.1) {
            g += 0.5 * ln_ratio(x, y);
            change += if x > 0.0 { d / x } else { 0.0 };
        }
        if change > pi {
            informative += 1;
            if g > 0.0 {
                improved += 1;
            }
        }
        gains.push(g);
    }
    let gain = gains.iter().sum::<f64>() / gains.len().max(1) as f64;
    let penalty = 0.5 * pi * extra_params as f64;
    // What B explains of the fitting part, less its penalty there.
    let (fpa, ffa) = Scale::part(a, Part::Fit);
    let (fpb, ffb) = Scale::part(b, Part::Fit);
    let ma = Scale::ms(fpa, ffa, 0..fpa.len());
    let mb = Scale::ms(fpb, ffb, 0..fpb.len());
    let explained = scale.loss(ma, true) - scale.loss(mb, true);
    let consistent = informative > 0 && improved + MISSES >= informative;
    let passes = consistent && gain > penalty && explained > FLOOR_SHARE * floor;
    Judgement {
        part,
        gains,
        informative,
        improved,
        gain,
        penalty,
        explained,
        floor: FLOOR_SHARE * floor,
        passes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A record whose fitting and held-out parts are both `pos`.
    fn eval(pos: Vec<f64>) -> Eval {
        Eval {
            fit_pos: pos.clone(),
            fit_force: None,
            hold_pos: pos,
            hold_force: None,
        }
    }

    /// White noise of known variance under a slow structured part: the estimate reads the
    /// noise, not the structure.
    #[test]
    fn the_noise_estimate_reads_the_white_part_under_a_slow_one() {
        let mut x: u64 = 7;
        let mut gauss = || {
            // Box–Muller from a small LCG: deterministic.
            let mut u = || {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (a, b) = (u(), u());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        let r: Vec<f64> = (0..20_000)
            .map(|k| 5.0 * (k as f64 / 500.0).sin() + 0.3 * gauss())
            .collect();
        let v = noise_variance(&r);
        assert!((v / 0.09 - 1.0).abs() < 0.05, "{v}");
    }

    /// A term that halves the residual everywhere wins with no floor and with a floor below
    /// what it explains; against a floor larger than its gain it does not.
    #[test]
    fn a_consistent_gain_wins_unless_the_floor_is_larger() {
        let base = eval(
            (0..2000)
                .map(|k: usize| if k.is_multiple_of(2) { 1.0 } else { -1.0 })
                .collect(),
        );
        let half = eval(base.hold_pos.iter().map(|v| 0.5 * v).collect());
        let scale = Scale::new(&base, 1.0, 0.0);
        let j = judge(&scale, &base, &half, Part::Held, 1, 0.0);
        assert!(j.passes, "{j:?}");
        assert_eq!(j.improved, BLOCKS);
        // ½·ln(1/0.25) per sample.
        assert!((j.gain - 0.5 * 4f64.ln()).abs() < 1e-9, "{}", j.gain);
        // Three quarters of the fitting part's mean square.
        assert!((j.explained - 0.75).abs() < 1e-9, "{}", j.explained);
        assert!(judge(&scale, &base, &half, Part::Held, 1, 0.5).passes);
        assert!(!judge(&scale, &base, &half, Part::Held, 1, 0.8).passes);
    }

    /// A term that helps in half the blocks and hurts in the others is not consistent,
    /// however large its mean gain.
    #[test]
    fn a_gain_in_some_blocks_only_is_not_consistent() {
        let sign = |k: usize| if k.is_multiple_of(2) { 1.0 } else { -1.0 };
        let base = eval((0..2000).map(sign).collect());
        let mixed = eval(
            (0..2000)
                .map(|k| sign(k) * if k < 1000 { 0.1 } else { 1.2 })
                .collect(),
        );
        let scale = Scale::new(&base, 1.0, 0.0);
        let j = judge(&scale, &base, &mixed, Part::Held, 1, 0.0);
        assert!(j.gain > 0.0, "{j:?}");
        assert!(!j.passes, "{j:?}");
    }

    /// Blocks where the two models agree say nothing: a change confined to two blocks is
    /// judged on those two.
    #[test]
    fn blocks_the_term_does_not_touch_are_not_counted() {
        let sign = |k: usize| if k.is_multiple_of(2) { 1.0 } else { -1.0 };
        let base = eval((0..2000).map(sign).collect());
        let local = eval(
            (0..2000)
                .map(|k| sign(k) * if k < 400 { 0.1 } else { 1.0 })
                .collect(),
        );
        let scale = Scale::new(&base, 1.0, 0.0);
        let j = judge(&scale, &base, &local, Part::Held, 1, 0.0);
        assert_eq!(j.informative, 2, "{j:?}");
        assert!(j.passes, "{j:?}");
    }
}
