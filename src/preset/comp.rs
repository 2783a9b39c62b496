//! The compensation settings of a preset: backlash (backlash patent, SPEC §2), quadrant (quadrant
//! patent, SPEC §5), thermal correction (thermal patent, SPEC §4) and cross tables (cross-table
//! patent, SPEC §6). The state machines that act on them are in [`crate::comp`]; here is only the
//! data and its validation.

use serde::{Deserialize, Serialize};

use super::FieldError;
use super::axis::{POS_MM, TEMP_C};
use super::fields::{Fields, Num, TableSpec, Walker};
use crate::units;

/// Limits of the thermal adjustment value E (thermal patent, SPEC §4 keeps E within 0.01 … 10).
pub const E_MIN: f64 = 0.01;
/// Upper limit of E.
pub const E_MAX: f64 = 10.0;

// ---- backlash (backlash patent, SPEC §2)

/// How the backlash correction is output after a reversal (backlash patent, SPEC §2, modes a–c and
/// the variant).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum OutputMode {
    /// (a) All of Q in the first distribution cycle after the reversal.
    #[default]
    Lump,
    /// (b) N parts Q/N: one at the reversal, then one each time travel since it reaches B·n.
    Distance,
    /// (c) M parts Q/M, one per distribution cycle for M consecutive cycles.
    Time,
    /// The patent's variant: cumulative share of Q follows a table of distance or time.
    Function,
}

/// What the x of a function-mode table measures since the reversal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FunctionBasis {
    /// Commanded travel since the reversal, µm.
    #[default]
    Distance,
    /// Time since the reversal, ms.
    Time,
}

/// How one reversal direction outputs its correction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DirectionParams {
    /// Lump, by distance, by time, or by function.
    pub mode: OutputMode,
    /// Distance mode: number of parts N.
    pub parts_n: u32,
    /// Distance mode: travel B between parts, µm.
    pub step_b_um: f64,
    /// Time mode: number of cycles M.
    pub cycles_m: u32,
    /// Function mode: what the table's x is (distance in µm or time in ms since reversal).
    pub function_basis: FunctionBasis,
    /// Function mode: (distance µm or time ms, cumulative share 0…1), ending at share 1.
    pub function: Vec<(f64, f64)>,
}

impl Default for DirectionParams {
    fn default() -> Self {
        DirectionParams {
            mode: OutputMode::Lump,
            parts_n: 4,
            step_b_um: 50.0,
            cycles_m: 8,
            function_basis: FunctionBasis::Distance,
            function: vec![(0.0, 0.0), (100.0, 1.0)],
        }
    }
}

/// Backlash compensation of one axis (backlash patent, SPEC §2): amount Q and an output mode per
/// reversal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BacklashParams {
    /// Whether the compensation is installed.
    pub enabled: bool,
    /// Backlash amount Q, µm; the total output over one reversal equals it (−Q for + → −,
    /// +Q for − → +, added to the move command).
    pub q_um: f64,
    /// Output mode for the reversal from + to − (e.g. by distance on a vertical axis going down).
    pub plus_to_minus: DirectionParams,
    /// Output mode for the reversal from − to +.
    pub minus_to_plus: DirectionParams,
}

impl Default for BacklashParams {
    fn default() -> Self {
        BacklashParams {
            enabled: false,
            q_um: 0.0,
            plus_to_minus: DirectionParams::default(),
            minus_to_plus: DirectionParams::default(),
        }
    }
}

// ---- quadrant (quadrant patent, SPEC §5)

/// What a stroke of at least P0 does to the short-stroke count N (quadrant patent, SPEC §5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum NUpdate {
    /// N := 0 after a long stroke (the seed's embodiment).
    #[default]
    Reset,
    /// N := N − 1 after a long stroke, not below 0 (the claim's wording).
    Decrement,
}

/// Where the quadrant pulse enters the amplifier; it sets the unit of M.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Injection {
    /// Torque feed-forward (TFF), M in N·m motor torque.
    #[default]
    Torque,
    /// Added to the velocity command, M in mm/s.
    Velocity,
    /// Added to the position command, M in µm.
    Position,
}

/// Time course of the quadrant pulse.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PulseShape {
    /// M for T, then 0.
    #[default]
    Rectangular,
    /// M·e^(−t/T), cut off after 5T.
    Exponential,
}

