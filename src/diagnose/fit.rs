//! Fitting one candidate effect on a base model: its signature first (a clearly absent one
//! skips the fit), then each of its variants by least squares on the fitting part — the
//! effect's own parameters alone, then jointly with the calibration and the effects
//! already selected — and the variant kept by the criterion.

use std::collections::BTreeMap;

use serde::Serialize;

use super::DiagnoseError;
use super::calibrate::{CalParam, Calibration};
use super::criterion::{self, Judgement, Part, Scale};
use super::effects::{Candidate, Effect, ParamDef};
use super::engine::{Cand, Engine, Eval};
use super::lm::{self, Param};
use super::replay::Disturbance;

/// What supports (or rules out) an effect besides the criterion: its signature test.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Evidence {
    /// Whether the signature is clearly there.
    pub pass: bool,
    /// Whether it is clearly absent: the fit is skipped.
    pub absent: bool,
    /// The figures, in words (for the report and the GUI).
    pub text: String,
    /// The figures by name (unit in the key).
    pub figures: BTreeMap<String, f64>,
    /// Starting values for the fit, in the order of the effect's parameters.
    #[serde(skip)]
    pub hint: Vec<f64>,
    /// What the signature's detector found, for the candidate's variants to shape from
    /// (not found twice).
    #[serde(skip)]
    pub detail: Option<Detail>,
}

/// A detector's finding carried from a candidate's signature to its variants.
#[derive(Clone)]
pub struct Detail(pub std::sync::Arc<dyn std::any::Any + Send + Sync>);

impl std::fmt::Debug for Detail {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Detail(..)")
    }
}

impl Detail {
    /// Wraps a finding.
    pub fn new<T: Send + Sync + 'static>(t: T) -> Detail {
        Detail(std::sync::Arc::new(t))
    }
}

impl Evidence {
    /// The detector's finding of type `T`, if the signature kept one.
    pub fn detail<T: 'static>(&self) -> Option<&T> {
        self.detail.as_ref().and_then(|d| d.0.downcast_ref::<T>())
    }
}

impl Evidence {
    /// No signature at all, and why: the fit is skipped.
    pub fn absent(why: impl Into<String>) -> Evidence {
        Evidence {
            absent: true,
            text: why.into(),
            ..Evidence::default()
        }
    }

    /// A signature test that found the signature (`pass`) or not, with its figures.
    pub fn found(pass: bool, text: impl Into<String>) -> Evidence {
        Evidence {
            pass,
            text: text.into(),
            ..Evidence::default()
        }
    }

    /// Adds a named figure.
    pub fn with(mut self, key: &str, v: f64) -> Evidence {
        self.figures.insert(key.to_owned(), v);
        self
    }

    /// Sets the starting values.
    pub fn hint(mut self, hint: Vec<f64>) -> Evidence {
        self.hint = hint;
        self
    }
}

/// The measured signals the signature tests read, on the fitting part: velocity and
/// acceleration from the measured position (smoothed over a few samples so the encoder grid
/// does not dominate), and the base model's residuals.
pub struct Signals {
    /// Time of each sample, s.
    pub t_s: Vec<f64>,
    /// Measured position, m.
    pub pos_m: Vec<f64>,
    /// The positions as the sensor logged them (before a realignment of a skewed channel,
    /// which puts values between its counts), m: what the grid test reads.
    pub logged_pos_m: Vec<f64>,
    /// Measured velocity, m/s.
    pub vel_mps: Vec<f64>,
    /// Measured acceleration, m/s².
    pub acc_mps2: Vec<f64>,
    /// Commanded velocity over the same ±5 ms as the measured one, m/s.
    pub cmd_vel_mps: Vec<f64>,
    /// Commanded acceleration, m/s².
    pub cmd_acc_mps2: Vec<f64>,
    /// Position residual of the base model, m.
    pub r_pos: Vec<f64>,
    /// Force residual of the base model, N.
    pub r_force: Option<Vec<f64>>,
    /// Correlation length of the residual, samples.
    pub corr_len: f64,
}

/// Centred difference of `x` over ±`h` samples, per `dt`.
fn derivative(x: &[f64], h: usize, dt: f64) -> Vec<f64> {
    let n = x.len();
    (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(h), (i + h).min(n.saturating_sub(1)));
            if b > a {
                (x[b] - x[a]) / ((b - a) as f64 * dt)
            } else {
                0.0
            }
        })
        .collect()
}

