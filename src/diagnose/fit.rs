//! "Which" and "how far": fitting each candidate effect on the fitting part, scoring it on
//! the held-out part, ranking, and the greedy selection of a second and third effect.

use super::effects::{Effect, ParamDef};
use super::regimes::{self, Regime};
use super::replay::{ForceEvent, Model, Record, SimOut, simulate};
use super::{DiagnoseError, Figures, Progress, RankEntry, RegimeChange, Report, Series};
use crate::preset::Preset;
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};
use std::cell::RefCell;
use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Complexity penalty per fitted parameter, in units of held-out shrink.
pub const PENALTY_PER_PARAM: f64 = 0.02;
/// Smallest held-out shrink (after the penalty) that counts as an unmodelled effect.
pub const MIN_SHRINK: f64 = 0.12;
/// Smallest further shrink of the remaining residual for a second or third effect.
pub const MIN_GREEDY_SHRINK: f64 = 0.15;
/// Candidates tried in the greedy rounds (the best of the first round's ranking).
const GREEDY_TRY: usize = 5;
/// Residual rows handed to the least-squares solver at most (the record is strided).
const MAX_LM_ROWS: usize = 60_000;
/// The solver's iterations replay at most this many samples of the fitting part (its
/// beginning); the fitted candidate is then scored on all of it. This bounds the cost of a
/// long record: the iterations are most of the work.
pub const MAX_LM_SAMPLES: usize = 200_000;

/// Where the fitting part ends and where the held-out part comes from.
pub struct Split<'a> {
    pub main: &'a Record,
    pub n_fit: usize,
    pub validate: Option<&'a Record>,
}

