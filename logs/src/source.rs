//! One entry point for every log form: an MCAP file, or a ROS 2 bag (a folder with
//! `metadata.yaml`, its `metadata.yaml`, or a lone `.db3`), read as one stream of raw
//! messages in storage order.

use std::fs::File;
use std::io::Read;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::bag::{Bag, BagStorage};
use crate::error::{LogError, LogResult};
use crate::mcap_read::{McapFacts, read_mcap_file};

pub use crate::raw::{RawMessage, ReadOptions, ReadReport, Topic};

/// How a log is stored.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StorageKind {
    /// A plain MCAP file.
    Mcap,
    /// A ROS 2 bag with sqlite3 storage.
    BagSqlite3,
    /// A ROS 2 bag with MCAP storage.
    BagMcap,
}

impl StorageKind {
    pub fn label(&self) -> &'static str {
        match self {
            StorageKind::Mcap => "mcap",
            StorageKind::BagSqlite3 => "sqlite3",
            StorageKind::BagMcap => "mcap",
        }
    }
}

/// An opened log.
#[derive(Debug, Clone)]
pub enum Log {
    Mcap { path: PathBuf },
    Bag(Bag),
}

/// The first bytes of every MCAP file.
pub const MCAP_MAGIC: &[u8] = b"\x89MCAP0\r\n";

impl Log {
    /// Opens `path`: an MCAP file, a bag folder, a bag's `metadata.yaml`, or a `.db3` file.
    pub fn open(path: &Path) -> LogResult<Self> {
        let meta = std::fs::metadata(path).map_err(|e| LogError::io(path, e))?;
        if meta.is_dir() {
            return Ok(Log::Bag(Bag::open_folder(path)?));
        }
        if path.file_name().is_some_and(|n| n == "metadata.yaml") {
            let folder = path.parent().unwrap_or(Path::new("."));
            return Ok(Log::Bag(Bag::open_folder(folder)?));
        }
        let mut magic = [0u8; 16];
        let n = File::open(path)
            .and_then(|mut f| f.read(&mut magic))
            .map_err(|e| LogError::io(path, e))?;
        if magic[..n].starts_with(MCAP_MAGIC) {
            Ok(Log::Mcap {
                path: path.to_path_buf(),
            })
        } else if magic[..n].starts_with(b"SQLite format 3\0") {
            Ok(Log::Bag(Bag::open_db3(path)?))
        } else {
            Err(LogError::format(
                path,
                "neither an MCAP file nor a ROS 2 bag (no MCAP magic, not SQLite, \
                 not a folder with metadata.yaml)",
            ))
        }
    }

    /// The path the log was opened from.
    pub fn path(&self) -> &Path {
        match self {
            Log::Mcap { path } => path,
            Log::Bag(bag) => &bag.folder,
        }
    }

    pub fn storage(&self) -> StorageKind {
        match self {
            Log::Mcap { .. } => StorageKind::Mcap,
            Log::Bag(bag) => match bag.storage {
                BagStorage::Sqlite3 => StorageKind::BagSqlite3,
                BagStorage::Mcap => StorageKind::BagMcap,
            },
        }
    }

    /// The data files (one for MCAP; the bag's storage files).
    pub fn files(&self) -> Vec<PathBuf> {
        match self {
            Log::Mcap { path } => vec![path.clone()],
            Log::Bag(bag) => bag.files.clone(),
        }
    }

    /// Reads the messages that pass `options` in storage order (MCAP: file order; sqlite3:
    /// by timestamp, then row id), calling `each` for every one. MCAP facts (profile,
    /// compression, statistics) are collected into `facts` for every MCAP file read.
    pub fn read(
        &self,
        options: &ReadOptions,
        facts: &mut McapFacts,
        each: impl FnMut(&Topic, RawMessage<'_>) -> ControlFlow<()>,
    ) -> LogResult<ReadReport> {
        match self {
            Log::Mcap { path } => read_mcap_file(path, options, facts, each),
            Log::Bag(bag) => bag.read(options, facts, each),
        }
    }

    /// [`Log::read`] without the MCAP facts.
    pub fn for_each_message(
        &self,
        options: &ReadOptions,
        each: impl FnMut(&Topic, RawMessage<'_>) -> ControlFlow<()>,
    ) -> LogResult<ReadReport> {
        self.read(options, &mut McapFacts::default(), each)
    }
}
