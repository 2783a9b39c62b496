//! Signatures of the friction-type effects in the force residual: a term that follows the
//! direction of motion (Coulomb), the speed (viscous), low speeds only (Stribeck), short
//! reversing strokes (stroke friction) or nothing at all (a constant force). Each is one
//! column of a least-squares regression of the residual on the measured motion; the
//! others are fitted alongside so that one does not pass for another. The residual is
//! correlated over many samples, which the standard errors account for.

use std::collections::BTreeMap;

use super::{Applied, Context, Evidence, Fitted, MIN_T};
use crate::diagnose::DiagnoseError;
use crate::diagnose::calibrate::{CalParam, MAX_RATIO_CHANGE};
use crate::diagnose::effects::{Effect, ParamDef};
use crate::diagnose::engine::Cand;
use crate::diagnose::engine::corr_length;
use crate::diagnose::evidence::{self, Regression};
use crate::diagnose::lm::Param;
use crate::preset::FilmLaw;
use crate::units::{mm_per_s_to_m_per_s, mm_to_m};

/// Below this measured speed the axis counts as standing (friction there is static, not a
/// function of speed), m/s.
const MOVING_MPS: f64 = 5e-4;

/// Direction of motion: ±1 while moving, 0 at rest.
fn dir(v: f64) -> f64 {
    if v > MOVING_MPS {
        1.0
    } else if v < -MOVING_MPS {
        -1.0
    } else {
        0.0
    }
}

/// The columns every friction regression carries: direction, speed, acceleration (a mass
/// left over after calibration) and a constant.
fn base_columns(ctx: &Context) -> Vec<Vec<f64>> {
    let s = ctx.sig;
    vec![
        s.vel_mps.iter().map(|&v| dir(v)).collect(),
        s.vel_mps.clone(),
        s.acc_mps2.clone(),
        vec![1.0; s.vel_mps.len()],
    ]
}

/// Regresses the force residual on `cols`. The residual the terms leave is what the
/// standard errors describe, so its correlation length is measured after a first pass (the
/// base residual's own is mostly the effect under test, and far longer).
///
/// Only samples in motion enter: at rest the slide holds whatever force stiction allows,
/// which says nothing about friction as a function of speed and swamps every term.
fn regress(ctx: &Context, cols: &[Vec<f64>]) -> Option<Regression> {
    let y_all = ctx.sig.r_force.as_ref()?;
    let moving: Vec<usize> = (0..y_all.len())
        .filter(|&k| ctx.sig.vel_mps[k].abs() >= MOVING_MPS)
        .collect();
    let pick = |v: &[f64]| -> Vec<f64> { moving.iter().map(|&k| v[k]).collect() };
    let y = pick(y_all);
    let cols: Vec<Vec<f64>> = cols.iter().map(|c| pick(c)).collect();
    let c: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    let first = evidence::regress(&c, &y, 1.0)?;
    let left = evidence::minus_fit(&y, &c, &first.coef);
    evidence::regress(&c, &y, corr_length(&left))
}

/// `t` of coefficient `i`.
fn t_of(r: &Regression, i: usize) -> f64 {
    if r.stderr[i] > 0.0 {
        r.coef[i] / r.stderr[i]
    } else {
        0.0
    }
}

/// How the lubricant film wears over short strokes, for the signature's regressor.
#[derive(Clone, Copy)]
enum Wear {
    /// By the number of short strokes (e-folding over three).
    Count,
    /// By the distance travelled in short strokes (e-folding over this many metres).
    Distance(f64),
}

/// The short-stroke level at every sample for a pitch `pitch_m`: each stroke between two
/// reversals shorter than the pitch wears the film (by one stroke, or by its length), a
/// longer one resets it.
fn stroke_level(vel: &[f64], pos: &[f64], pitch_m: f64, wear: Wear) -> Vec<f64> {
    let mut out = Vec::with_capacity(vel.len());
    let (mut level, mut last_dir, mut rev_pos) = (0.0, 0.0, pos.first().copied().unwrap_or(0.0));
    let (per_stroke, scale) = match wear {
        Wear::Count => (None, 3.0),
        Wear::Distance(l) => (Some(()), l),
    };
    for (&v, &x) in vel.iter().zip(pos) {
        let d = dir(v);
        if d != 0.0 && d != last_dir {
            if last_dir != 0.0 {
                let stroke = (x - rev_pos).abs();
                level = if stroke < pitch_m {
                    level + per_stroke.map_or(1.0, |()| stroke)
                } else {
                    0.0
                };
            }
            rev_pos = x;
            last_dir = d;
        }
        out.push(d * (1.0 - (-level / scale).exp()));
    }
    out
}

