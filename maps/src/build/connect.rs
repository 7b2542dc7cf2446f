//! Steps 4 and 5: lane-to-lane connections through every junction, then the turn
//! restrictions (`type=restriction` relations) that remove some of them.

use std::collections::{BTreeMap, BTreeSet};

use crate::geometry::{Point, polyline_length};
use crate::model::{
    Connection, ConnectionId, Direction, DrivingSide, JunctionId, JunctionKind, LaneId, RoadId,
    Turn,
};
use crate::osm::MemberKind;

use super::select::Builder;
use super::shape::lane_tip;
use crate::options::UTurns;

/// Heading changes below this count as going straight on.
const STRAIGHT_DEG: f64 = 35.0;

/// The lanes of one road in one direction at a junction, ordered from the centre outwards.
#[derive(Debug, Clone)]
struct Approach {
    road: RoadId,
    direction: Direction,
    lanes: Vec<LaneId>,
    /// Unit direction of travel at the junction.
    heading: Point,
}

impl Builder<'_> {
    fn approaches(&self, junction: JunctionId, incoming: bool) -> Vec<Approach> {
        let mut groups: BTreeMap<(RoadId, Direction), Vec<LaneId>> = BTreeMap::new();
        for lane in self.lanes_at(junction) {
            let at = if incoming {
                lane.to_junction
            } else {
                lane.from_junction
            };
            if at == junction {
                groups
                    .entry((lane.road, lane.direction))
                    .or_default()
                    .push(lane.id);
            }
        }
        groups
            .into_iter()
            .filter_map(|((road, direction), mut lanes)| {
                lanes.sort_by_key(|l| self.map.lanes.get(l).map(|x| x.index_from_centre));
                let first = self.map.lanes.get(lanes.first()?)?;
                let (_, heading) = lane_tip(&first.centre, incoming);
                Some(Approach {
                    road,
                    direction,
                    lanes,
                    heading,
                })
            })
            .collect()
    }

    /// Connects every incoming lane group to every outgoing one it may turn into: near-side
    /// turns from the outer lanes, far-side turns from the inner lanes, straight on lane by
    /// lane; `turn:lanes` narrows the choice where tagged.
    pub fn connect_lanes(&mut self) {
        use rayon::prelude::*;
        let junctions: Vec<(JunctionId, JunctionKind)> = self
            .map
            .junctions
            .values()
            .map(|j| (j.id, j.kind))
            .collect();
        // Each junction's movements depend only on the lanes, so they are found on every
        // core; ids are then given in junction order, the same whatever the thread count.
        let per_junction: Vec<Vec<Connection>> = junctions
            .par_iter()
            .map(|&(j, kind)| self.junction_connections(j, kind))
            .collect();
        for (mut connection, next) in per_junction.into_iter().flatten().zip(0u32..) {
            connection.id = ConnectionId(next);
            self.map.connections.insert(connection.id, connection);
        }
    }

    /// The connections through one junction, in the order of its incoming and outgoing lane
    /// groups; their ids are placeholders.
    fn junction_connections(&self, j: JunctionId, kind: JunctionKind) -> Vec<Connection> {
        let incoming = self.approaches(j, true);
        let outgoing = self.approaches(j, false);
        let mut connections = Vec::new();
        for a in &incoming {
            for b in &outgoing {
                let u_turn = a.road == b.road && a.direction != b.direction;
                if u_turn {
                    let allowed = match self.options.u_turns {
                        UTurns::Never => false,
                        UTurns::DeadEnds => kind == JunctionKind::DeadEnd,
                        UTurns::Everywhere => true,
                    };
                    if !allowed {
                        continue;
                    }
                }
                if a.road == b.road && a.direction == b.direction {
                    continue;
                }
                let turn = if u_turn {
                    Turn::UTurn
                } else if kind == JunctionKind::Continuation {
                    Turn::Straight
                } else {
                    classify(a.heading, b.heading, self.map.driving_side)
                };
                for (from, to) in self.lane_pairs(a, b, turn) {
                    let centre = self.connection_curve(from, to);
                    let length_m = polyline_length(&centre);
                    connections.push(Connection {
                        id: ConnectionId(0),
                        junction: j,
                        from,
                        to,
                        turn,
                        centre,
                        length_m,
                    });
                }
            }
        }
        connections
    }

    /// Which lanes of `a` feed which lanes of `b` for a movement of kind `turn`.
    fn lane_pairs(&self, a: &Approach, b: &Approach, turn: Turn) -> Vec<(LaneId, LaneId)> {
        let near_side = matches!(
            (turn, self.map.driving_side),
            (Turn::Right, DrivingSide::Right) | (Turn::Left, DrivingSide::Left)
        );
        let keyword = match turn {
            Turn::Left => "left",
            Turn::Right => "right",
            Turn::Straight => "through",
            Turn::UTurn => "reverse",
        };
        // Lanes whose `turn:lanes` allow this movement; all lanes when none is tagged for it.
        let tagged: Vec<LaneId> = a
            .lanes
            .iter()
            .copied()
            .filter(|l| {
                self.map.lanes.get(l).is_some_and(|lane| {
                    lane.turns.iter().any(|t| {
                        t.contains(keyword)
                            || (turn == Turn::Straight
                                && (t == "none" || t.starts_with("merge_to")))
                    })
                })
            })
            .collect();
        let from: Vec<LaneId> = if tagged.is_empty() {
            a.lanes.clone()
        } else {
            tagged
        };
        let to = &b.lanes;
        let (Some(&inner_from), Some(&outer_from)) = (from.first(), from.last()) else {
            return Vec::new();
        };
        let (Some(&inner_to), Some(&outer_to)) = (to.first(), to.last()) else {
            return Vec::new();
        };
        match turn {
            Turn::UTurn => vec![(inner_from, inner_to)],
            _ if near_side => vec![(outer_from, outer_to)],
            Turn::Left | Turn::Right => vec![(inner_from, inner_to)],
            Turn::Straight => {
                // Lane by lane from the outer side; extra lanes on either side share the innermost.
                let mut pairs = BTreeSet::new();
                let (nf, nt) = (from.len(), to.len());
                for k in 0..nf.max(nt) {
                    let f = from[nf - 1 - k.min(nf - 1)];
                    let t = to[nt - 1 - k.min(nt - 1)];
                    pairs.insert((f, t));
                }
                pairs.into_iter().collect()
            }
        }
    }

    /// A cubic Bézier from the end of `from` to the start of `to`, tangent to both.
    pub(super) fn connection_curve(&self, from: LaneId, to: LaneId) -> Vec<Point> {
        let (Some(a), Some(b)) = (self.map.lanes.get(&from), self.map.lanes.get(&to)) else {
            return vec![Point::default(); 2];
        };
        let (p0, d0) = lane_tip(&a.centre, true);
        let (p3, d3) = lane_tip(&b.centre, false);
        let gap = p0.distance(p3);
        if gap < 0.05 {
            return vec![p0, p3];
        }
        let (p1, p2) = (p0.add(d0.scale(gap / 3.0)), p3.sub(d3.scale(gap / 3.0)));
        (0..=8)
            .map(|i| {
                let t = f64::from(i) / 8.0;
                let u = 1.0 - t;
                p0.scale(u * u * u)
                    .add(p1.scale(3.0 * u * u * t))
                    .add(p2.scale(3.0 * u * t * t))
                    .add(p3.scale(t * t * t))
            })
            .collect()
    }

    /// Applies `restriction=no_*` / `only_*` relations with a via node (also
    /// `restriction:motorcar`); skips those excepting cars, with via ways, or naming ways
    /// that are not at the via node, and counts them.
    pub fn apply_turn_restrictions(&mut self) {
        for (&rel_id, rel) in &self.osm.relations {
            if !rel.tags.is("type", "restriction") {
                continue;
            }
            let Some(kind) = rel
                .tags
                .get("restriction")
                .or_else(|| rel.tags.get("restriction:motorcar"))
            else {
                continue;
            };
            if rel
                .tags
                .get("except")
                .is_some_and(|e| e.split(';').any(|x| x.trim() == "motorcar"))
            {
                continue;
            }
            let member = |role: &str, mk: MemberKind| {
                rel.members
                    .iter()
                    .find(|m| m.role == role && m.kind == mk)
                    .map(|m| m.id)
            };
            let (Some(from_way), Some(to_way)) = (
                member("from", MemberKind::Way),
                member("to", MemberKind::Way),
            ) else {
                self.map.report.restrictions_skipped.push(rel_id);
                continue;
            };
            let Some(via) = member("via", MemberKind::Node)
                .and_then(|n| self.junction_of_node.get(&n).copied())
            else {
                self.map.report.restrictions_skipped.push(rel_id);
                continue;
            };
            let roads_of = |way: i64| -> BTreeSet<RoadId> {
                self.map
                    .roads
                    .values()
                    .filter(|r| {
                        r.osm_way_ids.contains(&way)
                            && (r.start_junction == via || r.end_junction == via)
                    })
                    .map(|r| r.id)
                    .collect()
            };
            let (from_roads, to_roads) = (roads_of(from_way), roads_of(to_way));
            if from_roads.is_empty() || to_roads.is_empty() {
                self.map.report.restrictions_skipped.push(rel_id);
                continue;
            }
            let only = kind.starts_with("only_");
            let lanes = &self.map.lanes;
            let road_of = |l: &LaneId| lanes.get(l).map(|x| x.road);
            self.map.connections.retain(|_, c| {
                if c.junction != via || !road_of(&c.from).is_some_and(|r| from_roads.contains(&r)) {
                    return true;
                }
                let into_to = road_of(&c.to).is_some_and(|r| to_roads.contains(&r));
                if only { into_to } else { !into_to }
            });
            self.map.report.restrictions_applied += 1;
        }
    }
}

/// Straight, left or right from the signed heading change.
fn classify(from: Point, to: Point, _side: DrivingSide) -> Turn {
    let angle = from.cross(to).atan2(from.dot(to)).to_degrees();
    if angle.abs() < STRAIGHT_DEG {
        Turn::Straight
    } else if angle > 0.0 {
        Turn::Left
    } else {
        Turn::Right
    }
}
