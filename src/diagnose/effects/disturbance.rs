//! The external disturbance: force that follows no state of the axis (a periodic wave,
//! level steps or bursts), found in what the state regressors leave of the residuals.
//!
//! A force on the axis shows in two places: the force residual (the amplifier opposes a
//! force pushed on the table from outside) and the position residual (the loop gives way
//! by force / stiffness). A force injected into the amplifier's own output shows only in
//! the position: the record's force channel carries it. A periodic wave is therefore
//! searched in both residuals, and the site that replays better is kept.
//!
//! A wave predicts its held-out part and is scored there. Level steps and bursts come at
//! times no state predicts: they are shaped on the fitting part and scored there (their
//! parameters charged), and the model carries them in the fitting part only, so that
//! nothing of the held-out part is timed, located or sized on it.

use super::{Candidate, Effect};
use crate::diagnose::DiagnoseError;
use crate::diagnose::criterion::Part;
use crate::diagnose::evidence::{self, Periodic, WaveShape};
use crate::diagnose::fit::{Context, Detail, Evidence, Fixed, Shape, Signals, Variant};
use crate::diagnose::replay::{Disturbance, ForceEvent};
use nalgebra::{DMatrix, DVector};

/// Least peak-to-median ratio of the periodogram for a periodic disturbance (white noise
/// gives ~10–20).
const MIN_PEAK_RATIO: f64 = 20.0;

/// Least share of the unexplained force a periodic wave must explain.
const MIN_EXPLAINED_FORCE: f64 = 0.15;

/// Least share of the unexplained position residual a periodic wave must explain when the
/// record has a force channel too: the position residual of a model mismatch repeats with
/// a repeating command, so it needs a clearer wave than the force does.
const MIN_EXPLAINED_POS: f64 = 0.3;

/// More bursts than this are no bursts but a busy residual.
const MAX_BURSTS: usize = 400;

/// Shortest period searched, s.
const MIN_PERIOD_S: f64 = 0.1;

/// Longest period searched, s (and at most a third of the fitting part).
const MAX_PERIOD_S: f64 = 10.0;

/// `y` less its least-squares fit on the states a friction or inertia term follows
/// (direction, velocity, acceleration, a constant): what no state explains.
fn unexplained(s: &Signals, y: &[f64]) -> Vec<f64> {
    let dir: Vec<f64> = s.vel_mps.iter().map(|v| v.signum()).collect();
    let ones = vec![1.0; y.len()];
    let cols: Vec<&[f64]> = vec![&dir, &s.vel_mps, &s.acc_mps2, &ones];
    match evidence::regress(&cols, y, s.corr_len) {
        Some(r) => evidence::minus_fit(y, &cols, &r.coef),
        None => y.to_vec(),
    }
}

/// Least time between the last level step and the fitting part's end, s: the force
/// residual follows a step within a few tens of ms.
const STEP_END_GAP_S: f64 = 0.1;

/// Rounds of [`stepped_steps`]'s joint fit: the second round's steps rarely move.
const STEP_JOINT_ROUNDS: usize = 2;

/// The level steps of `y` fitted jointly with its states (direction, speed, acceleration,
/// a constant; see [`unexplained`]). A force that changes level at times the program's moves
/// share is partly taken by the speed or direction term when the states are fitted alone,
/// which leaves a residual that is no longer piecewise constant; fitting the steps with the states gives the states back
/// their own share. The constant goes with the states, so the level is 0 before the first
/// step, as [`Disturbance::Steps`] has it.
fn stepped_steps(s: &Signals, y: &[f64], min_gap: usize, end_gap: usize) -> Vec<evidence::Step> {
    let find = |rem: &[f64]| evidence::steps_to_end(rem, min_gap, end_gap, 10.0, 10);
    let mut rem = unexplained(s, y);
    let mut steps = find(&rem);
    let dir: Vec<f64> = s.vel_mps.iter().map(|v| v.signum()).collect();
    let ones = vec![1.0; y.len()];
    for _ in 0..STEP_JOINT_ROUNDS {
        if steps.is_empty() {
            break;
        }
        let held: Vec<Vec<f64>> = steps
            .iter()
            .map(|st| {
                (0..y.len())
                    .map(|k| f64::from(u8::from(k >= st.index)))
                    .collect()
            })
            .collect();
        let states: [&[f64]; 4] = [&dir, &s.vel_mps, &s.acc_mps2, &ones];
        let mut cols: Vec<&[f64]> = states.to_vec();
        cols.extend(held.iter().map(Vec::as_slice));
        let Some(r) = evidence::regress(&cols, y, s.corr_len) else {
            break;
        };
        rem = evidence::minus_fit(y, &states, &r.coef);
        steps = find(&rem);
    }
    steps
}

