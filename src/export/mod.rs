//! Export of a tuned preset to controllers, and import back.
//!
//! An export renders every file of a target in memory, checks them, simulates what the
//! target cannot carry and writes the mapping report; only when all of that succeeded are
//! the files written (each atomically). A preset that breaks a target's limits gives one
//! error listing every violation, and nothing is written.
//!
//! Targets: [`Target::Ron`] (axisbench's own format, lossless), [`linuxcnc`] (LinuxCNC 2.9
//! INI + comp files), [`siemens`] (SINUMERIK 840D sl machine/setting data and CEC tables),
//! [`heidenhain`] (`.COM` compensation table), [`beckhoff`] (TwinCAT CNC / ISG compensation
//! lists), [`fanuc`] (parameter list). Each module cites the documents its rules come from.
//!
//! What every target shares is derived here, once: the axis limits a controller needs
//! (velocity, acceleration, following-error limits), the travel a position table must
//! cover, and the pitch-error table that cancels the preset's measured lead error.

pub mod beckhoff;
pub mod fanuc;
pub mod heidenhain;
pub mod import;
pub mod linuxcnc;
pub mod report;
pub mod siemens;

use std::path::{Path, PathBuf};

use crate::preset::{AccDecKind, AxisParams, LeadError, Preset};

pub use report::{Entry, ErrFigures, Report, Status};

/// Where an export goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Target {
    Ron,
    Linuxcnc,
    Siemens,
    Heidenhain,
    Beckhoff,
    Fanuc,
}

impl Target {
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

/// One broken rule: where (field, file, line) and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Violation {
    pub location: String,
    pub reason: String,
}

impl Violation {
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

fn list(v: &[Violation]) -> String {
    v.iter()
        .map(|e| format!("  - {e}"))
        .collect::<Vec<_>>()
        .join("\n")
}

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("the preset cannot be exported to {target}; nothing was written. {} violation(s):\n{}", .violations.len(), list(.violations))]
    Violations {
        target: String,
        violations: Vec<Violation>,
    },
    #[error("{file}: {reason}")]
    Input { file: String, reason: String },
    #[error("{}: {} problem(s):\n{}", .file, .violations.len(), list(.violations))]
    Import {
        file: String,
        violations: Vec<Violation>,
    },
    #[error("cannot write {file}: {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
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
    pub target: Target,
    /// (file name relative to the output folder, contents).
    pub files: Vec<(String, String)>,
    pub report: Report,
}

/// Files of a target plus the report entries; the simulations are run afterwards.
pub(crate) struct Rendered {
    pub files: Vec<(String, String)>,
    pub entries: Vec<report::Pending>,
}

/// Renders, checks and simulates an export of `preset` (with its scenario programs as
/// `(file name, text)`), without writing anything.
pub fn export(
    preset: &Preset,
    programs: &[(String, String)],
    target: Target,
    opts: &ExportOptions,
) -> Result<Export, ExportError> {
    let mut violations: Vec<Violation> = preset
        .validate()
        .into_iter()
        .map(|e| Violation::new(e.path, e.reason))
        .collect();
    if !violations.is_empty() {
        // Target limits are still checked on what can be checked, so the user sees every
        // problem at once.
        let ctx = Ctx::new(preset, None);
        let _ = render(&ctx, target, programs, &mut violations);
        return Err(ExportError::Violations {
            target: target.title().into(),
            violations,
        });
    }
    let sim = report::Sim::new(preset, programs, opts.horizon_s)?;
    let ctx = Ctx::new(preset, Some(&sim));
    let rendered = render(&ctx, target, programs, &mut violations);
    let Some(rendered) = rendered.filter(|_| violations.is_empty()) else {
        return Err(ExportError::Violations {
            target: target.title().into(),
            violations,
        });
    };
    let mut report = report::finish(&ctx, &sim, target, rendered.entries)?;
    report.files = rendered.files.iter().map(|(n, _)| n.clone()).collect();
    Ok(Export {
        target,
        files: rendered.files,
        report,
    })
}

fn render(
    ctx: &Ctx,
    target: Target,
    programs: &[(String, String)],
    violations: &mut Vec<Violation>,
) -> Option<Rendered> {
    let r = match target {
        Target::Ron => ron_files(ctx.preset, programs),
        Target::Linuxcnc => linuxcnc::render(ctx),
        Target::Siemens => siemens::render(ctx),
        Target::Heidenhain => heidenhain::render(ctx),
        Target::Beckhoff => beckhoff::render(ctx),
        Target::Fanuc => fanuc::render(ctx),
    };
    match r {
        Ok(r) => Some(r),
        Err(v) => {
            violations.extend(v);
            None
        }
    }
}

