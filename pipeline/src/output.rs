//! Atomic output: a command writes into a hidden temporary sibling of its destination and
//! renames it into place only when everything succeeded, so a failed or killed run never
//! leaves a half-written folder where a finished one is expected.
//!
//! - temporary folder: `.<name>.tmp-<pid>` next to the destination (same file system, so
//!   the final rename is atomic);
//! - on error (or panic), [`AtomicDir`]'s `Drop` removes the temporary folder;
//! - an existing destination is replaced only after success, and only if it looks like an
//!   earlier output of the same kind (or is empty): `--out ~` must never wipe a home folder;
//! - temporary folders left by killed runs (their process is gone) are removed on the next
//!   run to the same destination.

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use crate::error::CliError;

/// A folder being written; see the module docs.
#[derive(Debug)]
pub struct AtomicDir {
    dest: PathBuf,
    tmp: PathBuf,
    committed: bool,
}

/// Files whose presence marks a folder as an earlier output that may be replaced.
pub type Markers = &'static [&'static str];

impl AtomicDir {
    /// Checks that `dest` can be written (or replaced) without creating anything; call it
    /// before long work so a bad `--out` fails at once.
    pub fn check_destination(dest: &Path, markers: Markers) -> Result<()> {
        match fs::symlink_metadata(dest) {
            Err(_) => Ok(()),
            Ok(meta) if !meta.is_dir() => Err(CliError::file(
                dest,
                "exists and is not a folder",
                "choose another --out folder or remove that file",
            )
            .into()),
            Ok(_) => {
                let mut entries = fs::read_dir(dest)
                    .with_context(|| format!("{}: cannot list", dest.display()))?;
                let empty = entries.next().is_none();
                if empty || markers.iter().any(|m| dest.join(m).exists()) {
                    Ok(())
                } else {
                    Err(CliError::file(
                        dest,
                        "exists and is not an earlier output of this command (it would be replaced)",
                        "choose a new --out folder, or empty or remove that one",
                    )
                    .into())
                }
            }
        }
    }

    /// Starts writing `dest` in a fresh temporary sibling.
    pub fn create(dest: &Path, markers: Markers) -> Result<Self> {
        Self::check_destination(dest, markers)?;
        let name = dest
            .file_name()
            .ok_or_else(|| {
                CliError::file(
                    dest,
                    "is not a folder name",
                    "give --out a folder name such as runs/campus",
                )
            })?
            .to_string_lossy()
            .into_owned();
        let parent = match dest.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        fs::create_dir_all(&parent).map_err(|e| {
            CliError::file(
                &parent,
                format!("cannot create folder: {e}"),
                "check the --out path and permissions",
            )
        })?;
        remove_stale_temporaries(&parent, &name);
        let tmp = parent.join(format!(".{name}.tmp-{}", std::process::id()));
        if tmp.exists() {
            fs::remove_dir_all(&tmp)
                .with_context(|| format!("{}: cannot remove", tmp.display()))?;
        }
        fs::create_dir(&tmp).map_err(|e| {
            CliError::file(
                &tmp,
                format!("cannot create folder: {e}"),
                "check that the output folder's parent is writable",
            )
        })?;
        Ok(AtomicDir {
            dest: dest.to_path_buf(),
            tmp,
            committed: false,
        })
    }

    /// Where to write the files now.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// The final destination.
    pub fn destination(&self) -> &Path {
        &self.dest
    }

    /// Moves the finished folder into place, replacing an earlier output.
    pub fn commit(mut self) -> Result<PathBuf> {
        let old = self.tmp.with_file_name(format!(
            ".{}.old-{}",
            self.dest
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            std::process::id()
        ));
        let replaced = self.dest.exists();
        if replaced {
            fs::rename(&self.dest, &old).map_err(|e| {
                CliError::file(
                    &self.dest,
                    format!("cannot move the earlier output aside: {e}"),
                    "check permissions",
                )
            })?;
        }
        if let Err(e) = fs::rename(&self.tmp, &self.dest) {
            if replaced {
                // Put the earlier output back: better old and whole than nothing.
                let _ = fs::rename(&old, &self.dest);
            }
            return Err(CliError::file(
                &self.dest,
                format!("cannot move the output into place: {e}"),
                "check permissions",
            )
            .into());
        }
        self.committed = true;
        if replaced {
            let _ = fs::remove_dir_all(&old);
        }
        Ok(self.dest.clone())
    }
}

impl Drop for AtomicDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
}

/// Removes `.<name>.tmp-<pid>` / `.<name>.old-<pid>` siblings whose process no longer runs.
fn remove_stale_temporaries(parent: &Path, name: &str) {
    let Ok(entries) = fs::read_dir(parent) else {
        return;
    };
    for entry in entries.flatten() {
        let file_name = entry.file_name().to_string_lossy().into_owned();
        let pid = [".tmp-", ".old-"].iter().find_map(|kind| {
            file_name
                .strip_prefix(&format!(".{name}{kind}"))
                .and_then(|pid| pid.parse::<u32>().ok())
        });
        if let Some(pid) = pid
            && pid != std::process::id()
            && !process_is_alive(pid)
        {
            let _ = fs::remove_dir_all(entry.path());
        }
    }
}

