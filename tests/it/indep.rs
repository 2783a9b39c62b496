//! The independent case generator: its own physics, checked against analytic results, and
//! one end-to-end comparison with the project's model.

use axisbench::diagnose::replay::{Model, Record, simulate};
use axisbench::indep::control::Grid;
use axisbench::indep::friction::{StrokeLaw, StrokeState};
use axisbench::indep::profile::Profile;
use axisbench::indep::rig::{Payload, Rig, RigParams};
use axisbench::indep::run::{Logging, TrueMachine, run};
use axisbench::indep::shapes::SpringLaw;
use axisbench::indep::{
    self, Case, CaseKind, CaseSpec, EFFECTS, EffectPick, Mix, PosSensor, SkewChannel, SkewPick,
};
use axisbench::units::{m_to_mm, m_to_um, mm_to_m, um_to_m};
use std::process::Command;

/// A physics-check case: exact nominal machine, ideal sensors, fixed duration.
fn spec(seed: u64, effects: &[(&str, &str)], duration_s: f64) -> CaseSpec {
    let picks = effects
        .iter()
        .map(|(n, f)| EffectPick::new(n, Some(f)).expect("known effect"))
        .collect();
    let mut s = CaseSpec::new("t", seed, picks);
    s.duration_s = Some(duration_s);
    s.nominal_offset = false;
    s.ideal_sensors = true;
    s
}

fn make(s: &CaseSpec) -> Case {
    indep::generate(s).expect("case generates")
}

fn col<'a>(c: &'a Case, name: &str) -> &'a [f64] {
    c.trace.values(name).expect("column")
}

fn param(c: &Case, key: &str) -> f64 {
    c.truth.effects[0].params[key]
}

/// Commanded velocity per row from the set-point column (central difference), m/s.
fn cmd_vel(c: &Case) -> Vec<f64> {
    let x = col(c, "x.cmd");
    let t3 = c.preset.timing.t3_s;
    (0..x.len())
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(x.len() - 1));
            (x[b] - x[a]) / ((b - a).max(1) as f64 * t3)
        })
        .collect()
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    (s / n.max(1) as f64).sqrt()
}

/// The lines of Rust source in `text` that import a forbidden module of the crate.
fn forbidden_imports(text: &str) -> Vec<String> {
    const BANNED: [&str; 7] = [
        "servo", "plant", "drive", "machine", "nc", "comp", "diagnose",
    ];
    // Join statements so a `use crate::{…}` over several lines is one string.
    let flat: String = text
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join(" ");
    let mut bad = Vec::new();
    for stmt in flat.split(';') {
        let s: String = stmt.split_whitespace().collect::<Vec<_>>().join("");
        for root in ["crate::", "axisbench::", "super::super::"] {
            let mut rest = s.as_str();
            while let Some(i) = rest.find(root) {
                let tail = &rest[i + root.len()..];
                let names: Vec<&str> = if let Some(group) = tail.strip_prefix('{') {
                    group
                        .split(['}', ','])
                        .map(|n| n.split("::").next().unwrap_or(""))
                        .collect()
                } else {
                    vec![
                        tail.split([':', ',', '}', ')', '(', '<', '>', '.'])
                            .next()
                            .unwrap_or(""),
                    ]
                };
                if names.iter().any(|n| BANNED.contains(&n.trim())) {
                    bad.push(stmt.trim().to_owned());
                }
                rest = tail;
            }
        }
    }
    bad
}

#[test]
fn the_import_check_catches_every_spelling() {
    assert!(forbidden_imports("use crate::servo::Servo;").len() == 1);
    assert!(
        forbidden_imports("use crate::{\n  preset::Preset,\n  plant::AxisPlant,\n};").len() == 1
    );
    assert!(forbidden_imports("let x = crate::diagnose::eval::Rng::new(1);").len() == 1);
    assert!(forbidden_imports("use crate::nc;").len() == 1);
    assert!(forbidden_imports("use crate::{units::mm_to_m, trace::Trace};").is_empty());
    assert!(
        forbidden_imports("use crate::preset::{Preset, PosSource}; // not crate::plant").is_empty()
    );
}

#[test]
fn indep_sources_import_no_model_code() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src/indep");
    let mut files = 0;
    for entry in std::fs::read_dir(&dir).expect("src/indep exists") {
        let path = entry.expect("entry").path();
        if path.extension().is_some_and(|e| e == "rs") {
            files += 1;
            let text = std::fs::read_to_string(&path).expect("readable");
            let bad = forbidden_imports(&text);
            assert!(bad.is_empty(), "{}: {bad:?}", path.display());
        }
    }
    assert!(files >= 8, "only {files} files in src/indep");
}

