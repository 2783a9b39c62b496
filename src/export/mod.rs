//! Export of a tuned preset to controllers, and import back.
//!
//! Every target builds ONE list of entries ([`entry::Entry`]: the preset field in the dot
//! dialect, its value with unit, the controller lines it becomes, how faithfully); the
//! files and the mapping report are both rendered from that list, so they cannot disagree.
//!
//! An export renders every file in memory and checks it: the target's own limits, the
//! physical ranges our import enforces ([`ranges`]), and — for LinuxCNC and RON — the
//! rendered files read back by our own importer (an export the import would reject is
//! refused, naming the preset field, its value and why). Only then are the approximations
//! simulated for the report, and only when all of that succeeded are the files written,
//! all together or not at all ([`crate::fsutil::write_all_atomic`]). A preset that breaks
//! a rule gives one error listing every violation, and nothing is written.
//!
//! Targets: [`Target::Ron`] (axisbench's own format, lossless), [`linuxcnc`] (LinuxCNC 2.9
//! INI + comp files), [`siemens`] (SINUMERIK 840D sl machine/setting data and CEC tables),
//! [`heidenhain`] (`.COM` compensation table), [`beckhoff`] (TwinCAT CNC / ISG compensation
//! lists), [`fanuc`] (parameter list). Each module cites the documents its rules come from.
//!
//! What every target shares is derived here, once: the axis limits a controller needs
//! (velocity, acceleration, following-error limits), the travel a position table must
//! cover, and the pitch-error table that cancels the preset's measured lead error.
#![warn(missing_docs)]

pub mod beckhoff;
pub mod entry;
pub mod fanuc;
pub mod heidenhain;
pub mod import;
pub mod linuxcnc;
pub mod ranges;
pub mod report;
mod shared;
pub mod siemens;
mod tables;

use std::path::{Path, PathBuf};

use crate::preset::{AccDecKind, AxisParams, Preset};
use crate::units::mm_to_m;

pub use entry::{Entry, Put, Status};
pub use report::{ErrFigures, Report};
pub use tables::{PitchTable, equidistant, lead_error_um, pitch_table, residual_um};

use entry::{FileSpec, Plan, RenderedFile, dot_path};
use report::Pending;

/// Where an export goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Target {
    /// axisbench's own RON preset (lossless).
    Ron,
    /// LinuxCNC 2.9 INI + comp files.
    Linuxcnc,
    /// Siemens SINUMERIK 840D sl.
    Siemens,
    /// HEIDENHAIN TNC.
    Heidenhain,
    /// Beckhoff TwinCAT CNC (ISG kernel).
    Beckhoff,
    /// FANUC Series 0i/30i.
    Fanuc,
}

impl Target {
    /// Every target, in the order the command line lists them.
    pub const ALL: [Target; 6] = [
        Target::Ron,
        Target::Linuxcnc,
        Target::Siemens,
        Target::Heidenhain,
        Target::Beckhoff,
        Target::Fanuc,
    ];

    /// The name used on the command line (`--to NAME`).
    pub fn name(self) -> &'static str {
        match self {
            Target::Ron => "ron",
            Target::Linuxcnc => "linuxcnc",
            Target::Siemens => "siemens",
            Target::Heidenhain => "heidenhain",
            Target::Beckhoff => "beckhoff",
            Target::Fanuc => "fanuc",
        }
    }

    /// The controller, as a report names it.
    pub fn title(self) -> &'static str {
        match self {
            Target::Ron => "axisbench RON preset",
            Target::Linuxcnc => "LinuxCNC 2.9",
            Target::Siemens => "Siemens SINUMERIK 840D sl",
            Target::Heidenhain => "HEIDENHAIN TNC",
            Target::Beckhoff => "Beckhoff TwinCAT CNC (ISG kernel)",
            Target::Fanuc => "FANUC Series 0i/30i",
        }
    }
}

