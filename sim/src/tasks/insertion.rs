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

use maps::{Map, Point};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use super::motion_inputs::{MOTION_SCALARS, MotionHistory};
use super::roundabouts::{EgoView, RoundaboutSetup, RoundaboutTaskConfig, ego_scene};
use super::{
    ConditionChoice, Episode, LayerFrame, PolicyFactory, Task, TaskId, TaskSummary, check_positive,
};
use crate::baselines::{Baseline, InsertionPolicy};
use crate::env::{Env, Observation, ObservationSpec, Outcome, Step};
use crate::error::SimError;
use crate::eval::insertion::{self as insertion_eval, Condition};
use crate::eval::{EvalHeader, EvalReport, Evaluation};
use crate::observer::SceneObserver;
use crate::render::{BevConfig, BevRenderer};
use crate::roundabout::LayoutConfig;
use crate::scene::Scene;
use crate::world::{Driver, EgoConfig, TrafficConfig, TrafficLevel, World};

actions! {
    /// The three actions, by index.
    pub enum Action {
        Permitted = 0 => "permitted",
        NotPermitted = 1 => "not_permitted",
        Caution = 2 => "caution",
    }
}

/// Reward constants (the Parma paper's by default).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RewardConfig {
    /// Per step, times σ, while the gap to the vehicle ahead is under `headway_s` of travel.
    pub headway_penalty: f64,
    pub headway_s: f64,
    /// Per step, times σ, while inside the ring in front of a circulating vehicle that
    /// would reach the ego within `cut_in_s` of its travel.
    pub cut_in_penalty: f64,
    pub cut_in_s: f64,
    /// Counts in the cut-in term only the circulating vehicles the ego cut in front of:
    /// those less than `cut_in_s` from its merge point as it entered
    /// ([`World::merge_lags_s`]). Off (the default), any circulating vehicle counts that
    /// comes within `cut_in_s` behind the ego while it is in the ring, also one that caught
    /// up with a slow ego later, which no choice of gap avoids: the 25 m rule, which waits
    /// for the longest gaps, collects as many cut-in steps as always Permitted (docs/agents.md).
    pub cut_in_only_cut_off: bool,
    /// The danger terms (`headway_penalty`, `cut_in_penalty`) scale with σ to this power:
    /// 1 (the paper's, the default) makes them fall linearly with aggressiveness; 2 keeps
    /// the full term at aggressiveness 0 and a quarter of it at 0.5, so a strong term can
    /// make a cautious driver wait without making the middle one wait as long.
    pub danger_sigma_power: f64,
    /// Once, as the ego enters in front of a circulating car less than `short_entry_s` from
    /// its merge point: −short_entry_penalty · (1 − lag / short_entry_s), times σ to
    /// `danger_sigma_power`. Unlike the cut-in term, which costs the same per step for any
    /// lag under `cut_in_s`, it grows as the gap taken shrinks: the agents' crashes follow
    /// entries under a second (docs/agents.md). 0 (the default) leaves it out.
    pub short_entry_penalty: f64,
    pub short_entry_s: f64,
    pub reach: f64,
    /// Crash (and off-road): −(crash_base + crash_sigma · σ).
    pub crash_base: f64,
    pub crash_sigma: f64,
    pub time_over: f64,
    /// Switching Permitted → Caution, and Permitted → Not Permitted.
    pub to_caution_penalty: f64,
    pub to_not_permitted_penalty: f64,
    /// Per step, times speed / target speed.
    pub speed: f64,
}

impl Default for RewardConfig {
    fn default() -> Self {
        RewardConfig {
            headway_penalty: 0.002,
            headway_s: 1.0,
            cut_in_penalty: 0.005,
            cut_in_s: 3.0,
            cut_in_only_cut_off: false,
            danger_sigma_power: 1.0,
            short_entry_penalty: 0.0,
            short_entry_s: 1.5,
            reach: 1.0,
            crash_base: 0.2,
            crash_sigma: 1.8,
            time_over: 1.0,
            to_caution_penalty: 0.05,
            to_not_permitted_penalty: 0.15,
            speed: 0.0045,
        }
    }
}

