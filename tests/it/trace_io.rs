//! Trace CSV: round trip, units, mappings, and every bad-input class.

use std::path::PathBuf;

use axisbench::trace::{self, Mapping, Trace, TraceError};

use crate::common::{col, plain, run};

#[test]
fn csv_round_trip_is_exact() {
    let m = run(&plain(), "G90 G01 X12.345 F2000\nM30\n");
    let dir = tempfile::tempdir().expect("tmp dir");
    let path = dir.path().join("rt.csv");
    m.trace.write_csv(&path).expect("write");
    let back = Trace::read_csv(&path, None).expect("read");
    assert_eq!(back.meta, m.trace.meta);
    assert_eq!(back.signals.len(), m.trace.signals.len());
    for (a, b) in m.trace.signals.iter().zip(&back.signals) {
        assert_eq!((&a.name, &a.unit), (&b.name, &b.unit));
        assert!(
            a.data
                .iter()
                .zip(&b.data)
                .all(|(x, y)| x.to_bits() == y.to_bits()),
            "{} changed",
            a.name
        );
    }
}

#[test]
fn units_are_converted_and_empty_cells_are_missing() {
    let text = "# machine: test\nt[ms],x.cmd[m],x.pos[um],x.vel[mm/min],x.meas[mm]\n0,0.001,1000,60,\n1,0.002,2000,120,2.5\n";
    let t = Trace::from_csv_str(text, "u.csv", None).expect("reads");
    assert_eq!(t.meta("machine"), Some("test"));
    // Traces hold SI; powers of ten of it (ms, um, mm) convert exactly, as the decimal read.
    assert_eq!(t.t(), &[0.0, 0.001]);
    assert_eq!(col(&t, "x.cmd"), &[0.001, 0.002]);
    assert_eq!(col(&t, "x.pos"), &[0.001, 0.002]);
    let vel = col(&t, "x.vel");
    assert!(
        (vel[0] - 0.001).abs() < 1e-18 && (vel[1] - 0.002).abs() < 1e-18,
        "{vel:?}"
    );
    let meas = col(&t, "x.meas");
    assert!(meas[0].is_nan() && meas[1] == 0.0025);
    assert_eq!(t.signal("x.vel").map(|s| s.unit.as_str()), Some("m/s"));
    assert_eq!(t.signal("x.pos").map(|s| s.unit.as_str()), Some("m"));
    assert_eq!(t.signal("t").map(|s| s.unit.as_str()), Some("s"));
}

