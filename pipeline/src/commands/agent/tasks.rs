//! What `agent train` and `agent eval` need of each task, behind one trait.
//!
//! Registering a new task (one file of `sim::tasks` implementing `sim::tasks::Task`):
//! 1. a variant of [`Task`](super::Task) (its kebab-case name is the `--task` value);
//! 2. its config table in [`AgentConfig`](super::AgentConfig) (e.g. `[agent.obstacle]`);
//! 3. a unit struct implementing [`TaskKind`] below (usually through [`GenericTask`]);
//! 4. an arm in the `match` of `train::train` and of `eval::eval`.
//!
//! Roundabout insertion keeps its own evaluation (conditions of traffic × aggressiveness,
//! the Parma study's baselines); every other task is evaluated by the generic
//! `sim::tasks::run_episodes` over the conditions its [`TaskKind`] names.

use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use maps::Map;
use serde::Serialize;
use serde::de::DeserializeOwned;
use sim::Env;
use sim::observer::{CameraViewConfig, SceneObserver, View};
use sim::tasks::obstacle::{ObstacleAvoidance, ObstacleConfig, ObstacleSetup, Scenario};
use sim::tasks::route::{RouteConfig, RouteFollowing, RouteSetup, RouteSplit};
use sim::tasks::{
    InsertionConfig, InsertionSetup, RingDriving, RingDrivingConfig, RingDrivingSetup,
    RoundaboutInsertion,
};
use sim::world::TrafficLevel;

use models::policy::QPolicy;
use sim::eval::{Condition, EVAL_STAGE, EvalOptions, evaluate};
use sim::seed::derive_seed;
use sim::tasks::{TaskResult, run_episodes};

use super::{AgentConfig, TaskRecord, episodes, insertion_setup};
use crate::error::CliError;
use crate::inputs::load_or_import_map;
use crate::recording::Stream;

/// The task-specific parts of training and evaluating an agent.
pub trait TaskKind {
    /// What the agent acts in.
    type Env: Env + 'static;
    /// The task's `[agent.<table>]` settings, stored in the agent's `task.json`.
    type Config: Clone + Serialize + DeserializeOwned;
    /// Prepared once (map, layouts, renderers) and shared by every environment.
    type Setup: Send + Sync + 'static;

    /// The `[agent.<table>]` of the config file.
    fn config(agent: &AgentConfig) -> Self::Config;

    /// Prepares the task, on the map at `map` when the task drives on one.
    fn setup(map: Option<&Path>, config: &Self::Config) -> Result<Arc<Self::Setup>>;

    /// The map the task drives on, for the recording.
    fn map(setup: &Self::Setup) -> Option<&Map>;

    /// One training environment.
    fn train_env(setup: &Arc<Self::Setup>, traffic: TrafficLevel) -> Self::Env;

    /// The task deciding every `steps` steps on frames stacked as in `config`
    /// (`[agent.validation] action_repeat`); only tasks that hold actions over steps can.
    fn deciding_every(_config: &Self::Config, _steps: usize) -> Result<Self::Config> {
        Err(CliError::new(
            "[agent.validation] action_repeat is for roundabout-insertion agents",
            "leave action_repeat out of [agent.validation]",
        )
        .into())
    }

    /// Validates `policy` (see [`super::validation`]): `episodes` greedy episodes per
    /// validation condition, drawn as an evaluation with `seed` draws them; per condition,
    /// the share that reached the goal. Never on conditions held out for evaluation.
    fn validate(
        setup: &Arc<Self::Setup>,
        policy: &QPolicy,
        traffic: TrafficLevel,
        episodes: usize,
        seed: u64,
    ) -> Vec<(String, f64)>;

    /// Logs `count` greedy episodes of `policy` to the recording: the first `count`
    /// episodes of an evaluation with `seed`.
    fn record_episodes(
        rec: &Stream,
        setup: &Arc<Self::Setup>,
        policy: &QPolicy,
        traffic: TrafficLevel,
        count: usize,
        seed: u64,
    ) -> Result<()>;
}

/// A task evaluated by the generic harness: named conditions, each its own environments.
pub trait GenericTask: TaskKind<Env: sim::tasks::Task + 'static> {
    /// The evaluation conditions by name, e.g. obstacle scenarios or traffic levels;
    /// `traffic` is what `agent eval --traffic` asked for (empty: the task's default).
    fn conditions(traffic: &[TrafficLevel]) -> Vec<String>;

    /// One environment of condition `name` (one of [`GenericTask::conditions`]).
    fn eval_env(setup: &Arc<Self::Setup>, condition: &str) -> Self::Env;
}

