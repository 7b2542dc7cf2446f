//! Training: Adam over one or several datasets, validation each epoch, checkpoints, resume,
//! early stopping and a time budget, deterministic under a seed.
//!
//! The run folder (the library writes it file by file, each file atomically, so a
//! `kill -9` leaves the last complete checkpoint):
//!
//! ```text
//! <run>/
//!   train.json        the TrainingConfig (a resumed run must have the same)
//!   curves.jsonl      one line per optimiser step and per epoch (CurvePoint)
//!   checkpoint/       the last epoch: model.bpk, optimizer.bpk, state.json, and with
//!                     `ema_decay` the averaged weights, ema.bpk
//!   best/             the model of the best validation mIoU: a model folder (see files)
//!                     plus metrics.json
//! ```
//!
//! What makes a run reproducible: the weights come from the seed
//! ([`PspNetConfig::init_seeded`]), each epoch's item order and each item's augmentation
//! from (seed, epoch, draw), each step's dropout masks from (seed, step), and burn's flex
//! backend computes a convolution's output elements independently of the thread that runs
//! them; so a run and a run resumed from any checkpoint take the same steps. Only the time
//! budget (`max_minutes`) depends on the machine, and with `decay_over_budget` the
//! learning rates too.

use std::collections::BTreeMap;
use std::fs::OpenOptions;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::config::Config;
use burn::module::Module;
use burn::optim::{GradientsAccumulator, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};
use sim::seed::derive_seed;

use crate::averaging::blend;

use super::data::{Sample, Source, check_sources, epoch_draws, load_batch, resize_sample};
use super::error::{Result, SegmenterError};
use super::eval::{Prediction, class_names, evaluate};
use super::files::{load_record, save_model, save_record};
use super::infer::{Inference, normalise};
use super::loss::{
    LabelRef, LossTargets, dice_loss, hard_pixel_loss, lovasz_loss, segmentation_dice_loss,
    segmentation_loss,
};
use super::metrics::MetricsSummary;
use super::model::{PspNet, PspNetConfig};
use super::recalibrate::recalibrate_batch_norms;

pub use super::recipe::{
    DEFAULT_SHORT_SIDE, TrainingConfig, load_training_config, load_training_config_text,
};
use crate::run_folder::{read_json, recover_dir, replace_dir, write_atomic, write_json};

pub const TRAIN_CONFIG_FILE: &str = "train.json";
pub const CURVES_FILE: &str = "curves.jsonl";
pub const CHECKPOINT_DIR: &str = "checkpoint";
pub const BEST_DIR: &str = "best";
pub const STATE_FILE: &str = "state.json";
pub const OPTIMIZER_FILE: &str = "optimizer.bpk";
pub const EMA_FILE: &str = "ema.bpk";
pub const METRICS_FILE: &str = "metrics.json";

/// Seed stage of the dropout masks.
const STAGE_DROPOUT: u64 = 0x5e6_0003;

/// Where a run stands after an epoch (`checkpoint/state.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    /// Epochs completed.
    pub epochs_done: usize,
    /// Optimiser steps taken.
    pub step: u64,
    pub best_miou: f64,
    pub best_epoch: usize,
    pub epochs_without_improvement: usize,
    /// Wall time of all sessions so far.
    pub seconds: f64,
    /// Why the run ended, once it has.
    pub stopped: Option<StopReason>,
}

/// Why training stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    Epochs,
    EarlyStopping,
    TimeBudget,
}

/// A point of the training curves (one line of `curves.jsonl`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum CurvePoint {
    Step(StepPoint),
    Epoch(EpochPoint),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepPoint {
    pub step: u64,
    pub epoch: usize,
    pub loss: f64,
    pub learning_rate: f64,
    pub seconds: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochPoint {
    /// 1-based: the number of epochs done.
    pub epoch: usize,
    pub step: u64,
    pub train_loss: f64,
    pub val: MetricsSummary,
    pub val_per_source: BTreeMap<String, MetricsSummary>,
    pub best: bool,
    pub seconds: f64,
}

/// The size of a run, told before its first step (for progress bars).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TrainPlan {
    pub epochs: usize,
    /// Epochs already done (a resumed run).
    pub epochs_done: usize,
    pub batches_per_epoch: usize,
    pub steps_per_epoch: u64,
    /// Optimiser steps of the whole run, and those already done.
    pub total_steps: u64,
    pub steps_done: u64,
}

