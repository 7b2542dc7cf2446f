//! What a segmenter training run does: [`TrainingConfig`], every setting with its default, and
//! how a run's `train.json` is read back.

use std::path::Path;

use burn::config::Config;

use super::data::Augment;
use super::error::{Result, SegmenterError};
use super::files::ConfigFileError;
use super::loss::HardPixels;
use super::model::PspNetConfig;

/// The short side images are trained at unless a run says otherwise; also what a model
/// outside a run folder is run at (see [`trained_short_side`]).
pub const DEFAULT_SHORT_SIDE: u32 = 256;

/// Everything a training run does, with the thesis's settings as defaults (Adam 1e-4,
/// batch 8) and a short side of 256 px for 2 CPU cores.
#[derive(Config, Debug, PartialEq)]
pub struct TrainingConfig {
    pub model: PspNetConfig,
    /// Adam's learning rate (after warm-up, before the poly decay).
    #[config(default = 1e-4)]
    pub learning_rate: f64,
    /// Images per forward pass.
    #[config(default = 8)]
    pub batch_size: usize,
    /// Forward passes whose gradients are summed into one optimiser step.
    #[config(default = 1)]
    pub accumulation: usize,
    #[config(default = 50)]
    pub epochs: usize,
    /// Items drawn per epoch [default: the train items of all sources].
    #[config(default = "None")]
    pub samples_per_epoch: Option<usize>,
    /// Poly decay `lr · (1 − step / steps)^power` over the whole run; 0 keeps it constant.
    #[config(default = 0.0)]
    pub poly_power: f64,
    /// Run the poly decay over the time budget (`max_minutes`) as well as over the steps:
    /// its progress is the larger of the steps' share and the budget's, so the rate reaches
    /// 0 when the budget ends however fast the machine is. The rates then depend on the
    /// machine's speed (each step's is in `curves.jsonl`), so such a run is not reproducible
    /// step for step.
    #[config(default = false)]
    pub decay_over_budget: bool,
    /// Steps of linear warm-up from 0.
    #[config(default = 0)]
    pub warmup_steps: usize,
    /// Short side of the images before the random scale (training and validation).
    #[config(default = "DEFAULT_SHORT_SIDE")]
    pub size: u32,
    /// Side of the square training crops.
    #[config(default = 256)]
    pub crop: u32,
    #[config(default = "[0.75, 1.25]")]
    pub scale: [f32; 2],
    #[config(default = true)]
    pub flip: bool,
    /// Share of the training crops placed around a pixel of a class drawn uniformly among
    /// those the image holds (`Augment::balanced_crops`); 0 places every crop uniformly.
    #[config(default = 0.0)]
    pub balanced_crops: f32,
    /// Loss weight of each class [default: all 1].
    #[config(default = "None")]
    pub class_weights: Option<Vec<f32>>,
    /// Weight of the soft Dice loss added to the cross-entropy (0: cross-entropy alone).
    #[config(default = 0.0)]
    pub dice_weight: f64,
    /// Weight of the Lovász-softmax loss added to the cross-entropy (`loss::lovasz_loss`; 0: off).
    #[config(default = 0.0)]
    pub lovasz_weight: f64,
    /// The main head's cross-entropy over the hard pixels only (`loss::hard_pixel_loss`)
    /// [default: every pixel].
    #[config(default = "None")]
    pub hard_pixels: Option<HardPixels>,
    /// Decay of an exponential moving average of the weights, which is then what is
    /// validated and saved as the best model (0: off, the trained weights themselves).
    /// Early steps use `min(decay, (1 + n) / (10 + n))` after `n` steps, so the average
    /// does not hold on to the random initial weights.
    #[config(default = 0.0)]
    pub ema_decay: f64,
    /// Run the training steps' convolutions in bfloat16 (`layers::Bf16Convolutions`; the
    /// LibTorch backend only): faster on CPUs with bfloat16 dot products. Validation stays f32.
    #[config(default = false)]
    pub bf16_convolutions: bool,
    /// Before each validation, replace the batch norms' running statistics by the average
    /// of the batch statistics of this many training batches (`recalibrate`; 0: off, the
    /// running statistics as training moved them). The batches count in the time budget.
    #[config(default = 0)]
    pub recalibration_batches: usize,
    /// Weight of the auxiliary head's loss (with `model.aux_head`).
    #[config(default = 0.4)]
    pub aux_weight: f64,
    /// Stop after this many epochs without a better validation mIoU.
    #[config(default = "None")]
    pub patience: Option<usize>,
    /// Stop when the run (all sessions together, validation included) reaches this.
    #[config(default = "None")]
    pub max_minutes: Option<f64>,
    /// Validation images per source each epoch [default: all].
    #[config(default = "None")]
    pub val_limit: Option<usize>,
    /// Validation images logged with prediction and label each epoch.
    #[config(default = 4)]
    pub preview_images: usize,
    #[config(default = 0)]
    pub seed: u64,
}

