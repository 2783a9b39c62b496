//! The mapping report of an export: every entry of the export's one list (see
//! [`super::entry`]) with the lines it became, or "not representable" with the nearest
//! approximation and the error that approximation introduces, computed by simulating both.
//!
//! The simulations run the preset's scenario (at most the horizon) twice in lockstep, once
//! with the preset's own compensations and once with the approximation installed, and
//! compare per T3 sample on the affected axes: the correction the NC adds to the command
//! (`cmd_comp − cmd`) and the position error of the tool (`pos − cmd`). An approximation
//! that only shifts the axis by a constant (LinuxCNC's symmetric backlash split) reports the
//! constant separately: homing absorbs it.

use serde::Serialize;

use super::entry::{Entry, Put, Status};
use super::{Ctx, ExportError, Target};
use crate::comp::CompStack;
use crate::comp::linuxcnc::{CompRow, CompTable, JointParams, LinuxCncComp, LinuxCncPosComp};
use crate::comp::{CompSignal, PosCompCtx, PositionComp};
use crate::machine::Machine;
use crate::preset::Preset;
use crate::preset::comp::BacklashParams;
use crate::preset::comp::CrossTable;
use crate::preset::comp::QuadrantParams;
use crate::units::{m_to_mm, m_to_um, mm_to_m};

/// The error an approximation introduces.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ErrFigures {
    /// How it was computed.
    pub method: String,
    /// Largest difference of the correction, µm (after removing `constant_offset_um`).
    pub correction_max_um: f64,
    /// RMS difference of the correction, µm, where a time series was compared.
    pub correction_rms_um: Option<f64>,
    /// Largest difference of the tool's position error, µm (after the constant offset).
    pub position_error_max_um: Option<f64>,
    /// A constant shift of the axis, µm (absorbed by homing / the reference offset).
    pub constant_offset_um: f64,
}

impl ErrFigures {
    /// A figure evaluated along a table or from a rounding, not simulated.
    pub fn evaluated(method: impl Into<String>, max_um: f64) -> ErrFigures {
        ErrFigures {
            method: method.into(),
            correction_max_um: max_um,
            correction_rms_um: None,
            position_error_max_um: None,
            constant_offset_um: 0.0,
        }
    }
}

/// The mapping report: the export's entries, rendered for people (Markdown) and programs
/// (JSON).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// The preset's name.
    pub preset: String,
    /// The controller, as [`Target::title`] names it.
    pub target: String,
    /// The target's command-line name.
    pub target_name: String,
    /// Files written besides the report.
    pub files: Vec<String>,
    /// What the simulations ran.
    pub simulation: String,
    /// The export's one list; the files were rendered from the same entries.
    pub entries: Vec<Entry>,
}

/// An entry as the JSON report shows it: the entry plus its rendered target summary.
#[derive(Serialize)]
struct JsonEntry<'a> {
    field: &'a str,
    value: &'a str,
    status: Status,
    target: String,
    puts: &'a [Put],
    note: &'a str,
    error: &'a Option<ErrFigures>,
}

#[derive(Serialize)]
struct JsonReport<'a> {
    preset: &'a str,
    target: &'a str,
    target_name: &'a str,
    files: &'a [String],
    simulation: &'a str,
    entries: Vec<JsonEntry<'a>>,
}

impl Report {
    /// The report as `mapping_report.md`.
    pub fn to_markdown(&self) -> String {
        let mut s = format!(
            "# Mapping report: preset `{}` → {}\n\n",
            self.preset, self.target
        );
        s += &format!(
            "Files: {}, `mapping_report.md`, `mapping_report.json`.\n\n",
            self.files
                .iter()
                .map(|f| format!("`{f}`"))
                .collect::<Vec<_>>()
                .join(", ")
        );
        s += &format!("Errors of approximations: {}\n\n", self.simulation);
        s += "Status: **mapped** = carried exactly; **derived** = computed by the stated rule; \
              **approximated** = carried but the target behaves differently; **not representable** = \
              the target cannot carry it (nearest approximation given); **no documented parameter** = \
              nothing is written because no parameter number is documented for it. \
              *Written as* lists the lines of the files this setting became (the files are rendered \
              from the same list).\n\n";
        s += "| Preset field | Value | Status | Written as | Rule / nearest approximation | Error introduced |\n";
        s += "|---|---|---|---|---|---|\n";
        for e in &self.entries {
            s += &format!(
                "| `{}` | {} | {} | {} | {} | {} |\n",
                e.field,
                cell(&e.value),
                e.status.label(),
                cell(&e.target()),
                cell(&e.note),
                cell(&e.error.as_ref().map_or("—".into(), describe))
            );
        }
        s
    }

