//! Lanelet2 HD maps (OSM XML with `type=lanelet` and `type=regulatory_element` relations, as
//! the INTERACTION dataset ships them) to a [`Map`].
//!
//! Lanelet2 already describes lanes, so most of the mapping is direct: each drivable lanelet
//! becomes one road with one lane whose boundaries are the lanelet's bounds. What Lanelet2
//! leaves implicit is made explicit here, in named steps each followed by an invariant check:
//!
//! - joints: a lanelet follows another when it starts on the pair of bound end nodes the other
//!   ends on (Lanelet2's own notion of "following"); every such node pair is one junction,
//!   and every (ending, starting) pair of lanelets at it is one connection;
//! - stop and give-way lines: `stop_line` ways and the `ref_line`s of `right_of_way`,
//!   `traffic_sign` and `all_way_stop` regulatory elements;
//! - roundabouts: the directed cycles of the successor graph through the lanelets that have
//!   right of way over the entries (the `right_of_way` members of `right_of_way` elements).
//!
//! Positions use Lanelet2's `UtmProjector` convention, origin (0, 0) unless the options give
//! another: that is what lines the INTERACTION maps up with their track files.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BTreeSet, BinaryHeap, VecDeque};

use crate::error::MapError;
use crate::geometry::{
    Point, convex_hull, direction_at, point_at, polyline_length, project_onto_polyline,
    signed_area, slice_polyline,
};
use crate::graph::{component_of, strongly_connected_components};
use crate::invariants::check_invariants;
use crate::model::{
    Connection, ConnectionId, Direction, DrivingSide, ImportReport, Junction, JunctionId,
    JunctionKind, Lane, LaneId, Map, Marking, MarkingKind, PrioritySource, Road, RoadId,
    RoadSource, Roundabout, RoundaboutArm, RoundaboutId, RoundaboutKind, RoundaboutPriority,
    RoundaboutSource, StopKind, StopLine, StopLineId, StopLineSource, Turn,
};
use crate::options::{Clip, ClipRegion, ImportOptions};
use crate::osm::{MemberKind, OsmData, OsmRelation, Tags};
use crate::projection::{LatLon, Projection, Projector};

/// Bound end nodes closer than this are one point even with different ids: some maps are
/// stitched from pieces that repeat a node instead of sharing it.
const JOINT_TOLERANCE_M: f64 = 0.05;
/// Both bounds are resampled at this spacing (at most) before taking midpoints, so the centre
/// line follows curved lanelets closely (a sagitta under 2 mm at 20 m radius).
const RESAMPLE_STEP_M: f64 = 0.5;
/// When no speed limit applies: the urban limit of most countries.
const DEFAULT_SPEED_LIMIT_KMH: f64 = 50.0;
/// Heading changes under this are straight on.
const STRAIGHT_LIMIT_DEG: f64 = 30.0;
/// Heading changes over this turn back.
const U_TURN_LIMIT_DEG: f64 = 150.0;
/// How far into the next lane its heading is measured: its first segment alone is too
/// short to mean much on a resampled line.
const TURN_LOOKAHEAD_M: f64 = 10.0;
/// How much of each lane end a junction area covers.
const JUNCTION_AREA_REACH_M: f64 = 5.0;
/// A `stop_line` way stands at the end of every lane ending within this distance of it.
const STOP_LINE_AT_END_M: f64 = 1.0;
/// Otherwise it belongs to the lane ending nearest to it, if that is within this distance.
const STOP_LINE_NEAREST_END_MAX_M: f64 = 10.0;
/// How many lanelets an entry may run through from its yield lanelet to reach the ring.
const ENTRY_SEARCH_DEPTH: usize = 8;
/// Rings whose centres are closer than this fraction of their radius are lanes of one
/// roundabout (a multi-lane ring is several cycles in Lanelet2).
const CONCENTRIC_FRACTION: f64 = 0.5;
/// A ring tour through all circulating lanelets may be this much longer than the shortest
/// cycle through its first one (lane changes between ring lanes make it a little longer).
const RING_TOUR_SLACK: f64 = 1.5;
/// Lanes between the rings of one roundabout lie within this margin of its outermost ring.
const RING_MARGIN_M: f64 = 1.0;
/// Lanelet subtypes for people on foot; they are no roads.
const PEDESTRIAN_SUBTYPES: &[&str] = &[
    "crosswalk",
    "walkway",
    "shared_walkway",
    "sidewalk",
    "stairs",
];
/// Lanelet subtypes that are roads, but not for passenger cars.
const NON_CAR_SUBTYPES: &[&str] = &["bicycle_lane", "bus_lane", "emergency_lane"];

/// Imports a Lanelet2 map: lanelets to roads and lanes, joints to junctions and connections,
/// regulatory elements to stop lines, right-of-way rings to roundabouts.
///
/// Lanelets that reference missing ways or nodes are skipped and recorded in `map.report`;
/// only a map without any usable lanelet is an error.
pub fn build_lanelet2_map(osm: &OsmData, options: &ImportOptions) -> Result<Map, MapError> {
    let projection = Projection::utm(options.origin.unwrap_or(LatLon::new(0.0, 0.0)));
    let driving_side = options.driving_side.unwrap_or(DrivingSide::Right);
    let mut map = Map::new(projection, driving_side, &options.profile.name);
    map.report.invalid_nodes = osm.invalid_nodes.len();
    let projector = projection.projector();

    let clip = options.clip.as_ref().map(Clip::region);
    let lanelets = read_lanelets(osm, &projector, clip.as_ref(), &mut map.report);
    if lanelets.is_empty() {
        return Err(MapError::Invalid {
            path: None,
            message: format!(
                "no drivable lanelets: {} lanelet relations, none with two complete bounds of a drivable subtype",
                osm.relations
                    .values()
                    .filter(|r| r.tags.is("type", "lanelet"))
                    .count()
            ),
        });
    }
    let joints = find_joints(&lanelets);

    add_roads_and_lanes(&mut map, &lanelets, &joints);
    add_junctions(&mut map, &joints);
    add_markings(&mut map, osm, &lanelets);
    checked(&map, options, "lanelet2: roads, lanes and junctions")?;

    add_connections(&mut map, &joints);
    checked(&map, options, "lanelet2: connections")?;

    add_stop_lines(&mut map, osm, &lanelets, &projector);
    checked(&map, options, "lanelet2: stop lines")?;

    add_roundabouts(&mut map, osm, &lanelets, &joints);
    checked(&map, options, "lanelet2: roundabouts")?;
    Ok(map)
}

