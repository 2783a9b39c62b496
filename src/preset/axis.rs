//! The parameters of one feed axis: drive, amplifier gains, encoders and the plant effects,
//! each a section with its own `check()`.

use serde::{Deserialize, Serialize};

use crate::units;

/// One feed axis: drive mechanics, amplifier, encoders, plant effects and its compensations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisParams {
    /// Axis name used in the trace (`x`, `z`, `z2`, …).
    pub name: String,
    /// Absolute program address (X, Y, Z or C). The incremental one is U, V, W or H.
    pub letter: char,
    /// NC channel (path) whose program drives this axis.
    #[serde(default)]
    pub channel: usize,
    /// Position of the axis at power-on (machine coordinates), mm.
    #[serde(default)]
    pub initial_pos_mm: f64,
    /// Motor, ball screw, table and the coupling between them.
    pub drive: Drive,
    /// Amplifier gains, feed-forwards, limits and which sensor closes the position loop.
    pub servo: ServoParams,
    /// Motor encoder and linear scale resolution.
    pub encoder: Encoder,
    /// Slide friction: Coulomb, viscous, Stribeck and short-stroke rise.
    pub friction: Friction,
    /// Backlash (dead zone) between motor and table in the plant.
    pub lost_motion: LostMotion,
    /// Gravity load and constant offset force on the table.
    pub gravity: Gravity,
    /// Ball-screw thermal growth in the plant (what the thermal correction must cancel).
    pub screw_thermal: ScrewThermal,
    /// Ball-screw lead (pitch) error in the plant.
    pub lead_error: LeadError,
    /// Backlash compensation (backlash patent, SPEC §2).
    #[serde(default)]
    pub backlash: super::comp::BacklashParams,
    /// Quadrant (reversal) compensation adapting to short strokes (quadrant patent, SPEC §5).
    #[serde(default)]
    pub quadrant: super::comp::QuadrantParams,
    /// Thermal displacement correction with automatic re-measurement (thermal patent, SPEC §4).
    #[serde(default)]
    pub thermal: super::comp::ThermalParams,
}

/// Drive train: rotary motor turning a ball screw that moves the table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Drive {
    /// Motor-side rotary inertia, kg·m²; must be > 0 with lost motion or a two-mass coupling.
    pub motor_inertia_kgm2: f64,
    /// Ball-screw lead: table travel per motor revolution.
    pub lead_mm: f64,
    /// Moving mass on the load side (table, workpiece), kg.
    pub table_mass_kg: f64,
    /// How motor and table are joined: rigidly or through a spring/damper.
    pub coupling: Coupling,
}

impl Drive {
    /// The screw lead in m.
    pub fn lead_m(&self) -> f64 {
        units::mm_to_m(self.lead_mm)
    }

    /// Load-side force per motor torque, 2π/lead.
    pub fn force_per_torque(&self) -> f64 {
        units::force_per_torque(self.lead_m())
    }

    /// The motor's rotor inertia seen from the table: J·(2π/lead)².
    pub fn reflected_motor_mass_kg(&self) -> f64 {
        let k = self.force_per_torque();
        self.motor_inertia_kgm2 * k * k
    }

    /// Everything the motor accelerates when motor and table move as one body (with a
    /// payload on a spring, the payload too).
    pub fn total_mass_kg(&self) -> f64 {
        self.reflected_motor_mass_kg() + self.table_mass_kg + self.payload_mass_kg()
    }

    /// The mass on a spring on the table ([`Coupling::Payload`]); 0 otherwise.
    pub fn payload_mass_kg(&self) -> f64 {
        match self.coupling {
            Coupling::Payload { mass_kg, .. } => mass_kg,
            _ => 0.0,
        }
    }
}

