//! Replay of a measured record through the model: the measured command drives the
//! amplifier and plant of one axis from the measured initial state, on the model's T3 grid.
//!
//! The NC is bypassed on purpose: the record's `cmd` is already the interpolated position
//! command, so running the program again would only add the NC's own differences.

use super::DiagnoseError;
use crate::drive::{AxisLoop, LoopInput, SegmentAcc};
use crate::plant::{Beam, PlantOut, Sensor, Start};
use crate::preset::{AxisParams, Crossbeam, PosSource, Preset};
use crate::trace::{AxisSignal, Quantity, Trace};

/// One axis of a measured record on the model's uniform T3 grid, in SI units.
#[derive(Debug, Clone)]
pub struct Record {
    /// Name of the preset axis the columns belong to.
    pub axis: String,
    /// Sample period, s: the model's T3 cycle the record was put on.
    pub t3_s: f64,
    /// Time of the first sample (the record's own clock).
    pub t0_s: f64,
    /// Interpolated position command before compensation, m: drives the replay.
    pub cmd_m: Vec<f64>,
    /// Total compensation the controller added to the command, when recorded.
    pub comp_m: Option<Vec<f64>>,
    /// Measured position as the record's position sensor reads it, m: what the replay is
    /// compared against.
    pub pos_m: Vec<f64>,
    /// Measured load-side motor force, N, when recorded: the second residual channel.
    pub force_n: Option<Vec<f64>>,
    /// Position of the base axis (cross tables, beam sag), when the record has one.
    pub base_pos_m: Option<Vec<f64>>,
    /// True when the record's sampling differed from T3 and it was interpolated.
    pub resampled: bool,
    /// The sensor behind `pos` when the record itself says (`# pos_source: load` in an
    /// axisbench trace); None: the preset's `diagnose.pos_source` decides.
    pub pos_source: Option<PosSource>,
    /// Positions of the crossbeam posts' X axes, in post order, when the replayed axis is a
    /// post's Z: the beam's sag moves the tool tip the record measures.
    pub beam_x_m: Vec<Vec<f64>>,
    /// True when the record says it starts with the machine at rest at power-up (`# start:
    /// rest` in an axisbench trace); otherwise the start state is estimated from the data.
    pub starts_at_rest: bool,
    /// The positions as logged, when `pos_m` was realigned by a fraction of a sample (a
    /// skewed position channel): realigned values lie between the encoder's counts, so the
    /// grid test reads these.
    pub logged_pos_m: Option<Vec<f64>>,
}

