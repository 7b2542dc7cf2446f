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

use maps::{Map, Point};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::roundabouts::{EgoView, RoundaboutSetup, RoundaboutTaskConfig, ego_scene};
use super::{
    ConditionChoice, Driving, Episode, PolicyFactory, Task, TaskId, TaskPolicy, TaskSetup,
    TaskSummary, baselines_with_rule, check_positive,
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

actions! {
    /// The three actions, by index.
    pub enum SteerAction {
        Forward = 0 => "forward",
        ForwardLeft = 1 => "forward_left",
        ForwardRight = 2 => "forward_right",
    }
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

/// Reward constants (the by default).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RingRewardConfig {
    /// The reward of a step that ends in a collision is minus this.
    pub collision_penalty: f64,
    /// The reward of a step that ends off the road is minus this.
    pub off_road_penalty: f64,
    /// Taken off every step while the ego is more than `far_from_ring_m` from the ring.
    pub far_penalty: f64,
    /// From the roundabout's centre circle (its mapped radius around its centre), m.
    pub far_from_ring_m: f64,
}

impl Default for RingRewardConfig {
    fn default() -> Self {
        RingRewardConfig {
            collision_penalty: 1.0,
            off_road_penalty: 1.0,
            far_penalty: 0.5,
            far_from_ring_m: 30.0,
        }
    }
}

/// The per-step lane reward: `min(1, 1/α) + min(1, 1/(10·d))`, α in degrees and d in
/// metres, both as absolute values; each term is 1 at 0 (and for NaN inputs, 0).
pub fn lane_reward(angle_deg: f64, distance_m: f64) -> f64 {
    let term = |x: f64| {
        let x = x.abs();
        if x.is_nan() {
            0.0
        } else if x <= 1.0 {
            1.0
        } else {
            1.0 / x
        }
    };
    term(angle_deg) + term(10.0 * distance_m)
}

/// Everything about the task; TOML-friendly, every field defaulted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RingDrivingConfig {
    pub traffic: TrafficConfig,
    pub ego: EgoConfig,
    pub layout: LayoutConfig,
    /// Which layers the agent sees: `bev` (the `observation` table) or
    /// `camera-segmentation` (the `camera` table).
    #[serde(skip_serializing_if = "is_bev")]
    pub view: View,
    /// The bird's-eye layers (drawn for the `navigable` test whatever the view).
    pub observation: BevConfig,
    /// The camera-segmentation view's settings (`segmenter` is required for that view).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraViewConfig>,
    pub reward: RingRewardConfig,
    /// Length of an episode, s.
    pub episode_s: f64,
    /// The wheel angle of forward-left / forward-right, rad (at most `ego.max_steer_rad`).
    pub steer_rad: f64,
    /// How fast the wheels turn towards an action's angle, rad/s.
    pub steer_rate_radps: f64,
    /// Probability that an episode starts in the ring rather than before the yield line.
    pub ring_start_probability: f64,
    /// Before the ring, the ego's front starts this far before its yield line (uniform), m.
    pub start_before_yield_m: (f64, f64),
    /// The ego starts at this fraction of its route's nominal speed (uniform).
    pub start_speed_fraction: (f64, f64),
    /// Farther than this from the route, the episode ends off the road, m.
    pub max_lane_distance_m: f64,
    /// Speeds are divided by this in the scalar inputs, m/s.
    pub speed_scale_mps: f64,
    /// Runs the task on this roundabout of the map only (its id, as in the map's
    /// `roundabouts`); unset (the default), on every roundabout with a route through its
    /// ring, one drawn per episode.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub roundabout: Option<u32>,
}

