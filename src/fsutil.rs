//! Crash-safe file writes.
//!
//! A single file ([`write_atomic`]) goes to a temporary file next to the target, is synced
//! to disk and replaces the target in one `rename`, so whatever happens (an error, a full
//! disk, the process killed) the target name holds either the previous or the new content,
//! never a half-written file.
//!
//! A set of files ([`write_all_atomic`], used by exports and imports) is staged in a
//! temporary folder inside the target folder (same filesystem, so the moves are renames),
//! then moved into place one rename per file; the previous versions are kept as hard links
//! (or copies) until the last file is in place. When a step fails, every file already moved
//! is taken back and the previous versions are restored; when the process is killed half
//! way, the next write into that folder finds the journal and does the same. Either way the
//! folder ends up with all of the old files or all of the new ones.
//!
//! Crash-consistency tests set `AXISBENCH_TEST_COMMIT_PAUSE_MS` to make a multi-file commit
//! pause that long after each rename, so a kill can be aimed inside the commit; it changes
//! nothing else.
//!
//! Temporaries are named after the process that made them (`.<name>.axb<pid>-<n>.tmp`,
//! `.axisbench-export.<pid>.<n>/`). The next write into a folder removes the ones whose
//! process is gone (`/proc/<pid>` absent); nothing else in the folder is touched.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A failed file-system step: what was attempted on which path, and the OS's reason.
///
/// The OS error is part of the message and deliberately not a `source()`: error reporters
/// print the source chain, which would repeat the OS text.
#[derive(Debug, thiserror::Error)]
#[error("cannot {op} {}: {reason}", path.display())]
pub struct FsError {
    /// What was attempted ("write", "create folder", "replace" …).
    pub op: &'static str,
    /// The path it was attempted on.
    pub path: PathBuf,
    /// The reason, as the OS or the check gave it.
    pub reason: String,
    /// The OS error kind, for callers that react to it.
    pub kind: std::io::ErrorKind,
}

impl FsError {
    fn io(op: &'static str, path: &Path, e: &std::io::Error) -> FsError {
        FsError {
            op,
            path: path.to_path_buf(),
            reason: e.to_string(),
            kind: e.kind(),
        }
    }

    fn other(op: &'static str, path: &Path, reason: impl Into<String>) -> FsError {
        FsError {
            op,
            path: path.to_path_buf(),
            reason: reason.into(),
            kind: std::io::ErrorKind::InvalidInput,
        }
    }
}

/// Prefix of the staging folders of [`write_all_atomic`].
pub const STAGE_PREFIX: &str = ".axisbench-export.";
/// Marker inside temporary file names of [`write_atomic_with`].
const TMP_MARK: &str = ".axb";
const TMP_SUFFIX: &str = ".tmp";
/// The journal of a commit in progress, inside the staging folder.
const JOURNAL: &str = "COMMIT";
/// Where the previous versions wait inside the staging folder.
const BACKUP_DIR: &str = ".old";

/// Distinguishes the temporaries of several writes of one process (threads, or a write
/// started while another one's temporary still exists).
static SEQ: AtomicU64 = AtomicU64::new(0);

fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Writes `path` atomically: `f` fills a temporary file next to it, which is synced and
/// renamed over `path`. On any error the temporary is removed and `path` is untouched.
/// Stale temporaries of killed processes in the same folder are removed first.
pub fn write_atomic_with(
    path: &Path,
    f: impl FnOnce(&mut BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let dir = parent_dir(path);
    let name = path.file_name().ok_or_else(|| {
        std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has no file name")
    })?;
    clean_stale(&dir);
    let tmp = dir.join(format!(
        ".{}{TMP_MARK}{}-{}{TMP_SUFFIX}",
        name.to_string_lossy(),
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed)
    ));
    let result = (|| {
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
        let mut w = BufWriter::new(file);
        f(&mut w)?;
        w.flush()?;
        w.get_ref().sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    } else {
        sync_dir(&dir);
    }
    result
}

/// [`write_atomic_with`] for bytes already in memory.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Makes a rename durable (best effort: not every filesystem can sync a folder).
fn sync_dir(dir: &Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Whether process `pid` may still be running. Only a missing `/proc/<pid>` on a system
/// that has `/proc` counts as gone: anything uncertain keeps the temporary.
fn process_gone(pid: u32) -> bool {
    pid != std::process::id()
        && Path::new("/proc/self").exists()
        && !Path::new("/proc").join(pid.to_string()).exists()
}

/// The owner of a temporary of ours, from its name, or None when the name is not ours.
fn temp_owner(name: &str, is_dir: bool) -> Option<u32> {
    if is_dir {
        // `.axisbench-export.<pid>` (older builds) or `.axisbench-export.<pid>.<n>`.
        let rest = name.strip_prefix(STAGE_PREFIX)?;
        let pid = rest.split('.').next()?;
        let ok = rest.split('.').count() <= 2 && rest.split('.').all(all_digits);
        return if ok { pid.parse().ok() } else { None };
    }
    let body = name.strip_prefix('.')?;
    if let Some(stem) = body.strip_suffix(TMP_SUFFIX) {
        // `.<name>.axb<pid>-<n>.tmp`
        let (_, tail) = stem.rsplit_once(TMP_MARK)?;
        let (pid, n) = tail.split_once('-')?;
        return (all_digits(pid) && all_digits(n))
            .then(|| pid.parse().ok())
            .flatten();
    }
    // `.<name>.tmp<pid>` (older builds).
    let (_, pid) = body.rsplit_once(".tmp")?;
    all_digits(pid).then(|| pid.parse().ok()).flatten()
}

fn all_digits(s: &str) -> bool {
    !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit())
}

/// Removes the temporaries in `dir` left by axisbench processes that are gone (killed
/// during a write): temporary files, and staging folders, whose interrupted commit is
/// rolled back first so the folder holds the previous files again. Returns how many were
/// removed. Called by every write; errors are ignored (a leftover is retried next time).
pub fn clean_stale(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let is_dir = e.file_type().map(|t| t.is_dir()).unwrap_or(false);
        let Some(pid) = temp_owner(&name, is_dir) else {
            continue;
        };
        if !process_gone(pid) {
            continue;
        }
        let path = e.path();
        let ok = if is_dir {
            let _ = roll_back(dir, &path);
            std::fs::remove_dir_all(&path).is_ok()
        } else {
            std::fs::remove_file(&path).is_ok()
        };
        removed += usize::from(ok);
    }
    if removed > 0 {
        sync_dir(dir);
    }
    removed
}

/// One file of a commit: its name and whether a previous version was backed up.
struct Moved {
    name: String,
    had_old: bool,
}

/// Undoes the commit journalled in `stage` (if any): restores every backed-up previous
/// version and removes the files that did not exist before. Returns what could not be
/// restored.
fn roll_back(dir: &Path, stage: &Path) -> Result<(), FsError> {
    let Ok(journal) = std::fs::read_to_string(stage.join(JOURNAL)) else {
        return Ok(()); // no commit started, or it completed
    };
    let moved: Vec<Moved> = journal
        .lines()
        .filter_map(|l| l.split_once('\t'))
        .map(|(k, n)| Moved {
            name: n.to_owned(),
            had_old: k == "old",
        })
        .collect();
    restore(dir, stage, &moved)
}

