//! The Q-network: convolutions over the bird's-eye layers, a small MLP over the scalar
//! inputs (speed, target speed, aggressiveness, last action), merged into fully connected
//! layers that output one value per action — plain, or split into a state value and action
//! advantages (dueling, Wang et al. 2016).
//!
//! Parameters are drawn from a seeded ChaCha generator with PyTorch's default bounds
//! (uniform in ±1/√fan_in for weights and biases), not from the backend's global generator,
//! so the same seed gives the same network on every backend, in any thread, and the PyTorch
//! comparison in `scripts/bench_qnet.py` starts from the same distribution.

use crate::layers::relu;
use burn::module::{Module, Param, ParamId};
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig};
use burn::nn::{Initializer, Linear, LinearConfig, PaddingConfig2d};
use burn::tensor::{Device, Tensor, TensorData};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::{Observation, ObservationSpec};

use crate::packed::scale_layer_byte;

/// One convolution (followed by a ReLU).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConvSpec {
    /// Output channels.
    pub channels: usize,
    /// Square kernel size.
    pub kernel: usize,
    pub stride: usize,
    /// Zero padding on every side.
    #[serde(default)]
    pub padding: usize,
}

/// How the convolution features become a vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Pooling {
    /// Keep every position (the Nature-DQN head).
    Flatten,
    /// Average over regions down to `height × width` cells first (the ITS study's network).
    Average { height: usize, width: usize },
}

/// The Q-network's architecture; the input and action sizes come from the task at
/// [`init`](QNetworkConfig::init).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QNetworkConfig {
    /// Convolutions over the layer stack, in order (none: the layers are flattened).
    pub convolutions: Vec<ConvSpec>,
    pub pooling: Pooling,
    /// Width of the one-layer MLP over the scalar inputs (0: the scalars join the merge as they are).
    pub scalar_hidden: usize,
    /// Widths of the fully connected layers after the merge.
    pub hidden: Vec<usize>,
    /// Separate state-value and advantage heads: Q = V + A − mean(A).
    pub dueling: bool,
    /// Indices of scalar inputs the network does not read (multiplied by zero). Agents
    /// learnt from human logs ignore what the logs cannot give them: the drivers'
    /// aggressiveness, and their previous decision (which nearly always equals the current
    /// one, so a network that reads it learns to repeat itself).
    pub ignored_scalars: Vec<usize>,
}

/// The Nature-DQN convolutions (32 8×8/4, 64 4×4/2, 64 3×3/1), shared by the presets.
fn nature_convolutions() -> Vec<ConvSpec> {
    [(32, 8, 4), (64, 4, 2), (64, 3, 1)]
        .into_iter()
        .map(|(channels, kernel, stride)| ConvSpec {
            channels,
            kernel,
            stride,
            padding: 0,
        })
        .collect()
}

impl Default for QNetworkConfig {
    /// The Nature-DQN convolutions (32 8×8/4, 64 4×4/2, 64 3×3/1), a 64-wide scalar MLP and
    /// one 256-wide hidden layer.
    fn default() -> Self {
        QNetworkConfig {
            convolutions: nature_convolutions(),
            pooling: Pooling::Flatten,
            scalar_hidden: 64,
            hidden: vec![256],
            dueling: false,
            ignored_scalars: Vec::new(),
        }
    }
}

impl QNetworkConfig {
    /// The ITS study's network: three convolutions, an average pool, and the speed (here:
    /// all scalar inputs) joined before the fully connected layers.
    pub fn its() -> Self {
        QNetworkConfig {
            convolutions: nature_convolutions(),
            pooling: Pooling::Average {
                height: 2,
                width: 2,
            },
            scalar_hidden: 0,
            hidden: vec![256],
            dueling: false,
            ignored_scalars: Vec::new(),
        }
    }