/// The signature of a friction-type effect.
pub fn evidence(ctx: &Context, effect: Effect) -> Evidence {
    if ctx.sig.r_force.is_none() {
        return Evidence {
            pass: true,
            text: "no force recorded: judged by the held-out shrink alone".into(),
            ..Evidence::default()
        };
    }
    match effect {
        Effect::StribeckFriction => stribeck(ctx),
        Effect::StrokeFriction => stroke(ctx),
        _ => linear(ctx, effect),
    }
}

/// Coulomb, viscous and constant force: one regression, one column each.
fn linear(ctx: &Context, effect: Effect) -> Evidence {
    let Some(r) = regress(ctx, &base_columns(ctx)) else {
        return Evidence::absent("the force residual could not be regressed");
    };
    let (col, name, unit) = match effect {
        Effect::CoulombFriction => (0, "direction-of-motion term", "n"),
        Effect::ViscousFriction => (1, "speed term", "n_s_per_m"),
        _ => (3, "constant term", "n"),
    };
    let t = t_of(&r, col);
    let c = r.coef[col];
    let mut pass = t.abs() >= MIN_T;
    let mut why = String::new();
    match effect {
        // More friction than the model resists motion: the motor pushes harder along it.
        Effect::CoulombFriction if c <= 0.0 => {
            pass = false;
            why = " (negative: less friction than the model, a calibration matter)".into();
        }
        Effect::CoulombFriction => {
            // The nominal has a Coulomb level and the residual only asks for a few per cent
            // more of it: the nominal is off, as nominals are, not missing an effect.
            let coulomb = |a: &crate::preset::AxisParams| {
                if a.friction.enabled {
                    a.friction.coulomb_n
                } else {
                    0.0
                }
            };
            let nominal_n = coulomb(&ctx.nominal.model.axis);
            let total_n = coulomb(&ctx.base.model.axis) + c;
            let change = total_n / nominal_n - 1.0;
            if nominal_n > 0.0 && change.abs() <= MAX_RATIO_CHANGE {
                pass = false;
                why = format!(
                    " (the nominal's {nominal_n:.1} N re-fitted to {total_n:.1} N, {:+.1} %: a calibration matter)",
                    100.0 * change
                );
            }
        }
        Effect::ViscousFriction => {
            if let Some(w) = viscous_calibration_matter(ctx, c) {
                pass = false;
                why = w;
            }
        }
        _ => {}
    }
    let hint = match effect {
        // The residual is the motor's extra force; a force on the table is opposed by it.
        Effect::ConstantForce => vec![-c],
        _ => vec![c],
    };
    let split = (effect == Effect::ViscousFriction)
        .then(|| viscous_split(ctx))
        .flatten();
    if let Some((_, t_split)) = split
        && t_split.abs() >= MIN_T
    {
        // No calibration ratio moves one direction's coefficient alone.
        pass = true;
    }
    let split_text = split.map_or_else(String::new, |(s, t_s)| {
        format!(
            "; a speed term that keeps its sign both ways (a coefficient that differs by direction) {s:.3} n·s·per·m ({t_s:.1} standard errors)"
        )
    });
    let mut ev = Evidence {
        pass,
        text: format!(
            "{name} of the force residual {c:.3} {unit} ({t:.1} standard errors){why}{split_text}",
            unit = unit.replace('_', "·")
        ),
        hint,
        ..Evidence::default()
    }
    .with(&format!("coefficient_{unit}"), c)
    .with("t", t)
    .with("explained_share", r.explained);
    if let Some((s, t_s)) = split {
        ev = ev.with("split_n_s_per_m", s).with("split_t", t_s);
    }
    if effect == Effect::ViscousFriction
        && let Some(p) = viscous_power(ctx)
    {
        ev.text += &format!(
            "; a speed term that grows as |v|^{:.2} beside the linear one, {:.3} n at 100 mm/s ({:.1} standard errors)",
            p.exponent, p.force_at_100_n, p.t
        );
        ev = ev
            .with("power_exponent", p.exponent)
            .with("power_n_at_100mm_per_s", p.force_at_100_n)
            .with("power_t", p.t);
    }
    ev
}