/// Static stiffness of the position loop, N/m: a steady force moves a P/PD loop off its
/// command by force / (kp·kv). It turns a wave in the position residual into a force.
fn loop_stiffness_n_per_m(ctx: &Context) -> f64 {
    let s = &ctx.base.model.axis.servo;
    let k = s.kp_per_s * s.kv_n_s_per_m;
    if k.is_finite() && k > 0.0 { k } else { 1e6 }
}

/// The force on the table that produces the wave `p` found in a residual that is `gain`
/// times that force (−1 for the force residual; the loop's compliance, inverted, for the
/// position residual). The amplitude is kept positive by moving the edge.
fn wave(p: &Periodic, gain: f64) -> Disturbance {
    let amplitude_n = gain.abs() * p.amplitude;
    let offset_n = gain * p.offset;
    match p.shape {
        WaveShape::Square { duty } if gain < 0.0 => Disturbance::Square {
            period_s: p.period_s,
            duty: 1.0 - duty,
            amplitude_n,
            offset_n,
            // High where the residual is low: the residual's falling edge.
            first_rise_s: (p.first_rise_s + duty * p.period_s).rem_euclid(p.period_s),
        },
        WaveShape::Square { duty } => Disturbance::Square {
            period_s: p.period_s,
            duty,
            amplitude_n,
            offset_n,
            first_rise_s: p.first_rise_s.rem_euclid(p.period_s),
        },
        WaveShape::Sine => {
            let shift = if gain < 0.0 { 0.5 * p.period_s } else { 0.0 };
            Disturbance::Sine {
                period_s: p.period_s,
                amplitude_n,
                // A sine has no mean: a mean beside it is a constant force (see `refine_sine`).
                offset_n: 0.0,
                first_rise_s: (p.first_rise_s + shift).rem_euclid(p.period_s),
            }
        }
    }
}

/// Samples either side of the detector's edge the refit searches: the detector times the
/// edge by the residual, which lags the force by the loop's response (EMPS: ~10 ms).
fn edge_reach_samples(period_s: f64, dt_s: f64) -> isize {
    let reach_s = (0.05 * period_s).max(0.02).min(0.25 * period_s);
    (reach_s / dt_s).round().max(1.0) as isize
}

/// Replays of the base with one more disturbance at a fixed site, as changes of the
/// solver's rows: the columns of the linear fits below.
struct Replays<'r, 'c, 'a> {
    ctx: &'r Context<'c, 'a>,
    in_command: bool,
    /// The base's own rows.
    r0: DVector<f64>,
}

impl Replays<'_, '_, '_> {
    /// `d` at this site.
    fn site(&self, d: Disturbance) -> Disturbance {
        if self.in_command {
            Disturbance::InCommand(Box::new(d))
        } else {
            d
        }
    }

    /// How adding `d` changes the rows.
    fn change(&self, d: Disturbance) -> Result<DVector<f64>, DiagnoseError> {
        let mut c = self.ctx.base.clone();
        c.model.disturbance.push(self.site(d));
        Ok(self.ctx.eng.lm_rows(&self.ctx.eng.sim_fit(&c, false)?) - &self.r0)
    }
}

