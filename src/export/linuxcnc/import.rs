//! LinuxCNC INI + comp files read back onto a base preset.
//!
//! Every number is checked for finiteness and against [`crate::export::ranges`] before it
//! is used, and the preset that results is run through [`crate::machine::check`] (the
//! validator and the closed-loop stability check), so whatever the files say, an import
//! either gives a preset the model can run or says which file, key or line is wrong, with
//! the value and the allowed range.

use std::path::Path;

use ini::Ini;

use super::comp::comp_findings;
use super::{At, Finding};
use crate::comp::linuxcnc::{CompRow, CompTable, JointParams, LinuxCncComp};
use crate::export::entry::{dot_path, show};
use crate::export::ranges::{ACCDEC_TIME_S, ACCELERATION_MM_S2, BACKLASH_MM, Range, VELOCITY_MM_S};
use crate::export::{ExportError, axis_limits, lead_error_um};
use crate::preset::{AccDecKind, Preset};
use crate::units::mm_to_um;

/// Reads a comp file named in the INI: (name for messages, contents or why not).
type ReadComp<'a> = dyn FnMut(&str) -> (String, Result<String, String>) + 'a;

/// Reads `linuxcnc.ini` (and the comp files it names, relative to its folder) back onto
/// `base`: joint n is the base preset's n-th axis. MAX_VELOCITY → `nc.rapid_mm_per_min`,
/// MAX_ACCELERATION → the acc/dec time constant, BACKLASH or the comp table's fwd − rev →
/// the backlash amount, the table's mean of fwd and rev → the lead error it cancels. A
/// value that agrees with the base preset to 1e-9 (relative) keeps the base's exact number,
/// so a round trip is exact. FERROR/MIN_FERROR are derived values and are not read back.
pub fn import(ini_path: &Path, base: &Preset) -> Result<Preset, ExportError> {
    let file = ini_path.display().to_string();
    let text = std::fs::read_to_string(ini_path).map_err(|e| ExportError::Read {
        file: file.clone(),
        reason: e.to_string(),
    })?;
    let dir = ini_path.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut read = |name: &str| {
        let p = dir.join(name);
        (
            p.display().to_string(),
            std::fs::read_to_string(&p).map_err(|e| e.to_string()),
        )
    };
    import_findings(&file, &text, base, &mut read).map_err(|f| into_error(&file, f))
}

/// [`import`] from text: the INI's contents and the comp files it may name, as (name as
/// written in COMP_FILE, contents). What the command line runs after reading the files,
/// and what the fuzz target drives. A COMP_FILE not among `comp_files` cannot be read.
pub fn import_text(
    ini_file: &str,
    ini_text: &str,
    comp_files: &[(String, String)],
    base: &Preset,
) -> Result<Preset, ExportError> {
    let mut read = |name: &str| {
        (
            name.to_owned(),
            comp_files
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, t)| t.clone())
                .ok_or_else(|| "no such file among the comp files given".to_owned()),
        )
    };
    import_findings(ini_file, ini_text, base, &mut read).map_err(|f| into_error(ini_file, f))
}

fn into_error(file: &str, findings: Vec<Finding>) -> ExportError {
    ExportError::Import {
        file: file.to_owned(),
        violations: findings.into_iter().map(Finding::violation).collect(),
    }
}

/// What one [JOINT_n] section says, every number checked.
struct Joint {
    max_vel: Option<f64>,
    max_acc: Option<f64>,
    backlash_mm: f64,
    /// The comp table, when COMP_FILE names one (file name for messages, rows).
    table: Option<(String, Vec<CompRow>)>,
}

/// The import with its findings kept apart (file, line or key), so an export can point
/// each one back at the preset field that wrote the line.
pub(crate) fn import_findings(
    ini_file: &str,
    ini_text: &str,
    base: &Preset,
    read: &mut ReadComp<'_>,
) -> Result<Preset, Vec<Finding>> {
    let ini = Ini::load_from_str(ini_text).map_err(|e| {
        vec![Finding::new(
            ini_file,
            At::File,
            format!("not an INI file: {e}"),
        )]
    })?;
    let njoints = (0..)
        .take_while(|n| ini.section(Some(format!("JOINT_{n}"))).is_some())
        .count();
    if njoints != base.axes.len() {
        return Err(vec![Finding::new(
            ini_file,
            At::File,
            format!(
                "{njoints} [JOINT_n] sections, the base preset '{}' has {} axes (joint n is the base's n-th axis)",
                base.name,
                base.axes.len()
            ),
        )]);
    }
    let mut bad = Vec::new();
    let joints: Vec<Joint> = (0..njoints)
        .map(|n| read_joint(ini_file, &ini, n, read, &mut bad))
        .collect();
    let mut p = base.clone();
    apply_limits(ini_file, &joints, base, &mut p, &mut bad);
    for (n, j) in joints.iter().enumerate() {
        apply_backlash_and_table(n, j, &mut p, &mut bad);
    }
    if bad.is_empty() {
        bad.extend(crate::machine::check(&p).into_iter().map(|e| {
            Finding::new(
                ini_file,
                At::Field(dot_path(&e.path)),
                format!("the imported preset is not valid: {}", e.reason),
            )
        }));
    }
    if bad.is_empty() { Ok(p) } else { Err(bad) }
}

