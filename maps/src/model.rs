//! The native map: roads, lanes, junctions, connections, roundabouts, stop lines, markings.
//!
//! Every element has a typed id and lives in an ordered map, so iteration order (and with
//! it every output) is deterministic. Geometry is in the map's metric frame (metres, x east,
//! y north), see [`Projection`]. Lane geometry runs in the lane's direction of travel.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::geometry::Point;
use crate::projection::Projection;

/// Version of the native map file format; bump on any incompatible change.
pub const MAP_FORMAT_VERSION: u32 = 3;

macro_rules! typed_id {
    ($($(#[$doc:meta])* $name:ident),* $(,)?) => {$(
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
        #[serde(transparent)]
        pub struct $name(pub u32);

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                write!(f, "{}", self.0)
            }
        }
    )*};
}

typed_id!(
    /// A road: one stretch of carriageway between two junctions.
    RoadId,
    /// One lane of a road, in one direction of travel.
    LaneId,
    /// Where road ends meet (an intersection, a continuation point or a dead end).
    JunctionId,
    /// A lane-to-lane movement through a junction.
    ConnectionId,
    /// One roundabout ring.
    RoundaboutId,
    /// A stop or give-way line across one or more lanes.
    StopLineId,
);

/// Which side of the road traffic keeps to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DrivingSide {
    Right,
    Left,
}

/// Direction of a lane relative to its road's reference line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Direction {
    Forward,
    Backward,
}

