//! Trace CSV: round trip, units, mappings, and every bad-input class.

use std::path::PathBuf;

use axisbench::trace::{Mapping, Trace, TraceError};

use crate::common::{plain, run};

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("axisbench-it-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp dir");
    dir.join(name)
}

#[test]
fn csv_round_trip_is_exact() {
    let m = run(&plain(), "G90 G01 X12.345 F2000\nM30\n");
    let path = tmp("rt.csv");
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
    assert_eq!(t.t(), &[0.0, 0.001]);
    assert_eq!(t.values("x.cmd").expect("cmd"), &[1.0, 2.0]);
    assert_eq!(t.values("x.pos").expect("pos"), &[1.0, 2.0]);
    assert_eq!(t.values("x.vel").expect("vel"), &[1.0, 2.0]);
    let meas = t.values("x.meas").expect("meas");
    assert!(meas[0].is_nan() && meas[1] == 2.5);
    assert_eq!(t.signal("x.vel").map(|s| s.unit.as_str()), Some("mm/s"));
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
    assert_eq!(t.values("x.cmd").expect("cmd"), &[1.0, 2.0]);
    assert_eq!(t.values("x.pos").expect("pos"), &[0.5, 1.5]);
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
    let pos = t.values("x.pos").expect("pos");
    let max = pos.iter().cloned().fold(f64::MIN, f64::max);
    assert!((max - 246.378).abs() < 0.01, "max position {max} mm");
}
