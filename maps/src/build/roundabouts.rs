//! Step 6: roundabouts. Tagged rings (`junction=roundabout|circular` ways sharing nodes,
//! however many ways and lanes) are found in the OSM data and checked for closure
//! (`find_rings`); untagged near-circular one-way loops are guessed, and the pieces of every
//! usable ring are joined lane to lane, each lane also to the lanes beside it
//! (`connect_rings`); then every ring whose lanes are strongly connected becomes a
//! roundabout with its entries, exits, priority and a give-way line on every entry
//! (`find_roundabouts`). `highway=mini_roundabout` nodes are recorded with the roads meeting
//! there (`find_mini_roundabouts`). Rings that cannot be used are listed in the report with
//! the reason, and their roads stay ordinary roads.

use std::collections::{BTreeMap, BTreeSet};
use std::f64::consts::PI;

use crate::geometry::{Point, polyline_length, signed_area};
use crate::model::{
    Connection, ConnectionId, Direction, DrivingSide, JunctionId, LaneId, PrioritySource,
    RingProblem, RoadId, Roundabout, RoundaboutArm, RoundaboutId, RoundaboutKind,
    RoundaboutPriority, RoundaboutSource, StopKind, StopLine, StopLineId, StopLineSource, Turn,
};
use crate::tags;

use super::select::{Builder, Ring};

/// 4πA/P² of a loop must reach this to be guessed a roundabout: a circle is 1, a regular
/// hexagon 0.91, a square 0.785 (city blocks of one-way streets stay out).
const MIN_CIRCULARITY: f64 = 0.85;
/// Service roads are left out of guessing: one-way parking aisles and driveway loops are
/// near-circular too (Leeds way 701166700, Northwestern way 165120169) but are not roundabouts.
const GUESS_EXCLUDED_HIGHWAYS: &[&str] = &["service"];
/// A guessed ring needs arms on at least this many distinct roads (a loop hanging off one
/// road is a turning loop).
const GUESS_MIN_ARM_ROADS: usize = 2;
/// Perimeter range of a guessed roundabout, metres.
const GUESS_PERIMETER_M: (f64, f64) = (15.0, 600.0);
/// Lane count keys whose values are checked on ring ways.
const LANE_COUNT_KEYS: &[&str] = &["lanes", "lanes:forward", "lanes:backward"];

/// The connections between lanes, both ways.
struct LaneGraph {
    next_of: BTreeMap<LaneId, Vec<LaneId>>,
    prev_of: BTreeMap<LaneId, Vec<LaneId>>,
}

/// Entry and exit arms of a ring or mini-roundabout.
struct Arms {
    entries: Vec<RoundaboutArm>,
    exits: Vec<RoundaboutArm>,
}