/// A wave's levels (and a square wave's edge) from replays: the residual moves linearly
/// with a wave's levels (the loop is linear away from friction's switching), so a few
/// replays give them by least squares, which a gradient solver on the edge would not (the
/// edge acts only at whole samples, so its finite differences are mostly zero).
fn refine(ctx: &Context, d: Disturbance) -> Result<Disturbance, DiagnoseError> {
    let (inner, in_command) = match d {
        Disturbance::InCommand(inner) => (*inner, true),
        other => (other, false),
    };
    let rp = Replays {
        ctx,
        in_command,
        r0: ctx.eng.lm_rows(&ctx.eng.sim_fit(ctx.base, false)?),
    };
    let refined = match inner {
        Disturbance::Square { .. } => refine_square(&rp, inner)?,
        Disturbance::Sine { .. } => refine_sine(&rp, inner)?,
        Disturbance::Windows(w) => refine_windows(&rp, w)?,
        other => other,
    };
    Ok(rp.site(refined))
}

/// Burst levels from one replay: the residual's mean over a window lags the force (the loop
/// takes over part of it), so all levels are scaled by the one factor that fits the
/// replays best.
fn refine_windows(rp: &Replays, w: Vec<ForceEvent>) -> Result<Disturbance, DiagnoseError> {
    let col = rp.change(Disturbance::Windows(w.clone()))?;
    let den = col.norm_squared();
    if den.is_nan() || den <= 0.0 {
        return Ok(Disturbance::Windows(w));
    }
    let alpha = (-col.dot(&rp.r0) / den).clamp(0.0, 10.0);
    if !alpha.is_finite() || alpha == 0.0 {
        return Ok(Disturbance::Windows(w));
    }
    Ok(Disturbance::Windows(
        w.into_iter()
            .map(|e| ForceEvent {
                force_n: e.force_n * alpha,
                ..e
            })
            .collect(),
    ))
}

/// A sine's amplitude and phase: its sine and cosine parts are two linear columns, so two
/// replays fit them exactly for a linear loop. The sine is fitted without a mean: a mean
/// beside it is a constant force, which is another candidate's (a sine's offset would take a
/// constant force standing beside it). A square wave keeps its offset: which of its two levels
/// is the rest level the record does not say.
fn refine_sine(rp: &Replays, d: Disturbance) -> Result<Disturbance, DiagnoseError> {
    let Disturbance::Sine {
        period_s,
        amplitude_n,
        first_rise_s,
        ..
    } = d
    else {
        return Ok(d);
    };
    let amp = amplitude_n.abs().max(1e-3);
    let sine = |amplitude_n: f64, offset_n: f64, first_rise_s: f64| Disturbance::Sine {
        period_s,
        amplitude_n,
        offset_n,
        first_rise_s,
    };
    let g_sin = rp.change(sine(amp, 0.0, first_rise_s))?;
    // A quarter period earlier: the cosine of the same phase.
    let g_cos = rp.change(sine(amp, 0.0, first_rise_s - 0.25 * period_s))?;
    let Some((_, x)) = linear_levels(&rp.r0, &[g_sin, g_cos]) else {
        return Ok(d);
    };
    // a·sin θ + b·cos θ = R·sin(θ + φ): the up-crossing moves φ/ω earlier.
    let phi = x[1].atan2(x[0]);
    let rise = first_rise_s - phi / std::f64::consts::TAU * period_s;
    Ok(sine(amp * x[0].hypot(x[1]), 0.0, rise.rem_euclid(period_s)))
}

