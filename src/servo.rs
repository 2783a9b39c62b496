//! The servo amplifier, run once per internal control period T3.
//!
//! Cascade: position P loop (+ velocity feed-forward) → velocity PI loop (+ torque
//! feed-forward slot) → torque limit → current loop as a first-order lag. Velocity feedback
//! always comes from the motor encoder; position feedback from the motor encoder
//! (semi-closed) or the linear scale (closed loop). Gains are load-side: force per velocity,
//! so the numbers do not change with the screw lead.

use nalgebra::DMatrix;

use crate::preset::{AxisParams, Coupling, Feedback};

#[derive(Debug, Clone)]
pub struct Servo {
    kp_per_s: f64,
    kv_n_s_per_m: f64,
    ki_per_s: f64,
    vff: f64,
    /// aff·M: feed-forward force per commanded acceleration.
    aff_mass_kg: f64,
    cur_alpha: f64,
    force_limit_n: f64,
    t3_s: f64,
    inv_t3: f64,
    avg2: bool,
    pub feedback: Feedback,
    pub integ_n: f64,
    pub force_cmd_n: f64,
    pub force_n: f64,
    pub vel_fb_mps: f64,
    pub ferr_m: f64,
    prev_cmd_m: f64,
    motor_hist_m: [f64; 2],
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

/// Converts between motor torque and load-side force for a screw of this lead.
pub fn force_per_torque(lead_m: f64) -> f64 {
    2.0 * std::f64::consts::PI / lead_m
}

impl Servo {
    pub fn new(a: &AxisParams, t3_s: f64, initial_pos_m: f64) -> Servo {
        let s = &a.servo;
        let lead_m = a.drive.lead_mm * 1e-3;
        Servo {
            kp_per_s: s.kp_per_s,
            kv_n_s_per_m: s.kv_n_s_per_m,
            ki_per_s: s.ki_per_s,
            vff: s.vff,
            aff_mass_kg: {
                let (m_m, m_t) = masses(a);
                s.aff * (m_m + m_t)
            },
            cur_alpha: current_alpha(s.current_lag_s, t3_s),
            force_limit_n: s.torque_limit_nm * force_per_torque(lead_m),
            t3_s,
            inv_t3: 1.0 / t3_s,
            avg2: s.vel_filter_avg2,
            feedback: s.feedback,
            integ_n: 0.0,
            force_cmd_n: 0.0,
            force_n: 0.0,
            vel_fb_mps: 0.0,
            ferr_m: 0.0,
            prev_cmd_m: initial_pos_m,
            motor_hist_m: [initial_pos_m; 2],
        }
    }

    /// Adopts new gains without resetting the loop state (live editing).
    pub fn retune(&mut self, a: &AxisParams) {
        let fresh = Servo::new(a, self.t3_s, 0.0);
        self.kp_per_s = fresh.kp_per_s;
        self.kv_n_s_per_m = fresh.kv_n_s_per_m;
        self.ki_per_s = fresh.ki_per_s;
        self.vff = fresh.vff;
        self.aff_mass_kg = fresh.aff_mass_kg;
        self.cur_alpha = fresh.cur_alpha;
        self.force_limit_n = fresh.force_limit_n;
        self.avg2 = fresh.avg2;
        self.feedback = fresh.feedback;
    }

