//! `pipeline agent train | eval`: DQN-family agents on the driving tasks.
//!
//! ```text
//! pipeline agent train --task roundabout-insertion|roundabout-driving --map MAP --out DIR [--steps N] [--traffic LEVEL] [--resume]
//! pipeline agent eval  --agent DIR --map MAP [--episodes N] [--out DIR]
//! ```
//!
//! `MAP` is a map folder or file written by `pipeline map import`, or an OSM / Lanelet2
//! file imported on the fly with the default car profile. The hyper-parameters come from
//! the `[agent.dqn]` table of `--config` (see [`models::dqn::DqnConfig`]); the task's from
//! `[agent.task]` for insertion (see [`sim::tasks::InsertionConfig`]) and
//! `[agent.roundabout_driving]` for roundabout driving (see [`sim::tasks::RingDrivingConfig`]).

mod episodes;
mod eval;
mod offline;
pub mod tasks;
pub(crate) mod train;
pub mod validation;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Result;
use clap::{Args, Subcommand, ValueEnum};
use maps::Map;
use serde::{Deserialize, Serialize};
use sim::tasks::{InsertionConfig, InsertionSetup};
use sim::world::TrafficLevel;

use super::Context;
use crate::error::CliError;

pub fn run(ctx: &Context<'_>, command: &AgentCommand) -> Result<()> {
    match command {
        AgentCommand::Train(args) => train::train(ctx, args),
        AgentCommand::Eval(args) => eval::eval(ctx, args),
    }
}

#[derive(Debug, Subcommand)]
pub enum AgentCommand {
    /// Train a DQN / Double DQN agent on a task (checkpoints as it goes; --resume after a kill).
    Train(TrainArgs),
    /// Evaluate an agent next to the baselines: eval.json and a markdown table per condition.
    Eval(EvalArgs),
}

/// The tasks agents learn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Task {
    /// Enter a roundabout from a yield line through circulating traffic (the Parma study).
    RoundaboutInsertion,
    /// Follow a planned route over an imported campus, keeping in lane among other traffic
    /// (the AIT / MTSU studies).
    RouteFollowing,
    /// Steer along a route through a roundabout for 10 s (the ITS study).
    RoundaboutDriving,
    /// Pass a parked vehicle or yield to a crossing one on a straight synthetic road (the
    /// Thai CARLA study); needs no map.
    ObstacleAvoidance,
}

impl Task {
    /// The `--task` value.
    pub fn name(self) -> String {
        self.to_possible_value()
            .map_or_else(|| format!("{self:?}"), |v| v.get_name().to_owned())
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TrafficArg {
    Low,
    Medium,
    High,
}

impl From<TrafficArg> for TrafficLevel {
    fn from(t: TrafficArg) -> Self {
        match t {
            TrafficArg::Low => TrafficLevel::Low,
            TrafficArg::Medium => TrafficLevel::Medium,
            TrafficArg::High => TrafficLevel::High,
        }
    }
}

#[derive(Debug, Args)]
pub struct TrainArgs {
    #[arg(long, value_enum, default_value = "roundabout-insertion")]
    pub task: Task,

    /// The map: a folder or file from `pipeline map import`, or an OSM / Lanelet2 file
    /// (required by the tasks that drive on a map).
    #[arg(long, value_name = "PATH")]
    pub map: Option<PathBuf>,

    /// Agent folder (written atomically at the end; checkpoints go to DIR.partial meanwhile).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Environment transitions to train for [default: total_steps of [agent.dqn]].
    #[arg(long, value_name = "N")]
    pub steps: Option<u64>,

    /// Traffic level of the training episodes.
    #[arg(long, value_enum, default_value = "medium")]
    pub traffic: TrafficArg,

    /// Continue from the last checkpoint in DIR.partial (or from a finished agent in DIR,
    /// e.g. with a larger --steps), with the config it was started with.
    #[arg(long)]
    pub resume: bool,

    /// Greedy episodes of the finished agent logged to the rerun recording.
    #[arg(long, value_name = "N", default_value_t = 2)]
    pub record_episodes: usize,

    /// Learn from recorded drivers instead of the simulator (roundabout insertion): the
    /// go / wait decisions of every vehicle approaching the map's roundabout in the --log
    /// files, with discrete CQL or behaviour cloning ([agent.offline]); --steps counts
    /// gradient steps.
    #[arg(long, requires = "logs")]
    pub offline: bool,

    /// A log to learn from with --offline (MCAP from `logs convert`, or any log with object
    /// detections); repeat for several.
    #[arg(long = "log", value_name = "FILE", requires = "offline")]
    pub logs: Vec<PathBuf>,

    /// The offline algorithm [default: algorithm of [agent.offline], cql].
    #[arg(long, value_enum, requires = "offline")]
    pub algorithm: Option<OfflineAlgorithmArg>,

    /// With --offline: the target speed the drivers are told in the inputs (as
    /// `replay eval --target-speed`), m/s.
    #[arg(long, value_name = "MPS", default_value_t = 8.0)]
    pub target_speed: f64,
}

/// `--algorithm` of `agent train --offline`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum OfflineAlgorithmArg {
    /// Discrete conservative Q-learning (TD loss + α · (logsumexp Q − Q of the driver's action)).
    Cql,
    /// Behaviour cloning: the Q-network as a classifier of the driver's action.
    Bc,
}

impl From<OfflineAlgorithmArg> for models::offline::OfflineAlgorithm {
    fn from(a: OfflineAlgorithmArg) -> Self {
        match a {
            OfflineAlgorithmArg::Cql => models::offline::OfflineAlgorithm::Cql,
            OfflineAlgorithmArg::Bc => models::offline::OfflineAlgorithm::BehaviourCloning,
        }
    }
}

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// An agent folder written by `pipeline agent train`.
    #[arg(long, value_name = "DIR")]
    pub agent: PathBuf,

