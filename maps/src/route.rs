//! Fastest routes over lanes, with waypoints every metre for a controller to follow.
//!
//! A route only ever moves from one lane to the next through a [`Connection`], and lanes are
//! one-directional, so no route can drive a lane against its direction. The search is A*
//! over the car lane graph ([`LaneGraph`]) with travel time as cost and the straight-line
//! distance at the map's highest speed limit as heuristic (never more than the true time,
//! so the route found is the fastest).

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use serde::{Deserialize, Serialize};

use crate::error::MapError;
use crate::geometry::{Point, polyline_length, slice_polyline};
use crate::graph::LaneGraph;
use crate::model::{ConnectionId, LaneId, Map};
use crate::spatial::LaneIndex;

/// Spacing of route waypoints, metres.
pub const WAYPOINT_SPACING_M: f64 = 1.0;

/// A place on a lane: arc length `s_m` along its centre line from the lane's start.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LanePosition {
    pub lane: LaneId,
    pub s_m: f64,
}

/// One sample of a route's path.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Waypoint {
    pub position: Point,
    /// Direction of travel, radians counter-clockwise from east.
    pub heading_rad: f64,
    /// Rate of change of heading along the path, 1/m (positive = turning left).
    pub curvature_per_m: f64,
    /// Distance along the route from its start, metres.
    pub s_m: f64,
    /// The lane the waypoint lies on; None inside a junction (on a connection).
    pub lane: Option<LaneId>,
}

/// A fastest path between two lane positions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Route {
    /// Lanes driven, in order (the first and last possibly only in part).
    pub lanes: Vec<LaneId>,
    /// Connections taken; `connections[i]` joins `lanes[i]` to `lanes[i + 1]`.
    pub connections: Vec<ConnectionId>,
    pub length_m: f64,
    /// At the speed limits of the lanes driven (a connection at its from-lane's limit).
    pub travel_time_s: f64,
    /// Every [`WAYPOINT_SPACING_M`] metres or less, both ends included.
    pub waypoints: Vec<Waypoint>,
}

/// Routes on one map, reusing its lane graph between queries. Only car lanes are used.
#[derive(Debug, Clone)]
pub struct Router<'a> {
    map: &'a Map,
    graph: LaneGraph,
    /// The car lanes' centre lines, for snapping points to lanes.
    index: LaneIndex,
    max_speed_mps: f64,
}

impl<'a> Router<'a> {
    pub fn new(map: &'a Map) -> Self {
        let graph = LaneGraph::new(map, true);
        let index = LaneIndex::new(map, graph.lanes.iter().copied());
        let max_speed_mps = graph
            .speed_mps
            .iter()
            .copied()
            .fold(f64::MIN_POSITIVE, f64::max);
        Router {
            map,
            graph,
            index,
            max_speed_mps,
        }
    }

    /// The lane graph routes run on (car lanes only).
    pub fn graph(&self) -> &LaneGraph {
        &self.graph
    }

    /// The nearest car lane to `p` (projection onto lane centre lines; ties go to the
    /// smaller lane id), with the distance to it.
    pub fn snap(&self, p: Point) -> Result<(LanePosition, f64), MapError> {
        if !p.is_finite() {
            return Err(MapError::NoRoute(format!(
                "point ({}, {}) is not finite",
                p.x, p.y
            )));
        }
        let best = self.index.nearest(self.map, p).map(|n| {
            (
                LanePosition {
                    lane: n.lane,
                    s_m: n.s_m,
                },
                n.distance_m,
            )
        });
        best.ok_or_else(|| MapError::NoRoute("the map has no car lanes".into()))
    }

    /// The fastest route between two points, each snapped to its nearest car lane.
    pub fn route(&self, from: Point, to: Point) -> Result<Route, MapError> {
        let (a, _) = self.snap(from)?;
        let (b, _) = self.snap(to)?;
        self.route_positions(a, b).map_err(|e| match e {
            MapError::NoRoute(m) => MapError::NoRoute(format!(
                "from ({:.1}, {:.1}) (lane {} at {:.1} m) to ({:.1}, {:.1}) (lane {} at {:.1} m): {m}",
                from.x, from.y, a.lane, a.s_m, to.x, to.y, b.lane, b.s_m
            )),
            other => other,
        })
    }

