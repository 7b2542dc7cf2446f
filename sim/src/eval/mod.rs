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
//! [`crate::baselines::Policy`] interface are in [`insertion`], the tables and report files
//! in [`report`] (both re-exported here).

use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::env::Observation;
use crate::seed::derive_seed;
use crate::tasks::{Driving, Task, TaskPolicy};
use crate::world::TrafficLevel;

pub mod insertion;
pub mod report;

pub use insertion::{
    Condition, ConditionResult, TIGHT_ENTRY_S, evaluate, evaluate_episodes, markdown_table,
    summarise, summarise_conditions,
};
pub use report::{
    EvalHeader, EvalReport, Evaluation, PairedTest, TaskResult, conditions_report, p_text,
    paired_table, paired_tests, rate_text, task_table,
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
    envs.iter().map(Driving::summary).collect()
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

/// Evaluates `agent` (as "agent") and, with `baselines`, the task's baselines, on the same
/// episodes of every condition; `progress` is told what runs.
pub fn evaluate_agent<T, P>(
    setup: &Arc<T::Setup>,
    agent: &P,
    conditions: Vec<T::Condition>,
    options: &EvalOptions,
    baselines: bool,
    progress: &mut dyn FnMut(&str),
) -> Evaluation<T::Condition, T::Summary>
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