/// Why a speed term `c` of the force residual is the calibration's business rather than a
/// viscous friction the nominal lacks, if it is: the calibration may leave a speed term it
/// could have taken (it weighs the position too), and one larger than its whole range is
/// more than a correction. Where the calibration's ratio ended on its bound, it may have
/// gone there to mimic another effect (a Coulomb level that builds up over a speed, which
/// the calibration's exact-law nuisance cannot follow, looks like more viscous friction);
/// once that effect is in the base, a term that brings the total back within the
/// calibration's range of the nominal's is the calibration undoing itself, not an effect
/// (4747 and 6262 case_013: +8 %, then −12 %).
fn viscous_calibration_matter(ctx: &Context, c: f64) -> Option<String> {
    let cal_at_bound = ctx.at_bound(CalParam::Viscous);
    let calibrated = ctx.base.model.axis.friction.viscous_n_s_per_m;
    let beyond_range = c.abs() > MAX_RATIO_CHANGE * calibrated;
    let nominal_c = ctx.nominal.model.axis.friction.viscous_n_s_per_m;
    let total_change = (calibrated + c) / nominal_c - 1.0;
    if calibrated > 0.0 && !cal_at_bound && !beyond_range {
        Some(" (within what the calibration of the nominal's viscous friction covers)".into())
    } else if nominal_c > 0.0 && cal_at_bound && total_change.abs() <= MAX_RATIO_CHANGE {
        Some(format!(
            " (the nominal's {nominal_c:.1} N·s/m re-fitted to {:.1} N·s/m, {:+.1} %: a calibration matter)",
            calibrated + c,
            100.0 * total_change
        ))
    } else {
        None
    }
}

/// Powers of the speed [`viscous_power`] tries: the grease and seal laws of the friction
/// literature lie between the square root and about 0.8.
const POWER_EXPONENTS: [f64; 3] = [0.4, 0.55, 0.7];

/// A speed term that grows as a power of the speed, regressed beside the base columns.
struct PowerTerm {
    exponent: f64,
    /// Its coefficient as a force at 100 mm/s, N.
    force_at_100_n: f64,
    t: f64,
}

/// The speed term c·sign(v)·(|v| / 100 mm/s)^δ, regressed beside the base columns for each
/// δ of [`POWER_EXPONENTS`], the one that stands clearest kept. A friction that grows less
/// than linearly with the speed leaves a residual that the linear speed term and the
/// direction term take only between them, bent: the power's column takes the bend. None
/// without a force residual.
fn viscous_power(ctx: &Context) -> Option<PowerTerm> {
    let v_ref = mm_per_s_to_m_per_s(100.0);
    let mut best: Option<PowerTerm> = None;
    for delta in POWER_EXPONENTS {
        let mut cols = base_columns(ctx);
        cols.push(
            ctx.sig
                .vel_mps
                .iter()
                .map(|&v| dir(v) * (v.abs() / v_ref).powf(delta))
                .collect(),
        );
        let Some(r) = regress(ctx, &cols) else {
            continue;
        };
        let t = t_of(&r, 4);
        if best.as_ref().is_none_or(|b| t.abs() > b.t.abs()) {
            best = Some(PowerTerm {
                exponent: delta,
                force_at_100_n: r.coef[4],
                t,
            });
        }
    }
    best
}

/// The speed term that keeps its sign both ways, |v|, regressed beside the base columns:
/// a viscous coefficient that is larger moving + than moving − leaves c·v + split·|v| in
/// the force residual, which neither a symmetric coefficient (v) nor a force (the constant
/// column) takes. Its coefficient (the split, N·s/m) and its `t`.
fn viscous_split(ctx: &Context) -> Option<(f64, f64)> {
    let mut cols = base_columns(ctx);
    cols.push(ctx.sig.vel_mps.iter().map(|v| v.abs()).collect());
    let r = regress(ctx, &cols)?;
    Some((r.coef[4], t_of(&r, 4)))
}

/// Stribeck: an extra force at low speed, falling off with a characteristic velocity,
/// searched over a few velocities.
fn stribeck(ctx: &Context) -> Evidence {
    let base = base_columns(ctx);
    let mut best: Option<(f64, f64, f64)> = None;
    for vs_mm_s in [0.5, 1.0, 2.0, 4.0, 8.0, 16.0] {
        let vs = mm_per_s_to_m_per_s(vs_mm_s);
        let g: Vec<f64> = ctx
            .sig
            .vel_mps
            .iter()
            .map(|&v| dir(v) * (-(v / vs).powi(2)).exp())
            .collect();
        let mut cols = base.clone();
        cols.push(g);
        if let Some(r) = regress(ctx, &cols) {
            let t = t_of(&r, 4);
            if best.is_none_or(|b| t > b.1) {
                best = Some((vs_mm_s, t, r.coef[4]));
            }
        }
    }
    let Some((vs, t, c)) = best else {
        return Evidence::absent("the force residual could not be regressed");
    };
    Evidence {
        pass: t >= MIN_T && c > 0.0,
        text: format!(
            "low-speed excess of the force residual {c:.2} N at a Stribeck velocity of {vs} mm/s ({t:.1} standard errors)"
        ),
        hint: vec![c.max(0.0), vs],
        ..Evidence::default()
    }
    .with("excess_n", c)
    .with("velocity_mm_per_s", vs)
    .with("t", t)
}

