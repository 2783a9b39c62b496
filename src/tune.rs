//! Auto-tune of the compensation on the simulated machine: backlash (backlash patent, SPEC §2) and
//! quadrant (quadrant patent, SPEC §5) parameters searched by Nelder–Mead (argmin) against the
//! reversal figures `simulate` reports, from several starts run side by side; thermal (thermal
//! patent, SPEC §4) and cross tables (cross-table patent, SPEC §6) through their existing
//! measurements.
//!
//! The objective is what a service engineer reads off a reversal test: per reversal, the
//! peak and the settled change of the error (cmd − pos) from its value in the old
//! direction ([`crate::analysis::summarize`], exactly as `simulate` prints them), averaged
//! over the program's reversals, plus the RMS position error; each term in µm with a stated
//! weight. The result is never worse than the start: if no start beats the shipped values,
//! they are returned unchanged.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use argmin::core::{CostFunction, Executor, State};
use argmin::solver::neldermead::NelderMead;

use crate::analysis::{self, Reversal};
use crate::indep::run::Correction;
use crate::machine::{Machine, MachineError};
use crate::measure;
use crate::preset::comp::{Injection, OutputMode};
use crate::preset::{AxisParams, Preset};
use crate::units::{fmt_qty, mm_to_um};

/// What a tune may change.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum What {
    /// Q, and each direction's output mode with its N and B, or M (backlash patent, SPEC §2).
    Backlash,
    /// M0, T0, A, B, C, D and P0 with the adaptive part on (quadrant patent, SPEC §5).
    Quadrant,
    /// k and a through Step 1 and Step 2 (thermal patent, SPEC §4).
    Thermal,
    /// The cross (sag) tables through their measurement (cross-table patent, SPEC §6).
    Cross,
}

impl What {
    /// Every kind, in the order a tune applies them.
    pub const ALL: [What; 4] = [What::Backlash, What::Quadrant, What::Thermal, What::Cross];

    /// The name `--what` takes.
    pub fn name(self) -> &'static str {
        match self {
            What::Backlash => "backlash",
            What::Quadrant => "quadrant",
            What::Thermal => "thermal",
            What::Cross => "cross",
        }
    }

    /// Parses a comma-separated list (`backlash,quadrant`).
    pub fn parse_list(text: &str) -> Result<Vec<What>, TuneError> {
        let mut out = vec![];
        for part in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let w = What::ALL
                .into_iter()
                .find(|w| w.name() == part)
                .ok_or_else(|| TuneError::Unknown(part.to_owned()))?;
            if !out.contains(&w) {
                out.push(w);
            }
        }
        if out.is_empty() {
            return Err(TuneError::NothingToTune);
        }
        Ok(out)
    }
}

/// Why a tune cannot run or stopped.
#[derive(Debug, thiserror::Error)]
pub enum TuneError {
    /// `--what` names nothing.
    #[error("--what is empty: name at least one of backlash, quadrant, thermal, cross")]
    NothingToTune,
    /// `--what` names something else.
    #[error("--what {0}: not one of backlash, quadrant, thermal, cross")]
    Unknown(String),
    /// The axis is not in the preset.
    #[error("axis '{axis}' is not in preset '{preset}' (its axes: {have})")]
    NoAxis {
        /// The axis asked for.
        axis: String,
        /// The preset's name.
        preset: String,
        /// Its axes.
        have: String,
    },
    /// The compensation to tune is switched off.
    #[error(
        "{what} compensation is off on axis {axis} in this preset: switch it on first (--set axes.{axis}.{what}.enabled=true)"
    )]
    Disabled {
        /// The compensation.
        what: &'static str,
        /// The axis.
        axis: String,
    },
    /// The reversal figures need a reversal.
    #[error(
        "the program has no reversal on axis {axis}: the tune works on the error change at reversals (give a program that reverses, --program)"
    )]
    NoReversal {
        /// The axis.
        axis: String,
    },
    /// A weight is negative, not finite, or all are zero.
    #[error("weights: {0}")]
    Weights(String),
    /// Cross tables need a crossbeam.
    #[error("cross: this preset has no crossbeam to measure tables on")]
    NoCrossbeam,
    /// The user cancelled; nothing was changed.
    #[error("cancelled: the preset is unchanged")]
    Cancelled,
    /// The simulated machine refused the preset or diverged.
    #[error(transparent)]
    Machine(#[from] MachineError),
    /// A shipped preset could not be read (a build defect).
    #[error(transparent)]
    Preset(#[from] crate::preset::PresetError),
}

/// The objective's weights, per µm of each figure.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Weights {
    /// On the mean peak error change at a reversal.
    pub peak: f64,
    /// On the mean |settled error change| at a reversal (the lost motion left).
    pub settled: f64,
    /// On the RMS position error over the run.
    pub rms: f64,
}

impl Default for Weights {
    /// Peak and settled change count alike; the RMS error a fifth as much, so that a tune
    /// does not trade a reversal glitch for a small shift of the whole run.
    fn default() -> Self {
        Weights {
            peak: 1.0,
            settled: 1.0,
            rms: 0.2,
        }
    }
}

impl Weights {
    /// Parses `peak=1,settled=1,rms=0.2` (any subset; the rest keep their defaults).
    pub fn parse(text: &str) -> Result<Weights, TuneError> {
        let mut w = Weights::default();
        for part in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (k, v) = part
                .split_once('=')
                .ok_or_else(|| TuneError::Weights(format!("'{part}': expected name=value")))?;
            let v: f64 = v
                .trim()
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite() && *v >= 0.0)
                .ok_or_else(|| {
                    TuneError::Weights(format!("'{part}': the value must be a number ≥ 0"))
                })?;
            match k.trim() {
                "peak" => w.peak = v,
                "settled" => w.settled = v,
                "rms" => w.rms = v,
                other => {
                    return Err(TuneError::Weights(format!(
                        "'{other}': not one of peak, settled, rms"
                    )));
                }
            }
        }
        if w.peak + w.settled + w.rms <= 0.0 {
            return Err(TuneError::Weights("all weights are 0".into()));
        }
        Ok(w)
    }
}

