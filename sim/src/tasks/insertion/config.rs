//! Roundabout insertion's settings (reward constants, the task's table), its inputs (the
//! scalar and rule inputs logs share), its setup, and what an episode reports.

use super::*;

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
    /// ([`MOTION_SCALARS`], [`crate::tasks::motion_inputs`]): its speed 0.5, 1 and 2 s ago and the
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
    pub(super) fn frames_every_step(&self) -> bool {
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
pub(super) const OBSTACLE_HORIZON_M: f64 = 12.0;

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

impl RoundaboutTaskConfig for InsertionConfig {
    const TASK: TaskId = TaskId::RoundaboutInsertion;

    /// Valid settings; no observer (the task draws only bird's-eye layers).
    fn checked(
        &self,
        _: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Option<Arc<dyn SceneObserver>>, SimError> {
        validate(self)?;
        Ok(None)
    }

    fn observation_spec(&self) -> ObservationSpec {
        self.observation.observation_spec(self.scalar_count())
    }

    roundabout_fields!();
}

pub(super) fn validate(c: &InsertionConfig) -> Result<(), SimError> {
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
