//! NC: parser errors, interpolation, acc/dec, both processing modes and mode switching.

use axisbench::Machine;
use axisbench::nc::program;
use axisbench::preset::{self, AccDecKind, Mode, PlcEvent};

use axisbench::trace::Quantity;
use axisbench::units::{m_to_um, mm_to_m};

use crate::common::{at, col, col_mm, plain, run};

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
    let cmd = col_mm(tr, "x.cmd");
    let v = |t: f64| {
        let k = at(tr, t);
        (cmd[k + 8] - cmd[k]) / (tr.t()[k + 8] - tr.t()[k])
    };
    // 50 mm/s reached after tc, half of it at tc/2.
    assert!((v(0.15) - 50.0).abs() < 0.5, "v after tc = {}", v(0.15));
    assert!((v(0.05) - 25.0).abs() < 3.0, "v at tc/2 = {}", v(0.05));
    assert_eq!(
        *col(tr, "x.cmd").last().unwrap_or(&0.0),
        mm_to_m(100.0),
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
    assert_eq!(*cmd.last().unwrap_or(&0.0), mm_to_m(50.0));
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
    // Same arithmetic as the NC: mm → m, accumulate; the trace holds m.
    let mut pos_m = 0.0;
    for (i, inc) in incs.iter().enumerate() {
        pos_m += mm_to_m(*inc);
        assert_eq!(cmd[first + i], pos_m, "sample {i}");
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
    assert_eq!(
        *col(&m.trace, "x.cmd").last().unwrap_or(&0.0),
        mm_to_m(0.001) + mm_to_m(0.001)
    );
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
    assert_eq!(*col(&m.trace, "x.cmd").last().unwrap_or(&0.0), mm_to_m(2.0));
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
    m_to_um(
        (at(tr, t0)..at(tr, t1))
            .map(|k| (x[k].hypot(y[k]) - mm_to_m(10.0)).abs())
            .fold(0.0, f64::max),
    )
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
        m.run(30.0).unwrap();
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
        m.run(60.0).unwrap();
        m.trace
    });
    let b = Machine::from_loaded(&lp).map(|mut m| {
        m.run(60.0).unwrap();
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
                quantity: Quantity::Length,
            }]
        }
        fn values(&self, out: &mut [f64]) {
            out[0] = 5e-6;
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
                quantity: Quantity::Torque,
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
    m.run(10.0).unwrap();
    let tr = &m.trace;
    assert!((col(tr, "x.comp")[tr.len() - 1] - 5e-6).abs() < 1e-15);
    assert!(
        (col(tr, "x.pos")[tr.len() - 1] - 5e-6).abs() < 1e-9,
        "the table follows the correction"
    );
    assert_eq!(col(tr, "x.offset_comp")[0], 5e-6);
    // Torque feed-forward: with the integrator balancing it at rest, the first sample shows it.
    let mut m = Machine::new(&p, &[("t".into(), "G04 P100\nM30\n".into())]).expect("machine");
    let mut comps = CompStack::default();
    comps.servo.push(Box::new(Tff));
    m.set_comps(comps);
    m.run_steps(1).unwrap();
    assert!((col(&m.trace, "x.torque_cmd")[0] - 1.5).abs() < 1e-9);
}

fn compile_xyz(src: &str) -> Result<Vec<program::Op>, program::ProgramError> {
    let blocks = program::parse(src, "p.ngc")?;
    program::compile(
        &blocks,
        &['X', 'Y', 'Z'],
        &[0.0; 3],
        1000.0,
        10000.0,
        "p.ngc",
    )
}

fn err_at(src: &str) -> (usize, usize, String) {
    match compile_xyz(src) {
        Ok(_) => panic!("accepted bad program:\n{src}"),
        Err(e) => (e.line, e.col, e.reason),
    }
}

#[test]
fn overflowing_code_numbers_are_errors_not_other_codes() {
    // u32 wrap-around used to run this as G00.
    let (l, c, r) = err_at("G90\nG01 X1 F100\nG2147483648 X10\n");
    assert_eq!((l, c), (3, 1), "{r}");
    assert_eq!(r, "G2147483648: G number out of range (G0 to G999)");
    // Past u32 it used to be dropped silently.
    let (l, c, r) = err_at("G99999999999 X1\n");
    assert_eq!((l, c), (1, 1), "{r}");
    assert!(r.starts_with("G99999999999: G number out of range"), "{r}");
    let (l, c, r) = err_at("G01 X1 M4294967296\n");
    assert_eq!((l, c), (1, 8), "{r}");
    assert!(r.starts_with("M4294967296: M number out of range"), "{r}");
    let (_, c, r) = err_at("G-1 X1\n");
    assert_eq!(c, 1);
    assert!(r.contains("G-1") && r.contains("out of range"), "{r}");
    let (_, _, r) = err_at("G91.1\n");
    assert!(r.contains("G91.1") && r.contains("not supported"), "{r}");
    let (_, c, r) = err_at("G01 X1 T1.5\n");
    assert_eq!(c, 8);
    assert!(r.contains("T1.5") && r.contains("whole number"), "{r}");
    let (_, c, r) = err_at("N123456789012 G01 X1\n");
    assert_eq!(c, 1);
    assert!(r.contains("N123456789012"), "{r}");
}

