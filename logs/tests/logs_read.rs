//! The logs reader on the real recordings in `../shared/data/logs`: the Husky
//! drive and the demo TF set in all three storages, the ROS 1 original of the demo set, and
//! the MCAP conformance subset against upstream's expected records.
//!
//! Skips with a printed notice when `../shared/data` is absent.

#![allow(clippy::print_stdout, clippy::unwrap_used)]

mod common;

use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use logs::mcap_read::{McapEvent, RecordOptions, read_records};
use logs::{Decoded, DecodedLog, Log, ReadOptions, read_decoded};
use serde_json::{Value, json};

fn logs_dir() -> Option<PathBuf> {
    common::shared_data("logs")
}

fn read(path: &Path) -> DecodedLog {
    let log = Log::open(path).unwrap_or_else(|e| panic!("{e}"));
    read_decoded(&log, &ReadOptions::default()).unwrap_or_else(|e| panic!("{e}"))
}

/// The decoded stream as (topic name, log time, message JSON) triples.
fn stream(log: &DecodedLog) -> Vec<(String, u64, Value)> {
    log.messages
        .iter()
        .map(|m| {
            (
                log.topics[m.topic].name.clone(),
                m.log_time,
                serde_json::to_value(&m.message).unwrap(),
            )
        })
        .collect()
}

fn counts(log: &DecodedLog) -> BTreeMap<String, u64> {
    let mut c = BTreeMap::new();
    for m in &log.messages {
        *c.entry(log.topics[m.topic].name.clone()).or_default() += 1;
    }
    c
}

#[test]
fn husky_drive_reads_the_same_in_all_three_storages() {
    let Some(dir) = logs_dir() else { return };
    let husky = dir.join("husky");
    let summary: Value =
        serde_json::from_slice(&std::fs::read(husky.join("summary.json")).unwrap()).unwrap();
    let storages = [
        husky.join("husky.mcap"),
        husky.join("husky_db3"),
        husky.join("husky_mcap"),
    ];
    let logs: Vec<DecodedLog> = storages.iter().map(|p| read(p)).collect();
    let expected_counts = BTreeMap::from([
        ("/imu/data".to_owned(), 11_865),
        ("/husky_velocity_controller/odom".to_owned(), 3_952),
        ("/fix".to_owned(), 989),
    ]);
    for (log, path) in logs.iter().zip(&storages) {
        assert_eq!(log.messages.len(), 16_806, "{}", path.display());
        assert_eq!(counts(log), expected_counts, "{}", path.display());
        assert!(log.undecoded.is_empty(), "{:?}", log.undecoded);
        assert!(!log.report.has_skips(), "{:?}", log.report);
    }
    // Identical full decoded streams (topic, time, every field).
    let reference = stream(&logs[0]);
    for (log, path) in logs.iter().zip(&storages).skip(1) {
        let other = stream(log);
        assert_eq!(other.len(), reference.len());
        for (i, (a, b)) in reference.iter().zip(&other).enumerate() {
            assert_eq!(a, b, "message {i} differs in {}", path.display());
        }
    }
    // First and last message of every topic as summary.json has them (decoded independently
    // by mcap-ros2-support), and the per-topic time spans.
    for topic in summary["topics"].as_array().unwrap() {
        let name = topic["name"].as_str().unwrap();
        let msgs: Vec<_> = reference.iter().filter(|(t, _, _)| t == name).collect();
        assert_eq!(
            msgs.first().unwrap().2,
            topic["first_message"],
            "{name}: first"
        );
        assert_eq!(
            msgs.last().unwrap().2,
            topic["last_message"],
            "{name}: last"
        );
        assert_eq!(
            msgs.first().unwrap().1,
            topic["first_timestamp_ns"].as_u64().unwrap()
        );
        assert_eq!(
            msgs.last().unwrap().1,
            topic["last_timestamp_ns"].as_u64().unwrap()
        );
    }
    println!(
        "husky: 3 storages x {} messages, identical decoded streams",
        reference.len()
    );
}

