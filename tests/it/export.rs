//! Export, import and the mapping report: round trips, target limits, the LinuxCNC output
//! checker, and the simulated errors of approximations.

use std::path::PathBuf;
use std::process::Command;

use axisbench::export::{self, ExportError, ExportOptions, Status, Target, linuxcnc};
use axisbench::preset::comp::OutputMode;
use axisbench::preset::{self, LoadedPreset, Preset};

/// A scratch folder `name` inside a temporary folder that is removed when the guard drops
/// (also when the test fails).
fn scratch(name: &str) -> (tempfile::TempDir, PathBuf) {
    let t = tempfile::tempdir().expect("tempdir");
    let d = t.path().join(name);
    (t, d)
}

fn shipped(name: &str) -> (LoadedPreset, Vec<(String, String)>) {
    let lp = preset::load_embedded(name).expect("shipped preset");
    let progs = lp
        .preset
        .scenario
        .programs
        .iter()
        .map(|p| (p.clone(), lp.program_text(p).expect("program")))
        .collect();
    (lp, progs)
}

fn opts() -> ExportOptions {
    ExportOptions {
        horizon_s: Some(20.0),
    }
}

/// The default preset with a lead error (cyclic + cumulative + measured table) and a
/// per-direction backlash.
fn lead_and_backlash() -> Preset {
    let mut p = preset::load_embedded("default.ron")
        .expect("default")
        .preset;
    let a = &mut p.axes[0];
    a.backlash.q_um = 12.5;
    a.backlash.plus_to_minus.mode = OutputMode::Distance;
    a.lead_error.enabled = true;
    a.lead_error.amplitude_um = 0.0;
    a.lead_error.cumulative_um_per_m = 30.0;
    a.lead_error.table = vec![(0.0, 0.0), (25.0, 3.5), (60.0, -1.25), (100.0, 2.0)];
    p
}

#[test]
fn ron_round_trip_is_exact_for_every_shipped_preset() {
    for name in preset::SHIPPED_PRESETS {
        let (lp, progs) = shipped(name);
        let ex = export::export(&lp.preset, &progs, Target::Ron, &opts()).expect("exports");
        let (_t, dir) = scratch(&format!("ron-{name}"));
        ex.write(&dir).expect("writes");
        let back = export::import::import(Target::Ron, &dir, &lp).expect("imports");
        assert_eq!(back, lp.preset, "{name}: RON round trip");
        // The exported folder loads on its own (programs next to the preset).
        let again = preset::load(&dir.join("preset.ron").display().to_string()).expect("loads");
        axisbench::Machine::from_loaded(&again).expect("runs from the exported folder");
    }
}

