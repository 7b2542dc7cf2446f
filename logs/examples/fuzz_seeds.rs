//! Writes the seed corpora of the two fuzz targets in `fuzz/` (see docs/logs.md, "Fuzzing"):
//!
//! - `<out>/mcap_reader/`: small MCAP files made here — three ROS 2 topics (NavSatFix, Odometry,
//!   TFMessage) and a Foxglove JSON topic, in every chunk compression, chunked and not, with
//!   and without a summary; with `--logs DIR` also the first messages of each real log
//!   re-written small, and the MCAP conformance files;
//! - `<out>/cdr_decode/`: one CDR payload of every supported ROS type (default and filled
//!   values); with `--logs DIR` also the first real payloads of each topic (CDR and ROS 1).
//!
//! The corpora are generated, not committed: the real logs stay in `../shared/data`.
//!
//! Usage: `fuzz_seeds --out fuzz/corpus [--logs ../shared/data/logs]`.

#![allow(clippy::print_stdout)]

use std::collections::BTreeMap;
use std::io::Cursor;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use logs::msgdefs::ros2msg_schema;
use logs::msgs::{self, Header, Time};
use logs::{Log, ReadOptions, Topic};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// Writes the fuzz targets' seed corpora.
#[derive(Debug, clap::Parser)]
struct Args {
    /// The corpus folder (`fuzz/corpus`): one sub-folder per target is written.
    #[arg(long)]
    out: PathBuf,
    /// The shared logs folder, for seeds cut from real logs (optional).
    #[arg(long)]
    logs: Option<PathBuf>,
    /// Messages per topic taken from each real log.
    #[arg(long, default_value_t = 6)]
    per_topic: usize,
}

/// A topic and its messages, to be written as a small MCAP.
struct Recording {
    topics: Vec<Topic>,
    /// (topic index, log time, payload).
    messages: Vec<(usize, u64, Vec<u8>)>,
}

fn header(sec: i32, frame: &str) -> Header {
    Header {
        stamp: Time {
            sec,
            nanosec: 500_000_000,
        },
        frame_id: frame.to_owned(),
    }
}

/// A CDR topic; its schema is our `ros2msg` text where we have one (readers only need the
/// type name).
fn ros_topic(name: &str, ty: &str) -> Topic {
    Topic {
        name: name.to_owned(),
        type_name: ty.to_owned(),
        encoding: "cdr".to_owned(),
        schema_encoding: "ros2msg".to_owned(),
        schema: ros2msg_schema(ty).unwrap_or_default().into_bytes(),
        channel_id: None,
    }
}

/// A recording made here: three ROS 2 topics and a Foxglove JSON one, times 1..=9.
fn synthetic() -> Result<Recording> {
    let topics = vec![
        ros_topic("/fix", "sensor_msgs/msg/NavSatFix"),
        ros_topic("/a", "nav_msgs/msg/Odometry"),
        ros_topic("/tf", "tf2_msgs/msg/TFMessage"),
        Topic {
            name: "/loc".to_owned(),
            type_name: "foxglove.LocationFix".to_owned(),
            encoding: "json".to_owned(),
            schema_encoding: "jsonschema".to_owned(),
            schema: b"{}".to_vec(),
            channel_id: None,
        },
    ];
    let mut messages = Vec::new();
    for i in 0..3u8 {
        let t = u64::from(i) * 3 + 1;
        let fix = msgs::NavSatFix {
            header: header(i.into(), "gps"),
            latitude: 42.0 + f64::from(i),
            longitude: -71.0,
            ..Default::default()
        };
        messages.push((0, t, msgs::encode(&fix)));
        let odom = msgs::Odometry {
            header: header(i.into(), "odom"),
            child_frame_id: "base_link".to_owned(),
            ..Default::default()
        };
        messages.push((1, t + 1, msgs::encode(&odom)));
        let tf = msgs::TfMessage {
            transforms: vec![msgs::TransformStamped {
                header: header(i.into(), "map"),
                child_frame_id: "base_link".to_owned(),
                ..Default::default()
            }],
        };
        messages.push((2, t + 2, msgs::encode(&tf)));
        let loc = format!(
            r#"{{"timestamp":{{"sec":{i},"nsec":0}},"frame_id":"gps","latitude":42.{i},"longitude":-71.0,"altitude":0}}"#
        );
        messages.push((3, t + 2, loc.into_bytes()));
    }
    Ok(Recording { topics, messages })
}

/// The first `per_topic` messages of every topic of a real log.
fn cut(path: &Path, per_topic: usize) -> Result<Recording> {
    let log = Log::open(path)?;
    let mut counts: BTreeMap<usize, usize> = BTreeMap::new();
    let mut messages = Vec::new();
    let report = log.for_each_message(&ReadOptions::default(), |_, m| {
        let n = counts.entry(m.topic).or_default();
        if *n < per_topic {
            *n += 1;
            messages.push((m.topic, m.log_time, m.data.to_vec()));
        }
        ControlFlow::Continue(())
    })?;
    Ok(Recording {
        topics: report.topics,
        messages,
    })
}

