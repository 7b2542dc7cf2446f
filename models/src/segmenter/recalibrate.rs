//! Batch-norm recalibration ("precise BN": Wu and Johnson, *Rethinking "Batch" in
//! BatchNorm*, 2021; detectron2's `update_bn_stats`).
//!
//! A batch norm trains on the statistics of each batch and keeps, for inference, running
//! statistics moved towards each batch's by a momentum of 0.1: an average over roughly the
//! last ten batches, and with batches of 4 crops that is an estimate from 40 crops, weighted
//! towards the last few. Those statistics are noisy and lag the weights, and inference
//! normalises every image with them. Recalibration replaces them by the plain average of the
//! batch statistics of many training batches drawn with the run's own augmentation, computed
//! with the weights as they are: what inference should use. The weights are not changed.

use burn::module::Module;
use burn::nn::BatchNorm;
use burn::tensor::Device;
use sim::seed::derive_seed;

use super::data::{Source, epoch_draws, load_batch};
use super::error::Result;
use super::infer::normalise;
use super::model::PspNet;
use super::recipe::TrainingConfig;

/// Seed stage of the recalibration batches' draws (apart from the training draws, so
/// recalibrating changes no training step).
const STAGE_RECALIBRATION: u64 = 0x5e6_0004;

/// Recomputes every batch norm's running statistics of `model` as the average of the batch
/// statistics of `batches` batches of `config.batch_size` training crops, drawn from
/// `sources` as `config` draws them (weights, resizing, scale, crop, flip) with draw set
/// `pass` (a run uses its epoch; any `pass` gives its own batches, the same each time).
/// Convolutions run as in training (`config.bf16_convolutions`).
///
/// `model` must be on an autodiff device with its batch norms in training mode (a model
/// being trained, or one loaded onto `device.autodiff()`), so that a forward pass
/// normalises with the batch's statistics and moves the running ones; on another device
/// nothing changes. Returns the model and the number of crops seen (fewer than asked only
/// when the sources are empty).
pub fn recalibrate_batch_norms(
    model: PspNet,
    config: &TrainingConfig,
    sources: &[Source],
    batches: usize,
    pass: u64,
    device: &Device,
) -> Result<(PspNet, usize)> {
    let seed = derive_seed(config.seed, STAGE_RECALIBRATION, 0);
    let draws = epoch_draws(sources, batches * config.batch_size, seed, pass);
    let augment = config.augment();
    // Without gradients no graph is recorded; the batch norms still normalise with the
    // batch's statistics and move the running ones.
    let mut model = model.set_require_grad(false);
    let mut momenta = Vec::new();
    model.visit_batch_norms(&mut |norm| momenta.push(norm.momentum));
    let _bf16 = config
        .bf16_convolutions
        .then(crate::layers::Bf16Convolutions::enter);
    for (k, chunk) in draws.chunks(config.batch_size).enumerate() {
        // Momentum 1 / (k + 1) makes the running statistics the mean of the k + 1 batches so far.
        set_momentum(&mut model, 1.0 / (k + 1) as f64);
        let batch = load_batch(sources, chunk, k * config.batch_size, &augment, seed, pass)?;
        let images: Vec<&image::RgbImage> = batch.iter().map(|(_, s)| &s.image).collect();
        let input = normalise(&images, &config.model, device);
        // Only the statistics are wanted: the output is dropped at once.
        drop(model.forward(input));
    }
    let mut restored = momenta.into_iter();
    model.visit_batch_norms(&mut |norm: &mut BatchNorm| {
        if let Some(momentum) = restored.next() {
            norm.momentum = momentum;
        }
    });
    Ok((model.set_require_grad(true), draws.len()))
}

fn set_momentum(model: &mut PspNet, momentum: f64) {
    model.visit_batch_norms(&mut |norm| norm.momentum = momentum);
}

#[cfg(test)]
mod tests {
    use burn::tensor::{Distribution, Tensor};

    use super::*;
    use crate::segmenter::model::PspNetConfig;

    fn running_means(model: &mut PspNet) -> Vec<Vec<f32>> {
        let mut means = Vec::new();
        model.visit_batch_norms(&mut |norm| {
            let mean = norm.running_mean.value_sync().into_data();
            means.push(mean.try_to_vec::<f32>().unwrap_or_default());
        });
        means
    }

    /// With momentum 1 / (k + 1), the running means after three batches are the plain
    /// average of each batch's own means (a batch's, read with momentum 1 from a fresh copy).
    #[test]
    fn recalibrated_statistics_are_the_average_of_the_batches() {
        let device = Device::flex().autodiff();
        let config = PspNetConfig::new()
            .with_width(0.125)
            .with_blocks(vec![1, 1, 1, 1])
            .with_psp_channels(16)
            .with_bins(vec![2]);
        // Separate networks with the same weights (clones would share running statistics).
        let fresh = || {
            config
                .init_seeded(&device, 3)
                .unwrap_or_else(|e| panic!("{e}"))
        };
        let batches: Vec<Tensor<4>> = (0..3)
            .map(|i| {
                let shift = Distribution::Normal(f64::from(i), 1.0 + f64::from(i));
                Tensor::<4>::random([2, 3, 32, 32], shift, &device)
            })
            .collect();
        let each: Vec<Vec<Vec<f32>>> = batches
            .iter()
            .map(|batch| {
                let mut model = fresh();
                set_momentum(&mut model, 1.0);
                drop(model.forward(batch.clone()));
                running_means(&mut model)
            })
            .collect();
        let mut model = fresh();
        for (k, batch) in batches.into_iter().enumerate() {
            set_momentum(&mut model, 1.0 / (k + 1) as f64);
            drop(model.forward(batch));
        }
        let got = running_means(&mut model);
        assert!(got.len() > 5, "every batch norm visited: {}", got.len());
        for (layer, means) in got.iter().enumerate() {
            for (c, &m) in means.iter().enumerate() {
                let average = each.iter().map(|e| e[layer][c]).sum::<f32>() / 3.0;
                assert!(
                    (m - average).abs() < 1e-4 * (1.0 + average.abs()),
                    "layer {layer}: {m} against {average}"
                );
            }
        }
    }
}
