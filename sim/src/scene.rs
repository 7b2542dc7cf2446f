//! A scene: a map plus the states of the road users on it at one instant.
//!
//! This is the only thing the bird's-eye renderer ([`crate::render`]) and the rerun logging
//! of the pipeline look at, so a recorded real log projected into the map frame renders
//! exactly like the simulator. Positions are in the map's metric frame (x east, y north).

use maps::geometry::closest_on_segment;
use maps::{LaneId, Map, Point};
use serde::{Deserialize, Serialize};

/// What kind of road user an actor is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActorKind {
    Car,
    Pedestrian,
}

/// One road user at one instant. `position` is the centre of its footprint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Actor {
    /// Stable over the actor's life; never reused within an episode.
    pub id: u32,
    pub kind: ActorKind,
    pub position: Point,
    /// Radians counter-clockwise from east.
    pub heading_rad: f64,
    pub speed_mps: f64,
    pub length_m: f64,
    pub width_m: f64,
    /// The lane it is on, when known (None in a junction or for a logged actor).
    pub lane: Option<LaneId>,
    /// The driver's style in [0, 1] (shorter accepted gaps, higher speed), when known.
    pub aggressiveness: Option<f64>,
}

impl Actor {
    /// The actor's footprint.
    pub fn footprint(&self) -> OrientedBox {
        OrientedBox::new(self.position, self.heading_rad, self.length_m, self.width_m)
    }
}

/// A rectangle with a heading: the footprint of a vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrientedBox {
    pub centre: Point,
    /// Unit vector along the length (the heading).
    pub axis: Point,
    pub half_length: f64,
    pub half_width: f64,
}

impl OrientedBox {
    pub fn new(centre: Point, heading_rad: f64, length: f64, width: f64) -> Self {
        let (sin, cos) = heading_rad.sin_cos();
        OrientedBox {
            centre,
            axis: Point::new(cos, sin),
            half_length: length / 2.0,
            half_width: width / 2.0,
        }
    }

    /// Corners counter-clockwise: front-right, front-left, rear-left, rear-right.
    pub fn corners(&self) -> [Point; 4] {
        let f = self.axis.scale(self.half_length);
        let l = self.axis.perp().scale(self.half_width);
        let c = self.centre;
        [
            c.add(f).sub(l),
            c.add(f).add(l),
            c.sub(f).add(l),
            c.sub(f).sub(l),
        ]
    }

    /// Half the extent along a unit direction `d` (projection radius).
    fn radius_along(&self, d: Point) -> f64 {
        self.half_length * self.axis.dot(d).abs() + self.half_width * self.axis.perp().dot(d).abs()
    }

    /// Whether two boxes overlap (separating axis test on the four edge normals).
    pub fn overlaps(&self, other: &OrientedBox) -> bool {
        let t = other.centre.sub(self.centre);
        [self.axis, self.axis.perp(), other.axis, other.axis.perp()]
            .iter()
            .all(|&d| t.dot(d).abs() <= self.radius_along(d) + other.radius_along(d))
    }

    /// Whether `p` lies inside the box (or on its edge).
    pub fn contains(&self, p: Point) -> bool {
        let d = p.sub(self.centre);
        d.dot(self.axis).abs() <= self.half_length
            && d.dot(self.axis.perp()).abs() <= self.half_width
    }

    /// Radius of the circle around the centre that holds the box.
    pub fn bounding_radius(&self) -> f64 {
        self.half_length.hypot(self.half_width)
    }

    /// Distance from `origin` along the unit direction `dir` to where the ray enters the
    /// box, if that is within `max` (0 when `origin` is inside). Slab test in the box frame.
    pub fn ray_distance(&self, origin: Point, dir: Point, max: f64) -> Option<f64> {
        let perp = self.axis.perp();
        let rel = origin.sub(self.centre);
        let (mut enter, mut exit) = (0.0_f64, max);
        for (axis, half) in [(self.axis, self.half_length), (perp, self.half_width)] {
            let (o, d) = (rel.dot(axis), dir.dot(axis));
            if d.abs() < 1e-12 {
                // Parallel to this slab: inside it everywhere or nowhere.
                if o.abs() > half {
                    return None;
                }
                continue;
            }
            let (t1, t2) = ((-half - o) / d, (half - o) / d);
            enter = enter.max(t1.min(t2));
            exit = exit.min(t1.max(t2));
            if enter > exit {
                return None;
            }
        }
        Some(enter)
    }

