//! Obstacle avoidance (after the Thai CARLA study): the ego starts at 40 km/h, 100 m before
//! its destination on a straight two-lane road, with a parked or a crossing vehicle on its
//! path.
//!
//! - Road: synthetic, straight along +x, two lanes of 3.5 m in the ego's direction (both
//!   usable); the ego starts in the right lane. Off the road beyond either edge.
//! - Scenarios (drawn per seed, [`Scenario`]): **static**: a vehicle parked in the ego's
//!   lane, its centre 30–70 m ahead of the ego's, up to ±0.5 m off the lane centre;
//!   **crossing**: a vehicle crossing the road at right angles, 30–70 m ahead, at
//!   1.5–3 m/s, from the left or the right, timed so its centre is on the ego's lane centre
//!   when the ego's centre would get there at 40 km/h (±0.5 s): without reacting, the ego
//!   always hits it.
//! - Kinematics: the ego is a [`Bicycle`] (wheelbase 2.7 m) moved in 0.1 s steps; the
//!   policy decides every 0.2 s.
//! - Actions: **straight** (front wheels at 0°; speed back towards 40 km/h at up to
//!   2 m/s²), **brake** (8 m/s², wheels at 0°), **steer left / right** (wheels set to
//!   ±`steer_deg`, 5° by default, speed as under straight). Set values rather than
//!   increments keep the state Markov in the six inputs (the wheel angle is the action, not
//!   hidden state); `steer_deg` is bounded by the study's ±35°, but 35° at 40 km/h would be
//!   a 3.9 m turning radius, so the default is a lane change's angle (about 8 decisions).
//! - LiDAR: 181 rays over ±90° from the ego's front bumper, 40 m range, cast against the
//!   obstacle's box; hits outside the study's window (±3 m lateral, 0–70 m longitudinal in
//!   the ego frame; the range makes it 0–40 m) are dropped; the nearest hit is the
//!   obstacle's offset and the distance `x` of the rewards.
//! - Inputs (six scalars, no layers): distance to destination / 100 m, lateral position
//!   (from the road's centre line / 3.5 m: ±1 at the edges), heading / 30° (the study's
//!   "position" is one-dimensional here since the distance to the destination already
//!   gives the longitudinal one, so its second slot holds the heading, which the bicycle's
//!   motion needs), speed / 40 km/h, and the nearest hit's longitudinal / 40 m and lateral
//!   / 3 m offsets (1 and 0 when nothing is detected).
//! - Rewards ([`RewardKind`]): see [`study_main_reward`], [`lidar_penalty`], [`stop_bonus`].
//!   **Study**: per step the LiDAR penalty p(x) while something is detected; once, the
//!   stop bonus when the ego first stops within 10 m; at the end the main reward of the
//!   final distance to the destination (3000 when reached; a crash or leaving the road
//!   counts as the farthest point, −9500; a time-over gets the main reward of where the ego
//!   is). **Normalised** (ours): the main reward as a potential, per step
//!   (M(d′) − M(d)) / 3000 (a crash or leaving the road sets d′ to the farthest point, so
//!   it loses all progress), the LiDAR penalty rescaled to [−`danger_per_step`, 0] over
//!   [0, 40] m, the stop bonus / 3000, and a bonus of 1 on reaching the destination
//!   (the quadratic is flat there: without it an agent stops just short and times out).
//! - Termination: Crashed (footprints overlap), OffRoad (the ego's centre beyond a road
//!   edge), Reached (the ego's centre passes the destination), TimeOver (30 s).
//! - Metrics: reached without collision, stopping distance (box-to-box gap when the ego
//!   first stopped), minimum gap (box to box), mean speed.

use std::f64::consts::FRAC_PI_2;
use std::sync::Arc;

use maps::{Map, Point};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::env::{Observation, ObservationSpec, Outcome};
use crate::error::SimError;
use crate::kinematics::{Bicycle, advance_speed, direction};
use crate::observer::SceneObserver;
use crate::scene::{Actor, ActorKind, OrientedBox, Scene};
use crate::synthetic::straight_road;
use crate::tasks::{
    ConditionChoice, Driving, Episode, PolicyFactory, Task, TaskId, TaskPolicy, TaskSetup,
    TaskSummary, baselines_with_rule, check_positive,
};
use crate::world::TrafficLevel;

actions! {
    /// The four actions, by index.
    pub enum Action {
        Straight = 0 => "straight",
        Brake = 1 => "brake",
        SteerLeft = 2 => "steer_left",
        SteerRight = 3 => "steer_right",
    }
}

/// The study's steering bound, degrees.
pub const MAX_STEER_DEG: f64 = 35.0;

/// Number of scalar inputs: the study's six.
pub const SCALARS: usize = 6;

/// Extra inputs with [`ObstacleConfig::motion_inputs`]: how the LiDAR return moved since the
/// last decision, laterally and longitudinally.
pub const MOTION_SCALARS: usize = 2;

/// Which obstacles the episodes get.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Scenario {
    Static,
    Crossing,
    /// Either, with equal probability (training).
    Mixed,
}

/// The obstacle of one episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleKind {
    Parked,
    Crossing,
}

/// Which reward the environment hands out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RewardKind {
    /// The study's terms at the study's scale.
    Study,
    /// The same shaping scaled to O(0.1) per step (ours).
    Normalised,
}

/// The simulated LiDAR.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LidarConfig {
    /// Rays, spread evenly over `fov_deg` centred on the heading.
    pub rays: usize,
    pub fov_deg: f64,
    pub range_m: f64,
    /// Hits further than this to either side of the ego's axis are dropped, m.
    pub window_lateral_m: f64,
    /// Hits further ahead than this (or behind the sensor) are dropped, m.
    pub window_longitudinal_m: f64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        LidarConfig {
            rays: 181,
            fov_deg: 180.0,
            range_m: 40.0,
            window_lateral_m: 3.0,
            window_longitudinal_m: 70.0,
        }
    }
}

