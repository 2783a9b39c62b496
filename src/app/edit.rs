//! The parameter sections: Backlash, Quadrant, Thermal, Cross, Servo, Plant. Every field
//! shows its unit; a value is taken on Enter or when the field loses focus, validated like
//! a preset file, and on error shown in red next to the field while the previous value stays
//! in force.

use axisbench::comp::measure;
use axisbench::comp::quadrant::Quadrant;
use axisbench::comp::thermal::Thermal;
use axisbench::preset::{AxisParams, Coupling};
use eframe::egui;

use super::Workbench;

/// The preset-file name of an enum value (`lump`, `two_mass`, …).
fn snake(v: &impl serde::Serialize) -> String {
    serde_json::to_value(v)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default()
}

/// A numeric field bound to a preset path.
fn num_ui(wb: &mut Workbench, ui: &mut egui::Ui, label: &str, unit: &str, path: &str, value: f64) {
    ui.horizontal(|ui| {
        let l = ui.label(label);
        let buf = wb
            .fields
            .entry(path.to_owned())
            .or_insert_with(|| format!("{value}"));
        let r = ui
            .add(egui::TextEdit::singleline(buf).desired_width(80.0))
            .labelled_by(l.id);
        ui.label(unit);
        let commit =
            r.lost_focus() || (r.has_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter)));
        // Follow the model (a load, a wizard, an edit elsewhere) only while the user is not
        // typing here and has no pending error to read.
        if !commit
            && !r.has_focus()
            && !wb.field_errors.contains_key(path)
            && *buf != format!("{value}")
        {
            *buf = format!("{value}");
        }
        if commit {
            let text = buf.trim().to_owned();
            let ok = match text.parse::<f64>() {
                Ok(v) if v.is_finite() => wb.set(path, &text),
                _ => {
                    wb.field_errors
                        .insert(path.to_owned(), format!("'{text}' is not a number"));
                    false
                }
            };
            if ok {
                wb.fields.remove(path);
            }
        }
        if let Some(e) = wb.field_errors.get(path) {
            ui.colored_label(egui::Color32::RED, e);
        }
    });
}

fn bool_ui(wb: &mut Workbench, ui: &mut egui::Ui, label: &str, path: &str, value: bool) {
    let mut v = value;
    if ui.checkbox(&mut v, label).changed() {
        wb.set(path, if v { "true" } else { "false" });
    }
}

/// A choice among the snake_case names of an enum.
fn choice_ui(
    wb: &mut Workbench,
    ui: &mut egui::Ui,
    label: &str,
    path: &str,
    current: &str,
    options: &[&str],
) {
    ui.horizontal(|ui| {
        ui.label(label);
        for o in options {
            if ui.selectable_label(current == *o, *o).clicked() && current != *o {
                wb.set(path, o);
            }
        }
    });
}

/// A point table edited as "x, y" lines.
fn table_ui(
    wb: &mut Workbench,
    ui: &mut egui::Ui,
    label: &str,
    units: &str,
    path: &str,
    points: &[(f64, f64)],
) {
    let l = ui.label(format!("{label} ({units}), one point per line:"));
    let key = format!("{path}#table");
    let buf = wb.fields.entry(key.clone()).or_insert_with(|| {
        points
            .iter()
            .map(|(x, y)| format!("{x}, {y}"))
            .collect::<Vec<_>>()
            .join("\n")
    });
    ui.add(egui::TextEdit::multiline(buf).desired_rows(4).code_editor())
        .labelled_by(l.id);
    let text = buf.clone();
    if ui.button(format!("Apply {label}")).clicked() {
        let parsed: Result<Vec<[f64; 2]>, String> = text
            .lines()
            .filter(|l| !l.trim().is_empty())
            .enumerate()
            .map(|(i, l)| {
                let mut it = l.split(',').map(|v| v.trim().parse::<f64>());
                match (it.next(), it.next(), it.next()) {
                    (Some(Ok(x)), Some(Ok(y)), None) if x.is_finite() && y.is_finite() => {
                        Ok([x, y])
                    }
                    _ => Err(format!("line {}: '{l}' is not two numbers 'x, y'", i + 1)),
                }
            })
            .collect();
        match parsed {
            Ok(pts) => {
                let json = serde_json::to_string(&pts).unwrap_or_default();
                if wb.set(path, &json) {
                    wb.fields.remove(&key);
                }
            }
            Err(e) => {
                wb.field_errors.insert(path.to_owned(), e);
            }
        }
    }
    if let Some(e) = wb.field_errors.get(path) {
        ui.colored_label(egui::Color32::RED, e);
    }
}

