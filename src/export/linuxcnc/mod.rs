//! LinuxCNC 2.9: `linuxcnc.ini` ([KINS], [TRAJ], one [AXIS_L] per axis, one [JOINT_n] per
//! joint) and one comp file per joint that needs a table.
//!
//! Rules, with their sources:
//! - LinuxCNC 2.9 INI configuration ("INI Configuration", sections [JOINT_n] and [AXIS_L]):
//!   MAX_VELOCITY (units/s), MAX_ACCELERATION (units/s²), FERROR (following-error limit
//!   at full speed), MIN_FERROR (at standstill), BACKLASH, COMP_FILE, COMP_FILE_TYPE. As
//!   the shared tool's README verified, 2.9 reads BACKLASH, COMP_FILE, COMP_FILE_TYPE and
//!   FERROR only from [JOINT_n].
//! - Comp file (`usrmotintf.cc: usrmotLoadComp`): one row per line, `nominal forward
//!   reverse`, whitespace separated, read with `sscanf("%lf %lf %lf")`; reading stops at
//!   the first line that is not three numbers, so the file has no header, comment, blank
//!   line or comma. Type 1 rows hold trims (what is added moving + / −). Rows must increase
//!   and at most 256 are kept (`command.c`, `EMCMOT_COMP_SIZE`).
//! - Semantics (`control.c: compute_screw_comp`, modelled in [`crate::comp::linuxcnc`]):
//!   ±BACKLASH/2 by the sign of the joint velocity, or the interpolated forward/reverse
//!   trim when a table is loaded (BACKLASH is then ignored), ends held, ramped at half the
//!   joint's MAX_VELOCITY and MAX_ACCELERATION.
//!
//! Choices where the issue is silent (also in the README):
//! - A joint gets a comp file only when the axis has a measured lead error to cancel; its
//!   backlash then goes into the forward/reverse columns (fwd − rev = Q, split ±Q/2 as
//!   BACKLASH does) and BACKLASH is written as 0. Otherwise BACKLASH = Q.
//! - Joint n is the preset's n-th axis; channel 1 axes get the letters U/V/W (B for C).
//!
//! Before anything is written, the rendered files go through [`check_outputs`] (what
//! LinuxCNC would accept silently) and through this module's own [`import`] onto the
//! exported preset: an export that the import would reject is refused, each finding named
//! by the preset field whose line it is about.

mod comp;
mod import;

pub use comp::{check_outputs, comp_file_text, parse_comp_file};
pub use import::{import, import_text, joint_model};

use super::entry::{FileSpec, Plan, Put, RenderedFile, with_unit};
use super::report::{Change, Pending};
use super::{Ctx, Violation, num, shared};
use crate::comp::linuxcnc::{COMP_SIZE, CompRow, JointParams};
use crate::units::{mm_to_um, um_to_mm};

/// Name of the INI file in the export folder.
pub const INI_FILE: &str = "linuxcnc.ini";

/// Comp file name of joint `n`.
pub fn comp_file_name(n: usize) -> String {
    format!("joint{n}.comp")
}

/// Where in the LinuxCNC files a finding of the checker or the importer is.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum At {
    /// The file as a whole.
    File,
    /// A line (1-based).
    Line(usize),
    /// `[section]key` of an INI file.
    Key { section: String, key: String },
    /// A field of the preset the import produced (dot dialect).
    Field(String),
}

/// One problem the checker or the importer found.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Finding {
    /// The file, as the reader named it.
    pub file: String,
    /// Where in it.
    pub at: At,
    /// What is wrong, with the value and the allowed range.
    pub reason: String,
}

impl Finding {
    /// A finding at `at` in `file`.
    pub fn new(file: impl Into<String>, at: At, reason: impl Into<String>) -> Finding {
        Finding {
            file: file.into(),
            at,
            reason: reason.into(),
        }
    }

    /// A finding at `[section]key` of an INI file.
    pub fn key(file: &str, section: &str, key: &str, reason: impl Into<String>) -> Finding {
        Finding::new(
            file,
            At::Key {
                section: section.to_owned(),
                key: key.to_owned(),
            },
            reason,
        )
    }