/// Quadrant (reversal) compensation of one axis, adapting to short strokes (quadrant patent, SPEC
/// §5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct QuadrantParams {
    /// Whether the compensation is installed.
    pub enabled: bool,
    /// Adapt M and T to short strokes (quadrant patent, SPEC §5); off = fixed TFF of M0 for T0.
    pub adaptive: bool,
    /// Pulse amount M0 for torque injection, N·m; applied in the new direction of motion.
    pub m0_torque_nm: f64,
    /// Pulse amount M0 for velocity injection, mm/s.
    pub m0_vel_mm_per_s: f64,
    /// Pulse amount M0 for position injection, µm.
    pub m0_pos_um: f64,
    /// Pulse duration T0 (rectangular) or time constant (exponential), ms.
    pub t0_ms: f64,
    /// TFF magnification A.
    pub a_mag: f64,
    /// TFF growth rate B (in reversals).
    pub b_rate: f64,
    /// Duration magnification C.
    pub c_mag: f64,
    /// Duration growth rate D (in reversals).
    pub d_rate: f64,
    /// Short-stroke threshold P0, mm: a stroke PA < P0 between reversal points adds 1 to N.
    pub p0_mm: f64,
    /// What a stroke PA ≥ P0 does to N: reset to 0 or decrement.
    pub update: NUpdate,
    /// Torque, velocity or position command; selects which M0 applies.
    pub inject: Injection,
    /// Rectangular or exponentially decaying pulse.
    pub shape: PulseShape,
}

impl Default for QuadrantParams {
    fn default() -> Self {
        // The seed's example: A = 2, B = 10, C = 1, D = 10.
        QuadrantParams {
            enabled: false,
            adaptive: true,
            m0_torque_nm: 0.5,
            m0_vel_mm_per_s: 1.0,
            m0_pos_um: 2.0,
            t0_ms: 10.0,
            a_mag: 2.0,
            b_rate: 10.0,
            c_mag: 1.0,
            d_rate: 10.0,
            p0_mm: 15.0,
            update: NUpdate::Reset,
            inject: Injection::Torque,
            shape: PulseShape::Rectangular,
        }
    }
}

impl QuadrantParams {
    /// M and T for a short-stroke count N: M = M0·A^(1−e^(−N/B)), T = T0·C^(1−e^(−N/D)).
    /// M is in the unit of the injection point.
    pub fn m_t(&self, n: f64) -> (f64, f64) {
        let m0 = match self.inject {
            Injection::Torque => self.m0_torque_nm,
            Injection::Velocity => self.m0_vel_mm_per_s,
            Injection::Position => self.m0_pos_um,
        };
        let m = m0 * self.a_mag.powf(1.0 - (-n / self.b_rate).exp());
        let t = units::ms_to_s(self.t0_ms) * self.c_mag.powf(1.0 - (-n / self.d_rate).exp());
        (m, t)
    }
}

// ---- thermal (thermal patent, SPEC §4)

/// What the thermal predictor computes F from (thermal patent, SPEC §4: operation and/or
/// temperatures).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// Operation history: the control's own screw model driven by commanded speed.
    #[default]
    Operation,
    /// The plant's screw temperature, through a first-order sensor lag.
    Temperature,
}

/// When the thermal correction asks for a re-measurement (thermal patent, SPEC §4, variants 1–3),
/// threshold Em.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Judgement {
    /// Never measure automatically.
    #[default]
    None,
    /// Variant 1: |E − E at start or at the last measurement| ≥ Em.
    SinceLast,
    /// Variant 2: within a window of ΔT, max(E) − min(E) ≥ Em.
    Window,
    /// Variant 3: at the check times, |E − E_ref(t)| ≥ Em.
    Reference,
}