/// Mechanical coupling between motor and table (drive compliance, SPEC §7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Coupling {
    /// Motor and table move as one body (apart from backlash).
    Rigid,
    /// Motor and table joined by the screw/nut/coupling spring and damper.
    TwoMass {
        /// Axial stiffness between motor (load side) and table, N/µm.
        stiffness_n_per_um: f64,
        /// Damping across that spring, N·s/m.
        damping_n_s_per_m: f64,
    },
    /// Motor and table rigid (apart from backlash is not supported), with a payload — a
    /// fixture, a workpiece, a tool head on a flexible mount — on a spring and damper on the
    /// table. The slide friction and the scale stay on the table; the payload is neither
    /// rubbed nor measured, so it shows only through the force it pushes back with.
    Payload {
        /// Mass on the spring, kg (not part of `table_mass_kg`).
        mass_kg: f64,
        /// Stiffness of its mount, N/µm.
        stiffness_n_per_um: f64,
        /// Damping across the mount, N·s/m.
        damping_n_s_per_m: f64,
        /// A mount that stiffens as it deflects: F = k·d·(1 + (d/d₀)²), d₀ this deflection,
        /// µm (where the force has doubled over the linear spring's). 0: a linear mount.
        #[serde(default)]
        hardening_deflection_um: f64,
    },
}

/// Which sensor closes the position loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Feedback {
    /// Position from the motor encoder (semi-closed loop).
    Motor,
    /// Position from the linear scale on the table (closed loop).
    Scale,
}

/// Cascade amplifier at T3. The gains are load-side (force per velocity), so the same
/// numbers work for any lead; the trace shows motor torque.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServoParams {
    /// Position-loop gain, 1/s: velocity command per position error.
    pub kp_per_s: f64,
    /// Velocity-loop proportional gain, load side.
    pub kv_n_s_per_m: f64,
    /// Velocity-loop integral corner: I-action = kv·ki·∫e. 0 = P only.
    #[serde(default)]
    pub ki_per_s: f64,
    /// Velocity feed-forward ratio, 0…1.
    #[serde(default)]
    pub vff: f64,
    /// Acceleration (torque) feed-forward ratio, 0…1: adds aff·M·a of the commanded
    /// acceleration, M the motor's reflected mass plus the table.
    #[serde(default)]
    pub aff: f64,
    /// Current-loop lag time constant. 0 = ideal current loop.
    #[serde(default)]
    pub current_lag_s: f64,
    /// Motor torque saturation, N·m (symmetric).
    pub torque_limit_nm: f64,
    /// Semi-closed (motor encoder) or closed loop (linear scale).
    pub feedback: Feedback,
    /// Velocity feedback through the 2-tap average (q_k + q_{k-1})/2 before differencing,
    /// as on the EMPS rig.
    #[serde(default)]
    pub vel_filter_avg2: bool,
}

/// Position sensors: motor encoder and linear scale, each optionally quantized.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Encoder {
    /// Motor encoder counts per revolution; one count is lead/counts of table travel.
    pub motor_counts_per_rev: u32,
    /// Round the motor encoder reading to whole counts.
    pub quantize_motor: bool,
    /// Linear-scale resolution (one count), µm.
    pub scale_resolution_um: f64,
    /// Round the linear-scale reading to whole counts.
    pub quantize_scale: bool,
}

/// Slide friction on the table, opposing its velocity (SPEC §7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Friction {
    /// Whether any friction acts.
    pub enabled: bool,
    /// Coulomb (sliding) friction level, N; it flips sign at each reversal.
    pub coulomb_n: f64,
    /// Speed over which the Coulomb level builds up, mm/s: the friction is
    /// level·tanh(v / this) and the slide never sticks. 0 (the default) is the exact
    /// stick/slip law, which flips the full level at the reversal and holds the slide at
    /// rest while the drive force stays within it. A lubricated contact or a rolling guide
    /// with a pre-sliding zone builds its friction up over a small speed (0.1–1 mm/s in the
    /// friction literature's smooth models).
    #[serde(default)]
    pub coulomb_smoothing_mm_per_s: f64,
    /// Viscous friction per table speed, N·s/m.
    pub viscous_n_s_per_m: f64,
    /// Half the difference of the viscous coefficients by direction, N·s/m: moving in +
    /// the coefficient is `viscous_n_s_per_m` + split, in − it is `viscous_n_s_per_m` −
    /// split. A wiper or a seal that drags more one way than the other does this; a
    /// symmetric viscous term cannot, and a constant force only at one feed. 0 (the
    /// default) is the same both ways.
    #[serde(default)]
    pub viscous_split_n_s_per_m: f64,
    /// A speed term that grows as a power of the speed, beside the linear one.
    #[serde(default)]
    pub viscous_power: ViscousPower,
    /// Breakaway friction above the Coulomb level at low speed.
    pub stribeck: Stribeck,
    /// Friction rise over repeated short strokes.
    pub stroke: StrokeFriction,
}

