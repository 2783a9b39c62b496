//! The tuning workbench: the live machine on the left (scenario, program, run controls and every
//! parameter), linked plots in the middle. A thin layer over the model: every edit goes through a
//! typed lens on the preset (`edit.rs`), the same validation as files and the CLI, and
//! `Machine::apply_params`, so it takes effect from the next control period.

mod assets;
mod diagnose;
mod edit;
mod live;
mod plots;
mod scope;
mod session;
#[cfg(test)]
mod tests;
mod tune;
mod worker;

use eframe::egui;
use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Context as _, Result};
use axisbench::analysis;
use axisbench::export::{self, Target};
use axisbench::preset::comp::Reversal;
use axisbench::preset::{self, Preset, SHIPPED_PRESETS};
use axisbench::trace::AxisSignal;
use axisbench::units::mm_to_um;
use axisbench::{Machine, Trace};

pub use live::Live;

/// What a browse button says when no file was chosen: where no file dialog answers (no
/// portal, a bare X server) the path field is the way in.
pub fn no_dialog(field: &str) -> String {
    format!(
        "no file chosen (if no file dialog opened, none is available here: type the path into the {field} field)"
    )
}

/// The label of a target's export button.
pub fn export_label(t: Target) -> String {
    format!("Export {}", t.name())
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tab {
    Time,
    Circle,
    Sag,
    Compare,
    Diagnose,
    Tune,
}

/// An action that drops unsaved edits, waiting for the user's answer.
#[derive(Debug, Clone, PartialEq)]
pub enum Pending {
    /// Load a shipped scenario.
    Scenario(String),
    /// Open a preset file.
    Open(PathBuf),
    /// Close the window.
    Quit,
}

/// The answers to "unsaved edits".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Answer {
    Save,
    Discard,
    Cancel,
}

/// Result of an A/B run.
pub struct Compare {
    pub axis: String,
    pub reference: String,
    /// (label, t s, err m as the trace holds it) for A and B.
    pub runs: Vec<(String, Vec<f64>, Vec<f64>)>,
    /// Rows: (label, peak |err| µm, RMS err µm, worst +->- change µm, worst -->+ change µm).
    pub table: Vec<(String, f64, f64, f64, f64)>,
}

pub struct Workbench {
    pub preset: Preset,
    /// The preset file being edited; None for an embedded preset.
    pub path: Option<PathBuf>,
    /// Name of the shipped preset the session came from (programs resolve from it).
    pub origin: String,
    /// RON of the last saved/loaded state, for the unsaved-changes marker.
    pub saved_ron: String,
    /// Program text per channel, and the editor buffer of the shown channel.
    pub programs: Vec<(String, String)>,
    pub program_buf: String,
    pub program_channel: usize,
    pub program_error: Option<String>,
    pub live: Live,
    pub axis_sel: usize,
    /// Text buffers of the numeric fields, by preset path.
    pub fields: BTreeMap<String, String>,
    /// Validation messages shown next to their field, by preset path.
    pub field_errors: BTreeMap<String, String>,
    pub window_s: f64,
    pub tab: Tab,
    pub compare: Option<Compare>,
    pub compare_ref_saved: bool,
    pub loaded_trace: Option<(String, Trace)>,
    pub recent: Vec<PathBuf>,
    pub status: String,
    pub path_input: String,
    pub magnify: f64,
    pub sag_points: usize,
    /// The cross-table point being dragged on the sag plot: (table, point).
    pub sag_drag: Option<(usize, usize)>,
    pub step1_interval_s: f64,
    pub step2_at_s: f64,
    pub step_result: Option<String>,
    /// Where the session is autosaved; None in tests.
    pub session_file: Option<PathBuf>,
    last_autosave: std::time::Instant,
    last_session: String,
    /// Outcome of the last plot PNG export, set by the screenshot callback.
    png_msg: std::sync::Arc<std::sync::Mutex<Option<String>>>,
    plot_rects: BTreeMap<String, egui::Rect>,
    pub diag: diagnose::DiagState,
    /// How the time plots are set up (hidden signals, y scales, cursors, whole run).
    pub scope: scope::ScopeView,
    /// Presets replaced by an Apply, newest last, each with what replaced it.
    pub undo: Vec<(String, Preset)>,
    /// The Tune view.
    pub tune: tune::TuneState,
    /// An action waiting for Save / Discard / Cancel.
    pub pending: Option<Pending>,
    /// The user agreed to close the window; the next frame closes it.
    pub close_now: bool,
    /// The user agreed to quit (the close request is no longer refused).
    pub quit_allowed: bool,
}

/// Applies kept for Undo.
const MAX_UNDO: usize = 20;

