//! The mechanical plant of one feed axis: motor, coupling/backlash, ball screw, table,
//! friction, gravity, screw thermal growth, lead error and the encoders; plus the crossbeam
//! of a vertical lathe, which couples the X position of each tool post into its Z axis.
//!
//! Internally everything is SI and load-side: the motor angle is carried as the table travel
//! it corresponds to (`x_m`), and motor inertia as its reflected mass. Positions are in the
//! screw's own frame (`x_t` is where the nut is along an ideal screw); thermal growth and lead
//! error turn that into where the table really is.

use std::cell::Cell;

use crate::preset::rules::MAX_SUBSTEPS;
use crate::preset::{AxisParams, Coupling, Crossbeam, Feedback, PosSource};
use crate::units;

const G_MPS2: f64 = 9.80665;
/// Below this table speed a sign change is not counted as a reversal (creep noise).
const REVERSAL_SPEED_MPS: f64 = 1e-5;

/// Friction on the slide (guideways + nut), with a stick/slip treatment that lands exactly
/// on zero velocity: no chatter and no drift at rest.
#[derive(Debug, Clone)]
pub struct FrictionModel {
    /// Whether friction acts at all (off: the slide runs free).
    pub enabled: bool,
    /// Kinetic (Coulomb) friction level, N, opposing the direction of motion.
    pub coulomb_n: f64,
    /// Speed-proportional friction coefficient, N·s/m.
    pub viscous_n_s_per_m: f64,
    /// Half the difference of the coefficients by direction, N·s/m: viscous + split moving
    /// in +, viscous − split in − (see [`crate::preset::Friction`]).
    pub viscous_split_n_s_per_m: f64,
    /// Whether the Stribeck term applies: breakaway friction above Coulomb at low speed.
    pub stribeck: bool,
    /// Breakaway (static) friction at zero speed when `stribeck` is on, N.
    pub static_n: f64,
    /// Stribeck velocity, m/s: the excess over Coulomb falls as e^(−(v/v_s)²), or as
    /// e^(−|v|/v_s) when `stribeck_exponential`.
    pub stribeck_mps: f64,
    stribeck_inv_mps: f64,
    /// The excess falls off exponentially rather than as a Gaussian.
    pub stribeck_exponential: bool,
    /// The power-law speed term ([`crate::preset::ViscousPower`]), if it acts.
    pub power: Option<PowerLaw>,
    /// 1 / the Coulomb smoothing speed, s/m: the kinetic level acts as level·tanh(v·this)
    /// and the slide never sticks; 0 for the exact stick/slip law (see
    /// [`crate::preset::Friction::coulomb_smoothing_mm_per_s`]).
    pub smoothing_inv_s_per_m: f64,
}

/// The power-law speed term in SI: k·|v|^exponent above `core_mps`, `slope`·|v| below it
/// (the same force at the core speed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PowerLaw {
    /// N per (m/s)^exponent.
    pub k: f64,
    /// The power of the speed.
    pub exponent: f64,
    /// Below this speed the term is linear, m/s.
    pub core_mps: f64,
    /// Its slope there, N·s/m.
    pub slope: f64,
}

impl PowerLaw {
    /// The term's magnitude at speed `speed_mps` ≥ 0, N.
    #[inline]
    pub fn force_n(&self, speed_mps: f64) -> f64 {
        if speed_mps >= self.core_mps {
            self.k * speed_mps.powf(self.exponent)
        } else {
            self.slope * speed_mps
        }
    }

    fn from_params(v: &crate::preset::ViscousPower) -> Option<PowerLaw> {
        if !v.enabled || v.force_at_100mm_per_s_n == 0.0 {
            return None;
        }
        let v_ref = units::mm_per_s_to_m_per_s(100.0);
        let k = v.force_at_100mm_per_s_n / v_ref.powf(v.exponent);
        let core_mps = units::mm_per_s_to_m_per_s(v.core_mm_per_s);
        Some(PowerLaw {
            k,
            exponent: v.exponent,
            core_mps,
            slope: k * core_mps.powf(v.exponent) / core_mps,
        })
    }
}

/// |v|/ε beyond which tanh(v/ε) is ±1 in f64 (1 − tanh x < 2^−53 from x ≈ 18.7).
const SMOOTH_FULL_LEVEL: f64 = 20.0;

/// tanh through one expm1: libm's tanh took twice the rest of a friction step. With
/// m = e^(−2|x|) − 1 (expm1, exact near 0), tanh|x| = −m/(2 + m), which loses nothing to
/// cancellation at small |x| as 1 − e^(−2|x|) would.
#[inline]
fn fast_tanh(x: f64) -> f64 {
    let m = (-2.0 * x.abs()).exp_m1();
    (-m / (2.0 + m)).copysign(x)
}

/// Per-body step constants of [`FrictionModel::step`].
#[derive(Debug, Clone, Copy, Default)]
pub struct Body {
    /// Step over mass: velocity change per force.
    pub h_over_m: f64,
    /// Mass over step: the force that stops the body within one step, per velocity.
    pub m_over_h: f64,
    /// 1/(1 + h·c/m): the implicit viscous step.
    pub visc_inv: f64,
    /// h/m · 1/(1 + h·c/m): velocity change per kinetic friction force after the viscous
    /// step.
    pub kin_per_n: f64,
    /// When the viscous coefficient differs by direction: [`Body::visc_inv`] and
    /// [`Body::kin_per_n`] of the − coefficient, then the coefficients (+, −), N·s/m (the
    /// two fields above then hold the + coefficient's). None when it does not.
    pub neg: Option<(f64, f64, [f64; 2])>,
}

impl FrictionModel {
    /// The friction of axis preset `a`, converted to SI.
    pub fn from_params(a: &AxisParams) -> FrictionModel {
        let f = &a.friction;
        FrictionModel {
            enabled: f.enabled,
            coulomb_n: f.coulomb_n,
            viscous_n_s_per_m: f.viscous_n_s_per_m,
            viscous_split_n_s_per_m: f.viscous_split_n_s_per_m,
            stribeck: f.stribeck.enabled,
            static_n: f.stribeck.static_n,
            stribeck_mps: units::mm_per_s_to_m_per_s(f.stribeck.velocity_mm_per_s),
            stribeck_inv_mps: 1.0 / units::mm_per_s_to_m_per_s(f.stribeck.velocity_mm_per_s),
            stribeck_exponential: f.stribeck.shape == crate::preset::StribeckShape::Exponential,
            power: PowerLaw::from_params(&f.viscous_power),
            smoothing_inv_s_per_m: if f.coulomb_smoothing_mm_per_s > 0.0 {
                1.0 / units::mm_per_s_to_m_per_s(f.coulomb_smoothing_mm_per_s)
            } else {
                0.0
            },
        }
    }

    /// Kinetic friction magnitude (without the linear viscous part) at speed |v|: the
    /// power-law term is taken at the speed the step starts with, as the Stribeck term is.
    #[inline]
    fn kinetic_n(&self, speed_mps: f64, scale: f64, add_n: f64) -> f64 {
        let level = self.kinetic_scaled(speed_mps, scale) + add_n;
        match &self.power {
            Some(p) => level + p.force_n(speed_mps),
            None => level,
        }
    }