/// The figures of one run on the tuned axis.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Figures {
    /// Each reversal, as `simulate` reports it.
    pub reversals: Vec<Reversal>,
    /// RMS position error, µm.
    pub rms_um: f64,
    /// The objective.
    pub objective: f64,
}

/// What a tune needs: the preset, the programs, the axis and what to tune.
pub struct Job<'a> {
    /// The preset to start from (never changed).
    pub preset: &'a Preset,
    /// One program per channel: (name, text).
    pub programs: &'a [(String, String)],
    /// The axis whose reversals are scored and whose compensation is tuned.
    pub axis: String,
    /// What to tune.
    pub what: Vec<What>,
    /// The objective's weights.
    pub weights: Weights,
    /// Seeds the extra starts; the same seed gives the same result.
    pub seed: u64,
    /// Nelder–Mead iterations per start.
    pub max_iters: u64,
    /// Threads running starts side by side (0: all cores).
    pub threads: usize,
}

/// Where a running tune stands, handed to [`Progress::report`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Status {
    /// Simulations run so far.
    pub simulations: usize,
    /// The best objective so far.
    pub best: f64,
    /// Parts of the search finished: Nelder–Mead starts and measuring steps (thermal,
    /// cross). Each part is a bounded amount of work, so their share is the progress bar.
    pub parts_done: usize,
    /// Parts of the search in all (0 for the grid check, whose count is the simulations').
    pub parts_total: usize,
}

impl Status {
    /// The share of the search finished, 0–1; `None` when the parts are not counted.
    pub fn share_done(&self) -> Option<f64> {
        (self.parts_total > 0).then(|| self.parts_done as f64 / self.parts_total as f64)
    }
}

/// Progress and cancel, shared with a GUI or the CLI's progress line.
pub struct Progress<'a> {
    /// Called whenever the best objective improves and whenever a part of the search
    /// finishes.
    pub report: &'a (dyn Fn(Status) + Sync),
    /// Set from outside to stop; the tune then returns [`TuneError::Cancelled`].
    pub cancel: &'a AtomicBool,
}

/// The outcome of a tune.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Outcome {
    /// The preset with the tuned values (the start itself when nothing beat it).
    #[serde(skip)]
    pub preset: Preset,
    /// The axis tuned.
    pub axis: String,
    /// What was tuned.
    pub what: Vec<What>,
    /// The objective's weights.
    pub weights: Weights,
    /// Figures with the values the tune started from.
    pub before: Figures,
    /// Figures with the tuned values.
    pub after: Figures,
    /// Figures of the same program on the ideal axis ([`ideal_axis`]): the floor, what is
    /// left of the glitch with no play and no friction to compensate.
    pub floor: Figures,
    /// Whether the start stayed (no start beat it).
    pub kept_start: bool,
    /// Simulations run.
    pub simulations: usize,
    /// Simulations per second of wall time.
    pub simulations_per_s: f64,
    /// Wall time of the tune, s.
    pub wall_s: f64,
    /// The objective after each evaluation that improved it: (evaluation, objective).
    pub history: Vec<(usize, f64)>,
    /// The tuned parameters: (preset path, value).
    pub values: Vec<(String, f64)>,
}

/// The before/after table of a tune, one row of text cells per reversal and one for the
/// RMS error, in [`Outcome::TABLE_HEADER`]'s columns: what the CLI prints and the Tune tab
/// shows.
impl Outcome {
    /// Column heads of [`Outcome::table`].
    pub const TABLE_HEADER: [&'static str; 7] = [
        "reversal",
        "t",
        "peak change before",
        "after",
        "ideal axis (floor)",
        "settled change before",
        "after",
    ];

    /// The rows of the table, values with their units ("—" where the ideal axis has no such
    /// reversal); the last row is the RMS position error.
    pub fn table(&self) -> Vec<[String; 7]> {
        let um = |mm: f64| fmt_qty(mm_to_um(mm), "um");
        let mut rows: Vec<[String; 7]> = self
            .before
            .reversals
            .iter()
            .zip(&self.after.reversals)
            .enumerate()
            .map(|(i, (b, a))| {
                [
                    b.direction.arrow().to_owned(),
                    fmt_qty(b.t_s, "s"),
                    um(b.peak_err_mm),
                    um(a.peak_err_mm),
                    self.floor
                        .reversals
                        .get(i)
                        .map_or_else(|| "—".to_owned(), |f| um(f.peak_err_mm)),
                    um(b.settled_err_mm),
                    um(a.settled_err_mm),
                ]
            })
            .collect();
        rows.push([
            "RMS error".to_owned(),
            String::new(),
            fmt_qty(self.before.rms_um, "um"),
            fmt_qty(self.after.rms_um, "um"),
            fmt_qty(self.floor.rms_um, "um"),
            String::new(),
            String::new(),
        ]);
        rows
    }
}

/// One searched number: its preset path below the axis, its range, whether it is a whole
/// number, and how it is read and written.
#[derive(Clone, Copy)]
struct Dim {
    path: &'static str,
    lo: f64,
    hi: f64,
    int: bool,
    get: fn(&AxisParams) -> f64,
    set: fn(&mut AxisParams, f64),
}

/// A searched number: its path below the axis (the field it reads and writes), its range;
/// `int` for a whole-number field.
macro_rules! dim {
    ($path:expr, $lo:expr, $hi:expr, $($f:ident).+) => {
        Dim {
            path: $path,
            lo: $lo,
            hi: $hi,
            int: false,
            get: |a| a.$($f).+,
            set: |a, v| a.$($f).+ = v,
        }
    };
    (int $path:expr, $lo:expr, $hi:expr, $($f:ident).+) => {
        Dim {
            path: $path,
            lo: $lo,
            hi: $hi,
            int: true,
            get: |a| f64::from(a.$($f).+),
            set: |a, v| a.$($f).+ = v as u32,
        }
    };
}