#[test]
fn exponents_are_refused_with_the_plain_number() {
    let (l, c, r) = err_at("G01X1e3\n");
    assert_eq!((l, c), (1, 4), "{r}");
    assert_eq!(r, "X1e3: exponents are not G-code; write X1000");
    let (_, c, r) = err_at("G01 X1 Y-2.5E-3 F100\n");
    assert_eq!(c, 8);
    assert_eq!(r, "Y-2.5E-3: exponents are not G-code; write Y-0.0025");
    let (_, _, r) = err_at("G01 F1e+300\n");
    assert_eq!(
        r, "F1e+300: exponents are not G-code",
        "no 300-digit suggestion"
    );
    // Inside comments anything goes.
    let ops = compile_xyz("(X1e3 and G99999999999) G01 X1 F100 ; Y2e5 G-1\nM30\n")
        .expect("comments are ignored");
    assert_eq!(ops.len(), 2);
}

#[test]
fn every_number_is_finite_and_in_range() {
    // 400 digits parse to inf.
    let huge = "9".repeat(400);
    let (_, c, r) = err_at(&format!("G01 X{huge}\n"));
    assert_eq!(c, 5);
    assert!(
        r.starts_with("X9999") && r.contains("out of range (|X| ≤ 100000 mm)"),
        "{r}"
    );
    assert!(r.len() < 200, "the number is quoted short: {r}");
    let cases = [
        ("G01 X100001\n", 5, "X out of range"),
        ("G01 Y-100000.5\n", 5, "Y out of range"),
        ("G01 X1 F0\n", 8, "feed F must be > 0"),
        ("G01 X1 F-5\n", 8, "feed F must be > 0"),
        (
            "G01 X1 F1000001\n",
            8,
            "F out of range (0 < F ≤ 1000000 mm/min)",
        ),
        ("G04 P-1\n", 5, "P must be ≥ 0"),
        ("G04 P86400001\n", 5, "P out of range"),
        ("G02 X1 R0\n", 8, "an arc radius must not be 0"),
        ("G02 X1 I100001\n", 8, "I out of range"),
        ("M3 S1000000\n", 4, "S out of range"),
        ("G01 A5\n", 5, "A5: address A is not supported"),
        ("G01 X1 X2\n", 8, "X2: address X appears twice"),
    ];
    for (src, col, needle) in cases {
        let (l, c, r) = err_at(src);
        assert_eq!((l, c), (1, col), "{src}: {r}");
        assert!(r.contains(needle), "{src}: {r}");
    }
}

#[test]
fn lexical_errors_name_line_and_column() {
    let cases = [
        ("G01 X1 Y$\n", 8, "Y: Y needs a number"),
        ("G01 X1.2.3\n", 5, "'1.2.3' is not a number"),
        ("G01 X1 (open\n", 8, "comment '(' is not closed"),
        ("#1=5\n", 1, "parameters (#) are not supported"),
        ("G01 X#1\n", 5, "parameters (#) are not supported"),
        ("/G01 X1\n", 1, "block delete"),
        ("G01 X1 ä\n", 8, "unexpected 'ä'"),
    ];
    for (src, col, needle) in cases {
        let (l, c, r) = err_at(src);
        assert_eq!((l, c), (1, col), "{src}: {r}");
        assert!(r.contains(needle), "{src}: {r}");
    }
    // Columns count characters, not bytes.
    let (_, c, r) = err_at("(ä) A1\n");
    assert_eq!(c, 5, "{r}");
}

#[test]
fn block_time_is_bounded_before_anything_interpolates() {
    let (l, c, r) = err_at("G01 X10 F100\nG04 X90000\n");
    assert_eq!((l, c), (2, 1), "{r}");
    assert!(
        r.contains("90000 s") && r.contains("MAX_BLOCK_TIME_S"),
        "{r}"
    );
    // 10 mm at 1e-9 mm/min: 1e10 min. Refused at compile time, not interpolated for ages.
    let (l, _, r) = err_at("G01 X10 F0.000000001\n");
    assert_eq!(l, 1);
    assert!(
        r.contains("this move of 10 mm")
            && r.contains("MAX_BLOCK_TIME_S")
            && r.contains("s per block"),
        "{r}"
    );
    // A day is the limit, and allowed.
    compile_xyz("G04 P86400000\nG04 X86400\nM30\n").expect("a day of dwell");
}

