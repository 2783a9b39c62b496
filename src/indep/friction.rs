//! Slide friction on the carriage (guideways and nut): viscous, Coulomb (possibly different
//! per direction), a Stribeck breakaway excess and a short-stroke rise, with either an exact
//! stick phase or a tanh-regularised sign.
//!
//! Friction is split into a velocity-odd viscous part V(v) and a level K(|v|, dir) ≥ 0 that
//! opposes the direction of sliding. With an exact stick phase the carriage stops when its
//! velocity reaches zero and the other forces on it stay within K(0, dir) in both
//! directions; [`super::rig`] handles the events. With the tanh form the level acts as
//! −tanh(v/ε)·K and the equations stay smooth (no stick state; ε sets the creep).

/// Extra viscous friction beyond the linear coefficient.
#[derive(Debug, Clone, Copy, Default)]
pub enum ViscousExtra {
    /// None.
    #[default]
    None,
    /// A different extra coefficient per direction, N·s/m.
    Directional {
        /// Extra coefficient while moving in +, N·s/m.
        pos_n_s_per_m: f64,
        /// Extra coefficient while moving in −, N·s/m.
        neg_n_s_per_m: f64,
    },
    /// F = f_ref·(|v|/v_ref)^δ, linear below `core_mps` (where the power law would have
    /// an infinite slope), so the force stays Lipschitz.
    Power {
        /// Force at the reference speed, N.
        ref_force_n: f64,
        /// Reference speed, m/s.
        ref_speed_mps: f64,
        /// Exponent δ of the power law.
        exponent: f64,
        /// Below this speed the force is linear in v, m/s.
        core_mps: f64,
    },
}

/// Shape of the Stribeck excess over speed s = |v| with characteristic speed vs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StribeckShape {
    /// exp(−s/vs).
    Exponential,
    /// exp(−(s/vs)²).
    Gaussian,
}

/// Breakaway excess: ΔF·shape(|v|/vs) on top of the Coulomb level.
#[derive(Debug, Clone, Copy)]
pub struct StribeckLaw {
    /// Breakaway excess over the Coulomb level at rest, N.
    pub excess_n: f64,
    /// Characteristic speed vs, m/s.
    pub speed_mps: f64,
    /// How the excess decays with speed.
    pub shape: StribeckShape,
}

/// How the short-stroke friction level grows and recovers.
#[derive(Debug, Clone, Copy)]
pub enum StrokeLaw {
    /// Count n of consecutive strokes shorter than the pitch: at each reversal
    /// n ← n·exp(−max(0, stroke − pitch)/recovery) + [stroke < pitch]; level =
    /// F·(1 − exp(−n/n0)).
    Count {
        /// Level reached after many short strokes, N.
        max_n: f64,
        /// A stroke shorter than this counts as short, m.
        pitch_m: f64,
        /// Strokes for the level to reach 63 %.
        n0: f64,
        /// Distance beyond the pitch over which the count decays by e, m.
        recovery_m: f64,
    },
    /// Film breakdown φ ∈ [0, 1] driven by distance: within the first `pitch` of a stroke
    /// dφ/ds = (1 − φ)/breakdown, beyond it dφ/ds = −φ/recovery; level = F·φ.
    Distance {
        /// Level of a fully broken film, N.
        max_n: f64,
        /// Distance from a turning point within which the film breaks down, m.
        pitch_m: f64,
        /// Short-stroke distance over which φ approaches 1 by e, m.
        breakdown_m: f64,
        /// Distance beyond the pitch over which φ decays by e, m.
        recovery_m: f64,
    },
}

/// The friction law of the carriage.
#[derive(Debug, Clone, Default)]
pub struct FrictionLaw {
    /// Linear viscous coefficient, N·s/m.
    pub viscous_n_s_per_m: f64,
    /// Extra viscous friction (directional or power law).
    pub viscous_extra: ViscousExtra,
    /// Coulomb level sliding in +, N.
    pub coulomb_pos_n: f64,
    /// Coulomb level sliding in −, N.
    pub coulomb_neg_n: f64,
    /// Breakaway excess, if any.
    pub stribeck: Option<StribeckLaw>,
    /// Short-stroke rise, if any.
    pub stroke: Option<StrokeLaw>,
    /// Some(ε): tanh(v/ε) instead of a sign with stick, m/s.
    pub tanh_speed_mps: Option<f64>,
}

impl FrictionLaw {
    /// Velocity-odd viscous force magnitude with sign (opposes nothing yet: +v gives +F).
    #[inline]
    pub fn viscous_n(&self, v_mps: f64) -> f64 {
        let mut f = self.viscous_n_s_per_m * v_mps;
        match self.viscous_extra {
            ViscousExtra::None => {}
            ViscousExtra::Directional {
                pos_n_s_per_m,
                neg_n_s_per_m,
            } => {
                f += if v_mps >= 0.0 {
                    pos_n_s_per_m
                } else {
                    neg_n_s_per_m
                } * v_mps;
            }
            ViscousExtra::Power {
                ref_force_n,
                ref_speed_mps,
                exponent,
                core_mps,
            } => {
                let s = v_mps.abs();
                let at = |s: f64| ref_force_n * (s / ref_speed_mps).powf(exponent);
                let mag = if s >= core_mps {
                    at(s)
                } else {
                    at(core_mps) * s / core_mps
                };
                f += mag.copysign(v_mps);
            }
        }
        f
    }