/// Everything about the task; TOML-friendly, every field defaulted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct InsertionConfig {
    pub traffic: TrafficConfig,
    pub ego: EgoConfig,
    pub layout: LayoutConfig,
    pub observation: BevConfig,
    pub reward: RewardConfig,
    /// The ego's aggressiveness; None draws it uniformly in [0, 1] every episode (training).
    pub aggressiveness: Option<f64>,
    /// An episode ends in a time-over after this long, or after `time_limit_factor` times
    /// the free-flow time from start to goal if that is longer (large roundabouts), s.
    pub time_limit_s: f64,
    pub time_limit_factor: f64,
    /// The ego's centre starts this far before its yield line, m.
    pub start_distance_m: f64,
    /// The ego starts at a speed drawn uniformly in this fraction of its target speed.
    pub start_speed_fraction: (f64, f64),
    /// The goal: this far into the exit lane, m.
    pub goal_past_exit_m: f64,
    /// Acceleration and deceleration of Permitted and Caution, m/s².
    pub comfort_accel_mps2: f64,
    pub comfort_decel_mps2: f64,
    /// Caution holds the speed within this band around half the target, m/s.
    pub caution_band_mps: f64,
    /// Speeds are divided by this in the scalar inputs, m/s.
    pub speed_scale_mps: f64,
    /// Adds what the rule-based baselines act on to the scalar inputs ([`RULE_SCALARS`]):
    /// the distance to the nearest circulating vehicle and from the ego's front to its
    /// yield line, both over [`RULE_INPUT_RANGE_M`], and whether the ego has entered. Off by
    /// default: the study's agent sees the ring only in the bird's-eye layers. Projected
    /// logs give them too (from the vehicle's recorded track and the other road users).
    pub rule_inputs: bool,
    /// Adds the ego's own recent motion to the scalar inputs, after the rule inputs
    /// ([`MOTION_SCALARS`], [`super::motion_inputs`]): its speed 0.5, 1 and 2 s ago and the
    /// slowest it has been this episode, over `speed_scale_mps`. Off by default.
    pub motion_inputs: bool,
    /// World steps (`traffic.step_s` each) per decision: the action is held and the rewards
    /// summed over them, and a frame is drawn once per decision, so the frame stack spans
    /// `action_repeat` steps per frame. 1 (the default) decides every step, as the study did.
    pub action_repeat: usize,
    /// World steps between the stacked frames; unset (the default), `action_repeat`: one
    /// frame per decision. A multiple of `action_repeat` stacks frames that many decisions
    /// apart; otherwise a frame is drawn every world step and the stack takes every
    /// `frame_steps`-th. So an agent trained deciding every 3 steps can decide every step on
    /// frames as far apart as it was trained on, and a stack can span more time.
    pub frame_steps: Option<usize>,
    /// The ego drives in the style of a world driver of its own aggressiveness: its target
    /// speed is the route's nominal speed times `traffic.drivers.speed_factor`, and it
    /// keeps the IDM following distance (time headway, minimum gap) of that driver. Off (the
    /// default), it drives as a driver of aggressiveness 0.5 whatever its own, which then
    /// changes only the reward (σ); at 0.5 both are the same. Whether to take a gap stays
    /// the agent's decision either way.
    pub ego_style_from_aggressiveness: bool,
    /// Runs the task on this roundabout of the map only (its id, as in the map's
    /// `roundabouts`); unset (the default), on every roundabout with a route through its
    /// ring, one drawn per episode.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub roundabout: Option<u32>,
}

impl InsertionConfig {
    /// The task deciding every `steps` world steps, on frames stacked as far apart as
    /// before: what an agent trained with this config sees when it re-decides more (or
    /// less) often.
    pub fn deciding_every(&self, steps: usize) -> InsertionConfig {
        InsertionConfig {
            frame_steps: Some(self.frame_steps.unwrap_or(self.action_repeat)),
            action_repeat: steps,
            ..self.clone()
        }
    }

    /// Whether a frame is drawn every world step rather than once per decision: when the
    /// stacked frames are not a whole number of decisions apart.
    fn frames_every_step(&self) -> bool {
        self.frame_steps
            .is_some_and(|f| f % self.action_repeat.max(1) != 0)
    }

    /// The ego's target speed over its route's nominal speed at `aggressiveness`: the world
    /// drivers' speed factor with [`InsertionConfig::ego_style_from_aggressiveness`], else 1.
    pub fn ego_speed_factor(&self, aggressiveness: f64) -> f64 {
        if self.ego_style_from_aggressiveness {
            self.traffic.drivers.speed_factor.at(aggressiveness)
        } else {
            1.0
        }
    }

    /// The number of scalar inputs: [`SCALARS`], plus the rule and motion inputs when on.
    pub fn scalar_count(&self) -> usize {
        SCALARS
            + if self.rule_inputs { RULE_SCALARS } else { 0 }
            + if self.motion_inputs {
                MOTION_SCALARS
            } else {
                0
            }
    }

    /// How many drawn frames apart the stacked ones are.
    pub fn frame_spacing(&self) -> usize {
        match self.frame_steps {
            Some(f) if self.frames_every_step() => f,
            Some(f) => f / self.action_repeat.max(1),
            None => 1,
        }
    }
}

impl Default for InsertionConfig {
    fn default() -> Self {
        InsertionConfig {
            traffic: TrafficConfig::default(),
            ego: EgoConfig::default(),
            layout: LayoutConfig::default(),
            observation: BevConfig::default(),
            reward: RewardConfig::default(),
            aggressiveness: None,
            time_limit_s: 40.0,
            time_limit_factor: 2.0,
            start_distance_m: 20.0,
            start_speed_fraction: (0.3, 0.8),
            goal_past_exit_m: 5.0,
            comfort_accel_mps2: 2.0,
            comfort_decel_mps2: 2.5,
            caution_band_mps: 0.5,
            speed_scale_mps: 15.0,
            rule_inputs: false,
            motion_inputs: false,
            action_repeat: 1,
            frame_steps: None,
            ego_style_from_aggressiveness: false,
            roundabout: None,
        }
    }
}

