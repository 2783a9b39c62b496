//! Traces: a columnar buffer of samples, each signal named with its unit, and the CSV format
//! of `shared/TRACE_FORMAT.md` shared by simulated and measured data.
//!
//! In memory every signal is held in one canonical unit per quantity (mm, s, mm/s, N, N*m,
//! A, degC), whatever unit the file used, so that code comparing a simulated and a measured
//! trace never converts. A missing sample ("not measured at this instant", an empty cell)
//! is held as NaN and written back as an empty cell; NaN never comes from a file.

use std::io::Write;
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    #[error("{file}: cannot read: {source}")]
    Read {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}: cannot write: {source}")]
    Write {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}:{line}: {reason}")]
    At {
        file: String,
        line: u64,
        reason: String,
    },
    #[error("{file}: {reason}")]
    Layout { file: String, reason: String },
    #[error("mapping '{entry}': {reason}")]
    Mapping { entry: String, reason: String },
}

#[derive(Debug, Clone, PartialEq)]
pub struct Signal {
    /// `t`, `mode`, `x.cmd`, `temp.x_screw`, …
    pub name: String,
    /// Canonical unit: mm, s, mm/s, N, N*m, A, degC, or "" for a plain number.
    pub unit: String,
    pub data: Vec<f64>,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trace {
    /// `# key: value` metadata lines, in file order.
    pub meta: Vec<(String, String)>,
    /// Column 0 is always `t` in s.
    pub signals: Vec<Signal>,
}

/// Maps an accepted unit to (canonical unit, factor to multiply by).
pub fn canonical_unit(unit: &str) -> Option<(&'static str, f64)> {
    Some(match unit {
        "m" => ("mm", 1e3),
        "mm" => ("mm", 1.0),
        "um" => ("mm", 1e-3),
        "s" => ("s", 1.0),
        "ms" => ("s", 1e-3),
        "m/s" => ("mm/s", 1e3),
        "mm/s" => ("mm/s", 1.0),
        "mm/min" => ("mm/s", 1.0 / 60.0),
        "N" => ("N", 1.0),
        "N*m" => ("N*m", 1.0),
        "A" => ("A", 1.0),
        "degC" => ("degC", 1.0),
        "" => ("", 1.0),
        _ => return None,
    })
}

/// Splits `x.cmd[mm]` into (`x.cmd`, `mm`); a name without brackets has unit "".
pub fn split_header(h: &str) -> Option<(&str, &str)> {
    let h = h.trim();
    match h.find('[') {
        Some(i) if h.ends_with(']') => Some((h[..i].trim(), &h[i + 1..h.len() - 1])),
        Some(_) => None,
        None => Some((h, "")),
    }
}

/// A column mapping for a foreign layout: `t[s]=t_s, x.cmd[m]=qg_m, x.force[N]=force_N*1`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Mapping {
    pub entries: Vec<MapEntry>,
}

#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MapEntry {
    /// Trace signal with the unit of the source column, e.g. `x.cmd[m]`.
    pub target: String,
    pub source: String,
    #[serde(default = "unit_scale")]
    pub scale: f64,
}

fn unit_scale() -> f64 {
    1.0
}

impl Mapping {
    /// Parses `target=source[*scale]` entries separated by commas or newlines.
    pub fn parse(text: &str) -> Result<Mapping, TraceError> {
        let mut entries = Vec::new();
        for raw in text.split([',', '\n']) {
            let e = raw.trim();
            if e.is_empty() || e.starts_with('#') {
                continue;
            }
            let bad = |reason: &str| TraceError::Mapping {
                entry: e.to_owned(),
                reason: reason.to_owned(),
            };
            let (target, src) = e
                .split_once('=')
                .ok_or_else(|| bad("expected target=source"))?;
            let (source, scale) = match src.split_once('*') {
                Some((s, k)) => (
                    s.trim(),
                    k.trim()
                        .parse::<f64>()
                        .ok()
                        .filter(|k| k.is_finite())
                        .ok_or_else(|| bad("scale after * must be a finite number"))?,
                ),
                None => (src.trim(), 1.0),
            };
            let (_, unit) = split_header(target).ok_or_else(|| bad("target must be name[unit]"))?;
            if canonical_unit(unit).is_none() {
                return Err(bad(&format!("unit '{unit}' is not accepted")));
            }
            entries.push(MapEntry {
                target: target.trim().to_owned(),
                source: source.to_owned(),
                scale,
            });
        }
        if entries.is_empty() {
            return Err(TraceError::Mapping {
                entry: text.to_owned(),
                reason: "no entries".into(),
            });
        }
        Ok(Mapping { entries })
    }
}

