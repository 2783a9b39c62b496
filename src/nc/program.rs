//! Part programs: the G-code subset the seeds use, read with the `gcode` tokenizer and
//! compiled into motion operations.
//!
//! The tokenizer stores numbers as f32; positions must be exact to the µm and below, so every
//! number is read again as f64 from its source span. Compilation walks the modal state once
//! (G90/G91, G00–G03, G17/G18, F), so that every geometric error (an arc end point off its
//! circle, an unknown axis) is reported with its line and column before anything moves.

use crate::preset::Mode;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}:{line}:{col}: {reason}")]
pub struct ProgramError {
    pub file: String,
    pub line: usize,
    pub col: usize,
    pub reason: String,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Motion {
    Rapid,
    Linear,
    ArcCw,
    ArcCcw,
}

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
    pub letter: char,
    pub value: f64,
    pub col: usize,
}

/// One parsed block, before modal state is applied.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Block {
    pub line: usize,
    pub g: Vec<(u32, usize)>,
    pub m: Vec<(u32, usize)>,
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
    Move {
        line: usize,
        /// End point per channel axis, m.
        end_m: Vec<f64>,
        feed_mps: f64,
        path: Path,
        length_m: f64,
    },
    Dwell {
        line: usize,
        t_s: f64,
    },
    Switch {
        line: usize,
        mode: Mode,
    },
    End,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Path {
    Line,
    /// Arc in the plane of channel axes `a`, `b` (indices), other axes linear.
    Arc {
        a: usize,
        b: usize,
        center_m: (f64, f64),
        radius_m: f64,
        start_rad: f64,
        sweep_rad: f64,
    },
}

/// Parses program text into blocks. Unsupported words are errors, not ignored.
pub fn parse(text: &str, file: &str) -> Result<Vec<Block>, ProgramError> {
    let line_starts: Vec<usize> = std::iter::once(0)
        .chain(text.match_indices('\n').map(|(i, _)| i + 1))
        .collect();
    let col_of = |start: usize, line: usize| -> usize {
        start.saturating_sub(line_starts.get(line).copied().unwrap_or(0)) + 1
    };
    let err = |line: usize, col: usize, reason: String| ProgramError {
        file: file.to_owned(),
        line: line + 1,
        col,
        reason,
    };
    let program = gcode::parse(text).map_err(|diags| match diags.iter().next() {
        Some(d) => err(
            d.span.line,
            col_of(d.span.start, d.span.line),
            format!("syntax error: {}", d.kind),
        ),
        None => err(0, 1, "syntax error".into()),
    })?;
    let number = |span: gcode::core::Span, letter: char| -> Result<f64, ProgramError> {
        let col = col_of(span.start, span.line);
        let raw = text
            .get(span.start..span.start + span.length)
            .unwrap_or_default();
        let digits = raw
            .trim_start_matches(|c: char| c.is_ascii_alphabetic())
            .trim();
        let v: f64 = digits.parse().map_err(|_| {
            err(
                span.line,
                col,
                format!("'{raw}': {letter} needs a plain number (variables are not supported)"),
            )
        })?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(err(
                span.line,
                col,
                format!("'{raw}' is not a finite number"),
            ))
        }
    };
    let mut blocks = Vec::new();
    for b in &program.blocks {
        let mut block = Block {
            line: b.span.line + 1,
            ..Block::default()
        };
        let mut args: Vec<(char, gcode::core::Span)> = Vec::new();
        for code in &b.codes {
            match code {
                gcode::Code::General(g) => {
                    if g.number.minor().is_some() {
                        return Err(err(
                            g.span.line,
                            col_of(g.span.start, g.span.line),
                            format!("G{} is not supported", g.number),
                        ));
                    }
                    block
                        .g
                        .push((g.number.major(), col_of(g.span.start, g.span.line)));
                    args.extend(g.args.iter().map(|a| (a.letter, a.span)));
                }
                gcode::Code::Miscellaneous(m) => {
                    block
                        .m
                        .push((m.number.major(), col_of(m.span.start, m.span.line)));
                    args.extend(m.args.iter().map(|a| (a.letter, a.span)));
                }
                gcode::Code::ToolChange(t) => {
                    // Tool changes do not move the axes; their arguments still must be valid.
                    args.extend(t.args.iter().map(|a| (a.letter, a.span)));
                }
                _ => {}
            }
        }
        args.extend(b.word_addresses.iter().map(|w| (w.letter, w.span)));
        for (letter, span) in args {
            let letter = letter.to_ascii_uppercase();
            let col = col_of(span.start, span.line);
            if !"XYZCUVWHIJKRFPS".contains(letter) {
                return Err(err(
                    span.line,
                    col,
                    format!("address {letter} is not supported (X Y Z C U V W H I J K R F P S)"),
                ));
            }
            if block.words.iter().any(|w| w.letter == letter) {
                return Err(err(
                    span.line,
                    col,
                    format!("address {letter} appears twice in one block"),
                ));
            }
            let value = number(span, letter)?;
            block.words.push(Word { letter, value, col });
        }
        if !block.g.is_empty() || !block.m.is_empty() || !block.words.is_empty() {
            blocks.push(block);
        }
    }
    Ok(blocks)
}

