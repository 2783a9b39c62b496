//! The parameter sections: Backlash, Quadrant, Thermal, Cross, Servo, Plant, NC.
//!
//! Each section is a lens — a closure from the preset to one of its structs — drawn by
//! walking that struct's fields ([`axisbench::preset::Fields`]): the compiler checks the way
//! from a widget to its field, and the unit and range shown come from the same list that
//! validates files and `--set`. An edit is written into a copy of the preset, the copy is
//! checked like a preset file, and only then does it replace the running one; on error the
//! message stays next to the field (under the field's path) and the previous value stays in
//! force.

use std::collections::BTreeMap;

use axisbench::comp::quadrant::Quadrant;
use axisbench::comp::thermal::Thermal;
use axisbench::measure;
use axisbench::preset::comp::Reversal;
use axisbench::preset::fields::{Field, FieldsDyn, Num, TableSpec, Visitor, Walker, short};
use axisbench::preset::{AxisParams, Preset};
use axisbench::units::{fmt_num, fmt_qty, fmt_sig, m_to_mm, m_to_um, s_to_ms, symbol};

/// Significant digits an editable number shows (more than a read-out: it is typed over).
const FIELD_DIGITS: i32 = 6;
use eframe::egui;

use super::Workbench;

/// A lens from the preset to one section (None when the section does not exist, e.g. an
/// axis index past the end after a preset change).
pub type Lens = dyn Fn(&mut Preset) -> Option<&mut dyn FieldsDyn>;

/// Draws the fields of one section and records which one the user committed.
struct Form<'a> {
    ui: &'a mut egui::Ui,
    /// Text being typed, by field path.
    bufs: &'a mut BTreeMap<String, String>,
    errors: &'a BTreeMap<String, String>,
    /// The section's own path; sub-sections below it get a heading.
    root: String,
    heading: String,
    /// The field edited this frame.
    changed: Option<String>,
    /// A typed value that does not parse: (path, message).
    parse_error: Option<(String, String)>,
    /// Fields whose error is void (the value in force was typed again).
    cleared: Vec<String>,
}

impl Form<'_> {
    /// A heading when the walk enters a sub-section (a reversal direction, Stribeck, …).
    fn heading(&mut self, path: &str) {
        let parent = path.rsplit_once('.').map_or("", |(p, _)| p);
        if parent == self.heading {
            return;
        }
        self.heading = parent.to_owned();
        if let Some(rest) = parent.strip_prefix(&self.root)
            && let Some(sub) = rest.strip_prefix('.')
        {
            let name = sub.rsplit('.').next().unwrap_or(sub);
            let title = Reversal::from_name(name)
                .map(|r| format!("{} reversal", r.arrow()))
                .unwrap_or_else(|| name.replace('_', " "));
            self.ui.label(egui::RichText::new(title).strong());
        }
    }

    fn error_ui(&mut self, path: &str) {
        if let Some(e) = self.errors.get(path) {
            self.ui.colored_label(egui::Color32::RED, e);
        }
    }

    /// A text field committed on Enter or when it loses focus; returns the committed text.
    fn text_ui(&mut self, path: &str, label: &str, unit: &str, shown: String) -> Option<String> {
        let mut out = None;
        let mut cleared = false;
        let bufs = &mut *self.bufs;
        let errors = self.errors;
        self.ui.horizontal(|ui| {
            let l = ui.label(label);
            let buf = bufs.entry(path.to_owned()).or_insert_with(|| shown.clone());
            let r = ui
                .add(egui::TextEdit::singleline(buf).desired_width(90.0))
                .labelled_by(l.id)
                .on_hover_text(path);
            ui.label(symbol(unit));
            let commit =
                r.lost_focus() || (r.has_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter)));
            // The field shows the value in force whenever the user is not typing in it: a
            // refused value leaves with its error message, which names it, and a load, a
            // wizard or an edit elsewhere shows at once.
            // Whether the user typed here since the field took focus (egui's memory, by
            // the field's id), so a focus change alone never counts as typing.
            let typed_id = r.id.with("typed");
            if r.changed() {
                ui.data_mut(|d| d.insert_temp(typed_id, true));
            }
            if commit && buf.trim() != shown {
                out = Some(buf.trim().to_owned());
            } else if commit {
                // The value in force typed again: nothing is refused any more.
                let typed = ui
                    .data_mut(|d| d.remove_temp::<bool>(typed_id))
                    .unwrap_or(false);
                if typed && errors.contains_key(path) {
                    cleared = true;
                }
            } else if !r.has_focus() && *buf != shown {
                *buf = shown;
            }
            if commit {
                ui.data_mut(|d| d.remove::<bool>(typed_id));
            }
        });
        if cleared {
            self.cleared.push(path.to_owned());
        }
        out
    }

    fn num_ui(&mut self, path: &str, label: &str, x: &mut f64, r: Num) {
        if let Some(text) = self.text_ui(path, label, r.unit, fmt_sig(*x, FIELD_DIGITS)) {
            match text.parse::<f64>() {
                Ok(v) => {
                    *x = v;
                    self.changed = Some(path.to_owned());
                }
                Err(_) => {
                    self.parse_error = Some((
                        path.to_owned(),
                        format!("'{text}' is not a number (allowed: {})", r.describe()),
                    ))
                }
            }
        }
        self.error_ui(path);
    }

    fn count_ui(&mut self, path: &str, label: &str, n: &mut u32) {
        if let Some(text) = self.text_ui(path, label, "", n.to_string()) {
            match text.parse::<u32>() {
                Ok(v) => {
                    *n = v;
                    self.changed = Some(path.to_owned());
                }
                Err(_) => {
                    self.parse_error =
                        Some((path.to_owned(), format!("'{text}' is not a whole number")))
                }
            }
        }
        self.error_ui(path);
    }

    fn table_ui(&mut self, path: &str, label: &str, t: &mut Vec<(f64, f64)>, spec: TableSpec) {
        let l = self.ui.label(format!(
            "{label} ({}, {}), one point per line:",
            symbol(spec.x.unit),
            symbol(spec.y.unit)
        ));
        let key = format!("{path}#table");
        let buf = self.bufs.entry(key.clone()).or_insert_with(|| {
            t.iter()
                .map(|(x, y)| format!("{}, {}", short(*x), short(*y)))
                .collect::<Vec<_>>()
                .join("\n")
        });
        self.ui
            .add(egui::TextEdit::multiline(buf).desired_rows(4).code_editor())
            .labelled_by(l.id);
        let text = buf.clone();
        if self.ui.button(format!("Apply {label}")).clicked() {
            match parse_table(&text, spec.max_points) {
                Ok(pts) => {
                    *t = pts;
                    self.bufs.remove(&key);
                    self.changed = Some(path.to_owned());
                }
                Err(e) => self.parse_error = Some((path.to_owned(), e)),
            }
        }
        self.error_ui(path);
    }
}

