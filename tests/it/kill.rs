//! Saves and exports survive being killed at any point.
//!
//! Each scenario runs the real binary as a child process (an export to LinuxCNC, a trace
//! CSV save, an import that writes a preset and its program) over a folder holding an older
//! version, kills it with SIGKILL after a random delay, then does what the next run does
//! first (`fsutil::clean_stale`) and checks the folder: it must hold exactly the old files
//! or exactly the new ones, byte for byte, and nothing else. The delays are spread over the
//! whole run (start-up, simulation, writing), measured beforehand; how many kills left
//! temporaries behind (i.e. landed while writing) is counted and must not be zero, so the
//! test cannot pass by only killing before or after the write. A multi-file commit's renames
//! are microseconds apart, so every other kill of the export and the import is aimed: the
//! child runs with `AXISBENCH_TEST_COMMIT_PAUSE_MS` (a pause after each rename) and is
//! killed the moment its first file is in place, leaving some files new and some old until
//! the next run rolls the commit back.

use std::collections::BTreeMap;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Every entry of `dir`: name → bytes (None for a folder).
type Snapshot = BTreeMap<String, Option<Vec<u8>>>;

fn snapshot(dir: &Path) -> Snapshot {
    std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .map(|e| {
                    (
                        e.file_name().to_string_lossy().into_owned(),
                        std::fs::read(e.path()).ok(),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

/// Makes `dir` hold exactly `s`.
fn restore(dir: &Path, s: &Snapshot) {
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir).expect("dir");
    for (name, bytes) in s {
        let p = dir.join(name);
        match bytes {
            Some(b) => std::fs::write(&p, b).expect("file"),
            None => std::fs::create_dir_all(&p).expect("folder"),
        }
    }
}

/// xorshift64*: reproducible from the printed seed, no dependency.
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn bin(args: &[OsString]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_axisbench"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    c
}

/// Runs to the end; returns how long it took.
fn run(args: &[OsString]) -> Duration {
    let t0 = Instant::now();
    let o = bin(args).output().expect("runs");
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    t0.elapsed()
}

fn is_temporary(name: &str) -> bool {
    name.starts_with(".axisbench-export.") || (name.contains(".axb") && name.ends_with(".tmp"))
}

/// One command writing into `dir`, and the folder before and after it.
struct Scenario {
    name: &'static str,
    dir: PathBuf,
    args: Vec<OsString>,
    old: Snapshot,
    new: Snapshot,
    /// How long an undisturbed run takes.
    duration: Duration,
    /// For multi-file writes: a file the commit replaces (or creates) first; some kills
    /// come the moment its identity (inode) changes, i.e. inside the commit.
    trigger: Option<String>,
}

/// Outcomes of a scenario's kills.
#[derive(Default, Debug)]
struct Tally {
    old: usize,
    new: usize,
    /// Kills that left temporaries (they landed while writing).
    temporaries: usize,
    /// Kills that left some files new and some old until the next run rolled them back.
    mixed: usize,
}

fn inode(p: &Path) -> Option<u64> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(p).ok().map(|m| m.ino())
}

impl Scenario {
    /// `setup` writes the old state into `dir`; `args` is the command under test.
    fn new(name: &'static str, dir: PathBuf, setup: impl Fn(&Path), args: Vec<OsString>) -> Self {
        std::fs::create_dir_all(&dir).expect("dir");
        setup(&dir);
        let old = snapshot(&dir);
        let mut runs: Vec<Duration> = (0..3)
            .map(|_| {
                restore(&dir, &old);
                run(&args)
            })
            .collect();
        runs.sort();
        let new = snapshot(&dir);
        assert_ne!(old, new, "{name}: the command must change the folder");
        Scenario {
            name,
            dir,
            args,
            old,
            new,
            duration: runs[1],
            trigger: None,
        }
    }

    /// Kill also the moment `file` appears or is replaced (the commit's first rename).
    fn triggered_by(mut self, file: &str) -> Self {
        self.trigger = Some(file.to_owned());
        self
    }

    /// Kills the command `n` times: at random points, and (every other time, when the
    /// scenario has a trigger) the moment its commit has begun.
    fn kill_test(&self, n: usize, rng: &mut Rng, seed: u64) -> Tally {
        let mut t = Tally::default();
        for k in 0..n {
            restore(&self.dir, &self.old);
            let watch = self
                .trigger
                .as_ref()
                .filter(|_| k % 2 == 1)
                .map(|f| self.dir.join(f));
            let delay = self.duration.mul_f64(1.2 * rng.unit());
            let mut cmd = bin(&self.args);
            if watch.is_some() {
                // Widen the window between two renames so the kill can land inside it.
                cmd.env("AXISBENCH_TEST_COMMIT_PAUSE_MS", "3");
            }
            let mut child = cmd.spawn().expect("spawns");
            match watch {
                Some(file) => {
                    let before = inode(&file);
                    let t0 = Instant::now();
                    while inode(&file) == before && t0.elapsed() < self.duration * 20 {
                        if let Ok(Some(_)) = child.try_wait() {
                            break;
                        }
                    }
                }
                None => std::thread::sleep(delay),
            }
            let _ = child.kill(); // SIGKILL; an error only means it had already exited
            let _ = child.wait();
            let left = snapshot(&self.dir);
            if left.keys().any(|n| is_temporary(n)) {
                t.temporaries += 1;
            }
            let visible: Snapshot = left
                .iter()
                .filter(|(n, _)| !is_temporary(n))
                .map(|(n, b)| (n.clone(), b.clone()))
                .collect();
            if visible != self.old && visible != self.new {
                t.mixed += 1;
            }

            // What the next run does first.
            axisbench::fsutil::clean_stale(&self.dir);
            let after = snapshot(&self.dir);
            if after == self.old {
                t.old += 1;
            } else if after == self.new {
                t.new += 1;
            } else {
                panic!(
                    "{} kill {k} (seed {seed}): the folder is neither the old nor the new state: {:?} (before cleaning: {:?})",
                    self.name,
                    after.keys().collect::<Vec<_>>(),
                    left.keys().collect::<Vec<_>>()
                );
            }
        }
        t
    }
}

fn os(v: &[&str]) -> Vec<OsString> {
    v.iter().map(OsString::from).collect()
}

#[test]
#[allow(clippy::too_many_lines)] // one scenario table, read top to bottom
fn a_killed_save_export_or_import_leaves_the_old_or_the_new_files() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let root = tmp.path();
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(1, |d| d.as_nanos() as u64)
        | 1;
    let mut rng = Rng(seed);
    let t0 = Instant::now();

    // 1. A LinuxCNC export over an older one: the new one has a comp file the old lacks.
    let ex_dir = root.join("export");
    let mut ex_args = os(&[
        "export",
        "--preset",
        "presets/default.ron",
        "--to",
        "linuxcnc",
        "--horizon",
        "0.5",
        "--set",
        "axes.x.lead_error.enabled=true",
        "--set",
        "axes.x.backlash.q_um=11",
        "--out",
    ]);
    ex_args.push(ex_dir.clone().into_os_string());
    let ex_old = {
        let mut a = os(&[
            "export",
            "--preset",
            "presets/default.ron",
            "--to",
            "linuxcnc",
            "--horizon",
            "0.5",
            "--out",
        ]);
        a.push(ex_dir.clone().into_os_string());
        a
    };
    let export = Scenario::new(
        "export",
        ex_dir.clone(),
        |_| {
            run(&ex_old);
        },
        ex_args,
    )
    .triggered_by("linuxcnc.ini");
    assert!(export.new.contains_key("joint0.comp") && !export.old.contains_key("joint0.comp"));

    // 2. A trace CSV (25 MB) over a shorter one.
    let sim_dir = root.join("simulate");
    let csv = sim_dir.join("big.csv");
    let sim = |duration: Option<&str>| {
        let mut a = os(&["simulate", "--preset", "presets/default.ron"]);
        if let Some(d) = duration {
            a.extend(os(&["--duration", d]));
        }
        a.push("--out".into());
        a.push(csv.clone().into_os_string());
        a
    };
    let old_sim = sim(Some("0.2"));
    let simulate = Scenario::new(
        "simulate --out",
        sim_dir,
        |_| {
            run(&old_sim);
        },
        sim(None),
    );

    // 3. An import writing a preset (over an older one) and its program next to it.
    let lcnc = root.join("lcnc");
    let mut a = os(&[
        "export",
        "--preset",
        "presets/default.ron",
        "--to",
        "linuxcnc",
        "--horizon",
        "0.2",
        "--set",
        "axes.x.backlash.q_um=9",
        "--out",
    ]);
    a.push(lcnc.clone().into_os_string());
    run(&a);
    let imp_dir = root.join("import");
    let mut imp_args = os(&["import", "--from", "linuxcnc", "--in"]);
    imp_args.push(lcnc.into_os_string());
    imp_args.extend(os(&["--base", "presets/default.ron", "--out"]));
    imp_args.push(imp_dir.join("preset.ron").into_os_string());
    let import = Scenario::new(
        "import --out",
        imp_dir,
        |d| {
            std::fs::write(d.join("preset.ron"), "// an older preset\n").expect("old");
        },
        imp_args,
    )
    .triggered_by("preset.ron");

    let mut total = 0;
    let mut tallies = Vec::new();
    for (s, n) in [(&export, 40), (&simulate, 30), (&import, 30)] {
        let t = s.kill_test(n, &mut rng, seed);
        println!(
            "{}: {n} kills (random over 0…{:?}, an undisturbed run takes {:?}{}): {} ended old, {} ended new; {} left temporaries and {} left a mix of old and new files, all put right by the next run",
            s.name,
            s.duration.mul_f64(1.2),
            s.duration,
            if s.trigger.is_some() {
                "; every other one the moment the commit began"
            } else {
                ""
            },
            t.old,
            t.new,
            t.temporaries,
            t.mixed
        );
        total += n;
        tallies.push(t);
    }
    println!("{total} kills in {:?} (seed {seed})", t0.elapsed());
    assert!(total >= 50);
    // The test must have hit the moments that matter, or it proves nothing.
    assert!(
        tallies.iter().all(|t| t.temporaries > 0),
        "a scenario was never killed while writing (seed {seed}): {tallies:?}"
    );
    assert!(
        tallies[0].mixed + tallies[2].mixed > 0,
        "no kill landed inside a multi-file commit (seed {seed}): {tallies:?}"
    );
}
