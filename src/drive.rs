//! One feed axis's T3 step: servo-stage compensations → amplifier → mechanics.
//!
//! [`AxisLoop::step`] is the only place this step is written. The machine calls it for every
//! axis every T3; the diagnosis replays measured commands through it; the stability check
//! linearises it ([`closed_loop_matrix`]). A change to the order, the feedback or a sensor
//! therefore reaches all three at once.
//!
//! The amplifier's acceleration feed-forward takes one acceleration per T2 segment of the
//! raw command ([`SegmentAcc`]); the machine and the replay both feed it from the same type.

use nalgebra::DMatrix;

use crate::comp::{ServoComp, ServoCompCtx, ServoCompOut};
use crate::plant::{AxisPlant, MechState, PlantOut, Sensor, Start};
use crate::preset::{AxisParams, Coupling, Feedback};
use crate::servo::{Servo, ServoInput, ServoOutput};

/// What one axis's loop reads from the NC in one T3 period.
#[derive(Debug, Clone, Copy, Default)]
pub struct LoopInput {
    /// Time at the start of the period, s.
    pub t_s: f64,
    /// The program's command before machine-error corrections, m; the feed-forwards follow it.
    pub cmd_raw_m: f64,
    /// The command after the NC's position compensations, m.
    pub cmd_nc_m: f64,
    /// Commanded acceleration of the current T2 segment, m/s².
    pub acc_cmd_mps2: f64,
    /// External force on the table, N (a disturbance the diagnosis fits; 0 on the machine).
    pub ext_force_n: f64,
}

/// A run of consecutive loop inputs, read one period at a time by [`AxisLoop::run`] and
/// [`AxisLoop::run_quiet`]. The machine's T2 block is one ([`T2Block`]): it is read straight
/// from the NC's command buffers, so no array of inputs is written and read back.
pub trait LoopInputs {
    /// Number of periods.
    fn periods(&self) -> usize;
    /// The input of period `j` (< [`LoopInputs::periods`]).
    fn at(&self, j: usize) -> LoopInput;
}

impl LoopInputs for [LoopInput] {
    #[inline(always)]
    fn periods(&self) -> usize {
        self.len()
    }
    #[inline(always)]
    fn at(&self, j: usize) -> LoopInput {
        self[j]
    }
}

/// A run of T2 periods of a machine axis, as the NC generated them: the interpolated
/// command rows and each period's segment acceleration, no external force.
pub struct T2Block<'a> {
    /// Index of the block's first T3 period since the start.
    pub k0: u64,
    /// T3 period, s: period `j` starts at (k0 + j)·T3.
    pub t3_s: f64,
    /// Raw command per period, m.
    pub cmd_raw_m: &'a [f64],
    /// Compensated command per period, m (as long as `cmd_raw_m`).
    pub cmd_nc_m: &'a [f64],
    /// Commanded acceleration of the T2 segment each period lies in, m/s² (as long as
    /// `cmd_raw_m`).
    pub acc_cmd_mps2: &'a [f64],
}

impl LoopInputs for T2Block<'_> {
    #[inline(always)]
    fn periods(&self) -> usize {
        self.cmd_raw_m
            .len()
            .min(self.cmd_nc_m.len())
            .min(self.acc_cmd_mps2.len())
    }
    #[inline(always)]
    fn at(&self, j: usize) -> LoopInput {
        LoopInput {
            t_s: (self.k0 + j as u64) as f64 * self.t3_s,
            cmd_raw_m: self.cmd_raw_m[j],
            cmd_nc_m: self.cmd_nc_m[j],
            acc_cmd_mps2: self.acc_cmd_mps2[j],
            ext_force_n: 0.0,
        }
    }
}

/// One trace row of an axis: the plant as the sensors saw it at the start of the period, and
/// what the amplifier did during it.
#[derive(Debug, Clone, Copy, Default)]
pub struct Sample {
    /// Plant outputs at the start of the period; `friction_n` is the friction over it.
    pub plant: PlantOut,
    /// The program's command, m.
    pub cmd_raw_m: f64,
    /// The command after the NC's position compensations, m.
    pub cmd_nc_m: f64,
    /// The command the position loop saw (after every compensation), m.
    pub cmd_m: f64,
    /// The amplifier's output.
    pub servo: ServoOutput,
    /// What the servo-stage compensations added.
    pub servo_add: ServoCompOut,
}

