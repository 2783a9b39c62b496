//! Sim-to-real diagnosis: real EMPS data, generated blind cases, bad input.

use axisbench::diagnose::{
    self, Options, Progress, Report,
    eval::{self, EvalConfig},
    replay::Record,
};
use axisbench::preset;
use axisbench::trace::Trace;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

fn shared(rel: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/real")
        .join(rel);
    assert!(
        p.exists(),
        "real data missing: {} (the tests expect shared/ next to the repository)",
        p.display()
    );
    p
}

fn run(preset: &preset::Preset, main: &Record, val: Option<&Record>, opts: &Options) -> Report {
    let cancel = AtomicBool::new(false);
    let quiet = |_: f64, _: &str| {};
    let p = Progress {
        report: &quiet,
        cancel: &cancel,
    };
    diagnose::diagnose(preset, main, val, opts, &p).expect("diagnosis runs")
}

fn record(preset: &preset::Preset, path: &std::path::Path) -> Record {
    let tr = diagnose::read_record(path, preset, None).expect("record reads");
    let file = path.display().to_string();
    let axis = diagnose::pick_axis(&tr, &file, preset, None).expect("axis");
    Record::from_trace(&tr, &file, &axis, None, preset.timing.t3_s).expect("record")
}

#[test]
fn emps_coulomb_friction_is_found_with_the_published_force_and_offset_sign() {
    let lp = preset::load("presets/emps.ron").expect("emps preset");
    let p = &lp.preset;
    let train = record(p, &shared("emps/emps_train_DATA_EMPS.csv"));
    let test = record(p, &shared("emps/emps_test_DATA_EMPS_PULSES.csv"));
    let r = run(p, &train, Some(&test), &Options::default());
    assert_eq!(r.ranking[0].effect, "coulomb_friction", "{:#?}", r.ranking);
    assert_eq!(r.verdict, "coulomb_friction");
    let fc = r.ranking[0].params["force_n"];
    // Published IDIM-LS estimate on DATA_EMPS: Fc = 20.3935 N; issue 12 asks for 5 %.
    assert!(
        (fc - 20.39).abs() <= 0.05 * 20.39,
        "Fc = {fc} N, published 20.39 N"
    );
    let fc_std = r.ranking[0].params_std["force_n"];
    assert!(fc_std.is_finite() && fc_std < 3.0, "Fc ± {fc_std} N");
    // Published offset −3.1648 N (motor-force offset convention).
    let cf = r
        .ranking
        .iter()
        .find(|e| e.effect == "constant_force")
        .expect("constant_force ranked");
    assert!(cf.params["offset_n"] < 0.0, "offset {:?}", cf.params);
    assert!(
        r.ranking[0].shrink > 0.5,
        "held-out shrink {}",
        r.ranking[0].shrink
    );
    // The remaining gap of the pulse record sits at the pulse edges: a 1 s square wave
    // with edges at 0.344 + 0.5 k s.
    for w in r.windows.iter().take(5) {
        let near_edge = (0..50).any(|k| {
            let e = 0.344 + 0.5 * k as f64;
            e >= w.t_start - 0.05 && e <= w.t_end + 0.05
        });
        assert!(near_edge, "window {w:?} is not at a pulse edge");
    }
}

/// The pulse record with its `pulses_N` column removed (the diagnosis must find the pulses
/// without it), written to `dir`; with the pulse edges the column held: (rising, falling)
/// times in s.
fn without_pulses(dir: &std::path::Path) -> (PathBuf, Vec<f64>, Vec<f64>) {
    let src = shared("emps/emps_test_DATA_EMPS_PULSES.csv");
    let text = std::fs::read_to_string(&src).expect("pulse record reads");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("{}: no column {name}", src.display()))
    };
    let (drop, t_col) = (col("pulses_N"), col("t_s"));
    let keep = |f: Vec<&str>| -> String {
        f.iter()
            .enumerate()
            .filter(|(i, _)| *i != drop)
            .map(|(_, v)| *v)
            .collect::<Vec<_>>()
            .join(",")
    };
    let mut out = keep(header.clone()) + "\n";
    let (mut rising, mut falling) = (vec![], vec![]);
    let mut prev = 0.0;
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        let t: f64 = f[t_col].parse().expect("t_s");
        let p: f64 = f[drop].parse().expect("pulses_N");
        if p > prev {
            rising.push(t);
        } else if p < prev {
            falling.push(t);
        }
        prev = p;
        out += &keep(f);
        out.push('\n');
    }
    let path = dir.join("emps_pulses_without_pulse_column.csv");
    std::fs::write(&path, out).expect("write the record without pulses_N");
    (path, rising, falling)
}

#[test]
fn emps_pulses_are_found_as_a_one_second_square_wave_without_the_pulse_column() {
    let lp = preset::load("presets/emps.ron").expect("emps preset");
    let p = &lp.preset;
    let dir = tempfile::tempdir().expect("tempdir");
    let (path, rising, falling) = without_pulses(dir.path());
    let header = std::fs::read_to_string(&path).expect("reads");
    assert!(!header.lines().next().unwrap_or("").contains("pulses"));
    let opts = Options {
        holdout: 0.3,
        ..Options::default()
    };
    let r = run(p, &record(p, &path), None, &opts);
    assert!(
        r.selected.iter().any(|s| s == "external_disturbance"),
        "selected {:?}\n{:#?}",
        r.selected,
        r.ranking
    );
    let d = ranked(&r, "external_disturbance");
    let period = d.params["period_s"];
    let rise = d.params["first_rise_s"];
    let duty = d.params.get("duty").copied().unwrap_or(0.5);
    assert!(
        (period - 1.0).abs() <= 0.03,
        "period {period} s, true 1.0 s"
    );
    let k = (rise - 0.344).round();
    assert!(
        (rise - 0.344 - k).abs() <= 0.030,
        "first rising edge {rise} s, true 0.344 + k s"
    );
    // The estimated edges against the column's, over the whole record (fitting and
    // held-out parts): the wave must extrapolate, not only fit.
    let nearest = |t: f64, phase: f64| {
        let k = ((t - rise - phase * period) / period).round();
        rise + phase * period + k * period
    };
    let mut worst = 0.0f64;
    println!("edge     true s    estimated s   error ms");
    for (kind, edges, phase) in [("rising", &rising, 0.0), ("falling", &falling, duty)] {
        for (i, &t) in edges.iter().enumerate() {
            let e = nearest(t, phase);
            worst = worst.max((e - t).abs());
            if i < 2 || i + 1 == edges.len() {
                println!("{kind:8} {t:9.4} {e:12.4} {:10.1}", (e - t) * 1e3);
            }
        }
    }
    println!(
        "period {period:.5} s, first rise {rise:.4} s, duty {duty:.4}, {} rising and {} falling edges, worst {:.1} ms",
        rising.len(),
        falling.len(),
        worst * 1e3
    );
    assert_eq!(rising.len() + falling.len(), 49, "the column's edges");
    assert!(
        worst <= 0.030,
        "an estimated edge is {} ms off",
        worst * 1e3
    );
}

/// A force added to the amplifier's output moves the axis exactly as the same force on the
/// table does; only the force channel differs, by that force (it records the amplifier's
/// output). This is what tells the EMPS pulses (injected into the drive's command) from a
/// push on the table.
#[test]
fn a_force_in_the_amplifiers_output_moves_the_axis_like_one_on_the_table() {
    use axisbench::diagnose::replay::{Disturbance, Model, simulate};
    let lp = preset::load("presets/emps.ron").expect("emps preset");
    let p = &lp.preset;
    let n = 2000;
    let rec = Record {
        axis: "x".into(),
        t3_s: p.timing.t3_s,
        t0_s: 0.0,
        cmd_m: (0..n).map(|k| 1e-5 * k as f64).collect(),
        comp_m: None,
        pos_m: vec![0.0; n],
        force_n: Some(vec![0.0; n]),
        base_pos_m: None,
        resampled: false,
        pos_source: None,
        beam_x_m: vec![],
        starts_at_rest: true,
        logged_pos_m: None,
    };
    let wave = Disturbance::Square {
        period_s: 0.4,
        duty: 0.5,
        amplitude_n: 80.0,
        offset_n: 10.0,
        first_rise_s: 0.1,
    };
    let model = |d: Disturbance| Model {
        axis: p.axes[0].clone(),
        t3_s: p.timing.t3_s,
        t2_s: p.timing.t2_s,
        t1_s: p.timing.t1_s,
        pos_source: p.diagnose.pos_source,
        delay_s: 0.0,
        lag_s: 0.0,
        pos_interval_m: 0.0,
        disturbance: vec![d],
        beam: None,
    };
    let table = simulate(&model(wave.clone()), &rec, n);
    let in_cmd = simulate(&model(Disturbance::InCommand(Box::new(wave))), &rec, n);
    for k in 0..n {
        assert_eq!(table.pos_m[k], in_cmd.pos_m[k], "position at sample {k}");
        let t = rec.t_s(k);
        let u = ((t - 0.1) / 0.4).rem_euclid(1.0);
        let d = 10.0 + if u < 0.5 { 80.0 } else { -80.0 };
        assert!(
            (in_cmd.force_n[k] - table.force_n[k] - d).abs() < 1e-9,
            "force at sample {k}: {} vs {} + {d}",
            in_cmd.force_n[k],
            table.force_n[k]
        );
    }
}

/// In-distribution: cases from our own model (the same equations the candidates fit), so
/// this is the easy check; the honest figure is `diagnose-eval --generator independent`.
/// Play in a drive whose motor, alone inside the play, is a lightly damped loop (EMPS: the
/// motor is 5 kg of 95): the independent generator's drive hunts, a steady tone in the
/// force. A limit cycle's phase cannot be replayed, so the tone itself must name the play,
/// with the loop's pole that explains it. A quantized record's force jitter is no tone.
#[test]
fn a_hunting_drive_is_diagnosed_as_backlash_and_a_quantized_one_is_not() {
    use axisbench::indep::{self, CaseSpec, EffectPick};
    let diagnose_case = |effect: &str, formula: &str, seed: u64| {
        let pick = EffectPick::new(effect, Some(formula)).expect("known effect");
        let mut s = CaseSpec::new("hunt", seed, vec![pick]);
        s.duration_s = Some(24.0);
        let c = indep::generate(&s).expect("case generates");
        let axis = diagnose::pick_axis(&c.trace, "hunt.csv", &c.preset, None).expect("axis");
        let rec = Record::for_preset(&c.trace, "hunt.csv", &c.preset, &axis).expect("record");
        run(&c.preset, &rec, None, &Options::default())
    };
    for (formula, seed) in [("two_mass_dead_zone", 11), ("rigid_lost_motion", 12)] {
        let r = diagnose_case("backlash", formula, seed);
        assert_eq!(r.verdict, "backlash", "{formula}: {:#?}", r.ranking);
        let b = r
            .ranking
            .iter()
            .find(|e| e.effect == "backlash")
            .expect("backlash ranked");
        let fig = |k: &str| b.evidence_figures.get(k).copied().unwrap_or(f64::NAN);
        assert!(b.evidence.contains("hunts"), "{formula}: {}", b.evidence);
        // The tone lies between the motion's content and the record's Nyquist frequency,
        // and holds nearly all the power there.
        assert!(
            (100.0..500.0).contains(&fig("hunting_hz")),
            "{:?}",
            b.evidence_figures
        );
        assert!(fig("hunting_share") >= 0.8, "{:?}", b.evidence_figures);
        // The calibrated model's motor-alone loop: on the edge or past it (EMPS as shipped:
        // |z| = 1.2 at 190 Hz), which is why the drive hunts at all.
        let radius = fig("motor_alone_pole_radius");
        assert!((0.9..1.5).contains(&radius), "{:?}", b.evidence_figures);
        assert!(
            (150.0..300.0).contains(&fig("motor_alone_pole_hz")),
            "{:?}",
            b.evidence_figures
        );
    }
    let r = diagnose_case("quantization", "round", 13);
    let b = r.ranking.iter().find(|e| e.effect == "backlash");
    assert!(
        b.is_none_or(|b| !b.evidence_figures.contains_key("hunting_share")),
        "quantization read as hunting: {:#?}",
        r.ranking
    );
    assert_ne!(r.verdict, "backlash");
}