    /// Whether the finding is about `[section]key`.
    pub fn is_key(&self, section: &str, key: &str) -> bool {
        matches!(&self.at, At::Key { section: s, key: k } if s == section && k == key)
    }

    /// "file:3", "file: [JOINT_0]BACKLASH", "file", or the preset field.
    pub fn location(&self) -> String {
        match &self.at {
            At::File => self.file.clone(),
            At::Line(n) => format!("{}:{n}", self.file),
            At::Key { section, key } => format!("{}: [{section}]{key}", self.file),
            At::Field(path) => path.clone(),
        }
    }

    /// The finding as a violation (location and reason).
    pub fn violation(self) -> Violation {
        Violation::new(self.location(), self.reason)
    }
}

/// The joint settings the comp model needs, as exported for axis `i`.
pub(crate) fn joint_params(ctx: &Ctx, i: usize, backlash_mm: f64) -> JointParams {
    let l = &ctx.axes[i].limits;
    JointParams {
        backlash: backlash_mm,
        max_velocity: l.max_vel_mm_s,
        max_acceleration: l.max_acc_mm_s2,
        servo_period_s: ctx.preset.timing.t2_s,
        feed_scale: 1.0,
    }
}

/// The comp rows of axis `i`, if it needs a table: (rows, pitch table used).
fn comp_rows(ctx: &Ctx, i: usize) -> Option<(Vec<CompRow>, super::PitchTable)> {
    let a = &ctx.preset.axes[i];
    if !a.lead_error.enabled {
        return None;
    }
    let pt = super::pitch_table(&a.lead_error, ctx.axes[i].travel_mm, COMP_SIZE, false);
    let half_q = if a.backlash.enabled {
        0.5 * um_to_mm(a.backlash.q_um)
    } else {
        0.0
    };
    let rows = pt
        .points
        .iter()
        .map(|&(x, c_um)| CompRow {
            nominal: x,
            fwd: um_to_mm(c_um) + half_q,
            rev: um_to_mm(c_um) - half_q,
        })
        .collect();
    Some((rows, pt))
}

/// The INI section of joint `i`.
fn joint_sec(i: usize) -> String {
    format!("[JOINT_{i}]")
}

/// The INI section of the axis with letter `l` (with the axisbench axis it is).
fn axis_sec(name: &str, l: char) -> String {
    format!("# axisbench axis '{name}'\n[AXIS_{l}]")
}

/// A line of `linuxcnc.ini`.
fn ini(section: &str, key: &str, value: impl Into<String>) -> Put {
    Put::new(INI_FILE, section, format!("{key} = "), value)
}

/// The export's one list and its files.
pub(crate) fn render(ctx: &Ctx) -> Result<Plan, Vec<Violation>> {
    let p = ctx.preset;
    let mut violations = Vec::new();
    let letters = super::flat_letters(p).unwrap_or_else(|v| {
        violations.extend(v);
        p.axes.iter().map(|a| a.letter).collect()
    });
    for a in &p.axes {
        let l = &a.lead_error;
        // A measured table is data: more rows than a joint holds is an error, not a
        // silent resampling (a cyclic error is sampled on a grid this export chooses).
        if l.enabled && l.amplitude_um == 0.0 && l.table.len() + 2 > COMP_SIZE {
            violations.push(Violation::new(
                format!("axes.{}.lead_error.table", a.name),
                format!(
                    "{} points (plus the two travel ends) do not fit a LinuxCNC comp file, which holds at most {COMP_SIZE} rows (EMCMOT_COMP_SIZE); LinuxCNC would drop the rest",
                    l.table.len()
                ),
            ));
        }
    }
    let mut entries = machine_entries(ctx, &letters);
    let mut files = vec![
        FileSpec::new(
            INI_FILE,
            format!(
                "# LinuxCNC 2.9 settings exported by axisbench from preset '{}'.\n\
                 # Merge [KINS], [TRAJ] and the [AXIS_L]/[JOINT_n] sections into the machine's INI.\n\
                 # Units: mm, s. mapping_report.md says where every value comes from.\n",
                p.name
            ),
            "",
        )
        .gaps()
        .always(),
    ];
    for i in 0..p.axes.len() {
        let letter = letters.get(i).copied().unwrap_or('X');
        entries.extend(axis_entries(ctx, i, letter));
        if p.axes[i].lead_error.enabled {
            files.push(FileSpec::new(comp_file_name(i), "", ""));
        }
    }
    entries.extend(shared::cross_omitted(
        ctx,
        &vec![false; p.cross.len()],
        "LinuxCNC's joint compensation depends only on the joint's own position; a cross-axis table needs a HAL component",
    ));
    if violations.is_empty() {
        Ok(Plan { files, entries })
    } else {
        Err(violations)
    }
}