/// Thermal displacement correction of one axis with automatic re-measurement (thermal patent, SPEC
/// §4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ThermalParams {
    /// Whether the correction is installed.
    pub enabled: bool,
    /// Predictor input: operation model or screw temperature sensor.
    pub source: Source,
    /// Predictor: expansion coefficient it assumes, 1/K.
    pub alpha_per_k: f64,
    /// Operation model: heat per commanded speed, W·s/m.
    pub heat_w_s_per_m: f64,
    /// Operation model: heat capacity of the modelled screw, J/K.
    pub capacity_j_per_k: f64,
    /// Operation model: heat loss to ambient, W/K.
    pub loss_w_per_k: f64,
    /// Temperature source: sensor time constant, s.
    pub sensor_lag_s: f64,
    /// Ambient the operation model cools to; the predictor starts at it, degC.
    pub ambient_c: f64,
    /// Temperature at which the predictor assumes no growth (F = 0), degC.
    pub reference_c: f64,
    /// Fixed (thrust) bearing position the correction grows from, mm; correction 0 there.
    pub fixed_end_mm: f64,
    /// Measurement point x_m, mm; F is the predicted displacement there.
    pub measure_pos_mm: f64,
    /// Slope k of E = a + k·|F|, per µm of |F| (from step 1).
    pub k_per_um: f64,
    /// Offset a of E = a + k·|F| (dimensionless); rewritten by each measurement (step 2).
    pub a: f64,
    /// Threshold Em on E.
    pub em: f64,
    /// Which automatic re-measurement rule applies, if any.
    pub judgement: Judgement,
    /// Window ΔT of the `window` judgement, s.
    pub window_s: f64,
    /// Check times of the `reference` judgement, s.
    pub check_times_s: Vec<f64>,
    /// Reference curve E_ref(t): (t s, E).
    pub e_ref: Vec<(f64, f64)>,
}

impl Default for ThermalParams {
    fn default() -> Self {
        ThermalParams {
            enabled: false,
            source: Source::Operation,
            alpha_per_k: 11.0e-6,
            heat_w_s_per_m: 100.0,
            capacity_j_per_k: 4000.0,
            loss_w_per_k: 3.0,
            sensor_lag_s: 120.0,
            ambient_c: 20.0,
            reference_c: 20.0,
            fixed_end_mm: 0.0,
            measure_pos_mm: 250.0,
            k_per_um: 0.0,
            a: 1.0,
            em: 0.05,
            judgement: Judgement::None,
            window_s: 600.0,
            check_times_s: vec![],
            e_ref: vec![],
        }
    }
}

impl ThermalParams {
    /// E for a predicted displacement F (m).
    pub fn e_of(&self, f_m: f64) -> f64 {
        (self.a + self.k_per_um * units::m_to_um(f_m).abs()).clamp(E_MIN, E_MAX)
    }
}

// ---- cross tables (cross-table patent, SPEC §6)

/// One cross (sag) compensation table (cross-table patent, SPEC §6): ΔZ of one axis over another's
/// position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrossTable {
    /// Whether the table is applied (default on).
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Axis whose position selects the correction (the crossbeam X).
    pub base_axis: String,
    /// Axis that receives the correction (the tool post's Z).
    pub comp_axis: String,
    /// (base position mm, correction µm), base positions strictly increasing.
    pub points: Vec<(f64, f64)>,
}

fn yes() -> bool {
    true
}

// ---- fields, ranges and rules ---------------------------------------------------------------

crate::choice_enum!(OutputMode { Lump => "lump", Distance => "distance", Time => "time", Function => "function" });
crate::choice_enum!(FunctionBasis { Distance => "distance", Time => "time" });
crate::choice_enum!(NUpdate { Reset => "reset", Decrement => "decrement" });
crate::choice_enum!(Injection { Torque => "torque", Velocity => "velocity", Position => "position" });
crate::choice_enum!(PulseShape { Rectangular => "rectangular", Exponential => "exponential" });
crate::choice_enum!(Source { Operation => "operation", Temperature => "temperature" });
crate::choice_enum!(Judgement { None => "none", SinceLast => "since_last", Window => "window", Reference => "reference" });

/// The reversal a backlash output mode applies to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Reversal {
    /// From moving + to moving −.
    PlusToMinus,
    /// From moving − to moving +.
    MinusToPlus,
}

crate::choice_enum!(Reversal { PlusToMinus => "plus_to_minus", MinusToPlus => "minus_to_plus" });

impl Reversal {
    /// Both directions, + → − first.
    pub const BOTH: [Reversal; 2] = [Reversal::PlusToMinus, Reversal::MinusToPlus];

    /// How the reversal reads on a form: `+ -> -` (ASCII: the GUI font has no arrows).
    pub fn arrow(self) -> &'static str {
        match self {
            Reversal::PlusToMinus => "+ -> -",
            Reversal::MinusToPlus => "- -> +",
        }
    }
}