/// The normalised reward's constants.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct NormalisedReward {
    /// The main reward and the stop bonus are divided by this.
    pub scale: f64,
    /// The LiDAR penalty per step at contact (0 at the end of the range).
    pub danger_per_step: f64,
    /// Added when the destination is reached. The quadratic main reward is flat near the
    /// destination (stopping 5 m short forgoes 0.3 % of its range), so without this an
    /// agent learns to stop just before it and let the time run out.
    pub reach_bonus: f64,
}

impl Default for NormalisedReward {
    fn default() -> Self {
        NormalisedReward {
            scale: 3000.0,
            danger_per_step: 0.02,
            reach_bonus: 1.0,
        }
    }
}

/// Everything about the task; TOML-friendly, every field defaulted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ObstacleConfig {
    pub scenario: Scenario,
    pub reward: RewardKind,
    pub normalised: NormalisedReward,
    pub lidar: LidarConfig,
    /// Width of each of the two lanes, m.
    pub lane_width_m: f64,
    /// From the ego's start (its centre) to the destination, m.
    pub destination_m: f64,
    /// The start speed, also the speed straight and steering drive back to, km/h.
    pub start_speed_kmh: f64,
    pub time_limit_s: f64,
    /// Simulation step, s.
    pub step_s: f64,
    /// The policy decides once per this (a whole number of simulation steps), s.
    pub policy_step_s: f64,
    pub ego_length_m: f64,
    pub ego_width_m: f64,
    pub wheelbase_m: f64,
    /// The front-wheel angle of steer left / right, degrees (at most [`MAX_STEER_DEG`]).
    pub steer_deg: f64,
    /// Acceleration back to the cruise speed, m/s².
    pub accel_mps2: f64,
    /// Deceleration of brake, m/s².
    pub brake_mps2: f64,
    /// Below this the ego counts as stopped, m/s.
    pub stop_speed_mps: f64,
    /// Centre-to-centre distance of the parked vehicle ahead, drawn in this range, m.
    pub static_distance_m: (f64, f64),
    /// The parked vehicle's centre is off the lane centre by up to this, either way, m.
    pub static_lateral_m: f64,
    /// Where the crossing vehicle crosses, ahead of the ego's centre, m.
    pub crossing_distance_m: (f64, f64),
    pub crossing_speed_mps: (f64, f64),
    /// The crossing vehicle is on the ego's lane centre within this of the ego's arrival, s.
    pub crossing_timing_s: f64,
    pub obstacle_length_m: f64,
    pub obstacle_width_m: f64,
    /// Adds two inputs to the study's six: the LiDAR return's lateral and longitudinal rate
    /// of change since the last decision. One return says where the obstacle is, not where it
    /// goes: without them a crossing vehicle right ahead looks like a parked one.
    pub motion_inputs: bool,
}

impl Default for ObstacleConfig {
    fn default() -> Self {
        ObstacleConfig {
            scenario: Scenario::Mixed,
            reward: RewardKind::Normalised,
            normalised: NormalisedReward::default(),
            lidar: LidarConfig::default(),
            lane_width_m: 3.5,
            destination_m: 100.0,
            start_speed_kmh: 40.0,
            time_limit_s: 30.0,
            step_s: 0.1,
            policy_step_s: 0.2,
            ego_length_m: 4.5,
            ego_width_m: 1.8,
            wheelbase_m: 2.7,
            steer_deg: 5.0,
            accel_mps2: 2.0,
            brake_mps2: 8.0,
            stop_speed_mps: 0.1,
            motion_inputs: false,
            static_distance_m: (30.0, 70.0),
            static_lateral_m: 0.5,
            crossing_distance_m: (30.0, 70.0),
            crossing_speed_mps: (1.5, 3.0),
            crossing_timing_s: 0.5,
            obstacle_length_m: 4.5,
            obstacle_width_m: 1.8,
        }
    }
}

impl ObstacleConfig {
    fn validate(&self) -> Result<(), SimError> {
        check_positive(&[
            ("lane_width_m", self.lane_width_m),
            ("destination_m", self.destination_m),
            ("start_speed_kmh", self.start_speed_kmh),
            ("time_limit_s", self.time_limit_s),
            ("step_s", self.step_s),
            ("policy_step_s", self.policy_step_s),
            ("ego_length_m", self.ego_length_m),
            ("ego_width_m", self.ego_width_m),
            ("wheelbase_m", self.wheelbase_m),
            ("steer_deg", self.steer_deg),
            ("accel_mps2", self.accel_mps2),
            ("brake_mps2", self.brake_mps2),
            ("obstacle_length_m", self.obstacle_length_m),
            ("obstacle_width_m", self.obstacle_width_m),
            ("lidar.range_m", self.lidar.range_m),
            ("lidar.window_lateral_m", self.lidar.window_lateral_m),
            (
                "lidar.window_longitudinal_m",
                self.lidar.window_longitudinal_m,
            ),
            ("normalised.scale", self.normalised.scale),
        ])?;
        let non_negative = [
            ("stop_speed_mps", self.stop_speed_mps),
            ("static_lateral_m", self.static_lateral_m),
            ("crossing_timing_s", self.crossing_timing_s),
            ("lidar.fov_deg", self.lidar.fov_deg),
            (
                "normalised.danger_per_step",
                self.normalised.danger_per_step,
            ),
            ("normalised.reach_bonus", self.normalised.reach_bonus),
        ];
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SimError::Config(format!("{name} = {v} must be >= 0")));
            }
        }
        let ranges = [
            ("static_distance_m", self.static_distance_m),
            ("crossing_distance_m", self.crossing_distance_m),
            ("crossing_speed_mps", self.crossing_speed_mps),
        ];
        for (name, (lo, hi)) in ranges {
            if !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi) {
                return Err(SimError::Config(format!(
                    "{name} = ({lo}, {hi}) must be an increasing positive range"
                )));
            }
        }
        if self.steer_deg > MAX_STEER_DEG {
            return Err(SimError::Config(format!(
                "steer_deg = {} exceeds the ±{MAX_STEER_DEG}° bound",
                self.steer_deg
            )));
        }
        if self.lidar.rays == 0 || self.lidar.fov_deg > 360.0 {
            return Err(SimError::Config(
                "lidar needs at least one ray and a field of view of at most 360°".into(),
            ));
        }
        if self.policy_step_s < self.step_s {
            return Err(SimError::Config(
                "policy_step_s must be at least step_s".into(),
            ));
        }
        Ok(())
    }

    fn cruise_speed_mps(&self) -> f64 {
        self.start_speed_kmh / 3.6
    }

    /// y of the ego's (right) lane centre; the other lane's is its negation.
    fn ego_lane_y(&self) -> f64 {
        -self.lane_width_m / 2.0
    }

    fn substeps(&self) -> usize {
        ((self.policy_step_s / self.step_s).round() as usize).max(1)
    }
}

