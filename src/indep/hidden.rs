//! The hidden effects: for each of the diagnosis's effect names, two or more physical
//! formulas with random parameters in documented ranges. Each draw changes the true
//! machine and returns its truth (parameter keys carry their unit).
//!
//! Parameter ranges (uniform unless noted; ± means a random sign):
//! - coulomb_friction: 8–40 N; half the draws asymmetric (+/− ratio 0.75–1.33).
//!   `sign_stick`: exact stick; `tanh`: tanh(v/ε), ε 0.1–1 mm/s.
//! - stribeck_friction: excess 10–50 N over the Coulomb level, vs 0.5–5 mm/s;
//!   `exponential` exp(−|v|/vs) or `gaussian` exp(−(v/vs)²), exact stick.
//! - viscous_friction: `linear` ±80–400 N·s/m (never below 30 % of the nominal);
//!   `directional` a different extra coefficient per direction (one 80–400, the other
//!   20–60 % of it); `power_law` 8–40 N at 100 mm/s, exponent 0.4–0.8, linear below 2 mm/s.
//! - stroke_friction: extra level up to 15–50 N on strokes shorter than a pitch of 3–15 mm;
//!   `count` (n0 1–4 strokes, recovery 10–50 mm) or `distance` (film breakdown over 2–15 mm,
//!   recovery 10–40 mm).
//! - backlash: gap 4–30 µm; `two_mass_dead_zone` contact stiffness 30–150 N/µm, damping
//!   ratio 0.05–0.3; `rigid_lost_motion` rigid flanks with inelastic impacts.
//! - backlash_asymmetry: the same gaps plus a bias on the carriage of ±20–80 N: constant
//!   (`dead_zone_bias`) or a preload spring varying 10–30 % over the travel
//!   (`lost_motion_preload`).
//! - constant_force: ±5–40 N; `constant` or `cable_carrier` (varies 5–25 % over the travel).
//! - compliance: a payload of 20–50 % of the table mass on a spring, resonance 30–300 Hz
//!   (log-uniform), damping ratio 0.02–0.1; `linear`, `hardening` (k·d·(1 + (d/d0)²), d0
//!   0.5–2 × the deflection under 1 m/s² of the payload) or `position_dependent` (stiffness
//!   ±(1.5–4)/m × (x − 125 mm) relative).
//! - thermal_growth: time constant 60–600 s, largest growth 5–25 µm, fixed bearing at
//!   −30 mm or 280 mm; `speed_heat` (q ∝ |v|) or `dissipated_power` (friction power plus
//!   copper loss 1e-4–1e-3 W/N²).
//! - lead_error: `harmonic` pitch 1–20 mm (log-uniform), first harmonic 1–6 µm, second
//!   0–40 % and third 0–25 % of it, half with a cumulative ±5–40 µm/m; `table` a smooth
//!   random error (σ 1.5–5 µm) at knots every 5–25 mm. Both are scaled down so that the
//!   carriage acceleration they cause at 150 mm/s stays below 0.2 m/s².
//! - quantization: a grid of 0.5–10 µm (log-uniform) on the logged position sensor,
//!   `round` (nearest) or `truncate` (floor).
//! - command_delay: `pure_delay` 0.2–6 samples (log-uniform), `first_order_lag` τ 0.5–5 ms.
//! - external_disturbance: `square` (period 0.3–3 s, ±10–60 N, duty 0.3–0.7), `sine`
//!   (period 0.2–5 s, ±10–50 N), `steps` (2–5 level changes of ±15–60 N), `bursts` (3–8
//!   pulses of 20–200 ms, ±40–150 N). Periodic ones record period_s, amplitude_n and
//!   first_rise_s.
//! - beam_sag is not generated: it needs a crossbeam and a second axis.

use std::collections::BTreeMap;
use std::f64::consts::TAU;

use super::control::{Grid, GridMode, SetPoint};
use super::dice::Dice;
use super::friction::{StribeckLaw, StribeckShape, StrokeLaw, ViscousExtra};
use super::rig::{Heat, HeatInput, Link, Payload};
use super::run::{ThermalView, TrueMachine};
use super::shapes::{Disturbance, Harmonics, LeadMap, Load, Spline, SpringLaw};
use super::{PosSensor, TrueEffect};
use crate::units::{m_to_um, mm_per_s_to_m_per_s, mm_to_m, ms_to_s, n_per_um_to_n_per_m, um_to_m};

