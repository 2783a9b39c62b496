//! The time plots as an instrument: one unit per plot, y tick labels and units on every
//! axis, fixed colours per signal, each signal shown or hidden and any one of them the
//! plot's y scale, two cursors with Δt/Δy, and a whole-run view beside the rolling window.
//!
//! A plot is a *unit group*: every signal in it shares its unit, so a torque never shares an
//! axis with a force in another unit. Which signals exist comes from the running machine's
//! trace; what each one is, its unit and its colour come from [`SIGNALS`], one table.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use eframe::egui;
use egui_plot::{GridInput, GridMark, Line, Plot, PlotPoints, VLine};

use axisbench::trace::{AxisSignal as S, display_unit_of};
use axisbench::units::{fmt_num, fmt_qty, m_per_s_to_mm_per_s, m_to_mm, m_to_um, symbol};

use super::Workbench;
use super::live::{History, Ring};
use super::plots::{Show, decimate, partition};

/// What a time plot can show of one signal: its key (the trace column after `axis.`), its
/// legend label, the plot (unit group) it belongs to, SI → shown unit, and its colour.
pub struct SigDef {
    pub key: &'static str,
    pub label: &'static str,
    pub plot: &'static str,
    pub unit: &'static str,
    pub show: Show,
    pub color: (u8, u8, u8),
}

fn si(v: f64) -> f64 {
    v
}

/// Every signal the time plots know, in plot order. The quadrant feed-forward is added by
/// [`plot_defs`] in the unit of what it injects.
pub const SIGNALS: &[SigDef] = &[
    SigDef {
        key: "err",
        label: "error cmd − pos",
        plot: "position error",
        unit: "um",
        show: m_to_um,
        color: (230, 80, 80),
    },
    SigDef {
        key: "ferr",
        label: "following error",
        plot: "position error",
        unit: "um",
        show: m_to_um,
        color: (90, 150, 240),
    },
    SigDef {
        key: "torque_cmd",
        label: "torque command",
        plot: "torque",
        unit: "N*m",
        show: si,
        color: (240, 150, 40),
    },
    SigDef {
        key: "torque",
        label: "torque",
        plot: "torque",
        unit: "N*m",
        show: si,
        color: (60, 190, 190),
    },
    SigDef {
        key: "friction",
        label: "friction force",
        plot: "friction force",
        unit: "N",
        show: si,
        color: (170, 200, 60),
    },
    SigDef {
        key: "backlash_comp",
        label: "backlash",
        plot: "compensation outputs",
        unit: "um",
        show: m_to_um,
        color: (230, 80, 80),
    },
    SigDef {
        key: "thermal_comp",
        label: "thermal F' at x",
        plot: "compensation outputs",
        unit: "um",
        show: m_to_um,
        color: (240, 150, 40),
    },
    SigDef {
        key: "thermal_f",
        label: "thermal F",
        plot: "compensation outputs",
        unit: "um",
        show: m_to_um,
        color: (200, 120, 230),
    },
    SigDef {
        key: "cross_comp",
        label: "cross ΔZ",
        plot: "compensation outputs",
        unit: "um",
        show: m_to_um,
        color: (90, 150, 240),
    },
    SigDef {
        key: "thermal_e",
        label: "E",
        plot: "thermal ratio E",
        unit: "",
        show: si,
        color: (240, 150, 40),
    },
    SigDef {
        key: "thermal_e_ref",
        label: "E_ref",
        plot: "thermal ratio E",
        unit: "",
        show: si,
        color: (60, 190, 190),
    },
    SigDef {
        key: "thermal_band_hi",
        label: "E_ref + Em",
        plot: "thermal ratio E",
        unit: "",
        show: si,
        color: (150, 150, 150),
    },
    SigDef {
        key: "thermal_band_lo",
        label: "E_ref − Em",
        plot: "thermal ratio E",
        unit: "",
        show: si,
        color: (110, 110, 110),
    },
    SigDef {
        key: "pos",
        label: "position",
        plot: "position",
        unit: "mm",
        show: m_to_mm,
        color: (230, 80, 80),
    },
    SigDef {
        key: "vel",
        label: "velocity",
        plot: "velocity",
        unit: "mm/s",
        show: m_per_s_to_mm_per_s,
        color: (90, 150, 240),
    },
];

