//! The driving tasks ([`sim::tasks::registry`]) from the command line: a task's settings
//! from the `--config` file, and its setup from a map path (the map loaded or imported, the
//! camera view's segmenter loaded), with one-line errors.

use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use maps::Map;
use serde::{Deserialize, Serialize};
use sim::SimError;
use sim::observer::{CameraViewConfig, SceneObserver};
use sim::tasks::insertion::InsertionConfig;
use sim::tasks::{Tables, TablesMut, Task, TaskVisitor};

use crate::error::CliError;
use crate::inputs::load_or_import_map;

/// `[agent]` of the `--config` file: the training settings, and one table per task of the
/// registry (its [`Task::Config`]).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AgentConfig {
    pub dqn: models::dqn::DqnConfig,
    /// Roundabout insertion.
    pub task: InsertionConfig,
    /// Route following.
    pub route: sim::tasks::route::RouteConfig,
    /// `[agent.roundabout_driving]`: the roundabout-driving task's settings.
    pub roundabout_driving: sim::tasks::RingDrivingConfig,
    /// Obstacle avoidance.
    pub obstacle: sim::tasks::obstacle::ObstacleConfig,
    /// `agent train --offline` (the network and optimiser settings come from `[agent.dqn]`).
    pub offline: models::offline::OfflineConfig,
    /// `[agent.validation]`: choosing the agent among the run's checkpoints.
    pub validation: models::validation::ValidationConfig,
}

impl AgentConfig {
    /// The tables of the tasks' settings.
    fn tables(&self) -> Tables<'_> {
        Tables {
            insertion: &self.task,
            route: &self.route,
            ring_driving: &self.roundabout_driving,
            obstacle: &self.obstacle,
        }
    }

    /// The tables of the tasks' settings, to change in place.
    fn tables_mut(&mut self) -> TablesMut<'_> {
        TablesMut {
            insertion: &mut self.task,
            route: &mut self.route,
            ring_driving: &mut self.roundabout_driving,
            obstacle: &mut self.obstacle,
        }
    }

    /// The settings table of task `T`.
    pub fn task_table<T: Task>(&self) -> T::Config {
        T::table(self.tables()).clone()
    }
}

/// Puts a traffic world into task `T`'s settings table of an [`AgentConfig`] (what
/// [`crate::config::Config::apply_world`] runs for every task).
#[derive(Debug)]
pub struct InWorld<'a> {
    pub agent: &'a mut AgentConfig,
    pub world: &'a sim::world::CalibratedWorld,
}

impl TaskVisitor for InWorld<'_> {
    type Output = ();
    fn visit<T: Task>(self) {
        let config = T::table_mut(self.agent.tables_mut());
        if let Some(changed) = T::in_world(config, self.world) {
            *config = changed;
        }
    }
}

/// The `[agent.<table>]` settings of task `T` in the config file, the camera table's
/// segmenter folder made absolute (when it exists), so the agent's task.json still finds it
/// from another working directory.
pub fn config<T: Task>(agent: &AgentConfig) -> T::Config {
    let mut config = agent.task_table::<T>();
    if let Some(camera) = T::camera_mut(&mut config)
        && let Ok(path) = std::fs::canonicalize(&camera.segmenter)
    {
        camera.segmenter = path;
    }
    config
}

/// Prepares task `T` with `config`, on the map at `map` when the task drives on one.
pub fn setup<T: Task>(map: Option<&Path>, config: &T::Config) -> Result<Arc<T::Setup>> {
    let info = T::ID.info();
    let loaded = if info.needs_map {
        Some(Arc::new(required_map(map, info.name)?))
    } else {
        None
    };
    let observer = match (&loaded, T::camera_view(config)) {
        (Some(map), Some(camera)) => Some(camera_observer(map, camera)?),
        _ => None,
    };
    let map_path = map.filter(|_| info.needs_map);
    T::setup(loaded, config.clone(), observer).map_err(|e| setup_error::<T>(e, map_path))
}

/// A failed setup of task `T` (on the map at `map`) as a one-line error with the task's hint.
pub fn setup_error<T: Task>(e: SimError, map: Option<&Path>) -> anyhow::Error {
    let info = T::ID.info();
    let problem = format!("cannot set up {}: {e}", info.title);
    match map {
        Some(path) => CliError::file(path, problem, info.setup_hint),
        None => CliError::new(problem, info.setup_hint),
    }
    .into()
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

/// The observer of `view = "camera-segmentation"` on `map`: the camera renderer and the
/// segmenter of the `camera` table. A missing or invalid segmenter folder is one error
/// naming the file.
pub fn camera_observer(map: &Map, camera: &CameraViewConfig) -> Result<Arc<dyn SceneObserver>> {
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
    Ok(Arc::new(observer))
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::tasks::{ObstacleAvoidance, RingDriving, RoundaboutInsertion, route::RouteFollowing};

    /// Each task reads the table of its own name in `[agent]`.
    #[test]
    fn each_task_reads_its_own_table() {
        let mut config = AgentConfig::default();
        config.task.time_limit_s = 101.0;
        config.route.step_s = 0.102;
        config.roundabout_driving.episode_s = 103.0;
        config.obstacle.time_limit_s = 104.0;
        assert_eq!(
            config.task_table::<RoundaboutInsertion>().time_limit_s,
            101.0
        );
        assert_eq!(config.task_table::<RouteFollowing>().step_s, 0.102);
        assert_eq!(config.task_table::<RingDriving>().episode_s, 103.0);
        assert_eq!(config.task_table::<ObstacleAvoidance>().time_limit_s, 104.0);
    }
}
