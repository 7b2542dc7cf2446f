//! The episode runner every task shares: a task says what differs ([`Driving`]: its actions,
//! how an episode starts, what one decision does and earns, what the agent observes), and
//! the runner is the [`Env`] of every such task, written once: action tables, the steps
//! after an episode ended or before any began, and the episode's bookkeeping of each step.

use super::episode::Episode;
use crate::env::{Env, Observation, ObservationSpec, Outcome, Step};
use crate::eval::report::TaskSummary;

/// A task's actions, as `actions!` declares them.
pub trait ActionSet: Copy + Send + 'static {
    /// The serde names, in index order.
    const NAMES: &'static [&'static str];

    /// What an index out of range means.
    const FALLBACK: Self;

    /// The action of index `i`, if any.
    fn from_index(i: usize) -> Option<Self>;
}

/// What a task does in its episodes; every `Driving` is an [`Env`] through the runner.
pub trait Driving: Send {
    /// The task's actions.
    type Action: ActionSet;

    /// The figures of one episode (outcome, return, the task's metrics).
    type Summary: TaskSummary;

    /// The shape of the task's observations.
    fn spec(&self) -> ObservationSpec;

    /// The current (or last) episode's bookkeeping.
    fn episode(&self) -> &Episode;

    /// The same, to change.
    fn episode_mut(&mut self) -> &mut Episode;

    /// Starts a new episode; everything random in it is drawn from `seed`, and the
    /// episode's bookkeeping starts at the ego's place.
    fn begin(&mut self, seed: u64);

    /// One decision of a running episode: the task's steps under `action` and their
    /// bookkeeping; its reward and how the episode ended (None while it runs). None, with
    /// nothing changed, when no episode has begun.
    fn decide(&mut self, action: Self::Action) -> Option<(f64, Option<Outcome>)>;

    /// What the agent observes now.
    fn observe(&self) -> Observation;

    /// The figures of the current (normally just finished) episode.
    fn summary(&self) -> Self::Summary;
}

impl<D: Driving> Env for D {
    fn observation_spec(&self) -> ObservationSpec {
        self.spec()
    }

    fn action_count(&self) -> usize {
        D::Action::NAMES.len()
    }

    fn action_names(&self) -> &'static [&'static str] {
        D::Action::NAMES
    }

    fn reset(&mut self, seed: u64) -> Observation {
        self.begin(seed);
        self.observe()
    }

    fn step(&mut self, action: usize) -> Step {
        let action = D::Action::from_index(action).unwrap_or(D::Action::FALLBACK);
        let decided = if self.episode().ended() {
            None
        } else {
            self.decide(action)
        };
        let observation = self.observe();
        match decided {
            Some((reward, outcome)) => self.episode_mut().step(observation, reward, outcome),
            // After the end, or never reset.
            None => self.episode().finished_step(observation),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    actions! {
        /// Two test actions.
        enum Toy {
            Stay = 0 => "stay",
            Go = 1 => "go",
        }
        fallback Stay;
    }

    #[derive(Clone, serde::Serialize)]
    struct Walked(Outcome);

    impl TaskSummary for Walked {
        fn outcome(&self) -> Outcome {
            self.0
        }
        fn episode_return(&self) -> f64 {
            0.0
        }
        fn metrics(&self) -> Vec<(&'static str, f64)> {
            Vec::new()
        }
    }

    /// Reaches the goal after three `Go`s; `Stay` earns nothing.
    #[derive(Default)]
    struct Walk {
        episode: Episode,
        started: bool,
        at: usize,
    }

    impl Driving for Walk {
        type Action = Toy;
        type Summary = Walked;

        fn spec(&self) -> ObservationSpec {
            ObservationSpec {
                channels: 0,
                height: 0,
                width: 0,
                scalars: 1,
            }
        }
        episode_in_field!();
        fn begin(&mut self, _: u64) {
            self.started = true;
            self.at = 0;
            self.episode.reset(None);
        }
        fn decide(&mut self, action: Toy) -> Option<(f64, Option<Outcome>)> {
            if !self.started {
                return None;
            }
            self.episode.steps += 1;
            if action == Toy::Go {
                self.at += 1;
            }
            let reached = (self.at == 3).then_some(Outcome::Reached);
            Some((f64::from(u8::from(action == Toy::Go)), reached))
        }
        fn observe(&self) -> Observation {
            Observation {
                layers: Vec::new(),
                scalars: vec![self.at as f32],
            }
        }
        fn summary(&self) -> Walked {
            Walked(self.episode.final_outcome())
        }
    }

    #[test]
    fn the_runner_keeps_the_episode_and_ends_it_once() {
        let mut walk = Walk::default();
        assert_eq!(walk.action_names(), &["stay", "go"]);
        let before = walk.step(1);
        assert_eq!(before.outcome, Some(Outcome::TimeOver), "no episode yet");
        assert_eq!(walk.reset(0).scalars, vec![0.0]);
        assert_eq!(walk.step(7).reward, 0.0, "out of range: the fallback");
        for _ in 0..2 {
            assert_eq!(walk.step(1).outcome, None);
        }
        let last = walk.step(1);
        assert_eq!(last.outcome, Some(Outcome::Reached));
        assert_eq!(walk.episode().episode_return, 3.0);
        assert_eq!(walk.episode().steps, 4);
        let after = walk.step(1);
        assert_eq!((after.reward, after.outcome), (0.0, Some(Outcome::Reached)));
        assert_eq!(walk.episode().episode_return, 3.0);
    }
}
