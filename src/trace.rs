//! Traces: a columnar buffer of samples, each signal named with its unit, and the CSV format
//! of `shared/TRACE_FORMAT.md` shared by simulated and measured data.
//!
//! In memory every signal is held in one canonical unit per quantity (mm, s, mm/s, N, N*m,
//! A, degC), whatever unit the file used, so that code comparing a simulated and a measured
//! trace never converts. A missing sample ("not measured at this instant", an empty cell)
//! is held as NaN and written back as an empty cell; NaN never comes from a file.
//!
//! Reading checks what the format promises: a unit that measures what its signal means
//! ([`expected_quantities`]), finite numbers, and time stamps that increase without a wild
//! jump ([`JUMP_FACTOR`], [`JUMP_MIN_S`]). Every bad row is counted and the first
//! [`MAX_REPORTED_ERRORS`] are reported in one [`TraceError::Rows`]. The reader streams: it
//! holds one row at a time besides the signals, a line is at most [`MAX_LINE_BYTES`], and a
//! trace at most [`MAX_TRACE_ROWS`] rows and [`MAX_TRACE_VALUES`] values, so no file makes it
//! allocate beyond about 1 GB.

use std::io::Write;
use std::path::Path;

use crate::units;

mod read;

/// Most data rows a trace may have: 20 M rows are 5.5 h at 1 kHz, 42 min at 8 kHz.
pub const MAX_TRACE_ROWS: usize = 20_000_000;
/// Most values (rows × stored signals) a trace may hold: 100 M f64 are 800 MB, about 1 GB
/// with the reader's growth slack (a quarter), so a trace fits well under 2 GB.
pub const MAX_TRACE_VALUES: usize = 100_000_000;
/// Longest line (metadata, header or row) the reader takes, bytes.
pub const MAX_LINE_BYTES: usize = 1024 * 1024;
/// Most `#` metadata lines before the header.
pub const MAX_META_LINES: usize = 10_000;
/// Row errors carried by one [`TraceError::Rows`]; the rest are counted. Keeps a file with a
/// million bad rows from printing megabytes.
pub const MAX_REPORTED_ERRORS: usize = 20;
/// A time step is a jump (an error) when it is more than this many times the record's median
/// spacing …
pub const JUMP_FACTOR: f64 = 1000.0;
/// … and more than this, s. A logger pausing a few ms, or a 10 Hz record with a 2 s gap, is
/// not refused; a time stamp of 1e17 s in a 1 kHz record is.
pub const JUMP_MIN_S: f64 = 1.0;

/// Budget of the rendered text of [`TraceError::Rows`], bytes.
const DISPLAY_BUDGET: usize = 3_600;
/// Longest piece of file text quoted in a message, characters.
const QUOTE_CHARS: usize = 40;

/// Why a trace could not be read or written. Every variant names the file; row problems name
/// the line (and the column, in the reason).
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    /// The file could not be opened or read.
    #[error("{file}: cannot read: {source}")]
    Read {
        /// The file.
        file: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file could not be written.
    #[error("{file}: cannot write: {source}")]
    Write {
        /// The file.
        file: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A problem at one line that stops reading (metadata, header, a line too long).
    #[error("{file}:{line}: {reason}")]
    At {
        /// The file.
        file: String,
        /// Line, from 1.
        line: u64,
        /// What is wrong.
        reason: String,
    },
    /// Problems in data rows (cells, time stamps): the first [`MAX_REPORTED_ERRORS`] in line
    /// order, and how many more there were. Shown one per line, under 4,000 characters.
    #[error("{}", render_rows(.file, .findings, *.omitted))]
    Rows {
        /// The file.
        file: String,
        /// The findings carried, in line order.
        findings: Vec<Finding>,
        /// Findings beyond those carried.
        omitted: usize,
    },
    /// The columns do not make a trace (no time, no cmd/pos pair, a unit that does not fit).
    #[error("{file}: {reason}")]
    Layout {
        /// The file.
        file: String,
        /// What is wrong.
        reason: String,
    },
    /// The file is larger than a trace may be ([`MAX_TRACE_ROWS`], [`MAX_TRACE_VALUES`]).
    #[error("{file}: {reason}")]
    TooLarge {
        /// The file.
        file: String,
        /// The estimate and the limit.
        reason: String,
    },
    /// A mapping entry is malformed.
    #[error("mapping '{entry}': {reason}")]
    Mapping {
        /// The entry as written.
        entry: String,
        /// What is wrong.
        reason: String,
    },
}

/// One problem in a data row.
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    /// Line in the file, from 1.
    pub line: u64,
    /// What is wrong, naming the column where there is one.
    pub reason: String,
}