/// What the caller hears about while a run goes (the library itself never prints).
pub trait TrainObserver {
    /// The curves so far, once, when a run is resumed.
    fn history(&mut self, _points: &[CurvePoint]) {}
    /// The size of the run, once, before training starts.
    fn plan(&mut self, _plan: &TrainPlan) {}
    fn step(&mut self, _point: &StepPoint) {}
    /// After validation: the epoch's figures and the preview images.
    fn epoch(&mut self, _point: &EpochPoint, _previews: &[Prediction]) {}
    /// Progress within an epoch: (what, done, total).
    fn progress(&mut self, _what: &str, _done: usize, _total: usize) {}
}

/// An observer that ignores everything.
#[derive(Debug, Default)]
pub struct Quiet;

impl TrainObserver for Quiet {}

/// How a run ended.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainSummary {
    pub state: TrainState,
    /// The best model's folder.
    pub best_dir: PathBuf,
    pub resumed_from_epoch: Option<usize>,
}

/// The datasets of a run.
#[derive(Debug)]
pub struct TrainData {
    pub train: Vec<Source>,
    pub val: Vec<Source>,
}

/// Trains into `run_dir` (created if needed), or continues the run there with `resume`.
pub fn train(
    run_dir: &Path,
    config: &TrainingConfig,
    data: &TrainData,
    resume: bool,
    device: &Device,
    observer: &mut dyn TrainObserver,
) -> Result<TrainSummary> {
    config.validate()?;
    check_sources(&data.train, "train")?;
    check_sources(&data.val, "validation")?;
    if config.bf16_convolutions && !crate::layers::bf16_convolutions_run_on(device) {
        return Err(SegmenterError::Config(
            "bfloat16 convolutions need the LibTorch backend (a build with the libtorch feature)"
                .into(),
        ));
    }
    let mut run = Run::open(run_dir, config, resume)?;
    let device = device.clone().autodiff();
    let mut model = config.model.init_seeded(&device, config.seed)?;
    let mut optimizer: ModuleOptimizer = crate::optim::adam(1e-8, None);
    let mut state = TrainState {
        epochs_done: 0,
        step: 0,
        best_miou: f64::NEG_INFINITY,
        best_epoch: 0,
        epochs_without_improvement: 0,
        seconds: 0.0,
        stopped: None,
    };
    let mut resumed_from_epoch = None;
    let mut average = WeightAverage::new(config.ema_decay, &model);
    if let Some(checkpoint) = run.checkpoint()? {
        model = load_record(&checkpoint.join(super::files::MODEL_RECORD_FILE), model)?;
        average.load(&checkpoint.join(EMA_FILE), &model)?;
        let optimizer_path = checkpoint.join(OPTIMIZER_FILE);
        optimizer = optimizer.load(&optimizer_path).map_err(|e| {
            SegmenterError::invalid(
                &optimizer_path,
                format!("not a readable optimizer state: {e}"),
            )
        })?;
        state = read_json(&checkpoint.join(STATE_FILE))?;
        resumed_from_epoch = Some(state.epochs_done);
        let history = run.truncate_curves(&state)?;
        observer.history(&history);
    }
    if state.stopped.is_some() && state.epochs_done >= config.epochs {
        return Ok(run.summary(state, resumed_from_epoch));
    }
    state.stopped = None;

    let samples = config
        .samples_per_epoch
        .unwrap_or_else(|| data.train.iter().map(|s| s.items.len()).sum());
    let batches_per_epoch = samples.div_ceil(config.batch_size);
    let steps_per_epoch = batches_per_epoch.div_ceil(config.accumulation) as u64;
    let total_steps = steps_per_epoch * config.epochs as u64;
    observer.plan(&TrainPlan {
        epochs: config.epochs,
        epochs_done: state.epochs_done,
        batches_per_epoch,
        steps_per_epoch,
        total_steps,
        steps_done: state.step,
    });
    let class_weights = config
        .class_weights
        .clone()
        .unwrap_or_else(|| vec![1.0; config.model.classes]);
    let augment = config.augment();
    let session_start = Instant::now();
    let seconds_before = state.seconds;
    let elapsed = || seconds_before + session_start.elapsed().as_secs_f64();
    let over_budget = |s: f64| config.max_minutes.is_some_and(|m| s >= m * 60.0);

    while state.epochs_done < config.epochs {
        let epoch = state.epochs_done;
        let draws = epoch_draws(&data.train, samples, config.seed, epoch as u64);
        let mut accumulator = GradientsAccumulator::new();
        let mut pending = 0;
        let (mut loss_sum, mut loss_count, mut step_loss) = (0.0, 0usize, 0.0);
        let mut out_of_time = false;
        for (b, chunk) in draws.chunks(config.batch_size).enumerate() {
            if over_budget(elapsed()) {
                out_of_time = true;
                break;
            }
            let first = b * config.batch_size;
            let batch = load_batch(
                &data.train,
                chunk,
                first,
                &augment,
                config.seed,
                epoch as u64,
            )?;
            let micro = (epoch * batches_per_epoch + b) as u64;
            let _bf16 = config
                .bf16_convolutions
                .then(crate::layers::Bf16Convolutions::enter);
            let loss = batch_loss(
                &model,
                config,
                &data.train,
                &batch,
                &class_weights,
                micro,
                &device,
            );
            let value = f64::from(loss.clone().into_scalar::<f32>());
            let loss = loss.div_scalar(config.accumulation as f64);
            let grads = GradientsParams::from_grads(loss.backward(), &model);
            accumulator.accumulate(&model, grads);
            pending += 1;
            step_loss += value;
            loss_sum += value;
            loss_count += 1;
            observer.progress("train", b + 1, batches_per_epoch);
            let last = b + 1 == batches_per_epoch;
            if pending == config.accumulation || last {
                let lr = config.learning_rate_at(state.step, total_steps, elapsed());
                model = optimizer.step(lr, model, accumulator.grads());
                state.step += 1;
                average.update(&model, state.step);
                let point = StepPoint {
                    step: state.step,
                    epoch: epoch + 1,
                    loss: step_loss / pending as f64,
                    learning_rate: lr,
                    seconds: elapsed(),
                };
                run.append(&CurvePoint::Step(point.clone()))?;
                observer.step(&point);
                pending = 0;
                step_loss = 0.0;
            }
        }
        if pending > 0 {
            // The time budget cut the accumulation short: use what was gathered.
            let lr = config.learning_rate_at(state.step, total_steps, elapsed());
            model = optimizer.step(lr, model, accumulator.grads());
            state.step += 1;
            average.update(&model, state.step);
        }

        if config.recalibration_batches > 0 {
            (model, _) = recalibrate_batch_norms(
                model,
                config,
                &data.train,
                config.recalibration_batches,
                epoch as u64,
                &device,
            )?;
        }
        let valid = average.weights(&model);
        let previews_wanted = config.preview_images;
        let mut previews = Vec::new();
        let evaluation = evaluate(
            &valid,
            &config.model,
            &data.val,
            &Inference::at(Some(config.size)),
            config.val_limit,
            &device.clone().inner(),
            |done, total, prediction| {
                if previews.len() < previews_wanted {
                    previews.push(preview(prediction, config.size));
                }
                observer.progress("validate", done, total);
            },
        )?;
        let names = class_names(config.model.classes);
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
        let val = evaluation.overall.summary(&names);
        let improved = val.miou > state.best_miou;
        state.epochs_done = epoch + 1;
        if improved {
            state.best_miou = val.miou;
            state.best_epoch = state.epochs_done;
            state.epochs_without_improvement = 0;
        } else {
            state.epochs_without_improvement += 1;
        }
        let point = EpochPoint {
            epoch: state.epochs_done,
            step: state.step,
            train_loss: if loss_count > 0 {
                loss_sum / loss_count as f64
            } else {
                f64::NAN
            },
            val_per_source: evaluation
                .per_source
                .iter()
                .map(|(name, m)| (name.clone(), m.summary(&names)))
                .collect(),
            val,
            best: improved,
            seconds: elapsed(),
        };
        state.stopped = if out_of_time || over_budget(elapsed()) {
            Some(StopReason::TimeBudget)
        } else if config
            .patience
            .is_some_and(|p| state.epochs_without_improvement >= p)
        {
            Some(StopReason::EarlyStopping)
        } else if state.epochs_done >= config.epochs {
            Some(StopReason::Epochs)
        } else {
            None
        };
        state.seconds = elapsed();
        if improved {
            run.save_best(&valid, &config.model, &point)?;
        }
        run.append(&CurvePoint::Epoch(point.clone()))?;
        run.save_checkpoint(&model, &optimizer, average.averaged.as_ref(), &state)?;
        observer.epoch(&point, &previews);
        if state.stopped.is_some() {
            break;
        }
    }
    Ok(run.summary(state, resumed_from_epoch))
}

