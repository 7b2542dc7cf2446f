//! What every task keeps of its current episode: the steps taken, the return, how the
//! episode ended and the ego's path; and the steps an [`crate::Env`] returns from it.

use maps::Point;

use crate::env::{Observation, Outcome, Step};

/// The bookkeeping of one episode.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Episode {
    /// Steps counted so far (world steps or decisions, as the task counts them).
    pub steps: usize,
    pub episode_return: f64,
    /// How the episode ended (None while it runs).
    pub outcome: Option<Outcome>,
    /// The ego's positions so far (the start first).
    pub trajectory: Vec<Point>,
}

impl Episode {
    /// Starts a new episode with the ego at `start` (when there is an ego).
    pub fn reset(&mut self, start: Option<Point>) {
        self.steps = 0;
        self.episode_return = 0.0;
        self.outcome = None;
        self.trajectory.clear();
        self.trajectory.extend(start);
    }

    /// Whether the episode has ended.
    pub fn ended(&self) -> bool {
        self.outcome.is_some()
    }

    /// How the episode ended, as a summary gives it: a time-over while it has not.
    pub fn final_outcome(&self) -> Outcome {
        self.outcome.unwrap_or(Outcome::TimeOver)
    }

    /// The mean of `sum` over the steps (0 before any).
    pub fn mean(&self, sum: f64) -> f64 {
        if self.steps > 0 {
            sum / self.steps as f64
        } else {
            0.0
        }
    }

    /// What a step after the end (or before any reset) returns: the observation, no
    /// reward, and the episode's outcome.
    pub fn finished_step(&self, observation: Observation) -> Step {
        Step {
            observation,
            reward: 0.0,
            outcome: Some(self.final_outcome()),
        }
    }

    /// Ends a step: `reward` is added to the return and `outcome` kept; the step to return.
    pub fn step(
        &mut self,
        observation: Observation,
        reward: f64,
        outcome: Option<Outcome>,
    ) -> Step {
        self.outcome = outcome;
        self.episode_return += reward;
        Step {
            observation,
            reward: reward as f32,
            outcome,
        }
    }
}
