//! Forward selection decided by the criterion, then naming against the floor.
//!
//! Each round fits every candidate not yet selected on the base (the calibrated model with
//! the effects selected so far) and adds the one that wins over the base by the criterion
//! with the largest net gain; it stops when none wins, or at the most effects asked for.
//! The effects found are then fitted once more together with the calibration, and each is
//! judged by the same criterion against the floor: the final model without it against the
//! final model, on its part, with the floor what the final model leaves. An effect that
//! does not explain more than that is dropped (the weakest first) and the rest judged
//! again.

use super::DiagnoseError;
use super::calibrate::Calibration;
use super::criterion::{self, Judgement, Part, Scale};
use super::effects::{Effect, candidate};
use super::engine::{Cand, Engine, Eval};
use super::fit::{Chosen, Context, Fitted, Signals, chosen_params, rebuild};
use super::lm::{self, Param};

/// An effect named by the diagnosis.
#[derive(Debug, Clone)]
pub struct Named {
    /// The effect as it was selected (its round's fit).
    pub fitted: Fitted,
    /// Its parameters after the final joint fit.
    pub theta: Vec<f64>,
    /// The final model without it against the final model, against the floor.
    pub judgement: Judgement,
}

/// What the selection found.
pub struct Outcome {
    /// Every candidate of the first round: fitted on the calibrated model, or skipped for a
    /// clearly absent signature (then with its evidence only).
    pub ranking: Vec<Ranked>,
    /// The named effects, the one that adds most to the final model first.
    pub named: Vec<Named>,
    /// Effects the forward pass selected that the floor did not let stand.
    pub dropped: Vec<Named>,
    /// The model with every named effect.
    pub final_cand: Cand,
    /// Its residuals.
    pub final_eval: Eval,
    /// Its calibration values.
    pub final_values: Vec<f64>,
    /// The floors the named effects were judged against (held-out part, fitting part).
    pub floors: (f64, f64),
}

/// A first-round candidate: its fit, or its evidence alone.
#[derive(Debug, Clone)]
pub enum Ranked {
    /// Fitted.
    Fitted(Box<Fitted>),
    /// Not fitted: its signature is clearly absent.
    Skipped(Effect, super::fit::Evidence),
}

impl Ranked {
    /// The effect.
    pub fn effect(&self) -> Effect {
        match self {
            Ranked::Fitted(f) => f.effect,
            Ranked::Skipped(e, _) => *e,
        }
    }
}

/// The base a round fits on.
struct Base {
    chosen: Vec<Chosen>,
    values: Vec<f64>,
    cand: Cand,
    eval: Eval,
}