impl Record {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.cmd_m.len()
    }

    /// Whether the record has no samples.
    pub fn is_empty(&self) -> bool {
        self.cmd_m.is_empty()
    }

    /// Time of sample `i` on the record's own clock, s.
    pub fn t_s(&self, i: usize) -> f64 {
        self.t0_s + i as f64 * self.t3_s
    }

    /// Reads axis `axis` (and `base`, if given) of `trace` onto the T3 grid. `file` names the
    /// record in errors. A record sampled other than at T3 is resampled; the grid's size is
    /// computed and bounded ([`MAX_REPLAY_SAMPLES`]) before anything is allocated for it.
    pub fn from_trace(
        trace: &Trace,
        file: &str,
        axis: &str,
        base: Option<&str>,
        t3_s: f64,
    ) -> Result<Record, DiagnoseError> {
        let bad = |reason: String| DiagnoseError::Record {
            file: file.to_owned(),
            reason,
        };
        let t = trace.t();
        check_clock(t, t3_s).map_err(bad)?;
        let cols = Columns::read(trace, axis, base).map_err(bad)?;
        let pos_source = trace.meta("pos_source").and_then(PosSource::from_name);
        let starts_at_rest = trace.meta("start") == Some("rest");
        let record = |t0_s: f64, c: Columns, resampled: bool| Record {
            axis: axis.to_owned(),
            t3_s,
            t0_s,
            cmd_m: c.cmd_m,
            comp_m: c.comp_m,
            pos_m: c.pos_m,
            force_n: c.force_n,
            base_pos_m: c.base_pos_m,
            resampled,
            pos_source,
            starts_at_rest,
            beam_x_m: vec![],
            logged_pos_m: None,
        };
        if is_uniform(t, t3_s) {
            return Ok(record(t[0], cols, false));
        }
        let m = grid_len(t, t3_s, cols.series()).map_err(bad)?;
        let grid: Vec<f64> = (0..m).map(|i| t[0] + i as f64 * t3_s).collect();
        Ok(record(t[0], cols.resampled(t, &grid), true))
    }

    /// Reads axis `axis` of `trace` for `preset`: on the preset's T3 grid, with its base axis
    /// (when the record has it) and, for a crossbeam post's Z, the posts' X positions.
    pub fn for_preset(
        trace: &Trace,
        file: &str,
        preset: &Preset,
        axis: &str,
    ) -> Result<Record, DiagnoseError> {
        let base = super::base_axis_of(preset, axis)
            .filter(|b| trace.axis_values(b, AxisSignal::Pos).is_some());
        let mut rec = Record::from_trace(trace, file, axis, base.as_deref(), preset.timing.t3_s)?;
        let cb = &preset.crossbeam;
        if cb.enabled && cb.posts.iter().any(|p| p.z_axis == axis) {
            for p in &cb.posts {
                let x = Record::from_trace(trace, file, &p.x_axis, None, preset.timing.t3_s)
                    .map_err(|e| DiagnoseError::Record {
                        file: file.to_owned(),
                        reason: format!(
                            "axis '{axis}' hangs from the crossbeam, whose sag depends on post axis '{}': {e}",
                            p.x_axis
                        ),
                    })?;
                rec.beam_x_m.push(x.pos_m);
            }
        }
        Ok(rec)
    }

    /// A contiguous piece of the record (for splitting into fit and held-out parts).
    pub fn slice(&self, r: std::ops::Range<usize>) -> Record {
        let s = |v: &Vec<f64>| v[r.clone()].to_vec();
        Record {
            axis: self.axis.clone(),
            t3_s: self.t3_s,
            t0_s: self.t_s(r.start),
            cmd_m: s(&self.cmd_m),
            comp_m: self.comp_m.as_ref().map(s),
            pos_m: s(&self.pos_m),
            force_n: self.force_n.as_ref().map(s),
            base_pos_m: self.base_pos_m.as_ref().map(s),
            resampled: self.resampled,
            pos_source: self.pos_source,
            starts_at_rest: self.starts_at_rest && r.start == 0,
            beam_x_m: self.beam_x_m.iter().map(s).collect(),
            logged_pos_m: self.logged_pos_m.as_ref().map(s),
        }
    }
}

/// The series of one axis a [`Record`] takes from a trace, in SI as the trace holds them,
/// on the trace's own time stamps.
struct Columns {
    cmd_m: Vec<f64>,
    comp_m: Option<Vec<f64>>,
    pos_m: Vec<f64>,
    force_n: Option<Vec<f64>>,
    base_pos_m: Option<Vec<f64>>,
}

impl Columns {
    /// Reads `cmd`, `pos` (required), `comp`, `force` of `axis` and `pos` of `base`; every
    /// value must be finite. A record with torque but no force is refused: the diagnosis
    /// compares load-side force.
    fn read(trace: &Trace, axis: &str, base: Option<&str>) -> Result<Columns, String> {
        let cmd_m = required(trace, axis, AxisSignal::Cmd)?;
        let pos_m = required(trace, axis, AxisSignal::Pos)?;
        let comp_m = optional(trace, axis, AxisSignal::Comp)?;
        let force_n = optional(trace, axis, AxisSignal::Force)?;
        if force_n.is_none() && trace.axis_values(axis, AxisSignal::Torque).is_some() {
            return Err(format!(
                "'{axis}.torque' is recorded but the diagnosis compares load-side force; map it as '{axis}.force[N]' (torque × 2π/lead)"
            ));
        }
        let base_pos_m = match base {
            Some(b) => Some(
                trace
                    .axis_values(b, AxisSignal::Pos)
                    .ok_or_else(|| format!("no column '{b}.pos' for the base axis '{b}'"))?
                    .to_vec(),
            ),
            None => None,
        };
        Ok(Columns {
            cmd_m,
            comp_m,
            pos_m,
            force_n,
            base_pos_m,
        })
    }

