//! Run folders: how training runs (the segmenter's, the agents') write and resume.
//!
//! - Every file appears whole: it is written beside its final name and renamed
//!   ([`write_atomic`], [`write_json`]).
//! - Folders (a checkpoint, the best model) are swapped in whole ([`replace_dir`]); a kill
//!   between the swap's two renames is undone by [`recover_dir`] on the next start.
//! - A fresh run needs an absent or empty folder; a resumed run a folder holding the run's
//!   marker file ([`prepare`]).
//! - Checkpoints kept beside the current one (earlier bests) are removed by [`prune`].

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde::de::DeserializeOwned;

/// What can go wrong with a run folder; every variant names the file or folder.
#[derive(Debug, thiserror::Error)]
pub enum RunFolderError {
    /// A file or folder could not be read, written, renamed or removed.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A file was read but is not what it should be.
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    /// `--resume` on a folder without the run's marker file.
    #[error("{}: holds no training run to resume (no {marker})", dir.display())]
    NothingToResume { dir: PathBuf, marker: String },
    /// A fresh run on a folder that holds files (`holds_run`: those of a run).
    #[error("{}: is not empty", dir.display())]
    NotEmpty { dir: PathBuf, holds_run: bool },
}

impl RunFolderError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        RunFolderError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    /// The file or folder the error is about.
    pub fn path(&self) -> &Path {
        match self {
            RunFolderError::Io { path, .. } | RunFolderError::Invalid { path, .. } => path,
            RunFolderError::NothingToResume { dir, .. } | RunFolderError::NotEmpty { dir, .. } => {
                dir
            }
        }
    }
}

/// Result with a [`RunFolderError`] by default.
pub type Result<T, E = RunFolderError> = std::result::Result<T, E>;

/// Checks and creates the folder of a run. A fresh run (`resume` false) needs `dir` absent or
/// empty; a resumed one needs `dir/marker`, the file every run writes first.
pub fn prepare(dir: &Path, marker: &str, resume: bool) -> Result<()> {
    let holds_run = dir.join(marker).is_file();
    if resume && !holds_run {
        return Err(RunFolderError::NothingToResume {
            dir: dir.to_path_buf(),
            marker: marker.to_owned(),
        });
    }
    if !resume && std::fs::read_dir(dir).is_ok_and(|mut entries| entries.next().is_some()) {
        return Err(RunFolderError::NotEmpty {
            dir: dir.to_path_buf(),
            holds_run,
        });
    }
    std::fs::create_dir_all(dir).map_err(|e| RunFolderError::io(dir, e))
}

/// Writes `path` by having `write` fill a temporary sibling, then renaming it: a kill never
/// leaves a half-written file under the final name. The temporary file is removed on failure.
pub fn write_atomic<E: From<RunFolderError>>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".to_owned());
    let tmp = path.with_file_name(format!(".{name}.tmp-{}", std::process::id()));
    if let Err(e) = write(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        RunFolderError::io(path, e).into()
    })
}

/// Writes `bytes` to `path` atomically.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |tmp| {
        std::fs::write(tmp, bytes).map_err(|e| RunFolderError::io(tmp, e))
    })
}

/// Writes `value` as pretty JSON with a final newline, atomically.
pub fn write_json<T: Serialize + ?Sized>(path: &Path, value: &T) -> Result<()> {
    let mut text = serde_json::to_string_pretty(value).map_err(|e| RunFolderError::Invalid {
        path: path.to_path_buf(),
        message: format!("cannot encode: {e}"),
    })?;
    text.push('\n');
    write_bytes(path, text.as_bytes())
}

/// Reads a JSON file written by [`write_json`].
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|e| RunFolderError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| RunFolderError::Invalid {
        path: path.to_path_buf(),
        message: format!("unreadable: {e}"),
    })
}

/// Writes the folder `dest` by having `fill` fill a temporary sibling, then swapping it in:
/// `dest` → `.old`, temporary → `dest`, `.old` removed. A kill between the two renames leaves
/// `.old`, which [`recover_dir`] puts back.
pub fn replace_dir<E: From<RunFolderError>>(
    dest: &Path,
    fill: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E> {
    let (tmp, old) = sibling_names(dest);
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| RunFolderError::io(&tmp, e))?;
    }
    std::fs::create_dir_all(&tmp).map_err(|e| RunFolderError::io(&tmp, e))?;
    if let Err(e) = fill(&tmp) {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    recover_dir(dest)?;
    if dest.exists() {
        std::fs::rename(dest, &old).map_err(|e| RunFolderError::io(dest, e))?;
    }
    std::fs::rename(&tmp, dest).map_err(|e| RunFolderError::io(dest, e))?;
    if old.exists() {
        std::fs::remove_dir_all(&old).map_err(|e| RunFolderError::io(&old, e))?;
    }
    Ok(())
}

/// Puts back a folder [`replace_dir`] was swapping when it was killed.
pub fn recover_dir(dest: &Path) -> Result<()> {
    let (_, old) = sibling_names(dest);
    if !dest.exists() && old.exists() {
        std::fs::rename(&old, dest).map_err(|e| RunFolderError::io(dest, e))?;
    }
    Ok(())
}

