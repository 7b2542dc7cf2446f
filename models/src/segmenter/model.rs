//! The network: a ResNet-style encoder of basic blocks, a pyramid pooling module, optional
//! light skip refinements at stride 4 and 2, a 1×1 classifier and bilinear upsampling to
//! the input size, as segmentation_models.pytorch's PSPNet (which the golf-cart thesis used),
//! plus an optional auxiliary head for training.
//!
//! ```text
//! image [B,3,H,W]
//!  └ stem: conv 7×7/2 (64w) BN ReLU                            stride 2   ─┐ fine skip
//!    max-pool 3×3/2                                             stride 4    │ refinement
//!  └ stage 1: basic blocks (64w)                                stride 4   ─┐ skip refinement
//!  └ stage 2: basic blocks (128w), first block strided          stride 8    │ (optional) and
//!  └ stage 3, 4 (depth 4, 5): 256w, 512w, strided or dilated                │ aux head input
//!  └ pyramid pooling: for each bin b in (1, 2, 3, 6): adaptive average pool to b×b,
//!      1×1 conv to C/len(bins) (BN ReLU; no BN for b = 1), bilinear back up;
//!      concat [branches..., features], 1×1 conv to psp_channels BN ReLU, channel dropout
//!  └ (mid skip refinement, depth 4 and 5: the same with stage 2, to mid_skip_channels at
//!      stride 8)
//!  └ (skip refinement: 1×1 convs of the pyramid output and of stage 1 to skip_channels,
//!      concat at stride 4, 3×3 conv BN ReLU)
//!  └ (fine skip refinement: the same with the stem's output, to fine_skip_channels at
//!      stride 2)
//!  └ classifier 1×1 -> classes, bilinear upsampling to H×W     logits [B,classes,H,W]
//! ```
//!
//! Parameter names follow the module fields (`encoder.stages.0.blocks.1.conv2.weight`, ...);
//! `scripts/segmenter_reference.py` builds the same tree in PyTorch, so its weights load here.

use crate::layers::relu;
use burn::config::Config;
use burn::module::{Module, Param, ParamId, RunningState};
use burn::nn::conv::Conv2d;
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, PaddingConfig2d};
use burn::tensor::module::{adaptive_avg_pool2d, interpolate};
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use burn::tensor::{Device, Tensor, TensorData};
use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::error::{Result, SegmenterError};

/// ResNet's channel widths: stem and stages 1-4, before the width multiplier.
const RESNET_WIDTHS: [usize; 5] = [64, 64, 128, 256, 512];

