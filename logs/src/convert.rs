//! INTERACTION track files into MCAP logs with standard ROS 2 messages, so drone-recorded
//! traffic reads like any other log (ros2 bag, Foxglove, the Python `mcap` readers, ours).
//!
//! Topics (all in frame `map`, the Lanelet2 map's UTM-with-origin frame the tracks use):
//! - `/objects` — `vision_msgs/msg/Detection3DArray`, one per frame: every vehicle with its
//!   box centre and heading, size (length, width; height 0: the dataset has none), class
//!   `agent_type` and the track id as the detection `id`;
//! - `/objects/odom` — `nav_msgs/msg/Odometry`, one per vehicle and frame: pose, and the
//!   velocity in the vehicle frame (x forward, y left) as ROS requires; `child_frame_id` is
//!   the track id. Detection3D has no velocity field, hence this topic;
//! - `/ego/odom` and `/ego/fix` (with `--ego`): the chosen vehicle's odometry (child frame
//!   `base_link`) and a GPS fix made by unprojecting its position through the map projection.
//!
//! Log times are `timestamp_ms` since the recording start (the dataset has no absolute
//! times). A `Metadata` record `interaction` names the source files, the ego and the
//! projection. Output is byte-identical for the same input (single-threaded compression).

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use maps::{Point as MapPoint, Projection};
use serde::Serialize;

use super::error::{LogError, LogResult};
use super::interaction::{TrackFile, TrackRow};
use super::msgdefs::ros2msg_schema;
use super::msgs::{
    self, BoundingBox3D, Detection3D, Detection3DArray, Header, NavSatFix, NavSatStatus,
    ObjectHypothesis, ObjectHypothesisWithPose, Odometry, Point, Pose, PoseWithCovariance,
    Quaternion, Time, Twist, TwistWithCovariance, Vector3,
};

/// Topic names the converter writes.
pub const OBJECTS_TOPIC: &str = "/objects";
pub const OBJECTS_ODOM_TOPIC: &str = "/objects/odom";
pub const EGO_ODOM_TOPIC: &str = "/ego/odom";
pub const EGO_FIX_TOPIC: &str = "/ego/fix";
/// The frame every pose is in.
pub const MAP_FRAME: &str = "map";

/// MCAP chunk compression.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChunkCompression {
    Zstd,
    Lz4,
    None,
}

/// What to write.
#[derive(Debug, Clone)]
pub struct ConvertConfig {
    /// Track id written as the ego.
    pub ego: Option<u32>,
    pub compression: ChunkCompression,
    /// Target uncompressed chunk size, bytes.
    pub chunk_size: u64,
    /// Names recorded in the `interaction` metadata record (source track file, map file).
    pub source_name: String,
    pub map_name: String,
}

impl Default for ConvertConfig {
    fn default() -> Self {
        ConvertConfig {
            ego: None,
            compression: ChunkCompression::Zstd,
            chunk_size: 1 << 20,
            source_name: String::new(),
            map_name: String::new(),
        }
    }
}

/// Counts of what was written.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct ConvertSummary {
    pub frames: u64,
    pub tracks: u64,
    pub detections: u64,
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
    pub first_ns: u64,
    pub last_ns: u64,
}

fn write_error(e: mcap::McapError) -> LogError {
    LogError::Config(format!("writing MCAP: {e}"))
}

fn stamp(row: &TrackRow) -> (u64, Header) {
    let ns = row.timestamp_ms.saturating_mul(1_000_000);
    let header = Header {
        stamp: Time::from_nanos(i64::try_from(ns).unwrap_or(i64::MAX)),
        frame_id: MAP_FRAME.to_owned(),
    };
    (ns, header)
}

fn pose(row: &TrackRow) -> Pose {
    Pose {
        position: Point {
            x: row.x,
            y: row.y,
            z: 0.0,
        },
        orientation: Quaternion::from_yaw(row.psi_rad),
    }
}