/// Signals hidden until the user shows them (the plots a first look does not need).
pub const HIDDEN_AT_START: &[&str] = &["friction", "pos"];

/// The quadrant feed-forward's colour.
const TFF_COLOR: (u8, u8, u8) = (200, 120, 230);

/// How the time plots are set up: what is hidden, which signal sets a plot's y scale, the
/// cursors, and whether the whole run is shown.
pub struct ScopeView {
    /// Signal keys not drawn.
    pub hidden: BTreeSet<String>,
    /// Per plot title: the one signal whose range sets the y axis (None: all of them).
    pub scale_alone: BTreeMap<String, String>,
    /// Cursor A and B, s.
    pub cursors: [Option<f64>; 2],
    /// Show the whole run (decimated history) instead of the rolling window.
    pub whole_run: bool,
}

impl Default for ScopeView {
    fn default() -> Self {
        ScopeView {
            hidden: HIDDEN_AT_START.iter().map(|s| (*s).to_owned()).collect(),
            scale_alone: BTreeMap::new(),
            cursors: [None, None],
            whole_run: false,
        }
    }
}

/// One line of a plot as drawn: key, label, trace column, SI → shown, colour.
pub struct LineDef {
    pub key: String,
    pub label: String,
    pub col: String,
    pub show: Show,
    pub color: egui::Color32,
}

/// One plot: its title, its unit (as written in presets), its lines.
pub struct PlotDef {
    pub title: String,
    pub unit: String,
    pub lines: Vec<LineDef>,
}

fn color((r, g, b): (u8, u8, u8)) -> egui::Color32 {
    egui::Color32::from_rgb(r, g, b)
}

/// The plots of axis `a`: every signal of [`SIGNALS`] the ring holds, grouped by plot, and
/// the quadrant feed-forward in the plot of its unit (a torque with the torques).
pub fn plot_defs(a: &str, ring: &Ring) -> Vec<PlotDef> {
    let mut plots: Vec<PlotDef> = vec![];
    let mut push = |title: &str, unit: &str, line: LineDef| match plots
        .iter_mut()
        .find(|p| p.title == title)
    {
        Some(p) => p.lines.push(line),
        None => plots.push(PlotDef {
            title: title.to_owned(),
            unit: unit.to_owned(),
            lines: vec![line],
        }),
    };
    for d in SIGNALS {
        let col = format!("{a}.{}", d.key);
        if ring.col(&col).is_none() {
            continue;
        }
        push(
            d.plot,
            d.unit,
            LineDef {
                key: d.key.to_owned(),
                label: d.label.to_owned(),
                col,
                show: d.show,
                color: color(d.color),
            },
        );
        // The quadrant feed-forward goes in the plot of the unit it injects.
        if d.key == "torque" || d.key == "vel" || d.key == "pos" {
            let q = S::QuadrantComp.column(a);
            if let Some(u) = ring.col(&q).and_then(|_| display_unit_of(ring.unit(&q)))
                && u.name == d.unit
            {
                push(
                    d.plot,
                    d.unit,
                    LineDef {
                        key: "quadrant_comp".to_owned(),
                        label: "quadrant feed-forward".to_owned(),
                        col: q,
                        show: u.from_si,
                        color: color(TFF_COLOR),
                    },
                );
            }
        }
    }
    plots
}

/// Closest grid lines are allowed to come, px (the plot's `grid_spacing` minimum, which
/// egui_plot hands the spacer as `base_step_size` in data units).
const GRID_MIN_PX: f32 = 8.0;
/// Labelled grid lines are at least this far apart, px: a line of text and a gap, so a
/// 60 px plot still carries three labels (the y axis is told to draw labels this close).
const LABEL_PX: f64 = 22.0;
/// Closest two labels may come when a plot would otherwise carry only one, px.
const MIN_LABEL_PX: f64 = 14.0;

/// The smallest 1-2-5 step at least `x`.
pub fn nice_step_at_least(x: f64) -> f64 {
    let p = 10f64.powf(x.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * p)
        .find(|s| *s >= x * (1.0 - 1e-9))
        .unwrap_or(10.0 * p)
}