/// [KINS] and [TRAJ], and the limits every axis shares (rapid traverse, acc/dec).
fn machine_entries(ctx: &Ctx, letters: &[char]) -> Vec<Pending> {
    let p = ctx.preset;
    let coords: String = letters.iter().collect();
    let axes = p
        .axes
        .iter()
        .map(|a| a.name.as_str())
        .collect::<Vec<_>>()
        .join(", ");
    let mut out = vec![
        Pending::derived("axes", format!("{axes} ({} axes)", p.axes.len()))
            .note("joint n is the preset's n-th axis; channel-1 axes take U/V/W (B for C); trivial kinematics, mm")
            .puts([
                ini("[KINS]", "KINEMATICS", format!("trivkins coordinates={coords}")),
                ini("[KINS]", "JOINTS", p.axes.len().to_string()),
                ini("[TRAJ]", "COORDINATES", coords.clone()),
                ini("[TRAJ]", "LINEAR_UNITS", "mm"),
            ]),
    ];
    let mut rapid = vec![ini(
        "[TRAJ]",
        "MAX_LINEAR_VELOCITY",
        num(p.nc.rapid_mm_per_min / 60.0),
    )];
    for (i, a) in p.axes.iter().enumerate() {
        let v = num(ctx.axes[i].limits.max_vel_mm_s);
        rapid.push(ini(
            &axis_sec(&a.name, letters[i]),
            "MAX_VELOCITY",
            v.clone(),
        ));
        rapid.push(ini(&joint_sec(i), "MAX_VELOCITY", v));
    }
    out.push(
        Pending::derived(
            "nc.rapid_mm_per_min",
            with_unit(p.nc.rapid_mm_per_min, "mm/min"),
        )
        .note("rapid traverse / 60 (mm/s), every joint and axis")
        .puts(rapid),
    );
    out.extend(acceleration_entries(ctx, letters));
    out
}

/// MAX_ACCELERATION of every [AXIS_L] and [JOINT_n].
fn acceleration_entries(ctx: &Ctx, letters: &[char]) -> Vec<Pending> {
    let p = ctx.preset;
    shared::acceleration_entries(
        ctx,
        "LinuxCNC plans trapezoidal velocity at MAX_ACCELERATION; the moving-average acc/dec filter (and a bell shape's jerk limit) is not representable. Not simulated: the trajectory is LinuxCNC's own planner",
        &|i| {
            let acc = num(ctx.axes[i].limits.max_acc_mm_s2);
            vec![
                ini(
                    &axis_sec(&p.axes[i].name, letters[i]),
                    "MAX_ACCELERATION",
                    acc.clone(),
                ),
                ini(&joint_sec(i), "MAX_ACCELERATION", acc),
            ]
        },
    )
}

