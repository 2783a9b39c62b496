//! How well the diagnosis names hidden effects, on records from two generators:
//! - `own`: [`crate::diagnose::eval`], which builds records with the project's own plant and
//!   amplifier, the same equations the candidates fit with (the in-distribution figure);
//! - `independent`: [`crate::indep`], a second simulator sharing no code with the model,
//!   with its own integrator, effect formulas, nominal offsets, noise and channel skew.
//!
//! Both are scored the same way: a single hidden effect must be the first one selected; a
//! clean record must end with the verdict `none`; a two-effect record must have both
//! selected. Cases run two at a time (the machines have two cores).

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use crate::diagnose::{self, DiagnoseError, Options, Progress, Report, eval, replay::Record};
use crate::indep;

/// Which generator made the records.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Generator {
    /// The project's own model (in-distribution).
    Own,
    /// The independent simulator.
    Independent,
}

crate::choice_enum!(Generator { Own => "own", Independent => "independent" });

/// What one case held and what the diagnosis said.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Case name.
    pub name: String,
    /// The hidden effects (empty: a clean record).
    pub hidden: Vec<String>,
    /// Whether a channel was logged off its instant.
    pub skewed: bool,
    /// The diagnosis's verdict: the first effect selected, or `none`.
    pub verdict: String,
    /// The selected effects, in order.
    pub selected: Vec<String>,
    /// The first three of the ranking.
    pub ranked: Vec<String>,
    /// Held-out shrink of the combined residual.
    pub shrink: f64,
    /// The report's one-line evidence for each selected effect.
    pub evidence: Vec<String>,
    /// The truth's parameters, for the case line.
    pub truth_params: String,
    /// The channel skew the diagnosis found (a measurement finding), e.g. `force-1.00`.
    pub found_skew: String,
    /// Wall time of the diagnosis alone (the record's generation not counted), s. Two
    /// cases run at once, so a figure against the bar wants `--only` one case.
    pub diagnose_s: f64,
}

/// The effect of our generator that the diagnosis names by two effects of the list
/// (see [`FLANK_PARTS`]).
const FAVOURED_FLANK: &str = "backlash_asymmetry";

/// The two effects a play with one flank favoured is made of: the play and the force that
/// holds the carriage on one flank.
const FLANK_PARTS: [&str; 2] = ["backlash", "constant_force"];

impl Outcome {
    /// A single effect, and it is the first one selected.
    pub fn single_first(&self) -> bool {
        let (Some(h), Some(first)) = (self.hidden.first(), self.selected.first()) else {
            return false;
        };
        self.hidden.len() == 1
            && (h == first
                || (h == FAVOURED_FLANK && FLANK_PARTS.contains(&first.as_str()) && self.names(h)))
    }
    /// Whether the selection names the hidden effect `h`. A play with one flank favoured is
    /// also named by its two parts, a play and a constant force, as the diagnosis reports it
    /// (the model is the same), unless a constant force is hidden beside it.
    fn names(&self, h: &str) -> bool {
        let has = |e: &str| self.selected.iter().any(|s| s == e);
        has(h)
            || (h == FAVOURED_FLANK
                && FLANK_PARTS.iter().all(|p| has(p))
                && !self.hidden.iter().any(|x| x == FLANK_PARTS[1]))
    }
    /// A clean record flagged with an effect.
    pub fn false_alarm(&self) -> bool {
        self.hidden.is_empty() && !self.selected.is_empty()
    }
    /// Two hidden effects, both selected.
    pub fn both_selected(&self) -> bool {
        self.hidden.len() == 2 && self.hidden.iter().all(|h| self.names(h))
    }
}

/// A case ready for the diagnosis.
struct Prepared {
    name: String,
    preset: crate::preset::Preset,
    record: Record,
    hidden: Vec<String>,
    skewed: bool,
    truth_params: String,
}

