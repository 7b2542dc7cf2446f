//! The lane graph: one node per lane, one edge per connection.
//!
//! Lanes are one-directional and a vehicle can only move from one lane to another through a
//! [`Connection`](crate::model::Connection), so this graph is exactly what routing may use,
//! and its strongly connected components tell which lanes can reach each other (a lane
//! outside the largest component is a one-way trap or an island, often an import problem
//! worth a look).
//!
//! Nodes are numbered in lane-id order and edges listed in connection-id order, so every
//! traversal (and with it every output) is deterministic.

use std::collections::BTreeMap;

use crate::model::{ConnectionId, LaneId, Map};

/// Speed used for a lane whose speed limit is missing or not positive, km/h. Keeps travel
/// times finite instead of letting one bad tag make a lane unreachable.
const FALLBACK_SPEED_KMH: f64 = 30.0;

/// One movement from the end of a lane to the start of the next.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    /// Node index of the lane entered.
    pub to: usize,
    pub connection: ConnectionId,
    /// Length of the lane left plus the connection, metres.
    pub length_m: f64,
    /// Travel time of that length at the lane's speed limit, seconds.
    pub cost_s: f64,
}

/// Adjacency of the lanes of a map (optionally car lanes only).
#[derive(Debug, Clone, PartialEq)]
pub struct LaneGraph {
    /// Node index to lane id, ascending.
    pub lanes: Vec<LaneId>,
    /// Outgoing edges per node, in connection-id order.
    pub edges: Vec<Vec<Edge>>,
    /// Speed limit per node, metres per second (always positive).
    pub speed_mps: Vec<f64>,
    /// Lane length per node, metres.
    pub length_m: Vec<f64>,
}

/// A lane's speed limit in m/s, with a fallback for missing or broken values.
pub fn lane_speed_mps(speed_limit_kmh: f64) -> f64 {
    let kmh = if speed_limit_kmh.is_finite() && speed_limit_kmh > 0.0 {
        speed_limit_kmh
    } else {
        FALLBACK_SPEED_KMH
    };
    kmh / 3.6
}

impl LaneGraph {
    /// Builds the graph; with `cars_only`, lanes of roads cars may not use (and connections
    /// touching them) are left out.
    pub fn new(map: &Map, cars_only: bool) -> Self {
        let lanes: Vec<LaneId> = if cars_only {
            map.car_lanes().map(|l| l.id).collect()
        } else {
            map.lanes.keys().copied().collect()
        };
        let mut speed_mps = Vec::with_capacity(lanes.len());
        let mut length_m = Vec::with_capacity(lanes.len());
        for id in &lanes {
            let (speed, len) = map.lanes.get(id).map_or((FALLBACK_SPEED_KMH, 0.0), |l| {
                (l.speed_limit_kmh, l.length_m)
            });
            speed_mps.push(lane_speed_mps(speed));
            length_m.push(len.max(0.0));
        }
        let mut graph = LaneGraph {
            edges: vec![Vec::new(); lanes.len()],
            lanes,
            speed_mps,
            length_m,
        };
        for c in map.connections.values() {
            let (Some(from), Some(to)) = (graph.index(c.from), graph.index(c.to)) else {
                continue;
            };
            let length_m = graph.length_m[from] + c.length_m.max(0.0);
            let cost_s = length_m / graph.speed_mps[from];
            graph.edges[from].push(Edge {
                to,
                connection: c.id,
                length_m,
                cost_s,
            });
        }
        graph
    }

    /// Node index of a lane, if the lane is in the graph.
    pub fn index(&self, lane: LaneId) -> Option<usize> {
        self.lanes.binary_search(&lane).ok()
    }

    pub fn len(&self) -> usize {
        self.lanes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.lanes.is_empty()
    }