/// The segmenter's architecture and input normalisation. The defaults are the thesis's
/// smp PSPNet: ResNet-18 blocks, encoder depth 3 (output stride 8), bins 1, 2, 3, 6, 512
/// pyramid channels, dropout 0.2, for the project's 5 classes.
#[derive(Config, Debug, PartialEq)]
pub struct PspNetConfig {
    /// Output classes.
    #[config(default = 5)]
    pub classes: usize,
    /// Basic blocks in each of the 4 encoder stages: `[2, 2, 2, 2]` is ResNet-18,
    /// `[3, 4, 6, 3]` ResNet-34. Stages beyond the depth are not built.
    #[config(default = "vec![2, 2, 2, 2]")]
    pub blocks: Vec<usize>,
    /// Channel multiplier over ResNet's 64, 64, 128, 256, 512 (rounded, at least 1).
    #[config(default = 1.0)]
    pub width: f64,
    /// Encoder depth as smp counts it: the stem is 1, each stage adds 1. Depth 3 ends after
    /// stage 2 (output stride 8); 4 and 5 add stages 3 and 4.
    #[config(default = 3)]
    pub depth: usize,
    /// Dilate stages 3 and 4 (by 2 and 4) instead of striding, so any depth keeps stride 8.
    #[config(default = false)]
    pub dilated: bool,
    /// Pyramid bins: each branch pools the features to b×b.
    #[config(default = "vec![1, 2, 3, 6]")]
    pub bins: Vec<usize>,
    /// Output channels of the pyramid pooling module.
    #[config(default = 512)]
    pub psp_channels: usize,
    /// Channel-dropout probability after the pyramid module (training only).
    #[config(default = 0.2)]
    pub dropout: f64,
    /// Channels of a refinement at stride 8, on stage 2's output, before the stride-4 one;
    /// 0 turns it off. Only for depth 4 and 5, where stage 2 would otherwise reach only the
    /// aux head (strided, the pyramid pools stride-16 or stride-32 features; dilated, stride-8
    /// ones, so the refinement then fuses at one size).
    #[config(default = 0)]
    pub mid_skip_channels: usize,
    /// Channels of the light skip refinement at stride 4; 0 turns it off.
    #[config(default = 0)]
    pub skip_channels: usize,
    /// Channels of a second refinement at stride 2, on the stem's output (after the stride-4
    /// one when both are on); 0 turns it off. A head at stride 4 of a 256-px image blurs
    /// objects a few pixels wide: docs/segmenter.md measures what it costs.
    #[config(default = 0)]
    pub fine_skip_channels: usize,
    /// An auxiliary classifier on the second-to-last encoder stage (training only).
    #[config(default = false)]
    pub aux_head: bool,
    /// Bilinear upsampling with aligned corners (smp and PyTorch's UpsamplingBilinear2d).
    #[config(default = true)]
    pub align_corners: bool,
    /// Per-channel mean of the input images in 0-255 units (ImageNet's by default;
    /// `pipeline dataset stats` gives a dataset's own).
    #[config(default = "[123.675, 116.28, 103.53]")]
    pub mean: [f32; 3],
    /// Per-channel standard deviation in 0-255 units.
    #[config(default = "[58.395, 57.12, 57.375]")]
    pub std: [f32; 3],
    /// Normalise each image by its own per-channel mean and standard deviation instead of
    /// `mean` and `std`, so a darker, brighter or flatter camera gives the network the same
    /// input (for images from another camera than the training set's).
    #[config(default = false)]
    pub per_image_normalisation: bool,
}

impl PspNetConfig {
    /// Checks that the settings describe a buildable network.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(SegmenterError::Config(m));
        if self.classes == 0 {
            return bad("classes must be at least 1".into());
        }
        if !(2..=5).contains(&self.depth) {
            return bad(format!("depth must be 2 to 5, not {}", self.depth));
        }
        if self.blocks.len() != 4 || self.blocks.contains(&0) {
            return bad(format!(
                "blocks must list 4 stages of at least one block, not {:?}",
                self.blocks
            ));
        }
        if !(self.width.is_finite() && self.width > 0.0) {
            return bad(format!("width must be positive, not {}", self.width));
        }
        if self.bins.is_empty() || self.bins.contains(&0) {
            return bad(format!("bins must be positive sizes, not {:?}", self.bins));
        }
        if self.psp_channels == 0 {
            return bad("psp_channels must be at least 1".into());
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return bad(format!("dropout must be in [0, 1), not {}", self.dropout));
        }
        if self.skip_channels > 0 && self.depth < 3 {
            return bad("the skip refinement needs depth 3 or more".into());
        }
        if self.mid_skip_channels > 0 && self.depth < 4 {
            return bad("the mid skip refinement needs depth 4 or more".into());
        }
        if self.std.iter().any(|&s| !(s.is_finite() && s > 0.0)) {
            return bad(format!("std must be positive, not {:?}", self.std));
        }
        Ok(())
    }

    /// Channels after the stem (index 0) and after each stage (1-4).
    pub fn widths(&self) -> [usize; 5] {
        RESNET_WIDTHS.map(|c| ((c as f64 * self.width).round() as usize).max(1))
    }

    /// Number of encoder stages built (depth minus the stem).
    pub fn stages(&self) -> usize {
        self.depth - 1
    }

    /// Stride and dilation of stage `index` (0-based).
    fn stage_geometry(&self, index: usize) -> (usize, usize) {
        match (index, self.dilated) {
            (0, _) => (1, 1),
            (1, _) => (2, 1),
            (2, true) => (1, 2),
            (3, true) => (1, 4),
            _ => (2, 1),
        }
    }

    /// Output stride of the encoder (input size over feature size).
    pub fn output_stride(&self) -> usize {
        4 * (1..self.stages())
            .map(|i| self.stage_geometry(i).0)
            .product::<usize>()
    }

    /// Channels of each pyramid branch.
    fn branch_channels(&self, features: usize) -> usize {
        (features / self.bins.len()).max(1)
    }

    /// Builds the network with weights drawn from a ChaCha generator seeded with 0 (see
    /// [`PspNetConfig::init_seeded`]).
    pub fn init(&self, device: &Device) -> Result<PspNet> {
        self.init_seeded(device, 0)
    }

    /// Builds the network: convolution weights He-uniform (bound √(6 / fan-in)) from
    /// `ChaCha8Rng::seed_from_u64(seed)` in field order, biases zero, batch norms at
    /// γ = 1, β = 0 and running statistics 0 / 1. Parameter ids are numbered in the same
    /// order, so the same seed gives the same network and the same record bytes.
    pub fn init_seeded(&self, device: &Device, seed: u64) -> Result<PspNet> {
        self.validate()?;
        let mut init = Init::new(device, seed);
        let widths = self.widths();
        let encoder = Encoder::new(self, &mut init);
        let features = widths[self.stages()];
        let pyramid = PyramidPooling::new(self, features, &mut init);
        // Each refinement takes the channels of the one before it (the pyramid's first).
        let mut head_channels = self.psp_channels;
        let mid_skip = SkipRefinement::chained(
            widths[2],
            self.mid_skip_channels,
            &mut head_channels,
            &mut init,
        );
        let skip =
            SkipRefinement::chained(widths[1], self.skip_channels, &mut head_channels, &mut init);
        let fine_skip = SkipRefinement::chained(
            widths[0],
            self.fine_skip_channels,
            &mut head_channels,
            &mut init,
        );
        let classifier = init.conv(head_channels, self.classes, 1, 1, 1, true);
        let aux = self
            .aux_head
            .then(|| AuxHead::new(widths[self.stages() - 1], self.classes, &mut init));
        Ok(PspNet {
            encoder,
            pyramid,
            mid_skip,
            skip,
            fine_skip,
            classifier,
            aux,
            dropout: self.dropout,
            align_corners: self.align_corners,
        })
    }
}