#[test]
fn incremental_moves_cannot_leave_the_coordinate_range() {
    let (l, c, r) = err_at("G91\nG01 X60000 F1000000\nX60000\n");
    assert_eq!((l, c), (3, 1), "{r}");
    assert!(
        r.contains("takes X to 120000 mm") && r.contains("100000"),
        "{r}"
    );
}

#[test]
fn many_bad_lines_give_the_first_twenty_and_a_count() {
    let src = "G41 X5\n".repeat(100_000);
    let e = compile_xyz(&src).expect_err("bad");
    assert_eq!(e.count(), 100_000);
    assert_eq!(e.more.len(), 19);
    assert_eq!(e.omitted, 99_980);
    let lines: Vec<usize> = e.findings().map(|f| f.line).collect();
    assert_eq!(lines, (1..=20).collect::<Vec<_>>());
    let shown = e.to_string();
    assert!(shown.chars().count() < 4000, "{} chars", shown.len());
    assert!(
        shown.starts_with("p.ngc:1:1: G41 is not supported"),
        "{shown}"
    );
    assert!(
        shown.ends_with("… and 99980 more errors (100000 in all)"),
        "{shown}"
    );
    // Long bad words and a long file name stay short too.
    let src = format!("A{}\n", "1".repeat(10_000)).repeat(50);
    let blocks = program::parse(&src, &"f".repeat(5000)).expect_err("bad");
    assert_eq!(blocks.count(), 50);
    assert!(blocks.to_string().chars().count() < 4000);
    // Compile errors are collected as well, each block judged from the programmed point.
    let e = compile_xyz("G01 X1 F100\nG01 A1\nG02 X3 Y0 I5 J0\nX4\nG01 Q1\n").expect_err("bad");
    let at: Vec<(usize, usize)> = e.findings().map(|f| (f.line, f.col)).collect();
    assert_eq!(at, vec![(2, 5), (5, 5)], "{e}");
    let e =
        compile_xyz("G01 X1 F100\nG02 X3 Y0 I5 J0\nG01 X4 W1\nG02 X0 Y0 I1\n").expect_err("bad");
    let lines: Vec<usize> = e.findings().map(|f| f.line).collect();
    assert_eq!(lines, vec![2, 4], "{e}");
}

#[test]
fn bom_and_crlf_are_accepted() {
    let ops = compile_xyz("\u{feff}G90 G01 F600\r\nX10.5\r\nM30\r\n").expect("BOM + CRLF");
    match &ops[0] {
        program::Op::Move { end_m, line, .. } => {
            assert_eq!(*line, 2);
            assert_eq!(end_m[0], axisbench::units::mm_to_m(10.5));
        }
        op => panic!("expected a move, got {op:?}"),
    }
    assert_eq!(ops[1], program::Op::End);
    // Columns after a BOM count from the first visible character.
    let (l, c, _) = err_at("\u{feff}G41\r\n");
    assert_eq!((l, c), (1, 1));
}

#[test]
fn program_size_is_bounded() {
    let lines = "\n".repeat(program::MAX_PROGRAM_LINES);
    let e = program::parse(&lines, "big.ngc").expect_err("too many lines");
    assert!(
        e.reason
            .contains(&format!("{} lines", program::MAX_PROGRAM_LINES + 1))
            && e.reason.contains("MAX_PROGRAM_LINES"),
        "{e}"
    );
    let bytes = " ".repeat(program::MAX_PROGRAM_BYTES + 1);
    let e = program::parse(&bytes, "big.ngc").expect_err("too many bytes");
    assert!(
        e.reason
            .contains(&format!("{} bytes", program::MAX_PROGRAM_BYTES + 1))
            && e.reason.contains("MAX_PROGRAM_BYTES"),
        "{e}"
    );
}

#[test]
fn ordinary_words_are_still_accepted() {
    let ops = compile_xyz(
        "%\nO1000\nN10 G21 G17 G90 T1 M6 (tool)\nN20 M3 S12000\nn30 g1 x+1. y-.5 z0 f1500.\nN40 G2 X2 Y.5 R1\nN50 G4 P250\nN60 M30\n",
    )
    .expect("accepted");
    assert_eq!(ops.len(), 4, "{ops:?}");
    assert!(matches!(ops[2], program::Op::Dwell { t_s, .. } if t_s == 0.25));
}
