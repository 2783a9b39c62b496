//! The mechanics of the generator's axis, in continuous time, integrated by classical
//! fixed-step RK4 with events.
//!
//! Bodies (all positions as load travel, m):
//! - the motor rotor with the screw, mass m_r (rotor inertia reflected through the lead),
//!   at travel u;
//! - the carriage (nut + table), mass m_c, at x_c. An ideal screw puts the nut at u; a lead
//!   error puts it at g(u) = u + e(u);
//! - optionally a payload of mass m_p on a spring/damper on the carriage (compliance).
//!
//! The motor–nut link is rigid, a contact spring with a dead zone (two-mass backlash), or
//! rigid lost motion (the flanks transmit force only in contact; inside the gap motor and
//! carriage move apart, a closing gap is an inelastic impact). While motor and carriage move
//! as one body the equation is written in u with the Lagrangian of the lead map:
//! (m_r + m_c g′²)·ü + m_c g′ g″ u̇² = F_m + g′·F_c, F_c all forces on the carriage.
//! Otherwise m_r ü = F_m − g′·F_link and m_c ẍ_c = F_link + F_c.
//!
//! Friction acts on the carriage ([`super::friction`]). With an exact stick law each
//! sub-step is integrated with the friction direction fixed; when the carriage velocity
//! changes sign inside a sub-step, the crossing is located by linear interpolation, the
//! step is redone up to it, and the carriage either sticks (the other forces lie within the
//! static level) or reverses. A stuck carriage breaks away when the net force leaves the
//! static band, checked at every sub-step start. Lost-motion impacts are located the same
//! way. Everything else (springs, dead zone, tanh friction) is plain RK4.

use super::friction::{FrictionLaw, StrokeState};
use super::shapes::{LeadMap, Load, SpringLaw};

/// Length of the state vector.
const N: usize = 8;
/// Motor travel u, m.
const U: usize = 0;
/// Motor velocity, m/s.
const VU: usize = 1;
/// Carriage position, m.
const XC: usize = 2;
/// Carriage velocity, m/s.
const VC: usize = 3;
/// Payload position, m.
const XP: usize = 4;
/// Payload velocity, m/s.
const VP: usize = 5;
/// Heat state of the screw (unit gain; see [`Heat`]).
const HEAT: usize = 6;
/// Motor force behind the current-loop lag, N.
const FORCE: usize = 7;

/// Events one sub-step may split into before it is finished without looking for more.
const MAX_EVENTS: usize = 8;

type State = [f64; N];

/// How the motor's screw drives the nut.
#[derive(Debug, Clone, Copy)]
pub enum Link {
    /// No play, no compliance.
    Rigid,
    /// A contact spring (stiffness, damping while engaged) with a dead zone of total width
    /// `gap_m`: the two-mass backlash.
    Spring {
        /// Total dead-zone width, m (0: no play).
        gap_m: f64,
        /// Contact stiffness, N/m.
        k_n_per_m: f64,
        /// Contact damping while engaged, N·s/m.
        c_n_s_per_m: f64,
    },
    /// Rigid flanks with a gap of total width `gap_m`.
    LostMotion {
        /// Total gap width, m.
        gap_m: f64,
    },
}

/// A payload on a spring/damper on the carriage (compliance).
#[derive(Debug, Clone, Copy)]
pub struct Payload {
    /// Payload mass, kg.
    pub mass_kg: f64,
    /// Spring law between carriage and payload.
    pub spring: SpringLaw,
    /// Damping between carriage and payload, N·s/m.
    pub damping_n_s_per_m: f64,
}

/// What heats the screw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HeatInput {
    /// Heat proportional to carriage speed (nut and bearings): q = |v|.
    Speed,
    /// Dissipated power: friction power plus motor copper loss, q = |F_fr·v| + ρ·F_m².
    Power {
        /// Copper loss per squared motor force, W/N².
        copper_w_per_n2: f64,
    },
}

/// Screw heating with one time constant: dθ/dt = q − θ/τ. θ is a unit-gain heat state;
/// the temperature rise is gain·θ, fixed afterwards from the wanted growth (the heat does
/// not act back on the mechanics, so the gain can be chosen after the run).
#[derive(Debug, Clone, Copy)]
pub struct Heat {
    /// What heats the screw.
    pub input: HeatInput,
    /// Thermal time constant τ, s.
    pub time_constant_s: f64,
}

