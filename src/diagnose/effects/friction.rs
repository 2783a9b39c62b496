//! Friction-type effects and a constant force. Their signatures are in the force residual:
//! a term that follows the direction of motion (Coulomb), the speed (viscous), low speeds
//! only (Stribeck), short reversing strokes (stroke friction) or nothing at all (a constant
//! force). Each is one column of a least-squares regression of the residual on the measured
//! motion; the others are fitted alongside so that one does not pass for another. The
//! residual is correlated over many samples, which the standard errors account for.

use super::{Candidate, Effect, ParamDef};
use crate::diagnose::DiagnoseError;
use crate::diagnose::criterion::ABSENT_T;
use crate::diagnose::engine::{Cand, corr_length};
use crate::diagnose::evidence::{self, Regression};
use crate::diagnose::fit::{Context, Evidence, Variant};
use crate::preset::{FilmLaw, StribeckShape};
use crate::units::{mm_per_s_to_m_per_s, mm_to_m};

/// A signature term standing this many standard errors clear of zero is reported as
/// found (the report's flag; it decides nothing).
const FOUND_T: f64 = 6.0;

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

/// Regresses the force residual on `cols`, in motion only (at rest the slide holds whatever
/// force stiction allows, which says nothing about friction as a function of speed). The
/// standard errors use the correlation length of what the terms leave.
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

/// The term `extra` regressed beside the base columns: its coefficient and `t`.
fn beside(ctx: &Context, extra: Vec<f64>) -> Option<(f64, f64)> {
    let mut cols = base_columns(ctx);
    cols.push(extra);
    let r = regress(ctx, &cols)?;
    Some((r.coef[4], t_of(&r, 4)))
}

/// The signature of a term of the force residual at `t` standard
/// errors: absent below [`ABSENT_T`] or with the wrong sign (`sign_ok`).
fn term_evidence(t: f64, sign_ok: bool, text: String) -> Evidence {
    if t.abs() < ABSENT_T || !sign_ok {
        let mut e = Evidence::absent(text);
        e.figures.insert("t".into(), t);
        return e;
    }
    Evidence::found(t.abs() >= FOUND_T, text).with("t", t)
}

/// Why a term `c` of the force residual, added to the base's value `base` of a term the
/// nominal has at `nominal`, is the calibration's: the total stays within the calibration's
/// range of the nominal (re-fitting a term the nominal has is calibration, not an effect).
/// None when the nominal lacks the term or the total leaves that range.
fn within_calibration(nominal: f64, base: f64, c: f64, what: &str, unit: &str) -> Option<String> {
    let change = (base + c) / nominal - 1.0;
    (nominal > 0.0 && change.abs() <= crate::diagnose::calibrate::MAX_RATIO_CHANGE).then(|| {
        format!(
            "the residual asks the nominal's {what} of {nominal:.1} {unit} to be {:.1} {unit} ({:+.1} %): within the calibration's range, a calibration matter",
            base + c,
            100.0 * change
        )
    })
}

/// Without a force column no friction signature can be read: each is fitted and judged by
/// the criterion on the position.
fn no_force() -> Evidence {
    Evidence::found(false, "no force recorded: judged on the position alone")
}

/// Coulomb, viscous and constant force: one regression, one column each.
fn linear_term(ctx: &Context, col: usize) -> Option<(f64, f64)> {
    let r = regress(ctx, &base_columns(ctx))?;
    Some((r.coef[col], t_of(&r, col)))
}

/// Sets a Coulomb level built up as tanh(v/ε) (`th`: force added N, ε mm/s).
fn set_coulomb_smooth(c: &mut Cand, th: &[f64]) {
    Effect::CoulombFriction.apply(&th[..1], &mut c.model);
    c.model.axis.friction.coulomb_smoothing_mm_per_s = th[1];
}

/// The parameters of a Coulomb level that builds up over a speed.
const SMOOTH_DEFS: [ParamDef; 2] = [
    ParamDef {
        key: "force_n",
        lo: 0.0,
        hi: 5000.0,
        init: 10.0,
    },
    ParamDef {
        key: "smoothing_mm_per_s",
        lo: 0.0,
        hi: crate::diagnose::calibrate::MAX_SMOOTHING_MM_PER_S,
        init: 0.5,
    },
];

fn set_params(e: Effect) -> fn(&mut Cand, &[f64]) {
    match e {
        Effect::CoulombFriction => |c, th| Effect::CoulombFriction.apply(th, &mut c.model),
        Effect::ViscousFriction => |c, th| Effect::ViscousFriction.apply(th, &mut c.model),
        Effect::StribeckFriction => |c, th| Effect::StribeckFriction.apply(th, &mut c.model),
        Effect::StrokeFriction => |c, th| Effect::StrokeFriction.apply(th, &mut c.model),
        _ => |c, th| Effect::ConstantForce.apply(th, &mut c.model),
    }
}

