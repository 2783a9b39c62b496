//! The command line: a thin layer over the model.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};

use axisbench::Machine;
use axisbench::analysis;
use axisbench::preset::{self, LoadedPreset};

#[derive(Parser, Debug)]
#[command(
    name = "axisbench",
    version,
    about = "Tuning workbench for CNC feed-axis compensations"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
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
        /// Override a preset field: --set axes.x.backlash.width_um=12 (repeatable).
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
    },
    /// Check preset files; exits non-zero listing every error.
    Validate {
        #[arg(required = true)]
        presets: Vec<String>,
    },
    /// Print model throughput (axis-steps per second) for the full model.
    Bench {
        /// Axis-steps per configuration.
        #[arg(long, default_value_t = 6_000_000)]
        steps: u64,
    },
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        None => open_gui(),
        Some(Command::Simulate {
            preset,
            program,
            duration,
            out,
            sets,
        }) => simulate(&preset, program, duration, out, &sets),
        Some(Command::Validate { presets }) => validate(&presets),
        Some(Command::Bench { steps }) => bench(steps),
    }
}

fn open_gui() -> Result<()> {
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
    bail!(
        "the workbench GUI is not part of this build yet; use the command line:\n  \
         axisbench simulate --preset presets/default.ron --out trace.csv\n  axisbench --help"
    )
}

/// Loads a preset and applies `--set` overrides in order.
pub fn load_with_sets(path: &str, sets: &[String]) -> Result<LoadedPreset> {
    let mut lp = preset::load(path)?;
    for s in sets {
        let (k, v) = s
            .split_once('=')
            .with_context(|| format!("--set {s}: expected PATH=VALUE"))?;
        lp.preset = lp.preset.with_override(k.trim(), v.trim())?;
    }
    Ok(lp)
}

fn simulate(
    preset_path: &str,
    program: Option<PathBuf>,
    duration: Option<f64>,
    out: Option<PathBuf>,
    sets: &[String],
) -> Result<()> {
    let mut lp = load_with_sets(preset_path, sets)?;
    if let Some(d) = duration {
        if !(d.is_finite() && d > 0.0) {
            bail!("--duration {d}: must be a positive number of seconds");
        }
        lp.preset.scenario.duration_s = Some(d);
    }
    let mut texts = Vec::new();
    for (i, name) in lp.preset.scenario.programs.iter().enumerate() {
        match (&program, i) {
            (Some(p), 0) => texts.push((
                p.display().to_string(),
                std::fs::read_to_string(p)
                    .with_context(|| format!("{}: cannot read program", p.display()))?,
            )),
            _ => texts.push((name.clone(), lp.program_text(name)?)),
        }
    }
    let mut m = Machine::new(&lp.preset, &texts)?;
    m.trace.meta.push(("preset_file".into(), lp.origin.clone()));
    let limit_s = duration.unwrap_or(4.0 * 3600.0);
    m.run(limit_s);
    if !m.done() {
        eprintln!("warning: stopped after {limit_s} s of machine time before the program ended");
    }
    let sums = analysis::summarize(&m.trace);
    print!("{}", analysis::format_summary(&m.trace, &sums));
    if let Some(out) = out {
        m.trace.write_csv(&out)?;
        println!("trace written to {}", out.display());
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
            Ok(()) => println!("{p}: ok"),
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

fn bench(steps: u64) -> Result<()> {
    for n in [1, 3] {
        let f = axisbench::bench::run(n, steps, false)?;
        println!(
            "axes={} recording=off steps={} axis_steps_per_s={:.0}",
            f.n_axes, f.steps, f.axis_steps_per_s
        );
    }
    let f = axisbench::bench::run(1, steps / 4, true)?;
    println!(
        "axes=1 recording=on steps={} axis_steps_per_s={:.0}",
        f.steps, f.axis_steps_per_s
    );
    let f = axisbench::bench::run(1, steps, false)?;
    println!("axis_steps_per_s={:.0}", f.axis_steps_per_s);
    Ok(())
}