fn prepare_own(seed: u64, i: usize, duration_s: f64) -> Result<Prepared, DiagnoseError> {
    let c = eval::case(seed, i, duration_s)?;
    let truth_params = c
        .params
        .iter()
        .map(|(k, v)| format!("{k}={v:.3}"))
        .collect::<Vec<_>>()
        .join(" ");
    Ok(Prepared {
        name: format!("own_{i:03}"),
        preset: c.nominal,
        record: c.record,
        hidden: c.hidden.iter().map(|s| (*s).to_owned()).collect(),
        skewed: false,
        truth_params,
    })
}

fn prepare_independent(spec: &indep::CaseSpec) -> Result<Prepared, DiagnoseError> {
    let c = indep::generate(spec).map_err(|e| DiagnoseError::Input(e.to_string()))?;
    // The case goes through the files `gen-cases` writes and `diagnose` reads (RON preset,
    // CSV record), in memory: the figures are those of a user running the command on them.
    let file = format!("{}.csv", c.name);
    let ron_file = format!("{}.ron", c.name);
    let input = |e: String| DiagnoseError::Input(e);
    let preset = crate::preset::Preset::from_ron(
        &c.preset.to_ron().map_err(|e| input(e.to_string()))?,
        &ron_file,
    )
    .map_err(|e| input(e.to_string()))?;
    let mut csv = Vec::new();
    c.trace
        .write_csv_to(&mut csv)
        .map_err(|e| input(format!("{file}: {e}")))?;
    let trace = diagnose::read_record_bytes(&csv, &file, &preset, None)?;
    let axis = diagnose::pick_axis(&trace, &file, &preset, None)?;
    let record = Record::for_preset(&trace, &file, &preset, &axis)?;
    let truth_params = c
        .truth
        .effects
        .iter()
        .map(|e| {
            let p: Vec<String> = e
                .params
                .iter()
                .map(|(k, v)| format!("{}.{k}={v:.3}", e.name))
                .collect();
            format!("[{}] {}", e.formula, p.join(" "))
        })
        .chain(
            (c.truth.skew_samples != 0.0)
                .then(|| format!("skew {}={:+.2}", c.truth.skew_channel, c.truth.skew_samples)),
        )
        .collect::<Vec<_>>()
        .join(" ");
    Ok(Prepared {
        name: c.name.clone(),
        preset,
        record,
        hidden: c.truth.effects.iter().map(|e| e.name.to_owned()).collect(),
        skewed: c.kind.skewed,
        truth_params,
    })
}

/// Which cases to run.
#[derive(Debug, Clone)]
pub struct EvalConfig {
    /// Which generator.
    pub generator: Generator,
    /// Seed of the set.
    pub seed: u64,
    /// Record length, s.
    pub duration_s: f64,
    /// Number of cases of the own generator (the independent set has a fixed size).
    pub cases: usize,
    /// Case indices to run; empty: all.
    pub only: Vec<usize>,
}

fn diagnose_one(p: &Prepared) -> Result<Report, DiagnoseError> {
    let cancel = AtomicBool::new(false);
    let quiet = |_: f64, _: &str| {};
    let progress = Progress {
        report: &quiet,
        cancel: &cancel,
    };

    diagnose::diagnose(&p.preset, &p.record, None, &Options::default(), &progress)
}

fn outcome(p: &Prepared, r: &Report, diagnose_s: f64) -> Outcome {
    Outcome {
        name: p.name.clone(),
        hidden: p.hidden.clone(),
        skewed: p.skewed,
        verdict: r.verdict.clone(),
        selected: r.selected.clone(),
        ranked: r
            .ranking
            .iter()
            .take(3)
            .map(|e| format!("{}({:.0}%)", e.effect, e.shrink * 100.0))
            .collect(),
        shrink: r.shrink,
        evidence: r
            .ranking
            .iter()
            .filter(|e| r.selected.contains(&e.effect))
            .map(|e| format!("{}: {}", e.effect, e.evidence))
            .collect(),
        truth_params: p.truth_params.clone(),
        found_skew: r.calibration.skew.map_or("none".to_owned(), |s| {
            format!(
                "{}{:+.2}",
                format!("{:?}", s.channel).to_lowercase(),
                s.samples
            )
        }),
        diagnose_s,
    }
}

