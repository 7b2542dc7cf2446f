//! What every log form reads into: its topics, raw messages in storage order, what to read
//! ([`ReadOptions`]) and what the read met ([`ReadReport`]).

use std::collections::BTreeSet;

use serde::Serialize;

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

/// How much a corrupt file may make the reader allocate.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Largest record (or chunk, compressed or not) accepted.
    pub max_record_bytes: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_record_bytes: 1 << 30,
        }
    }
}
