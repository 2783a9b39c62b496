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

use ini::Ini;

use super::report::{self, Change, Pending};
use super::{Ctx, Rendered, Violation, num};
use crate::comp::linuxcnc::{COMP_SIZE, CompRow, JointParams};
use crate::preset::Preset;

/// Name of the INI file in the export folder.
pub const INI_FILE: &str = "linuxcnc.ini";

/// Comp file name of joint `n`.
pub fn comp_file_name(n: usize) -> String {
    format!("joint{n}.comp")
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
        0.5 * a.backlash.q_um / 1000.0
    } else {
        0.0
    };
    let rows = pt
        .points
        .iter()
        .map(|&(x, c_um)| CompRow {
            nominal: x,
            fwd: c_um / 1000.0 + half_q,
            rev: c_um / 1000.0 - half_q,
        })
        .collect();
    Some((rows, pt))
}

pub(crate) fn render(ctx: &Ctx) -> Result<Rendered, Vec<Violation>> {
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
                format!("axes[{}].lead_error.table", a.name),
                format!(
                    "{} points (plus the two travel ends) do not fit a LinuxCNC comp file, which holds at most {COMP_SIZE} rows (EMCMOT_COMP_SIZE); LinuxCNC would drop the rest",
                    l.table.len()
                ),
            ));
        }
    }
    let coords: String = letters.iter().collect();
    let mut ini = format!(
        "# LinuxCNC 2.9 settings exported by axisbench from preset '{}'.\n\
         # Merge [KINS], [TRAJ] and the [AXIS_L]/[JOINT_n] sections into the machine's INI.\n\
         # Units: mm, s. mapping_report.md says where every value comes from.\n\n\
         [KINS]\nKINEMATICS = trivkins coordinates={coords}\nJOINTS = {}\n\n\
         [TRAJ]\nCOORDINATES = {coords}\nLINEAR_UNITS = mm\nMAX_LINEAR_VELOCITY = {}\n",
        p.name,
        p.axes.len(),
        num(p.nc.rapid_mm_per_min / 60.0)
    );
    let mut files: Vec<(String, String)> = Vec::new();
    let mut entries: Vec<Pending> = Vec::new();
    for (i, a) in p.axes.iter().enumerate() {
        let lim = &ctx.axes[i].limits;
        let letter = letters.get(i).copied().unwrap_or('X');
        let q_mm = if a.backlash.enabled {
            a.backlash.q_um / 1000.0
        } else {
            0.0
        };
        let table = comp_rows(ctx, i);
        let ty = if letter == 'B' || letter == 'C' {
            "ANGULAR"
        } else {
            "LINEAR"
        };
        ini += &format!(
            "\n# axisbench axis '{}'\n[AXIS_{letter}]\nMAX_VELOCITY = {}\nMAX_ACCELERATION = {}\n",
            a.name,
            num(lim.max_vel_mm_s),
            num(lim.max_acc_mm_s2)
        );
        ini += &format!(
            "\n[JOINT_{i}]\nTYPE = {ty}\nMAX_VELOCITY = {}\nMAX_ACCELERATION = {}\nFERROR = {}\nMIN_FERROR = {}\n",
            num(lim.max_vel_mm_s),
            num(lim.max_acc_mm_s2),
            num(lim.ferror_mm),
            num(lim.min_ferror_mm)
        );
        let joint = format!("[JOINT_{i}]");
        let axis = format!("[AXIS_{letter}]");
        match &table {
            Some((rows, _)) => {
                let name = comp_file_name(i);
                ini += &format!("BACKLASH = 0\nCOMP_FILE = {name}\nCOMP_FILE_TYPE = 1\n");
                files.push((name, comp_file_text(rows)));
            }
            None => ini += &format!("BACKLASH = {}\n", num(q_mm)),
        }
        // ---- report ----
        entries.push(Pending::derived(
            format!(
                "nc.rapid_mm_per_min = {} (axis {})",
                p.nc.rapid_mm_per_min, a.name
            ),
            format!(
                "{joint}MAX_VELOCITY = {0}, {axis}MAX_VELOCITY = {0}",
                num(lim.max_vel_mm_s)
            ),
            "rapid traverse / 60 (mm/s)",
        ));
        entries.push(Pending::approximated(
            format!(
                "nc.accdec = {:?}, τ1 = {} s, τ2 = {} s (axis {})",
                p.nc.accdec.kind, p.nc.accdec.tc1_s, p.nc.accdec.tc2_s, a.name
            ),
            format!("{joint}MAX_ACCELERATION = {0}, {axis}MAX_ACCELERATION = {0}", num(lim.max_acc_mm_s2)),
            &format!(
                "{}. LinuxCNC plans trapezoidal velocity at MAX_ACCELERATION; the moving-average acc/dec filter (and a bell shape's jerk limit) is not representable. Not simulated: the trajectory is LinuxCNC's own planner",
                lim.acc_basis
            ),
        ));
        entries.push(Pending::derived(
            format!("axes[{}].servo.kp_per_s = {}", a.name, a.servo.kp_per_s),
            format!("{joint}FERROR = {}, {joint}MIN_FERROR = {}", num(lim.ferror_mm), num(lim.min_ferror_mm)),
            "FERROR = 2·MAX_VELOCITY/Kp (twice the loop's lag at full speed without feed-forward); MIN_FERROR = FERROR/10",
        ));
        let ramp = format!(
            "LinuxCNC ramps every change of the correction at 0.5·MAX_ACCELERATION = {} mm/s² and 0.5·MAX_VELOCITY = {} mm/s (trapezoidal), starting at the servo period the direction flips",
            num(0.5 * lim.max_acc_mm_s2),
            num(0.5 * lim.max_vel_mm_s)
        );
        if a.backlash.enabled {
            let b = &a.backlash;
            let target = match &table {
                Some(_) => format!(
                    "{} forward − reverse columns = {} mm (BACKLASH = 0: ignored with a table)",
                    comp_file_name(i),
                    num(q_mm)
                ),
                None => format!("{joint}BACKLASH = {}", num(q_mm)),
            };
            // Simulate the backlash part alone, so the pitch table does not blur it.
            let lo = ctx.axes[i].travel_mm.0;
            let rows = if table.is_some() {
                vec![CompRow {
                    nominal: lo,
                    fwd: 0.5 * q_mm,
                    rev: -0.5 * q_mm,
                }]
            } else {
                vec![]
            };
            entries.push(
                Pending::approximated(
                    format!(
                        "axes[{}].backlash.q_um = {} (+→−: {}, −→+: {})",
                        a.name,
                        b.q_um,
                        report::direction_text(&b.plus_to_minus),
                        report::direction_text(&b.minus_to_plus)
                    ),
                    target,
                    &format!(
                        "The amount is exact. LinuxCNC splits it ±Q/2 by the sign of the joint velocity, where axisbench keeps the first direction of motion at 0 and adds ±Q against it: a constant Q/2 = {} µm offset, which homing absorbs. {ramp}. The simulation runs LinuxCNC's compensation (crate::comp::linuxcnc) in place of axisbench's",
                        num(0.5 * b.q_um)
                    ),
                )
                .sim(
                    vec![Change::Linuxcnc {
                        axis: i,
                        rows,
                        joint: joint_params(ctx, i, if table.is_some() { 0.0 } else { q_mm }),
                    }],
                    vec![i],
                    true,
                ),
            );
            for (name, d) in [
                ("plus_to_minus", &b.plus_to_minus),
                ("minus_to_plus", &b.minus_to_plus),
            ] {
                let setting = format!(
                    "axes[{}].backlash.{name}.mode = {}",
                    a.name,
                    report::direction_text(d)
                );
                entries.push(if d.mode == crate::comp::backlash::OutputMode::Lump {
                    Pending::approximated(
                        setting,
                        "(the ramp above)",
                        "LinuxCNC ramps the step instead of outputting it at once (the error is in the backlash amount row, which simulates the whole LinuxCNC correction)",
                    )
                } else {
                    Pending::not_representable(
                        setting,
                        "LinuxCNC has one output behaviour for both directions, a ramp in time; nearest: that ramp (the error is in the backlash amount row, which simulates the whole LinuxCNC correction)",
                    )
                });
            }
        } else {
            entries.push(Pending::mapped(
                format!("axes[{}].backlash.enabled = false", a.name),
                format!("{joint}BACKLASH = 0"),
                "no backlash compensation",
            ));
        }
        if let Some((_, pt)) = &table {
            entries.push(report::pitch_entry(
                ctx,
                i,
                pt,
                format!(
                    "{joint}COMP_FILE = {}, COMP_FILE_TYPE = 1 ({} rows, trims = correction ± Q/2)",
                    comp_file_name(i),
                    pt.points.len()
                ),
            ));
        }
        entries.extend(report::quadrant_omitted(
            ctx,
            i,
            "LinuxCNC's motion controller has no reversal feed-forward (a HAL component would be needed)",
        ));
        entries.extend(report::thermal_omitted(
            ctx,
            i,
            "LinuxCNC 2.9 has no thermal model in the INI (a HAL component would have to shift the joint)",
        ));
        entries.extend(report::servo_entries(
            ctx,
            i,
            "the drive or the HAL pid component (P, FF1 = vff, FF2)",
        ));
    }
    entries.extend(report::cross_omitted(
        ctx,
        &vec![false; p.cross.len()],
        "LinuxCNC's joint compensation depends only on the joint's own position; a cross-axis table needs a HAL component",
    ));
    files.insert(0, (INI_FILE.to_owned(), ini));
    // What LinuxCNC would accept silently must not be in our own output.
    let found = check_outputs(&files);
    violations.extend(found.into_iter().map(|v| {
        Violation::new(
            v.location,
            format!("internal: the generated output is wrong: {}", v.reason),
        )
    }));
    if violations.is_empty() {
        Ok(Rendered { files, entries })
    } else {
        Err(violations)
    }
}