    /// How many series a grid will carry (the grid itself, cmd, pos and those present).
    fn series(&self) -> usize {
        3 + [
            self.comp_m.is_some(),
            self.force_n.is_some(),
            self.base_pos_m.is_some(),
        ]
        .iter()
        .filter(|&&b| b)
        .count()
    }

    /// Every series resampled from time stamps `t` onto `grid`.
    fn resampled(&self, t: &[f64], grid: &[f64]) -> Columns {
        let rs = |v: &Vec<f64>| resample(t, v, grid);
        Columns {
            cmd_m: rs(&self.cmd_m),
            comp_m: self.comp_m.as_ref().map(rs),
            pos_m: rs(&self.pos_m),
            force_n: self.force_n.as_ref().map(rs),
            base_pos_m: self.base_pos_m.as_ref().map(rs),
        }
    }
}

/// Column `<axis>.<sig>`, which the diagnosis needs; the columns there are when it is missing.
fn required(trace: &Trace, axis: &str, sig: AxisSignal) -> Result<Vec<f64>, String> {
    optional(trace, axis, sig)?.ok_or_else(|| {
        let have: Vec<String> = trace
            .signals
            .iter()
            .map(|s| format!("{}[{}]", s.name, s.unit))
            .collect();
        format!(
            "no column '{}'; the record has: {}",
            sig.column(axis),
            have.join(", ")
        )
    })
}

/// Largest position a record may hold, m: no machine axis is a kilometre long, and the
/// replay's plant is not meant to integrate 1e305 m (the trace fuzzer found that NaN).
pub const MAX_RECORD_POS_M: f64 = 1e3;
/// Largest force a record may hold, N.
pub const MAX_RECORD_FORCE_N: f64 = 1e9;

/// Column `<axis>.<sig>` if recorded, in SI as the trace holds it; every value must be finite
/// and, for positions and forces, within what a machine axis can hold.
fn optional(trace: &Trace, axis: &str, sig: AxisSignal) -> Result<Option<Vec<f64>>, String> {
    let Some(v) = trace.axis_values(axis, sig) else {
        return Ok(None);
    };
    if let Some((i, x)) = v.iter().enumerate().find(|(_, x)| !x.is_finite()) {
        return Err(format!(
            "column '{}' has no finite value at data row {} ({x}); the diagnosis needs it at every sample",
            sig.column(axis),
            i + 1
        ));
    }
    let (limit, unit) = match sig.quantity() {
        Quantity::Length => (MAX_RECORD_POS_M, "m"),
        Quantity::Force => (MAX_RECORD_FORCE_N, "N"),
        _ => (f64::INFINITY, ""),
    };
    if let Some((i, x)) = v.iter().enumerate().find(|(_, x)| x.abs() > limit) {
        return Err(format!(
            "column '{}' holds {x:e} {unit} at data row {}, beyond the ±{limit:e} {unit} any machine axis can have",
            sig.column(axis),
            i + 1
        ));
    }
    Ok(Some(v.to_vec()))
}

/// True when the time stamps are T3 apart (within 5 % each, 0.1 % on average): the record
/// is used as it is, without resampling.
fn is_uniform(t: &[f64], t3_s: f64) -> bool {
    let n = t.len();
    let dt_mean = (t[n - 1] - t[0]) / (n - 1) as f64;
    ((dt_mean - t3_s) / t3_s).abs() < 1e-3
        && t.windows(2)
            .all(|w| ((w[1] - w[0]) - t3_s).abs() < 0.05 * t3_s)
}

/// Most samples [`Record::from_trace`] resamples a record onto: 10 M T3 periods (1250 s at
/// T3 = 125 µs). Each resampled series is 80 MB at this size, and a record has up to five
/// plus the grid.
pub const MAX_REPLAY_SAMPLES: usize = 10_000_000;

