//! The driving tasks ([`sim::tasks::registry`]) from the command line: a task's settings
//! from the `--config` file, and its setup from a map path (the map loaded or imported, the
//! camera view's segmenter loaded), with one-line errors.

use std::any::Any;
use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use maps::Map;
use serde::{Deserialize, Serialize};
use sim::SimError;
use sim::observer::{CameraViewConfig, SceneObserver};
use sim::tasks::insertion::InsertionConfig;
use sim::tasks::{Task, TaskVisitor};

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
    fn task_tables(&self) -> [&dyn Any; 4] {
        [
            &self.task,
            &self.route,
            &self.roundabout_driving,
            &self.obstacle,
        ]
    }

    /// The tables of the tasks' settings, to change in place.
    fn task_tables_mut(&mut self) -> [&mut dyn Any; 4] {
        [
            &mut self.task,
            &mut self.route,
            &mut self.roundabout_driving,
            &mut self.obstacle,
        ]
    }

    /// The settings table of task `T` (the table of its config type).
    pub fn task_table<T: Task>(&self) -> T::Config {
        self.task_tables()
            .into_iter()
            .find_map(|table| table.downcast_ref::<T::Config>())
            .cloned()
            .unwrap_or_default()
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
        for table in self.agent.task_tables_mut() {
            if let Some(config) = table.downcast_mut::<T::Config>()
                && let Some(changed) = T::in_world(config, self.world)
            {
                *config = changed;
            }
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
    use sim::tasks::{TaskId, TaskVisitor};

    struct HasTable<'a>(&'a AgentConfig);

    impl TaskVisitor for HasTable<'_> {
        type Output = bool;
        fn visit<T: Task>(self) -> bool {
            self.0
                .task_tables()
                .into_iter()
                .any(|table| table.is::<T::Config>())
        }
    }

    #[test]
    fn every_task_has_its_settings_table() {
        let config = AgentConfig::default();
        for id in TaskId::ALL {
            assert!(id.visit(HasTable(&config)), "{id:?}");
        }
    }
}