/// The exponential moving average of the weights a run keeps with `ema_decay` (inference
/// mode: it never takes gradients), or nothing.
struct WeightAverage {
    decay: f64,
    averaged: Option<PspNet>,
}

impl WeightAverage {
    /// Starts from the model's weights, when averaging is on.
    fn new(decay: f64, model: &PspNet) -> Self {
        WeightAverage {
            decay,
            averaged: (decay > 0.0).then(|| model.valid()),
        }
    }

    /// Takes the average saved with a checkpoint; a checkpoint without one (a run before
    /// averaging existed cannot be resumed with it: `same_run`) is an error.
    fn load(&mut self, path: &Path, model: &PspNet) -> Result<()> {
        if self.averaged.is_some() {
            self.averaged = Some(load_record(path, model.valid())?);
        }
        Ok(())
    }

    /// Moves the average towards the model after its `steps_done`-th step.
    fn update(&mut self, model: &PspNet, steps_done: u64) {
        if let Some(averaged) = self.averaged.take() {
            let n = steps_done as f64;
            let decay = self.decay.min((1.0 + n) / (10.0 + n));
            self.averaged = Some(blend(averaged, &model.valid(), 1.0 - decay));
        }
    }

    /// What is validated and kept as the best model: the average, or the model itself.
    fn weights(&self, model: &PspNet) -> PspNet {
        self.averaged.clone().unwrap_or_else(|| model.valid())
    }
}

