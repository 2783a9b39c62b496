//! The machine: NC channels → position compensations → amplifier (+ servo compensations) →
//! plant → structure (crossbeam sag) → trace, stepped once per T3.
//!
//! Timing, per T3 step k:
//! - at every T2 boundary (k mod n23 = 0) each channel produces the next T2 of commands
//!   (normal: one position at the end of the period, which the amplifier subdivides
//!   linearly into n23 T3 steps; direct: a batch of n23 T3 samples). The position
//!   compensations run on what is generated: once per T2 in normal mode, once per T3 sample
//!   when any channel is in direct mode;
//! - the amplifier of each axis then runs its T3 loop on the compensated command;
//! - the plant advances by T3, the beam sag follows the X positions of the tool posts;
//! - the trace records the sample.

use crate::comp::{CompStack, PosCompCtx, ServoComp};
use crate::drive::{AxisLoop, LoopInput, Sample, SegmentAcc, T2Block};
use crate::nc::Channel;
use crate::nc::program::{self, ProgramError};
use crate::plant::{Beam, Start};
use crate::preset::{FieldError, LoadedPreset, Mode, PosSource, Preset, PresetError};
use crate::trace::{AxisSignal, Prefault, Trace};
use crate::units::mm_to_m;

/// Why a machine could not be built or changed.
#[derive(Debug, thiserror::Error)]
pub enum MachineError {
    /// The preset is invalid.
    #[error(transparent)]
    Preset(#[from] PresetError),
    /// A program does not parse or compile.
    #[error(transparent)]
    Program(#[from] ProgramError),
    /// The structure (axes, channels, programs) does not fit.
    #[error("{0}")]
    Structure(String),
    /// An argument out of its range (a measuring interval, a time).
    #[error("{0}")]
    Argument(String),
    /// The model left every physical range: the settings are the likely cause.
    #[error("the model diverged at t = {t_s:.4} s: axis {axis} {what}; check {hint}")]
    Diverged {
        /// Machine time, s.
        t_s: f64,
        /// The axis.
        axis: String,
        /// What left its range.
        what: String,
        /// The fields most likely to blame.
        hint: String,
    },
    /// The recorded trace grew past its memory limit.
    #[error(
        "the trace reached {mib:.0} MiB at t = {t_s:.1} s ({rows} rows of {cols} columns), the limit is {limit_mib:.0} MiB: record every n-th sample (--set scenario.trace_every=N) or shorten the run"
    )]
    TraceTooLarge {
        /// Machine time, s.
        t_s: f64,
        /// Rows so far.
        rows: usize,
        /// Columns.
        cols: usize,
        /// Size so far, MiB.
        mib: f64,
        /// The limit, MiB.
        limit_mib: f64,
    },
}

/// Default memory limit of a recorded trace: with the model and a CSV writer it keeps a
/// run well inside 2 GB.
pub const MAX_TRACE_BYTES: usize = 1 << 30;
/// Beyond this position (m) or speed (m/s) no feed axis can be: the loop has diverged.
const DIVERGED_POS_M: f64 = 1e3;
/// See [`DIVERGED_POS_M`].
const DIVERGED_VEL_MPS: f64 = 1e3;

/// Every check a preset must pass before a model runs on it: the data rules of
/// [`Preset::validate`] and, once the numbers are sound, the closed-loop stability of each
/// axis (which needs the model, so it cannot live in the data layer).
pub fn check(p: &Preset) -> Vec<FieldError> {
    let mut errors = p.validate();
    if errors.is_empty() {
        for a in &p.axes {
            if let Err(reason) = crate::drive::check_stability(a, p.timing.t3_s) {
                errors.push(FieldError {
                    path: format!("axes.{}.servo", a.name),
                    reason,
                });
            }
        }
    }
    errors
}

/// [`check`] as a `Result`, naming `file` in the error.
pub fn checked(p: &Preset, file: &str) -> Result<(), PresetError> {
    let errors = check(p);
    if errors.is_empty() {
        Ok(())
    } else {
        Err(PresetError::Invalid {
            file: file.to_owned(),
            errors,
        })
    }
}

/// Per-axis runtime: the axis loop and the command buffer of the current T2 period.
pub struct AxisRt {
    /// The axis name from the preset.
    pub name: String,
    /// The NC channel that drives it.
    pub channel: usize,
    /// Index of this axis inside its channel.
    pub ch_idx: usize,
    /// Amplifier + mechanics + servo-stage compensations.
    pub axis_loop: AxisLoop,
    /// The commands of [`ahead_periods`] T2 periods, one row per T3: raw, compensated,
    /// and the acceleration of the segment each row lies in. Period `i` of a run-ahead
    /// block is at `i·n23`; a single T2 tick writes at 0.
    buf_raw: Vec<f64>,
    buf_comp: Vec<f64>,
    buf_acc: Vec<f64>,
    prev_comp_m: f64,
    /// The per-T2 acceleration feed-forward; its segment end is the latest raw command.
    seg: SegmentAcc,
    /// Command from the NC after the position compensations for the current T3, m.
    cmd_nc_m: f64,
    /// Structural displacement the scale does not see (crossbeam sag), m.
    pub sag_m: f64,
    /// True tool position: plant position plus sag, m.
    pub pos_m: f64,
    /// True position at the start of the latest T3 (what its trace row shows).
    sample_pos_m: f64,
}

impl AxisRt {
    /// The position feedback the amplifier closes its loop on, m.
    pub fn feedback_m(&self) -> f64 {
        self.axis_loop.feedback_m()
    }
    /// Motor torque command of the latest period, N·m.
    pub fn torque_cmd_nm(&self) -> f64 {
        self.axis_loop.sample().servo.force_cmd_n / self.axis_loop.force_per_torque()
    }
    /// Motor torque of the latest period, N·m.
    pub fn torque_nm(&self) -> f64 {
        self.axis_loop.sample().servo.force_n / self.axis_loop.force_per_torque()
    }
    /// The command of the latest period before any compensation, m.
    pub fn cmd_raw_m(&self) -> f64 {
        self.axis_loop.sample().cmd_raw_m
    }
    /// The command the position loop saw in the latest period, m.
    pub fn cmd_m(&self) -> f64 {
        self.axis_loop.sample().cmd_m
    }
    /// The commanded acceleration of the current T2 segment, m/s².
    pub fn acc_cmd_mps2(&self) -> f64 {
        self.seg.acc_mps2()
    }
}

