//! The model replays its own traces: simulate a preset, read the trace back as a measured
//! record, replay it through the diagnosis, and the two must agree. Any difference here is a
//! second copy of the model that has drifted from the first.

use axisbench::diagnose::replay::{self, Model, Record};
use axisbench::preset::{self, Preset};
use axisbench::{Machine, Trace};

/// Simulates `p` (every T3 sample traced, at most `max_s` of machine time) and reads the
/// trace back through the CSV text, as a user's `simulate --out` then `diagnose` would.
fn simulate_trace(p: &Preset, programs: &[(String, String)], max_s: f64) -> Trace {
    let mut q = p.clone();
    q.scenario.trace_every = 1;
    let mut m = Machine::new(&q, programs).expect("machine builds");
    m.run(max_s).unwrap();
    let mut csv = Vec::new();
    m.trace.write_csv_to(&mut csv).expect("writes");
    Trace::from_csv_str(&String::from_utf8(csv).expect("utf8"), "self.csv", None).expect("reads")
}

/// Residual of replaying axis `axis` of `tr` through `p`: (position rms µm, force rms N,
/// first sample where |Δpos| > 1 nm or |Δforce| > 0.1 N).
fn replay_residual(p: &Preset, tr: &Trace, axis: &str) -> (f64, f64, Option<usize>) {
    let rec = Record::for_preset(tr, "self.csv", p, axis).expect("record");
    let a = p
        .axes
        .iter()
        .find(|a| a.name == axis)
        .expect("axis")
        .clone();
    let model = Model {
        axis: a,
        t3_s: p.timing.t3_s,
        t2_s: p.timing.t2_s,
        t1_s: p.timing.t1_s,
        pos_source: rec.pos_source.unwrap_or(p.diagnose.pos_source),
        delay_s: 0.0,
        lag_s: 0.0,
        pos_interval_m: 0.0,
        disturbance: vec![],
        beam: replay::BeamModel::of(p, axis),
    };
    let sim = replay::simulate(&model, &rec, rec.len());
    let force = rec.force_n.as_ref().expect("force column");
    let mut first = None;
    let (mut sp, mut sf) = (0.0, 0.0);
    #[allow(clippy::needless_range_loop)]
    for k in 0..rec.len() {
        let dp = rec.pos_m[k] - sim.pos_m[k];
        let df = force[k] - sim.force_n[k];
        sp += dp * dp;
        sf += df * df;
        if first.is_none() && (dp.abs() > 1e-9 || df.abs() > 0.1) {
            first = Some(k);
        }
    }
    let n = rec.len() as f64;
    ((sp / n).sqrt() * 1e6, (sf / n).sqrt(), first)
}

fn programs(lp: &preset::LoadedPreset) -> Vec<(String, String)> {
    lp.preset
        .scenario
        .programs
        .iter()
        .map(|f| (f.clone(), lp.program_text(f).expect("program")))
        .collect()
}

/// Issue 11's bar for the model replaying its own trace.
const POS_TOL_UM: f64 = 0.02;
const FORCE_TOL_N: f64 = 0.5;

