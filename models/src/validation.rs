//! Choosing the agent by validation, as the segmenter keeps its best epoch.
//!
//! Q-learning does not improve monotonically: the greedy policy of the last network can be
//! worse than one a few checkpoints earlier (on obstacle avoidance, the same config gave
//! 80-99.6 % on crossing vehicles depending on the training seed, and the spread was in where
//! training stopped). With `[agent.validation] episodes = N`, every checkpoint (each
//! `checkpoint_every` transitions of `[agent.dqn]`) and the final network run `N` greedy
//! episodes per validation condition of the task, and the agent written is the checkpoint
//! with the highest mean share of episodes that reached the goal (the earlier one on a tie).
//!
//! Validation episodes are not the evaluation's: they are drawn from [`validation_seed`] of
//! the training seed, as `agent eval` draws its episodes from `--seed`, and route
//! following validates on training routes only, never on the held-out ones. Validation
//! does not change training: the run's transitions and gradient steps are the same with
//! and without it, so the final network is the one an unvalidated run gives.
//!
//! Files (written by the `pipeline` binary): while training, `DIR.partial/best-<steps>` (the
//! best checkpoint so far, for `--resume`, see [`best_dir_name`]) and
//! `DIR.partial/validation.json`; in the agent folder, [`VALIDATION_FILE`] (every point and
//! the one chosen).

use serde::{Deserialize, Serialize};
use sim::seed::derive_seed;

use crate::dqn::Checkpoint;
use crate::policy::QPolicy;

/// `[agent.validation]` of the config file.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValidationConfig {
    /// Greedy episodes per validation condition at every checkpoint; 0 (the default)
    /// turns validation off and the final network is the agent.
    pub episodes: usize,
    /// Roundabout insertion only: validate deciding every this many world steps (frames
    /// stacked as in training), as `agent eval --action-repeat` will evaluate; unset, as
    /// trained.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub action_repeat: Option<usize>,
}

impl ValidationConfig {
    pub fn is_off(&self) -> bool {
        self.episodes == 0
    }
}

/// Seed stage of the validation seed.
const VALIDATION_STAGE: u64 = 0x5641_4c49;

/// The seed validation episodes are drawn with, as `agent eval --seed` draws evaluation
/// episodes: a run trained with `seed` validates on the episodes an evaluation with this
/// seed would run, which are not those of `agent eval`'s seeds 0, 1, 2, ... (with
/// overwhelming probability).
pub fn validation_seed(training_seed: u64) -> u64 {
    derive_seed(training_seed, VALIDATION_STAGE, 0)
}

/// One validated checkpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationPoint {
    /// Transitions of training at the checkpoint.
    pub steps: u64,
    /// Per validation condition, the share of episodes that reached the goal.
    pub reached: Vec<(String, f64)>,
    /// The mean of `reached`: what checkpoints are ranked by.
    pub score: f64,
}

impl ValidationPoint {
    pub fn new(steps: u64, reached: Vec<(String, f64)>) -> Self {
        let score = if reached.is_empty() {
            0.0
        } else {
            reached.iter().map(|(_, r)| r).sum::<f64>() / reached.len() as f64
        };
        ValidationPoint {
            steps,
            reached,
            score,
        }
    }

    /// "step 25000: 0.912 (static obstacle 100.0 %, crossing obstacle 82.4 %)".
    pub fn describe(&self) -> String {
        let parts: Vec<String> = self
            .reached
            .iter()
            .map(|(name, r)| format!("{name} {:.1} %", 100.0 * r))
            .collect();
        format!(
            "validation at step {}: {:.3} ({})",
            self.steps,
            self.score,
            parts.join(", ")
        )
    }
}

/// `validation.json`: every validated checkpoint and the best (the one chosen).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ValidationHistory {
    /// Episodes per condition.
    pub episodes: usize,
    pub points: Vec<ValidationPoint>,
    /// The steps of the best point so far (the chosen agent once training has ended).
    pub best_steps: Option<u64>,
}

pub const VALIDATION_FILE: &str = "validation.json";

impl ValidationHistory {
    pub fn new(episodes: usize) -> Self {
        ValidationHistory {
            episodes,
            ..Default::default()
        }
    }

    /// The best point so far.
    pub fn best(&self) -> Option<&ValidationPoint> {
        let steps = self.best_steps?;
        self.points.iter().find(|p| p.steps == steps)
    }

    /// Adds `point`; true when it is strictly better than every earlier one (it becomes the
    /// best).
    pub fn add(&mut self, point: ValidationPoint) -> bool {
        let better = self.best().is_none_or(|best| point.score > best.score);
        if better {
            self.best_steps = Some(point.steps);
        }
        self.points.push(point);
        better
    }

    /// Forgets the points after `steps` (a run resumed from there redoes them).
    pub fn truncate(&mut self, steps: u64) {
        let points = std::mem::take(&mut self.points);
        self.best_steps = None;
        for point in points.into_iter().filter(|p| p.steps <= steps) {
            self.add(point);
        }
    }
}

