//! Where the ego car stands and where other road users are, for one view.
//!
//! The ego pose is a uniform place on the car lanes (by length), on the lane centre with a
//! little sideways and heading jitter. Other vehicles stand on nearby lanes (one often
//! straight ahead in the ego lane), people on sidewalks or crossing at intersections; only
//! places the camera can see are kept, and nothing overlaps anything else or the ego car.
//! The result is a list of [`Actor`]s — the same oriented boxes a traffic scene provides.

use maps::geometry::{Point, direction_at, point_at, polyline_length};
use maps::{LaneId, Map};
use rand::Rng;
use serde::{Deserialize, Serialize};

use super::scene::{MapScene, uniform};
use super::solids::{Actor, ActorColours, ActorKind, Rgb};

/// How many road users a view gets (uniform in each range, inclusive).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrafficConfig {
    pub vehicles: (u32, u32),
    pub pedestrians: (u32, u32),
    /// Share of views with a vehicle straight ahead in the ego lane.
    pub lead_vehicle_share: f64,
    /// Share of pedestrians that cross the road at an intersection, when one is near.
    pub crossing_share: f64,
    /// Road users are kept within this distance of the camera, metres.
    pub range_m: f64,
    /// Rows of cars parked along the right edge of a lane (2-5 nose to tail), per view;
    /// (0, 0) draws none and leaves the other road users as they are (rows come last).
    pub parked_rows: (u32, u32),
}

impl Default for TrafficConfig {
    fn default() -> Self {
        TrafficConfig {
            vehicles: (0, 12),
            pedestrians: (0, 10),
            lead_vehicle_share: 0.4,
            crossing_share: 0.3,
            range_m: 70.0,
            parked_rows: (0, 0),
        }
    }
}

impl TrafficConfig {
    /// Why the config cannot be used, if it cannot.
    pub fn problem(&self) -> Option<String> {
        let share = |name: &str, v: f64| {
            (!(0.0..=1.0).contains(&v)).then(|| format!("{name} {v} must be within 0 and 1"))
        };
        if self.vehicles.0 > self.vehicles.1 || self.pedestrians.0 > self.pedestrians.1 {
            return Some(format!(
                "road user ranges must run from least to most: vehicles {}-{}, pedestrians {}-{}",
                self.vehicles.0, self.vehicles.1, self.pedestrians.0, self.pedestrians.1
            ));
        }
        share("lead vehicle share", self.lead_vehicle_share)
            .or_else(|| share("crossing share", self.crossing_share))
            .or_else(|| {
                (!(self.range_m > 0.0 && self.range_m.is_finite()))
                    .then(|| format!("road user range {} m must be positive", self.range_m))
            })
    }
}

/// Where the ego car is: on `lane`, `s_m` from its start, jittered sideways.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EgoPose {
    pub lane: LaneId,
    pub s_m: f64,
    pub position: Point,
    pub heading_rad: f64,
}

/// The ego car's footprint relative to the camera: from 3.6 m behind to 0.9 m ahead.
const EGO_BACK_M: f64 = 3.6;
const EGO_FRONT_M: f64 = 0.9;
const EGO_WIDTH_M: f64 = 1.9;

/// Draws an ego pose: a uniform place on the car lanes, jittered by `lateral_m` and
/// `yaw_rad` (uniform in ±). None when the map has no car lanes.
pub fn sample_ego(
    map: &Map,
    scene: &MapScene,
    rng: &mut impl Rng,
    lateral_m: f64,
    yaw_rad: f64,
) -> Option<EgoPose> {
    let (i, s) = scene.lane_at_fraction(rng.random())?;
    let lane = map.lanes.get(scene.car_lanes.get(i)?)?;
    let centre = point_at(&lane.centre, s);
    let dir = direction_at(&lane.centre, s);
    let side = uniform(rng, (-lateral_m, lateral_m));
    let yaw = uniform(rng, (-yaw_rad, yaw_rad));
    Some(EgoPose {
        lane: lane.id,
        s_m: s,
        position: centre.add(dir.perp().scale(side)),
        heading_rad: dir.y.atan2(dir.x) + yaw,
    })
}

/// A rectangle footprint: centre, unit heading, half length, half width.
#[derive(Debug, Clone, Copy)]
struct Footprint {
    centre: Point,
    axis: Point,
    half: (f64, f64),
}