/// The row's odometry: pose in the map frame, velocity turned into the vehicle frame.
pub fn odometry(row: &TrackRow, child_frame_id: &str) -> Odometry {
    let (_, header) = stamp(row);
    let (s, c) = row.psi_rad.sin_cos();
    Odometry {
        header,
        child_frame_id: child_frame_id.to_owned(),
        pose: PoseWithCovariance {
            pose: pose(row),
            ..Default::default()
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: Vector3 {
                    x: row.vx * c + row.vy * s,
                    y: -row.vx * s + row.vy * c,
                    z: 0.0,
                },
                angular: Vector3::default(),
            },
            ..Default::default()
        },
    }
}

fn detection(row: &TrackRow) -> Detection3D {
    let (_, header) = stamp(row);
    Detection3D {
        header,
        results: vec![ObjectHypothesisWithPose {
            hypothesis: ObjectHypothesis {
                class_id: row.agent_type.clone(),
                score: 1.0,
            },
            pose: PoseWithCovariance {
                pose: pose(row),
                ..Default::default()
            },
        }],
        bbox: BoundingBox3D {
            center: pose(row),
            size: Vector3 {
                x: row.length,
                y: row.width,
                z: 0.0,
            },
        },
        id: row.track_id.to_string(),
    }
}

fn gps_fix(row: &TrackRow, projection: &maps::projection::Projector) -> NavSatFix {
    let (_, header) = stamp(row);
    let ll = projection.unproject(MapPoint::new(row.x, row.y));
    NavSatFix {
        header: Header {
            frame_id: "gps".to_owned(),
            ..header
        },
        // STATUS_FIX, SERVICE_GPS; covariance unknown.
        status: NavSatStatus {
            status: 0,
            service: 1,
        },
        latitude: ll.lat,
        longitude: ll.lon,
        altitude: 0.0,
        position_covariance: msgs::Array::default(),
        position_covariance_type: 0,
    }
}

struct Channels {
    ids: BTreeMap<&'static str, u16>,
    sequences: BTreeMap<u16, u32>,
}

impl Channels {
    fn add<W: Write + Seek>(
        writer: &mut mcap::Writer<W>,
        topics: &[(&'static str, &str)],
    ) -> LogResult<Self> {
        let mut ids = BTreeMap::new();
        for (topic, ty) in topics {
            let schema = ros2msg_schema(ty)
                .ok_or_else(|| LogError::Config(format!("no message definition for {ty}")))?;
            let schema_id = writer
                .add_schema(ty, "ros2msg", schema.as_bytes())
                .map_err(write_error)?;
            let channel = writer
                .add_channel(schema_id, topic, "cdr", &BTreeMap::new())
                .map_err(write_error)?;
            ids.insert(*topic, channel);
        }
        Ok(Channels {
            ids,
            sequences: BTreeMap::new(),
        })
    }

    fn write<W: Write + Seek>(
        &mut self,
        writer: &mut mcap::Writer<W>,
        summary: &mut ConvertSummary,
        topic: &'static str,
        log_time: u64,
        payload: &[u8],
    ) -> LogResult<()> {
        let channel_id = self.ids[topic];
        let sequence = self.sequences.entry(channel_id).or_insert(0);
        writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id,
                    sequence: *sequence,
                    log_time,
                    publish_time: log_time,
                },
                payload,
            )
            .map_err(write_error)?;
        *sequence += 1;
        *summary.messages.entry(topic.to_owned()).or_default() += 1;
        Ok(())
    }
}

