//! Position- and time-dependent shapes of the hidden effects: the screw's lead map, the
//! payload spring laws and the forces acting on the carriage.

use std::f64::consts::TAU;

/// Rise (and fall) time of a disturbance edge, s: a force never steps within an integration
/// sub-step, so the fixed-step integrator keeps its order through the edges.
pub const EDGE_S: f64 = 0.0005;

/// Travel error of the nut against an ideal screw: carriage position = u + e(u) for motor
/// travel u. Its slope and curvature make the carriage's inertia and a velocity-squared
/// force depend on where the nut is (see [`super::rig`]).
#[derive(Debug, Clone, Default)]
pub enum LeadMap {
    /// An ideal screw.
    #[default]
    Ideal,
    /// Cyclic error with up to three harmonics of one pitch plus a cumulative slope.
    Harmonic(Harmonics),
    /// A smooth tabulated error (natural cubic spline through equally spaced knots).
    Table(Spline),
}

impl LeadMap {
    /// Error e, slope e′ and curvature e″ at motor travel `u_m`.
    #[inline]
    pub fn eval(&self, u_m: f64) -> (f64, f64, f64) {
        match self {
            LeadMap::Ideal => (0.0, 0.0, 0.0),
            LeadMap::Harmonic(h) => h.eval(u_m),
            LeadMap::Table(s) => s.eval(u_m),
        }
    }
}

/// Cyclic lead error: Σ amp_h·sin(2π·h·u/pitch + phase_h) for h = 1, 2, 3, plus slope·u.
#[derive(Debug, Clone)]
pub struct Harmonics {
    /// Spatial period of the fundamental, m.
    pub pitch_m: f64,
    /// Amplitudes of harmonics 1, 2, 3, m.
    pub amp_m: [f64; 3],
    /// Phases of harmonics 1, 2, 3, rad.
    pub phase_rad: [f64; 3],
    /// Cumulative lead deviation, m/m.
    pub slope: f64,
    /// (sin, cos) of the phases, computed once.
    phase_sc: [(f64, f64); 3],
}

impl Harmonics {
    /// The error with these harmonics and cumulative slope.
    pub fn new(pitch_m: f64, amp_m: [f64; 3], phase_rad: [f64; 3], slope: f64) -> Harmonics {
        Harmonics {
            pitch_m,
            amp_m,
            phase_rad,
            slope,
            phase_sc: phase_rad.map(f64::sin_cos),
        }
    }

    /// Error, slope and curvature at `u_m`.
    #[inline]
    pub fn eval(&self, u_m: f64) -> (f64, f64, f64) {
        let w = TAU / self.pitch_m;
        let (s1, c1) = (w * u_m).sin_cos();
        // Harmonics by the multiple-angle identities: one sin/cos per call.
        let (s2, c2) = (2.0 * s1 * c1, c1 * c1 - s1 * s1);
        let (s3, c3) = (s1 * (3.0 - 4.0 * s1 * s1), c1 * (4.0 * c1 * c1 - 3.0));
        let (mut e, mut de, mut dde) = (self.slope * u_m, self.slope, 0.0);
        for (h, (sh, ch)) in [(s1, c1), (s2, c2), (s3, c3)].into_iter().enumerate() {
            let (sp, cp) = self.phase_sc[h];
            let sin_arg = sh * cp + ch * sp;
            let cos_arg = ch * cp - sh * sp;
            let k = w * (h + 1) as f64;
            e += self.amp_m[h] * sin_arg;
            de += self.amp_m[h] * k * cos_arg;
            dde -= self.amp_m[h] * k * k * sin_arg;
        }
        (e, de, dde)
    }

    /// Peak |e″| over a pitch (bound: Σ amp_h·(2πh/pitch)²), 1/m.
    pub fn max_curvature_per_m(&self) -> f64 {
        let w = TAU / self.pitch_m;
        self.amp_m
            .iter()
            .enumerate()
            .map(|(h, a)| a * (w * (h + 1) as f64).powi(2))
            .sum()
    }
}

/// A natural cubic spline through values at equally spaced knots; outside the knots the
/// end value is held.
#[derive(Debug, Clone)]
pub struct Spline {
    first_m: f64,
    step_m: f64,
    values: Vec<f64>,
    /// Second derivatives at the knots.
    curv: Vec<f64>,
}