/// The task's config as stored in `task.json`.
pub fn task_config<K: TaskKind>(record: &TaskRecord, file: &Path) -> Result<K::Config> {
    serde_json::from_value(record.config.clone()).map_err(|e| {
        CliError::file(
            file,
            format!("the {:?} task's config is invalid: {e}", record.task),
            "give a folder written by `pipeline agent train` of this version",
        )
        .into()
    })
}

/// The map argument of a task that drives on a map.
pub fn required_map(map: Option<&Path>, task: &str) -> Result<Map> {
    let Some(path) = map else {
        return Err(CliError::new(
            format!("--map is required for the {task} task"),
            "give a map folder from `pipeline map import`, or an OSM / Lanelet2 file",
        )
        .into());
    };
    load_or_import_map(path)
}

/// The observer of `view = "camera-segmentation"` on `map` (None for the other views): the
/// camera renderer and the segmenter of the `camera` table. A missing or invalid segmenter
/// folder is one error naming the file.
pub fn camera_observer(
    map: &Map,
    view: View,
    camera: Option<&CameraViewConfig>,
) -> Result<Option<Arc<dyn SceneObserver>>> {
    let (View::CameraSegmentation, Some(camera)) = (view, camera) else {
        return Ok(None);
    };
    let observer = models::camera_view::load(map, camera).map_err(|e| {
        let message = match e.path() {
            Some(_) => format!("the camera view's segmenter: {e}"),
            None => format!(
                "the camera view's segmenter {}: {e}",
                camera.segmenter.display()
            ),
        };
        CliError::new(
            message,
            "set segmenter = \"<folder>\" of the task's camera table to a model folder written by \
             `pipeline segmenter train` (model.json + model.bpk)",
        )
    })?;
    let observer: Arc<dyn SceneObserver> = Arc::new(observer);
    Ok(Some(observer))
}

/// The camera table with its segmenter folder made absolute (when it exists), so the
/// agent's task.json still finds it from another working directory.
fn absolute_camera(camera: Option<&CameraViewConfig>) -> Option<CameraViewConfig> {
    camera.map(|c| {
        let mut c = c.clone();
        if let Ok(path) = std::fs::canonicalize(&c.segmenter) {
            c.segmenter = path;
        }
        c
    })
}

/// The share of `episodes` greedy episodes of `policy` in environments from `make_env`
/// that reached the goal, drawn as an evaluation with `seed` draws them.
fn reached_share<E: sim::tasks::Task>(
    make_env: impl Fn() -> E + Sync,
    policy: &QPolicy,
    episodes: usize,
    seed: u64,
) -> f64 {
    let seeds: Vec<u64> = (0..episodes as u64)
        .map(|k| derive_seed(seed, EVAL_STAGE, k))
        .collect();
    TaskResult::of(&run_episodes(
        make_env,
        || policy.clone(),
        &seeds,
        VALIDATION_LOCKSTEP,
    ))
    .reaches
}

/// Episodes a validation runs side by side per network forward pass.
const VALIDATION_LOCKSTEP: usize = 32;

/// Roundabout insertion (the Parma study).
#[derive(Debug)]
pub struct Insertion;

impl TaskKind for Insertion {
    type Env = RoundaboutInsertion;
    type Config = InsertionConfig;
    type Setup = InsertionSetup;

    fn config(agent: &AgentConfig) -> InsertionConfig {
        agent.task.clone()
    }

    fn setup(map: Option<&Path>, config: &InsertionConfig) -> Result<Arc<InsertionSetup>> {
        let loaded = required_map(map, "roundabout-insertion")?;
        insertion_setup(loaded, map.unwrap_or(Path::new("")), config.clone())
    }

    fn map(setup: &InsertionSetup) -> Option<&Map> {
        Some(setup.map())
    }

    fn deciding_every(config: &InsertionConfig, steps: usize) -> Result<InsertionConfig> {
        Ok(config.deciding_every(steps))
    }

    fn train_env(setup: &Arc<InsertionSetup>, traffic: TrafficLevel) -> RoundaboutInsertion {
        let mut env = RoundaboutInsertion::new(Arc::clone(setup));
        env.set_traffic(traffic);
        env
    }

    /// At the training traffic, for each of the evaluation's aggressiveness values.
    fn validate(
        setup: &Arc<InsertionSetup>,
        policy: &QPolicy,
        traffic: TrafficLevel,
        episodes: usize,
        seed: u64,
    ) -> Vec<(String, f64)> {
        let conditions: Vec<Condition> = [0.0, 0.5, 1.0]
            .map(|aggressiveness| Condition {
                traffic,
                aggressiveness,
            })
            .to_vec();
        let options = EvalOptions {
            episodes,
            seed,
            lockstep: VALIDATION_LOCKSTEP,
        };
        evaluate(setup, || policy.clone(), &conditions, &options, &|_| {})
            .iter()
            .map(|r| (format!("aggressiveness {}", r.aggressiveness), r.reaches))
            .collect()
    }