    /// Strongly connected components as lists of node indices (petgraph's Kosaraju, whose
    /// searches keep their own stack, so deep graphs cannot overflow the thread's: petgraph's
    /// Tarjan recurses and overflows on the 50,000-lane ring of the test below). Each component is sorted.
    pub fn components(&self) -> Vec<Vec<usize>> {
        let mut graph = petgraph::graph::DiGraph::<(), ()>::with_capacity(
            self.len(),
            self.edges.iter().map(Vec::len).sum(),
        );
        for _ in 0..self.len() {
            graph.add_node(());
        }
        for (from, edges) in self.edges.iter().enumerate() {
            for edge in edges {
                graph.add_edge(
                    petgraph::graph::NodeIndex::new(from),
                    petgraph::graph::NodeIndex::new(edge.to),
                    (),
                );
            }
        }
        petgraph::algo::kosaraju_scc(&graph)
            .into_iter()
            .map(|c| {
                let mut c: Vec<usize> = c.into_iter().map(|n| n.index()).collect();
                c.sort_unstable();
                c
            })
            .collect()
    }
}

/// Strongly connected components of the lane graph, largest total lane length first (ties:
/// more lanes first, then the smallest lane id), each listing its lanes in id order. With
/// `cars_only`, only car lanes and the connections between them count.
pub fn strongly_connected_components(map: &Map, cars_only: bool) -> Vec<Vec<LaneId>> {
    let graph = LaneGraph::new(map, cars_only);
    let mut comps: Vec<(f64, Vec<LaneId>)> = graph
        .components()
        .into_iter()
        .map(|c| {
            let len: f64 = c.iter().map(|&i| graph.length_m[i]).sum();
            (len, c.into_iter().map(|i| graph.lanes[i]).collect())
        })
        .collect();
    comps.sort_by(|a, b| {
        b.0.total_cmp(&a.0)
            .then(b.1.len().cmp(&a.1.len()))
            .then(a.1.first().cmp(&b.1.first()))
    });
    comps.into_iter().map(|(_, c)| c).collect()
}

/// Total lane length of a set of lanes, metres (lanes missing from the map count zero).
pub fn lanes_length_m(map: &Map, lanes: &[LaneId]) -> f64 {
    lanes
        .iter()
        .filter_map(|l| map.lanes.get(l))
        .map(|l| l.length_m)
        .sum()
}

/// For each lane, the index (into `components`) of the component that holds it.
pub fn component_of(components: &[Vec<LaneId>]) -> BTreeMap<LaneId, usize> {
    let mut out = BTreeMap::new();
    for (i, c) in components.iter().enumerate() {
        for &l in c {
            out.insert(l, i);
        }
    }
    out
}

#[cfg(test)]
pub(crate) mod test_maps {
    //! Small hand-made maps for the tests of graph, route, raster, preview and summary.

    use crate::geometry::{Point, offset_polyline, polyline_length};
    use crate::model::*;
    use crate::projection::{LatLon, Projection};