/// Every effect the generator hides, with its formulas.
pub const EFFECTS: &[(&str, &[&str])] = &[
    ("coulomb_friction", &["sign_stick", "tanh"]),
    ("stribeck_friction", &["exponential", "gaussian"]),
    ("viscous_friction", &["linear", "directional", "power_law"]),
    ("stroke_friction", &["count", "distance"]),
    ("backlash", &["two_mass_dead_zone", "rigid_lost_motion"]),
    (
        "backlash_asymmetry",
        &["dead_zone_bias", "lost_motion_preload"],
    ),
    ("constant_force", &["constant", "cable_carrier"]),
    ("compliance", &["linear", "hardening", "position_dependent"]),
    ("thermal_growth", &["speed_heat", "dissipated_power"]),
    ("lead_error", &["harmonic", "table"]),
    ("quantization", &["round", "truncate"]),
    ("command_delay", &["pure_delay", "first_order_lag"]),
    (
        "external_disturbance",
        &["square", "sine", "steps", "bursts"],
    ),
];

/// The formulas of `effect`, if the generator knows it.
pub fn formulas(effect: &str) -> Option<&'static [&'static str]> {
    EFFECTS.iter().find(|(n, _)| *n == effect).map(|(_, f)| *f)
}

/// Largest carriage acceleration a lead error may cause at [`LEAD_SPEED_MPS`], m/s².
const LEAD_ACC_LIMIT_MPS2: f64 = 0.2;
/// The fastest commanded speed, m/s.
const LEAD_SPEED_MPS: f64 = 0.15;
/// Middle of the travel, m (reference of position-dependent shapes).
const MID_TRAVEL_MM: f64 = 125.0;
/// Travel over which position-dependent shapes are scaled, mm.
const TRAVEL_SPAN_MM: f64 = 240.0;

/// First knot of a tabulated lead error, mm (before the travel starts).
const TABLE_FIRST_MM: f64 = -50.0;
/// Span of the knots of a tabulated lead error, mm (past the end of the travel).
const TABLE_SPAN_MM: f64 = 350.0;

/// What a draw needs to know besides the machine.
pub struct Context {
    /// Record length, s (disturbance timing).
    pub duration_s: f64,
    /// The nominal linear viscous coefficient, N·s/m.
    pub nominal_viscous_n_s_per_m: f64,
}

/// A parameter map under construction.
#[derive(Default)]
struct Params(BTreeMap<String, f64>);

impl Params {
    fn put(&mut self, key: &str, v: f64) -> f64 {
        self.0.insert(key.to_owned(), v);
        v
    }
}

/// Draws effect `name` with `formula` into `m` and returns its truth.
pub fn hide(
    name: &'static str,
    formula: &'static str,
    dice: &mut Dice,
    m: &mut TrueMachine,
    ctx: &Context,
) -> TrueEffect {
    let mut p = Params::default();
    match name {
        "coulomb_friction" => coulomb(formula, dice, m, &mut p),
        "stribeck_friction" => stribeck(formula, dice, m, &mut p),
        "viscous_friction" => viscous(formula, dice, m, ctx, &mut p),
        "stroke_friction" => stroke(formula, dice, m, &mut p),
        "backlash" | "backlash_asymmetry" => backlash(name, formula, dice, m, &mut p),
        "constant_force" => constant_force(formula, dice, m, &mut p),
        "compliance" => compliance(formula, dice, m, &mut p),
        "thermal_growth" => thermal(formula, dice, m, &mut p),
        "lead_error" => lead(formula, dice, m, &mut p),
        "quantization" => quantization(formula, dice, m, &mut p),
        "command_delay" => delay(formula, dice, m, &mut p),
        _ => disturbance(formula, dice, m, ctx, &mut p),
    }
    TrueEffect {
        name,
        formula,
        params: p.0,
    }
}

fn coulomb(formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let f = dice.between(8.0, 40.0);
    let ratio = if dice.chance(0.5) {
        dice.between(0.75, 1.33)
    } else {
        1.0
    };
    let fr = &mut m.rig.friction;
    fr.coulomb_pos_n += p.put("force_pos_n", f * ratio.sqrt());
    fr.coulomb_neg_n += p.put("force_neg_n", f / ratio.sqrt());
    p.put("force_n", f);
    if formula == "tanh" {
        let eps = dice.between(0.1, 1.0);
        p.put("smoothing_speed_mm_per_s", eps);
        fr.tanh_speed_mps = Some(mm_per_s_to_m_per_s(eps));
    }
}

fn stribeck(formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let excess = p.put("breakaway_excess_n", dice.between(10.0, 50.0));
    let vs = p.put("velocity_mm_per_s", dice.between(0.5, 5.0));
    m.rig.friction.stribeck = Some(StribeckLaw {
        excess_n: excess,
        speed_mps: mm_per_s_to_m_per_s(vs),
        shape: if formula == "gaussian" {
            StribeckShape::Gaussian
        } else {
            StribeckShape::Exponential
        },
    });
}