/// Seeded, deterministic parameter construction (burn's own initialisers draw from the
/// backend's process-wide generator, which parallel tests and thread counts would disturb).
struct Init {
    device: Device,
    rng: ChaCha8Rng,
    next_id: u64,
}

impl Init {
    fn new(device: &Device, seed: u64) -> Init {
        Init {
            device: device.clone(),
            rng: ChaCha8Rng::seed_from_u64(seed),
            next_id: 1,
        }
    }

    fn id(&mut self) -> ParamId {
        let id = ParamId::from(self.next_id);
        self.next_id += 1;
        id
    }

    fn param<const D: usize>(&mut self, data: TensorData) -> Param<Tensor<D>> {
        // `from_tensor` marks the parameter trainable (effective on an autodiff device);
        // re-creating it keeps that and gives it the next deterministic id.
        let (_, value, mapper) =
            Param::from_tensor(Tensor::from_data(data, &self.device)).consume();
        Param::from_mapped_value(self.id(), value, mapper)
    }

    /// A square convolution with "same" padding for odd kernels (scaled by the dilation).
    fn conv(
        &mut self,
        input: usize,
        output: usize,
        kernel: usize,
        stride: usize,
        dilation: usize,
        bias: bool,
    ) -> Conv2d {
        let fan_in = input * kernel * kernel;
        let bound = (6.0 / fan_in as f64).sqrt() as f32;
        let weights: Vec<f32> = (0..output * fan_in)
            .map(|_| self.rng.random_range(-bound..=bound))
            .collect();
        let weight = self.param(TensorData::new(weights, [output, input, kernel, kernel]));
        let bias = bias.then(|| self.param(TensorData::new(vec![0.0f32; output], [output])));
        let pad = kernel / 2 * dilation;
        Conv2d {
            weight,
            bias,
            stride: [stride, stride],
            kernel_size: [kernel, kernel],
            dilation: [dilation, dilation],
            groups: 1,
            padding: PaddingConfig2d::Explicit(pad, pad, pad, pad),
        }
    }

