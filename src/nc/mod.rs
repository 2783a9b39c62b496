//! The NC: one [`Channel`] per program path. Each T2 it hands the amplifier either one position per
//! axis (normal mode: interpolated at T1, acc/dec at T1, subdivided to T2) or a batch of T3 samples
//! per axis (direct-command mode, the processing-mode patent (SPEC §3): every block is one T3
//! sample, acc/dec at T3, sent as one batch per T2).
//!
//! Mode switches (initial parameter, G05P4/G05P0 in the program, or a PLC request) take
//! effect at a block boundary once the acc/dec filter has drained, the way a real control
//! treats G05 as a non-buffered block: the two modes run their filters at different rates,
//! so switching with motion still inside a filter would lose or repeat travel.

pub mod program;

use crate::preset::{AccDec, AccDecKind, Mode};
use program::{Op, Path};

/// Moving-average stage: a velocity step in becomes a linear ramp out.
#[derive(Debug, Clone)]
struct MovingAverage {
    buf: Vec<f64>,
    idx: usize,
    sum: f64,
    same: usize,
    last_in: f64,
}

impl MovingAverage {
    fn new(n: usize, x0: f64) -> MovingAverage {
        let n = n.max(1);
        MovingAverage {
            buf: vec![x0; n],
            idx: 0,
            sum: x0 * n as f64,
            same: n,
            last_in: x0,
        }
    }

    #[inline]
    fn push(&mut self, x: f64) -> f64 {
        let n = self.buf.len();
        if n == 1 {
            self.last_in = x;
            return x;
        }
        self.sum += x - self.buf[self.idx];
        self.buf[self.idx] = x;
        self.idx = if self.idx + 1 == n { 0 } else { self.idx + 1 };
        if x == self.last_in {
            self.same = (self.same + 1).min(n);
        } else {
            self.same = 1;
            self.last_in = x;
        }
        // Once the window holds one value the output is that value exactly; resetting the
        // running sum here also stops rounding from accumulating over long runs.
        if self.same >= n {
            self.sum = x * n as f64;
            x
        } else {
            self.sum / n as f64
        }
    }

    fn settled(&self) -> bool {
        self.same >= self.buf.len()
    }
}

/// Acc/dec after interpolation for one axis: zero, one or two moving-average stages.
#[derive(Debug, Clone)]
pub struct AccDecFilter {
    stages: Vec<MovingAverage>,
}

impl AccDecFilter {
    /// Builds the filter for samples of period `period_s`, starting at rest at `x0`.
    pub fn new(p: &AccDec, period_s: f64, x0: f64) -> AccDecFilter {
        let n = |tc: f64| ((tc / period_s).round() as usize).max(1);
        let stages = match p.kind {
            AccDecKind::None => vec![],
            AccDecKind::Linear => vec![MovingAverage::new(n(p.tc1_s), x0)],
            AccDecKind::Bell => vec![
                MovingAverage::new(n(p.tc1_s), x0),
                MovingAverage::new(n(p.tc2_s), x0),
            ],
        };
        AccDecFilter { stages }
    }

    /// Feeds the next interpolated position (m) and returns the smoothed one, one per sample.
    #[inline]
    pub fn push(&mut self, x: f64) -> f64 {
        self.stages.iter_mut().fold(x, |v, s| s.push(v))
    }

    /// True when every stage holds one value: no motion left inside the filter.
    pub fn settled(&self) -> bool {
        self.stages.iter().all(MovingAverage::settled)
    }
}

/// The motion in progress, sampled at T1 (normal mode).
#[derive(Debug, Clone)]
struct Segment {
    start: Vec<f64>,
    end: Vec<f64>,
    path: Path,
    n_ticks: u64,
    k: u64,
}

/// The periods a channel works with: T1, T3, and the ratios T1/T2 and T2/T3.
#[derive(Debug, Clone, Copy)]
pub struct ChannelTiming {
    /// Interpolation period T1, s.
    pub t1_s: f64,
    /// Amplifier control period T3, s (one direct-command block each).
    pub t3_s: f64,
    /// T1/T2: position commands generated per interpolation period.
    pub n12: u32,
    /// T2/T3: amplifier cycles per generated position command.
    pub n23: u32,
}