#[test]
fn blind_cases_are_diagnosed() {
    let cfg = EvalConfig {
        cases: 14,
        seed: 11,
        duration_s: 16.0,
        only: vec![],
    };
    let res = eval::run(&cfg, &|_, _| {}, &|_| {}).expect("eval runs");
    let s = res.summary();
    assert!(res.kinds() >= 10, "{s}");
    assert!(res.top1() >= 0.75, "{s}");
    assert!(res.median_shrink() >= 0.6, "{s}");
    // Two clean cases; at most one may be flagged (the nominal is up to 6 % off).
    assert!(res.false_alarms() <= 0.5, "{s}");
    let missed = res
        .cases
        .iter()
        .filter(|c| !c.hidden.is_empty() && c.verdict == "none")
        .count();
    assert_eq!(missed, 0, "an effect present was called none\n{s}");
}

#[test]
fn a_hidden_coulomb_force_is_recovered() {
    // Case 27 of seed 1 hides extra Coulomb friction only.
    let c = eval::case(1, 27, 24.0).expect("case");
    assert_eq!(c.hidden, vec!["coulomb_friction"]);
    let truth = c.params["coulomb_friction.force_n"];
    let r = run(&c.nominal, &c.record, None, &Options::default());
    assert_eq!(r.verdict, "coulomb_friction", "{:#?}", r.ranking);
    let fc = r.ranking[0].params["force_n"];
    // The nominal's own Coulomb force is up to 6 % off (±3.6 N of 60 N); the fit absorbs it.
    assert!((fc - truth).abs() < 5.0, "fitted {fc} N, hidden {truth} N");
    assert!(r.shrink > 0.7, "shrink {}", r.shrink);
}

#[test]
fn the_same_record_gives_the_same_report() {
    let c = eval::case(1, 8, 8.0).expect("case");
    let a = run(&c.nominal, &c.record, None, &Options::default());
    let b = run(&c.nominal, &c.record, None, &Options::default());
    assert_eq!(
        serde_json::to_string(&a).expect("json"),
        serde_json::to_string(&b).expect("json")
    );
}

#[test]
fn cancelling_stops_a_running_diagnosis() {
    use std::sync::Mutex;
    use std::sync::atomic::Ordering;
    use std::time::{Duration, Instant};
    let c = eval::case(1, 3, 20.0).expect("case");
    let cancel = AtomicBool::new(false);
    // The diagnosis reports its progress; the test cancels once it is well under way
    // (past the calibration, fitting candidates), then times how long it takes to stop.
    let seen: Mutex<(f64, usize, Option<Instant>)> = Mutex::new((0.0, 0, None));
    let report = |f: f64, what: &str| {
        if let Ok(mut s) = seen.lock() {
            s.0 = s.0.max(f);
            if what == "fitting" {
                s.1 += 1;
            }
            // 60 replays in: the calibration is done and candidates are being fitted.
            if s.1 == 60 && s.2.is_none() {
                s.2 = Some(Instant::now());
                cancel.store(true, Ordering::Relaxed);
            }
        }
    };
    let p = Progress {
        report: &report,
        cancel: &cancel,
    };
    let e = diagnose::diagnose(&c.nominal, &c.record, None, &Options::default(), &p)
        .expect_err("cancelled");
    let stopped = Instant::now();
    assert!(matches!(e, diagnose::DiagnoseError::Cancelled), "{e}");
    let (frac, replays, at) = *seen.lock().expect("lock");
    assert!(replays >= 60, "only {replays} replays ran before the end");
    let at = at.expect("the diagnosis was fitting candidates when it was cancelled");
    assert!(
        frac > 0.0 && frac < 0.99,
        "cancelled mid-way, not at the end ({frac})"
    );
    // Every replay checks the flag, so the two workers stop within one replay each.
    assert!(
        stopped - at < Duration::from_secs(2),
        "it took {:?} to stop",
        stopped - at
    );
}

fn bad(text: &str) -> String {
    let p = eval::nominal_preset().expect("nominal");
    let tr = match Trace::from_csv_str(text, "bad.csv", None) {
        Ok(t) => t,
        Err(e) => return e.to_string(),
    };
    let axis = match diagnose::pick_axis(&tr, "bad.csv", &p, None) {
        Ok(a) => a,
        Err(e) => return e.to_string(),
    };
    match Record::from_trace(&tr, "bad.csv", &axis, None, p.timing.t3_s) {
        Ok(_) => "accepted".into(),
        Err(e) => e.to_string(),
    }
}

fn rows(n: usize, f: impl Fn(usize) -> String) -> String {
    (0..n).map(|i| f(i) + "\n").collect()
}

#[test]
fn bad_records_get_clear_errors() {
    let ok = |i: usize| {
        format!(
            "{:.4},{},{}",
            i as f64 * 0.0005,
            i as f64 * 1e-3,
            i as f64 * 1e-3
        )
    };
    assert_eq!(
        bad(&(String::from("t[s],x.cmd[mm],x.pos[mm]\n") + &rows(20, ok))),
        "accepted"
    );
    let e = bad(&(String::from("t[s],x.cmd[mm],x.feedback[mm]\n") + &rows(20, ok)));
    assert!(e.contains(".cmd") && e.contains(".pos"), "{e}");
    let e = bad(&(String::from("t[s],q.cmd[mm],q.pos[mm]\n") + &rows(20, ok)));
    assert!(e.contains("not in preset") && e.contains("q"), "{e}");
    let back = |i: usize| {
        let t = if i == 7 { 0.001 } else { i as f64 * 0.0005 };
        format!("{t},{},{}", i as f64 * 1e-3, i as f64 * 1e-3)
    };
    let e = bad(&(String::from("t[s],x.cmd[mm],x.pos[mm]\n") + &rows(20, back)));
    assert!(e.contains("increas"), "{e}");
    let nan = |i: usize| {
        let p = if i == 5 {
            "NaN".to_owned()
        } else {
            format!("{}", i as f64 * 1e-3)
        };
        format!("{},{},{p}", i as f64 * 0.0005, i as f64 * 1e-3)
    };
    let e = bad(&(String::from("t[s],x.cmd[mm],x.pos[mm]\n") + &rows(20, nan)));
    assert!(e.contains("x.pos") || e.contains("column 3"), "{e}");
    let empty = |i: usize| {
        let p = if i == 5 {
            String::new()
        } else {
            format!("{}", i as f64 * 1e-3)
        };
        format!("{},{},{p}", i as f64 * 0.0005, i as f64 * 1e-3)
    };
    let e = bad(&(String::from("t[s],x.cmd[mm],x.pos[mm]\n") + &rows(20, empty)));
    assert!(e.contains("x.pos") && e.contains("row 6"), "{e}");
}

/// One independent case with a single hidden effect, diagnosed.
fn diagnose_indep(effect: &str, formula: &str, seed: u64, scale: bool) -> Report {
    use axisbench::indep::{self, CaseSpec, EffectPick, PosSensor};
    let pick = EffectPick::new(effect, Some(formula)).expect("known effect");
    let mut s = CaseSpec::new("case", seed, vec![pick]);
    s.duration_s = Some(24.0);
    if scale {
        s.pos_sensor = PosSensor::LinearScale;
    }
    let c = indep::generate(&s).expect("case generates");
    let axis = diagnose::pick_axis(&c.trace, "case.csv", &c.preset, None).expect("axis");
    let rec = Record::for_preset(&c.trace, "case.csv", &c.preset, &axis).expect("record");
    run(&c.preset, &rec, None, &Options::default())
}

#[test]
fn a_lead_error_that_is_not_periodic_is_found_as_a_table_along_the_travel() {
    // Cases 49 and 51 of the independent seed 1: smoothed random knots every 9–10 mm, a
    // few µm, on the scale. The fitting part and the held-out part cover different travel.
    for seed in [1_000_052, 1_000_054] {
        let r = diagnose_indep("lead_error", "table", seed, true);
        assert_eq!(r.verdict, "lead_error", "seed {seed}: {:#?}", r.ranking);
        let e = &r.ranking[0];
        assert!(e.params.contains_key("table_points"), "{:?}", e.params);
        assert!(r.shrink > 0.05, "seed {seed}: shrink {}", r.shrink);
    }
}

#[test]
fn a_soft_payload_is_found_as_compliance() {
    // Case 41 of the independent seed 1: a payload on a 53 Hz hardening spring.
    let r = diagnose_indep("compliance", "hardening", 1_000_044, false);
    assert_eq!(r.verdict, "compliance", "{:#?}", r.ranking);
    assert!(r.shrink > 0.2, "shrink {}", r.shrink);
}

#[test]
fn a_screw_growth_is_found_with_its_fixed_bearing() {
    // Cases 44–47 of the independent seed 202: heat from speed or from friction power and
    // copper loss, the fixed bearing at −30 mm or 280 mm, 5–20 µm of growth, on the scale.
    // The fit starts from a regression of the position residual on the heat model's own
    // columns, so the fixed end (which only the growth's slope along the travel shows) is
    // recovered; from an arbitrary heat the fit slid to the bounds (−1390 … 2000 mm).
    for (seed, formula) in [
        (202_000_650, "speed_heat"),
        (202_000_652, "speed_heat"),
        (202_000_651, "dissipated_power"),
    ] {
        use axisbench::indep::{self, CaseSpec, EffectPick, PosSensor};
        let pick = EffectPick::new("thermal_growth", Some(formula)).expect("known effect");
        let mut s = CaseSpec::new("case", seed, vec![pick]);
        s.duration_s = Some(24.0);
        s.pos_sensor = PosSensor::LinearScale;
        let c = indep::generate(&s).expect("case generates");
        let truth_mm = c.truth.effects[0].params["fixed_end_mm"];
        let axis = diagnose::pick_axis(&c.trace, "case.csv", &c.preset, None).expect("axis");
        let rec = Record::for_preset(&c.trace, "case.csv", &c.preset, &axis).expect("record");
        let r = run(&c.preset, &rec, None, &Options::default());
        assert_eq!(r.verdict, "thermal_growth", "seed {seed}: {:#?}", r.ranking);
        let got_mm = r.ranking[0].params["fixed_end_mm"];
        assert!(
            (got_mm - truth_mm).abs() <= 40.0,
            "seed {seed}: fixed end {got_mm:.1} mm, true {truth_mm} mm"
        );
    }
}