/// The loss of one batch: `[B, 3, crop, crop]` images through the network, the merged
/// cross-entropy of the main head (over its hard pixels with `hard_pixels`), plus
/// `dice_weight` times its Dice loss and `lovasz_weight` times its Lovász-softmax loss, plus
/// `aux_weight` times the aux head's cross-entropy.
fn batch_loss(
    model: &PspNet,
    config: &TrainingConfig,
    sources: &[Source],
    batch: &[(usize, Sample)],
    class_weights: &[f32],
    micro_step: u64,
    device: &Device,
) -> Tensor<1> {
    let images: Vec<&image::RgbImage> = batch.iter().map(|(_, s)| &s.image).collect();
    let input = normalise(&images, &config.model, device);
    let labels: Vec<LabelRef<'_>> = batch
        .iter()
        .map(|(source, s)| LabelRef {
            pixels: s.label.as_raw(),
            unlabelable: &sources[*source].unlabelable,
        })
        .collect();
    let side = config.crop as usize;
    let targets = LossTargets::new(&labels, [side, side], class_weights, device);
    let heads = model.forward_train(input, derive_seed(config.seed, STAGE_DROPOUT, micro_step));
    let mut loss = match &config.hard_pixels {
        Some(hard) => {
            let loss = hard_pixel_loss(heads.logits.clone(), &targets, hard);
            if config.dice_weight > 0.0 {
                loss + dice_loss(heads.logits.clone(), &targets).mul_scalar(config.dice_weight)
            } else {
                loss
            }
        }
        None => segmentation_dice_loss(heads.logits.clone(), &targets, config.dice_weight),
    };
    if config.lovasz_weight > 0.0 {
        loss = loss + lovasz_loss(heads.logits, &targets).mul_scalar(config.lovasz_weight);
    }
    match heads.aux {
        Some(aux) => loss + segmentation_loss(aux, &targets).mul_scalar(config.aux_weight),
        None => loss,
    }
}

