//! NC: parser errors, interpolation, acc/dec, both processing modes and mode switching.

use axisbench::Machine;
use axisbench::nc::program;
use axisbench::preset::{self, AccDecKind, Mode, PlcEvent};

use crate::common::{at, col, plain, run};

fn parse_err(src: &str) -> program::ProgramError {
    let blocks = match program::parse(src, "p.ngc") {
        Ok(b) => b,
        Err(e) => return e,
    };
    program::compile(&blocks, &['X', 'Y'], &[0.0, 0.0], 1000.0, 10000.0, "p.ngc")
        .expect_err("should fail")
}

#[test]
fn bad_programs_name_line_column_and_reason() {
    let e = parse_err("G90\nG01 X10 F100\nG41 X5\n");
    assert_eq!((e.line, e.col), (3, 1), "{e}");
    assert!(e.reason.contains("G41"), "{e}");
    let e = parse_err("G01 X1\nG01 Z5 F100\n");
    assert_eq!((e.line, e.col), (2, 5), "{e}");
    assert!(e.reason.contains("axis Z"), "{e}");
    let e = parse_err("G01 X1 F100\nG02 X3 Y0 I5 J0\n");
    assert_eq!(e.line, 2, "{e}");
    assert!(e.reason.contains("not on the circle"), "{e}");
    let e = parse_err("G01 X1 Y$\n");
    assert_eq!(e.line, 1, "{e}");
    let e = parse_err("G05 P3\n");
    assert!(e.reason.contains("P4"), "{e}");
    let e = parse_err("G01 X1 X2\n");
    assert!(e.reason.contains("twice"), "{e}");
    assert!(e.to_string().starts_with("p.ngc:1:"), "{e}");
}

#[test]
fn numbers_are_read_exactly_not_through_f32() {
    let blocks = program::parse("G01 X123.456789 F1000\n", "p").expect("parses");
    let x = blocks[0]
        .words
        .iter()
        .find(|w| w.letter == 'X')
        .expect("X")
        .value;
    assert_eq!(x, 123.456789);
}

#[test]
fn arcs_stay_on_the_circle_and_end_exactly() {
    let blocks =
        program::parse("G17 G90 G03 X0 Y10 I-10 J0 F1000\nG02 X10 Y0 R10\n", "p").expect("parses");
    let ops = program::compile(&blocks, &['X', 'Y'], &[0.01, 0.0], 1000.0, 1000.0, "p")
        .expect("compiles");
    for op in &ops {
        if let program::Op::Move { path, end_m, .. } = op {
            let start = [0.01, 0.0];
            let start = if end_m[0] == 0.0 { start } else { [0.0, 0.01] };
            let mut out = [0.0; 2];
            for k in 0..=100 {
                program::point_on(path, &start, end_m, k as f64 / 100.0, &mut out);
                let r = out[0].hypot(out[1]);
                assert!((r - 0.01).abs() < 1e-12, "left the circle: r = {r}");
            }
            assert_eq!(out.to_vec(), *end_m);
        }
    }
}

#[test]
fn linear_accdec_ramps_velocity_over_its_time_constant() {
    let mut p = plain();
    p.nc.accdec.kind = AccDecKind::Linear;
    p.nc.accdec.tc1_s = 0.1;
    let m = run(&p, "G90 G01 X100. F3000\nM30\n");
    let tr = &m.trace;
    let cmd = col(tr, "x.cmd");
    let v = |t: f64| {
        let k = at(tr, t);
        (cmd[k + 8] - cmd[k]) / (tr.t()[k + 8] - tr.t()[k])
    };
    // 50 mm/s reached after tc, half of it at tc/2.
    assert!((v(0.15) - 50.0).abs() < 0.5, "v after tc = {}", v(0.15));
    assert!((v(0.05) - 25.0).abs() < 3.0, "v at tc/2 = {}", v(0.05));
    assert_eq!(
        *cmd.last().unwrap_or(&0.0),
        100.0,
        "acc/dec must not lose travel"
    );
}

#[test]
fn bell_accdec_limits_jerk_and_keeps_the_end_point() {
    let mut p = plain();
    p.nc.accdec.kind = AccDecKind::Bell;
    p.nc.accdec.tc1_s = 0.06;
    p.nc.accdec.tc2_s = 0.04;
    let m = run(&p, "G90 G01 X50. F3000\nM30\n");
    let cmd = col(&m.trace, "x.cmd");
    assert_eq!(*cmd.last().unwrap_or(&0.0), 50.0);
}

