//! Sim-to-real diagnosis (SPEC §8): replay a measured record through the nominal model,
//! calibrate it, fit each candidate unmodelled effect, and add effects forward while one
//! wins by the one criterion (`criterion`); name those that explain more than the floor the
//! fullest model leaves.
//!
//! Everything here drives the same plant and amplifier code as the machine; the candidates
//! change only preset parameters (plus command delay and external force, which sit outside
//! the plant), so a fitted effect can be written back into the preset as it is.

pub mod calibrate;
pub mod criterion;
pub mod effects;
pub mod engine;
pub mod eval;
pub mod evidence;
pub mod fit;
pub mod lm;
pub mod regimes;
pub mod replay;
pub mod report;
pub mod select;

use crate::preset::{Preset, PresetError};
use crate::trace::{Mapping, Trace, TraceError};
pub use effects::Effect;
use regimes::{BinStat, Regime, RegimeStat, Window};
use replay::{Model, Record};
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};

/// Why a diagnosis could not run or did not finish.
#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    /// A record cannot be used with this preset and axis (foreign axes, missing or
    /// non-finite columns).
    #[error("{file}: {reason}")]
    Record {
        /// The record's file, as named to the user.
        file: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A record or its column mapping could not be read.
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// A preset could not be loaded or is invalid.
    #[error(transparent)]
    Preset(#[from] PresetError),
    /// Options or records that cannot be diagnosed together (hold-out fraction out of range,
    /// records too short or mismatched, a replay that diverges).
    #[error("{0}")]
    Input(String),
    /// The user raised the cancel flag of [`Progress`].
    #[error("cancelled")]
    Cancelled,
}

/// Progress reports (fraction 0..1 and what is running) and the cancel flag, shared by the
/// CLI's progress line and the GUI's progress bar.
pub struct Progress<'a> {
    /// Called with the fraction done (0..1) and a label of the current step.
    pub report: &'a (dyn Fn(f64, &str) + Sync),
    /// Set from outside to stop the diagnosis at its next replay with
    /// [`DiagnoseError::Cancelled`].
    pub cancel: &'a AtomicBool,
}

impl Progress<'_> {
    fn check(&self) -> Result<(), DiagnoseError> {
        if self.cancel.load(Ordering::Relaxed) {
            Err(DiagnoseError::Cancelled)
        } else {
            Ok(())
        }
    }
}

/// Options of one diagnosis.
#[derive(Debug, Clone)]
pub struct Options {
    /// Axis to diagnose; None: the first preset axis the record has.
    pub axis: Option<String>,
    /// Fraction at the end of the record held out for scoring when no validation record is
    /// given.
    pub holdout: f64,
    /// Effects to try; empty: all.
    pub only: Vec<Effect>,
    /// At most this many effects are added greedily.
    pub max_effects: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            axis: None,
            holdout: 0.3,
            only: vec![],
            max_effects: 3,
        }
    }
}

/// Reads a record for `preset`: the `--map` text wins, then the preset's default mapping,
/// then the record's own TRACE_FORMAT header.
pub fn read_record(
    path: &std::path::Path,
    preset: &Preset,
    map: Option<&str>,
) -> Result<Trace, DiagnoseError> {
    read_record_with(preset, map, |m| Trace::read_csv(path, m))
}

/// [`read_record`] on CSV bytes already in memory (`file` names them in errors): the
/// evaluation reads its generated records this way, through the same parser and mapping
/// as a user's file.
pub fn read_record_bytes(
    bytes: &[u8],
    file: &str,
    preset: &Preset,
    map: Option<&str>,
) -> Result<Trace, DiagnoseError> {
    read_record_with(preset, map, |m| Trace::from_csv_bytes(bytes, file, m))
}

fn read_record_with(
    preset: &Preset,
    map: Option<&str>,
    read: impl Fn(Option<&Mapping>) -> Result<Trace, crate::trace::TraceError>,
) -> Result<Trace, DiagnoseError> {
    // A mapping the user gave is their word: it is the only reading.
    if let Some(text) = map {
        let m = Mapping::parse(text)?;
        return read(Some(&m)).map_err(|e| foreign_hint(e, None));
    }
    // A record in TRACE_FORMAT is read as it is under any preset, and its own errors (a bad
    // row) are the ones reported; only a foreign header turns to the preset's mapping.
    match read(None) {
        Ok(t) => Ok(t),
        Err(TraceError::Foreign { file, columns }) => match preset.diagnose.mapping.as_deref() {
            Some(text) => {
                let m = Mapping::parse(text)?;
                read(Some(&m)).map_err(|e| foreign_hint(e, Some((preset, &columns))))
            }
            None => Err(foreign_hint(
                TraceError::Foreign {
                    file,
                    columns: columns.clone(),
                },
                Some((preset, &columns)),
            )),
        },
        Err(e) => Err(e.into()),
    }
}