impl Workbench {
    /// A workbench on a shipped preset, without autosave (tests, benchmarks).
    pub fn new_embedded(name: &str) -> Result<Workbench> {
        let lp = preset::load_embedded(name)?;
        let programs = lp.programs()?;
        let mut wb = Workbench::with(lp.preset, programs, None, name.to_owned())?;
        wb.apply_scenario_view();
        Ok(wb)
    }

    fn with(
        preset: Preset,
        programs: Vec<(String, String)>,
        path: Option<PathBuf>,
        origin: String,
    ) -> Result<Workbench> {
        let machine = Machine::new(&preset, &programs)?;
        let saved_ron = preset.to_ron()?;
        Ok(Workbench {
            program_buf: programs.first().map(|p| p.1.clone()).unwrap_or_default(),
            preset,
            path,
            origin,
            saved_ron,
            programs,
            program_channel: 0,
            program_error: None,
            live: Live::new(machine),
            axis_sel: 0,
            fields: BTreeMap::new(),
            field_errors: BTreeMap::new(),
            window_s: 10.0,
            tab: Tab::Time,
            compare: None,
            compare_ref_saved: false,
            loaded_trace: None,
            recent: vec![],
            status: String::new(),
            path_input: String::new(),
            magnify: 200.0,
            sag_points: 9,
            sag_drag: None,
            step1_interval_s: 120.0,
            step2_at_s: 600.0,
            step_result: None,
            session_file: None,
            last_autosave: std::time::Instant::now(),
            last_session: String::new(),
            png_msg: Default::default(),
            plot_rects: BTreeMap::new(),
            diag: diagnose::DiagState::new(),
            scope: scope::ScopeView::default(),
            undo: vec![],
            tune: tune::TuneState::default(),
            pending: None,
            close_now: false,
            quit_allowed: false,
        })
    }

    /// The workbench as the binary opens it: the autosaved session if there is one, else
    /// the embedded default preset.
    pub fn open_session() -> Result<Workbench> {
        let file = session::session_file();
        if let Some(f) = &file
            && let Some(mut wb) = session::restore(f)
        {
            wb.status = format!("session restored from {}", f.display());
            wb.session_file = file;
            return Ok(wb);
        }
        let mut wb = Workbench::new_embedded("default.ron")?;
        wb.session_file = file;
        Ok(wb)
    }

    pub fn dirty(&self) -> bool {
        self.preset
            .to_ron()
            .map(|r| r != self.saved_ron)
            .unwrap_or(true)
    }

    pub fn axis_name(&self) -> String {
        self.preset
            .axes
            .get(self.axis_sel)
            .map_or_else(|| "x".into(), |a| a.name.clone())
    }

    /// Does `action` now, or, with unsaved edits, asks first (Save / Discard / Cancel).
    pub fn request(&mut self, action: Pending) {
        if self.dirty() {
            self.pending = Some(action);
        } else {
            self.perform(action);
        }
    }

    fn perform(&mut self, action: Pending) {
        match action {
            Pending::Scenario(n) => self.load_scenario(&n),
            Pending::Open(p) => self.open_file(p),
            Pending::Quit => {
                self.quit_allowed = true;
                self.close_now = true;
            }
        }
    }

    /// The user's answer to the unsaved-edits question. Save goes ahead only once the
    /// preset is saved; Cancel keeps everything as it is.
    pub fn answer(&mut self, a: Answer) {
        let Some(action) = self.pending.take() else {
            return;
        };
        match a {
            Answer::Save => {
                match (self.path.clone(), self.path_input.trim()) {
                    (Some(p), _) => self.save_to(p),
                    (None, typed) if !typed.is_empty() => self.save_to(PathBuf::from(typed)),
                    (None, _) => self.save_as_dialog(),
                }
                if self.dirty() {
                    self.status = format!(
                        "{}; nothing else was done, your edits are still here",
                        self.status
                    );
                } else {
                    self.perform(action);
                }
            }
            Answer::Discard => self.perform(action),
            Answer::Cancel => self.status = "cancelled: your edits are still here".into(),
        }
    }

