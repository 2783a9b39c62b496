//! Analytic and physical checks of the amplifier and the plant.

use axisbench::preset::{Coupling, Mode};
use axisbench::units::{force_per_torque, m_to_um, mm_to_m, mm_to_um, n_per_um_to_n_per_m};

use crate::common::{at, col, col_mm, plain, run};

#[test]
fn ramp_following_error_is_v_over_kp() {
    let p = plain();
    let kp = p.axes[0].servo.kp_per_s;
    // 100 mm/s for 2 s.
    let m = run(&p, "G90 G01 X200. F6000\nM30\n");
    let tr = &m.trace;
    let ferr = col_mm(tr, "x.ferr");
    let expected_mm = 100.0 / kp;
    for t_s in [0.8, 1.0, 1.5] {
        let e = ferr[at(tr, t_s)];
        assert!(
            (e - expected_mm).abs() < 0.01 * expected_mm,
            "t = {t_s}: following error {e} mm, expected v/Kp = {expected_mm} mm"
        );
    }
    // And it is gone once the axis stops.
    let last = *ferr.last().unwrap_or(&f64::NAN);
    assert!(
        last.abs() < 1e-3 * expected_mm,
        "residual error {last} mm at rest"
    );
}

#[test]
fn step_response_matches_second_order_analytic() {
    // P position loop around a P velocity loop, ideal current loop, rigid axis:
    // x'' = (kv/M)(kp (r − x) − x'), a second-order system with two real poles.
    let mut p = plain();
    let a = &mut p.axes[0];
    a.servo.ki_per_s = 0.0;
    a.servo.current_lag_s = 0.0;
    p.nc.initial_mode = Mode::Direct;
    let kv_over_m = p.axes[0].servo.kv_n_s_per_m / p.axes[0].drive.total_mass_kg();
    let kp = p.axes[0].servo.kp_per_s;
    let step_mm = 0.1;
    let m = run(&p, "G05P4\nU0.1\nG04 P500\nM30\n");
    let tr = &m.trace;
    let cmd = col(tr, "x.cmd");
    let pos = col_mm(tr, "x.pos");
    let k0 = cmd.iter().position(|&c| c > 0.0).expect("step arrives");
    assert_eq!(
        cmd[k0],
        mm_to_m(step_mm),
        "the amplifier sees the full step in one T3"
    );
    let disc = (kv_over_m * kv_over_m - 4.0 * kv_over_m * kp).sqrt();
    let p1 = (-kv_over_m + disc) / 2.0;
    let p2 = (-kv_over_m - disc) / 2.0;
    let t0 = tr.t()[k0]; // the row of the instant the step command is first applied
    let mut worst = 0.0_f64;
    let k1 = at(tr, t0 + 0.15);
    for (t_abs, x) in tr.t()[k0..k1].iter().zip(&pos[k0..k1]) {
        let t = t_abs - t0;
        let analytic = step_mm * (1.0 + (p2 * (p1 * t).exp() - p1 * (p2 * t).exp()) / (p1 - p2));
        worst = worst.max((x - analytic).abs());
    }
    assert!(
        worst < 0.01 * step_mm,
        "step response deviates {worst} mm from the analytic one"
    );
    let end = *pos.last().unwrap_or(&0.0);
    assert!(
        (end - step_mm).abs() < 1e-6,
        "settles at {end} mm, expected {step_mm}"
    );
}

#[test]
fn torque_offset_at_constant_velocity_equals_coulomb() {
    let mut p = plain();
    let a = &mut p.axes[0];
    a.friction.enabled = true;
    a.friction.coulomb_n = 250.0;
    a.friction.viscous_n_s_per_m = 0.0;
    a.friction.stribeck.enabled = false;
    let lead_m = a.drive.lead_mm * 1e-3;
    let m = run(&p, "G90 G01 X100. F3000\nM30\n");
    let tr = &m.trace;
    let (i0, i1) = (at(tr, 0.8), at(tr, 1.6));
    let torque = &col(tr, "x.torque")[i0..i1];
    let mean = torque.iter().sum::<f64>() / torque.len() as f64;
    let expected = 250.0 / force_per_torque(lead_m);
    assert!(
        (mean - expected).abs() < 0.01 * expected,
        "torque offset {mean} N·m, expected Coulomb {expected} N·m"
    );
    let fric = col(tr, "x.friction")[at(tr, 1.0)];
    assert!(
        (fric + 250.0).abs() < 1e-9,
        "friction force {fric} N while moving +"
    );
}

