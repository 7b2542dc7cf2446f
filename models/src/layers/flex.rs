//! The convolutions of burn's flex backend (the default build) by [`kernels::conv`], with its
//! backward passes under burn's autodiff (a backend extension, as the `torch` module is for
//! LibTorch). Tensors of another element type than f32 go to burn's own convolution.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::ModuleOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, Flex, backend_extension};
use burn::nn::BatchNorm;
use burn::nn::conv::Conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{DType, Device, Tensor, TensorData};

use kernels::conv::{self as cpu_conv, Conv2dGeometry};
use kernels::norm::{self as cpu_norm, NormGeometry};
use kernels::pool::{self as cpu_pool, Pool2dGeometry};

type FlexTensor = FloatTensor<Flex>;

/// Whether `device` (or the device under its autodiff) is burn's flex backend.
pub fn is_flex(device: &Device) -> bool {
    matches!(
        device.clone().inner().as_dispatch(),
        burn::backend::DispatchDevice::Flex(_)
    )
}

pub(super) fn max_pool2d(
    x: Tensor<4>,
    kernel: [usize; 2],
    stride: [usize; 2],
    padding: [usize; 2],
) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as FlexLayers>::max_pool2d_flex(
        x.into_dispatch(),
        kernel,
        stride,
        padding,
    ))
}

pub(super) fn conv2d(layer: &Conv2d, x: Tensor<4>, options: ConvOptions<2>) -> Tensor<4> {
    let (x, weight) = (x.into_dispatch(), layer.weight.val().into_dispatch());
    Tensor::from_dispatch(match &layer.bias {
        Some(bias) => <Dispatch as FlexLayers>::conv2d_bias_flex(
            x,
            weight,
            bias.val().into_dispatch(),
            options,
        ),
        None => <Dispatch as FlexLayers>::conv2d_flex(x, weight, options),
    })
}

