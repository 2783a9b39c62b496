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
            .map_err(|e| match e {
                preset::PresetError::Io { file, source } => ExportError::Read {
                    file,
                    reason: source.to_string(),
                },
                // The preset's own message names the file (and line, field).
                other => ExportError::Preset(other.to_string()),
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

/// Writes `p` to `out` and the programs it names next to it (taken from `programs_from`
/// when missing there), all together or not at all: on any error the folder is left as it
/// was. A program named with a folder part (`sub/a.ngc`) cannot join that unit and is
/// written on its own, atomically, afterwards.
pub fn write_preset(
    p: &Preset,
    out: &Path,
    programs_from: &LoadedPreset,
) -> Result<(), ExportError> {
    let ron = p.to_ron().map_err(|e| ExportError::Input {
        file: out.display().to_string(),
        reason: e.to_string(),
    })?;
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let Some(name) = out.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return Err(ExportError::Input {
            file: out.display().to_string(),
            reason: "not a file name".into(),
        });
    };
    let mut unit = vec![(name, ron.into_bytes())];
    let mut apart = Vec::new();
    for prog in &p.scenario.programs {
        let dest = dir.join(prog);
        if dest.exists() || unit.iter().any(|(n, _)| n == prog) {
            continue;
        }
        let text = programs_from
            .program_text(prog)
            .map_err(|e| ExportError::Input {
                file: prog.clone(),
                reason: e.to_string(),
            })?;
        if Path::new(prog)
            .file_name()
            .is_some_and(|f| f == prog.as_str())
        {
            unit.push((prog.clone(), text.into_bytes()));
        } else {
            apart.push((dest, text));
        }
    }
    crate::fsutil::write_all_atomic(&dir, &unit).map_err(ExportError::Write)?;
    for (dest, text) in apart {
        crate::fsutil::write_atomic(&dest, text.as_bytes()).map_err(|e| {
            ExportError::Write(crate::fsutil::FsError {
                op: "write",
                path: dest.clone(),
                reason: e.to_string(),
                kind: e.kind(),
            })
        })?;
    }
    Ok(())
}
