//! "Which": each candidate effect gets a signature test (its evidence, [`Evidence`]) and a
//! fit on top of the current base model, scored on held-out data.
//!
//! An effect counts as found only when both agree: its signature is in the residual (a grid,
//! a period along the travel, a lag, a resonance, a drift, a friction term, a force no state
//! explains) and adding it shrinks the held-out residual. Shrink alone let a delay or a
//! compliance absorb any small mismatch; a signature alone says nothing about size.

mod disturbance;
mod friction;
mod special;

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use serde::Serialize;

use super::DiagnoseError;
use super::calibrate::Calibration;
use super::effects::Effect;
use super::engine::{Cand, Engine, Eval, PENALTY_PER_PARAM, Scores};
use super::lm::{self, Param};
use crate::preset::Coupling;

/// Smallest held-out shrink (after the complexity penalty) that counts as an effect.
pub const MIN_SHRINK: f64 = 0.10;

/// Complexity penalty per parameter, in held-out shrink, for an effect whose signature was
/// found (the engine's full penalty applies otherwise).
pub const PENALTY_WITH_SIGNATURE: f64 = 0.005;

/// Smallest held-out shrink (after the penalty) for an effect whose signature is a shape
/// test on the residual (a pitch, a resonance, a drift, a play at the reversals). Friction,
/// force and delay terms are regressions any small mismatch of the nominal can pass, and
/// the external disturbance's evidence is only "what no state explains": they keep
/// [`MIN_SHRINK`] and the full penalty.
pub const MIN_SHRINK_WITH_SHAPE: f64 = 0.05;

/// Whether `e`'s signature is a shape test (see [`MIN_SHRINK_WITH_SHAPE`]).
fn has_shape_test(e: Effect) -> bool {
    matches!(
        e,
        Effect::LeadError
            | Effect::Compliance
            | Effect::ThermalGrowth
            | Effect::Backlash
            | Effect::BacklashAsymmetry
    )
}
/// A periodic external force whose spectral peak stands this far above the median of its
/// spectrum, and which explains this share of the residual it was found in, is a shape
/// test like a pitch or a resonance (see [`MIN_SHRINK_WITH_SHAPE`]). Set on the independent
/// seed 1: a wave of level steps there reads 910× and 0.40; no clean record (skewed or not)
/// shows a periodic force at all.
const STRONG_PERIODIC: (f64, f64) = (100.0, 0.3);

/// Whether `f` is an external disturbance found as a strong periodic force.
fn strong_periodic_force(f: &Fitted) -> bool {
    let fig = |k: &str| f.evidence.figures.get(k).copied().unwrap_or(0.0);
    f.effect == Effect::ExternalDisturbance
        && fig("peak_ratio") >= STRONG_PERIODIC.0
        && fig("explained_share") >= STRONG_PERIODIC.1
}

/// Share of the fitting residual that bursts of force must take away to count without a
/// held-out shrink (see `score`). Set on the independent seed 1.
const BURSTS_FIT_SHRINK: f64 = 0.2;

/// A signature term must stand this many standard errors clear of zero.
pub const MIN_T: f64 = 6.0;

/// What supports (or rules out) an effect besides the shrink.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Evidence {
    /// Whether the signature is there.
    pub pass: bool,
    /// The figures, in words (for the report and the GUI).
    pub text: String,
    /// The figures by name (unit in the key).
    pub figures: BTreeMap<String, f64>,
    /// Starting values for the fit, in the order of the effect's parameters.
    #[serde(skip)]
    pub hint: Vec<f64>,
    /// Further starting values tried besides `hint` and the effect's grid (another reading
    /// of the same signature; the fit keeps the start that ends best).
    #[serde(skip)]
    pub more_starts: Vec<Vec<f64>>,
}

impl Evidence {
    /// No signature, and why.
    pub fn absent(why: impl Into<String>) -> Evidence {
        Evidence {
            pass: false,
            text: why.into(),
            ..Evidence::default()
        }
    }

    /// Adds a named figure.
    pub fn with(mut self, key: &str, v: f64) -> Evidence {
        self.figures.insert(key.to_owned(), v);
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
    /// Commanded velocity over the same ±5 ms as the measured one, m/s: the reversals a
    /// play or a friction change sits at are the command's (a hunting drive's measured
    /// velocity changes sign all the time).
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

/// An effect fitted on top of a base.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// Which effect.
    pub effect: Effect,
    /// Report key (unit in it) of each parameter.
    pub keys: Vec<String>,
    /// The parameters.
    pub theta: Vec<f64>,
    /// One standard deviation of each.
    pub std: Vec<f64>,
    /// The base with the effect.
    pub cand: Cand,
    /// Its residuals.
    pub eval: Eval,
    /// Parameters counted in the complexity penalty.
    pub n_params: usize,
    /// Further figures of the fit.
    pub extra: BTreeMap<String, f64>,
    /// A remark (why it is or is not counted).
    pub note: String,
    /// The signature test.
    pub evidence: Evidence,
    /// Whether the effect's parameters enter the joint re-fit (effects fitted by a detector
    /// keep what it found).
    pub refit: bool,
    /// How the effect was added, to add it again to another base.
    pub applied: Applied,
    /// The calibration ratios of `cand` (fitted again alongside the effect, or the base's).
    pub ratios: Vec<f64>,
    /// The selected effects' parameters in `cand` when they were fitted again alongside
    /// this one ([`Context::selected_theta`] order); empty when they were kept.
    pub sel_theta: Vec<f64>,
    /// This fit's model with the effect taken out again (the calibration ratios and the
    /// earlier effects as the joint fit left them), and its residuals; None when the fit
    /// moved nothing but the effect. What the effect itself explains is judged against it
    /// (see [`score`]).
    pub without: Option<(Cand, Eval)>,
}

/// How a fitted effect changes a model, so that it can be added to another base (the joint
/// re-fit starts again from the nominal).
#[derive(Debug, Clone)]
pub enum Applied {
    /// Through [`Effect::apply`] with these parameters.
    Params(Effect, Vec<f64>),
    /// A lead-error table (position mm, error µm).
    LeadTable(Vec<(f64, f64)>),
    /// A disturbance on the main record (and those found on a validation record).
    Disturbance(super::replay::Disturbance, Vec<super::replay::Disturbance>),
    /// A stroke friction whose film wears by distance (see [`friction::set_film`]).
    Film(Vec<f64>),
    /// A viscous friction that differs by direction (see [`friction::set_split`]).
    Split(Vec<f64>),
    /// A speed term that grows as a power of the speed (see [`friction::set_power`]).
    Power(Vec<f64>),
    /// A Stribeck friction whose excess falls off exponentially (see
    /// [`friction::set_stribeck_exponential`]).
    StribeckExp(Vec<f64>),
    /// A Coulomb friction that builds up as tanh(v/ε) (see
    /// [`friction::set_coulomb_smooth`]).
    CoulombSmooth(Vec<f64>),
    /// A payload on a mount that stiffens as it deflects (see [`special::set_hardening`]).
    Hardening(Vec<f64>),
    /// A compliance as the screw's spring between motor and table (see
    /// [`super::effects::set_screw_spring`]).
    Screw(Vec<f64>),
    /// A command delay with a first-order lag behind it (see [`special::set_delay_lag`]).
    DelayLag(Vec<f64>),
}

impl Applied {
    /// The effect and its parameters, for the kinds a least-squares fit moves again.
    pub fn fitted(&self) -> Option<(Effect, &[f64])> {
        match self {
            Applied::Params(e, th) => Some((*e, th)),
            Applied::Screw(th) => Some((Effect::Compliance, th)),
            Applied::Power(th) => Some((Effect::ViscousFriction, th)),
            Applied::StribeckExp(th) => Some((Effect::StribeckFriction, th)),
            Applied::CoulombSmooth(th) => Some((Effect::CoulombFriction, th)),
            Applied::Film(th) => Some((Effect::StrokeFriction, th)),
            _ => None,
        }
    }

    /// The parameters [`Applied::fitted`] gives, as the solver bounds them (none for the
    /// kinds a fit does not move again).
    pub fn defs(&self) -> &'static [crate::diagnose::effects::ParamDef] {
        match self {
            Applied::Params(e, _) => e.params(),
            Applied::Screw(_) => Effect::Compliance.params(),
            Applied::Power(_) => &friction::POWER_DEFS,
            Applied::StribeckExp(_) => Effect::StribeckFriction.params(),
            Applied::CoulombSmooth(_) => &friction::SMOOTH_DEFS,
            Applied::Film(_) => &friction::FILM_DEFS,
            _ => &[],
        }
    }

    /// The same kind of effect at parameters `th` (see [`Applied::fitted`]; others as they
    /// are).
    pub fn with_theta(&self, th: &[f64]) -> Applied {
        match self {
            Applied::Params(e, _) => Applied::Params(*e, th.to_vec()),
            Applied::Screw(_) => Applied::Screw(th.to_vec()),
            Applied::Power(_) => Applied::Power(th.to_vec()),
            Applied::StribeckExp(_) => Applied::StribeckExp(th.to_vec()),
            Applied::CoulombSmooth(_) => Applied::CoulombSmooth(th.to_vec()),
            Applied::Film(_) => Applied::Film(th.to_vec()),
            other => other.clone(),
        }
    }

    /// Adds the effect to `c`.
    pub fn apply(&self, c: &mut Cand) {
        match self {
            Applied::Params(e, th) => e.apply(th, &mut c.model),
            Applied::LeadTable(t) => set_lead_table(c, t),
            Applied::Film(th) => friction::set_film(c, th),
            Applied::Split(th) => friction::set_split(c, th),
            Applied::Power(th) => friction::set_power(c, th),
            Applied::StribeckExp(th) => friction::set_stribeck_exponential(c, th),
            Applied::CoulombSmooth(th) => friction::set_coulomb_smooth(c, th),
            Applied::Hardening(th) => special::set_hardening(c, th),
            Applied::Screw(th) => super::effects::set_screw_spring(&mut c.model, th),
            Applied::DelayLag(th) => special::set_delay_lag(c, th),
            Applied::Disturbance(d, v) => {
                c.model.disturbance.push(d.clone());
                c.dist_val.extend(v.iter().cloned());
            }
        }
    }
}

/// Gives `c` the lead-error table `t` (position mm, error µm). A lead error the nominal did
/// not have starts from nothing: the preset's disabled cyclic and cumulative terms (typical
/// values a user never switched on) would otherwise come on with the table and add an error
/// the record does not have.
pub fn set_lead_table(c: &mut Cand, t: &[(f64, f64)]) {
    let l = &mut c.model.axis.lead_error;
    if !l.enabled {
        l.amplitude_um = 0.0;
        l.cumulative_um_per_m = 0.0;
    }
    l.enabled = true;
    l.table = t.to_vec();
}

/// An effect selected in an earlier round, as the later rounds see it.
#[derive(Debug, Clone)]
pub struct Selected {
    /// How it was added.
    pub applied: Applied,
    /// Whether its parameters are fitted again alongside every later candidate whose
    /// signature is there (forward selection that re-fits after each addition: an effect
    /// found first keeps only what the next one does not explain better).
    pub refit: bool,
}

impl Selected {
    /// The effect and its parameters, when they are fitted again in later rounds.
    fn refit_params(&self) -> Option<(Effect, &[f64])> {
        self.applied.fitted().filter(|_| self.refit)
    }

    /// [`Selected::refit_params`] with their bounds.
    fn refit_defs(&self) -> Option<(&'static [crate::diagnose::effects::ParamDef], &[f64])> {
        self.refit_params().map(|(_, th)| (self.applied.defs(), th))
    }
}

/// Whether a friction effect and a calibration ratio are one quantity (a Coulomb ratio and
/// an added Coulomb force, or viscous): fitting both is degenerate.
fn owns(e: Effect, p: super::calibrate::CalParam) -> bool {
    use super::calibrate::CalParam;
    matches!(
        (e, p),
        (Effect::CoulombFriction, CalParam::Coulomb) | (Effect::ViscousFriction, CalParam::Viscous)
    )
}

