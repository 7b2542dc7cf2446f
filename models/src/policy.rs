//! A trained Q-network as a [`Policy`] of the evaluation harness: greedy over the Q-values
//! of one batched forward pass per decision. It reads only the observations (never the
//! privileged state the rule-based baselines use).

use burn::tensor::Device;
use sim::baselines::{Policy, PolicyInput};
use sim::{Observation, ObservationSpec};

use crate::dqn::greedy_action;
use crate::qnet::{QNetwork, observations_to_tensors, tensor_values};

#[derive(Debug, Clone)]
pub struct QPolicy {
    network: QNetwork,
    spec: ObservationSpec,
    actions: usize,
    device: Device,
}

impl QPolicy {
    /// `network` in inference mode (see [`crate::dqn::load_network`]).
    pub fn new(network: QNetwork, spec: ObservationSpec, actions: usize, device: Device) -> Self {
        QPolicy {
            network,
            spec,
            actions,
            device,
        }
    }

    /// Q-values `[observations, actions]`, row-major.
    pub fn q_values(&self, observations: &[&Observation]) -> Vec<f32> {
        if observations.is_empty() {
            return Vec::new();
        }
        let (layers, scalars) = observations_to_tensors(observations, &self.spec, &self.device);
        tensor_values(self.network.forward(layers, scalars))
    }

    pub fn actions(&self) -> usize {
        self.actions
    }
}

impl Policy for QPolicy {
    fn act(&mut self, inputs: &[PolicyInput<'_>], actions: &mut Vec<usize>) {
        let observations: Vec<&Observation> = inputs.iter().map(|i| i.observation).collect();
        let q = self.q_values(&observations);
        actions.clear();
        actions.extend(q.chunks(self.actions.max(1)).map(greedy_action));
    }
}

impl<E> sim::tasks::TaskPolicy<E> for QPolicy {
    fn act(&mut self, _: &[&E], observations: &[&Observation], actions: &mut Vec<usize>) {
        let q = self.q_values(observations);
        actions.clear();
        actions.extend(q.chunks(self.actions.max(1)).map(greedy_action));
    }
}
