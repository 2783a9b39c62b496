//! `axisbench diagnose`, `diagnose-eval` and `bench --diagnose`.

use anyhow::{Context, Result, bail};
use axisbench::diagnose::{self, Effect, Options, Progress, Report, eval, replay::Record};
use axisbench::units::fmt_qty;
use std::io::Write as _;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

pub struct Args {
    pub preset: String,
    pub trace: PathBuf,
    pub map: Option<String>,
    pub validate: Option<PathBuf>,
    pub holdout: f64,
    pub axis: Option<String>,
    pub effects: Vec<String>,
    pub report: Option<PathBuf>,
    pub apply: Option<PathBuf>,
    pub residuals: Option<PathBuf>,
}

/// A progress line on stderr, rewritten in place (stdout stays clean for the summary).
fn progress_line(frac: f64, what: &str) {
    let mut e = std::io::stderr();
    let _ = write!(e, "\r[{:>3.0}%] {:<40}", frac * 100.0, what);
    if frac >= 1.0 {
        let _ = writeln!(e);
    }
    let _ = e.flush();
}

pub fn diagnose(a: Args) -> Result<()> {
    let lp = super::load_with_sets(&a.preset, &[])?;
    let preset = &lp.preset;
    let mut only = Vec::new();
    for name in &a.effects {
        match Effect::from_name(name.trim()) {
            Some(e) => only.push(e),
            None => bail!(
                "--effects: unknown effect '{name}'; known: {}",
                Effect::ALL.map(|e| e.name()).join(", ")
            ),
        }
    }
    let read = |p: &PathBuf| -> Result<(Record, String)> {
        let file = p.display().to_string();
        let tr = diagnose::read_record(p, preset, a.map.as_deref())?;
        let axis = diagnose::pick_axis(&tr, &file, preset, a.axis.as_deref())?;
        Ok((Record::for_preset(&tr, &file, preset, &axis)?, file))
    };
    let (main, main_file) = read(&a.trace)?;
    let validate = a.validate.as_ref().map(read).transpose()?;
    let opts = Options {
        axis: a.axis.clone(),
        holdout: a.holdout,
        only,
        max_effects: 3,
    };
    let cancel = AtomicBool::new(false);
    let report_fn = progress_line;
    let progress = Progress {
        report: &report_fn,
        cancel: &cancel,
    };
    let t0 = Instant::now();
    let rep = diagnose::diagnose(
        preset,
        &main,
        validate.as_ref().map(|v| &v.0),
        &opts,
        &progress,
    )?;
    let secs = t0.elapsed().as_secs_f64();
    print_summary(
        &rep,
        &main_file,
        validate.as_ref().map(|v| v.1.as_str()),
        secs,
    );
    if let Some(path) = &a.report {
        let json = serde_json::to_string_pretty(&rep)?;
        axisbench::fsutil::write_atomic(path, json.as_bytes())
            .with_context(|| format!("writing the report {}", path.display()))?;
        say!("report: {}", path.display());
    }
    if let (Some(path), Some(series)) = (&a.residuals, &rep.series) {
        let mut w = csv::Writer::from_writer(Vec::new());
        w.write_record(["t[s]", "pos[mm]", "before[um]", "after[um]", "regime"])?;
        for i in 0..series.t_s.len() {
            w.write_record([
                format!("{:.6}", series.t_s[i]),
                format!("{:.6}", series.pos_mm[i]),
                format!("{:.4}", series.before_um[i]),
                format!("{:.4}", series.after_um[i]),
                series.regimes[i].name().to_owned(),
            ])?;
        }
        let bytes = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
        axisbench::fsutil::write_atomic(path, &bytes)
            .with_context(|| format!("writing the residuals {}", path.display()))?;
        say!("residuals: {}", path.display());
    }
    if let Some(path) = &a.apply {
        let fitted = rep
            .fitted
            .as_ref()
            .context("the diagnosis produced no fitted preset")?;
        let text = fitted.to_ron()?;
        axisbench::fsutil::write_atomic(path, text.as_bytes())
            .with_context(|| format!("writing the fitted preset {}", path.display()))?;
        say!("fitted preset: {}", path.display());
    }
    Ok(())
}

fn print_summary(r: &Report, main: &str, validate: Option<&str>, secs: f64) {
    say!(
        "diagnosis of axis {} against preset '{}': fit on {} ({} samples), held out: {} ({} samples); {:.2} s, {} replays of the record",
        r.axis,
        r.preset,
        main,
        r.samples_fit,
        validate.unwrap_or(&r.holdout_source),
        r.samples_holdout,
        secs,
        r.replays
    );
    print_calibration(r);
    print_where(r);
    print_which(r);
    print_how_far(r);
}

/// The calibration of the nominal and any channel logged off its instant.
fn print_calibration(r: &Report) {
    let c = &r.calibration;
    say!("\nCALIBRATION (nominal parameters re-fitted first, within ±8 %, the mass ±11 %):");
    say!(
        "  {}",
        axisbench::diagnose::calibrate::lines(&c.ratios).join(", ")
    );
    if !c.at_bound.is_empty() {
        let names: Vec<&str> = c.at_bound.iter().map(|p| p.name()).collect();
        say!(
            "  at the bound (more than a correction): {}",
            names.join(", ")
        );
    }
    match &c.skew {
        Some(s) => say!(
            "  MEASUREMENT: the {:?} channel is logged {:+.2} samples off its time stamps; realigned before the effects",
            s.channel,
            s.samples
        ),
        None => say!("  no channel logged off its instant"),
    }
    if let (None, Some(s), Some(j)) = (&c.skew, &c.skew_read, &c.skew_judgement) {
        say!(
            "  the shifts read the {:?} channel {:+.2} samples off; not taken ({})",
            s.channel,
            s.samples,
            j.text()
        );
    }
    say!(
        "  common lag of position and force behind the model: {:.2} samples ({:+.3} ms)",
        -c.common_lag_samples,
        r.time_offset_ms
    );
}

