//! Atomic outputs: every export file (or folder) is written under a temporary name beside its
//! final name and renamed into place only when the whole export succeeded, so an interrupted
//! export never leaves a half-written file under a final name. Temporary names are fixed
//! (`.NAME.partial`), so the next run finds and removes what an interrupted one left.

use std::path::{Path, PathBuf};

use super::ExportError;

/// The suffix of temporary names.
pub const PARTIAL: &str = "partial";

/// One output being written.
#[derive(Clone, Debug)]
pub struct Staged {
    /// Where it is written.
    pub temp: PathBuf,
    /// Where it lands.
    pub target: PathBuf,
}

/// The temporary name of `target` with an extra `tag` (`""` for the output itself):
/// `dir/.NAME[.tag].partial`.
pub fn temp_name(target: &Path, tag: &str) -> PathBuf {
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tag = if tag.is_empty() {
        String::new()
    } else {
        format!(".{tag}")
    };
    target.with_file_name(format!(".{name}{tag}.{PARTIAL}"))
}

/// Removes a file or folder if it exists.
pub fn remove_any(path: &Path) -> Result<(), ExportError> {
    let result = match std::fs::symlink_metadata(path) {
        Ok(m) if m.is_dir() => std::fs::remove_dir_all(path),
        Ok(_) => std::fs::remove_file(path),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => Err(e),
    };
    result.map_err(|e| ExportError::io(path, e))
}

/// The outputs of one export.
#[derive(Debug, Default)]
pub struct Staging {
    outputs: Vec<Staged>,
    /// Scratch files of the writers (removed at the end, whatever happens).
    scratch: Vec<PathBuf>,
}

impl Staging {
    /// Plans output `target`: removes what an interrupted run left at its temporary name and
    /// returns that name.
    pub fn output(&mut self, target: PathBuf) -> Result<PathBuf, ExportError> {
        let temp = temp_name(&target, "");
        remove_any(&temp)?;
        self.outputs.push(Staged {
            temp: temp.clone(),
            target,
        });
        Ok(temp)
    }

    /// A scratch file beside `target` (stale copies removed now, this one at the end).
    pub fn scratch(&mut self, target: &Path, tag: &str) -> Result<PathBuf, ExportError> {
        let path = temp_name(target, tag);
        remove_any(&path)?;
        self.scratch.push(path.clone());
        Ok(path)
    }

    pub fn outputs(&self) -> &[Staged] {
        &self.outputs
    }

    /// Renames every output into place (a folder replaces the old folder of that name).
    pub fn commit(self) -> Result<Vec<PathBuf>, ExportError> {
        for s in &self.scratch {
            remove_any(s)?;
        }
        let mut done = Vec::new();
        for o in &self.outputs {
            if o.temp.is_dir() {
                remove_any(&o.target)?;
            }
            std::fs::rename(&o.temp, &o.target).map_err(|e| ExportError::io(&o.target, e))?;
            done.push(o.target.clone());
        }
        Ok(done)
    }

    /// Removes every temporary file (after a failure); the final names are left untouched.
    pub fn abandon(self) {
        for p in self
            .scratch
            .iter()
            .chain(self.outputs.iter().map(|o| &o.temp))
        {
            let _ = remove_any(p);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_appear_only_on_commit_and_stale_temporaries_are_removed() {
        let dir = std::env::temp_dir().join(format!("facesim-staging-{}", std::process::id()));
        remove_any(&dir).unwrap();
        std::fs::create_dir_all(&dir).unwrap();
        let target = dir.join("a.usda");
        // What an interrupted run left behind.
        std::fs::write(temp_name(&target, ""), "half").unwrap();
        std::fs::write(&target, "old").unwrap();
        let mut staging = Staging::default();
        let temp = staging.output(target.clone()).unwrap();
        assert!(!temp.exists(), "the stale temporary file is removed");
        let scratch = staging.scratch(&target, "normals").unwrap();
        std::fs::write(&temp, "new").unwrap();
        std::fs::write(&scratch, "x").unwrap();
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "old");
        staging.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "new");
        assert!(!temp.exists() && !scratch.exists());

        // A failed export leaves the old output and no temporaries.
        let mut staging = Staging::default();
        let temp = staging.output(target.clone()).unwrap();
        std::fs::write(&temp, "broken").unwrap();
        staging.abandon();
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "new");
        assert!(!temp.exists());
        remove_any(&dir).unwrap();
    }
}