/// One axis: its amplifier, its mechanics and the servo-stage compensations acting on it.
pub struct AxisLoop {
    servo: Servo,
    plant: AxisPlant,
    comps: Vec<Box<dyn ServoComp>>,
    t3_s: f64,
    /// Load-side force per motor torque, 2π/lead.
    f_per_t: f64,
    prev_cmd_nc_m: f64,
    sample: Sample,
}

impl AxisLoop {
    /// An axis at rest at `start`, its command at `cmd_raw_m` (raw) and `cmd_nc_m`
    /// (compensated), with the servo-stage compensations `comps`.
    pub fn new(
        a: &AxisParams,
        t3_s: f64,
        start: Start,
        cmd_raw_m: f64,
        cmd_nc_m: f64,
        comps: Vec<Box<dyn ServoComp>>,
    ) -> AxisLoop {
        let plant = AxisPlant::new(a, t3_s, start);
        let servo = Servo::new(a, t3_s, cmd_raw_m, plant.out().motor_enc_m);
        let mut l = AxisLoop {
            servo,
            plant,
            comps,
            t3_s,
            f_per_t: a.drive.force_per_torque(),
            prev_cmd_nc_m: cmd_nc_m,
            sample: Sample::default(),
        };
        l.sample = Sample {
            plant: *l.plant.out(),
            cmd_raw_m,
            cmd_nc_m,
            cmd_m: cmd_nc_m,
            servo: ServoOutput::default(),
            servo_add: ServoCompOut::default(),
        };
        l
    }

    /// Puts the axis at rest at `start` again (power-up placement), keeping its
    /// compensations.
    pub fn restart(&mut self, a: &AxisParams, start: Start, cmd_raw_m: f64, cmd_nc_m: f64) {
        let comps = std::mem::take(&mut self.comps);
        *self = AxisLoop::new(a, self.t3_s, start, cmd_raw_m, cmd_nc_m, comps);
    }

    /// Takes new parameters, keeping every state (live editing).
    pub fn retune(&mut self, a: &AxisParams) {
        self.servo.retune(a);
        self.plant.retune(a);
        self.f_per_t = a.drive.force_per_torque();
    }

    /// The position feedback the amplifier closes its loop on, m.
    #[inline]
    pub fn feedback_m(&self) -> f64 {
        feedback_of(self.servo.feedback(), self.plant.out())
    }

    /// One T3 period. Returns the force the motor put on the load.
    #[inline]
    pub fn step(&mut self, inp: &LoopInput) -> f64 {
        if self.is_plain() {
            self.step_inline::<false, true>(inp)
        } else {
            self.step_inline::<true, true>(inp)
        }
    }

    /// No servo-stage compensation and a plain plant ([`AxisPlant::is_plain`]): the step
    /// may leave the rarely used effects out of its code.
    fn is_plain(&self) -> bool {
        self.comps.is_empty() && self.plant.is_plain()
    }