fn viscous(formula: &str, dice: &mut Dice, m: &mut TrueMachine, ctx: &Context, p: &mut Params) {
    let floor = -0.7 * ctx.nominal_viscous_n_s_per_m;
    let fr = &mut m.rig.friction;
    match formula {
        "directional" => {
            let big = (dice.sign() * dice.between(80.0, 400.0)).max(floor);
            let small = big * dice.between(0.2, 0.6);
            let (pos, neg) = if dice.chance(0.5) {
                (big, small)
            } else {
                (small, big)
            };
            fr.viscous_extra = ViscousExtra::Directional {
                pos_n_s_per_m: p.put("pos_n_s_per_m", pos),
                neg_n_s_per_m: p.put("neg_n_s_per_m", neg),
            };
        }
        "power_law" => {
            let core_mm_s = p.put("core_mm_per_s", 2.0);
            fr.viscous_extra = ViscousExtra::Power {
                ref_force_n: p.put("force_at_100mm_per_s_n", dice.between(8.0, 40.0)),
                ref_speed_mps: mm_per_s_to_m_per_s(100.0),
                exponent: p.put("exponent", dice.between(0.4, 0.8)),
                core_mps: mm_per_s_to_m_per_s(core_mm_s),
            };
        }
        _ => {
            let dc = (dice.sign() * dice.between(80.0, 400.0)).max(floor);
            fr.viscous_n_s_per_m += p.put("viscous_n_s_per_m", dc);
        }
    }
}

fn stroke(formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let max_n = p.put("max_force_n", dice.between(15.0, 50.0));
    let pitch_m = mm_to_m(p.put("pitch_mm", dice.between(3.0, 15.0)));
    m.rig.friction.stroke = Some(if formula == "distance" {
        StrokeLaw::Distance {
            max_n,
            pitch_m,
            breakdown_m: mm_to_m(p.put("breakdown_mm", dice.between(2.0, 15.0))),
            recovery_m: mm_to_m(p.put("recovery_mm", dice.between(10.0, 40.0))),
        }
    } else {
        StrokeLaw::Count {
            max_n,
            pitch_m,
            n0: p.put("growth_strokes", dice.between(1.0, 4.0)),
            recovery_m: mm_to_m(p.put("recovery_mm", dice.between(10.0, 50.0))),
        }
    });
}

fn backlash(name: &str, formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let gap_m = um_to_m(p.put("width_um", dice.between(4.0, 30.0)));
    m.start_gap_frac = p.put("start_gap_fraction", dice.between(-1.0, 1.0));
    let two_mass = matches!(formula, "two_mass_dead_zone" | "dead_zone_bias");
    m.rig.link = if two_mass {
        let k = n_per_um_to_n_per_m(p.put("contact_stiffness_n_per_um", dice.between(30.0, 150.0)));
        let (m_r, m_c) = (m.rig.motor_mass_kg, m.rig.carriage_mass_kg);
        let m_red = m_r * m_c / (m_r + m_c);
        let zeta = p.put("contact_damping_ratio", dice.between(0.05, 0.3));
        Link::Spring {
            gap_m,
            k_n_per_m: k,
            c_n_s_per_m: p.put("contact_damping_n_s_per_m", 2.0 * zeta * (k * m_red).sqrt()),
        }
    } else {
        Link::LostMotion { gap_m }
    };
    if name != "backlash_asymmetry" {
        return;
    }
    let bias = p.put("bias_force_n", dice.sign() * dice.between(20.0, 80.0));
    m.rig.loads.push(if two_mass {
        Load::Constant { force_n: bias }
    } else {
        let rel = dice.sign() * dice.between(0.1, 0.3);
        let grad = bias.abs() * rel / mm_to_m(TRAVEL_SPAN_MM);
        Load::Gradient {
            force_n: bias,
            grad_n_per_m: p.put("bias_gradient_n_per_m", grad),
            ref_m: mm_to_m(p.put("bias_reference_mm", MID_TRAVEL_MM)),
        }
    });
}

fn constant_force(formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let f = p.put("force_n", dice.sign() * dice.between(5.0, 40.0));
    m.rig.loads.push(if formula == "cable_carrier" {
        let rel = dice.sign() * dice.between(0.05, 0.25);
        Load::Gradient {
            force_n: f,
            grad_n_per_m: p.put("gradient_n_per_m", f.abs() * rel / mm_to_m(TRAVEL_SPAN_MM)),
            ref_m: mm_to_m(p.put("reference_mm", MID_TRAVEL_MM)),
        }
    } else {
        Load::Constant { force_n: f }
    });
}