/// Everything of axis `i` (joint `i`, letter `letter`).
fn axis_entries(ctx: &Ctx, i: usize, letter: char) -> Vec<Pending> {
    let p = ctx.preset;
    let a = &p.axes[i];
    let lim = &ctx.axes[i].limits;
    let joint = joint_sec(i);
    let ty = if letter == 'B' || letter == 'C' {
        "ANGULAR"
    } else {
        "LINEAR"
    };
    let mut out = vec![
        Pending::derived(format!("axes.{}.letter", a.name), format!("{} (channel {})", a.letter, a.channel))
            .note(format!("joint {i}, axis letter {letter} on one motion controller; B and C are rotary"))
            .put(ini(&joint, "TYPE", ty)),
        Pending::derived(format!("axes.{}.servo.kp_per_s", a.name), with_unit(a.servo.kp_per_s, "/s"))
            .note("FERROR = 2·MAX_VELOCITY/Kp (twice the loop's lag at full speed without feed-forward); MIN_FERROR = FERROR/10")
            .puts([
                ini(&joint, "FERROR", num(lim.ferror_mm)),
                ini(&joint, "MIN_FERROR", num(lim.min_ferror_mm)),
            ]),
    ];
    let table = comp_rows(ctx, i);
    out.extend(backlash_entries(ctx, i, table.is_some()));
    if let Some((rows, pt)) = &table {
        let name = comp_file_name(i);
        let mut puts = vec![
            ini(&joint, "COMP_FILE", name.clone()),
            ini(&joint, "COMP_FILE_TYPE", "1"),
        ];
        // One line per row, keyed by its nominal (rows increase, so keys are unique).
        puts.extend(rows.iter().map(|r| {
            let line = comp::comp_row_text(r);
            let (key, rest) = line.split_once(' ').unwrap_or((&line, ""));
            Put::new(&name, "", format!("{key} "), rest.trim_end())
        }));
        let mut e = shared::pitch_entry(ctx, i, pt, puts);
        e.entry.note += &format!(
            ". Type-1 rows: trims = correction ± Q/2 (axes.{}.backlash.q_um), {} rows",
            a.name,
            rows.len()
        );
        out.push(e);
    }
    out.extend(shared::quadrant_omitted(
        ctx,
        i,
        "LinuxCNC's motion controller has no reversal feed-forward (a HAL component would be needed)",
    ));
    out.extend(shared::thermal_omitted(
        ctx,
        i,
        "LinuxCNC 2.9 has no thermal model in the INI (a HAL component would have to shift the joint)",
    ));
    out.extend(shared::servo_entries(
        ctx,
        i,
        "the drive or the HAL pid component (P, FF1 = vff, FF2)",
    ));
    out
}

/// BACKLASH (or 0 when the comp table carries it), simulated with LinuxCNC's own
/// compensation, and the per-direction output modes.
fn backlash_entries(ctx: &Ctx, i: usize, has_table: bool) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    let lim = &ctx.axes[i].limits;
    let joint = joint_sec(i);
    let b = &a.backlash;
    if !b.enabled {
        return vec![
            Pending::mapped(format!("axes.{}.backlash.enabled", a.name), "false")
                .note("no backlash compensation")
                .put(ini(&joint, "BACKLASH", "0")),
        ];
    }
    let q_mm = um_to_mm(b.q_um);
    let ramp = format!(
        "LinuxCNC ramps every change of the correction at 0.5·MAX_ACCELERATION = {} mm/s² and 0.5·MAX_VELOCITY = {} mm/s (trapezoidal), starting at the servo period the direction flips",
        num(0.5 * lim.max_acc_mm_s2),
        num(0.5 * lim.max_vel_mm_s)
    );
    let (written, where_) = if has_table {
        (
            "0".to_owned(),
            format!(
                "The amount goes into {}'s forward − reverse columns (BACKLASH = 0: LinuxCNC ignores it with a table). ",
                comp_file_name(i)
            ),
        )
    } else {
        (num(q_mm), String::new())
    };
    // Simulate the backlash part alone, so the pitch table does not blur it.
    let rows = if has_table {
        vec![CompRow {
            nominal: ctx.axes[i].travel_mm.0,
            fwd: 0.5 * q_mm,
            rev: -0.5 * q_mm,
        }]
    } else {
        vec![]
    };
    let (field, value) = shared::backlash_q(a);
    let mut out = vec![
        Pending::approximated(field, value)
            .note(format!(
                "{where_}The amount is exact. LinuxCNC splits it ±Q/2 by the sign of the joint velocity, where axisbench keeps the first direction of motion at 0 and adds ±Q against it: a constant Q/2 = {} µm offset, which homing absorbs. {ramp}. The simulation runs LinuxCNC's compensation (crate::comp::linuxcnc) in place of axisbench's",
                num(mm_to_um(0.5 * q_mm))
            ))
            .put(ini(&joint, "BACKLASH", written))
            .sim(
                vec![Change::Linuxcnc {
                    axis: i,
                    rows,
                    joint: joint_params(ctx, i, if has_table { 0.0 } else { q_mm }),
                }],
                vec![i],
                true,
            ),
    ];
    for (name, d) in shared::directions(b) {
        let field = format!("axes.{}.backlash.{name}.mode", a.name);
        let value = shared::direction_text(d);
        out.push(if d.mode == crate::preset::comp::OutputMode::Lump {
            Pending::approximated(field, value).note(
                "LinuxCNC ramps the step instead of outputting it at once (the error is in the backlash amount row, which simulates the whole LinuxCNC correction)",
            )
        } else {
            Pending::not_representable(field, value).note(
                "LinuxCNC has one output behaviour for both directions, a ramp in time; nearest: that ramp (the error is in the backlash amount row, which simulates the whole LinuxCNC correction)",
            )
        });
    }
    out
}

