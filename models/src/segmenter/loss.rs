//! The training loss: pixel-wise cross-entropy with class weights and an ignore label, where
//! a class a source cannot label is merged into the class the source calls it.
//!
//! The rule for a source that cannot label some classes `U` (its card's `labelable` list
//! leaves them out; CamVid and Cityscapes never label lane markings, which they call road):
//! a pixel labelled `y` by that source counts as correct if the network predicts `y` *or* a
//! class of `U` that the source calls `y` (`U_y`: lane marking on a pixel labelled road,
//! [`datasets::may_stand_for`]), because the truth may be a marking the source could not name.
//! The pixel's loss is
//!
//! ```text
//! −log Σ_{c ∈ {y} ∪ U_y} softmax(logits)_c  =  logsumexp(all logits) − logsumexp(logits of {y} ∪ U_y)
//! ```
//!
//! which is plain cross-entropy when `U_y` is empty. The source neither teaches nor punishes
//! markings on its road; data that labels them (generated images) teaches them. A marking
//! predicted on a pixel the source labelled vehicle, human or other is an error as usual: with
//! *any* class of `U` accepted everywhere, predicting lane marking on every pixel of a CamVid
//! image cost nothing, and a network learnt exactly that within one epoch.
//! Pixels labelled [`IGNORE`] (255) count nothing. With class weights `w` the loss is
//! `Σ w[y]·loss / Σ w[y]` over counted pixels, as PyTorch's `CrossEntropyLoss(weight=...)`.
//! Evaluation applies the same rule to predictions (see `eval`).
//!
//! [`hard_pixel_loss`], optional (`TrainingConfig::hard_pixels`), is the same cross-entropy
//! over the hard pixels only (online hard-example mining, as BiSeNet's and
//! mmsegmentation's OHEM): those whose probability of an acceptable class is under
//! [`HardPixels::probability`], and never fewer than [`HardPixels::min_share`] of the counted
//! pixels, the hardest first. The easy pixels, most of the road and the sky once they are
//! learnt, then stop diluting the gradient of the people, the vehicles' outlines and the
//! markings.
//!
//! [`dice_loss`], optional (`TrainingConfig::dice_weight`), is the soft Dice loss of
//! segmentation_models.pytorch: per class, `1 − 2 Σ p·t / (Σ p + Σ t)` over the batch's
//! pixels, averaged over the classes the batch's labels hold. It weighs each class by its
//! overlap rather than its pixel count, as IoU does. Only pixels with exactly one acceptable
//! class count in it (a pixel a source may have merged, road on CamVid, does not).
//!
//! [`lovasz_loss`], optional (`TrainingConfig::lovasz_weight`), is the Lovász-softmax loss
//! of Berman, Rannen Triki and Blaschko (CVPR 2018), over the batch and the classes its
//! labels hold, as segmentation_models.pytorch's `LovaszLoss` (multiclass, `per_image`
//! false): per class, the pixels' errors `|t − p|` sorted from the largest, each weighted by
//! how much it raises the Jaccard loss `1 − |truth ∩ predicted| / |truth ∪ predicted|` of the
//! pixels up to it (the Lovász extension of that loss). Its gradient reaches exactly the
//! pixels that cost IoU, the outlines of people and vehicles among them. The same pixels
//! count as in Dice.

use burn::config::Config;
use burn::tensor::{Device, Tensor, TensorData};

use datasets::IGNORE;

/// What the loss needs besides the logits, built on the CPU from the labels.
#[derive(Debug, Clone)]
pub struct LossTargets {
    /// `[B, classes, H, W]`: 1 where the class is an acceptable answer for the pixel.
    pub allowed: Tensor<4>,
    /// `[B, H, W]`: the class weight of the pixel's label, 0 for ignored pixels.
    pub weights: Tensor<3>,
    /// Σ weights, so the mean needs no reduction on the device.
    pub weight_sum: f64,
    /// `weights` on the host, row-major (for [`hard_pixel_loss`]'s threshold).
    pub host_weights: Vec<f32>,
    /// `[B, 1, H, W]`: 1 where the pixel has exactly one acceptable class (for [`dice_loss`]).
    pub single: Tensor<4>,
    /// `[classes]`: 1 for the classes some `single` pixel is labelled with.
    pub present: Tensor<1>,
    /// `[B, H, W]` row-major on the host: the class of each `single` pixel, [`IGNORE`]
    /// for the others (for [`lovasz_loss`]'s ordering).
    pub host_single: Vec<u8>,
}

/// One label of a batch and the classes its source cannot label.
#[derive(Debug, Clone, Copy)]
pub struct LabelRef<'a> {
    /// `H × W` class ids, row-major.
    pub pixels: &'a [u8],
    /// `unlabelable[c]`: the source cannot label class `c`.
    pub unlabelable: &'a [bool],
}

