//! Roundabout driving (after the ITS study): the ego is on a route through a roundabout
//! (entry → ring → exit), a little before its yield line or already in the ring, and must
//! steer along that route, the target lane, for 10 s among the world's traffic.
//!
//! - Actions (steering only): **forward** (front wheels straight), **forward-left** and
//!   **forward-right** (wheels at `±steer_rad`, left positive), each the angle the wheels
//!   turn towards, by at most `steer_rate_radps` (the steering actuator's rate). Fixed
//!   angles, as the study's actions name directions rather than steering increments; the
//!   rate limit keeps a switch of action from jerking the wheels, and lets the agent hold
//!   an intermediate curvature by alternating actions.
//! - Speed is not the agent's: the ego's own driver model (a middle driver's IDM behind
//!   the vehicles ahead on its route, waiting at its yield line until it accepts a gap,
//!   as every other driver of [`crate::world`]) chooses its acceleration.
//! - Reward per step: `min(1, 1/α) + min(1, 1/(10·d))`, α the absolute difference between
//!   the ego's heading and the route's at the point of the route nearest the ego's centre,
//!   **in degrees**, d that distance **in metres** (each term is 1 at α = 0 or d = 0);
//!   minus `far_penalty` (0.5) while the ego's centre is more than `far_from_ring_m` (30 m)
//!   from the roundabout's centre circle. The step that ends the episode in a collision or
//!   off the road gets `−collision_penalty` / `−off_road_penalty` (−1) instead. With α in
//!   radians the first term would be 1 for every deviation under 57°, a reward that does not
//!   tell good steering from poor.
//! - Termination: Crashed (the ego's footprint overlaps another's), OffRoad (its centre
//!   more than `max_lane_distance_m` (4 m) from the route or off the navigable area),
//!   Reached after `episode_s` (10 s) without either, or when the ego reaches the end of its
//!   route sooner: the task has no goal other than driving its time without a fault, so
//!   that is its success. Being far from the roundabout does not end an episode (the issue
//!   gives it as a per-step penalty); in practice the 4 m rule ends a stray one first.
//! - Observation (`view`): the bird's-eye layers around the ego (`"bev"`, the default:
//!   navigable area, the route as the target lane, every vehicle's footprint, stop / yield
//!   lines; ego-centred and aligned with its heading, `stack` frames), or the front camera's
//!   segmented view (`"camera-segmentation"`, settings in `camera`, drawn by an observer
//!   given to [`RingDrivingSetup::with_observer`]); and two scalars, the speed over
//!   `speed_scale_mps` and the front wheels' angle over `steer_rad`. Neither the heading
//!   nor the distance deviation is an input: the agent must read them from the layers.
//! - Metrics: mean angle deviation (°) and mean distance deviation (m) over the episode's
//!   steps, the episode's length (s), the mean speed (km/h).

use std::sync::Arc;

use maps::Point;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::roundabouts::{EgoView, RoundaboutSetup, RoundaboutTaskConfig, ego_scene};
use super::{
    ConditionChoice, Driving, Episode, PolicyFactory, Task, TaskId, TaskPolicy, TaskSummary,
    act_each, baselines_with_rule, check_positive,
};
use crate::env::{Observation, ObservationSpec, Outcome};
use crate::error::SimError;
use crate::kinematics::Bicycle;
use crate::observer::{CameraViewConfig, SceneObserver, View, checked_observer};
use crate::path::wrap_angle;
use crate::render::{BevConfig, BevRenderer};
use crate::roundabout::{LayoutConfig, RingRoute};
use crate::scene::Scene;
use crate::world::{CalibratedWorld, EgoCommand, EgoConfig, TrafficConfig, TrafficLevel, World};

mod config;
mod task;

pub use config::*;
pub use task::*;

actions! {
    /// The three actions, by index.
    pub enum SteerAction {
        Forward = 0 => "forward",
        ForwardLeft = 1 => "forward_left",
        ForwardRight = 2 => "forward_right",
    }
    fallback Forward;
}