/// Whether a process runs; where that cannot be told, assume it does (never delete another
/// run's work).
fn process_is_alive(pid: u32) -> bool {
    if !Path::new("/proc/self").exists() {
        return true;
    }
    match fs::read_to_string(format!("/proc/{pid}/stat")) {
        // A killed process nobody has reaped yet is a zombie (state Z, or X when dying):
        // it will never finish its output.
        Ok(stat) => !stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().next())
            .is_some_and(|state| state == "Z" || state == "X"),
        Err(_) => false,
    }
}

/// Writes `value` as pretty JSON with a final newline, atomically.
pub fn write_json<T: serde::Serialize + ?Sized>(path: &Path, value: &T) -> Result<()> {
    let mut text = serde_json::to_string_pretty(value)
        .with_context(|| format!("{}: serialisation failed", path.display()))?;
    text.push('\n');
    write_file_atomic(path, text.as_bytes())
}

/// Writes a file atomically: a temporary sibling, then a rename.
pub fn write_file_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        fs::create_dir_all(parent).map_err(|e| {
            CliError::file(
                parent,
                format!("cannot create folder: {e}"),
                "check the path and permissions",
            )
        })?;
    }
    models::run_folder::write_bytes(path, bytes).map_err(|e| {
        let message = match &e {
            models::run_folder::RunFolderError::Io { source, .. } => {
                format!("cannot write: {source}")
            }
            other => other.to_string(),
        };
        CliError::file(path, message, "check the path and permissions")
    })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const MARKERS: Markers = &["summary.json"];

    #[test]
    fn commit_moves_into_place_and_replaces_earlier_output() -> Result<()> {
        let root = tempfile::tempdir()?;
        let dest = root.path().join("out");
        let dir = AtomicDir::create(&dest, MARKERS)?;
        fs::write(dir.path().join("summary.json"), "1")?;
        assert!(!dest.exists());
        dir.commit()?;
        assert_eq!(fs::read_to_string(dest.join("summary.json"))?, "1");

        let dir = AtomicDir::create(&dest, MARKERS)?;
        fs::write(dir.path().join("summary.json"), "2")?;
        // The earlier output stays untouched until the commit.
        assert_eq!(fs::read_to_string(dest.join("summary.json"))?, "1");
        dir.commit()?;
        assert_eq!(fs::read_to_string(dest.join("summary.json"))?, "2");
        // Nothing else left beside it.
        let names: Vec<_> = fs::read_dir(root.path())?
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out")]);
        Ok(())
    }

    #[test]
    fn dropping_without_commit_leaves_nothing() -> Result<()> {
        let root = tempfile::tempdir()?;
        let dest = root.path().join("nested").join("out");
        {
            let dir = AtomicDir::create(&dest, MARKERS)?;
            fs::write(dir.path().join("half.json"), "x")?;
        }
        assert!(!dest.exists());
        assert_eq!(fs::read_dir(root.path().join("nested"))?.count(), 0);
        Ok(())
    }

    #[test]
    fn refuses_to_replace_foreign_folders_and_files() -> Result<()> {
        let root = tempfile::tempdir()?;
        let foreign = root.path().join("home");
        fs::create_dir(&foreign)?;
        fs::write(foreign.join("thesis.tex"), "precious")?;
        assert!(AtomicDir::create(&foreign, MARKERS).is_err());
        assert_eq!(fs::read_to_string(foreign.join("thesis.tex"))?, "precious");
        let file = root.path().join("file");
        fs::write(&file, "x")?;
        assert!(AtomicDir::create(&file, MARKERS).is_err());
        // An empty folder may be filled.
        let empty = root.path().join("empty");
        fs::create_dir(&empty)?;
        AtomicDir::create(&empty, MARKERS)?.commit()?;
        Ok(())
    }

    #[test]
    fn stale_temporaries_of_dead_processes_are_removed() -> Result<()> {
        let root = tempfile::tempdir()?;
        // PIDs are below 2^22 on Linux, so this one is not running.
        let stale = root.path().join(".out.tmp-4294967");
        fs::create_dir(&stale)?;
        let dir = AtomicDir::create(&root.path().join("out"), MARKERS)?;
        assert!(!stale.exists());
        dir.commit()?;
        Ok(())
    }

    /// A process killed but not yet reaped (a zombie) counts as gone; this one does not.
    #[test]
    fn zombies_are_not_alive() -> Result<()> {
        assert!(process_is_alive(std::process::id()));
        if !Path::new("/proc/self").exists() {
            return Ok(());
        }
        let mut child = std::process::Command::new("true").spawn()?;
        // Not waited for: once it exits it stays a zombie until `wait`.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while process_is_alive(child.id()) && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        assert!(!process_is_alive(child.id()));
        child.wait()?;
        Ok(())
    }

    #[test]
    fn atomic_file_write() -> Result<()> {
        let root = tempfile::tempdir()?;
        let path = root.path().join("a").join("route.json");
        write_file_atomic(&path, b"{}")?;
        assert_eq!(fs::read(&path)?, b"{}");
        assert_eq!(fs::read_dir(root.path().join("a"))?.count(), 1);
        Ok(())
    }
}