fn checked(map: &Map, options: &ImportOptions, step: &'static str) -> Result<(), MapError> {
    if options.check_invariants {
        check_invariants(map, step)
    } else {
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Lanelets

/// A usable lanelet: both bounds present, projected and oriented in its direction of travel.
#[derive(Debug, Clone)]
struct Lanelet {
    relation_id: i64,
    name: Option<String>,
    left_way: i64,
    right_way: i64,
    /// First node ids of the left and right bound, in the direction of travel.
    start_nodes: (i64, i64),
    /// Last node ids of the left and right bound.
    end_nodes: (i64, i64),
    left: Vec<Point>,
    right: Vec<Point>,
    centre: Vec<Point>,
    width_m: f64,
    allows_cars: bool,
    speed_limit_kmh: f64,
    speed_limit_is_default: bool,
    /// Regulatory elements the lanelet references (role `regulatory_element`).
    regulatory_elements: Vec<i64>,
}

/// Why a lanelet relation cannot become a road.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Skip {
    NoBounds,
    MissingWay(i64),
    MissingNodes(i64),
    Degenerate(i64),
    Clipped,
}

/// Lane and road ids are the lanelet's position in relation-id order.
fn lane_id(i: usize) -> LaneId {
    LaneId(i as u32)
}

fn road_id(i: usize) -> RoadId {
    RoadId(i as u32)
}

fn lanelet_index(lane: LaneId) -> usize {
    lane.0 as usize
}

fn first(pts: &[Point]) -> Point {
    pts.first().copied().unwrap_or_default()
}

fn last(pts: &[Point]) -> Point {
    pts.last().copied().unwrap_or_default()
}

/// Every usable lanelet in relation-id order; the others are counted in `report`.
fn read_lanelets(
    osm: &OsmData,
    projector: &Projector,
    clip: Option<&ClipRegion>,
    report: &mut ImportReport,
) -> Vec<Lanelet> {
    let speeds = speed_limit_elements(osm);
    let mut out = Vec::new();
    let (mut pedestrian, mut clipped, mut two_way) = (0usize, 0usize, 0usize);
    for (&id, rel) in &osm.relations {
        if !rel.tags.is("type", "lanelet") {
            continue;
        }
        if PEDESTRIAN_SUBTYPES.contains(&rel.tags.get("subtype").unwrap_or("road")) {
            pedestrian += 1;
            continue;
        }
        match read_lanelet(osm, id, rel, projector, clip, &speeds) {
            Ok(lanelet) => {
                two_way += usize::from(rel.tags.is("one_way", "no") && lanelet.allows_cars);
                out.push(lanelet);
            }
            Err(Skip::Clipped) => clipped += 1,
            Err(skip) => record_skip(report, id, skip),
        }
    }
    if pedestrian > 0 {
        report.notes.push(format!(
            "{pedestrian} pedestrian lanelets (crosswalk, walkway, ...) skipped"
        ));
    }
    if clipped > 0 {
        report.notes.push(format!(
            "{clipped} lanelets outside the clip region skipped"
        ));
    }
    if two_way > 0 {
        report.notes.push(format!(
            "{two_way} two-way lanelets (one_way=no) imported in one direction only"
        ));
    }
    out
}

fn record_skip(report: &mut ImportReport, lanelet: i64, skip: Skip) {
    let why = match skip {
        Skip::NoBounds => "it lacks a left or a right bound way".to_owned(),
        Skip::MissingWay(w) => format!("its bound way {w} is missing"),
        Skip::MissingNodes(w) => {
            if !report.ways_missing_nodes.contains(&w) {
                report.ways_missing_nodes.push(w);
            }
            format!("its bound way {w} references missing nodes")
        }
        Skip::Degenerate(w) => {
            if !report.degenerate_ways.contains(&w) {
                report.degenerate_ways.push(w);
            }
            format!("its bound way {w} (or the lane between its bounds) has no length")
        }
        Skip::Clipped => "it lies outside the clip region".to_owned(),
    };
    report
        .notes
        .push(format!("lanelet {lanelet} skipped: {why}"));
}

fn read_lanelet(
    osm: &OsmData,
    id: i64,
    rel: &OsmRelation,
    projector: &Projector,
    clip: Option<&ClipRegion>,
    speeds: &BTreeMap<i64, f64>,
) -> Result<Lanelet, Skip> {
    let (left_way, right_way) = bound_ways(rel).ok_or(Skip::NoBounds)?;
    let (mut left_nodes, mut left) = bound_points(osm, left_way, projector, clip)?;
    let (mut right_nodes, mut right) = bound_points(osm, right_way, projector, clip)?;
    let right_of_left = signed_distance(&left, middle_point(&right)) < 0.0;
    if !right_of_left {
        left.reverse();
        left_nodes.reverse();
    }
    let left_of_right = signed_distance(&right, middle_point(&left)) > 0.0;
    if !left_of_right {
        right.reverse();
        right_nodes.reverse();
    }
    let ends = |nodes: &[i64]| {
        (
            nodes.first().copied().unwrap_or_default(),
            nodes.last().copied().unwrap_or_default(),
        )
    };
    let ((left_start, left_end), (right_start, right_end)) =
        (ends(&left_nodes), ends(&right_nodes));
    let (centre, width_m) = centre_and_width(&left, &right);
    let length = polyline_length(&centre);
    let usable = length > 0.0 && length.is_finite() && width_m.is_finite();
    if !usable {
        return Err(Skip::Degenerate(left_way));
    }
    let regulatory_elements: Vec<i64> = rel
        .members
        .iter()
        .filter(|m| m.kind == MemberKind::Relation && m.role == "regulatory_element")
        .map(|m| m.id)
        .collect();
    let (speed_limit_kmh, speed_limit_is_default) =
        lanelet_speed_limit(&rel.tags, &regulatory_elements, speeds);
    Ok(Lanelet {
        relation_id: id,
        name: rel.tags.get("name").map(str::to_owned),
        left_way,
        right_way,
        start_nodes: (left_start, right_start),
        end_nodes: (left_end, right_end),
        left,
        right,
        centre,
        width_m,
        allows_cars: lanelet_allows_cars(&rel.tags),
        speed_limit_kmh,
        speed_limit_is_default,
        regulatory_elements,
    })
}

/// The first `left` and `right` way members.
fn bound_ways(rel: &OsmRelation) -> Option<(i64, i64)> {
    let way = |role: &str| {
        rel.members
            .iter()
            .find(|m| m.kind == MemberKind::Way && m.role == role)
            .map(|m| m.id)
    };
    Some((way("left")?, way("right")?))
}

/// Node ids and projected points of a bound way.
fn bound_points(
    osm: &OsmData,
    way_id: i64,
    projector: &Projector,
    clip: Option<&ClipRegion>,
) -> Result<(Vec<i64>, Vec<Point>), Skip> {
    let way = osm.ways.get(&way_id).ok_or(Skip::MissingWay(way_id))?;
    if way.nodes.len() < 2 {
        return Err(Skip::Degenerate(way_id));
    }
    let mut points = Vec::with_capacity(way.nodes.len());
    for n in &way.nodes {
        let node = osm.nodes.get(n).ok_or(Skip::MissingNodes(way_id))?;
        if clip.is_some_and(|c| !c.contains(node.pos)) {
            return Err(Skip::Clipped);
        }
        points.push(projector.project(node.pos));
    }
    let length = polyline_length(&points);
    if length.is_nan() || length <= 0.0 {
        return Err(Skip::Degenerate(way_id));
    }
    Ok((way.nodes.clone(), points))
}

// Lanelet2 lets a lanelet reference its bounds either way round (neighbouring lanelets share
// them), and its loader (`geometry::align`) orients them by where they lie: the left bound is
// turned if the right bound's middle is not on its right, then the right bound is turned if
// the left bound's middle is not on its left. The direction of travel follows, so a lanelet
// whose left way is drawn backwards runs the other way. The same rule is applied here.

/// The middle vertex of a line, or the midpoint of its ends when it has only two: the point
/// Lanelet2's `align` tests.
fn middle_point(pts: &[Point]) -> Point {
    if pts.len() > 2 {
        pts[pts.len() / 2]
    } else {
        first(pts).lerp(last(pts), 0.5)
    }
}

/// Distance from `p` to the nearest segment of `line`, positive when `p` lies on its left.
fn signed_distance(line: &[Point], p: Point) -> f64 {
    let mut best = (f64::INFINITY, 0.0);
    for w in line.windows(2) {
        let d = w[1].sub(w[0]);
        let distance = crate::geometry::closest_on_segment(w[0], w[1], p)
            .0
            .distance(p);
        if distance < best.0 {
            let side = if d.cross(p.sub(w[0])) >= 0.0 {
                1.0
            } else {
                -1.0
            };
            best = (distance, side * distance);
        }
    }
    best.1
}

/// Centre line (midpoints of both bounds resampled to the same number of points by arc
/// length) and mean width. Resampling by arc length pairs points across the lane even when
/// the two bounds have very different vertex counts.
fn centre_and_width(left: &[Point], right: &[Point]) -> (Vec<Point>, f64) {
    let longest = polyline_length(left).max(polyline_length(right));
    let n = ((longest / RESAMPLE_STEP_M).ceil() as usize).max(1);
    let (l, r) = (resample_n(left, n), resample_n(right, n));
    let centre: Vec<Point> = l.iter().zip(&r).map(|(a, b)| a.lerp(*b, 0.5)).collect();
    let width = l.iter().zip(&r).map(|(a, b)| a.distance(*b)).sum::<f64>() / l.len().max(1) as f64;
    (centre, width)
}

/// `n + 1` points evenly spaced by arc length, the ends exact so that lanelets sharing end
/// nodes get exactly the same centre end points.
fn resample_n(pts: &[Point], n: usize) -> Vec<Point> {
    let total = polyline_length(pts);
    let mut out: Vec<Point> = (0..=n)
        .map(|i| point_at(pts, total * i as f64 / n as f64))
        .collect();
    if let Some(end) = out.last_mut() {
        *end = last(pts);
    }
    out
}

/// Cars may use road-like lanelets unless `participant:vehicle(:car)` says otherwise.
fn lanelet_allows_cars(tags: &Tags) -> bool {
    let by_subtype = !NON_CAR_SUBTYPES.contains(&tags.get("subtype").unwrap_or("road"));
    match tags
        .get("participant:vehicle:car")
        .or_else(|| tags.get("participant:vehicle"))
    {
        Some("yes") => true,
        Some("no") => false,
        _ => by_subtype,
    }
}

/// Speed limit regulatory elements and their limit in km/h.
fn speed_limit_elements(osm: &OsmData) -> BTreeMap<i64, f64> {
    osm.relations
        .iter()
        .filter(|(_, r)| {
            r.tags.is("type", "regulatory_element") && r.tags.is("subtype", "speed_limit")
        })
        .filter_map(|(&id, r)| {
            let value = r
                .tags
                .get("sign_type")
                .or_else(|| r.tags.get("limit"))
                .or_else(|| r.tags.get("speed_limit"))?;
            Some((id, parse_speed_kmh(value)?))
        })
        .collect()
}

/// A lanelet's own `speed_limit` tag, else its first speed limit element, else the default.
fn lanelet_speed_limit(tags: &Tags, elements: &[i64], speeds: &BTreeMap<i64, f64>) -> (f64, bool) {
    tags.get("speed_limit")
        .and_then(parse_speed_kmh)
        .or_else(|| elements.iter().find_map(|e| speeds.get(e).copied()))
        .map_or((DEFAULT_SPEED_LIMIT_KMH, true), |s| (s, false))
}

/// Lanelet2 sign types (`25mph`, `30kmh`, `50 km/h`, `50`) to km/h.
fn parse_speed_kmh(value: &str) -> Option<f64> {
    let v: String = value
        .chars()
        .filter(|c| !c.is_whitespace())
        .collect::<String>()
        .to_ascii_lowercase();
    if let Some(n) = v.strip_suffix("kmh").or_else(|| v.strip_suffix("kph")) {
        let x: f64 = n.parse().ok()?;
        return (x.is_finite() && x > 0.0 && x < 400.0).then_some(x);
    }
    crate::tags::parse_maxspeed(&v)
}

// ---------------------------------------------------------------------------------------------
// Joints, roads, lanes, junctions

/// Where lanelets meet: the lanelets ending and starting on one pair of bound end nodes.
#[derive(Debug, Clone, Default)]
struct Joint {
    ins: Vec<usize>,
    outs: Vec<usize>,
    /// Positions of the left and right end nodes.
    left: Point,
    right: Point,
}

/// All joints (index = junction id) and, per lanelet, the joints it starts and ends at.
#[derive(Debug, Clone)]
struct Joints {
    list: Vec<Joint>,
    start_of: Vec<usize>,
    end_of: Vec<usize>,
}

impl Joints {
    fn successors(&self, lanelet: usize) -> &[usize] {
        &self.list[self.end_of[lanelet]].outs
    }
}

type JointKey = (i64, i64);

fn find_joints(lanelets: &[Lanelet]) -> Joints {
    let canonical = merge_close_end_nodes(lanelets);
    let node = |n: i64| canonical.get(&n).copied().unwrap_or(n);
    let starts: Vec<JointKey> = lanelets
        .iter()
        .map(|l| (node(l.start_nodes.0), node(l.start_nodes.1)))
        .collect();
    let ends: Vec<JointKey> = lanelets
        .iter()
        .map(|l| (node(l.end_nodes.0), node(l.end_nodes.1)))
        .collect();
    let keys: BTreeSet<JointKey> = starts.iter().chain(&ends).copied().collect();
    let index: BTreeMap<JointKey, usize> = keys.iter().enumerate().map(|(i, k)| (*k, i)).collect();
    let mut list = vec![Joint::default(); keys.len()];
    let mut placed = vec![false; keys.len()];
    let (mut start_of, mut end_of) = (
        Vec::with_capacity(lanelets.len()),
        Vec::with_capacity(lanelets.len()),
    );
    for (i, l) in lanelets.iter().enumerate() {
        let (s, e) = (index[&starts[i]], index[&ends[i]]);
        list[s].outs.push(i);
        list[e].ins.push(i);
        for (j, left, right) in [
            (s, first(&l.left), first(&l.right)),
            (e, last(&l.left), last(&l.right)),
        ] {
            if !placed[j] {
                (list[j].left, list[j].right, placed[j]) = (left, right, true);
            }
        }
        start_of.push(s);
        end_of.push(e);
    }
    Joints {
        list,
        start_of,
        end_of,
    }
}

/// Maps every bound end node to the smallest id of the end nodes within
/// [`JOINT_TOLERANCE_M`] of it (transitively), so that lanelets which repeat a node instead
/// of sharing it still follow each other.
fn merge_close_end_nodes(lanelets: &[Lanelet]) -> BTreeMap<i64, i64> {
    let mut ends: BTreeMap<i64, Point> = BTreeMap::new();
    for l in lanelets {
        ends.insert(l.start_nodes.0, first(&l.left));
        ends.insert(l.start_nodes.1, first(&l.right));
        ends.insert(l.end_nodes.0, last(&l.left));
        ends.insert(l.end_nodes.1, last(&l.right));
    }
    let mut pts: Vec<(i64, Point)> = ends.into_iter().collect();
    pts.sort_by(|a, b| a.1.x.total_cmp(&b.1.x).then(a.0.cmp(&b.0)));
    let mut parent: BTreeMap<i64, i64> = pts.iter().map(|(id, _)| (*id, *id)).collect();
    for (i, &(a, pa)) in pts.iter().enumerate() {
        for &(b, pb) in &pts[i + 1..] {
            if pb.x - pa.x > JOINT_TOLERANCE_M {
                break;
            }
            if pa.distance(pb) <= JOINT_TOLERANCE_M {
                let (ra, rb) = (find_root(&parent, a), find_root(&parent, b));
                parent.insert(ra.max(rb), ra.min(rb));
            }
        }
    }
    pts.iter()
        .map(|(id, _)| (*id, find_root(&parent, *id)))
        .collect()
}

fn find_root(parent: &BTreeMap<i64, i64>, mut id: i64) -> i64 {
    while let Some(&p) = parent.get(&id) {
        if p == id {
            break;
        }
        id = p;
    }
    id
}

fn add_roads_and_lanes(map: &mut Map, lanelets: &[Lanelet], joints: &Joints) {
    for (i, l) in lanelets.iter().enumerate() {
        let (from, to) = (
            JunctionId(joints.start_of[i] as u32),
            JunctionId(joints.end_of[i] as u32),
        );
        let length_m = polyline_length(&l.centre);
        map.roads.insert(
            road_id(i),
            Road {
                id: road_id(i),
                source: RoadSource::Lanelet {
                    relation_id: l.relation_id,
                },
                osm_way_ids: vec![l.left_way, l.right_way],
                highway: "lanelet".to_owned(),
                name: l.name.clone(),
                reference_line: l.centre.clone(),
                start_junction: from,
                end_junction: to,
                lanes_forward: vec![lane_id(i)],
                lanes_backward: Vec::new(),
                speed_limit_kmh: l.speed_limit_kmh,
                speed_limit_is_default: l.speed_limit_is_default,
                is_roundabout: false,
                allows_cars: l.allows_cars,
            },
        );
        map.lanes.insert(
            lane_id(i),
            Lane {
                id: lane_id(i),
                road: road_id(i),
                direction: Direction::Forward,
                index_from_centre: 0,
                centre: l.centre.clone(),
                left: l.left.clone(),
                right: l.right.clone(),
                width_m: l.width_m,
                length_m,
                speed_limit_kmh: l.speed_limit_kmh,
                turns: Vec::new(),
                from_junction: from,
                to_junction: to,
            },
        );
    }
}

/// Continuation for one lanelet in and one out, dead end where nothing comes in or nothing
/// goes out, intersection (a fork or a merge) otherwise.
fn junction_kind(joint: &Joint) -> JunctionKind {
    match (joint.ins.len(), joint.outs.len()) {
        (0, _) | (_, 0) => JunctionKind::DeadEnd,
        (1, 1) => JunctionKind::Continuation,
        _ => JunctionKind::Intersection,
    }
}

fn add_junctions(map: &mut Map, joints: &Joints) {
    for (j, joint) in joints.list.iter().enumerate() {
        let kind = junction_kind(joint);
        let polygon = if kind == JunctionKind::Intersection {
            junction_area(map, joint)
        } else {
            Vec::new()
        };
        let roads: BTreeSet<RoadId> = joint
            .ins
            .iter()
            .chain(&joint.outs)
            .map(|&i| road_id(i))
            .collect();
        let id = JunctionId(j as u32);
        map.junctions.insert(
            id,
            Junction {
                id,
                kind,
                osm_node_id: None,
                point: joint.left.lerp(joint.right, 0.5),
                polygon,
                roads: roads.into_iter().collect(),
                control: None,
            },
        );
    }
}

/// Convex hull of the bounds' last (incoming lanes) and first (outgoing lanes) few metres:
/// the area where a fork's or merge's lanes overlap.
fn junction_area(map: &Map, joint: &Joint) -> Vec<Point> {
    let mut pts = Vec::new();
    let lanes = |ids: &[usize]| {
        ids.iter()
            .filter_map(|&i| map.lanes.get(&lane_id(i)))
            .collect::<Vec<_>>()
    };
    for lane in lanes(&joint.ins) {
        for bound in [&lane.left, &lane.right] {
            let len = polyline_length(bound);
            pts.extend(slice_polyline(bound, len - JUNCTION_AREA_REACH_M, len));
        }
    }
    for lane in lanes(&joint.outs) {
        for bound in [&lane.left, &lane.right] {
            pts.extend(slice_polyline(bound, 0.0, JUNCTION_AREA_REACH_M));
        }
    }
    let hull = convex_hull(&pts);
    if hull.len() >= 3 && signed_area(&hull) > 0.0 {
        hull
    } else {
        Vec::new()
    }
}

/// One marking per painted bound way, on the first road it bounds. Kerbs, virtual lines
/// and the like are no paint.
fn add_markings(map: &mut Map, osm: &OsmData, lanelets: &[Lanelet]) {
    let mut seen = BTreeSet::new();
    for (i, l) in lanelets.iter().enumerate() {
        for (way, line) in [(l.left_way, &l.left), (l.right_way, &l.right)] {
            if !seen.insert(way) {
                continue;
            }
            if let Some(kind) = osm.ways.get(&way).and_then(|w| marking_kind(&w.tags)) {
                map.markings.push(Marking {
                    road: road_id(i),
                    kind,
                    line: line.clone(),
                });
            }
        }
    }
}

/// Lanelet2 line types to marking kinds: dashed lines between lanes, double or yellow lines
/// between directions, other solid lines at the edge.
fn marking_kind(tags: &Tags) -> Option<MarkingKind> {
    if !tags.is_any("type", &["line_thin", "line_thick"]) {
        return None;
    }
    let subtype = tags.get("subtype").unwrap_or("solid");
    Some(if subtype == "dashed" {
        MarkingKind::Dashed
    } else if subtype == "solid_solid" || tags.is("color", "yellow") {
        MarkingKind::CentreLine
    } else {
        MarkingKind::SolidEdge
    })
}

// ---------------------------------------------------------------------------------------------
// Connections

fn add_connections(map: &mut Map, joints: &Joints) {
    let mut next = 0u32;
    for (j, joint) in joints.list.iter().enumerate() {
        for &a in &joint.ins {
            for &b in &joint.outs {
                let (Some(from), Some(to)) =
                    (map.lanes.get(&lane_id(a)), map.lanes.get(&lane_id(b)))
                else {
                    continue;
                };
                let (start, end) = (last(&from.centre), first(&to.centre));
                let connection = Connection {
                    id: ConnectionId(next),
                    junction: JunctionId(j as u32),
                    from: from.id,
                    to: to.id,
                    turn: classify_turn(&from.centre, &to.centre),
                    centre: vec![start, end],
                    length_m: start.distance(end),
                };
                map.connections.insert(connection.id, connection);
                next += 1;
            }
        }
    }
}

/// Heading change from the end of `from` to the first [`TURN_LOOKAHEAD_M`] of `to`.
fn classify_turn(from: &[Point], to: &[Point]) -> Turn {
    let a = direction_at(from, polyline_length(from));
    let b = point_at(to, TURN_LOOKAHEAD_M.min(polyline_length(to)))
        .sub(first(to))
        .normalized();
    let delta = a.cross(b).atan2(a.dot(b)).to_degrees();
    if delta.abs() < STRAIGHT_LIMIT_DEG {
        Turn::Straight
    } else if delta.abs() > U_TURN_LIMIT_DEG {
        Turn::UTurn
    } else if delta > 0.0 {
        Turn::Left
    } else {
        Turn::Right
    }
}

// ---------------------------------------------------------------------------------------------
// Stop lines

/// A stop line being assembled from every element (or the bare `stop_line` way) naming it.
#[derive(Debug, Clone)]
struct StopLineDraft {
    kind: StopKind,
    lanes: BTreeSet<usize>,
}

impl StopLineDraft {
    /// A stop sign anywhere on the line makes it a stop line.
    fn merge(&mut self, kind: StopKind, lanes: impl IntoIterator<Item = usize>) {
        if kind == StopKind::Stop {
            self.kind = StopKind::Stop;
        }
        self.lanes.extend(lanes);
    }
}

/// Projected line geometry of ways, read once each; `None` when unusable (recorded once).
#[derive(Debug)]
struct LineCache<'a> {
    osm: &'a OsmData,
    projector: &'a Projector,
    lines: BTreeMap<i64, Option<Vec<Point>>>,
}