#[test]
fn viscous_open_loop_push_reaches_f_over_c() {
    let (m_r, m_c, c) = (5.0, 90.0, 200.0);
    let mut rig = Rig::new(RigParams::rigid(m_r, m_c, c), 0.0, 0.0);
    let f = 50.0;
    let tau = (m_r + m_c) / c;
    let mut t = 0.0;
    for step_s in [0.1, 0.4, 1.0, 3.0] {
        rig.push(f, t, step_s, 1e-4);
        t += step_s;
        let v = rig.bodies().motor_mps;
        let exact = f / c * (1.0 - (-t / tau).exp());
        let x_exact = f / c * (t - tau * (1.0 - (-t / tau).exp()));
        assert!((v - exact).abs() < 1e-10, "t={t}: v={v} exact={exact}");
        assert!((rig.bodies().motor_m - x_exact).abs() < 1e-10);
    }
    // After 4.5 s ≈ 9.5 time constants the speed is F/c to 1e-4.
    let v = rig.bodies().carriage_mps;
    assert!((v - f / c).abs() < 1e-4 * f / c, "v = {v}, F/c = {}", f / c);
}

#[test]
fn stick_holds_below_the_coulomb_level_and_slides_above_it() {
    let mut p = RigParams::rigid(5.0, 90.0, 200.0);
    p.friction.coulomb_pos_n = 30.0;
    p.friction.coulomb_neg_n = 30.0;
    let mut rig = Rig::new(p, 0.01, 0.0);
    rig.push(29.0, 0.0, 0.5, 1e-4);
    assert!(rig.is_stuck());
    assert_eq!(rig.bodies().motor_m, 0.01, "no creep while stuck");
    rig.push(40.0, 0.5, 0.05, 1e-4);
    assert!(!rig.is_stuck());
    // Sliding from rest: (F − Fc)/M·t less the viscous term, exactly v(t) of the linear law.
    let tau: f64 = 95.0 / 200.0;
    let exact = (40.0 - 30.0) / 200.0 * (1.0 - (-0.05 / tau).exp());
    let v = rig.bodies().motor_mps;
    assert!((v - exact).abs() < 1e-4 * exact, "v {v} vs {exact}");
    // Released, it stops and stays stopped.
    rig.push(0.0, 0.55, 0.5, 1e-4);
    assert!(rig.is_stuck());
    let x = rig.bodies().motor_m;
    rig.push(-25.0, 1.05, 0.5, 1e-4);
    assert_eq!(rig.bodies().motor_m, x);
}

#[test]
fn payload_spring_rings_at_its_resonance() {
    let (m_r, m_c, m_p, k) = (5.0, 50.0, 40.0, 4.0e6);
    let mut p = RigParams::rigid(m_r, m_c, 0.0);
    p.payload = Some(Payload {
        mass_kg: m_p,
        spring: SpringLaw::Linear { k_n_per_m: k },
        damping_n_s_per_m: 0.0,
    });
    let mut rig = Rig::new(p, 0.0, 0.0);
    rig.push(500.0, 0.0, 0.002, 1e-5);
    let (mut t, h) = (0.002, 1e-5);
    let mut crossings = Vec::new();
    let mut last = rig.bodies().payload_m - rig.bodies().carriage_m;
    rig.command(0.0);
    while t < 0.5 {
        rig.substep(t, h);
        t += h;
        let d = rig.bodies().payload_m - rig.bodies().carriage_m;
        if last < 0.0 && d >= 0.0 {
            crossings.push(t);
        }
        last = d;
    }
    let period = (crossings[crossings.len() - 1] - crossings[0]) / (crossings.len() - 1) as f64;
    let m_red = (m_r + m_c) * m_p / (m_r + m_c + m_p);
    let f_exact = (k / m_red).sqrt() / std::f64::consts::TAU;
    assert!(
        (1.0 / period - f_exact).abs() < 1e-3 * f_exact,
        "rings at {} Hz, expected {f_exact} Hz",
        1.0 / period
    );
}

#[test]
fn rk4_converges_when_the_substep_is_halved() {
    let mut figures = Vec::new();
    for effects in [
        vec![("compliance", "linear"), ("coulomb_friction", "tanh")],
        vec![
            ("coulomb_friction", "sign_stick"),
            ("stribeck_friction", "gaussian"),
        ],
    ] {
        let runs: Vec<Case> = [10, 20, 40, 80]
            .iter()
            .map(|n| {
                let mut s = spec(7, &effects, 8.0);
                s.substeps = Some(*n);
                make(&s)
            })
            .collect();
        let diff = |a: &Case, b: &Case| {
            let p = col(a, "x.pos")
                .iter()
                .zip(col(b, "x.pos"))
                .map(|(x, y)| (x - y).abs());
            let f = col(a, "x.force")
                .iter()
                .zip(col(b, "x.force"))
                .map(|(x, y)| (x - y).abs());
            (m_to_um(p.fold(0.0, f64::max)), f.fold(0.0, f64::max))
        };
        let errs: Vec<(f64, f64)> = (0..3).map(|i| diff(&runs[i], &runs[3])).collect();
        figures.push((effects.clone(), errs.clone()));
        // 20 sub-steps (50 µs) against 80: positions agree to 1e-4 µm and forces to 1 mN,
        // far below the 0.05 µm encoder step and the force noise.
        assert!(
            errs[1].0 < 1e-4 && errs[1].1 < 1e-3,
            "{effects:?}: {errs:?}"
        );
        // And the differences shrink as the step does.
        assert!(
            errs[2].0 <= errs[0].0 && errs[2].1 <= errs[0].1,
            "{effects:?}: {errs:?}"
        );
    }
    // The smooth case converges at fourth order: 10 → 20 sub-steps gains ≥ 8×.
    let smooth = &figures[0].1;
    assert!(smooth[0].0 > 8.0 * smooth[1].0, "{figures:?}");
    println!("RK4 max |Δpos| µm, max |ΔF| N against 80 sub-steps (10, 20, 40): {figures:?}");
}