/// How far ahead of its front the ego looks for cars covering its path, m.
const OBSTACLE_HORIZON_M: f64 = 12.0;

/// Number of scalar inputs: speed, target speed, aggressiveness, last action (one-hot).
pub const SCALARS: usize = 3 + Action::ALL.len();
/// Where the aggressiveness is among the scalar inputs.
pub const AGGRESSIVENESS_SCALAR: usize = 2;
/// Where the last action's one-hot is among the scalar inputs.
pub const LAST_ACTION_SCALARS: std::ops::Range<usize> = 3..SCALARS;

/// Extra scalar inputs with [`InsertionConfig::rule_inputs`]: nearest circulating vehicle,
/// distance to the yield line, entered (see [`rule_scalars`]).
pub const RULE_SCALARS: usize = 3;
/// Distances among the rule inputs are divided by this (and capped at ±1), m.
pub const RULE_INPUT_RANGE_M: f64 = 50.0;

/// The scalar inputs in their order: speed and target speed over `speed_scale_mps`, the
/// aggressiveness, and the last action one-hot (all zero for none). Logs projected for an
/// agent give the same inputs through this.
pub fn observation_scalars(
    speed_mps: f64,
    target_speed_mps: f64,
    speed_scale_mps: f64,
    aggressiveness: f64,
    last_action: Option<Action>,
) -> Vec<f32> {
    let mut scalars = vec![0.0f32; SCALARS];
    scalars[0] = (speed_mps / speed_scale_mps) as f32;
    scalars[1] = (target_speed_mps / speed_scale_mps) as f32;
    scalars[AGGRESSIVENESS_SCALAR] = aggressiveness as f32;
    if let Some(last) = last_action {
        scalars[LAST_ACTION_SCALARS.start + last as usize] = 1.0;
    }
    scalars
}

/// The rule inputs of `state`: the nearest circulating vehicle's distance and the distance
/// from the ego's front to its yield line over [`RULE_INPUT_RANGE_M`], clamped to [0, 1] and
/// [-1, 1] (an empty ring reads 1), and 1 once the ego has entered.
pub fn rule_scalars(state: &InsertionState) -> [f32; RULE_SCALARS] {
    rule_scalars_of(
        state.nearest_circulating_m,
        state.to_yield_line_m,
        state.ego_entered,
    )
}

/// [`rule_scalars`] of the three facts, wherever they come from (logs give them too).
pub fn rule_scalars_of(
    nearest_circulating_m: f64,
    to_yield_line_m: f64,
    entered: bool,
) -> [f32; RULE_SCALARS] {
    let scaled = |m: f64| (m / RULE_INPUT_RANGE_M).clamp(-1.0, 1.0) as f32;
    [
        scaled(nearest_circulating_m).max(0.0),
        scaled(to_yield_line_m),
        if entered { 1.0 } else { 0.0 },
    ]
}

/// The observation shape of the task drawn with `bev` (without the rule inputs).
pub fn observation_spec(bev: &BevConfig) -> ObservationSpec {
    bev.observation_spec(SCALARS)
}

/// What is prepared once per map and shared by every environment on it (read-only):
/// the routes of each usable roundabout and its static bird's-eye raster.
pub type InsertionSetup = RoundaboutSetup<InsertionConfig>;

impl InsertionSetup {
    /// Prepares every roundabout of `map` that has a route from an entry through the ring
    /// to an exit. Fails when there is none, or the configuration is invalid.
    pub fn new(map: Arc<Map>, config: InsertionConfig) -> Result<Arc<Self>, SimError> {
        validate(&config)?;
        Self::prepare(map, config, None)
    }
}

impl RoundaboutTaskConfig for InsertionConfig {
    fn layout(&self) -> &LayoutConfig {
        &self.layout
    }

    fn bev(&self) -> &BevConfig {
        &self.observation
    }

    fn observation_spec(&self) -> ObservationSpec {
        self.observation.observation_spec(self.scalar_count())
    }
    fn roundabout(&self) -> Option<maps::RoundaboutId> {
        self.roundabout.map(maps::RoundaboutId)
    }
}

fn validate(c: &InsertionConfig) -> Result<(), SimError> {
    c.observation.validate()?;
    check_positive(&[
        ("traffic.step_s", c.traffic.step_s),
        ("time_limit_s", c.time_limit_s),
        ("speed_scale_mps", c.speed_scale_mps),
        ("comfort_accel_mps2", c.comfort_accel_mps2),
        ("comfort_decel_mps2", c.comfort_decel_mps2),
        ("reward.danger_sigma_power", c.reward.danger_sigma_power),
        ("reward.short_entry_s", c.reward.short_entry_s),
    ])?;
    if c.action_repeat == 0 {
        return Err(SimError::Config(
            "action_repeat = 0: at least one world step per decision".to_owned(),
        ));
    }
    if c.frame_steps == Some(0) {
        return Err(SimError::Config(
            "frame_steps = 0: stacked frames must be at least one world step apart".to_owned(),
        ));
    }
    if let Some(a) = c.aggressiveness
        && !(0.0..=1.0).contains(&a)
    {
        return Err(SimError::Config(format!(
            "aggressiveness = {a} must lie in [0, 1]"
        )));
    }
    Ok(())
}