/// What every candidate fit needs.
pub struct Context<'c, 'a> {
    /// The residual engine.
    pub eng: &'c Engine<'a>,
    /// The nominal model, before calibration.
    pub nominal: &'c Cand,
    /// The effects selected so far (the base is the nominal, calibrated, with these).
    pub selected: &'c [Selected],
    /// The model effects are added to.
    pub base: &'c Cand,
    /// Its residuals.
    pub base_eval: &'c Eval,
    /// The calibration (which parameters, and the lags).
    pub cal: &'c Calibration,
    /// The calibration ratios of the base (they move when an effect is fitted with them).
    pub ratios: &'c [f64],
    /// The measured signals.
    pub sig: &'c Signals,
    /// Whether play (backlash, either kind) is selected already, modelled or proven by its
    /// signature alone (see [`FORCE_SHARE`]).
    pub play_found: bool,
    /// The first round's Coulomb evidence, for a Coulomb friction fitted beside a stroke
    /// friction (see [`Context::nested_coulomb`]); None in the first round.
    pub coulomb_first: Option<&'c Evidence>,
    /// The common lag of position and force (samples, negative: late) read again beside the
    /// first effect selected, for a command delay's signature in later rounds (see
    /// `special::delay`); None in the first round, or when it was not read.
    pub lag_beside_first: Option<f64>,
    /// The job of [`fit_all`] this context fits for, empty outside it: a warm start (see
    /// [`Context::fit_lm_defs`]) is the same job's, since two jobs run side by side and a
    /// fit one of them shares with the other would read whichever ended first.
    pub job: &'c str,
}

impl Context<'_, '_> {
    /// Whether a calibration parameter sits at its bound in the base.
    pub fn at_bound(&self, p: super::calibrate::CalParam) -> bool {
        self.cal
            .ratios
            .iter()
            .zip(self.ratios)
            .any(|((q, _), r)| *q == p && q.at_bound(*r))
    }

    /// The signature test of `effect` on the base's residual.
    pub fn evidence(&self, effect: Effect) -> Evidence {
        match effect {
            Effect::CoulombFriction
            | Effect::StribeckFriction
            | Effect::ViscousFriction
            | Effect::StrokeFriction
            | Effect::ConstantForce => friction::evidence(self, effect),
            Effect::Backlash | Effect::BacklashAsymmetry => {
                friction::reversal_evidence(self, effect)
            }
            _ => special::evidence(self, effect),
        }
    }

    /// The nominal, calibrated by `ratios`, with the selected effects, those re-fitted at
    /// `sel_theta` (their parameters in order, see [`Context::selected_theta`]): a base in
    /// which the calibration and the earlier effects can move again.
    fn rebuilt(&self, ratios: &[f64], sel_theta: &[f64]) -> Cand {
        let mut c = self.nominal.clone();
        for ((p, _), r) in self.cal.ratios.iter().zip(ratios) {
            p.apply(&mut c.model.axis, *r);
        }
        let mut at = 0;
        for s in self.selected {
            match s.refit_params() {
                Some((_, th)) => {
                    let n = th.len();
                    let th = sel_theta.get(at..at + n).unwrap_or(th);
                    s.applied.with_theta(th).apply(&mut c);
                    at += n;
                }
                None => s.applied.apply(&mut c),
            }
        }
        c
    }

    /// The parameters of the selected effects that are fitted again, in order.
    pub fn selected_theta(&self) -> Vec<f64> {
        self.selected
            .iter()
            .filter_map(Selected::refit_params)
            .flat_map(|(_, th)| th.iter().copied())
            .collect()
    }

    /// Bounds of [`Context::selected_theta`].
    fn selected_params(&self) -> Vec<Param> {
        self.selected
            .iter()
            .filter_map(Selected::refit_defs)
            .flat_map(|(defs, th)| {
                defs.iter().zip(th).map(|(d, v)| Param {
                    lo: d.lo,
                    hi: d.hi,
                    scale: v.abs().max(d.init.abs()).max(1e-9),
                })
            })
            .collect()
    }

    /// Fits `effect` on the base by least squares over its parameters, from the evidence's
    /// hint (and the effect's typical values), keeping the best of a few starts. When its
    /// signature is there, the calibration ratios are fitted again alongside: a ratio may
    /// have leant towards the missing effect (a velocity gain standing in for friction),
    /// and the effect alone cannot undo that.
    pub fn fit_lm(&self, effect: Effect, ev: Evidence) -> Result<Option<Fitted>, DiagnoseError> {
        self.fit_lm_as(
            effect,
            ev,
            &|th| Applied::Params(effect, th.to_vec()),
            LM_PATIENCE,
        )
    }

    /// [`Context::fit_lm`], the effect added to the model as `make` makes it from the
    /// parameters (a compliance as the screw's spring rather than a payload's mount), with
    /// the solver's `patience`.
    pub fn fit_lm_as(
        &self,
        effect: Effect,
        ev: Evidence,
        make: &(dyn Fn(&[f64]) -> Applied + Sync),
        patience: usize,
    ) -> Result<Option<Fitted>, DiagnoseError> {
        let defs = effect.params();
        let first: Vec<Vec<f64>> = starts(effect, &ev.hint)
            .into_iter()
            .chain(
                ev.more_starts
                    .iter()
                    .filter(|h| h.len() == defs.len())
                    .cloned(),
            )
            .collect();
        self.fit_lm_defs(effect, defs, first, ev, make, patience)
    }

    /// A richer shape of `effect` than [`Effect::params`] (parameters `defs`, starts
    /// `first`, applied by `make`), fitted as [`Context::fit_lm_defs`] does and described by
    /// `note`. Its parameters are not the effect's own: the later rounds and the final joint
    /// fit keep them as fitted.
    pub fn fit_variant(
        &self,
        effect: Effect,
        defs: &[crate::diagnose::effects::ParamDef],
        first: Vec<Vec<f64>>,
        ev: &Evidence,
        make: &(dyn Fn(&[f64]) -> Applied + Sync),
        note: &dyn Fn(&[f64]) -> String,
    ) -> Result<Option<Fitted>, DiagnoseError> {
        let fitted = self.fit_lm_defs(effect, defs, first, ev.clone(), make, LM_PATIENCE)?;
        Ok(fitted.map(|mut f| {
            f.refit = false;
            f.note = note(&f.theta);
            f
        }))
    }

    /// [`Context::fit_lm_as`] over parameters `defs` (another shape of the effect than
    /// [`Effect::params`]), from `first` (each as long as `defs`).
    ///
    /// In a later round a fit of one of [`WARM_EFFECTS`] starts alone from where the same
    /// fit (the effect in the same shape) ended in the round before: beside one more effect
    /// the optimum moves little, and each of the grid's starts costs a whole solve. A
    /// compliance's screw spring fitted jointly with two found effects and the ratios (ten
    /// parameters, 6–8 plant sub-steps per period) replayed the record 488 times from three
    /// starts (the fresh seed 6969 case_073_skew at 60 s, 3.4 s of a 10 s diagnosis). A
    /// warm start whose replays all ran away falls back to `first`.
    pub fn fit_lm_defs(
        &self,
        effect: Effect,
        defs: &[crate::diagnose::effects::ParamDef],
        first: Vec<Vec<f64>>,
        ev: Evidence,
        make: &(dyn Fn(&[f64]) -> Applied + Sync),
        patience: usize,
    ) -> Result<Option<Fitted>, DiagnoseError> {
        let key = first.first().map(|s| {
            format!(
                "{}/{effect:?}/{:?}",
                self.job,
                std::mem::discriminant(&make(s))
            )
        });
        let last = key
            .as_ref()
            .filter(|_| {
                self.eng.warm_starts && !self.selected.is_empty() && WARM_EFFECTS.contains(&effect)
            })
            .and_then(|k| {
                self.eng
                    .last_theta
                    .lock()
                    .ok()
                    .and_then(|m| m.get(k).cloned())
            })
            .filter(|t| t.len() == defs.len());
        let warm = match last {
            Some(t) => self.fit_lm_from(effect, defs, vec![t], ev.clone(), make, patience)?,
            None => None,
        };
        let fitted = match warm {
            Some(f) => Some(f),
            None => self.fit_lm_from(effect, defs, first, ev, make, patience)?,
        };
        if let (Some(k), Some(f), Ok(mut m)) = (key, &fitted, self.eng.last_theta.lock()) {
            m.insert(k, f.theta.clone());
        }
        Ok(fitted)
    }

    /// [`Context::fit_lm_defs`] from `first`, as given.
    fn fit_lm_from(
        &self,
        effect: Effect,
        defs: &[crate::diagnose::effects::ParamDef],
        first: Vec<Vec<f64>>,
        ev: Evidence,
        make: &(dyn Fn(&[f64]) -> Applied + Sync),
        patience: usize,
    ) -> Result<Option<Fitted>, DiagnoseError> {
        let n_e = defs.len();
        let mut params: Vec<Param> = defs
            .iter()
            .map(|d| Param {
                lo: d.lo,
                hi: d.hi,
                scale: d.init.abs().max(1e-9),
            })
            .collect();
        // A payload on a spring bends the calibration: the mass, kp and kv ratios fitted
        // without it took up its lag (seed 808 case_042: kp ×1.05, kv ×0.95, a 3 µm
        // following-error residual that the compliance alone, even from its true
        // parameters, could not touch). Its ratios are always fitted again with it.
        // A command delay whose signature was read beside the first effect is fitted on
        // that effect as found (see `special::delay`): fitted jointly with it and the
        // ratios, it traded with the loop's gains (6666 case_068: the ratios left their
        // bounds, the delay went to 1.05 ms of the true 0.72, and the held-out force got
        // 20 % worse, where on the base it took 0.49 ms, 91 % of the held-out position
        // residual and 8 % of the force).
        let joint = (ev.pass && !ev.figures.contains_key(special::LAG_BESIDE_KEY))
            || effect == Effect::Compliance;
        let ratios0: Vec<f64> = self.ratios.to_vec();
        // A ratio that is one quantity with this effect or a selected one stays put (see
        // [`owns`]).
        let owned = |p: super::calibrate::CalParam| {
            owns(effect, p)
                || self
                    .selected
                    .iter()
                    .filter_map(Selected::refit_params)
                    .any(|(e, _)| owns(e, p))
        };
        let free: Vec<usize> = (0..ratios0.len())
            .filter(|&i| joint && !owned(self.cal.ratios[i].0))
            .collect();
        params.extend(free.iter().map(|&i| self.cal.ratios[i].0.bounds()));
        // The earlier effects move with the candidate when its signature is there.
        let sel0 = if joint { self.selected_theta() } else { vec![] };
        if joint {
            params.extend(self.selected_params());
        }
        let n_r = free.len();
        let ratios_of = |th: &[f64]| -> Vec<f64> {
            let mut r = ratios0.clone();
            for (j, &i) in free.iter().enumerate() {
                r[i] = th[n_e + j];
            }
            r
        };
        let build = |th: &[f64]| -> Cand {
            let mut c = if joint {
                self.rebuilt(&ratios_of(th), &th[n_e + n_r..])
            } else {
                self.base.clone()
            };
            make(&th[..n_e]).apply(&mut c);
            c
        };
        let slow = self.growth_in_fit(effect, joint);
        let rows = |th: &[f64]| {
            let c = build(th);
            if self.outside_springs(&c) {
                return Ok(None);
            }
            Ok(Some(self.eng.lm_rows(&self.eng.sim_fit_as(&c, slow)?)))
        };
        let all_starts = first.into_iter().map(|mut s| {
            s.extend(free.iter().map(|&i| ratios0[i]));
            s.extend(sel0.iter().copied());
            s
        });
        let Some((f, std)) =
            self.best_lm_strided(all_starts, &params, &rows, patience, self.eng.n_lm(slow))?
        else {
            return Ok(None);
        };
        let cand = build(&f.theta);
        let eval = self.eng.evaluate(&cand)?;
        let ratios = ratios_of(&f.theta);
        // Beside a found effect, the joint fit re-fits that effect and the ratios too, and
        // whatever that alone gains would be credited to the candidate.
        let without = if joint && !self.selected.is_empty() {
            let c = self.rebuilt(&ratios, &f.theta[n_e + n_r..]);
            let e = self.eng.evaluate(&c)?;
            Some((c, e))
        } else {
            None
        };
        let mut extra = BTreeMap::new();
        if joint {
            for ((p, _), r) in self.cal.ratios.iter().zip(&ratios) {
                extra.insert(format!("calibration_{}_ratio", p.name()), *r);
            }
        }
        Ok(Some(Fitted {
            effect,
            keys: defs.iter().map(|d| d.key.to_owned()).collect(),
            applied: make(&f.theta[..n_e]),
            theta: f.theta[..n_e].to_vec(),
            std: std[..n_e].to_vec(),
            cand,
            eval,
            n_params: defs.len(),
            extra,
            note: String::new(),
            evidence: ev,
            refit: true,
            sel_theta: if joint {
                f.theta[n_e + n_r..].to_vec()
            } else {
                vec![]
            },
            ratios,
            without,
        }))
    }

