//! The command line: a thin layer over the model.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};

use axisbench::Machine;
use axisbench::analysis;
use axisbench::comp::quadrant::Quadrant;
use axisbench::comp::thermal::Thermal;
use axisbench::export::{self, ExportOptions, Status, Target};
use axisbench::measure;
use axisbench::preset::{self, LoadedPreset};

/// println! that ends the program quietly when stdout is closed (`| head`), instead of
/// panicking on a broken pipe.
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        if writeln!(std::io::stdout(), $($t)*).is_err() {
            std::process::exit(0);
        }
    }};
}

/// print! with the same broken-pipe handling as `say!`.
macro_rules! say_raw {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        if write!(std::io::stdout(), $($t)*).is_err() {
            std::process::exit(0);
        }
    }};
}

mod diag;
mod tune;

/// A flag or argument outside what it can mean: bad usage, exit status 2 (bad input,
/// a file that does not parse or a preset that is invalid, exits with 1).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

/// `value` of flag `name` if it is finite and within `lo ..= hi`.
pub(crate) fn flag(name: &str, value: f64, lo: f64, hi: f64, unit: &str) -> Result<f64> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(value)
    } else {
        Err(UsageError(format!(
            "{name} {}: must be a number in {lo} … {hi}{}",
            axisbench::preset::fields::short(value),
            if unit.is_empty() {
                String::new()
            } else {
                format!(" {unit}")
            }
        ))
        .into())
    }
}

/// A whole-number flag within `lo ..= hi`.
pub(crate) fn count_flag(name: &str, value: u64, lo: u64, hi: u64) -> Result<u64> {
    if (lo..=hi).contains(&value) {
        Ok(value)
    } else {
        Err(UsageError(format!(
            "{name} {value}: must be a whole number in {lo} … {hi}"
        ))
        .into())
    }
}

/// The exit status for an error: 2 for bad usage, 1 for bad input.
pub fn exit_status(e: &anyhow::Error) -> i32 {
    let usage = e.chain().any(|c| {
        c.downcast_ref::<UsageError>().is_some()
            || matches!(
                c.downcast_ref::<axisbench::MachineError>(),
                Some(axisbench::MachineError::Argument(_))
            )
    });
    if usage { 2 } else { 1 }
}

