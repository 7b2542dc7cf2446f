//! GeoJSON (RFC 7946) of a map, to open in QGIS or geojson.io next to other data.
//!
//! One `FeatureCollection` in WGS84 (`[lon, lat]`, as RFC 7946 orders them), with a `kind`
//! property on every feature so a viewer can style by it:
//!
//! | `kind` | geometry | from |
//! | --- | --- | --- |
//! | `road` | LineString | a road's reference line |
//! | `lane` | LineString | a lane's centre line, in its direction of travel |
//! | `junction` | Polygon | a junction area (only junctions that have one) |
//! | `roundabout` | Polygon (LineString if the ring does not close) | one trip round the ring's lanes; `roundabout_kind` (`roundabout`, `circular` or `mini_roundabout`), `ring_lanes`, `priority`, `priority_source` |
//! | `mini_roundabout` | Point | a `highway=mini_roundabout` node (the centre of the small ring made round it), with its arms and priority |
//! | `stop_line` / `give_way` | LineString | a stop or give-way line |
//!
//! Coordinates are rounded to 7 decimals (about 1 cm), which keeps files small and makes
//! them byte-identical for identical maps; points that collapse onto their predecessor after
//! rounding are dropped. Polygon rings are closed and counter-clockwise, as RFC 7946 asks.

use serde::Serialize;

use crate::error::MapError;
use crate::geometry::Point;
use crate::model::{
    Direction, LaneId, Map, PrioritySource, RoadId, RoundaboutKind, RoundaboutPriority,
    RoundaboutSource, StopKind, StopLineSource,
};
use crate::projection::Projector;

/// A GeoJSON `FeatureCollection`. Serialising it gives the members in the usual order
/// (`type` first).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FeatureCollection<'a> {
    #[serde(rename = "type")]
    pub kind: &'static str,
    pub features: Vec<Feature<'a>>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Feature<'a> {
    #[serde(rename = "type")]
    pub kind: &'static str,
    pub geometry: Geometry,
    pub properties: Properties<'a>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", content = "coordinates")]
pub enum Geometry {
    Point([f64; 2]),
    LineString(Vec<[f64; 2]>),
    Polygon(Vec<Vec<[f64; 2]>>),
}

/// A feature's properties, borrowed from the map. The fields of each kind are in
/// alphabetical order, so the keys come out sorted as in a `serde_json::Value` object (the
/// form files were written in before, without building a `Value` per feature).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Properties<'a> {
    Road {
        allows_cars: bool,
        highway: &'a str,
        id: u32,
        kind: &'static str,
        lanes_backward: usize,
        lanes_forward: usize,
        name: Option<&'a str>,
        osm_way_ids: &'a [i64],
        roundabout: bool,
        speed_limit_is_default: bool,
        speed_limit_kmh: f64,
    },
    Lane {
        direction: &'static str,
        id: u32,
        index_from_centre: u8,
        kind: &'static str,
        length_m: f64,
        road: u32,
        speed_limit_kmh: f64,
        turns: &'a [String],
        width_m: f64,
    },
    Junction {
        control: Option<&'a str>,
        id: u32,
        kind: &'static str,
        osm_node_id: Option<i64>,
        roads: &'a [RoadId],
    },
    Roundabout {
        circulating_lanes: &'a [LaneId],
        clockwise: bool,
        entries: usize,
        exits: usize,
        guessed: bool,
        id: u32,
        kind: &'static str,
        osm_way_ids: &'a [i64],
        priority: RoundaboutPriority,
        priority_source: PrioritySource,
        radius_m: f64,
        ring_lanes: u8,
        roundabout_kind: RoundaboutKind,
        source: RoundaboutSource,
        yield_lines: usize,
    },
    MiniRoundabout {
        entries: usize,
        exits: usize,
        id: u32,
        kind: &'static str,
        osm_node_id: i64,
        priority: RoundaboutPriority,
        priority_source: PrioritySource,
    },
    /// `kind` is `stop_line` or `give_way`.
    StopLine {
        id: u32,
        kind: &'static str,
        lanes: &'a [LaneId],
        source: StopSource,
    },
}

impl Properties<'_> {
    /// The `kind` property.
    pub fn kind(&self) -> &'static str {
        match self {
            Properties::Road { kind, .. }
            | Properties::Lane { kind, .. }
            | Properties::Junction { kind, .. }
            | Properties::Roundabout { kind, .. }
            | Properties::MiniRoundabout { kind, .. }
            | Properties::StopLine { kind, .. } => kind,
        }
    }
}

/// Where a stop line comes from: `{"osm_node": id}`, `{"roundabout_entry": id}` or
/// `{"lanelet_way": id}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopSource {
    OsmNode(i64),
    RoundaboutEntry(u32),
    LaneletWay(i64),
}

/// Decimal places kept in coordinates: 1e-7 degrees is about 1 cm.
const DECIMALS: f64 = 1e7;

fn round(v: f64) -> f64 {
    (v * DECIMALS).round() / DECIMALS
}

struct Converter {
    projector: Projector,
}

