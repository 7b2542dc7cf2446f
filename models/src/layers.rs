//! The networks' convolution, batch normalisation and ReLU: burn's `Conv2d`, `BatchNorm` and
//! `relu`, with LibTorch's own backward passes when the tensors live on burn's LibTorch backend.
//!
//! burn's autodiff differentiates these layers with backend-independent formulas built from
//! tensor operations (`burn-backend`: the weight gradient of a convolution as a convolution of
//! the input by the output gradient, batch norm's statistics and gradients as a dozen
//! element-wise passes, ReLU's gradient as a comparison and a masked fill), and `burn-tch` keeps
//! those defaults. On LibTorch, [`conv2d`], [`batch_norm`] and [`relu`] record the layer in
//! LibTorch's autograd as well and hand its backward to LibTorch (burn's backend-extension
//! mechanism: the `torch` module, with the `libtorch` feature), and [`conv2d`] stores its input
//! channels last there, in training and inference alike; every other backend runs burn's own
//! layer unchanged. Measured in docs/benchmarks.md (segmenter and DQN steps).
//!
//! [`Bf16Convolutions`] runs the LibTorch convolutions of one thread in bfloat16 while it lives,
//! as PyTorch's CPU autocast does: the weights, gradients and every other layer stay in f32.

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, Ordering};

use burn::nn::conv::Conv2d;
use burn::nn::pool::MaxPool2d;
use burn::nn::{BatchNorm, PaddingConfig2d};
use burn::tensor::Tensor;
use burn::tensor::ops::ConvOptions;

static OWN_KERNELS: AtomicBool = AtomicBool::new(true);

/// Whether the flex backend's layers run on the `kernels` crate (the default) or on burn-flex's
/// own kernels, for the whole process: the second is for comparing the two (the `pipeline`
/// binary sets it from `PIPELINE_BURN_KERNELS=1`; docs/benchmarks.md).
pub fn use_own_kernels(on: bool) {
    OWN_KERNELS.store(on, Ordering::Relaxed);
}

fn own_kernels_on(device: &burn::tensor::Device) -> bool {
    OWN_KERNELS.load(Ordering::Relaxed) && flex::is_flex(device)
}

/// `layer.forward(x)`. On the LibTorch backend, with the channels stored last (the layout in
/// which LibTorch's CPU convolutions run fastest) and, when training, LibTorch's backward pass.
///
/// Shapes: `x` is `[batch, channels_in, height, width]`; the result is
/// `[batch, channels_out, height_out, width_out]`, as `Conv2d::forward`.
pub fn conv2d(layer: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    #[cfg(feature = "libtorch")]
    if torch::is_libtorch(&x.device())
        && let Some(options) = symmetric_options(layer)
    {
        return torch::conv2d(layer, x, options);
    }
    if own_kernels_on(&x.device())
        && x.dtype() == burn::tensor::DType::F32
        && layer.groups == 1
        && let Some(options) = symmetric_options(layer)
    {
        return flex::conv2d(layer, x, options);
    }
    layer.forward(x)
}

/// `pool.forward(x)`; on the flex backend by [`kernels::pool`] (burn-flex pools through its
/// 3-D kernel with indices).
///
/// Shapes: `x` is `[batch, channels, height, width]`; the result `[batch, channels, height_out,
/// width_out]`, as `MaxPool2d::forward`.
pub fn max_pool2d(pool: &MaxPool2d, x: Tensor<4>) -> Tensor<4> {
    if own_kernels_on(&x.device())
        && x.dtype() == burn::tensor::DType::F32
        && pool.dilation == [1, 1]
        && !pool.ceil_mode
        && let Some(padding) = symmetric_padding(&pool.padding)
        && flex::pool_geometry(x.dims(), pool.kernel_size, pool.stride, padding).is_some()
    {
        return flex::max_pool2d(x, pool.kernel_size, pool.stride, padding);
    }
    pool.forward(x)
}