#[derive(Parser, Debug)]
#[command(
    name = "axisbench",
    version,
    about = "Tuning workbench for CNC feed-axis compensations"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
    /// With no command: open the workbench on this preset file (or `embedded:NAME.ron`, a
    /// shipped scenario) instead of the saved session.
    #[arg(long, global = false)]
    pub preset: Option<PathBuf>,
    /// With no command: open with the model paused (it runs from the first frame otherwise).
    #[arg(long)]
    pub paused: bool,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Run a preset headless, write the trace CSV and print a summary.
    Simulate {
        /// Preset file, or `embedded:NAME.ron` for a shipped one.
        #[arg(long, default_value = "embedded:default.ron")]
        preset: String,
        /// Program file to run instead of the preset's (first channel).
        #[arg(long)]
        program: Option<PathBuf>,
        /// Run for this long (s) instead of to the program end.
        #[arg(long)]
        duration: Option<f64>,
        /// Trace CSV to write.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Override a preset field: --set axes.z.backlash.minus_to_plus.mode=lump (repeatable).
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
        /// Also run with every compensation off and print both summaries.
        #[arg(long)]
        compare: bool,
        /// Measure a sag table of N points for every tool post of the crossbeam and install
        /// them as the cross tables before running.
        #[arg(long, value_name = "N")]
        measure_cross: Option<usize>,
    },
    /// Measuring cycles on the simulated machine, as on a real one.
    Measure {
        #[command(subcommand)]
        what: MeasureCmd,
    },
    /// Thermal correction calibration (thermal patent, SPEC §4) on simulated measurements.
    Calibrate {
        #[command(subcommand)]
        step: CalibrateCmd,
    },
    /// Check preset files; exits non-zero listing every error.
    Validate {
        #[arg(required = true)]
        presets: Vec<String>,
    },
    /// Export a preset to a controller: its files plus mapping_report.md/.json in DIR.
    /// Nothing is written unless every check passes.
    Export {
        /// Preset file, or `embedded:NAME.ron` for a shipped one.
        #[arg(long)]
        preset: String,
        /// ron, linuxcnc, siemens, heidenhain, beckhoff or fanuc.
        #[arg(long)]
        to: String,
        /// Output folder (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Override a preset field before exporting (repeatable).
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
        /// Machine time the report's simulations cover, s (default: the scenario, at most 60 s).
        #[arg(long)]
        horizon: Option<f64>,
    },
    /// Read an exported RON or LinuxCNC configuration back into a preset file.
    Import {
        /// ron or linuxcnc.
        #[arg(long)]
        from: String,
        /// preset.ron / linuxcnc.ini, or the export folder holding it.
        #[arg(long = "in")]
        input: PathBuf,
        /// Preset the LinuxCNC settings are read onto (joint n = its n-th axis); also where
        /// missing program files are copied from.
        #[arg(long, default_value = "embedded:default.ron")]
        base: String,
        /// Preset file to write.
        #[arg(long)]
        out: PathBuf,
    },
    /// Print model throughput (axis-steps per second) for the full model.
    Bench {
        /// Axis-steps per configuration, recording on as off (a recorded run stops at the
        /// trace's 1 GiB limit, and its line says how many steps it timed).
        #[arg(long, default_value_t = 6_000_000)]
        steps: u64,
        /// Measure the workbench's frame time instead (headless, plots full).
        #[arg(long)]
        frames: Option<usize>,
        /// Time the diagnosis of a generated record of this many samples instead.
        #[arg(long, value_name = "SAMPLES")]
        diagnose: Option<usize>,
        /// Only this figure: `step` (AxisLoop::step alone), `off` (full model, recording
        /// off), `on` (recording on) or `default` (the machine on default.ron, the peer's
        /// physics, recording off and on).
        #[arg(long, value_parser = ["step", "off", "on", "default"])]
        only: Option<String>,
    },
    /// Sim-to-real diagnosis: replay a measured record through the preset, find where the
    /// residual lies and which unmodelled effect explains it, and how far it shrinks.
    Diagnose {
        /// The nominal preset of the measured machine.
        #[arg(long)]
        preset: String,
        /// Measured record (TRACE_FORMAT.md, or a foreign layout through --map or the
        /// preset's default mapping). The candidates are fitted on it.
        #[arg(long)]
        trace: PathBuf,
        /// Column mapping for a foreign layout, e.g. "t[s]=t_s, x.cmd[m]=qg_m, x.pos[m]=qm_m".
        #[arg(long)]
        map: Option<String>,
        /// A second record for held-out scoring. Without it, the end of --trace is held out.
        #[arg(long)]
        validate: Option<PathBuf>,
        /// Fraction of --trace held out when there is no --validate record.
        #[arg(long, default_value_t = 0.3)]
        holdout: f64,
        /// Axis to diagnose (default: the first preset axis in the record).
        #[arg(long)]
        axis: Option<String>,
        /// Try only these candidates (comma-separated effect names).
        #[arg(long, value_delimiter = ',')]
        effects: Vec<String>,
        /// Write the report as JSON here.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Write the preset with the selected effects added here.
        #[arg(long)]
        apply: Option<PathBuf>,
        /// Write the held-out residuals (before/after, with regimes) as CSV here.
        #[arg(long)]
        residuals: Option<PathBuf>,
    },
    /// Auto-tune the compensation on the simulated machine: search the parameters for the
    /// smallest error change at the program's reversals, print a before/after table per
    /// reversal, write the tuned preset. Never returns values worse than the start.
    Tune(tune::Args),
    /// Transfer check of the tune: independent machines (src/indep) with hidden effects are
    /// diagnosed, the compensation tuned on the fitted model and run on the machine; prints
    /// the reversal glitch on the machine before and after next to the model's prediction.
    TuneTransfer(tune::TransferArgs),
    /// Blind check of the diagnosis: generated cases with hidden effects.
    DiagnoseEval {
        /// Which generator makes the records: `independent` (a second simulator sharing no
        /// code with the model: the honest figure) or `own` (the model itself:
        /// in-distribution).
        #[arg(long, default_value = "independent", value_parser = ["independent", "own"])]
        generator: String,
        /// Cases of the own generator (the independent set has a fixed composition).
        #[arg(long, default_value_t = 70)]
        cases: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Seconds of motion per case.
        #[arg(long, default_value_t = axisbench::indep::STANDARD_DURATION_S)]
        duration: f64,
        /// Print one line per case.
        #[arg(long)]
        verbose: bool,
        /// Run only these case numbers (comma-separated), e.g. to look at one closely.
        #[arg(long, value_delimiter = ',')]
        only: Vec<usize>,
    },
    /// Write the independent generator's check cases (records of a second simulator with
    /// known hidden effects) to DIR: <name>.csv, <name>.ron (nominal preset), truth.json.
    /// The same records `diagnose-eval --seed N` scores (same seed, same duration).
    GenCases {
        /// Output folder (created if missing).
        #[arg(long)]
        out: PathBuf,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Seconds of motion per case, 1–3600 (the same default as diagnose-eval's).
        #[arg(long, default_value_t = axisbench::indep::STANDARD_DURATION_S)]
        duration: f64,
        /// Only these kinds (comma-separated): clean, single, pair, clean_skew,
        /// single_skew, pair_skew.
        #[arg(long, value_delimiter = ',')]
        kind: Vec<String>,
    },
}