/// A preview at the training resolution (so the recording stays small).
fn preview(p: &Prediction, short: u32) -> Prediction {
    let sample = Sample {
        id: p.sample.id.clone(),
        image: p.sample.image.clone(),
        label: p.prediction.clone(),
    };
    let predicted = resize_sample(&sample, short);
    let truth = resize_sample(&p.sample, short);
    Prediction {
        sample: truth,
        prediction: predicted.label,
    }
}

/// The run folder.
struct Run {
    dir: PathBuf,
}

impl Run {
    /// Starts a run in `dir`, or reopens it for `resume` (the config must be the same).
    fn open(dir: &Path, config: &TrainingConfig, resume: bool) -> Result<Run> {
        std::fs::create_dir_all(dir).map_err(|e| SegmenterError::io(dir, e))?;
        let run = Run {
            dir: dir.to_path_buf(),
        };
        let config_path = dir.join(TRAIN_CONFIG_FILE);
        if resume {
            if !config_path.is_file() {
                return Err(SegmenterError::invalid(
                    dir,
                    "has no training run to resume (no train.json)",
                ));
            }
            let before = load_training_config(&config_path).map_err(|e| {
                SegmenterError::invalid(&config_path, format!("not a training config: {e}"))
            })?;
            if !same_run(&before, config) {
                return Err(SegmenterError::invalid(
                    &config_path,
                    "the run was started with other settings; resume it with the same ones (only epochs, patience and max-minutes may change)",
                ));
            }
        } else if config_path.exists() {
            return Err(SegmenterError::invalid(
                dir,
                "holds a training run; give --resume to continue it, or a new folder",
            ));
        }
        write_atomic(&config_path, |tmp| {
            config.save(tmp).map_err(|e| SegmenterError::io(tmp, e))
        })?;
        Ok(run)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// The last complete checkpoint folder, if there is one.
    fn checkpoint(&self) -> Result<Option<PathBuf>> {
        let dir = self.path(CHECKPOINT_DIR);
        recover_dir(&dir)?;
        Ok(dir.join(STATE_FILE).is_file().then_some(dir))
    }

    fn append(&mut self, point: &CurvePoint) -> Result<()> {
        let path = self.path(CURVES_FILE);
        let line = serde_json::to_string(point)
            .map_err(|e| SegmenterError::invalid(&path, format!("cannot encode: {e}")))?;
        let mut file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|e| SegmenterError::io(&path, e))?;
        writeln!(file, "{line}").map_err(|e| SegmenterError::io(&path, e))
    }

