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
    TaskSummary, act_each, baselines_with_rule, check_positive, turn,
};
use crate::world::TrafficLevel;

mod config;
mod task;

pub use config::*;
pub use task::*;

actions! {
    /// The four actions, by index.
    pub enum Action {
        Straight = 0 => "straight",
        Brake = 1 => "brake",
        SteerLeft = 2 => "steer_left",
        SteerRight = 3 => "steer_right",
    }
    fallback Brake;
}

/// The obstacle-avoidance task as an [`crate::Env`].
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

    fn decide(&mut self, action: Action) -> Option<(f64, Option<Outcome>)> {
        self.obstacle.as_ref()?;
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
        Some((reward, outcome))
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
}

#[cfg(test)]
mod tests;