impl Builder<'_> {
    /// Groups the tagged ring ways of the profile by shared nodes and checks that each group
    /// closes in one direction with all its nodes present; lists the rings that do not.
    pub fn find_rings(&mut self) {
        let ring_ways: Vec<i64> = self
            .osm
            .ways
            .iter()
            .filter(|(_, w)| self.options.profile.selects(&w.tags) && tags::is_roundabout(&w.tags))
            .map(|(&id, _)| id)
            .collect();
        // Union-find over the ways, joined through their nodes.
        let mut parent: Vec<usize> = (0..ring_ways.len()).collect();
        fn root(parent: &mut [usize], mut x: usize) -> usize {
            while parent[x] != x {
                parent[x] = parent[parent[x]];
                x = parent[x];
            }
            x
        }
        let mut way_of_node: BTreeMap<i64, usize> = BTreeMap::new();
        for (i, w) in ring_ways.iter().enumerate() {
            let Some(way) = self.osm.ways.get(w) else {
                continue;
            };
            for n in &way.nodes {
                match way_of_node.get(n) {
                    Some(&k) => {
                        let (a, b) = (root(&mut parent, i), root(&mut parent, k));
                        if a != b {
                            parent[a.max(b)] = a.min(b);
                        }
                    }
                    None => {
                        way_of_node.insert(*n, i);
                    }
                }
            }
        }
        let mut groups: BTreeMap<usize, Vec<i64>> = BTreeMap::new();
        for (i, w) in ring_ways.iter().enumerate() {
            let r = root(&mut parent, i);
            groups.entry(r).or_default().push(*w);
        }
        let mut roads_of_way: BTreeMap<i64, Vec<RoadId>> = BTreeMap::new();
        for road in self.map.roads.values().filter(|r| r.is_roundabout) {
            for w in &road.osm_way_ids {
                roads_of_way.entry(*w).or_default().push(road.id);
            }
        }
        let mut rings: Vec<Ring> = groups
            .into_values()
            .map(|mut ways| {
                ways.sort_unstable();
                let mut roads: Vec<RoadId> = ways
                    .iter()
                    .filter_map(|w| roads_of_way.get(w))
                    .flatten()
                    .copied()
                    .collect();
                roads.sort_unstable();
                let kind = if self
                    .minis
                    .is_some_and(|m| ways.iter().all(|w| m.ring_of_way.contains_key(w)))
                {
                    RoundaboutKind::MiniRoundabout
                } else if ways.iter().all(|w| {
                    self.osm
                        .ways
                        .get(w)
                        .is_some_and(|x| x.tags.is("junction", "circular"))
                }) {
                    RoundaboutKind::Circular
                } else {
                    RoundaboutKind::Roundabout
                };
                let (broken, mut warnings) = match self.ring_closure_problem(&ways) {
                    Ok(warnings) => (self.ring_roads_problem(&ways, &roads), warnings),
                    Err(reason) => (Some(reason), Vec::new()),
                };
                warnings.extend(self.lane_count_warnings(&ways));
                Ring {
                    source: RoundaboutSource::Tagged,
                    ways,
                    kind,
                    roads,
                    broken,
                    warnings,
                }
            })
            .collect();
        // Mini-roundabouts after the tagged rings (they get the last ids).
        rings.sort_by(|a, b| {
            let mini = |r: &Ring| r.kind == RoundaboutKind::MiniRoundabout;
            (mini(a), &a.ways).cmp(&(mini(b), &b.ways))
        });
        for ring in &rings {
            if let Some(reason) = &ring.broken {
                self.map.report.ring_problems.push(RingProblem {
                    osm_way_ids: ring.ways.clone(),
                    osm_node_id: None,
                    reason: reason.clone(),
                    imported: false,
                });
            }
        }
        self.rings = rings;
    }

    /// Lane count tags on the ring's ways that are not counts (the class default is used).
    fn lane_count_warnings(&self, ways: &[i64]) -> Vec<String> {
        let mut out = Vec::new();
        for w in ways {
            let Some(way) = self.osm.ways.get(w) else {
                continue;
            };
            for key in LANE_COUNT_KEYS {
                if let Some(v) = way.tags.get(key)
                    && tags::parse_count(&way.tags, key).is_none()
                {
                    out.push(format!(
                        "way {w} has {key}={v}, not a lane count from 1 to 8; the road class's default lane count is used"
                    ));
                }
            }
        }
        out
    }

    /// Why the OSM ways of a ring cannot make a closed one-way loop (Err), or the ways that
    /// do not chain into one closed ring but may still form one with the others (a way
    /// starting or ending inside another, as a bypass or chord does).
    fn ring_closure_problem(&self, ways: &[i64]) -> Result<Vec<String>, String> {
        let mut missing: Vec<String> = Vec::new();
        for w in ways {
            let Some(way) = self.osm.ways.get(w) else {
                return Err(format!("way {w} is not in the data"));
            };
            let n = way
                .nodes
                .iter()
                .filter(|n| !self.osm.nodes.contains_key(n))
                .collect::<BTreeSet<_>>()
                .len();
            if n > 0 {
                missing.push(format!(
                    "way {w} has {n} of its nodes missing from the extract"
                ));
            }
        }
        if !missing.is_empty() {
            return Err(format!("ring nodes missing: {}", missing.join("; ")));
        }
        // Ends of each way in its direction of travel. Where no ring way passes through an
        // end node, some way must end there and some way start there. (A way ending inside
        // another, or more ways ending than starting at a node, as with a bypass lane, is
        // left to the lane-level check.)
        let mut passed: BTreeSet<i64> = BTreeSet::new();
        for w in ways {
            let Some(way) = self.osm.ways.get(w) else {
                return Err(format!("way {w} is not in the data"));
            };
            let n = way.nodes.len();
            passed.extend(way.nodes.iter().take(n.saturating_sub(1)).skip(1).copied());
        }
        let mut ends: BTreeMap<i64, (Vec<i64>, Vec<i64>)> = BTreeMap::new();
        for w in ways {
            let Some(way) = self.osm.ways.get(w) else {
                return Err(format!("way {w} is not in the data"));
            };
            let (Some(&first), Some(&last)) = (way.nodes.first(), way.nodes.last()) else {
                return Err(format!("way {w} has no nodes"));
            };
            let (from, to) = match tags::oneway(&way.tags) {
                tags::Oneway::Forward => (first, last),
                tags::Oneway::Backward => (last, first),
                tags::Oneway::No => {
                    return Err(format!(
                        "way {w} is tagged oneway=no: traffic on it is not one-way round the ring"
                    ));
                }
            };
            if from == to {
                // A closed way passes through its own end node.
                passed.insert(from);
                continue;
            }
            ends.entry(from).or_default().1.push(*w);
            ends.entry(to).or_default().0.push(*w);
        }
        let mut warnings = Vec::new();
        for (node, (ins, outs)) in &ends {
            if passed.contains(node) {
                for (w, verb) in ins
                    .iter()
                    .map(|w| (w, "ends"))
                    .chain(outs.iter().map(|w| (w, "starts")))
                {
                    warnings.push(format!(
                        "way {w} {verb} at node {node}, inside another ring way: the ways do not chain into one closed ring"
                    ));
                }
            }
        }
        ends.retain(|node, _| !passed.contains(node));
        for (node, (ins, outs)) in &ends {
            if ins.len() + outs.len() == 1 {
                let (w, verb) = match (ins.first(), outs.first()) {
                    (Some(w), _) => (w, "ends"),
                    (None, Some(w)) => (w, "starts"),
                    (None, None) => continue,
                };
                return Err(format!(
                    "not closed: way {w} {verb} at node {node}, where no other ring way continues it"
                ));
            }
        }
        for (node, (ins, outs)) in &ends {
            if ins.len() != outs.len() && !ins.is_empty() && !outs.is_empty() {
                warnings.push(format!(
                    "{} ways end and {} start at node {node}: the ways do not chain into one closed ring",
                    ins.len(),
                    outs.len()
                ));
            }
            if ins.is_empty() || outs.is_empty() {
                let (list, verb) = if outs.is_empty() {
                    (ins, "end")
                } else {
                    (outs, "start")
                };
                let names: Vec<String> = list.iter().map(|w| format!("way {w}")).collect();
                return Err(format!(
                    "a piece runs against the ring's direction: {} {verb} at node {node}",
                    names.join(" and ")
                ));
            }
        }
        Ok(warnings)
    }

    /// Why the ring's roads (after clipping and dropping degenerate pieces) do not close, if
    /// they do not.
    fn ring_roads_problem(&self, ways: &[i64], roads: &[RoadId]) -> Option<String> {
        if roads.is_empty() {
            return Some(format!(
                "no road is left of ways {ways:?} (clipped away or degenerate)"
            ));
        }
        let mut balance: BTreeMap<JunctionId, (u32, u32)> = BTreeMap::new();
        for r in roads {
            let road = self.map.roads.get(r)?;
            if road.lanes().next().is_none() {
                return Some(format!("way {:?} has no lanes", road.osm_way_ids));
            }
            if !road.lanes_forward.is_empty() {
                balance.entry(road.start_junction).or_default().1 += 1;
                balance.entry(road.end_junction).or_default().0 += 1;
            }
            if !road.lanes_backward.is_empty() {
                balance.entry(road.end_junction).or_default().1 += 1;
                balance.entry(road.start_junction).or_default().0 += 1;
            }
        }
        // A junction only entered or only left breaks the ring; other imbalances (bypass
        // lanes) are left to the lane-level check.
        let open = balance.iter().find(|(_, (i, o))| (*i == 0) != (*o == 0))?;
        let node = self
            .map
            .junctions
            .get(open.0)
            .and_then(|j| j.osm_node_id)
            .map_or_else(|| format!("junction {}", open.0), |n| format!("node {n}"));
        Some(format!(
            "not closed within the imported roads of ways {ways:?}: the ring breaks at {node} (clipped, or a degenerate piece)"
        ))
    }

    /// Adds the guessed loops (when asked) to the rings, then joins consecutive pieces of
    /// every usable ring lane to lane (aligned on the
    /// outer side), and lets each lane also continue into the lanes beside it, so that
    /// every ring lane lies on a directed cycle and every exit can be reached.
    pub fn connect_rings(&mut self) {
        if self.options.guess_roundabouts {
            for roads in self.untagged_loops() {
                let mut ways: Vec<i64> = roads
                    .iter()
                    .filter_map(|r| self.map.roads.get(r))
                    .flat_map(|r| r.osm_way_ids.iter().copied())
                    .collect();
                ways.sort_unstable();
                ways.dedup();
                self.rings.push(Ring {
                    source: RoundaboutSource::Guessed,
                    ways,
                    kind: RoundaboutKind::Roundabout,
                    roads,
                    broken: None,
                    warnings: Vec::new(),
                });
            }
        }
        let rings: Vec<Vec<RoadId>> = self
            .rings
            .iter()
            .filter(|r| r.broken.is_none())
            .map(|r| r.roads.clone())
            .collect();
        let mut existing: BTreeSet<(LaneId, LaneId)> = self
            .map
            .connections
            .values()
            .map(|c| (c.from, c.to))
            .collect();
        for ring in rings {
            self.connect_ring_pieces(&ring, &mut existing);
        }
    }

    fn connect_ring_pieces(&mut self, ring: &[RoadId], existing: &mut BTreeSet<(LaneId, LaneId)>) {
        let ring_set: BTreeSet<RoadId> = ring.iter().copied().collect();
        let clockwise = self.ring_is_clockwise(ring);
        let junctions: BTreeSet<JunctionId> = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .flat_map(|r| [r.start_junction, r.end_junction])
            .collect();
        let mut added: Vec<Connection> = Vec::new();
        let left_hand = self.map.driving_side == DrivingSide::Left;
        // Turning into and out of the ring: right on an anticlockwise ring, left on a clockwise one.
        let arm_turn = if clockwise { Turn::Left } else { Turn::Right };
        for j in junctions {
            // Lanes arriving at and leaving `j`, per road and direction, ring and arms apart,
            // as (position from the left in the direction of travel, lane).
            type Groups = BTreeMap<(RoadId, Direction), Vec<(u8, LaneId)>>;
            let (mut arriving, mut leaving) = (Groups::new(), Groups::new());
            let (mut entering, mut exiting) = (Groups::new(), Groups::new());
            for lane in self.lanes_at(j) {
                let Some(road) = self.map.roads.get(&lane.road) else {
                    continue;
                };
                let on_ring = ring_set.contains(&lane.road);
                if !on_ring && !road.allows_cars {
                    continue;
                }
                // Index 0 is next to the centre line: the left edge of a one-way road, and of
                // a two-way road's lanes where traffic keeps right.
                let from_left = if !road.is_oneway() && left_hand {
                    u8::MAX - lane.index_from_centre
                } else {
                    lane.index_from_centre
                };
                let key = (lane.road, lane.direction);
                if lane.to_junction == j {
                    let groups = if on_ring {
                        &mut arriving
                    } else {
                        &mut entering
                    };
                    groups.entry(key).or_default().push((from_left, lane.id));
                }
                if lane.from_junction == j {
                    let groups = if on_ring { &mut leaving } else { &mut exiting };
                    groups.entry(key).or_default().push((from_left, lane.id));
                }
            }
            // The inside of an anticlockwise ring is on the left; the outer lanes, and the
            // arms' kerb-side lanes, come last.
            let inner_first = |mut v: Vec<(u8, LaneId)>| -> Vec<LaneId> {
                v.sort_unstable();
                if clockwise {
                    v.reverse();
                }
                v.into_iter().map(|(_, l)| l).collect()
            };
            let add = |f: LaneId,
                       t: LaneId,
                       turn: Turn,
                       existing: &mut BTreeSet<(LaneId, LaneId)>,
                       added: &mut Vec<Connection>| {
                if existing.insert((f, t)) {
                    let centre = self.connection_curve(f, t);
                    added.push(Connection {
                        id: ConnectionId(0),
                        junction: j,
                        from: f,
                        to: t,
                        turn,
                        length_m: polyline_length(&centre),
                        centre,
                    });
                }
            };
            // Every entry lane onto the ring and every exit lane from it, lane to lane from the
            // outer side, where no connection of the turns already does so.
            for a in entering.values() {
                let from = inner_first(a.clone());
                for b in leaving.values() {
                    let to = inner_first(b.clone());
                    let linked: Vec<bool> = from
                        .iter()
                        .map(|f| to.iter().any(|t| existing.contains(&(*f, *t))))
                        .collect();
                    for (f, t) in outer_aligned(&from, &to) {
                        if from
                            .iter()
                            .position(|x| *x == f)
                            .is_some_and(|i| !linked[i])
                        {
                            add(f, t, arm_turn, existing, &mut added);
                        }
                    }
                }
            }
            for b in exiting.values() {
                let to = inner_first(b.clone());
                for a in arriving.values() {
                    let from = inner_first(a.clone());
                    let linked: Vec<bool> = to
                        .iter()
                        .map(|t| from.iter().any(|f| existing.contains(&(*f, *t))))
                        .collect();
                    for (f, t) in outer_aligned(&from, &to) {
                        if to.iter().position(|x| *x == t).is_some_and(|i| !linked[i]) {
                            add(f, t, arm_turn, existing, &mut added);
                        }
                    }
                }
            }
            for (a_key, a) in &arriving {
                for (b_key, b) in &leaving {
                    if a_key.0 == b_key.0 {
                        continue;
                    }
                    let from = inner_first(a.clone());
                    let to = inner_first(b.clone());
                    for (f, t) in ring_lane_pairs(&from, &to) {
                        add(f, t, Turn::Straight, existing, &mut added);
                    }
                }
            }
        }
        let first = self
            .map
            .connections
            .keys()
            .next_back()
            .map_or(0, |c| c.0 + 1);
        for (mut c, id) in added.into_iter().zip(first..) {
            c.id = ConnectionId(id);
            self.map.connections.insert(c.id, c);
        }
    }

    /// Whether the ring runs clockwise: the shoelace sum over its lanes in their direction of
    /// travel, closed through the junction points (the order of the pieces does not matter).
    fn ring_is_clockwise(&self, ring: &[RoadId]) -> bool {
        let mut twice_area = 0.0;
        for r in ring {
            let Some(lane) = self
                .map
                .roads
                .get(r)
                .and_then(|road| road.lanes().next())
                .and_then(|l| self.map.lanes.get(&l))
            else {
                continue;
            };
            let from = self.map.junctions.get(&lane.from_junction).map(|j| j.point);
            let to = self.map.junctions.get(&lane.to_junction).map(|j| j.point);
            let pts: Vec<Point> = from
                .into_iter()
                .chain(lane.centre.iter().copied())
                .chain(to)
                .collect();
            twice_area += pts.windows(2).map(|w| w[0].cross(w[1])).sum::<f64>();
        }
        twice_area < 0.0
    }

    /// Makes a roundabout of every usable tagged ring and guessed loop; a ring whose lanes do not form strongly connected lanes reaching every exit is
    /// listed in the report instead.
    pub fn find_roundabouts(&mut self) {
        let rings: Vec<Ring> = self
            .rings
            .iter()
            .filter(|r| r.broken.is_none() && r.kind != RoundaboutKind::MiniRoundabout)
            .cloned()
            .collect();
        let graph = self.lane_graph();
        for ring in rings {
            let imported = self.add_roundabout(&ring.roads, ring.source, ring.kind, &graph);
            for reason in ring.warnings {
                self.map.report.ring_problems.push(RingProblem {
                    osm_way_ids: ring.ways.clone(),
                    osm_node_id: None,
                    reason,
                    imported,
                });
            }
        }
        // Stable: the problems of one ring stay in the order they were found.
        self.map
            .report
            .ring_problems
            .sort_by(|a, b| a.osm_way_ids.cmp(&b.osm_way_ids));
    }

    /// The connections between lanes, both ways.
    fn lane_graph(&self) -> LaneGraph {
        let mut next_of: BTreeMap<LaneId, Vec<LaneId>> = BTreeMap::new();
        let mut prev_of: BTreeMap<LaneId, Vec<LaneId>> = BTreeMap::new();
        for c in self.map.connections.values() {
            next_of.entry(c.from).or_default().push(c.to);
            prev_of.entry(c.to).or_default().push(c.from);
        }
        LaneGraph { next_of, prev_of }
    }

    /// Makes a roundabout of kind `mini_roundabout` of every ring made round a
    /// `highway=mini_roundabout` node (numbered after the other rings), and lists the nodes
    /// that could not be made into one, or stand on no road of the profile.
    pub fn find_mini_roundabouts(&mut self) {
        let minis = self.minis;
        let mut listed: BTreeSet<i64> = BTreeSet::new();
        if let Some(m) = minis {
            for p in &m.problems {
                listed.extend(p.osm_node_id);
                self.map.report.ring_problems.push(p.clone());
            }
        }
        let ringed: BTreeSet<i64> = minis
            .map(|m| m.ring_of_way.values().copied().collect())
            .unwrap_or_default();
        let nodes: Vec<i64> = self
            .osm
            .nodes
            .iter()
            .filter(|(id, n)| {
                n.tags.is("highway", "mini_roundabout")
                    && !ringed.contains(id)
                    && !listed.contains(id)
            })
            .map(|(&id, _)| id)
            .collect();
        for node in nodes {
            self.map.report.ring_problems.push(RingProblem {
                osm_way_ids: Vec::new(),
                osm_node_id: Some(node),
                reason: format!(
                    "mini-roundabout node {node} is on no road of the `{}` profile",
                    self.options.profile.name
                ),
                imported: false,
            });
        }
        let Some(minis) = minis else { return };
        let node_of = |r: &Ring| {
            r.ways
                .first()
                .and_then(|w| minis.ring_of_way.get(w))
                .copied()
        };
        let mut rings: Vec<Ring> = self
            .rings
            .iter()
            .filter(|r| r.broken.is_none() && r.kind == RoundaboutKind::MiniRoundabout)
            .cloned()
            .collect();
        rings.sort_by_key(node_of);
        let graph = self.lane_graph();
        for ring in rings {
            if !self.add_roundabout(&ring.roads, ring.source, ring.kind, &graph) {
                continue;
            }
            if let Some(r) = self.map.roundabouts.values_mut().next_back() {
                r.osm_node_id = node_of(&ring);
                r.osm_way_ids.clear();
            }
        }
    }

    /// The last step: the ways made for mini-roundabouts leave the map. Roads of their rings
    /// keep no way id, and problems of a ring name its node.
    pub fn forget_made_ways(&mut self) {
        let Some(minis) = self.minis else { return };
        for road in self.map.roads.values_mut() {
            road.osm_way_ids.retain(|w| !minis.is_made(*w));
        }
        for p in &mut self.map.report.ring_problems {
            if let Some(node) = p.osm_way_ids.iter().find_map(|w| minis.ring_of_way.get(w)) {
                p.osm_node_id = Some(*node);
            }
            p.osm_way_ids.retain(|w| !minis.is_made(*w));
        }
        let made = |w: &i64| minis.is_made(*w);
        self.map.report.degenerate_ways.retain(|w| !made(w));
        self.map.report.ways_missing_nodes.retain(|w| !made(w));
    }

    /// The car roads (not in `ring`) running into or out of the junctions `at`, one arm per
    /// road and direction of travel.
    fn arms_at(&self, at: &[JunctionId], ring: &BTreeSet<RoadId>) -> Arms {
        let mut entries = Vec::new();
        let mut exits = Vec::new();
        for &j in at {
            let mut arms: BTreeMap<(RoadId, bool), Vec<LaneId>> = BTreeMap::new();
            for lane in self.lanes_at(j) {
                if ring.contains(&lane.road)
                    || !self
                        .map
                        .roads
                        .get(&lane.road)
                        .is_some_and(|r| r.allows_cars)
                {
                    continue;
                }
                if lane.to_junction == j {
                    arms.entry((lane.road, true)).or_default().push(lane.id);
                }
                if lane.from_junction == j {
                    arms.entry((lane.road, false)).or_default().push(lane.id);
                }
            }
            for ((road, entering), lanes) in arms {
                let arm = RoundaboutArm {
                    road,
                    lanes,
                    junction: j,
                };
                if entering {
                    entries.push(arm)
                } else {
                    exits.push(arm)
                }
            }
        }
        Arms { entries, exits }
    }

    /// Priority from the data: traffic signals, or give-way / stop signs inside the ring's
    /// ways, make entering traffic go first; `priority_road` or `priority` = `yes|designated`
    /// on the ring, or give-way / stop signs on the entries, make circulating traffic go
    /// first. Otherwise the roundabout rule is assumed.
    fn priority(&self, ring: &[RoadId], arms: &Arms) -> (RoundaboutPriority, PrioritySource) {
        let node_highway = |n: &i64| self.osm.nodes.get(n).and_then(|x| x.tags.get("highway"));
        let ring_nodes: BTreeSet<i64> = ring
            .iter()
            .filter_map(|r| self.info.get(r))
            .flat_map(|i| i.nodes.iter().copied())
            .collect();
        let ring_signals = ring_nodes
            .iter()
            .any(|n| node_highway(n) == Some("traffic_signals"));
        let ring_signs = ring
            .iter()
            .filter_map(|r| self.info.get(r))
            .filter_map(|i| i.nodes.get(1..i.nodes.len().saturating_sub(1)))
            .flatten()
            .any(|n| matches!(node_highway(n), Some("give_way" | "stop")));
        if ring_signals || ring_signs {
            return (RoundaboutPriority::Entering, PrioritySource::Tags);
        }
        let ring_priority = ring.iter().filter_map(|r| self.info.get(r)).any(|i| {
            ["priority_road", "priority"]
                .iter()
                .any(|k| i.tags.is_any(k, &["yes", "designated"]))
        });
        // Signs along each entry road, up to and including its node at the ring (not the
        // far end, which belongs to another junction).
        let entry_signs = arms.entries.iter().any(|a| {
            let ring_node = self
                .map
                .junctions
                .get(&a.junction)
                .and_then(|j| j.osm_node_id);
            self.info.get(&a.road).is_some_and(|i| {
                let nodes = &i.nodes;
                let near = if nodes.first().copied() == ring_node {
                    nodes.get(..nodes.len().saturating_sub(1))
                } else {
                    nodes.get(1..)
                };
                near.into_iter()
                    .flatten()
                    .any(|n| matches!(node_highway(n), Some("give_way" | "stop")))
            })
        });
        if ring_priority || entry_signs {
            (RoundaboutPriority::Circulating, PrioritySource::Tags)
        } else {
            (RoundaboutPriority::Circulating, PrioritySource::Assumed)
        }
    }

    /// Simple cycles of one-way car roads (not tagged as roundabouts) that look like circles.
    fn untagged_loops(&self) -> Vec<Vec<RoadId>> {
        let oneway: Vec<RoadId> = self
            .map
            .roads
            .values()
            .filter(|r| {
                !r.is_roundabout
                    && r.allows_cars
                    && r.is_oneway()
                    && !GUESS_EXCLUDED_HIGHWAYS.contains(&r.highway.as_str())
            })
            .map(|r| r.id)
            .collect();
        let mut out = Vec::new();
        for group in group_by_junctions(&self.map, &oneway) {
            // A simple directed cycle: each junction entered once and left once within the group.
            let mut ins: BTreeMap<JunctionId, usize> = BTreeMap::new();
            let mut outs: BTreeMap<JunctionId, usize> = BTreeMap::new();
            for r in &group {
                if let Some(lane) = self
                    .map
                    .roads
                    .get(r)
                    .and_then(|road| road.lanes().next())
                    .and_then(|l| self.map.lanes.get(&l))
                {
                    *outs.entry(lane.from_junction).or_default() += 1;
                    *ins.entry(lane.to_junction).or_default() += 1;
                }
            }
            if group.len() < 2
                || ins.len() != group.len()
                || ins.values().any(|&c| c != 1)
                || outs.values().any(|&c| c != 1)
                || ins.keys().ne(outs.keys())
            {
                continue;
            }
            let Some(cycle) = self.lane_cycle(&group) else {
                continue;
            };
            let ring: Vec<Point> = cycle
                .iter()
                .filter_map(|l| self.map.lanes.get(l))
                .flat_map(|l| l.centre.iter().copied())
                .collect();
            let perimeter = ring.windows(2).map(|w| w[0].distance(w[1])).sum::<f64>()
                + ring
                    .first()
                    .zip(ring.last())
                    .map(|(a, b)| a.distance(*b))
                    .unwrap_or(0.0);
            let area = signed_area(&ring).abs();
            let circularity = 4.0 * PI * area / (perimeter * perimeter);
            let group_set: BTreeSet<RoadId> = group.iter().copied().collect();
            let arm_roads: BTreeSet<RoadId> = ins
                .keys()
                .filter_map(|j| self.map.junctions.get(j))
                .flat_map(|j| j.roads.iter().copied())
                .filter(|r| !group_set.contains(r))
                .collect();
            if circularity >= MIN_CIRCULARITY
                && (GUESS_PERIMETER_M.0..=GUESS_PERIMETER_M.1).contains(&perimeter)
                && arm_roads.len() >= GUESS_MIN_ARM_ROADS
            {
                out.push(group);
            }
        }
        out
    }

    /// One trip round the ring through connections, keeping to one lane where it can.
    fn lane_cycle(&self, ring: &[RoadId]) -> Option<Vec<LaneId>> {
        let ring_set: BTreeSet<RoadId> = ring.iter().copied().collect();
        let ring_lanes: BTreeSet<LaneId> = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .flat_map(|r| r.lanes())
            .collect();
        let start = *ring_lanes.iter().find(|l| {
            self.map
                .lanes
                .get(l)
                .is_some_and(|x| x.index_from_centre == 0)
        })?;
        let mut next_of: BTreeMap<LaneId, Vec<(LaneId, Turn)>> = BTreeMap::new();
        for c in self.map.connections.values() {
            if ring_lanes.contains(&c.from) && ring_lanes.contains(&c.to) {
                next_of.entry(c.from).or_default().push((c.to, c.turn));
            }
        }
        let mut cycle = vec![start];
        let mut seen = BTreeSet::from([start]);
        let mut current = start;
        loop {
            let index = self.map.lanes.get(&current)?.index_from_centre;
            let options = next_of.get(&current)?;
            let pick = options
                .iter()
                .min_by_key(|(l, turn)| {
                    let same_index = self
                        .map
                        .lanes
                        .get(l)
                        .is_some_and(|x| x.index_from_centre == index);
                    (*l != start, !same_index, *turn != Turn::Straight, *l)
                })
                .map(|(l, _)| *l)?;
            if pick == start {
                break;
            }
            if !seen.insert(pick)
                || !self
                    .map
                    .lanes
                    .get(&pick)
                    .is_some_and(|x| ring_set.contains(&x.road))
            {
                return None;
            }
            cycle.push(pick);
            current = pick;
        }
        Some(cycle)
    }

    /// Records a problem with a ring: in the report's ring problems for a tagged ring, as a
    /// note for a guessed one.
    fn ring_problem(
        &mut self,
        ways: &[i64],
        source: RoundaboutSource,
        reason: String,
        imported: bool,
    ) {
        if source == RoundaboutSource::Tagged {
            self.map.report.ring_problems.push(RingProblem {
                osm_way_ids: ways.to_vec(),
                osm_node_id: None,
                reason,
                imported,
            });
        } else {
            self.map
                .report
                .notes
                .push(format!("guessed roundabout ways {ways:?}: {reason}"));
        }
    }

    /// Adds one roundabout; false (and the reason listed) when its lanes do not make one.
    fn add_roundabout(
        &mut self,
        ring: &[RoadId],
        source: RoundaboutSource,
        kind: RoundaboutKind,
        graph: &LaneGraph,
    ) -> bool {
        let LaneGraph { next_of, prev_of } = graph;
        let mut osm_way_ids: Vec<i64> = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .flat_map(|r| r.osm_way_ids.iter().copied())
            .collect();
        osm_way_ids.sort_unstable();
        osm_way_ids.dedup();
        let ring_lanes: Vec<LaneId> = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .flat_map(|r| r.lanes())
            .collect();
        let lane_set: BTreeSet<LaneId> = ring_lanes.iter().copied().collect();
        if let Some(stuck) = not_strongly_connected(&ring_lanes, &lane_set, next_of, prev_of) {
            let way = self
                .map
                .lanes
                .get(&stuck)
                .and_then(|l| self.map.roads.get(&l.road))
                .map(|r| r.osm_way_ids.clone())
                .unwrap_or_default();
            self.ring_problem(
                &osm_way_ids,
                source,
                format!("the ring's lanes are not strongly connected: lane {stuck} (way {way:?}) lies on no directed cycle round the ring; not imported as a roundabout"),
                false,
            );
            return false;
        }
        let Some(cycle) = self.lane_cycle(ring) else {
            self.ring_problem(
                &osm_way_ids,
                source,
                "no trip round the ring keeps to its lanes; not imported as a roundabout".into(),
                false,
            );
            return false;
        };
        let id = RoundaboutId(self.map.roundabouts.len() as u32);
        let ring_set: BTreeSet<RoadId> = ring.iter().copied().collect();
        let ring_junctions: Vec<JunctionId> = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .flat_map(|r| [r.start_junction, r.end_junction])
            .collect::<BTreeSet<_>>()
            .into_iter()
            .collect();
        let Arms { entries, exits } = self.arms_at(&ring_junctions, &ring_set);
        // An arm cut off from the ring (by a turn restriction, say) is left out, and said so.
        let mut cut_off = Vec::new();
        let mut keep_linked =
            |arms: Vec<RoundaboutArm>, links: &BTreeMap<LaneId, Vec<LaneId>>, what| {
                arms.into_iter()
                    .filter(|arm| {
                        let ok = arm.lanes.iter().any(|l| {
                            links
                                .get(l)
                                .is_some_and(|n| n.iter().any(|x| lane_set.contains(x)))
                        });
                        if !ok {
                            cut_off.push((what, arm.road));
                        }
                        ok
                    })
                    .collect::<Vec<_>>()
            };
        let entries = keep_linked(entries, next_of, "entry");
        let exits = keep_linked(exits, prev_of, "exit");
        for (what, road) in cut_off {
            let way = self
                .map
                .roads
                .get(&road)
                .map(|r| r.osm_way_ids.clone())
                .unwrap_or_default();
            self.ring_problem(
                &osm_way_ids,
                source,
                format!("the {what} on way {way:?} does not connect to the ring; left out of the roundabout's arms"),
                true,
            );
        }
        let arms = Arms { entries, exits };
        let (priority, priority_source) = self.priority(ring, &arms);
        let Arms { entries, exits } = arms;
        let mut yield_lines = Vec::new();
        // A give-way line where each entry meets the ring, whatever `priority` says: a ring
        // that gives way to entering traffic is told apart by `priority`, not by its lines.
        for arm in &entries {
            if let Some(line) = self.line_across(&arm.lanes, None) {
                let sid = StopLineId(self.map.stop_lines.len() as u32);
                let s = arm
                    .lanes
                    .first()
                    .and_then(|l| self.map.lanes.get(l))
                    .map(|l| l.length_m)
                    .unwrap_or(0.0);
                self.map.stop_lines.insert(
                    sid,
                    StopLine {
                        id: sid,
                        kind: StopKind::GiveWay,
                        source: StopLineSource::RoundaboutEntry { roundabout: id },
                        lanes: arm.lanes.clone(),
                        line,
                        s_on_lane_m: s,
                    },
                );
                yield_lines.push(sid);
            }
        }
        let points: Vec<Point> = cycle
            .iter()
            .filter_map(|l| self.map.lanes.get(l))
            .flat_map(|l| l.centre.iter().copied())
            .collect();
        let n = points.len().max(1) as f64;
        let centre = points
            .iter()
            .fold(Point::default(), |a, p| a.add(*p))
            .scale(1.0 / n);
        let radius = points.iter().map(|p| p.distance(centre)).sum::<f64>() / n;
        let lanes_across = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .map(|r| r.lanes_forward.len().max(r.lanes_backward.len()))
            .max()
            .unwrap_or(0) as u8;
        self.map.roundabouts.insert(
            id,
            Roundabout {
                id,
                source,
                kind,
                priority,
                priority_source,
                osm_way_ids,
                osm_node_id: None,
                roads: ring.to_vec(),
                circulating_lanes: cycle,
                ring_lanes,
                lanes_across,
                entries,
                exits,
                yield_lines,
                centre,
                radius_m: radius,
                clockwise: signed_area(&points) < 0.0,
            },
        );
        true
    }

    /// A line across a group of side-by-side lanes at arc length `s` of each (None: their ends).
    pub(super) fn line_across(&self, lanes: &[LaneId], s: Option<f64>) -> Option<Vec<Point>> {
        let mut pts = Vec::new();
        for l in lanes {
            let lane = self.map.lanes.get(l)?;
            let at = |line: &[Point]| {
                let len = polyline_length(line);
                let frac = s
                    .map(|s| (s / lane.length_m).clamp(0.0, 1.0))
                    .unwrap_or(1.0);
                crate::geometry::point_at(line, len * frac)
            };
            pts.push(at(&lane.left));
            pts.push(at(&lane.right));
        }
        // The two points farthest apart span the group.
        let mut best = (0.0, 0, 0);
        for i in 0..pts.len() {
            for k in i + 1..pts.len() {
                let d = pts[i].distance(pts[k]);
                if d > best.0 {
                    best = (d, i, k);
                }
            }
        }
        (best.0 > 0.0).then(|| vec![pts[best.1], pts[best.2]])
    }
}