/// Diagnoses case `i` of the independent generator's standard set of `seed` (24 s records).
fn standard_case(seed: u64, i: usize) -> (Vec<String>, Report) {
    let (c, r) = standard_case_with_truth(seed, i);
    let hidden = c.truth.effects.iter().map(|e| e.name.to_owned()).collect();
    (hidden, r)
}

/// Standard case `i` of `seed` (its record and truth) and its report.
fn standard_case_with_truth(seed: u64, i: usize) -> (axisbench::indep::Case, Report) {
    use axisbench::indep;
    let spec = indep::standard_set(seed, indep::STANDARD_DURATION_S).swap_remove(i);
    let c = indep::generate(&spec).expect("case generates");
    let axis = diagnose::pick_axis(&c.trace, "case.csv", &c.preset, None).expect("axis");
    let rec = Record::for_preset(&c.trace, "case.csv", &c.preset, &axis).expect("record");
    let r = run(&c.preset, &rec, None, &Options::default());
    (c, r)
}

/// Standard case `i` of `seed`, which must hide `effect` alone, diagnosed: its report, after
/// checking that the verdict names the effect.
fn named_single(seed: u64, i: usize, effect: &str) -> Report {
    let (hidden, r) = standard_case(seed, i);
    assert_eq!(hidden, [effect], "seed {seed} case {i}");
    assert_eq!(r.verdict, effect, "seed {seed} case {i}: {:#?}", r.ranking);
    r
}

/// Standard case `i` of `seed`, which must hide the two `effects`, diagnosed: its report,
/// after checking that both are selected.
fn named_pair(seed: u64, i: usize, effects: [&str; 2]) -> Report {
    let (hidden, r) = standard_case(seed, i);
    assert_eq!(hidden, effects, "seed {seed} case {i}");
    for e in &hidden {
        assert!(r.selected.contains(e), "{e} not in {:?}", r.selected);
    }
    r
}

/// The calibration's ratio of the parameter named `name` in `r`.
fn cal_ratio(r: &Report, name: &str) -> f64 {
    r.calibration
        .ratios
        .iter()
        .find(|(p, _)| p.name() == name)
        .map(|(_, x)| *x)
        .unwrap_or_else(|| panic!("{name} calibrated"))
}

#[test]
fn a_friction_that_leaves_the_force_alone_is_not_reported() {
    // Clean record 0 of the independent seed 404 (motor encoder). Its calibrated residual
    // asks for a loop-dynamics correction; a viscous term shrank the held-out position
    // residual by 68 % and the force residual by −0.6 %, and was reported. A friction force
    // must show on the force channel (FORCE_SHARE).
    let (hidden, r) = standard_case(404, 0);
    assert!(hidden.is_empty(), "case 0 is clean: {hidden:?}");
    assert_eq!(r.verdict, "none", "{:#?}", r.ranking);
}

#[test]
fn a_lead_error_is_named_next_to_a_friction() {
    // Two-effect records 74 (lead error + viscous friction) and 75 (Stribeck friction + lead
    // error) of the independent seed 505, on the scale. Once the friction is modelled, the
    // lead error's pitch is found and it takes 14–25 % of the held-out position residual,
    // which the combined shrink (diluted by the force) read as 5–9 %.
    for i in [74, 75] {
        let (hidden, r) = standard_case(505, i);
        assert!(
            hidden.iter().any(|h| h == "lead_error"),
            "case {i}: {hidden:?}"
        );
        for h in &hidden {
            assert!(
                r.selected.contains(h),
                "case {i}: {h} not selected in {:?}",
                r.selected
            );
        }
    }
}

#[test]
fn a_compliance_that_leaves_the_force_alone_is_not_reported() {
    // Clean record 10 of the independent seed 606 (on the scale). A compliance candidate took
    // 81 % of the held-out position residual and none of the force (−4.8 %), on a 253 Hz
    // peak, and was reported; a payload on a spring changes the motor's force too.
    let (hidden, r) = standard_case(606, 10);
    assert!(hidden.is_empty(), "case 10 is clean: {hidden:?}");
    assert_eq!(r.verdict, "none", "{:#?}", r.ranking);
}

#[test]
fn a_lead_error_under_thermal_growth_is_named_too() {
    // Two-effect record 74 of the independent seed 808: screw growth of 17 µm and a lead
    // error of pitch 2.29 mm with a cumulative −26 µm/m. The growth, found first on the
    // fitting part, had taken the cumulative part there, so the lead error made the fitting
    // residual 9 % worse while it shrank the held-out one by 39 %, and it was dropped; beside
    // a growth, the held-out part alone now judges a lead error. A table with knots every
    // 2 mm cannot hold a 2.29 mm pitch either, and is no longer tried for it.
    let r = both_selected(808, 74, &["thermal_growth", "lead_error"]);
    let lead = ranked(&r, "lead_error");
    let pitch = lead.params.get("pitch_mm").copied().unwrap_or(f64::NAN);
    assert!(
        (pitch - 2.287).abs() < 0.02,
        "pitch {pitch} mm, hidden 2.287 mm"
    );
}

#[test]
fn a_command_logged_one_sample_ahead_is_a_skew_not_a_delay() {
    // A clean record whose command column holds each period's next command: position and
    // force follow the logged command exactly one sample late, which a one-sample command
    // delay would also give. A whole sample is read as the log's skew (WHOLE_SAMPLE_LAG_TOL),
    // removed, and the record ends clean; before, it was flagged `command_delay`.
    use axisbench::diagnose::calibrate::Channel;
    use axisbench::indep::{self, CaseSpec, SkewChannel, SkewPick};
    for seed in [31, 32] {
        let mut spec = CaseSpec::new("cmd_ahead", seed, vec![]);
        spec.duration_s = Some(24.0);
        spec.skew = SkewPick::Fixed(SkewChannel::Cmd, 1.0);
        let c = indep::generate(&spec).expect("case generates");
        let axis = diagnose::pick_axis(&c.trace, "case.csv", &c.preset, None).expect("axis");
        let rec = Record::for_preset(&c.trace, "case.csv", &c.preset, &axis).expect("record");
        let r = run(&c.preset, &rec, None, &Options::default());
        let skew = r.calibration.skew.as_ref().expect("a skew is found");
        assert!(
            matches!(skew.channel, Channel::Cmd),
            "seed {seed}: {skew:?}"
        );
        assert!((skew.samples - 1.0).abs() < 0.08, "seed {seed}: {skew:?}");
        assert_eq!(r.verdict, "none", "seed {seed}: {:#?}", r.ranking);
    }
}

#[test]
fn a_friction_seen_on_the_force_alone_is_reported() {
    // Single-effect record 20 of the independent seed 707: a viscous friction of
    // 107 N·s/m. Modelled, it takes 80 % of the held-out force residual away and leaves the
    // position residual (its noise and grid) as it was, so the combined shrink read 11.5 %,
    // a penalty short of the threshold, and the verdict was `none` (FORCE_ONLY_SHRINK).
    let r = named_single(707, 20, "viscous_friction");
    let v = &r.ranking[0].params["viscous_n_s_per_m"];
    assert!(
        (v - 107.4).abs() < 0.25 * 107.4,
        "viscous {v} N·s/m, hidden 107.4"
    );
}

#[test]
fn a_growth_without_a_drift_in_time_is_found_by_its_heat_and_bearing() {
    // Single-effect records 46 of the independent seeds 707 and 606: screw growth (12 and
    // 14 µm at steady state, time constants 107 and 585 s). The growth changes sign with
    // the position about its bearing, so the position residual has no slow drift in time,
    // and the verdict was `none` (707) or a lead error (606). The heat × distance regression
    // is now the growth's signature when it explains clearly more than a fixed slope.
    for seed in [707, 606] {
        let (hidden, r) = standard_case(seed, 46);
        assert_eq!(hidden, ["thermal_growth"]);
        assert_eq!(r.verdict, "thermal_growth", "seed {seed}: {:#?}", r.ranking);
    }
}

#[test]
fn a_friction_beside_a_hunting_play_is_found_through_the_tone() {
    // Pair record 67 of the independent seed 909: a viscous friction of 330 N·s/m and a
    // play of 11 µm. The drive hunts in the play (a 371 Hz tone of 41 N rms, 99 % of the
    // force residual above 50 Hz); the friction's held-out shrink was 2.7 % under the tone,
    // and only the play was named. Scored through a 20 ms moving average once the tone has
    // proven the play, the friction takes a quarter of the residual away.
    named_pair(909, 67, ["viscous_friction", "backlash"]);
    // Its size is not right yet, so it is not asserted: fitted on the model without the
    // play (a modelled play adds a tone of its own), the friction reads 72 N·s/m where the
    // record's speed term is 517 and the hidden one 330.
    // A play alone (seed 808's single record 29, its position logged a fraction of a sample
    // late) keeps its hunting tone out of the friction's score the other way: through the
    // moving average a viscous term took 43 % of the position residual and made the force
    // residual three times worse. A friction must show on the force first.
    let (hidden, r) = standard_case(808, 76 + 29);
    assert_eq!(hidden, ["backlash"]);
    assert!(
        !r.selected.iter().any(|e| e.ends_with("_friction")),
        "{:?}",
        r.selected
    );
}

#[test]
fn bursts_beside_a_hunting_play_are_found_through_the_tone() {
    // Pair record 70 of the independent seed 4949: bursts of 52–144 N for 0.08–0.19 s and a
    // rigid play of 19 µm in which the drive hunts (a 250 Hz tone of 51 N rms). Read off the
    // raw residual, the tone lifted the median window the bursts must stand above, and ten
    // level steps were read instead (held-out shrink −13 %); through the 20 ms moving
    // average that scores the rounds after the tone proved the play, four bursts are found
    // and take half of the held-out residual.
    let r = named_pair(4949, 70, ["external_disturbance", "backlash"]);
    let d = ranked(&r, "external_disturbance");
    // Reported as it was selected (the first round read steps).
    assert!(
        d.params.contains_key("windows") && d.evidence.contains("bursts"),
        "read as bursts, not steps: {:?}, {}",
        d.params,
        d.evidence
    );
}

#[test]
fn a_growth_beside_a_friction_is_found_as_the_friction_s_base() {
    // Pair record 73 of the independent seed 5151: a Coulomb friction of 24.2/27.8 N (by
    // direction) and a screw's growth of 20 µm heated by the friction's power. Neither was
    // found alone: the friction took 91 % of the held-out force but made the position 45 %
    // worse (the drift bent the calibration), and the growth took 19 % of the fitting part
    // and nothing held out. With the growth as the base, the friction takes 88 % of the
    // held-out residual.
    let r = named_pair(5151, 73, ["coulomb_friction", "thermal_growth"]);
    let fc = ranked(&r, "coulomb_friction").params["force_n"];
    assert!((fc - 25.9).abs() < 0.1 * 25.9, "Fc {fc} N, hidden 25.9 N");
    assert!(r.shrink > 0.5, "overall held-out shrink {}", r.shrink);
}