/// Rows the recorder stages before it writes them to the trace's columns.
const STAGE_ROWS: usize = 128;

/// T3 rows the NC may generate ahead of the axes in one block ([`Machine::run_block`]), in
/// whole T2 periods (at least one). A real NC's look-ahead buffer holds far more; 128 rows
/// (16 T2 periods, 16 ms, on default.ron) let each axis loop run that many steps without a
/// break, where the per-block cost is spread thin, and keep the block's buffers in the
/// first-level cache.
const AHEAD_ROWS: usize = 128;

/// T2 periods of [`AHEAD_ROWS`] rows at `n23` T3 periods per T2 (at least one).
fn ahead_periods(n23: usize) -> usize {
    (AHEAD_ROWS / n23.max(1)).max(1)
}

/// Values of one cache line: the most rows a flush holds back.
const LINE_F64: usize = crate::trace::LINE_BYTES / std::mem::size_of::<f64>();

struct Recorder {
    every: u32,
    /// Rows the stage holds: [`STAGE_ROWS`], or one T2 period and a line's worth if that is
    /// longer.
    cap: usize,
    /// Columns of the trace (row length).
    ncols: usize,
    /// Staged rows, column-major: column `c` is `stage[c * cap..][..cap]`, so that a flush
    /// appends each column with one copy.
    stage: Vec<f64>,
    /// Rows in `stage` not yet in the trace.
    staged: usize,
    axis_cols: Vec<usize>,
    temp_cols: Vec<usize>,
    ambient_col: usize,
    mode_cols: Vec<usize>,
    comp_cols: Vec<usize>,
    comp_vals: Vec<f64>,
}

/// The whole simulated machine: NC channels, position compensations, one [`AxisLoop`] per
/// axis, the crossbeam, and the trace.
pub struct Machine {
    /// The preset the machine was built from (with any live edits).
    pub preset: Preset,
    /// The amplifier period T3, s.
    pub t3_s: f64,
    /// T1/T2.
    pub n12: u32,
    /// T2/T3.
    pub n23: u32,
    /// T3 steps done.
    pub k: u64,
    /// k mod n23: position inside the current T2 period.
    phase: usize,
    /// Where the current T2 period's rows start in each axis's command buffers.
    buf_at: usize,
    /// (j + 1)/n23 for j in 0..n23: where each T3 lies on the amplifier's interpolation.
    frac: Vec<f64>,
    /// The NC channels, one per program.
    pub channels: Vec<Channel>,
    /// The axes, in preset order.
    pub axes: Vec<AxisRt>,
    beam: Option<Beam>,
    /// The position-stage compensations (the servo-stage ones live in each axis loop).
    comps: CompStack,
    comp_counts: Vec<usize>,
    plc_next: usize,
    ch_target: Vec<Vec<f64>>,
    ch_batch: Vec<Vec<f64>>,
    ch_mode: Vec<Mode>,
    comp_cmd: Vec<f64>,
    comp_prev: Vec<f64>,
    comp_out: Vec<f64>,
    comp_fb: Vec<f64>,
    comp_temp: Vec<f64>,
    x_pos: Vec<f64>,
    /// The recorded trace (empty while recording is off).
    pub trace: Trace,
    rec: Option<Recorder>,
    /// Inside [`Machine::run`] / [`Machine::run_steps`]: trace rows may wait in the stage.
    bulk: bool,
    /// Faults in the reserved trace memory beside the model (see [`Prefault`]).
    prefault: Option<Prefault>,
    end_k: Option<u64>,
}

impl Machine {
    /// Builds a machine from a loaded preset, reading its program files.
    pub fn from_loaded(lp: &LoadedPreset) -> Result<Machine, MachineError> {
        Machine::new(&lp.preset, &lp.programs()?)
    }

    /// Builds a machine from a preset and the text of each channel's program
    /// (`(file name for errors, text)`).
    pub fn new(preset: &Preset, programs: &[(String, String)]) -> Result<Machine, MachineError> {
        checked(preset, &preset.name)?;
        if programs.len() != preset.scenario.programs.len() {
            return Err(MachineError::Structure(format!(
                "{} programs given, the preset has {} channels",
                programs.len(),
                preset.scenario.programs.len()
            )));
        }
        let t = &preset.timing;
        let (n12, n23) = match (
            crate::preset::ratio(t.t1_s, t.t2_s),
            crate::preset::ratio(t.t2_s, t.t3_s),
        ) {
            (Some(a), Some(b)) => (a, b),
            _ => return Err(MachineError::Structure("timing ratios".into())),
        };
        let channels = build_channels(preset, programs, n12, n23)?;
        let axes: Vec<AxisRt> = preset
            .axes
            .iter()
            .map(|a| new_axis(preset, a, n23 as usize, mm_to_m(a.initial_pos_mm), vec![]))
            .collect();
        let beam = Beam::new(&preset.crossbeam, |n| axes.iter().position(|a| a.name == n));
        let n_ax = axes.len();
        let ch_sizes: Vec<usize> = (0..channels.len())
            .map(|c| axes.iter().filter(|a| a.channel == c).count())
            .collect();
        let mut m = Machine {
            preset: preset.clone(),
            t3_s: t.t3_s,
            n12,
            n23,
            k: 0,
            phase: 0,
            buf_at: 0,
            frac: (1..=n23).map(|j| j as f64 / n23 as f64).collect(),
            ch_target: ch_sizes.iter().map(|&n| vec![0.0; n]).collect(),
            ch_batch: ch_sizes
                .iter()
                .map(|&n| vec![0.0; n * n23 as usize])
                .collect(),
            ch_mode: vec![preset.nc.initial_mode; channels.len()],
            channels,
            axes,
            beam,
            comps: CompStack::default(),
            comp_counts: vec![],
            plc_next: 0,
            comp_cmd: vec![0.0; n_ax],
            comp_prev: vec![0.0; n_ax],
            comp_out: vec![0.0; n_ax],
            comp_fb: vec![0.0; n_ax],
            comp_temp: vec![0.0; n_ax],
            x_pos: vec![0.0; n_ax],
            trace: Trace::new(),
            rec: None,
            bulk: false,
            prefault: None,
            end_k: None,
        };
        for (i, a) in m.axes.iter().enumerate() {
            m.comp_prev[i] = a.seg.end_m();
        }
        m.update_sag();
        m.set_comps(crate::comp::build(preset));
        m.set_recording(true);
        Ok(m)
    }