/// Grid steps for an x axis: about four labelled 1-2-5 steps across the plot (x labels
/// are wide, so [`nice_grid`]'s spacing, set by the text's height, is too close for them).
pub fn x_grid(input: GridInput) -> Vec<GridMark> {
    let (lo, hi) = input.bounds;
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![];
    }
    let major = nice_step_at_least((hi - lo) / 5.0);
    egui_plot::uniform_grid_spacer(move |_| [major / 5.0, major, major * 10.0])(input)
}

/// Labelled grid lines at the smallest 1-2-5 step [`LABEL_PX`] apart, and unlabelled ones
/// between them. The default spacer (powers of ten only) leaves a short plot with a single
/// labelled line, often just "0".
pub fn nice_grid(input: GridInput) -> Vec<GridMark> {
    let (lo, hi) = input.bounds;
    let base = input.base_step_size.abs();
    if !(lo.is_finite() && hi.is_finite() && base.is_finite()) || base <= 0.0 || hi <= lo {
        return vec![];
    }
    let px_per_unit = f64::from(GRID_MIN_PX) / base;
    let mut major = nice_step_at_least(LABEL_PX / px_per_unit);
    // At least two labels, even on a short plot: the next finer 1-2-5 step while fewer
    // than two land inside (down to one text height, [`MIN_LABEL_PX`]).
    let majors_in = |m: f64| ((hi / m).floor() - (lo / m).ceil() + 1.0).max(0.0);
    while majors_in(major) < 2.0 {
        let finer = nice_step_at_least(major * 0.45);
        if finer >= major || finer * px_per_unit < MIN_LABEL_PX {
            break;
        }
        major = finer;
    }
    let mantissa = major / 10f64.powf(major.log10().floor());
    let minor = if (mantissa - 2.0).abs() < 1e-6 {
        major / 2.0
    } else {
        major / 5.0
    };
    let n = ((hi - lo) / minor).ceil();
    if !(0.0..=2000.0).contains(&n) {
        return vec![];
    }
    let first = (lo / minor).floor() as i64;
    (0..=(n as i64 + 1))
        .map(|i| {
            let v = (first + i) as f64 * minor;
            let on_major = ((v / major).round() * major - v).abs() < minor * 1e-6;
            GridMark {
                value: if on_major {
                    (v / major).round() * major
                } else {
                    v
                },
                step_size: if on_major { major } else { minor },
            }
        })
        // egui_plot draws a label for every mark it gets, inside the plot or not.
        .filter(|m| m.value >= lo && m.value <= hi)
        .collect()
}

/// A y axis's tick label: the value at four significant digits.
fn tick(mark: GridMark, _range: &std::ops::RangeInclusive<f64>) -> String {
    fmt_num(mark.value)
}

/// The value of ring column `col` at time `t` (the sample nearest it).
fn value_at(t: &VecDeque<f64>, col: &VecDeque<f64>, t_s: f64) -> Option<f64> {
    let n = t.len().min(col.len());
    if n == 0 || t_s < t[0] || t_s > t[n - 1] {
        return None;
    }
    let i = partition(t, t_s).min(n - 1);
    let j = if i > 0 && (t_s - t[i - 1]).abs() < (t[i] - t_s).abs() {
        i - 1
    } else {
        i
    };
    Some(col[j])
}

/// The series of one plot: (line, points) over [t0, t1], from the ring or the history.
type Series = Vec<(LineDef, Vec<[f64; 2]>)>;

fn series(
    ring: &Ring,
    hist: &History,
    def: PlotDef,
    range: (f64, f64),
    width_px: usize,
    whole: bool,
) -> (String, String, Series) {
    let empty = VecDeque::new();
    let t = ring.cols.first().unwrap_or(&empty);
    let lines = def
        .lines
        .into_iter()
        .filter_map(|l| {
            let pts = if whole {
                hist.points(ring.index(&l.col)?, width_px, l.show)
            } else {
                decimate(t, ring.col(&l.col)?, range.0, range.1, width_px, l.show)
            };
            Some((l, pts))
        })
        .collect();
    (def.title, def.unit, lines)
}