fn bad(text: &str) -> String {
    match Trace::from_csv_str(text, "bad.csv", None) {
        Ok(_) => panic!("accepted bad trace:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_traces_are_rejected_with_file_line_and_column() {
    let e = bad("t[s],x.cmd[mm],x.pos[mm]\n0,0,0\n0.1,NaN,0\n");
    assert!(
        e.contains("bad.csv:3") && e.contains("x.cmd[mm]") && e.contains("NaN"),
        "{e}"
    );
    let e = bad("t[s],x.cmd[mm],x.pos[mm]\n0,0,0\n0.1,abc,0\n");
    assert!(e.contains("bad.csv:3") && e.contains("'abc'"), "{e}");
    let e = bad("t[s],x.cmd[mm],x.pos[mm]\n0,0,0\n0.2,0,0\n0.1,0,0\n");
    assert!(
        e.contains("bad.csv:4") && e.contains("does not increase"),
        "{e}"
    );
    let e = bad("t[s],x.cmd[mm]\n0,0\n");
    assert!(e.contains("x.pos") || e.contains("pos"), "{e}");
    let e = bad("t[s],x.cmd[furlong],x.pos[mm]\n0,0,0\n");
    assert!(e.contains("furlong"), "{e}");
    let e = bad("x.cmd[mm],x.pos[mm]\n0,0\n");
    assert!(e.contains("time"), "{e}");
    let e = bad("t[s],x.cmd[mm],x.pos[mm]\n0,0,0\n0.1,0\n");
    assert!(e.contains("bad.csv:3"), "{e}");
    let e = bad("t[s],x.cmd[mm],x.pos[mm]\n0,0,inf\n");
    assert!(e.contains("finite"), "{e}");
}

#[test]
fn foreign_layout_is_read_through_a_mapping() {
    let map = Mapping::parse("t[s]=t_s, x.cmd[m]=qg_m, x.pos[m]=qm_m, x.force[N]=force_N")
        .expect("mapping");
    let text = "t_s,qg_m,qm_m,vir_V,force_N\n0,0.001,0.0005,1,35.15\n0.001,0.002,0.0015,2,70.3\n";
    let t = Trace::from_csv_str(text, "emps.csv", Some(&map)).expect("reads");
    assert_eq!(col(&t, "x.cmd"), &[0.001, 0.002]);
    assert_eq!(col(&t, "x.pos"), &[0.0005, 0.0015]);
    assert!(t.signal("vir_V").is_none());
    let missing = Mapping::parse("t[s]=t_s, x.cmd[m]=nope, x.pos[m]=qm_m").expect("mapping");
    let e = Trace::from_csv_str(text, "emps.csv", Some(&missing)).expect_err("missing column");
    assert!(
        matches!(e, TraceError::Layout { .. }) && e.to_string().contains("nope"),
        "{e}"
    );
}

#[test]
fn real_emps_record_reads_through_the_mapping() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/real/emps/emps_train_DATA_EMPS.csv");
    assert!(
        path.exists(),
        "real data missing: {} (the tests expect shared/ next to the repository)",
        path.display()
    );
    let map = Mapping::parse("t[s]=t_s, x.cmd[m]=qg_m, x.pos[m]=qm_m, x.force[N]=force_N")
        .expect("mapping");
    let t = Trace::read_csv(&path, Some(&map)).expect("reads");
    assert_eq!(t.len(), 24_841);
    let pos = col(&t, "x.pos");
    let max = pos.iter().cloned().fold(f64::MIN, f64::max);
    assert!((max - 0.246378).abs() < 1e-5, "max position {max} m");
}

/// A clean 1 kHz trace of `n` rows, with `f(i)` replacing row i's time when it returns Some.
fn timed(n: usize, f: impl Fn(usize) -> Option<String>) -> String {
    let mut s = String::from("t[s],x.cmd[mm],x.pos[mm]\n");
    for i in 0..n {
        let t = f(i).unwrap_or_else(|| format!("{}", i as f64 * 0.001));
        s += &format!("{t},{i},{i}\n");
    }
    s
}

#[test]
fn bom_and_crlf_are_accepted() {
    let text = "\u{feff}# source: logger\r\nt[s],x.cmd[mm],x.pos[mm]\r\n0,1,2\r\n0.1,3,4\r\n";
    let t = Trace::from_csv_str(text, "crlf.csv", None).expect("BOM + CRLF");
    assert_eq!(t.meta("source"), Some("logger"));
    assert_eq!(t.t(), &[0.0, 0.1]);
    assert_eq!(col(&t, "x.pos"), &[0.002, 0.004]);
    // A BOM right before the header (no metadata) used to give a "1:1" error.
    let text = "\u{feff}t[s],x.cmd[mm],x.pos[mm]\r\n0,1,2\r\n";
    let t = Trace::from_csv_str(text, "bom.csv", None).expect("BOM before the header");
    assert_eq!(t.signals[0].name, "t");
}

#[test]
fn units_must_measure_what_the_signal_means() {
    let cases = [
        (
            "t[s],x.cmd[mm/s],x.pos[mm]",
            "column 2 'x.cmd[mm/s]': x.cmd is a length (m, mm, um), not a velocity",
        ),
        (
            "t[s],x.cmd[mm],x.pos[degC]",
            "column 3 'x.pos[degC]': x.pos is a length",
        ),
        (
            "t[mm],x.cmd[mm],x.pos[mm]",
            "column 1 't[mm]': t is a time (s, ms), not a length",
        ),
        (
            "t[s],x.cmd[mm],x.pos[mm],x.torque[N]",
            "column 4 'x.torque[N]': x.torque is a torque (N*m), not a force",
        ),
        (
            "t[s],x.cmd[mm],x.pos[mm],temp.screw[mm]",
            "temp.screw is a temperature (degC)",
        ),
        (
            "t[s],x.cmd[mm],x.pos[mm],mode[s]",
            "mode is a plain number (none), not a time",
        ),
        (
            "t[s],x.cmd,x.pos[mm]",
            "column 2 'x.cmd': x.cmd is a length (m, mm, um), not a plain number",
        ),
        (
            "t[s],x.cmd[mm],x.pos[mm],x.vel[N*m]",
            "x.vel is a velocity (m/s, mm/s, mm/min)",
        ),
    ];
    for (header, needle) in cases {
        let e =
            Trace::from_csv_str(&format!("{header}\n0,0,0,0\n"), "u.csv", None).expect_err(header);
        assert!(matches!(e, TraceError::Layout { .. }), "{e}");
        assert!(e.to_string().contains(needle), "{header}: {e}");
    }
    // The quadrant compensation may be a torque, a velocity or a position; unknown signals
    // keep any accepted unit.
    let ok = "t[ms],x.cmd[um],x.pos[m],x.quadrant_comp[N*m],y.cmd[mm],y.pos[mm],y.quadrant_comp[mm/s],x.quadrant_pa[mm/min],x.current[A],x.meas[mm],mode.ch2[]\n0,1,2,3,4,5,6,60,1,,0\n";
    let t = Trace::from_csv_str(ok, "ok.csv", None).expect("units fit");
    assert!((col(&t, "x.quadrant_pa")[0] - 0.001).abs() < 1e-18);
    assert_eq!(col(&t, "x.cmd"), &[1e-6]);
    // Mappings are checked the same way.
    let e = Mapping::parse("t[s]=t_s, x.cmd[N]=qg_m, x.pos[m]=qm_m").expect_err("bad unit");
    assert!(e.to_string().contains("x.cmd is a length"), "{e}");
}

#[test]
fn time_stamps_must_be_finite_and_increase_without_jumps() {
    let e = Trace::from_csv_str(
        &timed(20, |i| (i == 5).then(|| "inf".into())),
        "t.csv",
        None,
    )
    .expect_err("inf");
    assert_eq!(
        e.to_string(),
        "t.csv:7: column 1 't[s]': 'inf' is not a finite number"
    );
    let e = Trace::from_csv_str(
        &timed(20, |i| (i == 5).then(|| "0.004".into())),
        "t.csv",
        None,
    )
    .expect_err("repeat");
    assert_eq!(
        e.to_string(),
        "t.csv:7: time 0.004 s does not increase (line 6: 0.004 s)"
    );
    // One wild time stamp in a 1 kHz record: the jump into it and the step back, both naming it.
    let e = Trace::from_csv_str(
        &timed(20_000, |i| (i == 10_000).then(|| "1e17".into())),
        "j.csv",
        None,
    )
    .expect_err("jump");
    let TraceError::Rows {
        findings, omitted, ..
    } = &e
    else {
        panic!("{e}")
    };
    assert_eq!(*omitted, 0);
    assert_eq!(findings.len(), 2, "{e}");
    assert_eq!(findings[0].line, 10_002);
    assert!(
        findings[0].reason.starts_with("time 1e17 s jumps")
            && findings[0]
                .reason
                .contains("1000 × the median spacing 0.001 s"),
        "{e}"
    );
    assert_eq!(findings[1].line, 10_003);
    assert!(
        findings[1]
            .reason
            .contains("does not increase (line 10002: 1e17 s)"),
        "{e}"
    );
    // The last row too.
    let e = Trace::from_csv_str(
        &timed(2000, |i| (i == 1999).then(|| "1e17".into())),
        "j.csv",
        None,
    )
    .expect_err("last row jump");
    assert!(
        e.to_string().starts_with("j.csv:2001: time 1e17 s jumps"),
        "{e}"
    );
    // The rule: more than 1000 × the median spacing and more than 1 s. A 0.9 s pause in a
    // 1 kHz record, and a 5 s gap in a 10 Hz one, are records, not errors.
    Trace::from_csv_str(
        &timed(2000, |i| {
            (i >= 1000).then(|| format!("{}", 0.9 + i as f64 * 0.001))
        }),
        "p.csv",
        None,
    )
    .expect("a 0.9 s pause");
    let slow = |i: usize| {
        Some(format!(
            "{}",
            i as f64 * 0.1 + if i >= 50 { 5.0 } else { 0.0 }
        ))
    };
    Trace::from_csv_str(&timed(100, slow), "p.csv", None).expect("a 5 s gap at 10 Hz");
    let e = Trace::from_csv_str(
        &timed(2000, |i| {
            (i >= 1000).then(|| format!("{}", 5.0 + i as f64 * 0.001))
        }),
        "p.csv",
        None,
    )
    .expect_err("a 5 s gap at 1 kHz");
    assert!(
        e.to_string()
            .starts_with("p.csv:1002: time 6 s jumps 5.001 s after line 1001"),
        "{e}"
    );
}

#[test]
fn many_bad_rows_give_the_first_twenty_and_a_count() {
    let mut text = String::from("t[s],x.cmd[mm],x.pos[mm]\n");
    for i in 0..100_000 {
        text += &format!("{},abc,0\n", i as f64 * 0.001);
    }
    let e = Trace::from_csv_str(&text, "many.csv", None).expect_err("bad");
    let TraceError::Rows {
        findings, omitted, ..
    } = &e
    else {
        panic!("{e}")
    };
    assert_eq!(findings.len(), trace::MAX_REPORTED_ERRORS);
    assert_eq!(*omitted, 100_000 - 20);
    assert_eq!(findings[0].line, 2);
    assert_eq!(
        findings[0].reason,
        "column 2 'x.cmd[mm]': 'abc' is not a number"
    );
    let shown = e.to_string();
    assert!(shown.chars().count() < 4000, "{} chars", shown.len());
    assert!(
        shown.ends_with("… and 99980 more rows in error (100000 in all)"),
        "{shown}"
    );
    // Long cells are quoted short.
    let long = format!("t[s],x.cmd[mm],x.pos[mm]\n0,{},0\n", "x".repeat(100_000));
    let e = Trace::from_csv_str(&long, "long.csv", None).expect_err("bad");
    assert!(e.to_string().len() < 200, "{e}");
}

#[test]
fn cells_name_their_line_and_column() {
    let e = Trace::from_csv_str("t[s],x.cmd[mm],x.pos[mm]\n0,0,0\n0.1,0\n", "s.csv", None)
        .expect_err("short row");
    assert_eq!(
        e.to_string(),
        "s.csv:3: the row has 2 cells; the header has 3"
    );
    let e = Trace::from_csv_bytes(b"t[s],x.cmd[mm],x.pos[mm]\n0,0,\xff\n", "b.csv", None)
        .expect_err("not UTF-8");
    assert_eq!(
        e.to_string(),
        "b.csv:2: column 3 'x.pos[mm]': the cell is not UTF-8 text"
    );
    let e = Trace::from_csv_str("t[s],x.cmd[mm],x.pos[mm]\n,0,0\n", "e.csv", None)
        .expect_err("empty time");
    assert_eq!(e.to_string(), "e.csv:2: column 1 't[s]': time t is empty");
    // A finite value that overflows by a mapping's scale.
    let map = Mapping::parse("t[s]=t, x.cmd[m]=c*1e10, x.pos[m]=p").expect("mapping");
    let e = Trace::from_csv_str("t,c,p\n0,1e308,0\n", "o.csv", Some(&map)).expect_err("overflow");
    assert!(
        e.to_string()
            .contains("column 2 'c': '1e308' is out of range in m"),
        "{e}"
    );
    // Converting to SI cannot overflow: 1e308 mm is 1e305 m.
    let t =
        Trace::from_csv_str("t[s],x.cmd[mm],x.pos[mm]\n0,1e308,0\n", "o.csv", None).expect("large");
    assert_eq!(col(&t, "x.cmd"), &[1e305]);
    // Empty cells are "not measured", not errors.
    let t = Trace::from_csv_str("t[s],x.cmd[mm],x.pos[mm]\n0,0,\n", "ok.csv", None).expect("empty");
    assert!(col(&t, "x.pos")[0].is_nan());
}

#[test]
fn lines_are_bounded() {
    let long = format!(
        "# note: {}\nt[s],x.cmd[mm],x.pos[mm]\n0,0,0\n",
        "x".repeat(trace::MAX_LINE_BYTES)
    );
    let e = Trace::from_csv_str(&long, "m.csv", None).expect_err("long metadata");
    assert!(
        e.to_string().starts_with("m.csv:1: line longer than"),
        "{e}"
    );
    let long = format!(
        "# a: b\nt[s],x.cmd[mm],x.pos[mm]\n0,0,0\n0.1,{},0\n",
        "1".repeat(trace::MAX_LINE_BYTES)
    );
    let e = Trace::from_csv_str(&long, "r.csv", None).expect_err("long row");
    assert!(
        e.to_string()
            .starts_with("r.csv:4: line longer than 1048576 bytes"),
        "{e}"
    );
}

#[test]
fn readers_bytes_and_files_read_the_same() {
    let m = run(&plain(), "G90 G01 X3 F2000\nM30\n");
    let dir = tempfile::tempdir().expect("tmp dir");
    let path = dir.path().join("same.csv");
    m.trace.write_csv(&path).expect("write");
    let bytes = std::fs::read(&path).expect("read back");
    let a = Trace::read_csv(&path, None).expect("file");
    let b = Trace::from_csv_bytes(&bytes, "same.csv", None).expect("bytes");
    let c = Trace::from_reader(std::io::Cursor::new(&bytes), "same.csv", None).expect("reader");
    assert_eq!(a, b);
    assert_eq!(a, c);
}

/// `v` (SI) in unit `u`'s cell text, read back through a one-row trace as signal `sig`.
fn cell_round_trip(v: f64, u: &str, sig: &str) -> f64 {
    let unit = trace::unit(u).expect("accepted unit");
    let mut cell = String::new();
    trace::push_value(&mut cell, v, unit);
    let text = format!("t[s],x.cmd[mm],x.pos[mm],{sig}[{u}]\n0,0,0,{cell}\n");
    let t = Trace::from_csv_str(&text, "p.csv", None).unwrap_or_else(|e| panic!("{v}: {e}"));
    col(&t, sig)[0]
}

/// Any finite f64: every exponent, subnormals and both zeros included.
fn finite() -> impl proptest::strategy::Strategy<Value = f64> {
    use proptest::prelude::*;
    prop_oneof![
        any::<u64>().prop_map(f64::from_bits),
        -1.0e3..1.0e3_f64,
        (-1.0e6..1.0e6_f64).prop_map(|x| x.round() / 1e4),
    ]
    .prop_filter("finite", |v| v.is_finite())
}

proptest::proptest! {
    #![proptest_config(proptest::test_runner::Config::with_cases(2000))]

    #[test]
    fn any_finite_value_reads_back_bit_identical_from_mm_um_and_mm_per_s(v in finite()) {
        for (u, sig) in [("mm", "x.meas"), ("um", "x.meas"), ("mm/s", "x.vel")] {
            let back = cell_round_trip(v, u, sig);
            proptest::prop_assert_eq!(back.to_bits(), v.to_bits(), "{} {} read back as {}", v, u, back);
        }
    }

    #[test]
    fn any_finite_value_round_trips_through_the_writer(v in finite(), w in finite()) {
        let mut tr = Trace::new();
        tr.signals[0].data = vec![0.0, 1.0];
        for (name, unit) in [("x.cmd", "m"), ("x.pos", "m"), ("x.vel", "m/s"), ("x.force", "N")] {
            let i = tr.add_signal(name, unit);
            tr.signals[i].data = vec![v, w];
        }
        let mut csv = Vec::new();
        tr.write_csv_to(&mut csv).expect("writes");
        let text = String::from_utf8(csv).expect("utf8");
        let back = Trace::from_csv_str(&text, "w.csv", None).expect("reads");
        for (a, b) in tr.signals.iter().zip(&back.signals) {
            proptest::prop_assert_eq!(&a.unit, &b.unit);
            let bits = |s: &trace::Signal| s.data.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            proptest::prop_assert_eq!(bits(a), bits(b), "{} in\n{}", a.name, text);
        }
    }
}

#[test]
fn cells_are_written_in_display_units_as_exact_decimals() {
    let mut tr = Trace::new();
    tr.signals[0].data = vec![0.0, 0.00025];
    for (name, unit, data) in [
        ("x.cmd", "m", [0.001, 0.1 + 0.2]),
        ("x.pos", "m", [-1.25e-13, 2.0e20]),
        ("x.vel", "m/s", [0.05, -0.0]),
        ("x.force", "N", [12.5, 1e-7]),
    ] {
        let i = tr.add_signal(name, unit);
        tr.signals[i].data = data.to_vec();
    }
    let mut csv = Vec::new();
    tr.write_csv_to(&mut csv).expect("writes");
    let text = String::from_utf8(csv).expect("utf8");
    assert_eq!(
        text,
        "t[s],x.cmd[mm],x.pos[mm],x.vel[mm/s],x.force[N]\n\
         0.0,1,-1.25e-10,50,12.5\n\
         0.00025,300.00000000000004,2e23,-0,1e-7\n"
    );
}

/// A simulated trace of every signal a shipped preset records (compensations included)
/// reads back from its CSV bit for bit.
#[test]
fn a_simulated_trace_reads_back_bit_for_bit() {
    for name in [
        "vertical_z_gravity.ron",
        "vertical_lathe_crossbeam.ron",
        "thermal_warmup.ron",
    ] {
        let lp = axisbench::preset::load_embedded(name).expect("preset");
        let mut m = axisbench::Machine::from_loaded(&lp).expect("machine");
        m.run(2.0).expect("runs");
        let mut csv = Vec::new();
        m.trace.write_csv_to(&mut csv).expect("writes");
        let text = String::from_utf8(csv).expect("utf8");
        assert!(
            text.contains(",x.cmd[mm],") || text.contains(",z.cmd[mm],"),
            "{name}"
        );
        let back = Trace::from_csv_str(&text, name, None).expect("reads");
        assert_eq!(back.meta, m.trace.meta, "{name}");
        assert_eq!(back.signals.len(), m.trace.signals.len(), "{name}");
        for (a, b) in m.trace.signals.iter().zip(&back.signals) {
            assert_eq!((&a.name, &a.unit), (&b.name, &b.unit), "{name}");
            let differ = a
                .data
                .iter()
                .zip(&b.data)
                .position(|(x, y)| x.to_bits() != y.to_bits() && !(x.is_nan() && y.is_nan()));
            assert_eq!(differ, None, "{name}: {} changed", a.name);
        }
    }
}

/// The streaming append writes exactly the staged rows, whatever the alignment of the
/// column's end, the row count's parity, or whether the room was reserved.
#[test]
fn staged_rows_append_exactly_at_any_alignment() {
    for (pre, rows, reserve) in [
        (0, 5, true),
        (1, 5, true),
        (1, 4, true),
        (3, 1, true),
        (2, 7, false),
        // Long enough for whole-line (up to 64-byte) streaming stores between a head and a
        // tail at every start within a line.
        (0, 64, true),
        (1, 63, true),
        (2, 40, true),
        (3, 37, true),
        (5, 17, true),
        (6, 24, true),
        (7, 33, true),
        (9, 50, false),
    ] {
        let mut t = Trace::new();
        t.add_signal("a", "m");
        t.add_signal("b", "N");
        for i in 0..pre {
            for s in &mut t.signals {
                s.data.push(-(i as f64));
            }
        }
        if reserve {
            t.reserve_rows(rows);
        }
        let stride = 64;
        let n = t.signals.len();
        let stage: Vec<f64> = (0..n * stride).map(|i| i as f64 + 0.5).collect();
        t.append_staged(&stage, stride, rows);
        for (c, s) in t.signals.iter().enumerate() {
            let want: Vec<f64> = (0..pre)
                .map(|i| -(i as f64))
                .chain((0..rows).map(|r| (c * stride + r) as f64 + 0.5))
                .collect();
            assert_eq!(s.data, want, "pre {pre}, rows {rows}, reserved {reserve}");
        }
    }
}

/// A flush inside a run appends only the rows that end the columns on a cache line, so that
/// no line is written in part: at most a line's worth (eight values) waits, and the end
/// lands on a 64-byte boundary at every start within a line.
#[test]
fn a_flush_inside_a_run_ends_the_columns_on_a_cache_line() {
    for pre in 0..12 {
        let mut t = Trace::new();
        t.add_signal("a", "m");
        t.reserve_rows(10_000);
        for s in &mut t.signals {
            s.data.extend((0..pre).map(f64::from));
        }
        for rows in [8, 9, 128, 133] {
            let n = t.line_aligned_rows(rows);
            let col = &t.signals[0].data;
            let end = col.as_ptr() as usize + 8 * (col.len() + n);
            assert_eq!(end % 64, 0, "pre {pre}, rows {rows}: {n} rows end mid-line");
            assert!(n + 8 > rows && n <= rows, "pre {pre}, rows {rows}: {n}");
        }
    }
    // Without reserved room nothing is held back (the column may move when it grows).
    let t = Trace::new();
    assert_eq!(t.line_aligned_rows(5), 5);
}

/// A foreign layout read under a preset without its mapping names the columns found, the
/// preset that maps them and `--map`; a native trace is read as native under any preset,
/// and its own bad row is what is reported.
#[test]
fn layout_errors_say_which_preset_or_mapping_reads_the_file() {
    use axisbench::diagnose::read_record_bytes;
    use axisbench::preset::load_embedded;
    let default = load_embedded("default.ron").expect("default").preset;
    let emps = load_embedded("emps.ron").expect("emps").preset;
    let foreign = "t_s,qg_m,qm_m,vir_V,force_N\n0,0,0,0,0\n0.001,0,0,0,0\n";
    let e = read_record_bytes(foreign.as_bytes(), "emps.csv", &default, None)
        .expect_err("not readable without a mapping")
        .to_string();
    for want in ["emps.csv", "t_s, qg_m", "`emps.ron`", "--map"] {
        assert!(e.contains(want), "missing {want:?} in: {e}");
    }
    // Under emps.ron the mapping reads it.
    assert!(read_record_bytes(foreign.as_bytes(), "emps.csv", &emps, None).is_ok());
    // A layout no shipped preset maps: the columns and how to give a mapping.
    let other = "time,position\n0,0\n";
    let e = read_record_bytes(other.as_bytes(), "odd.csv", &emps, None)
        .expect_err("no mapping reads it")
        .to_string();
    assert!(
        e.contains("odd.csv") && e.contains("time") && e.contains("wants the columns"),
        "{e}"
    );
    // A native trace whose time goes backwards, read under emps.ron: the bad line, not the
    // mapping's complaint.
    let mut native = String::from("t[s],x.cmd[mm],x.pos[mm]\n");
    for i in 0..20 {
        let t = if i == 12 { 0.0001 } else { i as f64 * 0.001 };
        native += &format!("{t},0,0\n");
    }
    for p in [&default, &emps] {
        let e = read_record_bytes(native.as_bytes(), "native.csv", p, None)
            .expect_err("time goes backwards")
            .to_string();
        assert!(
            e.contains("native.csv:14") && e.contains("does not increase"),
            "{e}"
        );
    }
}