impl Footprint {
    fn of(a: &Actor) -> Self {
        Footprint {
            centre: a.position,
            axis: Point::new(a.heading_rad.cos(), a.heading_rad.sin()),
            half: (a.length_m / 2.0, a.width_m / 2.0),
        }
    }

    /// Half the extent of the rectangle along unit vector `d`.
    fn reach(&self, d: Point) -> f64 {
        self.half.0 * self.axis.dot(d).abs() + self.half.1 * self.axis.perp().dot(d).abs()
    }

    /// Whether two rectangles grown by `margin` overlap (separating axis test).
    fn overlaps(&self, o: &Footprint, margin: f64) -> bool {
        let gap = o.centre.sub(self.centre);
        [self.axis, self.axis.perp(), o.axis, o.axis.perp()]
            .iter()
            .all(|&d| gap.dot(d).abs() <= self.reach(d) + o.reach(d) + margin)
    }
}

/// The camera's view on the ground: apex, heading, half-angle and range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wedge {
    pub apex: Point,
    pub heading_rad: f64,
    pub half_angle_rad: f64,
    pub range_m: f64,
}

impl Wedge {
    /// Whether a point lies inside the wedge.
    pub fn contains(&self, p: Point) -> bool {
        let d = p.sub(self.apex);
        let dist = d.norm();
        if dist > self.range_m {
            return false;
        }
        let fwd = Point::new(self.heading_rad.cos(), self.heading_rad.sin());
        let angle = fwd.cross(d).atan2(fwd.dot(d));
        angle.abs() <= self.half_angle_rad
    }
}

const CAR_PAINT: [Rgb; 10] = [
    [0.92, 0.92, 0.92],
    [0.08, 0.08, 0.09],
    [0.62, 0.63, 0.65],
    [0.38, 0.39, 0.41],
    [0.6, 0.08, 0.07],
    [0.1, 0.2, 0.45],
    [0.15, 0.28, 0.2],
    [0.7, 0.65, 0.55],
    [0.85, 0.85, 0.8],
    [0.25, 0.27, 0.3],
];
const CLOTHES: [Rgb; 8] = [
    [0.1, 0.1, 0.12],
    [0.2, 0.25, 0.45],
    [0.55, 0.1, 0.1],
    [0.8, 0.8, 0.78],
    [0.35, 0.4, 0.3],
    [0.6, 0.5, 0.35],
    [0.85, 0.6, 0.2],
    [0.45, 0.45, 0.5],
];
const TROUSERS: [Rgb; 4] = [
    [0.12, 0.14, 0.22],
    [0.08, 0.08, 0.08],
    [0.4, 0.38, 0.32],
    [0.3, 0.32, 0.36],
];
const SKIN: [Rgb; 4] = [
    [0.92, 0.76, 0.64],
    [0.78, 0.58, 0.44],
    [0.55, 0.38, 0.27],
    [0.35, 0.24, 0.17],
];

fn shade_of(rng: &mut impl Rng, palette: &[Rgb], spread: f32) -> Rgb {
    let c = palette[rng.random_range(0..palette.len())];
    let k = 1.0 + spread * (rng.random::<f32>() * 2.0 - 1.0);
    c.map(|v| (v * k).clamp(0.0, 1.0))
}

/// Draws colours for an actor.
pub fn actor_colours(kind: ActorKind, rng: &mut impl Rng) -> ActorColours {
    match kind {
        ActorKind::Vehicle => ActorColours {
            main: shade_of(rng, &CAR_PAINT, 0.1),
            second: shade_of(rng, &[[0.1, 0.12, 0.16], [0.16, 0.19, 0.22]], 0.3),
            third: shade_of(rng, &[[0.07, 0.07, 0.07]], 0.3),
        },
        ActorKind::Pedestrian => ActorColours {
            main: shade_of(rng, &CLOTHES, 0.2),
            second: shade_of(rng, &TROUSERS, 0.2),
            third: shade_of(rng, &SKIN, 0.08),
        },
    }
}

