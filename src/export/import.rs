//! Import: the RON and LinuxCNC formats read back into a preset.
//!
//! RON is axisbench's own format and comes back whole. LinuxCNC carries only part of a
//! preset (limits, backlash, a comp table), so it is read onto a base preset
//! ([`super::linuxcnc::import`]): everything the INI does not carry stays as the base has
//! it. The written preset gets the base's programs next to it when they are not there yet,
//! so it loads on its own.

use std::path::{Path, PathBuf};

use super::{ExportError, Target};
use crate::preset::{self, LoadedPreset, Preset};

/// Reads `input` (a file, or an export folder holding `preset.ron` / `linuxcnc.ini`).
pub fn import(from: Target, input: &Path, base: &LoadedPreset) -> Result<Preset, ExportError> {
    let path = resolve(from, input)?;
    match from {
        Target::Ron => preset::load(&path.display().to_string())
            .map(|lp| lp.preset)
            .map_err(|e| ExportError::Input {
                file: path.display().to_string(),
                reason: e.to_string(),
            }),
        Target::Linuxcnc => super::linuxcnc::import(&path, &base.preset),
        other => Err(ExportError::Input {
            file: path.display().to_string(),
            reason: format!(
                "import reads ron and linuxcnc; {} is export-only",
                other.name()
            ),
        }),
    }
}

fn resolve(from: Target, input: &Path) -> Result<PathBuf, ExportError> {
    if input.is_dir() {
        let name = match from {
            Target::Ron => "preset.ron",
            _ => super::linuxcnc::INI_FILE,
        };
        let p = input.join(name);
        if p.is_file() {
            return Ok(p);
        }
        return Err(ExportError::Input {
            file: input.display().to_string(),
            reason: format!("folder has no {name}"),
        });
    }
    Ok(input.to_path_buf())
}

/// Writes `p` to `out` (atomically) and the programs it names next to it, taken from
/// `programs_from` when missing there.
pub fn write_preset(
    p: &Preset,
    out: &Path,
    programs_from: &LoadedPreset,
) -> Result<(), ExportError> {
    let io = |file: &Path| {
        let file = file.display().to_string();
        move |source| ExportError::Io { file, source }
    };
    let ron = p.to_ron().map_err(|e| ExportError::Input {
        file: out.display().to_string(),
        reason: e.to_string(),
    })?;
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut texts = Vec::new();
    for name in &p.scenario.programs {
        let dest = dir.join(name);
        if !dest.exists() {
            let text = programs_from
                .program_text(name)
                .map_err(|e| ExportError::Input {
                    file: name.clone(),
                    reason: e.to_string(),
                })?;
            texts.push((dest, text));
        }
    }
    crate::fsutil::write_atomic(out, ron.as_bytes()).map_err(io(out))?;
    for (dest, text) in texts {
        crate::fsutil::write_atomic(&dest, text.as_bytes()).map_err(io(&dest))?;
    }
    Ok(())
}
