//! Behaviour cloning: a classifier of the driver's go / wait decision on the same inputs as
//! the agent (bird's-eye layer stack and scalars), the baseline an agent judged against
//! human decisions must beat. The network is a [`QNetwork`] with two outputs (go, wait)
//! read as logits; cross-entropy; Adam; shuffled mini-batches from a seeded generator.

use burn::module::Module;
use burn::optim::GradientsParams;
use burn::tensor::activation::log_softmax;
use burn::tensor::{Device, Int, Tensor, TensorData};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::{Observation, ObservationSpec};

use crate::error::ModelError;
use crate::qnet::{QNetwork, QNetworkConfig, observations_to_tensors, tensor_values};

/// Output index of "go"; "wait" is the other.
pub const GO: usize = 0;

/// Every setting of a behaviour-cloning run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BcConfig {
    pub network: QNetworkConfig,
    pub epochs: usize,
    pub batch_size: usize,
    pub learning_rate: f64,
}

impl Default for BcConfig {
    fn default() -> Self {
        BcConfig {
            network: QNetworkConfig::default(),
            epochs: 3,
            batch_size: 32,
            learning_rate: 1e-4,
        }
    }
}

/// What a run did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BcSummary {
    pub samples: usize,
    pub go_share: f64,
    pub steps: usize,
    /// Mean cross-entropy of each epoch.
    pub epoch_loss: Vec<f64>,
    /// Share of the training samples classified right after training.
    pub train_accuracy: f64,
}

/// Trains a go / wait classifier on `observations` (with `go[i]` the driver's decision).
pub fn train(
    observations: &[Observation],
    go: &[bool],
    spec: &ObservationSpec,
    config: &BcConfig,
    seed: u64,
    device: &Device,
) -> Result<(QNetwork, BcSummary), ModelError> {
    if observations.len() != go.len() || observations.is_empty() || config.batch_size == 0 {
        return Err(ModelError::Config(format!(
            "{} observations and {} labels (batch size {}): need as many of each, at least one",
            observations.len(),
            go.len(),
            config.batch_size
        )));
    }
    let train_device = device.clone().autodiff();
    let mut network = config
        .network
        .init(spec, 2, seed, &train_device)
        .map_err(ModelError::Config)?;
    let mut optimizer = crate::optim::adam(1e-5, None);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut order: Vec<usize> = (0..observations.len()).collect();
    let mut epoch_loss = Vec::new();
    let mut steps = 0;
    for _ in 0..config.epochs {
        order.shuffle(&mut rng);
        let mut total = 0.0;
        let mut batches = 0;
        for batch in order.chunks(config.batch_size) {
            let refs: Vec<&Observation> = batch.iter().map(|&i| &observations[i]).collect();
            let (layers, scalars) = observations_to_tensors(&refs, spec, &train_device);
            let targets: Vec<i64> = batch
                .iter()
                .map(|&i| if go[i] { GO as i64 } else { 1 - GO as i64 })
                .collect();
            let targets = Tensor::<2, Int>::from_data(
                TensorData::new(targets, [batch.len(), 1]),
                &train_device,
            );
            let logp = log_softmax(network.forward(layers, scalars), 1);
            let loss = logp.gather(1, targets).mean().neg();
            total += f64::from(
                tensor_values(loss.clone())
                    .first()
                    .copied()
                    .unwrap_or(f32::NAN),
            );
            batches += 1;
            let gradients = GradientsParams::from_grads(loss.backward(), &network);
            network = optimizer.step(config.learning_rate, network, gradients);
            steps += 1;
        }
        epoch_loss.push(total / f64::from(batches.max(1)));
    }
    let network = network.valid();
    let right = predict(&network, observations, spec, device)
        .iter()
        .zip(go)
        .filter(|(p, g)| p == g)
        .count();
    let summary = BcSummary {
        samples: observations.len(),
        go_share: go.iter().filter(|g| **g).count() as f64 / go.len() as f64,
        steps,
        epoch_loss,
        train_accuracy: right as f64 / observations.len() as f64,
    };
    Ok((network, summary))
}

/// The classifier's decisions (true = go), in batches of 64.
pub fn predict(
    network: &QNetwork,
    observations: &[Observation],
    spec: &ObservationSpec,
    device: &Device,
) -> Vec<bool> {
    let mut out = Vec::with_capacity(observations.len());
    for chunk in observations.chunks(64) {
        let refs: Vec<&Observation> = chunk.iter().collect();
        let (layers, scalars) = observations_to_tensors(&refs, spec, device);
        let logits = tensor_values(network.forward(layers, scalars));
        out.extend(logits.chunks_exact(2).map(|l| l[GO] >= l[1 - GO]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rule the inputs show plainly (go when the first scalar is high) is learnt.
    #[test]
    fn learns_a_rule_its_inputs_show() -> Result<(), ModelError> {
        let spec = ObservationSpec {
            channels: 1,
            height: 4,
            width: 4,
            scalars: 2,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut observations = Vec::new();
        let mut go = Vec::new();
        for i in 0..256 {
            let v = rand::Rng::random::<f32>(&mut rng);
            observations.push(Observation {
                layers: vec![(i % 7) as u8 * 30; 16],
                scalars: vec![v, 0.5],
            });
            go.push(v > 0.5);
        }
        let config = BcConfig {
            network: QNetworkConfig {
                convolutions: Vec::new(),
                hidden: vec![32],
                ..QNetworkConfig::default()
            },
            epochs: 30,
            batch_size: 32,
            learning_rate: 3e-3,
        };
        let device = crate::cpu_device();
        let (_, summary) = train(&observations, &go, &spec, &config, 3, &device)?;
        assert!(summary.train_accuracy > 0.9, "{summary:?}");
        assert!(
            summary.epoch_loss.last() < summary.epoch_loss.first(),
            "{summary:?}"
        );
        Ok(())
    }
}