/// The time plots of the selected axis, the cursor read-out, and a loaded trace overlaid.
pub fn time_plots_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    let axis = wb.axis_name();
    let width_px = ui.available_width().max(100.0) as usize;
    let (running, empty_run, plots, readout) = {
        let s = wb.live.lock();
        let ring = &s.ring;
        let t1 = ring.t_last();
        let range = if wb.scope.whole_run {
            (0.0, t1)
        } else {
            (t1 - wb.window_s, t1)
        };
        let plots: Vec<_> = plot_defs(&axis, ring)
            .into_iter()
            .map(|d| series(ring, &s.history, d, range, width_px, wb.scope.whole_run))
            .collect();
        let readout = cursor_readout(&wb.scope, ring, &s.history, &axis);
        (s.running, ring.is_empty(), plots, readout)
    };
    top_row_ui(wb, ui, running);
    if empty_run && !running {
        ui.add_space(8.0);
        ui.label(
            egui::RichText::new(
                "Press Run (left) to start the model: the plots fill as it runs. Step runs one T2 period.",
            )
            .heading(),
        );
    }
    let overlay = wb.loaded_trace.as_ref().map(|(_, t)| t.clone());
    let shown: usize = plots
        .iter()
        .filter(|(_, _, ls)| ls.iter().any(|(l, _)| !wb.scope.hidden.contains(&l.key)))
        .count()
        .max(1);
    let readout_h = if readout.is_empty() { 0.0 } else { 90.0 };
    let headers_h = 26.0 * plots.len() as f32;
    let h = ((ui.available_height() - headers_h - readout_h - 10.0) / shown as f32).max(70.0);
    let group = egui::Id::unique("time-plots");
    egui::ScrollArea::vertical()
        .id_salt("time-plots-scroll")
        .show(ui, |ui| {
            for (title, unit, lines) in plots {
                plot_header_ui(wb, ui, &title, &unit, &lines);
                if !lines.iter().any(|(l, _)| !wb.scope.hidden.contains(&l.key)) {
                    continue;
                }
                let extra = overlay
                    .as_ref()
                    .and_then(|tr| super::plots::overlay_line(tr, &axis, &title));
                plot_ui(wb, ui, &title, &unit, lines, extra, h, group, running);
            }
            readout_ui(wb, ui, &readout);
        });
}

/// Whole run / window, the overlay, cursor help.
fn top_row_ui(wb: &mut Workbench, ui: &mut egui::Ui, running: bool) {
    ui.horizontal_wrapped(|ui| {
        ui.checkbox(&mut wb.scope.whole_run, "Whole run")
            .on_hover_text("the whole run as a min/max history, beside the rolling window");
        if let Some((n, _)) = &wb.loaded_trace {
            ui.label(format!("overlay: {n}"));
            if ui.button("Close trace").clicked() {
                wb.loaded_trace = None;
            }
        }
        ui.label(if running {
            "following the live model · click: cursor A, right-click: cursor B"
        } else {
            "paused: drag to pan, scroll to zoom, hover for values · click: cursor A, right-click: cursor B"
        });
        if wb.scope.cursors.iter().any(Option::is_some) && ui.button("Clear cursors").clicked() {
            wb.scope.cursors = [None, None];
        }
    });
}

