//! Paths that vehicles drive: a chain of lanes and connections, sampled at equal steps,
//! with the speed a driver would choose along it (speed limit, and curvature at a lateral
//! acceleration limit, anticipated by comfortable braking).

use maps::geometry::{closest_on_segment, polyline_length};
use maps::{ConnectionId, LaneId, Map, Point};

/// Spacing of a path's samples, metres.
pub const SAMPLE_SPACING_M: f64 = 0.5;

/// What one piece of a path runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum PieceKey {
    Lane(LaneId),
    Connection(ConnectionId),
}

/// One lane or connection of a path, with where it starts and ends along the path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Piece {
    pub key: PieceKey,
    pub s_start: f64,
    pub s_end: f64,
}

/// How drivers drive a path: the line they take and the speeds they pick along it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedProfile {
    /// Lateral acceleration a driver accepts in curves, m/s².
    pub lateral_accel_mps2: f64,
    /// Deceleration used to slow down ahead of a curve, m/s².
    pub anticipation_decel_mps2: f64,
    /// Where the mapped line turns tighter than this radius (lane graphs of small
    /// roundabouts join entry, ring and exit with kinks no car can steer), drivers round
    /// it off: the path is smoothed there until it does not, moving no point more than
    /// [`MAX_ROUNDING_M`]; a path that needs more is not drivable (no path). m; 0 keeps
    /// the mapped line.
    pub min_turn_radius_m: f64,
}

impl Default for SpeedProfile {
    fn default() -> Self {
        SpeedProfile {
            lateral_accel_mps2: 2.5,
            anticipation_decel_mps2: 1.5,
            min_turn_radius_m: 0.0,
        }
    }
}

/// Most smoothing passes spent on one path's kinks.
const MAX_SMOOTHING_PASSES: usize = 400;
/// The farthest rounding moves a point of the mapped line, m: drivers round kinks off
/// within their lane, they do not take another road.
const MAX_ROUNDING_M: f64 = 2.0;
/// Samples on either side over which a path's turning is measured (1.5 m).
const KINK_WINDOW: usize = 3;

/// Rounds off the points of `line` where it turns tighter than `min_radius_m` (ends kept):
/// repeated neighbour averaging of those points and the window around them, until no point
/// turns too tightly or [`MAX_SMOOTHING_PASSES`] is reached.
fn round_off_kinks(line: &mut [Point], min_radius_m: f64) -> Rounding {
    let n = line.len();
    if n < 3 || min_radius_m <= 0.0 {
        return Rounding::Untouched;
    }
    let mapped = line.to_vec();
    let mut marked = vec![false; n];
    let mut next = line.to_vec();
    for pass in 0..MAX_SMOOTHING_PASSES {
        marked.iter_mut().for_each(|m| *m = false);
        let mut any = false;
        for i in 1..n - 1 {
            // Turning per metre between the chords to the points KINK_WINDOW before and
            // after: a mapped polygon's corners (a ring drawn with a few nodes) spread over
            // the window and pass; a kink does not.
            let (before, after) = (i.saturating_sub(KINK_WINDOW), (i + KINK_WINDOW).min(n - 1));
            let (a, b) = (line[i].sub(line[before]), line[after].sub(line[i]));
            let turn = wrap_angle(b.y.atan2(b.x) - a.y.atan2(a.x)).abs();
            if turn * 2.0 > (a.norm() + b.norm()) / min_radius_m {
                any = true;
                for m in &mut marked[before.max(1)..after] {
                    *m = true;
                }
            }
        }
        if !any {
            return if pass > 0 {
                Rounding::Rounded
            } else {
                Rounding::Untouched
            };
        }
        for i in 1..n - 1 {
            next[i] = if marked[i] {
                let averaged = line[i - 1]
                    .add(line[i + 1])
                    .scale(0.25)
                    .add(line[i].scale(0.5));
                // Never farther than MAX_ROUNDING_M from the mapped line.
                let moved = averaged.sub(mapped[i]);
                let d = moved.norm();
                if d > MAX_ROUNDING_M {
                    mapped[i].add(moved.scale(MAX_ROUNDING_M / d))
                } else {
                    averaged
                }
            } else {
                line[i]
            };
        }
        line[1..n - 1].copy_from_slice(&next[1..n - 1]);
    }
    Rounding::TooTight
}