#[test]
fn linuxcnc_round_trip_gives_back_what_is_representable() {
    let (lp, progs) = shipped("default.ron");
    for (label, p) in [
        ("default", lp.preset.clone()),
        ("lead", lead_and_backlash()),
        ("lathe", shipped("vertical_lathe_crossbeam.ron").0.preset),
    ] {
        let progs = if label == "lathe" {
            shipped("vertical_lathe_crossbeam.ron").1
        } else {
            progs.clone()
        };
        let ex = export::export(&p, &progs, Target::Linuxcnc, &opts()).expect("exports");
        let (_t, dir) = scratch(&format!("lcnc-rt-{label}"));
        ex.write(&dir).expect("writes");
        let ini = dir.join("linuxcnc.ini");
        let base = LoadedPreset {
            preset: p.clone(),
            dir: None,
            origin: "test".into(),
        };
        // Onto the preset itself: everything comes back bit for bit.
        let same = export::import::import(Target::Linuxcnc, &ini, &base).expect("imports");
        assert_eq!(same, p, "{label}: import onto the exported preset is exact");
        // Onto a base that differs in every representable field: those come back.
        let mut other = p.clone();
        other.nc.rapid_mm_per_min = 5000.0;
        other.nc.accdec.tc1_s = 0.2;
        for a in &mut other.axes {
            a.backlash.q_um = 1.0;
            a.backlash.enabled = true;
            a.lead_error.enabled = false;
        }
        let base = LoadedPreset {
            preset: other,
            dir: None,
            origin: "test".into(),
        };
        let back = export::import::import(Target::Linuxcnc, &ini, &base).expect("imports");
        let rel = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1.0);
        assert!(
            rel(back.nc.rapid_mm_per_min, p.nc.rapid_mm_per_min),
            "{label}: rapid"
        );
        for (a, b) in back.axes.iter().zip(&p.axes) {
            let la = export::axis_limits(&back, a);
            let lb = export::axis_limits(&p, b);
            assert!(
                rel(la.max_acc_mm_s2, lb.max_acc_mm_s2),
                "{label}: acceleration"
            );
            assert_eq!(
                a.backlash.enabled, b.backlash.enabled,
                "{label}: backlash on"
            );
            if b.backlash.enabled {
                assert!(
                    rel(a.backlash.q_um, b.backlash.q_um),
                    "{label}: Q {} vs {}",
                    a.backlash.q_um,
                    b.backlash.q_um
                );
            }
            assert_eq!(
                a.lead_error.enabled, b.lead_error.enabled,
                "{label}: lead error"
            );
            if b.lead_error.enabled {
                // The measured table is piecewise linear: the comp table carries it exactly.
                for &(x, e) in &b.lead_error.table {
                    let got = export::lead_error_um(&a.lead_error, x);
                    let want = export::lead_error_um(&b.lead_error, x);
                    assert!(
                        (got - want).abs() < 1e-9,
                        "{label}: lead error at {x}: {got} vs {want} ({e})"
                    );
                }
            }
        }
    }
}

#[test]
fn a_lead_table_is_exact_and_backlash_goes_into_the_fwd_rev_columns() {
    let p = lead_and_backlash();
    let (_, progs) = shipped("default.ron");
    let ex = export::export(&p, &progs, Target::Linuxcnc, &opts()).expect("exports");
    let ini = &ex
        .files
        .iter()
        .find(|f| f.0 == "linuxcnc.ini")
        .expect("ini")
        .1;
    assert!(ini.contains("COMP_FILE = joint0.comp") && ini.contains("COMP_FILE_TYPE = 1"));
    assert!(
        ini.contains("BACKLASH = 0\n"),
        "BACKLASH is ignored with a table: 0"
    );
    let comp = &ex
        .files
        .iter()
        .find(|f| f.0 == "joint0.comp")
        .expect("comp")
        .1;
    let (rows, issues) = linuxcnc::parse_comp_file(comp, "joint0.comp", 1);
    assert!(issues.is_empty(), "{issues:?}");
    for r in &rows {
        assert!((r.fwd - r.rev - 0.0125).abs() < 1e-15, "fwd − rev = Q");
        let pitch_um = -0.5 * (r.fwd + r.rev) * 1e3;
        let e = export::lead_error_um(&p.axes[0].lead_error, r.nominal);
        assert!(
            (pitch_um - e).abs() < 1e-9,
            "trims cancel the lead error at {}",
            r.nominal
        );
    }
    let pitch = ex
        .report
        .entries
        .iter()
        .find(|e| e.field == "axes.x.lead_error")
        .expect("lead error in the report");
    assert_eq!(
        pitch.status,
        Status::Derived,
        "a piecewise-linear error is carried exactly"
    );
    assert!(pitch.error.as_ref().expect("residual").correction_max_um < 1e-9);
}

