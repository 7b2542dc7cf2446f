//! Step 0, on the OSM data: every `highway=mini_roundabout` node becomes a small ring.
//!
//! A mini-roundabout is mapped as one node where the roads meet, but it is driven round a
//! painted (or slightly raised) centre. Before any road is made, each such node is replaced
//! by a closed one-way way of one lane round it, [`MINI_RING_RADIUS_M`] from the node (more
//! round wide roads, less where another junction is closer), turning the way traffic turns round a roundabout on
//! this side of the road; the ways that met at the node are cut where they reach that
//! circle. The rest of the import then treats it as any ring (lanes, connections, yield
//! lines on its entries), and `find_mini_roundabouts` marks it as a mini-roundabout with its
//! node. The ways made here carry ids below every id of the file; they never reach the
//! finished map (`forget_made_ways`).
//!
//! A node that cannot be made into a ring (an arm shorter than the smallest circle, another
//! junction right next to it, the node on a ring way) stays an ordinary junction and is
//! listed with the reason.

use std::collections::{BTreeMap, BTreeSet};

use crate::geometry::Point;
use crate::model::{DrivingSide, RingProblem};
use crate::osm::{OsmData, OsmNode, OsmWay, Tags};
use crate::projection::Projection;
use crate::tags;

use crate::options::ImportOptions;

/// Radius of the circle driven round a mini-roundabout node (the centre line of its one
/// lane), m: a small island of 2-4 m and a lane round it; at least 2 m more than half the
/// widest carriageway meeting there.
pub const MINI_RING_RADIUS_M: f64 = 6.0;
/// The circle shrinks to keep clear of another junction, but not below this radius, nor
/// below 1 m more than half the widest carriageway, m.
pub const MIN_MINI_RING_RADIUS_M: f64 = 4.0;
/// Largest angle between two nodes of a ring way, degrees (its pieces are polylines).
const MAX_STEP_DEG: f64 = 20.0;
/// Arms reaching the circle closer together than this share one node of the ring, m.
const SAME_CROSSING_M: f64 = 0.5;

/// The OSM data with its mini-roundabout nodes made into rings.
#[derive(Debug)]
pub(crate) struct MiniRings {
    pub osm: OsmData,
    /// Ring way made here -> the mini-roundabout node it goes round.
    pub ring_of_way: BTreeMap<i64, i64>,
    /// Way made here for a later part of a way cut at a node -> the way it comes from.
    pub part_of: BTreeMap<i64, i64>,
    /// Mini-roundabout nodes on the profile's roads left as ordinary junctions, with why.
    pub problems: Vec<RingProblem>,
}

impl MiniRings {
    /// The way an imported road comes from: the original of a part made here.
    pub fn original_way(&self, way: i64) -> i64 {
        self.part_of.get(&way).copied().unwrap_or(way)
    }

    /// Whether `way` was made here (a ring or a part of a cut way).
    pub fn is_made(&self, way: i64) -> bool {
        self.ring_of_way.contains_key(&way) || self.part_of.contains_key(&way)
    }
}

/// One way's stretch between mini-roundabout nodes, as node indices into the way
/// (inclusive), with whether each end is at the node.
struct Stretch {
    from: usize,
    to: usize,
    starts_at_node: bool,
    ends_at_node: bool,
}

/// Where an arm reaches the circle: the kept nodes of its way, nearest the node last.
struct Crossing {
    way: i64,
    stretch: usize,
    /// True for the stretch's start (the arm leaves the node), false for its end.
    at_start: bool,
    /// Index into the way's nodes of the last node kept outside the circle.
    kept: usize,
    /// The crossing in metres from the node.
    at: (f64, f64),
}

