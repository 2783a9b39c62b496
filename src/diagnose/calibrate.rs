//! Calibrate first, then look for effects.
//!
//! A nominal preset is never exact: masses, friction and gains are off by a few per cent.
//! Left alone, that mismatch is the largest residual, and whichever candidate mimics it
//! best (a delay, a viscous correction) gets the blame. So the nominal's own parameters are
//! re-fitted first, within ±8 % (the nominal offsets a real machine has, with margin; the
//! mass, read over the force constant, ±11 %), and
//! reported as calibration.
//!
//! At the same time each measured channel gets a time shift: position and force may be
//! logged a little before or after the instant the command was. A shift common to both is
//! how the machine responds late (a command delay, left to that candidate); a shift of one
//! channel alone is a logging skew, a measurement finding, and is removed from the record
//! before any effect is tested.

use std::sync::Mutex;

use serde::Serialize;

use super::engine::{Cand, Engine, at};
use super::lm::{self, Param};
use super::replay::{Record, SimOut};
use super::{DiagnoseError, Effect};
use crate::preset::AxisParams;

/// Largest calibration change: beyond it a parameter is not mis-set but missing an effect.
/// Nominals are typically off by a few per cent; a mass and a force constant off in
/// opposite directions make close to 8 %.
pub const MAX_RATIO_CHANGE: f64 = 0.08;
/// Largest calibration change of the moving mass. The record's force is the commanded one,
/// so the mass is read over the motor's force constant: a mass and a force constant each a
/// few per cent off in opposite directions (5 % each on the independent generator) make up
/// to 10.5 %. Beyond 8 % the mass stayed short on 17 of 380 independent records (seeds
/// 2323–3232); its ringing was read as a spring or left a clean record 0.02 µm short.
pub const MAX_MASS_RATIO_CHANGE: f64 = 0.11;
/// Largest channel shift searched, samples.
const MAX_SHIFT: f64 = 8.0;
/// A channel shift smaller than this is not a finding, samples.
pub const MIN_SKEW: f64 = 0.2;
/// Two free channel shifts must explain this much more of the residual than one common
/// shift does before a skew is called: an unmodelled friction term also moves the shifts a
/// little, a logging skew moves one channel's whole residual.
const MIN_SKEW_GAIN: f64 = 0.3;
/// A common lag this close to one whole sample is read as the command logged one sample
/// ahead of the responses, not as a command delay. The two give the same data (the
/// responses follow the logged command one sample late either way); a log that stamps the
/// command of the next period is a whole sample off, while a delay of the drive or a lag of
/// the loop is any fraction of a sample (within ±0.08 of one sample: about 4 % of the
/// independent generator's delays, drawn log-uniform over 0.2–6 samples). The report names
/// both readings.
const WHOLE_SAMPLE_LAG_TOL: f64 = 0.08;

/// A nominal parameter the calibration re-fits, as a ratio to its nominal value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CalParam {
    /// The moving mass: table and the motor's reflected inertia.
    Mass,
    /// Viscous friction.
    Viscous,
    /// Coulomb (and breakaway) friction, when the nominal has it.
    Coulomb,
    /// Position-loop gain.
    Kp,
    /// Velocity-loop gain.
    Kv,
}

