//! Perception noise for projected logs, as in the Parma study: Gaussian noise on the
//! position, size and heading of the other road users, and the ego's path bent by a cubic
//! Bézier curve (evaluated by De Casteljau's algorithm) between a point before the middle of
//! the path and one after it, so an agent does not learn one clean look of the world.
//!
//! Every draw comes from a generator seeded by (seed, stage, frame index), so noisy frames
//! are the same whatever the thread count.

use maps::geometry::Point;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::Actor;
use sim::seed::derive_seed;

/// Seed stage of perception noise.
const NOISE_STAGE: u64 = u64::from_le_bytes(*b"percnois");
/// Seed index of the path's bend (frames use their own index).
const PATH_INDEX: u64 = u64::MAX;

/// How much noise; all zero (the default) leaves frames exact.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NoiseConfig {
    /// Standard deviation of each coordinate of the other users' positions, m.
    pub position_sigma_m: f64,
    /// Standard deviation of their length and width (kept at 0.5 m or more), m.
    pub size_sigma_m: f64,
    /// Standard deviation of their heading, degrees.
    pub heading_sigma_deg: f64,
    /// Standard deviation of the sideways shift of the Bézier curve's two inner control
    /// points; 0 leaves the path as recorded, m.
    pub path_sigma_m: f64,
    pub seed: u64,
}

impl NoiseConfig {
    pub fn is_zero(&self) -> bool {
        self.position_sigma_m == 0.0
            && self.size_sigma_m == 0.0
            && self.heading_sigma_deg == 0.0
            && self.path_sigma_m == 0.0
    }
}