    fn batch_norm(&mut self, channels: usize) -> BatchNorm {
        let gamma = self.param(TensorData::new(vec![1.0f32; channels], [channels]));
        let beta = self.param(TensorData::new(vec![0.0f32; channels], [channels]));
        let mean_id = self.id();
        let var_id = self.id();
        BatchNorm {
            gamma,
            beta,
            training: Param::from_bool(true),
            running_mean: RunningState::with_id(mean_id, Tensor::zeros([channels], &self.device)),
            running_var: RunningState::with_id(var_id, Tensor::ones([channels], &self.device)),
            momentum: 0.1,
            epsilon: 1e-5,
        }
    }

    /// A convolution without bias followed by batch norm.
    fn conv_norm(
        &mut self,
        input: usize,
        output: usize,
        kernel: usize,
        stride: usize,
        dilation: usize,
    ) -> ConvNorm {
        ConvNorm {
            conv: self.conv(input, output, kernel, stride, dilation, false),
            norm: Some(self.batch_norm(output)),
        }
    }
}

/// A convolution and, usually, a batch norm; ReLU is left to the caller.
#[derive(Module, Debug)]
pub struct ConvNorm {
    pub conv: Conv2d,
    pub norm: Option<BatchNorm>,
}

/// Multiply-accumulates of a convolution on a `size` input, and its output size.
fn conv_macs(conv: &Conv2d, size: [usize; 2]) -> (u64, [usize; 2]) {
    let [out_c, in_c, kh, kw] = conv.weight.dims();
    let pad = match conv.padding {
        PaddingConfig2d::Explicit(top, left, _, _) => [top, left],
        _ => [0, 0],
    };
    let out = [0, 1].map(|i| {
        let k = conv.kernel_size[i];
        (size[i] + 2 * pad[i] - conv.dilation[i] * (k - 1) - 1) / conv.stride[i] + 1
    });
    let macs = (out_c * in_c * kh * kw) as u64 * (out[0] * out[1]) as u64;
    (macs, out)
}

impl ConvNorm {
    /// Multiply-accumulates on a `size` input, and the output size.
    pub fn macs(&self, size: [usize; 2]) -> (u64, [usize; 2]) {
        conv_macs(&self.conv, size)
    }

    fn visit_batch_norms(&mut self, visit: &mut dyn FnMut(&mut BatchNorm)) {
        if let Some(norm) = &mut self.norm {
            visit(norm);
        }
    }

    /// `[B, C_in, H, W] -> [B, C_out, H / stride, W / stride]`.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let x = crate::layers::conv2d(&self.conv, x);
        match &self.norm {
            Some(norm) => crate::layers::batch_norm(norm, x),
            None => x,
        }
    }
}

/// ResNet's basic block: two 3×3 conv-BN, ReLU between, identity (or 1×1 conv-BN when the
/// shape changes) added before the last ReLU.
#[derive(Module, Debug)]
pub struct BasicBlock {
    pub conv1: ConvNorm,
    pub conv2: ConvNorm,
    pub downsample: Option<ConvNorm>,
}

impl BasicBlock {
    fn new(
        input: usize,
        output: usize,
        stride: usize,
        dilation: usize,
        init: &mut Init,
    ) -> BasicBlock {
        BasicBlock {
            conv1: init.conv_norm(input, output, 3, stride, dilation),
            conv2: init.conv_norm(output, output, 3, 1, dilation),
            downsample: (stride != 1 || input != output)
                .then(|| init.conv_norm(input, output, 1, stride, 1)),
        }
    }

    /// Multiply-accumulates on a `size` input, and the output size.
    pub fn macs(&self, size: [usize; 2]) -> (u64, [usize; 2]) {
        let (a, mid) = self.conv1.macs(size);
        let (b, out) = self.conv2.macs(mid);
        let c = self.downsample.as_ref().map_or(0, |d| d.macs(size).0);
        (a + b + c, out)
    }

    fn visit_batch_norms(&mut self, visit: &mut dyn FnMut(&mut BatchNorm)) {
        self.conv1.visit_batch_norms(visit);
        self.conv2.visit_batch_norms(visit);
        if let Some(down) = &mut self.downsample {
            down.visit_batch_norms(visit);
        }
    }

    /// `[B, C_in, H, W] -> [B, C_out, H / stride, W / stride]`.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let shortcut = match &self.downsample {
            Some(down) => down.forward(x.clone()),
            None => x.clone(),
        };
        let y = relu(self.conv1.forward(x));
        relu(self.conv2.forward(y) + shortcut)
    }
}