    /// The kinetic level without the stroke friction's addition.
    #[inline(always)]
    fn kinetic_scaled(&self, speed_mps: f64, scale: f64) -> f64 {
        if self.stribeck {
            let r = speed_mps * self.stribeck_inv_mps;
            // Past 6 characteristic velocities the Gaussian term is below 3e-16 of the step
            // (the exponential one past 36); skipping exp there also avoids libm's slow
            // underflow path.
            let x = if self.stribeck_exponential { r } else { r * r };
            if x > 36.0 {
                return scale * self.coulomb_n;
            }
            scale * (self.coulomb_n + (self.static_n - self.coulomb_n) * (-x).exp())
        } else {
            scale * self.coulomb_n
        }
    }

    /// Step constants for a body of mass `m_kg` and step `h_s`, so that the per-step update
    /// has no divisions (they dominate the latency of this serial chain).
    pub fn body(&self, m_kg: f64, h_s: f64) -> Body {
        let split = self.viscous_split_n_s_per_m;
        let visc_inv_at = |c: f64| 1.0 / (1.0 + h_s * c / m_kg);
        let (c_pos, c_neg) = (
            self.viscous_n_s_per_m + split,
            self.viscous_n_s_per_m - split,
        );
        let visc_inv = visc_inv_at(c_pos);
        Body {
            h_over_m: h_s / m_kg,
            m_over_h: m_kg / h_s,
            visc_inv,
            kin_per_n: h_s / m_kg * visc_inv,
            neg: (split != 0.0).then(|| {
                let inv = visc_inv_at(c_neg);
                (inv, h_s / m_kg * inv, [c_pos, c_neg])
            }),
        }
    }

    /// Advances the velocity of `body` by one step under the forces `f_known_n` (known a
    /// step ahead: gravity, disturbance) plus `f_drive_n` (this step's drive or spring force)
    /// plus friction. Returns (new velocity, friction force). If friction can bring the body
    /// to rest within the step, it does so exactly (stick) and returns the force that took.
    ///
    /// The drive force arrives last in every period, so it enters last: everything else
    /// (the known forces, the kinetic friction, which depends on the previous velocity) is
    /// summed while the amplifier still computes.
    #[inline(always)]
    pub fn step<const FULL: bool>(
        &self,
        body: &Body,
        v_mps: f64,
        f_known_n: f64,
        f_drive_n: f64,
        scale: f64,
        add_n: f64,
    ) -> (f64, f64) {
        let v_ahead = v_mps + body.h_over_m * f_known_n;
        let v_free = v_ahead + body.h_over_m * f_drive_n;
        if !self.enabled {
            return (v_free, 0.0);
        }
        // Without Stribeck, stroke friction and the power-law speed term (`FULL` false) the
        // level is Coulomb's, exactly what the general expressions give with scale 1 and
        // nothing added.
        let (fk, f_static) = if FULL {
            let fk = self.kinetic_n(v_mps.abs(), scale, add_n);
            let f_static = if self.stribeck {
                scale * self.static_n
            } else {
                scale * self.coulomb_n
            } + add_n;
            (fk, f_static)
        } else {
            (self.coulomb_n, self.coulomb_n)
        };
        if FULL && self.smoothing_inv_s_per_m > 0.0 {
            return self.finish_smooth(body, v_mps, v_free, fk);
        }
        if let Some(neg) = body.neg {
            return FrictionModel::finish_split(*body, neg, v_free, fk, f_static);
        }
        let kin = body.kin_per_n * fk;
        let f_stop = -body.m_over_h * v_free;
        if f_stop.abs() <= f_static {
            return (0.0, f_stop);
        }
        let v_new = v_free * body.visc_inv - kin.copysign(v_free);
        if v_new * v_free <= 0.0 {
            return (0.0, f_stop);
        }
        (v_new, -fk.copysign(v_free) - self.viscous_n_s_per_m * v_new)
    }

    /// The end of [`FrictionModel::step`] with a smoothed Coulomb level: m·(v − v_free)/h
    /// = −c·v − fk·tanh(v/ε), taken linearly implicit (the tanh linearised at the step's
    /// start speed, one tanh per step), because its slope fk/ε near rest (up to
    /// 400 000 N·s/m at 40 N over 0.1 mm/s) makes an explicit step unstable at any T3 the
    /// model runs. A step that would cross rest from beyond the smoothing is linearised at
    /// rest instead, and the result is kept within the bracket ±h·fk/m of the viscous step
    /// that the friction can reach. There is no stick: at rest the friction is zero and
    /// builds up with the speed.
    #[cold]
    #[inline(never)]
    fn finish_smooth(&self, body: &Body, v_mps: f64, v_free: f64, fk: f64) -> (f64, f64) {
        let c = match &body.neg {
            Some(neg) if v_free < 0.0 => neg.2[1],
            Some(neg) => neg.2[0],
            None => self.viscous_n_s_per_m,
        };
        let inv = self.smoothing_inv_s_per_m;
        let k = body.m_over_h;
        let slope = k + c;
        if slope <= 0.0 {
            // A negative viscous coefficient beyond the mass's own: no implicit step; the
            // friction at the start speed, explicitly.
            let f = -c * v_mps - fk * fast_tanh(v_mps * inv);
            return (v_free + f / k, f);
        }
        let x0 = v_mps * inv;
        let mut v = if x0.abs() > SMOOTH_FULL_LEVEL {
            // Far beyond the smoothing speed (where the record runs most of the time) the
            // tanh is ±1 to the last bit and its slope 0: the step of the exact law.
            let (visc_inv, kin_per_n) = match &body.neg {
                Some(neg) if v_free < 0.0 => (neg.0, neg.1),
                _ => (body.visc_inv, body.kin_per_n),
            };
            v_free * visc_inv - (kin_per_n * fk).copysign(x0)
        } else {
            let t0 = fast_tanh(x0);
            let s0 = inv * (1.0 - t0 * t0);
            (k * v_free - fk * (t0 - s0 * v_mps)) / (slope + fk * s0)
        };
        if v * v_mps < 0.0 {
            v = k * v_free / (slope + fk * inv);
        }
        let v = v.clamp((k * v_free - fk) / slope, (k * v_free + fk) / slope);
        (v, k * (v - v_free))
    }

    /// The end of [`FrictionModel::step`] with a viscous coefficient that differs by
    /// direction (`neg`, see [`Body::neg`]). Apart, so that the common step stays as short
    /// as it was: a branch inside it cost a fifth of the loop's throughput. The coefficient
    /// is the one of the direction the body would move in without friction: friction cannot
    /// reverse it within the step (that is a stop, above and below). Copies in, not
    /// `&self`: see [`AxisPlant::step_with`] on calls inside the T3 loop.
    #[cold]
    #[inline(never)]
    fn finish_split(
        body: Body,
        neg: (f64, f64, [f64; 2]),
        v_free: f64,
        fk: f64,
        f_static: f64,
    ) -> (f64, f64) {
        let f_stop = -body.m_over_h * v_free;
        if f_stop.abs() <= f_static {
            return (0.0, f_stop);
        }
        let (visc_inv, kin_per_n, c) = if v_free >= 0.0 {
            (body.visc_inv, body.kin_per_n, neg.2[0])
        } else {
            (neg.0, neg.1, neg.2[1])
        };
        let kin = kin_per_n * fk;
        let v_new = v_free * visc_inv - kin.copysign(v_free);
        if v_new * v_free <= 0.0 {
            return (0.0, f_stop);
        }
        (v_new, -fk.copysign(v_free) - c * v_new)
    }
}

