//! The Tune view: the compensation searched on the simulated machine (`axisbench::tune`) on
//! a worker thread, with progress and Cancel, the objective against the evaluation count,
//! the before/after table per reversal, the error before and after overlaid, and Apply
//! (one Undo away) onto the preset the tune ran on only.

use eframe::egui;
use egui_plot::{Legend, Line, Plot, PlotPoints};

use axisbench::trace::AxisSignal;
use axisbench::tune::{self, Job, Outcome, Progress, Weights, What};
use axisbench::units::{fmt_num, fmt_qty, m_to_um};
use axisbench::{Machine, Preset};

use super::Workbench;
use super::diagnose::Basis;
use super::scope::{nice_grid, x_grid};
use super::worker::Computed;

/// A finished tune, with the error of both runs for the overlay: (t s, before µm, after µm).
pub struct TuneResult {
    pub outcome: Outcome,
    pub err_um: Vec<[f64; 3]>,
}

pub struct TuneState {
    pub backlash: bool,
    pub quadrant: bool,
    pub weights: Weights,
    /// The tune: progress, the result and its basis.
    pub run: Computed<Option<tune::Status>, TuneResult>,
}

impl Default for TuneState {
    fn default() -> Self {
        TuneState {
            backlash: true,
            quadrant: true,
            weights: Weights::default(),
            run: Computed::default(),
        }
    }
}

/// The error of one run on `axis`, µm, with its time stamps.
fn err_series(p: &Preset, programs: &[(String, String)], axis: &str) -> (Vec<f64>, Vec<f64>) {
    let Ok(mut m) = Machine::new(p, programs) else {
        return (vec![], vec![]);
    };
    if m.run(4.0 * 3600.0).is_err() {
        return (vec![], vec![]);
    }
    let t = m.trace.t().to_vec();
    let e = m
        .trace
        .axis_values(axis, AxisSignal::Err)
        .map(|v| v.iter().map(|x| m_to_um(*x)).collect())
        .unwrap_or_default();
    (t, e)
}

impl Workbench {
    /// What the checkboxes ask for.
    fn tune_what(&self) -> Vec<What> {
        let mut w = vec![];
        if self.tune.backlash {
            w.push(What::Backlash);
        }
        if self.tune.quadrant {
            w.push(What::Quadrant);
        }
        w
    }

    /// Starts a tune of the selected axis with the current preset and program.
    pub fn start_tune(&mut self) {
        let what = self.tune_what();
        if what.is_empty() {
            self.tune.run.error = Some("tick at least one of backlash, quadrant".into());
            return;
        }
        let preset = self.preset.clone();
        let programs = self.programs.clone();
        let axis = self.axis_name();
        let weights = self.tune.weights;
        let basis = Basis::of(self);
        self.tune.run.start(basis, None, move |progress, cancel| {
            let report = |st: tune::Status| {
                if let Ok(mut p) = progress.lock() {
                    *p = Some(st);
                }
            };
            let job = Job {
                preset: &preset,
                programs: &programs,
                axis: axis.clone(),
                what,
                weights,
                seed: 1,
                max_iters: 80,
                threads: 0,
            };
            let outcome = tune::tune(
                &job,
                &Progress {
                    report: &report,
                    cancel,
                },
            )
            .map_err(|e| e.to_string())?;
            let (t, before) = err_series(&preset, &programs, &axis);
            let (_, after) = err_series(&outcome.preset, &programs, &axis);
            let err_um = t
                .iter()
                .zip(before.iter().zip(&after))
                .map(|(t, (b, a))| [*t, *b, *a])
                .collect();
            Ok(TuneResult { outcome, err_um })
        });
    }

    /// Takes a finished tune's result.
    fn poll_tune(&mut self) {
        if let Some(r) = self.tune.run.poll() {
            self.status = format!(
                "tune: objective {} -> {} in {} simulations",
                fmt_num(r.outcome.before.objective),
                fmt_num(r.outcome.after.objective),
                r.outcome.simulations
            );
        }
    }