impl CalParam {
    /// The name in reports.
    pub fn name(self) -> &'static str {
        match self {
            CalParam::Mass => "mass",
            CalParam::Viscous => "viscous_friction",
            CalParam::Coulomb => "coulomb_friction",
            CalParam::Kp => "kp",
            CalParam::Kv => "kv",
        }
    }

    /// The largest change of this ratio the calibration may make.
    pub fn max_change(self) -> f64 {
        match self {
            CalParam::Mass => MAX_MASS_RATIO_CHANGE,
            _ => MAX_RATIO_CHANGE,
        }
    }

    /// Whether `ratio` lies at this parameter's bound (more than a correction).
    pub fn at_bound(self, ratio: f64) -> bool {
        (ratio - 1.0).abs() > self.max_change() - 0.005
    }

    /// The solver's bounds of this ratio.
    pub fn bounds(self) -> Param {
        Param {
            lo: 1.0 - self.max_change(),
            hi: 1.0 + self.max_change(),
            scale: 1.0,
        }
    }

    /// The parameters worth calibrating on `a`: those it has (a Coulomb level of 0 is an
    /// effect left out, not a value to scale).
    pub fn of(a: &AxisParams) -> Vec<CalParam> {
        let mut v = vec![CalParam::Mass];
        if a.friction.enabled && a.friction.viscous_n_s_per_m > 0.0 {
            v.push(CalParam::Viscous);
        }
        if a.friction.enabled && a.friction.coulomb_n > 0.0 {
            v.push(CalParam::Coulomb);
        }
        v.extend([CalParam::Kp, CalParam::Kv]);
        v
    }

    /// Scales this parameter of `a` by `ratio`.
    pub fn apply(self, a: &mut AxisParams, ratio: f64) {
        match self {
            CalParam::Mass => {
                a.drive.table_mass_kg *= ratio;
                a.drive.motor_inertia_kgm2 *= ratio;
            }
            CalParam::Viscous => a.friction.viscous_n_s_per_m *= ratio,
            CalParam::Coulomb => {
                a.friction.coulomb_n *= ratio;
                a.friction.stribeck.static_n *= ratio;
            }
            CalParam::Kp => a.servo.kp_per_s *= ratio,
            CalParam::Kv => a.servo.kv_n_s_per_m *= ratio,
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
    /// Each re-fitted parameter and its ratio to the nominal.
    pub ratios: Vec<(CalParam, f64)>,
    /// Parameters that hit their bound: the nominal lacks more than a correction.
    pub at_bound: Vec<CalParam>,
    /// Fitted time shift of the position channel against the model, samples.
    pub pos_shift_samples: f64,
    /// Fitted time shift of the force channel, samples.
    pub force_shift_samples: f64,
    /// A one-channel logging skew, removed from the record before effects are tested.
    pub skew: Option<Skew>,
    /// The lag both responses share (−: the machine responds late), samples: a command
    /// delay, or the command logged early, which a record cannot tell apart.
    pub common_lag_samples: f64,
    /// Held-out combined residual of the nominal and of the calibrated model (normalised).
    pub j_nominal: f64,
    /// … after calibration and skew removal.
    pub j_calibrated: f64,
    /// How a one-sample lag was read when both readings were diagnosed (see
    /// [`Calibration::lag_instead_of_skew`]); empty otherwise.
    #[serde(skip_serializing_if = "String::is_empty")]
    pub lag_reading: String,
    /// When the shifts, fitted again with the effects found, read another skew (or none):
    /// both readings were diagnosed, and which one was kept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refit: Option<ShiftRefit>,
}

/// The two readings of the channel shifts: before any effect, and fitted again beside the
/// effects that reading found.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ShiftRefit {
    /// The skew of the reading not kept.
    pub other: Option<Skew>,
    /// Whether the kept reading is the second one.
    pub kept_second: bool,
    /// Held-out criterion left by the first reading's diagnosis (nominal normalisation).
    pub j_first: f64,
    /// The same for the second.
    pub j_second: f64,
    /// Whether the first reading stopped after its first effect (the shifts, fitted again
    /// beside it, moved): `j_first` is then that one effect's model's.
    pub first_stopped: bool,
}

/// Whether two readings of the channel shifts name a different skew: a different channel,
/// or the same one off by [`MIN_SKEW`] or more, or a skew against none.
pub fn skews_differ(a: Option<Skew>, b: Option<Skew>) -> bool {
    match (a, b) {
        (None, None) => false,
        (Some(a), Some(b)) => a.channel != b.channel || (a.samples - b.samples).abs() >= MIN_SKEW,
        _ => true,
    }
}

impl Calibration {
    /// The calibrated model: `nominal` with the ratios applied.
    pub fn apply(&self, nominal: &Cand) -> Cand {
        let mut c = nominal.clone();
        for &(p, r) in &self.ratios {
            p.apply(&mut c.model.axis, r);
        }
        c
    }

