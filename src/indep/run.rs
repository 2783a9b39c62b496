//! The closed loop of the true machine sampled at T3, and what its sensors log.
//!
//! Per period k (t_k = k·T3): the set-point and the encoder are read at t_k, the controller
//! computes a force, the drive holds it over the period while the mechanics advance in
//! `substeps` RK4 sub-steps. Row k of the log holds the set-point and the position at t_k
//! and the force commanded in period k, unless a channel is skewed.

use super::control::{Controller, Gains, Grid, SetPoint};
use super::dice::Dice;
use super::profile::Profile;
use super::rig::{Bodies, Rig, RigParams};
use super::{IndepError, PosSensor, SkewChannel};

/// Following error beyond which the simulated axis counts as run away, m (the EMPS loop
/// saturates its force long before).
const RUNAWAY_M: f64 = 0.05;

/// How the screw's thermal growth shows on the linear scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThermalView {
    /// Position of the fixed (thrust) bearing, m: the screw grows away from it.
    pub fixed_end_m: f64,
    /// Largest |growth| over the record, m: sets the heat gain after the run.
    pub growth_m: f64,
}

/// The whole true machine: mechanics, controller, set-point handling and sensors.
#[derive(Debug, Clone)]
pub struct TrueMachine {
    /// The mechanics.
    pub rig: RigParams,
    /// The controller constants.
    pub gains: Gains,
    /// What the drive does to the set-point.
    pub setpoint: SetPoint,
    /// The motor encoder (feedback, and `pos` with [`PosSensor::MotorEncoder`]).
    pub encoder: Grid,
    /// The linear scale on the carriage (`pos` with [`PosSensor::LinearScale`]).
    pub scale: Grid,
    /// Which sensor the `pos` column logs.
    pub sensor: PosSensor,
    /// Thermal growth seen by the scale, if any.
    pub thermal: Option<ThermalView>,
    /// RK4 sub-steps per T3.
    pub substeps: u32,
    /// Where the nut starts inside a gap (−1…1 of the half gap).
    pub start_gap_frac: f64,
}

/// What the logging adds: noise and a channel skew.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Logging {
    /// White noise on the position reading (before the grid), m (1σ).
    pub pos_noise_m: f64,
    /// White noise on the logged force, N (1σ).
    pub force_noise_n: f64,
    /// A channel logged at t_k + samples·T3 instead of t_k.
    pub skew: Option<(SkewChannel, f64)>,
    /// Seed of the noise stream.
    pub seed: u64,
}

/// The logged record and the true signals behind it, one entry per row.
#[derive(Debug, Clone, Default)]
pub struct RunOut {
    /// Time of each row, s.
    pub t_s: Vec<f64>,
    /// Logged set-point, m.
    pub cmd_m: Vec<f64>,
    /// Logged position, m.
    pub pos_m: Vec<f64>,
    /// Logged force command, N.
    pub force_n: Vec<f64>,
    /// True motor travel at t_k, m.
    pub motor_m: Vec<f64>,
    /// True carriage position at t_k, m.
    pub carriage_m: Vec<f64>,
    /// Thermal growth at t_k, m.
    pub growth_m: Vec<f64>,
    /// Heat gain that gives the wanted growth (growth = gain·θ·(x − x_fixed)), 1/m.
    pub heat_gain: f64,
}

/// A compensation fed into the true machine from outside, per row (period k): a position
/// added to the set-point and a force added to the controller's output. The rig stays its
/// own: what it gets is the corrections a controller's compensation computes from the
/// command, nothing of the model's physics.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Correction {
    /// Added to the set-point, m.
    pub pos_m: Vec<f64>,
    /// Added to the force command, N.
    pub force_n: Vec<f64>,
}

/// Per-row samples gathered during the run.
struct Raw {
    reading_m: Vec<f64>,
    force_n: Vec<f64>,
    at_row: Vec<Bodies>,
    skewed: Vec<Bodies>,
}

/// Cubic Hermite interpolation of two snapshots `h_s` apart at fraction `th`.
fn hermite(a: &Bodies, b: &Bodies, h_s: f64, th: f64) -> Bodies {
    let (t2, t3) = (th * th, th * th * th);
    let (h00, h10, h01, h11) = (
        2.0 * t3 - 3.0 * t2 + 1.0,
        t3 - 2.0 * t2 + th,
        -2.0 * t3 + 3.0 * t2,
        t3 - t2,
    );
    let mix =
        |x0: f64, v0: f64, x1: f64, v1: f64| h00 * x0 + h10 * h_s * v0 + h01 * x1 + h11 * h_s * v1;
    Bodies {
        motor_m: mix(a.motor_m, a.motor_mps, b.motor_m, b.motor_mps),
        motor_mps: a.motor_mps + (b.motor_mps - a.motor_mps) * th,
        carriage_m: mix(a.carriage_m, a.carriage_mps, b.carriage_m, b.carriage_mps),
        carriage_mps: a.carriage_mps + (b.carriage_mps - a.carriage_mps) * th,
        payload_m: a.payload_m + (b.payload_m - a.payload_m) * th,
        heat: a.heat + (b.heat - a.heat) * th,
    }
}

/// The set-point the position loop sees in period `k`.
fn set_point(law: SetPoint, profile: &Profile, k: usize, t3_s: f64, lagged: &mut f64) -> f64 {
    let t = k as f64 * t3_s;
    match law {
        SetPoint::Direct => profile.pos_m(t),
        SetPoint::Delay { samples } => profile.pos_m(t - samples * t3_s),
        SetPoint::Lag { tau_s } => {
            *lagged += (1.0 - (-t3_s / tau_s).exp()) * (profile.pos_m(t) - *lagged);
            *lagged
        }
    }
}