/// One encoder stage: a run of basic blocks, the first one striding.
#[derive(Module, Debug)]
pub struct Stage {
    pub blocks: Vec<BasicBlock>,
}

impl Stage {
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.blocks.iter().fold(x, |x, block| block.forward(x))
    }
}

/// The ResNet encoder, truncated at the configured depth.
#[derive(Module, Debug)]
pub struct Encoder {
    pub stem: ConvNorm,
    pub pool: MaxPool2d,
    pub stages: Vec<Stage>,
}

impl Encoder {
    fn new(config: &PspNetConfig, init: &mut Init) -> Encoder {
        let widths = config.widths();
        let stem = init.conv_norm(3, widths[0], 7, 2, 1);
        let pool = MaxPool2dConfig::new([3, 3])
            .with_strides([2, 2])
            .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
            .init();
        let stages = (0..config.stages())
            .map(|s| {
                let (stride, dilation) = config.stage_geometry(s);
                let blocks = (0..config.blocks[s])
                    .map(|b| {
                        let input = if b == 0 { widths[s] } else { widths[s + 1] };
                        let stride = if b == 0 { stride } else { 1 };
                        BasicBlock::new(input, widths[s + 1], stride, dilation, init)
                    })
                    .collect();
                Stage { blocks }
            })
            .collect();
        Encoder { stem, pool, stages }
    }

    /// The stem's output and every stage's: `[B, 3, H, W] -> EncoderFeatures { stem:
    /// [B, C_0, H / 2, W / 2], stages: [[B, C_s, H / stride_s, W / stride_s]; stages] }`.
    pub fn forward(&self, images: Tensor<4>) -> EncoderFeatures {
        let stem = relu(self.stem.forward(images));
        let mut x = crate::layers::max_pool2d(&self.pool, stem.clone());
        let mut stages = Vec::with_capacity(self.stages.len());
        for stage in &self.stages {
            x = stage.forward(x);
            stages.push(x.clone());
        }
        EncoderFeatures { stem, stages }
    }
}

/// What the encoder gives the heads.
#[derive(Debug)]
pub struct EncoderFeatures {
    /// After the stem's convolution (stride 2, before the max-pool).
    pub stem: Tensor<4>,
    /// After each stage.
    pub stages: Vec<Tensor<4>>,
}

/// One pyramid branch: pool to `bin`×`bin`, 1×1 conv (+BN unless the bin is 1, where a
/// batch of one would have no statistics), ReLU.
#[derive(Module, Debug)]
pub struct PoolBranch {
    pub bin: usize,
    pub conv: ConvNorm,
}

/// The pyramid pooling module.
#[derive(Module, Debug)]
pub struct PyramidPooling {
    pub branches: Vec<PoolBranch>,
    pub bottleneck: ConvNorm,
}

impl PyramidPooling {
    fn new(config: &PspNetConfig, features: usize, init: &mut Init) -> PyramidPooling {
        let branch = config.branch_channels(features);
        let branches = config
            .bins
            .iter()
            .map(|&bin| PoolBranch {
                bin,
                conv: if bin == 1 {
                    ConvNorm {
                        conv: init.conv(features, branch, 1, 1, 1, true),
                        norm: None,
                    }
                } else {
                    init.conv_norm(features, branch, 1, 1, 1)
                },
            })
            .collect::<Vec<_>>();
        let concat = features + branch * config.bins.len();
        PyramidPooling {
            branches,
            bottleneck: init.conv_norm(concat, config.psp_channels, 1, 1, 1),
        }
    }

    fn visit_batch_norms(&mut self, visit: &mut dyn FnMut(&mut BatchNorm)) {
        for branch in &mut self.branches {
            branch.conv.visit_batch_norms(visit);
        }
        self.bottleneck.visit_batch_norms(visit);
    }

    /// `[B, C, h, w] -> [B, psp_channels, h, w]`.
    pub fn forward(&self, x: Tensor<4>, align_corners: bool) -> Tensor<4> {
        let [_, _, h, w] = x.dims();
        let mut parts: Vec<Tensor<4>> = self
            .branches
            .iter()
            .map(|b| {
                let pooled = adaptive_avg_pool2d(x.clone(), [b.bin, b.bin]);
                resize(relu(b.conv.forward(pooled)), [h, w], align_corners)
            })
            .collect();
        parts.push(x);
        relu(self.bottleneck.forward(Tensor::cat(parts, 1)))
    }
}

