//! Plots: four linked time plots over a rolling window, the circle test, the sag profile and
//! the A/B overlay. Live data is decimated to a min/max pair per pixel column before it
//! reaches egui_plot, so a full 60 s window at 8 kHz costs the same as a short one.

use eframe::egui;
use std::collections::VecDeque;

use egui_plot::{Legend, Line, Plot, PlotPoints, Points};

use super::Workbench;
use super::live::Ring;

/// Min/max per column of `buckets` columns over [t0, t1] for the ring signal `col`,
/// multiplied by `scale`. Returns points in time order (min then max within a column).
pub fn decimate(
    t: &VecDeque<f64>,
    col: &VecDeque<f64>,
    t0: f64,
    t1: f64,
    buckets: usize,
    scale: f64,
) -> Vec<[f64; 2]> {
    let n = t.len().min(col.len());
    if n == 0 || buckets == 0 || t1 <= t0 {
        return vec![];
    }
    let start = partition(t, t0);
    let width = (t1 - t0) / buckets as f64;
    let mut out = Vec::with_capacity(2 * buckets);
    // One pass; each sample goes to its column, so every step makes progress whatever the
    // rounding at column edges.
    let mut cur = usize::MAX;
    let (mut lo, mut hi, mut t_lo, mut t_hi) = (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0.0);
    let flush = |out: &mut Vec<[f64; 2]>, lo: f64, hi: f64, t_lo: f64, t_hi: f64| {
        if lo.is_finite() {
            if t_lo <= t_hi {
                out.push([t_lo, lo]);
                if t_hi != t_lo {
                    out.push([t_hi, hi]);
                }
            } else {
                out.push([t_hi, hi]);
                out.push([t_lo, lo]);
            }
        }
    };
    for k in start..n {
        let tk = t[k];
        if tk > t1 {
            break;
        }
        let b = (((tk - t0) / width) as usize).min(buckets - 1);
        if b != cur {
            flush(&mut out, lo, hi, t_lo, t_hi);
            cur = b;
            lo = f64::INFINITY;
            hi = f64::NEG_INFINITY;
        }
        let v = col[k] * scale;
        if v.is_finite() {
            if v < lo {
                lo = v;
                t_lo = tk;
            }
            if v > hi {
                hi = v;
                t_hi = tk;
            }
        }
    }
    flush(&mut out, lo, hi, t_lo, t_hi);
    out
}

