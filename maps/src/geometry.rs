//! Plane geometry in a map's metric frame: points, polylines, polygons.

use serde::{Deserialize, Serialize};

/// A position in metres: x east, y north (or x forward, y left in ego frames).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
}

// Plain methods rather than operator traits: `a.sub(b).dot(c)` reads left to right and needs
// no trait imports at every use.
#[allow(clippy::should_implement_trait)]
impl Point {
    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }
    pub fn distance(self, o: Point) -> f64 {
        (self.x - o.x).hypot(self.y - o.y)
    }
    pub fn sub(self, o: Point) -> Point {
        Point::new(self.x - o.x, self.y - o.y)
    }
    pub fn add(self, o: Point) -> Point {
        Point::new(self.x + o.x, self.y + o.y)
    }
    pub fn scale(self, s: f64) -> Point {
        Point::new(self.x * s, self.y * s)
    }
    pub fn dot(self, o: Point) -> f64 {
        self.x * o.x + self.y * o.y
    }
    pub fn cross(self, o: Point) -> f64 {
        self.x * o.y - self.y * o.x
    }
    pub fn norm(self) -> f64 {
        self.x.hypot(self.y)
    }
    /// Unit vector, or zero for the zero vector.
    pub fn normalized(self) -> Point {
        let n = self.norm();
        if n > 0.0 {
            self.scale(1.0 / n)
        } else {
            Point::default()
        }
    }
    /// Rotated a quarter turn counter-clockwise: the left normal of a direction.
    pub fn perp(self) -> Point {
        Point::new(-self.y, self.x)
    }
    pub fn lerp(self, o: Point, t: f64) -> Point {
        Point::new(self.x + (o.x - self.x) * t, self.y + (o.y - self.y) * t)
    }
    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite()
    }
}

/// Length of a polyline.
pub fn polyline_length(pts: &[Point]) -> f64 {
    pts.windows(2).map(|w| w[0].distance(w[1])).sum()
}

/// Drops consecutive points closer than `eps`; keeps the last point exact.
pub fn dedup_points(pts: &mut Vec<Point>, eps: f64) {
    if pts.len() < 2 {
        return;
    }
    let last = *pts.last().unwrap_or(&pts[0]);
    let mut out: Vec<Point> = Vec::with_capacity(pts.len());
    for &p in pts.iter() {
        if out.last().is_none_or(|q: &Point| q.distance(p) > eps) {
            out.push(p);
        }
    }
    if out.len() >= 2 && out[out.len() - 1].distance(last) > 0.0 {
        let n = out.len();
        out[n - 1] = last;
    }
    *pts = out;
}

/// The polyline shifted sideways by `offset` metres (positive = left of travel), with
/// mitred joins whose spikes are clamped to a few times the offset.
pub fn offset_polyline(pts: &[Point], offset: f64) -> Vec<Point> {
    let n = pts.len();
    if n < 2 || offset == 0.0 {
        return pts.to_vec();
    }
    let dirs: Vec<Point> = pts
        .windows(2)
        .map(|w| w[1].sub(w[0]).normalized())
        .collect();
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let normal = if i == 0 {
            dirs[0].perp()
        } else if i == n - 1 {
            dirs[n - 2].perp()
        } else {
            let (a, b) = (dirs[i - 1].perp(), dirs[i].perp());
            let m = a.add(b).normalized();
            let cos_half = m.dot(a);
            if cos_half < 0.25 {
                // A hairpin: a mitre would shoot far away; use the bisector at unit length.
                m
            } else {
                m.scale(1.0 / cos_half)
            }
        };
        out.push(pts[i].add(normal.scale(offset)));
    }
    out
}

/// The part of a polyline between arc lengths `from` and `to` (clamped).
pub fn slice_polyline(pts: &[Point], from: f64, to: f64) -> Vec<Point> {
    let total = polyline_length(pts);
    let (from, to) = (from.clamp(0.0, total), to.clamp(0.0, total));
    if pts.len() < 2 || to <= from {
        return vec![point_at(pts, from), point_at(pts, from)];
    }
    let mut out = vec![point_at(pts, from)];
    let mut s = 0.0;
    for w in pts.windows(2) {
        let seg = w[0].distance(w[1]);
        let end = s + seg;
        if end > from && end < to {
            out.push(w[1]);
        }
        s = end;
    }
    out.push(point_at(pts, to));
    out
}

/// The point at arc length `s` along a polyline (clamped to its ends).
pub fn point_at(pts: &[Point], s: f64) -> Point {
    let Some(&first) = pts.first() else {
        return Point::default();
    };
    if s <= 0.0 {
        return first;
    }
    let mut acc = 0.0;
    for w in pts.windows(2) {
        let seg = w[0].distance(w[1]);
        if acc + seg >= s && seg > 0.0 {
            return w[0].lerp(w[1], (s - acc) / seg);
        }
        acc += seg;
    }
    *pts.last().unwrap_or(&first)
}

/// Unit direction of travel at arc length `s`.
pub fn direction_at(pts: &[Point], s: f64) -> Point {
    let mut acc = 0.0;
    let mut last = Point::new(1.0, 0.0);
    for w in pts.windows(2) {
        let seg = w[0].distance(w[1]);
        if seg > 0.0 {
            last = w[1].sub(w[0]).scale(1.0 / seg);
            if acc + seg >= s {
                return last;
            }
        }
        acc += seg;
    }
    last
}