impl SteerAction {
    /// The wheel angle the action turns towards, for actions at `±steer_rad`.
    pub fn target_steer(self, steer_rad: f64) -> f64 {
        match self {
            SteerAction::Forward => 0.0,
            SteerAction::ForwardLeft => steer_rad,
            SteerAction::ForwardRight => -steer_rad,
        }
    }
}

/// Where the ego is relative to its route: the deviations the reward and metrics use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneDeviation {
    /// Absolute heading difference, degrees.
    pub angle_deg: f64,
    /// From the ego's centre to the nearest point of the route, m.
    pub distance_m: f64,
}

/// The roundabout driving task as an [`crate::Env`] and a [`Task`].
#[derive(Debug)]
pub struct RingDriving {
    setup: Arc<RingDrivingSetup>,
    config: RingDrivingConfig,
    roundabout: usize,
    world: Option<World>,
    /// The front wheels' angle, rad (left positive).
    steer: f64,
    /// World steps, return, outcome and the ego's positions.
    episode: Episode,
    start_time_s: f64,
    angle_sum_deg: f64,
    distance_sum_m: f64,
    speed_sum_mps: f64,
    view: EgoView,
}

impl RingDriving {
    pub fn new(setup: Arc<RingDrivingSetup>) -> Self {
        let config = setup.config.clone();
        let view = match (&setup.observer, &config.camera) {
            (Some(observer), Some(camera)) => EgoView::observed(Arc::clone(observer), camera.stack),
            _ => EgoView::new(&config.observation),
        };
        RingDriving {
            setup,
            config,
            roundabout: 0,
            world: None,
            steer: 0.0,
            episode: Episode::default(),
            start_time_s: 0.0,
            angle_sum_deg: 0.0,
            distance_sum_m: 0.0,
            speed_sum_mps: 0.0,
            view,
        }
    }

    /// Sets the traffic level of the following episodes.
    pub fn set_traffic(&mut self, level: TrafficLevel) {
        self.config.traffic.level = level;
    }

    pub fn config(&self) -> &RingDrivingConfig {
        &self.config
    }

    pub fn world(&self) -> Option<&World> {
        self.world.as_ref()
    }

    /// The episode's outcome once it has ended.
    pub fn outcome(&self) -> Option<Outcome> {
        self.episode.outcome
    }

    /// The front wheels' angle, rad (left positive).
    pub fn steer_rad(&self) -> f64 {
        self.steer
    }

    /// The newest frame of layers (`[layer, row, column]`; for the bird's-eye view see
    /// [`BevConfig::layers`]).
    pub fn newest_frame(&self) -> &[u8] {
        self.view.newest()
    }

    /// The bird's-eye renderer of the current episode's roundabout.
    pub fn renderer(&self) -> &BevRenderer {
        self.setup.roundabouts.renderer(self.roundabout)
    }

    /// The wheel angle of forward-left (forward-right is its opposite), rad.
    fn action_steer(&self) -> f64 {
        self.config.steer_rad.min(self.config.ego.max_steer_rad)
    }

    /// The wheel angle after one step of `action` from the current one.
    pub fn next_steer(&self, action: SteerAction) -> f64 {
        let max_turn = self.config.steer_rate_radps * self.config.traffic.step_s;
        let target = action.target_steer(self.action_steer());
        self.steer + (target - self.steer).clamp(-max_turn, max_turn)
    }

    /// The ego's deviation from its route (None before a reset).
    pub fn deviation(&self) -> Option<LaneDeviation> {
        let world = self.world.as_ref()?;
        let ego = world.ego_index()?;
        let me = &world.vehicles()[ego];
        Some(deviation_from(
            world.route(me),
            me.position,
            me.heading,
            me.s,
        ))
    }