    /// Whether a fit of `effect` (`joint`: refitting the selected effects beside it) has a
    /// screw's growth in it, which needs the whole fitting part (see
    /// `engine::MAX_LM_SAMPLES_SLOW`).
    fn growth_in_fit(&self, effect: Effect, joint: bool) -> bool {
        effect == Effect::ThermalGrowth
            || (joint
                && self
                    .selected
                    .iter()
                    .filter_map(Selected::refit_params)
                    .any(|(e, _)| e == Effect::ThermalGrowth))
    }

    /// The lowest-cost Levenberg–Marquardt fit over `starts`, with one standard deviation of
    /// each parameter (rows correlated over the record's correlation length).
    pub fn best_lm(
        &self,
        starts: impl IntoIterator<Item = Vec<f64>>,
        params: &[Param],
        rows: &lm::Rows<'_>,
    ) -> Result<Option<(lm::LmFit, Vec<f64>)>, DiagnoseError> {
        self.best_lm_within(starts, params, rows, LM_PATIENCE)
    }

    /// [`Context::best_lm`] with the solver's `patience` (its evaluations per parameter).
    pub fn best_lm_within(
        &self,
        starts: impl IntoIterator<Item = Vec<f64>>,
        params: &[Param],
        rows: &lm::Rows<'_>,
        patience: usize,
    ) -> Result<Option<(lm::LmFit, Vec<f64>)>, DiagnoseError> {
        self.best_lm_strided(starts, params, rows, patience, self.eng.n_lm(false))
    }

    /// [`Context::best_lm_within`] for rows from replays of `n_lm` samples (their stride
    /// sets how many rows one correlation length holds).
    fn best_lm_strided(
        &self,
        starts: impl IntoIterator<Item = Vec<f64>>,
        params: &[Param],
        rows: &lm::Rows<'_>,
        patience: usize,
        n_lm: usize,
    ) -> Result<Option<(lm::LmFit, Vec<f64>)>, DiagnoseError> {
        let mut best: Option<lm::LmFit> = None;
        for start in starts {
            // The first round's fits with whole Jacobians only (see `lm::SECANT_UPDATES`).
            let f = if self.selected.is_empty() {
                lm::fit(&start, params, rows, 0.03, patience)?
            } else {
                lm::fit_secant(&start, params, rows, 0.03, patience)?
            };
            if best.as_ref().is_none_or(|b| f.cost < b.cost) {
                best = Some(f);
            }
        }
        Ok(best.map(|f| {
            let std = lm::std_devs(
                &f,
                1.0 / (self.sig.corr_len / Engine::stride_of(n_lm) as f64).max(1.0),
            );
            (f, std)
        }))
    }

    /// Evidence and fit of one effect; None when it cannot be fitted on this record.
    pub fn fit(&self, effect: Effect) -> Result<Option<Fitted>, DiagnoseError> {
        if effect == Effect::ExternalDisturbance {
            // Its detector shapes the fit too: run once, not once for the evidence and
            // again for the fit (two spectra of each residual per round).
            return disturbance::fit(self);
        }
        if matches!(effect, Effect::Backlash | Effect::BacklashAsymmetry)
            && matches!(
                self.base.model.axis.drive.coupling,
                Coupling::Payload { .. }
            )
        {
            // The plant has no play beside a payload on a spring (see `Coupling::Payload`).
            return Ok(None);
        }
        let ev = self.evidence(effect);
        match effect {
            Effect::Quantization | Effect::LeadError | Effect::BeamSag => {
                special::fit(self, effect, ev)
            }
            Effect::StrokeFriction => {
                let film = friction::fit_film(self, &ev)?;
                let count = self.fit_lm(effect, ev)?;
                Ok(self.richer_if_better(count, film, FILM_OVER_COUNT))
            }
            Effect::Compliance => self.fit_compliance(ev),
            Effect::ViscousFriction => {
                let split = friction::fit_split(self, &ev)?;
                let power = friction::fit_power(self, &ev)?;
                let one = self.fit_lm(effect, ev)?;
                let linear = self.richer_if_better(one, split, SPLIT_OVER_ONE);
                Ok(self.richer_if_better(linear, power, POWER_OVER_LINEAR))
            }
            Effect::StribeckFriction => {
                let exponential = friction::fit_stribeck_exponential(self, &ev)?;
                let gaussian = self.fit_lm(effect, ev)?;
                Ok(self.richer_if_better(gaussian, exponential, EXPONENTIAL_OVER_GAUSSIAN))
            }
            Effect::CoulombFriction => {
                let ev = self.nested_coulomb(ev);
                let smooth = friction::fit_coulomb_smooth(self, &ev)?;
                let exact = self.fit_lm(effect, ev)?;
                Ok(self.richer_if_better(exact, smooth, SMOOTH_OVER_EXACT))
            }
            Effect::CommandDelay => {
                let pure = self.fit_lm(effect, ev.clone())?;
                let lag = special::fit_delay_lag(self, &ev, pure.as_ref())?;
                Ok(self.richer_if_better(pure, lag, LAG_OVER_PURE))
            }
            _ => self.fit_lm(effect, ev),
        }
    }

    /// A stroke friction is a Coulomb friction that rises over short strokes (the two are
    /// nested): selected first, with a long recovery, it holds a Coulomb level of the record
    /// as a film that never heals, and the residual it leaves has no direction-of-motion
    /// term for a Coulomb friction's own test to find. Beside it, a Coulomb friction whose
    /// signature the first round found (on the calibrated residual, before the stroke
    /// friction took it) keeps that signature, so that it is fitted jointly with the
    /// stroke friction, which can give the level back. It counts only by what it adds to
    /// that re-fitted stroke friction (see `Fitted::without`). Seen on the fresh seed 6464
    /// case_066 (a Coulomb friction of 30 N and a stroke friction; the film law fitted a
    /// recovery of 190 mm and the Coulomb friction beside it 0.1 N; now 28.5 N, held-out
    /// position 4.1 → 0.5 µm). 6565 case_066 stays a miss: fitted jointly from there, the
    /// Coulomb friction stops at 3.8 N of 19 N.
    /// Such a Coulomb friction counts only by [`nested_coulomb_takes_fit`].
    fn nested_coulomb(&self, ev: Evidence) -> Evidence {
        let beside_stroke = self.selected.iter().any(|s| {
            s.refit_params()
                .is_some_and(|(e, _)| e == Effect::StrokeFriction)
        });
        match self.coulomb_first {
            Some(first) if !ev.pass && first.pass && beside_stroke => Evidence {
                text: format!(
                    "{} (read on the calibrated residual, before the stroke friction, which holds a Coulomb level, took it)",
                    first.text
                ),
                ..first.clone()
            }
            .with(FIRST_ROUND_KEY, 1.0),
            _ => ev,
        }
    }

    /// Of two fits of one effect, the one with more parameters (`richer`) when it leaves
    /// less than `ratio` of what `plain` leaves of the fitting part, else `plain`; either
    /// when the other could not be fitted.
    fn richer_if_better(
        &self,
        plain: Option<Fitted>,
        richer: Option<Fitted>,
        ratio: f64,
    ) -> Option<Fitted> {
        let fit_j = |f: &Fitted| self.eng.j(&f.eval.fit_pos, f.eval.fit_force.as_deref());
        match (plain, richer) {
            (Some(p), Some(r)) if fit_j(&r) < ratio * fit_j(&p) => Some(r),
            (None, r) => r,
            (p, _) => p,
        }
    }
}

impl Context<'_, '_> {
    /// A compliance fitted both ways a spring can sit in a feed axis, keeping the one that
    /// leaves less of the fitting part: a payload on a mount on the table (neither rubbed
    /// nor measured; then also as a hardening mount) and the screw's spring between motor
    /// and table (the table rubbed and measured beyond it). With play in the drive only the
    /// screw's: the plant has no play beside a payload.
    fn fit_compliance(&self, ev: Evidence) -> Result<Option<Fitted>, DiagnoseError> {
        let screw = self.fit_screw_spring(ev.clone())?;
        if !self.payload_possible() {
            return Ok(screw);
        }
        let payload = self.fit_payload(ev)?;
        Ok(self.better_spring(payload, screw))
    }

    /// Whether a compliance may be a payload on a mount (not beside play, see
    /// [`Context::fit_compliance`]).
    fn payload_possible(&self) -> bool {
        !self.base.model.axis.lost_motion.enabled
    }

    /// The compliance as the screw's spring.
    fn fit_screw_spring(&self, ev: Evidence) -> Result<Option<Fitted>, DiagnoseError> {
        self.fit_lm_as(
            Effect::Compliance,
            ev,
            &|th| Applied::Screw(th.to_vec()),
            LM_PATIENCE,
        )
    }

    /// The compliance as a payload on a mount, linear or (with a signature) hardening.
    fn fit_payload(&self, ev: Evidence) -> Result<Option<Fitted>, DiagnoseError> {
        let fit_j = |f: &Fitted| self.eng.j(&f.eval.fit_pos, f.eval.fit_force.as_deref());
        let payload = self.fit_lm_as(
            Effect::Compliance,
            ev,
            &|th| Applied::Params(Effect::Compliance, th.to_vec()),
            PAYLOAD_PATIENCE,
        )?;
        let hard = match &payload {
            Some(l) if l.evidence.pass => special::fit_hardening(self, l)?,
            _ => None,
        };
        Ok(match (payload, hard) {
            (Some(l), Some(h)) if fit_j(&h) < HARDENING_OVER_LINEAR * fit_j(&l) => Some(h),
            (l, _) => l,
        })
    }

    /// Of a payload's and the screw's spring, the one that leaves less of the fitting part.
    fn better_spring(&self, payload: Option<Fitted>, screw: Option<Fitted>) -> Option<Fitted> {
        let fit_j = |f: &Fitted| self.eng.j(&f.eval.fit_pos, f.eval.fit_force.as_deref());
        match (payload, screw) {
            (Some(p), Some(s)) if fit_j(&s) < fit_j(&p) => Some(Fitted {
                note: "the screw's spring between motor and table (it explained more of the fitting part than a payload on a mount)".into(),
                ..s
            }),
            (None, s) => s,
            (p, _) => p,
        }
    }
}

/// Largest damping ratio a fitted spring may have. A screw's or a mount's spring rings
/// (feed drives measure 0.01–0.2; the independent generator draws 0.03–0.2): an overdamped
/// one is a dashpot in series that the fit uses to stand in for something else (a play's
/// impacts, a lag), and resolving its damper explicitly took up to 94 plant sub-steps per
/// period (the fresh seed 6666 case_069_skew at 60 s: one start of the screw's spring went
/// to ζ 6.6 and took 3.6 s, a third of the diagnosis). The fit treats such a spring as
/// outside the model, as it treats a replay that diverges.
const MAX_SPRING_DAMPING_RATIO: f64 = 1.0;