/// Runs the selection from the calibrated model `calibrated` (residual `cal_eval`).
#[allow(clippy::too_many_arguments)]
pub fn run(
    eng: &Engine,
    scale: &Scale,
    sensor_quantum_m: f64,
    cal: &Calibration,
    nominal: &Cand,
    calibrated: &Cand,
    cal_eval: &Eval,
    effects: &[Effect],
    max_effects: usize,
) -> Result<Outcome, DiagnoseError> {
    eng.sims_expected.store(
        60 * effects.len() * (max_effects + 1),
        std::sync::atomic::Ordering::Relaxed,
    );
    let mut base = Base {
        chosen: vec![],
        values: cal.values(),
        cand: calibrated.clone(),
        eval: cal_eval.clone(),
    };
    let mut picks: Vec<Fitted> = vec![];
    let mut ranking: Option<Vec<Ranked>> = None;
    while picks.len() < max_effects {
        let rest: Vec<Effect> = effects
            .iter()
            .copied()
            .filter(|e| !picks.iter().any(|p| p.effect == *e))
            .collect();
        if rest.is_empty() {
            break;
        }
        let sig = Signals::new(eng, &base.eval);
        let ctx = Context {
            eng,
            scale,
            sensor_quantum_m,
            nominal,
            cal,
            values: &base.values,
            chosen: &base.chosen,
            base: &base.cand,
            base_eval: &base.eval,
            sig: &sig,
        };
        let round = polish_contenders(&ctx, fit_all(&ctx, &rest)?)?;
        if std::env::var_os("AXB_DBG").is_some() {
            for r in &round {
                if let Ranked::Fitted(f) = r {
                    eprintln!(
                        "ROUND{} {:?}/{} {}: {}",
                        picks.len(),
                        f.effect,
                        f.variant,
                        f.judgement.passes,
                        f.judgement.text()
                    );
                }
            }
        }
        // A force at times no state predicts is the residual category: it is judged on the
        // part it was shaped on, where its gain is not comparable with a held-out one, and
        // any state or time law that wins comes first.
        let best = [Part::Held, Part::Fit].into_iter().find_map(|part| {
            round
                .iter()
                .filter_map(|r| match r {
                    Ranked::Fitted(f) if f.judgement.passes && f.part == part => Some(f.as_ref()),
                    _ => None,
                })
                .max_by(|a, b| a.judgement.net().total_cmp(&b.judgement.net()))
                .cloned()
        });
        if ranking.is_none() {
            ranking = Some(round);
        }
        let Some(best) = best else {
            break;
        };
        base.chosen = with_params(&base.chosen, &best.sel_theta);
        base.chosen.push(best.chosen.clone());
        base.values.clone_from(&best.values);
        base.cand = best.cand.clone();
        base.eval = best.eval.clone();
        picks.push(best);
    }
    let ranking = ranking.unwrap_or_default();
    if picks.is_empty() {
        return Ok(Outcome {
            ranking,
            named: vec![],
            dropped: vec![],
            final_cand: calibrated.clone(),
            final_eval: cal_eval.clone(),
            final_values: cal.values(),
            floors: (
                scale.floor(cal_eval, Part::Held),
                scale.floor(cal_eval, Part::Fit),
            ),
        });
    }
    let slow = picks.iter().any(|p| p.effect == Effect::ThermalGrowth);
    let base = joint_refit(eng, cal, nominal, base, slow)?;
    name(eng, scale, cal, nominal, ranking, picks, base)
}

/// Fits every effect of `effects` on `ctx.base`, two at a time, in `effects`' order.
fn fit_all(ctx: &Context, effects: &[Effect]) -> Result<Vec<Ranked>, DiagnoseError> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: std::sync::Mutex<Vec<Option<Result<Ranked, DiagnoseError>>>> =
        std::sync::Mutex::new((0..effects.len()).map(|_| None).collect());
    let threads = if std::env::var_os("AXB_SERIAL").is_some() {
        1
    } else {
        2
    };
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(&e) = effects.get(i) else {
                        break;
                    };
                    let c = candidate(e);
                    let before = ctx.eng.replays();
                    let t0 = std::time::Instant::now();
                    let r = ctx.fit(c).map(|f| match f {
                        Ok(f) => Ranked::Fitted(Box::new(f)),
                        Err(ev) => Ranked::Skipped(e, ev),
                    });
                    if std::env::var_os("AXB_SERIAL").is_some() {
                        eprintln!(
                            "FIT {e:?} replays {} {:.3} s",
                            ctx.eng.replays() - before,
                            t0.elapsed().as_secs_f64()
                        );
                    }
                    let failed = r.is_err();
                    if let Ok(mut v) = results.lock() {
                        v[i] = Some(r);
                    }
                    if failed {
                        next.store(effects.len(), std::sync::atomic::Ordering::Relaxed);
                    }
                }
            });
        }
    });
    let v = results
        .into_inner()
        .map_err(|_| DiagnoseError::Input("a candidate fit panicked".into()))?;
    v.into_iter().flatten().collect::<Result<Vec<_>, _>>()
}

/// How many of a round's fits, best first by their net gain, are fitted again jointly with
/// the calibration (besides every one that already wins): the search's breadth, which the
/// criterion's decisions do not depend on beyond which fits it sees.
const CONTENDERS: usize = 3;