/// What the rule-based baselines may look at (the learned agents see the [`Observation`],
/// which carries these facts only with [`InsertionConfig::rule_inputs`]): facts of the
/// current state that a perception stack would report.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct InsertionState {
    /// Straight-line distance from the ego to the nearest vehicle on the ring (infinite when
    /// the ring is empty), m. On a multi-lane ring only vehicles on the lanes the ego's
    /// entry meets count: its merge lane and the lanes outside it.
    pub nearest_circulating_m: f64,
    /// The ego's front is past its yield line.
    pub ego_entered: bool,
    /// From the ego's front to the yield line (negative past it), m.
    pub to_yield_line_m: f64,
    pub speed_mps: f64,
    pub target_speed_mps: f64,
    pub aggressiveness: f64,
    /// The least time a circulating vehicle needs to reach the ego's merge point
    /// ([`World::merge_lag_s`]); None when none is coming.
    pub merge_lag_s: Option<f64>,
}

/// How one episode went.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpisodeSummary {
    pub outcome: Outcome,
    pub steps: usize,
    pub episode_return: f64,
    pub mean_speed_mps: f64,
    /// From the start until the ego's front passed the yield line, s (None if it never did).
    pub time_to_enter_s: Option<f64>,
    pub aggressiveness: f64,
    /// World steps in which the ego followed the vehicle ahead closer than the reward's
    /// `headway_s` of travel (r_danger's first term).
    #[serde(default)]
    pub close_following_steps: usize,
    /// World steps in which the ego was in the ring within the reward's `cut_in_s` of a
    /// circulating vehicle's travel in front of it (r_danger's second term).
    #[serde(default)]
    pub cut_in_steps: usize,
    /// The gap the ego accepted: as its front passed the yield line, the time the nearest
    /// circulating vehicle needed to reach its merge point ([`World::merge_lag_s`]), s (None
    /// if it never entered or nobody was coming).
    #[serde(default)]
    pub entry_lag_s: Option<f64>,
}

/// The danger the reward penalises, in one world step.
#[derive(Debug, Clone, Copy)]
struct Danger {
    close_following: bool,
    cut_in: bool,
}

/// The roundabout insertion task as an [`Env`].
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

    /// Decisions taken so far in the episode ([`Env::step`] calls).
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

    fn observation(&self) -> Observation {
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

    /// What the danger terms are multiplied by: σ to `danger_sigma_power`.
    fn danger_scale(&self) -> f64 {
        (1.0 - self.aggressiveness).powf(self.config.reward.danger_sigma_power)
    }

    /// The one-time cost of the entry just made, from its lag (`short_entry_penalty`).
    fn short_entry_cost(&self) -> f64 {
        let r = &self.config.reward;
        match self.entry_lag_s {
            Some(lag) if lag < r.short_entry_s => {
                r.short_entry_penalty * (1.0 - lag / r.short_entry_s) * self.danger_scale()
            }
            _ => 0.0,
        }
    }

    /// Reward terms that apply every step: speed, indecision, and r_danger for `danger`.
    fn step_reward(&self, world: &World, ego: usize, action: Action, danger: Danger) -> f64 {
        let r = &self.config.reward;
        let me = &world.vehicles()[ego];
        let danger_scale = self.danger_scale();
        let mut reward = r.speed * me.speed / self.target_speed(world, ego);
        if self.last_action == Action::Permitted {
            reward -= match action {
                Action::Caution => r.to_caution_penalty,
                Action::NotPermitted => r.to_not_permitted_penalty,
                Action::Permitted => 0.0,
            };
        }
        if danger.close_following {
            reward -= r.headway_penalty * danger_scale;
        }
        if danger.cut_in {
            reward -= r.cut_in_penalty * danger_scale;
        }
        reward
    }

    /// Which of r_danger's situations the ego is in: following closer than `headway_s`,
    /// or in the ring just in front of a circulating vehicle.
    fn danger(&self, world: &World, ego: usize) -> Danger {
        let r = &self.config.reward;
        let me = &world.vehicles()[ego];
        let close_following = world
            .leader(ego)
            .is_some_and(|l| l.gap_m < me.speed * r.headway_s);
        let in_ring = me.committed && me.s < world.route(me).exit_s;
        Danger {
            close_following,
            cut_in: in_ring && self.cut_in(world, ego),
        }
    }

    /// Whether a circulating vehicle has the ego as the vehicle ahead of it and would
    /// reach it within `cut_in_s` at its speed (with `cut_in_only_cut_off`, one the ego
    /// entered in front of).
    fn cut_in(&self, world: &World, ego: usize) -> bool {
        let r = &self.config.reward;
        let limit = r.cut_in_s;
        (0..world.vehicles().len()).any(|j| {
            let v = &world.vehicles()[j];
            if v.is_ego()
                || !v.committed
                || (r.cut_in_only_cut_off && !self.cut_off.contains(&v.id))
            {
                return false;
            }
            [world.leader(j), world.merging_leader(j)]
                .into_iter()
                .flatten()
                .any(|l| l.index == ego && l.gap_m.max(0.0) < limit * v.speed)
        })
    }
}

