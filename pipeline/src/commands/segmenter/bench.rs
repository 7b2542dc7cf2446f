//! `pipeline segmenter bench`: inference latency and throughput, training-step time,
//! parameters and FLOPs of a model at a stated size, batch and thread count.
//!
//! Inputs are fixed pseudo-random images (ChaCha, seed 0): the weights and the pixel values
//! do not change the work a convolutional network does. Each timing is a median over
//! `--iterations` runs after `--warmup` runs; the device is synchronised inside the timed
//! region, so the figure includes all the work.

use std::time::Instant;

use anyhow::Result;
use burn::module::Module;
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor, TensorData};
use clap::Args;
use models::segmenter::loss::{LabelRef, LossTargets, segmentation_dice_loss};
use models::segmenter::{PspNet, PspNetConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::arch_args::ArchArgs;
use super::{Context, check_size, open_model, with_threads};
use crate::error::CliError;
use crate::ui::plural;

#[derive(Debug, Args)]
pub struct BenchArgs {
    /// A trained model [default: an untrained network of the options below].
    #[arg(long, value_name = "DIR")]
    pub model: Option<std::path::PathBuf>,

    #[command(flatten)]
    pub arch: ArchArgs,

    /// Input height and width.
    #[arg(long, value_name = "PX", default_value_t = 256)]
    pub size: usize,

    #[arg(long, default_value_t = 1)]
    pub batch: usize,

    /// Threads of burn's CPU backend.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,

    /// Timed runs (the median is reported).
    #[arg(long, default_value_t = 20)]
    pub iterations: usize,

    /// Untimed runs first.
    #[arg(long, default_value_t = 3)]
    pub warmup: usize,

    /// Also time this many training steps (forward, backward, Adam) at --train-batch.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub train_steps: usize,

    /// Batch of the training steps.
    #[arg(long, value_name = "N", default_value_t = 8)]
    pub train_batch: usize,

    /// Run the training steps' convolutions in bfloat16 (`--device libtorch` only).
    #[arg(long)]
    pub bf16_convolutions: bool,

    /// Print the figures as JSON.
    #[arg(long)]
    pub json: bool,
}

/// The figures of a benchmark run.
#[derive(Debug, Serialize)]
pub struct BenchReport {
    pub config: PspNetConfig,
    pub size: usize,
    pub batch: usize,
    pub threads: usize,
    /// Every tensor of the record: weights, biases and the batch-norm running statistics.
    pub parameters: usize,
    /// Convolution FLOPs (2 × multiply-accumulates) of one image's forward pass.
    pub gflops_per_image: f64,
    pub inference_ms: Timing,
    pub images_per_second: f64,
    pub train_batch: usize,
    pub train_step_ms: Option<Timing>,
    /// Whether the training steps' convolutions ran in bfloat16.
    pub bf16_convolutions: bool,
}

#[derive(Debug, Serialize)]
pub struct Timing {
    pub median: f64,
    pub min: f64,
    pub max: f64,
    pub runs: usize,
}

fn timing(mut ms: Vec<f64>) -> Timing {
    ms.sort_by(f64::total_cmp);
    let n = ms.len();
    let median = if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        ms[n / 2]
    } else {
        (ms[n / 2 - 1] + ms[n / 2]) / 2.0
    };
    Timing {
        median,
        min: ms.first().copied().unwrap_or(f64::NAN),
        max: ms.last().copied().unwrap_or(f64::NAN),
        runs: n,
    }
}

/// Fixed pseudo-random normalised images `[batch, 3, size, size]`.
fn images(batch: usize, size: usize, device: &Device) -> Tensor<4> {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let values: Vec<f32> = (0..batch * 3 * size * size)
        .map(|_| rng.random_range(-2.0..2.0))
        .collect();
    Tensor::from_data(TensorData::new(values, [batch, 3, size, size]), device)
}

/// Times `f` (`warmup` untimed runs, then `runs` timed ones), in milliseconds.
fn time_runs(warmup: usize, runs: usize, device: &Device, mut f: impl FnMut()) -> Result<Vec<f64>> {
    let mut out = Vec::with_capacity(runs);
    for i in 0..warmup + runs {
        let start = Instant::now();
        f();
        device
            .sync()
            .map_err(|e| CliError::new(format!("the CPU backend failed: {e:?}"), "run it again"))?;
        if i >= warmup {
            out.push(start.elapsed().as_secs_f64() * 1000.0);
        }
    }
    Ok(out)
}

fn inference(model: &PspNet, args: &BenchArgs, device: &Device) -> Result<Vec<f64>> {
    let x = images(args.batch, args.size, device);
    time_runs(args.warmup, args.iterations, device, || {
        let y = model.forward(x.clone());
        // Reading the result back makes sure the work is done, not queued.
        let _ = y.slice([0..1, 0..1, 0..1, 0..1]).into_data();
    })
}

