//! Presets: the whole machine and scenario as one RON document.
//!
//! A preset is what a service engineer saves and reloads, so it uses the units an engineer
//! reads off a data sheet (mm, µm, kg, N, degC, with the unit in every field name). The model
//! converts to SI once, when it is built ([`crate::machine::Machine::new`]).
//!
//! Loading is strict: unknown fields are rejected (`deny_unknown_fields`) so that a typo in a
//! hand-edited file is an error, not a silently ignored setting, and every file carries a
//! `version` so that old files can be migrated instead of misread.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub mod axis;
pub mod comp;
pub mod fields;
pub mod rules;

pub use fields::Fields;

pub use axis::*;

/// The preset format version this build reads and writes.
pub const PRESET_VERSION: u32 = 1;

/// Every preset and program shipped in `presets/`, embedded so the binary runs anywhere.
pub const EMBEDDED: &[(&str, &str)] = &[
    ("default.ron", include_str!("../../presets/default.ron")),
    ("default.ngc", include_str!("../../presets/default.ngc")),
    (
        "vertical_z_gravity.ron",
        include_str!("../../presets/vertical_z_gravity.ron"),
    ),
    (
        "vertical_z_gravity.ngc",
        include_str!("../../presets/vertical_z_gravity.ngc"),
    ),
    (
        "short_stroke_quadrant.ron",
        include_str!("../../presets/short_stroke_quadrant.ron"),
    ),
    (
        "short_stroke_quadrant.ngc",
        include_str!("../../presets/short_stroke_quadrant.ngc"),
    ),
    (
        "thermal_warmup.ron",
        include_str!("../../presets/thermal_warmup.ron"),
    ),
    (
        "thermal_warmup.ngc",
        include_str!("../../presets/thermal_warmup.ngc"),
    ),
    (
        "thermal_warmup_slow.ngc",
        include_str!("../../presets/thermal_warmup_slow.ngc"),
    ),
    (
        "vertical_lathe_crossbeam.ron",
        include_str!("../../presets/vertical_lathe_crossbeam.ron"),
    ),
    (
        "vertical_lathe_left.ngc",
        include_str!("../../presets/vertical_lathe_left.ngc"),
    ),
    (
        "vertical_lathe_right.ngc",
        include_str!("../../presets/vertical_lathe_right.ngc"),
    ),
    (
        "vertical_lathe_right_traverse.ngc",
        include_str!("../../presets/vertical_lathe_right_traverse.ngc"),
    ),
    ("xy_circle.ron", include_str!("../../presets/xy_circle.ron")),
    ("xy_circle.ngc", include_str!("../../presets/xy_circle.ngc")),
    ("emps.ron", include_str!("../../presets/emps.ron")),
    ("emps.ngc", include_str!("../../presets/emps.ngc")),
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

/// One machine (control periods, NC, axes, structure, compensations) and the scenario it runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Preset {
    /// Format version of the file; must equal [`PRESET_VERSION`].
    pub version: u32,
    /// Display name of the machine/scenario.
    pub name: String,
    /// Free text for the user: what the preset shows and how to use it.
    #[serde(default)]
    pub description: String,
    /// Control periods T1, T2, T3.
    pub timing: Timing,
    /// NC settings shared by all channels: initial mode, acc/dec, feeds.
    pub nc: NcParams,
    /// The feed axes, 1 to [`rules::MAX_AXES`]; names unique, letters unique per channel.
    pub axes: Vec<AxisParams>,
    /// Vertical-lathe crossbeam whose sag moves the tool posts' Z (off by default).
    #[serde(default)]
    pub crossbeam: Crossbeam,
    /// Cross (sag) compensation tables (cross-table patent, SPEC §6).
    #[serde(default)]
    pub cross: Vec<comp::CrossTable>,
    /// Programs, run length, PLC events and trace decimation.
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
    /// True when nothing is set, so the section is left out of a saved preset.
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

/// NC processing mode (processing-mode patent, SPEC §3), switchable at run time by G05P4/G05P0 or a
/// PLC event.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Parse → interpolate at T1 → acc/dec → position command at T2 → amplifier subdivides.
    #[default]
    Normal,
    /// Program blocks are already-interpolated T3 samples (processing-mode patent, SPEC §3, G05P4).
    Direct,
}