    /// Drops the curve points after the checkpoint (work a kill lost; it is done again)
    /// and returns the rest.
    fn truncate_curves(&self, state: &TrainState) -> Result<Vec<CurvePoint>> {
        let path = self.path(CURVES_FILE);
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
            Err(e) => return Err(SegmenterError::io(&path, e)),
        };
        // A kill may cut the last line short: it is not a point.
        let kept: Vec<CurvePoint> = text
            .lines()
            .filter_map(|line| serde_json::from_str::<CurvePoint>(line).ok())
            .filter(|p| match p {
                CurvePoint::Step(s) => s.step <= state.step,
                CurvePoint::Epoch(e) => e.epoch <= state.epochs_done,
            })
            .collect();
        let mut out = String::new();
        for p in &kept {
            out.push_str(&serde_json::to_string(p).unwrap_or_default());
            out.push('\n');
        }
        write_atomic(&path, |tmp| {
            std::fs::write(tmp, &out).map_err(|e| SegmenterError::io(tmp, e))
        })?;
        Ok(kept)
    }

    fn save_best(&self, model: &PspNet, config: &PspNetConfig, point: &EpochPoint) -> Result<()> {
        replace_dir(&self.path(BEST_DIR), |dir| {
            save_model(dir, model, config)?;
            Ok(write_json(&dir.join(METRICS_FILE), point)?)
        })
    }

    fn save_checkpoint(
        &self,
        model: &PspNet,
        optimizer: &ModuleOptimizer,
        averaged: Option<&PspNet>,
        state: &TrainState,
    ) -> Result<()> {
        replace_dir(&self.path(CHECKPOINT_DIR), |dir| {
            save_record(&dir.join(super::files::MODEL_RECORD_FILE), model)?;
            if let Some(averaged) = averaged {
                save_record(&dir.join(EMA_FILE), averaged)?;
            }
            let opt_path = dir.join(OPTIMIZER_FILE);
            optimizer.save(&opt_path).map_err(|e| {
                SegmenterError::invalid(&opt_path, format!("cannot write the optimizer state: {e}"))
            })?;
            Ok(write_json(&dir.join(STATE_FILE), state)?)
        })
    }

    fn summary(&self, state: TrainState, resumed_from_epoch: Option<usize>) -> TrainSummary {
        TrainSummary {
            state,
            best_dir: self.path(BEST_DIR),
            resumed_from_epoch,
        }
    }
}

/// Whether a resumed run may continue under `new`: everything that shapes the steps must
/// be the same; how long to go on may change.
fn same_run(old: &TrainingConfig, new: &TrainingConfig) -> bool {
    let mut old = old.clone();
    old.epochs = new.epochs;
    old.patience = new.patience;
    old.max_minutes = new.max_minutes;
    old == *new
}

