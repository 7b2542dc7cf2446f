//! The evaluation harness of every task: runs a policy for many episodes of a [`Task`] under
//! its conditions (traffic levels, route splits, obstacle scenarios, traffic ×
//! aggressiveness for roundabout insertion), in parallel with rayon, and tabulates them:
//! outcome fractions and the task's metrics ([`TaskResult`], [`task_table`]); an agent and
//! the task's baselines on the same episodes ([`evaluate_agent`]) make an evaluation report
//! ([`Task::eval_report`]); validation shares ([`reached_shares`]).
//!
//! Plugging in a learned policy: implement [`TaskPolicy`] (its `act` gets a batch of
//! environments and their observations, one per running episode of a chunk, so a Q-network
//! can do one forward pass per step) and pass a factory `|| MyPolicy::new(...)` that builds
//! one per chunk of episodes; reading only the observations keeps it honest.
//!
//! Determinism: episode `k` is reset with `derive_seed(seed, EVAL_STAGE, k)` under every
//! condition (so conditions and policies are compared on the same traffic), episodes are
//! grouped into fixed chunks of `lockstep` whatever the number of threads, and results are
//! gathered in episode order: the same seed gives the same table with 1 or N threads.
//!
//! Roundabout insertion's conditions, its figures per condition and the harness for its
//! [`crate::baselines::Policy`] interface are in [`crate::tasks::insertion_eval`] (re-exported
//! here).

use std::path::PathBuf;
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::env::{Observation, Outcome};
use crate::error::SimError;
use crate::seed::derive_seed;
use crate::stats::{PairedRates, paired_rates, wilson};
use crate::tasks::{Task, TaskId, TaskPolicy, TaskSummary};
use crate::world::TrafficLevel;

pub use crate::tasks::insertion_eval::{
    Condition, ConditionResult, TIGHT_ENTRY_S, evaluate, evaluate_episodes, markdown_table,
    summarise, summarise_conditions,
};

/// Seed stage of evaluation episodes.
pub const EVAL_STAGE: u64 = 0x4556_414c;

/// Episodes a validation runs side by side per network forward pass.
pub const VALIDATION_LOCKSTEP: usize = 32;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EvalOptions {
    pub episodes: usize,
    pub seed: u64,
    /// Episodes a policy instance runs side by side (the batch of its `act`).
    pub lockstep: usize,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            episodes: 100,
            seed: 0,
            lockstep: 8,
        }
    }
}

/// The seeds of evaluation episodes `0..episodes` with `seed`.
pub fn eval_seeds(seed: u64, episodes: usize) -> Vec<u64> {
    (0..episodes as u64)
        .map(|k| derive_seed(seed, EVAL_STAGE, k))
        .collect()
}

/// Runs one episode per seed, `lockstep` episodes side by side per policy instance, in
/// parallel; summaries come back in seed order, the same whatever the thread count.
pub fn run_episodes<E, P, FE, FP>(
    make_env: FE,
    make_policy: FP,
    seeds: &[u64],
    lockstep: usize,
) -> Vec<E::Summary>
where
    E: Task,
    P: TaskPolicy<E>,
    FE: Fn() -> E + Sync,
    FP: Fn() -> P + Sync,
{
    let chunks: Vec<&[u64]> = seeds.chunks(lockstep.max(1)).collect();
    chunks
        .par_iter()
        .flat_map_iter(|chunk| run_chunk(&make_env, &mut make_policy(), chunk))
        .collect()
}

