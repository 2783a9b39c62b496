//! Calibrate first, then look for effects.
//!
//! A nominal preset is never exact: masses, friction and gains are off by a few per cent.
//! Left alone, that mismatch is the largest residual, and whichever candidate mimics it
//! best (a delay, a viscous correction) gets the blame. So the nominal's own parameters are
//! re-fitted first, within ±8 % (the mass, read over the force constant, ±11 %), and so is
//! the shape of a term the nominal already has: a Coulomb level that builds up over a small
//! speed (tanh) instead of sticking is the same friction, reshaped, not a new effect.
//!
//! At the same time each measured channel gets a time shift: position and force may be
//! logged a little before or after the instant the command was. A shift of one channel
//! alone, or a lead of both (the command logged late), is a logging skew: a measurement
//! finding, taken when the criterion says the shifted model wins, and removed from the
//! record before any effect is tested. A lag of both is how the machine responds late: a
//! command delay, left to that candidate.

use std::sync::Mutex;

use serde::Serialize;

use super::criterion::{self, Judgement, Part, Scale};
use super::engine::{Cand, Engine, Eval, at};
use super::lm::{self, Param};
use super::replay::{Model, Record};
use super::{DiagnoseError, Effect};
use crate::preset::AxisParams;

/// Largest calibration change of a ratio: beyond it a parameter is not mis-set but missing
/// an effect. Nominals are typically off by a few per cent; a mass and a force constant off
/// in opposite directions make close to 8 %.
pub const MAX_RATIO_CHANGE: f64 = 0.08;
/// Largest calibration change of the moving mass. The record's force is the commanded one,
/// so the mass is read over the motor's force constant: a mass and a force constant each a
/// few per cent off in opposite directions make up to 10.5 %.
pub const MAX_MASS_RATIO_CHANGE: f64 = 0.11;
/// Largest speed a nominal Coulomb level may build up over, mm/s: the smooth friction laws
/// of the literature (tanh, LuGre's steady state) reach their level within a few mm/s.
pub const MAX_SMOOTHING_MM_PER_S: f64 = 5.0;
/// The solver's patience in the calibration (evaluations per parameter): every candidate
/// is judged against the calibrated model, so it must sit at its optimum, not where a
/// short solve along a valley of the gains stopped.
const CALIBRATION_PATIENCE: usize = 20;
/// Largest command delay the calibration takes, samples: half a period. A drive samples
/// its command and holds it, and a hold lags by half a period on average; how a real loop
/// and the replay's discretisation place that half period differs from machine to machine
/// and is no effect. A command delay beyond it is the candidate's.
pub const MAX_CAL_DELAY_SAMPLES: f64 = 0.5;
/// Largest channel shift searched, samples.
const MAX_SHIFT: f64 = 8.0;
/// A difference of the two channels' shifts below this is one shift of both, samples: a
/// fifth of a sample is what the replay's linear interpolation between samples resolves.
pub const MIN_SKEW: f64 = 0.2;

/// A nominal parameter the calibration re-fits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CalParam {
    /// The moving mass (ratio): table and the motor's reflected inertia.
    Mass,
    /// Viscous friction (ratio).
    Viscous,
    /// Coulomb (and breakaway) friction (ratio), when the nominal has it.
    Coulomb,
    /// The speed the nominal Coulomb level builds up over, mm/s (0: exact stick).
    Smoothing,
    /// Position-loop gain (ratio).
    Kp,
    /// Velocity-loop gain (ratio).
    Kv,
    /// A command delay within half a sample, samples (see [`MAX_CAL_DELAY_SAMPLES`]).
    Delay,
}

