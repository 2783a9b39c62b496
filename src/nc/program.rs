//! Part programs: the G-code subset the seeds use, read into blocks and compiled into motion
//! operations.
//!
//! The reader is a small word lexer of its own: a letter, an optional sign and a decimal
//! number, with `( … )` and `;` comments. Every number is read as f64 by `str::parse` from its
//! source text, so positions are exact to the µm and below. (The `gcode` crate used before
//! stores numbers as f32, wraps or panics on G numbers past 429496729, drops numbers it
//! cannot parse without a word, and splits `X1e3` into `X1 E3`; guarding against all of that
//! needed a lexer anyway.)
//!
//! Every number is checked where it is read — finite, and in the range its address allows
//! ([`MAX_COORD_MM`], [`MAX_FEED_MM_PER_MIN`], …); nothing is clamped. Compilation walks the
//! modal state once (G90/G91, G00–G03, G17/G18, F), so that every geometric error (an arc end
//! point off its circle, an unknown axis, a move that would take days) is reported with its
//! line and column before anything moves. Errors are collected, not stopped at: one
//! [`ProgramError`] carries the first [`MAX_REPORTED_ERRORS`] findings and the count of the
//! rest. Program size and the number of operations are bounded ([`MAX_PROGRAM_BYTES`],
//! [`MAX_PROGRAM_LINES`], [`MAX_OPS`]), and so is the time of any one block
//! ([`MAX_BLOCK_TIME_S`]), which bounds the interpolation steps of a block to
//! `MAX_BLOCK_TIME_S / T1` whatever F or P the program writes.

use crate::preset::Mode;
use crate::units::{m_to_mm, mm_per_min_to_m_per_s, mm_to_m, ms_to_s, s_to_ms};

/// Largest program text accepted, bytes (64 MiB): with its blocks and operations a program
/// at this size stays well under 1 GB in memory.
pub const MAX_PROGRAM_BYTES: usize = 64 * 1024 * 1024;
/// Most lines accepted. A direct-command program (one line per T3 sample) of this length
/// runs 250 s at T3 = 125 µs.
pub const MAX_PROGRAM_LINES: usize = 2_000_000;
/// Most compiled operations; each costs about 130 bytes, so the limit is about 260 MB.
pub const MAX_OPS: usize = 2_000_000;
/// Findings carried by one [`ProgramError`]; the rest are counted. Keeps a file of 100,000
/// bad lines from printing megabytes.
pub const MAX_REPORTED_ERRORS: usize = 20;
/// Largest coordinate, arc offset or radius, mm (±100 m): beyond any machine tool, small
/// enough that no arithmetic on it loses the µm.
pub const MAX_COORD_MM: f64 = 100_000.0;
/// Largest feed F, mm/min (1 km/min, ten times the fastest linear-motor axes).
pub const MAX_FEED_MM_PER_MIN: f64 = 1_000_000.0;
/// Longest time of one block (a move at its feed, or a dwell), s: one day. Bounds the
/// interpolation steps of any block, however small F or large P.
pub const MAX_BLOCK_TIME_S: f64 = 86_400.0;
/// Largest G or M number.
pub const MAX_CODE_NUMBER: u32 = 999;
/// Largest N (block number) or O (program number).
pub const MAX_BLOCK_NUMBER: u32 = 99_999_999;
/// Largest T (tool number).
pub const MAX_TOOL_NUMBER: u32 = 99_999;
/// Largest spindle speed S, rpm.
pub const MAX_SPINDLE_RPM: f64 = 100_000.0;

/// Tolerance on an arc's end radius against its start radius, m (1 µm, plus the same
/// relative to the radius).
const ARC_END_TOL_M: f64 = 1.0e-6;
/// Two arc end points closer than this are one point (a full circle), m.
const SAME_POINT_M: f64 = 1.0e-9;
/// Budget of the rendered error text, bytes; the rest is counted.
const DISPLAY_BUDGET: usize = 3_600;
/// Longest piece of program text quoted in a message, characters.
const QUOTE_CHARS: usize = 24;
/// The G codes the compiler implements, for messages.
const SUPPORTED_G: &str = "G00–G05, G17, G18, G21, G90, G91";
/// The addresses the compiler reads, for messages.
const SUPPORTED_ADDRESSES: &str = "X Y Z C U V W H I J K R F P S";

/// One thing wrong in a program, where it stands.
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    /// Line, from 1.
    pub line: usize,
    /// Column, from 1, in characters.
    pub col: usize,
    /// What is wrong, led by the word as written when there is one.
    pub reason: String,
}