fn compliance(formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let share = p.put("payload_share", dice.between(0.2, 0.5));
    let table = m.rig.carriage_mass_kg;
    let m_p = p.put("payload_mass_kg", table * share);
    m.rig.carriage_mass_kg = table - m_p;
    let driven = m.rig.motor_mass_kg + m.rig.carriage_mass_kg;
    let m_red = driven * m_p / (driven + m_p);
    let f_hz = p.put("resonance_hz", dice.log_between(30.0, 300.0));
    let k = (TAU * f_hz).powi(2) * m_red;
    p.put("stiffness_n_per_um", k / n_per_um_to_n_per_m(1.0));
    let zeta = p.put("damping_ratio", dice.between(0.02, 0.1));
    let spring = match formula {
        "hardening" => {
            let d0 = dice.between(0.5, 2.0) * m_p / k;
            p.put("hardening_deflection_um", m_to_um(d0));
            SpringLaw::Hardening {
                k_n_per_m: k,
                d0_m: d0,
            }
        }
        "position_dependent" => SpringLaw::Positional {
            k_n_per_m: k,
            grad_per_m: p.put(
                "stiffness_gradient_per_m",
                dice.sign() * dice.between(1.5, 4.0),
            ),
            ref_m: mm_to_m(p.put("reference_mm", MID_TRAVEL_MM)),
        },
        _ => SpringLaw::Linear { k_n_per_m: k },
    };
    m.rig.payload = Some(Payload {
        mass_kg: m_p,
        spring,
        damping_n_s_per_m: p.put("damping_n_s_per_m", 2.0 * zeta * (k * m_red).sqrt()),
    });
}

fn thermal(formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let tau = p.put("time_constant_s", dice.between(60.0, 600.0));
    let growth = p.put("growth_max_um", dice.between(5.0, 25.0));
    let fixed = p.put("fixed_end_mm", if dice.chance(0.5) { -30.0 } else { 280.0 });
    let input = if formula == "dissipated_power" {
        HeatInput::Power {
            copper_w_per_n2: p.put("copper_w_per_n2", dice.log_between(1e-4, 1e-3)),
        }
    } else {
        HeatInput::Speed
    };
    m.rig.heat = Some(Heat {
        input,
        time_constant_s: tau,
    });
    m.thermal = Some(ThermalView {
        fixed_end_m: mm_to_m(fixed),
        growth_m: um_to_m(growth),
    });
}

fn lead(formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let limit_curv = LEAD_ACC_LIMIT_MPS2 / (LEAD_SPEED_MPS * LEAD_SPEED_MPS);
    if formula == "table" {
        let step_mm = p.put("knot_spacing_mm", dice.between(5.0, 25.0));
        let first_mm = p.put("first_knot_mm", TABLE_FIRST_MM);
        let count = ((TABLE_SPAN_MM / step_mm).ceil() as usize) + 1;
        let sigma = dice.between(1.5, 5.0);
        let mut v: Vec<f64> = (0..count).map(|_| sigma * dice.gauss()).collect();
        for _ in 0..2 {
            let w = v.clone();
            for i in 1..count - 1 {
                v[i] = 0.25 * w[i - 1] + 0.5 * w[i] + 0.25 * w[i + 1];
            }
        }
        let build = |vals: &[f64]| {
            Spline::new(
                mm_to_m(first_mm),
                mm_to_m(step_mm),
                vals.iter().map(|x| um_to_m(*x)).collect(),
            )
        };
        let probe = build(&v);
        let curv = (0..count * 8)
            .map(|i| {
                probe
                    .eval(mm_to_m(first_mm + step_mm * i as f64 / 8.0))
                    .2
                    .abs()
            })
            .fold(0.0, f64::max);
        let scale = if curv > limit_curv {
            limit_curv / curv
        } else {
            1.0
        };
        for (i, x) in v.iter_mut().enumerate() {
            *x *= scale;
            p.put(&format!("knot_{i:03}_um"), *x);
        }
        m.rig.lead = LeadMap::Table(build(&v));
        return;
    }
    let pitch_mm = p.put("pitch_mm", dice.log_between(1.0, 20.0));
    let a1 = dice.between(1.0, 6.0);
    let mut amp = [
        a1,
        a1 * dice.between(0.0, 0.4),
        a1 * dice.between(0.0, 0.25),
    ];
    let phase = [
        dice.between(0.0, TAU),
        dice.between(0.0, TAU),
        dice.between(0.0, TAU),
    ];
    let slope = if dice.chance(0.5) {
        dice.sign() * dice.between(5.0, 40.0)
    } else {
        0.0
    };
    let probe = Harmonics::new(mm_to_m(pitch_mm), amp.map(um_to_m), phase, 0.0);
    let curv = probe.max_curvature_per_m();
    if curv > limit_curv {
        amp = amp.map(|a| a * limit_curv / curv);
    }
    for (h, (a, ph)) in amp.iter().zip(phase).enumerate() {
        p.put(&format!("amplitude_{}_um", h + 1), *a);
        p.put(&format!("phase_{}_rad", h + 1), ph);
    }
    p.put("cumulative_um_per_m", slope);
    m.rig.lead = LeadMap::Harmonic(Harmonics::new(
        mm_to_m(pitch_mm),
        amp.map(um_to_m),
        phase,
        crate::units::um_per_m_to_ratio(slope),
    ));
}