impl TrainingConfig {
    pub fn validate(&self) -> Result<()> {
        self.model.validate()?;
        let bad = |m: String| Err(SegmenterError::Config(m));
        if self.batch_size == 0 || self.accumulation == 0 || self.epochs == 0 {
            return bad("batch size, accumulation and epochs must be at least 1".into());
        }
        if !(0.0..=1.0).contains(&self.balanced_crops) {
            return bad(format!(
                "balanced crops is a share from 0 to 1, not {}",
                self.balanced_crops
            ));
        }
        if !(0.0..1.0).contains(&self.ema_decay) {
            return bad(format!(
                "EMA decay must be from 0 (off) up to but not including 1, not {}",
                self.ema_decay
            ));
        }
        for (name, weight) in [("dice", self.dice_weight), ("Lovász", self.lovasz_weight)] {
            if !(weight.is_finite() && weight >= 0.0) {
                return bad(format!("{name} weight must be 0 or more, not {weight}"));
            }
        }
        if let Some(hard) = &self.hard_pixels
            && !hard.is_valid()
        {
            return bad(format!(
                "hard pixels need a probability and a minimum share in (0, 1], not {} and {}",
                hard.probability, hard.min_share
            ));
        }
        if self.recalibration_batches > 0 && self.ema_decay > 0.0 {
            return bad(
                "batch-norm recalibration works on the trained weights, not on a weight average: \
                 give one of the two"
                    .into(),
            );
        }
        if self.decay_over_budget && (self.max_minutes.is_none() || self.poly_power <= 0.0) {
            return bad("decaying over the time budget needs a budget and a poly decay".into());
        }
        if !(self.learning_rate.is_finite() && self.learning_rate > 0.0) {
            return bad(format!(
                "learning rate must be positive, not {}",
                self.learning_rate
            ));
        }
        if self.size == 0 || self.crop == 0 {
            return bad("size and crop must be at least 1 px".into());
        }
        if !(self.scale[0] > 0.0 && self.scale[1] >= self.scale[0]) {
            return bad(format!(
                "scale must be a range of positive factors, not {:?}",
                self.scale
            ));
        }
        if let Some(w) = &self.class_weights
            && (w.len() != self.model.classes || w.iter().any(|&v| !(v.is_finite() && v >= 0.0)))
        {
            return bad(format!(
                "class weights must be {} non-negative numbers, not {w:?}",
                self.model.classes
            ));
        }
        Ok(())
    }

    /// The on-the-fly augmentation of the training crops.
    pub fn augment(&self) -> Augment {
        Augment {
            size: self.size,
            crop: self.crop,
            scale: self.scale,
            flip: self.flip,
            balanced_crops: self.balanced_crops,
        }
    }

    /// Learning rate of optimiser step `step` (0-based) of `total`, taken when the run has
    /// lasted `seconds` (which only `decay_over_budget` looks at).
    pub fn learning_rate_at(&self, step: u64, total: u64, seconds: f64) -> f64 {
        let warm = self.warmup_steps as u64;
        if step < warm {
            return self.learning_rate * (step + 1) as f64 / warm as f64;
        }
        if self.poly_power > 0.0 && total > 0 {
            let mut t = step as f64 / total as f64;
            if let Some(minutes) = self.max_minutes.filter(|_| self.decay_over_budget) {
                t = t.max(seconds / (minutes * 60.0));
            }
            return self.learning_rate * (1.0 - t.min(1.0)).powf(self.poly_power);
        }
        self.learning_rate
    }
}

/// Reads a `train.json`, also one written before a setting existed (it gets the setting's
/// default; [`super::files::load_config`]).
pub fn load_training_config(path: &Path) -> std::result::Result<TrainingConfig, ConfigFileError> {
    super::files::load_config(path, &TrainingConfig::new(PspNetConfig::new()))
}

/// [`load_training_config`] on the text of a `train.json`.
pub fn load_training_config_text(
    json: &str,
) -> std::result::Result<TrainingConfig, ConfigFileError> {
    let value: serde_json::Value = serde_json::from_str(json)?;
    super::files::config_from_value(value, &TrainingConfig::new(PspNetConfig::new()))
}
