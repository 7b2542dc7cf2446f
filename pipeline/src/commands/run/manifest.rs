//! The run manifest (`manifest.json` in the run folder): per finished stage, the key of
//! its inputs and settings and the content hash of each output, like `dvc.lock`. A stage
//! whose key is unchanged and whose outputs still hash as recorded is skipped.
//!
//! The manifest is rewritten atomically after every stage, so a killed run keeps every
//! stage it finished and nothing of the one it was in.

use std::collections::BTreeMap;
use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::error::CliError;
use crate::output::write_file_atomic;
use crate::recording::RECORDING_FILE;

pub const MANIFEST_FILE: &str = "manifest.json";
const MANIFEST_VERSION: u32 = 1;

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub version: u32,
    /// Finished stages by name.
    pub stages: BTreeMap<String, StageRecord>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageRecord {
    /// Hash of the stage's settings and of its inputs' contents.
    pub key: String,
    /// The settings that went into the key, for reading.
    pub settings: serde_json::Value,
    /// Input path (relative to the run folder for upstream outputs) -> content hash.
    pub inputs: BTreeMap<String, String>,
    /// Output path relative to the run folder -> content hash.
    pub outputs: BTreeMap<String, String>,
    /// Wall time of the stage's last run.
    pub seconds: f64,
}

impl Manifest {
    /// Reads the run folder's manifest; an absent one is empty.
    pub fn load(run_dir: &Path) -> Result<Manifest> {
        let path = run_dir.join(MANIFEST_FILE);
        let text = match fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Ok(Manifest {
                    version: MANIFEST_VERSION,
                    ..Default::default()
                });
            }
            Err(e) => return Err(CliError::file(&path, e, "check permissions").into()),
        };
        let manifest: Manifest = serde_json::from_str(&text).map_err(|e| {
            CliError::file(
                &path,
                format!("not a run manifest: {e}"),
                "remove it to run every stage again",
            )
        })?;
        if manifest.version != MANIFEST_VERSION {
            return Err(CliError::file(
                &path,
                format!(
                    "manifest version {} (expected {MANIFEST_VERSION})",
                    manifest.version
                ),
                "remove it to run every stage again",
            )
            .into());
        }
        Ok(manifest)
    }

    pub fn save(&self, run_dir: &Path) -> Result<()> {
        let mut text = serde_json::to_string_pretty(self)?;
        text.push('\n');
        write_file_atomic(&run_dir.join(MANIFEST_FILE), text.as_bytes())
    }
}

/// SHA-256 of a file, or of a folder: every file below it (the rerun recording excepted:
/// its bytes are not reproducible) by relative path in sorted order, path and contents.
pub fn content_hash(path: &Path) -> Result<String> {
    let mut hasher = Sha256::new();
    let meta = fs::metadata(path).with_context(|| format!("{}: cannot read", path.display()))?;
    if meta.is_dir() {
        let mut files = Vec::new();
        list_files(path, path, &mut files)?;
        files.sort();
        for rel in files {
            hasher.update(rel.to_string_lossy().as_bytes());
            hasher.update([0]);
            hash_file(&path.join(&rel), &mut hasher)?;
        }
    } else {
        hash_file(path, &mut hasher)?;
    }
    Ok(hex(&hasher.finalize()))
}

/// SHA-256 of bytes, hex.
pub fn bytes_hash(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn hash_file(path: &Path, hasher: &mut Sha256) -> Result<()> {
    let mut file =
        fs::File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let mut buffer = vec![0u8; 1 << 16];
    loop {
        let n = file
            .read(&mut buffer)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        if n == 0 {
            return Ok(());
        }
        hasher.update(&buffer[..n]);
    }
}

fn list_files(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
    for entry in fs::read_dir(dir).with_context(|| format!("{}: cannot list", dir.display()))? {
        let entry = entry?;
        let path = entry.path();
        if entry.file_type()?.is_dir() {
            list_files(root, &path, out)?;
        } else if entry.file_name() != RECORDING_FILE {
            out.push(path.strip_prefix(root).unwrap_or(&path).to_path_buf());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folder_hash_follows_contents_and_names_not_the_recording() -> Result<()> {
        let dir = tempfile::tempdir()?;
        let root = dir.path().join("out");
        fs::create_dir_all(root.join("sub"))?;
        fs::write(root.join("a.txt"), "a")?;
        fs::write(root.join("sub/b.txt"), "b")?;
        let first = content_hash(&root)?;
        fs::write(root.join(RECORDING_FILE), "changes every run")?;
        assert_eq!(content_hash(&root)?, first);
        fs::write(root.join("sub/b.txt"), "c")?;
        assert_ne!(content_hash(&root)?, first);
        fs::write(root.join("sub/b.txt"), "b")?;
        fs::rename(root.join("a.txt"), root.join("z.txt"))?;
        assert_ne!(content_hash(&root)?, first);
        Ok(())
    }

    #[test]
    fn manifest_round_trips_and_rejects_garbage() -> Result<()> {
        let dir = tempfile::tempdir()?;
        let mut m = Manifest::load(dir.path())?;
        assert!(m.stages.is_empty());
        m.stages.insert(
            "maps".into(),
            StageRecord {
                key: "k".into(),
                settings: serde_json::json!({"a": 1}),
                inputs: BTreeMap::new(),
                outputs: BTreeMap::from([("maps/campus".into(), "h".into())]),
                seconds: 1.5,
            },
        );
        m.save(dir.path())?;
        assert_eq!(Manifest::load(dir.path())?, m);
        fs::write(dir.path().join(MANIFEST_FILE), "{")?;
        let err = Manifest::load(dir.path()).err().map(|e| e.to_string());
        assert!(err.is_some_and(|e| e.contains(MANIFEST_FILE)));
        Ok(())
    }
}