#[test]
fn clean_ramp_following_error_is_v_over_kp_plus_viscous_share() {
    let preset = indep::nominal::nominal_preset(PosSensor::MotorEncoder).expect("preset");
    let mut m: TrueMachine =
        indep::nominal::exact_machine(&preset, PosSensor::MotorEncoder).expect("machine");
    m.encoder = Grid::EXACT;
    let v = 0.05;
    let profile = Profile::ramp(0.02, 0.1, v, 3.0);
    let log = Logging {
        pos_noise_m: 0.0,
        force_noise_n: 0.0,
        skew: None,
        seed: 1,
    };
    let out = run(&m, &profile, 2500, &log, None).expect("runs");
    let (kp, kv, c) = (
        m.gains.kp_per_s,
        m.gains.kv_n_s_per_m,
        m.rig.friction.viscous_n_s_per_m,
    );
    // Steady ramp of a P position / P velocity loop on a viscous load: the velocity loop
    // must hold F = c·v, so kv·(kp·e − v) = c·v and e = v/kp·(1 + c/kv).
    let expected = v / kp * (1.0 + c / kv);
    let e = out.cmd_m[2400] - out.pos_m[2400];
    assert!(
        (e - expected).abs() < 1e-4 * expected,
        "error {e} m, expected {expected} m"
    );
    // Without the viscous share it would be 2.4 % smaller: the check tells them apart.
    assert!((e - v / kp).abs() > 0.02 * expected);
    assert!(
        (out.force_n[2400] - c * v).abs() < 1e-3 * c * v,
        "F {}",
        out.force_n[2400]
    );
}

#[test]
fn same_seed_gives_a_bit_identical_trace() {
    let mut s = CaseSpec::new(
        "d",
        42,
        vec![EffectPick::new("backlash", None).expect("known")],
    );
    s.duration_s = Some(5.0);
    s.skew = SkewPick::Random;
    let (a, b) = (make(&s), make(&s));
    for (x, y) in a.trace.signals.iter().zip(&b.trace.signals) {
        assert!(
            x.data
                .iter()
                .zip(&y.data)
                .all(|(p, q)| p.to_bits() == q.to_bits()),
            "{}",
            x.name
        );
    }
    assert_eq!(a.truth, b.truth);
    s.seed = 43;
    let c = make(&s);
    assert_ne!(col(&a, "x.pos"), col(&c, "x.pos"));
}

#[test]
fn coulomb_friction_adds_its_level_against_the_motion() {
    let clean = make(&spec(11, &[], 40.0));
    for formula in ["sign_stick", "tanh"] {
        let c = make(&spec(11, &[("coulomb_friction", formula)], 40.0));
        let (fp, fneg) = (param(&c, "force_pos_n"), param(&c, "force_neg_n"));
        let v = cmd_vel(&c);
        let (mut up, mut down) = (Vec::new(), Vec::new());
        for i in 0..v.len() {
            let d = col(&c, "x.force")[i] - col(&clean, "x.force")[i];
            // Steady motion (20 ms after any change of commanded speed).
            let steady = (i.saturating_sub(20)..=i).all(|j| (v[j] - v[i]).abs() < 1e-6);
            if steady && v[i] > 0.005 {
                up.push(d);
            } else if steady && v[i] < -0.005 {
                down.push(d);
            }
        }
        let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len().max(1) as f64;
        assert!(
            up.len() > 50 && down.len() > 50,
            "{formula}: {} {}",
            up.len(),
            down.len()
        );
        assert!(
            (mean(&up) - fp).abs() < 0.02 * fp,
            "{formula}: + {} vs {fp}",
            mean(&up)
        );
        assert!(
            (mean(&down) + fneg).abs() < 0.02 * fneg,
            "{formula}: − {} vs {fneg}",
            mean(&down)
        );
    }
}

#[test]
fn viscous_friction_adds_force_proportional_to_speed() {
    let clean = make(&spec(12, &[], 20.0));
    let c = make(&spec(12, &[("viscous_friction", "linear")], 20.0));
    let dc = param(&c, "viscous_n_s_per_m");
    let v = cmd_vel(&c);
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for i in 20..v.len() {
        let steady = (i - 20..=i).all(|j| (v[j] - v[i]).abs() < 1e-6);
        if steady && v[i].abs() > 0.005 {
            let d = col(&c, "x.force")[i] - col(&clean, "x.force")[i];
            sxy += d * v[i];
            sxx += v[i] * v[i];
        }
    }
    let slope = sxy / sxx;
    assert!(
        (slope - dc).abs() < 0.03 * dc.abs(),
        "slope {slope} vs {dc} N·s/m"
    );
}

