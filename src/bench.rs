//! Model throughput: axis-steps per second of the full model (every plant effect on), with
//! 1 and 3 axes, trace recording off. Printed by `axisbench bench`; speed targets live here,
//! never in timed unit tests.

use std::time::Instant;

use crate::machine::{Machine, MachineError};
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

#[derive(Debug, Clone)]
pub struct BenchFigure {
    pub n_axes: usize,
    pub steps: u64,
    pub recording: bool,
    pub axis_steps_per_s: f64,
}

/// Runs the full model for `axis_steps` axis-steps, best of three.
pub fn run(n_axes: usize, axis_steps: u64, recording: bool) -> Result<BenchFigure, MachineError> {
    let p = full_model_preset(n_axes)?;
    let prog = bench_program(n_axes);
    let steps = (axis_steps / n_axes as u64).max(1);
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let mut m = Machine::new(&p, &[("bench.ngc".into(), prog.clone())])?;
        m.set_recording(recording);
        let t0 = Instant::now();
        m.run_steps(steps);
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