/// Stroke-dependent friction rise (SPEC §5): short reversal strokes break the lubricant
/// film down, long strokes rebuild it.
#[derive(Debug, Clone)]
pub struct StrokeFriction {
    /// Whether the short-stroke rise applies (off: multiplier 1, nothing added).
    pub enabled: bool,
    pitch_m: f64,
    rise_ratio: f64,
    rise_n: f64,
    /// 1/growth strokes and 1/recovery distance: the per-step update multiplies (a division on
    /// the friction's loop-carried chain costs more than the rest of the update).
    inv_growth: f64,
    inv_recovery_per_m: f64,
    /// Short-stroke level n.
    pub level: f64,
    /// e^(−n/growth), kept up to date with n.
    decay: f64,
    /// Distance beyond the pitch already applied to the recovery on this stroke.
    beyond_done_m: f64,
    /// The film wears by distance ([`crate::preset::FilmLaw::Distance`]) rather than count.
    distance: bool,
    /// 1/breakdown distance (distance law).
    inv_breakdown_per_m: f64,
    /// Broken-down share of the film, 0..1 (distance law).
    pub film: f64,
    /// Position at the previous period (distance law).
    prev_x_m: f64,
    dir: f64,
    last_rev_m: Option<f64>,
    /// Current friction multiplier.
    pub scale: f64,
    /// Current friction added to the level, N.
    pub add_n: f64,
}

impl StrokeFriction {
    fn from_params(a: &AxisParams) -> StrokeFriction {
        let s = &a.friction.stroke;
        StrokeFriction {
            enabled: s.enabled,
            pitch_m: units::mm_to_m(s.pitch_mm),
            rise_ratio: s.rise_ratio,
            rise_n: s.rise_n,
            inv_growth: 1.0 / s.growth_strokes,
            inv_recovery_per_m: 1.0 / units::mm_to_m(s.recovery_mm),
            level: 0.0,
            decay: 1.0,
            beyond_done_m: 0.0,
            distance: s.law == crate::preset::FilmLaw::Distance,
            inv_breakdown_per_m: 1.0 / units::mm_to_m(s.breakdown_mm),
            film: 0.0,
            prev_x_m: f64::NAN,
            dir: 0.0,
            last_rev_m: None,
            scale: 1.0,
            add_n: 0.0,
        }
    }

    /// Inlined into the T3 step: the per-period work (the recovery on a long stroke) is a
    /// few products; a reversal, a few per second, goes out of line. A call every period
    /// made the compiler save every live floating-point value around it.
    #[inline(always)]
    fn observe(&mut self, x_m: f64, v_mps: f64) {
        if self.distance {
            self.observe_film(x_m, v_mps);
            return;
        }
        // Recovery: past the pitch, the film rebuilds with every mm travelled.
        if self.level > 0.0
            && let Some(prev) = self.last_rev_m
        {
            let beyond = (x_m - prev).abs() - self.pitch_m;
            if beyond > self.beyond_done_m {
                let u = (beyond - self.beyond_done_m.max(0.0)) * self.inv_recovery_per_m;
                self.beyond_done_m = beyond;
                // Per step u is ~1e-3, so the series is exact to ~1e-12 and avoids two exp
                // calls every T3 on a long stroke; each reversal recomputes exactly.
                let f = small_exp(-u);
                let g = self.level * self.inv_growth;
                self.level *= f;
                self.decay *= small_exp(g * (1.0 - f));
                if self.level < 1e-6 {
                    self.level = 0.0;
                    self.decay = 1.0;
                }
                self.refresh();
            }
        }
        if v_mps.abs() < REVERSAL_SPEED_MPS {
            return;
        }
        let dir = v_mps.signum();
        if dir != self.dir {
            self.reversal(x_m, dir);
        }
    }

    /// The distance law: the film breaks down with the distance run within the pitch of the
    /// last turning point and rebuilds beyond it.
    #[cold]
    #[inline(never)]
    fn observe_film(&mut self, x_m: f64, v_mps: f64) {
        let ds = if self.prev_x_m.is_finite() {
            (x_m - self.prev_x_m).abs()
        } else {
            0.0
        };
        self.prev_x_m = x_m;
        if let Some(prev) = self.last_rev_m
            && ds > 0.0
        {
            let w = self.film;
            self.film = if (x_m - prev).abs() <= self.pitch_m {
                1.0 - (1.0 - w) * small_exp(-ds * self.inv_breakdown_per_m)
            } else {
                w * small_exp(-ds * self.inv_recovery_per_m)
            };
            self.refresh();
        }
        if v_mps.abs() >= REVERSAL_SPEED_MPS && v_mps.signum() != self.dir {
            self.last_rev_m = Some(x_m);
            self.dir = v_mps.signum();
        }
    }

    /// A reversal at `x_m` into direction `dir`: a short stroke raises the level.
    #[cold]
    #[inline(never)]
    fn reversal(&mut self, x_m: f64, dir: f64) {
        if self.dir != 0.0
            && let Some(prev) = self.last_rev_m
            && (x_m - prev).abs() < self.pitch_m
        {
            self.level += 1.0;
        }
        self.last_rev_m = Some(x_m);
        self.beyond_done_m = 0.0;
        self.dir = dir;
        self.update_scale();
    }

    fn update_scale(&mut self) {
        self.decay = (-self.level * self.inv_growth).exp();
        self.refresh();
    }

    /// The friction multiplier and addition for the current level.
    fn refresh(&mut self) {
        let (scale, add) = if self.enabled {
            let g = if self.distance {
                self.film
            } else {
                1.0 - self.decay
            };
            (1.0 + self.rise_ratio * g, self.rise_n * g)
        } else {
            (1.0, 0.0)
        };
        self.scale = scale;
        self.add_n = add;
    }
}

/// First-order screw temperature and the elongation it causes.
#[derive(Debug, Clone)]
pub struct ScrewThermal {
    /// Whether the screw heats and grows (off: no elongation).
    pub enabled: bool,
    alpha_per_k: f64,
    inv_capacity: f64,
    loss_w_per_k: f64,
    friction_heat_share: f64,
    motion_heat_w_s_per_m: f64,
    /// Ambient temperature the screw loses its heat to, °C.
    pub ambient_c: f64,
    reference_c: f64,
    fixed_end_m: f64,
    /// Current screw temperature, °C (traced, and read by the thermal compensation).
    pub temp_c: f64,
}

impl ScrewThermal {
    fn from_params(a: &AxisParams) -> ScrewThermal {
        let t = &a.screw_thermal;
        ScrewThermal {
            enabled: t.enabled,
            alpha_per_k: t.alpha_per_k,
            inv_capacity: 1.0 / t.heat_capacity_j_per_k,
            loss_w_per_k: t.loss_w_per_k,
            friction_heat_share: t.friction_heat_share,
            motion_heat_w_s_per_m: t.motion_heat_w_s_per_m,
            ambient_c: t.ambient_c,
            reference_c: t.reference_c,
            fixed_end_m: units::mm_to_m(t.fixed_end_mm),
            temp_c: t.initial_c,
        }
    }

    #[inline(always)]
    fn step(&mut self, fric_power_w: f64, speed_mps: f64, dt_s: f64) {
        if !self.enabled {
            return;
        }
        let q_w = self.friction_heat_share * fric_power_w + self.motion_heat_w_s_per_m * speed_mps;
        self.temp_c +=
            dt_s * self.inv_capacity * (q_w - self.loss_w_per_k * (self.temp_c - self.ambient_c));
    }

