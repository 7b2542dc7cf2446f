//! `pipeline segmenter train | eval | predict | bench | recalibrate`: the PSPNet-style segmenter of
//! `models::segmenter` on datasets in the project's manifest format.
//!
//! ```text
//! pipeline segmenter train   --data DIR[:WEIGHT]... [--val DIR...] --out RUN [--resume] [--max-minutes M] ...
//! pipeline segmenter eval    [--model MODEL] --data DIR... [--split val|test|train|all] --out DIR
//! pipeline segmenter predict [--model MODEL] INPUT --out DIR
//! pipeline segmenter bench   [--model MODEL] [--size 256] [--batch 1] [--threads 2]
//! pipeline segmenter recalibrate --run RUN [--from best|checkpoint] --data DIR[:WEIGHT]... [--batches 100] --out DIR
//! ```
//!
//! `MODEL` is a model folder (`model.json` + `model.bpk` or `model.safetensors`) or a training
//! run folder, whose `best/` model is used; without `--model`, `eval` and `predict` use the
//! model shipped in the binary (`models::segmenter::shipped`).

mod arch_args;
mod bench;
mod eval;
mod eval_report;
mod predict;
mod recalibrate;
mod record;
mod train;

use std::path::{Path, PathBuf};

use anyhow::Result;
use burn::tensor::Device;
use clap::{Args, Subcommand};
use models::segmenter::data::{Source, SourceSpec, Split};
use models::segmenter::files::{MODEL_CONFIG_FILE, load_model};
use models::segmenter::infer::Inference;
use models::segmenter::shipped::{SHIPPED_MODEL_NAME, shipped_model, shipped_short_side};
use models::segmenter::train::{
    BEST_DIR, DEFAULT_SHORT_SIDE, TrainingConfig, load_training_config, trained_short_side,
};
use models::segmenter::{PspNet, PspNetConfig, SegmenterError};

use super::Context;
use crate::error::CliError;

#[derive(Debug, Subcommand)]
pub enum SegmenterCommand {
    /// Train on one or several datasets (checkpoints each epoch; --resume after a kill).
    Train(Box<train::TrainArgs>),
    /// Evaluate a model: metrics.json, report.md and a confusion-matrix image.
    Eval(eval::EvalArgs),
    /// Label an image or a folder of images: label PNGs and overlays.
    Predict(predict::PredictArgs),
    /// Inference latency and throughput, training-step time, parameters and FLOPs.
    Bench(bench::BenchArgs),
    /// Recompute a run's batch-norm statistics over training batches ("precise BN").
    Recalibrate(recalibrate::RecalibrateArgs),
}

pub fn run(ctx: &Context<'_>, command: &SegmenterCommand) -> Result<()> {
    match command {
        SegmenterCommand::Train(args) => train::run(ctx, args),
        SegmenterCommand::Eval(args) => eval::run(ctx, args),
        SegmenterCommand::Predict(args) => predict::run(ctx, args),
        SegmenterCommand::Bench(args) => bench::run(ctx, args),
        SegmenterCommand::Recalibrate(args) => recalibrate::run(ctx, args),
    }
}

/// Options shared by the commands that run a trained model.
#[derive(Debug, Args)]
pub struct ModelArgs {
    /// A model folder (model.json with model.bpk or model.safetensors) or a training run
    /// folder (its best model) [default: the model shipped in the binary].
    #[arg(long, value_name = "DIR")]
    pub model: Option<PathBuf>,

    /// Short side the images are resized to before the network (predictions are scaled
    /// back to the image's size); 0 keeps the images' own size [default: the size the model
    /// was trained at (its run folder's train.json, or the shipped model's), else 256].
    #[arg(long, value_name = "PX")]
    pub size: Option<u32>,

    /// Multi-scale test: also run each image at these short sides (comma-separated) and
    /// average the class probabilities of all sizes (one more pass per size).
    #[arg(long, value_name = "PX,...", value_delimiter = ',', value_parser = clap::value_parser!(u32).range(16..=4096))]
    pub extra_sizes: Vec<u32>,

    /// Test-time flip: average the class probabilities of each image and of its mirror
    /// image (twice the inference time).
    #[arg(long)]
    pub flip: bool,
}

/// The short sides the network takes, in px (as `--extra-sizes`): below, its pyramid
/// pooling has nothing left to pool; above, one image fills gigabytes.
pub const SIZES: std::ops::RangeInclusive<u32> = 16..=4096;