/// The study's main reward at distance `d` to the destination, with `farthest` the start
/// distance (100 m): 3000 − 12,500·(d / farthest)², 3000 at the destination and −9500 at
/// the farthest point, the shape the study states. Its printed coefficients (a = −2,
/// b = −98, c = 3000 in a·d² + b·d + c) give −26,800 at 100 m instead, contradicting it.
pub fn study_main_reward(d: f64, farthest: f64) -> f64 {
    let u = (d / farthest).clamp(0.0, 1.0);
    3000.0 - 12_500.0 * u * u
}

/// The study's LiDAR penalty of the nearest detected distance `x` (m):
/// −0.0011x⁴ + 0.15x³ − 6.60x² + 145x − 3040. Over 0–40 m it rises monotonically from
/// −3040 (contact) to −1016 (40 m): always a large penalty, larger the closer, never a
/// reward.
pub fn lidar_penalty(x: f64) -> f64 {
    (((-0.0011 * x + 0.15) * x - 6.60) * x + 145.0) * x - 3040.0
}

/// The study's bonus for stopping `x` m from the obstacle (given within 10 m): 2200 at
/// contact, 200 at 10 m.
pub fn stop_bonus(x: f64) -> f64 {
    -200.0 * x + 2200.0
}

/// The stop bonus applies when the ego stops this close (LiDAR distance), m.
pub const STOP_BONUS_WITHIN_M: f64 = 10.0;

/// The nearest LiDAR return inside the window.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LidarHit {
    /// Along the ray from the sensor, m.
    pub distance_m: f64,
    /// In the ego frame: ahead and to the left of the sensor, m.
    pub longitudinal_m: f64,
    pub lateral_m: f64,
}

/// Casts `lidar.rays` rays from `origin` around `heading` against `boxes` and returns the
/// nearest hit inside the window, if any.
pub fn scan(
    lidar: &LidarConfig,
    origin: Point,
    heading: f64,
    boxes: &[OrientedBox],
) -> Option<LidarHit> {
    let forward = direction(heading);
    let left = forward.perp();
    let fov = lidar.fov_deg.to_radians();
    let spacing = if lidar.rays > 1 {
        fov / (lidar.rays - 1) as f64
    } else {
        0.0
    };
    let first = if lidar.rays > 1 { -fov / 2.0 } else { 0.0 };
    let mut nearest: Option<LidarHit> = None;
    for k in 0..lidar.rays {
        let ray = direction(heading + first + k as f64 * spacing);
        for b in boxes {
            let Some(t) = b.ray_distance(origin, ray, lidar.range_m) else {
                continue;
            };
            let rel = ray.scale(t);
            let (lon, lat) = (rel.dot(forward), rel.dot(left));
            let inside = (0.0..=lidar.window_longitudinal_m).contains(&lon)
                && lat.abs() <= lidar.window_lateral_m;
            if inside && nearest.is_none_or(|n| t < n.distance_m) {
                nearest = Some(LidarHit {
                    distance_m: t,
                    longitudinal_m: lon,
                    lateral_m: lat,
                });
            }
        }
    }
    nearest
}

/// Prepared once and shared by every environment: the validated config, the straight
/// road's map and the ego's lane centre (its path, for scenes).
#[derive(Debug)]
pub struct ObstacleSetup {
    config: ObstacleConfig,
    map: Map,
    ego_path: Vec<Point>,
}

impl TaskSetup for ObstacleSetup {
    type Config = ObstacleConfig;

    /// On its own straight road: `map` is not used.
    fn prepare(
        _: Option<Arc<Map>>,
        config: ObstacleConfig,
        _: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self>, SimError> {
        ObstacleSetup::new(config)
    }

    fn map(&self) -> &Map {
        &self.map
    }
}

impl ObstacleSetup {
    pub fn new(config: ObstacleConfig) -> Result<Arc<Self>, SimError> {
        config.validate()?;
        // The road runs from 20 m behind the start to 30 m past the destination, so a
        // scene shows road around the ego wherever an episode can end.
        let start = Point::new(-20.0, 0.0);
        let end = Point::new(config.destination_m + 30.0, 0.0);
        let map = straight_road(start, end, 2, config.lane_width_m, config.start_speed_kmh);
        let y = config.ego_lane_y();
        let ego_path = vec![Point::new(0.0, y), Point::new(config.destination_m, y)];
        Ok(Arc::new(ObstacleSetup {
            config,
            map,
            ego_path,
        }))
    }

