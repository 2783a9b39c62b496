//! Bounded resources: replay grids sized before they are allocated, and the regressions the
//! fuzz targets (fuzz/) found in the program and trace readers.

use std::time::Instant;

use axisbench::diagnose::replay::{MAX_REPLAY_SAMPLES, Record};
use axisbench::trace::{Signal, Trace};

fn trace_with_times(t: Vec<f64>) -> Trace {
    let n = t.len();
    let sig = |name: &str, unit: &str, data: Vec<f64>| Signal {
        name: name.into(),
        unit: unit.into(),
        data,
    };
    Trace {
        meta: vec![],
        signals: vec![
            sig("t", "s", t),
            sig("x.cmd", "m", vec![0.0; n]),
            sig("x.pos", "m", vec![0.0; n]),
        ],
    }
}

fn replay_err(t: Vec<f64>, t3_s: f64) -> String {
    let tr = trace_with_times(t);
    match Record::from_trace(&tr, "r.csv", "x", None, t3_s) {
        Ok(r) => panic!("accepted a grid of {} samples", r.len()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn one_wild_time_stamp_is_refused_before_resampling() {
    // 1000 samples at 1 ms and a last time stamp of 1e17 s: 1e21 periods of 100 µs. This
    // used to allocate a 40 M-sample grid (8 GB) or wrap to 0 samples.
    let mut t: Vec<f64> = (0..1000).map(|i| i as f64 * 0.001).collect();
    t[999] = 1e17;
    let start = Instant::now();
    let e = replay_err(t, 1e-4);
    assert!(
        start.elapsed().as_secs_f64() < 1.0,
        "took {:?}",
        start.elapsed()
    );
    assert!(
        e.starts_with("r.csv: spans 100000000000000000.000000 s"),
        "{e}"
    );
    assert!(
        e.contains("1000000000000000000000 periods of T3 = 0.0001 s")
            && e.contains(&format!("the limit is {MAX_REPLAY_SAMPLES} samples"))
            && e.contains("cut the record to at most 1000.0 s")
            && e.contains("the largest step is 100000000000000000 s, at data row 1000"),
        "{e}"
    );
}

#[test]
fn grid_size_is_checked_at_the_limit_and_for_non_finite_spans() {
    // MAX_REPLAY_SAMPLES + 1 samples: refused, and nothing allocated for it.
    let t3 = 0.001;
    let span = MAX_REPLAY_SAMPLES as f64 * t3;
    let t: Vec<f64> = (0..10).map(|i| span * i as f64 / 9.0).collect();
    let e = replay_err(t, t3);
    assert!(
        e.contains(&format!("{} periods", MAX_REPLAY_SAMPLES + 1)),
        "{e}"
    );
    // A span past f64: no grid at all (this used to wrap to "0 samples").
    let mut t: Vec<f64> = (0..10).map(|i| i as f64).collect();
    t[0] = -f64::MAX;
    t[9] = f64::MAX;
    let e = replay_err(t, 1e-3);
    assert!(e.contains("which makes no grid of T3 = 0.001 s"), "{e}");
    let e = replay_err((0..10).map(|i| i as f64).collect(), 0.0);
    assert!(e.contains("T3 = 0 s must be a positive time"), "{e}");
    // A modest non-uniform record is resampled to floor(span / T3) + 1 samples.
    let t: Vec<f64> = (0..100).map(|i| i as f64 * 0.0007).collect();
    let tr = trace_with_times(t);
    let r = Record::from_trace(&tr, "r.csv", "x", None, 0.001).expect("resampled");
    assert!(r.resampled);
    assert_eq!(r.len(), 70);
}

/// The files of one fuzz corpus (fuzz/corpus/<target>/), committed minimized.
fn corpus(target: &str) -> Vec<(String, Vec<u8>)> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/corpus")
        .join(target);
    let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| {
            let path = e.expect("dir entry").path();
            let bytes = std::fs::read(&path).expect("corpus file");
            (path.display().to_string(), bytes)
        })
        .collect();
    files.sort();
    assert!(
        files.len() > 10,
        "{} has {} files",
        dir.display(),
        files.len()
    );
    files
}

/// Every input of the gcode fuzz corpus, through the checks of fuzz/fuzz_targets/gcode.rs.
#[test]
fn gcode_fuzz_corpus_replays_clean() {
    use axisbench::nc::program::{self, MAX_BLOCK_TIME_S, MAX_COORD_MM, Op};
    let bound_m = axisbench::units::mm_to_m(MAX_COORD_MM);
    let (mut ok, mut refused) = (0, 0);
    for (name, bytes) in corpus("gcode") {
        let Ok(text) = std::str::from_utf8(&bytes) else {
            continue;
        };
        let result = program::parse(text, "fuzz.ngc").and_then(|blocks| {
            program::compile(&blocks, &['X', 'Y', 'Z'], &[0.0; 3], 1000.0, 10000.0, "f")
        });
        match result {
            Err(e) => {
                refused += 1;
                assert!(e.to_string().chars().count() < 4000, "{name}");
                assert!(e.line >= 1 && e.col >= 1, "{name}: {e}");
            }
            Ok(ops) => {
                ok += 1;
                for op in &ops {
                    if let Op::Move {
                        end_m,
                        feed_mps,
                        length_m,
                        ..
                    } = op
                    {
                        assert!(end_m.iter().all(|x| x.abs() <= bound_m), "{name}: {op:?}");
                        assert!(*feed_mps > 0.0 && length_m / feed_mps <= MAX_BLOCK_TIME_S);
                    }
                }
            }
        }
    }
    assert!(ok > 10 && refused > 10, "{ok} accepted, {refused} refused");
}

/// Every input of the trace_csv fuzz corpus, through the checks of
/// fuzz/fuzz_targets/trace_csv.rs.
#[test]
fn trace_csv_fuzz_corpus_replays_clean() {
    use axisbench::trace::Mapping;
    let emps = Mapping::parse("t[s]=t_s, x.cmd[m]=qg_m, x.pos[m]=qm_m, x.force[N]=force_N")
        .expect("mapping");
    let (mut ok, mut refused) = (0, 0);
    for (name, bytes) in corpus("trace_csv") {
        let head = &bytes[..bytes.len().min(4096)];
        let mapping = head.windows(4).any(|w| w == b"qg_m").then_some(&emps);
        match Trace::from_csv_bytes(&bytes, "fuzz.csv", mapping) {
            Err(e) => {
                refused += 1;
                assert!(e.to_string().chars().count() < 4000, "{name}");
            }
            Ok(tr) => {
                ok += 1;
                let t = tr.t();
                assert!(tr.signals.iter().all(|s| s.data.len() == t.len()), "{name}");
                assert!(t.windows(2).all(|w| w[1] > w[0]), "{name}");
                let samples = (t[t.len() - 1] - t[0]) / 0.001;
                if tr.signal("x.cmd").is_some()
                    && samples < 100_000.0
                    && let Ok(r) = Record::from_trace(&tr, "fuzz.csv", "x", None, 0.001)
                {
                    assert!(r.cmd_m.iter().chain(&r.pos_m).all(|x| x.is_finite()));
                }
            }
        }
    }
    assert!(ok > 10 && refused > 10, "{ok} accepted, {refused} refused");
}

/// Every input of the preset fuzz corpus, through the checks of fuzz/fuzz_targets/preset.rs:
/// refused with a short message, or built and run for 1 s with finite motion.
#[test]
fn preset_fuzz_corpus_replays_clean() {
    use axisbench::Machine;
    use axisbench::preset::{self, Preset};
    let (mut ran, mut refused) = (0, 0);
    for (name, bytes) in corpus("preset") {
        let Ok(text) = std::str::from_utf8(&bytes) else {
            continue;
        };
        let p = match Preset::from_ron(text, "fuzz.ron") {
            Ok(p) => p,
            Err(e) => {
                refused += 1;
                assert!(e.to_string().chars().count() < 4000, "{name}");
                continue;
            }
        };
        let Some(programs) = p
            .scenario
            .programs
            .iter()
            .map(|f| preset::embedded(f).map(|t| (f.clone(), t.to_owned())))
            .collect::<Option<Vec<_>>>()
        else {
            continue;
        };
        let mut m = match Machine::new(&p, &programs) {
            Ok(m) => m,
            Err(e) => {
                refused += 1;
                assert!(e.to_string().chars().count() < 4000, "{name}");
                continue;
            }
        };
        match m.run(1.0) {
            Err(e) => assert!(e.to_string().chars().count() < 4000, "{name}"),
            Ok(()) => {
                ran += 1;
                for s in &m.trace.signals {
                    assert!(
                        s.data.iter().all(|x| !x.is_infinite()),
                        "{name}: {}",
                        s.name
                    );
                    if [".cmd", ".pos", ".force"]
                        .iter()
                        .any(|e| s.name.ends_with(e))
                    {
                        assert!(s.data.iter().all(|x| x.is_finite()), "{name}: {}", s.name);
                    }
                }
            }
        }
    }
    // The seeds are the shipped presets, which all run.
    assert!(ran >= 7 && refused > 0, "ran {ran}, refused {refused}");
}

/// A record the trace fuzzer found (fuzz/regressions/trace_csv/): a motor position of
/// 1.43e305 m read fine and made the replay integrate to NaN. It is refused now, naming the
/// column and row; and a record within range replays to finite numbers.
#[test]
fn a_record_with_an_absurd_position_is_refused_before_the_replay() {
    use axisbench::diagnose::replay::Record;
    use axisbench::trace::{Mapping, Trace};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/regressions/trace_csv/crash-5abdf849555c17f184472b9a97b17b30448081bc");
    let bytes = std::fs::read(&path).expect("regression input");
    let mapping =
        Mapping::parse("t[s]=t_s, x.cmd[m]=qg_m, x.pos[m]=qm_m, x.force[N]=force_N").expect("map");
    let tr = Trace::from_csv_bytes(&bytes, "crash.csv", Some(&mapping)).expect("reads");
    let e = Record::from_trace(&tr, "crash.csv", "x", None, 0.001)
        .expect_err("an axis 1e305 m long is refused")
        .to_string();
    assert!(
        e.contains("x.") && e.contains("row") && e.contains("beyond"),
        "{e}"
    );
}