    /// What pure pursuit on the route would set the wheels to (the world's controller,
    /// with its look-ahead), rad; 0 before a reset.
    pub fn pursuit_steer(&self) -> f64 {
        let Some(world) = self.world.as_ref() else {
            return 0.0;
        };
        world
            .ego_index()
            .map_or(0.0, |ego| pursuit_steer(world, ego, &self.config.ego))
    }

    /// The rule baseline's choice: the action whose next wheel angle is nearest to pure
    /// pursuit's (reads the privileged route and pose).
    pub fn pursuit_action(&self) -> SteerAction {
        let wanted = self.pursuit_steer();
        SteerAction::ALL
            .into_iter()
            .min_by(|a, b| {
                (self.next_steer(*a) - wanted)
                    .abs()
                    .total_cmp(&(self.next_steer(*b) - wanted).abs())
            })
            .unwrap_or(SteerAction::Forward)
    }

    /// Draws the current scene: the first frame of an episode, or the next one.
    fn render(&mut self, first: bool) {
        let scene = self
            .world
            .as_ref()
            .and_then(|world| ego_scene(self.setup.map(), world, self.start_time_s, None));
        self.view.draw(
            self.setup.roundabouts.renderer(self.roundabout),
            scene,
            first,
        );
    }

    /// After a world step: the reward and whether (and how) the episode ended.
    fn resolve(&mut self, world: &mut World) -> (f64, Option<Outcome>) {
        let Some(ego) = world.ego_index() else {
            return (0.0, Some(Outcome::TimeOver));
        };
        let (position, speed, s, deviation) = {
            let me = &world.vehicles()[ego];
            let route = world.route(me);
            (
                me.position,
                me.speed,
                me.s,
                deviation_from(route, me.position, me.heading, me.s),
            )
        };
        self.episode.steps += 1;
        self.speed_sum_mps += speed;
        self.angle_sum_deg += deviation.angle_deg;
        self.distance_sum_m += deviation.distance_m;
        self.episode.trajectory.push(position);
        let c = &self.config;
        let r = c.reward;
        let layout = world.layout();
        let from_ring = position.distance(layout.centre) - layout.radius_m;
        let mut reward = lane_reward(deviation.angle_deg, deviation.distance_m);
        if from_ring > r.far_from_ring_m {
            reward -= r.far_penalty;
        }
        let route_end = world.route(&world.vehicles()[ego]).path.length() - c.ego.length_m / 2.0;
        let raster = self.setup.roundabouts.renderer(self.roundabout).raster();
        let elapsed = world.time_s() - self.start_time_s;
        if world.collision_with(ego).is_some() {
            (-r.collision_penalty, Some(Outcome::Crashed))
        } else if deviation.distance_m > c.max_lane_distance_m || !raster.navigable(position) {
            (-r.off_road_penalty, Some(Outcome::OffRoad))
        } else if elapsed >= c.episode_s - 1e-9 || s >= route_end {
            (reward, Some(Outcome::Reached))
        } else {
            (reward, None)
        }
    }
}

/// The deviation of a pose from `route`, looking for the nearest point of the route
/// within a few metres of `s_hint` (the ego's progress along it).
fn deviation_from(route: &RingRoute, position: Point, heading: f64, s_hint: f64) -> LaneDeviation {
    let (s, distance_m) = route.path.project(position, s_hint, 3.0, 3.0);
    let (_, lane_heading) = route.path.pose_at(s);
    LaneDeviation {
        angle_deg: wrap_angle(heading - lane_heading).abs().to_degrees(),
        distance_m,
    }
}

/// The world's pure pursuit wheel angle for vehicle `ego` on its route.
fn pursuit_steer(world: &World, ego: usize, cfg: &EgoConfig) -> f64 {
    let me = &world.vehicles()[ego];
    let lookahead = (cfg.lookahead_min_m + cfg.lookahead_s * me.speed).min(8.0);
    let (target, _) = world.route(me).path.pose_at(me.s + lookahead);
    Bicycle::at_centre(me.position, me.heading, cfg.wheelbase_m)
        .pure_pursuit(target, cfg.max_steer_rad)
}