    /// The map (need not be the one the agent was trained on) [default: the training map].
    #[arg(long, value_name = "PATH")]
    pub map: Option<PathBuf>,

    /// Episodes per condition and policy.
    #[arg(long, value_name = "N", default_value_t = 1000)]
    pub episodes: usize,

    /// Traffic levels [default: low, medium, high].
    #[arg(long, value_enum, value_delimiter = ',')]
    pub traffic: Vec<TrafficArg>,

    /// The ego's aggressiveness values [default: 0, 0.5, 1].
    #[arg(long, value_name = "A,B,...", value_delimiter = ',')]
    pub aggressiveness: Vec<f64>,

    /// Leave out the baselines (rules at 25 / 20 / 15 / 10 m, always Permitted, random,
    /// always Not Permitted).
    #[arg(long)]
    pub no_baselines: bool,

    /// Output folder [default: AGENT/eval/<map name>].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// Greedy episodes logged to the rerun recording (medium traffic, aggressiveness 0.5).
    #[arg(long, value_name = "N", default_value_t = 2)]
    pub record_episodes: usize,

    /// Roundabout insertion only: the agent decides every N world steps instead of the
    /// `action_repeat` it was trained with, on frames stacked as far apart as in training
    /// (`frame_steps`). 1 re-decides every 0.1 s; the baselines decide every N steps too.
    #[arg(long, value_name = "N")]
    pub action_repeat: Option<usize>,
}

/// `[agent]` of the `--config` file.
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
    pub validation: validation::ValidationConfig,
}

/// `task.json` of an agent folder: what it was trained on, so evaluation renders the same
/// observations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TaskRecord {
    pub task: Task,
    /// The map file as given to `agent train` (None for tasks on a synthetic road).
    pub map: Option<PathBuf>,
    pub traffic: TrafficLevel,
    /// The task's `[agent.<table>]` settings (see [`tasks::TaskKind::Config`]).
    pub config: serde_json::Value,
    /// How the agent was chosen among the run's checkpoints (absent: the final network).
    #[serde(default, skip_serializing_if = "validation::ValidationConfig::is_off")]
    pub validation: validation::ValidationConfig,
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
        tasks::task_config::<tasks::Insertion>(self, file)
    }
}

pub const TASK_FILE: &str = "task.json";

/// The roundabout-insertion setup of `map` (its roundabouts' routes and rasters).
pub fn insertion_setup(
    map: Map,
    map_path: &Path,
    config: InsertionConfig,
) -> Result<Arc<InsertionSetup>> {
    InsertionSetup::new(Arc::new(map), config).map_err(|e| {
        CliError::file(
            map_path,
            format!("cannot set up roundabout insertion: {e}"),
            "the map needs a roundabout with an entry, a ring and an exit (`pipeline map info` lists them); \
             check [agent.task] in --config",
        )
        .into()
    })
}
