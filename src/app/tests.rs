//! The workbench driven as a user would, headless (egui_kittest): widgets found by their
//! label, clicked and typed into; assertions on the model behind them.

#[cfg(test)]
use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::{NodeT, Queryable};

use axisbench::comp::backlash::Backlash;
use axisbench::preset::comp::OutputMode;

use super::{Tab, Workbench};

fn harness(wb: Workbench) -> Harness<'static, Workbench> {
    Harness::builder()
        .with_size(egui::vec2(1400.0, 1000.0))
        .build_ui_state(|ui, wb: &mut Workbench| wb.ui(ui), wb)
}

fn default_wb() -> Workbench {
    match Workbench::new_embedded("default.ron") {
        Ok(wb) => wb,
        Err(e) => panic!("default workbench: {e:#}"),
    }
}

#[test]
fn backlash_mode_change_reaches_the_model_and_the_next_reversal() {
    let mut h = harness(default_wb());
    h.run();
    // The first "distance" option belongs to the + → − reversal.
    h.get_all_by_label("distance")
        .next()
        .expect("a distance option")
        .click();
    h.run();
    let wb = h.state();
    assert_eq!(
        wb.preset.axes[0].backlash.plus_to_minus.mode,
        OutputMode::Distance
    );
    assert_eq!(
        wb.preset.axes[0].backlash.minus_to_plus.mode,
        OutputMode::Lump,
        "only that direction"
    );
    {
        let s = wb.live.lock();
        let b = s
            .machine
            .find_comp::<Backlash>()
            .next()
            .expect("backlash installed");
        assert_eq!(
            b.p.plus_to_minus.mode,
            OutputMode::Distance,
            "the running machine took it"
        );
    }
    // Run past the first + → − reversal (x = 100 mm at about 2.2 s).
    wb.live.advance(24_000);
    let s = wb.live.lock();
    let comp = s.ring.col("x.backlash_comp").expect("backlash column");
    // The trace holds m.
    let q_m = axisbench::units::um_to_m(wb.preset.axes[0].backlash.q_um);
    let n = wb.preset.axes[0].backlash.plus_to_minus.parts_n as f64;
    let first_part = comp
        .iter()
        .find(|&&v| v != 0.0)
        .copied()
        .expect("the reversal happened");
    assert!(
        (first_part + q_m / n).abs() < 1e-15,
        "first output {first_part} m, expected −Q/N"
    );
    assert!(
        comp.iter().any(|&v| (v + q_m).abs() < 1e-15),
        "all of Q by the end"
    );
}

#[test]
fn run_and_pause() {
    let mut h = harness(default_wb());
    h.run();
    h.get_by_label("Run").click();
    // While running, every frame asks for the next one: step frames instead of settling.
    h.step();
    h.step();
    assert!(h.state().live.lock().running);
    h.get_by_label("Pause").click();
    h.step();
    h.step();
    assert!(!h.state().live.lock().running);
    let t0 = h.state().live.lock().machine.t_s();
    h.get_by_label("Step").click();
    h.run();
    let t1 = h.state().live.lock().machine.t_s();
    assert!(
        (t1 - t0 - 0.001).abs() < 1e-12,
        "Step advances one T2: {t0} → {t1}"
    );
}

#[test]
fn load_a_preset_from_the_scenario_list() {
    let mut h = harness(default_wb());
    h.run();
    h.get_by_label("Scenario").click();
    h.run();
    h.get_by_label("xy_circle.ron").click();
    h.run();
    let wb = h.state();
    assert_eq!(wb.preset.name, "xy_circle");
    assert_eq!(wb.live.lock().machine.axes.len(), 2);
    assert!(
        !wb.dirty(),
        "a freshly loaded preset has no unsaved changes"
    );
}