impl Mode {
    /// The mode as the trace's `mode` column shows it (0 normal, 1 direct).
    pub fn as_f64(self) -> f64 {
        match self {
            Mode::Normal => 0.0,
            Mode::Direct => 1.0,
        }
    }
}

/// NC settings: processing mode at power-on/reset, acc/dec and default feeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NcParams {
    /// Processing mode at power-on/reset (the seed's initial-mode parameter).
    #[serde(default)]
    pub initial_mode: Mode,
    /// Acc/dec after interpolation, applied to every axis.
    pub accdec: AccDec,
    /// Feed used for G00, mm/min.
    pub rapid_mm_per_min: f64,
    /// Feed used by G01/G02/G03 before the program sets F, mm/min.
    #[serde(default = "default_feed")]
    pub default_feed_mm_per_min: f64,
}

fn default_feed() -> f64 {
    1000.0
}

/// Shape of the acc/dec after interpolation.
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
    /// None, linear (one stage) or bell (two stages).
    pub kind: AccDecKind,
    /// Time constant of the first moving-average stage, s (0–10); the acceleration time.
    pub tc1_s: f64,
    /// Time constant of the second stage (bell only), s (0–10); rounds the velocity corners.
    #[serde(default)]
    pub tc2_s: f64,
}

/// Crossbeam of a vertical lathe: a simply supported beam along X carrying one or two tool
/// posts, each with its own vertical (Z) axis. The beam deflection at a post moves that
/// post's tool tip in −Z.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Crossbeam {
    /// Whether the beam sag is simulated.
    pub enabled: bool,
    /// Span between the two column supports; X = 0 is the left support.
    pub span_mm: f64,
    /// Young's modulus of the beam material, GPa (steel ≈ 210).
    pub youngs_modulus_gpa: f64,
    /// Second moment of area of the beam section, cm⁴.
    pub area_moment_cm4: f64,
    /// Beam self-weight per length, N/m.
    pub self_weight_n_per_m: f64,
    /// The one or two tool posts hanging on the beam.
    pub posts: Vec<ToolPost>,
}

impl Default for Crossbeam {
    /// Switched off, with the numbers of a 4 m steel box beam, so that switching it on
    /// starts from a real beam rather than from zeros.
    fn default() -> Self {
        Crossbeam {
            enabled: false,
            span_mm: 4000.0,
            youngs_modulus_gpa: 210.0,
            area_moment_cm4: 200_000.0,
            self_weight_n_per_m: 3000.0,
            posts: vec![],
        }
    }
}

/// A tool post on the crossbeam: its load bends the beam, which lowers its ram's tool tip.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToolPost {
    /// Axis that moves the post along the beam.
    pub x_axis: String,
    /// The post's vertical ram axis, which the sag displaces.
    pub z_axis: String,
    /// Weight of the post acting on the beam at its X position, N.
    pub weight_n: f64,
}

/// What the machine runs: programs, run length, PLC events, trace decimation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// One program per NC channel, as file names relative to the preset file.
    pub programs: Vec<String>,
    /// Fixed run length. None: run the program to its end, then `settle_s`.
    #[serde(default)]
    pub duration_s: Option<f64>,
    /// Extra run time after the programs end and acc/dec has drained, s, so the axes settle.
    #[serde(default = "default_settle")]
    pub settle_s: f64,
    /// PLC mode-switch requests at set times (processing-mode patent, SPEC §3).
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

/// A PLC request to switch a channel's processing mode at a set time (processing-mode patent, SPEC
/// §3).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlcEvent {
    /// Machine time of the request, s; events must be in time order.
    pub t_s: f64,
    /// Mode requested; it takes effect at the next block boundary once acc/dec has drained.
    pub mode: Mode,
    /// NC channel (index into `scenario.programs`) the request goes to.
    #[serde(default)]
    pub channel: usize,
}

/// One validation finding: which field, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldError {
    /// Dotted field path, as `--set` takes it, e.g. `axes.x.servo.kp_per_s`.
    pub path: String,
    /// What is wrong, with the offending value and the allowed range or rule.
    pub reason: String,
}

impl std::fmt::Display for FieldError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path, self.reason)
    }
}