/// Runs the set, two cases at a time; `line` gets one line per case as it finishes.
pub fn run(
    cfg: &EvalConfig,
    line: &(dyn Fn(&Outcome) + Sync),
) -> Result<Vec<Outcome>, DiagnoseError> {
    if !(cfg.duration_s.is_finite() && (5.0..=3600.0).contains(&cfg.duration_s)) {
        return Err(DiagnoseError::Input(format!(
            "--duration {}: each record must last 5 … 3600 s",
            cfg.duration_s
        )));
    }
    let specs = match cfg.generator {
        Generator::Independent => indep::standard_set(cfg.seed, cfg.duration_s),
        Generator::Own => vec![],
    };
    let total = match cfg.generator {
        Generator::Independent => specs.len(),
        Generator::Own => cfg.cases,
    };
    let list: Vec<usize> = if cfg.only.is_empty() {
        (0..total).collect()
    } else {
        cfg.only.iter().copied().filter(|&i| i < total).collect()
    };
    let next = AtomicUsize::new(0);
    let results: Mutex<BTreeMap<usize, Outcome>> = Mutex::new(BTreeMap::new());
    let first_error: Mutex<Option<DiagnoseError>> = Mutex::new(None);
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| {
                loop {
                    let at = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&i) = list.get(at) else { break };
                    let prepared = match cfg.generator {
                        Generator::Own => prepare_own(cfg.seed, i, cfg.duration_s),
                        Generator::Independent => prepare_independent(&specs[i]),
                    };
                    let res = prepared.and_then(|p| {
                        let t0 = std::time::Instant::now();
                        diagnose_one(&p).map(|r| outcome(&p, &r, t0.elapsed().as_secs_f64()))
                    });
                    match res {
                        Ok(o) => {
                            line(&o);
                            if let Ok(mut m) = results.lock() {
                                m.insert(i, o);
                            }
                        }
                        Err(e) => {
                            if let Ok(mut f) = first_error.lock() {
                                f.get_or_insert(e);
                            }
                        }
                    }
                }
            });
        }
    });
    if let Some(e) = first_error.into_inner().ok().flatten() {
        return Err(e);
    }
    Ok(results
        .into_inner()
        .map(|m| m.into_values().collect())
        .unwrap_or_default())
}

/// One case as a line of the evaluation log.
pub fn case_line(o: &Outcome) -> String {
    format!(
        "{:<10} hidden={:<44}{} verdict={:<34} selected={:<44} shrink={:>5.1}% ranked {} | {} | found skew {} | diagnosis {:.1} s",
        o.name,
        if o.hidden.is_empty() {
            "none".to_owned()
        } else {
            o.hidden.join("+")
        },
        if o.skewed { " (skewed)" } else { "" },
        o.verdict,
        if o.selected.is_empty() {
            "none".to_owned()
        } else {
            o.selected.join("+")
        },
        o.shrink * 100.0,
        o.ranked.join(" "),
        o.truth_params,
        o.found_skew,
        o.diagnose_s
    )
}

/// `n/N (p %)`.
fn frac(n: usize, d: usize) -> String {
    if d == 0 {
        "—".into()
    } else {
        format!("{n}/{d} ({:.0} %)", 100.0 * n as f64 / d as f64)
    }
}