/// `norm.forward(x)`, with LibTorch's batch norm and its backward pass when training on the
/// LibTorch backend (the running statistics are updated as `BatchNorm` updates them).
///
/// Shapes: `x` and the result are `[batch, channels, height, width]`.
pub fn batch_norm(norm: &BatchNorm, x: Tensor<4>) -> Tensor<4> {
    #[cfg(feature = "libtorch")]
    if torch::trains_on_libtorch(&x) && norm.training.is_enabled() {
        return torch::batch_norm_train(norm, x);
    }
    let device = x.device();
    if device.is_autodiff()
        && norm.training.is_enabled()
        && own_kernels_on(&device)
        && x.dtype() == burn::tensor::DType::F32
    {
        return flex::batch_norm_train(norm, x);
    }
    norm.forward(x)
}

/// `relu(x)`, with LibTorch's ReLU and its backward pass when training on the LibTorch backend
/// (burn's backward masks the gradient with a separate comparison and masked fill).
pub fn relu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    #[cfg(feature = "libtorch")]
    if torch::trains_on_libtorch(&x) {
        return Tensor::from_dispatch(
            <burn::backend::Dispatch as torch::TorchLayers>::relu_torch_backward(x.into_dispatch()),
        );
    }
    burn::tensor::activation::relu(x)
}

thread_local! {
    static BF16_CONVOLUTIONS: Cell<bool> = const { Cell::new(false) };
}

/// While a value of this type lives, [`conv2d`] on the LibTorch backend casts its input and
/// weights to bfloat16 on this thread, convolves and casts the output back to f32 (LibTorch's
/// autograd differentiates the casts, so the gradients reach the f32 weights). On a CPU with
/// bfloat16 dot products (AVX-512 BF16, AMX) the convolutions run faster; elsewhere oneDNN
/// emulates them, slower. No effect on other backends: see [`bf16_convolutions_run_on`].
#[derive(Debug)]
#[must_use = "the convolutions are in bfloat16 only while the guard lives"]
pub struct Bf16Convolutions {
    previous: bool,
}

impl Bf16Convolutions {
    pub fn enter() -> Bf16Convolutions {
        Bf16Convolutions {
            previous: BF16_CONVOLUTIONS.with(|on| on.replace(true)),
        }
    }
}

impl Drop for Bf16Convolutions {
    fn drop(&mut self) {
        BF16_CONVOLUTIONS.with(|on| on.set(self.previous));
    }
}

/// Whether [`Bf16Convolutions`] changes anything on `device` (LibTorch, in a build with the
/// `libtorch` feature).
pub fn bf16_convolutions_run_on(device: &burn::tensor::Device) -> bool {
    #[cfg(feature = "libtorch")]
    return torch::is_libtorch(device);
    #[cfg(not(feature = "libtorch"))]
    {
        let _ = device;
        false
    }
}

/// Moves `norm`'s running statistics towards a batch's `mean` and biased `variance` by the
/// layer's momentum, as `BatchNorm::forward` does in training.
fn move_running_statistics(norm: &BatchNorm, mean: Tensor<1>, variance: Tensor<1>) {
    let device = mean.device();
    let momentum = norm.momentum;
    let moved = |running: Tensor<1>, batch: Tensor<1>| {
        running
            .to_device(&device)
            .mul_scalar(1.0 - momentum)
            .add(batch.detach().mul_scalar(momentum))
            .detach()
    };
    norm.running_mean
        .update(moved(norm.running_mean.value_sync(), mean));
    norm.running_var
        .update(moved(norm.running_var.value_sync(), variance));
}

/// `[vertical, horizontal]` padding when it is the same on both sides of each axis.
fn symmetric_padding(padding: &PaddingConfig2d) -> Option<[usize; 2]> {
    match *padding {
        PaddingConfig2d::Valid => Some([0, 0]),
        PaddingConfig2d::Explicit(top, left, bottom, right) if top == bottom && left == right => {
            Some([top, left])
        }
        _ => None,
    }
}

