//! Roundabout driving's settings (reward, view, start), its inputs and its setup.

use super::*;

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

pub(super) fn is_bev(view: &View) -> bool {
    *view == View::Bev
}

pub(super) fn validate(c: &RingDrivingConfig) -> Result<(), SimError> {
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

    fn observation_spec(&self) -> ObservationSpec {
        RingDrivingConfig::observation_spec(self)
    }

    roundabout_fields!();
}