/// One NC channel (path): program, modal state, interpolator, acc/dec and mode.
#[derive(Debug, Clone)]
pub struct Channel {
    ops: Vec<Op>,
    pc: usize,
    /// Processing mode in force: normal (T1 interpolation) or direct command (T3 blocks).
    pub mode: Mode,
    pending: Option<Mode>,
    /// Switch latched in direct mode, applied at the start of the next T2 batch.
    switch_next: Option<Mode>,
    accdec: AccDec,
    t1_s: f64,
    t3_s: f64,
    n12: u32,
    n23: u32,
    /// Interpolator output (before acc/dec), m.
    prog_pos: Vec<f64>,
    seg: Option<Segment>,
    dwell_ticks: u64,
    filters: Vec<AccDecFilter>,
    q_prev: Vec<f64>,
    q_cur: Vec<f64>,
    t1_phase: u32,
    ended: bool,
    /// Program line (1-based) of the block being executed; 0 before the first.
    pub line: usize,
}

impl Channel {
    /// A channel at rest at `start_m` (m per channel axis), about to run `ops` in `initial_mode`.
    pub fn new(
        ops: Vec<Op>,
        start_m: &[f64],
        initial_mode: Mode,
        accdec: AccDec,
        timing: ChannelTiming,
    ) -> Channel {
        let ChannelTiming {
            t1_s,
            t3_s,
            n12,
            n23,
        } = timing;
        let mut ch = Channel {
            ops,
            pc: 0,
            mode: initial_mode,
            pending: None,
            switch_next: None,
            accdec,
            t1_s,
            t3_s,
            n12,
            n23,
            prog_pos: start_m.to_vec(),
            seg: None,
            dwell_ticks: 0,
            filters: vec![],
            q_prev: start_m.to_vec(),
            q_cur: start_m.to_vec(),
            t1_phase: 0,
            ended: false,
            line: 0,
        };
        ch.reset_filters();
        ch
    }

    fn reset_filters(&mut self) {
        let period = match self.mode {
            Mode::Normal => self.t1_s,
            Mode::Direct => self.t3_s,
        };
        self.filters = self
            .prog_pos
            .iter()
            .map(|&x| AccDecFilter::new(&self.accdec, period, x))
            .collect();
        self.q_prev.clone_from(&self.prog_pos);
        self.q_cur.clone_from(&self.prog_pos);
        self.t1_phase = 0;
    }

    /// Live edit of the acc/dec: takes effect once the filter is at rest.
    pub fn set_accdec(&mut self, accdec: AccDec) {
        self.accdec = accdec;
        if self.filters.iter().all(AccDecFilter::settled) {
            self.reset_filters();
        }
    }

    /// A PLC request: switch at the next block boundary.
    pub fn request_mode(&mut self, mode: Mode) {
        if mode != self.mode {
            self.pending = Some(mode);
        }
    }

    /// Program ended and all motion has left the acc/dec filter.
    pub fn finished(&self) -> bool {
        self.ended && self.filters.iter().all(AccDecFilter::settled)
    }

    /// Produces the next T2 worth of uncompensated commands. In normal mode `target[i]` is
    /// the position at the end of this T2 period; in direct mode `batch[i*n23 + j]` holds the
    /// n23 T3 samples. Returns the mode the data was produced in.
    #[inline]
    pub fn tick_t2(&mut self, target: &mut [f64], batch: &mut [f64]) -> Mode {
        if let Some(m) = self.switch_next.take() {
            self.mode = m;
            self.reset_filters();
        }
        if self.mode == Mode::Normal {
            if self.t1_phase == 0 {
                self.tick_t1();
            }
            if self.mode == Mode::Normal {
                let f = (self.t1_phase + 1) as f64 / self.n12 as f64;
                for (i, t) in target.iter_mut().enumerate() {
                    *t = self.q_prev[i] + (self.q_cur[i] - self.q_prev[i]) * f;
                }
                self.t1_phase += 1;
                if self.t1_phase == self.n12 {
                    self.t1_phase = 0;
                }
                return Mode::Normal;
            }
        }
        let n23 = self.n23 as usize;
        for j in 0..n23 {
            self.next_direct_sample();
            for i in 0..self.prog_pos.len() {
                let q = self.filters[i].push(self.prog_pos[i]);
                batch[i * n23 + j] = q;
            }
        }
        Mode::Direct
    }