/// The round's contenders fitted again jointly (see [`Context::polish`]): each fit that
/// wins, and the best [`CONTENDERS`] by net gain. A joint fit replays the record far more
/// often than a fit of the effect alone, and most candidates of a round lose by far.
fn polish_contenders(ctx: &Context, round: Vec<Ranked>) -> Result<Vec<Ranked>, DiagnoseError> {
    let mut order: Vec<(usize, f64)> = round
        .iter()
        .enumerate()
        .filter_map(|(i, r)| match r {
            Ranked::Fitted(f) => Some((i, f.judgement.net())),
            Ranked::Skipped(..) => None,
        })
        .collect();
    order.sort_by(|a, b| b.1.total_cmp(&a.1));
    let chosen: Vec<usize> = order
        .iter()
        .enumerate()
        .filter(|(k, (i, _))| {
            *k < CONTENDERS || matches!(&round[*i], Ranked::Fitted(f) if f.judgement.passes)
        })
        .map(|(_, (i, _))| *i)
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let polished: std::sync::Mutex<Vec<(usize, Result<Fitted, DiagnoseError>)>> =
        std::sync::Mutex::new(vec![]);
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| {
                loop {
                    let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(&i) = chosen.get(k) else {
                        break;
                    };
                    if let Ranked::Fitted(f) = &round[i] {
                        let r = ctx.polish(f.as_ref().clone());
                        if let Ok(mut v) = polished.lock() {
                            v.push((i, r));
                        }
                    }
                }
            });
        }
    });
    let polished = polished
        .into_inner()
        .map_err(|_| DiagnoseError::Input("a joint fit panicked".into()))?;
    let mut round = round;
    for (i, r) in polished {
        round[i] = Ranked::Fitted(Box::new(r?));
    }
    Ok(round)
}

/// `chosen` with their refittable parameters set from `sel` (in order; empty: as they are).
fn with_params(chosen: &[Chosen], sel: &[f64]) -> Vec<Chosen> {
    let mut at = 0;
    chosen
        .iter()
        .map(|c| {
            let mut c = c.clone();
            if let super::fit::Shape::Params { theta, .. } = &c.shape
                && !c.defs.is_empty()
            {
                let n = theta.len();
                if let Some(th) = sel.get(at..at + n) {
                    c.shape = c.shape.with_theta(th);
                }
                at += n;
            }
            c
        })
        .collect()
}

/// The selected effects and the calibration values they do not own, fitted together from
/// where the selection left them: an effect found first keeps only what the next one does
/// not explain better.
fn joint_refit(
    eng: &Engine,
    cal: &Calibration,
    nominal: &Cand,
    base: Base,
    slow: bool,
) -> Result<Base, DiagnoseError> {
    let (sel0, sel_params) = chosen_params(&base.chosen);
    let owned = |p| {
        base.chosen.iter().any(|c| {
            matches!(
                (c.effect, p),
                (
                    Effect::CoulombFriction,
                    super::calibrate::CalParam::Coulomb | super::calibrate::CalParam::Smoothing
                ) | (Effect::ViscousFriction, super::calibrate::CalParam::Viscous)
            )
        })
    };
    let free: Vec<usize> = (0..base.values.len())
        .filter(|&i| !owned(cal.ratios[i].0))
        .collect();
    let values_of = |th: &[f64]| {
        let mut v = base.values.clone();
        for (j, &i) in free.iter().enumerate() {
            v[i] = th[j];
        }
        v
    };
    let n_r = free.len();
    let build = |th: &[f64]| rebuild(nominal, cal, &values_of(th), &base.chosen, Some(&th[n_r..]));
    let mut params: Vec<Param> = free.iter().map(|&i| cal.ratios[i].0.bounds()).collect();
    params.extend(sel_params);
    let mut start: Vec<f64> = free.iter().map(|&i| base.values[i]).collect();
    start.extend(sel0);
    let rows = |th: &[f64]| Ok(Some(eng.lm_rows(&eng.sim_fit(&build(th), slow)?)));
    let f = lm::fit_secant(&start, &params, &rows, 0.03, 3)?;
    let before = eng.j(&base.eval.fit_pos, base.eval.fit_force.as_deref());
    let cand = build(&f.theta);
    let eval = eng.evaluate(&cand)?;
    if f.rows.is_none() || eng.j(&eval.fit_pos, eval.fit_force.as_deref()) > before {
        return Ok(base);
    }
    Ok(Base {
        chosen: with_params(&base.chosen, &f.theta[n_r..]),
        values: values_of(&f.theta),
        cand,
        eval,
    })
}