impl Default for RingDrivingConfig {
    fn default() -> Self {
        RingDrivingConfig {
            traffic: TrafficConfig::default(),
            ego: EgoConfig::default(),
            // Exits 20 m long (10 m for insertion): 10 s from before the line at the
            // speeds of small roundabouts mostly fit on the route.
            layout: LayoutConfig {
                exit_m: 20.0,
                ..LayoutConfig::default()
            },
            // A close view (0.57 m a pixel): the lane's offset and direction matter more
            // here than traffic far away; 42 × 42 × 2 keeps training on two CPU cores
            // affordable.
            observation: BevConfig {
                width: 42,
                height: 42,
                forward_m: 24.0,
                lateral_m: 24.0,
                stack: 2,
                path_width_m: 1.5,
                ..BevConfig::default()
            },
            view: View::Bev,
            camera: None,
            reward: RingRewardConfig::default(),
            episode_s: 10.0,
            steer_rad: 0.6,
            steer_rate_radps: 2.0,
            ring_start_probability: 0.5,
            start_before_yield_m: (3.0, 12.0),
            start_speed_fraction: (0.5, 1.0),
            max_lane_distance_m: 4.0,
            speed_scale_mps: 15.0,
            roundabout: None,
        }
    }
}

fn is_bev(view: &View) -> bool {
    *view == View::Bev
}

fn validate(c: &RingDrivingConfig) -> Result<(), SimError> {
    c.observation.validate()?;
    match c.view {
        View::Bev => {}
        View::Scalars => {
            return Err(SimError::Config(
                "view = \"scalars\": roundabout driving has no route inputs besides its layers; \
                 use \"bev\" or \"camera-segmentation\""
                    .into(),
            ));
        }
        View::CameraSegmentation => c.camera_view()?.validate()?,
    }
    check_positive(&[
        ("traffic.step_s", c.traffic.step_s),
        ("episode_s", c.episode_s),
        ("steer_rad", c.steer_rad),
        ("steer_rate_radps", c.steer_rate_radps),
        ("max_lane_distance_m", c.max_lane_distance_m),
        ("speed_scale_mps", c.speed_scale_mps),
        ("ego.max_steer_rad", c.ego.max_steer_rad),
        ("ego.wheelbase_m", c.ego.wheelbase_m),
    ])?;
    if !(0.0..=1.0).contains(&c.ring_start_probability) {
        return Err(SimError::Config(format!(
            "ring_start_probability = {} must lie in [0, 1]",
            c.ring_start_probability
        )));
    }
    for (name, (lo, hi)) in [
        ("start_before_yield_m", c.start_before_yield_m),
        ("start_speed_fraction", c.start_speed_fraction),
    ] {
        if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi) {
            return Err(SimError::Config(format!(
                "{name} = ({lo}, {hi}) must be a range of non-negative numbers"
            )));
        }
    }
    Ok(())
}

/// Number of scalar inputs: speed, wheel angle.
pub const SCALARS: usize = 2;

/// The observation shape of the task drawn with `bev`.
pub fn observation_spec(bev: &BevConfig) -> ObservationSpec {
    bev.observation_spec(SCALARS)
}

impl RingDrivingConfig {
    /// The camera view's settings, required by `view = "camera-segmentation"`.
    pub fn camera_view(&self) -> Result<&CameraViewConfig, SimError> {
        self.camera.as_ref().ok_or_else(|| {
            SimError::Config(
                "view = \"camera-segmentation\" needs a [agent.roundabout_driving.camera] table \
                 with segmenter = \"<model folder>\""
                    .into(),
            )
        })
    }

    /// The shape of the task's observations with this config.
    pub fn observation_spec(&self) -> ObservationSpec {
        match (self.view, &self.camera) {
            (View::CameraSegmentation, Some(camera)) => camera.observation_spec(SCALARS),
            _ => observation_spec(&self.observation),
        }
    }
}

/// What is prepared once per map and shared by every environment on it (read-only).
pub type RingDrivingSetup = RoundaboutSetup<RingDrivingConfig>;

impl RingDrivingSetup {
    /// Prepares every roundabout of `map` that has a route through its ring. Fails when
    /// there is none, or the configuration is invalid.
    /// A camera view needs its observer: see [`RingDrivingSetup::with_observer`].
    pub fn new(map: Arc<Map>, config: RingDrivingConfig) -> Result<Arc<Self>, SimError> {
        Self::with_observer(map, config, None)
    }

