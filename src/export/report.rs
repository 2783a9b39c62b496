//! The mapping report of an export: every preset setting, the target key it went to, or
//! "not representable" with the nearest approximation and the error that approximation
//! introduces, computed by simulating both.
//!
//! The simulations run the preset's scenario (at most the horizon) twice in lockstep, once
//! with the preset's own compensations and once with the approximation installed, and
//! compare per T3 sample on the affected axes: the correction the NC adds to the command
//! (`cmd_comp − cmd`) and the position error of the tool (`pos − cmd`). An approximation
//! that only shifts the axis by a constant (LinuxCNC's symmetric backlash split) reports the
//! constant separately: homing absorbs it.

use serde::Serialize;

use super::{Ctx, ExportError, Target};
use crate::comp::CompStack;
use crate::comp::backlash::BacklashParams;
use crate::comp::cross::CrossTable;
use crate::comp::linuxcnc::{CompRow, CompTable, JointParams, LinuxCncComp, LinuxCncPosComp};
use crate::comp::quadrant::QuadrantParams;
use crate::comp::{CompSignal, PosCompCtx, PositionComp};
use crate::machine::Machine;
use crate::preset::Preset;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Carried exactly.
    Mapped,
    /// Computed from preset settings by a documented rule.
    Derived,
    /// Carried, but the target's behaviour differs; the error is given.
    Approximated,
    NotRepresentable,
    /// The target may have such a function, but no parameter number is documented here.
    NoDocumentedParameter,
}

impl Status {
    pub fn label(self) -> &'static str {
        match self {
            Status::Mapped => "mapped",
            Status::Derived => "derived",
            Status::Approximated => "approximated",
            Status::NotRepresentable => "not representable",
            Status::NoDocumentedParameter => "no documented parameter",
        }
    }
}

/// The error an approximation introduces.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ErrFigures {
    /// How it was computed.
    pub method: String,
    /// Largest difference of the correction, µm (after removing `constant_offset_um`).
    pub correction_max_um: f64,
    pub correction_rms_um: Option<f64>,
    /// Largest difference of the tool's position error, µm (after the constant offset).
    pub position_error_max_um: Option<f64>,
    /// A constant shift of the axis, µm (absorbed by homing / the reference offset).
    pub constant_offset_um: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Entry {
    /// The preset setting and its value.
    pub setting: String,
    pub status: Status,
    /// Target key = value (or file), empty when nothing is written.
    pub target: String,
    /// The rule used, or the nearest approximation.
    pub note: String,
    pub error: Option<ErrFigures>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub preset: String,
    pub target: String,
    pub target_name: String,
    /// Files written besides the report.
    pub files: Vec<String>,
    /// What the simulations ran.
    pub simulation: String,
    pub entries: Vec<Entry>,
}

