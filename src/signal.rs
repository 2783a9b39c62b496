//! The vocabulary of recorded signals: what a value measures ([`Quantity`], with its SI and
//! display units) and the per-axis signals a trace knows ([`AxisSignal`], `<axis>.<signal>`).
//! One enum instead of string tables, so the machine that records them, the compensations
//! that add theirs, the reader that checks their units and the code that reads them agree on
//! every name. It depends on nothing, so every layer may use it; [`crate::trace`] re-exports it.

use Quantity::{Current, Force, Length, Torque, Velocity};

/// What a unit measures. A signal's unit must measure what the signal means: `x.pos[mm/s]`
/// is a velocity where a length is meant, and is refused rather than silently mis-scaled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// m, mm, um.
    Length,
    /// s, ms.
    Time,
    /// m/s, mm/s, mm/min.
    Velocity,
    /// N.
    Force,
    /// N*m.
    Torque,
    /// A.
    Current,
    /// degC.
    Temperature,
    /// No unit: counts, modes, ratios.
    Plain,
}

impl Quantity {
    /// The name used in messages.
    pub fn name(self) -> &'static str {
        match self {
            Quantity::Length => "a length",
            Quantity::Time => "a time",
            Quantity::Velocity => "a velocity",
            Quantity::Force => "a force",
            Quantity::Torque => "a torque",
            Quantity::Current => "a current",
            Quantity::Temperature => "a temperature",
            Quantity::Plain => "a plain number",
        }
    }

    /// The unit a trace holds this quantity in: SI (m, s, m/s, N, N*m, A, degC, none), the
    /// units the model computes in, so nothing converts between model and trace.
    pub fn si_unit(self) -> &'static str {
        match self {
            Quantity::Length => "m",
            Quantity::Time => "s",
            Quantity::Velocity => "m/s",
            Quantity::Force => "N",
            Quantity::Torque => "N*m",
            Quantity::Current => "A",
            Quantity::Temperature => "degC",
            Quantity::Plain => "",
        }
    }

    /// The unit a trace file is written in: mm and mm/s for lengths and velocities (what an
    /// engineer reads in a CNC record), SI for the rest. Both are powers of ten of SI, so the
    /// file holds the exact decimal of each in-memory value.
    pub fn display_unit(self) -> &'static str {
        match self {
            Quantity::Length => "mm",
            Quantity::Velocity => "mm/s",
            q => q.si_unit(),
        }
    }
}

/// A known axis signal: the `<signal>` of an `<axis>.<signal>` column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AxisSignal {
    /// Position commanded by the program, before any compensation.
    Cmd,
    /// Command with the position-stage compensations added (what the amplifier receives).
    CmdComp,
    /// Total compensation added to the command.
    Comp,
    /// Motor position converted to load travel.
    MotorPos,
    /// Measured position (the feedback the record names, the true table position simulated).
    Pos,
    /// Position error `cmd − pos`.
    Err,
    /// Following error of the position loop.
    Ferr,
    /// Load velocity.
    Vel,
    /// Torque command, motor side.
    TorqueCmd,
    /// Motor torque.
    Torque,
    /// Load-side drive force.
    Force,
    /// Friction force.
    Friction,
    /// Lost-motion gap of the coupling.
    Gap,
    /// Thermal growth of the screw at the table.
    Thermal,
    /// Lead error of the screw at the table.
    LeadErr,
    /// Tool-tip displacement by the crossbeam's sag.
    Sag,
    /// Motor current.
    Current,
    /// Backlash compensation output.
    BacklashComp,
    /// Quadrant (reversal) compensation output: a torque, a velocity or a position.
    QuadrantComp,
    /// Thermal compensation output.
    ThermalComp,
    /// Cross (sag) compensation output.
    CrossComp,
    /// A measurement taken at that instant (sparse).
    Meas,
}

use AxisSignal as S;

impl AxisSignal {
    /// Every known axis signal.
    pub const ALL: [AxisSignal; 22] = [
        S::Cmd,
        S::CmdComp,
        S::Comp,
        S::MotorPos,
        S::Pos,
        S::Err,
        S::Ferr,
        S::Vel,
        S::TorqueCmd,
        S::Torque,
        S::Force,
        S::Friction,
        S::Gap,
        S::Thermal,
        S::LeadErr,
        S::Sag,
        S::Current,
        S::BacklashComp,
        S::QuadrantComp,
        S::ThermalComp,
        S::CrossComp,
        S::Meas,
    ];

    /// The signals the simulated machine records for every axis, in column order (the
    /// compensations add their own after them).
    pub const RECORDED: [AxisSignal; 16] = [
        S::Cmd,
        S::CmdComp,
        S::Comp,
        S::MotorPos,
        S::Pos,
        S::Err,
        S::Ferr,
        S::Vel,
        S::TorqueCmd,
        S::Torque,
        S::Force,
        S::Friction,
        S::Gap,
        S::Thermal,
        S::LeadErr,
        S::Sag,
    ];

    /// The name in a column header, e.g. `motor_pos`.
    pub fn name(self) -> &'static str {
        match self {
            S::Cmd => "cmd",
            S::CmdComp => "cmd_comp",
            S::Comp => "comp",
            S::MotorPos => "motor_pos",
            S::Pos => "pos",
            S::Err => "err",
            S::Ferr => "ferr",
            S::Vel => "vel",
            S::TorqueCmd => "torque_cmd",
            S::Torque => "torque",
            S::Force => "force",
            S::Friction => "friction",
            S::Gap => "gap",
            S::Thermal => "thermal",
            S::LeadErr => "lead_err",
            S::Sag => "sag",
            S::Current => "current",
            S::BacklashComp => "backlash_comp",
            S::QuadrantComp => "quadrant_comp",
            S::ThermalComp => "thermal_comp",
            S::CrossComp => "cross_comp",
            S::Meas => "meas",
        }
    }

    /// The signal called `name` (without axis and unit), if known.
    pub fn from_name(name: &str) -> Option<AxisSignal> {
        S::ALL.into_iter().find(|s| s.name() == name)
    }

    /// What the signal measures; for the quadrant compensation, which may be injected as a
    /// torque, a velocity or a position, the torque (see [`AxisSignal::quantities`]).
    pub fn quantity(self) -> Quantity {
        self.quantities()[0]
    }

    /// Every quantity a file may give the signal in: one, except the quadrant compensation,
    /// which is a torque, a velocity or a position by where it is injected.
    pub fn quantities(self) -> &'static [Quantity] {
        match self {
            S::Vel => &[Velocity],
            S::TorqueCmd | S::Torque => &[Torque],
            S::Force | S::Friction => &[Force],
            S::Current => &[Current],
            S::QuadrantComp => &[Torque, Velocity, Length],
            S::Cmd
            | S::CmdComp
            | S::Comp
            | S::MotorPos
            | S::Pos
            | S::Err
            | S::Ferr
            | S::Gap
            | S::Thermal
            | S::LeadErr
            | S::Sag
            | S::BacklashComp
            | S::ThermalComp
            | S::CrossComp
            | S::Meas => &[Length],
        }
    }

    /// The SI unit the trace holds the signal in.
    pub fn si_unit(self) -> &'static str {
        self.quantity().si_unit()
    }

    /// The column name of this signal on axis `axis`, e.g. `x.cmd`.
    pub fn column(self, axis: &str) -> String {
        format!("{axis}.{}", self.name())
    }
}
