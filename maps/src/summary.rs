//! The figures of `summary.json` (also `pipeline map info --json`): what a map holds, in a
//! form later tools and golden tests read.
//!
//! Lengths and positions are rounded to centimetres (two decimals) so the file is stable
//! across platforms and readable in a diff. Every key is documented on its field;
//! `docs/maps.md` repeats them.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::geometry::Point;
use crate::graph::{lanes_length_m, strongly_connected_components};
use crate::model::{
    DrivingSide, JunctionKind, Map, PrioritySource, RingProblem, RoundaboutKind,
    RoundaboutPriority, RoundaboutSource, StopKind,
};
use crate::projection::Projection;

/// Rounds to two decimals (centimetres for metres).
fn r2(v: f64) -> f64 {
    let r = (v * 100.0).round() / 100.0;
    // No "-0.0" in the output.
    if r == 0.0 { 0.0 } else { r }
}

fn r2p(p: Point) -> Point {
    Point::new(r2(p.x), r2(p.y))
}

/// Summary of a map. Serialised as `summary.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapSummary {
    /// Number of lanes (every direction of every selected road, cars or not).
    pub lanes: usize,
    /// Number of lanes passenger cars may use.
    pub car_lanes: usize,
    /// Total centre-line length of all lanes, metres (connections through junctions not included).
    pub lane_length_m: f64,
    /// Total centre-line length of the car lanes, metres; the figure compared with
    /// netconvert's passenger-car lane length.
    pub car_lane_length_m: f64,
    /// `car_lane_length_m` split by the roads' `highway=*` class (`lanelet` for Lanelet2 maps).
    pub car_lane_length_by_highway_m: BTreeMap<String, f64>,
    /// Number of roads (stretches of carriageway between junctions).
    pub roads: usize,
    /// Number of real intersections: junctions where three or more roads meet.
    pub junctions: usize,
    /// Number of all junctions, continuation points and dead ends included.
    pub junctions_all: usize,
    /// Number of lane-to-lane connections through junctions.
    pub connections: usize,
    /// Stop and give-way lines: `stop`, `give_way` and `total` counts (roundabout yield lines included).
    pub stop_lines: BTreeMap<String, usize>,
    /// Strongly connected components of the car lane graph.
    pub components: ComponentsSummary,
    /// Every roundabout, in id order: the rings, then the mini-roundabouts.
    pub roundabouts: Vec<RoundaboutSummary>,
    /// Tagged rings and mini-roundabout nodes with a problem (not closed, nodes missing,
    /// a piece against the ring's direction, an unusable `lanes` value, ...): `osm_way_ids`,
    /// `osm_node_id` (mini-roundabouts), `reason` and whether the ring was still `imported`.
    #[serde(default)]
    pub ring_problems: Vec<RingProblem>,
    /// What the import skipped, as counts.
    pub skipped: SkippedSummary,
    /// The map's projection: `{"local": {"origin": {"lat", "lon"}}}` or `{"utm": {"origin", "zone"}}`.
    pub projection: Projection,
    /// `right` or `left`.
    pub driving_side: DrivingSide,
    /// Name of the road-selection profile used by the import (e.g. `car`).
    pub profile: String,
    /// Extent of the lanes and junction areas in map metres: `min` {`x`, `y`}, `max` {`x`, `y`}
    /// (null for an empty map).
    pub bounds: Option<SummaryBounds>,
}

/// Strong connectivity of the car lanes: a car can drive from any lane of a component to
/// any other of the same component.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComponentsSummary {
    /// Number of strongly connected components (a lane that reaches no other lane and is
    /// reached from none counts as one).
    pub count: usize,
    /// Lanes in the largest component (largest by lane length).
    pub largest_lane_count: usize,
    /// Total lane length of the largest component, metres.
    pub largest_lane_length_m: f64,
}

