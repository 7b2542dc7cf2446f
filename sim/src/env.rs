//! The interface between driving tasks and the agents that learn them.
//!
//! A task is an [`Env`]: it hands out [`Observation`]s (bird's-eye layers plus scalar
//! inputs), takes a discrete action index, and says when an episode ends and how.
//! The `models` crate trains against this trait only, so every task in [`crate`] and
//! every recorded-log replay can be driven by the same agents.

/// Shape of the observations an environment produces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ObservationSpec {
    /// Channels of the layer stack: layers per frame × stacked frames.
    pub channels: usize,
    pub height: usize,
    pub width: usize,
    /// Non-visual inputs (speed, target speed, aggressiveness, last action, ...).
    pub scalars: usize,
}

impl ObservationSpec {
    /// Bytes of one layer stack.
    pub fn layer_len(&self) -> usize {
        self.channels * self.height * self.width
    }
}

/// One observation. Layers are `u8` intensities (0 = empty, 255 = full), channel-major
/// (`[channels, height, width]`, row 0 = farthest ahead), so a replay buffer stays small;
/// networks scale them to [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    pub layers: Vec<u8>,
    /// Already normalised to roughly [-1, 1].
    pub scalars: Vec<f32>,
}

/// How an episode ended.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// The goal was reached (the exit, the route's end): the only success.
    Reached,
    Crashed,
    OffRoad,
    TimeOver,
}

impl Outcome {
    /// The outcome's name in written files, the one serde writes (`time_over`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Outcome::Reached => "reached",
            Outcome::Crashed => "crashed",
            Outcome::OffRoad => "off_road",
            Outcome::TimeOver => "time_over",
        }
    }
}

/// What one [`Env::step`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    pub observation: Observation,
    pub reward: f32,
    /// `Some` when the episode ended with this step.
    pub outcome: Option<Outcome>,
}

/// A driving task as an episodic environment with discrete actions.
pub trait Env: Send {
    fn observation_spec(&self) -> ObservationSpec;
    fn action_count(&self) -> usize;
    /// Human-readable action names, `action_count()` of them.
    fn action_names(&self) -> &'static [&'static str];
    /// Starts a new episode; everything random in it is drawn from `seed`.
    fn reset(&mut self, seed: u64) -> Observation;
    /// Advances one policy step. Calling it after an episode ended is a logic error and
    /// returns the final step again with zero reward.
    fn step(&mut self, action: usize) -> Step;
}

/// Several environments of one task (one per map or ring) as one: each episode is played
/// in the environment its seed picks (`seed % n`), so training meets all of them. They
/// must agree on observations and actions ([`Rotating::new`] checks).
#[derive(Debug)]
pub struct Rotating<E> {
    envs: Vec<E>,
    current: usize,
}

impl<E: Env> Rotating<E> {
    /// The environments as one; None when there is none or when their observation specs
    /// or action counts differ.
    pub fn new(envs: Vec<E>) -> Option<Rotating<E>> {
        let first = envs.first()?;
        let (spec, actions) = (first.observation_spec(), first.action_count());
        envs.iter()
            .all(|e| e.observation_spec() == spec && e.action_count() == actions)
            .then_some(Rotating { envs, current: 0 })
    }

    /// The environment of the current (or last) episode.
    pub fn current(&self) -> usize {
        self.current
    }
}

impl<E: Env> Env for Rotating<E> {
    fn observation_spec(&self) -> ObservationSpec {
        self.envs[self.current].observation_spec()
    }

    fn action_count(&self) -> usize {
        self.envs[self.current].action_count()
    }

    fn action_names(&self) -> &'static [&'static str] {
        self.envs[self.current].action_names()
    }

    fn reset(&mut self, seed: u64) -> Observation {
        self.current = (seed % self.envs.len() as u64) as usize;
        self.envs[self.current].reset(seed)
    }

    fn step(&mut self, action: usize) -> Step {
        self.envs[self.current].step(action)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// An environment that observes its own id in one scalar.
    struct Tagged(u8, usize);

    impl Env for Tagged {
        fn observation_spec(&self) -> ObservationSpec {
            ObservationSpec {
                channels: 0,
                height: 0,
                width: 0,
                scalars: 1,
            }
        }
        fn action_count(&self) -> usize {
            self.1
        }
        fn action_names(&self) -> &'static [&'static str] {
            &["a", "b"]
        }
        fn reset(&mut self, _seed: u64) -> Observation {
            Observation {
                layers: Vec::new(),
                scalars: vec![f32::from(self.0)],
            }
        }
        fn step(&mut self, _action: usize) -> Step {
            Step {
                observation: self.reset(0),
                reward: f32::from(self.0),
                outcome: None,
            }
        }
    }

    #[test]
    fn rotating_plays_each_episode_in_the_environment_its_seed_picks() {
        let mut env = Rotating::new(vec![Tagged(0, 2), Tagged(1, 2), Tagged(2, 2)]).unwrap();
        for seed in [0u64, 1, 2, 3, 7, 11, 1_000_000_005] {
            let first = env.reset(seed);
            let expected = (seed % 3) as f32;
            assert_eq!(first.scalars, [expected]);
            assert_eq!(env.current() as f32, expected);
            // The episode stays in that environment until the next reset.
            assert_eq!(env.step(0).reward, expected);
            assert_eq!(env.step(1).reward, expected);
        }
        assert!(
            Rotating::new(vec![Tagged(0, 2), Tagged(1, 3)]).is_none(),
            "actions differ"
        );
        assert!(Rotating::<Tagged>::new(Vec::new()).is_none());
    }

    #[test]
    fn outcome_names_are_the_serde_names() {
        for o in [
            Outcome::Reached,
            Outcome::Crashed,
            Outcome::OffRoad,
            Outcome::TimeOver,
        ] {
            assert_eq!(
                serde_json::to_value(o).unwrap(),
                serde_json::json!(o.name())
            );
        }
    }
}
