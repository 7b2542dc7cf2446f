//! Between simulated scenes and logs: scene frames written as tracks (so a simulated drive
//! becomes a log like a recorded one, through [`super::convert`]), and logged object
//! detections turned back into scene actors (the first step of projecting a log into the
//! bird's-eye representation).

use sim::{Actor, ActorKind};

use super::interaction::{TrackFile, TrackRow};
use super::msgs::Detection3DArray;

/// The road users of one simulated instant.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneFrame {
    /// Seconds since the start of the drive.
    pub time_s: f64,
    pub actors: Vec<Actor>,
}

/// Agent type written for each actor kind (INTERACTION's `agent_type` column).
fn agent_type(kind: ActorKind) -> &'static str {
    match kind {
        ActorKind::Car => "car",
        ActorKind::Pedestrian => "pedestrian/bicycle",
    }
}

/// One track row per actor per frame, frames numbered from 1 as INTERACTION does; times
/// rounded to the millisecond.
pub fn tracks_from_scene_frames(frames: &[SceneFrame]) -> TrackFile {
    let mut rows = Vec::new();
    for (index, frame) in frames.iter().enumerate() {
        let timestamp_ms = (frame.time_s * 1000.0).round().max(0.0) as u64;
        for a in &frame.actors {
            let (s, c) = a.heading_rad.sin_cos();
            rows.push(TrackRow {
                track_id: a.id,
                frame_id: index as u32 + 1,
                timestamp_ms,
                agent_type: agent_type(a.kind).to_owned(),
                x: a.position.x,
                y: a.position.y,
                vx: a.speed_mps * c,
                vy: a.speed_mps * s,
                psi_rad: a.heading_rad,
                length: a.length_m,
                width: a.width_m,
            });
        }
    }
    TrackFile {
        rows,
        skipped: Vec::new(),
    }
}

/// The actors of a logged detection array: footprint centre, heading and size from the
/// bounding box, id from the tracking id (detections without a numeric id get ids after
/// the largest one seen, in order). Speed is unknown to a detection (0 here; the log's
/// object odometry carries it).
pub fn actors_from_detections(array: &Detection3DArray) -> Vec<Actor> {
    let mut next_id = array
        .detections
        .iter()
        .filter_map(|d| d.id.parse::<u32>().ok())
        .max()
        .map_or(0, |m| m.saturating_add(1));
    array
        .detections
        .iter()
        .map(|d| {
            let id = d.id.parse::<u32>().unwrap_or_else(|_| {
                next_id = next_id.saturating_add(1);
                next_id - 1
            });
            let pedestrian = d
                .results
                .iter()
                .any(|r| r.hypothesis.class_id.contains("pedestrian"));
            let centre = &d.bbox.center;
            Actor {
                id,
                kind: if pedestrian {
                    ActorKind::Pedestrian
                } else {
                    ActorKind::Car
                },
                position: maps::geometry::Point::new(centre.position.x, centre.position.y),
                heading_rad: centre.orientation.yaw(),
                speed_mps: 0.0,
                length_m: d.bbox.size.x,
                width_m: d.bbox.size.y,
                lane: None,
                aggressiveness: None,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::convert::{ConvertConfig, interaction_to_mcap};
    use crate::decode::{Decoded, read_decoded};
    use crate::source::{Log, ReadOptions};

    fn car(id: u32, x: f64, y: f64, heading_rad: f64) -> Actor {
        Actor {
            id,
            kind: ActorKind::Car,
            position: maps::geometry::Point::new(x, y),
            heading_rad,
            speed_mps: 4.0,
            length_m: 4.6,
            width_m: 1.9,
            lane: None,
            aggressiveness: None,
        }
    }

    /// Scene frames written as MCAP and read back give the same footprints.
    #[test]
    fn scene_frames_round_trip_through_mcap() -> Result<(), Box<dyn std::error::Error>> {
        let frames: Vec<SceneFrame> = (0..5)
            .map(|i| SceneFrame {
                time_s: f64::from(i) * 0.1,
                actors: vec![
                    car(3, 1.0 + f64::from(i), -2.0, 0.3),
                    car(7, -5.0, 4.0 - f64::from(i), -1.2),
                ],
            })
            .collect();
        let tracks = tracks_from_scene_frames(&frames);
        assert_eq!(tracks.rows.len(), 10);
        let dir = tempfile::tempdir()?;
        let path = dir.path().join("sim.mcap");
        let projection = maps::Projection::local(maps::LatLon::new(47.6, -122.3));
        let config = ConvertConfig {
            ego: Some(3),
            ..Default::default()
        };
        let summary =
            interaction_to_mcap(&tracks, &projection, &config, std::fs::File::create(&path)?)?;
        assert_eq!(summary.frames, 5);
        let log = read_decoded(&Log::open(&path)?, &ReadOptions::default())?;
        let arrays: Vec<_> = log
            .topic_messages(crate::convert::OBJECTS_TOPIC)
            .filter_map(|m| match &m.message {
                Decoded::Detection3DArray(a) => Some(a),
                _ => None,
            })
            .collect();
        assert_eq!(arrays.len(), 5);
        for (frame, array) in frames.iter().zip(arrays) {
            let back = actors_from_detections(array);
            assert_eq!(back.len(), frame.actors.len());
            for (a, b) in frame.actors.iter().zip(&back) {
                assert_eq!(a.id, b.id);
                assert!(a.position.distance(b.position) < 1e-9);
                assert!((a.heading_rad - b.heading_rad).abs() < 1e-9);
                assert!((a.length_m - b.length_m).abs() < 1e-12);
            }
        }
        Ok(())
    }
}
