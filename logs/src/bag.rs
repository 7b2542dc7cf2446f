//! ROS 2 bags (rosbag2): a folder with `metadata.yaml` and one or more storage files, sqlite3
//! (`.db3`) or MCAP.
//!
//! `metadata.yaml` is read for the few keys a reader needs (storage, files, compression),
//! tolerating what writers vary in (QoS profiles as a string or a list, folded hashes,
//! `custom_data: null`). The sqlite3 files are opened read-only; their `topics` table names the
//! topics (with `message_definitions` giving schemas where present, schema version 4 on) and
//! `messages` holds `(topic_id, timestamp, data)` rows, read in `(timestamp, id)` order as
//! rosbag2 itself does.

use std::collections::HashMap;
use std::io::Read;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use rusqlite::{Connection, OpenFlags, OptionalExtension};
use serde::Deserialize;

use super::error::{LogError, LogResult};
use super::mcap_read::McapFacts;
use crate::mcap_read::read_mcap_file;
use crate::raw::{RawMessage, ReadOptions, ReadReport, Topic};

/// A bag's storage plugin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BagStorage {
    Sqlite3,
    Mcap,
}

/// The parts of `metadata.yaml` this reader uses.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct BagMetadata {
    #[serde(default)]
    pub version: u32,
    #[serde(default)]
    pub storage_identifier: String,
    #[serde(default)]
    pub relative_file_paths: Vec<String>,
    #[serde(default)]
    pub message_count: u64,
    #[serde(default)]
    pub compression_format: Option<String>,
    #[serde(default)]
    pub compression_mode: Option<String>,
    #[serde(default)]
    pub ros_distro: Option<String>,
    #[serde(default)]
    pub topics_with_message_count: Vec<BagTopicCount>,
}

#[derive(Debug, Clone, Default, Deserialize)]
pub struct BagTopicCount {
    #[serde(default)]
    pub message_count: u64,
    pub topic_metadata: BagTopicMetadata,
}

#[derive(Debug, Clone, Default, Deserialize)]
pub struct BagTopicMetadata {
    pub name: String,
    #[serde(rename = "type")]
    pub type_name: String,
    #[serde(default)]
    pub serialization_format: String,
}

#[derive(Debug, Deserialize)]
struct MetadataFile {
    rosbag2_bagfile_information: BagMetadata,
}

/// How messages inside a bag are compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BagCompression {
    None,
    /// Every message payload is a zstd frame (`compression_mode: MESSAGE`).
    ZstdPerMessage,
}

/// An opened ROS 2 bag.
#[derive(Debug, Clone)]
pub struct Bag {
    /// The bag folder (or the folder of a lone `.db3`).
    pub folder: PathBuf,
    /// `None` for a lone `.db3` opened without its folder's metadata.
    pub metadata: Option<BagMetadata>,
    pub storage: BagStorage,
    pub compression: BagCompression,
    /// Storage files in the order they are read.
    pub files: Vec<PathBuf>,
}