fn print_where(r: &Report) {
    say!("\nWHERE (held-out position residual of the nominal model, um):");
    say!(
        "  {:<22} {:>7} {:>9} {:>9}",
        "regime",
        "share",
        "rms",
        "peak"
    );
    for g in &r.regimes {
        say!(
            "  {:<22} {:>6.1}% {:>9.3} {:>9.3}",
            g.name,
            g.share * 100.0,
            g.rms,
            g.peak
        );
    }
    if let Some(w) = r.windows_before.first() {
        say!(
            "  worst window {:.3}-{:.3} s, peak {:.3} um",
            w.t_start,
            w.t_end,
            w.peak
        );
    }
}

fn print_which(r: &Report) {
    say!(
        "\nWHICH (found = signature in the residual and held-out shrink; ranked by shrink minus complexity penalty):"
    );
    for (i, e) in r.ranking.iter().enumerate() {
        let params: Vec<String> = e
            .params
            .iter()
            .filter(|(k, _)| !k.starts_with("calibration_"))
            .map(|(k, v)| match e.params_std.get(k) {
                Some(s) if s.is_finite() && *s > 0.0 => format!("{k}={v:.4} +-{s:.2}"),
                _ => format!("{k}={v:.4}"),
            })
            .collect();
        say!(
            "  {:>2}. {:<21} shrink {:>6.1}%{} {}",
            i + 1,
            e.effect,
            e.shrink * 100.0,
            if e.significant { "*" } else { " " },
            params.join(" ")
        );
        say!(
            "      {} {}",
            if e.evidence_pass {
                "signature:"
            } else {
                "no signature:"
            },
            e.evidence
        );
        if !e.note.is_empty() {
            say!("      note: {}", e.note);
        }
    }
    say!("  (* found)");
    say!("\nVERDICT: {}", r.verdict);
    say!("  {}", r.summary);
    say!("  (shrink of {})", r.shrink_of);
}

fn print_how_far(r: &Report) {
    say!(
        "\nHOW FAR (held out, position residual; nominal as given -> calibrated -> with the effects; the shrink is the verdict's):"
    );
    say!(
        "  overall RMS {} -> {} -> {}, peak {} -> {}",
        fmt_qty(r.overall.rms_before, "um"),
        fmt_qty(r.overall.rms_calibrated, "um"),
        fmt_qty(r.overall.rms_after, "um"),
        fmt_qty(r.overall.peak_before, "um"),
        fmt_qty(r.overall.peak_after, "um")
    );
    if let (Some(b), Some(c), Some(a)) = (
        r.force_rms_before,
        r.force_rms_calibrated,
        r.force_rms_after,
    ) {
        say!(
            "  force residual RMS {} -> {} -> {}",
            fmt_qty(b, "N"),
            fmt_qty(c, "N"),
            fmt_qty(a, "N")
        );
    }
    for g in &r.per_regime {
        say!(
            "  {:<22} rms {:>9.3} -> {:>9.3}  peak {:>9.3} -> {:>9.3}",
            g.name,
            g.rms_before,
            g.rms_after,
            g.peak_before,
            g.peak_after
        );
    }
    say!("  remaining gap, worst windows:");
    for w in r.windows.iter().take(5) {
        say!(
            "    {:>9.3}-{:<9.3} s  peak {:.3} um",
            w.t_start,
            w.t_end,
            w.peak
        );
    }
}

pub fn eval(
    generator: &str,
    cases: usize,
    seed: u64,
    duration_s: f64,
    verbose: bool,
    only: Vec<usize>,
) -> Result<()> {
    use axisbench::evaluation::{self, EvalConfig, Generator};
    let generator = Generator::from_name(generator)
        .with_context(|| format!("--generator {generator}: not 'independent' or 'own'"))?;
    let cfg = EvalConfig {
        generator,
        seed,
        duration_s,
        cases,
        only,
    };
    let t0 = Instant::now();
    let line = |o: &evaluation::Outcome| {
        if verbose {
            say!("{}", evaluation::case_line(o));
        }
    };
    let res = evaluation::run(&cfg, &line)?;
    say!(
        "generator={} seed={seed} duration={duration_s} s cases={}",
        generator.name(),
        res.len()
    );
    say!("{}", evaluation::summary(&res));
    say!("elapsed {:.1} s", t0.elapsed().as_secs_f64());
    Ok(())
}

pub fn bench(samples: usize) -> Result<()> {
    let case = eval::bench_case(samples, 7)?;
    let cancel = AtomicBool::new(false);
    let quiet = |_: f64, _: &str| {};
    let progress = Progress {
        report: &quiet,
        cancel: &cancel,
    };
    let t0 = Instant::now();
    let rep = diagnose::diagnose(
        &case.nominal,
        &case.record,
        None,
        &Options::default(),
        &progress,
    )?;
    let secs = t0.elapsed().as_secs_f64();
    say!(
        "diagnose samples={} candidates={} hidden={} verdict={} replays={} seconds={:.2}",
        case.record.len(),
        rep.ranking.len(),
        case.hidden.join("+"),
        rep.verdict,
        rep.replays,
        secs
    );
    Ok(())
}
