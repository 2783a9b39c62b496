//! Load arbitrary text as a RON preset, validate it, build the machine (which adds the
//! closed-loop stability check) and simulate one second, then check what the model promises:
//! a bounded error text or a finite trace of bounded length. Programs resolve against the
//! embedded set, so a fuzzed preset can name any shipped program.
#![no_main]

use axisbench::Machine;
use axisbench::preset::{self, Preset};
use libfuzzer_sys::fuzz_target;

/// Machine time simulated per input, s (the "1 s simulate").
const SIM_S: f64 = 1.0;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let p = match Preset::from_ron(text, "fuzz.ron") {
        Ok(p) => p,
        Err(e) => {
            let shown = e.to_string();
            assert!(shown.chars().count() < 4000, "{} chars", shown.len());
            return;
        }
    };
    let mut programs = Vec::new();
    for f in &p.scenario.programs {
        match preset::embedded(f) {
            Some(t) => programs.push((f.clone(), t.to_owned())),
            None => return,
        }
    }
    let mut m = match Machine::new(&p, &programs) {
        Ok(m) => m,
        Err(e) => {
            let shown = e.to_string();
            assert!(shown.chars().count() < 4000, "{} chars", shown.len());
            return;
        }
    };
    if let Err(e) = m.run(SIM_S) {
        let shown = e.to_string();
        assert!(shown.chars().count() < 4000, "{} chars", shown.len());
        return;
    }
    let n = m.trace.len();
    for s in &m.trace.signals {
        assert_eq!(s.data.len(), n, "{}", s.name);
        // Compensation columns may hold NaN for "not measured"; nothing may be infinite,
        // and the axis's own motion is always a number.
        assert!(s.data.iter().all(|x| !x.is_infinite()), "{} infinite", s.name);
        if [".cmd", ".pos", ".force"].iter().any(|e| s.name.ends_with(e)) {
            assert!(s.data.iter().all(|x| x.is_finite()), "{} not finite", s.name);
        }
    }
});
