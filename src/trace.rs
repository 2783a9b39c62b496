//! Traces: a columnar buffer of samples, each signal named with its unit, and the CSV format
//! of `shared/TRACE_FORMAT.md` shared by simulated and measured data.
//!
//! In memory every signal is held in SI (m, s, m/s, N, N*m, A, degC), whatever unit the file
//! used, so that code comparing a simulated and a measured trace, or feeding a record to the
//! model, never converts. Files are written in display units (mm, mm/s; SI for the rest) by
//! shifting the decimal point of the shortest round-trip text, and read back by shifting it
//! again, so a trace written and read is the same trace bit for bit. A missing sample ("not measured at this instant", an empty cell)
//! is held as NaN and written back as an empty cell; NaN never comes from a file.
//!
//! Reading checks what the format promises: a unit that measures what its signal means
//! ([`expected_quantities`]), finite numbers, and time stamps that increase without a wild
//! jump ([`JUMP_FACTOR`], [`JUMP_MIN_S`]). Every bad row is counted and the first
//! [`MAX_REPORTED_ERRORS`] are reported in one [`TraceError::Rows`]. The reader streams: it
//! holds one row at a time besides the signals, a line is at most [`MAX_LINE_BYTES`], and a
//! trace at most [`MAX_TRACE_ROWS`] rows and [`MAX_TRACE_VALUES`] values, so no file makes it
//! allocate beyond about 1 GB.

mod decimal;
mod read;
mod unit;
mod write;

