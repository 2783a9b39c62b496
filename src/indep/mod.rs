//! Independent case generator: a second axis simulator, sharing no code with the model, that
//! writes records with known hidden effects for checking the sim-to-real diagnosis.
//!
//! `diagnose::eval` builds its cases with the project's own plant and amplifier, so the
//! diagnosis is checked against the equations it fits with. This module is written from the
//! physics instead: its own continuous-time equations ([`rig`]), its own fixed-step RK4 with
//! stick and impact events, its own discrete controller ([`control`]), command generator
//! ([`profile`]), sensors and effect shapes ([`hidden`]). It reads the nominal machine from
//! `presets/emps.ron` (data only) and writes a [`Trace`] in the TRACE_FORMAT layout. It
//! imports nothing from the servo, plant, drive, machine, nc, comp or diagnose modules
//! (a test reads these files to check).
//!
//! The true machine of every case has each nominal parameter (masses, viscous friction,
//! position and velocity gains, the drive's force constant) off by 1–5 % with a random sign,
//! so a diagnosis must calibrate before it attributes a residual. Records carry white noise
//! on position and force and the encoder's 5e-8 m grid by default; a case may log one
//! channel up to a sample early or late.
//!
//! Use [`generate`] for one case, [`standard_set`] for the check set and [`write_cases`] to
//! put cases on disk (`axisbench gen-cases`).

#![warn(missing_docs)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::preset::{Preset, PresetError};
use crate::trace::{AxisSignal, Trace, TraceError};
use crate::units::um_to_m;

pub mod control;
pub mod dice;
pub mod friction;
pub mod hidden;
mod io;
pub mod nominal;
pub mod profile;
pub mod rig;
pub mod run;
pub mod shapes;

use dice::Dice;
pub use hidden::{EFFECTS, formulas};
use run::{Logging, RunOut};

/// Why a case could not be generated or written.
#[derive(Debug, thiserror::Error)]
pub enum IndepError {
    /// The nominal preset could not be read.
    #[error(transparent)]
    Preset(#[from] PresetError),
    /// The record could not be written.
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// A file or folder could not be written.
    #[error("{path}: cannot write: {source}")]
    Io {
        /// The path written.
        path: String,
        /// Why it failed.
        source: std::io::Error,
    },
    /// A case specification out of range.
    #[error("case '{case}': {reason}")]
    Spec {
        /// Name of the case.
        case: String,
        /// What is out of range.
        reason: String,
    },
    /// The nominal preset has something the generator does not model.
    #[error("the independent generator does not model this nominal machine: {0}")]
    Unsupported(String),
    /// The simulation ran away (an unstable combination of effects).
    #[error("{0}")]
    Unstable(String),
}

/// The sensor behind the record's `pos` column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PosSensor {
    /// The motor encoder in load travel (as the EMPS records): blind to what happens
    /// between the nut and the table, i.e. lead error and thermal growth.
    MotorEncoder,
    /// A linear scale on the carriage: sees lead error and thermal growth.
    LinearScale,
}

impl PosSensor {
    /// Name used in truths and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            PosSensor::MotorEncoder => "motor_encoder",
            PosSensor::LinearScale => "scale",
        }
    }
}

/// A logged channel that can be skewed in time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SkewChannel {
    /// The set-point column.
    Cmd,
    /// The position column.
    Pos,
    /// The force column (a held value: only whole samples change it).
    Force,
}

impl SkewChannel {
    /// Name used in truths.
    pub fn name(self) -> &'static str {
        match self {
            SkewChannel::Cmd => "cmd",
            SkewChannel::Pos => "pos",
            SkewChannel::Force => "force",
        }
    }
}

/// Whether one channel is logged off its sample instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SkewPick {
    /// Every channel at t_k.
    None,
    /// A random channel, ±1 sample (60 %) or ±0.3–1 sample (40 %; whole samples for force).
    Random,
    /// This channel at t_k + samples·T3 (|samples| ≤ 1).
    Fixed(SkewChannel, f64),
}

/// Measurement noise (1σ, white).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// On the position reading before the sensor grid, µm.
    pub pos_um: f64,
    /// On the logged force, N.
    pub force_n: f64,
}

impl Default for Noise {
    fn default() -> Self {
        Noise {
            pos_um: 0.02,
            force_n: 0.2,
        }
    }
}