impl std::str::FromStr for Target {
    type Err = String;
    fn from_str(s: &str) -> Result<Target, String> {
        Target::ALL
            .into_iter()
            .find(|t| t.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| {
                format!(
                    "unknown target '{s}'; targets are: {}",
                    Target::ALL.map(|t| t.name()).join(", ")
                )
            })
    }
}

/// One broken rule: where (preset field in the dot dialect, or file and line) and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Violation {
    /// The preset field (`axes.x.lead_error.table`) or file location (`joint0.comp:3`).
    pub location: String,
    /// What is wrong, with the value and the rule it breaks.
    pub reason: String,
}

impl Violation {
    /// A violation at `location`.
    pub fn new(location: impl Into<String>, reason: impl Into<String>) -> Violation {
        Violation {
            location: location.into(),
            reason: reason.into(),
        }
    }
}

impl std::fmt::Display for Violation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.location, self.reason)
    }
}

/// At most this many violations are listed one by one; a broken file can have hundreds of
/// the same finding.
const LISTED: usize = 40;

fn list(v: &[Violation]) -> String {
    let mut lines: Vec<String> = v.iter().take(LISTED).map(|e| format!("  - {e}")).collect();
    if v.len() > LISTED {
        lines.push(format!("  … and {} more", v.len() - LISTED));
    }
    lines.join("\n")
}

/// Why an export or import failed. Each variant prints its whole message once (no error
/// source is chained, so no OS text is repeated).
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The preset breaks the target's limits, the physical ranges, or our own import.
    #[error("the preset cannot be exported to {target}; nothing was written. {} violation(s):\n{}", .violations.len(), list(.violations))]
    Violations {
        /// The controller.
        target: String,
        /// Every broken rule.
        violations: Vec<Violation>,
    },
    /// An input that is wrong as a whole (not a folder with the expected file, a bad option).
    #[error("{file}: {reason}")]
    Input {
        /// The file or option.
        file: String,
        /// What is wrong.
        reason: String,
    },
    /// An imported file with problems, every one listed.
    #[error("{}: {} problem(s):\n{}", .file, .violations.len(), list(.violations))]
    Import {
        /// The file imported.
        file: String,
        /// Every problem, by file, section/key or line.
        violations: Vec<Violation>,
    },
    /// A RON file that is not a valid preset; the message names the file, line or field.
    #[error("{0}")]
    Preset(String),
    /// A file could not be read.
    #[error("cannot read {file}: {reason}")]
    Read {
        /// The file.
        file: String,
        /// The OS's reason.
        reason: String,
    },
    /// Writing failed; the folder was left as it was.
    #[error("{0}; nothing was changed in the folder")]
    Write(crate::fsutil::FsError),
    /// The report's simulation could not run.
    #[error("simulation for the mapping report failed: {0}")]
    Simulation(String),
}

/// Options of an export.
#[derive(Debug, Clone, Default)]
pub struct ExportOptions {
    /// Machine time the report's simulations cover (default: the scenario, at most
    /// [`DEFAULT_HORIZON_S`]).
    pub horizon_s: Option<f64>,
}

/// The report's simulations stop here unless asked otherwise, so an export takes seconds.
pub const DEFAULT_HORIZON_S: f64 = 60.0;

/// Everything an export produces, in memory, before anything is written.
#[derive(Debug, Clone)]
pub struct Export {
    /// The controller.
    pub target: Target,
    /// (file name relative to the output folder, contents).
    pub files: Vec<(String, String)>,
    /// The mapping report, from the same entries as the files.
    pub report: Report,
}