impl Trace {
    pub fn new() -> Trace {
        Trace {
            meta: vec![],
            signals: vec![Signal {
                name: "t".into(),
                unit: "s".into(),
                data: vec![],
            }],
        }
    }

    /// Adds an empty signal and returns its column index.
    pub fn add_signal(&mut self, name: &str, unit: &str) -> usize {
        self.signals.push(Signal {
            name: name.to_owned(),
            unit: unit.to_owned(),
            data: Vec::new(),
        });
        self.signals.len() - 1
    }

    pub fn len(&self) -> usize {
        self.signals.first().map_or(0, |s| s.data.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn t(&self) -> &[f64] {
        self.signals.first().map_or(&[], |s| &s.data)
    }

    pub fn signal(&self, name: &str) -> Option<&Signal> {
        self.signals.iter().find(|s| s.name == name)
    }

    pub fn values(&self, name: &str) -> Option<&[f64]> {
        self.signal(name).map(|s| s.data.as_slice())
    }

    pub fn meta(&self, key: &str) -> Option<&str> {
        self.meta
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// Axis names that have both `cmd` and `pos`.
    pub fn axes(&self) -> Vec<String> {
        self.signals
            .iter()
            .filter_map(|s| s.name.strip_suffix(".cmd"))
            .filter(|a| self.signal(&format!("{a}.pos")).is_some())
            .map(str::to_owned)
            .collect()
    }

    /// Drops all samples, keeping the columns (live plots reuse the buffer).
    pub fn clear(&mut self) {
        for s in &mut self.signals {
            s.data.clear();
        }
    }

    pub fn write_csv_to<W: Write>(&self, mut w: W) -> std::io::Result<()> {
        for (k, v) in &self.meta {
            writeln!(w, "# {k}: {v}")?;
        }
        let mut cw = csv::Writer::from_writer(w);
        let header: Vec<String> = self
            .signals
            .iter()
            .map(|s| format!("{}[{}]", s.name, s.unit))
            .collect();
        cw.write_record(&header)?;
        let mut buf = ryu::Buffer::new();
        let mut row: Vec<String> = vec![String::new(); self.signals.len()];
        for i in 0..self.len() {
            for (cell, s) in row.iter_mut().zip(&self.signals) {
                cell.clear();
                let v = s.data[i];
                if v.is_finite() {
                    cell.push_str(buf.format_finite(v));
                }
            }
            cw.write_record(&row)?;
        }
        cw.flush()?;
        Ok(())
    }

    /// Writes the CSV atomically: a crash mid-write never leaves a half file behind.
    pub fn write_csv(&self, path: &Path) -> Result<(), TraceError> {
        crate::fsutil::write_atomic_with(path, |w| self.write_csv_to(w)).map_err(|source| {
            TraceError::Write {
                file: path.display().to_string(),
                source,
            }
        })
    }

    pub fn read_csv(path: &Path, mapping: Option<&Mapping>) -> Result<Trace, TraceError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| TraceError::Read {
            file: file.clone(),
            source,
        })?;
        Trace::from_csv_str(&text, &file, mapping)
    }

    /// Parses trace CSV text. `file` names the source in every error.
    pub fn from_csv_str(
        text: &str,
        file: &str,
        mapping: Option<&Mapping>,
    ) -> Result<Trace, TraceError> {
        let at = |line: u64, reason: String| TraceError::At {
            file: file.to_owned(),
            line,
            reason,
        };
        let layout = |reason: String| TraceError::Layout {
            file: file.to_owned(),
            reason,
        };
        let mut meta = Vec::new();
        let mut body_start = 0;
        let mut meta_lines = 0u64;
        for line in text.split_inclusive('\n') {
            let l = line.trim();
            if !l.starts_with('#') {
                break;
            }
            if let Some((k, v)) = l.trim_start_matches('#').split_once(':') {
                meta.push((k.trim().to_owned(), v.trim().to_owned()));
            }
            body_start += line.len();
            meta_lines += 1;
        }
        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(true)
            .trim(csv::Trim::All)
            .from_reader(&text.as_bytes()[body_start..]);
        let headers = rdr
            .headers()
            .map_err(|e| at(meta_lines + 1, format!("bad header row: {e}")))?
            .clone();
        // (source column index, signal name, canonical unit, factor)
        let mut cols: Vec<(usize, String, &'static str, f64)> = Vec::new();
        let find = |src: &str| headers.iter().position(|h| h == src);
        match mapping {
            Some(m) => {
                for e in &m.entries {
                    let idx = find(&e.source).ok_or_else(|| {
                        layout(format!(
                            "mapping needs column '{}', which is not in the header (columns: {})",
                            e.source,
                            headers.iter().collect::<Vec<_>>().join(", ")
                        ))
                    })?;
                    let (name, unit) = split_header(&e.target).ok_or_else(|| {
                        layout(format!("mapping target '{}' must be name[unit]", e.target))
                    })?;
                    let (cu, f) = canonical_unit(unit)
                        .ok_or_else(|| layout(format!("unit '{unit}' is not accepted")))?;
                    cols.push((idx, name.to_owned(), cu, f * e.scale));
                }
            }
            None => {
                for (idx, h) in headers.iter().enumerate() {
                    let (name, unit) = split_header(h).ok_or_else(|| {
                        layout(format!(
                            "column {} header '{h}' is not signal[unit]",
                            idx + 1
                        ))
                    })?;
                    let (cu, f) = canonical_unit(unit).ok_or_else(|| {
                        layout(format!(
                            "column '{h}': unit '{unit}' is not accepted (m, mm, um, s, ms, m/s, mm/s, mm/min, N, N*m, A, degC)"
                        ))
                    })?;
                    cols.push((idx, name.to_owned(), cu, f));
                }
            }
        }
        for (i, c) in cols.iter().enumerate() {
            if cols[..i].iter().any(|d| d.1 == c.1) {
                return Err(layout(format!("signal '{}' appears twice", c.1)));
            }
        }
        let t_pos = cols
            .iter()
            .position(|c| c.1 == "t")
            .ok_or_else(|| layout("no time column t[s]".into()))?;
        if cols[t_pos].2 != "s" {
            return Err(layout("column t must be a time (s or ms)".into()));
        }
        cols.swap(0, t_pos);
        let mut signals: Vec<Signal> = cols
            .iter()
            .map(|c| Signal {
                name: c.1.clone(),
                unit: c.2.to_owned(),
                data: Vec::new(),
            })
            .collect();
        let mut rec = csv::StringRecord::new();
        let mut last_t = f64::NEG_INFINITY;
        loop {
            let more = rdr.read_record(&mut rec).map_err(|e| {
                let line = e.position().map_or(0, |p| p.line()) + meta_lines;
                at(line, format!("bad row: {e}"))
            })?;
            if !more {
                break;
            }
            let line = rec.position().map_or(0, |p| p.line()) + meta_lines;
            for (k, c) in cols.iter().enumerate() {
                let cell = rec.get(c.0).unwrap_or("");
                let v = if cell.is_empty() {
                    if k == 0 {
                        return Err(at(line, "time t is empty".into()));
                    }
                    f64::NAN
                } else {
                    let v: f64 = cell.parse().map_err(|_| {
                        at(
                            line,
                            format!(
                                "column '{}': '{cell}' is not a number",
                                headers.get(c.0).unwrap_or("")
                            ),
                        )
                    })?;
                    if !v.is_finite() {
                        return Err(at(
                            line,
                            format!(
                                "column '{}': '{cell}' is not a finite number",
                                headers.get(c.0).unwrap_or("")
                            ),
                        ));
                    }
                    v * c.3
                };
                signals[k].data.push(v);
            }
            let t = signals[0].data[signals[0].data.len() - 1];
            if t <= last_t {
                return Err(at(
                    line,
                    format!("time {t} s does not increase (previous row {last_t} s)"),
                ));
            }
            last_t = t;
        }
        let trace = Trace { meta, signals };
        if trace.is_empty() {
            return Err(layout("no data rows".into()));
        }
        if trace.axes().is_empty() {
            return Err(layout(
                "needs, for at least one axis, both <axis>.cmd and <axis>.pos columns".into(),
            ));
        }
        Ok(trace)
    }
}