#[test]
fn stribeck_excess_shows_at_creep_speed_only() {
    for formula in ["exponential", "gaussian"] {
        let clean = make(&spec(13, &[], 30.0));
        let c = make(&spec(13, &[("stribeck_friction", formula)], 30.0));
        let (excess, vs) = (
            param(&c, "breakaway_excess_n"),
            param(&c, "velocity_mm_per_s"),
        );
        let shape = |s: f64| match formula {
            "gaussian" => (-(s / vs) * (s / vs)).exp(),
            _ => (-s / vs).exp(),
        };
        let v = cmd_vel(&c);
        let (mut slow, mut fast) = (Vec::new(), Vec::new());
        for i in 200..v.len() {
            // Steady for 200 ms: the decaying stick-slip oscillation of the negative
            // friction slope has settled to its mean.
            let steady = (i - 200..=i).all(|j| (v[j] - v[i]).abs() < 1e-6);
            let s = m_to_mm(v[i].abs());
            let d = (col(&c, "x.force")[i] - col(&clean, "x.force")[i]) * v[i].signum();
            if steady && s > 0.1 && s < 2.0 * vs {
                slow.push(d - excess * shape(s));
            } else if steady && s > 10.0 * vs {
                fast.push(d);
            }
        }
        let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len().max(1) as f64;
        assert!(
            slow.len() > 50 && fast.len() > 50,
            "{formula}: {} {}",
            slow.len(),
            fast.len()
        );
        assert!(
            mean(&slow).abs() < 0.05 * excess,
            "{formula}: creep excess off by {}",
            mean(&slow)
        );
        assert!(
            mean(&fast).abs() < 0.01 * excess,
            "{formula}: fast {}",
            mean(&fast)
        );
    }
}

#[test]
fn stroke_levels_follow_their_formulas() {
    let (max_n, pitch, n0, rec) = (40.0, 0.005, 2.0, 0.02);
    let count = StrokeLaw::Count {
        max_n,
        pitch_m: pitch,
        n0,
        recovery_m: rec,
    };
    let dist = StrokeLaw::Distance {
        max_n,
        pitch_m: pitch,
        breakdown_m: 0.004,
        recovery_m: rec,
    };
    let (mut a, mut b) = (StrokeState::new(0.0), StrokeState::new(0.0));
    // Strokes of 2 mm back and forth, 0.1 mm per period.
    let mut x = 0.0;
    let mut dir = 1.0;
    let mut levels = Vec::new();
    for k in 0..200 {
        if k > 0 && k % 20 == 0 {
            dir = -dir;
            levels.push((a.force_n(&count), b.force_n(&dist)));
        }
        x += dir * 1e-4;
        a.update(&count, x, dir * 0.1);
        b.update(&dist, x, dir * 0.1);
    }
    // n short strokes completed at the n-th turn after the first: F·(1 − e^(−n/n0)).
    for (i, (fc, _)) in levels.iter().enumerate() {
        let want = max_n * (1.0 - (-(i as f64) / n0).exp());
        assert!((fc - want).abs() < 1e-9, "turn {i}: {fc} vs {want}");
    }
    // The film breaks down with the distance run in short strokes (0.2 mm·k so far).
    for (i, (_, fd)) in levels.iter().enumerate() {
        let want = max_n * (1.0 - (-0.002 * (i + 1) as f64 / 0.004).exp());
        assert!((fd - want).abs() < 1e-6 * max_n, "turn {i}: {fd} vs {want}");
    }
    // A long stroke of pitch + 3 recovery lengths: the count decays by e^3 at the next
    // reversal, the film by e^(−3) beyond the pitch.
    let (n_before, phi_before) = (a.force_n(&count), b.force_n(&dist));
    for _ in 0..((pitch + 3.0 * rec) / 1e-4).round() as usize {
        x += dir * 1e-4;
        a.update(&count, x, dir * 0.1);
        b.update(&dist, x, dir * 0.1);
    }
    a.update(&count, x - 1e-4, -dir * 0.1);
    assert!(
        a.force_n(&count) < 0.2 * n_before,
        "{} vs {n_before}",
        a.force_n(&count)
    );
    assert!(
        b.force_n(&dist) < 0.06 * phi_before,
        "{} vs {phi_before}",
        b.force_n(&dist)
    );
}

#[test]
fn stroke_friction_only_adds_friction_and_shows_after_short_strokes() {
    for formula in ["count", "distance"] {
        let clean = make(&spec(14, &[], 40.0));
        let c = make(&spec(14, &[("stroke_friction", formula)], 40.0));
        let v = cmd_vel(&c);
        let mut against = Vec::new();
        for i in 50..v.len() {
            let steady = (i - 50..=i).all(|j| (v[j] - v[i]).abs() < 1e-6);
            if steady && v[i].abs() > 0.002 {
                against.push((col(&c, "x.force")[i] - col(&clean, "x.force")[i]) * v[i].signum());
            }
        }
        let peak = against.iter().copied().fold(0.0, f64::max);
        let least = against.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(peak > 5.0, "{formula}: no rise, peak {peak} N");
        assert!(
            least > -0.5,
            "{formula}: friction pulled along the motion by {least} N"
        );
    }
}