    /// The same calibration with a one-sample command skew read as a common lag instead
    /// (None when the shifts were not read so): the two give the same record, and a force
    /// the model lacks can make the loop follow one sample late too (seed 1818 case_020, a
    /// viscous friction of 170 % of the nominal's, realigned, left no viscous friction to
    /// fit). [`super::diagnose`] tries both.
    pub fn lag_instead_of_skew(&self) -> Option<Calibration> {
        let s = self.skew?;
        (s.channel == Channel::Cmd && (s.samples - 1.0).abs() < WHOLE_SAMPLE_LAG_TOL).then(|| {
            Calibration {
                skew: None,
                common_lag_samples: -s.samples,
                ..self.clone()
            }
        })
    }

    /// The two readings of the shifts, when fitting them again beside the effects found
    /// named another skew.
    pub fn refit_note(&self) -> Option<String> {
        let r = self.refit?;
        let other = r.other.map_or("no skew".to_string(), |s| {
            format!("the {:?} channel {:+.2} samples off", s.channel, s.samples)
        });
        Some(if r.first_stopped {
            format!(
                "the shifts were fitted again beside the first effect found; before, they read {other}, and that reading, stopped there, left {:.3} of the held-out part (the kept reading {:.3})",
                r.j_first, r.j_second
            )
        } else if r.kept_second {
            format!(
                "the shifts were fitted again with the effects found; before them they read {other}, which left {:.3} of the held-out part against {:.3}",
                r.j_first, r.j_second
            )
        } else {
            format!(
                "fitted again with the effects found, the shifts read {other}, which left {:.3} of the held-out part against {:.3}: the first reading is kept",
                r.j_second, r.j_first
            )
        })
    }

    /// A one-line summary for reports.
    pub fn summary(&self) -> String {
        let r: Vec<String> = self
            .ratios
            .iter()
            .map(|(p, r)| format!("{} ×{:.3}", p.name(), r))
            .collect();
        let skew = match self.skew {
            Some(s) => format!(
                "; {:?} channel logged {:+.2} samples off and realigned{}",
                s.channel,
                s.samples,
                if matches!(s.channel, Channel::Cmd)
                    && (s.samples - 1.0).abs() < WHOLE_SAMPLE_LAG_TOL
                {
                    " (a one-sample command delay gives the same record)"
                } else {
                    ""
                }
            ),
            None => String::new(),
        };
        let mut reading = if self.lag_reading.is_empty() {
            String::new()
        } else {
            format!("; {}", self.lag_reading)
        };
        if let Some(note) = self.refit_note() {
            reading += &format!("; {note}");
        }
        format!("{}{skew}{reading}", r.join(", "))
    }
}

/// `base` with ratios `r` applied to the parameters `ps`, and the nuisance friction
/// `nuisance` = [Coulomb force added, constant force] (N).
fn with_ratios(base: &Cand, ps: &[CalParam], r: &[f64], nuisance: &[f64]) -> Cand {
    let mut c = base.clone();
    for (&p, &x) in ps.iter().zip(r) {
        p.apply(&mut c.model.axis, x);
    }
    if let [fc, f0] = nuisance {
        Effect::CoulombFriction.apply(&[*fc], &mut c.model);
        Effect::ConstantForce.apply(&[*f0], &mut c.model);
    }
    c
}

/// Friction a nominal left out (a Coulomb level, a constant force) is nearly always there
/// and would otherwise pull the mass, the viscous friction and the gains off their values
/// to mimic it. The calibration therefore fits both alongside, as nuisance parameters, and
/// keeps only the ratios: whether the friction is really there is the candidates' question.
const N_NUISANCE: usize = 2;

/// Whether [`fit_ratios`] fits the two channel shifts too.
#[derive(Clone, Copy)]
enum ShiftFit {
    /// The ratios alone.
    No,
    /// The shifts too, judged by [`judge_shifts`].
    Free,
    /// The shifts too, kept only when they explain clearly more than these (position,
    /// force) shifts of an earlier reading; else those.
    Against(f64, f64),
}