#[test]
fn a_stroke_friction_worn_by_distance_is_named() {
    // Single-effect record 27 of the independent seed 1010: a lubricant film that breaks
    // down over 3.7 mm run in short strokes (16 N at most). The signature regressed the
    // force on a level that counts short strokes only, 2.0 standard errors, and the record
    // was named Coulomb friction (22 % shrink) although the stroke friction's replay took
    // 77 % of the held-out residual. Worn by distance, the level stands at 4.4.
    named_single(1010, 27, "stroke_friction");
}

#[test]
fn a_stroke_friction_ahead_of_coulomb_on_both_parts_is_named() {
    // Single-effect record 25 of the independent seed 4848: a film that breaks down over
    // 7 mm run in short strokes, 18.2 N at most. Its regression stood 2.5 standard errors
    // clear (short of the signature's 6 and of the weak bar's 3), so the Coulomb friction,
    // 58 % held out, was named; the stroke friction's replay took 73 % held out and 85 % of
    // the fitting part against the Coulomb friction's 55 %. The stroke friction holds the
    // Coulomb friction, and its lead on both parts is the rise it adds
    // (STROKE_OVER_COULOMB).
    let r = named_single(4848, 25, "stroke_friction");
    let s = ranked(&r, "stroke_friction");
    assert!(
        s.note.contains("lead over a Coulomb friction"),
        "{}",
        s.note
    );
    let rise = s.params["rise_n"];
    assert!(
        (0.5 * 18.2..=1.5 * 18.2).contains(&rise),
        "rise {rise} N, hidden at most 18.2 N: {:?}",
        s.params
    );
}

#[test]
fn a_pitch_table_whose_error_lies_beyond_the_fitted_travel_is_named() {
    // Single-effect record 49 of the independent seed 4949: a pitch table of 17 knots every
    // 22.6 mm (±1.1 µm). The fitting part ran over 17–77 mm, where the table's error is
    // 0.135 µm rms; the held-out part over 32–130 mm, 79 % of its samples within the fitted
    // travel, but the 21 % beyond it carry 0.92 µm rms, most of the held-out position
    // residual. A table claims nothing beyond its travel, so it took 5 % held out and the
    // record was named `none`, although a table fitted on the first half of the fitting
    // part explained 96 % of the second half. The held-out part beyond the travel is now
    // also weighed by its residual (HOLDOUT_IN_TRAVEL).
    let r = named_single(4949, 49, "lead_error");
    let l = ranked(&r, "lead_error");
    let energy_in = l.evidence_figures["holdout_energy_in_travel_share"];
    assert!(energy_in < 0.5, "{energy_in}: {}", l.evidence);
    assert_eq!(
        l.evidence_figures.get("halves_hold"),
        Some(&1.0),
        "{}",
        l.evidence
    );
}

#[test]
fn a_compliance_without_ringing_is_found_with_its_calibration() {
    // Single-effect record 42 of the independent seed 808: a 19 kg payload on a spring at
    // 55 Hz. The calibration without it took kp ×1.05 and kv ×0.95, leaving a 3 µm
    // following-error residual; the compliance fitted on top of those ratios took 0.3 % of
    // the position and nothing showed a signature. Fitted together with the ratios it
    // takes both channels' residuals down (COMPLIANCE_BOTH).
    let r = named_single(808, 42, "compliance");
    let c = ranked(&r, "compliance");
    assert!(c.shrink_pos >= 0.5, "{c:#?}");
    assert!(c.shrink_force.is_some_and(|f| f >= 0.25), "{c:#?}");
}

#[test]
fn a_clean_record_whose_position_a_spring_absorbs_is_not_flagged() {
    // Clean record 1 of the independent seed 101: a compliance refitted with the
    // calibration takes 90 % of the held-out position residual, as a lag would, and only
    // 21 % of the force: no payload pushes on the drive.
    let (hidden, r) = standard_case(101, 1);
    assert!(hidden.is_empty());
    assert_eq!(r.verdict, "none", "{:#?}", r.ranking);
}

#[test]
fn a_stroke_friction_far_ahead_of_coulomb_counts_without_its_signature() {
    // Single-effect record 27 of the independent seed 808: a film worn over 3–15 mm strokes.
    // Its regression stood at 1.0 standard errors and the record was named Coulomb friction
    // (22 % held-out score), while the stroke friction's replay scored 41 %.
    let r = named_single(808, 27, "stroke_friction");
    assert!(
        ranked(&r, "stroke_friction")
            .note
            .contains("held-out score")
    );
}

#[test]
fn a_stroke_friction_alone_counts_by_the_force_it_takes() {
    // Single-effect record 26 of the independent seed 3434: friction grown over successive
    // strokes shorter than 7.5 mm. Its regression stood at 5.9 standard errors (the
    // direction column takes most of it), nothing else was found, and the record was named
    // `none`, while the stroke friction's replay took 32 % of the held-out residual and 33 %
    // of the force (STROKE_ALONE).
    let r = named_single(3434, 26, "stroke_friction");
    let note = &ranked(&r, "stroke_friction").note;
    assert!(note.contains("no other effect found"), "{note}");
}

#[test]
fn a_coulomb_friction_the_stroke_model_also_fits_stays_coulomb() {
    // Skewed record 13 of the independent seed 808 (index 76 + 13): a Coulomb friction on
    // which the stroke friction scores 1.22× the Coulomb friction, the most of any Coulomb
    // record seen; STROKE_OVER_BEST keeps it Coulomb.
    named_single(808, 89, "coulomb_friction");
}

#[test]
fn level_steps_are_not_read_as_a_slow_square_wave() {
    // Single-effect record 62 of the independent seed 808: two lasting force changes
    // (−54 N at 4.7 s, +20 N at 14.5 s). Their long "period" made a 5.6 s square wave the
    // detector's reading, which the held-out end refuted (−157 %) and the verdict was none.
    // Steps leave less than half of what the wave leaves of the unexplained force.
    let r = named_single(808, 62, "external_disturbance");
    let e = ranked(&r, "external_disturbance");
    assert!(e.params.contains_key("steps"), "{:?}", e.params);
    assert!(e.shrink > 0.5, "held-out shrink {}", e.shrink);
}

#[test]
fn bursts_are_not_read_as_a_slow_square_wave() {
    // Single-effect record 63 of the independent seed 808: bursts of +60, −43 N … lasting
    // 0.1–0.2 s. The periodogram of the force residual made a 3.1 s square wave of them
    // (24× its median), which the held-out end refuted (−40 %): verdict none. The bursts
    // leave less than half of what the wave leaves of the unexplained force.
    let r = named_single(808, 63, "external_disturbance");
    let e = ranked(&r, "external_disturbance");
    assert!(e.params.contains_key("windows"), "{:?}", e.params);
}

#[test]
fn a_sine_slow_enough_for_a_staircase_stays_a_sine() {
    // Single-effect record 61 of the independent seed 1111: a 4.9 s sine of ±37 N. Ten
    // level steps trace it closely enough to beat the wave; at most WAVE_RIVAL_STEPS may.
    let r = named_single(1111, 61, "external_disturbance");
    let e = ranked(&r, "external_disturbance");
    // A wave, at its period (5.08 s read against 4.875 s true: 3.3 periods in the fit).
    let period_s = e.params.get("period_s").copied().unwrap_or(f64::NAN);
    assert!((period_s / 4.875 - 1.0).abs() < 0.1, "{:?}", e.params);
}

#[test]
fn level_steps_count_by_the_fitting_part_when_the_held_out_end_steps_again() {
    // Single-effect record 62 of the independent seed 909: steps at 15.3, 17.9 and 21.0 s,
    // two of them in the held-out end, where the model holds the last level: held-out −31 %,
    // fitting part +89 %. Counted like bursts, and the report says why.
    let r = named_single(909, 62, "external_disturbance");
    let e = ranked(&r, "external_disturbance");
    assert!(e.shrink < 0.0, "held-out shrink {}", e.shrink);
    assert!(e.note.contains("fitting part"), "{}", e.note);
}

#[test]
fn level_steps_are_fitted_with_the_states_they_move_with() {
    // Single-effect record 62 of the independent seed 2929: level steps of −38, +50 and
    // +20 N at 2.1, 13.2 and 16.2 s. The force's states fitted alone took −312 N·s/m of
    // speed term from them, which left a residual no staircase follows (ten steps, held-out
    // −40 %, verdict none); fitted with the steps, the states keep their own share.
    let r = named_single(2929, 62, "external_disturbance");
    let e = ranked(&r, "external_disturbance");
    assert!(e.params.contains_key("steps"), "{:?}", e.params);
    assert!(e.shrink > 0.5, "held-out shrink {}", e.shrink);
}

#[test]
fn a_level_step_shortly_before_the_held_out_end_sets_its_level() {
    // Single-effect record 62 of the independent seed 3434: the last step (47 → 19 N)
    // comes 0.28 s before the fitting part's end, inside the 0.5 s the step search kept from
    // the ends, so the held-out part was predicted at 47 N (held-out position residual
    // doubled once the channels were skewed). The last step may come 0.1 s before the end.
    let r = named_single(3434, 62, "external_disturbance");
    let e = ranked(&r, "external_disturbance");
    assert!(e.params.contains_key("steps"), "{:?}", e.params);
    assert!(e.shrink > 0.6, "held-out shrink {}", e.shrink);
}

#[test]
fn bursts_that_a_stribeck_friction_explains_better_are_not_counted_by_the_fitting_part() {
    // Single-effect record 16 of the independent seed 3232: a Stribeck friction, whose
    // excess at each reversal the burst search read as ten bursts. Bursts count by the
    // fitting part (58 % of it) and were named first; the Stribeck friction explains 88 %
    // of the fitting part, so the bursts are its force and count only by the held-out part.
    let (hidden, r) = standard_case(3232, 16);
    assert_eq!(hidden, ["stribeck_friction"]);
    let e = ranked(&r, "external_disturbance");
    assert!(e.params.contains_key("windows"), "{:?}", e.params);
    assert!(!e.significant, "{e:?}");
    assert!(
        e.note.contains("stribeck_friction explains more"),
        "{}",
        e.note
    );
    assert!(
        !r.selected.iter().any(|s| s == "external_disturbance"),
        "{:?}",
        r.selected
    );
}

#[test]
fn level_steps_that_explain_little_of_the_fitting_part_are_not_named() {
    // Single-effect record 37 of the independent seed 3333: a constant force. Once it was
    // found, ten level steps of a few newtons took 4 % of the fitting residual and 38 % of the
    // held-out one (the last level is an offset there), and were named beside it.
    let r = named_single(3333, 37, "constant_force");
    assert_eq!(r.selected, ["constant_force"], "{:#?}", r.ranking);
}

