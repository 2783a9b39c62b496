//! Compensation slots: where machine-error corrections plug into the command path.
//!
//! Two stages, as on a real control:
//! - [`PositionComp`]: the NC's position command generator adds machine-error corrections
//!   (backlash, thermal, cross/sag) once per generated command, i.e. at T2 in normal mode and
//!   at T3 in direct-command mode (seed 001).
//! - [`ServoComp`]: the amplifier adds per-axis feed-forwards at T3 (quadrant/TFF), into the
//!   position command, the velocity command or the torque command.
//!
//! Each compensation is a small state machine with one `step` per period and names its own
//! trace signals, so the GUI, the tests and the diagnosis all drive the same code.

/// A trace column a compensation writes: (axis name or "" for machine-wide, signal, unit).
#[derive(Debug, Clone, PartialEq)]
pub struct CompSignal {
    pub axis: String,
    pub signal: String,
    pub unit: String,
}

/// What a position compensation sees when the NC generates a position command.
#[derive(Debug, Clone, Copy)]
pub struct PosCompCtx<'a> {
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

pub trait PositionComp: Send {
    fn name(&self) -> &str;
    /// Adds this compensation's correction (m) for each axis into `out_m`.
    fn step(&mut self, ctx: &PosCompCtx<'_>, out_m: &mut [f64]);
    fn signals(&self) -> Vec<CompSignal>;
    /// Current values, in the order and units of [`PositionComp::signals`].
    fn values(&self, out: &mut [f64]);
}

/// What a servo-stage compensation sees each T3 for its axis.
#[derive(Debug, Clone, Copy)]
pub struct ServoCompCtx {
    pub t_s: f64,
    pub t3_s: f64,
    /// Compensated position command from the NC this period and the previous one, m.
    pub cmd_m: f64,
    pub prev_cmd_m: f64,
    /// Position feedback, m.
    pub fb_m: f64,
}

/// Additions a servo-stage compensation makes this T3.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ServoCompOut {
    pub pos_m: f64,
    pub vel_mps: f64,
    pub torque_nm: f64,
}

pub trait ServoComp: Send {
    fn name(&self) -> &str;
    fn axis(&self) -> usize;
    fn step(&mut self, ctx: &ServoCompCtx, out: &mut ServoCompOut);
    fn signals(&self) -> Vec<CompSignal>;
    fn values(&self, out: &mut [f64]);
}

/// The compensations installed in a machine. Empty is a valid (uncompensated) machine.
#[derive(Default)]
pub struct CompStack {
    pub position: Vec<Box<dyn PositionComp>>,
    pub servo: Vec<Box<dyn ServoComp>>,
}

impl CompStack {
    pub fn is_empty(&self) -> bool {
        self.position.is_empty() && self.servo.is_empty()
    }

    pub fn signals(&self) -> Vec<CompSignal> {
        self.position
            .iter()
            .flat_map(|c| c.signals())
            .chain(self.servo.iter().flat_map(|c| c.signals()))
            .collect()
    }
}