/// Ring lane pairs at a joint: `from` and `to` inner lane first. Lane to lane aligned on the
/// outer side (extra inner lanes share the innermost), and each lane also into the lanes on
/// either side of its own target (a lane change: outwards towards the exits, inwards to go
/// further round), so that the ring lanes are strongly connected.
fn ring_lane_pairs(from: &[LaneId], to: &[LaneId]) -> Vec<(LaneId, LaneId)> {
    let (nf, nt) = (from.len(), to.len());
    if nf == 0 || nt == 0 {
        return Vec::new();
    }
    // Target index (in `to`) of from-lane i.
    let target = |i: usize| (nt - 1).saturating_sub((nf - 1 - i).min(nt - 1));
    let mut pairs = BTreeSet::new();
    for (i, &f) in from.iter().enumerate() {
        let t = target(i);
        pairs.insert((f, to[t]));
        if t + 1 < nt {
            pairs.insert((f, to[t + 1]));
        }
        if t > 0 {
            pairs.insert((f, to[t - 1]));
        }
    }
    // Extra lanes on the target side are fed from the innermost lane.
    for &t in &to[..nt.saturating_sub(nf)] {
        pairs.insert((from[0], t));
    }
    pairs.into_iter().collect()
}

/// Lane to lane from the outer side (the last of each list): extra lanes on either side
/// share the innermost lane of the other.
fn outer_aligned(from: &[LaneId], to: &[LaneId]) -> Vec<(LaneId, LaneId)> {
    let (nf, nt) = (from.len(), to.len());
    (0..nf.max(nt))
        .filter_map(|k| {
            let f = from.get(nf.checked_sub(1 + k.min(nf.checked_sub(1)?))?)?;
            let t = to.get(nt.checked_sub(1 + k.min(nt.checked_sub(1)?))?)?;
            Some((*f, *t))
        })
        .collect()
}