#[test]
fn a_constant_force_is_not_read_as_a_play_of_no_width() {
    // Single-effect records 38 of the independent seeds 808 and 909: a constant force of
    // 27 and 38 N. The play with one flank favoured fitted a 4 µm gap and scored 0.6 % above
    // the constant force, though it predicted the held-out part 0.3–0.4 % worse.
    for seed in [808, 909] {
        let r = named_single(seed, 38, "constant_force");
        assert!(
            !r.selected.iter().any(|s| s == "backlash_asymmetry"),
            "seed {seed}: {:?}",
            r.selected
        );
    }
}

#[test]
fn a_viscous_term_beyond_the_calibrations_range_is_found_beside_quantization() {
    // Two-effect record 73 of the independent seed 1010: a directional viscous friction
    // (−149 / −56 N·s/m on a nominal 203.5) and a 0.8 µm grid. The calibration stopped at
    // ×0.967, not at its bound, so the speed term (−95 N·s/m, 50 standard errors) was read
    // as "within what the calibration covers". More than the calibration's whole range is
    // not a correction.
    named_pair(1010, 73, ["viscous_friction", "quantization"]);
}

#[test]
fn a_film_worn_by_distance_is_fitted_with_the_distance_law() {
    // Single-effect record 25 of the independent seed 808: a film that breaks down within
    // 15 mm of every turning point (6.3 mm scale) and rebuilds over 26 mm beyond. The count
    // law predicted 56 % of the held-out part; the distance law (FilmLaw::Distance) leaves
    // less than 0.9× of the count law's fitting residual and predicts 88 %.
    let r = named_single(808, 25, "stroke_friction");
    let e = ranked(&r, "stroke_friction");
    assert!(e.params.contains_key("recovery_mm"), "{:?}", e.params);
    assert!(e.shrink > 0.8, "held-out shrink {}", e.shrink);
}

/// The ranking entry of `effect` in `r`.
fn ranked<'a>(r: &'a Report, effect: &str) -> &'a axisbench::diagnose::RankEntry {
    r.ranking
        .iter()
        .find(|e| e.effect == effect)
        .unwrap_or_else(|| panic!("{effect} ranked in {:?}", r.selected))
}

#[test]
fn a_payload_on_a_hardening_mount_is_found_with_its_hardening() {
    // Single-effect record 41 of the independent seed 1717: a 36 kg payload on a 45 Hz mount
    // whose force doubles at 11.9 µm. The force residual rang after the acceleration steps
    // (9 standard errors), but a linear spring made the force residual worse (−2 %) and
    // the record was named command delay. The hardening mount takes 35 % of the force and
    // 91 % of the position.
    let r = named_single(1717, 41, "compliance");
    let c = ranked(&r, "compliance");
    let d0 = c
        .params
        .get("hardening_deflection_um")
        .copied()
        .unwrap_or(f64::NAN);
    assert!(
        (3.0..=30.0).contains(&d0),
        "d0 = {d0} µm (true 11.9): {:?}",
        c.params
    );
    assert!(c.shrink_force.is_some_and(|f| f >= 0.2), "{c:#?}");
}

#[test]
fn a_command_that_lags_is_fitted_as_a_lag() {
    // Single-effect record 59 of the independent seed 3838: the command passes a first-order
    // lag of 1.83 ms. A pure delay (1.23 samples) left each change of feed's rounding, a
    // screw's spring took 4 % of it, and the delay, short enough for a command skew, was
    // named after the spring. Fitted as a lag, the delay is the verdict and alone.
    let r = named_single(3838, 59, "command_delay");
    assert_eq!(r.selected, ["command_delay"], "{:#?}", r.ranking);
    let d = ranked(&r, "command_delay");
    let lag_ms = d.params.get("lag_ms").copied().unwrap_or(f64::NAN);
    assert!(
        (lag_ms - 1.826).abs() <= 0.1 * 1.826,
        "lag {lag_ms} ms (true 1.826): {:?}",
        d.params
    );
}

#[test]
fn a_cumulative_lead_error_outranks_a_growth_by_the_position() {
    // Single-effect record 48 of the independent seed 4444: a lead error of 10.4 µm/m along
    // the travel under a 0.09 µm pitch error, on a scale. Its candidate took 67 % of the
    // held-out position residual and a screw's growth 49 %; both were found, and the growth's
    // combined score (3 parameters against the harmonics' 8) named it. Both move the
    // position alone: the one that takes clearly more of it ranks first (POSITION_LEAD).
    let r = named_single(4444, 48, "lead_error");
    let note = &ranked(&r, "lead_error").note;
    assert!(note.contains("held-out position"), "{note}");
}

#[test]
fn a_near_tie_of_coulomb_and_stroke_friction_is_decided_by_the_fitting_part() {
    // Single-effect records of the independent seeds 1010 (case 24: a stroke friction, 29 N
    // over strokes shorter than a 4.3 mm pitch) and 909 (case 13: a Coulomb friction
    // smoothed over 1 mm/s). Their held-out ends hold long moves only, where the two laws
    // predict alike: 0.573 against 0.604 and 0.400 against 0.375 held-out, so the wrong one
    // came first. The fitting part, which saw the short strokes, tells them apart (0.480
    // against 0.245, 0.571 against 0.457). Since stop 56 the Coulomb friction of 909 is
    // fitted with its smoothing (tanh(v/ε)), and that law leads outright: it is named with
    // ε within 20 % of the hidden 1 mm/s, and the tie is not needed.
    let r = named_single(1010, 24, "stroke_friction");
    let e = ranked(&r, "stroke_friction");
    assert!(e.note.contains("by the fitting part"), "{:?}", e.note);
    let r = named_single(909, 13, "coulomb_friction");
    let e = ranked(&r, "coulomb_friction");
    let eps = e
        .params
        .get("smoothing_mm_per_s")
        .copied()
        .unwrap_or(f64::NAN);
    assert!(
        e.note.contains("by the fitting part") || (eps - 1.0).abs() < 0.2,
        "{:?} {:?}",
        e.note,
        e.params
    );
}

#[test]
fn a_wide_lead_on_the_fitting_part_widens_the_coulomb_stroke_tie() {
    // Single-effect records 24 and 26 of the independent seed 2727: stroke frictions (44 N
    // over strokes shorter than 12.3 mm, 22 N under 12.6 mm) whose held-out ends trailed
    // Coulomb's score by 0.077 and 0.141, outside the fixed tie of 0.06, while they took
    // 0.85 against 0.53 and 0.63 against 0.43 of the fitting part: the tie is now 3/4 of
    // that lead. Since the calibration is fitted again with the candidates' weights (stop
    // 32), both stroke frictions lead or tie the held-out part too: they must stay named.
    for i in [24, 26] {
        named_single(2727, i, "stroke_friction");
    }
}

#[test]
fn a_friction_that_takes_a_third_of_the_force_counts_whatever_the_position_gained() {
    // Record 21 of the independent seed 2828 with its force logged a sample off (standard
    // case 76 + 21): the viscous friction that differs by direction took 84 % of
    // the held-out position and 38 % of the force, less than half the position's share
    // (FORCE_SHARE), and was not counted; 38 % of the force is a force by itself.
    let r = named_single(2828, 76 + 21, "viscous_friction");
    let e = ranked(&r, "viscous_friction");
    assert!(e.shrink_force.is_some_and(|f| f >= 0.3), "{e:#?}");
}

#[test]
fn a_one_sample_lag_of_a_missing_viscous_friction_is_not_read_as_a_command_skew() {
    // Single-effect record 20 of the independent seed 1818: a viscous friction of
    // +344 N·s/m. The loop follows late by 0.98 samples, which the calibration read as the
    // command logged one sample early; realigned, no viscous friction fitted (−6.5 %
    // held-out) and the verdict was none. Both readings are diagnosed now, and the lag's
    // leaves a tenth of what the realigned one leaves.
    let r = named_single(1818, 20, "viscous_friction");
    assert!(r.calibration.skew.is_none(), "{:?}", r.calibration.skew);
    assert!(
        r.calibration
            .lag_reading
            .contains("also diagnosed as the command logged a sample early"),
        "{:?}",
        r.calibration.lag_reading
    );
    let c = ranked(&r, "viscous_friction")
        .params
        .get("viscous_n_s_per_m")
        .copied()
        .unwrap_or(f64::NAN);
    assert!((250.0..=450.0).contains(&c), "{c} N·s/m (true 344)");
}

#[test]
fn a_compliance_the_held_out_end_never_excites_counts_by_the_fitting_part() {
    // Single-effect record 43 of the independent seed 808: a 78 Hz payload mount. The
    // fitting part's acceleration steps make the force residual ring (10 standard errors)
    // and the payload takes 62 % of it; the held-out end (16.8–24 s) holds no acceleration
    // step, so nothing there can confirm the spring (−1 % held-out) and the verdict was none.
    let r = named_single(808, 43, "compliance");
    let e = ranked(&r, "compliance");
    assert!(
        e.note.contains("counted by the fitting part"),
        "{:?}",
        e.note
    );
}

#[test]
fn a_second_effect_is_not_credited_with_a_refit_of_the_first() {
    // Single-effect records 38 and 39 of the independent seed 808: a constant force. Beside
    // it, a viscous friction fitted jointly with the constant force and the calibration took
    // 60–64 % of the held-out force residual and was selected second; with the viscous term
    // taken out again, the constant force and the ratios as that fit left them took all of
    // that (the viscous term itself: 1 %). A later round's candidates are judged against the
    // best such fit of the round (`candidates::best_without`).
    for i in [38, 39] {
        let r = named_single(808, i, "constant_force");
        assert_eq!(r.selected, ["constant_force"], "case {i}: {:?}", r.selected);
    }
}

#[test]
fn a_lag_reading_that_names_a_delay_is_the_skew_again() {
    // Clean record 11 of the independent seed 1111, its command logged one sample early
    // (standard case 87). Read as a lag of the responses, a one-sample command delay took
    // it, a viscous term beside it took a little more, and that reading was kept: a false
    // alarm. A delay of one sample is the realignment by another name.
    let (hidden, r) = standard_case(1111, 87);
    assert!(hidden.is_empty(), "case 87 is clean: {hidden:?}");
    assert_eq!(r.verdict, "none", "{:#?}", r.ranking);
}

#[test]
fn a_pitch_table_is_fitted_as_a_table_though_the_residual_drifts_in_time() {
    // Seed 2222 case 49: a lead error given as a pitch table (knots every 12 mm, ±4 µm).
    // The program visits the travel unevenly in time, so the residual also "drifts", and a
    // drifting residual used to keep the local table out (a growing screw leaves an error
    // along the travel too). Three harmonics of the 68 mm period the spectrum found
    // explained none of the held-out part and the verdict was none. A table fitted on the
    // first half of the fitting part predicts its second half, so it is a pitch error.
    let shrink_pos = lead_named_as_table(2222, 49);
    assert!(shrink_pos > 0.4, "position shrink {shrink_pos}");
}