#[test]
fn every_shipped_preset_replays_its_own_trace() {
    let mut report = Vec::new();
    let mut worst = Vec::new();
    for name in preset::SHIPPED_PRESETS {
        let lp = preset::load_embedded(name).expect("embedded preset");
        let tr = simulate_trace(&lp.preset, &programs(&lp), 6.0);
        for a in &lp.preset.axes {
            let (pos_um, force_n, first) = replay_residual(&lp.preset, &tr, &a.name);
            report.push(format!(
                "{name} {}: pos {pos_um:.3e} µm, force {force_n:.3e} N, first divergence {first:?}",
                a.name
            ));
            worst.push((pos_um, force_n));
        }
    }
    println!("{}", report.join("\n"));
    let bad: Vec<&String> = report
        .iter()
        .zip(&worst)
        .filter(|&(_, &(p, f))| p > POS_TOL_UM || f > FORCE_TOL_N)
        .map(|(r, _)| r)
        .collect();
    assert!(
        bad.is_empty(),
        "self-replay residual above {POS_TOL_UM} µm / {FORCE_TOL_N} N:\n{}",
        bad.iter()
            .map(|s| s.as_str())
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// Runs the diagnosis, quietly, on `rec` against `p`.
fn diagnose_quietly(p: &Preset, rec: &Record) -> axisbench::diagnose::Report {
    use axisbench::diagnose::{self, Options, Progress};
    let cancel = std::sync::atomic::AtomicBool::new(false);
    let quiet = |_: f64, _: &str| {};
    let progress = Progress {
        report: &quiet,
        cancel: &cancel,
    };
    diagnose::diagnose(p, rec, None, &Options::default(), &progress).expect("diagnosis runs")
}

#[test]
fn the_diagnosis_finds_nothing_missing_in_the_models_own_traces() {
    let mut found = Vec::new();
    for name in preset::SHIPPED_PRESETS {
        let lp = preset::load_embedded(name).expect("embedded preset");
        // The diagnosis replays its sensors unrounded (their rounding is the record's
        // noise): recorded so, its own trace is the replay exactly.
        let mut unrounded = lp.preset.clone();
        for a in &mut unrounded.axes {
            a.encoder.quantize_motor = false;
            a.encoder.quantize_scale = false;
        }
        let p = &unrounded;
        let tr = simulate_trace(p, &programs(&lp), 3.0);
        let axis = &p.axes[0].name;
        let rec = Record::for_preset(&tr, "self.csv", p, axis).expect("record");
        let r = diagnose_quietly(p, &rec);
        if r.verdict != "none" {
            found.push(format!(
                "{name} {axis}: verdict {} ({:?})",
                r.verdict, r.selected
            ));
        }
    }
    assert!(found.is_empty(), "{}", found.join("\n"));
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(32))]

    /// Random periods (T3, T2 = n23·T3, T1 = n12·T2) and gains: as long as the loop is
    /// stable (the machine refuses it otherwise), replaying the trace reproduces it.
    #[test]
    fn random_periods_and_gains_replay_exactly(
        t3_exp in 0u32..4,
        n23 in proptest::sample::select(vec![1u32, 2, 4, 8]),
        n12 in proptest::sample::select(vec![1u32, 2, 4]),
        kp_per_s in 15.0f64..80.0,
        kv_scale in 0.5f64..1.5,
        ki_per_s in 0.0f64..200.0,
    ) {
        let lp = preset::load_embedded("default.ron").expect("default");
        let mut p = lp.preset.clone();
        p.timing.t3_s = 0.000125 * f64::from(1u32 << t3_exp);
        p.timing.t2_s = p.timing.t3_s * f64::from(n23);
        p.timing.t1_s = p.timing.t2_s * f64::from(n12);
        let s = &mut p.axes[0].servo;
        s.kp_per_s = kp_per_s;
        s.kv_n_s_per_m *= kv_scale;
        s.ki_per_s = ki_per_s;
        let mut q = p.clone();
        q.scenario.trace_every = 1;
        let Ok(mut m) = Machine::new(&q, &programs(&lp)) else {
            // Unstable or otherwise refused: nothing to replay.
            return Ok(());
        };
        m.run(3.0).expect("runs");
        let mut csv = Vec::new();
        m.trace.write_csv_to(&mut csv).expect("writes");
        let tr = Trace::from_csv_str(&String::from_utf8(csv).expect("utf8"), "self.csv", None)
            .expect("reads");
        let (pos_um, force_n, first) = replay_residual(&p, &tr, "x");
        proptest::prop_assert!(
            pos_um <= POS_TOL_UM && force_n <= FORCE_TOL_N,
            "pos {pos_um} µm, force {force_n} N, first divergence {first:?}"
        );
    }
}