fn partition(t: &VecDeque<f64>, x: f64) -> usize {
    let (mut lo, mut hi) = (0, t.len());
    while lo < hi {
        let mid = (lo + hi) / 2;
        if t[mid] < x {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    lo
}

/// One line of a plot: (legend label, trace signal, scale to the plotted unit).
type LineDef = (String, String, f64);
/// A plot's decimated lines: (legend label, points).
type PlotLines = Vec<(String, Vec<[f64; 2]>)>;

/// What each time plot shows for axis `a`.
fn plot_defs(a: &str, ring: &Ring) -> Vec<(&'static str, Vec<LineDef>)> {
    let has = |s: &str| ring.col(s).is_some();
    let mut comps = vec![];
    for (sig, label) in [
        ("backlash_comp", "backlash [µm]"),
        ("thermal_comp", "thermal F' at x [µm]"),
        ("thermal_f", "thermal F [µm]"),
        ("cross_comp", "cross ΔZ [µm]"),
    ] {
        let name = format!("{a}.{sig}");
        if has(&name) {
            comps.push((label.to_owned(), name, 1e3));
        }
    }
    let q = format!("{a}.quadrant_comp");
    if has(&q) {
        comps.push((format!("TFF [{}]", ring.unit(&q)), q, 1.0));
    }
    let e = format!("{a}.thermal_e");
    if has(&e) {
        comps.push(("E [-]".to_owned(), e, 1.0));
    }
    for (sig, label) in [
        ("thermal_e_ref", "E_ref [-]"),
        ("thermal_band_hi", "E_ref + Em"),
        ("thermal_band_lo", "E_ref - Em"),
    ] {
        let name = format!("{a}.{sig}");
        if has(&name) {
            comps.push((label.to_owned(), name, 1.0));
        }
    }
    vec![
        (
            "position error",
            vec![
                ("error cmd - pos [µm]".into(), format!("{a}.err"), 1e3),
                ("following error [µm]".into(), format!("{a}.ferr"), 1e3),
            ],
        ),
        (
            "torque",
            vec![
                (
                    "torque command [N·m]".into(),
                    format!("{a}.torque_cmd"),
                    1.0,
                ),
                ("torque [N·m]".into(), format!("{a}.torque"), 1.0),
                ("friction force [kN]".into(), format!("{a}.friction"), 1e-3),
            ],
        ),
        ("compensation outputs", comps),
        (
            "position and velocity",
            vec![
                ("position [mm]".into(), format!("{a}.pos"), 1.0),
                ("velocity [mm/s]".into(), format!("{a}.vel"), 1.0),
            ],
        ),
    ]
}

pub fn time_plots_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    let axis = wb.axis_name();
    let group = egui::Id::unique("time-plots");
    let width_px = ui.available_width().max(100.0) as usize;
    // Four plots, each with a title row above it.
    let h = ((ui.available_height() - 30.0) / 4.0 - 26.0).max(80.0);
    let (running, series) = {
        let s = wb.live.lock();
        let ring = &s.ring;
        let t1 = ring.t_last();
        let t0 = t1 - wb.window_s;
        let empty = VecDeque::new();
        let t = ring.cols.first().unwrap_or(&empty);
        let series: Vec<(&'static str, PlotLines)> = plot_defs(&axis, ring)
            .into_iter()
            .map(|(title, sigs)| {
                let lines = sigs
                    .into_iter()
                    .filter_map(|(label, name, k)| {
                        ring.col(&name)
                            .map(|c| (label, decimate(t, c, t0, t1, width_px, k)))
                    })
                    .collect();
                (title, lines)
            })
            .collect();
        (s.running, series)
    };
    let file = wb
        .loaded_trace
        .as_ref()
        .map(|(n, t)| (n.clone(), t.clone()));
    ui.horizontal(|ui| {
        if let Some((n, _)) = &file {
            ui.label(format!("overlay: {n}"));
            if ui.button("Close trace").clicked() {
                wb.loaded_trace = None;
            }
        }
        ui.label(if running {
            "following the live model"
        } else {
            "paused: drag to pan, scroll to zoom, hover for values"
        });
    });
    for (title, lines) in series {
        ui.horizontal(|ui| {
            ui.label(egui::RichText::new(title).strong());
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
        let mut plot = Plot::new(title)
            .height(h)
            .legend(Legend::default())
            .link_axis(group, [true, false])
            .link_cursor(group, [true, false])
            .x_axis_label("t [s]")
            .label_formatter(|hp| {
                Some(match hp {
                    egui_plot::HoverPosition::NearDataPoint {
                        plot_name,
                        position,
                        ..
                    } => {
                        format!("{plot_name}\nt = {:.4} s\n{:.4}", position.x, position.y)
                    }
                    egui_plot::HoverPosition::Elsewhere { position } => {
                        format!("t = {:.4} s\n{:.4}", position.x, position.y)
                    }
                })
            });
        if running {
            plot = plot.auto_bounds([true, true]);
        }
        let overlay = file.as_ref().map(|(_, t)| t);
        let resp = plot.show(ui, |pu| {
            for (label, pts) in lines {
                pu.line(Line::new(label, PlotPoints::from(pts)));
            }
            if let Some(tr) = overlay {
                let sig = match title {
                    "position error" => Some((format!("{axis}.err"), 1e3)),
                    "position and velocity" => Some((format!("{axis}.pos"), 1.0)),
                    "torque" => Some((format!("{axis}.torque"), 1.0)),
                    _ => None,
                };
                if let Some((name, k)) = sig {
                    let vals: Option<Vec<f64>> =
                        tr.values(&name).map(<[f64]>::to_vec).or_else(|| {
                            // A measured trace has cmd and pos; its error is derived.
                            let c = tr.values(&format!("{axis}.cmd"))?;
                            let p = tr.values(&format!("{axis}.pos"))?;
                            (title == "position error")
                                .then(|| c.iter().zip(p).map(|(a, b)| a - b).collect())
                        });
                    if let Some(v) = vals {
                        let t: VecDeque<f64> = tr.t().iter().copied().collect();
                        let c: VecDeque<f64> = v.into_iter().collect();
                        let (t0, t1) = (
                            t.front().copied().unwrap_or(0.0),
                            t.back().copied().unwrap_or(0.0),
                        );
                        let pts = decimate(&t, &c, t0, t1, 2000, k);
                        pu.line(Line::new(format!("file: {name}"), PlotPoints::from(pts)));
                    }
                }
            }
        });
        wb.plot_rects_insert(title, resp.response.rect);
    }
}

impl Workbench {
    fn plot_rects_insert(&mut self, name: &str, rect: egui::Rect) {
        self.plot_rects.insert(name.to_owned(), rect);
    }
}

pub fn circle_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    if wb.preset.axes.len() < 2 {
        ui.label("The circle test needs two axes (load the xy_circle scenario).");
        return;
    }
    let (a, b) = (
        wb.preset.axes[0].name.clone(),
        wb.preset.axes[1].name.clone(),
    );
    ui.horizontal(|ui| {
        let l = ui.label("radial error magnification");
        ui.add(
            egui::Slider::new(&mut wb.magnify, 1.0..=2000.0)
                .logarithmic(true)
                .suffix("×"),
        )
        .labelled_by(l.id);
    });
    let (cmd, act) = {
        let s = wb.live.lock();
        let r = &s.ring;
        let get = |n: &str| r.col(n).map(|c| c.iter().copied().collect::<Vec<f64>>());
        let pairs = |x: Option<Vec<f64>>, y: Option<Vec<f64>>| match (x, y) {
            (Some(x), Some(y)) => x.into_iter().zip(y).collect::<Vec<(f64, f64)>>(),
            _ => vec![],
        };
        (
            pairs(get(&format!("{a}.cmd")), get(&format!("{b}.cmd"))),
            pairs(get(&format!("{a}.pos")), get(&format!("{b}.pos"))),
        )
    };
    if cmd.is_empty() {
        ui.label("run the model to draw the circle");
        return;
    }
    // Centre and radius of the commanded circle by a least-squares (Kåsa) fit over the
    // samples where the command moves, as ballbar software fits its test circle; a mean of
    // all samples would be biased by dwells at the start point.
    let moving: Vec<(f64, f64)> = cmd
        .windows(2)
        .filter(|w| w[1] != w[0])
        .map(|w| w[1])
        .collect();
    let Some((cx, cy, r0)) = fit_circle(&moving) else {
        ui.label("the commanded path is not a circle yet");
        return;
    };
    let k = wb.magnify;
    let magnified = |pts: &[(f64, f64)]| -> Vec<[f64; 2]> {
        let step = (pts.len() / 4000).max(1);
        pts.iter()
            .step_by(step)
            .map(|&(x, y)| {
                let (dx, dy) = (x - cx, y - cy);
                let r = dx.hypot(dy);
                let rm = r0 + (r - r0) * k;
                if r > 0.0 {
                    [dx / r * rm, dy / r * rm]
                } else {
                    [0.0, 0.0]
                }
            })
            .collect()
    };
    let max_err = act
        .iter()
        .map(|&(x, y)| ((x - cx).hypot(y - cy) - r0).abs())
        .fold(0.0, f64::max);
    ui.label(format!(
        "R = {r0:.4} mm, radial deviation max {:.3} µm (plot magnified {k:.0}×)",
        max_err * 1e3
    ));
    Plot::new("circle")
        .data_aspect(1.0)
        .legend(Legend::default())
        .show(ui, |pu| {
            pu.line(Line::new("commanded", PlotPoints::from(magnified(&cmd))));
            pu.line(Line::new(
                "actual (radial error magnified)",
                PlotPoints::from(magnified(&act)),
            ));
        });
}

pub fn sag_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    let cb = wb.preset.crossbeam.clone();
    if !cb.enabled {
        ui.label("No crossbeam in this preset (load vertical_lathe_crossbeam).");
        return;
    }
    let Some(beam) =
        axisbench::plant::Beam::new(&cb, |n| wb.preset.axes.iter().position(|a| a.name == n))
    else {
        return;
    };
    let x_pos: Vec<f64> = {
        let s = wb.live.lock();
        s.machine.axes.iter().map(|a| a.pos_m).collect()
    };
    let loads: Vec<(f64, f64)> = beam
        .posts
        .iter()
        .map(|p| (x_pos[p.x_axis], p.weight_n))
        .collect();
    let span = cb.span_mm * 1e-3;
    let profile: Vec<[f64; 2]> = (0..=200)
        .map(|i| {
            let x = span * i as f64 / 200.0;
            [x * 1e3, -beam.deflection_m(x, &loads) * 1e6]
        })
        .collect();
    let posts: Vec<(String, [f64; 2])> = beam
        .posts
        .iter()
        .zip(&loads)
        .map(|(p, &(x, _))| {
            (
                format!("post on {}", wb.preset.axes[p.x_axis].name),
                [x * 1e3, -beam.deflection_m(x, &loads) * 1e6],
            )
        })
        .collect();
    ui.label(
        "Beam deflection Z(x) under the tool posts where they stand now, and the cross-table points \
         (as corrections, sign flipped to compare with the sag). Drag a table point up or down to edit it.",
    );
    let tables = wb.preset.cross.clone();
    let resp = Plot::new("sag")
        .legend(Legend::default())
        .x_axis_label("x [mm]")
        .y_axis_label("Z [µm]")
        .allow_drag(false)
        .show(ui, |pu| {
            pu.line(Line::new("beam sag Z(x) [µm]", PlotPoints::from(profile)));
            for t in &tables {
                let pts: Vec<[f64; 2]> = t.points.iter().map(|&(x, dz)| [x, -dz]).collect();
                pu.points(
                    Points::new(
                        format!("table {} over {} (-ΔZ)", t.comp_axis, t.base_axis),
                        PlotPoints::from(pts),
                    )
                    .radius(4.0),
                );
            }
            for (name, pt) in posts {
                pu.points(Points::new(name, vec![pt]).radius(6.0));
            }
            (pu.pointer_coordinate(), *pu.transform())
        });
    let (pointer, transform) = resp.inner;
    // Drag: the table point nearest the press (within 12 px) follows the pointer vertically.
    let r = &resp.response;
    if r.drag_started()
        && let Some(p) = pointer
    {
        let press = transform.position_from_point(&p);
        wb.sag_drag = tables
            .iter()
            .enumerate()
            .flat_map(|(ti, t)| {
                t.points
                    .iter()
                    .enumerate()
                    .map(move |(pi, &(x, dz))| (ti, pi, x, dz))
            })
            .map(|(ti, pi, x, dz)| {
                let sp = transform.position_from_point(&egui_plot::PlotPoint::new(x, -dz));
                ((sp - press).length(), ti, pi)
            })
            .filter(|(d, _, _)| *d < 12.0)
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, ti, pi)| (ti, pi));
    }
    if let Some((ti, pi)) = wb.sag_drag {
        if r.dragged()
            && let Some(p) = pointer
            && let Some(t) = wb.preset.cross.get(ti)
        {
            let pts: Vec<(f64, f64)> = t
                .points
                .iter()
                .enumerate()
                .map(|(i, &(x, y))| if i == pi { (x, -p.y) } else { (x, y) })
                .collect();
            let path = format!("cross.{ti}.points");
            if wb.edit(&path, |q| {
                if let Some(t) = q.cross.get_mut(ti) {
                    t.points = pts;
                }
            }) {
                wb.fields.remove(&format!("{path}#table"));
            }
        }
        if r.drag_stopped() {
            wb.sag_drag = None;
        }
    }
}

