//! Figures an engineer reads off a run: following-error and position-error peaks and RMS,
//! and the peak error after each reversal of the command, split by direction.

use crate::preset::comp::Reversal as Direction;
use crate::trace::{AxisSignal, Trace};
use crate::units::{m_to_mm, m_to_um, mm_to_um};

/// Increments of the command below this (m) are standstill, not motion: a picometre.
const MOVE_EPS_M: f64 = 1e-12;
/// Longest window after a reversal in which its peak error is looked for.
const REVERSAL_WINDOW_S: f64 = 0.25;

/// One reversal of the program command and the error it leaves (the quadrant glitch, lost motion).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Reversal {
    /// Time of the first sample moving the new way, s.
    pub t_s: f64,
    /// Turning point: the command at the sample before the reversal, mm.
    pub pos_mm: f64,
    /// Which reversal (+ to −, or − to +).
    pub direction: Direction,
    /// Largest change of the error (cmd − pos), in the window after the reversal, from its
    /// steady value in the old direction (taken mid-way through the previous stroke): the
    /// step or spike the reversal causes. A constant offset (which setting the reference
    /// point removes) does not count.
    pub peak_err_mm: f64,
    /// The same change at the end of the window: the lost motion that remains once the
    /// transient has passed.
    pub settled_err_mm: f64,
    /// Largest |cmd − pos| in the same window.
    pub peak_abs_err_mm: f64,
    /// The same change at the last sample before the reversal: what the stop before it
    /// already did (a table coasting across its play while the axis decelerates, say).
    /// A compensation started by the command's reversal comes after it.
    pub before_err_mm: f64,
}

/// Error figures of one axis over a whole trace.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AxisSummary {
    /// Axis name as in the trace columns, e.g. "x".
    pub axis: String,
    /// Largest |following error| of the position loop (`ferr`), mm; the position error if absent.
    pub max_ferr_mm: f64,
    /// RMS following error (`ferr`), mm; the position error's if absent.
    pub rms_ferr_mm: f64,
    /// Largest |cmd − pos|: program command minus measured position, mm.
    pub max_err_mm: f64,
    /// RMS of cmd − pos, mm.
    pub rms_err_mm: f64,
    /// Every reversal of the command, in time order.
    pub reversals: Vec<Reversal>,
}

/// Finds reversals of `cmd` (m, as a trace holds it): sign changes of its increments, standstill
/// keeping the last direction. Returns (index of the first sample moving the new way, +1 for −→+ /
/// −1 for
/// +→−); the turning point is the sample before it.
pub fn reversals(cmd: &[f64]) -> Vec<(usize, f64)> {
    let mut out = Vec::new();
    let mut dir = 0.0;
    for i in 1..cmd.len() {
        let d = cmd[i] - cmd[i - 1];
        if d.abs() <= MOVE_EPS_M || !d.is_finite() {
            continue;
        }
        let s = d.signum();
        if dir != 0.0 && s != dir {
            out.push((i, s));
        }
        dir = s;
    }
    out
}

fn max_rms(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut max, mut sq, mut n) = (0.0_f64, 0.0, 0usize);
    for x in v.filter(|x| x.is_finite()) {
        max = max.max(x.abs());
        sq += x * x;
        n += 1;
    }
    (max, if n > 0 { (sq / n as f64).sqrt() } else { 0.0 })
}