fn sibling_names(dest: &Path) -> (PathBuf, PathBuf) {
    let name = dest
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    (
        dest.with_file_name(format!(".{name}.tmp")),
        dest.with_file_name(format!(".{name}.old")),
    )
}

/// Removes the entries of `dir` whose names start with `prefix`, except `keep` (the current
/// best checkpoint, say). A missing `dir` has nothing to remove.
pub fn prune(dir: &Path, prefix: &str, keep: Option<&str>) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with(prefix) && Some(name.as_str()) != keep {
            let path = entry.path();
            let removed = if path.is_dir() {
                std::fs::remove_dir_all(&path)
            } else {
                std::fs::remove_file(&path)
            };
            removed.map_err(|e| RunFolderError::io(&path, e))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(path: &Path) -> Option<String> {
        std::fs::read_to_string(path).ok()
    }

    #[test]
    fn fresh_runs_need_an_empty_folder_and_resumed_ones_a_run() -> Result<()> {
        let root = tempfile::tempdir().map_err(|e| RunFolderError::io(Path::new("tmp"), e))?;
        let run = root.path().join("run");
        assert!(matches!(
            prepare(&run, "train.json", true),
            Err(RunFolderError::NothingToResume { .. })
        ));
        prepare(&run, "train.json", false)?;
        assert!(run.is_dir());
        // An empty folder may start again.
        prepare(&run, "train.json", false)?;
        write_json(&run.join("train.json"), &[1, 2])?;
        assert!(matches!(
            prepare(&run, "train.json", false),
            Err(RunFolderError::NotEmpty {
                holds_run: true,
                ..
            })
        ));
        prepare(&run, "train.json", true)?;
        assert_eq!(read_json::<Vec<u8>>(&run.join("train.json"))?, vec![1, 2]);
        Ok(())
    }

    #[test]
    fn failed_writes_leave_nothing_behind() -> Result<()> {
        let root = tempfile::tempdir().map_err(|e| RunFolderError::io(Path::new("tmp"), e))?;
        let path = root.path().join("a.json");
        write_bytes(&path, b"1")?;
        let failed: Result<()> = write_atomic(&path, |tmp| {
            std::fs::write(tmp, b"half").map_err(|e| RunFolderError::io(tmp, e))?;
            Err(RunFolderError::Invalid {
                path: tmp.to_path_buf(),
                message: "killed".into(),
            })
        });
        assert!(failed.is_err());
        assert_eq!(read(&path).as_deref(), Some("1"));
        let names: Vec<_> = std::fs::read_dir(root.path())
            .map_err(|e| RunFolderError::io(root.path(), e))?
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
        // A damaged file is an error naming it.
        std::fs::write(&path, "{").map_err(|e| RunFolderError::io(&path, e))?;
        let err = read_json::<Vec<u8>>(&path).err().map(|e| e.to_string());
        assert!(err.is_some_and(|e| e.contains("a.json")));
        Ok(())
    }

    #[test]
    fn replaced_folders_survive_a_kill_between_renames() -> Result<()> {
        let root = tempfile::tempdir().map_err(|e| RunFolderError::io(Path::new("tmp"), e))?;
        let dest = root.path().join("checkpoint");
        let fill = |text: &'static str| move |d: &Path| write_bytes(&d.join("a"), text.as_bytes());
        replace_dir(&dest, fill("1"))?;
        replace_dir(&dest, fill("2"))?;
        assert_eq!(read(&dest.join("a")).as_deref(), Some("2"));
        // As if killed after `dest -> .old`: recovery brings the old one back.
        let (_, old) = sibling_names(&dest);
        std::fs::rename(&dest, &old).map_err(|e| RunFolderError::io(&dest, e))?;
        recover_dir(&dest)?;
        assert_eq!(read(&dest.join("a")).as_deref(), Some("2"));
        // A fill that fails leaves the folder as it was.
        let failed: Result<()> = replace_dir(&dest, |d| {
            Err(RunFolderError::Invalid {
                path: d.to_path_buf(),
                message: "killed".into(),
            })
        });
        assert!(failed.is_err());
        assert_eq!(read(&dest.join("a")).as_deref(), Some("2"));
        Ok(())
    }

    #[test]
    fn prune_keeps_the_current_best() -> Result<()> {
        let root = tempfile::tempdir().map_err(|e| RunFolderError::io(Path::new("tmp"), e))?;
        for name in ["best-100", "best-200", "checkpoint"] {
            replace_dir(&root.path().join(name), |d| write_bytes(&d.join("x"), b"x"))?;
        }
        prune(root.path(), "best-", Some("best-200"))?;
        assert!(!root.path().join("best-100").exists());
        assert!(root.path().join("best-200").is_dir());
        assert!(root.path().join("checkpoint").is_dir());
        prune(&root.path().join("absent"), "best-", None)?;
        Ok(())
    }
}