#[test]
fn the_report_simulates_what_linuxcnc_cannot_carry() {
    let (lp, progs) = shipped("vertical_z_gravity.ron");
    let ex = export::export(&lp.preset, &progs, Target::Linuxcnc, &opts()).expect("exports");
    let q = lp.preset.axes[0].backlash.q_um;
    let bl = ex
        .report
        .entries
        .iter()
        .find(|e| e.field.ends_with(".backlash.q_um"))
        .expect("backlash row");
    assert_eq!(bl.status, Status::Approximated);
    let f = bl.error.as_ref().expect("simulated");
    // The symmetric ±Q/2 split is the preset's one-sided correction shifted by Q/2.
    assert!(
        (f.constant_offset_um.abs() - q / 2.0).abs() < 1e-6,
        "offset {}",
        f.constant_offset_um
    );
    // The distance-spread +→− reversal and the ramp differ from the preset's output, but
    // by less than the whole amount.
    assert!(
        f.correction_max_um > 0.1 && f.correction_max_um <= q + 1e-6,
        "{f:?}"
    );
    let mode = ex
        .report
        .entries
        .iter()
        .find(|e| e.setting().contains("plus_to_minus.mode = distance"))
        .expect("distance mode row");
    assert_eq!(mode.status, Status::NotRepresentable);
    let md = ex.report.to_markdown();
    assert!(
        md.contains("not representable") && md.contains("homing absorbs"),
        "{md}"
    );
    // SINUMERIK outputs the backlash as a step: the distance spreading is what is lost.
    let ex = export::export(&lp.preset, &progs, Target::Siemens, &opts()).expect("exports");
    let lump = ex
        .report
        .entries
        .iter()
        .find(|e| e.setting().contains("plus_to_minus.mode = distance"))
        .expect("distance mode row");
    let f = lump.error.as_ref().expect("simulated");
    assert!(
        f.correction_max_um > 0.5 && f.correction_max_um <= q + 1e-6,
        "{f:?}"
    );
    assert_eq!(f.constant_offset_um, 0.0);
}

#[test]
fn omitted_compensations_cost_what_the_simulation_says() {
    // Quadrant (torque TFF) cannot go to LinuxCNC: the position error grows without it.
    let (lp, progs) = shipped("short_stroke_quadrant.ron");
    let ex = export::export(&lp.preset, &progs, Target::Linuxcnc, &opts()).expect("exports");
    let q = ex
        .report
        .entries
        .iter()
        .find(|e| e.field.ends_with(".quadrant"))
        .expect("quadrant row");
    assert_eq!(q.status, Status::NotRepresentable);
    let f = q.error.as_ref().expect("simulated");
    assert!(f.position_error_max_um.unwrap_or(0.0) > 1.0, "{f:?}");
    // The cross tables of the vertical lathe: the sag they correct is the error.
    let (lp, progs) = shipped("vertical_lathe_crossbeam.ron");
    let ex = export::export(&lp.preset, &progs, Target::Linuxcnc, &opts()).expect("exports");
    let crosses: Vec<_> = ex
        .report
        .entries
        .iter()
        .filter(|e| e.field.starts_with("cross."))
        .collect();
    assert_eq!(crosses.len(), 4);
    // Each row is the error of omitting that table alone. The left post travels the
    // beam, so its own sag table (cross[0], up to 75.6 µm mid-span) is the big one.
    let err = |i: usize| {
        crosses[i]
            .error
            .as_ref()
            .expect("simulated")
            .correction_max_um
    };
    assert!(err(0) > 30.0 && err(0) < 76.0, "cross[0]: {}", err(0));
    assert!(err(3) > 1.0, "cross[3]: {}", err(3));
    // SINUMERIK, HEIDENHAIN carry them: mapped, no error.
    for t in [Target::Siemens, Target::Heidenhain] {
        let ex = export::export(&lp.preset, &progs, t, &opts()).expect("exports");
        assert_eq!(
            ex.report
                .entries
                .iter()
                .filter(|e| e.field.starts_with("cross.") && e.status == Status::Mapped)
                .count(),
            4,
            "{t:?}"
        );
    }
}

