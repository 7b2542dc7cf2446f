//! `pipeline replay eval | merge`: policies judged against what real drivers did at
//! roundabout entries (open loop, and closed loop among the replayed traffic), and the shards
//! of one evaluation added up. The judging is `judge`'s; these commands read the
//! inputs, call it and write `replay.json`, `replay.md` and the recording.
//!
//! With `--shard i/n` only shard `i`'s share of the approaches (numbered over the logs in
//! the order given) is evaluated, and the folder holds `replay_shard.json`: the settings
//! and the counts (frames, confusion matrices, matches per log, go delays in approach
//! order), which `pipeline replay merge --shards` adds up into the unsharded run's
//! `replay.json` and `replay.md`.

mod eval;
mod gaps;
mod merge;

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::{Args, Subcommand};
use datasets::shard::Shard;
use judge::{REPLAY_JSON, REPLAY_MD, REPLAY_SHARD_JSON, Report, markdown};

use super::Context;
use crate::error::CliError;
use crate::output::{AtomicDir, Markers, write_file_atomic, write_json};

const MARKERS: Markers = &[REPLAY_JSON, REPLAY_SHARD_JSON];

#[derive(Debug, Subcommand)]
pub enum ReplayCommand {
    /// Agreement of policies (an agent, the gap rules, always go) with real drivers' go /
    /// wait decisions at roundabout entries, frame by frame.
    Eval(EvalArgs),
    /// Gap acceptance at roundabout entries: every gap offered to a recorded driver (the
    /// drivers of `replay eval`'s approaches) and whether it entered, with the critical gap
    /// fitted on --train-log recordings, and the
    /// policies (critical-gap rules, distance rules, behaviour cloning, an agent) scored on
    /// each gap: gaps.json, gaps.md, gaps.csv.
    Gaps(GapsArgs),
    /// Add up the shards of one `replay eval --shard i/n` run into its replay.json and
    /// replay.md (the unsharded run's, byte for byte).
    Merge(MergeArgs),
}

#[derive(Debug, Args)]
pub struct GapsArgs {
    /// The recordings to score, their map and roundabout.
    #[command(flatten)]
    pub recordings: crate::recordings::Recordings,

    /// Recordings to fit the critical gaps and behaviour cloning on (never a scored one);
    /// repeat for several. Without them only the distance rules and always accept are
    /// scored, and the critical gap reported describes the scored recordings.
    #[arg(long = "train-log", value_name = "FILE")]
    pub train_logs: Vec<PathBuf>,

    /// The map the --train-log recordings were made on, when it is not --map (policies
    /// fitted at one roundabout scored at another).
    #[arg(long, value_name = "PATH")]
    pub train_map: Option<PathBuf>,

    /// An agent folder (`agent train`) to score beside the rules.
    #[arg(long, value_name = "DIR")]
    pub agent: Option<PathBuf>,

    /// The agent's aggressiveness input.
    #[arg(long, value_name = "A", default_value_t = 0.5)]
    pub aggressiveness: f64,

    /// The route's nominal speed the agent is told, m/s.
    #[arg(long, value_name = "MPS", default_value_t = 8.0)]
    pub target_speed: f64,

    /// Output folder.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

#[derive(Debug, Args)]
pub struct MergeArgs {
    /// The shard folders of one `replay eval --shard i/n` run, each of 0..n once (any
    /// order).
    #[arg(long, value_name = "DIR", num_args = 1.., required = true)]
    pub shards: Vec<PathBuf>,

    /// Output folder: replay.json and replay.md (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Logs to replay (MCAP from `logs convert`, or any log with object detections).
    #[arg(long = "log", value_name = "FILE", required = true)]
    pub logs: Vec<PathBuf>,

    /// The map the logs were recorded on (a Lanelet2 .osm, or a map folder).
    #[arg(long, value_name = "MAP|OSM")]
    pub map: PathBuf,

    /// An agent folder from `agent train` [default: only the baselines].
    #[arg(long, value_name = "DIR")]
    pub agent: Option<PathBuf>,

    /// The agent's aggressiveness input, one evaluation per level.
    #[arg(long, value_name = "A,B,...", value_delimiter = ',', default_values_t = [0.0, 0.5, 1.0], allow_hyphen_values = true)]
    pub aggressiveness: Vec<f64>,

    /// The target speed the agent is told (the simulator gives the route's speed), m/s.
    #[arg(long, value_name = "MPS", default_value_t = 8.0)]
    pub target_speed: f64,

    /// Logs to train a behaviour-cloning classifier of go / wait on (the same inputs as
    /// the agent), evaluated beside the other policies; use other recordings than --log.
    #[arg(long = "train-log", value_name = "FILE")]
    pub train_logs: Vec<PathBuf>,

    /// Behaviour cloning learns from every N-th go or wait frame of an approach.
    #[arg(long, value_name = "N", default_value_t = 2)]
    pub bc_stride: usize,

    /// Output folder: replay.json and replay.md (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Evaluate only shard i of n of the approaches (for running across machines); the
    /// folder gets replay_shard.json, which `pipeline replay merge --shards` adds up
    /// (docs/scaling.md). Each shard trains behaviour cloning itself (the same network).
    #[arg(long, value_name = "i/n", value_parser = Shard::parse)]
    pub shard: Option<Shard>,

    /// Also closed loop: each policy drives each approach's vehicle along its driver's path
    /// while the other road users replay the log (reaches, crashes, time-overs, log
    /// divergence).
    #[arg(long)]
    pub closed_loop: bool,
}

pub fn run(ctx: &Context<'_>, command: &ReplayCommand) -> Result<()> {
    match command {
        ReplayCommand::Eval(args) => eval::run(ctx, args),
        ReplayCommand::Gaps(args) => gaps::run(ctx, args),
        ReplayCommand::Merge(args) => merge::run(ctx, args),
    }
}

/// Writes replay.json, replay.md and the recording (the table) into `out`, atomically.
fn write_report(ctx: &Context<'_>, out: &Path, report: &Report) -> Result<()> {
    let md = markdown(report);
    let dir = AtomicDir::create(out, MARKERS)?;
    write_json(&dir.path().join(REPLAY_JSON), report)?;
    write_file_atomic(&dir.path().join(REPLAY_MD), md.as_bytes())?;
    let recording = ctx.open_recording(Some(dir.path()))?;
    if let Some(rec) = recording.stream() {
        rec.log_static(
            "replay/table",
            &rerun::TextDocument::from_markdown(md.clone()),
        )
        .map_err(|e| {
            CliError::new(
                format!("rerun: cannot log the table: {e}"),
                "use --rerun off",
            )
        })?;
    }
    recording.finish()?;
    let dest = dir.commit()?;
    ctx.ui.result(&md);
    ctx.ui.info(&format!("wrote {}", dest.display()));
    Ok(())
}