impl LineCache<'_> {
    fn get(&mut self, way_id: i64, report: &mut ImportReport) -> Option<Vec<Point>> {
        if let Some(line) = self.lines.get(&way_id) {
            return line.clone();
        }
        let line = self.read(way_id, report);
        self.lines.insert(way_id, line.clone());
        line
    }

    fn read(&self, way_id: i64, report: &mut ImportReport) -> Option<Vec<Point>> {
        let Some(way) = self.osm.ways.get(&way_id) else {
            report
                .notes
                .push(format!("stop line way {way_id} is missing"));
            return None;
        };
        let mut line: Vec<Point> = Vec::with_capacity(way.nodes.len());
        for n in &way.nodes {
            let Some(node) = self.osm.nodes.get(n) else {
                if !report.ways_missing_nodes.contains(&way_id) {
                    report.ways_missing_nodes.push(way_id);
                }
                return None;
            };
            let p = self.projector.project(node.pos);
            if line.last() != Some(&p) {
                line.push(p);
            }
        }
        if line.len() < 2 {
            report.degenerate_ways.push(way_id);
            return None;
        }
        Some(line)
    }
}

fn add_stop_lines(map: &mut Map, osm: &OsmData, lanelets: &[Lanelet], projector: &Projector) {
    let index = relation_index(lanelets);
    let referencing = referencing_lanelets(lanelets);
    let mut cache = LineCache {
        osm,
        projector,
        lines: BTreeMap::new(),
    };
    let mut drafts: BTreeMap<i64, StopLineDraft> = BTreeMap::new();
    for (&id, rel) in &osm.relations {
        if !rel.tags.is("type", "regulatory_element") {
            continue;
        }
        let Some(kind) = element_stop_kind(osm, rel) else {
            continue;
        };
        let lanes =
            controlled_lanelets(rel, referencing.get(&id).map_or(&[], Vec::as_slice), &index);
        let mut lines = Vec::new();
        for way in element_line_ways(osm, rel) {
            if let Some(line) = cache.get(way, &mut map.report) {
                lines.push((way, line));
            }
        }
        if lines.is_empty() || lanes.is_empty() {
            map.report.notes.push(format!(
                "regulatory element {id}: no usable ref_line or no lanelet yielding to it"
            ));
            continue;
        }
        for (way, assigned) in assign_lanes_to_lines(map, &lines, &lanes) {
            drafts
                .entry(way)
                .or_insert_with(|| StopLineDraft {
                    kind,
                    lanes: BTreeSet::new(),
                })
                .merge(kind, assigned);
        }
    }
    for (&way, w) in &osm.ways {
        if !w.tags.is("type", "stop_line") || drafts.contains_key(&way) {
            continue;
        }
        let Some(line) = cache.get(way, &mut map.report) else {
            continue;
        };
        let lanes = lanes_ending_at(map, &line);
        if lanes.is_empty() {
            map.report
                .notes
                .push(format!("stop line way {way} is near no lanelet end"));
            continue;
        }
        drafts.insert(
            way,
            StopLineDraft {
                kind: StopKind::Stop,
                lanes,
            },
        );
    }
    let mut next = 0u32;
    for (way, draft) in drafts {
        let Some(line) = cache.get(way, &mut map.report) else {
            continue;
        };
        if let Some(stop_line) = place_stop_line(map, StopLineId(next), way, line, &draft) {
            map.stop_lines.insert(stop_line.id, stop_line);
            next += 1;
        }
    }
}

