//! The common ground of the diagnosis: which part of the record fits and which is held out,
//! a candidate model and its residuals on both parts, the normalised residual the solver
//! sees, and the held-out scores every candidate is ranked by.

use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::DVector;

use super::replay::{Disturbance, Model, Record, SimOut, simulate};
use super::{DiagnoseError, Progress};

/// Samples of each channel whose residuals go to the least-squares solver at most; a longer
/// fitting part is strided. The solver's work per iteration (its QR and the rows
/// themselves, a third of a diagnosis at 60 000) grows with its rows. The independent
/// check's records (24 s at 1 kHz, 30 % held out: 16 801 fitting samples), on which every
/// threshold was set, and the EMPS pulse record (17 389) are not strided.
const MAX_LM_ROWS: usize = 17_400;
/// The solver's iterations replay at most this many samples of the fitting part (its
/// beginning); a fitted candidate is then scored on all of it. The iterations are most of
/// a diagnosis's work, and each replays its samples one after the other, so this bounds
/// the cost of a long record: a 60 s record is fitted on about as much as a 24 s one, which
/// is what the thresholds were set on. 17 400 samples are hundreds of correlation lengths of
/// every effect but a screw's growth (see [`MAX_LM_SAMPLES_SLOW`]); the independent check's
/// records and the EMPS pulse record are replayed whole (the EMPS training record, fitted
/// whole beside its validation record, is cut at 17 400 of 24 841: Fc 19.86 N against
/// 19.84 N at 20 000). On the 76 unskewed 60 s records of independent seed 5959 (42 000
/// fitting samples) the diagnosis took 1.2–7.5 s (median 3.1 s, 12 over 5 s) with 20 000
/// here at stop 54; 1.2–6.3 s (3.0 s, 8 over) with the fit order of `candidates::fit_all`
/// (stop 55); 1.1–6.4 s (2.6 s, 3 over) with 17 400 as well. Three of the 76 verdicts
/// changed with 17 400, none losing its hidden effect.
pub const MAX_LM_SAMPLES: usize = 17_400;

/// … and this many when a screw's growth is fitted (as the candidate or beside it): its
/// time constant is minutes, and fitted on the first 20 s of a 60 s record the growth left
/// a drift that a lead error's slope then took (seed 5050 case_045 and case_047).
pub const MAX_LM_SAMPLES_SLOW: usize = 200_000;

/// Where the fitting part ends and where the held-out part comes from.
pub struct Split<'a> {
    /// The record fitted on (all of it when a validation record is given).
    pub main: &'a Record,
    /// Samples of `main` the fits use.
    pub n_fit: usize,
    /// A separate held-out record, or None to hold out the end of `main`.
    pub validate: Option<&'a Record>,
}

impl<'a> Split<'a> {
    /// Checks the records and splits them.
    pub fn new(
        main: &'a Record,
        validate: Option<&'a Record>,
        holdout: f64,
    ) -> Result<Split<'a>, DiagnoseError> {
        let n_fit = match validate {
            Some(v) => {
                if v.axis != main.axis {
                    return Err(DiagnoseError::Input(format!(
                        "the validation record is axis '{}', the fitting record '{}'",
                        v.axis, main.axis
                    )));
                }
                if v.len() < 10 {
                    return Err(DiagnoseError::Input(
                        "the validation record has fewer than 10 samples".into(),
                    ));
                }
                if v.force_n.is_some() != main.force_n.is_some() {
                    return Err(DiagnoseError::Input(
                        "one record has a force column and the other has not; map both the same way".into(),
                    ));
                }
                main.len()
            }
            None => ((1.0 - holdout) * main.len() as f64).round() as usize,
        };
        if n_fit < 10 || (validate.is_none() && main.len() - n_fit < 10) {
            return Err(DiagnoseError::Input(format!(
                "{} samples are too few to split into fitting and held-out parts",
                main.len()
            )));
        }
        Ok(Split {
            main,
            n_fit,
            validate,
        })
    }

    /// The measured positions of the held-out part, m.
    pub fn hold_pos_m(&self) -> &[f64] {
        match self.validate {
            Some(v) => &v.pos_m,
            None => self.main.pos_m.get(self.n_fit..).unwrap_or(&[]),
        }
    }
}