    /// The T3 step itself: servo-stage compensations, amplifier, mechanics. `FULL` false
    /// compiles the step for a plain axis ([`AxisLoop::is_plain`]); it computes the same
    /// numbers, with less code in the loop. `SAMPLE` false leaves the trace row
    /// ([`AxisLoop::sample`]) as it was: a period nobody reads the row of
    /// ([`AxisLoop::run_quiet`]).
    #[inline(always)]
    fn step_inline<const FULL: bool, const SAMPLE: bool>(&mut self, inp: &LoopInput) -> f64 {
        // Only the two readings the loop needs, not a copy of the whole output struct:
        // that copy is one wide load of fields stored one by one at the end of the previous
        // period, which the store buffer cannot forward (a stall of ~25 % of the step).
        let o = self.plant.out();
        let (enc_m, fb) = (o.motor_enc_m, feedback_of(self.servo.feedback(), o));
        let mut add = ServoCompOut::default();
        if FULL && !self.comps.is_empty() {
            let ctx = ServoCompCtx {
                t_s: inp.t_s,
                t3_s: self.t3_s,
                cmd_m: inp.cmd_nc_m,
                prev_cmd_m: self.prev_cmd_nc_m,
                fb_m: fb,
            };
            for c in &mut self.comps {
                let mut one = ServoCompOut::default();
                c.step(&ctx, &mut one);
                add.pos_m += one.pos_m;
                add.vel_mps += one.vel_mps;
                add.torque_nm += one.torque_nm;
            }
        }
        self.prev_cmd_nc_m = inp.cmd_nc_m;
        let cmd_m = inp.cmd_nc_m + add.pos_m;
        let force = self.servo.step(&ServoInput {
            cmd_m,
            ff_cmd_m: inp.cmd_raw_m,
            fb_pos_m: fb,
            motor_pos_m: enc_m,
            vel_add_mps: add.vel_mps,
            force_ff_n: add.torque_nm * self.f_per_t,
            acc_cmd_mps2: inp.acc_cmd_mps2,
        });
        if !SAMPLE {
            self.plant.step_with::<FULL>(force, inp.ext_force_n);
            return force;
        }
        // The row shows the plant as the sensors saw it at the start of the period.
        self.plant.out().store(&mut self.sample.plant);
        self.plant.step_with::<FULL>(force, inp.ext_force_n);
        let s = &mut self.sample;
        s.plant.friction_n = self.plant.out().friction_n;
        s.cmd_raw_m = inp.cmd_raw_m;
        s.cmd_nc_m = inp.cmd_nc_m;
        s.cmd_m = cmd_m;
        self.servo.output().store(&mut s.servo);
        s.servo_add.pos_m = add.pos_m;
        s.servo_add.vel_mps = add.vel_mps;
        s.servo_add.torque_nm = add.torque_nm;
        force
    }

    /// Runs one period per input, handing the loop to `sink` after each period (its trace
    /// row is [`AxisLoop::sample`]). The same step as [`AxisLoop::step`], in a loop the
    /// compiler can keep the loop's state in registers for, with the plain/full choice made
    /// once: the machine runs each axis through its T2 period this way.
    #[inline]
    pub fn run<I: LoopInputs + ?Sized>(&mut self, inputs: &I, sink: impl FnMut(usize, &AxisLoop)) {
        if self.is_plain() {
            self.run_with::<false, I>(inputs, sink);
        } else {
            self.run_with::<true, I>(inputs, sink);
        }
    }

    #[inline(always)]
    fn run_with<const FULL: bool, I: LoopInputs + ?Sized>(
        &mut self,
        inputs: &I,
        mut sink: impl FnMut(usize, &AxisLoop),
    ) {
        for j in 0..inputs.periods() {
            self.step_inline::<FULL, true>(&inputs.at(j));
            sink(j, self);
        }
    }

    /// [`AxisLoop::run`] when only the last period's row is read (the machine with its
    /// recording off): the same steps, the row written once at the end. Writing a row
    /// nobody reads is a fifth of the T3 step's stores.
    #[inline]
    pub fn run_quiet<I: LoopInputs + ?Sized>(&mut self, inputs: &I) {
        self.run_quiet_inlined(inputs);
    }

    /// [`AxisLoop::run_quiet`], always compiled into its caller: the machine's T2 block,
    /// whose few periods do not pay for a call (left to the compiler, the call stayed in
    /// and cost 4 % of the machine's instructions).
    #[inline(always)]
    pub(crate) fn run_quiet_inlined<I: LoopInputs + ?Sized>(&mut self, inputs: &I) {
        if self.is_plain() {
            self.run_quiet_with::<false, I>(inputs);
        } else {
            self.run_quiet_with::<true, I>(inputs);
        }
    }

    #[inline(always)]
    fn run_quiet_with<const FULL: bool, I: LoopInputs + ?Sized>(&mut self, inputs: &I) {
        let Some(last) = inputs.periods().checked_sub(1) else {
            return;
        };
        for j in 0..last {
            self.step_inline::<FULL, false>(&inputs.at(j));
        }
        self.step_inline::<FULL, true>(&inputs.at(last));
    }

