//! The seed compensations: exact behaviour of each state machine, and their effect on the
//! shipped scenarios.

use axisbench::Machine;
use axisbench::analysis;
use axisbench::comp::backlash::Backlash;
use axisbench::comp::cross;
use axisbench::comp::quadrant::Quadrant;
use axisbench::comp::thermal::{self, Judge};
use axisbench::measure;
use axisbench::preset::comp::{
    BacklashParams, DirectionParams, FunctionBasis, Judgement, NUpdate, OutputMode, QuadrantParams,
    ThermalParams,
};
use axisbench::preset::{self, Fields, Preset};
use proptest::prelude::*;

const Q_UM: f64 = 10.0;

fn dir(mode: OutputMode, n: u32, b_um: f64, m: u32) -> DirectionParams {
    DirectionParams {
        mode,
        parts_n: n,
        step_b_um: b_um,
        cycles_m: m,
        function_basis: FunctionBasis::Distance,
        function: vec![(0.0, 0.0), (30.0, 0.5), (90.0, 1.0)],
    }
}

fn backlash(p2m: DirectionParams, m2p: DirectionParams) -> Backlash {
    Backlash::new(
        0,
        "x",
        BacklashParams {
            enabled: true,
            q_um: Q_UM,
            plus_to_minus: p2m,
            minus_to_plus: m2p,
        },
    )
}

fn mode_strategy() -> impl Strategy<Value = DirectionParams> {
    (0..4u8, 1..6u32, 1.0..40.0f64, 1..10u32, any::<bool>()).prop_map(|(m, n, b, cyc, time_fn)| {
        let mode = [
            OutputMode::Lump,
            OutputMode::Distance,
            OutputMode::Time,
            OutputMode::Function,
        ][m as usize];
        let mut d = dir(mode, n, b, cyc);
        if time_fn {
            d.function_basis = FunctionBasis::Time;
            d.function = vec![(0.0, 0.2), (3.0, 0.6), (8.0, 1.0)];
        }
        d
    })
}

proptest! {
    /// Whatever the modes and however short the strokes, once the axis has moved on long
    /// enough after its last reversal the accumulated correction is exactly the value of the
    /// current direction: 0 in the reference (first) direction, ±Q against it.
    #[test]
    fn accumulated_correction_ends_at_the_direction_value(
        p2m in mode_strategy(),
        m2p in mode_strategy(),
        strokes in prop::collection::vec((any::<bool>(), 1..40usize, 0.1..5.0f64), 1..30),
    ) {
        let mut b = backlash(p2m, m2p);
        for (up, cycles, step_um) in strokes {
            let d = if up { step_um } else { -step_um } * 1e-6;
            for _ in 0..cycles {
                b.cycle(d, 1e-3);
            }
            // Some standstill cycles: they keep the direction.
            for _ in 0..3 {
                b.cycle(0.0, 1e-3);
            }
        }
        // A long final stroke in the current direction completes every pending part.
        let last = b.dir;
        for _ in 0..500 {
            b.cycle(last as f64 * 5e-6, 1e-3);
        }
        let expected = if last == b.ref_dir { 0.0 } else { last as f64 * Q_UM * 1e-6 };
        prop_assert!((b.acc_m - expected).abs() < 1e-15, "ended at {} m, expected {} m", b.acc_m, expected);
    }
}

#[test]
fn distance_mode_emits_part_n_plus_1_exactly_when_r_reaches_b_n() {
    for (p2m_mode, forward_first) in [(true, true), (false, false)] {
        let d = dir(OutputMode::Distance, 5, 12.0, 4);
        let (p2m, m2p) = if p2m_mode {
            (d.clone(), dir(OutputMode::Lump, 1, 1.0, 1))
        } else {
            (dir(OutputMode::Lump, 1, 1.0, 1), d.clone())
        };
        let mut b = backlash(p2m, m2p);
        let s = if forward_first { 1.0 } else { -1.0 };
        for _ in 0..5 {
            b.cycle(s * 3e-6, 1e-3);
        }
        // Reverse with uneven per-cycle travel, some of it standstill.
        let steps: Vec<f64> = (0..60)
            .map(|k| [2.5, 0.0, 4.0, 1.5, 3.0][k % 5] * 1e-6)
            .collect();
        let mut travel_before = 0.0; // R as accumulated up to the previous cycle
        let mut parts = 0;
        for (k, &st) in steps.iter().enumerate() {
            let out = b.cycle(-s * st, 1e-3);
            if k == 0 {
                assert!(out != 0.0, "the first part comes with the reversal");
                parts = 1;
            } else if out != 0.0 {
                parts += 1;
                let threshold = 12e-6 * (parts - 1) as f64;
                assert!(
                    travel_before >= threshold - 1e-18,
                    "part {parts} before R reached B·n"
                );
                let r_prev = travel_before - steps[k - 1];
                assert!(r_prev < threshold, "part {parts} came a cycle late");
                assert!((out.abs() - Q_UM * 1e-6 / 5.0).abs() < 1e-15);
            }
            travel_before += st;
        }
        assert_eq!(parts, 5, "N parts in all");
    }
}

