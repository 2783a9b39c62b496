//! The trace CSV reader: one streaming code path for files, byte slices and readers.
//!
//! Metadata lines are read first (each at most [`MAX_LINE_BYTES`]), then the `csv` crate
//! reads the header and the rows through a guard that refuses an over-long line. Cells are
//! checked as they come, bad rows collected; time stamps are checked once all are in, since
//! the jump rule needs the record's median spacing.

use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use super::{
    Finding, JUMP_FACTOR, JUMP_MIN_S, MAX_LINE_BYTES, MAX_META_LINES, MAX_REPORTED_ERRORS,
    MAX_TRACE_ROWS, MAX_TRACE_VALUES, Mapping, QUOTE_CHARS, Signal, Trace, TraceError, Unit,
    check_unit, decimal, quote, split_header,
};

/// The size limits of one read (the constants, or small ones in tests).
#[derive(Clone, Copy)]
struct Limits {
    max_rows: usize,
    max_values: usize,
}

const LIMITS: Limits = Limits {
    max_rows: MAX_TRACE_ROWS,
    max_values: MAX_TRACE_VALUES,
};

/// Steps sampled for the median spacing: enough for its value, bounded in memory.
const MEDIAN_SAMPLES: usize = 1 << 20;
/// The first allocation of a column, values.
const FIRST_CHUNK: usize = 1024;

impl Trace {
    /// Reads a trace CSV file, streaming (the file is never held whole in memory).
    pub fn read_csv(path: &Path, mapping: Option<&Mapping>) -> Result<Trace, TraceError> {
        let file = path.display().to_string();
        let f = std::fs::File::open(path).map_err(|source| TraceError::Read {
            file: file.clone(),
            source,
        })?;
        let size = f.metadata().ok().map(|m| m.len());
        read(BufReader::new(f), &file, mapping, size, LIMITS)
    }

    /// Parses trace CSV text. `file` names the source in every error.
    pub fn from_csv_str(
        text: &str,
        file: &str,
        mapping: Option<&Mapping>,
    ) -> Result<Trace, TraceError> {
        Trace::from_csv_bytes(text.as_bytes(), file, mapping)
    }

    /// Parses trace CSV bytes through the same path as files (the fuzzing entry point; the
    /// bytes need not be UTF-8, a cell that is not is an error naming its line).
    pub fn from_csv_bytes(
        bytes: &[u8],
        file: &str,
        mapping: Option<&Mapping>,
    ) -> Result<Trace, TraceError> {
        read(bytes, file, mapping, Some(bytes.len() as u64), LIMITS)
    }

    /// Reads trace CSV from any reader (a pipe, a decompressor), streaming.
    pub fn from_reader<R: Read>(
        r: R,
        file: &str,
        mapping: Option<&Mapping>,
    ) -> Result<Trace, TraceError> {
        read(BufReader::new(r), file, mapping, None, LIMITS)
    }
}

/// Passes bytes through to the CSV reader, refusing a line longer than [`MAX_LINE_BYTES`]
/// (so a file without line ends cannot grow one record without bound) and counting bytes
/// for the size estimate.
struct Guard<R> {
    inner: R,
    line_bytes: usize,
    lines: u64,
    bytes: u64,
    /// Line (from 1, counted from the header) that was too long.
    too_long: Option<u64>,
}

impl<R: Read> Read for Guard<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        for &c in buf.iter().take(n) {
            if c == b'\n' {
                self.lines += 1;
                self.line_bytes = 0;
            } else {
                self.line_bytes += 1;
                if self.line_bytes > MAX_LINE_BYTES {
                    self.too_long = Some(self.lines + 1);
                    return Err(std::io::Error::new(
                        std::io::ErrorKind::InvalidData,
                        "line too long",
                    ));
                }
            }
        }
        self.bytes += n as u64;
        Ok(n)
    }
}

/// Findings in line order: the first [`MAX_REPORTED_ERRORS`] kept, all counted.
#[derive(Default)]
struct Findings {
    kept: Vec<Finding>,
    total: usize,
}

impl Findings {
    fn push(&mut self, line: u64, reason: String) {
        self.total += 1;
        if self.kept.len() < MAX_REPORTED_ERRORS {
            self.kept.push(Finding { line, reason });
        }
    }

    /// Both lists merged in line order (each is in line order already).
    fn merge(self, other: Findings) -> Findings {
        let mut all = self.kept;
        all.extend(other.kept);
        all.sort_by_key(|f| f.line);
        all.truncate(MAX_REPORTED_ERRORS);
        Findings {
            kept: all,
            total: self.total + other.total,
        }
    }
}