    /// The shortest distance between two boxes, 0 when they overlap. For disjoint convex
    /// polygons it is attained between a corner of one and an edge of the other.
    pub fn distance(&self, other: &OrientedBox) -> f64 {
        if self.overlaps(other) {
            return 0.0;
        }
        let corner_to_edges = |a: &OrientedBox, b: &OrientedBox| {
            let edges = b.corners();
            a.corners()
                .iter()
                .flat_map(|&p| {
                    (0..4).map(move |i| {
                        closest_on_segment(edges[i], edges[(i + 1) % 4], p)
                            .0
                            .distance(p)
                    })
                })
                .fold(f64::INFINITY, f64::min)
        };
        corner_to_edges(self, other).min(corner_to_edges(other, self))
    }
}

/// A map and its road users at one instant, from the point of view of one of them (the
/// ego), with the path the ego means to drive.
#[derive(Debug, Clone)]
pub struct Scene<'a> {
    pub map: &'a Map,
    pub time_s: f64,
    /// Every road user, the ego included.
    pub actors: Vec<Actor>,
    /// Index of the ego in `actors`.
    pub ego: usize,
    /// The ego's intended path (its route), in the map frame, in driving order.
    pub ego_path: &'a [Point],
}

impl Scene<'_> {
    pub fn ego_actor(&self) -> Option<&Actor> {
        self.actors.get(self.ego)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_overlap_and_separate() {
        let a = OrientedBox::new(Point::new(0.0, 0.0), 0.0, 4.0, 2.0);
        // Side by side with a 0.2 m gap.
        let b = OrientedBox::new(Point::new(0.0, 2.2), 0.0, 4.0, 2.0);
        assert!(!a.overlaps(&b));
        let c = OrientedBox::new(Point::new(0.0, 1.8), 0.0, 4.0, 2.0);
        assert!(a.overlaps(&c));
        // Rotated 45 degrees: its corner reaches 2.12 m along x from its centre.
        let d = OrientedBox::new(Point::new(3.9, 0.0), std::f64::consts::FRAC_PI_4, 3.0, 3.0);
        assert!(a.overlaps(&d));
        let e = OrientedBox::new(Point::new(4.2, 0.0), std::f64::consts::FRAC_PI_4, 3.0, 3.0);
        assert!(!e.overlaps(&a));
        // Corners of an east-facing box: front-right is east and south of the centre.
        let k = a.corners();
        assert_eq!(k[0], Point::new(2.0, -1.0));
        assert_eq!(k[2], Point::new(-2.0, 1.0));
    }

    #[test]
    fn rays_enter_boxes_and_boxes_have_gaps() {
        let b = OrientedBox::new(Point::new(10.0, 0.0), 0.0, 4.0, 2.0);
        let east = Point::new(1.0, 0.0);
        let hit = b.ray_distance(Point::new(0.0, 0.5), east, 40.0);
        assert!((hit.unwrap_or(f64::NAN) - 8.0).abs() < 1e-9, "{hit:?}");
        // Passing beside it, pointing away, or out of range.
        assert_eq!(b.ray_distance(Point::new(0.0, 1.5), east, 40.0), None);
        assert_eq!(
            b.ray_distance(Point::new(0.0, 0.0), east.scale(-1.0), 40.0),
            None
        );
        assert_eq!(b.ray_distance(Point::new(0.0, 0.0), east, 7.0), None);
        // Diagonal ray from (6, -2): misses the bottom face (x = 7 there), enters the rear
        // face at (8, 0).
        let diag = Point::new(1.0, 1.0).normalized();
        let d = b.ray_distance(Point::new(8.0, 0.0).sub(Point::new(2.0, 2.0)), diag, 40.0);
        assert!(
            (d.unwrap_or(f64::NAN) - 2.0 * 2f64.sqrt()).abs() < 1e-9,
            "{d:?}"
        );
        // Box to box: 1 m apart along x, then overlapping.
        let c = OrientedBox::new(Point::new(15.0, 0.0), 0.0, 4.0, 2.0);
        assert!((b.distance(&c) - 1.0).abs() < 1e-9);
        let e = OrientedBox::new(Point::new(14.0, 0.5), 0.3, 4.0, 2.0);
        assert_eq!(b.distance(&e), 0.0);
    }
}