/// The RON target: the preset itself (f64 written shortest-round-trip, so lossless) and its
/// programs, so the folder loads on its own.
fn ron_files(p: &Preset, programs: &[(String, String)]) -> Result<Rendered, Vec<Violation>> {
    let ron = p
        .to_ron()
        .map_err(|e| vec![Violation::new("preset", e.to_string())])?;
    let mut files = vec![("preset.ron".to_owned(), ron)];
    for (name, text) in programs {
        files.push((name.clone(), text.clone()));
    }
    let entries = vec![report::Pending::mapped(
        "the whole preset",
        "preset.ron",
        "lossless: every field, f64 in shortest round-trip form",
    )];
    Ok(Rendered { files, entries })
}

impl Export {
    /// Writes the files and the report into `dir` (created if missing). Everything was
    /// rendered and checked before, so a failure here is an I/O failure.
    pub fn write(&self, dir: &Path) -> Result<Vec<PathBuf>, ExportError> {
        let io = |p: &Path| {
            let file = p.display().to_string();
            move |source| ExportError::Io { file, source }
        };
        let created = !dir.exists();
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let mut all: Vec<(String, String)> = self.files.clone();
        all.push(("mapping_report.md".into(), self.report.to_markdown()));
        all.push(("mapping_report.json".into(), self.report.to_json()));
        // Every file is first written (and synced) into a staging folder inside `dir`;
        // only when all of them are there are they renamed into place, so a failure
        // (disk full, permissions) leaves the folder as it was.
        let stage = dir.join(format!(".axisbench-export.{}", std::process::id()));
        let staged = (|| -> Result<(), ExportError> {
            std::fs::create_dir_all(&stage).map_err(io(&stage))?;
            for (name, text) in &all {
                let p = stage.join(name);
                crate::fsutil::write_atomic(&p, text.as_bytes()).map_err(io(&p))?;
            }
            Ok(())
        })();
        if let Err(e) = staged {
            let _ = std::fs::remove_dir_all(&stage);
            if created {
                let _ = std::fs::remove_dir(dir);
            }
            return Err(e);
        }
        let mut written = Vec::new();
        for (name, _) in &all {
            let to = dir.join(name);
            std::fs::rename(stage.join(name), &to).map_err(io(&to))?;
            written.push(to);
        }
        let _ = std::fs::remove_dir_all(&stage);
        Ok(written)
    }
}

/// What every target derives from the preset.
pub(crate) struct Ctx<'a> {
    pub preset: &'a Preset,
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