/// The checks on a record's clock before a grid is laid over it: at least 10 samples, a
/// positive T3, and strictly increasing times.
fn check_clock(t: &[f64], t3_s: f64) -> Result<(), String> {
    if t.len() < 10 {
        return Err(format!(
            "{} samples; the diagnosis needs at least 10",
            t.len()
        ));
    }
    if !(t3_s.is_finite() && t3_s > 0.0) {
        return Err(format!("T3 = {t3_s} s must be a positive time"));
    }
    for (i, w) in t.windows(2).enumerate() {
        if w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater) {
            return Err(format!(
                "t[s] does not increase at data row {} ({} after {})",
                i + 2,
                w[1],
                w[0]
            ));
        }
    }
    Ok(())
}

/// Samples of the T3 grid over the times `t` (increasing), computed in floating point and
/// bounded by [`MAX_REPLAY_SAMPLES`] before anything is allocated. When too many: the
/// estimate, the memory it would take for `series` resampled series, the limit, what to
/// change, and the largest time step (the usual cause is one wrong time stamp).
fn grid_len(t: &[f64], t3_s: f64, series: usize) -> Result<usize, String> {
    let (Some(&first), Some(&last)) = (t.first(), t.last()) else {
        return Err("has no samples".into());
    };
    let span_s = last - first;
    let periods = (span_s / t3_s).floor();
    if !(periods.is_finite() && periods >= 0.0) {
        return Err(format!(
            "spans {first} s to {last} s, which makes no grid of T3 = {t3_s} s"
        ));
    }
    let samples = periods + 1.0;
    if samples > MAX_REPLAY_SAMPLES as f64 {
        let (row, step) = t
            .windows(2)
            .map(|w| w[1] - w[0])
            .enumerate()
            .fold((0, 0.0), |m, (i, d)| if d > m.1 { (i + 2, d) } else { m });
        let gb = samples * (series as f64) * 8.0 / 1024f64.powi(3);
        return Err(format!(
            "spans {span_s:.6} s, which is {samples:.0} periods of T3 = {t3_s} s ({gb:.1} GiB to resample {series} series); the limit is {MAX_REPLAY_SAMPLES} samples (MAX_REPLAY_SAMPLES): cut the record to at most {:.1} s, or check its time stamps (the largest step is {step} s, at data row {row})",
            (MAX_REPLAY_SAMPLES - 1) as f64 * t3_s
        ));
    }
    // Whole, non-negative and at most MAX_REPLAY_SAMPLES: the conversion is exact.
    Ok(samples as usize)
}

/// Linear interpolation of (t, v) at the sorted `grid` times.
fn resample(t: &[f64], v: &[f64], grid: &[f64]) -> Vec<f64> {
    let mut j = 0;
    grid.iter()
        .map(|&g| {
            while j + 2 < t.len() && t[j + 1] < g {
                j += 1;
            }
            let (t0, t1) = (t[j], t[j + 1]);
            let f = ((g - t0) / (t1 - t0)).clamp(0.0, 1.0);
            v[j] + (v[j + 1] - v[j]) * f
        })
        .collect()
}

/// The crossbeam the replayed axis's tool post hangs from.
#[derive(Debug, Clone)]
pub struct BeamModel {
    /// The beam (span, stiffness, self-weight, post weights).
    pub crossbeam: Crossbeam,
    /// Which of its posts carries the replayed axis.
    pub post: usize,
}

impl BeamModel {
    /// The beam of `preset` if `axis` is one of its posts' Z axes.
    pub fn of(preset: &Preset, axis: &str) -> Option<BeamModel> {
        let cb = &preset.crossbeam;
        let post = cb.posts.iter().position(|p| p.z_axis == axis)?;
        cb.enabled.then(|| BeamModel {
            crossbeam: cb.clone(),
            post,
        })
    }

    /// The beam with its posts' X axes numbered 0, 1, … in post order.
    fn beam(&self) -> Option<Beam> {
        let posts = &self.crossbeam.posts;
        Beam::new(&self.crossbeam, |name| {
            posts
                .iter()
                .position(|p| p.x_axis == name || p.z_axis == name)
        })
    }
}