/// Why a program was refused. The first finding sits in the flat fields, so a caller that
/// shows one error needs nothing else; `more` holds the next ones (in line order, at most
/// [`MAX_REPORTED_ERRORS`] in all) and `omitted` counts those not kept. The display is
/// one finding per line, `file:line:col: reason`, under 4,000 characters in all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}", self.render())]
pub struct ProgramError {
    /// The program's name, as given to [`parse`]/[`compile`].
    pub file: String,
    /// Line of the first finding, from 1.
    pub line: usize,
    /// Column of the first finding, from 1.
    pub col: usize,
    /// The first finding.
    pub reason: String,
    /// Further findings after the first.
    pub more: Vec<Finding>,
    /// Findings beyond those carried.
    pub omitted: usize,
}

impl ProgramError {
    /// One finding.
    fn single(file: &str, line: usize, col: usize, reason: String) -> ProgramError {
        ProgramError {
            file: file.to_owned(),
            line,
            col,
            reason,
            more: Vec::new(),
            omitted: 0,
        }
    }

    /// Every finding carried, the first one first.
    pub fn findings(&self) -> impl Iterator<Item = Finding> + '_ {
        std::iter::once(Finding {
            line: self.line,
            col: self.col,
            reason: self.reason.clone(),
        })
        .chain(self.more.iter().cloned())
    }

    /// How many findings there were, carried or not.
    pub fn count(&self) -> usize {
        1 + self.more.len() + self.omitted
    }

    fn render(&self) -> String {
        let file = quote(&self.file, 80);
        let mut out = String::new();
        let mut shown = 0;
        for f in self.findings() {
            let line = format!("{file}:{}:{}: {}", f.line, f.col, quote(&f.reason, 200));
            if shown > 0 && out.len() + line.len() + 1 > DISPLAY_BUDGET {
                break;
            }
            if shown > 0 {
                out.push('\n');
            }
            out.push_str(&line);
            shown += 1;
        }
        let rest = self.count() - shown;
        if rest > 0 {
            out.push_str(&format!(
                "\n… and {rest} more errors ({} in all)",
                self.count()
            ));
        }
        out
    }
}

/// Collects findings: keeps the first [`MAX_REPORTED_ERRORS`], counts all.
#[derive(Default)]
struct Findings {
    kept: Vec<Finding>,
    total: usize,
}

impl Findings {
    fn push(&mut self, line: usize, col: usize, reason: String) {
        self.total += 1;
        if self.kept.len() < MAX_REPORTED_ERRORS {
            self.kept.push(Finding { line, col, reason });
        }
    }

    fn finish<T>(self, file: &str, ok: T) -> Result<T, ProgramError> {
        let mut it = self.kept.into_iter();
        match it.next() {
            None => Ok(ok),
            Some(first) => {
                let more: Vec<Finding> = it.collect();
                let omitted = self.total - 1 - more.len();
                Err(ProgramError {
                    file: file.to_owned(),
                    line: first.line,
                    col: first.col,
                    reason: first.reason,
                    more,
                    omitted,
                })
            }
        }
    }
}

/// `s`, cut to `max` characters with an ellipsis, for quoting untrusted text in a message.
fn quote(s: &str, max: usize) -> String {
    match s.char_indices().nth(max) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_owned(),
    }
}

/// How a move block interpolates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Motion {
    /// G00: straight line at the rapid feed.
    Rapid,
    /// G01: straight line at the programmed feed.
    Linear,
    /// G02: clockwise arc.
    ArcCw,
    /// G03: counter-clockwise arc.
    ArcCcw,
}

/// The plane arcs are drawn in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Plane {
    /// G17: arcs in X–Y.
    Xy,
    /// G18: arcs in Z–X.
    Zx,
}

/// A number from the program with where it stood.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Word {
    /// The address, upper case.
    pub letter: char,
    /// The value as written, in the program's units (mm, mm/min, ms).
    pub value: f64,
    /// Column of the letter, from 1.
    pub col: usize,
}

/// One parsed block, before modal state is applied.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Block {
    /// Line, from 1.
    pub line: usize,
    /// G codes with their columns.
    pub g: Vec<(u32, usize)>,
    /// M codes with their columns.
    pub m: Vec<(u32, usize)>,
    /// Address words (coordinates, F, P, …), each at most once.
    pub words: Vec<Word>,
}

impl Block {
    fn word(&self, letter: char) -> Option<Word> {
        self.words.iter().copied().find(|w| w.letter == letter)
    }
}