#[test]
fn every_target_exports_every_shipped_preset_with_a_report_row_per_compensation() {
    for name in preset::SHIPPED_PRESETS {
        let (lp, progs) = shipped(name);
        for t in Target::ALL {
            let ex = export::export(&lp.preset, &progs, t, &opts())
                .unwrap_or_else(|e| panic!("{name} → {t:?}: {e}"));
            // Every target writes its files for what it carries (a quadrant-only preset
            // gives Beckhoff nothing to list); the report is always written.
            assert!(!ex.report.entries.is_empty(), "{name} → {t:?}: report");
            if t == Target::Ron {
                continue;
            }
            for a in &lp.preset.axes {
                for (on, what) in [
                    (a.backlash.enabled, "backlash"),
                    (a.quadrant.enabled, "quadrant"),
                    (a.thermal.enabled, "thermal"),
                ] {
                    if on {
                        assert!(
                            ex.report
                                .entries
                                .iter()
                                .any(|e| e.field.starts_with(&format!("axes.{}.{what}", a.name))),
                            "{name} → {t:?}: no row for {}.{what}",
                            a.name
                        );
                    }
                }
            }
            for e in &ex.report.entries {
                if matches!(e.status, Status::NotRepresentable | Status::Approximated)
                    && e.error.is_none()
                {
                    assert!(
                        e.note.contains("Not simulated")
                            || e.note.contains("row")
                            || e.note.contains("loop gains"),
                        "{name} → {t:?}: '{}' has no error figure and does not say why",
                        e.setting()
                    );
                }
            }
        }
    }
}

#[test]
fn target_limits_are_all_listed_and_nothing_is_written() {
    let mut p = lead_and_backlash();
    p.axes[0].lead_error.table = (0..300).map(|i| (i as f64, (i % 7) as f64)).collect();
    p.axes[0].backlash.q_um = 20_000.0; // 20 mm: beyond FANUC's ±9999 detection units
    let (_, progs) = shipped("default.ron");
    let err = export::export(&p, &progs, Target::Linuxcnc, &opts()).expect_err("too long");
    let ExportError::Violations { violations, .. } = &err else {
        panic!("{err}")
    };
    assert!(
        violations
            .iter()
            .any(|v| v.location == "axes.x.lead_error.table" && v.reason.contains("256")),
        "{err}"
    );
    let err = export::export(&p, &progs, Target::Fanuc, &opts()).expect_err("out of range");
    assert!(err.to_string().contains("1851"), "{err}");
    // An invalid preset: every field problem and the target limit, in one error.
    let mut bad = p.clone();
    bad.axes[0].servo.kp_per_s = f64::NAN;
    bad.cross = vec![axisbench::preset::comp::CrossTable {
        enabled: true,
        base_axis: "x".into(),
        comp_axis: "nope".into(),
        points: vec![(0.0, 1.0), (0.0, 2.0)],
    }];
    // Every target lists the preset's problems without tripping over them.
    for t in Target::ALL {
        let e = export::export(&bad, &progs, t, &opts()).expect_err("invalid");
        assert!(e.to_string().contains("servo.kp_per_s"), "{t:?}: {e}");
    }
    let mut empty = bad.clone();
    empty.cross[0].points.clear();
    for t in Target::ALL {
        let e = export::export(&empty, &progs, t, &opts()).expect_err("invalid");
        assert!(e.to_string().contains("cross.0.points"), "{t:?}: {e}");
    }
    let err = export::export(&bad, &progs, Target::Linuxcnc, &opts()).expect_err("invalid");
    let text = err.to_string();
    for needle in [
        "servo.kp_per_s",
        "cross.0.points.1",
        "no axis named 'nope'",
        "lead_error.table",
        "nothing was written",
    ] {
        assert!(text.contains(needle), "missing '{needle}' in:\n{text}");
    }
    // Through the command line: a clear error and no folder.
    let (_t, dir) = scratch("bad-cli");
    std::fs::create_dir_all(&dir).expect("dir");
    let pf = dir.join("bad.ron");
    std::fs::write(&pf, p.to_ron().expect("ron")).expect("write");
    std::fs::write(
        dir.join("default.ngc"),
        preset::embedded("default.ngc").expect("ngc"),
    )
    .expect("write");
    let out = dir.join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_axisbench"))
        .args(["export", "--to", "linuxcnc", "--preset"])
        .arg(&pf)
        .arg("--out")
        .arg(&out)
        .output()
        .expect("runs");
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("lead_error.table") && stderr.contains("256"),
        "{stderr}"
    );
    assert!(!out.exists(), "nothing was written");
}