#[test]
fn backlash_keeps_the_carriage_within_the_gap_and_reaches_both_flanks() {
    for formula in ["rigid_lost_motion", "two_mass_dead_zone"] {
        let mut s = spec(15, &[("backlash", formula)], 20.0);
        s.pos_sensor = PosSensor::LinearScale;
        let c = make(&s);
        let half = um_to_m(param(&c, "width_um")) / 2.0;
        let sig = &c.signals;
        let t3 = c.preset.timing.t3_s;
        let speed = |x: &[f64]| {
            x.windows(2)
                .map(|w| (w[1] - w[0]).abs() / t3)
                .fold(0.0, f64::max)
        };
        // The contact spring gives way by at most the force limit plus the impact of the
        // fastest closing speed: (F_max + v·√(k·m_red))/k, with m_red ≤ the 5 kg rotor.
        let give = match c.truth.effects[0].params.get("contact_stiffness_n_per_um") {
            Some(k) => {
                let k = axisbench::units::n_per_um_to_n_per_m(*k);
                let v = speed(&sig.motor_m) + speed(&sig.carriage_m);
                (360.0 + v * (k * 5.0).sqrt()) / k
            }
            None => 1e-12,
        };
        let gaps: Vec<f64> = (0..sig.motor_m.len())
            .map(|i| sig.motor_m[i] - sig.carriage_m[i])
            .collect();
        let (lo, hi) = gaps
            .iter()
            .fold((0.0_f64, 0.0_f64), |(l, h), g| (l.min(*g), h.max(*g)));
        assert!(
            hi <= half + give && lo >= -half - give,
            "{formula}: gap {lo}…{hi}, half {half}"
        );
        assert!(
            hi > 0.98 * half && lo < -0.98 * half,
            "{formula}: flanks not reached: {lo}…{hi}"
        );
        // The scale shows it: the scale minus the motor encoder spans the gap.
        let seen: Vec<f64> = (0..gaps.len())
            .map(|i| col(&c, "x.pos")[i] - sig.motor_m[i])
            .collect();
        let span = seen.iter().fold(f64::MIN, |m, x| m.max(*x))
            - seen.iter().fold(f64::MAX, |m, x| m.min(*x));
        assert!(span > 1.96 * half, "{formula}: scale − motor spans {span}");
    }
}

#[test]
fn constant_force_shifts_the_force_by_its_value() {
    let clean = make(&spec(16, &[], 20.0));
    let c = make(&spec(16, &[("constant_force", "constant")], 20.0));
    let f0 = param(&c, "force_n");
    let v = cmd_vel(&c);
    let d: Vec<f64> = (100..v.len())
        .filter(|i| (i - 100..=*i).all(|j| v[j] == 0.0))
        .map(|i| col(&c, "x.force")[i] - col(&clean, "x.force")[i])
        .collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    // The motor holds the load at rest: its force is −F0 more.
    assert!((mean + f0).abs() < 0.01 * f0.abs(), "{mean} vs {f0}");
}

#[test]
fn thermal_growth_moves_the_scale_slowly_by_the_stated_amount() {
    for formula in ["speed_heat", "dissipated_power"] {
        let mut s = spec(17, &[("thermal_growth", formula)], 30.0);
        s.pos_sensor = PosSensor::LinearScale;
        let c = make(&s);
        let mut s0 = spec(17, &[], 30.0);
        s0.pos_sensor = PosSensor::LinearScale;
        let clean = make(&s0);
        let d: Vec<f64> = col(&c, "x.pos")
            .iter()
            .zip(col(&clean, "x.pos"))
            .map(|(a, b)| a - b)
            .collect();
        let peak = d.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
        let want = param(&c, "growth_max_um");
        assert!(
            (m_to_um(peak) - want).abs() < 0.01 * want,
            "{formula}: {peak} m vs {want} µm"
        );
        // Slow: from one sample to the next the growth moves by far less than its size.
        let jump = d
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .fold(0.0, f64::max);
        assert!(jump < 1e-3 * peak + 1e-12, "{formula}: jump {jump} m");
        // The motor encoder does not see it.
        assert!(
            c.signals
                .motor_m
                .iter()
                .zip(&clean.signals.motor_m)
                .all(|(a, b)| a == b)
        );
    }
}