/// The sag of the replayed axis's post at each sample (zeros without a beam), m.
fn sag_series(model: &Model, rec: &Record, n: usize) -> Vec<f64> {
    let (Some(bm), false) = (&model.beam, rec.beam_x_m.is_empty()) else {
        return vec![0.0; n];
    };
    let Some(beam) = bm.beam() else {
        return vec![0.0; n];
    };
    let mut x = vec![0.0; rec.beam_x_m.len()];
    let mut out = [0.0; 2];
    (0..n)
        .map(|k| {
            for (xi, col) in x.iter_mut().zip(&rec.beam_x_m) {
                *xi = col[k];
            }
            beam.sag_m(&x, &mut out);
            out.get(bm.post).copied().unwrap_or(0.0)
        })
        .collect()
}

/// A window of constant external force on the table (a burst of the disturbance
/// candidate), in samples of the record it belongs to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceEvent {
    /// First sample the force acts in.
    pub i0: usize,
    /// First sample after it.
    pub i1: usize,
    /// The force on the table, N.
    pub force_n: f64,
}

/// An external force on the table that no state of the axis explains: what the
/// `external_disturbance` candidate adds. Times are in the record's own clock.
#[derive(Debug, Clone, PartialEq)]
pub enum Disturbance {
    /// Windows of constant force (bursts).
    Windows(Vec<ForceEvent>),
    /// A square wave between `offset_n − amplitude_n` and `offset_n + amplitude_n`, high for
    /// `duty` of each period, rising at `first_rise_s` (+ k periods).
    Square {
        /// Period, s.
        period_s: f64,
        /// Share of the period at the high level, 0..1.
        duty: f64,
        /// Half the step height, N.
        amplitude_n: f64,
        /// Mean level, N.
        offset_n: f64,
        /// A rising edge, s.
        first_rise_s: f64,
    },
    /// A sine `offset_n + amplitude_n·sin(2π(t − first_rise_s)/period_s)`.
    Sine {
        /// Period, s.
        period_s: f64,
        /// Amplitude, N.
        amplitude_n: f64,
        /// Mean level, N.
        offset_n: f64,
        /// An upward zero crossing, s.
        first_rise_s: f64,
    },
    /// A piecewise-constant force: `levels[i]` from `times_s[i]` on (0 before the first).
    Steps {
        /// Change times, s, increasing.
        times_s: Vec<f64>,
        /// The level from each change on, N.
        levels_n: Vec<f64>,
    },
    /// The inner force added to the amplifier's output rather than pushed on the table from
    /// outside: it moves the axis the same way, but the record's force channel (the
    /// amplifier's output) carries it, so the force residual shows no step and only the
    /// position residual does. A pulse injected into the drive's command (the EMPS
    /// cross-validation run) acts so.
    InCommand(Box<Disturbance>),
}

impl Disturbance {
    /// The force at time `t_s` (windows are added by [`disturbance_series`] directly).
    pub fn force_at(&self, t_s: f64) -> f64 {
        match self {
            Disturbance::Windows(_) => 0.0,
            Disturbance::InCommand(d) => d.force_at(t_s),
            Disturbance::Square {
                period_s,
                duty,
                amplitude_n,
                offset_n,
                first_rise_s,
            } => {
                let u = ((t_s - first_rise_s) / period_s).rem_euclid(1.0);
                offset_n
                    + if u < *duty {
                        *amplitude_n
                    } else {
                        -amplitude_n
                    }
            }
            Disturbance::Sine {
                period_s,
                amplitude_n,
                offset_n,
                first_rise_s,
            } => {
                offset_n
                    + amplitude_n * (std::f64::consts::TAU * (t_s - first_rise_s) / period_s).sin()
            }
            Disturbance::Steps { times_s, levels_n } => {
                let i = times_s.partition_point(|&x| x <= t_s);
                if i == 0 { 0.0 } else { levels_n[i - 1] }
            }
        }
    }
}