    pub fn config(&self) -> &ObstacleConfig {
        &self.config
    }
}

/// How one episode went.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ObstacleSummary {
    pub outcome: Outcome,
    pub kind: ObstacleKind,
    pub steps: usize,
    pub episode_return: f64,
    pub mean_speed_mps: f64,
    /// Box-to-box gap to the obstacle when the ego first stopped (None: never stopped), m.
    pub stopping_gap_m: Option<f64>,
    /// Smallest box-to-box gap to the obstacle over the episode, m.
    pub min_gap_m: f64,
}

impl TaskSummary for ObstacleSummary {
    fn outcome(&self) -> Outcome {
        self.outcome
    }

    fn episode_return(&self) -> f64 {
        self.episode_return
    }

    fn metrics(&self) -> Vec<(&'static str, f64)> {
        vec![
            (
                "reached without collision",
                f64::from(u8::from(self.outcome == Outcome::Reached)),
            ),
            (
                "stopping distance m",
                self.stopping_gap_m.unwrap_or(f64::NAN),
            ),
            ("minimum gap m", self.min_gap_m),
            ("mean speed m/s", self.mean_speed_mps),
        ]
    }
}

/// The obstacle-avoidance task as an [`Env`].
#[derive(Debug)]
pub struct ObstacleAvoidance {
    setup: Arc<ObstacleSetup>,
    config: ObstacleConfig,
    ego: Bicycle,
    speed_mps: f64,
    obstacle: Option<(ObstacleKind, Actor)>,
    lidar: Option<LidarHit>,
    /// The return at the previous decision (for the motion inputs).
    previous_lidar: Option<LidarHit>,
    time_s: f64,
    /// Decisions, return, outcome and the ego's positions (one per decision).
    episode: Episode,
    speed_sum: f64,
    stopping_gap_m: Option<f64>,
    stop_bonus_given: bool,
    min_gap_m: f64,
}

impl ObstacleAvoidance {
    pub fn new(setup: Arc<ObstacleSetup>) -> Self {
        let config = setup.config.clone();
        ObstacleAvoidance {
            ego: Bicycle::at_centre(
                Point::new(0.0, config.ego_lane_y()),
                0.0,
                config.wheelbase_m,
            ),
            setup,
            config,
            speed_mps: 0.0,
            obstacle: None,
            lidar: None,
            previous_lidar: None,
            time_s: 0.0,
            episode: Episode::default(),
            speed_sum: 0.0,
            stopping_gap_m: None,
            stop_bonus_given: false,
            min_gap_m: f64::INFINITY,
        }
    }

    /// Chooses the obstacles of the following episodes (the draws per seed stay the same).
    pub fn set_scenario(&mut self, scenario: Scenario) {
        self.config.scenario = scenario;
    }

    /// Chooses the reward of the following steps.
    pub fn set_reward(&mut self, reward: RewardKind) {
        self.config.reward = reward;
    }

    pub fn config(&self) -> &ObstacleConfig {
        &self.config
    }

    pub fn ego(&self) -> &Bicycle {
        &self.ego
    }

    pub fn speed_mps(&self) -> f64 {
        self.speed_mps
    }

    /// The episode's obstacle and what it is (None before a reset).
    pub fn obstacle(&self) -> Option<(ObstacleKind, &Actor)> {
        self.obstacle.as_ref().map(|(k, a)| (*k, a))
    }

    /// The nearest LiDAR return inside the window after the last step.
    pub fn lidar(&self) -> Option<LidarHit> {
        self.lidar
    }

    pub fn outcome(&self) -> Option<Outcome> {
        self.episode.outcome
    }

    fn ego_actor(&self) -> Actor {
        Actor {
            id: 0,
            kind: ActorKind::Car,
            position: self.ego.centre(),
            heading_rad: self.ego.heading,
            speed_mps: self.speed_mps,
            length_m: self.config.ego_length_m,
            width_m: self.config.ego_width_m,
            lane: None,
            aggressiveness: None,
        }
    }

    fn distance_to_destination(&self) -> f64 {
        self.config.destination_m - self.ego.centre().x
    }

    fn sensor(&self) -> Point {
        self.ego
            .centre()
            .add(direction(self.ego.heading).scale(self.config.ego_length_m / 2.0))
    }

    fn rescan(&mut self) {
        let boxes: Vec<OrientedBox> = self.obstacle.iter().map(|(_, a)| a.footprint()).collect();
        self.previous_lidar = self.lidar.take();
        self.lidar = scan(&self.config.lidar, self.sensor(), self.ego.heading, &boxes);
    }

    /// The main reward's potential at the ego's distance `d` (normalised reward).
    fn potential(&self, d: f64) -> f64 {
        study_main_reward(d, self.config.destination_m) / self.config.normalised.scale
    }

    /// Moves everything one simulation step; the outcome if the episode ends in it.
    fn advance(&mut self, action: Action) -> Option<Outcome> {
        let c = &self.config;
        let dt = c.step_s;
        let steer = match action {
            Action::SteerLeft => c.steer_deg.to_radians(),
            Action::SteerRight => -c.steer_deg.to_radians(),
            Action::Straight | Action::Brake => 0.0,
        };
        let accel = match action {
            Action::Brake => -c.brake_mps2,
            _ => ((c.cruise_speed_mps() - self.speed_mps) / dt).clamp(-c.accel_mps2, c.accel_mps2),
        };
        let (speed, travelled) = advance_speed(self.speed_mps, accel, dt);
        self.speed_mps = speed;
        self.ego.advance(travelled, steer);
        if let Some((_, obstacle)) = &mut self.obstacle {
            obstacle.position = obstacle
                .position
                .add(direction(obstacle.heading_rad).scale(obstacle.speed_mps * dt));
        }
        self.time_s += dt;
        let ego_box = self.ego_actor().footprint();
        let gap = self
            .obstacle
            .as_ref()
            .map_or(f64::INFINITY, |(_, a)| ego_box.distance(&a.footprint()));
        self.min_gap_m = self.min_gap_m.min(gap);
        if speed <= c.stop_speed_mps && self.stopping_gap_m.is_none() {
            self.stopping_gap_m = Some(gap).filter(|g| g.is_finite());
        }
        let centre = self.ego.centre();
        if gap <= 0.0 {
            Some(Outcome::Crashed)
        } else if centre.y.abs() > c.lane_width_m {
            Some(Outcome::OffRoad)
        } else if centre.x >= c.destination_m {
            Some(Outcome::Reached)
        } else {
            None
        }
    }