/// A light skip refinement: coarse features (the pyramid output, or the refinement before)
/// and finer encoder features (stage 2's at stride 8, stage 1's at stride 4, the stem's at
/// stride 2), each 1×1-projected to `channels`, concatenated at the finer size and fused by
/// a 3×3 conv.
#[derive(Module, Debug)]
pub struct SkipRefinement {
    pub low: ConvNorm,
    pub high: ConvNorm,
    pub fuse: ConvNorm,
}

impl SkipRefinement {
    fn new(low: usize, high: usize, channels: usize, init: &mut Init) -> SkipRefinement {
        SkipRefinement {
            low: init.conv_norm(low, channels, 1, 1, 1),
            high: init.conv_norm(high, channels, 1, 1, 1),
            fuse: init.conv_norm(2 * channels, channels, 3, 1, 1),
        }
    }

    /// A refinement to `channels` (none when 0) of the `*high`-channel head with a skip of
    /// `low` channels; `*high` becomes what the head has after it.
    fn chained(
        low: usize,
        channels: usize,
        high: &mut usize,
        init: &mut Init,
    ) -> Option<SkipRefinement> {
        (channels > 0).then(|| {
            let refinement = SkipRefinement::new(low, *high, channels, init);
            *high = channels;
            refinement
        })
    }

    fn visit_batch_norms(&mut self, visit: &mut dyn FnMut(&mut BatchNorm)) {
        for layer in [&mut self.low, &mut self.high, &mut self.fuse] {
            layer.visit_batch_norms(visit);
        }
    }

    /// `high [B, P, h, w]`, `low [B, L, H, W] -> [B, channels, H, W]` (`H, W` 1, 2 or 4
    /// times `h, w`).
    pub fn forward(&self, high: Tensor<4>, low: Tensor<4>, align_corners: bool) -> Tensor<4> {
        let [_, _, h, w] = low.dims();
        let high = resize(relu(self.high.forward(high)), [h, w], align_corners);
        let low = relu(self.low.forward(low));
        relu(self.fuse.forward(Tensor::cat(vec![high, low], 1)))
    }
}

/// The auxiliary head: 3×3 conv-BN-ReLU and a 1×1 classifier.
#[derive(Module, Debug)]
pub struct AuxHead {
    pub conv: ConvNorm,
    pub classifier: Conv2d,
}

impl AuxHead {
    fn new(input: usize, classes: usize, init: &mut Init) -> AuxHead {
        AuxHead {
            conv: init.conv_norm(input, input, 3, 1, 1),
            classifier: init.conv(input, classes, 1, 1, 1, true),
        }
    }
}

/// What a training forward pass gives: the logits and, with the aux head, its logits.
#[derive(Debug)]
pub struct Heads {
    /// `[B, classes, H, W]`.
    pub logits: Tensor<4>,
    /// `[B, classes, H, W]`, when the network has an auxiliary head.
    pub aux: Option<Tensor<4>>,
}

/// The PSPNet-style segmenter; build it with [`PspNetConfig::init`].
#[derive(Module, Debug)]
pub struct PspNet {
    pub encoder: Encoder,
    pub pyramid: PyramidPooling,
    pub mid_skip: Option<SkipRefinement>,
    pub skip: Option<SkipRefinement>,
    pub fine_skip: Option<SkipRefinement>,
    pub classifier: Conv2d,
    pub aux: Option<AuxHead>,
    pub dropout: f64,
    pub align_corners: bool,
}