fn restore(dir: &Path, stage: &Path, moved: &[Moved]) -> Result<(), FsError> {
    let mut first_err = None;
    for m in moved.iter().rev() {
        let to = dir.join(&m.name);
        let r = if m.had_old {
            let backup = stage.join(BACKUP_DIR).join(&m.name);
            if backup.exists() {
                std::fs::rename(&backup, &to).map_err(|e| FsError::io("restore", &to, &e))
            } else {
                Ok(())
            }
        } else {
            match std::fs::remove_file(&to) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    Err(FsError::io("remove", &to, &e))
                }
                _ => Ok(()),
            }
        };
        if let Err(e) = r {
            first_err.get_or_insert(e);
        }
    }
    sync_dir(dir);
    first_err.map_or(Ok(()), Err)
}

/// Writes every `(file name, contents)` into `dir` (created if missing) as one unit: either
/// all of them replace their previous versions, or — on any error — the folder is left
/// exactly as it was (previous files restored, new ones removed, folders this call created
/// removed, no temporary left behind). Names must be plain file names. Returns the paths
/// written, in order.
pub fn write_all_atomic(dir: &Path, files: &[(String, Vec<u8>)]) -> Result<Vec<PathBuf>, FsError> {
    let names: Vec<String> = files.iter().map(|(n, _)| n.clone()).collect();
    write_all_atomic_with(dir, &names, &mut |i, w| match files.get(i) {
        Some((_, bytes)) => w.write_all(bytes),
        None => Ok(()),
    })
}

/// [`write_all_atomic`] for a set too large to hold in memory at once: `fill(i, w)` writes
/// the contents of `names[i]` into `w`, once per file, in order (a writer that fails
/// rolls the whole set back like any other error; its message names the file).
pub fn write_all_atomic_with(
    dir: &Path,
    names: &[String],
    fill: &mut dyn FnMut(usize, &mut dyn Write) -> std::io::Result<()>,
) -> Result<Vec<PathBuf>, FsError> {
    for name in names {
        check_plain_name(dir, name)?;
    }
    let created = create_dirs(dir)?;
    let result = (|| {
        clean_stale(dir);
        preflight(dir, names)?;
        commit_staged(dir, names, fill)
    })();
    if result.is_err() {
        for d in created.iter().rev() {
            let _ = std::fs::remove_dir(d);
        }
    }
    result
}

fn check_plain_name(dir: &Path, name: &str) -> Result<(), FsError> {
    let plain = !name.is_empty()
        && name != "."
        && name != ".."
        && !name.contains(['/', '\\', '\n', '\t', '\0'])
        && name != BACKUP_DIR
        && temp_owner(name, true).is_none()
        && temp_owner(name, false).is_none();
    if plain {
        Ok(())
    } else {
        Err(FsError::other(
            "write",
            &dir.join(name),
            "not a plain file name (no folders, tabs or newlines, not a temporary's name)",
        ))
    }
}

/// Creates `dir` and any missing parents; returns the ones created, outermost first.
fn create_dirs(dir: &Path) -> Result<Vec<PathBuf>, FsError> {
    let mut missing = Vec::new();
    let mut d = dir.to_path_buf();
    while !d.as_os_str().is_empty() && !d.exists() {
        missing.push(d.clone());
        match d.parent() {
            Some(p) => d = p.to_path_buf(),
            None => break,
        }
    }
    missing.reverse();
    let mut created = Vec::new();
    for m in missing {
        if let Err(e) = std::fs::create_dir(&m) {
            for c in created.iter().rev() {
                let _ = std::fs::remove_dir(c);
            }
            return Err(FsError::io("create folder", &m, &e));
        }
        created.push(m);
    }
    if !dir.is_dir() {
        return Err(FsError::other("write into", dir, "not a folder"));
    }
    Ok(created)
}

/// Refuses before anything is written when a target name is taken by something that is not
/// a file (a folder, a socket …): a rename could not replace it.
fn preflight(dir: &Path, names: &[String]) -> Result<(), FsError> {
    for name in names {
        let p = dir.join(name);
        if let Ok(m) = std::fs::metadata(&p)
            && !m.is_file()
        {
            let what = if m.is_dir() {
                "a folder of that name is in the way"
            } else {
                "something that is not a regular file is in the way"
            };
            return Err(FsError::other("write", &p, what));
        }
    }
    Ok(())
}