/// One roundabout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RoundaboutSummary {
    /// Roundabout id in the native map.
    pub id: u32,
    /// Number of roads entering the ring.
    pub entries: usize,
    /// Number of roads leaving the ring.
    pub exits: usize,
    /// Number of yield lines (one per entry where it meets the ring, when placed).
    pub yield_lines: usize,
    /// Number of lanes forming the ring.
    pub circulating_lanes: usize,
    /// True when found geometrically (an untagged near-circular one-way loop) rather than
    /// from `junction=roundabout|circular` tags or Lanelet2 data.
    pub guessed: bool,
    /// `tagged`, `guessed` or `lanelet2`.
    pub source: RoundaboutSource,
    /// `roundabout`, `circular` (`junction=circular`) or `mini_roundabout`.
    #[serde(default)]
    pub kind: RoundaboutKind,
    /// Most lanes side by side on any piece of the ring (1 for a mini-roundabout).
    #[serde(default)]
    pub ring_lanes: u8,
    /// Who goes first where an entry meets the ring: `circulating` or `entering`.
    #[serde(default)]
    pub priority: RoundaboutPriority,
    /// `tags` when the data says so, `assumed` when the roundabout rule is taken.
    #[serde(default)]
    pub priority_source: PrioritySource,
    /// The OSM ways forming the ring (Lanelet2: the lanelets' bound ways; empty for a
    /// mini-roundabout).
    pub osm_way_ids: Vec<i64>,
    /// The `highway=mini_roundabout` node, for a mini-roundabout.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub osm_node_id: Option<i64>,
    /// Centre of the ring in map metres.
    pub centre: Point,
    /// Mean radius of the ring, metres.
    pub radius_m: f64,
    /// Direction of circulation seen from above.
    pub clockwise: bool,
}

/// Counts of what the import left out (details are in the native map's `report`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SkippedSummary {
    /// Selected ways that referenced nodes missing from the file.
    pub ways_missing_nodes: usize,
    /// Nodes with coordinates outside WGS84's range or not numbers.
    pub invalid_nodes: usize,
    /// Selected ways with fewer than two distinct positions.
    pub degenerate_ways: usize,
    /// Turn restrictions applied.
    pub restrictions_applied: usize,
    /// Turn restrictions that could not be applied (unknown ways, via ways, ...).
    pub restrictions_skipped: usize,
    /// `highway=stop` / `give_way` nodes not on any selected road.
    pub stop_nodes_unplaced: usize,
    /// Free-form notes recorded by the import.
    pub notes: usize,
}

/// A rounded bounding box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SummaryBounds {
    pub min: Point,
    pub max: Point,
}

