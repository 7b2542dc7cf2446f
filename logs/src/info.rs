//! What `logs info` reports: files and sizes, storage and compression, time span, and per
//! topic the type, encoding, count, rate and whether we decode it — measured by reading every
//! message (so the figures are checked, not copied from an index), with the file's own
//! statistics compared where it has them.

use std::collections::BTreeMap;
use std::ops::ControlFlow;

use serde::Serialize;

use super::bag::BagCompression;
use super::decode::Codec;
use super::error::{LogError, LogResult};
use super::mcap_read::McapFacts;
use super::source::{Log, ReadOptions, StorageKind};

#[derive(Debug, Clone, Serialize)]
pub struct FileInfo {
    pub path: String,
    pub bytes: u64,
}

#[derive(Debug, Clone, Serialize)]
pub struct TopicInfo {
    pub name: String,
    pub type_name: String,
    /// Serialization format / message encoding (`cdr`, `ros1`, `protobuf`, `json`).
    pub encoding: String,
    pub count: u64,
    pub first_ns: Option<u64>,
    pub last_ns: Option<u64>,
    /// `(count − 1) / (last − first)`, the topic's own rate.
    pub rate_hz: Option<f64>,
    /// Payload bytes.
    pub bytes: u64,
    /// The decoder used for it, or why there is none.
    pub decoder: Result<String, String>,
}

#[derive(Debug, Clone, Serialize)]
pub struct LogInfo {
    pub path: String,
    pub storage: StorageKind,
    pub files: Vec<FileInfo>,
    pub total_bytes: u64,
    /// Compression of messages: `none`, `zstd`, `lz4` (chunks), `zstd per message`.
    pub compression: String,
    /// Chunk compression counts of MCAP files (`""` = uncompressed chunks).
    pub chunk_compressions: BTreeMap<String, u64>,
    pub mcap_profile: Option<String>,
    pub mcap_library: Option<String>,
    pub ros_distro: Option<String>,
    pub message_count: u64,
    pub start_ns: Option<u64>,
    pub end_ns: Option<u64>,
    pub duration_ns: u64,
    pub topics: Vec<TopicInfo>,
    pub metadata_records: Vec<String>,
    pub attachments: u64,
    /// Whether the file's own message count (MCAP Statistics, bag metadata) agrees with the
    /// messages read; `None` when it states none.
    pub stated_count_agrees: Option<bool>,
    pub skipped_chunks: Vec<String>,
    pub messages_without_channel: u64,
    pub skipped_messages: u64,
    pub warnings: Vec<String>,
}

#[derive(Debug, Clone, Default)]
struct Tally {
    count: u64,
    first: Option<u64>,
    last: Option<u64>,
    bytes: u64,
}

/// Reads `log` through and summarises it.
pub fn log_info(log: &Log) -> LogResult<LogInfo> {
    let mut facts = McapFacts::default();
    let mut tallies: Vec<Tally> = Vec::new();
    let options = ReadOptions {
        read_summary: true,
        ..Default::default()
    };
    let report = log.read(&options, &mut facts, |_, m| {
        if tallies.len() <= m.topic {
            tallies.resize(m.topic + 1, Tally::default());
        }
        let t = &mut tallies[m.topic];
        t.count += 1;
        t.first = Some(t.first.map_or(m.log_time, |f| f.min(m.log_time)));
        t.last = Some(t.last.map_or(m.log_time, |l| l.max(m.log_time)));
        t.bytes += m.data.len() as u64;
        ControlFlow::Continue(())
    })?;
    tallies.resize(report.topics.len(), Tally::default());

    let topics: Vec<TopicInfo> = report
        .topics
        .iter()
        .zip(&tallies)
        .map(|(topic, t)| TopicInfo {
            name: topic.name.clone(),
            type_name: topic.type_name.clone(),
            encoding: topic.encoding.clone(),
            count: t.count,
            first_ns: t.first,
            last_ns: t.last,
            rate_hz: match (t.first, t.last) {
                (Some(f), Some(l)) if l > f && t.count > 1 => {
                    Some((t.count - 1) as f64 / ((l - f) as f64 * 1e-9))
                }
                _ => None,
            },
            bytes: t.bytes,
            decoder: Codec::for_topic(topic).map(|c| format!("{:?}", c.kind())),
        })
        .collect();
    let start_ns = topics.iter().filter_map(|t| t.first_ns).min();
    let end_ns = topics.iter().filter_map(|t| t.last_ns).max();

    let mut files = Vec::new();
    for file in log.files() {
        let bytes = std::fs::metadata(&file)
            .map_err(|e| LogError::io(&file, e))?
            .len();
        files.push(FileInfo {
            path: file.display().to_string(),
            bytes,
        });
    }
    let (ros_distro, stated_count, bag_compression) = match log {
        Log::Bag(bag) => (
            bag.metadata.as_ref().and_then(|m| m.ros_distro.clone()),
            bag.metadata.as_ref().map(|m| m.message_count),
            bag.compression,
        ),
        Log::Mcap { .. } => (
            None,
            facts.statistics.as_ref().map(|s| s.message_count),
            BagCompression::None,
        ),
    };
    let compression = if bag_compression == BagCompression::ZstdPerMessage {
        "zstd per message".to_owned()
    } else {
        let used: Vec<&str> = facts
            .chunk_compressions
            .keys()
            .filter(|k| !k.is_empty())
            .map(String::as_str)
            .collect();
        if used.is_empty() {
            "none".to_owned()
        } else {
            used.join(", ")
        }
    };
    let message_count = report.messages;
    Ok(LogInfo {
        path: log.path().display().to_string(),
        storage: log.storage(),
        total_bytes: files.iter().map(|f| f.bytes).sum(),
        files,
        compression,
        chunk_compressions: facts.chunk_compressions,
        mcap_profile: (!matches!(log.storage(), StorageKind::BagSqlite3)).then_some(facts.profile),
        mcap_library: (!matches!(log.storage(), StorageKind::BagSqlite3)).then_some(facts.library),
        ros_distro,
        message_count,
        start_ns,
        end_ns,
        duration_ns: match (start_ns, end_ns) {
            (Some(s), Some(e)) => e - s,
            _ => 0,
        },
        topics,
        metadata_records: facts.metadata,
        attachments: facts.attachments,
        stated_count_agrees: stated_count.map(|c| c == message_count),
        skipped_chunks: report.skipped_chunks,
        messages_without_channel: report.messages_without_channel,
        skipped_messages: report.skipped_messages,
        warnings: report.warnings,
    })
}
