//! The mechanical plant of one feed axis: motor, coupling/backlash, ball screw, table,
//! friction, gravity, screw thermal growth, lead error and the encoders; plus the crossbeam
//! of a vertical lathe, which couples the X position of each tool post into its Z axis.
//!
//! Internally everything is SI and load-side: the motor angle is carried as the table travel
//! it corresponds to (`x_m`), and motor inertia as its reflected mass. Positions are in the
//! screw's own frame (`x_t` is where the nut is along an ideal screw); thermal growth and lead
//! error turn that into where the table really is.

use crate::preset::{AxisParams, Coupling, Crossbeam};
use crate::servo::{masses, plant_substeps};

const G_MPS2: f64 = 9.80665;
/// Below this table speed a sign change is not counted as a reversal (creep noise).
const REVERSAL_SPEED_MPS: f64 = 1e-5;

/// Friction on the slide (guideways + nut), with a stick/slip treatment that lands exactly
/// on zero velocity: no chatter and no drift at rest.
#[derive(Debug, Clone)]
pub struct FrictionModel {
    pub enabled: bool,
    pub coulomb_n: f64,
    pub viscous_n_s_per_m: f64,
    pub stribeck: bool,
    pub static_n: f64,
    pub stribeck_mps: f64,
    stribeck_inv_mps: f64,
}

/// Per-body step constants of [`FrictionModel::step`].
#[derive(Debug, Clone, Copy, Default)]
pub struct Body {
    pub h_over_m: f64,
    pub m_over_h: f64,
    pub visc_inv: f64,
}

impl FrictionModel {
    pub fn from_params(a: &AxisParams) -> FrictionModel {
        let f = &a.friction;
        FrictionModel {
            enabled: f.enabled,
            coulomb_n: f.coulomb_n,
            viscous_n_s_per_m: f.viscous_n_s_per_m,
            stribeck: f.stribeck.enabled,
            static_n: f.stribeck.static_n,
            stribeck_mps: f.stribeck.velocity_mm_per_s * 1e-3,
            stribeck_inv_mps: 1.0 / (f.stribeck.velocity_mm_per_s * 1e-3),
        }
    }

    /// Kinetic friction magnitude (without the viscous part) at speed |v|.
    #[inline]
    fn kinetic_n(&self, speed_mps: f64, scale: f64) -> f64 {
        if self.stribeck {
            let r = speed_mps * self.stribeck_inv_mps;
            // Past 6 characteristic velocities the Stribeck term is below 3e-16 of the step;
            // skipping exp there also avoids libm's slow underflow path.
            if r > 6.0 {
                return scale * self.coulomb_n;
            }
            scale * (self.coulomb_n + (self.static_n - self.coulomb_n) * (-r * r).exp())
        } else {
            scale * self.coulomb_n
        }
    }

    /// Step constants for a body of mass `m_kg` and step `h_s`, so that the per-step update
    /// has no divisions (they dominate the latency of this serial chain).
    pub fn body(&self, m_kg: f64, h_s: f64) -> Body {
        Body {
            h_over_m: h_s / m_kg,
            m_over_h: m_kg / h_s,
            visc_inv: 1.0 / (1.0 + h_s * self.viscous_n_s_per_m / m_kg),
        }
    }

    /// Advances the velocity of `body` by one step under `f_other_n` plus friction. Returns
    /// (new velocity, friction force). If friction can bring the body to rest within the
    /// step, it does so exactly (stick) and returns the force that took.
    #[inline]
    pub fn step(&self, body: &Body, v_mps: f64, f_other_n: f64, scale: f64) -> (f64, f64) {
        let v_free = v_mps + body.h_over_m * f_other_n;
        if !self.enabled {
            return (v_free, 0.0);
        }
        let f_stop = -body.m_over_h * v_free;
        let f_static = if self.stribeck {
            scale * self.static_n
        } else {
            scale * self.coulomb_n
        };
        if f_stop.abs() <= f_static {
            return (0.0, f_stop);
        }
        let dir = v_free.signum();
        let fk = self.kinetic_n(v_mps.abs(), scale);
        let v_new = (v_free - dir * body.h_over_m * fk) * body.visc_inv;
        if v_new * dir <= 0.0 {
            return (0.0, f_stop);
        }
        (v_new, -dir * fk - self.viscous_n_s_per_m * v_new)
    }
}