/// Runs the closed loop for `rows` periods (plus two, for channels logged late).
fn simulate(
    m: &TrueMachine,
    profile: &Profile,
    rows: usize,
    log: &Logging,
    corr: Option<&Correction>,
) -> Result<Raw, IndepError> {
    let t3 = m.gains.t3_s;
    let n_sub = m.substeps.max(1);
    let h = t3 / f64::from(n_sub);
    let x0 = profile.start_pos_m();
    let mut rig = Rig::new(m.rig.clone(), x0, m.start_gap_frac);
    let mut noise = Dice::new(log.seed, "noise.encoder");
    let read = |x: f64, noise: &mut Dice| m.encoder.read(x + log.pos_noise_m * noise.gauss());
    let mut ctrl = Controller::new(m.gains, read(x0, &mut noise));
    let total = rows + 2;
    let pos_skew = match log.skew {
        Some((SkewChannel::Pos, s)) => Some(s),
        _ => None,
    };
    let mut raw = Raw {
        reading_m: Vec::with_capacity(total),
        force_n: Vec::with_capacity(total),
        at_row: Vec::with_capacity(total),
        skewed: Vec::with_capacity(if pos_skew.is_some() { total } else { 0 }),
    };
    let start = rig.bodies();
    let mut next_cap = 0usize;
    if let Some(s) = pos_skew {
        while next_cap < total && (next_cap as f64 + s) <= 0.0 {
            raw.skewed.push(start);
            next_cap += 1;
        }
    }
    let mut lagged = x0;
    for k in 0..total {
        let t = k as f64 * t3;
        let b = rig.bodies();
        let reading = read(b.motor_m, &mut noise);
        let add = |v: Option<&Vec<f64>>| v.and_then(|v| v.get(k)).copied().unwrap_or(0.0);
        let set = set_point(m.setpoint, profile, k, t3, &mut lagged) + add(corr.map(|c| &c.pos_m));
        let f = ctrl.update(set, reading) + add(corr.map(|c| &c.force_n));
        rig.command(f);
        raw.reading_m.push(reading);
        raw.force_n.push(f);
        raw.at_row.push(b);
        for j in 0..n_sub {
            let ta = t + f64::from(j) * h;
            let before = rig.bodies();
            rig.substep(ta, h);
            if let Some(s) = pos_skew {
                let after = rig.bodies();
                while next_cap < total && (next_cap as f64 + s) * t3 <= ta + h {
                    let th = (((next_cap as f64 + s) * t3 - ta) / h).clamp(0.0, 1.0);
                    raw.skewed.push(hermite(&before, &after, h, th));
                    next_cap += 1;
                }
            }
        }
        rig.end_period();
        let now = rig.bodies();
        if !(now.motor_m.is_finite() && now.carriage_m.is_finite())
            || (now.motor_m - set).abs() > RUNAWAY_M
        {
            return Err(IndepError::Unstable(format!(
                "the simulated axis ran away at t = {t:.3} s (motor {:.4} m, set-point {set:.4} m)",
                now.motor_m
            )));
        }
    }
    while raw.skewed.len() < total && pos_skew.is_some() {
        raw.skewed.push(rig.bodies());
    }
    Ok(raw)
}

/// Runs the machine on `profile` for `rows` samples, with `corr` fed in when given, and
/// logs it.
pub fn run(
    m: &TrueMachine,
    profile: &Profile,
    rows: usize,
    log: &Logging,
    corr: Option<&Correction>,
) -> Result<RunOut, IndepError> {
    let raw = simulate(m, profile, rows, log, corr)?;
    let t3 = m.gains.t3_s;
    let heat_gain = match m.thermal {
        Some(th) => {
            let peak = raw.at_row[..rows]
                .iter()
                .map(|b| (b.heat * (b.carriage_m - th.fixed_end_m)).abs())
                .fold(0.0, f64::max);
            if peak > 0.0 { th.growth_m / peak } else { 0.0 }
        }
        None => 0.0,
    };
    let growth = |b: &Bodies| match m.thermal {
        Some(th) => heat_gain * b.heat * (b.carriage_m - th.fixed_end_m),
        None => 0.0,
    };
    let mut noise = Dice::new(log.seed, "noise.log");
    let mut out = RunOut {
        heat_gain,
        ..RunOut::default()
    };
    for k in 0..rows {
        let t = k as f64 * t3;
        out.t_s.push(t);
        let (chan, s) = log.skew.unwrap_or((SkewChannel::Cmd, 0.0));
        let cmd_t = if chan == SkewChannel::Cmd {
            t + s * t3
        } else {
            t
        };
        out.cmd_m.push(profile.pos_m(cmd_t));
        let b = &raw.at_row[k];
        let fidx = if chan == SkewChannel::Force {
            ((k as f64 + s).floor().max(0.0) as usize).min(raw.force_n.len() - 1)
        } else {
            k
        };
        out.force_n
            .push(raw.force_n[fidx] + log.force_noise_n * noise.gauss());
        let pos_noise = log.pos_noise_m * noise.gauss();
        let pos_late = chan == SkewChannel::Pos && s != 0.0;
        let seen = if pos_late { &raw.skewed[k] } else { b };
        let pos = match m.sensor {
            // Unskewed, the log holds the very reading the controller used.
            PosSensor::MotorEncoder if !pos_late => raw.reading_m[k],
            PosSensor::MotorEncoder => m.encoder.read(seen.motor_m + pos_noise),
            PosSensor::LinearScale => m.scale.read(seen.carriage_m + growth(seen) + pos_noise),
        };
        out.pos_m.push(pos);
        out.motor_m.push(b.motor_m);
        out.carriage_m.push(b.carriage_m);
        out.growth_m.push(growth(b));
    }
    Ok(out)
}