/// A direction's numbers by mode: distance (N, B) and time (M).
macro_rules! direction_dims {
    ($d:ident) => {
        (
            [
                dim!(int concat!("backlash.", stringify!($d), ".parts_n"), 1.0, 32.0, backlash.$d.parts_n),
                dim!(concat!("backlash.", stringify!($d), ".step_b_um"), 1.0, 2000.0, backlash.$d.step_b_um),
            ],
            dim!(int concat!("backlash.", stringify!($d), ".cycles_m"), 1.0, 64.0, backlash.$d.cycles_m),
        )
    };
}

/// The backlash numbers searched for the modes each direction uses now.
fn backlash_dims(a: &AxisParams) -> Vec<Dim> {
    let mut d = vec![Dim {
        hi: (4.0 * a.backlash.q_um).max(50.0),
        ..dim!("backlash.q_um", 0.0, 0.0, backlash.q_um)
    }];
    for (mode, (distance, time)) in [
        (
            a.backlash.plus_to_minus.mode,
            direction_dims!(plus_to_minus),
        ),
        (
            a.backlash.minus_to_plus.mode,
            direction_dims!(minus_to_plus),
        ),
    ] {
        match mode {
            OutputMode::Distance => d.extend(distance),
            OutputMode::Time => d.push(time),
            OutputMode::Lump | OutputMode::Function => {}
        }
    }
    d
}

/// The quadrant numbers searched (M0 in the unit of its injection point, up to four times
/// the value given).
fn quadrant_dims(a: &AxisParams) -> Vec<Dim> {
    let q = &a.quadrant;
    let m0 = match q.inject {
        Injection::Torque => Dim {
            hi: (4.0 * q.m0_torque_nm).max(2.0),
            ..dim!("quadrant.m0_torque_nm", 0.0, 0.0, quadrant.m0_torque_nm)
        },
        Injection::Velocity => Dim {
            hi: (4.0 * q.m0_vel_mm_per_s).max(5.0),
            ..dim!(
                "quadrant.m0_vel_mm_per_s",
                0.0,
                0.0,
                quadrant.m0_vel_mm_per_s
            )
        },
        Injection::Position => Dim {
            hi: (4.0 * q.m0_pos_um).max(20.0),
            ..dim!("quadrant.m0_pos_um", 0.0, 0.0, quadrant.m0_pos_um)
        },
    };
    vec![
        m0,
        dim!("quadrant.t0_ms", 0.5, 100.0, quadrant.t0_ms),
        dim!("quadrant.a_mag", 1.0, 5.0, quadrant.a_mag),
        dim!("quadrant.b_rate", 0.5, 50.0, quadrant.b_rate),
        dim!("quadrant.c_mag", 0.5, 5.0, quadrant.c_mag),
        dim!("quadrant.d_rate", 0.5, 50.0, quadrant.d_rate),
        dim!("quadrant.p0_mm", 0.5, 200.0, quadrant.p0_mm),
    ]
}

/// Runs the programs on `p` and returns the axis's figures.
pub fn evaluate(
    p: &Preset,
    programs: &[(String, String)],
    axis: &str,
    w: &Weights,
) -> Result<Figures, MachineError> {
    let mut m = Machine::new(p, programs)?;
    m.run(4.0 * 3600.0)?;
    let sums = analysis::summarize(&m.trace);
    let s = sums.into_iter().find(|s| s.axis == axis);
    let (reversals, rms_um) = s.map_or((vec![], 0.0), |s| (s.reversals, mm_to_um(s.rms_err_mm)));
    let peak = mean_peak_change_um(&reversals);
    let settled = mean_um(&reversals, |r| r.settled_err_mm.abs());
    let objective = w.peak * peak + w.settled * settled + w.rms * rms_um;
    Ok(Figures {
        reversals,
        rms_um,
        objective: if objective.is_finite() {
            objective
        } else {
            f64::INFINITY
        },
    })
}

/// `p` with axis `axis_i` ideal: no play, no friction, and so no backlash or quadrant
/// compensation (they would only add error there). The rest of the machine (servo, drive,
/// heat) stays: what is left is the servo's own following error at the reversal.
pub fn ideal_axis(p: &Preset, axis_i: usize) -> Preset {
    let mut q = p.clone();
    if let Some(a) = q.axes.get_mut(axis_i) {
        a.lost_motion.enabled = false;
        a.friction.enabled = false;
        a.backlash.enabled = false;
        a.quadrant.enabled = false;
    }
    q
}

/// How long the programs run on `p` (to their end and the settling time), s.
fn last_t(p: &Preset, programs: &[(String, String)]) -> Option<f64> {
    let mut m = Machine::new(p, programs).ok()?;
    m.set_recording(false);
    m.run(4.0 * 3600.0).ok()?;
    Some(m.t_s())
}

/// The search over one set of dimensions on a base preset: x in [0, 1]^n maps to the dims'
/// ranges (whole numbers rounded); points outside are pulled onto the box.
struct Problem<'a> {
    base: &'a Preset,
    axis_i: usize,
    dims: &'a [Dim],
    job: &'a Job<'a>,
    shared: &'a Shared<'a>,
}

/// What every start shares: the count, the best so far and the cancel flag.
struct Shared<'a> {
    /// The start's run length, s (every candidate runs as long).
    run_s: Option<f64>,
    evals: AtomicUsize,
    best: Mutex<(f64, Vec<(usize, f64)>)>,
    progress: &'a Progress<'a>,
    /// See [`Status::parts_total`].
    parts_total: usize,
    parts_done: AtomicUsize,
}