/// Highest resonance a fitted spring may have, as a share of the record's Nyquist
/// frequency. A compliance's signature is its resonance, and a mode above the Nyquist
/// frequency cannot ring in the record: a spring that stiff stands in for something else
/// (a play's contact, a lag), as an overdamped one does, and resolving it took 15–21 plant
/// sub-steps per period (the fresh seed 6969 case_073_skew at 60 s, a Coulomb friction and
/// a cable carrier's force: a screw's spring on a twentieth of the mass climbed to 150 N/µm,
/// 900 Hz, over 780 replays, 6 s of the diagnosis). The independent generator's payloads
/// ring at 30–300 Hz, below the 500 Hz of a 1 kHz record.
const MAX_SPRING_RESONANCE_OVER_NYQUIST: f64 = 1.0;

/// Whether the candidate's coupling is damped beyond [`MAX_SPRING_DAMPING_RATIO`] or rings
/// above [`MAX_SPRING_RESONANCE_OVER_NYQUIST`].
pub fn outside_spring(c: &Cand) -> bool {
    let a = &c.model.axis;
    let nyquist_rad_per_s = std::f64::consts::PI / c.model.t3_s;
    a.coupling_damping_ratio()
        .is_some_and(|z| z > MAX_SPRING_DAMPING_RATIO)
        || a.coupling_resonance_rad_per_s()
            .is_some_and(|w| w > MAX_SPRING_RESONANCE_OVER_NYQUIST * nyquist_rad_per_s)
}

impl Context<'_, '_> {
    /// Whether a fit's candidate `c` has a spring outside the fits' range
    /// ([`outside_spring`]) that the round's base has not (a nominal drive modelled so keeps
    /// it).
    pub fn outside_springs(&self, c: &Cand) -> bool {
        outside_spring(c) && !outside_spring(self.base)
    }
}

/// The effects whose fits in a later round start where the round before left them (see
/// [`Context::fit_lm_defs`]). Measured at stop 61 on the 304 records of seeds 6969 and 7070
/// against the grid: with these, one more skewed mixture with both effects, no single
/// moved, and the sum of the per-record times 42–53 % lower. A Stribeck friction started
/// so was lost beside a Coulomb friction (6969 case_065, both ways); a screw's growth, a
/// lead error and a play with a bias force lost three mixtures of 7070 (case_065, case_073,
/// case_074), where the round before had fitted them to what the first effect left. A
/// command delay's start in a later round is the lag read beside the first effect (see
/// `special::delay`).
const WARM_EFFECTS: [Effect; 4] = [
    Effect::Compliance,
    Effect::CoulombFriction,
    Effect::StrokeFriction,
    Effect::ViscousFriction,
];

/// The Levenberg–Marquardt solver's patience in the candidate fits (evaluations per
/// parameter).
const LM_PATIENCE: usize = 6;

/// The payload's fit, fitted beside the screw's spring on every record (see
/// [`Context::fit_compliance`]), gets half the patience: a light payload on a stiff,
/// heavily damped mount needs several plant sub-steps per period, and the full patience
/// made the diagnosis of a 60 s record 1 s longer.
const PAYLOAD_PATIENCE: usize = 3;

/// A hardening payload mount ([`special::fit_hardening`]) replaces the linear one when it
/// leaves at most this share of what the linear mount leaves of the fitting part: one more
/// parameter must earn its place (as [`FILM_OVER_COUNT`] for the film law).
const HARDENING_OVER_LINEAR: f64 = 0.9;

/// `base` with `effect` at parameters `theta`.
pub fn with_effect(base: &Cand, e: Effect, theta: &[f64]) -> Cand {
    let mut c = base.clone();
    e.apply(theta, &mut c.model);
    c
}

/// Starting points: the evidence's hint first, then a small grid over the parameters the
/// residual depends on nonlinearly.
fn starts(effect: Effect, hint: &[f64]) -> Vec<Vec<f64>> {
    let defs = effect.params();
    let init: Vec<f64> = defs.iter().map(|d| d.init).collect();
    let clamp = |v: Vec<f64>| -> Vec<f64> {
        v.iter()
            .zip(defs)
            .map(|(x, d)| x.clamp(d.lo, d.hi))
            .collect()
    };
    let mut out = Vec::new();
    if hint.len() == defs.len() {
        out.push(clamp(hint.to_vec()));
    }
    let vary = |i: usize, vals: &[f64]| -> Vec<Vec<f64>> {
        vals.iter()
            .map(|&v| {
                let mut s = init.clone();
                s[i] = v;
                s
            })
            .collect()
    };
    let grid = match effect {
        Effect::StribeckFriction => vary(1, &[0.5, 2.0, 8.0]),
        Effect::StrokeFriction => vary(1, &[5.0, 20.0]),
        // Damped well (about 0.1–0.2 of critical on a 100 kg axis). These starts once kept
        // the replay from ringing up (the two-mass step fed a light spring energy, fixed in
        // the plant since); starting lighter, from the evidence's own damping ratio, changed
        // no verdict over the compliance cases of eight independent seeds.
        Effect::Compliance => vec![
            vec![2.0, 1500.0, 0.3],
            vec![10.0, 4000.0, 0.3],
            vec![50.0, 10000.0, 0.3],
        ],
        Effect::ThermalGrowth => vary(1, &[60.0, 600.0]),
        Effect::Backlash => vary(0, &[3.0, 10.0, 30.0]),
        Effect::BacklashAsymmetry => vec![vec![5.0, -30.0], vec![5.0, 30.0], vec![20.0, 30.0]],
        _ => vec![init],
    };
    // With a hint, one more start is enough; without, the whole grid.
    if out.is_empty() {
        grid.into_iter().map(clamp).collect()
    } else {
        out.extend(grid.into_iter().take(1).map(clamp));
        out
    }
}

/// The ranking of candidates on one base.
pub struct Round {
    /// Each fitted candidate with its scores, best first.
    pub ranked: Vec<(Fitted, Scores)>,
}

/// Fits every effect of `effects` on `ctx.base`, two at a time (two cores), and ranks them:
/// significant ones first (both signature and shrink), then by score.
pub fn fit_all(ctx: &Context, effects: &[Effect]) -> Result<Round, DiagnoseError> {
    let next = AtomicUsize::new(0);
    let order = job_order(ctx, effects);
    let label = |i: usize, job: SpringJob| job_label(effects[i], job);
    let secs: Mutex<std::collections::BTreeMap<String, f64>> = Mutex::new(Default::default());
    let results: Mutex<Vec<(usize, SpringJob, Fitted)>> = Mutex::new(Vec::new());
    let first_err: Mutex<Option<DiagnoseError>> = Mutex::new(None);
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| {
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&(i, job)) = order.get(k) else {
                        break;
                    };
                    let e = effects[i];
                    let t0 = std::time::Instant::now();
                    let job_key = label(i, job);
                    let ctx = &Context {
                        job: &job_key,
                        ..*ctx
                    };
                    let fitted = match job {
                        SpringJob::Whole => ctx.fit(e),
                        SpringJob::Payload => ctx.fit_payload(ctx.evidence(e)),
                        SpringJob::Screw => ctx.fit_screw_spring(ctx.evidence(e)),
                    };
                    let took_s = t0.elapsed().as_secs_f64();
                    if let Ok(mut m) = secs.lock() {
                        m.insert(label(i, job), took_s);
                    }
                    // Development aid: each fit's wall time (`AXB_TIME=1`).
                    if std::env::var_os("AXB_TIME").is_some() {
                        eprintln!("TIME {e:?} {job:?} {took_s:.3}");
                    }
                    match fitted {
                        Ok(Some(f)) => {
                            if let Ok(mut r) = results.lock() {
                                r.push((i, job, f));
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
    if let (Ok(mut m), Ok(took)) = (ctx.eng.job_secs.lock(), secs.into_inner()) {
        m.extend(took);
    }
    let mut r = merge_springs(ctx, results.into_inner().unwrap_or_default());
    r.sort_by_key(|x| x.0);
    // A candidate whose replay ran away (a spring the solver drove unstable) has no
    // residual to rank by: it is left out, not ranked by a NaN.
    let polished = best_without(ctx.eng, ctx.base_eval, r.iter().map(|(_, f)| f))
        .and_then(|f| f.without.as_ref())
        .map(|(_, e)| e.clone());
    let mut ranked: Vec<(Fitted, Scores)> = r
        .into_iter()
        .map(|(_, f)| {
            let s = score(ctx, &f, polished.as_ref());
            (f, s)
        })
        .filter(|(_, s)| s.score.is_finite() && s.shrink.is_finite())
        .collect();
    note_stroke_by_fit(&mut ranked);
    if ctx.selected.is_empty() {
        stroke_far_ahead(&mut ranked);
        lasting_steps(&mut ranked);
    }
    play_beyond_constant(&mut ranked);
    bursts_a_state_explains(&mut ranked);
    stroke_beyond_coulomb(&mut ranked);
    stroke_or_coulomb_by_fit(&mut ranked);
    nested_coulomb_takes_fit(&mut ranked);
    lead_or_growth_by_position(&mut ranked);
    compliance_unseen_in_holdout(ctx, &mut ranked);
    if ctx.selected.is_empty() {
        stiff_mount_in_position(ctx, &mut ranked);
    }
    ranked.sort_by(|a, b| {
        b.1.significant
            .cmp(&a.1.significant)
            .then(b.1.score.total_cmp(&a.1.score))
    });
    Ok(Round { ranked })
}

/// Of `fits`, the one whose joint fit with its effect taken out again (see
/// [`Fitted::without`]) leaves the least of the fitting part, when that is less than
/// `base_eval` leaves and the held-out part does not grow (a model that predicts the
/// held-out part worse would make every candidate judged against it look better: 1717
/// case_066, a 2 % slack let a screw growth pass beside a stroke friction). Beside a found effect every joint fit re-fits it and the ratios, and one
/// of them may find them a better fit than the base's: 808 case_038 (a constant force) took
/// 60 % more of the held-out force residual that way, beside a viscous candidate whose own
/// term took 1 %. The round's candidates are judged against that model, not the base.
pub fn best_without<'f>(
    eng: &Engine,
    base_eval: &Eval,
    fits: impl IntoIterator<Item = &'f Fitted>,
) -> Option<&'f Fitted> {
    let fit = |e: &Eval| eng.j(&e.fit_pos, e.fit_force.as_deref());
    let hold = |e: &Eval| eng.j(&e.hold_pos, e.hold_force.as_deref());
    let (fit_b, hold_b) = (fit(base_eval), hold(base_eval));
    fits.into_iter()
        .filter_map(|f| f.without.as_ref().map(|(_, e)| (f, fit(e), hold(e))))
        .filter(|(_, j, h)| *j < fit_b && *h <= hold_b)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(f, _, _)| f)
}

/// The jobs of [`fit_all`] in the order they start: one per effect, a compliance that may be
/// a payload two (payload, screw: the two slowest fits, run side by side), each as (index in
/// `effects`, job).
///
/// Longest first, so that neither thread is left with one at the end: by each job's wall
/// time in the last round where it ran (the cost of a fit follows the effects already found,
/// whose parameters it fits again beside its own), else by its rough weight. A long fit
/// started last was a round's critical path (independent seed 5959 case_022, 24 s: a command
/// delay's two fits, 1.4 s, started when the other core was nearly done; started first, the
/// diagnosis took 4.4–4.7 s instead of 5.1–5.5 s). The order changes no result: each fit is
/// the same on any thread, and [`fit_all`] puts the results back in the given order.
fn job_order(ctx: &Context, effects: &[Effect]) -> Vec<(usize, SpringJob)> {
    let mut order: Vec<(usize, SpringJob)> = Vec::new();
    for (i, e) in effects.iter().enumerate() {
        if *e == Effect::Compliance && ctx.payload_possible() {
            order.push((i, SpringJob::Payload));
            order.push((i, SpringJob::Screw));
        } else {
            order.push((i, SpringJob::Whole));
        }
    }
    let last_secs = ctx
        .eng
        .job_secs
        .lock()
        .map(|m| m.clone())
        .unwrap_or_default();
    let longest = last_secs.values().copied().fold(0.0, f64::max);
    let cost = |i: usize, job: SpringJob| {
        if last_secs.is_empty() {
            f64::from(fit_weight(effects[i]))
        } else {
            last_secs
                .get(&job_label(effects[i], job))
                .copied()
                .unwrap_or(longest)
        }
    };
    order.sort_by(|&(a, ja), &(b, jb)| cost(b, jb).total_cmp(&cost(a, ja)));
    order
}