#[test]
fn demo_tf_set_reads_the_same_in_all_storages_and_from_ros1() {
    let Some(dir) = logs_dir() else { return };
    let demo = dir.join("other/demo_tf_cdr");
    let storages = [
        demo.join("demo_tf_cdr.mcap"),
        demo.join("demo_tf_cdr_db3"),
        demo.join("demo_tf_cdr_mcap"),
        dir.join("other/foxglove_demo_ros1.mcap"),
    ];
    let logs: Vec<DecodedLog> = storages.iter().map(|p| read(p)).collect();
    let expected = BTreeMap::from([("/diagnostics".to_owned(), 52), ("/tf".to_owned(), 774)]);
    for (log, path) in logs.iter().zip(&storages) {
        assert_eq!(counts(log), expected, "{}", path.display());
        assert!(log.undecoded.is_empty(), "{:?}", log.undecoded);
    }
    let reference = stream(&logs[0]);
    for (log, path) in logs.iter().zip(&storages).skip(1) {
        assert_eq!(stream(log), reference, "{}", path.display());
    }
    // The first /tf: base_link -> radar, translation (3.835, 0, 0).
    let (_, _, first_tf) = reference.iter().find(|(t, _, _)| t == "/tf").unwrap();
    let transform = &first_tf["transforms"][0];
    assert_eq!(transform["header"]["frame_id"], "base_link");
    assert_eq!(transform["child_frame_id"], "radar");
    assert_eq!(transform["transform"]["translation"]["x"], 3.835);
    assert_eq!(
        transform["header"]["stamp"],
        json!({"sec": 1490149580, "nanosec": 117017840})
    );
    // Ties in log time keep storage order in every storage (74 such messages).
    let ties = reference.windows(2).filter(|w| w[0].1 == w[1].1).count();
    assert_eq!(ties, 74);
    let first = logs[0].messages.first().unwrap();
    assert!(matches!(first.message, Decoded::DiagnosticArray(_)));
}