    /// The unsaved-edits question, while an action waits for it.
    fn pending_ui(&mut self, ctx: &egui::Context) {
        let Some(action) = self.pending.clone() else {
            return;
        };
        let what = match &action {
            Pending::Scenario(n) => format!("load scenario {n}"),
            Pending::Open(p) => format!("open {}", p.display()),
            Pending::Quit => "quit".to_owned(),
        };
        let mut answer = None;
        let r = egui::Modal::new(egui::Id::unique("unsaved-edits")).show(ctx, |ui| {
            ui.heading("Unsaved edits");
            ui.label(format!(
                "The preset has edits that are not saved. Save them before you {what}?"
            ));
            let n = Preset::from_ron(&self.saved_ron, "saved")
                .map(|p| p.diff(&self.preset).len())
                .unwrap_or(0);
            ui.label(if n == 1 {
                "1 field differs from the saved preset.".to_owned()
            } else {
                format!("{n} fields differ from the saved preset.")
            });
            ui.horizontal(|ui| {
                if ui.button("Save").clicked() {
                    answer = Some(Answer::Save);
                }
                if ui.button("Discard").clicked() {
                    answer = Some(Answer::Discard);
                }
                if ui.button("Cancel").clicked() {
                    answer = Some(Answer::Cancel);
                }
            });
        });
        if r.should_close() && answer.is_none() {
            answer = Some(Answer::Cancel);
        }
        if let Some(a) = answer {
            self.answer(a);
        }
    }

    /// Replaces the whole preset (an Apply of a diagnosis or a tune), keeping the previous
    /// one on the undo stack under `what`.
    pub fn replace_preset(&mut self, new: Preset, what: String) {
        let old = std::mem::replace(&mut self.preset, new);
        self.undo.push((what, old));
        if self.undo.len() > MAX_UNDO {
            self.undo.remove(0);
        }
        self.preset_replaced();
    }

    /// Undoes the last Apply: the preset before it comes back.
    pub fn undo_apply(&mut self) {
        let Some((what, old)) = self.undo.pop() else {
            self.status = "nothing to undo".into();
            return;
        };
        self.preset = old;
        self.preset_replaced();
        self.diag.run.applied = false;
        self.tune.run.applied = false;
        self.status = format!("undone: {what}");
    }

    /// The running machine takes the new preset (from the next period, or by a reset when
    /// the change is structural); the field buffers follow it.
    fn preset_replaced(&mut self) {
        self.fields.clear();
        self.field_errors.clear();
        let applied = self.live.lock().machine.apply_params(&self.preset);
        if applied.is_err() {
            self.reset();
        }
    }

    /// Rebuilds the machine from the current preset and programs (Reset).
    pub fn reset(&mut self) {
        match Machine::new(&self.preset, &self.programs) {
            Ok(m) => {
                let running = self.live.lock().running;
                self.live.replace(m);
                self.live.lock().running = running;
            }
            Err(e) => self.status = format!("cannot reset: {e}"),
        }
    }

    /// Takes the program editor's text for the shown channel; a bad program keeps the old
    /// one and shows the error with its line and column.
    pub fn apply_program(&mut self) {
        let mut progs = self.programs.clone();
        if let Some(p) = progs.get_mut(self.program_channel) {
            p.1 = self.program_buf.clone();
        }
        match Machine::new(&self.preset, &progs) {
            Ok(m) => {
                self.programs = progs;
                self.program_error = None;
                self.live.replace(m);
                self.status = "program applied; machine reset".into();
            }
            Err(e) => self.program_error = Some(e.to_string()),
        }
    }

    /// Loads a shipped scenario (preset, programs and explanation).
    pub fn load_scenario(&mut self, name: &str) {
        match Workbench::new_embedded(name) {
            Ok(wb) => self.adopt(wb, format!("loaded scenario {name}")),
            Err(e) => self.status = format!("cannot load {name}: {e:#}"),
        }
    }

    /// Opens a preset file (and its programs, relative to it).
    pub fn open_file(&mut self, path: PathBuf) {
        let r = (|| -> Result<Workbench> {
            let lp = preset::load(&path.display().to_string())?;
            let programs = lp.programs()?;
            Workbench::with(
                lp.preset,
                programs,
                Some(path.clone()),
                path.display().to_string(),
            )
        })();
        match r {
            Ok(wb) => {
                self.add_recent(path.clone());
                self.adopt(wb, format!("opened {}", path.display()));
            }
            Err(e) => self.status = format!("cannot open {}: {e:#}", path.display()),
        }
    }

    fn adopt(&mut self, wb: Workbench, status: String) {
        let running = self.live.lock().running;
        match Machine::new(&wb.preset, &wb.programs) {
            Ok(m) => self.live.replace(m),
            Err(e) => {
                self.status = format!("cannot load: {e}");
                return;
            }
        }
        self.live.lock().running = running;
        self.preset = wb.preset;
        self.path = wb.path;
        self.origin = wb.origin;
        self.saved_ron = wb.saved_ron;
        self.programs = wb.programs;
        self.program_buf = self
            .programs
            .first()
            .map(|p| p.1.clone())
            .unwrap_or_default();
        self.program_channel = 0;
        self.program_error = None;
        self.axis_sel = 0;
        self.fields.clear();
        self.field_errors.clear();
        self.compare = None;
        // Undo restores presets of the machine that was here, not of this one.
        self.undo.clear();
        self.apply_scenario_view();
        self.status = status;
    }

