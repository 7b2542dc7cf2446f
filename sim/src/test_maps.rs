//! Small hand-made maps and the bundled real one for the tests of this crate.
#![allow(dead_code)]

use maps::geometry::{offset_polyline, polyline_length};
use maps::projection::{LatLon, Projection};
use maps::*;

/// A map with one straight one-lane road from `a` to `b` (3.5 m wide, 50 km/h).
pub fn straight_road(a: Point, b: Point) -> Map {
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
    let centre = vec![a, b];
    map.roads.insert(
        RoadId(0),
        Road {
            id: RoadId(0),
            source: RoadSource::OsmWay,
            osm_way_ids: vec![1],
            highway: "residential".into(),
            name: None,
            reference_line: centre.clone(),
            start_junction: JunctionId(0),
            end_junction: JunctionId(1),
            lanes_forward: vec![LaneId(0)],
            lanes_backward: vec![],
            speed_limit_kmh: 50.0,
            speed_limit_is_default: false,
            is_roundabout: false,
            allows_cars: true,
        },
    );
    map.lanes.insert(
        LaneId(0),
        Lane {
            id: LaneId(0),
            road: RoadId(0),
            direction: Direction::Forward,
            index_from_centre: 0,
            left: offset_polyline(&centre, 1.75),
            right: offset_polyline(&centre, -1.75),
            length_m: polyline_length(&centre),
            centre,
            width_m: 3.5,
            speed_limit_kmh: 50.0,
            turns: vec![],
            from_junction: JunctionId(0),
            to_junction: JunctionId(1),
        },
    );
    map
}

/// The bundled montlake_roundabout map (one mini roundabout, five entries), from the
/// repository's `data/osm`.
#[allow(clippy::expect_used)]
pub fn montlake() -> Map {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/osm/montlake_roundabout.osm.pbf");
    maps::import_file(&path, &Default::default()).expect("bundled montlake map imports")
}

/// `../shared/data/<relative>` imported, or None with a skip notice when absent.
#[allow(clippy::print_stderr, clippy::expect_used)]
pub fn shared_map(relative: &str) -> Option<Map> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(relative);
    if !path.exists() {
        eprintln!("skipped: {} not found", path.display());
        return None;
    }
    Some(maps::import_file(&path, &Default::default()).expect("shared map imports"))
}
