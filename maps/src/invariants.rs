//! What must hold of a [`Map`] after every import transformation.
//!
//! Checked: every reference points at an existing element; lanes have positive length and
//! finite geometry; each connection joins the end of its `from` lane to the start of its `to`
//! lane at its junction; the circulating lanes of a roundabout form one directed cycle
//! through the connections; the ring lanes of a roundabout imported from OSM ways are
//! strongly connected, every entry leads onto them and every exit is reached from them (so
//! from every entry every exit is reachable); mini-roundabouts, and only they, name their
//! node; stop lines lie on existing lanes.

use std::collections::{BTreeMap, BTreeSet};

use crate::error::MapError;
use crate::model::{LaneId, Map, RoundaboutSource};

fn fail(step: &'static str, message: String) -> Result<(), MapError> {
    Err(MapError::Invariant { step, message })
}

/// Checks every invariant; `step` names the transformation just run, for the message.
pub fn check_invariants(map: &Map, step: &'static str) -> Result<(), MapError> {
    for (id, road) in &map.roads {
        if *id != road.id {
            return fail(
                step,
                format!("road stored under {id} says it is {}", road.id),
            );
        }
        for j in [road.start_junction, road.end_junction] {
            if !map.junctions.contains_key(&j) {
                return fail(step, format!("road {id} ends at missing junction {j}"));
            }
        }
        if road.reference_line.len() < 2 || !road.reference_line.iter().all(|p| p.is_finite()) {
            return fail(step, format!("road {id} has a degenerate reference line"));
        }
        for lane in road.lanes() {
            match map.lanes.get(&lane) {
                Some(l) if l.road == *id => {}
                _ => {
                    return fail(
                        step,
                        format!(
                            "road {id} lists lane {lane}, which is missing or belongs elsewhere"
                        ),
                    );
                }
            }
        }
    }
    for (id, lane) in &map.lanes {
        if *id != lane.id {
            return fail(
                step,
                format!("lane stored under {id} says it is {}", lane.id),
            );
        }
        let Some(road) = map.roads.get(&lane.road) else {
            return fail(
                step,
                format!("lane {id} belongs to missing road {}", lane.road),
            );
        };
        if !road.lanes().any(|l| l == *id) {
            return fail(
                step,
                format!("lane {id} is not listed by its road {}", lane.road),
            );
        }
        if lane.length_m.is_nan() || lane.length_m <= 0.0 || lane.centre.len() < 2 {
            return fail(step, format!("lane {id} has length {} m", lane.length_m));
        }
        if !lane
            .centre
            .iter()
            .chain(&lane.left)
            .chain(&lane.right)
            .all(|p| p.is_finite())
        {
            return fail(step, format!("lane {id} has a non-finite point"));
        }
        for j in [lane.from_junction, lane.to_junction] {
            if !map.junctions.contains_key(&j) {
                return fail(step, format!("lane {id} touches missing junction {j}"));
            }
        }
    }
    for (id, j) in &map.junctions {
        for r in &j.roads {
            match map.roads.get(r) {
                Some(road) if road.start_junction == *id || road.end_junction == *id => {}
                _ => {
                    return fail(
                        step,
                        format!("junction {id} lists road {r}, which does not end there"),
                    );
                }
            }
        }
    }
    for (id, c) in &map.connections {
        let (Some(from), Some(to)) = (map.lanes.get(&c.from), map.lanes.get(&c.to)) else {
            return fail(
                step,
                format!("connection {id} joins missing lanes {} -> {}", c.from, c.to),
            );
        };
        if from.to_junction != c.junction || to.from_junction != c.junction {
            return fail(
                step,
                format!(
                    "connection {id} at junction {} joins lane {} (ends at {}) to lane {} (starts at {})",
                    c.junction, c.from, from.to_junction, c.to, to.from_junction
                ),
            );
        }
        if c.centre.len() < 2 || !c.centre.iter().all(|p| p.is_finite()) {
            return fail(step, format!("connection {id} has degenerate geometry"));
        }
    }
    let links: BTreeSet<(LaneId, LaneId)> = if map.roundabouts.is_empty() {
        BTreeSet::new()
    } else {
        map.connections.values().map(|c| (c.from, c.to)).collect()
    };
    let mut next_of: BTreeMap<LaneId, Vec<LaneId>> = BTreeMap::new();
    let mut prev_of: BTreeMap<LaneId, Vec<LaneId>> = BTreeMap::new();
    for (a, b) in &links {
        next_of.entry(*a).or_default().push(*b);
        prev_of.entry(*b).or_default().push(*a);
    }
    for (id, r) in &map.roundabouts {
        let lanes = &r.circulating_lanes;
        if lanes.is_empty() {
            return fail(step, format!("roundabout {id} has no circulating lanes"));
        }
        let distinct: BTreeSet<_> = lanes.iter().collect();
        if distinct.len() != lanes.len() {
            return fail(
                step,
                format!("roundabout {id} lists a circulating lane twice"),
            );
        }
        for (i, a) in lanes.iter().enumerate() {
            let b = lanes[(i + 1) % lanes.len()];
            if !links.contains(&(*a, b)) {
                return fail(
                    step,
                    format!(
                        "roundabout {id}: circulating lane {a} does not lead to {b}, so the ring is not one directed cycle"
                    ),
                );
            }
        }
        for arm in r.entries.iter().chain(&r.exits) {
            if !map.roads.contains_key(&arm.road)
                || arm.lanes.iter().any(|l| !map.lanes.contains_key(l))
            {
                return fail(
                    step,
                    format!("roundabout {id} has an arm on a missing road or lane"),
                );
            }
        }
        if matches!(
            r.source,
            RoundaboutSource::Tagged | RoundaboutSource::Guessed
        ) {
            let ring: BTreeSet<LaneId> = r.ring_lanes.iter().copied().collect();
            for (step_of, way) in [(&next_of, "leads to"), (&prev_of, "is reached from")] {
                let Some(&start) = r.ring_lanes.first() else {
                    break;
                };
                let mut seen = BTreeSet::from([start]);
                let mut stack = vec![start];
                while let Some(l) = stack.pop() {
                    for n in step_of.get(&l).into_iter().flatten() {
                        if ring.contains(n) && seen.insert(*n) {
                            stack.push(*n);
                        }
                    }
                }
                if let Some(missed) = r.ring_lanes.iter().find(|l| !seen.contains(l)) {
                    return fail(
                        step,
                        format!(
                            "roundabout {id}: ring lane {start} {way} no path to ring lane {missed}: the ring lanes are not strongly connected"
                        ),
                    );
                }
            }
            for arm in &r.entries {
                let onto = arm.lanes.iter().any(|l| {
                    next_of
                        .get(l)
                        .is_some_and(|n| n.iter().any(|x| ring.contains(x)))
                });
                if !onto {
                    return fail(
                        step,
                        format!(
                            "roundabout {id}: the entry on road {} leads onto no ring lane",
                            arm.road
                        ),
                    );
                }
            }
            for arm in &r.exits {
                let from_ring = arm.lanes.iter().any(|l| {
                    prev_of
                        .get(l)
                        .is_some_and(|p| p.iter().any(|x| ring.contains(x)))
                });
                if !from_ring {
                    return fail(
                        step,
                        format!(
                            "roundabout {id}: the exit on road {} is reached from no ring lane",
                            arm.road
                        ),
                    );
                }
            }
        }
        for s in &r.yield_lines {
            if !map.stop_lines.contains_key(s) {
                return fail(
                    step,
                    format!("roundabout {id} lists missing yield line {s}"),
                );
            }
        }
    }
    for (id, r) in &map.roundabouts {
        let mini = r.kind == crate::model::RoundaboutKind::MiniRoundabout;
        if mini != r.osm_node_id.is_some() {
            return fail(
                step,
                format!("roundabout {id}: a node id belongs to mini-roundabouts only"),
            );
        }
    }
    for (id, s) in &map.stop_lines {
        if s.lanes.is_empty() || s.lanes.iter().any(|l| !map.lanes.contains_key(l)) {
            return fail(
                step,
                format!("stop line {id} stands on no lane or a missing one"),
            );
        }
        if s.line.len() < 2 || !s.line.iter().all(|p| p.is_finite()) {
            return fail(step, format!("stop line {id} has degenerate geometry"));
        }
    }
    Ok(())
}
