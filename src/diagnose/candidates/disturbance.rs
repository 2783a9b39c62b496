//! The external disturbance: force that follows no state of the axis (a periodic wave,
//! level steps or bursts), found in what the state regressors leave of the residuals.
//!
//! A force on the axis shows in two places: the force residual (the amplifier opposes a
//! force pushed on the table from outside) and the position residual (the loop gives way
//! by force / stiffness). A force injected into the amplifier's own output shows only in
//! the position: the record's force channel carries it, so the force residual keeps no
//! trace of it but the edges. A periodic wave is therefore searched in both residuals, and
//! the site that replays better is kept.

use super::{Context, Evidence, Fitted, Signals, special};
use crate::diagnose::DiagnoseError;
use crate::diagnose::effects::Effect;
use crate::diagnose::evidence::{self, Periodic, WaveShape};
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

/// Level steps or bursts replace a periodic wave when they leave at most this share of what
/// the wave leaves of the unexplained force. Set on the independent generator's stepped
/// records of seeds 808, 909 and 1111, where a 5–6 s "square wave" stood for two or three
/// steps, and a bursty one of seed 808 (a 3.1 s wave for three bursts).
const STEPS_OVER_WAVE: f64 = 0.5;

/// More bursts than this are no bursts but a busy residual.
const MAX_BURSTS: usize = 400;

/// At most this many steps rival a wave: a few lasting changes, not a staircase that traces
/// a slow sine (seed 1111: a 5 s sine read as ten steps).
const WAVE_RIVAL_STEPS: usize = 5;

/// Shortest period searched, s.
const MIN_PERIOD_S: f64 = 0.1;

/// Longest period searched, s (and at most a third of the fitting part).
const MAX_PERIOD_S: f64 = 10.0;

/// What the detector shaped: the disturbance as a force on the table, and whether its
/// wave was read off the position residual (so that it may as well sit in the amplifier's
/// output; the fit decides).
pub struct Shaped {
    /// The disturbance, as a force on the table.
    pub dist: Disturbance,
    /// Whether a periodic wave was found in the position residual.
    pub from_position: bool,
    /// The periodic wave's figures: peak over the median of its periodogram, and the share
    /// of the unexplained residual it explains (0 for steps and bursts).
    pub peak_explained: (f64, f64),
}

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

/// `y` through the moving average a round scores slow effects by (`Engine::smooth_n`),
/// when that round follows an effect proven by its signature alone: a hunting drive's
/// steady tone (250–400 Hz, tens of N) or a grid's rounding stays in the residual the
/// detector reads, and lifts the median window a burst must stand above (4949 case_070:
/// bursts of 52–144 N beside a 51 N rms tone were read as ten level steps). Else `y`.
fn toneless(ctx: &Context, y: &[f64]) -> Vec<f64> {
    let n = ctx.eng.smooth_n;
    if n > 1 {
        crate::diagnose::engine::moving_average(y, n)
    } else {
        y.to_vec()
    }
}

/// Least time between the last level step and the fitting part's end, s: the force
/// residual follows a step within a few tens of ms.
const STEP_END_GAP_S: f64 = 0.1;

/// Rounds of [`stepped_steps`]'s joint fit: the second round's steps rarely move.
const STEP_JOINT_ROUNDS: usize = 2;

/// The level steps of `y` fitted jointly with its states (direction, speed, acceleration,
/// a constant; see [`unexplained`]). A force that changes level at times the program's moves
/// share is partly taken by the speed or direction term when the states are fitted alone
/// (2929 case_062: −312 N·s/m from three level steps), which leaves a residual that is no
/// longer piecewise constant; fitting the steps with the states gives the states back
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

