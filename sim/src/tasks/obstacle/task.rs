//! Obstacle avoidance as a [`Task`]: its road, summary, conditions and rule baseline.

use super::*;
use crate::tasks::tables::{Tables, TablesMut};

/// Prepared once and shared by every environment: the validated config, the straight
/// road's map and the ego's lane centre (its path, for scenes).
#[derive(Debug)]
pub struct ObstacleSetup {
    pub(super) config: ObstacleConfig,
    pub(super) map: Map,
    pub(super) ego_path: Vec<Point>,
}

impl TaskSetup for ObstacleSetup {
    type Config = ObstacleConfig;

    /// On its own straight road: `map` is not used.
    fn prepare(
        _: Option<Arc<Map>>,
        config: ObstacleConfig,
        _: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self>, SimError> {
        ObstacleSetup::new(config)
    }

    fn map(&self) -> &Map {
        &self.map
    }
}

impl ObstacleSetup {
    pub fn new(config: ObstacleConfig) -> Result<Arc<Self>, SimError> {
        config.validate()?;
        // The road runs from 20 m behind the start to 30 m past the destination, so a
        // scene shows road around the ego wherever an episode can end.
        let start = Point::new(-20.0, 0.0);
        let end = Point::new(config.destination_m + 30.0, 0.0);
        let map = straight_road(start, end, 2, config.lane_width_m, config.start_speed_kmh);
        let y = config.ego_lane_y();
        let ego_path = vec![Point::new(0.0, y), Point::new(config.destination_m, y)];
        Ok(Arc::new(ObstacleSetup {
            config,
            map,
            ego_path,
        }))
    }

    pub fn config(&self) -> &ObstacleConfig {
        &self.config
    }
}

/// How one episode went.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ObstacleSummary {
    pub outcome: Outcome,
    pub kind: ObstacleKind,
    pub steps: usize,
    pub episode_return: f64,
    pub mean_speed_mps: f64,
    /// Box-to-box gap to the obstacle when the ego first stopped (None: never stopped), m.
    pub stopping_gap_m: Option<f64>,
    /// Smallest box-to-box gap to the obstacle over the episode, m.
    pub min_gap_m: f64,
}

impl TaskSummary for ObstacleSummary {
    outcome_and_return_fields!();

    fn metrics(&self) -> Vec<(&'static str, f64)> {
        vec![
            (
                "reached without collision",
                f64::from(u8::from(self.outcome == Outcome::Reached)),
            ),
            (
                "stopping distance m",
                self.stopping_gap_m.unwrap_or(f64::NAN),
            ),
            ("minimum gap m", self.min_gap_m),
            ("mean speed m/s", self.mean_speed_mps),
        ]
    }
}

pub(super) const STATIC_OBSTACLE: &str = "static obstacle";
pub(super) const CROSSING_OBSTACLE: &str = "crossing obstacle";

impl Task for ObstacleAvoidance {
    type Config = ObstacleConfig;
    type Setup = ObstacleSetup;
    /// The obstacles the episodes get.
    type Condition = Scenario;

    const ID: TaskId = TaskId::ObstacleAvoidance;