/// What the interpolator executes.
#[derive(Debug, Clone, PartialEq)]
pub enum Op {
    /// A move to `end_m` along `path`.
    Move {
        /// Program line, for the trace and messages.
        line: usize,
        /// End point per channel axis, m.
        end_m: Vec<f64>,
        /// Path feed, m/s.
        feed_mps: f64,
        /// Straight line or arc.
        path: Path,
        /// Path length, m.
        length_m: f64,
    },
    /// G04: wait.
    Dwell {
        /// Program line.
        line: usize,
        /// Dwell time, s (0 to [`MAX_BLOCK_TIME_S`]).
        t_s: f64,
    },
    /// G05: switch between normal and direct-command processing.
    Switch {
        /// Program line.
        line: usize,
        /// The mode switched to.
        mode: Mode,
    },
    /// M02/M30: program end.
    End,
}

/// The geometry of a move.
#[derive(Debug, Clone, PartialEq)]
pub enum Path {
    /// Straight line from start to end.
    Line,
    /// Arc in the plane of channel axes `a`, `b` (indices), other axes linear.
    Arc {
        /// Index of the plane's first axis.
        a: usize,
        /// Index of the plane's second axis.
        b: usize,
        /// Centre in (a, b), m.
        center_m: (f64, f64),
        /// Radius, m.
        radius_m: f64,
        /// Angle of the start point, rad.
        start_rad: f64,
        /// Signed sweep, rad (negative clockwise).
        sweep_rad: f64,
    },
}

/// A word as written: letter, value, column, and its source text for messages.
struct Lexeme<'a> {
    letter: char,
    value: f64,
    col: usize,
    raw: &'a str,
}

/// Columns (in characters) of byte offsets into one line, asked for in increasing order, so
/// that a long line costs linear time.
struct Cols<'a> {
    line: &'a str,
    byte: usize,
    col: usize,
}

impl Cols<'_> {
    fn at(&mut self, byte: usize) -> usize {
        if let Some(piece) = self.line.get(self.byte..byte) {
            self.col += piece.chars().count();
            self.byte = byte;
        }
        self.col
    }
}

fn is_blank(c: u8) -> bool {
    matches!(c, b' ' | b'\t' | b'\r')
}

/// Reads the words of one line (without its `\n`) into `words`. Returns the first lexical
/// error as (column, reason); the words before it are kept.
fn lex_line<'a>(line: &'a str, words: &mut Vec<Lexeme<'a>>) -> Option<(usize, String)> {
    let b = line.as_bytes();
    let mut cols = Cols {
        line,
        byte: 0,
        col: 1,
    };
    let mut i = 0;
    loop {
        while b.get(i).copied().is_some_and(is_blank) {
            i += 1;
        }
        let &c = b.get(i)?;
        let col = cols.at(i);
        match c {
            b';' => return None,
            b'(' => match line[i..].find(')') {
                Some(k) => i += k + 1,
                None => return Some((col, "comment '(' is not closed on this line".into())),
            },
            // A program delimiter line.
            b'%' if words.is_empty() => return None,
            b'/' if words.is_empty() => {
                return Some((col, "block delete '/' is not supported".into()));
            }
            c if c.is_ascii_alphabetic() => match lex_word(line, &mut i) {
                Ok((letter, value, raw)) => words.push(Lexeme {
                    letter,
                    value,
                    col,
                    raw,
                }),
                Err(reason) => return Some((col, reason)),
            },
            _ => {
                let ch = line[i..].chars().next().unwrap_or(' ');
                let what = match ch {
                    '#' => "parameters (#) are not supported",
                    '[' => "expressions ([ ]) are not supported",
                    _ => "not G-code",
                };
                return Some((col, format!("unexpected {ch:?}: {what}")));
            }
        }
    }
}

/// Reads one word starting at the letter at `*i`: letter, optional sign, decimal number.
/// Moves `*i` past it. Returns (letter, value, source text).
fn lex_word<'a>(line: &'a str, i: &mut usize) -> Result<(char, f64, &'a str), String> {
    let b = line.as_bytes();
    let start = *i;
    let letter = char::from(b[start]);
    let mut j = start + 1;
    let skip_blanks = |j: &mut usize| {
        while b.get(*j).copied().is_some_and(is_blank) {
            *j += 1;
        }
    };
    skip_blanks(&mut j);
    let negative = match b.get(j) {
        Some(b'-') => {
            j += 1;
            true
        }
        Some(b'+') => {
            j += 1;
            false
        }
        _ => false,
    };
    skip_blanks(&mut j);
    let num_start = j;
    while b.get(j).is_some_and(|c| c.is_ascii_digit() || *c == b'.') {
        j += 1;
    }
    let digits = &line[num_start..j];
    if !digits.bytes().any(|c| c.is_ascii_digit()) {
        *i = j.max(start + 1);
        let raw = quote(&line[start..*i], QUOTE_CHARS);
        return Err(match b.get(j) {
            Some(b'#') => format!("{raw}#: parameters (#) are not supported"),
            Some(b'[') => format!("{raw}[: expressions ([ ]) are not supported"),
            _ => format!("{raw}: {letter} needs a number"),
        });
    }
    if let Some(end) = exponent_end(b, j) {
        *i = end;
        return Err(exponent_message(
            letter,
            negative,
            &line[num_start..end],
            &line[start..end],
        ));
    }
    *i = j;
    let raw = &line[start..j];
    let v: f64 = digits.parse().map_err(|_| {
        format!(
            "{}: '{}' is not a number",
            quote(raw, QUOTE_CHARS),
            quote(digits, QUOTE_CHARS)
        )
    })?;
    Ok((letter, if negative { -v } else { v }, raw))
}

