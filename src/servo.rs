//! The servo amplifier's control law, run once per internal control period T3.
//!
//! Cascade: position P loop (+ velocity feed-forward) → velocity PI loop (+ torque
//! feed-forward) → torque limit → current loop as a first-order lag. Gains are load-side
//! (force per velocity), so the numbers do not change with the screw lead.
//!
//! This module is only the control law: it reads feedback and commands and returns a force.
//! Which sensor feeds it, the mechanics it drives and the order of the two live in
//! [`crate::drive::AxisLoop`], the one place an axis's T3 step is written.

use crate::preset::{AxisParams, Feedback};

/// The amplifier's constants, derived once from the preset (and again on a live edit).
#[derive(Debug, Clone, Copy)]
struct Gains {
    kp_per_s: f64,
    kv_n_s_per_m: f64,
    /// kv·ki·T3: integrator increment per velocity error.
    integ_gain_n_per_mps: f64,
    /// kv + kv·ki·T3: the velocity error's whole effect on the force command this period.
    kv_total_n_s_per_m: f64,
    /// vff / T3: velocity feed-forward per commanded travel this period.
    vff_per_s: f64,
    /// aff·M: feed-forward force per commanded acceleration.
    aff_mass_kg: f64,
    /// Current-loop step factor 1 − e^(−T3/τ), and 1 minus it.
    cur_alpha: f64,
    cur_keep: f64,
    /// kp + velocity scale: the velocity error's dependence on the encoder when the position
    /// loop closes on the motor encoder too (one sensor, one product).
    k_enc_per_s: f64,
    /// The force command's dependence on the encoder then: (kv + kv·ki·T3)·(kp + vs).
    kv_k_enc_n_per_m: f64,
    force_limit_n: f64,
    /// 1/T3 or 1/(2·T3): velocity from the encoder difference.
    vel_scale_per_s: f64,
    avg2: bool,
}

impl Gains {
    fn new(a: &AxisParams, t3_s: f64) -> Gains {
        let s = &a.servo;
        let integ = s.kv_n_s_per_m * s.ki_per_s * t3_s;
        Gains {
            kp_per_s: s.kp_per_s,
            kv_n_s_per_m: s.kv_n_s_per_m,
            integ_gain_n_per_mps: integ,
            kv_total_n_s_per_m: s.kv_n_s_per_m + integ,
            vff_per_s: s.vff / t3_s,
            aff_mass_kg: s.aff * a.drive.total_mass_kg(),
            cur_alpha: current_alpha(s.current_lag_s, t3_s),
            cur_keep: 1.0 - current_alpha(s.current_lag_s, t3_s),
            k_enc_per_s: s.kp_per_s
                + if s.vel_filter_avg2 {
                    0.5 / t3_s
                } else {
                    1.0 / t3_s
                },
            force_limit_n: s.torque_limit_nm * a.drive.force_per_torque(),
            vel_scale_per_s: if s.vel_filter_avg2 {
                0.5 / t3_s
            } else {
                1.0 / t3_s
            },
            avg2: s.vel_filter_avg2,
            kv_k_enc_n_per_m: 0.0,
        }
        .with_products()
    }

    fn with_products(mut self) -> Gains {
        self.kv_k_enc_n_per_m = self.kv_total_n_s_per_m * self.k_enc_per_s;
        self
    }
}

/// Everything the amplifier remembers from one period to the next.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ServoState {
    /// Velocity-loop integrator, N.
    pub integ_n: f64,
    /// Current-loop output: the force the motor really produces, N.
    pub force_n: f64,
    /// The previous feed-forward command, m.
    pub prev_ff_cmd_m: f64,
    /// The last two motor-encoder readings (newest first), m.
    pub motor_hist_m: [f64; 2],
}

/// What the amplifier reads in one T3 period.
#[derive(Debug, Clone, Copy, Default)]
pub struct ServoInput {
    /// Position command after all position compensations.
    pub cmd_m: f64,
    /// The interpolated command before machine-error corrections: the feed-forwards follow
    /// it, so correction pulses (a lump backlash step) go to the position loop only.
    pub ff_cmd_m: f64,
    /// Position feedback (motor encoder or scale, already quantized).
    pub fb_pos_m: f64,
    /// Motor encoder position in load travel (quantized), for the velocity loop.
    pub motor_pos_m: f64,
    /// Velocity-command addition from a servo-stage compensation.
    pub vel_add_mps: f64,
    /// Force feed-forward from a servo-stage compensation (torque converted to load side).
    pub force_ff_n: f64,
    /// Commanded acceleration for the acceleration feed-forward.
    pub acc_cmd_mps2: f64,
}

/// What the amplifier did in one period, for the trace.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ServoOutput {
    /// Force command after the limit, before the current loop, N.
    pub force_cmd_n: f64,
    /// Force the current loop delivers this period, N.
    pub force_n: f64,
    /// Position-loop error (command − feedback), m.
    pub ferr_m: f64,
    /// Velocity feedback, m/s.
    pub vel_fb_mps: f64,
}

impl ServoOutput {
    /// `*dst = *self`, one field at a time (see [`crate::plant::PlantOut::store`]).
    #[inline(always)]
    pub fn store(&self, dst: &mut ServoOutput) {
        dst.force_cmd_n = self.force_cmd_n;
        dst.force_n = self.force_n;
        dst.ferr_m = self.ferr_m;
        dst.vel_fb_mps = self.vel_fb_mps;
    }
}

/// One axis's amplifier.
#[derive(Debug, Clone)]
pub struct Servo {
    g: Gains,
    t3_s: f64,
    /// Which sensor closes the position loop.
    feedback: Feedback,
    state: ServoState,
    out: ServoOutput,
}

