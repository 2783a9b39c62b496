//! The library's modules import only down the machine's flow: preset (data) → nc → comp →
//! servo → plant → drive → trace → machine, with measuring cycles, diagnosis, export and
//! benchmarks on top. This test reads every `crate::…` path in `src/` (comments excluded)
//! and fails on an import against the flow, between two top-layer modules, or in a cycle.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Each library module's layer, lowest first. A module may use only modules of a lower
/// layer; ARCHITECTURE.md draws the same graph.
const LAYERS: &[(&str, u32)] = &[
    ("units", 0),
    ("table", 0),
    ("fsutil", 0),
    ("signal", 0),
    ("preset", 1),
    ("nc", 2),
    ("comp", 3),
    ("servo", 4),
    ("plant", 5),
    ("drive", 6),
    ("trace", 7),
    ("machine", 8),
    ("measure", 9),
    ("analysis", 9),
    ("bench", 9),
    ("diagnose", 9),
    ("export", 9),
    ("indep", 9),
    ("evaluation", 10),
    ("tune", 10),
];

/// Macros exported at the crate root, and the module that defines them.
const MACROS: &[(&str, &str)] = &[("choice_enum", "preset")];

/// Removes `//` comments (doc comments included: a doc link is not an import).
fn strip_comments(src: &str) -> String {
    src.lines()
        .map(|l| match l.find("//") {
            Some(i) if !l[..i].contains('"') => &l[..i],
            _ => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn rust_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).expect("src readable") {
        let p = e.expect("entry").path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// module → the crate modules its files name.
fn imports() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = vec![];
    rust_files(&src, &mut files);
    let mut out: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for f in files {
        let rel = f.strip_prefix(&src).expect("under src");
        let first = rel
            .components()
            .next()
            .and_then(|c| c.as_os_str().to_str())
            .unwrap_or("")
            .trim_end_matches(".rs")
            .to_owned();
        // The binary's layers (command line, workbench) sit on top of everything.
        if ["main", "lib", "cli", "app"].contains(&first.as_str()) {
            continue;
        }
        let text = strip_comments(&std::fs::read_to_string(&f).expect("readable"));
        let deps = out.entry(first.clone()).or_default();
        for (i, _) in text.match_indices("crate::") {
            let name: String = text[i + 7..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            let module = MACROS
                .iter()
                .find(|(m, _)| *m == name)
                .map_or(name.clone(), |(_, owner)| (*owner).to_owned());
            if module != first {
                deps.insert(module);
            }
        }
    }
    out
}

#[test]
fn modules_import_only_down_the_flow() {
    let layer: BTreeMap<&str, u32> = LAYERS.iter().copied().collect();
    let graph = imports();
    let mut problems = vec![];
    for (m, deps) in &graph {
        let Some(&lm) = layer.get(m.as_str()) else {
            problems.push(format!(
                "module '{m}' has no layer in LAYERS (and ARCHITECTURE.md)"
            ));
            continue;
        };
        for d in deps {
            match layer.get(d.as_str()) {
                None => problems.push(format!("{m} uses '{d}', which has no layer")),
                Some(&ld) if ld >= lm => problems.push(format!(
                    "{m} (layer {lm}) uses {d} (layer {ld}): against the flow"
                )),
                Some(_) => {}
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    // Strictly lower layers cannot form a cycle; check the graph anyway, so that a change
    // to LAYERS cannot hide one.
    for start in graph.keys() {
        let mut stack = vec![start.clone()];
        let mut seen = BTreeSet::new();
        while let Some(m) = stack.pop() {
            for d in graph.get(&m).into_iter().flatten() {
                assert_ne!(d, start, "cycle through {start}");
                if seen.insert(d.clone()) {
                    stack.push(d.clone());
                }
            }
        }
    }
}

#[test]
fn the_flow_check_catches_an_upward_import() {
    // The parser the check relies on sees a use that a comment does not hide.
    let text =
        strip_comments("use crate::machine::Machine; // crate::app\n/// [`crate::diagnose`]\n");
    assert!(text.contains("crate::machine"));
    assert!(!text.contains("crate::app"));
    assert!(!text.contains("crate::diagnose"));
    // And the layers put plant above servo: plant may not be imported by servo.
    let layer: BTreeMap<&str, u32> = LAYERS.iter().copied().collect();
    assert!(layer["servo"] < layer["plant"] && layer["plant"] < layer["drive"]);
    assert!(layer["preset"] < layer["comp"] && layer["machine"] < layer["measure"]);
}