    /// As [`RingDrivingSetup::new`], with the observer that draws the layers of
    /// `view = "camera-segmentation"` (required by that view, unused by the others; its
    /// frame shape must be the `camera` table's).
    pub fn with_observer(
        map: Arc<Map>,
        config: RingDrivingConfig,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self>, SimError> {
        Self::prepare(Some(map), config, observer)
    }
}

impl RoundaboutTaskConfig for RingDrivingConfig {
    const TASK: TaskId = TaskId::RoundaboutDriving;

    fn checked(
        &self,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Option<Arc<dyn SceneObserver>>, SimError> {
        validate(self)?;
        let camera = match self.view {
            View::CameraSegmentation => Some(self.camera_view()?),
            View::Bev | View::Scalars => None,
        };
        checked_observer("agent.roundabout_driving", self.view, camera, observer)
    }

    fn layout(&self) -> &LayoutConfig {
        &self.layout
    }

    fn bev(&self) -> &BevConfig {
        &self.observation
    }

    fn observation_spec(&self) -> ObservationSpec {
        RingDrivingConfig::observation_spec(self)
    }
    fn roundabout(&self) -> Option<maps::RoundaboutId> {
        self.roundabout.map(maps::RoundaboutId)
    }

    fn world_mut(&mut self) -> (&mut TrafficConfig, &mut LayoutConfig) {
        (&mut self.traffic, &mut self.layout)
    }

    fn roundabout_mut(&mut self) -> &mut Option<u32> {
        &mut self.roundabout
    }
}

/// How one episode went.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RingDrivingSummary {
    pub outcome: Outcome,
    pub steps: usize,
    pub episode_return: f64,
    pub mean_angle_deviation_deg: f64,
    pub mean_distance_deviation_m: f64,
    pub episode_length_s: f64,
    pub mean_speed_kmh: f64,
}

impl TaskSummary for RingDrivingSummary {
    fn outcome(&self) -> Outcome {
        self.outcome
    }

    fn episode_return(&self) -> f64 {
        self.episode_return
    }

    fn metrics(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("mean angle deviation °", self.mean_angle_deviation_deg),
            ("mean distance deviation m", self.mean_distance_deviation_m),
            ("episode length s", self.episode_length_s),
            ("mean speed km/h", self.mean_speed_kmh),
        ]
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

/// The roundabout driving task as an [`Env`] and a [`Task`].
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
    const FALLBACK: SteerAction = SteerAction::Forward;

    fn spec(&self) -> ObservationSpec {
        self.setup.observation_spec()
    }

    episode_in_field!();

    fn started(&self) -> bool {
        self.world.is_some()
    }

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

    fn decide(&mut self, action: SteerAction) -> (f64, Option<Outcome>) {
        let Some(mut world) = self.world.take() else {
            return (0.0, Some(self.episode.final_outcome()));
        };
        self.steer = self.next_steer(action);
        world.step_ego(EgoCommand {
            accel: None,
            steer_rad: Some(self.steer),
        });
        let (reward, outcome) = self.resolve(&mut world);
        self.world = Some(world);
        self.render(false);
        (reward, outcome)
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
}

impl Task for RingDriving {
    type Config = RingDrivingConfig;
    type Setup = RingDrivingSetup;
    /// The traffic level.
    type Condition = TrafficLevel;

    const ID: TaskId = TaskId::RoundaboutDriving;

    fn in_world(config: &RingDrivingConfig, world: &CalibratedWorld) -> Option<RingDrivingConfig> {
        Some(config.in_world(world))
    }

    fn on_roundabout(config: &RingDrivingConfig, id: u32) -> Option<RingDrivingConfig> {
        Some(config.on_roundabout(id))
    }

    fn camera_view(config: &RingDrivingConfig) -> Option<&CameraViewConfig> {
        config.view.camera(config.camera.as_ref())
    }

    fn camera_mut(config: &mut RingDrivingConfig) -> Option<&mut CameraViewConfig> {
        config.camera.as_mut()
    }

    fn training_env(setup: &Arc<RingDrivingSetup>, traffic: TrafficLevel) -> Self {
        let mut env = RingDriving::new(Arc::clone(setup));
        env.set_traffic(traffic);
        env
    }

