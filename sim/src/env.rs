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

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::Outcome;

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