    /// The fastest route from the start of `from` to the end of `to`.
    pub fn route_lanes(&self, from: LaneId, to: LaneId) -> Result<Route, MapError> {
        let end = self
            .map
            .lanes
            .get(&to)
            .map_or(0.0, |l| polyline_length(&l.centre));
        self.route_positions(
            LanePosition {
                lane: from,
                s_m: 0.0,
            },
            LanePosition { lane: to, s_m: end },
        )
    }

    /// The fastest route between two lane positions. When both are on one lane and `to` is
    /// ahead of `from`, the route is that piece of the lane; otherwise A* over connections.
    pub fn route_positions(&self, from: LanePosition, to: LanePosition) -> Result<Route, MapError> {
        let (Some(start), Some(goal)) = (self.graph.index(from.lane), self.graph.index(to.lane))
        else {
            let bad = if self.graph.index(from.lane).is_none() {
                from.lane
            } else {
                to.lane
            };
            return Err(MapError::NoRoute(format!(
                "lane {bad} is not a car lane of this map"
            )));
        };
        let (Some(from_lane), Some(to_lane)) =
            (self.map.lanes.get(&from.lane), self.map.lanes.get(&to.lane))
        else {
            return Err(MapError::NoRoute("lane missing from the map".into()));
        };
        let s0 = from.s_m.clamp(0.0, polyline_length(&from_lane.centre));
        let s1 = to.s_m.clamp(0.0, polyline_length(&to_lane.centre));
        let (lanes, connections) = if start == goal && s1 >= s0 {
            (vec![from.lane], vec![])
        } else {
            self.search(start, s0, goal, to_lane.centre.as_slice())?
        };
        Ok(self.assemble(lanes, connections, s0, s1))
    }

    /// A* from position `s0` on node `start` to node `goal`. States are "at the start of
    /// lane n"; g is the time to get there counted from `s0`. The start lane's own state
    /// is never seeded, so a route from a lane back to an earlier point of itself goes
    /// round a loop.
    fn search(
        &self,
        start: usize,
        s0: f64,
        goal: usize,
        goal_centre: &[Point],
    ) -> Result<(Vec<LaneId>, Vec<ConnectionId>), MapError> {
        // The goal state is the start of the goal lane (every path onto the goal lane enters
        // there), so the heuristic aims at that point and is zero at the goal.
        let target = goal_centre.first().copied().unwrap_or_default();
        let n = self.graph.len();
        let mut best = vec![f64::INFINITY; n];
        // (previous node, connection, whether the previous node is the route's start).
        let mut parent: Vec<Option<(usize, ConnectionId, bool)>> = vec![None; n];
        let mut closed = vec![false; n];
        let mut heap = BinaryHeap::new();
        let start_offset = s0 / self.graph.speed_mps[start];
        for e in &self.graph.edges[start] {
            let g = e.cost_s - start_offset;
            if g < best[e.to] {
                best[e.to] = g;
                parent[e.to] = Some((start, e.connection, true));
                heap.push(Entry {
                    f: g + self.heuristic(e.to, target),
                    node: e.to,
                });
            }
        }
        while let Some(Entry { node, .. }) = heap.pop() {
            if closed[node] {
                continue;
            }
            closed[node] = true;
            if node == goal {
                return Ok(self.unwind(goal, &parent));
            }
            for e in &self.graph.edges[node] {
                let g = best[node] + e.cost_s;
                if g < best[e.to] {
                    best[e.to] = g;
                    parent[e.to] = Some((node, e.connection, false));
                    // Reopen: the heuristic is only approximately consistent when connection
                    // geometry does not meet lane ends exactly.
                    closed[e.to] = false;
                    heap.push(Entry {
                        f: g + self.heuristic(e.to, target),
                        node: e.to,
                    });
                }
            }
        }
        Err(MapError::NoRoute(format!(
            "lane {} cannot be reached from lane {} by following lane connections (they lie in different strongly connected parts of the lane graph)",
            self.graph.lanes[goal], self.graph.lanes[start]
        )))
    }

    fn heuristic(&self, node: usize, target: Point) -> f64 {
        let start = self
            .map
            .lanes
            .get(&self.graph.lanes[node])
            .and_then(|l| l.centre.first().copied())
            .unwrap_or(target);
        start.distance(target) / self.max_speed_mps
    }

