//! "How far": the report of one diagnosis — the calibration and any skewed channel, the
//! ranking with each candidate's evidence and judgement, the named effects with their final
//! parameters, and the held-out residual before and after, overall and per regime, bin and
//! window.

use std::collections::BTreeMap;

use super::calibrate::Calibration;
use super::criterion::{Part, Scale};
use super::engine::{Engine, Eval, peak, rms};
use super::fit::Fitted;
use super::regimes;
use super::replay::Record;
use super::select::{Named, Outcome, Ranked};
use super::{Figures, RankEntry, RegimeChange, Report, Series};
use crate::preset::Preset;
use crate::units::{m_to_mm, m_to_um, s_to_ms};

/// What a report is built from.
pub struct Parts<'a> {
    /// The calibration.
    pub cal: Calibration,
    /// The criterion's scale.
    pub scale: &'a Scale,
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

/// The held-out shrink of the combined residual from `before` to `after` (the one shrink
/// figure of the report: 1 − the ratio of the two RMS levels, position and force each
/// weighed by the calibrated model's fitting residual).
pub fn shrink(scale: &Scale, before: &Eval, after: &Eval) -> f64 {
    let (b, a) = (
        scale.level(before, Part::Held),
        scale.level(after, Part::Held),
    );
    if b > 0.0 { 1.0 - (a / b).sqrt() } else { 0.0 }
}

fn ratio_shrink(before: f64, after: f64) -> f64 {
    if before > 0.0 {
        1.0 - after / before
    } else {
        0.0
    }
}

/// One ranking row of a fitted candidate, with its final parameters and naming judgement
/// when it was named (or dropped).
fn rank_entry(
    scale: &Scale,
    cal_eval: &Eval,
    f: &Fitted,
    named: Option<(&Named, bool)>,
) -> RankEntry {
    let theta = named.map_or(f.theta.as_slice(), |(n, _)| n.theta.as_slice());
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
    let e = &f.eval;
    let predictable = f.part == Part::Held;
    let judgement = named.map_or(&f.judgement, |(n, _)| &n.judgement);
    let mut note = format!("{} variant: {}", f.variant, f.note);
    if !predictable {
        note += "; held-out shrink not predictable (not scored)";
    }
    note += &format!("; {}", judgement.text());
    RankEntry {
        effect: f.effect.name().to_owned(),
        variant: f.variant.to_owned(),
        params,
        params_std: f
            .keys
            .iter()
            .zip(&f.std)
            .map(|(k, v)| (k.clone(), *v))
            .collect(),
        fit_rms_before: m_to_um(rms(&cal_eval.fit_pos)),
        fit_rms_after: m_to_um(rms(&e.fit_pos)),
        holdout_rms_before: m_to_um(rms(&cal_eval.hold_pos)),
        holdout_rms_after: m_to_um(rms(&e.hold_pos)),
        shrink: if predictable {
            shrink(scale, cal_eval, e)
        } else {
            0.0
        },
        shrink_pos: ratio_shrink(rms(&cal_eval.hold_pos), rms(&e.hold_pos)),
        shrink_force: match (&cal_eval.hold_force, &e.hold_force) {
            (Some(b), Some(a)) => Some(ratio_shrink(rms(b), rms(a))),
            _ => None,
        },
        predictable,
        score: f.judgement.net(),
        significant: named.is_some_and(|(_, kept)| kept),
        judgement: Some(judgement.clone()),
        note,
        evidence: f.evidence.text.clone(),
        evidence_pass: f.evidence.pass,
        evidence_figures: f.evidence.figures.clone(),
    }
}

/// A candidate not fitted (its signature clearly absent).
fn skipped_entry(e: super::Effect, ev: &super::fit::Evidence) -> RankEntry {
    RankEntry {
        effect: e.name().to_owned(),
        variant: String::new(),
        params: BTreeMap::new(),
        params_std: BTreeMap::new(),
        fit_rms_before: 0.0,
        fit_rms_after: 0.0,
        holdout_rms_before: 0.0,
        holdout_rms_after: 0.0,
        shrink: 0.0,
        shrink_pos: 0.0,
        shrink_force: None,
        predictable: true,
        score: f64::NEG_INFINITY,
        significant: false,
        judgement: None,
        note: "not fitted: its signature is clearly absent".into(),
        evidence: ev.text.clone(),
        evidence_pass: false,
        evidence_figures: ev.figures.clone(),
    }
}

