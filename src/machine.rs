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

use crate::comp::{CompStack, PosCompCtx, ServoCompCtx, ServoCompOut};
use crate::nc::Channel;
use crate::nc::program::{self, ProgramError};
use crate::plant::{AxisPlant, Beam};
use crate::preset::{Feedback, LoadedPreset, Mode, Preset, PresetError};
use crate::servo::{Servo, force_per_torque};
use crate::trace::Trace;

#[derive(Debug, thiserror::Error)]
pub enum MachineError {
    #[error(transparent)]
    Preset(#[from] PresetError),
    #[error(transparent)]
    Program(#[from] ProgramError),
    #[error("{0}")]
    Structure(String),
}

/// Per-axis runtime: amplifier, plant and the command buffer of the current T2 period.
pub struct AxisRt {
    pub name: String,
    pub channel: usize,
    /// Index of this axis inside its channel.
    pub ch_idx: usize,
    pub servo: Servo,
    pub plant: AxisPlant,
    lead_m: f64,
    /// Load-side force per motor torque, 2π/lead.
    f_per_t: f64,
    buf_raw: Vec<f64>,
    buf_comp: Vec<f64>,
    prev_raw_m: f64,
    prev_comp_m: f64,
    /// Velocity of the previous T2 command segment, for the acceleration feed-forward.
    seg_vel_mps: f64,
    /// Commanded acceleration over the current T2 segment.
    pub acc_cmd_mps2: f64,
    /// Command of this T3 before compensation (what the program asked for), m.
    pub cmd_raw_m: f64,
    /// Command from the NC after the position compensations, m.
    pub cmd_nc_m: f64,
    /// Command the position loop saw (after all compensations), m.
    pub cmd_m: f64,
    /// Structural displacement the scale does not see (crossbeam sag), m.
    pub sag_m: f64,
    /// True tool position: plant position plus sag, m.
    pub pos_m: f64,
    pub servo_add: ServoCompOut,
    post_z: bool,
    /// Plant output and true position at the start of the latest T3 (what the trace row
    /// for that instant shows, next to the command and feedback the servo used).
    sample_out: crate::plant::PlantOut,
    sample_pos_m: f64,
}

impl AxisRt {
    pub fn feedback_m(&self) -> f64 {
        match self.servo.feedback {
            Feedback::Motor => self.plant.out.motor_enc_m,
            Feedback::Scale => self.plant.out.scale_m,
        }
    }
    pub fn torque_cmd_nm(&self) -> f64 {
        self.servo.force_cmd_n / force_per_torque(self.lead_m)
    }
    pub fn torque_nm(&self) -> f64 {
        self.servo.force_n / force_per_torque(self.lead_m)
    }
}

struct Recorder {
    every: u32,
    axis_cols: Vec<usize>,
    temp_cols: Vec<usize>,
    ambient_col: usize,
    mode_cols: Vec<usize>,
    comp_cols: Vec<usize>,
    comp_vals: Vec<f64>,
}

const AXIS_SIGNALS: &[(&str, &str)] = &[
    ("cmd", "mm"),
    ("cmd_comp", "mm"),
    ("comp", "mm"),
    ("motor_pos", "mm"),
    ("pos", "mm"),
    ("err", "mm"),
    ("ferr", "mm"),
    ("vel", "mm/s"),
    ("torque_cmd", "N*m"),
    ("torque", "N*m"),
    ("force", "N"),
    ("friction", "N"),
    ("gap", "mm"),
    ("thermal", "mm"),
    ("lead_err", "mm"),
    ("sag", "mm"),
];

pub struct Machine {
    pub preset: Preset,
    pub t3_s: f64,
    pub n12: u32,
    pub n23: u32,
    /// T3 steps done.
    pub k: u64,
    /// k mod n23: position inside the current T2 period.
    phase: usize,
    /// (j + 1)/n23 for j in 0..n23: where each T3 lies on the amplifier's interpolation.
    frac: Vec<f64>,
    pub channels: Vec<Channel>,
    pub axes: Vec<AxisRt>,
    beam: Option<Beam>,
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
    pub trace: Trace,
    rec: Option<Recorder>,
    end_k: Option<u64>,
}

impl Machine {
    /// Builds a machine from a loaded preset, reading its program files.
    pub fn from_loaded(lp: &LoadedPreset) -> Result<Machine, MachineError> {
        let texts = lp
            .preset
            .scenario
            .programs
            .iter()
            .map(|p| Ok((p.clone(), lp.program_text(p)?)))
            .collect::<Result<Vec<_>, PresetError>>()?;
        Machine::new(&lp.preset, &texts)
    }

    /// Builds a machine from a preset and the text of each channel's program
    /// (`(file name for errors, text)`).
    pub fn new(preset: &Preset, programs: &[(String, String)]) -> Result<Machine, MachineError> {
        let errors = preset.validate();
        if !errors.is_empty() {
            return Err(PresetError::Invalid {
                file: preset.name.clone(),
                errors,
            }
            .into());
        }
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
        let t3 = t.t3_s;
        let mut channels = Vec::new();
        let mut axes: Vec<AxisRt> = Vec::new();
        for (ci, (file, text)) in programs.iter().enumerate() {
            let ch_axes: Vec<(usize, &crate::preset::AxisParams)> = preset
                .axes
                .iter()
                .enumerate()
                .filter(|(_, a)| a.channel == ci)
                .collect();
            let letters: Vec<char> = ch_axes.iter().map(|(_, a)| a.letter).collect();
            let start: Vec<f64> = ch_axes
                .iter()
                .map(|(_, a)| a.initial_pos_mm * 1e-3)
                .collect();
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
                    t3_s: t3,
                    n12,
                    n23,
                },
            ));
        }
        for a in &preset.axes {
            let ch_idx = preset
                .axes
                .iter()
                .filter(|b| b.channel == a.channel)
                .position(|b| b.name == a.name)
                .unwrap_or(0);
            let x0 = a.initial_pos_mm * 1e-3;
            let plant = AxisPlant::new(a, t3, x0);
            let pos = plant.out.pos_m;
            axes.push(AxisRt {
                name: a.name.clone(),
                channel: a.channel,
                ch_idx,
                servo: Servo::new(a, t3, x0),
                plant,
                lead_m: a.drive.lead_mm * 1e-3,
                f_per_t: force_per_torque(a.drive.lead_mm * 1e-3),
                buf_raw: vec![x0; n23 as usize],
                buf_comp: vec![x0; n23 as usize],
                prev_raw_m: x0,
                prev_comp_m: x0,
                seg_vel_mps: 0.0,
                acc_cmd_mps2: 0.0,
                cmd_raw_m: x0,
                cmd_nc_m: x0,
                cmd_m: x0,
                sag_m: 0.0,
                pos_m: pos,
                servo_add: ServoCompOut::default(),
                post_z: false,
                sample_out: crate::plant::PlantOut::default(),
                sample_pos_m: pos,
            });
        }
        let beam = Beam::new(&preset.crossbeam, |n| axes.iter().position(|a| a.name == n));
        if let Some(b) = &beam {
            for p in &b.posts {
                axes[p.z_axis].post_z = true;
            }
        }
        let n_ax = axes.len();
        let ch_sizes: Vec<usize> = (0..channels.len())
            .map(|c| axes.iter().filter(|a| a.channel == c).count())
            .collect();
        let mut m = Machine {
            preset: preset.clone(),
            t3_s: t3,
            n12,
            n23,
            k: 0,
            phase: 0,
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
            end_k: None,
        };
        for (i, a) in m.axes.iter().enumerate() {
            m.comp_prev[i] = a.prev_raw_m;
        }
        m.update_sag();
        let comps = crate::comp::build(preset);
        m.set_comps(comps);
        m.set_recording(true);
        Ok(m)
    }

    /// Installs the compensations (replaces any installed before) and re-lays the trace.
    pub fn set_comps(&mut self, comps: CompStack) {
        self.comp_counts = comps
            .position
            .iter()
            .map(|c| c.signals().len())
            .chain(comps.servo.iter().map(|c| c.signals().len()))
            .collect();
        self.comps = comps;
        if self.k == 0 {
            self.start_corrected();
        }
        let on = self.rec.is_some();
        self.set_recording(on);
    }

    /// At power-up the position corrections are already in force and the axes stand at rest
    /// at the corrected position, as on a real control; without this every table would be
    /// switched on as a step at t = 0.
    fn start_corrected(&mut self) {
        let n23 = self.n23 as usize;
        for (i, a) in self.axes.iter().enumerate() {
            self.comp_cmd[i] = a.prev_raw_m;
            self.comp_fb[i] = a.feedback_m();
            self.comp_temp[i] = a.plant.thermal.temp_c;
        }
        self.comp_prev.clone_from(&self.comp_cmd);
        self.run_position_comps(0.0, self.t3_s * n23 as f64);
        for (i, a) in self.axes.iter_mut().enumerate() {
            let off = self.comp_out[i];
            if off == 0.0 {
                continue;
            }
            let x = a.prev_raw_m + off;
            let params = &self.preset.axes[i];
            a.plant = AxisPlant::new(params, self.t3_s, x);
            a.servo = Servo::new(params, self.t3_s, x);
            a.prev_comp_m = x;
            a.buf_comp.iter_mut().for_each(|b| *b = x);
            a.cmd_nc_m = x;
            a.cmd_m = x;
            a.pos_m = a.plant.out.pos_m + a.sag_m;
        }
        self.update_sag();
    }

    /// Live edit: takes the parameters of `p` from the next control period on, keeping the
    /// machine's state (positions, temperatures, pending backlash parts, quadrant N…). The
    /// structure (axes, channels, programs) must be the same; a structural change needs a new
    /// machine. The set of installed compensations is rebuilt only when one is switched on or
    /// off; otherwise each keeps its state and takes the new parameters.
    pub fn apply_params(&mut self, p: &Preset) -> Result<(), MachineError> {
        let errors = p.validate();
        if !errors.is_empty() {
            return Err(PresetError::Invalid {
                file: p.name.clone(),
                errors,
            }
            .into());
        }
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
            a.servo.retune(params);
            a.plant.retune(params);
            a.f_per_t = force_per_torque(params.drive.lead_mm * 1e-3);
            a.lead_m = params.drive.lead_mm * 1e-3;
        }
        for ch in &mut self.channels {
            ch.set_accdec(p.nc.accdec.clone());
        }
        self.beam = Beam::new(&p.crossbeam, |n| self.axes.iter().position(|a| a.name == n));
        let enabled = |q: &Preset| -> Vec<bool> {
            q.axes
                .iter()
                .flat_map(|a| [a.backlash.enabled, a.thermal.enabled, a.quadrant.enabled])
                .chain([q.cross.iter().any(|t| t.enabled)])
                .collect()
        };
        let rebuild = enabled(p) != enabled(&self.preset) || p.cross != self.preset.cross;
        let old_plc = std::mem::replace(&mut self.preset, p.clone());
        if old_plc.scenario.plc_events != p.scenario.plc_events {
            let t = self.t_s();
            self.plc_next = p
                .scenario
                .plc_events
                .iter()
                .take_while(|e| e.t_s <= t)
                .count();
        }
        if rebuild {
            let stack = crate::comp::build(p);
            self.comp_counts = stack
                .position
                .iter()
                .map(|c| c.signals().len())
                .chain(stack.servo.iter().map(|c| c.signals().len()))
                .collect();
            self.comps = stack;
            let on = self.rec.is_some();
            self.set_recording(on);
        } else {
            for (i, a) in p.axes.iter().enumerate() {
                for b in self.comps.find_mut::<crate::comp::backlash::Backlash>() {
                    if b.axis() == i {
                        b.p = a.backlash.clone();
                    }
                }
                for q in self.comps.find_mut::<crate::comp::quadrant::Quadrant>() {
                    if crate::comp::ServoComp::axis(q) == i {
                        q.p = a.quadrant.clone();
                    }
                }
                for t in self.comps.find_mut::<crate::comp::thermal::Thermal>() {
                    if t.axis() == i {
                        t.retune(a.thermal.clone());
                    }
                }
            }
        }
        Ok(())
    }

    /// A PLC mode request now (the GUI's PLC switch), for `channel`.
    pub fn plc_request(&mut self, channel: usize, mode: Mode) {
        if let Some(ch) = self.channels.get_mut(channel) {
            ch.request_mode(mode);
        }
    }

    pub fn comps(&self) -> &CompStack {
        &self.comps
    }

    pub fn comps_mut(&mut self) -> &mut CompStack {
        &mut self.comps
    }

    /// Turns trace recording on (a fresh trace) or off (benchmarks, batch fitting).
    pub fn set_recording(&mut self, on: bool) {
        self.trace = Trace::new();
        if !on {
            self.rec = None;
            return;
        }
        let tr = &mut self.trace;
        tr.meta.push(("source".into(), "simulated".into()));
        tr.meta.push(("preset".into(), self.preset.name.clone()));
        tr.meta.push(("t3_s".into(), format!("{}", self.t3_s)));
        let mut axis_cols = Vec::new();
        for a in &self.axes {
            axis_cols.push(tr.signals.len());
            for (s, u) in AXIS_SIGNALS {
                tr.add_signal(&format!("{}.{s}", a.name), u);
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
        let comp_cols: Vec<usize> = self
            .comps
            .signals()
            .iter()
            .map(|s| {
                let name = if s.axis.is_empty() {
                    s.signal.clone()
                } else {
                    format!("{}.{}", s.axis, s.signal)
                };
                tr.add_signal(&name, &s.unit)
            })
            .collect();
        self.rec = Some(Recorder {
            every: self.preset.scenario.trace_every.max(1),
            axis_cols,
            temp_cols,
            ambient_col,
            mode_cols,
            comp_vals: vec![0.0; comp_cols.len()],
            comp_cols,
        });
    }

    pub fn t_s(&self) -> f64 {
        self.k as f64 * self.t3_s
    }

    /// All programs done, filters drained, and the settle time passed (or the fixed
    /// scenario duration reached).
    pub fn done(&self) -> bool {
        match self.preset.scenario.duration_s {
            Some(d) => self.t_s() >= d - 0.5 * self.t3_s,
            None => match self.end_k {
                Some(e) => {
                    (self.k - e) as f64 * self.t3_s
                        >= self.preset.scenario.settle_s - 0.5 * self.t3_s
                }
                None => false,
            },
        }
    }

    /// Runs until [`Machine::done`] or `max_s` of machine time, whichever is first.
    pub fn run(&mut self, max_s: f64) {
        let max_k = (max_s / self.t3_s).ceil() as u64;
        while !self.done() && self.k < max_k {
            self.step();
        }
    }

    /// Runs `n` T3 steps.
    pub fn run_steps(&mut self, n: u64) {
        for _ in 0..n {
            self.step();
        }
    }

    /// One T3 period of the whole machine.
    pub fn step(&mut self) {
        let t = self.t_s();
        while let Some(ev) = self.preset.scenario.plc_events.get(self.plc_next) {
            if ev.t_s > t + 0.5 * self.t3_s {
                break;
            }
            if let Some(ch) = self.channels.get_mut(ev.channel) {
                ch.request_mode(ev.mode);
            }
            self.plc_next += 1;
        }
        let j = self.phase;
        if j == 0 {
            self.tick_t2(t);
        }
        for (i, a) in self.axes.iter_mut().enumerate() {
            let mut add = ServoCompOut::default();
            let ctx = ServoCompCtx {
                t_s: t,
                t3_s: self.t3_s,
                cmd_m: a.buf_comp[j],
                prev_cmd_m: a.cmd_nc_m,
                fb_m: a.feedback_m(),
            };
            for c in self.comps.servo.iter_mut().filter(|c| c.axis() == i) {
                let mut o = ServoCompOut::default();
                c.step(&ctx, &mut o);
                add.pos_m += o.pos_m;
                add.vel_mps += o.vel_mps;
                add.torque_nm += o.torque_nm;
            }
            a.servo_add = add;
            a.cmd_raw_m = a.buf_raw[j];
            a.cmd_nc_m = a.buf_comp[j];
            a.cmd_m = a.buf_comp[j] + add.pos_m;
            let input = crate::servo::ServoInput {
                cmd_m: a.cmd_m,
                ff_cmd_m: a.cmd_raw_m,
                fb_pos_m: a.feedback_m(),
                motor_pos_m: a.plant.out.motor_enc_m,
                vel_add_mps: add.vel_mps,
                force_ff_n: add.torque_nm * a.f_per_t,
                acc_cmd_mps2: a.acc_cmd_mps2,
            };
            let force = a.servo.step(&input);
            a.sample_out = a.plant.out;
            a.sample_pos_m = a.pos_m;
            a.plant.step(force);
            // Friction is the force over the step just taken.
            a.sample_out.friction_n = a.plant.out.friction_n;
            a.pos_m = a.plant.out.pos_m + a.sag_m;
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

    fn update_sag(&mut self) {
        if let Some(beam) = &self.beam {
            for (i, a) in self.axes.iter().enumerate() {
                self.x_pos[i] = a.plant.out.pos_m;
            }
            let mut sag = [0.0; 2];
            beam.sag_m(&self.x_pos, &mut sag);
            for (p, s) in beam.posts.iter().zip(sag) {
                self.axes[p.z_axis].sag_m = s;
            }
        }
        for a in &mut self.axes {
            a.pos_m = a.plant.out.pos_m + a.sag_m;
        }
    }

    /// Generates the next T2 of commands in every channel and runs the position
    /// compensations on them.
    fn tick_t2(&mut self, t: f64) {
        let n23 = self.n23 as usize;
        for (c, ch) in self.channels.iter_mut().enumerate() {
            self.ch_mode[c] = ch.tick_t2(&mut self.ch_target[c], &mut self.ch_batch[c]);
        }
        for (i, a) in self.axes.iter().enumerate() {
            self.comp_fb[i] = a.feedback_m();
            self.comp_temp[i] = a.plant.thermal.temp_c;
        }
        let any_direct = self.ch_mode.contains(&Mode::Direct);
        let gens = if any_direct { n23 } else { 1 };
        let period = if any_direct {
            self.t3_s
        } else {
            self.t3_s * n23 as f64
        };
        for g in 0..gens {
            for (i, a) in self.axes.iter().enumerate() {
                self.comp_cmd[i] = match self.ch_mode[a.channel] {
                    Mode::Direct => self.ch_batch[a.channel][a.ch_idx * n23 + g],
                    Mode::Normal => {
                        let target = self.ch_target[a.channel][a.ch_idx];
                        a.prev_raw_m
                            + (target - a.prev_raw_m) * ((g + 1) * n23 / gens) as f64 / n23 as f64
                    }
                };
            }
            self.run_position_comps(t + g as f64 * self.t3_s, period);
            for (i, a) in self.axes.iter_mut().enumerate() {
                let raw = self.comp_cmd[i];
                let comp = raw + self.comp_out[i];
                if any_direct {
                    a.buf_raw[g] = raw;
                    a.buf_comp[g] = comp;
                } else {
                    for jj in 0..n23 {
                        let f = self.frac[jj];
                        a.buf_raw[jj] = a.prev_raw_m + (raw - a.prev_raw_m) * f;
                        a.buf_comp[jj] = a.prev_comp_m + (comp - a.prev_comp_m) * f;
                    }
                    a.buf_raw[n23 - 1] = raw;
                    a.buf_comp[n23 - 1] = comp;
                }
            }
            self.comp_prev.clone_from(&self.comp_cmd);
        }
        let t2_s = self.t3_s * n23 as f64;
        for a in &mut self.axes {
            // One acceleration per T2 segment: the command is (piecewise) linear inside it,
            // so a per-T3 second difference would be a train of spikes.
            let v = (a.buf_raw[n23 - 1] - a.prev_raw_m) / t2_s;
            a.acc_cmd_mps2 = (v - a.seg_vel_mps) / t2_s;
            a.seg_vel_mps = v;
            a.prev_raw_m = a.buf_raw[n23 - 1];
            a.prev_comp_m = a.buf_comp[n23 - 1];
        }
    }

    /// One position-command generation: every position compensation adds its correction to
    /// `comp_out` for the command in `comp_cmd`, and any measurement asked for is taken.
    fn run_position_comps(&mut self, t_s: f64, period_s: f64) {
        self.comp_out.iter_mut().for_each(|o| *o = 0.0);
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
                let real = self.axes[axis].plant.thermal.elongation_m(x_m);
                c.measured(ctx.t_s, real);
            }
        }
    }

    fn record(&mut self) {
        let Some(rec) = &mut self.rec else { return };
        if !(self.k - 1).is_multiple_of(rec.every as u64) {
            return;
        }
        let tr = &mut self.trace;
        // The row is the instant t_k at the start of the step just taken.
        tr.signals[0].data.push((self.k - 1) as f64 * self.t3_s);
        for (a, &base) in self.axes.iter().zip(&rec.axis_cols) {
            let o = &a.sample_out;
            let vals = [
                a.cmd_raw_m * 1e3,
                a.cmd_m * 1e3,
                (a.cmd_m - a.cmd_raw_m) * 1e3,
                o.motor_pos_m * 1e3,
                a.sample_pos_m * 1e3,
                (a.cmd_raw_m - a.sample_pos_m) * 1e3,
                a.servo.ferr_m * 1e3,
                o.vel_mps * 1e3,
                a.torque_cmd_nm(),
                a.torque_nm(),
                a.servo.force_n,
                o.friction_n,
                o.gap_m * 1e3,
                o.thermal_m * 1e3,
                o.lead_err_m * 1e3,
                (a.sample_pos_m - o.pos_m) * 1e3,
            ];
            for (i, v) in vals.into_iter().enumerate() {
                tr.signals[base + i].data.push(v);
            }
        }
        for (a, &c) in self.axes.iter().zip(&rec.temp_cols) {
            tr.signals[c].data.push(a.plant.thermal.temp_c);
        }
        let amb = self
            .axes
            .first()
            .map_or(20.0, |a| a.plant.thermal.ambient_c);
        tr.signals[rec.ambient_col].data.push(amb);
        for (ch, &c) in self.channels.iter().zip(&rec.mode_cols) {
            tr.signals[c].data.push(ch.mode.as_f64());
        }
        if !rec.comp_cols.is_empty() {
            let mut at = 0;
            let counts = &self.comp_counts;
            let comps = self
                .comps
                .position
                .iter()
                .map(|c| c as &dyn CompValues)
                .chain(self.comps.servo.iter().map(|c| c as &dyn CompValues));
            for (c, &n) in comps.zip(counts) {
                c.vals(&mut rec.comp_vals[at..at + n]);
                at += n;
            }
            for (&col, &v) in rec.comp_cols.iter().zip(&rec.comp_vals) {
                tr.signals[col].data.push(v);
            }
        }
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

impl CompValues for Box<dyn crate::comp::ServoComp> {
    fn vals(&self, out: &mut [f64]) {
        self.values(out);
    }
}
