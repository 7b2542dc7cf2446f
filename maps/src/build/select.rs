//! Step 1: choose the ways the profile wants, split them at shared nodes, and make roads and
//! junctions of them.

use std::collections::{BTreeMap, BTreeSet};

use crate::error::MapError;
use crate::geometry::{Bounds, Point, polyline_length};
use crate::invariants::check_invariants;
use crate::model::{
    Junction, JunctionId, JunctionKind, Map, Road, RoadId, RoadSource, RoundaboutKind,
    RoundaboutSource,
};
use crate::osm::{OsmData, Tags};
use crate::projection::{LatLon, Projection};
use crate::tags;

use super::mini::MiniRings;
use crate::options::{Clip, ImportOptions};

/// Per road, what the later steps need from its way.
#[derive(Debug, Clone)]
pub(super) struct RoadInfo<'a> {
    pub tags: &'a Tags,
    /// OSM node ids along the reference line (before trimming).
    pub nodes: Vec<i64>,
    pub lanes_forward: u8,
    pub lanes_backward: u8,
    pub lane_width: f64,
}

impl RoadInfo<'_> {
    /// Width of the carriageway to the right (negative side) and left of the reference line.
    pub fn half_widths(&self, side: crate::model::DrivingSide) -> (f64, f64) {
        let (f, b) = (
            f64::from(self.lanes_forward),
            f64::from(self.lanes_backward),
        );
        let w = self.lane_width;
        if f == 0.0 || b == 0.0 {
            let half = (f + b) * w / 2.0;
            return (half, half);
        }
        match side {
            crate::model::DrivingSide::Right => (f * w, b * w),
            crate::model::DrivingSide::Left => (b * w, f * w),
        }
    }
}

/// One group of tagged ring ways (sharing nodes), as `find_rings` found it, or a guessed
/// loop (`connect_rings`). Defined here, next to the [`Builder`] that holds the rings, so
/// that the roundabout steps build on this module and not the other way round.
#[derive(Debug, Clone)]
pub(crate) struct Ring {
    pub source: RoundaboutSource,
    /// The ring's OSM ways, sorted.
    pub ways: Vec<i64>,
    pub kind: RoundaboutKind,
    /// The roads made of those ways, sorted.
    pub roads: Vec<RoadId>,
    /// Why the ring cannot be a roundabout; None when it may be one.
    pub broken: Option<String>,
    /// Problems that do not keep it from being a roundabout, listed with whether it is one.
    pub warnings: Vec<String>,
}

/// The map under construction plus what the steps need from the OSM data.
#[derive(Debug)]
pub(crate) struct Builder<'a> {
    pub osm: &'a OsmData,
    pub options: &'a ImportOptions,
    pub map: Map,
    pub info: BTreeMap<RoadId, RoadInfo<'a>>,
    pub junction_of_node: BTreeMap<i64, JunctionId>,
    /// Tagged rings found by `find_rings`, in order of their ways, then the guessed loops.
    pub rings: Vec<Ring>,
    /// The rings made of mini-roundabout nodes (`None` when the data has none).
    pub minis: Option<&'a MiniRings>,
}

impl<'a> Builder<'a> {
    pub fn check(&self, step: &'static str) -> Result<(), MapError> {
        if self.options.check_invariants {
            check_invariants(&self.map, step)
        } else {
            Ok(())
        }
    }

