//! The drive's discrete controller, sampled once per period T3, and the position sensors.
//!
//! Cascade as documented for the EMPS rig: a proportional position loop gives a velocity
//! reference kp·(set − q); the velocity loop puts out kv·(reference − q̇) (plus an optional
//! integral part kv·ki·∫), limited to ±F_max. q̇ comes from the encoder through the 2-tap
//! average q_f(k) = (q(k) + q(k−1))/2 and a backward difference (q_f(k) − q_f(k−1))/T3.
//! The force computed from the reading at the start of period k acts during period k.

/// Controller constants (load side: force per velocity).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gains {
    /// Position-loop gain, 1/s.
    pub kp_per_s: f64,
    /// Velocity-loop gain, N·s/m.
    pub kv_n_s_per_m: f64,
    /// Velocity-loop integral corner, 1/s (0: P only).
    pub ki_per_s: f64,
    /// Output limit, N.
    pub force_limit_n: f64,
    /// Velocity through the 2-tap average (otherwise a plain backward difference).
    pub avg2: bool,
    /// Sampling period, s.
    pub t3_s: f64,
}

/// The controller's memory.
#[derive(Debug, Clone)]
pub struct Controller {
    g: Gains,
    /// Previous encoder reading, m.
    last_m: f64,
    /// Previous filtered position, m.
    filt_m: f64,
    /// Integral part, N.
    integ_n: f64,
}

impl Controller {
    /// A controller at rest with its encoder reading `reading_m`.
    pub fn new(g: Gains, reading_m: f64) -> Controller {
        Controller {
            g,
            last_m: reading_m,
            filt_m: reading_m,
            integ_n: 0.0,
        }
    }

    /// One period: the force command for set-point `set_m` and encoder reading
    /// `reading_m`, N.
    pub fn update(&mut self, set_m: f64, reading_m: f64) -> f64 {
        let g = &self.g;
        let vel_mps = if g.avg2 {
            let filt = 0.5 * (reading_m + self.last_m);
            let v = (filt - self.filt_m) / g.t3_s;
            self.filt_m = filt;
            v
        } else {
            (reading_m - self.last_m) / g.t3_s
        };
        self.last_m = reading_m;
        let vel_err = g.kp_per_s * (set_m - reading_m) - vel_mps;
        let raw = g.kv_n_s_per_m * vel_err + self.integ_n;
        let out = raw.clamp(-g.force_limit_n, g.force_limit_n);
        if g.ki_per_s > 0.0 {
            let step = g.kv_n_s_per_m * g.ki_per_s * g.t3_s * vel_err;
            // Anti-windup: while saturated, integrate only back towards the range.
            if out == raw || step * raw < 0.0 {
                self.integ_n += step;
            }
        }
        out
    }
}

/// How a sensor rounds to its grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GridMode {
    /// To the nearest line.
    Round,
    /// To the last line passed (towards −∞), as a counter that reports whole increments.
    Floor,
}

/// A position sensor's grid (step 0: continuous).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Grid step, m (0: continuous).
    pub step_m: f64,
    /// How a reading is rounded to the grid.
    pub mode: GridMode,
}

impl Grid {
    /// A continuous reading.
    pub const EXACT: Grid = Grid {
        step_m: 0.0,
        mode: GridMode::Round,
    };

    /// What the sensor shows for position `x_m`.
    #[inline]
    pub fn read(&self, x_m: f64) -> f64 {
        if self.step_m <= 0.0 {
            return x_m;
        }
        let n = x_m / self.step_m;
        let whole = match self.mode {
            GridMode::Round => n.round(),
            GridMode::Floor => n.floor(),
        };
        whole * self.step_m
    }
}

/// What the drive does to the set-point before its position loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SetPoint {
    /// Uses it as it is.
    Direct,
    /// Uses it `samples` periods late (fractions evaluate the set-point between samples).
    Delay {
        /// Delay in periods (fractions allowed).
        samples: f64,
    },
    /// A first-order lag with time constant `tau_s` (discretised exactly for a set-point
    /// held over each period).
    Lag {
        /// Time constant, s.
        tau_s: f64,
    },
}