    /// The report as `mapping_report.json` (every entry with every line it became).
    pub fn to_json(&self) -> String {
        let view = JsonReport {
            preset: &self.preset,
            target: &self.target,
            target_name: &self.target_name,
            files: &self.files,
            simulation: &self.simulation,
            entries: self
                .entries
                .iter()
                .map(|e| JsonEntry {
                    field: &e.field,
                    value: &e.value,
                    status: e.status,
                    target: e.target(),
                    puts: &e.puts,
                    note: &e.note,
                    error: &e.error,
                })
                .collect(),
        };
        serde_json::to_string_pretty(&view).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// The entries of one status, for tests and summaries.
    pub fn with_status(&self, st: Status) -> impl Iterator<Item = &Entry> {
        self.entries.iter().filter(move |e| e.status == st)
    }

    /// The entries for one preset field (exact path).
    pub fn for_field<'a>(&'a self, field: &'a str) -> impl Iterator<Item = &'a Entry> {
        self.entries.iter().filter(move |e| e.field == field)
    }
}

fn cell(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', "<br>")
}

fn describe(f: &ErrFigures) -> String {
    let mut s = format!("max {:.3} µm", f.correction_max_um);
    if let Some(r) = f.correction_rms_um {
        s += &format!(", RMS {r:.3} µm");
    }
    s += " (correction)";
    if let Some(p) = f.position_error_max_um {
        s += &format!("; position error max {p:.3} µm");
    }
    if f.constant_offset_um != 0.0 {
        s += &format!(
            "; plus a constant offset of {:.3} µm that homing absorbs (compared from the sample it is established)",
            f.constant_offset_um
        );
    }
    s += &format!(" — {}", f.method);
    s
}

/// What the approximation machine changes relative to the preset.
#[derive(Debug, Clone)]
pub(crate) enum Change {
    /// Axis backlash compensation replaced (None = removed).
    Backlash {
        axis: usize,
        params: Option<BacklashParams>,
    },
    /// Axis backlash compensation replaced by LinuxCNC's joint compensation.
    Linuxcnc {
        axis: usize,
        rows: Vec<CompRow>,
        joint: JointParams,
    },
    /// Quadrant compensation replaced (None = removed).
    Quadrant {
        axis: usize,
        params: Option<QuadrantParams>,
    },
    /// Thermal correction removed, or frozen at its value at the end of the baseline run
    /// (a static position-proportional correction, as setting data hold it).
    Thermal { axis: usize, frozen: bool },
    /// The cross tables the target carries (replacing the preset's list).
    Cross { tables: Vec<CrossTable> },
}

/// How an entry's error figure is obtained.
#[derive(Debug, Clone)]
pub(crate) enum Approx {
    None,
    /// Already evaluated (e.g. a table's interpolation residual).
    Evaluated(ErrFigures),
    /// Simulate with these changes; compare these axes.
    Sim {
        changes: Vec<Change>,
        axes: Vec<usize>,
        remove_offset: bool,
    },
}

/// An entry whose error figure may still have to be simulated.
pub(crate) struct Pending {
    /// The entry as the report will show it.
    pub entry: Entry,
    /// How its error figure is obtained.
    pub approx: Approx,
}

impl Pending {
    /// An entry for `field` (dot dialect) with `value` (with unit).
    pub fn new(field: impl Into<String>, value: impl Into<String>, status: Status) -> Pending {
        Pending {
            entry: Entry {
                field: field.into(),
                value: value.into(),
                status,
                puts: Vec::new(),
                note: String::new(),
                error: None,
            },
            approx: Approx::None,
        }
    }
    /// Carried exactly.
    pub fn mapped(field: impl Into<String>, value: impl Into<String>) -> Pending {
        Pending::new(field, value, Status::Mapped)
    }
    /// Computed from preset settings by the rule in the note.
    pub fn derived(field: impl Into<String>, value: impl Into<String>) -> Pending {
        Pending::new(field, value, Status::Derived)
    }
    /// Carried, but the target behaves differently (the error says how much).
    pub fn approximated(field: impl Into<String>, value: impl Into<String>) -> Pending {
        Pending::new(field, value, Status::Approximated)
    }
    /// Not carried; the note gives the nearest approximation.
    pub fn not_representable(field: impl Into<String>, value: impl Into<String>) -> Pending {
        Pending::new(field, value, Status::NotRepresentable)
    }
    /// The target may have the function, but no parameter number is documented.
    pub fn undocumented(field: impl Into<String>, value: impl Into<String>) -> Pending {
        Pending::new(field, value, Status::NoDocumentedParameter)
    }
    /// The rule, or why it is approximated and how.
    pub fn note(mut self, note: impl Into<String>) -> Pending {
        self.entry.note = note.into();
        self
    }
    /// A line this entry becomes.
    pub fn put(mut self, p: Put) -> Pending {
        self.entry.puts.push(p);
        self
    }
    /// Lines this entry becomes.
    pub fn puts(mut self, p: impl IntoIterator<Item = Put>) -> Pending {
        self.entry.puts.extend(p);
        self
    }
    /// The error is simulated: these changes on these axes (`remove_offset`: a constant
    /// shift is reported apart, homing absorbs it).
    pub fn sim(mut self, changes: Vec<Change>, axes: Vec<usize>, remove_offset: bool) -> Pending {
        self.approx = Approx::Sim {
            changes,
            axes,
            remove_offset,
        };
        self
    }
    /// The error is already known.
    pub fn evaluated(mut self, f: ErrFigures) -> Pending {
        self.approx = Approx::Evaluated(f);
        self
    }
}

/// The baseline run of the preset's scenario and what the approximations compare against.
pub struct Sim {
    preset: Preset,
    programs: Vec<(String, String)>,
    /// T3 steps simulated.
    pub steps: u64,
    /// The preset's T3, s.
    pub t3_s: f64,
    /// Per axis, per T3: correction (cmd_comp − cmd) and position error (pos − cmd), µm.
    corr_um: Vec<Vec<f64>>,
    err_um: Vec<Vec<f64>>,
    /// Per axis: commanded range, mm.
    range_mm: Vec<Option<(f64, f64)>>,
    /// Per axis with a thermal correction: F' at the measurement point at the end, m.
    thermal_end_m: Vec<Option<f64>>,
    /// Whether the scenario ran to its end within the horizon.
    pub finished: bool,
}

impl Sim {
    /// Runs the preset's scenario for at most `horizon_s` (default [`super::DEFAULT_HORIZON_S`]).
    pub fn new(
        preset: &Preset,
        programs: &[(String, String)],
        horizon_s: Option<f64>,
    ) -> Result<Sim, ExportError> {
        let horizon = horizon_s.unwrap_or(super::DEFAULT_HORIZON_S);
        if !(horizon.is_finite() && horizon > 0.0) {
            return Err(ExportError::Input {
                file: "--horizon".into(),
                reason: format!("{horizon} s must be a positive time"),
            });
        }
        let mut m =
            Machine::new(preset, programs).map_err(|e| ExportError::Simulation(e.to_string()))?;
        m.set_recording(false);
        let max_k = (horizon / m.t3_s).ceil() as u64;
        let n = m.axes.len();
        let mut corr = vec![Vec::new(); n];
        let mut err = vec![Vec::new(); n];
        let mut range: Vec<Option<(f64, f64)>> = vec![None; n];
        while !m.done() && m.k < max_k {
            m.step();
            for (i, a) in m.axes.iter().enumerate() {
                corr[i].push(m_to_um(a.cmd_m() - a.cmd_raw_m()));
                err[i].push(m_to_um(a.pos_m - a.cmd_raw_m()));
                let x = m_to_mm(a.cmd_raw_m());
                range[i] = Some(match range[i] {
                    Some((l, h)) => (l.min(x), h.max(x)),
                    None => (x, x),
                });
            }
        }
        let thermal_end_m = (0..n)
            .map(|i| {
                m.find_comp::<crate::comp::thermal::Thermal>()
                    .find(|t| t.axis() == i)
                    .map(|t| t.f_applied_m)
            })
            .collect();
        Ok(Sim {
            preset: preset.clone(),
            programs: programs.to_vec(),
            steps: m.k,
            t3_s: m.t3_s,
            corr_um: corr,
            err_um: err,
            range_mm: range,
            thermal_end_m,
            finished: m.done(),
        })
    }