/// File line of each data row, stored as the few rows where the lines stop running one per
/// row (blank lines, quoted line ends), so it costs nothing for an ordinary file.
#[derive(Default)]
struct LineMap {
    anchors: Vec<(usize, u64)>,
}

impl LineMap {
    fn line(&self, row: usize) -> u64 {
        let k = self.anchors.partition_point(|a| a.0 <= row);
        match k.checked_sub(1).and_then(|j| self.anchors.get(j)) {
            Some(&(r, l)) => l + (row - r) as u64,
            None => 0,
        }
    }

    /// Records that `row` (the next one) is at `line`.
    fn push(&mut self, row: usize, line: u64) {
        let expected = self.anchors.last().map(|&(r, l)| l + (row - r) as u64);
        if expected != Some(line) {
            self.anchors.push((row, line));
        }
    }
}

/// One stored column: where it comes from and how it converts.
struct Col {
    /// Index in the file's header.
    src: usize,
    /// Trace signal name.
    name: String,
    unit: &'static Unit,
    /// Mapping scale (1 for TRACE_FORMAT files).
    scale: f64,
    /// `column 3 'x.pos[mm]'`, for messages.
    label: String,
}

/// The whole reader, on any buffered source; `size` (when known) only feeds the estimate of
/// a too-large file.
fn read<R: BufRead>(
    mut r: R,
    file: &str,
    mapping: Option<&Mapping>,
    size: Option<u64>,
    limits: Limits,
) -> Result<Trace, TraceError> {
    let at = |line: u64, reason: String| TraceError::At {
        file: file.to_owned(),
        line,
        reason,
    };
    if r.fill_buf()
        .map_err(|e| at(1, format!("cannot read: {e}")))?
        .starts_with(b"\xEF\xBB\xBF")
    {
        r.consume(3);
    }
    let (meta, meta_lines) = read_meta(&mut r, &at)?;
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(Guard {
            inner: r,
            line_bytes: 0,
            lines: 0,
            bytes: 0,
            too_long: None,
        });
    let header_line = meta_lines + 1;
    let headers = match rdr.headers() {
        Ok(h) => h.clone(),
        Err(e) => return Err(at(header_line, read_error(&e, rdr.get_ref(), meta_lines).1)),
    };
    let cols = columns(&headers, mapping, file)?;
    let source = Source {
        file,
        meta_lines,
        size,
        limits,
    };
    let rows = read_rows(&mut rdr, &cols, headers.len(), &source)?;
    let time = check_times(&rows.signals[0].data, &rows.lines);
    let found = rows.found.merge(time);
    if found.total > 0 {
        return Err(TraceError::Rows {
            file: file.to_owned(),
            omitted: found.total - found.kept.len(),
            findings: found.kept,
        });
    }
    let layout = |reason: &str| TraceError::Layout {
        file: file.to_owned(),
        reason: reason.to_owned(),
    };
    let trace = Trace {
        meta,
        signals: rows.signals,
    };
    if trace.is_empty() {
        return Err(layout("no data rows"));
    }
    if trace.axes().is_empty() {
        return Err(layout(
            "needs, for at least one axis, both <axis>.cmd and <axis>.pos columns",
        ));
    }
    Ok(trace)
}

/// (file line, reason) of an error from the CSV reader.
fn read_error<R>(e: &csv::Error, guard: &Guard<R>, meta_lines: u64) -> (u64, String) {
    if let Some(l) = guard.too_long {
        return (
            l + meta_lines,
            format!("line longer than {MAX_LINE_BYTES} bytes (MAX_LINE_BYTES)"),
        );
    }
    let line = e.position().map_or(guard.lines + 1, |p| p.line()) + meta_lines;
    (line, format!("cannot read: {e}"))
}

/// Reads the `# key: value` lines before the header. Returns them and their count.
fn read_meta<R: BufRead>(
    r: &mut R,
    at: &dyn Fn(u64, String) -> TraceError,
) -> Result<(Vec<(String, String)>, u64), TraceError> {
    let mut meta = Vec::new();
    let mut n = 0u64;
    let mut buf = Vec::new();
    loop {
        let peek = r
            .fill_buf()
            .map_err(|e| at(n + 1, format!("cannot read: {e}")))?;
        if peek.iter().find(|c| !matches!(c, b' ' | b'\t')) != Some(&b'#') {
            return Ok((meta, n));
        }
        n += 1;
        if n > MAX_META_LINES as u64 {
            return Err(at(
                n,
                format!("more than {MAX_META_LINES} metadata lines (MAX_META_LINES)"),
            ));
        }
        buf.clear();
        r.by_ref()
            .take(MAX_LINE_BYTES as u64 + 1)
            .read_until(b'\n', &mut buf)
            .map_err(|e| at(n, format!("cannot read: {e}")))?;
        if buf.len() > MAX_LINE_BYTES {
            return Err(at(
                n,
                format!("line longer than {MAX_LINE_BYTES} bytes (MAX_LINE_BYTES)"),
            ));
        }
        let line = std::str::from_utf8(&buf)
            .map_err(|_| at(n, "metadata line is not UTF-8 text".into()))?
            .trim();
        if let Some((k, v)) = line.trim_start_matches('#').split_once(':') {
            meta.push((k.trim().to_owned(), v.trim().to_owned()));
        }
    }
}

