//! One entry point for every log form: an MCAP file, or a ROS 2 bag (a folder with
//! `metadata.yaml`, its `metadata.yaml`, or a lone `.db3`), read as one stream of raw
//! messages in storage order.

use std::collections::BTreeSet;
use std::fs::File;
use std::io::Read;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::bag::{Bag, BagStorage};
use super::error::{LogError, LogResult};
use super::mcap_read::{self, Limits, McapFacts};

/// One topic (MCAP channel, rosbag2 topic).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Topic {
    pub name: String,
    /// Message type as the log names it (`nav_msgs/msg/Odometry`, `foxglove.LocationFix`).
    pub type_name: String,
    /// Message encoding: `cdr`, `ros1`, `protobuf`, `json`.
    pub encoding: String,
    /// Schema encoding (`ros2msg`, `ros1msg`, `protobuf`, `jsonschema`), empty if none.
    pub schema_encoding: String,
    /// The schema (message definition) bytes, empty if none.
    #[serde(skip)]
    pub schema: Vec<u8>,
    /// The MCAP channel id, for MCAP sources.
    pub channel_id: Option<u16>,
}

/// One message as stored: the payload is not decoded.
#[derive(Debug, Clone, Copy)]
pub struct RawMessage<'a> {
    /// Index into the read's topic list ([`ReadReport::topics`]).
    pub topic: usize,
    /// Receive time, nanoseconds since the epoch (MCAP `log_time`, rosbag2 `timestamp`).
    pub log_time: u64,
    pub publish_time: u64,
    pub sequence: u32,
    pub data: &'a [u8],
}

/// Which messages to read.
#[derive(Debug, Clone, Default)]
pub struct ReadOptions {
    /// Only messages with `log_time >= start_ns`.
    pub start_ns: Option<u64>,
    /// Only messages with `log_time < end_ns`.
    pub end_ns: Option<u64>,
    /// Only these topics (all when `None`).
    pub topics: Option<BTreeSet<String>>,
    pub limits: Limits,
    /// Also read an MCAP file's summary section (statistics, footer), not only its data.
    pub read_summary: bool,
}

impl ReadOptions {
    pub fn time_range(&self) -> Option<(u64, u64)> {
        if self.start_ns.is_none() && self.end_ns.is_none() {
            None
        } else {
            Some((self.start_ns.unwrap_or(0), self.end_ns.unwrap_or(u64::MAX)))
        }
    }

    pub fn accepts(&self, topic: &str, log_time: u64) -> bool {
        self.start_ns.is_none_or(|s| log_time >= s)
            && self.end_ns.is_none_or(|e| log_time < e)
            && self.topics.as_ref().is_none_or(|t| t.contains(topic))
    }
}

/// What a read found besides the messages it passed on.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ReadReport {
    /// Every topic of the log (also those without messages in the range).
    pub topics: Vec<Topic>,
    /// Messages passed on.
    pub messages: u64,
    /// Chunks dropped whole, with the reason for each (bad CRC, broken compression...).
    pub skipped_chunks: Vec<String>,
    /// Messages whose channel or topic id is not defined.
    pub messages_without_channel: u64,
    /// Messages dropped for another reason (e.g. a NULL payload in a `.db3`).
    pub skipped_messages: u64,
    pub warnings: Vec<String>,
}

impl ReadReport {
    /// True if something was dropped (the read is not complete).
    pub fn has_skips(&self) -> bool {
        !self.skipped_chunks.is_empty()
            || self.messages_without_channel > 0
            || self.skipped_messages > 0
    }
}

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

/// Reads one MCAP file from disk.
pub fn read_mcap_file(
    path: &Path,
    options: &ReadOptions,
    facts: &mut McapFacts,
    each: impl FnMut(&Topic, RawMessage<'_>) -> ControlFlow<()>,
) -> LogResult<ReadReport> {
    let file = File::open(path).map_err(|e| LogError::io(path, e))?;
    let len = file.metadata().map_err(|e| LogError::io(path, e))?.len();
    mcap_read::read_messages(file, len, path, options, facts, each)
}