impl Spline {
    /// The spline through `values` at `first_m + i·step_m` (at least 3 values).
    pub fn new(first_m: f64, step_m: f64, values: Vec<f64>) -> Spline {
        let n = values.len();
        let mut curv = vec![0.0; n];
        if n >= 3 {
            // Tridiagonal system M[i−1] + 4 M[i] + M[i+1] = 6 Δ²y[i] / h², M[0] = M[n−1] = 0,
            // solved by forward elimination and back substitution.
            let m = n - 2;
            let rhs: Vec<f64> = (1..n - 1)
                .map(|i| {
                    6.0 * (values[i + 1] - 2.0 * values[i] + values[i - 1]) / (step_m * step_m)
                })
                .collect();
            let mut diag = vec![4.0; m];
            let mut r = rhs;
            for i in 1..m {
                let f = 1.0 / diag[i - 1];
                diag[i] -= f;
                r[i] -= f * r[i - 1];
            }
            let mut x = vec![0.0; m];
            for i in (0..m).rev() {
                let next = if i + 1 < m { x[i + 1] } else { 0.0 };
                x[i] = (r[i] - next) / diag[i];
            }
            curv[1..n - 1].copy_from_slice(&x);
        }
        Spline {
            first_m,
            step_m,
            values,
            curv,
        }
    }

    /// The knot values.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Value, slope and curvature at `x_m`.
    #[inline]
    pub fn eval(&self, x_m: f64) -> (f64, f64, f64) {
        let n = self.values.len();
        let u = (x_m - self.first_m) / self.step_m;
        if n < 2 || u <= 0.0 {
            return (self.values.first().copied().unwrap_or(0.0), 0.0, 0.0);
        }
        if u >= (n - 1) as f64 {
            return (self.values[n - 1], 0.0, 0.0);
        }
        let i = (u as usize).min(n - 2);
        let t = u - i as f64;
        let h = self.step_m;
        let (y0, y1, m0, m1) = (
            self.values[i],
            self.values[i + 1],
            self.curv[i],
            self.curv[i + 1],
        );
        let s = 1.0 - t;
        let val = s * y0 + t * y1 + h * h / 6.0 * ((s * s * s - s) * m0 + (t * t * t - t) * m1);
        let slope =
            (y1 - y0) / h + h / 6.0 * (-(3.0 * s * s - 1.0) * m0 + (3.0 * t * t - 1.0) * m1);
        (val, slope, s * m0 + t * m1)
    }
}

/// Force law of the spring between carriage and payload (compliance).
#[derive(Debug, Clone, Copy)]
pub enum SpringLaw {
    /// F = k·d.
    Linear {
        /// Stiffness, N/m.
        k_n_per_m: f64,
    },
    /// F = k·d·(1 + (d/d0)²): a mount that stiffens as it deflects.
    Hardening {
        /// Stiffness at small deflection, N/m.
        k_n_per_m: f64,
        /// Deflection at which the stiffness has doubled, m.
        d0_m: f64,
    },
    /// F = k·(1 + g·(x − x_ref))·d: stiffness changing along the travel x of the carriage.
    Positional {
        /// Stiffness at the reference position, N/m.
        k_n_per_m: f64,
        /// Relative stiffness change per metre of travel, 1/m.
        grad_per_m: f64,
        /// Reference position, m.
        ref_m: f64,
    },
}

impl SpringLaw {
    /// Spring force for deflection `d_m` with the carriage at `x_m`.
    #[inline]
    pub fn force_n(&self, d_m: f64, x_m: f64) -> f64 {
        match *self {
            SpringLaw::Linear { k_n_per_m } => k_n_per_m * d_m,
            SpringLaw::Hardening { k_n_per_m, d0_m } => {
                let r = d_m / d0_m;
                k_n_per_m * d_m * (1.0 + r * r)
            }
            SpringLaw::Positional {
                k_n_per_m,
                grad_per_m,
                ref_m,
            } => k_n_per_m * (1.0 + grad_per_m * (x_m - ref_m)) * d_m,
        }
    }

