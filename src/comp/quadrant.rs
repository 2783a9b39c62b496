//! Quadrant (reversal) compensation that adapts to short strokes (quadrant patent, SPEC §5).
//!
//! In the amplifier, every T3: reversals are detected from the internal position command
//! (the acc/dec output the position loop receives). At each reversal the stroke PA since
//! the previous reversal point is compared with P0: PA < P0 adds one to N; otherwise N is
//! reset to 0 (the embodiment) or decremented by one (the claim's "decrease"), as selected.
//! Then M = M0·A^(1 − e^(−N/B)) and T = T0·C^(1 − e^(−N/D)), and a feed-forward pulse of
//! amount M and duration T is injected in the new direction of motion, into the torque
//! command (default), the velocity command or the position command. The pulse is
//! rectangular (M for T) or decays exponentially (M·e^(−t/T), cut after 5T).
//!
//! With `adaptive` off, N stays 0: a fixed TFF of M0 for T0, the conventional compensation
//! the seed improves on. The first reversal measures PA from where the motion started.

use super::{CompSignal, ServoComp, ServoCompCtx, ServoCompOut};
use crate::preset::comp::{Injection, NUpdate, PulseShape, QuadrantParams};
use crate::signal::{AxisSignal, Quantity};
use crate::units::{mm_per_s_to_m_per_s, mm_to_m, um_to_m};

/// Quadrant compensation of one axis.
pub struct Quadrant {
    axis: usize,
    axis_name: String,
    /// The preset's parameters (M0, T0, A–D, P0, shape, injection); editable while running.
    pub p: QuadrantParams,
    dir: i8,
    last_rev_m: Option<f64>,
    /// Distance between the previous and the latest reversal point, m.
    pub pa_m: f64,
    /// Short-stroke count N.
    pub n: f64,
    /// Amount and duration of the latest pulse (M in the injection unit, T in s).
    pub m: f64,
    /// Duration T of the latest pulse, s (the time constant for an exponential pulse).
    pub t_s: f64,
    pulse_age_s: Option<f64>,
    pulse_dir: f64,
    /// Value injected this T3, in the injection unit.
    pub value: f64,
    /// Reversals of the internal position command seen since start.
    pub reversals: u64,
}

impl Quadrant {
    /// Compensation for axis index `axis`; no reversal seen yet, N = 0, so M = M0 and T = T0.
    pub fn new(axis: usize, axis_name: &str, p: QuadrantParams) -> Quadrant {
        let (m, t) = p.m_t(0.0);
        Quadrant {
            axis,
            axis_name: axis_name.to_owned(),
            p,
            dir: 0,
            last_rev_m: None,
            pa_m: 0.0,
            n: 0.0,
            m,
            t_s: t,
            pulse_age_s: None,
            pulse_dir: 0.0,
            value: 0.0,
            reversals: 0,
        }
    }

    /// One T3: command increment `d_m`, reversal point candidate `prev_cmd_m`.
    pub fn tick(&mut self, prev_cmd_m: f64, d_m: f64, t3_s: f64) -> f64 {
        let eps = super::backlash::MOVE_EPS_M;
        let s: i8 = if d_m > eps {
            1
        } else if d_m < -eps {
            -1
        } else {
            0
        };
        if s != 0 && self.dir == 0 {
            self.last_rev_m = Some(prev_cmd_m);
        }
        if s != 0 && self.dir != 0 && s != self.dir {
            self.reversals += 1;
            let here = prev_cmd_m;
            self.pa_m = self.last_rev_m.map_or(f64::INFINITY, |p| (here - p).abs());
            self.last_rev_m = Some(here);
            if self.p.adaptive {
                if self.pa_m < mm_to_m(self.p.p0_mm) {
                    self.n += 1.0;
                } else {
                    self.n = match self.p.update {
                        NUpdate::Reset => 0.0,
                        NUpdate::Decrement => (self.n - 1.0).max(0.0),
                    };
                }
            } else {
                self.n = 0.0;
            }
            let (m, t) = self.p.m_t(self.n);
            self.m = m;
            self.t_s = t;
            self.pulse_age_s = Some(0.0);
            self.pulse_dir = s as f64;
        }
        if s != 0 {
            self.dir = s;
        }
        self.value = match self.pulse_age_s {
            Some(age) => {
                let v = match self.p.shape {
                    PulseShape::Rectangular if age < self.t_s => self.m,
                    PulseShape::Exponential if age < 5.0 * self.t_s => {
                        self.m * (-age / self.t_s).exp()
                    }
                    _ => {
                        self.pulse_age_s = None;
                        0.0
                    }
                };
                if let Some(a) = &mut self.pulse_age_s {
                    *a += t3_s;
                }
                self.pulse_dir * v
            }
            None => 0.0,
        };
        self.value
    }
}

impl ServoComp for Quadrant {
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn name(&self) -> &str {
        "quadrant"
    }

    fn axis(&self) -> usize {
        self.axis
    }

    fn step(&mut self, ctx: &ServoCompCtx, out: &mut ServoCompOut) {
        let v = self.tick(ctx.prev_cmd_m, ctx.cmd_m - ctx.prev_cmd_m, ctx.t3_s);
        match self.p.inject {
            Injection::Torque => out.torque_nm += v,
            Injection::Velocity => out.vel_mps += mm_per_s_to_m_per_s(v),
            Injection::Position => out.pos_m += um_to_m(v),
        }
    }

    fn signals(&self) -> Vec<CompSignal> {
        let s = |name: &str, quantity: Quantity| CompSignal {
            axis: self.axis_name.clone(),
            signal: name.into(),
            quantity,
        };
        let q = match self.p.inject {
            Injection::Torque => Quantity::Torque,
            Injection::Velocity => Quantity::Velocity,
            Injection::Position => Quantity::Length,
        };
        vec![
            s(AxisSignal::QuadrantComp.name(), q),
            s("quadrant_pa", Quantity::Length),
            s("quadrant_n", Quantity::Plain),
            s("quadrant_m", q),
            s("quadrant_t", Quantity::Time),
        ]
    }

    fn values(&self, out: &mut [f64]) {
        // Pulses are set in N·m, mm/s or µm by where they are injected; the trace holds SI.
        let si: fn(f64) -> f64 = match self.p.inject {
            Injection::Torque => std::convert::identity,
            Injection::Velocity => mm_per_s_to_m_per_s,
            Injection::Position => um_to_m,
        };
        out[0] = si(self.value);
        out[1] = if self.pa_m.is_finite() {
            self.pa_m
        } else {
            0.0
        };
        out[2] = self.n;
        out[3] = si(self.m);
        out[4] = self.t_s;
    }
}
