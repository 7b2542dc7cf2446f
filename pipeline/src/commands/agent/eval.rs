//! `pipeline agent eval`: an agent and its task's baselines on the same episodes of every
//! condition of the task (traffic level × the ego's aggressiveness for roundabout
//! insertion; traffic levels, route splits or obstacle scenarios for the others), with the
//! sim crate's parallel evaluation harness ([`sim::eval`]). Writes `eval.json` (fractions of
//! reaches, crashes, off-roads and time-overs and the task's metrics per condition and
//! policy), `eval.md` (the tables), the task's other files (for roundabout insertion
//! `episodes.csv`, every episode's outcome per policy and condition) and `recording.rrd`.

use std::path::{Path, PathBuf};

use anyhow::Result;
use sim::Outcome;
use sim::eval::{EvalHeader, EvalOptions, EvalReport, Evaluation, evaluate_agent};
use sim::tasks::{ConditionChoice, Task, TaskSummary, TaskVisitor};

use super::EvalArgs;
use crate::agent_folder::{LoadedAgent, TASK_FILE};
use crate::agent_recording::record_episodes;
use crate::commands::Context;
use crate::error::CliError;
use crate::output::{AtomicDir, Markers, write_file_atomic};
use crate::plots::PolicyOutcomes;
use crate::recording::Stream;
use crate::ui::Progress;

pub const EVAL_JSON: &str = "eval.json";
/// The evaluation's picture: outcome shares of the agent and each baseline.
pub const EVAL_PNG: &str = "eval.png";
pub const EVAL_MD: &str = "eval.md";
const EVAL_MARKERS: Markers = &[EVAL_JSON];

/// Episodes a Q-network policy runs side by side (one batched forward pass per step).
const AGENT_LOCKSTEP: usize = 32;

pub fn eval(ctx: &Context<'_>, args: &EvalArgs) -> Result<()> {
    if args.episodes == 0 {
        return Err(CliError::new("--episodes must be positive", "e.g. --episodes 1000").into());
    }
    let mut progress = ctx.ui.progress("agent eval");
    progress.step(&format!("loading the agent {}", args.agent.display()));
    let agent = LoadedAgent::load(&args.agent)?;
    let map = args.map.clone().or_else(|| agent.task.map.clone());
    if let Some(map) = &map {
        progress.step(&format!("loading {}", map.display()));
    }
    agent.task.task.visit(Eval {
        ctx,
        args,
        agent,
        map,
        progress,
    })
}

/// Evaluates an agent of the task its folder names.
struct Eval<'a, 'b> {
    ctx: &'a Context<'b>,
    args: &'a EvalArgs,
    agent: LoadedAgent,
    map: Option<PathBuf>,
    progress: Progress<'b>,
}

impl TaskVisitor for Eval<'_, '_> {
    type Output = Result<()>;

    fn visit<T: Task>(self) -> Result<()> {
        eval_task::<T>(self)
    }
}

/// Evaluates an agent of task `T` and its baselines on every condition asked for.
fn eval_task<T: Task>(run: Eval<'_, '_>) -> Result<()> {
    let Eval {
        ctx,
        args,
        agent,
        map,
        mut progress,
    } = run;
    let task = agent.task.clone();
    if T::ID.info().uses_aggressiveness
        && let Some(a) = args
            .aggressiveness
            .iter()
            .find(|a| !(0.0..=1.0).contains(*a))
    {
        return Err(CliError::new(
            format!("--aggressiveness {a} is outside [0, 1]"),
            "e.g. --aggressiveness 0,0.5,1",
        )
        .into());
    }
    let mut config = task.task_config::<T>(&args.agent.join(TASK_FILE))?;
    if let Some(steps) = args.action_repeat {
        config = T::deciding_every(&config, steps).ok_or_else(|| {
            CliError::new(
                format!(
                    "--action-repeat is for roundabout-insertion agents; this one is {}",
                    task.task.name()
                ),
                "leave --action-repeat out",
            )
        })?;
    }
    if let Some(id) = args.roundabout {
        config = T::on_roundabout(&config, id).ok_or_else(|| {
            CliError::new(
                format!(
                    "--roundabout is for roundabout tasks; this agent's task is {}",
                    task.task.name()
                ),
                "leave --roundabout out",
            )
        })?;
    }
    let world = ctx.config.world();
    if !world.is_empty() {
        // A calibration given with --config: the agent is judged in that world.
        if let Some(c) = T::in_world(&config, &world) {
            progress.note("in the traffic world of --config ([traffic], [recorded], [layout])");
            config = c;
        }
    }
    if args.traffic.contains(&super::TrafficArg::Recorded) {
        require_recorded(ctx, map.as_deref())?;
    }
    let setup = crate::tasks::setup::<T>(map.as_deref(), &config)?;
    let choice = ConditionChoice {
        traffic: args.traffic.iter().map(|&t| t.into()).collect(),
        aggressiveness: args.aggressiveness.clone(),
    };
    let conditions = T::conditions(&choice);
    let recorded = T::recorded_eval_condition(&conditions);
    let spec = T::env(&setup, &recorded).observation_spec();
    let policy = agent.policy(&args.agent, spec)?;
    let out = output_dir(ctx, args, map.as_deref(), task.task.name());
    AtomicDir::check_destination(&out, EVAL_MARKERS)?;

    let options = EvalOptions {
        episodes: args.episodes,
        seed: ctx.global.seed,
        lockstep: AGENT_LOCKSTEP,
    };
    let baselines = !args.no_baselines;
    let step = &mut |s: &str| progress.step(s);
    let evaluation = evaluate_agent::<T, _>(&setup, &policy, conditions, &options, baselines, step);
    let header = EvalHeader {
        agent: args.agent.clone(),
        task: task.task,
        map: map.clone(),
        trained_on: task.map.clone(),
        roundabouts: T::roundabouts(&setup),
        episodes: args.episodes,
        seed: ctx.global.seed,
    };
    let picture = eval_png(&evaluation, task.task.name())?;
    let report = T::eval_report(&header, &evaluation).map_err(|e| {
        CliError::new(
            format!("cannot tabulate the evaluation: {e}"),
            "report the bug",
        )
    })?;

    write_outputs(ctx, args, &out, (&report, &picture), progress, |rec| {
        crate::recording::log_map(rec, T::map(&setup))?;
        let make_env = || T::env(&setup, &recorded);
        record_episodes(
            rec,
            make_env,
            &policy,
            args.record_episodes,
            ctx.global.seed,
        )
    })
}

