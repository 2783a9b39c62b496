//! LinuxCNC comp files and the checker of a LinuxCNC export's output.
//!
//! The reader is strict on purpose: LinuxCNC (`usrmotintf.cc: usrmotLoadComp`) stops at the
//! first line that is not three numbers and accepts NaN trims, so a hand-edited or broken
//! file degrades the compensation silently. Every such line is a finding here, and every
//! number must be finite and inside [`crate::export::ranges`].

use ini::Ini;

use super::{At, Finding, INI_FILE};
use crate::comp::linuxcnc::{COMP_SIZE, CompRow};
use crate::export::Violation;
use crate::export::entry::show;
use crate::export::ranges::{POSITION_MM, TRIM_MM};

/// A type-1 comp file: `nominal fwd rev` per line, nothing else.
pub fn comp_file_text(rows: &[CompRow]) -> String {
    rows.iter().map(comp_row_text).collect()
}

/// One comp-file line, newline included.
pub(crate) fn comp_row_text(r: &CompRow) -> String {
    use crate::export::num;
    format!("{} {} {}\n", num(r.nominal), num(r.fwd), num(r.rev))
}

/// Parses a comp file strictly: every line three finite numbers separated by blanks,
/// nominals increasing and inside the position range, trims inside the compensation
/// range, at most 256 rows. Every line LinuxCNC would silently stop at or accept wrongly
/// (NaN, header, comment, comma, blank line, an empty file) is a violation. Type 0 rows
/// are converted to trims as LinuxCNC does.
pub fn parse_comp_file(text: &str, file: &str, file_type: u8) -> (Vec<CompRow>, Vec<Violation>) {
    let (rows, findings) = comp_findings(text, file, file_type);
    (rows, findings.into_iter().map(Finding::violation).collect())
}

/// [`parse_comp_file`] with findings that keep the line number apart.
pub(crate) fn comp_findings(text: &str, file: &str, file_type: u8) -> (Vec<CompRow>, Vec<Finding>) {
    let mut rows: Vec<CompRow> = Vec::new();
    let mut bad = Vec::new();
    let body = text.strip_suffix('\n').unwrap_or(text);
    if body.trim().is_empty() {
        bad.push(Finding::new(
            file,
            At::File,
            "empty: LinuxCNC loads 0 rows without a word and compensates nothing",
        ));
        return (rows, bad);
    }
    for (n, line) in body.split('\n').enumerate() {
        let line = line.strip_suffix('\r').unwrap_or(line);
        match comp_line(line, file_type, rows.last()) {
            Ok(row) => rows.push(row),
            Err(why) => bad.push(Finding::new(file, At::Line(n + 1), why)),
        }
    }
    if rows.len() > COMP_SIZE {
        bad.push(Finding::new(
            file,
            At::File,
            format!(
                "{} rows; a joint holds {COMP_SIZE} and LinuxCNC drops the rest (\"too many compensation entries\")",
                rows.len()
            ),
        ));
    }
    (rows, bad)
}