impl Converter {
    /// Map metres to rounded `[lon, lat]`, without consecutive repeats.
    fn positions(&self, pts: &[Point]) -> Vec<[f64; 2]> {
        let mut out: Vec<[f64; 2]> = Vec::with_capacity(pts.len());
        for p in pts {
            let ll = self.projector.unproject(*p);
            let q = [round(ll.lon), round(ll.lat)];
            if !(q[0].is_finite() && q[1].is_finite()) {
                continue;
            }
            if out.last() != Some(&q) {
                out.push(q);
            }
        }
        out
    }

    fn line(&self, pts: &[Point]) -> Option<Geometry> {
        let positions = self.positions(pts);
        (positions.len() >= 2).then_some(Geometry::LineString(positions))
    }

    /// A closed, counter-clockwise ring, or None when fewer than three distinct positions remain.
    fn polygon(&self, pts: &[Point]) -> Option<Geometry> {
        let mut ring = self.positions(pts);
        if ring.len() >= 2 && ring.first() == ring.last() {
            ring.pop();
        }
        if ring.len() < 3 {
            return None;
        }
        if ring_area(&ring) < 0.0 {
            ring.reverse();
        }
        let first = ring[0];
        ring.push(first);
        Some(Geometry::Polygon(vec![ring]))
    }
}

/// Twice the signed area in degrees² (positive counter-clockwise); only the sign matters.
fn ring_area(ring: &[[f64; 2]]) -> f64 {
    let n = ring.len();
    (0..n)
        .map(|i| {
            let (a, b) = (ring[i], ring[(i + 1) % n]);
            a[0] * b[1] - b[0] * a[1]
        })
        .sum()
}

fn direction_name(d: Direction) -> &'static str {
    match d {
        Direction::Forward => "forward",
        Direction::Backward => "backward",
    }
}

/// The map as a GeoJSON `FeatureCollection`: roads, lanes, junction areas, roundabouts and
/// stop lines, in that order and in id order within each kind.
pub fn to_geojson<'a>(map: &'a Map) -> FeatureCollection<'a> {
    let c = Converter {
        projector: map.projection.projector(),
    };
    let mut features = Vec::new();
    let mut push = |geometry: Option<Geometry>, properties: Properties<'a>| {
        if let Some(geometry) = geometry {
            features.push(Feature {
                kind: "Feature",
                geometry,
                properties,
            });
        }
    };

    for road in map.roads.values() {
        push(
            c.line(&road.reference_line),
            Properties::Road {
                allows_cars: road.allows_cars,
                highway: &road.highway,
                id: road.id.0,
                kind: "road",
                lanes_backward: road.lanes_backward.len(),
                lanes_forward: road.lanes_forward.len(),
                name: road.name.as_deref(),
                osm_way_ids: &road.osm_way_ids,
                roundabout: road.is_roundabout,
                speed_limit_is_default: road.speed_limit_is_default,
                speed_limit_kmh: road.speed_limit_kmh,
            },
        );
    }
    for lane in map.lanes.values() {
        push(
            c.line(&lane.centre),
            Properties::Lane {
                direction: direction_name(lane.direction),
                id: lane.id.0,
                index_from_centre: lane.index_from_centre,
                kind: "lane",
                length_m: lane.length_m,
                road: lane.road.0,
                speed_limit_kmh: lane.speed_limit_kmh,
                turns: &lane.turns,
                width_m: lane.width_m,
            },
        );
    }
    for junction in map.junctions.values() {
        if junction.polygon.len() < 3 {
            continue;
        }
        push(
            c.polygon(&junction.polygon),
            Properties::Junction {
                control: junction.control.as_deref(),
                id: junction.id.0,
                kind: "junction",
                osm_node_id: junction.osm_node_id,
                roads: &junction.roads,
            },
        );
    }
    for roundabout in map.roundabouts.values() {
        let mut ring: Vec<Point> = Vec::new();
        for lane in roundabout
            .circulating_lanes
            .iter()
            .filter_map(|id| map.lanes.get(id))
        {
            ring.extend_from_slice(&lane.centre);
        }
        let positions = c.positions(&ring);
        let closes = positions.len() >= 4
            && positions
                .first()
                .zip(positions.last())
                .is_some_and(|(a, b)| {
                    // The last lane ends where the first begins, up to a few centimetres.
                    (a[0] - b[0]).abs() < 1e-6 && (a[1] - b[1]).abs() < 1e-6
                });
        let geometry = if closes {
            c.polygon(&ring)
        } else {
            c.line(&ring)
        };
        push(
            geometry,
            Properties::Roundabout {
                circulating_lanes: &roundabout.circulating_lanes,
                clockwise: roundabout.clockwise,
                entries: roundabout.entries.len(),
                exits: roundabout.exits.len(),
                guessed: roundabout.source == RoundaboutSource::Guessed,
                id: roundabout.id.0,
                kind: "roundabout",
                osm_way_ids: &roundabout.osm_way_ids,
                priority: roundabout.priority,
                priority_source: roundabout.priority_source,
                radius_m: roundabout.radius_m,
                ring_lanes: roundabout.lanes_across,
                roundabout_kind: roundabout.kind,
                source: roundabout.source,
                yield_lines: roundabout.yield_lines.len(),
            },
        );
    }
    for mini in map.roundabouts.values() {
        let Some(osm_node_id) = mini.osm_node_id else {
            continue;
        };
        push(
            c.positions(&[mini.centre])
                .first()
                .map(|p| Geometry::Point(*p)),
            Properties::MiniRoundabout {
                entries: mini.entries.len(),
                exits: mini.exits.len(),
                id: mini.id.0,
                kind: "mini_roundabout",
                osm_node_id,
                priority: mini.priority,
                priority_source: mini.priority_source,
            },
        );
    }
    for stop in map.stop_lines.values() {
        let kind = match stop.kind {
            StopKind::Stop => "stop_line",
            StopKind::GiveWay => "give_way",
        };
        let source = match &stop.source {
            StopLineSource::OsmNode { id } => StopSource::OsmNode(*id),
            StopLineSource::RoundaboutEntry { roundabout } => {
                StopSource::RoundaboutEntry(roundabout.0)
            }
            StopLineSource::LaneletWay { id } => StopSource::LaneletWay(*id),
        };
        push(
            c.line(&stop.line),
            Properties::StopLine {
                id: stop.id.0,
                kind,
                lanes: &stop.lanes,
                source,
            },
        );
    }
    FeatureCollection {
        kind: "FeatureCollection",
        features,
    }
}

