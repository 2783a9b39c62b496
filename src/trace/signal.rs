//! The per-axis signals a trace knows (`<axis>.<signal>`): one enum instead of string tables,
//! so the machine that records them, the reader that checks their units and the code that
//! reads them agree on every name.

use super::Quantity::{self, Current, Force, Length, Torque, Velocity};

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