    /// A named preset: `default` or `its`.
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "default" | "nature" => Some(Self::default()),
            "its" => Some(Self::its()),
            _ => None,
        }
    }

    /// `(channels, height, width)` after the convolutions, or an error naming the layer that
    /// no longer fits.
    pub fn conv_output(&self, spec: &ObservationSpec) -> Result<(usize, usize, usize), String> {
        let (mut c, mut h, mut w) = (spec.channels, spec.height, spec.width);
        for (i, conv) in self.convolutions.iter().enumerate() {
            if conv.channels == 0 || conv.kernel == 0 || conv.stride == 0 {
                return Err(format!(
                    "convolution {i}: channels, kernel and stride must be positive"
                ));
            }
            let (ph, pw) = (h + 2 * conv.padding, w + 2 * conv.padding);
            if ph < conv.kernel || pw < conv.kernel {
                return Err(format!(
                    "convolution {i}: a {k}×{k} kernel does not fit a {h}×{w} input",
                    k = conv.kernel
                ));
            }
            (c, h, w) = (
                conv.channels,
                (ph - conv.kernel) / conv.stride + 1,
                (pw - conv.kernel) / conv.stride + 1,
            );
        }
        Ok((c, h, w))
    }

    /// Length of the vector the convolutions hand to the merge.
    pub fn conv_features(&self, spec: &ObservationSpec) -> Result<usize, String> {
        let (c, h, w) = self.conv_output(spec)?;
        Ok(match self.pooling {
            Pooling::Flatten => c * h * w,
            Pooling::Average { height, width } => c * height * width,
        })
    }

    /// Builds the network for `spec` and `actions`, its parameters drawn from `seed`.
    pub fn init(
        &self,
        spec: &ObservationSpec,
        actions: usize,
        seed: u64,
        device: &Device,
    ) -> Result<QNetwork, String> {
        if actions == 0 {
            return Err("the task has no actions".into());
        }
        if let Some(i) = self.ignored_scalars.iter().find(|&&i| i >= spec.scalars) {
            return Err(format!(
                "ignored_scalars: the task has {} scalar inputs, there is no input {i}",
                spec.scalars
            ));
        }
        let scalar_mask = if self.ignored_scalars.is_empty() {
            Vec::new()
        } else {
            (0..spec.scalars)
                .map(|i| f32::from(u8::from(!self.ignored_scalars.contains(&i))))
                .collect()
        };
        if let Pooling::Average { height, width } = self.pooling
            && (height == 0 || width == 0)
        {
            return Err("pooling.height and pooling.width must be positive".into());
        }
        let mut rng = ParamSource::new(seed);
        let mut in_channels = spec.channels;
        let mut convolutions = Vec::with_capacity(self.convolutions.len());
        // Without layers (a task of scalar inputs only) there is nothing to convolve.
        let conv_specs: &[ConvSpec] = if spec.layer_len() == 0 {
            &[]
        } else {
            &self.convolutions
        };
        for conv in conv_specs {
            convolutions.push(seeded_conv(in_channels, conv, &mut rng, device));
            in_channels = conv.channels;
        }
        let pool = match self.pooling {
            Pooling::Average { height, width } if !conv_specs.is_empty() => {
                Some(AdaptiveAvgPool2dConfig::new([height, width]).init())
            }
            _ => None,
        };
        let conv_features = if spec.layer_len() == 0 {
            0
        } else if self.convolutions.is_empty() {
            spec.layer_len()
        } else {
            self.conv_features(spec)?
        };
        let scalar_layer = (self.scalar_hidden > 0 && spec.scalars > 0)
            .then(|| seeded_linear(spec.scalars, self.scalar_hidden, &mut rng, device));
        let scalar_features = if scalar_layer.is_some() {
            self.scalar_hidden
        } else {
            spec.scalars
        };
        let mut width = conv_features + scalar_features;
        if width == 0 {
            return Err("the network has no inputs (no layers and no scalars)".into());
        }
        let mut hidden = Vec::with_capacity(self.hidden.len());
        for &h in &self.hidden {
            if h == 0 {
                return Err("hidden layer widths must be positive".into());
            }
            hidden.push(seeded_linear(width, h, &mut rng, device));
            width = h;
        }
        let head = seeded_linear(width, actions, &mut rng, device);
        let value = self
            .dueling
            .then(|| seeded_linear(width, 1, &mut rng, device));
        Ok(QNetwork {
            convolutions,
            pool,
            scalar_mask,
            scalar_layer,
            hidden,
            head,
            value,
        })
    }
}

/// See the module docs. Built by [`QNetworkConfig::init`].
#[derive(Module, Debug)]
pub struct QNetwork {
    convolutions: Vec<Conv2d>,
    pool: Option<AdaptiveAvgPool2d>,
    /// 0 for the scalar inputs the network ignores, 1 for the others; empty: reads them all.
    /// Rebuilt from the config, not saved with the parameters.
    #[module(skip)]
    scalar_mask: Vec<f32>,
    scalar_layer: Option<Linear>,
    hidden: Vec<Linear>,
    /// Q-values, or the advantages of a dueling network.
    head: Linear,
    /// The state value of a dueling network.
    value: Option<Linear>,
}