/// The LinuxCNC compensation of joint `joint` as configured by `ini_path` (its
/// [JOINT_n] BACKLASH, MAX_VELOCITY, MAX_ACCELERATION and comp file), with the given servo
/// period and feed scale 1: what the conformance test replays LinuxCNC's trace through.
pub fn joint_model(
    ini_path: &std::path::Path,
    joint: usize,
    servo_period_s: f64,
) -> Result<crate::comp::linuxcnc::LinuxCncComp, super::ExportError> {
    let file = ini_path.display().to_string();
    let text = std::fs::read_to_string(ini_path).map_err(|source| super::ExportError::Io {
        file: file.clone(),
        source,
    })?;
    let ini = Ini::load_from_str(&text).map_err(|e| super::ExportError::Input {
        file: file.clone(),
        reason: e.to_string(),
    })?;
    let sec = format!("JOINT_{joint}");
    let props = ini
        .section(Some(sec.as_str()))
        .ok_or_else(|| super::ExportError::Input {
            file: file.clone(),
            reason: format!("no [{sec}]"),
        })?;
    let mut bad = Vec::new();
    let num = |key: &str, default: Option<f64>, bad: &mut Vec<Violation>| -> f64 {
        match props.get(key).map(|v| v.trim().parse::<f64>()) {
            Some(Ok(x)) => x,
            Some(Err(_)) => {
                bad.push(Violation::new(
                    format!("{file}: [{sec}]{key}"),
                    "not a number",
                ));
                f64::NAN
            }
            None => default.unwrap_or_else(|| {
                bad.push(Violation::new(format!("{file}: [{sec}]{key}"), "missing"));
                f64::NAN
            }),
        }
    };
    let backlash = num("BACKLASH", Some(0.0), &mut bad);
    let max_velocity = num("MAX_VELOCITY", None, &mut bad);
    let max_acceleration = num("MAX_ACCELERATION", None, &mut bad);
    let mut rows = Vec::new();
    if let Some(cf) = props
        .get("COMP_FILE")
        .map(str::trim)
        .filter(|c| !c.is_empty())
    {
        let ty = if props.get("COMP_FILE_TYPE").map(str::trim) == Some("1") {
            1
        } else {
            0
        };
        let dir = ini_path
            .parent()
            .map(|d| d.to_path_buf())
            .unwrap_or_default();
        let path = dir.join(cf);
        match std::fs::read_to_string(&path) {
            Ok(t) => {
                let (r, issues) = parse_comp_file(&t, &path.display().to_string(), ty);
                bad.extend(issues);
                rows = r;
            }
            Err(e) => bad.push(Violation::new(path.display().to_string(), e.to_string())),
        }
    }
    if !bad.is_empty() {
        return Err(super::ExportError::Import {
            file,
            violations: bad,
        });
    }
    let (table, _) = crate::comp::linuxcnc::CompTable::load(&rows);
    Ok(crate::comp::linuxcnc::LinuxCncComp::new(
        table,
        JointParams {
            backlash,
            max_velocity,
            max_acceleration,
            servo_period_s,
            feed_scale: 1.0,
        },
    ))
}