pub fn sections_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    let Some(a) = wb.preset.axes.get(wb.axis_sel).cloned() else {
        return;
    };
    let p = format!("axes.{}", a.name);
    egui::CollapsingHeader::new("Backlash")
        .default_open(true)
        .show(ui, |ui| backlash_ui(wb, ui, &a, &p));
    egui::CollapsingHeader::new("Quadrant").show(ui, |ui| quadrant_ui(wb, ui, &a, &p));
    egui::CollapsingHeader::new("Thermal").show(ui, |ui| thermal_ui(wb, ui, &a, &p));
    egui::CollapsingHeader::new("Cross").show(ui, |ui| cross_ui(wb, ui));
    egui::CollapsingHeader::new("Servo").show(ui, |ui| servo_ui(wb, ui, &a, &p));
    egui::CollapsingHeader::new("Plant effects").show(ui, |ui| plant_ui(wb, ui, &a, &p));
}

fn backlash_ui(wb: &mut Workbench, ui: &mut egui::Ui, a: &AxisParams, p: &str) {
    let b = &a.backlash;
    bool_ui(
        wb,
        ui,
        "backlash compensation on",
        &format!("{p}.backlash.enabled"),
        b.enabled,
    );
    num_ui(wb, ui, "Q", "µm", &format!("{p}.backlash.q_um"), b.q_um);
    for (key, title, d) in [
        ("plus_to_minus", "+ -> - reversal", &b.plus_to_minus),
        ("minus_to_plus", "- -> + reversal", &b.minus_to_plus),
    ] {
        ui.label(egui::RichText::new(title).strong());
        let dp = format!("{p}.backlash.{key}");
        let mode = snake(&d.mode);
        choice_ui(
            wb,
            ui,
            &format!("{title} mode:"),
            &format!("{dp}.mode"),
            &mode,
            &["lump", "distance", "time", "function"],
        );
        match mode.as_str() {
            "distance" => {
                num_ui(
                    wb,
                    ui,
                    "parts N",
                    "",
                    &format!("{dp}.parts_n"),
                    d.parts_n as f64,
                );
                num_ui(
                    wb,
                    ui,
                    "step B",
                    "µm",
                    &format!("{dp}.step_b_um"),
                    d.step_b_um,
                );
            }
            "time" => num_ui(
                wb,
                ui,
                "cycles M",
                "",
                &format!("{dp}.cycles_m"),
                d.cycles_m as f64,
            ),
            "function" => {
                let basis = snake(&d.function_basis);
                choice_ui(
                    wb,
                    ui,
                    "share over",
                    &format!("{dp}.function_basis"),
                    &basis,
                    &["distance", "time"],
                );
                let units = if basis == "time" {
                    "ms, share"
                } else {
                    "µm, share"
                };
                table_ui(
                    wb,
                    ui,
                    "function",
                    units,
                    &format!("{dp}.function"),
                    &d.function,
                );
            }
            _ => {}
        }
    }
}

