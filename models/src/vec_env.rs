//! Several environments stepped side by side with rayon, so the simulator uses every core
//! while one batched forward pass picks all their actions.
//!
//! Determinism: environment `e`'s `k`-th episode is reset with
//! [`episode_seed`]`(seed, e, k)`, and each environment only ever sees its own actions, so
//! the trajectories do not depend on the number of threads or on scheduling.

use rayon::prelude::*;
use sim::seed::derive_seed;
use sim::{Env, Observation, Outcome};

/// Seed stage of training episodes.
pub const TRAIN_STAGE: u64 = 0x5452_4149;

/// The reset seed of environment `env`'s episode number `episode` under `seed`.
pub fn episode_seed(seed: u64, env: usize, episode: u64) -> u64 {
    derive_seed(derive_seed(seed, TRAIN_STAGE, env as u64), 0, episode)
}

/// An episode that ended during a [`VecEnv::step`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeEnd {
    pub env: usize,
    pub episode_return: f64,
    pub length: usize,
    pub outcome: Outcome,
}

/// What one vector step produced; the new observations are in [`VecEnv::observations`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct VecStep {
    pub rewards: Vec<f32>,
    /// Per environment: its episode ended with this step (and it was reset).
    pub ended: Vec<bool>,
    pub finished: Vec<EpisodeEnd>,
}

#[derive(Debug)]
pub struct VecEnv<E> {
    envs: Vec<E>,
    seed: u64,
    /// Per environment: the index of its current episode.
    episodes: Vec<u64>,
    observations: Vec<Observation>,
    returns: Vec<f64>,
    lengths: Vec<usize>,
}

impl<E: Env> VecEnv<E> {
    /// Resets every environment: environment `e` starts its episode `first_episodes[e]`
    /// (0 for a fresh run; a resumed run continues its counts).
    pub fn new(mut envs: Vec<E>, seed: u64, first_episodes: &[u64]) -> Self {
        let episodes: Vec<u64> = (0..envs.len())
            .map(|e| first_episodes.get(e).copied().unwrap_or(0))
            .collect();
        let observations = envs
            .par_iter_mut()
            .enumerate()
            .map(|(e, env)| env.reset(episode_seed(seed, e, episodes[e])))
            .collect();
        let n = envs.len();
        VecEnv {
            envs,
            seed,
            episodes,
            observations,
            returns: vec![0.0; n],
            lengths: vec![0; n],
        }
    }

    pub fn len(&self) -> usize {
        self.envs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.envs.is_empty()
    }

    /// The current observation of every environment.
    pub fn observations(&self) -> &[Observation] {
        &self.observations
    }

    /// The index of every environment's current episode.
    pub fn episodes(&self) -> &[u64] {
        &self.episodes
    }

    pub fn envs(&self) -> &[E] {
        &self.envs
    }

    /// Steps every environment with its action; where an episode ends, the environment is
    /// reset to its next episode and its observation is that episode's first.
    pub fn step(&mut self, actions: &[usize]) -> VecStep {
        let seed = self.seed;
        let results: Vec<(f32, Option<Outcome>)> = self
            .envs
            .par_iter_mut()
            .zip(self.observations.par_iter_mut())
            .zip(self.episodes.par_iter_mut())
            .zip(actions.par_iter())
            .enumerate()
            .map(|(e, (((env, observation), episode), &action))| {
                let step = env.step(action);
                *observation = step.observation;
                if step.outcome.is_some() {
                    *episode += 1;
                    *observation = env.reset(episode_seed(seed, e, *episode));
                }
                (step.reward, step.outcome)
            })
            .collect();
        let mut out = VecStep {
            rewards: Vec::with_capacity(results.len()),
            ended: Vec::with_capacity(results.len()),
            finished: Vec::new(),
        };
        for (e, (reward, outcome)) in results.into_iter().enumerate() {
            self.returns[e] += f64::from(reward);
            self.lengths[e] += 1;
            out.rewards.push(reward);
            out.ended.push(outcome.is_some());
            if let Some(outcome) = outcome {
                out.finished.push(EpisodeEnd {
                    env: e,
                    episode_return: self.returns[e],
                    length: self.lengths[e],
                    outcome,
                });
                self.returns[e] = 0.0;
                self.lengths[e] = 0;
            }
        }
        out
    }
}