/// The summed external force at each of `n` samples of `rec`.
pub fn disturbance_series(d: &[Disturbance], rec: &Record, n: usize) -> Vec<f64> {
    let mut out = vec![0.0; n];
    for dist in d {
        add_series(dist, rec, &mut out);
    }
    out
}

/// The part of [`disturbance_series`] the record's force channel carries (the
/// [`Disturbance::InCommand`] ones); None when there is none.
pub fn commanded_series(d: &[Disturbance], rec: &Record, n: usize) -> Option<Vec<f64>> {
    let mut out: Option<Vec<f64>> = None;
    for dist in d {
        if let Disturbance::InCommand(inner) = dist {
            add_series(inner, rec, out.get_or_insert_with(|| vec![0.0; n]));
        }
    }
    out
}

/// Adds the force of `dist` at each sample of `rec` to `out`.
fn add_series(dist: &Disturbance, rec: &Record, out: &mut [f64]) {
    let n = out.len();
    match dist {
        Disturbance::Windows(ev) => {
            for e in ev {
                for f in out.iter_mut().take(e.i1.min(n)).skip(e.i0) {
                    *f += e.force_n;
                }
            }
        }
        Disturbance::InCommand(inner) => add_series(inner, rec, out),
        _ => {
            for (k, f) in out.iter_mut().enumerate() {
                *f += dist.force_at(rec.t_s(k));
            }
        }
    }
}

/// Everything a candidate can change: the axis parameters plus what lies outside the
/// plant (command delay, external forces).
#[derive(Debug, Clone)]
pub struct Model {
    /// The axis as the candidate has it.
    pub axis: AxisParams,
    /// Amplifier period T3, s.
    pub t3_s: f64,
    /// NC → amplifier period T2, s: the acceleration feed-forward takes one value per T2.
    pub t2_s: f64,
    /// Interpolation period T1, s: the command is linear within a T1 period, which says how
    /// to extrapolate it back before the record's first sample.
    pub t1_s: f64,
    /// Which sensor the record's `pos` comes from.
    pub pos_source: PosSource,
    /// Command delay, s (fractions of a sample interpolate).
    pub delay_s: f64,
    /// Time constant of a first-order lag the (delayed) command passes through, s; 0 for
    /// none. A drive's command filter or a smoothing stage lags like this rather than by a
    /// whole shift.
    pub lag_s: f64,
    /// Half the interval the record's position reading stands for, m: a sensor that rounds
    /// to a quantum q reads within ±q/2 of the position, so only what lies beyond is misfit
    /// (0: the reading is a point).
    pub pos_interval_m: f64,
    /// External forces on the table.
    pub disturbance: Vec<Disturbance>,
    /// The crossbeam, when the axis is a tool post's Z.
    pub beam: Option<BeamModel>,
}

impl Model {
    /// The quantum the model's position sensor (the one behind the record's `pos`) rounds
    /// to, m (0: none).
    pub fn pos_quantum_m(&self) -> f64 {
        let a = &self.axis;
        match self.pos_source {
            PosSource::MotorEncoder
                if a.encoder.quantize_motor && a.encoder.motor_counts_per_rev > 0 =>
            {
                a.drive.lead_m() / f64::from(a.encoder.motor_counts_per_rev)
            }
            PosSource::Scale if a.encoder.quantize_scale => {
                crate::units::um_to_m(a.encoder.scale_resolution_um)
            }
            _ => 0.0,
        }
    }
}

/// Simulated signals, sample for sample with the record.
#[derive(Debug, Clone, Default)]
pub struct SimOut {
    /// The simulated reading of the record's position sensor, m.
    pub pos_m: Vec<f64>,
    /// The simulated load-side motor force, N.
    pub force_n: Vec<f64>,
}

/// Below this initial speed the record starts from rest, m/s.
const REST_SPEED_MPS: f64 = 1e-5;

