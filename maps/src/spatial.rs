//! A spatial index of lane centre lines (an R*-tree from the `rstar` crate): the nearest lane
//! to a point without scanning every lane. Routing snaps route ends with it; log matching
//! and other point-to-lane queries can share it.

use rstar::{AABB, Envelope as _, PointDistance, RTree, RTreeObject};

use crate::geometry::{Point, project_onto_polyline};
use crate::model::{LaneId, Map};

/// One lane's bounding box in the tree.
#[derive(Debug, Clone)]
struct LaneBox {
    lane: LaneId,
    envelope: AABB<[f64; 2]>,
}

impl RTreeObject for LaneBox {
    type Envelope = AABB<[f64; 2]>;

    fn envelope(&self) -> Self::Envelope {
        self.envelope
    }
}

impl PointDistance for LaneBox {
    fn distance_2(&self, point: &[f64; 2]) -> f64 {
        self.envelope.distance_2(point)
    }
}

/// The nearest lane to a point, with the arc length of the nearest place on its centre line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NearestLane {
    pub lane: LaneId,
    /// Arc length along the lane's centre line of the nearest place, metres.
    pub s_m: f64,
    /// Distance from the point to that place, metres.
    pub distance_m: f64,
}

/// An R*-tree over the bounding boxes of a set of lanes' centre lines.
#[derive(Debug, Clone)]
pub struct LaneIndex {
    tree: RTree<LaneBox>,
}

impl LaneIndex {
    /// Indexes `lanes` of `map` (lanes missing from the map or without points are left out).
    pub fn new(map: &Map, lanes: impl IntoIterator<Item = LaneId>) -> Self {
        let boxes = lanes
            .into_iter()
            .filter_map(|id| {
                let centre = &map.lanes.get(&id)?.centre;
                let first = centre.first()?;
                let mut envelope = AABB::from_point([first.x, first.y]);
                for p in centre {
                    envelope.merge(&AABB::from_point([p.x, p.y]));
                }
                Some(LaneBox { lane: id, envelope })
            })
            .collect();
        LaneIndex {
            tree: RTree::bulk_load(boxes),
        }
    }

    /// Indexes every car lane of `map`.
    pub fn car_lanes(map: &Map) -> Self {
        Self::new(map, map.car_lanes().map(|l| l.id))
    }

    pub fn is_empty(&self) -> bool {
        self.tree.size() == 0
    }

    /// The nearest indexed lane to `p` by projection onto centre lines; on a tie, the
    /// smaller lane id. None when the index is empty or `p` is not finite.
    pub fn nearest(&self, map: &Map, p: Point) -> Option<NearestLane> {
        if !p.is_finite() {
            return None;
        }
        let mut best: Option<NearestLane> = None;
        // Boxes come nearest first; a box farther than the best lane found cannot hold a
        // nearer one (a box at the same distance may hold a tie with a smaller id).
        for (candidate, box_d2) in self.tree.nearest_neighbor_iter_with_distance_2(&[p.x, p.y]) {
            if best.is_some_and(|b| box_d2.sqrt() > b.distance_m) {
                break;
            }
            let Some(lane) = map.lanes.get(&candidate.lane) else {
                continue;
            };
            let (s_m, distance_m) = project_onto_polyline(&lane.centre, p);
            let better = best.is_none_or(|b| {
                distance_m < b.distance_m || (distance_m == b.distance_m && candidate.lane < b.lane)
            });
            if better {
                best = Some(NearestLane {
                    lane: candidate.lane,
                    s_m,
                    distance_m,
                });
            }
        }
        best
    }

    /// The lanes whose bounding box lies within `radius_m` of `p` (a superset of the lanes
    /// whose centre line does), in no particular order.
    pub fn lanes_near(&self, p: Point, radius_m: f64) -> impl Iterator<Item = LaneId> + '_ {
        self.tree
            .locate_within_distance([p.x, p.y], radius_m * radius_m)
            .map(|b| b.lane)
    }
}