    /// Why the tune on screen cannot be applied now; None when Apply may go ahead.
    pub fn tune_not_applicable(&self) -> Option<String> {
        let r = self.tune.run.result.as_ref()?;
        if r.outcome.kept_start {
            return Some("nothing beat the values in force: nothing to apply".into());
        }
        self.tune.run.why_not(self)
    }

    /// Apply: the preset takes the tuned values; the previous preset is one Undo away.
    pub fn apply_tune(&mut self) {
        if let Some(why) = self.tune_not_applicable() {
            self.status = format!("not applied: {why}");
            return;
        }
        let Some(p) = self
            .tune
            .run
            .result
            .as_ref()
            .map(|r| r.outcome.preset.clone())
        else {
            return;
        };
        let n = self.preset.diff(&p).len();
        self.replace_preset(p, "tune".into());
        self.tune.run.applied = true;
        self.status = format!(
            "tuned values applied, {n} fields changed (Undo restores them; save the preset to keep it)"
        );
    }
}

pub fn tune_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    wb.poll_tune();
    ui.label(format!(
        "Searches the compensation of axis {} on the simulated machine for the smallest error change at the program's reversals (as A/B compare and `simulate` report them). Never returns values worse than those in force.",
        wb.axis_name()
    ));
    settings_ui(wb, ui);
    run_row_ui(wb, ui);
    if let Some(e) = &wb.tune.run.error {
        ui.colored_label(egui::Color32::from_rgb(230, 80, 80), e);
    }
    if let Some(r) = &wb.tune.run.result {
        result_ui(r, ui);
    }
}

fn settings_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        ui.label("Tune:");
        ui.checkbox(&mut wb.tune.backlash, "backlash (Q, modes, N, B, M)");
        ui.checkbox(&mut wb.tune.quadrant, "quadrant (M0, T0, A, B, C, D, P0)");
    });
    ui.horizontal(|ui| {
        ui.label("Objective weights per µm:");
        for (label, v) in [
            ("peak change", &mut wb.tune.weights.peak),
            ("settled change", &mut wb.tune.weights.settled),
            ("RMS error", &mut wb.tune.weights.rms),
        ] {
            let l = ui.label(label);
            ui.add(egui::DragValue::new(v).range(0.0..=10.0).speed(0.05))
                .labelled_by(l.id);
        }
    });
}

fn run_row_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        if let Some(job) = &wb.tune.run.job {
            let st = job.progress.lock().ok().and_then(|p| *p);
            let share = st.and_then(|s| s.share_done()).unwrap_or(0.0);
            ui.add(
                egui::ProgressBar::new(share as f32)
                    .desired_width(160.0)
                    .show_percentage(),
            );
            let (n, f) = st.map_or((0, f64::NAN), |s| (s.simulations, s.best));
            ui.label(format!(
                "{n} simulations, best objective {}",
                if f.is_finite() {
                    fmt_num(f)
                } else {
                    "—".into()
                }
            ));
            if ui.button("Cancel tune").clicked() {
                wb.tune.run.cancel();
            }
            ui.ctx().request_repaint();
        } else if ui.button("Run tune").clicked() {
            wb.start_tune();
        }
        let why_not = wb.tune_not_applicable();
        if ui
            .add_enabled(
                wb.tune.run.result.is_some() && why_not.is_none(),
                egui::Button::new("Apply tuned values"),
            )
            .clicked()
        {
            wb.apply_tune();
        }
        super::undo_apply_ui(wb, ui);
    });
    if let (Some(_), Some(why)) = (&wb.tune.run.result, wb.tune_not_applicable()) {
        super::apply_off_ui(ui, &why);
    }
}