impl Env for RoundaboutInsertion {
    fn observation_spec(&self) -> ObservationSpec {
        self.setup.observation_spec()
    }

    fn action_count(&self) -> usize {
        Action::ALL.len()
    }

    fn action_names(&self) -> &'static [&'static str] {
        &Action::NAMES
    }

    fn reset(&mut self, seed: u64) -> Observation {
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
        self.observation()
    }

    fn step(&mut self, action: usize) -> Step {
        let world = if self.episode.ended() {
            None
        } else {
            self.world.take()
        };
        let Some(mut world) = world else {
            // After the end, or never reset.
            return self.episode.finished_step(self.observation());
        };
        self.decisions += 1;
        let action = Action::from_index(action).unwrap_or(Action::NotPermitted);
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
        self.episode.step(self.observation(), reward, outcome)
    }
}

impl Task for RoundaboutInsertion {
    type Config = InsertionConfig;
    type Setup = InsertionSetup;
    type Summary = EpisodeSummary;
    type Condition = Condition;

    const ID: TaskId = TaskId::RoundaboutInsertion;

    fn setup(
        map: Option<Arc<Map>>,
        config: InsertionConfig,
        _: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<InsertionSetup>, SimError> {
        let map = map.ok_or_else(|| SimError::Map("roundabout insertion needs a map".into()))?;
        InsertionSetup::new(map, config)
    }

    fn map(setup: &InsertionSetup) -> &Map {
        setup.map()
    }

    fn roundabouts(setup: &InsertionSetup) -> Vec<u32> {
        setup.layouts().map(|l| l.roundabout.0).collect()
    }

    fn deciding_every(config: &InsertionConfig, steps: usize) -> Option<InsertionConfig> {
        Some(config.deciding_every(steps))
    }

    fn in_world(
        config: &InsertionConfig,
        world: &crate::world::CalibratedWorld,
    ) -> Option<InsertionConfig> {
        let mut config = config.clone();
        world.apply(&mut config.traffic, &mut config.layout);
        Some(config)
    }

    fn on_roundabout(config: &InsertionConfig, id: u32) -> Option<InsertionConfig> {
        Some(InsertionConfig {
            roundabout: Some(id),
            ..config.clone()
        })
    }

    fn training_env(setup: &Arc<InsertionSetup>, traffic: TrafficLevel) -> Self {
        let mut env = RoundaboutInsertion::new(Arc::clone(setup));
        env.set_traffic(traffic);
        env
    }

    fn env(setup: &Arc<InsertionSetup>, condition: &Condition) -> Self {
        let mut env = RoundaboutInsertion::new(Arc::clone(setup));
        env.set_traffic(condition.traffic);
        env.set_aggressiveness(Some(condition.aggressiveness));
        env
    }

    /// Traffic levels × aggressiveness values (by default every level × 0, 0.5 and 1).
    fn conditions(choice: &ConditionChoice) -> Vec<Condition> {
        let aggressiveness = if choice.aggressiveness.is_empty() {
            vec![0.0, 0.5, 1.0]
        } else {
            choice.aggressiveness.clone()
        };
        choice
            .traffic_levels()
            .into_iter()
            .flat_map(|traffic| {
                aggressiveness.iter().map(move |&aggressiveness| Condition {
                    traffic,
                    aggressiveness,
                })
            })
            .collect()
    }

    fn condition_name(condition: &Condition) -> String {
        condition.name()
    }

    /// At the training traffic, for each of the evaluation's aggressiveness values.
    fn validation_conditions(traffic: TrafficLevel) -> Vec<(String, Condition)> {
        [0.0, 0.5, 1.0]
            .map(|aggressiveness| {
                let condition = Condition {
                    traffic,
                    aggressiveness,
                };
                (format!("aggressiveness {aggressiveness}"), condition)
            })
            .to_vec()
    }

    fn recorded_condition(traffic: TrafficLevel) -> Condition {
        Condition {
            traffic,
            aggressiveness: 0.5,
        }
    }

    /// Medium traffic, aggressiveness 0.5, whatever the conditions.
    fn recorded_eval_condition(_: &[Condition]) -> Condition {
        Self::recorded_condition(TrafficLevel::Medium)
    }

    fn eval_report(
        header: &EvalHeader,
        evaluation: &Evaluation<Condition, EpisodeSummary>,
    ) -> Result<EvalReport, SimError> {
        insertion_eval::report(header, evaluation)
    }

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

    /// The study's baselines, and in a calibrated world the rule of its median driver's
    /// critical gap.
    fn setup_baselines(setup: &InsertionSetup) -> Vec<(String, PolicyFactory<Self>)> {
        let mut all = Self::baselines();
        if let Some(gap) = setup.config().traffic.drivers.critical_gap.measured() {
            let baseline = Baseline::CriticalGap {
                seconds: gap.median_s,
            };
            let make: PolicyFactory<Self> = Box::new(move || Box::new(InsertionPolicy(baseline)));
            all.push((baseline.name(), make));
        }
        all
    }

    /// The Parma study's rules, always Permitted, random and always Not Permitted.
    fn baselines() -> Vec<(String, PolicyFactory<Self>)> {
        Baseline::STANDARD
            .into_iter()
            .map(|baseline| {
                let make: PolicyFactory<Self> =
                    Box::new(move || Box::new(InsertionPolicy(baseline)));
                (baseline.name(), make)
            })
            .collect()
    }

    /// The current scene (None before the first reset).
    fn scene(&self) -> Option<Scene<'_>> {
        ego_scene(
            self.setup.map(),
            self.world.as_ref()?,
            self.start_time_s,
            Some(self.aggressiveness),
        )
    }

