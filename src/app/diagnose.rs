//! The Diagnose view: pick a measured record (and a validation record), run the
//! sim-to-real diagnosis on a worker thread with a progress bar and Cancel, read where the
//! residual lies, which effect explains it, and apply the fitted effect to the preset.

use super::Workbench;
use super::worker::Computed;
use axisbench::diagnose::{self, Options, Progress, Report, regimes::Regime, replay::Record};
use axisbench::units::{fmt_num, fmt_qty};
use eframe::egui;
use egui_plot::{Bar, BarChart, Legend, Line, Plot, PlotPoints, Points, Polygon};
use std::path::PathBuf;

/// What a result was computed on: the scenario or file and the preset with every edit, so
/// it is never applied to another machine.
#[derive(Clone, Debug, PartialEq)]
pub struct Basis {
    /// The scenario or file name shown in the title.
    pub origin: String,
    /// The preset as RON when the computation started.
    pub preset_ron: String,
}

impl Basis {
    pub fn of(wb: &Workbench) -> Basis {
        Basis {
            origin: wb
                .path
                .as_ref()
                .map_or(wb.origin.clone(), |p| p.display().to_string()),
            preset_ron: wb.preset.to_ron().unwrap_or_default(),
        }
    }

    /// Why a result on this basis may not be applied to the workbench as it is now; None
    /// when it still belongs to it.
    pub fn stale(&self, wb: &Workbench) -> Option<String> {
        let now = Basis::of(wb);
        if now.origin != self.origin {
            return Some(format!(
                "computed on {}, and the workbench now holds {}: run it again to apply",
                self.origin, now.origin
            ));
        }
        if now.preset_ron != self.preset_ron {
            let n = axisbench::Preset::from_ron(&self.preset_ron, "basis")
                .map(|p| p.diff(&wb.preset).len())
                .unwrap_or(0);
            return Some(format!(
                "the preset was edited since it was computed ({n} fields): run it again to apply"
            ));
        }
        None
    }
}

#[derive(Default)]
pub struct DiagState {
    pub trace_path: String,
    pub validate_path: String,
    pub holdout: f64,
    /// The diagnosis: progress (share done, what it does), the report and its basis.
    pub run: Computed<(f64, String), Report>,
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
        let basis = Basis::of(self);
        self.diag.run.start(
            basis,
            (0.0, "reading the records".into()),
            move |progress, cancel| {
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
                    cancel,
                };
                let opts = Options {
                    holdout,
                    ..Options::default()
                };
                diagnose::diagnose(&preset, &main, val.as_ref(), &opts, &prog)
                    .map_err(|e| e.to_string())
            },
        );
    }

    /// Takes a finished job's result.
    fn poll_diagnosis(&mut self) {
        if let Some(rep) = self.diag.run.poll() {
            self.status = format!("diagnosis: {}", rep.summary);
        }
    }

    /// Why the diagnosis on screen cannot be applied now (no result, no effect, or
    /// computed on another preset or before an edit); None when Apply may go ahead.
    pub fn diagnosis_not_applicable(&self) -> Option<String> {
        let rep = self.diag.run.result.as_ref()?;
        if rep.selected.is_empty() || rep.fitted.is_none() {
            return Some("no effect was named: nothing to apply".into());
        }
        self.diag.run.why_not(self)
    }

    /// "Apply to model": the preset takes the fitted effects (only onto the preset they
    /// were fitted on); the previous preset is one Undo away; the user saves as usual.
    pub fn apply_diagnosis(&mut self) {
        if let Some(why) = self.diagnosis_not_applicable() {
            self.status = format!("not applied: {why}");
            return;
        }
        let Some(fitted) = self.diag.run.result.as_ref().and_then(|r| r.fitted.clone()) else {
            return;
        };
        let added = self
            .diag
            .run
            .result
            .as_ref()
            .map(|r| r.selected.join(" + "))
            .unwrap_or_default();
        let n = self.preset.diff(&fitted).len();
        self.replace_preset(fitted, format!("diagnosis: {added}"));
        self.diag.run.applied = true;
        self.status = format!(
            "applied to the model: {added}, {n} fields changed (Undo restores them; save the preset to keep it)"
        );
    }
}

/// A regime's colour, at opacity `alpha`; the legend and the shading use the same one.
fn regime_color(r: Regime, alpha: u8) -> egui::Color32 {
    let c = match r {
        Regime::ReversalPosToNeg => (220, 60, 60),
        Regime::ReversalNegToPos => (60, 90, 220),
        Regime::Acceleration => (230, 160, 40),
        Regime::Deceleration => (150, 80, 200),
        Regime::ConstantFeed => (60, 170, 90),
        Regime::Standstill => (128, 128, 128),
    };
    egui::Color32::from_rgba_unmultiplied(c.0, c.1, c.2, alpha)
}

/// Shading opacity of the regimes behind the residual.
const SHADE_ALPHA: u8 = 60;
/// The residual lines' colours: outside the regime palette, the same on every run.
const NOMINAL_COLOR: egui::Color32 = egui::Color32::from_rgb(235, 235, 235);
const FITTED_COLOR: egui::Color32 = egui::Color32::from_rgb(0, 200, 210);