/// Error figures for every axis of `trace` that has both `cmd` and `pos`. The trace holds
/// m; the figures are in mm, as an engineer reads them.
pub fn summarize(trace: &Trace) -> Vec<AxisSummary> {
    let t = trace.t();
    let mm = |(max, rms): (f64, f64)| (m_to_mm(max), m_to_mm(rms));
    trace
        .axes()
        .into_iter()
        .filter_map(|axis| {
            let cmd = trace.axis_values(&axis, AxisSignal::Cmd)?;
            let pos = trace.axis_values(&axis, AxisSignal::Pos)?;
            let err: Vec<f64> = cmd.iter().zip(pos).map(|(c, p)| c - p).collect();
            let (max_err_mm, rms_err_mm) = mm(max_rms(err.iter().copied()));
            let (max_ferr_mm, rms_ferr_mm) = match trace.axis_values(&axis, AxisSignal::Ferr) {
                Some(f) => mm(max_rms(f.iter().copied())),
                None => (max_err_mm, rms_err_mm),
            };
            let revs = reversals(cmd);
            let first_move = cmd
                .windows(2)
                .position(|w| (w[1] - w[0]).abs() > MOVE_EPS_M)
                .unwrap_or(0);
            let reversals = revs
                .iter()
                .enumerate()
                .map(|(n, &(i, s))| {
                    let t0 = t[i];
                    let t_end = revs
                        .get(n + 1)
                        .map_or(f64::INFINITY, |&(k, _)| t[k])
                        .min(t0 + REVERSAL_WINDOW_S);
                    let window = || (i..t.len()).take_while(|&k| t[k] <= t_end);
                    // Steady error in the old direction: mid-way through the previous stroke.
                    let prev_start = if n == 0 { first_move } else { revs[n - 1].0 };
                    let e0 = err[(prev_start + i) / 2];
                    let peak = window()
                        .map(|k| (err[k] - e0).abs())
                        .filter(|x| x.is_finite())
                        .fold(0.0, f64::max);
                    let peak_abs = window()
                        .map(|k| err[k].abs())
                        .filter(|x| x.is_finite())
                        .fold(0.0, f64::max);
                    Reversal {
                        t_s: t0,
                        pos_mm: m_to_mm(cmd[i.saturating_sub(1)]),
                        direction: if s > 0.0 {
                            Direction::MinusToPlus
                        } else {
                            Direction::PlusToMinus
                        },
                        peak_err_mm: m_to_mm(peak),
                        settled_err_mm: m_to_mm(window().last().map_or(0.0, |k| err[k] - e0)),
                        peak_abs_err_mm: m_to_mm(peak_abs),
                        before_err_mm: m_to_mm(err[i.saturating_sub(1)] - e0),
                    }
                })
                .collect();
            Some(AxisSummary {
                axis,
                max_ferr_mm,
                rms_ferr_mm,
                max_err_mm,
                rms_err_mm,
                reversals,
            })
        })
        .collect()
}

/// A plain-text summary, as the CLI prints it.
pub fn format_summary(trace: &Trace, sums: &[AxisSummary]) -> String {
    let mut s = format!(
        "samples: {}  duration: {:.4} s\n",
        trace.len(),
        trace.t().last().copied().unwrap_or(0.0)
    );
    for a in sums {
        s += &format!(
            "axis {}: following error max {:.4} µm, rms {:.4} µm; position error (cmd − actual) max {:.4} µm, rms {:.4} µm\n",
            a.axis,
            mm_to_um(a.max_ferr_mm),
            mm_to_um(a.rms_ferr_mm),
            mm_to_um(a.max_err_mm),
            mm_to_um(a.rms_err_mm)
        );
        if let Some(th) = trace.axis_values(&a.axis, AxisSignal::Thermal)
            && th.iter().any(|&x| x != 0.0)
        {
            let comp = trace.axis_values(&a.axis, AxisSignal::ThermalComp);
            let resid = th
                .iter()
                .enumerate()
                .map(|(k, &x)| x + comp.map_or(0.0, |c| c[k]));
            let (max, rms) = max_rms(resid);
            s += &format!(
                "  thermal residual (growth − correction): max {:.3} µm, rms {:.3} µm\n",
                m_to_um(max),
                m_to_um(rms)
            );
        }
        if a.reversals.is_empty() {
            s += "  no reversals\n";
        } else if a.reversals.len() > 12 {
            let (mut up, mut dn) = (0.0_f64, 0.0_f64);
            for r in &a.reversals {
                if r.direction == Direction::PlusToMinus {
                    dn = dn.max(r.peak_err_mm);
                } else {
                    up = up.max(r.peak_err_mm);
                }
            }
            s += &format!(
                "  {} reversals: largest peak error change +→− {:.4} µm, −→+ {:.4} µm\n",
                a.reversals.len(),
                mm_to_um(dn),
                mm_to_um(up)
            );
        }
        for r in a.reversals.iter().filter(|_| a.reversals.len() <= 12) {
            s += &format!(
                "  reversal {} at t = {:.4} s, {} = {:.4} mm: peak error change {:.4} µm, settled change {:+.4} µm (peak |error| {:.4} µm)\n",
                r.direction.arrow(),
                r.t_s,
                a.axis,
                r.pos_mm,
                mm_to_um(r.peak_err_mm),
                mm_to_um(r.settled_err_mm),
                mm_to_um(r.peak_abs_err_mm)
            );
        }
    }
    s
}