    fn record_episodes(
        rec: &Stream,
        setup: &Arc<InsertionSetup>,
        policy: &QPolicy,
        traffic: TrafficLevel,
        count: usize,
        seed: u64,
    ) -> Result<()> {
        let condition = Condition {
            traffic,
            aggressiveness: 0.5,
        };
        episodes::record(rec, setup, policy, condition, count, seed)
    }
}

/// Roundabout driving (the ITS study): steering along a route through the roundabout.
#[derive(Debug)]
pub struct RoundaboutDriving;

impl TaskKind for RoundaboutDriving {
    type Env = RingDriving;
    type Config = RingDrivingConfig;
    type Setup = RingDrivingSetup;

    fn config(agent: &AgentConfig) -> RingDrivingConfig {
        let mut config = agent.roundabout_driving.clone();
        config.camera = absolute_camera(config.camera.as_ref());
        config
    }

    fn setup(map: Option<&Path>, config: &RingDrivingConfig) -> Result<Arc<RingDrivingSetup>> {
        let loaded = Arc::new(required_map(map, "roundabout-driving")?);
        let observer = camera_observer(&loaded, config.view, config.camera.as_ref())?;
        RingDrivingSetup::with_observer(loaded, config.clone(), observer).map_err(|e| {
            CliError::new(
                format!("cannot set up roundabout driving: {e}"),
                "give a map with a roundabout (e.g. data/osm/montlake_roundabout.osm.pbf) and \
                 valid [agent.roundabout_driving] settings",
            )
            .into()
        })
    }

    fn map(setup: &RingDrivingSetup) -> Option<&Map> {
        Some(setup.map())
    }

    fn train_env(setup: &Arc<RingDrivingSetup>, traffic: TrafficLevel) -> RingDriving {
        let mut env = RingDriving::new(Arc::clone(setup));
        env.set_traffic(traffic);
        env
    }

    /// At the training traffic.
    fn validate(
        setup: &Arc<RingDrivingSetup>,
        policy: &QPolicy,
        traffic: TrafficLevel,
        episodes: usize,
        seed: u64,
    ) -> Vec<(String, f64)> {
        let make_env = || Self::train_env(setup, traffic);
        let reached = reached_share(make_env, policy, episodes, seed);
        vec![(format!("traffic {}", traffic.name()), reached)]
    }

    fn record_episodes(
        rec: &Stream,
        setup: &Arc<RingDrivingSetup>,
        policy: &QPolicy,
        traffic: TrafficLevel,
        count: usize,
        seed: u64,
    ) -> Result<()> {
        episodes::record_task(rec, || Self::train_env(setup, traffic), policy, count, seed)
    }
}

impl GenericTask for RoundaboutDriving {
    /// One condition per traffic level, `traffic low` / `medium` / `high` by default.
    fn conditions(traffic: &[TrafficLevel]) -> Vec<String> {
        let levels = if traffic.is_empty() {
            &TrafficLevel::ALL[..]
        } else {
            traffic
        };
        levels
            .iter()
            .map(|t| format!("traffic {}", t.name()))
            .collect()
    }

    fn eval_env(setup: &Arc<RingDrivingSetup>, condition: &str) -> RingDriving {
        let level = condition
            .strip_prefix("traffic ")
            .and_then(|name| name.parse().ok())
            .unwrap_or(TrafficLevel::Medium);
        Self::train_env(setup, level)
    }
}

/// Campus route following (the AIT / MTSU studies).
#[derive(Debug)]
pub struct Route;

impl TaskKind for Route {
    type Env = RouteFollowing;
    type Config = RouteConfig;
    type Setup = RouteSetup;

    fn config(agent: &AgentConfig) -> RouteConfig {
        let mut config = agent.route.clone();
        config.camera = absolute_camera(config.camera.as_ref());
        config
    }

    fn setup(map: Option<&Path>, config: &RouteConfig) -> Result<Arc<RouteSetup>> {
        let loaded = Arc::new(required_map(map, "route-following")?);
        let path = map.unwrap_or(Path::new(""));
        let observer = camera_observer(&loaded, config.view, config.camera.as_ref())?;
        RouteSetup::with_observer(loaded, config.clone(), observer).map_err(|e| {
            CliError::file(
                path,
                format!("cannot set up route following: {e}"),
                "the map needs connected car lanes with routes of [agent.route] route_length_m",
            )
            .into()
        })
    }