fn quadrant_ui(wb: &mut Workbench, ui: &mut egui::Ui, a: &AxisParams, p: &str) {
    let q = &a.quadrant;
    let qp = format!("{p}.quadrant");
    bool_ui(
        wb,
        ui,
        "quadrant compensation on",
        &format!("{qp}.enabled"),
        q.enabled,
    );
    bool_ui(
        wb,
        ui,
        "adaptive to short strokes (seed 003)",
        &format!("{qp}.adaptive"),
        q.adaptive,
    );
    num_ui(
        wb,
        ui,
        "M0 (torque)",
        "N·m",
        &format!("{qp}.m0_torque_nm"),
        q.m0_torque_nm,
    );
    num_ui(
        wb,
        ui,
        "M0 (velocity)",
        "mm/s",
        &format!("{qp}.m0_vel_mm_per_s"),
        q.m0_vel_mm_per_s,
    );
    num_ui(
        wb,
        ui,
        "M0 (position)",
        "µm",
        &format!("{qp}.m0_pos_um"),
        q.m0_pos_um,
    );
    num_ui(wb, ui, "T0", "ms", &format!("{qp}.t0_ms"), q.t0_ms);
    num_ui(
        wb,
        ui,
        "A (TFF magnification)",
        "",
        &format!("{qp}.a_mag"),
        q.a_mag,
    );
    num_ui(
        wb,
        ui,
        "B (TFF growth)",
        "reversals",
        &format!("{qp}.b_rate"),
        q.b_rate,
    );
    num_ui(
        wb,
        ui,
        "C (duration magnification)",
        "",
        &format!("{qp}.c_mag"),
        q.c_mag,
    );
    num_ui(
        wb,
        ui,
        "D (duration growth)",
        "reversals",
        &format!("{qp}.d_rate"),
        q.d_rate,
    );
    num_ui(
        wb,
        ui,
        "P0 (short stroke)",
        "mm",
        &format!("{qp}.p0_mm"),
        q.p0_mm,
    );
    choice_ui(
        wb,
        ui,
        "N update:",
        &format!("{qp}.update"),
        &snake(&q.update),
        &["reset", "decrement"],
    );
    choice_ui(
        wb,
        ui,
        "inject into:",
        &format!("{qp}.inject"),
        &snake(&q.inject),
        &["torque", "velocity", "position"],
    );
    choice_ui(
        wb,
        ui,
        "pulse:",
        &format!("{qp}.shape"),
        &snake(&q.shape),
        &["rectangular", "exponential"],
    );
    let axis = wb.axis_sel;
    let readout = {
        let s = wb.live.lock();
        s.machine
            .comps()
            .find::<Quadrant>()
            .find(|c| axisbench::comp::ServoComp::axis(*c) == axis)
            .map(|c| (c.pa_m, c.n, c.m, c.t_s))
    };
    if let Some((pa, n, m, t)) = readout {
        ui.label(format!(
            "live: PA = {} mm, N = {n}, M = {m:.4}, T = {:.2} ms",
            if pa.is_finite() {
                format!("{:.3}", pa * 1e3)
            } else {
                "—".into()
            },
            t * 1e3
        ));
    }
}