/// Fits ratios and (see [`ShiftFit`]) the two channel shifts on the engine's fitting part.
/// The ratios start from `from` (else 1).
fn fit_ratios(
    eng: &Engine,
    base: &Cand,
    ps: &[CalParam],
    shift_fit: ShiftFit,
    from: Option<&[f64]>,
) -> Result<(Vec<f64>, f64, f64), DiagnoseError> {
    let shifts = !matches!(shift_fit, ShiftFit::No);
    let n = ps.len();
    let force_scale = (0.01 * base.model.axis.drive.total_mass_kg() * 9.81).max(1.0);
    let mut params: Vec<Param> = ps.iter().map(|p| p.bounds()).collect();
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
    let m = n + N_NUISANCE;
    if shifts {
        let sh = Param {
            lo: -MAX_SHIFT,
            hi: MAX_SHIFT,
            scale: 1.0,
        };
        params.extend([sh, sh]);
    }
    // The shifts only move the simulated output, so a replay is reused while the ratios
    // stay the same.
    let cache: Mutex<Option<(Vec<f64>, SimOut)>> = Mutex::new(None);
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
        let s = eng.sim_fit(&with_ratios(base, ps, &th[..n], &th[n..m]))?;
        let rows = eng.lm_rows_shifted(&s, up, uf);
        if let Ok(mut c) = cache.lock() {
            *c = Some((model_part.to_vec(), s));
        }
        Ok(Some(rows))
    };
    let mut start = from
        .filter(|r| r.len() == n)
        .map_or_else(|| vec![1.0; n], <[f64]>::to_vec);
    start.extend([0.0; N_NUISANCE]);
    if shifts {
        start.extend([0.0, 0.0]);
    }
    let f = lm::fit(&start, &params, &rows, 0.01, 8)?;
    let (up, uf) = if shifts {
        (f.theta[m], f.theta[m + 1])
    } else {
        (0.0, 0.0)
    };
    // The shifts are judged on the fitted model's replay (whichever replay the solver's
    // threads left in the cache).
    if shifts {
        let fitted = &f.theta[..m];
        let held = cache
            .lock()
            .is_ok_and(|c| c.as_ref().is_some_and(|(r, _)| r == fitted));
        if !held {
            let s = eng.sim_fit(&with_ratios(base, ps, &f.theta[..n], &f.theta[n..m]))?;
            if let Ok(mut c) = cache.lock() {
                *c = Some((fitted.to_vec(), s));
            }
        }
    }
    let (up, uf) = match shift_fit {
        ShiftFit::No => (up, uf),
        ShiftFit::Free => judge_shifts(eng, &cache, up, uf, None),
        ShiftFit::Against(p, q) => judge_shifts(eng, &cache, up, uf, Some((p, q))),
    };
    Ok((f.theta[..n].to_vec(), up, uf))
}