/// "x, y" lines to points; the error names the line.
fn parse_table(text: &str, max_points: usize) -> Result<Vec<(f64, f64)>, String> {
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    if lines.len() > max_points {
        return Err(format!(
            "{} points; at most {max_points} are allowed",
            lines.len()
        ));
    }
    lines
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let mut it = l.split(',').map(|v| v.trim().parse::<f64>());
            match (it.next(), it.next(), it.next()) {
                (Some(Ok(x)), Some(Ok(y)), None) => Ok((x, y)),
                _ => Err(format!("line {}: '{l}' is not two numbers 'x, y'", i + 1)),
            }
        })
        .collect()
}

impl Visitor for Form<'_> {
    fn field(&mut self, path: &str, label: &'static str, f: Field<'_>, relevant: bool) {
        if !relevant {
            return;
        }
        self.heading(path);
        match f {
            Field::Num(x, r) => self.num_ui(path, label, x, r),
            Field::Count(n, _) => self.count_ui(path, label, n),
            Field::Flag(b) => {
                if self.ui.checkbox(b, label).changed() {
                    self.changed = Some(path.to_owned());
                }
                self.error_ui(path);
            }
            Field::Choice(c) => {
                let cur = c.current();
                let mut pick = None;
                self.ui.horizontal(|ui| {
                    ui.label(format!("{label}:"));
                    for o in c.options() {
                        if ui.selectable_label(cur == *o, *o).clicked() && cur != *o {
                            pick = Some(*o);
                        }
                    }
                });
                if let Some(o) = pick
                    && c.select(o)
                {
                    self.changed = Some(path.to_owned());
                }
                self.error_ui(path);
            }
            Field::Table(t, spec) => self.table_ui(path, label, t, spec),
            // Names, files, letters and whole lists are set in the preset file, not here.
            _ => {}
        }
    }
}