impl LossTargets {
    /// Targets of a batch of `[h, w]` labels (each `h * w` long). `class_weights` has one
    /// weight per class (all 1 for plain cross-entropy).
    pub fn new(
        labels: &[LabelRef<'_>],
        [h, w]: [usize; 2],
        class_weights: &[f32],
        device: &Device,
    ) -> LossTargets {
        let classes = class_weights.len();
        let plane = h * w;
        let mut allowed = vec![0.0f32; labels.len() * classes * plane];
        let mut weights = vec![0.0f32; labels.len() * plane];
        let mut single = vec![0.0f32; labels.len() * plane];
        let mut host_single = vec![IGNORE; labels.len() * plane];
        let mut present = vec![0.0f32; classes];
        for (b, label) in labels.iter().enumerate() {
            for (i, &y) in label.pixels.iter().enumerate().take(plane) {
                let at = |c: usize| (b * classes + c) * plane + i;
                let y = usize::from(y);
                if y == usize::from(IGNORE) || y >= classes {
                    // Ignored: every class allowed, so the pixel's loss is exactly 0.
                    (0..classes).for_each(|c| allowed[at(c)] = 1.0);
                    continue;
                }
                weights[b * plane + i] = class_weights[y];
                allowed[at(y)] = 1.0;
                let mut merged = false;
                for c in (0..classes).filter(|&c| {
                    label.unlabelable.get(c).copied().unwrap_or(false)
                        && datasets::may_stand_for(y as u8, c as u8)
                }) {
                    allowed[at(c)] = 1.0;
                    merged = true;
                }
                if !merged {
                    single[b * plane + i] = 1.0;
                    host_single[b * plane + i] = y as u8;
                    present[y] = 1.0;
                }
            }
        }
        let weight_sum = weights.iter().map(|&w| f64::from(w)).sum();
        LossTargets {
            allowed: Tensor::from_data(
                TensorData::new(allowed, [labels.len(), classes, h, w]),
                device,
            ),
            weights: Tensor::from_data(
                TensorData::new(weights.clone(), [labels.len(), h, w]),
                device,
            ),
            weight_sum,
            host_weights: weights,
            single: Tensor::from_data(TensorData::new(single, [labels.len(), 1, h, w]), device),
            present: Tensor::from_data(TensorData::new(present, [classes]), device),
            host_single,
        }
    }
}

/// The weighted, merged cross-entropy of the module docs:
/// `logits [B, classes, H, W]` with `targets` -> a scalar `[1]`.
pub fn segmentation_loss(logits: Tensor<4>, targets: &LossTargets) -> Tensor<1> {
    let per_pixel = pixel_losses(logits, targets);
    weighted_mean(per_pixel, targets.weights.clone(), targets.weight_sum)
}

/// `segmentation_loss + dice_weight · dice_loss` (no Dice term when `dice_weight` is 0):
/// `logits [B, classes, H, W]` with `targets` -> a scalar `[1]`. When training on LibTorch,
/// one kernel computes the loss and its gradient in two passes over the logits
/// ([`crate::torch_kernels::segmentation_loss`]) where burn's tensor operations make some forty;
/// elsewhere it is the sum of the two functions.
pub fn segmentation_dice_loss(
    logits: Tensor<4>,
    targets: &LossTargets,
    dice_weight: f64,
) -> Tensor<1> {
    #[cfg(feature = "libtorch")]
    if crate::layers::torch::trains_on_libtorch(&logits) {
        return torch::segmentation_dice_loss(logits, targets, dice_weight);
    }
    let loss = segmentation_loss(logits.clone(), targets);
    if dice_weight == 0.0 {
        return loss;
    }
    loss + dice_loss(logits, targets).mul_scalar(dice_weight)
}

/// Which pixels [`hard_pixel_loss`] keeps.
#[derive(Config, Debug, PartialEq)]
pub struct HardPixels {
    /// A pixel is hard while its probability of an acceptable class is under this
    /// (BiSeNet's and mmsegmentation's 0.7).
    #[config(default = 0.7)]
    pub probability: f64,
    /// Share of the counted pixels kept at least, the hardest (BiSeNet's 1/16).
    #[config(default = 0.0625)]
    pub min_share: f64,
}

impl HardPixels {
    /// Whether the two numbers are shares in (0, 1].
    pub fn is_valid(&self) -> bool {
        let share = |v: f64| v.is_finite() && v > 0.0 && v <= 1.0;
        share(self.probability) && share(self.min_share)
    }