/// A type-1 comp file: `nominal fwd rev` per line, nothing else.
pub fn comp_file_text(rows: &[CompRow]) -> String {
    let mut s = String::new();
    for r in rows {
        s += &format!("{} {} {}\n", num(r.nominal), num(r.fwd), num(r.rev));
    }
    s
}

/// Parses a comp file strictly: every line three finite numbers separated by blanks,
/// nominals increasing, at most 256 rows. Every line LinuxCNC would silently stop at or
/// accept wrongly (NaN, header, comment, comma, blank line, an empty file) is a violation.
/// Type 0 rows are converted to trims as LinuxCNC does.
pub fn parse_comp_file(text: &str, file: &str, file_type: u8) -> (Vec<CompRow>, Vec<Violation>) {
    let mut rows: Vec<CompRow> = Vec::new();
    let mut bad = Vec::new();
    let body = text.strip_suffix('\n').unwrap_or(text);
    if body.trim().is_empty() {
        bad.push(Violation::new(
            file,
            "empty: LinuxCNC loads 0 rows without a word and compensates nothing",
        ));
        return (rows, bad);
    }
    for (n, line) in body.split('\n').enumerate() {
        let at = format!("{file}:{}", n + 1);
        let line = line.strip_suffix('\r').unwrap_or(line);
        let fields: Vec<&str> = line.split_whitespace().collect();
        let why = if line.trim().is_empty() {
            Some("blank line".to_owned())
        } else if line.contains(',') {
            Some("comma separator".to_owned())
        } else if line.trim_start().starts_with('#') || line.trim_start().starts_with(';') {
            Some("comment line".to_owned())
        } else if fields.len() != 3 {
            Some(format!("{} fields, not 3 (a header?)", fields.len()))
        } else {
            None
        };
        if let Some(why) = why {
            bad.push(Violation::new(
                &at,
                format!("{why}: LinuxCNC stops reading at the first line that is not three numbers, so this line and every row after it would be ignored silently"),
            ));
            continue;
        }
        let parsed: Vec<Option<f64>> = fields.iter().map(|f| f.parse::<f64>().ok()).collect();
        if parsed.iter().any(Option::is_none) {
            bad.push(Violation::new(
                &at,
                format!("'{line}' is not three numbers (a header or text line?): LinuxCNC stops reading here and ignores every row after it"),
            ));
            continue;
        }
        let vals: Vec<f64> = parsed.into_iter().flatten().collect();
        if let Some(k) = vals.iter().position(|v| !v.is_finite()) {
            bad.push(Violation::new(
                &at,
                format!("field {} is {}: LinuxCNC accepts it silently and the compensation goes wrong (a NaN trim freezes backlash_filt)", k + 1, vals[k]),
            ));
            continue;
        }
        let row = if file_type == 0 {
            CompRow::from_type0(vals[0], vals[1], vals[2])
        } else {
            CompRow {
                nominal: vals[0],
                fwd: vals[1],
                rev: vals[2],
            }
        };
        if let Some(prev) = rows.last()
            && row.nominal <= prev.nominal
        {
            bad.push(Violation::new(
                &at,
                format!(
                    "nominal {} is not above the previous row's {}; LinuxCNC rejects the row (\"compensation values must increase\")",
                    row.nominal, prev.nominal
                ),
            ));
            continue;
        }
        rows.push(row);
    }
    if rows.len() > COMP_SIZE {
        bad.push(Violation::new(
            file,
            format!(
                "{} rows; a joint holds {COMP_SIZE} and LinuxCNC drops the rest (\"too many compensation entries\")",
                rows.len()
            ),
        ));
    }
    (rows, bad)
}

