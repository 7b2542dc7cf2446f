//! The routes through one roundabout of a map: every entry arm to every exit arm, each from
//! a stretch before the yield line, round the ring, to a stretch past the exit. The traffic
//! world and the insertion task share these routes (prepared once per map), so vehicles on
//! one approach always compare positions along the same geometry.

use std::collections::{BTreeMap, BTreeSet, BinaryHeap};

use maps::geometry::{Bounds, polyline_length};
use maps::{ConnectionId, LaneId, Map, Point, Roundabout, RoundaboutId};
use serde::{Deserialize, Serialize};

use crate::error::SimError;
use crate::path::{Path, PieceKey, SpeedProfile};
use crate::scene::OrientedBox;

/// How far routes reach before and after the ring.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LayoutConfig {
    /// Length of approach before the yield line, metres (less where the map ends sooner).
    pub approach_m: f64,
    /// Length of the exit after leaving the ring, metres (less where the map ends sooner).
    pub exit_m: f64,
    /// Lateral acceleration drivers accept in curves, m/s².
    pub lateral_accel_mps2: f64,
    /// A car waiting at a yield line keeps at least this far from the footprints of traffic
    /// entering, circulating or leaving (mini roundabouts put mapped lines right at the
    /// ring's edge, where cars sweeping round would clip a waiting car), m. The line is
    /// moved back along the approach until that holds.
    pub waiting_clearance_m: f64,
    /// Routes are rounded off where the mapped lanes turn tighter than this radius (see
    /// [`SpeedProfile::min_turn_radius_m`]); above the ego's own turning circle, so it can
    /// steer every route, m.
    pub min_turn_radius_m: f64,
}

impl Default for LayoutConfig {
    fn default() -> Self {
        LayoutConfig {
            approach_m: 22.0,
            exit_m: 10.0,
            lateral_accel_mps2: 2.5,
            waiting_clearance_m: 0.5,
            min_turn_radius_m: 5.0,
        }
    }
}

/// One lane of an arm: entering the ring (an entry) or leaving it (an exit).
#[derive(Debug, Clone, PartialEq)]
pub struct ArmLane {
    pub road: maps::RoadId,
    pub lane: LaneId,
}

/// Every lane of `arms` that the map has.
fn arm_lanes(map: &Map, arms: &[maps::RoundaboutArm]) -> Vec<ArmLane> {
    arms.iter()
        .flat_map(|a| a.lanes.iter().map(|&lane| ArmLane { road: a.road, lane }))
        .filter(|e| map.lanes.contains_key(&e.lane))
        .collect()
}

/// A route from one entry to one exit, with the places along it that matter.
#[derive(Debug, Clone)]
pub struct RingRoute {
    pub entry: usize,
    pub exit: usize,
    pub path: Path,
    /// Where a driver gives way, metres along the path: the mapped yield line (or the
    /// ring's edge when the map has none), moved back as far as
    /// [`LayoutConfig::waiting_clearance_m`] asks.
    pub yield_s: f64,
    /// Start of the first ring lane: where the route joins circulating traffic.
    pub merge_s: f64,
    pub merge_lane: LaneId,
    /// Start of the exit lane: where the route leaves the ring.
    pub exit_s: f64,
    /// Ring lanes driven, each with where it starts along the path, in driving order.
    pub ring_lanes: Vec<(LaneId, f64)>,
    /// Lanes of the merge lane's ring road outside it, outermost first: an entry into an
    /// inner lane of a multi-lane ring crosses them, and gives way to their traffic as to
    /// the merge lane's. Empty where the route joins the outer lane.
    pub crossed_lanes: Vec<LaneId>,
    /// Routes from other entries that do not drive this route's merge lane but whose cars
    /// still touch a car entering here (typically cars leaving the ring at this arm, whose
    /// exit curve sweeps the entry's mouth): a driver at this yield line waits for them as
    /// for circulating traffic. See [`EntryConflict`].
    pub entry_conflicts: Vec<EntryConflict>,
}

/// Where a car on route `route` touches a car entering on another route: while its centre
/// is within `from_s..to_s` along its own path, some pose of the entering car between its
/// yield line and its merge point (centre) overlaps it, heading another way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EntryConflict {
    pub route: usize,
    pub from_s: f64,
    pub to_s: f64,
}