/// Lanelet relation id to lanelet index.
fn relation_index(lanelets: &[Lanelet]) -> BTreeMap<i64, usize> {
    lanelets
        .iter()
        .enumerate()
        .map(|(i, l)| (l.relation_id, i))
        .collect()
}

/// Regulatory element id to the lanelets that reference it.
fn referencing_lanelets(lanelets: &[Lanelet]) -> BTreeMap<i64, Vec<usize>> {
    let mut out: BTreeMap<i64, Vec<usize>> = BTreeMap::new();
    for (i, l) in lanelets.iter().enumerate() {
        for &e in &l.regulatory_elements {
            out.entry(e).or_default().push(i);
        }
    }
    out
}

/// Whether ways of an element are traffic signs or lights rather than lines. Decided by the
/// way's type, not by the member role, because maps swap `ref_line` and `refers`
/// (DR_DEU_Roundabout_OF does).
fn is_sign_way(osm: &OsmData, way: i64) -> bool {
    osm.ways
        .get(&way)
        .is_some_and(|w| w.tags.is_any("type", &["traffic_sign", "traffic_light"]))
}

fn element_line_ways(osm: &OsmData, rel: &OsmRelation) -> Vec<i64> {
    let mut out: Vec<i64> = Vec::new();
    for m in &rel.members {
        if m.kind == MemberKind::Way
            && (m.role == "ref_line" || m.role == "refers")
            && !is_sign_way(osm, m.id)
            && !out.contains(&m.id)
        {
            out.push(m.id);
        }
    }
    out
}

/// The sign codes (`usR1-1`, `de205`, ...) of an element's traffic sign ways.
fn element_sign_codes<'a>(osm: &'a OsmData, rel: &OsmRelation) -> Vec<&'a str> {
    rel.members
        .iter()
        .filter(|m| m.kind == MemberKind::Way && is_sign_way(osm, m.id))
        .filter_map(|m| osm.ways.get(&m.id))
        .filter_map(|w| w.tags.get("subtype").or_else(|| w.tags.get("sign_type")))
        .collect()
}

fn is_stop_sign(code: &str) -> bool {
    let c = code.to_ascii_lowercase();
    let c = c.strip_prefix("us").unwrap_or(&c);
    c == "r1-1" || c == "de206" || c.contains("stop")
}

fn is_yield_sign(code: &str) -> bool {
    let c = code.to_ascii_lowercase();
    let c = c.strip_prefix("us").unwrap_or(&c);
    c == "r1-2" || c == "de205" || c.contains("yield") || c.contains("give_way")
}

/// What an element asks of the lanelets that yield to it: `all_way_stop` stops, a
/// `right_of_way` gives way unless a stop sign goes with it, a `traffic_sign` only counts
/// for stop and yield signs.
fn element_stop_kind(osm: &OsmData, rel: &OsmRelation) -> Option<StopKind> {
    let codes = element_sign_codes(osm, rel);
    let stop = codes.iter().any(|c| is_stop_sign(c));
    match rel.tags.get("subtype")? {
        "all_way_stop" => Some(StopKind::Stop),
        "right_of_way" => Some(if stop {
            StopKind::Stop
        } else {
            StopKind::GiveWay
        }),
        "traffic_sign" if stop => Some(StopKind::Stop),
        "traffic_sign" if codes.iter().any(|c| is_yield_sign(c)) => Some(StopKind::GiveWay),
        _ => None,
    }
}

/// The `yield` members, or else the referencing lanelets that are not `right_of_way` members.
fn controlled_lanelets(
    rel: &OsmRelation,
    referencing: &[usize],
    index: &BTreeMap<i64, usize>,
) -> Vec<usize> {
    let members = |role: &str| -> BTreeSet<usize> {
        rel.members
            .iter()
            .filter(|m| m.kind == MemberKind::Relation && m.role == role)
            .filter_map(|m| index.get(&m.id).copied())
            .collect()
    };
    let yields = members("yield");
    if !yields.is_empty() {
        return yields.into_iter().collect();
    }
    let priority = members("right_of_way");
    referencing
        .iter()
        .copied()
        .filter(|l| !priority.contains(l))
        .collect()
}

/// With several lines in one element (an all-way stop), each lane stops at the line whose
/// midpoint lies nearest its centre line.
fn assign_lanes_to_lines(
    map: &Map,
    lines: &[(i64, Vec<Point>)],
    lanes: &[usize],
) -> Vec<(i64, Vec<usize>)> {
    let mut out: Vec<(i64, Vec<usize>)> = lines.iter().map(|(w, _)| (*w, Vec::new())).collect();
    for &i in lanes {
        let Some(lane) = map.lanes.get(&lane_id(i)) else {
            continue;
        };
        let distance = |line: &[Point]| project_onto_polyline(&lane.centre, midpoint(line)).1;
        let nearest = lines
            .iter()
            .enumerate()
            .min_by(|(_, a), (_, b)| {
                distance(&a.1)
                    .total_cmp(&distance(&b.1))
                    .then(a.0.cmp(&b.0))
            })
            .map(|(k, _)| k);
        if let Some(k) = nearest {
            out[k].1.push(i);
        }
    }
    out.retain(|(_, l)| !l.is_empty());
    out
}

fn midpoint(line: &[Point]) -> Point {
    point_at(line, polyline_length(line) / 2.0)
}

/// Lanes whose centre ends on the line, or else the one ending nearest it.
fn lanes_ending_at(map: &Map, line: &[Point]) -> BTreeSet<usize> {
    let ends: Vec<(usize, f64)> = map
        .lanes
        .values()
        .map(|l| {
            (
                lanelet_index(l.id),
                project_onto_polyline(line, last(&l.centre)).1,
            )
        })
        .collect();
    let at_end: BTreeSet<usize> = ends
        .iter()
        .filter(|(_, d)| *d <= STOP_LINE_AT_END_M)
        .map(|(i, _)| *i)
        .collect();
    if !at_end.is_empty() {
        return at_end;
    }
    ends.iter()
        .filter(|(_, d)| *d <= STOP_LINE_NEAREST_END_MAX_M)
        .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
        .map(|(i, _)| *i)
        .into_iter()
        .collect()
}