    fn unwind(
        &self,
        goal: usize,
        parent: &[Option<(usize, ConnectionId, bool)>],
    ) -> (Vec<LaneId>, Vec<ConnectionId>) {
        let mut lanes = vec![self.graph.lanes[goal]];
        let mut conns = Vec::new();
        let mut node = goal;
        // A path visits each node at most once plus the start, so n + 1 steps bound the walk.
        for _ in 0..=self.graph.len() {
            let Some((prev, c, from_start)) = parent[node] else {
                break;
            };
            conns.push(c);
            lanes.push(self.graph.lanes[prev]);
            if from_start {
                break;
            }
            node = prev;
        }
        lanes.reverse();
        conns.reverse();
        (lanes, conns)
    }

    /// Path geometry, length, time and waypoints of a lane sequence.
    fn assemble(
        &self,
        lanes: Vec<LaneId>,
        connections: Vec<ConnectionId>,
        s0: f64,
        s1: f64,
    ) -> Route {
        let mut pieces: Vec<(Vec<Point>, Option<LaneId>, f64)> = Vec::new();
        let last = lanes.len() - 1;
        for (i, id) in lanes.iter().enumerate() {
            let Some(lane) = self.map.lanes.get(id) else {
                continue;
            };
            let len = polyline_length(&lane.centre);
            let (a, b) = (
                if i == 0 { s0 } else { 0.0 },
                if i == last { s1 } else { len },
            );
            let pts = if a <= 0.0 && b >= len {
                lane.centre.clone()
            } else {
                slice_polyline(&lane.centre, a, b)
            };
            pieces.push((pts, Some(*id), lane.speed_limit_kmh));
            if let Some(c) = connections.get(i).and_then(|c| self.map.connections.get(c)) {
                pieces.push((c.centre.clone(), None, lane.speed_limit_kmh));
            }
        }
        let mut travel_time_s = 0.0;
        let mut length_m = 0.0;
        for (pts, _, kmh) in &pieces {
            let l = polyline_length(pts);
            length_m += l;
            travel_time_s += l / crate::graph::lane_speed_mps(*kmh);
        }
        let waypoints = waypoints(
            &pieces
                .iter()
                .map(|(p, l, _)| (p.as_slice(), *l))
                .collect::<Vec<_>>(),
            WAYPOINT_SPACING_M,
        );
        Route {
            lanes,
            connections,
            length_m,
            travel_time_s,
            waypoints,
        }
    }
}

/// Heap entry: smallest f first, then the smallest node index (lane id order), so equal
/// costs always resolve the same way.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Entry {
    f: f64,
    node: usize,
}

impl Eq for Entry {}

impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        o.f.total_cmp(&self.f).then(o.node.cmp(&self.node))
    }
}

impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

/// Wraps an angle to (-pi, pi].
fn wrap_angle(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let w = a.rem_euclid(t);
    if w > std::f64::consts::PI { w - t } else { w }
}

/// Samples a path made of pieces (each a polyline, tagged with its lane or None) at equal
/// steps of at most `step` metres. Headings come from central differences of the samples
/// (one-sided at the ends), curvature from the change of heading over arc length.
pub fn waypoints(pieces: &[(&[Point], Option<LaneId>)], step: f64) -> Vec<Waypoint> {
    // Flatten into segments (a, b, lane, s at a), dropping zero-length ones.
    let mut segs: Vec<(Point, Point, Option<LaneId>, f64)> = Vec::new();
    let mut total = 0.0;
    let mut first: Option<(Point, Option<LaneId>)> = None;
    for (pts, lane) in pieces {
        if first.is_none() {
            first = pts.first().map(|p| (*p, *lane));
        }
        for w in pts.windows(2) {
            let len = w[0].distance(w[1]);
            if len > 0.0 && len.is_finite() {
                segs.push((w[0], w[1], *lane, total));
                total += len;
            }
        }
    }
    let Some((p0, lane0)) = first else {
        return Vec::new();
    };
    if segs.is_empty() {
        return vec![Waypoint {
            position: p0,
            heading_rad: 0.0,
            curvature_per_m: 0.0,
            s_m: 0.0,
            lane: lane0,
        }];
    }
    let n = ((total / step).ceil() as usize).max(1);
    let mut samples: Vec<(Point, f64, Option<LaneId>)> = Vec::with_capacity(n + 1);
    let mut k = 0;
    for i in 0..=n {
        let s = total * i as f64 / n as f64;
        while k + 1 < segs.len() && segs[k + 1].3 <= s {
            k += 1;
        }
        let (a, b, lane, s_a) = segs[k];
        let len = a.distance(b);
        let t = ((s - s_a) / len).clamp(0.0, 1.0);
        samples.push((a.lerp(b, t), s, lane));
    }
    // Heading of the segment under each sample, used where the samples are too close.
    let headings: Vec<f64> = (0..samples.len())
        .map(|i| {
            let (lo, hi) = (i.saturating_sub(1), (i + 1).min(samples.len() - 1));
            let d = samples[hi].0.sub(samples[lo].0);
            d.y.atan2(d.x)
        })
        .collect();
    let last = samples.len() - 1;
    samples
        .iter()
        .enumerate()
        .map(|(i, &(position, s_m, lane))| {
            let (lo, hi) = (i.saturating_sub(1), (i + 1).min(last));
            let ds = samples[hi].1 - samples[lo].1;
            let curvature_per_m = if ds > 0.0 {
                wrap_angle(headings[hi] - headings[lo]) / ds
            } else {
                0.0
            };
            Waypoint {
                position,
                heading_rad: headings[i],
                curvature_per_m,
                s_m,
                lane,
            }
        })
        .collect()
}