/// What [`round_off_kinks`] did to a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Rounding {
    /// No kink: the mapped line as it was.
    Untouched,
    /// Kinks rounded off to the radius.
    Rounded,
    /// A turn too tight to round off within [`MAX_ROUNDING_M`] of the line.
    TooTight,
}

/// Length along `line` from its start to each of its points.
fn cumulative_lengths(line: &[Point]) -> Vec<f64> {
    let mut along = Vec::with_capacity(line.len());
    let mut total = 0.0;
    along.push(0.0);
    for w in line.windows(2) {
        total += w[0].distance(w[1]);
        along.push(total);
    }
    along
}

/// A drivable path: its pieces, its samples and its speed profile.
#[derive(Debug, Clone)]
pub struct Path {
    pieces: Vec<Piece>,
    points: Vec<Point>,
    headings: Vec<f64>,
    /// The speed a nominal driver aims for at each sample, m/s.
    speeds: Vec<f64>,
    spacing: f64,
    length: f64,
    /// The path's shape with nearly straight runs merged, for drawing.
    outline: Vec<Point>,
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let w = a.rem_euclid(t);
    if w > std::f64::consts::PI { w - t } else { w }
}

impl Path {
    /// Builds a path over `keys` (each lane followed by the connection that leaves it, and so
    /// on), starting `trim_start_m` into the first piece and ending after `max_length_m` at
    /// most (later pieces dropped, the last one cut). Returns None when a key is missing
    /// from the map, the path has no length, or it turns too tightly to be driven (see
    /// [`SpeedProfile::min_turn_radius_m`]).
    pub fn new(
        map: &Map,
        keys: &[PieceKey],
        trim_start_m: f64,
        max_length_m: f64,
        profile: SpeedProfile,
    ) -> Option<Path> {
        let mut geometry: Vec<(PieceKey, Vec<Point>, f64)> = Vec::with_capacity(keys.len());
        for (i, key) in keys.iter().enumerate() {
            let (pts, limit_kmh) = match key {
                PieceKey::Lane(id) => {
                    let lane = map.lanes.get(id)?;
                    (lane.centre.clone(), lane.speed_limit_kmh)
                }
                PieceKey::Connection(id) => {
                    let c = map.connections.get(id)?;
                    let limit = map.lanes.get(&c.from).map_or(0.0, |l| l.speed_limit_kmh);
                    (c.centre.clone(), limit)
                }
            };
            let pts = if i == 0 && trim_start_m > 0.0 {
                maps::geometry::slice_polyline(&pts, trim_start_m, polyline_length(&pts))
            } else {
                pts
            };
            geometry.push((*key, pts, maps::graph::lane_speed_mps(limit_kmh)));
        }
        let mut total = 0.0;
        for k in 0..geometry.len() {
            let len = polyline_length(&geometry[k].1);
            if total + len >= max_length_m {
                geometry[k].1 =
                    maps::geometry::slice_polyline(&geometry[k].1, 0.0, max_length_m - total);
                geometry.truncate(k + 1);
                break;
            }
            total += len;
        }
        Self::from_geometry(&geometry, profile)
    }

