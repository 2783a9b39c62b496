//! Presets: the whole machine and scenario as one RON document.
//!
//! A preset is what a service engineer saves and reloads, so it uses the units an engineer
//! reads off a data sheet (mm, µm, kg, N, degC, with the unit in every field name). The model
//! converts to SI once, when it is built ([`crate::machine::Machine::new`]).
//!
//! Loading is strict: unknown fields are rejected (`deny_unknown_fields`) so that a typo in a
//! hand-edited file is an error, not a silently ignored setting, and every file carries a
//! `version` so that old files can be migrated instead of misread.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The preset format version this build reads and writes.
pub const PRESET_VERSION: u32 = 1;

/// Every preset and program shipped in `presets/`, embedded so the binary runs anywhere.
pub const EMBEDDED: &[(&str, &str)] = &[
    ("default.ron", include_str!("../presets/default.ron")),
    ("default.ngc", include_str!("../presets/default.ngc")),
    (
        "vertical_z_gravity.ron",
        include_str!("../presets/vertical_z_gravity.ron"),
    ),
    (
        "vertical_z_gravity.ngc",
        include_str!("../presets/vertical_z_gravity.ngc"),
    ),
    (
        "short_stroke_quadrant.ron",
        include_str!("../presets/short_stroke_quadrant.ron"),
    ),
    (
        "short_stroke_quadrant.ngc",
        include_str!("../presets/short_stroke_quadrant.ngc"),
    ),
    (
        "thermal_warmup.ron",
        include_str!("../presets/thermal_warmup.ron"),
    ),
    (
        "thermal_warmup.ngc",
        include_str!("../presets/thermal_warmup.ngc"),
    ),
    (
        "thermal_warmup_slow.ngc",
        include_str!("../presets/thermal_warmup_slow.ngc"),
    ),
    (
        "vertical_lathe_crossbeam.ron",
        include_str!("../presets/vertical_lathe_crossbeam.ron"),
    ),
    (
        "vertical_lathe_left.ngc",
        include_str!("../presets/vertical_lathe_left.ngc"),
    ),
    (
        "vertical_lathe_right.ngc",
        include_str!("../presets/vertical_lathe_right.ngc"),
    ),
    (
        "vertical_lathe_right_traverse.ngc",
        include_str!("../presets/vertical_lathe_right_traverse.ngc"),
    ),
    ("xy_circle.ron", include_str!("../presets/xy_circle.ron")),
    ("xy_circle.ngc", include_str!("../presets/xy_circle.ngc")),
    ("emps.ron", include_str!("../presets/emps.ron")),
    ("emps.ngc", include_str!("../presets/emps.ngc")),
];

/// Names of the shipped presets, in the order a trainer would show them.
pub const SHIPPED_PRESETS: &[&str] = &[
    "default.ron",
    "vertical_z_gravity.ron",
    "short_stroke_quadrant.ron",
    "thermal_warmup.ron",
    "vertical_lathe_crossbeam.ron",
    "xy_circle.ron",
    "emps.ron",
];

/// Looks up an embedded file by its name in `presets/`.
pub fn embedded(name: &str) -> Option<&'static str> {
    EMBEDDED.iter().find(|(n, _)| *n == name).map(|(_, s)| *s)
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Preset {
    pub version: u32,
    pub name: String,
    #[serde(default)]
    pub description: String,
    pub timing: Timing,
    pub nc: NcParams,
    pub axes: Vec<AxisParams>,
    #[serde(default)]
    pub crossbeam: Crossbeam,
    /// Cross (sag) compensation tables (seed 004).
    #[serde(default)]
    pub cross: Vec<crate::comp::cross::CrossTable>,
    pub scenario: Scenario,
    /// How measured records of this machine are read for the sim-to-real diagnosis.
    #[serde(default, skip_serializing_if = "DiagnoseSettings::is_default")]
    pub diagnose: DiagnoseSettings,
}