pub fn compare_ui(wb: &mut Workbench, ui: &mut egui::Ui) {
    ui.horizontal(|ui| {
        ui.label("Reference B:");
        ui.radio_value(&mut wb.compare_ref_saved, false, "compensation off");
        ui.radio_value(&mut wb.compare_ref_saved, true, "last saved preset");
        if ui.button("Run A/B").clicked() {
            wb.run_compare();
        }
    });
    let Some(c) = &wb.compare else {
        ui.label("Runs the program twice, headless, and overlays the errors.");
        return;
    };
    ui.label(format!(
        "axis {}, A = current settings, B = {}",
        c.axis, c.reference
    ));
    egui::Grid::new("compare-table")
        .striped(true)
        .show(ui, |ui| {
            for h in [
                "run",
                "peak |error| µm",
                "RMS error µm",
                "worst +->- reversal µm",
                "worst -->+ reversal µm",
            ] {
                ui.label(egui::RichText::new(h).strong());
            }
            ui.end_row();
            for (label, peak, rms, dn, up) in &c.table {
                ui.label(label);
                ui.label(format!("{peak:.3}"));
                ui.label(format!("{rms:.3}"));
                ui.label(format!("{dn:.3}"));
                ui.label(format!("{up:.3}"));
                ui.end_row();
            }
        });
    Plot::new("compare-plot")
        .legend(Legend::default())
        .x_axis_label("t [s]")
        .y_axis_label("error [µm]")
        .show(ui, |pu| {
            for (label, t, e) in &c.runs {
                let t: VecDeque<f64> = t.iter().copied().collect();
                let v: VecDeque<f64> = e.iter().copied().collect();
                let (t0, t1) = (
                    t.front().copied().unwrap_or(0.0),
                    t.back().copied().unwrap_or(0.0),
                );
                pu.line(Line::new(
                    label.clone(),
                    PlotPoints::from(decimate(&t, &v, t0, t1, 2000, 1e3)),
                ));
            }
        });
}

/// Least-squares circle through points: solves x² + y² + D·x + E·y + F = 0.
pub fn fit_circle(pts: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    if pts.len() < 3 {
        return None;
    }
    let a = nalgebra::DMatrix::from_fn(pts.len(), 3, |i, j| match j {
        0 => pts[i].0,
        1 => pts[i].1,
        _ => 1.0,
    });
    let b = nalgebra::DVector::from_iterator(pts.len(), pts.iter().map(|&(x, y)| -(x * x + y * y)));
    let sol = a.svd(true, true).solve(&b, 1e-12).ok()?;
    let (cx, cy) = (-sol[0] / 2.0, -sol[1] / 2.0);
    let r2 = cx * cx + cy * cy - sol[2];
    (r2 > 0.0).then(|| (cx, cy, r2.sqrt()))
}
