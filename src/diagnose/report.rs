//! "How far": the report of one diagnosis — the calibration and any skewed channel, the
//! ranking with each candidate's evidence, the selected effects with their final
//! parameters, and the held-out residual before and after, overall and per regime, bin and
//! window.

use std::collections::BTreeMap;

use super::calibrate::{CalParam, Calibration};
use super::candidates::Fitted;
use super::engine::{Engine, Eval, Scores, peak, rms};
use super::regimes;
use super::replay::Record;
use super::select::Outcome;
use super::{Figures, RankEntry, RegimeChange, Report, Series};
use crate::preset::Preset;
use crate::units::{m_to_mm, m_to_um, s_to_ms};

/// What a report is built from.
pub struct Parts {
    /// The calibration.
    pub cal: Calibration,
    /// The nominal's residuals.
    pub nom_eval: Eval,
    /// The calibrated model's residuals.
    pub cal_eval: Eval,
    /// The selection.
    pub outcome: Outcome,
    /// The base axis (for base-position bins).
    pub base_axis: Option<String>,
}

fn um(v: &[f64]) -> Vec<f64> {
    v.iter().map(|x| m_to_um(*x)).collect()
}

/// One ranking row: the parameters (the final ones, for a selected effect), their
/// uncertainties, the scores and the evidence.
fn rank_entry(first: &Fitted, s: &Scores, selected: Option<(&Fitted, &[f64])>) -> RankEntry {
    // A selected effect is described as it was selected, which may be a later round than
    // the first, with another shape (level steps in the first round, bursts once a hunting
    // play's tone was averaged out): its keys, evidence and note with its final parameters.
    let (f, theta) = selected.unwrap_or((first, &first.theta));
    let mut params: BTreeMap<String, f64> = f
        .keys
        .iter()
        .zip(theta)
        .map(|(k, v)| (k.clone(), *v))
        .collect();
    if f.effect == super::Effect::ConstantForce
        && let Some(&force) = theta.first()
    {
        // The same force as the motor-force offset of the identification literature
        // (M·a + Fv·v + Fc·sign(v) + offset = F): offset = −(force on the table).
        params.insert("offset_n".to_owned(), -force);
    }
    params.extend(f.extra.clone());
    RankEntry {
        effect: f.effect.name().to_owned(),
        params,
        params_std: f
            .keys
            .iter()
            .zip(&f.std)
            .map(|(k, v)| (k.clone(), *v))
            .collect(),
        fit_rms_before: m_to_um(s.fit_pos_before),
        fit_rms_after: m_to_um(s.fit_pos_after),
        holdout_rms_before: m_to_um(s.hold_pos_before),
        holdout_rms_after: m_to_um(s.hold_pos_after),
        shrink: s.shrink,
        shrink_pos: s.shrink_pos,
        shrink_force: s.shrink_force,
        score: s.score,
        significant: s.significant,
        note: f.note.clone(),
        evidence: f.evidence.text.clone(),
        evidence_pass: f.evidence.pass,
        evidence_figures: f.evidence.figures.clone(),
    }
}

/// The held-out part as a record of its own.
fn holdout_record(eng: &Engine) -> Record {
    match eng.split.validate {
        Some(v) => v.clone(),
        None => eng.split.main.slice(eng.split.n_fit..eng.split.main.len()),
    }
}

/// Residual before and after per regime of the held-out command.
fn per_regime(before: &[f64], after: &[f64], labels: &[regimes::Regime]) -> Vec<RegimeChange> {
    let reg_b = regimes::per_regime(before, labels);
    let reg_a = regimes::per_regime(after, labels);
    reg_b
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
        .collect()
}