/// The stored columns, `t` first: from the mapping, or from the file's own header. Every
/// unit must be accepted and fit its signal.
fn columns(
    headers: &csv::StringRecord,
    mapping: Option<&Mapping>,
    file: &str,
) -> Result<Vec<Col>, TraceError> {
    let layout = |reason: String| TraceError::Layout {
        file: file.to_owned(),
        reason,
    };
    let label = |idx: usize, h: &str| format!("column {} '{}'", idx + 1, quote(h, QUOTE_CHARS));
    let mut cols: Vec<Col> = Vec::new();
    match mapping {
        Some(m) => {
            for e in &m.entries {
                let idx = headers.iter().position(|h| h == e.source).ok_or_else(|| {
                    let all: Vec<&str> = headers.iter().collect();
                    layout(format!(
                        "mapping needs column '{}', which is not in the header (columns: {})",
                        quote(&e.source, QUOTE_CHARS),
                        quote(&all.join(", "), 400)
                    ))
                })?;
                let (name, unit) = split_header(&e.target).ok_or_else(|| {
                    layout(format!(
                        "mapping target '{}' must be name[unit]",
                        quote(&e.target, QUOTE_CHARS)
                    ))
                })?;
                let unit = check_unit(name, unit)
                    .map_err(|r| layout(format!("mapping target '{}': {r}", e.target)))?;
                cols.push(Col {
                    src: idx,
                    name: name.to_owned(),
                    unit,
                    scale: e.scale,
                    label: label(idx, &e.source),
                });
            }
        }
        None => {
            // A header without t[s], or with a column that is not signal[unit], is another
            // layout, not a broken trace: say so with its columns, so a caller can name the
            // mapping that reads it.
            let native = headers
                .iter()
                .any(|h| split_header(h).is_some_and(|(n, _)| n == "t"))
                && headers.iter().all(|h| split_header(h).is_some());
            if !native {
                return Err(TraceError::Foreign {
                    file: file.to_owned(),
                    columns: headers.iter().map(str::to_owned).collect(),
                });
            }
            for (idx, h) in headers.iter().enumerate() {
                let (name, unit) = split_header(h)
                    .ok_or_else(|| layout(format!("{} is not signal[unit]", label(idx, h))))?;
                let unit = check_unit(name, unit)
                    .map_err(|r| layout(format!("{}: {r}", label(idx, h))))?;
                cols.push(Col {
                    src: idx,
                    name: name.to_owned(),
                    unit,
                    scale: 1.0,
                    label: label(idx, h),
                });
            }
        }
    }
    for (i, c) in cols.iter().enumerate() {
        if cols[..i].iter().any(|d| d.name == c.name) {
            return Err(layout(format!(
                "signal '{}' appears twice",
                quote(&c.name, QUOTE_CHARS)
            )));
        }
    }
    let t = cols
        .iter()
        .position(|c| c.name == "t")
        .ok_or_else(|| layout("no time column t[s]".into()))?;
    cols.swap(0, t);
    Ok(cols)
}

/// What the row pass produced.
struct Rows {
    signals: Vec<Signal>,
    lines: LineMap,
    found: Findings,
}

/// Where the rows come from, for messages and limits.
struct Source<'a> {
    file: &'a str,
    meta_lines: u64,
    size: Option<u64>,
    limits: Limits,
}