/// Makes a ring of every mini-roundabout node on the profile's roads. `None` when the data
/// has none (the data is then used as it is, without a copy).
pub(crate) fn ring_mini_roundabouts(osm: &OsmData, options: &ImportOptions) -> Option<MiniRings> {
    let minis: BTreeSet<i64> = osm
        .nodes
        .iter()
        .filter(|(_, n)| n.tags.is("highway", "mini_roundabout"))
        .map(|(&id, _)| id)
        .collect();
    if minis.is_empty() {
        return None;
    }
    // The profile's complete ways through each node, and how many such ways use each node.
    let mut through: BTreeMap<i64, Vec<i64>> = BTreeMap::new();
    let mut uses: BTreeMap<i64, u32> = BTreeMap::new();
    let mut ends: BTreeSet<i64> = BTreeSet::new();
    for (&id, way) in &osm.ways {
        if !options.profile.selects(&way.tags)
            || way.nodes.iter().any(|n| !osm.nodes.contains_key(n))
        {
            continue;
        }
        for n in &way.nodes {
            *uses.entry(*n).or_default() += 1;
            if minis.contains(n) && through.get(n).is_none_or(|w| w.last() != Some(&id)) {
                through.entry(*n).or_default().push(id);
            }
        }
        if let (Some(a), Some(b)) = (way.nodes.first(), way.nodes.last()) {
            ends.insert(*a);
            ends.insert(*b);
        }
    }
    if through.is_empty() {
        return None;
    }
    let mut out = MiniRings {
        osm: osm.clone(),
        ring_of_way: BTreeMap::new(),
        part_of: BTreeMap::new(),
        problems: Vec::new(),
    };
    let lowest = osm
        .nodes
        .keys()
        .next()
        .copied()
        .unwrap_or(0)
        .min(osm.ways.keys().next().copied().unwrap_or(0))
        .min(0);
    let mut next_id = lowest - 1;
    let mut new_id = || {
        let id = next_id;
        next_id -= 1;
        id
    };
    let nodes: Vec<i64> = through.keys().copied().collect();
    for node in nodes {
        let ways = through.get(&node).cloned().unwrap_or_default();
        match ring_one(&mut out, options, node, &ways, &uses, &ends, &mut new_id) {
            Ok(made) => {
                // Later nodes on a cut way now lie on one of its parts; the ring's nodes
                // are junctions too.
                for (way, parts) in made.parts {
                    for (part, part_nodes) in parts {
                        for n in part_nodes.iter().filter(|n| **n != node) {
                            if let Some(list) = through.get_mut(n) {
                                for w in list.iter_mut().filter(|w| **w == way) {
                                    *w = part;
                                }
                                if !list.contains(&part) {
                                    list.push(part);
                                }
                            }
                        }
                    }
                }
                ends.extend(made.ring_nodes);
            }
            Err(reason) => out.problems.push(RingProblem {
                osm_way_ids: Vec::new(),
                osm_node_id: Some(node),
                reason: format!(
                    "mini-roundabout node {node}: {reason}; driven as an ordinary junction"
                ),
                imported: false,
            }),
        }
    }
    Some(out)
}

/// What making one ring changed: per way cut, its parts (id and nodes), and the ring's
/// nodes.
/// A way's parts after a cut: each part's way id and nodes.
type Parts = Vec<(i64, Vec<i64>)>;

struct Made {
    parts: Vec<(i64, Parts)>,
    ring_nodes: Vec<i64>,
}