impl Shared<'_> {
    /// Hands the current [`Status`] to the progress report, with `best` if known.
    fn report(&self, best: Option<f64>) {
        let best = best
            .or_else(|| self.best.lock().ok().map(|b| b.0))
            .unwrap_or(f64::NAN);
        (self.progress.report)(Status {
            simulations: self.evals.load(Ordering::Relaxed),
            best,
            parts_done: self.parts_done.load(Ordering::Relaxed),
            parts_total: self.parts_total,
        });
    }

    /// One part of the search done.
    fn part_done(&self) {
        self.parts_done.fetch_add(1, Ordering::Relaxed);
        self.report(None);
    }
}

impl Problem<'_> {
    fn preset_at(&self, x: &[f64]) -> Preset {
        let mut p = self.base.clone();
        if let Some(a) = p.axes.get_mut(self.axis_i) {
            for (d, &u) in self.dims.iter().zip(x) {
                let v = d.lo + u.clamp(0.0, 1.0) * (d.hi - d.lo);
                (d.set)(a, if d.int { v.round() } else { v });
            }
        }
        p
    }

    fn x_of(&self, p: &Preset) -> Vec<f64> {
        let a = &p.axes[self.axis_i];
        self.dims
            .iter()
            .map(|d| (((d.get)(a) - d.lo) / (d.hi - d.lo)).clamp(0.0, 1.0))
            .collect()
    }
}

impl CostFunction for Problem<'_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, x: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        // Once cancelled, every point is infinitely bad and costs nothing: the solver (which
        // does not expect an error while it sets up its simplex) winds down, and the tune
        // reports the cancel.
        if self.shared.progress.cancel.load(Ordering::Relaxed) {
            return Ok(f64::INFINITY);
        }
        let mut p = self.preset_at(x);
        // The run's length is known from the start's run: one trace allocation, not a
        // growing one (most of a short run's cost otherwise).
        p.scenario.duration_s = self.shared.run_s;
        // A point the preset's own checks refuse, or one that diverges, is simply bad.
        let f = evaluate(&p, self.job.programs, &self.job.axis, &self.job.weights)
            .map_or(f64::INFINITY, |f| f.objective);
        // Outside the box: the box's value plus the distance, so the simplex comes back.
        let out: f64 = x.iter().map(|u| (u - u.clamp(0.0, 1.0)).abs()).sum::<f64>();
        let f = f + out * 100.0;
        let k = self.shared.evals.fetch_add(1, Ordering::Relaxed) + 1;
        let improved = match self.shared.best.lock() {
            Ok(mut b) if f < b.0 => {
                b.0 = f;
                b.1.push((k, f));
                true
            }
            _ => false,
        };
        if improved {
            self.shared.report(Some(f));
        }
        Ok(f)
    }
}

/// Nelder–Mead stops when its simplex's objective values spread less than this (µm): a
/// thousandth of a micrometre is far below what a machine shows.
const SD_TOLERANCE: f64 = 1e-3;

/// One start: Nelder–Mead from `x0` with a simplex of `step` per dimension.
fn run_start(prob: Problem<'_>, x0: Vec<f64>, step: f64, iters: u64) -> Option<(Vec<f64>, f64)> {
    let n = x0.len();
    if n == 0 {
        let f = prob.cost(&x0).ok()?;
        return Some((x0, f));
    }
    let mut simplex = vec![x0.clone()];
    for i in 0..n {
        let mut v = x0.clone();
        v[i] = if v[i] + step <= 1.0 {
            v[i] + step
        } else {
            v[i] - step
        };
        simplex.push(v);
    }
    let solver = NelderMead::new(simplex)
        .with_sd_tolerance(SD_TOLERANCE)
        .ok()?;
    let res = Executor::new(prob, solver)
        .configure(|s| s.max_iters(iters))
        .run()
        .ok()?;
    let st = res.state();
    Some((st.get_best_param()?.clone(), st.get_best_cost()))
}

/// A start of one stage: the mode pair (backlash) and the point.
struct Start {
    base: Preset,
    x0: Option<Vec<f64>>,
}

/// Runs the starts side by side and returns the best (preset, objective); ties go to the
/// earlier start, so the result does not depend on the threads.
fn stage(
    job: &Job<'_>,
    shared: &Shared<'_>,
    axis_i: usize,
    starts: Vec<Start>,
    dims_of: DimsOf,
) -> Result<Option<(Preset, f64)>, TuneError> {
    let threads = job.thread_count();
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<(Preset, f64)>>> = Mutex::new(vec![None; starts.len()]);
    std::thread::scope(|sc| {
        for _ in 0..threads.min(starts.len()).max(1) {
            sc.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(s) = starts.get(i) else { break };
                    let dims = s.base.axes.get(axis_i).map(dims_of).unwrap_or_default();
                    let prob = Problem {
                        base: &s.base,
                        axis_i,
                        dims: &dims,
                        job,
                        shared,
                    };
                    let x0 = s.x0.clone().unwrap_or_else(|| prob.x_of(&s.base));
                    let out = run_start(prob, x0, 0.15, job.max_iters).map(|(x, f)| {
                        let prob = Problem {
                            base: &s.base,
                            axis_i,
                            dims: &dims,
                            job,
                            shared,
                        };
                        (prob.preset_at(&x), f)
                    });
                    if let Ok(mut r) = results.lock() {
                        r[i] = out;
                    }
                    shared.part_done();
                }
            });
        }
    });
    if job.progress_cancelled(shared) {
        return Err(TuneError::Cancelled);
    }
    let results = results.into_inner().unwrap_or_default();
    Ok(results
        .into_iter()
        .flatten()
        .fold(None, |best: Option<(Preset, f64)>, (p, f)| match best {
            Some((_, bf)) if bf <= f => best,
            _ => Some((p, f)),
        }))
}