fn thermal_ui(wb: &mut Workbench, ui: &mut egui::Ui, a: &AxisParams, p: &str) {
    let t = &a.thermal;
    let tp = format!("{p}.thermal");
    bool_ui(
        wb,
        ui,
        "thermal correction on",
        &format!("{tp}.enabled"),
        t.enabled,
    );
    choice_ui(
        wb,
        ui,
        "predictor:",
        &format!("{tp}.source"),
        &snake(&t.source),
        &["operation", "temperature"],
    );
    num_ui(wb, ui, "k", "1/µm", &format!("{tp}.k_per_um"), t.k_per_um);
    num_ui(wb, ui, "a", "", &format!("{tp}.a"), t.a);
    num_ui(wb, ui, "Em", "", &format!("{tp}.em"), t.em);
    choice_ui(
        wb,
        ui,
        "judgement:",
        &format!("{tp}.judgement"),
        &snake(&t.judgement),
        &["none", "since_last", "window", "reference"],
    );
    num_ui(
        wb,
        ui,
        "ΔT (window)",
        "s",
        &format!("{tp}.window_s"),
        t.window_s,
    );
    num_ui(
        wb,
        ui,
        "measurement point",
        "mm",
        &format!("{tp}.measure_pos_mm"),
        t.measure_pos_mm,
    );
    num_ui(
        wb,
        ui,
        "predictor α",
        "1/K",
        &format!("{tp}.alpha_per_k"),
        t.alpha_per_k,
    );
    num_ui(
        wb,
        ui,
        "predictor heat",
        "W·s/m",
        &format!("{tp}.heat_w_s_per_m"),
        t.heat_w_s_per_m,
    );
    num_ui(
        wb,
        ui,
        "predictor capacity",
        "J/K",
        &format!("{tp}.capacity_j_per_k"),
        t.capacity_j_per_k,
    );
    num_ui(
        wb,
        ui,
        "predictor loss",
        "W/K",
        &format!("{tp}.loss_w_per_k"),
        t.loss_w_per_k,
    );
    table_ui(wb, ui, "E_ref", "s, E", &format!("{tp}.e_ref"), &t.e_ref);
    let axis = wb.axis_sel;
    let readout = {
        let s = wb.live.lock();
        s.machine
            .comps()
            .find::<Thermal>()
            .find(|c| c.axis() == axis)
            .map(|c| (c.f_m, c.f_applied_m, c.e, c.measurements))
    };
    if let Some((f, fa, e, n)) = readout {
        ui.label(format!(
            "live: F = {:.3} µm, F' = {:.3} µm, E = {e:.4}, measurements {n}",
            f * 1e6,
            fa * 1e6
        ));
    }
    if ui.button("Measure now").clicked() {
        let mut s = wb.live.lock();
        for c in s.machine.comps_mut().find_mut::<Thermal>() {
            if c.axis() == axis {
                c.request_measurement();
            }
        }
    }
    ui.label(egui::RichText::new("Calibration (seed 002), on the simulated machine").strong());
    ui.horizontal(|ui| {
        let l = ui.label("Step 1 interval");
        ui.add(
            egui::DragValue::new(&mut wb.step1_interval_s)
                .range(1.0..=3600.0)
                .suffix(" s"),
        )
        .labelled_by(l.id);
        if ui.button("Run Step 1 (fit k)").clicked() {
            let r = measure::thermal_step1(
                &wb.preset,
                &a.name,
                std::slice::from_ref(&wb.programs),
                wb.step1_interval_s,
            );
            wb.step_result = Some(match r {
                Ok(fit) => {
                    let k = fit.k_per_um;
                    wb.set(&format!("{tp}.k_per_um"), &format!("{k}"));
                    format!("Step 1: k = {k:.6} per µm (applied)")
                }
                Err(e) => format!("Step 1 failed: {e}"),
            });
        }
    });
    ui.horizontal(|ui| {
        let l = ui.label("Step 2 at");
        ui.add(
            egui::DragValue::new(&mut wb.step2_at_s)
                .range(0.0..=36000.0)
                .suffix(" s"),
        )
        .labelled_by(l.id);
        if ui.button("Run Step 2 (set a)").clicked() {
            let r = measure::thermal_step2(&wb.preset, &a.name, &wb.programs, wb.step2_at_s);
            wb.step_result = Some(match r {
                Ok(av) => {
                    wb.set(&format!("{tp}.a"), &format!("{av}"));
                    format!("Step 2: a = {av:.4} (applied)")
                }
                Err(e) => format!("Step 2 failed: {e}"),
            });
        }
    });
    if let Some(r) = &wb.step_result {
        ui.label(r);
    }
}