    /// The scenario's own speed, window and view (a 2 h warm-up opens at 1000× with the
    /// whole run shown); other presets keep what the user set.
    fn apply_scenario_view(&mut self) {
        if let Some(v) = assets::scenario(&self.origin) {
            self.live.lock().speed = v.speed;
            self.window_s = v.window_s;
            self.scope.whole_run = v.whole_run;
        }
    }

    /// Saves the preset (atomically) to `path`, with its programs next to it.
    pub fn save_to(&mut self, path: PathBuf) {
        // The preset and its programs are one unit: all of them are written, or none.
        let r = self.preset.save_with_programs(&path, &self.programs);
        match r {
            Ok(()) => {
                self.saved_ron = self.preset.to_ron().unwrap_or_default();
                self.path = Some(path.clone());
                self.add_recent(path.clone());
                self.status = format!("saved {}", path.display());
            }
            Err(e) => self.status = format!("not saved: {e:#}"),
        }
    }

    /// Exports the current preset to `target` into the folder `dir` (files and mapping
    /// report), as `axisbench export` does; nothing is written if a check fails.
    pub fn export_to(&mut self, target: Target, dir: PathBuf) {
        if dir.as_os_str().is_empty() {
            self.status = "export: type an output folder into the Path field first".into();
            return;
        }
        let r = export::export(
            &self.preset,
            &self.programs,
            target,
            &export::ExportOptions::default(),
        )
        .and_then(|ex| ex.write(&dir).map(|w| (ex, w)));
        self.status = match r {
            Ok((ex, written)) => format!(
                "exported to {} in {}: {} files, {} report entries ({} not representable)",
                target.title(),
                dir.display(),
                written.len(),
                ex.report.entries.len(),
                ex.report
                    .with_status(export::Status::NotRepresentable)
                    .count()
            ),
            Err(e) => format!("not exported: {e}"),
        };
    }

    fn add_recent(&mut self, p: PathBuf) {
        self.recent.retain(|q| *q != p);
        self.recent.insert(0, p);
        self.recent.truncate(8);
    }

    /// Runs the program twice headless, with the current settings and with the reference
    /// (compensation off, or the last saved preset), and fills the compare table.
    pub fn run_compare(&mut self) {
        let axis = self.axis_name();
        let reference = if self.compare_ref_saved {
            match Preset::from_ron(&self.saved_ron, "saved") {
                Ok(p) => ("last saved preset".to_owned(), p),
                Err(e) => {
                    self.status = format!("cannot compare: {e}");
                    return;
                }
            }
        } else {
            (
                "compensation off".to_owned(),
                self.preset.compensations_off(),
            )
        };
        let mut runs = vec![];
        let mut table = vec![];
        for (label, p) in [
            ("A: current".to_owned(), self.preset.clone()),
            (format!("B: {}", reference.0), reference.1),
        ] {
            let mut m = match Machine::new(&p, &self.programs) {
                Ok(m) => m,
                Err(e) => {
                    self.status = format!("cannot compare: {e}");
                    return;
                }
            };
            if let Err(e) = m.run(4.0 * 3600.0) {
                self.status = format!("cannot compare: {e}");
                return;
            }
            let sums = analysis::summarize(&m.trace);
            if let Some(s) = sums.iter().find(|s| s.axis == axis) {
                let worst = |plus_to_minus: bool| {
                    s.reversals
                        .iter()
                        .filter(|r| (r.direction == Reversal::PlusToMinus) == plus_to_minus)
                        .map(|r| mm_to_um(r.peak_err_mm))
                        .fold(0.0, f64::max)
                };
                table.push((
                    label.clone(),
                    mm_to_um(s.max_err_mm),
                    mm_to_um(s.rms_err_mm),
                    worst(true),
                    worst(false),
                ));
            }
            let t = m.trace.t().to_vec();
            let err = m
                .trace
                .axis_values(&axis, AxisSignal::Err)
                .map(<[f64]>::to_vec)
                .unwrap_or_default();
            runs.push((label, t, err));
        }
        self.compare = Some(Compare {
            axis,
            reference: reference.0,
            runs,
            table,
        });
        self.tab = Tab::Compare;
    }

