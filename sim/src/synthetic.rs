//! Maps made in code rather than imported: a straight one-way road for tasks that need no
//! real map (obstacle avoidance) and for tests.

use maps::geometry::{offset_polyline, polyline_length};
use maps::projection::{LatLon, Projection};
use maps::*;

/// A straight one-way road from `a` to `b` with `lanes` lanes of `lane_width_m`, all in the
/// direction a → b, laid symmetrically about the segment (lane 0 leftmost), at `speed_limit_kmh`.
/// Dead-end junctions at both ends, no connections.
pub fn straight_road(
    a: Point,
    b: Point,
    lanes: usize,
    lane_width_m: f64,
    speed_limit_kmh: f64,
) -> Map {
    let mut map = Map::new(
        Projection::local(LatLon::new(0.0, 0.0)),
        DrivingSide::Right,
        "car",
    );
    for (j, p) in [(JunctionId(0), a), (JunctionId(1), b)] {
        map.junctions.insert(
            j,
            Junction {
                id: j,
                kind: JunctionKind::DeadEnd,
                osm_node_id: None,
                point: p,
                polygon: vec![],
                roads: vec![RoadId(0)],
                control: None,
            },
        );
    }
    let reference = vec![a, b];
    let lane_ids: Vec<LaneId> = (0..lanes as u32).map(LaneId).collect();
    map.roads.insert(
        RoadId(0),
        Road {
            id: RoadId(0),
            source: RoadSource::OsmWay,
            osm_way_ids: vec![1],
            highway: "residential".into(),
            name: None,
            reference_line: reference.clone(),
            start_junction: JunctionId(0),
            end_junction: JunctionId(1),
            lanes_forward: lane_ids.clone(),
            lanes_backward: vec![],
            speed_limit_kmh,
            speed_limit_is_default: false,
            is_roundabout: false,
            allows_cars: true,
        },
    );
    for (i, id) in lane_ids.into_iter().enumerate() {
        // Offset of the lane's centre to the left of the reference line.
        let offset = ((lanes as f64 - 1.0) / 2.0 - i as f64) * lane_width_m;
        let centre = offset_polyline(&reference, offset);
        map.lanes.insert(
            id,
            Lane {
                id,
                road: RoadId(0),
                direction: Direction::Forward,
                index_from_centre: i.min(u8::MAX as usize) as u8,
                left: offset_polyline(&reference, offset + lane_width_m / 2.0),
                right: offset_polyline(&reference, offset - lane_width_m / 2.0),
                length_m: polyline_length(&centre),
                centre,
                width_m: lane_width_m,
                speed_limit_kmh,
                turns: vec![],
                from_junction: JunctionId(0),
                to_junction: JunctionId(1),
            },
        );
    }
    map
}