impl RingRoute {
    /// Where lane `lane` starts along this route, if the route drives it in the ring.
    pub fn ring_lane_start(&self, lane: LaneId) -> Option<f64> {
        self.ring_lanes
            .iter()
            .find(|(l, _)| *l == lane)
            .map(|(_, s)| *s)
    }

    /// Where ring lane `lane` ends along this route (where the piece after it starts), if
    /// the route drives it.
    pub fn ring_lane_end(&self, lane: LaneId) -> Option<f64> {
        self.ring_lane_start(lane)?;
        self.path
            .pieces()
            .iter()
            .find(|p| p.key == PieceKey::Lane(lane))
            .map(|p| p.s_end)
    }

    /// The ring lanes a car at this yield line gives way to: the merge lane, then the
    /// lanes it crosses to reach it.
    pub fn yield_lanes(&self) -> impl Iterator<Item = LaneId> + '_ {
        std::iter::once(self.merge_lane).chain(self.crossed_lanes.iter().copied())
    }
}

/// Every usable route through one roundabout.
#[derive(Debug, Clone)]
pub struct RoundaboutLayout {
    pub roundabout: RoundaboutId,
    pub centre: Point,
    pub radius_m: f64,
    pub entries: Vec<ArmLane>,
    pub exits: Vec<ArmLane>,
    pub routes: Vec<RingRoute>,
    /// Indices into `routes` by entry.
    pub routes_by_entry: Vec<Vec<usize>>,
    /// Each ring lane's place across its ring road: 0 for the outermost lane (every lane
    /// of a single-lane ring), 1 for the one inside it, and so on.
    pub ring_lane_ranks: BTreeMap<LaneId, u8>,
    /// Each ring lane's road: lanes of one road run side by side.
    pub ring_lane_roads: BTreeMap<LaneId, maps::RoadId>,
    /// The box holding every route.
    pub bounds: Bounds,
}

/// Lanes a route may cross between an entry lane and the ring (Lanelet2 maps split
/// approaches into several lanelets).
const MAX_LANES_BEFORE_RING: usize = 3;
/// Lanes walked at most when extending an approach backwards or an exit forwards.
const MAX_EXTENSION_LANES: usize = 64;

impl RoundaboutLayout {
    /// The routes through roundabout `id` of `map`. Fails when it has no entry from which
    /// an exit can be reached through the ring.
    pub fn new(map: &Map, id: RoundaboutId, config: &LayoutConfig) -> Result<Self, SimError> {
        let rb = map
            .roundabouts
            .get(&id)
            .ok_or_else(|| SimError::Map(format!("roundabout {id} is not in the map")))?;
        let ring: BTreeSet<LaneId> = rb.ring_lanes.iter().copied().collect();
        let ranks = ring_lane_ranks(map, rb);
        let outgoing = map.outgoing();
        let entries = arm_lanes(map, &rb.entries);
        let exits = arm_lanes(map, &rb.exits);
        let profile = SpeedProfile {
            lateral_accel_mps2: config.lateral_accel_mps2,
            min_turn_radius_m: config.min_turn_radius_m,
            ..SpeedProfile::default()
        };
        let mut routes = Vec::new();
        let mut routes_by_entry = vec![Vec::new(); entries.len()];
        for (ei, entry) in entries.iter().enumerate() {
            for (xi, exit) in exits.iter().enumerate() {
                if exit.road == entry.road {
                    continue; // a U-turn back into the road it came from
                }
                let Some(route) = build_route(
                    map,
                    rb,
                    (&ring, &ranks),
                    &outgoing,
                    (ei, entry),
                    (xi, exit),
                    config,
                    profile,
                ) else {
                    continue;
                };
                routes_by_entry[ei].push(routes.len());
                routes.push(route);
            }
        }
        set_back_yield_points(&mut routes, config.waiting_clearance_m);
        find_entry_conflicts(&mut routes);
        if routes.is_empty() {
            return Err(SimError::Map(format!(
                "roundabout {id} has no entry from which an exit can be reached through the ring"
            )));
        }
        let mut bounds = Bounds::empty();
        for r in &routes {
            for p in r.path.outline() {
                bounds.extend(*p);
            }
        }
        Ok(RoundaboutLayout {
            roundabout: id,
            centre: rb.centre,
            radius_m: rb.radius_m,
            entries,
            exits,
            routes,
            routes_by_entry,
            ring_lane_ranks: ranks,
            ring_lane_roads: rb
                .ring_lanes
                .iter()
                .filter_map(|l| Some((*l, map.lanes.get(l)?.road)))
                .collect(),
            bounds,
        })
    }