/// The stop line with its lanes ordered by how close the line's midpoint is to each lane's
/// centre (the lane it stands on first) and its position along that first lane.
fn place_stop_line(
    map: &Map,
    id: StopLineId,
    way: i64,
    line: Vec<Point>,
    draft: &StopLineDraft,
) -> Option<StopLine> {
    let mid = midpoint(&line);
    let mut lanes: Vec<(f64, f64, LaneId)> = draft
        .lanes
        .iter()
        .filter_map(|&i| map.lanes.get(&lane_id(i)))
        .map(|l| {
            let (s, d) = project_onto_polyline(&l.centre, mid);
            (d, s, l.id)
        })
        .collect();
    lanes.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.2.cmp(&b.2)));
    let &(_, s_on_lane_m, _) = lanes.first()?;
    Some(StopLine {
        id,
        kind: draft.kind,
        source: StopLineSource::LaneletWay { id: way },
        lanes: lanes.iter().map(|x| x.2).collect(),
        line,
        s_on_lane_m,
    })
}

// ---------------------------------------------------------------------------------------------
// Roundabouts

/// A `right_of_way` element: the lanelets with priority and those that yield to them.
#[derive(Debug, Clone)]
struct RightOfWay {
    priority: Vec<usize>,
    yields: Vec<usize>,
}

fn right_of_way_elements(osm: &OsmData, index: &BTreeMap<i64, usize>) -> Vec<RightOfWay> {
    let members = |rel: &OsmRelation, role: &str| -> Vec<usize> {
        let set: BTreeSet<usize> = rel
            .members
            .iter()
            .filter(|m| m.kind == MemberKind::Relation && m.role == role)
            .filter_map(|m| index.get(&m.id).copied())
            .collect();
        set.into_iter().collect()
    };
    osm.relations
        .values()
        .filter(|r| r.tags.is("type", "regulatory_element") && r.tags.is("subtype", "right_of_way"))
        .map(|r| RightOfWay {
            priority: members(r, "right_of_way"),
            yields: members(r, "yield"),
        })
        .collect()
}

/// The successor graph of the lanelets with lane lengths (integer millimetres, so that
/// shortest paths have no floating-point ties to break).
#[derive(Debug)]
struct LaneletGraph<'a> {
    joints: &'a Joints,
    cost_mm: Vec<u64>,
}

impl LaneletGraph<'_> {
    /// Shortest path (by lane length) from the successors of `from` to the first lanelet
    /// satisfying `is_target`, through lanelets in `allowed` and not in `avoid` (a target may
    /// be in `avoid`). The path leaves out `from` and ends with the target.
    fn shortest_path(
        &self,
        from: usize,
        allowed: &BTreeSet<usize>,
        avoid: &BTreeSet<usize>,
        is_target: impl Fn(usize) -> bool,
    ) -> Option<Vec<usize>> {
        let enterable = |n: usize| allowed.contains(&n) && (is_target(n) || !avoid.contains(&n));
        let mut best: BTreeMap<usize, u64> = BTreeMap::new();
        let mut prev: BTreeMap<usize, usize> = BTreeMap::new();
        let mut heap = BinaryHeap::new();
        for &s in self.joints.successors(from) {
            if enterable(s) && best.get(&s).is_none_or(|&b| self.cost_mm[s] < b) {
                best.insert(s, self.cost_mm[s]);
                heap.push(Reverse((self.cost_mm[s], s)));
            }
        }
        while let Some(Reverse((cost, node))) = heap.pop() {
            if best.get(&node).is_some_and(|&b| cost > b) {
                continue;
            }
            if is_target(node) {
                return Some(unwind(node, &prev));
            }
            for &s in self.joints.successors(node) {
                let c = cost + self.cost_mm[s];
                if enterable(s) && best.get(&s).is_none_or(|&b| c < b) {
                    best.insert(s, c);
                    prev.insert(s, node);
                    heap.push(Reverse((c, s)));
                }
            }
        }
        None
    }

    /// A directed cycle through `start` that visits as many of `targets` (the circulating
    /// lanelets of its component) as it can: from each visited target, the shortest way on
    /// to the nearest unvisited one, then back to `start`. The tour may be at most
    /// [`RING_TOUR_SLACK`] times as long as the shortest cycle through `start` (the ring
    /// itself), so that it cannot run off to another roundabout that two-way roads put in
    /// the same component. Falls back to that shortest cycle if the tour cannot close.
    fn ring_through(
        &self,
        start: usize,
        component: &BTreeSet<usize>,
        targets: &BTreeSet<usize>,
    ) -> Option<Vec<usize>> {
        let mut shortest =
            self.shortest_path(start, component, &BTreeSet::from([start]), |l| l == start)?;
        shortest.pop();
        shortest.insert(0, start);
        let budget = (self.cost(&shortest) as f64 * RING_TOUR_SLACK) as u64;
        let mut ring = vec![start];
        let mut on_ring: BTreeSet<usize> = BTreeSet::from([start]);
        while let Some(path) = self.shortest_path(*ring.last()?, component, &on_ring, |l| {
            targets.contains(&l) && !on_ring.contains(&l)
        }) {
            if self.cost(&ring) + self.cost(&path) > budget {
                break;
            }
            on_ring.extend(path.iter().copied());
            ring.extend(path);
        }
        let back = self.shortest_path(*ring.last()?, component, &on_ring, |l| l == start);
        match back {
            Some(mut back) => {
                back.pop();
                ring.extend(back);
                Some(if self.cost(&ring) <= budget {
                    ring
                } else {
                    shortest
                })
            }
            None => Some(shortest),
        }
    }

    fn cost(&self, lanelets: &[usize]) -> u64 {
        lanelets.iter().map(|&l| self.cost_mm[l]).sum()
    }
}

/// The path to `node` following `prev` back to a first-level lanelet (which has no `prev`).
fn unwind(node: usize, prev: &BTreeMap<usize, usize>) -> Vec<usize> {
    let mut path = vec![node];
    let mut current = node;
    while let Some(&p) = prev.get(&current) {
        path.push(p);
        current = p;
    }
    path.reverse();
    path
}

/// Where a ring lies: centre and radius from its lanes' centre points, their farthest
/// distance from the centre, and its sense of rotation.
#[derive(Debug, Clone, Copy)]
struct RingShape {
    centre: Point,
    radius: f64,
    extent: f64,
    clockwise: bool,
}

fn ring_shape(map: &Map, ring: &[usize]) -> RingShape {
    let pts: Vec<Point> = ring
        .iter()
        .filter_map(|&i| map.lanes.get(&lane_id(i)))
        .flat_map(|l| l.centre.iter().copied())
        .collect();
    let n = pts.len().max(1) as f64;
    let centre = pts
        .iter()
        .fold(Point::default(), |acc, p| acc.add(*p))
        .scale(1.0 / n);
    let radius = pts.iter().map(|p| p.distance(centre)).sum::<f64>() / n;
    let extent = pts.iter().map(|p| p.distance(centre)).fold(0.0, f64::max);
    RingShape {
        centre,
        radius,
        extent,
        clockwise: signed_area(&pts) < 0.0,
    }
}

/// Groups concentric rings (the lanes of a multi-lane roundabout), in order of first ring.
fn group_concentric(shapes: &[RingShape]) -> Vec<Vec<usize>> {
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (k, s) in shapes.iter().enumerate() {
        let concentric = |m: &usize| {
            let o = &shapes[*m];
            s.centre.distance(o.centre) < CONCENTRIC_FRACTION * s.radius.max(o.radius)
        };
        match groups.iter_mut().find(|g| g.iter().any(concentric)) {
            Some(g) => g.push(k),
            None => groups.push(vec![k]),
        }
    }
    groups
}

fn add_roundabouts(map: &mut Map, osm: &OsmData, lanelets: &[Lanelet], joints: &Joints) {
    let elements = right_of_way_elements(osm, &relation_index(lanelets));
    let circulating: BTreeSet<usize> = elements
        .iter()
        .flat_map(|e| e.priority.iter().copied())
        .collect();
    if circulating.is_empty() {
        return;
    }
    let components: Vec<BTreeSet<usize>> = strongly_connected_components(map, false)
        .into_iter()
        .map(|c| c.into_iter().map(lanelet_index).collect())
        .collect();
    let lane_component = component_of(
        &components
            .iter()
            .map(|c| c.iter().map(|&i| lane_id(i)).collect::<Vec<_>>())
            .collect::<Vec<_>>(),
    );
    let component = |i: usize| {
        lane_component
            .get(&lane_id(i))
            .and_then(|&k| components.get(k))
    };
    let graph = LaneletGraph {
        joints,
        cost_mm: (0..lanelets.len())
            .map(|i| {
                map.lanes
                    .get(&lane_id(i))
                    .map_or(1, |l| ((l.length_m * 1000.0).round() as u64).max(1))
            })
            .collect(),
    };

    let mut rings: Vec<Vec<usize>> = Vec::new();
    let mut covered: BTreeSet<usize> = BTreeSet::new();
    for &c in &circulating {
        if covered.contains(&c) {
            continue;
        }
        let Some(comp) = component(c) else { continue };
        let targets: BTreeSet<usize> = circulating.intersection(comp).copied().collect();
        match graph.ring_through(c, comp, &targets) {
            Some(ring) => {
                covered.extend(ring.iter().copied());
                rings.push(ring);
            }
            None => {
                covered.insert(c);
                let relation = lanelets[c].relation_id;
                map.report.notes.push(format!(
                    "circulating lanelet {relation} lies on no directed cycle"
                ));
            }
        }
    }

    let shapes: Vec<RingShape> = rings.iter().map(|r| ring_shape(map, r)).collect();
    for group in group_concentric(&shapes) {
        let id = RoundaboutId(map.roundabouts.len() as u32);
        let group_rings: Vec<(&Vec<usize>, RingShape)> =
            group.iter().map(|&k| (&rings[k], shapes[k])).collect();
        if let Some(roundabout) =
            build_roundabout(map, id, &group_rings, &elements, joints, &component)
        {
            map.roundabouts.insert(id, roundabout);
        }
    }
}