/// A foreign layout's error, with what would read it: the columns found, the ones the
/// preset's mapping wants, and the shipped preset whose mapping reads them.
fn foreign_hint(e: TraceError, found: Option<(&Preset, &[String])>) -> DiagnoseError {
    let Some((preset, columns)) = found else {
        return e.into();
    };
    let (file, mut reason) = match &e {
        TraceError::Foreign { file, .. } => (
            file.clone(),
            format!(
                "the columns {} are not a TRACE_FORMAT trace (it needs a time column t[s] and axis.signal[unit] columns)",
                crate::trace::quote(&columns.join(", "), 400)
            ),
        ),
        TraceError::Layout { file, reason } => (
            file.clone(),
            format!(
                "{reason}; the mapping of preset '{}' wants the columns {}",
                preset.name,
                preset
                    .diagnose
                    .mapping
                    .as_deref()
                    .and_then(|t| Mapping::parse(t).ok())
                    .map(|m| m
                        .entries
                        .iter()
                        .map(|e| e.source.clone())
                        .collect::<Vec<_>>()
                        .join(", "))
                    .unwrap_or_default()
            ),
        ),
        _ => return e.into(),
    };
    let readers: Vec<&str> = crate::preset::SHIPPED_PRESETS
        .iter()
        .copied()
        .filter(|name| {
            crate::preset::load_embedded(name)
                .ok()
                .and_then(|lp| lp.preset.diagnose.mapping)
                .and_then(|t| Mapping::parse(&t).ok())
                .is_some_and(|m| m.entries.iter().all(|e| columns.contains(&e.source)))
        })
        .collect();
    reason += &match readers.as_slice() {
        [] => ": give a column mapping with --map (target=source, e.g. t[s]=time_s)".to_owned(),
        names => format!(
            ": these are the columns {} maps: use {}, or --map",
            names.join(", "),
            names
                .iter()
                .map(|n| format!("`{n}`"))
                .collect::<Vec<_>>()
                .join(" or ")
        ),
    };
    DiagnoseError::Record { file, reason }
}

/// Picks the axis to diagnose and checks that the record's axes belong to the preset.
pub fn pick_axis(
    trace: &Trace,
    file: &str,
    preset: &Preset,
    want: Option<&str>,
) -> Result<String, DiagnoseError> {
    let have = trace.axes();
    let names: Vec<&str> = preset.axes.iter().map(|a| a.name.as_str()).collect();
    let foreign: Vec<&String> = have
        .iter()
        .filter(|a| !names.contains(&a.as_str()))
        .collect();
    if !foreign.is_empty() {
        return Err(DiagnoseError::Record {
            file: file.to_owned(),
            reason: format!(
                "axes {:?} are not in preset '{}' (its axes: {:?})",
                foreign, preset.name, names
            ),
        });
    }
    if let Some(w) = want {
        if !have.iter().any(|a| a == w) {
            return Err(DiagnoseError::Record {
                file: file.to_owned(),
                reason: format!("no cmd/pos columns for axis '{w}' (the record has {have:?})"),
            });
        }
        return Ok(w.to_owned());
    }
    names
        .iter()
        .find(|n| have.iter().any(|a| a == *n))
        .map(|s| (*s).to_owned())
        .ok_or_else(|| DiagnoseError::Record {
            file: file.to_owned(),
            reason: format!(
                "no axis with both cmd and pos columns (need e.g. '{}.cmd[mm]' and '{}.pos[mm]')",
                names.first().unwrap_or(&"x"),
                names.first().unwrap_or(&"x")
            ),
        })
}

/// The base axis of `axis` (for base-position bins and beam sag): the X axis of a crossbeam
/// post whose Z is `axis`, or the base axis of a cross table compensating it.
pub fn base_axis_of(preset: &Preset, axis: &str) -> Option<String> {
    if let Some(t) = preset.cross.iter().find(|t| t.comp_axis == axis) {
        return Some(t.base_axis.clone());
    }
    preset
        .crossbeam
        .posts
        .iter()
        .find(|p| p.z_axis == axis)
        .map(|p| p.x_axis.clone())
}