impl CalParam {
    /// The name in reports.
    pub fn name(self) -> &'static str {
        match self {
            CalParam::Mass => "mass",
            CalParam::Viscous => "viscous_friction",
            CalParam::Coulomb => "coulomb_friction",
            CalParam::Smoothing => "coulomb_smoothing_mm_per_s",
            CalParam::Kp => "kp",
            CalParam::Kv => "kv",
            CalParam::Delay => "delay_samples",
        }
    }

    /// The value that leaves the nominal as it is.
    pub fn neutral(self) -> f64 {
        match self {
            CalParam::Smoothing | CalParam::Delay => 0.0,
            _ => 1.0,
        }
    }

    /// The solver's bounds.
    pub fn bounds(self) -> Param {
        let ratio = |m: f64| Param {
            lo: 1.0 - m,
            hi: 1.0 + m,
            scale: 1.0,
        };
        match self {
            CalParam::Mass => ratio(MAX_MASS_RATIO_CHANGE),
            CalParam::Smoothing => Param {
                lo: 0.0,
                hi: MAX_SMOOTHING_MM_PER_S,
                scale: 0.5,
            },
            CalParam::Delay => Param {
                lo: -MAX_CAL_DELAY_SAMPLES,
                hi: MAX_CAL_DELAY_SAMPLES,
                scale: 0.1,
            },
            _ => ratio(MAX_RATIO_CHANGE),
        }
    }

    /// Whether `v` lies at this parameter's bound (more than a correction).
    pub fn at_bound(self, v: f64) -> bool {
        let b = self.bounds();
        let tol = 0.005 * (b.hi - b.lo);
        !matches!(self, CalParam::Smoothing) && (v < b.lo + tol || v > b.hi - tol)
    }

    /// The parameters worth calibrating on `a`: those it has (a Coulomb level of 0 is an
    /// effect left out, not a value to scale or reshape).
    pub fn of(a: &AxisParams) -> Vec<CalParam> {
        let mut v = vec![CalParam::Mass];
        if a.friction.enabled && a.friction.viscous_n_s_per_m > 0.0 {
            v.push(CalParam::Viscous);
        }
        if a.friction.enabled && a.friction.coulomb_n > 0.0 {
            v.extend([CalParam::Coulomb, CalParam::Smoothing]);
        }
        v.extend([CalParam::Kp, CalParam::Kv, CalParam::Delay]);
        v
    }

    /// Sets this parameter of `m` to `v` (a ratio scales the nominal's value).
    pub fn apply(self, m: &mut Model, v: f64) {
        if self == CalParam::Delay {
            m.delay_s += v * m.t3_s;
            return;
        }
        let a = &mut m.axis;
        match self {
            CalParam::Mass => {
                a.drive.table_mass_kg *= v;
                a.drive.motor_inertia_kgm2 *= v;
            }
            CalParam::Viscous => a.friction.viscous_n_s_per_m *= v,
            CalParam::Coulomb => {
                a.friction.coulomb_n *= v;
                a.friction.stribeck.static_n *= v;
            }
            CalParam::Smoothing => a.friction.coulomb_smoothing_mm_per_s = v.max(0.0),
            CalParam::Kp => a.servo.kp_per_s *= v,
            CalParam::Kv => a.servo.kv_n_s_per_m *= v,
            CalParam::Delay => {}
        }
    }
}

/// A measured channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Channel {
    /// The command.
    Cmd,
    /// The position.
    Pos,
    /// The force.
    Force,
}

/// A channel logged off its instant: it shows the value of `samples` periods later (+) or
/// earlier (−) than its time stamp.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Skew {
    /// Which channel.
    pub channel: Channel,
    /// How far, in samples.
    pub samples: f64,
}

/// What the calibration found.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    /// Each re-fitted parameter and its value (a ratio to the nominal, or a speed).
    pub ratios: Vec<(CalParam, f64)>,
    /// Parameters that hit their bound: the nominal lacks more than a correction.
    pub at_bound: Vec<CalParam>,
    /// Fitted time shift of the position channel against the model, samples (+: the
    /// record shows the model's value that many samples later).
    pub pos_shift_samples: f64,
    /// Fitted time shift of the force channel, samples.
    pub force_shift_samples: f64,
    /// The logging skew the shifts read, whether taken or not.
    pub skew_read: Option<Skew>,
    /// The logging skew taken (removed from the record before effects are tested).
    pub skew: Option<Skew>,
    /// How the criterion judged the skew read.
    pub skew_judgement: Option<Judgement>,
    /// The lag both responses share (−: the machine responds late), samples: a command
    /// delay's signature.
    pub common_lag_samples: f64,
    /// Held-out level of the nominal (the calibrated model's fitting part is 1).
    pub level_nominal: f64,
    /// … of the calibrated model.
    pub level_calibrated: f64,
}

impl Calibration {
    /// The calibrated model: `nominal` with the parameters applied.
    pub fn apply(&self, nominal: &Cand) -> Cand {
        let mut c = nominal.clone();
        for &(p, r) in &self.ratios {
            p.apply(&mut c.model, r);
        }
        c
    }

