//! Roundabout insertion's evaluation: its conditions (traffic level × the ego's
//! aggressiveness), the harness for its [`Policy`] interface (the rules reading the
//! privileged state, and policies judged on recorded logs), its figures per condition, and
//! its report: `eval.json` and `eval.md` per condition and policy, and `episodes.csv`, every
//! episode's outcome per policy and condition, so two policies can be compared episode by
//! episode. The episodes are run by the one harness, [`crate::eval`].

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::baselines::{InsertionPolicy, Policy};
use crate::env::Outcome;
use crate::error::SimError;
use crate::eval::{
    EvalHeader, EvalOptions, EvalReport, Evaluation, PairedTest, evaluate_task, paired_table,
    paired_tests, rate_text,
};
use crate::stats::wilson;
use crate::tasks::{EpisodeSummary, InsertionSetup, RoundaboutInsertion};
use crate::world::TrafficLevel;

/// One evaluation condition.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Condition {
    pub traffic: TrafficLevel,
    /// The ego's aggressiveness, fixed for the condition.
    pub aggressiveness: f64,
}

impl Condition {
    /// Every traffic level × aggressiveness 0, 0.5 and 1.
    pub fn grid() -> Vec<Condition> {
        TrafficLevel::ALL
            .iter()
            .flat_map(|&traffic| {
                [0.0, 0.5, 1.0].map(|aggressiveness| Condition {
                    traffic,
                    aggressiveness,
                })
            })
            .collect()
    }

    /// "traffic medium, aggressiveness 0.5".
    pub fn name(&self) -> String {
        format!(
            "traffic {}, aggressiveness {}",
            self.traffic.name(),
            self.aggressiveness
        )
    }
}

/// Outcome counts and means of one condition.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConditionResult {
    pub traffic: TrafficLevel,
    pub aggressiveness: f64,
    pub episodes: usize,
    /// Fractions of the episodes.
    pub reaches: f64,
    /// 95 % Wilson intervals of `reaches` and `crashes`.
    #[serde(default)]
    pub reaches_ci95: (f64, f64),
    pub crashes: f64,
    #[serde(default)]
    pub crashes_ci95: (f64, f64),
    pub off_roads: f64,
    pub time_overs: f64,
    pub mean_return: f64,
    pub mean_speed_mps: f64,
    /// Mean over episodes in which the ego entered, s (None if it never did).
    pub mean_time_to_enter_s: Option<f64>,
    pub mean_steps: f64,
    /// Shares of all the condition's world steps in which the ego followed closer than the
    /// reward's headway, and was in the ring just in front of a circulating vehicle (the
    /// situations r_danger penalises): how much risk the policy takes short of crashing.
    #[serde(default)]
    pub close_following_share: f64,
    #[serde(default)]
    pub cut_in_share: f64,
    /// Share of the episodes in which the ego entered that it entered in front of a
    /// circulating vehicle less than [`TIGHT_ENTRY_S`] from its merge point
    /// ([`EpisodeSummary::entry_lag_s`]): how small the gaps it takes are.
    #[serde(default)]
    pub tight_entry_share: f64,
}

/// An entry is tight when a circulating vehicle is less than this from the ego's merge
/// point, s: the reward's default `cut_in_s`, within which being in front of one is danger.
pub const TIGHT_ENTRY_S: f64 = 3.0;

/// Runs `options.episodes` episodes of every condition with policies from `make_policy`
/// (see [`evaluate_task`]); `progress` is told how many episodes each finished chunk held.
/// Summaries come back per condition, in episode order.
pub fn evaluate_episodes<P, F>(
    setup: &Arc<InsertionSetup>,
    make_policy: F,
    conditions: &[Condition],
    options: &EvalOptions,
    progress: &(dyn Fn(usize) + Sync),
) -> Vec<Vec<EpisodeSummary>>
where
    P: Policy,
    F: Fn() -> P + Sync,
{
    evaluate_task::<RoundaboutInsertion, _, _>(
        setup,
        || InsertionPolicy(make_policy()),
        conditions,
        options,
        progress,
    )
}

/// Like [`evaluate_episodes`], tabulated per condition.
pub fn evaluate<P, F>(
    setup: &Arc<InsertionSetup>,
    make_policy: F,
    conditions: &[Condition],
    options: &EvalOptions,
    progress: &(dyn Fn(usize) + Sync),
) -> Vec<ConditionResult>
where
    P: Policy,
    F: Fn() -> P + Sync,
{
    let episodes = evaluate_episodes(setup, make_policy, conditions, options, progress);
    summarise_conditions(conditions, &episodes)
}

/// [`summarise`] for every condition, from [`evaluate_episodes`]' episodes per condition.
pub fn summarise_conditions(
    conditions: &[Condition],
    episodes: &[Vec<EpisodeSummary>],
) -> Vec<ConditionResult> {
    conditions
        .iter()
        .zip(episodes)
        .map(|(condition, episodes)| summarise(*condition, episodes))
        .collect()
}