    /// Entries that have at least one route.
    pub fn usable_entries(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.entries.len()).filter(|&e| !self.routes_by_entry[e].is_empty())
    }

    /// The rank ([`RoundaboutLayout::ring_lane_ranks`]) of the ring lane under piece
    /// `piece` of route `route`: a ring lane's own, the outer of the two ring lanes a
    /// connection joins (a lane change counts on both lanes), the ring lane an exit
    /// connection leaves; None off the ring.
    pub fn ring_rank_at(&self, route: usize, piece: usize) -> Option<u8> {
        let pieces = self.routes.get(route)?.path.pieces();
        let rank = |i: usize| match pieces.get(i)?.key {
            PieceKey::Lane(l) => self.ring_lane_ranks.get(&l).copied(),
            PieceKey::Connection(_) => None,
        };
        match pieces.get(piece)?.key {
            PieceKey::Lane(_) => rank(piece),
            PieceKey::Connection(_) => {
                let before = rank(piece.checked_sub(1)?)?;
                Some(rank(piece + 1).map_or(before, |after| before.min(after)))
            }
        }
    }

    /// The first roundabout of the map (in id order) that has usable routes.
    pub fn first_in(map: &Map, config: &LayoutConfig) -> Result<Self, SimError> {
        let mut last_err = SimError::Map("the map has no roundabout".into());
        for id in map.roundabouts.keys() {
            match Self::new(map, *id, config) {
                Ok(layout) => return Ok(layout),
                Err(e) => last_err = e,
            }
        }
        Err(last_err)
    }
}

/// The largest car the world spawns (see `TrafficConfig`), m: waiting positions are
/// checked with this footprint.
const CAR_LENGTH_M: f64 = 4.9;
const CAR_WIDTH_M: f64 = 2.0;
/// Step of the search for a clear waiting position, and of the swept poses, m.
const SET_BACK_STEP_M: f64 = 0.25;
/// The farthest a yield point is moved back, m.
const MAX_SET_BACK_M: f64 = 10.0;

/// Moves each route's yield point back until a car waiting there (front at the point),
/// grown by `clearance` on every side, touches none of the footprints that cars sweep
/// along every route from another entry, from just before its merge point to a little
/// past its exit.
fn set_back_yield_points(routes: &mut [RingRoute], clearance: f64) {
    let swept: Vec<(usize, Vec<OrientedBox>)> = routes
        .iter()
        .map(|r| {
            let to = (r.exit_s + 10.0).min(r.path.length());
            let boxes = car_poses(r, r.merge_s - 3.0, to).map(|(_, b)| b).collect();
            (r.entry, boxes)
        })
        .collect();
    for route in routes.iter_mut() {
        let others: Vec<&OrientedBox> = swept
            .iter()
            .filter(|(entry, _)| *entry != route.entry)
            .flat_map(|(_, boxes)| boxes.iter())
            .collect();
        let clear_at = |front_s: f64| {
            let (p, h) = route.path.pose_at(front_s - CAR_LENGTH_M / 2.0);
            let waiting = OrientedBox::new(
                p,
                h,
                CAR_LENGTH_M + 2.0 * clearance,
                CAR_WIDTH_M + 2.0 * clearance,
            );
            others.iter().all(|b| !b.overlaps(&waiting))
        };
        let mut s = route.yield_s;
        let lowest = (route.yield_s - MAX_SET_BACK_M).max(CAR_LENGTH_M);
        while s - SET_BACK_STEP_M >= lowest && !clear_at(s) {
            s -= SET_BACK_STEP_M;
        }
        route.yield_s = s;
    }
}

/// The footprints of the largest car along `r` with its centre every [`SET_BACK_STEP_M`]
/// from `from` to `to`, with the arc length of each.
fn car_poses(r: &RingRoute, from: f64, to: f64) -> impl Iterator<Item = (f64, OrientedBox)> + '_ {
    let n = ((to - from) / SET_BACK_STEP_M).ceil().max(0.0) as usize;
    (0..=n).map(move |k| {
        let s = (from + k as f64 * SET_BACK_STEP_M).min(to);
        let (p, h) = r.path.pose_at(s);
        (s, OrientedBox::new(p, h, CAR_LENGTH_M, CAR_WIDTH_M))
    })
}

