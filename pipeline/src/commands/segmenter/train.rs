//! `pipeline segmenter train`.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use models::segmenter::PspNetConfig;
use models::segmenter::data::{SourceSpec, Split};
use models::segmenter::loss::HardPixels;
use models::segmenter::train::{StopReason, TRAIN_CONFIG_FILE, TrainData, TrainingConfig, train};

use super::arch_args::{ArchArgs, set};
use super::record::TrainRecorder;
use super::{
    Context, check_size, open_sources, parse_source, read_training_config, segmenter_error,
    with_threads,
};
use crate::error::CliError;
use crate::ui::plural;

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Training dataset, optionally with a sampling weight (`DIR:2`); repeat for several.
    /// Its `train` split is used (every item when it has no splits).
    #[arg(long = "data", value_name = "DIR[:WEIGHT]", required = true, value_parser = parse_source)]
    pub data: Vec<SourceSpec>,

    /// Validation dataset (its `val` split); repeat for several [default: the `val` split
    /// of the --data datasets].
    #[arg(long = "val", value_name = "DIR", value_parser = parse_source)]
    pub val: Vec<SourceSpec>,

    /// The run folder: checkpoints, curves, the best model (best/), the recording.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    pub resume: bool,

    /// All settings as a TOML file (such as those of configs/) or the train.json a run
    /// writes; the options below override it.
    #[arg(long, value_name = "FILE")]
    pub settings: Option<PathBuf>,

    /// Stop when the run has taken this long (resumed sessions count together).
    #[arg(long, value_name = "MINUTES")]
    pub max_minutes: Option<f64>,

    #[arg(long)]
    pub epochs: Option<usize>,

    /// Stop after this many epochs without a better validation mIoU.
    #[arg(long, value_name = "EPOCHS")]
    pub patience: Option<usize>,

    #[arg(long)]
    pub batch_size: Option<usize>,

    /// Batches whose gradients make one optimiser step.
    #[arg(long, value_name = "N")]
    pub accumulation: Option<usize>,

    /// Adam's learning rate [default: 1e-4].
    #[arg(long, value_name = "LR")]
    pub lr: Option<f64>,

    /// Poly learning-rate decay power (0.9 is usual) [default: constant].
    #[arg(long, value_name = "POWER")]
    pub poly: Option<f64>,

    /// Run the poly decay over --max-minutes too, so the rate reaches 0 when the budget ends
    /// on a slow machine as on a fast one (the rates then depend on the machine's speed).
    #[arg(long)]
    pub decay_over_budget: bool,

    #[arg(long, value_name = "STEPS")]
    pub warmup_steps: Option<usize>,

    /// Items per epoch [default: all train items].
    #[arg(long, value_name = "N")]
    pub samples_per_epoch: Option<usize>,

    /// Short side of the images [default: 256].
    #[arg(long, value_name = "PX")]
    pub size: Option<u32>,

    /// Side of the square training crops [default: 256].
    #[arg(long, value_name = "PX")]
    pub crop: Option<u32>,

    /// Validation images per dataset each epoch [default: all].
    #[arg(long, value_name = "N")]
    pub val_limit: Option<usize>,

    /// Loss weight per class, comma-separated (e.g. from `pipeline dataset stats`).
    #[arg(long, value_name = "W,W,...", value_delimiter = ',')]
    pub class_weights: Option<Vec<f32>>,

    /// Weight of a soft Dice loss added to the cross-entropy [default: 0, cross-entropy alone].
    #[arg(long, value_name = "W")]
    pub dice_weight: Option<f64>,

    /// Weight of a Lovász-softmax loss (a surrogate of each class's IoU) added to the
    /// cross-entropy [default: 0, off].
    #[arg(long, value_name = "W")]
    pub lovasz_weight: Option<f64>,

    /// Train the main head's cross-entropy on the hard pixels only (online hard-example
    /// mining): those whose probability of their class is under PROBABILITY (e.g. 0.7), and
    /// at least the hardest 1/16 [default: every pixel].
    #[arg(long, value_name = "PROBABILITY")]
    pub hard_pixels: Option<f64>,

    /// Share of the crops placed around a pixel of a class drawn uniformly among those the
    /// image holds, so rare small objects are cropped in more often [default: 0, uniform].
    #[arg(long, value_name = "SHARE")]
    pub balanced_crops: Option<f32>,

    /// Validate and keep an exponential moving average of the weights with this decay
    /// (0.999 is usual) [default: 0, the trained weights themselves].
    #[arg(long, value_name = "DECAY")]
    pub ema_decay: Option<f64>,

    /// Run the training steps' convolutions in bfloat16, weights and everything else in f32
    /// (`--device libtorch` only; faster on CPUs with AVX-512 BF16 or AMX).
    #[arg(long)]
    pub bf16_convolutions: bool,

    /// Before each validation, recompute the batch norms' running statistics as the average
    /// over this many training batches ("precise BN"; about a third of a step each)
    /// [default: 0, off].
    #[arg(long, value_name = "N")]
    pub recalibration_batches: Option<usize>,

    #[command(flatten)]
    pub arch: ArchArgs,

    /// Threads of the run [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
}