    /// Elongation per metre from the fixed bearing at the current temperature (0 when off).
    #[inline(always)]
    fn growth_per_m(&self) -> f64 {
        if self.enabled {
            self.alpha_per_k * (self.temp_c - self.reference_c)
        } else {
            0.0
        }
    }

    /// Elongation of the screw between the fixed bearing and the nut at `x_m`.
    #[inline]
    pub fn elongation_m(&self, x_m: f64) -> f64 {
        if self.enabled {
            self.alpha_per_k * (self.temp_c - self.reference_c) * (x_m - self.fixed_end_m)
        } else {
            0.0
        }
    }
}

/// Cyclic, cumulative and tabulated lead error.
#[derive(Debug, Clone)]
struct LeadErr {
    enabled: bool,
    /// [`sin_lookup`]'s points, held here so the T3 step does not check their initialisation.
    sin: &'static SinPoints,
    amplitude_m: f64,
    inv_period_per_m: f64,
    phase_turns: f64,
    cumulative: f64,
    /// (position m, error m)
    table: Vec<(f64, f64)>,
    /// The table's segment the last lookup found (see `table::interp_slope_near`).
    segment: Cell<usize>,
}

impl LeadErr {
    #[inline(always)]
    fn at(&self, x_m: f64) -> f64 {
        if !self.enabled {
            return 0.0;
        }
        self.at_enabled(x_m)
    }

    #[inline(always)]
    fn at_enabled(&self, x_m: f64) -> f64 {
        self.linearised(x_m).0
    }

    /// The error at `x_m` and its slope there (d error / dx). The error is piecewise linear
    /// (the sine by its table, the measured table by its points), so the pair gives the
    /// error exactly anywhere in the segments around `x_m`.
    #[inline(always)]
    fn linearised(&self, x_m: f64) -> (f64, f64) {
        // One lookup per T3 instead of a libm sin of a large argument (x/period reaches the
        // hundreds on a long axis); see `sin_lookup` for the error bound.
        let turns = x_m * self.inv_period_per_m;
        let frac = turns - f64::floor(turns);
        let (s, ds_per_turn) = sin_lookup(self.sin, frac + self.phase_turns);
        let (table, table_slope) = if self.table.is_empty() {
            (0.0, 0.0)
        } else {
            crate::table::interp_slope_near(&self.table, x_m, &self.segment)
        };
        (
            self.amplitude_m * s + self.cumulative * x_m + table,
            self.amplitude_m * ds_per_turn * self.inv_period_per_m + self.cumulative + table_slope,
        )
    }
}

/// Where the table is at the end of a period, as a function of the screw-frame position
/// `x_t` there: `pos = gain·x_t + offset`. It is built one period ahead, from the state at
/// the start of the previous period, so that neither the thermal growth nor the lead error
/// sits on the chain that runs from one period's feedback to the next: that chain gets one
/// product and one sum instead of a table lookup and a temperature update.
///
/// - Thermal growth: the screw temperature two periods back. It moves by µK per period
///   against time constants of minutes.
/// - Lead error: linearised around the predicted end position `x_ref` = x_t + 2·T3·v_t.
///   The real end position differs from it by 2·T3·Δv, below 1e-6 m at any acceleration
///   the drive reaches in two periods. The error is piecewise linear (table points), so
///   the neglected part is the slope change at a point passed inside that distance:
///   ~1e-11 m for a 2 µm, 10 mm-period lead error, the size of the sine table's own error.
#[derive(Debug, Clone, Copy, Default)]
struct PosMap {
    gain: f64,
    offset: f64,
    growth_per_m: f64,
    /// The lead error is `lead_slope·x_t + lead_offset_m`.
    lead_slope: f64,
    lead_offset_m: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Mech {
    /// One body, no play.
    Rigid,
    /// One body while a flank is in contact; motor and table move apart inside the gap.
    RigidPlay,
    /// Spring + damper with an optional dead zone.
    TwoMass { k_n_per_m: f64, c_n_s_per_m: f64 },
    /// Motor and table one body, a payload on a spring + damper on the table. The payload's
    /// state takes the motor's slots (`x_m`, `v_m`): the motor moves with the table, and the
    /// state keeps four entries for the loop's linearisation.
    Payload {
        k_n_per_m: f64,
        c_n_s_per_m: f64,
        /// Sub-step over the payload's mass, s/kg.
        h_over_m: f64,
        /// k/d₀² of a hardening mount, N/m³ (0: linear).
        k3_n_per_m3: f64,
    },
}

/// What the plant shows after a step, in SI, load side.
#[derive(Debug, Clone, Copy, Default)]
pub struct PlantOut {
    /// Motor position as load travel (unquantized).
    pub motor_pos_m: f64,
    /// Motor encoder reading as load travel.
    pub motor_enc_m: f64,
    /// Where the table really is (screw frame + thermal + lead error); sag is added later.
    pub pos_m: f64,
    /// Linear scale reading (quantized `pos_m`).
    pub scale_m: f64,
    /// Table velocity, m/s.
    pub vel_mps: f64,
    /// Friction force on the table over the last step, N (signed, against the motion).
    pub friction_n: f64,
    /// Motor minus table inside the backlash: −b/2 … +b/2 at the flanks.
    pub gap_m: f64,
    /// Thermal elongation of the screw at the table, m (included in `pos_m`).
    pub thermal_m: f64,
    /// Lead error at the table, m (included in `pos_m`).
    pub lead_err_m: f64,
}

impl PlantOut {
    /// `*dst = *self`, one field at a time. A struct assignment may go through one wide
    /// copy; a wide load of fields just stored one by one cannot be forwarded from the store
    /// buffer, and in the T3 step that stall cost ~25 % of the time.
    #[inline(always)]
    pub fn store(&self, dst: &mut PlantOut) {
        let fields = [
            (&mut dst.motor_pos_m, self.motor_pos_m),
            (&mut dst.motor_enc_m, self.motor_enc_m),
            (&mut dst.pos_m, self.pos_m),
            (&mut dst.scale_m, self.scale_m),
            (&mut dst.vel_mps, self.vel_mps),
            (&mut dst.friction_n, self.friction_n),
            (&mut dst.gap_m, self.gap_m),
            (&mut dst.thermal_m, self.thermal_m),
            (&mut dst.lead_err_m, self.lead_err_m),
        ];
        for (d, v) in fields {
            // SAFETY: `d` comes from a `&mut` borrow, so it is valid, aligned and exclusive.
            // The write is volatile only so that the compiler keeps it one 8-byte store:
            // without it, it merged four of these copies back into one wide load and store,
            // the stall this function exists to avoid (+3 % on the T3 step when removed).
            unsafe { std::ptr::write_volatile(d, v) };
        }
    }
}

/// The mechanical state of the drive: motor and table positions (screw frame, load travel)
/// and velocities. With a payload on a spring ([`Coupling::Payload`]) the motor moves with
/// the table and `x_m`, `v_m` are the payload's.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MechState {
    /// Motor position as load travel (the payload's, see above), m.
    pub x_m: f64,
    /// Motor velocity as load travel (the payload's, see above), m/s.
    pub v_m: f64,
    /// Table (nut) position along an ideal screw, m.
    pub x_t: f64,
    /// Table velocity, m/s.
    pub v_t: f64,
}

/// Which sensor a plant's starting position is given for: the plant starts at rest where
/// that sensor reads the given value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sensor {
    /// The motor encoder (semi-closed loop; the machine's power-up position).
    MotorEncoder,
    /// The true table position (screw frame + thermal growth + lead error).
    Load,
    /// The linear scale on the table.
    Scale,
}