impl Report {
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
              nothing is written because no parameter number is documented for it.\n\n";
        s += "| Preset setting | Status | Target | Rule / nearest approximation | Error introduced |\n";
        s += "|---|---|---|---|---|\n";
        for e in &self.entries {
            s += &format!(
                "| {} | {} | {} | {} | {} |\n",
                cell(&e.setting),
                e.status.label(),
                cell(&e.target),
                cell(&e.note),
                cell(&e.error.as_ref().map_or("—".into(), describe))
            );
        }
        s
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// The entries of one status, for tests and summaries.
    pub fn with_status(&self, st: Status) -> impl Iterator<Item = &Entry> {
        self.entries.iter().filter(move |e| e.status == st)
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

pub(crate) struct Pending {
    pub entry: Entry,
    pub approx: Approx,
}

impl Pending {
    fn new(setting: impl Into<String>, status: Status, target: impl Into<String>) -> Pending {
        Pending {
            entry: Entry {
                setting: setting.into(),
                status,
                target: target.into(),
                note: String::new(),
                error: None,
            },
            approx: Approx::None,
        }
    }
    pub fn mapped(setting: impl Into<String>, target: impl Into<String>, note: &str) -> Pending {
        Pending::new(setting, Status::Mapped, target).note(note)
    }
    pub fn derived(setting: impl Into<String>, target: impl Into<String>, note: &str) -> Pending {
        Pending::new(setting, Status::Derived, target).note(note)
    }
    pub fn approximated(
        setting: impl Into<String>,
        target: impl Into<String>,
        note: &str,
    ) -> Pending {
        Pending::new(setting, Status::Approximated, target).note(note)
    }
    pub fn not_representable(setting: impl Into<String>, nearest: &str) -> Pending {
        Pending::new(setting, Status::NotRepresentable, "").note(nearest)
    }
    pub fn undocumented(setting: impl Into<String>, note: &str) -> Pending {
        Pending::new(setting, Status::NoDocumentedParameter, "").note(note)
    }
    pub fn note(mut self, note: &str) -> Pending {
        self.entry.note = note.to_owned();
        self
    }
    pub fn sim(mut self, changes: Vec<Change>, axes: Vec<usize>, remove_offset: bool) -> Pending {
        self.approx = Approx::Sim {
            changes,
            axes,
            remove_offset,
        };
        self
    }
    pub fn evaluated(mut self, f: ErrFigures) -> Pending {
        self.approx = Approx::Evaluated(f);
        self
    }
}

/// The baseline run of the preset's scenario and what the approximations compare against.
pub struct Sim {
    preset: Preset,
    programs: Vec<(String, String)>,
    pub steps: u64,
    pub t3_s: f64,
    /// Per axis, per T3: correction (cmd_comp − cmd) and position error (pos − cmd), µm.
    corr_um: Vec<Vec<f64>>,
    err_um: Vec<Vec<f64>>,
    /// Per axis: commanded range, mm.
    range_mm: Vec<Option<(f64, f64)>>,
    /// Per axis with a thermal correction: F' at the measurement point at the end, m.
    thermal_end_m: Vec<Option<f64>>,
    pub finished: bool,
}

impl Sim {
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
                corr[i].push((a.cmd_m - a.cmd_raw_m) * 1e6);
                err[i].push((a.pos_m - a.cmd_raw_m) * 1e6);
                let x = a.cmd_raw_m * 1e3;
                range[i] = Some(match range[i] {
                    Some((l, h)) => (l.min(x), h.max(x)),
                    None => (x, x),
                });
            }
        }
        let thermal_end_m = (0..n)
            .map(|i| {
                m.comps()
                    .find::<crate::comp::thermal::Thermal>()
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

    pub fn base_range_mm(&self, axis: usize) -> Option<(f64, f64)> {
        self.range_mm.get(axis).copied().flatten()
    }

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

    fn run(
        &self,
        changes: &[Change],
        axes: &[usize],
        remove_offset: bool,
    ) -> Result<ErrFigures, ExportError> {
        let sim_err = |e: String| ExportError::Simulation(e);
        let mut p = self.preset.clone();
        let mut lcnc: Vec<(usize, LinuxCncComp)> = Vec::new();
        let mut frozen: Vec<(usize, f64)> = Vec::new();
        for c in changes {
            match c {
                Change::Backlash { axis, params } => match params {
                    Some(b) => p.axes[*axis].backlash = b.clone(),
                    None => p.axes[*axis].backlash.enabled = false,
                },
                Change::Linuxcnc { axis, rows, joint } => {
                    p.axes[*axis].backlash.enabled = false;
                    let (table, _) = CompTable::load(rows);
                    lcnc.push((*axis, LinuxCncComp::new(table, joint.clone())));
                }
                Change::Quadrant { axis, params } => match params {
                    Some(q) => p.axes[*axis].quadrant = q.clone(),
                    None => p.axes[*axis].quadrant.enabled = false,
                },
                Change::Thermal { axis, frozen: f } => {
                    if *f {
                        let slope = self.thermal_end_m[*axis].unwrap_or(0.0);
                        frozen.push((*axis, slope));
                    }
                    p.axes[*axis].thermal.enabled = false;
                }
                Change::Cross { tables } => p.cross = tables.clone(),
            }
        }
        let mut m = Machine::new(&p, &self.programs).map_err(|e| sim_err(e.to_string()))?;
        m.set_recording(false);
        if !lcnc.is_empty() || !frozen.is_empty() {
            let mut stack: CompStack = crate::comp::build(&p);
            let mut front: Vec<Box<dyn PositionComp>> = Vec::new();
            for (axis, joint) in lcnc {
                let name = p.axes[axis].name.clone();
                front.push(Box::new(LinuxCncPosComp::new(axis, &name, joint)));
            }
            for (axis, f_applied_m) in frozen {
                let t = &self.preset.axes[axis].thermal;
                front.push(Box::new(FrozenThermal {
                    axis,
                    x0_m: t.fixed_end_mm * 1e-3,
                    slope: f_applied_m / ((t.measure_pos_mm - t.fixed_end_mm) * 1e-3),
                }));
            }
            front.append(&mut stack.position);
            stack.position = front;
            m.set_comps(stack);
        }
        let mut d_corr: Vec<Vec<f64>> = vec![Vec::with_capacity(self.steps as usize); axes.len()];
        let mut d_err: Vec<Vec<f64>> = vec![Vec::with_capacity(self.steps as usize); axes.len()];
        for k in 0..self.steps as usize {
            m.step();
            for (j, &i) in axes.iter().enumerate() {
                let a = &m.axes[i];
                d_corr[j].push((a.cmd_m - a.cmd_raw_m) * 1e6 - self.corr_um[i][k]);
                d_err[j].push((a.pos_m - a.cmd_raw_m) * 1e6 - self.err_um[i][k]);
            }
        }
        let mut out = ErrFigures {
            method: self.describe(),
            correction_max_um: 0.0,
            correction_rms_um: Some(0.0),
            position_error_max_um: Some(0.0),
            constant_offset_um: 0.0,
        };
        let mut rms_sum = 0.0;
        let mut rms_n = 0usize;
        for j in 0..axes.len() {
            let off = if remove_offset {
                d_corr[j].last().copied().unwrap_or(0.0)
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
                d_corr[j]
                    .iter()
                    .position(|d| (d - off).abs() <= 1e-6)
                    .unwrap_or(0)
            } else {
                0
            };
            for (dc, de) in d_corr[j].iter().zip(&d_err[j]).skip(start) {
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
        Ok(out)
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
        files: Vec::new(),
        simulation: sim.describe(),
        entries,
    })
}

// ---- entries several targets share ----------------------------------------------------

/// "axes[x].backlash.plus_to_minus = distance (N = 4, B = 500 µm)" and the like.
pub(crate) fn direction_text(d: &crate::comp::backlash::DirectionParams) -> String {
    use crate::comp::backlash::OutputMode;
    match d.mode {
        OutputMode::Lump => "lump".into(),
        OutputMode::Distance => format!("distance (N = {}, B = {} µm)", d.parts_n, d.step_b_um),
        OutputMode::Time => format!("time (M = {} cycles)", d.cycles_m),
        OutputMode::Function => format!(
            "function of {:?} ({} points)",
            d.function_basis,
            d.function.len()
        )
        .to_lowercase(),
    }
}

/// Backlash output modes the target applies as one step at the reversal.
pub(crate) fn backlash_modes_as_lump(ctx: &Ctx, i: usize, control: &str) -> Vec<Pending> {
    use crate::comp::backlash::OutputMode;
    let a = &ctx.preset.axes[i];
    let b = &a.backlash;
    if !b.enabled {
        return vec![];
    }
    let mut out = Vec::new();
    let lump = BacklashParams {
        plus_to_minus: crate::comp::backlash::DirectionParams {
            mode: OutputMode::Lump,
            ..b.plus_to_minus.clone()
        },
        minus_to_plus: crate::comp::backlash::DirectionParams {
            mode: OutputMode::Lump,
            ..b.minus_to_plus.clone()
        },
        ..b.clone()
    };
    for (name, d) in [
        ("plus_to_minus", &b.plus_to_minus),
        ("minus_to_plus", &b.minus_to_plus),
    ] {
        let setting = format!(
            "axes[{}].backlash.{name}.mode = {}",
            a.name,
            direction_text(d)
        );
        if d.mode == OutputMode::Lump {
            out.push(Pending::mapped(
                setting,
                "(the amount above)",
                &format!("{control} outputs the backlash amount in one step at the reversal, as lump does"),
            ));
        } else {
            out.push(
                Pending::not_representable(
                    setting,
                    &format!("{control} has no per-direction spreading of the backlash correction; nearest: the whole amount at the reversal (lump, both directions)"),
                )
                .sim(
                    vec![Change::Backlash {
                        axis: i,
                        params: Some(lump.clone()),
                    }],
                    vec![i],
                    false,
                ),
            );
        }
    }
    out
}

/// A quadrant compensation the target cannot carry: omitted, and simulated without it.
pub(crate) fn quadrant_omitted(ctx: &Ctx, i: usize, why: &str) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    if !a.quadrant.enabled {
        return vec![];
    }
    let q = &a.quadrant;
    vec![
        Pending::not_representable(
            format!(
                "axes[{}].quadrant (adaptive = {}, inject {:?}, M0 = {} / T0 = {} ms, P0 = {} mm)",
                a.name,
                q.adaptive,
                q.inject,
                match q.inject {
                    crate::comp::quadrant::Injection::Torque => format!("{} N·m", q.m0_torque_nm),
                    crate::comp::quadrant::Injection::Velocity =>
                        format!("{} mm/s", q.m0_vel_mm_per_s),
                    crate::comp::quadrant::Injection::Position => format!("{} µm", q.m0_pos_um),
                },
                q.t0_ms,
                q.p0_mm
            ),
            &format!("{why}; nearest: none (omitted)"),
        )
        .sim(
            vec![Change::Quadrant {
                axis: i,
                params: None,
            }],
            vec![i],
            false,
        ),
    ]
}

/// A thermal correction the target cannot carry as a model.
pub(crate) fn thermal_omitted(ctx: &Ctx, i: usize, why: &str) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    if !a.thermal.enabled {
        return vec![];
    }
    vec![
        Pending::not_representable(
            thermal_setting(a),
            &format!("{why}; nearest: none (omitted)"),
        )
        .sim(
            vec![Change::Thermal {
                axis: i,
                frozen: false,
            }],
            vec![i],
            false,
        ),
    ]
}

pub(crate) fn thermal_setting(a: &crate::preset::AxisParams) -> String {
    let t = &a.thermal;
    format!(
        "axes[{}].thermal (source {:?}, E = a + k·|F| with a = {}, k = {}/µm, judgement {:?}, x₀ = {} mm, x_m = {} mm)",
        a.name, t.source, t.a, t.k_per_um, t.judgement, t.fixed_end_mm, t.measure_pos_mm
    )
}

/// Cross tables: the ones `keep` says the target carries are mapped by the caller; the rest
/// are reported omitted, simulated with only the kept ones.
pub(crate) fn cross_omitted(ctx: &Ctx, keep: &[bool], why: &str) -> Vec<Pending> {
    ctx.preset
        .cross
        .iter()
        .enumerate()
        .filter(|(i, t)| t.enabled && !keep.get(*i).copied().unwrap_or(false))
        .map(|(i, t)| {
            let comp = ctx
                .preset
                .axes
                .iter()
                .position(|a| a.name == t.comp_axis)
                .unwrap_or(0);
            // The error this table's omission alone introduces: every other table as in
            // the preset.
            let others: Vec<CrossTable> = ctx
                .preset
                .cross
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, t)| t.clone())
                .collect();
            Pending::not_representable(
                cross_setting(i, t),
                &format!("{why}; nearest: none (omitted)"),
            )
            .sim(vec![Change::Cross { tables: others }], vec![comp], false)
        })
        .collect()
}

