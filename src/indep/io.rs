//! Cases on disk: the record as TRACE_FORMAT CSV, the nominal preset as RON, and every
//! truth in one JSON file (written here by hand: the generator depends on no serializer).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::{Case, IndepError, TrueEffect};

/// A JSON string literal.
fn text(s: &str) -> String {
    let mut o = String::with_capacity(s.len() + 2);
    o.push('"');
    for c in s.chars() {
        match c {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            '\n' => o.push_str("\\n"),
            c if (c as u32) < 0x20 => {
                let _ = write!(o, "\\u{:04x}", c as u32);
            }
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

/// A JSON number (null for a non-finite value, which JSON cannot hold).
fn num(x: f64) -> String {
    if x.is_finite() {
        format!("{x:?}")
    } else {
        "null".into()
    }
}

/// A JSON object of numbers.
fn numbers<'a>(map: impl Iterator<Item = (&'a String, &'a f64)>) -> String {
    let items: Vec<String> = map
        .map(|(k, v)| format!("{}: {}", text(k), num(*v)))
        .collect();
    format!("{{{}}}", items.join(", "))
}

fn effect(e: &TrueEffect) -> String {
    format!(
        "{{\"name\": {}, \"formula\": {}, \"params\": {}}}",
        text(e.name),
        text(e.formula),
        numbers(e.params.iter())
    )
}

/// The truth of one case as a JSON object.
pub fn case_json(c: &Case) -> String {
    let t = &c.truth;
    let effects: Vec<String> = t.effects.iter().map(effect).collect();
    format!(
        "{{\"name\": {}, \"seed\": {}, \"kind\": {}, \"duration_s\": {}, \"pos_sensor\": {}, \
         \"skew_channel\": {}, \"skew_samples\": {}, \"nominal_scale\": {}, \"effects\": [{}]}}",
        text(&c.name),
        c.seed,
        text(c.kind.name()),
        num(t.duration_s),
        text(t.pos_sensor),
        text(t.skew_channel),
        num(t.skew_samples),
        numbers(t.nominal_scale.iter()),
        effects.join(", ")
    )
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> IndepError + '_ {
    move |source| IndepError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// See [`super::write_cases`].
pub fn write_cases(dir: &Path, cases: &[Case]) -> Result<Vec<PathBuf>, IndepError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let mut written = Vec::new();
    for c in cases {
        let csv = dir.join(format!("{}.csv", c.name));
        c.trace.write_csv(&csv)?;
        written.push(csv);
        let ron = dir.join(format!("{}.ron", c.name));
        std::fs::write(&ron, c.preset.to_ron()?).map_err(io_err(&ron))?;
        written.push(ron);
    }
    let body: Vec<String> = cases
        .iter()
        .map(|c| format!("  {}", case_json(c)))
        .collect();
    let json = format!(
        "{{\"generator\": \"axisbench indep\", \"cases\": [\n{}\n]}}\n",
        body.join(",\n")
    );
    let path = dir.join("truth.json");
    std::fs::write(&path, json).map_err(io_err(&path))?;
    written.push(path);
    Ok(written)
}
