//! Per-frame features of the drivers' go / wait decisions at roundabout entries, as CSV on
//! standard output: what a policy could observe (its own speed and its history, the distance
//! to the line, the vehicles on the ring upstream of its entry and the one ahead of it) next
//! to the label `replay eval` scores. For studying how far such observations explain the
//! drivers' decisions (docs/logs.md).
//!
//! cargo run --release -p logs --example decision_features -- MAP.osm LOG.mcap... > f.csv
#![allow(clippy::print_stdout, clippy::print_stderr, clippy::unwrap_used)]

use std::collections::BTreeMap;
use std::f64::consts::TAU;
use std::path::Path;

use logs::project::log_frames;
use logs::{Log, ReadOptions, read_decoded};
use maps::geometry::Point;
use traffic::decisions::{Decision, LabelConfig, approaches};

/// Ring vehicles this far from the ring's radius count as circulating, m.
const RING_BAND_M: f64 = 6.0;
/// Upstream arc searched for circulating vehicles, m.
const UPSTREAM_M: f64 = 120.0;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let map = maps::import_file(Path::new(&args[0]), &maps::ImportOptions::default()).unwrap();
    println!(
        "log,track,frame,label,v,v05,v10,v20,vmin_so_far,dist_line,t_in_approach,\
         up_arc,up_speed,up_eta,up_count40,min_eta,near_entry,ahead_dist,ahead_speed,ring_count"
    );
    for log_path in &args[1..] {
        let log = Log::open(Path::new(log_path)).unwrap();
        let decoded = read_decoded(&log, &ReadOptions::default()).unwrap();
        let frames = log_frames(&decoded, None);
        let name = Path::new(log_path).file_stem().unwrap().to_string_lossy();
        // Per frame: id -> (position, heading, speed from the frame before).
        let mut states: Vec<BTreeMap<u32, (Point, f64, f64)>> = Vec::with_capacity(frames.len());
        for (k, f) in frames.iter().enumerate() {
            let mut m = BTreeMap::new();
            for a in &f.actors {
                let speed = k
                    .checked_sub(1)
                    .and_then(|p| states[p].get(&a.id).map(|s: &(Point, f64, f64)| (p, s.0)))
                    .map_or(0.0, |(p, prev)| {
                        let dt = (f.time_ns - frames[p].time_ns) as f64 * 1e-9;
                        a.position.distance(prev) / dt.max(1e-3)
                    });
                m.insert(a.id, (a.position, a.heading_rad, speed));
            }
            states.push(m);
        }
        for ap in approaches(&map, &frames, &LabelConfig::default()) {
            let Some(r) = map
                .roundabouts
                .values()
                .find(|r| u64::from(r.id.0) == ap.roundabout)
            else {
                continue;
            };
            let Some(&(entry, _, _)) = states[ap.crossed_at].get(&ap.track) else {
                continue;
            };
            let angle = |p: Point| (p.y - r.centre.y).atan2(p.x - r.centre.x);
            let entry_angle = angle(entry);
            // Arc from p to the entry along the circulation, m.
            let arc_to_entry = |p: Point| {
                let d = if r.clockwise {
                    angle(p) - entry_angle
                } else {
                    entry_angle - angle(p)
                };
                d.rem_euclid(TAU) * r.radius_m
            };
            // Driven distance from each frame to the crossing.
            let positions: Vec<Point> = ap.frames.iter().map(|&k| states[k][&ap.track].0).collect();
            let mut to_line = vec![0.0; positions.len()];
            let mut acc = positions.last().map_or(0.0, |last| last.distance(entry));
            for i in (0..positions.len()).rev() {
                to_line[i] = acc;
                if i > 0 {
                    acc += positions[i].distance(positions[i - 1]);
                }
            }
            let mut vmin = f64::INFINITY;
            for (i, (&k, &label)) in ap.frames.iter().zip(&ap.labels).enumerate() {
                let label = match label {
                    Decision::Go => "go",
                    Decision::Wait => "wait",
                    Decision::Ambiguous => "ambiguous",
                    Decision::Queued => "queued",
                };
                let speed_at = |back: usize| {
                    k.checked_sub(back)
                        .and_then(|b| states[b].get(&ap.track))
                        .map_or(f64::NAN, |s| s.2)
                };
                let (pos, heading, v) = states[k][&ap.track];
                vmin = vmin.min(v);
                let t = (frames[k].time_ns - frames[ap.frames[0]].time_ns) as f64 * 1e-9;
                let (mut up_arc, mut up_speed, mut up_eta) = (UPSTREAM_M, 0.0, 99.0);
                let (mut count40, mut min_eta, mut near_entry) = (0, 99.0_f64, 0);
                let (mut ahead_dist, mut ahead_speed) = (99.0, 0.0);
                let mut ring_count = 0;
                let dir = Point::new(heading.cos(), heading.sin());
                for (&id, &(p, h, s)) in &states[k] {
                    if id == ap.track {
                        continue;
                    }
                    let off = p.sub(pos);
                    let along = off.x * dir.x + off.y * dir.y;
                    let side = (off.y * dir.x - off.x * dir.y).abs();
                    let dh =
                        (h - heading + std::f64::consts::PI).rem_euclid(TAU) - std::f64::consts::PI;
                    if along > 0.0 && along < ahead_dist && side < 2.5 && dh.abs() < 0.8 {
                        ahead_dist = along;
                        ahead_speed = s;
                    }
                    if (p.distance(r.centre) - r.radius_m).abs() > RING_BAND_M {
                        continue;
                    }
                    ring_count += 1;
                    let arc = arc_to_entry(p);
                    if p.distance(entry) < 10.0 {
                        near_entry += 1;
                    }
                    if arc < UPSTREAM_M {
                        let eta = arc / s.max(0.5);
                        if arc < 40.0 {
                            count40 += 1;
                        }
                        min_eta = min_eta.min(eta);
                        if arc < up_arc {
                            up_arc = arc;
                            up_speed = s;
                            up_eta = eta;
                        }
                    }
                }
                println!(
                    "{name},{},{k},{label},{v:.3},{:.3},{:.3},{:.3},{vmin:.3},{:.2},{t:.2},{up_arc:.2},{up_speed:.2},{up_eta:.2},{count40},{min_eta:.2},{near_entry},{ahead_dist:.2},{ahead_speed:.2},{ring_count}",
                    ap.track,
                    speed_at(5),
                    speed_at(10),
                    speed_at(20),
                    to_line[i],
                );
            }
        }
        eprintln!("{name}: done");
    }
}