/// Renders, checks and simulates an export of `preset` (with its scenario programs as
/// `(file name, text)`), without writing anything.
pub fn export(
    preset: &Preset,
    programs: &[(String, String)],
    target: Target,
    opts: &ExportOptions,
) -> Result<Export, ExportError> {
    let refuse = |violations: Vec<Violation>| ExportError::Violations {
        target: target.title().into(),
        violations,
    };
    let mut violations: Vec<Violation> = crate::machine::check(preset)
        .into_iter()
        .map(|e| Violation::new(dot_path(&e.path), e.reason))
        .collect();
    if !violations.is_empty() {
        // Target limits are still checked on what can be checked, so the user sees every
        // problem at once.
        let ctx = Ctx::new(preset, None);
        if let Err(v) = plan(&ctx, target, programs) {
            violations.extend(v);
        }
        return Err(refuse(violations));
    }
    let sim = report::Sim::new(preset, programs, opts.horizon_s)?;
    let ctx = Ctx::new(preset, Some(&sim));
    let (plan, files) = checked_plan(&ctx, target, programs).map_err(refuse)?;
    let names = files.iter().map(|f| f.name.clone()).collect();
    let report = report::finish(&ctx, &sim, target, plan.entries, names)?;
    Ok(Export {
        target,
        files: files.into_iter().map(|f| (f.name, f.text)).collect(),
        report,
    })
}

/// The plan and its rendered files, or every violation: the target's limits, the physical
/// ranges, and what our own import says about the rendered files.
fn checked_plan(
    ctx: &Ctx,
    target: Target,
    programs: &[(String, String)],
) -> Result<(Plan, Vec<RenderedFile>), Vec<Violation>> {
    let ranges = if target == Target::Ron {
        Vec::new()
    } else {
        ranges::check_export(ctx)
    };
    let plan = match plan(ctx, target, programs) {
        Ok(p) if ranges.is_empty() => p,
        Ok(_) => return Err(ranges),
        Err(mut v) => {
            v.extend(ranges);
            return Err(v);
        }
    };
    let files = plan.render()?;
    let back = match target {
        Target::Linuxcnc => linuxcnc::self_check(ctx, &files, &plan.entries),
        Target::Ron => ron_self_check(ctx.preset, &files),
        _ => Vec::new(),
    };
    if back.is_empty() {
        Ok((plan, files))
    } else {
        Err(back)
    }
}

/// The target's plan: its files' layout and its one list of entries.
fn plan(ctx: &Ctx, target: Target, programs: &[(String, String)]) -> Result<Plan, Vec<Violation>> {
    match target {
        Target::Ron => ron_plan(ctx.preset, programs),
        Target::Linuxcnc => linuxcnc::render(ctx),
        Target::Siemens => siemens::render(ctx),
        Target::Heidenhain => heidenhain::render(ctx),
        Target::Beckhoff => beckhoff::render(ctx),
        Target::Fanuc => fanuc::render(ctx),
    }
}

/// The RON target: the preset itself (f64 written shortest-round-trip, so lossless) and its
/// programs, so the folder loads on its own.
fn ron_plan(p: &Preset, programs: &[(String, String)]) -> Result<Plan, Vec<Violation>> {
    let ron = p
        .to_ron()
        .map_err(|e| vec![Violation::new("preset", e.to_string())])?;
    let mut files = vec![FileSpec::new("preset.ron", "", "").raw().always()];
    let mut entries = vec![
        Pending::mapped("(the whole preset)", format!("preset '{}'", p.name))
            .note("lossless: every field, f64 in shortest round-trip form")
            .put(Put::new("preset.ron", "", "", ron)),
    ];
    for (k, (name, text)) in programs.iter().enumerate() {
        files.push(FileSpec::new(name.clone(), "", "").raw().always());
        entries.push(
            Pending::mapped(format!("scenario.programs.{k}"), name.clone())
                .note("the program file, as it is")
                .put(Put::new(name.clone(), "", "", text.clone())),
        );
    }
    Ok(Plan { files, entries })
}

/// The rendered `preset.ron` read back as the RON import reads it: it must load, pass
/// every check and equal the preset.
fn ron_self_check(p: &Preset, files: &[RenderedFile]) -> Vec<Violation> {
    let Some(f) = files.iter().find(|f| f.name == "preset.ron") else {
        return vec![Violation::new("preset.ron", "internal: not rendered")];
    };
    match Preset::from_ron(&f.text, "preset.ron") {
        Ok(back) if back == *p => Vec::new(),
        Ok(_) => vec![Violation::new(
            "preset.ron",
            "internal: the written preset does not read back equal",
        )],
        Err(e) => vec![Violation::new(
            "preset.ron",
            format!("our own import rejects it: {e}"),
        )],
    }
}