    fn env(setup: &Arc<RingDrivingSetup>, traffic: &TrafficLevel) -> Self {
        Self::training_env(setup, *traffic)
    }

    /// One condition per traffic level (by default low, medium and high).
    fn conditions(choice: &ConditionChoice) -> Vec<TrafficLevel> {
        choice.traffic_levels()
    }

    fn condition_name(traffic: &TrafficLevel) -> String {
        format!("traffic {}", traffic.name())
    }

    /// At the training traffic.
    fn validation_conditions(traffic: TrafficLevel) -> Vec<(String, TrafficLevel)> {
        vec![(Self::condition_name(&traffic), traffic)]
    }

    fn recorded_condition(traffic: TrafficLevel) -> TrafficLevel {
        traffic
    }

    fn baselines() -> Vec<(String, PolicyFactory<Self>)> {
        baselines_with_rule::<Self, PursuitRule>(
            &SteerAction::NAMES,
            "rule: pure pursuit, quantised",
        )
    }

    fn scene(&self) -> Option<Scene<'_>> {
        ego_scene(
            self.setup.map(),
            self.world.as_ref()?,
            self.start_time_s,
            None,
        )
    }

    /// Turns drawing the layers (bird's-eye or camera) on or off.
    fn set_rendering(&mut self, on: bool) {
        self.view.set_rendering(on);
    }
}

/// The rule baseline: pure pursuit on the route (privileged: the route and the ego's
/// exact pose), quantised to the action whose next wheel angle is nearest; an upper
/// bound for what the three actions can do rather than a fair opponent.
#[derive(Debug, Clone, Copy, Default)]
pub struct PursuitRule;

impl TaskPolicy<RingDriving> for PursuitRule {
    fn act(&mut self, envs: &[&RingDriving], _: &[&Observation], actions: &mut Vec<usize>) {
        actions.clear();
        actions.extend(envs.iter().map(|e| e.pursuit_action() as usize));
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::env::Env;
    use crate::eval::{TaskResult, run_episodes};
    use crate::tasks::ConstantAction;
    use crate::test_maps;

    /// Montlake without other traffic: what steering alone does.
    fn empty_setup() -> Arc<RingDrivingSetup> {
        let mut config = RingDrivingConfig::default();
        config.traffic.max_vehicles = Some(0);
        RingDrivingSetup::new(Arc::new(test_maps::montlake()), config).unwrap()
    }

    fn results<P: TaskPolicy<RingDriving>>(
        setup: &Arc<RingDrivingSetup>,
        policy: impl Fn() -> P + Sync,
        episodes: u64,
    ) -> (TaskResult, Vec<RingDrivingSummary>) {
        let seeds: Vec<u64> = (0..episodes).collect();
        let make_env = || {
            let mut env = RingDriving::new(Arc::clone(setup));
            env.set_rendering(false);
            env
        };
        let summaries = run_episodes(make_env, policy, &seeds, 8);
        (TaskResult::of(&summaries), summaries)
    }

    #[test]
    fn lane_reward_at_known_deviations() {
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(lane_reward(0.0, 0.0), 2.0));
        assert!(close(lane_reward(1.0, 0.1), 2.0));
        assert!(close(lane_reward(0.5, 0.05), 2.0));
        assert!(close(lane_reward(2.0, 0.2), 1.0));
        assert!(close(lane_reward(10.0, 1.0), 0.2));
        assert!(close(lane_reward(-4.0, 0.0), 1.25));
        assert!(close(lane_reward(90.0, 4.0), 1.0 / 90.0 + 1.0 / 40.0));
        assert!(close(lane_reward(f64::NAN, 0.0), 1.0));
        assert!(close(lane_reward(f64::INFINITY, f64::INFINITY), 0.0));
    }