/// Stroke friction: friction that grows over successive short strokes, searched over a few
/// pitches.
fn stroke(ctx: &Context) -> Evidence {
    let base = base_columns(ctx);
    let mut best: Option<(f64, f64, f64)> = None;
    // The film worn by the number of short strokes, or by the distance run in them (over
    // 2, 5 or 12 mm): two readings of the same physics, the regression picks.
    let wears = [
        Wear::Count,
        Wear::Distance(mm_to_m(2.0)),
        Wear::Distance(mm_to_m(5.0)),
        Wear::Distance(mm_to_m(12.0)),
    ];
    let grid = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0]
        .into_iter()
        .flat_map(|p| wears.iter().map(move |w| (p, *w)));
    for (pitch_mm, wear) in grid {
        let lvl = stroke_level(&ctx.sig.vel_mps, &ctx.sig.pos_m, mm_to_m(pitch_mm), wear);
        if lvl.iter().all(|x| *x == 0.0) {
            continue;
        }
        let mut cols = base.clone();
        cols.push(lvl);
        if let Some(r) = regress(ctx, &cols) {
            let t = t_of(&r, 4);
            if best.is_none_or(|b| t > b.1) {
                best = Some((pitch_mm, t, r.coef[4]));
            }
        }
    }
    let Some((pitch, t, c)) = best else {
        return Evidence::absent("no short reversing strokes in the fitting data");
    };
    Evidence {
        pass: t >= MIN_T && c > 0.0,
        text: format!(
            "friction rising by {c:.2} N over strokes shorter than {pitch} mm ({t:.1} standard errors)"
        ),
        hint: vec![c.max(0.0), pitch],
        ..Evidence::default()
    }
    .with("rise_n", c)
    .with("pitch_mm", pitch)
    .with("t", t)
}

/// Share of the force residual's power above [`HUNT_F_LO_HZ`] that one tone must hold for
/// the drive to count as hunting (white noise: a few per cent; measured limit cycles
/// 0.95–1.0, quantization jitter 0.1–0.3).
const HUNT_SHARE: f64 = 0.8;

/// The tone's rms must be at least this share of the measured force's spread: a hunting
/// drive's is tens of per cent; a faint line in a quiet record is not play.
const HUNT_REL_RMS: f64 = 0.05;

/// The motor-alone loop must be this lightly damped (largest |z|) for play to keep it
/// ringing between impacts.
const HUNT_MIN_RADIUS: f64 = 0.9;

/// Lowest frequency of the hunting band, Hz (below: the motion's own content).
const HUNT_F_LO_HZ: f64 = 50.0;

/// Backlash in a loop that hunts: the motor, alone while it crosses the play, is a lightly
/// damped loop, and every impact on a flank kicks it again, so the force carries one steady
/// tone that no model without play has. A limit cycle cannot be replayed sample by sample
/// (its phase wanders), so this signature, like quantization's grid, is proof on its own.
/// None when the record has no force or the drive does not hunt.
fn hunting_evidence(ctx: &Context) -> Option<Evidence> {
    let y = ctx.sig.r_force.as_deref()?;
    let dt = ctx.eng.split.main.t3_s;
    let t = evidence::tone(y, dt, HUNT_F_LO_HZ, 0.5 / dt)?;
    let f = ctx.eng.split.main.force_n.as_deref()?;
    let m = f.iter().sum::<f64>() / f.len().max(1) as f64;
    let spread = (f.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / f.len().max(1) as f64).sqrt();
    let model = &ctx.base.model;
    let (radius, mode_hz) = crate::drive::motor_alone_mode(&model.axis, model.t3_s).ok()?;
    let pass = t.share >= HUNT_SHARE && t.rms >= HUNT_REL_RMS * spread && radius >= HUNT_MIN_RADIUS;
    pass.then(|| {
        Evidence {
            pass: true,
            text: format!(
                "the drive hunts: a steady {:.0} Hz tone of {:.1} N rms holds {:.0} % of the force residual above {HUNT_F_LO_HZ:.0} Hz; the loop on the motor alone, as it runs inside the play, has its least damped pole at |z| = {radius:.3} ({mode_hz:.0} Hz), so each impact on a flank keeps it ringing",
                t.freq_hz,
                t.rms,
                100.0 * t.share
            ),
            ..Evidence::default()
        }
        .with("hunting_hz", t.freq_hz)
        .with("hunting_rms_n", t.rms)
        .with("hunting_share", t.share)
        .with("motor_alone_pole_radius", radius)
        .with("motor_alone_pole_hz", mode_hz)
    })
}