/// What a measured record of this machine looks like, so `axisbench diagnose` can read it
/// without a `--map` every time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct DiagnoseSettings {
    /// Default column mapping for foreign layouts (TRACE_FORMAT.md), e.g.
    /// `"t[s]=t_s, x.cmd[m]=qg_m, x.pos[m]=qm_m, x.force[N]=force_N"`.
    #[serde(default)]
    pub mapping: Option<String>,
    /// Which sensor the record's `pos` column comes from.
    #[serde(default)]
    pub pos_source: PosSource,
}

impl DiagnoseSettings {
    pub fn is_default(&self) -> bool {
        *self == DiagnoseSettings::default()
    }
}

/// The sensor behind a trace's `pos` column. It decides which model signal a measured
/// position is compared with: backlash, lead error and thermal growth are invisible to a
/// motor encoder and visible to a linear scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PosSource {
    /// The true table position, as axisbench's own traces record it.
    #[default]
    Load,
    /// The motor encoder converted to load travel (quantized at the motor counts).
    MotorEncoder,
    /// The linear scale on the table (quantized at the scale resolution).
    Scale,
}

/// Control periods. T1 ≥ T2 ≥ T3, with integer ratios (SPEC §1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Timing {
    /// Interpolation period T1 of the normal processing mode.
    pub t1_s: f64,
    /// NC → amplifier communication period T2.
    pub t2_s: f64,
    /// Amplifier internal control period T3 (one trace sample).
    pub t3_s: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Parse → interpolate at T1 → acc/dec → position command at T2 → amplifier subdivides.
    #[default]
    Normal,
    /// Program blocks are already-interpolated T3 samples (seed 001, G05P4).
    Direct,
}