    #[test]
    fn the_rule_follows_the_lane_round_the_roundabout() {
        let setup = empty_setup();
        let (result, summaries) = results(&setup, || PursuitRule, 40);
        // Three actions cannot follow every kink of a mini roundabout's mapped lanes: one
        // of these 40 episodes (seed 2) ends off the road.
        assert!(result.reaches >= 0.95, "{result:?}");
        let angle = result.metrics[0].1.unwrap();
        let distance = result.metrics[1].1.unwrap();
        assert!(angle < 10.0, "mean angle deviation {angle}°");
        assert!(distance < 0.3, "mean distance deviation {distance} m");
        // Episodes last the full 10 s unless the route ended first, never longer.
        assert!(summaries.iter().all(|s| s.episode_length_s <= 10.0 + 1e-9));
        assert!(summaries.iter().any(|s| s.steps == 100));
        // Every step of a clean episode earns at most 2.
        assert!(
            summaries
                .iter()
                .all(|s| s.episode_return > 0.0 && s.episode_return <= 2.0 * s.steps as f64)
        );
    }

    #[test]
    fn always_forward_left_leaves_the_lane() {
        let setup = empty_setup();
        let (result, _) = results(
            &setup,
            || ConstantAction(SteerAction::ForwardLeft as usize),
            40,
        );
        assert!(result.off_roads >= 0.9, "{result:?}");
        assert!(result.metrics[0].1.unwrap() > 15.0, "{result:?}");
    }

    /// Rewards as bits, outcomes and a hash of every observation over 300 steps of random
    /// actions, episodes reset as they end.
    fn trace(setup: &Arc<RingDrivingSetup>, seed: u64) -> (Vec<u32>, Vec<Option<Outcome>>, u64) {
        let mut env = RingDriving::new(Arc::clone(setup));
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut hash = 0u64;
        let mut fold = |o: &Observation| {
            for b in &o.layers {
                hash = hash.wrapping_mul(31).wrapping_add(u64::from(*b));
            }
            for s in &o.scalars {
                hash = hash.rotate_left(7) ^ u64::from(s.to_bits());
            }
        };
        let mut episode = seed;
        fold(&env.reset(episode));
        let (mut rewards, mut outcomes) = (Vec::new(), Vec::new());
        for _ in 0..300 {
            let step = env.step(rng.random_range(0..3));
            fold(&step.observation);
            rewards.push(step.reward.to_bits());
            outcomes.push(step.outcome);
            if step.outcome.is_some() {
                episode += 1;
                fold(&env.reset(episode));
            }
        }
        (rewards, outcomes, hash)
    }

    #[test]
    fn the_same_seed_gives_the_same_episodes() {
        let setup = RingDrivingSetup::new(
            Arc::new(test_maps::montlake()),
            RingDrivingConfig::default(),
        )
        .unwrap();
        let a = trace(&setup, 3);
        assert_eq!(a, trace(&setup, 3));
        assert_ne!(a.0, trace(&setup, 4).0);
        assert!(a.1.iter().filter(|o| o.is_some()).count() >= 3);
    }

    #[test]
    fn observations_have_the_declared_shape_and_odd_inputs_do_not_panic() {
        let setup = RingDrivingSetup::new(
            Arc::new(test_maps::montlake()),
            RingDrivingConfig::default(),
        )
        .unwrap();
        let mut env = RingDriving::new(Arc::clone(&setup));
        // Stepping before any reset ends at once.
        assert!(env.step(0).outcome.is_some());
        let spec = env.observation_spec();
        let first = env.reset(u64::MAX);
        assert_eq!(first.layers.len(), spec.layer_len());
        assert_eq!(first.scalars.len(), spec.scalars);
        // An unknown action index is driven as forward.
        let mut last = env.step(usize::MAX);
        while last.outcome.is_none() {
            last = env.step(7);
        }
        let after = env.step(1);
        assert_eq!(after.reward, 0.0);
        assert_eq!(after.outcome, last.outcome);
    }

    /// Frames that encode the ego's position, in the default camera table's shape.
    #[derive(Debug)]
    struct PositionFrames((usize, usize, usize));

    impl SceneObserver for PositionFrames {
        fn frame_shape(&self) -> (usize, usize, usize) {
            self.0
        }