/// The record's command, delayed by `delay_s` (linear interpolation between samples; the
/// first sample is held before the record starts).
fn delayed_cmd(rec: &Record, delay_s: f64, n: usize) -> Vec<f64> {
    let d = delay_s / rec.t3_s;
    if d == 0.0 {
        return rec.cmd_m[..n].to_vec();
    }
    let last = (rec.len() - 1) as f64;
    (0..n)
        .map(|k| {
            let u = (k as f64 - d).clamp(0.0, last);
            let i = u.floor() as usize;
            let f = u - i as f64;
            match rec.cmd_m.get(i + 1) {
                Some(&next) => rec.cmd_m[i] + (next - rec.cmd_m[i]) * f,
                None => rec.cmd_m[i],
            }
        })
        .collect()
}

/// `cmd` through a first-order lag of time constant `lag_s` (sampled exactly at `t3_s`),
/// started in its steady state for the command's first velocity: a record that starts
/// moving has its filtered command lagging already.
fn lagged_cmd(mut cmd: Vec<f64>, lag_s: f64, t3_s: f64) -> Vec<f64> {
    if !(lag_s > 0.0 && lag_s.is_finite() && t3_s > 0.0) || cmd.len() < 2 {
        return cmd;
    }
    let alpha = 1.0 - (-t3_s / lag_s).exp();
    let step0 = cmd[1] - cmd[0];
    // The output one sample before the first, on a ramp of step0 per sample: it trails by
    // (1 − α)/α steps in the steady state, and the ramp was one step back then.
    let mut y = cmd[0] - step0 / alpha;
    for x in &mut cmd {
        y += alpha * (*x - y);
        *x = y;
    }
    cmd
}

/// The plant's state at the first sample, from the measured record: the position sensor
/// reads the first measured position; the velocity is the second-order forward difference
/// of the measured positions.
///
/// A record that says it starts at power-up (axisbench's own traces) starts from rest: its
/// command is already moving in the first sample while the axis has not been driven yet,
/// and a fast loop moves it within that sample, so the data alone cannot tell the two apart.
fn initial_state(model: &Model, rec: &Record) -> Start {
    let p = &rec.pos_m;
    let v_pos = if p.len() >= 3 && !rec.starts_at_rest {
        (-3.0 * p[0] + 4.0 * p[1] - p[2]) / (2.0 * rec.t3_s)
    } else {
        0.0
    };
    let moving = v_pos.abs() >= REST_SPEED_MPS;
    Start {
        sensor: Sensor::from(model.pos_source),
        reading_m: p[0],
        vel_mps: if moving { v_pos } else { 0.0 },
    }
}

/// Replays `rec[..n]` through `model`. Row k holds the position at the start of period k
/// and the force the amplifier put out during it, as the machine's own trace does.
///
/// The record's first row is taken as the first T3 of a T2 period (axisbench's traces start
/// at t = 0 on a T2 boundary). The command before the record is extrapolated back by one
/// sample; a record that starts from rest starts its acceleration feed-forward from rest
/// too, one that starts moving from the command's first velocity.
pub fn simulate(model: &Model, rec: &Record, n: usize) -> SimOut {
    let n = n.min(rec.len());
    let mut out = SimOut {
        pos_m: Vec::with_capacity(n),
        force_n: Vec::with_capacity(n),
    };
    if n == 0 {
        return out;
    }
    let t3 = model.t3_s;
    let a = &model.axis;
    let cmd = lagged_cmd(delayed_cmd(rec, model.delay_s, n), model.lag_s, t3);
    let comp = |k: usize| rec.comp_m.as_ref().map_or(0.0, |v| v[k]);
    let sag = sag_series(model, rec, n);
    let mut start = initial_state(model, rec);
    start.reading_m -= sag[0];
    let c1 = cmd.get(1).copied().unwrap_or(cmd[0]);
    let n23 = crate::preset::ratio(model.t2_s, t3).unwrap_or(1) as usize;
    // The command before the record ends the interpolation period before the first. Within
    // a T1 period the command is linear in T3 steps, so when a T1 holds two or more samples
    // one step back along the first two is exact; with T1 = T3 every sample is its own
    // period, and a constant acceleration through the first three (an acc/dec ramp from
    // rest) is exact instead.
    let n13 = crate::preset::ratio(model.t1_s, t3).unwrap_or(1);
    let before = match cmd.get(2) {
        Some(&c2) if n13 == 1 => 3.0 * cmd[0] - 3.0 * c1 + c2,
        _ => 2.0 * cmd[0] - c1,
    };
    let mut seg = if start.vel_mps == 0.0 {
        SegmentAcc::new(model.t2_s, before)
    } else {
        SegmentAcc::moving(model.t2_s, before, (c1 - cmd[0]) / t3)
    };
    let mut axis = AxisLoop::new(
        a,
        t3,
        start,
        before,
        before + comp(0),
        crate::comp::servo_comps(0, a),
    );
    let ext = disturbance_series(&model.disturbance, rec, n);
    // A force added to the amplifier's output is part of what the force channel records.
    let seen = commanded_series(&model.disturbance, rec, n);
    for k in 0..n {
        if k % n23 == 0 {
            seg.next_segment(cmd[(k + n23 - 1).min(n - 1)]);
        }
        out.pos_m
            .push(reading(model.pos_source, axis.plant().out()) + sag[k]);
        let force = axis.step(&LoopInput {
            t_s: rec.t_s(k),
            cmd_raw_m: cmd[k],
            cmd_nc_m: cmd[k] + comp(k),
            acc_cmd_mps2: seg.acc_mps2(),
            ext_force_n: ext[k],
        });
        out.force_n
            .push(force + seen.as_ref().map_or(0.0, |s| s[k]));
    }
    out
}

