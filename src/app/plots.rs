//! Plots: the circle test, the sag profile and the A/B overlay, and the decimation the
//! time plots (`scope.rs`) share. Live data is decimated to a min/max pair per pixel column before it
//! reaches egui_plot, so a full 60 s window at 8 kHz costs the same as a short one.

use eframe::egui;
use std::collections::VecDeque;

use egui_plot::{Legend, Line, Plot, PlotPoints, Points};

use axisbench::Trace;
use axisbench::trace::{AxisSignal, AxisSignal as S};
use axisbench::units::{fmt_qty, m_to_mm, m_to_um, mm_to_m, mm_to_um};

use super::Workbench;

/// Min/max per column of `buckets` columns over [t0, t1] for the ring signal `col` (SI, as
/// the trace holds it), shown through `show` (SI → the plotted unit, a named helper of
/// [`axisbench::units`]). Returns points in time order (min then max within a column).
pub fn decimate(
    t: &VecDeque<f64>,
    col: &VecDeque<f64>,
    t0: f64,
    t1: f64,
    buckets: usize,
    show: Show,
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
        let v = show(col[k]);
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

pub fn partition(t: &VecDeque<f64>, x: f64) -> usize {
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

/// SI value → the unit a plot shows it in.
pub type Show = fn(f64) -> f64;

fn si(v: f64) -> f64 {
    v
}

/// The line a loaded trace adds to the time plot `title`: its error (derived from cmd and
/// pos when the file has no `err`), position or torque, decimated over its whole length.
pub fn overlay_line(tr: &Trace, axis: &str, title: &str) -> Option<(String, Vec<[f64; 2]>)> {
    let (sig, show): (AxisSignal, Show) = match title {
        "position error" => (S::Err, m_to_um),
        "position and velocity" => (S::Pos, m_to_mm),
        "torque" => (S::Torque, si),
        _ => return None,
    };
    let vals: Vec<f64> = tr.axis_values(axis, sig).map(<[f64]>::to_vec).or_else(|| {
        // A measured trace has cmd and pos; its error is derived.
        let c = tr.axis_values(axis, S::Cmd)?;
        let p = tr.axis_values(axis, S::Pos)?;
        (sig == S::Err).then(|| c.iter().zip(p).map(|(a, b)| a - b).collect())
    })?;
    let t: VecDeque<f64> = tr.t().iter().copied().collect();
    let c: VecDeque<f64> = vals.into_iter().collect();
    let (t0, t1) = (
        t.front().copied().unwrap_or(0.0),
        t.back().copied().unwrap_or(0.0),
    );
    Some((
        format!("file: {}", sig.column(axis)),
        decimate(&t, &c, t0, t1, 2000, show),
    ))
}

impl Workbench {
    pub(super) fn plot_rects_insert(&mut self, name: &str, rect: egui::Rect) {
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
        // The ring holds m; the circle is drawn in mm.
        let get = |n: &str| {
            r.col(n)
                .map(|c| c.iter().map(|&x| m_to_mm(x)).collect::<Vec<f64>>())
        };
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
        "R = {}, radial deviation max {} (plot magnified {k:.0}×)",
        fmt_qty(r0, "mm"),
        fmt_qty(mm_to_um(max_err), "um")
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

/// Points with a legend label each.
type LabelledPoints = Vec<(String, [f64; 2])>;

/// The beam's deflection profile (x mm, −Z µm) under `loads` (post x m, weight N), and each
/// post's point on it, labelled by its X axis.
fn sag_profile(
    wb: &Workbench,
    beam: &axisbench::plant::Beam,
    loads: &[(f64, f64)],
    span_m: f64,
) -> (Vec<[f64; 2]>, LabelledPoints) {
    let point = |x_m: f64| [m_to_mm(x_m), -m_to_um(beam.deflection_m(x_m, loads))];
    let profile = (0..=200)
        .map(|i| point(span_m * i as f64 / 200.0))
        .collect();
    let posts = beam
        .posts
        .iter()
        .zip(loads)
        .map(|(p, &(x, _))| {
            (
                format!("post on {}", wb.preset.axes[p.x_axis].name),
                point(x),
            )
        })
        .collect();
    (profile, posts)
}

/// Drag on the sag plot: the table point nearest the press (within 12 px) follows the
/// pointer vertically, each move an edit of the preset.
fn sag_drag(
    wb: &mut Workbench,
    r: &egui::Response,
    pointer: Option<egui_plot::PlotPoint>,
    transform: &egui_plot::PlotTransform,
) {
    let tables = &wb.preset.cross;
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

/// The sag view: the crossbeam's deflection under the posts where they stand now, with the
/// cross-table points to compare and drag.
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
    let (profile, posts) = sag_profile(wb, &beam, &loads, mm_to_m(cb.span_mm));
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
    sag_drag(wb, &resp.response, pointer, &transform);
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
                "peak |error|",
                "RMS error",
                "worst +->- reversal",
                "worst -->+ reversal",
            ] {
                ui.label(egui::RichText::new(h).strong());
            }
            ui.end_row();
            for (label, peak, rms, dn, up) in &c.table {
                ui.label(label);
                for v in [peak, rms, dn, up] {
                    ui.label(fmt_qty(*v, "um"));
                }
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
                    PlotPoints::from(decimate(&t, &v, t0, t1, 2000, m_to_um)),
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
