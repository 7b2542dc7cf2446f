//! An agent folder, as `agent train` writes it and `agent eval`, `replay eval` and
//! `pipeline run` read it: the network (`models::dqn`), what it was trained on (`task.json`,
//! [`TaskRecord`]), and while it trains the checkpoints kept beside it in `DIR.partial`
//! (the newest, and with `[agent.validation]` the best so far and the validation history).
//! Reading and writing them, with one-line errors naming the file.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Result;
use maps::Map;
use models::ModelError;
use models::dqn::{AGENT_FILE, AgentDescription, Checkpoint, load_network, read_agent_description};
use models::policy::QPolicy;
use models::qnet::QNetwork;
use models::validation::{
    BEST_PREFIX, VALIDATION_FILE, Validation, ValidationConfig, ValidationHistory, ValidationRun,
    best_dir_name,
};
use serde::{Deserialize, Serialize};
use sim::ObservationSpec;
use sim::tasks::{InsertionConfig, InsertionSetup, RoundaboutInsertion};
use sim::world::TrafficLevel;

pub use sim::tasks::TaskId as Task;

use crate::error::CliError;
use crate::output::{Markers, write_json};

pub const TASK_FILE: &str = "task.json";
pub const SUMMARY_FILE: &str = "summary.json";

/// A folder holding any of these is an earlier agent that may be replaced.
pub const AGENT_MARKERS: Markers = &[AGENT_FILE, TASK_FILE];

/// One map `agent train` trained on, and the ring of it (None: the task's choice).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingMap {
    pub path: PathBuf,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roundabout: Option<u32>,
}

/// `task.json` of an agent folder: what it was trained on, so evaluation renders the same
/// observations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TaskRecord {
    pub task: Task,
    /// The map file as given to `agent train` (None for tasks on a synthetic road); the
    /// first of several.
    pub map: Option<PathBuf>,
    /// Every training map with its ring, when there were several or a ring was named.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub maps: Vec<TrainingMap>,
    pub traffic: TrafficLevel,
    /// The task's `[agent.<table>]` settings (see [`sim::tasks::Task::Config`]).
    pub config: serde_json::Value,
    /// How the agent was chosen among the run's checkpoints (absent: the final network).
    #[serde(default, skip_serializing_if = "ValidationConfig::is_off")]
    pub validation: ValidationConfig,
}

impl TaskRecord {
    /// The roundabout-insertion settings of an insertion agent.
    pub fn insertion_config(&self, file: &Path) -> Result<InsertionConfig> {
        if self.task != Task::RoundaboutInsertion {
            return Err(CliError::file(
                file,
                format!("is a {:?} agent, not a roundabout-insertion one", self.task),
                "give an agent trained with --task roundabout-insertion",
            )
            .into());
        }
        self.task_config::<RoundaboutInsertion>(file)
    }

    /// The settings of task `T` as stored in `file` (this record's).
    pub fn task_config<T: sim::tasks::Task>(&self, file: &Path) -> Result<T::Config> {
        serde_json::from_value(self.config.clone()).map_err(|e| {
            CliError::file(
                file,
                format!("the {:?} task's config is invalid: {e}", self.task),
                "give a folder written by `pipeline agent train` of this version",
            )
            .into()
        })
    }
}

pub fn read_task(dir: &Path) -> Result<TaskRecord> {
    let path = dir.join(TASK_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| {
        CliError::file(
            &path,
            format!("cannot read: {e}"),
            "give a folder written by `pipeline agent train`",
        )
    })?;
    Ok(serde_json::from_str(&text).map_err(|e| {
        CliError::file(
            &path,
            format!("invalid: {e}"),
            "give a folder written by `pipeline agent train`",
        )
    })?)
}

/// A models-crate error as a one-line CLI error.
pub fn models_error(e: ModelError, context: &Path) -> anyhow::Error {
    match e {
        ModelError::File { .. } => CliError::new(
            e.to_string(),
            "check the agent folder (written by `pipeline agent train`)",
        )
        .into(),
        ModelError::Config(_) => CliError::file(context, e, "check [agent.dqn] in --config").into(),
    }
}

/// The roundabout-insertion setup of `map` (its roundabouts' routes and rasters).
pub fn insertion_setup(
    map: Map,
    map_path: &Path,
    config: InsertionConfig,
) -> Result<Arc<InsertionSetup>> {
    InsertionSetup::new(Arc::new(map), config)
        .map_err(|e| crate::tasks::setup_error::<RoundaboutInsertion>(e, Some(map_path)))
}

/// An agent folder's network, description and task record.
#[derive(Debug)]
pub struct LoadedAgent {
    pub description: AgentDescription,
    pub task: TaskRecord,
    pub network: QNetwork,
}

impl LoadedAgent {
    pub fn load(dir: &Path) -> Result<LoadedAgent> {
        let description = read_agent_description(dir).map_err(|e| models_error(e, dir))?;
        let task = read_task(dir)?;
        let network = load_network(dir, &description, &models::cpu_device())
            .map_err(|e| models_error(e, dir))?;
        Ok(LoadedAgent {
            description,
            task,
            network,
        })
    }