/// The GeoJSON as compact text (one line), deterministic for a given map.
pub fn to_geojson_string(map: &Map) -> Result<String, MapError> {
    serde_json::to_string(&to_geojson(map)).map_err(|e| MapError::Serialise(e.to_string()))
}

/// Writes the GeoJSON to a file.
pub fn save_geojson(map: &Map, path: &std::path::Path) -> Result<(), MapError> {
    let text = to_geojson_string(map)?;
    std::fs::write(path, text).map_err(|e| MapError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::*;
    use crate::projection::{LatLon, Projection};

    fn map_with_a_road_and_a_junction() -> Map {
        let origin = LatLon::new(42.0561, -87.6752);
        let mut map = Map::new(Projection::local(origin), DrivingSide::Right, "car");
        let line = vec![
            Point::new(0.0, 0.0),
            Point::new(0.001, 0.0),
            Point::new(100.0, 0.0),
        ];
        map.roads.insert(
            RoadId(0),
            Road {
                id: RoadId(0),
                source: RoadSource::OsmWay,
                osm_way_ids: vec![123],
                highway: "residential".into(),
                name: Some("Sheridan Road".into()),
                reference_line: line.clone(),
                start_junction: JunctionId(0),
                end_junction: JunctionId(0),
                lanes_forward: vec![LaneId(0)],
                lanes_backward: vec![],
                speed_limit_kmh: 40.0,
                speed_limit_is_default: true,
                is_roundabout: false,
                allows_cars: true,
            },
        );
        map.junctions.insert(
            JunctionId(0),
            Junction {
                id: JunctionId(0),
                kind: JunctionKind::Intersection,
                osm_node_id: Some(5),
                point: Point::new(0.0, 0.0),
                // Clockwise on purpose: the output must be counter-clockwise.
                polygon: vec![
                    Point::new(0.0, 0.0),
                    Point::new(0.0, 10.0),
                    Point::new(10.0, 10.0),
                    Point::new(10.0, 0.0),
                ],
                roads: vec![RoadId(0)],
                control: Some("traffic_signals".into()),
            },
        );
        map
    }

    #[test]
    fn lon_lat_order_rounding_and_closed_ccw_rings() {
        let map = map_with_a_road_and_a_junction();
        let fc = to_geojson(&map);
        assert_eq!(fc.features.len(), 2);
        let Geometry::LineString(road) = &fc.features[0].geometry else {
            panic!("road is not a LineString")
        };
        // 1 mm apart collapses after rounding to 7 decimals.
        assert_eq!(road.len(), 2);
        assert_eq!(road[0], [-87.6752, 42.0561]);
        assert!(road[1][0] > road[0][0], "east is increasing longitude");
        let Geometry::Polygon(rings) = &fc.features[1].geometry else {
            panic!("junction is not a Polygon")
        };
        let ring = &rings[0];
        assert_eq!(ring.len(), 5);
        assert_eq!(ring.first(), ring.last());
        assert!(ring_area(&ring[..4]) > 0.0);
        for p in ring {
            for v in p {
                assert_eq!(round(*v), *v);
            }
        }
        assert_eq!(fc.features[0].properties.kind(), "road");
        assert_eq!(fc.features[1].properties.kind(), "junction");
    }

    #[test]
    fn text_starts_with_the_type_and_is_deterministic() -> Result<(), MapError> {
        let map = map_with_a_road_and_a_junction();
        let a = to_geojson_string(&map)?;
        assert!(a.starts_with(r#"{"type":"FeatureCollection","features":[{"type":"Feature","geometry":{"type":"LineString","coordinates":[[-87.6752,42.0561]"#), "{a}");
        assert_eq!(a, to_geojson_string(&map)?);
        Ok(())
    }
}
