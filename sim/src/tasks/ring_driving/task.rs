//! Roundabout driving as a [`Task`]: its summary, conditions (traffic levels) and rule
//! baseline.

use super::*;
use crate::tasks::tables::{Tables, TablesMut};

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
    outcome_and_return_fields!();

    fn metrics(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("mean angle deviation °", self.mean_angle_deviation_deg),
            ("mean distance deviation m", self.mean_distance_deviation_m),
            ("episode length s", self.episode_length_s),
            ("mean speed km/h", self.mean_speed_kmh),
        ]
    }
}

impl Task for RingDriving {
    type Config = RingDrivingConfig;
    type Setup = RingDrivingSetup;
    /// The traffic level.
    type Condition = TrafficLevel;

    const ID: TaskId = TaskId::RoundaboutDriving;

    fn table<'a>(tables: Tables<'a>) -> &'a Self::Config {
        tables.ring_driving
    }

    fn table_mut<'a>(tables: TablesMut<'a>) -> &'a mut Self::Config {
        tables.ring_driving
    }

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
        act_each(envs, actions, |env| env.pursuit_action() as usize);
    }
}