impl Bag {
    /// Opens a bag folder through its `metadata.yaml`.
    pub fn open_folder(folder: &Path) -> LogResult<Self> {
        let yaml_path = folder.join("metadata.yaml");
        let text = std::fs::read_to_string(&yaml_path).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                LogError::format(folder, "a folder without metadata.yaml is not a ROS 2 bag")
            } else {
                LogError::io(&yaml_path, e)
            }
        })?;
        let metadata = parse_metadata(&text).map_err(|m| LogError::format(&yaml_path, m))?;
        let storage = match metadata.storage_identifier.as_str() {
            "sqlite3" => BagStorage::Sqlite3,
            "mcap" => BagStorage::Mcap,
            other => {
                return Err(LogError::format(
                    &yaml_path,
                    format!("storage_identifier `{other}` is not sqlite3 or mcap"),
                ));
            }
        };
        let compression = match (
            metadata.compression_mode.as_deref().unwrap_or(""),
            metadata.compression_format.as_deref().unwrap_or(""),
        ) {
            ("" | "NONE" | "none", _) | (_, "") => BagCompression::None,
            ("MESSAGE" | "message", "zstd") => BagCompression::ZstdPerMessage,
            (mode, format) => {
                return Err(LogError::format(
                    &yaml_path,
                    format!(
                        "compression_mode {mode} with format {format} is not supported \
                         (decompress the bag with `ros2 bag convert` first)"
                    ),
                ));
            }
        };
        if metadata.relative_file_paths.is_empty() {
            return Err(LogError::format(&yaml_path, "relative_file_paths is empty"));
        }
        let mut files = Vec::new();
        for name in &metadata.relative_file_paths {
            let file = folder.join(name);
            if !file.is_file() {
                return Err(LogError::format(
                    &yaml_path,
                    format!("lists storage file {name}, which is missing"),
                ));
            }
            files.push(file);
        }
        Ok(Bag {
            folder: folder.to_path_buf(),
            metadata: Some(metadata),
            storage,
            compression,
            files,
        })
    }

    /// Opens a lone sqlite3 storage file (its topics come from the `topics` table).
    pub fn open_db3(path: &Path) -> LogResult<Self> {
        Ok(Bag {
            folder: path.parent().unwrap_or(Path::new(".")).to_path_buf(),
            metadata: None,
            storage: BagStorage::Sqlite3,
            compression: BagCompression::None,
            files: vec![path.to_path_buf()],
        })
    }

    /// Reads every storage file in turn. Topics are merged by name across files.
    pub fn read(
        &self,
        options: &ReadOptions,
        facts: &mut McapFacts,
        mut each: impl FnMut(&Topic, RawMessage<'_>) -> ControlFlow<()>,
    ) -> LogResult<ReadReport> {
        let mut total = ReadReport::default();
        let mut decompressed = Vec::new();
        for file in &self.files {
            let mut topic_index: HashMap<usize, usize> = HashMap::new();
            let mut stopped = false;
            let mut each_file = |local: &Topic, m: RawMessage<'_>| {
                let index = *topic_index
                    .entry(m.topic)
                    .or_insert_with(|| merge_topic(&mut total.topics, local));
                let data = match self.compression {
                    BagCompression::None => m.data,
                    BagCompression::ZstdPerMessage => {
                        match decompress_message(
                            m.data,
                            options.limits.max_record_bytes,
                            &mut decompressed,
                        ) {
                            Ok(()) => &decompressed[..],
                            Err(_) => {
                                total.skipped_messages += 1;
                                return ControlFlow::Continue(());
                            }
                        }
                    }
                };
                let flow = each(
                    &total.topics[index],
                    RawMessage {
                        topic: index,
                        data,
                        ..m
                    },
                );
                if flow.is_break() {
                    stopped = true;
                }
                flow
            };
            let report = match self.storage {
                BagStorage::Sqlite3 => read_db3(file, options, &mut each_file)?,
                BagStorage::Mcap => read_mcap_file(file, options, facts, &mut each_file)?,
            };
            for topic in &report.topics {
                merge_topic(&mut total.topics, topic);
            }
            total.messages += report.messages;
            total.skipped_chunks.extend(report.skipped_chunks);
            total.messages_without_channel += report.messages_without_channel;
            total.skipped_messages += report.skipped_messages;
            total.warnings.extend(report.warnings);
            if stopped {
                break;
            }
        }
        Ok(total)
    }
}

/// The index of `topic` (by name) in `topics`, adding it when new.
fn merge_topic(topics: &mut Vec<Topic>, topic: &Topic) -> usize {
    match topics.iter().position(|t| t.name == topic.name) {
        Some(i) => i,
        None => {
            topics.push(topic.clone());
            topics.len() - 1
        }
    }
}

fn decompress_message(data: &[u8], limit: usize, out: &mut Vec<u8>) -> std::io::Result<()> {
    out.clear();
    let decoder = zstd::stream::read::Decoder::new(data)?;
    decoder.take(limit as u64).read_to_end(out)?;
    Ok(())
}

/// Parses `metadata.yaml`.
pub fn parse_metadata(text: &str) -> Result<BagMetadata, String> {
    serde_norway::from_str::<MetadataFile>(text)
        .map(|m| m.rosbag2_bagfile_information)
        .map_err(|e| format!("not a rosbag2 metadata file: {e}"))
}

/// The tables a rosbag2 sqlite3 file must have.
const REQUIRED_TABLES: [&str; 2] = ["topics", "messages"];

fn open_db3(path: &Path) -> LogResult<Connection> {
    let db_error = |e: rusqlite::Error| LogError::format(path, format!("sqlite3: {e}"));
    let conn = Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(db_error)?;
    for table in REQUIRED_TABLES {
        let found: Option<String> = conn
            .query_row(
                "SELECT name FROM sqlite_master WHERE type = 'table' AND name = ?1",
                [table],
                |row| row.get(0),
            )
            .optional()
            .map_err(db_error)?;
        if found.is_none() {
            return Err(LogError::format(
                path,
                format!("not a rosbag2 sqlite3 file: table `{table}` is missing"),
            ));
        }
    }
    Ok(conn)
}

fn has_table(conn: &Connection, name: &str) -> bool {
    conn.query_row(
        "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?1",
        [name],
        |_| Ok(()),
    )
    .is_ok()
}