    /// Installs the compensations (replaces any installed before) and re-lays the trace.
    /// Servo-stage compensations go to the axis loop of their axis. Before the first step,
    /// the axes are placed at the corrected position (see `start_corrected`).
    pub fn set_comps(&mut self, comps: CompStack) {
        self.install(comps);
        if self.k == 0 {
            self.start_corrected();
        }
    }

    fn install(&mut self, comps: CompStack) {
        let CompStack { position, servo } = comps;
        let mut per_axis: Vec<Vec<Box<dyn ServoComp>>> =
            (0..self.axes.len()).map(|_| Vec::new()).collect();
        for c in servo {
            if let Some(v) = per_axis.get_mut(c.axis()) {
                v.push(c);
            }
        }
        for (a, v) in self.axes.iter_mut().zip(per_axis) {
            a.axis_loop.set_comps(v);
        }
        self.comps = CompStack {
            position,
            servo: vec![],
        };
        self.comp_counts = self.comp_signal_counts();
        let on = self.rec.is_some();
        self.set_recording(on);
    }

    fn comp_signal_counts(&self) -> Vec<usize> {
        self.comps
            .position
            .iter()
            .map(|c| c.signals().len())
            .chain(
                self.axes
                    .iter()
                    .flat_map(|a| a.axis_loop.comps().iter().map(|c| c.signals().len())),
            )
            .collect()
    }

    /// At power-up the position corrections are already in force and the axes stand at rest
    /// at the corrected position, as on a real control; without this every table would be
    /// switched on as a step at t = 0.
    fn start_corrected(&mut self) {
        let n23 = self.n23 as usize;
        load_commands(&self.axes, &mut self.comp_cmd, &mut self.comp_out, |a| {
            a.seg.end_m()
        });
        self.read_comp_sensors();
        self.comp_prev.clone_from(&self.comp_cmd);
        self.run_position_comps(0.0, self.t3_s * n23 as f64);
        for (i, a) in self.axes.iter_mut().enumerate() {
            let off = self.comp_out[i];
            if off == 0.0 {
                continue;
            }
            let params = &self.preset.axes[i];
            let raw = a.seg.end_m();
            let x = raw + off;
            let start = Start::at_rest(params.servo.feedback.into(), x);
            a.axis_loop.restart(params, start, raw, x);
            a.prev_comp_m = x;
            a.buf_comp.iter_mut().for_each(|b| *b = x);
            a.cmd_nc_m = x;
        }
        self.update_sag();
    }

    /// Live edit: takes the parameters of `p` from the next control period on, keeping the
    /// machine's state (positions, temperatures, pending backlash parts, quadrant N…). The
    /// structure (axes, channels, programs) must be the same; a structural change needs a new
    /// machine. The set of installed compensations is rebuilt only when one is switched on or
    /// off; otherwise each keeps its state and takes the new parameters.
    pub fn apply_params(&mut self, p: &Preset) -> Result<(), MachineError> {
        checked(p, &p.name)?;
        let same = p.axes.len() == self.preset.axes.len()
            && p.axes
                .iter()
                .zip(&self.preset.axes)
                .all(|(a, b)| a.name == b.name && a.channel == b.channel && a.letter == b.letter)
            && p.scenario.programs.len() == self.preset.scenario.programs.len()
            && p.timing == self.preset.timing;
        if !same {
            return Err(MachineError::Structure(
                "axes, channels or periods changed: reset the machine to apply".into(),
            ));
        }
        for (a, params) in self.axes.iter_mut().zip(&p.axes) {
            a.axis_loop.retune(params);
        }
        for ch in &mut self.channels {
            ch.set_accdec(p.nc.accdec.clone());
        }
        self.beam = Beam::new(&p.crossbeam, |n| self.axes.iter().position(|a| a.name == n));
        let rebuild =
            p.enabled_comps() != self.preset.enabled_comps() || p.cross != self.preset.cross;
        let old = std::mem::replace(&mut self.preset, p.clone());
        if old.scenario.plc_events != p.scenario.plc_events {
            let t = self.t_s();
            self.plc_next = p
                .scenario
                .plc_events
                .iter()
                .take_while(|e| e.t_s <= t)
                .count();
        }
        if rebuild {
            self.install(crate::comp::build(p));
        } else {
            self.retune_comps(p);
        }
        Ok(())
    }

    /// Hands new parameters to each installed compensation, keeping its state.
    fn retune_comps(&mut self, p: &Preset) {
        for (i, a) in p.axes.iter().enumerate() {
            for b in self.find_comp_mut::<crate::comp::backlash::Backlash>() {
                if b.axis() == i {
                    b.p = a.backlash.clone();
                }
            }
            for q in self.find_comp_mut::<crate::comp::quadrant::Quadrant>() {
                if ServoComp::axis(q) == i {
                    q.p = a.quadrant.clone();
                }
            }
            for t in self.find_comp_mut::<crate::comp::thermal::Thermal>() {
                if t.axis() == i {
                    t.retune(a.thermal.clone());
                }
            }
        }
    }

    /// A PLC mode request now (the GUI's PLC switch), for `channel`.
    pub fn plc_request(&mut self, channel: usize, mode: Mode) {
        if let Some(ch) = self.channels.get_mut(channel) {
            ch.request_mode(mode);
        }
    }

    /// The installed position-stage compensations.
    pub fn position_comps(&self) -> &[Box<dyn crate::comp::PositionComp>] {
        &self.comps.position
    }