impl QNetwork {
    /// Q-values of a batch.
    ///
    /// - `layers`: `[batch, channels, height, width]`, the `u8` layers scaled to [0, 1]
    ///   (see [`observations_to_tensors`]);
    /// - `scalars`: `[batch, scalars]`;
    /// - returns `[batch, actions]`.
    pub fn forward(&self, layers: Tensor<4>, scalars: Tensor<2>) -> Tensor<2> {
        let [_, channels, height, width] = layers.dims();
        let visual = if channels * height * width == 0 {
            // A task with scalar inputs only: nothing to see.
            None
        } else if self.convolutions.is_empty() {
            Some(layers.flatten::<2>(1, 3))
        } else {
            let mut x = layers;
            for conv in &self.convolutions {
                x = relu(crate::layers::conv2d(conv, x));
            }
            if let Some(pool) = &self.pool {
                x = pool.forward(x);
            }
            Some(x.flatten::<2>(1, 3))
        };
        let scalars = if self.scalar_mask.is_empty() {
            scalars
        } else {
            let mask = Tensor::<1>::from_data(
                TensorData::new(self.scalar_mask.clone(), [self.scalar_mask.len()]),
                &scalars.device(),
            );
            scalars * mask.unsqueeze::<2>()
        };
        let scalar = match &self.scalar_layer {
            Some(layer) => relu(layer.forward(scalars)),
            None => scalars,
        };
        let mut x = match visual {
            Some(visual) => Tensor::cat(vec![visual, scalar], 1),
            None => scalar,
        };
        for layer in &self.hidden {
            x = relu(layer.forward(x));
        }
        let head = self.head.forward(x.clone());
        match &self.value {
            None => head,
            Some(value) => {
                let advantage_mean = head.clone().mean_dim(1);
                value.forward(x) + head - advantage_mean
            }
        }
    }
}

/// A batch of observations as network inputs: layers `[batch, channels, height, width]`
/// scaled to [0, 1], and scalars `[batch, scalars]`.
pub fn observations_to_tensors(
    observations: &[&Observation],
    spec: &ObservationSpec,
    device: &Device,
) -> (Tensor<4>, Tensor<2>) {
    let b = observations.len();
    let mut layers = Vec::with_capacity(b * spec.layer_len());
    let mut scalars = Vec::with_capacity(b * spec.scalars);
    for obs in observations {
        layers.extend(obs.layers.iter().map(|&v| scale_layer_byte(v)));
        scalars.extend_from_slice(&obs.scalars);
    }
    batch_tensors(layers, scalars, b, spec, device)
}

/// Row-major `f32` batches (as the replay buffer samples them) as network inputs.
pub fn batch_tensors(
    layers: Vec<f32>,
    scalars: Vec<f32>,
    batch: usize,
    spec: &ObservationSpec,
    device: &Device,
) -> (Tensor<4>, Tensor<2>) {
    let layers = Tensor::from_data(
        TensorData::new(layers, [batch, spec.channels, spec.height, spec.width]),
        device,
    );
    let scalars = Tensor::from_data(TensorData::new(scalars, [batch, spec.scalars]), device);
    (layers, scalars)
}

/// A tensor's values, row-major (empty if the tensor is not `f32`).
pub fn tensor_values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap_or_default()
}

/// Uniform values in ±`bound`.
fn uniform(len: usize, bound: f32, rng: &mut ChaCha8Rng) -> Vec<f32> {
    (0..len).map(|_| rng.random_range(-bound..bound)).collect()
}

/// Parameter values and ids, both drawn deterministically: values from the seed's
/// generator, ids counting up (burn's own ids are random, which would make two runs'
/// files differ byte for byte).
struct ParamSource {
    rng: ChaCha8Rng,
    next_id: u64,
}

impl ParamSource {
    fn new(seed: u64) -> Self {
        ParamSource {
            rng: ChaCha8Rng::seed_from_u64(seed),
            next_id: 1,
        }
    }

    /// Uniform values in ±`bound`, shaped `shape`, as the next parameter.
    fn uniform<const D: usize>(
        &mut self,
        shape: [usize; D],
        bound: f32,
        device: &Device,
    ) -> Param<Tensor<D>> {
        let values = uniform(shape.iter().product(), bound, &mut self.rng);
        let tensor = Tensor::from_data(TensorData::new(values, shape), device);
        // `from_tensor` marks the parameter trainable; re-creating it keeps that and gives
        // it the next id.
        let (_, value, mapper) = Param::from_tensor(tensor).consume();
        let id = ParamId::from(self.next_id);
        self.next_id += 1;
        Param::from_mapped_value(id, value, mapper)
    }
}