/// `eval.png`: the share of episodes each policy reached, crashed in and ran out of time
/// in, over every condition evaluated.
fn eval_png<C, S: TaskSummary>(evaluation: &Evaluation<C, S>, task: &str) -> Result<Vec<u8>> {
    let outcomes: Vec<PolicyOutcomes> = evaluation
        .policies
        .iter()
        .map(|(name, per_condition)| {
            let episodes: Vec<_> = per_condition.iter().flatten().collect();
            let n = episodes.len().max(1) as f64;
            let share =
                |o: Outcome| episodes.iter().filter(|s| s.outcome() == o).count() as f64 / n;
            PolicyOutcomes {
                name: name.clone(),
                reach: share(Outcome::Reached),
                crash: share(Outcome::Crashed),
                time_over: share(Outcome::TimeOver),
            }
        })
        .collect();
    crate::plots::agent_eval_png(&format!("{task}: the agent and its baselines"), &outcomes)
}

/// The output folder: --out, else `AGENT/eval/<map name>` (or `<task>` without a map).
fn output_dir(ctx: &Context<'_>, args: &EvalArgs, map: Option<&Path>, task: &str) -> PathBuf {
    match (&args.out, map) {
        (Some(out), _) => ctx.output_path(out),
        (None, Some(map)) => args.agent.join("eval").join(map_name(map)),
        (None, None) => args.agent.join("eval").join(task),
    }
}

/// Writes `eval.json`, `eval.md`, the report's other files and the recording (the greedy
/// episodes `record` logs, when `--record-episodes` asks for any) into `out`, atomically,
/// and prints the tables.
fn write_outputs(
    ctx: &Context<'_>,
    args: &EvalArgs,
    out: &Path,
    (report, picture): (&EvalReport, &[u8]),
    mut progress: Progress<'_>,
    record: impl FnOnce(&Stream) -> Result<()>,
) -> Result<()> {
    let dir = AtomicDir::create(out, EVAL_MARKERS)?;
    write_file_atomic(
        &dir.path().join(EVAL_JSON),
        format!("{}\n", report.json).as_bytes(),
    )?;
    write_file_atomic(&dir.path().join(EVAL_MD), report.markdown.as_bytes())?;
    for (name, contents) in &report.extra {
        write_file_atomic(&dir.path().join(name), contents.as_bytes())?;
    }
    write_file_atomic(&dir.path().join(EVAL_PNG), picture)?;
    let recording = ctx.open_recording(Some(dir.path()))?;
    if let Some(rec) = recording.stream()
        && args.record_episodes > 0
    {
        progress.step("recording greedy episodes");
        record(rec)?;
    }
    recording.finish()?;
    let dest = dir.commit()?;
    drop(progress);
    ctx.ui.result(&format!(
        "{}\nwritten to {}",
        report.markdown,
        dest.display()
    ));
    Ok(())
}

/// A folder name for a map path: its file name without the map extensions.
fn map_name(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "map".into());
    let stem = [".osm.pbf", ".osm.gz", ".osm", ".pbf", ".json", ".bin"]
        .iter()
        .find_map(|ext| name.strip_suffix(ext))
        .unwrap_or(&name);
    if stem == "map" {
        path.parent()
            .and_then(|p| p.file_name())
            .map_or_else(|| "map".to_owned(), |n| n.to_string_lossy().into_owned())
    } else {
        stem.to_owned()
    }
}

/// `--traffic recorded` needs the recordings' flows (`[recorded]` of a calibration), on the
/// entries of the map they were recorded on (`map`, when the task runs on one).
pub(crate) fn require_recorded(ctx: &Context<'_>, map: Option<&std::path::Path>) -> Result<()> {
    let Some(recorded) = &ctx.config.recorded else {
        return Err(CliError::new(
            "--traffic recorded needs the recordings' flows, and the config has no [recorded] table",
            "give the calibration `pipeline sim calibrate` wrote (--config FILE), on its map",
        )
        .into());
    };
    let Some(path) = map else { return Ok(()) };
    let loaded = crate::inputs::load_or_import_map(path)?;
    let layout = ctx.config.layout.unwrap_or_default();
    let traffic = sim::world::TrafficConfig {
        flows: recorded.flows.clone(),
        ..Default::default()
    };
    sim::roundabout::RoundaboutLayout::new(
        &loaded,
        maps::RoundaboutId(recorded.roundabout),
        &layout,
    )
    .map_err(|e| e.to_string())
    .and_then(|l| traffic.check_flows(&l))
    .map_err(|e| {
        CliError::file(
            path,
            format!("the recorded flows of --config do not fit this map: {e}"),
            "--traffic recorded runs on the map the calibration's recordings were made on",
        )
    })?;
    Ok(())
}
