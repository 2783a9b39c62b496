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
        pos_source: rec.pos_source.unwrap_or(p.diagnose.pos_source),
        delay_s: 0.0,
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