/// A speed-dependent friction that grows as a power of the speed, added to the linear
/// viscous term: F = `force_at_100mm_per_s_n`·(|v| / 100 mm/s)^`exponent`, opposing the
/// motion. Grease in a guideway or a seal's lip drags like this: more than linear at low
/// speed, less at high speed (the viscous term F_v·|v|^δ_v of the generalised Stribeck
/// curve). Below `core_mm_per_s` it is linear in the speed, through the same force there:
/// a power under 1 has an infinite slope at rest, which no period-by-period step can
/// follow. Off by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViscousPower {
    /// Whether the power-law term acts.
    pub enabled: bool,
    /// Its force at 100 mm/s, N.
    pub force_at_100mm_per_s_n: f64,
    /// The power of the speed (1: linear; under 1: a grease or a seal).
    pub exponent: f64,
    /// Below this speed the term is linear in the speed, mm/s.
    pub core_mm_per_s: f64,
}

impl Default for ViscousPower {
    fn default() -> Self {
        ViscousPower {
            enabled: false,
            force_at_100mm_per_s_n: 0.0,
            exponent: 0.5,
            core_mm_per_s: 1.0,
        }
    }
}

/// Breakaway friction: at rest the slide holds up to `static_n`; the kinetic level falls
/// from `static_n` to Coulomb with the characteristic velocity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stribeck {
    /// Whether the breakaway level applies.
    pub enabled: bool,
    /// Breakaway (static) friction, N; not below the Coulomb level.
    pub static_n: f64,
    /// Stribeck velocity, mm/s: the kinetic level decays toward Coulomb as
    /// e^(−(v/v_s)²), or e^(−|v|/v_s) with [`StribeckShape::Exponential`].
    pub velocity_mm_per_s: f64,
    /// How the breakaway excess falls off with the speed.
    #[serde(default)]
    pub shape: StribeckShape,
}

/// How the breakaway excess of [`Stribeck`] falls off with the speed: the two exponents of
/// the generalised Stribeck curve e^(−|v/v_s|^δ) that the friction literature fits most,
/// δ = 2 and δ = 1. The exponential keeps more of the excess well above v_s.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StribeckShape {
    /// e^(−(v/v_s)²).
    #[default]
    Gaussian,
    /// e^(−|v|/v_s).
    Exponential,
}

crate::choice_enum!(StribeckShape { Gaussian => "gaussian", Exponential => "exponential" });

/// How the lubricant film of [`StrokeFriction`] wears.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FilmLaw {
    /// By the count of short strokes (SPEC §5, the patent's N).
    #[default]
    Count,
    /// By the distance run near the turning points: within `pitch_mm` of the last reversal
    /// the film breaks down, w += (1 − w)·ds/breakdown; beyond it, it rebuilds,
    /// w −= w·ds/recovery; the level is w instead of 1 − e^(−n/growth). Every stroke starts
    /// with a rise, short strokes keep it.
    Distance,
}

crate::choice_enum!(FilmLaw { Count => "count", Distance => "distance" });