    fn table<'a>(tables: Tables<'a>) -> &'a Self::Config {
        tables.obstacle
    }

    fn table_mut<'a>(tables: TablesMut<'a>) -> &'a mut Self::Config {
        tables.obstacle
    }

    /// The config's scenario, whatever the traffic (there is none).
    fn training_env(setup: &Arc<ObstacleSetup>, _: TrafficLevel) -> Self {
        ObstacleAvoidance::new(Arc::clone(setup))
    }

    fn env(setup: &Arc<ObstacleSetup>, scenario: &Scenario) -> Self {
        let mut env = ObstacleAvoidance::new(Arc::clone(setup));
        env.set_scenario(*scenario);
        env
    }

    /// Each scenario on its own: static, then crossing.
    fn conditions(_: &ConditionChoice) -> Vec<Scenario> {
        vec![Scenario::Static, Scenario::Crossing]
    }

    fn condition_name(scenario: &Scenario) -> String {
        match scenario {
            Scenario::Static => STATIC_OBSTACLE,
            Scenario::Crossing => CROSSING_OBSTACLE,
            Scenario::Mixed => "mixed obstacles",
        }
        .to_owned()
    }

    /// Each scenario on its own, as evaluated.
    fn validation_conditions(_: TrafficLevel) -> Vec<(String, Scenario)> {
        Self::conditions(&ConditionChoice::default())
            .into_iter()
            .map(|scenario| (Self::condition_name(&scenario), scenario))
            .collect()
    }

    /// Mixed scenarios: the recorded episodes show both kinds of obstacle.
    fn recorded_condition(_: TrafficLevel) -> Scenario {
        Scenario::Mixed
    }

    fn baselines() -> Vec<(String, PolicyFactory<Self>)> {
        baselines_with_rule::<Self, PassOrYield>(&Action::NAMES, "rule: pass or yield")
    }

    fn scene(&self) -> Option<Scene<'_>> {
        let (_, obstacle) = self.obstacle.as_ref()?;
        Some(Scene {
            map: &self.setup.map,
            time_s: self.time_s,
            actors: vec![self.ego_actor(), obstacle.clone()],
            ego: 0,
            ego_path: &self.setup.ego_path,
        })
    }
}

/// The rule baseline, reading the privileged state: a parked vehicle is passed on the other
/// lane (pure pursuit on its centre line from 45 m before it until the ego's rear is 6 m
/// past it, then back); for a crossing vehicle the ego brakes once within its stopping
/// distance + 6 m of it while it has not yet cleared the ego's corridor (the ego's width
/// and 0.7 m more each side, in its direction of travel), and drives on when it has.
/// Pure pursuit's angle becomes steer left / right when beyond half the steering angle.
#[derive(Debug, Clone, Copy, Default)]
pub struct PassOrYield;

impl PassOrYield {
    pub(super) fn decide(env: &ObstacleAvoidance) -> Action {
        let c = env.config();
        let Some((kind, obstacle)) = env.obstacle() else {
            return Action::Straight;
        };
        let ego = env.ego();
        let centre = ego.centre();
        let v = env.speed_mps();
        let front_x = centre.x + c.ego_length_m / 2.0;
        let rear_x = centre.x - c.ego_length_m / 2.0;
        let corners = obstacle.footprint().corners();
        let (mut x_min, mut x_max, mut y_min, mut y_max) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        for p in corners {
            x_min = x_min.min(p.x);
            x_max = x_max.max(p.x);
            y_min = y_min.min(p.y);
            y_max = y_max.max(p.y);
        }
        let own_lane = c.ego_lane_y();
        let target_y = match kind {
            ObstacleKind::Parked => {
                let passing = x_min - front_x < 45.0 && rear_x < x_max + 6.0;
                if passing { -own_lane } else { own_lane }
            }
            ObstacleKind::Crossing => {
                let half = c.ego_width_m / 2.0 + 0.7;
                let moving_left = obstacle.heading_rad.sin() > 0.0;
                let cleared = if moving_left {
                    y_min > centre.y + half
                } else {
                    y_max < centre.y - half
                };
                let gap = x_min - front_x;
                let stopping = v * v / (2.0 * c.brake_mps2) + v * c.policy_step_s + 6.0;
                if !cleared && x_max > rear_x && gap < stopping {
                    return Action::Brake;
                }
                own_lane
            }
        };
        let lookahead = 6.0 + 0.8 * v;
        let target = Point::new(ego.rear.x + lookahead, target_y);
        let angle = ego.pure_pursuit(target, MAX_STEER_DEG.to_radians());
        let threshold = c.steer_deg.to_radians() / 2.0;
        let actions = [Action::SteerLeft, Action::Straight, Action::SteerRight];
        turn(angle, (-threshold, threshold), actions)
    }
}

impl TaskPolicy<ObstacleAvoidance> for PassOrYield {
    fn act(&mut self, envs: &[&ObstacleAvoidance], _: &[&Observation], actions: &mut Vec<usize>) {
        act_each(envs, actions, |env| Self::decide(env) as usize);
    }
}
