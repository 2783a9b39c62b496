//! Read arbitrary bytes as a trace CSV through the same path as files (with the EMPS or the
//! mill mapping when the header looks like one), check what the reader promises, and when
//! it has x.cmd/x.pos lay the record on a T3 grid of bounded length and replay its first
//! samples through the EMPS preset's axis (the diagnosis's replay): the output stays finite
//! or the replay says the model diverged.
#![no_main]

use axisbench::diagnose::replay::{self, MAX_REPLAY_SAMPLES, Model, Record};
use axisbench::preset;
use axisbench::trace::{MAX_TRACE_ROWS, Mapping, Trace};
use libfuzzer_sys::fuzz_target;

const EMPS: &str = "t[s]=t_s, x.cmd[m]=qg_m, x.pos[m]=qm_m, x.force[N]=force_N";
const MILL: &str = "t[s]=t_s, x.cmd[mm]=X1_CommandPosition, x.pos[mm]=X1_ActualPosition, x.vel[mm/s]=X1_ActualVelocity";
/// Longest grid the target builds, samples (a fuzz run must stay fast); longer ones are
/// skipped unless the replay refuses them anyway (past MAX_REPLAY_SAMPLES).
const MAX_FUZZ_GRID: f64 = 100_000.0;
const T3_S: f64 = 0.001;
/// Samples replayed per input.
const REPLAY_SAMPLES: usize = 2000;

fuzz_target!(|data: &[u8]| {
    let head = &data[..data.len().min(4096)];
    let has = |s: &str| head.windows(s.len()).any(|w| w == s.as_bytes());
    let mapping = if has("qg_m") {
        Mapping::parse(EMPS).ok()
    } else if has("X1_ActualPosition") {
        Mapping::parse(MILL).ok()
    } else {
        None
    };
    let trace = match Trace::from_csv_bytes(data, "fuzz.csv", mapping.as_ref()) {
        Ok(t) => t,
        Err(e) => {
            let shown = e.to_string();
            assert!(shown.chars().count() < 4000, "{} chars", shown.len());
            return;
        }
    };
    let n = trace.len();
    assert!((1..=MAX_TRACE_ROWS).contains(&n));
    assert!(trace.signals.iter().all(|s| s.data.len() == n));
    let t = trace.t();
    assert!(t.iter().all(|x| x.is_finite()));
    assert!(t.windows(2).all(|w| w[1] > w[0]));
    for s in &trace.signals {
        assert!(s.data.iter().all(|x| !x.is_infinite()), "{}", s.name);
    }
    if trace.signal("x.cmd").is_none() || trace.signal("x.pos").is_none() {
        return;
    }
    let samples = ((t[n - 1] - t[0]) / T3_S).floor() + 1.0;
    if samples > MAX_FUZZ_GRID && samples <= MAX_REPLAY_SAMPLES as f64 + 1.0 {
        return;
    }
    if let Ok(r) = Record::from_trace(&trace, "fuzz.csv", "x", None, T3_S) {
        assert!(r.len() <= MAX_REPLAY_SAMPLES);
        assert!(r.cmd_m.iter().chain(&r.pos_m).all(|x| x.is_finite()));
        let Ok(lp) = preset::load_embedded("emps.ron") else {
            return;
        };
        let p = &lp.preset;
        let model = Model {
            axis: p.axes[0].clone(),
            t3_s: T3_S,
            t2_s: T3_S,
            t1_s: T3_S,
            pos_source: r.pos_source.unwrap_or(p.diagnose.pos_source),
            delay_s: 0.0,
            disturbance: vec![],
            beam: None,
        };
        let n = r.len().min(REPLAY_SAMPLES);
        let out = replay::simulate(&model, &r, n);
        assert!(out.pos_m.len() <= n && out.force_n.len() == out.pos_m.len());
        assert!(
            out.pos_m.iter().chain(&out.force_n).all(|x| !x.is_nan()),
            "NaN in the replay"
        );
    }
});
