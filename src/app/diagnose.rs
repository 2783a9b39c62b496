//! The Diagnose view: pick a measured record (and a validation record), run the
//! sim-to-real diagnosis on a worker thread with a progress bar and Cancel, read where the
//! residual lies, which effect explains it, and apply the fitted effect to the preset.

use super::Workbench;
use axisbench::diagnose::{self, Options, Progress, Report, regimes::Regime, replay::Record};
use eframe::egui;
use egui_plot::{Bar, BarChart, Legend, Line, Plot, PlotPoints, Points, Polygon};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// A diagnosis running on its worker thread.
pub struct DiagJob {
    pub progress: Arc<Mutex<(f64, String)>>,
    pub cancel: Arc<AtomicBool>,
    pub result: Arc<Mutex<Option<Result<Report, String>>>>,
}

#[derive(Default)]
pub struct DiagState {
    pub trace_path: String,
    pub validate_path: String,
    pub holdout: f64,
    pub job: Option<DiagJob>,
    pub report: Option<Report>,
    pub error: Option<String>,
}

impl DiagState {
    pub fn new() -> DiagState {
        DiagState {
            holdout: 0.3,
            ..Default::default()
        }
    }
}

/// Reads a record for the preset the way the CLI does.
fn load(preset: &axisbench::Preset, path: &str) -> Result<Record, String> {
    let p = PathBuf::from(path);
    let tr = diagnose::read_record(&p, preset, None).map_err(|e| e.to_string())?;
    let axis = diagnose::pick_axis(&tr, path, preset, None).map_err(|e| e.to_string())?;
    Record::for_preset(&tr, path, preset, &axis).map_err(|e| e.to_string())
}

impl Workbench {
    /// Starts the diagnosis of the chosen record(s) against the current preset.
    pub fn start_diagnosis(&mut self) {
        let preset = self.preset.clone();
        let main_path = self.diag.trace_path.trim().to_owned();
        let val_path = self.diag.validate_path.trim().to_owned();
        let holdout = self.diag.holdout;
        let job = DiagJob {
            progress: Arc::new(Mutex::new((0.0, "reading the records".into()))),
            cancel: Arc::new(AtomicBool::new(false)),
            result: Arc::new(Mutex::new(None)),
        };
        let (progress, cancel, result) =
            (job.progress.clone(), job.cancel.clone(), job.result.clone());
        self.diag.error = None;
        std::thread::spawn(move || {
            let run = || -> Result<Report, String> {
                if main_path.is_empty() {
                    return Err("choose a measured record first".into());
                }
                let main = load(&preset, &main_path)?;
                let val = if val_path.is_empty() {
                    None
                } else {
                    Some(load(&preset, &val_path)?)
                };
                let report_fn = |f: f64, what: &str| {
                    if let Ok(mut p) = progress.lock() {
                        *p = (f, what.to_owned());
                    }
                };
                let prog = Progress {
                    report: &report_fn,
                    cancel: &cancel,
                };
                let opts = Options {
                    holdout,
                    ..Options::default()
                };
                diagnose::diagnose(&preset, &main, val.as_ref(), &opts, &prog)
                    .map_err(|e| e.to_string())
            };
            let r = run();
            if let Ok(mut slot) = result.lock() {
                *slot = Some(r);
            }
        });
        self.diag.job = Some(job);
    }

    /// Takes a finished job's result.
    fn poll_diagnosis(&mut self) {
        let done = self
            .diag
            .job
            .as_ref()
            .and_then(|j| j.result.lock().ok().and_then(|mut r| r.take()));
        if let Some(r) = done {
            self.diag.job = None;
            match r {
                Ok(rep) => {
                    self.status = format!("diagnosis: {}", rep.verdict);
                    self.diag.report = Some(rep);
                }
                Err(e) => self.diag.error = Some(e),
            }
        }
    }