    /// The loss from which a pixel counts: `−ln(probability)`, lowered to the loss of the
    /// `ceil(min_share · n)`-th hardest of the `n` counted pixels when fewer are over it.
    /// `None` when no pixel counts.
    fn threshold(&self, losses: &[f32], weights: &[f32]) -> Option<f32> {
        let mut counted: Vec<f32> = losses
            .iter()
            .zip(weights)
            .filter(|&(_, &w)| w > 0.0)
            .map(|(&l, _)| l)
            .collect();
        if counted.is_empty() {
            return None;
        }
        let k = ((self.min_share * counted.len() as f64).ceil() as usize).clamp(1, counted.len());
        let (_, kth, _) = counted.select_nth_unstable_by(k - 1, |a, b| b.total_cmp(a));
        Some((-self.probability.ln() as f32).min(*kth))
    }
}

/// The cross-entropy of [`segmentation_loss`] over the hard pixels of `hard` only (module
/// docs): `logits [B, classes, H, W]` with `targets` -> a scalar `[1]`. Reads the pixel
/// losses back to the host once, to find the threshold.
pub fn hard_pixel_loss(logits: Tensor<4>, targets: &LossTargets, hard: &HardPixels) -> Tensor<1> {
    let per_pixel = pixel_losses(logits, targets);
    let losses = to_host(per_pixel.clone());
    let Some(threshold) = hard.threshold(&losses, &targets.host_weights) else {
        return weighted_mean(per_pixel, targets.weights.clone(), 0.0);
    };
    // The host decides which pixels count, so the weights and their sum agree exactly.
    let kept: Vec<f32> = losses
        .iter()
        .zip(&targets.host_weights)
        .map(|(&l, &w)| if l >= threshold { w } else { 0.0 })
        .collect();
    let kept_sum = kept.iter().map(|&w| f64::from(w)).sum();
    let kept = Tensor::from_data(TensorData::new(kept, per_pixel.dims()), &per_pixel.device());
    weighted_mean(per_pixel, kept, kept_sum)
}

/// `[B, H, W]`: each pixel's merged cross-entropy (module docs), 0 where ignored.
fn pixel_losses(logits: Tensor<4>, targets: &LossTargets) -> Tensor<3> {
    let max = logits.clone().max_dim(1).detach();
    let exp = (logits - max).exp();
    let all = exp.clone().sum_dim(1);
    // Clamped so an allowed set whose logits underflow gives a large, finite loss.
    let allowed = (exp * targets.allowed.clone()).sum_dim(1).clamp_min(1e-30);
    (all.log() - allowed.log()).squeeze_dim(1)
}

/// `Σ weights · losses / weight_sum`, 0 (not NaN) when nothing counts.
fn weighted_mean(losses: Tensor<3>, weights: Tensor<3>, weight_sum: f64) -> Tensor<1> {
    let weighted = (losses * weights).sum();
    if weight_sum > 0.0 {
        weighted.div_scalar(weight_sum)
    } else {
        weighted.mul_scalar(0.0)
    }
}

/// The soft Dice loss of the module docs: `logits [B, classes, H, W]` with `targets` -> a
/// scalar `[1]` in [0, 1] (0 when no pixel counts).
pub fn dice_loss(logits: Tensor<4>, targets: &LossTargets) -> Tensor<1> {
    let [_, classes, _, _] = logits.dims();
    let probabilities = burn::tensor::activation::softmax(logits, 1) * targets.single.clone();
    let truth = targets.allowed.clone() * targets.single.clone();
    let per_class = |t: Tensor<4>| -> Tensor<1> {
        t.swap_dims(0, 1)
            .reshape([classes as i32, -1])
            .sum_dim(1)
            .reshape([classes])
    };
    let overlap = per_class(probabilities.clone() * truth.clone());
    let total = per_class(probabilities) + per_class(truth);
    // smp's smoothing 0 and eps 1e-7: an absent class would read 0 / 0, and is masked out.
    let dice = overlap.mul_scalar(2.0) / total.clamp_min(1e-7);
    let present = targets.present.clone();
    let count = present.clone().sum();
    ((present.clone() - dice * present).sum() / count.clamp_min(1.0)).reshape([1])
}

/// The Lovász-softmax loss of the module docs: `logits [B, classes, H, W]` with `targets`
/// -> a scalar `[1]` (0 when no pixel counts). Reads the errors back to the host once, to
/// order them; the order carries no gradient, so the loss is `Σ error · weight` with the
/// weights computed there.
pub fn lovasz_loss(logits: Tensor<4>, targets: &LossTargets) -> Tensor<1> {
    let [batch, classes, h, w] = logits.dims();
    let single = targets.single.clone();
    let truth = targets.allowed.clone() * single.clone();
    let probabilities = burn::tensor::activation::softmax(logits, 1) * single;
    let errors = (truth - probabilities).abs();
    let host_errors = to_host(errors.clone());
    let plane = h * w;
    // The counted pixels (index into `[B, H, W]`, class), found once for all classes.
    let counted: Vec<(usize, u8)> = (targets.host_single.iter().copied().enumerate())
        .filter(|&(_, y)| y != IGNORE)
        .collect();
    let mut weights = vec![0.0f32; batch * classes * plane];
    let mut order = ErrorOrder::default();
    let mut counted_classes = 0usize;
    for class in 0..classes {
        let at = |p: usize| (p / plane * classes + class) * plane + p % plane;
        let pixels: Vec<(f32, bool)> = counted
            .iter()
            .map(|&(p, y)| {
                let error = host_errors.get(at(p)).copied().unwrap_or(0.0);
                (error, usize::from(y) == class)
            })
            .collect();
        let class_weights = order.lovasz_weights(&pixels);
        if class_weights.is_empty() {
            continue;
        }
        counted_classes += 1;
        for (&(p, _), weight) in counted.iter().zip(class_weights) {
            weights[at(p)] = weight;
        }
    }
    let weights = Tensor::from_data(
        TensorData::new(weights, [batch, classes, h, w]),
        &errors.device(),
    );
    let total = (errors * weights).sum();
    total.div_scalar(counted_classes.max(1) as f64)
}

/// A tensor's values on the host, row-major, outside the autodiff graph.
fn to_host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.detach()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap_or_default()
}

