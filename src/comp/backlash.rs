//! Backlash compensation with a separate output mode per reversal direction (backlash patent, SPEC
//! §2).
//!
//! Once per distribution cycle (each generated position command) the sign of the
//! distributed move command is compared with the last non-zero one. On a reversal the
//! correction for the new direction is output by that direction's mode:
//! - `lump`: all of it in the reversal cycle;
//! - `distance`: N equal parts A; the first in the reversal cycle, with the register R set to
//!   that cycle's travel; then, each cycle, if R ≥ B·n (R as accumulated up to the previous
//!   cycle) n is incremented and, while n ≤ N, one more part is output; R then accumulates
//!   this cycle's travel (the seed's steps S13–S17);
//! - `time`: M equal parts, one per cycle for M consecutive cycles;
//! - `function`: the cumulative share of the amount follows a table of distance or time
//!   since the reversal (the seed's variant).
//!
//! Sign convention (as on the seed's control): the correction is added to the move command.
//! Like the seed's flag F = 0 at power-on, nothing is output until the first reversal; the
//! first direction of motion is the reference direction. Moving in the reference direction
//! the accumulated correction is 0; moving against it, it is +Q when moving + and −Q when
//! moving − (a + → − reversal adds −Q in total, − → + adds +Q).
//!
//! A new reversal while parts are still pending starts the new direction's sequence with
//! whatever amount takes the accumulated correction from where it is to the new direction's
//! value, split by that direction's mode (N or M parts of that amount). So the correction
//! always ends at the value of the current direction, however short the strokes.

use super::{CompSignal, PosCompCtx, PositionComp};
use crate::preset::comp::{BacklashParams, FunctionBasis, OutputMode};
use crate::signal::AxisSignal;
use crate::units::{ms_to_s, um_to_m};

/// Commanded travel per cycle below this (m) is standstill, not a direction.
pub const MOVE_EPS_M: f64 = 1e-12;

/// The sequence being output after the latest reversal.
#[derive(Debug, Clone)]
struct Sequence {
    mode: OutputMode,
    /// Amount this sequence must add in total (signed), m.
    amount_m: f64,
    /// Part size for distance/time modes, m.
    part_m: f64,
    /// Parts output so far (the seed's n or m).
    n: u32,
    parts: u32,
    /// Register R: commanded travel since the reversal, m.
    r_m: f64,
    step_b_m: f64,
    cycles: u32,
    basis: FunctionBasis,
    /// (x in m or s, share)
    table: Vec<(f64, f64)>,
    /// Share output so far (function mode).
    share: f64,
    /// Output of this sequence so far, m.
    emitted_m: f64,
}

/// Backlash compensation of one axis.
pub struct Backlash {
    axis: usize,
    axis_name: String,
    /// The preset's parameters (Q and each direction's output mode); editable while running.
    pub p: BacklashParams,
    /// Last non-zero direction of the distributed move command.
    pub dir: i8,
    /// First direction of motion: the direction whose correction is 0.
    pub ref_dir: i8,
    /// Accumulated correction C, m.
    pub acc_m: f64,
    /// Output of the latest cycle, m.
    pub out_m: f64,
    seq: Option<Sequence>,
    /// Reversals of the distributed move command seen since start.
    pub reversals: u64,
}

impl Backlash {
    /// Compensation for axis index `axis`, as at power-on: no direction yet, correction 0.
    pub fn new(axis: usize, axis_name: &str, p: BacklashParams) -> Backlash {
        Backlash {
            axis,
            axis_name: axis_name.to_owned(),
            p,
            dir: 0,
            ref_dir: 0,
            acc_m: 0.0,
            out_m: 0.0,
            seq: None,
            reversals: 0,
        }
    }

    /// Index of the compensated axis, in preset order.
    pub fn axis(&self) -> usize {
        self.axis
    }

    /// The value the accumulated correction settles at while moving in `dir`.
    pub fn target_m(&self, dir: i8) -> f64 {
        if dir == 0 || dir == self.ref_dir {
            0.0
        } else {
            dir as f64 * um_to_m(self.p.q_um)
        }
    }

    /// One distribution cycle with commanded travel `d_m` and cycle time `period_s`.
    /// Returns this cycle's output (m); the accumulated correction is `acc_m`.
    #[inline]
    pub fn cycle(&mut self, d_m: f64, period_s: f64) -> f64 {
        let s: i8 = if d_m > MOVE_EPS_M {
            1
        } else if d_m < -MOVE_EPS_M {
            -1
        } else {
            0
        };
        let travel = d_m.abs();
        let mut out = 0.0;
        if s != 0 && self.dir != 0 && s != self.dir {
            out = self.start_reversal(s, travel, period_s);
        } else if s != 0 && self.dir == 0 {
            self.ref_dir = s;
        } else if let Some(seq) = &mut self.seq {
            let (o, done) = seq.next(travel, period_s);
            out = o;
            if done {
                self.seq = None;
            }
        }
        if s != 0 {
            self.dir = s;
        }
        self.acc_m += out;
        self.out_m = out;
        out
    }