/// The strongest periodic wave in the unexplained force (`rem_force`) or position
/// (`rem_pos`) that passes its thresholds, as a force on the table.
fn periodic_wave(ctx: &Context, rem_force: Option<&[f64]>, rem_pos: &[f64]) -> Option<Shaped> {
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
    Some(Shaped {
        dist: wave(&p, gain),
        from_position,
        peak_explained: (p.peak_ratio, p.explained),
    })
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

/// The evidence of a periodic wave.
fn wave_evidence(w: &Shaped) -> Evidence {
    let (peak_ratio, explained) = w.peak_explained;
    let (shape, period_s, amplitude_n, rise_s, duty) = match &w.dist {
        Disturbance::Square {
            period_s,
            duty,
            amplitude_n,
            first_rise_s,
            ..
        } => ("square", *period_s, *amplitude_n, *first_rise_s, *duty),
        Disturbance::Sine {
            period_s,
            amplitude_n,
            first_rise_s,
            ..
        } => ("sine", *period_s, *amplitude_n, *first_rise_s, 0.5),
        _ => ("", 0.0, 0.0, 0.0, 0.0),
    };
    let seen = if w.from_position {
        "the position residual"
    } else {
        "the force residual"
    };
    Evidence {
        pass: true,
        text: format!(
            "a {shape} force of period {period_s:.4} s and ±{amplitude_n:.2} N no state explains, rising at {rise_s:.3} s (+ k periods), seen in {seen}: {peak_ratio:.0}× the median of its spectrum, {:.0} % of what no state explains",
            100.0 * explained
        ),
        ..Evidence::default()
    }
    .with("period_s", period_s)
    .with("amplitude_n", amplitude_n)
    .with("first_rise_s", rise_s)
    .with("duty", duty)
    .with("peak_ratio", peak_ratio)
    .with("explained_share", explained)
    .with("from_position", if w.from_position { 1.0 } else { 0.0 })
}

/// The part of the residuals no state of the axis explains, and what shape it has: a
/// periodic wave, level steps or bursts.
pub fn detect(ctx: &Context) -> (Evidence, Option<Shaped>) {
    let s = ctx.sig;
    let dt = ctx.eng.split.main.t3_s;
    let r_force = s.r_force.as_deref().map(|f| toneless(ctx, f));
    let r_pos = toneless(ctx, &s.r_pos);
    let rem_force = r_force.as_deref().map(|f| unexplained(s, f));
    let rem_pos = unexplained(s, &r_pos);
    let min_gap = ((0.5 / dt) as usize).max(4);
    if let Some(w) = periodic_wave(ctx, rem_force.as_deref(), &rem_pos) {
        // A few lasting level changes, or a few bursts, make a long period's peak too; when
        // either leaves far less of the unexplained force than the wave does, the force is
        // stepped or bursty.
        let window = ((0.02 / dt) as usize).max(4);
        let not_a_wave = rem_force.as_deref().is_some_and(|f| {
            let wave_left = STEPS_OVER_WAVE * wave_sse(f, &s.t_s, &w.dist);
            let st = evidence::steps(f, min_gap, 10.0, WAVE_RIVAL_STEPS);
            let bu = evidence::bursts(f, window, 10.0);
            // A wave read off the position may sit in the amplifier's output, where the force
            // residual keeps only its edges, which look like bursts (the EMPS pulse record).
            let bursty = !w.from_position && !bu.is_empty() && bu.len() <= MAX_BURSTS;
            (!st.is_empty() && centred_steps_sse(f, &st) <= wave_left)
                || (bursty && bursts_sse(f, &bu) <= wave_left)
        });
        if !not_a_wave {
            let ev = wave_evidence(&w);
            return (ev, Some(w));
        }
    }
    let t0 = s.t_s.first().copied().unwrap_or(0.0);
    let table = |dist| {
        Some(Shaped {
            dist,
            from_position: false,
            peak_explained: (0.0, 0.0),
        })
    };
    let rem = rem_force.unwrap_or(rem_pos);
    let plain = evidence::steps(&rem, min_gap, 10.0, 10);
    let window = ((0.02 / dt) as usize).max(4);
    let bursts = evidence::bursts(&rem, window, 10.0);
    let bursts_ok = !bursts.is_empty() && bursts.len() <= MAX_BURSTS;
    // A burst is two opposite level changes close together: the step search (at least
    // 0.5 s between steps) takes one edge of each for a lasting step. When both shapes are
    // there, the one that leaves less of the unexplained force wins, both read off the
    // same residual (steps fitted with the states would win against bursts by their
    // extra columns alone: our own generator's case 66, three bursts).
    let steps_first =
        !plain.is_empty() && (!bursts_ok || steps_sse(&rem, &plain) <= bursts_sse(&rem, &bursts));
    if steps_first {
        // Their times and levels come from the fit with the states; the last step may lie
        // closer to the end, since the held-out part takes its level.
        let end_gap = ((STEP_END_GAP_S / dt) as usize).clamp(4, min_gap);
        let joint = stepped_steps(s, r_force.as_deref().unwrap_or(&r_pos), min_gap, end_gap);
        let steps = if joint.is_empty() { plain } else { joint };
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
        return (ev, table(Disturbance::Steps { times_s, levels_n }));
    }
    if !bursts_ok {
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
    (ev, table(Disturbance::Windows(windows)))
}

/// What a level-step reading leaves of `y`: y minus the level the steps reach (0 before the
/// first, as [`Disturbance::Steps`] has it), squared and summed.
fn steps_sse(y: &[f64], steps: &[evidence::Step]) -> f64 {
    let mut level = 0.0;
    let mut next = steps.iter().peekable();
    let mut sse = 0.0;
    for (k, v) in y.iter().enumerate() {
        while let Some(st) = next.next_if(|st| st.index <= k) {
            level += st.jump;
        }
        sse += (v - level) * (v - level);
    }
    sse
}

/// What the wave `d` leaves of `y` (sampled at `t_s`) at its least-squares level and scale:
/// the wave at its best, whichever residual it was read off.
fn wave_sse(y: &[f64], t_s: &[f64], d: &Disturbance) -> f64 {
    let w: Vec<f64> = t_s.iter().take(y.len()).map(|&t| d.force_at(t)).collect();
    let y = &y[..w.len()];
    let n = w.len().max(1) as f64;
    let (mw, my) = (w.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let (mut sww, mut swy, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in w.iter().zip(y) {
        let (dw, dy) = (a - mw, b - my);
        sww += dw * dw;
        swy += dw * dy;
        syy += dy * dy;
    }
    let explained = if sww > 0.0 { swy * swy / sww } else { 0.0 };
    (syy - explained).max(0.0)
}

/// [`steps_sse`] about the best level before the first step: the regression that leaves
/// the unexplained force takes its mean out, so the steps' levels sit off zero there.
fn centred_steps_sse(y: &[f64], steps: &[evidence::Step]) -> f64 {
    let mut level = 0.0;
    let mut next = steps.iter().peekable();
    let (mut sum, mut sum_sq) = (0.0, 0.0);
    for (k, v) in y.iter().enumerate() {
        while let Some(st) = next.next_if(|st| st.index <= k) {
            level += st.jump;
        }
        let e = v - level;
        sum += e;
        sum_sq += e * e;
    }
    (sum_sq - sum * sum / y.len().max(1) as f64).max(0.0)
}

/// What a burst reading leaves of `y`: inside each burst y minus its mean, elsewhere y.
fn bursts_sse(y: &[f64], bursts: &[evidence::Burst]) -> f64 {
    let mut sse: f64 = y.iter().map(|v| v * v).sum();
    for b in bursts {
        let seg = &y[b.start.min(y.len())..b.end.min(y.len())];
        let before: f64 = seg.iter().map(|v| v * v).sum();
        let after: f64 = seg.iter().map(|v| (v - b.mean) * (v - b.mean)).sum();
        sse += after - before;
    }
    sse
}

/// Where a wave read off the position residual acts: on the table or in the amplifier's
/// output. The two move the axis alike and differ only in the force channel, so one replay
/// of each decides (on a record without force they are the same; the table is kept).
fn place(ctx: &Context, shaped: Shaped) -> Result<Disturbance, DiagnoseError> {
    let on_table = shaped.dist;
    if !shaped.from_position || !ctx.eng.has_force {
        return Ok(on_table);
    }
    let in_command = Disturbance::InCommand(Box::new(on_table.clone()));
    let cost = |d: &Disturbance| -> Result<f64, DiagnoseError> {
        let mut c = ctx.base.clone();
        c.model.disturbance.push(d.clone());
        Ok(ctx.eng.lm_rows(&ctx.eng.sim_fit(&c)?).norm_squared())
    };
    Ok(if cost(&in_command)? < cost(&on_table)? {
        in_command
    } else {
        on_table
    })
}

/// The disturbance the detector shaped, placed, its level (and for a wave its edge)
/// refined on replays.
pub fn fit(ctx: &Context) -> Result<Option<Fitted>, DiagnoseError> {
    let (ev, shaped) = detect(ctx);
    let (Some(shaped), true) = (shaped, ev.pass) else {
        return Ok(None);
    };
    let placed = place(ctx, shaped)?;
    let detected = placed.clone();
    let d = refine(ctx, placed)?;
    let (d, d_val) = time_held_out_bursts(ctx, d, &detected);
    let applied = super::Applied::Disturbance(d.clone(), d_val);
    let mut cand = ctx.base.clone();
    applied.apply(&mut cand);
    let eval = ctx.eng.evaluate(&cand)?;
    let (keys, theta) = describe(&d);
    let mut f = special::fitted(
        ctx,
        special::Made {
            effect: Effect::ExternalDisturbance,
            cand,
            eval,
            keys,
            theta,
            applied,
        },
        ev,
    );
    if matches!(d, Disturbance::InCommand(_)) {
        f.extra.insert("in_command".into(), 1.0);
    }
    // Shape (period, duty, step times or window edges) is found by the detector: counted
    // as parameters too.
    f.n_params = f.theta.len().max(3);
    Ok(Some(f))
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
        Ok(self.ctx.eng.lm_rows(&self.ctx.eng.sim_fit(&c)?) - &self.r0)
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
        r0: ctx.eng.lm_rows(&ctx.eng.sim_fit(ctx.base)?),
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

/// Bursts come at times no state predicts, so the held-out part's own bursts are timed by
/// the same detector on the held-out residual; their size is the fitting part's (the
/// median level found there, signed as the held-out residual leans). The held-out check
/// then asks whether bursts of that size explain what the held-out part shows. Returns the
/// disturbance on the main record (fitting windows plus, when the held-out part is the
/// record's end, its windows) and those on a validation record. A held-out stretch counts
/// as a burst only if it looks like those of the fitting part (`detected`, before the
/// levels were refined): no longer than twice the longest, and a residual at least half as
/// large as their median.
fn time_held_out_bursts(
    ctx: &Context,
    d: Disturbance,
    detected: &Disturbance,
) -> (Disturbance, Vec<Disturbance>) {
    let (Disturbance::Windows(mut w), Disturbance::Windows(seen)) = (d.clone(), detected) else {
        return (d, vec![]);
    };
    let mut seen_abs: Vec<f64> = seen.iter().map(|e| e.force_n.abs()).collect();
    seen_abs.sort_by(f64::total_cmp);
    let seen_level = seen_abs.get(seen_abs.len() / 2).copied().unwrap_or(0.0);
    let longest = seen.iter().map(|e| e.i1 - e.i0).max().unwrap_or(0);
    let mut levels: Vec<f64> = w.iter().map(|e| e.force_n.abs()).collect();
    if levels.is_empty() {
        return (Disturbance::Windows(w), vec![]);
    }
    levels.sort_by(f64::total_cmp);
    let level = levels[levels.len() / 2];
    let dt = ctx.eng.split.main.t3_s;
    let window = ((0.02 / dt) as usize).max(4);
    let y = toneless(
        ctx,
        ctx.base_eval
            .hold_force
            .as_deref()
            .unwrap_or(&ctx.base_eval.hold_pos),
    );
    let held: Vec<ForceEvent> = evidence::bursts(&y, window, 10.0)
        .into_iter()
        .filter(|b| b.end - b.start <= 2 * longest && b.mean.abs() >= 0.5 * seen_level)
        .take(400)
        .map(|b| ForceEvent {
            i0: b.start,
            i1: b.end,
            force_n: -level.copysign(b.mean),
        })
        .collect();
    if ctx.eng.split.validate.is_some() {
        return (Disturbance::Windows(w), vec![Disturbance::Windows(held)]);
    }
    let off = ctx.eng.split.n_fit;
    w.extend(held.into_iter().map(|e| ForceEvent {
        i0: e.i0 + off,
        i1: e.i1 + off,
        ..e
    }));
    (Disturbance::Windows(w), vec![])
}

/// A sine's amplitude and phase: its sine and cosine parts are two linear columns, so two
/// replays fit them exactly for a linear loop. The sine is fitted without a mean: a mean
/// beside it is a constant force, which the next round names (2828 case_066: a sine of
/// 19 N beside a cable carrier's −35 N, the sine's offset took the carrier's force and the
/// constant force was not named). A square wave keeps its offset: which of its two levels
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

#[cfg(test)]
mod tests {
    use super::{bursts_sse, steps_sse};
    use crate::diagnose::evidence;

    /// Two bursts of opposite sign in noise: the step search (steps at least 0.5 s apart)
    /// reads one edge of each as a lasting level; the burst reading leaves far less.
    #[test]
    fn bursts_are_not_read_as_level_steps() {
        let dt = 0.001;
        let mut y: Vec<f64> = (0..20_000)
            .map(|k| 2.0 * ((k as f64 * 12.9898).sin() * 43_758.545).fract())
            .collect();
        y[3000..3100].iter_mut().for_each(|v| *v += 100.0);
        y[12_000..12_150].iter_mut().for_each(|v| *v -= 120.0);
        let st = evidence::steps(&y, (0.5 / dt) as usize, 10.0, 10);
        let bu = evidence::bursts(&y, 20, 10.0);
        assert_eq!(bu.len(), 2, "{bu:?}");
        assert!((bu[0].mean - 100.0).abs() < 25.0, "{bu:?}");
        let (s, b) = (steps_sse(&y, &st), bursts_sse(&y, &bu));
        // The bursts hold 100²·100 + 120²·150 ≈ 3.2e6; what their reading leaves is the
        // noise (≈ 27 000) and the windows' overhang at the edges.
        assert!(b < 0.5 * s, "bursts leave {b}, steps {s}");
        assert!(b < 0.3 * 3.2e6, "bursts leave {b}");
    }
}