/// A number under `key` of `[sec]`: None when absent; a finding when it is not a finite
/// number inside `range`.
fn number(
    file: &str,
    sec: &str,
    props: Option<&ini::Properties>,
    key: &str,
    range: &Range,
    bad: &mut Vec<Finding>,
) -> Option<f64> {
    let v = props.and_then(|s| s.get(key))?;
    let checked = v
        .trim()
        .parse::<f64>()
        .map_err(|_| format!("'{}' is not a number", v.trim()))
        .and_then(|x| range.check(x));
    match checked {
        Ok(x) => Some(x),
        Err(why) => {
            bad.push(Finding::key(file, sec, key, why));
            None
        }
    }
}

/// Reads and checks one [JOINT_n] section and its comp file.
fn read_joint(
    file: &str,
    ini: &Ini,
    n: usize,
    read: &mut ReadComp<'_>,
    bad: &mut Vec<Finding>,
) -> Joint {
    let sec = format!("JOINT_{n}");
    let props = ini.section(Some(sec.as_str()));
    let max_vel = number(file, &sec, props, "MAX_VELOCITY", &VELOCITY_MM_S, bad);
    let max_acc = number(
        file,
        &sec,
        props,
        "MAX_ACCELERATION",
        &ACCELERATION_MM_S2,
        bad,
    );
    let backlash_mm = number(file, &sec, props, "BACKLASH", &BACKLASH_MM, bad).unwrap_or(0.0);
    let table = props
        .and_then(|s| s.get("COMP_FILE"))
        .map(str::trim)
        .map(|cf| read_table(file, &sec, props, cf, read, bad));
    Joint {
        max_vel,
        max_acc,
        backlash_mm,
        table,
    }
}

/// COMP_FILE_TYPE and the comp file COMP_FILE names, read strictly.
fn read_table(
    file: &str,
    sec: &str,
    props: Option<&ini::Properties>,
    cf: &str,
    read: &mut ReadComp<'_>,
    bad: &mut Vec<Finding>,
) -> (String, Vec<CompRow>) {
    let ty = match props.and_then(|s| s.get("COMP_FILE_TYPE")).map(str::trim) {
        None | Some("0") => 0,
        Some("1") => 1,
        Some(o) => {
            bad.push(Finding::key(
                file,
                sec,
                "COMP_FILE_TYPE",
                format!("'{o}' is not 0 or 1"),
            ));
            1
        }
    };
    if cf.is_empty() {
        bad.push(Finding::key(
            file,
            sec,
            "COMP_FILE",
            "empty: LinuxCNC loads 0 rows silently",
        ));
        return (String::new(), Vec::new());
    }
    let (name, text) = read(cf);
    match text {
        Ok(text) => {
            let (rows, issues) = comp_findings(&text, &name, ty);
            bad.extend(issues);
            (name, rows)
        }
        Err(e) => {
            bad.push(Finding::new(&name, At::File, format!("cannot read: {e}")));
            (name, Vec::new())
        }
    }
}

/// A table that reproduces the base's lead error to this (µm) keeps the base's model
/// (cyclic + cumulative + table) instead of replacing it by the table.
const SAME_UM: f64 = 0.000_001;

/// Close enough to the base's value to keep the base's exact number.
fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1e-12)
}

/// MAX_VELOCITY (one rapid traverse for all axes) and MAX_ACCELERATION (→ a linear acc/dec
/// time constant, which must stay inside its range).
fn apply_limits(
    file: &str,
    joints: &[Joint],
    base: &Preset,
    p: &mut Preset,
    bad: &mut Vec<Finding>,
) {
    let mut rapid: Option<f64> = None;
    for (n, j) in joints.iter().enumerate() {
        let sec = format!("JOINT_{n}");
        let base_lim = axis_limits(base, &base.axes[n]);
        if let Some(v) = j.max_vel {
            let v = if close(v, base_lim.max_vel_mm_s) {
                base_lim.max_vel_mm_s
            } else {
                v
            };
            match rapid {
                Some(r) if !close(r, v) => bad.push(Finding::key(
                    file,
                    &sec,
                    "MAX_VELOCITY",
                    format!("{} differs from joint 0's {}: axisbench has one rapid traverse for all axes", show(v), show(r)),
                )),
                _ => rapid = Some(v),
            }
        }
        if let Some(acc) = j.max_acc
            && !close(acc, base_lim.max_acc_mm_s2)
        {
            let v = rapid.unwrap_or(base_lim.max_vel_mm_s);
            match ACCDEC_TIME_S.check(v / acc) {
                Ok(tau) => {
                    p.nc.accdec.kind = AccDecKind::Linear;
                    p.nc.accdec.tc1_s = tau;
                    p.nc.accdec.tc2_s = 0.0;
                }
                Err(why) => bad.push(Finding::key(
                    file,
                    &sec,
                    "MAX_ACCELERATION",
                    format!(
                        "{} mm/s² with MAX_VELOCITY {} mm/s: {why}",
                        show(acc),
                        show(v)
                    ),
                )),
            }
        }
    }
    if let Some(v) = rapid {
        p.nc.rapid_mm_per_min = if close(v * 60.0, base.nc.rapid_mm_per_min) {
            base.nc.rapid_mm_per_min
        } else {
            v * 60.0
        };
    }
}

