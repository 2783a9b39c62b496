//! Model throughput: axis-steps per second of the full model (every plant effect on), with
//! 1 and 3 axes, trace recording off. Printed by `axisbench bench`; speed targets live here,
//! never in timed unit tests.

use std::time::Instant;

use crate::drive::{AxisLoop, LoopInput};
use crate::machine::{Machine, MachineError};
use crate::plant::Start;
use crate::preset::{self, Coupling, Feedback, Preset};

/// The embedded default preset with every plant effect switched on, on `n_axes` axes.
pub fn full_model_preset(n_axes: usize) -> Result<Preset, MachineError> {
    let mut p = preset::load_embedded("default.ron")?.preset;
    let mut a = p.axes[0].clone();
    a.drive.coupling = Coupling::TwoMass {
        stiffness_n_per_um: 150.0,
        damping_n_s_per_m: 2.0e4,
    };
    a.lost_motion.enabled = true;
    a.friction.enabled = true;
    a.friction.stribeck.enabled = true;
    a.friction.stroke.enabled = true;
    a.gravity.enabled = true;
    a.gravity.incline_deg = 30.0;
    a.screw_thermal.enabled = true;
    a.lead_error.enabled = true;
    a.encoder.quantize_motor = true;
    a.encoder.quantize_scale = true;
    a.servo.feedback = Feedback::Scale;
    p.axes = ["x", "y", "z"]
        .iter()
        .zip(['X', 'Y', 'Z'])
        .take(n_axes)
        .map(|(n, l)| {
            let mut b = a.clone();
            b.name = (*n).into();
            b.letter = l;
            b
        })
        .collect();
    p.scenario.programs = vec!["bench.ngc".into()];
    p.scenario.duration_s = None;
    Ok(p)
}

/// The embedded default preset as shipped (the effects the numba peer models), its first
/// axis driven by [`bench_program`]: the whole machine, NC included, on the peer's physics.
pub fn default_model_preset() -> Result<Preset, MachineError> {
    let mut p = preset::load_embedded("default.ron")?.preset;
    p.axes.truncate(1);
    p.scenario.programs = vec!["bench.ngc".into()];
    p.scenario.duration_s = None;
    Ok(p)
}

/// A long back-and-forth program, short and long strokes, so every effect stays active.
pub fn bench_program(n_axes: usize) -> String {
    let letters = ['X', 'Y', 'Z'];
    let mut s = String::from("G90 G01 F6000\n");
    for _ in 0..2000 {
        for (target, _) in [(50.0, 0), (40.0, 1), (90.0, 2), (5.0, 3)] {
            let words: Vec<String> = letters[..n_axes]
                .iter()
                .map(|l| format!("{l}{target:.3}"))
                .collect();
            s += &words.join(" ");
            s.push('\n');
        }
    }
    s += "M30\n";
    s
}

/// One throughput measurement of the full model.
#[derive(Debug, Clone)]
pub struct BenchFigure {
    /// Axes simulated (1–3).
    pub n_axes: usize,
    /// Machine steps (T3 periods) run per attempt.
    pub steps: u64,
    /// Whether the trace was recorded during the run.
    pub recording: bool,
    /// Throughput: T3 periods × axes per second of wall time, best of three attempts.
    pub axis_steps_per_s: f64,
}

/// Steps a recorded run of `m` can take before its trace reaches
/// [`crate::machine::MAX_TRACE_BYTES`].
fn max_recorded_steps(m: &Machine) -> u64 {
    let row_bytes = m.trace.signals.len().max(1) * std::mem::size_of::<f64>();
    let rows = (crate::machine::MAX_TRACE_BYTES / row_bytes).saturating_sub(m.trace.len() + 1);
    u64::try_from(rows).unwrap_or(u64::MAX).max(1)
}

/// Runs the full model for `axis_steps` axis-steps, best of three.
pub fn run(n_axes: usize, axis_steps: u64, recording: bool) -> Result<BenchFigure, MachineError> {
    run_preset(&full_model_preset(n_axes)?, axis_steps, recording)
}

/// Runs the machine of preset `p` (its program is [`bench_program`]) for `axis_steps`
/// axis-steps, best of three.
pub fn run_preset(
    p: &Preset,
    axis_steps: u64,
    recording: bool,
) -> Result<BenchFigure, MachineError> {
    let n_axes = p.axes.len().max(1);
    let prog = bench_program(n_axes);
    let mut steps = (axis_steps / n_axes as u64).max(1);
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let mut m = Machine::new(p, &[("bench.ngc".into(), prog.clone())])?;
        m.set_recording(recording);
        if recording {
            // A recorded run stops at the trace's memory limit; the figure says how many
            // steps it timed.
            steps = steps.min(max_recorded_steps(&m));
        }
        let t0 = Instant::now();
        m.run_steps(steps)?;
        let dt = t0.elapsed().as_secs_f64();
        std::hint::black_box(m.axes[0].pos_m);
        best = best.min(dt);
    }
    Ok(BenchFigure {
        n_axes,
        steps,
        recording,
        axis_steps_per_s: (steps * n_axes as u64) as f64 / best,
    })
}

/// The inputs of axis 0's loop at every T3 of a run of `preset` (recording off), to replay
/// through [`AxisLoop::step`] alone.
pub fn recorded_inputs(
    p: &Preset,
    programs: &[(String, String)],
) -> Result<Vec<LoopInput>, MachineError> {
    let mut m = Machine::new(p, programs)?;
    m.set_recording(false);
    let mut out = Vec::new();
    while !m.done() && out.len() < 20_000_000 {
        let t_s = m.t_s();
        m.step();
        let a = &m.axes[0];
        let s = a.axis_loop.sample();
        out.push(LoopInput {
            t_s,
            cmd_raw_m: s.cmd_raw_m,
            cmd_nc_m: s.cmd_nc_m,
            acc_cmd_mps2: a.acc_cmd_mps2(),
            ext_force_n: 0.0,
        });
    }
    Ok(out)
}

/// [`AxisLoop::step`] alone on the default preset's X axis, driven by the inputs the machine
/// gave it on the default program (tiled to `steps`), best of three: the figure the numba
/// peer (`tools/peer`) is compared with, step for step on the same input. No trace row is
/// written ([`AxisLoop::run_quiet`]), as the peer's timed kernel records none
/// (`record=False`): a row per step is the recording-on figure's cost, not the step's.
pub fn step_kernel(steps: u64) -> Result<BenchFigure, MachineError> {
    let lp = preset::load_embedded("default.ron")?;
    let p = &lp.preset;
    let programs = vec![("default.ngc".to_owned(), lp.program_text("default.ngc")?)];
    let inputs = recorded_inputs(p, &programs)?;
    let n = inputs.len().max(1);
    let a = &p.axes[0];
    let x0 = inputs.first().map_or(0.0, |i| i.cmd_raw_m);
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let mut l = AxisLoop::new(
            a,
            p.timing.t3_s,
            Start::at_rest(a.servo.feedback.into(), x0),
            x0,
            x0,
            crate::comp::servo_comps(0, a),
        );
        let t0 = Instant::now();
        let mut left = steps as usize;
        while left > 0 {
            let m = left.min(n);
            l.run_quiet(&inputs[..m]);
            left -= m;
        }
        best = best.min(t0.elapsed().as_secs_f64());
        std::hint::black_box(l.plant().out().pos_m);
    }
    Ok(BenchFigure {
        n_axes: 1,
        steps,
        recording: false,
        axis_steps_per_s: steps as f64 / best,
    })
}