/// One hidden effect asked for: a name of [`EFFECTS`] and optionally one of its formulas
/// (None: drawn from the seed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EffectPick {
    /// Effect name (one of [`EFFECTS`]).
    pub name: &'static str,
    /// Formula; None: drawn from the seed.
    pub formula: Option<&'static str>,
}

impl EffectPick {
    /// Checks the names against [`EFFECTS`].
    pub fn new(name: &str, formula: Option<&str>) -> Option<EffectPick> {
        let (n, fs) = EFFECTS.iter().find(|(n, _)| *n == name)?;
        let formula = match formula {
            Some(f) => Some(*fs.iter().find(|x| **x == f)?),
            None => None,
        };
        Some(EffectPick { name: n, formula })
    }
}

/// What to generate. Everything random is drawn from `seed`.
#[derive(Debug, Clone, PartialEq)]
pub struct CaseSpec {
    /// File name of the case (no extension).
    pub name: String,
    /// Seed of every random choice of the case.
    pub seed: u64,
    /// Record length, s; None: drawn in 30–60 s.
    pub duration_s: Option<f64>,
    /// Hidden effects (none: a clean case).
    pub effects: Vec<EffectPick>,
    /// Channel skew of the log.
    pub skew: SkewPick,
    /// Sensor behind the `pos` column.
    pub pos_sensor: PosSensor,
    /// Measurement noise.
    pub noise: Noise,
    /// Whether the true machine is off the nominal by 1–5 % (true for every case of the set).
    pub nominal_offset: bool,
    /// No noise and no default sensor grids (a quantization effect still applies): for
    /// checks of the physics.
    pub ideal_sensors: bool,
    /// RK4 sub-steps per sample; None: from the fastest mechanical rate, at least 10.
    pub substeps: Option<u32>,
}

impl CaseSpec {
    /// A case with these effects and the defaults: motor encoder, default noise, nominal
    /// offset, no skew, duration drawn.
    pub fn new(name: &str, seed: u64, effects: Vec<EffectPick>) -> CaseSpec {
        CaseSpec {
            name: name.to_owned(),
            seed,
            duration_s: None,
            effects,
            skew: SkewPick::None,
            pos_sensor: PosSensor::MotorEncoder,
            noise: Noise::default(),
            nominal_offset: true,
            ideal_sensors: false,
            substeps: None,
        }
    }
}

/// How many effects a case hides.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mix {
    /// Nominal offset and noise only.
    Clean,
    /// One effect.
    Single,
    /// Two effects.
    Pair,
}

/// The kind of a case: its mix and whether a channel is skewed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CaseKind {
    /// How many effects.
    pub mix: Mix,
    /// Whether a channel is logged off its instant.
    pub skewed: bool,
}

impl CaseKind {
    /// Every kind, in the order of [`CaseKind::name`].
    pub const ALL: [CaseKind; 6] = [
        CaseKind {
            mix: Mix::Clean,
            skewed: false,
        },
        CaseKind {
            mix: Mix::Single,
            skewed: false,
        },
        CaseKind {
            mix: Mix::Pair,
            skewed: false,
        },
        CaseKind {
            mix: Mix::Clean,
            skewed: true,
        },
        CaseKind {
            mix: Mix::Single,
            skewed: true,
        },
        CaseKind {
            mix: Mix::Pair,
            skewed: true,
        },
    ];

    /// `clean`, `single`, `pair`, with `_skew` when a channel is skewed.
    pub fn name(self) -> &'static str {
        match (self.mix, self.skewed) {
            (Mix::Clean, false) => "clean",
            (Mix::Single, false) => "single",
            (Mix::Pair, false) => "pair",
            (Mix::Clean, true) => "clean_skew",
            (Mix::Single, true) => "single_skew",
            (Mix::Pair, true) => "pair_skew",
        }
    }

    /// The kind named `name` (see [`CaseKind::name`]).
    pub fn from_name(name: &str) -> Option<CaseKind> {
        CaseKind::ALL.into_iter().find(|k| k.name() == name)
    }

    /// The kind of a specification.
    pub fn of(spec: &CaseSpec) -> CaseKind {
        CaseKind {
            mix: match spec.effects.len() {
                0 => Mix::Clean,
                1 => Mix::Single,
                _ => Mix::Pair,
            },
            skewed: spec.skew != SkewPick::None,
        }
    }
}

/// One hidden effect as generated.
#[derive(Debug, Clone, PartialEq)]
pub struct TrueEffect {
    /// One of the diagnosis's effect names.
    pub name: &'static str,
    /// Which of the effect's formulas ([`EFFECTS`]).
    pub formula: &'static str,
    /// Its parameters, the unit in each key.
    pub params: BTreeMap<String, f64>,
}