/// One candidate effect in the report's ranking: its fitted parameters, how much it shrinks
/// the residual, and the evidence for it.
#[derive(Debug, Clone, Serialize)]
pub struct RankEntry {
    /// The effect's [`Effect::name`].
    pub effect: String,
    /// Which of its shapes was kept (`linear`, `hardening`, `wave`, …).
    pub variant: String,
    /// Fitted parameters by key (unit in the key), plus further figures of the fit; for a
    /// selected effect, the values after the joint re-fit.
    pub params: BTreeMap<String, f64>,
    /// One standard deviation of each parameter (from the fit's Jacobian, corrected for
    /// the residual's correlation time).
    pub params_std: BTreeMap<String, f64>,
    /// Position residual RMS in µm.
    pub fit_rms_before: f64,
    /// Position residual RMS on the fitting part with the effect added, µm (before: the
    /// calibrated model it was added to).
    pub fit_rms_after: f64,
    /// Held-out position residual RMS of the calibrated model, µm.
    pub holdout_rms_before: f64,
    /// Held-out position residual RMS with the effect added, µm.
    pub holdout_rms_after: f64,
    /// Held-out shrink of the combined (position and force) residual, 0..1, from the
    /// calibrated model (0 for an effect whose held-out part is not predictable).
    pub shrink: f64,
    /// Held-out shrink of the position residual alone.
    pub shrink_pos: f64,
    /// Held-out shrink of the force residual alone (when force was recorded).
    pub shrink_force: Option<f64>,
    /// Whether its times are predictable (scored on the held-out part), or it is a force at
    /// times no state predicts (scored on the fitting part; its held-out shrink not scored).
    pub predictable: bool,
    /// The criterion's net gain over the calibrated model in the first round (gain less
    /// penalty): the ranking key of the effects not named.
    pub score: f64,
    /// Whether the effect is named: it won by the criterion in the forward selection and,
    /// in the final model, explains more than the floor.
    pub significant: bool,
    /// The judgement it was named (or not) by: for a named or dropped effect the final
    /// model without it against the final model, against the floor; otherwise the first
    /// round's against the calibrated model.
    pub judgement: Option<criterion::Judgement>,
    /// Remark on the fit: why the effect is or is not counted.
    pub note: String,
    /// The figures that support the effect besides the shrink (its signature test).
    pub evidence: String,
    /// Whether the signature test found the effect's signature.
    pub evidence_pass: bool,
    /// The signature test's figures by name (unit in the key).
    pub evidence_figures: BTreeMap<String, f64>,
}

/// Held-out position residual of the nominal model, the calibrated one and the model with
/// the named effects, µm. Levels only: the one shrink figure is [`Report::shrink`].
#[derive(Debug, Clone, Serialize)]
pub struct Figures {
    /// RMS with the nominal model as given, µm.
    pub rms_before: f64,
    /// RMS with the calibrated nominal (where [`Report::shrink`] starts), µm.
    pub rms_calibrated: f64,
    /// RMS with the named effects, µm.
    pub rms_after: f64,
    /// Largest |residual| with the nominal model, µm.
    pub peak_before: f64,
    /// Largest |residual| with the named effects, µm.
    pub peak_after: f64,
}

/// Held-out position residual levels in one regime: shows in which phase of motion the
/// named effects removed the misfit.
#[derive(Debug, Clone, Serialize)]
pub struct RegimeChange {
    /// The regime's [`Regime::name`].
    pub name: String,
    /// Position residual RMS in the regime with the nominal model, µm.
    pub rms_before: f64,
    /// Position residual RMS in the regime with the named effects, µm.
    pub rms_after: f64,
    /// Largest |residual| in the regime with the nominal model, µm.
    pub peak_before: f64,
    /// Largest |residual| in the regime with the named effects, µm.
    pub peak_after: f64,
    /// Fraction of the residual energy left after the named effects that lies in this
    /// regime.
    pub share_after: f64,
}