pub use crate::signal::{AxisSignal, Quantity};
pub use unit::{UNITS, Unit, check_unit, display_unit_of, expected_quantities, unit};
pub use write::push_value;

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
    /// The header is not a TRACE_FORMAT header (no `t[s]`, or a column that is not
    /// signal[unit]) and no mapping was given: a foreign layout. Carries the columns found,
    /// so the caller can say which mapping reads them.
    #[error(
        "{file}: the columns {} are not a TRACE_FORMAT trace (it needs a time column t[s] and axis.signal[unit] columns): give a column mapping (--map, or a preset whose diagnose.mapping reads them)",
        quote(&.columns.join(", "), 400)
    )]
    Foreign {
        /// The file.
        file: String,
        /// The header's columns, in file order.
        columns: Vec<String>,
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
pub(crate) fn quote(s: &str, max: usize) -> String {
    match s.char_indices().nth(max) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_owned(),
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

/// One recorded signal: its samples in the SI unit of its quantity.
#[derive(Debug, Clone, PartialEq)]
pub struct Signal {
    /// `t`, `mode`, `x.cmd`, `temp.x_screw`, …
    pub name: String,
    /// SI unit: m, s, m/s, N, N*m, A, degC, or "" for a plain number.
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

    /// The samples of signal `name`, in SI.
    pub fn values(&self, name: &str) -> Option<&[f64]> {
        self.signal(name).map(|s| s.data.as_slice())
    }

    /// The samples of axis signal `sig` of axis `axis` (column `<axis>.<sig>`), in SI; found
    /// without building the column name.
    pub fn axis_values(&self, axis: &str, sig: AxisSignal) -> Option<&[f64]> {
        self.signals
            .iter()
            .find(|s| {
                s.name.strip_prefix(axis).and_then(|r| r.strip_prefix('.')) == Some(sig.name())
            })
            .map(|s| s.data.as_slice())
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
            .filter(|a| self.axis_values(a, AxisSignal::Pos).is_some())
            .map(str::to_owned)
            .collect()
    }

    /// Makes room for `rows` more samples in every column, so that a long run appends
    /// without reallocating. On Linux the room is also offered to the kernel for huge pages:
    /// a recorded run writes hundreds of MB of fresh memory, and faulting it in 4 KiB pages
    /// cost more than the simulation itself (half the time of `bench` with recording on).
    pub fn reserve_rows(&mut self, rows: usize) {
        for s in &mut self.signals {
            s.data.reserve(rows);
            advise_huge_pages(&mut s.data);
        }
    }

    /// The address ranges of every column's unused capacity, as (start, length in bytes),
    /// for [`Prefault`]. Addresses only: nothing is read or written through them.
    pub fn spare_ranges(&mut self) -> Vec<(usize, usize)> {
        self.signals
            .iter_mut()
            .map(|s| {
                let spare = s.data.spare_capacity_mut();
                (spare.as_mut_ptr() as usize, std::mem::size_of_val(spare))
            })
            .collect()
    }

    /// Appends `rows` rows from a column-major `stage` (column `c` at `c * stride`) to the
    /// first columns, one column at a time. The rows go to fresh memory that nothing reads
    /// soon, so where the room is already reserved they are written with non-temporal
    /// stores: a plain store first reads each cache line it fills, and that read was a
    /// third of the cost of a recorded step.
    pub fn append_staged(&mut self, stage: &[f64], stride: usize, rows: usize) {
        let n = stage.len().checked_div(stride).unwrap_or(0);
        for (c, sig) in self.signals.iter_mut().enumerate().take(n) {
            let src = &stage[c * stride..c * stride + rows.min(stride)];
            extend_streaming(&mut sig.data, src);
        }
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a store fence has no operands; it orders the streaming stores above before
        // any later store, as their documentation asks.
        unsafe {
            std::arch::x86_64::_mm_sfence();
        }
    }

    /// How many of `rows` rows to append now so that the columns end on a cache line
    /// boundary (judged on the first column; the columns are reserved together, so they
    /// share its alignment), or `rows` when there is no room reserved or no such count.
    pub fn line_aligned_rows(&self, rows: usize) -> usize {
        let Some(col) = self.signals.first() else {
            return rows;
        };
        if col.data.capacity() - col.data.len() < rows {
            return rows;
        }
        let end = col.data.as_ptr() as usize + std::mem::size_of_val(col.data.as_slice());
        let over = (end + rows * std::mem::size_of::<f64>()) % LINE_BYTES;
        if !over.is_multiple_of(std::mem::size_of::<f64>()) {
            return rows;
        }
        rows.saturating_sub(over / std::mem::size_of::<f64>())
    }

    /// Drops all samples, keeping the columns (live plots reuse the buffer).
    pub fn clear(&mut self) {
        for s in &mut self.signals {
            s.data.clear();
        }
    }
}

/// Size of a cache line on the machines we run on (x86-64, aarch64).
pub const LINE_BYTES: usize = 64;

/// Size of a transparent huge page on x86-64 and aarch64 Linux.
#[cfg(target_os = "linux")]
const HUGE_PAGE_BYTES: usize = 2 * 1024 * 1024;

/// Asks the kernel to back the unused capacity of `v` with transparent huge pages (only
/// where the system leaves that to the program, `madvise` mode). Advice only: contents,
/// length and ownership do not change, and a refusal changes nothing but speed.
#[cfg(target_os = "linux")]
fn advise_huge_pages(v: &mut Vec<f64>) {
    let spare = v.spare_capacity_mut();
    let start = spare.as_mut_ptr() as usize;
    let end = start + std::mem::size_of_val(spare);
    let first = start.div_ceil(HUGE_PAGE_BYTES) * HUGE_PAGE_BYTES;
    let last = end / HUGE_PAGE_BYTES * HUGE_PAGE_BYTES;
    if last > first {
        // SAFETY: [first, last) lies inside `v`'s own allocation (its spare capacity), which
        // this function holds mutably; MADV_HUGEPAGE changes how the kernel backs those pages,
        // never what they hold, and nothing is read or written through the pointer.
        unsafe {
            libc::madvise(
                first as *mut libc::c_void,
                last - first,
                libc::MADV_HUGEPAGE,
            );
        }
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge_pages(_v: &mut Vec<f64>) {}

/// Faults in reserved trace memory on another core while the model runs.
///
/// A recorded run appends to hundreds of MB of fresh memory, and the kernel zeroes every
/// page on its first touch; on these machines that zeroing took more time than the model
/// itself. This thread asks the kernel to fault the reserved pages in ahead of the writer
/// (`MADV_POPULATE_WRITE`), chunk by chunk in the order the rows are written, so that the
/// zeroing runs beside the model instead of inside it.
///
/// It is advice only: the thread never reads or writes the memory, populating pages never
/// changes what they hold, and a range that was freed meanwhile makes the call fail
/// harmlessly. Dropping the handle stops the thread and waits for it (at most one chunk).
pub struct Prefault {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    handle: Option<std::thread::JoinHandle<()>>,
}

/// Below this much reserved memory a thread is not worth starting.
const PREFAULT_MIN_BYTES: usize = 32 * 1024 * 1024;

/// Bytes of each column populated per round (one huge page).
const PREFAULT_CHUNK_BYTES: usize = 2 * 1024 * 1024;

impl Prefault {
    /// Starts faulting in `ranges` (from [`Trace::spare_ranges`]), or returns `None` when
    /// they are too small to bother or the platform has no such call.
    pub fn start(ranges: Vec<(usize, usize)>) -> Option<Prefault> {
        let total: usize = ranges.iter().map(|r| r.1).sum();
        if total < PREFAULT_MIN_BYTES || !cfg!(target_os = "linux") {
            return None;
        }
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = stop.clone();
        let handle = std::thread::Builder::new()
            .name("trace-prefault".into())
            .spawn(move || populate_rounds(&ranges, &flag))
            .ok()?;
        Some(Prefault {
            stop,
            handle: Some(handle),
        })
    }
}

impl Drop for Prefault {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            // The thread only makes system calls; a panic there is not ours to report.
            let _ = h.join();
        }
    }
}

/// Populates every range chunk by chunk, all columns' first chunks first.
fn populate_rounds(ranges: &[(usize, usize)], stop: &std::sync::atomic::AtomicBool) {
    let longest = ranges.iter().map(|r| r.1).max().unwrap_or(0);
    let mut off = 0;
    while off < longest {
        for &(start, len) in ranges {
            if stop.load(std::sync::atomic::Ordering::Relaxed) {
                return;
            }
            if off < len {
                populate(start + off, PREFAULT_CHUNK_BYTES.min(len - off));
            }
        }
        off += PREFAULT_CHUNK_BYTES;
    }
}

#[cfg(target_os = "linux")]
fn populate(start: usize, len: usize) {
    // madvise wants a page-aligned start; the part of the first page before `start` belongs
    // to the same allocation or to the allocator's header, and populating it changes nothing.
    const PAGE: usize = 4096;
    let first = start / PAGE * PAGE;
    // SAFETY: MADV_POPULATE_WRITE faults pages in as a write would, without writing: no
    // memory is read or changed, so no Rust reference is affected. If the range was freed
    // meanwhile, the kernel refuses the call (ENOMEM/EFAULT) or populates pages of the new
    // mapping, which again changes nothing they hold. The result is advice; it is ignored.
    unsafe {
        libc::madvise(
            first as *mut libc::c_void,
            len + (start - first),
            libc::MADV_POPULATE_WRITE,
        );
    }
}

#[cfg(not(target_os = "linux"))]
fn populate(_start: usize, _len: usize) {}

/// Appends `src` to `v`, with non-temporal stores when `v` already has room for it (x86-64).
/// The caller fences (see [`Trace::append_staged`]).
fn extend_streaming(v: &mut Vec<f64>, src: &[f64]) {
    #[cfg(target_arch = "x86_64")]
    if v.capacity() - v.len() >= src.len() {
        let spare = &mut v.spare_capacity_mut()[..src.len()];
        let dst = spare.as_mut_ptr().cast::<f64>();
        // Plain stores up to the first address the wide streaming store accepts.
        let head = (dst as usize)
            .next_multiple_of(STREAM_BYTES)
            .saturating_sub(dst as usize)
            / std::mem::size_of::<f64>();
        let mut i = 0;
        while i < head.min(src.len()) {
            if let (Some(d), Some(&x)) = (spare.get_mut(i), src.get(i)) {
                d.write(x);
            }
            i += 1;
        }
        while i + STREAM_LANES <= src.len() {
            // SAFETY: `i + STREAM_LANES <= src.len() == spare.len()`, so the load from `src`
            // and the store into the spare capacity stay in bounds; `dst + i` is aligned to
            // `STREAM_BYTES` (the head above, then `i` moves by whole vectors).
            unsafe { stream_lanes(dst.add(i), src.as_ptr().add(i)) };
            i += STREAM_LANES;
        }
        while i < src.len() {
            if let (Some(d), Some(&x)) = (spare.get_mut(i), src.get(i)) {
                d.write(x);
            }
            i += 1;
        }
        let len = v.len() + src.len();
        // SAFETY: every element of the first `src.len()` spare slots was written above.
        unsafe { v.set_len(len) };
        return;
    }
    v.extend_from_slice(src);
}

/// Bytes of one streaming store: a whole cache line where the CPU has AVX-512, so that the
/// line goes to memory in one piece.
#[cfg(all(target_arch = "x86_64", target_feature = "avx512f"))]
const STREAM_BYTES: usize = 64;
#[cfg(all(
    target_arch = "x86_64",
    not(target_feature = "avx512f"),
    target_feature = "avx"
))]
const STREAM_BYTES: usize = 32;
#[cfg(all(
    target_arch = "x86_64",
    not(target_feature = "avx512f"),
    not(target_feature = "avx")
))]
const STREAM_BYTES: usize = 16;
#[cfg(target_arch = "x86_64")]
const STREAM_LANES: usize = STREAM_BYTES / std::mem::size_of::<f64>();