/// Closest point to `p` on segment `a`-`b`, and its parameter t in [0, 1] along it.
pub fn closest_on_segment(a: Point, b: Point, p: Point) -> (Point, f64) {
    let d = b.sub(a);
    let len2 = d.dot(d);
    let t = if len2 > 0.0 {
        (p.sub(a).dot(d) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a.add(d.scale(t)), t)
}

/// Closest point on a polyline: (arc length there, distance to it).
pub fn project_onto_polyline(pts: &[Point], p: Point) -> (f64, f64) {
    let mut best = (0.0, f64::INFINITY);
    let mut acc = 0.0;
    for w in pts.windows(2) {
        let (q, t) = closest_on_segment(w[0], w[1], p);
        let seg = w[0].distance(w[1]);
        let dist = q.distance(p);
        if dist < best.1 {
            best = (acc + t * seg, dist);
        }
        acc += seg;
    }
    best
}

/// Points every `step` metres along a polyline, both ends included.
pub fn resample(pts: &[Point], step: f64) -> Vec<Point> {
    let total = polyline_length(pts);
    let n = ((total / step).ceil() as usize).max(1);
    (0..=n)
        .map(|i| point_at(pts, total * i as f64 / n as f64))
        .collect()
}

/// Signed area (counter-clockwise positive) of a closed ring given without repeating the first point.
pub fn signed_area(ring: &[Point]) -> f64 {
    let n = ring.len();
    (0..n)
        .map(|i| ring[i].cross(ring[(i + 1) % n]))
        .sum::<f64>()
        / 2.0
}

/// Convex hull, counter-clockwise, without the closing point (Andrew's monotone chain).
pub fn convex_hull(points: &[Point]) -> Vec<Point> {
    let mut pts: Vec<Point> = points.iter().copied().filter(|p| p.is_finite()).collect();
    pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let mut hull: Vec<Point> = Vec::with_capacity(pts.len() * 2);
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &Point>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2 {
                let (a, b) = (hull[hull.len() - 2], hull[hull.len() - 1]);
                if b.sub(a).cross(p.sub(a)) <= 0.0 {
                    hull.pop();
                } else {
                    break;
                }
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

/// Axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Bounds {
    pub min: Point,
    pub max: Point,
}

impl Bounds {
    pub fn empty() -> Self {
        Bounds {
            min: Point::new(f64::INFINITY, f64::INFINITY),
            max: Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY),
        }
    }
    pub fn extend(&mut self, p: Point) {
        self.min.x = self.min.x.min(p.x);
        self.min.y = self.min.y.min(p.y);
        self.max.x = self.max.x.max(p.x);
        self.max.y = self.max.y.max(p.y);
    }
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }
    pub fn width(&self) -> f64 {
        self.max.x - self.min.x
    }
    pub fn height(&self) -> f64 {
        self.max.y - self.min.y
    }
    pub fn center(&self) -> Point {
        self.min.lerp(self.max, 0.5)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn offset_of_a_straight_line_is_parallel() {
        let line = [
            Point::new(0.0, 0.0),
            Point::new(10.0, 0.0),
            Point::new(20.0, 0.0),
        ];
        let left = offset_polyline(&line, 2.0);
        assert!(left.iter().all(|p| (p.y - 2.0).abs() < 1e-12));
        let right = offset_polyline(&line, -1.5);
        assert!(right.iter().all(|p| (p.y + 1.5).abs() < 1e-12));
    }

    #[test]
    fn offset_keeps_distance_at_a_right_angle_corner() {
        let line = [
            Point::new(0.0, 0.0),
            Point::new(10.0, 0.0),
            Point::new(10.0, 10.0),
        ];
        let left = offset_polyline(&line, 1.0);
        // Mitre corner of a left turn lies inside: (9, 1).
        assert!(left[1].distance(Point::new(9.0, 1.0)) < 1e-12);
    }

    #[test]
    fn hull_of_square_with_inner_point() {
        let pts = [
            Point::new(0.0, 0.0),
            Point::new(1.0, 0.0),
            Point::new(1.0, 1.0),
            Point::new(0.0, 1.0),
            Point::new(0.5, 0.5),
        ];
        let hull = convex_hull(&pts);
        assert_eq!(hull.len(), 4);
        assert!((signed_area(&hull) - 1.0).abs() < 1e-12);
    }

    proptest! {
        #[test]
        fn slice_lengths_add_up(xs in proptest::collection::vec((-100.0f64..100.0, -100.0f64..100.0), 2..12), cut in 0.0f64..1.0) {
            let pts: Vec<Point> = xs.into_iter().map(|(x, y)| Point::new(x, y)).collect();
            let total = polyline_length(&pts);
            let a = slice_polyline(&pts, 0.0, total * cut);
            let b = slice_polyline(&pts, total * cut, total);
            prop_assert!((polyline_length(&a) + polyline_length(&b) - total).abs() < 1e-6 * total.max(1.0));
        }

        #[test]
        fn projection_onto_polyline_finds_its_own_points(xs in proptest::collection::vec((-100.0f64..100.0, -100.0f64..100.0), 2..12), t in 0.0f64..1.0) {
            let pts: Vec<Point> = xs.into_iter().map(|(x, y)| Point::new(x, y)).collect();
            let s = polyline_length(&pts) * t;
            let p = point_at(&pts, s);
            let (_, d) = project_onto_polyline(&pts, p);
            prop_assert!(d < 1e-6);
        }
    }
}