    /// Small-deflection stiffness, N/m (largest over the travel for the positional law).
    pub fn stiffness_n_per_m(&self) -> f64 {
        match *self {
            SpringLaw::Linear { k_n_per_m } | SpringLaw::Hardening { k_n_per_m, .. } => k_n_per_m,
            SpringLaw::Positional {
                k_n_per_m,
                grad_per_m,
                ..
            } => k_n_per_m * (1.0 + grad_per_m.abs() * 0.3),
        }
    }
}

/// 0 before `t_edge_s`, 1 after it plus [`EDGE_S`], linear in between.
#[inline]
fn edge(t_s: f64, t_edge_s: f64) -> f64 {
    ((t_s - t_edge_s) / EDGE_S).clamp(0.0, 1.0)
}

/// An external force on the table that the nominal model does not know.
#[derive(Debug, Clone)]
pub enum Disturbance {
    /// 0 before `first_rise_s`, then a square wave between 0 and `amplitude_n`, high for
    /// `duty` of each period.
    Square {
        /// Period, s.
        period_s: f64,
        /// Force while high, N.
        amplitude_n: f64,
        /// First rising edge, s.
        first_rise_s: f64,
        /// Share of each period spent high.
        duty: f64,
    },
    /// 0 before `first_rise_s`, then amplitude·sin(2π(t − first_rise)/period).
    Sine {
        /// Period, s.
        period_s: f64,
        /// Amplitude, N.
        amplitude_n: f64,
        /// Start (an upward zero crossing), s.
        first_rise_s: f64,
    },
    /// A level that changes at the given times (level i holds from time i on).
    Steps {
        /// When each level starts, s.
        times_s: Vec<f64>,
        /// The levels, N.
        levels_n: Vec<f64>,
    },
    /// Short force pulses (start, duration, force).
    Bursts {
        /// (start s, duration s, force N) of each pulse.
        pulses: Vec<(f64, f64, f64)>,
    },
}

impl Disturbance {
    /// The force at `t_s`, N.
    #[inline]
    pub fn force_n(&self, t_s: f64) -> f64 {
        match self {
            Disturbance::Square {
                period_s,
                amplitude_n,
                first_rise_s,
                duty,
            } => {
                if t_s < *first_rise_s {
                    return 0.0;
                }
                let phase_s = (t_s - first_rise_s).rem_euclid(*period_s);
                let high_s = duty * period_s;
                amplitude_n * (edge(phase_s, 0.0) - edge(phase_s, high_s))
            }
            Disturbance::Sine {
                period_s,
                amplitude_n,
                first_rise_s,
            } => {
                if t_s < *first_rise_s {
                    return 0.0;
                }
                amplitude_n * (TAU * (t_s - first_rise_s) / period_s).sin()
            }
            Disturbance::Steps { times_s, levels_n } => {
                let mut f = 0.0;
                let mut prev = 0.0;
                for (t, l) in times_s.iter().zip(levels_n) {
                    f += (l - prev) * edge(t_s, *t);
                    prev = *l;
                }
                f
            }
            Disturbance::Bursts { pulses } => pulses
                .iter()
                .map(|&(t0, d, f)| f * (edge(t_s, t0) - edge(t_s, t0 + d)))
                .sum(),
        }
    }
}

/// A force on the carriage, + along the axis.
#[derive(Debug, Clone)]
pub enum Load {
    /// A constant force (gravity component, counterbalance error, preload).
    Constant {
        /// The force, N.
        force_n: f64,
    },
    /// A nearly constant force that changes linearly along the travel (cable carrier,
    /// preload spring): force + grad·(x − ref).
    Gradient {
        /// Force at the reference position, N.
        force_n: f64,
        /// Change per metre of travel, N/m.
        grad_n_per_m: f64,
        /// Reference position, m.
        ref_m: f64,
    },
    /// A force that depends on time only.
    External(Disturbance),
}

impl Load {
    /// The force with the carriage at `x_m` at time `t_s`, N.
    #[inline]
    pub fn force_n(&self, t_s: f64, x_m: f64) -> f64 {
        match self {
            Load::Constant { force_n } => *force_n,
            Load::Gradient {
                force_n,
                grad_n_per_m,
                ref_m,
            } => force_n + grad_n_per_m * (x_m - ref_m),
            Load::External(d) => d.force_n(t_s),
        }
    }
}
