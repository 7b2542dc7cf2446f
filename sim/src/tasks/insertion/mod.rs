//! Roundabout insertion (after the Parma study): the ego starts before an entry of a
//! roundabout and must join the circulating traffic and leave at its exit.
//!
//! - Actions: **Permitted** (comfort acceleration up to the target speed), **Not
//!   Permitted** (decelerate by min(max deceleration, the deceleration that stops the
//!   front at the yield line); full braking once past it), **Caution** (speed held at half
//!   the target, within a ±0.5 m/s band). Under every action the ego also keeps an IDM
//!   following distance to a vehicle ahead on its own path (not to vehicles coming round
//!   the ring: whether to go in front of those is the decision being learned), and once
//!   it has entered it brakes for a vehicle merging ahead of it from a later entry, as the
//!   world's other drivers do, and under every action for a car whose body covers its path
//!   within 12 m ahead (one leaving the ring in front of it).
//! - Reward per step: `r_danger + r_terminal + r_indecision + r_speed`, see
//!   [`RewardConfig`]; σ = 1 − aggressiveness.
//! - Termination: Reached (the ego's centre passes a point `goal_past_exit_m` into its exit
//!   lane), Crashed (its footprint overlaps another's), OffRoad (its centre leaves the
//!   navigable area), TimeOver (`time_limit_s`).
//! - The ego's aggressiveness is drawn uniformly in [0, 1] per episode for training, or
//!   fixed for evaluation ([`eval::insertion`](crate::eval::insertion): conditions of traffic
//!   × aggressiveness); other drivers draw their own.
//! - Baselines: the Parma study's rules ([`crate::baselines::Baseline::STANDARD`]).

use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use super::motion_inputs::{MOTION_SCALARS, MotionHistory};
use super::roundabouts::{EgoView, RoundaboutSetup, RoundaboutTaskConfig, ego_scene};
use super::{
    ConditionChoice, Driving, Episode, LayerFrame, PolicyFactory, Task, TaskId, TaskSummary,
    check_positive,
};
use crate::baselines::{Baseline, InsertionPolicy};
use crate::env::{Observation, ObservationSpec, Outcome};
use crate::error::SimError;
use crate::eval::insertion::{self as insertion_eval, Condition};
use crate::eval::{EvalHeader, EvalReport, Evaluation};
use crate::observer::SceneObserver;
use crate::render::{BevConfig, BevRenderer};
use crate::roundabout::LayoutConfig;
use crate::scene::Scene;
use crate::world::{CalibratedWorld, Driver, EgoConfig, TrafficConfig, TrafficLevel, World};

mod config;
mod reward;
mod task;

pub use config::*;

actions! {
    /// The three actions, by index.
    pub enum Action {
        Permitted = 0 => "permitted",
        NotPermitted = 1 => "not_permitted",
        Caution = 2 => "caution",
    }
    fallback NotPermitted;
}

/// The roundabout insertion task as an [`crate::Env`].
#[derive(Debug)]
pub struct RoundaboutInsertion {
    setup: Arc<InsertionSetup>,
    config: InsertionConfig,
    roundabout: usize,
    world: Option<World>,
    route: usize,
    aggressiveness: f64,
    last_action: Action,
    /// World steps, return, outcome and the ego's positions (one per world step).
    episode: Episode,
    /// The seed of the current episode, and the decisions taken in it (the inputs of a
    /// [`crate::baselines::Policy`]).
    episode_seed: u64,
    decisions: usize,
    start_time_s: f64,
    goal_s: f64,
    time_limit_s: f64,
    speed_sum: f64,
    entered_at_s: Option<f64>,
    entry_lag_s: Option<f64>,
    /// The ids of the circulating vehicles the ego entered less than `cut_in_s` in front of.
    cut_off: Vec<u32>,
    close_following_steps: usize,
    cut_in_steps: usize,
    view: EgoView,
    /// The ego's speeds this episode, for [`InsertionConfig::motion_inputs`].
    motion: MotionHistory,
    /// The ego's following model: IDM with the parameters of a driver of aggressiveness 0.5,
    /// or of the ego's own with [`InsertionConfig::ego_style_from_aggressiveness`].
    follower: Driver,
}