/// Direction-dependent sliding friction added to the nominal's.
pub struct Coulomb;

impl Candidate for Coulomb {
    fn effect(&self) -> Effect {
        Effect::CoulombFriction
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        if ctx.sig.r_force.is_none() {
            return no_force().hint(vec![10.0]);
        }
        let Some((c, t)) = linear_term(ctx, 0) else {
            return Evidence::absent("the force residual could not be regressed");
        };
        if let Some(why) = within_calibration(
            ctx.nominal.model.axis.friction.coulomb_n,
            ctx.base.model.axis.friction.coulomb_n,
            c,
            "Coulomb level",
            "N",
        ) {
            return Evidence::absent(why);
        }
        // More friction than the model resists motion: the motor pushes harder along it.
        term_evidence(
            t,
            c > 0.0,
            format!(
                "direction-of-motion term of the force residual {c:.3} N ({t:.1} standard errors)"
            ),
        )
        .with("coefficient_n", c)
        .hint(vec![c.max(0.0)])
    }

    fn variants(&self, ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let fc = ev.hint.first().copied().unwrap_or(10.0).max(0.0);
        let mut v = vec![Variant::params(
            "exact",
            "a level that sticks at rest and flips at the reversal",
            Effect::CoulombFriction.params(),
            set_params(Effect::CoulombFriction),
            vec![vec![fc]],
        )];
        // A nominal with a Coulomb level has its shape calibrated; one without gets it here.
        if ctx.nominal.model.axis.friction.coulomb_n <= 0.0 {
            v.push(Variant::params(
                "smooth",
                "a level that builds up as tanh(v/ε), no stick",
                &SMOOTH_DEFS,
                set_coulomb_smooth,
                vec![vec![fc, 0.3], vec![fc, 1.0]],
            ));
        }
        Ok(v)
    }
}

/// Breakaway friction above the Coulomb level at low speed.
pub struct Stribeck;

/// Sets a Stribeck excess that falls off exponentially.
fn set_stribeck_exponential(c: &mut Cand, th: &[f64]) {
    Effect::StribeckFriction.apply(th, &mut c.model);
    c.model.axis.friction.stribeck.shape = StribeckShape::Exponential;
}

impl Candidate for Stribeck {
    fn effect(&self) -> Effect {
        Effect::StribeckFriction
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        if ctx.sig.r_force.is_none() {
            return no_force().hint(vec![20.0, 2.0]);
        }
        let mut best: Option<(f64, f64, f64)> = None;
        for vs_mm_s in [0.5, 1.0, 2.0, 4.0, 8.0, 16.0] {
            let vs = mm_per_s_to_m_per_s(vs_mm_s);
            let g = ctx
                .sig
                .vel_mps
                .iter()
                .map(|&v| dir(v) * (-(v / vs).powi(2)).exp())
                .collect();
            if let Some((c, t)) = beside(ctx, g)
                && best.is_none_or(|b| t > b.1)
            {
                best = Some((vs_mm_s, t, c));
            }
        }
        let Some((vs, t, c)) = best else {
            return Evidence::absent("the force residual could not be regressed");
        };
        term_evidence(
            t,
            c > 0.0,
            format!("low-speed excess of the force residual {c:.2} N at a Stribeck velocity of {vs} mm/s ({t:.1} standard errors)"),
        )
        .with("excess_n", c)
        .with("velocity_mm_per_s", vs)
        .hint(vec![c.max(0.0), vs])
    }

    fn variants(&self, _ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let h = match ev.hint.as_slice() {
            [a, b] => vec![*a, *b],
            _ => vec![20.0, 2.0],
        };
        let starts = vec![h.clone(), vec![h[0], 0.5], vec![h[0], 8.0]];
        Ok(vec![
            Variant::params(
                "gaussian",
                "an excess that falls off as e^(-(v/v_s)²)",
                Effect::StribeckFriction.params(),
                set_params(Effect::StribeckFriction),
                starts.clone(),
            ),
            Variant::params(
                "exponential",
                "an excess that falls off as e^(-|v|/v_s)",
                Effect::StribeckFriction.params(),
                set_stribeck_exponential,
                starts,
            ),
        ])
    }
}

/// The parameters of a viscous friction that differs by direction.
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

/// A viscous friction corrected by `th[0]` (N·s/m) and split by direction by `th[1]`.
/// Each direction's coefficient stays ≥ 0.
fn set_split(c: &mut Cand, th: &[f64]) {
    let f = &mut c.model.axis.friction;
    f.enabled = true;
    f.viscous_n_s_per_m = (f.viscous_n_s_per_m + th[0]).max(0.0);
    let max = f.viscous_n_s_per_m;
    f.viscous_split_n_s_per_m = (f.viscous_split_n_s_per_m + th[1]).clamp(-max, max);
}