    /// The greedy policy, once the task's observations are checked to be what the agent
    /// was trained on.
    pub fn policy(self, dir: &Path, spec: ObservationSpec) -> Result<QPolicy> {
        if spec != self.description.shape.spec() {
            return Err(CliError::file(
                dir,
                format!(
                    "was trained on observations {:?}, the task renders {spec:?}",
                    self.description.shape.spec()
                ),
                "evaluate with the task settings the agent was trained with (task.json)",
            )
            .into());
        }
        Ok(QPolicy::new(
            self.network,
            spec,
            self.description.shape.actions,
            models::cpu_device(),
        ))
    }
}

/// `DIR.partial` beside the agent folder `DIR`.
pub fn partial_dir(out: &Path) -> Result<PathBuf> {
    let name = out.file_name().ok_or_else(|| {
        CliError::file(
            out,
            "is not a folder name",
            "give --out a folder name such as runs/agent",
        )
    })?;
    Ok(out.with_file_name(format!("{}.partial", name.to_string_lossy())))
}

/// The checkpoint to resume from: the newest in `DIR.partial`, else the finished agent in
/// `DIR`; with its task record and the folder it came from.
pub fn find_checkpoint(out: &Path, partial: &Path) -> Result<(Checkpoint, TaskRecord, PathBuf)> {
    let candidates = [partial.join("checkpoint"), out.to_path_buf()];
    let Some(dir) = candidates.iter().find(|d| d.join(AGENT_FILE).is_file()) else {
        return Err(CliError::new(
            format!(
                "nothing to resume: neither {} nor {} holds a checkpoint",
                candidates[0].display(),
                out.display()
            ),
            "train without --resume first (checkpoints are written every checkpoint_every steps)",
        )
        .into());
    };
    let checkpoint =
        Checkpoint::load(dir, &models::cpu_device()).map_err(|e| models_error(e, dir))?;
    let task = read_task(dir)?;
    Ok((checkpoint, task, dir.join(TASK_FILE)))
}

/// Writes `checkpoint` and its task record into the folder `dest`, atomically.
pub fn write_checkpoint(dest: &Path, checkpoint: &Checkpoint, task: &TaskRecord) -> Result<()> {
    models::run_folder::replace_dir(dest, |dir| {
        checkpoint.save(dir)?;
        Ok::<_, ModelError>(models::run_folder::write_json(&dir.join(TASK_FILE), task)?)
    })
    .map_err(|e| models_error(e, dest))
}

/// Reads `validation.json` of `dir`, if there is one.
pub fn read_validation(dir: &Path) -> Result<Option<ValidationHistory>> {
    let path = dir.join(VALIDATION_FILE);
    if !path.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path)
        .map_err(|e| CliError::file(&path, format!("cannot read: {e}"), "check permissions"))?;
    let history = serde_json::from_str(&text).map_err(|e| {
        CliError::file(
            &path,
            format!("is not a validation history: {e}"),
            "remove the folder and train again without --resume",
        )
    })?;
    Ok(Some(history))
}

/// Validation of a new run, or of a run resumed from `resumed`: the history and best
/// checkpoint of the folder it was resumed from (`DIR.partial`, else the finished agent
/// `DIR`), without the points after the checkpoint it resumes from.
pub fn start_validation(
    config: ValidationConfig,
    run: ValidationRun,
    partial: &Path,
    out: &Path,
    resumed: Option<&Checkpoint>,
) -> Result<Validation> {
    let Some(resumed) = resumed else {
        return Ok(Validation::new(config, run));
    };
    let found = match read_validation(partial)? {
        Some(history) => Some((history, partial)),
        None => read_validation(out)?.map(|h| (h, out)),
    };
    let Some((mut history, dir)) = found else {
        return Ok(Validation::new(config, run));
    };
    history.truncate(resumed.state.steps);
    let best = match history.best_steps {
        Some(steps) if steps == resumed.state.steps => Some(resumed.clone()),
        Some(steps) => {
            let best_dir = dir.join(best_dir_name(steps));
            if best_dir.is_dir() {
                Some(
                    Checkpoint::load(&best_dir, &models::cpu_device())
                        .map_err(|e| models_error(e, &best_dir))?,
                )
            } else {
                None
            }
        }
        None => None,
    };
    Ok(Validation::resumed(config, run, history, best))
}

/// Writes the best checkpoint (when new) and the history into `partial`; call
/// [`prune_validation`] once the run's own checkpoint is written.
pub fn save_validation(validation: &Validation, partial: &Path, task: &TaskRecord) -> Result<()> {
    if let Some(best) = validation.best() {
        let dest = partial.join(best_dir_name(best.state.steps));
        if !dest.exists() {
            write_checkpoint(&dest, best, task)?;
        }
    }
    write_json(&partial.join(VALIDATION_FILE), &validation.history)
}

/// Removes the best checkpoints of `partial` other than the current one. (Until the run's
/// checkpoint is written, a resume may still need the earlier one.)
pub fn prune_validation(validation: &Validation, partial: &Path) -> Result<()> {
    let keep = validation.history.best_steps.map(best_dir_name);
    models::run_folder::prune(partial, BEST_PREFIX, keep.as_deref())
        .map_err(|e| CliError::new(format!("cannot remove: {e}"), "check permissions").into())
}