/// Everything about the mechanics of the true machine.
#[derive(Debug, Clone)]
pub struct RigParams {
    /// Rotor (and screw) inertia as load-side mass, kg.
    pub motor_mass_kg: f64,
    /// Carriage mass (with the payload unless a payload spring is given), kg.
    pub carriage_mass_kg: f64,
    /// Payload on a spring (compliance), if any.
    pub payload: Option<Payload>,
    /// How the screw drives the nut.
    pub link: Link,
    /// Slide friction on the carriage.
    pub friction: FrictionLaw,
    /// Forces on the carriage.
    pub loads: Vec<Load>,
    /// Travel error of the screw.
    pub lead: LeadMap,
    /// Screw heating, if tracked.
    pub heat: Option<Heat>,
    /// Motor force per commanded force (the drive's force constant against its nominal).
    pub force_gain: f64,
    /// Current-loop lag, s (0: the force follows the command at once).
    pub force_lag_s: f64,
}

impl RigParams {
    /// A rigid axis with linear viscous friction only.
    pub fn rigid(motor_mass_kg: f64, carriage_mass_kg: f64, viscous_n_s_per_m: f64) -> RigParams {
        RigParams {
            motor_mass_kg,
            carriage_mass_kg,
            payload: None,
            link: Link::Rigid,
            friction: FrictionLaw {
                viscous_n_s_per_m,
                ..FrictionLaw::default()
            },
            loads: Vec::new(),
            lead: LeadMap::Ideal,
            heat: None,
            force_gain: 1.0,
            force_lag_s: 0.0,
        }
    }

    /// The fastest mechanical rate, 1/s: sets the number of RK4 sub-steps.
    pub fn fastest_rate_per_s(&self) -> f64 {
        let m_r = self.motor_mass_kg;
        let m_c = self.carriage_mass_kg;
        let mut w: f64 = (self.friction.viscous_n_s_per_m / m_c).abs();
        if let Link::Spring {
            k_n_per_m,
            c_n_s_per_m,
            ..
        } = self.link
        {
            let m_red = m_r * m_c / (m_r + m_c);
            w = w.max((k_n_per_m / m_red).sqrt()).max(c_n_s_per_m / m_red);
        }
        if let Some(p) = &self.payload {
            let m_red = p.mass_kg * m_c / (p.mass_kg + m_c);
            let k = p.spring.stiffness_n_per_m();
            w = w.max((k / m_red).sqrt()).max(p.damping_n_s_per_m / m_red);
        }
        if let Some(eps) = self.friction.tanh_speed_mps {
            let level = self
                .friction
                .level_n(0.0, 1.0, 0.0)
                .max(self.friction.level_n(0.0, -1.0, 0.0));
            w = w.max(level / (eps * m_c));
        }
        if self.force_lag_s > 0.0 {
            w = w.max(1.0 / self.force_lag_s);
        }
        w
    }
}

/// A snapshot of the bodies, for the sensors.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Bodies {
    /// Motor travel, m.
    pub motor_m: f64,
    /// Motor velocity, m/s.
    pub motor_mps: f64,
    /// Carriage position, m.
    pub carriage_m: f64,
    /// Carriage velocity, m/s.
    pub carriage_mps: f64,
    /// Payload position (the carriage's without a payload), m.
    pub payload_m: f64,
    /// Unit-gain heat state.
    pub heat: f64,
}

/// What ends one integration attempt early.
#[derive(Debug, Clone, Copy)]
enum Event {
    /// The sliding carriage reached zero velocity.
    Stop,
    /// The lost-motion gap closed on this flank.
    Impact(i8),
}

/// The mechanics of one axis.
#[derive(Debug, Clone)]
pub struct Rig {
    p: RigParams,
    s: State,
    /// Lost motion: the flank in contact (+1: the screw pushes the carriage in +), 0 free.
    contact: i8,
    /// The carriage is held by static friction.
    stuck: bool,
    /// Direction the sliding carriage moves in (stick law).
    dir: f64,
    stroke: StrokeState,
    stroke_n: f64,
    /// Force the drive is asked for, after the force gain, N.
    target_n: f64,
}

#[inline]
fn add(a: &State, b: &State, h: f64) -> State {
    let mut o = *a;
    for i in 0..N {
        o[i] += h * b[i];
    }
    o
}

#[inline]
fn dead_zone(d: f64, half: f64) -> f64 {
    if d > half {
        d - half
    } else if d < -half {
        d + half
    } else {
        0.0
    }
}