/// The rendered files through the checker and our own import onto the exported preset;
/// every finding is named by the preset field that wrote the line it is about.
pub(crate) fn self_check(ctx: &Ctx, files: &[RenderedFile], entries: &[Pending]) -> Vec<Violation> {
    let texts: Vec<(String, String)> = files
        .iter()
        .map(|f| (f.name.clone(), f.text.clone()))
        .collect();
    let mut findings = comp::output_findings(&texts);
    if findings.is_empty() {
        let ini = texts
            .iter()
            .find(|(n, _)| n == INI_FILE)
            .map(|(_, t)| t.as_str())
            .unwrap_or("");
        let mut read = |name: &str| {
            (
                name.to_owned(),
                texts
                    .iter()
                    .find(|(n, _)| n == name)
                    .map(|(_, t)| t.clone())
                    .ok_or_else(|| "not among the exported files".to_owned()),
            )
        };
        if let Err(f) = import::import_findings(INI_FILE, ini, ctx.preset, &mut read) {
            findings = f;
        }
    }
    findings
        .into_iter()
        .map(|f| attribute(f, files, entries))
        .collect()
}

/// The entry whose line a finding is about, as a violation naming its field and value.
fn attribute(f: Finding, files: &[RenderedFile], entries: &[Pending]) -> Violation {
    let file = files.iter().find(|r| r.name == f.file);
    let line = match (&f.at, file) {
        (At::Line(n), Some(_)) => Some(*n),
        (At::Key { section, key }, Some(r)) => ini_line(&r.text, section, key),
        _ => None,
    };
    let owner = match (&f.at, line, file) {
        (At::Field(path), _, _) => entries
            .iter()
            .filter(|p| {
                let f = &p.entry.field;
                path == f || path.starts_with(&format!("{f}."))
            })
            .max_by_key(|p| p.entry.field.len()),
        (_, Some(n), Some(r)) => r
            .owners
            .get(n.wrapping_sub(1))
            .and_then(|o| o.first())
            .and_then(|&k| entries.get(k)),
        _ => None,
    };
    let text = match (line, file) {
        (Some(n), Some(r)) => r.text.lines().nth(n.wrapping_sub(1)).unwrap_or(""),
        _ => "",
    };
    match owner {
        Some(p) => Violation::new(
            &p.entry.field,
            format!(
                "{} is written as {} `{}`, which our own import rejects: {}",
                p.entry.value,
                f.location(),
                text.trim(),
                f.reason
            ),
        ),
        None => Violation::new(
            f.location(),
            format!("internal: the generated output is wrong: {}", f.reason),
        ),
    }
}

/// The 1-based line of `key = …` in `[section]` of an INI text.
fn ini_line(text: &str, section: &str, key: &str) -> Option<usize> {
    let mut current = String::new();
    for (n, line) in text.lines().enumerate() {
        let t = line.trim();
        if let Some(s) = t.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
            current = s.to_owned();
        } else if current == section
            && let Some(rest) = t.strip_prefix(key)
            && rest.trim_start().starts_with('=')
        {
            return Some(n + 1);
        }
    }
    None
}