    /// The reward of one policy step from distance `before` to the destination.
    fn reward(&mut self, before: f64, stopped_now: bool) -> f64 {
        let c = &self.config;
        let farthest = c.destination_m;
        // A crash or leaving the road counts as being at the farthest point (the study's
        // worst main reward); otherwise where the ego is.
        let after = match self.episode.outcome {
            Some(Outcome::Crashed | Outcome::OffRoad) => farthest,
            _ => self.distance_to_destination().max(0.0),
        };
        let x = self.lidar.map(|h| h.distance_m);
        let bonus = match x {
            Some(x) if stopped_now && !self.stop_bonus_given && x <= STOP_BONUS_WITHIN_M => {
                self.stop_bonus_given = true;
                stop_bonus(x)
            }
            _ => 0.0,
        };
        match c.reward {
            RewardKind::Study => {
                let main = if self.episode.ended() {
                    study_main_reward(after, farthest)
                } else {
                    0.0
                };
                main + x.map_or(0.0, lidar_penalty) + bonus
            }
            RewardKind::Normalised => {
                let range = c.lidar.range_m;
                let span = lidar_penalty(range) - lidar_penalty(0.0);
                let danger = x.map_or(0.0, |x| {
                    c.normalised.danger_per_step * (lidar_penalty(x) - lidar_penalty(range)) / span
                });
                let reach = if self.episode.outcome == Some(Outcome::Reached) {
                    c.normalised.reach_bonus
                } else {
                    0.0
                };
                self.potential(after) - self.potential(before)
                    + danger
                    + bonus / c.normalised.scale
                    + reach
            }
        }
    }
}

impl Driving for ObstacleAvoidance {
    type Summary = ObstacleSummary;
    type Action = Action;
    const FALLBACK: Action = Action::Brake;

    fn spec(&self) -> ObservationSpec {
        ObservationSpec {
            channels: 0,
            height: 0,
            width: 0,
            scalars: SCALARS
                + if self.config.motion_inputs {
                    MOTION_SCALARS
                } else {
                    0
                },
        }
    }

    episode_in_field!();

    fn started(&self) -> bool {
        self.obstacle.is_some()
    }

    fn begin(&mut self, seed: u64) {
        let c = self.config.clone();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // Every draw is made whatever the scenario, so a seed gives the same static and
        // crossing obstacles under Static, Crossing and Mixed.
        let mut within = |(lo, hi): (f64, f64)| lo + (hi - lo) * rng.random::<f64>();
        let coin = within((0.0, 1.0));
        let parked_x = within(c.static_distance_m);
        let parked_dy = within((-c.static_lateral_m, c.static_lateral_m));
        let crossing_x = within(c.crossing_distance_m);
        let crossing_speed = within(c.crossing_speed_mps);
        let from_left = within((0.0, 1.0)) < 0.5;
        let timing = within((-c.crossing_timing_s, c.crossing_timing_s));
        let kind = match c.scenario {
            Scenario::Static => ObstacleKind::Parked,
            Scenario::Crossing => ObstacleKind::Crossing,
            Scenario::Mixed if coin < 0.5 => ObstacleKind::Parked,
            Scenario::Mixed => ObstacleKind::Crossing,
        };
        let lane_y = c.ego_lane_y();
        let (position, heading, speed) = match kind {
            ObstacleKind::Parked => (Point::new(parked_x, lane_y + parked_dy), 0.0, 0.0),
            ObstacleKind::Crossing => {
                let on_lane_at = (crossing_x / c.cruise_speed_mps() + timing).max(0.0);
                let (heading, sign) = if from_left {
                    (-FRAC_PI_2, 1.0)
                } else {
                    (FRAC_PI_2, -1.0)
                };
                let y = lane_y + sign * crossing_speed * on_lane_at;
                (Point::new(crossing_x, y), heading, crossing_speed)
            }
        };
        self.obstacle = Some((
            kind,
            Actor {
                id: 1,
                kind: ActorKind::Car,
                position,
                heading_rad: heading,
                speed_mps: speed,
                length_m: c.obstacle_length_m,
                width_m: c.obstacle_width_m,
                lane: None,
                aggressiveness: None,
            },
        ));
        self.ego = Bicycle::at_centre(Point::new(0.0, lane_y), 0.0, c.wheelbase_m);
        self.speed_mps = c.cruise_speed_mps();
        self.time_s = 0.0;
        self.speed_sum = 0.0;
        self.stopping_gap_m = None;
        self.stop_bonus_given = false;
        let ego_box = self.ego_actor().footprint();
        self.min_gap_m = self
            .obstacle
            .as_ref()
            .map_or(f64::INFINITY, |(_, a)| ego_box.distance(&a.footprint()));
        self.episode.reset(Some(self.ego.centre()));
        self.lidar = None;
        self.rescan();
    }

