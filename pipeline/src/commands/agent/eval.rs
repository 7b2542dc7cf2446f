//! `pipeline agent eval`: an agent and the baselines on the same episodes of every
//! condition (traffic level × the ego's aggressiveness), with the sim crate's parallel
//! evaluation harness. Writes `eval.json` (fractions of reaches, crashes, off-roads and
//! time-overs per condition and policy), `eval.md` (the table) and `recording.rrd`; for
//! roundabout insertion also `episodes.csv`, every episode's outcome per policy and condition,
//! so two policies can be compared episode by episode.

use std::path::{Path, PathBuf};

use anyhow::Result;
use models::dqn::{AgentDescription, load_network, read_agent_description};
use models::policy::QPolicy;
use models::qnet::QNetwork;
use serde::Serialize;
use sim::baselines::Baseline;
use sim::eval::{
    Condition, ConditionResult, EVAL_STAGE, EvalOptions, evaluate_episodes, markdown_table,
    summarise_conditions,
};
use sim::seed::derive_seed;
use sim::tasks::insertion::EpisodeSummary;
use sim::tasks::{Task as _, TaskResult, run_episodes, task_table};
use sim::world::TrafficLevel;
use sim::{Env as _, ObservationSpec};

use super::tasks::{GenericTask, Insertion, Obstacle, RoundaboutDriving, Route, TaskKind};
use super::train::{models_error, read_task};
use super::{EvalArgs, Task, TaskRecord, episodes};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::write_json;
use crate::output::{AtomicDir, Markers, write_file_atomic};
use crate::recording::Stream;
use crate::ui::Progress;

pub const EVAL_JSON: &str = "eval.json";
pub const EVAL_MD: &str = "eval.md";
pub const EPISODES_CSV: &str = "episodes.csv";
const EVAL_MARKERS: Markers = &[EVAL_JSON];

/// Episodes a Q-network policy runs side by side (one batched forward pass per step).
const AGENT_LOCKSTEP: usize = 32;

/// `eval.json`.
#[derive(Debug, Serialize)]
struct EvalReport {
    agent: PathBuf,
    map: PathBuf,
    /// The map the agent was trained on.
    trained_on: PathBuf,
    episodes: usize,
    seed: u64,
    conditions: Vec<ConditionReport>,
}

#[derive(Debug, Serialize)]
struct ConditionReport {
    traffic: TrafficLevel,
    aggressiveness: f64,
    /// The agent first, then the baselines, each on the same episodes.
    policies: Vec<PolicyResult>,
}

#[derive(Debug, Serialize)]
struct PolicyResult {
    policy: String,
    #[serde(flatten)]
    result: ConditionResult,
}

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
    match agent.task.task {
        Task::RoundaboutInsertion => eval_insertion(ctx, args, agent, map, progress),
        Task::RouteFollowing => eval_task::<Route>(ctx, args, agent, map, progress),
        Task::RoundaboutDriving => eval_task::<RoundaboutDriving>(ctx, args, agent, map, progress),
        Task::ObstacleAvoidance => eval_task::<Obstacle>(ctx, args, agent, map, progress),
    }
}

/// An agent folder's network, description and task record.
struct LoadedAgent {
    description: AgentDescription,
    task: TaskRecord,
    network: QNetwork,
}