#[test]
fn lead_error_puts_the_carriage_where_the_formula_says() {
    let mut s = spec(18, &[("lead_error", "harmonic")], 20.0);
    s.pos_sensor = PosSensor::LinearScale;
    let c = make(&s);
    let p = &c.truth.effects[0].params;
    let pitch = mm_to_m(p["pitch_mm"]);
    let e = |u: f64| {
        (1..=3)
            .map(|h| {
                um_to_m(p[&format!("amplitude_{h}_um")])
                    * (std::f64::consts::TAU * h as f64 * u / pitch + p[&format!("phase_{h}_rad")])
                        .sin()
            })
            .sum::<f64>()
            + um_to_m(p["cumulative_um_per_m"]) * u
    };
    let sig = &c.signals;
    let worst = (0..sig.motor_m.len())
        .map(|i| (sig.carriage_m[i] - sig.motor_m[i] - e(sig.motor_m[i])).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-12, "carriage − motor − e(motor) up to {worst} m");
    // The error is really there, at its drawn size: over a travel of several pitches the
    // carriage leads and lags the motor by about twice the first harmonic's amplitude.
    let a1_um = p["amplitude_1_um"];
    assert!(a1_um <= 6.0, "first harmonic {a1_um} µm, drawn from 1–6 µm");
    let d: Vec<f64> = (0..sig.motor_m.len())
        .map(|i| {
            sig.carriage_m[i] - sig.motor_m[i] - um_to_m(p["cumulative_um_per_m"]) * sig.motor_m[i]
        })
        .collect();
    let spread_um = (d.iter().fold(f64::MIN, |a, &b| a.max(b))
        - d.iter().fold(f64::MAX, |a, &b| a.min(b)))
        * 1e6;
    assert!(
        spread_um >= 1.5 * a1_um,
        "carriage − motor spans {spread_um} µm for a first harmonic of {a1_um} µm"
    );
}

#[test]
fn quantization_puts_every_position_on_the_grid() {
    for (formula, sensor) in [
        ("round", PosSensor::MotorEncoder),
        ("truncate", PosSensor::LinearScale),
    ] {
        let mut s = spec(19, &[("quantization", formula)], 10.0);
        s.pos_sensor = sensor;
        s.ideal_sensors = false;
        let c = make(&s);
        let q = param(&c, "resolution_um");
        let off = col(&c, "x.pos")
            .iter()
            .map(|x| {
                let n = m_to_um(*x) / q;
                (n - n.round()).abs()
            })
            .fold(0.0, f64::max);
        assert!(off < 1e-6, "{formula}: {off} of a step off the grid");
        if formula == "truncate" {
            // Truncation reads low: on average half a step below the true position.
            let bias: f64 = col(&c, "x.pos")
                .iter()
                .zip(&c.signals.carriage_m)
                .map(|(p, x)| p - x)
                .sum::<f64>()
                / c.signals.carriage_m.len() as f64;
            assert!(
                (bias + um_to_m(q) / 2.0).abs() < um_to_m(q) * 0.1,
                "bias {bias} m, step {q} µm"
            );
        }
    }
}

#[test]
fn command_delay_shifts_the_response_by_the_delay() {
    let clean = make(&spec(20, &[], 20.0));
    let c = make(&spec(20, &[("command_delay", "pure_delay")], 20.0));
    let d = param(&c, "delay_samples");
    let v = cmd_vel(&c);
    let t3 = c.preset.timing.t3_s;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (i, vi) in v.iter().enumerate() {
        let dp = col(&c, "x.pos")[i] - col(&clean, "x.pos")[i];
        sxy += -dp * vi;
        sxx += vi * vi;
    }
    let est = sxy / sxx / t3;
    assert!(
        (est - d).abs() < 0.05 * d + 0.02,
        "delay {est} samples vs {d}"
    );
}

/// |DFT| of `x` at `f_hz` (sampled at `t3_s`), mean removed.
fn dft(x: &[f64], t3_s: f64, f_hz: f64) -> f64 {
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let (mut re, mut im) = (0.0, 0.0);
    for (i, v) in x.iter().enumerate() {
        let a = std::f64::consts::TAU * f_hz * i as f64 * t3_s;
        re += (v - mean) * a.cos();
        im += (v - mean) * a.sin();
    }
    re.hypot(im)
}

#[test]
fn periodic_disturbance_spectrum_peaks_at_its_period() {
    for formula in ["square", "sine"] {
        let clean = make(&spec(21, &[], 40.0));
        let c = make(&spec(21, &[("external_disturbance", formula)], 40.0));
        let period = param(&c, "period_s");
        let d: Vec<f64> = col(&c, "x.force")
            .iter()
            .zip(col(&clean, "x.force"))
            .map(|(a, b)| a - b)
            .collect();
        let t3 = c.preset.timing.t3_s;
        let (best, _) = (1..400)
            .map(|i| 0.05 * i as f64)
            .map(|f| (f, dft(&d, t3, f)))
            .fold((0.0, 0.0), |b, x| if x.1 > b.1 { x } else { b });
        assert!(
            (best - 1.0 / period).abs() < 0.06 / period.min(1.0) + 0.05,
            "{formula}: peak at {best} Hz, period {period} s"
        );
    }
}