    /// Builds a path from explicit piece geometry: (key, centre line, speed limit m/s).
    pub fn from_geometry(
        geometry: &[(PieceKey, Vec<Point>, f64)],
        profile: SpeedProfile,
    ) -> Option<Path> {
        let mut pieces = Vec::with_capacity(geometry.len());
        let mut s = 0.0;
        for (key, pts, _) in geometry {
            let len = polyline_length(pts);
            pieces.push(Piece {
                key: *key,
                s_start: s,
                s_end: s + len,
            });
            s += len;
        }
        let mut length = s;
        if !(length > 0.0 && length.is_finite()) {
            return None;
        }
        let refs: Vec<(&[Point], Option<LaneId>)> = geometry
            .iter()
            .map(|(_, p, _)| (p.as_slice(), None))
            .collect();
        let mut samples = maps::route::waypoints(&refs, SAMPLE_SPACING_M);
        if samples.len() < 2 {
            return None;
        }
        if profile.min_turn_radius_m > 0.0 {
            let mut line: Vec<Point> = samples.iter().map(|w| w.position).collect();
            let rounding = round_off_kinks(&mut line, profile.min_turn_radius_m);
            if rounding == Rounding::TooTight {
                return None;
            } else if rounding == Rounding::Rounded {
                // The rounded line is shorter: measure the pieces on it, and sample it again.
                let old_spacing = length / (samples.len() - 1) as f64;
                let along = cumulative_lengths(&line);
                let on_new_line = |s: f64| {
                    let x = (s / old_spacing).clamp(0.0, (line.len() - 1) as f64);
                    let i = (x.floor() as usize).min(line.len() - 2);
                    along[i] + (along[i + 1] - along[i]) * (x - i as f64)
                };
                for piece in &mut pieces {
                    piece.s_start = on_new_line(piece.s_start);
                    piece.s_end = on_new_line(piece.s_end);
                }
                length = along[along.len() - 1];
                samples = maps::route::waypoints(&[(line.as_slice(), None)], SAMPLE_SPACING_M);
                if samples.len() < 2 {
                    return None;
                }
            }
        }
        let n = samples.len();
        let spacing = length / (n - 1) as f64;
        let points: Vec<Point> = samples.iter().map(|w| w.position).collect();
        let headings: Vec<f64> = samples.iter().map(|w| w.heading_rad).collect();
        let speeds = speed_profile(&samples, &pieces, geometry, spacing, profile);
        let outline = simplify(&points, &headings);
        Some(Path {
            pieces,
            points,
            headings,
            speeds,
            spacing,
            length,
            outline,
        })
    }

    pub fn length(&self) -> f64 {
        self.length
    }

    pub fn pieces(&self) -> &[Piece] {
        &self.pieces
    }

    /// The path's shape for drawing (nearly straight runs merged).
    pub fn outline(&self) -> &[Point] {
        &self.outline
    }

    /// Sample index below `s` and the fraction towards the next one.
    fn locate(&self, s: f64) -> (usize, f64) {
        let x = (s / self.spacing).clamp(0.0, (self.points.len() - 1) as f64);
        let i = (x.floor() as usize).min(self.points.len() - 2);
        (i, x - i as f64)
    }

    /// Position and heading at arc length `s` (clamped to the path).
    pub fn pose_at(&self, s: f64) -> (Point, f64) {
        let (i, t) = self.locate(s);
        let p = self.points[i].lerp(self.points[i + 1], t);
        let (h0, h1) = (self.headings[i], self.headings[i + 1]);
        (p, h0 + wrap_angle(h1 - h0) * t)
    }

    /// The nominal driver's speed at `s`: speed limit and curves, m/s.
    pub fn speed_at(&self, s: f64) -> f64 {
        let (i, t) = self.locate(s);
        self.speeds[i] + (self.speeds[i + 1] - self.speeds[i]) * t
    }

    /// Time to drive from `from` to `to` at the nominal speed profile, s.
    pub fn travel_time(&self, from: f64, to: f64) -> f64 {
        let n = ((to - from) / self.spacing).ceil().max(0.0) as usize;
        let ds = (to - from) / n.max(1) as f64;
        (0..n)
            .map(|k| ds / self.speed_at(from + (k as f64 + 0.5) * ds).max(0.5))
            .sum()
    }

    /// The samples between arc lengths `from` and `to`.
    pub fn samples_between(&self, from: f64, to: f64) -> &[Point] {
        let last = self.points.len() - 1;
        let i0 = ((from / self.spacing).floor().max(0.0) as usize).min(last);
        let i1 = ((to / self.spacing).ceil().max(0.0) as usize).min(last);
        &self.points[i0..=i1.max(i0)]
    }

    /// Index of the piece holding `s`, searching forward from `hint`.
    pub fn piece_at(&self, s: f64, hint: usize) -> usize {
        let mut i = hint.min(self.pieces.len() - 1);
        while i > 0 && s < self.pieces[i].s_start {
            i -= 1;
        }
        while i + 1 < self.pieces.len() && s >= self.pieces[i].s_end {
            i += 1;
        }
        i
    }