/// The layer's convolution options when its padding is the same on both sides of each axis
/// (every layer of our networks); `None` sends the layer through `Conv2d::forward`.
fn symmetric_options(layer: &Conv2d) -> Option<ConvOptions<2>> {
    let padding = symmetric_padding(&layer.padding)?;
    Some(ConvOptions::new(
        layer.stride,
        padding,
        layer.dilation,
        layer.groups,
    ))
}

pub mod flex;

#[cfg(feature = "libtorch")]
// burn 0.22 marks LibTorch deprecated (models::device says why we use it).
#[allow(deprecated)]
pub mod torch {
    //! LibTorch's backward passes under burn's autodiff (a backend extension).
    //!
    //! Forward, when any input needs a gradient: the layer runs in LibTorch with autograd on,
    //! over detached views of the inputs (marked as needing a gradient where burn tracks them);
    //! burn gets the detached output and the autograd graph stays in the backward state.
    //! Backward: LibTorch's autograd engine runs from the output with burn's gradient of it
    //! (`torch::autograd::grad`, through [`crate::torch_kernels`]), so the inputs' gradients
    //! are exactly the layer's, computed by LibTorch's own kernels.

    use std::fmt;

    use burn::backend::autodiff::checkpoint::base::Checkpointer;
    use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::libtorch::TchTensor;
    use burn::backend::tensor::FloatTensor;
    use burn::backend::{
        Autodiff, AutodiffBackend, Backend, Dispatch, LibTorch, backend_extension,
    };
    use burn::nn::BatchNorm;
    use burn::nn::conv::Conv2d;
    use burn::tensor::Tensor;
    use burn::tensor::ops::ConvOptions;

    /// Whether `x` lives on LibTorch with autodiff: the case these layers are for (without
    /// autodiff, burn's layers call the same LibTorch kernels).
    pub fn trains_on_libtorch<const D: usize>(x: &Tensor<D>) -> bool {
        let device = x.device();
        device.is_autodiff() && is_libtorch(&device)
    }

    /// Whether `device` (or the device under its autodiff) is burn's LibTorch backend.
    pub fn is_libtorch(device: &burn::tensor::Device) -> bool {
        matches!(
            device.clone().inner().as_dispatch(),
            burn::backend::DispatchDevice::LibTorch(_)
        )
    }

    pub(super) fn conv2d(layer: &Conv2d, x: Tensor<4>, options: ConvOptions<2>) -> Tensor<4> {
        let (x, weight) = (x.into_dispatch(), layer.weight.val().into_dispatch());
        Tensor::from_dispatch(match &layer.bias {
            Some(bias) => <Dispatch as TorchLayers>::conv2d_bias_torch_backward(
                x,
                weight,
                bias.val().into_dispatch(),
                options,
            ),
            None => <Dispatch as TorchLayers>::conv2d_torch_backward(x, weight, options),
        })
    }

    /// `BatchNorm::forward` in training: normalise with the batch's statistics and move the
    /// running ones towards them by the layer's momentum.
    pub(super) fn batch_norm_train(norm: &BatchNorm, x: Tensor<4>) -> Tensor<4> {
        let (output, mean, variance) = <Dispatch as TorchLayers>::batch_norm_train_torch_backward(
            x.into_dispatch(),
            norm.gamma.val().into_dispatch(),
            norm.beta.val().into_dispatch(),
            norm.epsilon,
        );
        super::move_running_statistics(
            norm,
            Tensor::from_dispatch(mean),
            Tensor::from_dispatch(variance),
        );
        Tensor::from_dispatch(output)
    }

    /// Layers whose backward pass is LibTorch's. (Separate methods rather than an optional
    /// bias: burn 0.22's extension macro does not route an `Option` tensor.)
    #[backend_extension(LibTorch, Autodiff)]
    pub trait TorchLayers: Backend {
        /// `conv2d(x, weight)`.
        fn conv2d_torch_backward(
            x: FloatTensor<Self>,
            weight: FloatTensor<Self>,
            options: ConvOptions<2>,
        ) -> FloatTensor<Self>;