impl Export {
    /// Writes the files and the report into `dir` (created if missing), all together or
    /// not at all: on any error the folder is left exactly as it was. Everything was
    /// rendered and checked before, so a failure here is an I/O failure.
    pub fn write(&self, dir: &Path) -> Result<Vec<PathBuf>, ExportError> {
        let mut all: Vec<(String, Vec<u8>)> = self
            .files
            .iter()
            .map(|(n, t)| (n.clone(), t.clone().into_bytes()))
            .collect();
        all.push((
            "mapping_report.md".into(),
            self.report.to_markdown().into_bytes(),
        ));
        all.push((
            "mapping_report.json".into(),
            self.report.to_json().into_bytes(),
        ));
        crate::fsutil::write_all_atomic(dir, &all).map_err(ExportError::Write)
    }
}

/// What every target derives from the preset.
pub(crate) struct Ctx<'a> {
    /// The preset exported.
    pub preset: &'a Preset,
    /// Per axis: limits and travel.
    pub axes: Vec<AxisDerived>,
    /// Per axis: the thermal correction F' (m) at the end of the report's baseline run.
    pub thermal_end_m: Vec<Option<f64>>,
}

impl<'a> Ctx<'a> {
    fn new(preset: &'a Preset, sim: Option<&report::Sim>) -> Ctx<'a> {
        let axes = preset
            .axes
            .iter()
            .enumerate()
            .map(|(i, a)| {
                let travel = travel_mm(a, sim.and_then(|s| s.base_range_mm(i)));
                AxisDerived {
                    limits: axis_limits(preset, a),
                    travel_mm: travel,
                }
            })
            .collect();
        let thermal_end_m = (0..preset.axes.len())
            .map(|i| sim.and_then(|s| s.thermal_end_m(i)))
            .collect();
        Ctx {
            preset,
            axes,
            thermal_end_m,
        }
    }
}

/// What every target derives for one axis.
pub(crate) struct AxisDerived {
    /// The limits a controller needs.
    pub limits: AxisLimits,
    /// (lowest, highest) position a position table must cover, mm.
    pub travel_mm: (f64, f64),
}

/// The limits a controller needs for an axis, derived from the NC and servo settings.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisLimits {
    /// `nc.rapid_mm_per_min` / 60: the fastest the NC moves the axis.
    pub max_vel_mm_s: f64,
    /// The acceleration the acc/dec filter gives a rapid-traverse start (v/τ); with no
    /// filter, the torque limit's acceleration of motor + table.
    pub max_acc_mm_s2: f64,
    /// How the acceleration was derived, for the report.
    pub acc_basis: String,
    /// Following-error limit at full speed: twice the position loop's lag v/Kp without
    /// feed-forward (the feed-forward is commissioned after the limit is set, and must not
    /// trip it).
    pub ferror_mm: f64,
    /// Following-error limit at standstill: a tenth of `ferror_mm`.
    pub min_ferror_mm: f64,
}

/// The limits a controller needs for axis `a` of `p` (see [`AxisLimits`]).
pub fn axis_limits(p: &Preset, a: &AxisParams) -> AxisLimits {
    let v = p.nc.rapid_mm_per_min / 60.0;
    let ad = &p.nc.accdec;
    let tau = match ad.kind {
        AccDecKind::None => 0.0,
        AccDecKind::Linear => ad.tc1_s,
        AccDecKind::Bell => ad.tc1_s.max(ad.tc2_s),
    };
    let (acc, basis) = if tau > 0.0 {
        (
            v / tau,
            format!(
                "rapid {v} mm/s over the acc/dec time constant {tau} s ({:?})",
                ad.kind
            )
            .to_lowercase(),
        )
    } else {
        let lead_m = mm_to_m(a.drive.lead_mm);
        let k = std::f64::consts::TAU / lead_m;
        let force = a.servo.torque_limit_nm * k;
        let mass = a.drive.table_mass_kg + a.drive.motor_inertia_kgm2 * k * k;
        (
            crate::units::m_to_mm(force / mass),
            "no acc/dec filter: torque limit over motor + table inertia".to_owned(),
        )
    };
    let ferror = 2.0 * v / a.servo.kp_per_s;
    AxisLimits {
        max_vel_mm_s: v,
        max_acc_mm_s2: acc,
        acc_basis: basis,
        ferror_mm: ferror,
        min_ferror_mm: ferror / 10.0,
    }
}