/// The parameters of a speed term that grows as a power of the speed. Toward an exponent
/// of 0 it is a level (a Coulomb friction by another name): the bound keeps the two apart.
const POWER_DEFS: [ParamDef; 2] = [
    ParamDef {
        key: "force_at_100mm_per_s_n",
        lo: 0.0,
        hi: 1.0e4,
        init: 20.0,
    },
    ParamDef {
        key: "exponent",
        lo: 0.3,
        hi: 1.5,
        init: 0.5,
    },
];

/// A power-law speed term of `th[0]` N at 100 mm/s and exponent `th[1]`.
fn set_power(c: &mut Cand, th: &[f64]) {
    let f = &mut c.model.axis.friction;
    f.enabled = true;
    let v = &mut f.viscous_power;
    v.enabled = true;
    v.force_at_100mm_per_s_n = th[0].max(0.0);
    v.exponent = th[1];
}

/// Speed-proportional friction beyond the nominal's.
pub struct Viscous;

impl Candidate for Viscous {
    fn effect(&self) -> Effect {
        Effect::ViscousFriction
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        if ctx.sig.r_force.is_none() {
            return no_force().hint(vec![0.0]);
        }
        let Some((c, t)) = linear_term(ctx, 1) else {
            return Evidence::absent("the force residual could not be regressed");
        };
        let (s, ts) =
            beside(ctx, ctx.sig.vel_mps.iter().map(|v| v.abs()).collect()).unwrap_or((0.0, 0.0));
        let v_ref = mm_per_s_to_m_per_s(100.0);
        let power = [0.4, 0.55, 0.7]
            .into_iter()
            .filter_map(|d| {
                let col = ctx
                    .sig
                    .vel_mps
                    .iter()
                    .map(|&v| dir(v) * (v.abs() / v_ref).powf(d))
                    .collect();
                beside(ctx, col).map(|(c, t)| (d, c, t))
            })
            .max_by(|a, b| a.2.abs().total_cmp(&b.2.abs()));
        let (pd, pc, pt) = power.unwrap_or((0.5, 0.0, 0.0));
        // A linear term the calibration covers is its; the other shapes are no ratio's.
        let f = &ctx.base.model.axis.friction;
        if ts.abs() < ABSENT_T
            && pt.abs() < ABSENT_T
            && let Some(why) = within_calibration(
                ctx.nominal.model.axis.friction.viscous_n_s_per_m,
                f.viscous_n_s_per_m,
                c,
                "viscous coefficient",
                "N·s/m",
            )
        {
            return Evidence::absent(why);
        }
        let t_max = t.abs().max(ts.abs()).max(pt.abs());
        let text = format!(
            "speed term of the force residual {c:.3} N·s/m ({t:.1} standard errors); one that keeps its sign both ways {s:.3} N·s/m ({ts:.1}); one growing as |v|^{pd:.2}, {pc:.3} N at 100 mm/s ({pt:.1})"
        );
        term_evidence(t_max, true, text)
            .with("coefficient_n_s_per_m", c)
            .with("split_n_s_per_m", s)
            .with("split_t", ts)
            .with("power_exponent", pd)
            .with("power_n_at_100mm_per_s", pc)
            .with("power_t", pt)
            .hint(vec![c])
    }