#[test]
fn a_viscous_split_drags_more_one_way_by_exactly_twice_the_split() {
    // Coulomb 100 N, viscous 800 ± 300 N·s/m, at 50 mm/s each way: the slide's friction
    // is 100 + 1100·0.05 = 155 N moving +, 100 + 500·0.05 = 125 N moving −. Without the
    // split both are 140 N (the default path, unchanged).
    let friction_at = |split: f64| {
        let mut p = plain();
        let a = &mut p.axes[0];
        a.friction.enabled = true;
        a.friction.coulomb_n = 100.0;
        a.friction.viscous_n_s_per_m = 800.0;
        a.friction.viscous_split_n_s_per_m = split;
        a.friction.stribeck.enabled = false;
        let m = run(&p, "G90 G01 X100. F3000\nX0.\nM30\n");
        let tr = &m.trace;
        let fric = col(tr, "x.friction");
        let vel = col(tr, "x.vel");
        // Mid-stroke of each move: 1.0 s (moving +) and 3.0 s (moving −).
        let (kp, kn) = (at(tr, 1.0), at(tr, 3.0));
        (fric[kp], vel[kp], fric[kn], vel[kn])
    };
    let (fp, vp, fn_, vn) = friction_at(300.0);
    assert!(vp > 0.0 && vn < 0.0, "mid-stroke velocities {vp}, {vn}");
    let want_p = -(100.0 + 1100.0 * vp);
    let want_n = 100.0 - 500.0 * vn;
    assert!(
        (fp - want_p).abs() < 1e-6 && (fn_ - want_n).abs() < 1e-6,
        "friction {fp} N moving + (want {want_p}), {fn_} N moving − (want {want_n})"
    );
    let (fp0, vp0, fn0, vn0) = friction_at(0.0);
    assert!(
        (fp0 + 100.0 + 800.0 * vp0).abs() < 1e-6 && (fn0 - 100.0 + 800.0 * vn0).abs() < 1e-6,
        "no split: {fp0} N and {fn0} N"
    );
}

#[test]
fn a_power_law_speed_term_adds_its_force_at_each_speed() {
    // Coulomb 100 N, viscous 800 N·s/m and 20 N·(|v| / 100 mm/s)^0.5 at 50 and 25 mm/s:
    // 100 + 800·v + 20·√(v / 0.1 m/s). The power term is taken at the speed a step starts
    // with, which at a constant feed is the speed it ends with to far below a µN.
    let mut p = plain();
    let a = &mut p.axes[0];
    a.friction.enabled = true;
    a.friction.coulomb_n = 100.0;
    a.friction.viscous_n_s_per_m = 800.0;
    a.friction.stribeck.enabled = false;
    a.friction.viscous_power.enabled = true;
    a.friction.viscous_power.force_at_100mm_per_s_n = 20.0;
    a.friction.viscous_power.exponent = 0.5;
    let m = run(&p, "G90 G01 X100. F3000\nX50. F1500\nM30\n");
    let tr = &m.trace;
    let fric = col(tr, "x.friction");
    let vel = col(tr, "x.vel");
    for t_s in [1.0, 3.5] {
        let k = at(tr, t_s);
        let v = vel[k];
        let want = 100.0 + 800.0 * v.abs() + 20.0 * (v.abs() / 0.1).sqrt();
        assert!(
            (fric[k].abs() - want).abs() < 1e-6,
            "t = {t_s} s at {v} m/s: friction {} N, want {want} N",
            fric[k]
        );
    }
    let k = at(tr, 1.0);
    assert!(
        (vel[k] - 0.05).abs() < 1e-4,
        "mid-stroke speed {} m/s, expected 50 mm/s",
        vel[k]
    );
    // Below the core speed (1 mm/s) it is linear, through the same force there: a power
    // under 1 would have an infinite slope at rest.
    let law = axisbench::plant::FrictionModel::from_params(&p.axes[0]);
    let pl = law.power.expect("the power term is on");
    let at_core = pl.force_n(mm_to_m(1.0));
    // 20 N·(1 mm/s / 100 mm/s)^0.5 = 2 N.
    assert!((at_core - 2.0).abs() < 1e-12, "{at_core}");
    assert!((pl.force_n(mm_to_m(0.5)) - 0.5 * at_core).abs() < 1e-12);
}

#[test]
fn a_smoothed_coulomb_level_lets_a_force_below_it_creep_where_the_exact_law_sticks() {
    // 40 N of Coulomb friction built up as tanh(v / 0.5 mm/s) on a 100 kg slide, stepped
    // at 0.1 ms (the slope at rest, 80 000 N·s/m, is 8× what an explicit step takes).
    let mut p = plain();
    let a = &mut p.axes[0];
    a.friction.enabled = true;
    a.friction.coulomb_n = 40.0;
    a.friction.viscous_n_s_per_m = 0.0;
    a.friction.stribeck.enabled = false;
    let creep = |smoothing_mm_per_s: f64, drive_n: f64, viscous: f64| {
        let mut a = p.axes[0].clone();
        a.friction.coulomb_smoothing_mm_per_s = smoothing_mm_per_s;
        a.friction.viscous_n_s_per_m = viscous;
        let law = axisbench::plant::FrictionModel::from_params(&a);
        let body = law.body(100.0, 1e-4);
        let (mut v, mut f) = (0.0, 0.0);
        for _ in 0..40_000 {
            (v, f) = law.step::<true>(&body, v, 0.0, drive_n, 1.0, 0.0);
        }
        (v, f)
    };
    // 20 N against 40 N: the exact law holds the slide; the smooth one lets it creep where
    // 40·tanh(v/ε) = 20, v = ε·atanh(0.5) = 0.2747 mm/s.
    let (v_exact, f_exact) = creep(0.0, 20.0, 0.0);
    assert_eq!(v_exact, 0.0, "the exact law sticks");
    assert!((f_exact + 20.0).abs() < 1e-9, "{f_exact}");
    let (v, f) = creep(0.5, 20.0, 0.0);
    let want = mm_to_m(0.5) * 0.5f64.atanh();
    assert!(
        (v - want).abs() < 1e-6 * want,
        "creep {v} m/s, want {want} m/s"
    );
    assert!((f + 20.0).abs() < 1e-6, "{f}");
    // 60 N with 1000 N·s/m beside it: far above ε the full level acts, 60 = 40 + 1000·v.
    let (v, f) = creep(0.5, 60.0, 1000.0);
    assert!((v - 0.02).abs() < 1e-6, "{v} m/s, want 20 mm/s");
    assert!((f + 60.0).abs() < 1e-6, "{f}");
}