/// Runs `options.episodes` episodes of every condition with policies from `make_policy`;
/// `progress` is told how many episodes each finished chunk held. Summaries come back per
/// condition, in episode order.
pub fn evaluate_task<T, P, F>(
    setup: &Arc<T::Setup>,
    make_policy: F,
    conditions: &[T::Condition],
    options: &EvalOptions,
    progress: &(dyn Fn(usize) + Sync),
) -> Vec<Vec<T::Summary>>
where
    T: Task,
    P: TaskPolicy<T>,
    F: Fn() -> P + Sync,
{
    let seeds = eval_seeds(options.seed, options.episodes);
    let lockstep = options.lockstep.max(1);
    let chunks: Vec<(usize, &[u64])> = (0..conditions.len())
        .flat_map(|c| seeds.chunks(lockstep).map(move |chunk| (c, chunk)))
        .collect();
    let results: Vec<(usize, Vec<T::Summary>)> = chunks
        .par_iter()
        .map(|&(c, chunk)| {
            let make_env = || T::env(setup, &conditions[c]);
            let out = run_chunk(&make_env, &mut make_policy(), chunk);
            progress(out.len());
            (c, out)
        })
        .collect();
    let mut per_condition: Vec<Vec<T::Summary>> = vec![Vec::new(); conditions.len()];
    for (c, summaries) in results {
        per_condition[c].extend(summaries);
    }
    per_condition
}

/// One episode per seed in environments from `make_env`, stepped side by side.
fn run_chunk<E, P>(make_env: &impl Fn() -> E, policy: &mut P, seeds: &[u64]) -> Vec<E::Summary>
where
    E: Task,
    P: TaskPolicy<E>,
{
    let render = policy.needs_observation();
    let mut envs: Vec<E> = Vec::with_capacity(seeds.len());
    let mut observations: Vec<Observation> = Vec::with_capacity(seeds.len());
    for &seed in seeds {
        let mut env = make_env();
        if !render {
            env.set_rendering(false);
        }
        observations.push(env.reset(seed));
        envs.push(env);
    }
    let mut running = vec![true; envs.len()];
    let mut actions = Vec::with_capacity(envs.len());
    while running.iter().any(|r| *r) {
        let live: Vec<usize> = (0..envs.len()).filter(|&i| running[i]).collect();
        let env_refs: Vec<&E> = live.iter().map(|&i| &envs[i]).collect();
        let obs_refs: Vec<&Observation> = live.iter().map(|&i| &observations[i]).collect();
        policy.act_in_slots(&live, &env_refs, &obs_refs, &mut actions);
        for (&i, &action) in live.iter().zip(actions.iter()) {
            let step = envs[i].step(action);
            observations[i] = step.observation;
            if step.outcome.is_some() {
                running[i] = false;
            }
        }
    }
    envs.iter().map(Task::summary).collect()
}

/// Validates `policy` for a training run at `traffic`: per validation condition of the task
/// ([`Task::validation_conditions`]), the share of `episodes` greedy episodes, drawn as an
/// evaluation with `seed` draws them, that reached the goal. `done` is told how many more
/// episodes have finished, as they finish.
pub fn reached_shares<T, P>(
    setup: &Arc<T::Setup>,
    policy: &P,
    traffic: TrafficLevel,
    episodes: usize,
    seed: u64,
    done: &(dyn Fn(u64) + Sync),
) -> Vec<(String, f64)>
where
    T: Task,
    P: TaskPolicy<T> + Clone + Sync,
{
    let (names, conditions): (Vec<String>, Vec<T::Condition>) =
        T::validation_conditions(traffic).into_iter().unzip();
    let options = EvalOptions {
        episodes,
        seed,
        lockstep: VALIDATION_LOCKSTEP,
    };
    let episodes = evaluate_task(setup, || policy.clone(), &conditions, &options, &|n| {
        done(n as u64);
    });
    names
        .into_iter()
        .zip(&episodes)
        .map(|(name, episodes)| (name, TaskResult::of(episodes).reaches))
        .collect()
}

/// Every policy's episodes under every condition: the agent first, then the baselines.
#[derive(Debug, Clone)]
pub struct Evaluation<T: Task> {
    pub conditions: Vec<T::Condition>,
    /// Per policy (by name), per condition, every episode in order.
    pub policies: Vec<(String, Vec<Vec<T::Summary>>)>,
}