/// Stroke-dependent friction rise (SPEC §5): short reversal strokes break the lubricant
/// film down, long strokes rebuild it.
#[derive(Debug, Clone)]
pub struct StrokeFriction {
    pub enabled: bool,
    pitch_m: f64,
    rise_ratio: f64,
    growth_strokes: f64,
    recovery_m: f64,
    /// Short-stroke level n.
    pub level: f64,
    /// e^(−n/growth), kept up to date with n.
    decay: f64,
    /// Distance beyond the pitch already applied to the recovery on this stroke.
    beyond_done_m: f64,
    dir: f64,
    last_rev_m: Option<f64>,
    /// Current friction multiplier.
    pub scale: f64,
}

impl StrokeFriction {
    fn from_params(a: &AxisParams) -> StrokeFriction {
        let s = &a.friction.stroke;
        StrokeFriction {
            enabled: s.enabled,
            pitch_m: s.pitch_mm * 1e-3,
            rise_ratio: s.rise_ratio,
            growth_strokes: s.growth_strokes,
            recovery_m: s.recovery_mm * 1e-3,
            level: 0.0,
            decay: 1.0,
            beyond_done_m: 0.0,
            dir: 0.0,
            last_rev_m: None,
            scale: 1.0,
        }
    }

    #[inline]
    fn observe(&mut self, x_m: f64, v_mps: f64) {
        // Recovery: past the pitch, the film rebuilds with every mm travelled.
        if self.level > 0.0
            && let Some(prev) = self.last_rev_m
        {
            let beyond = (x_m - prev).abs() - self.pitch_m;
            if beyond > self.beyond_done_m {
                let u = (beyond - self.beyond_done_m.max(0.0)) / self.recovery_m;
                self.beyond_done_m = beyond;
                // Per step u is ~1e-3, so the series is exact to ~1e-12 and avoids two exp
                // calls every T3 on a long stroke; each reversal recomputes exactly.
                let f = small_exp(-u);
                let g = self.level / self.growth_strokes;
                self.level *= f;
                self.decay *= small_exp(g * (1.0 - f));
                if self.level < 1e-6 {
                    self.level = 0.0;
                    self.decay = 1.0;
                }
                self.scale = if self.enabled {
                    1.0 + self.rise_ratio * (1.0 - self.decay)
                } else {
                    1.0
                };
            }
        }
        if v_mps.abs() < REVERSAL_SPEED_MPS {
            return;
        }
        let dir = v_mps.signum();
        if dir == self.dir {
            return;
        }
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
        self.decay = (-self.level / self.growth_strokes).exp();
        self.scale = if self.enabled {
            1.0 + self.rise_ratio * (1.0 - self.decay)
        } else {
            1.0
        };
    }
}

