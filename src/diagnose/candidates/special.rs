//! Signatures read off the record rather than a friction regression, and the effects whose
//! shape a detector finds before any fit: a grid the positions lie on, an error periodic
//! along the travel at a pitch nobody told us, a common lag, a resonance, a slow drift, a
//! force that follows no state of the axis (periodic, steps or bursts).

use std::collections::BTreeMap;

use super::{Applied, Context, Evidence, Fitted, with_effect};
use crate::diagnose::DiagnoseError;
use crate::diagnose::calibrate::MIN_SKEW;
use crate::diagnose::effects::Effect;
use crate::diagnose::engine::{Cand, Eval};
use crate::diagnose::evidence::{self, WaveShape};
use crate::diagnose::lm::{self, Param};
use crate::diagnose::replay::{Disturbance, ForceEvent};
use crate::preset::PosSource;
use crate::units::{m_to_mm, m_to_um, mm_to_m, s_to_ms, um_to_m};

/// Whether the record's position sees the table (scale or true position): lead error and
/// thermal growth are invisible to a motor encoder.
fn sees_table(ctx: &Context) -> bool {
    ctx.base.model.pos_source != PosSource::MotorEncoder
}

/// The signature of one of the effects this module handles.
pub fn evidence(ctx: &Context, effect: Effect) -> Evidence {
    match effect {
        Effect::Quantization => quantization(ctx),
        Effect::LeadError => lead(ctx),
        Effect::CommandDelay => delay(ctx),
        Effect::Compliance => resonance(ctx),
        Effect::ThermalGrowth => drift(ctx),
        Effect::ExternalDisturbance => disturbance(ctx).0,
        Effect::BeamSag => beam(ctx),
        _ => Evidence::absent("no signature test"),
    }
}

/// The quantum the model's own position sensor already has, m (0: none).
fn model_quantum_m(ctx: &Context) -> f64 {
    let a = &ctx.base.model.axis;
    match ctx.base.model.pos_source {
        PosSource::MotorEncoder if a.encoder.quantize_motor => {
            a.drive.lead_m() / f64::from(a.encoder.motor_counts_per_rev)
        }
        PosSource::Scale if a.encoder.quantize_scale => um_to_m(a.encoder.scale_resolution_um),
        _ => 0.0,
    }
}

fn quantization(ctx: &Context) -> Evidence {
    // Coarser than the model's own sensor, and coarser than numbers written to a few
    // decimals (a CSV at 0.1 nm).
    let min_q = (3.0 * model_quantum_m(ctx)).max(1e-7);
    match evidence::grid(&ctx.sig.pos_m, min_q, 0.02) {
        Some(g) if g.on_grid >= 0.99 && g.by_chance <= 0.2 => Evidence {
            pass: true,
            text: format!(
                "{:.1} % of the measured positions lie on a {:.3} µm grid ({:.0} % would by chance)",
                100.0 * g.on_grid,
                m_to_um(g.quantum),
                100.0 * g.by_chance
            ),
            hint: vec![m_to_um(g.quantum)],
            ..Evidence::default()
        }
        .with("quantum_um", m_to_um(g.quantum))
        .with("on_grid_share", g.on_grid)
        .with("by_chance_share", g.by_chance),
        _ => Evidence::absent(format!(
            "the measured positions lie on no grid coarser than {:.3} µm",
            m_to_um(min_q)
        )),
    }
}

/// Harmonics fitted along the travel.
const LEAD_HARMONICS: usize = 3;

fn lead(ctx: &Context) -> Evidence {
    if !sees_table(ctx) {
        return Evidence::absent(
            "the record's position is the motor encoder, which a lead error does not move",
        );
    }
    let Some(p) = evidence::periodic_in_position(
        &ctx.sig.pos_m,
        &ctx.sig.r_pos,
        mm_to_m(0.5),
        mm_to_m(60.0),
        LEAD_HARMONICS,
    ) else {
        return Evidence::absent("the position residual has no period along the travel");
    };
    let pass = p.peak_ratio >= 12.0 && p.explained >= 0.1;
    let mut hint = vec![m_to_mm(p.period_m), p.slope_per_m];
    for (s, c) in p.sin.iter().zip(&p.cos) {
        hint.extend([*s, *c]);
    }
    Evidence {
        pass,
        text: format!(
            "the position residual repeats every {:.3} mm of travel, {:.2} µm at the fundamental, {:.0}× the median of its spectrum, {:.0} % of it explained",
            m_to_mm(p.period_m),
            m_to_um(p.amplitude),
            p.peak_ratio,
            100.0 * p.explained
        ),
        hint,
        ..Evidence::default()
    }
    .with("pitch_mm", m_to_mm(p.period_m))
    .with("amplitude_um", m_to_um(p.amplitude))
    .with("peak_ratio", p.peak_ratio)
    .with("explained_share", p.explained)
}