impl From<Feedback> for Sensor {
    fn from(f: Feedback) -> Sensor {
        match f {
            Feedback::Motor => Sensor::MotorEncoder,
            Feedback::Scale => Sensor::Scale,
        }
    }
}

impl From<PosSource> for Sensor {
    fn from(p: PosSource) -> Sensor {
        match p {
            PosSource::Load => Sensor::Load,
            PosSource::MotorEncoder => Sensor::MotorEncoder,
            PosSource::Scale => Sensor::Scale,
        }
    }
}

/// Where and how a plant starts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Start {
    /// The sensor whose reading is given.
    pub sensor: Sensor,
    /// What that sensor reads at the start, m.
    pub reading_m: f64,
    /// Common velocity of motor and table at the start, m/s (0: at rest).
    pub vel_mps: f64,
}

impl Start {
    /// At rest where `sensor` reads `reading_m`.
    pub fn at_rest(sensor: Sensor, reading_m: f64) -> Start {
        Start {
            sensor,
            reading_m,
            vel_mps: 0.0,
        }
    }
}

/// Number of plant sub-steps per T3 so that the coupling resonance is well resolved
/// (validation refuses a coupling that needs more than [`MAX_SUBSTEPS`]).
pub fn substeps(a: &AxisParams, t3_s: f64) -> u32 {
    a.required_substeps(t3_s)
        .clamp(1.0, f64::from(MAX_SUBSTEPS)) as u32
}

/// One feed axis's mechanics: motor, coupling/backlash, screw, table, friction, gravity,
/// screw thermal growth, lead error and the encoders.
#[derive(Debug, Clone)]
pub struct AxisPlant {
    mech: Mech,
    m_m: f64,
    m_t: f64,
    half_gap_m: f64,
    f_grav_n: f64,
    friction: FrictionModel,
    stroke: StrokeFriction,
    thermal: ScrewThermal,
    lead: LeadErr,
    /// Encoder quanta as (quantum, 1/quantum).
    motor_q_m: Option<(f64, f64)>,
    scale_q_m: Option<(f64, f64)>,
    n_sub: u32,
    h_s: f64,
    body_all: Body,
    body_table: Body,
    motor_h_over_m: f64,
    t3_s: f64,
    x_m: f64,
    v_m: f64,
    x_t: f64,
    v_t: f64,
    /// +1/−1: which flank is in contact (RigidPlay); 0: inside the gap.
    contact: i8,
    /// Only the common effects are on (see [`AxisPlant::is_plain`]).
    plain: bool,
    /// The position map for the end of the coming period (see [`PosMap`]).
    next_map: PosMap,
    out: PlantOut,
}

impl AxisPlant {
    /// A plant at `start`: the load resting on the flank gravity pushes it onto, the screw at
    /// its initial temperature.
    pub fn new(a: &AxisParams, t3_s: f64, start: Start) -> AxisPlant {
        let initial_pos_m = start.reading_m;
        let mut p = AxisPlant {
            mech: Mech::Rigid,
            m_m: 0.0,
            m_t: 0.0,
            half_gap_m: 0.0,
            f_grav_n: 0.0,
            friction: FrictionModel::from_params(a),
            stroke: StrokeFriction::from_params(a),
            thermal: ScrewThermal::from_params(a),
            lead: LeadErr {
                enabled: false,
                sin: sin_points(),
                amplitude_m: 0.0,
                inv_period_per_m: 0.0,
                phase_turns: 0.0,
                cumulative: 0.0,
                table: vec![],
                segment: Cell::new(0),
            },
            motor_q_m: None,
            scale_q_m: None,
            n_sub: 1,
            h_s: t3_s,
            body_all: Body::default(),
            body_table: Body::default(),
            motor_h_over_m: 0.0,
            t3_s,
            x_m: initial_pos_m,
            v_m: 0.0,
            x_t: initial_pos_m,
            v_t: 0.0,
            contact: 1,
            plain: false,
            next_map: PosMap::default(),
            out: PlantOut::default(),
        };
        p.retune(a);
        p.contact = if p.f_grav_n > 0.0 { -1 } else { 1 };
        p.place(start);
        p
    }

    /// Puts motor and table where `start.sensor` reads `start.reading_m`, both moving at
    /// `start.vel_mps`. The table reading includes thermal growth and lead error, which
    /// depend on where the table is, so it is solved for by a few fixed-point steps (the
    /// errors are µm against metres: each step gains six digits).
    fn place(&mut self, start: Start) {
        let b2 = if self.mech == Mech::Rigid {
            0.0
        } else {
            self.half_gap_m
        };
        let flank = self.contact as f64 * b2;
        let x_t = match start.sensor {
            Sensor::MotorEncoder => start.reading_m - flank,
            Sensor::Load | Sensor::Scale => {
                let mut x = start.reading_m;
                for _ in 0..4 {
                    x = start.reading_m - self.thermal.elongation_m(x) - self.lead.at(x);
                }
                x
            }
        };
        self.x_t = x_t;
        self.x_m = x_t + flank;
        self.v_m = start.vel_mps;
        self.v_t = start.vel_mps;
        self.refresh_out::<true>(0.0);
    }

    /// The mechanical state.
    pub fn mech_state(&self) -> MechState {
        MechState {
            x_m: self.x_m,
            v_m: self.v_m,
            x_t: self.x_t,
            v_t: self.v_t,
        }
    }

    /// Replaces the mechanical state (the linearisation perturbs it one entry at a time).
    pub fn set_mech_state(&mut self, s: MechState) {
        self.x_m = s.x_m;
        self.v_m = s.v_m;
        self.x_t = s.x_t;
        self.v_t = s.v_t;
        self.refresh_out::<true>(self.out.friction_n);
    }

    /// What the sensors and the trace see after the latest step.
    pub fn out(&self) -> &PlantOut {
        &self.out
    }

    /// The screw's thermal state.
    pub fn thermal(&self) -> &ScrewThermal {
        &self.thermal
    }

    /// The short-stroke friction state.
    pub fn stroke(&self) -> &StrokeFriction {
        &self.stroke
    }

    /// The slide friction model.
    pub fn friction(&self) -> &FrictionModel {
        &self.friction
    }

    /// Sub-steps the mechanics take per T3.
    pub fn substeps(&self) -> u32 {
        self.n_sub
    }