    /// The values in `ratios`' order.
    pub fn values(&self) -> Vec<f64> {
        self.ratios.iter().map(|(_, v)| *v).collect()
    }

    /// A one-line summary for reports.
    pub fn summary(&self) -> String {
        let mut s = lines(&self.ratios).join(", ");
        match (self.skew, self.skew_read, &self.skew_judgement) {
            (Some(k), _, _) => {
                s += &format!(
                    "; the {:?} channel was logged {:+.2} samples off its instant and realigned",
                    k.channel, k.samples
                );
            }
            (None, Some(k), Some(j)) => {
                s += &format!(
                    "; the shifts read the {:?} channel {:+.2} samples off, which the criterion did not take ({})",
                    k.channel,
                    k.samples,
                    j.text()
                );
            }
            _ => {}
        }
        s
    }
}

/// The calibration as report lines (`mass ×1.021`, `coulomb_smoothing_mm_per_s 0.31`).
pub fn lines(ratios: &[(CalParam, f64)]) -> Vec<String> {
    ratios
        .iter()
        .map(|(p, r)| match p {
            CalParam::Smoothing | CalParam::Delay => format!("{} {r:.3}", p.name()),
            _ => format!("{} ×{r:.4}", p.name()),
        })
        .collect()
}

/// `base` with values `r` of the parameters `ps`, and the nuisance friction `nuisance` =
/// [Coulomb force added, constant force] (N).
fn with_ratios(base: &Cand, ps: &[CalParam], r: &[f64], nuisance: &[f64]) -> Cand {
    let mut c = base.clone();
    for (&p, &x) in ps.iter().zip(r) {
        p.apply(&mut c.model, x);
    }
    if let [fc, f0] = nuisance {
        Effect::CoulombFriction.apply(&[*fc], &mut c.model);
        Effect::ConstantForce.apply(&[*f0], &mut c.model);
    }
    c
}

/// Friction a nominal left out (a Coulomb level, a constant force) is nearly always there
/// and would otherwise pull the mass, the viscous friction and the gains, and with them the
/// channel shifts, off their values to mimic it. The calibration therefore fits both
/// alongside, as nuisance parameters, and keeps only the nominal's parameters: whether the
/// friction is there is the candidates' question.
const N_NUISANCE: usize = 2;

/// Fits the calibration parameters (from `from`, else neutral) and the nuisance friction
/// (see [`N_NUISANCE`]) on the engine's fitting part; with `shifts`, the two channel shifts
/// too. Returns the parameters and the shifts.
fn fit_ratios(
    eng: &Engine,
    base: &Cand,
    ps: &[CalParam],
    shifts: bool,
    from: Option<&[f64]>,
) -> Result<(Vec<f64>, f64, f64), DiagnoseError> {
    let n = ps.len();
    let force_scale = (0.01 * base.model.axis.drive.total_mass_kg() * 9.81).max(1.0);
    let mut params: Vec<Param> = ps.iter().map(|p| p.bounds()).collect();
    let n_nuisance = N_NUISANCE;
    {
        params.push(Param {
            lo: 0.0,
            hi: 1e4,
            scale: force_scale,
        });
        params.push(Param {
            lo: -1e4,
            hi: 1e4,
            scale: force_scale,
        });
    }
    let m = n + n_nuisance;
    if shifts {
        let sh = Param {
            lo: -MAX_SHIFT,
            hi: MAX_SHIFT,
            scale: 1.0,
        };
        params.extend([sh, sh]);
    }
    // The shifts only move the simulated output, so a replay is reused while the model's
    // parameters stay the same.
    let cache: Mutex<Option<(Vec<f64>, super::replay::SimOut)>> = Mutex::new(None);
    let rows = |th: &[f64]| {
        let model_part = &th[..m];
        let (up, uf) = if shifts {
            (th[m], th[m + 1])
        } else {
            (0.0, 0.0)
        };
        if let Ok(c) = cache.lock()
            && let Some((r, s)) = c.as_ref()
            && r == model_part
        {
            return Ok(Some(eng.lm_rows_shifted(s, up, uf)));
        }
        let s = eng.sim_fit(&with_ratios(base, ps, &th[..n], &th[n..m]), false)?;
        let rows = eng.lm_rows_shifted(&s, up, uf);
        if let Ok(mut c) = cache.lock() {
            *c = Some((model_part.to_vec(), s));
        }
        Ok(Some(rows))
    };
    let mut start: Vec<f64> = match from.filter(|r| r.len() == n) {
        Some(r) => r.to_vec(),
        None => ps.iter().map(|p| p.neutral()).collect(),
    };
    start.extend(std::iter::repeat_n(0.0, n_nuisance));
    if shifts {
        start.extend([0.0, 0.0]);
    }
    let f = lm::fit(&start, &params, &rows, 0.01, CALIBRATION_PATIENCE)?;
    let (up, uf) = if shifts {
        (f.theta[m], f.theta[m + 1])
    } else {
        (0.0, 0.0)
    };
    Ok((
        f.theta[..n].to_vec(),
        up,
        if eng.has_force { uf } else { up },
    ))
}