/// Length, width and height of a random vehicle: mostly cars, some SUVs, vans and buses.
fn vehicle_size(rng: &mut impl Rng) -> (f64, f64, f64) {
    let r = |rng: &mut _, lo, hi| uniform(rng, (lo, hi));
    match rng.random_range(0..20) {
        0..=11 => (r(rng, 4.1, 4.8), r(rng, 1.72, 1.88), r(rng, 1.4, 1.55)),
        12..=16 => (r(rng, 4.5, 5.1), r(rng, 1.85, 2.0), r(rng, 1.65, 1.85)),
        17..=18 => (r(rng, 5.0, 5.9), r(rng, 1.95, 2.1), r(rng, 2.2, 2.7)),
        _ => (r(rng, 10.5, 12.5), r(rng, 2.45, 2.55), r(rng, 2.9, 3.3)),
    }
}

/// Places vehicles and people around the ego pose, inside the camera's `view`.
pub fn place_actors(
    map: &Map,
    scene: &MapScene,
    ego: &EgoPose,
    view: &Wedge,
    config: &TrafficConfig,
    rng: &mut impl Rng,
) -> Vec<Actor> {
    let ego_box = Footprint {
        centre: ego.position.add(
            Point::new(ego.heading_rad.cos(), ego.heading_rad.sin())
                .scale((EGO_FRONT_M - EGO_BACK_M) / 2.0),
        ),
        axis: Point::new(ego.heading_rad.cos(), ego.heading_rad.sin()),
        half: ((EGO_FRONT_M + EGO_BACK_M) / 2.0, EGO_WIDTH_M / 2.0),
    };
    let visible = Wedge {
        range_m: view.range_m.min(config.range_m),
        ..*view
    };
    let mut placed: Vec<Actor> = Vec::new();
    let mut boxes = vec![ego_box];
    let mut try_place = |a: Actor, placed: &mut Vec<Actor>| {
        let fp = Footprint::of(&a);
        let margin = match a.kind {
            ActorKind::Vehicle => 0.6,
            ActorKind::Pedestrian => 0.2,
        };
        if visible.contains(a.position) && !boxes.iter().any(|b| b.overlaps(&fp, margin)) {
            boxes.push(fp);
            placed.push(a);
        }
    };
    let r = visible.range_m;
    let around = (
        Point::new(ego.position.x - r, ego.position.y - r),
        Point::new(ego.position.x + r, ego.position.y + r),
    );

    let n_vehicles = rng.random_range(config.vehicles.0..=config.vehicles.1.max(config.vehicles.0));
    let mut lanes = Vec::new();
    scene.lanes_near(around, &mut lanes);
    if n_vehicles > 0
        && rng.random::<f64>() < config.lead_vehicle_share
        && let Some(lane) = map.lanes.get(&ego.lane)
    {
        let s = ego.s_m + uniform(rng, (7.0, 40.0));
        if s < polyline_length(&lane.centre) {
            let a = vehicle_on(&lane.centre, s, rng);
            try_place(a, &mut placed);
        }
    }
    for _ in 0..n_vehicles * 12 {
        if placed.len() >= n_vehicles as usize || lanes.is_empty() {
            break;
        }
        let id = scene.car_lanes[lanes[rng.random_range(0..lanes.len())] as usize];
        let Some(lane) = map.lanes.get(&id) else {
            continue;
        };
        let s = uniform(rng, (0.0, polyline_length(&lane.centre)));
        let a = vehicle_on(&lane.centre, s, rng);
        try_place(a, &mut placed);
    }

    let n_people =
        rng.random_range(config.pedestrians.0..=config.pedestrians.1.max(config.pedestrians.0));
    let target = placed.len() + n_people as usize;
    let (mut walks, mut crossings) = (Vec::new(), Vec::new());
    scene.sidewalks_near(around, &mut walks);
    scene.crossings_near(around, &mut crossings);
    for _ in 0..n_people * 12 {
        if placed.len() >= target {
            break;
        }
        let height = uniform(rng, (1.5, 1.95));
        let crossing = !crossings.is_empty() && rng.random::<f64>() < config.crossing_share;
        let (position, heading) = if crossing {
            let c = scene.crossings[crossings[rng.random_range(0..crossings.len())] as usize];
            let side = uniform(rng, (-1.3, 1.3)) * c.half_width_m;
            let back = uniform(rng, (-1.0, 1.0));
            let across = c.along.perp();
            let facing = if rng.random::<bool>() { 1.0 } else { -1.0 };
            (
                c.point.add(across.scale(side)).add(c.along.scale(back)),
                across.y.atan2(across.x)
                    + if facing > 0.0 {
                        0.0
                    } else {
                        std::f64::consts::PI
                    },
            )
        } else if !walks.is_empty() {
            let line = &scene.sidewalk_lines[walks[rng.random_range(0..walks.len())] as usize];
            let s = uniform(rng, (0.0, polyline_length(line)));
            let d = direction_at(line, s);
            let p = point_at(line, s).add(d.perp().scale(uniform(rng, (-0.5, 0.5))));
            let turn = if rng.random::<bool>() {
                0.0
            } else {
                std::f64::consts::PI
            };
            (p, d.y.atan2(d.x) + turn + uniform(rng, (-0.3, 0.3)))
        } else {
            break;
        };
        let a = Actor {
            kind: ActorKind::Pedestrian,
            position,
            heading_rad: heading,
            length_m: 0.4,
            width_m: 0.55,
            height_m: height,
        };
        try_place(a, &mut placed);
    }

    let rows =
        rng.random_range(config.parked_rows.0..=config.parked_rows.1.max(config.parked_rows.0));
    for _ in 0..rows {
        if lanes.is_empty() {
            break;
        }
        let id = scene.car_lanes[lanes[rng.random_range(0..lanes.len())] as usize];
        let Some(lane) = map.lanes.get(&id) else {
            continue;
        };
        let len = polyline_length(&lane.centre);
        let mut s = uniform(rng, (0.0, len));
        for _ in 0..rng.random_range(2..=5) {
            let mut a = vehicle_on(&lane.centre, s, rng);
            let d = direction_at(&lane.centre, s);
            let towards_kerb =
                (lane.width_m / 2.0 - a.width_m / 2.0 - uniform(rng, (0.05, 0.3))).max(0.0);
            a.position = point_at(&lane.centre, s).add(d.perp().scale(-towards_kerb));
            s += a.length_m + uniform(rng, (0.5, 2.0));
            if s >= len {
                break;
            }
            try_place(a, &mut placed);
        }
    }
    placed
}