#[test]
fn a_stribeck_excess_falls_off_with_the_shape_asked_for() {
    // Coulomb 100 N, breakaway 160 N, v_s = 2 mm/s: at 3 mm/s the Gaussian leaves
    // 60·e^(−2.25) of the excess, the exponential 60·e^(−1.5).
    let mut p = plain();
    let a = &mut p.axes[0];
    a.friction.enabled = true;
    a.friction.coulomb_n = 100.0;
    a.friction.viscous_n_s_per_m = 0.0;
    a.friction.stribeck.enabled = true;
    a.friction.stribeck.static_n = 160.0;
    a.friction.stribeck.velocity_mm_per_s = 2.0;
    for (shape, x) in [
        (axisbench::preset::StribeckShape::Gaussian, 2.25f64),
        (axisbench::preset::StribeckShape::Exponential, 1.5),
    ] {
        p.axes[0].friction.stribeck.shape = shape;
        let m = run(&p, "G90 G01 X3. F180\nM30\n");
        let tr = &m.trace;
        let k = at(tr, 0.5);
        let v = col(tr, "x.vel")[k];
        assert!((v - 0.003).abs() < 1e-6, "{shape:?}: {v} m/s mid-stroke");
        let r = v / 0.002;
        let e = if x == 1.5 { r } else { r * r };
        let want = 100.0 + 60.0 * (-e).exp();
        let got = -col(tr, "x.friction")[k];
        assert!(
            (got - want).abs() < 1e-6,
            "{shape:?}: friction {got} N at {v} m/s, want {want} N"
        );
    }
}

#[test]
fn uncompensated_backlash_loses_b_at_a_reversal() {
    let mut p = plain();
    let a = &mut p.axes[0];
    a.lost_motion.enabled = true;
    a.lost_motion.width_um = 20.0;
    a.friction.enabled = true;
    let m = run(&p, "G90 G01 X10. F1000\nG04 P500\nX5.\nG04 P500\nM30\n");
    let tr = &m.trace;
    let err = col_mm(tr, "x.err");
    let after_plus = err[at(tr, 0.6 + 0.45)];
    let after_minus = *err.last().unwrap_or(&f64::NAN);
    let lost_um = mm_to_um(after_plus - after_minus);
    assert!(
        (lost_um - 20.0).abs() < 0.2,
        "lost motion at the reversal {lost_um} µm, expected b = 20 µm"
    );
    // Semi-closed loop: the motor itself is exactly where it was told to be.
    let ferr = *col_mm(tr, "x.ferr").last().unwrap_or(&f64::NAN);
    assert!(
        ferr.abs() < 1e-6,
        "motor-side following error {ferr} mm at rest"
    );
}

#[test]
fn closed_loop_on_the_scale_removes_the_backlash_error() {
    let mut p = plain();
    let a = &mut p.axes[0];
    a.lost_motion.enabled = true;
    a.lost_motion.width_um = 20.0;
    a.friction.enabled = true;
    a.servo.feedback = axisbench::preset::Feedback::Scale;
    let m = run(&p, "G90 G01 X10. F1000\nG04 P500\nX5.\nG04 P500\nM30\n");
    let err = *col_mm(&m.trace, "x.err").last().unwrap_or(&f64::NAN);
    assert!(err.abs() < 1e-4, "closed loop leaves {err} mm at rest");
}

#[test]
fn stick_holds_exactly_without_drift_or_chatter() {
    // A slope load below the breakaway force: the table must stay put, velocity exactly 0.
    let mut p = plain();
    let a = &mut p.axes[0];
    a.friction.enabled = true;
    a.friction.coulomb_n = 300.0;
    a.friction.stribeck.enabled = true;
    a.friction.stribeck.static_n = 400.0;
    a.gravity.enabled = true;
    a.gravity.incline_deg = 0.0;
    a.gravity.offset_n = 350.0; // pushes +, held by static friction
    a.servo.torque_limit_nm = 1e-6; // drive effectively off
    let m = run(&p, "G04 P1000\nM30\n");
    let vel = col_mm(&m.trace, "x.vel");
    let pos = col_mm(&m.trace, "x.pos");
    assert!(vel.iter().all(|&v| v == 0.0), "table crept while stuck");
    assert!(
        pos.iter().all(|&x| x == pos[0]),
        "table drifted while stuck"
    );
}

#[test]
fn stroke_friction_rises_on_short_strokes_and_recovers_on_long_ones() {
    let mut p = plain();
    let a = &mut p.axes[0];
    a.friction.enabled = true;
    a.friction.viscous_n_s_per_m = 0.0;
    a.friction.stroke.enabled = true;
    a.friction.stroke.pitch_mm = 15.0;
    a.friction.stroke.rise_ratio = 0.8;
    let fc = a.friction.coulomb_n;
    let prog = "G90 G01 F2000\nX40.\nX30.\nX40.\nX30.\nX40.\nX30.\nX40.\nX0.\nX60.\nX0.\nM30\n";
    let m = run(&p, prog);
    let tr = &m.trace;
    let fric = col(tr, "x.friction");
    let cmd = col(tr, "x.cmd");
    // Mid-stroke friction magnitude on each stroke.
    let revs = axisbench::analysis::reversals(cmd);
    let mut levels = vec![];
    for w in revs.windows(2) {
        let mid = (w[0].0 + w[1].0) / 2;
        levels.push(fric[mid].abs());
    }
    // strokes: 40→30 (short after long) ... later 0→60 long ones
    assert!(
        levels[1] > levels[0] * 1.1,
        "friction did not rise over short strokes: {levels:?}"
    );
    let peak = levels.iter().cloned().fold(0.0, f64::max);
    assert!(peak <= fc * 1.8 + 1e-9, "rise exceeds 1 + rise_ratio");
    let last = *levels.last().unwrap_or(&0.0);
    assert!(
        last < peak * 0.9,
        "friction did not recover on long strokes: {levels:?}"
    );
}