/// Evaluates `agent` (as "agent") and, with `baselines`, the task's baselines, on the same
/// episodes of every condition; `progress` is told what runs.
pub fn evaluate_agent<T, P>(
    setup: &Arc<T::Setup>,
    agent: &P,
    conditions: Vec<T::Condition>,
    options: &EvalOptions,
    baselines: bool,
    progress: &mut dyn FnMut(&str),
) -> Evaluation<T>
where
    T: Task,
    P: TaskPolicy<T> + Clone + Sync,
{
    let quiet = |_: usize| {};
    progress(&format!(
        "agent: {} episodes × {} conditions",
        options.episodes,
        conditions.len()
    ));
    let mut policies = vec![(
        "agent".to_owned(),
        evaluate_task(setup, || agent.clone(), &conditions, options, &quiet),
    )];
    if baselines {
        for (name, make_policy) in T::setup_baselines(setup) {
            progress(&format!("baseline {name}"));
            let episodes = evaluate_task(setup, &make_policy, &conditions, options, &quiet);
            policies.push((name, episodes));
        }
    }
    Evaluation {
        conditions,
        policies,
    }
}

/// One baseline compared with the agent on the same episodes: exact McNemar tests on
/// reaching and on crashing ("first" is the agent).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairedTest {
    pub baseline: String,
    pub reaches: PairedRates,
    pub crashes: PairedRates,
}

/// The agent (the first of `policies`, per condition `c`) against each other policy on the
/// same episodes of condition `c`.
pub fn paired_tests<S: TaskSummary>(
    policies: &[(String, Vec<Vec<S>>)],
    c: usize,
) -> Vec<PairedTest> {
    let outcomes = |episodes: &[S], o: Outcome| -> Vec<bool> {
        episodes.iter().map(|e| e.outcome() == o).collect()
    };
    let Some((_, agent)) = policies.first() else {
        return Vec::new();
    };
    let Some(agent) = agent.get(c) else {
        return Vec::new();
    };
    policies
        .iter()
        .skip(1)
        .filter_map(|(name, per_condition)| {
            let baseline = per_condition.get(c)?;
            Some(PairedTest {
                baseline: name.clone(),
                reaches: paired_rates(
                    &outcomes(agent, Outcome::Reached),
                    &outcomes(baseline, Outcome::Reached),
                ),
                crashes: paired_rates(
                    &outcomes(agent, Outcome::Crashed),
                    &outcomes(baseline, Outcome::Crashed),
                ),
            })
        })
        .collect()
}

/// A markdown table of [`paired_tests`].
pub fn paired_table(tests: &[PairedTest]) -> String {
    if tests.is_empty() {
        return String::new();
    }
    let mut out = String::from(
        "Paired with the agent on the same episodes (exact McNemar): episodes reached only by the agent / only by the baseline, p; crashed likewise.\n\n\
         | baseline | reached: agent only / baseline only | p | crashed: agent only / baseline only | p |\n\
         | --- | --- | --- | --- | --- |\n",
    );
    for t in tests {
        out.push_str(&format!(
            "| {} | {} / {} | {} | {} / {} | {} |\n",
            t.baseline,
            t.reaches.only_first,
            t.reaches.only_second,
            p_text(t.reaches.p_value),
            t.crashes.only_first,
            t.crashes.only_second,
            p_text(t.crashes.p_value),
        ));
    }
    out
}

/// A rate with its 95 % interval as text: "99.4 % [98.9, 99.7]".
pub fn rate_text(rate: f64, ci95: (f64, f64)) -> String {
    format!(
        "{:.1} % [{:.1}, {:.1}]",
        100.0 * rate,
        100.0 * ci95.0,
        100.0 * ci95.1
    )
}

/// A p-value as text: three significant figures, "< 1e-6" below that.
pub fn p_text(p: f64) -> String {
    if p < 1e-6 {
        "< 1e-6".into()
    } else if p < 0.001 {
        format!("{p:.1e}")
    } else {
        format!("{p:.3}")
    }
}

/// What an evaluation report says of its run.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalHeader {
    /// The agent folder.
    pub agent: PathBuf,
    pub task: TaskId,
    /// The map evaluated on (None for a task on its own road).
    pub map: Option<PathBuf>,
    /// The map the agent was trained on.
    pub trained_on: Option<PathBuf>,
    /// The roundabouts of the map evaluated on (empty for a task on none).
    pub roundabouts: Vec<u32>,
    /// Per condition and policy.
    pub episodes: usize,
    pub seed: u64,
}

