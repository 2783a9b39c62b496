//! Cases on disk: the record as TRACE_FORMAT CSV, the nominal preset as RON, and every
//! truth in one JSON file (written here by hand: the generator depends on no serializer).

use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};

use super::{Case, CaseSpec, IndepError, TrueEffect};

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

/// See [`super::write_cases`].
pub fn write_cases(
    dir: &Path,
    specs: &[CaseSpec],
    progress: &mut dyn FnMut(usize, &str),
) -> Result<Vec<PathBuf>, IndepError> {
    let mut names: Vec<String> = specs
        .iter()
        .flat_map(|s| [format!("{}.csv", s.name), format!("{}.ron", s.name)])
        .collect();
    names.push("truth.json".into());
    // One case in memory at a time: generated when its record is due, its preset held for
    // the next file, its truth kept (small) for truth.json.
    let mut ron = String::new();
    let mut truths: Vec<String> = Vec::with_capacity(specs.len());
    let mut failed: Option<IndepError> = None;
    let mut fill = |i: usize, w: &mut dyn Write| -> std::io::Result<()> {
        let halt = |e: IndepError, failed: &mut Option<IndepError>| {
            let text = e.to_string();
            *failed = Some(e);
            std::io::Error::other(text)
        };
        match (specs.get(i / 2), i % 2) {
            (Some(spec), 0) => {
                progress(i / 2, &spec.name);
                let c = super::generate(spec).map_err(|e| halt(e, &mut failed))?;
                ron = c.preset.to_ron().map_err(|e| halt(e.into(), &mut failed))?;
                truths.push(format!("  {}", case_json(&c)));
                c.trace.write_csv_to(w)
            }
            (Some(_), _) => w.write_all(ron.as_bytes()),
            (None, _) => write!(
                w,
                "{{\"generator\": \"axisbench indep\", \"cases\": [\n{}\n]}}\n",
                truths.join(",\n")
            ),
        }
    };
    let written = crate::fsutil::write_all_atomic_with(dir, &names, &mut fill);
    match (written, failed) {
        (Ok(w), _) => Ok(w),
        (Err(_), Some(e)) => Err(e),
        (Err(e), None) => Err(IndepError::Io {
            path: e.path.display().to_string(),
            source: std::io::Error::new(e.kind, format!("{}: {}", e.op, e.reason)),
        }),
    }
}
