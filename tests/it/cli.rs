//! The binary, as a user runs it.

use std::process::Command;

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_axisbench"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

#[test]
fn simulate_writes_a_trace_and_prints_a_summary() {
    let tmp_out = tempfile::tempdir().expect("tempdir");
    let out = tmp_out.path().join("axisbench-cli.csv");
    let o = bin()
        .args(["simulate", "--preset", "presets/default.ron", "--out"])
        .arg(&out)
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        stdout.contains("samples:") && stdout.contains("following error max"),
        "{stdout}"
    );
    assert!(stdout.contains("reversal + -> -"), "{stdout}");
    let t = axisbench::Trace::read_csv(&out, None).expect("valid trace");
    assert_eq!(t.axes(), vec!["x".to_owned()]);
    let _ = std::fs::remove_file(out);
}

#[test]
fn validate_exits_nonzero_listing_errors() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path().join("axisbench-cli-v");
    std::fs::create_dir_all(&dir).expect("dir");
    let bad = dir.join("bad.ron");
    let text = axisbench::preset::embedded("default.ron")
        .expect("embedded")
        .replace("table_mass_kg: 300.0", "table_mass_kg: -3.0")
        .replace("coulomb_n: 250.0", "coulomb_n: NaN");
    std::fs::write(&bad, text).expect("write");
    let o = bin().arg("validate").arg(&bad).output().expect("runs");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("table_mass_kg") && stderr.contains("coulomb_n"),
        "{stderr}"
    );
    let o = bin()
        .args(["validate", "presets/default.ron", "presets/emps.ron"])
        .output()
        .expect("runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn no_display_points_to_the_cli() {
    let o = bin()
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("no display") && stderr.contains("axisbench simulate"),
        "{stderr}"
    );
}

#[test]
fn a_bad_program_names_its_line() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path().join("axisbench-cli-p");
    std::fs::create_dir_all(&dir).expect("dir");
    let prog = dir.join("bad.ngc");
    std::fs::write(&prog, "G90 G01 F1000\nX10\nG42 X3\n").expect("write");
    let o = bin()
        .args(["simulate", "--program"])
        .arg(&prog)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("bad.ngc:3:1") && stderr.contains("G42"),
        "{stderr}"
    );
}