impl Signals {
    /// The signals of the engine's fitting part under base residual `ev`.
    pub fn new(eng: &Engine, ev: &Eval) -> Signals {
        let rec = eng.split.main;
        let n = eng.split.n_fit;
        let dt = rec.t3_s;
        // About 5 ms either side: several encoder counts at creep speed, short against a
        // reversal.
        let h = ((0.005 / dt).round() as usize).max(1);
        let pos = rec.pos_m[..n].to_vec();
        let vel = derivative(&pos, h, dt);
        let acc = derivative(&vel, h, dt);
        let cmd_vel = derivative(&rec.cmd_m[..n], 1, dt);
        Signals {
            t_s: (0..n).map(|k| rec.t_s(k)).collect(),
            cmd_acc_mps2: derivative(&cmd_vel, 1, dt),
            cmd_vel_mps: derivative(&rec.cmd_m[..n], h, dt),
            logged_pos_m: rec
                .logged_pos_m
                .as_ref()
                .map_or_else(|| pos.clone(), |l| l[..n].to_vec()),
            pos_m: pos,
            vel_mps: vel,
            acc_mps2: acc,
            r_pos: ev.fit_pos.clone(),
            r_force: ev.fit_force.clone(),
            corr_len: eng.corr_len,
        }
    }
}

/// Sets a parametric shape's parameters on a model.
pub type SetFn = fn(&mut Cand, &[f64]);

/// How a fitted effect changes a model, so that it can be added to another base.
#[derive(Debug, Clone)]
pub enum Shape {
    /// Parameters set by the effect's function.
    Params {
        /// The function.
        set: SetFn,
        /// The parameters.
        theta: Vec<f64>,
    },
    /// A lead-error table (position mm, error µm).
    LeadTable(Vec<(f64, f64)>),
    /// A force no state explains, on the main record.
    Disturbance(Disturbance),
}

impl Shape {
    /// Adds the effect to `c`.
    pub fn apply(&self, c: &mut Cand) {
        match self {
            Shape::Params { set, theta } => set(c, theta),
            Shape::LeadTable(t) => super::effects::lead::set_table(c, t),
            Shape::Disturbance(d) => c.model.disturbance.push(d.clone()),
        }
    }

    /// The same shape at parameters `th` (detector shapes as they are).
    pub fn with_theta(&self, th: &[f64]) -> Shape {
        match self {
            Shape::Params { set, .. } => Shape::Params {
                set: *set,
                theta: th.to_vec(),
            },
            other => other.clone(),
        }
    }
}

/// A detector-shaped variant: the shape as found, the figures it is reported by and the
/// parameters it is charged.
pub struct Fixed {
    /// The shape.
    pub shape: Shape,
    /// Report keys.
    pub keys: Vec<String>,
    /// Report values.
    pub theta: Vec<f64>,
    /// Parameters charged by the criterion's penalty.
    pub n_params: usize,
}

/// One way an effect can look: its parameters and how they are set, or a shape a
/// detector found.
pub struct Variant {
    /// Name in the report (`linear`, `hardening`, `square_wave`, …).
    pub name: &'static str,
    /// What the shape is, in words.
    pub note: String,
    /// The fitted parameters (empty for a detector's shape).
    pub defs: &'static [ParamDef],
    /// How they are set.
    pub set: SetFn,
    /// Starting points of the fit (each as long as `defs`).
    pub starts: Vec<Vec<f64>>,
    /// A detector's shape, fitted already.
    pub fixed: Option<Fixed>,
    /// The part the criterion scores it on: the held-out part, or the fitting part for a
    /// force at times no state predicts.
    pub part: Part,
    /// Whether its fits replay the whole fitting part (a screw's growth).
    pub slow: bool,
}

impl Variant {
    /// A parametric variant scored on the held-out part.
    pub fn params(
        name: &'static str,
        note: impl Into<String>,
        defs: &'static [ParamDef],
        set: SetFn,
        starts: Vec<Vec<f64>>,
    ) -> Variant {
        Variant {
            name,
            note: note.into(),
            defs,
            set,
            starts,
            fixed: None,
            part: Part::Held,
            slow: false,
        }
    }

    /// A detector's shape, scored on `part`.
    pub fn fixed(name: &'static str, note: impl Into<String>, fixed: Fixed, part: Part) -> Variant {
        Variant {
            name,
            note: note.into(),
            defs: &[],
            set: |_, _| {},
            starts: vec![],
            fixed: Some(fixed),
            part,
            slow: false,
        }
    }
}

/// An effect in the base: selected in an earlier round.
#[derive(Debug, Clone)]
pub struct Chosen {
    /// Which effect.
    pub effect: Effect,
    /// How it is added.
    pub shape: Shape,
    /// The parameters a joint fit moves again (empty: kept as found).
    pub defs: &'static [ParamDef],
}