fn delay(ctx: &Context) -> Evidence {
    let lag = ctx.cal.common_lag_samples;
    let t3 = ctx.eng.split.main.t3_s;
    let text = format!(
        "position and force both follow the model {:.2} samples ({:.2} ms) late{}",
        -lag,
        s_to_ms(-lag * t3),
        if ctx.eng.has_force {
            ""
        } else {
            " (position alone)"
        }
    );
    Evidence {
        pass: lag <= -MIN_SKEW,
        text,
        hint: vec![s_to_ms(-lag * t3)],
        ..Evidence::default()
    }
    .with("lag_samples", -lag)
}

fn resonance(ctx: &Context) -> Evidence {
    let dt = ctx.eng.split.main.t3_s;
    let y: &[f64] = ctx.sig.r_force.as_deref().unwrap_or(&ctx.sig.r_pos);
    let f_hi = (0.4 / dt).min(600.0);
    match evidence::resonance(y, dt, 8.0, f_hi, Some(&ctx.sig.cmd_acc_mps2)) {
        Some(r) if r.peak_ratio >= 8.0 && r.ref_ratio.is_none_or(|x| x >= 4.0) => {
            let a = &ctx.base.model.axis;
            let m = a.drive.total_mass_kg();
            let w = std::f64::consts::TAU * r.freq_hz;
            // A payload of about a third of the mass on the spring, to start from.
            let share = 0.3;
            let m_red = share * (1.0 - share) * m;
            let k_n_per_um = w * w * m_red * 1e-6;
            let c = 2.0 * r.damping_ratio.max(0.02) * w * m_red;
            Evidence {
                pass: true,
                text: format!(
                    "the residual resonates at {:.1} Hz, {:.0}× its band's median{}",
                    r.freq_hz,
                    r.peak_ratio,
                    r.ref_ratio
                        .map(|x| format!(", {x:.0}× what the command excites"))
                        .unwrap_or_default()
                ),
                hint: vec![k_n_per_um, c, share],
                ..Evidence::default()
            }
            .with("frequency_hz", r.freq_hz)
            .with("peak_ratio", r.peak_ratio)
            .with("damping_ratio", r.damping_ratio)
        }
        _ => Evidence::absent("no resonance in the residual's spectrum"),
    }
}

fn drift(ctx: &Context) -> Evidence {
    if !sees_table(ctx) {
        return Evidence::absent(
            "the record's position is the motor encoder, which the screw's growth does not move",
        );
    }
    match evidence::drift(&ctx.sig.t_s, &ctx.sig.r_pos, None) {
        Some(d) if d.explained >= 0.5 && m_to_um(d.magnitude.abs()) >= 1.0 => {
            let tau = d.tau_s.unwrap_or(600.0);
            Evidence {
                pass: true,
                text: format!(
                    "the position residual drifts by {:.1} µm{}, {:.0} % of its slow part",
                    m_to_um(d.magnitude),
                    d.tau_s
                        .map(|t| format!(" with a time constant of {t:.0} s"))
                        .unwrap_or_default(),
                    100.0 * d.explained
                ),
                hint: vec![100.0, tau.clamp(10.0, 36_000.0), 0.0],
                ..Evidence::default()
            }
            .with("drift_um", m_to_um(d.magnitude))
            .with("time_constant_s", tau)
            .with("explained_share", d.explained)
        }
        _ => Evidence::absent("no slow drift in the position residual"),
    }
}

fn beam(ctx: &Context) -> Evidence {
    if ctx.base.model.beam.is_some() && !ctx.eng.split.main.beam_x_m.is_empty() {
        Evidence {
            pass: true,
            text: "the axis hangs from a crossbeam whose posts' positions are recorded".into(),
            ..Evidence::default()
        }
    } else {
        Evidence::absent("no crossbeam posts recorded for this axis")
    }
}