/// Cars heading within 30° of each other follow one another (car following handles that):
/// not a conflict.
const SAME_DIRECTION_COS: f64 = 0.866;

/// Fills every route's [`RingRoute::entry_conflicts`]: the stretches of the routes from other
/// entries, not driving its merge lane, on which a car touches one entering on it.
fn find_entry_conflicts(routes: &mut [RingRoute]) {
    // Every car pose of each route from before its merge point to its end.
    let swept: Vec<Vec<(f64, OrientedBox)>> = routes
        .iter()
        .map(|r| car_poses(r, (r.merge_s - 3.0).max(0.0), r.path.length()).collect())
        .collect();
    // Centres farther apart than this cannot overlap.
    let reach = CAR_LENGTH_M.hypot(CAR_WIDTH_M);
    let conflicts: Vec<Vec<EntryConflict>> = routes
        .iter()
        .map(|r| {
            let half = CAR_LENGTH_M / 2.0;
            let entering: Vec<_> = car_poses(r, r.yield_s - half, r.merge_s + half).collect();
            routes
                .iter()
                .enumerate()
                .filter(|(_, q)| q.entry != r.entry && q.ring_lane_start(r.merge_lane).is_none())
                .filter_map(|(qi, _)| {
                    let touching = swept[qi].iter().filter(|(_, b)| {
                        entering.iter().any(|(_, e)| {
                            e.centre.distance(b.centre) <= reach
                                && e.axis.dot(b.axis) < SAME_DIRECTION_COS
                                && e.overlaps(b)
                        })
                    });
                    let (from_s, to_s) = touching
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (s, _)| {
                            (lo.min(*s), hi.max(*s))
                        });
                    (from_s <= to_s).then_some(EntryConflict {
                        route: qi,
                        from_s,
                        to_s,
                    })
                })
                .collect()
        })
        .collect();
    for (r, c) in routes.iter_mut().zip(conflicts) {
        r.entry_conflicts = c;
    }
}