/// What the diagnosis should find.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// The hidden effects, as drawn.
    pub effects: Vec<TrueEffect>,
    /// How far the skewed channel is logged late (+) or early (−), samples; 0: none.
    pub skew_samples: f64,
    /// `none`, `cmd`, `pos` or `force`.
    pub skew_channel: &'static str,
    /// `motor_encoder` or `scale`.
    pub pos_sensor: &'static str,
    /// True/nominal ratio of each offset nominal parameter.
    pub nominal_scale: BTreeMap<String, f64>,
    /// Record length, s.
    pub duration_s: f64,
}

/// A generated case.
#[derive(Debug, Clone)]
pub struct Case {
    /// Case name (file stem on disk).
    pub name: String,
    /// The record (`t[s]`, `x.cmd[mm]`, `x.pos[mm]`, `x.force[N]`).
    pub trace: Trace,
    /// The nominal preset the diagnosis receives.
    pub preset: Preset,
    /// What the record hides.
    pub truth: Truth,
    /// Clean, single or pair, skewed or not.
    pub kind: CaseKind,
    /// The seed it was generated from.
    pub seed: u64,
    /// The true signals behind the record (for inspection and tests).
    pub signals: RunOut,
}

/// Longest record, s.
const MAX_DURATION_S: f64 = 3600.0;
/// Shortest record, s.
const MIN_DURATION_S: f64 = 1.0;
/// Most sub-steps per sample.
const MAX_SUBSTEPS: u32 = 1000;
/// Largest position noise, µm.
const MAX_POS_NOISE_UM: f64 = 10.0;
/// Largest force noise, N.
const MAX_FORCE_NOISE_N: f64 = 50.0;

/// Checks a specification's numbers and effects.
fn check(spec: &CaseSpec) -> Result<(), IndepError> {
    let bad = |reason: String| IndepError::Spec {
        case: spec.name.clone(),
        reason,
    };
    if let Some(d) = spec.duration_s
        && !(d.is_finite() && (MIN_DURATION_S..=MAX_DURATION_S).contains(&d))
    {
        return Err(bad(format!(
            "duration {d} s is outside {MIN_DURATION_S}…{MAX_DURATION_S} s"
        )));
    }
    let n = &spec.noise;
    if !(n.pos_um.is_finite() && (0.0..=MAX_POS_NOISE_UM).contains(&n.pos_um)) {
        return Err(bad(format!(
            "position noise {} µm is outside 0…{MAX_POS_NOISE_UM} µm",
            n.pos_um
        )));
    }
    if !(n.force_n.is_finite() && (0.0..=MAX_FORCE_NOISE_N).contains(&n.force_n)) {
        return Err(bad(format!(
            "force noise {} N is outside 0…{MAX_FORCE_NOISE_N} N",
            n.force_n
        )));
    }
    if let Some(s) = spec.substeps
        && !(1..=MAX_SUBSTEPS).contains(&s)
    {
        return Err(bad(format!("{s} sub-steps is outside 1…{MAX_SUBSTEPS}")));
    }
    if let SkewPick::Fixed(_, s) = spec.skew
        && !(s.is_finite() && s.abs() <= 1.0)
    {
        return Err(bad(format!("skew {s} samples is outside −1…1")));
    }
    for (i, e) in spec.effects.iter().enumerate() {
        if formulas(e.name).is_none() {
            return Err(bad(format!("unknown effect '{}'", e.name)));
        }
        if spec.effects[..i].iter().any(|o| o.name == e.name) {
            return Err(bad(format!("effect '{}' twice", e.name)));
        }
    }
    let names: Vec<&str> = spec.effects.iter().map(|e| e.name).collect();
    if names.contains(&"backlash") && names.contains(&"backlash_asymmetry") {
        return Err(bad(
            "backlash and backlash_asymmetry both set the screw link".into(),
        ));
    }
    Ok(())
}

/// Skew actually used: channel and samples.
fn resolve_skew(pick: SkewPick, dice: &mut Dice) -> Option<(SkewChannel, f64)> {
    match pick {
        SkewPick::None => None,
        SkewPick::Fixed(c, s) => Some((c, s)),
        SkewPick::Random => {
            let chan = [SkewChannel::Cmd, SkewChannel::Pos, SkewChannel::Force][dice.index(3)];
            let whole = chan == SkewChannel::Force || dice.chance(0.6);
            let mag = if whole { 1.0 } else { dice.between(0.3, 1.0) };
            Some((chan, dice.sign() * mag))
        }
    }
}