/// The fastest route between two points, each snapped to the nearest car lane.
pub fn route(map: &Map, from: Point, to: Point) -> Result<Route, MapError> {
    Router::new(map).route(from, to)
}

/// The fastest route from the start of lane `from` to the end of lane `to`.
pub fn route_lanes(map: &Map, from: LaneId, to: LaneId) -> Result<Route, MapError> {
    Router::new(map).route_lanes(from, to)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::print_stderr)]
mod tests {
    use super::*;
    use crate::geometry::project_onto_polyline;
    use crate::graph::test_maps;

    fn check_route(map: &Map, r: &Route) {
        assert_eq!(r.connections.len() + 1, r.lanes.len());
        for (i, c) in r.connections.iter().enumerate() {
            let c = &map.connections[c];
            assert_eq!(
                (c.from, c.to),
                (r.lanes[i], r.lanes[i + 1]),
                "connection {} does not join the route's lanes",
                c.id
            );
        }
        for w in r.waypoints.windows(2) {
            assert!(w[0].position.distance(w[1].position) <= WAYPOINT_SPACING_M + 1e-6);
            assert!(w[1].s_m > w[0].s_m);
        }
        let last = r.waypoints.last().unwrap();
        assert!((last.s_m - r.length_m).abs() < 1e-6 * r.length_m.max(1.0));
    }

    #[test]
    fn same_lane_ahead_is_the_piece_between() {
        let map = test_maps::square_loop();
        let r = route(&map, Point::new(10.0, 0.5), Point::new(60.0, -0.5)).unwrap();
        assert_eq!(r.lanes, vec![LaneId(0)]);
        assert!((r.length_m - 50.0).abs() < 1e-9);
        assert!((r.travel_time_s - 5.0).abs() < 1e-9);
        assert_eq!(r.waypoints.len(), 51);
        assert!(
            r.waypoints
                .iter()
                .all(|w| w.heading_rad.abs() < 1e-12 && w.curvature_per_m.abs() < 1e-12)
        );
        check_route(&map, &r);
    }

    #[test]
    fn same_lane_behind_goes_round_the_loop() {
        let map = test_maps::square_loop();
        let r = route(&map, Point::new(60.0, 0.0), Point::new(10.0, 0.0)).unwrap();
        assert_eq!(
            r.lanes,
            vec![LaneId(0), LaneId(1), LaneId(2), LaneId(3), LaneId(0)]
        );
        assert!((r.length_m - 350.0).abs() < 1e-9);
        check_route(&map, &r);
        // A quarter turn left at each corner of the square: a full turn in all.
        let turned: f64 = r
            .waypoints
            .windows(2)
            .map(|w| (w[0].curvature_per_m + w[1].curvature_per_m) / 2.0 * (w[1].s_m - w[0].s_m))
            .sum();
        assert!((turned - std::f64::consts::TAU).abs() < 0.05, "{turned}");
        assert_eq!(r.waypoints[0].lane, Some(LaneId(0)));
    }