    /// One frame of the workbench.
    pub fn ui(&mut self, ui: &mut egui::Ui) {
        let ctx = ui.ctx().clone();
        if ctx.input(|i| i.viewport().close_requested()) && !self.quit_allowed && self.dirty() {
            ctx.send_viewport_cmd(egui::ViewportCommand::CancelClose);
            self.pending = Some(Pending::Quit);
        }
        if self.close_now {
            self.close_now = false;
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        self.pending_ui(&ctx);
        self.menu_ui(ui);
        egui::Panel::bottom("status").show(ui, |ui| {
            ui.horizontal(|ui| {
                let (t, mode, running, fault, done) = {
                    let s = self.live.lock();
                    (
                        s.machine.t_s(),
                        s.machine.channels.first().map(|c| c.mode),
                        s.running,
                        s.fault.clone(),
                        s.machine.done(),
                    )
                };
                ui.label(format!(
                    "t = {t:.3} s   mode: {}   {}",
                    match mode {
                        Some(preset::Mode::Direct) => "direct command",
                        _ => "normal",
                    },
                    if running {
                        "running".to_owned()
                    } else if done {
                        format!("program finished at t = {t:.3} s: Reset to run it again")
                    } else {
                        "paused".to_owned()
                    }
                ));
                ui.separator();
                if let Some(f) = fault {
                    ui.colored_label(
                        egui::Color32::RED,
                        format!("stopped: {f} (Reset to start again)"),
                    );
                }
                ui.label(&self.status);
            });
        });
        egui::Panel::left("machine")
            .default_size(380.0)
            .resizable(true)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| {
                    self.run_controls_ui(ui);
                    ui.separator();
                    edit::sections_ui(self, ui);
                });
            });
        egui::CentralPanel::default().show(ui, |ui| {
            ui.horizontal(|ui| {
                for (tab, label) in [
                    (Tab::Time, "Time plots"),
                    (Tab::Circle, "Circle (XY)"),
                    (Tab::Sag, "Sag profile"),
                    (Tab::Compare, "A/B compare"),
                    (Tab::Diagnose, "Diagnose"),
                    (Tab::Tune, "Tune"),
                ] {
                    ui.selectable_value(&mut self.tab, tab, label);
                }
            });
            ui.separator();
            match self.tab {
                Tab::Time => scope::time_plots_ui(self, ui),
                Tab::Circle => plots::circle_ui(self, ui),
                Tab::Sag => plots::sag_ui(self, ui),
                Tab::Compare => plots::compare_ui(self, ui),
                Tab::Diagnose => diagnose::diagnose_ui(self, ui),
                Tab::Tune => tune::tune_ui(self, ui),
            }
        });
        self.handle_screenshot(ui.ctx());
        if self.live.lock().running {
            ui.ctx().request_repaint();
        }
        self.autosave();
    }

    fn menu_ui(&mut self, ui: &mut egui::Ui) {
        egui::Panel::top("menu").show(ui, |ui| {
            egui::MenuBar::new().ui(ui, |ui| {
                ui.menu_button("File", |ui| {
                    if ui.button("Open preset…").clicked() {
                        if let Some(p) = rfd::FileDialog::new()
                            .add_filter("RON preset", &["ron"])
                            .pick_file()
                        {
                            self.request(Pending::Open(p));
                        } else {
                            self.status = no_dialog("Path");
                        }
                        ui.close();
                    }
                    if ui.button("Save").clicked() {
                        match self.path.clone() {
                            Some(p) => self.save_to(p),
                            None => self.save_as_dialog(),
                        }
                        ui.close();
                    }
                    if ui.button("Save as…").clicked() {
                        self.save_as_dialog();
                        ui.close();
                    }
                    ui.menu_button("Recent", |ui| {
                        for p in self.recent.clone() {
                            if ui.button(p.display().to_string()).clicked() {
                                self.request(Pending::Open(p));
                                ui.close();
                            }
                        }
                    });
                    ui.separator();
                    if ui.button("Record trace to CSV…").clicked() {
                        if let Some(p) = rfd::FileDialog::new()
                            .add_filter("trace", &["csv"])
                            .save_file()
                        {
                            self.record_csv(p);
                        } else {
                            self.status = no_dialog("Path");
                        }
                        ui.close();
                    }
                    if ui.button("Open trace CSV…").clicked() {
                        if let Some(p) = rfd::FileDialog::new()
                            .add_filter("trace", &["csv"])
                            .pick_file()
                        {
                            self.open_trace(p);
                        } else {
                            self.status = no_dialog("Path");
                        }
                        ui.close();
                    }
                    ui.separator();
                    ui.menu_button("Export", |ui| {
                        for t in Target::ALL {
                            if ui.button(format!("{}…", t.title())).clicked() {
                                match rfd::FileDialog::new().pick_folder() {
                                    Some(dir) => self.export_to(t, dir),
                                    None => self.status = no_dialog("Path"),
                                }
                                ui.close();
                            }
                        }
                    });
                });
                ui.menu_button("Scenarios", |ui| {
                    for name in SHIPPED_PRESETS {
                        let note = assets::scenario_note(name);
                        if ui.button(*name).on_hover_text(note).clicked() {
                            self.request(Pending::Scenario((*name).to_owned()));
                            ui.close();
                        }
                    }
                });
                let title = format!(
                    "axisbench — {}{}",
                    self.path
                        .as_ref()
                        .map_or(self.origin.clone(), |p| p.display().to_string()),
                    if self.dirty() {
                        " * unsaved changes"
                    } else {
                        ""
                    }
                );
                ui.label(title);
            });
        });
    }

    fn save_as_dialog(&mut self) {
        if let Some(p) = rfd::FileDialog::new()
            .add_filter("RON preset", &["ron"])
            .save_file()
        {
            self.save_to(p);
        } else {
            self.status = no_dialog("Path");
        }
    }

    pub fn record_csv(&mut self, path: PathBuf) {
        let tr = self.live.lock().ring.to_trace();
        match tr.write_csv(&path) {
            Ok(()) => self.status = format!("trace written to {}", path.display()),
            Err(e) => self.status = e.to_string(),
        }
    }

    pub fn open_trace(&mut self, path: PathBuf) {
        match axisbench::diagnose::read_record(&path, &self.preset, None) {
            Ok(t) => {
                self.status = format!("opened trace {} ({} samples)", path.display(), t.len());
                self.loaded_trace = Some((path.display().to_string(), t));
            }
            Err(e) => self.status = e.to_string(),
        }
    }

    /// One button per export target; the Path field names the output folder.
    fn export_row_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal_wrapped(|ui| {
            ui.label("Export to path:");
            for t in Target::ALL {
                if ui
                    .button(export_label(t))
                    .on_hover_text(format!(
                        "{}: files and mapping_report.md into the folder in the Path field",
                        t.title()
                    ))
                    .clicked()
                {
                    self.export_to(t, PathBuf::from(self.path_input.trim()));
                }
            }
        });
    }

    fn run_controls_ui(&mut self, ui: &mut egui::Ui) {
        ui.heading("Machine");
        let note = assets::scenario_note(&self.origin);
        if !note.is_empty() {
            ui.label(egui::RichText::new(note).italics());
        }
        self.files_ui(ui);
        self.run_buttons_ui(ui);
        self.modes_ui(ui);
        self.program_ui(ui);
        self.axis_select_ui(ui);
    }

    /// Scenario choice, the path field with its open/save/export/trace buttons.
    fn files_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            let mut chosen = None;
            egui::ComboBox::from_label("Scenario")
                .selected_text(&self.origin)
                .show_ui(ui, |ui| {
                    for name in SHIPPED_PRESETS {
                        if ui.selectable_label(self.origin == *name, *name).clicked() {
                            chosen = Some(*name);
                        }
                    }
                });
            if let Some(n) = chosen {
                self.request(Pending::Scenario(n.to_owned()));
            }
        });
        ui.horizontal(|ui| {
            let label = ui.label("Path:");
            ui.add(egui::TextEdit::singleline(&mut self.path_input).desired_width(160.0))
                .labelled_by(label.id);
            if ui.button("Open path").clicked() {
                self.request(Pending::Open(PathBuf::from(self.path_input.trim())));
            }
            if ui.button("Save to path").clicked() {
                self.save_to(PathBuf::from(self.path_input.trim()));
            }
        });
        self.export_row_ui(ui);
        ui.horizontal(|ui| {
            if ui.button("Record trace CSV to path").clicked() {
                self.record_csv(PathBuf::from(self.path_input.trim()));
            }
            if ui.button("Open trace CSV from path").clicked() {
                self.open_trace(PathBuf::from(self.path_input.trim()));
            }
        });
    }

    /// Run, pause, step, reset; speed and plot window.
    fn run_buttons_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            let running = self.live.lock().running;
            if ui.add_enabled(!running, egui::Button::new("Run")).clicked() {
                self.live.lock().running = true;
            }
            if ui
                .add_enabled(running, egui::Button::new("Pause"))
                .clicked()
            {
                self.live.lock().running = false;
            }
            if ui.button("Step").on_hover_text("one T2 period").clicked() {
                let n = self.live.lock().machine.n23 as u64;
                self.live.advance(n);
            }
            if ui.button("Reset").clicked() {
                self.reset();
            }
        });
        ui.horizontal(|ui| {
            let label = ui.label("Speed:");
            let mut speed = self.live.lock().speed;
            let r = ui
                .add(
                    egui::Slider::new(&mut speed, 0.1..=1000.0)
                        .logarithmic(true)
                        .suffix("×"),
                )
                .labelled_by(label.id);
            if r.changed() {
                self.live.lock().speed = speed;
            }
        });
        ui.horizontal(|ui| {
            let label = ui.label("Window:");
            ui.add(egui::Slider::new(&mut self.window_s, 1.0..=live::MAX_WINDOW_S).suffix(" s"))
                .labelled_by(label.id);
        });
    }

    /// The NC's initial processing mode and the PLC's mode-switch requests (processing-mode patent,
    /// SPEC §3).
    fn modes_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.label("Initial mode:");
            let mode = self.preset.nc.initial_mode;
            for (m, label) in [
                (preset::Mode::Normal, "normal"),
                (preset::Mode::Direct, "direct command"),
            ] {
                if ui.selectable_label(mode == m, label).clicked()
                    && mode != m
                    && self.edit("nc.initial_mode", |p| p.nc.initial_mode = m)
                {
                    self.reset();
                }
            }
        });
        ui.horizontal(|ui| {
            ui.label("PLC switch:");
            if ui.button("-> direct").clicked() {
                self.live
                    .lock()
                    .machine
                    .plc_request(0, preset::Mode::Direct);
            }
            if ui.button("-> normal").clicked() {
                self.live
                    .lock()
                    .machine
                    .plc_request(0, preset::Mode::Normal);
            }
        });
    }

    /// The program editor of each channel.
    fn program_ui(&mut self, ui: &mut egui::Ui) {
        egui::CollapsingHeader::new("Program")
            .default_open(false)
            .show(ui, |ui| {
                if self.programs.len() > 1 {
                    ui.horizontal(|ui| {
                        for c in 0..self.programs.len() {
                            if ui
                                .selectable_label(
                                    self.program_channel == c,
                                    format!("channel {}", c + 1),
                                )
                                .clicked()
                            {
                                self.program_channel = c;
                                self.program_buf = self.programs[c].1.clone();
                            }
                        }
                    });
                }
                let l = ui.label(format!(
                    "Program {}",
                    self.programs
                        .get(self.program_channel)
                        .map_or("", |p| p.0.as_str())
                ));
                ui.add(
                    egui::TextEdit::multiline(&mut self.program_buf)
                        .code_editor()
                        .desired_rows(8)
                        .desired_width(f32::INFINITY),
                )
                .labelled_by(l.id);
                if ui.button("Apply program").clicked() {
                    self.apply_program();
                }
                if let Some(e) = &self.program_error {
                    ui.colored_label(egui::Color32::RED, e);
                }
            });
    }

    /// Which axis the parameter sections show.
    fn axis_select_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.label("Axis:");
            for (i, a) in self.preset.axes.iter().enumerate() {
                if ui.selectable_label(self.axis_sel == i, &a.name).clicked() {
                    self.axis_sel = i;
                }
            }
        });
    }

    fn handle_screenshot(&mut self, _ctx: &egui::Context) {
        let done = match self.png_msg.lock() {
            Ok(mut m) => m.take(),
            Err(p) => p.into_inner().take(),
        };
        if let Some(msg) = done {
            self.status = msg;
        }
    }

    /// Asks for a screenshot of the plot `name` to be written to `path` as PNG.
    pub fn export_plot(&mut self, ctx: &egui::Context, name: &str, path: PathBuf) {
        let Some(rect) = self.plot_rects.get(name).copied() else {
            return;
        };
        let ppp = ctx.pixels_per_point();
        let msg = std::sync::Arc::clone(&self.png_msg);
        let repaint = ctx.clone();
        ctx.send_viewport_cmd(egui::ViewportCommand::Screenshot(
            egui::ScreenshotCallback::new(move |image| {
                let text = match save_png(&image, rect, ppp, &path) {
                    Ok(()) => format!("plot saved to {}", path.display()),
                    Err(e) => format!("plot not saved: {e:#}"),
                };
                if let Ok(mut m) = msg.lock() {
                    *m = Some(text);
                }
                repaint.request_repaint();
            }),
        ));
    }

    fn autosave(&mut self) {
        let Some(file) = self.session_file.clone() else {
            return;
        };
        if self.last_autosave.elapsed().as_secs_f64() < 3.0 {
            return;
        }
        self.last_autosave = std::time::Instant::now();
        let text = session::to_text(self);
        if text != self.last_session {
            if let Err(e) = session::write(&file, &text) {
                self.status = format!("autosave failed: {e:#}");
            }
            self.last_session = text;
        }
    }

    /// Writes the session now (on exit).
    pub fn save_session(&mut self) {
        if let Some(file) = self.session_file.clone() {
            let text = session::to_text(self);
            let _ = session::write(&file, &text);
        }
    }
}