/// Reads every data row, checking each cell; refuses past the row limit.
fn read_rows<R: Read>(
    rdr: &mut csv::Reader<Guard<R>>,
    cols: &[Col],
    n_header: usize,
    src: &Source<'_>,
) -> Result<Rows, TraceError> {
    let (file, meta_lines) = (src.file, src.meta_lines);
    let max_rows = src
        .limits
        .max_rows
        .min(src.limits.max_values / cols.len().max(1));
    let mut signals: Vec<Signal> = cols
        .iter()
        .map(|c| Signal {
            name: c.name.clone(),
            unit: c.unit.si().to_owned(),
            data: Vec::new(),
        })
        .collect();
    let mut lines = LineMap::default();
    let mut found = Findings::default();
    let mut rec = csv::ByteRecord::new();
    let mut buf = String::new();
    loop {
        match rdr.read_byte_record(&mut rec) {
            Ok(true) => {}
            Ok(false) => break,
            Err(e) => {
                let (line, reason) = read_error(&e, rdr.get_ref(), meta_lines);
                return Err(TraceError::At {
                    file: file.to_owned(),
                    line,
                    reason,
                });
            }
        }
        let row = signals[0].data.len();
        if row >= max_rows {
            return Err(too_large(src, max_rows, cols.len(), rdr.get_ref().bytes));
        }
        let line = rec.position().map_or(0, |p| p.line()) + meta_lines;
        lines.push(row, line);
        if rec.len() != n_header {
            found.push(
                line,
                format!("the row has {} cells; the header has {n_header}", rec.len()),
            );
        }
        for (k, c) in cols.iter().enumerate() {
            let v = cell_value(rec.get(c.src), c, k == 0, &mut buf).unwrap_or_else(|reason| {
                found.push(line, reason);
                f64::NAN
            });
            push_bounded(&mut signals[k].data, v, max_rows);
        }
    }
    Ok(Rows {
        signals,
        lines,
        found,
    })
}

/// Appends with growth of a quarter (not the doubling of `Vec::push`), so a trace near the
/// limit does not reserve twice its size.
fn push_bounded(v: &mut Vec<f64>, x: f64, max: usize) {
    if v.len() == v.capacity() {
        let extra = (v.len() / 4)
            .max(FIRST_CHUNK)
            .min(max.saturating_sub(v.len()))
            .max(1);
        v.reserve_exact(extra);
    }
    v.push(x);
}

/// The refusal of a file with more rows than a trace may hold, with the estimate.
fn too_large(src: &Source<'_>, max_rows: usize, n_cols: usize, read: u64) -> TraceError {
    let estimate = match src.size {
        Some(s) if read > 0 => format!(
            "; by its size, about {} rows",
            (s as f64 / read as f64 * max_rows as f64).round()
        ),
        _ => String::new(),
    };
    let Limits {
        max_rows: rows_limit,
        max_values,
    } = src.limits;
    TraceError::TooLarge {
        file: src.file.to_owned(),
        reason: format!(
            "more than {max_rows} data rows of {n_cols} signals{estimate}; the limit is {max_rows} rows here (MAX_TRACE_ROWS = {rows_limit}, MAX_TRACE_VALUES = {max_values} values of rows × signals); read a shorter span, or fewer columns through a mapping"
        ),
    }
}

/// One cell in SI: empty is NaN ("not measured"), except for `t`; text, NaN and inf are
/// errors naming the column. A unit that is a power of ten of SI has its decimal exponent
/// moved in the text (in `buf`, reused across cells) before the one correctly rounded parse,
/// so a value the writer wrote reads back bit for bit; other units convert numerically.
fn cell_value(cell: Option<&[u8]>, c: &Col, is_t: bool, buf: &mut String) -> Result<f64, String> {
    let cell = cell.unwrap_or_default();
    if cell.is_empty() {
        return if is_t {
            Err(format!("{}: time t is empty", c.label))
        } else {
            Ok(f64::NAN)
        };
    }
    let text = std::str::from_utf8(cell)
        .map_err(|_| format!("{}: the cell is not UTF-8 text", c.label))?;
    let shown = || quote(text, QUOTE_CHARS);
    let not_a_number = || format!("{}: '{}' is not a number", c.label, shown());
    let v: f64 = match c.unit.pow10 {
        Some(0) => text.parse().map_err(|_| not_a_number())?,
        // The rewritten text parses exactly when the cell is a decimal number; anything else
        // (inf, text) is parsed as written, for its own message.
        Some(k) => match decimal::shift_text(text, k, buf).and_then(|t| t.parse().ok()) {
            Some(v) => v,
            None => (c.unit.to_si)(text.parse().map_err(|_| not_a_number())?),
        },
        None => (c.unit.to_si)(text.parse().map_err(|_| not_a_number())?),
    };
    if !v.is_finite() {
        return Err(format!("{}: '{}' is not a finite number", c.label, shown()));
    }
    let x = if c.scale == 1.0 { v } else { v * c.scale };
    if !x.is_finite() {
        return Err(format!(
            "{}: '{}' is out of range in {}",
            c.label,
            shown(),
            c.unit.si()
        ));
    }
    Ok(x)
}