#[test]
fn a_pos_skew_of_one_sample_shifts_that_channel_only() {
    let base = spec(22, &[], 5.0);
    let mut late = base.clone();
    late.skew = SkewPick::Fixed(SkewChannel::Pos, 1.0);
    let (a, b) = (make(&base), make(&late));
    let (pa, pb) = (col(&a, "x.pos"), col(&b, "x.pos"));
    let worst = (0..pa.len() - 1)
        .map(|i| (pb[i] - pa[i + 1]).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-12, "pos[k] late vs pos[k+1]: {worst} m");
    assert_eq!(col(&a, "x.force"), col(&b, "x.force"));
    assert_eq!(col(&a, "x.cmd"), col(&b, "x.cmd"));
    assert_eq!((b.truth.skew_channel, b.truth.skew_samples), ("pos", 1.0));
    let mut half = base.clone();
    half.skew = SkewPick::Fixed(SkewChannel::Cmd, -0.5);
    let h = make(&half);
    let ch = col(&h, "x.cmd");
    let ca = col(&a, "x.cmd");
    // Half a sample early sits between the neighbours on a ramp.
    let moving = (1..ca.len())
        .find(|i| (ca[*i] - ca[*i - 1]).abs() > 1e-6)
        .expect("moves");
    let i = moving + 100;
    assert!((ch[i] - 0.5 * (ca[i] + ca[i - 1])).abs() < 1e-3 * (ca[i] - ca[i - 1]).abs() + 1e-12);
}

#[test]
fn clean_case_replays_through_the_project_model() {
    let residual = |c: &Case| {
        let rec =
            Record::from_trace(&c.trace, "indep", "x", None, c.preset.timing.t3_s).expect("record");
        let model = Model {
            axis: c.preset.axes[0].clone(),
            t3_s: c.preset.timing.t3_s,
            t2_s: c.preset.timing.t2_s,
            t1_s: c.preset.timing.t1_s,
            pos_source: c.preset.diagnose.pos_source,
            delay_s: 0.0,
            lag_s: 0.0,
            pos_interval_m: 0.0,
            disturbance: vec![],
            beam: None,
        };
        let sim = simulate(&model, &rec, rec.len());
        let force = rec.force_n.as_ref().expect("force");
        let pos_um = rms((0..rec.len()).map(|i| m_to_um(sim.pos_m[i] - rec.pos_m[i])));
        let force_n = rms((0..rec.len()).map(|i| sim.force_n[i] - force[i]));
        let follow_um = rms((0..rec.len()).map(|i| m_to_um(rec.cmd_m[i] - rec.pos_m[i])));
        let force_rms = rms(force.iter().copied());
        (pos_um, force_n, follow_um, force_rms)
    };
    // Same machine, same gains, ideal sensors: only the two integrators differ.
    let exact = make(&spec(23, &[], 40.0));
    let (p0, f0, follow, frms) = residual(&exact);
    println!(
        "clean, exact nominal: residual pos {p0:.3} µm rms, force {f0:.3} N rms (following error {follow:.1} µm rms, force {frms:.1} N rms)"
    );
    assert!(p0 < 2.0 && f0 < 2.0, "exact nominal: {p0} µm, {f0} N");
    // The cases as generated: nominal off by 1–5 %, noise and the 50 nm encoder.
    let mut s = CaseSpec::new("c", 23, vec![]);
    s.duration_s = Some(40.0);
    let offset = make(&s);
    let (p1, f1, follow, frms) = residual(&offset);
    println!(
        "clean, nominal off 1–5 %: residual pos {p1:.3} µm rms, force {f1:.3} N rms (following error {follow:.1} µm rms, force {frms:.1} N rms)"
    );
    assert!(
        p1 < 0.1 * follow && f1 < 0.2 * frms,
        "offset nominal: {p1} µm, {f1} N"
    );
    assert!(p1 > p0, "the nominal offset must show");
}

#[test]
fn standard_set_covers_every_effect_formula_and_kind() {
    let set = indep::standard_set(5, 30.0);
    assert_eq!(set.len(), 2 * (12 + 4 * EFFECTS.len() + 12));
    for (name, formulas) in EFFECTS {
        for f in *formulas {
            assert!(
                set.iter().any(|s| s.effects.len() == 1
                    && s.effects[0].name == *name
                    && s.effects[0].formula == Some(*f)),
                "{name}/{f} missing"
            );
        }
    }
    for kind in CaseKind::ALL {
        assert!(
            set.iter().filter(|s| CaseKind::of(s) == kind).count() >= 12,
            "{}",
            kind.name()
        );
    }
    let mut names: Vec<&str> = set.iter().map(|s| s.name.as_str()).collect();
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), set.len());
    assert!(
        set.iter()
            .all(|s| !s.name.contains("friction") && s.nominal_offset)
    );
    // Lead error and thermal growth are logged on the scale, which sees them.
    for s in &set {
        if s.effects
            .iter()
            .any(|e| matches!(e.name, "lead_error" | "thermal_growth"))
        {
            assert_eq!(s.pos_sensor, PosSensor::LinearScale, "{}", s.name);
        }
    }
    assert!(set.iter().any(|s| CaseKind::of(s).mix == Mix::Pair));
}