impl BacklashParams {
    /// The output mode of one reversal direction.
    pub fn direction(&self, r: Reversal) -> &DirectionParams {
        match r {
            Reversal::PlusToMinus => &self.plus_to_minus,
            Reversal::MinusToPlus => &self.minus_to_plus,
        }
    }

    /// The output mode of one reversal direction, to edit.
    pub fn direction_mut(&mut self, r: Reversal) -> &mut DirectionParams {
        match r {
            Reversal::PlusToMinus => &mut self.plus_to_minus,
            Reversal::MinusToPlus => &mut self.minus_to_plus,
        }
    }
}

impl Fields for BacklashParams {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "backlash compensation on", &mut self.enabled);
        w.num("q_um", "Q", &mut self.q_um, Num::closed("um", 0.0, 1e5));
        for r in Reversal::BOTH {
            w.nest(r.name(), |w| self.direction_mut(r).fields(w));
        }
    }

    fn rules(&self, at: &str, out: &mut Vec<FieldError>) {
        for r in Reversal::BOTH {
            let d = self.direction(r);
            if d.mode != OutputMode::Function {
                continue;
            }
            let p = format!("{at}.{}.function", r.name());
            if d.function.len() < 2 {
                out.push(FieldError {
                    path: p.clone(),
                    reason: format!("needs at least 2 points, has {}", d.function.len()),
                });
            }
            if d.function.last().is_some_and(|pt| pt.1 != 1.0) {
                out.push(FieldError {
                    path: p,
                    reason: "the last share must be 1 (all of Q)".into(),
                });
            }
        }
    }
}

impl Fields for DirectionParams {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.choice("mode", "mode", &mut self.mode);
        let mode = self.mode;
        w.when(mode == OutputMode::Distance, |w| {
            w.count("parts_n", "parts N", &mut self.parts_n, 1, 10_000);
            w.num(
                "step_b_um",
                "step B",
                &mut self.step_b_um,
                Num::above("um", 0.0, 1e6),
            );
        });
        w.when(mode == OutputMode::Time, |w| {
            w.count("cycles_m", "cycles M", &mut self.cycles_m, 1, 100_000);
        });
        w.when(mode == OutputMode::Function, |w| {
            w.choice("function_basis", "share over", &mut self.function_basis);
            let x = match self.function_basis {
                FunctionBasis::Distance => Num::closed("um", 0.0, 1e6),
                FunctionBasis::Time => Num::closed("ms", 0.0, 1e6),
            };
            w.table(
                "function",
                "function",
                &mut self.function,
                TableSpec {
                    x,
                    y: Num::closed("share", 0.0, 1.0),
                    min_points: 2,
                    max_points: 1000,
                },
            );
        });
    }
}

impl Fields for QuadrantParams {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "quadrant compensation on", &mut self.enabled);
        w.flag("adaptive", "adapt to short strokes", &mut self.adaptive);
        w.choice("inject", "inject into", &mut self.inject);
        let inj = self.inject;
        w.when(inj == Injection::Torque, |w| {
            w.num(
                "m0_torque_nm",
                "M0",
                &mut self.m0_torque_nm,
                Num::closed("N*m", 0.0, 1e4),
            );
        });
        w.when(inj == Injection::Velocity, |w| {
            w.num(
                "m0_vel_mm_per_s",
                "M0",
                &mut self.m0_vel_mm_per_s,
                Num::closed("mm/s", 0.0, 1e5),
            );
        });
        w.when(inj == Injection::Position, |w| {
            w.num(
                "m0_pos_um",
                "M0",
                &mut self.m0_pos_um,
                Num::closed("um", 0.0, 1e4),
            );
        });
        w.num("t0_ms", "T0", &mut self.t0_ms, Num::above("ms", 0.0, 1e4));
        w.choice("shape", "pulse shape", &mut self.shape);
        let adaptive = self.adaptive;
        w.when(adaptive, |w| {
            w.num("a_mag", "A", &mut self.a_mag, Num::above("", 0.0, 100.0));
            w.num(
                "b_rate",
                "B",
                &mut self.b_rate,
                Num::above("reversals", 0.0, 1e6),
            );
            w.num("c_mag", "C", &mut self.c_mag, Num::above("", 0.0, 100.0));
            w.num(
                "d_rate",
                "D",
                &mut self.d_rate,
                Num::above("reversals", 0.0, 1e6),
            );
            w.num("p0_mm", "P0", &mut self.p0_mm, Num::closed("mm", 0.0, 1e5));
            w.choice("update", "after a long stroke", &mut self.update);
        });
    }
}