/// A square wave's level, offset and edge: for each trial edge one replay of the wave gives
/// the best level and offset there; the edge is scanned coarsely and then narrowed by
/// halving steps.
fn refine_square(rp: &Replays, d: Disturbance) -> Result<Disturbance, DiagnoseError> {
    let Disturbance::Square {
        period_s,
        duty,
        amplitude_n,
        first_rise_s,
        ..
    } = d
    else {
        return Ok(d);
    };
    let amp = amplitude_n.abs().max(1e-3);
    let square = |amplitude_n: f64, offset_n: f64, first_rise_s: f64| Disturbance::Square {
        period_s,
        duty,
        amplitude_n,
        offset_n,
        first_rise_s,
    };
    let g_offset = rp.change(square(0.0, amp, first_rise_s))?;
    let dt_s = rp.ctx.eng.split.main.t3_s;
    // (cost, level, offset) with the edge `shift` samples from the detector's.
    let at = |shift: isize| -> Result<(f64, f64, f64), DiagnoseError> {
        let rise = first_rise_s + shift as f64 * dt_s;
        let g_wave = rp.change(square(amp, 0.0, rise))?;
        Ok(match linear_levels(&rp.r0, &[g_wave, g_offset.clone()]) {
            Some((cost, x)) => (cost, x[0] * amp, x[1] * amp),
            None => (f64::INFINITY, 0.0, 0.0),
        })
    };
    let reach = edge_reach_samples(period_s, dt_s);
    let mut step = (reach / 5).max(1);
    let mut best = (0isize, at(0)?);
    let mut k = -reach;
    while k <= reach {
        if k != 0 {
            let v = at(k)?;
            if v.0 < best.1.0 {
                best = (k, v);
            }
        }
        k += step;
    }
    while step > 1 {
        step /= 2;
        let centre = best.0;
        for k in [centre - step, centre + step] {
            let v = at(k)?;
            if v.0 < best.1.0 {
                best = (k, v);
            }
        }
    }
    let (shift, (_, level, offset_n)) = best;
    let rise = first_rise_s + shift as f64 * dt_s;
    // A negative level is the same wave with its halves swapped.
    Ok(if level >= 0.0 {
        square(level, offset_n, rise.rem_euclid(period_s))
    } else {
        Disturbance::Square {
            period_s,
            duty: 1.0 - duty,
            amplitude_n: -level,
            offset_n,
            first_rise_s: (rise + duty * period_s).rem_euclid(period_s),
        }
    })
}

/// The least-squares `x` of `r0 + Σ x_j·cols_j ≈ 0` (nalgebra's SVD), with the sum of
/// squares left: (cost, x). None when the system is degenerate.
fn linear_levels(r0: &DVector<f64>, cols: &[DVector<f64>]) -> Option<(f64, DVector<f64>)> {
    let a = DMatrix::from_columns(cols);
    let x = a.clone().svd(true, true).solve(&(-r0), 1e-12).ok()?;
    let cost = (r0 + &a * &x).norm_squared();
    (cost.is_finite() && x.iter().all(|v| v.is_finite())).then_some((cost, x))
}

/// Report keys and values of a disturbance.
fn describe(d: &Disturbance) -> (Vec<String>, Vec<f64>) {
    let keys = |k: &[&str]| k.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>();
    match d {
        Disturbance::InCommand(inner) => describe(inner),
        Disturbance::Square {
            period_s,
            duty,
            amplitude_n,
            offset_n,
            first_rise_s,
        } => (
            keys(&[
                "period_s",
                "amplitude_n",
                "first_rise_s",
                "duty",
                "offset_n",
            ]),
            vec![*period_s, *amplitude_n, *first_rise_s, *duty, *offset_n],
        ),
        Disturbance::Sine {
            period_s,
            amplitude_n,
            offset_n,
            first_rise_s,
        } => (
            keys(&["period_s", "amplitude_n", "first_rise_s", "offset_n"]),
            vec![*period_s, *amplitude_n, *first_rise_s, *offset_n],
        ),
        Disturbance::Steps { times_s, levels_n } => (
            keys(&["steps", "largest_level_n"]),
            vec![
                times_s.len() as f64,
                levels_n.iter().fold(0.0f64, |m, l| m.max(l.abs())),
            ],
        ),
        Disturbance::Windows(w) => (
            keys(&["windows", "largest_force_n"]),
            vec![
                w.len() as f64,
                w.iter().fold(0.0f64, |m, e| m.max(e.force_n.abs())),
            ],
        ),
    }
}

/// A periodic wave found in a residual: the force on the table, whether it was read off
/// the position residual, its peak ratio and share explained.
struct Wave {
    dist: Disturbance,
    from_position: bool,
    peak_ratio: f64,
    explained: f64,
}