fn render_rows(file: &str, findings: &[Finding], omitted: usize) -> String {
    let file = quote(file, 80);
    let mut out = String::new();
    let mut shown = 0;
    for f in findings {
        let line = format!("{file}:{}: {}", f.line, quote(&f.reason, 240));
        if shown > 0 && out.len() + line.len() + 1 > DISPLAY_BUDGET {
            break;
        }
        if shown > 0 {
            out.push('\n');
        }
        out.push_str(&line);
        shown += 1;
    }
    let rest = findings.len() - shown + omitted;
    if rest > 0 {
        out.push_str(&format!(
            "\n… and {rest} more rows in error ({} in all)",
            findings.len() + omitted
        ));
    }
    out
}

/// `s`, cut to `max` characters with an ellipsis, for quoting file text in a message.
fn quote(s: &str, max: usize) -> String {
    match s.char_indices().nth(max) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_owned(),
    }
}

/// What a unit measures. A signal's unit must measure what the signal means: `x.pos[mm/s]`
/// is a velocity where a length is meant, and is refused rather than silently mis-scaled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// m, mm, um.
    Length,
    /// s, ms.
    Time,
    /// m/s, mm/s, mm/min.
    Velocity,
    /// N.
    Force,
    /// N*m.
    Torque,
    /// A.
    Current,
    /// degC.
    Temperature,
    /// No unit: counts, modes, ratios.
    Plain,
}

impl Quantity {
    /// The name used in messages.
    pub fn name(self) -> &'static str {
        match self {
            Quantity::Length => "a length",
            Quantity::Time => "a time",
            Quantity::Velocity => "a velocity",
            Quantity::Force => "a force",
            Quantity::Torque => "a torque",
            Quantity::Current => "a current",
            Quantity::Temperature => "a temperature",
            Quantity::Plain => "a plain number",
        }
    }
}

/// An accepted unit: what it measures, the canonical unit a trace holds it in, and the
/// conversion into that unit (a named helper from [`crate::units`], never a bare factor).
#[derive(Debug, Clone, Copy)]
pub struct Unit {
    /// As written in a header, e.g. `mm/min`.
    pub name: &'static str,
    /// What it measures.
    pub quantity: Quantity,
    /// The unit held in memory, e.g. `mm/s`.
    pub canonical: &'static str,
    /// Value in this unit → value in the canonical unit.
    pub to_canonical: fn(f64) -> f64,
}

fn same(v: f64) -> f64 {
    v
}