#[test]
fn export_and_import_through_the_binary() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().to_path_buf();
    let o = bin()
        .args([
            "export",
            "--preset",
            "presets/vertical_z_gravity.ron",
            "--to",
            "linuxcnc",
            "--horizon",
            "5",
            "--out",
        ])
        .arg(dir.join("lcnc"))
        .output()
        .expect("runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("linuxcnc.ini") && stdout.contains("not representable"),
        "{stdout}"
    );
    let out = dir.join("tuned.ron");
    let o = bin()
        .args(["import", "--from", "linuxcnc", "--in"])
        .arg(dir.join("lcnc"))
        .args(["--base", "presets/vertical_z_gravity.ron", "--out"])
        .arg(&out)
        .output()
        .expect("runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let back = axisbench::preset::load(&out.display().to_string()).expect("valid preset");
    let orig = axisbench::preset::load("presets/vertical_z_gravity.ron").expect("preset");
    assert_eq!(
        back.preset, orig.preset,
        "export → import onto itself is exact"
    );
    assert!(
        dir.join("vertical_z_gravity.ngc").is_file(),
        "program copied"
    );
    let o = bin()
        .args([
            "export",
            "--preset",
            "presets/default.ron",
            "--to",
            "mazak",
            "--out",
        ])
        .arg(dir.join("x"))
        .output()
        .expect("runs");
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("targets are: ron, linuxcnc"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn diagnose_runs_the_documented_emps_command() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path().join("axb-diag");
    std::fs::create_dir_all(&dir).expect("tmp");
    let report = dir.join("emps.json");
    let out = bin()
        .args([
            "diagnose",
            "--preset",
            "presets/emps.ron",
            "--trace",
            "../shared/data/real/emps/emps_train_DATA_EMPS.csv",
            "--validate",
            "../shared/data/real/emps/emps_test_DATA_EMPS_PULSES.csv",
            "--report",
        ])
        .arg(&report)
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("VERDICT: coulomb_friction"), "{stdout}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(json["verdict"], "coulomb_friction");
    assert_eq!(json["selected"][0], "coulomb_friction");
    let first = &json["ranking"][0];
    for key in [
        "effect",
        "params",
        "fit_rms_before",
        "fit_rms_after",
        "holdout_rms_before",
        "holdout_rms_after",
        "shrink",
    ] {
        assert!(!first[key].is_null(), "ranking entry lacks {key}: {first}");
    }
    for key in ["name", "share", "rms", "peak"] {
        assert!(!json["regimes"][0][key].is_null(), "regime lacks {key}");
    }
    for key in ["t_start", "t_end", "peak"] {
        assert!(!json["windows"][0][key].is_null(), "window lacks {key}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn diagnose_names_a_missing_column() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path().join("axb-diag-bad");
    std::fs::create_dir_all(&dir).expect("tmp");
    let f = dir.join("bad.csv");
    std::fs::write(&f, "t_s,qg_m,force_N\n0,0,0\n0.001,0,0\n").expect("write");
    let out = bin()
        .args(["diagnose", "--preset", "presets/emps.ron", "--trace"])
        .arg(&f)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("qm_m"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every entry of `dir` with its bytes (None for a folder), sorted: what "the folder is
/// exactly as it was" compares.
fn snapshot(dir: &std::path::Path) -> Vec<(String, Option<Vec<u8>>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .expect("dir")
        .flatten()
        .map(|e| {
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).ok(),
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn an_export_blocked_by_a_folder_fails_once_and_changes_nothing() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("out");
    std::fs::create_dir_all(out.join("mapping_report.md")).expect("folder in the way");
    std::fs::write(out.join("linuxcnc.ini"), "previous export\n").expect("old file");
    let before = snapshot(&out);
    let o = bin()
        .args([
            "export",
            "--preset",
            "presets/default.ron",
            "--to",
            "linuxcnc",
            "--horizon",
            "1",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert_eq!(stderr.lines().count(), 1, "one message: {stderr}");
    assert!(
        stderr.contains("mapping_report.md")
            && stderr.contains("a folder of that name is in the way"),
        "{stderr}"
    );
    assert_eq!(
        snapshot(&out),
        before,
        "linuxcnc.ini kept, no staging folder left"
    );
}

#[test]
fn read_failures_say_cannot_read_once() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let missing = tmp.path().join("nothere");
    let out = tmp.path().join("x.ron");
    let m = missing.as_os_str();
    for args in [
        vec![
            "import".as_ref(),
            "--from".as_ref(),
            "linuxcnc".as_ref(),
            "--in".as_ref(),
            m,
        ],
        vec![
            "import".as_ref(),
            "--from".as_ref(),
            "ron".as_ref(),
            "--in".as_ref(),
            m,
        ],
        vec![
            "import".as_ref(),
            "--from".as_ref(),
            "linuxcnc".as_ref(),
            "--in".as_ref(),
            "presets".as_ref(),
            "--base".as_ref(),
            m,
        ],
    ] {
        let args: Vec<&std::ffi::OsStr> = args;
        let mut c = bin();
        c.args(&args).arg("--out").arg(&out);
        let o = c.output().expect("runs");
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success());
        assert!(stderr.contains("cannot read"), "{args:?}: {stderr}");
        assert!(!stderr.contains("cannot write"), "{args:?}: {stderr}");
        assert_eq!(
            stderr.matches("No such file or directory").count(),
            1,
            "{args:?}: the OS text once: {stderr}"
        );
        assert_eq!(
            stderr.matches(&*missing.display().to_string()).count(),
            1,
            "{args:?}: the path once: {stderr}"
        );
        assert!(!out.exists());
    }
}
