//! Compensation slots: where machine-error corrections plug into the command path.
//!
//! Two stages, as on a real control:
//! - [`PositionComp`]: the NC's position command generator adds machine-error corrections
//!   (backlash, thermal, cross/sag) once per generated command, i.e. at T2 in normal mode and
//!   at T3 in direct-command mode (processing-mode patent, SPEC §3).
//! - [`ServoComp`]: the amplifier adds per-axis feed-forwards at T3 (quadrant/TFF), into the
//!   position command, the velocity command or the torque command.
//!
//! The four mechanisms of the seeds live in [`backlash`], [`quadrant`], [`thermal`] and
//! [`cross`]; [`build`] installs what a preset enables. The measuring cycles that fill their
//! parameters run a whole machine, so they live above it, in [`crate::measure`].
//!
//! Each compensation is a small state machine with one `step` per period and names its own
//! trace signals, so the GUI, the tests and the diagnosis all drive the same code.

pub mod backlash;
pub mod cross;
pub mod linuxcnc;
pub mod quadrant;
pub mod thermal;

use crate::preset::{AxisParams, Preset};
use crate::signal::Quantity;

/// A trace column a compensation writes: (axis name or "" for machine-wide, signal, what it
/// measures).
#[derive(Debug, Clone, PartialEq)]
pub struct CompSignal {
    /// Axis name the column belongs to, e.g. "X"; empty for a machine-wide signal.
    pub axis: String,
    /// Signal name within the axis, e.g. "backlash_comp".
    pub signal: String,
    /// What the values measure; they are in its SI unit ([`Quantity::si_unit`]), like every
    /// trace column, so the trace and its file get the unit from one place.
    pub quantity: Quantity,
}

/// What a position compensation sees when the NC generates a position command.
#[derive(Debug, Clone, Copy)]
pub struct PosCompCtx<'a> {
    /// Machine time of this command generation, s.
    pub t_s: f64,
    /// Time between two generated commands: T2 (normal) or T3 (direct).
    pub period_s: f64,
    /// Uncompensated command per axis, m.
    pub cmd_m: &'a [f64],
    /// Uncompensated command per axis at the previous generation, m.
    pub prev_cmd_m: &'a [f64],
    /// Machine position feedback per axis, m.
    pub fb_m: &'a [f64],
    /// Screw temperature sensor per axis, degC.
    pub temps_c: &'a [f64],
}

/// A machine-error correction added by the NC's position command generator (T2 or T3).
pub trait PositionComp: Send {
    /// Short identifier of the mechanism, e.g. "backlash".
    fn name(&self) -> &str;
    /// Adds this compensation's correction (m) for each axis into `out_m`.
    fn step(&mut self, ctx: &PosCompCtx<'_>, out_m: &mut [f64]);
    /// The trace columns this compensation writes, in the order of [`PositionComp::values`].
    fn signals(&self) -> Vec<CompSignal>;
    /// Current values, in the order of [`PositionComp::signals`], in SI.
    fn values(&self, out: &mut [f64]);
    /// A measurement this compensation wants taken now: (axis, position m).
    fn measurement_request(&self) -> Option<(usize, f64)> {
        None
    }
    /// The real displacement measured at the requested point, m.
    fn measured(&mut self, _t_s: f64, _real_m: f64) {}
    /// Whether the correction reads the machine (feedback, screw temperatures, a
    /// measurement), so that it must run at each T2 tick as the axes reach it. A correction
    /// of the command alone says false, which lets the NC run several T2 periods ahead of
    /// the axes (see `Machine::run_block`).
    fn reads_machine(&self) -> bool {
        true
    }
    /// For [`CompStack::find`]: downcast to the concrete compensation.
    fn as_any(&self) -> &dyn std::any::Any;
    /// For [`CompStack::find_mut`]: downcast to the concrete compensation, e.g. to edit it live.
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any;
}

/// What a servo-stage compensation sees each T3 for its axis.
#[derive(Debug, Clone, Copy)]
pub struct ServoCompCtx {
    /// Machine time of this amplifier cycle, s.
    pub t_s: f64,
    /// Amplifier control period T3, s.
    pub t3_s: f64,
    /// Compensated position command from the NC this period and the previous one, m.
    pub cmd_m: f64,
    /// The NC position command of the previous T3, m; `cmd_m - prev_cmd_m` is this T3's move.
    pub prev_cmd_m: f64,
    /// Position feedback, m.
    pub fb_m: f64,
}

/// Additions a servo-stage compensation makes this T3.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ServoCompOut {
    /// Added to the position command fed to the position loop, m.
    pub pos_m: f64,
    /// Added to the velocity command (position-loop output), m/s.
    pub vel_mps: f64,
    /// Torque feed-forward added to the torque command, motor side, N·m.
    pub torque_nm: f64,
}

