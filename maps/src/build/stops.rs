//! Step 7: stop and give-way lines from `highway=stop` / `highway=give_way` nodes.
//!
//! A sign node inside a road stops the lanes heading to the nearer end of that road (or the
//! direction its `direction=forward|backward` tag names), at the node's position. A sign on
//! a junction node stops every lane arriving there except circulating roundabout lanes.

use crate::geometry::{Point, project_onto_polyline};
use crate::model::{Direction, LaneId, RoadId, StopKind, StopLine, StopLineId, StopLineSource};

use super::select::Builder;

impl Builder<'_> {
    pub fn place_stop_lines(&mut self) {
        let projector = self.map.projection.projector();
        for (&node_id, node) in &self.osm.nodes {
            let kind = match node.tags.get("highway") {
                Some("stop") => StopKind::Stop,
                Some("give_way") => StopKind::GiveWay,
                _ => continue,
            };
            let p = projector.project(node.pos);
            let groups = if let Some(&j) = self.junction_of_node.get(&node_id) {
                self.groups_arriving_at(j)
            } else if let Some((road, index)) = self.road_containing(node_id) {
                self.group_for_sign(road, index, node.tags.get("direction"))
            } else {
                self.map.report.stop_nodes_unplaced.push(node_id);
                continue;
            };
            if groups.is_empty() {
                self.map.report.stop_nodes_unplaced.push(node_id);
            }
            for lanes in groups {
                self.add_stop_line(
                    kind,
                    StopLineSource::OsmNode { id: node_id },
                    lanes,
                    Some(p),
                );
            }
        }
    }

    /// Adds a stop line across `lanes` at the point nearest `at` (None: at their ends).
    fn add_stop_line(
        &mut self,
        kind: StopKind,
        source: StopLineSource,
        lanes: Vec<LaneId>,
        at: Option<Point>,
    ) {
        let Some(first) = lanes.first().and_then(|l| self.map.lanes.get(l)) else {
            return;
        };
        let s = at
            .map(|p| project_onto_polyline(&first.centre, p).0)
            .unwrap_or(first.length_m);
        let Some(line) = self.line_across(&lanes, Some(s)) else {
            return;
        };
        let id = StopLineId(self.map.stop_lines.len() as u32);
        self.map.stop_lines.insert(
            id,
            StopLine {
                id,
                kind,
                source,
                lanes,
                line,
                s_on_lane_m: s,
            },
        );
    }

    fn groups_arriving_at(&self, j: crate::model::JunctionId) -> Vec<Vec<LaneId>> {
        let mut groups: std::collections::BTreeMap<(RoadId, Direction), Vec<LaneId>> =
            Default::default();
        for lane in self.lanes_at(j) {
            let on_ring = self
                .map
                .roads
                .get(&lane.road)
                .is_some_and(|r| r.is_roundabout);
            if lane.to_junction == j && !on_ring {
                groups
                    .entry((lane.road, lane.direction))
                    .or_default()
                    .push(lane.id);
            }
        }
        groups.into_values().collect()
    }

    /// The road whose node list holds `node` strictly inside, and the node's index there.
    fn road_containing(&self, node: i64) -> Option<(RoadId, usize)> {
        self.info.iter().find_map(|(r, info)| {
            let i = info.nodes.iter().position(|n| *n == node)?;
            (i > 0 && i + 1 < info.nodes.len()).then_some((*r, i))
        })
    }

    fn group_for_sign(
        &self,
        road_id: RoadId,
        index: usize,
        direction: Option<&str>,
    ) -> Vec<Vec<LaneId>> {
        let (Some(road), Some(info)) = (self.map.roads.get(&road_id), self.info.get(&road_id))
        else {
            return Vec::new();
        };
        let dir = match direction {
            Some("forward") => Direction::Forward,
            Some("backward") => Direction::Backward,
            _ => {
                // Towards the nearer end, by node count along the way (cheap and good enough:
                // signs stand a few metres before the junction they guard).
                let to_end = info.nodes.len() - 1 - index;
                if to_end <= index {
                    Direction::Forward
                } else {
                    Direction::Backward
                }
            }
        };
        let lanes = match dir {
            Direction::Forward => road.lanes_forward.clone(),
            Direction::Backward => road.lanes_backward.clone(),
        };
        // A one-way road signed against its direction: the sign is for the lanes it has.
        let lanes = if lanes.is_empty() {
            road.lanes().collect()
        } else {
            lanes
        };
        vec![lanes]
    }
}