/// One route: the lanes from the entry lane to the exit lane through the ring, extended
/// backwards to `approach_m` before the yield line and forwards to `exit_m` after the exit.
#[allow(clippy::too_many_arguments)]
fn build_route(
    map: &Map,
    rb: &Roundabout,
    (ring, ranks): (&BTreeSet<LaneId>, &BTreeMap<LaneId, u8>),
    outgoing: &BTreeMap<LaneId, Vec<ConnectionId>>,
    (entry_index, entry): (usize, &ArmLane),
    (exit_index, exit): (usize, &ArmLane),
    config: &LayoutConfig,
    profile: SpeedProfile,
) -> Option<RingRoute> {
    let core = ring_core(map, rb, (ring, ranks), outgoing, entry, exit)?;
    let entry_lane = map.lanes.get(&entry.lane)?;
    let entry_len = polyline_length(&entry_lane.centre);
    // Yield line on the entry lane, as a distance from the lane's start.
    let yield_on_entry = rb
        .yield_lines
        .iter()
        .filter_map(|id| map.stop_lines.get(id))
        .find(|l| l.lanes.contains(&entry.lane))
        .map(|l| l.s_on_lane_m.clamp(0.0, entry_len));
    // Walk back until the approach is long enough or the map ends.
    let mut before: Vec<PieceKey> = Vec::new();
    let mut behind = yield_on_entry.unwrap_or(entry_len);
    let mut lane = entry.lane;
    let mut seen = BTreeSet::from([lane]);
    // Around a multi-lane ring (main roads, often with junctions close by) the approach and
    // the exit stretch stop at the first intersection rather than cross it, where they
    // could turn across the traffic of a neighbouring arm; elsewhere the first connection
    // in id order is taken.
    let through_intersections = rb.lanes_across < 2;
    let pick = |candidates: Vec<&maps::Connection>| -> Option<ConnectionId> {
        candidates
            .iter()
            .find(|c| {
                through_intersections
                    || map
                        .junctions
                        .get(&c.junction)
                        .is_some_and(|j| j.kind != maps::JunctionKind::Intersection)
            })
            .map(|c| c.id)
    };
    while behind < config.approach_m && before.len() < 2 * MAX_EXTENSION_LANES {
        let Some(c) = pick(
            map.connections
                .values()
                .filter(|c| c.to == lane && !ring.contains(&c.from) && !seen.contains(&c.from))
                .collect(),
        )
        .and_then(|id| map.connections.get(&id)) else {
            break;
        };
        let from = map.lanes.get(&c.from)?;
        before.push(PieceKey::Connection(c.id));
        before.push(PieceKey::Lane(c.from));
        behind += c.length_m + polyline_length(&from.centre);
        seen.insert(c.from);
        lane = c.from;
    }
    before.reverse();
    let trim = (behind - config.approach_m).max(0.0);
    let mut keys = before;
    keys.extend(core.iter().copied());
    // Walk on past the exit lane.
    let exit_lane = map.lanes.get(&exit.lane)?;
    let mut ahead = polyline_length(&exit_lane.centre);
    let mut lane = exit.lane;
    let mut seen = BTreeSet::from([lane]);
    for _ in 0..MAX_EXTENSION_LANES {
        if ahead >= config.exit_m {
            break;
        }
        let next = outgoing.get(&lane).and_then(|cs| {
            pick(
                cs.iter()
                    .filter_map(|c| map.connections.get(c))
                    .filter(|c| !ring.contains(&c.to) && !seen.contains(&c.to))
                    .collect(),
            )
            .and_then(|id| map.connections.get(&id))
        });
        let Some(c) = next else { break };
        let to = map.lanes.get(&c.to)?;
        keys.push(PieceKey::Connection(c.id));
        keys.push(PieceKey::Lane(c.to));
        ahead += c.length_m + polyline_length(&to.centre);
        seen.insert(c.to);
        lane = c.to;
    }
    // Approach (after the trim), entry lane to the start of the exit lane, exit stretch.
    let piece_length = |k: &PieceKey| match k {
        PieceKey::Lane(l) => map.lanes.get(l).map_or(0.0, |l| polyline_length(&l.centre)),
        PieceKey::Connection(c) => map
            .connections
            .get(c)
            .map_or(0.0, |c| polyline_length(&c.centre)),
    };
    let before_entry = behind - yield_on_entry.unwrap_or(entry_len);
    let core_to_exit: f64 = core[..core.len() - 1].iter().map(piece_length).sum();
    let max_length = before_entry - trim + core_to_exit + config.exit_m;
    let path = Path::new(map, &keys, trim, max_length, profile)?;
    let lane_start = |id: LaneId| {
        path.pieces()
            .iter()
            .find(|p| p.key == PieceKey::Lane(id))
            .map(|p| p.s_start)
    };
    let entry_start = lane_start(entry.lane)?;
    let ring_lanes: Vec<(LaneId, f64)> = path
        .pieces()
        .iter()
        .filter_map(|p| match p.key {
            PieceKey::Lane(l) if ring.contains(&l) => Some((l, p.s_start)),
            _ => None,
        })
        .collect();
    let &(merge_lane, merge_s) = ring_lanes.first()?;
    let crossed_lanes = crossed_lanes(map, ranks, merge_lane);
    let exit_s = lane_start(exit.lane)?;
    let yield_s = yield_on_entry.map_or(merge_s, |y| (entry_start + y).min(merge_s));
    Some(RingRoute {
        entry: entry_index,
        exit: exit_index,
        path,
        yield_s,
        merge_s,
        merge_lane,
        exit_s,
        ring_lanes,
        crossed_lanes,
        entry_conflicts: Vec::new(),
    })
}

/// The lanes of `merge_lane`'s ring road outside it, outermost first.
fn crossed_lanes(map: &Map, ranks: &BTreeMap<LaneId, u8>, merge_lane: LaneId) -> Vec<LaneId> {
    let Some(&rank) = ranks.get(&merge_lane).filter(|r| **r > 0) else {
        return Vec::new();
    };
    let Some(road) = map
        .lanes
        .get(&merge_lane)
        .and_then(|l| map.roads.get(&l.road))
    else {
        return Vec::new();
    };
    let mut outside: Vec<(u8, LaneId)> = road
        .lanes()
        .filter_map(|l| Some((*ranks.get(&l)?, l)))
        .filter(|(r, _)| *r < rank)
        .collect();
    outside.sort_unstable();
    outside.into_iter().map(|(_, l)| l).collect()
}