    /// The range axis `axis` was commanded over, mm.
    pub fn base_range_mm(&self, axis: usize) -> Option<(f64, f64)> {
        self.range_mm.get(axis).copied().flatten()
    }

    /// F' of the axis's thermal correction at the end of the run, m.
    pub fn thermal_end_m(&self, axis: usize) -> Option<f64> {
        self.thermal_end_m.get(axis).copied().flatten()
    }

    /// Largest |correction| of the preset's own compensations on `axis`, µm.
    pub fn base_correction_max_um(&self, axis: usize) -> f64 {
        self.corr_um[axis].iter().fold(0.0, |m, v| m.max(v.abs()))
    }

    fn describe(&self) -> String {
        format!(
            "simulated {:.2} s of the scenario ({}) {}: the preset's own compensations vs the approximation, compared every T3 = {} s",
            self.steps as f64 * self.t3_s,
            self.programs
                .iter()
                .map(|(n, _)| n.as_str())
                .collect::<Vec<_>>()
                .join(", "),
            if self.finished {
                "to its end"
            } else {
                "(stopped at the horizon; `--horizon` runs longer)"
            },
            self.t3_s
        )
    }

    /// The preset with `changes` applied, and the position compensations that replace
    /// model ones (LinuxCNC's joint compensation, a frozen thermal correction).
    fn changed(&self, changes: &[Change]) -> (Preset, Vec<Box<dyn PositionComp>>) {
        let mut p = self.preset.clone();
        let mut front: Vec<Box<dyn PositionComp>> = Vec::new();
        for c in changes {
            match c {
                Change::Backlash { axis, params } => match params {
                    Some(b) => p.axes[*axis].backlash = b.clone(),
                    None => p.axes[*axis].backlash.enabled = false,
                },
                Change::Linuxcnc { axis, rows, joint } => {
                    p.axes[*axis].backlash.enabled = false;
                    let (table, _) = CompTable::load(rows);
                    let comp = LinuxCncComp::new(table, joint.clone());
                    let name = p.axes[*axis].name.clone();
                    front.push(Box::new(LinuxCncPosComp::new(*axis, &name, comp)));
                }
                Change::Quadrant { axis, params } => match params {
                    Some(q) => p.axes[*axis].quadrant = q.clone(),
                    None => p.axes[*axis].quadrant.enabled = false,
                },
                Change::Thermal { axis, frozen } => {
                    if *frozen {
                        let t = &self.preset.axes[*axis].thermal;
                        let f_applied_m = self.thermal_end_m[*axis].unwrap_or(0.0);
                        front.push(Box::new(FrozenThermal {
                            axis: *axis,
                            x0_m: mm_to_m(t.fixed_end_mm),
                            slope: f_applied_m / mm_to_m(t.measure_pos_mm - t.fixed_end_mm),
                        }));
                    }
                    p.axes[*axis].thermal.enabled = false;
                }
                Change::Cross { tables } => p.cross = tables.clone(),
            }
        }
        (p, front)
    }