/// The outcome of one diagnosis, as the CLI prints it, the GUI shows it and JSON stores it.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Name of the preset diagnosed against.
    pub preset: String,
    /// The axis diagnosed.
    pub axis: String,
    /// The axis whose position bins [`Report::base_bins`] (a crossbeam post's X, a cross
    /// table's base axis); None when the axis has none.
    pub base_axis: Option<String>,
    /// Sample period of the replay grid (the model's T3 cycle), s.
    pub t3_s: f64,
    /// Whether the record was sampled at another period and interpolated onto T3.
    pub resampled: bool,
    /// Samples in the fitting part.
    pub samples_fit: usize,
    /// Samples in the held-out part that scores the candidates.
    pub samples_holdout: usize,
    /// Where the held-out part comes from: "validation record" or "end of the record".
    pub holdout_source: String,
    /// Constant time offset between the record and the model (positive: the machine lags
    /// the model): the lag position and force share, in ms.
    pub time_offset_ms: f64,
    /// The nominal's parameters re-fitted before any effect is tested, and any channel
    /// logged off its instant (a measurement finding, removed before the effects).
    pub calibration: calibrate::Calibration,
    /// The calibration values after the named effects were re-fitted with them.
    pub calibration_final: Vec<(calibrate::CalParam, f64)>,
    /// How the criterion weighs the channels and how much of each is noise.
    pub scale: criterion::Scale,
    /// What the final model leaves structured on the held-out part: the floor the named
    /// effects explained more than (loss units, the calibrated fitting part's level is 1).
    pub floor_holdout: f64,
    /// … on the fitting part (for forces at times no state predicts).
    pub floor_fit: f64,
    /// Replays of the record the diagnosis ran (the work it did).
    #[serde(skip)]
    pub replays: usize,
    /// Units of the figures: position residuals in µm, force residuals in N.
    pub units: String,
    /// Name of the first effect named (the one that adds most to the final model), or
    /// "none".
    pub verdict: String,
    /// Names of the named effects, the one that adds most first.
    pub selected: Vec<String>,
    /// Held-out shrink of the combined residual from the calibrated model to the one with
    /// the named effects, 0..1: 1 − the ratio of their RMS levels, position and force each
    /// weighed by the calibrated model's fitting residual. The one shrink figure.
    pub shrink: f64,
    /// What [`Report::shrink`] is a shrink of, in words.
    pub shrink_of: String,
    /// The regime holding most (over half) of the residual energy left after the named
    /// effects, with its share; None when no regime holds most.
    pub remaining_regime: Option<(String, f64)>,
    /// The verdict line, built once ([`report::summary_line`]) for the CLI, the GUI and the
    /// JSON.
    pub summary: String,
    /// Every candidate: the named ones first, then by their first-round net gain.
    pub ranking: Vec<RankEntry>,
    /// Held-out position residual of the nominal model, per regime.
    pub regimes: Vec<RegimeStat>,
    /// Held-out position residual of the nominal model in 10 bins of measured position, mm.
    pub position_bins: Vec<BinStat>,
    /// The same in 10 bins of the base axis's position, mm (empty without a recorded base).
    pub base_bins: Vec<BinStat>,
    /// The same in 10 bins of record time, s.
    pub time_bins: Vec<BinStat>,
    /// Worst held-out windows that remain after the selected effects.
    pub windows: Vec<Window>,
    /// Worst held-out windows of the nominal model.
    pub windows_before: Vec<Window>,
    /// Held-out force residual RMS of the nominal model, N (None without a force column).
    pub force_rms_before: Option<f64>,
    /// Held-out force residual RMS with the selected effects, N.
    pub force_rms_after: Option<f64>,
    /// Held-out force residual RMS with the calibrated nominal, N.
    pub force_rms_calibrated: Option<f64>,
    /// Held-out position residual, nominal against the selected effects, over all samples.
    pub overall: Figures,
    /// The same per regime of the held-out command.
    pub per_regime: Vec<RegimeChange>,
    /// The fitted preset with the selected effects (for "apply to model").
    #[serde(skip)]
    pub fitted: Option<Preset>,
    /// Residuals for the GUI: held-out position residual (µm) before and after, regime
    /// labels, times and positions.
    #[serde(skip)]
    pub series: Option<Series>,
}

/// The held-out part sample by sample, for the GUI's residual plots.
#[derive(Debug, Clone)]
pub struct Series {
    /// Record time of each sample, s.
    pub t_s: Vec<f64>,
    /// Measured position, mm.
    pub pos_mm: Vec<f64>,
    /// Position residual (measured − simulated) of the nominal model, µm.
    pub before_um: Vec<f64>,
    /// Position residual with the selected effects, µm.
    pub after_um: Vec<f64>,
    /// Regime of each sample, from the held-out command.
    pub regimes: Vec<Regime>,
}