/// The travel a position table covers: what the scenario commands (from the report's
/// baseline run) together with the measured lead-error table; at least 1 mm wide. Presets
/// carry no soft limits, so this is the best knowledge of the used travel; outside it every
/// target holds the end values.
fn travel_mm(a: &AxisParams, scenario: Option<(f64, f64)>) -> (f64, f64) {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    if let Some((l, h)) = scenario {
        lo = lo.min(l);
        hi = hi.max(h);
    }
    if let (Some(f), Some(l)) = (a.lead_error.table.first(), a.lead_error.table.last()) {
        lo = lo.min(f.0);
        hi = hi.max(l.0);
    }
    if !lo.is_finite() || !hi.is_finite() {
        lo = a.initial_pos_mm;
        hi = a.initial_pos_mm;
    }
    if hi - lo < 1.0 {
        let c = 0.5 * (lo + hi);
        lo = c - 0.5;
        hi = c + 0.5;
    }
    (lo.floor(), hi.ceil())
}

/// The letter each axis has on a single-channel control: channel 0 keeps X/Y/Z/C; channel 1
/// uses the secondary letters U/V/W (parallel linear axes) and B for C. More channels do not
/// fit one motion controller.
pub(crate) fn flat_letters(p: &Preset) -> Result<Vec<char>, Vec<Violation>> {
    let mut out = Vec::new();
    let mut bad = Vec::new();
    for a in &p.axes {
        let l = match (a.channel, a.letter) {
            (0, l) => Some(l),
            (1, 'X') => Some('U'),
            (1, 'Y') => Some('V'),
            (1, 'Z') => Some('W'),
            (1, 'C') => Some('B'),
            _ => None,
        };
        match l {
            Some(l) => out.push(l),
            None => bad.push(Violation::new(
                format!("axes.{}.channel", a.name),
                format!(
                    "channel {} has no free axis letter on a single motion controller (channel 0 uses X/Y/Z/C, channel 1 U/V/W/B)",
                    a.channel
                ),
            )),
        }
    }
    if bad.is_empty() { Ok(out) } else { Err(bad) }
}

/// f64 written so that reading it back gives the same number (Rust's shortest round-trip
/// form, never an exponent, so `sscanf("%lf")`, `strtod` and every NC parser read it).
pub fn num(x: f64) -> String {
    let s = format!("{x}");
    if s == "-0" { "0".into() } else { s }
}

/// A number rounded to `digits` decimals for controls with a fixed input format.
pub fn fixed(x: f64, digits: usize) -> String {
    let s = format!("{x:.digits$}");
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        s.trim_start_matches('-').to_owned()
    } else {
        s
    }
}

/// The cross tables whose compensated axis is `axis`, with their index.
pub(crate) fn cross_into<'a>(
    p: &'a Preset,
    axis: &str,
) -> Vec<(usize, &'a crate::preset::comp::CrossTable)> {
    p.cross
        .iter()
        .enumerate()
        .filter(|(_, t)| t.enabled && t.comp_axis == axis)
        .collect()
}

/// Index of the axis named `name` (validated presets always have it).
pub(crate) fn axis_index(p: &Preset, name: &str) -> usize {
    p.axes.iter().position(|a| a.name == name).unwrap_or(0)
}