    /// Selects ways, drops broken ones (counted), splits at shared nodes and self-touches.
    pub fn select_roads(
        osm: &'a OsmData,
        options: &'a ImportOptions,
        minis: Option<&'a MiniRings>,
    ) -> Result<Self, MapError> {
        let mut report = crate::model::ImportReport {
            invalid_nodes: osm.invalid_nodes.len(),
            ..Default::default()
        };
        // Node runs per selected way: clipping can cut one way into several runs.
        let mut runs: Vec<(i64, Vec<i64>)> = Vec::new();
        let mut selected = 0usize;
        let clip = options.clip.as_ref().map(Clip::region);
        for (&way_id, way) in &osm.ways {
            if !options.profile.selects(&way.tags) {
                continue;
            }
            selected += 1;
            if way.nodes.iter().any(|n| !osm.nodes.contains_key(n)) {
                report.ways_missing_nodes.push(way_id);
                continue;
            }
            let mut nodes = way.nodes.clone();
            nodes.dedup();
            let mut current: Vec<i64> = Vec::new();
            for n in nodes {
                let inside = clip
                    .as_ref()
                    .is_none_or(|c| osm.nodes.get(&n).is_some_and(|node| c.contains(node.pos)));
                if inside {
                    current.push(n);
                } else if !current.is_empty() {
                    runs.push((way_id, std::mem::take(&mut current)));
                }
            }
            if !current.is_empty() {
                runs.push((way_id, current));
            }
        }
        if selected == 0 {
            return Err(MapError::Invalid {
                path: None,
                message: format!(
                    "no way matches the `{}` road profile: nothing to import (is this the right file, or do you want another --profile?)",
                    options.profile.name
                ),
            });
        }
        let broken = report.ways_missing_nodes.len();
        if broken * 2 > selected {
            let sample: Vec<String> = report
                .ways_missing_nodes
                .iter()
                .take(5)
                .map(|w| w.to_string())
                .collect();
            return Err(MapError::Invalid {
                path: None,
                message: match osm.invalid_nodes.first() {
                    None => format!(
                        "{broken} of {selected} selected ways reference nodes missing from the file (ways {}...): the extract is incomplete; export it with complete ways",
                        sample.join(", ")
                    ),
                    Some(node) => format!(
                        "{broken} of {selected} selected ways use nodes that are missing or have impossible coordinates ({} nodes outside WGS84's range, e.g. node {node}); fix or re-export the file",
                        osm.invalid_nodes.len()
                    ),
                },
            });
        }
        runs.retain(|(_, r)| r.len() >= 2);
        if runs.is_empty() {
            return Err(MapError::Invalid {
                path: None,
                message: "no road is left after clipping and dropping broken ways".into(),
            });
        }

        let origin = options.origin.unwrap_or_else(|| centre_of(osm, &runs));
        let projection = Projection::local(origin);
        let projector = projection.projector();
        let side = options
            .driving_side
            .unwrap_or_else(|| tags::driving_side_at(origin));

        // A node splits ways where two runs share it, where one run passes it twice, and at run ends.
        let mut uses: BTreeMap<i64, u32> = BTreeMap::new();
        for (_, r) in &runs {
            for n in r {
                *uses.entry(*n).or_default() += 1;
            }
        }
        let mut split: BTreeSet<i64> = uses
            .iter()
            .filter(|(_, c)| **c >= 2)
            .map(|(n, _)| *n)
            .collect();
        for (_, r) in &runs {
            split.insert(r[0]);
            split.insert(r[r.len() - 1]);
        }
        // A mini-roundabout is a junction even where only one way passes through it.
        split.extend(uses.keys().copied().filter(|n| {
            osm.nodes
                .get(n)
                .is_some_and(|node| node.tags.is("highway", "mini_roundabout"))
        }));

        let project = |n: i64| -> Point {
            osm.nodes
                .get(&n)
                .map(|node| projector.project(node.pos))
                .unwrap_or_default()
        };
        let mut builder = Builder {
            osm,
            options,
            map: Map::new(projection, side, &options.profile.name),
            info: BTreeMap::new(),
            junction_of_node: BTreeMap::new(),
            rings: Vec::new(),
            minis,
        };
        let mut pieces: Vec<(i64, Vec<i64>)> = Vec::new();
        for (way_id, r) in &runs {
            let mut piece = vec![r[0]];
            for &n in &r[1..] {
                piece.push(n);
                if split.contains(&n) {
                    pieces.push((*way_id, std::mem::replace(&mut piece, vec![n])));
                }
            }
        }
        // A piece that closes on itself (a loop way with no other split node) is cut in two so
        // that every road joins two different junctions.
        let mut final_pieces = Vec::with_capacity(pieces.len());
        for (w, p) in pieces {
            if p.first() == p.last() && p.len() >= 3 {
                let mid = p.len() / 2;
                final_pieces.push((w, p[..=mid].to_vec()));
                final_pieces.push((w, p[mid..].to_vec()));
            } else {
                final_pieces.push((w, p));
            }
        }
        // Each node is projected once (ends of pieces are used several times), on every core.
        let positions: BTreeMap<i64, Point> = {
            use rayon::prelude::*;
            let ids: BTreeSet<i64> = final_pieces
                .iter()
                .flat_map(|(_, p)| p.iter().copied())
                .collect();
            let ids: Vec<i64> = ids.into_iter().collect();
            let points: Vec<Point> = ids.par_iter().map(|&n| project(n)).collect();
            ids.into_iter().zip(points).collect()
        };
        let pos = |n: i64| -> Point { positions.get(&n).copied().unwrap_or_else(|| project(n)) };
        for (way_id, nodes) in final_pieces {
            let mut line: Vec<Point> = nodes.iter().map(|&n| pos(n)).collect();
            // Zero-length segments (distinct nodes at one position) are dropped; the end nodes stay.
            crate::geometry::dedup_points(&mut line, 1e-6);
            if line.len() < 2 || polyline_length(&line) < 0.05 {
                let way_id = minis.map_or(way_id, |m| m.original_way(way_id));
                if !report.degenerate_ways.contains(&way_id) {
                    report.degenerate_ways.push(way_id);
                }
                continue;
            }
            let Some(way) = osm.ways.get(&way_id) else {
                continue;
            };
            let (start, end) = (nodes[0], nodes[nodes.len() - 1]);
            let start_j = builder.junction_at(start, pos(start));
            let end_j = builder.junction_at(end, pos(end));
            let id = RoadId(builder.map.roads.len() as u32);
            let highway = way.tags.get("highway").unwrap_or("road").to_owned();
            let (lanes_forward, lanes_backward) = tags::lane_counts(&way.tags, &highway);
            let lane_width = tags::lane_width(&way.tags, &highway, lanes_forward + lanes_backward);
            let (speed, is_default) = tags::speed_limit_kmh(&way.tags, &highway, None);
            builder.map.roads.insert(
                id,
                Road {
                    id,
                    source: RoadSource::OsmWay,
                    osm_way_ids: vec![minis.map_or(way_id, |m| m.original_way(way_id))],
                    highway: highway.clone(),
                    name: way.tags.get("name").map(str::to_owned),
                    reference_line: line,
                    start_junction: start_j,
                    end_junction: end_j,
                    lanes_forward: Vec::new(),
                    lanes_backward: Vec::new(),
                    speed_limit_kmh: speed,
                    speed_limit_is_default: is_default,
                    is_roundabout: tags::is_roundabout(&way.tags),
                    allows_cars: options.profile.cars_allowed(&way.tags),
                },
            );
            builder.info.insert(
                id,
                RoadInfo {
                    tags: &way.tags,
                    nodes,
                    lanes_forward,
                    lanes_backward,
                    lane_width,
                },
            );
            for j in [start_j, end_j] {
                if let Some(junction) = builder.map.junctions.get_mut(&j) {
                    junction.roads.push(id);
                }
            }
        }
        if builder.map.roads.is_empty() {
            return Err(MapError::Invalid {
                path: None,
                message: "every selected way is degenerate (fewer than two distinct positions)"
                    .into(),
            });
        }
        // Junctions without a road (every road at them was degenerate) go; the rest get a kind.
        builder.map.junctions.retain(|_, j| !j.roads.is_empty());
        builder
            .junction_of_node
            .retain(|_, j| builder.map.junctions.contains_key(j));
        for j in builder.map.junctions.values_mut() {
            // Each road end at a junction added the road to its list once.
            let ends = j.roads.len();
            j.kind = match ends {
                0 | 1 => JunctionKind::DeadEnd,
                2 => JunctionKind::Continuation,
                _ => JunctionKind::Intersection,
            };
            j.control = j
                .osm_node_id
                .and_then(|n| osm.nodes.get(&n))
                .and_then(|n| junction_control(&n.tags));
        }
        builder.map.report = report;
        Ok(builder)
    }