    fn decide(&mut self, action: Action) -> (f64, Option<Outcome>) {
        let before = self.distance_to_destination().max(0.0);
        let was_stopped = self.speed_mps <= self.config.stop_speed_mps;
        let mut outcome = None;
        for _ in 0..self.config.substeps() {
            outcome = self.advance(action);
            if outcome.is_some() {
                break;
            }
        }
        if outcome.is_none() && self.time_s >= self.config.time_limit_s - 1e-9 {
            outcome = Some(Outcome::TimeOver);
        }
        // The reward reads how the episode ended.
        self.episode.outcome = outcome;
        self.episode.steps += 1;
        self.speed_sum += self.speed_mps;
        self.episode.trajectory.push(self.ego.centre());
        self.rescan();
        let stopped_now = !was_stopped && self.speed_mps <= self.config.stop_speed_mps;
        let reward = self.reward(before, stopped_now);
        (reward, outcome)
    }

    fn observe(&self) -> Observation {
        let c = &self.config;
        let centre = self.ego.centre();
        let (lon, lat) = self.lidar.map_or((1.0, 0.0), |h| {
            (
                h.longitudinal_m / c.lidar.range_m,
                h.lateral_m / c.lidar.window_lateral_m,
            )
        });
        let mut scalars = vec![
            (self.distance_to_destination() / c.destination_m).clamp(-1.0, 1.5),
            (centre.y / c.lane_width_m).clamp(-1.5, 1.5),
            (self.ego.heading / 30f64.to_radians()).clamp(-3.0, 3.0),
            self.speed_mps / c.cruise_speed_mps(),
            lon,
            lat,
        ];
        if c.motion_inputs {
            let (lateral_rate, longitudinal_rate) = match (self.lidar, self.previous_lidar) {
                (Some(now), Some(before)) => (
                    (now.lateral_m - before.lateral_m) / c.policy_step_s,
                    (now.longitudinal_m - before.longitudinal_m) / c.policy_step_s,
                ),
                _ => (0.0, 0.0),
            };
            // Over 5 m/s (a brisk crossing) and over the cruise speed.
            scalars.push((lateral_rate / 5.0).clamp(-2.0, 2.0));
            scalars.push((longitudinal_rate / c.cruise_speed_mps()).clamp(-2.0, 2.0));
        }
        Observation {
            layers: Vec::new(),
            scalars: scalars.iter().map(|&v| v as f32).collect(),
        }
    }

    fn summary(&self) -> ObstacleSummary {
        ObstacleSummary {
            outcome: self.episode.final_outcome(),
            kind: self
                .obstacle
                .as_ref()
                .map_or(ObstacleKind::Parked, |(k, _)| *k),
            steps: self.episode.steps,
            episode_return: self.episode.episode_return,
            mean_speed_mps: self.episode.mean(self.speed_sum),
            stopping_gap_m: self.stopping_gap_m,
            min_gap_m: self.min_gap_m,
        }
    }
}

const STATIC_OBSTACLE: &str = "static obstacle";
const CROSSING_OBSTACLE: &str = "crossing obstacle";

impl Task for ObstacleAvoidance {
    type Config = ObstacleConfig;
    type Setup = ObstacleSetup;
    /// The obstacles the episodes get.
    type Condition = Scenario;

    const ID: TaskId = TaskId::ObstacleAvoidance;

    /// The config's scenario, whatever the traffic (there is none).
    fn training_env(setup: &Arc<ObstacleSetup>, _: TrafficLevel) -> Self {
        ObstacleAvoidance::new(Arc::clone(setup))
    }

    fn env(setup: &Arc<ObstacleSetup>, scenario: &Scenario) -> Self {
        let mut env = ObstacleAvoidance::new(Arc::clone(setup));
        env.set_scenario(*scenario);
        env
    }

    /// Each scenario on its own: static, then crossing.
    fn conditions(_: &ConditionChoice) -> Vec<Scenario> {
        vec![Scenario::Static, Scenario::Crossing]
    }

    fn condition_name(scenario: &Scenario) -> String {
        match scenario {
            Scenario::Static => STATIC_OBSTACLE,
            Scenario::Crossing => CROSSING_OBSTACLE,
            Scenario::Mixed => "mixed obstacles",
        }
        .to_owned()
    }

    /// Each scenario on its own, as evaluated.
    fn validation_conditions(_: TrafficLevel) -> Vec<(String, Scenario)> {
        Self::conditions(&ConditionChoice::default())
            .into_iter()
            .map(|scenario| (Self::condition_name(&scenario), scenario))
            .collect()
    }

    /// Mixed scenarios: the recorded episodes show both kinds of obstacle.
    fn recorded_condition(_: TrafficLevel) -> Scenario {
        Scenario::Mixed
    }

    fn baselines() -> Vec<(String, PolicyFactory<Self>)> {
        baselines_with_rule::<Self, PassOrYield>(&Action::NAMES, "rule: pass or yield")
    }

    fn scene(&self) -> Option<Scene<'_>> {
        let (_, obstacle) = self.obstacle.as_ref()?;
        Some(Scene {
            map: &self.setup.map,
            time_s: self.time_s,
            actors: vec![self.ego_actor(), obstacle.clone()],
            ego: 0,
            ego_path: &self.setup.ego_path,
        })
    }
}

/// The rule baseline, reading the privileged state: a parked vehicle is passed on the other
/// lane (pure pursuit on its centre line from 45 m before it until the ego's rear is 6 m
/// past it, then back); for a crossing vehicle the ego brakes once within its stopping
/// distance + 6 m of it while it has not yet cleared the ego's corridor (the ego's width
/// and 0.7 m more each side, in its direction of travel), and drives on when it has.
/// Pure pursuit's angle becomes steer left / right when beyond half the steering angle.
#[derive(Debug, Clone, Copy, Default)]
pub struct PassOrYield;