/// Counts and means of one condition's episodes.
pub fn summarise(condition: Condition, episodes: &[EpisodeSummary]) -> ConditionResult {
    let n = episodes.len();
    let count = |o: Outcome| episodes.iter().filter(|e| e.outcome == o).count();
    let frac = |o: Outcome| {
        if n == 0 {
            0.0
        } else {
            count(o) as f64 / n as f64
        }
    };
    let mean = |f: &dyn Fn(&EpisodeSummary) -> f64| {
        if n == 0 {
            0.0
        } else {
            episodes.iter().map(f).sum::<f64>() / n as f64
        }
    };
    let entered: Vec<f64> = episodes.iter().filter_map(|e| e.time_to_enter_s).collect();
    let total_steps = episodes.iter().map(|e| e.steps).sum::<usize>().max(1) as f64;
    let share = |f: &dyn Fn(&EpisodeSummary) -> usize| {
        episodes.iter().map(f).sum::<usize>() as f64 / total_steps
    };
    ConditionResult {
        traffic: condition.traffic,
        aggressiveness: condition.aggressiveness,
        episodes: n,
        reaches: frac(Outcome::Reached),
        reaches_ci95: wilson(count(Outcome::Reached) as u64, n as u64),
        crashes: frac(Outcome::Crashed),
        crashes_ci95: wilson(count(Outcome::Crashed) as u64, n as u64),
        off_roads: frac(Outcome::OffRoad),
        time_overs: frac(Outcome::TimeOver),
        mean_return: mean(&|e| e.episode_return),
        mean_speed_mps: mean(&|e| e.mean_speed_mps),
        mean_time_to_enter_s: (!entered.is_empty())
            .then(|| entered.iter().sum::<f64>() / entered.len() as f64),
        mean_steps: mean(&|e| e.steps as f64),
        close_following_share: share(&|e| e.close_following_steps),
        cut_in_share: share(&|e| e.cut_in_steps),
        tight_entry_share: if entered.is_empty() {
            0.0
        } else {
            episodes
                .iter()
                .filter(|e| e.entry_lag_s.is_some_and(|lag| lag < TIGHT_ENTRY_S))
                .count() as f64
                / entered.len() as f64
        },
    }
}

/// A markdown table: one row per (policy, condition).
pub fn markdown_table(rows: &[(String, Vec<ConditionResult>)]) -> String {
    let mut out = String::from(
        "| policy | traffic | aggressiveness | episodes | reaches | crashes | time-overs | off-road | mean speed m/s | time to enter s | close following | tight entries |\n\
         | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
    );
    for (policy, results) in rows {
        for r in results {
            out.push_str(&format!(
                "| {policy} | {} | {} | {} | {} | {} | {:.1} % | {:.1} % | {:.2} | {} | {:.2} % | {:.1} % |\n",
                r.traffic.name(),
                r.aggressiveness,
                r.episodes,
                rate_text(r.reaches, r.reaches_ci95),
                rate_text(r.crashes, r.crashes_ci95),
                100.0 * r.time_overs,
                100.0 * r.off_roads,
                r.mean_speed_mps,
                r.mean_time_to_enter_s.map_or("-".into(), |t| format!("{t:.1}")),
                100.0 * r.close_following_share,
                100.0 * r.tight_entry_share,
            ));
        }
    }
    out
}

/// `eval.json`.
#[derive(Debug, Serialize)]
struct ReportJson<'a> {
    agent: &'a std::path::Path,
    map: &'a std::path::Path,
    /// The map the agent was trained on.
    trained_on: &'a std::path::Path,
    /// The roundabouts of the map evaluated on.
    roundabouts: &'a [u32],
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
    /// The agent against each baseline, episode by episode.
    paired: Vec<PairedTest>,
}

#[derive(Debug, Serialize)]
struct PolicyResult {
    policy: String,
    #[serde(flatten)]
    result: ConditionResult,
}

/// The report of an evaluation: `eval.json` and `eval.md` with a [`ConditionResult`] per
/// condition and policy, and `episodes.csv`.
pub(crate) fn report(
    header: &EvalHeader,
    evaluation: &Evaluation<Condition, EpisodeSummary>,
) -> Result<EvalReport, SimError> {
    let conditions = &evaluation.conditions;
    let rows: Vec<(String, Vec<ConditionResult>)> = evaluation
        .policies
        .iter()
        .map(|(name, per_condition)| {
            (
                name.clone(),
                summarise_conditions(conditions, per_condition),
            )
        })
        .collect();
    let map = header.map.clone().unwrap_or_default();
    let trained_on = header.trained_on.clone().unwrap_or_default();
    let json = ReportJson {
        agent: &header.agent,
        map: &map,
        trained_on: &trained_on,
        roundabouts: &header.roundabouts,
        episodes: header.episodes,
        seed: header.seed,
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
                paired: paired_tests(&evaluation.policies, c),
            })
            .collect(),
    };
    let mut markdown = format!(
        "# {}{}\n\n{} episodes per condition and policy, seed {}; the same episodes for every policy.\n\n{}",
        header.agent.display(),
        header.place(),
        header.episodes,
        header.seed,
        markdown_table(&by_condition(&rows, conditions.len()))
    );
    for (c, condition) in conditions.iter().enumerate() {
        let table = paired_table(&paired_tests(&evaluation.policies, c));
        if !table.is_empty() {
            markdown.push_str(&format!("\n## {}\n\n{table}", condition.name()));
        }
    }
    Ok(EvalReport {
        json: serde_json::to_string_pretty(&json)?,
        markdown,
        extra: vec![(EPISODES_CSV, episodes_csv(&evaluation.policies, conditions))],
    })
}

/// The file of every episode's outcome.
pub const EPISODES_CSV: &str = "episodes.csv";

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