#[cfg(feature = "libtorch")]
// burn 0.22 marks LibTorch deprecated (models::device says why we use it).
#[allow(deprecated)]
mod torch {
    //! [`super::segmentation_dice_loss`] on LibTorch: a backend extension whose forward pass
    //! computes the loss and its gradient at once, and whose backward pass scales that
    //! gradient by the loss's.

    use burn::backend::autodiff::checkpoint::base::Checkpointer;
    use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::libtorch::TchTensor;
    use burn::backend::tensor::FloatTensor;
    use burn::backend::{
        Autodiff, AutodiffBackend, Backend, Dispatch, LibTorch, backend_extension,
    };
    use burn::tensor::Tensor;

    use super::LossTargets;
    use crate::torch_kernels::{self, LossInputs};

    pub(super) fn segmentation_dice_loss(
        logits: Tensor<4>,
        targets: &LossTargets,
        dice_weight: f64,
    ) -> Tensor<1> {
        Tensor::from_dispatch(<Dispatch as TorchLoss>::segmentation_dice_loss_torch(
            logits.into_dispatch(),
            targets.allowed.clone().into_dispatch(),
            targets.weights.clone().into_dispatch(),
            targets.single.clone().into_dispatch(),
            targets.present.clone().into_dispatch(),
            targets.weight_sum,
            dice_weight,
        ))
    }

    #[backend_extension(LibTorch, Autodiff)]
    pub trait TorchLoss: Backend {
        /// The loss of [`super::segmentation_dice_loss`], `[1]`.
        fn segmentation_dice_loss_torch(
            logits: FloatTensor<Self>,
            allowed: FloatTensor<Self>,
            weights: FloatTensor<Self>,
            single: FloatTensor<Self>,
            present: FloatTensor<Self>,
            weight_sum: f64,
            dice_weight: f64,
        ) -> FloatTensor<Self>;
    }

    /// The kernel on the tensors; panics only on shapes `LossTargets` never builds.
    fn kernel(
        logits: &tch::Tensor,
        [allowed, weights, single, present]: [&tch::Tensor; 4],
        weight_sum: f64,
        dice_weight: f64,
    ) -> (tch::Tensor, tch::Tensor) {
        let targets = LossInputs {
            allowed,
            weights,
            single,
            present,
            weight_sum,
        };
        torch_kernels::segmentation_loss(logits, targets, dice_weight)
            .unwrap_or_else(|error| panic!("the segmentation loss kernel: {error}"))
    }

    // Without autodiff (not used by training, but the extension needs it): the loss alone.
    impl TorchLoss for LibTorch {
        fn segmentation_dice_loss_torch(
            logits: TchTensor,
            allowed: TchTensor,
            weights: TchTensor,
            single: TchTensor,
            present: TchTensor,
            weight_sum: f64,
            dice_weight: f64,
        ) -> TchTensor {
            let targets = [&allowed, &weights, &single, &present].map(|t| &t.tensor);
            TchTensor::new(kernel(&logits.tensor, targets, weight_sum, dice_weight).0)
        }
    }

    impl<C: CheckpointStrategy> TorchLoss for Autodiff<LibTorch, C> {
        fn segmentation_dice_loss_torch(
            logits: FloatTensor<Self>,
            allowed: FloatTensor<Self>,
            weights: FloatTensor<Self>,
            single: FloatTensor<Self>,
            present: FloatTensor<Self>,
            weight_sum: f64,
            dice_weight: f64,
        ) -> FloatTensor<Self> {
            let targets = [allowed, weights, single, present].map(Self::inner);
            let targets = targets.each_ref().map(|t| &t.tensor);
            let (logits, node) = logits.into_parts();
            let (loss, grad) = kernel(&logits.tensor, targets, weight_sum, dice_weight);
            match LossBackward.prepare::<C>([node]).compute_bound().stateful() {
                OpsKind::Tracked(prep) => prep.finish(LogitsGradient(grad), TchTensor::new(loss)),
                OpsKind::UnTracked(prep) => prep.finish(TchTensor::new(loss)),
            }
        }
    }