/// A candidate: the model (its disturbances are those of the main record) plus the
/// disturbances found on a separate validation record.
#[derive(Debug, Clone)]
pub struct Cand {
    /// The model, with the main record's disturbances.
    pub model: Model,
    /// Disturbances of the validation record.
    pub dist_val: Vec<Disturbance>,
}

/// Residuals (measured − simulated) of one candidate, in m and N.
#[derive(Debug, Clone, Default)]
pub struct Eval {
    /// Position residual on the fitting part.
    pub fit_pos: Vec<f64>,
    /// Force residual on the fitting part.
    pub fit_force: Option<Vec<f64>>,
    /// Position residual on the held-out part.
    pub hold_pos: Vec<f64>,
    /// Force residual on the held-out part.
    pub hold_force: Option<Vec<f64>>,
}

/// How a candidate changes the residual.
#[derive(Debug, Clone, Copy, Default)]
pub struct Scores {
    /// Position residual RMS on the fitting part before, m.
    pub fit_pos_before: f64,
    /// … and after.
    pub fit_pos_after: f64,
    /// Held-out position residual RMS before, m.
    pub hold_pos_before: f64,
    /// … and after.
    pub hold_pos_after: f64,
    /// Held-out shrink of the combined residual, 0..1.
    pub shrink: f64,
    /// Held-out shrink of the position residual.
    pub shrink_pos: f64,
    /// Held-out shrink of the force residual.
    pub shrink_force: Option<f64>,
    /// Shrink of the combined residual on the fitting part (set by the candidate scoring).
    pub fit_shrink: f64,
    /// Shrink minus the complexity penalty: the ranking key.
    pub score: f64,
    /// Whether the effect counts as found.
    pub significant: bool,
}

/// Complexity penalty per fitted parameter, in units of held-out shrink.
pub const PENALTY_PER_PARAM: f64 = 0.02;

pub(crate) fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

pub(crate) fn peak(x: &[f64]) -> f64 {
    x.iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

fn resid(meas: &[f64], sim: &[f64]) -> Vec<f64> {
    meas.iter().zip(sim).map(|(m, s)| m - s).collect()
}

/// The residuals and scores of candidates on one split.
pub struct Engine<'a> {
    /// The records.
    pub split: Split<'a>,
    progress: &'a Progress<'a>,
    /// Whether the records have force.
    pub has_force: bool,
    /// Normalisation of the position residual, m.
    pub sig_pos: f64,
    /// Normalisation of the force residual, N.
    pub sig_force: f64,
    /// Stride of the solver's rows for a replay of [`Engine::n_lm`]`(false)` samples.
    pub stride: usize,
    /// Samples over which the baseline's residual stays correlated.
    pub corr_len: f64,
    /// Held-out samples the state-dependent candidates are scored on: blocks whose baseline
    /// residual is far beyond anything in the fitting data (a disturbance the fitting data
    /// never showed) are left out, so that they do not drown the score of an effect that is
    /// present in both. The overall before/after figures keep them.
    pub hold_mask: Vec<bool>,
    /// Samples of the moving average the held-out residuals of slow effects are scored
    /// through when asked (1: none).
    pub smooth_n: usize,
    /// Mean square of the position residual that no replay can take away, m²: the rounding
    /// of a scale grid proven by its signature (a grid of `q` rounds with a spread of
    /// `q²/12`). Scores of the effects that act within a few samples are taken on what lies
    /// above it (0: none).
    pub pos_floor_ms: f64,
    sims: AtomicUsize,
    /// Replays expected in all (for the progress bar).
    pub sims_expected: AtomicUsize,
    /// Wall time of each job of the last round of candidate fits, s, by its label: the next
    /// round starts the longest first (see `candidates::fit_all`).
    pub job_secs: std::sync::Mutex<std::collections::BTreeMap<String, f64>>,
    /// The parameters each warm-started fit found in the last round where it ran, by its
    /// label: the next round starts it there (see `candidates::Context::fit_lm_defs`).
    pub last_theta: std::sync::Mutex<std::collections::BTreeMap<String, Vec<f64>>>,
    /// Whether the fits use `last_theta` (`Options::warm_starts`).
    pub warm_starts: bool,
}