    /// The ego's positions so far this episode (one per step, the start included).
    fn trajectory(&self) -> &[Point] {
        &self.episode.trajectory
    }

    fn set_rendering(&mut self, on: bool) {
        self.view.set_rendering(on);
    }

    /// The newest bird's-eye frame.
    fn recorded_layers(&self) -> Option<LayerFrame<'_>> {
        let bev = &self.setup.config().observation;
        Some(LayerFrame {
            layers: self.newest_frame(),
            names: &bev.layers,
            width: bev.width,
            height: bev.height,
        })
    }
}

impl TaskSummary for EpisodeSummary {
    fn outcome(&self) -> Outcome {
        self.outcome
    }

    fn episode_return(&self) -> f64 {
        self.episode_return
    }

    fn metrics(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("mean speed m/s", self.mean_speed_mps),
            ("time to enter s", self.time_to_enter_s.unwrap_or(f64::NAN)),
            ("entry lag s", self.entry_lag_s.unwrap_or(f64::NAN)),
        ]
    }
}

impl RoundaboutInsertion {
    /// After a world step: the reward and whether (and how) the episode ended.
    fn resolve(&mut self, world: &mut World, action: Action) -> (f64, Option<Outcome>) {
        let Some(ego) = world.ego_index() else {
            return (0.0, Some(Outcome::TimeOver));
        };
        self.episode.steps += 1;
        let (speed, position, s, committed) = {
            let me = &world.vehicles()[ego];
            (me.speed, me.position, me.s, me.committed)
        };
        self.speed_sum += speed;
        self.episode.trajectory.push(position);
        self.motion.push(speed);
        let elapsed = world.time_s() - self.start_time_s;
        let just_entered = committed && self.entered_at_s.is_none();
        if just_entered {
            self.entered_at_s = Some(elapsed);
            self.entry_lag_s = world.merge_lag_s(ego);
            let limit = self.config.reward.cut_in_s;
            self.cut_off = world
                .merge_lags_s(ego)
                .filter(|&(_, lag)| lag < limit)
                .map(|(j, _)| world.vehicles()[j].id)
                .collect();
        }
        let danger = self.danger(world, ego);
        self.close_following_steps += usize::from(danger.close_following);
        self.cut_in_steps += usize::from(danger.cut_in);
        let mut reward = self.step_reward(world, ego, action, danger);
        if just_entered {
            reward -= self.short_entry_cost();
        }
        let r = self.config.reward;
        let sigma = 1.0 - self.aggressiveness;
        let raster = self.setup.roundabouts.renderer(self.roundabout).raster();
        let outcome = if world.collision_with(ego).is_some() {
            Some(Outcome::Crashed)
        } else if !raster.navigable(position) {
            Some(Outcome::OffRoad)
        } else if s >= self.goal_s {
            Some(Outcome::Reached)
        } else if elapsed >= self.time_limit_s - 1e-9 {
            Some(Outcome::TimeOver)
        } else {
            None
        };
        reward += match outcome {
            Some(Outcome::Reached) => r.reach,
            Some(Outcome::Crashed | Outcome::OffRoad) => -(r.crash_base + r.crash_sigma * sigma),
            Some(Outcome::TimeOver) => -r.time_over,
            None => 0.0,
        };
        (reward, outcome)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An ego that has entered the ring and meets a car merging in front of it from a later
    /// entry brakes for it, as the world's drivers do (before, it drove on into it).
    #[test]
    fn an_entered_ego_brakes_for_a_car_merging_ahead() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../data/osm/montlake_roundabout.osm.pbf");
        let map = maps::import_file(&path, &Default::default()).expect("montlake imports");
        let setup = InsertionSetup::new(Arc::new(map), InsertionConfig::default())
            .expect("montlake has a roundabout");
        let env = RoundaboutInsertion::new(Arc::clone(&setup));
        let layout = Arc::clone(setup.layouts().next().expect("a layout"));
        // The ego's route drives the merge lane of a route from another entry.
        let (ego_route, other_route, merge_lane_start) = layout
            .routes
            .iter()
            .enumerate()
            .find_map(|(a, ra)| {
                layout.routes.iter().enumerate().find_map(|(b, rb)| {
                    let start = ra.ring_lane_start(rb.merge_lane)?;
                    (rb.entry != ra.entry && start - ra.merge_s > 12.0).then_some((a, b, start))
                })
            })
            .expect("two routes meeting in the ring");
        let config = &setup.config;
        let other = &layout.routes[other_route];
        // The ego's Permitted acceleration one step after it is put 9 m before that merge
        // lane (past its own line, so it counts as entered), with or without a car about
        // to merge there.
        let permitted = |with_other: bool| {
            let mut world = World::new(Arc::clone(&layout), config.traffic.clone(), config.ego, 7);
            world.insert_ego(ego_route, merge_lane_start - 9.0, 4.0, 0.0);
            if with_other {
                world.insert_vehicle(other_route, other.merge_s - 2.5, 2.0, 0.5, true);
            }
            world.step(0.0);
            let ego = world.ego_index().expect("the ego");
            assert!(world.vehicles()[ego].committed);
            assert!(world.leader(ego).is_none(), "nobody in the ego's lane");
            if with_other {
                let merging = world.merging_leader(ego).expect("the car merging ahead");
                assert!(merging.gap_m < 8.0, "{merging:?}");
            }
            env.ego_accel(&world, ego, Action::Permitted)
        };
        let (free, cut_in) = (permitted(false), permitted(true));
        assert!(
            cut_in < free - 1.0 && cut_in < 0.0,
            "Permitted gives {cut_in} m/s² towards a car cutting in, {free} m/s² without it"
        );
    }