/// End of an exponent (`e3`, `E-6`, `e+2`) starting at `j`, if there is one.
fn exponent_end(b: &[u8], j: usize) -> Option<usize> {
    if !matches!(b.get(j), Some(b'e' | b'E')) {
        return None;
    }
    let mut k = j + 1;
    if matches!(b.get(k), Some(b'+' | b'-')) {
        k += 1;
    }
    if !b.get(k).is_some_and(u8::is_ascii_digit) {
        return None;
    }
    while b.get(k).is_some_and(u8::is_ascii_digit) {
        k += 1;
    }
    Some(k)
}

/// "X1e3: exponents are not G-code; write X1000" (the suggestion only when it is short).
fn exponent_message(letter: char, negative: bool, number: &str, raw: &str) -> String {
    let plain = number
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .map(|v| format!("{}", if negative { -v } else { v }))
        .filter(|p| p.len() <= QUOTE_CHARS);
    let raw = quote(raw, QUOTE_CHARS);
    match plain {
        Some(p) => format!("{raw}: exponents are not G-code; write {letter}{p}"),
        None => format!("{raw}: exponents are not G-code"),
    }
}

/// Refuses a program text past [`MAX_PROGRAM_BYTES`] or [`MAX_PROGRAM_LINES`] before
/// anything is allocated for it.
fn check_size(text: &str, file: &str) -> Result<(), ProgramError> {
    if text.len() > MAX_PROGRAM_BYTES {
        return Err(ProgramError::single(
            file,
            1,
            1,
            format!(
                "the program is {} bytes; the limit is {MAX_PROGRAM_BYTES} bytes (MAX_PROGRAM_BYTES); split it",
                text.len()
            ),
        ));
    }
    let lines = text.bytes().filter(|&c| c == b'\n').count() + 1;
    if lines > MAX_PROGRAM_LINES {
        return Err(ProgramError::single(
            file,
            MAX_PROGRAM_LINES + 1,
            1,
            format!(
                "the program has {lines} lines; the limit is {MAX_PROGRAM_LINES} lines (MAX_PROGRAM_LINES); split it"
            ),
        ));
    }
    Ok(())
}

/// Parses program text into blocks. Unsupported words are errors, not ignored; every error
/// names its line and column, and all lines are checked (see [`ProgramError`]). A UTF-8 BOM
/// and CRLF line ends are accepted.
pub fn parse(text: &str, file: &str) -> Result<Vec<Block>, ProgramError> {
    check_size(text, file)?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut found = Findings::default();
    let mut blocks = Vec::new();
    let mut words = Vec::new();
    for (n, line) in text.split('\n').enumerate() {
        let line_no = n + 1;
        words.clear();
        let lex_error = lex_line(line, &mut words);
        let mut block = Block {
            line: line_no,
            ..Block::default()
        };
        for w in &words {
            if let Err(reason) = add_word(&mut block, w) {
                found.push(line_no, w.col, reason);
            }
        }
        if let Some((col, reason)) = lex_error {
            found.push(line_no, col, reason);
        }
        let empty = block.g.is_empty() && block.m.is_empty() && block.words.is_empty();
        if found.total == 0 && !empty {
            blocks.push(block);
        }
    }
    found.finish(file, blocks)
}

/// `v` as a whole number in 0..=max.
fn whole(v: f64, max: u32) -> Option<u32> {
    if (0.0..=f64::from(max)).contains(&v) && v.fract() == 0.0 {
        // In range and whole: the conversion is exact.
        Some(v as u32)
    } else {
        None
    }
}

/// Whether the compiler implements G `g`, and why not.
fn check_g(g: u32) -> Result<(), String> {
    match g {
        0..=5 | 17 | 18 | 21 | 90 | 91 => Ok(()),
        20 => Err("G20 (inch) is not supported; programs are in mm".into()),
        _ => Err(format!("G{g:02} is not supported ({SUPPORTED_G})")),
    }
}