#[test]
fn time_mode_emits_one_part_per_cycle_for_m_cycles() {
    let mut b = backlash(
        dir(OutputMode::Time, 1, 1.0, 7),
        dir(OutputMode::Time, 1, 1.0, 3),
    );
    for _ in 0..4 {
        b.cycle(2e-6, 1e-3);
    }
    let outs: Vec<f64> = (0..12).map(|_| b.cycle(-2e-6, 1e-3)).collect();
    for (k, o) in outs.iter().enumerate() {
        if k < 7 {
            assert!((o + Q_UM * 1e-6 / 7.0).abs() < 1e-15, "cycle {k}: {o}");
        } else {
            assert_eq!(*o, 0.0, "cycle {k} after M parts");
        }
    }
    assert!((b.acc_m + Q_UM * 1e-6).abs() < 1e-18);
    // The other direction uses its own M.
    let outs: Vec<f64> = (0..5).map(|_| b.cycle(1e-6, 1e-3)).collect();
    assert_eq!(outs.iter().filter(|&&o| o != 0.0).count(), 3);
    assert!(b.acc_m.abs() < 1e-18);
}

#[test]
fn lump_and_function_modes_and_a_reversal_inside_a_sequence() {
    let mut b = backlash(
        dir(OutputMode::Function, 1, 1.0, 1),
        dir(OutputMode::Lump, 1, 1.0, 1),
    );
    b.cycle(1e-6, 1e-3);
    // + → − by function of distance: share(R) with R including the cycle's travel.
    let first = b.cycle(-15e-6, 1e-3);
    assert!(
        (first + Q_UM * 1e-6 * 0.25).abs() < 1e-15,
        "share at 15 µm is 0.25: {first}"
    );
    b.cycle(-15e-6, 1e-3);
    assert!((b.acc_m + Q_UM * 1e-6 * 0.5).abs() < 1e-15);
    // Reversal with half still pending: the lump takes the correction straight back to 0.
    let back = b.cycle(3e-6, 1e-3);
    assert!((back - Q_UM * 1e-6 * 0.5).abs() < 1e-15);
    assert_eq!(b.acc_m, 0.0);
}

#[test]
fn quadrant_n_grows_over_short_strokes_and_resets_on_the_long_one() {
    let p = QuadrantParams {
        enabled: true,
        ..QuadrantParams::default()
    };
    let mut q = Quadrant::new(0, "x", p.clone());
    // The seed's workpiece: 40 mm to A, then 10 mm strokes (B), then 40 mm to C.
    let mut x = 0.0;
    let mut ns = vec![];
    let go = |q: &mut Quadrant, to: f64, x: &mut f64| {
        let step = 1e-5 * (to - *x).signum();
        while (to - *x).abs() > 1e-12 {
            let d = if (to - *x).abs() < step.abs() {
                to - *x
            } else {
                step
            };
            q.tick(*x, d, 1.25e-4);
            *x += d;
        }
    };
    // 30 → 40 → 70 is one stroke: no reversal at 40 on the way to C.
    for to in [0.040, 0.030, 0.040, 0.030, 0.040, 0.070, 0.030] {
        go(&mut q, to, &mut x);
        ns.push(q.n);
    }
    // N after arriving at each point is the N of the reversal that started that stroke.
    assert_eq!(ns, vec![0.0, 0.0, 1.0, 2.0, 3.0, 3.0, 0.0], "N per stroke");
    // M and T are the seed's formula at that N.
    go(&mut q, 0.040, &mut x);
    let n = q.n;
    assert_eq!(n, 0.0);
    let (m, t) = p.m_t(4.0);
    assert!((m - p.m0_torque_nm * p.a_mag.powf(1.0 - (-4.0 / p.b_rate).exp())).abs() < 1e-15);
    assert!((t - p.t0_ms * 1e-3 * p.c_mag.powf(1.0 - (-4.0 / p.d_rate).exp())).abs() < 1e-15);
    assert_eq!(p.m_t(0.0).0, p.m0_torque_nm, "M = M0 at N = 0");
    // Decrement instead of reset.
    let mut q = Quadrant::new(
        0,
        "x",
        QuadrantParams {
            update: NUpdate::Decrement,
            ..p
        },
    );
    let mut x = 0.0;
    for to in [0.040, 0.030, 0.040, 0.030, 0.070, 0.030] {
        go(&mut q, to, &mut x);
    }
    // Reversals at 40 (long: stays 0), 30, 40, 30 (short: 1, 2, 3), 70 (long: 3 − 1).
    assert_eq!(q.n, 2.0);
}