/// What the record's position sensor reads from the plant.
fn reading(src: PosSource, o: &PlantOut) -> f64 {
    match src {
        PosSource::Load => o.pos_m,
        PosSource::MotorEncoder => o.motor_enc_m,
        PosSource::Scale => o.scale_m,
    }
}

#[cfg(test)]
mod tests {
    use super::lagged_cmd;

    #[test]
    fn a_ramp_through_the_lag_trails_by_its_steady_lag_from_the_first_sample() {
        // 0.1 mm per 1 ms sample through a 2 ms lag: the exact discrete lag is (1 − α)/α
        // steps, α = 1 − e^(−1/2), which is 1.54 samples (τ less half a sample, nearly).
        let step_m = 1e-4;
        let cmd: Vec<f64> = (0..200).map(|k| 0.01 + step_m * f64::from(k)).collect();
        let out = lagged_cmd(cmd.clone(), 2e-3, 1e-3);
        let alpha = 1.0 - (-0.5_f64).exp();
        let trail_m = (1.0 - alpha) / alpha * step_m;
        assert!(
            (trail_m / step_m - 1.5415).abs() < 1e-3,
            "{}",
            trail_m / step_m
        );
        for (k, (c, y)) in cmd.iter().zip(&out).enumerate() {
            assert!((c - y - trail_m).abs() < 1e-15, "sample {k}: {}", c - y);
        }
    }

    #[test]
    fn a_step_through_the_lag_closes_by_its_factor_each_sample() {
        // At rest, then 1 mm: after n samples (1 − α)^n of the step is left.
        let mut cmd = vec![0.0; 10];
        cmd.extend(std::iter::repeat_n(1e-3, 40));
        let out = lagged_cmd(cmd, 5e-3, 1e-3);
        let keep = (-0.2_f64).exp();
        assert!(out[..10].iter().all(|y| *y == 0.0));
        for n in 0..40 {
            let left = 1e-3 - out[10 + n];
            let want = 1e-3 * keep.powi(i32::try_from(n + 1).unwrap_or(i32::MAX));
            assert!((left - want).abs() < 1e-15, "n {n}: {left} against {want}");
        }
    }

    #[test]
    fn no_lag_leaves_the_command_as_it_is() {
        let cmd = vec![0.0, 1e-4, 3e-4, 2e-4];
        assert_eq!(lagged_cmd(cmd.clone(), 0.0, 1e-3), cmd);
        assert_eq!(lagged_cmd(cmd.clone(), f64::NAN, 1e-3), cmd);
    }
}
