//! The stability check linearises the same T3 step the machine runs, so its verdict must
//! match a long simulation of that step: on either side of the boundary it finds, the loop
//! decays or diverges exactly as the check says.

use axisbench::drive::{AxisLoop, LoopInput, check_stability, spectral_radius};
use axisbench::plant::{Sensor, Start};
use axisbench::preset::{self, AxisParams, Coupling};

/// The default X axis with its nonlinear effects off (friction, play, quantization, gravity,
/// thermal growth, lead error) and a torque limit far away: the part of the loop that is
/// linear, whose divergence nothing bounds.
fn linear_axis() -> (AxisParams, f64) {
    let p = preset::load_embedded("default.ron")
        .expect("default preset")
        .preset;
    let mut a = p.axes[0].clone();
    a.friction.enabled = false;
    a.lost_motion.enabled = false;
    a.encoder.quantize_motor = false;
    a.encoder.quantize_scale = false;
    a.gravity.enabled = false;
    a.screw_thermal.enabled = false;
    a.lead_error.enabled = false;
    a.servo.torque_limit_nm = 1e5;
    (a, p.timing.t3_s)
}

/// max |position| over the last tenth of `steps` periods after a 1 µm offset, relative to the
/// offset: ≪ 1 for a loop that settles, ≫ 1 for one that diverges.
fn growth(a: &AxisParams, t3_s: f64, steps: usize) -> f64 {
    let x0 = 1e-6;
    let mut l = AxisLoop::new(
        a,
        t3_s,
        Start::at_rest(Sensor::MotorEncoder, x0),
        0.0,
        0.0,
        vec![],
    );
    let inp = LoopInput::default();
    let mut late = 0.0f64;
    for k in 0..steps {
        l.step(&inp);
        let x = l.plant().out().motor_pos_m;
        if !x.is_finite() {
            return f64::INFINITY;
        }
        if k >= steps - steps / 10 {
            late = late.max(x.abs());
        }
    }
    late / x0
}

/// The value of the gain `set` puts where the largest pole crosses |z| = 1, between a stable
/// `lo` and an unstable `hi` (bisection on the logarithm).
fn boundary(a: &AxisParams, t3_s: f64, set: fn(&mut AxisParams, f64), lo: f64, hi: f64) -> f64 {
    let r = |g: f64| {
        let mut b = a.clone();
        set(&mut b, g);
        spectral_radius(&b, t3_s).expect("poles")
    };
    assert!(
        r(lo) < 1.0 && r(hi) > 1.0,
        "{lo} must be stable and {hi} not"
    );
    let (mut lo, mut hi) = (lo.ln(), hi.ln());
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if r(mid.exp()) < 1.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (0.5 * (lo + hi)).exp()
}

fn check_both_sides(
    name: &str,
    a: &AxisParams,
    t3_s: f64,
    set: fn(&mut AxisParams, f64),
    lo: f64,
    hi: f64,
) {
    let g0 = boundary(a, t3_s, set, lo, hi);
    for (factor, stable) in [(0.97, true), (1.03, false)] {
        let mut b = a.clone();
        set(&mut b, g0 * factor);
        let verdict = check_stability(&b, t3_s);
        assert_eq!(
            verdict.is_ok(),
            stable,
            "{name} at {factor}× the boundary {g0}: {verdict:?}"
        );
        let r = spectral_radius(&b, t3_s).expect("poles");
        // Enough periods for the slowest mode near the boundary to change by e^24.
        let steps = ((24.0 / r.ln().abs()).ceil() as usize).clamp(2_000, 600_000);
        let g = growth(&b, t3_s, steps);
        if stable {
            assert!(
                g < 1e-3,
                "{name}: the check says stable (|z| = {r:.6}) but after {steps} periods the offset is {g:.3e}× its start"
            );
        } else {
            assert!(
                g > 1e3,
                "{name}: the check says unstable (|z| = {r:.6}) but after {steps} periods the offset is only {g:.3e}× its start"
            );
        }
    }
}