/// Keeps the fitted channel shifts only where they read as a logging skew clearly: two
/// different shifts must explain [`MIN_SKEW_GAIN`] more than one common shift does (else
/// the common one), and responses that lead the model (which no delay makes: the command
/// logged late) must explain that much more than no shift at all (else none). An
/// unmodelled friction or load moves the fitted shifts: on the independent seed 2424, 12
/// of the 60 unskewed records with an effect read a lead of 0.23–1.9 samples as the
/// command logged late. This test drops 6 of them (fitting the shifts again with the
/// effects found, in [`super::diagnose`], most of the others); of the skewed records it
/// drops three wrong readings and one true skew (0.42 samples, read as 0.80).
///
/// Judged twice: on the residual as it is, and on its fast part (what is left after a
/// 0.2 s moving mean). A slow drift the model lacks (screw growth) can hold most of the
/// position residual and hide what a skew does during the moves.
///
/// With an earlier reading (`prior`, fitted before the effects were found), the shifts must
/// also explain that much more than the earlier ones do on the same replay, or the earlier
/// ones stay: a second diagnosis on a reading that is hardly better is not run.
fn judge_shifts(
    eng: &Engine,
    cache: &Mutex<Option<(Vec<f64>, SimOut)>>,
    up: f64,
    uf: f64,
    prior: Option<(f64, f64)>,
) -> (f64, f64) {
    let Ok(c) = cache.lock() else {
        return (up, uf);
    };
    let Some((_, s)) = c.as_ref() else {
        return (up, uf);
    };
    let n_pos = s.pos_m.len().div_ceil(eng.stride);
    let window = ((0.2 / eng.split.main.t3_s) / eng.stride as f64).round() as usize;
    let costs = |u: f64, w: f64| {
        let r = eng.lm_rows_shifted(s, u, w);
        let fast = fast_part(r.as_slice(), n_pos, window);
        (r.norm_squared(), fast)
    };
    let gains = |b: (f64, f64), c: (f64, f64)| {
        b.0 <= (1.0 - MIN_SKEW_GAIN) * c.0 || b.1 <= (1.0 - MIN_SKEW_GAIN) * c.1
    };
    if std::env::var_os("AXB_DBG").is_some() {
        let (b, z) = (costs(up, uf), costs(0.0, 0.0));
        eprintln!(
            "SHIFTS up {up:.3} uf {uf:.3} cost over no shift {:.3} (fast part {:.3})",
            b.0 / z.0,
            b.1 / z.1
        );
    }
    let (mut up, mut uf) = (up, uf);
    if eng.has_force && (up - uf).abs() >= MIN_SKEW {
        // The best single common shift for the same replay.
        let common = (0..=40)
            .map(|i| up.min(uf) + (up - uf).abs() * f64::from(i) / 40.0)
            .map(|u| costs(u, u))
            .fold((f64::INFINITY, f64::INFINITY), |a, b| {
                (a.0.min(b.0), a.1.min(b.1))
            });
        if !gains(costs(up, uf), common) {
            let mid = 0.5 * (up + uf);
            (up, uf) = (mid, mid);
        }
    }
    let lead = if eng.has_force {
        (up - uf).abs() < MIN_SKEW && 0.5 * (up + uf) > MIN_SKEW
    } else {
        up > MIN_SKEW
    };
    let (up, uf) = if lead && !gains(costs(up, uf), costs(0.0, 0.0)) {
        (0.0, 0.0)
    } else {
        (up, uf)
    };
    match prior {
        Some((p, q)) if !gains(costs(up, uf), costs(p, q)) => {
            if std::env::var_os("AXB_DBG").is_some() {
                let (b, z) = (costs(up, uf), costs(p, q));
                eprintln!(
                    "SHIFTS kept the earlier reading: the new one leaves {:.3} (fast part {:.3}) of it",
                    b.0 / z.0,
                    b.1 / z.1
                );
            }
            (p, q)
        }
        _ => (up, uf),
    }
}

/// Sum of squares of `rows` (the position rows, `n_pos` of them, then the force rows) less
/// each channel's centred moving mean over `window` rows.
fn fast_part(rows: &[f64], n_pos: usize, window: usize) -> f64 {
    let half = (window / 2).max(1);
    let one = |r: &[f64]| -> f64 {
        let mut prefix = Vec::with_capacity(r.len() + 1);
        prefix.push(0.0);
        for v in r {
            prefix.push(prefix.last().copied().unwrap_or(0.0) + v);
        }
        (0..r.len())
            .map(|k| {
                let (lo, hi) = (k.saturating_sub(half), (k + half + 1).min(r.len()));
                let mean = (prefix[hi] - prefix[lo]) / (hi - lo) as f64;
                (r[k] - mean).powi(2)
            })
            .sum()
    };
    let (pos, force) = rows.split_at(n_pos.min(rows.len()));
    one(pos) + one(force)
}