    /// Arc length of the point of the path nearest to `p`, looking only between
    /// `s_hint - behind` and `s_hint + ahead`; and the distance to it.
    pub fn project(&self, p: Point, s_hint: f64, behind: f64, ahead: f64) -> (f64, f64) {
        let last = self.points.len() - 1;
        let i0 = ((s_hint - behind) / self.spacing).floor().max(0.0) as usize;
        let i1 = (((s_hint + ahead) / self.spacing).ceil().max(0.0) as usize).min(last);
        let mut best = (s_hint.clamp(0.0, self.length), f64::INFINITY);
        for i in i0.min(last.saturating_sub(1))..i1.max(1) {
            let (q, t) = closest_on_segment(self.points[i], self.points[i + 1], p);
            let d = q.distance(p);
            if d < best.1 {
                best = (((i as f64) + t) * self.spacing, d);
            }
        }
        best
    }
}

/// Speed at each sample: the lower of the piece's limit and the curve speed, lowered ahead
/// of slow stretches so a driver braking at `anticipation_decel` gets there in time.
fn speed_profile(
    samples: &[maps::route::Waypoint],
    pieces: &[Piece],
    geometry: &[(PieceKey, Vec<Point>, f64)],
    spacing: f64,
    profile: SpeedProfile,
) -> Vec<f64> {
    let n = samples.len();
    // Curvature averaged over about 3 m: joints between pieces show up as one-sample spikes.
    let half = ((1.5 / spacing).round() as usize).max(1);
    let mut prefix = vec![0.0; n + 1];
    for (i, w) in samples.iter().enumerate() {
        prefix[i + 1] = prefix[i] + w.curvature_per_m;
    }
    let mut piece = 0;
    let mut speeds: Vec<f64> = (0..n)
        .map(|i| {
            let (lo, hi) = (i.saturating_sub(half), (i + half + 1).min(n));
            let curvature = ((prefix[hi] - prefix[lo]) / (hi - lo) as f64).abs();
            let curve = (profile.lateral_accel_mps2 / curvature.max(1e-6)).sqrt();
            let s = i as f64 * spacing;
            while piece + 1 < pieces.len() && s >= pieces[piece].s_end {
                piece += 1;
            }
            geometry[piece].2.min(curve)
        })
        .collect();
    for i in (0..n - 1).rev() {
        let reachable =
            (speeds[i + 1].powi(2) + 2.0 * profile.anticipation_decel_mps2 * spacing).sqrt();
        speeds[i] = speeds[i].min(reachable);
    }
    speeds
}