    fn variants(&self, _ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let fig = |k: &str| ev.figures.get(k).copied().unwrap_or(0.0);
        let c0 = ev.hint.first().copied().unwrap_or(0.0);
        let (s0, p0, d0) = (
            fig("split_n_s_per_m"),
            fig("power_n_at_100mm_per_s").max(1.0),
            fig("power_exponent").max(0.3),
        );
        Ok(vec![
            Variant::params(
                "linear",
                "one coefficient both ways",
                Effect::ViscousFriction.params(),
                set_params(Effect::ViscousFriction),
                vec![vec![c0]],
            ),
            Variant::params(
                "split",
                "a coefficient that differs by direction",
                &SPLIT_DEFS,
                set_split,
                vec![vec![c0, s0], vec![0.0, s0]],
            ),
            Variant::params(
                "power",
                "a speed term that grows as a power of the speed",
                &POWER_DEFS,
                set_power,
                vec![vec![p0, d0], vec![p0, 0.7]],
            ),
        ])
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

/// The parameters of a stroke friction whose film wears by distance.
const FILM_DEFS: [ParamDef; 3] = [
    ParamDef {
        key: "rise_n",
        lo: 0.0,
        hi: 5000.0,
        init: 20.0,
    },
    ParamDef {
        key: "pitch_mm",
        lo: 0.5,
        hi: 200.0,
        init: 10.0,
    },
    ParamDef {
        key: "recovery_mm",
        lo: 1.0,
        hi: 1000.0,
        init: 20.0,
    },
];

/// A stroke friction whose film wears by the distance run near the turning points (`th`:
/// rise N, pitch mm, recovery mm; the film breaks down over one pitch).
fn set_film(c: &mut Cand, th: &[f64]) {
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

/// Friction that rises over repeated short reversing strokes.
pub struct Stroke;

impl Candidate for Stroke {
    fn effect(&self) -> Effect {
        Effect::StrokeFriction
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        if ctx.sig.r_force.is_none() {
            return no_force().hint(vec![20.0, 10.0]);
        }
        let wears = [
            Wear::Count,
            Wear::Distance(mm_to_m(2.0)),
            Wear::Distance(mm_to_m(5.0)),
            Wear::Distance(mm_to_m(12.0)),
        ];
        let mut best: Option<(f64, f64, f64)> = None;
        for pitch_mm in [1.0, 2.0, 4.0, 8.0, 16.0, 32.0] {
            for w in wears {
                let lvl = stroke_level(&ctx.sig.vel_mps, &ctx.sig.pos_m, mm_to_m(pitch_mm), w);
                if lvl.iter().all(|x| *x == 0.0) {
                    continue;
                }
                if let Some((c, t)) = beside(ctx, lvl)
                    && best.is_none_or(|b| t > b.1)
                {
                    best = Some((pitch_mm, t, c));
                }
            }
        }
        let Some((pitch, t, c)) = best else {
            return Evidence::absent("no short reversing strokes in the fitting data");
        };
        term_evidence(
            t,
            c > 0.0,
            format!("friction rising by {c:.2} N over strokes shorter than {pitch} mm ({t:.1} standard errors)"),
        )
        .with("rise_n", c)
        .with("pitch_mm", pitch)
        .hint(vec![c.max(0.0), pitch])
    }

    fn variants(&self, _ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let (rise, pitch) = match ev.hint.as_slice() {
            [a, b] => (a.max(1.0), *b),
            _ => (20.0, 10.0),
        };
        Ok(vec![
            Variant::params(
                "count",
                "a film worn by the count of short strokes",
                Effect::StrokeFriction.params(),
                set_params(Effect::StrokeFriction),
                vec![vec![rise, pitch], vec![rise, 5.0], vec![rise, 20.0]],
            ),
            Variant::params(
                "distance",
                "a film worn by the distance run near the turning points",
                &FILM_DEFS,
                set_film,
                vec![vec![rise, 5.0, 20.0], vec![rise, 12.0, 30.0]],
            ),
        ])
    }
}

/// A constant force on the table.
pub struct ConstantForce;

impl Candidate for ConstantForce {
    fn effect(&self) -> Effect {
        Effect::ConstantForce
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        if ctx.sig.r_force.is_none() {
            return no_force().hint(vec![10.0]);
        }
        let Some((c, t)) = linear_term(ctx, 3) else {
            return Evidence::absent("the force residual could not be regressed");
        };
        // The residual is the motor's extra force; a force on the table is opposed by it.
        term_evidence(
            t,
            true,
            format!("constant term of the force residual {c:.3} N ({t:.1} standard errors)"),
        )
        .with("coefficient_n", c)
        .hint(vec![-c])
    }

    fn variants(&self, _ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let f0 = ev.hint.first().copied().unwrap_or(10.0);
        Ok(vec![Variant::params(
            "constant",
            "the same force at every position and speed",
            Effect::ConstantForce.params(),
            set_params(Effect::ConstantForce),
            vec![vec![f0]],
        )])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stroke_level_counts_short_strokes_and_resets_on_a_long_one() {
        // +3 mm, −3 mm, +3 mm, then +30 mm, at 10 mm/s in 1 ms samples.
        let mut pos = vec![0.0];
        let mut vel = vec![0.0];
        for (len_mm, sign) in [
            (3.0, 1.0),
            (3.0, -1.0),
            (3.0, 1.0),
            (30.0, -1.0),
            (3.0, 1.0),
        ] {
            let n = (len_mm / 0.01) as usize;
            for _ in 0..n {
                let x = pos.last().copied().unwrap_or(0.0) + sign * 1e-5;
                pos.push(x);
                vel.push(sign * 0.01);
            }
        }
        let lvl = stroke_level(&vel, &pos, mm_to_m(5.0), Wear::Count);
        let at = |i: usize| lvl[i].abs();
        // After two short strokes the third runs at a raised level; the long stroke resets.
        assert!(at(850) > at(450), "{} {}", at(850), at(450));
        assert!(at(4000) < 1e-12, "{}", at(4000));
    }
}