/// Friction rise over short reversal strokes (SPEC §5): each reversal stroke shorter than
/// `pitch_mm` adds one to a level n; once a stroke runs past the pitch, n decays with the
/// distance beyond it, n·exp(−(d − pitch)/recovery); the Coulomb and static levels scale
/// by 1 + rise·(1 − e^(−n/growth_strokes)). [`FilmLaw::Distance`] wears the film by the
/// distance run instead.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StrokeFriction {
    /// Whether the short-stroke rise applies.
    pub enabled: bool,
    /// How the film wears (count of short strokes by default).
    #[serde(default)]
    pub law: FilmLaw,
    /// Distance run within the pitch over which the film breaks down by 1 − 1/e, mm
    /// ([`FilmLaw::Distance`] only).
    #[serde(default = "default_breakdown_mm")]
    pub breakdown_mm: f64,
    /// Oil-groove pitch or screw lead, mm: strokes shorter than this count as short.
    pub pitch_mm: f64,
    /// Relative rise of the Coulomb and static levels at full growth (0.5 = +50 %).
    pub rise_ratio: f64,
    /// A rise added to the friction level rather than scaling it (for a slide whose
    /// nominal Coulomb level is 0): the level grows by rise_n·(1 − e^(−n/growth_strokes)).
    #[serde(default)]
    pub rise_n: f64,
    /// Short strokes for the rise to reach 1 − 1/e of full (the growth constant).
    pub growth_strokes: f64,
    /// Travel beyond the pitch over which the level n decays by 1/e, mm.
    pub recovery_mm: f64,
}

/// Backlash in the plant: a dead zone between motor and table (what the backlash patent, SPEC §2,
/// compensates).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LostMotion {
    /// Whether the dead zone exists; needs a motor inertia > 0.
    pub enabled: bool,
    /// Total width b of the dead zone between motor and table, µm.
    pub width_um: f64,
}

/// Gravity load on an inclined or vertical axis: −m·g·sin(incline) along the axis, plus an offset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gravity {
    /// Whether the gravity and offset forces act.
    pub enabled: bool,
    /// Angle of the axis above horizontal; 90 = vertical axis with + pointing up.
    pub incline_deg: f64,
    /// Mass gravity acts on along the axis (table, ram, tool), kg.
    pub moving_mass_kg: f64,
    /// A constant extra force on the table (counterbalance error, cable carrier), + along
    /// the axis.
    #[serde(default)]
    pub offset_n: f64,
}

/// First-order screw temperature heated by friction power and motion, cooled to ambient.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScrewThermal {
    /// Whether the screw heats and grows.
    pub enabled: bool,
    /// Linear expansion coefficient of the screw, 1/K (steel ≈ 11.5e−6).
    pub alpha_per_k: f64,
    /// Heat capacity of the screw, J/K.
    pub heat_capacity_j_per_k: f64,
    /// Heat loss to ambient per kelvin above it, W/K.
    pub loss_w_per_k: f64,
    /// Share of the slide friction power that heats the screw, 0…1.
    pub friction_heat_share: f64,
    /// Heat from nut, bearings and motor per unit speed.
    pub motion_heat_w_s_per_m: f64,
    /// Ambient temperature the screw cools toward, degC.
    pub ambient_c: f64,
    /// Screw temperature at start.
    pub initial_c: f64,
    /// Temperature at which the screw has its nominal length.
    pub reference_c: f64,
    /// Position of the fixed (thrust) bearing; the screw grows away from it.
    pub fixed_end_mm: f64,
}

/// Cyclic lead (pitch) error plus a cumulative lead deviation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LeadError {
    /// Whether the lead error acts; + error puts the table further + than the screw angle says.
    pub enabled: bool,
    /// Amplitude of the cyclic (sinusoidal) error, µm.
    pub amplitude_um: f64,
    /// Period of the cyclic error along the axis, mm (typically the screw lead).
    pub period_mm: f64,
    /// Phase of the cyclic error at position 0, degrees.
    #[serde(default)]
    pub phase_deg: f64,
    /// Cumulative lead deviation, µm per m of travel from position 0.
    #[serde(default)]
    pub cumulative_um_per_m: f64,
    /// Measured lead deviation (position mm, error µm), added to the cyclic part;
    /// interpolated linearly, end values held.
    #[serde(default)]
    pub table: Vec<(f64, f64)>,
}

// ---- fields, ranges and rules of each section ----------------------------------------------

use super::FieldError;
use super::fields::{Fields, Num, TableSpec, Walker};

/// Positions along an axis: ±100 m covers any machine tool.
pub(crate) const POS_MM: Num = Num::closed("mm", -1e5, 1e5);
/// Temperatures a machine meets in service.
pub(crate) const TEMP_C: Num = Num::closed("degC", -50.0, 200.0);
/// Forces on a feed axis: up to 1 MN.
const FORCE_N: Num = Num::closed("N", 0.0, 1e6);