#[test]
fn a_film_worn_by_distance_rises_after_each_turn_and_rebuilds_past_the_pitch() {
    // FilmLaw::Distance with breakdown = pitch = 5 mm, recovery 10 mm, rise ×0.8: one pitch
    // after a turning point the film is 1 − e^(−1) broken (from nearly whole after a 60 mm
    // stroke), so the Coulomb level is ×(1 + 0.8·0.632); 45 mm further it has rebuilt to
    // e^(−4.5) of that. Twenty 2 mm strokes break it down almost fully (×1.8).
    let mut p = plain();
    let a = &mut p.axes[0];
    a.friction.enabled = true;
    a.friction.viscous_n_s_per_m = 0.0;
    let s = &mut a.friction.stroke;
    s.enabled = true;
    s.law = axisbench::preset::FilmLaw::Distance;
    s.pitch_mm = 5.0;
    s.breakdown_mm = 5.0;
    s.recovery_mm = 10.0;
    s.rise_ratio = 0.8;
    let fc = a.friction.coulomb_n;
    let mut prog = String::from("G90 G01 F2000\nX60.\nX0.\n");
    for _ in 0..10 {
        prog += "X2.\nX0.\n";
    }
    prog += "M30\n";
    let m = run(&p, &prog);
    let fric = col(&m.trace, "x.friction");
    let pos = col_mm(&m.trace, "x.pos");
    // The turning point: the NC reverses without an exact stop, so the table turns short of
    // 60 mm by its following error.
    let turn = (0..pos.len())
        .max_by(|&i, &j| pos[i].total_cmp(&pos[j]))
        .expect("a trace");
    let ratio_at = |x_mm: f64| {
        let k = turn
            + pos[turn..]
                .iter()
                .position(|&x| x <= pos[turn] - x_mm)
                .expect("passes");
        fric[k].abs() / fc
    };
    let one_pitch = ratio_at(5.0);
    assert!(
        (one_pitch - (1.0 + 0.8 * (1.0 - (-1.0_f64).exp()))).abs() < 0.02,
        "one pitch after the turn: ×{one_pitch}"
    );
    let far = ratio_at(50.0);
    let want_far = 1.0 + 0.8 * (1.0 - (-1.0_f64).exp()) * (-4.5_f64).exp();
    assert!(
        (far - want_far).abs() < 0.01,
        "45 mm past the pitch: ×{far}, want ×{want_far}"
    );
    let short = fric[fric.len() - 2000..]
        .iter()
        .map(|f| f.abs() / fc)
        .fold(0.0, f64::max);
    assert!(
        short > 1.7 && short <= 1.8 + 1e-9,
        "after short strokes: ×{short}"
    );
}

#[test]
fn thermal_growth_grows_with_distance_from_the_fixed_bearing() {
    let mut p = plain();
    let a = &mut p.axes[0];
    a.screw_thermal.enabled = true;
    a.screw_thermal.initial_c = 25.0; // a warm screw, 5 K above reference
    a.screw_thermal.ambient_c = 25.0;
    a.screw_thermal.motion_heat_w_s_per_m = 0.0;
    a.screw_thermal.friction_heat_share = 0.0;
    let alpha = a.screw_thermal.alpha_per_k;
    let m = run(&p, "G90 G01 X100. F6000\nG04 P300\nX400.\nM30\n");
    let tr = &m.trace;
    let th = col_mm(tr, "x.thermal");
    let pos = col_mm(tr, "x.pos");
    for k in [at(tr, 1.2), tr.len() - 1] {
        let expected = alpha * 5.0 * (pos[k] - th[k]);
        assert!(
            (th[k] - expected).abs() < 1e-9,
            "elongation {} mm, expected {expected} mm",
            th[k]
        );
    }
    assert!(
        th[tr.len() - 1] > 3.5 * th[at(tr, 1.2)],
        "error does not grow with position"
    );
}

#[test]
fn screw_heats_from_friction_and_cools_to_ambient() {
    let mut p = plain();
    let a = &mut p.axes[0];
    a.screw_thermal.enabled = true;
    a.friction.enabled = true;
    let m = run(&p, "G90 G01 F6000\nX400.\nX0.\nX400.\nX0.\nM30\n");
    let temp = col(&m.trace, "temp.x_screw");
    assert!(
        temp[temp.len() - 1] > temp[0],
        "moving with friction did not heat the screw"
    );
}