impl<'a> Engine<'a> {
    /// An engine whose normalisation comes from the residual of `base`.
    pub fn new(
        split: Split<'a>,
        base: &Cand,
        progress: &'a Progress<'a>,
    ) -> Result<(Engine<'a>, Eval), DiagnoseError> {
        let has_force = split.main.force_n.is_some();
        let mut e = Engine {
            split,
            progress,
            has_force,
            sig_pos: 1.0,
            sig_force: 1.0,
            stride: 1,
            corr_len: 1.0,
            hold_mask: vec![],
            smooth_n: 1,
            pos_floor_ms: 0.0,
            sims: AtomicUsize::new(0),
            sims_expected: AtomicUsize::new(200),
            job_secs: std::sync::Mutex::new(std::collections::BTreeMap::new()),
            last_theta: std::sync::Mutex::new(std::collections::BTreeMap::new()),
            warm_starts: true,
        };
        e.stride = Engine::stride_of(e.n_lm(false));
        let ev = e.evaluate(base)?;
        for v in [&ev.fit_pos, &ev.hold_pos] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(DiagnoseError::Input(
                    "the model's position diverged during the replay; check the preset's servo gains against the record".into(),
                ));
            }
        }
        e.set_scale(&ev);
        Ok((e, ev))
    }

    /// Normalises position and force by the fitting residual of `ev` (each round of the
    /// selection weighs the two by what is left of each on its base), keeping the anomaly
    /// mask; returns the normalisation it replaced.
    pub fn set_norm(&mut self, ev: &Eval) -> (f64, f64) {
        let old = (self.sig_pos, self.sig_force);
        self.sig_pos = rms(&ev.fit_pos).max(1e-12);
        self.sig_force = ev.fit_force.as_deref().map_or(1.0, rms).max(1e-9);
        old
    }

    /// Puts back a normalisation [`Engine::set_norm`] returned.
    pub fn restore_norm(&mut self, norm: (f64, f64)) {
        (self.sig_pos, self.sig_force) = norm;
    }

    /// Takes the normalisation (and the anomaly mask) from the residual `ev`.
    pub fn set_scale(&mut self, ev: &Eval) {
        self.sig_pos = rms(&ev.fit_pos).max(1e-12);
        self.sig_force = ev.fit_force.as_deref().map_or(1.0, rms).max(1e-9);
        self.corr_len = corr_length(&ev.fit_pos);
        self.hold_mask = self.anomaly_mask(ev);
    }

    /// Replays of the record this engine has run.
    pub fn replays(&self) -> usize {
        self.sims.load(Ordering::Relaxed)
    }

    /// Reports progress and honours a cancel.
    pub fn tick(&self, what: &str) -> Result<(), DiagnoseError> {
        self.progress.check()?;
        let d = self.sims.fetch_add(1, Ordering::Relaxed) + 1;
        let exp = self.sims_expected.load(Ordering::Relaxed).max(d + 1);
        (self.progress.report)((d as f64 / exp as f64).min(0.99), what);
        Ok(())
    }

    /// Samples the solver's iterations replay (`slow`: a fit with a screw's growth in it,
    /// see [`MAX_LM_SAMPLES_SLOW`]).
    pub fn n_lm(&self, slow: bool) -> usize {
        self.split.n_fit.min(if slow {
            MAX_LM_SAMPLES_SLOW
        } else {
            MAX_LM_SAMPLES
        })
    }

    /// Simulates the part of the fitting data the solver uses.
    pub fn sim_fit(&self, c: &Cand) -> Result<SimOut, DiagnoseError> {
        self.sim_fit_as(c, false)
    }

    /// [`Engine::sim_fit`] for a fit with a screw's growth in it when `slow`.
    pub fn sim_fit_as(&self, c: &Cand, slow: bool) -> Result<SimOut, DiagnoseError> {
        self.tick("fitting")?;
        Ok(simulate(&c.model, self.split.main, self.n_lm(slow)))
    }

    /// The stride of the solver's rows for a replay of `n` samples (see [`MAX_LM_ROWS`]).
    pub fn stride_of(n: usize) -> usize {
        n.div_ceil(MAX_LM_ROWS).max(1)
    }

    /// Simulates both parts and returns the residuals.
    pub fn evaluate(&self, c: &Cand) -> Result<Eval, DiagnoseError> {
        self.tick("scoring")?;
        let main = self.split.main;
        let nf = self.split.n_fit;
        let n_main = if self.split.validate.is_some() {
            nf
        } else {
            main.len()
        };
        let s = simulate(&c.model, main, n_main);
        let pos = resid(&main.pos_m[..n_main], &s.pos_m);
        let force = main
            .force_n
            .as_ref()
            .map(|f| resid(&f[..n_main], &s.force_n));
        match self.split.validate {
            None => Ok(Eval {
                fit_pos: pos[..nf].to_vec(),
                fit_force: force.as_ref().map(|f| f[..nf].to_vec()),
                hold_pos: pos[nf..].to_vec(),
                hold_force: force.as_ref().map(|f| f[nf..].to_vec()),
            }),
            Some(v) => {
                let mut mv = c.model.clone();
                mv.disturbance.clone_from(&c.dist_val);
                let sv = simulate(&mv, v, v.len());
                Ok(Eval {
                    fit_pos: pos,
                    fit_force: force,
                    hold_pos: resid(&v.pos_m, &sv.pos_m),
                    hold_force: v.force_n.as_ref().map(|f| resid(f, &sv.force_n)),
                })
            }
        }
    }

    fn anomaly_mask(&self, ev: &Eval) -> Vec<bool> {
        let t3 = self.split.main.t3_s;
        let w = ((0.1 / t3).round() as usize).max(1);
        let cf = self.combined(&ev.fit_pos, ev.fit_force.as_deref());
        let ch = self.combined(&ev.hold_pos, ev.hold_force.as_deref());
        let mut fb: Vec<f64> = cf.chunks(w).map(rms).collect();
        fb.sort_by(f64::total_cmp);
        let p95 = fb
            .get(fb.len() * 95 / 100)
            .copied()
            .unwrap_or(f64::INFINITY);
        let thr = 3.0 * p95;
        let mut mask = Vec::with_capacity(ch.len());
        for c in ch.chunks(w) {
            mask.extend(std::iter::repeat_n(rms(c) <= thr, c.len()));
        }
        // Never score on nothing: if most of the held-out part is anomalous, keep it all.
        if mask.iter().filter(|k| **k).count() * 5 < mask.len() {
            mask.iter_mut().for_each(|k| *k = true);
        }
        mask
    }

    /// Samples of `v` where the held-out mask is set.
    fn masked(&self, v: &[f64]) -> Vec<f64> {
        v.iter()
            .zip(&self.hold_mask)
            .filter(|(_, k)| **k)
            .map(|(x, _)| *x)
            .collect()
    }

    /// Combined normalised RMS of position and force residuals.
    pub fn j(&self, pos: &[f64], force: Option<&[f64]>) -> f64 {
        let p = rms(pos) / self.sig_pos;
        match force {
            Some(f) if self.has_force => {
                let q = rms(f) / self.sig_force;
                (0.5 * (p * p + q * q)).sqrt()
            }
            _ => p,
        }
    }

    /// Per-sample combined residual magnitude (for locating events).
    pub fn combined(&self, pos: &[f64], force: Option<&[f64]>) -> Vec<f64> {
        match force {
            Some(f) if self.has_force => pos
                .iter()
                .zip(f)
                .map(|(p, q)| {
                    let a = p / self.sig_pos;
                    let b = q / self.sig_force;
                    (0.5 * (a * a + b * b)).sqrt()
                })
                .collect(),
            _ => pos.iter().map(|p| (p / self.sig_pos).abs()).collect(),
        }
    }

    /// The normalised fitting residual of a simulation, strided: the solver's rows.
    pub fn lm_rows(&self, s: &SimOut) -> DVector<f64> {
        self.lm_rows_shifted(s, 0.0, 0.0)
    }

    /// [`Engine::lm_rows`] with the simulated position and force read `pos_shift` and
    /// `force_shift` samples later (a channel logged off its instant).
    pub fn lm_rows_shifted(&self, s: &SimOut, pos_shift: f64, force_shift: f64) -> DVector<f64> {
        let main = self.split.main;
        let n = s.pos_m.len();
        let st = Engine::stride_of(n);
        let per_channel = n.div_ceil(st);
        let channels = if main.force_n.is_some() { 2 } else { 1 };
        let root = ((channels * per_channel) as f64).sqrt();
        let mut v = Vec::with_capacity(channels * per_channel);
        // Unshifted (every iteration of every fit), a sample is read as it is: `at` at a
        // whole index returns it, and skipping its interpolation is a tenth of a diagnosis.
        let push = |v: &mut Vec<f64>, rec: &[f64], sim: &[f64], shift: f64, sig: f64| {
            let rows = (0..sim.len()).step_by(st);
            if shift == 0.0 && st == 1 {
                // Unstrided, as a plain zip (which vectorises; the same divisions).
                v.extend(rec.iter().zip(sim).map(|(r, s)| (r - s) / sig / root));
            } else if shift == 0.0 {
                v.extend(rows.map(|k| (rec[k] - sim[k]) / sig / root));
            } else {
                v.extend(rows.map(|k| (rec[k] - at(sim, k as f64 + shift)) / sig / root));
            }
        };
        push(&mut v, &main.pos_m, &s.pos_m, pos_shift, self.sig_pos);
        if let Some(f) = &main.force_n {
            push(&mut v, f, &s.force_n, force_shift, self.sig_force);
        }
        DVector::from_vec(v)
    }

    /// How candidate `after` changes the held-out residual of `base`. `mask` leaves out the
    /// anomalous held-out blocks (for effects that depend on the axis's state).
    pub fn scores(
        &self,
        base: &Eval,
        after: &Eval,
        n_params: usize,
        mask: bool,
        smooth: bool,
    ) -> Scores {
        if smooth && self.smooth_n > 1 {
            let n = self.smooth_n;
            let sm = |e: &Eval| Eval {
                hold_pos: moving_average(&e.hold_pos, n),
                hold_force: e.hold_force.as_deref().map(|f| moving_average(f, n)),
                ..e.clone()
            };
            return self.scores_of(&sm(base), &sm(after), n_params, mask, 0.0);
        }
        self.scores_of(base, after, n_params, mask, self.pos_floor_ms)
    }

    fn scores_of(
        &self,
        base: &Eval,
        after: &Eval,
        n_params: usize,
        mask: bool,
        floor_ms: f64,
    ) -> Scores {
        // What lies above the floor is weighed against what lay above it in the base's
        // fitting part, not against the whole residual with the grid's rounding in it.
        let sig_pos = above_norm(self.sig_pos, floor_ms);
        let hj = |e: &Eval| {
            use std::borrow::Cow;
            let (pos, force): (Cow<[f64]>, Option<Cow<[f64]>>) = if mask {
                (
                    Cow::Owned(self.masked(&e.hold_pos)),
                    e.hold_force.as_deref().map(|f| Cow::Owned(self.masked(f))),
                )
            } else {
                (
                    Cow::Borrowed(&e.hold_pos),
                    e.hold_force.as_deref().map(Cow::Borrowed),
                )
            };
            let p = above(&pos, floor_ms) / sig_pos;
            match force.as_deref() {
                Some(f) if self.has_force => {
                    let q = rms(f) / self.sig_force;
                    (0.5 * (p * p + q * q)).sqrt()
                }
                _ => p,
            }
        };
        let jb = hj(base);
        let ja = hj(after);
        let shrink = if jb > 0.0 { 1.0 - ja / jb } else { 0.0 };
        let (hb, ha) = (
            above(&base.hold_pos, floor_ms),
            above(&after.hold_pos, floor_ms),
        );
        let shrink_force = match (&base.hold_force, &after.hold_force) {
            (Some(b), Some(a)) if rms(b) > 0.0 => Some(1.0 - rms(a) / rms(b)),
            _ => None,
        };
        Scores {
            fit_pos_before: rms(&base.fit_pos),
            fit_pos_after: rms(&after.fit_pos),
            hold_pos_before: hb,
            hold_pos_after: ha,
            shrink,
            shrink_pos: if hb > 0.0 { 1.0 - ha / hb } else { 0.0 },
            shrink_force,
            fit_shrink: 0.0,
            score: shrink - PENALTY_PER_PARAM * n_params as f64,
            significant: false,
        }
    }
}