/// Deterministic increments in µm-ish steps, as a direct-command program.
fn direct_program(n: usize) -> (String, Vec<f64>) {
    let mut s = String::from("G05P4\n");
    let mut incs = Vec::new();
    for i in 0..n {
        let v = ((i * 7919) % 23) as f64 * 0.0007 - 0.003;
        let txt = format!("{v:.4}");
        incs.push(txt.parse::<f64>().unwrap_or(0.0));
        s += &format!("U{txt}\n");
    }
    s += "G05P0\nM30\n";
    (s, incs)
}

#[test]
fn direct_mode_delivers_the_programs_t3_data_exactly() {
    let p = plain();
    let (prog, incs) = direct_program(400);
    let m = run(&p, &prog);
    let tr = &m.trace;
    let cmd = col(tr, "x.cmd");
    let mode = col(tr, "mode");
    let first = mode
        .iter()
        .position(|&x| x == 1.0)
        .expect("direct mode entered");
    // Same arithmetic as the NC: mm → m, accumulate, back to mm for the trace.
    let mut pos_m = 0.0;
    for (i, inc) in incs.iter().enumerate() {
        pos_m += inc * 1e-3;
        assert_eq!(cmd[first + i], pos_m * 1e3, "sample {i}");
    }
    // The amplifier ran on exactly one sample per T3 in between.
    assert_eq!(mode[first + incs.len() - 1], 1.0);
}

#[test]
fn modes_switch_by_parameter_program_and_plc() {
    // Initial parameter.
    let mut p = plain();
    p.nc.initial_mode = Mode::Direct;
    let m = run(&p, "U0.001\nU0.001\nM30\n");
    assert_eq!(col(&m.trace, "mode")[0], 1.0);
    assert_eq!(*col(&m.trace, "x.cmd").last().unwrap_or(&0.0), 0.002);
    // G05P4 / G05P0 in the program.
    let p = plain();
    let m = run(&p, "G01 X1. F600\nG05P4\nU0.001\nG05P0\nG01 X2.\nM30\n");
    let mode = col(&m.trace, "mode");
    let on = mode.iter().position(|&x| x == 1.0).expect("switched on");
    let off = on
        + mode[on..]
            .iter()
            .position(|&x| x == 0.0)
            .expect("switched off");
    assert!(off > on);
    assert_eq!(*col(&m.trace, "x.cmd").last().unwrap_or(&0.0), 2.0);
    // PLC event at a set time.
    let mut p = plain();
    p.scenario.plc_events = vec![PlcEvent {
        t_s: 0.5,
        mode: Mode::Direct,
        channel: 0,
    }];
    let m = run(&p, "G04 P1000\nU0.5\nM30\n");
    let tr = &m.trace;
    // Latched at 0.5 s, taken at the next block boundary (after the dwell).
    assert_eq!(col(tr, "mode")[at(tr, 0.6)], 0.0);
    assert_eq!(col(tr, "mode")[at(tr, 1.1)], 1.0);
}

fn radial_error_um(m: &Machine, t0: f64, t1: f64) -> f64 {
    let tr = &m.trace;
    let x = col(tr, "x.pos");
    let y = col(tr, "y.pos");
    (at(tr, t0)..at(tr, t1))
        .map(|k| (x[k].hypot(y[k]) - 10.0).abs())
        .fold(0.0, f64::max)
        * 1e3
}

#[test]
fn high_feed_circle_is_more_accurate_in_direct_mode() {
    let lp = preset::load_embedded("xy_circle.ron").expect("preset");
    let mut p = lp.preset;
    // Without acc/dec, so that the moving-average contraction of the radius (the same in
    // both modes, ≈ R(ωτ)²/24) does not mask the chord error of the T1 grid.
    p.nc.accdec.kind = AccDecKind::None;
    let feed = 10000.0; // mm/min
    let normal =
        "G90 G17 G01 F10000\nG03 X10. Y0. I-10. J0.\nG03 X10. Y0. I-10. J0.\nM30\n".to_owned();
    // The same circle as T3 points.
    let t3 = p.timing.t3_s;
    let omega = feed / 60.0 / 10.0; // rad/s
    let n = (2.0 * 2.0 * std::f64::consts::PI / (omega * t3)).round() as usize;
    let mut direct = String::from("G90\nG05P4\n");
    for k in 1..=n {
        let th = (k as f64 * omega * t3).min(4.0 * std::f64::consts::PI);
        direct += &format!("X{:.6} Y{:.6}\n", 10.0 * th.cos(), 10.0 * th.sin());
    }
    direct += "X10. Y0.\nG05P0\nM30\n";
    let run2 = |prog: &str| {
        let mut m = Machine::new(&p, &[("c.ngc".into(), prog.to_owned())]).expect("machine");
        m.run(30.0);
        m
    };
    let mn = run2(&normal);
    let md = run2(&direct);
    let rev = 2.0 * std::f64::consts::PI / omega;
    // Second revolution, away from the start transient.
    let en = radial_error_um(&mn, rev + 0.05, 2.0 * rev - 0.05);
    let ed = radial_error_um(&md, rev + 0.05, 2.0 * rev - 0.05);
    assert!(ed < en, "direct {ed:.2} µm should beat normal {en:.2} µm");
    assert!(
        en - ed > 1.0,
        "chord error should be visible: normal {en:.2} µm, direct {ed:.2} µm"
    );
}