/// What the two fitted shifts mean (+: the record shows the model's value that many
/// samples later). A lag both channels share is the machine responding late, a command
/// delay (returned as the common lag, negative); a lead of both is the command logged
/// late, a skew of the command. Shifts that differ by [`MIN_SKEW`] or more are a skew of one
/// channel: the reading whose common part is no lead (a lead of the responses no machine
/// makes) and, of two such, the one with the smaller common part.
pub fn classify_shifts(pos: f64, force: Option<f64>) -> (Option<Skew>, f64) {
    let common_or_skew = |c: f64| {
        if c > 0.0 {
            (
                Some(Skew {
                    channel: Channel::Cmd,
                    samples: -c,
                }),
                0.0,
            )
        } else {
            (None, c)
        }
    };
    let Some(force) = force else {
        // Position alone: a lead is the command or the position logged late; a lag a delay.
        return if pos > 0.0 {
            (
                Some(Skew {
                    channel: Channel::Pos,
                    samples: pos,
                }),
                0.0,
            )
        } else {
            (None, pos)
        };
    };
    if (pos - force).abs() < MIN_SKEW {
        return common_or_skew(0.5 * (pos + force));
    }
    // The position skewed: the force shows the common part; or the other way round.
    let pos_skew = (
        Some(Skew {
            channel: Channel::Pos,
            samples: pos - force.min(0.0),
        }),
        force.min(0.0),
    );
    let force_skew = (
        Some(Skew {
            channel: Channel::Force,
            samples: force - pos.min(0.0),
        }),
        pos.min(0.0),
    );
    match (force <= 0.0, pos <= 0.0) {
        (true, false) => pos_skew,
        (false, true) => force_skew,
        (true, true) if force.abs() > pos.abs() => force_skew,
        _ => pos_skew,
    }
}

/// The record with a skewed channel realigned to its time stamps. Command and position
/// are smooth, and are interpolated by cubic (Catmull–Rom) segments: a straight line
/// between samples cuts the corners of an acceleration by a·T²/8, 0.1 µm at 1 m/s² and
/// 1 kHz, the size of the effects looked for. The force is a value held over each period,
/// and is interpolated linearly.
pub fn deskew(rec: &Record, skew: &Skew) -> Record {
    let shift = |v: &[f64]| -> Vec<f64> {
        (0..v.len())
            .map(|k| at_cubic(v, k as f64 - skew.samples))
            .collect()
    };
    let shift_held = |v: &[f64]| -> Vec<f64> {
        (0..v.len())
            .map(|k| at(v, k as f64 - skew.samples))
            .collect()
    };
    let mut r = rec.clone();
    match skew.channel {
        Channel::Pos => {
            r.pos_m = shift(&rec.pos_m);
            if r.logged_pos_m.is_none() && skew.samples.fract() != 0.0 {
                r.logged_pos_m = Some(rec.pos_m.clone());
            }
        }
        Channel::Force => r.force_n = rec.force_n.as_deref().map(shift_held),
        Channel::Cmd => {
            r.cmd_m = shift(&rec.cmd_m);
            r.comp_m = rec.comp_m.as_deref().map(shift);
        }
    }
    r
}