impl RoundaboutInsertion {
    pub fn new(setup: Arc<InsertionSetup>) -> Self {
        let config = setup.config.clone();
        let view = EgoView::spaced(&config.observation, config.frame_spacing());
        let follower = Driver::new(&config.traffic.drivers, 0.5);
        let motion = MotionHistory::new(config.traffic.step_s);
        RoundaboutInsertion {
            setup,
            config,
            roundabout: 0,
            world: None,
            route: 0,
            aggressiveness: 0.5,
            last_action: Action::Permitted,
            episode: Episode::default(),
            episode_seed: 0,
            decisions: 0,
            start_time_s: 0.0,
            goal_s: 0.0,
            time_limit_s: 0.0,
            speed_sum: 0.0,
            entered_at_s: None,
            entry_lag_s: None,
            cut_off: Vec::new(),
            close_following_steps: 0,
            cut_in_steps: 0,
            view,
            motion,
            follower,
        }
    }

    /// Sets the traffic level of the following episodes.
    pub fn set_traffic(&mut self, level: TrafficLevel) {
        self.config.traffic.level = level;
    }

    /// Fixes the ego's aggressiveness (evaluation) or, with None, draws it per episode.
    pub fn set_aggressiveness(&mut self, aggressiveness: Option<f64>) {
        self.config.aggressiveness = aggressiveness.map(|a| a.clamp(0.0, 1.0));
    }

    pub fn config(&self) -> &InsertionConfig {
        &self.config
    }

    pub fn world(&self) -> Option<&World> {
        self.world.as_ref()
    }

    /// The episode's outcome once it has ended.
    pub fn outcome(&self) -> Option<Outcome> {
        self.episode.outcome
    }

    /// The seed the current episode was reset with.
    pub fn episode_seed(&self) -> u64 {
        self.episode_seed
    }

    /// Decisions taken so far in the episode ([`crate::Env::step`] calls).
    pub fn decisions(&self) -> usize {
        self.decisions
    }

    /// The newest bird's-eye frame (`[layer, row, column]`, see [`BevConfig::layers`]).
    pub fn newest_frame(&self) -> &[u8] {
        self.view.newest()
    }

    /// The bird's-eye renderer of the current episode's roundabout: what draws the layers,
    /// so a scene rebuilt elsewhere (from a recorded log) is drawn exactly the same way.
    pub fn renderer(&self) -> &BevRenderer {
        self.setup.roundabouts.renderer(self.roundabout)
    }

    /// What the rule-based baselines see.
    pub fn state(&self) -> InsertionState {
        let Some((world, ego)) = self.world_and_ego() else {
            return InsertionState {
                nearest_circulating_m: f64::INFINITY,
                ego_entered: false,
                to_yield_line_m: 0.0,
                speed_mps: 0.0,
                target_speed_mps: 0.0,
                aggressiveness: self.aggressiveness,
                merge_lag_s: None,
            };
        };
        let me = &world.vehicles()[ego];
        let route = world.route(me);
        let layout = world.layout();
        // The ring lanes the ego's entry meets: its merge lane and those outside it (on a
        // multi-lane ring, traffic on lanes inside the merge lane does not cross its way).
        let merge_rank = layout
            .ring_lane_ranks
            .get(&route.merge_lane)
            .copied()
            .unwrap_or(0);
        let nearest_circulating_m = world
            .vehicles()
            .iter()
            .filter(|v| !v.is_ego())
            .filter(|v| {
                let r = world.route(v);
                v.s >= r.merge_s
                    && v.s < r.exit_s
                    && layout
                        .ring_rank_at(v.route, v.piece)
                        .is_none_or(|rank| rank <= merge_rank)
            })
            .map(|v| v.position.distance(me.position))
            .fold(f64::INFINITY, f64::min);
        InsertionState {
            nearest_circulating_m,
            ego_entered: me.committed,
            to_yield_line_m: route.yield_s - (me.s + me.length / 2.0),
            speed_mps: me.speed,
            target_speed_mps: self.target_speed(world, ego),
            aggressiveness: self.aggressiveness,
            merge_lag_s: world.merge_lag_s(ego),
        }
    }