/// First-order screw temperature and the elongation it causes.
#[derive(Debug, Clone)]
pub struct ScrewThermal {
    pub enabled: bool,
    alpha_per_k: f64,
    inv_capacity: f64,
    loss_w_per_k: f64,
    friction_heat_share: f64,
    motion_heat_w_s_per_m: f64,
    pub ambient_c: f64,
    reference_c: f64,
    fixed_end_m: f64,
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
            fixed_end_m: t.fixed_end_mm * 1e-3,
            temp_c: t.initial_c,
        }
    }

    #[inline]
    fn step(&mut self, fric_power_w: f64, speed_mps: f64, dt_s: f64) {
        if !self.enabled {
            return;
        }
        let q_w = self.friction_heat_share * fric_power_w + self.motion_heat_w_s_per_m * speed_mps;
        self.temp_c +=
            dt_s * self.inv_capacity * (q_w - self.loss_w_per_k * (self.temp_c - self.ambient_c));
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

#[derive(Debug, Clone)]
struct LeadErr {
    enabled: bool,
    amplitude_m: f64,
    inv_period_per_m: f64,
    phase_turns: f64,
    cumulative: f64,
    /// (position m, error m)
    table: Vec<(f64, f64)>,
}

impl LeadErr {
    #[inline]
    fn at(&self, x_m: f64) -> f64 {
        if !self.enabled {
            return 0.0;
        }
        // One lookup per T3 instead of a libm sin of a large argument (x/period reaches the
        // hundreds on a long axis); see `sin_table` for the error bound.
        let turns = x_m * self.inv_period_per_m;
        let frac = turns - f64::floor(turns);
        let cyclic = self.amplitude_m * sin_table(frac + self.phase_turns);
        cyclic + self.cumulative * x_m + crate::table::interp(&self.table, x_m)
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Mech {
    /// One body, no play.
    Rigid,
    /// One body while a flank is in contact; motor and table move apart inside the gap.
    RigidPlay,
    /// Spring + damper with an optional dead zone.
    TwoMass { k_n_per_m: f64, c_n_s_per_m: f64 },
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
    pub vel_mps: f64,
    pub friction_n: f64,
    /// Motor minus table inside the backlash: −b/2 … +b/2 at the flanks.
    pub gap_m: f64,
    pub thermal_m: f64,
    pub lead_err_m: f64,
}

#[derive(Debug, Clone)]
pub struct AxisPlant {
    mech: Mech,
    m_m: f64,
    m_t: f64,
    half_gap_m: f64,
    f_grav_n: f64,
    pub friction: FrictionModel,
    pub stroke: StrokeFriction,
    pub thermal: ScrewThermal,
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
    pub x_m: f64,
    pub v_m: f64,
    pub x_t: f64,
    pub v_t: f64,
    /// +1/−1: which flank is in contact (RigidPlay); 0: inside the gap.
    contact: i8,
    pub out: PlantOut,
}

impl AxisPlant {
    pub fn new(a: &AxisParams, t3_s: f64, initial_pos_m: f64) -> AxisPlant {
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
                amplitude_m: 0.0,
                inv_period_per_m: 0.0,
                phase_turns: 0.0,
                cumulative: 0.0,
                table: vec![],
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
            out: PlantOut::default(),
        };
        p.retune(a);
        // Start with the load resting on the flank gravity pushes it onto.
        p.contact = if p.f_grav_n > 0.0 { -1 } else { 1 };
        if p.half_gap_m > 0.0 {
            p.x_t = p.x_m - p.contact as f64 * p.half_gap_m;
        }
        p.refresh_out(0.0);
        p
    }

    /// Takes new parameters while keeping the physical state (live editing).
    pub fn retune(&mut self, a: &AxisParams) {
        let (m_m, m_t) = masses(a);
        self.m_m = m_m;
        self.m_t = m_t;
        self.half_gap_m = if a.lost_motion.enabled {
            0.5 * a.lost_motion.width_um * 1e-6
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
                k_n_per_m: stiffness_n_per_um * 1e6,
                c_n_s_per_m: damping_n_s_per_m,
            },
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
        let level = self.stroke.level;
        let (dir, last) = (self.stroke.dir, self.stroke.last_rev_m);
        self.stroke = StrokeFriction::from_params(a);
        self.stroke.level = level;
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
            amplitude_m: l.amplitude_um * 1e-6,
            inv_period_per_m: 1.0 / (l.period_mm * 1e-3),
            phase_turns: l.phase_deg / 360.0,
            cumulative: l.cumulative_um_per_m * 1e-6,
            table: l.table.iter().map(|&(x, e)| (x * 1e-3, e * 1e-6)).collect(),
        };
        let e = &a.encoder;
        let q = |q: f64| (q, 1.0 / q);
        self.motor_q_m = e
            .quantize_motor
            .then(|| q(a.drive.lead_mm * 1e-3 / e.motor_counts_per_rev as f64));
        self.scale_q_m = e.quantize_scale.then(|| q(e.scale_resolution_um * 1e-6));
        self.n_sub = plant_substeps(a, self.t3_s);
        self.h_s = self.t3_s / self.n_sub as f64;
        self.body_all = self.friction.body(self.m_m + self.m_t, self.h_s);
        self.body_table = self.friction.body(self.m_t, self.h_s);
        self.motor_h_over_m = if self.m_m > 0.0 {
            self.h_s / self.m_m
        } else {
            0.0
        };
    }

    /// Advances the mechanics by one T3 under the motor force `force_n` (load side).
    #[inline]
    pub fn step(&mut self, force_n: f64) {
        let h = self.h_s;
        let scale = self.stroke.scale;
        let mut fric = 0.0;
        for _ in 0..self.n_sub {
            fric = match self.mech {
                Mech::Rigid => {
                    let (v, f) = self.friction.step(
                        &self.body_all,
                        self.v_t,
                        force_n + self.f_grav_n,
                        scale,
                    );
                    self.v_t = v;
                    self.v_m = v;
                    self.x_t += h * v;
                    self.x_m = self.x_t;
                    f
                }
                Mech::RigidPlay => self.step_play(force_n, h, scale),
                Mech::TwoMass {
                    k_n_per_m,
                    c_n_s_per_m,
                } => {
                    let gap = self.x_m - self.x_t;
                    let defl = dead_zone(gap, self.half_gap_m);
                    let f_s = if defl != 0.0 || self.half_gap_m == 0.0 {
                        k_n_per_m * defl + c_n_s_per_m * (self.v_m - self.v_t)
                    } else {
                        0.0
                    };
                    self.v_m += self.motor_h_over_m * (force_n - f_s);
                    let (v, f) =
                        self.friction
                            .step(&self.body_table, self.v_t, f_s + self.f_grav_n, scale);
                    self.v_t = v;
                    self.x_m += h * self.v_m;
                    self.x_t += h * self.v_t;
                    f
                }
            };
        }
        self.stroke.observe(self.x_t, self.v_t);
        self.thermal
            .step((fric * self.v_t).abs(), self.v_t.abs(), self.t3_s);
        self.refresh_out(fric);
    }

    /// Rigid drive with play: one body while a flank transmits force, two bodies in the gap,
    /// an inelastic impact when the gap closes.
    fn step_play(&mut self, force_n: f64, h: f64, scale: f64) -> f64 {
        let b2 = self.half_gap_m;
        if self.contact != 0 {
            let (v, f) =
                self.friction
                    .step(&self.body_all, self.v_t, force_n + self.f_grav_n, scale);
            // Force the motor flank must exert on the table for it to share this motion.
            let f_contact = self.m_t * (v - self.v_t) / h - self.f_grav_n - f;
            if f_contact * self.contact as f64 >= 0.0 {
                self.v_t = v;
                self.v_m = v;
                self.x_m += h * v;
                self.x_t = self.x_m - self.contact as f64 * b2;
                return f;
            }
            self.contact = 0;
        }
        self.v_m += self.motor_h_over_m * force_n;
        self.x_m += h * self.v_m;
        let (v, f) = self
            .friction
            .step(&self.body_table, self.v_t, self.f_grav_n, scale);
        self.v_t = v;
        self.x_t += h * v;
        let gap = self.x_m - self.x_t;
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

    #[inline]
    fn refresh_out(&mut self, fric_n: f64) {
        let thermal = self.thermal.elongation_m(self.x_t);
        let lead = self.lead.at(self.x_t);
        let pos = self.x_t + thermal + lead;
        self.out = PlantOut {
            motor_pos_m: self.x_m,
            motor_enc_m: quantize(self.x_m, self.motor_q_m),
            pos_m: pos,
            scale_m: quantize(pos, self.scale_q_m),
            vel_mps: self.v_t,
            friction_n: fric_n,
            gap_m: self.x_m - self.x_t,
            thermal_m: thermal,
            lead_err_m: lead,
        };
    }

    /// Net constant force on the table along the axis (gravity component plus offset).
    pub fn gravity_force_n(&self) -> f64 {
        self.f_grav_n
    }
}

#[inline]
fn quantize(x: f64, q: Option<(f64, f64)>) -> f64 {
    match q {
        Some((q, inv)) => f64::floor(x * inv + 0.5) * q,
        None => x,
    }
}

/// e^x for |x| ≲ 0.01 by its series to third order; exact libm exp beyond.
#[inline]
fn small_exp(x: f64) -> f64 {
    if x.abs() < 0.01 {
        1.0 + x * (1.0 + x * (0.5 + x * (1.0 / 6.0)))
    } else {
        x.exp()
    }
}

const SIN_N: usize = 1024;

/// sin(2π·turns) from a 1024-point table with linear interpolation. The interpolation error
/// is at most (2π/1024)²/8 ≈ 4.7e-6 of the amplitude: 1e-11 m for a 2 µm lead error.
#[inline]
fn sin_table(turns: f64) -> f64 {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    let t = TABLE.get_or_init(|| {
        (0..=SIN_N)
            .map(|i| (std::f64::consts::TAU * i as f64 / SIN_N as f64).sin())
            .collect()
    });
    let u = (turns - f64::floor(turns)) * SIN_N as f64;
    let i = (u as usize).min(SIN_N - 1);
    let f = u - i as f64;
    t[i] + (t[i + 1] - t[i]) * f
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
    pub posts: Vec<BeamPost>,
}

#[derive(Debug, Clone)]
pub struct BeamPost {
    pub x_axis: usize,
    pub z_axis: usize,
    pub weight_n: f64,
}

impl Beam {
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
            span_m: cb.span_mm * 1e-3,
            ei_nm2: cb.youngs_modulus_gpa * 1e9 * cb.area_moment_cm4 * 1e-8,
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
