//! The LinuxCNC import on the fuzz target's inputs (`fuzz/fuzz_targets/import_linuxcnc.rs`):
//! its seeds and every input the fuzzer found a crash with (`fuzz/regressions/`), under the
//! same properties — the import never panics, and whatever it accepts passes
//! `machine::check` and a machine built from it runs.
//!
//! Input format as in the fuzz target: the INI text, then comp files separated by NUL
//! bytes, the k-th named `joint<k>.comp`; the base is the 4-axis vertical lathe when the INI
//! has at least four `[JOINT_` sections, else the default preset.

use std::path::{Path, PathBuf};

use axisbench::Machine;
use axisbench::export::linuxcnc::import_text;
use axisbench::preset::load_embedded;

/// Runs one input; true when the import accepted it.
fn check(data: &[u8]) -> bool {
    let text = String::from_utf8_lossy(data);
    let mut parts = text.split('\0');
    let ini = parts.next().unwrap_or("");
    let comps: Vec<(String, String)> = parts
        .enumerate()
        .map(|(k, t)| (format!("joint{k}.comp"), t.to_owned()))
        .collect();
    let name = if ini.matches("[JOINT_").count() >= 4 {
        "vertical_lathe_crossbeam.ron"
    } else {
        "default.ron"
    };
    let base = load_embedded(name).expect("shipped preset");
    let programs: Vec<(String, String)> = base
        .preset
        .scenario
        .programs
        .iter()
        .map(|p| (p.clone(), base.program_text(p).expect("program")))
        .collect();
    match import_text("linuxcnc.ini", ini, &comps, &base.preset) {
        Ok(p) => {
            assert!(
                axisbench::machine::check(&p).is_empty(),
                "accepted but invalid"
            );
            let mut m = Machine::new(&p, &programs).expect("an accepted preset builds");
            m.set_recording(false);
            for _ in 0..200 {
                m.step();
            }
            assert!(m.axes.iter().all(|a| a.pos_m.is_finite()));
            true
        }
        Err(e) => {
            assert!(!e.to_string().is_empty());
            false
        }
    }
}

fn inputs(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| rd.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

#[test]
fn fuzz_seeds_and_found_crashes_keep_the_import_properties() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    // AXISBENCH_FUZZ_CORPUS=<dir> runs a whole corpus the same way (not in CI).
    let extra = std::env::var_os("AXISBENCH_FUZZ_CORPUS").map(PathBuf::from);
    let mut files = inputs(&root.join("seeds/import_linuxcnc"));
    let seeds = files.len();
    files.extend(inputs(&root.join("regressions/import_linuxcnc")));
    if let Some(d) = &extra {
        files.extend(inputs(d));
    }
    assert!(seeds >= 5, "the seeds are missing: {}", root.display());
    let mut accepted = 0;
    for f in &files {
        let data = std::fs::read(f).expect("input");
        if check(&data) {
            accepted += 1;
        }
    }
    println!("{} inputs, {accepted} accepted", files.len());
    // The exported seeds import; the broken ones (1e-300 acceleration, NaN trim) do not.
    assert!(
        accepted >= 4 && accepted < files.len(),
        "{accepted} of {}",
        files.len()
    );
}