/// `v` at fractional index `x` by a Catmull–Rom cubic through the four samples around it
/// (exact for whole indices; ends held, and linear next to them).
fn at_cubic(v: &[f64], x: f64) -> f64 {
    let n = v.len();
    if n < 4 || x <= 1.0 || x >= (n - 2) as f64 {
        return at(v, x);
    }
    let i = x.floor() as usize;
    let t = x - i as f64;
    let (p0, p1, p2, p3) = (v[i - 1], v[i], v[i + 1], v[i + 2]);
    p1 + 0.5
        * t
        * ((p2 - p0)
            + t * ((2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) + t * (3.0 * (p1 - p2) + p3 - p0)))
}

/// The residual of `c` with the skew `s` taken out of the simulated channels instead of
/// the record (the same comparison, without a second record).
fn eval_with_skew(eng: &Engine, c: &Cand, s: &Skew) -> Result<Eval, DiagnoseError> {
    match s.channel {
        Channel::Cmd => {
            // The command logged late by |samples|: the model driven by the realigned command.
            let main = deskew(eng.split.main, s);
            let val = eng.split.validate.map(|v| deskew(v, s));
            let quiet = |_: f64, _: &str| {};
            let cancel = std::sync::atomic::AtomicBool::new(false);
            let p = super::Progress {
                report: &quiet,
                cancel: &cancel,
            };
            let split = super::engine::Split {
                main: &main,
                n_fit: eng.split.n_fit,
                validate: val.as_ref(),
            };
            let (_, ev) = Engine::new(split, c, &p)?;
            Ok(ev)
        }
        _ => {
            let ev = eng.evaluate(c)?;
            let shift = |meas_minus_sim: &[f64], part_meas: &[f64]| -> Vec<f64> {
                // sim = meas − r; the record's channel realigned is what the model is
                // compared with: r' = meas(k − s) − sim(k), as `deskew` realigns it.
                let sim: Vec<f64> = part_meas
                    .iter()
                    .zip(meas_minus_sim)
                    .map(|(m, r)| m - r)
                    .collect();
                (0..sim.len())
                    .map(|k| at(part_meas, k as f64 - s.samples) - sim[k])
                    .collect()
            };
            let main = eng.split.main;
            let nf = eng.split.n_fit;
            let (fit_meas, hold_meas): (&[f64], &[f64]) = match s.channel {
                Channel::Pos => (
                    &main.pos_m[..nf],
                    match eng.split.validate {
                        Some(v) => &v.pos_m,
                        None => &main.pos_m[nf..],
                    },
                ),
                _ => match (&main.force_n, eng.split.validate) {
                    (Some(f), None) => (&f[..nf], &f[nf..]),
                    (Some(f), Some(v)) => (&f[..nf], v.force_n.as_deref().unwrap_or(&[])),
                    (None, _) => return Ok(ev),
                },
            };
            Ok(match s.channel {
                Channel::Pos => Eval {
                    fit_pos: shift(&ev.fit_pos, fit_meas),
                    hold_pos: shift(&ev.hold_pos, hold_meas),
                    ..ev
                },
                _ => Eval {
                    fit_force: ev.fit_force.as_deref().map(|r| shift(r, fit_meas)),
                    hold_force: ev.hold_force.as_deref().map(|r| shift(r, hold_meas)),
                    ..ev
                },
            })
        }
    }
}

/// Fits the nominal's parameters and the channel shifts on `eng`'s fitting part, and judges
/// the skew the shifts read: taken when the model with it wins by the criterion.
pub fn fit(eng: &Engine, nominal: &Cand) -> Result<Calibration, DiagnoseError> {
    // A delay and a common shift of both channels are one parameter: the shifts are read
    // without the delay, which the fits without them take up.
    let mut ps: Vec<CalParam> = CalParam::of(&nominal.model.axis)
        .into_iter()
        .filter(|p| *p != CalParam::Delay)
        .collect();
    let (mut values, up, uf) = fit_ratios(eng, nominal, &ps, true, None)?;
    ps.push(CalParam::Delay);
    values.push(0.0);
    let (skew_read, common) = classify_shifts(up, eng.has_force.then_some(uf));
    let cal = Calibration {
        at_bound: at_bound(&ps, &values),
        ratios: ps.into_iter().zip(values).collect(),
        pos_shift_samples: up,
        force_shift_samples: uf,
        skew_read,
        skew: None,
        skew_judgement: None,
        common_lag_samples: common,
        level_nominal: 0.0,
        level_calibrated: 0.0,
    };
    let Some(s) = skew_read else {
        return Ok(cal);
    };
    let calibrated = cal.apply(nominal);
    let plain = eng.evaluate(&calibrated)?;
    let skewed = eval_with_skew(eng, &calibrated, &s)?;
    let scale = Scale::new(&plain, eng.corr_len, 0.0);
    let j = criterion::judge(&scale, &plain, &skewed, Part::Held, 1, 0.0);
    Ok(Calibration {
        skew: j.passes.then_some(s),
        skew_judgement: Some(j),
        ..cal
    })
}