impl Job<'_> {
    /// Threads for the starts or grid points (0 in the job: all cores).
    fn thread_count(&self) -> usize {
        if self.threads == 0 {
            std::thread::available_parallelism().map_or(2, |n| n.get())
        } else {
            self.threads
        }
    }

    fn progress_cancelled(&self, shared: &Shared<'_>) -> bool {
        shared.progress.cancel.load(Ordering::Relaxed)
    }
}

/// `n` uniform numbers in [0, 1) for extra start `k`, from the job's seed.
fn jitter(seed: u64, k: u64, n: usize) -> Vec<f64> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed.wrapping_add(k));
    (0..n).map(|_| rng.r#gen::<f64>()).collect()
}

/// The output modes the backlash stage tries for each direction.
const BACKLASH_MODES: [OutputMode; 3] = [OutputMode::Lump, OutputMode::Distance, OutputMode::Time];

/// `p` with each pair of backlash output modes (lump, distance, time) on axis `axis_i`: the
/// backlash stage's bases.
fn mode_pairs(p: &Preset, axis_i: usize) -> Vec<Preset> {
    BACKLASH_MODES
        .iter()
        .flat_map(|&m1| {
            BACKLASH_MODES.iter().map(move |&m2| {
                let mut q = p.clone();
                q.axes[axis_i].backlash.plus_to_minus.mode = m1;
                q.axes[axis_i].backlash.minus_to_plus.mode = m2;
                q
            })
        })
        .collect()
}

/// What the starts of one tune share, with the start's objective counted as the first
/// evaluation; every candidate runs as long as the start did.
fn shared_for<'a>(
    job: &Job<'_>,
    start_f: f64,
    progress: &'a Progress<'a>,
    parts_total: usize,
) -> Shared<'a> {
    Shared {
        parts_total,
        parts_done: AtomicUsize::new(0),
        run_s: job
            .preset
            .scenario
            .duration_s
            .or_else(|| last_t(job.preset, job.programs)),
        evals: AtomicUsize::new(1),
        best: Mutex::new((start_f, vec![(1, start_f)])),
        progress,
    }
}

/// The axis's index, once every compensation to tune is on and the preset has what it
/// needs.
fn check(job: &Job<'_>) -> Result<usize, TuneError> {
    let axis_i = job
        .preset
        .axes
        .iter()
        .position(|a| a.name == job.axis)
        .ok_or_else(|| TuneError::NoAxis {
            axis: job.axis.clone(),
            preset: job.preset.name.clone(),
            have: job
                .preset
                .axes
                .iter()
                .map(|a| a.name.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        })?;
    let a = &job.preset.axes[axis_i];
    for w in &job.what {
        let on = match w {
            What::Backlash => a.backlash.enabled,
            What::Quadrant => a.quadrant.enabled,
            What::Thermal => a.thermal.enabled,
            What::Cross => true,
        };
        if !on {
            return Err(TuneError::Disabled {
                what: w.name(),
                axis: job.axis.clone(),
            });
        }
    }
    if job.what.contains(&What::Cross) && !job.preset.crossbeam.enabled {
        return Err(TuneError::NoCrossbeam);
    }
    Ok(axis_i)
}

/// Seeded starts of the quadrant stage, besides the values given.
const QUADRANT_EXTRA_STARTS: u64 = 3;

/// The parts [`search`] runs for `what` (see [`Status::parts_done`]).
fn search_parts(what: &[What]) -> usize {
    what.iter()
        .map(|w| match w {
            What::Thermal | What::Cross => 1,
            What::Backlash => BACKLASH_MODES.len() * BACKLASH_MODES.len(),
            What::Quadrant => 1 + QUADRANT_EXTRA_STARTS as usize,
        })
        .sum()
}

/// A searched stage's numbers, read from an axis.
type DimsOf = fn(&AxisParams) -> Vec<Dim>;

/// The searched stages in order, for the search and the grid check alike: the backlash on
/// every pair of output modes, then the quadrant (adaptive on) on the best so far. `run`
/// takes a stage's bases, its numbers and whether seeded starts belong to it, and returns
/// the stage's best; that is kept only when it beats `cur`.
fn searched_stages(
    job: &Job<'_>,
    axis_i: usize,
    cur: &mut (Preset, f64),
    mut run: impl FnMut(Vec<Preset>, DimsOf, bool) -> Result<Option<(Preset, f64)>, TuneError>,
) -> Result<(), TuneError> {
    if job.what.contains(&What::Backlash) {
        keep_better(cur, run(mode_pairs(&cur.0, axis_i), backlash_dims, false)?);
    }
    if job.what.contains(&What::Quadrant) {
        let mut p = cur.0.clone();
        p.axes[axis_i].quadrant.adaptive = true;
        keep_better(cur, run(vec![p], quadrant_dims, true)?);
    }
    Ok(())
}

/// `best` replaces `cur` when its objective is lower.
fn keep_better(cur: &mut (Preset, f64), best: Option<(Preset, f64)>) {
    if let Some(b) = best
        && b.1 < cur.1
    {
        *cur = b;
    }
}

/// The measured parts, then the searched stages ([`searched_stages`]) from Nelder–Mead
/// starts: each base as given, plus seeded points where the stage has them. Returns the
/// preset and its objective.
fn search(
    job: &Job<'_>,
    shared: &Shared<'_>,
    axis_i: usize,
    start_f: f64,
) -> Result<(Preset, f64), TuneError> {
    let mut cur = (job.preset.clone(), start_f);
    // Measured parts first: they change the machine the searched parts act on.
    if job.what.contains(&What::Thermal) {
        cur.0 = tune_thermal(&cur.0, job)?;
        cur.1 = evaluate(&cur.0, job.programs, &job.axis, &job.weights)?.objective;
        shared.part_done();
    }
    if job.what.contains(&What::Cross) {
        cur.0.cross = measure::sag_tables(&cur.0, 9)?;
        cur.1 = evaluate(&cur.0, job.programs, &job.axis, &job.weights)?.objective;
        shared.part_done();
    }
    searched_stages(job, axis_i, &mut cur, |bases, dims_of, seeded| {
        let mut starts: Vec<Start> = bases
            .iter()
            .map(|base| Start {
                base: base.clone(),
                x0: None,
            })
            .collect();
        if seeded && let Some(base) = bases.first() {
            let n = base.axes.get(axis_i).map_or(0, |a| dims_of(a).len());
            starts.extend((0..QUADRANT_EXTRA_STARTS).map(|k| Start {
                base: base.clone(),
                x0: Some(jitter(job.seed, k, n)),
            }));
        }
        stage(job, shared, axis_i, starts, dims_of)
    })?;
    Ok(cur)
}

/// The best point of a full grid over the same numbers a stage searches: `n` values per
/// dimension (ends included) on every base; points shared out to the threads.
fn grid_stage(
    job: &Job<'_>,
    shared: &Shared<'_>,
    axis_i: usize,
    bases: &[Preset],
    dims_of: DimsOf,
    n: usize,
) -> Option<(Preset, f64)> {
    let n = n.max(2);
    let dims: Vec<Vec<Dim>> = bases
        .iter()
        .map(|b| b.axes.get(axis_i).map(dims_of).unwrap_or_default())
        .collect();
    let counts: Vec<usize> = dims
        .iter()
        .map(|d| n.saturating_pow(d.len() as u32))
        .collect();
    let total: usize = counts.iter().sum();
    let threads = job.thread_count();
    let next = AtomicUsize::new(0);
    let best: Mutex<Option<(usize, f64)>> = Mutex::new(None);
    let locate = |mut i: usize| -> Option<(usize, usize)> {
        for (b, c) in counts.iter().enumerate() {
            if i < *c {
                return Some((b, i));
            }
            i -= c;
        }
        None
    };
    let point = |mut j: usize, d: usize| -> Vec<f64> {
        (0..d)
            .map(|_| {
                let u = (j % n) as f64 / (n - 1) as f64;
                j /= n;
                u
            })
            .collect()
    };
    std::thread::scope(|sc| {
        for _ in 0..threads.max(1) {
            sc.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= total {
                        break;
                    }
                    let Some((b, j)) = locate(i) else { break };
                    let prob = Problem {
                        base: &bases[b],
                        axis_i,
                        dims: &dims[b],
                        job,
                        shared,
                    };
                    let Ok(f) = prob.cost(&point(j, dims[b].len())) else {
                        continue;
                    };
                    if let Ok(mut g) = best.lock() {
                        // Ties go to the lower index: the same grid gives the same answer.
                        let better = match *g {
                            Some((gi, gf)) => f < gf || (f == gf && i < gi),
                            None => true,
                        };
                        if better {
                            *g = Some((i, f));
                        }
                    }
                }
            });
        }
    });
    let (i, f) = best.into_inner().ok().flatten()?;
    let (b, j) = locate(i)?;
    let prob = Problem {
        base: &bases[b],
        axis_i,
        dims: &dims[b],
        job,
        shared,
    };
    Some((prob.preset_at(&point(j, dims[b].len())), f))
}

