//! Obstacle avoidance's settings, its reward terms and the ego's lidar.

use super::*;

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
    pub(super) fn validate(&self) -> Result<(), SimError> {
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

    pub(super) fn cruise_speed_mps(&self) -> f64 {
        self.start_speed_kmh / 3.6
    }

    /// y of the ego's (right) lane centre; the other lane's is its negation.
    pub(super) fn ego_lane_y(&self) -> f64 {
        -self.lane_width_m / 2.0
    }

    pub(super) fn substeps(&self) -> usize {
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
