//! `axisbench tune`: the compensation searched on the simulated machine, a before/after
//! table per reversal, the tuned preset written with its programs (all or nothing).

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use anyhow::{Context, Result};
use axisbench::tune::{self, Job, Outcome, Progress, Weights, What};
use axisbench::units::fmt_qty;

use super::{load_with_sets, program_texts};

/// The arguments of `axisbench tune`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Preset file, or `embedded:NAME.ron` for a shipped one.
    #[arg(long, default_value = "embedded:default.ron")]
    preset: String,
    /// Axis to tune (default: the preset's first).
    #[arg(long)]
    axis: Option<String>,
    /// What to tune, comma-separated: backlash, quadrant, thermal, cross.
    #[arg(long, default_value = "backlash,quadrant")]
    what: String,
    /// Program to tune on instead of the preset's (first channel).
    #[arg(long)]
    program: Option<PathBuf>,
    /// Write the tuned preset (and its programs, next to it) here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write the report (before/after figures, values, simulations) as JSON here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Objective weights per µm: `peak=1,settled=1,rms=0.2` (the defaults).
    #[arg(long)]
    weights: Option<String>,
    /// Seed of the extra starts (same seed, same result).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Nelder–Mead iterations per start.
    #[arg(long, default_value_t = 80)]
    iters: u64,
    /// Override a preset field before tuning (repeatable), as for simulate.
    #[arg(long = "set", value_name = "PATH=VALUE")]
    sets: Vec<String>,
    /// Instead of the search, the dense-grid check: N values per searched number over
    /// the same stages (offline: N^dims simulations); prints the best objective and
    /// the time.
    #[arg(long, value_name = "N")]
    grid: Option<usize>,
}

pub fn run(a: Args) -> Result<()> {
    super::count_flag("--iters", a.iters, 1, 100_000)?;
    if let Some(n) = a.grid {
        super::count_flag("--grid", n as u64, 2, 64)?;
    }
    let what = What::parse_list(&a.what)?;
    let weights = match &a.weights {
        Some(w) => Weights::parse(w)?,
        None => Weights::default(),
    };
    let mut lp = load_with_sets(&a.preset, &a.sets)?;
    let mut texts = program_texts(&lp, a.program.as_ref())?;
    if let (Some(p), Some(first)) = (&a.program, texts.first_mut()) {
        // The tuned preset runs the program it was tuned on.
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .with_context(|| format!("--program {}: not a file name", p.display()))?;
        first.0 = name.clone();
        if let Some(s) = lp.preset.scenario.programs.first_mut() {
            *s = name;
        }
    }
    let axis = a
        .axis
        .clone()
        .or_else(|| lp.preset.axes.first().map(|x| x.name.clone()))
        .context("the preset has no axis")?;
    let job = Job {
        preset: &lp.preset,
        programs: &texts,
        axis,
        what,
        weights,
        seed: a.seed,
        max_iters: a.iters,
        threads: 0,
    };
    let cancel = AtomicBool::new(false);
    let report = |st: tune::Status| {
        let share = st
            .share_done()
            .map(|d| format!(", {:.0} % of the search", 100.0 * d))
            .unwrap_or_default();
        eprint!(
            "\r  {} simulations, best objective {}{share}        ",
            st.simulations,
            fmt_qty(st.best, "")
        );
    };
    let progress = Progress {
        report: &report,
        cancel: &cancel,
    };
    if let Some(n) = a.grid {
        let g = tune::grid(&job, n, &progress)?;
        eprintln!();
        say!(
            "grid of {n} values per searched number: objective {} -> best {} ({} simulations, {:.1} s)",
            fmt_qty(g.start, ""),
            fmt_qty(g.best, ""),
            g.simulations,
            g.wall_s
        );
        return Ok(());
    }
    let out = tune::tune(&job, &progress)?;
    eprintln!();
    print_outcome(&out);
    if let Some(path) = &a.out {
        out.preset
            .save_with_programs(path, &texts)
            .with_context(|| format!("writing the tuned preset {}", path.display()))?;
        say!("tuned preset: {} (with its programs)", path.display());
    }
    if let Some(path) = &a.report {
        let json = serde_json::to_string_pretty(&out)?;
        axisbench::fsutil::write_atomic(path, json.as_bytes())
            .with_context(|| format!("writing the report {}", path.display()))?;
        say!("report: {}", path.display());
    }
    Ok(())
}