fn err(out: &mut Vec<FieldError>, path: String, reason: String) {
    out.push(FieldError { path, reason });
}

crate::choice_enum!(Feedback { Motor => "motor", Scale => "scale" });

fn default_breakdown_mm() -> f64 {
    5.0
}

impl Fields for AxisParams {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.text("name", "name", &mut self.name);
        w.letter("letter", "program letter", &mut self.letter);
        w.index("channel", "channel", &mut self.channel, 0, 7);
        w.num(
            "initial_pos_mm",
            "initial position",
            &mut self.initial_pos_mm,
            POS_MM,
        );
        w.nest("drive", |w| self.drive.fields(w));
        w.nest("servo", |w| self.servo.fields(w));
        w.nest("encoder", |w| self.encoder.fields(w));
        w.nest("friction", |w| self.friction.fields(w));
        w.nest("lost_motion", |w| self.lost_motion.fields(w));
        w.nest("gravity", |w| self.gravity.fields(w));
        w.nest("screw_thermal", |w| self.screw_thermal.fields(w));
        w.nest("lead_error", |w| self.lead_error.fields(w));
        w.nest("backlash", |w| self.backlash.fields(w));
        w.nest("quadrant", |w| self.quadrant.fields(w));
        w.nest("thermal", |w| self.thermal.fields(w));
    }

    fn rules(&self, at: &str, out: &mut Vec<FieldError>) {
        if self.name.is_empty()
            || !self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_')
        {
            err(
                out,
                format!("{at}.name"),
                format!(
                    "'{}' must be non-empty ASCII letters, digits or _",
                    self.name
                ),
            );
        }
        if !matches!(self.letter, 'X' | 'Y' | 'Z' | 'C') {
            err(
                out,
                format!("{at}.letter"),
                format!("'{}' is not one of X, Y, Z, C", self.letter),
            );
        }
        let needs_motor_mass =
            self.lost_motion.enabled || matches!(self.drive.coupling, Coupling::TwoMass { .. });
        if self.lost_motion.enabled && matches!(self.drive.coupling, Coupling::Payload { .. }) {
            err(
                out,
                format!("{at}.drive.coupling"),
                "a payload on a spring is modelled on a drive without backlash: turn lost_motion \
                 off or use a two_mass coupling"
                    .into(),
            );
        }
        if needs_motor_mass && self.drive.motor_inertia_kgm2 <= 0.0 {
            err(
                out,
                format!("{at}.drive.motor_inertia_kgm2"),
                "must be > 0 when backlash or a two-mass coupling separates motor and table".into(),
            );
        }
        for (name, sub) in [
            ("friction", &self.friction as &dyn SectionRules),
            ("backlash", &self.backlash),
            ("quadrant", &self.quadrant),
            ("thermal", &self.thermal),
            ("lead_error", &self.lead_error),
        ] {
            sub.section_rules(&format!("{at}.{name}"), out);
        }
    }
}

/// Lets [`AxisParams::rules`] run the rules of its sub-sections through one list.
pub(crate) trait SectionRules {
    fn section_rules(&self, at: &str, out: &mut Vec<FieldError>);
}

impl<T: Fields> SectionRules for T {
    fn section_rules(&self, at: &str, out: &mut Vec<FieldError>) {
        self.rules(at, out);
    }
}