/// The short side a model was trained at, from the run folder it belongs to: `model_dir`
/// itself or its parent (a run's `best/` or `checkpoint/`). `None` when no run folder holds
/// it (a model folder copied elsewhere). A network trained at one scale sees objects at
/// another as other sizes, so evaluating it at its training size is the sensible default.
pub fn trained_short_side(model_dir: &Path) -> Result<Option<u32>> {
    let candidates = [Some(model_dir), model_dir.parent()];
    let Some(path) = candidates
        .into_iter()
        .flatten()
        .map(|dir| dir.join(TRAIN_CONFIG_FILE))
        .find(|path| path.is_file())
    else {
        return Ok(None);
    };
    let config = load_training_config(&path)
        .map_err(|e| SegmenterError::invalid(&path, format!("not a training config: {e}")))?;
    Ok(Some(config.size))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn learning_rate_warms_up_then_decays() {
        let c = TrainingConfig::new(PspNetConfig::new())
            .with_learning_rate(1.0)
            .with_warmup_steps(4)
            .with_poly_power(1.0);
        assert_eq!(c.learning_rate_at(0, 100, 0.0), 0.25);
        assert_eq!(c.learning_rate_at(3, 100, 0.0), 1.0);
        assert!((c.learning_rate_at(50, 100, 0.0) - 0.5).abs() < 1e-12);
        let constant = TrainingConfig::new(PspNetConfig::new());
        assert_eq!(constant.learning_rate_at(99, 100, 0.0), 1e-4);
    }

    #[test]
    fn the_decay_can_run_over_the_time_budget() {
        let steps = TrainingConfig::new(PspNetConfig::new())
            .with_learning_rate(1.0)
            .with_poly_power(1.0)
            .with_max_minutes(Some(10.0));
        // By steps alone the clock is ignored.
        assert!((steps.learning_rate_at(25, 100, 450.0) - 0.75).abs() < 1e-12);
        let budget = steps.clone().with_decay_over_budget(true);
        assert!(budget.validate().is_ok());
        // 450 s of 600 is further on than 25 steps of 100 ...
        assert!((budget.learning_rate_at(25, 100, 450.0) - 0.25).abs() < 1e-12);
        // ... and 60 s is not as far as 50 steps.
        assert!((budget.learning_rate_at(50, 100, 60.0) - 0.5).abs() < 1e-12);
        // Past the budget the rate stays 0 rather than turning negative.
        assert_eq!(budget.learning_rate_at(10, 100, 900.0), 0.0);
        // Without a budget there is nothing to decay over.
        let unbounded = budget.with_max_minutes(None);
        assert!(unbounded.validate().is_err());
    }

    #[test]
    fn a_runs_models_know_their_training_size() -> Result<()> {
        let root = tempfile::tempdir().map_err(|e| SegmenterError::io(Path::new("tmp"), e))?;
        let run = root.path().join("run");
        let best = run.join(BEST_DIR);
        std::fs::create_dir_all(&best).map_err(|e| SegmenterError::io(&best, e))?;
        // A model folder outside any run: no size to go by.
        assert_eq!(trained_short_side(&best)?, None);
        let config = TrainingConfig::new(PspNetConfig::new()).with_size(384);
        write_json(&run.join(TRAIN_CONFIG_FILE), &config)?;
        assert_eq!(trained_short_side(&best)?, Some(384));
        assert_eq!(trained_short_side(&run)?, Some(384));
        // A damaged train.json is an error naming it, not a silent fallback.
        std::fs::write(run.join(TRAIN_CONFIG_FILE), "{")
            .map_err(|e| SegmenterError::io(&run, e))?;
        let err = trained_short_side(&best).err().map(|e| e.to_string());
        assert!(err.is_some_and(|e| e.contains(TRAIN_CONFIG_FILE)));
        Ok(())
    }

    #[test]
    fn settings_read_from_toml_keep_defaults_and_refuse_typos() -> Result<()> {
        let root = tempfile::tempdir().map_err(|e| SegmenterError::io(Path::new("tmp"), e))?;
        let path = root.path().join("recipe.toml");
        let write =
            |text: &str| std::fs::write(&path, text).map_err(|e| SegmenterError::io(&path, e));
        write(
            "# a recipe\nepochs = 7\nclass_weights = [1.0, 2.0, 1.0, 1.0, 0.5]\n[model]\nwidth = 0.5\n",
        )?;
        let c = load_training_config(&path)
            .map_err(|e| SegmenterError::invalid(&path, e.to_string()))?;
        let defaults = TrainingConfig::new(PspNetConfig::new());
        assert_eq!(c.epochs, 7);
        assert_eq!(c.model.width, 0.5);
        assert_eq!(c.class_weights, Some(vec![1.0, 2.0, 1.0, 1.0, 0.5]));
        assert_eq!(c.batch_size, defaults.batch_size);
        assert_eq!(c.model.depth, defaults.model.depth);
        // A misspelt key, at the top or in [model], is named rather than ignored.
        write("epoch = 7\n")?;
        let err = load_training_config(&path).err();
        assert!(err.is_some_and(|e| e.to_string().contains("`epoch`")));
        write("[model]\nwidht = 0.5\n")?;
        let err = load_training_config(&path).err();
        assert!(err.is_some_and(|e| e.to_string().contains("`model.widht`")));
        // An unset setting may be given.
        write("patience = 3\n")?;
        let c = load_training_config(&path)
            .map_err(|e| SegmenterError::invalid(&path, e.to_string()))?;
        assert_eq!(c.patience, Some(3));
        Ok(())
    }
}