/// The ranking: the named effects first (as named), then the others by their first-round
/// net gain, then those not fitted.
fn ranking(scale: &Scale, cal_eval: &Eval, out: &Outcome) -> Vec<RankEntry> {
    let mut entries: Vec<RankEntry> = out
        .named
        .iter()
        .map(|n| rank_entry(scale, cal_eval, &n.fitted, Some((n, true))))
        .collect();
    let listed = |e: super::Effect| out.named.iter().any(|n| n.fitted.effect == e);
    let mut rest: Vec<(f64, RankEntry)> = out
        .ranking
        .iter()
        .filter(|r| !listed(r.effect()))
        .map(|r| match r {
            Ranked::Fitted(f) => {
                let dropped = out.dropped.iter().find(|d| d.fitted.effect == f.effect);
                let entry = match dropped {
                    Some(d) => rank_entry(scale, cal_eval, &d.fitted, Some((d, false))),
                    None => rank_entry(scale, cal_eval, f, None),
                };
                (f.judgement.net(), entry)
            }
            Ranked::Skipped(e, ev) => (f64::NEG_INFINITY, skipped_entry(*e, ev)),
        })
        .collect();
    rest.sort_by(|a, b| b.0.total_cmp(&a.0));
    entries.extend(rest.into_iter().map(|(_, e)| e));
    entries
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
            let (ra, pa, sa) = a.map_or((0.0, 0.0, 0.0), |a| (a.rms, a.peak, a.share));
            RegimeChange {
                name: b.name.clone(),
                rms_before: b.rms,
                rms_after: ra,
                peak_before: b.peak,
                peak_after: pa,
                share_after: sa,
            }
        })
        .collect()
}

/// A regime holds "most" of what is left when it has more than half of its energy.
const MOST: f64 = 0.5;

/// The regime holding most of the residual left after the named effects, if one does.
fn remaining_regime(per: &[RegimeChange]) -> Option<(String, f64)> {
    per.iter()
        .filter(|r| r.share_after > MOST)
        .max_by(|a, b| a.share_after.total_cmp(&b.share_after))
        .map(|r| (r.name.clone(), r.share_after))
}

/// What the shrink is a shrink of, in words, by the channels the record scores.
fn shrink_of(has_force: bool) -> String {
    if has_force {
        "the held-out position and force residuals together (each weighed by the calibrated model's fitting residual), calibrated model -> with the named effects".into()
    } else {
        "the held-out position residual RMS, calibrated model -> with the named effects".into()
    }
}

/// The verdict line: the one sentence the CLI prints, the GUI shows and the JSON stores, so
/// the three cannot disagree.
pub fn summary_line(r: &Report) -> String {
    let mut s = if r.selected.is_empty() {
        "verdict: none (no unmodelled effect beyond the calibration)".to_owned()
    } else {
        let levels = match (r.force_rms_calibrated, r.force_rms_after) {
            (Some(b), Some(a)) => format!(
                "position RMS {} -> {}, force RMS {} -> {}",
                fmt_um(r.overall.rms_calibrated),
                fmt_um(r.overall.rms_after),
                crate::units::fmt_qty(b, "N"),
                crate::units::fmt_qty(a, "N")
            ),
            _ => format!(
                "position RMS {} -> {}",
                fmt_um(r.overall.rms_calibrated),
                fmt_um(r.overall.rms_after)
            ),
        };
        format!(
            "verdict: {}; held-out shrink {:.1} % ({levels}, calibrated -> with the effects)",
            r.selected.join(" + "),
            r.shrink * 100.0
        )
    };
    if let Some((name, share)) = &r.remaining_regime {
        s += &format!(
            "; most of what is left lies in {} ({:.0} % of its energy)",
            name.replace('_', " "),
            share * 100.0
        );
    }
    s
}

fn fmt_um(v_um: f64) -> String {
    crate::units::fmt_qty(v_um, "um")
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
    let selected: Vec<String> = out
        .named
        .iter()
        .map(|n| n.fitted.effect.name().to_owned())
        .collect();
    let verdict = selected.first().cloned().unwrap_or_else(|| "none".into());
    let (rb, ra) = (rms(&before), rms(&after));
    let rc = m_to_um(rms(&p.cal_eval.hold_pos));
    let per = per_regime(&before, &after, &labels);
    let has_force = p.cal_eval.hold_force.is_some();
    let mut fitted = preset.clone();
    if let Some(a) = fitted.axes.iter_mut().find(|a| a.name == main.axis) {
        *a = out.final_cand.model.axis.clone();
    }
    let final_values: Vec<_> = p
        .cal
        .ratios
        .iter()
        .map(|(c, _)| *c)
        .zip(out.final_values.iter().copied())
        .collect();
    let mut rep = Report {
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
        calibration_final: final_values,
        calibration: p.cal.clone(),
        scale: *p.scale,
        floor_holdout: out.floors.0,
        floor_fit: out.floors.1,
        replays: 0,
        units: "position residuals in um (measured - simulated); force residuals in N".into(),
        verdict,
        shrink: if selected.is_empty() {
            0.0
        } else {
            shrink(p.scale, &p.cal_eval, &out.final_eval)
        },
        selected,
        ranking: ranking(p.scale, &p.cal_eval, out),
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
        force_rms_calibrated: p.cal_eval.hold_force.as_deref().map(rms),
        overall: Figures {
            rms_before: rb,
            rms_calibrated: rc,
            rms_after: ra,
            peak_before: peak(&before),
            peak_after: peak(&after),
        },
        shrink_of: shrink_of(has_force),
        remaining_regime: remaining_regime(&per),
        summary: String::new(),
        per_regime: per,
        fitted: Some(fitted),
        series: Some(Series {
            t_s: t,
            pos_mm,
            before_um: before,
            after_um: after,
            regimes: labels,
        }),
    };
    rep.summary = summary_line(&rep);
    rep
}