impl Fields for Drive {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.num(
            "motor_inertia_kgm2",
            "motor inertia",
            &mut self.motor_inertia_kgm2,
            Num::closed("kg*m^2", 0.0, 100.0),
        );
        w.num(
            "lead_mm",
            "screw lead",
            &mut self.lead_mm,
            Num::closed("mm", 0.1, 1000.0),
        );
        w.num(
            "table_mass_kg",
            "table mass",
            &mut self.table_mass_kg,
            Num::closed("kg", 0.01, 1e6),
        );
        let mut kind = CouplingKind::of(&self.coupling);
        w.choice("coupling", "coupling", &mut kind);
        kind.apply(&mut self.coupling);
        if let Coupling::TwoMass {
            stiffness_n_per_um,
            damping_n_s_per_m,
        } = &mut self.coupling
        {
            w.nest("coupling", |w| {
                w.num(
                    "stiffness_n_per_um",
                    "stiffness",
                    stiffness_n_per_um,
                    Num::closed("N/um", 0.01, 1e5),
                );
                w.num(
                    "damping_n_s_per_m",
                    "damping",
                    damping_n_s_per_m,
                    Num::closed("N*s/m", 0.0, 1e8),
                );
            });
        }
        if let Coupling::Payload {
            mass_kg,
            stiffness_n_per_um,
            damping_n_s_per_m,
            hardening_deflection_um,
        } = &mut self.coupling
        {
            w.nest("coupling", |w| {
                w.num(
                    "mass_kg",
                    "payload mass",
                    mass_kg,
                    Num::closed("kg", 0.01, 1e6),
                );
                w.num(
                    "stiffness_n_per_um",
                    "mount stiffness",
                    stiffness_n_per_um,
                    Num::closed("N/um", 0.01, 1e5),
                );
                w.num(
                    "damping_n_s_per_m",
                    "mount damping",
                    damping_n_s_per_m,
                    Num::closed("N*s/m", 0.0, 1e8),
                );
                w.num(
                    "hardening_deflection_um",
                    "hardening deflection (0: linear)",
                    hardening_deflection_um,
                    Num::closed("um", 0.0, 1e5),
                );
            });
        }
    }
}

/// The coupling's variant, chosen by name; switching to two-mass starts from a stiff,
/// lightly damped screw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum CouplingKind {
    Rigid,
    TwoMass,
    Payload,
}

crate::choice_enum!(CouplingKind { Rigid => "rigid", TwoMass => "two_mass", Payload => "payload" });

impl CouplingKind {
    fn of(c: &Coupling) -> CouplingKind {
        match c {
            Coupling::Rigid => CouplingKind::Rigid,
            Coupling::TwoMass { .. } => CouplingKind::TwoMass,
            Coupling::Payload { .. } => CouplingKind::Payload,
        }
    }

    fn apply(self, c: &mut Coupling) {
        match (self, &*c) {
            (CouplingKind::Rigid, Coupling::Rigid)
            | (CouplingKind::TwoMass, Coupling::TwoMass { .. })
            | (CouplingKind::Payload, Coupling::Payload { .. }) => {}
            (CouplingKind::Rigid, _) => *c = Coupling::Rigid,
            (CouplingKind::TwoMass, _) => {
                *c = Coupling::TwoMass {
                    stiffness_n_per_um: 200.0,
                    damping_n_s_per_m: 2000.0,
                }
            }
            (CouplingKind::Payload, _) => {
                *c = Coupling::Payload {
                    mass_kg: 20.0,
                    stiffness_n_per_um: 10.0,
                    damping_n_s_per_m: 1000.0,
                    hardening_deflection_um: 0.0,
                }
            }
        }
    }
}

impl Fields for ServoParams {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.num(
            "kp_per_s",
            "Kp",
            &mut self.kp_per_s,
            Num::above("1/s", 0.0, 1e4),
        );
        w.num(
            "kv_n_s_per_m",
            "Kv",
            &mut self.kv_n_s_per_m,
            Num::above("N*s/m", 0.0, 1e9),
        );
        w.num(
            "ki_per_s",
            "Ki",
            &mut self.ki_per_s,
            Num::closed("1/s", 0.0, 1e5),
        );
        w.num(
            "vff",
            "velocity feed-forward",
            &mut self.vff,
            Num::closed("", 0.0, 1.0),
        );
        w.num(
            "aff",
            "acceleration feed-forward",
            &mut self.aff,
            Num::closed("", 0.0, 1.0),
        );
        w.num(
            "current_lag_s",
            "current-loop lag",
            &mut self.current_lag_s,
            Num::closed("s", 0.0, 1.0),
        );
        w.num(
            "torque_limit_nm",
            "torque limit",
            &mut self.torque_limit_nm,
            Num::above("N*m", 0.0, 1e5),
        );
        w.choice("feedback", "position feedback", &mut self.feedback);
        w.flag(
            "vel_filter_avg2",
            "2-tap velocity filter",
            &mut self.vel_filter_avg2,
        );
    }
}