    /// The trace row of the latest period.
    pub fn sample(&self) -> &Sample {
        &self.sample
    }

    /// The mechanics (read only: only [`AxisLoop::step`] moves them).
    pub fn plant(&self) -> &AxisPlant {
        &self.plant
    }

    /// The amplifier (read only).
    pub fn servo(&self) -> &Servo {
        &self.servo
    }

    /// Load-side force per motor torque.
    pub fn force_per_torque(&self) -> f64 {
        self.f_per_t
    }

    /// The servo-stage compensations of this axis.
    pub fn comps(&self) -> &[Box<dyn ServoComp>] {
        &self.comps
    }

    /// The servo-stage compensations, for a live edit of their parameters.
    pub fn comps_mut(&mut self) -> &mut [Box<dyn ServoComp>] {
        &mut self.comps
    }

    /// Replaces the servo-stage compensations (they start from their power-up state).
    pub fn set_comps(&mut self, comps: Vec<Box<dyn ServoComp>>) {
        self.comps = comps;
    }

    /// The loop's linear state, for [`closed_loop_matrix`].
    fn linear_state(&self) -> [f64; N_STATE] {
        let m = self.plant.mech_state();
        let s = self.servo.state();
        [
            m.x_m,
            m.v_m,
            m.x_t,
            m.v_t,
            s.integ_n,
            s.force_n,
            s.motor_hist_m[0],
            s.motor_hist_m[1],
        ]
    }

    fn set_linear_state(&mut self, x: &[f64; N_STATE]) {
        self.plant.set_mech_state(MechState {
            x_m: x[0],
            v_m: x[1],
            x_t: x[2],
            v_t: x[3],
        });
        let mut s = self.servo.state();
        s.integ_n = x[4];
        s.force_n = x[5];
        s.motor_hist_m = [x[6], x[7]];
        self.servo.set_state(s);
    }
}

#[inline]
fn feedback_of(f: Feedback, o: &PlantOut) -> f64 {
    match f {
        Feedback::Motor => o.motor_enc_m,
        Feedback::Scale => o.scale_m,
    }
}

/// The commanded acceleration the amplifier feeds forward: one value per T2 segment of the
/// raw command. Inside a segment the command is a straight line (the amplifier subdivides
/// it), so a per-T3 second difference would be a train of spikes at the segment joints.
#[derive(Debug, Clone, Copy)]
pub struct SegmentAcc {
    inv_t2_per_s: f64,
    prev_end_m: f64,
    seg_vel_mps: f64,
    acc_mps2: f64,
}

impl SegmentAcc {
    /// Before the first segment, at rest at `start_m`.
    pub fn new(t2_s: f64, start_m: f64) -> SegmentAcc {
        SegmentAcc {
            inv_t2_per_s: 1.0 / t2_s,
            prev_end_m: start_m,
            seg_vel_mps: 0.0,
            acc_mps2: 0.0,
        }
    }

    /// Before the first segment, moving through `start_m` at `vel_mps` (a record that starts
    /// mid-motion).
    pub fn moving(t2_s: f64, start_m: f64, vel_mps: f64) -> SegmentAcc {
        SegmentAcc {
            seg_vel_mps: vel_mps,
            ..SegmentAcc::new(t2_s, start_m)
        }
    }

    /// Starts the next T2 segment, which ends at `end_m`; returns its acceleration.
    #[inline]
    pub fn next_segment(&mut self, end_m: f64) -> f64 {
        let v = (end_m - self.prev_end_m) * self.inv_t2_per_s;
        self.acc_mps2 = (v - self.seg_vel_mps) * self.inv_t2_per_s;
        self.seg_vel_mps = v;
        self.prev_end_m = end_m;
        self.acc_mps2
    }

    /// The acceleration of the current segment.
    #[inline]
    pub fn acc_mps2(&self) -> f64 {
        self.acc_mps2
    }