    /// Takes new parameters while keeping the physical state (live editing).
    pub fn retune(&mut self, a: &AxisParams) {
        self.m_m = a.drive.reflected_motor_mass_kg();
        self.m_t = a.drive.table_mass_kg;
        // A payload coupling has no play (validation turns the pair down; see `Coupling`).
        self.half_gap_m =
            if a.lost_motion.enabled && !matches!(a.drive.coupling, Coupling::Payload { .. }) {
                0.5 * units::um_to_m(a.lost_motion.width_um)
            } else {
                0.0
            };
        self.mech = match a.drive.coupling {
            Coupling::Rigid if self.half_gap_m > 0.0 => Mech::RigidPlay,
            Coupling::Rigid => Mech::Rigid,
            Coupling::TwoMass {
                stiffness_n_per_um,
                damping_n_s_per_m,
            } => Mech::TwoMass {
                k_n_per_m: units::n_per_um_to_n_per_m(stiffness_n_per_um),
                c_n_s_per_m: damping_n_s_per_m,
            },
            Coupling::Payload {
                mass_kg,
                stiffness_n_per_um,
                damping_n_s_per_m,
                hardening_deflection_um,
            } => {
                let k = units::n_per_um_to_n_per_m(stiffness_n_per_um);
                let d0 = units::um_to_m(hardening_deflection_um);
                Mech::Payload {
                    k_n_per_m: k,
                    c_n_s_per_m: damping_n_s_per_m,
                    // Set with the sub-step below.
                    h_over_m: 1.0 / mass_kg.max(1e-6),
                    k3_n_per_m3: if d0 > 0.0 { k / (d0 * d0) } else { 0.0 },
                }
            }
        };
        if self.mech == Mech::Rigid {
            self.x_t = self.x_m;
            self.v_t = self.v_m;
        }
        let g = &a.gravity;
        self.f_grav_n = if g.enabled {
            -g.moving_mass_kg * G_MPS2 * g.incline_deg.to_radians().sin() + g.offset_n
        } else {
            0.0
        };
        self.friction = FrictionModel::from_params(a);
        let (level, film, prev_x) = (self.stroke.level, self.stroke.film, self.stroke.prev_x_m);
        let (dir, last) = (self.stroke.dir, self.stroke.last_rev_m);
        self.stroke = StrokeFriction::from_params(a);
        self.stroke.level = level;
        self.stroke.film = film;
        self.stroke.prev_x_m = prev_x;
        self.stroke.update_scale();
        self.stroke.dir = dir;
        self.stroke.last_rev_m = last;
        // The screw keeps its temperature across a parameter edit; only `new` starts cold.
        let temp = self.thermal.temp_c;
        self.thermal = ScrewThermal::from_params(a);
        self.thermal.temp_c = temp;
        let l = &a.lead_error;
        self.lead = LeadErr {
            enabled: l.enabled,
            sin: sin_points(),
            amplitude_m: units::um_to_m(l.amplitude_um),
            inv_period_per_m: 1.0 / units::mm_to_m(l.period_mm),
            phase_turns: l.phase_deg / 360.0,
            cumulative: units::um_per_m_to_ratio(l.cumulative_um_per_m),
            table: l
                .table
                .iter()
                .map(|&(x, e)| (units::mm_to_m(x), units::um_to_m(e)))
                .collect(),
            segment: Cell::new(0),
        };
        let e = &a.encoder;
        let q = |q: f64| (q, 1.0 / q);
        self.motor_q_m = e
            .quantize_motor
            .then(|| q(a.drive.lead_m() / e.motor_counts_per_rev as f64));
        self.scale_q_m = e
            .quantize_scale
            .then(|| q(units::um_to_m(e.scale_resolution_um)));
        self.n_sub = substeps(a, self.t3_s);
        self.h_s = self.t3_s / self.n_sub as f64;
        if let Mech::Payload { h_over_m, .. } = &mut self.mech {
            *h_over_m *= self.h_s;
        }
        self.body_all = self.friction.body(self.m_m + self.m_t, self.h_s);
        self.body_table = self.friction.body(self.m_t, self.h_s);
        self.motor_h_over_m = if self.m_m > 0.0 {
            self.h_s / self.m_m
        } else {
            0.0
        };
        self.plain = self.plain_now();
        self.next_map = self.pos_map::<true>(self.x_t + self.t3_s * self.v_t);
    }

    /// Advances the mechanics by one T3 under the motor force `force_n` (load side) and an
    /// external force `ext_n` on the table (a disturbance; 0 on the machine).
    #[inline]
    pub fn step(&mut self, force_n: f64, ext_n: f64) {
        self.step_with::<true>(force_n, ext_n);
    }

    /// Whether this plant uses only the common effects: a rigid drive with or without
    /// play, Coulomb + viscous friction, motor-encoder quantization and screw growth. Then
    /// [`AxisPlant::step_with`] may run with `FULL` false.
    pub fn is_plain(&self) -> bool {
        self.plain
    }

    fn plain_now(&self) -> bool {
        !self.stroke.enabled
            && !self.lead.enabled
            && self.scale_q_m.is_none()
            && !self.friction.stribeck
            && self.friction.power.is_none()
            && self.friction.smoothing_inv_s_per_m == 0.0
            && !matches!(self.mech, Mech::TwoMass { .. } | Mech::Payload { .. })
    }

    /// [`AxisPlant::step`], with the rarely used effects (Stribeck, stroke friction, the
    /// power-law speed term, lead error, scale quantization, two-mass coupling) compiled in
    /// only when `FULL`. Leaving
    /// out code that does nothing for a plain axis halves the work of its T3 step. The
    /// result is the same to the bit. `FULL` false is only for a plant that is
    /// [`AxisPlant::is_plain`]; its one caller, [`crate::drive::AxisLoop`], checks that once
    /// per run. The check used to be here too, with a call out to the full step behind it:
    /// a call inside the loop, like the cold calls that took pointers into the state
    /// (`servo::saturate`, [`FrictionModel`]'s split end, now values in and out), keeps the
    /// compiler from holding the loop's state in registers. Without them the step alone ran
    /// +14 % (58.5 → 66.6 M steps/s, six alternated runs) and the machine on `default.ron`
    /// +11 %.
    #[inline(always)]
    pub(crate) fn step_with<const FULL: bool>(&mut self, force_n: f64, ext_n: f64) {
        debug_assert!(
            FULL || self.plain,
            "the plain step of a plant that is not plain"
        );
        let (scale, add) = (self.stroke.scale, self.stroke.add_n);
        // The film sees the stroke as it stood at the start of this period and acts from the
        // next one: a lag of one T3 against a film that builds up over strokes, which keeps
        // the level's update (exponentials, reversal bookkeeping) off the chain from one
        // period's table velocity to the next.
        if FULL && self.stroke.enabled {
            self.stroke.observe(self.x_t, self.v_t);
        }
        // This period's map was built a period ago; the next one is built now, from the state
        // at the start of this period (see `PosMap`).
        let map = self.next_map;
        self.next_map = self.pos_map::<FULL>(self.x_t + 2.0 * self.t3_s * self.v_t);
        let f_load = self.f_grav_n + ext_n;
        // One match per T3, the sub-step loop inside each arm: the mechanism never changes
        // between sub-steps.
        // A single sub-step (every rigid drive, most couplings) is written out without the
        // loop: a loop makes the compiler hoist the step's constants into spilled
        // temporaries, tens of instructions per period.
        let fric = match self.mech {
            Mech::Rigid if self.n_sub == 1 => self.sub_rigid::<FULL>(force_n, f_load, scale, add),
            Mech::Rigid => {
                let mut fric = 0.0;
                for _ in 0..self.n_sub {
                    fric = self.sub_rigid::<FULL>(force_n, f_load, scale, add);
                }
                fric
            }
            Mech::RigidPlay if self.n_sub == 1 => {
                self.step_play::<FULL>(force_n, f_load, self.h_s, scale, add)
            }
            Mech::RigidPlay => {
                let mut fric = 0.0;
                for _ in 0..self.n_sub {
                    fric = self.step_play::<FULL>(force_n, f_load, self.h_s, scale, add);
                }
                fric
            }
            Mech::TwoMass {
                k_n_per_m,
                c_n_s_per_m,
            } if FULL => {
                let (k, c) = (k_n_per_m, c_n_s_per_m);
                if self.n_sub == 1 {
                    self.sub_two_mass(force_n, f_load, scale, add, k, c)
                } else {
                    let mut fric = 0.0;
                    for _ in 0..self.n_sub {
                        fric = self.sub_two_mass(force_n, f_load, scale, add, k, c);
                    }
                    fric
                }
            }
            Mech::Payload {
                k_n_per_m,
                c_n_s_per_m,
                h_over_m,
                k3_n_per_m3,
            } if FULL => {
                let mut fric = 0.0;
                for _ in 0..self.n_sub {
                    fric = self.sub_payload(
                        force_n,
                        f_load,
                        (scale, add),
                        (k_n_per_m, k3_n_per_m3, c_n_s_per_m, h_over_m),
                    );
                }
                fric
            }
            Mech::TwoMass { .. } | Mech::Payload { .. } => 0.0,
        };
        self.thermal
            .step((fric * self.v_t).abs(), self.v_t.abs(), self.t3_s);
        self.write_out::<FULL>(fric, &map);
    }