#[test]
fn a_pitch_table_is_fitted_beside_the_following_error_of_each_direction() {
    // Seed 5555 case 51: a lead error given as a pitch table (knots every 5–25 mm, ±2.6 µm),
    // on a machine whose friction law differs from the model's, so the following error at
    // constant feed differs by direction of travel at the same place. The table fitted to
    // the residual alone took that offset in as well, and the record's verdict was none. A
    // lead error is the same both ways: fitted beside a direction offset (left out of the
    // model), the table is found and takes about a third of the held-out position residual.
    let shrink_pos = lead_named_as_table(5555, 51);
    assert!(shrink_pos > 0.25, "position shrink {shrink_pos}");
}

#[test]
fn a_pitch_the_harmonics_cannot_use_leaves_the_table_its_own_test() {
    // Seed 5454 case 51: a lead error given as a pitch table (knots every 8 mm, ±4 µm). The
    // spectrum peaked at 6.3 mm, a pitch the table does not have; three harmonics there left
    // 14 % more of the fitting part than none, and since a period was found the table's own
    // test (fitted on the first half of the fitting part, does it hold on the second?) was
    // never asked. The verdict was none. Now a period the harmonics cannot use counts as
    // none found, and the table, which explains 99 % of the second half, is named.
    let shrink_pos = lead_named_as_table(5454, 51);
    assert!(shrink_pos > 0.05, "position shrink {shrink_pos}");
}

/// Standard case `i` of `seed`, a lead error alone, diagnosed: the lead error must be the
/// verdict and fitted as a table of knots. Returns its held-out position shrink.
fn lead_named_as_table(seed: u64, i: usize) -> f64 {
    let r = named_single(seed, i, "lead_error");
    let lead = r
        .ranking
        .iter()
        .find(|e| e.effect == "lead_error")
        .expect("lead error ranked");
    assert!(lead.params.contains_key("table_points"), "{lead:#?}");
    lead.shrink_pos
}

#[test]
fn a_settled_screw_growth_is_not_taken_for_a_pitch_table() {
    // Seed 1919 case 46: a screw growth that settled early in the record. A local table of
    // knots explains its held-out part about as well (0.235 against 0.237); charged as two
    // report figures instead of the harmonics it replaces, the freer table won on the
    // penalty alone.
    let r = named_single(1919, 46, "thermal_growth");
    assert_eq!(
        r.selected.first().map(String::as_str),
        Some("thermal_growth")
    );
}

#[test]
fn a_pitch_table_is_not_read_as_harmonics_that_miss_the_held_out_part() {
    // Seed 2323 case 51: a pitch table of knots. Three harmonics of the 65 mm period the
    // spectrum found took a quarter of the fitting part and made the held-out position
    // residual 37 % worse; the table took a little more of the fitting part, and fitted on
    // the first half of it, predicted the second half far better than the harmonics did.
    let shrink_pos = lead_named_as_table(2323, 51);
    assert!(shrink_pos > 0.3, "position shrink {shrink_pos}");
}

#[test]
fn a_friction_read_as_a_skew_before_any_effect_is_no_skew_once_it_is_found() {
    // Single-effect record 14 of the independent seed 2424: a Coulomb friction, no channel
    // skewed. Fitted against the calibrated nominal, which lacks the friction, the shifts
    // read the responses 0.72 samples ahead of the model, i.e. the command logged late,
    // and the record was realigned by it. Fitted again beside the friction found, the
    // shifts leave no skew; the effects selected again on the record as logged leave less
    // of the held-out part, and that reading is kept. The shifts are fitted again as soon
    // as the first round has found the friction, and the first reading stops there.
    use axisbench::diagnose::calibrate::Channel;
    let r = named_single(2424, 14, "coulomb_friction");
    assert!(r.calibration.skew.is_none(), "{:?}", r.calibration.skew);
    let refit = r.calibration.refit.expect("fitted again");
    assert!(refit.kept_second && refit.first_stopped, "{refit:?}");
    assert!(refit.j_second < refit.j_first, "{refit:?}");
    assert!(
        refit
            .other
            .is_some_and(|s| matches!(s.channel, Channel::Cmd) && s.samples < -0.5),
        "{refit:?}"
    );
}

#[test]
fn a_skew_hidden_by_a_friction_is_found_once_the_friction_is_found() {
    // The same record with its force logged one sample early (standard case 76 + 14).
    // Against the nominal alone, the friction holds most of the residual and the two
    // shifts read a common lag of 0.87 samples: no skew, and the force skew left to the
    // effects. Fitted again beside the friction found, the force is a sample off.
    use axisbench::diagnose::calibrate::Channel;
    let r = named_single(2424, 90, "coulomb_friction");
    let skew = r.calibration.skew.expect("a skew is found");
    assert!(
        matches!(skew.channel, Channel::Force) && (skew.samples + 1.0).abs() < 0.1,
        "{skew:?}"
    );
    let refit = r.calibration.refit.expect("fitted again");
    assert!(refit.kept_second && refit.other.is_none(), "{refit:?}");
}

/// Standard case `i` of `seed`, which must hide exactly `effects`, diagnosed: its report,
/// after checking that every hidden effect is selected.
fn both_selected(seed: u64, i: usize, effects: &[&str]) -> Report {
    let (mut hidden, r) = standard_case(seed, i);
    hidden.sort();
    let mut want: Vec<String> = effects.iter().map(|e| (*e).to_owned()).collect();
    want.sort();
    assert_eq!(hidden, want, "seed {seed} case {i}");
    for h in &hidden {
        assert!(
            r.selected.contains(h),
            "seed {seed} case {i}: {h} not selected in {:?}: {:#?}",
            r.selected,
            r.ranking
        );
    }
    r
}

#[test]
fn a_fine_pitch_beside_a_viscous_friction_is_found_by_its_period() {
    // Two-effect record 64 of the independent seed 2323: a lead error of pitch 2.591 mm and
    // 0.33 µm beside a viscous friction. Binned by position, the following error of each
    // feed and the dynamics at the ends of the moves showed as periods of 39–53 mm that
    // drowned the pitch; with each feed's mean removed where the command holds a feed, the
    // pitch is the spectrum's peak.
    let (hidden, r) = standard_case(2323, 64);
    assert!(hidden.iter().any(|h| h == "lead_error"), "{hidden:?}");
    let lead = r
        .ranking
        .iter()
        .find(|e| e.effect == "lead_error")
        .expect("lead error ranked");
    let pitch_mm = lead.evidence_figures["pitch_mm"];
    // The fundamental, or a subharmonic whose second or third harmonic it is (the search
    // tries those).
    let k = (pitch_mm / 2.591).round();
    assert!(
        (1.0..=3.0).contains(&k) && (pitch_mm / k - 2.591).abs() < 0.01 * 2.591,
        "pitch {pitch_mm} mm: {}",
        lead.evidence
    );
}

#[test]
fn a_pitch_table_beside_a_viscous_friction_is_named() {
    // Two-effect record 71 of the independent seed 2727: a lead-error table of knots every
    // 19 mm beside a viscous friction. Searched over every sample, the period of the
    // residual was a 60 mm bow of the dynamics (4 % explained); where the command holds a
    // feed, less each feed's mean, the knots' 25 mm shape explains 32 %, and the table of
    // knots takes 22 % of the held-out position residual.
    both_selected(2727, 71, &["lead_error", "viscous_friction"]);
}

#[test]
fn a_viscous_friction_that_differs_by_direction_is_named_with_its_split() {
    // Single-effect record 21 of the independent seed 2828: the generator's viscous
    // coefficient is 105.7 N·s/m larger moving + and 36.4 N·s/m moving − (its own
    // formula, on top of a nominal off by 4 %). One symmetric coefficient took the mean and
    // left the force residual worse held-out (−140 %), and the verdict was `none`; the
    // |v| term of the force residual is the split, (105.7 − 36.4)/2 = 34.7 N·s/m.
    let r = named_single(2828, 21, "viscous_friction");
    let v = ranked(&r, "viscous_friction");
    let split = v.params.get("split_n_s_per_m").copied().unwrap_or(f64::NAN);
    assert!(
        (split - 34.7).abs() < 0.25 * 34.7,
        "split {split} N·s/m, want 34.7 ± 25 %: {v:#?}"
    );
}

#[test]
fn a_split_that_stands_far_beyond_its_noise_counts_without_the_force_share() {
    // Single-effect record 21 of the independent seed 4747: an extra viscous coefficient of
    // 20.4 N·s/m moving + and 89.9 N·s/m moving −. Fitted with its split, it took 70 % of
    // the held-out position and 25 % of the force, short of half the position's share
    // (FORCE_SHARE), and the verdict was `none`, while the |v| term of the force residual
    // stood at 328 standard errors (SPLIT_T_ALONE): no loop mismatch leaves a force that
    // keeps its sign both ways. The split is (20.4 − 89.9)/2 = −34.8 N·s/m.
    let r = named_single(4747, 21, "viscous_friction");
    let v = ranked(&r, "viscous_friction");
    let split = v.params.get("split_n_s_per_m").copied().unwrap_or(f64::NAN);
    assert!(
        (split + 34.8).abs() < 0.15 * 34.8,
        "split {split} N·s/m, want −34.8 ± 15 %: {v:#?}"
    );
}

#[test]
fn a_stroke_friction_the_held_out_end_hardly_exercises_counts_by_its_fit() {
    // Single-effect record 24 of the independent seed 4747: friction rising by 40.4 N over
    // strokes shorter than 7.5 mm. Its regression stood at 11.7 standard errors and its
    // replay took 77 % of the fitting part, but 13 % of the held-out part (9 % after the
    // penalty, below MIN_SHRINK), and the verdict was `none` (STROKE_FIT_SHRINK).
    let r = named_single(4747, 24, "stroke_friction");
    let e = ranked(&r, "stroke_friction");
    assert!(e.note.contains("fitting part"), "{e:#?}");
    let rise = e.params.get("rise_n").copied().unwrap_or(f64::NAN);
    assert!(
        (rise - 40.4).abs() < 0.15 * 40.4,
        "rise {rise} N (true 40.4): {e:#?}"
    );
    let pitch = e.params.get("pitch_mm").copied().unwrap_or(f64::NAN);
    assert!(
        (0.8 * 7.52..=1.6 * 7.52).contains(&pitch),
        "pitch {pitch} mm (true 7.52): {e:#?}"
    );
}

#[test]
fn a_screw_growth_beside_a_friction_counts_by_its_position_shrink() {
    // Two-effect record 64 of the independent seed 2626: a screw growth of 9.6 µm beside a
    // Stribeck friction. Once the friction is found, the growth takes 29 % of the held-out
    // position residual, but the force the friction left dilutes its combined score to
    // 0.007, and a lead error's harmonics took the drift instead.
    both_selected(2626, 64, &["thermal_growth", "stribeck_friction"]);
}

#[test]
fn a_delay_beside_a_coarse_grid_is_scored_on_what_lies_above_the_rounding() {
    // Two-effect record 75 of the independent seed 4747: a command lagging 0.78 ms (first
    // order) and a 3.6 µm scale grid. The grid's rounding (1.05 µm rms) is most of the
    // 1.6 µm held-out position residual; the delay took 26 % of it, 0.09 combined, below the
    // threshold, and only the grid was named. Above the rounding's spread it takes over half.
    let r = both_selected(4747, 75, &["command_delay", "quantization"]);
    let d = ranked(&r, "command_delay");
    let ms = d.params["delay_ms"];
    assert!(ms > 0.1 && ms < 1.5, "delay {ms} ms: {d:#?}");
}