/// A number for a message: plain when it reads well, in exponent form when tiny or huge.
fn num(v: f64) -> String {
    if v == 0.0 || (1.0e-4..1.0e9).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// A derived number (a step, a median) for a message, to 6 significant digits.
fn num6(v: f64) -> String {
    num(format!("{v:.5e}").parse().unwrap_or(v))
}

/// The median of the time steps (sampled when there are many), s; 0 without steps.
fn median_step(t: &[f64]) -> f64 {
    let stride = t.len().div_ceil(MEDIAN_SAMPLES).max(1);
    let mut steps: Vec<f64> = t
        .windows(2)
        .step_by(stride)
        .map(|w| w[1] - w[0])
        .filter(|d| d.is_finite())
        .collect();
    if steps.is_empty() {
        return 0.0;
    }
    let mid = steps.len() / 2;
    let (_, m, _) = steps.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

/// The time rules: each step from the row before must be positive, and not a jump — more
/// than [`JUMP_FACTOR`] × the median step and more than [`JUMP_MIN_S`]. A single wild time
/// stamp shows as the jump into it and the step back from it, both naming its value.
/// Rows whose time cell was bad (NaN here) are already reported and skipped.
fn check_times(t: &[f64], lines: &LineMap) -> Findings {
    let median = median_step(t);
    let jump_s = (JUMP_FACTOR * median).max(JUMP_MIN_S);
    let mut found = Findings::default();
    for (i, w) in t.windows(2).enumerate() {
        let (a, b) = (w[0], w[1]);
        if a.is_nan() || b.is_nan() {
            continue;
        }
        let (prev, line) = (lines.line(i), lines.line(i + 1));
        let d = b - a;
        if d <= 0.0 {
            found.push(
                line,
                format!(
                    "time {} s does not increase (line {prev}: {} s)",
                    num(b),
                    num(a)
                ),
            );
        } else if d > jump_s {
            found.push(
                line,
                format!(
                    "time {} s jumps {} s after line {prev} ({} s): more than {JUMP_FACTOR} × the median spacing {} s and more than {JUMP_MIN_S} s",
                    num(b),
                    num6(d),
                    num(a),
                    num6(median)
                ),
            );
        }
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(n: usize) -> String {
        let mut s = String::from("t[s],x.cmd[mm],x.pos[mm]\n");
        for i in 0..n {
            s += &format!("{},0,0\n", i as f64 * 0.001);
        }
        s
    }

    fn small(text: &str, max_rows: usize, max_values: usize) -> Result<Trace, TraceError> {
        let limits = Limits {
            max_rows,
            max_values,
        };
        read(
            text.as_bytes(),
            "big.csv",
            None,
            Some(text.len() as u64),
            limits,
        )
    }

    #[test]
    fn the_row_limit_refuses_with_the_estimate() {
        let text = rows(1000);
        assert_eq!(small(&text, 1000, 3000).map(|t| t.len()).ok(), Some(1000));
        let e = small(&text, 100, 3000).expect_err("over the row limit");
        let msg = e.to_string();
        assert!(matches!(e, TraceError::TooLarge { .. }), "{msg}");
        assert!(
            msg.contains("more than 100 data rows of 3 signals")
                && msg.contains("MAX_TRACE_ROWS = 100")
                && msg.contains("about "),
            "{msg}"
        );
        // The value limit binds with more columns: 300 values / 3 signals = 100 rows.
        let e = small(&text, 1000, 300).expect_err("over the value limit");
        assert!(e.to_string().contains("more than 100 data rows"), "{e}");
    }

    #[test]
    fn columns_grow_by_a_quarter_not_double() {
        let mut v = Vec::new();
        for i in 0..100_000 {
            push_bounded(&mut v, i as f64, 100_000);
        }
        assert!(v.capacity() <= 100_000, "capacity {}", v.capacity());
        let mut v = Vec::new();
        for i in 0..50_000 {
            push_bounded(&mut v, i as f64, usize::MAX);
        }
        assert!(
            v.capacity() < 50_000 * 5 / 4 + FIRST_CHUNK,
            "capacity {}",
            v.capacity()
        );
    }

    #[test]
    fn line_map_follows_blank_lines() {
        let mut m = LineMap::default();
        for (row, line) in [(0, 2), (1, 3), (2, 5), (3, 6), (4, 9)] {
            m.push(row, line);
        }
        let lines: Vec<u64> = (0..5).map(|r| m.line(r)).collect();
        assert_eq!(lines, vec![2, 3, 5, 6, 9]);
        assert_eq!(m.anchors.len(), 3);
    }
}