/// The part of the force residual no state of the axis explains, and what shape it has:
/// a periodic wave, level steps or bursts.
fn disturbance(ctx: &Context) -> (Evidence, Option<Disturbance>) {
    let s = ctx.sig;
    let dt = ctx.eng.split.main.t3_s;
    let y: Vec<f64> = match &s.r_force {
        Some(f) => f.clone(),
        None => s.r_pos.clone(),
    };
    let dir: Vec<f64> = s.vel_mps.iter().map(|v| v.signum()).collect();
    let ones = vec![1.0; y.len()];
    let cols: Vec<&[f64]> = vec![&dir, &s.vel_mps, &s.acc_mps2, &ones];
    let rem: Vec<f64> = match evidence::regress(&cols, &y, s.corr_len) {
        Some(r) => y
            .iter()
            .enumerate()
            .map(|(k, v)| v - cols.iter().zip(&r.coef).map(|(c, b)| c[k] * b).sum::<f64>())
            .collect(),
        None => y,
    };
    let t0 = s.t_s.first().copied().unwrap_or(0.0);
    let span = dt * rem.len() as f64;
    if let Some(p) = evidence::periodic_in_time(&rem, t0, dt, 0.1, (span / 3.0).min(10.0))
        && p.peak_ratio >= 20.0
        && p.explained >= 0.15
    {
        return periodic(p);
    }
    let min_gap = ((0.5 / dt) as usize).max(4);
    let steps = evidence::steps(&rem, min_gap, 10.0, 10);
    if !steps.is_empty() {
        let mut times_s = vec![];
        let mut levels_n = vec![];
        let mut level = 0.0;
        for st in &steps {
            level -= st.jump;
            times_s.push(t0 + st.index as f64 * dt);
            levels_n.push(level);
        }
        let ev = Evidence {
            pass: true,
            text: format!(
                "{} level steps in the force no state explains, up to {:.1} N",
                steps.len(),
                steps.iter().map(|s| s.jump.abs()).fold(0.0, f64::max)
            ),
            ..Evidence::default()
        }
        .with("steps", steps.len() as f64);
        return (ev, Some(Disturbance::Steps { times_s, levels_n }));
    }
    let window = ((0.02 / dt) as usize).max(4);
    let bursts = evidence::bursts(&rem, window, 10.0);
    if bursts.is_empty() || bursts.len() > 400 {
        return (
            Evidence::absent(
                "the force no state explains is neither periodic nor stepped nor bursty",
            ),
            None,
        );
    }
    let ev = Evidence {
        pass: true,
        text: format!(
            "{} bursts of force no state explains, {:.1} N rms at most",
            bursts.len(),
            bursts.iter().map(|b| b.rms).fold(0.0, f64::max)
        ),
        ..Evidence::default()
    }
    .with("bursts", bursts.len() as f64);
    let windows = bursts
        .iter()
        .map(|b| ForceEvent {
            i0: b.start,
            i1: b.end,
            force_n: -b.mean,
        })
        .collect();
    (ev, Some(Disturbance::Windows(windows)))
}

/// A periodic force on the table from the periodic part of the force residual: the motor
/// opposes the force, so the wave is inverted; its amplitude is kept positive by moving the
/// edge.
fn periodic(p: evidence::Periodic) -> (Evidence, Option<Disturbance>) {
    let (d, shape, duty) = match p.shape {
        WaveShape::Square { duty } => {
            // Inverted: high where the residual is low.
            let rise = p.first_rise_s + duty * p.period_s;
            (
                Disturbance::Square {
                    period_s: p.period_s,
                    duty: 1.0 - duty,
                    amplitude_n: p.amplitude,
                    offset_n: -p.offset,
                    first_rise_s: rise.rem_euclid(p.period_s),
                },
                "square",
                1.0 - duty,
            )
        }
        WaveShape::Sine => (
            Disturbance::Sine {
                period_s: p.period_s,
                amplitude_n: p.amplitude,
                offset_n: -p.offset,
                first_rise_s: (p.first_rise_s + 0.5 * p.period_s).rem_euclid(p.period_s),
            },
            "sine",
            0.5,
        ),
    };
    let rise = match &d {
        Disturbance::Square { first_rise_s, .. } | Disturbance::Sine { first_rise_s, .. } => {
            *first_rise_s
        }
        _ => 0.0,
    };
    let ev = Evidence {
        pass: true,
        text: format!(
            "a {shape} force of period {:.4} s and ±{:.2} N no state explains, rising at {:.3} s (+ k periods); {:.0}× the median of the spectrum, {:.0} % of that force explained",
            p.period_s,
            p.amplitude,
            rise,
            p.peak_ratio,
            100.0 * p.explained
        ),
        ..Evidence::default()
    }
    .with("period_s", p.period_s)
    .with("amplitude_n", p.amplitude)
    .with("first_rise_s", rise)
    .with("duty", duty)
    .with("peak_ratio", p.peak_ratio);
    (ev, Some(d))
}