    /// Deciding every step on frames 3 steps apart, with the actions held for 3 steps, sees
    /// and earns exactly what deciding every 3 steps does (how the stack moves in between is
    /// `render::tests::spaced_frame_stack_picks_every_spacing_th_frame`).
    #[test]
    fn deciding_every_step_keeps_the_trained_frame_spacing() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../data/osm/montlake_roundabout.osm.pbf");
        let map = Arc::new(maps::import_file(&path, &Default::default()).expect("montlake"));
        // Frames a decision apart (drawn per decision), two decisions apart (per decision,
        // every other one stacked) and 4 steps apart (drawn every step).
        for frame_steps in [None, Some(6), Some(4)] {
            let mut trained = InsertionConfig {
                action_repeat: 3,
                frame_steps,
                ..InsertionConfig::default()
            };
            trained.observation.width = 42;
            trained.observation.height = 42;
            trained.observation.stack = 3;
            let every_step = trained.deciding_every(1);
            assert_eq!(every_step.action_repeat, 1);
            assert_eq!(every_step.frame_steps, Some(frame_steps.unwrap_or(3)));
            let env = |config: &InsertionConfig| {
                let setup = InsertionSetup::new(Arc::clone(&map), config.clone()).expect("setup");
                let mut env = RoundaboutInsertion::new(setup);
                env.set_traffic(TrafficLevel::High);
                env
            };
            let (mut coarse, mut fine) = (env(&trained), env(&every_step));
            assert_eq!(coarse.reset(11), fine.reset(11));
            let actions = [Action::Caution, Action::NotPermitted, Action::Permitted];
            for action in actions.into_iter().cycle().take(7) {
                let want = coarse.step(action as usize);
                let mut reward = 0.0;
                let mut got = None;
                for _ in 0..3 {
                    let step = fine.step(action as usize);
                    reward += step.reward;
                    got = Some(step.observation);
                }
                assert_eq!(
                    got.as_ref(),
                    Some(&want.observation),
                    "{frame_steps:?}, {action:?}"
                );
                assert!(
                    (reward - want.reward).abs() < 1e-6,
                    "{reward} against {}",
                    want.reward
                );
            }
            // The returns are summed in another order: equal up to rounding.
            let (a, b) = (coarse.summary(), fine.summary());
            assert!((a.episode_return - b.episode_return).abs() < 1e-9);
            assert_eq!(
                EpisodeSummary {
                    episode_return: 0.0,
                    ..a
                },
                EpisodeSummary {
                    episode_return: 0.0,
                    ..b
                }
            );
        }
    }

    /// The danger terms fall with σ to `danger_sigma_power`: at aggressiveness 0.5 a cut-in
    /// step costs half the term with the paper's power 1 and a quarter of it with power 2,
    /// and the other reward terms do not change.
    #[test]
    fn the_danger_terms_scale_with_sigma_to_the_configured_power() {
        let map = Arc::new(crate::test_maps::montlake());
        let cut_in_cost = |power: f64| {
            let mut config = InsertionConfig {
                aggressiveness: Some(0.5),
                ..InsertionConfig::default()
            };
            config.reward.cut_in_penalty = 0.08;
            config.reward.danger_sigma_power = power;
            let setup = InsertionSetup::new(Arc::clone(&map), config).expect("setup");
            let mut env = RoundaboutInsertion::new(setup);
            env.set_rendering(false);
            env.reset(5);
            let world = env.world.as_ref().expect("a world after reset");
            let ego = world.ego_index().expect("the ego");
            let reward = |cut_in| {
                let danger = Danger {
                    close_following: false,
                    cut_in,
                };
                env.step_reward(world, ego, env.last_action, danger)
            };
            reward(false) - reward(true)
        };
        assert!(
            (cut_in_cost(1.0) - 0.04).abs() < 1e-12,
            "{}",
            cut_in_cost(1.0)
        );
        assert!(
            (cut_in_cost(2.0) - 0.02).abs() < 1e-12,
            "{}",
            cut_in_cost(2.0)
        );
        let mut config = InsertionConfig::default();
        config.reward.danger_sigma_power = 0.0;
        assert!(InsertionSetup::new(Arc::clone(&map), config).is_err());
    }

    /// The short-entry term is charged once, at the entry, and grows as the lag taken
    /// shrinks: always-Permitted episodes with and without it drive the same and their
    /// returns differ by exactly penalty · (1 − lag / short_entry_s) · σ for the episodes
    /// that entered less than `short_entry_s` in front of a car, and not at all otherwise.
    #[test]
    fn a_short_entry_costs_once_and_more_the_shorter_the_lag() {
        let map = Arc::new(crate::test_maps::montlake());
        let episode = |penalty: f64, seed: u64| {
            let mut config = InsertionConfig {
                aggressiveness: Some(0.5),
                ..InsertionConfig::default()
            };
            config.reward.short_entry_penalty = penalty;
            config.reward.short_entry_s = 2.0;
            let setup = InsertionSetup::new(Arc::clone(&map), config).expect("setup");
            let mut env = RoundaboutInsertion::new(setup);
            env.set_traffic(TrafficLevel::High);
            env.set_rendering(false);
            env.reset(seed);
            while env.step(Action::Permitted as usize).outcome.is_none() {}
            env.summary()
        };
        let (mut short, mut long) = (0, 0);
        for seed in 0..40 {
            let (without, with) = (episode(0.0, seed), episode(0.6, seed));
            assert_eq!(without.steps, with.steps);
            assert_eq!(without.entry_lag_s, with.entry_lag_s);
            let charged = without.episode_return - with.episode_return;
            let want = match with.entry_lag_s {
                Some(lag) if lag < 2.0 => {
                    short += 1;
                    0.6 * (1.0 - lag / 2.0) * 0.5
                }
                _ => {
                    long += 1;
                    0.0
                }
            };
            assert!(
                (charged - want).abs() < 1e-9,
                "seed {seed}: {charged} against {want}"
            );
        }
        assert!(
            short > 0 && long > 0,
            "{short} short entries, {long} others"
        );
    }

    /// With `ego_style_from_aggressiveness`, an aggressive ego aims faster and drives a
    /// whole always-Permitted episode faster than a passive one; without it, aggressiveness
    /// changes the reward only and the two episodes drive the same.
    #[test]
    fn the_ego_drives_in_its_aggressiveness_style_only_when_asked() {
        let map = Arc::new(crate::test_maps::montlake());
        let episode = |style: bool, aggressiveness: f64| {
            let config = InsertionConfig {
                ego_style_from_aggressiveness: style,
                aggressiveness: Some(aggressiveness),
                ..InsertionConfig::default()
            };
            let setup = InsertionSetup::new(Arc::clone(&map), config).expect("setup");
            let mut env = RoundaboutInsertion::new(setup);
            env.set_traffic(TrafficLevel::Low);
            env.set_rendering(false);
            let target = env.reset(3).scalars[1];
            while env.step(Action::Permitted as usize).outcome.is_none() {}
            (target, env.summary(), env.trajectory().to_vec())
        };
        let (passive_target, passive, passive_path) = episode(true, 0.0);
        let (aggressive_target, aggressive, _) = episode(true, 1.0);
        let ratio = f64::from(aggressive_target / passive_target);
        let span = InsertionConfig::default().traffic.drivers.speed_factor;
        assert!(
            (ratio - span.aggressive / span.passive).abs() < 1e-3,
            "target speeds {aggressive_target} and {passive_target}"
        );
        assert!(
            aggressive.mean_speed_mps > passive.mean_speed_mps * 1.05,
            "{aggressive:?} against {passive:?}"
        );
        let (_, plain_passive, plain_passive_path) = episode(false, 0.0);
        let (_, plain_aggressive, plain_aggressive_path) = episode(false, 1.0);
        assert_eq!(plain_passive_path, plain_aggressive_path);
        assert_eq!(plain_passive.steps, plain_aggressive.steps);
        assert_ne!(plain_passive_path, passive_path);
    }
}