    /// Waits for a running diagnosis (tests).
    #[cfg(test)]
    pub fn wait_diagnosis(&mut self) {
        while self.diag.job.is_some() {
            self.poll_diagnosis();
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
    }

    /// "Apply to model": the preset takes the fitted effects; the user saves as usual.
    pub fn apply_diagnosis(&mut self) {
        let Some(fitted) = self.diag.report.as_ref().and_then(|r| r.fitted.clone()) else {
            return;
        };
        let added = self
            .diag
            .report
            .as_ref()
            .map(|r| r.selected.join(" + "))
            .unwrap_or_default();
        let applied = self.live.lock().machine.apply_params(&fitted);
        self.preset = fitted;
        self.fields.clear();
        if applied.is_err() {
            self.reset();
        }
        self.status = format!("applied to the model: {added} (save the preset to keep it)");
    }
}

fn regime_color(r: Regime) -> egui::Color32 {
    let c = match r {
        Regime::ReversalPosToNeg => (220, 60, 60),
        Regime::ReversalNegToPos => (60, 90, 220),
        Regime::Acceleration => (230, 160, 40),
        Regime::Deceleration => (150, 80, 200),
        Regime::ConstantFeed => (60, 170, 90),
        Regime::Standstill => (128, 128, 128),
    };
    egui::Color32::from_rgba_unmultiplied(c.0, c.1, c.2, 40)
}

pub fn diagnose_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    wb.poll_diagnosis();
    // Measured before the tables, which may ask for more width than the panel has.
    let full_w = ui.available_width();
    records_ui(wb, ui);
    run_row_ui(wb, ui);
    if let Some(e) = &wb.diag.error {
        ui.colored_label(egui::Color32::from_rgb(200, 40, 40), e);
    }
    let Some(rep) = &wb.diag.report else {
        ui.label("Replays the measured command through this preset and ranks the unmodelled effects that explain the residual.");
        return;
    };
    summary_ui(rep, ui);
    tables_ui(rep, ui, full_w);
    if let Some(s) = &rep.series {
        plots_ui(rep, s, ui, full_w);
    }
}

/// The measured and validation records, and the held-out share.
fn records_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        let l = ui.label("Measured record");
        ui.add(egui::TextEdit::singleline(&mut wb.diag.trace_path).desired_width(320.0))
            .labelled_by(l.id);
        if ui.button("Browse record…").clicked()
            && let Some(p) = rfd::FileDialog::new()
                .add_filter("CSV", &["csv"])
                .pick_file()
        {
            wb.diag.trace_path = p.display().to_string();
        }
    });
    ui.horizontal(|ui| {
        let l = ui.label("Validation record");
        ui.add(egui::TextEdit::singleline(&mut wb.diag.validate_path).desired_width(320.0))
            .labelled_by(l.id);
        if ui.button("Browse validation…").clicked()
            && let Some(p) = rfd::FileDialog::new()
                .add_filter("CSV", &["csv"])
                .pick_file()
        {
            wb.diag.validate_path = p.display().to_string();
        }
        ui.label("held out without one:");
        ui.add(
            egui::DragValue::new(&mut wb.diag.holdout)
                .range(0.1..=0.6)
                .speed(0.01)
                .suffix(" of the record"),
        );
    });
}

/// Run / progress / cancel, and "Apply to model".
fn run_row_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        if let Some(job) = &wb.diag.job {
            let (f, what) = job
                .progress
                .lock()
                .map(|p| p.clone())
                .unwrap_or((0.0, String::new()));
            ui.add(
                egui::ProgressBar::new(f as f32)
                    .desired_width(300.0)
                    .text(format!("{:.0} % {what}", f * 100.0)),
            );
            if ui.button("Cancel").clicked() {
                job.cancel.store(true, Ordering::Relaxed);
            }
            ui.ctx().request_repaint();
        } else if ui.button("Run diagnosis").clicked() {
            wb.start_diagnosis();
        }
        let can_apply = wb
            .diag
            .report
            .as_ref()
            .is_some_and(|r| !r.selected.is_empty());
        if ui
            .add_enabled(can_apply, egui::Button::new("Apply to model"))
            .on_hover_text("Add the selected effects with their fitted parameters to the preset")
            .clicked()
        {
            wb.apply_diagnosis();
        }
    });
}

/// The verdict line.
fn summary_ui(rep: &Report, ui: &mut egui::Ui) {
    ui.separator();
    let c = &rep.calibration;
    ui.label(format!(
        "Calibration (nominal re-fitted first, within ±8 %, the mass ±11 %): {}",
        axisbench::diagnose::calibrate::lines(&c.ratios).join(", ")
    ));
    if let Some(s) = &c.skew {
        ui.colored_label(
            egui::Color32::from_rgb(180, 110, 0),
            format!(
                "Measurement: the {:?} channel is logged {:+.2} samples off its time stamps (realigned before the effects)",
                s.channel, s.samples
            ),
        );
    }
    ui.horizontal(|ui| {
        ui.strong(format!("Verdict: {}", rep.verdict));
        if rep.verdict == "none" {
            ui.label("(no unmodelled effect beyond the calibration)");
        } else {
            ui.label(format!(
                "added: {}   held-out residual {:.2} -> {:.2} um ({:.0} % shrink)",
                rep.selected.join(" + "),
                rep.overall.rms_before,
                rep.overall.rms_after,
                rep.shrink * 100.0
            ));
        }
    });
    for e in rep
        .ranking
        .iter()
        .filter(|e| rep.selected.contains(&e.effect))
    {
        ui.label(format!("{}: {}", e.effect, e.evidence));
        if !e.note.is_empty() {
            ui.label(format!("    {}", e.note));
        }
    }
}