/// Convolutions by [`kernels::conv`]. (Separate methods rather than an optional bias: burn
/// 0.22's extension macro does not route an `Option` tensor.)
#[backend_extension(Flex: cfg(all()), Autodiff)]
pub trait FlexLayers: Backend {
    /// `conv2d(x, weight)`.
    fn conv2d_flex(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self>;

    /// `conv2d(x, weight) + bias`.
    fn conv2d_bias_flex(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self>;

    /// Batch norm with the batch's statistics: the output, and the batch's mean and biased
    /// variance per channel (as burn's `batch_norm_train`). `x` is `[batch, channels, height,
    /// width]` in f32.
    fn batch_norm_train_flex(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);

    /// Max pooling of `x` (f32, contiguous or not) over a valid [`Pool2dGeometry`] (the
    /// caller checks: [`pool_geometry`]).
    fn max_pool2d_flex(
        x: FloatTensor<Self>,
        kernel: [usize; 2],
        stride: [usize; 2],
        padding: [usize; 2],
    ) -> FloatTensor<Self>;
}

impl FlexLayers for Flex {
    fn conv2d_flex(x: FlexTensor, weight: FlexTensor, options: ConvOptions<2>) -> FlexTensor {
        forward(x, weight, None, options)
    }

    fn conv2d_bias_flex(
        x: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        options: ConvOptions<2>,
    ) -> FlexTensor {
        forward(x, weight, Some(bias), options)
    }

    fn batch_norm_train_flex(
        x: FlexTensor,
        gamma: FlexTensor,
        beta: FlexTensor,
        epsilon: f64,
    ) -> (FlexTensor, FlexTensor, FlexTensor) {
        norm_forward(
            &x.to_contiguous(),
            &gamma.to_contiguous(),
            &beta.to_contiguous(),
            epsilon,
        )
    }

    fn max_pool2d_flex(
        x: FlexTensor,
        kernel: [usize; 2],
        stride: [usize; 2],
        padding: [usize; 2],
    ) -> FlexTensor {
        pool_forward(&x.to_contiguous(), kernel, stride, padding)
    }
}

impl<C: CheckpointStrategy> FlexLayers for Autodiff<Flex, C> {
    fn conv2d_flex(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        differentiated::<C, 2>([x, weight], options)
    }

    fn conv2d_bias_flex(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        differentiated::<C, 3>([x, weight, bias], options)
    }

    fn batch_norm_train_flex(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let (x, x_node) = x.into_parts();
        let (gamma, gamma_node) = gamma.into_parts();
        let (beta, beta_node) = beta.into_parts();
        let (x, gamma) = (x.to_contiguous(), gamma.to_contiguous());
        let (output, mean, variance) = norm_forward(&x, &gamma, &beta.to_contiguous(), epsilon);
        let constant = |t: FlexTensor| <Self as AutodiffBackend>::from_inner(t);
        let state = NormState {
            x,
            gamma,
            mean: mean.clone(),
            variance: variance.clone(),
            epsilon,
        };
        let output = match NormBackward
            .prepare::<C>([x_node, gamma_node, beta_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(state, output),
            OpsKind::UnTracked(prep) => prep.finish(output),
        };
        (output, constant(mean), constant(variance))
    }

    fn max_pool2d_flex(
        x: FloatTensor<Self>,
        kernel: [usize; 2],
        stride: [usize; 2],
        padding: [usize; 2],
    ) -> FloatTensor<Self> {
        let (x, node) = x.into_parts();
        let x = x.to_contiguous();
        let output = pool_forward(&x, kernel, stride, padding);
        let state = PoolState {
            x,
            kernel,
            stride,
            padding,
        };
        match PoolBackward.prepare::<C>([node]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => prep.finish(state, output),
            OpsKind::UnTracked(prep) => prep.finish(output),
        }
    }
}

fn norm_geometry(x: &FlexTensor) -> NormGeometry {
    let s = x.layout().shape();
    NormGeometry {
        batch: s[0],
        channels: s[1],
        pixels: s[2..].iter().product(),
    }
}

fn norm_forward(
    x: &FlexTensor,
    gamma: &FlexTensor,
    beta: &FlexTensor,
    epsilon: f64,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let g = norm_geometry(x);
    let mut out = vec![0.0; g.len()];
    let (mut mean, mut variance) = (vec![0.0; g.channels], vec![0.0; g.channels]);
    cpu_norm::batch_norm_train_forward(
        &g,
        x.storage::<f32>(),
        gamma.storage::<f32>(),
        beta.storage::<f32>(),
        epsilon,
        &mut out,
        &mut mean,
        &mut variance,
    );
    let channels = |v: Vec<f32>| FlexTensor::from_data(TensorData::new(v, [g.channels]));
    let out = FlexTensor::from_data(TensorData::new(out, x.layout().shape().to_vec()));
    (out, channels(mean), channels(variance))
}

#[derive(Debug, Clone)]
struct NormState {
    x: FlexTensor,
    gamma: FlexTensor,
    mean: FlexTensor,
    variance: FlexTensor,
    epsilon: f64,
}

#[derive(Debug)]
struct NormBackward;

impl Backward<Flex, 3> for NormBackward {
    type State = NormState;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad: FlexTensor = grads.consume::<Flex>(&ops.node);
        let NormState {
            x,
            gamma,
            mean,
            variance,
            epsilon,
        } = ops.state;
        let g = norm_geometry(&x);
        let grad = grad.to_contiguous();
        let mut dx = vec![0.0; g.len()];
        let (mut dgamma, mut dbeta) = (vec![0.0; g.channels], vec![0.0; g.channels]);
        cpu_norm::batch_norm_train_backward(
            &g,
            x.storage::<f32>(),
            gamma.storage::<f32>(),
            mean.storage::<f32>(),
            variance.storage::<f32>(),
            epsilon,
            grad.storage::<f32>(),
            &mut dx,
            &mut dgamma,
            &mut dbeta,
        );
        let shape = x.layout().shape().to_vec();
        let [x_parent, gamma_parent, beta_parent] = &ops.parents;
        if let Some(parent) = x_parent {
            grads.register::<Flex>(parent.id, FlexTensor::from_data(TensorData::new(dx, shape)));
        }
        let channels = |v: Vec<f32>| FlexTensor::from_data(TensorData::new(v, [g.channels]));
        if let Some(parent) = gamma_parent {
            grads.register::<Flex>(parent.id, channels(dgamma));
        }
        if let Some(parent) = beta_parent {
            grads.register::<Flex>(parent.id, channels(dbeta));
        }
    }
}

/// `BatchNorm::forward` in training: normalise with the batch's statistics and move the
/// running ones towards them by the layer's momentum.
pub(super) fn batch_norm_train(norm: &BatchNorm, x: Tensor<4>) -> Tensor<4> {
    let (output, mean, variance) = <Dispatch as FlexLayers>::batch_norm_train_flex(
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

/// The pooling's geometry for an input of `shape`, when the kernel applies: 4 dimensions, no
/// dilation, floor mode, padding below the kernel.
pub fn pool_geometry(
    shape: [usize; 4],
    kernel: [usize; 2],
    stride: [usize; 2],
    padding: [usize; 2],
) -> Option<Pool2dGeometry> {
    let g = Pool2dGeometry {
        planes: shape[0] * shape[1],
        height: shape[2],
        width: shape[3],
        kernel,
        stride,
        padding,
    };
    g.is_valid().then_some(g)
}

fn pool_geometry_of(
    x: &FlexTensor,
    kernel: [usize; 2],
    stride: [usize; 2],
    padding: [usize; 2],
) -> Pool2dGeometry {
    let shape = x.layout().shape();
    let shape = [shape[0], shape[1], shape[2], shape[3]];
    pool_geometry(shape, kernel, stride, padding)
        .unwrap_or_else(|| panic!("max_pool2d_flex: {shape:?} with kernel {kernel:?}, stride {stride:?}, padding {padding:?}: the caller checks pool_geometry"))
}

fn pool_forward(
    x: &FlexTensor,
    kernel: [usize; 2],
    stride: [usize; 2],
    padding: [usize; 2],
) -> FlexTensor {
    let g = pool_geometry_of(x, kernel, stride, padding);
    let mut out = vec![0.0; g.output_len()];
    cpu_pool::max_pool2d_forward(&g, x.storage::<f32>(), &mut out);
    let [h, w] = g.output_size();
    let shape = x.layout().shape();
    tensor(out, [shape[0], shape[1], h, w])
}

#[derive(Debug, Clone)]
struct PoolState {
    x: FlexTensor,
    kernel: [usize; 2],
    stride: [usize; 2],
    padding: [usize; 2],
}

#[derive(Debug)]
struct PoolBackward;

impl Backward<Flex, 1> for PoolBackward {
    type State = PoolState;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad: FlexTensor = grads.consume::<Flex>(&ops.node);
        let PoolState {
            x,
            kernel,
            stride,
            padding,
        } = ops.state;
        if let Some(parent) = &ops.parents[0] {
            let g = pool_geometry_of(&x, kernel, stride, padding);
            let mut dx = vec![0.0; g.input_len()];
            let grad = grad.to_contiguous();
            cpu_pool::max_pool2d_backward(&g, x.storage::<f32>(), grad.storage::<f32>(), &mut dx);
            let s = x.layout().shape();
            grads.register::<Flex>(parent.id, tensor(dx, [s[0], s[1], s[2], s[3]]));
        }
    }
}

/// The geometry of `x` convolved by `weight`; `None` when the kernel does not apply (another
/// element type than f32, groups, or an asymmetric padding).
fn geometry(
    x: &FlexTensor,
    weight: &FlexTensor,
    options: &ConvOptions<2>,
) -> Option<Conv2dGeometry> {
    if x.dtype() != DType::F32 || weight.dtype() != DType::F32 || options.groups != 1 {
        return None;
    }
    let padding = options.padding_begin();
    if options.padding_end() != padding {
        return None;
    }
    let (xs, ws) = (x.layout().shape(), weight.layout().shape());
    if xs.len() != 4 || ws.len() != 4 || xs[1] != ws[1] {
        return None;
    }
    Some(Conv2dGeometry {
        batch: xs[0],
        channels_in: xs[1],
        height: xs[2],
        width: xs[3],
        channels_out: ws[0],
        kernel: [ws[2], ws[3]],
        stride: options.stride,
        padding,
        dilation: options.dilation,
    })
}

fn tensor(values: Vec<f32>, shape: [usize; 4]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape))
}

fn forward(
    x: FlexTensor,
    weight: FlexTensor,
    bias: Option<FlexTensor>,
    options: ConvOptions<2>,
) -> FlexTensor {
    let Some(g) = geometry(&x, &weight, &options) else {
        return Flex::conv2d(x, weight, bias, options);
    };
    let (x, weight) = (x.to_contiguous(), weight.to_contiguous());
    let bias = bias.map(|b| b.to_contiguous());
    let mut out = vec![0.0; g.output_len()];
    cpu_conv::conv2d_forward(
        &g,
        x.storage::<f32>(),
        weight.storage::<f32>(),
        bias.as_ref().map(|b| b.storage::<f32>()),
        &mut out,
    );
    let [h, w] = g.output_size();
    tensor(out, [g.batch, g.channels_out, h, w])
}

/// What the backward pass needs: the input and the weight (contiguous), the options.
#[derive(Debug, Clone)]
struct ConvState {
    x: FlexTensor,
    weight: FlexTensor,
    options: ConvOptions<2>,
}

#[derive(Debug)]
struct ConvBackward;

impl<const N: usize> Backward<Flex, N> for ConvBackward {
    type State = ConvState;