#[test]
fn crossbeam_sag_matches_the_beam_formula() {
    let lp = axisbench::preset::load_embedded("vertical_lathe_crossbeam.ron").expect("preset");
    let p = lp.preset.clone();
    let mut m = axisbench::Machine::from_loaded(&lp).expect("machine");
    m.run_steps(10).unwrap();
    let cb = &p.crossbeam;
    let l = cb.span_mm * 1e-3;
    let ei = cb.youngs_modulus_gpa * 1e9 * cb.area_moment_cm4 * 1e-8;
    let x1 = m.axes[0].pos_m;
    let x2 = m.axes[2].pos_m;
    // Superposition of the two posts and the self-weight at post 1.
    let point = |x: f64, a: f64, pw: f64| {
        let (xx, aa) = if x <= a { (x, a) } else { (l - x, l - a) };
        let b = l - aa;
        pw * b * xx * (l * l - b * b - xx * xx) / (6.0 * ei * l)
    };
    let w = cb.self_weight_n_per_m;
    let d1 = w * x1 * (l.powi(3) - 2.0 * l * x1 * x1 + x1.powi(3)) / (24.0 * ei)
        + point(x1, x1, cb.posts[0].weight_n)
        + point(x1, x2, cb.posts[1].weight_n);
    let sag = m.axes[1].sag_m;
    assert!(
        (sag + d1).abs() < 1e-12,
        "sag {sag} m, beam formula {}",
        -d1
    );
    // Midspan load on a simply supported beam: P L³ / 48 EI.
    let beam = axisbench::plant::Beam::new(
        &axisbench::preset::Crossbeam {
            self_weight_n_per_m: 0.0,
            ..cb.clone()
        },
        |_| Some(0),
    )
    .expect("beam");
    let mid = beam.deflection_m(l / 2.0, &[(l / 2.0, 1000.0)]);
    assert!((mid - 1000.0 * l.powi(3) / (48.0 * ei)).abs() < 1e-15);
}

#[test]
fn sag_is_largest_with_the_post_at_midspan() {
    let mut lp = axisbench::preset::load_embedded("vertical_lathe_crossbeam.ron").expect("preset");
    lp.preset.cross.clear();
    lp.preset.scenario.programs[1] = "vertical_lathe_right_traverse.ngc".into();
    let mut m = axisbench::Machine::from_loaded(&lp).expect("machine");
    m.set_recording(true);
    m.run(600.0).unwrap();
    let tr = &m.trace;
    let x = col_mm(tr, "x.pos");
    let sag = col_mm(tr, "z.sag");
    let k_mid = x
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1 - 1900.0).abs().total_cmp(&(b.1 - 1900.0).abs()))
        .map(|(k, _)| k)
        .unwrap_or(0);
    assert!(
        sag[k_mid] < sag[0],
        "post near midspan should sag more than near the support"
    );
    // The Z servo cannot see the sag: the tool error equals it.
    let err = col_mm(tr, "z.err");
    assert!((err[k_mid] + sag[k_mid]).abs() < 5e-3);
}

#[test]
fn two_mass_axis_follows_and_settles() {
    let mut p = plain();
    p.axes[0].drive.coupling = Coupling::TwoMass {
        stiffness_n_per_um: 150.0,
        damping_n_s_per_m: 2.0e4,
    };
    let m = run(&p, "G90 G01 X50. F3000\nM30\n");
    let err = *col_mm(&m.trace, "x.err").last().unwrap_or(&f64::NAN);
    assert!(err.abs() < 1e-4, "two-mass axis left {err} mm");
}

/// A lightly damped coupling, left to ring after one force pulse (no servo, no friction),
/// decays at its analytic rate exp(−ζωt). The sub-step of the rule (ω·h ≤ 0.3) resolves the
/// resonance but does not damp it: an integrator that takes the spring force at the start
/// of the sub-step adds about ω·h/4 of negative damping, and this spring rang up instead.
#[test]
fn lightly_damped_coupling_decays_at_the_analytic_rate() {
    use axisbench::plant::{AxisPlant, Sensor, Start};
    let mut p = plain();
    let a = &mut p.axes[0];
    let (m_m, m_t) = (a.drive.reflected_motor_mass_kg(), a.drive.table_mass_kg);
    let m_red = m_m * m_t / (m_m + m_t);
    let (f_hz, zeta) = (100.0, 0.01);
    let w = std::f64::consts::TAU * f_hz;
    a.drive.coupling = Coupling::TwoMass {
        stiffness_n_per_um: w * w * m_red * 1e-6,
        damping_n_s_per_m: 2.0 * zeta * w * m_red,
    };
    // The damping ratio the diagnosis bounds its fitted springs by is this mode's.
    let z = a.coupling_damping_ratio().unwrap_or(f64::NAN);
    assert!(
        (z / zeta - 1.0).abs() < 1e-9,
        "damping ratio {z}, built with {zeta}"
    );
    // So is the resonance it bounds them by (below the record's Nyquist frequency).
    let w_fit = a.coupling_resonance_rad_per_s().unwrap_or(f64::NAN);
    assert!(
        (w_fit / w - 1.0).abs() < 1e-9,
        "resonance {w_fit} rad/s, built with {w}"
    );
    let t3_s = 1e-3;
    let mut plant = AxisPlant::new(a, t3_s, Start::at_rest(Sensor::MotorEncoder, 0.0));
    assert_eq!(
        plant.substeps(),
        3,
        "ω·h stays below 0.3 with three sub-steps"
    );
    plant.step(1000.0, 0.0);
    let defl: Vec<f64> = (0..700)
        .map(|_| {
            plant.step(0.0, 0.0);
            plant.out().motor_pos_m - plant.out().pos_m
        })
        .collect();
    // The envelope: the largest deflection over one period (10 samples) at 0.1 s and 0.6 s.
    let peak = |k: usize| defl[k..k + 10].iter().fold(0.0_f64, |m, d| m.max(d.abs()));
    let (early, late) = (peak(100), peak(600));
    let ratio = late / early;
    let expected = (-zeta * w * 0.5).exp();
    assert!(
        (ratio / expected - 1.0).abs() < 0.1,
        "envelope ratio over 0.5 s {ratio:.4}, analytic exp(−ζωt) = {expected:.4}"
    );
}

