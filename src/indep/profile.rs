//! The position set-point as an exact function of time: a chain of constant-jerk pieces.
//!
//! Point-to-point moves are either bang-bang in acceleration (trapezoidal velocity, as the
//! EMPS excitation) or jerk-limited S-curves (seven pieces). Because the set-point is known
//! between samples, a command delay of a fraction of a sample and a command channel logged
//! off its sample instant are evaluated exactly rather than interpolated.

use super::dice::Dice;
use crate::units::mm_to_m;

/// One piece of constant jerk starting at `t0_s`.
#[derive(Debug, Clone, Copy)]
struct Piece {
    t0_s: f64,
    pos_m: f64,
    vel_mps: f64,
    acc_mps2: f64,
    jerk_mps3: f64,
}

/// A set-point trajectory x(t), held before its start and after its end.
#[derive(Debug, Clone)]
pub struct Profile {
    pieces: Vec<Piece>,
    end_s: f64,
    end_pos_m: f64,
}

/// How one move accelerates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Acceleration switches between +a, 0 and −a (trapezoidal velocity).
    BangBang,
    /// Acceleration ramps with the given jerk, m/s³ (S-curve).
    Jerk(f64),
}

/// Builds a profile move by move.
#[derive(Debug, Clone)]
pub struct ProfileBuilder {
    pieces: Vec<Piece>,
    t_s: f64,
    pos_m: f64,
}

impl ProfileBuilder {
    /// A profile at rest at `pos_m` from t = 0.
    pub fn new(pos_m: f64) -> ProfileBuilder {
        ProfileBuilder {
            pieces: Vec::new(),
            t_s: 0.0,
            pos_m,
        }
    }

    /// Time reached so far, s.
    pub fn time_s(&self) -> f64 {
        self.t_s
    }

    /// Position reached so far, m.
    pub fn pos_m(&self) -> f64 {
        self.pos_m
    }

    /// Appends `dur_s` of constant jerk from the current state, with the given starting
    /// velocity and acceleration (a bang-bang move jumps its acceleration between pieces).
    fn piece(&mut self, dur_s: f64, vel_mps: f64, acc_mps2: f64, jerk_mps3: f64) -> (f64, f64) {
        if dur_s <= 0.0 {
            return (vel_mps, acc_mps2);
        }
        self.pieces.push(Piece {
            t0_s: self.t_s,
            pos_m: self.pos_m,
            vel_mps,
            acc_mps2,
            jerk_mps3,
        });
        let d = dur_s;
        self.pos_m += vel_mps * d + acc_mps2 * d * d / 2.0 + jerk_mps3 * d * d * d / 6.0;
        self.t_s += d;
        (
            vel_mps + acc_mps2 * d + jerk_mps3 * d * d / 2.0,
            acc_mps2 + jerk_mps3 * d,
        )
    }

    /// Stays at rest for `dur_s`.
    pub fn dwell(&mut self, dur_s: f64) {
        self.piece(dur_s, 0.0, 0.0, 0.0);
    }

    /// Moves from rest to rest to `target_m` with at most `speed_mps` and `acc_mps2`.
    pub fn move_to(&mut self, target_m: f64, speed_mps: f64, acc_mps2: f64, shape: Shape) {
        let dist = (target_m - self.pos_m).abs();
        if dist <= 0.0 || speed_mps <= 0.0 || acc_mps2 <= 0.0 {
            return;
        }
        let s = (target_m - self.pos_m).signum();
        match shape {
            Shape::BangBang => {
                let v = speed_mps.min((dist * acc_mps2).sqrt());
                let t_acc = v / acc_mps2;
                let t_cruise = (dist - v * t_acc) / v;
                self.piece(t_acc, 0.0, s * acc_mps2, 0.0);
                self.piece(t_cruise, s * v, 0.0, 0.0);
                self.piece(t_acc, s * v, -s * acc_mps2, 0.0);
            }
            Shape::Jerk(jerk) => self.s_curve(dist, s, speed_mps, acc_mps2, jerk),
        }
        // The pieces land on the target to rounding; snap so that the next move starts
        // exactly there.
        self.pos_m = target_m;
    }

    /// Seven-piece jerk-limited move over `dist` in direction `s`.
    fn s_curve(&mut self, dist: f64, s: f64, speed_mps: f64, acc_mps2: f64, jerk: f64) {
        // Acceleration phase for a peak speed v: ramps of tj = a/j and a plateau; a lower
        // speed that never reaches a uses a = sqrt(v·j). It covers v·(its duration)/2.
        let phase = |v: f64| -> (f64, f64, f64) {
            let a = acc_mps2.min((v * jerk).sqrt());
            let tj = a / jerk;
            let plateau = (v / a - tj).max(0.0);
            (a, tj, plateau)
        };
        let covered = |v: f64| {
            let (_, tj, plateau) = phase(v);
            v * (2.0 * tj + plateau)
        };
        let mut v = speed_mps;
        if covered(v) > dist {
            let (mut lo, mut hi) = (0.0, speed_mps);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if covered(mid) > dist {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            v = lo;
        }
        let (_, tj, plateau) = phase(v);
        let cruise = ((dist - covered(v)) / v).max(0.0);
        let (mut vel, mut acc) = (0.0, 0.0);
        for (dur, j) in [
            (tj, s * jerk),
            (plateau, 0.0),
            (tj, -s * jerk),
            (cruise, 0.0),
            (tj, -s * jerk),
            (plateau, 0.0),
            (tj, s * jerk),
        ] {
            (vel, acc) = self.piece(dur, vel, acc, j);
        }
    }

    /// The finished profile.
    pub fn build(self) -> Profile {
        Profile {
            end_s: self.t_s,
            end_pos_m: self.pos_m,
            pieces: self.pieces,
        }
    }
}

impl Profile {
    /// Position, velocity and acceleration at `t_s` (held before the start and after the end).
    pub fn state(&self, t_s: f64) -> (f64, f64, f64) {
        if t_s >= self.end_s {
            return (self.end_pos_m, 0.0, 0.0);
        }
        let i = self.pieces.partition_point(|p| p.t0_s <= t_s);
        let Some(p) = i.checked_sub(1).and_then(|i| self.pieces.get(i)) else {
            return (self.start_pos_m(), 0.0, 0.0);
        };
        let d = t_s - p.t0_s;
        let j = p.jerk_mps3;
        (
            p.pos_m + p.vel_mps * d + p.acc_mps2 * d * d / 2.0 + j * d * d * d / 6.0,
            p.vel_mps + p.acc_mps2 * d + j * d * d / 2.0,
            p.acc_mps2 + j * d,
        )
    }