#[derive(Subcommand, Debug)]
pub enum MeasureCmd {
    /// Reversal test: lost motion Q of an axis (compensation off).
    Backlash {
        #[arg(long)]
        preset: String,
        #[arg(long)]
        axis: String,
    },
    /// Sag table: move the base axis across the beam and read the Z error at N points.
    Sag {
        #[arg(long)]
        preset: String,
        /// Base axis (moves along the beam).
        #[arg(long)]
        base: String,
        /// Compensated axis (the tool post's Z).
        #[arg(long)]
        axis: String,
        #[arg(long, default_value_t = 9)]
        points: usize,
        /// Start of the table, mm (default 0).
        #[arg(long)]
        from: Option<f64>,
        /// End of the table, mm (default the beam span).
        #[arg(long)]
        to: Option<f64>,
    },
    /// Real thermal displacement at the thermal measurement point at intervals.
    Thermal {
        #[arg(long)]
        preset: String,
        #[arg(long)]
        axis: String,
        #[arg(long, default_value_t = 300.0)]
        interval: f64,
    },
}

#[derive(Subcommand, Debug)]
pub enum CalibrateCmd {
    /// Step 1: fit k over several programs (each run from cold, E = 1, measuring at intervals).
    Step1 {
        #[arg(long)]
        preset: String,
        #[arg(long)]
        axis: String,
        /// Program files (repeatable); default: the preset's own program.
        #[arg(long = "program")]
        programs: Vec<PathBuf>,
        #[arg(long, default_value_t = 60.0)]
        interval: f64,
        /// Override a preset field (repeatable).
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
    },
    /// Step 2: a from one measurement at time --at with the preset's k.
    Step2 {
        #[arg(long)]
        preset: String,
        #[arg(long)]
        axis: String,
        #[arg(long)]
        at: f64,
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
    },
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        None => open_gui(cli.preset, cli.paused),
        Some(Command::Simulate {
            preset,
            program,
            duration,
            out,
            sets,
            compare,
            measure_cross,
        }) => simulate(
            &preset,
            program,
            duration,
            out,
            &sets,
            compare,
            measure_cross,
        ),
        Some(Command::Measure { what }) => measure(what),
        Some(Command::Calibrate { step }) => calibrate(step),
        Some(Command::Validate { presets }) => validate(&presets),
        Some(Command::Export {
            preset,
            to,
            out,
            sets,
            horizon,
        }) => {
            if let Some(h) = horizon {
                flag(
                    "--horizon",
                    h,
                    0.01,
                    axisbench::preset::rules::MAX_DURATION_S,
                    "s",
                )?;
            }
            export(&preset, &to, &out, &sets, horizon)
        }
        Some(Command::Import {
            from,
            input,
            base,
            out,
        }) => import(&from, &input, &base, &out),
        Some(cmd @ Command::Bench { .. }) => bench_cmd(cmd),
        Some(Command::Diagnose {
            preset,
            trace,
            map,
            validate,
            holdout,
            axis,
            effects,
            report,
            apply,
            residuals,
        }) => {
            if validate.is_none() {
                flag("--holdout", holdout, 0.05, 0.8, "of the record")?;
            }
            diag::diagnose(diag::Args {
                residuals,
                preset,
                trace,
                map,
                validate,
                holdout,
                axis,
                effects,
                report,
                apply,
            })
        }
        Some(Command::Tune(a)) => tune::run(a),
        Some(Command::TuneTransfer(a)) => tune::transfer_run(a),
        Some(Command::DiagnoseEval {
            generator,
            cases,
            seed,
            duration,
            verbose,
            only,
        }) => {
            count_flag("--cases", cases as u64, 1, 10_000)?;
            flag("--duration", duration, 5.0, 3600.0, "s")?;
            diag::eval(&generator, cases, seed, duration, verbose, only)
        }
        Some(Command::GenCases {
            out,
            seed,
            duration,
            kind,
        }) => gen_cases(&out, seed, duration, &kind),
    }
}