impl Servo {
    /// An amplifier at rest: integrator and current zero, the encoder history at
    /// `motor_enc_m` and the feed-forward command at `ff_cmd_m`, so that the first period
    /// sees no velocity.
    pub fn new(a: &AxisParams, t3_s: f64, ff_cmd_m: f64, motor_enc_m: f64) -> Servo {
        Servo {
            g: Gains::new(a, t3_s),
            t3_s,
            feedback: a.servo.feedback,
            state: ServoState {
                integ_n: 0.0,
                force_n: 0.0,
                prev_ff_cmd_m: ff_cmd_m,
                motor_hist_m: [motor_enc_m; 2],
            },
            out: ServoOutput::default(),
        }
    }

    /// Adopts new gains without resetting the loop state (live editing).
    pub fn retune(&mut self, a: &AxisParams) {
        self.g = Gains::new(a, self.t3_s);
        self.feedback = a.servo.feedback;
    }

    /// Which sensor closes the position loop.
    pub fn feedback(&self) -> Feedback {
        self.feedback
    }

    /// The loop state (for the linearisation in [`crate::drive`]).
    pub fn state(&self) -> ServoState {
        self.state
    }

    /// Replaces the loop state (the linearisation perturbs it one entry at a time).
    pub fn set_state(&mut self, s: ServoState) {
        self.state = s;
    }

    /// What the amplifier did in the latest period.
    pub fn output(&self) -> &ServoOutput {
        &self.out
    }

    /// One T3 period. Returns the actual (current-loop) force on the load side.
    ///
    /// The velocity error is ev = kp·(cmd − fb) + vel_ff − (enc − older)·vs. Everything but
    /// this period's sensor readings is known a period ahead, so it is summed first and the
    /// readings enter last: the feedback → force path, which every period of the loop waits
    /// on, is one product and one sum long.
    #[inline(always)]
    pub fn step(&mut self, inp: &ServoInput) -> f64 {
        let g = &self.g;
        let st = &mut self.state;
        let older = if g.avg2 {
            st.motor_hist_m[1]
        } else {
            st.motor_hist_m[0]
        };
        let enc = inp.motor_pos_m;
        st.motor_hist_m = [enc, st.motor_hist_m[0]];
        let vel_ff = g.vff_per_s * (inp.ff_cmd_m - st.prev_ff_cmd_m);
        st.prev_ff_cmd_m = inp.ff_cmd_m;
        let ahead =
            g.kp_per_s * inp.cmd_m + (g.vel_scale_per_s * older + (vel_ff + inp.vel_add_mps));
        let base_n = g.aff_mass_kg * inp.acc_cmd_mps2 + (st.integ_n + inp.force_ff_n);
        let early_n = g.kv_total_n_s_per_m * ahead + base_n;
        let (ev, raw) = if self.feedback == Feedback::Motor {
            (
                ahead - g.k_enc_per_s * enc,
                early_n - g.kv_k_enc_n_per_m * enc,
            )
        } else {
            let from_sensors = g.kp_per_s * inp.fb_pos_m + g.vel_scale_per_s * enc;
            (
                ahead - from_sensors,
                early_n - g.kv_total_n_s_per_m * from_sensors,
            )
        };
        let integ_new = st.integ_n + g.integ_gain_n_per_mps * ev;
        let lim = g.force_limit_n;
        // Inside the limit (nearly always) the command goes on as it is, behind a branch the
        // CPU predicts, so the limit is not on the loop's critical path. `saturate` gives the
        // same value for any command; it only runs when the limit bites.
        let clamped = if raw.abs() <= lim {
            st.integ_n = integ_new;
            raw
        } else {
            let (clamped, integ) = saturate(raw, lim, integ_new, st.integ_n);
            st.integ_n = integ;
            clamped
        };
        st.force_n = g.cur_keep * st.force_n + g.cur_alpha * clamped;
        self.out = ServoOutput {
            force_cmd_n: clamped,
            force_n: st.force_n,
            ferr_m: inp.cmd_m - inp.fb_pos_m,
            vel_fb_mps: (enc - older) * g.vel_scale_per_s,
        };
        st.force_n
    }

    /// The P-only velocity loop ignores its integrator; the linearisation leaves it out of
    /// the spectrum so that a pole at exactly 1 does not read as unstable.
    pub fn has_integrator(&self) -> bool {
        self.g.integ_gain_n_per_mps > 0.0
    }

    /// kv, for the trace's velocity-loop figures.
    pub fn kv_n_s_per_m(&self) -> f64 {
        self.g.kv_n_s_per_m
    }
}

/// The force limit and the conditional integration: the integrator is held while the output
/// is saturated in the direction the integrator is pushing, so it does not wind up. Returns
/// (clamped command, integrator). Values in and out, no pointer into the servo's state: see
/// `AxisPlant::step_with` on calls inside the T3 loop.
#[cold]
#[inline(never)]
fn saturate(raw_n: f64, lim_n: f64, integ_new_n: f64, integ_n: f64) -> (f64, f64) {
    let clamped = raw_n.clamp(-lim_n, lim_n);
    if clamped == raw_n
        || (raw_n > lim_n && integ_new_n < integ_n)
        || (raw_n < -lim_n && integ_new_n > integ_n)
    {
        (clamped, integ_new_n)
    } else {
        (clamped, integ_n)
    }
}

fn current_alpha(lag_s: f64, t3_s: f64) -> f64 {
    if lag_s > 0.0 {
        1.0 - (-t3_s / lag_s).exp()
    } else {
        1.0
    }
}