impl Chosen {
    /// The parameters a joint fit moves, when it moves any.
    fn theta(&self) -> Option<&[f64]> {
        match (&self.shape, self.defs.is_empty()) {
            (Shape::Params { theta, .. }, false) => Some(theta),
            _ => None,
        }
    }
}

/// The nominal with calibration values `values` and the chosen effects, those with
/// parameters at `sel` (their refittable parameters in order; None: as they are).
pub fn rebuild(
    nominal: &Cand,
    cal: &Calibration,
    values: &[f64],
    chosen: &[Chosen],
    sel: Option<&[f64]>,
) -> Cand {
    let mut c = nominal.clone();
    for ((p, _), v) in cal.ratios.iter().zip(values) {
        p.apply(&mut c.model, *v);
    }
    let mut at = 0;
    for s in chosen {
        match (s.theta(), sel) {
            (Some(th), Some(sel)) => {
                let n = th.len();
                let th = sel.get(at..at + n).unwrap_or(th);
                s.shape.with_theta(th).apply(&mut c);
                at += n;
            }
            _ => s.shape.apply(&mut c),
        }
    }
    c
}

/// The refittable parameters of `chosen`, in order, with their bounds.
pub fn chosen_params(chosen: &[Chosen]) -> (Vec<f64>, Vec<Param>) {
    let mut theta = vec![];
    let mut params = vec![];
    for s in chosen {
        if let Some(th) = s.theta() {
            for (d, v) in s.defs.iter().zip(th) {
                theta.push(*v);
                params.push(Param {
                    lo: d.lo,
                    hi: d.hi,
                    scale: v.abs().max(d.init.abs()).max(1e-9),
                });
            }
        }
    }
    (theta, params)
}

/// What every candidate fit needs.
pub struct Context<'c, 'a> {
    /// The residual engine.
    pub eng: &'c Engine<'a>,
    /// The criterion's scale.
    pub scale: &'c Scale,
    /// The quantum the preset's position sensor rounds to, m (0: none); the replay reads
    /// it unrounded.
    pub sensor_quantum_m: f64,
    /// The nominal model, before calibration.
    pub nominal: &'c Cand,
    /// The calibration (which parameters, the shifts).
    pub cal: &'c Calibration,
    /// The calibration values of the base.
    pub values: &'c [f64],
    /// The effects in the base.
    pub chosen: &'c [Chosen],
    /// The model effects are added to.
    pub base: &'c Cand,
    /// Its residuals.
    pub base_eval: &'c Eval,
    /// The measured signals and the base's residuals.
    pub sig: &'c Signals,
}

/// An effect fitted on a base.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// Which effect.
    pub effect: Effect,
    /// Which of its variants.
    pub variant: &'static str,
    /// What the variant is, and why it was kept.
    pub note: String,
    /// Report key (unit in it) of each parameter.
    pub keys: Vec<String>,
    /// The parameters.
    pub theta: Vec<f64>,
    /// One standard deviation of each.
    pub std: Vec<f64>,
    /// How it is added to a model.
    pub chosen: Chosen,
    /// Parameters charged by the criterion.
    pub n_params: usize,
    /// The part it is scored on.
    pub part: Part,
    /// The base with the effect (calibration and earlier effects as the joint fit left
    /// them).
    pub cand: Cand,
    /// Its residuals.
    pub eval: Eval,
    /// The calibration values of `cand`.
    pub values: Vec<f64>,
    /// The earlier effects' refittable parameters in `cand`.
    pub sel_theta: Vec<f64>,
    /// The signature test.
    pub evidence: Evidence,
    /// The criterion's judgement of the base against `cand` (floor 0).
    pub judgement: Judgement,
    /// Further figures of the fit.
    pub extra: BTreeMap<String, f64>,
}

/// The solver's patience (evaluations per parameter) of a fit of the effect's parameters
/// alone, and of the joint fit (see [`Context::polish`]) that starts where it ended.
const PATIENCE_ALONE: usize = 6;
const PATIENCE_JOINT: usize = 6;

/// Whether a calibration parameter and an effect are one quantity (fitting both is
/// degenerate): it stays where it is while that effect is fitted.
fn owns(e: Effect, p: CalParam) -> bool {
    matches!(
        (e, p),
        (
            Effect::CoulombFriction,
            CalParam::Coulomb | CalParam::Smoothing
        ) | (Effect::ViscousFriction, CalParam::Viscous)
    )
}