/// Keeps the samples where the heading has turned by more than a degree since the last kept
/// one (and both ends): the same shape within a few centimetres, with far fewer segments.
fn simplify(points: &[Point], headings: &[f64]) -> Vec<Point> {
    let mut out = vec![points[0]];
    let mut last_heading = headings[0];
    for i in 1..points.len() - 1 {
        if wrap_angle(headings[i] - last_heading).abs() > 1f64.to_radians() {
            out.push(points[i]);
            last_heading = headings[i];
        }
    }
    out.push(points[points.len() - 1]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arc(radius: f64, from: f64, to: f64, n: usize) -> Vec<Point> {
        (0..=n)
            .map(|i| {
                let a = from + (to - from) * i as f64 / n as f64;
                Point::new(radius * a.cos(), radius * a.sin())
            })
            .collect()
    }

    #[test]
    fn pose_speed_and_projection_on_a_straight_then_a_curve() {
        let straight = vec![Point::new(-50.0, -10.0), Point::new(0.0, -10.0)];
        let curve = arc(10.0, -std::f64::consts::FRAC_PI_2, 0.0, 40);
        let path = Path::from_geometry(
            &[
                (PieceKey::Lane(LaneId(0)), straight, 15.0),
                (PieceKey::Connection(ConnectionId(0)), curve, 15.0),
            ],
            SpeedProfile::default(),
        )
        .expect("path");
        let quarter = 10.0 * std::f64::consts::FRAC_PI_2;
        assert!((path.length() - 50.0 - quarter).abs() < 0.01);
        let (p, h) = path.pose_at(25.0);
        assert!(p.distance(Point::new(-25.0, -10.0)) < 1e-9 && h.abs() < 1e-9);
        // On a 10 m radius at 2.5 m/s²: 5 m/s; far up the straight the limit, 15 m/s.
        assert!((path.speed_at(50.0 + quarter / 2.0) - 5.0).abs() < 0.3);
        // Braking at 1.5 m/s² from 15 to 5 m/s takes 66.7 m, more than the 50 m straight:
        // even its start is slower than the limit, √(5² + 2 · 1.5 · 50) = 13.2 m/s.
        assert!(
            (path.speed_at(0.0) - 13.2).abs() < 0.3,
            "{}",
            path.speed_at(0.0)
        );
        // Well into the curve the speed is the curve's; 6.5 m before, no more than braking
        // at 1.5 m/s² allows (up to the linear interpolation between samples).
        let in_curve = path.speed_at(51.5);
        assert!((in_curve - 5.0).abs() < 0.3, "{in_curve}");
        let before = path.speed_at(45.0);
        assert!(
            before <= (in_curve.powi(2) + 2.0 * 1.5 * 6.5).sqrt() + 0.02,
            "{before}"
        );
        assert_eq!(path.piece_at(49.0, 0), 0);
        assert_eq!(path.piece_at(51.0, 0), 1);
        assert_eq!(path.piece_at(10.0, 1), 0);
        let (s, d) = path.project(Point::new(-20.0, -9.0), 30.0, 5.0, 5.0);
        assert!((s - 30.0).abs() < 1e-6 && (d - 1.0).abs() < 1e-9);
        assert!(path.outline().len() < path.points.len() / 2);
    }

    fn lane(points: Vec<Point>) -> (PieceKey, Vec<Point>, f64) {
        (PieceKey::Lane(LaneId(0)), points, 10.0)
    }

    fn rounded(points: Vec<Point>, radius: f64) -> Option<Path> {
        let profile = SpeedProfile {
            min_turn_radius_m: radius,
            ..SpeedProfile::default()
        };
        Path::from_geometry(&[lane(points)], profile)
    }

    /// A 60° corner, as lane graphs join an entry to a ring: rounded off so that nowhere
    /// does the path turn tighter than the radius (measured over 1.5 m), no point moves more
    /// than MAX_ROUNDING_M from the mapped line, and the ends stay where they were.
    #[test]
    fn a_kink_is_rounded_off_to_the_turn_radius() {
        let end = Point::new(10.0, 10.0 * 3f64.sqrt());
        let corner = vec![Point::new(-20.0, 0.0), Point::new(0.0, 0.0), end];
        let path = rounded(corner.clone(), 5.0).expect("roundable");
        assert!(
            path.length() < 40.0 && path.length() > 39.0,
            "{}",
            path.length()
        );
        let step = (1.5 / path.spacing).round() as usize;
        for i in step..path.points.len() - step {
            let turn = wrap_angle(path.headings[i + step] - path.headings[i - step]).abs();
            let per_m = turn / (2.0 * step as f64 * path.spacing);
            assert!(per_m < 1.1 / 5.0, "turns {per_m:.3}/m at {i}");
        }
        for p in &path.points {
            let off_mapped = corner
                .windows(2)
                .map(|w| closest_on_segment(w[0], w[1], *p).0.distance(*p))
                .fold(f64::INFINITY, f64::min);
            assert!(off_mapped <= MAX_ROUNDING_M + 1e-9, "{p:?} {off_mapped}");
        }
        assert!(path.pose_at(0.0).0.distance(corner[0]) < 1e-9);
        assert!(path.pose_at(path.length()).0.distance(end) < 1e-6);
        assert!((path.pieces()[0].s_end - path.length()).abs() < 1e-9);
        // Without a radius the mapped corner is kept.
        let mapped = rounded(corner, 0.0).expect("path");
        assert!((mapped.length() - 40.0).abs() < 1e-9);
    }

    /// A U-turn within two metres cannot be rounded to a 5 m radius within MAX_ROUNDING_M:
    /// no path.
    #[test]
    fn a_hairpin_too_tight_to_round_off_is_no_path() {
        let hairpin = vec![
            Point::new(-20.0, 0.0),
            Point::new(0.0, 0.0),
            Point::new(0.0, 2.0),
            Point::new(-20.0, 2.0),
        ];
        assert!(rounded(hairpin.clone(), 5.0).is_none());
        assert!(rounded(hairpin, 0.0).is_some());
    }
}