/// A random vehicle on a lane centre line at `s`, a little off-centre and askew.
fn vehicle_on(centre: &[Point], s: f64, rng: &mut impl Rng) -> Actor {
    let (length_m, width_m, height_m) = vehicle_size(rng);
    let d = direction_at(centre, s);
    let p = point_at(centre, s).add(d.perp().scale(uniform(rng, (-0.3, 0.3))));
    Actor {
        kind: ActorKind::Vehicle,
        position: p,
        heading_rad: d.y.atan2(d.x) + uniform(rng, (-0.05, 0.05)),
        length_m,
        width_m,
        height_m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn actor(x: f64, y: f64, heading: f64) -> Actor {
        Actor {
            kind: ActorKind::Vehicle,
            position: Point::new(x, y),
            heading_rad: heading,
            length_m: 4.0,
            width_m: 2.0,
            height_m: 1.5,
        }
    }

    #[test]
    fn footprints_overlap_only_when_they_touch() {
        let a = Footprint::of(&actor(0.0, 0.0, 0.0));
        // Side by side in the next lane: 3.5 m apart, 2 m wide each.
        assert!(!a.overlaps(&Footprint::of(&actor(0.0, 3.5, 0.0)), 0.5));
        assert!(a.overlaps(&Footprint::of(&actor(0.0, 2.2, 0.0)), 0.5));
        // Nose to tail.
        assert!(!a.overlaps(&Footprint::of(&actor(5.0, 0.0, 0.0)), 0.5));
        assert!(a.overlaps(&Footprint::of(&actor(4.2, 0.0, 0.0)), 0.5));
        // Turned across: reaches 1 m along x.
        let across = std::f64::consts::FRAC_PI_2;
        assert!(a.overlaps(&Footprint::of(&actor(2.9, 0.0, across)), 0.0));
        assert!(!a.overlaps(&Footprint::of(&actor(3.2, 0.0, across)), 0.1));
    }

    #[test]
    fn wedge_contains_what_is_ahead() {
        let w = Wedge {
            apex: Point::new(0.0, 0.0),
            heading_rad: std::f64::consts::FRAC_PI_2,
            half_angle_rad: 0.6,
            range_m: 50.0,
        };
        assert!(w.contains(Point::new(0.0, 10.0)));
        assert!(w.contains(Point::new(5.0, 10.0)));
        assert!(!w.contains(Point::new(10.0, 5.0)));
        assert!(!w.contains(Point::new(0.0, -10.0)));
        assert!(!w.contains(Point::new(0.0, 60.0)));
    }
}