#[test]
fn a_bad_value_shows_an_error_and_keeps_the_previous_value() {
    let mut h = harness(default_wb());
    h.run();
    let before = h.state().preset.axes[0].backlash.q_um;
    let text_input = egui::accesskit::Role::TextInput;
    h.get_by_role_and_label(text_input, "Q").focus();
    h.run();
    h.get_by_role_and_label(text_input, "Q").type_text("abc");
    h.run();
    h.key_press(egui::Key::Enter);
    h.run();
    assert_eq!(
        h.state().preset.axes[0].backlash.q_um,
        before,
        "the old value stays in force"
    );
    assert!(
        h.query_by_label_contains("is not a number").is_some(),
        "error shown next to the field"
    );
    // A number the validator refuses is just as harmless.
    let wb = h.state_mut();
    assert!(!wb.edit("axes.x.backlash.q_um", |p| p.axes[0].backlash.q_um = -5.0));
    assert_eq!(wb.preset.axes[0].backlash.q_um, before);
    assert!(
        wb.field_errors
            .get("axes.x.backlash.q_um")
            .is_some_and(|e| e.contains("-5 is outside the allowed range 0 … 100000 µm")),
        "{:?}",
        wb.field_errors
    );
    // A good value is taken and the machine gets it.
    assert!(wb.edit("axes.x.backlash.q_um", |p| p.axes[0].backlash.q_um = 9.5));
    assert_eq!(wb.live.lock().machine.preset.axes[0].backlash.q_um, 9.5);
    assert!(wb.dirty(), "edits mark the preset unsaved");
}

#[test]
fn ab_compare_produces_its_table() {
    let mut h = harness(default_wb());
    h.run();
    h.get_by_label("A/B compare").click();
    h.run();
    h.get_by_label("Run A/B").click();
    h.run();
    let wb = h.state();
    assert_eq!(wb.tab, Tab::Compare);
    let c = wb.compare.as_ref().expect("compare ran");
    assert_eq!(c.table.len(), 2, "A and B rows");
    let (a, b) = (&c.table[0], &c.table[1]);
    assert!(a.1 > 0.0 && b.1 > 0.0 && a.1.is_finite());
    assert!(
        a.3 > 0.0 && a.4 > 0.0,
        "both reversal directions are reported: {a:?}"
    );
    assert!(
        h.query_by_label("RMS error").is_some(),
        "table header shown"
    );
}

#[test]
fn a_bad_program_keeps_the_old_one_and_names_the_line() {
    let mut wb = default_wb();
    let old = wb.programs[0].1.clone();
    wb.program_buf = "G90 G01 F1000\nG41 X5\n".into();
    wb.apply_program();
    assert_eq!(wb.programs[0].1, old);
    assert!(
        wb.program_error
            .as_deref()
            .is_some_and(|e| e.contains(":2:1") && e.contains("G41"))
    );
}

#[test]
fn saves_are_atomic_files_that_load_back() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path().join("axisbench-app");
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("mine.ron");
    let mut wb = default_wb();
    assert!(wb.edit("axes.x.backlash.q_um", |p| p.axes[0].backlash.q_um = 5.5));
    wb.save_to(path.clone());
    assert!(!wb.dirty());
    assert!(
        dir.join("default.ngc").exists(),
        "the program is saved next to the preset"
    );
    let mut other = default_wb();
    other.open_file(path.clone());
    assert_eq!(other.preset.axes[0].backlash.q_um, 5.5);
    assert_eq!(other.recent.first(), Some(&path));
    // Session round trip: what is autosaved restores the same edits.
    let session = dir.join("session.ron");
    super::session::write(&session, &super::session::to_text(&wb)).expect("session written");
    let back = super::session::restore(&session).expect("session restores");
    assert_eq!(back.preset.axes[0].backlash.q_um, 5.5);
}

#[test]
fn circle_fit_recovers_centre_and_radius() {
    let pts: Vec<(f64, f64)> = (0..50)
        .map(|k| {
            let th = k as f64 * 0.1;
            (3.0 + 10.0 * th.cos(), -2.0 + 10.0 * th.sin())
        })
        .collect();
    let (cx, cy, r) = super::plots::fit_circle(&pts).expect("fits");
    assert!((cx - 3.0).abs() < 1e-9 && (cy + 2.0).abs() < 1e-9 && (r - 10.0).abs() < 1e-9);
}

#[test]
fn decimation_keeps_extremes_and_bounds_the_point_count() {
    use std::collections::VecDeque;
    let t: VecDeque<f64> = (0..80_000).map(|k| k as f64 * 1.25e-4).collect();
    let v: VecDeque<f64> = (0..80_000)
        .map(|k| {
            if k == 40_001 {
                5.0
            } else {
                (k as f64 * 0.01).sin()
            }
        })
        .collect();
    let pts = super::plots::decimate(&t, &v, 0.0, 10.0, 1000, std::convert::identity);
    assert!(pts.len() <= 2000, "{} points for 1000 columns", pts.len());
    assert!(
        pts.iter().any(|p| p[1] == 5.0),
        "a one-sample spike survives decimation"
    );
    assert!(
        pts.windows(2).all(|w| w[1][0] >= w[0][0]),
        "time order kept"
    );
}