impl EvalHeader {
    /// " on MAP, roundabout N" (or "roundabouts N, M"), as the reports' titles say where the
    /// agent was judged; empty for a task on its own road.
    pub fn place(&self) -> String {
        let mut place = self
            .map
            .as_ref()
            .map_or(String::new(), |m| format!(" on {}", m.display()));
        if !self.roundabouts.is_empty() {
            let ids: Vec<String> = self.roundabouts.iter().map(u32::to_string).collect();
            place.push_str(&format!(
                ", roundabout{} {}",
                if ids.len() == 1 { "" } else { "s" },
                ids.join(", ")
            ));
        }
        place
    }
}

/// The files of an evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalReport {
    /// `eval.json` (pretty-printed, without the final line break).
    pub json: String,
    /// `eval.md`: the tables.
    pub markdown: String,
    /// More files, by name.
    pub extra: Vec<(&'static str, String)>,
}

/// `eval.json` of a task evaluated per named condition.
#[derive(Debug, Serialize)]
struct ConditionsJson<'a> {
    agent: &'a PathBuf,
    task: TaskId,
    map: &'a Option<PathBuf>,
    trained_on: &'a Option<PathBuf>,
    #[serde(skip_serializing_if = "<[u32]>::is_empty")]
    roundabouts: &'a [u32],
    episodes: usize,
    seed: u64,
    conditions: Vec<NamedCondition>,
}

#[derive(Debug, Serialize)]
struct NamedCondition {
    condition: String,
    /// The agent first, then the baselines, each on the same episodes (seeds).
    policies: Vec<NamedResult>,
    /// The agent against each baseline, episode by episode.
    paired: Vec<PairedTest>,
}

#[derive(Debug, Serialize)]
struct NamedResult {
    policy: String,
    #[serde(flatten)]
    result: TaskResult,
}

/// The default evaluation report: per condition (by [`Task::condition_name`]), a
/// [`TaskResult`] per policy, as JSON and as one markdown table per condition.
pub fn conditions_report<T: Task>(
    header: &EvalHeader,
    evaluation: &Evaluation<T>,
) -> Result<EvalReport, SimError> {
    let mut conditions = Vec::with_capacity(evaluation.conditions.len());
    let mut tables = String::new();
    for (c, condition) in evaluation.conditions.iter().enumerate() {
        let name = T::condition_name(condition);
        let rows: Vec<(String, TaskResult)> = evaluation
            .policies
            .iter()
            .map(|(policy, episodes)| (policy.clone(), TaskResult::of(&episodes[c])))
            .collect();
        let paired = paired_tests(&evaluation.policies, c);
        tables.push_str(&format!(
            "## {name}\n\n{}\n{}",
            task_table(&rows),
            paired_table(&paired)
        ));
        conditions.push(NamedCondition {
            paired,
            condition: name,
            policies: rows
                .into_iter()
                .map(|(policy, result)| NamedResult { policy, result })
                .collect(),
        });
    }
    let json = ConditionsJson {
        agent: &header.agent,
        task: header.task,
        map: &header.map,
        trained_on: &header.trained_on,
        roundabouts: &header.roundabouts,
        episodes: header.episodes,
        seed: header.seed,
        conditions,
    };
    let markdown = format!(
        "# {} ({}){}\n\n{} episodes per condition and policy, seed {}; the same episodes for every policy.\n\n{tables}",
        header.agent.display(),
        header.task.name(),
        header.place(),
        header.episodes,
        header.seed,
    );
    Ok(EvalReport {
        json: serde_json::to_string_pretty(&json)?,
        markdown,
        extra: Vec::new(),
    })
}

/// Outcome fractions and metric means of one policy's episodes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TaskResult {
    pub episodes: usize,
    pub reaches: f64,
    /// 95 % Wilson interval of `reaches`.
    pub reaches_ci95: (f64, f64),
    pub crashes: f64,
    /// 95 % Wilson interval of `crashes`.
    pub crashes_ci95: (f64, f64),
    pub off_roads: f64,
    pub time_overs: f64,
    pub mean_return: f64,
    /// Means over the episodes that give the metric (NaN ones left out), by name.
    pub metrics: Vec<(String, Option<f64>)>,
}