/// A per-axis feed-forward the amplifier adds every T3 (e.g. the quadrant TFF pulse).
pub trait ServoComp: Send {
    /// Short identifier of the mechanism, e.g. "quadrant".
    fn name(&self) -> &str;
    /// Index of the axis this compensation acts on, in preset order.
    fn axis(&self) -> usize;
    /// One T3: adds this compensation's contribution into `out` (summed over all of them).
    fn step(&mut self, ctx: &ServoCompCtx, out: &mut ServoCompOut);
    /// The trace columns this compensation writes, in the order of [`ServoComp::values`].
    fn signals(&self) -> Vec<CompSignal>;
    /// Current values, in the order of [`ServoComp::signals`], in SI.
    fn values(&self, out: &mut [f64]);
    /// For [`CompStack::find`]: downcast to the concrete compensation.
    fn as_any(&self) -> &dyn std::any::Any;
    /// For [`CompStack::find_mut`]: downcast to the concrete compensation, e.g. to edit it live.
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any;
}

/// The compensations installed in a machine. Empty is a valid (uncompensated) machine.
#[derive(Default)]
pub struct CompStack {
    /// NC-side corrections, applied in this order at each position command generation.
    pub position: Vec<Box<dyn PositionComp>>,
    /// Amplifier-side feed-forwards, each for one axis, run every T3.
    pub servo: Vec<Box<dyn ServoComp>>,
}

impl CompStack {
    /// True when no compensation is installed: the machine runs uncompensated.
    pub fn is_empty(&self) -> bool {
        self.position.is_empty() && self.servo.is_empty()
    }

    /// All trace columns of the installed compensations: position stage first, then servo.
    pub fn signals(&self) -> Vec<CompSignal> {
        self.position
            .iter()
            .flat_map(|c| c.signals())
            .chain(self.servo.iter().flat_map(|c| c.signals()))
            .collect()
    }
}

impl CompStack {
    /// Every installed compensation of type `T` (position stage first, then servo).
    pub fn find<T: 'static>(&self) -> impl Iterator<Item = &T> {
        self.position
            .iter()
            .filter_map(|c| c.as_any().downcast_ref::<T>())
            .chain(
                self.servo
                    .iter()
                    .filter_map(|c| c.as_any().downcast_ref::<T>()),
            )
    }

    /// Every installed compensation of type `T`, mutable (position stage first, then servo).
    pub fn find_mut<T: 'static>(&mut self) -> impl Iterator<Item = &mut T> {
        self.position
            .iter_mut()
            .filter_map(|c| c.as_any_mut().downcast_mut::<T>())
            .chain(
                self.servo
                    .iter_mut()
                    .filter_map(|c| c.as_any_mut().downcast_mut::<T>()),
            )
    }
}

/// Installs every compensation the preset enables, in the order the NC applies them:
/// backlash, thermal, cross (position stage), then quadrant (servo stage).
pub fn build(p: &Preset) -> CompStack {
    let mut stack = CompStack::default();
    for (i, a) in p.axes.iter().enumerate() {
        if a.backlash.enabled {
            stack.position.push(Box::new(backlash::Backlash::new(
                i,
                &a.name,
                a.backlash.clone(),
            )));
        }
    }
    for (i, a) in p.axes.iter().enumerate() {
        if a.thermal.enabled {
            stack.position.push(Box::new(thermal::Thermal::new(
                i,
                &a.name,
                a.thermal.clone(),
            )));
        }
    }
    let cross = cross::Cross::new(&p.cross, |n| p.axes.iter().position(|a| a.name == n));
    if !cross.is_empty() {
        stack.position.push(Box::new(cross));
    }
    for (i, a) in p.axes.iter().enumerate() {
        stack.servo.extend(servo_comps(i, a));
    }
    stack
}

/// The servo-stage compensations axis `a` (index `i`) enables: the amplifier's own, which
/// the diagnosis replay runs as the machine does.
pub fn servo_comps(i: usize, a: &AxisParams) -> Vec<Box<dyn ServoComp>> {
    let mut v: Vec<Box<dyn ServoComp>> = Vec::new();
    if a.quadrant.enabled {
        v.push(Box::new(quadrant::Quadrant::new(
            i,
            &a.name,
            a.quadrant.clone(),
        )));
    }
    v
}