/// BACKLASH, or the comp table's fwd − rev (one amount per axis), and the lead error the
/// table's mean trim cancels.
fn apply_backlash_and_table(n: usize, j: &Joint, p: &mut Preset, bad: &mut Vec<Finding>) {
    let a = &mut p.axes[n];
    let mut q_mm = j.backlash_mm;
    if let Some((name, rows)) = &j.table
        && let Some(first) = rows.first()
    {
        q_mm = first.fwd - first.rev;
        for (k, r) in rows.iter().enumerate() {
            let d = r.fwd - r.rev;
            if !close(d, q_mm) && (d - q_mm).abs() > 1e-12 {
                bad.push(Finding::new(
                    name,
                    At::Line(k + 1),
                    format!(
                        "forward − reverse = {} mm differs from the first row's {} mm: a position-dependent backlash is not representable in axisbench (one amount per axis)",
                        show(d),
                        show(q_mm)
                    ),
                ));
            }
        }
        if let Err(why) = BACKLASH_MM.check(q_mm) {
            bad.push(Finding::new(
                name,
                At::Line(1),
                format!("forward − reverse is the backlash: {why}"),
            ));
        }
        // The pitch part: the correction the table applies besides backlash.
        let pts: Vec<(f64, f64)> = rows
            .iter()
            .map(|r| (r.nominal, -mm_to_um(0.5 * (r.fwd + r.rev))))
            .collect();
        let same = a.lead_error.enabled
            && pts
                .iter()
                .all(|&(x, e)| (lead_error_um(&a.lead_error, x) - e).abs() <= SAME_UM);
        if !same {
            a.lead_error.enabled = pts.iter().any(|p| p.1 != 0.0);
            a.lead_error.amplitude_um = 0.0;
            a.lead_error.cumulative_um_per_m = 0.0;
            a.lead_error.phase_deg = 0.0;
            a.lead_error.table = pts;
        }
    }
    // A negative amount was refused above (BACKLASH and fwd − rev are range-checked).
    if q_mm > 0.0 {
        a.backlash.enabled = true;
        let q_um = mm_to_um(q_mm);
        if !close(q_um, a.backlash.q_um) {
            a.backlash.q_um = q_um;
        }
    } else {
        a.backlash.enabled = false;
    }
}

/// The LinuxCNC compensation of joint `joint` as configured by `ini_path` (its
/// [JOINT_n] BACKLASH, MAX_VELOCITY, MAX_ACCELERATION and comp file, read and checked as
/// the import reads them), with the given servo period and feed scale 1: what the
/// conformance test replays LinuxCNC's trace through.
pub fn joint_model(
    ini_path: &Path,
    joint: usize,
    servo_period_s: f64,
) -> Result<LinuxCncComp, ExportError> {
    let file = ini_path.display().to_string();
    let text = std::fs::read_to_string(ini_path).map_err(|e| ExportError::Read {
        file: file.clone(),
        reason: e.to_string(),
    })?;
    let ini = Ini::load_from_str(&text).map_err(|e| ExportError::Input {
        file: file.clone(),
        reason: format!("not an INI file: {e}"),
    })?;
    let sec = format!("JOINT_{joint}");
    if ini.section(Some(sec.as_str())).is_none() {
        return Err(ExportError::Input {
            file,
            reason: format!("no [{sec}]"),
        });
    }
    let dir = ini_path.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut read = |name: &str| {
        let p = dir.join(name);
        (
            p.display().to_string(),
            std::fs::read_to_string(&p).map_err(|e| e.to_string()),
        )
    };
    let mut bad = Vec::new();
    let j = read_joint(&file, &ini, joint, &mut read, &mut bad);
    for key in ["MAX_VELOCITY", "MAX_ACCELERATION"] {
        let v = if key == "MAX_VELOCITY" {
            j.max_vel
        } else {
            j.max_acc
        };
        if v.is_none() && !bad.iter().any(|f| f.is_key(&sec, key)) {
            bad.push(Finding::key(&file, &sec, key, "missing"));
        }
    }
    if !bad.is_empty() {
        return Err(into_error(&file, bad));
    }
    let rows = j.table.map(|t| t.1).unwrap_or_default();
    let (table, _) = CompTable::load(&rows);
    Ok(LinuxCncComp::new(
        table,
        JointParams {
            backlash: j.backlash_mm,
            max_velocity: j.max_vel.unwrap_or(0.0),
            max_acceleration: j.max_acc.unwrap_or(0.0),
            servo_period_s,
            feed_scale: 1.0,
        },
    ))
}