/// "Undo apply" while an Apply (of a diagnosis or a tune) can be undone.
fn undo_apply_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    let Some(what) = wb.undo.last().map(|(w, _)| w.clone()) else {
        return;
    };
    if ui
        .button("Undo apply")
        .on_hover_text(format!("restore the preset before: {what}"))
        .clicked()
    {
        wb.undo_apply();
    }
}

/// Why an Apply button is off, under it.
fn apply_off_ui(ui: &mut egui::Ui, why: &str) {
    ui.colored_label(
        egui::Color32::from_rgb(230, 160, 60),
        format!("Apply is off: {why}"),
    );
}

/// Crops the plot's rectangle out of a window screenshot and writes it as PNG, atomically.
fn save_png(
    image: &egui::ColorImage,
    rect: egui::Rect,
    ppp: f32,
    path: &std::path::Path,
) -> Result<()> {
    let region = image.region(&rect, Some(ppp));
    let [w, h] = region.size;
    let bytes: Vec<u8> = region.pixels.iter().flat_map(|c| c.to_array()).collect();
    let img = image::RgbaImage::from_raw(w as u32, h as u32, bytes).context("screenshot size")?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    axisbench::fsutil::write_atomic(path, &png)
        .with_context(|| format!("{}: cannot write", path.display()))?;
    Ok(())
}