/// Backlash: the residual gathers at the reversals, where the drive crosses its play, or
/// the drive hunts across it (see `hunting_evidence`).
pub fn reversal_evidence(ctx: &Context, effect: Effect) -> Evidence {
    if effect == Effect::Backlash
        && let Some(e) = hunting_evidence(ctx)
    {
        return e;
    }
    let s = ctx.sig;
    let y: &[f64] = match &s.r_force {
        Some(f) => f,
        None => &s.r_pos,
    };
    let n = y.len();
    let half = ((0.03 / ctx.eng.split.main.t3_s).round() as usize).max(1);
    let mut near = vec![false; n];
    let mut reversals = 0usize;
    let mut last = 0.0;
    for (k, &v) in s.cmd_vel_mps.iter().enumerate() {
        let d = dir(v);
        if d != 0.0 && last != 0.0 && d != last {
            reversals += 1;
            for m in near
                .iter_mut()
                .take((k + half).min(n))
                .skip(k.saturating_sub(half))
            {
                *m = true;
            }
        }
        if d != 0.0 {
            last = d;
        }
    }
    if reversals < 3 {
        return Evidence::absent("fewer than 3 reversals in the fitting data");
    }
    let mean = y.iter().sum::<f64>() / n.max(1) as f64;
    let (mut e_near, mut e_all) = (0.0, 0.0);
    for (v, &m) in y.iter().zip(&near) {
        let e = (v - mean) * (v - mean);
        e_all += e;
        if m {
            e_near += e;
        }
    }
    let time_share = near.iter().filter(|m| **m).count() as f64 / n.max(1) as f64;
    let energy_share = if e_all > 0.0 { e_near / e_all } else { 0.0 };
    let ratio = energy_share / time_share.max(1e-9);
    let what = if effect == Effect::Backlash {
        "play"
    } else {
        "play with one flank favoured"
    };
    Evidence {
        pass: ratio >= 2.0,
        text: format!(
            "{:.0} % of the residual energy lies within ±30 ms of the {reversals} reversals, which take {:.0} % of the time ({ratio:.1}×), as {what} makes it",
            100.0 * energy_share,
            100.0 * time_share
        ),
        ..Evidence::default()
    }
    .with("energy_share_at_reversals", energy_share)
    .with("time_share_at_reversals", time_share)
    .with("concentration", ratio)
}

/// Report keys of the stroke friction whose film wears by distance ([`fit_film`]).
const FILM_KEYS: [&str; 3] = ["rise_n", "pitch_mm", "recovery_mm"];

/// The parameters of [`fit_film`] as the later rounds and the joint re-fit bound them.
pub const FILM_DEFS: [ParamDef; 3] = [
    ParamDef {
        key: FILM_KEYS[0],
        lo: 0.0,
        hi: 5000.0,
        init: 20.0,
    },
    ParamDef {
        key: FILM_KEYS[1],
        lo: 0.5,
        hi: 200.0,
        init: 10.0,
    },
    ParamDef {
        key: FILM_KEYS[2],
        lo: 1.0,
        hi: 1000.0,
        init: 20.0,
    },
];

/// Gives `c` a stroke friction whose film wears by the distance run near the turning
/// points (`th`: rise N, pitch mm, recovery mm; the film breaks down over one pitch).
pub fn set_film(c: &mut Cand, th: &[f64]) {
    let f = &mut c.model.axis.friction;
    f.enabled = true;
    let s = &mut f.stroke;
    s.enabled = true;
    s.law = FilmLaw::Distance;
    s.rise_ratio = 0.0;
    s.rise_n = th[0];
    s.pitch_mm = th[1];
    s.breakdown_mm = th[1];
    s.recovery_mm = th[2];
}