    /// Set-point position at `t_s`, m.
    pub fn pos_m(&self, t_s: f64) -> f64 {
        self.state(t_s).0
    }

    /// Where the profile starts, m.
    pub fn start_pos_m(&self) -> f64 {
        self.pieces.first().map_or(self.end_pos_m, |p| p.pos_m)
    }

    /// When the last move ends, s.
    pub fn end_s(&self) -> f64 {
        self.end_s
    }

    /// A constant-velocity ramp from `from_m` starting at `t_start_s`, lasting `dur_s`,
    /// with a velocity step (no acceleration limit): for following-error checks.
    pub fn ramp(from_m: f64, t_start_s: f64, vel_mps: f64, dur_s: f64) -> Profile {
        let mut b = ProfileBuilder::new(from_m);
        b.dwell(t_start_s);
        b.piece(dur_s, vel_mps, 0.0, 0.0);
        b.build()
    }

    /// An EMPS-like excitation of `duration_s`: long and medium moves, runs of short
    /// reversal strokes, slow creeping moves and dwells. See [`random_block`].
    pub fn random(dice: &mut Dice, duration_s: f64) -> Profile {
        let mut b = ProfileBuilder::new(mm_to_m(dice.between(8.0, 40.0)));
        b.dwell(dice.between(0.2, 0.5));
        let mut dir = 1.0;
        while b.time_s() < duration_s {
            random_block(dice, &mut b, &mut dir);
        }
        b.dwell(1.0);
        b.build()
    }
}

/// Travel the random moves stay within, mm (the EMPS stroke is 0…246 mm).
const TRAVEL_MM: (f64, f64) = (5.0, 245.0);

/// Appends one random block of moves:
/// - 40 %: a move of 5–100 mm at 20–150 mm/s;
/// - 20 %: 3–8 short reversal strokes of 0.5–5 mm at 5–60 mm/s;
/// - 15 %: a creeping move of 0.5–5 mm at 0.5–5 mm/s;
/// - 25 %: a reversal of 5–30 mm at 20–150 mm/s.
///
/// Accelerations 0.3–1.5 m/s², half bang-bang, half S-curve (jerk 5–60 m/s³); after each
/// move no dwell (40 %), 0.05–0.5 s (40 %) or 0.5–1.5 s.
fn random_block(dice: &mut Dice, b: &mut ProfileBuilder, dir: &mut f64) {
    let kind = dice.unit();
    let (strokes, len_mm, speed_mm_s, reverse) = if kind < 0.4 {
        (
            1,
            dice.between(5.0, 100.0),
            dice.between(20.0, 150.0),
            dice.chance(0.5),
        )
    } else if kind < 0.6 {
        (
            3 + dice.index(6),
            dice.between(0.5, 5.0),
            dice.between(5.0, 60.0),
            true,
        )
    } else if kind < 0.75 {
        (
            1,
            dice.between(0.5, 5.0),
            dice.between(0.5, 5.0),
            dice.chance(0.5),
        )
    } else {
        (1, dice.between(5.0, 30.0), dice.between(20.0, 150.0), true)
    };
    for _ in 0..strokes {
        if reverse {
            *dir = -*dir;
        }
        let here_mm = crate::units::m_to_mm(b.pos_m());
        let mut to_mm = here_mm + *dir * len_mm;
        if !(TRAVEL_MM.0..=TRAVEL_MM.1).contains(&to_mm) {
            *dir = -*dir;
            to_mm = (here_mm + *dir * len_mm).clamp(TRAVEL_MM.0, TRAVEL_MM.1);
        }
        let acc = dice.between(0.3, 1.5);
        let shape = if dice.chance(0.5) {
            Shape::BangBang
        } else {
            Shape::Jerk(dice.between(5.0, 60.0))
        };
        b.move_to(
            mm_to_m(to_mm),
            crate::units::mm_per_s_to_m_per_s(speed_mm_s),
            acc,
            shape,
        );
        let pause = dice.unit();
        if pause < 0.4 {
            continue;
        }
        b.dwell(if pause < 0.8 {
            dice.between(0.05, 0.5)
        } else {
            dice.between(0.5, 1.5)
        });
    }
}