pub(crate) struct AxisDerived {
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
    pub acc_basis: String,
    /// Following-error limit at full speed: twice the position loop's lag v/Kp without
    /// feed-forward (the feed-forward is commissioned after the limit is set, and must not
    /// trip it).
    pub ferror_mm: f64,
    /// Following-error limit at standstill: a tenth of `ferror_mm`.
    pub min_ferror_mm: f64,
}

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
        let lead_m = a.drive.lead_mm * 1e-3;
        let k = std::f64::consts::TAU / lead_m;
        let force = a.servo.torque_limit_nm * k;
        let mass = a.drive.table_mass_kg + a.drive.motor_inertia_kgm2 * k * k;
        (
            force / mass * 1e3,
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

/// The preset's lead (pitch) error at screw position `x_mm`, µm: the cyclic part, the
/// cumulative lead deviation and the measured table, as the plant applies them.
pub fn lead_error_um(l: &LeadError, x_mm: f64) -> f64 {
    if !l.enabled {
        return 0.0;
    }
    let turns = x_mm / l.period_mm + l.phase_deg / 360.0;
    l.amplitude_um * (std::f64::consts::TAU * turns).sin()
        + l.cumulative_um_per_m * x_mm * 1e-3
        + crate::table::interp(&l.table, x_mm)
}

/// A pitch-error compensation table: (position mm, correction µm = −lead error).
#[derive(Debug, Clone, PartialEq)]
pub struct PitchTable {
    pub points: Vec<(f64, f64)>,
    /// Largest |lead error + table correction| over the travel, µm (0 = exact).
    pub residual_um: f64,
    pub equidistant: bool,
}

/// The table that cancels the preset's lead error over `travel`, with at most `max_points`
/// points; `equidistant` for controls whose tables have one spacing (SINUMERIK, FANUC).
/// The measured table's own points are used when they fit and the error is piecewise
/// linear (then the table is exact); otherwise a uniform grid as fine as the limit allows
/// (32 points per cyclic period are enough for a 0.5 % residual).
pub fn pitch_table(
    l: &LeadError,
    travel: (f64, f64),
    max_points: usize,
    equidistant: bool,
) -> PitchTable {
    let (lo, hi) = travel;
    let piecewise_linear = l.amplitude_um == 0.0;
    let mut xs: Vec<f64> = Vec::new();
    if piecewise_linear && !equidistant {
        xs.push(lo);
        xs.extend(l.table.iter().map(|p| p.0));
        xs.push(hi);
        xs.sort_by(f64::total_cmp);
        xs.dedup();
    }
    if xs.is_empty() || xs.len() > max_points {
        let width = hi - lo;
        let wanted = if !piecewise_linear {
            (width / (l.period_mm / 32.0)).ceil() as usize + 1
        } else if l.table.len() >= 2 {
            let min_gap = l
                .table
                .windows(2)
                .map(|w| w[1].0 - w[0].0)
                .fold(f64::INFINITY, f64::min);
            (width / min_gap).ceil() as usize + 1
        } else {
            2
        };
        let n = wanted.clamp(2, max_points.max(2));
        let step = width / (n - 1) as f64;
        xs = (0..n).map(|i| lo + step * i as f64).collect();
        if let Some(last) = xs.last_mut() {
            *last = hi;
        }
    }
    let points: Vec<(f64, f64)> = xs.iter().map(|&x| (x, -lead_error_um(l, x))).collect();
    let residual = residual_um(l, &points, travel);
    PitchTable {
        points,
        residual_um: residual,
        equidistant,
    }
}

/// Largest |lead error + correction| over the travel, evaluated on 20 000 points plus every
/// table point (the correction interpolated with its ends held, as every target does).
pub fn residual_um(l: &LeadError, points: &[(f64, f64)], travel: (f64, f64)) -> f64 {
    let (lo, hi) = travel;
    let n = 20_000;
    (0..=n)
        .map(|i| lo + (hi - lo) * i as f64 / n as f64)
        .chain(points.iter().map(|p| p.0))
        .map(|x| (lead_error_um(l, x) + crate::table::interp(points, x)).abs())
        .fold(0.0, f64::max)
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
                format!("axes[{}].channel", a.name),
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

/// A point table on an equidistant grid, for controls whose tables have one spacing: the
/// table itself when its points are equidistant, else resampled at its smallest spacing
/// (at most `max_points`). Returns (points, spacing, largest interpolation change µm or
/// table unit).
pub fn equidistant(points: &[(f64, f64)], max_points: usize) -> (Vec<(f64, f64)>, f64, f64) {
    let (Some(first), Some(last)) = (points.first(), points.last()) else {
        return (vec![], 0.0, 0.0);
    };
    if points.len() < 2 {
        return (points.to_vec(), 1.0, 0.0);
    }
    let width = last.0 - first.0;
    let step0 = points[1].0 - points[0].0;
    let regular = points
        .windows(2)
        .all(|w| ((w[1].0 - w[0].0) - step0).abs() <= 1e-9 * width.max(1.0));
    if regular {
        return (points.to_vec(), step0, 0.0);
    }
    let min_gap = points
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .fold(f64::INFINITY, f64::min);
    let n = ((width / min_gap).ceil() as usize + 1).clamp(2, max_points.max(2));
    let step = width / (n - 1) as f64;
    let out: Vec<(f64, f64)> = (0..n)
        .map(|i| {
            let x = if i + 1 == n {
                last.0
            } else {
                first.0 + step * i as f64
            };
            (x, crate::table::interp(points, x))
        })
        .collect();
    let m = 20_000;
    let err = (0..=m)
        .map(|i| first.0 + width * i as f64 / m as f64)
        .chain(points.iter().map(|p| p.0))
        .map(|x| (crate::table::interp(points, x) - crate::table::interp(&out, x)).abs())
        .fold(0.0, f64::max);
    (out, step, err)
}

/// The cross tables whose compensated axis is `axis`, with their index.
pub(crate) fn cross_into<'a>(
    p: &'a Preset,
    axis: &str,
) -> Vec<(usize, &'a crate::comp::cross::CrossTable)> {
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