#[test]
fn same_input_gives_a_bit_identical_trace() {
    let lp = preset::load_embedded("default.ron").expect("preset");
    let a = Machine::from_loaded(&lp).map(|mut m| {
        m.run(60.0);
        m.trace
    });
    let b = Machine::from_loaded(&lp).map(|mut m| {
        m.run(60.0);
        m.trace
    });
    let (a, b) = (a.expect("run a"), b.expect("run b"));
    assert_eq!(a.signals.len(), b.signals.len());
    for (sa, sb) in a.signals.iter().zip(&b.signals) {
        let bits_a: Vec<u64> = sa.data.iter().map(|v| v.to_bits()).collect();
        let bits_b: Vec<u64> = sb.data.iter().map(|v| v.to_bits()).collect();
        assert!(bits_a == bits_b, "signal {} differs", sa.name);
    }
    let (mut ca, mut cb) = (Vec::new(), Vec::new());
    a.write_csv_to(&mut ca).expect("csv");
    b.write_csv_to(&mut cb).expect("csv");
    assert!(ca == cb, "CSV bytes differ");
}

#[test]
fn compensation_slots_reach_the_command_and_the_torque() {
    use axisbench::comp::*;
    struct Offset;
    impl PositionComp for Offset {
        fn name(&self) -> &str {
            "offset"
        }
        fn step(&mut self, _: &PosCompCtx<'_>, out: &mut [f64]) {
            out[0] += 5e-6;
        }
        fn signals(&self) -> Vec<CompSignal> {
            vec![CompSignal {
                axis: "x".into(),
                signal: "offset_comp".into(),
                unit: "mm".into(),
            }]
        }
        fn values(&self, out: &mut [f64]) {
            out[0] = 0.005;
        }
        fn as_any(&self) -> &dyn std::any::Any {
            self
        }

        fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
            self
        }
    }
    struct Tff;
    impl ServoComp for Tff {
        fn name(&self) -> &str {
            "tff"
        }
        fn axis(&self) -> usize {
            0
        }
        fn step(&mut self, _: &ServoCompCtx, out: &mut ServoCompOut) {
            out.torque_nm = 1.5;
        }
        fn signals(&self) -> Vec<CompSignal> {
            vec![CompSignal {
                axis: "x".into(),
                signal: "tff".into(),
                unit: "N*m".into(),
            }]
        }
        fn values(&self, out: &mut [f64]) {
            out[0] = 1.5;
        }
        fn as_any(&self) -> &dyn std::any::Any {
            self
        }

        fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
            self
        }
    }
    let p = plain();
    let mut m = Machine::new(&p, &[("t".into(), "G04 P500\nM30\n".into())]).expect("machine");
    let mut comps = CompStack::default();
    comps.position.push(Box::new(Offset));
    m.set_comps(comps);
    m.run(10.0);
    let tr = &m.trace;
    assert!((col(tr, "x.comp")[tr.len() - 1] - 0.005).abs() < 1e-12);
    assert!(
        (col(tr, "x.pos")[tr.len() - 1] - 0.005).abs() < 1e-6,
        "the table follows the correction"
    );
    assert_eq!(col(tr, "x.offset_comp")[0], 0.005);
    // Torque feed-forward: with the integrator balancing it at rest, the first sample shows it.
    let mut m = Machine::new(&p, &[("t".into(), "G04 P100\nM30\n".into())]).expect("machine");
    let mut comps = CompStack::default();
    comps.servo.push(Box::new(Tff));
    m.set_comps(comps);
    m.run_steps(1);
    assert!((col(&m.trace, "x.torque_cmd")[0] - 1.5).abs() < 1e-9);
}
