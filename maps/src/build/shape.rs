//! Steps 2 and 3: cut roads back from intersections to make room for junction areas, then
//! lay lanes along the trimmed reference lines.

use std::collections::BTreeMap;

use crate::geometry::{
    Point, convex_hull, direction_at, offset_polyline, point_at, polyline_length, slice_polyline,
};
use crate::model::{Direction, DrivingSide, JunctionId, JunctionKind, Lane, LaneId, RoadId};
use crate::tags;

use super::select::Builder;

/// No road end is cut back further than this, whatever the angles say.
const MAX_TRIM_M: f64 = 20.0;
/// Nor by more than this share of the road, so short roads keep some length.
const MAX_TRIM_SHARE: f64 = 0.45;

/// One road end at a junction.
#[derive(Debug, Clone, Copy)]
struct RoadEnd {
    road: RoadId,
    at_start: bool,
    /// Unit direction leaving the junction along the road.
    direction: Point,
    /// Carriageway half-widths to the right and left when looking out of the junction.
    right: f64,
    left: f64,
}

impl Builder<'_> {
    fn road_ends(&self, junction: JunctionId) -> Vec<RoadEnd> {
        let side = self.map.driving_side;
        let mut ends = Vec::new();
        let mut at_junction: Vec<RoadId> = self
            .map
            .junctions
            .get(&junction)
            .map(|j| j.roads.clone())
            .unwrap_or_default();
        at_junction.sort_unstable();
        at_junction.dedup();
        for road in at_junction.iter().filter_map(|r| self.map.roads.get(r)) {
            let Some(info) = self.info.get(&road.id) else {
                continue;
            };
            let (hr, hl) = info.half_widths(side);
            let len = polyline_length(&road.reference_line);
            let probe = (len / 2.0).min(5.0);
            if road.start_junction == junction {
                ends.push(RoadEnd {
                    road: road.id,
                    at_start: true,
                    direction: direction_at(&road.reference_line, probe / 2.0),
                    right: hr,
                    left: hl,
                });
            }
            if road.end_junction == junction {
                let rev: Vec<Point> = road.reference_line.iter().rev().copied().collect();
                ends.push(RoadEnd {
                    road: road.id,
                    at_start: false,
                    direction: direction_at(&rev, probe / 2.0),
                    right: hl,
                    left: hr,
                });
            }
        }
        ends.sort_by(|a, b| {
            a.direction
                .y
                .atan2(a.direction.x)
                .total_cmp(&b.direction.y.atan2(b.direction.x))
        });
        ends
    }

    /// Trims every road end at an intersection by the distance at which it clears its
    /// neighbours (for two roads at angle θ with half-widths w1, w2: (w2 + w1 cos θ) / sin θ),
    /// and makes the junction polygon the hull of the trimmed carriageway ends.
    pub fn shape_junctions(&mut self) {
        let mut trims: BTreeMap<(RoadId, bool), f64> = BTreeMap::new();
        let intersections: Vec<JunctionId> = self
            .map
            .junctions
            .values()
            .filter(|j| j.kind == JunctionKind::Intersection)
            .map(|j| j.id)
            .collect();
        for &j in &intersections {
            let ends = self.road_ends(j);
            let n = ends.len();
            for (i, e) in ends.iter().enumerate() {
                let widest_other = ends
                    .iter()
                    .enumerate()
                    .filter(|(k, _)| *k != i)
                    .map(|(_, o)| o.left.max(o.right))
                    .fold(0.0, f64::max);
                let mut d = widest_other;
                // The neighbour counter-clockwise meets this end's left side; clockwise, its right side.
                for (other, own_half, other_half) in [
                    (ends[(i + 1) % n], e.left, ends[(i + 1) % n].right),
                    (ends[(i + n - 1) % n], e.right, ends[(i + n - 1) % n].left),
                ] {
                    let cos = e.direction.dot(other.direction).clamp(-1.0, 1.0);
                    let sin = e.direction.cross(other.direction).abs();
                    if sin > 1e-3 {
                        d = d.max(((other_half + own_half * cos) / sin).clamp(0.0, MAX_TRIM_M));
                    } else if cos > 0.0 {
                        d = MAX_TRIM_M;
                    }
                }
                trims.insert((e.road, e.at_start), d);
            }
        }
        for road in self.map.roads.values_mut() {
            let len = polyline_length(&road.reference_line);
            let cap = len * MAX_TRIM_SHARE;
            let from = trims.get(&(road.id, true)).copied().unwrap_or(0.0).min(cap);
            let to = len
                - trims
                    .get(&(road.id, false))
                    .copied()
                    .unwrap_or(0.0)
                    .min(cap);
            if from > 0.0 || to < len {
                road.reference_line = slice_polyline(&road.reference_line, from, to);
            }
        }
        for &j in &intersections {
            let mut corners = Vec::new();
            for e in self.road_ends(j) {
                let Some(road) = self.map.roads.get(&e.road) else {
                    continue;
                };
                let line = &road.reference_line;
                let (p, dir) = if e.at_start {
                    (line[0], e.direction)
                } else {
                    (line[line.len() - 1], e.direction)
                };
                let left_normal = dir.perp();
                corners.push(p.add(left_normal.scale(e.left)));
                corners.push(p.sub(left_normal.scale(e.right)));
            }
            if let Some(junction) = self.map.junctions.get_mut(&j) {
                corners.push(junction.point);
                junction.polygon = convex_hull(&corners);
            }
        }
    }

    /// Lays lanes along each road: on two-way roads forward lanes on the driving side of the
    /// reference line and backward lanes on the other; one-way roads centred on it.
    pub fn build_lanes(&mut self) {
        let side = self.map.driving_side;
        let mut next = 0u32;
        let road_ids: Vec<RoadId> = self.map.roads.keys().copied().collect();
        for rid in road_ids {
            let (Some(road), Some(info)) = (self.map.roads.get(&rid), self.info.get(&rid)) else {
                continue;
            };
            let two_way = info.lanes_forward > 0 && info.lanes_backward > 0;
            let w = info.lane_width;
            let mut made: Vec<(Direction, LaneId)> = Vec::new();
            for (direction, count) in [
                (Direction::Forward, info.lanes_forward),
                (Direction::Backward, info.lanes_backward),
            ] {
                let travel: Vec<Point> = match direction {
                    Direction::Forward => road.reference_line.clone(),
                    Direction::Backward => road.reference_line.iter().rev().copied().collect(),
                };
                let (from_j, to_j) = match direction {
                    Direction::Forward => (road.start_junction, road.end_junction),
                    Direction::Backward => (road.end_junction, road.start_junction),
                };
                let (speed_key, turn_key) = match (direction, two_way) {
                    (_, false) => ("maxspeed", "turn:lanes"),
                    (Direction::Forward, true) => ("maxspeed:forward", "turn:lanes:forward"),
                    (Direction::Backward, true) => ("maxspeed:backward", "turn:lanes:backward"),
                };
                let speed = tags::speed_limit_kmh(info.tags, &road.highway, Some(speed_key)).0;
                let turn_lanes = tags::turn_lanes(info.tags, turn_key);
                for i in 0..count {
                    let n = f64::from(count);
                    let k = f64::from(i);
                    // Offset of the lane centre, positive = left of travel.
                    let offset = match (two_way, side) {
                        (true, DrivingSide::Right) => -(k + 0.5) * w,
                        (true, DrivingSide::Left) => (k + 0.5) * w,
                        (false, DrivingSide::Right) => (n / 2.0 - k - 0.5) * w,
                        (false, DrivingSide::Left) => -(n / 2.0 - k - 0.5) * w,
                    };
                    let centre = offset_polyline(&travel, offset);
                    // `turn:lanes` lists lanes left to right; our index counts from the centre.
                    let left_to_right = match side {
                        DrivingSide::Right => usize::from(i),
                        DrivingSide::Left => usize::from(count - 1 - i),
                    };
                    let id = LaneId(next);
                    next += 1;
                    let length = polyline_length(&centre);
                    self.map.lanes.insert(
                        id,
                        Lane {
                            id,
                            road: rid,
                            direction,
                            index_from_centre: i,
                            left: offset_polyline(&travel, offset + w / 2.0),
                            right: offset_polyline(&travel, offset - w / 2.0),
                            centre,
                            width_m: w,
                            length_m: length.max(f64::MIN_POSITIVE),
                            speed_limit_kmh: speed,
                            turns: turn_lanes.get(left_to_right).cloned().unwrap_or_default(),
                            from_junction: from_j,
                            to_junction: to_j,
                        },
                    );
                    made.push((direction, id));
                }
            }
            if let Some(road) = self.map.roads.get_mut(&rid) {
                for (d, id) in made {
                    match d {
                        Direction::Forward => road.lanes_forward.push(id),
                        Direction::Backward => road.lanes_backward.push(id),
                    }
                }
            }
        }
    }
}