impl Context<'_, '_> {
    /// The signature of `c`, and its fit when the signature is not clearly absent: each
    /// variant fitted, the first kept unless a later one wins over it by the criterion.
    pub fn fit(&self, c: &dyn Candidate) -> Result<Result<Fitted, Evidence>, DiagnoseError> {
        let ev = c.signature(self);
        if ev.absent {
            return Ok(Err(ev));
        }
        let mut best: Option<Fitted> = None;
        for v in c.variants(self, &ev)? {
            let Some(f) = self.fit_variant(c.effect(), &v, &ev)? else {
                continue;
            };
            best = Some(match best {
                None => f,
                Some(b) => {
                    let part = if b.part == Part::Fit || f.part == Part::Fit {
                        Part::Fit
                    } else {
                        Part::Held
                    };
                    let dp = f.n_params.saturating_sub(b.n_params);
                    let j = criterion::judge(self.scale, &b.eval, &f.eval, part, dp, 0.0);
                    if j.passes {
                        Fitted {
                            note: format!(
                                "{} (it won over the {} shape: {})",
                                f.note,
                                b.variant,
                                j.text()
                            ),
                            ..f
                        }
                    } else {
                        b
                    }
                }
            });
        }
        Ok(best.ok_or(ev))
    }

    /// One variant fitted (or a detector's shape added) and judged against the base.
    fn fit_variant(
        &self,
        effect: Effect,
        v: &Variant,
        ev: &Evidence,
    ) -> Result<Option<Fitted>, DiagnoseError> {
        let (chosen, keys, theta, std, n_params, cand, values, sel_theta) = match &v.fixed {
            Some(fx) => {
                let mut cand = self.base.clone();
                fx.shape.apply(&mut cand);
                let chosen = Chosen {
                    effect,
                    shape: fx.shape.clone(),
                    defs: &[],
                };
                (
                    chosen,
                    fx.keys.clone(),
                    fx.theta.clone(),
                    vec![0.0; fx.theta.len()],
                    fx.n_params,
                    cand,
                    self.values.to_vec(),
                    vec![],
                )
            }
            None => {
                let Some(p) = self.fit_params(v)? else {
                    return Ok(None);
                };
                let chosen = Chosen {
                    effect,
                    shape: Shape::Params {
                        set: v.set,
                        theta: p.theta.clone(),
                    },
                    defs: v.defs,
                };
                let keys = v.defs.iter().map(|d| d.key.to_owned()).collect();
                (
                    chosen,
                    keys,
                    p.theta,
                    p.std,
                    v.defs.len(),
                    p.cand,
                    p.values,
                    p.sel_theta,
                )
            }
        };
        let eval = self.eng.evaluate(&cand)?;
        let judgement = criterion::judge(self.scale, self.base_eval, &eval, v.part, n_params, 0.0);
        let mut extra = BTreeMap::new();
        for ((p, _), r) in self.cal.ratios.iter().zip(&values) {
            extra.insert(format!("calibration_{}", p.name()), *r);
        }
        Ok(Some(Fitted {
            effect,
            variant: v.name,
            note: v.note.clone(),
            keys,
            theta,
            std,
            chosen,
            n_params,
            part: v.part,
            cand,
            eval,
            values,
            sel_theta,
            evidence: ev.clone(),
            judgement,
            extra,
        }))
    }

    /// Least squares over a variant's parameters alone on the base, from each start.
    fn fit_params(&self, v: &Variant) -> Result<Option<ParamFit>, DiagnoseError> {
        let own: Vec<Param> = v
            .defs
            .iter()
            .map(|d| Param {
                lo: d.lo,
                hi: d.hi,
                scale: d.init.abs().max(1e-9),
            })
            .collect();
        let alone = |th: &[f64]| {
            let mut c = self.base.clone();
            (v.set)(&mut c, th);
            c
        };
        let rows = |th: &[f64]| self.rows_of(&alone(th), v.slow);
        let mut best: Option<lm::LmFit> = None;
        for s in &v.starts {
            let s: Vec<f64> = s
                .iter()
                .zip(v.defs)
                .map(|(x, d)| x.clamp(d.lo, d.hi))
                .collect();
            let f = lm::fit(&s, &own, &rows, 0.03, PATIENCE_ALONE)?;
            if f.rows.is_some() && best.as_ref().is_none_or(|b| f.cost < b.cost) {
                best = Some(f);
            }
        }
        let Some(f) = best else {
            return Ok(None);
        };
        let std = lm::std_devs(&f, self.per_row(v.slow));
        Ok(Some(ParamFit {
            cand: alone(&f.theta),
            std,
            theta: f.theta,
            values: self.values.to_vec(),
            sel_theta: chosen_params(self.chosen).0,
        }))
    }