/// What a grid check found: the best objective, the grid's size and its time.
#[derive(Debug, Clone, serde::Serialize)]
pub struct GridOutcome {
    /// The objective at the start.
    pub start: f64,
    /// The best objective on the grid (the start's when no grid point beat it).
    pub best: f64,
    /// Values per dimension.
    pub per_dim: usize,
    /// Simulations run.
    pub simulations: usize,
    /// Wall time, s.
    pub wall_s: f64,
}

/// The dense-grid check of the search: the same stages as [`tune`] (backlash over every
/// pair of output modes, then the quadrant on the best backlash), each a full grid of
/// `per_dim` values per searched number instead of Nelder–Mead.
pub fn grid(
    job: &Job<'_>,
    per_dim: usize,
    progress: &Progress<'_>,
) -> Result<GridOutcome, TuneError> {
    let t0 = std::time::Instant::now();
    let axis_i = check(job)?;
    let before = evaluate(job.preset, job.programs, &job.axis, &job.weights)?;
    let shared = shared_for(job, before.objective, progress, 0);
    let mut cur = (job.preset.clone(), before.objective);
    searched_stages(job, axis_i, &mut cur, |bases, dims_of, _| {
        Ok(grid_stage(job, &shared, axis_i, &bases, dims_of, per_dim))
    })?;
    if progress.cancel.load(Ordering::Relaxed) {
        return Err(TuneError::Cancelled);
    }
    Ok(GridOutcome {
        start: before.objective,
        best: cur.1,
        per_dim,
        simulations: shared.evals.load(Ordering::Relaxed),
        wall_s: t0.elapsed().as_secs_f64(),
    })
}

/// Tunes what `job` asks for and returns the outcome; the input preset is never changed.
pub fn tune(job: &Job<'_>, progress: &Progress<'_>) -> Result<Outcome, TuneError> {
    let t0 = std::time::Instant::now();
    let axis_i = check(job)?;
    let before = evaluate(job.preset, job.programs, &job.axis, &job.weights)?;
    if before.reversals.is_empty()
        && job
            .what
            .iter()
            .any(|w| matches!(w, What::Backlash | What::Quadrant))
    {
        return Err(TuneError::NoReversal {
            axis: job.axis.clone(),
        });
    }
    let shared = shared_for(job, before.objective, progress, search_parts(&job.what));
    let (cur, cur_f) = search(job, &shared, axis_i, before.objective)?;
    // Never worse than the start: the comparison is on the same figures.
    let kept_start = cur_f >= before.objective;
    let preset = if kept_start { job.preset.clone() } else { cur };
    let after = evaluate(&preset, job.programs, &job.axis, &job.weights)?;
    let floor = evaluate(
        &ideal_axis(job.preset, axis_i),
        job.programs,
        &job.axis,
        &job.weights,
    )?;
    let values = tuned_values(&preset, axis_i, job);
    let wall_s = t0.elapsed().as_secs_f64();
    let simulations = shared.evals.load(Ordering::Relaxed) + 1;
    let history = shared.best.into_inner().map(|b| b.1).unwrap_or_default();
    Ok(Outcome {
        preset,
        axis: job.axis.clone(),
        what: job.what.clone(),
        weights: job.weights,
        before,
        after,
        floor,
        kept_start,
        simulations,
        simulations_per_s: simulations as f64 / wall_s.max(1e-9),
        wall_s,
        history,
        values,
    })
}