/// Computes the summary of a map.
pub fn summarize(map: &Map) -> MapSummary {
    let mut lane_length = 0.0;
    let mut car_lanes = 0;
    let mut car_length = 0.0;
    let mut by_highway: BTreeMap<String, f64> = BTreeMap::new();
    for lane in map.lanes.values() {
        lane_length += lane.length_m;
        if let Some(road) = map.roads.get(&lane.road).filter(|r| r.allows_cars) {
            car_lanes += 1;
            car_length += lane.length_m;
            *by_highway.entry(road.highway.clone()).or_default() += lane.length_m;
        }
    }
    let mut stop_lines: BTreeMap<String, usize> = [("stop", 0), ("give_way", 0), ("total", 0)]
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v))
        .collect();
    for s in map.stop_lines.values() {
        let key = match s.kind {
            StopKind::Stop => "stop",
            StopKind::GiveWay => "give_way",
        };
        for k in [key, "total"] {
            *stop_lines.entry(k.to_owned()).or_default() += 1;
        }
    }
    let comps = strongly_connected_components(map, true);
    let components = ComponentsSummary {
        count: comps.len(),
        largest_lane_count: comps.first().map_or(0, Vec::len),
        largest_lane_length_m: r2(comps.first().map_or(0.0, |c| lanes_length_m(map, c))),
    };
    let roundabouts = map
        .roundabouts
        .values()
        .map(|r| RoundaboutSummary {
            id: r.id.0,
            entries: r.entries.len(),
            exits: r.exits.len(),
            yield_lines: r.yield_lines.len(),
            circulating_lanes: r.circulating_lanes.len(),
            guessed: r.source == RoundaboutSource::Guessed,
            source: r.source,
            kind: r.kind,
            ring_lanes: r.lanes_across,
            priority: r.priority,
            priority_source: r.priority_source,
            osm_way_ids: r.osm_way_ids.clone(),
            osm_node_id: r.osm_node_id,
            centre: r2p(r.centre),
            radius_m: r2(r.radius_m),
            clockwise: r.clockwise,
        })
        .collect();
    let rep = &map.report;
    let skipped = SkippedSummary {
        ways_missing_nodes: rep.ways_missing_nodes.len(),
        invalid_nodes: rep.invalid_nodes,
        degenerate_ways: rep.degenerate_ways.len(),
        restrictions_applied: rep.restrictions_applied,
        restrictions_skipped: rep.restrictions_skipped.len(),
        stop_nodes_unplaced: rep.stop_nodes_unplaced.len(),
        notes: rep.notes.len(),
    };
    let b = map.bounds();
    let bounds = (!b.is_empty()).then(|| SummaryBounds {
        min: r2p(b.min),
        max: r2p(b.max),
    });
    MapSummary {
        lanes: map.lanes.len(),
        car_lanes,
        lane_length_m: r2(lane_length),
        car_lane_length_m: r2(car_length),
        car_lane_length_by_highway_m: by_highway.into_iter().map(|(k, v)| (k, r2(v))).collect(),
        roads: map.roads.len(),
        junctions: map
            .junctions
            .values()
            .filter(|j| j.kind == JunctionKind::Intersection)
            .count(),
        junctions_all: map.junctions.len(),
        connections: map.connections.len(),
        stop_lines,
        components,
        roundabouts,
        ring_problems: rep.ring_problems.clone(),
        skipped,
        projection: map.projection,
        driving_side: map.driving_side,
        profile: map.profile.clone(),
        bounds,
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::graph::test_maps;

    #[test]
    fn summary_of_the_square_loop() {
        let map = test_maps::square_loop();
        let s = summarize(&map);
        assert_eq!((s.lanes, s.car_lanes, s.roads, s.connections), (6, 6, 6, 5));
        assert_eq!(s.car_lane_length_m, 600.0);
        assert_eq!(s.car_lane_length_by_highway_m["residential"], 600.0);
        assert_eq!(s.components.count, 3);
        assert_eq!(s.components.largest_lane_count, 4);
        assert_eq!(s.components.largest_lane_length_m, 400.0);
        assert_eq!(s.junctions, 0);
        assert_eq!(s.stop_lines["total"], 0);
        let json = serde_json::to_string_pretty(&s).unwrap();
        let back: MapSummary = serde_json::from_str(&json).unwrap();
        assert_eq!(back, s);
        for key in [
            "\"lanes\"",
            "\"car_lane_length_m\"",
            "\"junctions\"",
            "\"components\"",
            "\"roundabouts\"",
            "\"largest_lane_length_m\"",
            "\"skipped\"",
        ] {
            assert!(json.contains(key), "{key} missing");
        }
    }

    #[test]
    #[allow(clippy::print_stderr)]
    fn tiny_roundabout_has_one_tagged_roundabout() {
        let Some(map) = crate::graph::test_maps::shared_osm_map("tiny_roundabout.osm") else {
            return;
        };
        let s = summarize(&map);
        assert_eq!(s.roundabouts.len(), 1);
        let r = &s.roundabouts[0];
        assert!(!r.guessed && r.source == RoundaboutSource::Tagged);
        assert!(!r.osm_way_ids.is_empty() && r.entries > 0 && r.exits > 0);
        assert_eq!(r.yield_lines, r.entries);
        assert_eq!(s.components.count, 1);
        // Stable: the same map gives the same JSON.
        let json = serde_json::to_string(&s).unwrap();
        assert_eq!(json, serde_json::to_string(&summarize(&map)).unwrap());
    }

    #[test]
    fn rounding() {
        assert_eq!(r2(1.23456), 1.23);
        assert_eq!(r2(-0.001), 0.0);
        assert!(r2(-0.001).is_sign_positive());
    }
}