/// The headline figures and the per-effect confusion matrix, as Markdown.
pub fn summary(outcomes: &[Outcome]) -> String {
    let part = |skewed: bool| -> Vec<&Outcome> {
        outcomes.iter().filter(|o| o.skewed == skewed).collect()
    };
    let mut s = String::new();
    for (title, set) in [
        ("unskewed", part(false)),
        ("one channel skewed", part(true)),
    ] {
        if set.is_empty() {
            continue;
        }
        let singles: Vec<&&Outcome> = set.iter().filter(|o| o.hidden.len() == 1).collect();
        let clean: Vec<&&Outcome> = set.iter().filter(|o| o.hidden.is_empty()).collect();
        let pairs: Vec<&&Outcome> = set.iter().filter(|o| o.hidden.len() == 2).collect();
        let missed = set
            .iter()
            .filter(|o| !o.hidden.is_empty() && o.selected.is_empty())
            .count();
        s += &format!(
            "| {title} | single effect ranked first | clean flagged (false alarm) | both of two selected | effect present, verdict none |\n|---|---|---|---|---|\n| | {} | {} | {} | {} |\n\n",
            frac(
                singles.iter().filter(|o| o.single_first()).count(),
                singles.len()
            ),
            frac(
                clean.iter().filter(|o| o.false_alarm()).count(),
                clean.len()
            ),
            frac(
                pairs.iter().filter(|o| o.both_selected()).count(),
                pairs.len()
            ),
            frac(missed, set.iter().filter(|o| !o.hidden.is_empty()).count()),
        );
    }
    s += &confusion(outcomes);
    s
}

/// Rows: the hidden single effect (or none); columns: the first selected effect. The
/// `first` column counts as [`Outcome::single_first`] does (a favoured flank named by its
/// two parts counts).
fn confusion(outcomes: &[Outcome]) -> String {
    let mut rows: BTreeMap<String, BTreeMap<String, usize>> = BTreeMap::new();
    let mut right: BTreeMap<String, usize> = BTreeMap::new();
    for o in outcomes.iter().filter(|o| o.hidden.len() <= 1) {
        let truth = o.hidden.first().cloned().unwrap_or_else(|| "none".into());
        let said = o.selected.first().cloned().unwrap_or_else(|| "none".into());
        let hit = o.single_first() || (o.hidden.is_empty() && o.selected.is_empty());
        *right.entry(truth.clone()).or_default() += usize::from(hit);
        *rows.entry(truth).or_default().entry(said).or_default() += 1;
    }
    let mut s = String::from(
        "| hidden (single or none) | first | first selected: count |\n|---|---|---|\n",
    );
    for (t, r) in &rows {
        let n: usize = r.values().sum();
        let right = right.get(t).copied().unwrap_or(0);
        let cells: Vec<String> = r.iter().map(|(v, c)| format!("{v} {c}")).collect();
        s += &format!("| {t} | {right}/{n} | {} |\n", cells.join(", "));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::Outcome;

    fn outcome(hidden: &[&str], selected: &[&str]) -> Outcome {
        let v = |x: &[&str]| x.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>();
        Outcome {
            name: "case".into(),
            hidden: v(hidden),
            skewed: false,
            verdict: selected.first().copied().unwrap_or("none").into(),
            selected: v(selected),
            ranked: vec![],
            shrink: 0.0,
            evidence: vec![],
            truth_params: String::new(),
            found_skew: String::new(),
            diagnose_s: 0.0,
        }
    }

    #[test]
    fn a_favoured_flank_is_named_by_a_play_and_a_constant_force() {
        let flank = ["backlash_asymmetry"];
        assert!(outcome(&flank, &["constant_force", "backlash"]).single_first());
        assert!(outcome(&flank, &["backlash", "constant_force", "compliance"]).single_first());
        assert!(outcome(&flank, &["backlash_asymmetry"]).single_first());
        // One part alone, or the parts behind another effect, is not the effect named first.
        assert!(!outcome(&flank, &["backlash"]).single_first());
        assert!(!outcome(&flank, &["compliance", "backlash", "constant_force"]).single_first());
        let pair = ["backlash_asymmetry", "lead_error"];
        assert!(outcome(&pair, &["backlash", "lead_error", "constant_force"]).both_selected());
        assert!(!outcome(&pair, &["backlash", "lead_error"]).both_selected());
        // A constant force hidden beside it cannot name both.
        let two = ["backlash_asymmetry", "constant_force"];
        assert!(!outcome(&two, &["backlash", "constant_force"]).both_selected());
        assert!(
            outcome(
                &["backlash", "constant_force"],
                &["constant_force", "backlash"]
            )
            .both_selected()
        );
    }
}