    /// A reversal into direction `s`: starts that direction's sequence for whatever takes
    /// the accumulated correction to the new direction's value; returns its first output.
    fn start_reversal(&mut self, s: i8, travel: f64, period_s: f64) -> f64 {
        self.reversals += 1;
        let dp = if s < 0 {
            &self.p.plus_to_minus
        } else {
            &self.p.minus_to_plus
        };
        let amount = self.target_m(s) - self.acc_m;
        let mut seq = Sequence {
            mode: dp.mode,
            amount_m: amount,
            part_m: 0.0,
            n: 1,
            parts: 1,
            r_m: travel,
            step_b_m: um_to_m(dp.step_b_um),
            cycles: 1,
            basis: dp.function_basis,
            table: dp
                .function
                .iter()
                .map(|&(x, f)| match dp.function_basis {
                    FunctionBasis::Distance => (um_to_m(x), f),
                    FunctionBasis::Time => (ms_to_s(x), f),
                })
                .collect(),
            share: 0.0,
            emitted_m: 0.0,
        };
        let out = match dp.mode {
            OutputMode::Lump => amount,
            OutputMode::Distance | OutputMode::Time => {
                let n = if dp.mode == OutputMode::Distance {
                    dp.parts_n
                } else {
                    dp.cycles_m
                };
                seq.parts = n.max(1);
                seq.part_m = amount / seq.parts as f64;
                seq.part_m
            }
            OutputMode::Function => {
                let x = match seq.basis {
                    FunctionBasis::Distance => seq.r_m,
                    FunctionBasis::Time => period_s,
                };
                function_output(&mut seq, x)
            }
        };
        let done = match seq.mode {
            OutputMode::Lump => true,
            OutputMode::Distance | OutputMode::Time => seq.parts == 1,
            OutputMode::Function => seq.share >= 1.0,
        };
        seq.emitted_m = out;
        self.seq = if done { None } else { Some(seq) };
        out
    }
}

impl Sequence {
    /// The output of the next cycle of a running sequence (m), and whether it is the last.
    fn next(&mut self, travel: f64, period_s: f64) -> (f64, bool) {
        let mut out = 0.0;
        let done = match self.mode {
            OutputMode::Lump => true,
            OutputMode::Distance => {
                if self.r_m >= self.step_b_m * self.n as f64 {
                    self.n += 1;
                    if self.n > self.parts {
                        true
                    } else {
                        self.r_m += travel;
                        out = self.part_m;
                        self.n == self.parts
                    }
                } else {
                    self.r_m += travel;
                    false
                }
            }
            OutputMode::Time => {
                self.n += 1;
                if self.n > self.parts {
                    true
                } else {
                    out = self.part_m;
                    self.n == self.parts
                }
            }
            OutputMode::Function => {
                self.r_m += travel;
                self.cycles += 1;
                let x = match self.basis {
                    FunctionBasis::Distance => self.r_m,
                    FunctionBasis::Time => self.cycles as f64 * period_s,
                };
                out = function_output(self, x);
                self.share >= 1.0
            }
        };
        if done {
            // The last part lands the correction exactly on its target, whatever rounding
            // the division into parts left.
            if out != 0.0 {
                out = self.amount_m - self.emitted_m;
            }
        } else {
            self.emitted_m += out;
        }
        (out, done)
    }
}

/// Function mode: output the growth of the share since the last cycle; at or past the end of
/// the table the share is 1.
fn function_output(seq: &mut Sequence, x: f64) -> f64 {
    let end = seq.table.last().map_or(0.0, |p| p.0);
    let share = if x >= end {
        1.0
    } else {
        crate::table::interp(&seq.table, x)
    };
    let share = share.max(seq.share);
    let out = seq.amount_m * (share - seq.share);
    seq.share = share;
    out
}

impl PositionComp for Backlash {
    fn reads_machine(&self) -> bool {
        false
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn name(&self) -> &str {
        "backlash"
    }

    fn step(&mut self, ctx: &PosCompCtx<'_>, out_m: &mut [f64]) {
        let d = ctx.cmd_m[self.axis] - ctx.prev_cmd_m[self.axis];
        self.cycle(d, ctx.period_s);
        out_m[self.axis] += self.acc_m;
    }

    fn signals(&self) -> Vec<CompSignal> {
        vec![CompSignal {
            axis: self.axis_name.clone(),
            signal: AxisSignal::BacklashComp.name().into(),
            quantity: AxisSignal::BacklashComp.quantity(),
        }]
    }

    fn values(&self, out: &mut [f64]) {
        out[0] = self.acc_m;
    }
}