/// Each ring lane's place across its ring road, 0 for the outermost: the lanes of a road
/// in order of their mean distance from the ring's centre, farthest first.
fn ring_lane_ranks(map: &Map, rb: &Roundabout) -> BTreeMap<LaneId, u8> {
    let ring: BTreeSet<LaneId> = rb.ring_lanes.iter().copied().collect();
    let mut ranks = BTreeMap::new();
    for road in rb.roads.iter().filter_map(|r| map.roads.get(r)) {
        let mut lanes: Vec<(f64, LaneId)> = road
            .lanes()
            .filter(|l| ring.contains(l))
            .filter_map(|l| map.lanes.get(&l))
            .map(|l| {
                let n = l.centre.len().max(1) as f64;
                let mean = l.centre.iter().map(|p| p.distance(rb.centre)).sum::<f64>() / n;
                (mean, l.id)
            })
            .collect();
        lanes.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        for (k, (_, id)) in lanes.into_iter().enumerate() {
            ranks.insert(id, u8::try_from(k).unwrap_or(u8::MAX));
        }
    }
    for l in &rb.ring_lanes {
        ranks.entry(*l).or_insert(0);
    }
    ranks
}

/// Added to a route's length for each change of lane on the ring when the route keeps to
/// its lane, m: more than any way round a ring.
const KEEP_LANE_COST_M: f64 = 10_000.0;
/// Added for each change of lane when the route may take an inner lane, m: enough that a
/// route changes lanes only where the inner lane saves more than the changes cost.
const LANE_CHANGE_COST_M: f64 = 2.0;
/// Added for entering the ring onto an inner lane, and for leaving it from one, m: routes
/// join and leave by the outer lane wherever the map lets them (on the imported two-lane
/// rings, the connections into and out of the inner lane cut across the outer lane's
/// traffic and across the other lane of the arm, where cars wait to enter), and use the
/// inner lane by changing lanes on the ring.
const INNER_LANE_ARM_COST_M: f64 = 1_000.0;
/// A route that passes more exits than this before its own takes an inner lane where the
/// ring has one.
const EXITS_PASSED_ON_OUTER_LANE: usize = 1;

/// The pieces from the entry lane through the ring to the exit lane. On a multi-lane ring
/// a route keeps to the lane it enters on (the outer lane, from a single-lane entry) when
/// its exit is among the next [`EXITS_PASSED_ON_OUTER_LANE`] + 1; a route to a later exit
/// is the shortest, with a small cost per lane change: it moves to an inner lane after
/// entering and back out to the outer lane, from which exits leave, before its exit.
fn ring_core(
    map: &Map,
    rb: &Roundabout,
    (ring, ranks): (&BTreeSet<LaneId>, &BTreeMap<LaneId, u8>),
    outgoing: &BTreeMap<LaneId, Vec<ConnectionId>>,
    entry: &ArmLane,
    exit: &ArmLane,
) -> Option<Vec<PieceKey>> {
    if ranks.values().all(|r| *r == 0) {
        return shortest_through_ring(map, (ring, ranks), outgoing, (entry.lane, exit.lane), 0.0);
    }
    let kept = shortest_through_ring(
        map,
        (ring, ranks),
        outgoing,
        (entry.lane, exit.lane),
        KEEP_LANE_COST_M,
    );
    let exit_junctions: BTreeSet<maps::JunctionId> = rb
        .exits
        .iter()
        .filter(|a| a.road != exit.road)
        .map(|a| a.junction)
        .collect();
    // Once round is the most a driver goes: a route that drives a ring road twice passes its
    // own entry again, where cars entering behind it would not expect it.
    let once_round = |keys: &Vec<PieceKey>| {
        let mut roads = BTreeSet::new();
        keys.iter()
            .filter_map(|k| match k {
                PieceKey::Lane(l) if ring.contains(l) => map.lanes.get(l),
                _ => None,
            })
            .all(|l| roads.insert(l.road))
    };
    let kept = kept.filter(once_round);
    let passed = kept.as_ref().map_or(0, |keys| {
        let ring_lanes: Vec<LaneId> = keys
            .iter()
            .filter_map(|k| match k {
                PieceKey::Lane(l) if ring.contains(l) => Some(*l),
                _ => None,
            })
            .collect();
        let passed: BTreeSet<maps::JunctionId> = ring_lanes
            .iter()
            .take(ring_lanes.len().saturating_sub(1))
            .filter_map(|l| map.lanes.get(l))
            .map(|l| l.to_junction)
            .filter(|j| exit_junctions.contains(j))
            .collect();
        passed.len()
    });
    if kept.is_some() && passed <= EXITS_PASSED_ON_OUTER_LANE {
        return kept;
    }
    shortest_through_ring(
        map,
        (ring, ranks),
        outgoing,
        (entry.lane, exit.lane),
        LANE_CHANGE_COST_M,
    )
    .filter(once_round)
    .or(kept)
}