impl Workbench {
    /// Applies an edited copy of the preset: checked like a file, then handed to the
    /// running machine. On error the message is kept for `path` and nothing changes.
    pub fn commit(&mut self, cand: Preset, path: &str) -> bool {
        let errors = axisbench::machine::check(&cand);
        if !errors.is_empty() {
            let mine: Vec<String> = errors
                .iter()
                .filter(|e| e.path == path || e.path.starts_with(&format!("{path}.")))
                .map(|e| e.reason.clone())
                .collect();
            let msg = if mine.is_empty() {
                errors
                    .iter()
                    .map(|e| e.to_string())
                    .collect::<Vec<_>>()
                    .join("; ")
            } else {
                mine.join("; ")
            };
            self.field_errors.insert(
                path.to_owned(),
                format!("refused: {msg} (the value shown stays in force)"),
            );
            self.fields.remove(path);
            return false;
        }
        self.field_errors.remove(path);
        self.fields.remove(path);
        let applied = self.live.lock().machine.apply_params(&cand);
        self.preset = cand;
        if let Err(e) = applied {
            // A structural change: start the machine again with the new settings.
            self.status = format!("{e}; the machine was reset");
            self.reset();
        }
        true
    }

    /// Edits the preset through `f` (a typed change made by a wizard or a plot), checked
    /// and applied like a form edit; `path` names the field for the error message.
    pub fn edit(&mut self, path: &str, f: impl FnOnce(&mut Preset)) -> bool {
        let mut cand = self.preset.clone();
        f(&mut cand);
        self.commit(cand, path)
    }

    /// Draws the section the lens points at and applies what the user committed.
    pub fn section_fields_ui(&mut self, ui: &mut egui::Ui, at: &str, lens: &Lens) {
        let mut cand = self.preset.clone();
        let Some(section) = lens(&mut cand) else {
            return;
        };
        let mut form = Form {
            ui,
            bufs: &mut self.fields,
            errors: &self.field_errors,
            root: at.to_owned(),
            heading: at.to_owned(),
            changed: None,
            parse_error: None,
            cleared: vec![],
        };
        section.walk(&mut Walker::new(at, &mut form));
        let (changed, parse_error) = (form.changed, form.parse_error);
        for p in form.cleared {
            self.field_errors.remove(&p);
        }
        if let Some((path, msg)) = parse_error {
            self.fields.remove(&path);
            self.field_errors.insert(
                path,
                format!("refused: {msg} (the value shown stays in force)"),
            );
        }
        if let Some(path) = changed {
            self.commit(cand, &path);
        }
    }
}

/// The lens to a section of axis `i`.
fn axis_lens(
    i: usize,
    part: fn(&mut AxisParams) -> &mut dyn FieldsDyn,
) -> impl Fn(&mut Preset) -> Option<&mut dyn FieldsDyn> {
    move |p: &mut Preset| p.axes.get_mut(i).map(part)
}

/// The sections of the selected axis, then the machine-wide ones.
pub fn sections_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    let i = wb.axis_sel;
    let Some(name) = wb.preset.axes.get(i).map(|a| a.name.clone()) else {
        return;
    };
    let at = format!("axes.{name}");
    egui::CollapsingHeader::new("Backlash")
        .default_open(true)
        .show(ui, |ui| {
            wb.section_fields_ui(
                ui,
                &format!("{at}.backlash"),
                &axis_lens(i, |a| &mut a.backlash),
            );
        });
    egui::CollapsingHeader::new("Quadrant").show(ui, |ui| {
        wb.section_fields_ui(
            ui,
            &format!("{at}.quadrant"),
            &axis_lens(i, |a| &mut a.quadrant),
        );
        quadrant_live_ui(wb, ui);
    });
    egui::CollapsingHeader::new("Thermal").show(ui, |ui| {
        wb.section_fields_ui(
            ui,
            &format!("{at}.thermal"),
            &axis_lens(i, |a| &mut a.thermal),
        );
        thermal_live_ui(wb, ui);
        calibration_ui(wb, ui, &name);
    });
    egui::CollapsingHeader::new("Cross").show(ui, |ui| cross_ui(wb, ui));
    egui::CollapsingHeader::new("Servo").show(ui, |ui| {
        wb.section_fields_ui(ui, &format!("{at}.servo"), &axis_lens(i, |a| &mut a.servo));
    });
    egui::CollapsingHeader::new("Plant effects").show(ui, |ui| plant_ui(wb, ui, i, &at));
    egui::CollapsingHeader::new("NC").show(ui, |ui| {
        wb.section_fields_ui(ui, "nc", &|p: &mut Preset| {
            Some(&mut p.nc as &mut dyn FieldsDyn)
        });
    });
}