/// The range check of an address value, as a reason when it fails.
fn check_value(letter: char, v: f64) -> Result<(), String> {
    let within = |lo: f64, hi: f64| (lo..=hi).contains(&v);
    let ok = match letter {
        'X' | 'Y' | 'Z' | 'C' | 'U' | 'V' | 'W' | 'H' | 'I' | 'J' | 'K' => {
            within(-MAX_COORD_MM, MAX_COORD_MM)
        }
        'R' => {
            if v == 0.0 {
                return Err("an arc radius must not be 0".to_owned());
            }
            within(-MAX_COORD_MM, MAX_COORD_MM)
        }
        'F' => {
            if v <= 0.0 {
                return Err("feed F must be > 0".to_owned());
            }
            within(f64::MIN_POSITIVE, MAX_FEED_MM_PER_MIN)
        }
        'P' => {
            if v < 0.0 {
                return Err("P must be ≥ 0 (a dwell in ms, or G05's P0/P4)".to_owned());
            }
            within(0.0, s_to_ms(MAX_BLOCK_TIME_S))
        }
        'S' => within(0.0, MAX_SPINDLE_RPM),
        _ => {
            return Err(format!(
                "address {letter} is not supported ({SUPPORTED_ADDRESSES})"
            ));
        }
    };
    if ok {
        return Ok(());
    }
    let range = match letter {
        'F' => format!("0 < F ≤ {MAX_FEED_MM_PER_MIN} mm/min"),
        'P' => format!("0 ≤ P ≤ {} ms", s_to_ms(MAX_BLOCK_TIME_S)),
        'S' => format!("0 ≤ S ≤ {MAX_SPINDLE_RPM} rpm"),
        _ => format!("|{letter}| ≤ {MAX_COORD_MM} mm"),
    };
    Err(format!("{letter} out of range ({range})"))
}

/// Checks one word and adds it to `block`.
fn add_word(block: &mut Block, w: &Lexeme<'_>) -> Result<(), String> {
    let letter = w.letter.to_ascii_uppercase();
    let raw = || quote(w.raw, QUOTE_CHARS);
    let v = w.value;
    match letter {
        'G' | 'M' => {
            if !(0.0..=f64::from(MAX_CODE_NUMBER)).contains(&v) {
                return Err(format!(
                    "{}: {letter} number out of range ({letter}0 to {letter}{MAX_CODE_NUMBER})",
                    raw()
                ));
            }
            let Some(n) = whole(v, MAX_CODE_NUMBER) else {
                return Err(format!(
                    "{}: {letter}{v} is not supported (no sub-codes)",
                    raw()
                ));
            };
            if letter == 'G' {
                check_g(n)?;
                block.g.push((n, w.col));
            } else {
                block.m.push((n, w.col));
            }
            Ok(())
        }
        'N' | 'O' | 'T' => {
            let max = if letter == 'T' {
                MAX_TOOL_NUMBER
            } else {
                MAX_BLOCK_NUMBER
            };
            match whole(v, max) {
                // Block and program numbers and tool changes do not move the axes.
                Some(_) => Ok(()),
                None => Err(format!(
                    "{}: {letter} must be a whole number from 0 to {max}",
                    raw()
                )),
            }
        }
        _ => {
            check_value(letter, v).map_err(|r| format!("{}: {r}", raw()))?;
            if block.words.iter().any(|x| x.letter == letter) {
                return Err(format!(
                    "{}: address {letter} appears twice in one block",
                    raw()
                ));
            }
            block.words.push(Word {
                letter,
                value: v,
                col: w.col,
            });
            Ok(())
        }
    }
}

/// The modal state while compiling.
struct Modal {
    /// Programmed position per channel axis, m.
    pos: Vec<f64>,
    abs: bool,
    motion: Motion,
    plane: Plane,
    feed_mps: f64,
    rapid_mps: f64,
}

/// An error in one block: (column, reason).
type BlockError = (usize, String);