#[test]
fn every_effect_and_formula_generates_and_is_quick() {
    let t0 = std::time::Instant::now();
    let mut n = 0;
    for (name, formulas) in EFFECTS {
        for f in *formulas {
            let mut s = CaseSpec::new(
                "e",
                30,
                vec![EffectPick::new(name, Some(f)).expect("known")],
            );
            s.duration_s = Some(6.0);
            let c = make(&s);
            assert_eq!(c.truth.effects[0].formula, *f);
            assert!(col(&c, "x.pos").iter().all(|x| x.is_finite()));
            n += 1;
        }
    }
    let per_minute = t0.elapsed().as_secs_f64() / (6.0 * n as f64) * 60.0;
    println!("{n} effect formulas; {per_minute:.3} s of generation per minute of record");
    if !cfg!(debug_assertions) {
        assert!(per_minute < 1.0, "{per_minute} s per 60 s case");
    }
}

#[test]
fn bad_specs_are_refused_with_the_reason() {
    let mut s = CaseSpec::new("bad", 1, vec![]);
    s.duration_s = Some(f64::NAN);
    let e = indep::generate(&s).expect_err("NaN duration").to_string();
    assert!(e.contains("duration"), "{e}");
    s.duration_s = Some(5.0);
    s.noise.force_n = -1.0;
    assert!(
        indep::generate(&s)
            .expect_err("negative noise")
            .to_string()
            .contains("force noise")
    );
    s.noise.force_n = 0.1;
    s.skew = SkewPick::Fixed(SkewChannel::Pos, 2.0);
    assert!(
        indep::generate(&s)
            .expect_err("skew")
            .to_string()
            .contains("skew")
    );
    s.skew = SkewPick::None;
    s.effects = vec![
        EffectPick::new("backlash", None).expect("known"),
        EffectPick::new("backlash_asymmetry", None).expect("known"),
    ];
    assert!(indep::generate(&s).is_err());
    assert!(EffectPick::new("beam_sag", None).is_none());
    assert!(EffectPick::new("backlash", Some("elastic")).is_none());
}

#[test]
fn gen_cases_writes_cases_the_diagnosis_reads() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path().join("axisbench-indep");
    let bin = env!("CARGO_BIN_EXE_axisbench");
    let o = Command::new(bin)
        .args([
            "gen-cases",
            "--seed",
            "3",
            "--duration",
            "4",
            "--kind",
            "clean",
            "--out",
        ])
        .arg(&dir)
        .output()
        .expect("runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let truth = std::fs::read_to_string(dir.join("truth.json")).expect("truth.json");
    let json: serde_json::Value = serde_json::from_str(&truth).expect("valid JSON");
    let cases = json["cases"].as_array().expect("cases");
    assert_eq!(cases.len(), 12);
    assert_eq!(cases[0]["kind"], "clean");
    let d = Command::new(bin)
        .args(["diagnose", "--preset"])
        .arg(dir.join("case_000.ron"))
        .arg("--trace")
        .arg(dir.join("case_000.csv"))
        .output()
        .expect("runs");
    assert!(d.status.success(), "{}", String::from_utf8_lossy(&d.stderr));
    assert!(String::from_utf8_lossy(&d.stdout).contains("VERDICT"));
    for bad in [
        ["--duration", "NaN"],
        ["--duration", "0"],
        ["--kind", "double"],
    ] {
        let o = Command::new(bin)
            .args(["gen-cases", "--out"])
            .arg(&dir)
            .args(bad)
            .output()
            .expect("runs");
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(bad[0]), "{err}");
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// `gen-cases` writes, byte for byte, the records `diagnose-eval` scores for the same seed
/// (one default duration, one case list).
#[test]
fn gen_cases_writes_the_records_the_eval_scores() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path().join("cases");
    let o = Command::new(env!("CARGO_BIN_EXE_axisbench"))
        .args(["gen-cases", "--seed", "5", "--kind", "clean", "--out"])
        .arg(&dir)
        .output()
        .expect("runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let specs = indep::standard_set(5, indep::STANDARD_DURATION_S);
    for i in [0, 7] {
        let c = make(&specs[i]);
        let mut expected = Vec::new();
        c.trace.write_csv_to(&mut expected).expect("in memory");
        let written = std::fs::read(dir.join(format!("{}.csv", c.name))).expect("written");
        assert!(
            written == expected,
            "{}: gen-cases wrote another record than the eval's",
            c.name
        );
    }
}

/// A case that cannot be generated part-way through the set leaves the folder as it was:
/// the earlier cases' files are not left behind, the previous truth.json stays.
#[test]
fn gen_cases_writes_all_cases_or_none() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path();
    std::fs::write(dir.join("truth.json"), "previous").expect("seed file");
    let mut specs: Vec<CaseSpec> = indep::standard_set(5, 2.0).into_iter().take(3).collect();
    specs[2].duration_s = Some(f64::NAN);
    let mut started = Vec::new();
    let err = indep::write_cases(dir, &specs, &mut |i, _| started.push(i))
        .expect_err("the third case is out of range");
    assert_eq!(started, vec![0, 1, 2], "the first two were generated");
    assert!(err.to_string().contains("case_002"), "{err}");
    let mut left: Vec<String> = std::fs::read_dir(dir)
        .expect("folder")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, vec!["truth.json".to_owned()]);
    assert_eq!(
        std::fs::read_to_string(dir.join("truth.json")).expect("kept"),
        "previous"
    );
}