    /// Every installed compensation of type `T`: position stage first, then each axis's
    /// servo stage.
    pub fn find_comp<T: 'static>(&self) -> impl Iterator<Item = &T> {
        self.comps.find::<T>().chain(self.axes.iter().flat_map(|a| {
            a.axis_loop
                .comps()
                .iter()
                .filter_map(|c| c.as_any().downcast_ref::<T>())
        }))
    }

    /// [`Machine::find_comp`], mutable.
    pub fn find_comp_mut<T: 'static>(&mut self) -> impl Iterator<Item = &mut T> {
        self.comps
            .find_mut::<T>()
            .chain(self.axes.iter_mut().flat_map(|a| {
                a.axis_loop
                    .comps_mut()
                    .iter_mut()
                    .filter_map(|c| c.as_any_mut().downcast_mut::<T>())
            }))
    }

    /// Turns trace recording on (a fresh trace) or off (benchmarks, batch fitting).
    pub fn set_recording(&mut self, on: bool) {
        self.prefault = None;
        self.trace = Trace::new();
        if !on {
            self.rec = None;
            return;
        }
        let tr = &mut self.trace;
        tr.meta.push(("source".into(), "simulated".into()));
        tr.meta.push(("preset".into(), self.preset.name.clone()));
        tr.meta.push(("t3_s".into(), format!("{}", self.t3_s)));
        tr.meta
            .push(("t2_s".into(), format!("{}", self.preset.timing.t2_s)));
        // The simulator's `pos` is the true table position, whatever sensor the real machine
        // of this preset would record; the diagnosis reads this line to compare like with like.
        tr.meta
            .push(("pos_source".into(), PosSource::Load.name().into()));
        if self.k == 0 {
            tr.meta.push(("start".into(), "rest".into()));
        }
        let mut axis_cols = Vec::new();
        for a in &self.axes {
            axis_cols.push(tr.signals.len());
            for s in AxisSignal::RECORDED {
                tr.add_signal(&s.column(&a.name), s.si_unit());
            }
        }
        let temp_cols = self
            .axes
            .iter()
            .map(|a| tr.add_signal(&format!("temp.{}_screw", a.name), "degC"))
            .collect();
        let ambient_col = tr.add_signal("temp.ambient", "degC");
        let mode_cols = (0..self.channels.len())
            .map(|c| {
                if c == 0 {
                    tr.add_signal("mode", "")
                } else {
                    tr.add_signal(&format!("mode.ch{}", c + 1), "")
                }
            })
            .collect();
        let signals = self.comps.position.iter().flat_map(|c| c.signals()).chain(
            self.axes
                .iter()
                .flat_map(|a| a.axis_loop.comps().iter().flat_map(|c| c.signals())),
        );
        let comp_cols: Vec<usize> = signals
            .map(|s| {
                let name = if s.axis.is_empty() {
                    s.signal.clone()
                } else {
                    format!("{}.{}", s.axis, s.signal)
                };
                tr.add_signal(&name, s.quantity.si_unit())
            })
            .collect();
        let ncols = tr.signals.len();
        // Room for one T2 period beside the rows a flush holds back (see `flush_rows`).
        let cap = STAGE_ROWS.max(self.n23 as usize + LINE_F64);
        self.rec = Some(Recorder {
            every: self.preset.scenario.trace_every.max(1),
            cap,
            ncols,
            stage: vec![0.0; cap * ncols],
            staged: 0,
            axis_cols,
            temp_cols,
            ambient_col,
            mode_cols,
            comp_vals: vec![0.0; comp_cols.len()],
            comp_cols,
        });
    }

    /// Machine time at the start of the next step, s.
    pub fn t_s(&self) -> f64 {
        self.k as f64 * self.t3_s
    }

    /// All programs done, filters drained, and the settle time passed (or the fixed
    /// scenario duration reached).
    pub fn done(&self) -> bool {
        self.done_at(self.k)
    }

    /// [`Machine::done`] once `k` steps are done (with the end of the programs as known now).
    fn done_at(&self, k: u64) -> bool {
        match self.preset.scenario.duration_s {
            Some(d) => k as f64 * self.t3_s >= d - 0.5 * self.t3_s,
            None => match self.end_k {
                Some(e) => {
                    k.saturating_sub(e) as f64 * self.t3_s
                        >= self.preset.scenario.settle_s - 0.5 * self.t3_s
                }
                None => false,
            },
        }
    }

    /// Runs until [`Machine::done`] or `max_s` of machine time, whichever is first. Stops
    /// with an error when the model diverges or the trace outgrows its memory limit.
    pub fn run(&mut self, max_s: f64) -> Result<(), MachineError> {
        self.bulk = true;
        let r = self.run_staged(max_s);
        self.bulk = false;
        self.flush_rows(true);
        r
    }

    fn run_staged(&mut self, max_s: f64) -> Result<(), MachineError> {
        let max_k = (max_s / self.t3_s).ceil() as u64;
        // A program-driven run ends when the program does, unknown here: its trace grows.
        if let Some(d) = self.preset.scenario.duration_s {
            let until_k = max_k.min((d / self.t3_s).ceil() as u64);
            self.reserve_rows(until_k.saturating_sub(self.k));
        }
        let check = u64::from(self.n23).max(64);
        let mut next_check = (self.k / check + 1) * check;
        while !self.done() && self.k < max_k {
            self.advance(max_k - self.k, true, check, &mut next_check)?;
        }
        self.health()
    }

    /// Runs `n` T3 steps, with the checks of [`Machine::run`].
    pub fn run_steps(&mut self, n: u64) -> Result<(), MachineError> {
        self.bulk = true;
        let r = self.run_steps_staged(n);
        self.bulk = false;
        self.flush_rows(true);
        r
    }

    fn run_steps_staged(&mut self, n: u64) -> Result<(), MachineError> {
        self.reserve_rows(n);
        let check = u64::from(self.n23).max(64);
        let mut next_check = (self.k / check + 1) * check;
        let end = self.k + n;
        while self.k < end {
            self.advance(end - self.k, false, check, &mut next_check)?;
        }
        self.health()
    }

    /// Takes at most `max_steps` steps: a whole T2 period axis by axis where that is allowed
    /// ([`Machine::block_ready`]), one step otherwise. Checks the health whenever the step
    /// count passes a multiple of `check`. With `until_done` a block ends at the step after
    /// which [`Machine::done`] holds, as single steps would.
    /// `next_check` is the next multiple of `check` (kept by the caller, so the hot loop
    /// divides once per check, not twice per T2 period).
    fn advance(
        &mut self,
        max_steps: u64,
        until_done: bool,
        check: u64,
        next_check: &mut u64,
    ) -> Result<(), MachineError> {
        if self.block_ready() {
            self.run_block(max_steps, until_done);
        } else {
            self.step();
        }
        if self.k >= *next_check {
            *next_check = (self.k / check + 1) * check;
            self.health()?;
        }
        Ok(())
    }

    /// Whether the next T2 period may run axis by axis ([`Machine::run_block`]): at a T2
    /// boundary, with no crossbeam (its sag couples the axes every T3) and, while recording,
    /// no servo-stage compensation (their trace values change every T3; the block records
    /// only what the axis loop hands on).
    fn block_ready(&self) -> bool {
        self.phase == 0
            && self.beam.is_none()
            && (self.rec.is_none() || self.axes.iter().all(|a| a.axis_loop.comps().is_empty()))
    }

    /// Whether the NC may run [`ahead_periods`] T2 periods ahead of the axes in one block:
    /// recording off (a trace row shows the compensations of its own period), and no position
    /// compensation that reads the machine at its tick
    /// ([`crate::comp::PositionComp::reads_machine`]). The NC's own state (programs, interpolation,
    /// acc/dec, modes) never depends on the axes, and PLC requests act only at a tick, so they are
    /// handed over tick by tick.
    fn may_run_ahead(&self) -> bool {
        self.rec.is_none() && self.comps.position.iter().all(|c| !c.reads_machine())
    }

    /// One T2 period (or its first `max_steps` T3 steps) as [`Machine::step`] takes it, or up to
    /// [`ahead_periods`] where the NC may run ahead ([`Machine::may_run_ahead`]), but axis by axis:
    /// the NC generates every period's commands first, and then each axis, whose loop depends on
    /// nothing but its own command buffer, runs all its periods in one tight loop
    /// ([`AxisLoop::run`]) without the per-period dispatch, checks and bookkeeping of
    /// [`Machine::step`]. The NC ticks, the inputs, the steps and the trace rows are the same, bit
    /// for bit (tests `a_staged_run_records_the_trace_that_single_steps_record` and
    /// `the_nc_running_ahead_gives_the_steps_of_single_steps`). PLC requests only latch until the
    /// next T2 tick, so each tick takes those due by its time, and those falling inside the last
    /// period are handed over at its end.
    fn run_block(&mut self, max_steps: u64, until_done: bool) {
        let k0 = self.k;
        let n23 = self.n23 as usize;
        let max_len = usize::try_from(max_steps).unwrap_or(usize::MAX).max(1);
        let periods = if self.may_run_ahead() {
            ahead_periods(n23)
        } else {
            1
        };
        let mut len = 0;
        for i in 0..periods {
            let kt = k0 + len as u64;
            if len >= max_len || (i > 0 && until_done && self.done_at(kt)) {
                break;
            }
            let t = kt as f64 * self.t3_s;
            self.plc_events(t);
            self.tick_t2(t, len);
            self.buf_at = len;
            if self.end_k.is_none() && self.channels.iter().all(Channel::finished) {
                self.end_k = Some(kt + 1);
            }
            let mut n = n23.min(max_len - len);
            if until_done && let Some(s) = (1..n).find(|&s| self.done_at(kt + s as u64)) {
                n = s;
            }
            len += n;
            if n < n23 {
                break;
            }
        }
        if let Some(rec) = &self.rec
            && rec.staged + len > rec.cap
        {
            self.flush_rows(false);
        }
        let t3 = self.t3_s;
        for (i, a) in self.axes.iter_mut().enumerate() {
            let block = T2Block {
                k0,
                t3_s: t3,
                cmd_raw_m: &a.buf_raw[..len],
                cmd_nc_m: &a.buf_comp[..len],
                acc_cmd_mps2: &a.buf_acc[..len],
            };
            let sag = a.sag_m;
            match &mut self.rec {
                None => a.axis_loop.run_quiet_inlined(&block),
                Some(rec) => {
                    let (every, cap, first) = (u64::from(rec.every), rec.cap, rec.staged);
                    let (base, temp_col) = (rec.axis_cols[i], rec.temp_cols[i]);
                    let stage = &mut rec.stage;
                    let mut r = first;
                    // Periods to skip before the next recorded one (k ≡ 0 mod `every`),
                    // counted down instead of a division per period.
                    let mut skip = (every - k0 % every) % every;
                    a.axis_loop.run(
                        &block,
                        #[inline(always)]
                        |_, l| {
                            if skip > 0 {
                                skip -= 1;
                                return;
                            }
                            skip = every - 1;
                            let s = l.sample();
                            let fpt = l.force_per_torque();
                            let vals = recorded_row(s, s.plant.pos_m + sag, fpt);
                            for (c, v) in vals.into_iter().enumerate() {
                                stage[(base + c) * cap + r] = v;
                            }
                            stage[temp_col * cap + r] = l.plant().thermal().temp_c;
                            r += 1;
                        },
                    );
                }
            }
            a.cmd_nc_m = a.buf_comp[len - 1];
            a.sample_pos_m = a.axis_loop.sample().plant.pos_m + sag;
            a.pos_m = a.axis_loop.plant().out().pos_m + sag;
        }
        self.k = k0 + len as u64;
        self.phase = len % n23;
        if len > 1 {
            self.plc_events((self.k - 1) as f64 * t3);
        }
        self.record_block_rows(k0, len);
    }

    /// The columns of a block's rows that do not come from the axis loops: time, ambient,
    /// channel modes, and the position-stage compensations (they step only at the T2 tick).
    /// The axis columns are already in the stage.
    fn record_block_rows(&mut self, k0: u64, len: usize) {
        let Some(rec) = &mut self.rec else { return };
        let every = u64::from(rec.every);
        let ambient = self
            .axes
            .first()
            .map_or(20.0, |a| a.axis_loop.plant().thermal().ambient_c);
        let cap = rec.cap;
        let step = usize::try_from(every).unwrap_or(usize::MAX);
        for (row, k) in (k0.next_multiple_of(every)..k0 + len as u64)
            .step_by(step)
            .enumerate()
        {
            // The position-stage compensations step only at the T2 tick, so their values
            // hold over the block. They are read for the first two rows, as `record` reads
            // them for every row: a sparse value (a thermal measurement) shows on the first
            // recorded row after it and is then spent; the second read is what the rest of
            // the block shows.
            if row < 2 {
                let mut at = 0;
                for (c, &cn) in self.comps.position.iter().zip(&self.comp_counts) {
                    c.values(&mut rec.comp_vals[at..at + cn]);
                    at += cn;
                }
            }
            let (r, stage) = (rec.staged, &mut rec.stage);
            stage[r] = k as f64 * self.t3_s;
            stage[rec.ambient_col * cap + r] = ambient;
            for (ch, &c) in self.channels.iter().zip(&rec.mode_cols) {
                stage[c * cap + r] = ch.mode.as_f64();
            }
            for (&col, &v) in rec.comp_cols.iter().zip(&rec.comp_vals) {
                stage[col * cap + r] = v;
            }
            rec.staged += 1;
        }
    }

    /// Makes room for the rows of the next `steps` T3 steps (within the trace's memory
    /// limit), so that recording never copies the trace to grow it.
    fn reserve_rows(&mut self, steps: u64) {
        let Some(rec) = &self.rec else { return };
        let cols = self.trace.signals.len().max(1);
        let room =
            (MAX_TRACE_BYTES / std::mem::size_of::<f64>() / cols).saturating_sub(self.trace.len());
        let rows = usize::try_from(steps / u64::from(rec.every) + 1)
            .unwrap_or(usize::MAX)
            .min(room);
        // Stop the previous thread before the columns can move.
        self.prefault = None;
        self.trace.reserve_rows(rows);
        self.prefault = Prefault::start(self.trace.spare_ranges());
    }

    /// Bytes the recorded trace holds.
    pub fn trace_bytes(&self) -> usize {
        self.trace.signals.len() * self.trace.len() * std::mem::size_of::<f64>()
    }

    /// Whether the state is still physical and the trace within its limit.
    pub fn health(&self) -> Result<(), MachineError> {
        for a in &self.axes {
            let o = a.axis_loop.plant().out();
            let bad = if !(o.pos_m.is_finite() && o.motor_pos_m.is_finite()) {
                Some("position is no longer a finite number".to_owned())
            } else if o.pos_m.abs() > DIVERGED_POS_M {
                Some(format!("is {:.3e} m from zero", o.pos_m))
            } else if !o.vel_mps.is_finite() || o.vel_mps.abs() > DIVERGED_VEL_MPS {
                Some(format!("moves at {:.3e} m/s", o.vel_mps))
            } else {
                None
            };
            if let Some(what) = bad {
                return Err(MachineError::Diverged {
                    t_s: self.t_s(),
                    axis: a.name.clone(),
                    what,
                    hint: format!(
                        "axes.{}.servo (kp_per_s, kv_n_s_per_m, ki_per_s) against axes.{0}.drive (masses, lead) and timing.t3_s",
                        a.name
                    ),
                });
            }
        }
        let bytes = self.trace_bytes();
        if bytes > MAX_TRACE_BYTES {
            return Err(MachineError::TraceTooLarge {
                t_s: self.t_s(),
                rows: self.trace.len(),
                cols: self.trace.signals.len(),
                mib: bytes as f64 / (1u64 << 20) as f64,
                limit_mib: MAX_TRACE_BYTES as f64 / (1u64 << 20) as f64,
            });
        }
        Ok(())
    }

    /// One T3 period of the whole machine.
    pub fn step(&mut self) {
        let t = self.t_s();
        self.plc_events(t);
        let j = self.phase;
        if j == 0 {
            self.tick_t2(t, 0);
            self.buf_at = 0;
        }
        let row = self.buf_at + j;
        for a in &mut self.axes {
            a.cmd_nc_m = a.buf_comp[row];
            a.sample_pos_m = a.pos_m;
            a.axis_loop.step(&LoopInput {
                t_s: t,
                cmd_raw_m: a.buf_raw[row],
                cmd_nc_m: a.cmd_nc_m,
                acc_cmd_mps2: a.buf_acc[row],
                ext_force_n: 0.0,
            });
            a.pos_m = a.axis_loop.plant().out().pos_m + a.sag_m;
        }
        if self.beam.is_some() {
            self.update_sag();
        }
        self.k += 1;
        self.phase = if j + 1 == self.n23 as usize { 0 } else { j + 1 };
        if j == 0 && self.end_k.is_none() && self.channels.iter().all(Channel::finished) {
            self.end_k = Some(self.k);
        }
        if self.rec.is_some() {
            self.record();
        }
    }

    /// Hands the PLC mode requests due by `t` to their channels.
    fn plc_events(&mut self, t: f64) {
        while let Some(ev) = self.preset.scenario.plc_events.get(self.plc_next) {
            if ev.t_s > t + 0.5 * self.t3_s {
                break;
            }
            if let Some(ch) = self.channels.get_mut(ev.channel) {
                ch.request_mode(ev.mode);
            }
            self.plc_next += 1;
        }
    }

    fn update_sag(&mut self) {
        if let Some(beam) = &self.beam {
            for (i, a) in self.axes.iter().enumerate() {
                self.x_pos[i] = a.axis_loop.plant().out().pos_m;
            }
            let mut sag = [0.0; 2];
            beam.sag_m(&self.x_pos, &mut sag);
            for (p, s) in beam.posts.iter().zip(sag) {
                self.axes[p.z_axis].sag_m = s;
            }
        }
        for a in &mut self.axes {
            a.pos_m = a.axis_loop.plant().out().pos_m + a.sag_m;
        }
    }

    /// Generates the next T2 of commands in every channel, runs the position compensations
    /// on them, and writes the period's rows at `at` in each axis's command buffers.
    fn tick_t2(&mut self, t: f64, at: usize) {
        let mut any_direct = false;
        let outputs = self.ch_target.iter_mut().zip(&mut self.ch_batch);
        for ((ch, mode), (target, batch)) in
            self.channels.iter_mut().zip(&mut self.ch_mode).zip(outputs)
        {
            *mode = ch.tick_t2(target, batch);
            any_direct |= *mode == Mode::Direct;
        }
        self.read_comp_sensors();
        let n23 = self.n23 as usize;
        if any_direct {
            self.generate_direct(t, at);
        } else {
            self.generate_normal(t, at);
        }
        let last = at + n23 - 1;
        for a in &mut self.axes {
            let acc = a.seg.next_segment(a.buf_raw[last]);
            a.buf_acc[at..=last].fill(acc);
            a.prev_comp_m = a.buf_comp[last];
        }
    }

    /// The sensor readings the position compensations see: feedback and screw temperature
    /// per axis.
    fn read_comp_sensors(&mut self) {
        let readings = self.comp_fb.iter_mut().zip(&mut self.comp_temp);
        for (a, (fb, temp)) in self.axes.iter().zip(readings) {
            *fb = a.feedback_m();
            *temp = a.axis_loop.plant().thermal().temp_c;
        }
    }

    /// Every channel in normal mode: one command per axis at the end of the T2 period, which
    /// the amplifier reaches along a straight line, one point per T3.
    #[inline]
    fn generate_normal(&mut self, t: f64, at: usize) {
        let n23 = self.n23 as usize;
        let target = &self.ch_target;
        load_commands(&self.axes, &mut self.comp_cmd, &mut self.comp_out, |a| {
            target[a.channel][a.ch_idx]
        });
        self.run_position_comps(t, self.t3_s * n23 as f64);
        let frac = &self.frac[..n23];
        let gens = self.comp_cmd.iter().zip(&self.comp_out);
        for (a, (&raw, &out)) in self.axes.iter_mut().zip(gens) {
            ramp(&mut a.buf_raw[at..at + n23], a.seg.end_m(), raw, frac);
            ramp(
                &mut a.buf_comp[at..at + n23],
                a.prev_comp_m,
                raw + out,
                frac,
            );
        }
        std::mem::swap(&mut self.comp_prev, &mut self.comp_cmd);
    }

    /// A channel in direct mode: one command per axis every T3, each compensated on its own.
    /// An axis of a channel in normal mode meanwhile takes the points of its straight line.
    fn generate_direct(&mut self, t: f64, at: usize) {
        let n23 = self.n23 as usize;
        for g in 0..n23 {
            let (mode, batch, target, f) =
                (&self.ch_mode, &self.ch_batch, &self.ch_target, self.frac[g]);
            load_commands(
                &self.axes,
                &mut self.comp_cmd,
                &mut self.comp_out,
                |a| match mode[a.channel] {
                    Mode::Direct => batch[a.channel][a.ch_idx * n23 + g],
                    Mode::Normal => {
                        let prev_raw = a.seg.end_m();
                        prev_raw + (target[a.channel][a.ch_idx] - prev_raw) * f
                    }
                },
            );
            self.run_position_comps(t + g as f64 * self.t3_s, self.t3_s);
            let gens = self.comp_cmd.iter().zip(&self.comp_out);
            for (a, (&raw, &out)) in self.axes.iter_mut().zip(gens) {
                a.buf_raw[at + g] = raw;
                a.buf_comp[at + g] = raw + out;
            }
            // comp_cmd is written afresh for every axis before it is read again.
            std::mem::swap(&mut self.comp_prev, &mut self.comp_cmd);
        }
    }

    /// One position-command generation: every position compensation adds its correction to
    /// `comp_out` (zeros on entry) for the command in `comp_cmd`, and any measurement asked
    /// for is taken.
    #[inline]
    fn run_position_comps(&mut self, t_s: f64, period_s: f64) {
        let ctx = PosCompCtx {
            t_s,
            period_s,
            cmd_m: &self.comp_cmd,
            prev_cmd_m: &self.comp_prev,
            fb_m: &self.comp_fb,
            temps_c: &self.comp_temp,
        };
        for c in self.comps.position.iter_mut() {
            c.step(&ctx, &mut self.comp_out);
            // A measuring cycle (touch probe on the reference point) reads the real
            // displacement there; only the plant knows it.
            if let Some((axis, x_m)) = c.measurement_request() {
                let real = self.axes[axis]
                    .axis_loop
                    .plant()
                    .thermal()
                    .elongation_m(x_m);
                c.measured(ctx.t_s, real);
            }
        }
    }

    /// Writes the trace row of the step just taken into the recorder's stage; the stage
    /// goes to the trace's columns every [`STAGE_ROWS`] rows inside [`Machine::run`] and
    /// [`Machine::run_steps`], and at once after a single [`Machine::step`].
    fn record(&mut self) {
        let Some(rec) = &mut self.rec else { return };
        if !(self.k - 1).is_multiple_of(rec.every as u64) {
            return;
        }
        let (cap, r) = (rec.cap, rec.staged);
        let stage = &mut rec.stage;
        // The row is the instant t_k at the start of the step just taken.
        stage[r] = (self.k - 1) as f64 * self.t3_s;
        for (a, &base) in self.axes.iter().zip(&rec.axis_cols) {
            let l = &a.axis_loop;
            let vals = recorded_row(l.sample(), a.sample_pos_m, l.force_per_torque());
            for (c, v) in vals.into_iter().enumerate() {
                stage[(base + c) * cap + r] = v;
            }
        }
        for (a, &c) in self.axes.iter().zip(&rec.temp_cols) {
            stage[c * cap + r] = a.axis_loop.plant().thermal().temp_c;
        }
        stage[rec.ambient_col * cap + r] = self
            .axes
            .first()
            .map_or(20.0, |a| a.axis_loop.plant().thermal().ambient_c);
        for (ch, &c) in self.channels.iter().zip(&rec.mode_cols) {
            stage[c * cap + r] = ch.mode.as_f64();
        }
        if !rec.comp_cols.is_empty() {
            let mut at = 0;
            let counts = &self.comp_counts;
            let comps = self
                .comps
                .position
                .iter()
                .map(|c| c as &dyn CompValues)
                .chain(
                    self.axes
                        .iter()
                        .flat_map(|a| a.axis_loop.comps().iter().map(|c| c as &dyn CompValues)),
                );
            for (c, &n) in comps.zip(counts) {
                c.vals(&mut rec.comp_vals[at..at + n]);
                at += n;
            }
            for (&col, &v) in rec.comp_cols.iter().zip(&rec.comp_vals) {
                stage[col * cap + r] = v;
            }
        }
        rec.staged += 1;
        if !self.bulk || rec.staged == rec.cap {
            let whole = !self.bulk;
            self.flush_rows(whole);
        }
    }

    /// Appends the staged rows to the trace's columns, one column at a time: a long run
    /// then writes each column in bursts instead of touching every column every row (the
    /// writes per row went to 21 places in memory, and recording cost three times the model).
    ///
    /// Inside a run (`whole` false) the rows that would end a column inside a cache line
    /// wait in the stage for the next flush (at most seven), so that every flush writes
    /// whole lines: a line the streaming stores fill only in part is first read from memory.
    fn flush_rows(&mut self, whole: bool) {
        let Some(rec) = &mut self.rec else { return };
        let (n, cap, staged) = (rec.ncols, rec.cap, rec.staged);
        let rows = if whole {
            staged
        } else {
            self.trace.line_aligned_rows(staged)
        };
        self.trace.append_staged(&rec.stage[..n * cap], cap, rows);
        if rows < staged {
            for c in 0..n {
                rec.stage
                    .copy_within(c * cap + rows..c * cap + staged, c * cap);
            }
        }
        rec.staged = staged - rows;
    }
}