    /// Normal mode, once per T1: advance the interpolator, then acc/dec.
    fn tick_t1(&mut self) {
        self.next_t1_position();
        if self.mode == Mode::Direct {
            return;
        }
        std::mem::swap(&mut self.q_prev, &mut self.q_cur);
        for i in 0..self.prog_pos.len() {
            self.q_cur[i] = self.filters[i].push(self.prog_pos[i]);
        }
    }

    fn settled(&self) -> bool {
        self.filters.iter().all(AccDecFilter::settled)
    }

    /// Takes a latched mode switch if the filters are at rest. Returns true if it switched.
    fn try_switch(&mut self) -> bool {
        if let Some(m) = self.pending
            && self.settled()
        {
            self.pending = None;
            if m != self.mode {
                self.mode = m;
                self.reset_filters();
                return true;
            }
        }
        false
    }

    fn next_t1_position(&mut self) {
        loop {
            if let Some(seg) = &mut self.seg {
                seg.k += 1;
                let s = seg.k as f64 / seg.n_ticks as f64;
                program::point_on(&seg.path, &seg.start, &seg.end, s, &mut self.prog_pos);
                if seg.k >= seg.n_ticks {
                    self.prog_pos.clone_from(&seg.end);
                    self.seg = None;
                }
                return;
            }
            if self.dwell_ticks > 0 {
                self.dwell_ticks -= 1;
                return;
            }
            if self.pending.is_some() {
                if self.try_switch() {
                    return;
                }
                if self.pending.is_some() {
                    return; // hold while the filter drains
                }
            }
            if let Some(Op::Move {
                line,
                end_m,
                feed_mps,
                path,
                length_m,
            }) = self.next_op(self.t1_s)
            {
                self.line = line;
                let n_ticks = (length_m / (feed_mps * self.t1_s)).ceil().max(1.0) as u64;
                self.seg = Some(Segment {
                    start: self.prog_pos.clone(),
                    end: end_m,
                    path,
                    n_ticks,
                    k: 0,
                });
            } else if self.ended {
                return;
            }
        }
    }

    /// Fetches the next operation of the program. Dwell, mode switch and end are taken
    /// here (a dwell counts in ticks of `tick_s`); a move is returned to the caller.
    fn next_op(&mut self, tick_s: f64) -> Option<Op> {
        if self.ended {
            return None;
        }
        let Some(op) = self.ops.get(self.pc).cloned() else {
            self.ended = true;
            return None;
        };
        self.pc += 1;
        match op {
            Op::Move { .. } => Some(op),
            Op::Dwell { line, t_s } => {
                self.line = line;
                self.dwell_ticks = (t_s / tick_s).round() as u64;
                None
            }
            Op::Switch { line, mode } => {
                self.line = line;
                self.pending = Some(mode);
                None
            }
            Op::End => {
                self.ended = true;
                None
            }
        }
    }

    /// Direct mode: one block is one T3 sample.
    fn next_direct_sample(&mut self) {
        loop {
            if self.switch_next.is_some() {
                return;
            }
            if self.dwell_ticks > 0 {
                self.dwell_ticks -= 1;
                return;
            }
            if let Some(m) = self.pending {
                if self.settled() {
                    self.pending = None;
                    if m != self.mode {
                        self.switch_next = Some(m);
                    }
                }
                return;
            }
            if let Some(Op::Move { line, end_m, .. }) = self.next_op(self.t3_s) {
                self.line = line;
                self.prog_pos = end_m;
                return;
            } else if self.ended {
                return;
            }
        }
    }
}