/// Stages, commits and cleans up; the staging folder is gone on every path out, except
/// when a rollback itself failed (then it holds the only copy of the previous files, and
/// the error says where).
fn commit_staged(
    dir: &Path,
    names: &[String],
    fill: &mut dyn FnMut(usize, &mut dyn Write) -> std::io::Result<()>,
) -> Result<Vec<PathBuf>, FsError> {
    let stage = dir.join(format!(
        "{STAGE_PREFIX}{}.{}",
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::create_dir(&stage).map_err(|e| FsError::io("write into", dir, &e))?;
    let result =
        stage_files(&stage, names, fill).and_then(|()| move_into_place(dir, &stage, names));
    match &result {
        Err(e) if e.op == "restore" => {}
        _ => {
            let _ = std::fs::remove_dir_all(&stage);
        }
    }
    result
}

fn stage_files(
    stage: &Path,
    names: &[String],
    fill: &mut dyn FnMut(usize, &mut dyn Write) -> std::io::Result<()>,
) -> Result<(), FsError> {
    for (i, name) in names.iter().enumerate() {
        let p = stage.join(name);
        let mut w = || -> std::io::Result<()> {
            let mut f = BufWriter::new(std::fs::File::create(&p)?);
            fill(i, &mut f)?;
            f.flush()?;
            f.get_ref().sync_all()
        };
        // The error names the final path: the staging folder is an implementation detail.
        w().map_err(|e| FsError::io("write", &stage.parent().unwrap_or(stage).join(name), &e))?;
    }
    sync_dir(stage);
    Ok(())
}

/// Backs up the previous versions, journals the commit, renames every staged file into
/// place, and rolls back on the first failure.
fn move_into_place(dir: &Path, stage: &Path, names: &[String]) -> Result<Vec<PathBuf>, FsError> {
    let backups = stage.join(BACKUP_DIR);
    std::fs::create_dir(&backups).map_err(|e| FsError::io("write into", dir, &e))?;
    let mut moved = Vec::new();
    let mut journal = String::new();
    for name in names {
        let to = dir.join(name);
        let had_old = to.exists();
        if had_old {
            let b = backups.join(name);
            std::fs::hard_link(&to, &b)
                .or_else(|_| std::fs::copy(&to, &b).map(|_| ()))
                .map_err(|e| FsError::io("keep the previous version of", &to, &e))?;
        }
        journal += &format!("{}\t{name}\n", if had_old { "old" } else { "new" });
        moved.push(Moved {
            name: name.clone(),
            had_old,
        });
    }
    sync_dir(&backups);
    write_atomic(&stage.join(JOURNAL), journal.as_bytes())
        .map_err(|e| FsError::io("write into", dir, &e))?;
    let mut written = Vec::new();
    let pause = commit_pause();
    for (k, name) in names.iter().enumerate() {
        let to = dir.join(name);
        if let Err(e) = rename_into(&stage.join(name), &to, k) {
            let err = FsError::io("replace", &to, &e);
            return Err(match restore(dir, stage, &moved[..=k]) {
                Ok(()) => err,
                Err(r) => FsError {
                    reason: format!(
                        "{}; restoring the previous files failed too ({r}); they are kept in {}",
                        err.reason,
                        backups.display()
                    ),
                    op: "restore",
                    ..err
                },
            });
        }
        written.push(to);
        if !pause.is_zero() {
            std::thread::sleep(pause);
        }
    }
    sync_dir(dir);
    // The commit point: without a journal the staging folder is only garbage.
    std::fs::remove_file(stage.join(JOURNAL)).map_err(|e| FsError::io("write into", dir, &e))?;
    Ok(written)
}

/// The pause after each rename of a commit that crash-consistency tests ask for (see the
/// module documentation); zero normally.
fn commit_pause() -> std::time::Duration {
    std::env::var("AXISBENCH_TEST_COMMIT_PAUSE_MS")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
        .map_or(std::time::Duration::ZERO, std::time::Duration::from_millis)
}

/// The k-th rename of a commit. Tests make one fail to exercise the rollback.
fn rename_into(from: &Path, to: &Path, k: usize) -> std::io::Result<()> {
    #[cfg(test)]
    if tests::FAIL_RENAME_AT.with(|f| f.get()) == Some(k) {
        return Err(std::io::Error::other("injected failure"));
    }
    let _ = k;
    std::fs::rename(from, to)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::Cell;

    thread_local! {
        /// Makes the k-th rename of a commit on this thread fail.
        pub(super) static FAIL_RENAME_AT: Cell<Option<usize>> = const { Cell::new(None) };
    }

    /// A pid no process has (above every Linux pid_max).
    const DEAD_PID: u32 = 4_000_000_000;

    /// Every entry of `dir` (names, including hidden ones) with its contents ("<dir>" for
    /// a folder), sorted.
    fn snapshot(dir: &Path) -> Vec<(String, String)> {
        let mut v: Vec<(String, String)> = std::fs::read_dir(dir)
            .expect("dir")
            .flatten()
            .map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                let text = std::fs::read_to_string(e.path()).unwrap_or_else(|_| "<dir>".into());
                (name, text)
            })
            .collect();
        v.sort();
        v
    }

    fn files(list: &[(&str, &str)]) -> Vec<(String, Vec<u8>)> {
        list.iter()
            .map(|(n, t)| ((*n).to_owned(), t.as_bytes().to_vec()))
            .collect()
    }

    #[test]
    fn a_failed_commit_restores_the_previous_files_and_removes_the_new_ones() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let dir = tmp.path();
        std::fs::write(dir.join("a.txt"), "old a").expect("a");
        std::fs::write(dir.join("b.txt"), "old b").expect("b");
        let before = snapshot(dir);
        // a and c are in place when b's rename fails.
        FAIL_RENAME_AT.with(|f| f.set(Some(2)));
        let r = write_all_atomic(
            dir,
            &files(&[("a.txt", "new a"), ("c.txt", "new c"), ("b.txt", "new b")]),
        );
        FAIL_RENAME_AT.with(|f| f.set(None));
        let err = r.expect_err("injected failure");
        assert!(
            err.to_string().contains("b.txt") && err.to_string().contains("injected"),
            "{err}"
        );
        assert_eq!(
            snapshot(dir),
            before,
            "old files back, new one gone, no staging folder"
        );
        // Without the failure the same call replaces all three.
        write_all_atomic(
            dir,
            &files(&[("a.txt", "new a"), ("c.txt", "new c"), ("b.txt", "new b")]),
        )
        .expect("writes");
        assert_eq!(
            snapshot(dir),
            vec![
                ("a.txt".into(), "new a".into()),
                ("b.txt".into(), "new b".into()),
                ("c.txt".into(), "new c".into())
            ]
        );
    }

    #[test]
    fn a_folder_in_the_way_refuses_before_anything_is_written() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let dir = tmp.path().join("out");
        std::fs::create_dir(&dir).expect("out");
        std::fs::write(dir.join("a.txt"), "old a").expect("a");
        std::fs::create_dir(dir.join("b.txt")).expect("b is a folder");
        let before = snapshot(&dir);
        let err = write_all_atomic(&dir, &files(&[("a.txt", "new"), ("b.txt", "new")]))
            .expect_err("folder in the way");
        assert!(err.to_string().contains("folder of that name"), "{err}");
        assert_eq!(snapshot(&dir), before);
        // A folder this call would have created is gone again.
        let fresh = tmp.path().join("x").join("y");
        let err = write_all_atomic(&fresh, &files(&[("../a", "no")])).expect_err("not plain");
        assert!(err.to_string().contains("plain file name"), "{err}");
        assert!(!tmp.path().join("x").exists());
    }

    #[test]
    fn an_interrupted_commit_of_a_dead_process_is_rolled_back_on_the_next_write() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let dir = tmp.path();
        // The state a kill leaves between two renames: a.txt already new (its old version
        // in the backups), c.txt new, b.txt still old, the journal present.
        let stage = dir.join(format!("{STAGE_PREFIX}{DEAD_PID}.0"));
        std::fs::create_dir_all(stage.join(BACKUP_DIR)).expect("stage");
        std::fs::write(stage.join(BACKUP_DIR).join("a.txt"), "old a").expect("backup");
        std::fs::write(stage.join(BACKUP_DIR).join("b.txt"), "old b").expect("backup");
        std::fs::write(stage.join("b.txt"), "new b").expect("staged");
        std::fs::write(stage.join(JOURNAL), "old\ta.txt\nnew\tc.txt\nold\tb.txt\n")
            .expect("journal");
        std::fs::write(dir.join("a.txt"), "new a").expect("a");
        std::fs::write(dir.join("c.txt"), "new c").expect("c");
        std::fs::write(dir.join("b.txt"), "old b").expect("b");
        // Stale single-file temporaries: a dead process's goes, ours and foreign ones stay.
        let dead_tmp = format!(".x.ron{TMP_MARK}{DEAD_PID}-3{TMP_SUFFIX}");
        let own_tmp = format!(".x.ron{TMP_MARK}{}-3{TMP_SUFFIX}", std::process::id());
        for n in [dead_tmp.as_str(), own_tmp.as_str(), ".x.tmp", ".tmp.x"] {
            std::fs::write(dir.join(n), "partial").expect("tmp");
        }
        assert_eq!(
            clean_stale(dir),
            2,
            "the stage and the dead process's temporary"
        );
        let names: Vec<String> = snapshot(dir).into_iter().map(|(n, _)| n).collect();
        let mut want = vec![".tmp.x", ".x.tmp", own_tmp.as_str(), "a.txt", "b.txt"];
        want.sort_unstable();
        assert_eq!(names, want);
        assert_eq!(
            std::fs::read_to_string(dir.join("a.txt")).expect("a"),
            "old a"
        );
        assert_eq!(
            std::fs::read_to_string(dir.join("b.txt")).expect("b"),
            "old b"
        );
    }

    #[test]
    fn a_failing_single_write_leaves_the_target_and_no_temporary() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let target = tmp.path().join("t.csv");
        std::fs::write(&target, "old").expect("old");
        let r = write_atomic_with(&target, |w| {
            w.write_all(b"half")?;
            Err(std::io::Error::other("disk full"))
        });
        assert!(r.is_err());
        assert_eq!(
            snapshot(tmp.path()),
            vec![("t.csv".to_owned(), "old".to_owned())]
        );
        write_atomic(&target, b"new").expect("writes");
        assert_eq!(
            snapshot(tmp.path()),
            vec![("t.csv".to_owned(), "new".to_owned())]
        );
    }

    #[test]
    fn temporary_names_are_recognised_strictly() {
        assert_eq!(temp_owner(".preset.ron.axb123-4.tmp", false), Some(123));
        assert_eq!(temp_owner(".preset.ron.tmp77", false), Some(77));
        assert_eq!(temp_owner(".axisbench-export.42", true), Some(42));
        assert_eq!(temp_owner(".axisbench-export.42.3", true), Some(42));
        for not_ours in ["preset.ron", ".bashrc", "x.tmp", ".a.tmp", ".a.axbx-1.tmp"] {
            assert_eq!(temp_owner(not_ours, false), None, "{not_ours}");
        }
        assert_eq!(temp_owner(".axisbench-export.42.3.x", true), None);
        assert_eq!(temp_owner(".axisbench-export.", true), None);
    }
}