#[test]
fn the_checker_catches_what_linuxcnc_accepts_silently() {
    let ini = "[JOINT_0]\nMAX_VELOCITY = 10\nMAX_ACCELERATION = 100\nFERROR = 1\nMIN_FERROR = 0.1\nBACKLASH = 0\nCOMP_FILE = j.comp\nCOMP_FILE_TYPE = 1\n";
    let check = |comp: &str| {
        linuxcnc::check_outputs(&[
            ("linuxcnc.ini".into(), ini.into()),
            ("j.comp".into(), comp.into()),
        ])
    };
    assert!(
        check("0 0.01 -0.01\n10 0.02 -0.01\n").is_empty(),
        "a good file passes"
    );
    for (comp, at, needle) in [
        ("0 nan -0.01\n10 0.02 -0.01\n", "j.comp:1", "NaN"),
        ("nominal fwd rev\n0 0.01 -0.01\n", "j.comp:1", "a header"),
        ("# comp\n0 0.01 -0.01\n", "j.comp:1", "comment"),
        ("0,0.01,-0.01\n", "j.comp:1", "comma"),
        ("0 0.01 -0.01\n\n10 0.02 -0.01\n", "j.comp:2", "blank line"),
        ("0 0.01 -0.01\n0 0.02 -0.01\n", "j.comp:2", "must increase"),
        ("", "j.comp", "empty"),
    ] {
        let v = check(comp);
        assert!(
            v.iter()
                .any(|v| v.location == at && v.reason.contains(needle)),
            "{comp:?}: expected '{needle}' at {at}, got {v:?}"
        );
    }
    let many: String = (0..300).map(|i| format!("{i} 0 0\n")).collect();
    assert!(check(&many).iter().any(|v| v.reason.contains("300 rows")));
    let empty_cf = linuxcnc::check_outputs(&[(
        "linuxcnc.ini".into(),
        "[JOINT_0]\nCOMP_FILE =\n[AXIS_X]\nBACKLASH = 0.01\n".into(),
    )]);
    assert!(
        empty_cf.iter().any(|v| v.reason.contains("empty")),
        "{empty_cf:?}"
    );
    assert!(
        empty_cf
            .iter()
            .any(|v| v.location.contains("[AXIS_X]BACKLASH")),
        "{empty_cf:?}"
    );
}

#[test]
fn import_reports_every_problem_of_a_hand_edited_comp_file() {
    let (_t, dir) = scratch("import-bad");
    std::fs::create_dir_all(&dir).expect("dir");
    std::fs::write(
        dir.join("linuxcnc.ini"),
        "[JOINT_0]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\nCOMP_FILE = j.comp\nCOMP_FILE_TYPE = 1\n",
    )
    .expect("ini");
    std::fs::write(
        dir.join("j.comp"),
        "0 0.01 -0.01\n5 0.03 -0.01\n4 0 0\n10 nan 0\n",
    )
    .expect("comp");
    let (lp, _) = shipped("default.ron");
    let err = export::import::import(Target::Linuxcnc, &dir, &lp).expect_err("bad file");
    let text = err.to_string();
    assert!(
        text.contains("j.comp:3") && text.contains("must increase"),
        "{text}"
    );
    assert!(text.contains("j.comp:4") && text.contains("NaN"), "{text}");
    assert!(
        text.contains("j.comp:2") && text.contains("position-dependent backlash"),
        "{text}"
    );
}