/// The point and unit direction at the end of a lane (`at_end`) or its start.
pub(super) fn lane_tip(centre: &[Point], at_end: bool) -> (Point, Point) {
    let len = polyline_length(centre);
    if at_end {
        let rev: Vec<Point> = centre.iter().rev().copied().collect();
        (point_at(centre, len), direction_at(&rev, 0.0).scale(-1.0))
    } else {
        (point_at(centre, 0.0), direction_at(centre, 0.0))
    }
}

impl Builder<'_> {
    /// Paint: a centre line between the directions, dashed lines between lanes of one
    /// direction, solid lines along both carriageway edges.
    pub fn paint_markings(&mut self) {
        use crate::model::{Marking, MarkingKind};
        let mut markings = Vec::new();
        for road in self.map.roads.values() {
            let lanes = |ids: &[LaneId]| -> Vec<&Lane> {
                ids.iter().filter_map(|l| self.map.lanes.get(l)).collect()
            };
            let (fwd, bwd) = (lanes(&road.lanes_forward), lanes(&road.lanes_backward));
            for group in [&fwd, &bwd] {
                for pair in group.windows(2) {
                    // Lanes run from the centre outwards: the inner lane's outer edge is shared.
                    let shared = if self.map.driving_side == DrivingSide::Right || group.len() < 2 {
                        &pair[0].right
                    } else {
                        &pair[0].left
                    };
                    markings.push(Marking {
                        road: road.id,
                        kind: MarkingKind::Dashed,
                        line: shared.clone(),
                    });
                }
            }
            let two_way = !fwd.is_empty() && !bwd.is_empty();
            if two_way {
                markings.push(Marking {
                    road: road.id,
                    kind: MarkingKind::CentreLine,
                    line: road.reference_line.clone(),
                });
            }
            for group in [&fwd, &bwd] {
                if let (Some(first), Some(last)) = (group.first(), group.last()) {
                    // The outer edge of each direction; on one-way roads also the inner (first) edge.
                    let outer = match self.map.driving_side {
                        DrivingSide::Right => &last.right,
                        DrivingSide::Left => &last.left,
                    };
                    markings.push(Marking {
                        road: road.id,
                        kind: MarkingKind::SolidEdge,
                        line: outer.clone(),
                    });
                    if !two_way {
                        let inner = match self.map.driving_side {
                            DrivingSide::Right => &first.left,
                            DrivingSide::Left => &first.right,
                        };
                        markings.push(Marking {
                            road: road.id,
                            kind: MarkingKind::SolidEdge,
                            line: inner.clone(),
                        });
                    }
                }
            }
        }
        self.map.markings = markings;
    }
}