impl Driving for RingDriving {
    type Summary = RingDrivingSummary;
    type Action = SteerAction;

    fn summary(&self) -> RingDrivingSummary {
        let steps = self.episode.steps;
        let n = steps.max(1) as f64;
        RingDrivingSummary {
            outcome: self.episode.final_outcome(),
            steps,
            episode_return: self.episode.episode_return,
            mean_angle_deviation_deg: self.angle_sum_deg / n,
            mean_distance_deviation_m: self.distance_sum_m / n,
            episode_length_s: steps as f64 * self.config.traffic.step_s,
            mean_speed_kmh: self.speed_sum_mps / n * 3.6,
        }
    }

    fn spec(&self) -> ObservationSpec {
        self.setup.observation_spec()
    }

    episode_in_field!();

    fn begin(&mut self, seed: u64) {
        let c = &self.config;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (roundabout, route_index) = self.setup.roundabouts.draw_route(&mut rng);
        self.roundabout = roundabout;
        // Every draw is made whatever the branch, so one choice never shifts the next.
        let in_ring = rng.random::<f64>() < c.ring_start_probability;
        let place_draw: f64 = rng.random();
        let speed_draw: f64 = rng.random();
        let world_seed: u64 = rng.random();
        let layout = Arc::clone(self.setup.roundabouts.layout(roundabout));
        let route = &layout.routes[route_index];
        let half = c.ego.length_m / 2.0;
        let s0 = if in_ring {
            // The centre between just past the merge point and the exit, so the driver
            // model sees it over its line (committed) from the start.
            let from = route.merge_s + 1.0;
            from + place_draw * (route.exit_s - from).max(0.0)
        } else {
            let (lo, hi) = c.start_before_yield_m;
            route.yield_s - half - (lo + (hi - lo) * place_draw)
        };
        let s0 = s0.clamp(half, (route.path.length() - c.ego.length_m).max(half));
        let (lo, hi) = c.start_speed_fraction;
        let speed = route.path.speed_at(s0 + half) * (lo + (hi - lo) * speed_draw);
        let mut world = World::new(Arc::clone(&layout), c.traffic.clone(), c.ego, world_seed);
        world.warm_up(c.traffic.warm_up_s);
        world.insert_ego(route_index, s0, speed, 8.0);
        self.start_time_s = world.time_s();
        // The wheels start where the path-following controller would hold them: a driver
        // already in a curve is already steering.
        self.steer = world.ego_index().map_or(0.0, |ego| {
            let s = pursuit_steer(&world, ego, &c.ego);
            let limit = self.action_steer();
            s.clamp(-limit, limit)
        });
        self.episode
            .reset(world.ego_index().map(|ego| world.vehicles()[ego].position));
        self.world = Some(world);
        self.angle_sum_deg = 0.0;
        self.distance_sum_m = 0.0;
        self.speed_sum_mps = 0.0;
        self.render(true);
    }

    fn decide(&mut self, action: SteerAction) -> Option<(f64, Option<Outcome>)> {
        let mut world = self.world.take()?;
        self.steer = self.next_steer(action);
        world.step_ego(EgoCommand {
            accel: None,
            steer_rad: Some(self.steer),
        });
        let (reward, outcome) = self.resolve(&mut world);
        self.world = Some(world);
        self.render(false);
        Some((reward, outcome))
    }

    fn observe(&self) -> Observation {
        let speed = self
            .world
            .as_ref()
            .and_then(|w| Some(w.vehicles()[w.ego_index()?].speed))
            .unwrap_or(0.0);
        Observation {
            layers: self.view.layers(),
            scalars: vec![
                (speed / self.config.speed_scale_mps) as f32,
                (self.steer / self.action_steer()) as f32,
            ],
        }
    }
}

#[cfg(test)]
mod tests;