/// `bench`: frame cost of the GUI, diagnosis throughput, or model steps per second.
fn bench_cmd(cmd: Command) -> Result<()> {
    match cmd {
        Command::Bench {
            frames: Some(n), ..
        } => {
            count_flag("--frames", n as u64, 1, 100_000)?;
            let (mean, p99, max) = crate::app::bench_frames(n)?;
            say!(
                "frames={n} window=10s rate=8kHz plots=4 frame_ms_mean={mean:.3} frame_ms_p99={p99:.3} frame_ms_max={max:.3}"
            );
            Ok(())
        }
        Command::Bench {
            diagnose: Some(n), ..
        } => {
            count_flag("--diagnose", n as u64, 1000, 10_000_000)?;
            diag::bench(n)
        }
        Command::Bench { steps, only, .. } => {
            count_flag("--steps", steps, 1000, 10_000_000_000)?;
            bench(steps, only.as_deref())
        }
        _ => Ok(()),
    }
}

/// `gen-cases`: the independent generator's standard set, filtered by kind, on disk.
fn gen_cases(out: &std::path::Path, seed: u64, duration: f64, kinds: &[String]) -> Result<()> {
    use axisbench::indep::{self, CaseKind};
    if !(duration.is_finite() && (1.0..=3600.0).contains(&duration)) {
        bail!("--duration {duration}: must be a number of seconds in 1…3600");
    }
    let mut want = Vec::new();
    for k in kinds {
        match CaseKind::from_name(k.trim()) {
            Some(kind) => want.push(kind),
            None => bail!(
                "--kind {k}: unknown kind; kinds are {}",
                CaseKind::ALL.map(|k| k.name()).join(", ")
            ),
        }
    }
    let mut specs = indep::standard_set(seed, duration);
    specs.retain(|s| want.is_empty() || want.contains(&CaseKind::of(s)));
    let t0 = std::time::Instant::now();
    let n = specs.len();
    let files = indep::write_cases(out, &specs, &mut |i, name| {
        eprint!("\r[{}/{n}] {name:<16}", i + 1);
    });
    eprintln!();
    let files = files.with_context(|| format!("writing the cases to {}", out.display()))?;
    say!(
        "{} cases ({} files) written to {} in {:.1} s; the truths are in truth.json",
        n,
        files.len(),
        out.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The error and its causes on one line, each cause once: a cause whose text the message
/// already holds (an OS error an error type also prints) is not repeated.
pub fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let c = cause.to_string();
        if text.contains(&c) {
            continue;
        }
        if !text.is_empty() {
            text += ": ";
        }
        text += &c;
    }
    text
}