/// The stroke friction with the distance law ([`FilmLaw::Distance`]): every stroke starts
/// with a rise that decays once the axis has run past the pitch, where the count law rises
/// only over a run of short strokes. Fitted on the base (the calibration ratios stay), so
/// the caller keeps it only when it leaves less of the fitting part than the count law.
pub fn fit_film(ctx: &Context, ev: &Evidence) -> Result<Option<Fitted>, DiagnoseError> {
    let params = FILM_DEFS.map(|d| Param {
        lo: d.lo,
        hi: d.hi,
        scale: d.init,
    });
    let build = |th: &[f64]| {
        let mut c = ctx.base.clone();
        set_film(&mut c, th);
        c
    };
    let rows = |th: &[f64]| Ok(Some(ctx.eng.lm_rows(&ctx.eng.sim_fit(&build(th))?)));
    let rise0 = ev
        .hint
        .first()
        .copied()
        .filter(|x| *x > 0.0)
        .unwrap_or(20.0);
    let starts = [vec![rise0, 5.0, 20.0], vec![rise0, 12.0, 30.0]];
    let Some((f, std)) = ctx.best_lm(starts, &params, &rows)? else {
        return Ok(None);
    };
    let cand = build(&f.theta);
    let eval = ctx.eng.evaluate(&cand)?;
    Ok(Some(Fitted {
        effect: Effect::StrokeFriction,
        keys: FILM_KEYS.iter().map(|k| (*k).to_owned()).collect(),
        applied: Applied::Film(f.theta.clone()),
        theta: f.theta,
        std,
        cand,
        eval,
        n_params: FILM_KEYS.len(),
        extra: BTreeMap::new(),
        note: "a film worn by the distance run near the turning points (it explained more of the fitting part than the count of short strokes)".into(),
        evidence: ev.clone(),
        // Fitted again beside the later candidates, as the count law is: a Coulomb
        // friction beside it can take back the level its long recovery held (see
        // `Context::nested_coulomb`).
        refit: true,
        sel_theta: vec![],
        ratios: ctx.ratios.to_vec(),
        without: None,
    }))
}

/// The parameters of the viscous friction that differs by direction ([`fit_split`]): the
/// correction of the mean coefficient (as [`Effect::params`] has it) and the split.
const SPLIT_DEFS: [ParamDef; 2] = [
    ParamDef {
        key: "viscous_n_s_per_m",
        lo: -1.0e5,
        hi: 1.0e5,
        init: 100.0,
    },
    ParamDef {
        key: "split_n_s_per_m",
        lo: -1.0e5,
        hi: 1.0e5,
        init: 100.0,
    },
];

/// Gives `c` a viscous friction corrected by `th[0]` (N·s/m, as [`Effect::apply`] does) and
/// split by direction by `th[1]` more (N·s/m: + drags by that much more than the mean,
/// − by that much less). Each direction's coefficient stays ≥ 0.
pub fn set_split(c: &mut Cand, th: &[f64]) {
    let f = &mut c.model.axis.friction;
    f.enabled = true;
    f.viscous_n_s_per_m = (f.viscous_n_s_per_m + th[0]).max(0.0);
    let max = f.viscous_n_s_per_m;
    f.viscous_split_n_s_per_m = (f.viscous_split_n_s_per_m + th[1]).clamp(-max, max);
}

/// A viscous friction that differs by direction: the mean coefficient corrected and the
/// split between the directions, from the evidence's |v| term, fitted as one coefficient
/// is (the calibration ratios and the earlier effects move with it). The caller keeps it
/// only when it leaves clearly less of the fitting part than one coefficient. None without
/// a |v| term.
pub fn fit_split(ctx: &Context, ev: &Evidence) -> Result<Option<Fitted>, DiagnoseError> {
    let Some(split0) = ev
        .figures
        .get("split_n_s_per_m")
        .copied()
        .filter(|_| ev.figures.get("split_t").is_some_and(|t| t.abs() >= MIN_T))
    else {
        return Ok(None);
    };
    let c0 = ev.hint.first().copied().unwrap_or(0.0);
    let first = vec![vec![c0, split0], vec![0.0, split0]];
    ctx.fit_variant(
        Effect::ViscousFriction,
        &SPLIT_DEFS,
        first,
        ev,
        &|th| Applied::Split(th.to_vec()),
        &|_| "a coefficient that differs by direction (it explained more of the fitting part than one coefficient)".into(),
    )
}

/// The smallest exponent [`fit_power`] may reach. Toward 0 the power law flattens into a
/// level that does not depend on the speed, a Coulomb friction under another name: on 5353
/// case_072 (a power law of 0.49 beside a Coulomb friction) a fit down to 0.1 took both as
/// one power of 0.1, and one bounded at 0.3 ended on the bound (as on 5151 case_066, a
/// power of 0.75 beside a Coulomb friction), with the Coulomb friction's level in it. A fit
/// that ends there is dropped: the Coulomb friction is fitted first, and the power beside
/// it in the next round.
const POWER_EXPONENT_MIN: f64 = 0.3;