/// A payload on a mount on the table, the drive pushed by a constant force (no friction, no
/// servo): once the mount's ringing has died out the whole axis accelerates at F/(m_near +
/// m_p), and the mount carries the payload's share m_p·a at the deflection its law gives:
/// d = m_p·a/k for a linear mount, k·d·(1 + (d/d₀)²) = m_p·a for a hardening one.
#[test]
fn a_payload_mount_deflects_by_its_law_under_a_steady_acceleration() {
    use axisbench::plant::{AxisPlant, Sensor, Start};
    for d0_um in [0.0, 4.0] {
        let mut p = plain();
        let a = &mut p.axes[0];
        a.friction.enabled = false;
        a.gravity.enabled = false;
        let (m_p, k_n_per_um) = (30.0, 2.0);
        let m_near = a.drive.reflected_motor_mass_kg() + a.drive.table_mass_kg;
        let m_red = m_near * m_p / (m_near + m_p);
        // Half of critical damping, so the ringing is gone well within the run.
        let c = 2.0 * 0.5 * (n_per_um_to_n_per_m(k_n_per_um) * m_red).sqrt();
        a.drive.coupling = Coupling::Payload {
            mass_kg: m_p,
            stiffness_n_per_um: k_n_per_um,
            damping_n_s_per_m: c,
            hardening_deflection_um: d0_um,
        };
        let z = a.coupling_damping_ratio().unwrap_or(f64::NAN);
        assert!(
            (z - 0.5).abs() < 1e-9,
            "the mount's damping ratio {z}, built with 0.5"
        );
        let mut plant = AxisPlant::new(a, 1e-3, Start::at_rest(Sensor::MotorEncoder, 0.0));
        let force_n = 500.0;
        for _ in 0..300 {
            plant.step(force_n, 0.0);
        }
        let s = plant.mech_state();
        // The payload's state is in the motor's slots.
        let defl_um = m_to_um(s.x_t - s.x_m);
        let f_s = m_p * force_n / (m_near + m_p);
        let expected_um = if d0_um > 0.0 {
            // r + r³ = f_s/(k·d0), by Newton from the linear deflection's ratio.
            let q = f_s / (k_n_per_um * d0_um);
            let mut r = q.cbrt();
            for _ in 0..50 {
                r -= (r + r * r * r - q) / (1.0 + 3.0 * r * r);
            }
            r * d0_um
        } else {
            f_s / k_n_per_um
        };
        assert!(
            (defl_um / expected_um - 1.0).abs() < 0.005,
            "d0 = {d0_um} µm: deflection {defl_um:.3} µm, the law gives {expected_um:.3} µm"
        );
        assert!(
            (plant.out().motor_pos_m - plant.out().pos_m).abs() < 1e-12,
            "the motor moves with the table"
        );
    }
}

#[test]
fn torque_limit_saturates_the_command() {
    let mut p = plain();
    p.axes[0].servo.torque_limit_nm = 2.0;
    let m = run(&p, "G05P4\nU5.\nG04 P500\nM30\n");
    let tq = col(&m.trace, "x.torque_cmd");
    let peak = tq.iter().fold(0.0_f64, |a, &b| a.max(b.abs()));
    assert!(
        (peak - 2.0).abs() < 1e-12,
        "torque command peaked at {peak} N·m with a 2 N·m limit"
    );
    let end = *col_mm(&m.trace, "x.pos").last().unwrap_or(&0.0);
    assert!(
        (end - 5.0).abs() < 1e-3,
        "did not recover from saturation: {end}"
    );
}

#[test]
fn encoder_quantization_puts_feedback_on_the_grid() {
    let mut p = plain();
    p.axes[0].encoder.quantize_motor = true;
    p.axes[0].encoder.motor_counts_per_rev = 1000; // 10 µm per count on a 10 mm lead
    let m = run(&p, "G90 G01 X0.1234 F100\nM30\n");
    let ferr = col_mm(&m.trace, "x.ferr");
    let cmd = col_mm(&m.trace, "x.cmd_comp");
    let fb: Vec<f64> = cmd.iter().zip(ferr).map(|(c, e)| c - e).collect();
    for v in fb {
        let counts = v / 0.01;
        assert!(
            (counts - counts.round()).abs() < 1e-6,
            "feedback {v} mm off the 10 µm grid"
        );
    }
}

#[test]
fn lead_error_table_is_interpolated_and_held() {
    let mut p = plain();
    let a = &mut p.axes[0];
    a.lead_error.enabled = true;
    a.lead_error.amplitude_um = 0.0;
    a.lead_error.table = vec![(0.0, 0.0), (50.0, 4.0), (100.0, -2.0)];
    let m = run(
        &p,
        "G90 G01 X25. F3000\nG04 P200\nX75.\nG04 P200\nX150.\nM30\n",
    );
    let tr = &m.trace;
    let le = col_mm(tr, "x.lead_err");
    let pos = col_mm(tr, "x.pos");
    for k in (0..tr.len()).step_by(997) {
        let x = pos[k] - le[k];
        let want = if x <= 0.0 {
            0.0
        } else if x <= 50.0 {
            0.004 * x / 50.0
        } else if x <= 100.0 {
            0.004 + (x - 50.0) / 50.0 * (-0.006)
        } else {
            -0.002
        };
        assert!(
            (le[k] - want).abs() < 1e-9,
            "lead error {} mm at x = {x}, expected {want}",
            le[k]
        );
    }
}