/// A lane of `lanes` that is not on a directed cycle through all of them (None when they
/// are strongly connected through the connections `next_of` / `prev_of`).
fn not_strongly_connected(
    lanes: &[LaneId],
    set: &BTreeSet<LaneId>,
    next_of: &BTreeMap<LaneId, Vec<LaneId>>,
    prev_of: &BTreeMap<LaneId, Vec<LaneId>>,
) -> Option<LaneId> {
    let start = *lanes.first()?;
    for step in [next_of, prev_of] {
        let mut seen = BTreeSet::from([start]);
        let mut stack = vec![start];
        while let Some(l) = stack.pop() {
            for n in step.get(&l).into_iter().flatten() {
                if set.contains(n) && seen.insert(*n) {
                    stack.push(*n);
                }
            }
        }
        if let Some(missed) = lanes.iter().find(|l| !seen.contains(l)) {
            return Some(*missed);
        }
    }
    None
}

/// Groups roads into connected sets by shared junctions (union-find), in id order.
fn group_by_junctions(map: &crate::model::Map, roads: &[RoadId]) -> Vec<Vec<RoadId>> {
    let mut parent: BTreeMap<JunctionId, JunctionId> = BTreeMap::new();
    fn find(parent: &mut BTreeMap<JunctionId, JunctionId>, x: JunctionId) -> JunctionId {
        let mut root = x;
        while let Some(&p) = parent.get(&root) {
            if p == root {
                break;
            }
            root = p;
        }
        let mut cur = x;
        while let Some(&p) = parent.get(&cur) {
            if p == root {
                break;
            }
            parent.insert(cur, root);
            cur = p;
        }
        root
    }
    for r in roads {
        let Some(road) = map.roads.get(r) else {
            continue;
        };
        parent
            .entry(road.start_junction)
            .or_insert(road.start_junction);
        parent.entry(road.end_junction).or_insert(road.end_junction);
        let (a, b) = (
            find(&mut parent, road.start_junction),
            find(&mut parent, road.end_junction),
        );
        if a != b {
            let (lo, hi) = if a < b { (a, b) } else { (b, a) };
            parent.insert(hi, lo);
        }
    }
    let mut groups: BTreeMap<JunctionId, Vec<RoadId>> = BTreeMap::new();
    for r in roads {
        if let Some(road) = map.roads.get(r) {
            let root = find(&mut parent, road.start_junction);
            groups.entry(root).or_default().push(*r);
        }
    }
    groups.into_values().collect()
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use crate::model::{
        LaneId, PrioritySource, RoundaboutKind, RoundaboutPriority, RoundaboutSource,
    };
    use crate::{ImportOptions, import_osm};

    /// OSM XML with a one-way loop through `ring` (metres around 50° N 10° E, drawn in
    /// order and closed) and a two-way residential arm leaving from each ring node in `arms`.
    fn loop_with_arms(ring: &[(f64, f64)], arms: &[usize], ring_tags: &str) -> String {
        let to_deg = |(x, y): (f64, f64)| {
            (
                50.0 + y / 111_320.0,
                10.0 + x / (111_320.0 * 50f64.to_radians().cos()),
            )
        };
        let mut xml = String::from("<osm version=\"0.6\">\n");
        for (i, p) in ring.iter().enumerate() {
            let (lat, lon) = to_deg(*p);
            xml += &format!(
                "<node id=\"{}\" lat=\"{lat:.7}\" lon=\"{lon:.7}\"/>\n",
                i + 1
            );
        }
        for (k, &i) in arms.iter().enumerate() {
            let (x, y) = ring[i];
            let n = (x * x + y * y).sqrt();
            let (lat, lon) = to_deg((x + 100.0 * x / n, y + 100.0 * y / n));
            xml += &format!(
                "<node id=\"{}\" lat=\"{lat:.7}\" lon=\"{lon:.7}\"/>\n",
                100 + k
            );
            xml += &format!(
                "<way id=\"{}\"><nd ref=\"{}\"/><nd ref=\"{}\"/><tag k=\"highway\" v=\"residential\"/></way>\n",
                200 + k,
                i + 1,
                100 + k
            );
        }
        xml += "<way id=\"1\">";
        for i in 0..=ring.len() {
            xml += &format!("<nd ref=\"{}\"/>", i % ring.len() + 1);
        }
        xml += &format!(
            "<tag k=\"highway\" v=\"residential\"/><tag k=\"oneway\" v=\"yes\"/>{ring_tags}</way>\n</osm>\n"
        );
        xml
    }

    fn import(xml: &str) -> crate::Map {
        let osm = crate::osm::parse_xml(xml.as_bytes()).expect("test XML parses");
        import_osm(&osm, &ImportOptions::default()).expect("imports")
    }

    fn circle(r: f64, n: usize) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                (r * a.cos(), r * a.sin())
            })
            .collect()
    }

    #[test]
    fn untagged_circular_one_way_loop_is_a_guessed_roundabout() {
        let map = import(&loop_with_arms(&circle(20.0, 12), &[0, 4, 8], ""));
        assert_eq!(map.roundabouts.len(), 1);
        let r = map.roundabouts.values().next().expect("one");
        assert_eq!(r.source, RoundaboutSource::Guessed);
        assert_eq!(
            (r.entries.len(), r.exits.len(), r.yield_lines.len()),
            (3, 3, 3)
        );
        assert!(!r.clockwise);
        assert!((r.radius_m - 20.0).abs() < 2.0, "radius {}", r.radius_m);
    }

    #[test]
    fn the_same_loop_tagged_is_a_tagged_roundabout_and_guessing_can_be_off() {
        let tagged = import(&loop_with_arms(
            &circle(20.0, 12),
            &[0, 4, 8],
            "<tag k=\"junction\" v=\"roundabout\"/>",
        ));
        assert_eq!(
            tagged.roundabouts.values().next().map(|r| r.source),
            Some(RoundaboutSource::Tagged)
        );
        let osm =
            crate::osm::parse_xml(loop_with_arms(&circle(20.0, 12), &[0, 4, 8], "").as_bytes())
                .expect("parses");
        let off = import_osm(
            &osm,
            &ImportOptions {
                guess_roundabouts: false,
                ..Default::default()
            },
        )
        .expect("imports");
        assert!(off.roundabouts.is_empty());
    }

    #[test]
    fn a_square_block_of_one_way_streets_is_not_a_roundabout() {
        // 100 m square (circularity 0.785), the shape netconvert mistakes for roundabouts.
        let square = [(-50.0, -50.0), (50.0, -50.0), (50.0, 50.0), (-50.0, 50.0)];
        let map = import(&loop_with_arms(&square, &[0, 1, 2, 3], ""));
        assert!(map.roundabouts.is_empty());
    }

    #[test]
    fn a_loop_hanging_off_one_road_is_a_turning_loop() {
        let map = import(&loop_with_arms(&circle(15.0, 10), &[0], ""));
        assert!(map.roundabouts.is_empty());
    }
    /// The tagged ring problems of a map, as (ways, imported) with the reason.
    fn problems(map: &crate::Map) -> Vec<(Vec<i64>, bool, String)> {
        map.report
            .ring_problems
            .iter()
            .map(|p| (p.osm_way_ids.clone(), p.imported, p.reason.clone()))
            .collect()
    }

    fn tagged(map: &crate::Map) -> usize {
        map.roundabouts
            .values()
            .filter(|r| r.source == RoundaboutSource::Tagged)
            .count()
    }

    /// The ring of `loop_with_arms` split into two ways at ring node `split + 1`: way 1 up to
    /// it, way 2 from it (reversed when `reverse_second`), both with `tags`.
    fn split_ring(n: usize, split: usize, reverse_second: bool, tags: &str) -> String {
        let xml = loop_with_arms(&circle(20.0, n), &[0, 4, 8], "");
        let start = xml.find("<way id=\"1\">").unwrap_or(0);
        let mut out = xml[..start].to_owned();
        let nd = |i: usize| format!("<nd ref=\"{}\"/>", i % n + 1);
        let first: String = (0..=split).map(nd).collect();
        let mut second: Vec<String> = (split..=n).map(nd).collect();
        if reverse_second {
            second.reverse();
        }
        for (id, nds) in [(1, first), (2, second.concat())] {
            out += &format!(
                "<way id=\"{id}\">{nds}<tag k=\"highway\" v=\"residential\"/><tag k=\"junction\" v=\"roundabout\"/>{tags}</way>\n"
            );
        }
        out + "</osm>\n"
    }

    #[test]
    fn a_two_lane_ring_is_one_roundabout_with_strongly_connected_lanes() {
        // Two lanes on the ring, two each way on the arms.
        let map = import(
            &loop_with_arms(
                &circle(25.0, 12),
                &[0, 4, 8],
                "<tag k=\"junction\" v=\"roundabout\"/><tag k=\"lanes\" v=\"2\"/>",
            )
            .replace(
                "v=\"residential\"/></way>",
                "v=\"residential\"/><tag k=\"lanes\" v=\"4\"/></way>",
            ),
        );
        assert_eq!(tagged(&map), 1, "{:?}", problems(&map));
        let r = map.roundabouts.values().next().expect("one");
        assert_eq!(r.lanes_across, 2);
        assert_eq!(r.kind, RoundaboutKind::Roundabout);
        assert_eq!(
            (r.priority, r.priority_source),
            (RoundaboutPriority::Circulating, PrioritySource::Assumed)
        );
        assert_eq!(r.ring_lanes.len(), 2 * r.roads.len());
        assert_eq!((r.entries.len(), r.exits.len()), (3, 3));
        // Every lane of every entry leads onto the ring, every lane of every exit is reached
        // from it.
        let onto_ring = |from: &LaneId, to: &LaneId| {
            map.connections
                .values()
                .any(|c| c.from == *from && c.to == *to)
        };
        for arm in &r.entries {
            assert_eq!(arm.lanes.len(), 2);
            for l in &arm.lanes {
                assert!(
                    r.ring_lanes.iter().any(|x| onto_ring(l, x)),
                    "entry lane {l}"
                );
            }
        }
        for arm in &r.exits {
            assert_eq!(arm.lanes.len(), 2);
            for l in &arm.lanes {
                assert!(
                    r.ring_lanes.iter().any(|x| onto_ring(x, l)),
                    "exit lane {l}"
                );
            }
        }
        // Every entry reaches every exit through the ring.
        let next = map.outgoing();
        for entry in &r.entries {
            let mut seen: BTreeSet<LaneId> = entry.lanes.iter().copied().collect();
            let mut stack: Vec<LaneId> = seen.iter().copied().collect();
            while let Some(l) = stack.pop() {
                for c in next.get(&l).into_iter().flatten() {
                    let to = map.connections[c].to;
                    if (r.ring_lanes.contains(&to) || r.exits.iter().any(|x| x.lanes.contains(&to)))
                        && seen.insert(to)
                    {
                        stack.push(to);
                    }
                }
            }
            for exit in &r.exits {
                assert!(
                    exit.lanes.iter().any(|l| seen.contains(l)),
                    "entry {:?} to exit {:?}",
                    entry.road,
                    exit.road
                );
            }
        }
    }

    #[test]
    fn a_circular_junction_with_give_way_signs_on_its_entries() {
        let xml = loop_with_arms(
            &circle(20.0, 12),
            &[0, 4, 8],
            "<tag k=\"junction\" v=\"circular\"/>",
        )
        .replace("<node id=\"100\"", "<node id=\"100\" ");
        // A give-way sign in the middle of the first arm (a node added to way 200).
        let xml = xml
            .replace(
                "<way id=\"200\"><nd ref=\"1\"/>",
                "<node id=\"150\" lat=\"50.0\" lon=\"10.000400\"><tag k=\"highway\" v=\"give_way\"/></node>\n<way id=\"200\"><nd ref=\"1\"/><nd ref=\"150\"/>",
            );
        let map = import(&xml);
        let r = map.roundabouts.values().next().expect("one");
        assert_eq!(r.kind, RoundaboutKind::Circular);
        assert_eq!(
            (r.priority, r.priority_source),
            (RoundaboutPriority::Circulating, PrioritySource::Tags)
        );
    }

    #[test]
    fn a_ring_that_is_not_closed_is_listed_and_its_road_kept() {
        let mut ring = circle(20.0, 12);
        ring.truncate(9);
        let xml = loop_with_arms(&ring, &[0, 4, 8], "<tag k=\"junction\" v=\"roundabout\"/>")
            .replace(
                "<nd ref=\"1\"/><tag k=\"highway\" v=\"residential\"/><tag k=\"oneway\"",
                "<tag k=\"highway\" v=\"residential\"/><tag k=\"oneway\"",
            );
        let map = import(&xml);
        assert_eq!(tagged(&map), 0);
        let p = problems(&map);
        assert_eq!(p.len(), 1, "{p:?}");
        assert!(
            p[0].2.starts_with("not closed") && p[0].2.contains("way 1") && !p[0].1,
            "{p:?}"
        );
        assert!(map.roads.values().any(|r| r.osm_way_ids == [1]));
    }

    #[test]
    fn a_ring_with_nodes_missing_from_the_extract_is_listed() {
        let xml = split_ring(12, 6, false, "")
            .replace("<nd ref=\"4\"/>", "<nd ref=\"4\"/><nd ref=\"999\"/>");
        let map = import(&xml);
        assert_eq!(tagged(&map), 0);
        let p = problems(&map);
        assert_eq!(p.len(), 1, "{p:?}");
        assert_eq!(p[0].0, vec![1, 2]);
        assert!(p[0].2.contains("way 1 has 1 of its nodes missing"), "{p:?}");
        // The rest of the ring is still imported as a one-way road.
        assert!(map.roads.values().any(|r| r.osm_way_ids == [2]));
    }

    #[test]
    fn a_piece_against_the_ring_direction_is_listed() {
        let map = import(&split_ring(12, 6, true, ""));
        assert_eq!(tagged(&map), 0);
        let p = problems(&map);
        assert_eq!(p.len(), 1, "{p:?}");
        assert!(
            p[0].2.contains("against the ring's direction") && p[0].2.contains("way 1 and way 2"),
            "{p:?}"
        );
        // The same ring drawn the right way round is one roundabout.
        let map = import(&split_ring(12, 6, false, ""));
        assert_eq!(tagged(&map), 1, "{:?}", problems(&map));
        assert_eq!(
            map.roundabouts
                .values()
                .next()
                .map(|r| r.osm_way_ids.clone()),
            Some(vec![1, 2])
        );
    }

    #[test]
    fn unusable_lane_counts_import_with_the_default_and_are_listed() {
        for value in ["0", "banana", "-1", "99"] {
            let map = import(&split_ring(
                12,
                6,
                false,
                &format!("<tag k=\"lanes\" v=\"{value}\"/>"),
            ));
            assert_eq!(tagged(&map), 1, "lanes={value}: {:?}", problems(&map));
            assert_eq!(
                map.roundabouts.values().next().map(|r| r.lanes_across),
                Some(1)
            );
            let p = problems(&map);
            assert_eq!(p.len(), 2, "lanes={value}: one per way: {p:?}");
            assert!(
                p.iter().all(|(ways, imported, reason)| *ways == [1, 2]
                    && *imported
                    && reason.contains(&format!("lanes={value}"))),
                "{p:?}"
            );
        }
    }

    #[test]
    fn mini_roundabout_nodes_are_found_at_crossings_and_inside_one_way() {
        // A crossing of two streets at node 1 (a mini-roundabout), and node 11 inside street 20.
        let xml = r#"<osm version="0.6">
<node id="1" lat="50.0" lon="10.0"><tag k="highway" v="mini_roundabout"/></node>
<node id="2" lat="50.001" lon="10.0"/><node id="3" lat="49.999" lon="10.0"/>
<node id="4" lat="50.0" lon="10.001"/><node id="5" lat="50.0" lon="9.999"/>
<node id="11" lat="50.0005" lon="10.0"><tag k="highway" v="mini_roundabout"/></node>
<node id="12" lat="50.5" lon="10.5"><tag k="highway" v="mini_roundabout"/></node>
<way id="20"><nd ref="2"/><nd ref="11"/><nd ref="1"/><nd ref="3"/><tag k="highway" v="residential"/></way>
<way id="21"><nd ref="4"/><nd ref="1"/><nd ref="5"/><tag k="highway" v="residential"/></way>
</osm>"#;
        let map = import(xml);
        let found: Vec<(Option<i64>, usize, usize)> = map
            .roundabouts
            .values()
            .map(|m| (m.osm_node_id, m.entries.len(), m.exits.len()))
            .collect();
        assert_eq!(found, vec![(Some(1), 4, 4), (Some(11), 2, 2)]);
        for r in map.roundabouts.values() {
            // A small ring of one lane, driven anticlockwise (traffic keeps right here),
            // given way to on every entry, with no way id of its own.
            assert_eq!(r.kind, RoundaboutKind::MiniRoundabout);
            assert!(r.osm_way_ids.is_empty());
            assert_eq!(r.lanes_across, 1);
            assert!(!r.clockwise);
            assert!(
                (r.radius_m - super::super::mini::MINI_RING_RADIUS_M).abs() < 0.5,
                "{}",
                r.radius_m
            );
            assert_eq!(r.yield_lines.len(), r.entries.len());
            for road in &r.roads {
                assert!(map.roads[road].osm_way_ids.is_empty());
            }
        }
        // The streets keep their own way ids on both sides of the ring.
        let street_roads = map.roads.values().filter(|r| r.osm_way_ids == [20]).count();
        assert_eq!(street_roads, 3);
        let s = crate::summary::summarize(&map);
        assert!(
            s.roundabouts
                .iter()
                .all(|r| r.kind == RoundaboutKind::MiniRoundabout)
        );
        assert_eq!(s.ring_problems.len(), 1);
        assert_eq!(s.ring_problems[0].osm_node_id, Some(12));
    }
    #[test]
    fn a_mini_roundabout_with_a_junction_next_to_it_stays_a_junction_and_is_listed() {
        // Node 6, a junction of way 21 with way 22, lies 3 m from the mini-roundabout.
        let xml = r#"<osm version="0.6">
<node id="1" lat="50.0" lon="10.0"><tag k="highway" v="mini_roundabout"/></node>
<node id="2" lat="50.001" lon="10.0"/><node id="3" lat="49.999" lon="10.0"/>
<node id="4" lat="50.0" lon="10.001"/><node id="5" lat="50.0" lon="9.999"/>
<node id="6" lat="50.0" lon="10.000042"/><node id="7" lat="50.001" lon="10.001"/>
<way id="20"><nd ref="2"/><nd ref="1"/><nd ref="3"/><tag k="highway" v="residential"/></way>
<way id="21"><nd ref="4"/><nd ref="6"/><nd ref="1"/><nd ref="5"/><tag k="highway" v="residential"/></way>
<way id="22"><nd ref="6"/><nd ref="7"/><tag k="highway" v="residential"/></way>
</osm>"#;
        let map = import(xml);
        assert!(map.roundabouts.is_empty());
        let s = crate::summary::summarize(&map);
        assert_eq!(s.ring_problems.len(), 1);
        let p = &s.ring_problems[0];
        assert_eq!(p.osm_node_id, Some(1));
        assert!(!p.imported);
        assert!(
            p.reason.contains("node 1") && p.reason.contains("within"),
            "{}",
            p.reason
        );
        // The node is still the junction of both streets.
        assert!(map.junctions.values().any(|j| j.osm_node_id == Some(1)));
    }

    #[test]
    fn a_mini_roundabout_where_traffic_keeps_left_is_driven_clockwise() {
        let xml = r#"<osm version="0.6">
<node id="1" lat="51.5" lon="-0.1"><tag k="highway" v="mini_roundabout"/></node>
<node id="2" lat="51.501" lon="-0.1"/><node id="3" lat="51.499" lon="-0.1"/>
<node id="4" lat="51.5" lon="-0.099"/>
<way id="20"><nd ref="2"/><nd ref="1"/><nd ref="3"/><tag k="highway" v="residential"/></way>
<way id="21"><nd ref="1"/><nd ref="4"/><tag k="highway" v="residential"/></way>
</osm>"#;
        let map = import(xml);
        assert_eq!(map.driving_side, crate::model::DrivingSide::Left);
        let r = map.roundabouts.values().next().expect("a ring");
        assert!(r.clockwise);
        assert_eq!((r.entries.len(), r.exits.len()), (3, 3));
    }

    #[test]
    fn a_chord_across_a_ring_is_listed_and_the_ring_still_imported() {
        // A one-way chord from ring node 1 (the closed way's end) to ring node 5, tagged too.
        let xml = loop_with_arms(
            &circle(25.0, 12),
            &[0, 4, 8],
            "<tag k=\"junction\" v=\"roundabout\"/>",
        )
        .replace(
            "</osm>",
            "<way id=\"3\"><nd ref=\"1\"/><nd ref=\"5\"/><tag k=\"highway\" v=\"residential\"/><tag k=\"junction\" v=\"roundabout\"/></way>\n</osm>",
        );
        let map = import(&xml);
        assert_eq!(tagged(&map), 1, "{:?}", problems(&map));
        assert_eq!(
            map.roundabouts
                .values()
                .next()
                .map(|r| r.osm_way_ids.clone()),
            Some(vec![1, 3])
        );
        let p = problems(&map);
        assert!(
            !p.is_empty()
                && p.iter()
                    .all(|(ways, imported, _)| *ways == [1, 3] && *imported),
            "{p:?}"
        );
    }
    #[test]
    fn traffic_signals_on_the_ring_give_entering_traffic_priority() {
        let xml = loop_with_arms(
            &circle(20.0, 12),
            &[0, 4, 8],
            "<tag k=\"junction\" v=\"roundabout\"/>",
        );
        let at = xml.find("<node id=\"5\"").unwrap_or(0);
        let end = at + xml[at..].find("/>").unwrap_or(0);
        let xml = format!(
            "{}><tag k=\"highway\" v=\"traffic_signals\"/></node>{}",
            &xml[..end],
            &xml[end + 2..]
        );
        let map = import(&xml);
        let r = map.roundabouts.values().next().expect("one");
        assert_eq!(
            (r.priority, r.priority_source),
            (RoundaboutPriority::Entering, PrioritySource::Tags)
        );
        // The give-way lines stay on the entries.
        assert_eq!(r.yield_lines.len(), r.entries.len());
    }
}