/// A plot's title and unit, a checkbox per signal in its colour, the y-scale choice and
/// the PNG export.
fn plot_header_ui(
    wb: &mut Workbench,
    ui: &mut egui::Ui,
    title: &str,
    unit: &str,
    lines: &[(LineDef, Vec<[f64; 2]>)],
) {
    ui.horizontal(|ui| {
        let unit_txt = if unit.is_empty() {
            "[-]".to_owned()
        } else {
            format!("[{}]", symbol(unit))
        };
        ui.label(egui::RichText::new(format!("{title} {unit_txt}")).strong());
        for (l, _) in lines {
            let mut on = !wb.scope.hidden.contains(&l.key);
            if ui
                .checkbox(&mut on, egui::RichText::new(&l.label).color(l.color))
                .changed()
            {
                if on {
                    wb.scope.hidden.remove(&l.key);
                } else {
                    wb.scope.hidden.insert(l.key.clone());
                }
            }
        }
        if lines.len() > 1 {
            let cur = wb.scope.scale_alone.get(title).cloned();
            let label = cur
                .as_ref()
                .and_then(|k| lines.iter().find(|(l, _)| l.key == *k))
                .map_or("all signals".to_owned(), |(l, _)| l.label.clone());
            let mut pick: Option<Option<String>> = None;
            egui::ComboBox::new(format!("scale-{title}"), "y scale")
                .selected_text(label)
                .show_ui(ui, |ui| {
                    if ui.selectable_label(cur.is_none(), "all signals").clicked() {
                        pick = Some(None);
                    }
                    for (l, _) in lines {
                        if ui
                            .selectable_label(cur.as_deref() == Some(&l.key), &l.label)
                            .clicked()
                        {
                            pick = Some(Some(l.key.clone()));
                        }
                    }
                });
            match pick {
                Some(Some(k)) => {
                    wb.scope.scale_alone.insert(title.to_owned(), k);
                }
                Some(None) => {
                    wb.scope.scale_alone.remove(title);
                }
                None => {}
            }
        }
        if ui
            .small_button("PNG")
            .on_hover_text("export this plot to PNG")
            .clicked()
        {
            let path =
                std::path::PathBuf::from(format!("axisbench-{}.png", title.replace(' ', "-")));
            wb.export_plot(ui.ctx(), title, path);
        }
    });
}

/// The y range of `pts` with a margin, for a plot scaled to one signal.
fn y_range(pts: &[[f64; 2]]) -> Option<(f64, f64)> {
    let (lo, hi) = pts
        .iter()
        .map(|p| p[1])
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !lo.is_finite() {
        return None;
    }
    let pad = ((hi - lo) * 0.05)
        .max(hi.abs().max(lo.abs()) * 1e-6)
        .max(1e-12);
    Some((lo - pad, hi + pad))
}

#[allow(clippy::too_many_arguments)]
fn plot_ui(
    wb: &mut Workbench,
    ui: &mut egui::Ui,
    title: &str,
    unit: &str,
    lines: Series,
    overlay: Option<(String, Vec<[f64; 2]>)>,
    h: f32,
    group: egui::Id,
    running: bool,
) {
    let alone = wb.scope.scale_alone.get(title).and_then(|k| {
        lines
            .iter()
            .find(|(l, _)| l.key == *k && !wb.scope.hidden.contains(&l.key))
            .and_then(|(_, p)| y_range(p))
    });
    let unit_sym = symbol(unit);
    let hover_unit = unit.to_owned();
    let mut plot = Plot::new(title)
        .height(h)
        .link_axis(group, [true, false])
        .link_cursor(group, [true, false])
        .x_axis_label("t [s]")
        .custom_y_axes(vec![
            egui_plot::AxisHints::new_y()
                .label(if unit_sym.is_empty() {
                    "[-]".to_owned()
                } else {
                    format!("[{unit_sym}]")
                })
                .formatter(tick)
                .min_thickness(52.0)
                .label_spacing(egui::Rangef::new(
                    MIN_LABEL_PX as f32 - 1.0,
                    MIN_LABEL_PX as f32,
                )),
        ])
        .grid_spacing(egui::Rangef::new(GRID_MIN_PX, 60.0))
        .y_grid_spacer(nice_grid)
        .label_formatter(move |hp| {
            Some(match hp {
                egui_plot::HoverPosition::NearDataPoint {
                    plot_name,
                    position,
                    ..
                } => format!(
                    "{plot_name}\nt = {}\n{}",
                    fmt_qty(position.x, "s"),
                    fmt_qty(position.y, &hover_unit)
                ),
                egui_plot::HoverPosition::Elsewhere { position } => format!(
                    "t = {}\n{}",
                    fmt_qty(position.x, "s"),
                    fmt_qty(position.y, &hover_unit)
                ),
            })
        });
    if running || wb.scope.whole_run {
        plot = plot.auto_bounds([true, alone.is_none()]);
    }
    let cursors = wb.scope.cursors;
    let resp = plot.show(ui, |pu| {
        for (l, pts) in lines {
            if wb.scope.hidden.contains(&l.key) {
                continue;
            }
            pu.line(Line::new(l.label, PlotPoints::from(pts)).color(l.color));
        }
        if let Some((label, pts)) = overlay {
            pu.line(Line::new(label, PlotPoints::from(pts)).color(egui::Color32::from_gray(200)));
        }
        for (i, c) in cursors.iter().enumerate() {
            if let Some(t) = c {
                pu.vline(
                    VLine::new(["cursor A", "cursor B"][i], *t)
                        .color(egui::Color32::from_rgb(250, 220, 80))
                        .style(egui_plot::LineStyle::dashed_loose()),
                );
            }
        }
        if let Some((lo, hi)) = alone {
            let b = pu.plot_bounds();
            pu.set_plot_bounds_x(b.min()[0]..=b.max()[0]);
            pu.set_plot_bounds_y(lo..=hi);
        }
        pu.pointer_coordinate()
    });
    let r = &resp.response;
    if let Some(p) = resp.inner {
        if r.clicked() {
            wb.scope.cursors[0] = Some(p.x);
        } else if r.secondary_clicked() {
            wb.scope.cursors[1] = Some(p.x);
        }
    }
    wb.plot_rects_insert(title, r.rect);
}