    fn map(setup: &RouteSetup) -> Option<&Map> {
        Some(setup.map())
    }

    fn train_env(setup: &Arc<RouteSetup>, _: TrafficLevel) -> RouteFollowing {
        let mut env = RouteFollowing::new(Arc::clone(setup));
        env.set_split(RouteSplit::Training);
        env
    }

    /// On training routes only: the held-out routes are for evaluation.
    fn validate(
        setup: &Arc<RouteSetup>,
        policy: &QPolicy,
        traffic: TrafficLevel,
        episodes: usize,
        seed: u64,
    ) -> Vec<(String, f64)> {
        let make_env = || Self::train_env(setup, traffic);
        let reached = reached_share(make_env, policy, episodes, seed);
        vec![(TRAINING_ROUTES.to_owned(), reached)]
    }

    fn record_episodes(
        rec: &Stream,
        setup: &Arc<RouteSetup>,
        policy: &QPolicy,
        _: TrafficLevel,
        count: usize,
        seed: u64,
    ) -> Result<()> {
        episodes::record_task(rec, || Self::eval_env(setup, HELD_OUT), policy, count, seed)
    }
}

const HELD_OUT: &str = "held-out routes";
const TRAINING_ROUTES: &str = "training routes";

impl GenericTask for Route {
    fn conditions(_: &[TrafficLevel]) -> Vec<String> {
        vec![HELD_OUT.to_owned(), TRAINING_ROUTES.to_owned()]
    }

    fn eval_env(setup: &Arc<RouteSetup>, condition: &str) -> RouteFollowing {
        let mut env = RouteFollowing::new(Arc::clone(setup));
        env.set_split(if condition == TRAINING_ROUTES {
            RouteSplit::Training
        } else {
            RouteSplit::HeldOut
        });
        env
    }
}

/// Obstacle avoidance (the Thai CARLA study), on its own synthetic road: `--map` is not used.
#[derive(Debug)]
pub struct Obstacle;

impl TaskKind for Obstacle {
    type Env = ObstacleAvoidance;
    type Config = ObstacleConfig;
    type Setup = ObstacleSetup;

    fn config(agent: &AgentConfig) -> ObstacleConfig {
        agent.obstacle.clone()
    }

    fn setup(_: Option<&Path>, config: &ObstacleConfig) -> Result<Arc<ObstacleSetup>> {
        ObstacleSetup::new(config.clone()).map_err(|e| {
            CliError::new(
                format!("cannot set up obstacle avoidance: {e}"),
                "check the [agent.obstacle] table of the config",
            )
            .into()
        })
    }

    fn map(setup: &ObstacleSetup) -> Option<&Map> {
        Some(setup.map())
    }

    fn train_env(setup: &Arc<ObstacleSetup>, _: TrafficLevel) -> ObstacleAvoidance {
        ObstacleAvoidance::new(Arc::clone(setup))
    }

    /// Each scenario on its own, as evaluated.
    fn validate(
        setup: &Arc<ObstacleSetup>,
        policy: &QPolicy,
        _: TrafficLevel,
        episodes: usize,
        seed: u64,
    ) -> Vec<(String, f64)> {
        Self::conditions(&[])
            .into_iter()
            .map(|condition| {
                let make_env = || Self::eval_env(setup, &condition);
                let reached = reached_share(make_env, policy, episodes, seed);
                (condition, reached)
            })
            .collect()
    }

    fn record_episodes(
        rec: &Stream,
        setup: &Arc<ObstacleSetup>,
        policy: &QPolicy,
        _: TrafficLevel,
        count: usize,
        seed: u64,
    ) -> Result<()> {
        // Mixed scenarios: the recorded episodes show both kinds of obstacle.
        let make_env = || {
            let mut env = ObstacleAvoidance::new(Arc::clone(setup));
            env.set_scenario(Scenario::Mixed);
            env
        };
        episodes::record_task(rec, make_env, policy, count, seed)
    }
}

const STATIC_OBSTACLE: &str = "static obstacle";
const CROSSING_OBSTACLE: &str = "crossing obstacle";

impl GenericTask for Obstacle {
    fn conditions(_: &[TrafficLevel]) -> Vec<String> {
        vec![STATIC_OBSTACLE.to_owned(), CROSSING_OBSTACLE.to_owned()]
    }

    fn eval_env(setup: &Arc<ObstacleSetup>, condition: &str) -> ObstacleAvoidance {
        let mut env = ObstacleAvoidance::new(Arc::clone(setup));
        env.set_scenario(if condition == CROSSING_OBSTACLE {
            Scenario::Crossing
        } else {
            Scenario::Static
        });
        env
    }
}