/// Checks an export's files for everything LinuxCNC would reject or, worse, accept
/// silently: comp files (see [`parse_comp_file`]), an empty or missing COMP_FILE, a
/// COMP_FILE_TYPE other than 0/1, non-finite or non-positive limits, BACKLASH in [AXIS_L]
/// (ignored by 2.9).
pub fn check_outputs(files: &[(String, String)]) -> Vec<Violation> {
    let mut bad = Vec::new();
    let Some((_, ini_text)) = files.iter().find(|(n, _)| n == INI_FILE) else {
        return vec![Violation::new(INI_FILE, "missing")];
    };
    let ini = match Ini::load_from_str(ini_text) {
        Ok(i) => i,
        Err(e) => return vec![Violation::new(INI_FILE, format!("not an INI file: {e}"))],
    };
    for (sec, props) in ini.iter() {
        let Some(sec) = sec else { continue };
        let at = |k: &str| format!("{INI_FILE}: [{sec}]{k}");
        if sec.starts_with("AXIS_") && props.contains_key("BACKLASH") {
            bad.push(Violation::new(
                at("BACKLASH"),
                "LinuxCNC 2.9 reads BACKLASH only from [JOINT_n]; here it is ignored silently",
            ));
        }
        if !(sec.starts_with("JOINT_") || sec.starts_with("AXIS_")) {
            continue;
        }
        for key in [
            "MAX_VELOCITY",
            "MAX_ACCELERATION",
            "FERROR",
            "MIN_FERROR",
            "BACKLASH",
        ] {
            if let Some(v) = props.get(key) {
                match v.trim().parse::<f64>() {
                    Ok(x) if x.is_finite() && (x > 0.0 || (key == "BACKLASH" && x == 0.0)) => {}
                    Ok(x) if key == "BACKLASH" && x < 0.0 => bad.push(Violation::new(
                        at(key),
                        format!("{x} is negative: LinuxCNC accepts it and inverts the correction"),
                    )),
                    _ => bad.push(Violation::new(
                        at(key),
                        format!(
                            "'{v}' must be a finite number > 0{}",
                            if key == "BACKLASH" { " (or 0)" } else { "" }
                        ),
                    )),
                }
            }
        }
        if let (Some(f), Some(m)) = (props.get("FERROR"), props.get("MIN_FERROR"))
            && let (Ok(f), Ok(m)) = (f.trim().parse::<f64>(), m.trim().parse::<f64>())
            && m > f
        {
            bad.push(Violation::new(
                at("MIN_FERROR"),
                format!("{m} is above FERROR = {f}"),
            ));
        }
        if let Some(cf) = props.get("COMP_FILE") {
            let cf = cf.trim();
            let ty = props.get("COMP_FILE_TYPE").map(str::trim).unwrap_or("0");
            let ty = match ty {
                "0" => 0,
                "1" => 1,
                other => {
                    bad.push(Violation::new(
                        at("COMP_FILE_TYPE"),
                        format!("'{other}' is not 0 or 1"),
                    ));
                    1
                }
            };
            if cf.is_empty() {
                bad.push(Violation::new(
                    at("COMP_FILE"),
                    "empty: LinuxCNC loads 0 rows silently",
                ));
            } else if let Some((_, text)) = files.iter().find(|(n, _)| n == cf) {
                bad.extend(parse_comp_file(text, cf, ty).1);
            } else {
                bad.push(Violation::new(
                    at("COMP_FILE"),
                    format!("'{cf}' is not among the exported files"),
                ));
            }
        }
    }
    bad
}