/// A job's key in `Engine::job_secs`.
fn job_label(e: Effect, job: SpringJob) -> String {
    format!("{e:?}/{job:?}")
}

/// A job of [`fit_all`]: an effect's whole fit, or one of a compliance's two springs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SpringJob {
    Whole,
    Payload,
    Screw,
}

/// The fits of [`fit_all`], a compliance's two springs merged into the better one
/// ([`Context::better_spring`]).
fn merge_springs(ctx: &Context, r: Vec<(usize, SpringJob, Fitted)>) -> Vec<(usize, Fitted)> {
    let mut out = Vec::with_capacity(r.len());
    let mut payload: Option<(usize, Fitted)> = None;
    let mut screw: Option<(usize, Fitted)> = None;
    for (i, job, f) in r {
        match job {
            SpringJob::Whole => out.push((i, f)),
            SpringJob::Payload => payload = Some((i, f)),
            SpringJob::Screw => screw = Some((i, f)),
        }
    }
    let i = payload.as_ref().or(screw.as_ref()).map(|(i, _)| *i);
    if let (Some(i), Some(f)) = (
        i,
        ctx.better_spring(payload.map(|p| p.1), screw.map(|s| s.1)),
    ) {
        out.push((i, f));
    }
    out
}

/// Rough cost of fitting `e`: the scheduling order of [`fit_all`]'s first round (longest
/// first; later rounds go by the last round's wall times). From each fit's wall time
/// (`AXB_TIME=1`) on the 60 s record of `bench --diagnose 60000`: a play's fits (three
/// starts, a switching replay) and a compliance's are the slowest, and a delay's (two fits,
/// a pure delay and a lag, each beside the calibration's ratios when its signature is
/// there) took 1.4 s on independent seed 5959 case_022 and is often short: it starts first.
fn fit_weight(e: Effect) -> u32 {
    match e {
        Effect::CommandDelay => 5,
        Effect::Compliance | Effect::BacklashAsymmetry => 4,
        Effect::Backlash | Effect::StrokeFriction => 3,
        Effect::ThermalGrowth | Effect::StribeckFriction => 2,
        _ => 1,
    }
}

/// A stroke friction whose signature fails (its regression spans a count or a distance law
/// at a few pitches; the film of a record may follow neither closely) still counts when its
/// replay predicts the held-out part this many times better than the best effect found, or
/// when nothing is found, at [`LARGE_SCORE`] or more. On the calibrated model alone. Set on
/// the independent seeds 1–909 and 1010–1313 (Coulomb, stroke, clean and compliance records,
/// unskewed and skewed): on Coulomb records the stroke friction reached 1.22× the Coulomb
/// friction's score; clean and compliance records left it below 0.07; five stroke records
/// (seeds 808, 1111, 1313) reached 1.9× or more, or stood alone at 0.46–0.68.
const STROKE_OVER_BEST: f64 = 1.5;

/// A stroke friction with nothing else found counts at this held-out score (below
/// [`LARGE_SCORE`]: its law's four parameters pay the penalty) when it takes at least `.1`
/// of the held-out force residual: a film that follows neither law of the signature's
/// regression, which the direction column then takes too, leaves its force behind. Set in
/// stop 39 on the traces of the independent seeds 2323–3434 and 3838–4242 before seeds 4343
/// and 4444 were generated: three stroke records named `none` scored 0.22–0.28 with
/// 0.33–0.76 of the force; of the other records named `none`, a Stribeck friction's stroke
/// candidate scored 0.17 with 0.21–0.23 of the force, and no clean record's passed 0.07.
const STROKE_ALONE: (f64, f64) = (0.2, 0.3);

/// Marks the stroke friction of a round significant by [`STROKE_OVER_BEST`] or
/// [`STROKE_ALONE`].
fn stroke_far_ahead(ranked: &mut [(Fitted, Scores)]) {
    let best = ranked
        .iter()
        .filter(|(_, s)| s.significant)
        .map(|(_, s)| s.score)
        .fold(0.0_f64, f64::max);
    let alone = |s: &Scores| {
        best <= 0.0
            && s.score >= STROKE_ALONE.0
            && s.shrink_force.is_some_and(|x| x >= STROKE_ALONE.1)
    };
    for (f, s) in ranked.iter_mut() {
        if f.effect != Effect::StrokeFriction || s.significant {
            continue;
        }
        if s.score >= LARGE_SCORE && s.score >= STROKE_OVER_BEST * best {
            s.significant = true;
            f.note = format!(
                "counted by its held-out score, {:.0} % against {:.0} % for the best effect the signatures found",
                100.0 * s.score,
                100.0 * best
            );
        } else if alone(s) {
            let note = format!(
                "counted by its held-out score, {:.0} %, and the {:.0} % of the held-out force residual it takes, with no other effect found",
                100.0 * s.score,
                100.0 * s.shrink_force.unwrap_or(0.0)
            );
            count_with_note(f, s, note);
        }
    }
}

/// Level steps of force that take this share of the fitting residual away count on that
/// alone, like bursts (see [`BURSTS_FIT_SHRINK`]), even when the held-out end is made worse:
/// a later step is as unpredictable as a burst, and the model holds the last level. Set on
/// the independent seeds 808–1111: stepped disturbances took 74–91 %, and the step search on
/// every other record at most 63 % (62 % before the first effect was added).
const STEPS_FIT_SHRINK: f64 = 0.7;

/// Least share of the fitting residual level steps must take away to count at all. Steps
/// predict the held-out part through their last level alone, so steps that explain little
/// of the fitting part and much of the held-out part have found a level offset there, not
/// the changes of a force. Over the independent seeds 2323–3434: stepped disturbances took
/// 34–92 % of the fitting residual; steps named beside a constant force, a play or a
/// stroke friction took 2–14 % and 20–24 % of the held-out residual (3232 case_033, 3333
/// case_037 and case_039).
const STEPS_MIN_FIT_SHRINK: f64 = 0.2;

/// [`STEPS_FIT_SHRINK`]'s rule, before the first effect is added.
fn lasting_steps(ranked: &mut [(Fitted, Scores)]) {
    for (f, s) in ranked.iter_mut() {
        if f.effect == Effect::ExternalDisturbance
            && !s.significant
            && f.evidence.pass
            && f.evidence.figures.contains_key("steps")
            && s.fit_shrink >= STEPS_FIT_SHRINK
        {
            count_by_fitting_part(
                f,
                s,
                format!(
                    "counted by the fitting part: the steps take {:.0} % of its residual away",
                    100.0 * s.fit_shrink
                ),
            );
            if s.shrink < 0.0 {
                f.note += &format!(
                    "; the held-out end holds changes no model predicts ({:.0} % worse)",
                    -100.0 * s.shrink
                );
            }
        }
    }
}

/// Bursts count by the fitting part because nothing predicts when they come (see
/// `score`). When an effect that follows the axis's state, found by its own signature,
/// explains more of the fitting part than the bursts do, the bursts are that effect's
/// force seen at the moments it is largest: a Stribeck friction's excess at each reversal
/// reads as a burst there. They then count only by the held-out part, like any other
/// candidate. Over the independent seeds 2323–3434: bursts of true bursty disturbances
/// took 14–41 % of the fitting residual where the best other candidate took at most 7 %;
/// bursts read off Stribeck frictions took 55–60 %, the Stribeck friction 70–97 % (3232
/// case_016: bursts named first, ahead of the Stribeck friction).
fn bursts_a_state_explains(ranked: &mut [(Fitted, Scores)]) {
    let Some((best_effect, best_fit)) = ranked
        .iter()
        .filter(|(f, _)| f.effect != Effect::ExternalDisturbance && f.evidence.pass)
        .map(|(f, s)| (f.effect, s.fit_shrink))
        .max_by(|a, b| a.1.total_cmp(&b.1))
    else {
        return;
    };
    for (f, s) in ranked.iter_mut() {
        let held = s.shrink - PENALTY_PER_PARAM * f.n_params as f64;
        if f.effect == Effect::ExternalDisturbance
            && f.evidence.figures.contains_key("bursts")
            && s.significant
            && held < MIN_SHRINK
            && best_fit > s.fit_shrink
        {
            s.significant = false;
            s.score = held;
            f.note = format!(
                "not counted by the fitting part: {} explains more of it ({:.0} % against the bursts' {:.0} %)",
                best_effect.name(),
                100.0 * best_fit,
                100.0 * s.fit_shrink
            );
        }
    }
}

/// A compliance found by its signature that takes at least this share of the fitting
/// residual away counts on that, when the held-out part holds none of the acceleration
/// steps that excite it (see [`compliance_unseen_in_holdout`]).
const UNEXCITED_FIT_SHRINK: f64 = 0.5;

/// Acceleration steps of the command in the held-out part, at least the share of the
/// fitting part's largest step that the ringing test counts.
fn holdout_acc_steps(ctx: &Context) -> usize {
    let split = &ctx.eng.split;
    let (cmd, dt) = match split.validate {
        Some(v) => (&v.cmd_m[..], v.t3_s),
        None => (&split.main.cmd_m[split.n_fit..], split.main.t3_s),
    };
    let acc = derivative(&derivative(cmd, 1, dt), 1, dt);
    let biggest = ctx
        .sig
        .cmd_acc_mps2
        .windows(2)
        .fold(0.0_f64, |m, w| m.max((w[1] - w[0]).abs()));
    if biggest.is_nan() || biggest <= 0.0 {
        return 0;
    }
    acc.windows(2)
        .filter(|w| (w[1] - w[0]).abs() >= super::evidence::RINGING_STEP_SHARE * biggest)
        .count()
}

/// A payload on a spring shows only after the command's acceleration steps; a held-out end
/// without any (a record that ends on slow, steady moves) cannot confirm or refute it, and
/// its held-out shrink is the noise of a part where the model changes nothing. Such a
/// compliance, found by its ringing or resonance, counts by the fitting part when it takes
/// [`UNEXCITED_FIT_SHRINK`] of it away and leaves the held-out part no worse than 2 %.
/// Seen on the independent seed 808 case_043 (a 78 Hz mount; the fitting part's 19 steps
/// rang at 10 standard errors, 62 % of its residual explained; the held-out end, 16.8–24 s,
/// holds no step). Clean records whose ringing test passed took at most 33 % of the fitting
/// part over seeds 808–1919.
fn compliance_unseen_in_holdout(ctx: &Context, ranked: &mut [(Fitted, Scores)]) {
    let Some((f, s)) = ranked.iter_mut().find(|(f, s)| {
        f.effect == Effect::Compliance
            && !s.significant
            && f.evidence.pass
            && s.fit_shrink >= UNEXCITED_FIT_SHRINK
            && s.shrink >= -0.02
    }) else {
        return;
    };
    if holdout_acc_steps(ctx) > 0 {
        return;
    }
    let note = format!(
        "counted by the fitting part ({:.0} % of its residual): the held-out part holds none of the acceleration steps that excite a payload",
        100.0 * s.fit_shrink
    );
    count_by_fitting_part(f, s, note);
}