    /// Level K opposing sliding in `dir` (±1) at speed `speed_mps`, with the short-stroke
    /// level `stroke_n` added.
    #[inline]
    pub fn level_n(&self, speed_mps: f64, dir: f64, stroke_n: f64) -> f64 {
        let mut k = if dir >= 0.0 {
            self.coulomb_pos_n
        } else {
            self.coulomb_neg_n
        } + stroke_n;
        if let Some(s) = self.stribeck {
            let r = speed_mps / s.speed_mps;
            k += s.excess_n
                * match s.shape {
                    StribeckShape::Exponential => (-r).exp(),
                    StribeckShape::Gaussian => (-r * r).exp(),
                };
        }
        k
    }

    /// Whether the law has a level at all (otherwise it is smooth and needs no stick logic).
    pub fn has_level(&self) -> bool {
        self.coulomb_pos_n > 0.0
            || self.coulomb_neg_n > 0.0
            || self.stribeck.is_some()
            || self.stroke.is_some()
    }

    /// Whether zero-velocity events (stop, stick, breakaway) are handled exactly.
    pub fn sticks(&self) -> bool {
        self.tanh_speed_mps.is_none() && self.has_level()
    }

    /// Friction force on a carriage moving at `v_mps` that slides in `dir` (stick law) or
    /// any direction (tanh law), N.
    #[inline]
    pub fn force_n(&self, v_mps: f64, dir: f64, stroke_n: f64) -> f64 {
        let visc = self.viscous_n(v_mps);
        if !self.has_level() {
            return -visc;
        }
        match self.tanh_speed_mps {
            Some(eps) => {
                let d = if v_mps >= 0.0 { 1.0 } else { -1.0 };
                -(v_mps / eps).tanh() * self.level_n(v_mps.abs(), d, stroke_n) - visc
            }
            None => -dir * self.level_n(v_mps.abs(), dir, stroke_n) - visc,
        }
    }
}

/// Below this carriage speed a sign change is not a reversal (m/s).
const REVERSAL_SPEED_MPS: f64 = 5e-5;

/// The short-stroke state, updated once per controller period from the carriage motion.
#[derive(Debug, Clone, Default)]
pub struct StrokeState {
    /// Direction of the current stroke (0 before the first motion).
    dir: f64,
    /// Where the current stroke started (the previous turning point), m.
    start_m: f64,
    /// Furthest point of the current stroke, m.
    extreme_m: f64,
    /// Count n or film φ.
    level: f64,
    /// Carriage position at the previous update, m.
    last_m: f64,
}

impl StrokeState {
    /// A state at rest at `x_m`.
    pub fn new(x_m: f64) -> StrokeState {
        StrokeState {
            dir: 0.0,
            start_m: x_m,
            extreme_m: x_m,
            level: 0.0,
            last_m: x_m,
        }
    }

    /// The friction level the state adds, N.
    pub fn force_n(&self, law: &StrokeLaw) -> f64 {
        match *law {
            StrokeLaw::Count { max_n, n0, .. } => max_n * (1.0 - (-self.level / n0).exp()),
            StrokeLaw::Distance { max_n, .. } => max_n * self.level,
        }
    }

    /// Takes the carriage at `x_m` moving at `v_mps` (end of a period).
    pub fn update(&mut self, law: &StrokeLaw, x_m: f64, v_mps: f64) {
        let travelled = (x_m - self.last_m).abs();
        self.last_m = x_m;
        if let StrokeLaw::Distance {
            pitch_m,
            breakdown_m,
            recovery_m,
            ..
        } = *law
        {
            // Exact solution of the linear law over this period's travel.
            let into = (self.extreme_m - self.start_m).abs();
            self.level = if into < pitch_m {
                1.0 - (1.0 - self.level) * (-travelled / breakdown_m).exp()
            } else {
                self.level * (-travelled / recovery_m).exp()
            };
        }
        if self.dir * (x_m - self.extreme_m) > 0.0 || self.dir == 0.0 {
            self.extreme_m = x_m;
        }
        if v_mps.abs() < REVERSAL_SPEED_MPS {
            return;
        }
        let dir = v_mps.signum();
        if dir == self.dir {
            return;
        }
        if self.dir != 0.0 {
            let stroke = (self.extreme_m - self.start_m).abs();
            if let StrokeLaw::Count {
                pitch_m,
                recovery_m,
                ..
            } = *law
            {
                self.level *= (-(stroke - pitch_m).max(0.0) / recovery_m).exp();
                if stroke < pitch_m {
                    self.level += 1.0;
                }
            }
            self.start_m = self.extreme_m;
        }
        self.extreme_m = x_m;
        self.dir = dir;
    }
}