/// The strongest periodic wave in the unexplained force (`rem_force`) or position
/// (`rem_pos`) that passes its detector's thresholds, as a force on the table.
fn periodic_wave(ctx: &Context, rem_force: Option<&[f64]>, rem_pos: &[f64]) -> Option<Wave> {
    let dt = ctx.eng.split.main.t3_s;
    let t0 = ctx.sig.t_s.first().copied().unwrap_or(0.0);
    let span = dt * rem_pos.len() as f64;
    let max_period_s = (span / 3.0).min(MAX_PERIOD_S);
    let find = |y: &[f64], min_explained: f64| {
        evidence::periodic_in_time(y, t0, dt, MIN_PERIOD_S, max_period_s)
            .filter(|p| p.peak_ratio >= MIN_PEAK_RATIO && p.explained >= min_explained)
    };
    // The motor opposes a force on the table: the force residual is the force inverted.
    let in_force = rem_force.and_then(|f| find(f, MIN_EXPLAINED_FORCE).map(|p| (p, -1.0)));
    let pos_min = if rem_force.is_some() {
        MIN_EXPLAINED_POS
    } else {
        MIN_EXPLAINED_FORCE
    };
    let in_pos = find(rem_pos, pos_min).map(|p| (p, loop_stiffness_n_per_m(ctx)));
    let from_position = match (&in_force, &in_pos) {
        (Some(f), Some(p)) => p.0.explained > f.0.explained,
        (None, Some(_)) => true,
        _ => false,
    };
    let (p, gain) = if from_position { in_pos } else { in_force }?;
    Some(Wave {
        dist: wave(&p, gain),
        from_position,
        peak_ratio: p.peak_ratio,
        explained: p.explained,
    })
}

/// Where a wave read off the position residual acts: on the table or in the amplifier's
/// output. The two move the axis alike and differ only in the force channel, so one replay
/// of each decides (on a record without force they are the same; the table is kept).
fn place(ctx: &Context, w: &Wave) -> Result<Disturbance, DiagnoseError> {
    let on_table = w.dist.clone();
    if !w.from_position || !ctx.eng.has_force {
        return Ok(on_table);
    }
    let in_command = Disturbance::InCommand(Box::new(on_table.clone()));
    let cost = |d: &Disturbance| -> Result<f64, DiagnoseError> {
        let mut c = ctx.base.clone();
        c.model.disturbance.push(d.clone());
        Ok(ctx.eng.lm_rows(&ctx.eng.sim_fit(&c, false)?).norm_squared())
    };
    Ok(if cost(&in_command)? < cost(&on_table)? {
        in_command
    } else {
        on_table
    })
}

/// The force no state explains.
pub struct External;

/// The shapes the detectors find in what no state explains.
struct Found {
    wave: Option<Wave>,
    steps: Vec<evidence::Step>,
    bursts: Vec<evidence::Burst>,
}

fn detect(ctx: &Context) -> Found {
    let s = ctx.sig;
    let dt = ctx.eng.split.main.t3_s;
    let rem_force = s.r_force.as_deref().map(|f| unexplained(s, f));
    let rem_pos = unexplained(s, &s.r_pos);
    let wave = periodic_wave(ctx, rem_force.as_deref(), &rem_pos);
    let min_gap = ((0.5 / dt) as usize).max(4);
    let end_gap = ((STEP_END_GAP_S / dt) as usize).clamp(4, min_gap);
    let y = s.r_force.as_deref().unwrap_or(&s.r_pos);
    let steps = stepped_steps(s, y, min_gap, end_gap);
    let rem = rem_force.as_deref().unwrap_or(&rem_pos);
    let window = ((0.02 / dt) as usize).max(4);
    let mut bursts = evidence::bursts(rem, window, 10.0);
    // A wave read off the position may sit in the amplifier's output, where the force
    // residual keeps only its edges, which look like bursts.
    if bursts.len() > MAX_BURSTS || wave.as_ref().is_some_and(|w| w.from_position) {
        bursts.clear();
    }
    Found {
        wave,
        steps,
        bursts,
    }
}