pub(crate) fn cross_setting(i: usize, t: &CrossTable) -> String {
    format!(
        "cross[{i}] ({} = f({}), {} points {}…{} mm)",
        t.comp_axis,
        t.base_axis,
        t.points.len(),
        t.points.first().map_or(0.0, |p| p.0),
        t.points.last().map_or(0.0, |p| p.0)
    )
}

/// The pitch table entry: derived from the measured lead error, residual evaluated.
pub(crate) fn pitch_entry(
    ctx: &Ctx,
    i: usize,
    table: &super::PitchTable,
    target: String,
) -> Pending {
    let a = &ctx.preset.axes[i];
    let l = &a.lead_error;
    let (lo, hi) = ctx.axes[i].travel_mm;
    let setting = format!(
        "axes[{}].lead_error (amplitude {} µm, period {} mm, cumulative {} µm/m, table {} points)",
        a.name,
        l.amplitude_um,
        l.period_mm,
        l.cumulative_um_per_m,
        l.table.len()
    );
    let note = format!(
        "The measured lead error is a property of the screw, which axisbench's NC does not compensate; every control compensates it with a pitch-error table, so the export writes the table that cancels it (correction = −error) at {} points over the travel {lo}…{hi} mm{} (the scenario's travel and the measured table; outside it the end values are held)",
        table.points.len(),
        if table.equidistant {
            ", equidistant"
        } else {
            ""
        }
    );
    let status = if table.residual_um <= 1e-9 {
        Status::Derived
    } else {
        Status::Approximated
    };
    let mut p = Pending::new(setting, status, target).note(&note);
    p = p.evaluated(ErrFigures {
        method: format!(
            "evaluated along {lo}…{hi} mm: lead error + table correction, linear interpolation between table points"
        ),
        correction_max_um: table.residual_um,
        correction_rms_um: None,
        position_error_max_um: None,
        constant_offset_um: 0.0,
    });
    p
}

/// Servo gains: the drive's, never in the NC data a compensation export writes.
pub(crate) fn servo_entries(ctx: &Ctx, i: usize, where_: &str) -> Vec<Pending> {
    let a = &ctx.preset.axes[i];
    let s = &a.servo;
    vec![Pending::not_representable(
        format!(
            "axes[{}].servo (Kp = {}/s, Kv = {} N·s/m, Ki = {}/s, vff = {}, aff = {})",
            a.name, s.kp_per_s, s.kv_n_s_per_m, s.ki_per_s, s.vff, s.aff
        ),
        &format!(
            "the loop gains belong to {where_}, which this export does not write; they set the following-error limits derived above"
        ),
    )]
}
