//! Adam for the networks: burn's `Adam`, with one in-place LibTorch pass per parameter when the
//! parameters live on burn's LibTorch backend.
//!
//! burn's Adam updates a parameter with about a dozen tensor operations, each writing a new
//! tensor. On LibTorch, [`adam`]'s optimizer updates the moments and the parameter in place, in
//! PyTorch's own formulation (`lerp_` for the moments, one `addcdiv_` for the step; the training
//! steps' timings are in docs/benchmarks.md). On every other backend it is burn's `Adam`,
//! unchanged. Both keep burn's `AdamState`, so checkpoints are the same files and a run can
//! resume on either.

use burn::optim::grad_clipping::GradientClippingConfig;
use burn::optim::{AdamConfig, AdamState, LearningRate, ModuleOptimizer, Optimizer};
use burn::tensor::{Device, Tensor};

/// Adam's coefficients: burn's defaults, which are PyTorch's.
const BETA_1: f32 = 0.9;
const BETA_2: f32 = 0.999;

/// Adam with burn's default betas (0.9, 0.999), the given `epsilon` and optional gradient
/// clipping, as `AdamConfig::new().with_epsilon(epsilon).with_grad_clipping(clipping).init()`.
pub fn adam(epsilon: f32, clipping: Option<GradientClippingConfig>) -> ModuleOptimizer {
    let burn = AdamConfig::new()
        .with_beta_1(BETA_1)
        .with_beta_2(BETA_2)
        .with_epsilon(epsilon)
        .build();
    let mut optimizer = ModuleOptimizer::from(Adam { burn, epsilon });
    if let Some(clipping) = clipping {
        optimizer = optimizer.with_grad_clipping(clipping.init());
    }
    optimizer
}

#[derive(Clone)]
struct Adam {
    burn: burn::optim::Adam,
    #[cfg_attr(not(feature = "libtorch"), allow(dead_code))]
    epsilon: f32,
}

impl Optimizer for Adam {
    type State<const D: usize> = AdamState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        #[cfg(feature = "libtorch")]
        if crate::layers::torch::is_libtorch(&tensor.device()) {
            return torch::step(lr, self.epsilon, tensor, grad, state);
        }
        self.burn.step(lr, tensor, grad, state)
    }

    fn to_device<const D: usize>(state: Self::State<D>, device: &Device) -> Self::State<D> {
        burn::optim::Adam::to_device(state, device)
    }
}

#[cfg(feature = "libtorch")]
// burn 0.22 marks LibTorch deprecated (models::device says why we use it).
#[allow(deprecated)]
mod torch {
    //! Adam's step in place on LibTorch (a backend extension).

    use burn::backend::libtorch::TchTensor;
    use burn::backend::tensor::FloatTensor;
    use burn::backend::{Backend, Dispatch, LibTorch, backend_extension};
    use burn::optim::{AdamState, AdaptiveMomentumState, LearningRate};
    use burn::tensor::Tensor;

    use super::{BETA_1, BETA_2};

    /// Adam's step for one parameter: burn's `Adam::step`, in place where burn holds the only
    /// handle on a tensor (a copy otherwise: the target network shares the online one's).
    pub(super) fn step<const D: usize>(
        lr: LearningRate,
        epsilon: f32,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<AdamState<D>>,
    ) -> (Tensor<D>, Option<AdamState<D>>) {
        let (time, moment_1, moment_2) = match state {
            Some(state) => (
                state.momentum.time + 1,
                state.momentum.moment_1,
                state.momentum.moment_2,
            ),
            None => (1, grad.zeros_like(), grad.zeros_like()),
        };
        let (tensor, moment_1, moment_2) = <Dispatch as TorchAdam>::adam_step_in_place(
            tensor.into_dispatch(),
            grad.into_dispatch(),
            moment_1.into_dispatch(),
            moment_2.into_dispatch(),
            lr,
            f64::from(epsilon),
            time as i32,
        );
        let momentum = AdaptiveMomentumState::new(
            time,
            Tensor::from_dispatch(moment_1),
            Tensor::from_dispatch(moment_2),
        );
        (
            Tensor::from_dispatch(tensor),
            Some(AdamState::new(momentum)),
        )
    }