/// Why a preset could not be read, checked, edited or written.
#[derive(Debug, thiserror::Error)]
pub enum PresetError {
    /// The preset or one of its program files could not be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// Path (or `<embedded>/NAME`) of the file.
        file: String,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// The preset and its programs could not be written (none of them was); the error
    /// names the step and the path.
    #[error(transparent)]
    Write(#[from] crate::fsutil::FsError),
    /// The text is not valid RON for a preset (including unknown fields).
    #[error("{file}:{line}:{col}: {msg}")]
    Syntax {
        /// Source named in the message.
        file: String,
        /// Line of the error, as the RON parser reports it.
        line: usize,
        /// Column of the error, as the RON parser reports it.
        col: usize,
        /// The parser's message.
        msg: String,
    },
    /// Parsed, but fields are out of range or break a rule between fields.
    #[error("{file}: invalid preset:\n{}", list(.errors))]
    Invalid {
        /// Source named in the message.
        file: String,
        /// Every finding, not just the first.
        errors: Vec<FieldError>,
    },
    /// The file's `version` is not [`PRESET_VERSION`].
    #[error(
        "{file}: preset version {found} is not supported (this build reads version {PRESET_VERSION})"
    )]
    Version {
        /// Source named in the message.
        file: String,
        /// The version the file declares.
        found: u32,
    },
    /// A `--set PATH=VALUE` override names no field, does not parse, or leaves the preset invalid.
    #[error("--set {path}: {reason}")]
    Override {
        /// The field path given.
        path: String,
        /// Why it was refused.
        reason: String,
    },
    /// RON serialization failed (message of the serializer).
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
    /// The parsed and validated preset.
    pub preset: Preset,
    /// Folder of the preset file; None for an embedded preset.
    pub dir: Option<PathBuf>,
    /// Where it was loaded from, for display: the path given or `<embedded>/NAME`.
    pub origin: String,
}

impl LoadedPreset {
    /// Every program of the scenario as (name, text), one per channel.
    pub fn programs(&self) -> Result<Vec<(String, String)>, PresetError> {
        self.preset
            .scenario
            .programs
            .iter()
            .map(|p| Ok((p.clone(), self.program_text(p)?)))
            .collect()
    }

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

    /// Which compensations are switched on, in one fixed order: backlash, thermal and
    /// quadrant of each axis, then whether any cross table is.
    pub fn enabled_comps(&self) -> Vec<bool> {
        self.axes
            .iter()
            .flat_map(|a| [a.backlash.enabled, a.thermal.enabled, a.quadrant.enabled])
            .chain([self.cross.iter().any(|t| t.enabled)])
            .collect()
    }

    /// The same machine with every compensation switched off: the one definition of
    /// "uncompensated" that measuring cycles, comparisons and exports share.
    pub fn compensations_off(&self) -> Preset {
        let mut q = self.clone();
        for a in &mut q.axes {
            a.backlash.enabled = false;
            a.quadrant.enabled = false;
            a.thermal.enabled = false;
        }
        for t in &mut q.cross {
            t.enabled = false;
        }
        q
    }

    /// Writes the preset to `path` and its programs (name, text) next to it, all or
    /// nothing: a preset names its programs relative to itself, so they travel together.
    pub fn save_with_programs(
        &self,
        path: &std::path::Path,
        programs: &[(String, String)],
    ) -> Result<(), PresetError> {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .ok_or_else(|| crate::fsutil::FsError {
                op: "write",
                path: path.to_path_buf(),
                reason: "not a file name".into(),
                kind: std::io::ErrorKind::InvalidInput,
            })?;
        let mut files = vec![(name, self.to_ron()?.into_bytes())];
        files.extend(
            programs
                .iter()
                .map(|(n, text)| (n.clone(), text.clone().into_bytes())),
        );
        crate::fsutil::write_all_atomic(&dir, &files)?;
        Ok(())
    }

    /// Serializes to the RON preset format.
    pub fn to_ron(&self) -> Result<String, PresetError> {
        let cfg = ron::ser::PrettyConfig::new()
            .depth_limit(8)
            .struct_names(false);
        ron::ser::to_string_pretty(self, cfg).map_err(|e| PresetError::Serialize(e.to_string()))
    }

    /// Checks every field against its physical range and every rule between fields;
    /// returns all findings, not just the first. This is the data check: the closed-loop
    /// stability, which needs the model, is added by [`crate::machine::check`].
    pub fn validate(&self) -> Vec<FieldError> {
        self.check("")
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

/// Loads one of the presets built into the binary ([`EMBEDDED`]) by its file name.
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