/// A standard normal draw (Box–Muller).
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Noise on every actor but the ego (index `ego`) of frame `index`.
pub fn perturb_actors(actors: &mut [Actor], ego: usize, index: u64, config: &NoiseConfig) {
    if config.position_sigma_m == 0.0
        && config.size_sigma_m == 0.0
        && config.heading_sigma_deg == 0.0
    {
        return;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(derive_seed(config.seed, NOISE_STAGE, index));
    for (i, a) in actors.iter_mut().enumerate() {
        // Draw for the ego too, so the others' noise does not depend on where it sits.
        let d = [
            normal(&mut rng),
            normal(&mut rng),
            normal(&mut rng),
            normal(&mut rng),
            normal(&mut rng),
        ];
        if i == ego {
            continue;
        }
        a.position = Point::new(
            a.position.x + d[0] * config.position_sigma_m,
            a.position.y + d[1] * config.position_sigma_m,
        );
        a.length_m = (a.length_m + d[2] * config.size_sigma_m).max(0.5);
        a.width_m = (a.width_m + d[3] * config.size_sigma_m).max(0.5);
        a.heading_rad += (d[4] * config.heading_sigma_deg).to_radians();
    }
}

/// A point of the cubic Bézier curve with control points `c` at `t` in [0, 1], by De
/// Casteljau's algorithm (repeated linear interpolation).
pub fn de_casteljau(c: &[Point; 4], t: f64) -> Point {
    let [a, b, cc, d] = *c;
    let (ab, bc, cd) = (a.lerp(b, t), b.lerp(cc, t), cc.lerp(d, t));
    let (abc, bcd) = (ab.lerp(bc, t), bc.lerp(cd, t));
    abc.lerp(bcd, t)
}

/// The path with a stretch bent: start in its first half, end in its second half (drawn),
/// the curve from the start point to the end point through inner control points a third
/// and two thirds along the stretch, each shifted sideways by N(0, path_sigma_m).
pub fn bend_path(path: &[Point], config: &NoiseConfig) -> Vec<Point> {
    if config.path_sigma_m == 0.0 || path.len() < 4 {
        return path.to_vec();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(derive_seed(config.seed, NOISE_STAGE, PATH_INDEX));
    let half = path.len() / 2;
    let start = rng.random_range(0..half);
    let end = rng.random_range(half..path.len());
    if end <= start + 2 {
        return path.to_vec();
    }
    let at = |f: f64| path[start + ((end - start) as f64 * f).round() as usize];
    let shift = |p: Point, q: Point, s: f64| {
        let dir = q.sub(p).normalized();
        p.add(dir.perp().scale(s))
    };
    let (p1, p2) = (at(1.0 / 3.0), at(2.0 / 3.0));
    let control = [
        path[start],
        shift(p1, p2, normal(&mut rng) * config.path_sigma_m),
        shift(p2, path[end], normal(&mut rng) * config.path_sigma_m),
        path[end],
    ];
    let steps = end - start;
    let mut out = path[..start].to_vec();
    out.extend((0..=steps).map(|k| de_casteljau(&control, k as f64 / steps as f64)));
    out.extend_from_slice(&path[end + 1..]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::ActorKind;

    fn car(id: u32, x: f64) -> Actor {
        Actor {
            id,
            kind: ActorKind::Car,
            position: Point::new(x, 0.0),
            heading_rad: 0.0,
            speed_mps: 0.0,
            length_m: 4.5,
            width_m: 1.8,
            lane: None,
            aggressiveness: None,
        }
    }

    #[test]
    fn de_casteljau_ends_at_the_end_points_and_stays_in_the_hull() {
        let c = [
            Point::new(0.0, 0.0),
            Point::new(1.0, 2.0),
            Point::new(3.0, 2.0),
            Point::new(4.0, 0.0),
        ];
        assert_eq!(de_casteljau(&c, 0.0), c[0]);
        assert_eq!(de_casteljau(&c, 1.0), c[3]);
        let mid = de_casteljau(&c, 0.5);
        // (P0 + 3 P1 + 3 P2 + P3) / 8.
        assert!(
            (mid.x - 2.0).abs() < 1e-12 && (mid.y - 1.5).abs() < 1e-12,
            "{mid:?}"
        );
        for k in 0..=20 {
            let p = de_casteljau(&c, f64::from(k) / 20.0);
            assert!((0.0..=4.0).contains(&p.x) && (0.0..=2.0).contains(&p.y));
        }
    }

    #[test]
    fn actor_noise_has_the_asked_spread_spares_the_ego_and_repeats() {
        let config = NoiseConfig {
            position_sigma_m: 0.5,
            heading_sigma_deg: 3.0,
            seed: 7,
            ..Default::default()
        };
        let clean: Vec<Actor> = (0..2000).map(|i| car(i, f64::from(i))).collect();
        let mut noisy = clean.clone();
        perturb_actors(&mut noisy, 10, 3, &config);
        assert_eq!(noisy[10], clean[10]);
        let dx: Vec<f64> = noisy
            .iter()
            .zip(&clean)
            .enumerate()
            .filter(|(i, _)| *i != 10)
            .map(|(_, (n, c))| n.position.x - c.position.x)
            .collect();
        let sd = (dx.iter().map(|d| d * d).sum::<f64>() / dx.len() as f64).sqrt();
        assert!((sd - 0.5).abs() < 0.05, "{sd}");
        assert!(
            noisy
                .iter()
                .zip(&clean)
                .all(|(n, c)| n.length_m == c.length_m)
        );
        let mut again = clean.clone();
        perturb_actors(&mut again, 10, 3, &config);
        assert_eq!(again, noisy);
        let mut other_frame = clean.clone();
        perturb_actors(&mut other_frame, 10, 4, &config);
        assert_ne!(other_frame, noisy);
    }

    #[test]
    fn a_bent_path_keeps_its_ends_and_only_moves_the_stretch() {
        let path: Vec<Point> = (0..40).map(|i| Point::new(f64::from(i), 0.0)).collect();
        assert_eq!(bend_path(&path, &NoiseConfig::default()), path);
        let config = NoiseConfig {
            path_sigma_m: 2.0,
            seed: 1,
            ..Default::default()
        };
        let bent = bend_path(&path, &config);
        assert_eq!(bent.first(), path.first());
        assert_eq!(bent.last(), path.last());
        assert_eq!(bent.len(), path.len());
        assert!(bent.iter().any(|p| p.y.abs() > 1e-6), "nothing moved");
        assert_eq!(bend_path(&path, &config), bent);
    }
}
