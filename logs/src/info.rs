//! What `logs info` reports: files and sizes, storage and compression, time span, and per
//! topic the type, encoding, count, rate and whether we decode it — measured by reading every
//! message (so the figures are checked, not copied from an index), with the file's own
//! statistics compared where it has them.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::ops::ControlFlow;
use std::path::Path;

use serde::Serialize;

use super::bag::BagCompression;
use super::decode::Codec;
use super::error::{LogError, LogResult};
use super::mcap_read::McapFacts;
use super::roles::{Assignment, Role, TopicRoles};
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
    /// The decoder used for it, or why there is none; written as the decoder's name, or as
    /// `none (<why>)` ([`decoder_text`]).
    #[serde(serialize_with = "serialize_decoder")]
    pub decoder: Result<String, String>,
}

/// A topic's decoder as `logs info` says it: its name, or `none (<why>)`.
pub fn decoder_text(decoder: &Result<String, String>) -> String {
    match decoder {
        Ok(kind) => kind.clone(),
        Err(why) => format!("none ({why})"),
    }
}

fn serialize_decoder<S: serde::Serializer>(
    decoder: &Result<String, String>,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    serializer.serialize_str(&decoder_text(decoder))
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

impl LogInfo {
    /// What the reader had to skip or found inconsistent, one line each naming the log.
    pub fn reader_warnings(&self) -> Vec<String> {
        let mut out: Vec<String> = self
            .skipped_chunks
            .iter()
            .map(|r| format!("{}: skipped a chunk: {r}", self.path))
            .collect();
        if self.messages_without_channel > 0 {
            out.push(format!(
                "{}: {} messages name an undefined channel or topic and were skipped",
                self.path, self.messages_without_channel
            ));
        }
        if self.skipped_messages > 0 {
            out.push(format!(
                "{}: {} unreadable messages were skipped",
                self.path, self.skipped_messages
            ));
        }
        if self.stated_count_agrees == Some(false) {
            out.push(format!(
                "{}: the file's own message count differs from the {} messages read",
                self.path, self.message_count
            ));
        }
        out.extend(self.warnings.iter().map(|w| format!("{}: {w}", self.path)));
        out
    }
}

/// One line per role: its topic and how it was chosen.
pub fn render_roles(roles: &TopicRoles) -> String {
    let mut s = String::new();
    for (i, role) in Role::ALL.into_iter().enumerate() {
        let value = match roles.get(role) {
            Assignment::Given { topic } => format!("{topic} (given)"),
            Assignment::Detected { topic } => format!("{topic} (detected)"),
            Assignment::Ambiguous { candidates } => {
                format!("ambiguous: {} (name one)", candidates.join(", "))
            }
            Assignment::Absent => "-".into(),
        };
        let key = if i == 0 { "Topic roles:" } else { "" };
        let _ = writeln!(s, "{key:<19}{:<9} {value}", role.name());
    }
    s
}

/// The text form, laid out like `ros2 bag info` with rate and decoder added per topic.
pub fn render(info: &LogInfo) -> String {
    let mut s = String::new();
    let names: Vec<String> = info
        .files
        .iter()
        .map(|f| {
            Path::new(&f.path)
                .file_name()
                .map_or(f.path.clone(), |n| n.to_string_lossy().into_owned())
        })
        .collect();
    let label = |s: &mut String, key: &str, value: &str| {
        let _ = writeln!(s, "{:<19}{value}", format!("{key}:"));
    };
    label(&mut s, "Files", &names.join(", "));
    label(
        &mut s,
        "Bag size",
        &format!(
            "{} ({} bytes)",
            human_bytes(info.total_bytes),
            thousands(info.total_bytes)
        ),
    );
    label(&mut s, "Storage id", info.storage.label());
    if let Some(distro) = &info.ros_distro {
        label(&mut s, "ROS Distro", distro);
    }
    if let Some(profile) = &info.mcap_profile {
        let library = info.mcap_library.as_deref().unwrap_or("");
        label(
            &mut s,
            "MCAP",
            &format!("profile `{profile}`, library `{library}`"),
        );
    }
    let chunks: u64 = info.chunk_compressions.values().sum();
    let compression = if chunks > 0 {
        format!("{} ({chunks} chunks)", info.compression)
    } else {
        info.compression.clone()
    };
    label(&mut s, "Compression", &compression);
    label(
        &mut s,
        "Duration",
        &format!("{}s", seconds(info.duration_ns)),
    );
    if let (Some(start), Some(end)) = (info.start_ns, info.end_ns) {
        label(
            &mut s,
            "Start",
            &format!("{} ({})", utc(start), seconds(start)),
        );
        label(&mut s, "End", &format!("{} ({})", utc(end), seconds(end)));
    }
    label(&mut s, "Messages", &info.message_count.to_string());
    for (i, t) in info.topics.iter().enumerate() {
        let key = if i == 0 { "Topic information" } else { "" };
        let rate = t.rate_hz.map_or("-".to_owned(), |r| format!("{r:.3} Hz"));
        let decoder = decoder_text(&t.decoder);
        let _ = writeln!(
            s,
            "{:<19}Topic: {} | Type: {} | Count: {} | Serialization Format: {} | Rate: {rate} | Decoder: {decoder}",
            if key.is_empty() {
                String::new()
            } else {
                format!("{key}:")
            },
            t.name,
            t.type_name,
            t.count,
            t.encoding,
        );
    }
    if !info.metadata_records.is_empty() {
        label(&mut s, "Metadata", &info.metadata_records.join(", "));
    }
    if info.attachments > 0 {
        label(&mut s, "Attachments", &info.attachments.to_string());
    }
    s
}

fn seconds(ns: u64) -> String {
    format!("{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

fn human_bytes(bytes: u64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < units.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{value:.1} {}", units[unit])
    }
}

fn thousands(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// `May 21 2015 19:11:38.025043042 UTC`.
fn utc(ns: u64) -> String {
    const MONTHS: [&str; 12] = [
        "Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec",
    ];
    let secs = ns / 1_000_000_000;
    let (days, rem) = (secs / 86_400, secs % 86_400);
    let (year, month, day) = civil_from_days(days as i64);
    format!(
        "{} {day:02} {year} {:02}:{:02}:{:02}.{:09} UTC",
        MONTHS[(month - 1) as usize],
        rem / 3600,
        rem % 3600 / 60,
        rem % 60,
        ns % 1_000_000_000
    )
}

/// Days since 1970-01-01 to (year, month, day) in the proleptic Gregorian calendar
/// (H. Hinnant's `civil_from_days`).
fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_and_sizes() {
        assert_eq!(
            utc(1_432_235_498_025_043_042),
            "May 21 2015 19:11:38.025043042 UTC"
        );
        assert_eq!(utc(0), "Jan 01 1970 00:00:00.000000000 UTC");
        assert_eq!(
            utc(951_782_400_000_000_000),
            "Feb 29 2000 00:00:00.000000000 UTC"
        );
        assert_eq!(human_bytes(8_364_032), "8.0 MiB");
        assert_eq!(thousands(8_364_032), "8,364,032");
        assert_eq!(thousands(989), "989");
        assert_eq!(seconds(395_307_116_140), "395.307116140");
    }
}