fn cross_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    let tables = wb.preset.cross.clone();
    if tables.is_empty() {
        ui.label("no cross tables");
    }
    for (i, t) in tables.iter().enumerate() {
        ui.label(
            egui::RichText::new(format!(
                "table {}: {} over {}",
                i + 1,
                t.comp_axis,
                t.base_axis
            ))
            .strong(),
        );
        bool_ui(wb, ui, "on", &format!("cross.{i}.enabled"), t.enabled);
        table_ui(
            wb,
            ui,
            &format!("points {}", i + 1),
            "mm, µm",
            &format!("cross.{i}.points"),
            &t.points,
        );
    }
    if wb.preset.crossbeam.enabled {
        ui.horizontal(|ui| {
            let l = ui.label("points");
            ui.add(egui::DragValue::new(&mut wb.sag_points).range(2..=65))
                .labelled_by(l.id);
            if ui.button("Measure tables from machine").clicked() {
                match measure::sag_tables(&wb.preset, wb.sag_points) {
                    Ok(tables) => {
                        let json = serde_json::to_string(&tables).unwrap_or_default();
                        if wb.set("cross", &json) {
                            wb.fields.retain(|k, _| !k.starts_with("cross."));
                            wb.status = format!(
                                "measured {} cross tables of {} points",
                                tables.len(),
                                wb.sag_points
                            );
                        }
                    }
                    Err(e) => wb.status = format!("measuring failed: {e}"),
                }
            }
        });
    }
}

fn servo_ui(wb: &mut Workbench, ui: &mut egui::Ui, a: &AxisParams, p: &str) {
    let s = &a.servo;
    let sp = format!("{p}.servo");
    num_ui(
        wb,
        ui,
        "position gain Kp",
        "1/s",
        &format!("{sp}.kp_per_s"),
        s.kp_per_s,
    );
    num_ui(
        wb,
        ui,
        "velocity gain Kv",
        "N·s/m",
        &format!("{sp}.kv_n_s_per_m"),
        s.kv_n_s_per_m,
    );
    num_ui(
        wb,
        ui,
        "velocity integral",
        "1/s",
        &format!("{sp}.ki_per_s"),
        s.ki_per_s,
    );
    num_ui(
        wb,
        ui,
        "velocity feed-forward",
        "",
        &format!("{sp}.vff"),
        s.vff,
    );
    num_ui(
        wb,
        ui,
        "acceleration feed-forward",
        "",
        &format!("{sp}.aff"),
        s.aff,
    );
    num_ui(
        wb,
        ui,
        "current-loop lag",
        "s",
        &format!("{sp}.current_lag_s"),
        s.current_lag_s,
    );
    num_ui(
        wb,
        ui,
        "torque limit",
        "N·m",
        &format!("{sp}.torque_limit_nm"),
        s.torque_limit_nm,
    );
    let fb = if s.feedback == axisbench::preset::Feedback::Motor {
        "motor"
    } else {
        "scale"
    };
    choice_ui(
        wb,
        ui,
        "position feedback:",
        &format!("{sp}.feedback"),
        fb,
        &["motor", "scale"],
    );
}