        /// `conv2d(x, weight) + bias`.
        fn conv2d_bias_torch_backward(
            x: FloatTensor<Self>,
            weight: FloatTensor<Self>,
            bias: FloatTensor<Self>,
            options: ConvOptions<2>,
        ) -> FloatTensor<Self>;

        /// `max(x, 0)`.
        fn relu_torch_backward(x: FloatTensor<Self>) -> FloatTensor<Self>;

        /// Batch norm with the batch's statistics: the output, and the batch's mean and biased
        /// variance per channel (as burn's `batch_norm_train`).
        fn batch_norm_train_torch_backward(
            x: FloatTensor<Self>,
            gamma: FloatTensor<Self>,
            beta: FloatTensor<Self>,
            epsilon: f64,
        ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
    }

    // The layers on tensors without autodiff: LibTorch's forward passes. Only `conv2d` comes
    // here (in inference, for the channels-last layout); batch norm and ReLU come only when
    // training, but the extension needs all of them.
    impl TorchLayers for LibTorch {
        fn conv2d_torch_backward(
            x: TchTensor,
            weight: TchTensor,
            options: ConvOptions<2>,
        ) -> TchTensor {
            TchTensor::new(conv2d_op(&[x.tensor, weight.tensor], &options))
        }

        fn conv2d_bias_torch_backward(
            x: TchTensor,
            weight: TchTensor,
            bias: TchTensor,
            options: ConvOptions<2>,
        ) -> TchTensor {
            TchTensor::new(conv2d_op(&[x.tensor, weight.tensor, bias.tensor], &options))
        }

        fn relu_torch_backward(x: TchTensor) -> TchTensor {
            TchTensor::new(x.tensor.relu())
        }

        fn batch_norm_train_torch_backward(
            x: TchTensor,
            gamma: TchTensor,
            beta: TchTensor,
            epsilon: f64,
        ) -> (TchTensor, TchTensor, TchTensor) {
            let (output, [mean, variance]) =
                batch_norm_op(&[x.tensor, gamma.tensor, beta.tensor], epsilon);
            (
                TchTensor::new(output),
                TchTensor::new(mean),
                TchTensor::new(variance),
            )
        }
    }

    impl<C: CheckpointStrategy> TorchLayers for Autodiff<LibTorch, C> {
        fn conv2d_torch_backward(
            x: FloatTensor<Self>,
            weight: FloatTensor<Self>,
            options: ConvOptions<2>,
        ) -> FloatTensor<Self> {
            differentiated::<C, 2, ()>([x, weight], |inputs| (conv2d_op(inputs, &options), ())).0
        }

        fn conv2d_bias_torch_backward(
            x: FloatTensor<Self>,
            weight: FloatTensor<Self>,
            bias: FloatTensor<Self>,
            options: ConvOptions<2>,
        ) -> FloatTensor<Self> {
            differentiated::<C, 3, ()>([x, weight, bias], |inputs| {
                (conv2d_op(inputs, &options), ())
            })
            .0
        }

        fn relu_torch_backward(x: FloatTensor<Self>) -> FloatTensor<Self> {
            differentiated::<C, 1, ()>([x], |[x]| (x.relu(), ())).0
        }

        fn batch_norm_train_torch_backward(
            x: FloatTensor<Self>,
            gamma: FloatTensor<Self>,
            beta: FloatTensor<Self>,
            epsilon: f64,
        ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
            let (output, [mean, variance]) =
                differentiated::<C, 3, _>([x, gamma, beta], |inputs| {
                    batch_norm_op(inputs, epsilon)
                });
            let constant = |t: tch::Tensor| Self::from_inner(TchTensor::new(t.detach()));
            (output, constant(mean), constant(variance))
        }
    }