fn open_gui(preset: Option<PathBuf>, paused: bool) -> Result<()> {
    let has_display =
        std::env::var_os("DISPLAY").is_some() || std::env::var_os("WAYLAND_DISPLAY").is_some();
    if !has_display {
        bail!(
            "no display found (DISPLAY/WAYLAND_DISPLAY unset), so the workbench window cannot open.\n\
             Use the command line instead, e.g.:\n  \
             axisbench simulate --preset presets/default.ron --out trace.csv\n  \
             axisbench validate presets/*.ron\n  \
             axisbench --help"
        );
    }
    crate::app::run(preset, paused)
}

/// Loads a preset and applies `--set` overrides in order.
pub fn load_with_sets(path: &str, sets: &[String]) -> Result<LoadedPreset> {
    let mut lp = preset::load(path)?;
    for s in sets {
        let (k, v) = s
            .split_once('=')
            .with_context(|| format!("--set {s}: expected PATH=VALUE"))?;
        lp.preset = lp.preset.set(k.trim(), v.trim())?;
    }
    Ok(lp)
}

pub(crate) fn program_texts(
    lp: &LoadedPreset,
    program: Option<&PathBuf>,
) -> Result<Vec<(String, String)>> {
    let Some(p) = program else {
        return Ok(lp.programs()?);
    };
    let Some((_, others)) = lp.preset.scenario.programs.split_first() else {
        return Ok(vec![]);
    };
    let first = (
        p.display().to_string(),
        std::fs::read_to_string(p)
            .with_context(|| format!("{}: cannot read program", p.display()))?,
    );
    let mut texts = vec![first];
    for name in others {
        texts.push((name.clone(), lp.program_text(name)?));
    }
    Ok(texts)
}

fn simulate(
    preset_path: &str,
    program: Option<PathBuf>,
    duration: Option<f64>,
    out: Option<PathBuf>,
    sets: &[String],
    compare: bool,
    measure_cross: Option<usize>,
) -> Result<()> {
    let mut lp = load_with_sets(preset_path, sets)?;
    if let Some(d) = duration {
        flag(
            "--duration",
            d,
            lp.preset.timing.t3_s,
            axisbench::preset::rules::MAX_DURATION_S,
            "s",
        )?;
        lp.preset.scenario.duration_s = Some(d);
    }
    if let Some(n) = measure_cross {
        count_flag("--measure-cross", n as u64, 2, 65)?;
        let cb = lp.preset.crossbeam.clone();
        if !cb.enabled {
            bail!("--measure-cross: {} has no crossbeam", lp.origin);
        }
        let tables = measure::sag_tables(&lp.preset, n)?;
        for t in &tables {
            say!(
                "measured cross table {} over {} ({n} points, µm):",
                t.comp_axis,
                t.base_axis
            );
            for (x, dz) in &t.points {
                say!("  x = {x:9.3} mm  ΔZ = {dz:8.3} µm");
            }
        }
        lp.preset.cross = tables;
    }
    let texts = program_texts(&lp, program.as_ref())?;
    let runs: Vec<(&str, axisbench::Preset)> = if compare {
        vec![
            ("compensated", lp.preset.clone()),
            ("uncompensated", lp.preset.compensations_off()),
        ]
    } else {
        vec![("", lp.preset.clone())]
    };
    for (label, p) in runs {
        let mut m = Machine::new(&p, &texts)?;
        m.trace.meta.push(("preset_file".into(), lp.origin.clone()));
        let limit_s = duration.unwrap_or(4.0 * 3600.0);
        if let Some(d) = duration {
            trace_fits(&m, d)?;
        }
        m.run(limit_s)?;
        if !m.done() {
            eprintln!(
                "warning: stopped after {limit_s} s of machine time before the program ended"
            );
        }
        if !label.is_empty() {
            say!("== {label}");
        }
        let sums = analysis::summarize(&m.trace);
        say_raw!("{}", analysis::format_summary(&m.trace, &sums));
        say_raw!("{}", comp_report(&m));
        if let (Some(out), true) = (&out, label != "uncompensated") {
            m.trace.write_csv(out)?;
            say!("trace written to {}", out.display());
        }
    }
    Ok(())
}

