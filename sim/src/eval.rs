//! The evaluation harness: runs a policy for many episodes of roundabout insertion under
//! several conditions (traffic level × the ego's aggressiveness), in parallel with rayon,
//! and tabulates reaches, crashes, off-roads and time-overs, speed, time to enter, and the
//! share of steps in the situations the reward counts as danger.
//!
//! Plugging in a learned policy: implement [`Policy`] (its `act` gets a batch of inputs,
//! one per running episode of a chunk, so a Q-network can do one forward pass per step)
//! and pass a factory `|| MyPolicy::new(...)` that builds one per chunk of episodes;
//! reading only `input.observation` keeps it honest.
//!
//! Determinism: episode `k` is reset with `derive_seed(seed, EVAL_STAGE, k)` under every
//! condition (so conditions and policies are compared on the same traffic), episodes are
//! grouped into fixed chunks of `lockstep` whatever the number of threads, and results are
//! gathered in episode order: the same seed gives the same table with 1 or N threads.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::baselines::{Policy, PolicyInput};
use crate::env::{Env, Observation, Outcome};
use crate::seed::derive_seed;
use crate::tasks::{EpisodeSummary, InsertionSetup, InsertionState, RoundaboutInsertion};
use crate::world::TrafficLevel;

/// Seed stage of evaluation episodes.
pub const EVAL_STAGE: u64 = 0x4556_414c;

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
}

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

/// Outcome counts and means of one condition.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConditionResult {
    pub traffic: TrafficLevel,
    pub aggressiveness: f64,
    pub episodes: usize,
    /// Fractions of the episodes.
    pub reaches: f64,
    pub crashes: f64,
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

/// Runs `options.episodes` episodes of every condition with policies from `make_policy`;
/// `progress` is told how many episodes each finished chunk held. Summaries come back per
/// condition, in episode order.
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
    let lockstep = options.lockstep.max(1);
    let chunks: Vec<(usize, usize)> = (0..conditions.len())
        .flat_map(|c| {
            (0..options.episodes)
                .step_by(lockstep)
                .map(move |start| (c, start))
        })
        .collect();
    let done = AtomicUsize::new(0);
    let results: Vec<(usize, Vec<EpisodeSummary>)> = chunks
        .par_iter()
        .map(|&(c, start)| {
            let end = (start + lockstep).min(options.episodes);
            let mut policy = make_policy();
            let out = run_chunk(setup, &mut policy, conditions[c], options.seed, start..end);
            done.fetch_add(out.len(), Ordering::Relaxed);
            progress(out.len());
            (c, out)
        })
        .collect();
    let mut per_condition: Vec<Vec<EpisodeSummary>> = vec![Vec::new(); conditions.len()];
    for (c, summaries) in results {
        per_condition[c].extend(summaries);
    }
    per_condition
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

/// Episodes `range` of one condition, stepped side by side.
fn run_chunk<P: Policy>(
    setup: &Arc<InsertionSetup>,
    policy: &mut P,
    condition: Condition,
    seed: u64,
    range: std::ops::Range<usize>,
) -> Vec<EpisodeSummary> {
    let render = policy.needs_observation();
    let mut envs: Vec<RoundaboutInsertion> = Vec::with_capacity(range.len());
    let mut observations: Vec<Observation> = Vec::with_capacity(range.len());
    let seeds: Vec<u64> = range
        .clone()
        .map(|k| derive_seed(seed, EVAL_STAGE, k as u64))
        .collect();
    for &episode_seed in &seeds {
        let mut env = RoundaboutInsertion::new(Arc::clone(setup));
        env.set_traffic(condition.traffic);
        env.set_aggressiveness(Some(condition.aggressiveness));
        env.set_rendering(render);
        observations.push(env.reset(episode_seed));
        envs.push(env);
    }
    let mut running: Vec<bool> = vec![true; envs.len()];
    let mut steps = vec![0usize; envs.len()];
    let mut actions = Vec::with_capacity(envs.len());
    while running.iter().any(|r| *r) {
        let states: Vec<(usize, InsertionState)> = (0..envs.len())
            .filter(|&i| running[i])
            .map(|i| (i, envs[i].state()))
            .collect();
        let inputs: Vec<PolicyInput<'_>> = states
            .iter()
            .map(|(i, state)| PolicyInput {
                slot: *i,
                episode_seed: seeds[*i],
                step: steps[*i],
                observation: &observations[*i],
                state,
            })
            .collect();
        policy.act(&inputs, &mut actions);
        let chosen: Vec<(usize, usize)> = states
            .iter()
            .map(|(i, _)| *i)
            .zip(actions.iter().copied())
            .collect();
        for (i, action) in chosen {
            let step = envs[i].step(action);
            steps[i] += 1;
            observations[i] = step.observation;
            if step.outcome.is_some() {
                running[i] = false;
            }
        }
    }
    envs.iter().map(RoundaboutInsertion::summary).collect()
}

/// Counts and means of one condition's episodes.
pub fn summarise(condition: Condition, episodes: &[EpisodeSummary]) -> ConditionResult {
    let n = episodes.len();
    let frac = |o: Outcome| {
        if n == 0 {
            0.0
        } else {
            episodes.iter().filter(|e| e.outcome == o).count() as f64 / n as f64
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
        crashes: frac(Outcome::Crashed),
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
                "| {policy} | {} | {} | {} | {:.1} % | {:.1} % | {:.1} % | {:.1} % | {:.2} | {} | {:.2} % | {:.1} % |\n",
                r.traffic.name(),
                r.aggressiveness,
                r.episodes,
                100.0 * r.reaches,
                100.0 * r.crashes,
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