fn quantization(formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let grid = Grid {
        step_m: um_to_m(p.put("resolution_um", dice.log_between(0.5, 10.0))),
        mode: if formula == "truncate" {
            GridMode::Floor
        } else {
            GridMode::Round
        },
    };
    match m.sensor {
        PosSensor::MotorEncoder => m.encoder = grid,
        PosSensor::LinearScale => m.scale = grid,
    }
}

fn delay(formula: &str, dice: &mut Dice, m: &mut TrueMachine, p: &mut Params) {
    let t3_ms = crate::units::s_to_ms(m.gains.t3_s);
    m.setpoint = if formula == "first_order_lag" {
        SetPoint::Lag {
            tau_s: ms_to_s(p.put("time_constant_ms", dice.between(0.5, 5.0))),
        }
    } else {
        let samples = p.put("delay_samples", dice.log_between(0.2, 6.0));
        p.put("delay_ms", samples * t3_ms);
        SetPoint::Delay { samples }
    };
}

fn disturbance(formula: &str, dice: &mut Dice, m: &mut TrueMachine, ctx: &Context, p: &mut Params) {
    let d = match formula {
        "square" => {
            let period = p.put("period_s", dice.between(0.3, 3.0));
            Disturbance::Square {
                period_s: period,
                amplitude_n: p.put("amplitude_n", dice.sign() * dice.between(10.0, 60.0)),
                first_rise_s: p.put("first_rise_s", dice.between(0.2, 0.2 + period)),
                duty: p.put("duty", dice.between(0.3, 0.7)),
            }
        }
        "sine" => {
            let period = p.put("period_s", dice.between(0.2, 5.0));
            Disturbance::Sine {
                period_s: period,
                amplitude_n: p.put("amplitude_n", dice.between(10.0, 50.0)),
                first_rise_s: p.put("first_rise_s", dice.between(0.2, 0.2 + period.min(5.0))),
            }
        }
        "steps" => {
            let count = 2 + dice.index(4);
            let mut times: Vec<f64> = (0..count)
                .map(|_| dice.between(0.05, 0.95) * ctx.duration_s)
                .collect();
            times.sort_by(f64::total_cmp);
            let levels: Vec<f64> = (0..count)
                .map(|_| dice.sign() * dice.between(15.0, 60.0))
                .collect();
            for (i, (t, l)) in times.iter().zip(&levels).enumerate() {
                p.put(&format!("step_{i}_time_s"), *t);
                p.put(&format!("step_{i}_level_n"), *l);
            }
            Disturbance::Steps {
                times_s: times,
                levels_n: levels,
            }
        }
        _ => {
            let count = 3 + dice.index(6);
            let stretch = ctx.duration_s / count as f64;
            let pulses: Vec<(f64, f64, f64)> = (0..count)
                .map(|i| {
                    let start = stretch * (i as f64 + dice.between(0.05, 0.8));
                    let dur = dice.between(0.02, 0.2);
                    (start, dur, dice.sign() * dice.between(40.0, 150.0))
                })
                .collect();
            for (i, (t, d, f)) in pulses.iter().enumerate() {
                p.put(&format!("burst_{i}_start_s"), *t);
                p.put(&format!("burst_{i}_duration_s"), *d);
                p.put(&format!("burst_{i}_force_n"), *f);
            }
            Disturbance::Bursts { pulses }
        }
    };
    m.rig.loads.push(Load::External(d));
}

/// Lead-error table truth: the knot positions in mm, for readers of the truth.
pub fn knot_mm(params: &BTreeMap<String, f64>, i: usize) -> Option<f64> {
    Some(params.get("first_knot_mm")? + params.get("knot_spacing_mm")? * i as f64)
}