/// Step 1 (k) and Step 2 (a) of the thermal patent (SPEC §4) on the simulated machine, as the
/// workbench runs them: a two-hour warm-up program's measurements.
fn tune_thermal(p: &Preset, job: &Job<'_>) -> Result<Preset, TuneError> {
    let step1 = measure::thermal_step1(p, &job.axis, &[job.programs.to_vec()], 120.0)?;
    let mut q = p.clone();
    if let Some(a) = q.axes.iter_mut().find(|a| a.name == job.axis) {
        a.thermal.k_per_um = step1.k_per_um;
    }
    let a_val = measure::thermal_step2(&q, &job.axis, job.programs, 600.0)?;
    if let Some(a) = q.axes.iter_mut().find(|a| a.name == job.axis) {
        a.thermal.a = a_val;
    }
    Ok(q)
}

/// The values of every searched number in `p`, by preset path.
fn tuned_values(p: &Preset, axis_i: usize, job: &Job<'_>) -> Vec<(String, f64)> {
    let a = &p.axes[axis_i];
    let mut dims = vec![];
    if job.what.contains(&What::Backlash) {
        dims.extend(backlash_dims(a));
    }
    if job.what.contains(&What::Quadrant) {
        dims.extend(quadrant_dims(a));
    }
    let mut out: Vec<(String, f64)> = dims
        .iter()
        .map(|d| (format!("axes.{}.{}", a.name, d.path), (d.get)(a)))
        .collect();
    if job.what.contains(&What::Thermal) {
        out.push((
            format!("axes.{}.thermal.k_per_um", a.name),
            a.thermal.k_per_um,
        ));
        out.push((format!("axes.{}.thermal.a", a.name), a.thermal.a));
    }
    out
}

/// The position and force corrections the backlash and quadrant compensations of `p`'s
/// axis compute from a command sampled every `t3_s` (handed over every T3, as in the NC's
/// direct mode), fed back their own command: what a controller with these settings adds on
/// any machine. Per sample: position (m, the backlash output plus a position-injected
/// quadrant pulse) and force (N, a torque-injected pulse through the screw). A
/// velocity-injected pulse has no input on a rig that takes position and force; it is left
/// out (the tune then should not use it).
pub fn corrections(p: &Preset, axis: &str, cmd_m: &[f64], t3_s: f64) -> Correction {
    use crate::comp::backlash::Backlash;
    use crate::comp::quadrant::Quadrant;
    use crate::comp::{PosCompCtx, PositionComp, ServoComp, ServoCompCtx, ServoCompOut};
    let mut out = Correction::default();
    let Some(i) = p.axes.iter().position(|a| a.name == axis) else {
        return out;
    };
    let a = &p.axes[i];
    let n_axes = p.axes.len();
    let mut bl = a
        .backlash
        .enabled
        .then(|| Backlash::new(i, axis, a.backlash.clone()));
    let mut qd = a
        .quadrant
        .enabled
        .then(|| Quadrant::new(i, axis, a.quadrant.clone()));
    let f_per_t = a.drive.force_per_torque();
    let mut cmds = vec![0.0; n_axes];
    let mut prev = vec![0.0; n_axes];
    let temps = vec![20.0; n_axes];
    let mut prev_comp = cmd_m.first().copied().unwrap_or(0.0);
    for (k, &c) in cmd_m.iter().enumerate() {
        let t_s = k as f64 * t3_s;
        cmds[i] = c;
        prev[i] = if k == 0 { c } else { cmd_m[k - 1] };
        let mut pos = vec![0.0; n_axes];
        if let Some(b) = bl.as_mut() {
            b.step(
                &PosCompCtx {
                    t_s,
                    period_s: t3_s,
                    cmd_m: &cmds,
                    prev_cmd_m: &prev,
                    fb_m: &cmds,
                    temps_c: &temps,
                },
                &mut pos,
            );
        }
        let comp = c + pos[i];
        let mut s = ServoCompOut::default();
        if let Some(q) = qd.as_mut() {
            q.step(
                &ServoCompCtx {
                    t_s,
                    t3_s,
                    cmd_m: comp,
                    prev_cmd_m: prev_comp,
                    fb_m: c,
                },
                &mut s,
            );
        }
        prev_comp = comp;
        out.pos_m.push(pos[i] + s.pos_m);
        out.force_n.push(s.torque_nm * f_per_t);
    }
    out
}

/// The mean peak error change over `reversals`, µm: the reversal glitch the objective and
/// the transfer check read (0 without reversals).
pub fn mean_peak_change_um(reversals: &[Reversal]) -> f64 {
    mean_um(reversals, |r| r.peak_err_mm)
}

/// The mean |error change| already there at the last sample before each reversal, µm
/// ([`Reversal::before_err_mm`]): the part of the glitch a compensation started by the
/// reversal cannot reach.
pub fn mean_change_before_um(reversals: &[Reversal]) -> f64 {
    mean_um(reversals, |r| r.before_err_mm.abs())
}

