//! The driving tasks ([`sim::tasks::registry`]) from the command line: a task's settings
//! from the `--config` file, and its setup from a map path (the map loaded or imported, the
//! camera view's segmenter loaded), with one-line errors.

use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use maps::Map;
use sim::SimError;
use sim::observer::{CameraViewConfig, SceneObserver};
use sim::tasks::Task;

use crate::commands::agent::AgentConfig;
use crate::error::CliError;
use crate::inputs::load_or_import_map;

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