/// One roundabout from its concentric rings: the outermost ring is the circulating lane
/// cycle; entries are the lanelets yielding to any ring lanelet, exits the lanelets leaving
/// the ring area.
fn build_roundabout<'a>(
    map: &mut Map,
    id: RoundaboutId,
    rings: &[(&Vec<usize>, RingShape)],
    elements: &[RightOfWay],
    joints: &Joints,
    component: &impl Fn(usize) -> Option<&'a BTreeSet<usize>>,
) -> Option<Roundabout> {
    let (primary, shape) = rings
        .iter()
        .copied()
        .reduce(|a, b| if b.1.radius > a.1.radius { b } else { a })?;
    let yielding: BTreeSet<usize> = elements
        .iter()
        .flat_map(|e| e.yields.iter().copied())
        .collect();
    let ring = ring_lanelets(map, rings, shape, joints, component, &yielding);

    let entry_lanelets: BTreeSet<usize> = elements
        .iter()
        .filter(|e| e.priority.iter().any(|p| ring.contains(p)))
        .flat_map(|e| e.yields.iter().copied())
        .filter(|y| !ring.contains(y))
        .collect();
    let mut reached = BTreeSet::new();
    let entries: Vec<RoundaboutArm> = entry_lanelets
        .iter()
        .map(|&y| {
            let (junction, path) = meeting_joint(map, y, &ring, joints);
            reached.extend(path);
            RoundaboutArm {
                road: road_id(y),
                lanes: vec![lane_id(y)],
                junction: JunctionId(junction as u32),
            }
        })
        .collect();
    let exits: Vec<RoundaboutArm> = (0..joints.start_of.len())
        .filter(|i| {
            !ring.contains(i)
                && joints.list[joints.start_of[*i]]
                    .ins
                    .iter()
                    .any(|l| ring.contains(l))
        })
        .map(|i| RoundaboutArm {
            road: road_id(i),
            lanes: vec![lane_id(i)],
            junction: JunctionId(joints.start_of[i] as u32),
        })
        .collect();
    note_unregulated_entries(map, id, &ring, &reached, joints);

    let entry_lanes: BTreeSet<LaneId> = entry_lanelets.iter().map(|&i| lane_id(i)).collect();
    let yield_lines: Vec<StopLineId> = map
        .stop_lines
        .values()
        .filter(|s| s.lanes.iter().any(|l| entry_lanes.contains(l)))
        .map(|s| s.id)
        .collect();
    let mut osm_way_ids = BTreeSet::new();
    for &i in &ring {
        if let Some(road) = map.roads.get_mut(&road_id(i)) {
            road.is_roundabout = true;
            osm_way_ids.extend(road.osm_way_ids.iter().copied());
        }
    }
    Some(Roundabout {
        id,
        source: RoundaboutSource::Lanelet2,
        kind: RoundaboutKind::Roundabout,
        // Lanelet2 roundabouts are found from their `right_of_way` elements, which say
        // that the ring has priority.
        priority: RoundaboutPriority::Circulating,
        priority_source: PrioritySource::Tags,
        osm_way_ids: osm_way_ids.into_iter().collect(),
        osm_node_id: None,
        roads: ring.iter().map(|&i| road_id(i)).collect(),
        circulating_lanes: primary.iter().map(|&i| lane_id(i)).collect(),
        ring_lanes: ring.iter().map(|&i| lane_id(i)).collect(),
        // Each lanelet is one lane, so side by side means one lanelet per concentric ring.
        lanes_across: u8::try_from(rings.len()).unwrap_or(u8::MAX),
        entries,
        exits,
        yield_lines,
        centre: shape.centre,
        radius_m: shape.radius,
        clockwise: shape.clockwise,
    })
}

/// The lanelets of the ring area: the rings themselves, the other lanelets of their strongly
/// connected components, and the connectors that leave a ring lanelet and join one again
/// (lane changes between the rings of a multi-lane roundabout). A lanelet only joining the
/// ring (the end of an entry) or only leaving it (the start of an exit) is not ring. Nothing
/// beyond the outermost ring counts, so that roundabouts joined by two-way roads (one
/// component) stay apart; yield lanelets are entries, never ring.
fn ring_lanelets<'a>(
    map: &Map,
    rings: &[(&Vec<usize>, RingShape)],
    outer: RingShape,
    joints: &Joints,
    component: &impl Fn(usize) -> Option<&'a BTreeSet<usize>>,
    yielding: &BTreeSet<usize>,
) -> BTreeSet<usize> {
    let limit = outer.extent + RING_MARGIN_M;
    let inside = |i: usize| {
        !yielding.contains(&i)
            && map
                .lanes
                .get(&lane_id(i))
                .is_some_and(|l| l.centre.iter().all(|p| p.distance(outer.centre) <= limit))
    };
    let mut core: BTreeSet<usize> = rings.iter().flat_map(|(r, _)| r.iter().copied()).collect();
    let components: BTreeSet<usize> = core
        .iter()
        .filter_map(|&i| component(i))
        .flatten()
        .copied()
        .collect();
    core.extend(components.into_iter().filter(|&i| inside(i)));
    let connectors: Vec<usize> = (0..joints.start_of.len())
        .filter(|i| !core.contains(i) && inside(*i))
        .filter(|&i| {
            let (from, to) = (
                &joints.list[joints.start_of[i]],
                &joints.list[joints.end_of[i]],
            );
            from.ins.iter().any(|l| core.contains(l)) && to.outs.iter().any(|l| core.contains(l))
        })
        .collect();
    core.extend(connectors);
    core
}

/// The joint where an entry meets the ring: following successors from its yield lanelet
/// (breadth first, up to [`ENTRY_SEARCH_DEPTH`] lanelets) to the first joint a ring
/// lanelet starts at; for a map whose entry does not join the ring by shared nodes, the
/// ring joint nearest the entry's end. Also returns the lanelets walked through.
fn meeting_joint(
    map: &Map,
    entry: usize,
    ring: &BTreeSet<usize>,
    joints: &Joints,
) -> (usize, Vec<usize>) {
    let mut queue = VecDeque::from([(entry, 0usize)]);
    let mut seen = vec![entry];
    while let Some((l, depth)) = queue.pop_front() {
        let joint = joints.end_of[l];
        if joints.list[joint].outs.iter().any(|o| ring.contains(o)) {
            return (joint, seen);
        }
        for &o in &joints.list[joint].outs {
            if depth + 1 < ENTRY_SEARCH_DEPTH && !ring.contains(&o) && !seen.contains(&o) {
                seen.push(o);
                queue.push_back((o, depth + 1));
            }
        }
    }
    let end = map
        .lanes
        .get(&lane_id(entry))
        .map_or_else(Point::default, |l| last(&l.centre));
    let nearest = joints
        .list
        .iter()
        .enumerate()
        .filter(|(_, j)| j.outs.iter().any(|o| ring.contains(o)))
        .min_by(|a, b| {
            let d = |j: &Joint| j.left.lerp(j.right, 0.5).distance(end);
            d(a.1).total_cmp(&d(b.1)).then(a.0.cmp(&b.0))
        })
        .map_or(joints.end_of[entry], |(k, _)| k);
    (nearest, seen)
}