/// The eframe shell around the workbench.
pub struct App {
    pub wb: Workbench,
}

impl eframe::App for App {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.wb.ui(ui);
    }

    fn on_exit(&mut self, _gl: Option<&eframe::glow::Context>) {
        self.wb.save_session();
    }
}

/// Opens the workbench window, on `preset` if given, else on the saved session; the model
/// runs from the first frame unless `paused`.
pub fn run(preset: Option<PathBuf>, paused: bool) -> Result<()> {
    let mut wb = Workbench::open_session()?;
    if let Some(p) = preset {
        // `embedded:NAME.ron` opens a shipped scenario, with its speed and view.
        match p.to_str().and_then(|s| s.strip_prefix("embedded:")) {
            Some(name) => {
                wb.load_scenario(name);
                if wb.origin != name {
                    anyhow::bail!("{}", wb.status);
                }
            }
            None => {
                wb.open_file(p.clone());
                if wb.path.as_ref() != Some(&p) {
                    anyhow::bail!("{}", wb.status);
                }
            }
        }
    }
    wb.live.lock().running = !paused;
    let mut viewport = egui::ViewportBuilder::default()
        .with_title("axisbench")
        .with_inner_size([1280.0, 800.0]);
    if let Some(icon) = assets::icon() {
        viewport = viewport.with_icon(std::sync::Arc::new(icon));
    }
    let options = eframe::NativeOptions {
        viewport,
        ..Default::default()
    };
    eframe::run_native(
        "axisbench",
        options,
        Box::new(move |cc| {
            let ctx = cc.egui_ctx.clone();
            wb.live.spawn(move || ctx.request_repaint());
            Ok(Box::new(App { wb }))
        }),
    )
    .map_err(|e| anyhow::anyhow!("the workbench window could not open: {e}"))
}