/// Validates a greedy policy: per validation condition, the share that reached the goal.
pub type ValidationRun = Box<dyn Fn(&QPolicy, &EpisodesDone<'_>) -> Vec<(String, f64)>>;

/// Told how many more validation episodes have finished (called from worker threads).
pub type EpisodesDone<'a> = dyn Fn(u64) + Sync + 'a;

/// Validation during a training run: the history, and the best checkpoint so far (kept in
/// memory, and in `DIR.partial/best-<steps>` for `--resume`).
pub struct Validation {
    /// Validates a greedy policy: per condition, the share that reached the goal.
    run: ValidationRun,
    pub history: ValidationHistory,
    best: Option<Checkpoint>,
}

impl std::fmt::Debug for Validation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Validation")
            .field("history", &self.history)
            .field("best", &self.best.as_ref().map(|b| b.state.steps))
            .finish_non_exhaustive()
    }
}

impl Validation {
    /// Validation of a new run.
    pub fn new(config: ValidationConfig, run: ValidationRun) -> Self {
        Validation {
            run,
            history: ValidationHistory::new(config.episodes),
            best: None,
        }
    }

    /// Validation of a run resumed from a checkpoint: `history` is the history of the folder
    /// it was resumed from, without the points after that checkpoint, and `best` the best
    /// checkpoint of that history when it is still there. Without it, validation starts
    /// again from the resumed network.
    pub fn resumed(
        config: ValidationConfig,
        run: ValidationRun,
        history: ValidationHistory,
        best: Option<Checkpoint>,
    ) -> Self {
        let history = if best.is_none() && history.best_steps.is_some() {
            ValidationHistory::new(config.episodes)
        } else {
            history
        };
        Validation { run, history, best }
    }

    /// Validates `checkpoint` (`done` is told of the episodes as they finish); true when it is
    /// the best so far.
    pub fn validate(
        &mut self,
        checkpoint: &Checkpoint,
        done: &EpisodesDone<'_>,
    ) -> (ValidationPoint, bool) {
        let policy = QPolicy::new(
            checkpoint.online.clone(),
            checkpoint.shape.spec(),
            checkpoint.shape.actions,
            crate::cpu_device(),
        );
        let point = ValidationPoint::new(checkpoint.state.steps, (self.run)(&policy, done));
        let better = self.history.add(point.clone());
        if better {
            self.best = Some(checkpoint.clone());
        }
        (point, better)
    }

    /// The best checkpoint so far.
    pub fn best(&self) -> Option<&Checkpoint> {
        self.best.as_ref()
    }

    /// Whether `last` (the final checkpoint) still needs validating before [`Self::choose`].
    pub fn needs(&self, last: &Checkpoint) -> bool {
        self.history.points.last().map(|p| p.steps) != Some(last.state.steps)
    }

    /// The agent of the run: the final checkpoint, validated (`done` is told of its
    /// episodes), unless an earlier one scored higher; and the history with the choice.
    pub fn choose(
        mut self,
        last: Checkpoint,
        done: &EpisodesDone<'_>,
    ) -> (Checkpoint, ValidationHistory) {
        if self.needs(&last) {
            self.validate(&last, done);
        }
        let chosen = match self.best {
            Some(best) if Some(best.state.steps) == self.history.best_steps => best,
            _ => last,
        };
        (chosen, self.history)
    }
}

/// Folders of the best checkpoints begin with this.
pub const BEST_PREFIX: &str = "best-";

/// The folder of the best checkpoint at `steps` transitions.
pub fn best_dir_name(steps: u64) -> String {
    format!("{BEST_PREFIX}{steps}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(steps: u64, static_: f64, crossing: f64) -> ValidationPoint {
        ValidationPoint::new(
            steps,
            vec![("static".into(), static_), ("crossing".into(), crossing)],
        )
    }

    #[test]
    fn the_best_is_the_first_with_the_highest_mean() {
        let mut history = ValidationHistory::new(10);
        assert!(history.add(point(1, 0.5, 0.5)));
        assert!(history.add(point(2, 1.0, 0.6)));
        assert!(
            !history.add(point(3, 0.6, 1.0)),
            "a tie keeps the earlier one"
        );
        assert!(!history.add(point(4, 1.0, 0.0)));
        assert_eq!(history.best_steps, Some(2));
        assert!((history.best().expect("a best point").score - 0.8).abs() < 1e-12);
        assert!(history.add(point(5, 1.0, 0.9)));
        assert_eq!(history.best_steps, Some(5));
    }

    #[test]
    fn truncating_forgets_later_points_and_their_best() {
        let mut history = ValidationHistory::new(10);
        for (steps, r) in [(1, 0.2), (2, 0.7), (3, 0.4), (4, 0.9)] {
            history.add(point(steps, r, r));
        }
        history.truncate(3);
        assert_eq!(history.points.len(), 3);
        assert_eq!(history.best_steps, Some(2));
        history.truncate(0);
        assert!(history.points.is_empty());
        assert_eq!(history.best_steps, None);
    }

    #[test]
    fn validation_seeds_are_not_evaluation_seeds() {
        for seed in 0..100 {
            assert!(validation_seed(seed) > 1000, "{seed}");
            assert_ne!(validation_seed(seed), validation_seed(seed + 1));
        }
    }
}