    fn backward(self, ops: Ops<Self::State, N>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad: FlexTensor = grads.consume::<Flex>(&ops.node);
        let ConvState { x, weight, options } = ops.state;
        let [x_parent, w_parent] = [&ops.parents[0], &ops.parents[1]];
        let bias_parent = ops.parents.get(2).and_then(|p| p.as_ref());
        let Some(g) = geometry(&x, &weight, &options) else {
            unreachable!("the forward pass took the fast path, so the geometry exists")
        };
        let grad = grad.to_contiguous();
        let grad_values = grad.storage::<f32>();
        if let Some(parent) = x_parent {
            let mut dx = vec![0.0; g.input_len()];
            cpu_conv::conv2d_backward_input(&g, grad_values, weight.storage::<f32>(), &mut dx);
            let shape = [g.batch, g.channels_in, g.height, g.width];
            grads.register::<Flex>(parent.id, tensor(dx, shape));
        }
        if w_parent.is_some() || bias_parent.is_some() {
            let mut dw = vec![0.0; g.weight_len()];
            let mut db = bias_parent.map(|_| vec![0.0; g.channels_out]);
            cpu_conv::conv2d_backward_weight(
                &g,
                x.storage::<f32>(),
                grad_values,
                &mut dw,
                db.as_deref_mut(),
            );
            if let Some(parent) = w_parent {
                let shape = [g.channels_out, g.channels_in, g.kernel[0], g.kernel[1]];
                grads.register::<Flex>(parent.id, tensor(dw, shape));
            }
            if let (Some(parent), Some(db)) = (bias_parent, db) {
                let bias = FlexTensor::from_data(TensorData::new(db, [g.channels_out]));
                grads.register::<Flex>(parent.id, bias);
            }
        }
    }
}

/// The convolution of `inputs` (`[x, weight]` or `[x, weight, bias]`), registered with burn's
/// autodiff when any input is tracked.
fn differentiated<C: CheckpointStrategy, const N: usize>(
    inputs: [FloatTensor<Autodiff<Flex, C>>; N],
    options: ConvOptions<2>,
) -> FloatTensor<Autodiff<Flex, C>> {
    let parts = inputs.map(|t| t.into_parts());
    let mut primitives = Vec::with_capacity(N);
    let nodes = parts.map(|(primitive, node)| {
        primitives.push(primitive.to_contiguous());
        node
    });
    let bias = primitives.get(2).cloned();
    let (x, weight) = (primitives[0].clone(), primitives[1].clone());
    let fast = geometry(&x, &weight, &options).is_some();
    match ConvBackward.prepare::<C>(nodes).compute_bound().stateful() {
        OpsKind::Tracked(prep) if fast => {
            let output = forward(x.clone(), weight.clone(), bias, options.clone());
            prep.finish(ConvState { x, weight, options }, output)
        }
        OpsKind::Tracked(_) => unreachable!("convolutions off the fast path use burn's layer"),
        OpsKind::UnTracked(prep) => prep.finish(forward(x, weight, bias, options)),
    }
}

/// Our layers give burn's outputs and gradients on the flex backend.
#[cfg(test)]
mod tests {
    use burn::module::Module;
    use burn::nn::conv::Conv2dConfig;
    use burn::nn::pool::MaxPool2dConfig;
    use burn::nn::{BatchNormConfig, PaddingConfig2d};
    use burn::tensor::{Device, Distribution, Tensor};