impl Fields for Encoder {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.count(
            "motor_counts_per_rev",
            "motor encoder counts/rev",
            &mut self.motor_counts_per_rev,
            1,
            1 << 30,
        );
        w.flag(
            "quantize_motor",
            "quantize motor encoder",
            &mut self.quantize_motor,
        );
        w.num(
            "scale_resolution_um",
            "scale resolution",
            &mut self.scale_resolution_um,
            Num::closed("um", 1e-4, 1000.0),
        );
        w.flag("quantize_scale", "quantize scale", &mut self.quantize_scale);
    }
}

impl Fields for Friction {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "friction on", &mut self.enabled);
        w.when(self.enabled, |w| {
            w.num("coulomb_n", "Coulomb", &mut self.coulomb_n, FORCE_N);
            w.num(
                "coulomb_smoothing_mm_per_s",
                "Coulomb smoothing (tanh)",
                &mut self.coulomb_smoothing_mm_per_s,
                Num::closed("mm/s", 0.0, 100.0),
            );
            w.num(
                "viscous_n_s_per_m",
                "viscous",
                &mut self.viscous_n_s_per_m,
                Num::closed("N*s/m", 0.0, 1e8),
            );
            w.num(
                "viscous_split_n_s_per_m",
                "viscous split (+/-)",
                &mut self.viscous_split_n_s_per_m,
                Num::closed("N*s/m", -1e8, 1e8),
            );
            w.nest("viscous_power", |w| self.viscous_power.fields(w));
            w.nest("stribeck", |w| {
                w.flag("enabled", "Stribeck on", &mut self.stribeck.enabled);
                w.when(self.stribeck.enabled, |w| {
                    w.num(
                        "static_n",
                        "breakaway",
                        &mut self.stribeck.static_n,
                        FORCE_N,
                    );
                    w.num(
                        "velocity_mm_per_s",
                        "Stribeck velocity",
                        &mut self.stribeck.velocity_mm_per_s,
                        Num::closed("mm/s", 1e-4, 1e4),
                    );
                    w.choice("shape", "Stribeck fall-off", &mut self.stribeck.shape);
                });
            });
            w.nest("stroke", |w| {
                let s = &mut self.stroke;
                w.flag("enabled", "short-stroke rise on", &mut s.enabled);
                w.when(s.enabled, |w| {
                    w.choice("law", "film wears by", &mut s.law);
                    let distance = s.law == FilmLaw::Distance;
                    w.when(distance, |w| {
                        w.num(
                            "breakdown_mm",
                            "breakdown",
                            &mut s.breakdown_mm,
                            Num::closed("mm", 0.01, 1e6),
                        );
                    });
                    w.num(
                        "pitch_mm",
                        "pitch",
                        &mut s.pitch_mm,
                        Num::closed("mm", 0.01, 1e4),
                    );
                    w.num(
                        "rise_ratio",
                        "rise",
                        &mut s.rise_ratio,
                        Num::closed("", 0.0, 100.0),
                    );
                    w.num("rise_n", "added rise", &mut s.rise_n, FORCE_N);
                    w.num(
                        "growth_strokes",
                        "growth",
                        &mut s.growth_strokes,
                        Num::closed("strokes", 0.01, 1e6),
                    );
                    w.num(
                        "recovery_mm",
                        "recovery",
                        &mut s.recovery_mm,
                        Num::closed("mm", 0.01, 1e6),
                    );
                });
            });
        });
    }

    fn rules(&self, at: &str, out: &mut Vec<FieldError>) {
        if self.enabled && self.viscous_split_n_s_per_m.abs() > self.viscous_n_s_per_m {
            err(
                out,
                format!("{at}.viscous_split_n_s_per_m"),
                format!(
                    "a split of {} N*s/m around a viscous coefficient of {} N*s/m makes one direction's coefficient negative (a friction that pushes)",
                    super::fields::short(self.viscous_split_n_s_per_m),
                    super::fields::short(self.viscous_n_s_per_m)
                ),
            );
        }
        if self.stribeck.enabled && self.stribeck.static_n < self.coulomb_n {
            err(
                out,
                format!("{at}.stribeck.static_n"),
                format!(
                    "breakaway {} N is below the Coulomb level {} N",
                    super::fields::short(self.stribeck.static_n),
                    super::fields::short(self.coulomb_n)
                ),
            );
        }
    }
}

