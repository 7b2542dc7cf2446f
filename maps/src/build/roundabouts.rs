//! Step 6: roundabouts. Tagged rings (`junction=roundabout|circular`, closed or split over
//! many ways) are grouped by shared junctions; untagged near-circular one-way loops are
//! found geometrically and marked as guessed. Each gets its circulating cycle, its entries
//! and exits, and a give-way line on every entry where it meets the ring.

use std::collections::{BTreeMap, BTreeSet};
use std::f64::consts::PI;

use crate::geometry::{Point, polyline_length, signed_area};
use crate::model::{
    JunctionId, LaneId, RoadId, Roundabout, RoundaboutArm, RoundaboutId, RoundaboutSource,
    StopKind, StopLine, StopLineId, StopLineSource, Turn,
};

use super::select::Builder;

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

impl Builder<'_> {
    pub fn find_roundabouts(&mut self) {
        let tagged: Vec<RoadId> = self
            .map
            .roads
            .values()
            .filter(|r| r.is_roundabout)
            .map(|r| r.id)
            .collect();
        for ring in group_by_junctions(&self.map, &tagged) {
            self.add_roundabout(&ring, RoundaboutSource::Tagged);
        }
        if self.options.guess_roundabouts {
            for ring in self.untagged_loops() {
                self.add_roundabout(&ring, RoundaboutSource::Guessed);
            }
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
                    (*l != start, *turn != Turn::Straight, !same_index, *l)
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

    fn add_roundabout(&mut self, ring: &[RoadId], source: RoundaboutSource) {
        let Some(cycle) = self.lane_cycle(ring) else {
            let ways: Vec<i64> = ring
                .iter()
                .filter_map(|r| self.map.roads.get(r))
                .flat_map(|r| r.osm_way_ids.iter().copied())
                .collect();
            self.map.report.notes.push(format!("roundabout ways {ways:?}: the ring's lanes do not form one directed cycle; not imported as a roundabout"));
            return;
        };
        let id = RoundaboutId(self.map.roundabouts.len() as u32);
        let ring_set: BTreeSet<RoadId> = ring.iter().copied().collect();
        let ring_junctions: BTreeSet<JunctionId> = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .flat_map(|r| [r.start_junction, r.end_junction])
            .collect();
        let mut entries = Vec::new();
        let mut exits = Vec::new();
        for &j in &ring_junctions {
            let mut arms: BTreeMap<(RoadId, bool), Vec<LaneId>> = BTreeMap::new();
            for lane in self.lanes_at(j) {
                if ring_set.contains(&lane.road)
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
        let mut yield_lines = Vec::new();
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
        let ring_lanes: Vec<LaneId> = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .flat_map(|r| r.lanes())
            .collect();
        let lanes_across = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .map(|r| r.lanes_forward.len().max(r.lanes_backward.len()))
            .max()
            .unwrap_or(0) as u8;
        let mut osm_way_ids: Vec<i64> = ring
            .iter()
            .filter_map(|r| self.map.roads.get(r))
            .flat_map(|r| r.osm_way_ids.iter().copied())
            .collect();
        osm_way_ids.sort_unstable();
        osm_way_ids.dedup();
        self.map.roundabouts.insert(
            id,
            Roundabout {
                id,
                source,
                osm_way_ids,
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
    use crate::model::RoundaboutSource;
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
}