impl PspNet {
    /// Multiply-accumulates of the convolutions of one inference pass on an `h`×`w` image
    /// (pooling, normalisation, activations and upsampling are not counted; they are a few
    /// per cent). FLOPs are twice this.
    pub fn macs(&self, h: usize, w: usize) -> u64 {
        let (mut total, stem_out) = self.encoder.stem.macs([h, w]);
        // The 3×3/2 max-pool with padding 1 halves the size, rounding up.
        let mut size = stem_out.map(|n| n.div_ceil(2));
        let mut stage_sizes = Vec::new();
        for stage in &self.encoder.stages {
            for block in &stage.blocks {
                let (m, out) = block.macs(size);
                total += m;
                size = out;
            }
            stage_sizes.push(size);
        }
        let branches: u64 = self
            .pyramid
            .branches
            .iter()
            .map(|b| b.conv.macs([b.bin, b.bin]).0)
            .sum();
        total += branches + self.pyramid.bottleneck.macs(size).0;
        let mut head_size = size;
        let refinements = [
            (&self.mid_skip, stage_sizes.get(1).copied().unwrap_or(size)),
            (&self.skip, stage_sizes.first().copied().unwrap_or(size)),
            (&self.fine_skip, stem_out),
        ];
        for (refinement, low) in refinements {
            if let Some(r) = refinement {
                total += r.high.macs(head_size).0 + r.low.macs(low).0 + r.fuse.macs(low).0;
                head_size = low;
            }
        }
        total + conv_macs(&self.classifier, head_size).0
    }

    /// Calls `visit` on every batch norm of the network: the encoder's, the pyramid's, the
    /// refinements' and the aux head's, in that order.
    pub fn visit_batch_norms(&mut self, visit: &mut dyn FnMut(&mut BatchNorm)) {
        self.encoder.stem.visit_batch_norms(visit);
        for block in self.encoder.stages.iter_mut().flat_map(|s| &mut s.blocks) {
            block.visit_batch_norms(visit);
        }
        self.pyramid.visit_batch_norms(visit);
        for refinement in [&mut self.mid_skip, &mut self.skip, &mut self.fine_skip]
            .into_iter()
            .flatten()
        {
            refinement.visit_batch_norms(visit);
        }
        if let Some(aux) = &mut self.aux {
            aux.conv.visit_batch_norms(visit);
        }
    }

    /// Class logits of normalised images (see [`super::infer::normalise`]):
    /// `[batch, 3, H, W] -> [batch, classes, H, W]`. No dropout; batch norms use their
    /// running statistics unless the model is on an autodiff device in training mode.
    pub fn forward(&self, images: Tensor<4>) -> Tensor<4> {
        self.heads(images, None).logits
    }

    /// The training forward pass: like [`PspNet::forward`] plus the aux head, with channel
    /// dropout whose masks come from `noise_seed` (so a step is reproducible).
    /// `[batch, 3, H, W] -> Heads { logits: [batch, classes, H, W], aux }`.
    pub fn forward_train(&self, images: Tensor<4>, noise_seed: u64) -> Heads {
        self.heads(images, Some(noise_seed))
    }

    fn heads(&self, images: Tensor<4>, noise_seed: Option<u64>) -> Heads {
        let [_, _, h, w] = images.dims();
        let ac = self.align_corners;
        let EncoderFeatures { stem, stages } = self.encoder.forward(images);
        let mut x = match stages.last() {
            Some(last) => self.pyramid.forward(last.clone(), ac),
            None => unreachable_stages(),
        };
        if let Some(seed) = noise_seed {
            x = channel_dropout(x, self.dropout, seed);
        }
        // Coarse to fine, in the order `macs` counts them.
        let refinements = [
            (&self.mid_skip, stages.get(1)),
            (&self.skip, stages.first()),
            (&self.fine_skip, Some(&stem)),
        ];
        for (refinement, low) in refinements {
            if let (Some(r), Some(low)) = (refinement, low) {
                x = r.forward(x, low.clone(), ac);
            }
        }
        let logits = resize(crate::layers::conv2d(&self.classifier, x), [h, w], ac);
        let aux = match (&self.aux, noise_seed) {
            (Some(aux), Some(_)) if stages.len() >= 2 => {
                let input = stages[stages.len() - 2].clone();
                let y = crate::layers::conv2d(&aux.classifier, relu(aux.conv.forward(input)));
                Some(resize(y, [h, w], ac))
            }
            _ => None,
        };
        Heads { logits, aux }
    }
}

/// The encoder always has at least one stage ([`PspNetConfig::validate`] asks for depth ≥ 2).
#[cold]
fn unreachable_stages() -> Tensor<4> {
    unreachable!("a validated PspNetConfig builds at least one encoder stage")
}