impl PassOrYield {
    fn decide(env: &ObstacleAvoidance) -> Action {
        let c = env.config();
        let Some((kind, obstacle)) = env.obstacle() else {
            return Action::Straight;
        };
        let ego = env.ego();
        let centre = ego.centre();
        let v = env.speed_mps();
        let front_x = centre.x + c.ego_length_m / 2.0;
        let rear_x = centre.x - c.ego_length_m / 2.0;
        let corners = obstacle.footprint().corners();
        let (mut x_min, mut x_max, mut y_min, mut y_max) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        for p in corners {
            x_min = x_min.min(p.x);
            x_max = x_max.max(p.x);
            y_min = y_min.min(p.y);
            y_max = y_max.max(p.y);
        }
        let own_lane = c.ego_lane_y();
        let target_y = match kind {
            ObstacleKind::Parked => {
                let passing = x_min - front_x < 45.0 && rear_x < x_max + 6.0;
                if passing { -own_lane } else { own_lane }
            }
            ObstacleKind::Crossing => {
                let half = c.ego_width_m / 2.0 + 0.7;
                let moving_left = obstacle.heading_rad.sin() > 0.0;
                let cleared = if moving_left {
                    y_min > centre.y + half
                } else {
                    y_max < centre.y - half
                };
                let gap = x_min - front_x;
                let stopping = v * v / (2.0 * c.brake_mps2) + v * c.policy_step_s + 6.0;
                if !cleared && x_max > rear_x && gap < stopping {
                    return Action::Brake;
                }
                own_lane
            }
        };
        let lookahead = 6.0 + 0.8 * v;
        let target = Point::new(ego.rear.x + lookahead, target_y);
        let angle = ego.pure_pursuit(target, MAX_STEER_DEG.to_radians());
        let threshold = c.steer_deg.to_radians() / 2.0;
        if angle > threshold {
            Action::SteerLeft
        } else if angle < -threshold {
            Action::SteerRight
        } else {
            Action::Straight
        }
    }
}