#[test]
fn record_and_reopen_a_trace() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path().join("axisbench-app-tr");
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("rec.csv");
    let mut wb = default_wb();
    wb.live.advance(8_000);
    wb.record_csv(path.clone());
    wb.open_trace(path.clone());
    let (_, tr) = wb.loaded_trace.as_ref().expect("trace loaded");
    assert_eq!(tr.len(), 8_000);
    assert!(tr.values("x.err").is_some());
    // A bad file is a message, not a crash, and the plots keep the old overlay.
    std::fs::write(dir.join("bad.csv"), "t[s],x.cmd[mm],x.pos[mm]\n0,0,NaN\n").expect("write");
    wb.open_trace(dir.join("bad.csv"));
    assert!(wb.status.contains("bad.csv:2"), "{}", wb.status);
    assert!(wb.loaded_trace.is_some());
}

#[test]
fn diagnose_view_runs_and_applies_the_fitted_effect() {
    let wb = match Workbench::new_embedded("emps.ron") {
        Ok(wb) => wb,
        Err(e) => panic!("emps workbench: {e:#}"),
    };
    let mut h = harness(wb);
    h.run();
    h.get_by_label("Diagnose").click();
    h.run();
    assert_eq!(h.state().tab, Tab::Diagnose);
    let rec = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/real/emps/emps_train_DATA_EMPS.csv");
    assert!(rec.exists(), "real data missing: {}", rec.display());
    h.state_mut().diag.trace_path = rec.display().to_string();
    h.run();
    h.get_by_label("Run diagnosis").click();
    // The progress bar repaints while the job runs, so step rather than settle.
    h.step();
    assert!(h.state().diag.run.job.is_some(), "the job started");
    h.state().diag.run.wait();
    h.run();
    {
        let wb = h.state();
        assert!(wb.diag.run.error.is_none(), "{:?}", wb.diag.run.error);
        let rep = wb.diag.run.result.as_ref().expect("a report");
        assert_eq!(rep.verdict, "coulomb_friction");
        assert_eq!(wb.preset.axes[0].friction.coulomb_n, 0.0, "not applied yet");
    }
    apply_belongs_to_its_preset(&mut h);
}

/// Apply lists its diff, refuses a result computed on another preset or before an edit,
/// and is undone in one click.
fn apply_belongs_to_its_preset(h: &mut Harness<'static, Workbench>) {
    // What Apply will change is listed field by field before it is clicked.
    assert!(
        h.query_by_label_contains("Apply will change").is_some(),
        "the diff is offered"
    );
    let diff = {
        let wb = h.state();
        let fitted = wb.diag.run.result.as_ref().and_then(|r| r.fitted.clone());
        wb.preset.diff(&fitted.expect("a fitted preset"))
    };
    assert!(
        diff.iter().any(|c| c.path == "axes.x.friction.coulomb_n"),
        "{diff:?}"
    );

    // The problem this guards against: diagnose on emps.ron, switch to default.ron, and
    // Apply must not put the EMPS machine in its place.
    h.get_by_label("Scenario").click();
    h.run();
    h.get_by_label("default.ron").click();
    h.run();
    assert_eq!(h.state().preset.name, "default");
    let default_ron = h.state().preset.to_ron().expect("ron");
    assert!(
        h.query_by_label_contains("Apply is off: computed on emps.ron")
            .is_some(),
        "the reason is shown"
    );
    h.get_by_label("Apply to model").click();
    h.run();
    assert_eq!(
        h.state().preset.to_ron().expect("ron"),
        default_ron,
        "a disabled Apply changes nothing"
    );
    h.state_mut().apply_diagnosis();
    assert_eq!(
        h.state().preset.to_ron().expect("ron"),
        default_ron,
        "nor does calling it directly"
    );

    // Back on the machine it was computed on, an edit also makes it stale…
    h.get_by_label("Scenario").click();
    h.run();
    h.get_by_label("emps.ron").click();
    h.run();
    assert!(h.state().diagnosis_not_applicable().is_none());
    assert!(
        h.state_mut()
            .edit("axes.x.servo.kp_per_s", |p| p.axes[0].servo.kp_per_s *= 1.1)
    );
    h.run();
    assert!(
        h.state()
            .diagnosis_not_applicable()
            .is_some_and(|w| w.contains("edited since")),
        "{:?}",
        h.state().diagnosis_not_applicable()
    );
    // … and the scenario as it was makes it current again.
    h.state_mut().load_scenario("emps.ron");
    h.run();
    assert!(h.state().diagnosis_not_applicable().is_none());
    let before = h.state().preset.clone();
    h.get_by_label("Apply to model").click();
    h.run();
    {
        let wb = h.state();
        let fc = wb.preset.axes[0].friction.coulomb_n;
        assert!((fc - 20.39).abs() < 3.0, "applied Coulomb force {fc} N");
        assert_eq!(
            wb.live.lock().machine.preset.axes[0].friction.coulomb_n,
            fc,
            "the running machine took it"
        );
        assert!(wb.dirty(), "the fitted preset is an unsaved edit");
        assert!(
            wb.diagnosis_not_applicable().is_some(),
            "applied once: not again"
        );
    }
    h.get_by_label("Undo apply").click();
    h.run();
    let wb = h.state();
    assert_eq!(wb.preset, before, "Undo restores every field");
    assert_eq!(
        wb.live.lock().machine.preset.axes[0].friction.coulomb_n,
        0.0,
        "and the running machine has it back"
    );
}