/// The candidate ranking and the per-regime residuals.
fn tables_ui(rep: &Report, ui: &mut egui::Ui, full_w: f32) {
    ui.horizontal_top(|ui| {
        egui::ScrollArea::vertical()
            .id_salt("ranking")
            .max_height(160.0)
            .max_width(0.62 * full_w)
            .show(ui, |ui| {
                egui::Grid::new("ranking_grid")
                    .striped(true)
                    .show(ui, |ui| {
                        ui.strong("effect");
                        ui.strong("shrink");
                        ui.strong("parameters");
                        ui.strong("signature");
                        ui.end_row();
                        for e in &rep.ranking {
                            ui.label(&e.effect);
                            ui.label(format!(
                                "{:.1} %{}",
                                e.shrink * 100.0,
                                if e.significant { " *" } else { "" }
                            ));
                            let p: Vec<String> = e
                                .params
                                .iter()
                                .filter(|(k, _)| !k.starts_with("calibration_"))
                                .map(|(k, v)| format!("{k}={v:.4}"))
                                .collect();
                            ui.label(p.join(" "));
                            let mark = if e.evidence_pass { "yes" } else { "no" };
                            ui.label(mark).on_hover_text(&e.evidence);
                            ui.end_row();
                        }
                    });
            });
        egui::Grid::new("regime_grid").striped(true).show(ui, |ui| {
            ui.strong("regime");
            ui.strong("share");
            ui.strong("rms um");
            ui.strong("after");
            ui.end_row();
            for (g, c) in rep.regimes.iter().zip(&rep.per_regime) {
                ui.label(&g.name);
                ui.label(format!("{:.1} %", g.share * 100.0));
                ui.label(format!("{:.3}", g.rms));
                ui.label(format!("{:.3}", c.rms_after));
                ui.end_row();
            }
        });
    });
}

/// Residual against time (regimes shaded), against position, and per time bin.
fn plots_ui(rep: &Report, s: &axisbench::diagnose::Series, ui: &mut egui::Ui, full_w: f32) {
    let h = ui.available_height();
    // Residual against time, regimes shaded behind it.
    let step = (s.t_s.len() / 4000).max(1);
    let (lo, hi) = s
        .before_um
        .iter()
        .chain(&s.after_um)
        .fold((0.0f64, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
    let w = full_w;
    Plot::new("diag_time")
        .height(h * 0.5)
        .width(w)
        .legend(Legend::default())
        .x_axis_label("t [s]")
        .y_axis_label("residual [um]")
        .show(ui, |pu| {
            let mut i = 0;
            while i < s.regimes.len() {
                let r = s.regimes[i];
                let mut j = i;
                while j + 1 < s.regimes.len() && s.regimes[j + 1] == r {
                    j += 1;
                }
                let (t0, t1) = (s.t_s[i], s.t_s[j]);
                if j > i {
                    pu.polygon(
                        Polygon::new(
                            r.name(),
                            PlotPoints::new(vec![[t0, lo], [t1, lo], [t1, hi], [t0, hi]]),
                        )
                        .fill_color(regime_color(r))
                        .stroke(egui::Stroke::NONE),
                    );
                }
                i = j + 1;
            }
            let pts = |v: &[f64]| -> PlotPoints {
                PlotPoints::new(
                    (0..s.t_s.len())
                        .step_by(step)
                        .map(|k| [s.t_s[k], v[k]])
                        .collect(),
                )
            };
            pu.line(Line::new("nominal", pts(&s.before_um)));
            pu.line(Line::new("with fitted effects", pts(&s.after_um)));
        });
    ui.horizontal(|ui| {
        let w0 = 0.5 * full_w - 6.0;
        Plot::new("diag_pos")
            .height(h * 0.4)
            .width(w0)
            .x_axis_label("position [mm]")
            .y_axis_label("residual [um]")
            .show(ui, |pu| {
                let pts: Vec<[f64; 2]> = (0..s.pos_mm.len())
                    .step_by(step)
                    .map(|k| [s.pos_mm[k], s.before_um[k]])
                    .collect();
                pu.points(Points::new("residual vs position", PlotPoints::new(pts)).radius(1.0));
            });
        let w1 = w0;
        Plot::new("diag_time_bins")
            .height(h * 0.4)
            .width(w1)
            .x_axis_label("t [s]")
            .y_axis_label("rms residual [um]")
            .show(ui, |pu| {
                let bars: Vec<Bar> = rep
                    .time_bins
                    .iter()
                    .map(|b| Bar::new(0.5 * (b.lo + b.hi), b.rms).width(b.hi - b.lo))
                    .collect();
                pu.bar_chart(BarChart::new("rms per time bin", bars));
            });
    });
}