/// The NC channels, one per program, with their programs parsed and compiled.
fn build_channels(
    preset: &Preset,
    programs: &[(String, String)],
    n12: u32,
    n23: u32,
) -> Result<Vec<Channel>, MachineError> {
    let t = &preset.timing;
    let mut channels = Vec::new();
    for (ci, (file, text)) in programs.iter().enumerate() {
        let ch_axes: Vec<&crate::preset::AxisParams> =
            preset.axes.iter().filter(|a| a.channel == ci).collect();
        let letters: Vec<char> = ch_axes.iter().map(|a| a.letter).collect();
        let start: Vec<f64> = ch_axes.iter().map(|a| mm_to_m(a.initial_pos_mm)).collect();
        let blocks = program::parse(text, file)?;
        let ops = program::compile(
            &blocks,
            &letters,
            &start,
            preset.nc.default_feed_mm_per_min,
            preset.nc.rapid_mm_per_min,
            file,
        )?;
        channels.push(Channel::new(
            ops,
            &start,
            preset.nc.initial_mode,
            preset.nc.accdec.clone(),
            crate::nc::ChannelTiming {
                t1_s: t.t1_s,
                t3_s: t.t3_s,
                n12,
                n23,
            },
        ));
    }
    Ok(channels)
}

/// One axis at rest at the raw command `x0_m`, its feedback sensor reading `x0_m`.
fn new_axis(
    preset: &Preset,
    a: &crate::preset::AxisParams,
    n23: usize,
    x0_m: f64,
    comps: Vec<Box<dyn ServoComp>>,
) -> AxisRt {
    let t3 = preset.timing.t3_s;
    let ch_idx = preset
        .axes
        .iter()
        .filter(|b| b.channel == a.channel)
        .position(|b| b.name == a.name)
        .unwrap_or(0);
    let start = Start::at_rest(a.servo.feedback.into(), x0_m);
    let axis_loop = AxisLoop::new(a, t3, start, x0_m, x0_m, comps);
    let pos = axis_loop.plant().out().pos_m;
    AxisRt {
        name: a.name.clone(),
        channel: a.channel,
        ch_idx,
        axis_loop,
        buf_raw: vec![x0_m; n23 * ahead_periods(n23)],
        buf_comp: vec![x0_m; n23 * ahead_periods(n23)],
        buf_acc: vec![0.0; n23 * ahead_periods(n23)],
        prev_comp_m: x0_m,
        seg: SegmentAcc::new(preset.timing.t2_s, x0_m),
        cmd_nc_m: x0_m,
        sag_m: 0.0,
        pos_m: pos,
        sample_pos_m: pos,
    }
}