fn peaks(p: &Preset) -> Vec<f64> {
    let lp = preset::load_embedded("short_stroke_quadrant.ron").expect("preset");
    let text = lp
        .program_text("short_stroke_quadrant.ngc")
        .expect("program");
    let mut m = Machine::new(p, &[("s.ngc".into(), text)]).expect("machine");
    m.run(60.0).unwrap();
    analysis::summarize(&m.trace)[0]
        .reversals
        .iter()
        .map(|r| r.peak_err_mm)
        .collect()
}

#[test]
fn adaptive_quadrant_keeps_short_stroke_reversals_within_20_percent() {
    let p = preset::load_embedded("short_stroke_quadrant.ron")
        .expect("preset")
        .preset;
    let adaptive = peaks(&p);
    let mut fixed_p = p.clone();
    fixed_p.axes[0].quadrant.adaptive = false;
    let fixed = peaks(&fixed_p);
    let mut off_p = p.clone();
    off_p.axes[0].quadrant.enabled = false;
    let off = peaks(&off_p);
    assert_eq!(adaptive.len(), 7, "A, five B, C");
    let (a, c) = (adaptive[0], adaptive[6]);
    for (i, b) in adaptive[1..6].iter().enumerate() {
        assert!(
            (b - a).abs() <= 0.2 * a && (b - c).abs() <= 0.2 * c,
            "adaptive B{}: {b} vs A {a}, C {c}",
            i + 1
        );
    }
    let worst_fixed = fixed[1..6].iter().cloned().fold(0.0, f64::max);
    assert!(
        worst_fixed > 1.2 * fixed[0],
        "a fixed TFF should not hold B: {fixed:?}"
    );
    assert!(
        adaptive.iter().zip(&off).all(|(x, y)| x < y),
        "compensation must reduce every peak"
    );
}

#[test]
fn step1_recovers_a_known_k_within_2_percent() {
    let (a0, k0) = (1.3, -0.004); // per µm
    let programs: Vec<Vec<(f64, f64)>> = (0..3)
        .map(|j| {
            (1..40)
                .map(|i| {
                    let f = (i as f64 * (1.0 + 0.3 * j as f64)) * 1e-6; // F in m
                    let d = (a0 + 0.05 * j as f64 + k0 * f * 1e6) * f;
                    // deterministic measurement noise of ±0.05 µm
                    let noise = (((i * 7 + j * 3) % 11) as f64 - 5.0) * 0.01e-6;
                    (f, d - f + noise) // A = D − F (E = 1)
                })
                .chain([(0.0, 0.3e-6), (2e-6, -9e-6)]) // F = 0 skipped; r < 0 dropped
                .collect()
        })
        .collect();
    let fit = thermal::step1(&programs).expect("fits");
    assert!(
        (fit.k_per_um - k0).abs() <= 0.02 * k0.abs(),
        "k = {}, expected {k0}",
        fit.k_per_um
    );
    assert_eq!(fit.fits[0].2, 39, "F = 0 and r < 0 points are not used");
    // Step 2 returns the a that makes E·F equal the measured displacement.
    let (f, e) = (20e-6, 1.1);
    let d = 30e-6;
    let a = thermal::step2(k0, f, d - e * f, e);
    assert!(((a + k0 * 20.0) * f - d).abs() < 1e-15);
}

#[test]
fn e_is_clamped_to_its_range() {
    let p = ThermalParams {
        a: 50.0,
        ..ThermalParams::default()
    };
    assert_eq!(p.e_of(1e-6), axisbench::preset::comp::E_MAX);
    let p = ThermalParams {
        a: -3.0,
        ..ThermalParams::default()
    };
    assert_eq!(p.e_of(1e-6), axisbench::preset::comp::E_MIN);
}