#[test]
fn export_buttons_write_the_target_files_and_the_report() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let dir = tmp_dir.path().join("axisbench-gui-export");
    let _ = std::fs::remove_dir_all(&dir);
    let mut wb = default_wb();
    wb.path_input = dir.display().to_string();
    let mut h = harness(wb);
    h.run();
    h.get_by_label("Export linuxcnc").click();
    h.run();
    let ini = std::fs::read_to_string(dir.join("linuxcnc.ini")).expect("linuxcnc.ini written");
    let q_mm = h.state().preset.axes[0].backlash.q_um / 1000.0;
    assert!(
        ini.contains(&format!("BACKLASH = {q_mm}")),
        "the preset's backlash went into [JOINT_0]: {ini}"
    );
    let report = std::fs::read_to_string(dir.join("mapping_report.md")).expect("report written");
    assert!(report.contains("BACKLASH"), "{report}");
    assert!(
        h.state().status.starts_with("exported"),
        "{}",
        h.state().status
    );
    h.get_by_label("Export fanuc").click();
    h.run();
    let fanuc = std::fs::read_to_string(dir.join("fanuc_parameters.txt")).expect("fanuc list");
    assert!(
        fanuc.contains("N1851 A1 P7"),
        "7.4 µm → 7 detection units: {fanuc}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Opens every closed section (and sub-section) of the machine panel; sub-sections only
/// appear once their parent is open, so this repeats until none is left closed.
fn open_all_sections(h: &mut Harness<'static, Workbench>) {
    for _ in 0..4 {
        let closed: Vec<String> = h
            .query_all_by_role(egui::accesskit::Role::DisclosureTriangle)
            .filter(|n| n.accesskit_node().data().is_expanded() == Some(false))
            .filter_map(|n| n.accesskit_node().label())
            .collect();
        if closed.is_empty() {
            return;
        }
        for title in closed {
            if let Some(n) = h.query_by_label(&title) {
                n.click();
            }
            h.run();
        }
    }
}

/// Every on/off box switched on, so that the fields it hides are shown too.
fn switch_everything_on(h: &mut Harness<'static, Workbench>) -> usize {
    let mut switched = 0;
    let boxes: Vec<String> = h
        .query_all_by_role(egui::accesskit::Role::CheckBox)
        .filter_map(|n| n.accesskit_node().label())
        .collect();
    for label in boxes {
        let clicked = {
            let n = h
                .query_all_by_label(&label)
                .find(|n| n.accesskit_node().role() == egui::accesskit::Role::CheckBox);
            match n {
                Some(n)
                    if n.accesskit_node().toggled() == Some(egui::accesskit::Toggled::False) =>
                {
                    n.click();
                    true
                }
                _ => false,
            }
        };
        if clicked {
            h.run();
            switched += 1;
        }
    }
    switched
}

#[test]
fn extreme_values_in_every_numeric_field_leave_the_model_finite_and_the_app_responsive() {
    let mut h = Harness::builder()
        .with_size(egui::vec2(1600.0, 6000.0))
        .build_ui_state(|ui, wb: &mut Workbench| wb.ui(ui), default_wb());
    h.run();
    open_all_sections(&mut h);
    let switched = switch_everything_on(&mut h);
    open_all_sections(&mut h);
    let mut labels: Vec<String> = h
        .query_all_by_role(egui::accesskit::Role::TextInput)
        .filter_map(|n| n.accesskit_node().label())
        .filter(|l| !l.contains("record") && l != "Path:" && !l.starts_with("Program"))
        .collect();
    labels.dedup();
    assert!(switched >= 5, "only {switched} on/off boxes switched on");
    assert!(
        labels.len() >= 40,
        "only {} numeric fields found: {labels:?}",
        labels.len()
    );
    let extremes = ["1e300", "1e-300", "0", "-1", "NaN", "inf", "fast", "-1e300"];
    let mut typed = 0;
    for label in &labels {
        for value in extremes {
            // A label can repeat (one per reversal direction): each field in turn.
            let count = h
                .query_all_by_role_and_label(egui::accesskit::Role::TextInput, label)
                .count();
            for i in 0..count {
                let Some(n) = h
                    .query_all_by_role_and_label(egui::accesskit::Role::TextInput, label)
                    .nth(i)
                else {
                    continue;
                };
                n.focus();
                n.set_text_value_accesskit(value);
                h.run();
                h.key_press(egui::Key::Enter);
                h.run();
                typed += 1;
            }
        }
        // The live model stays finite and keeps stepping after every field.
        let wb = h.state();
        wb.live.advance(200);
        let s = wb.live.lock();
        assert!(s.fault.is_none(), "after '{label}': {:?}", s.fault);
        for a in &s.machine.axes {
            assert!(a.pos_m.is_finite(), "after '{label}': position not finite");
        }
        assert!(
            axisbench::machine::check(&wb.preset).is_empty(),
            "after '{label}': the preset in force is not valid"
        );
    }
    assert!(typed >= 400, "only {typed} values typed");
    // Still responsive: a sound value typed now is taken, and the model runs on it.
    let kp = h.state().preset.axes[0].servo.kp_per_s * 0.9;
    let n = h.get_by_label("Kp");
    n.focus();
    n.set_text_value_accesskit(&kp.to_string());
    h.run();
    h.key_press(egui::Key::Enter);
    h.run();
    let wb = h.state();
    assert_eq!(
        wb.preset.axes[0].servo.kp_per_s, kp,
        "{:?}",
        wb.field_errors
    );
    let t0_s = wb.live.lock().machine.t_s();
    wb.live.advance(100);
    assert!(wb.live.lock().machine.t_s() > t0_s);
}

#[test]
fn the_stroke_friction_film_law_is_chosen_in_the_plant_panel() {
    let mut h = Harness::builder()
        .with_size(egui::vec2(1600.0, 6000.0))
        .build_ui_state(|ui, wb: &mut Workbench| wb.ui(ui), default_wb());
    h.run();
    open_all_sections(&mut h);
    h.get_all_by_label("short-stroke rise on")
        .next()
        .expect("the stroke friction's switch")
        .click();
    h.run();
    assert!(h.state().preset.axes[0].friction.stroke.enabled);
    assert!(
        h.query_by_label("breakdown").is_none(),
        "count law: no breakdown"
    );
    // "distance" also names backlash output modes: the film law's is the one that sets it.
    let n = h.get_all_by_label("distance").count();
    let mut found = false;
    for i in 0..n {
        if let Some(node) = h.get_all_by_label("distance").nth(i) {
            node.click();
        }
        h.run();
        if h.state().preset.axes[0].friction.stroke.law == axisbench::preset::FilmLaw::Distance {
            found = true;
            break;
        }
    }
    assert!(found, "no \"distance\" option set the film law");
    assert!(
        h.query_by_label("breakdown").is_some(),
        "the breakdown field shows"
    );
    let wb = h.state();
    wb.live.advance(2000);
    let s = wb.live.lock();
    assert!(s.fault.is_none(), "{:?}", s.fault);
    assert!(s.machine.axes[0].pos_m.is_finite());
}

/// A payload on a hardening mount, chosen and edited in the plant panel, runs live.
#[test]
fn a_payload_coupling_is_chosen_and_edited_in_the_plant_panel() {
    let mut h = Harness::builder()
        .with_size(egui::vec2(1600.0, 6000.0))
        .build_ui_state(|ui, wb: &mut Workbench| wb.ui(ui), default_wb());
    h.run();
    open_all_sections(&mut h);
    assert!(
        h.query_by_label("payload mass").is_none(),
        "rigid: no payload"
    );
    // The default X axis has lost motion, which a payload coupling does not take: refused,
    // with the reason at the coupling.
    assert!(h.state().preset.axes[0].lost_motion.enabled);
    h.get_by_label("payload").click();
    h.run();
    assert!(matches!(
        h.state().preset.axes[0].drive.coupling,
        axisbench::preset::Coupling::Rigid
    ));
    assert!(
        h.query_all_by_label_contains("without backlash")
            .next()
            .is_some(),
        "the refusal is shown"
    );
    assert!(h.state_mut().edit("axes.x.lost_motion.enabled", |p| {
        p.axes[0].lost_motion.enabled = false
    }));
    h.run();
    h.get_by_label("payload").click();
    h.run();
    assert!(matches!(
        h.state().preset.axes[0].drive.coupling,
        axisbench::preset::Coupling::Payload { .. }
    ));
    // Typed into the field after its value: "0" then "3" reads 3 µm (or 3 if replaced).
    let text_input = egui::accesskit::Role::TextInput;
    let label = "hardening deflection (0: linear)";
    h.get_by_role_and_label(text_input, label).focus();
    h.run();
    h.get_by_role_and_label(text_input, label).type_text("3");
    h.run();
    h.key_press(egui::Key::Enter);
    h.run();
    match h.state().preset.axes[0].drive.coupling {
        axisbench::preset::Coupling::Payload {
            hardening_deflection_um,
            ..
        } => assert!(
            hardening_deflection_um > 0.0,
            "{hardening_deflection_um}: {:?}",
            h.state().field_errors
        ),
        ref c => panic!("coupling is {c:?}"),
    }
    let wb = h.state();
    wb.live.advance(2000);
    let s = wb.live.lock();
    assert!(s.fault.is_none(), "{:?}", s.fault);
    assert!(s.machine.axes[0].pos_m.is_finite());
}

#[test]
fn a_refused_value_leaves_the_field_showing_the_value_in_force() {
    let mut h = harness(default_wb());
    h.run();
    let before = h.state().preset.axes[0].backlash.q_um;
    let shown = axisbench::units::fmt_sig(before, 6);
    let huge: f64 = format!("{shown}e300").parse().expect("a number");
    let refused = format!(
        "refused: {} is outside the allowed range",
        axisbench::preset::fields::short(huge)
    );
    let text_input = egui::accesskit::Role::TextInput;
    h.get_by_role_and_label(text_input, "Q").focus();
    h.run();
    // Appended to the value shown: Q × 10^300.
    h.get_by_role_and_label(text_input, "Q").type_text("e300");
    h.run();
    h.key_press(egui::Key::Enter);
    h.run();
    h.run();
    assert_eq!(h.state().preset.axes[0].backlash.q_um, before);
    assert!(
        h.query_by_label_contains(&refused).is_some(),
        "the message names the refused value: {:?}",
        h.state().field_errors
    );
    assert_eq!(
        h.state()
            .fields
            .get("axes.x.backlash.q_um")
            .cloned()
            .unwrap_or_else(|| shown.clone()),
        shown,
        "the field shows the value in force, not the refused one"
    );
    let node_value = h
        .get_by_role_and_label(text_input, "Q")
        .accesskit_node()
        .value();
    assert_eq!(node_value.as_deref(), Some(shown.as_str()));
    // Leaving the field untouched keeps the message…
    h.get_by_role_and_label(text_input, "Q").focus();
    h.run();
    h.key_press(egui::Key::Enter);
    h.run();
    assert!(h.query_by_label_contains(&refused).is_some());
    // … typing the value in force again clears it: nothing is refused any more.
    h.get_by_role_and_label(text_input, "Q").focus();
    h.run();
    h.key_press(egui::Key::Backspace);
    h.run();
    let last = shown.chars().last().expect("a digit").to_string();
    h.get_by_role_and_label(text_input, "Q").type_text(&last);
    h.run();
    h.key_press(egui::Key::Enter);
    h.run();
    assert!(
        h.query_by_label_contains("refused").is_none(),
        "the error goes once the field holds the value in force"
    );
}

#[test]
fn switching_scenario_with_unsaved_edits_asks_first() {
    let tmp_dir = tempfile::tempdir().expect("tempdir");
    let mut h = harness(default_wb());
    h.run();
    assert!(
        h.state_mut()
            .edit("axes.x.backlash.q_um", |p| p.axes[0].backlash.q_um = 9.5)
    );
    h.run();
    // Cancel: nothing changes, the edit stays.
    h.get_by_label("Scenario").click();
    h.run();
    h.get_by_label("xy_circle.ron").click();
    h.run();
    assert_eq!(
        h.state().pending,
        Some(super::Pending::Scenario("xy_circle.ron".into()))
    );
    assert!(
        h.query_by_label("Unsaved edits").is_some(),
        "the question is asked"
    );
    assert_eq!(h.state().preset.name, "default", "nothing loaded yet");
    h.get_by_label("Cancel").click();
    h.run();
    assert_eq!(h.state().preset.name, "default");
    assert_eq!(
        h.state().preset.axes[0].backlash.q_um,
        9.5,
        "the edit is kept"
    );
    // Save: the preset is written where the Path field says, then the scenario loads.
    let path = tmp_dir.path().join("kept.ron");
    h.state_mut().path_input = path.display().to_string();
    h.get_by_label("Scenario").click();
    h.run();
    h.get_by_label("xy_circle.ron").click();
    h.run();
    h.get_by_label("Save").click();
    h.run();
    assert_eq!(h.state().preset.name, "xy_circle", "loaded after the save");
    let saved = axisbench::preset::load(&path.display().to_string()).expect("saved preset loads");
    assert_eq!(saved.preset.axes[0].backlash.q_um, 9.5, "with the edit");
    // Discard: the edit goes, as asked.
    assert!(
        h.state_mut()
            .edit("axes.x.servo.kp_per_s", |p| p.axes[0].servo.kp_per_s *= 1.5)
    );
    h.state_mut()
        .request(super::Pending::Scenario("default.ron".into()));
    h.run();
    assert!(
        h.query_by_label("Unsaved edits").is_some(),
        "pending {:?}, status {}",
        h.state().pending,
        h.state().status
    );
    h.get_by_label("Discard").click();
    h.run();
    assert_eq!(h.state().preset.name, "default");
    // Quitting asks too; Discard lets the window close.
    assert!(
        h.state_mut()
            .edit("axes.x.backlash.q_um", |p| p.axes[0].backlash.q_um = 3.0)
    );
    h.state_mut().request(super::Pending::Quit);
    h.run();
    assert!(h.query_by_label("Unsaved edits").is_some());
    assert!(!h.state().close_now);
    h.get_by_label("Discard").click();
    h.run();
    assert!(h.state().quit_allowed, "Discard lets the window close");
}

#[test]
fn first_open_says_press_run_and_the_end_of_the_program_is_said() {
    let mut h = harness(default_wb());
    h.run();
    assert!(
        h.query_by_label_contains("Press Run").is_some(),
        "a hint over the empty plots"
    );
    // Run the program to its end: the status line says so.
    h.state().live.advance(200_000);
    h.run();
    assert!(h.query_by_label_contains("Press Run").is_none());
    assert!(
        h.query_by_label_contains("program finished at t =")
            .is_some(),
        "the end is said"
    );
    // A scenario brings its own speed and view: the warm-up at 1000×, the whole run shown.
    h.state_mut().load_scenario("thermal_warmup.ron");
    h.run();
    let wb = h.state();
    assert_eq!(wb.live.lock().speed, 1000.0);
    assert!(wb.scope.whole_run);
}

#[test]
fn every_time_plot_holds_one_unit_and_the_cursors_read_out_with_units() {
    for name in axisbench::preset::SHIPPED_PRESETS {
        let wb = match Workbench::new_embedded(name) {
            Ok(wb) => wb,
            Err(e) => panic!("{name}: {e:#}"),
        };
        wb.live.advance(4_000);
        let s = wb.live.lock();
        for a in &wb.preset.axes {
            for p in super::scope::plot_defs(&a.name, &s.ring) {
                for l in &p.lines {
                    let u = axisbench::trace::display_unit_of(s.ring.unit(&l.col))
                        .map(|u| u.name)
                        .unwrap_or("");
                    // µm lines hold m and are shown in µm; the rest in their display unit.
                    let ok = u == p.unit || (p.unit == "um" && u == "mm");
                    assert!(
                        ok,
                        "{name}: {} ({u}) in plot {} [{}]",
                        l.col, p.title, p.unit
                    );
                }
            }
        }
    }
    let mut wb = default_wb();
    wb.live.advance(16_000);
    wb.scope.cursors = [Some(0.5), Some(1.5)];
    let mut h = harness(wb);
    h.run();
    assert!(
        h.query_by_label_contains("Δt = 1 s").is_some(),
        "Δt with its unit"
    );
    assert!(
        h.query_all_by_label_contains(" µm").count() >= 2,
        "values with their unit"
    );
}

#[test]
fn the_whole_run_history_is_bounded_and_keeps_the_extremes() {
    let mut wb = Workbench::new_embedded("thermal_warmup.ron").expect("warm-up");
    wb.scope.whole_run = true;
    // A long stretch of the warm-up, in T3 steps.
    let steps = 2_000_000;
    wb.live.advance(steps);
    let s = wb.live.lock();
    let t_end = s.machine.t_s();
    let i = s.ring.index("x.pos").expect("position column");
    let pts = s.history.points(i, 1_000_000, |v| v);
    assert!(pts.len() <= 2 * 4096, "{} points", pts.len());
    assert!(
        pts.last().is_some_and(|p| p[0] > 0.9 * t_end),
        "the history reaches the end of the run"
    );
    assert!(
        pts.first().is_some_and(|p| p[0] < 0.1 * t_end),
        "and its start"
    );
    let hi = pts.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max);
    let ring_hi = s
        .ring
        .col("x.pos")
        .expect("ring")
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    assert!(hi >= ring_hi - 1e-12, "the history keeps the largest value");
}