/// The position's normalisation `sig_pos` (the rms of a round base's fitting residual) with
/// a floor `floor_ms` taken out, as [`above`] takes it out of the residuals it scores: the
/// grid's rounding is in both, and scored against the whole residual a spring that takes
/// half of what lies above the grid counted as a few per cent of the combined residual
/// (5454 case_074: 46 % of the held-out position, 2.7 % in all, the force weighed ~18×).
/// At least [`GRID_NORM_MIN`] of `sig_pos`: a base that leaves hardly more than the grid's
/// spread would make any sample's noise a large share.
fn above_norm(sig_pos: f64, floor_ms: f64) -> f64 {
    if floor_ms > 0.0 {
        (sig_pos * sig_pos - floor_ms)
            .max((GRID_NORM_MIN * sig_pos).powi(2))
            .sqrt()
    } else {
        sig_pos
    }
}

/// Least share of the whole position normalisation [`above_norm`] keeps.
const GRID_NORM_MIN: f64 = 0.1;

/// Root mean square of `v` above a mean square `floor_ms` that is no one's to explain
/// (0 when `v` lies within it).
fn above(v: &[f64], floor_ms: f64) -> f64 {
    let r = rms(v);
    if floor_ms > 0.0 {
        (r * r - floor_ms).max(0.0).sqrt()
    } else {
        r
    }
}