/// RK4 sub-steps for a machine: ω·h ≤ 0.3 for its fastest rate, at least 10 per sample.
fn auto_substeps(rate_per_s: f64, t3_s: f64) -> u32 {
    ((rate_per_s * t3_s / 0.3).ceil() as u32).clamp(10, 200)
}

/// Generates one case. Deterministic in `spec.seed`: the same spec gives a bit-identical
/// trace.
pub fn generate(spec: &CaseSpec) -> Result<Case, IndepError> {
    generate_corrected(spec, None)
}

/// [`generate`] with a compensation fed into the true machine: the same machine, command
/// and noise as the uncorrected case of the same spec, so the two records differ by what
/// the correction does. `corr` is per row of the record.
pub fn generate_corrected(
    spec: &CaseSpec,
    corr: Option<&run::Correction>,
) -> Result<Case, IndepError> {
    check(spec)?;
    let preset = nominal::nominal_preset(spec.pos_sensor)?;
    let mut m = nominal::exact_machine(&preset, spec.pos_sensor)?;
    let duration_s = spec
        .duration_s
        .unwrap_or_else(|| Dice::new(spec.seed, "duration").between(30.0, 60.0));
    let nominal_scale = if spec.nominal_offset {
        nominal::offset_nominal(&mut m, &mut Dice::new(spec.seed, "nominal"))
    } else {
        BTreeMap::new()
    };
    if spec.ideal_sensors {
        m.encoder = control::Grid::EXACT;
        m.scale = control::Grid::EXACT;
    }
    let profile = profile::Profile::random(&mut Dice::new(spec.seed, "command"), duration_s);
    let ctx = hidden::Context {
        duration_s,
        nominal_viscous_n_s_per_m: m.rig.friction.viscous_n_s_per_m,
    };
    let mut effects = Vec::new();
    for pick in &spec.effects {
        let mut dice = Dice::new(spec.seed, &format!("effect.{}", pick.name));
        let fs = formulas(pick.name).unwrap_or(&[]);
        let formula = pick.formula.unwrap_or_else(|| fs[dice.index(fs.len())]);
        effects.push(hidden::hide(pick.name, formula, &mut dice, &mut m, &ctx));
    }
    m.substeps = spec
        .substeps
        .unwrap_or_else(|| auto_substeps(m.rig.fastest_rate_per_s(), m.gains.t3_s));
    let skew = resolve_skew(spec.skew, &mut Dice::new(spec.seed, "skew"));
    let noise = if spec.ideal_sensors {
        Noise {
            pos_um: 0.0,
            force_n: 0.0,
        }
    } else {
        spec.noise
    };
    let log = Logging {
        pos_noise_m: um_to_m(noise.pos_um),
        force_noise_n: noise.force_n,
        skew,
        seed: spec.seed,
    };
    let rows = (duration_s / m.gains.t3_s).round() as usize;
    let signals = run::run(&m, &profile, rows, &log, corr)?;
    for e in &mut effects {
        if e.name == "thermal_growth" {
            e.params
                .insert("strain_per_heat_unit".into(), signals.heat_gain);
        }
    }
    let axis = preset
        .axes
        .first()
        .map_or("x".to_owned(), |a| a.name.clone());
    let trace = to_trace(&signals, &axis, spec);
    Ok(Case {
        name: spec.name.clone(),
        trace,
        truth: Truth {
            effects,
            skew_samples: skew.map_or(0.0, |s| s.1),
            skew_channel: skew.map_or("none", |s| s.0.name()),
            pos_sensor: spec.pos_sensor.name(),
            nominal_scale,
            duration_s,
        },
        kind: CaseKind::of(spec),
        seed: spec.seed,
        preset,
        signals,
    })
}

/// The logged record as a trace (SI in memory like every trace; written through
/// [`Trace::write_csv`] in mm, s, N). The metadata says what the record is, never what it
/// hides.
fn to_trace(s: &RunOut, axis: &str, spec: &CaseSpec) -> Trace {
    let mut tr = Trace::new();
    tr.meta = vec![
        ("source".into(), "axisbench indep generator".into()),
        ("case".into(), spec.name.clone()),
        ("seed".into(), spec.seed.to_string()),
        ("preset".into(), "presets/emps.ron (nominal)".into()),
        ("pos_source".into(), spec.pos_sensor.name().into()),
    ];
    let mut add = |sig: AxisSignal, data: &[f64]| {
        let i = tr.add_signal(&sig.column(axis), sig.si_unit());
        tr.signals[i].data = data.to_vec();
    };
    add(AxisSignal::Cmd, &s.cmd_m);
    add(AxisSignal::Pos, &s.pos_m);
    add(AxisSignal::Force, &s.force_n);
    tr.signals[0].data = s.t_s.clone();
    tr
}