/// A stiff payload mount (a resonance above ~120 Hz behind jerk-limited moves) leaves no
/// peak and no ringing, and its force is the payload's mass, which the calibration already
/// has; what is left of it is the small lag it adds to the position. A compliance that takes
/// [`STIFF_MOUNT`]`.0` of the held-out position residual away, leaves the force residual no
/// worse than `.1` and shrinks the combined residual by `.2` counts on the calibrated model
/// alone, unless the position channel was found logged off its instant: the skew's removal
/// leaves a position lag of its own that a spring takes as well. Set on stop 37's traces of
/// the independent seeds 2323–3434, 3838 and 3939, before the fresh seeds 4040 and 4141 were
/// generated: 10 of the 13 unskewed compliance singles named otherwise pass (mounts of
/// 124–282 Hz; 9–35 % of the position, −0.1–2.8 % of the force), and 7 skewed ones; one of
/// the 120 unskewed clean records passes (3030 case_005: 21 %, +1.1 %), and the five skewed
/// clean records that would pass all had a position skew. Lowered from 0.09 of the position
/// to 0.06 in stop 39: seed 4242's mounts of 230–235 Hz took 7.7 % and 8.4 %, and no
/// unskewed clean record over thirteen seeds that leaves the force no worse took more than
/// 1.5 % apart from 3030 case_005; 4343 and 4444 were generated after the change.
const STIFF_MOUNT: (f64, f64, f64) = (0.06, -0.005, 0.03);

/// Counts a compliance by [`STIFF_MOUNT`] (on the calibrated model alone).
fn stiff_mount_in_position(ctx: &Context, ranked: &mut [(Fitted, Scores)]) {
    if ctx
        .cal
        .skew
        .as_ref()
        .is_some_and(|k| k.channel == super::calibrate::Channel::Pos)
    {
        return;
    }
    let Some((f, s)) = ranked.iter_mut().find(|(f, s)| {
        f.effect == Effect::Compliance
            && !s.significant
            && s.shrink_pos >= STIFF_MOUNT.0
            && s.shrink_force.is_some_and(|x| x >= STIFF_MOUNT.1)
            && s.shrink >= STIFF_MOUNT.2
    }) else {
        return;
    };
    let note = format!(
        "counted by the position ({:.0} % of its held-out residual, the force's {:+.1} %): a stiff mount the moves hardly excite",
        100.0 * s.shrink_pos,
        100.0 * s.shrink_force.unwrap_or(0.0)
    );
    count_with_note(f, s, note);
}

/// Marks `f` found by what it takes away of the fitting part (its held-out part cannot
/// judge it), scored at least by that shrink less the per-parameter penalty.
fn count_by_fitting_part(f: &mut Fitted, s: &mut Scores, note: String) {
    s.significant = true;
    s.score = s
        .score
        .max(s.fit_shrink - PENALTY_WITH_SIGNATURE * f.n_params as f64);
    f.note = note;
}

/// A stroke friction is a Coulomb friction that rises over short strokes: the two are
/// nested, and the rise is what the stroke friction adds. A stroke friction whose
/// signature is weak counts when its replay beats the replay of a Coulomb friction that
/// counts in the same round by at least this much, both on the held-out score and on the
/// share of the fitting part taken, …
const STROKE_OVER_COULOMB: (f64, f64) = (0.05, 0.05);

/// … its regression stands this many standard errors clear of zero, and it takes at least
/// [`MIN_SHRINK`] of the held-out residual after its penalty. Set in stop 49 on the traced
/// singles and clean records of the independent seeds 3838–4747 (and 4848 case_025): no
/// record without a stroke friction had one at ≥ 1.5 standard errors that led the Coulomb
/// friction on both parts by more than 0.02; two stroke frictions the rule adds (4646
/// case_027 skewed, 4.8 and 12 points ahead at 5.2 standard errors, named a command delay;
/// 4848 case_025, 16 and 30 points ahead at 2.5, named a Coulomb friction). The Coulomb
/// friction must count itself: beside a viscous friction (5050 case_022) a Coulomb
/// friction at −0.30 held out made a 0.76 N rise 59 points "ahead".
const STROKE_OVER_COULOMB_T: f64 = 2.0;

/// Marks a stroke friction significant by [`STROKE_OVER_COULOMB`].
fn stroke_beyond_coulomb(ranked: &mut [(Fitted, Scores)]) {
    let find = |e: Effect| ranked.iter().position(|(f, _)| f.effect == e);
    let (Some(st), Some(co)) = (find(Effect::StrokeFriction), find(Effect::CoulombFriction)) else {
        return;
    };
    let (fs, ss) = (&ranked[st].0, &ranked[st].1);
    let sc = &ranked[co].1;
    let fig = |k: &str| fs.evidence.figures.get(k).copied();
    let lead = (ss.score - sc.score, ss.fit_shrink - sc.fit_shrink);
    if ss.significant
        || !sc.significant
        || !fig("rise_n").is_some_and(|c| c > 0.0)
        || !fig("t").is_some_and(|t| t >= STROKE_OVER_COULOMB_T)
        || ss.score < MIN_SHRINK
        || lead.0 < STROKE_OVER_COULOMB.0
        || lead.1 < STROKE_OVER_COULOMB.1
    {
        return;
    }
    let note = format!(
        "counted by its lead over a Coulomb friction, which it holds and adds a rise over short strokes to: {:.0} points on the held-out score and {:.0} on the fitting part",
        100.0 * lead.0,
        100.0 * lead.1
    );
    let (f, s) = &mut ranked[st];
    count_with_note(f, s, note);
}

/// The evidence figure that marks a Coulomb friction's signature as the first round's
/// (see [`Context::nested_coulomb`]).
const FIRST_ROUND_KEY: &str = "read_before_stroke_friction";

/// A Coulomb friction on the first round's signature must take back a level: at least
/// [`MIN_SHRINK`] of the fitting part's residual (against the joint fit without it, the
/// stroke friction re-fitted too), the part that saw the short strokes the two are told
/// apart by. On the fresh seed 6464 case_027 (a stroke friction alone) a 1.4 N Coulomb
/// friction beside the film took 1.4 % of the fitting part and 16 % of the held-out end;
/// on case_066 (both) 28.5 N took 49 %.
fn nested_coulomb_takes_fit(ranked: &mut [(Fitted, Scores)]) {
    for (f, s) in ranked.iter_mut() {
        let nested = f.evidence.figures.contains_key(FIRST_ROUND_KEY);
        if nested && s.significant && s.fit_shrink < MIN_SHRINK {
            s.significant = false;
            add_note(
                f,
                format!(
                    "not counted: beside the stroke friction it takes {:.1} % of the fitting part, under the {:.0} % a Coulomb level given back by it takes",
                    100.0 * s.fit_shrink,
                    100.0 * MIN_SHRINK
                ),
            );
        }
    }
}

/// Coulomb and stroke friction whose held-out scores lie this close …
const FRICTION_TIE: f64 = 0.06;

/// … are ranked by the fitting part instead, when one of them takes at least this much more
/// of its residual away.
const FRICTION_FIT_LEAD: f64 = 0.05;

/// The tie widens with the fitting part's lead: to this share of it. A wide lead on the
/// part that saw the short strokes outweighs a held-out end that may hold few: the stroke
/// frictions of the independent seed 2727 (case_024 and case_026 and their skewed twins)
/// led the fitting part by 0.11–0.32 and trailed Coulomb's held-out score by 0.06–0.14.
/// Over the traced records of seeds 2323–2929 every pair of the two where one led the
/// fitting part by more than 0.05 hid the leader (25 stroke frictions, 2 Coulomb).
const FRICTION_TIE_PER_LEAD: f64 = 0.75;

/// A stroke friction differs from a Coulomb friction only over short strokes, and the
/// held-out end may hold none (a record that ends on long moves): there the two predict
/// alike and a near tie of their held-out scores says nothing, while the fitting part, which
/// saw the short strokes, does. Seen on the independent seeds 808–1919: 1010 case_024 (a
/// stroke friction, 0.573 against Coulomb's 0.604 held-out, 0.480 against 0.245 of the
/// fitting part) and 909 case_013 (a smooth Coulomb friction, 0.375 against 0.400 held-out,
/// 0.571 against 0.457 fitting); every other near tie of the two over those seeds already
/// ranked the one that explained more of the fitting part first, or had them within 0.05.
fn stroke_or_coulomb_by_fit(ranked: &mut [(Fitted, Scores)]) {
    let Some((c, st)) = significant_pair(ranked, Effect::CoulombFriction, Effect::StrokeFriction)
    else {
        return;
    };
    let (sc, ss) = (&ranked[c].1, &ranked[st].1);
    let (win, lose) = if sc.fit_shrink >= ss.fit_shrink {
        (c, st)
    } else {
        (st, c)
    };
    let (fw, fl) = (ranked[win].1.fit_shrink, ranked[lose].1.fit_shrink);
    let (sw, sl) = (ranked[win].1.score, ranked[lose].1.score);
    let tie = FRICTION_TIE.max(FRICTION_TIE_PER_LEAD * (fw - fl));
    if fw - fl < FRICTION_FIT_LEAD || sw > sl || sl - sw >= tie {
        return;
    }
    let other = ranked[lose].0.effect.name();
    let note = format!(
        "ranked above {other} by the fitting part ({:.0} % against {:.0} % of its residual): their held-out scores are within {:.0} % ({:.1} % against {:.1} %)",
        100.0 * fw,
        100.0 * fl,
        100.0 * tie,
        100.0 * sw,
        100.0 * sl
    );
    rank_above(ranked, win, lose, note);
}

/// The places in `ranked` of the significant candidates of the effects `a` and `b`, when
/// both are.
fn significant_pair(ranked: &[(Fitted, Scores)], a: Effect, b: Effect) -> Option<(usize, usize)> {
    let find = |e: Effect| {
        ranked
            .iter()
            .position(|(f, s)| f.effect == e && s.significant)
    };
    Some((find(a)?, find(b)?))
}

/// Ranks `ranked[win]` just above `ranked[lose]`, and says why in its note.
fn rank_above(ranked: &mut [(Fitted, Scores)], win: usize, lose: usize, why: String) {
    ranked[win].1.score = ranked[lose].1.score + 1e-6;
    add_note(&mut ranked[win].0, why);
}

/// Marks `f` found by a rule other than its signature, which `note` names.
fn count_with_note(f: &mut Fitted, s: &mut Scores, note: String) {
    s.significant = true;
    add_note(f, note);
}

/// Adds `note` to what `f`'s note already says.
pub(crate) fn add_note(f: &mut Fitted, note: String) {
    f.note = if f.note.is_empty() {
        note
    } else {
        format!("{}; {note}", f.note)
    };
}

/// A lead error and a screw's growth both move the position alone, and both can take a
/// slope along the travel: a cumulative lead error's is fixed, a growth's rises with the
/// heat. Found together, the one that takes this much more of the held-out position
/// residual ranks first, whatever the combined score (which charges the lead error's
/// harmonics more parameters). Set in stop 39 on the independent seeds 2323–4242: of the
/// growth records where both were found, a lead error took at most 0.02 more of the
/// position (2929 case_047 and 3333 case_047, skewed); seed 4444 case_048, a cumulative lead
/// error of 10.4 µm/m under a 0.09 µm pitch error, was named a growth with 0.67 of the
/// position taken by the lead error against 0.49 by the growth.
const POSITION_LEAD: f64 = 0.1;

/// Ranks a lead error and a screw's growth by [`POSITION_LEAD`].
fn lead_or_growth_by_position(ranked: &mut [(Fitted, Scores)]) {
    let Some((l, g)) = significant_pair(ranked, Effect::LeadError, Effect::ThermalGrowth) else {
        return;
    };
    let (win, lose) = if ranked[l].1.shrink_pos >= ranked[g].1.shrink_pos {
        (l, g)
    } else {
        (g, l)
    };
    let (pw, pl) = (ranked[win].1.shrink_pos, ranked[lose].1.shrink_pos);
    let (sw, sl) = (ranked[win].1.score, ranked[lose].1.score);
    if pw - pl < POSITION_LEAD || sw > sl {
        return;
    }
    let other = ranked[lose].0.effect.name();
    let note = format!(
        "ranked above {other} by the held-out position ({:.0} % against {:.0} % of its residual): both move the position alone",
        100.0 * pw,
        100.0 * pl
    );
    rank_above(ranked, win, lose, note);
}

/// The distance law of the stroke friction replaces the count law when it leaves at most
/// this share of what the count law leaves of the fitting part.
const FILM_OVER_COUNT: f64 = 0.9;

