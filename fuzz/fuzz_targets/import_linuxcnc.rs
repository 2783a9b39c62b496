//! LinuxCNC import (INI + comp files) on arbitrary input, through the same function the
//! command line uses after reading the files (`export::linuxcnc::import_text`).
//!
//! Input: the INI text, then the comp files separated by NUL bytes; the k-th comp file is
//! named `joint<k>.comp` (what an export writes, so the seeds reach the comp reader). The
//! base preset is the 4-axis vertical lathe when the INI has at least four `[JOINT_`
//! sections, else the 1-axis default.
//!
//! Properties: the import never panics; whatever it accepts passes `machine::check` and a
//! machine built from it runs (the bug this guards against: a MAX_ACCELERATION of 1e-300
//! imported, and the simulation then died allocating its acc/dec filter).
#![no_main]

use std::sync::OnceLock;

use axisbench::Machine;
use axisbench::export::linuxcnc::import_text;
use axisbench::preset::{LoadedPreset, load_embedded};
use libfuzzer_sys::fuzz_target;

/// (base preset, its programs) for the 1-axis and the 4-axis case, loaded once.
fn bases() -> &'static [(LoadedPreset, Vec<(String, String)>); 2] {
    static B: OnceLock<[(LoadedPreset, Vec<(String, String)>); 2]> = OnceLock::new();
    B.get_or_init(|| {
        ["default.ron", "vertical_lathe_crossbeam.ron"].map(|n| {
            let lp = load_embedded(n).expect("shipped preset");
            let progs = lp
                .preset
                .scenario
                .programs
                .iter()
                .map(|p| (p.clone(), lp.program_text(p).expect("program")))
                .collect();
            (lp, progs)
        })
    })
}

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let mut parts = text.split('\0');
    let ini = parts.next().unwrap_or("");
    let comps: Vec<(String, String)> = parts
        .enumerate()
        .map(|(k, t)| (format!("joint{k}.comp"), t.to_owned()))
        .collect();
    let (base, programs) = &bases()[usize::from(ini.matches("[JOINT_").count() >= 4)];
    if let Ok(p) = import_text("linuxcnc.ini", ini, &comps, &base.preset) {
        assert!(
            axisbench::machine::check(&p).is_empty(),
            "an accepted import must pass the machine check"
        );
        let mut m = Machine::new(&p, programs).expect("an accepted preset builds");
        m.set_recording(false);
        for _ in 0..200 {
            m.step();
        }
    }
});