/// Where a road came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
// Externally tagged (`{"local": {...}}`): the binary form (postcard) can read it back,
// which it cannot for internally tagged enums.
#[serde(rename_all = "snake_case")]
pub enum RoadSource {
    /// An OSM way (or a piece of one, split at shared nodes).
    OsmWay,
    /// A Lanelet2 lanelet relation; `osm_way_ids` then holds its left and right bound ways.
    Lanelet { relation_id: i64 },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Road {
    pub id: RoadId,
    pub source: RoadSource,
    /// The OSM ways this road was made from.
    pub osm_way_ids: Vec<i64>,
    /// `highway=*` class (`lanelet` for Lanelet2 roads).
    pub highway: String,
    pub name: Option<String>,
    /// Reference line (the way's geometry, trimmed back to the junction areas).
    pub reference_line: Vec<Point>,
    pub start_junction: JunctionId,
    pub end_junction: JunctionId,
    /// Lanes in the reference line's direction, from the centre outwards.
    pub lanes_forward: Vec<LaneId>,
    /// Lanes against it, from the centre outwards.
    pub lanes_backward: Vec<LaneId>,
    pub speed_limit_kmh: f64,
    /// True when `speed_limit_kmh` is a class default, not from a tag.
    pub speed_limit_is_default: bool,
    pub is_roundabout: bool,
    /// Whether passenger cars may use it (the import profile decides which roads exist at all).
    pub allows_cars: bool,
}

impl Road {
    pub fn lanes(&self) -> impl Iterator<Item = LaneId> + '_ {
        self.lanes_forward
            .iter()
            .chain(&self.lanes_backward)
            .copied()
    }
    pub fn is_oneway(&self) -> bool {
        self.lanes_forward.is_empty() || self.lanes_backward.is_empty()
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Lane {
    pub id: LaneId,
    pub road: RoadId,
    pub direction: Direction,
    /// 0 is the lane next to the road's centre line (or its left edge on a one-way road).
    pub index_from_centre: u8,
    /// Centre line, in the direction of travel.
    pub centre: Vec<Point>,
    /// Left and right boundaries, in the direction of travel.
    pub left: Vec<Point>,
    pub right: Vec<Point>,
    pub width_m: f64,
    pub length_m: f64,
    pub speed_limit_kmh: f64,
    /// Allowed turns from `turn:lanes` (e.g. `left`, `through`), empty when untagged.
    pub turns: Vec<String>,
    /// The junction the lane leaves from and the one it runs into.
    pub from_junction: JunctionId,
    pub to_junction: JunctionId,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JunctionKind {
    /// Three or more roads meet.
    Intersection,
    /// Exactly two road ends meet (a way split point, or one way running into another).
    Continuation,
    /// A road ends here.
    DeadEnd,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Junction {
    pub id: JunctionId,
    pub kind: JunctionKind,
    /// The OSM node at its centre (None for Lanelet2 joints).
    pub osm_node_id: Option<i64>,
    pub point: Point,
    /// Junction area, counter-clockwise, not closed; empty for continuations and dead ends.
    pub polygon: Vec<Point>,
    pub roads: Vec<RoadId>,
    /// `highway=traffic_signals` or similar on the node.
    pub control: Option<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Turn {
    Straight,
    Left,
    Right,
    UTurn,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Connection {
    pub id: ConnectionId,
    pub junction: JunctionId,
    pub from: LaneId,
    pub to: LaneId,
    pub turn: Turn,
    /// Path through the junction, from the end of `from` to the start of `to`.
    pub centre: Vec<Point>,
    pub length_m: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RoundaboutArm {
    pub road: RoadId,
    /// The arm's lanes that enter (for an entry) or leave (for an exit) the ring.
    pub lanes: Vec<LaneId>,
    /// The junction on the ring where the arm meets it.
    pub junction: JunctionId,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RoundaboutSource {
    /// `junction=roundabout` or `junction=circular` ways.
    Tagged,
    /// A near-circular one-way loop without the tag.
    Guessed,
    /// Lanelet2 circulating lanelets (the `right_of_way` members of regulatory elements).
    Lanelet2,
}

/// What kind of ring a roundabout is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RoundaboutKind {
    /// `junction=roundabout`, a guessed loop, or a Lanelet2 ring.
    #[default]
    Roundabout,
    /// `junction=circular`: a ring where circulating traffic need not have priority.
    Circular,
    /// A `highway=mini_roundabout` node, imported as a small ring of one lane round it
    /// ([`Roundabout::osm_node_id`] names the node).
    MiniRoundabout,
}

impl RoundaboutKind {
    /// For people: `roundabout`, `circular junction` or `mini-roundabout`.
    pub fn words(self) -> &'static str {
        match self {
            RoundaboutKind::Roundabout => "roundabout",
            RoundaboutKind::Circular => "circular junction",
            RoundaboutKind::MiniRoundabout => "mini-roundabout",
        }
    }
}

/// Who gives way where a roundabout's entry meets its ring.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RoundaboutPriority {
    /// Entering traffic gives way to traffic on the ring (the roundabout rule).
    #[default]
    Circulating,
    /// Traffic on the ring gives way to entering traffic (give-way or stop signs on the
    /// ring, or traffic signals on its nodes).
    Entering,
}

impl RoundaboutPriority {
    /// For people, with where it comes from: e.g. `ring first (assumed)`.
    pub fn words(self, source: PrioritySource) -> String {
        let first = match self {
            RoundaboutPriority::Circulating => "ring first",
            RoundaboutPriority::Entering => "entries first",
        };
        let how = match source {
            PrioritySource::Tags => "tagged",
            PrioritySource::Assumed => "assumed",
        };
        format!("{first} ({how})")
    }
}

/// Where a roundabout's [`RoundaboutPriority`] comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PrioritySource {
    /// `priority_road` / `priority` on the ring, give-way / stop signs or traffic signals in
    /// the data.
    Tags,
    /// Nothing in the data says; the roundabout rule is assumed.
    #[default]
    Assumed,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Roundabout {
    pub id: RoundaboutId,
    pub source: RoundaboutSource,
    pub kind: RoundaboutKind,
    pub priority: RoundaboutPriority,
    pub priority_source: PrioritySource,
    /// The ring's OSM ways (empty for a mini-roundabout, whose ring is made on import).
    pub osm_way_ids: Vec<i64>,
    /// The `highway=mini_roundabout` node of a mini-roundabout.
    #[serde(default)]
    pub osm_node_id: Option<i64>,
    pub roads: Vec<RoadId>,
    /// One trip round the ring: circulating lanes, each followed (through a connection)
    /// by the next in the direction of travel, the last by the first.
    pub circulating_lanes: Vec<LaneId>,
    /// Every lane of the ring's roads (several per segment on multi-lane rings).
    pub ring_lanes: Vec<LaneId>,
    /// Most lanes side by side anywhere on the ring.
    pub lanes_across: u8,
    pub entries: Vec<RoundaboutArm>,
    pub exits: Vec<RoundaboutArm>,
    /// A give-way line on every entry where it meets the ring (OSM rings: whatever
    /// `priority` says).
    pub yield_lines: Vec<StopLineId>,
    pub centre: Point,
    pub radius_m: f64,
    pub clockwise: bool,
}

/// A tagged ring (or mini-roundabout node) with a problem: not closed, nodes missing from
/// the extract, a piece against the ring's direction, an unusable `lanes` value, lanes that
/// do not connect. Its roads are still imported as ordinary roads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RingProblem {
    /// The ring's OSM ways (sorted; empty for a mini-roundabout node).
    pub osm_way_ids: Vec<i64>,
    /// The mini-roundabout node, for a node problem.
    #[serde(default)]
    pub osm_node_id: Option<i64>,
    /// What is wrong, naming the way or node.
    pub reason: String,
    /// True when the ring was still imported as a roundabout (e.g. an unusable `lanes`
    /// value replaced by the class default).
    pub imported: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopKind {
    Stop,
    GiveWay,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
// Externally tagged (`{"local": {...}}`): the binary form (postcard) can read it back,
// which it cannot for internally tagged enums.
#[serde(rename_all = "snake_case")]
pub enum StopLineSource {
    /// A `highway=stop` / `highway=give_way` node.
    OsmNode { id: i64 },
    /// The entry of a roundabout, where it meets the ring.
    RoundaboutEntry { roundabout: RoundaboutId },
    /// A Lanelet2 `stop_line` way or the `ref_line` of a `right_of_way` element.
    LaneletWay { id: i64 },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StopLine {
    pub id: StopLineId,
    pub kind: StopKind,
    pub source: StopLineSource,
    /// The lanes whose traffic stops here.
    pub lanes: Vec<LaneId>,
    /// The line itself, across those lanes.
    pub line: Vec<Point>,
    /// Where it stands along the first lane, metres from the lane's start.
    pub s_on_lane_m: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MarkingKind {
    /// Between lanes of one direction.
    Dashed,
    /// Between the two directions.
    CentreLine,
    /// The outer edge of the carriageway.
    SolidEdge,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Marking {
    pub road: RoadId,
    pub kind: MarkingKind,
    pub line: Vec<Point>,
}

/// What the import left out, and why. Part of the map so every output can report it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ImportReport {
    /// Selected ways skipped because they referenced nodes missing from the file.
    pub ways_missing_nodes: Vec<i64>,
    /// Nodes dropped for coordinates outside WGS84's range.
    pub invalid_nodes: usize,
    /// Selected ways with fewer than two distinct positions.
    pub degenerate_ways: Vec<i64>,
    /// Turn restrictions applied, and those that could not be (unknown ways, via ways, ...).
    pub restrictions_applied: usize,
    pub restrictions_skipped: Vec<i64>,
    /// Stop / give-way nodes that could not be placed on a selected road.
    pub stop_nodes_unplaced: Vec<i64>,
    /// Free-form notes (e.g. a Lanelet2 element that was not understood).
    pub notes: Vec<String>,
    /// Tagged rings and mini-roundabout nodes with a problem, in way-id order.
    #[serde(default)]
    pub ring_problems: Vec<RingProblem>,
}

/// A drivable map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Map {
    pub format_version: u32,
    pub projection: Projection,
    pub driving_side: DrivingSide,
    /// The road-selection profile the map was imported with.
    pub profile: String,
    pub roads: BTreeMap<RoadId, Road>,
    pub lanes: BTreeMap<LaneId, Lane>,
    pub junctions: BTreeMap<JunctionId, Junction>,
    pub connections: BTreeMap<ConnectionId, Connection>,
    pub roundabouts: BTreeMap<RoundaboutId, Roundabout>,
    pub stop_lines: BTreeMap<StopLineId, StopLine>,
    pub markings: Vec<Marking>,
    pub report: ImportReport,
}

impl Map {
    pub fn new(projection: Projection, driving_side: DrivingSide, profile: &str) -> Self {
        Map {
            format_version: MAP_FORMAT_VERSION,
            projection,
            driving_side,
            profile: profile.to_owned(),
            roads: BTreeMap::new(),
            lanes: BTreeMap::new(),
            junctions: BTreeMap::new(),
            connections: BTreeMap::new(),
            roundabouts: BTreeMap::new(),
            stop_lines: BTreeMap::new(),
            markings: Vec::new(),
            report: ImportReport::default(),
        }
    }

    /// Connections leaving the end of each lane, in id order.
    pub fn outgoing(&self) -> BTreeMap<LaneId, Vec<ConnectionId>> {
        let mut out: BTreeMap<LaneId, Vec<ConnectionId>> = BTreeMap::new();
        for c in self.connections.values() {
            out.entry(c.from).or_default().push(c.id);
        }
        out
    }

    /// Lanes that passenger cars may use.
    pub fn car_lanes(&self) -> impl Iterator<Item = &Lane> {
        self.lanes
            .values()
            .filter(|l| self.roads.get(&l.road).is_some_and(|r| r.allows_cars))
    }

    pub fn bounds(&self) -> crate::geometry::Bounds {
        let mut b = crate::geometry::Bounds::empty();
        for lane in self.lanes.values() {
            for p in lane.left.iter().chain(&lane.right) {
                b.extend(*p);
            }
        }
        for j in self.junctions.values() {
            for p in &j.polygon {
                b.extend(*p);
            }
        }
        b
    }
}
