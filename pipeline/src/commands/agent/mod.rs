//! `pipeline agent train | eval`: DQN-family agents on the driving tasks.
//!
//! ```text
//! pipeline agent train --task TASK [--map MAP] --out DIR [--steps N] [--traffic LEVEL] [--resume]
//! pipeline agent eval  --agent DIR --map MAP [--episodes N] [--out DIR]
//! ```
//!
//! `MAP` is a map folder or file written by `pipeline map import`, or an OSM / Lanelet2
//! file imported on the fly with the default car profile. `TASK` is a task of the registry
//! ([`sim::tasks::registry`]). The hyper-parameters come from the `[agent.dqn]` table of
//! `--config` (see [`models::dqn::DqnConfig`]); the task's from its table of [`AgentConfig`].

mod eval;
mod offline;
mod train;
mod train_inputs;

use std::path::PathBuf;

use anyhow::Result;
use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::{Args, Subcommand, ValueEnum};

use sim::tasks::TaskId;
use sim::world::TrafficLevel;

use super::Context;

pub fn run(ctx: &Context<'_>, command: &AgentCommand) -> Result<()> {
    match command {
        AgentCommand::Train(args) if args.offline => offline::train(ctx, args),
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

/// `--task`: a task of the registry, by name, its description for `--help`.
fn task_parser() -> impl TypedValueParser<Value = TaskId> {
    let names = sim::tasks::TASKS
        .iter()
        .map(|info| PossibleValue::new(info.name).help(info.description));
    PossibleValuesParser::new(names).try_map(|name| TaskId::from_name(&name).ok_or("unknown task"))
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TrafficArg {
    Low,
    Medium,
    High,
    /// The recordings' own flows per entry (`[recorded]` of a calibration given with
    /// --config, on the recordings' map).
    Recorded,
}

impl From<TrafficArg> for TrafficLevel {
    fn from(t: TrafficArg) -> Self {
        match t {
            TrafficArg::Low => TrafficLevel::Low,
            TrafficArg::Medium => TrafficLevel::Medium,
            TrafficArg::High => TrafficLevel::High,
            TrafficArg::Recorded => TrafficLevel::Recorded,
        }
    }
}

#[derive(Debug, Args)]
pub struct TrainArgs {
    #[arg(long, value_parser = task_parser(), default_value = "roundabout-insertion")]
    pub task: TaskId,

    /// The map: a folder or file from `pipeline map import`, or an OSM / Lanelet2 file
    /// (required by the tasks that drive on a map). Repeat to train on several: each
    /// episode is drawn on one of them.
    #[arg(long, value_name = "PATH")]
    pub map: Vec<PathBuf>,

    /// A file listing training maps, one per line: `PATH [ROUNDABOUT]` (a roundabout id, as
    /// `map info` lists them, to train on that ring of the map), `#` comments; relative
    /// paths are from the file's folder. Added to --map.
    #[arg(long, value_name = "FILE")]
    pub maps: Option<PathBuf>,

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
    /// Roundabout tasks only: evaluate on this roundabout of the map (its id, as `map info`
    /// and `summary.json` list them) instead of the one(s) the agent was trained on.
    #[arg(long, value_name = "ID")]
    pub roundabout: Option<u32>,
}

pub use crate::tasks::AgentConfig;