/// The lines the report's entries put into `file`, assembled as the renderer assembles
/// them: one line per (section, key), the entries' texts after the key in entry order.
fn lines_from_entries(report: &export::Report, file: &str) -> Vec<String> {
    let mut lines: Vec<((String, String), String)> = Vec::new();
    for e in &report.entries {
        for p in e.puts.iter().filter(|p| p.file == file) {
            let id = (p.section.clone(), p.key.clone());
            match lines.iter_mut().find(|(k, _)| *k == id) {
                Some((_, t)) => t.push_str(&p.text),
                None => lines.push((id, format!("{}{}", p.key, p.text))),
            }
        }
    }
    lines.into_iter().map(|(_, t)| t).collect()
}

/// A line that carries no value: blank, comment, section header, program frame.
fn layout(line: &str) -> bool {
    let t = line.trim();
    t.is_empty()
        || t.starts_with('#')
        || t.starts_with(';')
        || (t.starts_with('[') && t.ends_with(']'))
        || t.starts_with("BEGIN ")
        || t.starts_with("%_N_")
        || t == "CHANDATA(1)"
        || t == "M17"
}

#[test]
fn files_and_report_are_rendered_from_the_same_entries() {
    let short = ExportOptions {
        horizon_s: Some(2.0),
    };
    let mut checked_lines = 0;
    for name in preset::SHIPPED_PRESETS {
        let (lp, progs) = shipped(name);
        for t in Target::ALL {
            let ex = export::export(&lp.preset, &progs, t, &short)
                .unwrap_or_else(|e| panic!("{name} → {t:?}: {e}"));
            let names: Vec<&str> = ex.files.iter().map(|f| f.0.as_str()).collect();
            for e in &ex.report.entries {
                for p in &e.puts {
                    assert!(
                        names.contains(&p.file.as_str()),
                        "{name} → {t:?}: {} puts a line into {}, which is not written",
                        e.field,
                        p.file
                    );
                }
            }
            for (file, text) in &ex.files {
                if t == Target::Ron {
                    let puts: Vec<_> = ex
                        .report
                        .entries
                        .iter()
                        .flat_map(|e| e.puts.iter())
                        .filter(|p| p.file == *file)
                        .collect();
                    assert_eq!(puts.len(), 1, "{name}: {file}");
                    assert_eq!(&puts[0].text, text, "{name}: {file} is its entry's text");
                    continue;
                }
                // Every line an entry claims is in the file …
                let mut rest: Vec<&str> = text.lines().collect();
                for l in lines_from_entries(&ex.report, file) {
                    let pos = rest.iter().position(|r| *r == l).unwrap_or_else(|| {
                        panic!("{name} → {t:?}: {file} lacks the entry line {l:?}:\n{text}")
                    });
                    rest.remove(pos);
                    checked_lines += 1;
                }
                // … and every other line of the file is layout, carrying no value.
                for r in rest {
                    assert!(
                        layout(r),
                        "{name} → {t:?}: {file} line {r:?} belongs to no entry"
                    );
                }
            }
            // The JSON report is the same list, with each entry's rendered target.
            let json: serde_json::Value =
                serde_json::from_str(&ex.report.to_json()).expect("valid JSON");
            for (k, e) in ex.report.entries.iter().enumerate() {
                assert_eq!(json["entries"][k]["field"], e.field.as_str());
                assert_eq!(json["entries"][k]["target"], e.target().as_str());
                assert_eq!(
                    json["entries"][k]["puts"].as_array().map(Vec::len),
                    Some(e.puts.len())
                );
            }
        }
    }
    assert!(checked_lines > 300, "{checked_lines} lines checked");
}