/// One read-out row: label, unit, value at A, at B.
pub type ReadoutRow = (String, String, Option<f64>, Option<f64>);

/// The values of every shown signal at the cursors.
fn cursor_readout(view: &ScopeView, ring: &Ring, hist: &History, axis: &str) -> Vec<ReadoutRow> {
    if view.cursors.iter().all(Option::is_none) {
        return vec![];
    }
    let empty = VecDeque::new();
    let t = ring.cols.first().unwrap_or(&empty);
    let at = |col: &str, show: Show, c: Option<f64>| -> Option<f64> {
        let tc = c?;
        let v = match ring.col(col).and_then(|cv| value_at(t, cv, tc)) {
            Some(v) => Some(v),
            None => hist.value_at(ring.index(col)?, tc),
        }?;
        Some(show(v))
    };
    plot_defs(axis, ring)
        .into_iter()
        .flat_map(|p| {
            let unit = p.unit.clone();
            p.lines.into_iter().map(move |l| (l, unit.clone()))
        })
        .filter(|(l, _)| !view.hidden.contains(&l.key))
        .map(|(l, unit)| {
            (
                l.label.clone(),
                unit,
                at(&l.col, l.show, view.cursors[0]),
                at(&l.col, l.show, view.cursors[1]),
            )
        })
        .collect()
}

/// The cursor table: t at A and B and Δt, then each shown signal at A, at B and Δ.
fn readout_ui(wb: &Workbench, ui: &mut egui::Ui, rows: &[ReadoutRow]) {
    if rows.is_empty() {
        return;
    }
    let [a, b] = wb.scope.cursors;
    let opt = |v: Option<f64>, unit: &str| v.map_or("—".to_owned(), |v| fmt_qty(v, unit));
    egui::Grid::new("cursor-readout")
        .striped(true)
        .show(ui, |ui| {
            ui.strong("cursors");
            ui.strong("A");
            ui.strong("B");
            ui.strong("Δ (B − A)");
            ui.end_row();
            ui.label("t");
            ui.label(opt(a, "s"));
            ui.label(opt(b, "s"));
            ui.label(match (a, b) {
                (Some(a), Some(b)) if b != a => format!(
                    "Δt = {} (1/Δt = {})",
                    fmt_qty(b - a, "s"),
                    fmt_qty(1.0 / (b - a).abs(), "Hz")
                ),
                _ => "—".to_owned(),
            });
            ui.end_row();
            for (label, unit, va, vb) in rows {
                ui.label(label);
                ui.label(opt(*va, unit));
                ui.label(opt(*vb, unit));
                ui.label(match (va, vb) {
                    (Some(x), Some(y)) => format!("Δ = {}", fmt_qty(y - x, unit)),
                    _ => "—".to_owned(),
                });
                ui.end_row();
            }
        });
}