    /// One sub-step of the rigid drive without play: one body.
    #[inline(always)]
    fn sub_rigid<const FULL: bool>(
        &mut self,
        force_n: f64,
        f_load: f64,
        scale: f64,
        add: f64,
    ) -> f64 {
        let (v, f) =
            self.friction
                .step::<FULL>(&self.body_all, self.v_t, f_load, force_n, scale, add);
        // Trapezoidal position: exact for the force held over the sub-step. Advancing by the
        // new velocity alone puts the position half a sub-step ahead of the continuous
        // motion (0.5 ms at EMPS's 1 ms T3, 9 % of its following error).
        self.x_t = trapezoid(self.x_t, self.h_s, self.v_t, v);
        self.v_t = v;
        self.v_m = v;
        self.x_m = self.x_t;
        f
    }

    /// One sub-step of motor and table joined by a spring and damper, with an optional
    /// dead zone.
    #[inline(always)]
    fn sub_two_mass(
        &mut self,
        force_n: f64,
        f_load: f64,
        scale: f64,
        add: f64,
        k_n_per_m: f64,
        c_n_s_per_m: f64,
    ) -> f64 {
        let h = self.h_s;
        // The spring acts at the middle of the sub-step: the velocities are updated from it
        // and the positions integrated by the trapezoid, and a force taken at the start of
        // the sub-step would feed the oscillation energy each sub-step (negative damping of
        // about ω·h/4: a ζ = 0.05 spring at ω·h = 0.3 rang up without bound).
        let gap = self.x_m - self.x_t + 0.5 * h * (self.v_m - self.v_t);
        let defl = dead_zone(gap, self.half_gap_m);
        let f_s = if defl != 0.0 || self.half_gap_m == 0.0 {
            k_n_per_m * defl + c_n_s_per_m * (self.v_m - self.v_t)
        } else {
            0.0
        };
        let v_m0 = self.v_m;
        self.v_m += self.motor_h_over_m * (force_n - f_s);
        let (v, f) =
            self.friction
                .step::<true>(&self.body_table, self.v_t, f_load, f_s, scale, add);
        self.x_m = trapezoid(self.x_m, h, v_m0, self.v_m);
        self.x_t = trapezoid(self.x_t, h, self.v_t, v);
        self.v_t = v;
        f
    }

    /// One sub-step of the rigid drive with a payload on a spring + damper on the table
    /// (`spring`: stiffness N/m, hardening N/m³, damping N·s/m, sub-step over the payload
    /// mass s/kg). The
    /// spring acts at the middle of the sub-step, as in [`Self::sub_two_mass`]; the payload's
    /// state is in the motor's slots (see [`Mech::Payload`]).
    #[inline(always)]
    fn sub_payload(
        &mut self,
        force_n: f64,
        f_load: f64,
        (scale, add): (f64, f64),
        (k_n_per_m, k3_n_per_m3, c_n_s_per_m, h_over_m): (f64, f64, f64, f64),
    ) -> f64 {
        let h = self.h_s;
        let defl = self.x_t - self.x_m + 0.5 * h * (self.v_t - self.v_m);
        let f_s =
            defl * (k_n_per_m + k3_n_per_m3 * defl * defl) + c_n_s_per_m * (self.v_t - self.v_m);
        let v_p0 = self.v_m;
        self.v_m += h_over_m * f_s;
        let (v, f) =
            self.friction
                .step::<true>(&self.body_all, self.v_t, f_load - f_s, force_n, scale, add);
        self.x_m = trapezoid(self.x_m, h, v_p0, self.v_m);
        self.x_t = trapezoid(self.x_t, h, self.v_t, v);
        self.v_t = v;
        f
    }

    /// Rigid drive with play: one body while a flank transmits force, two bodies in the gap,
    /// an inelastic impact when the gap closes. `f_load_n` acts on the table.
    #[inline(always)]
    fn step_play<const FULL: bool>(
        &mut self,
        force_n: f64,
        f_load_n: f64,
        h: f64,
        scale: f64,
        add: f64,
    ) -> f64 {
        let b2 = self.half_gap_m;
        if self.contact != 0 {
            let (v, f) =
                self.friction
                    .step::<FULL>(&self.body_all, self.v_t, f_load_n, force_n, scale, add);
            // Force the motor flank must exert on the table for it to share this motion.
            let f_contact = self.body_table.m_over_h * (v - self.v_t) - f_load_n - f;
            if f_contact * self.contact as f64 >= 0.0 {
                self.x_m = trapezoid(self.x_m, h, self.v_m, v);
                self.v_t = v;
                self.v_m = v;
                self.x_t = self.x_m - self.contact as f64 * b2;
                return f;
            }
            self.contact = 0;
        }
        let v_m0 = self.v_m;
        self.v_m += self.motor_h_over_m * force_n;
        self.x_m = trapezoid(self.x_m, h, v_m0, self.v_m);
        let (v, f) =
            self.friction
                .step::<FULL>(&self.body_table, self.v_t, f_load_n, 0.0, scale, add);
        self.x_t = trapezoid(self.x_t, h, self.v_t, v);
        self.v_t = v;
        let gap = self.x_m - self.x_t + 0.5 * h * (self.v_m - self.v_t);
        let side = if gap >= b2 {
            1
        } else if gap <= -b2 {
            -1
        } else {
            0
        };
        if side != 0 {
            let v = (self.m_m * self.v_m + self.m_t * self.v_t) / (self.m_m + self.m_t);
            self.v_m = v;
            self.v_t = v;
            self.contact = side;
            self.x_t = self.x_m - side as f64 * b2;
        }
        f
    }

    /// The outputs for the state as it is (placement, linearisation), and the map for the
    /// coming period.
    fn refresh_out<const FULL: bool>(&mut self, fric_n: f64) {
        let map = self.pos_map::<FULL>(self.x_t);
        self.write_out::<FULL>(fric_n, &map);
        self.next_map = self.pos_map::<FULL>(self.x_t + self.t3_s * self.v_t);
    }

    /// The map from the screw-frame position to the table's, for a period whose end position
    /// is expected near `x_ref_m` (see [`PosMap`]).
    #[inline(always)]
    fn pos_map<const FULL: bool>(&self, x_ref_m: f64) -> PosMap {
        let growth_per_m = self.thermal.growth_per_m();
        let fixed_end_m = self.thermal.fixed_end_m;
        let (lead_ref_m, lead_slope) = if FULL && self.lead.enabled {
            self.lead.linearised(x_ref_m)
        } else {
            (0.0, 0.0)
        };
        let lead_offset_m = lead_ref_m - lead_slope * x_ref_m;
        PosMap {
            gain: 1.0 + growth_per_m + lead_slope,
            offset: lead_offset_m - growth_per_m * fixed_end_m,
            growth_per_m,
            lead_slope,
            lead_offset_m,
        }
    }