#[test]
fn each_judgement_fires_exactly_at_its_crossing() {
    let e_at = |k: usize| 1.0 + 0.001 * k as f64; // E rises 0.001 per second
    // Variant 1: ΔE since the start ≥ Em = 0.05 first at k = 50.
    let p = ThermalParams {
        judgement: Judgement::SinceLast,
        em: 0.05,
        ..ThermalParams::default()
    };
    let mut j = Judge::new(&p);
    let first = (0..200).find(|&k| j.update(k as f64, e_at(k)));
    assert_eq!(first, Some(50));
    // After a measurement the reference restarts there.
    j.measured(50.0, e_at(50));
    let next = (51..200).find(|&k| j.update(k as f64, e_at(k)));
    assert_eq!(next, Some(100));
    // Variant 2: windows of 30 s; E spreads 0.029 within one window → never; with a jump
    // inside the window at t = 75, the spread crosses exactly there.
    let p = ThermalParams {
        judgement: Judgement::Window,
        em: 0.03,
        window_s: 30.0,
        ..ThermalParams::default()
    };
    let mut j = Judge::new(&p);
    let e2 = |k: usize| e_at(k) + if k >= 75 { 0.02 } else { 0.0 };
    let fired: Vec<usize> = (0..120).filter(|&k| j.update(k as f64, e2(k))).collect();
    assert_eq!(
        fired.first(),
        Some(&75),
        "window judgement fired at {fired:?}"
    );
    // Variant 3: only at the set times, against the reference curve.
    let p = ThermalParams {
        judgement: Judgement::Reference,
        em: 0.04,
        check_times_s: vec![20.0, 40.0, 60.0, 80.0],
        e_ref: vec![(0.0, 1.0), (100.0, 1.05)], // E_ref rises 0.0005/s, E 0.001/s
        ..ThermalParams::default()
    };
    let mut j = Judge::new(&p);
    let fired: Vec<usize> = (0..100).filter(|&k| j.update(k as f64, e_at(k))).collect();
    // |E − E_ref| = 0.0005·t: 0.01, 0.02, 0.03, 0.04 → only the check at 80 s.
    assert_eq!(fired, vec![80]);
}

#[test]
fn thermal_auto_remeasurement_beats_a_fixed_e() {
    let lp = preset::load_embedded("thermal_warmup.ron").expect("preset");
    let texts = vec![(
        "w.ngc".to_owned(),
        lp.program_text("thermal_warmup.ngc").expect("program"),
    )];
    let resid = |p: &Preset| -> (f64, u32) {
        let mut m = Machine::new(p, &texts).expect("machine");
        m.run(3.0 * 3600.0).unwrap();
        let tr = &m.trace;
        let th = tr.values("x.thermal").expect("thermal");
        let comp = tr.values("x.thermal_comp");
        let max = th
            .iter()
            .enumerate()
            .map(|(k, x)| (x + comp.map_or(0.0, |c| c[k])).abs())
            .fold(0.0, f64::max);
        let n = m
            .find_comp::<thermal::Thermal>()
            .next()
            .map_or(0, |t| t.measurements);
        (max, n)
    };
    let p = lp.preset.clone();
    let (auto, n) = resid(&p);
    let mut fixed = p.clone();
    fixed.axes[0].thermal.judgement = Judgement::None;
    let (fixed_r, n0) = resid(&fixed);
    let mut off = p.clone();
    off.axes[0].thermal.enabled = false;
    let (off_r, _) = resid(&off);
    assert_eq!(n0, 0);
    assert!(n >= 1, "no automatic measurement in 2 h");
    assert!(
        auto < 0.6 * fixed_r && fixed_r < 0.5 * off_r,
        "residuals: off {off_r}, fixed {fixed_r}, auto {auto} m"
    );
    // The sparse measurement column holds exactly the measurements taken.
    let mut m = Machine::new(&p, &texts).expect("machine");
    m.run(3.0 * 3600.0).unwrap();
    let meas = m.trace.values("x.meas").expect("meas column");
    assert_eq!(meas.iter().filter(|v| v.is_finite()).count() as u32, n);
}