pub fn diagnose_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    wb.poll_diagnosis();
    // Measured before the tables, which may ask for more width than the panel has.
    let full_w = ui.available_width();
    records_ui(wb, ui);
    run_row_ui(wb, ui);
    if let Some(e) = &wb.diag.run.error {
        ui.colored_label(egui::Color32::from_rgb(200, 40, 40), e);
    }
    let Some(rep) = &wb.diag.run.result else {
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
        if ui.button("Browse record…").clicked() {
            match rfd::FileDialog::new()
                .add_filter("CSV", &["csv"])
                .pick_file()
            {
                Some(p) => wb.diag.trace_path = p.display().to_string(),
                None => wb.status = super::no_dialog("Measured record"),
            }
        }
    });
    ui.horizontal(|ui| {
        let l = ui.label("Validation record");
        ui.add(egui::TextEdit::singleline(&mut wb.diag.validate_path).desired_width(320.0))
            .labelled_by(l.id);
        if ui.button("Browse validation…").clicked() {
            match rfd::FileDialog::new()
                .add_filter("CSV", &["csv"])
                .pick_file()
            {
                Some(p) => wb.diag.validate_path = p.display().to_string(),
                None => wb.status = super::no_dialog("Validation record"),
            }
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
        if let Some(job) = &wb.diag.run.job {
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
                wb.diag.run.cancel();
            }
            ui.ctx().request_repaint();
        } else if ui.button("Run diagnosis").clicked() {
            wb.start_diagnosis();
        }
        let why_not = wb.diagnosis_not_applicable();
        let r = ui
            .add_enabled(
                wb.diag.run.result.is_some() && why_not.is_none(),
                egui::Button::new("Apply to model"),
            )
            .on_hover_text("Add the named effects with their fitted parameters to the preset");
        if r.clicked() {
            wb.apply_diagnosis();
        }
        super::undo_apply_ui(wb, ui);
    });
    if wb.diag.run.result.is_some() {
        match wb.diagnosis_not_applicable() {
            Some(why) => super::apply_off_ui(ui, &why),
            None => apply_diff_ui(wb, ui),
        }
    }
}

/// What Apply will change, field by field.
fn apply_diff_ui(wb: &Workbench, ui: &mut egui::Ui) {
    let Some(fitted) = wb.diag.run.result.as_ref().and_then(|r| r.fitted.as_ref()) else {
        return;
    };
    let diff = wb.preset.diff(fitted);
    egui::CollapsingHeader::new(format!("Apply will change {} fields", diff.len()))
        .id_salt("apply-diff")
        .show(ui, |ui| {
            egui::Grid::new("apply-diff-grid")
                .striped(true)
                .show(ui, |ui| {
                    ui.strong("field");
                    ui.strong("now");
                    ui.strong("after Apply");
                    ui.end_row();
                    for c in &diff {
                        ui.label(&c.path);
                        ui.label(&c.before);
                        ui.label(&c.after);
                        ui.end_row();
                    }
                });
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
    ui.strong(&rep.summary);
    ui.label(
        egui::RichText::new(format!(
            "shrink (here, in the ranking and in the JSON): of {}",
            rep.shrink_of
        ))
        .small(),
    );
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
                        ui.strong("held-out shrink");
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
                                .map(|(k, v)| format!("{k} = {}", fmt_num(*v)))
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
            ui.strong("share of Σr² (nominal)");
            ui.strong("RMS nominal");
            ui.strong("RMS with effects");
            ui.strong("share left");
            ui.end_row();
            for (g, c) in rep.regimes.iter().zip(&rep.per_regime) {
                let color = Regime::ALL
                    .iter()
                    .find(|r| r.name() == g.name)
                    .map_or(ui.visuals().text_color(), |r| regime_color(*r, 255));
                ui.colored_label(color, g.name.replace('_', " "));
                ui.label(format!("{:.1} %", g.share * 100.0));
                ui.label(fmt_qty(g.rms, "um"));
                ui.label(fmt_qty(c.rms_after, "um"));
                ui.label(format!("{:.1} %", c.share_after * 100.0));
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
        .y_axis_label("residual [µm]")
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
                            r.name().replace('_', " "),
                            PlotPoints::new(vec![[t0, lo], [t1, lo], [t1, hi], [t0, hi]]),
                        )
                        .fill_color(regime_color(r, SHADE_ALPHA))
                        // No outline; its colour is what the legend shows.
                        .stroke(egui::Stroke::new(0.0, regime_color(r, SHADE_ALPHA))),
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
            pu.line(Line::new("nominal", pts(&s.before_um)).color(NOMINAL_COLOR));
            pu.line(Line::new("with fitted effects", pts(&s.after_um)).color(FITTED_COLOR));
        });
    ui.horizontal(|ui| {
        let w0 = 0.5 * full_w - 6.0;
        Plot::new("diag_pos")
            .height(h * 0.4)
            .width(w0)
            .x_axis_label("position [mm]")
            .y_axis_label("residual [µm]")
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
            .y_axis_label("RMS residual [µm]")
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