/// The parameters of [`fit_power`].
pub const POWER_DEFS: [ParamDef; 2] = [
    ParamDef {
        key: "force_at_100mm_per_s_n",
        lo: 0.0,
        hi: 1.0e4,
        init: 20.0,
    },
    ParamDef {
        key: "exponent",
        lo: POWER_EXPONENT_MIN,
        hi: 1.5,
        init: 0.5,
    },
];

/// Gives `c` a power-law speed term of `th[0]` N at 100 mm/s and exponent `th[1]` (see
/// [`crate::preset::ViscousPower`]), beside its linear viscous term.
pub fn set_power(c: &mut Cand, th: &[f64]) {
    let f = &mut c.model.axis.friction;
    f.enabled = true;
    let v = &mut f.viscous_power;
    v.enabled = true;
    v.force_at_100mm_per_s_n = th[0].max(0.0);
    v.exponent = th[1];
}

/// A viscous friction that grows as a power of the speed: the force at 100 mm/s and the
/// exponent, from the evidence's power term, fitted as one coefficient is (the calibration
/// ratios, the nominal's linear term among them, and the earlier effects move with it). The
/// caller keeps it only when it leaves clearly less of the fitting part than the linear
/// shapes. None when the power term does not stand clear, or takes away friction.
pub fn fit_power(ctx: &Context, ev: &Evidence) -> Result<Option<Fitted>, DiagnoseError> {
    let fig = |k: &str| ev.figures.get(k).copied();
    let (Some(f100), Some(delta)) = (
        fig("power_n_at_100mm_per_s").filter(|f| *f > 0.0),
        fig("power_exponent"),
    ) else {
        return Ok(None);
    };
    if fig("power_t").is_none_or(|t| t < MIN_T) {
        return Ok(None);
    }
    let first = vec![vec![f100, delta], vec![f100, 0.7]];
    ctx.fit_variant(
        Effect::ViscousFriction,
        &POWER_DEFS,
        first,
        ev,
        &|th| Applied::Power(th.to_vec()),
        &|th| {
            format!(
                "a speed term growing as |v|^{:.2}, {:.1} N at 100 mm/s (it explained more of the fitting part than a linear coefficient)",
                th[1], th[0]
            )
        },
    )
    .map(|f| {
        // A power that ends at its floor is a level, not a speed law (see
        // [`POWER_EXPONENT_MIN`]). Otherwise, unlike the other variants, its parameters move
        // again beside every later effect and in the final joint fit.
        f.filter(|f| f.theta.get(1).is_some_and(|d| *d > POWER_EXPONENT_MIN + POWER_AT_FLOOR))
            .map(|mut f| {
                f.refit = true;
                f
            })
    })
}

/// How close to [`POWER_EXPONENT_MIN`] a fitted power counts as having ended on it.
const POWER_AT_FLOOR: f64 = 0.02;

/// Gives `c` a Stribeck friction of `th` (excess N, velocity mm/s, as [`Effect::apply`]
/// does) whose excess falls off as e^(−|v|/v_s).
pub fn set_stribeck_exponential(c: &mut Cand, th: &[f64]) {
    Effect::StribeckFriction.apply(th, &mut c.model);
    c.model.axis.friction.stribeck.shape = crate::preset::StribeckShape::Exponential;
}

/// A Stribeck friction whose excess falls off exponentially with the speed rather than as a
/// Gaussian (the two shapes of the generalised Stribeck curve the literature fits), from the
/// same starts as the Gaussian and one at half its velocity, fitted as the Gaussian is.
/// Tried only when the low-speed excess stands clear (the signature): the caller keeps it
/// when it leaves clearly less of the fitting part. Its parameters move again beside later
/// effects, as the Gaussian's do.
pub fn fit_stribeck_exponential(
    ctx: &Context,
    ev: &Evidence,
) -> Result<Option<Fitted>, DiagnoseError> {
    if !ev.pass {
        return Ok(None);
    }
    let mut first = super::starts(Effect::StribeckFriction, &ev.hint);
    if let Some(h) = first.first().cloned() {
        first.push(vec![h[0], (0.5 * h[1]).max(0.05)]);
    }
    ctx.fit_variant(
        Effect::StribeckFriction,
        Effect::StribeckFriction.params(),
        first,
        ev,
        &|th| Applied::StribeckExp(th.to_vec()),
        &|th| {
            format!(
                "an excess that falls off as e^(-|v|/{:.2} mm/s) (it explained more of the fitting part than a Gaussian fall-off)",
                th[1]
            )
        },
    )
    .map(|f| {
        f.map(|mut f| {
            f.refit = true;
            f
        })
    })
}