/// Refuses, before running, a fixed-length run whose trace would outgrow its memory limit.
fn trace_fits(m: &Machine, duration_s: f64) -> Result<()> {
    let every = f64::from(m.preset.scenario.trace_every.max(1));
    let rows = duration_s / m.t3_s / every;
    let bytes = rows * m.trace.signals.len() as f64 * 8.0;
    let limit = axisbench::machine::MAX_TRACE_BYTES as f64;
    if bytes > limit {
        let need = (bytes / limit).ceil();
        return Err(UsageError(format!(
            "--duration {duration_s} s would record {rows:.3e} rows, about {:.1} GiB of trace (limit {:.1} GiB): record every n-th sample with --set scenario.trace_every={} or more, or shorten --duration",
            bytes / f64::from(1u32 << 30),
            limit / f64::from(1u32 << 30),
            (need * every) as u64
        ))
        .into());
    }
    Ok(())
}

/// What the compensations did, in one line each.
fn comp_report(m: &Machine) -> String {
    let mut s = String::new();
    for t in m.find_comp::<Thermal>() {
        s += &format!(
            "thermal correction: {} measurements, a = {:.4}, E = {:.4}, F = {:.3} µm\n",
            t.measurements,
            t.p.a,
            t.e,
            axisbench::units::m_to_um(t.f_m)
        );
    }
    for (q, a) in m.find_comp::<Quadrant>().zip(m.axes.iter()) {
        s += &format!(
            "quadrant {}: {} reversals, last PA = {:.3} mm, N = {}, M = {:.4}, T = {:.2} ms\n",
            a.name,
            q.reversals,
            if q.pa_m.is_finite() {
                axisbench::units::m_to_mm(q.pa_m)
            } else {
                0.0
            },
            q.n,
            q.m,
            axisbench::units::s_to_ms(q.t_s)
        );
    }
    s
}

fn measure(what: MeasureCmd) -> Result<()> {
    match what {
        MeasureCmd::Backlash { preset, axis } => {
            let lp = preset::load(&preset)?;
            let q = measure::backlash_um(&lp.preset, &axis)?;
            say!("backlash (lost motion) of {axis}: Q = {q:.3} µm");
        }
        MeasureCmd::Sag {
            preset,
            base,
            axis,
            points,
            from,
            to,
        } => {
            let lp = preset::load(&preset)?;
            count_flag("--points", points as u64, 2, 1000)?;
            for (name, v) in [("--from", from), ("--to", to)] {
                if let Some(v) = v {
                    flag(name, v, -1e5, 1e5, "mm")?;
                }
            }
            let span = lp.preset.crossbeam.span_mm;
            let table = measure::sag_table(
                &lp.preset,
                &base,
                &axis,
                points,
                from.unwrap_or(0.0),
                to.unwrap_or(span),
            )?;
            say!("sag table for {axis} over {base} (x mm, correction µm):");
            for (x, dz) in table {
                say!("  ({x:.3}, {dz:.3}),");
            }
        }
        MeasureCmd::Thermal {
            preset,
            axis,
            interval,
        } => {
            let lp = preset::load(&preset)?;
            let texts = program_texts(&lp, None)?;
            for (t, d) in measure::thermal_series(&lp.preset, &texts, &axis, interval)? {
                say!("t = {t:8.1} s  D = {d:8.3} µm");
            }
        }
    }
    Ok(())
}

fn calibrate(step: CalibrateCmd) -> Result<()> {
    match step {
        CalibrateCmd::Step1 {
            preset,
            axis,
            programs,
            interval,
            sets,
        } => {
            let lp = load_with_sets(&preset, &sets)?;
            let runs = if programs.is_empty() {
                vec![program_texts(&lp, None)?]
            } else {
                programs
                    .iter()
                    .map(|p| program_texts(&lp, Some(p)))
                    .collect::<Result<Vec<_>>>()?
            };
            let fit = measure::thermal_step1(&lp.preset, &axis, &runs, interval)?;
            for (j, (a, k, n)) in fit.fits.iter().enumerate() {
                say!(
                    "program {}: r = {a:.4} + {k:.6}·|F|/µm over {n} points",
                    j + 1
                );
            }
            say!(
                "k = {:.6} per µm (mean of {} programs)",
                fit.k_per_um,
                fit.fits.len()
            );
        }
        CalibrateCmd::Step2 {
            preset,
            axis,
            at,
            sets,
        } => {
            let lp = load_with_sets(&preset, &sets)?;
            let texts = program_texts(&lp, None)?;
            let a = measure::thermal_step2(&lp.preset, &axis, &texts, at)?;
            say!(
                "a = {a:.4} (measured at t = {at} s, k = {})",
                lp.preset
                    .axes
                    .iter()
                    .find(|x| x.name == axis)
                    .map_or(0.0, |x| x.thermal.k_per_um)
            );
        }
    }
    Ok(())
}