impl TaskResult {
    pub fn of<S: TaskSummary>(episodes: &[S]) -> TaskResult {
        let n = episodes.len();
        let count = |o: Outcome| episodes.iter().filter(|e| e.outcome() == o).count();
        let frac = |o: Outcome| count(o) as f64 / n.max(1) as f64;
        let interval = |o: Outcome| wilson(count(o) as u64, n as u64);
        let per_episode: Vec<Vec<(&'static str, f64)>> =
            episodes.iter().map(TaskSummary::metrics).collect();
        let names: Vec<&'static str> = per_episode
            .first()
            .map(|m| m.iter().map(|(name, _)| *name).collect())
            .unwrap_or_default();
        let metrics = names
            .iter()
            .enumerate()
            .map(|(k, name)| {
                let values: Vec<f64> = per_episode
                    .iter()
                    .filter_map(|m| m.get(k).map(|(_, v)| *v))
                    .filter(|v| !v.is_nan())
                    .collect();
                let mean =
                    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64);
                ((*name).to_owned(), mean)
            })
            .collect();
        TaskResult {
            episodes: n,
            reaches: frac(Outcome::Reached),
            reaches_ci95: interval(Outcome::Reached),
            crashes: frac(Outcome::Crashed),
            crashes_ci95: interval(Outcome::Crashed),
            off_roads: frac(Outcome::OffRoad),
            time_overs: frac(Outcome::TimeOver),
            mean_return: episodes
                .iter()
                .map(TaskSummary::episode_return)
                .sum::<f64>()
                / n.max(1) as f64,
            metrics,
        }
    }
}

/// A markdown table of policies' results: outcome fractions, then the task's metrics.
pub fn task_table(rows: &[(String, TaskResult)]) -> String {
    let metric_names: Vec<&str> = rows
        .first()
        .map(|(_, r)| r.metrics.iter().map(|(n, _)| n.as_str()).collect())
        .unwrap_or_default();
    let mut out = String::from(
        "| policy | episodes | reached | crashed | off road | time over | mean return |",
    );
    for name in &metric_names {
        out.push_str(&format!(" {name} |"));
    }
    out.push_str("\n|");
    // Seven fixed columns (policy to mean return), then the metrics.
    out.push_str(&" --- |".repeat(7 + metric_names.len()));
    out.push('\n');
    for (policy, r) in rows {
        out.push_str(&format!(
            "| {policy} | {} | {} | {} | {:.1} % | {:.1} % | {:.2} |",
            r.episodes,
            rate_text(r.reaches, r.reaches_ci95),
            rate_text(r.crashes, r.crashes_ci95),
            100.0 * r.off_roads,
            100.0 * r.time_overs,
            r.mean_return,
        ));
        for (_, value) in &r.metrics {
            match value {
                Some(v) => out.push_str(&format!(" {v:.2} |")),
                None => out.push_str(" - |"),
            }
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Clone, Serialize)]
    struct One(Outcome);

    impl TaskSummary for One {
        fn outcome(&self) -> Outcome {
            self.0
        }
        fn episode_return(&self) -> f64 {
            1.0
        }
        fn metrics(&self) -> Vec<(&'static str, f64)> {
            vec![("a m", 1.0), ("b s", f64::NAN)]
        }
    }

    #[test]
    fn every_table_row_has_the_header_s_columns() {
        let result = TaskResult::of(&[One(Outcome::Reached), One(Outcome::Crashed)]);
        assert_eq!(result.metrics[0].1, Some(1.0));
        assert_eq!(result.metrics[1].1, None);
        let table = task_table(&[("p".into(), result)]);
        let columns: Vec<usize> = table.lines().map(|l| l.matches('|').count()).collect();
        assert_eq!(columns.len(), 3);
        assert!(columns.iter().all(|&c| c == columns[0]), "{table}");
    }
}