    #[backend_extension(LibTorch)]
    pub trait TorchAdam: Backend {
        /// The parameter and its two moments after Adam's step number `time` (from 1).
        fn adam_step_in_place(
            tensor: FloatTensor<Self>,
            grad: FloatTensor<Self>,
            moment_1: FloatTensor<Self>,
            moment_2: FloatTensor<Self>,
            lr: f64,
            epsilon: f64,
            time: i32,
        ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
    }

    impl TorchAdam for LibTorch {
        fn adam_step_in_place(
            tensor: TchTensor,
            grad: TchTensor,
            moment_1: TchTensor,
            moment_2: TchTensor,
            lr: f64,
            epsilon: f64,
            time: i32,
        ) -> (TchTensor, TchTensor, TchTensor) {
            let (beta_1, beta_2) = (f64::from(BETA_1), f64::from(BETA_2));
            let (mut tensor, mut moment_1, mut moment_2) =
                (writable(tensor), writable(moment_1), writable(moment_2));
            let grad = &grad.tensor;
            // m ← β₁·m + (1 − β₁)·g and v ← β₂·v + (1 − β₂)·g², as lerps.
            let _ = moment_1.tensor.lerp_(grad, 1.0 - beta_1);
            let _ = moment_2.tensor.lerp_(&grad.square(), 1.0 - beta_2);
            // θ ← θ − lr·(m / (1 − β₁ᵗ)) / (√(v / (1 − β₂ᵗ)) + ε), written as burn writes it:
            // θ − lr·c·m / (√v + ε·√(1 − β₂ᵗ)) with c = √(1 − β₂ᵗ) / (1 − β₁ᵗ).
            let correction_2 = (1.0 - beta_2.powi(time)).sqrt();
            let factor = correction_2 / (1.0 - beta_1.powi(time));
            let mut denominator = moment_2.tensor.sqrt();
            let _ = denominator.g_add_scalar_(epsilon * correction_2);
            if lr > 0.0 {
                let _ = denominator.g_mul_scalar_(-1.0 / (lr * factor));
                let _ = tensor.tensor.addcdiv_(&moment_1.tensor, &denominator);
            }
            (tensor, moment_1, moment_2)
        }
    }

    /// `t` itself when burn holds the only handle on its storage, a copy otherwise.
    fn writable(t: TchTensor) -> TchTensor {
        if t.can_mut() {
            t
        } else {
            TchTensor::new(t.tensor.copy())
        }
    }
}

/// The in-place LibTorch step gives burn's Adam's parameters and leaves other handles on the
/// parameters alone. Runs in a build with `--features libtorch` (not in CI, which has no
/// libtorch: docs/gpu.md).
#[cfg(all(test, feature = "libtorch"))]
mod tests {
    use burn::nn::{Linear, LinearConfig};
    use burn::optim::GradientsParams;
    use burn::tensor::{Distribution, Tensor};

    use super::*;
    use crate::qnet::tensor_values as values;

    #[test]
    fn libtorch_step_matches_burns_adam() {
        #[allow(deprecated)]
        let device = Device::libtorch().autodiff();
        let start: Linear = LinearConfig::new(5, 3).init(&device);
        let x = Tensor::<2>::random([4, 5], Distribution::Normal(0.0, 1.0), &device);
        let train = |mut optimizer: ModuleOptimizer| {
            let mut model = start.clone();
            // A handle the steps must not change, as the DQN target network's.
            let kept = model.clone();
            for lr in [1e-2, 0.0, 5e-3] {
                let loss = model.forward(x.clone()).powi_scalar(2).sum();
                let grads = GradientsParams::from_grads(loss.backward(), &model);
                model = optimizer.step(lr, model, grads);
            }
            assert_eq!(
                values(kept.weight.val()),
                values(start.weight.val()),
                "a shared parameter changed"
            );
            let bias = model.bias.as_ref().map(|b| values(b.val()));
            (values(model.weight.val()), bias)
        };
        let ours = train(adam(1e-8, None));
        let burns = train(AdamConfig::new().with_epsilon(1e-8).init());
        assert_ne!(
            ours.0,
            values(start.weight.val()),
            "the steps moved nothing"
        );
        for (a, b) in ours.0.iter().zip(&burns.0) {
            assert!((a - b).abs() <= 1e-6, "weight: {a} against burn's {b}");
        }
        let (a, b) = (ours.1.expect("a bias"), burns.1.expect("a bias"));
        for (a, b) in a.iter().zip(&b) {
            assert!((a - b).abs() <= 1e-6, "bias: {a} against burn's {b}");
        }
    }
}