/// The plant's effects, one sub-section each.
fn plant_ui(wb: &mut Workbench, ui: &mut egui::Ui, i: usize, at: &str) {
    type Part = fn(&mut AxisParams) -> &mut dyn FieldsDyn;
    let parts: [(&str, &str, Part); 7] = [
        ("Drive", "drive", |a| &mut a.drive),
        ("Friction", "friction", |a| &mut a.friction),
        ("Lost motion", "lost_motion", |a| &mut a.lost_motion),
        ("Gravity and constant force", "gravity", |a| &mut a.gravity),
        ("Screw thermal growth", "screw_thermal", |a| {
            &mut a.screw_thermal
        }),
        ("Lead error", "lead_error", |a| &mut a.lead_error),
        ("Encoders", "encoder", |a| &mut a.encoder),
    ];
    for (title, key, part) in parts {
        egui::CollapsingHeader::new(title)
            .id_salt(format!("plant-{key}"))
            .show(ui, |ui| {
                wb.section_fields_ui(ui, &format!("{at}.{key}"), &axis_lens(i, part));
            });
    }
}

fn quadrant_live_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    let axis = wb.axis_sel;
    let readout = {
        let s = wb.live.lock();
        s.machine
            .find_comp::<Quadrant>()
            .find(|c| axisbench::comp::ServoComp::axis(*c) == axis)
            .map(|c| (c.pa_m, c.n, c.m, c.t_s))
    };
    if let Some((pa, n, m, t)) = readout {
        ui.label(format!(
            "live: PA = {}, N = {n}, M = {}, T = {}",
            fmt_qty(m_to_mm(pa), "mm"),
            fmt_num(m),
            fmt_qty(s_to_ms(t), "ms")
        ));
    }
}

fn thermal_live_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    let axis = wb.axis_sel;
    let readout = {
        let s = wb.live.lock();
        s.machine
            .find_comp::<Thermal>()
            .find(|c| c.axis() == axis)
            .map(|c| (c.f_m, c.f_applied_m, c.e, c.measurements))
    };
    if let Some((f, fa, e, n)) = readout {
        ui.label(format!(
            "live: F = {}, F' = {}, E = {}, measurements {n}",
            fmt_qty(m_to_um(f), "um"),
            fmt_qty(m_to_um(fa), "um"),
            fmt_num(e)
        ));
    }
    if ui.button("Measure now").clicked() {
        let mut s = wb.live.lock();
        for c in s.machine.find_comp_mut::<Thermal>() {
            if c.axis() == axis {
                c.request_measurement();
            }
        }
    }
}

/// Seed 002's Step 1 and Step 2, run on the simulated machine; their results go into the
/// preset like any edit.
fn calibration_ui(wb: &mut Workbench, ui: &mut egui::Ui, name: &str) {
    let i = wb.axis_sel;
    let path = format!("axes.{name}.thermal");
    ui.label(
        egui::RichText::new("Calibration (thermal patent, SPEC §4), on the simulated machine")
            .strong(),
    );
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
                name,
                std::slice::from_ref(&wb.programs),
                wb.step1_interval_s,
            );
            wb.step_result = Some(match r {
                Ok(fit) => {
                    let k = fit.k_per_um;
                    wb.edit(&format!("{path}.k_per_um"), |p| {
                        if let Some(a) = p.axes.get_mut(i) {
                            a.thermal.k_per_um = k;
                        }
                    });
                    format!("Step 1: k = {} per µm (applied)", fmt_num(k))
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
            let r = measure::thermal_step2(&wb.preset, name, &wb.programs, wb.step2_at_s);
            wb.step_result = Some(match r {
                Ok(av) => {
                    wb.edit(&format!("{path}.a"), |p| {
                        if let Some(a) = p.axes.get_mut(i) {
                            a.thermal.a = av;
                        }
                    });
                    format!("Step 2: a = {} (applied)", fmt_num(av))
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
    let n = wb.preset.cross.len();
    if n == 0 {
        ui.label("no cross tables");
    }
    for ti in 0..n {
        let Some(t) = wb.preset.cross.get(ti) else {
            break;
        };
        ui.label(
            egui::RichText::new(format!(
                "table {}: {} over {}",
                ti + 1,
                t.comp_axis,
                t.base_axis
            ))
            .strong(),
        );
        wb.section_fields_ui(ui, &format!("cross.{ti}"), &move |p: &mut Preset| {
            p.cross.get_mut(ti).map(|t| t as &mut dyn FieldsDyn)
        });
    }
    if wb.preset.crossbeam.enabled {
        ui.horizontal(|ui| {
            let l = ui.label("points");
            ui.add(egui::DragValue::new(&mut wb.sag_points).range(2..=65))
                .labelled_by(l.id);
            if ui.button("Measure tables from machine").clicked() {
                match measure::sag_tables(&wb.preset, wb.sag_points) {
                    Ok(tables) => {
                        let count = tables.len();
                        if wb.edit("cross", |p| p.cross = tables) {
                            wb.fields.retain(|k, _| !k.starts_with("cross."));
                            wb.status = format!(
                                "measured {count} cross tables of {} points",
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