/// The parameters of [`fit_coulomb_smooth`]: the level and the speed it builds up over.
pub const SMOOTH_DEFS: [ParamDef; 2] = [
    ParamDef {
        key: "force_n",
        lo: 0.0,
        hi: 5000.0,
        init: 10.0,
    },
    ParamDef {
        key: "smoothing_mm_per_s",
        lo: SMOOTHING_MIN_MM_PER_S,
        hi: 5.0,
        init: 0.5,
    },
];

/// The smallest smoothing speed [`fit_coulomb_smooth`] may reach, mm/s. Below it the
/// tanh is a step within the record's speed resolution, the exact law by another name.
const SMOOTHING_MIN_MM_PER_S: f64 = 0.02;

/// Gives `c` a Coulomb friction of `th[0]` N (added to the level, as [`Effect::apply`]
/// does) that builds up as tanh(v / `th[1]` mm/s) (see
/// [`crate::preset::Friction::coulomb_smoothing_mm_per_s`]).
pub fn set_coulomb_smooth(c: &mut Cand, th: &[f64]) {
    Effect::CoulombFriction.apply(&th[..1], &mut c.model);
    c.model.axis.friction.coulomb_smoothing_mm_per_s = th[1];
}

/// A Coulomb friction that builds up over a small speed instead of flipping at the
/// reversal (the smooth friction laws, tanh(v/ε), beside the exact stick/slip one).
/// Where the record crawls through its reversals the two differ most: the smooth level
/// passes through zero and the slide never sticks, so the following error through a
/// reversal and the force there differ. Tried only when the direction-of-motion term
/// stands clear (the signature), from the plain fit's start at two speeds; the caller
/// keeps it when it leaves clearly less of the fitting part. Its parameters move again
/// beside later effects.
pub fn fit_coulomb_smooth(ctx: &Context, ev: &Evidence) -> Result<Option<Fitted>, DiagnoseError> {
    if !ev.pass {
        return Ok(None);
    }
    let fc = ev.hint.first().copied().unwrap_or(10.0).max(0.0);
    let first = vec![vec![fc, 0.3], vec![fc, 1.0]];
    ctx.fit_variant(
        Effect::CoulombFriction,
        &SMOOTH_DEFS,
        first,
        ev,
        &|th| Applied::CoulombSmooth(th.to_vec()),
        &|th| {
            format!(
                "a level that builds up as tanh(v/{:.2} mm/s), no stick (it explained more of the fitting part than the exact stick/slip law)",
                th[1]
            )
        },
    )
    .map(|f| {
        // A smoothing that ends on its floor is the exact law (see
        // [`SMOOTHING_MIN_MM_PER_S`]).
        f.filter(|f| {
            f.theta
                .get(1)
                .is_some_and(|e| *e > SMOOTHING_MIN_MM_PER_S * 1.5)
        })
        .map(|mut f| {
            f.refit = true;
            f
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stroke_level_counts_short_strokes_and_resets_on_a_long_one() {
        // +3 mm, −3 mm, +3 mm, then +30 mm, at 10 mm/s in 1 ms samples.
        let mut pos = vec![0.0];
        let mut vel = vec![0.0];
        for (len_mm, sign) in [(3.0, 1.0), (3.0, -1.0), (3.0, 1.0), (30.0, -1.0)] {
            let steps = (len_mm / 0.01) as usize;
            for _ in 0..steps {
                let x = pos.last().copied().unwrap_or(0.0) + sign * 1e-5;
                pos.push(x);
                vel.push(sign * 0.01);
            }
        }
        let lvl = stroke_level(&vel, &pos, mm_to_m(5.0), Wear::Count);
        let at = |mm: f64| lvl[(mm / 0.01) as usize];
        assert_eq!(at(1.0), 0.0, "first stroke: no reversal yet");
        assert!(at(4.0).abs() > 0.2, "second stroke: level 1");
        assert!(at(7.0).abs() > at(4.0).abs(), "third stroke: level 2");
        assert!(at(7.0) > 0.0 && at(4.0) < 0.0, "signed with the direction");
        assert!(at(14.0).abs() > 0.0, "the long stroke starts at level 3");
        // Worn by distance over 3 mm: two 3 mm strokes behind it, the third stroke runs at
        // 1 − e^(−6/3) (less the one sample each reversal is seen late).
        let lvl = stroke_level(&vel, &pos, mm_to_m(5.0), Wear::Distance(mm_to_m(3.0)));
        let expected = 1.0 - (-2.0f64).exp();
        let got = lvl[700];
        assert!(
            (got - expected).abs() < 0.01,
            "level {got}, expected {expected}"
        );
    }
}