/// Records the lanelets that join the ring without any yield lanelet leading to them: they
/// enter without a right-of-way element, so they have no entry or yield line.
fn note_unregulated_entries(
    map: &mut Map,
    id: RoundaboutId,
    ring: &BTreeSet<usize>,
    reached: &BTreeSet<usize>,
    joints: &Joints,
) {
    let unregulated: Vec<String> = (0..joints.end_of.len())
        .filter(|i| !ring.contains(i) && !reached.contains(i))
        .filter(|&i| joints.successors(i).iter().any(|o| ring.contains(o)))
        .filter_map(|i| map.roads.get(&road_id(i)))
        .filter_map(|r| match r.source {
            RoadSource::Lanelet { relation_id } => Some(relation_id.to_string()),
            RoadSource::OsmWay => None,
        })
        .collect();
    if !unregulated.is_empty() {
        map.report.notes.push(format!(
            "roundabout {id}: lanelets {} join the ring without a right_of_way element (no entry arm or yield line)",
            unregulated.join(", ")
        ));
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::print_stderr)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::osm::{parse_xml, read_xml};

    /// The INTERACTION maps folder, or None (with a notice) where the shared data is absent.
    /// The files are licensed for tests only: they are read in place, never copied.
    fn interaction_maps() -> Option<PathBuf> {
        let dir = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"))
            .join("trajectories/interaction/maps");
        if dir.is_dir() {
            Some(dir)
        } else {
            eprintln!(
                "skipped: {}: {} not found",
                std::thread::current().name().unwrap_or("-"),
                dir.display()
            );
            None
        }
    }

    fn import(dir: &std::path::Path, name: &str) -> (OsmData, Map) {
        let osm = read_xml(&dir.join(format!("{name}.osm"))).unwrap();
        let map = build_lanelet2_map(&osm, &ImportOptions::default()).unwrap();
        (osm, map)
    }

    /// Per map: entries, exits and yield lines of its one roundabout, and its lanes side by
    /// side. Entries are the distinct `yield` members of `right_of_way` elements (FT 7, EP 7,
    /// SR 4, LN 6, OF 3 in the files); exits were counted independently from the lanelets
    /// that start where a ring lanelet ends. EP and LN have ref_lines across two entry lanes.
    const EXPECTED_ROUNDABOUTS: [(&str, usize, usize, usize, u8); 5] = [
        ("DR_USA_Roundabout_FT", 7, 6, 7, 1),
        ("DR_USA_Roundabout_EP", 7, 4, 4, 1),
        ("DR_USA_Roundabout_SR", 4, 4, 4, 1),
        ("DR_CHN_Roundabout_LN", 6, 9, 7, 3),
        ("DR_DEU_Roundabout_OF", 3, 3, 3, 1),
    ];

    #[test]
    fn all_interaction_maps_import_and_pass_invariants() {
        let Some(dir) = interaction_maps() else {
            return;
        };
        for (name, entries, exits, yield_lines, across) in EXPECTED_ROUNDABOUTS {
            let (osm, map) = import(&dir, name);
            check_invariants(&map, "test").unwrap();
            let lanelets = osm
                .relations
                .values()
                .filter(|r| r.tags.is("type", "lanelet"))
                .count();
            assert_eq!(map.roads.len(), lanelets, "{name}: every lanelet is a road");
            assert_eq!(map.lanes.len(), lanelets, "{name}");
            assert!(
                map.report.notes.is_empty(),
                "{name}: {:?}",
                map.report.notes
            );
            assert!(
                map.roads
                    .values()
                    .all(|r| r.highway == "lanelet" && r.allows_cars),
                "{name}"
            );
            // FT's circulatory roadway is one lanelet up to 18 m wide; entries flare to 10 m.
            assert!(
                map.lanes
                    .values()
                    .all(|l| l.width_m > 1.5 && l.width_m < 20.0),
                "{name}"
            );
            assert_eq!(map.roundabouts.len(), 1, "{name}");
            let r = &map.roundabouts[&RoundaboutId(0)];
            let found = (
                r.entries.len(),
                r.exits.len(),
                r.yield_lines.len(),
                r.lanes_across,
            );
            assert_eq!(found, (entries, exits, yield_lines, across), "{name}");
            assert!(
                r.radius_m > 5.0 && r.radius_m < 60.0,
                "{name}: radius {}",
                r.radius_m
            );
            // Right-hand traffic everywhere here: counter-clockwise rings.
            assert!(!r.clockwise, "{name}");
            eprintln!(
                "{name}: roads {} lanes {} junctions {} connections {} stop lines {}; roundabout: \
                 {} circulating lanes ({} ring lanes, {} across), r {:.1} m, entries {}, exits {}, \
                 yield lines {}",
                map.roads.len(),
                map.lanes.len(),
                map.junctions.len(),
                map.connections.len(),
                map.stop_lines.len(),
                r.circulating_lanes.len(),
                r.ring_lanes.len(),
                r.lanes_across,
                r.radius_m,
                r.entries.len(),
                r.exits.len(),
                r.yield_lines.len(),
            );
        }
    }

    #[test]
    fn ft_roundabout_has_its_entries_exits_and_yield_lines() {
        let Some(dir) = interaction_maps() else {
            return;
        };
        let (_, map) = import(&dir, "DR_USA_Roundabout_FT");
        assert_eq!(map.roads.len(), 48);
        assert_eq!(map.roundabouts.len(), 1);
        let r = &map.roundabouts[&RoundaboutId(0)];
        assert_eq!(r.source, RoundaboutSource::Lanelet2);
        assert!(
            r.entries.len() >= 3 && r.exits.len() >= 3,
            "entries {} exits {}",
            r.entries.len(),
            r.exits.len()
        );
        // FT: 7 right_of_way elements, 7 distinct yield lanelets, each with its own ref_line.
        let yield_entries: BTreeSet<RoadId> = r.entries.iter().map(|a| a.road).collect();
        assert_eq!(yield_entries.len(), 7);
        assert_eq!(r.yield_lines.len(), yield_entries.len());
        // 5 of the 7 signs are US stop signs (R1-1), 2 yield signs (R1-2).
        let kinds: Vec<StopKind> = r
            .yield_lines
            .iter()
            .map(|s| map.stop_lines[s].kind)
            .collect();
        assert_eq!(kinds.iter().filter(|k| **k == StopKind::Stop).count(), 5);
        assert_eq!(kinds.iter().filter(|k| **k == StopKind::GiveWay).count(), 2);
        // The six priority lanelets all lie on the ring.
        let ring: BTreeSet<LaneId> = r.circulating_lanes.iter().copied().collect();
        for rel in [30002, 30020, 30028, 30039, 30042, 30043] {
            let lane = map
                .roads
                .values()
                .find(|road| road.source == RoadSource::Lanelet { relation_id: rel })
                .unwrap();
            assert!(
                ring.contains(&lane.lanes_forward[0]),
                "lanelet {rel} not on the ring"
            );
        }
        // Right-hand traffic goes round counter-clockwise.
        assert!(!r.clockwise);
        assert!(
            map.lanes
                .values()
                .all(|l| (l.speed_limit_kmh - 25.0 * 1.609_344).abs() < 1e-9)
        );
    }

    #[test]
    fn ft_projection_matches_the_xy_ground_truth() {
        let Some(dir) = interaction_maps() else {
            return;
        };
        let osm = read_xml(&dir.join("DR_USA_Roundabout_FT.osm")).unwrap();
        let xy = std::fs::read_to_string(dir.join("DR_USA_Roundabout_FT.osm_xy")).unwrap();
        let projector = Projection::utm(LatLon::new(0.0, 0.0)).projector();
        let attr = |line: &str, key: &str| -> Option<String> {
            let start = line.find(&format!(" {key}=\""))? + key.len() + 3;
            let len = line[start..].find('"')?;
            Some(line[start..start + len].to_owned())
        };
        let (mut compared, mut max_error) = (0usize, 0.0f64);
        for line in xy.lines().filter(|l| l.trim_start().starts_with("<node ")) {
            let id: i64 = attr(line, "id").unwrap().parse().unwrap();
            let x: f64 = attr(line, "x").unwrap().parse().unwrap();
            let y: f64 = attr(line, "y").unwrap().parse().unwrap();
            let p = projector.project(osm.nodes[&id].pos);
            max_error = max_error.max(p.distance(Point::new(x, y)));
            compared += 1;
        }
        assert_eq!(compared, osm.nodes.len());
        assert_eq!(compared, 749);
        assert!(max_error < 0.01, "max error {max_error} m");
        eprintln!("FT projection: {compared} nodes, max error {max_error:.2e} m");
    }

    /// Two lanelets one after the other (the second with its right bound drawn backwards),
    /// a yield sign, and a 30 mph limit. Points about 10 m apart near (0, 0).
    const TWO_LANELETS: &str = r#"<?xml version="1.0"?>
<osm version="0.6" generator="test">
  <node id="1" lat="0.0000" lon="0.0000"/>
  <node id="2" lat="0.0000" lon="0.0001"/>
  <node id="3" lat="0.0000" lon="0.0002"/>
  <node id="4" lat="-0.00003" lon="0.0000"/>
  <node id="5" lat="-0.00003" lon="0.0001"/>
  <node id="6" lat="-0.00003" lon="0.0002"/>
  <node id="7" lat="-0.00001" lon="0.0001"/>
  <node id="8" lat="-0.00002" lon="0.0001"/>
  <node id="9" lat="-0.00004" lon="0.0001"/>
  <way id="10"><nd ref="1"/><nd ref="2"/><tag k="type" v="line_thin"/><tag k="subtype" v="solid"/></way>
  <way id="11"><nd ref="4"/><nd ref="5"/><tag k="type" v="curbstone"/></way>
  <way id="12"><nd ref="2"/><nd ref="3"/><tag k="type" v="line_thin"/><tag k="subtype" v="dashed"/></way>
  <way id="13"><nd ref="6"/><nd ref="5"/><tag k="type" v="curbstone"/></way>
  <way id="14"><nd ref="7"/><nd ref="8"/><tag k="type" v="stop_line"/></way>
  <way id="15"><nd ref="9"/><tag k="type" v="traffic_sign"/><tag k="subtype" v="usR1-2"/></way>
  <relation id="100">
    <member type="way" ref="10" role="left"/><member type="way" ref="11" role="right"/>
    <member type="relation" ref="200" role="regulatory_element"/>
    <tag k="type" v="lanelet"/><tag k="subtype" v="road"/><tag k="one_way" v="yes"/>
  </relation>
  <relation id="101">
    <member type="way" ref="12" role="left"/><member type="way" ref="13" role="right"/>
    <member type="relation" ref="200" role="regulatory_element"/>
    <tag k="type" v="lanelet"/><tag k="subtype" v="road"/>
  </relation>
  <relation id="102">
    <member type="way" ref="99" role="left"/><member type="way" ref="13" role="right"/>
    <tag k="type" v="lanelet"/>
  </relation>
  <relation id="103">
    <member type="way" ref="10" role="left"/><member type="way" ref="11" role="right"/>
    <tag k="type" v="lanelet"/><tag k="subtype" v="crosswalk"/>
  </relation>
  <relation id="200"><tag k="type" v="regulatory_element"/><tag k="subtype" v="speed_limit"/><tag k="sign_type" v="30mph"/></relation>
  <relation id="201">
    <member type="way" ref="14" role="ref_line"/><member type="way" ref="15" role="refers"/>
    <member type="relation" ref="101" role="right_of_way"/><member type="relation" ref="100" role="yield"/>
    <tag k="type" v="regulatory_element"/><tag k="subtype" v="right_of_way"/>
  </relation>
</osm>"#;

    #[test]
    fn two_consecutive_lanelets_give_one_connection() {
        let osm = parse_xml(TWO_LANELETS.as_bytes()).unwrap();
        let map = build_lanelet2_map(&osm, &ImportOptions::default()).unwrap();
        check_invariants(&map, "test").unwrap();
        assert_eq!(map.roads.len(), 2);
        assert_eq!(map.connections.len(), 1);
        let c = &map.connections[&ConnectionId(0)];
        assert_eq!(
            (c.from, c.to, c.turn),
            (LaneId(0), LaneId(1), Turn::Straight)
        );
        assert!(c.length_m < 1e-9);
        let kinds: Vec<JunctionKind> = map.junctions.values().map(|j| j.kind).collect();
        assert_eq!(
            kinds
                .iter()
                .filter(|k| **k == JunctionKind::Continuation)
                .count(),
            1
        );
        assert_eq!(
            kinds
                .iter()
                .filter(|k| **k == JunctionKind::DeadEnd)
                .count(),
            2
        );
        // The reversed right bound was turned round: both lanes run east, about 3.3 m wide.
        for lane in map.lanes.values() {
            assert!(last(&lane.centre).x > first(&lane.centre).x);
            assert!(last(&lane.right).x > first(&lane.right).x);
            assert!((lane.width_m - 3.32).abs() < 0.05, "width {}", lane.width_m);
            assert!((lane.speed_limit_kmh - 48.28).abs() < 0.01);
        }
        // The yield sign's ref_line is a give-way line on the first lanelet, near its end.
        assert_eq!(map.stop_lines.len(), 1);
        let s = &map.stop_lines[&StopLineId(0)];
        assert_eq!(
            (s.kind, s.lanes.clone()),
            (StopKind::GiveWay, vec![LaneId(0)])
        );
        assert_eq!(s.source, StopLineSource::LaneletWay { id: 14 });
        assert!((s.s_on_lane_m - map.lanes[&LaneId(0)].length_m).abs() < 0.1);
        // The lanelet with a missing way is skipped and recorded; the crosswalk is no road.
        assert!(
            map.report
                .notes
                .iter()
                .any(|n| n.contains("lanelet 102") && n.contains("99"))
        );
        assert!(map.report.notes.iter().any(|n| n.contains("1 pedestrian")));
        // Markings: the solid and the dashed line, not the kerbs.
        let marks: Vec<MarkingKind> = map.markings.iter().map(|m| m.kind).collect();
        assert_eq!(marks, vec![MarkingKind::SolidEdge, MarkingKind::Dashed]);
        assert!(map.roundabouts.is_empty());
    }

    #[test]
    fn a_lanelet_runs_the_way_that_puts_its_left_bound_on_its_left() {
        // Lanelet 100 with its bounds swapped: the southern way is now its left bound, so,
        // as in Lanelet2's loader, both bounds are turned and the lane runs west.
        let xml = TWO_LANELETS.replace(
            r#"<member type="way" ref="10" role="left"/><member type="way" ref="11" role="right"/>
    <member type="relation" ref="200""#,
            r#"<member type="way" ref="11" role="left"/><member type="way" ref="10" role="right"/>
    <member type="relation" ref="200""#,
        );
        let osm = parse_xml(xml.as_bytes()).unwrap();
        let map = build_lanelet2_map(&osm, &ImportOptions::default()).unwrap();
        let west = &map.lanes[&LaneId(0)];
        assert!(last(&west.centre).x < first(&west.centre).x);
        assert!(
            first(&west.left).y < first(&west.right).y,
            "left bound is the southern one"
        );
        assert!(map.connections.is_empty());
    }

    #[test]
    fn bounds_within_five_centimetres_join_without_shared_nodes() {
        // Lanelet 101 repeats nodes 2 and 5 as 20 and 50, 1 cm away.
        let xml = TWO_LANELETS
            .replace(r#"<way id="12"><nd ref="2"/>"#, r#"<way id="12"><nd ref="20"/>"#)
            .replace(r#"<nd ref="6"/><nd ref="5"/>"#, r#"<nd ref="6"/><nd ref="50"/>"#)
            .replace(
                r#"<node id="7""#,
                r#"<node id="20" lat="0.00000009" lon="0.0001"/><node id="50" lat="-0.00003" lon="0.00010009"/><node id="7""#,
            );
        let osm = parse_xml(xml.as_bytes()).unwrap();
        let map = build_lanelet2_map(&osm, &ImportOptions::default()).unwrap();
        assert_eq!(map.connections.len(), 1);
    }

    #[test]
    fn no_usable_lanelet_is_an_error() {
        let xml = TWO_LANELETS
            .replace(r#"<node id="1" "#, r#"<node id="1000" "#)
            .replace(r#"<node id="3" "#, r#"<node id="3000" "#);
        let osm = parse_xml(xml.as_bytes()).unwrap();
        let err = build_lanelet2_map(&osm, &ImportOptions::default()).unwrap_err();
        assert!(err.to_string().contains("no drivable lanelets"), "{err}");
    }

    #[test]
    fn a_bound_with_a_missing_node_skips_its_lanelet_only() {
        let xml = TWO_LANELETS.replace(r#"<node id="3" "#, r#"<node id="3000" "#);
        let osm = parse_xml(xml.as_bytes()).unwrap();
        let map = build_lanelet2_map(&osm, &ImportOptions::default()).unwrap();
        assert_eq!(map.roads.len(), 1);
        assert_eq!(map.report.ways_missing_nodes, vec![12]);
        assert!(map.report.notes.iter().any(|n| n.contains("lanelet 101")));
        check_invariants(&map, "test").unwrap();
    }

    /// A one-lane ring of 8 lanelets (radius 10 to 14 m, counter-clockwise) with one entry
    /// merging at its east point behind a yield line, and one exit leaving at its north point.
    fn ring_xml() -> String {
        let mut xml = String::from(r#"<osm version="0.6" generator="test">"#);
        let mut node = |id: i64, x: f64, y: f64| {
            xml += &format!(
                r#"<node id="{id}" lat="{}" lon="{}"/>"#,
                y / 110_574.0,
                x / 111_320.0
            );
        };
        for k in 0..8 {
            let a = f64::from(k) * std::f64::consts::FRAC_PI_4;
            node(1 + i64::from(k), 10.0 * a.cos(), 10.0 * a.sin());
            node(11 + i64::from(k), 14.0 * a.cos(), 14.0 * a.sin());
        }
        for (id, x, y) in [
            (21, 10.0, -20.0),
            (22, 14.0, -20.0),
            (23, -20.0, 10.0),
            (24, -20.0, 14.0),
        ] {
            node(id, x, y);
        }
        for (id, x, y) in [(25, 10.0, -2.0), (26, 14.0, -2.0), (27, 16.0, -3.0)] {
            node(id, x, y);
        }
        let mut way = |id: i64, nodes: &[i64], kind: &str| {
            let nds: String = nodes
                .iter()
                .map(|n| format!(r#"<nd ref="{n}"/>"#))
                .collect();
            let sign = if kind == "traffic_sign" {
                r#"<tag k="subtype" v="usR1-2"/>"#
            } else {
                ""
            };
            xml += &format!(r#"<way id="{id}">{nds}<tag k="type" v="{kind}"/>{sign}</way>"#);
        };
        for k in 0..8 {
            way(200 + k, &[1 + k, 1 + (k + 1) % 8], "line_thin");
            way(300 + k, &[11 + k, 11 + (k + 1) % 8], "curbstone");
        }
        way(400, &[21, 1], "curbstone");
        way(401, &[22, 11], "curbstone");
        way(402, &[3, 23], "curbstone");
        way(403, &[13, 24], "curbstone");
        way(404, &[25, 26], "virtual");
        way(405, &[27, 27], "traffic_sign");
        let lanelet = |id: i64, left: i64, right: i64, extra: &str| {
            format!(
                r#"<relation id="{id}"><member type="way" ref="{left}" role="left"/><member type="way" ref="{right}" role="right"/>{extra}<tag k="type" v="lanelet"/><tag k="subtype" v="road"/></relation>"#
            )
        };
        for k in 0..8 {
            xml += &lanelet(100 + k, 200 + k, 300 + k, "");
        }
        xml += &lanelet(
            150,
            400,
            401,
            r#"<member type="relation" ref="500" role="regulatory_element"/>"#,
        );
        xml += &lanelet(151, 402, 403, "");
        xml += r#"<relation id="500"><member type="way" ref="404" role="ref_line"/><member type="way" ref="405" role="refers"/><member type="relation" ref="100" role="right_of_way"/><member type="relation" ref="150" role="yield"/><tag k="type" v="regulatory_element"/><tag k="subtype" v="right_of_way"/></relation>"#;
        xml + "</osm>"
    }

    #[test]
    fn a_synthetic_ring_is_one_roundabout_with_its_entry_exit_and_yield_line() {
        let osm = parse_xml(ring_xml().as_bytes()).unwrap();
        let map = build_lanelet2_map(&osm, &ImportOptions::default()).unwrap();
        check_invariants(&map, "test").unwrap();
        assert_eq!(map.roads.len(), 10);
        // 8 round the ring, the entry into it and the ring into the exit.
        assert_eq!(map.connections.len(), 10);
        assert_eq!(map.roundabouts.len(), 1);
        let r = &map.roundabouts[&RoundaboutId(0)];
        let ring: Vec<LaneId> = (0..8).map(LaneId).collect();
        let mut circulating = r.circulating_lanes.clone();
        circulating.sort();
        assert_eq!(circulating, ring);
        assert_eq!((r.entries.len(), r.exits.len(), r.lanes_across), (1, 1, 1));
        assert_eq!((r.entries[0].road, r.exits[0].road), (RoadId(8), RoadId(9)));
        assert_eq!(
            map.junctions[&r.entries[0].junction].kind,
            JunctionKind::Intersection
        );
        assert_eq!(r.yield_lines.len(), 1);
        assert_eq!(map.stop_lines[&r.yield_lines[0]].kind, StopKind::GiveWay);
        assert!(!r.clockwise);
        assert!(
            r.centre.distance(Point::new(0.0, 0.0)) < 1.5,
            "centre {:?}",
            r.centre
        );
        assert!((r.radius_m - 11.5).abs() < 1.0, "radius {}", r.radius_m);
        assert!(map.roads.values().filter(|road| road.is_roundabout).count() == 8);
        assert!(
            map.markings
                .iter()
                .all(|m| m.kind == MarkingKind::SolidEdge)
        );
    }

    #[test]
    fn speed_signs_parse_to_kmh() {
        assert!((parse_speed_kmh("25mph").unwrap() - 40.233_6).abs() < 1e-9);
        assert_eq!(parse_speed_kmh("30kmh"), Some(30.0));
        assert_eq!(parse_speed_kmh("50 km/h"), Some(50.0));
        assert_eq!(parse_speed_kmh("60"), Some(60.0));
        assert_eq!(parse_speed_kmh("fast"), None);
    }

    #[test]
    fn turns_follow_the_heading_change() {
        let east = [Point::new(0.0, 0.0), Point::new(10.0, 0.0)];
        let north = [Point::new(10.0, 0.0), Point::new(10.0, 10.0)];
        let south = [Point::new(10.0, 0.0), Point::new(10.0, -10.0)];
        let west = [Point::new(10.0, 0.0), Point::new(0.0, 0.1)];
        assert_eq!(
            classify_turn(&east, &[Point::new(10.0, 0.0), Point::new(20.0, 1.0)]),
            Turn::Straight
        );
        assert_eq!(classify_turn(&east, &north), Turn::Left);
        assert_eq!(classify_turn(&east, &south), Turn::Right);
        assert_eq!(classify_turn(&east, &west), Turn::UTurn);
    }
}