/// Every unit TRACE_FORMAT accepts.
pub const UNITS: &[Unit] = &[
    Unit {
        name: "m",
        quantity: Quantity::Length,
        canonical: "mm",
        to_canonical: units::m_to_mm,
    },
    Unit {
        name: "mm",
        quantity: Quantity::Length,
        canonical: "mm",
        to_canonical: same,
    },
    Unit {
        name: "um",
        quantity: Quantity::Length,
        canonical: "mm",
        to_canonical: units::um_to_mm,
    },
    Unit {
        name: "s",
        quantity: Quantity::Time,
        canonical: "s",
        to_canonical: same,
    },
    Unit {
        name: "ms",
        quantity: Quantity::Time,
        canonical: "s",
        to_canonical: units::ms_to_s,
    },
    Unit {
        name: "m/s",
        quantity: Quantity::Velocity,
        canonical: "mm/s",
        to_canonical: units::m_per_s_to_mm_per_s,
    },
    Unit {
        name: "mm/s",
        quantity: Quantity::Velocity,
        canonical: "mm/s",
        to_canonical: same,
    },
    Unit {
        name: "mm/min",
        quantity: Quantity::Velocity,
        canonical: "mm/s",
        to_canonical: units::mm_per_min_to_mm_per_s,
    },
    Unit {
        name: "N",
        quantity: Quantity::Force,
        canonical: "N",
        to_canonical: same,
    },
    Unit {
        name: "N*m",
        quantity: Quantity::Torque,
        canonical: "N*m",
        to_canonical: same,
    },
    Unit {
        name: "A",
        quantity: Quantity::Current,
        canonical: "A",
        to_canonical: same,
    },
    Unit {
        name: "degC",
        quantity: Quantity::Temperature,
        canonical: "degC",
        to_canonical: same,
    },
    Unit {
        name: "",
        quantity: Quantity::Plain,
        canonical: "",
        to_canonical: same,
    },
];

/// The accepted unit called `name`, if any.
pub fn unit(name: &str) -> Option<&'static Unit> {
    UNITS.iter().find(|u| u.name == name)
}

/// The units of one quantity, for messages: "m, mm, um".
fn unit_names(q: Quantity) -> String {
    UNITS
        .iter()
        .filter(|u| u.quantity == q)
        .map(|u| if u.name.is_empty() { "none" } else { u.name })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The accepted units, for messages.
fn all_unit_names() -> String {
    UNITS
        .iter()
        .filter(|u| !u.name.is_empty())
        .map(|u| u.name)
        .collect::<Vec<_>>()
        .join(", ")
}

use Quantity::{Current, Force, Length, Plain, Temperature, Time, Torque, Velocity};

/// The known axis signals (`<axis>.<signal>`) and what their unit must measure. The
/// quadrant compensation is injected as a torque, a velocity or a position, so it may be any
/// of the three.
const AXIS_SIGNALS: &[(&str, &[Quantity])] = &[
    ("cmd", &[Length]),
    ("cmd_comp", &[Length]),
    ("comp", &[Length]),
    ("motor_pos", &[Length]),
    ("pos", &[Length]),
    ("err", &[Length]),
    ("ferr", &[Length]),
    ("vel", &[Velocity]),
    ("torque_cmd", &[Torque]),
    ("torque", &[Torque]),
    ("force", &[Force]),
    ("friction", &[Force]),
    ("gap", &[Length]),
    ("thermal", &[Length]),
    ("lead_err", &[Length]),
    ("sag", &[Length]),
    ("current", &[Current]),
    ("backlash_comp", &[Length]),
    ("quadrant_comp", &[Torque, Velocity, Length]),
    ("thermal_comp", &[Length]),
    ("cross_comp", &[Length]),
    ("meas", &[Length]),
];

/// What the unit of signal `name` must measure: `t` a time, `mode` (and `mode.<channel>`)
/// nothing, `temp.<name>` a temperature, `<axis>.<signal>` per the table of known axis
/// signals. None for a signal this table does not know, which keeps any accepted unit.
pub fn expected_quantities(name: &str) -> Option<&'static [Quantity]> {
    if name == "t" {
        return Some(&[Time]);
    }
    if name == "mode" || name.starts_with("mode.") {
        return Some(&[Plain]);
    }
    if name.starts_with("temp.") {
        return Some(&[Temperature]);
    }
    let (_, signal) = name.split_once('.')?;
    AXIS_SIGNALS
        .iter()
        .find(|(s, _)| *s == signal)
        .map(|(_, q)| *q)
}