/// One non-temporal store of `STREAM_LANES` values from `src` to `dst`.
///
/// # Safety
/// `src` must be readable and `dst` writable for `STREAM_LANES` f64, and `dst` aligned to
/// `STREAM_BYTES`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn stream_lanes(dst: *mut f64, src: *const f64) {
    #[cfg(target_feature = "avx512f")]
    // SAFETY: as the caller promises; the CPU has AVX-512 (compile-time feature).
    unsafe {
        use std::arch::x86_64::{_mm512_loadu_pd, _mm512_stream_pd};
        _mm512_stream_pd(dst, _mm512_loadu_pd(src));
    }
    #[cfg(all(not(target_feature = "avx512f"), target_feature = "avx"))]
    // SAFETY: as the caller promises; the CPU has AVX (compile-time feature).
    unsafe {
        use std::arch::x86_64::{_mm256_loadu_pd, _mm256_stream_pd};
        _mm256_stream_pd(dst, _mm256_loadu_pd(src));
    }
    #[cfg(all(not(target_feature = "avx512f"), not(target_feature = "avx")))]
    // SAFETY: as the caller promises; SSE2 is part of x86-64.
    unsafe {
        use std::arch::x86_64::{_mm_loadu_pd, _mm_stream_pd};
        _mm_stream_pd(dst, _mm_loadu_pd(src));
    }
}