#[test]
fn cross_table_is_exact_at_nodes_linear_between_and_held_outside() {
    let pts = [(0.0, 0.0), (1.0, 4e-6), (3.0, -2e-6)];
    assert_eq!(cross::delta_m(&pts, 1.0), 4e-6);
    assert_eq!(cross::delta_m(&pts, 3.0), -2e-6);
    assert!((cross::delta_m(&pts, 0.25) - 1e-6).abs() < 1e-21);
    assert!((cross::delta_m(&pts, 2.0) - 1e-6).abs() < 1e-21);
    assert_eq!(cross::delta_m(&pts, -5.0), 0.0);
    assert_eq!(cross::delta_m(&pts, 9.0), -2e-6);
    let bad = axisbench::preset::comp::CrossTable {
        enabled: true,
        base_axis: "x".into(),
        comp_axis: "z".into(),
        points: vec![(0.0, 1.0), (0.0, 2.0)],
    };
    assert!(
        bad.check("cross.0")
            .iter()
            .any(|e| e.path == "cross.0.points.1" && e.reason.contains("strictly increasing"))
    );
    let short = axisbench::preset::comp::CrossTable {
        points: vec![(0.0, 1.0)],
        ..bad.clone()
    };
    assert!(
        short
            .check("cross.0")
            .iter()
            .any(|e| e.path == "cross.0.points" && e.reason.contains("at least 2"))
    );
    let nan = axisbench::preset::comp::CrossTable {
        points: vec![(0.0, f64::NAN), (1.0, 2.0)],
        ..bad
    };
    assert!(
        nan.check("cross.0")
            .iter()
            .any(|e| e.path == "cross.0.points.0" && e.reason.contains("finite"))
    );
}

#[test]
fn sag_tables_with_more_points_leave_less_z_error() {
    let lp = preset::load_embedded("vertical_lathe_crossbeam.ron").expect("preset");
    let texts: Vec<(String, String)> = lp
        .preset
        .scenario
        .programs
        .iter()
        .map(|n| (n.clone(), lp.program_text(n).expect("program")))
        .collect();
    let rms = |p: &Preset| {
        let mut m = Machine::new(p, &texts).expect("machine");
        m.run(120.0).unwrap();
        analysis::summarize(&m.trace)
            .iter()
            .find(|s| s.axis == "z")
            .map_or(f64::NAN, |s| s.rms_err_mm)
    };
    let mut off = lp.preset.clone();
    off.cross.clear();
    let mut last = rms(&off);
    for n in [5, 9, 17] {
        let mut p = lp.preset.clone();
        p.cross = measure::sag_tables(&p, n).expect("measured");
        let r = rms(&p);
        assert!(r < last * 0.6, "{n} points: rms {r} mm, not below {last}");
        last = r;
    }
    assert!(last < 0.5e-3, "17 points leave {last} mm");
}

#[test]
fn reversal_test_measures_the_lost_motion() {
    let mut p = crate::common::plain();
    p.axes[0].lost_motion.enabled = true;
    p.axes[0].lost_motion.width_um = 15.0;
    p.axes[0].friction.enabled = true;
    let q = measure::backlash_um(&p, "x").expect("measured");
    assert!((q - 15.0).abs() < 0.5, "measured {q} µm of 15 µm");
}

#[test]
fn backlash_compensation_removes_the_lost_motion_on_the_default_axis() {
    let p = preset::load_embedded("default.ron").expect("preset").preset;
    let settled = |p: &Preset| -> f64 {
        let lp = preset::load_embedded("default.ron").expect("preset");
        let text = lp.program_text("default.ngc").expect("program");
        let mut m = Machine::new(p, &[("d.ngc".into(), text)]).expect("machine");
        m.run(60.0).unwrap();
        analysis::summarize(&m.trace)[0]
            .reversals
            .iter()
            .map(|r| r.settled_err_mm.abs())
            .fold(0.0, f64::max)
    };
    let on = settled(&p);
    let mut q = p.clone();
    q.axes[0].backlash.enabled = false;
    let off = settled(&q);
    assert!(
        off > 7e-3 && on < 1e-3,
        "lost motion at reversals: off {off} mm, on {on} mm"
    );
}

#[test]
fn compensations_write_their_trace_signals_and_validate() {
    let lp = preset::load_embedded("vertical_z_gravity.ron").expect("preset");
    let mut m = Machine::from_loaded(&lp).expect("machine");
    m.run(60.0).unwrap();
    let bl = m.trace.values("z.backlash_comp").expect("backlash column");
    assert!(bl.iter().any(|&v| v != 0.0));
    let text = preset::embedded("default.ron")
        .expect("embedded")
        .replace("parts_n: 4", "parts_n: 0");
    let e = Preset::from_ron(&text, "bad.ron").expect_err("invalid");
    assert!(
        e.to_string()
            .contains("axes.x.backlash.plus_to_minus.parts_n"),
        "{e}"
    );
}