fn validate(paths: &[String]) -> Result<()> {
    let mut bad = 0;
    for p in paths {
        match preset::load(p).map_err(anyhow::Error::from).and_then(|lp| {
            Machine::from_loaded(&lp)?;
            Ok(())
        }) {
            Ok(()) => say!("{p}: ok"),
            Err(e) => {
                bad += 1;
                eprintln!("{e:#}");
            }
        }
    }
    if bad > 0 {
        bail!("{bad} of {} presets are invalid", paths.len());
    }
    Ok(())
}

fn export(
    preset_path: &str,
    to: &str,
    out: &std::path::Path,
    sets: &[String],
    horizon: Option<f64>,
) -> Result<()> {
    let target: Target = to.parse().map_err(anyhow::Error::msg)?;
    let lp = load_with_sets(preset_path, sets)?;
    let texts = program_texts(&lp, None)?;
    let opts = ExportOptions { horizon_s: horizon };
    let ex = export::export(&lp.preset, &texts, target, &opts)?;
    let written = ex.write(out)?;
    for p in &written {
        say!("wrote {}", p.display());
    }
    let r = &ex.report;
    let count = |s: Status| r.with_status(s).count();
    say!(
        "{} settings: {} mapped, {} derived, {} approximated, {} not representable, {} without a documented parameter (see mapping_report.md)",
        r.entries.len(),
        count(Status::Mapped),
        count(Status::Derived),
        count(Status::Approximated),
        count(Status::NotRepresentable),
        count(Status::NoDocumentedParameter)
    );
    Ok(())
}

fn import(from: &str, input: &std::path::Path, base: &str, out: &std::path::Path) -> Result<()> {
    let target: Target = from.parse().map_err(anyhow::Error::msg)?;
    let base = preset::load(base)?;
    let p = export::import::import(target, input, &base)?;
    export::import::write_preset(&p, out, &base)?;
    say!("wrote {}", out.display());
    Ok(())
}

fn bench(steps: u64, only: Option<&str>) -> Result<()> {
    let want = |k: &str| only.is_none_or(|o| o == k);
    if want("step") {
        let f = axisbench::bench::step_kernel(steps)?;
        say!(
            "step alone (AxisLoop::step, default.ron x, recorded inputs) steps={} axis_steps_per_s={:.0}",
            f.steps,
            f.axis_steps_per_s
        );
    }
    let full = |n: usize, n_steps: u64, rec: bool| -> Result<()> {
        let f = axisbench::bench::run(n, n_steps, rec)?;
        say!(
            "axes={} recording={} steps={} axis_steps_per_s={:.0}",
            f.n_axes,
            if rec { "on" } else { "off" },
            f.steps,
            f.axis_steps_per_s
        );
        Ok(())
    };
    match only {
        Some("off") => return full(1, steps, false),
        Some("on") => return full(1, steps, true),
        Some("step") => return Ok(()),
        _ => {}
    }
    if only.is_none() {
        full(1, steps, false)?;
        full(3, steps, false)?;
        full(1, steps, true)?;
    }
    let p = axisbench::bench::default_model_preset()?;
    for rec in [false, true] {
        let f = axisbench::bench::run_preset(&p, steps, rec)?;
        say!(
            "machine on default.ron (the peer's physics + NC) recording={} steps={} axis_steps_per_s={:.0}",
            if rec { "on" } else { "off" },
            f.steps,
            f.axis_steps_per_s
        );
    }
    if only.is_none() {
        let f = axisbench::bench::run(1, steps, false)?;
        say!("axis_steps_per_s={:.0}", f.axis_steps_per_s);
    }
    Ok(())
}