    /// `conv2d(inputs[0], inputs[1]) + inputs[2]` (the bias when there are three); in
    /// bfloat16 with an f32 result while a [`super::Bf16Convolutions`] lives on this thread.
    fn conv2d_op<const N: usize>(
        inputs: &[tch::Tensor; N],
        options: &ConvOptions<2>,
    ) -> tch::Tensor {
        let bf16 = super::BF16_CONVOLUTIONS.with(|on| on.get());
        let cast = |t: &tch::Tensor| {
            if bf16 {
                t.to_kind(tch::Kind::BFloat16)
            } else {
                t.shallow_clone()
            }
        };
        let output = tch::Tensor::conv2d(
            &cast(&channels_last(&inputs[0])),
            &cast(&inputs[1]),
            inputs.get(2).map(cast).as_ref(),
            options.stride.map(|v| v as i64),
            options.padding_begin().map(|v| v as i64),
            options.dilation.map(|v| v as i64),
            options.groups as i64,
        );
        if bf16 {
            output.to_kind(tch::Kind::Float)
        } else {
            output
        }
    }

    /// `x` with its channels stored last (strides `[h·w·c, 1, w·c, c]`), the layout in which
    /// LibTorch's CPU convolutions (oneDNN) run fastest; the same tensor when it is already so.
    /// Convolutions, batch norm, ReLU, pooling and element-wise operations keep that layout, so
    /// only the network's input is copied.
    fn channels_last(x: &tch::Tensor) -> tch::Tensor {
        if x.dim() != 4 || is_channels_last(x) {
            return x.shallow_clone();
        }
        x.permute([0, 2, 3, 1]).contiguous().permute([0, 3, 1, 2])
    }

    fn is_channels_last(x: &tch::Tensor) -> bool {
        let (size, stride) = (x.size(), x.stride());
        size.len() == 4 && stride[1] == 1 && stride[3] == size[1] && stride[2] == size[1] * size[3]
    }

    /// Batch norm of `x` with `gamma` and `beta` over the batch's statistics; also returns the
    /// mean and the biased variance (LibTorch gives `1 / sqrt(variance + epsilon)`).
    fn batch_norm_op(inputs: &[tch::Tensor; 3], epsilon: f64) -> (tch::Tensor, [tch::Tensor; 2]) {
        let [x, gamma, beta] = inputs;
        let (output, mean, inv_std) = x.native_batch_norm(
            Some(gamma),
            Some(beta),
            None::<&tch::Tensor>,
            None,
            true,
            0.0,
            epsilon,
        );
        // Copies: burn may update the statistics in place, and LibTorch saved them for the
        // backward pass.
        let variance = inv_std.detach().square().reciprocal() - epsilon;
        (output, [mean.detach().copy(), variance])
    }