/// The mean of one figure (mm) over `reversals`, µm (0 without reversals).
fn mean_um(reversals: &[Reversal], mm: fn(&Reversal) -> f64) -> f64 {
    let n = reversals.len().max(1) as f64;
    reversals.iter().map(|r| mm_to_um(mm(r))).sum::<f64>() / n
}

/// The mean peak error change at the reversals of a record, µm (the glitch).
fn mean_peak_um(tr: &crate::trace::Trace, axis: &str) -> f64 {
    analysis::summarize(tr)
        .iter()
        .find(|s| s.axis == axis)
        .map_or(f64::NAN, |s| mean_peak_change_um(&s.reversals))
}

/// A tune on a diagnosed model, run on the machine the record came from.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Transfer {
    /// The effects the diagnosis named.
    pub named: Vec<String>,
    /// Mean peak error change at the independent machine's reversals without and with the
    /// tuned compensation, µm.
    pub machine_before_um: f64,
    /// … with it.
    pub machine_after_um: f64,
    /// What the model predicted on its tuning program, µm: without …
    pub model_before_um: f64,
    /// … and with the tuned compensation.
    pub model_after_um: f64,
    /// The tuned values.
    pub values: Vec<(String, f64)>,
}

impl Transfer {
    /// The machine's cut as a share of the model's predicted cut (1: as predicted).
    pub fn share_of_predicted(&self) -> f64 {
        let predicted = self.model_before_um - self.model_after_um;
        if predicted > 0.0 {
            (self.machine_before_um - self.machine_after_um) / predicted
        } else {
            f64::NAN
        }
    }
}

/// Why a transfer check could not run.
#[derive(Debug, thiserror::Error)]
pub enum TransferError {
    /// The independent machine failed.
    #[error(transparent)]
    Indep(#[from] crate::indep::IndepError),
    /// The diagnosis failed.
    #[error(transparent)]
    Diagnose(#[from] crate::diagnose::DiagnoseError),
    /// The tune failed.
    #[error(transparent)]
    Tune(#[from] TuneError),
    /// The diagnosis gave no model.
    #[error("the diagnosis returned no fitted preset")]
    NoModel,
}

/// The transfer check: an independent machine's record is diagnosed, the backlash and
/// quadrant compensation tuned on the fitted model (from zero: Q = 0, M0 = 0, as an operator
/// starts), the corrections those settings compute from the record's command fed into the
/// same independent machine, and the reversal glitch compared with what the model predicted.
pub fn transfer(
    spec: &crate::indep::CaseSpec,
    weights: Weights,
    seed: u64,
    max_iters: u64,
) -> Result<Transfer, TransferError> {
    use crate::diagnose::{self, replay::Record};
    let case = crate::indep::generate(spec)?;
    let axis = case
        .preset
        .axes
        .first()
        .map_or("x".to_owned(), |a| a.name.clone());
    let rec = Record::for_preset(&case.trace, &case.name, &case.preset, &axis)?;
    let cancel = AtomicBool::new(false);
    let report = diagnose::diagnose(
        &case.preset,
        &rec,
        None,
        &diagnose::Options::default(),
        &diagnose::Progress {
            report: &|_, _| {},
            cancel: &cancel,
        },
    )?;
    let mut model = report.fitted.clone().ok_or(TransferError::NoModel)?;
    // The calibration may put the nominal's marginal loop over the edge of the discrete
    // stability check (its mass and gain factors, a few per cent, describe the record's
    // response): the compensation is then tuned with the nominal's drive and controller,
    // keeping the named effects.
    if !crate::machine::check(&model).is_empty()
        && let (Some(a), Some(n)) = (
            model.axes.iter_mut().find(|a| a.name == axis),
            case.preset.axes.iter().find(|a| a.name == axis),
        )
    {
        a.servo = n.servo.clone();
        a.drive = n.drive.clone();
    }
    // A play the diagnosis named lets the motor run alone across the gap, a loop the
    // record's 1 ms amplifier period may not hold in the discrete model: the model then
    // runs its amplifier faster (the settings tuned are in µm, N·m and ms, not in samples).
    for _ in 0..3 {
        if crate::machine::check(&model).is_empty() {
            break;
        }
        model.timing.t3_s /= 4.0;
    }
    if let Some(a) = model.axes.iter_mut().find(|a| a.name == axis) {
        a.backlash.enabled = true;
        a.backlash.q_um = 0.0;
        a.quadrant.enabled = true;
        a.quadrant.inject = Injection::Torque;
        a.quadrant.m0_torque_nm = 0.0;
    }
    let lp = crate::preset::load_embedded("emps.ron").map_err(TuneError::Preset)?;
    let programs = lp.programs().map_err(TuneError::Preset)?;
    model.scenario = lp.preset.scenario.clone();
    let job = Job {
        preset: &model,
        programs: &programs,
        axis: axis.clone(),
        what: vec![What::Backlash, What::Quadrant],
        weights,
        seed,
        max_iters,
        threads: 0,
    };
    let outcome = tune(
        &job,
        &Progress {
            report: &|_| {},
            cancel: &cancel,
        },
    )?;
    let cmd = case
        .trace
        .axis_values(&axis, crate::trace::AxisSignal::Cmd)
        .map(<[f64]>::to_vec)
        .unwrap_or_default();
    let corr = corrections(&outcome.preset, &axis, &cmd, case.preset.timing.t3_s);
    let corrected = crate::indep::generate_corrected(spec, Some(&corr))?;
    Ok(Transfer {
        named: report.selected.clone(),
        machine_before_um: mean_peak_um(&case.trace, &axis),
        machine_after_um: mean_peak_um(&corrected.trace, &axis),
        model_before_um: mean_peak_change_um(&outcome.before.reversals),
        model_after_um: mean_peak_change_um(&outcome.after.reversals),
        values: outcome.values.clone(),
    })
}