/// Runs the whole diagnosis of `main` (fit) and `validate` (held out), or of `main` alone
/// with its last `opts.holdout` held out.
pub fn diagnose(
    preset: &Preset,
    main: &Record,
    validate: Option<&Record>,
    opts: &Options,
    progress: &Progress,
) -> Result<Report, DiagnoseError> {
    let axis_params = preset
        .axes
        .iter()
        .find(|a| a.name == main.axis)
        .ok_or_else(|| DiagnoseError::Input(format!("axis '{}' not in preset", main.axis)))?
        .clone();
    if !(opts.holdout > 0.0 && opts.holdout < 0.9) && validate.is_none() {
        return Err(DiagnoseError::Input(format!(
            "--holdout {} must lie in (0, 0.9): it is the fraction of the record kept for scoring",
            opts.holdout
        )));
    }
    let mut nominal = engine::Cand {
        model: Model {
            axis: axis_params,
            t3_s: preset.timing.t3_s,
            t2_s: preset.timing.t2_s,
            t1_s: preset.timing.t1_s,
            pos_source: main.pos_source.unwrap_or(preset.diagnose.pos_source),
            delay_s: 0.0,
            lag_s: 0.0,
            pos_interval_m: 0.0,
            disturbance: vec![],
            beam: replay::BeamModel::of(preset, &main.axis),
        },
        dist_val: vec![],
    };
    // The record's own sensor rounding is noise, not a prediction: the replay reads its
    // sensors unrounded (a rounded replay is a staircase in every parameter, which the
    // solver's differences cannot follow), and the rounding is counted in the position's
    // noise. A grid coarser than the preset's sensor is the quantization candidate's.
    let sensor_quantum_m = nominal.model.pos_quantum_m();
    nominal.model.axis.encoder.quantize_motor = false;
    nominal.model.axis.encoder.quantize_scale = false;
    let effects: Vec<Effect> = if opts.only.is_empty() {
        Effect::DEFAULT.to_vec()
    } else {
        opts.only.clone()
    };
    // Calibrate, and read the channel shifts, on the record as it is.
    let (eng0, nom_eval) = engine::Engine::new(
        engine::Split::new(main, validate, opts.holdout)?,
        &nominal,
        progress,
    )?;
    (progress.report)(0.02, "calibrating the nominal");
    let mut cal = calibrate::fit(&eng0, &nominal)?;
    // A skew the criterion took is removed from the record; the rest of the diagnosis reads
    // the realigned record (one reading).
    let (main_d, val_d) = match &cal.skew {
        Some(s) => (
            calibrate::deskew(main, s),
            validate.map(|v| calibrate::deskew(v, s)),
        ),
        None => (main.clone(), validate.cloned()),
    };
    let (mut eng, _) = engine::Engine::new(
        engine::Split::new(&main_d, val_d.as_ref(), opts.holdout)?,
        &cal.apply(&nominal),
        progress,
    )?;
    // The nominal's parameters fitted again without the shifts (the common lag is not
    // kept; a skew taken is gone from the record), then once more with the calibrated
    // residual's weights of position and force, the weights every candidate is fitted with.
    calibrate::refit(&eng, &nominal, &mut cal, true)?;
    eng.set_scale(&eng.evaluate(&cal.apply(&nominal))?);
    calibrate::refit(&eng, &nominal, &mut cal, false)?;
    let calibrated = cal.apply(&nominal);
    let cal_eval = eng.evaluate(&calibrated)?;
    eng.set_scale(&cal_eval);
    let scale = criterion::Scale::new(&cal_eval, eng.corr_len, sensor_quantum_m);
    if std::env::var_os("AXB_DBG").is_some() {
        eprintln!(
            "CAL {:?} shifts {:.3} {:.3} skew {:?} scale {:?}",
            cal.ratios, cal.pos_shift_samples, cal.force_shift_samples, cal.skew, scale
        );
    }
    cal.level_nominal = scale.level(&eng.evaluate(&nominal)?, criterion::Part::Held);
    cal.level_calibrated = scale.level(&cal_eval, criterion::Part::Held);
    let outcome = select::run(
        &eng,
        &scale,
        sensor_quantum_m,
        &cal,
        &nominal,
        &calibrated,
        &cal_eval,
        &effects,
        opts.max_effects,
    )?;
    let mut report = report::build(
        preset,
        &eng,
        report::Parts {
            cal,
            scale: &scale,
            nom_eval,
            cal_eval,
            outcome,
            base_axis: base_axis_of(preset, &main.axis),
        },
    );
    report.replays = eng0.replays() + eng.replays();
    (progress.report)(1.0, "done");
    Ok(report)
}