#[test]
fn stability_check_rejects_an_unstable_loop_and_accepts_the_presets() {
    let mut p = plain();
    assert!(axisbench::drive::check_stability(&p.axes[0], p.timing.t3_s).is_ok());
    // kv·α·T3/M far above 4 − 2α: the discrete velocity loop with its current lag diverges.
    p.axes[0].servo.kv_n_s_per_m = 5.0e8;
    p.axes[0].servo.torque_limit_nm = 1e9;
    let e = axisbench::drive::check_stability(&p.axes[0], p.timing.t3_s).expect_err("unstable");
    assert!(e.contains("unstable"), "{e}");
    // And the simulation really does diverge with those gains (the check is not just a rule).
    let mut m = axisbench::Machine::new(
        &plain(),
        &[("t".into(), "G05P4\nU0.01\nG04 P50\nM30\n".into())],
    )
    .expect("machine");
    m.axes[0].axis_loop.retune(&p.axes[0]);
    let r = m.run(0.05);
    assert!(
        matches!(r, Err(axisbench::machine::MachineError::Diverged { .. })),
        "an unstable loop stayed bounded: {r:?}"
    );
}

/// A servo-stage compensation that adds nothing: with it installed the axis is not plain,
/// so its loop takes the full step.
struct Nothing;