/// A viscous friction that differs by direction replaces one coefficient when it leaves at
/// most this share of what one coefficient leaves of the fitting part (one more parameter
/// must earn its place, as [`FILM_OVER_COUNT`]).
const SPLIT_OVER_ONE: f64 = 0.9;

/// A Stribeck friction whose excess falls off exponentially replaces the Gaussian one when
/// it leaves at most this share of what the Gaussian leaves of the fitting part: the same
/// number of parameters, but the Gaussian stays the shape unless the other is clearly
/// better.
const EXPONENTIAL_OVER_GAUSSIAN: f64 = 0.9;

/// A viscous friction that grows as a power of the speed replaces the linear shapes when it
/// leaves at most this share of what they leave of the fitting part (one more parameter, as
/// [`SPLIT_OVER_ONE`]).
const POWER_OVER_LINEAR: f64 = 0.9;

/// A Coulomb friction that builds up over a small speed replaces the exact stick/slip law
/// when it leaves at most this share of what the exact law leaves of the fitting part (one
/// more parameter, as [`SPLIT_OVER_ONE`]).
const SMOOTH_OVER_EXACT: f64 = 0.9;

/// A command delay with a first-order lag ([`special::fit_delay_lag`]) replaces the pure
/// delay when it leaves at most this share of what the pure delay leaves of the fitting
/// part (one more parameter must earn its place, as [`SPLIT_OVER_ONE`]).
const LAG_OVER_PURE: f64 = 0.9;

/// A play with one flank favoured is a constant force with a gap of width zero: when the
/// constant force alone predicts the held-out part at least as well, the gap is not found.
/// (The play's signature test charges it less per parameter than the constant force's
/// regression, so the scores alone would keep the larger model.) Seen on the independent
/// seeds 808 and 909: constant forces read as 4 µm plays, 0.3–0.4 % behind.
fn play_beyond_constant(ranked: &mut [(Fitted, Scores)]) {
    let Some(constant) = ranked
        .iter()
        .find(|(f, _)| f.effect == Effect::ConstantForce)
        .map(|(_, s)| s.shrink)
    else {
        return;
    };
    for (f, s) in ranked.iter_mut() {
        if f.effect == Effect::BacklashAsymmetry && s.significant && s.shrink <= constant {
            s.significant = false;
            f.note = format!(
                "a constant force alone predicts the held-out part as well ({:.1} % against {:.1} %)",
                100.0 * constant,
                100.0 * s.shrink
            );
        }
    }
}

/// A low-speed or short-stroke friction term whose regression stands this many standard
/// errors clear of zero, short of [`MIN_T`] …
const WEAK_T: f64 = 3.0;

/// … still counts when its held-out score is this large: a short record has few slow
/// passes or short strokes, so the regression is weak, but the replay with the effect
/// predicts held-out data far better. Set on the independent seed 202 (a 24 s record with
/// 12 reversals: 4.2 standard errors, 66 % held-out score).
const LARGE_SCORE: f64 = 0.3;

/// Whether `f` is a friction effect of the kind [`LARGE_SCORE`] describes.
fn weak_but_large(f: &Fitted, s: &Scores, fit_improved: bool) -> bool {
    let fig = |k: &str| f.evidence.figures.get(k).copied();
    let level = match f.effect {
        Effect::StribeckFriction => fig("excess_n"),
        Effect::StrokeFriction => fig("rise_n"),
        _ => None,
    };
    !f.evidence.pass
        && level.is_some_and(|c| c > 0.0)
        && fig("t").is_some_and(|t| t >= WEAK_T)
        && s.score >= LARGE_SCORE
        && fit_improved
}

/// A friction force or a constant force acts on the force channel first: the position loop
/// takes most of it out of the position. Such a candidate must take at least this share of
/// its held-out position shrink off the force residual too. One that shrinks the position
/// and leaves the force alone is standing in for a loop-dynamics mismatch (gains, a lag, a
/// channel skew), not a force. Set on the independent seeds 1, 101 and 202 (clean records
/// flagged viscous friction with 47–66 % position and −0.1–15 % force shrink; true friction
/// singles kept ≥ 0.7× the position shrink on the force). Not applied once play is in the
/// model: a friction force then decides where in the gap the drive sits, which moves the
/// position directly (two-effect records with backlash, seeds 1, 101 and 606, lost their
/// friction to it).
const FORCE_SHARE: f64 = 0.5;

/// A payload on a spring pushes back on the drive, so a compliance the record holds also
/// changes the force the motor needs. A compliance candidate must take at least this share
/// of the held-out force residual away when a force is logged. Set on the independent seeds
/// 1, 101 and 202: four clean records passed with 35–79 % position shrink and −0.4–1.5 %
/// force shrink; of the true compliances, one skewed single (−2.6 %) falls below.
const COMPLIANCE_FORCE_SHRINK: f64 = 0.02;

/// Whether `e` is a force effect whose held-out force shrink falls short of [`FORCE_SHARE`]
/// of its position shrink (only when a force channel is logged). A force shrink of
/// [`FORCE_ONLY_SHRINK`] is a force by itself, whatever the position gained: no clean
/// record's candidate came near it (2828 case_021 skewed, a viscous coefficient that
/// differs by direction, took 84 % of the position and 38 % of the force; over the traced
/// records of seeds 2323–2929 the only other candidates this lets count were a constant
/// force beside a play and one beside a Coulomb friction, both selected later anyway).
fn force_shows_less(e: Effect, s: &Scores) -> bool {
    acts_on_force(e)
        && s.shrink_force
            .is_some_and(|f| f < FORCE_SHARE * s.shrink_pos && f < FORCE_ONLY_SHRINK)
}

/// How many standard errors the speed term that keeps its sign both ways (a viscous
/// coefficient that differs by direction, see `friction::viscous_split`) must stand for a
/// split viscous friction to count without [`FORCE_SHARE`]. A loop-dynamics mismatch (gains,
/// a lag, a skew) leaves a force residual that changes sign with the motion; one that keeps
/// its sign both ways and grows with the speed is a force. Clean records of seeds 4545–4848
/// read at most 5; a directional viscous friction (4747 case_021: 90 and 20 N·s/m) read 328
/// and 303 skewed, and lost to the force share with 70 % position and 25 % force shrink.
const SPLIT_T_ALONE: f64 = 30.0;

/// Whether `f` is a viscous friction that differs by direction, fitted so, whose split
/// stands beyond [`SPLIT_T_ALONE`].
fn sign_kept_both_ways(f: &Fitted) -> bool {
    matches!(f.applied, Applied::Split(_))
        && f.evidence
            .figures
            .get("split_t")
            .is_some_and(|t| t.abs() >= SPLIT_T_ALONE)
}

/// A friction or a constant force: an effect that acts on the force channel first.
fn acts_on_force(e: Effect) -> bool {
    matches!(
        e,
        Effect::CoulombFriction
            | Effect::ViscousFriction
            | Effect::StribeckFriction
            | Effect::StrokeFriction
            | Effect::ConstantForce
    )
}

/// The mirror of [`LEAD_POS_SHRINK`]: a force effect that leaves the position residual as
/// it was (a residual the noise or the grid holds) is diluted in the combined shrink just
/// as much. One whose signature is there counts when it takes this share of the held-out
/// force residual away and does not make the position worse. Read off seeds 1, 101, 202 and
/// 505–808: true frictions scored 0.08–0.10 combined with 33–80 % force shrink; no clean
/// record's candidate reached 15 %, and wrong friction shapes stayed below 28 %.
const FORCE_ONLY_SHRINK: f64 = 0.3;

/// A stroke friction acts only while the axis makes short strokes, and the held-out end
/// of a record may hold few of them, as it may hold no burst: one whose signature passes
/// also counts when its replay takes this share of the fitting residual away, and the
/// held-out part gains on the force ([`STROKE_FIT_FORCE`]) without losing on the position.
/// Over the traced records of seeds 2323–3434 and 3838–4848 (pairs of all, singles of
/// 4040, 4545, 4747, 4848), one candidate met it: 4747 case_024, a 40 N rise below 7.5 mm
/// fitted as 39 N below 10 mm, 77 % of the fitting part and 13 % held out. The nearest
/// other, a power-law viscous friction's stand-in, took 41 %.
const STROKE_FIT_SHRINK: f64 = 0.6;

/// The held-out force shrink [`STROKE_FIT_SHRINK`] asks for.
const STROKE_FIT_FORCE: f64 = 0.1;

/// Whether `f` is a stroke friction that [`STROKE_FIT_SHRINK`] lets count.
fn stroke_by_fit(f: &Fitted, s: &Scores) -> bool {
    f.effect == Effect::StrokeFriction
        && s.fit_shrink >= STROKE_FIT_SHRINK
        && s.shrink_force.is_some_and(|x| x >= STROKE_FIT_FORCE)
        && s.shrink_pos >= 0.0
}

/// Says so in the note of a stroke friction that [`STROKE_FIT_SHRINK`] let count below the
/// plain threshold.
fn note_stroke_by_fit(ranked: &mut [(Fitted, Scores)]) {
    for (f, s) in ranked.iter_mut() {
        if s.significant && s.score < MIN_SHRINK && stroke_by_fit(f, s) {
            add_note(
                f,
                format!(
                    "counted by the fitting part ({:.0} % of its residual) and the {:.0} % of the held-out force residual it takes: the held-out end holds few of the short strokes it acts on",
                    100.0 * s.fit_shrink,
                    100.0 * s.shrink_force.unwrap_or(0.0)
                ),
            );
        }
    }
}

/// Whether `f` is a force effect that [`FORCE_ONLY_SHRINK`] lets count.
fn force_in_force(f: &Fitted, s: &Scores) -> bool {
    acts_on_force(f.effect)
        && s.shrink_force.is_some_and(|x| x >= FORCE_ONLY_SHRINK)
        && s.shrink_pos >= -0.02
}

/// A lead error moves the position only, and the combined shrink dilutes its position
/// shrink with a force residual it cannot touch (in a second round, the first effect's
/// force is what is left). One whose pitch the spectrum found counts when it takes this
/// share of the held-out position residual away. Set on the independent seeds 1, 101 and
/// 202: no clean record passes the pitch test; mixtures' lead errors showed 11–25 %.
const LEAD_POS_SHRINK: f64 = 0.12;

/// A pitch a screw can have (at most this many mm), standing this far above the median of
/// the spectrum along the travel and explaining this share of the quiet samples' residual,
/// is a lead error's signature no other effect left: a lead error so found counts with
/// [`LEAD_SHARP_POS_SHRINK`] of the held-out position residual. Beside a friction whose law
/// the model lacks (2323 case_064: a 0.33 µm pitch error of 2.6 mm beside a power-law
/// viscous friction, 960–1100× and 0.48–0.52, took 4.7–6.3 % of the held-out position
/// residual: the rest is the friction's). Over the independent seeds 2323–3333 no record
/// without a lead error showed a pitch under 20 mm above 155× with 0.3 explained.
const LEAD_SHARP: (f64, f64, f64) = (20.0, 300.0, 0.4);

/// See [`LEAD_SHARP`].
const LEAD_SHARP_POS_SHRINK: f64 = 0.04;

/// Whether `f` is a lead error found by its pitch that [`LEAD_POS_SHRINK`] (or, for a sharp
/// pitch, [`LEAD_SHARP_POS_SHRINK`]) lets count.
fn lead_in_position(f: &Fitted, s: &Scores, shape: bool) -> bool {
    let fig = |k: &str| f.evidence.figures.get(k).copied().unwrap_or(0.0);
    let sharp = fig("pitch_mm") <= LEAD_SHARP.0
        && fig("peak_ratio") >= LEAD_SHARP.1
        && fig("explained_share") >= LEAD_SHARP.2;
    let min_pos = if sharp {
        LEAD_SHARP_POS_SHRINK
    } else {
        LEAD_POS_SHRINK
    };
    f.effect == Effect::LeadError
        && shape
        && s.shrink_pos >= min_pos
        && s.shrink_force.is_none_or(|x| x > LEAD_FORCE_SLACK)
}

