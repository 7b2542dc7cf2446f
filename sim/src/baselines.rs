//! Policies for the roundabout-insertion task, on the inputs a simulated episode or a
//! recorded log gives them, and the baselines every agent is reported next to.
//!
//! A [`Policy`] decides for a batch of episodes at once (one input per running episode of
//! its batch), so a learned policy can run its network on the whole batch in one forward
//! pass. Learned agents must only read [`PolicyInput::observation`]; the privileged
//! [`PolicyInput::state`] is there for the rule-based baselines. The evaluation harness runs
//! a [`Policy`] as a [`TaskPolicy`] through [`InsertionPolicy`].

use serde::{Deserialize, Serialize};

use crate::env::Observation;
use crate::seed::derive_seed;
use crate::tasks::{Action, InsertionState, RoundaboutInsertion, TaskPolicy};

/// What a policy sees at one decision of one episode.
#[derive(Debug, Clone, Copy)]
pub struct PolicyInput<'a> {
    /// The episode's place in the policy's batch (stable over the episode).
    pub slot: usize,
    /// The seed the episode was reset with (a stochastic policy draws from it, so its
    /// choices do not depend on which worker runs the episode).
    pub episode_seed: u64,
    /// Steps taken so far in the episode.
    pub step: usize,
    pub observation: &'a Observation,
    pub state: &'a InsertionState,
}

/// A decision rule over batches of episodes. One instance serves one worker at a time
/// (made by the factory given to [`crate::eval::evaluate_episodes`]), hence `Send` but not
/// `Sync`.
pub trait Policy: Send {
    /// One action index per input, in the same order, into `actions` (cleared first).
    fn act(&mut self, inputs: &[PolicyInput<'_>], actions: &mut Vec<usize>);

    /// Whether the policy reads observations; when it does not, the harness skips
    /// rendering them (the episodes are the same either way).
    fn needs_observation(&self) -> bool {
        true
    }
}

/// The baselines of the Parma study, the constant "never go" policy, and a critical-gap rule.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Baseline {
    /// Enter when the nearest circulating vehicle is farther than this many metres (until
    /// entered: Not Permitted; after: Permitted).
    Rule {
        threshold_m: f64,
    },
    AlwaysPermitted,
    AlwaysNotPermitted,
    /// Uniform over the actions, drawn from (episode seed, step).
    Random,
    /// Gap acceptance as drivers do it: go when every circulating vehicle is at least
    /// `seconds` (a critical gap, e.g. a calibration's) away in time from the ego's merge
    /// point, beyond the time the ego needs to reach its yield line at its speed.
    CriticalGap {
        seconds: f64,
    },
}

impl Baseline {
    /// The study's set: rules at 25 / 20 / 15 / 10 m, always Permitted, random, and
    /// always Not Permitted.
    pub const STANDARD: [Baseline; 7] = [
        Baseline::Rule { threshold_m: 25.0 },
        Baseline::Rule { threshold_m: 20.0 },
        Baseline::Rule { threshold_m: 15.0 },
        Baseline::Rule { threshold_m: 10.0 },
        Baseline::AlwaysPermitted,
        Baseline::Random,
        Baseline::AlwaysNotPermitted,
    ];

    pub fn name(&self) -> String {
        match self {
            Baseline::Rule { threshold_m } => format!("rule {threshold_m} m"),
            Baseline::AlwaysPermitted => "always permitted".into(),
            Baseline::AlwaysNotPermitted => "always not permitted".into(),
            Baseline::Random => "random".into(),
            Baseline::CriticalGap { seconds } => format!("critical gap {seconds:.2} s"),
        }
    }

    /// The action for one input.
    pub fn decide(&self, input: &PolicyInput<'_>) -> Action {
        match *self {
            Baseline::Rule { threshold_m } => {
                if input.state.ego_entered || input.state.nearest_circulating_m > threshold_m {
                    Action::Permitted
                } else {
                    Action::NotPermitted
                }
            }
            Baseline::CriticalGap { seconds } => {
                let s = input.state;
                let to_line_s = s.to_yield_line_m.max(0.0) / s.speed_mps.max(2.0);
                if s.ego_entered || s.merge_lag_s.is_none_or(|lag| lag >= to_line_s + seconds) {
                    Action::Permitted
                } else {
                    Action::NotPermitted
                }
            }
            Baseline::AlwaysPermitted => Action::Permitted,
            Baseline::AlwaysNotPermitted => Action::NotPermitted,
            Baseline::Random => {
                let draw = derive_seed(input.episode_seed, RANDOM_POLICY_STAGE, input.step as u64);
                Action::ALL[(draw % Action::ALL.len() as u64) as usize]
            }
        }
    }
}

/// Seed stage of the random baseline's draws.
const RANDOM_POLICY_STAGE: u64 = 0x5241_4e44;

impl Policy for Baseline {
    fn act(&mut self, inputs: &[PolicyInput<'_>], actions: &mut Vec<usize>) {
        actions.clear();
        actions.extend(inputs.iter().map(|i| self.decide(i) as usize));
    }

    fn needs_observation(&self) -> bool {
        false
    }
}

/// A [`Policy`] as a [`TaskPolicy`] of the insertion environments: each decision gets the
/// episode's input (its place in the batch, seed, decisions so far, observation and state).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsertionPolicy<P>(pub P);

impl<P: Policy> TaskPolicy<RoundaboutInsertion> for InsertionPolicy<P> {
    fn act(
        &mut self,
        envs: &[&RoundaboutInsertion],
        observations: &[&Observation],
        actions: &mut Vec<usize>,
    ) {
        let slots: Vec<usize> = (0..envs.len()).collect();
        self.act_in_slots(&slots, envs, observations, actions);
    }

    fn act_in_slots(
        &mut self,
        slots: &[usize],
        envs: &[&RoundaboutInsertion],
        observations: &[&Observation],
        actions: &mut Vec<usize>,
    ) {
        let states: Vec<InsertionState> = envs.iter().map(|env| env.state()).collect();
        let inputs: Vec<PolicyInput<'_>> = slots
            .iter()
            .zip(envs)
            .zip(observations.iter().zip(&states))
            .map(|((&slot, env), (observation, state))| PolicyInput {
                slot,
                episode_seed: env.episode_seed(),
                step: env.decisions(),
                observation,
                state,
            })
            .collect();
        self.0.act(&inputs, actions);
    }

    fn needs_observation(&self) -> bool {
        self.0.needs_observation()
    }
}
