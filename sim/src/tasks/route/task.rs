//! Route following as a [`Task`]: its summary, conditions (route splits) and rule
//! baseline.

use super::*;
use crate::tasks::tables::{Tables, TablesMut};

/// How one episode went.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RouteSummary {
    pub outcome: Outcome,
    pub steps: usize,
    pub episode_return: f64,
    pub route_length_m: f64,
    /// Share of the route driven when the episode ended.
    pub completion: f64,
    pub lane_rms_error_m: f64,
    /// Share of decisions with the in-lane fraction at or above the threshold.
    pub time_in_lane: f64,
    pub mean_speed_kmh: f64,
}

impl TaskSummary for RouteSummary {
    outcome_and_return_fields!();

    fn metrics(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("route completion %", 100.0 * self.completion),
            ("lane-centre RMS m", self.lane_rms_error_m),
            ("time in lane %", 100.0 * self.time_in_lane),
            ("mean speed km/h", self.mean_speed_kmh),
            ("route m", self.route_length_m),
        ]
    }
}

pub(super) const HELD_OUT: &str = "held-out routes";
pub(super) const TRAINING_ROUTES: &str = "training routes";

impl Task for RouteFollowing {
    type Config = RouteConfig;
    type Setup = RouteSetup;
    /// The routes episodes draw from.
    type Condition = RouteSplit;

    const ID: TaskId = TaskId::RouteFollowing;

    fn table<'a>(tables: Tables<'a>) -> &'a Self::Config {
        tables.route
    }

    fn table_mut<'a>(tables: TablesMut<'a>) -> &'a mut Self::Config {
        tables.route
    }

    fn camera_view(config: &RouteConfig) -> Option<&CameraViewConfig> {
        config.view.camera(config.camera.as_ref())
    }

    fn camera_mut(config: &mut RouteConfig) -> Option<&mut CameraViewConfig> {
        config.camera.as_mut()
    }

    /// On training routes, whatever the traffic (the other vehicles are the config's).
    fn training_env(setup: &Arc<RouteSetup>, _: TrafficLevel) -> Self {
        Self::env(setup, &RouteSplit::Training)
    }

    fn env(setup: &Arc<RouteSetup>, split: &RouteSplit) -> Self {
        let mut env = RouteFollowing::new(Arc::clone(setup));
        env.set_split(*split);
        env
    }

    /// The held-out routes, then the training ones.
    fn conditions(_: &ConditionChoice) -> Vec<RouteSplit> {
        vec![RouteSplit::HeldOut, RouteSplit::Training]
    }

    fn condition_name(split: &RouteSplit) -> String {
        match split {
            RouteSplit::HeldOut => HELD_OUT,
            RouteSplit::Training => TRAINING_ROUTES,
        }
        .to_owned()
    }

    /// On training routes only: the held-out routes are for evaluation.
    fn validation_conditions(_: TrafficLevel) -> Vec<(String, RouteSplit)> {
        vec![(TRAINING_ROUTES.to_owned(), RouteSplit::Training)]
    }

    fn recorded_condition(_: TrafficLevel) -> RouteSplit {
        RouteSplit::HeldOut
    }

    fn baselines() -> Vec<(String, PolicyFactory<Self>)> {
        baselines_with_rule::<Self, PursuitRule>(&SteerAction::NAMES, "rule: pure pursuit")
    }

    fn scene(&self) -> Option<Scene<'_>> {
        let ego = &self.config().ego;
        let mut actors = vec![Actor {
            id: 0,
            kind: ActorKind::Car,
            position: self.bike.centre(),
            heading_rad: self.bike.heading,
            speed_mps: self.speed,
            length_m: ego.length_m,
            width_m: ego.width_m,
            lane: None,
            aggressiveness: None,
        }];
        for (i, o) in self.others.iter().enumerate() {
            let (p, h) = self.other_pose(o);
            actors.push(Actor {
                id: i as u32 + 1,
                kind: ActorKind::Car,
                position: p,
                heading_rad: h,
                speed_mps: o.speed,
                length_m: o.length,
                width_m: o.width,
                lane: None,
                aggressiveness: None,
            });
        }
        Some(Scene {
            map: &self.setup.map,
            time_s: self.time_s,
            actors,
            ego: 0,
            ego_path: self.route().path.outline(),
        })
    }

    /// Nothing to draw with `view = "scalars"`.
    fn set_rendering(&mut self, on: bool) {
        if let Some(view) = &mut self.view {
            view.set_rendering(on);
        }
    }
}

/// Pure pursuit on the route, turned into steering increments: an upper bound that reads
/// the route exactly.
#[derive(Debug, Clone, Copy, Default)]
pub struct PursuitRule;

impl PursuitRule {
    pub(super) fn decide(env: &RouteFollowing) -> SteerAction {
        let config = env.config();
        let lookahead = 3.0 + 0.5 * env.speed;
        let path = &env.route().path;
        let (target, _) = path.pose_at((env.s + lookahead).min(path.length()));
        let wanted = env.bike.pure_pursuit(target, config.ego.max_steer_rad);
        let half_step = config.steer_increment_rad / 2.0;
        let band = (env.steer - half_step, env.steer + half_step);
        let actions = [
            SteerAction::ForwardLeft,
            SteerAction::Forward,
            SteerAction::ForwardRight,
        ];
        turn(wanted, band, actions)
    }
}

impl TaskPolicy<RouteFollowing> for PursuitRule {
    fn act(&mut self, envs: &[&RouteFollowing], _: &[&Observation], actions: &mut Vec<usize>) {
        act_each(envs, actions, |env| Self::decide(env) as usize);
    }
}
