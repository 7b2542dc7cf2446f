//! Route following's settings: the ego, the route pool, the other vehicles, the reward
//! and the view.

use super::*;

/// Distance within which the nearest other vehicle is an input, m.
pub(super) const NEAR_M: f64 = 20.0;

/// Reward constants (the AIT study's).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RouteReward {
    pub in_lane_threshold: f64,
    pub below_lane_penalty: f64,
    pub terminal_penalty: f64,
    pub steer_change_penalty: f64,
}

impl Default for RouteReward {
    fn default() -> Self {
        RouteReward {
            in_lane_threshold: 0.98,
            below_lane_penalty: -1.0,
            terminal_penalty: -4.0,
            steer_change_penalty: -0.2,
        }
    }
}

/// `[agent.route]`: the route-following task's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RouteConfig {
    /// The ego's size, wheelbase and steering limit (`max_steer_rad`).
    pub ego: EgoConfig,
    pub max_speed_kmh: f64,
    /// Simulation step, s.
    pub step_s: f64,
    /// Simulation steps per decision.
    pub action_repeat: usize,
    pub steer_increment_rad: f64,
    /// Length range of the routes in the pool, m (the MTSU routes were about 128 m).
    pub route_length_m: (f64, f64),
    /// Routes in the pool.
    pub pool_size: usize,
    /// Seed of the pool (fixed, so a map always has the same routes and held-out set).
    pub pool_seed: u64,
    /// Share of the pool held out of training.
    pub held_out_fraction: f64,
    pub other_vehicles: usize,
    /// Speed range of the other vehicles, m/s.
    pub other_speed_mps: (f64, f64),
    /// Lateral distances of the route's centre line are given at these distances ahead, m.
    pub lookahead_m: Vec<f64>,
    /// Beyond the lane's edge, m, the ego is off road.
    pub off_road_m: f64,
    pub time_limit_factor: f64,
    pub reward: RouteReward,
    /// Which layers the agent sees besides its scalars: `scalars` (none), `bev` (the `bev`
    /// table, or [`RouteConfig::default_bev`]) or `camera-segmentation` (the `camera` table).
    #[serde(skip_serializing_if = "is_scalars")]
    pub view: View,
    /// The bird's-eye layers of `view = "bev"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bev: Option<BevConfig>,
    /// The camera-segmentation view's settings (`segmenter` is required for that view).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraViewConfig>,
}

pub(super) fn is_scalars(view: &View) -> bool {
    *view == View::Scalars
}

impl Default for RouteConfig {
    fn default() -> Self {
        RouteConfig {
            ego: EgoConfig::default(),
            max_speed_kmh: 8.0,
            step_s: 0.1,
            action_repeat: 2,
            steer_increment_rad: 0.1,
            route_length_m: (80.0, 200.0),
            pool_size: 200,
            pool_seed: 7,
            held_out_fraction: 0.25,
            other_vehicles: 4,
            other_speed_mps: (1.0, 4.0),
            lookahead_m: vec![0.0, 2.0, 4.0, 6.0, 8.0, 11.0, 14.0, 18.0],
            off_road_m: 1.5,
            time_limit_factor: 2.0,
            reward: RouteReward::default(),
            view: View::Scalars,
            bev: None,
            camera: None,
        }
    }
}

impl RouteConfig {
    pub(super) fn validate(&self) -> Result<(), SimError> {
        let (lo, hi) = self.route_length_m;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let problem = if !positive(self.max_speed_kmh) {
            Some("max_speed_kmh must be positive")
        } else if !positive(self.step_s) || self.action_repeat == 0 {
            Some("step_s and action_repeat must be positive")
        } else if !positive(lo) || hi.is_nan() || hi < lo {
            Some("route_length_m must be (min, max) with 0 < min <= max")
        } else if self.pool_size == 0 {
            Some("pool_size must be positive")
        } else if !(0.0..1.0).contains(&self.held_out_fraction) {
            Some("held_out_fraction must be in [0, 1)")
        } else if self.lookahead_m.is_empty() {
            Some("lookahead_m needs at least one distance")
        } else if self.view == View::CameraSegmentation && self.camera.is_none() {
            Some(
                "view = \"camera-segmentation\" needs a [agent.route.camera] table with \
                 segmenter = \"<model folder>\"",
            )
        } else {
            None
        };
        if let Some(p) = problem {
            return Err(SimError::Config(format!("[agent.route]: {p}")));
        }
        match self.view {
            View::Scalars => Ok(()),
            View::Bev => self.bev_config().validate(),
            View::CameraSegmentation => self.camera.as_ref().map_or(Ok(()), |c| c.validate()),
        }
    }

    /// The bird's-eye view of a campus drive when no `bev` table is given: 42 × 42 pixels
    /// over 24 m (0.57 m a pixel), navigable area, route (1.5 m wide), vehicles; 2 frames.
    pub fn default_bev() -> BevConfig {
        BevConfig {
            width: 42,
            height: 42,
            forward_m: 24.0,
            lateral_m: 24.0,
            layers: vec![
                crate::render::Layer::Navigable,
                crate::render::Layer::Path,
                crate::render::Layer::Obstacles,
            ],
            stack: 2,
            map_resolution_m: 0.25,
            path_width_m: 1.5,
            ..BevConfig::default()
        }
    }

    /// The bird's-eye view used by `view = "bev"`.
    pub fn bev_config(&self) -> BevConfig {
        self.bev.clone().unwrap_or_else(Self::default_bev)
    }

    /// Scalar inputs: the route offsets, lane half width, speed, steering, nearest vehicle.
    pub fn scalars(&self) -> usize {
        self.lookahead_m.len() + 5
    }

    /// The shape of the task's observations with this config.
    pub fn observation_spec(&self) -> ObservationSpec {
        let scalars = self.scalars();
        match (self.view, &self.camera) {
            (View::Bev, _) => self.bev_config().observation_spec(scalars),
            (View::CameraSegmentation, Some(camera)) => camera.observation_spec(scalars),
            _ => ObservationSpec {
                channels: 0,
                height: 0,
                width: 0,
                scalars,
            },
        }
    }

    pub(super) fn max_speed_mps(&self) -> f64 {
        self.max_speed_kmh / 3.6
    }
}