fn result_ui(r: &TuneResult, ui: &mut egui::Ui) {
    let o = &r.outcome;
    ui.separator();
    ui.strong(format!(
        "objective {} -> {}{} · {} simulations in {} ({} per s)",
        fmt_num(o.before.objective),
        fmt_num(o.after.objective),
        if o.kept_start {
            " (nothing beat the values in force: kept)"
        } else {
            ""
        },
        o.simulations,
        fmt_qty(o.wall_s, "s"),
        fmt_num(o.simulations_per_s)
    ));
    ui.horizontal_top(|ui| {
        reversal_table_ui(o, ui);
        egui::Grid::new("tune-values").striped(true).show(ui, |ui| {
            ui.strong("tuned value");
            ui.strong("");
            ui.end_row();
            for (k, v) in &o.values {
                ui.label(k);
                ui.label(axisbench::units::fmt_sig(*v, 6));
                ui.end_row();
            }
        });
    });
    let h = (ui.available_height() * 0.5).max(120.0);
    ui.horizontal(|ui| {
        let w = ui.available_width() * 0.35;
        Plot::new("tune-objective")
            .height(h)
            .width(w)
            .x_axis_label("simulations")
            .y_axis_label("best objective [µm]")
            .x_grid_spacer(x_grid)
            .y_grid_spacer(nice_grid)
            .show(ui, |pu| {
                // A staircase has vertical steps: drawn as a min/max band (egui_plot's
                // default for dense lines) each step would become a wedge.
                pu.line(
                    Line::new("best objective", PlotPoints::from(best_steps(o)))
                        .color(egui::Color32::from_rgb(0, 200, 210))
                        .allow_band(false),
                );
            });
        let step = (r.err_um.len() / 4000).max(1);
        Plot::new("tune-error")
            .height(h)
            .legend(Legend::default())
            .y_grid_spacer(nice_grid)
            .x_axis_label("t [s]")
            .y_axis_label("error cmd − pos [µm]")
            .show(ui, |pu| {
                let before: Vec<[f64; 2]> = r
                    .err_um
                    .iter()
                    .step_by(step)
                    .map(|p| [p[0], p[1]])
                    .collect();
                let after: Vec<[f64; 2]> = r
                    .err_um
                    .iter()
                    .step_by(step)
                    .map(|p| [p[0], p[2]])
                    .collect();
                pu.line(
                    Line::new("before", PlotPoints::from(before))
                        .color(egui::Color32::from_rgb(230, 80, 80)),
                );
                pu.line(
                    Line::new("tuned", PlotPoints::from(after))
                        .color(egui::Color32::from_rgb(0, 200, 210)),
                );
            });
    });
}

/// Peak and settled change per reversal before and after, next to the ideal axis's.
fn reversal_table_ui(o: &Outcome, ui: &mut egui::Ui) {
    egui::Grid::new("tune-reversals")
        .striped(true)
        .show(ui, |ui| {
            for h in Outcome::TABLE_HEADER {
                ui.strong(h);
            }
            ui.end_row();
            for row in o.table() {
                for cell in row {
                    ui.label(cell);
                }
                ui.end_row();
            }
        });
}

/// The best objective as a staircase over the simulation count: it holds until a better
/// point is found. The threads record their improvements in the order they take the lock,
/// so the points are sorted by count first.
fn best_steps(o: &Outcome) -> Vec<[f64; 2]> {
    let mut h = o.history.clone();
    h.sort_by_key(|(n, _)| *n);
    let mut pts: Vec<[f64; 2]> = Vec::with_capacity(2 * h.len() + 1);
    let mut best = f64::INFINITY;
    for (n, f) in h {
        if f < best {
            if let Some(&[_, prev]) = pts.last() {
                pts.push([n as f64, prev]);
            }
            pts.push([n as f64, f]);
            best = f;
        }
    }
    if let Some(&[_, last]) = pts.last() {
        pts.push([o.simulations as f64, last]);
    }
    pts
}
