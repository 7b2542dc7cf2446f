//! Projection of a log into the bird's-eye representation: every frame of object
//! detections becomes a [`Scene`] around a chosen ego and is drawn by the simulator's
//! renderer, so a recorded drive and a simulated one give the same kind of frames.
//!
//! The ego's path (the route layer in simulation) is the ego's own recorded trajectory:
//! where the driver actually went. Speeds come from the positions (central differences).
//! Perception noise ([`super::noise`]) may be laid over the other users and the path.

use std::collections::BTreeMap;

use maps::geometry::Point;
use rayon::prelude::*;
use serde::Serialize;
use sim::render::BevRenderer;
use sim::{Actor, Scene};

use super::convert::OBJECTS_TOPIC;
use super::decode::{Decoded, DecodedLog};
use super::noise::{NoiseConfig, bend_path, perturb_actors};
use super::scenes::actors_from_detections;
use datasets::shard::Shard;

/// Least distance between the ego path's points, m.
const PATH_SPACING_M: f64 = 1.0;

/// The road users of one logged instant.
#[derive(Debug, Clone, PartialEq)]
pub struct LogFrame {
    pub time_ns: u64,
    pub actors: Vec<Actor>,
}

/// Every detection frame of `topic` (default: the converter's `/objects`), in time order.
pub fn log_frames(log: &DecodedLog, topic: Option<&str>) -> Vec<LogFrame> {
    let mut frames: Vec<LogFrame> = log
        .topic_messages(topic.unwrap_or(OBJECTS_TOPIC))
        .filter_map(|m| match &m.message {
            Decoded::Detection3DArray(a) => Some(LogFrame {
                time_ns: m.log_time,
                actors: actors_from_detections(a),
            }),
            _ => None,
        })
        .collect();
    frames.sort_by_key(|f| f.time_ns);
    frames
}

/// How many frames each track id appears in.
pub fn track_lengths(frames: &[LogFrame]) -> BTreeMap<u32, usize> {
    let mut lengths = BTreeMap::new();
    for f in frames {
        for a in &f.actors {
            *lengths.entry(a.id).or_insert(0) += 1;
        }
    }
    lengths
}

/// One projected frame's figures (the layers are stored apart).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProjectedFrame {
    /// Index into the log's frames.
    pub log_frame: usize,
    pub time_ns: u64,
    pub ego: u32,
    pub x: f64,
    pub y: f64,
    pub heading_rad: f64,
    pub speed_mps: f64,
    /// Road users in the frame, the ego included.
    pub actors: usize,
}

/// The frames in which `ego` appears, drawn around it with `noise`: the figures per frame
/// (exact, without noise) and the layers of all of them (frame after frame, each
/// `renderer.config().frame_len()` bytes). Frames are drawn in parallel; the result does
/// not depend on the thread count.
pub fn project(
    map: &maps::Map,
    renderer: &BevRenderer,
    frames: &[LogFrame],
    ego: u32,
    noise: &NoiseConfig,
) -> (Vec<ProjectedFrame>, Vec<u8>) {
    project_shard(map, renderer, frames, ego, noise, None)
}

/// [`project`], or only the ego's frames of `shard` (its share of the frames in which `ego`
/// appears, in order): the path, the speeds and the noise come from the whole log, so the
/// shards' frames put one after the other are [`project`]'s, byte for byte.
pub fn project_shard(
    map: &maps::Map,
    renderer: &BevRenderer,
    frames: &[LogFrame],
    ego: u32,
    noise: &NoiseConfig,
    shard: Option<Shard>,
) -> (Vec<ProjectedFrame>, Vec<u8>) {
    // The ego's track: (log frame, time, actor index).
    let track: Vec<(usize, u64, usize)> = frames
        .iter()
        .enumerate()
        .filter_map(|(k, f)| {
            f.actors
                .iter()
                .position(|a| a.id == ego)
                .map(|i| (k, f.time_ns, i))
        })
        .collect();
    let path: Vec<Point> = track
        .iter()
        .map(|&(k, _, i)| frames[k].actors[i].position)
        .fold(Vec::new(), |mut path, p| {
            // Positions 10 times a second are centimetres apart at a crawl: every one a
            // segment to draw, for no difference in a path 2 m wide on a 0.6 m grid.
            if path
                .last()
                .is_none_or(|q: &Point| q.distance(p) >= PATH_SPACING_M)
            {
                path.push(p);
            }
            path
        });
    let path = bend_path(&path, noise);
    let speeds = central_speeds(
        &track
            .iter()
            .map(|&(k, t, i)| (t, frames[k].actors[i].position))
            .collect::<Vec<_>>(),
    );
    let frame_len = renderer.config().frame_len();
    let all = track.len() as u64;
    let part = shard.map_or(0..all, |s| s.range(all));
    let results: Vec<(ProjectedFrame, Vec<u8>)> = (part.start as usize..part.end as usize)
        .into_par_iter()
        .map_init(Vec::new, |out, j| {
            let (k, time_ns, i) = track[j];
            let mut actors = frames[k].actors.clone();
            let speed_mps = speeds[j];
            actors[i].speed_mps = speed_mps;
            let e = actors[i].clone();
            let figures = ProjectedFrame {
                log_frame: k,
                time_ns,
                ego,
                x: e.position.x,
                y: e.position.y,
                heading_rad: e.heading_rad,
                speed_mps,
                actors: actors.len(),
            };
            perturb_actors(&mut actors, i, k as u64, noise);
            let scene = Scene {
                map,
                time_s: time_ns as f64 * 1e-9,
                actors,
                ego: i,
                ego_path: &path,
            };
            renderer.render(&scene, out);
            debug_assert_eq!(out.len(), frame_len);
            (figures, out.clone())
        })
        .collect();
    let mut figures = Vec::with_capacity(results.len());
    let mut layers = Vec::with_capacity(results.len() * frame_len);
    for (f, l) in results {
        figures.push(f);
        layers.extend_from_slice(&l);
    }
    (figures, layers)
}

/// Speeds along a track of (time ns, position) by central differences (one-sided at the
/// ends), m/s; 0 where the times do not advance.
pub fn central_speeds(track: &[(u64, Point)]) -> Vec<f64> {
    (0..track.len())
        .map(|j| {
            let (a, b) = (j.saturating_sub(1), (j + 1).min(track.len() - 1));
            let dt = (track[b].0.saturating_sub(track[a].0)) as f64 * 1e-9;
            if a == b || dt <= 0.0 {
                0.0
            } else {
                track[a].1.distance(track[b].1) / dt
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speeds_by_central_differences() {
        let track: Vec<(u64, Point)> = (0..4)
            .map(|i| (i as u64 * 100_000_000, Point::new(i as f64 * 0.5, 0.0)))
            .collect();
        let v = central_speeds(&track);
        assert!(v.iter().all(|s| (s - 5.0).abs() < 1e-9), "{v:?}");
        assert_eq!(central_speeds(&track[..1]), vec![0.0]);
    }
}