/// One comp-file line as a row, or why it is not a good one.
fn comp_line(line: &str, file_type: u8, prev: Option<&CompRow>) -> Result<CompRow, String> {
    const STOPS: &str = "LinuxCNC stops reading at the first line that is not three numbers, so this line and every row after it would be ignored silently";
    let fields: Vec<&str> = line.split_whitespace().collect();
    if line.trim().is_empty() {
        return Err(format!("blank line: {STOPS}"));
    }
    if line.contains(',') {
        return Err(format!("comma separator: {STOPS}"));
    }
    if line.trim_start().starts_with('#') || line.trim_start().starts_with(';') {
        return Err(format!("comment line: {STOPS}"));
    }
    if fields.len() != 3 {
        return Err(format!(
            "{} fields, not 3 (a header?): {STOPS}",
            fields.len()
        ));
    }
    let mut vals = [0.0; 3];
    for (k, f) in fields.iter().enumerate() {
        vals[k] = f.parse::<f64>().map_err(|_| {
            format!("'{}' is not three numbers (a header or text line?): LinuxCNC stops reading here and ignores every row after it", line.trim())
        })?;
    }
    if let Some(k) = vals.iter().position(|v| !v.is_finite()) {
        return Err(format!(
            "field {} is {}: LinuxCNC accepts it silently and the compensation goes wrong (a NaN trim freezes backlash_filt)",
            k + 1,
            show(vals[k])
        ));
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
    POSITION_MM
        .check(row.nominal)
        .map_err(|r| format!("nominal: {r}"))?;
    TRIM_MM
        .check(row.fwd)
        .map_err(|r| format!("forward trim: {r}"))?;
    TRIM_MM
        .check(row.rev)
        .map_err(|r| format!("reverse trim: {r}"))?;
    if let Some(prev) = prev
        && row.nominal <= prev.nominal
    {
        return Err(format!(
            "nominal {} is not above the previous row's {}; LinuxCNC rejects the row (\"compensation values must increase\")",
            show(row.nominal),
            show(prev.nominal)
        ));
    }
    Ok(row)
}

/// Checks an export's files for everything LinuxCNC would reject or, worse, accept
/// silently: comp files (see [`parse_comp_file`]), an empty or missing COMP_FILE, a
/// COMP_FILE_TYPE other than 0/1, non-finite or non-positive limits, BACKLASH in [AXIS_L]
/// (ignored by 2.9).
pub fn check_outputs(files: &[(String, String)]) -> Vec<Violation> {
    output_findings(files)
        .into_iter()
        .map(Finding::violation)
        .collect()
}

/// [`check_outputs`] with findings that keep the location apart.
pub(crate) fn output_findings(files: &[(String, String)]) -> Vec<Finding> {
    let Some((_, ini_text)) = files.iter().find(|(n, _)| n == INI_FILE) else {
        return vec![Finding::new(INI_FILE, At::File, "missing")];
    };
    let ini = match Ini::load_from_str(ini_text) {
        Ok(i) => i,
        Err(e) => {
            return vec![Finding::new(
                INI_FILE,
                At::File,
                format!("not an INI file: {e}"),
            )];
        }
    };
    let mut bad = Vec::new();
    for (sec, props) in ini.iter() {
        let Some(sec) = sec else { continue };
        if sec.starts_with("AXIS_") && props.contains_key("BACKLASH") {
            bad.push(Finding::key(
                INI_FILE,
                sec,
                "BACKLASH",
                "LinuxCNC 2.9 reads BACKLASH only from [JOINT_n]; here it is ignored silently",
            ));
        }
        if sec.starts_with("JOINT_") || sec.starts_with("AXIS_") {
            bad.extend(limit_findings(sec, props));
            bad.extend(comp_file_findings(files, sec, props));
        }
    }
    bad
}

/// Limits that must be finite and positive (BACKLASH may be 0), MIN_FERROR ≤ FERROR.
fn limit_findings(sec: &str, props: &ini::Properties) -> Vec<Finding> {
    let mut bad = Vec::new();
    for key in [
        "MAX_VELOCITY",
        "MAX_ACCELERATION",
        "FERROR",
        "MIN_FERROR",
        "BACKLASH",
    ] {
        let Some(v) = props.get(key) else { continue };
        let why = match v.trim().parse::<f64>() {
            Ok(x) if x.is_finite() && (x > 0.0 || (key == "BACKLASH" && x == 0.0)) => continue,
            Ok(x) if key == "BACKLASH" && x < 0.0 => {
                format!("{x} is negative: LinuxCNC accepts it and inverts the correction")
            }
            _ => format!(
                "'{v}' must be a finite number > 0{}",
                if key == "BACKLASH" { " (or 0)" } else { "" }
            ),
        };
        bad.push(Finding::key(INI_FILE, sec, key, why));
    }
    if let (Some(f), Some(m)) = (props.get("FERROR"), props.get("MIN_FERROR"))
        && let (Ok(f), Ok(m)) = (f.trim().parse::<f64>(), m.trim().parse::<f64>())
        && m > f
    {
        bad.push(Finding::key(
            INI_FILE,
            sec,
            "MIN_FERROR",
            format!("{m} is above FERROR = {f}"),
        ));
    }
    bad
}

/// COMP_FILE / COMP_FILE_TYPE of one section, and the comp file they name.
fn comp_file_findings(
    files: &[(String, String)],
    sec: &str,
    props: &ini::Properties,
) -> Vec<Finding> {
    let Some(cf) = props.get("COMP_FILE") else {
        return vec![];
    };
    let mut bad = Vec::new();
    let cf = cf.trim();
    let ty = match props.get("COMP_FILE_TYPE").map(str::trim).unwrap_or("0") {
        "0" => 0,
        "1" => 1,
        other => {
            bad.push(Finding::key(
                INI_FILE,
                sec,
                "COMP_FILE_TYPE",
                format!("'{other}' is not 0 or 1"),
            ));
            1
        }
    };
    if cf.is_empty() {
        bad.push(Finding::key(
            INI_FILE,
            sec,
            "COMP_FILE",
            "empty: LinuxCNC loads 0 rows silently",
        ));
    } else if let Some((_, text)) = files.iter().find(|(n, _)| n == cf) {
        bad.extend(comp_findings(text, cf, ty).1);
    } else {
        bad.push(Finding::key(
            INI_FILE,
            sec,
            "COMP_FILE",
            format!("'{cf}' is not among the exported files"),
        ));
    }
    bad
}