fn print_outcome(o: &tune::Outcome) {
    let w = &o.weights;
    say!(
        "tune of {} on axis {}: objective = {}·mean peak change + {}·mean |settled change| + {}·RMS error (µm)",
        o.what
            .iter()
            .map(|w| w.name())
            .collect::<Vec<_>>()
            .join(", "),
        o.axis,
        w.peak,
        w.settled,
        w.rms
    );
    say!(
        "  objective {} -> {}{}; {} simulations in {:.2} s ({:.0} per s)",
        fmt_qty(o.before.objective, ""),
        fmt_qty(o.after.objective, ""),
        if o.kept_start {
            " (no start beat the values given: they are kept)"
        } else {
            ""
        },
        o.simulations,
        o.wall_s,
        o.simulations_per_s
    );
    let widths = [8, 10, 20, 12, 20, 24, 12];
    let line = |cells: &[String]| {
        let text: Vec<String> = cells
            .iter()
            .zip(widths)
            .map(|(c, w)| format!("{c:<w$}"))
            .collect();
        say!("  {}", text.join(" ").trim_end());
    };
    line(&Outcome::TABLE_HEADER.map(str::to_owned));
    for row in o.table() {
        line(&row);
    }
    say!(
        "  of the tuned peak change, {} (mean) is there at the last sample before the reversal (the deceleration into it), out of reach of a compensation the reversal starts",
        fmt_qty(tune::mean_change_before_um(&o.after.reversals), "um")
    );
    say!("  tuned values:");
    for (k, v) in &o.values {
        say!("    {k} = {}", axisbench::units::fmt_sig(*v, 6));
    }
}

/// The arguments of `axisbench tune-transfer`.
#[derive(clap::Args, Debug)]
pub struct TransferArgs {
    /// First seed; one case per seed from it.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Cases.
    #[arg(long, default_value_t = 3)]
    cases: u64,
    /// Hidden effects of each case, comma-separated (names of `gen-cases`).
    #[arg(long, default_value = "backlash,coulomb_friction")]
    effects: String,
    /// Seconds of motion per case.
    #[arg(long, default_value_t = 24.0)]
    duration: f64,
}

/// `axisbench tune-transfer …` from its arguments.
pub fn transfer_run(a: TransferArgs) -> Result<()> {
    super::count_flag("--cases", a.cases, 1, 100)?;
    super::flag("--duration", a.duration, 5.0, 600.0, "s")?;
    transfer_cmd(a.seed, a.cases, &a.effects, a.duration)
}

/// `axisbench tune-transfer`: one line per case, then the share of the predicted cut the
/// machines got.
pub fn transfer_cmd(seed: u64, cases: u64, effects: &str, duration_s: f64) -> Result<()> {
    use axisbench::indep::{CaseSpec, EffectPick};
    let picks: Vec<EffectPick> = effects
        .split(',')
        .map(str::trim)
        .filter(|e| !e.is_empty())
        .map(|e| {
            EffectPick::new(e, None).with_context(|| format!("--effects: unknown effect '{e}'"))
        })
        .collect::<Result<_>>()?;
    say!(
        "case  named by the diagnosis             machine glitch before -> after   model predicted before -> after   share of the predicted cut"
    );
    let mut shares = vec![];
    for k in 0..cases {
        let mut spec = CaseSpec::new(&format!("transfer_{k}"), seed + k, picks.clone());
        spec.duration_s = Some(duration_s);
        let t = tune::transfer(&spec, Weights::default(), 1, 80)?;
        let share = t.share_of_predicted();
        shares.push(share);
        say!(
            "{:>4}  {:<34} {:>9} -> {:<9}          {:>9} -> {:<9}          {}",
            seed + k,
            t.named.join(" + "),
            fmt_qty(t.machine_before_um, "um"),
            fmt_qty(t.machine_after_um, "um"),
            fmt_qty(t.model_before_um, "um"),
            fmt_qty(t.model_after_um, "um"),
            axisbench::units::fmt_num(share)
        );
    }
    let ok = shares.iter().filter(|s| **s >= 0.5).count();
    say!(
        "{ok} of {} machines got at least half of the predicted cut",
        shares.len()
    );
    Ok(())
}