    /// The loss's gradient with respect to the logits, for a loss gradient of one.
    struct LogitsGradient(tch::Tensor);

    // burn's backward state must be `Clone`; a shallow clone shares the values.
    impl Clone for LogitsGradient {
        fn clone(&self) -> Self {
            LogitsGradient(self.0.shallow_clone())
        }
    }

    impl std::fmt::Debug for LogitsGradient {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.debug_tuple("LogitsGradient")
                .field(&self.0.size())
                .finish()
        }
    }

    #[derive(Debug)]
    struct LossBackward;

    impl Backward<LibTorch, 1> for LossBackward {
        type State = LogitsGradient;

        fn backward(
            self,
            ops: Ops<Self::State, 1>,
            grads: &mut Gradients,
            _checkpointer: &mut Checkpointer,
        ) {
            let loss_grad: TchTensor = grads.consume::<LibTorch>(&ops.node);
            let [Some(parent)] = &ops.parents else {
                return;
            };
            let LogitsGradient(grad) = ops.state;
            grads.register::<LibTorch>(parent.id, TchTensor::new(grad * loss_grad.tensor));
        }
    }
}

/// Error levels [`ErrorOrder`] tells apart: errors in [0, 1] are ordered by
/// `⌊error · (LEVELS − 1)⌋`, ties by pixel, so by a counting sort (two linear passes) rather
/// than a comparison sort: it runs on the host for every class of every training step, over
/// the 262,144 pixels of a batch of four 256-px crops. Errors closer than 1/65,535 may swap
/// places; the loss moves by less than their difference.
const ERROR_LEVELS: usize = 1 << 16;

/// Buffers of the counting sort, reused across classes.
#[derive(Default)]
struct ErrorOrder {
    counts: Vec<u32>,
    order: Vec<u32>,
}