impl TaskPolicy<ObstacleAvoidance> for PassOrYield {
    fn act(&mut self, envs: &[&ObstacleAvoidance], _: &[&Observation], actions: &mut Vec<usize>) {
        actions.clear();
        actions.extend(envs.iter().map(|e| Self::decide(e) as usize));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::Env;
    use crate::eval::{TaskResult, run_episodes};

    fn env(scenario: Scenario) -> ObstacleAvoidance {
        let setup = ObstacleSetup::new(ObstacleConfig {
            scenario,
            ..ObstacleConfig::default()
        });
        #[allow(clippy::unwrap_used)]
        ObstacleAvoidance::new(setup.unwrap())
    }

    fn run<P: TaskPolicy<ObstacleAvoidance>>(
        scenario: Scenario,
        policy: impl Fn() -> P + Sync,
        n: u64,
    ) -> Vec<ObstacleSummary> {
        let seeds: Vec<u64> = (0..n).collect();
        run_episodes(|| env(scenario), policy, &seeds, 8)
    }

    #[test]
    fn reward_shapes_match_the_study() {
        assert_eq!(study_main_reward(0.0, 100.0), 3000.0);
        assert_eq!(study_main_reward(100.0, 100.0), -9500.0);
        // The printed coefficients would give this at 100 m.
        assert_eq!(-2.0 * 100.0f64.powi(2) - 98.0 * 100.0 + 3000.0, -26_800.0);
        assert!((lidar_penalty(0.0) + 3040.0).abs() < 1e-9);
        assert!((lidar_penalty(40.0) + 1016.0).abs() < 1e-6);
        // Monotone over the range: closer is always worse.
        let values: Vec<f64> = (0..=400).map(|i| lidar_penalty(i as f64 / 10.0)).collect();
        assert!(values.windows(2).all(|w| w[1] > w[0]));
        assert_eq!(stop_bonus(10.0), 200.0);
        assert_eq!(stop_bonus(0.0), 2200.0);
    }

    #[test]
    fn lidar_sees_a_box_ahead_and_nothing_outside_the_window() {
        let lidar = LidarConfig::default();
        let ahead = OrientedBox::new(Point::new(20.0, 0.0), 0.0, 4.0, 2.0);
        let hit = scan(&lidar, Point::new(0.0, 0.0), 0.0, &[ahead]);
        let hit = hit.unwrap_or(LidarHit {
            distance_m: f64::NAN,
            longitudinal_m: f64::NAN,
            lateral_m: f64::NAN,
        });
        assert!((hit.distance_m - 18.0).abs() < 1e-9, "{hit:?}");
        assert!((hit.longitudinal_m - 18.0).abs() < 1e-9 && hit.lateral_m.abs() < 1e-9);
        // The same box rotated with the ego: the offsets are in the ego frame.
        let turned = OrientedBox::new(Point::new(0.0, 20.0), FRAC_PI_2, 4.0, 2.0);
        let hit = scan(&lidar, Point::new(0.0, 0.0), FRAC_PI_2, &[turned]);
        assert!(hit.is_some_and(|h| (h.longitudinal_m - 18.0).abs() < 1e-9));
        // Beside the window (its near side 4 m off the axis), behind, beyond the range.
        let beside = OrientedBox::new(Point::new(10.0, 5.0), 0.0, 4.0, 2.0);
        let behind = OrientedBox::new(Point::new(-10.0, 0.0), 0.0, 4.0, 2.0);
        let far = OrientedBox::new(Point::new(45.0, 0.0), 0.0, 4.0, 2.0);
        assert_eq!(
            scan(&lidar, Point::new(0.0, 0.0), 0.0, &[beside, behind, far]),
            None
        );
        // Partly inside: the nearest hit is at the window's edge or within it.
        let edge = OrientedBox::new(Point::new(10.0, 3.5), 0.0, 4.0, 2.0);
        let hit = scan(&lidar, Point::new(0.0, 0.0), 0.0, &[edge]);
        assert!(
            hit.is_some_and(|h| h.lateral_m <= 3.0 && h.lateral_m >= 2.5),
            "{hit:?}"
        );
    }

    #[test]
    fn motion_inputs_tell_a_crossing_vehicle_from_a_parked_one() {
        let lateral_rates = |scenario: Scenario| -> Vec<f32> {
            let setup = ObstacleSetup::new(ObstacleConfig {
                scenario,
                motion_inputs: true,
                ..ObstacleConfig::default()
            });
            #[allow(clippy::unwrap_used)]
            let mut env = ObstacleAvoidance::new(setup.unwrap());
            assert_eq!(env.observation_spec().scalars, SCALARS + MOTION_SCALARS);
            let first = env.reset(5);
            assert_eq!(
                first.scalars[SCALARS..],
                [0.0, 0.0],
                "no motion before a second return"
            );
            // Drive on until the obstacle is in view, then brake so the ego stays behind it
            // while a crossing one passes in front.
            let mut seen = false;
            let mut rates = Vec::new();
            for _ in 0..100 {
                let action = if seen {
                    Action::Brake
                } else {
                    Action::Straight
                };
                let step = env.step(action as usize);
                seen |= step.observation.scalars[4] < 1.0;
                rates.push(step.observation.scalars[SCALARS]);
                if step.outcome.is_some() {
                    break;
                }
            }
            assert!(seen, "{scenario:?}: the obstacle came into view");
            rates
        };
        let parked = lateral_rates(Scenario::Static);
        let crossing = lateral_rates(Scenario::Crossing);
        assert!(parked.iter().all(|r| r.abs() < 0.02), "{parked:?}");
        // 1.5-3 m/s across the road over 5 m/s (once in view).
        assert!(crossing.iter().any(|r| r.abs() > 0.2), "{crossing:?}");
    }

    #[test]
    fn driving_straight_hits_a_parked_vehicle_and_a_crossing_one() {
        for scenario in [Scenario::Static, Scenario::Crossing] {
            let episodes = run(scenario, || ConstantAction(Action::Straight as usize), 20);
            assert!(
                episodes.iter().all(|e| e.outcome == Outcome::Crashed),
                "{scenario:?}: {:?}",
                episodes.iter().map(|e| e.outcome).collect::<Vec<_>>()
            );
            assert!(episodes.iter().all(|e| e.min_gap_m == 0.0));
        }
    }

    #[test]
    fn the_rule_reaches_the_destination_in_both_scenarios() {
        for scenario in [Scenario::Static, Scenario::Crossing] {
            let episodes = run(scenario, || PassOrYield, 100);
            let result = TaskResult::of(&episodes);
            assert!(result.reaches >= 0.95, "{scenario:?}: {result:?}");
        }
        // The rule stops for crossing vehicles, not for parked ones.
        let crossing = run(Scenario::Crossing, || PassOrYield, 20);
        assert!(crossing.iter().any(|e| e.stopping_gap_m.is_some()));
    }

    #[test]
    fn episodes_are_deterministic_and_the_scenario_only_picks_the_obstacle() {
        let a = run(Scenario::Mixed, || PassOrYield, 16);
        let b = run(Scenario::Mixed, || PassOrYield, 16);
        assert_eq!(a, b);
        let kinds: Vec<ObstacleKind> = a.iter().map(|e| e.kind).collect();
        assert!(kinds.contains(&ObstacleKind::Parked) && kinds.contains(&ObstacleKind::Crossing));
        let mut one = env(Scenario::Static);
        let first = one.reset(3);
        one.step(Action::SteerLeft as usize);
        assert_eq!(one.reset(3), first);
    }

    #[test]
    fn any_action_index_and_steps_after_the_end_are_safe() {
        let mut e = env(Scenario::Crossing);
        // Before any reset: a finished step, no panic.
        assert!(e.step(0).outcome.is_some());
        e.reset(1);
        let mut last = None;
        for i in 0..1000 {
            let step = e.step(i * 7919 % 11);
            assert!(step.observation.scalars.iter().all(|v| v.is_finite()));
            assert_eq!(step.observation.scalars.len(), SCALARS);
            if step.outcome.is_some() {
                last = step.outcome;
                break;
            }
        }
        assert!(last.is_some());
        let again = e.step(0);
        assert_eq!((again.reward, again.outcome), (0.0, last));
    }

    #[test]
    fn normalised_rewards_are_small_and_study_ones_follow_the_terms() {
        let mut e = env(Scenario::Static);
        e.reset(5);
        let mut total = 0.0;
        loop {
            let step = e.step(Action::Straight as usize);
            assert!(step.reward.abs() < 5.0, "{}", step.reward);
            total += f64::from(step.reward);
            if step.outcome.is_some() {
                break;
            }
        }
        // Driving into the parked vehicle loses every bit of progress: the potential
        // returns to the farthest point's, minus the danger terms.
        assert!(total < 0.0, "{total}");
        e.set_reward(RewardKind::Study);
        e.reset(5);
        let mut study = 0.0;
        let mut crashed = false;
        while !crashed {
            let step = e.step(Action::Straight as usize);
            study += f64::from(step.reward);
            crashed = step.outcome.is_some();
        }
        assert!(study < -9500.0, "{study}");
    }

    #[test]
    fn invalid_configs_are_refused() {
        let bad = [
            ObstacleConfig {
                steer_deg: 40.0,
                ..ObstacleConfig::default()
            },
            ObstacleConfig {
                step_s: 0.0,
                ..ObstacleConfig::default()
            },
            ObstacleConfig {
                static_distance_m: (70.0, 30.0),
                ..ObstacleConfig::default()
            },
        ];
        for config in bad {
            assert!(ObstacleSetup::new(config).is_err());
        }
    }

    use crate::tasks::ConstantAction;
}