/// Decides what the two channel shifts mean. Equal shifts are a common lag (a command
/// delay), or, when the responses lead the command, the command logged late. Different
/// shifts are a skew of one channel; the force is a held value, so its skew comes in whole
/// samples, and a fractional difference must be the position's.
pub fn classify_shifts(pos: f64, force: Option<f64>) -> (Option<Skew>, f64) {
    let Some(force) = force else {
        // Position alone: a lead is a skew of the command or the position; a lag is a delay.
        return if pos > MIN_SKEW || (pos + 1.0).abs() < WHOLE_SAMPLE_LAG_TOL {
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
    let diff = pos - force;
    if diff.abs() < MIN_SKEW {
        let common = 0.5 * (pos + force);
        if common > MIN_SKEW || (common + 1.0).abs() < WHOLE_SAMPLE_LAG_TOL {
            return (
                Some(Skew {
                    channel: Channel::Cmd,
                    samples: -common,
                }),
                0.0,
            );
        }
        return (None, common);
    }
    let whole = (diff - diff.round()).abs() < 0.15;
    // Position skewed: the force shows the common lag, which must not be a lead.
    let pos_ok = force <= MIN_SKEW;
    // Force skewed: the position shows the common lag.
    let force_ok = whole && pos <= MIN_SKEW;
    let pos_skew = (
        Some(Skew {
            channel: Channel::Pos,
            samples: diff,
        }),
        force.min(0.0),
    );
    let force_skew = (
        Some(Skew {
            channel: Channel::Force,
            samples: -diff,
        }),
        pos.min(0.0),
    );
    match (pos_ok, force_ok) {
        (true, false) => pos_skew,
        (false, true) => force_skew,
        // Both readings possible: the simpler one (no common lag) wins; else the position.
        (true, true) if force.abs() > pos.abs() + MIN_SKEW => force_skew,
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

/// Fits the ratios and the channel shifts on `eng`'s fitting part.
pub fn fit(eng: &Engine, nominal: &Cand) -> Result<Calibration, DiagnoseError> {
    fit_with(eng, nominal, ShiftFit::Free)
}

/// Fits the channel shifts again beside the effects found (`found`: the model with them),
/// keeping `first`'s shifts unless the new ones explain clearly more (see
/// [`judge_shifts`]). Only the shifts and what they are read as are meant: the ratios
/// returned are relative to `found`.
pub fn fit_again(
    eng: &Engine,
    found: &Cand,
    first: &Calibration,
) -> Result<Calibration, DiagnoseError> {
    fit_with(
        eng,
        found,
        ShiftFit::Against(first.pos_shift_samples, first.force_shift_samples),
    )
}

fn fit_with(
    eng: &Engine,
    nominal: &Cand,
    shift_fit: ShiftFit,
) -> Result<Calibration, DiagnoseError> {
    let ps = CalParam::of(&nominal.model.axis);
    let (ratios, up, uf) = fit_ratios(eng, nominal, &ps, shift_fit, None)?;
    let (skew, common) = classify_shifts(up, eng.has_force.then_some(uf));
    let at_bound: Vec<CalParam> = ps
        .iter()
        .zip(&ratios)
        .filter(|(p, r)| p.at_bound(**r))
        .map(|(p, _)| *p)
        .collect();

    Ok(Calibration {
        ratios: ps.into_iter().zip(ratios).collect(),
        at_bound,
        pos_shift_samples: up,
        force_shift_samples: uf,
        skew,
        common_lag_samples: common,
        j_nominal: 0.0,
        j_calibrated: 0.0,
        lag_reading: String::new(),
        refit: None,
    })
}

/// Re-fits the ratios alone (after the skew is removed), starting from the nominal's, or
/// from `cal`'s when `from_cal` (a second pass with other weights goes on from the first).
pub fn refit_ratios(
    eng: &Engine,
    nominal: &Cand,
    cal: &mut Calibration,
    from_cal: bool,
) -> Result<(), DiagnoseError> {
    let ps: Vec<CalParam> = cal.ratios.iter().map(|(p, _)| *p).collect();
    let now: Vec<f64> = cal.ratios.iter().map(|(_, r)| *r).collect();
    let from = from_cal.then_some(now.as_slice());
    let (ratios, _, _) = fit_ratios(eng, nominal, &ps, ShiftFit::No, from)?;
    cal.at_bound = ps
        .iter()
        .zip(&ratios)
        .filter(|(p, r)| p.at_bound(**r))
        .map(|(p, _)| *p)
        .collect();
    cal.ratios = ps.into_iter().zip(ratios).collect();
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

    /// A skew hidden under a slow drift: the moving mean takes the drift out and leaves the
    /// fast part, here a step of the position rows.
    #[test]
    fn the_fast_part_leaves_out_a_slow_drift() {
        let drift: Vec<f64> = (0..400).map(|k| 1e-2 * f64::from(k)).collect();
        assert!(fast_part(&drift, 400, 50) < 1e-3 * drift.iter().map(|d| d * d).sum::<f64>());
        let mut step = drift.clone();
        step[200..].iter_mut().for_each(|v| *v += 1.0);
        assert!(fast_part(&step, 400, 50) > 4.0);
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
        let whole = deskew(
            &rec,
            &Skew {
                channel: Channel::Pos,
                samples: 1.0,
            },
        );
        assert!(whole.logged_pos_m.is_none());
    }
}