impl ErrorOrder {
    /// Each pixel's weight in the Lovász extension of the Jaccard loss of one class:
    /// `pixels[i] = (error, is the class)`. With the pixels in descending error, the `k`-th
    /// weighs `J_k − J_{k−1}`, where `J_k = 1 − (F − f_k) / (F + b_k)` for `F` pixels of the
    /// class, `f_k` of them and `b_k` others among the first `k`. Empty when no pixel is of
    /// the class (smp's `classes="present"`).
    fn lovasz_weights(&mut self, pixels: &[(f32, bool)]) -> Vec<f32> {
        let foreground = pixels.iter().filter(|(_, is)| *is).count();
        if foreground == 0 {
            return Vec::new();
        }
        let level = |e: f32| {
            // Descending: the largest error gets level 0.
            let rank = (e.clamp(0.0, 1.0) * (ERROR_LEVELS - 1) as f32) as usize;
            ERROR_LEVELS - 1 - rank.min(ERROR_LEVELS - 1)
        };
        self.counts.clear();
        self.counts.resize(ERROR_LEVELS + 1, 0);
        for &(e, _) in pixels {
            self.counts[level(e) + 1] += 1;
        }
        for l in 1..=ERROR_LEVELS {
            self.counts[l] += self.counts[l - 1];
        }
        self.order.clear();
        self.order.resize(pixels.len(), 0);
        for (i, &(e, _)) in pixels.iter().enumerate() {
            let slot = &mut self.counts[level(e)];
            self.order[*slot as usize] = i as u32;
            *slot += 1;
        }
        let total = foreground as f64;
        let (mut found, mut others, mut previous) = (0.0f64, 0.0f64, 0.0f64);
        let mut weights = vec![0.0f32; pixels.len()];
        for &i in &self.order {
            if pixels[i as usize].1 {
                found += 1.0;
            } else {
                others += 1.0;
            }
            let jaccard = 1.0 - (total - found) / (total + others);
            weights[i as usize] = (jaccard - previous) as f32;
            previous = jaccard;
        }
        weights
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::activation::log_softmax;

    fn device() -> Device {
        Device::flex()
    }

    fn scalar(t: Tensor<1>) -> f32 {
        t.into_data().try_to_vec::<f32>().unwrap_or_default()[0]
    }

    /// The targets of one 1×4 label.
    fn targets_of_one(labels: &[u8; 4], unlabelable: &[bool; 3], weights: &[f32]) -> LossTargets {
        LossTargets::new(
            &[LabelRef {
                pixels: labels,
                unlabelable,
            }],
            [1, 4],
            weights,
            &device(),
        )
    }

    /// 1 image, 3 classes, 1×4 pixels.
    fn logits() -> Tensor<4> {
        let values = vec![
            2.0, -1.0, 0.5, 0.0, // class 0
            0.0, 3.0, 0.5, 1.0, // class 1
            -1.0, 0.0, 0.5, 4.0, // class 2
        ];
        Tensor::from_data(TensorData::new(values, [1, 3, 1, 4]), &device())
    }

    #[test]
    fn without_masking_it_is_weighted_cross_entropy() {
        let targets = targets_of_one(&[0, 1, 255, 0], &[false; 3], &[1.0, 2.0, 1.0]);
        let loss = scalar(segmentation_loss(logits(), &targets));
        // By hand from log-softmax: pixels 0 (class 0, w 1), 1 (class 1, w 2), 3 (class 0, w 1).
        let logp = log_softmax(logits(), 1)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap_or_default();
        let lp = |c: usize, i: usize| logp[c * 4 + i];
        let expected = -(lp(0, 0) + 2.0 * lp(1, 1) + lp(0, 3)) / 4.0;
        assert!((loss - expected).abs() < 1e-5, "{loss} vs {expected}");
    }

    #[test]
    fn lane_markings_a_source_cannot_label_are_merged_into_its_road_only() {
        // Classes 0 road, 1 lane marking, 2 vehicle. Pixel 1 is labelled road but the network
        // says lane marking (logit 3): costly normally, nearly free when the source cannot
        // label markings (it calls them road).
        let weights = [1.0f32; 3];
        let loss_with = |labels: &[u8; 4], unlabelable: [bool; 3]| {
            scalar(segmentation_loss(
                logits(),
                &targets_of_one(labels, &unlabelable, &weights),
            ))
        };
        let logp = log_softmax(logits(), 1)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap_or_default();
        let road = [255u8, 0, 255, 255];
        let plain = loss_with(&road, [false; 3]);
        let merged = loss_with(&road, [false, true, false]);
        let expected_merged = -(logp[1].exp() + logp[4 + 1].exp()).ln();
        assert!((plain + logp[1]).abs() < 1e-5);
        assert!(
            (merged - expected_merged).abs() < 1e-5,
            "{merged} vs {expected_merged}"
        );
        assert!(merged < 0.1 && plain > 3.0);
        // The same marking prediction on a pixel labelled vehicle stays an error: a source
        // that cannot label markings does not call them vehicle.
        let vehicle = [255u8, 2, 255, 255];
        assert!(
            (loss_with(&vehicle, [false, true, false]) - loss_with(&vehicle, [false; 3])).abs()
                < 1e-6
        );
        // Nor is any other class a source cannot label merged into anything.
        let labelled_road_said_vehicle = [255u8, 255, 255, 0];
        assert!(
            (loss_with(&labelled_road_said_vehicle, [false, false, true])
                - loss_with(&labelled_road_said_vehicle, [false; 3]))
            .abs()
                < 1e-6
        );
        // Nothing counted: zero, not NaN.
        let t = targets_of_one(&[255; 4], &[false; 3], &weights);
        assert_eq!(scalar(segmentation_loss(logits(), &t)), 0.0);
    }

    #[test]
    fn hard_pixels_keep_the_unsure_pixels_and_at_least_the_hardest_share() {
        // Pixels 0 (class 0, weight 1), 1 (class 1, weight 2) and 3 (class 0, weight 1)
        // count; pixel 2 is ignored.
        let weights = [1.0f32, 2.0, 1.0];
        let targets = targets_of_one(&[0, 1, 255, 0], &[false; 3], &weights);
        let logp = log_softmax(logits(), 1)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap_or_default();
        let loss_of = [-logp[0], -logp[4 + 1], -logp[3]];
        // Pixel 3's class-0 logit is 0 against 4 for class 2: by far the hardest.
        assert!(loss_of[2] > loss_of[0] && loss_of[2] > loss_of[1]);
        let hard = |probability: f64, min_share: f64| {
            let h = HardPixels::new()
                .with_probability(probability)
                .with_min_share(min_share);
            assert!(h.is_valid());
            scalar(hard_pixel_loss(logits(), &targets, &h))
        };
        // Probability 1: every pixel is unsure, so it is the plain loss.
        let plain = scalar(segmentation_loss(logits(), &targets));
        assert!((hard(1.0, 0.1) - plain).abs() < 1e-6);
        // A threshold no pixel reaches keeps the hardest third: pixel 3 alone.
        assert!((hard(1e-9, 0.3) - loss_of[2]).abs() < 1e-5);
        // A probability between pixel 0's and pixel 1's keeps the harder of them and pixel 3,
        // weighted as the plain loss weighs them.
        let p = |i: usize| (-loss_of[i]).exp();
        let (easy, harder) = if p(0) > p(1) { (0, 1) } else { (1, 0) };
        let between = f64::from((p(easy) + p(harder)) / 2.0);
        let w = |i: usize| [1.0f32, 2.0, 1.0][i];
        let expected = (w(harder) * loss_of[harder] + loss_of[2]) / (w(harder) + 1.0);
        let got = hard(between, 0.01);
        assert!((got - expected).abs() < 1e-5, "{got} vs {expected}");
        // Nothing counted: zero, not NaN.
        let t = targets_of_one(&[255; 4], &[false; 3], &weights);
        let none = scalar(hard_pixel_loss(logits(), &t, &HardPixels::new()));
        assert_eq!(none, 0.0);
        // Shares outside (0, 1] are refused.
        assert!(!HardPixels::new().with_probability(0.0).is_valid());
        assert!(!HardPixels::new().with_min_share(1.5).is_valid());
    }

    #[test]
    fn dice_averages_the_overlap_of_the_classes_the_labels_hold() {
        let targets_of = |labels: &[u8; 4], unlabelable: [bool; 3]| {
            targets_of_one(labels, &unlabelable, &[1.0; 3])
        };
        let p = burn::tensor::activation::softmax(logits(), 1)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap_or_default();
        let p = |c: usize, i: usize| p[c * 4 + i];
        // Pixels 0 and 3 are class 0, pixel 1 class 1, pixel 2 ignored; class 2 is absent
        // and does not count.
        let dice = scalar(dice_loss(
            logits(),
            &targets_of(&[0, 1, 255, 0], [false; 3]),
        ));
        let class0 = 2.0 * (p(0, 0) + p(0, 3)) / (p(0, 0) + p(0, 1) + p(0, 3) + 2.0);
        let class1 = 2.0 * p(1, 1) / (p(1, 0) + p(1, 1) + p(1, 3) + 1.0);
        let expected = 1.0 - (class0 + class1) / 2.0;
        assert!((dice - expected).abs() < 1e-5, "{dice} vs {expected}");
        // A road pixel of a source that cannot label markings (merged) does not count:
        // only pixel 3 (vehicle) does.
        let merged = scalar(dice_loss(
            logits(),
            &targets_of(&[255, 0, 255, 2], [false, true, false]),
        ));
        let expected = 1.0 - 2.0 * p(2, 3) / (p(2, 3) + 1.0);
        assert!((merged - expected).abs() < 1e-5, "{merged} vs {expected}");
        // Nothing counted: zero.
        let none = scalar(dice_loss(logits(), &targets_of(&[255; 4], [false; 3])));
        assert_eq!(none, 0.0);
    }

    /// Berman et al.'s reference, with a comparison sort: `Σ_k sorted_error_k · (J_k − J_{k−1})`.
    fn lovasz_by_sorting(pixels: &[(f32, bool)]) -> f32 {
        let mut sorted = pixels.to_vec();
        sorted.sort_by(|a, b| b.0.total_cmp(&a.0));
        let total = sorted.iter().filter(|p| p.1).count() as f32;
        let (mut found, mut others, mut previous, mut loss) = (0.0, 0.0, 0.0, 0.0);
        for (e, is) in sorted {
            if is {
                found += 1.0;
            } else {
                others += 1.0;
            }
            let jaccard = 1.0 - (total - found) / (total + others);
            loss += e * (jaccard - previous);
            previous = jaccard;
        }
        loss
    }

    #[test]
    fn lovasz_orders_the_errors_of_each_present_class() {
        let targets = targets_of_one(&[0, 1, 255, 0], &[false; 3], &[1.0; 3]);
        let p = burn::tensor::activation::softmax(logits(), 1)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap_or_default();
        // Pixels 0, 1 and 3 count (pixel 2 is ignored); classes 0 and 1 are present.
        let class_pixels = |c: usize, labels: [u8; 3]| -> Vec<(f32, bool)> {
            [0usize, 1, 3]
                .iter()
                .zip(labels)
                .map(|(&i, y)| {
                    let truth = usize::from(y) == c;
                    ((f32::from(u8::from(truth)) - p[c * 4 + i]).abs(), truth)
                })
                .collect()
        };
        let expected = (lovasz_by_sorting(&class_pixels(0, [0, 1, 0]))
            + lovasz_by_sorting(&class_pixels(1, [0, 1, 0])))
            / 2.0;
        let got = scalar(lovasz_loss(logits(), &targets));
        assert!((got - expected).abs() < 1e-4, "{got} vs {expected}");
        // Confident and right everywhere: nearly 0. Nothing counted: 0, not NaN.
        let sure = Tensor::from_data(
            TensorData::new(
                vec![
                    20.0, 0.0, 0.0, 20.0, //
                    0.0, 20.0, 0.0, 0.0, //
                    0.0, 0.0, 0.0, 0.0,
                ],
                [1, 3, 1, 4],
            ),
            &device(),
        );
        assert!(scalar(lovasz_loss(sure, &targets)) < 1e-6);
        let none = targets_of_one(&[255; 4], &[false; 3], &[1.0; 3]);
        assert_eq!(scalar(lovasz_loss(logits(), &none)), 0.0);
    }

    #[test]
    fn the_counting_sort_gives_the_weights_of_a_comparison_sort() {
        // 2,000 pseudo-random pixels, a third of them of the class; errors 1/65,535 apart at
        // least, so the order is the same.
        let pixels: Vec<(f32, bool)> = (0..2000u32)
            .map(|i| {
                let e = (i.wrapping_mul(2_654_435_761) % 60_000) as f32 / 60_000.0;
                (e, i % 3 == 0)
            })
            .collect();
        let weights = ErrorOrder::default().lovasz_weights(&pixels);
        let loss: f32 = pixels.iter().zip(&weights).map(|(p, w)| p.0 * w).sum();
        let expected = lovasz_by_sorting(&pixels);
        assert!((loss - expected).abs() < 1e-4, "{loss} vs {expected}");
        // The weights sum to the Jaccard loss of predicting nothing right: 1.
        let sum: f32 = weights.iter().sum();
        assert!((sum - 1.0).abs() < 1e-5, "{sum}");
        assert!(
            ErrorOrder::default()
                .lovasz_weights(&[(0.5, false)])
                .is_empty()
        );
    }
}

/// The LibTorch kernel of [`segmentation_dice_loss`] against burn's tensor operations. Runs in
/// a build with `--features libtorch` (not in CI, which has no libtorch: docs/gpu.md).
#[cfg(all(test, feature = "libtorch"))]
mod torch_tests {
    use burn::tensor::{Distribution, Tensor};

