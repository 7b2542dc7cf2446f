//! Driving tasks: actions, reward, termination, metrics and baselines on the traffic world.
//!
//! Every task is an [`Env`]: roundabout insertion ([`insertion`]) and roundabout driving
//! ([`ring_driving`]), sharing the prepared roundabouts and the ego's view
//! ([`roundabouts`]). Roundabout insertion has its own evaluation harness
//! ([`crate::eval`], conditions of traffic × aggressiveness); the other tasks implement
//! [`Task`] and are evaluated by [`run_episodes`] with any [`TaskPolicy`]: a learned
//! policy (reading only the observations), a [`ConstantAction`], or a task's own rule.

pub mod insertion;
pub mod motion_inputs;
pub mod obstacle;
pub mod ring_driving;
pub mod roundabouts;
pub mod route;

use rayon::prelude::*;
use serde::Serialize;

use maps::Point;

use crate::env::{Env, Observation, Outcome};
use crate::scene::Scene;

pub use insertion::{
    Action, EpisodeSummary, InsertionConfig, InsertionSetup, InsertionState, RewardConfig,
    RoundaboutInsertion,
};
pub use obstacle::{ObstacleAvoidance, ObstacleConfig, ObstacleSetup, ObstacleSummary};
pub use ring_driving::{
    PursuitRule, RingDriving, RingDrivingConfig, RingDrivingSetup, RingDrivingSummary,
    RingRewardConfig, SteerAction,
};
pub use roundabouts::{EgoView, RoundaboutSet, ego_scene};

/// A task whose finished episodes can be summarised for evaluation tables.
pub trait Task: Env + Sized {
    /// The figures of one episode (outcome, return, the task's metrics).
    type Summary: TaskSummary;

    /// The figures of the current (normally just finished) episode.
    fn summary(&self) -> Self::Summary;

    /// The baselines every agent of the task is reported next to: one per constant action,
    /// then the task's rules, by name.
    fn baselines() -> Vec<(String, PolicyFactory<Self>)>;

    /// The current scene, for pictures and the rerun recording (None before a reset).
    fn scene(&self) -> Option<Scene<'_>>;

    /// The ego's path so far in this episode.
    fn trajectory(&self) -> &[Point];
}

/// What an evaluation table reads from an episode's summary.
pub trait TaskSummary: Clone + Send + Serialize {
    fn outcome(&self) -> Outcome;
    fn episode_return(&self) -> f64;
    /// The task's own metrics, by name with their unit (e.g. `("mean angle deviation °", 12.0)`),
    /// in the same order for every episode. A metric an episode cannot give (e.g. a
    /// stopping distance when the ego never stopped) is NaN and left out of its mean.
    fn metrics(&self) -> Vec<(&'static str, f64)>;
}

/// Makes one policy instance per chunk of episodes (policies are `Send`, not `Sync`).
pub type PolicyFactory<E> = Box<dyn Fn() -> Box<dyn TaskPolicy<E>> + Send + Sync>;

/// The [`PolicyFactory`] of each constant action of `E`.
pub fn constant_baselines<E: Task + 'static>(
    action_names: &[&str],
) -> Vec<(String, PolicyFactory<E>)> {
    action_names
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let make: PolicyFactory<E> = Box::new(move || Box::new(ConstantAction(i)));
            (format!("always {}", name.replace('_', " ")), make)
        })
        .collect()
}

/// A decision rule for a batch of episodes of task `E`, stepped side by side so a network
/// runs one forward pass per step. A learned policy must read only `observations`; rules
/// may read the environments' privileged state.
pub trait TaskPolicy<E>: Send {
    /// One action per environment, in order, into `actions` (cleared first).
    fn act(&mut self, envs: &[&E], observations: &[&Observation], actions: &mut Vec<usize>);
}

impl<E> TaskPolicy<E> for Box<dyn TaskPolicy<E>> {
    fn act(&mut self, envs: &[&E], observations: &[&Observation], actions: &mut Vec<usize>) {
        (**self).act(envs, observations, actions);
    }
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

/// Outcome fractions and metric means of one policy's episodes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TaskResult {
    pub episodes: usize,
    pub reaches: f64,
    pub crashes: f64,
    pub off_roads: f64,
    pub time_overs: f64,
    pub mean_return: f64,
    /// Means over the episodes that give the metric (NaN ones left out), by name.
    pub metrics: Vec<(String, Option<f64>)>,
}

impl TaskResult {
    pub fn of<S: TaskSummary>(episodes: &[S]) -> TaskResult {
        let n = episodes.len();
        let frac = |o: Outcome| {
            episodes.iter().filter(|e| e.outcome() == o).count() as f64 / n.max(1) as f64
        };
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
            crashes: frac(Outcome::Crashed),
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
            "| {policy} | {} | {:.1} % | {:.1} % | {:.1} % | {:.1} % | {:.2} |",
            r.episodes,
            100.0 * r.reaches,
            100.0 * r.crashes,
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