#[test]
fn field_paths_use_the_dot_dialect() {
    let short = ExportOptions {
        horizon_s: Some(1.0),
    };
    for name in preset::SHIPPED_PRESETS {
        let (lp, progs) = shipped(name);
        for t in Target::ALL {
            let ex = export::export(&lp.preset, &progs, t, &short).expect("exports");
            for e in &ex.report.entries {
                let ok = e.field == "(the whole preset)"
                    || (!e.field.is_empty()
                        && e.field.split('.').all(|seg| {
                            !seg.is_empty()
                                && seg.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                        }));
                assert!(ok, "{name} → {t:?}: field '{}'", e.field);
                // The field resolves in the preset as --set takes it (a list of axes by
                // axis name, other lists by index).
                if e.field.contains('.') {
                    let known = lp
                        .preset
                        .field_paths()
                        .iter()
                        .any(|(p, _)| p == &e.field || p.starts_with(&format!("{}.", e.field)));
                    assert!(
                        known,
                        "{name} → {t:?}: '{}' is not a preset path or section",
                        e.field
                    );
                }
            }
            let md = ex.report.to_markdown();
            assert!(
                !md.contains("axes["),
                "{name} → {t:?}: bracket dialect in the report"
            );
        }
    }
    // Violations, too.
    let mut bad = lead_and_backlash();
    bad.axes[0].servo.kp_per_s = f64::NAN;
    let (_, progs) = shipped("default.ron");
    let err = export::export(&bad, &progs, Target::Linuxcnc, &opts()).expect_err("invalid");
    let text = err.to_string();
    assert!(
        text.contains("axes.x.servo.kp_per_s") && !text.contains("axes["),
        "{text}"
    );
}