/// Evidence and fit of the effects a detector shapes.
pub fn fit(ctx: &Context, effect: Effect, ev: Evidence) -> Result<Option<Fitted>, DiagnoseError> {
    match effect {
        Effect::Quantization if ev.pass => fit_quantization(ctx, ev),
        Effect::LeadError if ev.hint.len() >= 2 => fit_lead(ctx, ev),
        Effect::ExternalDisturbance => fit_disturbance(ctx),
        Effect::BeamSag if ev.pass => ctx.fit_lm(effect, ev),
        _ => Ok(None),
    }
}

/// A detector-shaped effect, fitted.
struct Made {
    effect: Effect,
    cand: Cand,
    eval: Eval,
    keys: Vec<String>,
    theta: Vec<f64>,
    applied: Applied,
}

fn fitted(ctx: &Context, m: Made, ev: Evidence) -> Fitted {
    let Made {
        effect,
        cand,
        eval,
        keys,
        theta,
        applied,
    } = m;
    Fitted {
        ratios: ctx.ratios.to_vec(),
        applied,
        effect,
        std: vec![0.0; theta.len()],
        n_params: theta.len(),
        keys,
        theta,
        cand,
        eval,
        extra: BTreeMap::new(),
        note: String::new(),
        evidence: ev,
        refit: false,
    }
}

fn fit_quantization(ctx: &Context, ev: Evidence) -> Result<Option<Fitted>, DiagnoseError> {
    let q_um = ev.hint.first().copied().unwrap_or(1.0);
    let cand = with_effect(ctx.base, Effect::Quantization, &[q_um]);
    let eval = ctx.eng.evaluate(&cand)?;
    Ok(Some(fitted(
        ctx,
        Made {
            effect: Effect::Quantization,
            cand,
            eval,
            keys: vec!["resolution_um".into()],
            theta: vec![q_um],
            applied: Applied::Params(Effect::Quantization, vec![q_um]),
        },
        ev,
    )))
}

/// The lead error as a table of the fitted harmonics (pitch from the spectrum, coefficients
/// by least squares on the position residual), every 1/24 of a pitch over the travel.
fn fit_lead(ctx: &Context, ev: Evidence) -> Result<Option<Fitted>, DiagnoseError> {
    let pitch_mm = ev.hint[0];
    let slope = ev.hint[1];
    let coef: Vec<(f64, f64)> = ev.hint[2..]
        .chunks(2)
        .map(|c| (c[0], c.get(1).copied().unwrap_or(0.0)))
        .collect();
    let (lo, hi) = ctx
        .eng
        .split
        .main
        .pos_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let step = mm_to_m(pitch_mm) / 24.0;
    let n = (((hi - lo) / step).ceil() as usize + 3).min(9_000);
    let mut cand = ctx.base.clone();
    let l = &mut cand.model.axis.lead_error;
    l.enabled = true;
    let x0 = lo - step;
    l.table = (0..n)
        .map(|i| {
            let x = x0 + i as f64 * step;
            let ph = std::f64::consts::TAU * x / mm_to_m(pitch_mm);
            let e: f64 = coef
                .iter()
                .enumerate()
                .map(|(k, (s, c))| {
                    let kk = (k + 1) as f64;
                    s * (kk * ph).sin() + c * (kk * ph).cos()
                })
                .sum::<f64>()
                + slope * (x - x0);
            (m_to_mm(x), m_to_um(e))
        })
        .collect();
    let table = cand.model.axis.lead_error.table.clone();
    let eval = ctx.eng.evaluate(&cand)?;
    let mut keys = vec!["pitch_mm".to_owned(), "cumulative_um_per_m".to_owned()];
    let mut theta = vec![pitch_mm, slope * 1e6];
    for (k, (s, c)) in coef.iter().enumerate() {
        keys.push(format!("h{}_sin_um", k + 1));
        keys.push(format!("h{}_cos_um", k + 1));
        theta.extend([m_to_um(*s), m_to_um(*c)]);
    }
    Ok(Some(fitted(
        ctx,
        Made {
            effect: Effect::LeadError,
            cand,
            eval,
            keys,
            theta,
            applied: Applied::LeadTable(table),
        },
        ev,
    )))
}