#[test]
fn a_delay_beside_a_disturbance_counts_by_the_position_it_takes() {
    // Two-effect record 65 of the independent seed 4040: a command delay and an external
    // force. Position and force lag the model by 1.73 samples, more than a channel skew
    // makes; the delay takes 73 % of the held-out position residual and leaves the force as
    // it was, but the disturbance's force residual diluted its combined shrink to 1 %, and
    // only the disturbance was named.
    let r = both_selected(4040, 65, &["command_delay", "external_disturbance"]);
    let ms = ranked(&r, "command_delay").params["delay_ms"];
    assert!((ms - 2.0).abs() < 0.25 * 2.0, "delay {ms} ms, true 2.0 ms");
}

#[test]
fn a_play_and_a_constant_force_are_both_named() {
    // Two-effect record 64 of the independent seed 4545: an 18 µm gap in a two-mass drive and
    // a constant force of 5.1 N. The two were found, and named as one play with a favoured
    // flank, a name the list of effects does not have.
    let r = both_selected(4545, 64, &["backlash", "constant_force"]);
    let f = ranked(&r, "constant_force").params["force_n"];
    assert!(
        (f - 5.05).abs() < 0.2 * 5.05,
        "force {f} N: {:#?}",
        r.ranking
    );
}

#[test]
fn a_play_with_one_flank_favoured_is_named_as_a_play_and_a_constant_force() {
    // Single-effect record 32 of the independent seed 2929: a gap of 21.4 µm (contact
    // stiffness 140 N/µm) and a bias of −42.1 N on the carriage. `backlash_asymmetry` is
    // exactly a play and a constant force, so the diagnosis names the two effects of the
    // issue's list (a record with a play and a load is a two-effect record), each with a
    // note that together they favour one flank.
    let (hidden, r) = standard_case(2929, 32);
    assert_eq!(hidden, ["backlash_asymmetry"]);
    for e in ["backlash", "constant_force"] {
        assert!(r.selected.iter().any(|s| s == e), "{e}: {:#?}", r.selected);
    }
    assert!(
        !r.selected.iter().any(|s| s == "backlash_asymmetry"),
        "{:#?}",
        r.selected
    );
    let (b, c) = (ranked(&r, "backlash"), ranked(&r, "constant_force"));
    let (w, f) = (b.params["width_um"], c.params["force_n"]);
    assert!((f.abs() - 42.1).abs() < 0.1 * 42.1, "force {f} N: {c:#?}");
    // The bias holds the carriage on one flank except where the drive's force crosses it,
    // so the width is seen only in part (read at 10.7 µm): found, but not to the µm.
    assert!(w > 0.4 * 21.4 && w < 1.2 * 21.4, "width {w} µm: {b:#?}");
    assert!(c.note.contains("one flank"), "{c:#?}");
}

#[test]
fn the_calibration_reads_the_gains_with_the_weights_the_candidates_are_scored_with() {
    // Clean record 0 of the independent seed 2323 (motor encoder): its velocity gain is
    // 5.0 % above the nominal. Fitted with the nominal's weights, where the force's noise
    // outweighs a tenth of a µm of position, the calibration read +4.3 % and left a held-out
    // position residual of 0.20 µm, of which a stiff compliance then took 79 %. Fitted once
    // more with the calibrated residual's weights, it reads the gain and leaves the noise.
    let (c, r) = standard_case_with_truth(2323, 0);
    assert!(c.truth.effects.is_empty(), "case 0 is clean");
    let kv_true = c.truth.nominal_scale["kv_n_s_per_m"];
    assert_eq!(r.verdict, "none", "{:#?}", r.ranking);
    let kv = cal_ratio(&r, "kv");
    assert!((kv - kv_true).abs() < 0.003, "kv ×{kv}, true ×{kv_true}");
    assert!(
        r.overall.rms_after < 0.05,
        "held-out position residual {} µm",
        r.overall.rms_after
    );
}

#[test]
fn a_mass_more_than_eight_per_cent_off_is_read_as_calibration() {
    // Clean record 11 of the independent seed 2929 (motor encoder): its carriage is 4.4 %
    // heavier and its motor's force constant 1.9 % weaker than the nominal says, so the mass
    // the commanded force moves is 9.5 % above the nominal's. Within ±8 % the calibration
    // stopped at the bound and left 0.034 µm held-out; the mass's own bound reads it.
    let (c, r) = standard_case_with_truth(2929, 11);
    assert!(c.truth.effects.is_empty(), "case 11 is clean");
    let s = &c.truth.nominal_scale;
    let d = &c.preset.axes[0].drive;
    let (m_motor, m_table) = (d.reflected_motor_mass_kg(), d.table_mass_kg);
    let mass_true = (m_motor * s["motor_mass_kg"] + m_table * s["table_mass_kg"])
        / (m_motor + m_table)
        / s["force_gain"];
    assert!(mass_true > 1.09, "the record's mass ×{mass_true}");
    assert_eq!(r.verdict, "none", "{:#?}", r.ranking);
    let mass = cal_ratio(&r, "mass");
    assert!(
        (mass - mass_true).abs() < 0.005,
        "mass ×{mass}, true ×{mass_true}"
    );
    assert!(
        r.overall.rms_after < 0.03,
        "held-out position residual {} µm",
        r.overall.rms_after
    );
}

#[test]
fn a_stiff_payload_the_force_noise_hides_is_found_by_the_loops_peak() {
    // Single-effect record 43 of the independent seed 3333 (motor encoder): 26 kg on a
    // 108 Hz mount (8.7 N/µm, 3.7 % of critical). The force residual shows no resonance (the
    // command does not excite it above the force noise) and no ringing, but the closed loop
    // rings at ~24 Hz where the calibrated model's does not: the position residual's peak
    // there stands hundreds of times above its spectrum's median (clean records: 2–16×).
    // (Until stop 36 this was 3232's record 42, whose ringing now passes: its overshoot
    // is paired with the dip before it, see `evidence::ringing`.)
    let r = named_single(3333, 43, "compliance");
    let e = ranked(&r, "compliance");
    let f_hz = e.evidence_figures.get("loop_peak_hz").copied();
    assert!(f_hz.is_some_and(|f| (10.0..40.0).contains(&f)), "{e:#?}");
    let k = e.params["stiffness_n_per_um"];
    assert!(
        k > 8.73 / 2.0 && k < 8.73 * 2.0,
        "stiffness {k} N/µm: {e:#?}"
    );
}

#[test]
fn a_pitch_table_whose_held_out_part_lies_beyond_its_travel_is_judged_on_its_halves() {
    // Single-effect record 49 of the independent seed 2929 (scale): a pitch table of ±4 µm,
    // knots every 11.8 mm. The program's travel moves on: 94 % of the held-out part lies
    // beyond the travel the fitting part covers, where a table claims nothing, so the table
    // took 0.6 % of the held-out residual and was not named. Fitted on the first half of the
    // fitting part, it holds on the second.
    let r = named_single(2929, 49, "lead_error");
    let e = ranked(&r, "lead_error");
    let fig = |k: &str| e.evidence_figures.get(k).copied();
    assert!(
        fig("holdout_in_travel_share").is_some_and(|s| s < 0.1),
        "{e:#?}"
    );
    assert_eq!(fig("halves_hold"), Some(1.0), "{e:#?}");
    assert!(e.shrink > -0.02, "held-out shrink {}", e.shrink);
}

#[test]
fn a_straight_pitch_table_beyond_the_held_out_travel_is_judged_without_the_line() {
    // Single-effect record 49 of the independent seed 5858: a pitch table of knots. 86 % of
    // the held-out part lies beyond the travel the fitting part covers, so the table is
    // judged on the halves of the fitting part. Within the first half's travel the table
    // was nearly straight: fitted on the first half it explained 99 % of the second, but a
    // straight line did as well, and "no better than a line" kept it out (the verdict was
    // none). The line test tells a screw's growth from a pitch error; this residual does not
    // drift in time, and a straight error along the travel that stays put is a lead error.
    let r = named_single(5858, 49, "lead_error");
    let e = ranked(&r, "lead_error");
    assert_eq!(e.evidence_figures.get("halves_hold"), Some(&1.0), "{e:#?}");
    assert!(
        e.shrink_pos > 0.05,
        "held-out position shrink {}",
        e.shrink_pos
    );
}

#[test]
fn a_sharp_fine_pitch_beside_a_friction_the_model_lacks_is_named() {
    // Two-effect record 64 of the independent seed 2323 (scale): a lead error of 0.33 µm
    // at a 2.59 mm pitch beside a power-law viscous friction. The linear viscous term found
    // first leaves most of the held-out position residual (the friction's law), so the
    // pitch takes only ~6 % of it; its spectrum's peak, ~1000× the median with half the
    // quiet samples' residual explained, is what names it.
    let r = both_selected(2323, 64, &["lead_error", "viscous_friction"]);
    let pitch_mm = ranked(&r, "lead_error").params["pitch_mm"];
    assert!(
        (pitch_mm - 2.5906).abs() < 0.01,
        "pitch {pitch_mm} mm, true 2.5906 mm"
    );
}

#[test]
fn a_constant_force_beside_a_sine_is_named_as_well() {
    // Two-effect record 66 of the independent seed 2828: a cable carrier's force (−35 N,
    // 33 N/m along the travel) beside a 3.8 s sine of ±19 N. The sine was fitted with a mean,
    // which took the carrier's force, and the constant force was not named. A sine has no
    // mean: the constant force is what the next round finds.
    let r = both_selected(2828, 66, &["constant_force", "external_disturbance"]);
    let e = ranked(&r, "external_disturbance");
    assert_eq!(e.params.get("offset_n"), Some(&0.0), "{:?}", e.params);
    let f_n = ranked(&r, "constant_force").params["force_n"];
    assert!(
        (f_n + 34.7).abs() < 7.0,
        "constant force {f_n} N, true −34.7 N"
    );
}

#[test]
fn a_delay_a_command_skew_makes_is_named_after_the_records_own_effect() {
    // Single-effect record 20 of the independent seed 2929, skewed (index 76 + 20): a
    // viscous friction, its command logged one sample early. Position and force lag the
    // logged command by a sample, which a command delay also makes; the delay (1.05
    // samples) took more of the held-out residual than the friction and was named first.
    // A delay of at most a sample and a quarter beside another effect is named after it.
    let (hidden, r) = standard_case(2929, 96);
    assert_eq!(hidden, ["viscous_friction"]);
    assert_eq!(r.verdict, "viscous_friction", "{:#?}", r.ranking);
    assert_eq!(r.selected, ["viscous_friction", "command_delay"]);
    let d = ranked(&r, "command_delay");
    assert!(d.note.contains("logged"), "{}", d.note);
    assert!(d.params["delay_ms"] < 1.25, "{:?}", d.params);
}