/// Our records of one conformance file in upstream's JSON form.
fn conformance_records(path: &Path) -> Vec<Value> {
    let bytes = std::fs::read(path).unwrap();
    let mut out = Vec::new();
    read_records(
        &bytes[..],
        bytes.len() as u64,
        path,
        &RecordOptions::default(),
        |event| {
            if let McapEvent::Record { record, .. } = event {
                out.push(record_json(&record));
            }
            ControlFlow::Continue(())
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    out
}

fn n(v: impl std::fmt::Display) -> Value {
    Value::String(v.to_string())
}

fn bytes_json(b: &[u8]) -> Value {
    Value::Array(b.iter().map(n).collect())
}

fn map_json<K: std::fmt::Display, V: std::fmt::Display>(m: &BTreeMap<K, V>) -> Value {
    Value::Object(m.iter().map(|(k, v)| (k.to_string(), n(v))).collect())
}

/// Upstream's record form: type plus fields sorted by name, integers as strings.
fn record_json(record: &mcap::records::Record<'_>) -> Value {
    use mcap::records::Record;
    let (ty, mut fields): (&str, Vec<(&str, Value)>) = match record {
        Record::Header(h) => (
            "Header",
            vec![("library", n(&h.library)), ("profile", n(&h.profile))],
        ),
        Record::Footer(f) => (
            "Footer",
            vec![
                ("summary_crc", n(f.summary_crc)),
                ("summary_offset_start", n(f.summary_offset_start)),
                ("summary_start", n(f.summary_start)),
            ],
        ),
        Record::Schema { header, data } => (
            "Schema",
            vec![
                ("data", bytes_json(data)),
                ("encoding", n(&header.encoding)),
                ("id", n(header.id)),
                ("name", n(&header.name)),
            ],
        ),
        Record::Channel(c) => (
            "Channel",
            vec![
                ("id", n(c.id)),
                ("message_encoding", n(&c.message_encoding)),
                ("metadata", map_json(&c.metadata)),
                ("schema_id", n(c.schema_id)),
                ("topic", n(&c.topic)),
            ],
        ),
        Record::Message { header, data } => (
            "Message",
            vec![
                ("channel_id", n(header.channel_id)),
                ("data", bytes_json(data)),
                ("log_time", n(header.log_time)),
                ("publish_time", n(header.publish_time)),
                ("sequence", n(header.sequence)),
            ],
        ),
        Record::ChunkIndex(c) => (
            "ChunkIndex",
            vec![
                ("chunk_length", n(c.chunk_length)),
                ("chunk_start_offset", n(c.chunk_start_offset)),
                ("compressed_size", n(c.compressed_size)),
                ("compression", n(&c.compression)),
                ("message_end_time", n(c.message_end_time)),
                ("message_index_length", n(c.message_index_length)),
                ("message_index_offsets", map_json(&c.message_index_offsets)),
                ("message_start_time", n(c.message_start_time)),
                ("uncompressed_size", n(c.uncompressed_size)),
            ],
        ),
        Record::Attachment { header, data, .. } => (
            "Attachment",
            vec![
                ("create_time", n(header.create_time)),
                ("data", bytes_json(data)),
                ("log_time", n(header.log_time)),
                ("media_type", n(&header.media_type)),
                ("name", n(&header.name)),
            ],
        ),
        Record::AttachmentIndex(a) => (
            "AttachmentIndex",
            vec![
                ("create_time", n(a.create_time)),
                ("data_size", n(a.data_size)),
                ("length", n(a.length)),
                ("log_time", n(a.log_time)),
                ("media_type", n(&a.media_type)),
                ("name", n(&a.name)),
                ("offset", n(a.offset)),
            ],
        ),
        Record::Statistics(s) => (
            "Statistics",
            vec![
                ("attachment_count", n(s.attachment_count)),
                ("channel_count", n(s.channel_count)),
                (
                    "channel_message_counts",
                    map_json(&s.channel_message_counts),
                ),
                ("chunk_count", n(s.chunk_count)),
                ("message_count", n(s.message_count)),
                ("message_end_time", n(s.message_end_time)),
                ("message_start_time", n(s.message_start_time)),
                ("metadata_count", n(s.metadata_count)),
                ("schema_count", n(s.schema_count)),
            ],
        ),
        Record::Metadata(m) => (
            "Metadata",
            vec![("metadata", map_json(&m.metadata)), ("name", n(&m.name))],
        ),
        Record::MetadataIndex(m) => (
            "MetadataIndex",
            vec![
                ("length", n(m.length)),
                ("name", n(&m.name)),
                ("offset", n(m.offset)),
            ],
        ),
        Record::SummaryOffset(s) => (
            "SummaryOffset",
            vec![
                ("group_length", n(s.group_length)),
                ("group_opcode", n(s.group_opcode)),
                ("group_start", n(s.group_start)),
            ],
        ),
        Record::DataEnd(d) => ("DataEnd", vec![("data_section_crc", n(d.data_section_crc))]),
        other => ("unexpected", vec![("opcode", n(other.opcode()))]),
    };
    fields.sort_by(|a, b| a.0.cmp(b.0));
    json!({
        "type": ty,
        "fields": fields.into_iter().map(|(k, v)| json!([k, v])).collect::<Vec<_>>(),
    })
}

#[test]
fn conformance_subset_matches_the_expected_records() {
    let Some(dir) = logs_dir() else { return };
    let root = dir.join("mcap-conformance");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .flat_map(|d| std::fs::read_dir(d.unwrap().path()).into_iter().flatten())
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    files.sort();
    assert_eq!(files.len(), 76);
    let mut messages_checked = 0;
    for mcap_path in &files {
        let expected: Value =
            serde_json::from_slice(&std::fs::read(mcap_path.with_extension("json")).unwrap())
                .unwrap();
        let ours = conformance_records(mcap_path);
        assert_eq!(
            Value::Array(ours),
            expected["records"],
            "{}",
            mcap_path.display()
        );
        // The message layer yields the same messages, in file order.
        let expected_messages: Vec<(u64, Vec<u8>)> = expected["records"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|r| r["type"] == "Message")
            .map(|r| {
                let f: BTreeMap<&str, &Value> = r["fields"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|kv| (kv[0].as_str().unwrap(), &kv[1]))
                    .collect();
                let data = f["data"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|b| b.as_str().unwrap().parse().unwrap())
                    .collect();
                (f["log_time"].as_str().unwrap().parse().unwrap(), data)
            })
            .collect();
        let log = Log::open(mcap_path).unwrap();
        let mut got = Vec::new();
        log.for_each_message(&ReadOptions::default(), |_, m| {
            got.push((m.log_time, m.data.to_vec()));
            ControlFlow::Continue(())
        })
        .unwrap();
        assert_eq!(got, expected_messages, "{}", mcap_path.display());
        messages_checked += got.len();
    }
    println!(
        "conformance: {} files, {messages_checked} messages",
        files.len()
    );
}

#[test]
fn time_range_and_topic_filters() {
    let Some(dir) = logs_dir() else { return };
    for storage in ["husky.mcap", "husky_db3", "husky_mcap"] {
        let log = Log::open(&dir.join("husky").join(storage)).unwrap();
        let start = 1_432_235_600_000_000_000;
        let end = 1_432_235_700_000_000_000;
        let options = ReadOptions {
            start_ns: Some(start),
            end_ns: Some(end),
            topics: Some(["/fix".to_owned()].into()),
            ..Default::default()
        };
        let mut times = Vec::new();
        log.for_each_message(&options, |t, m| {
            assert_eq!(t.name, "/fix");
            times.push(m.log_time);
            ControlFlow::Continue(())
        })
        .unwrap();
        // 2.5 Hz over 100 s.
        assert!(
            (245..=255).contains(&times.len()),
            "{storage}: {}",
            times.len()
        );
        assert!(times.iter().all(|t| (start..end).contains(t)));
    }
}