    /// Each row of the solver is worth this many independent samples (rows correlated over
    /// the residual's correlation length).
    fn per_row(&self, slow: bool) -> f64 {
        let n_lm = self.eng.n_lm(slow);
        1.0 / (self.sig.corr_len / Engine::stride_of(n_lm) as f64).max(1.0)
    }

    /// `f` fitted again jointly with the calibration values it does not own and the earlier
    /// effects' parameters, from where it stands: a calibration value may have leant towards
    /// the missing effect (a velocity gain standing in for friction), which the effect alone
    /// cannot undo. Kept when it leaves less of the fitting part; judged again against the
    /// base. A detector's shape stays as found.
    pub fn polish(&self, f: Fitted) -> Result<Fitted, DiagnoseError> {
        let (Shape::Params { set, theta }, false) = (&f.chosen.shape, f.chosen.defs.is_empty())
        else {
            return Ok(f);
        };
        let (set, defs) = (*set, f.chosen.defs);
        let slow = f.effect == Effect::ThermalGrowth
            || self
                .chosen
                .iter()
                .any(|c| c.effect == Effect::ThermalGrowth);
        let n_e = defs.len();
        let free: Vec<usize> = (0..self.values.len())
            .filter(|&i| {
                !owns(f.effect, self.cal.ratios[i].0)
                    && !self
                        .chosen
                        .iter()
                        .any(|c| owns(c.effect, self.cal.ratios[i].0))
            })
            .collect();
        let (sel0, sel_params) = chosen_params(self.chosen);
        let n_r = free.len();
        let values_of = |th: &[f64]| -> Vec<f64> {
            let mut r = self.values.to_vec();
            for (j, &i) in free.iter().enumerate() {
                r[i] = th[n_e + j];
            }
            r
        };
        let joint_cand = |th: &[f64]| {
            let mut c = rebuild(
                self.nominal,
                self.cal,
                &values_of(th),
                self.chosen,
                Some(&th[n_e + n_r..]),
            );
            set(&mut c, &th[..n_e]);
            c
        };
        let mut params: Vec<Param> = defs
            .iter()
            .zip(theta)
            .map(|(d, v)| Param {
                lo: d.lo,
                hi: d.hi,
                scale: v.abs().max(d.init.abs()).max(1e-9),
            })
            .collect();
        params.extend(free.iter().map(|&i| self.cal.ratios[i].0.bounds()));
        params.extend(sel_params);
        let mut start = theta.clone();
        start.extend(free.iter().map(|&i| self.values[i]));
        start.extend(sel0.iter().copied());
        let rows = |th: &[f64]| self.rows_of(&joint_cand(th), slow);
        let before = rows(&start)?.map_or(f64::INFINITY, |r| r.norm_squared());
        let joint = lm::fit_secant(&start, &params, &rows, 0.03, PATIENCE_JOINT)?;
        if joint.rows.is_none() || joint.cost >= before {
            return Ok(f);
        }
        let cand = joint_cand(&joint.theta);
        let eval = self.eng.evaluate(&cand)?;
        let std = lm::std_devs(&joint, self.per_row(slow));
        let values = values_of(&joint.theta);
        let judgement =
            criterion::judge(self.scale, self.base_eval, &eval, f.part, f.n_params, 0.0);
        let mut extra = f.extra.clone();
        for ((p, _), r) in self.cal.ratios.iter().zip(&values) {
            extra.insert(format!("calibration_{}", p.name()), *r);
        }
        Ok(Fitted {
            theta: joint.theta[..n_e].to_vec(),
            std: std[..n_e].to_vec(),
            chosen: Chosen {
                shape: f.chosen.shape.with_theta(&joint.theta[..n_e]),
                ..f.chosen.clone()
            },
            cand,
            eval,
            values,
            sel_theta: joint.theta[n_e + n_r..].to_vec(),
            judgement,
            extra,
            ..f
        })
    }

    /// The solver's rows of candidate `c`; None for a model outside the fits' range (a
    /// spring the base has not, damped beyond critical or ringing above the Nyquist
    /// frequency), as for a replay that diverges.
    fn rows_of(
        &self,
        c: &Cand,
        slow: bool,
    ) -> Result<Option<nalgebra::DVector<f64>>, DiagnoseError> {
        if super::effects::compliance::outside_spring(c)
            && !super::effects::compliance::outside_spring(self.base)
        {
            return Ok(None);
        }
        Ok(Some(self.eng.lm_rows(&self.eng.sim_fit(c, slow)?)))
    }
}

/// A parametric fit's result.
struct ParamFit {
    theta: Vec<f64>,
    std: Vec<f64>,
    cand: Cand,
    values: Vec<f64>,
    sel_theta: Vec<f64>,
}