impl LoadedAgent {
    fn load(dir: &Path) -> Result<LoadedAgent> {
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
    fn policy(self, dir: &Path, spec: ObservationSpec) -> Result<QPolicy> {
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

/// The output folder: --out, else `AGENT/eval/<map name>` (or `<task>` without a map).
fn output_dir(ctx: &Context<'_>, args: &EvalArgs, map: Option<&Path>, task: Task) -> PathBuf {
    match (&args.out, map) {
        (Some(out), _) => ctx.output_path(out),
        (None, Some(map)) => args.agent.join("eval").join(map_name(map)),
        (None, None) => args.agent.join("eval").join(task.name()),
    }
}

fn eval_insertion(
    ctx: &Context<'_>,
    args: &EvalArgs,
    agent: LoadedAgent,
    map_path: Option<PathBuf>,
    mut progress: Progress<'_>,
) -> Result<()> {
    if let Some(a) = args
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
    let task = agent.task.clone();
    let mut config = task.insertion_config(&args.agent.join(super::TASK_FILE))?;
    if let Some(steps) = args.action_repeat {
        config = config.deciding_every(steps);
    }
    let setup = Insertion::setup(map_path.as_deref(), &config)?;
    let map_path = map_path.unwrap_or_default();
    let spec = setup.observation_spec();
    let policy = agent.policy(&args.agent, spec)?;

    let out = output_dir(ctx, args, Some(&map_path), task.task);
    AtomicDir::check_destination(&out, EVAL_MARKERS)?;
    let conditions = conditions(args);
    let options = EvalOptions {
        episodes: args.episodes,
        seed: ctx.cli.seed,
        lockstep: AGENT_LOCKSTEP,
    };
    let quiet = |_: usize| {};

    progress.step(&format!(
        "agent: {} episodes × {} conditions",
        args.episodes,
        conditions.len()
    ));
    // Per policy, per condition, every episode in order.
    let mut episodes_of: Vec<(String, Vec<Vec<EpisodeSummary>>)> = vec![(
        "agent".to_owned(),
        evaluate_episodes(&setup, || policy.clone(), &conditions, &options, &quiet),
    )];
    if !args.no_baselines {
        let baseline_options = EvalOptions {
            lockstep: EvalOptions::default().lockstep,
            ..options
        };
        for baseline in Baseline::STANDARD {
            progress.step(&format!("baseline {}", baseline.name()));
            episodes_of.push((
                baseline.name(),
                evaluate_episodes(&setup, || baseline, &conditions, &baseline_options, &quiet),
            ));
        }
    }
    let rows: Vec<(String, Vec<ConditionResult>)> = episodes_of
        .iter()
        .map(|(name, per_condition)| {
            (
                name.clone(),
                summarise_conditions(&conditions, per_condition),
            )
        })
        .collect();
    let episodes_csv = episodes_csv(&episodes_of, &conditions);

    let report = EvalReport {
        agent: args.agent.clone(),
        map: map_path.clone(),
        trained_on: task.map.clone().unwrap_or_default(),
        episodes: args.episodes,
        seed: ctx.cli.seed,
        conditions: conditions
            .iter()
            .enumerate()
            .map(|(c, condition)| ConditionReport {
                traffic: condition.traffic,
                aggressiveness: condition.aggressiveness,
                policies: rows
                    .iter()
                    .map(|(name, results)| PolicyResult {
                        policy: name.clone(),
                        result: results[c].clone(),
                    })
                    .collect(),
            })
            .collect(),
    };
    let table = format!(
        "# {} on {}\n\n{} episodes per condition and policy, seed {}; the same episodes for every policy.\n\n{}",
        args.agent.display(),
        map_path.display(),
        args.episodes,
        ctx.cli.seed,
        markdown_table(&by_condition(&rows, conditions.len()))
    );

    let map = setup.map();
    let extra = [(EPISODES_CSV, episodes_csv.as_bytes())];
    write_outputs(ctx, args, &out, &report, &table, &extra, progress, |rec| {
        crate::recording::log_map(rec, map)?;
        let condition = Condition {
            traffic: TrafficLevel::Medium,
            aggressiveness: 0.5,
        };
        episodes::record(
            rec,
            &setup,
            &policy,
            condition,
            args.record_episodes,
            ctx.cli.seed,
        )
    })
}

/// `eval.json` of a task other than insertion.
#[derive(Debug, Serialize)]
struct TaskEvalReport {
    agent: PathBuf,
    task: Task,
    map: Option<PathBuf>,
    trained_on: Option<PathBuf>,
    episodes: usize,
    seed: u64,
    conditions: Vec<TaskConditionReport>,
}

#[derive(Debug, Serialize)]
struct TaskConditionReport {
    condition: String,
    /// The agent first, then the baselines, each on the same episodes (seeds).
    policies: Vec<TaskPolicyResult>,
}

#[derive(Debug, Serialize)]
struct TaskPolicyResult {
    policy: String,
    #[serde(flatten)]
    result: TaskResult,
}

/// Evaluates an agent of task `K` and its baselines on every condition of `K`.
fn eval_task<K: GenericTask>(
    ctx: &Context<'_>,
    args: &EvalArgs,
    agent: LoadedAgent,
    map: Option<PathBuf>,
    mut progress: Progress<'_>,
) -> Result<()> {
    if args.action_repeat.is_some() {
        return Err(CliError::new(
            format!(
                "--action-repeat is for roundabout-insertion agents; this one is {}",
                agent.task.task.name()
            ),
            "leave --action-repeat out",
        )
        .into());
    }
    let task = agent.task.clone();
    let config = super::tasks::task_config::<K>(&task, &args.agent.join(super::TASK_FILE))?;
    let setup = K::setup(map.as_deref(), &config)?;
    let traffic: Vec<TrafficLevel> = args.traffic.iter().map(|&t| t.into()).collect();
    let conditions = K::conditions(&traffic);
    let spec = K::eval_env(&setup, &conditions[0]).observation_spec();
    let policy = agent.policy(&args.agent, spec)?;
    let out = output_dir(ctx, args, map.as_deref(), task.task);
    AtomicDir::check_destination(&out, EVAL_MARKERS)?;

    let seeds: Vec<u64> = (0..args.episodes as u64)
        .map(|k| derive_seed(ctx.cli.seed, EVAL_STAGE, k))
        .collect();
    let baselines = if args.no_baselines {
        Vec::new()
    } else {
        K::Env::baselines()
    };
    let mut reports = Vec::with_capacity(conditions.len());
    let mut tables = String::new();
    for condition in &conditions {
        let make_env = || K::eval_env(&setup, condition);
        progress.step(&format!("{condition}: agent, {} episodes", args.episodes));
        let mut rows = vec![(
            "agent".to_owned(),
            TaskResult::of(&run_episodes(
                make_env,
                || policy.clone(),
                &seeds,
                AGENT_LOCKSTEP,
            )),
        )];
        for (name, make_policy) in &baselines {
            progress.step(&format!("{condition}: {name}"));
            let summaries = run_episodes(make_env, make_policy, &seeds, AGENT_LOCKSTEP);
            rows.push((name.clone(), TaskResult::of(&summaries)));
        }
        tables.push_str(&format!("## {condition}\n\n{}\n", task_table(&rows)));
        reports.push(TaskConditionReport {
            condition: condition.clone(),
            policies: rows
                .into_iter()
                .map(|(policy, result)| TaskPolicyResult { policy, result })
                .collect(),
        });
    }
    let report = TaskEvalReport {
        agent: args.agent.clone(),
        task: task.task,
        map: map.clone(),
        trained_on: task.map.clone(),
        episodes: args.episodes,
        seed: ctx.cli.seed,
        conditions: reports,
    };
    let text = format!(
        "# {} ({}){}\n\n{} episodes per condition and policy, seed {}; the same episodes for every policy.\n\n{tables}",
        args.agent.display(),
        task.task.name(),
        map.as_ref()
            .map_or(String::new(), |m| format!(" on {}", m.display())),
        args.episodes,
        ctx.cli.seed,
    );

    write_outputs(ctx, args, &out, &report, &text, &[], progress, |rec| {
        if let Some(map) = K::map(&setup) {
            crate::recording::log_map(rec, map)?;
        }
        episodes::record_task(
            rec,
            || K::eval_env(&setup, &conditions[0]),
            &policy,
            args.record_episodes,
            ctx.cli.seed,
        )
    })
}

/// Writes `eval.json`, `eval.md`, the `extra` files (name, contents) and the recording (the
/// greedy episodes `record` logs, when `--record-episodes` asks for any) into `out`,
/// atomically, and prints the table.
#[allow(clippy::too_many_arguments)]
fn write_outputs(
    ctx: &Context<'_>,
    args: &EvalArgs,
    out: &Path,
    report: &impl Serialize,
    text: &str,
    extra: &[(&str, &[u8])],
    mut progress: Progress<'_>,
    record: impl FnOnce(&Stream) -> Result<()>,
) -> Result<()> {
    let dir = AtomicDir::create(out, EVAL_MARKERS)?;
    write_json(&dir.path().join(EVAL_JSON), report)?;
    write_file_atomic(&dir.path().join(EVAL_MD), text.as_bytes())?;
    for (name, contents) in extra {
        write_file_atomic(&dir.path().join(name), contents)?;
    }
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
    ctx.ui
        .result(&format!("{text}\nwritten to {}", dest.display()));
    Ok(())
}

/// `episodes.csv`: one line per policy, condition and episode (episode k is seeded alike for
/// every policy), in the order of `eval.json`.
fn episodes_csv(
    episodes_of: &[(String, Vec<Vec<EpisodeSummary>>)],
    conditions: &[Condition],
) -> String {
    let mut csv = String::from(
        "policy,traffic,aggressiveness,episode,outcome,steps,return,mean_speed_mps,time_to_enter_s,close_following_steps,cut_in_steps,entry_lag_s\n",
    );
    for (policy, per_condition) in episodes_of {
        for (condition, episodes) in conditions.iter().zip(per_condition) {
            for (k, e) in episodes.iter().enumerate() {
                let outcome = e.outcome.name();
                let enter = e
                    .time_to_enter_s
                    .map_or(String::new(), |t| format!("{t:.1}"));
                let lag = e.entry_lag_s.map_or(String::new(), |t| format!("{t:.2}"));
                csv.push_str(&format!(
                    "{policy},{},{},{k},{outcome},{},{:.4},{:.3},{enter},{},{},{lag}\n",
                    condition.traffic.name(),
                    condition.aggressiveness,
                    e.steps,
                    e.episode_return,
                    e.mean_speed_mps,
                    e.close_following_steps,
                    e.cut_in_steps,
                ));
            }
        }
    }
    csv
}

/// The conditions asked for: traffic levels × aggressiveness values.
fn conditions(args: &EvalArgs) -> Vec<Condition> {
    let traffic: Vec<TrafficLevel> = if args.traffic.is_empty() {
        TrafficLevel::ALL.to_vec()
    } else {
        args.traffic.iter().map(|&t| t.into()).collect()
    };
    let aggressiveness = if args.aggressiveness.is_empty() {
        vec![0.0, 0.5, 1.0]
    } else {
        args.aggressiveness.clone()
    };
    traffic
        .iter()
        .flat_map(|&traffic| {
            aggressiveness.iter().map(move |&aggressiveness| Condition {
                traffic,
                aggressiveness,
            })
        })
        .collect()
}

/// Rows regrouped so the table lists every policy of a condition together.
fn by_condition(
    rows: &[(String, Vec<ConditionResult>)],
    conditions: usize,
) -> Vec<(String, Vec<ConditionResult>)> {
    (0..conditions)
        .flat_map(|c| {
            rows.iter()
                .map(move |(name, results)| (name.clone(), vec![results[c].clone()]))
        })
        .collect()
}

/// A folder name for a map path: its file name without the map extensions.
fn map_name(path: &std::path::Path) -> String {
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