impl Mode {
    pub fn as_f64(self) -> f64 {
        match self {
            Mode::Normal => 0.0,
            Mode::Direct => 1.0,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NcParams {
    #[serde(default)]
    pub initial_mode: Mode,
    pub accdec: AccDec,
    /// Feed used for G00.
    pub rapid_mm_per_min: f64,
    /// Feed used by G01/G02/G03 before the program sets F.
    #[serde(default = "default_feed")]
    pub default_feed_mm_per_min: f64,
}

fn default_feed() -> f64 {
    1000.0
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AccDecKind {
    /// No acc/dec filter: the interpolated command goes straight to the position command.
    None,
    /// One moving-average stage: velocity ramps linearly over `tc1_s`.
    Linear,
    /// Two moving-average stages (`tc1_s`, `tc2_s`): bell/S-shaped velocity, limited jerk.
    Bell,
}

/// Acc/dec after interpolation, applied per axis in both processing modes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccDec {
    pub kind: AccDecKind,
    pub tc1_s: f64,
    #[serde(default)]
    pub tc2_s: f64,
}

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
    #[serde(default)]
    pub initial_pos_mm: f64,
    pub drive: Drive,
    pub servo: ServoParams,
    pub encoder: Encoder,
    pub friction: Friction,
    pub lost_motion: LostMotion,
    pub gravity: Gravity,
    pub screw_thermal: ScrewThermal,
    pub lead_error: LeadError,
    /// Backlash compensation (seed 000).
    #[serde(default)]
    pub backlash: crate::comp::backlash::BacklashParams,
    /// Quadrant (reversal) compensation adapting to short strokes (seed 003).
    #[serde(default)]
    pub quadrant: crate::comp::quadrant::QuadrantParams,
    /// Thermal displacement correction with automatic re-measurement (seed 002).
    #[serde(default)]
    pub thermal: crate::comp::thermal::ThermalParams,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Drive {
    pub motor_inertia_kgm2: f64,
    /// Ball-screw lead: table travel per motor revolution.
    pub lead_mm: f64,
    pub table_mass_kg: f64,
    pub coupling: Coupling,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Coupling {
    /// Motor and table move as one body (apart from backlash).
    Rigid,
    /// Motor and table joined by the screw/nut/coupling spring and damper.
    TwoMass {
        stiffness_n_per_um: f64,
        damping_n_s_per_m: f64,
    },
}

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
    pub torque_limit_nm: f64,
    pub feedback: Feedback,
    /// Velocity feedback through the 2-tap average (q_k + q_{k-1})/2 before differencing,
    /// as on the EMPS rig.
    #[serde(default)]
    pub vel_filter_avg2: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Encoder {
    pub motor_counts_per_rev: u32,
    pub quantize_motor: bool,
    pub scale_resolution_um: f64,
    pub quantize_scale: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Friction {
    pub enabled: bool,
    pub coulomb_n: f64,
    pub viscous_n_s_per_m: f64,
    pub stribeck: Stribeck,
    pub stroke: StrokeFriction,
}

/// Breakaway friction: at rest the slide holds up to `static_n`; the kinetic level falls
/// from `static_n` to Coulomb with the characteristic velocity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stribeck {
    pub enabled: bool,
    pub static_n: f64,
    pub velocity_mm_per_s: f64,
}

/// Friction rise over short reversal strokes (SPEC §5): each reversal stroke shorter than
/// `pitch_mm` adds one to a level n; once a stroke runs past the pitch, n decays with the
/// distance beyond it, n·exp(−(d − pitch)/recovery); the Coulomb and static levels scale
/// by 1 + rise·(1 − e^(−n/growth_strokes)).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StrokeFriction {
    pub enabled: bool,
    pub pitch_mm: f64,
    pub rise_ratio: f64,
    pub growth_strokes: f64,
    pub recovery_mm: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LostMotion {
    pub enabled: bool,
    /// Total width b of the dead zone between motor and table.
    pub width_um: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gravity {
    pub enabled: bool,
    /// Angle of the axis above horizontal; 90 = vertical axis with + pointing up.
    pub incline_deg: f64,
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
    pub enabled: bool,
    pub alpha_per_k: f64,
    pub heat_capacity_j_per_k: f64,
    pub loss_w_per_k: f64,
    /// Share of the slide friction power that heats the screw, 0…1.
    pub friction_heat_share: f64,
    /// Heat from nut, bearings and motor per unit speed.
    pub motion_heat_w_s_per_m: f64,
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
    pub enabled: bool,
    pub amplitude_um: f64,
    pub period_mm: f64,
    #[serde(default)]
    pub phase_deg: f64,
    #[serde(default)]
    pub cumulative_um_per_m: f64,
    /// Measured lead deviation (position mm, error µm), added to the cyclic part;
    /// interpolated linearly, end values held.
    #[serde(default)]
    pub table: Vec<(f64, f64)>,
}

/// Crossbeam of a vertical lathe: a simply supported beam along X carrying one or two tool
/// posts, each with its own vertical (Z) axis. The beam deflection at a post moves that
/// post's tool tip in −Z.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Crossbeam {
    pub enabled: bool,
    /// Span between the two column supports; X = 0 is the left support.
    pub span_mm: f64,
    pub youngs_modulus_gpa: f64,
    /// Second moment of area of the beam section.
    pub area_moment_cm4: f64,
    /// Beam self-weight per length.
    pub self_weight_n_per_m: f64,
    pub posts: Vec<ToolPost>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToolPost {
    /// Axis that moves the post along the beam.
    pub x_axis: String,
    /// The post's vertical ram axis, which the sag displaces.
    pub z_axis: String,
    pub weight_n: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// One program per NC channel, as file names relative to the preset file.
    pub programs: Vec<String>,
    /// Fixed run length. None: run the program to its end, then `settle_s`.
    #[serde(default)]
    pub duration_s: Option<f64>,
    #[serde(default = "default_settle")]
    pub settle_s: f64,
    /// PLC mode-switch requests at set times (seed 001).
    #[serde(default)]
    pub plc_events: Vec<PlcEvent>,
    /// Keep every n-th T3 sample in the trace (1 = every sample). Long thermal runs use more.
    #[serde(default = "one")]
    pub trace_every: u32,
}

fn default_settle() -> f64 {
    0.2
}

fn one() -> u32 {
    1
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlcEvent {
    pub t_s: f64,
    pub mode: Mode,
    #[serde(default)]
    pub channel: usize,
}

/// One validation finding: which field, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldError {
    pub path: String,
    pub reason: String,
}

impl std::fmt::Display for FieldError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path, self.reason)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum PresetError {
    #[error("{file}: cannot read: {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}:{line}:{col}: {msg}")]
    Syntax {
        file: String,
        line: usize,
        col: usize,
        msg: String,
    },
    #[error("{file}: invalid preset:\n{}", list(.errors))]
    Invalid {
        file: String,
        errors: Vec<FieldError>,
    },
    #[error(
        "{file}: preset version {found} is not supported (this build reads version {PRESET_VERSION})"
    )]
    Version { file: String, found: u32 },
    #[error("--set {path}: {reason}")]
    Override { path: String, reason: String },
    #[error("cannot write preset: {0}")]
    Serialize(String),
}

fn list(errors: &[FieldError]) -> String {
    errors
        .iter()
        .map(|e| format!("  - {e}"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// A preset plus where it came from, so that program files resolve relative to it.
#[derive(Debug, Clone)]
pub struct LoadedPreset {
    pub preset: Preset,
    /// Folder of the preset file; None for an embedded preset.
    pub dir: Option<PathBuf>,
    pub origin: String,
}

impl LoadedPreset {
    /// Reads one of the scenario's program files (embedded presets read embedded programs).
    pub fn program_text(&self, name: &str) -> Result<String, PresetError> {
        match &self.dir {
            Some(dir) => {
                let path = dir.join(name);
                std::fs::read_to_string(&path).map_err(|source| PresetError::Io {
                    file: path.display().to_string(),
                    source,
                })
            }
            None => embedded(name)
                .map(str::to_owned)
                .ok_or_else(|| PresetError::Io {
                    file: format!("<embedded>/{name}"),
                    source: std::io::Error::new(
                        std::io::ErrorKind::NotFound,
                        "no such embedded program",
                    ),
                }),
        }
    }
}

impl Preset {
    /// Parses and validates RON text. `file` names the source in every error.
    pub fn from_ron(text: &str, file: &str) -> Result<Preset, PresetError> {
        let preset: Preset = ron::from_str(text).map_err(|e| PresetError::Syntax {
            file: file.to_owned(),
            line: e.span.start.line,
            col: e.span.start.col,
            msg: e.code.to_string(),
        })?;
        if preset.version != PRESET_VERSION {
            return Err(PresetError::Version {
                file: file.to_owned(),
                found: preset.version,
            });
        }
        let errors = preset.validate();
        if errors.is_empty() {
            Ok(preset)
        } else {
            Err(PresetError::Invalid {
                file: file.to_owned(),
                errors,
            })
        }
    }

    pub fn to_ron(&self) -> Result<String, PresetError> {
        let cfg = ron::ser::PrettyConfig::new()
            .depth_limit(8)
            .struct_names(false);
        ron::ser::to_string_pretty(self, cfg).map_err(|e| PresetError::Serialize(e.to_string()))
    }

    /// Checks every physical and structural rule; returns all findings, not just the first.
    pub fn validate(&self) -> Vec<FieldError> {
        let mut v = Validator::default();
        let t = &self.timing;
        v.pos("timing.t1_s", t.t1_s);
        v.pos("timing.t2_s", t.t2_s);
        v.pos("timing.t3_s", t.t3_s);
        if t.t1_s > 0.0 && t.t2_s > 0.0 && t.t3_s > 0.0 {
            if ratio(t.t1_s, t.t2_s).is_none() {
                v.err(
                    "timing.t1_s",
                    format!(
                        "T1 = {} s is not an integer multiple (≥ 1) of T2 = {} s",
                        t.t1_s, t.t2_s
                    ),
                );
            }
            if ratio(t.t2_s, t.t3_s).is_none() {
                v.err(
                    "timing.t2_s",
                    format!(
                        "T2 = {} s is not an integer multiple (≥ 1) of T3 = {} s",
                        t.t2_s, t.t3_s
                    ),
                );
            }
        }
        v.nonneg("nc.accdec.tc1_s", self.nc.accdec.tc1_s);
        v.nonneg("nc.accdec.tc2_s", self.nc.accdec.tc2_s);
        v.pos("nc.rapid_mm_per_min", self.nc.rapid_mm_per_min);
        v.pos(
            "nc.default_feed_mm_per_min",
            self.nc.default_feed_mm_per_min,
        );
        if self.axes.is_empty() {
            v.err("axes", "a machine needs at least one axis".into());
        }
        if self.axes.len() > 8 {
            v.err("axes", "at most 8 axes are supported".into());
        }
        let mut seen_names = BTreeMap::new();
        let mut seen_letters = BTreeMap::new();
        for (i, a) in self.axes.iter().enumerate() {
            let p = format!("axes[{}]", a.name);
            if a.name.is_empty()
                || !a
                    .name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_')
            {
                v.err(
                    &format!("axes[{i}].name"),
                    format!("'{}' must be non-empty ASCII letters, digits or _", a.name),
                );
            }
            if seen_names.insert(a.name.clone(), i).is_some() {
                v.err(&format!("{p}.name"), "duplicate axis name".into());
            }
            if !matches!(a.letter, 'X' | 'Y' | 'Z' | 'C') {
                v.err(
                    &format!("{p}.letter"),
                    format!("'{}' is not one of X, Y, Z, C", a.letter),
                );
            }
            if seen_letters.insert((a.channel, a.letter), i).is_some() {
                v.err(
                    &format!("{p}.letter"),
                    format!("letter {} is used twice in channel {}", a.letter, a.channel),
                );
            }
            if a.channel >= self.scenario.programs.len() {
                v.err(
                    &format!("{p}.channel"),
                    format!(
                        "channel {} has no program (scenario.programs has {})",
                        a.channel,
                        self.scenario.programs.len()
                    ),
                );
            }
            v.finite(&format!("{p}.initial_pos_mm"), a.initial_pos_mm);
            let d = &a.drive;
            v.nonneg(
                &format!("{p}.drive.motor_inertia_kgm2"),
                d.motor_inertia_kgm2,
            );
            v.pos(&format!("{p}.drive.lead_mm"), d.lead_mm);
            v.pos(&format!("{p}.drive.table_mass_kg"), d.table_mass_kg);
            let needs_motor_mass =
                a.lost_motion.enabled || matches!(d.coupling, Coupling::TwoMass { .. });
            if needs_motor_mass && d.motor_inertia_kgm2 <= 0.0 {
                v.err(
                    &format!("{p}.drive.motor_inertia_kgm2"),
                    "must be > 0 when backlash or a two-mass coupling separates motor and table"
                        .into(),
                );
            }
            if let Coupling::TwoMass {
                stiffness_n_per_um,
                damping_n_s_per_m,
            } = d.coupling
            {
                v.pos(
                    &format!("{p}.drive.coupling.stiffness_n_per_um"),
                    stiffness_n_per_um,
                );
                v.nonneg(
                    &format!("{p}.drive.coupling.damping_n_s_per_m"),
                    damping_n_s_per_m,
                );
            }
            let s = &a.servo;
            v.pos(&format!("{p}.servo.kp_per_s"), s.kp_per_s);
            v.pos(&format!("{p}.servo.kv_n_s_per_m"), s.kv_n_s_per_m);
            v.nonneg(&format!("{p}.servo.ki_per_s"), s.ki_per_s);
            v.range(&format!("{p}.servo.vff"), s.vff, 0.0, 1.0);
            v.range(&format!("{p}.servo.aff"), s.aff, 0.0, 1.0);
            v.nonneg(&format!("{p}.servo.current_lag_s"), s.current_lag_s);
            v.pos(&format!("{p}.servo.torque_limit_nm"), s.torque_limit_nm);
            if a.encoder.motor_counts_per_rev == 0 {
                v.err(
                    &format!("{p}.encoder.motor_counts_per_rev"),
                    "must be > 0".into(),
                );
            }
            v.pos(
                &format!("{p}.encoder.scale_resolution_um"),
                a.encoder.scale_resolution_um,
            );
            let f = &a.friction;
            v.nonneg(&format!("{p}.friction.coulomb_n"), f.coulomb_n);
            v.nonneg(
                &format!("{p}.friction.viscous_n_s_per_m"),
                f.viscous_n_s_per_m,
            );
            v.nonneg(
                &format!("{p}.friction.stribeck.static_n"),
                f.stribeck.static_n,
            );
            v.pos(
                &format!("{p}.friction.stribeck.velocity_mm_per_s"),
                f.stribeck.velocity_mm_per_s,
            );
            if f.stribeck.enabled && f.stribeck.static_n < f.coulomb_n {
                v.err(
                    &format!("{p}.friction.stribeck.static_n"),
                    format!(
                        "breakaway {} N is below the Coulomb level {} N",
                        f.stribeck.static_n, f.coulomb_n
                    ),
                );
            }
            v.pos(&format!("{p}.friction.stroke.pitch_mm"), f.stroke.pitch_mm);
            v.nonneg(
                &format!("{p}.friction.stroke.rise_ratio"),
                f.stroke.rise_ratio,
            );
            v.pos(
                &format!("{p}.friction.stroke.growth_strokes"),
                f.stroke.growth_strokes,
            );
            v.pos(
                &format!("{p}.friction.stroke.recovery_mm"),
                f.stroke.recovery_mm,
            );
            v.nonneg(&format!("{p}.lost_motion.width_um"), a.lost_motion.width_um);
            v.range(
                &format!("{p}.gravity.incline_deg"),
                a.gravity.incline_deg,
                -90.0,
                90.0,
            );
            v.nonneg(
                &format!("{p}.gravity.moving_mass_kg"),
                a.gravity.moving_mass_kg,
            );
            v.finite(&format!("{p}.gravity.offset_n"), a.gravity.offset_n);
            let th = &a.screw_thermal;
            v.nonneg(&format!("{p}.screw_thermal.alpha_per_k"), th.alpha_per_k);
            v.pos(
                &format!("{p}.screw_thermal.heat_capacity_j_per_k"),
                th.heat_capacity_j_per_k,
            );
            v.nonneg(&format!("{p}.screw_thermal.loss_w_per_k"), th.loss_w_per_k);
            v.range(
                &format!("{p}.screw_thermal.friction_heat_share"),
                th.friction_heat_share,
                0.0,
                1.0,
            );
            v.nonneg(
                &format!("{p}.screw_thermal.motion_heat_w_s_per_m"),
                th.motion_heat_w_s_per_m,
            );
            v.temp(&format!("{p}.screw_thermal.ambient_c"), th.ambient_c);
            v.temp(&format!("{p}.screw_thermal.initial_c"), th.initial_c);
            v.temp(&format!("{p}.screw_thermal.reference_c"), th.reference_c);
            v.finite(&format!("{p}.screw_thermal.fixed_end_mm"), th.fixed_end_mm);
            v.nonneg(
                &format!("{p}.lead_error.amplitude_um"),
                a.lead_error.amplitude_um,
            );
            v.pos(&format!("{p}.lead_error.period_mm"), a.lead_error.period_mm);
            v.finite(&format!("{p}.lead_error.phase_deg"), a.lead_error.phase_deg);
            v.finite(
                &format!("{p}.lead_error.cumulative_um_per_m"),
                a.lead_error.cumulative_um_per_m,
            );
            for (path, reason) in
                crate::table::check(&format!("{p}.lead_error.table"), &a.lead_error.table, 0)
            {
                v.err(&path, reason);
            }
        }
        for a in &self.axes {
            let p = format!("axes[{}]", a.name);
            for (sub, reason) in a.backlash.check() {
                v.err(&format!("{p}.backlash.{sub}"), reason);
            }
            for (sub, reason) in a.quadrant.check() {
                v.err(&format!("{p}.quadrant.{sub}"), reason);
            }
            for (sub, reason) in a.thermal.check() {
                v.err(&format!("{p}.thermal.{sub}"), reason);
            }
        }
        for (i, t) in self.cross.iter().enumerate() {
            for (sub, reason) in t.check() {
                v.err(&format!("cross[{i}].{sub}"), reason);
            }
            for (field, name) in [("base_axis", &t.base_axis), ("comp_axis", &t.comp_axis)] {
                if !self.axes.iter().any(|a| &a.name == name) {
                    v.err(
                        &format!("cross[{i}].{field}"),
                        format!("no axis named '{name}'"),
                    );
                }
            }
            if t.base_axis == t.comp_axis {
                v.err(
                    &format!("cross[{i}].comp_axis"),
                    "must differ from the base axis".into(),
                );
            }
        }
        let cb = &self.crossbeam;
        if cb.enabled {
            v.pos("crossbeam.span_mm", cb.span_mm);
            v.pos("crossbeam.youngs_modulus_gpa", cb.youngs_modulus_gpa);
            v.pos("crossbeam.area_moment_cm4", cb.area_moment_cm4);
            v.nonneg("crossbeam.self_weight_n_per_m", cb.self_weight_n_per_m);
            if cb.posts.is_empty() || cb.posts.len() > 2 {
                v.err(
                    "crossbeam.posts",
                    format!("needs one or two tool posts, found {}", cb.posts.len()),
                );
            }
            for (i, post) in cb.posts.iter().enumerate() {
                v.nonneg(&format!("crossbeam.posts[{i}].weight_n"), post.weight_n);
                for (field, name) in [("x_axis", &post.x_axis), ("z_axis", &post.z_axis)] {
                    if !self.axes.iter().any(|a| &a.name == name) {
                        v.err(
                            &format!("crossbeam.posts[{i}].{field}"),
                            format!("no axis named '{name}'"),
                        );
                    }
                }
            }
        }
        let sc = &self.scenario;
        if sc.programs.is_empty() {
            v.err("scenario.programs", "needs at least one program".into());
        }
        if let Some(d) = sc.duration_s {
            v.pos("scenario.duration_s", d);
        }
        v.nonneg("scenario.settle_s", sc.settle_s);
        if sc.trace_every == 0 {
            v.err("scenario.trace_every", "must be ≥ 1".into());
        }
        let mut last_t = f64::NEG_INFINITY;
        for (i, e) in sc.plc_events.iter().enumerate() {
            v.nonneg(&format!("scenario.plc_events[{i}].t_s"), e.t_s);
            if e.t_s < last_t {
                v.err(
                    &format!("scenario.plc_events[{i}].t_s"),
                    "events must be in time order".into(),
                );
            }
            last_t = e.t_s;
            if e.channel >= sc.programs.len() {
                v.err(
                    &format!("scenario.plc_events[{i}].channel"),
                    format!("no channel {}", e.channel),
                );
            }
        }
        // Closed-loop stability only makes sense once the numbers themselves are sound.
        if v.errors.is_empty() {
            for a in &self.axes {
                if let Err(reason) = crate::servo::check_stability(a, self.timing.t3_s) {
                    v.err(&format!("axes[{}].servo", a.name), reason);
                }
            }
        }
        v.errors
    }

    /// Applies `path=value` overrides (`axes.z.backlash.minus_to_plus.mode=lump`). A list of named items
    /// can be indexed by its `name` field. The value is read as RON/JSON-like text; a bare
    /// word is taken as a string (enum variants such as `lump`).
    pub fn with_override(&self, path: &str, value: &str) -> Result<Preset, PresetError> {
        let oerr = |reason: String| PresetError::Override {
            path: path.to_owned(),
            reason,
        };
        let mut doc = serde_json::to_value(self).map_err(|e| oerr(e.to_string()))?;
        let mut node = &mut doc;
        for seg in path.split('.') {
            node = match node {
                serde_json::Value::Object(map) => {
                    let keys: Vec<String> = map.keys().cloned().collect();
                    map.get_mut(seg).ok_or_else(|| {
                        oerr(format!(
                            "no field '{seg}' here; fields are: {}",
                            keys.join(", ")
                        ))
                    })?
                }
                serde_json::Value::Array(items) => {
                    let idx = match seg.parse::<usize>() {
                        Ok(i) => Some(i),
                        Err(_) => items
                            .iter()
                            .position(|it| it.get("name").and_then(|n| n.as_str()) == Some(seg)),
                    };
                    let len = items.len();
                    idx.and_then(|i| items.get_mut(i))
                        .ok_or_else(|| oerr(format!("no item '{seg}' in a list of {len}")))?
                }
                _ => return Err(oerr(format!("'{seg}' goes below a plain value"))),
            };
        }
        let new_val: serde_json::Value = serde_json::from_str(value)
            .unwrap_or_else(|_| serde_json::Value::String(value.to_owned()));
        *node = new_val;
        let preset: Preset = serde_json::from_value(doc).map_err(|e| oerr(e.to_string()))?;
        let errors = preset.validate();
        if errors.is_empty() {
            Ok(preset)
        } else {
            Err(oerr(list(&errors)))
        }
    }
}

/// Loads a preset from a path, or from the embedded set when `path` is `embedded:NAME`.
pub fn load(path: &str) -> Result<LoadedPreset, PresetError> {
    if let Some(name) = path.strip_prefix("embedded:") {
        return load_embedded(name);
    }
    let text = std::fs::read_to_string(path).map_err(|source| PresetError::Io {
        file: path.to_owned(),
        source,
    })?;
    let preset = Preset::from_ron(&text, path)?;
    let dir = Path::new(path)
        .parent()
        .map(|p| {
            if p.as_os_str().is_empty() {
                PathBuf::from(".")
            } else {
                p.to_path_buf()
            }
        })
        .unwrap_or_else(|| PathBuf::from("."));
    Ok(LoadedPreset {
        preset,
        dir: Some(dir),
        origin: path.to_owned(),
    })
}

pub fn load_embedded(name: &str) -> Result<LoadedPreset, PresetError> {
    let file = format!("<embedded>/{name}");
    let text = embedded(name).ok_or_else(|| PresetError::Io {
        file: file.clone(),
        source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such embedded preset"),
    })?;
    Ok(LoadedPreset {
        preset: Preset::from_ron(text, &file)?,
        dir: None,
        origin: file,
    })
}

/// Integer ratio a/b if a is a whole multiple (≥ 1) of b, to 1e-9 relative.
pub fn ratio(a: f64, b: f64) -> Option<u32> {
    let r = a / b;
    let n = r.round();
    if (1.0..1e6).contains(&n) && (r - n).abs() <= 1e-9 * n {
        Some(n as u32)
    } else {
        None
    }
}

#[derive(Default)]
struct Validator {
    errors: Vec<FieldError>,
}

impl Validator {
    fn err(&mut self, path: &str, reason: String) {
        self.errors.push(FieldError {
            path: path.to_owned(),
            reason,
        });
    }
    fn finite(&mut self, path: &str, x: f64) -> bool {
        if x.is_finite() {
            true
        } else {
            self.err(path, format!("{x} is not a finite number"));
            false
        }
    }
    fn nonneg(&mut self, path: &str, x: f64) {
        if self.finite(path, x) && x < 0.0 {
            self.err(
                path,
                format!("{x} is negative; a physical amount must be ≥ 0"),
            );
        }
    }
    fn pos(&mut self, path: &str, x: f64) {
        if self.finite(path, x) && x <= 0.0 {
            self.err(path, format!("{x} must be > 0"));
        }
    }
    fn range(&mut self, path: &str, x: f64, lo: f64, hi: f64) {
        if self.finite(path, x) && !(lo..=hi).contains(&x) {
            self.err(path, format!("{x} is outside {lo}…{hi}"));
        }
    }
    fn temp(&mut self, path: &str, x: f64) {
        self.range(path, x, -50.0, 200.0);
    }
}