impl Rig {
    /// The axis at rest with the motor at `motor_m`. Inside a gap the nut starts at
    /// `gap_frac` (−1…1) of the half gap from the carriage flank centre; ±1 is in contact.
    pub fn new(p: RigParams, motor_m: f64, gap_frac: f64) -> Rig {
        let gap_m = match p.link {
            Link::Rigid => 0.0,
            Link::Spring { gap_m, .. } | Link::LostMotion { gap_m } => gap_m,
        };
        let frac = gap_frac.clamp(-1.0, 1.0);
        let contact = match p.link {
            Link::LostMotion { .. } if frac.abs() < 1.0 => 0,
            Link::LostMotion { .. } => frac.signum() as i8,
            _ => 1,
        };
        let (e, _, _) = p.lead.eval(motor_m);
        let x_c = motor_m + e - frac * gap_m / 2.0;
        let mut s = [0.0; N];
        s[U] = motor_m;
        s[XC] = x_c;
        s[XP] = x_c;
        let sticks = p.friction.sticks();
        Rig {
            p,
            s,
            contact,
            stuck: sticks,
            dir: 1.0,
            stroke: StrokeState::new(x_c),
            stroke_n: 0.0,
            target_n: 0.0,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &RigParams {
        &self.p
    }

    /// Where the bodies are.
    pub fn bodies(&self) -> Bodies {
        Bodies {
            motor_m: self.s[U],
            motor_mps: self.s[VU],
            carriage_m: self.s[XC],
            carriage_mps: self.s[VC],
            payload_m: if self.p.payload.is_some() {
                self.s[XP]
            } else {
                self.s[XC]
            },
            heat: self.s[HEAT],
        }
    }

    /// Whether static friction holds the carriage.
    pub fn is_stuck(&self) -> bool {
        self.stuck
    }

    /// The force the motor puts out now, N.
    pub fn motor_force_n(&self) -> f64 {
        self.force_of(&self.s)
    }

    /// Sets the commanded force for the coming period (before the force gain), N.
    pub fn command(&mut self, force_cmd_n: f64) {
        self.target_n = self.p.force_gain * force_cmd_n;
    }

    #[inline]
    fn force_of(&self, s: &State) -> f64 {
        if self.p.force_lag_s > 0.0 {
            s[FORCE]
        } else {
            self.target_n
        }
    }

    /// Motor and carriage move as one body.
    #[inline]
    fn clustered(&self) -> bool {
        match self.p.link {
            Link::Rigid => true,
            Link::LostMotion { .. } => self.contact != 0,
            Link::Spring { .. } => false,
        }
    }

    /// Nut minus carriage while clustered, m.
    fn offset_m(&self) -> f64 {
        match self.p.link {
            Link::LostMotion { gap_m } => f64::from(self.contact) * gap_m / 2.0,
            _ => 0.0,
        }
    }

    /// Force of the motor–nut link on the carriage when the bodies are apart, N.
    #[inline]
    fn link_force(&self, s: &State, g1: f64, e: f64) -> f64 {
        match self.p.link {
            Link::Spring {
                gap_m,
                k_n_per_m,
                c_n_s_per_m,
            } => {
                let d = dead_zone(s[U] + e - s[XC], gap_m / 2.0);
                if d == 0.0 && gap_m > 0.0 {
                    0.0
                } else {
                    k_n_per_m * d + c_n_s_per_m * (g1 * s[VU] - s[VC])
                }
            }
            _ => 0.0,
        }
    }

    /// Loads plus the payload spring on the carriage, N.
    #[inline]
    fn carriage_forces(&self, t_s: f64, s: &State) -> f64 {
        let mut f: f64 = self.p.loads.iter().map(|l| l.force_n(t_s, s[XC])).sum();
        if let Some(p) = &self.p.payload {
            f += p.spring.force_n(s[XP] - s[XC], s[XC]) + p.damping_n_s_per_m * (s[VP] - s[VC]);
        }
        f
    }

    /// Motor acceleration of the clustered bodies (not stuck), m/s².
    #[inline]
    fn cluster_acc(&self, fm: f64, f_c: f64, fr: f64, s: &State) -> f64 {
        let (_, de, dde) = self.p.lead.eval(s[U]);
        let g1 = 1.0 + de;
        let (m_r, m_c) = (self.p.motor_mass_kg, self.p.carriage_mass_kg);
        (fm + g1 * (f_c + fr) - m_c * g1 * dde * s[VU] * s[VU]) / (m_r + m_c * g1 * g1)
    }

    /// Time derivative of the state.
    fn deriv(&self, t_s: f64, s: &State) -> State {
        let mut d = [0.0; N];
        let fm = self.force_of(s);
        let f_c = self.carriage_forces(t_s, s);
        let fr = if self.stuck {
            0.0
        } else {
            self.p.friction.force_n(s[VC], self.dir, self.stroke_n)
        };
        if self.clustered() {
            if !self.stuck {
                let (_, de, dde) = self.p.lead.eval(s[U]);
                let acc = self.cluster_acc(fm, f_c, fr, s);
                d[U] = s[VU];
                d[VU] = acc;
                d[XC] = (1.0 + de) * s[VU];
                d[VC] = (1.0 + de) * acc + dde * s[VU] * s[VU];
            }
        } else {
            let (e, de, _) = self.p.lead.eval(s[U]);
            let g1 = 1.0 + de;
            let f_link = self.link_force(s, g1, e);
            d[U] = s[VU];
            d[VU] = (fm - g1 * f_link) / self.p.motor_mass_kg;
            if !self.stuck {
                d[XC] = s[VC];
                d[VC] = (f_link + f_c + fr) / self.p.carriage_mass_kg;
            }
        }
        if let Some(p) = &self.p.payload {
            let f_pl =
                p.spring.force_n(s[XP] - s[XC], s[XC]) + p.damping_n_s_per_m * (s[VP] - s[VC]);
            d[XP] = s[VP];
            d[VP] = -f_pl / p.mass_kg;
        }
        if let Some(h) = &self.p.heat {
            let q = match h.input {
                HeatInput::Speed => s[VC].abs(),
                HeatInput::Power { copper_w_per_n2 } => {
                    (fr * s[VC]).abs() + copper_w_per_n2 * fm * fm
                }
            };
            d[HEAT] = q - s[HEAT] / h.time_constant_s;
        }
        if self.p.force_lag_s > 0.0 {
            d[FORCE] = (self.target_n - s[FORCE]) / self.p.force_lag_s;
        }
        d
    }

    /// One classical RK4 step of `h_s` from `s` at `t_s` in the current mode.
    fn rk4(&self, t_s: f64, s: &State, h_s: f64) -> State {
        let k1 = self.deriv(t_s, s);
        let k2 = self.deriv(t_s + h_s / 2.0, &add(s, &k1, h_s / 2.0));
        let k3 = self.deriv(t_s + h_s / 2.0, &add(s, &k2, h_s / 2.0));
        let k4 = self.deriv(t_s + h_s, &add(s, &k3, h_s));
        let mut o = *s;
        for i in 0..N {
            o[i] += h_s / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
        o
    }

    /// Puts the constrained coordinates back on their constraint after a step.
    fn project(&mut self) {
        if self.clustered() {
            if self.stuck {
                self.s[VU] = 0.0;
            }
            let (e, de, _) = self.p.lead.eval(self.s[U]);
            self.s[XC] = self.s[U] + e - self.offset_m();
            self.s[VC] = (1.0 + de) * self.s[VU];
        } else if self.stuck {
            self.s[VC] = 0.0;
        }
    }

    /// The non-friction force on the carriage at rest, N.
    fn net_force(&self, t_s: f64) -> f64 {
        let s = &self.s;
        let (e, de, _) = self.p.lead.eval(s[U]);
        let g1 = 1.0 + de;
        let f_c = self.carriage_forces(t_s, s);
        if self.clustered() {
            self.force_of(s) / g1 + f_c
        } else {
            self.link_force(s, g1, e) + f_c
        }
    }

    /// Mode changes decided at the start of a sub-step: lost-motion separation, breakaway.
    fn settle(&mut self, t_s: f64) {
        if matches!(self.p.link, Link::LostMotion { .. }) && self.contact != 0 {
            let fm = self.force_of(&self.s);
            let side = f64::from(self.contact);
            let pushing = if self.stuck {
                fm * side >= 0.0
            } else {
                let (_, de, _) = self.p.lead.eval(self.s[U]);
                let f_c = self.carriage_forces(t_s, &self.s);
                let fr = self.p.friction.force_n(self.s[VC], self.dir, self.stroke_n);
                let acc = self.cluster_acc(fm, f_c, fr, &self.s);
                (fm - self.p.motor_mass_kg * acc) / (1.0 + de) * side >= 0.0
            };
            if !pushing {
                self.contact = 0;
            }
        }
        if self.stuck {
            let f = self.net_force(t_s);
            let fr = &self.p.friction;
            if f > fr.level_n(0.0, 1.0, self.stroke_n) {
                self.stuck = false;
                self.dir = 1.0;
            } else if f < -fr.level_n(0.0, -1.0, self.stroke_n) {
                self.stuck = false;
                self.dir = -1.0;
            }
        } else if self.s[VC] != 0.0 {
            self.dir = self.s[VC].signum();
        }
    }

    /// The first event between `s0` and `s1` and the fraction of the step it happens at.
    fn event(&self, s0: &State, s1: &State) -> Option<(Event, f64)> {
        let mut best: Option<(Event, f64)> = None;
        if self.p.friction.sticks() && !self.stuck {
            let (a, b) = (s0[VC] * self.dir, s1[VC] * self.dir);
            if b < 0.0 {
                best = Some((Event::Stop, if a > 0.0 { a / (a - b) } else { 0.0 }));
            }
        }
        if let (Link::LostMotion { gap_m }, 0) = (self.p.link, self.contact) {
            let half = gap_m / 2.0;
            let gap = |s: &State| s[U] + self.p.lead.eval(s[U]).0 - s[XC];
            let (d0, d1) = (gap(s0), gap(s1));
            for side in [1i8, -1] {
                let k = f64::from(side);
                let (a, b) = (half - k * d0, half - k * d1);
                if b <= 0.0 {
                    let th = if a > 0.0 { a / (a - b) } else { 0.0 };
                    if best.is_none_or(|(_, t)| th < t) {
                        best = Some((Event::Impact(side), th));
                    }
                }
            }
        }
        best
    }

    /// Applies an event at `t_s`.
    fn apply(&mut self, ev: Event, t_s: f64) {
        match ev {
            Event::Stop => {
                self.s[VC] = 0.0;
                if self.clustered() {
                    self.s[VU] = 0.0;
                }
                let f = self.net_force(t_s);
                let fr = &self.p.friction;
                if f > fr.level_n(0.0, 1.0, self.stroke_n) {
                    self.dir = 1.0;
                } else if f < -fr.level_n(0.0, -1.0, self.stroke_n) {
                    self.dir = -1.0;
                } else {
                    self.stuck = true;
                }
            }
            Event::Impact(side) => {
                let (_, de, _) = self.p.lead.eval(self.s[U]);
                let g1 = 1.0 + de;
                let (m_r, m_c) = (self.p.motor_mass_kg, self.p.carriage_mass_kg);
                let v = (m_r * self.s[VU] + m_c * g1 * self.s[VC]) / (m_r + m_c * g1 * g1);
                self.contact = side;
                self.s[VU] = v;
                if v != 0.0 {
                    self.stuck = false;
                    self.dir = v.signum();
                }
                self.project();
            }
        }
    }

    /// Advances the mechanics by `h_s` from `t_s` under the current force command.
    pub fn substep(&mut self, t_s: f64, h_s: f64) {
        let end = t_s + h_s;
        let mut t = t_s;
        for _ in 0..MAX_EVENTS {
            self.settle(t);
            let left = end - t;
            if left <= 1e-9 * h_s {
                return;
            }
            let s0 = self.s;
            let s1 = self.rk4(t, &s0, left);
            match self.event(&s0, &s1) {
                None => {
                    self.s = s1;
                    self.project();
                    return;
                }
                Some((ev, frac)) => {
                    let dt = frac * left;
                    if dt > 0.0 {
                        self.s = self.rk4(t, &s0, dt);
                        self.project();
                    }
                    self.apply(ev, t + dt);
                    t += dt;
                }
            }
        }
        // Chatter: finish the sub-step in the mode reached, then stop a carriage that
        // would otherwise slide against its friction.
        let left = end - t;
        if left > 0.0 {
            self.s = self.rk4(t, &self.s, left);
            self.project();
        }
        if self.p.friction.sticks() && !self.stuck && self.s[VC] * self.dir < 0.0 {
            self.apply(Event::Stop, end);
        }
    }

    /// Book-keeping at the end of a controller period: the short-stroke level.
    pub fn end_period(&mut self) {
        if let Some(law) = &self.p.friction.stroke {
            self.stroke.update(law, self.s[XC], self.s[VC]);
            self.stroke_n = self.stroke.force_n(law);
        }
    }

    /// The short-stroke friction level now, N.
    pub fn stroke_level_n(&self) -> f64 {
        self.stroke_n
    }

    /// Runs open loop under the force command `force_cmd_n` for `dur_s` in sub-steps of
    /// `h_s`, from time `t_s` (for checks of the mechanics alone).
    pub fn push(&mut self, force_cmd_n: f64, t_s: f64, dur_s: f64, h_s: f64) {
        self.command(force_cmd_n);
        let n = (dur_s / h_s).round() as usize;
        for i in 0..n {
            self.substep(t_s + i as f64 * h_s, h_s);
        }
    }
}
