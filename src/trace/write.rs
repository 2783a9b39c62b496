//! The trace CSV writer: SI values in memory, display units (mm, mm/s) in the file, each
//! value the exact decimal of the one in memory (see [`super::decimal`]).

use std::io::Write;
use std::path::Path;

use super::decimal::push_shifted;
use super::{Signal, Trace, TraceError, Unit, unit};

/// How column `s` is written: (its header unit, the decimal shift from the in-memory value
/// to the file's). The display unit of its quantity when both it and the in-memory unit are
/// powers of ten of SI, so the shift is exact; otherwise its own unit, unshifted (a unit the
/// format does not know is written as it is, and the reader will refuse it).
fn column_out(s: &Signal) -> (&str, i32) {
    let Some(held) = unit(&s.unit) else {
        return (&s.unit, 0);
    };
    match (held.pow10, unit(held.quantity.display_unit())) {
        (Some(ph), Some(shown)) => match shown.pow10 {
            Some(pd) => (shown.name, ph - pd),
            None => (held.name, 0),
        },
        _ => (held.name, 0),
    }
}

impl Trace {
    /// Writes the trace as TRACE_FORMAT CSV: metadata lines, header in display units (mm,
    /// mm/s, SI for the rest), one row per sample, each value the shortest text that reads
    /// back as the same `f64`, missing samples as empty cells.
    pub fn write_csv_to<W: Write>(&self, mut w: W) -> std::io::Result<()> {
        for (k, v) in &self.meta {
            writeln!(w, "# {k}: {v}")?;
        }
        let mut cw = csv::Writer::from_writer(w);
        let outs: Vec<(&str, i32)> = self.signals.iter().map(column_out).collect();
        let header: Vec<String> = self
            .signals
            .iter()
            .zip(&outs)
            .map(|(s, (u, _))| format!("{}[{u}]", s.name))
            .collect();
        cw.write_record(&header)?;
        let mut buf = ryu::Buffer::new();
        let mut row: Vec<String> = vec![String::new(); self.signals.len()];
        for i in 0..self.len() {
            for ((cell, s), &(_, shift)) in row.iter_mut().zip(&self.signals).zip(&outs) {
                cell.clear();
                let v = s.data[i];
                if v.is_finite() {
                    push_shifted(cell, &mut buf, v, shift);
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

/// Appends the SI value `v_si` written in unit `u` to `out`, as the writer writes a cell:
/// for a power of ten of SI the exact decimal (ryu's shortest digits with the point moved),
/// which the reader turns back into `v_si` bit for bit; otherwise (mm/min) converted with
/// [`Unit::from_si`]. Nothing for a non-finite value (an empty cell, "not measured").
pub fn push_value(out: &mut String, v_si: f64, u: &Unit) {
    if !v_si.is_finite() {
        return;
    }
    let mut buf = ryu::Buffer::new();
    match u.pow10 {
        Some(k) => push_shifted(out, &mut buf, v_si, -k),
        None => {
            let v = (u.from_si)(v_si);
            if v.is_finite() {
                out.push_str(buf.format_finite(v));
            }
        }
    }
}