/// Reads the topics of a `.db3` file, in id order, with their ids.
fn read_db3_topics(conn: &Connection, path: &Path) -> LogResult<Vec<(i64, Topic)>> {
    let db_error = |e: rusqlite::Error| LogError::format(path, format!("sqlite3 topics: {e}"));
    let mut definitions: HashMap<String, (String, Vec<u8>)> = HashMap::new();
    if has_table(conn, "message_definitions") {
        let mut stmt = conn
            .prepare(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions",
            )
            .map_err(db_error)?;
        let rows = stmt
            .query_map([], |row| {
                Ok((
                    row.get::<_, String>(0)?,
                    row.get::<_, String>(1)?,
                    row.get::<_, String>(2)?,
                ))
            })
            .map_err(db_error)?;
        for row in rows {
            let (ty, encoding, text) = row.map_err(db_error)?;
            definitions.insert(ty, (encoding, text.into_bytes()));
        }
    }
    let mut stmt = conn
        .prepare("SELECT id, name, type, serialization_format FROM topics ORDER BY id")
        .map_err(db_error)?;
    let rows = stmt
        .query_map([], |row| {
            Ok((
                row.get::<_, i64>(0)?,
                row.get::<_, String>(1)?,
                row.get::<_, String>(2)?,
                row.get::<_, String>(3)?,
            ))
        })
        .map_err(db_error)?;
    let mut topics = Vec::new();
    for row in rows {
        let (id, name, type_name, encoding) = row.map_err(db_error)?;
        let (schema_encoding, schema) = definitions.get(&type_name).cloned().unwrap_or_default();
        topics.push((
            id,
            Topic {
                name,
                type_name,
                encoding,
                schema_encoding,
                schema,
                channel_id: None,
            },
        ));
    }
    Ok(topics)
}

/// Reads one `.db3` file in `(timestamp, id)` order.
fn read_db3(
    path: &Path,
    options: &ReadOptions,
    each: &mut impl FnMut(&Topic, RawMessage<'_>) -> ControlFlow<()>,
) -> LogResult<ReadReport> {
    let conn = open_db3(path)?;
    let with_ids = read_db3_topics(&conn, path)?;
    let ids: HashMap<i64, usize> = with_ids
        .iter()
        .enumerate()
        .map(|(i, (id, _))| (*id, i))
        .collect();
    let topics: Vec<Topic> = with_ids.into_iter().map(|(_, t)| t).collect();
    let mut report = ReadReport::default();
    let db_error = |e: rusqlite::Error| LogError::format(path, format!("sqlite3 messages: {e}"));
    let (start, end) = options.time_range().unwrap_or((0, u64::MAX));
    let start = i64::try_from(start).unwrap_or(i64::MAX);
    let end = i64::try_from(end).unwrap_or(i64::MAX);
    let mut stmt = conn
        .prepare(
            "SELECT topic_id, timestamp, data FROM messages \
             WHERE timestamp >= ?1 AND timestamp < ?2 ORDER BY timestamp, id",
        )
        .map_err(db_error)?;
    let mut rows = stmt.query([start, end]).map_err(db_error)?;
    while let Some(row) = rows.next().map_err(db_error)? {
        let topic_id: i64 = row.get(0).map_err(db_error)?;
        let timestamp: i64 = row.get(1).map_err(db_error)?;
        let Some(&topic) = ids.get(&topic_id) else {
            report.messages_without_channel += 1;
            continue;
        };
        let (Ok(log_time), Ok(data)) = (
            u64::try_from(timestamp),
            row.get_ref(2).map_err(db_error)?.as_blob(),
        ) else {
            report.skipped_messages += 1;
            continue;
        };
        if !options.accepts(&topics[topic].name, log_time) {
            continue;
        }
        report.messages += 1;
        let flow = each(
            &topics[topic],
            RawMessage {
                topic,
                log_time,
                publish_time: log_time,
                sequence: 0,
                data,
            },
        );
        if flow.is_break() {
            break;
        }
    }
    report.topics = topics;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metadata_with_folded_hashes_and_list_qos() -> Result<(), String> {
        let text = "rosbag2_bagfile_information:\n  compression_format: ''\n  compression_mode: ''\n  custom_data: null\n  message_count: 3\n  relative_file_paths:\n  - a.db3\n  storage_identifier: sqlite3\n  topics_with_message_count:\n  - message_count: 3\n    topic_metadata:\n      name: /fix\n      offered_qos_profiles: []\n      serialization_format: cdr\n      type: sensor_msgs/msg/NavSatFix\n      type_description_hash: \n        RIHS01_abc\n  version: 9\n";
        let m = parse_metadata(text)?;
        assert_eq!(m.storage_identifier, "sqlite3");
        assert_eq!(m.relative_file_paths, vec!["a.db3".to_owned()]);
        assert_eq!(m.topics_with_message_count[0].topic_metadata.name, "/fix");
        // Older writers give the QoS profiles as one string.
        let older = text.replace(
            "offered_qos_profiles: []",
            "offered_qos_profiles: \"- history: 3\"",
        );
        assert_eq!(parse_metadata(&older)?.message_count, 3);
        assert!(parse_metadata("just: text").is_err());
        Ok(())
    }
}