/// Builds the report (and the fitted preset for "apply to model").
pub fn build(preset: &Preset, eng: &Engine, p: Parts) -> Report {
    let out = &p.outcome;
    let main = eng.split.main;
    let hold_rec = holdout_record(eng);
    let before = um(&p.nom_eval.hold_pos);
    let after = um(&out.final_eval.hold_pos);
    let labels = regimes::classify(&hold_rec.cmd_m, hold_rec.t3_s);
    let t: Vec<f64> = (0..hold_rec.len()).map(|i| hold_rec.t_s(i)).collect();
    let pos_mm: Vec<f64> = hold_rec.pos_m.iter().map(|x| m_to_mm(*x)).collect();
    let win_len = ((0.1 / hold_rec.t3_s).round() as usize).max(1);
    let finals: BTreeMap<&str, (&Fitted, &[f64])> = out
        .selected
        .iter()
        .zip(&out.final_params)
        .map(|((f, _), th)| (f.effect.name(), (f, th.as_slice())))
        .collect();
    let ranking: Vec<RankEntry> = out
        .ranking
        .iter()
        .map(|(f, s)| rank_entry(f, s, finals.get(f.effect.name()).copied()))
        .collect();
    let selected: Vec<String> = out
        .selected
        .iter()
        .map(|(f, _)| f.effect.name().to_owned())
        .collect();
    let verdict = selected.first().cloned().unwrap_or_else(|| "none".into());
    let (rb, ra) = (rms(&before), rms(&after));
    let cal_hold = eng.j(&p.cal_eval.hold_pos, p.cal_eval.hold_force.as_deref());
    let fin_hold = eng.j(
        &out.final_eval.hold_pos,
        out.final_eval.hold_force.as_deref(),
    );
    let mut fitted = preset.clone();
    if let Some(a) = fitted.axes.iter_mut().find(|a| a.name == main.axis) {
        *a = out.final_cand.model.axis.clone();
    }
    Report {
        preset: preset.name.clone(),
        axis: main.axis.clone(),
        base_axis: p.base_axis.clone(),
        t3_s: main.t3_s,
        resampled: main.resampled,
        samples_fit: eng.split.n_fit,
        samples_holdout: hold_rec.len(),
        holdout_source: if eng.split.validate.is_some() {
            "validation record".into()
        } else {
            "end of the record".into()
        },
        time_offset_ms: s_to_ms(-p.cal.common_lag_samples * main.t3_s),
        calibration_final: out.final_ratios.clone(),
        calibration: p.cal.clone(),
        holdout_masked: eng.hold_mask.iter().filter(|k| !**k).count(),
        replays: 0,
        units: "position residuals in um (measured - simulated); force residuals in N".into(),
        verdict,
        shrink: if cal_hold > 0.0 && !selected.is_empty() {
            1.0 - fin_hold / cal_hold
        } else {
            0.0
        },
        selected,
        ranking,
        regimes: regimes::per_regime(&before, &labels),
        position_bins: regimes::per_bin(&before, &pos_mm, 10),
        base_bins: hold_rec
            .base_pos_m
            .as_ref()
            .map(|b| {
                let mm: Vec<f64> = b.iter().map(|x| m_to_mm(*x)).collect();
                regimes::per_bin(&before, &mm, 10)
            })
            .unwrap_or_default(),
        time_bins: regimes::per_bin(&before, &t, 10),
        windows: regimes::worst_windows(&after, hold_rec.t0_s, hold_rec.t3_s, win_len, 10),
        windows_before: regimes::worst_windows(&before, hold_rec.t0_s, hold_rec.t3_s, win_len, 10),
        force_rms_before: p.nom_eval.hold_force.as_deref().map(rms),
        force_rms_after: out.final_eval.hold_force.as_deref().map(rms),
        overall: Figures {
            rms_before: rb,
            rms_after: ra,
            peak_before: peak(&before),
            peak_after: peak(&after),
            shrink: if rb > 0.0 { 1.0 - ra / rb } else { 0.0 },
        },
        per_regime: per_regime(&before, &after, &labels),
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

/// The calibration as report lines (`mass ×1.021`, …).
pub fn calibration_lines(ratios: &[(CalParam, f64)]) -> Vec<String> {
    ratios
        .iter()
        .map(|(p, r)| format!("{} ×{r:.4}", p.name()))
        .collect()
}