/// The parameters of a chosen effect as they stand.
fn theta_of(c: &Chosen, fallback: &[f64]) -> Vec<f64> {
    match &c.shape {
        super::fit::Shape::Params { theta, .. } if !c.defs.is_empty() => theta.clone(),
        _ => fallback.to_vec(),
    }
}

/// Names the selected effects by the criterion against the floor (see the module's
/// documentation).
fn name(
    eng: &Engine,
    scale: &Scale,
    cal: &Calibration,
    nominal: &Cand,
    ranking: Vec<Ranked>,
    mut picks: Vec<Fitted>,
    mut base: Base,
) -> Result<Outcome, DiagnoseError> {
    let mut dropped: Vec<Named> = vec![];
    loop {
        let floors = (
            scale.floor(&base.eval, Part::Held),
            scale.floor(&base.eval, Part::Fit),
        );
        if std::env::var_os("AXB_DBG").is_some() {
            eprintln!(
                "NAME floors {floors:?} picks {:?} values {:?}",
                picks.iter().map(|p| p.effect).collect::<Vec<_>>(),
                base.values
            );
        }
        let mut judged = vec![];
        for (i, p) in picks.iter().enumerate() {
            let rest: Vec<Chosen> = base
                .chosen
                .iter()
                .enumerate()
                .filter(|(k, _)| *k != i)
                .map(|(_, c)| c.clone())
                .collect();
            // Without it, the rest of the final model as it stands.
            let without = eng.evaluate(&rebuild(nominal, cal, &base.values, &rest, None))?;
            let j = criterion::judge(scale, &without, &base.eval, p.part, p.n_params, floors.1);
            if std::env::var_os("AXB_DBG").is_some() {
                eprintln!("NAMING {:?}: {} {}", p.effect, j.passes, j.text());
            }
            judged.push(j);
        }
        let weakest = judged
            .iter()
            .enumerate()
            .filter(|(_, j)| !j.passes)
            .min_by(|a, b| a.1.net().total_cmp(&b.1.net()))
            .map(|(i, _)| i);
        let Some(i) = weakest else {
            let mut named: Vec<Named> = picks
                .into_iter()
                .zip(judged)
                .zip(&base.chosen)
                .map(|((f, j), c)| Named {
                    theta: theta_of(c, &f.theta),
                    fitted: f,
                    judgement: j,
                })
                .collect();
            named.sort_by(|a, b| b.judgement.net().total_cmp(&a.judgement.net()));
            return Ok(Outcome {
                ranking,
                named,
                dropped,
                final_cand: base.cand,
                final_eval: base.eval,
                final_values: base.values,
                floors,
            });
        };
        let f = picks.remove(i);
        let c = base.chosen.remove(i);
        dropped.push(Named {
            theta: theta_of(&c, &f.theta),
            fitted: f,
            judgement: judged.swap_remove(i),
        });
        // The rest fitted again without it; with none left, the calibrated model.
        if picks.is_empty() {
            base.values = cal.values();
            base.cand = cal.apply(nominal);
            base.eval = eng.evaluate(&base.cand)?;
        } else {
            base.cand = rebuild(nominal, cal, &base.values, &base.chosen, None);
            base.eval = eng.evaluate(&base.cand)?;
            let slow = picks.iter().any(|p| p.effect == Effect::ThermalGrowth);
            base = joint_refit(eng, cal, nominal, base, slow)?;
        }
    }
}