/// Checks that unit `unit_name` is accepted and fits signal `name`; the reason when not.
pub fn check_unit(name: &str, unit_name: &str) -> Result<&'static Unit, String> {
    let u = unit(unit_name).ok_or_else(|| {
        format!(
            "unit '{}' is not accepted ({})",
            quote(unit_name, QUOTE_CHARS),
            all_unit_names()
        )
    })?;
    match expected_quantities(name) {
        Some(qs) if !qs.contains(&u.quantity) => {
            let want: Vec<String> = qs
                .iter()
                .map(|q| format!("{} ({})", q.name(), unit_names(*q)))
                .collect();
            Err(format!(
                "{} is {}, not {} ('{}')",
                quote(name, QUOTE_CHARS),
                want.join(" or "),
                u.quantity.name(),
                u.name
            ))
        }
        _ => Ok(u),
    }
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

/// One recorded signal: its samples in the canonical unit of its quantity.
#[derive(Debug, Clone, PartialEq)]
pub struct Signal {
    /// `t`, `mode`, `x.cmd`, `temp.x_screw`, …
    pub name: String,
    /// Canonical unit: mm, s, mm/s, N, N*m, A, degC, or "" for a plain number.
    pub unit: String,
    /// One value per row; NaN where the row did not measure it.
    pub data: Vec<f64>,
}

/// A time series of one run, simulated or measured, with its metadata.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trace {
    /// `# key: value` metadata lines, in file order.
    pub meta: Vec<(String, String)>,
    /// Column 0 is always `t` in s.
    pub signals: Vec<Signal>,
}

/// A column mapping for a foreign layout: `t[s]=t_s, x.cmd[m]=qg_m, x.force[N]=force_N*1`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Mapping {
    /// One entry per trace signal read.
    pub entries: Vec<MapEntry>,
}

/// One signal of a foreign layout: which source column, in which unit, times what.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MapEntry {
    /// Trace signal with the unit of the source column, e.g. `x.cmd[m]`.
    pub target: String,
    /// The source column's header.
    pub source: String,
    /// Factor applied to the source value before the unit conversion (e.g. N per V).
    #[serde(default = "unit_scale")]
    pub scale: f64,
}

fn unit_scale() -> f64 {
    1.0
}

impl Mapping {
    /// Parses `target=source[*scale]` entries separated by commas or newlines. Each target's
    /// unit must be accepted and fit its signal.
    pub fn parse(text: &str) -> Result<Mapping, TraceError> {
        let mut entries = Vec::new();
        for raw in text.split([',', '\n']) {
            let e = raw.trim();
            if e.is_empty() || e.starts_with('#') {
                continue;
            }
            let bad = |reason: &str| TraceError::Mapping {
                entry: quote(e, QUOTE_CHARS),
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
            let (name, unit) =
                split_header(target).ok_or_else(|| bad("target must be name[unit]"))?;
            check_unit(name, unit).map_err(|r| bad(&r))?;
            entries.push(MapEntry {
                target: target.trim().to_owned(),
                source: source.to_owned(),
                scale,
            });
        }
        if entries.is_empty() {
            return Err(TraceError::Mapping {
                entry: quote(text, QUOTE_CHARS),
                reason: "no entries".into(),
            });
        }
        Ok(Mapping { entries })
    }
}

impl Trace {
    /// An empty trace with only its time column, ready for [`Trace::add_signal`].
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

    /// Number of rows (samples of `t`).
    pub fn len(&self) -> usize {
        self.signals.first().map_or(0, |s| s.data.len())
    }

    /// True without rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The time column, s.
    pub fn t(&self) -> &[f64] {
        self.signals.first().map_or(&[], |s| &s.data)
    }

    /// The signal called `name` (without unit), if recorded.
    pub fn signal(&self, name: &str) -> Option<&Signal> {
        self.signals.iter().find(|s| s.name == name)
    }

    /// The samples of signal `name`, in its canonical unit.
    pub fn values(&self, name: &str) -> Option<&[f64]> {
        self.signal(name).map(|s| s.data.as_slice())
    }

    /// The value of metadata `key`, if the file had it.
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

    /// Writes the trace as TRACE_FORMAT CSV: metadata lines, header, one row per sample,
    /// shortest round-trip numbers, missing samples as empty cells.
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
}