    use super::*;
    use crate::qnet::tensor_values as values;

    /// Two 48 × 50 images (more pixels than one block of the kernel, and a partial block), a
    /// tenth of the pixels ignored, the second from a source that cannot label lane markings.
    fn targets(device: &Device) -> LossTargets {
        let plane = 48 * 50;
        let labels: Vec<Vec<u8>> = (0..2u32)
            .map(|b| {
                (0..plane as u32)
                    .map(|i| {
                        let r = (i + 7919 * b).wrapping_mul(2_654_435_761) >> 24;
                        if r % 10 == 0 { IGNORE } else { (r % 5) as u8 }
                    })
                    .collect()
            })
            .collect();
        let unlabelable = [
            vec![false; 5],
            (0..5u8)
                .map(|c| datasets::may_stand_for(0, c) || datasets::may_stand_for(4, c))
                .collect::<Vec<_>>(),
        ];
        assert!(
            unlabelable[1].contains(&true),
            "the second source merges a class"
        );
        let refs: Vec<LabelRef<'_>> = labels
            .iter()
            .zip(&unlabelable)
            .map(|(pixels, unlabelable)| LabelRef {
                pixels,
                unlabelable,
            })
            .collect();
        LossTargets::new(&refs, [48, 50], &[0.6, 1.2, 1.0, 2.0, 0.5], device)
    }