fn at_bound(ps: &[CalParam], values: &[f64]) -> Vec<CalParam> {
    ps.iter()
        .zip(values)
        .filter(|(p, v)| p.at_bound(**v))
        .map(|(p, _)| *p)
        .collect()
}

/// Re-fits the nominal's parameters without the channel shifts (they were read beside a
/// common lag that is not kept): from neutral values when `fresh` (a fit from the shifted
/// reading's values starts on its bounds, where the solver's clamped steps cannot tell
/// which way is in), else from `cal`'s.
pub fn refit(
    eng: &Engine,
    nominal: &Cand,
    cal: &mut Calibration,
    fresh: bool,
) -> Result<(), DiagnoseError> {
    let ps: Vec<CalParam> = cal.ratios.iter().map(|(p, _)| *p).collect();
    let now = cal.values();
    let from = (!fresh).then_some(now.as_slice());
    let (values, _, _) = fit_ratios(eng, nominal, &ps, false, from)?;
    cal.at_bound = at_bound(&ps, &values);
    cal.ratios = ps.into_iter().zip(values).collect();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Catmull–Rom segments reproduce a parabola exactly (a constant acceleration), where a
    /// straight line between samples is off by a·T²/8 in mid-period.
    #[test]
    fn cubic_realignment_is_exact_for_a_constant_acceleration() {
        let v: Vec<f64> = (0..10).map(|k| f64::from(k * k)).collect();
        assert!((at_cubic(&v, 4.5) - 20.25).abs() < 1e-12);
        assert!((at(&v, 4.5) - 20.25 - 0.25).abs() < 1e-12);
        assert_eq!(at_cubic(&v, 6.0), 36.0);
    }

    /// The readings of the two shifts: a common lag is a delay, a common lead the command
    /// logged late, one channel off a skew of that channel.
    #[test]
    fn shifts_are_read_as_a_delay_a_late_command_or_one_skewed_channel() {
        assert_eq!(classify_shifts(-0.7, Some(-0.75)), (None, -0.725));
        let (s, c) = classify_shifts(0.5, Some(0.5));
        assert_eq!(s.map(|s| s.channel), Some(Channel::Cmd));
        assert_eq!(c, 0.0);
        let (s, c) = classify_shifts(-1.0, Some(0.0));
        assert_eq!(
            s.map(|s| (s.channel, s.samples)),
            Some((Channel::Pos, -1.0))
        );
        assert_eq!(c, 0.0);
        let (s, c) = classify_shifts(0.6, Some(-0.2));
        assert_eq!(s.map(|s| (s.channel, s.samples)), Some((Channel::Pos, 0.8)));
        assert_eq!(c, -0.2);
    }

    /// Realigning a position logged a fraction of a sample late puts values between the
    /// encoder's counts; the record keeps the logged ones for the grid test.
    #[test]
    fn a_fractional_position_realignment_keeps_the_logged_positions() {
        let q = 1e-6;
        let pos: Vec<f64> = (0..50).map(|k| (f64::from(k) * 0.37).round() * q).collect();
        let rec = Record {
            axis: "x".into(),
            t3_s: 1e-3,
            t0_s: 0.0,
            cmd_m: pos.clone(),
            comp_m: None,
            pos_m: pos.clone(),
            force_n: None,
            base_pos_m: None,
            resampled: false,
            pos_source: None,
            beam_x_m: vec![],
            starts_at_rest: false,
            logged_pos_m: None,
        };
        let skew = Skew {
            channel: Channel::Pos,
            samples: 0.4,
        };
        let d = deskew(&rec, &skew);
        assert_eq!(d.logged_pos_m.as_deref(), Some(pos.as_slice()));
        let off_grid = d
            .pos_m
            .iter()
            .filter(|p| ((*p / q) - (*p / q).round()).abs() > 1e-6)
            .count();
        assert!(off_grid > 10, "{off_grid} realigned positions off the grid");
    }
}