    fn world_and_ego(&self) -> Option<(&World, usize)> {
        let w = self.world.as_ref()?;
        Some((w, w.ego_index()?))
    }

    /// The ego's following model for this episode's aggressiveness.
    fn ego_follower(&self) -> Driver {
        let c = &self.config;
        let style = if c.ego_style_from_aggressiveness {
            self.aggressiveness
        } else {
            0.5
        };
        Driver::new(&c.traffic.drivers, style)
    }

    /// The speed the ego aims for under Permitted: its route's nominal speed (limit and
    /// curves) at its front, times its style's speed factor.
    fn target_speed(&self, world: &World, ego: usize) -> f64 {
        let me = &world.vehicles()[ego];
        let nominal = world.route(me).path.speed_at(me.s + me.length / 2.0);
        (nominal * self.config.ego_speed_factor(self.aggressiveness)).max(0.5)
    }

    /// The ego's acceleration under `action`.
    fn ego_accel(&self, world: &World, ego: usize, action: Action) -> f64 {
        let c = &self.config;
        let me = &world.vehicles()[ego];
        let v = me.speed;
        let target = self.target_speed(world, ego);
        let dt = c.traffic.step_s;
        let toward =
            |goal: f64| ((goal - v) / dt).clamp(-c.comfort_decel_mps2, c.comfort_accel_mps2);
        let chosen = match action {
            Action::Permitted => toward(target),
            Action::Caution => {
                let half = target / 2.0;
                if (v - half).abs() <= c.caution_band_mps {
                    0.0
                } else {
                    toward(half)
                }
            }
            Action::NotPermitted => {
                let to_line = world.route(me).yield_s - (me.s + me.length / 2.0);
                if me.committed || to_line <= 0.0 {
                    -c.ego.max_brake_mps2
                } else if v <= 0.0 {
                    0.0
                } else {
                    -(v * v / (2.0 * to_line.max(0.05))).min(c.ego.max_brake_mps2)
                }
            }
        };
        let mut follow = world.leader(ego).map_or(f64::INFINITY, |l| {
            self.follower
                .idm(v, target.max(0.1), Some((l.gap_m, l.closing_mps)))
        });
        // Once in, a car cutting in ahead from a later entry is braked for as every other
        // driver of the world brakes for one (the decision learned is the ego's own entry).
        if me.committed
            && let Some(m) = world.merging_leader(ego)
        {
            let cut_in = self
                .follower
                .idm(v, target.max(0.1), Some((m.gap_m, m.closing_mps)));
            follow = follow.min(cut_in.max(-self.follower.merge_brake_mps2));
        }
        // A car just ahead whose body still covers the ego's path (leaving the ring, or
        // crossing it) is braked for whatever the action.
        if let Some(o) = world.obstacle_on_path(ego, OBSTACLE_HORIZON_M) {
            let obstacle = self
                .follower
                .idm(v, target.max(0.1), Some((o.gap_m, o.closing_mps)));
            follow = follow.min(obstacle);
        }
        chosen.min(follow)
    }

    /// Draws the current scene: the first frame of an episode, or the next one.
    fn render(&mut self, first: bool) {
        let world = self.world.take();
        self.draw(world.as_ref(), first);
        self.world = world;
    }

    /// Draws `world`'s scene into the view.
    fn draw(&mut self, world: Option<&World>, first: bool) {
        let scene = world.and_then(|world| {
            ego_scene(
                self.setup.map(),
                world,
                self.start_time_s,
                Some(self.aggressiveness),
            )
        });
        self.view.draw(
            self.setup.roundabouts.renderer(self.roundabout),
            scene,
            first,
        );
    }
}

impl Driving for RoundaboutInsertion {
    type Summary = EpisodeSummary;
    type Action = Action;

    fn summary(&self) -> EpisodeSummary {
        EpisodeSummary {
            outcome: self.episode.final_outcome(),
            steps: self.episode.steps,
            episode_return: self.episode.episode_return,
            mean_speed_mps: self.episode.mean(self.speed_sum),
            time_to_enter_s: self.entered_at_s,
            aggressiveness: self.aggressiveness,
            close_following_steps: self.close_following_steps,
            cut_in_steps: self.cut_in_steps,
            entry_lag_s: self.entry_lag_s,
        }
    }