/// Compiles blocks for a channel whose axes carry these absolute letters, starting at
/// `start_m`. Returns the motion operations in program order.
pub fn compile(
    blocks: &[Block],
    letters: &[char],
    start_m: &[f64],
    default_feed_mm_per_min: f64,
    rapid_mm_per_min: f64,
    file: &str,
) -> Result<Vec<Op>, ProgramError> {
    let err = |line: usize, col: usize, reason: String| ProgramError {
        file: file.to_owned(),
        line,
        col,
        reason,
    };
    let mut pos = start_m.to_vec();
    let mut abs = true;
    let mut motion = Motion::Linear;
    let mut plane = Plane::Xy;
    let mut feed_mps = default_feed_mm_per_min / 60_000.0;
    let rapid_mps = rapid_mm_per_min / 60_000.0;
    let mut ops = Vec::new();
    for b in blocks {
        let mut dwell = false;
        let mut switch = None;
        for &(g, col) in &b.g {
            match g {
                0 => motion = Motion::Rapid,
                1 => motion = Motion::Linear,
                2 => motion = Motion::ArcCw,
                3 => motion = Motion::ArcCcw,
                4 => dwell = true,
                5 => {
                    let p = b.word('P').ok_or_else(|| {
                        err(
                            b.line,
                            col,
                            "G05 needs P4 (direct command on) or P0 (off)".into(),
                        )
                    })?;
                    switch = Some(match p.value {
                        4.0 => Mode::Direct,
                        0.0 => Mode::Normal,
                        v => {
                            return Err(err(
                                b.line,
                                p.col,
                                format!("G05 P{v}: only P4 (direct on) and P0 (off) exist"),
                            ));
                        }
                    });
                }
                17 => plane = Plane::Xy,
                18 => plane = Plane::Zx,
                21 => {}
                90 => abs = true,
                91 => abs = false,
                20 => {
                    return Err(err(
                        b.line,
                        col,
                        "G20 (inch) is not supported; programs are in mm".into(),
                    ));
                }
                _ => return Err(err(b.line, col, format!("G{g:02} is not supported"))),
            }
        }
        if let Some(f) = b.word('F') {
            if f.value <= 0.0 {
                return Err(err(b.line, f.col, format!("feed F{} must be > 0", f.value)));
            }
            feed_mps = f.value / 60_000.0;
        }
        if let Some(mode) = switch {
            ops.push(Op::Switch { line: b.line, mode });
            continue;
        }
        if dwell {
            let t_s = match (b.word('P'), b.word('X').or(b.word('U'))) {
                (Some(p), _) => p.value * 1e-3,
                (None, Some(x)) => x.value,
                (None, None) => {
                    return Err(err(b.line, 1, "G04 needs P (ms) or X (s)".into()));
                }
            };
            if t_s < 0.0 {
                return Err(err(b.line, 1, "dwell time must be ≥ 0".into()));
            }
            ops.push(Op::Dwell { line: b.line, t_s });
            continue;
        }
        let mut end = pos.clone();
        let mut moved = false;
        for w in &b.words {
            let (abs_letter, incremental) = match w.letter {
                'X' | 'Y' | 'Z' | 'C' => (w.letter, !abs),
                'U' => ('X', true),
                'V' => ('Y', true),
                'W' => ('Z', true),
                'H' => ('C', true),
                _ => continue,
            };
            let idx = letters.iter().position(|&l| l == abs_letter).ok_or_else(|| {
                let have: String = letters.iter().collect();
                err(
                    b.line,
                    w.col,
                    format!("{} moves axis {abs_letter}, which this channel does not have (it has {have})", w.letter),
                )
            })?;
            let v = w.value * 1e-3;
            end[idx] = if incremental { end[idx] + v } else { v };
            moved = true;
        }
        let ends = b.m.iter().any(|&(m, _)| m == 30 || m == 2);
        if moved {
            let mut path = Path::Line;
            let mut length_m = dist(&pos, &end);
            if matches!(motion, Motion::ArcCw | Motion::ArcCcw) {
                let (la, lb, ca, cb) = match plane {
                    Plane::Xy => ('X', 'Y', 'I', 'J'),
                    Plane::Zx => ('Z', 'X', 'K', 'I'),
                };
                let ia = letters.iter().position(|&l| l == la);
                let ib = letters.iter().position(|&l| l == lb);
                let (Some(a), Some(bi)) = (ia, ib) else {
                    return Err(err(
                        b.line,
                        1,
                        format!("an arc in the {la}{lb} plane needs axes {la} and {lb}"),
                    ));
                };
                let (sa, sb, ea, eb) = (pos[a], pos[bi], end[a], end[bi]);
                let center = if let Some(r) = b.word('R') {
                    arc_center_r(sa, sb, ea, eb, r.value * 1e-3, motion == Motion::ArcCw)
                        .ok_or_else(|| {
                            err(
                                b.line,
                                r.col,
                                format!("R{} is too small for this chord", r.value),
                            )
                        })?
                } else {
                    let oa = b.word(ca).map_or(0.0, |w| w.value * 1e-3);
                    let ob = b.word(cb).map_or(0.0, |w| w.value * 1e-3);
                    if oa == 0.0 && ob == 0.0 {
                        return Err(err(
                            b.line,
                            1,
                            format!(
                                "G0{} needs {ca}/{cb} or R",
                                if motion == Motion::ArcCw { 2 } else { 3 }
                            ),
                        ));
                    }
                    (sa + oa, sb + ob)
                };
                let r0 = ((sa - center.0).powi(2) + (sb - center.1).powi(2)).sqrt();
                let r1 = ((ea - center.0).powi(2) + (eb - center.1).powi(2)).sqrt();
                if (r0 - r1).abs() > 1e-6 + 1e-6 * r0 {
                    return Err(err(
                        b.line,
                        1,
                        format!(
                            "arc end point is not on the circle: start radius {:.4} mm, end radius {:.4} mm",
                            r0 * 1e3,
                            r1 * 1e3
                        ),
                    ));
                }
                let t0 = (sb - center.1).atan2(sa - center.0);
                let t1 = (eb - center.1).atan2(ea - center.0);
                let tau = 2.0 * std::f64::consts::PI;
                let full = (ea - sa).abs() < 1e-9 && (eb - sb).abs() < 1e-9;
                let sweep = if motion == Motion::ArcCcw {
                    let d = (t1 - t0).rem_euclid(tau);
                    if full || d == 0.0 { tau } else { d }
                } else {
                    let d = (t0 - t1).rem_euclid(tau);
                    -(if full || d == 0.0 { tau } else { d })
                };
                let arc_len = r0 * sweep.abs();
                let others: f64 = (0..pos.len())
                    .filter(|&i| i != a && i != bi)
                    .map(|i| (end[i] - pos[i]).powi(2))
                    .sum();
                length_m = (arc_len * arc_len + others).sqrt();
                path = Path::Arc {
                    a,
                    b: bi,
                    center_m: center,
                    radius_m: r0,
                    start_rad: t0,
                    sweep_rad: sweep,
                };
            }
            ops.push(Op::Move {
                line: b.line,
                end_m: end.clone(),
                feed_mps: if motion == Motion::Rapid {
                    rapid_mps
                } else {
                    feed_mps
                },
                path,
                length_m,
            });
            pos = end;
        }
        if ends {
            ops.push(Op::End);
            break;
        }
    }
    Ok(ops)
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
    if d == 0.0 || d > 2.0 * r.abs() + 1e-9 {
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