/// A number for a message: plain when it reads well, in exponent form when tiny or huge.
fn num(v: f64) -> String {
    if v == 0.0 || (1.0e-4..1.0e9).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Compiles blocks for a channel whose axes carry these absolute letters, starting at
/// `start_m`. Returns the motion operations in program order, or every error found (a block
/// in error is skipped, its end point still taken, so later blocks are judged from where the
/// program meant to be). At most [`MAX_OPS`] operations are made.
pub fn compile(
    blocks: &[Block],
    letters: &[char],
    start_m: &[f64],
    default_feed_mm_per_min: f64,
    rapid_mm_per_min: f64,
    file: &str,
) -> Result<Vec<Op>, ProgramError> {
    let feeds = (default_feed_mm_per_min, rapid_mm_per_min);
    compile_limited(blocks, letters, start_m, feeds, file, MAX_OPS)
}

/// [`compile`] with the operation limit as a parameter (so that tests can reach it).
fn compile_limited(
    blocks: &[Block],
    letters: &[char],
    start_m: &[f64],
    (default_feed_mm_per_min, rapid_mm_per_min): (f64, f64),
    file: &str,
    max_ops: usize,
) -> Result<Vec<Op>, ProgramError> {
    if start_m.len() != letters.len() {
        return Err(ProgramError::single(
            file,
            1,
            1,
            format!(
                "the channel has {} axis letters but {} start positions",
                letters.len(),
                start_m.len()
            ),
        ));
    }
    let mut st = Modal {
        pos: start_m.to_vec(),
        abs: true,
        motion: Motion::Linear,
        plane: Plane::Xy,
        feed_mps: mm_per_min_to_m_per_s(default_feed_mm_per_min),
        rapid_mps: mm_per_min_to_m_per_s(rapid_mm_per_min),
    };
    let mut found = Findings::default();
    let mut ops = Vec::new();
    for b in blocks {
        let (op, ends) = match compile_block(&mut st, b, letters) {
            Ok(r) => r,
            Err((col, reason)) => {
                found.push(b.line, col, reason);
                continue;
            }
        };
        for op in op.into_iter().chain(ends.then_some(Op::End)) {
            if ops.len() >= max_ops {
                return Err(ProgramError::single(
                    file,
                    b.line,
                    1,
                    format!(
                        "the program compiles to more than {max_ops} operations by this line (it has {} blocks, so up to {} operations); the limit is MAX_OPS = {max_ops}; split it",
                        blocks.len(),
                        blocks.len() + 1
                    ),
                ));
            }
            ops.push(op);
        }
        if ends {
            break;
        }
    }
    found.finish(file, ops)
}

/// Compiles one block against the modal state: the operation it makes, if any, and whether
/// it ends the program.
fn compile_block(
    st: &mut Modal,
    b: &Block,
    letters: &[char],
) -> Result<(Option<Op>, bool), BlockError> {
    let ends = b.m.iter().any(|&(m, _)| m == 30 || m == 2);
    let mut dwell = None;
    let mut switch = None;
    for &(g, col) in &b.g {
        match g {
            0 => st.motion = Motion::Rapid,
            1 => st.motion = Motion::Linear,
            2 => st.motion = Motion::ArcCw,
            3 => st.motion = Motion::ArcCcw,
            4 => dwell = Some(col),
            5 => switch = Some(g05_mode(b, col)?),
            17 => st.plane = Plane::Xy,
            18 => st.plane = Plane::Zx,
            21 => {}
            90 => st.abs = true,
            91 => st.abs = false,
            _ => return Err((col, check_g(g).err().unwrap_or_default())),
        }
    }
    if let Some(f) = b.word('F') {
        check_value('F', f.value).map_err(|r| (f.col, format!("F{}: {r}", num(f.value))))?;
        st.feed_mps = mm_per_min_to_m_per_s(f.value);
    }
    if let Some(mode) = switch {
        return Ok((Some(Op::Switch { line: b.line, mode }), ends));
    }
    if let Some(col) = dwell {
        return Ok((Some(dwell_op(b, col)?), ends));
    }
    let Some(end) = block_end(st, b, letters)? else {
        return Ok((None, ends));
    };
    let op = move_op(st, b, letters, &end);
    st.pos = end;
    Ok((Some(op?), ends))
}

/// The mode a G05 block switches to.
fn g05_mode(b: &Block, col: usize) -> Result<Mode, BlockError> {
    let p = b.word('P').ok_or_else(|| {
        (
            col,
            "G05 needs P4 (direct command on) or P0 (off)".to_owned(),
        )
    })?;
    match p.value {
        4.0 => Ok(Mode::Direct),
        0.0 => Ok(Mode::Normal),
        v => Err((
            p.col,
            format!("G05 P{}: only P4 (direct on) and P0 (off) exist", num(v)),
        )),
    }
}

/// A G04 block: P in ms, or X (U) in s; at most [`MAX_BLOCK_TIME_S`].
fn dwell_op(b: &Block, col: usize) -> Result<Op, BlockError> {
    let t_s = match (b.word('P'), b.word('X').or(b.word('U'))) {
        (Some(p), _) => ms_to_s(p.value),
        (None, Some(x)) => x.value,
        (None, None) => return Err((col, "G04 needs P (ms) or X (s)".into())),
    };
    if t_s.is_nan() || t_s < 0.0 {
        return Err((col, format!("G04: dwell time {} s must be ≥ 0", num(t_s))));
    }
    if t_s > MAX_BLOCK_TIME_S {
        return Err((
            col,
            format!(
                "G04: a dwell of {} s; the limit is {MAX_BLOCK_TIME_S} s per block (MAX_BLOCK_TIME_S)",
                num(t_s)
            ),
        ));
    }
    Ok(Op::Dwell { line: b.line, t_s })
}

/// The end point of a block's move, or None when it moves no axis.
fn block_end(st: &Modal, b: &Block, letters: &[char]) -> Result<Option<Vec<f64>>, BlockError> {
    let mut end = st.pos.clone();
    let mut moved = false;
    for w in &b.words {
        let (axis, incremental) = match w.letter {
            'X' | 'Y' | 'Z' | 'C' => (w.letter, !st.abs),
            'U' => ('X', true),
            'V' => ('Y', true),
            'W' => ('Z', true),
            'H' => ('C', true),
            _ => continue,
        };
        let raw = || format!("{}{}", w.letter, num(w.value));
        check_value(w.letter, w.value).map_err(|r| (w.col, format!("{}: {r}", raw())))?;
        let idx = letters.iter().position(|&l| l == axis).ok_or_else(|| {
            let have: String = letters.iter().collect();
            (
                w.col,
                format!(
                    "{} moves axis {axis}, which this channel does not have (it has {have})",
                    w.letter
                ),
            )
        })?;
        let Some(e) = end.get_mut(idx) else {
            continue;
        };
        let v = mm_to_m(w.value);
        *e = if incremental { *e + v } else { v };
        if e.abs() > mm_to_m(MAX_COORD_MM) {
            return Err((
                w.col,
                format!(
                    "{}: takes {axis} to {} mm, beyond ±{MAX_COORD_MM} mm",
                    raw(),
                    num(m_to_mm(*e))
                ),
            ));
        }
        moved = true;
    }
    Ok(moved.then_some(end))
}

/// A move from the modal position to `end`, refused when it would take longer than
/// [`MAX_BLOCK_TIME_S`] at its feed.
fn move_op(st: &Modal, b: &Block, letters: &[char], end: &[f64]) -> Result<Op, BlockError> {
    let (path, length_m) = if matches!(st.motion, Motion::ArcCw | Motion::ArcCcw) {
        arc_path(st, b, letters, end)?
    } else {
        (Path::Line, dist(&st.pos, end))
    };
    let feed_mps = if st.motion == Motion::Rapid {
        st.rapid_mps
    } else {
        st.feed_mps
    };
    let t_s = length_m / feed_mps;
    if t_s.is_nan() || t_s > MAX_BLOCK_TIME_S {
        let col = b.words.first().map_or(1, |w| w.col);
        return Err((
            col,
            format!(
                "this move of {} mm at {} mm/min would take {} s; the limit is {MAX_BLOCK_TIME_S} s per block (MAX_BLOCK_TIME_S); raise F or split the move",
                num(m_to_mm(length_m)),
                num(crate::units::m_per_s_to_mm_per_min(feed_mps)),
                num(t_s)
            ),
        ));
    }
    Ok(Op::Move {
        line: b.line,
        end_m: end.to_vec(),
        feed_mps,
        path,
        length_m,
    })
}

/// Resolves an arc block (G02/G03 with I/J/K or R) into its path and length.
fn arc_path(
    st: &Modal,
    b: &Block,
    letters: &[char],
    end: &[f64],
) -> Result<(Path, f64), BlockError> {
    let cw = st.motion == Motion::ArcCw;
    let (la, lb, ca, cb) = match st.plane {
        Plane::Xy => ('X', 'Y', 'I', 'J'),
        Plane::Zx => ('Z', 'X', 'K', 'I'),
    };
    let ia = letters.iter().position(|&l| l == la);
    let ib = letters.iter().position(|&l| l == lb);
    let (Some(a), Some(bi)) = (ia, ib) else {
        return Err((
            1,
            format!("an arc in the {la}{lb} plane needs axes {la} and {lb}"),
        ));
    };
    let pos = &st.pos;
    let (sa, sb, ea, eb) = (pos[a], pos[bi], end[a], end[bi]);
    let checked = |w: Word| -> Result<f64, BlockError> {
        check_value(w.letter, w.value)
            .map_err(|r| (w.col, format!("{}{}: {r}", w.letter, num(w.value))))?;
        Ok(mm_to_m(w.value))
    };
    let center = if let Some(r) = b.word('R') {
        arc_center_r(sa, sb, ea, eb, checked(r)?, cw).ok_or_else(|| {
            (
                r.col,
                format!("R{} is too small for this chord", num(r.value)),
            )
        })?
    } else {
        let oa = b.word(ca).map(checked).transpose()?.unwrap_or(0.0);
        let ob = b.word(cb).map(checked).transpose()?.unwrap_or(0.0);
        if oa == 0.0 && ob == 0.0 {
            return Err((
                1,
                format!("G0{} needs {ca}/{cb} or R", if cw { 2 } else { 3 }),
            ));
        }
        (sa + oa, sb + ob)
    };
    let r0 = ((sa - center.0).powi(2) + (sb - center.1).powi(2)).sqrt();
    let r1 = ((ea - center.0).powi(2) + (eb - center.1).powi(2)).sqrt();
    if (r0 - r1).abs() > ARC_END_TOL_M + ARC_END_TOL_M * r0 {
        return Err((
            1,
            format!(
                "arc end point is not on the circle: start radius {:.4} mm, end radius {:.4} mm",
                m_to_mm(r0),
                m_to_mm(r1)
            ),
        ));
    }
    let t0 = (sb - center.1).atan2(sa - center.0);
    let t1 = (eb - center.1).atan2(ea - center.0);
    let tau = std::f64::consts::TAU;
    let full = (ea - sa).abs() < SAME_POINT_M && (eb - sb).abs() < SAME_POINT_M;
    let sweep = if cw {
        let d = (t0 - t1).rem_euclid(tau);
        -(if full || d == 0.0 { tau } else { d })
    } else {
        let d = (t1 - t0).rem_euclid(tau);
        if full || d == 0.0 { tau } else { d }
    };
    let arc_len = r0 * sweep.abs();
    let others: f64 = (0..pos.len())
        .filter(|&i| i != a && i != bi)
        .map(|i| (end[i] - pos[i]).powi(2))
        .sum();
    let path = Path::Arc {
        a,
        b: bi,
        center_m: center,
        radius_m: r0,
        start_rad: t0,
        sweep_rad: sweep,
    };
    Ok((path, (arc_len * arc_len + others).sqrt()))
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (y - x).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Center of an R-programmed arc: R > 0 takes the short way (≤ 180°), R < 0 the long way.
fn arc_center_r(sa: f64, sb: f64, ea: f64, eb: f64, r: f64, cw: bool) -> Option<(f64, f64)> {
    let (dx, dy) = (ea - sa, eb - sb);
    let d = (dx * dx + dy * dy).sqrt();
    if d == 0.0 || d > 2.0 * r.abs() + SAME_POINT_M {
        return None;
    }
    let h = (r * r - d * d / 4.0).max(0.0).sqrt();
    let (mx, my) = (sa + dx / 2.0, sb + dy / 2.0);
    // Unit normal to the chord, to the left of the travel direction.
    let (nx, ny) = (-dy / d, dx / d);
    let left = (cw && r < 0.0) || (!cw && r > 0.0);
    let s = if left { h } else { -h };
    Some((mx + s * nx, my + s * ny))
}

/// Position on `path` at arc-length fraction `s` ∈ [0, 1], from `start` to `end`.
pub fn point_on(path: &Path, start: &[f64], end: &[f64], s: f64, out: &mut [f64]) {
    for i in 0..out.len() {
        out[i] = start[i] + (end[i] - start[i]) * s;
    }
    if let Path::Arc {
        a,
        b,
        center_m,
        radius_m,
        start_rad,
        sweep_rad,
    } = *path
    {
        if s >= 1.0 {
            out[a] = end[a];
            out[b] = end[b];
        } else {
            let th = start_rad + sweep_rad * s;
            out[a] = center_m.0 + radius_m * th.cos();
            out[b] = center_m.1 + radius_m * th.sin();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_operation_limit_refuses_with_the_estimate() {
        let blocks = parse("G01 X1 F100\nX2\nX3\nX4\nX5\nM30\n", "p").expect("parses");
        let ok = compile_limited(&blocks, &['X'], &[0.0], (100.0, 1000.0), "p", 6);
        assert_eq!(ok.map(|o| o.len()), Ok(6));
        let e = compile_limited(&blocks, &['X'], &[0.0], (100.0, 1000.0), "p", 3)
            .expect_err("over the limit");
        assert_eq!((e.line, e.col), (4, 1));
        assert!(
            e.reason.contains("more than 3 operations")
                && e.reason.contains("6 blocks, so up to 7 operations")
                && e.reason.contains("MAX_OPS = 3"),
            "{e}"
        );
    }

    #[test]
    fn quotes_are_cut_to_length() {
        assert_eq!(quote("abc", 3), "abc");
        assert_eq!(quote("abcd", 3), "abc…");
        assert_eq!(quote("ääää", 2), "ää…");
    }
}