    #[test]
    fn across_lanes_and_no_route() {
        let map = test_maps::square_loop();
        let r = route(&map, Point::new(50.0, 100.0), Point::new(150.0, 0.0)).unwrap();
        assert_eq!(r.lanes, vec![LaneId(2), LaneId(3), LaneId(0), LaneId(4)]);
        assert!((r.length_m - 300.0).abs() < 1e-9);
        check_route(&map, &r);
        let r = route_lanes(&map, LaneId(1), LaneId(0)).unwrap();
        assert_eq!(r.lanes, vec![LaneId(1), LaneId(2), LaneId(3), LaneId(0)]);
        assert!((r.length_m - 400.0).abs() < 1e-9);
        let err = route(&map, Point::new(150.0, 0.0), Point::new(50.0, 0.0)).unwrap_err();
        assert!(matches!(err, MapError::NoRoute(_)), "{err}");
        assert!(route_lanes(&map, LaneId(0), LaneId(5)).is_err());
    }

    /// splitmix64: a tiny deterministic generator, enough to draw test cases.
    struct SplitMix(u64);
    impl SplitMix {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n as u64) as usize
        }
        fn unit(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// Acceptance point 6: 1,000 random lane pairs in the largest strongly connected
    /// component of northwestern_nu all get a route, every step follows a connection.
    #[test]
    fn northwestern_random_routes() {
        let Some(map) = crate::graph::test_maps::shared_osm_map("northwestern_nu.osm.pbf") else {
            return;
        };
        let comps = crate::graph::strongly_connected_components(&map, true);
        let largest = &comps[0];
        assert!(
            largest.len() > 100,
            "largest component has only {} lanes",
            largest.len()
        );
        let router = Router::new(&map);
        let mut rng = SplitMix(0x5EED_0006);
        let (mut total_len, mut total_lanes, mut by_points) = (0.0, 0usize, 0usize);
        for _ in 0..1000 {
            let (a, b) = (
                largest[rng.below(largest.len())],
                largest[rng.below(largest.len())],
            );
            let (la, lb) = (&map.lanes[&a], &map.lanes[&b]);
            let sa = rng.unit() * polyline_length(&la.centre);
            let sb = rng.unit() * polyline_length(&lb.centre);
            let r = router
                .route_positions(
                    LanePosition { lane: a, s_m: sa },
                    LanePosition { lane: b, s_m: sb },
                )
                .unwrap_or_else(|e| panic!("{a}@{sa} -> {b}@{sb}: {e}"));
            assert_eq!((r.lanes[0], *r.lanes.last().unwrap()), (a, b));
            check_route(&map, &r);
            let (pa, pb) = (
                crate::geometry::point_at(&la.centre, sa),
                crate::geometry::point_at(&lb.centre, sb),
            );
            assert!(r.waypoints[0].position.distance(pa) < 1e-6);
            assert!(r.waypoints.last().unwrap().position.distance(pb) < 1e-6);
            // Waypoints on a lane head the lane's way (away from its ends, where a U-turn
            // connection may bend the central difference).
            for w in r.waypoints.iter().step_by(7) {
                let Some(lane) = w.lane.map(|l| &map.lanes[&l]) else {
                    continue;
                };
                let (s, d) = project_onto_polyline(&lane.centre, w.position);
                if d > 1e-6 || s < 2.0 || s > polyline_length(&lane.centre) - 2.0 {
                    continue;
                }
                let dir = crate::geometry::direction_at(&lane.centre, s);
                let dot = dir.x * w.heading_rad.cos() + dir.y * w.heading_rad.sin();
                assert!(
                    dot > 0.5,
                    "waypoint at {} m of lane {} heads against it",
                    s,
                    lane.id
                );
            }
            total_len += r.length_m;
            total_lanes += r.lanes.len();
            // The same query by points: snapping finds a lane through the point (maybe another
            // one where lanes overlap, e.g. at a bridge); when it is in the component, a route exists.
            let (snap_a, da) = router.snap(pa).unwrap();
            let (snap_b, db) = router.snap(pb).unwrap();
            assert!(da < 1e-6 && db < 1e-6);
            if largest.binary_search(&snap_a.lane).is_ok()
                && largest.binary_search(&snap_b.lane).is_ok()
            {
                let r = router.route(pa, pb).unwrap();
                assert!(r.waypoints[0].position.distance(pa) < 1e-6);
                assert!(r.waypoints.last().unwrap().position.distance(pb) < 1e-6);
                by_points += 1;
            }
        }
        eprintln!(
            "northwestern_nu: largest component {} lanes of {}; 1000 routes, mean {:.0} m over {:.1} lanes; {by_points} also routed by points",
            largest.len(),
            map.car_lanes().count(),
            total_len / 1000.0,
            total_lanes as f64 / 1000.0
        );
        assert!(by_points >= 990);
    }
}