/// Frame time of the workbench with the plots full: the default preset run for 10 s at
/// 8 kHz, a 10 s window, then `n` frames laid out and tessellated headlessly. Returns the
/// mean, 99th percentile and maximum in ms. Rasterising is the GPU's (or Mesa's) part and
/// is not included.
pub fn bench_frames(n: usize) -> Result<(f64, f64, f64)> {
    let mut wb = Workbench::new_embedded("default.ron")?;
    wb.live.advance(80_000);
    wb.window_s = 10.0;
    let ctx = egui::Context::default();
    let raw = || egui::RawInput {
        screen_rect: Some(egui::Rect::from_min_size(
            egui::Pos2::ZERO,
            egui::vec2(1400.0, 900.0),
        )),
        ..Default::default()
    };
    let mut times = Vec::with_capacity(n);
    for i in 0..n + 5 {
        let t0 = std::time::Instant::now();
        let out = ctx.run_ui(raw(), |ui| wb.ui(ui));
        let prims = ctx.tessellate(out.shapes, out.pixels_per_point);
        std::hint::black_box(prims);
        if i >= 5 {
            times.push(axisbench::units::s_to_ms(t0.elapsed().as_secs_f64()));
        }
    }
    times.sort_by(f64::total_cmp);
    let mean = times.iter().sum::<f64>() / times.len().max(1) as f64;
    let p99 = times
        .get(((times.len() as f64 * 0.99) as usize).min(times.len().saturating_sub(1)))
        .copied()
        .unwrap_or(0.0);
    let max = times.last().copied().unwrap_or(0.0);
    Ok((mean, p99, max))
}