    /// Where the current segment ends (the latest command handed to the amplifier), m.
    #[inline]
    pub fn end_m(&self) -> f64 {
        self.prev_end_m
    }
}

/// States of the linearised loop: motor x, v; table x, v; integrator; current-loop force;
/// the two encoder readings the velocity loop remembers.
const N_STATE: usize = 8;

/// The axis without its nonlinear effects (friction, play, gravity, quantization, torque
/// limit, thermal growth, lead error): what remains is linear, so one step of it is a
/// matrix.
fn linear_part(a: &AxisParams) -> AxisParams {
    let mut l = a.clone();
    l.friction.enabled = false;
    l.friction.stribeck.enabled = false;
    l.friction.stroke.enabled = false;
    l.lost_motion.enabled = false;
    l.gravity.enabled = false;
    l.encoder.quantize_motor = false;
    l.encoder.quantize_scale = false;
    l.screw_thermal.enabled = false;
    l.lead_error.enabled = false;
    l.servo.torque_limit_nm = f64::INFINITY;
    // A hardening payload mount, at rest: its tangent stiffness there is the linear one
    // (the matrix is stepped from unit states, where the cubic term would dominate).
    if let Coupling::Payload {
        hardening_deflection_um,
        ..
    } = &mut l.drive.coupling
    {
        *hardening_deflection_um = 0.0;
    }
    l
}

/// The transition matrix of one T3 period of the axis loop's linear part, obtained by
/// stepping [`AxisLoop::step`] itself from unit states with the command held at zero.
///
/// Each state is scaled to a displacement per T3 (velocities by T3, forces by T3²/M). The
/// scaling is a similarity transform, so the poles are unchanged, but it keeps the entries
/// within a few decades of each other: unscaled, forces of 1e6 N against positions of 1 m make
/// the eigen-solver report poles outside the unit circle for loops that are stable.
pub fn closed_loop_matrix(a: &AxisParams, t3_s: f64) -> DMatrix<f64> {
    matrix_of(&linear_part(a), t3_s)
}

/// The axis while the motor crosses the backlash gap: the table is left behind, so the
/// loop drives the motor's own inertia alone. A motor far lighter than the table can make
/// this loop unstable while the coupled one is stable; the machine then diverges in the
/// first reversal, so the check must see it. `None` when nothing separates motor and table.
fn in_gap_part(a: &AxisParams) -> Option<AxisParams> {
    if !a.lost_motion.enabled {
        return None;
    }
    Some(motor_alone(a))
}

/// The linear part of `a` with the table taken away: the motor's inertia alone.
fn motor_alone(a: &AxisParams) -> AxisParams {
    let mut l = linear_part(a);
    l.drive.coupling = Coupling::Rigid;
    l.drive.table_mass_kg = 0.0;
    l
}

/// The transition matrix of one T3 period of the linear axis `lin`, from unit states.
fn matrix_of(lin: &AxisParams, t3_s: f64) -> DMatrix<f64> {
    let lin = lin.clone();
    let proto = AxisLoop::new(
        &lin,
        t3_s,
        Start::at_rest(Sensor::MotorEncoder, 0.0),
        0.0,
        0.0,
        vec![],
    );
    let f_scale = lin.drive.total_mass_kg() / (t3_s * t3_s);
    let scale = [1.0, 1.0 / t3_s, 1.0, 1.0 / t3_s, f_scale, f_scale, 1.0, 1.0];
    // Without an integral action the integrator is a constant that never moves: a pole at
    // exactly 1 that says nothing about stability. Leave it out.
    let states: Vec<usize> = (0..N_STATE)
        .filter(|&i| i != 4 || proto.servo.has_integrator())
        .collect();
    let n = states.len();
    let mut mat = DMatrix::<f64>::zeros(n, n);
    for (col, &j) in states.iter().enumerate() {
        let mut l = AxisLoop::new(
            &lin,
            t3_s,
            Start::at_rest(Sensor::MotorEncoder, 0.0),
            0.0,
            0.0,
            vec![],
        );
        let mut x = [0.0; N_STATE];
        x[j] = scale[j];
        l.set_linear_state(&x);
        l.step(&LoopInput::default());
        let y = l.linear_state();
        for (row, &i) in states.iter().enumerate() {
            mat[(row, col)] = y[i] / scale[i];
        }
    }
    mat
}