/// Reads `linuxcnc.ini` (and the comp files it names) back onto `base`: joint n is the
/// base preset's n-th axis. MAX_VELOCITY → `nc.rapid_mm_per_min`, MAX_ACCELERATION → the
/// acc/dec time constant, BACKLASH or the comp table's fwd − rev → the backlash amount,
/// the table's mean of fwd and rev → the lead error it cancels. A value that agrees with the
/// base preset to 1e-9 (relative) keeps the base's exact number, so a round trip is exact.
/// FERROR/MIN_FERROR are derived values and are not read back.
pub fn import(ini_path: &std::path::Path, base: &Preset) -> Result<Preset, super::ExportError> {
    let file = ini_path.display().to_string();
    let text = std::fs::read_to_string(ini_path).map_err(|source| super::ExportError::Io {
        file: file.clone(),
        source,
    })?;
    let dir = ini_path
        .parent()
        .map(|d| d.to_path_buf())
        .unwrap_or_default();
    let ini = Ini::load_from_str(&text).map_err(|e| super::ExportError::Input {
        file: file.clone(),
        reason: format!("not an INI file: {e}"),
    })?;
    let mut bad: Vec<Violation> = Vec::new();
    let mut p = base.clone();
    let njoints = (0..)
        .take_while(|n| ini.section(Some(format!("JOINT_{n}"))).is_some())
        .count();
    if njoints != p.axes.len() {
        bad.push(Violation::new(
            &file,
            format!(
                "{njoints} [JOINT_n] sections, the base preset '{}' has {} axes (joint n is the base's n-th axis)",
                p.name,
                p.axes.len()
            ),
        ));
        return Err(super::ExportError::Import {
            file,
            violations: bad,
        });
    }
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1e-12);
    let mut rapid: Option<f64> = None;
    for n in 0..njoints {
        let sec = format!("JOINT_{n}");
        let props = ini.section(Some(sec.as_str()));
        let get = |key: &str, bad: &mut Vec<Violation>| -> Option<f64> {
            let v = props.and_then(|s| s.get(key))?;
            match v.trim().parse::<f64>() {
                Ok(x) if x.is_finite() => Some(x),
                _ => {
                    bad.push(Violation::new(
                        format!("{file}: [{sec}]{key}"),
                        format!("'{v}' is not a finite number"),
                    ));
                    None
                }
            }
        };
        let base_lim = super::axis_limits(base, &base.axes[n]);
        if let Some(v) = get("MAX_VELOCITY", &mut bad) {
            let v = if close(v, base_lim.max_vel_mm_s) {
                base_lim.max_vel_mm_s
            } else {
                v
            };
            match rapid {
                Some(r) if !close(r, v) => bad.push(Violation::new(
                    format!("{file}: [{sec}]MAX_VELOCITY"),
                    format!("{v} differs from joint 0's {r}: axisbench has one rapid traverse for all axes"),
                )),
                _ => rapid = Some(v),
            }
        }
        if let Some(acc) = get("MAX_ACCELERATION", &mut bad)
            && !close(acc, base_lim.max_acc_mm_s2)
        {
            if acc <= 0.0 {
                bad.push(Violation::new(
                    format!("{file}: [{sec}]MAX_ACCELERATION"),
                    format!("{acc} must be > 0"),
                ));
            } else {
                let v = rapid.unwrap_or(base_lim.max_vel_mm_s);
                p.nc.accdec.kind = crate::preset::AccDecKind::Linear;
                p.nc.accdec.tc1_s = v / acc;
                p.nc.accdec.tc2_s = 0.0;
            }
        }
        let backlash = get("BACKLASH", &mut bad).unwrap_or(0.0);
        let comp = props.and_then(|s| s.get("COMP_FILE")).map(str::trim);
        let a = &mut p.axes[n];
        let mut q_mm = backlash;
        if let Some(cf) = comp {
            let ty = match props.and_then(|s| s.get("COMP_FILE_TYPE")).map(str::trim) {
                None | Some("0") => 0,
                Some("1") => 1,
                Some(o) => {
                    bad.push(Violation::new(
                        format!("{file}: [{sec}]COMP_FILE_TYPE"),
                        format!("'{o}' is not 0 or 1"),
                    ));
                    1
                }
            };
            let path = dir.join(cf);
            let text = if cf.is_empty() {
                bad.push(Violation::new(
                    format!("{file}: [{sec}]COMP_FILE"),
                    "empty: LinuxCNC loads 0 rows silently",
                ));
                String::new()
            } else {
                match std::fs::read_to_string(&path) {
                    Ok(t) => t,
                    Err(e) => {
                        bad.push(Violation::new(
                            path.display().to_string(),
                            format!("cannot read: {e}"),
                        ));
                        String::new()
                    }
                }
            };
            let (rows, issues) = parse_comp_file(&text, &path.display().to_string(), ty);
            if !cf.is_empty() {
                bad.extend(issues);
            }
            if let Some(first) = rows.first() {
                q_mm = first.fwd - first.rev;
                for (k, r) in rows.iter().enumerate() {
                    if !close(r.fwd - r.rev, q_mm) && ((r.fwd - r.rev) - q_mm).abs() > 1e-12 {
                        bad.push(Violation::new(
                            format!("{}:{}", path.display(), k + 1),
                            format!(
                                "forward − reverse = {} mm differs from the first row's {q_mm} mm: a position-dependent backlash is not representable in axisbench (one amount per axis)",
                                r.fwd - r.rev
                            ),
                        ));
                    }
                }
                // The pitch part: the correction the table applies besides backlash.
                let pts: Vec<(f64, f64)> = rows
                    .iter()
                    .map(|r| (r.nominal, -0.5 * (r.fwd + r.rev) * 1e3))
                    .collect();
                let same = a.lead_error.enabled
                    && pts
                        .iter()
                        .all(|&(x, e)| (super::lead_error_um(&a.lead_error, x) - e).abs() <= 1e-6);
                if !same {
                    a.lead_error.enabled = pts.iter().any(|p| p.1 != 0.0);
                    a.lead_error.amplitude_um = 0.0;
                    a.lead_error.cumulative_um_per_m = 0.0;
                    a.lead_error.phase_deg = 0.0;
                    a.lead_error.table = pts;
                }
            }
        }
        if q_mm < 0.0 {
            bad.push(Violation::new(
                format!("{file}: [{sec}]"),
                format!("backlash {q_mm} mm is negative (LinuxCNC would invert the correction)"),
            ));
        } else if q_mm == 0.0 {
            a.backlash.enabled = false;
        } else {
            a.backlash.enabled = true;
            let q_um = q_mm * 1000.0;
            if !close(q_um, a.backlash.q_um) {
                a.backlash.q_um = q_um;
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
    bad.extend(
        p.validate()
            .into_iter()
            .map(|e| Violation::new(e.path, e.reason)),
    );
    if bad.is_empty() {
        Ok(p)
    } else {
        Err(super::ExportError::Import {
            file,
            violations: bad,
        })
    }
}
