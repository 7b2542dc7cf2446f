//! Campus route following (the AIT lane-keeping study with the MTSU route goal): the ego
//! follows a planned route over an imported map, keeping in its lane among other traffic.
//!
//! - Routes: a pool of fastest routes between random lanes of the map (`maps::route`),
//!   `route_length_m` long, drawn once per map from `pool_seed`. A fixed share of them
//!   (`held_out_fraction`, chosen by a hash of their end lanes) is held out: training
//!   episodes never see them, evaluation on [`RouteSplit::HeldOut`] uses only them.
//! - Actions ([`SteerAction`], as roundabout driving's, but on steering increments):
//!   **forward** (steering kept), **forward+left**
//!   (steering + `steer_increment_rad`), **forward+right** (− the same), within
//!   ±`max_steer_rad`. Speed is not the agent's: the ego accelerates to `max_speed_kmh`
//!   (8 km/h by default, the study's campus speed) and brakes (IDM) behind a vehicle in its
//!   lane ahead.
//! - Other traffic: `other_vehicles` vehicles on other routes of the pool near the ego's
//!   and on the ego's own route ahead of it, each driving its route at its own steady speed
//!   (they do not react to the ego: a road user that does not yield, as on a campus).
//! - Reward per decision: `speed / max_speed + in-lane fraction` (the share of the ego's
//!   width within its lane), replaced by `below_lane_penalty` (−1) when the fraction is
//!   under `in_lane_threshold` (0.98); `steer_change_penalty` (−0.2) on a steering change;
//!   `terminal_penalty` (−4) when the ego goes off road or hits a vehicle.
//! - Termination: Reached (the route's end), Crashed, OffRoad (the ego's centre more than
//!   `off_road_m` beyond its lane's edge), TimeOver (`time_limit_factor` × the route's
//!   time at the maximum speed, plus 10 s).
//! - Observation: the route ahead in the ego's frame (lateral offsets of the route's centre
//!   line at `lookahead_m` metres along it), the lane's half width, speed and steering
//!   angle, and the nearest other vehicle within 20 m (ego-frame position): a navigation
//!   system gives a driver the route the same way. Layers by `view`: none (`"scalars"`, the
//!   default), the bird's-eye layers of the scene around the ego (`"bev"`, the `bev` table;
//!   the route is the `path` layer), or the front camera's segmented view
//!   (`"camera-segmentation"`, the `camera` table, drawn by an observer given to
//!   [`RouteSetup::with_observer`]).
//! - Metrics: route completion (share of the route driven), lane-centre RMS error (m),
//!   time in lane (share of decisions at or above the in-lane threshold).

use std::sync::Arc;

use maps::route::Router;
use maps::{LaneId, Map, Point};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::env::{Observation, ObservationSpec, Outcome};
use crate::error::SimError;
use crate::kinematics::{Bicycle, advance_speed, direction};
use crate::observer::{CameraViewConfig, SceneObserver, View, checked_observer};
use crate::path::{Path, PieceKey, SpeedProfile, wrap_angle};
use crate::render::{BevConfig, BevRenderer};
use crate::scene::{Actor, ActorKind, OrientedBox, Scene};
use crate::seed::derive_seed;
use crate::tasks::ring_driving::SteerAction;
use crate::tasks::roundabouts::EgoView;
use crate::tasks::{
    ConditionChoice, Driving, Episode, PolicyFactory, Task, TaskId, TaskPolicy, TaskSetup,
    TaskSummary, act_each, baselines_with_rule, required_map, turn,
};
use crate::world::{Driver, DriverConfig, EgoConfig, TrafficLevel};

mod config;
mod setup;
mod task;

pub use config::*;
pub use setup::*;
pub use task::*;

/// Another road user: a box driving a route of the pool at a steady speed.
#[derive(Debug, Clone)]
struct Other {
    route: usize,
    s: f64,
    speed: f64,
    desired_speed: f64,
    length: f64,
    width: f64,
}

/// A vehicle as the car-following sees it.
#[derive(Debug, Clone, Copy)]
struct Mover {
    route: usize,
    s: f64,
    position: Point,
    heading: f64,
    speed: f64,
    length: f64,
    width: f64,
}

/// The route-following task as an [`crate::Env`].
#[derive(Debug)]
pub struct RouteFollowing {
    setup: Arc<RouteSetup>,
    split: RouteSplit,
    route: usize,
    bike: Bicycle,
    speed: f64,
    steer: f64,
    /// Arc length of the ego's centre along its route.
    s: f64,
    others: Vec<Other>,
    time_s: f64,
    time_limit_s: f64,
    /// Decisions, return, outcome and the ego's positions (one per decision).
    episode: Episode,
    squared_error_sum: f64,
    in_lane_steps: usize,
    speed_sum: f64,
    /// The ego's stacked layers (None for `view = "scalars"`).
    view: Option<EgoView>,
}