/// Iterations the eigenvalue solver may take before the check gives up with an error.
const EIGEN_MAX_ITER: usize = 10_000;

/// The largest pole magnitude |z| of the axis loop's linear part at T3 = `t3_s`.
///
/// With backlash on, this is the larger of the coupled loop's radius and the radius of the
/// loop on the motor alone, as it runs while crossing the gap.
pub fn spectral_radius(a: &AxisParams, t3_s: f64) -> Result<f64, String> {
    let coupled = radius_of(closed_loop_matrix(a, t3_s), t3_s)?;
    match in_gap_part(a) {
        Some(gap) => Ok(coupled.max(radius_of(matrix_of(&gap, t3_s), t3_s)?)),
        None => Ok(coupled),
    }
}

fn radius_of(m: DMatrix<f64>, t3_s: f64) -> Result<f64, String> {
    Ok(poles_of(m, t3_s)?
        .iter()
        .map(|z| z.norm())
        .fold(0.0_f64, f64::max))
}

/// The poles (eigenvalues) of a transition matrix.
fn poles_of(
    m: DMatrix<f64>,
    t3_s: f64,
) -> Result<nalgebra::DVector<nalgebra::Complex<f64>>, String> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err(format!(
            "the closed loop at T3 = {t3_s} s has a non-finite transition matrix; \
             a gain, mass or lead is out of any physical range"
        ));
    }
    let schur =
        nalgebra::linalg::Schur::try_new(m, f64::EPSILON, EIGEN_MAX_ITER).ok_or_else(|| {
            format!(
                "the pole calculation did not converge in {EIGEN_MAX_ITER} iterations at \
                 T3 = {t3_s} s; the gains are out of any physical range"
            )
        })?;
    Ok(schur.complex_eigenvalues())
}

/// The least damped mode of the loop on the motor alone (the table left behind, as while
/// crossing a backlash gap), whether or not the preset has backlash on: (|z|, frequency in
/// Hz). A loop near |z| = 1 here is one that play can make hunt: each impact on a flank
/// kicks a mode that hardly decays before the next. The diagnosis uses it to tell play
/// from other causes of a steady tone in the force.
pub fn motor_alone_mode(a: &AxisParams, t3_s: f64) -> Result<(f64, f64), String> {
    let poles = poles_of(matrix_of(&motor_alone(a), t3_s), t3_s)?;
    let z = poles
        .iter()
        .max_by(|a, b| a.norm().total_cmp(&b.norm()))
        .copied()
        .unwrap_or_default();
    Ok((z.norm(), z.arg().abs() / (std::f64::consts::TAU * t3_s)))
}

/// Checks that every pole of the axis loop's linear part lies inside the unit circle, for
/// the coupled axis and, with backlash on, for the motor alone in the gap.
pub fn check_stability(a: &AxisParams, t3_s: f64) -> Result<(), String> {
    let stable = |r: f64| r.is_finite() && r < 1.0 - 1e-9;
    let radius = radius_of(closed_loop_matrix(a, t3_s), t3_s)?;
    if !stable(radius) {
        return Err(format!(
            "the discrete closed loop at T3 = {t3_s} s is unstable: largest pole |z| = {radius:.4} ≥ 1 \
             (lower kp_per_s / kv_n_s_per_m / ki_per_s, or shorten T3)"
        ));
    }
    if let Some(gap) = in_gap_part(a) {
        let radius = radius_of(matrix_of(&gap, t3_s), t3_s)?;
        if !stable(radius) {
            return Err(format!(
                "the discrete loop on the motor alone, as it runs while crossing the backlash \
                 gap, is unstable at T3 = {t3_s} s: largest pole |z| = {radius:.4} ≥ 1 (raise \
                 drive.motor_inertia_kgm2, lower kp_per_s / kv_n_s_per_m / ki_per_s, or shorten T3)"
            ));
        }
    }
    Ok(())
}
