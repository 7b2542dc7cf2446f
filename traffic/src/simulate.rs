//! The world's traffic on a recorded roundabout, as frames the measurements read like a
//! recording's.

use std::sync::Arc;

use maps::{Map, RoundaboutId};
use sim::roundabout::{LayoutConfig, RoundaboutLayout};
use sim::world::{EgoConfig, EntryFlow, ExitShare, TrafficConfig, World, WorldStats};

use crate::measure::{Measurements, RingGeometry, entry_flows_vph};
use logs::project::LogFrame;

/// A simulated run: its frames (one per world step, times from 0 after the warm-up) and the
/// world's counters.
#[derive(Debug, Clone)]
pub struct Simulated {
    pub frames: Vec<LogFrame>,
    pub stats: WorldStats,
    /// Arrivals still waiting off the map at the end.
    pub waiting: u64,
}

/// Runs the world of `traffic` (its flows) on roundabout `id` of `map` for `seconds` after
/// `warm_up_s`, all draws from `seed`.
pub fn simulate(
    map: &Map,
    id: RoundaboutId,
    traffic: &TrafficConfig,
    layout: &LayoutConfig,
    seconds: f64,
    warm_up_s: f64,
    seed: u64,
) -> Result<Simulated, String> {
    let layout = RoundaboutLayout::new(map, id, layout).map_err(|e| e.to_string())?;
    traffic.check_flows(&layout)?;
    let mut world = World::new(
        Arc::new(layout),
        traffic.clone(),
        EgoConfig::default(),
        seed,
    );
    world.warm_up(warm_up_s);
    let steps = (seconds / traffic.step_s).round().max(0.0) as usize;
    let mut frames = Vec::with_capacity(steps);
    let t0 = world.time_s();
    for _ in 0..steps {
        world.step(0.0);
        frames.push(LogFrame {
            time_ns: ((world.time_s() - t0) * 1e9).round() as u64,
            actors: world.actors(),
        });
    }
    Ok(Simulated {
        frames,
        stats: world.stats(),
        waiting: world.waiting_to_enter(),
    })
}

/// Each usable entry of roundabout `id`'s layout with the flow measured at its yield line in
/// `measured` (pooled over the recordings), veh/h, and where those vehicles went: an entry
/// takes the line nearest to where its routes give way (an entry line shared by several entry
/// lanes splits its flow evenly); each vehicle seen leaving the ring goes to the exit whose
/// routes leave it nearest (by angle round the centre) to where it left.
pub fn recorded_flows(
    map: &Map,
    id: RoundaboutId,
    layout: &LayoutConfig,
    geometry: &RingGeometry,
    measured: &[Measurements],
) -> Result<Vec<EntryFlow>, String> {
    let layout = RoundaboutLayout::new(map, id, layout).map_err(|e| e.to_string())?;
    let seconds: f64 = measured.iter().map(|m| m.duration_s).sum();
    if seconds <= 0.0 {
        return Err("the recordings hold no time".into());
    }
    let n = geometry.entries.len();
    let mut per_line = entry_flows_vph(measured);
    per_line.resize(n, 0.0);
    // Each usable entry's line.
    let lines: Vec<(u32, usize)> = layout
        .usable_entries()
        .filter_map(|e| {
            let route = &layout.routes[*layout.routes_by_entry[e].first()?];
            let (p, _) = route.path.pose_at(route.yield_s);
            let k = (0..n).min_by(|&a, &b| {
                let da = line_distance(&geometry.entries[a].line, p);
                let db = line_distance(&geometry.entries[b].line, p);
                da.total_cmp(&db)
            })?;
            Some((layout.entries[e].lane.0, k))
        })
        .collect();
    // Each exit lane with the angle round the centre at which its routes leave the ring.
    let mut exit_angles: Vec<(u32, f64)> = Vec::new();
    for r in &layout.routes {
        let lane = layout.exits[r.exit].lane.0;
        if exit_angles.iter().all(|(l, _)| *l != lane) {
            let (p, _) = r.path.pose_at(r.exit_s);
            let d = p.sub(geometry.centre);
            exit_angles.push((lane, d.y.atan2(d.x)));
        }
    }
    let mut went: Vec<Vec<(u32, u32)>> = vec![Vec::new(); n];
    for e in measured.iter().flat_map(|m| &m.entering) {
        let Some(left) = e.left_angle else { continue };
        let nearest = exit_angles
            .iter()
            .min_by(|a, b| angle_between(a.1, left).total_cmp(&angle_between(b.1, left)));
        if let (Some(&(lane, _)), Some(list)) = (nearest, went.get_mut(e.entry)) {
            match list.iter_mut().find(|(l, _)| *l == lane) {
                Some(slot) => slot.1 += 1,
                None => list.push((lane, 1)),
            }
        }
    }
    Ok(lines
        .iter()
        .map(|&(lane, k)| {
            let sharing = lines.iter().filter(|(_, j)| *j == k).count().max(1);
            let seen: u32 = went[k].iter().map(|(_, c)| c).sum();
            let mut exits: Vec<ExitShare> = went[k]
                .iter()
                .map(|&(lane, c)| ExitShare {
                    lane,
                    share: f64::from(c) / f64::from(seen.max(1)),
                })
                .collect();
            exits.sort_by_key(|x| x.lane);
            EntryFlow {
                lane,
                vph: per_line[k] / sharing as f64,
                exits,
            }
        })
        .collect())
}

/// Distance from `p` to the nearest vertex of `line`'s middle (enough to tell entries apart).
fn line_distance(line: &[maps::Point], p: maps::Point) -> f64 {
    match (line.first(), line.last()) {
        (Some(a), Some(b)) => a.add(*b).scale(0.5).distance(p),
        _ => f64::INFINITY,
    }
}

/// The absolute difference of two angles, in [0, π].
fn angle_between(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    d.min(std::f64::consts::TAU - d)
}