/// Makes the ring of one node in `out.osm`; nothing changes when it cannot.
fn ring_one(
    out: &mut MiniRings,
    options: &ImportOptions,
    node: i64,
    ways: &[i64],
    uses: &BTreeMap<i64, u32>,
    ends: &BTreeSet<i64>,
    new_id: &mut impl FnMut() -> i64,
) -> Result<Made, String> {
    let osm = &out.osm;
    let centre = osm.nodes[&node].pos;
    let projection = Projection::local(centre);
    let xy = |n: i64| -> (f64, f64) {
        let p = projection.project(osm.nodes[&n].pos);
        (p.x, p.y)
    };
    if let Some(w) = ways.iter().find(|w| tags::is_roundabout(&osm.ways[w].tags)) {
        return Err(format!("it lies on the ring way {w}"));
    }
    // The circle clears the widest carriageway meeting there by a metre or two, and keeps
    // clear of every other junction or way end.
    let half_width = ways
        .iter()
        .map(|w| {
            let t = &osm.ways[w].tags;
            let highway = t.get("highway").unwrap_or("road");
            let (f, b) = tags::lane_counts(t, highway);
            f64::from(f + b) * tags::lane_width(t, highway, f + b) / 2.0
        })
        .fold(0.0, f64::max);
    let smallest = MIN_MINI_RING_RADIUS_M.max(half_width + 1.0);
    let mut radius = MINI_RING_RADIUS_M.max(half_width + 2.0);
    for w in ways {
        for &n in &osm.ways[w].nodes {
            if n == node || !(uses.get(&n).is_some_and(|&u| u >= 2) || ends.contains(&n)) {
                continue;
            }
            let (x, y) = xy(n);
            let d = x.hypot(y);
            if d < radius / 0.8 {
                radius = radius.min(0.8 * d);
            }
        }
    }
    if radius < smallest {
        return Err(format!(
            "another junction or way end lies within {:.1} m of it",
            radius / 0.8
        ));
    }
    // Every stretch of every way, cut where it reaches the circle.
    let mut crossings: Vec<Crossing> = Vec::new();
    let mut stretches: BTreeMap<i64, Vec<Stretch>> = BTreeMap::new();
    for &w in ways {
        let nodes = &osm.ways[&w].nodes;
        let at: Vec<usize> = (0..nodes.len()).filter(|&i| nodes[i] == node).collect();
        let mut cuts: Vec<usize> = vec![0];
        cuts.extend(at.iter().copied());
        cuts.push(nodes.len() - 1);
        cuts.dedup();
        let mut list = Vec::new();
        for pair in cuts.windows(2) {
            let (from, to) = (pair[0], pair[1]);
            if from == to {
                continue;
            }
            let stretch = Stretch {
                from,
                to,
                starts_at_node: nodes[from] == node,
                ends_at_node: nodes[to] == node,
            };
            let index = list.len();
            for at_start in [true, false] {
                let at_node = if at_start {
                    stretch.starts_at_node
                } else {
                    stretch.ends_at_node
                };
                if !at_node {
                    continue;
                }
                // Walk away from the node to the first node outside the circle.
                let order: Vec<usize> = if at_start {
                    (from..=to).collect()
                } else {
                    (from..=to).rev().collect()
                };
                let Some(k) = order.iter().position(|&i| {
                    let (x, y) = xy(nodes[i]);
                    x.hypot(y) > radius
                }) else {
                    return Err(format!("way {w} ends within {radius:.1} m of it"));
                };
                let (inside, outside) = (xy(nodes[order[k - 1]]), xy(nodes[order[k]]));
                crossings.push(Crossing {
                    way: w,
                    stretch: index,
                    at_start,
                    kept: order[k],
                    at: circle_crossing(inside, outside, radius),
                });
            }
            list.push(stretch);
        }
        stretches.insert(w, list);
    }
    // A stretch whose two ends both reach the node (a loop back to it) needs its kept nodes
    // in the right order; a stretch cut away entirely is refused above.
    for (w, list) in &stretches {
        for (i, s) in list.iter().enumerate() {
            let kept: Vec<&Crossing> = crossings
                .iter()
                .filter(|c| c.way == *w && c.stretch == i)
                .collect();
            let first = kept.iter().find(|c| c.at_start).map_or(s.from, |c| c.kept);
            let last = kept.iter().find(|c| !c.at_start).map_or(s.to, |c| c.kept);
            if first > last {
                return Err(format!("way {w} turns back within the circle round it"));
            }
        }
    }
    // The ring's nodes: one per crossing (crossings close together share one), and more
    // between them so no piece turns more than MAX_STEP_DEG; in the direction traffic goes
    // round on this side of the road.
    let side = options
        .driving_side
        .unwrap_or_else(|| tags::driving_side_at(centre));
    let counterclockwise = side == DrivingSide::Right;
    let angle = |(x, y): (f64, f64)| y.atan2(x).rem_euclid(std::f64::consts::TAU);
    let mut on_ring: Vec<(f64, i64)> = Vec::new();
    let mut node_of_crossing: Vec<i64> = Vec::with_capacity(crossings.len());
    for c in &crossings {
        let a = angle(c.at);
        let near = on_ring.iter().find(|(b, _)| {
            let d = (a - b).abs().min(std::f64::consts::TAU - (a - b).abs());
            d * radius < SAME_CROSSING_M
        });
        let id = match near {
            Some(&(_, id)) => id,
            None => {
                let id = new_id();
                on_ring.push((a, id));
                id
            }
        };
        node_of_crossing.push(id);
    }
    on_ring.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut ring_nodes: Vec<(f64, Option<i64>)> = Vec::new();
    for (i, &(a, id)) in on_ring.iter().enumerate() {
        ring_nodes.push((a, Some(id)));
        let next = on_ring
            .get(i + 1)
            .map_or(on_ring[0].0 + std::f64::consts::TAU, |n| n.0);
        let gap = next - a;
        let steps = (gap.to_degrees() / MAX_STEP_DEG).ceil().max(1.0) as usize;
        for k in 1..steps {
            ring_nodes.push((a + gap * k as f64 / steps as f64, None));
        }
    }
    if !counterclockwise {
        ring_nodes.reverse();
    }
    let class = ring_class(osm, ways).to_owned();
    let name = osm.nodes[&node].tags.get("name").map(str::to_owned);
    let way_data: BTreeMap<i64, (Vec<i64>, Tags)> = ways
        .iter()
        .map(|w| (*w, (osm.ways[w].nodes.clone(), osm.ways[w].tags.clone())))
        .collect();
    // Write it all: new nodes, the ring way, the cut ways.
    let mut ring_ids: Vec<i64> = Vec::with_capacity(ring_nodes.len() + 1);
    for (a, id) in ring_nodes {
        let id = id.unwrap_or_else(&mut *new_id);
        let pos = projection.unproject(Point::new(radius * a.cos(), radius * a.sin()));
        out.osm.nodes.insert(
            id,
            OsmNode {
                pos,
                tags: Tags::default(),
            },
        );
        ring_ids.push(id);
    }
    let made_ring_nodes = ring_ids.clone();
    ring_ids.push(ring_ids[0]);
    let ring_way = new_id();
    let mut ring_tags = Tags::from_pairs(&[
        ("highway", class.as_str()),
        ("junction", "roundabout"),
        ("lanes", "1"),
    ]);
    if let Some(name) = name {
        ring_tags.insert("name".into(), name);
    }
    out.osm.ways.insert(
        ring_way,
        OsmWay {
            nodes: ring_ids,
            tags: ring_tags,
        },
    );
    out.ring_of_way.insert(ring_way, node);
    let mut made = Made {
        parts: Vec::new(),
        ring_nodes: made_ring_nodes,
    };
    for (w, list) in stretches {
        let original = out.original_way(w);
        let (nodes, tags) = &way_data[&w];
        let mut parts: Vec<Vec<i64>> = Vec::new();
        for (i, s) in list.iter().enumerate() {
            let mut part = Vec::new();
            let start = crossings
                .iter()
                .zip(&node_of_crossing)
                .find(|(c, _)| c.way == w && c.stretch == i && c.at_start);
            let end = crossings
                .iter()
                .zip(&node_of_crossing)
                .find(|(c, _)| c.way == w && c.stretch == i && !c.at_start);
            let first = start.map_or(s.from, |(c, _)| c.kept);
            let last = end.map_or(s.to, |(c, _)| c.kept);
            if let Some((_, &id)) = start {
                part.push(id);
            }
            part.extend_from_slice(&nodes[first..=last]);
            if let Some((_, &id)) = end {
                part.push(id);
            }
            parts.push(part);
        }
        // The first part keeps the way's id; the others get new ones, traced back to it.
        let mut cut = Vec::new();
        for (i, part) in parts.into_iter().enumerate() {
            let id = if i == 0 { w } else { new_id() };
            if i > 0 {
                out.part_of.insert(id, original);
            }
            cut.push((id, part.clone()));
            out.osm.ways.insert(
                id,
                OsmWay {
                    nodes: part,
                    tags: tags.clone(),
                },
            );
        }
        made.parts.push((w, cut));
    }
    Ok(made)
}