    use crate::qnet::tensor_values as values;

    fn assert_close(ours: Vec<f32>, burns: Vec<f32>, what: &str) {
        assert_eq!(ours.len(), burns.len(), "{what}: lengths");
        let scale = burns.iter().fold(1.0f32, |m, v| m.max(v.abs()));
        for (i, (a, b)) in ours.iter().zip(&burns).enumerate() {
            assert!(
                (a - b).abs() <= 1e-4 * scale,
                "{what}[{i}]: ours {a} against burn's {b}"
            );
        }
    }

    /// Gradients of `sum(pool(norm(conv(x))) * r)` with respect to `x` and the parameters, through
    /// ours and through burn's layers.
    #[test]
    fn convolution_and_pooling_have_burns_outputs_and_gradients() {
        let device = Device::flex().autodiff();
        let x = Tensor::<4>::random([2, 3, 13, 11], Distribution::Normal(0.0, 1.0), &device);
        let cases = [
            (3, 1, 1, 1, true),
            (3, 2, 0, 1, false),
            (3, 4, 2, 1, true),
            (3, 1, 2, 2, false),
            (1, 1, 0, 1, true),
            (1, 2, 0, 1, false),
            (7, 2, 3, 1, false),
        ];
        for (kernel, stride, pad, dilation, bias) in cases {
            let conv = Conv2dConfig::new([3, 4], [kernel, kernel])
                .with_stride([stride, stride])
                .with_dilation([dilation, dilation])
                .with_padding(PaddingConfig2d::Explicit(pad, pad, pad, pad))
                .with_bias(bias)
                .init(&device);
            let pool = MaxPool2dConfig::new([3, 3])
                .with_strides([2, 2])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init();
            let out_dims = pool.forward(conv.forward(x.clone())).dims();
            let r = Tensor::<4>::random(out_dims, Distribution::Normal(0.0, 1.0), &device);
            let run = |ours: bool| {
                // A fresh batch norm each time: a forward pass in training moves its running
                // statistics.
                let norm = BatchNormConfig::new(4).init(&device);
                let x = x.clone().detach().require_grad();
                let y = if ours {
                    let y = super::super::batch_norm(&norm, super::super::conv2d(&conv, x.clone()));
                    super::super::max_pool2d(&pool, y)
                } else {
                    pool.forward(norm.forward(conv.forward(x.clone())))
                };
                let grads = (y.clone() * r.clone()).sum().backward();
                let mut out = vec![
                    values(y),
                    values(x.grad(&grads).expect("x's gradient")),
                    values(
                        conv.weight
                            .val()
                            .grad(&grads)
                            .expect("the weight's gradient"),
                    ),
                    values(norm.gamma.val().grad(&grads).expect("gamma's gradient")),
                    values(norm.beta.val().grad(&grads).expect("beta's gradient")),
                    values(norm.running_mean.value_sync()),
                    values(norm.running_var.value_sync()),
                ];
                if let Some(b) = &conv.bias {
                    out.push(values(b.val().grad(&grads).expect("the bias's gradient")));
                }
                out
            };
            let what = format!("kernel {kernel} stride {stride} pad {pad} dilation {dilation}");
            for ((a, b), name) in run(true).into_iter().zip(run(false)).zip([
                "output",
                "x",
                "weight",
                "gamma",
                "beta",
                "running mean",
                "running var",
                "bias",
            ]) {
                assert_close(a, b, &format!("{what}: {name}"));
            }
            // Without autodiff (inference) too.
            let plain = x.clone().inner();
            let ours = super::super::conv2d(&conv.valid(), plain.clone());
            assert_close(
                values(ours),
                values(conv.valid().forward(plain)),
                &format!("{what}: inference"),
            );
        }
    }
}