impl<'a> Split<'a> {
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
                if (v.force_n.is_some()) != (main.force_n.is_some()) {
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
}

/// A model plus its external force events on each record.
#[derive(Debug, Clone)]
pub struct Cand {
    pub model: Model,
    pub ev_main: Vec<ForceEvent>,
    pub ev_val: Vec<ForceEvent>,
}

/// Residuals (measured − simulated) of one candidate, in m and N.
#[derive(Debug, Clone, Default)]
pub struct Eval {
    pub fit_pos: Vec<f64>,
    pub fit_force: Option<Vec<f64>>,
    pub hold_pos: Vec<f64>,
    pub hold_force: Option<Vec<f64>>,
}

fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

fn peak(x: &[f64]) -> f64 {
    x.iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

fn resid(meas: &[f64], sim: &[f64]) -> Vec<f64> {
    meas.iter().zip(sim).map(|(m, s)| m - s).collect()
}

#[derive(Debug, Clone)]
pub struct Fitted {
    pub effect: Effect,
    pub theta: Vec<f64>,
    pub std: Vec<f64>,
    pub cand: Cand,
    pub eval: Eval,
    pub n_params: usize,
    pub extra: BTreeMap<String, f64>,
    pub note: String,
}

pub struct Engine<'a> {
    pub nominal: Cand,
    pub split: Split<'a>,
    progress: &'a Progress<'a>,
    pub has_force: bool,
    sig_pos: f64,
    sig_force: f64,
    stride: usize,
    pub nom: Eval,
    /// Correlation length of the nominal fit residual in samples (for parameter
    /// uncertainties).
    corr_len: f64,
    pub time_offset_ms: f64,
    /// Held-out samples the state-dependent candidates are scored on: blocks whose nominal
    /// residual is far beyond anything in the fitting data (an unmodelled disturbance the
    /// fitting data never showed) are left out, so that they do not drown the score of an
    /// effect that is present in both. The overall before/after figures keep them.
    pub hold_mask: Vec<bool>,
    sims: AtomicUsize,
    sims_expected: AtomicUsize,
}

pub struct Outcome {
    pub ranking: Vec<(Fitted, Scores)>,
    pub selected: Vec<(Fitted, Scores)>,
    pub final_eval: Eval,
    pub final_cand: Cand,
}

#[derive(Debug, Clone, Copy)]
pub struct Scores {
    pub fit_pos_before: f64,
    pub fit_pos_after: f64,
    pub hold_pos_before: f64,
    pub hold_pos_after: f64,
    pub shrink: f64,
    pub shrink_pos: f64,
    pub shrink_force: Option<f64>,
    pub score: f64,
    pub significant: bool,
}

impl<'a> Engine<'a> {
    pub fn new(
        nominal: &Model,
        split: Split<'a>,
        progress: &'a Progress<'a>,
    ) -> Result<Engine<'a>, DiagnoseError> {
        let has_force = split.main.force_n.is_some();
        let cand = Cand {
            model: nominal.clone(),
            ev_main: vec![],
            ev_val: vec![],
        };
        let mut e = Engine {
            nominal: cand.clone(),
            split,
            progress,
            has_force,
            sig_pos: 1.0,
            sig_force: 1.0,
            stride: 1,
            nom: Eval::default(),
            corr_len: 1.0,
            time_offset_ms: 0.0,
            hold_mask: vec![],
            sims: AtomicUsize::new(0),
            sims_expected: AtomicUsize::new(200),
        };
        e.stride = e.n_lm().div_ceil(MAX_LM_ROWS).max(1);
        (e.progress.report)(0.0, "replaying the nominal model");
        let nom = e.evaluate(&cand)?;
        let floor = 1e-12;
        e.sig_pos = rms(&nom.fit_pos).max(floor);
        e.sig_force = nom.fit_force.as_deref().map_or(1.0, rms).max(1e-9);
        e.corr_len = corr_length(&nom.fit_pos);
        e.time_offset_ms = time_offset_ms(e.split.main, &nom.fit_pos);
        for (name, v) in [("position", &nom.fit_pos), ("position", &nom.hold_pos)] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(DiagnoseError::Input(format!(
                    "the nominal model's {name} diverged during the replay; check the preset's servo gains against the record"
                )));
            }
        }
        e.hold_mask = e.anomaly_mask(&nom);
        e.nom = nom;
        Ok(e)
    }

    fn tick(&self, what: &str) -> Result<(), DiagnoseError> {
        self.progress.check()?;
        let d = self.sims.fetch_add(1, Ordering::Relaxed) + 1;
        let exp = self.sims_expected.load(Ordering::Relaxed).max(d + 1);
        (self.progress.report)((d as f64 / exp as f64).min(0.99), what);
        Ok(())
    }

    /// Simulates the fitting part only.
    fn sim_fit(&self, c: &Cand) -> Result<SimOut, DiagnoseError> {
        self.tick("fitting")?;
        let mut m = c.model.clone();
        m.events.clone_from(&c.ev_main);
        Ok(simulate(&m, self.split.main, self.n_lm()))
    }

    /// Simulates both parts and returns the residuals.
    pub fn evaluate(&self, c: &Cand) -> Result<Eval, DiagnoseError> {
        self.tick("scoring")?;
        let main = self.split.main;
        let nf = self.split.n_fit;
        let mut m = c.model.clone();
        m.events.clone_from(&c.ev_main);
        let n_main = if self.split.validate.is_some() {
            nf
        } else {
            main.len()
        };
        let s = simulate(&m, main, n_main);
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
                mv.events.clone_from(&c.ev_val);
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

    /// Samples the solver's iterations replay.
    fn n_lm(&self) -> usize {
        self.split.n_fit.min(MAX_LM_SAMPLES)
    }

    fn anomaly_mask(&self, nom: &Eval) -> Vec<bool> {
        let t3 = self.split.main.t3_s;
        let w = ((0.1 / t3).round() as usize).max(1);
        let cf = self.combined(&nom.fit_pos, nom.fit_force.as_deref());
        let ch = self.combined(&nom.hold_pos, nom.hold_force.as_deref());
        let mut fb: Vec<f64> = cf.chunks(w).map(rms).collect();
        fb.sort_by(f64::total_cmp);
        let p95 = fb
            .get(fb.len() * 95 / 100)
            .copied()
            .unwrap_or(f64::INFINITY);
        let thr = 3.0 * p95;
        let mut mask = Vec::with_capacity(ch.len());
        for c in ch.chunks(w) {
            let keep = rms(c) <= thr;
            mask.extend(std::iter::repeat_n(keep, c.len()));
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

    /// Combined normalized RMS of position and force residuals.
    fn j(&self, pos: &[f64], force: Option<&[f64]>) -> f64 {
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
    fn combined(&self, pos: &[f64], force: Option<&[f64]>) -> Vec<f64> {
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

    /// Stacked, strided, normalized fit residual of a simulation (the solver's vector).
    fn lm_rows(&self, s: &SimOut) -> DVector<f64> {
        let main = self.split.main;
        let st = self.stride;
        let mut v = Vec::with_capacity(2 * self.n_lm() / st + 2);
        for k in (0..s.pos_m.len()).step_by(st) {
            v.push((main.pos_m[k] - s.pos_m[k]) / self.sig_pos);
        }
        if let Some(f) = &main.force_n {
            for k in (0..s.force_n.len()).step_by(st) {
                v.push((f[k] - s.force_n[k]) / self.sig_force);
            }
        }
        let n = v.len() as f64;
        DVector::from_vec(v) / n.sqrt()
    }

    pub fn scores(&self, base: &Eval, after: &Eval, n_params: usize, mask: bool) -> Scores {
        let hj = |e: &Eval| {
            if mask {
                let f = e.hold_force.as_deref().map(|f| self.masked(f));
                self.j(&self.masked(&e.hold_pos), f.as_deref())
            } else {
                self.j(&e.hold_pos, e.hold_force.as_deref())
            }
        };
        let jb = hj(base);
        let ja = hj(after);
        let shrink = if jb > 0.0 { 1.0 - ja / jb } else { 0.0 };
        let (hb, ha) = (rms(&base.hold_pos), rms(&after.hold_pos));
        let shrink_force = match (&base.hold_force, &after.hold_force) {
            (Some(b), Some(a)) if rms(b) > 0.0 => Some(1.0 - rms(a) / rms(b)),
            _ => None,
        };
        let fit_b = self.j(&base.fit_pos, base.fit_force.as_deref());
        let fit_a = self.j(&after.fit_pos, after.fit_force.as_deref());
        let score = shrink - PENALTY_PER_PARAM * n_params as f64;
        Scores {
            fit_pos_before: rms(&base.fit_pos),
            fit_pos_after: rms(&after.fit_pos),
            hold_pos_before: hb,
            hold_pos_after: ha,
            shrink,
            shrink_pos: if hb > 0.0 { 1.0 - ha / hb } else { 0.0 },
            shrink_force,
            score,
            significant: score >= MIN_SHRINK && fit_a < fit_b,
        }
    }

    /// True when a fitted correction of a parameter the nominal already has stays within
    /// the tolerance any nominal has (10 %): that is a mis-set value, not a missing effect.
    fn within_tolerance(&self, f: &Fitted) -> bool {
        let fr = &self.nominal.model.axis.friction;
        match f.effect {
            Effect::CoulombFriction if fr.enabled && fr.coulomb_n > 0.0 => {
                f.theta[0].abs() < 0.1 * fr.coulomb_n
            }
            Effect::ViscousFriction if fr.enabled && fr.viscous_n_s_per_m > 0.0 => {
                f.theta[0].abs() < 0.1 * fr.viscous_n_s_per_m
            }
            _ => false,
        }
    }

    /// Fits `effect` on top of `base`.
    pub fn fit_effect(
        &self,
        base: &Cand,
        base_eval: &Eval,
        effect: Effect,
    ) -> Result<Option<Fitted>, DiagnoseError> {
        match effect {
            Effect::ExternalDisturbance => return self.fit_external(base, base_eval),
            Effect::Quantization => return self.fit_quantization(base),
            Effect::BeamSag => return Ok(None),
            Effect::Compliance if base.model.axis.lost_motion.enabled => {}
            _ => {}
        }
        let defs = effect.params();
        let starts = self.starts(effect, defs);
        let mut best: Option<(f64, Vec<f64>)> = None;
        for s in starts {
            let c = with_effect(base, effect, &s);
            let r = self.lm_rows(&self.sim_fit(&c)?);
            let cost = r.norm_squared();
            if best.as_ref().is_none_or(|b| cost < b.0) {
                best = Some((cost, s));
            }
        }
        let Some((_, start)) = best else {
            return Ok(None);
        };
        let scale: Vec<f64> = defs
            .iter()
            .zip(&start)
            .map(|(d, s)| s.abs().max(0.2 * d.init.abs()).max(1e-12))
            .collect();
        let problem = Problem {
            eng: self,
            base,
            effect,
            defs,
            scale: scale.clone(),
            x: DVector::from_iterator(start.len(), start.iter().zip(&scale).map(|(s, k)| s / k)),
            last_j: RefCell::new(None),
            err: RefCell::new(None),
        };
        let (problem, _report) = LevenbergMarquardt::new()
            .with_patience(6)
            .with_tol(1e-4)
            .minimize(problem);
        if let Some(e) = problem.err.borrow_mut().take() {
            return Err(e);
        }
        let theta = problem.theta();
        let cand = with_effect(base, effect, &theta);
        let eval = self.evaluate(&cand)?;
        let std = problem.std(&theta, self.corr_len);
        let mut extra = BTreeMap::new();
        if effect == Effect::ConstantForce {
            // The same force as the motor-force offset of the identification literature
            // (M·a + Fv·v + Fc·sign(v) + offset = F): offset = −(force on the table).
            extra.insert("offset_n".to_owned(), -theta[0]);
        }
        Ok(Some(Fitted {
            effect,
            theta,
            std,
            cand,
            eval,
            n_params: defs.len(),
            extra,
            note: String::new(),
        }))
    }

    /// Starting points: a small grid over the parameters the residual depends on
    /// nonlinearly, the typical magnitude for the rest.
    fn starts(&self, effect: Effect, defs: &[ParamDef]) -> Vec<Vec<f64>> {
        let init: Vec<f64> = defs.iter().map(|d| d.init).collect();
        let vary = |i: usize, vals: &[f64]| -> Vec<Vec<f64>> {
            vals.iter()
                .map(|&v| {
                    let mut s = init.clone();
                    s[i] = v;
                    s
                })
                .collect()
        };
        match effect {
            Effect::StribeckFriction => vary(1, &[0.5, 2.0, 8.0]),
            Effect::StrokeFriction => vary(1, &[5.0, 20.0, 60.0]),
            Effect::Compliance => vary(0, &[10.0, 50.0, 250.0]),
            Effect::ThermalGrowth => vary(1, &[10.0, 60.0, 600.0, 3600.0]),
            Effect::Backlash => vary(0, &[3.0, 10.0, 30.0]),
            Effect::BacklashAsymmetry => {
                let mut v = Vec::new();
                for w in [3.0, 10.0, 30.0] {
                    for f in [-150.0, 150.0] {
                        v.push(vec![w, f]);
                    }
                }
                v
            }
            Effect::CommandDelay => {
                let d = self.time_offset_ms.clamp(-40.0, 40.0);
                vary(0, &[d, if d.abs() > 0.1 { d * 0.5 } else { 1.0 }])
            }
            _ => vec![init],
        }
    }

    /// Quantization: find the grid the measured positions lie on, then simulate with it.
    fn fit_quantization(&self, base: &Cand) -> Result<Option<Fitted>, DiagnoseError> {
        let pos = &self.split.main.pos_m[..self.split.n_fit];
        let Some(q_m) = detect_grid(pos) else {
            return Ok(None);
        };
        let theta = vec![q_m * 1e6];
        let cand = with_effect(base, Effect::Quantization, &theta);
        let eval = self.evaluate(&cand)?;
        Ok(Some(Fitted {
            effect: Effect::Quantization,
            std: vec![0.0],
            theta,
            cand,
            eval,
            n_params: 1,
            extra: BTreeMap::new(),
            note: "resolution read from the grid the measured positions lie on".into(),
        }))
    }

    /// External disturbance: localized bursts of residual the state does not explain,
    /// modelled as windows of constant force on the table. It is a detector: on held-out
    /// data the windows are detected again and their forces fitted there, and every window
    /// counts as two parameters in the penalty.
    fn fit_external(&self, base: &Cand, base_eval: &Eval) -> Result<Option<Fitted>, DiagnoseError> {
        let main = self.split.main;
        let t3 = main.t3_s;
        let labels_main = regimes::classify(&main.cmd_m, t3);
        let cm = self.combined(&base_eval.fit_pos, base_eval.fit_force.as_deref());
        let mut ev_main = detect_events(&cm, 0, t3, &labels_main);
        let mut ev_val = Vec::new();
        match self.split.validate {
            None => {
                let ch = self.combined(&base_eval.hold_pos, base_eval.hold_force.as_deref());
                ev_main.extend(detect_events(&ch, self.split.n_fit, t3, &labels_main));
            }
            Some(v) => {
                let labels_v = regimes::classify(&v.cmd_m, t3);
                let ch = self.combined(&base_eval.hold_pos, base_eval.hold_force.as_deref());
                ev_val = detect_events(&ch, 0, t3, &labels_v);
            }
        }
        let n_events = ev_main.len() + ev_val.len();
        if std::env::var_os("AXB_DEBUG").is_some() {
            eprintln!("ext: events main {:?} val {:?}", ev_main, ev_val);
        }
        let in_fit = ev_main.iter().filter(|e| e.0 < self.split.n_fit).count();
        // A disturbance the fitting data never showed is reported as a remaining gap, not
        // diagnosed: there is nothing to learn its signature from.
        if in_fit < 1 || n_events > 400 {
            return Ok(None);
        }
        // One simulation with a unit force in every window gives each window's response
        // (the windows are apart, so the responses hardly overlap); the forces then follow
        // by linear least squares, window by window.
        const UNIT_N: f64 = 10.0;
        let mut unit = base.clone();
        let unit_ev = |e: &[(usize, usize)], have: &[ForceEvent]| -> Vec<ForceEvent> {
            let mut v: Vec<ForceEvent> = have.to_vec();
            v.extend(e.iter().map(|&(i0, i1)| ForceEvent {
                i0,
                i1,
                force_n: UNIT_N,
            }));
            v.sort_by_key(|e| e.i0);
            v
        };
        unit.ev_main = unit_ev(&ev_main, &base.ev_main);
        unit.ev_val = unit_ev(&ev_val, &base.ev_val);
        let ue = self.evaluate(&unit)?;
        let nf = self.split.n_fit;
        let solve = |evs: &[(usize, usize)],
                     off: usize,
                     b_pos: &[f64],
                     b_force: Option<&[f64]>,
                     u_pos: &[f64],
                     u_force: Option<&[f64]>|
         -> Vec<ForceEvent> {
            let mut out = Vec::new();
            for (j, &(i0, i1)) in evs.iter().enumerate() {
                let end = evs.get(j + 1).map_or(b_pos.len() + off, |e| e.0);
                let (a, b) = (i0 - off, (end - off).min(b_pos.len()));
                let (mut num, mut den) = (0.0, 0.0);
                for k in a..b {
                    // Residual of base = meas − base; the unit run moved the model by
                    // (base − unit)·…: column = (unit − base) per newton.
                    let col = (b_pos[k] - u_pos[k]) / UNIT_N / self.sig_pos;
                    num += col * b_pos[k] / self.sig_pos;
                    den += col * col;
                    if let (Some(bf), Some(uf)) = (b_force, u_force) {
                        let col = (bf[k] - uf[k]) / UNIT_N / self.sig_force;
                        num += col * bf[k] / self.sig_force;
                        den += col * col;
                    }
                }
                if den > 0.0 {
                    out.push(ForceEvent {
                        i0,
                        i1,
                        force_n: num / den,
                    });
                }
            }
            out
        };
        let (em_fit, em_hold): (Vec<_>, Vec<_>) = ev_main.iter().partition(|e| e.0 < nf);
        let mut fitted_main = solve(
            &em_fit,
            0,
            &base_eval.fit_pos,
            base_eval.fit_force.as_deref(),
            &ue.fit_pos,
            ue.fit_force.as_deref(),
        );
        let hold_evs: Vec<(usize, usize)> = if self.split.validate.is_some() {
            ev_val.clone()
        } else {
            em_hold.clone()
        };
        let off = if self.split.validate.is_some() { 0 } else { nf };
        let fitted_hold = solve(
            &hold_evs,
            off,
            &base_eval.hold_pos,
            base_eval.hold_force.as_deref(),
            &ue.hold_pos,
            ue.hold_force.as_deref(),
        );
        let mut cand = base.clone();
        if self.split.validate.is_some() {
            cand.ev_main.extend(fitted_main);
            cand.ev_val.extend(fitted_hold);
        } else {
            fitted_main.extend(fitted_hold);
            cand.ev_main.extend(fitted_main);
        }
        cand.ev_main.sort_by_key(|e| e.i0);
        cand.ev_val.sort_by_key(|e| e.i0);
        let eval = self.evaluate(&cand)?;
        let forces: Vec<f64> = cand
            .ev_main
            .iter()
            .chain(&cand.ev_val)
            .map(|e| e.force_n)
            .collect();
        let mut extra = BTreeMap::new();
        extra.insert("events".to_owned(), n_events as f64);
        extra.insert("force_rms_n".to_owned(), rms(&forces));
        extra.insert(
            "duration_mean_s".to_owned(),
            cand.ev_main
                .iter()
                .chain(&cand.ev_val)
                .map(|e| (e.i1 - e.i0) as f64 * t3)
                .sum::<f64>()
                / n_events as f64,
        );
        Ok(Some(Fitted {
            effect: Effect::ExternalDisturbance,
            theta: vec![],
            std: vec![],
            cand,
            eval,
            // Window finding (threshold, widening) and a force per window: counted as four
            // parameters, whatever the number of windows.
            n_params: 4,
            extra,
            note: format!(
                "{n_events} windows of unexplained force, detected and fitted on each part separately"
            ),
        }))
    }

    /// Fits every effect in `effects` on top of `base`, two at a time in parallel.
    fn fit_all(
        &self,
        base: &Cand,
        base_eval: &Eval,
        effects: &[Effect],
    ) -> Result<Vec<(Fitted, Scores)>, DiagnoseError> {
        let next = AtomicUsize::new(0);
        let results: Mutex<Vec<(usize, Fitted)>> = Mutex::new(Vec::new());
        let first_err: Mutex<Option<DiagnoseError>> = Mutex::new(None);
        let workers = std::thread::available_parallelism()
            .map_or(2, |n| n.get())
            .clamp(1, 4);
        std::thread::scope(|s| {
            for _ in 0..workers {
                s.spawn(|| {
                    loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        let Some(&e) = effects.get(i) else { break };
                        match self.fit_effect(base, base_eval, e) {
                            Ok(Some(f)) => {
                                if let Ok(mut r) = results.lock() {
                                    r.push((i, f));
                                }
                            }
                            Ok(None) => {}
                            Err(err) => {
                                if let Ok(mut fe) = first_err.lock() {
                                    fe.get_or_insert(err);
                                }
                                next.store(usize::MAX / 2, Ordering::Relaxed);
                                break;
                            }
                        }
                    }
                });
            }
        });
        if let Some(e) = first_err.into_inner().ok().flatten() {
            return Err(e);
        }
        let mut r = results.into_inner().unwrap_or_default();
        r.sort_by_key(|x| x.0);
        let mut out: Vec<(Fitted, Scores)> = r
            .into_iter()
            .map(|(_, f)| {
                let mut s = self.scores(
                    base_eval,
                    &f.eval,
                    f.n_params,
                    f.effect != Effect::ExternalDisturbance,
                );
                let mut f = f;
                if self.within_tolerance(&f) {
                    s.significant = false;
                    f.note = "a correction within the nominal's 10 % tolerance".into();
                }
                (f, s)
            })
            .collect();
        // An effect must clearly beat what a within-tolerance correction of the nominal
        // already explains; otherwise it is only absorbing the same mismatch.
        let tol_best = out
            .iter()
            .filter(|(f, _)| self.within_tolerance(f))
            .map(|(_, s)| s.shrink)
            .fold(f64::NEG_INFINITY, f64::max);
        for (f, s) in &mut out {
            if s.significant && s.shrink < tol_best + 0.5 * MIN_SHRINK {
                s.significant = false;
                f.note =
                    "explains no more than a within-tolerance correction of the nominal".into();
            }
        }
        out.sort_by(|a, b| b.1.score.total_cmp(&a.1.score));
        Ok(out)
    }

    pub fn run(&self, effects: &[Effect], max_effects: usize) -> Result<Outcome, DiagnoseError> {
        self.sims_expected.store(
            8 * effects.len() * (1 + 2 * max_effects.saturating_sub(1).min(1)),
            Ordering::Relaxed,
        );
        let ranking = self.fit_all(&self.nominal, &self.nom, effects)?;
        let mut selected: Vec<(Fitted, Scores)> = Vec::new();
        let mut base = self.nominal.clone();
        let mut base_eval = self.nom.clone();
        if let Some((f, s)) = ranking.iter().find(|(_, s)| s.significant) {
            base = f.cand.clone();
            base_eval = f.eval.clone();
            selected.push((f.clone(), *s));
        }
        while !selected.is_empty() && selected.len() < max_effects {
            let tried: Vec<Effect> = ranking
                .iter()
                .map(|(f, _)| f.effect)
                .filter(|e| !selected.iter().any(|(s, _)| s.effect == *e))
                .take(GREEDY_TRY)
                .collect();
            let round = self.fit_all(&base, &base_eval, &tried)?;
            let Some((f, s)) = round.into_iter().find(|(_, s)| s.significant) else {
                break;
            };
            if s.score < MIN_GREEDY_SHRINK || !s.significant {
                break;
            }
            base = f.cand.clone();
            base_eval = f.eval.clone();
            selected.push((f, s));
        }
        (self.progress.report)(1.0, "done");
        Ok(Outcome {
            ranking,
            selected,
            final_eval: base_eval,
            final_cand: base,
        })
    }
}

fn with_effect(base: &Cand, e: Effect, theta: &[f64]) -> Cand {
    let mut c = base.clone();
    e.apply(theta, &mut c.model);
    c
}

/// The least-squares problem of one candidate: parameters scaled to order 1, clamped to
/// their bounds, residuals from a full replay of the fitting part.
struct Problem<'e, 'a> {
    eng: &'e Engine<'a>,
    base: &'e Cand,
    effect: Effect,
    defs: &'static [ParamDef],
    scale: Vec<f64>,
    x: DVector<f64>,
    last_j: RefCell<Option<(DVector<f64>, DMatrix<f64>)>>,
    err: RefCell<Option<DiagnoseError>>,
}

impl Problem<'_, '_> {
    fn theta_of(&self, x: &DVector<f64>) -> Vec<f64> {
        x.iter()
            .zip(&self.scale)
            .zip(self.defs)
            .map(|((x, k), d)| (x * k).clamp(d.lo, d.hi))
            .collect()
    }

    fn theta(&self) -> Vec<f64> {
        self.theta_of(&self.x)
    }

    fn rows_at(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        if self.err.borrow().is_some() {
            return None;
        }
        let c = with_effect(self.base, self.effect, &self.theta_of(x));
        match self.eng.sim_fit(&c) {
            Ok(s) => {
                let r = self.eng.lm_rows(&s);
                r.iter().all(|v| v.is_finite()).then_some(r)
            }
            Err(e) => {
                *self.err.borrow_mut() = Some(e);
                None
            }
        }
    }

    /// Forward differences with a step of 3 % of the parameter: smaller steps would see
    /// the encoder grid and the stick-slip switching instead of the trend.
    fn jac_at(&self, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        if let Some((xj, j)) = self.last_j.borrow().as_ref()
            && xj == x
        {
            return Some(j.clone());
        }
        let r0 = self.rows_at(x)?;
        let mut j = DMatrix::zeros(r0.len(), x.len());
        for i in 0..x.len() {
            let h = 0.03 * x[i].abs().max(0.3);
            let mut xp = x.clone();
            xp[i] += h;
            let r = self.rows_at(&xp)?;
            j.set_column(i, &((r - &r0) / h));
        }
        *self.last_j.borrow_mut() = Some((x.clone(), j.clone()));
        Some(j)
    }

    /// Parameter standard deviations from JᵀJ at the optimum. The residual is correlated
    /// over `corr_len` samples, so the rows are worth fewer independent samples than they
    /// number; the covariance is inflated by that factor.
    fn std(&self, theta: &[f64], corr_len: f64) -> Vec<f64> {
        let x = self.x.clone();
        let (Some(r), Some(j)) = (self.rows_at(&x), self.jac_at(&x)) else {
            return vec![f64::NAN; theta.len()];
        };
        // Rows were divided by sqrt(n) for the solver; undo it for the variance estimate.
        let n = (r.len() as f64).max(1.0);
        let jn = &j * n.sqrt();
        let ssr = r.norm_squared() * n;
        let dof = (n - theta.len() as f64).max(1.0);
        let s2 = ssr / dof * (corr_len * 1.0 / self.eng.stride as f64).max(1.0);
        let jtj = jn.transpose() * &jn;
        match jtj.try_inverse() {
            Some(inv) => (0..theta.len())
                .map(|i| (inv[(i, i)].max(0.0) * s2).sqrt() * self.scale[i])
                .collect(),
            None => vec![f64::INFINITY; theta.len()],
        }
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_, '_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        self.rows_at(&self.x)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        self.jac_at(&self.x)
    }
}

/// Samples over which the residual stays correlated (first lag where the autocorrelation
/// falls below 1/e), at most 10,000.
fn corr_length(r: &[f64]) -> f64 {
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
        let c: f64 = (0..n - lag)
            .step_by(((n - lag) / 20_000).max(1))
            .map(|i| (r[i] - mean) * (r[i + lag] - mean))
            .sum::<f64>()
            * ((n - lag) / 20_000).max(1) as f64;
        if c / var < (-1.0f64).exp() {
            break;
        }
        lag = (lag as f64 * 1.5).ceil() as usize;
    }
    lag as f64
}

/// Least-squares time offset δ in r ≈ −v·δ (v from the measured position).
fn time_offset_ms(rec: &Record, r_pos: &[f64]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    let n = r_pos.len().min(rec.len());
    for (k, r) in r_pos.iter().enumerate().take(n.saturating_sub(1)).skip(1) {
        let v = (rec.pos_m[k + 1] - rec.pos_m[k - 1]) / (2.0 * rec.t3_s);
        num += -v * r;
        den += v * v;
    }
    if den > 0.0 { num / den * 1e3 } else { 0.0 }
}

/// The quantum of a grid the positions lie on, if ≥ 98 % of them do (to 2 % of a quantum).
pub fn detect_grid(pos: &[f64]) -> Option<f64> {
    let mut steps: Vec<f64> = pos
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 1e-12)
        .collect();
    if steps.len() < 20 {
        return None;
    }
    steps.sort_by(f64::total_cmp);
    // The smallest steps cluster at one quantum; take their median as the estimate.
    let q0 = steps[steps.len() / 50];
    let small: Vec<f64> = steps.iter().copied().filter(|s| *s < 1.5 * q0).collect();
    let q = small[small.len() / 2];
    let o = pos[0];
    let on = pos
        .iter()
        .filter(|p| {
            let u = (*p - o) / q;
            (u - u.round()).abs() < 0.02
        })
        .count();
    (on as f64 >= 0.98 * pos.len() as f64).then_some(q)
}

/// Windows where the combined residual is far above its usual level, away from the
/// regime changes a state-dependent effect would explain. Indices are offset by `off`.
fn detect_events(c: &[f64], off: usize, t3_s: f64, labels: &[Regime]) -> Vec<(usize, usize)> {
    let w = ((0.02 / t3_s).round() as usize).max(4);
    let blocks: Vec<f64> = c.chunks(w).map(rms).collect();
    if blocks.len() < 10 {
        return vec![];
    }
    let mut sorted = blocks.clone();
    sorted.sort_by(f64::total_cmp);
    let base = sorted[sorted.len() / 2].max(1e-12);
    let top = sorted[sorted.len() - 1];
    // A disturbance stands out: bursts at least 20× the usual level. Model mismatch in
    // accelerations and friction stays within a few times it.
    if top < 20.0 * base {
        return vec![];
    }
    let thr = (5.0 * base).max(0.2 * top);
    if std::env::var_os("AXB_DEBUG").is_some() {
        eprintln!(
            "detect: off {off} len {} blocks {} median {base:.3} p90 {:.3} p99 {:.3} max {:.3}",
            c.len(),
            blocks.len(),
            sorted[sorted.len() * 9 / 10],
            sorted[sorted.len() * 99 / 100],
            sorted[sorted.len() - 1]
        );
    }
    let mut out: Vec<(usize, usize)> = Vec::new();
    let mut b = 0;
    while b < blocks.len() {
        if blocks[b] > thr {
            let start = b;
            let mut end = b;
            let mut gap = 0;
            let mut k = b + 1;
            while k < blocks.len() && gap <= 2 {
                if blocks[k] > thr {
                    end = k;
                    gap = 0;
                } else {
                    gap += 1;
                }
                k += 1;
            }
            let i0 = (start * w).saturating_sub(w / 2);
            let i1 = ((end + 1) * w).min(c.len());
            // A burst that sits on a command reversal is what backlash or friction does;
            // leave those to the state-dependent candidates.
            let on_reversal = labels.get(off + i0..off + i1).is_some_and(|l| {
                l.iter()
                    .filter(|r| matches!(r, Regime::ReversalNegToPos | Regime::ReversalPosToNeg))
                    .count()
                    * 2
                    > l.len()
            });
            // Only a short burst can be a reversal's doing; a long one that happens to
            // overlap reversals (short strokes) is still a disturbance.
            let short = ((i1 - i0) as f64) * t3_s <= 2.0 * regimes::REVERSAL_HALF_WINDOW_S;
            if !(on_reversal && short) {
                out.push((off + i0, off + i1));
            }
            b = end + 1;
        } else {
            b += 1;
        }
    }
    out
}

/// Turns the outcome into the report (and the fitted preset for "apply to model").
pub fn build_report(
    preset: &Preset,
    eng: &Engine,
    out: Outcome,
    base_axis: Option<String>,
) -> Report {
    let main = eng.split.main;
    let hold_rec: Record = match eng.split.validate {
        Some(v) => v.clone(),
        None => main.slice(eng.split.n_fit..main.len()),
    };
    let um = |v: &[f64]| -> Vec<f64> { v.iter().map(|x| x * 1e6).collect() };
    let before = um(&eng.nom.hold_pos);
    let after = um(&out.final_eval.hold_pos);
    let labels = regimes::classify(&hold_rec.cmd_m, hold_rec.t3_s);
    let t: Vec<f64> = (0..hold_rec.len()).map(|i| hold_rec.t_s(i)).collect();
    let pos_mm: Vec<f64> = hold_rec.pos_m.iter().map(|x| x * 1e3).collect();
    let win_len = ((0.1 / hold_rec.t3_s).round() as usize).max(1);
    let ranking: Vec<RankEntry> = out.ranking.iter().map(|(f, s)| rank_entry(f, s)).collect();
    let selected: Vec<String> = out
        .selected
        .iter()
        .map(|(f, _)| f.effect.name().to_owned())
        .collect();
    let verdict = selected.first().cloned().unwrap_or_else(|| "none".into());
    let reg_b = regimes::per_regime(&before, &labels);
    let reg_a = regimes::per_regime(&after, &labels);
    let per_regime = reg_b
        .iter()
        .map(|b| {
            let a = reg_a.iter().find(|a| a.name == b.name);
            let (ra, pa) = a.map_or((0.0, 0.0), |a| (a.rms, a.peak));
            RegimeChange {
                name: b.name.clone(),
                rms_before: b.rms,
                rms_after: ra,
                peak_before: b.peak,
                peak_after: pa,
                shrink: if b.rms > 0.0 { 1.0 - ra / b.rms } else { 0.0 },
            }
        })
        .collect();
    let (rb, ra) = (rms(&before), rms(&after));
    let mut fitted = preset.clone();
    if let Some(a) = fitted.axes.iter_mut().find(|a| a.name == main.axis) {
        *a = out.final_cand.model.axis.clone();
    }
    Report {
        preset: preset.name.clone(),
        axis: main.axis.clone(),
        base_axis: base_axis.clone(),
        t3_s: main.t3_s,
        resampled: main.resampled,
        samples_fit: eng.split.n_fit,
        samples_holdout: hold_rec.len(),
        holdout_source: if eng.split.validate.is_some() {
            "validation record".into()
        } else {
            "end of the record".into()
        },
        time_offset_ms: eng.time_offset_ms,
        holdout_masked: eng.hold_mask.iter().filter(|k| !**k).count(),
        units: "position residuals in um (measured - simulated); force residuals in N".into(),
        verdict,
        shrink: 1.0
            - out
                .selected
                .iter()
                .map(|(_, s)| 1.0 - s.shrink)
                .product::<f64>(),
        selected,
        ranking,
        regimes: reg_b,
        position_bins: regimes::per_bin(&before, &pos_mm, 10),
        base_bins: hold_rec
            .base_pos_m
            .as_ref()
            .map(|b| {
                let mm: Vec<f64> = b.iter().map(|x| x * 1e3).collect();
                regimes::per_bin(&before, &mm, 10)
            })
            .unwrap_or_default(),
        time_bins: regimes::per_bin(&before, &t, 10),
        windows: regimes::worst_windows(&after, hold_rec.t0_s, hold_rec.t3_s, win_len, 10),
        windows_before: regimes::worst_windows(&before, hold_rec.t0_s, hold_rec.t3_s, win_len, 10),
        force_rms_before: eng.nom.hold_force.as_deref().map(rms),
        force_rms_after: out.final_eval.hold_force.as_deref().map(rms),
        overall: Figures {
            rms_before: rb,
            rms_after: ra,
            peak_before: peak(&before),
            peak_after: peak(&after),
            shrink: if rb > 0.0 { 1.0 - ra / rb } else { 0.0 },
        },
        per_regime,
        fitted: Some(fitted),
        series: Some(Series {
            t_s: t,
            pos_mm,
            before_um: before,
            after_um: after,
            regimes: labels,
        }),
    }
}

fn rank_entry(f: &Fitted, s: &Scores) -> RankEntry {
    let defs = f.effect.params();
    let mut params: BTreeMap<String, f64> = defs
        .iter()
        .zip(&f.theta)
        .map(|(d, v)| (d.key.to_owned(), *v))
        .collect();
    params.extend(f.extra.clone());
    let params_std = defs
        .iter()
        .zip(&f.std)
        .map(|(d, v)| (d.key.to_owned(), *v))
        .collect();
    RankEntry {
        effect: f.effect.name().to_owned(),
        params,
        params_std,
        fit_rms_before: s.fit_pos_before * 1e6,
        fit_rms_after: s.fit_pos_after * 1e6,
        holdout_rms_before: s.hold_pos_before * 1e6,
        holdout_rms_after: s.hold_pos_after * 1e6,
        shrink: s.shrink,
        shrink_pos: s.shrink_pos,
        shrink_force: s.shrink_force,
        score: s.score,
        significant: s.significant,
        note: f.note.clone(),
    }
}