impl Candidate for External {
    fn effect(&self) -> Effect {
        Effect::ExternalDisturbance
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        let f = detect(ctx);
        let mut parts = vec![];
        let mut ev = Evidence::default();
        if let Some(w) = &f.wave {
            let (shape, period_s) = match &w.dist {
                Disturbance::Square { period_s, .. } => ("square", *period_s),
                Disturbance::Sine { period_s, .. } => ("sine", *period_s),
                _ => ("", 0.0),
            };
            parts.push(format!(
                "a {shape} wave of period {period_s:.4} s in the {} residual, {:.0}× the median of its spectrum, {:.0} % of what no state explains",
                if w.from_position { "position" } else { "force" },
                w.peak_ratio,
                100.0 * w.explained
            ));
            ev = ev
                .with("period_s", period_s)
                .with("peak_ratio", w.peak_ratio)
                .with("explained_share", w.explained);
        }
        if !f.steps.is_empty() {
            parts.push(format!("{} level steps", f.steps.len()));
            ev = ev.with("steps", f.steps.len() as f64);
        }
        if !f.bursts.is_empty() {
            parts.push(format!("{} bursts", f.bursts.len()));
            ev = ev.with("bursts", f.bursts.len() as f64);
        }
        if parts.is_empty() {
            return Evidence::absent(
                "the force no state explains is neither periodic nor stepped nor bursty",
            );
        }
        Evidence {
            pass: f.wave.is_some(),
            text: format!("in what no state explains: {}", parts.join("; ")),
            detail: Some(Detail::new(f)),
            ..ev
        }
    }

    fn variants(&self, ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let found;
        let f = match ev.detail::<Found>() {
            Some(f) => f,
            None => {
                found = detect(ctx);
                &found
            }
        };
        let dt = ctx.eng.split.main.t3_s;
        let t0 = ctx.sig.t_s.first().copied().unwrap_or(0.0);
        let t_end = t0 + ctx.sig.t_s.len() as f64 * dt;
        let fixed = |d: Disturbance, n_params: usize| {
            let (keys, theta) = describe(&d);
            let mut theta = theta;
            let mut keys = keys;
            if matches!(d, Disturbance::InCommand(_)) {
                keys.push("in_command".into());
                theta.push(1.0);
            }
            Fixed {
                shape: Shape::Disturbance(d),
                keys,
                theta,
                n_params,
            }
        };
        let mut out = vec![];
        if let Some(w) = &f.wave {
            let d = refine(ctx, place(ctx, w)?)?;
            let n = if matches!(w.dist, Disturbance::Square { .. }) {
                5
            } else {
                3
            };
            out.push(Variant::fixed(
                "wave",
                "a periodic wave, which predicts its held-out part",
                fixed(d, n),
                Part::Held,
            ));
        }
        if !f.steps.is_empty() {
            let mut times_s = vec![];
            let mut levels_n = vec![];
            let mut level = 0.0;
            for st in &f.steps {
                level -= st.jump;
                times_s.push(t0 + st.index as f64 * dt);
                levels_n.push(level);
            }
            // The model carries the steps over the fitting part only.
            times_s.push(t_end);
            levels_n.push(0.0);
            let n = 2 * f.steps.len();
            out.push(Variant::fixed(
                "steps",
                "level steps at times no state predicts: judged on the fitting part, their held-out part not predictable",
                fixed(Disturbance::Steps { times_s, levels_n }, n),
                Part::Fit,
            ));
        }
        if !f.bursts.is_empty() {
            let windows: Vec<ForceEvent> = f
                .bursts
                .iter()
                .map(|b| ForceEvent {
                    i0: b.start,
                    i1: b.end,
                    force_n: -b.mean,
                })
                .collect();
            let n = 3 * windows.len();
            let d = refine(ctx, Disturbance::Windows(windows))?;
            out.push(Variant::fixed(
                "bursts",
                "bursts at times no state predicts: judged on the fitting part, their held-out part not predictable",
                fixed(d, n),
                Part::Fit,
            ));
        }
        Ok(out)
    }
}