/// Shortest chain of pieces from the start of lane `from` to the end of lane `to` that
/// crosses at most [`MAX_LANES_BEFORE_RING`] lanes before the ring, then only ring lanes;
/// each connection between ring lanes of different ranks (a lane change) counts
/// `lane_change_cost` metres on top of its length.
///
/// A search of its own rather than petgraph's: the states (lane, lanes crossed, in the ring)
/// are made as it goes, and ties fall to the smaller state and the first predecessor found,
/// which petgraph's `astar` (ties in heap order, lanes rather than connections) would not keep.
fn shortest_through_ring(
    map: &Map,
    (ring, ranks): (&BTreeSet<LaneId>, &BTreeMap<LaneId, u8>),
    outgoing: &BTreeMap<LaneId, Vec<ConnectionId>>,
    (from, to): (LaneId, LaneId),
    lane_change_cost: f64,
) -> Option<Vec<PieceKey>> {
    // State: (lane, lanes crossed before reaching the ring, whether the ring was reached).
    type State = (LaneId, usize, bool);
    #[derive(PartialEq)]
    struct Item(f64, State);
    impl Eq for Item {}
    impl Ord for Item {
        fn cmp(&self, o: &Self) -> std::cmp::Ordering {
            o.0.total_cmp(&self.0).then_with(|| o.1.cmp(&self.1))
        }
    }
    impl PartialOrd for Item {
        fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
            Some(self.cmp(o))
        }
    }
    let start: State = (from, 0, false);
    let mut best: BTreeMap<State, (f64, Option<(State, ConnectionId)>)> = BTreeMap::new();
    best.insert(start, (0.0, None));
    let mut heap = BinaryHeap::from([Item(0.0, start)]);
    let mut goal = None;
    while let Some(Item(d, state)) = heap.pop() {
        if best.get(&state).is_some_and(|(b, _)| d > *b) {
            continue;
        }
        let (lane, crossed, in_ring) = state;
        if lane == to && in_ring {
            goal = Some(state);
            break;
        }
        let lane_len = map.lanes.get(&lane).map_or(0.0, |l| l.length_m);
        for c in outgoing.get(&lane).into_iter().flatten() {
            let Some(conn) = map.connections.get(c) else {
                continue;
            };
            let next_in_ring = ring.contains(&conn.to);
            // Into the ring, or from the ring onto the exit lane: both count as in the ring.
            let next = if next_in_ring || (conn.to == to && in_ring) {
                (conn.to, crossed, true)
            } else if !in_ring && crossed < MAX_LANES_BEFORE_RING {
                (conn.to, crossed + 1, false)
            } else {
                continue;
            };
            let mut nd = d + lane_len + conn.length_m;
            match (ranks.get(&conn.from), ranks.get(&conn.to)) {
                (Some(a), Some(b)) if a != b => nd += lane_change_cost,
                (Some(r), None) | (None, Some(r)) if *r > 0 => nd += INNER_LANE_ARM_COST_M,
                _ => {}
            }
            if best.get(&next).is_none_or(|(b, _)| nd < *b) {
                best.insert(next, (nd, Some((state, *c))));
                heap.push(Item(nd, next));
            }
        }
    }
    let mut state = goal?;
    let mut keys = vec![PieceKey::Lane(state.0)];
    while let Some((_, Some((prev, c)))) = best.get(&state) {
        keys.push(PieceKey::Connection(*c));
        keys.push(PieceKey::Lane(prev.0));
        state = *prev;
    }
    keys.reverse();
    Some(keys)
}