/// A linear layer with PyTorch's default initialisation (±1/√fan_in).
fn seeded_linear(
    inputs: usize,
    outputs: usize,
    source: &mut ParamSource,
    device: &Device,
) -> Linear {
    let mut layer = LinearConfig::new(inputs, outputs)
        .with_initializer(Initializer::Zeros)
        .init(device);
    let bound = 1.0 / (inputs as f32).sqrt();
    layer.weight = source.uniform([inputs, outputs], bound, device);
    layer.bias = Some(source.uniform([outputs], bound, device));
    layer
}

fn seeded_conv(
    inputs: usize,
    conv: &ConvSpec,
    source: &mut ParamSource,
    device: &Device,
) -> Conv2d {
    let k = conv.kernel;
    let mut layer = Conv2dConfig::new([inputs, conv.channels], [k, k])
        .with_stride([conv.stride, conv.stride])
        .with_padding(PaddingConfig2d::Explicit(
            conv.padding,
            conv.padding,
            conv.padding,
            conv.padding,
        ))
        .with_initializer(Initializer::Zeros)
        .init(device);
    let fan_in = inputs * k * k;
    let bound = 1.0 / (fan_in as f32).sqrt();
    layer.weight = source.uniform([conv.channels, inputs, k, k], bound, device);
    layer.bias = Some(source.uniform([conv.channels], bound, device));
    layer
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> ObservationSpec {
        ObservationSpec {
            channels: 16,
            height: 84,
            width: 84,
            scalars: 6,
        }
    }

    fn q_values(net: &QNetwork, batch: usize, device: &Device) -> Vec<f32> {
        let s = spec();
        let layers: Vec<f32> = (0..batch * s.layer_len())
            .map(|i| (i % 7) as f32 / 7.0)
            .collect();
        let scalars: Vec<f32> = (0..batch * s.scalars)
            .map(|i| (i % 3) as f32 - 1.0)
            .collect();
        let (l, sc) = batch_tensors(layers, scalars, batch, &s, device);
        let q = net.forward(l, sc);
        assert_eq!(q.dims(), [batch, 3]);
        tensor_values(q)
    }

    #[test]
    fn output_shapes_of_the_presets() -> Result<(), String> {
        let device = Device::flex();
        let s = spec();
        // Nature-DQN: 84 → 20 → 9 → 7.
        assert_eq!(QNetworkConfig::default().conv_output(&s)?, (64, 7, 7));
        assert_eq!(QNetworkConfig::default().conv_features(&s)?, 3136);
        assert_eq!(QNetworkConfig::its().conv_features(&s)?, 256);
        for config in [
            QNetworkConfig::default(),
            QNetworkConfig::its(),
            QNetworkConfig {
                dueling: true,
                ..QNetworkConfig::default()
            },
            QNetworkConfig {
                convolutions: vec![],
                scalar_hidden: 0,
                ..QNetworkConfig::default()
            },
        ] {
            let net = config.init(&s, 3, 1, &device)?;
            let q = q_values(&net, 2, &device);
            assert_eq!(q.len(), 6);
            assert!(q.iter().all(|v| v.is_finite()));
        }
        Ok(())
    }

    #[test]
    fn two_networks_of_one_seed_save_to_the_same_bytes() -> Result<(), String> {
        // Parameter ids are part of the file: they must come from the seed too.
        let device = Device::flex();
        let dir = std::env::temp_dir().join(format!("qnet_bytes_{}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        let mut files = Vec::new();
        for name in ["a", "b"] {
            let path = dir.join(format!("{name}.bpk"));
            QNetworkConfig::default()
                .init(&spec(), 3, 7, &device)?
                .save_file(&path)
                .map_err(|e| e.to_string())?;
            files.push(std::fs::read(&path).map_err(|e| e.to_string())?);
        }
        std::fs::remove_dir_all(&dir).map_err(|e| e.to_string())?;
        assert!(
            files[0] == files[1],
            "two saves of one seed's network differ"
        );
        Ok(())
    }

    #[test]
    fn a_network_over_scalars_only() -> Result<(), String> {
        // Tasks such as obstacle avoidance have no layers: the convolutions are skipped.
        let device = Device::flex();
        let s = ObservationSpec {
            channels: 0,
            height: 0,
            width: 0,
            scalars: 6,
        };
        let net = QNetworkConfig::default().init(&s, 4, 1, &device)?;
        assert_eq!(
            net.num_params(),
            (6 * 64 + 64) + (64 * 256 + 256) + (256 * 4 + 4)
        );
        let observation = Observation {
            layers: Vec::new(),
            scalars: vec![0.5; 6],
        };
        let (layers, scalars) = observations_to_tensors(&[&observation, &observation], &s, &device);
        let q = tensor_values(net.forward(layers, scalars));
        assert_eq!(q.len(), 8);
        assert_eq!(q[..4], q[4..], "the same input gives the same Q-values");
        Ok(())
    }

    /// The parameter counts of the presets at 16 × 84 × 84 layers, 6 scalars and 3 actions,
    /// counted by hand layer by layer (weights + biases); the PyTorch network of
    /// `scripts/bench_qnet.py` has the same counts, so the speed comparison is like for like.
    #[test]
    fn preset_parameter_counts() -> Result<(), String> {
        let device = Device::flex();
        let convs = (16 * 32 * 8 * 8 + 32) + (32 * 64 * 4 * 4 + 64) + (64 * 64 * 3 * 3 + 64);
        let head = 256 * 3 + 3;
        // default: flatten 64 × 7 × 7, a 64-wide scalar layer, one 256-wide hidden layer.
        let default = convs + (6 * 64 + 64) + ((3136 + 64) * 256 + 256) + head;
        // its: 2 × 2 average pool (256 features), scalars joined as they are.
        let its = convs + ((256 + 6) * 256 + 256) + head;
        assert_eq!((default, its), (923_235, 170_659));
        let count = |config: QNetworkConfig| -> Result<usize, String> {
            Ok(config.init(&spec(), 3, 1, &device)?.num_params())
        };
        assert_eq!(count(QNetworkConfig::default())?, default);
        assert_eq!(count(QNetworkConfig::its())?, its);
        Ok(())
    }

    #[test]
    fn same_seed_same_network_other_seed_other_network() -> Result<(), String> {
        let device = Device::flex();
        let config = QNetworkConfig::its();
        let a = q_values(&config.init(&spec(), 3, 5, &device)?, 1, &device);
        let b = q_values(&config.init(&spec(), 3, 5, &device)?, 1, &device);
        let c = q_values(&config.init(&spec(), 3, 6, &device)?, 1, &device);
        assert_eq!(a, b);
        assert_ne!(a, c);
        Ok(())
    }

    #[test]
    fn dueling_q_values_are_value_plus_centred_advantages() -> Result<(), String> {
        let device = Device::flex();
        let s = ObservationSpec {
            channels: 0,
            height: 0,
            width: 0,
            scalars: 2,
        };
        let config = QNetworkConfig {
            convolutions: vec![],
            scalar_hidden: 0,
            hidden: vec![],
            dueling: true,
            ..QNetworkConfig::default()
        };
        let net = config.init(&s, 3, 9, &device)?;
        let (layers, scalars) = batch_tensors(vec![], vec![0.5, -1.0], 1, &s, &device);
        let q = tensor_values(net.forward(layers, scalars.clone()));
        let advantages = tensor_values(net.head.forward(scalars.clone()));
        let value = net
            .value
            .as_ref()
            .map(|v| tensor_values(v.forward(scalars)));
        let value = value.ok_or("dueling network without a value head")?[0];
        let mean = advantages.iter().sum::<f32>() / 3.0;
        for (q, a) in q.iter().zip(&advantages) {
            assert!((q - (value + a - mean)).abs() < 1e-5);
        }
        Ok(())
    }

    /// Ignored scalar inputs change nothing; the others do; an index past the task's
    /// scalars is refused.
    #[test]
    fn ignored_scalars_do_not_reach_the_q_values() -> Result<(), String> {
        let device = Device::flex();
        let s = ObservationSpec {
            channels: 0,
            height: 0,
            width: 0,
            scalars: 3,
        };
        let config = QNetworkConfig {
            convolutions: vec![],
            hidden: vec![8],
            ignored_scalars: vec![1, 2],
            ..QNetworkConfig::default()
        };
        let net = config.init(&s, 2, 4, &device)?;
        let q = |values: Vec<f32>| {
            let (layers, scalars) = batch_tensors(vec![], values, 1, &s, &device);
            tensor_values(net.forward(layers, scalars))
        };
        assert_eq!(q(vec![0.3, 0.0, 0.0]), q(vec![0.3, 5.0, -2.0]));
        assert_ne!(q(vec![0.3, 0.0, 0.0]), q(vec![0.9, 0.0, 0.0]));
        let bad = QNetworkConfig {
            ignored_scalars: vec![3],
            ..config
        };
        let err = bad.init(&s, 2, 4, &device).err().unwrap_or_default();
        assert!(err.contains("no input 3"), "{err}");
        Ok(())
    }

    #[test]
    fn kernels_that_do_not_fit_are_reported() {
        let s = ObservationSpec {
            channels: 4,
            height: 10,
            width: 10,
            scalars: 1,
        };
        let err = QNetworkConfig::default()
            .conv_output(&s)
            .err()
            .unwrap_or_default();
        assert!(err.contains("convolution 1"), "{err}");
    }
}
