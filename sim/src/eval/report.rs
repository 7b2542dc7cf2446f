//! An evaluation's figures and files: outcome fractions and the task's metrics per policy
//! ([`TaskResult`], [`task_table`]), the agent paired with each baseline on the same episodes
//! ([`paired_tests`]) and the default report ([`conditions_report`]). Nothing here runs an
//! episode or knows a task's type: the harness ([`super`]) and the tasks build on it.

use std::path::PathBuf;

use serde::Serialize;

use crate::env::Outcome;
use crate::error::SimError;
use crate::stats::{PairedRates, paired_rates, wilson};
use crate::tasks::id::TaskId;

/// What an evaluation table reads from an episode's summary.
pub trait TaskSummary: Clone + Send + Serialize {
    fn outcome(&self) -> Outcome;
    fn episode_return(&self) -> f64;
    /// The task's own metrics, by name with their unit (e.g. `("mean angle deviation °", 12.0)`),
    /// in the same order for every episode. A metric an episode cannot give (e.g. a
    /// stopping distance when the ego never stopped) is NaN and left out of its mean.
    fn metrics(&self) -> Vec<(&'static str, f64)>;
}

/// Every policy's episodes under every condition: the agent first, then the baselines.
#[derive(Debug, Clone)]
pub struct Evaluation<C, S> {
    pub conditions: Vec<C>,
    /// Per policy (by name), per condition, every episode in order.
    pub policies: Vec<(String, Vec<Vec<S>>)>,
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

/// The default evaluation report: per condition (by `condition_name`, a task's
/// [`crate::tasks::Task::condition_name`]), a
/// [`TaskResult`] per policy, as JSON and as one markdown table per condition.
pub fn conditions_report<C, S: TaskSummary>(
    header: &EvalHeader,
    evaluation: &Evaluation<C, S>,
    condition_name: impl Fn(&C) -> String,
) -> Result<EvalReport, SimError> {
    let mut conditions = Vec::with_capacity(evaluation.conditions.len());
    let mut tables = String::new();
    for (c, condition) in evaluation.conditions.iter().enumerate() {
        let name = condition_name(condition);
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