#[test]
fn the_check_and_a_long_simulation_agree_on_both_sides_of_the_boundary() {
    let (a, t3) = linear_axis();
    assert!(
        check_stability(&a, t3).is_ok(),
        "the default axis is stable"
    );
    // The velocity loop against the current lag and T3.
    check_both_sides("kv", &a, t3, |a, g| a.servo.kv_n_s_per_m = g, 1e5, 1e8);
    // The position loop against the velocity loop.
    check_both_sides("kp", &a, t3, |a, g| a.servo.kp_per_s = g, 10.0, 9000.0);
    // A compliant screw: the resonance against the velocity loop.
    let mut tm = a.clone();
    tm.drive.coupling = Coupling::TwoMass {
        stiffness_n_per_um: 100.0,
        damping_n_s_per_m: 500.0,
    };
    tm.servo.feedback = axisbench::preset::Feedback::Scale;
    check_both_sides(
        "kv, two-mass, scale feedback",
        &tm,
        t3,
        |a, g| a.servo.kv_n_s_per_m = g,
        1e6,
        1e8,
    );
}

#[test]
fn absurd_gains_end_the_check_with_an_error_not_a_hang() {
    let (mut a, t3) = linear_axis();
    a.servo.ki_per_s = 1e300;
    a.servo.kv_n_s_per_m = 1e300;
    let e = check_stability(&a, t3).expect_err("absurd gains");
    assert!(
        e.contains("unstable") || e.contains("non-finite") || e.contains("converge"),
        "{e}"
    );
}

/// With backlash, the motor crosses the gap alone. A motor far lighter than its load can
/// make that loop unstable while the coupled one is fine: the check must refuse it, and the
/// machine must agree on both sides of the boundary it finds (decaying on one, hunting
/// without end on the other).
#[test]
fn the_check_sees_the_motor_alone_in_the_backlash_gap() {
    let (mut a, t3) = linear_axis();
    a.lost_motion.enabled = true;
    let set = |a: &mut AxisParams, j: f64| a.drive.motor_inertia_kgm2 = j;
    let r = |j: f64| {
        let mut b = a.clone();
        set(&mut b, j);
        spectral_radius(&b, t3).expect("poles")
    };
    // Heavier motor is more stable here: bisection with the stable side high.
    let (mut lo, mut hi) = (1e-14f64.ln(), a.drive.motor_inertia_kgm2.ln());
    assert!(r(lo.exp()) > 1.0 && r(hi.exp()) < 1.0);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if r(mid.exp()) < 1.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let j0 = (0.5 * (lo + hi)).exp();
    for (factor, stable) in [(1.05, true), (0.95, false)] {
        let mut b = a.clone();
        set(&mut b, j0 * factor);
        let verdict = check_stability(&b, t3);
        assert_eq!(
            verdict.is_ok(),
            stable,
            "motor inertia {factor}× the boundary {j0} kg·m²: {verdict:?}"
        );
        let g = growth(&b, t3, 200_000);
        if stable {
            assert!(
                g < 1e-3,
                "stable by the check, but the offset is {g:.3e}× its start"
            );
        } else {
            let e = verdict.expect_err("unstable");
            assert!(
                e.contains("backlash gap") && e.contains("motor_inertia_kgm2"),
                "{e}"
            );
            // Unstable inside the play, the motor hunts: the impacts on the flanks bound
            // the swing (frictionless here, so the table is pushed around too), but the
            // motion never dies out, where the stable side decays to nothing.
            assert!(
                g > 1.0,
                "unstable by the check, but the offset decayed to {g:.3e}× its start"
            );
        }
    }
    // Without backlash nothing separates the motor from the table: the same light motor is fine.
    let mut rigid = a.clone();
    rigid.lost_motion.enabled = false;
    set(&mut rigid, j0 * 0.5);
    assert!(check_stability(&rigid, t3).is_ok());
}