    /// Runs `op` on the inputs' LibTorch tensors, recorded by LibTorch's autograd when burn
    /// tracks any input, and registers the backward step with burn's autodiff. Returns the
    /// output as burn's tensor and `op`'s other results as they are.
    fn differentiated<C: CheckpointStrategy, const N: usize, X>(
        inputs: [FloatTensor<Autodiff<LibTorch, C>>; N],
        op: impl FnOnce(&[tch::Tensor; N]) -> (tch::Tensor, X),
    ) -> (FloatTensor<Autodiff<LibTorch, C>>, X) {
        let tracked = inputs.each_ref().map(|t| t.is_tracked());
        let parts = inputs.map(|t| t.into_parts());
        let mut primitives = Vec::with_capacity(N);
        let nodes = parts.map(|(primitive, node)| {
            primitives.push(primitive);
            node
        });
        let Ok(primitives): Result<[TchTensor; N], _> = primitives.try_into() else {
            unreachable!("one primitive per input")
        };
        match TorchBackward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                // The leaves share the inputs' storage and the output shares the graph's; the
                // graph keeps burn's handles on both alive, so burn-tch, which updates a tensor
                // in place when it holds the only handle, leaves the values LibTorch saved for
                // the backward pass alone.
                let leaves: [tch::Tensor; N] = std::array::from_fn(|i| {
                    primitives[i].tensor.detach().set_requires_grad(tracked[i])
                });
                let (output, extra) = tch::with_grad(|| op(&leaves));
                let detached = TchTensor::new(output.detach());
                let graph = TorchGraph {
                    output,
                    leaves,
                    inputs: primitives,
                    output_handle: detached.clone(),
                };
                (prep.finish(graph, detached), extra)
            }
            OpsKind::UnTracked(prep) => {
                let tensors = primitives.map(|p| p.tensor);
                let (output, extra) = op(&tensors);
                (prep.finish(TchTensor::new(output)), extra)
            }
        }
    }

    /// A layer as LibTorch's autograd recorded it: its output (carrying the graph), the leaves
    /// it differentiates with respect to, and burn's handles on the inputs and the output (see
    /// [`differentiated`]).
    struct TorchGraph<const N: usize> {
        output: tch::Tensor,
        leaves: [tch::Tensor; N],
        inputs: [TchTensor; N],
        output_handle: TchTensor,
    }

    // burn's backward state must be `Clone`; a shallow clone shares the graph.
    impl<const N: usize> Clone for TorchGraph<N> {
        fn clone(&self) -> Self {
            Self {
                output: self.output.shallow_clone(),
                leaves: std::array::from_fn(|i| self.leaves[i].shallow_clone()),
                inputs: self.inputs.clone(),
                output_handle: self.output_handle.clone(),
            }
        }
    }

    impl<const N: usize> fmt::Debug for TorchGraph<N> {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.debug_struct("TorchGraph")
                .field("output", &self.output.size())
                .field("inputs", &N)
                .finish()
        }
    }

    #[derive(Debug)]
    struct TorchBackward;

    impl<const N: usize> Backward<LibTorch, N> for TorchBackward {
        type State = TorchGraph<N>;

        fn backward(
            self,
            ops: Ops<Self::State, N>,
            grads: &mut Gradients,
            _checkpointer: &mut Checkpointer,
        ) {
            let output_grad: TchTensor = grads.consume::<LibTorch>(&ops.node);
            let TorchGraph { output, leaves, .. } = ops.state;
            // The tracked inputs: burn's node and LibTorch's leaf of each.
            let (parents, inputs): (Vec<_>, Vec<_>) = ops
                .parents
                .iter()
                .zip(&leaves)
                .filter_map(|(parent, leaf)| parent.as_ref().map(|p| (p.id, leaf)))
                .unzip();
            if inputs.is_empty() {
                return;
            }
            let input_grads =
                crate::torch_kernels::autograd_grad(&output, &output_grad.tensor, &inputs)
                    .unwrap_or_else(|error| panic!("LibTorch's backward pass of a layer: {error}"));
            for (parent, grad) in parents.into_iter().zip(input_grads) {
                grads.register::<LibTorch>(parent, TchTensor::new(grad));
            }
        }
    }
}

/// LibTorch's backward passes give burn's gradients. Runs in a build with `--features
/// libtorch` (not in CI, which has no libtorch: docs/gpu.md).
#[cfg(all(test, feature = "libtorch"))]
mod tests {
    use burn::module::Param;
    use burn::nn::conv::Conv2dConfig;
    use burn::nn::{BatchNormConfig, PaddingConfig2d};
    use burn::tensor::{Device, Distribution, Tensor};

    use super::*;
    use crate::qnet::tensor_values as values;

    #[allow(deprecated)]
    fn device() -> Device {
        Device::libtorch().autodiff()
    }

    fn assert_close(ours: Vec<f32>, burns: Vec<f32>, what: &str) {
        assert_eq!(ours.len(), burns.len(), "{what}: lengths");
        let scale = burns.iter().fold(1.0f32, |m, v| m.max(v.abs()));
        for (i, (a, b)) in ours.iter().zip(&burns).enumerate() {
            assert!(
                (a - b).abs() <= 1e-4 * scale,
                "{what}[{i}]: LibTorch's {a} against burn's {b}"
            );
        }
    }

