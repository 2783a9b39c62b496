//! The common ground of the diagnosis: which part of the record fits and which is held out,
//! a candidate model and its residuals on both parts, and the normalised residual the
//! solver sees.

use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::DVector;

use super::replay::{Disturbance, Model, Record, SimOut, simulate};
use super::{DiagnoseError, Progress};

/// Samples of each channel whose residuals go to the least-squares solver at most; a longer
/// fitting part is strided. The solver's work per iteration (its QR and the rows
/// themselves) grows with its rows.
const MAX_LM_ROWS: usize = 17_400;
/// The solver's iterations replay at most this many samples of the fitting part (its
/// beginning); a fitted candidate is then scored on all of it. The iterations are most of
/// a diagnosis's work and each replays its samples one after the other, so this bounds the
/// cost of a long record. 17 400 samples at 1 kHz are hundreds of correlation lengths of
/// every effect but a screw's growth (see [`MAX_LM_SAMPLES_SLOW`]).
pub const MAX_LM_SAMPLES: usize = 17_400;

/// … and this many when a screw's growth is fitted (as the candidate or beside it): its
/// time constant is minutes, and a growth fitted on a third of the record cannot tell its
/// time constant from a slope along the travel.
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
/// disturbances on a separate validation record.
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

pub(crate) fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

pub(crate) fn peak(x: &[f64]) -> f64 {
    x.iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

/// Measured − simulated, less `interval_m` of it either way (see [`Model::pos_interval_m`]).
fn resid(meas: &[f64], sim: &[f64], interval_m: f64) -> Vec<f64> {
    meas.iter()
        .zip(sim)
        .map(|(m, s)| {
            let r = m - s;
            if interval_m > 0.0 {
                r.signum() * (r.abs() - interval_m).max(0.0)
            } else {
                r
            }
        })
        .collect()
}

/// The residuals of candidates on one split, and the solver's rows.
pub struct Engine<'a> {
    /// The records.
    pub split: Split<'a>,
    progress: &'a Progress<'a>,
    /// Whether the records have force.
    pub has_force: bool,
    /// Normalisation of the solver's position rows, m.
    pub sig_pos: f64,
    /// Normalisation of the solver's force rows, N.
    pub sig_force: f64,
    /// Stride of the solver's rows for a replay of [`Engine::n_lm`]`(false)` samples.
    pub stride: usize,
    /// Samples over which the calibrated residual stays correlated.
    pub corr_len: f64,
    sims: AtomicUsize,
    /// Replays expected in all (for the progress bar).
    pub sims_expected: AtomicUsize,
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
            sims: AtomicUsize::new(0),
            sims_expected: AtomicUsize::new(400),
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

    /// Takes the solver's normalisation and the correlation length from the residual `ev`.
    pub fn set_scale(&mut self, ev: &Eval) {
        self.sig_pos = rms(&ev.fit_pos).max(1e-12);
        self.sig_force = ev.fit_force.as_deref().map_or(1.0, rms).max(1e-9);
        self.corr_len = corr_length(&ev.fit_pos);
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

    /// Simulates the part of the fitting data the solver uses (`slow`: see
    /// [`Engine::n_lm`]).
    pub fn sim_fit(&self, c: &Cand, slow: bool) -> Result<SimOut, DiagnoseError> {
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
        let pos = resid(&main.pos_m[..n_main], &s.pos_m, c.model.pos_interval_m);
        let force = main
            .force_n
            .as_ref()
            .map(|f| resid(&f[..n_main], &s.force_n, 0.0));
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
                    hold_pos: resid(&v.pos_m, &sv.pos_m, c.model.pos_interval_m),
                    hold_force: v.force_n.as_ref().map(|f| resid(f, &sv.force_n, 0.0)),
                })
            }
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
        let push = |v: &mut Vec<f64>, rec: &[f64], sim: &[f64], shift: f64, sig: f64| {
            if shift == 0.0 && st == 1 {
                v.extend(rec.iter().zip(sim).map(|(r, s)| (r - s) / sig / root));
            } else if shift == 0.0 {
                v.extend(
                    (0..sim.len())
                        .step_by(st)
                        .map(|k| (rec[k] - sim[k]) / sig / root),
                );
            } else {
                v.extend(
                    (0..sim.len())
                        .step_by(st)
                        .map(|k| (rec[k] - at(sim, k as f64 + shift)) / sig / root),
                );
            }
        };
        push(&mut v, &main.pos_m, &s.pos_m, pos_shift, self.sig_pos);
        if let Some(f) = &main.force_n {
            push(&mut v, f, &s.force_n, force_shift, self.sig_force);
        }
        DVector::from_vec(v)
    }

    /// Combined normalised RMS of position and force residuals (the solver's weights).
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