/// The disturbance the detector shaped, its level (and for a wave its edge) refined on
/// replays, and detected again on a separate validation record.
fn fit_disturbance(ctx: &Context) -> Result<Option<Fitted>, DiagnoseError> {
    let (ev, d) = disturbance(ctx);
    let (Some(d), true) = (d, ev.pass) else {
        return Ok(None);
    };
    let d = refine(ctx, d)?;
    let applied = Applied::Disturbance(d.clone(), vec![]);
    let mut cand = ctx.base.clone();
    applied.apply(&mut cand);
    let eval = ctx.eng.evaluate(&cand)?;
    let (keys, theta) = describe(&d);
    let mut f = fitted(
        ctx,
        Made {
            effect: Effect::ExternalDisturbance,
            cand,
            eval,
            keys,
            theta,
            applied,
        },
        ev,
    );
    // Shape (period, duty, step times or window edges) is found by the detector: counted
    // as parameters too.
    f.n_params = f.theta.len().max(3);
    Ok(Some(f))
}

/// A wave's amplitude, offset and edge, by least squares on replays from the detector's
/// values.
fn refine(ctx: &Context, d: Disturbance) -> Result<Disturbance, DiagnoseError> {
    let Disturbance::Square {
        period_s,
        duty,
        amplitude_n,
        offset_n,
        first_rise_s,
    } = d
    else {
        return Ok(d);
    };
    let wave = |th: &[f64]| Disturbance::Square {
        period_s,
        duty,
        amplitude_n: th[0],
        offset_n: th[1],
        first_rise_s: th[2],
    };
    let rows = |th: &[f64]| {
        let mut c = ctx.base.clone();
        c.model.disturbance.push(wave(th));
        Ok(Some(ctx.eng.lm_rows(&ctx.eng.sim_fit(&c)?)))
    };
    let amp = amplitude_n.abs().max(1e-3);
    let params = [
        Param {
            lo: 0.0,
            hi: 20.0 * amp,
            scale: amp,
        },
        Param {
            lo: -20.0 * amp,
            hi: 20.0 * amp,
            scale: amp,
        },
        Param {
            lo: first_rise_s - 0.1 * period_s,
            hi: first_rise_s + 0.1 * period_s,
            scale: 0.01 * period_s,
        },
    ];
    let f = lm::fit(
        &[amplitude_n, offset_n, first_rise_s],
        &params,
        &rows,
        0.03,
        6,
    )?;
    Ok(wave(&f.theta))
}

/// Report keys and values of a disturbance.
fn describe(d: &Disturbance) -> (Vec<String>, Vec<f64>) {
    match d {
        Disturbance::Square {
            period_s,
            duty,
            amplitude_n,
            offset_n,
            first_rise_s,
        } => (
            [
                "period_s",
                "amplitude_n",
                "first_rise_s",
                "duty",
                "offset_n",
            ]
            .map(String::from)
            .to_vec(),
            vec![*period_s, *amplitude_n, *first_rise_s, *duty, *offset_n],
        ),
        Disturbance::Sine {
            period_s,
            amplitude_n,
            offset_n,
            first_rise_s,
        } => (
            ["period_s", "amplitude_n", "first_rise_s", "offset_n"]
                .map(String::from)
                .to_vec(),
            vec![*period_s, *amplitude_n, *first_rise_s, *offset_n],
        ),
        Disturbance::Steps { times_s, levels_n } => (
            ["steps", "largest_level_n"].map(String::from).to_vec(),
            vec![
                times_s.len() as f64,
                levels_n.iter().fold(0.0f64, |m, l| m.max(l.abs())),
            ],
        ),
        Disturbance::Windows(w) => (
            ["windows", "largest_force_n"].map(String::from).to_vec(),
            vec![
                w.len() as f64,
                w.iter().fold(0.0f64, |m, e| m.max(e.force_n.abs())),
            ],
        ),
    }
}