/// Cases per effect kind in [`standard_set`].
const SINGLES_PER_EFFECT: usize = 4;
/// Clean cases in [`standard_set`].
const CLEAN_CASES: usize = 12;
/// Two-effect cases in [`standard_set`].
const PAIR_CASES: usize = 12;

/// Effects that a motor encoder cannot see; their cases log the linear scale.
fn needs_scale(names: &[&str]) -> bool {
    names
        .iter()
        .any(|n| matches!(*n, "lead_error" | "thermal_growth"))
}

/// Seconds of motion per case of the standard set, unless asked otherwise: `gen-cases` and
/// `diagnose-eval` share it, so both see the same records of a seed.
pub const STANDARD_DURATION_S: f64 = 24.0;

/// The check set: 12 clean cases (a third on the scale), 4 single cases per effect kind
/// (formulas in turn; lead error and thermal growth on the scale, quantization on both),
/// 12 two-effect cases, and each again with a random channel skew (same seed, name
/// suffixed `_skew`). Names are neutral (`case_` and a number): the truth is in [`Case::truth`].
pub fn standard_set(seed: u64, duration_s: f64) -> Vec<CaseSpec> {
    let mut plain: Vec<CaseSpec> = Vec::new();
    let case_seed = |i: usize| seed.wrapping_mul(1_000_003).wrapping_add(i as u64);
    let mut push = |effects: Vec<EffectPick>, sensor: PosSensor| {
        let i = plain.len();
        let mut s = CaseSpec::new(&format!("case_{i:03}"), case_seed(i), effects);
        s.duration_s = Some(duration_s);
        s.pos_sensor = sensor;
        plain.push(s);
    };
    for i in 0..CLEAN_CASES {
        let sensor = if i % 3 == 2 {
            PosSensor::LinearScale
        } else {
            PosSensor::MotorEncoder
        };
        push(vec![], sensor);
    }
    for (name, fs) in EFFECTS {
        for j in 0..SINGLES_PER_EFFECT {
            let sensor = if needs_scale(&[name]) || (*name == "quantization" && j % 2 == 1) {
                PosSensor::LinearScale
            } else {
                PosSensor::MotorEncoder
            };
            push(
                vec![EffectPick {
                    name,
                    formula: Some(fs[j % fs.len()]),
                }],
                sensor,
            );
        }
    }
    let mut dice = Dice::new(seed, "standard_set.pairs");
    let mut pairs = 0;
    while pairs < PAIR_CASES {
        let a = EFFECTS[dice.index(EFFECTS.len())].0;
        let b = EFFECTS[dice.index(EFFECTS.len())].0;
        if a == b || (a.starts_with("backlash") && b.starts_with("backlash")) {
            continue;
        }
        let sensor = if needs_scale(&[a, b]) {
            PosSensor::LinearScale
        } else {
            PosSensor::MotorEncoder
        };
        let pick = |n| EffectPick {
            name: n,
            formula: None,
        };
        push(vec![pick(a), pick(b)], sensor);
        pairs += 1;
    }
    let skewed: Vec<CaseSpec> = plain
        .iter()
        .map(|s| CaseSpec {
            name: format!("{}_skew", s.name),
            skew: SkewPick::Random,
            ..s.clone()
        })
        .collect();
    plain.extend(skewed);
    plain
}

/// Generates each case of `specs` and writes it as `DIR/<name>.csv` (the record) and
/// `DIR/<name>.ron` (the nominal preset), and all truths as `DIR/truth.json`; creates DIR.
/// All or nothing: a failed case or a failed write leaves DIR as it was. One case is in
/// memory at a time; `progress(i, name)` is called as case `i` starts. Returns the files
/// written.
pub fn write_cases(
    dir: &Path,
    specs: &[CaseSpec],
    progress: &mut dyn FnMut(usize, &str),
) -> Result<Vec<PathBuf>, IndepError> {
    io::write_cases(dir, specs, progress)
}