fn training_steps(config: &PspNetConfig, args: &BenchArgs, device: &Device) -> Result<Vec<f64>> {
    let ad = device.clone().autodiff();
    let mut model = config
        .init(&ad)
        .map_err(|e| CliError::new(e.to_string(), "check the options"))?;
    let mut optimizer = models::optim::adam(1e-8, None);
    let x = images(args.train_batch, args.size, &ad);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let plane = args.size * args.size;
    let labels: Vec<Vec<u8>> = (0..args.train_batch)
        .map(|_| {
            (0..plane)
                .map(|_| rng.random_range(0..config.classes as u8))
                .collect()
        })
        .collect();
    let none = vec![false; config.classes];
    let refs: Vec<LabelRef<'_>> = labels
        .iter()
        .map(|l| LabelRef {
            pixels: l,
            unlabelable: &none,
        })
        .collect();
    let targets = LossTargets::new(
        &refs,
        [args.size, args.size],
        &vec![1.0; config.classes],
        &ad,
    );
    let mut step = 0u64;
    time_runs(args.warmup.min(1), args.train_steps, device, || {
        let _bf16 = args
            .bf16_convolutions
            .then(models::layers::Bf16Convolutions::enter);
        let heads = model.forward_train(x.clone(), step);
        let loss = segmentation_dice_loss(heads.logits, &targets, 0.0);
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optimizer.step(1e-4, model.clone(), grads);
        // Reading a weight back makes sure the update is done.
        let _ = model
            .classifier
            .weight
            .val()
            .slice([0..1, 0..1, 0..1, 0..1])
            .into_data();
        step += 1;
    })
}

pub fn run(ctx: &Context<'_>, args: &BenchArgs) -> Result<()> {
    if args.batch == 0 || args.iterations == 0 {
        return Err(CliError::new(
            "--batch and --iterations must be at least 1",
            "see `pipeline segmenter bench --help`",
        )
        .into());
    }
    check_size("--size", args.size as u64, "bench", false)?;
    let device = ctx.device()?;
    if args.bf16_convolutions && !models::layers::bf16_convolutions_run_on(&device) {
        return Err(CliError::new(
            "--bf16-convolutions needs the LibTorch backend",
            "add --device libtorch (a build with --features libtorch: docs/gpu.md)",
        )
        .into());
    }
    let mut progress = ctx.ui.progress("segmenter bench");
    // Everything on one thread of one pool: LibTorch's OpenMP starts a team of workers for each
    // thread that runs its operations, and with more team threads than cores its idle workers
    // stop spinning and sleep between operations (about 10 % of a training step here, which a
    // training run, all on one thread, does not pay).
    let (model, config, inference_ms, train_step_ms) =
        with_threads(Some(args.threads), || -> Result<_> {
            let (model, config) = match &args.model {
                Some(dir) => open_model(dir, &device)?,
                None => {
                    let mut config = PspNetConfig::new();
                    args.arch.apply(&mut config);
                    let model = config.init(&device).map_err(|e| {
                        CliError::new(e.to_string(), "check the architecture options")
                    })?;
                    (model, config)
                }
            };
            progress.step(&format!(
                "inference: {} at {}x{}, batch {}, {}",
                plural(args.iterations, "run"),
                args.size,
                args.size,
                args.batch,
                plural(args.threads, "thread")
            ));
            let inference_ms = timing(inference(&model, args, &device)?);
            let train_step_ms = if args.train_steps > 0 {
                progress.step(&format!(
                    "training: {}, batch {}",
                    plural(args.train_steps, "step"),
                    args.train_batch
                ));
                Some(timing(training_steps(&config, args, &device)?))
            } else {
                None
            };
            Ok((model, config, inference_ms, train_step_ms))
        })??;
    drop(progress);
    let report = BenchReport {
        parameters: model.num_params(),
        gflops_per_image: 2.0 * model.macs(args.size, args.size) as f64 / 1e9,
        images_per_second: args.batch as f64 * 1000.0 / inference_ms.median,
        inference_ms,
        train_step_ms,
        train_batch: args.train_batch,
        bf16_convolutions: args.bf16_convolutions,
        size: args.size,
        batch: args.batch,
        threads: args.threads,
        config,
    };
    if args.json {
        ctx.ui.result(&serde_json::to_string_pretty(&report)?);
    } else {
        let mut text = format!(
            "parameters {} (batch-norm running statistics included), {:.2} GFLOPs per {}x{} image\ninference batch {}, {}: median {:.1} ms (min {:.1}, max {:.1}, {}), {:.1} images/s",
            report.parameters,
            report.gflops_per_image,
            args.size,
            args.size,
            args.batch,
            plural(args.threads, "thread"),
            report.inference_ms.median,
            report.inference_ms.min,
            report.inference_ms.max,
            plural(report.inference_ms.runs, "run"),
            report.images_per_second
        );
        if let Some(t) = &report.train_step_ms {
            text.push_str(&format!(
                "\ntraining step batch {}: median {:.1} ms (min {:.1}, max {:.1}, {})",
                report.train_batch,
                t.median,
                t.min,
                t.max,
                plural(t.runs, "run")
            ));
        }
        ctx.ui.result(&text);
    }
    Ok(())
}