/// Refuses a `--size` (or `--crop`) outside [`SIZES`], the same way in every segmenter
/// command. `own_size` allows 0, the images' own size (`eval` and `predict`).
pub fn check_size(option: &str, size: u64, command: &str, own_size: bool) -> Result<()> {
    if SIZES.contains(&u32::try_from(size).unwrap_or(u32::MAX)) || (own_size && size == 0) {
        return Ok(());
    }
    let range = format!("{} to {} px", SIZES.start(), SIZES.end());
    let hint = if own_size {
        format!("give {option} from {range}, or 0 for the images' own size")
    } else {
        format!("give {option} from {range} (see `pipeline segmenter {command} --help`)")
    };
    Err(CliError::new(
        format!("{option} {size}: the network takes short sides of {range}"),
        hint,
    )
    .into())
}

impl ModelArgs {
    /// `--size`, else the model's training size, else the training default (256); 0 means
    /// the images' own size. A size the network cannot take is refused.
    pub fn size(&self, command: &str) -> Result<u32> {
        if let Some(size) = self.size {
            check_size("--size", size.into(), command, true)?;
            return Ok(size);
        }
        let Some(path) = &self.model else {
            return shipped_short_side()
                .map_err(|e| segmenter_error(e, "give --size, or --model with a model folder"));
        };
        let trained = trained_short_side(&model_dir(path)).map_err(|e| {
            segmenter_error(e, "give --size, or repair the run folder's train.json")
        })?;
        Ok(trained.unwrap_or(DEFAULT_SHORT_SIDE))
    }

    /// The model `--model` names, else the shipped one.
    pub fn open(&self, device: &Device) -> Result<(PspNet, PspNetConfig)> {
        match &self.model {
            Some(path) => open_model(path, device),
            None => shipped_model(device)
                .map_err(|e| segmenter_error(e, "give --model with a model folder")),
        }
    }

    /// What outputs call the model: its folder (a run folder's `best/`), or `shipped`.
    pub fn name(&self) -> PathBuf {
        self.model
            .as_deref()
            .map_or_else(|| PathBuf::from(SHIPPED_MODEL_NAME), model_dir)
    }
}

/// How to run the model for a `--size` (0 keeps the images' own size), `--extra-sizes`
/// and `--flip`.
pub fn inference(size: u32, args: &ModelArgs) -> Inference {
    Inference {
        short: (size > 0).then_some(size),
        extra_shorts: args.extra_sizes.clone(),
        flip: args.flip,
    }
}

/// A model folder, or a run folder's best model.
pub fn model_dir(path: &Path) -> PathBuf {
    if !path.join(MODEL_CONFIG_FILE).is_file()
        && path.join(BEST_DIR).join(MODEL_CONFIG_FILE).is_file()
    {
        path.join(BEST_DIR)
    } else {
        path.to_path_buf()
    }
}

/// Loads `--model` with an error that names the folder and says what to give.
pub fn open_model(path: &Path, device: &Device) -> Result<(PspNet, PspNetConfig)> {
    load_model(&model_dir(path), device).map_err(|e| {
        segmenter_error(
            e,
            "give a model folder or a run folder written by `pipeline segmenter train`",
        )
    })
}

/// Opens datasets given as `DIR[:WEIGHT]`, selecting `split`.
pub fn open_sources(specs: &[SourceSpec], split: Split) -> Result<Vec<Source>> {
    specs
        .iter()
        .map(|spec| {
            Source::open(spec, split).map_err(|e| {
                segmenter_error(
                    e,
                    "give a dataset folder written by `pipeline dataset generate | import | augment`",
                )
            })
        })
        .collect()
}

/// A library error as the user sees it: one line naming the file, and a hint.
pub fn segmenter_error(err: SegmenterError, hint: &str) -> anyhow::Error {
    let hint = match &err {
        SegmenterError::Config(_) => "see `pipeline segmenter <command> --help`",
        _ => hint,
    };
    CliError::new(err.to_string(), hint).into()
}

/// Reads a run's (or a `--settings`) train.json, with an error that names the file.
pub fn read_training_config(path: &Path) -> Result<TrainingConfig> {
    Ok(load_training_config(path).map_err(|e| {
        CliError::file(
            path,
            format!("not a training config: {e}"),
            "give a settings .toml (see configs/) or a train.json written by `pipeline segmenter train`",
        )
    })?)
}

/// Parses `DIR[:WEIGHT]`.
pub fn parse_source(text: &str) -> Result<SourceSpec, String> {
    SourceSpec::parse(text)
}

/// Runs `f` on a rayon pool of `threads` threads (burn's flex backend uses the current pool;
/// LibTorch's own pool is capped at the same number).
pub fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> Result<T> {
    match threads {
        None => Ok(f()),
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| {
                    CliError::new(
                        format!("cannot start {n} threads: {e}"),
                        "use fewer --threads",
                    )
                })?;
            // LibTorch keeps a pool of its own; flex runs on this one.
            models::set_network_threads(n);
            Ok(pool.install(f))
        }
    }
}