/// The point at distance `r` from the origin on the segment from `inside` (within `r`) to
/// `outside` (beyond it).
fn circle_crossing(inside: (f64, f64), outside: (f64, f64), r: f64) -> (f64, f64) {
    let (dx, dy) = (outside.0 - inside.0, outside.1 - inside.1);
    let a = dx * dx + dy * dy;
    let b = 2.0 * (inside.0 * dx + inside.1 * dy);
    let c = inside.0 * inside.0 + inside.1 * inside.1 - r * r;
    let t = if a > 0.0 {
        ((-b + (b * b - 4.0 * a * c).max(0.0).sqrt()) / (2.0 * a)).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (inside.0 + t * dx, inside.1 + t * dy)
}

/// The ring's `highway` class: the most important of the ways meeting at the node.
fn ring_class<'a>(osm: &'a OsmData, ways: &[i64]) -> &'a str {
    const ORDER: [&str; 10] = [
        "motorway",
        "trunk",
        "primary",
        "secondary",
        "tertiary",
        "unclassified",
        "residential",
        "living_street",
        "service",
        "road",
    ];
    let rank = |h: &str| ORDER.iter().position(|o| h == *o).unwrap_or(ORDER.len());
    ways.iter()
        .filter_map(|w| osm.ways[w].tags.get("highway"))
        .map(|h| h.strip_suffix("_link").unwrap_or(h))
        .min_by_key(|h| rank(h))
        .unwrap_or("residential")
}
