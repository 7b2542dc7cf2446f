//! `pipeline agent eval`: an agent and the baselines on the same episodes of every
//! condition (traffic level × the ego's aggressiveness), with the sim crate's parallel
//! evaluation harness. Writes `eval.json` (fractions of reaches, crashes, off-roads and
//! time-overs per condition and policy), `eval.md` (the table) and `recording.rrd`.

use std::path::PathBuf;

use anyhow::Result;
use models::dqn::{load_network, read_agent_description};
use models::policy::QPolicy;
use serde::Serialize;
use sim::baselines::Baseline;
use sim::eval::{Condition, ConditionResult, EvalOptions, evaluate, markdown_table};
use sim::world::TrafficLevel;

use super::train::{models_error, read_task, write_json};
use super::{EvalArgs, episodes, insertion_setup, load_or_import_map};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::{AtomicDir, Markers, write_file_atomic};

pub const EVAL_JSON: &str = "eval.json";
pub const EVAL_MD: &str = "eval.md";
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
    let mut progress = ctx.ui.progress("agent eval");
    progress.step(&format!("loading the agent {}", args.agent.display()));
    let device = models::cpu_device();
    let description =
        read_agent_description(&args.agent).map_err(|e| models_error(e, &args.agent))?;
    let task = read_task(&args.agent)?;
    let network = load_network(&args.agent, &description, &device)
        .map_err(|e| models_error(e, &args.agent))?;

    progress.step(&format!("loading {}", args.map.display()));
    let map = load_or_import_map(&args.map)?;
    let setup = insertion_setup(map, &args.map, task.config.clone())?;
    let spec = setup.observation_spec();
    if spec != description.shape.spec() {
        return Err(CliError::file(
            &args.agent,
            format!(
                "was trained on observations {:?}, the task renders {spec:?}",
                description.shape.spec()
            ),
            "evaluate with the task settings the agent was trained with (task.json)",
        )
        .into());
    }
    let policy = QPolicy::new(network, spec, description.shape.actions, device);

    let out = match &args.out {
        Some(out) => ctx.output_path(out),
        None => args.agent.join("eval").join(map_name(&args.map)),
    };
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
    let mut rows: Vec<(String, Vec<ConditionResult>)> = vec![(
        "agent".to_owned(),
        evaluate(&setup, || policy.clone(), &conditions, &options, &quiet),
    )];
    if !args.no_baselines {
        let baseline_options = EvalOptions {
            lockstep: EvalOptions::default().lockstep,
            ..options
        };
        for baseline in Baseline::STANDARD {
            progress.step(&format!("baseline {}", baseline.name()));
            rows.push((
                baseline.name(),
                evaluate(&setup, || baseline, &conditions, &baseline_options, &quiet),
            ));
        }
    }

    let report = EvalReport {
        agent: args.agent.clone(),
        map: args.map.clone(),
        trained_on: task.map.clone(),
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
        args.map.display(),
        args.episodes,
        ctx.cli.seed,
        markdown_table(&by_condition(&rows, conditions.len()))
    );

    let dir = AtomicDir::create(&out, EVAL_MARKERS)?;
    write_json(&dir.path().join(EVAL_JSON), &report)?;
    write_file_atomic(&dir.path().join(EVAL_MD), table.as_bytes())?;
    let recording = ctx.open_recording(Some(dir.path()))?;
    if let Some(rec) = recording.stream()
        && args.record_episodes > 0
    {
        progress.step("recording greedy episodes");
        crate::recording::log_map(rec, setup.map())?;
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
        )?;
    }
    recording.finish()?;
    let dest = dir.commit()?;
    drop(progress);
    ctx.ui
        .result(&format!("{table}\nwritten to {}", dest.display()));
    Ok(())
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
