//! Driving tasks: actions, reward, termination, metrics and baselines on the traffic world.
//!
//! Every task is an [`Env`]. Roundabout insertion has its own evaluation harness
//! ([`crate::eval`], conditions of traffic × aggressiveness); the other tasks implement
//! [`Task`] and are evaluated by [`run_episodes`] with any [`TaskPolicy`]: a learned
//! policy (reading only the observations), a [`ConstantAction`], or a task's own rule.

pub mod insertion;

use rayon::prelude::*;
use serde::Serialize;

use crate::env::{Env, Observation};

pub use insertion::{
    Action, EpisodeSummary, InsertionConfig, InsertionSetup, InsertionState, RewardConfig,
    RoundaboutInsertion,
};

/// A task whose finished episodes can be summarised for evaluation tables.
pub trait Task: Env {
    /// The figures of one episode (outcome, return, the task's metrics).
    type Summary: Clone + Send + Serialize;

    /// The figures of the current (normally just finished) episode.
    fn summary(&self) -> Self::Summary;
}

/// A decision rule for a batch of episodes of task `E`, stepped side by side so a network
/// runs one forward pass per step. A learned policy must read only `observations`; rules
/// may read the environments' privileged state.
pub trait TaskPolicy<E>: Send {
    /// One action per environment, in order, into `actions` (cleared first).
    fn act(&mut self, envs: &[&E], observations: &[&Observation], actions: &mut Vec<usize>);
}

/// The same action at every step: the constant-action baselines.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConstantAction(pub usize);

impl<E> TaskPolicy<E> for ConstantAction {
    fn act(&mut self, envs: &[&E], _: &[&Observation], actions: &mut Vec<usize>) {
        actions.clear();
        actions.resize(envs.len(), self.0);
    }
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
        .flat_map_iter(|chunk| {
            let mut policy = make_policy();
            let mut envs: Vec<E> = chunk.iter().map(|_| make_env()).collect();
            let mut observations: Vec<Observation> = envs
                .iter_mut()
                .zip(chunk.iter())
                .map(|(env, &seed)| env.reset(seed))
                .collect();
            let mut running = vec![true; envs.len()];
            let mut actions = Vec::with_capacity(envs.len());
            while running.iter().any(|r| *r) {
                let live: Vec<usize> = (0..envs.len()).filter(|&i| running[i]).collect();
                let env_refs: Vec<&E> = live.iter().map(|&i| &envs[i]).collect();
                let obs_refs: Vec<&Observation> = live.iter().map(|&i| &observations[i]).collect();
                policy.act(&env_refs, &obs_refs, &mut actions);
                for (&i, &action) in live.iter().zip(actions.iter()) {
                    let step = envs[i].step(action);
                    observations[i] = step.observation;
                    if step.outcome.is_some() {
                        running[i] = false;
                    }
                }
            }
            envs.iter().map(Task::summary).collect::<Vec<_>>()
        })
        .collect()
}