#[test]
fn the_tune_panel_runs_applies_and_undoes() {
    let mut h = harness(default_wb());
    h.run();
    h.get_by_label("Tune").click();
    h.run();
    assert_eq!(h.state().tab, Tab::Tune);
    // default.ron has its quadrant compensation off: tune the backlash alone.
    h.get_by_label("quadrant (M0, T0, A, B, C, D, P0)").click();
    h.run();
    let before = h.state().preset.clone();
    h.get_by_label("Run tune").click();
    h.step();
    assert!(h.state().tune.run.job.is_some(), "the tune started");
    h.state().tune.run.wait();
    h.run();
    {
        let wb = h.state();
        assert!(wb.tune.run.error.is_none(), "{:?}", wb.tune.run.error);
        let r = wb.tune.run.result.as_ref().expect("a result");
        assert!(r.outcome.after.objective <= r.outcome.before.objective);
        assert!(!r.err_um.is_empty(), "the error overlay has both runs");
        assert_eq!(wb.preset, before, "nothing applied yet");
    }
    assert!(
        h.query_by_label("peak change before").is_some(),
        "the table"
    );
    assert!(
        h.query_by_label("ideal axis (floor)").is_some(),
        "the floor next to before and after"
    );
    h.get_by_label("Apply tuned values").click();
    h.run();
    {
        let wb = h.state();
        let tuned = &wb.tune.run.result.as_ref().expect("result").outcome.preset;
        assert_eq!(&wb.preset, tuned, "the tuned values are in force");
        assert_eq!(
            wb.live.lock().machine.preset.axes[0].backlash.q_um,
            tuned.axes[0].backlash.q_um,
            "and the running machine has them"
        );
    }
    h.get_by_label("Undo apply").click();
    h.run();
    assert_eq!(h.state().preset, before, "Undo restores the preset before");
    // A cancelled tune changes nothing and says so.
    h.get_by_label("Run tune").click();
    h.step();
    h.step();
    h.get_by_label("Cancel tune").click();
    h.step();
    h.state().tune.run.wait();
    h.run();
    assert_eq!(h.state().preset, before);
    let wb = h.state();
    assert!(
        wb.tune
            .run
            .error
            .as_deref()
            .is_some_and(|e| e.contains("cancelled")),
        "{:?}",
        wb.tune.run.error
    );
}