    /// One T3 period. Returns the actual (current-loop) force on the load side.
    #[inline]
    pub fn step(&mut self, inp: &ServoInput) -> f64 {
        let t3 = self.t3_s;
        let vel_fb = if self.avg2 {
            (inp.motor_pos_m - self.motor_hist_m[1]) * (0.5 * self.inv_t3)
        } else {
            (inp.motor_pos_m - self.motor_hist_m[0]) * self.inv_t3
        };
        self.motor_hist_m = [inp.motor_pos_m, self.motor_hist_m[0]];
        let vel_ff = self.vff * (inp.ff_cmd_m - self.prev_cmd_m) * self.inv_t3;
        self.prev_cmd_m = inp.ff_cmd_m;
        self.ferr_m = inp.cmd_m - inp.fb_pos_m;
        let vel_cmd = self.kp_per_s * self.ferr_m + vel_ff + inp.vel_add_mps;
        let ev = vel_cmd - vel_fb;
        self.vel_fb_mps = vel_fb;
        let integ_new = self.integ_n + self.kv_n_s_per_m * self.ki_per_s * ev * t3;
        let raw = self.kv_n_s_per_m * ev
            + integ_new
            + inp.force_ff_n
            + self.aff_mass_kg * inp.acc_cmd_mps2;
        let lim = self.force_limit_n;
        let clamped = raw.clamp(-lim, lim);
        // Conditional integration: hold the integrator while the output is saturated in the
        // direction the integrator is pushing, so it does not wind up.
        if clamped == raw
            || (raw > lim && integ_new < self.integ_n)
            || (raw < -lim && integ_new > self.integ_n)
        {
            self.integ_n = integ_new;
        }
        self.force_cmd_n = clamped;
        self.force_n += self.cur_alpha * (clamped - self.force_n);
        self.force_n
    }
}

fn current_alpha(lag_s: f64, t3_s: f64) -> f64 {
    if lag_s > 0.0 {
        1.0 - (-t3_s / lag_s).exp()
    } else {
        1.0
    }
}

/// Number of plant sub-steps per T3 so that the coupling resonance is well resolved.
pub fn plant_substeps(a: &AxisParams, t3_s: f64) -> u32 {
    match a.drive.coupling {
        Coupling::Rigid => 1,
        Coupling::TwoMass {
            stiffness_n_per_um,
            damping_n_s_per_m,
        } => {
            let (m_m, m_t) = masses(a);
            let m_red = m_m * m_t / (m_m + m_t);
            let omega = (stiffness_n_per_um * 1e6 / m_red).sqrt();
            let by_k = (t3_s * omega / 0.3).ceil();
            let by_c = (t3_s * damping_n_s_per_m / m_red / 0.5).ceil();
            by_k.max(by_c).clamp(1.0, 64.0) as u32
        }
    }
}

/// Motor inertia reflected to the load side, and the table mass.
pub fn masses(a: &AxisParams) -> (f64, f64) {
    let lead_m = a.drive.lead_mm * 1e-3;
    let fpt = force_per_torque(lead_m);
    (
        a.drive.motor_inertia_kgm2 * fpt * fpt,
        a.drive.table_mass_kg,
    )
}

/// Builds the closed-loop transition matrix of one T3 period for the linear part of the axis
/// (no friction, backlash, quantization or limit) and checks that every pole is inside the
/// unit circle. The matrix uses the same update order and sub-stepping as the simulation.
pub fn check_stability(a: &AxisParams, t3_s: f64) -> Result<(), String> {
    let m = closed_loop_matrix(a, t3_s);
    let radius = m
        .complex_eigenvalues()
        .iter()
        .map(|z| z.norm())
        .fold(0.0_f64, f64::max);
    if radius.is_finite() && radius < 1.0 - 1e-9 {
        Ok(())
    } else {
        Err(format!(
            "the discrete closed loop at T3 = {t3_s} s is unstable: largest pole |z| = {radius:.4} ≥ 1 \
             (lower kp_per_s / kv_n_s_per_m / ki_per_s, or shorten T3)"
        ))
    }
}

/// State: [x_m, v_m, x_t, v_t, integ, force, motor_prev, motor_prev2], each scaled to a
/// displacement per T3 (velocities by T3, forces by T3²/M). The scaling is a similarity
/// transform, so the poles are unchanged, but it keeps the entries within a few decades of
/// each other: unscaled, forces of 1e6 N against positions of 1 m make the eigen-solver
/// report poles outside the unit circle for loops that are stable.
pub fn closed_loop_matrix(a: &AxisParams, t3_s: f64) -> DMatrix<f64> {
    const N: usize = 8;
    let s = &a.servo;
    let (m_m, m_t) = masses(a);
    let alpha = current_alpha(s.current_lag_s, t3_s);
    let n_sub = plant_substeps(a, t3_s);
    let h = t3_s / n_sub as f64;
    let step = |x: &[f64; N]| -> [f64; N] {
        let [mut xm, mut vm, mut xt, mut vt, integ, force, prev, prev2] = *x;
        let vel_fb = if s.vel_filter_avg2 {
            (xm - prev2) / (2.0 * t3_s)
        } else {
            (xm - prev) / t3_s
        };
        let fb = match s.feedback {
            Feedback::Motor => xm,
            Feedback::Scale => xt,
        };
        let ev = s.kp_per_s * (0.0 - fb) - vel_fb;
        // With ki = 0 the integrator is not part of the loop; keep it out of the spectrum.
        let integ2 = if s.ki_per_s > 0.0 {
            integ + s.kv_n_s_per_m * s.ki_per_s * ev * t3_s
        } else {
            0.0
        };
        let fcmd = s.kv_n_s_per_m * ev + integ2;
        let force2 = force + alpha * (fcmd - force);
        let (new_prev, new_prev2) = (xm, prev);
        match a.drive.coupling {
            Coupling::Rigid => {
                vm += h * force2 / (m_m + m_t) * n_sub as f64;
                xm += t3_s * vm;
                xt = xm;
                vt = vm;
            }
            Coupling::TwoMass {
                stiffness_n_per_um,
                damping_n_s_per_m,
            } => {
                let k = stiffness_n_per_um * 1e6;
                for _ in 0..n_sub {
                    let fs = k * (xm - xt) + damping_n_s_per_m * (vm - vt);
                    vm += h * (force2 - fs) / m_m;
                    vt += h * fs / m_t;
                    xm += h * vm;
                    xt += h * vt;
                }
            }
        }
        [xm, vm, xt, vt, integ2, force2, new_prev, new_prev2]
    };
    let f_scale = (m_m + m_t) / (t3_s * t3_s);
    let scale = [1.0, 1.0 / t3_s, 1.0, 1.0 / t3_s, f_scale, f_scale, 1.0, 1.0];
    let mut mat = DMatrix::<f64>::zeros(N, N);
    for j in 0..N {
        let mut e = [0.0; N];
        e[j] = scale[j];
        let col = step(&e);
        for i in 0..N {
            mat[(i, j)] = col[i] / scale[i];
        }
    }
    mat
}