impl TrainArgs {
    /// The settings: `--settings` (or, when resuming, the run's train.json) under the options.
    pub fn training_config(&self, seed: u64, run_dir: &Path) -> Result<TrainingConfig> {
        let file = match (&self.settings, self.resume) {
            (Some(path), _) => Some(path.clone()),
            (None, true) => Some(run_dir.join(TRAIN_CONFIG_FILE)),
            (None, false) => None,
        };
        let mut c = match &file {
            Some(path) => read_training_config(path)?,
            None => TrainingConfig::new(PspNetConfig::new()).with_seed(seed),
        };
        if file.is_none() || self.settings.is_some() {
            c.seed = seed;
        }
        self.arch.apply(&mut c.model);
        set(&mut c.epochs, self.epochs);
        set(&mut c.batch_size, self.batch_size);
        set(&mut c.accumulation, self.accumulation);
        set(&mut c.learning_rate, self.lr);
        set(&mut c.poly_power, self.poly);
        set(&mut c.warmup_steps, self.warmup_steps);
        set(&mut c.size, self.size);
        set(&mut c.crop, self.crop);
        set(&mut c.dice_weight, self.dice_weight);
        set(&mut c.lovasz_weight, self.lovasz_weight);
        set(&mut c.balanced_crops, self.balanced_crops);
        if let Some(probability) = self.hard_pixels {
            let hard = c.hard_pixels.take().unwrap_or_else(HardPixels::new);
            c.hard_pixels = Some(hard.with_probability(probability));
        }
        set(&mut c.ema_decay, self.ema_decay);
        set(&mut c.recalibration_batches, self.recalibration_batches);
        c.bf16_convolutions |= self.bf16_convolutions;
        c.decay_over_budget |= self.decay_over_budget;
        if self.samples_per_epoch.is_some() {
            c.samples_per_epoch = self.samples_per_epoch;
        }
        if self.val_limit.is_some() {
            c.val_limit = self.val_limit;
        }
        if self.class_weights.is_some() {
            c.class_weights.clone_from(&self.class_weights);
        }
        if self.patience.is_some() {
            c.patience = self.patience;
        }
        if self.max_minutes.is_some() {
            c.max_minutes = self.max_minutes;
        }
        check_size("--size", c.size.into(), "train", false)?;
        check_size("--crop", c.crop.into(), "train", false)?;
        c.validate()
            .map_err(|e| segmenter_error(e, "see `pipeline segmenter train --help`"))?;
        Ok(c)
    }
}

/// A fresh run needs an absent or empty folder; a resumed one the folder of a run.
fn prepare_run_dir(out: &Path, resume: bool) -> Result<()> {
    use models::run_folder::RunFolderError;
    models::run_folder::prepare(out, TRAIN_CONFIG_FILE, resume).map_err(|e| {
        let hint = match &e {
            RunFolderError::NothingToResume { .. } => "start it without --resume",
            RunFolderError::NotEmpty {
                holds_run: true, ..
            } => "continue it with --resume, or give a new --out folder",
            RunFolderError::NotEmpty { .. } => "give a new or empty --out folder",
            _ => "check the --out path",
        };
        CliError::new(e.to_string(), hint).into()
    })
}

pub fn run(ctx: &Context<'_>, args: &TrainArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    let config = args.training_config(ctx.global.seed, &out)?;
    let train_sources = open_sources(&args.data, Split::Train)?;
    let val_sources = if args.val.is_empty() {
        open_sources(&args.data, Split::Val)?
    } else {
        open_sources(&args.val, Split::Val)?
    };
    let data = TrainData {
        train: train_sources,
        val: val_sources,
    };
    prepare_run_dir(&out, args.resume)?;
    // A resumed session writes a new recording and logs the curves so far into it first.
    let recording = ctx.open_recording(Some(&out))?;
    let mut progress = ctx.ui.progress("segmenter train");
    let mut recorder = TrainRecorder::new(&recording, &mut progress, config.model.classes, &out)?;
    let device = ctx.device()?;
    let summary = with_threads(args.threads, || {
        train(&out, &config, &data, args.resume, &device, &mut recorder)
    })?
    .map_err(|e| segmenter_error(e, "check the datasets and the run folder"))?;
    recorder.finish()?;
    drop(progress);
    recording.finish()?;
    let state = &summary.state;
    let why = match state.stopped {
        Some(StopReason::Epochs) => "all epochs done",
        Some(StopReason::EarlyStopping) => "early stopping",
        Some(StopReason::TimeBudget) => "time budget reached",
        None => "stopped",
    };
    ctx.ui.result(&format!(
        "{}, {}, {:.0} s ({why}); best validation mIoU {:.4} at epoch {}; model in {}",
        plural(state.epochs_done, "epoch"),
        plural(state.step as usize, "step"),
        state.seconds,
        state.best_miou,
        state.best_epoch,
        summary.best_dir.display()
    ));
    Ok(())
}
