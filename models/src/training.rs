//! The bookkeeping of a DQN training run besides its networks: the success rates of its
//! training curves ([`OutcomeRates`]) and its summary (`summary.json`, [`TrainSummary`]).

use std::collections::VecDeque;
use std::path::Path;

use serde::Serialize;

use crate::dqn::{EpisodeRecord, OutcomeName, TrainState};

/// Episodes the success rates on the training curves are averaged over.
pub const RATE_WINDOW: usize = 100;

/// The outcomes of the newest [`RATE_WINDOW`] training episodes, for the success rates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OutcomeRates {
    recent: VecDeque<OutcomeName>,
}

impl OutcomeRates {
    pub fn new() -> Self {
        OutcomeRates {
            recent: VecDeque::with_capacity(RATE_WINDOW),
        }
    }

    /// Adds a finished episode's outcome (the oldest drops out of a full window).
    pub fn push(&mut self, outcome: OutcomeName) {
        if self.recent.len() == RATE_WINDOW {
            self.recent.pop_front();
        }
        self.recent.push_back(outcome);
    }

    /// Episodes in the window.
    pub fn len(&self) -> usize {
        self.recent.len()
    }

    pub fn is_empty(&self) -> bool {
        self.recent.is_empty()
    }

    /// The share of the window's episodes that ended in `outcome` (0 without any).
    pub fn rate(&self, outcome: OutcomeName) -> f64 {
        if self.recent.is_empty() {
            return 0.0;
        }
        self.recent.iter().filter(|&&o| o == outcome).count() as f64 / self.recent.len() as f64
    }

    /// The rates the training curves show, by name: reached, crashed, time over.
    pub fn curves(&self) -> [(&'static str, f64); 3] {
        [
            ("reached", self.rate(OutcomeName::Reached)),
            ("crashed", self.rate(OutcomeName::Crashed)),
            ("time_over", self.rate(OutcomeName::TimeOver)),
        ]
    }

    /// The curves' rates after each episode of `history`, in order (the curves of a run
    /// as it went, e.g. the earlier part of a resumed one).
    pub fn along(history: &[EpisodeRecord]) -> Vec<[(&'static str, f64); 3]> {
        let mut rates = OutcomeRates::new();
        history
            .iter()
            .map(|record| {
                rates.push(record.outcome);
                rates.curves()
            })
            .collect()
    }
}

/// `summary.json` of an agent folder.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrainSummary {
    pub seed: u64,
    pub steps: u64,
    pub updates: u64,
    pub episodes: u64,
    pub resumed_at: Vec<u64>,
    /// Of this invocation (a resumed run counts from where it resumed).
    pub wall_seconds: f64,
    pub steps_per_second: f64,
    /// Outcome fractions over the last (up to) 1,000 training episodes (with exploration).
    pub last_episodes: usize,
    pub reached: f64,
    pub crashed: f64,
    pub off_road: f64,
    pub time_over: f64,
    /// With `[agent.validation]`: the transitions of the checkpoint chosen as the agent
    /// (its files are that checkpoint's; the figures above are of the whole run).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub chosen_steps: Option<u64>,
}

impl TrainSummary {
    /// The summary of a run that has reached `state`, after `wall_seconds` of this
    /// invocation, which started at `first_step` transitions.
    pub fn new(state: &TrainState, first_step: u64, wall_seconds: f64) -> Self {
        let tail = &state.episode_history[state.episode_history.len().saturating_sub(1000)..];
        let frac = |o: OutcomeName| {
            if tail.is_empty() {
                0.0
            } else {
                tail.iter().filter(|e| e.outcome == o).count() as f64 / tail.len() as f64
            }
        };
        TrainSummary {
            seed: state.seed,
            steps: state.steps,
            updates: state.updates,
            episodes: state.episodes,
            resumed_at: state.resumed_at.clone(),
            wall_seconds,
            steps_per_second: (state.steps - first_step) as f64 / wall_seconds.max(1e-9),
            last_episodes: tail.len(),
            reached: frac(OutcomeName::Reached),
            crashed: frac(OutcomeName::Crashed),
            off_road: frac(OutcomeName::OffRoad),
            time_over: frac(OutcomeName::TimeOver),
            chosen_steps: None,
        }
    }

    /// What the command says of the agent written to `dest`.
    pub fn describe(&self, dest: &Path) -> String {
        format!(
            "agent: {}\n  {} transitions, {} gradient steps, {} episodes in {:.0} s ({:.0} transitions/s)\n  \
             last {} training episodes (with exploration): reached {:.1} %, crashed {:.1} %, off road {:.1} %, \
             time over {:.1} %",
            dest.display(),
            self.steps,
            self.updates,
            self.episodes,
            self.wall_seconds,
            self.steps_per_second,
            self.last_episodes,
            100.0 * self.reached,
            100.0 * self.crashed,
            100.0 * self.off_road,
            100.0 * self.time_over,
        )
    }
}