    /// Lanes of the roads that end at junction `j` (each lane once, in id order).
    pub fn lanes_at(&self, j: JunctionId) -> Vec<&crate::model::Lane> {
        let mut roads: Vec<RoadId> = self
            .map
            .junctions
            .get(&j)
            .map(|x| x.roads.clone())
            .unwrap_or_default();
        roads.sort_unstable();
        roads.dedup();
        let mut lanes: Vec<&crate::model::Lane> = roads
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .flat_map(|r| r.lanes())
            .filter_map(|l| self.map.lanes.get(&l))
            .collect();
        lanes.sort_by_key(|l| l.id);
        lanes
    }

    fn junction_at(&mut self, node: i64, point: Point) -> JunctionId {
        if let Some(j) = self.junction_of_node.get(&node) {
            return *j;
        }
        let id = JunctionId(self.map.junctions.len() as u32);
        self.map.junctions.insert(
            id,
            Junction {
                id,
                kind: JunctionKind::DeadEnd,
                osm_node_id: Some(node),
                point,
                polygon: Vec::new(),
                roads: Vec::new(),
                control: None,
            },
        );
        self.junction_of_node.insert(node, id);
        id
    }
}

fn junction_control(tags: &Tags) -> Option<String> {
    match tags.get("highway") {
        Some("traffic_signals") => Some("traffic_signals".into()),
        Some("stop") if tags.is("stop", "all") => Some("all_way_stop".into()),
        Some("stop") => Some("stop".into()),
        Some("give_way") => Some("give_way".into()),
        Some("mini_roundabout") => Some("mini_roundabout".into()),
        _ => None,
    }
}

/// Centre of the bounding box of the selected nodes: the default projection origin.
fn centre_of(osm: &OsmData, runs: &[(i64, Vec<i64>)]) -> LatLon {
    let mut b = Bounds::empty();
    for (_, r) in runs {
        for n in r {
            if let Some(node) = osm.nodes.get(n) {
                b.extend(Point::new(node.pos.lon, node.pos.lat));
            }
        }
    }
    let c = b.center();
    LatLon { lat: c.y, lon: c.x }
}