impl RouteFollowing {
    pub fn new(setup: Arc<RouteSetup>) -> Self {
        let wheelbase = setup.config.ego.wheelbase_m;
        let view = match (&setup.observer, &setup.config.camera, &setup.renderer) {
            (Some(observer), Some(camera), _) => {
                Some(EgoView::observed(Arc::clone(observer), camera.stack))
            }
            (None, _, Some(renderer)) => Some(EgoView::new(renderer.config())),
            _ => None,
        };
        RouteFollowing {
            setup,
            split: RouteSplit::Training,
            route: 0,
            bike: Bicycle::at_centre(Point::new(0.0, 0.0), 0.0, wheelbase),
            speed: 0.0,
            steer: 0.0,
            s: 0.0,
            others: Vec::new(),
            time_s: 0.0,
            time_limit_s: 0.0,
            episode: Episode::default(),
            squared_error_sum: 0.0,
            in_lane_steps: 0,
            speed_sum: 0.0,
            view,
        }
    }

    /// Draws the current scene into the layers: the first frame of an episode, or the next.
    fn draw(&mut self, first: bool) {
        let Some(mut view) = self.view.take() else {
            return;
        };
        let setup = Arc::clone(&self.setup);
        view.draw_with(setup.renderer.as_ref(), self.scene(), first);
        self.view = Some(view);
    }

    /// Which routes the next episodes draw from.
    pub fn set_split(&mut self, split: RouteSplit) {
        self.split = split;
    }

    /// Whether the current episode's route is one of the held-out routes.
    pub fn route_is_held_out(&self) -> bool {
        self.route().held_out
    }

    fn route(&self) -> &PlannedRoute {
        &self.setup.routes[self.route]
    }

    fn config(&self) -> &RouteConfig {
        &self.setup.config
    }

    /// The ego's signed lateral offset from the route (left positive) and heading error.
    fn deviation(&self) -> (f64, f64) {
        let path = &self.route().path;
        let centre = self.bike.centre();
        let (p, heading) = path.pose_at(self.s);
        let offset = centre.sub(p).dot(direction(heading).perp());
        (offset, wrap_angle(self.bike.heading - heading))
    }

    /// The share of the ego's width inside its lane.
    fn in_lane_fraction(&self) -> f64 {
        let (offset, heading_error) = self.deviation();
        let ego = &self.config().ego;
        let half_extent = ego.width_m / 2.0 * heading_error.cos().abs()
            + ego.length_m / 2.0 * heading_error.sin().abs();
        let half_lane = self.route().half_width(self.s);
        let inside = (offset + half_extent).min(half_lane) - (offset - half_extent).max(-half_lane);
        (inside / (2.0 * half_extent)).clamp(0.0, 1.0)
    }

    fn other_pose(&self, other: &Other) -> (Point, f64) {
        self.setup.routes[other.route].path.pose_at(other.s)
    }

    fn ego_box(&self) -> OrientedBox {
        let ego = &self.config().ego;
        OrientedBox::new(
            self.bike.centre(),
            self.bike.heading,
            ego.length_m,
            ego.width_m,
        )
    }

    /// Every vehicle, the ego first (index 0), then the others.
    fn vehicles(&self) -> Vec<Mover> {
        let ego = &self.config().ego;
        let mut all = Vec::with_capacity(self.others.len() + 1);
        all.push(Mover {
            route: self.route,
            s: self.s,
            position: self.bike.centre(),
            heading: self.bike.heading,
            speed: self.speed,
            length: ego.length_m,
            width: ego.width_m,
        });
        for o in &self.others {
            let (position, heading) = self.other_pose(o);
            all.push(Mover {
                route: o.route,
                s: o.s,
                position,
                heading,
                speed: o.speed,
                length: o.length,
                width: o.width,
            });
        }
        all
    }