/// Bilinear resize: `[B, C, h, w] -> [B, C, size[0], size[1]]` (a no-op at the same size).
pub fn resize(x: Tensor<4>, size: [usize; 2], align_corners: bool) -> Tensor<4> {
    let [_, _, h, w] = x.dims();
    if [h, w] == size {
        return x;
    }
    interpolate(
        x,
        InterpolateOptions {
            mode: InterpolateMode::Bilinear,
            align_corners,
            output_size: Some(size),
            scale_factor: None,
        },
    )
}

/// Channel dropout (PyTorch's Dropout2d, as smp's PSPNet uses): whole feature maps are
/// zeroed with probability `p`, the rest scaled by 1 / (1 - p). Masks come from
/// `ChaCha8Rng::seed_from_u64(seed)`. `[B, C, H, W] -> [B, C, H, W]`.
fn channel_dropout(x: Tensor<4>, p: f64, seed: u64) -> Tensor<4> {
    if p <= 0.0 {
        return x;
    }
    let [b, c, _, _] = x.dims();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let keep = (1.0 / (1.0 - p)) as f32;
    let mask: Vec<f32> = (0..b * c)
        .map(|_| if rng.random::<f64>() < p { 0.0 } else { keep })
        .collect();
    let mask = Tensor::<4>::from_data(TensorData::new(mask, [b, c, 1, 1]), &x.device());
    x * mask
}

/// The segmenter crate's tests' network: width 1/8 (stem 8 channels), one block per stage,
/// stride-4 refinement of 8 channels.
#[cfg(test)]
pub(crate) fn tiny_test_config() -> PspNetConfig {
    PspNetConfig::new()
        .with_width(0.125)
        .with_blocks(vec![1, 1, 1, 1])
        .with_psp_channels(16)
        .with_skip_channels(8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fine_refinement_predicts_at_the_input_size_and_counts_its_convolutions() {
        let device = Device::flex();
        let coarse = tiny_test_config()
            .init(&device)
            .unwrap_or_else(|e| panic!("{e}"));
        let fine = tiny_test_config()
            .with_fine_skip_channels(4)
            .init(&device)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(coarse.fine_skip.is_none());
        let images = Tensor::<4>::zeros([2, 3, 32, 32], &device);
        assert_eq!(fine.forward(images).dims(), [2, 5, 32, 32]);
        // On 32×32: the stem gives 16×16, stage 1 8×8. The refinement projects the 8
        // stride-4 channels (1×1 at 8×8) and the 8 stem channels (1×1 at 16×16) to 4 each,
        // fuses them (3×3, 8 -> 4 at 16×16), and the classifier (to 5 classes) then runs on
        // 4 channels at 16×16 instead of 8 at 8×8.
        let added = 8 * 4 * 64 + 8 * 4 * 256 + 8 * 4 * 9 * 256 + 4 * 5 * 256 - 8 * 5 * 64;
        assert_eq!(fine.macs(32, 32) - coarse.macs(32, 32), added);
    }

    #[test]
    fn the_mid_refinement_needs_depth_4_and_counts_its_convolutions() {
        let device = Device::flex();
        assert!(
            tiny_test_config()
                .with_mid_skip_channels(4)
                .init(&device)
                .is_err()
        );
        let deep = tiny_test_config().with_depth(4);
        let plain = deep.init(&device).unwrap_or_else(|e| panic!("{e}"));
        let mid = deep
            .with_mid_skip_channels(4)
            .init(&device)
            .unwrap_or_else(|e| panic!("{e}"));
        let images = Tensor::<4>::zeros([2, 3, 64, 64], &device);
        assert_eq!(mid.forward(images).dims(), [2, 5, 64, 64]);
        // On 64×64 stage 2 (16 channels at width 1/8) is 8×8 and the pyramid (16 channels)
        // 4×4. The refinement projects the pyramid (1×1 at 4×4) and stage 2 (1×1 at 8×8) to
        // 4 each and fuses them (3×3, 8 -> 4 at 8×8). The stride-4 refinement's projection
        // of the head (to 8 channels) then takes 4 channels at 8×8 instead of 16 at 4×4: the
        // same count.
        let added = 16 * 4 * 16 + 16 * 4 * 64 + 8 * 4 * 9 * 64;
        assert_eq!(mid.macs(64, 64) as i64 - plain.macs(64, 64) as i64, added);
    }
}