        fn observe(&self, scene: &Scene<'_>, out: &mut Vec<u8>) {
            let (c, h, w) = self.0;
            let p = scene
                .ego_actor()
                .map_or(0.0, |a| a.position.x + a.position.y);
            out.clear();
            out.resize(c * h * w, (p * 10.0).rem_euclid(251.0) as u8);
        }
    }

    #[test]
    fn the_camera_view_needs_its_table_and_observer_and_has_their_shape() {
        let map = Arc::new(test_maps::montlake());
        let mut config = RingDrivingConfig {
            view: View::CameraSegmentation,
            ..RingDrivingConfig::default()
        };
        let no_table = RingDrivingSetup::new(Arc::clone(&map), config.clone()).unwrap_err();
        assert!(no_table.to_string().contains("camera"), "{no_table}");
        config.camera = Some(CameraViewConfig {
            segmenter: "some/model".into(),
            ..CameraViewConfig::default()
        });
        let no_observer = RingDrivingSetup::new(Arc::clone(&map), config.clone()).unwrap_err();
        assert!(
            no_observer.to_string().contains("observer"),
            "{no_observer}"
        );
        let shape = config.camera.as_ref().unwrap().frame_shape();
        assert_eq!(shape, (3, 32, 64));
        let wrong: Arc<dyn SceneObserver> = Arc::new(PositionFrames((1, 2, 3)));
        assert!(
            RingDrivingSetup::with_observer(Arc::clone(&map), config.clone(), Some(wrong)).is_err()
        );

        let observer: Arc<dyn SceneObserver> = Arc::new(PositionFrames(shape));
        let setup = RingDrivingSetup::with_observer(map, config, Some(observer)).unwrap();
        let spec = setup.observation_spec();
        assert_eq!(
            spec,
            ObservationSpec {
                channels: 6,
                height: 32,
                width: 64,
                scalars: SCALARS
            }
        );
        let mut env = RingDriving::new(Arc::clone(&setup));
        assert_eq!(env.observation_spec(), spec);
        let first = env.reset(5);
        assert_eq!(first.layers.len(), spec.layer_len());
        // Both stacked frames of a reset are the first one.
        let half = spec.layer_len() / 2;
        assert_eq!(first.layers[..half], first.layers[half..]);
        let mut step = env.step(0);
        for _ in 0..3 {
            step = env.step(0);
        }
        assert_eq!(step.observation.layers.len(), spec.layer_len());
        assert_ne!(
            step.observation.layers, first.layers,
            "the frames follow the ego"
        );
        // Rendering off: no layers, the same episode.
        env.set_rendering(false);
        assert!(env.reset(5).layers.is_empty());
    }

    #[test]
    fn the_bird_s_eye_view_stays_the_default_and_out_of_saved_configs() {
        let config = RingDrivingConfig::default();
        assert_eq!(config.view, View::Bev);
        let json = serde_json::to_value(&config).unwrap();
        assert!(
            json.get("view").is_none() && json.get("camera").is_none(),
            "{json}"
        );
        let scalars = RingDrivingConfig {
            view: View::Scalars,
            ..RingDrivingConfig::default()
        };
        let map = Arc::new(test_maps::montlake());
        assert!(RingDrivingSetup::new(map, scalars).is_err());
    }

    #[test]
    fn invalid_configs_are_rejected() {
        let map = Arc::new(test_maps::montlake());
        let bad = [
            RingDrivingConfig {
                episode_s: 0.0,
                ..RingDrivingConfig::default()
            },
            RingDrivingConfig {
                steer_rad: f64::NAN,
                ..RingDrivingConfig::default()
            },
            RingDrivingConfig {
                ring_start_probability: 1.5,
                ..RingDrivingConfig::default()
            },
            RingDrivingConfig {
                start_before_yield_m: (5.0, 1.0),
                ..RingDrivingConfig::default()
            },
        ];
        for config in bad {
            assert!(RingDrivingSetup::new(Arc::clone(&map), config).is_err());
        }
        let road = test_maps::straight_road(Point::new(0.0, 0.0), Point::new(100.0, 0.0));
        assert!(RingDrivingSetup::new(Arc::new(road), RingDrivingConfig::default()).is_err());
    }
}