    fn spec(&self) -> ObservationSpec {
        self.setup.observation_spec()
    }

    episode_in_field!();

    fn begin(&mut self, seed: u64) {
        self.episode_seed = seed;
        self.decisions = 0;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (self.roundabout, self.route) = self.setup.roundabouts.draw_route(&mut rng);
        let layout = Arc::clone(self.setup.roundabouts.layout(self.roundabout));
        let drawn_aggressiveness: f64 = rng.random();
        self.aggressiveness = self.config.aggressiveness.unwrap_or(drawn_aggressiveness);
        self.follower = self.ego_follower();
        let speed_draw: f64 = rng.random();
        let world_seed: u64 = rng.random();
        let mut world = World::new(
            Arc::clone(&layout),
            self.config.traffic.clone(),
            self.config.ego,
            world_seed,
        );
        world.warm_up(self.config.traffic.warm_up_s);
        let route = &layout.routes[self.route];
        let s0 = (route.yield_s - self.config.start_distance_m - self.config.ego.length_m / 2.0)
            .max(self.config.ego.length_m / 2.0);
        let (lo, hi) = self.config.start_speed_fraction;
        let target = route.path.speed_at(s0 + self.config.ego.length_m / 2.0)
            * self.config.ego_speed_factor(self.aggressiveness);
        let speed = target * (lo + (hi - lo) * speed_draw);
        world.insert_ego(self.route, s0, speed, 8.0);
        self.goal_s = (route.exit_s + self.config.goal_past_exit_m).min(route.path.length() - 0.1);
        self.time_limit_s = self
            .config
            .time_limit_s
            .max(self.config.time_limit_factor * route.path.travel_time(s0, self.goal_s));
        self.start_time_s = world.time_s();
        self.world = Some(world);
        self.last_action = Action::Permitted;
        self.speed_sum = 0.0;
        self.entered_at_s = None;
        self.entry_lag_s = None;
        self.cut_off.clear();
        self.close_following_steps = 0;
        self.cut_in_steps = 0;
        let start = self
            .world_and_ego()
            .map(|(w, e)| (w.vehicles()[e].position, w.vehicles()[e].speed));
        self.episode.reset(start.map(|(p, _)| p));
        if let Some((_, v)) = start {
            self.motion.reset(v);
        }
        self.render(true);
    }

    fn decide(&mut self, action: Action) -> Option<(f64, Option<Outcome>)> {
        let mut world = self.world.take()?;
        self.decisions += 1;
        let (mut reward, mut outcome) = (0.0, None);
        for _ in 0..self.config.action_repeat {
            let (r, o) = match world.ego_index() {
                Some(ego) => {
                    let accel = self.ego_accel(&world, ego, action);
                    world.step(accel);
                    self.resolve(&mut world, action)
                }
                None => (0.0, Some(Outcome::TimeOver)),
            };
            // The indecision penalty is for changing the action: once per decision.
            self.last_action = action;
            reward += r;
            outcome = o;
            if self.config.frames_every_step() {
                self.draw(Some(&world), false);
            }
            if outcome.is_some() {
                break;
            }
        }
        self.world = Some(world);
        if !self.config.frames_every_step() {
            self.render(false);
        }
        Some((reward, outcome))
    }

    fn observe(&self) -> Observation {
        let layers = self.view.layers();
        let (speed, target) = self.world_and_ego().map_or((0.0, 0.0), |(world, ego)| {
            (world.vehicles()[ego].speed, self.target_speed(world, ego))
        });
        let mut scalars = observation_scalars(
            speed,
            target,
            self.config.speed_scale_mps,
            self.aggressiveness,
            Some(self.last_action),
        );
        if self.config.rule_inputs {
            scalars.extend(rule_scalars(&self.state()));
        }
        if self.config.motion_inputs {
            scalars.extend(self.motion.scalars(self.config.speed_scale_mps));
        }
        Observation { layers, scalars }
    }
}

#[cfg(test)]
mod tests;