#[test]
fn an_effect_the_final_model_needs_most_is_named_first() {
    // Pair record 67 of the independent seed 3838: a viscous friction and a compliance.
    // Round 0 took the compliance (28 % of the held-out residual), round 1 the viscous
    // friction. Without the viscous friction the final model's fitting residual grows by
    // 1.31, without the compliance by 0.10: the effects are named by what each adds to the
    // final model, not by the round that added them. (Until stop 44 this was the Stribeck
    // friction of seed 2323 case 17 named before the Coulomb friction that round 0 took for
    // it; with secant Jacobians in round 1 that record's Stribeck fit lands in a poorer
    // local minimum and a constant force is taken instead.)
    let (hidden, r) = standard_case(3838, 67);
    assert_eq!(hidden, ["viscous_friction", "compliance"]);
    assert_eq!(
        r.selected,
        ["viscous_friction", "compliance"],
        "{:#?}",
        r.ranking
    );
    let v = ranked(&r, "viscous_friction");
    assert!(v.note.contains("named before compliance"), "{}", v.note);
}

#[test]
fn a_stiff_mount_is_found_by_the_lag_it_adds_to_the_position() {
    // Single-effect record 43 of the independent seed 2323: a payload of 45 % of the table
    // on a 214 Hz mount. The jerk-limited moves hardly excite it: no peak, no ringing, and
    // its force is the payload's mass, which the calibration has. The compliance took 25 %
    // of the held-out position residual and left the force as it was (−0.1 %), and the
    // record was named `none`. It counts by the position (STIFF_MOUNT).
    let r = named_single(2323, 43, "compliance");
    let c = ranked(&r, "compliance");
    assert!(c.note.contains("stiff mount"), "{}", c.note);
}

#[test]
fn a_stiffer_mount_counts_by_a_smaller_lag() {
    // Single-effect record 40 of the independent seed 4242: a payload of 35 % of the table
    // on a 235 Hz mount. The compliance took 7.7 % of the held-out position residual and
    // 2.2 % of the force, below stop 38's 9 %, and the record was named `none`.
    let r = named_single(4242, 40, "compliance");
    let c = ranked(&r, "compliance");
    assert!(c.note.contains("stiff mount"), "{}", c.note);
}

#[test]
fn a_stribeck_friction_is_fitted_with_the_fall_off_the_record_has() {
    // Single-effect records 16 and 18 of the independent seed 4747 hide a breakaway excess
    // that falls off as e^(−|v|/v_s) (18.3 N at 2.55 mm/s, 38.4 N at 3.34 mm/s), record 17
    // one that falls off as e^(−(v/v_s)²) (18.0 N at 0.71 mm/s). A Gaussian fitted to the
    // exponential ones left 3× the fitting residual the exponential leaves, with its excess
    // 24–26 % low; each record now keeps the shape it has, and its figures.
    for (i, exponential, excess_n, v_mm_s) in [
        (16, true, 18.328, 2.546),
        (18, true, 38.378, 3.339),
        (17, false, 18.014, 0.709),
    ] {
        let r = named_single(4747, i, "stribeck_friction");
        let s = ranked(&r, "stribeck_friction");
        assert_eq!(
            s.note.contains("falls off as e^(-|v|/"),
            exponential,
            "case {i}: {}",
            s.note
        );
        let got_n = s.params["breakaway_excess_n"];
        let got_v = s.params["velocity_mm_per_s"];
        assert!(
            (got_n / excess_n - 1.0).abs() < 0.1 && (got_v / v_mm_s - 1.0).abs() < 0.15,
            "case {i}: {got_n:.2} N at {got_v:.3} mm/s, hidden {excess_n} N at {v_mm_s} mm/s"
        );
    }
}

#[test]
fn a_viscous_friction_that_grows_as_a_power_of_the_speed_is_fitted_so() {
    // Two-effect record 68 of the independent seed 5252: a viscous friction of 17.7 N at
    // 100 mm/s growing as |v|^0.57, beside a screw's growth. A linear coefficient took the
    // force (65 % of it held out) but left the position 50 % worse, and a lead error was
    // named in place of both. As a power of the speed it takes both channels, and the
    // growth is found beside it.
    let r = both_selected(5252, 68, &["viscous_friction", "thermal_growth"]);
    let v = ranked(&r, "viscous_friction");
    let f100 = v.params["force_at_100mm_per_s_n"];
    let delta = v.params["exponent"];
    assert!(
        (f100 / 17.728 - 1.0).abs() < 0.2 && (delta - 0.568).abs() < 0.1,
        "{f100:.2} N at 100 mm/s, exponent {delta:.3}; hidden 17.73 N and 0.568"
    );
}

#[test]
fn a_coulomb_friction_that_builds_up_over_a_small_speed_is_fitted_so_and_alone() {
    // Single-effect record 13 of the independent seed 4747: 23.38 N of Coulomb friction
    // built up as tanh(v / 0.815 mm/s). The exact stick/slip law took it with the
    // calibration's viscous ratio on its +8 % bound (the true one is −4.6 %), and once the
    // smooth law was in, a viscous friction of −24 N·s/m "explained" 65 % held out: the
    // calibration undoing itself. Fitted as tanh(v/ε) it takes the level and the speed,
    // and the viscous term that brings the total back within ±8 % of the nominal's is a
    // calibration matter.
    let r = named_single(4747, 13, "coulomb_friction");
    assert_eq!(r.selected, ["coulomb_friction"], "{:#?}", r.ranking);
    let c = ranked(&r, "coulomb_friction");
    let (fc, eps) = (c.params["force_n"], c.params["smoothing_mm_per_s"]);
    assert!(
        (fc / 23.379 - 1.0).abs() < 0.06 && (eps / 0.815 - 1.0).abs() < 0.2,
        "{fc:.2} N over {eps:.3} mm/s; hidden 23.38 N over 0.815 mm/s"
    );
}

#[test]
fn a_coulomb_friction_that_a_stroke_friction_took_first_is_given_back_and_named() {
    // Two-effect record 66 of the fresh seed 6464: 30.2 N more Coulomb friction and a stroke
    // friction (film worn by distance, 33.7 N). The film law, selected first, fitted a
    // recovery of 190 mm: a film that never heals, the Coulomb level held as a rise, and the
    // residual it left had no direction-of-motion term for the Coulomb friction's test. The
    // Coulomb friction beside it keeps the first round's signature and is fitted jointly
    // with the stroke friction, which gives the level back.
    let r = named_pair(6464, 66, ["stroke_friction", "coulomb_friction"]);
    let c = ranked(&r, "coulomb_friction");
    let fc = c.params["force_n"];
    assert!(
        (fc / 30.193 - 1.0).abs() < 0.15,
        "{fc:.2} N of Coulomb friction; hidden 30.19 N"
    );
    // The film it leaves is the hidden one: 33.67 N recovering over 20.02 mm.
    let s = ranked(&r, "stroke_friction");
    let (rise, recovery) = (s.params["rise_n"], s.params["recovery_mm"]);
    assert!(
        (rise / 33.671 - 1.0).abs() < 0.15 && (recovery / 20.022 - 1.0).abs() < 0.2,
        "{rise:.2} N over {recovery:.1} mm; hidden 33.67 N over 20.02 mm"
    );
    assert!(r.shrink > 0.9, "shrink {}", r.shrink);
}

#[test]
fn a_stroke_friction_alone_does_not_give_a_coulomb_level_back() {
    // Single-effect record 27 of the fresh seed 6464: a stroke friction alone. Beside it, on
    // the first round's signature, a 1.4 N Coulomb friction took 1.4 % of the fitting part
    // (and 16 % of the held-out end): no level given back, not counted.
    let r = named_single(6464, 27, "stroke_friction");
    assert_eq!(r.selected, ["stroke_friction"], "{:#?}", r.ranking);
}

#[test]
fn a_delay_the_calibration_read_short_is_read_again_beside_the_friction() {
    // Two-effect record 68 of the fresh seed 6666: a pure command delay of 0.72 samples and
    // an exponential Stribeck friction (36.4 N at 4.3 mm/s). Against the calibrated model,
    // which lacks the friction, position and force lag by 0.14 samples, below the skew
    // floor (0.2), so the delay's signature failed, though it took 91 % of the held-out
    // position residual beside the friction. Read again beside the friction, the lag is
    // 0.86 samples.
    let r = named_pair(6666, 68, ["command_delay", "stribeck_friction"]);
    let d = ranked(&r, "command_delay");
    let lag = d
        .evidence_figures
        .get("lag_samples")
        .copied()
        .unwrap_or(f64::NAN);
    let lag_cal = d
        .evidence_figures
        .get("lag_samples_calibrated")
        .copied()
        .unwrap_or(f64::NAN);
    assert!(
        (0.5..=1.2).contains(&lag) && lag_cal < 0.2,
        "lag {lag:.2} samples beside the friction, {lag_cal:.2} calibrated; true 0.72: {}",
        d.evidence
    );
    let delay_ms = d.params["delay_ms"];
    assert!(
        (0.3..=1.2).contains(&delay_ms),
        "delay {delay_ms:.3} ms; true 0.72 ms"
    );
}

#[test]
fn later_rounds_started_where_the_last_left_off_find_the_payload_from_fewer_replays() {
    // Two-effect record 68 of the independent seed 7070: a viscous friction that differs by
    // direction (75 and 148 N·s/m) and a 38.8 kg payload on a hardening mount of
    // 1.716 N/µm (share 0.418 of the mass, hardening over 18.9 µm). Found in the second
    // round, the payload's fits start where the first round's ended; from the grid, the
    // same round selected the same two effects with a mount of 2.80 N/µm on 0.58 of the
    // mass, as far from the truth as the shrink could not tell.
    use axisbench::indep;
    let spec = indep::standard_set(7070, indep::STANDARD_DURATION_S).swap_remove(68);
    let c = indep::generate(&spec).expect("case generates");
    let hidden: Vec<&str> = c.truth.effects.iter().map(|e| e.name).collect();
    assert_eq!(hidden, ["viscous_friction", "compliance"]);
    let axis = diagnose::pick_axis(&c.trace, "case.csv", &c.preset, None).expect("axis");
    let rec = Record::for_preset(&c.trace, "case.csv", &c.preset, &axis).expect("record");
    let diagnosed = |warm_starts: bool| {
        let opts = Options {
            warm_starts,
            ..Options::default()
        };
        run(&c.preset, &rec, None, &opts)
    };
    let (warm, cold) = (diagnosed(true), diagnosed(false));
    for r in [&warm, &cold] {
        for e in &hidden {
            assert!(
                r.selected.iter().any(|s| s == e),
                "{e} not in {:?}",
                r.selected
            );
        }
    }
    let mount = ranked(&warm, "compliance");
    let k = mount.params["stiffness_n_per_um"];
    let share = mount.params["far_mass_share"];
    assert!(
        (k - 1.716).abs() <= 0.05 * 1.716,
        "stiffness {k} N/um, true 1.716"
    );
    assert!(
        (share - 0.418).abs() <= 0.03,
        "mass share {share}, true 0.418"
    );
    assert!(
        warm.replays < cold.replays,
        "warm starts replayed the record {} times, the grid {}",
        warm.replays,
        cold.replays
    );
}