/// Centred moving average of `v` over `n` samples (shorter at the ends).
pub fn moving_average(v: &[f64], n: usize) -> Vec<f64> {
    let len = v.len();
    let h = n / 2;
    let mut pre = Vec::with_capacity(len + 1);
    pre.push(0.0);
    for x in v {
        pre.push(pre[pre.len() - 1] + x);
    }
    (0..len)
        .map(|i| {
            let (a, b) = (i.saturating_sub(h), (i + h + 1).min(len));
            (pre[b] - pre[a]) / (b - a) as f64
        })
        .collect()
}

/// `v` at fractional index `x` (linear interpolation, ends held).
pub fn at(v: &[f64], x: f64) -> f64 {
    let last = v.len().saturating_sub(1);
    if v.is_empty() {
        return 0.0;
    }
    if x <= 0.0 {
        return v[0];
    }
    if x >= last as f64 {
        return v[last];
    }
    let i = x.floor() as usize;
    let f = x - i as f64;
    v[i] + (v[i + 1] - v[i]) * f
}

/// Samples over which the residual stays correlated (first lag where the autocorrelation
/// falls below 1/e), at most 10,000.
pub fn corr_length(r: &[f64]) -> f64 {
    let n = r.len();
    if n < 4 {
        return 1.0;
    }
    let mean = r.iter().sum::<f64>() / n as f64;
    let var: f64 = r.iter().map(|x| (x - mean).powi(2)).sum();
    if var <= 0.0 {
        return 1.0;
    }
    let mut lag = 1;
    while lag < n / 2 && lag < 10_000 {
        let step = ((n - lag) / 20_000).max(1);
        let c: f64 = (0..n - lag)
            .step_by(step)
            .map(|i| (r[i] - mean) * (r[i + lag] - mean))
            .sum::<f64>()
            * step as f64;
        if c / var < (-1.0f64).exp() {
            break;
        }
        lag = (lag as f64 * 1.5).ceil() as usize;
    }
    lag as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 5454 case_074's figures: a base that leaves 0.643 µm rms of the fitting part's
    /// position beside a 2.149 µm grid, and a spring that halves what lies above the grid
    /// held out (0.168 → 0.090 µm) while the force stays. Weighed against what lies above the
    /// grid, the position counts as much as the force and the spring takes ~20 % of the
    /// combined residual; against the whole residual it took 2.7 %.
    #[test]
    fn the_grid_floor_is_taken_out_of_the_normalisation_as_out_of_the_residual() {
        let sig_pos = 0.643e-6;
        let q: f64 = 2.149e-6;
        let floor_ms = q * q / 12.0;
        let norm = above_norm(sig_pos, floor_ms);
        assert!((norm - (sig_pos * sig_pos - floor_ms).sqrt()).abs() < 1e-15);
        assert!((norm - 0.169e-6).abs() < 0.001e-6, "{norm}");
        let combined = |pos_m: f64, sig: f64| (0.5 * ((pos_m / sig).powi(2) + 1.0)).sqrt();
        let shrink = |sig: f64| 1.0 - combined(0.090e-6, sig) / combined(0.168e-6, sig);
        assert!(shrink(norm) > 0.19, "{}", shrink(norm));
        assert!(shrink(sig_pos) < 0.03, "{}", shrink(sig_pos));
        // No floor: the normalisation as it was; a floor at or above the whole residual:
        // a tenth of it, never zero.
        assert_eq!(above_norm(sig_pos, 0.0), sig_pos);
        assert!((above_norm(sig_pos, 2.0 * sig_pos * sig_pos) - 0.1 * sig_pos).abs() < 1e-18);
    }
}