#[test]
fn an_export_our_import_would_reject_is_refused_before_anything_is_written() {
    // The issue's example: a lead error of 1e300 µm/m would make comp trims of ~1e296 mm.
    let (_t, dir) = scratch("refused");
    let out = dir.join("lcnc");
    let o = Command::new(env!("CARGO_BIN_EXE_axisbench"))
        .args([
            "export",
            "--preset",
            "embedded:default.ron",
            "--to",
            "linuxcnc",
            "--horizon",
            "1",
            "--set",
            "axes.x.lead_error.enabled=true",
            "--set",
            "axes.x.lead_error.cumulative_um_per_m=1e300",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    // The preset's own range check refuses it at --set, before any export runs.
    for needle in [
        "axes.x.lead_error.cumulative_um_per_m",
        "1.000000e300 is outside the allowed range -10000 … 10000 um/m",
    ] {
        assert!(stderr.contains(needle), "missing '{needle}' in:\n{stderr}");
    }
    assert!(!out.exists(), "nothing was written");
    // Every value inside its range, but the comp file's trims (correction ± Q/2) are not:
    // only reading the rendered files back finds it, and it is named by the entry that
    // wrote the line.
    let mut p = lead_and_backlash();
    p.axes[0].backlash.q_um = 10_000.0;
    p.axes[0].lead_error.cumulative_um_per_m = 0.0;
    p.axes[0].lead_error.table = vec![(0.0, 6000.0), (100.0, 6000.0)];
    let (_, progs) = shipped("default.ron");
    let err = export::export(&p, &progs, Target::Linuxcnc, &opts()).expect_err("refused");
    let ExportError::Violations { violations, .. } = &err else {
        panic!("{err}")
    };
    let v = violations
        .iter()
        .find(|v| v.location == "axes.x.lead_error")
        .unwrap_or_else(|| panic!("{err}"));
    assert!(
        v.reason.contains("joint0.comp:1")
            && v.reason.contains("our own import rejects")
            && v.reason
                .contains("reverse trim: -11 mm is outside the allowed range"),
        "{v}"
    );
    // SINUMERIK writes the same amounts separately, within range: accepted.
    export::export(&p, &progs, Target::Siemens, &opts()).expect("siemens carries it");
}

/// Writes `linuxcnc.ini` (and `j.comp` when given) into a fresh folder and imports it
/// onto the default preset.
fn import_ini(ini: &str, comp: Option<&str>) -> Result<Preset, ExportError> {
    let (_t, dir) = scratch("import");
    std::fs::create_dir_all(&dir).expect("dir");
    std::fs::write(dir.join("linuxcnc.ini"), ini).expect("ini");
    if let Some(c) = comp {
        std::fs::write(dir.join("j.comp"), c).expect("comp");
    }
    let (lp, _) = shipped("default.ron");
    export::import::import(Target::Linuxcnc, &dir, &lp)
}

#[test]
fn import_checks_every_number_against_its_physical_range() {
    let joint = |extra: &str| format!("[JOINT_0]\nMAX_VELOCITY = 100\n{extra}");
    for (ini, comp, needles) in [
        // The issue's example: this imported and then overflowed the acc/dec filter.
        (
            joint("MAX_ACCELERATION = 1e-300\n"),
            None,
            vec![
                "[JOINT_0]MAX_ACCELERATION",
                "1e-300 mm/s² is outside the allowed range 0.01…1000000 mm/s²",
            ],
        ),
        (
            joint("MAX_ACCELERATION = 0.02\n"),
            None,
            vec![
                "[JOINT_0]MAX_ACCELERATION",
                "5000 s is outside",
                "acc/dec time constant",
            ],
        ),
        (
            "[JOINT_0]\nMAX_VELOCITY = inf\n".to_owned(),
            None,
            vec!["[JOINT_0]MAX_VELOCITY", "inf is not a finite number"],
        ),
        (
            joint("BACKLASH = 50\n"),
            None,
            vec![
                "[JOINT_0]BACKLASH",
                "50 mm is outside the allowed range 0…10 mm",
            ],
        ),
        (
            joint("BACKLASH = -0.01\n"),
            None,
            vec!["[JOINT_0]BACKLASH", "-0.01 mm is outside"],
        ),
        (
            joint("COMP_FILE = j.comp\nCOMP_FILE_TYPE = 1\n"),
            Some("1e9 0 0\n"),
            vec![
                "j.comp:1",
                "nominal: 1000000000 mm is outside the allowed range -100000…100000 mm",
            ],
        ),
        (
            joint("COMP_FILE = j.comp\nCOMP_FILE_TYPE = 1\n"),
            Some("0 0.5 0.4\n10 1e-310 -20\n"),
            vec!["j.comp:2", "reverse trim: -20 mm"],
        ),
        (
            joint("COMP_FILE = missing.comp\n"),
            None,
            vec!["missing.comp", "cannot read", "No such file"],
        ),
    ] {
        let err = import_ini(&ini, comp).expect_err(&ini);
        let text = err.to_string();
        for n in needles {
            assert!(
                text.contains(n),
                "missing '{n}' for {ini:?} / {comp:?}:\n{text}"
            );
        }
    }
    // In range: imported, and the preset runs.
    let p =
        import_ini(&joint("MAX_ACCELERATION = 2000\nBACKLASH = 0.01\n"), None).expect("imports");
    assert!(
        (p.nc.accdec.tc1_s - 0.05).abs() < 1e-12,
        "τ = v/a = 100/2000 s"
    );
    assert!((p.axes[0].backlash.q_um - 10.0).abs() < 1e-9);
    let mut m = axisbench::Machine::new(&p, &[("t.ngc".into(), "G01 X10 F3000\nM30\n".into())])
        .expect("builds");
    m.run(0.5).unwrap();
    assert!(m.axes[0].pos_m.is_finite());
}

#[test]
fn import_refuses_a_result_the_machine_check_rejects() {
    // A base whose servo passes the field rules but not the closed-loop stability check.
    let (lp, progs) = shipped("default.ron");
    let ex = export::export(&lp.preset, &progs, Target::Linuxcnc, &opts()).expect("exports");
    let (_t, dir) = scratch("unstable");
    ex.write(&dir).expect("writes");
    let mut base = lp.clone();
    base.preset.axes[0].servo.kv_n_s_per_m = 5e8;
    assert!(
        base.preset.validate().is_empty(),
        "the field rules accept it"
    );
    assert!(
        !axisbench::machine::check(&base.preset).is_empty(),
        "unstable"
    );
    let err = export::import::import(Target::Linuxcnc, &dir, &base).expect_err("refused");
    let text = err.to_string();
    assert!(
        text.contains("axes.x.servo") && text.contains("the imported preset is not valid"),
        "{text}"
    );
}