impl Fields for ViscousPower {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "power-law speed term on", &mut self.enabled);
        w.when(self.enabled, |w| {
            w.num(
                "force_at_100mm_per_s_n",
                "force at 100 mm/s",
                &mut self.force_at_100mm_per_s_n,
                Num::closed("N", 0.0, 1e6),
            );
            w.num(
                "exponent",
                "speed exponent",
                &mut self.exponent,
                Num::closed("", 0.05, 3.0),
            );
            w.num(
                "core_mm_per_s",
                "linear below",
                &mut self.core_mm_per_s,
                Num::closed("mm/s", 1e-3, 1e3),
            );
        });
    }
}

impl Fields for LostMotion {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "lost motion on", &mut self.enabled);
        w.when(self.enabled, |w| {
            w.num(
                "width_um",
                "width",
                &mut self.width_um,
                Num::closed("um", 0.0, 1e4),
            );
        });
    }
}

impl Fields for Gravity {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "gravity on", &mut self.enabled);
        w.when(self.enabled, |w| {
            w.num(
                "incline_deg",
                "incline",
                &mut self.incline_deg,
                Num::closed("deg", -90.0, 90.0),
            );
            w.num(
                "moving_mass_kg",
                "moving mass",
                &mut self.moving_mass_kg,
                Num::closed("kg", 0.0, 1e6),
            );
            w.num(
                "offset_n",
                "offset force",
                &mut self.offset_n,
                Num::closed("N", -1e6, 1e6),
            );
        });
    }
}

impl Fields for ScrewThermal {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "screw thermal growth on", &mut self.enabled);
        w.when(self.enabled, |w| {
            w.num(
                "alpha_per_k",
                "expansion coefficient",
                &mut self.alpha_per_k,
                Num::closed("1/K", 0.0, 1e-3),
            );
            w.num(
                "heat_capacity_j_per_k",
                "heat capacity",
                &mut self.heat_capacity_j_per_k,
                Num::above("J/K", 0.0, 1e9),
            );
            w.num(
                "loss_w_per_k",
                "heat loss",
                &mut self.loss_w_per_k,
                Num::closed("W/K", 0.0, 1e6),
            );
            w.num(
                "friction_heat_share",
                "friction heat share",
                &mut self.friction_heat_share,
                Num::closed("", 0.0, 1.0),
            );
            w.num(
                "motion_heat_w_s_per_m",
                "motion heat",
                &mut self.motion_heat_w_s_per_m,
                Num::closed("W*s/m", 0.0, 1e7),
            );
            w.num("ambient_c", "ambient", &mut self.ambient_c, TEMP_C);
            w.num("initial_c", "initial", &mut self.initial_c, TEMP_C);
            w.num("reference_c", "reference", &mut self.reference_c, TEMP_C);
            w.num(
                "fixed_end_mm",
                "fixed bearing at",
                &mut self.fixed_end_mm,
                POS_MM,
            );
        });
    }
}

impl Fields for LeadError {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "lead error on", &mut self.enabled);
        w.when(self.enabled, |w| {
            w.num(
                "amplitude_um",
                "cyclic amplitude",
                &mut self.amplitude_um,
                Num::closed("um", 0.0, 1e4),
            );
            w.num(
                "period_mm",
                "cyclic period",
                &mut self.period_mm,
                Num::closed("mm", 0.01, 1e5),
            );
            w.num(
                "phase_deg",
                "phase",
                &mut self.phase_deg,
                Num::closed("deg", -1e4, 1e4),
            );
            w.num(
                "cumulative_um_per_m",
                "cumulative",
                &mut self.cumulative_um_per_m,
                Num::closed("um/m", -1e4, 1e4),
            );
            w.table(
                "table",
                "measured table",
                &mut self.table,
                TableSpec {
                    x: POS_MM,
                    y: Num::closed("um", -1e5, 1e5),
                    min_points: 0,
                    max_points: 10_000,
                },
            );
        });
    }
}