fn plant_ui(wb: &mut Workbench, ui: &mut egui::Ui, a: &AxisParams, p: &str) {
    let two_mass = matches!(a.drive.coupling, Coupling::TwoMass { .. });
    let mut tm = two_mass;
    if ui
        .checkbox(&mut tm, "two-mass drive (compliant screw)")
        .changed()
    {
        let v = if tm {
            r#"{"two_mass":{"stiffness_n_per_um":150.0,"damping_n_s_per_m":20000.0}}"#
        } else {
            r#""rigid""#
        };
        wb.set(&format!("{p}.drive.coupling"), v);
    }
    if let Coupling::TwoMass {
        stiffness_n_per_um,
        damping_n_s_per_m,
    } = a.drive.coupling
    {
        num_ui(
            wb,
            ui,
            "stiffness",
            "N/µm",
            &format!("{p}.drive.coupling.two_mass.stiffness_n_per_um"),
            stiffness_n_per_um,
        );
        num_ui(
            wb,
            ui,
            "damping",
            "N·s/m",
            &format!("{p}.drive.coupling.two_mass.damping_n_s_per_m"),
            damping_n_s_per_m,
        );
    }
    num_ui(
        wb,
        ui,
        "table mass",
        "kg",
        &format!("{p}.drive.table_mass_kg"),
        a.drive.table_mass_kg,
    );
    num_ui(
        wb,
        ui,
        "motor inertia",
        "kg·m²",
        &format!("{p}.drive.motor_inertia_kgm2"),
        a.drive.motor_inertia_kgm2,
    );
    num_ui(
        wb,
        ui,
        "screw lead",
        "mm",
        &format!("{p}.drive.lead_mm"),
        a.drive.lead_mm,
    );
    let f = &a.friction;
    bool_ui(
        wb,
        ui,
        "friction",
        &format!("{p}.friction.enabled"),
        f.enabled,
    );
    num_ui(
        wb,
        ui,
        "Coulomb",
        "N",
        &format!("{p}.friction.coulomb_n"),
        f.coulomb_n,
    );
    num_ui(
        wb,
        ui,
        "viscous",
        "N·s/m",
        &format!("{p}.friction.viscous_n_s_per_m"),
        f.viscous_n_s_per_m,
    );
    bool_ui(
        wb,
        ui,
        "Stribeck (breakaway)",
        &format!("{p}.friction.stribeck.enabled"),
        f.stribeck.enabled,
    );
    num_ui(
        wb,
        ui,
        "breakaway",
        "N",
        &format!("{p}.friction.stribeck.static_n"),
        f.stribeck.static_n,
    );
    bool_ui(
        wb,
        ui,
        "short-stroke friction rise",
        &format!("{p}.friction.stroke.enabled"),
        f.stroke.enabled,
    );
    num_ui(
        wb,
        ui,
        "groove pitch",
        "mm",
        &format!("{p}.friction.stroke.pitch_mm"),
        f.stroke.pitch_mm,
    );
    num_ui(
        wb,
        ui,
        "rise",
        "",
        &format!("{p}.friction.stroke.rise_ratio"),
        f.stroke.rise_ratio,
    );
    bool_ui(
        wb,
        ui,
        "lost motion (backlash)",
        &format!("{p}.lost_motion.enabled"),
        a.lost_motion.enabled,
    );
    num_ui(
        wb,
        ui,
        "play b",
        "µm",
        &format!("{p}.lost_motion.width_um"),
        a.lost_motion.width_um,
    );
    bool_ui(
        wb,
        ui,
        "gravity",
        &format!("{p}.gravity.enabled"),
        a.gravity.enabled,
    );
    num_ui(
        wb,
        ui,
        "incline",
        "deg",
        &format!("{p}.gravity.incline_deg"),
        a.gravity.incline_deg,
    );
    num_ui(
        wb,
        ui,
        "moving mass",
        "kg",
        &format!("{p}.gravity.moving_mass_kg"),
        a.gravity.moving_mass_kg,
    );
    num_ui(
        wb,
        ui,
        "constant force",
        "N",
        &format!("{p}.gravity.offset_n"),
        a.gravity.offset_n,
    );
    bool_ui(
        wb,
        ui,
        "screw thermal growth",
        &format!("{p}.screw_thermal.enabled"),
        a.screw_thermal.enabled,
    );
    num_ui(
        wb,
        ui,
        "screw heat capacity",
        "J/K",
        &format!("{p}.screw_thermal.heat_capacity_j_per_k"),
        a.screw_thermal.heat_capacity_j_per_k,
    );
    bool_ui(
        wb,
        ui,
        "lead error",
        &format!("{p}.lead_error.enabled"),
        a.lead_error.enabled,
    );
    num_ui(
        wb,
        ui,
        "lead error amplitude",
        "µm",
        &format!("{p}.lead_error.amplitude_um"),
        a.lead_error.amplitude_um,
    );
    bool_ui(
        wb,
        ui,
        "quantize motor encoder",
        &format!("{p}.encoder.quantize_motor"),
        a.encoder.quantize_motor,
    );
    bool_ui(
        wb,
        ui,
        "quantize linear scale",
        &format!("{p}.encoder.quantize_scale"),
        a.encoder.quantize_scale,
    );
}