impl Fields for ThermalParams {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "thermal correction on", &mut self.enabled);
        w.choice("source", "predictor", &mut self.source);
        let src = self.source;
        w.num(
            "alpha_per_k",
            "expansion coefficient",
            &mut self.alpha_per_k,
            Num::closed("1/K", 0.0, 1e-3),
        );
        w.when(src == Source::Operation, |w| {
            w.num(
                "heat_w_s_per_m",
                "heat per speed",
                &mut self.heat_w_s_per_m,
                Num::closed("W*s/m", 0.0, 1e7),
            );
            w.num(
                "capacity_j_per_k",
                "heat capacity",
                &mut self.capacity_j_per_k,
                Num::above("J/K", 0.0, 1e9),
            );
            w.num(
                "loss_w_per_k",
                "heat loss",
                &mut self.loss_w_per_k,
                Num::closed("W/K", 0.0, 1e6),
            );
        });
        w.when(src == Source::Temperature, |w| {
            w.num(
                "sensor_lag_s",
                "sensor lag",
                &mut self.sensor_lag_s,
                Num::above("s", 0.0, 1e6),
            );
        });
        w.num("ambient_c", "ambient", &mut self.ambient_c, TEMP_C);
        w.num("reference_c", "reference", &mut self.reference_c, TEMP_C);
        w.num(
            "fixed_end_mm",
            "fixed bearing at",
            &mut self.fixed_end_mm,
            POS_MM,
        );
        w.num(
            "measure_pos_mm",
            "measuring point",
            &mut self.measure_pos_mm,
            POS_MM,
        );
        w.num(
            "k_per_um",
            "k",
            &mut self.k_per_um,
            Num::closed("1/um", -100.0, 100.0),
        );
        w.num("a", "a", &mut self.a, Num::closed("", -100.0, 100.0));
        w.choice("judgement", "re-measure when", &mut self.judgement);
        let j = self.judgement;
        w.when(j != Judgement::None, |w| {
            w.num("em", "Em", &mut self.em, Num::above("", 0.0, 10.0));
        });
        w.when(j == Judgement::Window, |w| {
            w.num(
                "window_s",
                "window ΔT",
                &mut self.window_s,
                Num::above("s", 0.0, 1e6),
            );
        });
        w.when(j == Judgement::Reference, |w| {
            w.times(
                "check_times_s",
                "check times",
                &mut self.check_times_s,
                Num::closed("s", 0.0, 1e7),
                10_000,
            );
            w.table(
                "e_ref",
                "reference curve E_ref(t)",
                &mut self.e_ref,
                TableSpec {
                    x: Num::closed("s", 0.0, 1e7),
                    y: Num::closed("", 0.0, 100.0),
                    min_points: 2,
                    max_points: 10_000,
                },
            );
        });
    }

    fn rules(&self, at: &str, out: &mut Vec<FieldError>) {
        if self.measure_pos_mm == self.fixed_end_mm {
            out.push(FieldError {
                path: format!("{at}.measure_pos_mm"),
                reason: "must differ from fixed_end_mm (no growth at the fixed bearing)".into(),
            });
        }
        if self.judgement == Judgement::Reference && self.e_ref.len() < 2 {
            out.push(FieldError {
                path: format!("{at}.e_ref"),
                reason: "the reference judgement needs a curve of ≥ 2 points".into(),
            });
        }
    }
}

impl Fields for CrossTable {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "table on", &mut self.enabled);
        w.text("base_axis", "base axis", &mut self.base_axis);
        w.text("comp_axis", "compensated axis", &mut self.comp_axis);
        w.table(
            "points",
            "points",
            &mut self.points,
            TableSpec {
                x: POS_MM,
                y: Num::closed("um", -1e5, 1e5),
                min_points: 2,
                max_points: 10_000,
            },
        );
    }

    fn rules(&self, at: &str, out: &mut Vec<FieldError>) {
        if self.points.len() < 2 {
            out.push(FieldError {
                path: format!("{at}.points"),
                reason: format!("needs at least 2 points, has {}", self.points.len()),
            });
        }
        if self.base_axis == self.comp_axis {
            out.push(FieldError {
                path: format!("{at}.comp_axis"),
                reason: "must differ from the base axis".into(),
            });
        }
    }
}