/// Writes `tracks` as an MCAP log into `out`. `projection` is the map's (for the GPS fixes and
/// the metadata); the track positions are already in its frame.
pub fn interaction_to_mcap<W: Write + Seek>(
    tracks: &TrackFile,
    projection: &Projection,
    config: &ConvertConfig,
    out: W,
) -> LogResult<ConvertSummary> {
    if let Some(ego) = config.ego
        && !tracks.rows.iter().any(|r| r.track_id == ego)
    {
        return Err(LogError::Config(format!(
            "track {ego} is not in the track file (it has {} tracks, ids {}..={})",
            tracks.track_ids().len(),
            tracks.track_ids().first().copied().unwrap_or(0),
            tracks.track_ids().last().copied().unwrap_or(0),
        )));
    }
    let options = mcap::WriteOptions::new()
        .profile("ros2")
        .library(format!(
            "pipeline logs convert (mcap-rust {})",
            mcap::VERSION
        ))
        .compression(match config.compression {
            ChunkCompression::Zstd => Some(mcap::Compression::Zstd),
            ChunkCompression::Lz4 => Some(mcap::Compression::Lz4),
            ChunkCompression::None => None,
        })
        .compression_threads(0)
        .chunk_size(Some(config.chunk_size));
    let mut writer = options.create(out).map_err(write_error)?;

    let mut topics = vec![
        (OBJECTS_TOPIC, "vision_msgs/msg/Detection3DArray"),
        (OBJECTS_ODOM_TOPIC, "nav_msgs/msg/Odometry"),
    ];
    if config.ego.is_some() {
        topics.push((EGO_ODOM_TOPIC, "nav_msgs/msg/Odometry"));
        topics.push((EGO_FIX_TOPIC, "sensor_msgs/msg/NavSatFix"));
    }
    let mut channels = Channels::add(&mut writer, &topics)?;
    let projector = projection.projector();
    let mut summary = ConvertSummary {
        tracks: tracks.track_ids().len() as u64,
        ..Default::default()
    };

    for (index, rows) in tracks.frames().values().enumerate() {
        let first = &tracks.rows[rows[0]];
        let (ns, header) = stamp(first);
        if index == 0 {
            summary.first_ns = ns;
        }
        summary.last_ns = ns;
        summary.frames += 1;
        let array = Detection3DArray {
            header,
            detections: rows.iter().map(|&i| detection(&tracks.rows[i])).collect(),
        };
        summary.detections += array.detections.len() as u64;
        channels.write(
            &mut writer,
            &mut summary,
            OBJECTS_TOPIC,
            ns,
            &msgs::encode(&array),
        )?;
        for &i in rows {
            let row = &tracks.rows[i];
            let odom = odometry(row, &row.track_id.to_string());
            channels.write(
                &mut writer,
                &mut summary,
                OBJECTS_ODOM_TOPIC,
                ns,
                &msgs::encode(&odom),
            )?;
            if config.ego == Some(row.track_id) {
                let ego = odometry(row, "base_link");
                channels.write(
                    &mut writer,
                    &mut summary,
                    EGO_ODOM_TOPIC,
                    ns,
                    &msgs::encode(&ego),
                )?;
                let fix = gps_fix(row, &projector);
                channels.write(
                    &mut writer,
                    &mut summary,
                    EGO_FIX_TOPIC,
                    ns,
                    &msgs::encode(&fix),
                )?;
            }
        }
    }

    let origin = projection.origin();
    let mut metadata = BTreeMap::from([
        ("source".to_owned(), config.source_name.clone()),
        ("map".to_owned(), config.map_name.clone()),
        ("frame".to_owned(), MAP_FRAME.to_owned()),
        ("origin_lat".to_owned(), origin.lat.to_string()),
        ("origin_lon".to_owned(), origin.lon.to_string()),
        (
            "ego_track_id".to_owned(),
            config.ego.map_or(String::new(), |e| e.to_string()),
        ),
        (
            "log_time".to_owned(),
            "timestamp_ms since the recording start".to_owned(),
        ),
    ]);
    match projection {
        Projection::Utm { zone, .. } => {
            metadata.insert(
                "projection".to_owned(),
                format!("utm zone {zone} minus origin"),
            );
        }
        Projection::Local { .. } => {
            metadata.insert(
                "projection".to_owned(),
                "local transverse mercator".to_owned(),
            );
        }
    }
    writer
        .write_metadata(&mcap::records::Metadata {
            name: "interaction".to_owned(),
            metadata,
        })
        .map_err(write_error)?;
    writer.finish().map_err(write_error)?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use std::io::Cursor;
    use std::ops::ControlFlow;
    use std::path::Path;

    use super::*;
    use crate::decode::{Codec, Decoded};
    use crate::interaction::parse_tracks;
    use crate::mcap_read::{McapFacts, read_messages};
    use crate::source::ReadOptions;

    const TRACKS: &str = "track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,psi_rad,length,width\n\
        1,1,100,car,1000.0,990.0,0,2,1.5707963267948966,4.5,1.8\n\
        1,2,200,car,1000.0,990.2,0,2,1.5707963267948966,4.5,1.8\n\
        2,2,200,car,1010.0,995.0,-3,0,3.141592653589793,5.0,2.0\n";

    fn convert(ego: Option<u32>) -> (Vec<u8>, ConvertSummary) {
        let tracks = parse_tracks(TRACKS).unwrap_or_default();
        let projection = Projection::utm(maps::LatLon::new(0.0, 0.0));
        let config = ConvertConfig {
            ego,
            ..Default::default()
        };
        let mut out = Cursor::new(Vec::new());
        let summary = interaction_to_mcap(&tracks, &projection, &config, &mut out)
            .unwrap_or_else(|e| panic!("{e}"));
        (out.into_inner(), summary)
    }

    #[test]
    fn converted_tracks_read_back() -> LogResult<()> {
        let (bytes, summary) = convert(Some(1));
        assert_eq!(
            (summary.frames, summary.tracks, summary.detections),
            (2, 2, 3)
        );
        let mut facts = McapFacts::default();
        let mut decoded = Vec::new();
        read_messages(
            &bytes[..],
            bytes.len() as u64,
            Path::new("t.mcap"),
            &ReadOptions::default(),
            &mut facts,
            |topic, m| {
                let codec = Codec::for_topic(topic).unwrap_or_else(|e| panic!("{e}"));
                decoded.push((topic.name.clone(), m.log_time, codec.decode(m.data).ok()));
                ControlFlow::Continue(())
            },
        )?;
        assert_eq!(facts.profile, "ros2");
        assert_eq!(decoded.len(), 2 + 3 + 2 + 2);
        let Some((_, t, Some(Decoded::Detection3DArray(frame2)))) =
            decoded.iter().filter(|d| d.0 == OBJECTS_TOPIC).nth(1)
        else {
            panic!("no frame 2")
        };
        assert_eq!(*t, 200_000_000);
        let ids: Vec<&str> = frame2.detections.iter().map(|d| d.id.as_str()).collect();
        assert_eq!(ids, ["1", "2"]);
        assert_eq!(frame2.detections[1].bbox.size.x, 5.0);
        assert!(
            (frame2.detections[1].bbox.center.orientation.yaw().abs() - std::f64::consts::PI).abs()
                < 1e-12
        );
        // Vehicle 2 drives at 3 m/s along its heading (-x in the map): +3 forward.
        let Some((_, _, Some(Decoded::Odometry(odom)))) =
            decoded.iter().filter(|d| d.0 == OBJECTS_ODOM_TOPIC).nth(2)
        else {
            panic!("no odometry")
        };
        assert_eq!(odom.child_frame_id, "2");
        assert!((odom.twist.twist.linear.x - 3.0).abs() < 1e-12);
        assert!(odom.twist.twist.linear.y.abs() < 1e-12);
        // The ego's GPS fix projects back onto its map position.
        let Some((_, _, Some(Decoded::NavSatFix(fix)))) =
            decoded.iter().find(|d| d.0 == EGO_FIX_TOPIC)
        else {
            panic!("no fix")
        };
        let back = Projection::utm(maps::LatLon::new(0.0, 0.0))
            .project(maps::LatLon::new(fix.latitude, fix.longitude));
        assert!((back.x - 1000.0).abs() < 1e-6 && (back.y - 990.0).abs() < 1e-6);
        Ok(())
    }

    #[test]
    fn same_input_same_bytes_and_unknown_ego_is_an_error() {
        assert_eq!(convert(None).0, convert(None).0);
        let tracks = parse_tracks(TRACKS).unwrap_or_default();
        let config = ConvertConfig {
            ego: Some(9),
            ..Default::default()
        };
        let projection = Projection::utm(maps::LatLon::new(0.0, 0.0));
        assert!(
            interaction_to_mcap(&tracks, &projection, &config, Cursor::new(Vec::new())).is_err()
        );
    }
}