    /// Imports `../shared/data/osm/<file>` with default options, or prints a skip notice and
    /// returns None when the data folder is absent (a user's clone).
    #[allow(clippy::print_stderr, clippy::unwrap_used)]
    pub fn shared_osm_map(file: &str) -> Option<Map> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/osm")
            .join(file);
        if !path.exists() {
            eprintln!(
                "skipped: {}: {} not found",
                std::thread::current().name().unwrap_or("-"),
                path.display()
            );
            return None;
        }
        Some(crate::build::import_file(&path, &Default::default()).unwrap())
    }

    /// A map of straight one-lane roads: `lanes` are (start, end) of each lane centre
    /// (ids 0, 1, ...; one road per lane, `highway=residential`, 36 km/h, 3.5 m wide), and
    /// `connections` are (from, to) lane indices joined by a straight connection.
    pub fn straight_lanes(lanes: &[(Point, Point)], connections: &[(u32, u32)]) -> Map {
        let mut map = Map::new(
            Projection::local(LatLon::new(0.0, 0.0)),
            DrivingSide::Right,
            "car",
        );
        for (i, &(a, b)) in lanes.iter().enumerate() {
            let i = i as u32;
            let (j0, j1) = (JunctionId(2 * i), JunctionId(2 * i + 1));
            for (j, p) in [(j0, a), (j1, b)] {
                map.junctions.insert(
                    j,
                    Junction {
                        id: j,
                        kind: JunctionKind::DeadEnd,
                        osm_node_id: None,
                        point: p,
                        polygon: vec![],
                        roads: vec![RoadId(i)],
                        control: None,
                    },
                );
            }
            let centre = vec![a, b];
            map.roads.insert(
                RoadId(i),
                Road {
                    id: RoadId(i),
                    source: RoadSource::OsmWay,
                    osm_way_ids: vec![i64::from(i) + 100],
                    highway: "residential".into(),
                    name: None,
                    reference_line: centre.clone(),
                    start_junction: j0,
                    end_junction: j1,
                    lanes_forward: vec![LaneId(i)],
                    lanes_backward: vec![],
                    speed_limit_kmh: 36.0,
                    speed_limit_is_default: false,
                    is_roundabout: false,
                    allows_cars: true,
                },
            );
            map.lanes.insert(
                LaneId(i),
                Lane {
                    id: LaneId(i),
                    road: RoadId(i),
                    direction: Direction::Forward,
                    index_from_centre: 0,
                    left: offset_polyline(&centre, 1.75),
                    right: offset_polyline(&centre, -1.75),
                    length_m: polyline_length(&centre),
                    centre,
                    width_m: 3.5,
                    speed_limit_kmh: 36.0,
                    turns: vec![],
                    from_junction: j0,
                    to_junction: j1,
                },
            );
        }
        for (k, &(from, to)) in connections.iter().enumerate() {
            let (a, b) = (
                map.lanes[&LaneId(from)].clone(),
                map.lanes[&LaneId(to)].clone(),
            );
            let centre = vec![*a.centre.last().unwrap_or(&a.centre[0]), b.centre[0]];
            let id = ConnectionId(k as u32);
            map.connections.insert(
                id,
                Connection {
                    id,
                    junction: a.to_junction,
                    from: a.id,
                    to: b.id,
                    turn: Turn::Straight,
                    length_m: polyline_length(&centre),
                    centre,
                },
            );
        }
        map
    }

    /// A square loop of four 100 m lanes (0 -> 1 -> 2 -> 3 -> 0, counter-clockwise) with a
    /// 100 m spur (lane 4) leaving the corner after lane 0 and a dead-end lane 5 nobody
    /// reaches.
    pub fn square_loop() -> Map {
        let p = |x: f64, y: f64| Point::new(x, y);
        straight_lanes(
            &[
                (p(0.0, 0.0), p(100.0, 0.0)),
                (p(100.0, 0.0), p(100.0, 100.0)),
                (p(100.0, 100.0), p(0.0, 100.0)),
                (p(0.0, 100.0), p(0.0, 0.0)),
                (p(100.0, 0.0), p(200.0, 0.0)),
                (p(300.0, 0.0), p(400.0, 0.0)),
            ],
            &[(0, 1), (1, 2), (2, 3), (3, 0), (0, 4)],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn components_of_a_loop_with_a_spur() {
        let map = test_maps::square_loop();
        let comps = strongly_connected_components(&map, true);
        assert_eq!(comps.len(), 3);
        assert_eq!(comps[0], vec![LaneId(0), LaneId(1), LaneId(2), LaneId(3)]);
        // Equal lengths: the smaller lane id first.
        assert_eq!(comps[1], vec![LaneId(4)]);
        assert_eq!(comps[2], vec![LaneId(5)]);
    }

    #[test]
    fn edge_cost_is_travel_time() {
        let map = test_maps::square_loop();
        let g = LaneGraph::new(&map, true);
        let e = g.edges[0][0];
        // 100 m lane + 0 m connection at 10 m/s.
        assert!((e.cost_s - 10.0).abs() < 1e-9);
        assert_eq!(g.edges[0].len(), 2);
    }

    #[test]
    fn deep_chain_does_not_overflow() {
        let n = 50_000u32;
        let lanes: Vec<_> = (0..n)
            .map(|i| {
                (
                    crate::geometry::Point::new(f64::from(i), 0.0),
                    crate::geometry::Point::new(f64::from(i) + 1.0, 0.0),
                )
            })
            .collect();
        let mut conns: Vec<_> = (0..n - 1).map(|i| (i, i + 1)).collect();
        conns.push((n - 1, 0));
        let map = test_maps::straight_lanes(&lanes, &conns);
        let comps = strongly_connected_components(&map, false);
        assert_eq!(comps.len(), 1);
        assert_eq!(comps[0].len(), n as usize);
    }
}