    /// For vehicle `i` of `vehicles`: gap to and closing speed on the nearest vehicle ahead
    /// (the leader of its IDM): ahead on the same route (measured along it, so curves do
    /// not hide it), or in the straight corridor of its lane ahead (crossing traffic).
    fn leader(vehicles: &[Mover], i: usize, half_lane: f64) -> Option<(f64, f64)> {
        let me = &vehicles[i];
        let axis = direction(me.heading);
        vehicles
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .filter_map(|(_, other)| {
                let half_lengths = (me.length + other.length) / 2.0;
                if other.route == me.route && other.s > me.s {
                    let gap = other.s - me.s - half_lengths;
                    return (gap < 30.0).then_some((gap.max(0.0), me.speed - other.speed));
                }
                let rel = other.position.sub(me.position);
                let ahead = rel.dot(axis);
                let lateral = rel.dot(axis.perp()).abs();
                (ahead > 0.0 && ahead < 30.0 && lateral < half_lane + other.width / 2.0).then(
                    || {
                        let along = other.speed * wrap_angle(other.heading - me.heading).cos();
                        ((ahead - half_lengths).max(0.0), me.speed - along)
                    },
                )
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
    }

    /// One simulation step of everyone; the outcome if the episode ended.
    fn advance(&mut self) -> Option<Outcome> {
        // The setup, not its config, is cloned: an Arc, cheap at every step.
        let setup = Arc::clone(&self.setup);
        let config = &setup.config;
        let dt = config.step_s;
        // Everyone drives by the IDM behind whoever is ahead in their lane, the ego included.
        let driver = &setup.driver;
        let vehicles = self.vehicles();
        let accels: Vec<f64> = (0..vehicles.len())
            .map(|i| {
                let (half_lane, desired) = if i == 0 {
                    (self.route().half_width(self.s), config.max_speed_mps())
                } else {
                    let o = &self.others[i - 1];
                    (self.setup.routes[o.route].half_width(o.s), o.desired_speed)
                };
                driver.idm(
                    vehicles[i].speed,
                    desired,
                    Self::leader(&vehicles, i, half_lane),
                )
            })
            .collect();
        for (o, &a) in self.others.iter_mut().zip(&accels[1..]) {
            let (speed, ds) = advance_speed(o.speed, a.clamp(-8.0, 3.0), dt);
            o.speed = speed;
            o.s += ds;
        }
        // Others leave at the end of their route.
        let routes = &self.setup.routes;
        self.others
            .retain(|o| o.s < routes[o.route].path.length() - 0.5);
        let (speed, travelled) = advance_speed(
            self.speed,
            accels[0].clamp(-config.ego.max_brake_mps2, config.ego.max_accel_mps2),
            dt,
        );
        self.bike.advance(travelled, self.steer);
        self.speed = speed;
        self.time_s += dt;
        let path = &self.setup.routes[self.route].path;
        let (s, distance) = path.project(self.bike.centre(), self.s, 1.0, travelled + 2.0);
        self.s = s.max(self.s);
        let ego_box = self.ego_box();
        let hit = self.others.iter().any(|o| {
            let (p, h) = self.other_pose(o);
            OrientedBox::new(p, h, o.length, o.width).overlaps(&ego_box)
        });
        if hit {
            return Some(Outcome::Crashed);
        }
        if distance > self.route().half_width(self.s) + config.off_road_m {
            return Some(Outcome::OffRoad);
        }
        if self.s >= path.length() - 0.5 {
            return Some(Outcome::Reached);
        }
        (self.time_s >= self.time_limit_s).then_some(Outcome::TimeOver)
    }

    /// Puts other vehicles on routes of the pool that pass near the ego's, and on the
    /// ego's route ahead of it.
    fn place_others(&mut self, rng: &mut ChaCha8Rng) {
        let config = &self.setup.config;
        let start = self.bike.centre();
        let near: Vec<usize> = (0..self.setup.routes.len())
            .filter(|&r| r != self.route)
            .filter(|&r| {
                let path = &self.setup.routes[r].path;
                path.outline().iter().any(|p| p.distance(start) < 60.0)
            })
            .collect();
        let (lo, hi) = config.other_speed_mps;
        let ego = config.ego;
        for k in 0..config.other_vehicles {
            let own = k % 2 == 1 || near.is_empty();
            let route = if own {
                self.route
            } else {
                near[rng.random_range(0..near.len())]
            };
            let length = self.setup.routes[route].path.length();
            let s = if own {
                // Ahead of the ego, slower than it: it must follow, not drive through.
                (rng.random_range(15.0..40.0) + 12.0 * k as f64).min(length - 1.0)
            } else {
                rng.random_range(0.0..length)
            };
            let speed = if own {
                rng.random_range(lo..hi).min(0.6 * config.max_speed_mps())
            } else {
                rng.random_range(lo..hi)
            };
            let other = Other {
                route,
                s,
                speed,
                desired_speed: speed,
                length: ego.length_m,
                width: ego.width_m,
            };
            let (p, h) = self.other_pose(&other);
            let clear = OrientedBox::new(p, h, other.length + 6.0, other.width + 2.0);
            if !clear.overlaps(&self.ego_box()) {
                self.others.push(other);
            }
        }
    }
}

impl Driving for RouteFollowing {
    type Summary = RouteSummary;
    type Action = SteerAction;

    fn summary(&self) -> RouteSummary {
        let length = self.route().path.length();
        let steps = self.episode.steps.max(1) as f64;
        RouteSummary {
            outcome: self.episode.final_outcome(),
            steps: self.episode.steps,
            episode_return: self.episode.episode_return,
            route_length_m: length,
            completion: if self.episode.outcome == Some(Outcome::Reached) {
                1.0
            } else {
                (self.s / length).clamp(0.0, 1.0)
            },
            lane_rms_error_m: (self.squared_error_sum / steps).sqrt(),
            time_in_lane: self.in_lane_steps as f64 / steps,
            mean_speed_kmh: 3.6 * self.speed_sum / steps,
        }
    }

    fn spec(&self) -> ObservationSpec {
        self.setup.observation_spec()
    }

    episode_in_field!();

    fn begin(&mut self, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let want_held_out = self.split == RouteSplit::HeldOut;
        let candidates: Vec<usize> = (0..self.setup.routes.len())
            .filter(|&r| self.setup.routes[r].held_out == want_held_out)
            .collect();
        self.route = candidates[rng.random_range(0..candidates.len())];
        let (p, heading) = self.route().path.pose_at(0.0);
        self.bike = Bicycle::at_centre(p, heading, self.config().ego.wheelbase_m);
        self.speed = 0.0;
        self.steer = 0.0;
        self.s = 0.0;
        self.others.clear();
        self.place_others(&mut rng);
        self.time_s = 0.0;
        self.time_limit_s = self.config().time_limit_factor * self.route().path.length()
            / self.config().max_speed_mps()
            + 10.0;
        self.episode.reset(Some(self.bike.centre()));
        self.squared_error_sum = 0.0;
        self.in_lane_steps = 0;
        self.speed_sum = 0.0;
        self.draw(true);
    }

    fn decide(&mut self, action: SteerAction) -> Option<(f64, Option<Outcome>)> {
        // The setup, not its config, is cloned: an Arc, cheap at every step.
        let setup = Arc::clone(&self.setup);
        let config = &setup.config;
        let change = match action {
            SteerAction::ForwardLeft => config.steer_increment_rad,
            SteerAction::ForwardRight => -config.steer_increment_rad,
            SteerAction::Forward => 0.0,
        };
        let max_steer = config.ego.max_steer_rad;
        let new_steer = (self.steer + change).clamp(-max_steer, max_steer);
        let changed = new_steer != self.steer;
        self.steer = new_steer;
        let mut outcome = None;
        for _ in 0..config.action_repeat {
            outcome = self.advance();
            if outcome.is_some() {
                break;
            }
        }
        self.episode.steps += 1;
        self.episode.trajectory.push(self.bike.centre());
        let (offset, _) = self.deviation();
        self.squared_error_sum += offset * offset;
        self.speed_sum += self.speed;
        let fraction = self.in_lane_fraction();
        if fraction >= config.reward.in_lane_threshold {
            self.in_lane_steps += 1;
        }
        let mut reward = if fraction < config.reward.in_lane_threshold {
            config.reward.below_lane_penalty
        } else {
            self.speed / config.max_speed_mps() + fraction
        };
        if changed {
            reward += config.reward.steer_change_penalty;
        }
        if matches!(outcome, Some(Outcome::Crashed | Outcome::OffRoad)) {
            reward += config.reward.terminal_penalty;
        }
        self.draw(false);
        Some((reward, outcome))
    }

    fn observe(&self) -> Observation {
        let config = self.config();
        let path = &self.route().path;
        let centre = self.bike.centre();
        let axis = direction(self.bike.heading);
        let mut scalars = Vec::with_capacity(config.lookahead_m.len() + 5);
        for &ahead in &config.lookahead_m {
            let (p, _) = path.pose_at((self.s + ahead).min(path.length()));
            // Lateral distance of the route in the ego's frame, over 5 m.
            scalars.push((p.sub(centre).dot(axis.perp()) / 5.0) as f32);
        }
        scalars.push((self.route().half_width(self.s) / 2.0) as f32);
        scalars.push((self.speed / config.max_speed_mps()) as f32);
        scalars.push((self.steer / config.ego.max_steer_rad) as f32);
        let nearest = self
            .others
            .iter()
            .map(|o| self.other_pose(o).0.sub(centre))
            .filter(|rel| rel.norm() < NEAR_M)
            .min_by(|a, b| a.norm().total_cmp(&b.norm()));
        let (x, y) = nearest.map_or((1.0, 0.0), |rel| {
            (rel.dot(axis) / NEAR_M, rel.dot(axis.perp()) / NEAR_M)
        });
        scalars.push(x as f32);
        scalars.push(y as f32);
        Observation {
            layers: self.view.as_ref().map(EgoView::layers).unwrap_or_default(),
            scalars,
        }
    }
}

#[cfg(test)]
mod tests;