    /// Runs the approximation in lockstep with the baseline; per compared axis the
    /// differences of correction and position error, µm.
    fn diffs(&self, changes: &[Change], axes: &[usize]) -> Result<Diffs, ExportError> {
        let (p, mut front) = self.changed(changes);
        let mut m =
            Machine::new(&p, &self.programs).map_err(|e| ExportError::Simulation(e.to_string()))?;
        m.set_recording(false);
        if !front.is_empty() {
            let mut stack: CompStack = crate::comp::build(&p);
            front.append(&mut stack.position);
            stack.position = front;
            m.set_comps(stack);
        }
        let n = self.steps as usize;
        let mut d = Diffs {
            corr: vec![Vec::with_capacity(n); axes.len()],
            err: vec![Vec::with_capacity(n); axes.len()],
        };
        for k in 0..n {
            m.step();
            for (j, &i) in axes.iter().enumerate() {
                let a = &m.axes[i];
                d.corr[j].push(m_to_um(a.cmd_m() - a.cmd_raw_m()) - self.corr_um[i][k]);
                d.err[j].push(m_to_um(a.pos_m - a.cmd_raw_m()) - self.err_um[i][k]);
            }
        }
        Ok(d)
    }

    fn run(
        &self,
        changes: &[Change],
        axes: &[usize],
        remove_offset: bool,
    ) -> Result<ErrFigures, ExportError> {
        let d = self.diffs(changes, axes)?;
        Ok(d.figures(self.describe(), remove_offset))
    }
}

/// Two corrections closer than this (µm) are the same: float noise, far below any
/// encoder step.
const SAME_UM: f64 = 0.000_001;

/// Differences between the approximation and the baseline, per compared axis, µm.
struct Diffs {
    corr: Vec<Vec<f64>>,
    err: Vec<Vec<f64>>,
}

impl Diffs {
    fn figures(&self, method: String, remove_offset: bool) -> ErrFigures {
        let mut out = ErrFigures {
            method,
            correction_max_um: 0.0,
            correction_rms_um: Some(0.0),
            position_error_max_um: Some(0.0),
            constant_offset_um: 0.0,
        };
        let mut rms_sum = 0.0;
        let mut rms_n = 0usize;
        for (corr, err) in self.corr.iter().zip(&self.err) {
            let off = if remove_offset {
                corr.last().copied().unwrap_or(0.0)
            } else {
                0.0
            };
            if off.abs() > out.constant_offset_um.abs() {
                out.constant_offset_um = off;
            }
            // With a constant offset, compare from the sample it is first reached: before,
            // the target is still taking up its initial direction (on a machine, homing
            // does that).
            let start = if remove_offset {
                corr.iter()
                    .position(|d| (d - off).abs() <= SAME_UM)
                    .unwrap_or(0)
            } else {
                0
            };
            for (dc, de) in corr.iter().zip(err).skip(start) {
                let c = dc - off;
                out.correction_max_um = out.correction_max_um.max(c.abs());
                rms_sum += c * c;
                rms_n += 1;
                let e = de - off;
                out.position_error_max_um =
                    Some(out.position_error_max_um.unwrap_or(0.0).max(e.abs()));
            }
        }
        out.correction_rms_um = Some(if rms_n > 0 {
            (rms_sum / rms_n as f64).sqrt()
        } else {
            0.0
        });
        out
    }
}

/// A thermal correction frozen at one state: −slope·(x − x₀), what a static setting-data
/// correction (SINUMERIK SD43910) applies between two updates.
struct FrozenThermal {
    axis: usize,
    x0_m: f64,
    slope: f64,
}

impl PositionComp for FrozenThermal {
    fn reads_machine(&self) -> bool {
        false
    }

    fn name(&self) -> &str {
        "frozen_thermal"
    }
    fn step(&mut self, ctx: &PosCompCtx<'_>, out_m: &mut [f64]) {
        out_m[self.axis] += -self.slope * (ctx.cmd_m[self.axis] - self.x0_m);
    }
    fn signals(&self) -> Vec<CompSignal> {
        vec![]
    }
    fn values(&self, _out: &mut [f64]) {}
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

/// Runs the pending simulations and assembles the report.
pub(crate) fn finish(
    ctx: &Ctx,
    sim: &Sim,
    target: Target,
    pending: Vec<Pending>,
    files: Vec<String>,
) -> Result<Report, ExportError> {
    let mut entries = Vec::new();
    for p in pending {
        let mut e = p.entry;
        e.error = match p.approx {
            Approx::None => None,
            Approx::Evaluated(f) => Some(f),
            Approx::Sim {
                changes,
                axes,
                remove_offset,
            } => Some(sim.run(&changes, &axes, remove_offset)?),
        };
        entries.push(e);
    }
    Ok(Report {
        preset: ctx.preset.name.clone(),
        target: target.title().into(),
        target_name: target.name().into(),
        files,
        simulation: sim.describe(),
        entries,
    })
}