impl axisbench::comp::ServoComp for Nothing {
    fn name(&self) -> &str {
        "nothing"
    }
    fn axis(&self) -> usize {
        0
    }
    fn step(&mut self, _: &axisbench::comp::ServoCompCtx, _: &mut axisbench::comp::ServoCompOut) {}
    fn signals(&self) -> Vec<axisbench::comp::CompSignal> {
        vec![]
    }
    fn values(&self, _: &mut [f64]) {}
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

/// The plain step (the rarely used effects compiled out) is the full step to the bit, on the
/// inputs the default program gives the default preset's X axis.
#[test]
fn the_plain_step_computes_what_the_full_step_computes() {
    use axisbench::drive::AxisLoop;
    use axisbench::plant::Start;
    let lp = axisbench::preset::load_embedded("default.ron").expect("default preset");
    let p = &lp.preset;
    let programs = vec![(
        "default.ngc".to_owned(),
        lp.program_text("default.ngc").expect("program"),
    )];
    let inputs = axisbench::bench::recorded_inputs(p, &programs).expect("inputs");
    assert!(inputs.len() > 50_000, "{} inputs", inputs.len());
    let a = &p.axes[0];
    let x0 = inputs[0].cmd_raw_m;
    let start = Start::at_rest(a.servo.feedback.into(), x0);
    let mut plain = AxisLoop::new(a, p.timing.t3_s, start, x0, x0, vec![]);
    let mut full = AxisLoop::new(a, p.timing.t3_s, start, x0, x0, vec![Box::new(Nothing)]);
    assert!(
        plain.plant().is_plain(),
        "default.ron's X axis should be plain"
    );
    let (mut a_rows, mut b_rows) = (Vec::new(), Vec::new());
    plain.run(inputs.as_slice(), |_, l| {
        let s = l.sample();
        a_rows.push([
            s.plant.pos_m,
            s.plant.motor_enc_m,
            s.servo.force_n,
            s.plant.friction_n,
        ])
    });
    full.run(inputs.as_slice(), |_, l| {
        let s = l.sample();
        b_rows.push([
            s.plant.pos_m,
            s.plant.motor_enc_m,
            s.servo.force_n,
            s.plant.friction_n,
        ])
    });
    let moved = a_rows.iter().map(|r| (r[0] - x0).abs()).fold(0.0, f64::max);
    assert!(moved > 0.05, "the axis moved only {moved} m");
    for (k, (x, y)) in a_rows.iter().zip(&b_rows).enumerate() {
        let same = x.iter().zip(y).all(|(u, v)| u.to_bits() == v.to_bits());
        assert!(same, "row {k}: plain {x:?} vs full {y:?}");
    }
}

/// `Machine::run` stages trace rows and writes them in bursts; stepping one T3 at a time
/// writes each row at once. Both give the same trace, bit for bit.
#[test]
fn a_staged_run_records_the_trace_that_single_steps_record() {
    let lp = axisbench::preset::load_embedded("default.ron").expect("default preset");
    let mut a = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
    let mut b = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
    a.set_recording(true);
    b.set_recording(true);
    a.run(1.0).expect("run");
    while b.k < a.k {
        b.step();
    }
    // An odd number of rows, so the last stage was partly filled.
    assert!(
        a.trace.len() > 7_000 && !a.trace.len().is_multiple_of(128),
        "{}",
        a.trace.len()
    );
    assert_same_trace(&a.trace, &b.trace, "default.ron");
}

/// `Machine::run_steps` reserves the trace's room, so its flushes hold back the rows that
/// would end a column inside a cache line and carry them to the next flush. The trace still
/// comes out as single steps record it, bit for bit, and whole.
#[test]
fn a_run_that_holds_rows_back_for_whole_lines_records_what_single_steps_record() {
    let lp = axisbench::preset::load_embedded("default.ron").expect("default preset");
    let mut a = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
    let mut b = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
    a.set_recording(true);
    b.set_recording(true);
    let rows0 = a.trace.len();
    a.run_steps(30_001).expect("run");
    while b.k < a.k {
        b.step();
    }
    assert_eq!(a.trace.len(), rows0 + 30_001);
    assert_same_trace(&a.trace, &b.trace, "default.ron, run_steps");
}

/// With recording off, `Machine::run_block` lets the NC generate up to 128 T3 rows (16 T2
/// periods on default.ron) ahead of the axes when no position compensation reads the
/// machine at its tick. On every
/// shipped preset, a run to the end of its program, and a run in chunks of 1 237 steps
/// (which end blocks inside T2 periods), leave every axis where single steps leave it, bit
/// for bit, at the same step.
#[test]
fn the_nc_running_ahead_gives_the_steps_of_single_steps() {
    type State = Vec<[u64; 6]>;
    fn state(m: &axisbench::machine::Machine) -> State {
        m.axes
            .iter()
            .map(|a| {
                [
                    a.pos_m,
                    a.feedback_m(),
                    a.torque_nm(),
                    a.cmd_raw_m(),
                    a.cmd_m(),
                    a.axis_loop.plant().thermal().temp_c,
                ]
                .map(f64::to_bits)
            })
            .collect()
    }
    let mut cases = Vec::new();
    for (name, _) in axisbench::preset::EMBEDDED
        .iter()
        .filter(|(n, _)| n.ends_with(".ron"))
    {
        let lp = axisbench::preset::load_embedded(name).expect("preset");
        if *name == "default.ron" {
            // A PLC request 5 ms before the dwell after the first move ends (the command
            // leaves X100 at 2.2 s), inside a run-ahead block. A switch waits for the end
            // of a move or dwell, so a request handed over late would switch one move
            // later. And one while moving.
            use axisbench::preset::{Mode, PlcEvent};
            let mut l = lp.clone();
            l.preset.scenario.plc_events = [(2.1953, Mode::Direct), (3.00011, Mode::Normal)]
                .iter()
                .map(|&(t_s, mode)| PlcEvent {
                    t_s,
                    mode,
                    channel: 0,
                })
                .collect();
            cases.push((format!("{name} with PLC mode requests"), l));
        }
        cases.push((name.to_string(), lp));
    }
    for (name, lp) in cases {
        let max_s = 30.0003;
        let mut a = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
        let mut b = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
        a.set_recording(false);
        b.set_recording(false);
        a.run(max_s).expect("run");
        let max_k = (max_s / b.t3_s).ceil() as u64;
        while !b.done() && b.k < max_k {
            b.step();
        }
        assert_eq!(a.k, b.k, "{name}: the run ended at another step");
        assert_eq!(state(&a), state(&b), "{name}: the run to the end");

        let mut a = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
        let mut b = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
        a.set_recording(false);
        b.set_recording(false);
        for chunk in 0..24 {
            a.run_steps(1_237).expect("run");
            while b.k < a.k {
                b.step();
            }
            assert_eq!(state(&a), state(&b), "{name}: after chunk {chunk}");
        }
    }
}

/// Same columns, same rows, every value the same to the bit.
fn assert_same_trace(a: &axisbench::trace::Trace, b: &axisbench::trace::Trace, what: &str) {
    assert_eq!(a.signals.len(), b.signals.len(), "{what}");
    for (x, y) in a.signals.iter().zip(&b.signals) {
        assert_eq!(x.name, y.name, "{what}");
        assert_eq!(x.data.len(), y.data.len(), "{what}: {}", x.name);
        let same = x
            .data
            .iter()
            .zip(&y.data)
            .all(|(u, v)| u.to_bits() == v.to_bits());
        assert!(same, "{what}: column {} differs", x.name);
    }
}

/// `Machine::run` takes whole T2 periods axis by axis (`Machine::run_block`) where it may,
/// and single T3 steps where it may not (crossbeam, servo-stage compensations). On every
/// shipped preset, and with every third and seventh row recorded, a run to the end of its
/// program (or 30 s)
/// ends at the same step and records the same trace, bit for bit, as `Machine::step` taken
/// one T3 at a time with the same stopping rule.
#[test]
fn a_run_in_t2_blocks_ends_and_records_as_single_steps_do() {
    let mut cases = Vec::new();
    for (name, _) in axisbench::preset::EMBEDDED
        .iter()
        .filter(|(n, _)| n.ends_with(".ron"))
    {
        let lp = axisbench::preset::load_embedded(name).expect("preset");
        cases.push((name.to_string(), lp.clone()));
        if *name == "default.ron" || *name == "xy_circle.ron" {
            for every in [3, 7] {
                let mut l = lp.clone();
                l.preset.scenario.trace_every = every;
                cases.push((format!("{name} every {every}"), l));
            }
        }
    }
    for (what, lp) in cases {
        let max_s = 30.0003;
        let mut a = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
        let mut b = axisbench::machine::Machine::from_loaded(&lp).expect("machine");
        a.run(max_s).expect("run");
        let max_k = (max_s / b.t3_s).ceil() as u64;
        while !b.done() && b.k < max_k {
            b.step();
        }
        assert_eq!(a.k, b.k, "{what}: the run ended at another step");
        assert!(a.trace.len() > 10, "{what}: {} rows", a.trace.len());
        assert_same_trace(&a.trace, &b.trace, &what);
    }
}