/// `recording` as an MCAP file.
fn write_mcap(
    recording: &Recording,
    compression: Option<mcap::Compression>,
    chunked: bool,
    summary: bool,
) -> Result<Vec<u8>> {
    let profile = if recording.topics.iter().any(|t| t.encoding == "ros1") {
        "ros1"
    } else {
        "ros2"
    };
    let mut options = mcap::WriteOptions::new()
        .profile(profile)
        .library("fuzz_seeds")
        .compression(compression)
        .use_chunks(chunked)
        // Small chunks: several per seed.
        .chunk_size(Some(512));
    if !summary {
        options = options
            .emit_summary_records(false)
            .emit_summary_offsets(false);
    }
    let mut writer = options.create(Cursor::new(Vec::new()))?;
    let mut channels = Vec::new();
    for topic in &recording.topics {
        let schema = if topic.schema_encoding.is_empty() && topic.schema.is_empty() {
            0
        } else {
            writer.add_schema(&topic.type_name, &topic.schema_encoding, &topic.schema)?
        };
        channels.push(writer.add_channel(
            schema,
            &topic.name,
            &topic.encoding,
            &BTreeMap::new(),
        )?);
    }
    for (sequence, (topic, log_time, payload)) in recording.messages.iter().enumerate() {
        writer.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: channels[*topic],
                sequence: sequence as u32,
                log_time: *log_time,
                publish_time: *log_time,
            },
            payload,
        )?;
    }
    writer.finish()?;
    Ok(writer.into_inner().into_inner())
}

fn main() -> Result<()> {
    let args: Args = clap::Parser::parse();
    let mcap_dir = args.out.join("mcap_reader");
    let cdr_dir = args.out.join("cdr_decode");
    std::fs::create_dir_all(&mcap_dir)?;
    std::fs::create_dir_all(&cdr_dir)?;
    let mut written = (0usize, 0usize);

    let mut recordings = vec![("synthetic".to_owned(), synthetic()?)];
    if let Some(logs) = &args.logs {
        for name in [
            "husky/husky.mcap",
            "husky/husky_db3",
            "other/foxglove_demo_ros1.mcap",
            "other/demo_tf_cdr/demo_tf_cdr.mcap",
        ] {
            let stem = name.replace(['/', '.'], "_");
            recordings.push((stem, cut(&logs.join(name), args.per_topic)?));
        }
    }
    let compressions = [
        ("none", None),
        ("zstd", Some(mcap::Compression::Zstd)),
        ("lz4", Some(mcap::Compression::Lz4)),
    ];
    for (stem, recording) in &recordings {
        for (label, compression) in compressions {
            for (chunked, summary) in [(true, true), (true, false), (false, true)] {
                if !chunked && compression.is_some() {
                    continue;
                }
                let bytes = write_mcap(recording, compression, chunked, summary)?;
                let name = format!(
                    "{stem}_{}_{}.mcap",
                    if chunked { label } else { "unchunked" },
                    if summary { "summary" } else { "nosummary" },
                );
                std::fs::write(mcap_dir.join(name), bytes)?;
                written.0 += 1;
            }
        }
        // CDR (and ROS 1) payloads: the first two of each topic.
        let mut per_topic: BTreeMap<usize, usize> = BTreeMap::new();
        for (topic, _, payload) in &recording.messages {
            let n = per_topic.entry(*topic).or_default();
            if *n < 2 && recording.topics[*topic].encoding != "json" {
                let t = &recording.topics[*topic];
                let name = format!(
                    "{stem}_{}_{n}.{}",
                    t.name.trim_start_matches('/').replace('/', "_"),
                    t.encoding
                );
                std::fs::write(cdr_dir.join(name), payload)?;
                written.1 += 1;
                *n += 1;
            }
        }
    }
    // Every supported ROS type, default values.
    let defaults: [(&str, Vec<u8>); 10] = [
        ("odometry", msgs::encode(&msgs::Odometry::default())),
        ("pose_stamped", msgs::encode(&msgs::PoseStamped::default())),
        (
            "pose_cov_stamped",
            msgs::encode(&msgs::PoseWithCovarianceStamped::default()),
        ),
        ("navsatfix", msgs::encode(&msgs::NavSatFix::default())),
        ("imu", msgs::encode(&msgs::Imu::default())),
        ("tf", msgs::encode(&msgs::TfMessage::default())),
        (
            "detections",
            msgs::encode(&msgs::Detection3DArray {
                header: header(1, "map"),
                detections: vec![msgs::Detection3D::default()],
            }),
        ),
        (
            "image",
            msgs::encode(&msgs::Image {
                header: header(1, "cam"),
                height: 1,
                width: 2,
                encoding: "mono8".to_owned(),
                step: 2,
                data: msgs::Bytes(vec![1, 2]),
                ..Default::default()
            }),
        ),
        (
            "compressed_image",
            msgs::encode(&msgs::CompressedImage {
                header: header(1, "cam"),
                format: "jpeg".to_owned(),
                data: msgs::Bytes(vec![0xff, 0xd8]),
            }),
        ),
        (
            "diagnostics",
            msgs::encode(&msgs::DiagnosticArray {
                header: header(1, ""),
                status: vec![msgs::DiagnosticStatus {
                    values: vec![msgs::KeyValue {
                        key: "k".to_owned(),
                        value: "v".to_owned(),
                    }],
                    ..Default::default()
                }],
            }),
        ),
    ];
    for (name, bytes) in defaults {
        std::fs::write(cdr_dir.join(format!("default_{name}.cdr")), bytes)?;
        written.1 += 1;
    }
    if let Some(logs) = &args.logs {
        let conformance = logs.join("mcap-conformance");
        for entry in std::fs::read_dir(&conformance)? {
            let dir = entry?.path();
            if !dir.is_dir() {
                continue;
            }
            for file in std::fs::read_dir(&dir)? {
                let file = file?.path();
                if file.extension().is_some_and(|e| e == "mcap") {
                    let name = file
                        .file_name()
                        .map(|n| n.to_string_lossy().into_owned())
                        .unwrap_or_default();
                    std::fs::copy(&file, mcap_dir.join(format!("conformance_{name}")))?;
                    written.0 += 1;
                }
            }
        }
    }
    println!(
        "{} MCAP seeds in {}, {} payload seeds in {}",
        written.0,
        mcap_dir.display(),
        written.1,
        cdr_dir.display()
    );
    Ok(())
}