    /// Under [`Bf16Convolutions`] a convolution gives f32 values and gradients within
    /// bfloat16's precision (8 bits of mantissa) of the f32 ones, and the guard's end restores
    /// f32 exactly.
    #[test]
    fn bf16_convolutions_stay_close_to_f32_and_end_with_the_guard() {
        let device = device();
        let x = Tensor::<4>::random([2, 8, 12, 12], Distribution::Normal(0.0, 1.0), &device);
        let conv = Conv2dConfig::new([8, 6], [3, 3])
            .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
            .init(&device);
        let run = || {
            let x = x.clone().detach().require_grad();
            let y = conv2d(&conv, x.clone());
            let grads = (y.clone() * y.clone()).sum().backward();
            let weight_grad = conv.weight.val().grad(&grads).expect("a weight gradient");
            (values(y), values(weight_grad))
        };
        let (y32, w32) = run();
        let (y16, w16) = {
            let _bf16 = Bf16Convolutions::enter();
            run()
        };
        let relative = |a: &[f32], b: &[f32]| {
            let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
            a.iter().zip(b).fold(0f32, |m, (a, b)| m.max((a - b).abs())) / scale
        };
        assert!(
            relative(&y16, &y32) < 2e-2,
            "output {}",
            relative(&y16, &y32)
        );
        assert!(
            relative(&w16, &w32) < 2e-2,
            "weight grad {}",
            relative(&w16, &w32)
        );
        assert!(y16 != y32, "the guard changed nothing");
        assert_eq!(run(), (y32, w32), "f32 after the guard ended");
    }

    /// Gradients of `sum(layer(x) * r)` with respect to `x` and the parameters, through ours
    /// and through burn's forward.
    #[test]
    fn convolution_batch_norm_and_relu_have_burns_gradients() {
        let device = device();
        let x = Tensor::<4>::random([2, 3, 9, 9], Distribution::Normal(0.0, 1.0), &device);
        for (stride, pad, bias) in [(1, 1, true), (2, 0, false), (4, 2, true)] {
            let conv = Conv2dConfig::new([3, 4], [3, 3])
                .with_stride([stride, stride])
                .with_padding(PaddingConfig2d::Explicit(pad, pad, pad, pad))
                .with_bias(bias)
                .init(&device);
            let gamma = Tensor::<1>::random([4], Distribution::Normal(1.0, 0.3), &device);
            let beta = Tensor::<1>::random([4], Distribution::Normal(0.0, 0.3), &device);
            let r = Tensor::<4>::random(
                conv.forward(x.clone()).dims(),
                Distribution::Normal(0.0, 1.0),
                &device,
            );
            let run = |native: bool| {
                // A fresh layer each time: a forward pass in training moves its running
                // statistics.
                let norm = burn::nn::BatchNorm {
                    gamma: Param::from_tensor(gamma.clone().detach()),
                    beta: Param::from_tensor(beta.clone().detach()),
                    ..BatchNormConfig::new(4).init(&device)
                };
                let x = x.clone().detach().require_grad();
                let y = if native {
                    relu(batch_norm(&norm, conv2d(&conv, x.clone())))
                } else {
                    burn::tensor::activation::relu(norm.forward(conv.forward(x.clone())))
                };
                let loss = (y.clone() * r.clone()).sum();
                let grads = loss.backward();
                let grad = |t: &Tensor<4>| values(t.grad(&grads).expect("a gradient"));
                let mut out = vec![values(y.clone()), grad(&x), grad(&conv.weight.val())];
                if let Some(b) = &conv.bias {
                    out.push(values(b.val().grad(&grads).expect("a bias gradient")));
                }
                out.push(values(
                    norm.gamma.val().grad(&grads).expect("gamma's gradient"),
                ));
                out.push(values(
                    norm.beta.val().grad(&grads).expect("beta's gradient"),
                ));
                out.push(values(norm.running_mean.value_sync()));
                out.push(values(norm.running_var.value_sync()));
                out
            };
            let ours = run(true);
            let burns = run(false);
            let names = [
                "output",
                "x",
                "weight",
                "bias",
                "gamma",
                "beta",
                "running mean",
                "running var",
            ];
            let names = names.iter().filter(|n| bias || **n != "bias");
            for ((a, b), name) in ours.into_iter().zip(burns).zip(names) {
                assert_close(a, b, &format!("stride {stride} pad {pad}: {name}"));
            }
        }
    }
}