    #[inline(always)]
    fn write_out<const FULL: bool>(&mut self, fric_n: f64, map: &PosMap) {
        let x = self.x_t;
        // With a payload the motor moves with the table (the payload has the motor's slots).
        let x_motor = if FULL && matches!(self.mech, Mech::Payload { .. }) {
            x
        } else {
            self.x_m
        };
        let pos = map.gain * x + map.offset;
        let thermal = map.growth_per_m * (x - self.thermal.fixed_end_m);
        let lead = map.lead_slope * x + map.lead_offset_m;
        self.out = PlantOut {
            motor_pos_m: x_motor,
            motor_enc_m: quantize(x_motor, self.motor_q_m),
            pos_m: pos,
            scale_m: if FULL {
                quantize(pos, self.scale_q_m)
            } else {
                pos
            },
            vel_mps: self.v_t,
            friction_n: fric_n,
            gap_m: x_motor - x,
            thermal_m: thermal,
            lead_err_m: lead,
        };
    }

    /// Net constant force on the table along the axis (gravity component plus offset).
    pub fn gravity_force_n(&self) -> f64 {
        self.f_grav_n
    }
}

/// x + h·(v0 + v1)/2, the position after a sub-step whose velocity went from `v0` to `v1`
/// under a held force. Written as (x + h/2·v0) + h/2·v1 so that the new velocity `v1`, which
/// the whole loop waits for, is one product and one sum away from the position instead of
/// a sum, a product and a sum.
#[inline(always)]
fn trapezoid(x: f64, h: f64, v0: f64, v1: f64) -> f64 {
    let hh = 0.5 * h;
    (x + hh * v0) + hh * v1
}

/// The reading of an encoder of quantum `q` (with 1/q) at `x`: the nearest count.
#[inline]
fn quantize(x: f64, q: Option<(f64, f64)>) -> f64 {
    match q {
        Some((q, inv)) => (x * inv).round_ties_even() * q,
        None => x,
    }
}

/// e^x for |x| ≲ 0.01 by its series to third order; exact libm exp beyond.
#[inline]
fn small_exp(x: f64) -> f64 {
    if x.abs() < 0.01 {
        1.0 + x * (1.0 + x * (0.5 + x * (1.0 / 6.0)))
    } else {
        cold_exp(x)
    }
}

#[cold]
#[inline(never)]
fn cold_exp(x: f64) -> f64 {
    x.exp()
}

const SIN_N: usize = 1024;

/// sin(2π·i/1024), i = 0 … 1024.
type SinPoints = [f64; SIN_N + 1];

/// The points of [`sin_lookup`]'s table.
fn sin_points() -> &'static SinPoints {
    static TABLE: std::sync::OnceLock<SinPoints> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        std::array::from_fn(|i| (std::f64::consts::TAU * i as f64 / SIN_N as f64).sin())
    })
}

/// sin(2π·turns) by linear interpolation in the table `t` ([`sin_points`]), and its slope
/// per turn in that segment. The interpolation error is at most (2π/1024)²/8 ≈ 4.7e-6 of the
/// amplitude: 1e-11 m for a 2 µm lead error.
#[inline(always)]
fn sin_lookup(t: &SinPoints, turns: f64) -> (f64, f64) {
    let u = (turns - f64::floor(turns)) * SIN_N as f64;
    // u reaches 1024 itself when the fraction rounds up: that is the last segment's end.
    let u_floor = f64::floor(u).min((SIN_N - 1) as f64);
    // The segment index from the bits of 2^52 + ⌊u⌋ (exact: 0 ≤ ⌊u⌋ ≤ 1023): one sum and a
    // mask instead of a saturating float-to-integer cast and two bounds checks per T3. A
    // non-finite u (a diverged state) lands in some segment; the value is NaN anyway.
    let i = ((u_floor + 4_503_599_627_370_496.0).to_bits() & (SIN_N as u64 - 1)) as usize;
    let f = u - i as f64;
    let (a, b) = (t[i], t[i + 1]);
    (a + (b - a) * f, (b - a) * SIN_N as f64)
}

#[inline]
fn dead_zone(gap: f64, half: f64) -> f64 {
    if gap > half {
        gap - half
    } else if gap < -half {
        gap + half
    } else {
        0.0
    }
}

/// Euler–Bernoulli crossbeam, simply supported at X = 0 and X = span, loaded by its own
/// weight and by the tool posts at their current X positions.
#[derive(Debug, Clone)]
pub struct Beam {
    span_m: f64,
    ei_nm2: f64,
    w_n_per_m: f64,
    /// The tool posts hanging on the beam, in preset order (at most two are used).
    pub posts: Vec<BeamPost>,
}

/// A tool post on the crossbeam: its weight loads the beam at its X position, and the sag
/// there moves its Z.
#[derive(Debug, Clone)]
pub struct BeamPost {
    /// Index of the axis moving the post along the beam, into the positions [`Beam::sag_m`]
    /// reads.
    pub x_axis: usize,
    /// Index of the post's vertical ram axis, which the sag displaces.
    pub z_axis: usize,
    /// Weight of the post acting on the beam, N.
    pub weight_n: f64,
}

impl Beam {
    /// The beam of `cb`, with post axes resolved to indices by `axis_index` (posts whose
    /// axes are missing are left out); None when the crossbeam is disabled.
    pub fn new(cb: &Crossbeam, axis_index: impl Fn(&str) -> Option<usize>) -> Option<Beam> {
        if !cb.enabled {
            return None;
        }
        let posts = cb
            .posts
            .iter()
            .filter_map(|p| {
                Some(BeamPost {
                    x_axis: axis_index(&p.x_axis)?,
                    z_axis: axis_index(&p.z_axis)?,
                    weight_n: p.weight_n,
                })
            })
            .collect();
        Some(Beam {
            span_m: units::mm_to_m(cb.span_mm),
            ei_nm2: units::gpa_to_pa(cb.youngs_modulus_gpa) * units::cm4_to_m4(cb.area_moment_cm4),
            w_n_per_m: cb.self_weight_n_per_m,
            posts,
        })
    }

    /// Downward deflection at `x_m` for post loads at `loads` = [(position, weight)].
    pub fn deflection_m(&self, x_m: f64, loads: &[(f64, f64)]) -> f64 {
        let l = self.span_m;
        let x = x_m.clamp(0.0, l);
        let ei = self.ei_nm2;
        let mut d = self.w_n_per_m * x * (l * l * l - 2.0 * l * x * x + x * x * x) / (24.0 * ei);
        for &(a_m, p_n) in loads {
            let a = a_m.clamp(0.0, l);
            let (xx, aa) = if x <= a { (x, a) } else { (l - x, l - a) };
            let b = l - aa;
            d += p_n * b * xx * (l * l - b * b - xx * xx) / (6.0 * ei * l);
        }
        d
    }

    /// Z displacement (m, + up) of each post's tool, in post order.
    pub fn sag_m(&self, x_pos_m: &[f64], out: &mut [f64; 2]) {
        let mut loads = [(0.0, 0.0); 2];
        for (i, p) in self.posts.iter().enumerate().take(2) {
            loads[i] = (x_pos_m[p.x_axis], p.weight_n);
        }
        let n = self.posts.len().min(2);
        for (i, p) in self.posts.iter().enumerate().take(2) {
            out[i] = -self.deflection_m(x_pos_m[p.x_axis], &loads[..n]);
        }
    }
}