    /// The loss and its gradient with respect to the logits.
    fn loss_and_gradient(
        logits: &Tensor<4>,
        loss: impl Fn(Tensor<4>) -> Tensor<1>,
    ) -> (Vec<f32>, Vec<f32>) {
        let logits = logits.clone().detach().require_grad();
        let value = loss(logits.clone());
        let grads = value.clone().mul_scalar(0.5).backward();
        let gradient = logits.grad(&grads).expect("a gradient of the logits");
        (values(value), values(gradient))
    }

    #[test]
    #[allow(deprecated)]
    fn the_kernel_gives_burns_loss_and_gradient_whatever_the_threads() {
        let device = Device::libtorch().autodiff();
        let targets = targets(&device);
        let logits = Tensor::<4>::random([2, 5, 48, 50], Distribution::Normal(0.0, 3.0), &device);
        for dice_weight in [0.0, 2.0] {
            let kernel = loss_and_gradient(&logits, |z| {
                segmentation_dice_loss(z, &targets, dice_weight)
            });
            let burns = loss_and_gradient(&logits, |z| {
                let loss = segmentation_loss(z.clone(), &targets);
                loss + dice_loss(z, &targets).mul_scalar(dice_weight)
            });
            assert!(
                (kernel.0[0] - burns.0[0]).abs() <= 1e-5 * burns.0[0].abs(),
                "dice {dice_weight}: loss {} against burn's {}",
                kernel.0[0],
                burns.0[0]
            );
            let scale = burns.1.iter().fold(0f32, |m, v| m.max(v.abs()));
            assert!(scale > 0.0);
            for (i, (k, b)) in kernel.1.iter().zip(&burns.1).enumerate() {
                assert!(
                    (k - b).abs() <= 1e-4 * scale,
                    "dice {dice_weight}: gradient[{i}] {k} against burn's {b}"
                );
            }
            // The kernel sums in fixed blocks, so one thread gives the same bits as two.
            crate::set_network_threads(1);
            let one_thread = loss_and_gradient(&logits, |z| {
                segmentation_dice_loss(z, &targets, dice_weight)
            });
            crate::set_network_threads(2);
            assert_eq!(
                one_thread, kernel,
                "dice {dice_weight}: one thread against two"
            );
        }
    }
}