/// Hands the position compensations one command per axis, `cmd_of(axis)`, in `cmd`, with their
/// corrections in `out` cleared (they add into it).
#[inline(always)]
fn load_commands(
    axes: &[AxisRt],
    cmd: &mut [f64],
    out: &mut [f64],
    cmd_of: impl Fn(&AxisRt) -> f64,
) {
    for ((a, c), o) in axes.iter().zip(cmd).zip(out) {
        *c = cmd_of(a);
        *o = 0.0;
    }
}

/// Fills `buf` with the straight line from `from` (the point before it) to `to`: point `j`
/// lies at `frac[j]` of the way, and the last point is `to` exactly.
#[inline(always)]
fn ramp(buf: &mut [f64], from: f64, to: f64, frac: &[f64]) {
    for (b, &f) in buf.iter_mut().zip(frac) {
        *b = from + (to - from) * f;
    }
    if let Some(last) = buf.last_mut() {
        *last = to;
    }
}

/// An axis's trace row, in [`AxisSignal::RECORDED`] order. Each element names its signal by a
/// constant index, so the `match` in [`recorded_value`] folds away and the row is sixteen
/// plain expressions (a `map` over the list kept a jump table per value: a third of the cost
/// of recording).
#[inline(always)]
fn recorded_row(s: &Sample, sample_pos_m: f64, fpt: f64) -> [f64; AxisSignal::RECORDED.len()] {
    let v = |i: usize| recorded_value(AxisSignal::RECORDED[i], s, sample_pos_m, fpt);
    [
        v(0),
        v(1),
        v(2),
        v(3),
        v(4),
        v(5),
        v(6),
        v(7),
        v(8),
        v(9),
        v(10),
        v(11),
        v(12),
        v(13),
        v(14),
        v(15),
    ]
}

