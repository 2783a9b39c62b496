//! The session: the preset being edited, its programs, where it came from and the recent
//! files, autosaved (atomically) every few seconds and restored at start, so closing the
//! window or a crash never loses an edit.

use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result};
use serde::{Deserialize, Serialize};

use axisbench::preset::Preset;

use super::Workbench;

#[derive(Serialize, Deserialize)]
struct Session {
    version: u32,
    preset_ron: String,
    saved_ron: String,
    programs: Vec<(String, String)>,
    path: Option<PathBuf>,
    origin: String,
    recent: Vec<PathBuf>,
}

/// `<config dir>/axisbench/session.ron`, e.g. ~/.config/axisbench/session.ron.
pub fn session_file() -> Option<PathBuf> {
    directories::ProjectDirs::from("", "", "axisbench").map(|d| d.config_dir().join("session.ron"))
}

pub fn to_text(wb: &Workbench) -> String {
    let s = Session {
        version: 1,
        preset_ron: wb.preset.to_ron().unwrap_or_default(),
        saved_ron: wb.saved_ron.clone(),
        programs: wb.programs.clone(),
        path: wb.path.clone(),
        origin: wb.origin.clone(),
        recent: wb.recent.clone(),
    };
    ron::ser::to_string_pretty(&s, ron::ser::PrettyConfig::default()).unwrap_or_default()
}

pub fn write(file: &Path, text: &str) -> Result<()> {
    if let Some(dir) = file.parent() {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create", dir.display()))?;
    }
    axisbench::fsutil::write_atomic(file, text.as_bytes())
        .with_context(|| format!("{}: cannot write", file.display()))
}

/// The saved session, if there is a readable and valid one.
pub fn restore(file: &Path) -> Option<Workbench> {
    let text = std::fs::read_to_string(file).ok()?;
    let s: Session = ron::from_str(&text).ok()?;
    let preset = Preset::from_ron(&s.preset_ron, &file.display().to_string()).ok()?;
    let mut wb = Workbench::with(preset, s.programs, s.path, s.origin).ok()?;
    wb.saved_ron = s.saved_ron;
    wb.recent = s.recent;
    Some(wb)
}