/// Whether `f` is a lead error's table whose held-out part lies mostly beyond its travel and
/// which holds from one half of the fitting part to the next (see
/// [`special::HOLDOUT_IN_TRAVEL`]): it counts when the held-out part is not made worse.
fn lead_beyond_holdout(f: &Fitted, s: &Scores) -> bool {
    f.effect == Effect::LeadError
        && f.evidence.pass
        && f.evidence.figures.get("halves_hold") == Some(&1.0)
        && s.shrink_pos >= -0.02
        && s.shrink_force.is_none_or(|x| x > LEAD_FORCE_SLACK)
}

/// A command delay that position and force both show as a lag of more than a channel skew
/// can make ([`DELAY_BEYOND_SKEW`] samples) counts when it takes this share of the held-out
/// position residual away and leaves the force no worse: beside a force effect the model
/// lacks (a disturbance, a stroke friction), the force residual the delay cannot touch
/// dilutes its combined shrink to a few per cent. Read off the traces of the independent
/// seeds 2323–3434, 3838–4646 (two-effect records) and 4747 (all records): the delays of
/// 1.3–1.7 samples beside a disturbance or a stroke friction took 0.45–0.73 of the held-out
/// position with the force at −0.002–+0.009, and combined 0.01–0.08; every record whose
/// delay candidate took ≥ 0.3 of the position without a delay in it (a clean skewed record,
/// a constant force, a compliance) lagged 0.22–0.60 samples.
const DELAY_POS_SHRINK: f64 = 0.4;

/// The lag, in samples, beyond which [`DELAY_POS_SHRINK`] applies: a channel logged up to a
/// sample off its instant makes a lag of up to a sample.
const DELAY_BEYOND_SKEW: f64 = 1.25;

/// How much worse a delay counted by its position may leave the held-out force residual.
const DELAY_FORCE_SLACK: f64 = -0.01;

/// Whether `f` is a command delay that [`DELAY_POS_SHRINK`] lets count.
fn delay_in_position(f: &Fitted, s: &Scores) -> bool {
    f.effect == Effect::CommandDelay
        && f.evidence.pass
        && f.evidence
            .figures
            .get("lag_samples")
            .is_some_and(|l| *l > DELAY_BEYOND_SKEW)
        && s.shrink_pos >= DELAY_POS_SHRINK
        && s.shrink_force.is_some_and(|x| x >= DELAY_FORCE_SLACK)
}

/// How much worse a lead error may leave the held-out force residual and still count by
/// its position shrink: on a scale-fed axis the table moves the motor a little, and with
/// it the force (2727 case_051, a pitch table alone: 0.90 of the position, −0.022 of the
/// force, was refused at −0.02). Over the independent seeds 2323–2727 no record without a
/// lead error had a lead candidate with a pitch and 0.12 of the position that left the
/// force 1 % worse or more.
const LEAD_FORCE_SLACK: f64 = -0.05;

/// A screw's growth moves the position only too, and beside a friction found first the
/// force that friction left dilutes its combined shrink the same way (2626 case_064, a
/// growth beside a Stribeck friction: 0.29 of the held-out position residual, a combined
/// score of 0.007, and a lead error's harmonics took the drift instead). One whose drift in
/// time was found counts when it takes this share of the held-out position residual away.
/// Set on the independent seeds 2323, 2424 and 2626: of the records without a growth, one
/// drift passed with 0.61 of the position, and it grew the force residual by 12 %.
const GROWTH_POS_SHRINK: f64 = 0.25;

/// Whether `f` is a screw growth found by its drift that [`GROWTH_POS_SHRINK`] lets count.
fn growth_in_position(f: &Fitted, s: &Scores) -> bool {
    f.effect == Effect::ThermalGrowth
        && f.evidence.figures.contains_key("drift_um")
        && s.shrink_pos >= GROWTH_POS_SHRINK
        && s.shrink_force.is_none_or(|x| x > -0.02)
}

/// Whether `f` is a lead error on a base that has a screw's growth. The growth was fitted on
/// the fitting part alone, and there it has taken the lead error's cumulative part (the two
/// are one shape along the travel), so the lead error cannot make that part better; the
/// held-out part, where the growth has moved on, is where the two come apart, and it alone
/// judges. Seen on the independent seeds 606 and 808: a lead error beside growth shrank the
/// held-out residual by 18–39 % and the fitting residual grew by 9 %.
fn lead_beside_growth(ctx: &Context, f: &Fitted) -> bool {
    f.effect == Effect::LeadError && growth_in_base(ctx)
}

/// Whether the round's base has a screw's growth among the effects selected.
pub(super) fn growth_in_base(ctx: &Context) -> bool {
    ctx.selected
        .iter()
        .any(|s| matches!(s.applied, Applied::Params(Effect::ThermalGrowth, _)))
}

/// A compliance whose ringing the command hardly excites (a resonance above ~100 Hz behind
/// jerk-limited moves) shows no signature, but fitted with the calibration it takes large
/// shares of both residuals away: the payload's lag from the position and its push from
/// the force. Set on the independent seeds 1, 101, 202, 505, 606, 707, 808 and 909 (clean
/// and compliance records, unskewed and skewed): the most a clean record took was 0.21 of
/// the force (with 0.90 of the position) and, skewed, 0.24 (with 0.08); ten of the 32
/// unskewed compliances took both shares. Only on the calibrated model alone: beside a
/// found effect, the shares are of what that effect left (two disturbance records, seeds
/// 808 and 909, added a compliance that way). The position share was 0.5 until seed 1717
/// (a 47 Hz spring whose stiffness varies along the travel: 0.47 of the position and 0.45
/// of the force); over the records of seeds 1–1717 no clean record took 0.25 of the force
/// with more than 0.08 of the position, and the delay records that took a force share
/// (up to 0.35) left the position as it was.
const COMPLIANCE_BOTH: (f64, f64) = (0.3, 0.25);

/// Whether `f` is a compliance that [`COMPLIANCE_BOTH`] lets count without a signature.
fn compliance_in_both(f: &Fitted, s: &Scores) -> bool {
    f.effect == Effect::Compliance
        && s.score >= MIN_SHRINK
        && s.shrink_pos >= COMPLIANCE_BOTH.0
        && s.shrink_force.is_some_and(|x| x >= COMPLIANCE_BOTH.1)
}

/// Whether `e` changes the record only slowly (a force that follows the motion, a load, a
/// drift): what a moving average keeps (see `Engine::smooth_n`). A spring, a delay, a play
/// or a pitch act within a few samples and are scored as recorded.
fn is_slow(e: Effect) -> bool {
    matches!(
        e,
        Effect::CoulombFriction
            | Effect::StribeckFriction
            | Effect::ViscousFriction
            | Effect::StrokeFriction
            | Effect::ConstantForce
            | Effect::ExternalDisturbance
            | Effect::ThermalGrowth
    )
}

/// Whether a candidate that passed the thresholds is still not found: a force effect
/// that shows less on the force than on the position ([`force_shows_less`]), a compliance
/// that leaves the force alone ([`COMPLIANCE_FORCE_SHRINK`]), level steps that take too
/// little of the fitting part ([`STEPS_MIN_FIT_SHRINK`]).
fn shown_wrong_channel(ctx: &Context, f: &Fitted, s: &Scores) -> bool {
    // A limit cycle's tone drowns the force shrink of a play's record, unless the scores
    // were taken through the moving average that removes it.
    let tone_removed = ctx.eng.smooth_n > 1 && is_slow(f.effect);
    ((!ctx.play_found || tone_removed) && !sign_kept_both_ways(f) && force_shows_less(f.effect, s))
        || (f.effect == Effect::Compliance
            && s.shrink_force.is_some_and(|x| x < COMPLIANCE_FORCE_SHRINK))
        || (f.effect == Effect::ExternalDisturbance
            && f.evidence.figures.contains_key("steps")
            && s.fit_shrink < STEPS_MIN_FIT_SHRINK)
}

/// Held-out scores of a fitted candidate and whether it counts as found. A candidate whose
/// fit re-fitted the earlier effects and the ratios is judged against `polished` (see
/// [`best_without`]) when there is one, the others against the base.
fn score(ctx: &Context, f: &Fitted, polished: Option<&Eval>) -> Scores {
    let state_dependent = f.effect != Effect::ExternalDisturbance;
    let fit_j = |e: &Eval| ctx.eng.j(&e.fit_pos, e.fit_force.as_deref());
    let before = polished
        .filter(|_| f.without.is_some())
        .unwrap_or(ctx.base_eval);
    let mut s = ctx.eng.scores(
        before,
        &f.eval,
        f.n_params,
        state_dependent,
        is_slow(f.effect),
    );
    let fit_b = fit_j(before);
    let fit_a = ctx.eng.j(&f.eval.fit_pos, f.eval.fit_force.as_deref());
    let shape = f.evidence.pass && (has_shape_test(f.effect) || strong_periodic_force(f));
    if shape {
        // The signature test already says the shape is in the residual, and the shrink is
        // measured on held-out data, so a shape with many coefficients (a lead error's
        // harmonics) is not also charged the full per-parameter penalty.
        s.score = s.shrink - PENALTY_WITH_SIGNATURE * f.n_params as f64;
    }
    let hunting = f
        .evidence
        .figures
        .get("hunting_share")
        .copied()
        .filter(|_| f.evidence.pass);
    // Bursts come at times nothing predicts, and the held-out end may hold none: bursts that
    // the signature test found, and that take a large part of the fitting residual away,
    // count on that, if the held-out part is not made worse.
    let fit_shrink = if fit_b > 0.0 {
        1.0 - fit_a / fit_b
    } else {
        0.0
    };
    s.fit_shrink = fit_shrink;
    let bursts = f.effect == Effect::ExternalDisturbance
        && f.evidence.pass
        && f.evidence.figures.contains_key("bursts")
        && fit_shrink >= BURSTS_FIT_SHRINK
        && s.shrink >= -0.01;
    if bursts {
        s.score = s
            .score
            .max(fit_shrink - PENALTY_WITH_SIGNATURE * f.n_params as f64);
    }
    s.significant = if bursts || weak_but_large(f, &s, fit_a < fit_b) {
        true
    } else if f.effect == Effect::Quantization {
        // Rounding cannot be predicted sample by sample, so modelling the grid does not
        // shrink the residual; the grid is proven by the positions themselves.
        f.evidence.pass
    } else if hunting.is_some() {
        // Nor can a limit cycle's phase: the steady tone proves the play.
        true
    } else {
        // A compliance found by its ringing after the acceleration steps (no spectral peak)
        // has a weaker shape test than a resonance: it keeps the plain threshold. Set on the
        // independent seeds 101 and 202, where clean records passed with 7–10 %.
        let ringing_only = f.evidence.figures.contains_key("ringing_steps")
            || f.evidence.figures.contains_key("loop_peak_hz");
        let min = if shape && !ringing_only {
            MIN_SHRINK_WITH_SHAPE
        } else {
            MIN_SHRINK
        };
        (f.evidence.pass
            && (s.score >= min
                || lead_in_position(f, &s, shape)
                || lead_beyond_holdout(f, &s)
                || growth_in_position(f, &s)
                || delay_in_position(f, &s)
                || stroke_by_fit(f, &s)
                || force_in_force(f, &s))
            || (ctx.selected.is_empty() && compliance_in_both(f, &s)))
            && (fit_a < fit_b || lead_beside_growth(ctx, f))
    };
    if s.significant && shown_wrong_channel(ctx, f, &s) {
        s.significant = false;
    }
    if let Some(share) = hunting {
        s.score = s.score.max(MIN_SHRINK + 0.5 * share);
    }
    if f.effect == Effect::Quantization && s.significant {
        s.score = s.score.max(
            MIN_SHRINK
                + f.evidence
                    .figures
                    .get("on_grid_share")
                    .copied()
                    .unwrap_or(0.0)
                    * 0.5,
        );
    }
    s
}