/// The value of `sig` in an axis's trace row: `s` is the row its loop handed on,
/// `sample_pos_m` the true tool position at the start of the period (plant plus sag), `fpt`
/// the loop's force per torque. SI.
#[inline(always)]
fn recorded_value(sig: AxisSignal, s: &Sample, sample_pos_m: f64, fpt: f64) -> f64 {
    let o = &s.plant;
    match sig {
        AxisSignal::Cmd => s.cmd_raw_m,
        AxisSignal::CmdComp => s.cmd_m,
        AxisSignal::Comp => s.cmd_nc_m - s.cmd_raw_m,
        AxisSignal::MotorPos => o.motor_pos_m,
        AxisSignal::Pos => sample_pos_m,
        AxisSignal::Err => s.cmd_raw_m - sample_pos_m,
        AxisSignal::Ferr => s.servo.ferr_m,
        AxisSignal::Vel => o.vel_mps,
        AxisSignal::TorqueCmd => s.servo.force_cmd_n / fpt,
        AxisSignal::Torque => s.servo.force_n / fpt,
        AxisSignal::Force => s.servo.force_n,
        AxisSignal::Friction => o.friction_n,
        AxisSignal::Gap => o.gap_m,
        AxisSignal::Thermal => o.thermal_m,
        AxisSignal::LeadErr => o.lead_err_m,
        AxisSignal::Sag => sample_pos_m - o.pos_m,
        // Not recorded per axis by the machine (compensations add theirs).
        _ => f64::NAN,
    }
}

/// Lets the recorder read both kinds of compensation through one call.
trait CompValues {
    fn vals(&self, out: &mut [f64]);
}

impl CompValues for Box<dyn crate::comp::PositionComp> {
    fn vals(&self, out: &mut [f64]) {
        self.values(out);
    }
}

impl CompValues for Box<dyn ServoComp> {
    fn vals(&self, out: &mut [f64]) {
        self.values(out);
    }
}
