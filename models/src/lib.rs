//! burn networks and their training: Q-networks and the DQN family for the driving tasks,
//! and the PSPNet-style segmenter.
//!
//! - [`segmenter`]: the PSPNet-style segmenter.
//! - [`layers`]: the networks' convolution, batch norm and ReLU (LibTorch's own backward passes
//!   when training on LibTorch).
//! - [`optim`]: Adam (in place on LibTorch).
//! - `torch_kernels` (the `libtorch` feature): LibTorch code tch does not expose, in C++.
//! - [`allocator`]: mimalloc's settings for training.
//! - [`qnet`]: the Q-network (convolutions over the bird's-eye layers + an MLP over the
//!   scalar inputs; dueling head; the ITS preset).
//! - [`dqn`]: DQN / Double DQN in one file, every hyper-parameter in [`dqn::DqnConfig`];
//!   checkpoints and resuming.
//! - [`replay`]: the replay buffer (each observation stored once, run-length packed; n-step
//!   returns; prioritised sampling over a [`sum_tree`]).
//! - [`vec_env`]: environments stepped in parallel with rayon.
//! - [`bc`]: behaviour cloning, a go / wait classifier on the agent's inputs.
//! - [`offline`]: learning from recorded transitions: discrete CQL and behaviour cloning on
//!   the agent's Q-network.
//! - [`policy`]: a trained Q-network as a policy of the evaluation harness ([`sim::eval`]).
//! - [`training`]: a training run's bookkeeping: the success rates of its curves, its summary.
//! - [`validation`]: choosing the agent among a run's checkpoints by validation.
//!
//! Backend: burn's `flex` CPU backend by default ([`cpu_device`]); the `cuda` and `wgpu`
//! features add GPU backends, chosen at run time with [`device`] (burn's `Device` is one
//! type whatever the backend, so the networks need no backend type parameter).

pub mod allocator;
pub mod averaging;
pub mod bc;
pub mod camera_view;
pub mod dqn;
pub mod error;
pub mod layers;
pub mod offline;
pub mod optim;
pub mod packed;
pub mod policy;
pub mod qnet;
pub mod replay;
pub mod run_folder;
pub mod segmenter;
pub mod sum_tree;
#[cfg(feature = "libtorch")]
pub mod torch_kernels;
pub mod training;
pub mod validation;
pub mod vec_env;

#[cfg(test)]
mod toy;

pub use error::ModelError;

/// The default device: burn's flex CPU backend.
pub fn cpu_device() -> burn::tensor::Device {
    burn::tensor::Device::flex()
}

/// Where the networks run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DeviceChoice {
    /// burn's flex CPU backend (every build).
    #[default]
    Cpu,
    /// The first CUDA GPU (builds with the `cuda` feature).
    Cuda,
    /// The default wgpu adapter: Vulkan, Metal or DX12 (builds with the `wgpu` feature).
    Wgpu,
    /// burn's LibTorch backend on the CPU: PyTorch's kernels (builds with the `libtorch`
    /// feature).
    LibTorch,
}

impl DeviceChoice {
    /// The cargo feature that brings the backend in (`None` for the CPU).
    pub fn feature(self) -> Option<&'static str> {
        match self {
            DeviceChoice::Cpu => None,
            DeviceChoice::Cuda => Some("cuda"),
            DeviceChoice::Wgpu => Some("wgpu"),
            DeviceChoice::LibTorch => Some("libtorch"),
        }
    }

    /// Whether this build has the backend.
    pub fn compiled_in(self) -> bool {
        match self {
            DeviceChoice::Cpu => true,
            DeviceChoice::Cuda => cfg!(feature = "cuda"),
            DeviceChoice::Wgpu => cfg!(feature = "wgpu"),
            DeviceChoice::LibTorch => cfg!(feature = "libtorch"),
        }
    }
}

/// Caps the threads the networks use for their own work, where the backend has a pool of its
/// own: LibTorch's intra-op threads. burn's flex backend has none; it runs on the caller's
/// rayon pool, which the caller sizes.
pub fn set_network_threads(threads: usize) {
    #[cfg(feature = "libtorch")]
    tch::set_num_threads(threads.max(1) as i32);
    #[cfg(not(feature = "libtorch"))]
    let _unused_without_libtorch = threads;
}

/// A device was asked for whose backend this build lacks.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("this build has no {feature} support")]
pub struct MissingBackend {
    /// The cargo feature that brings it in.
    pub feature: &'static str,
}

/// The burn device of `choice`, or [`MissingBackend`] when this build was made without the
/// backend's feature. A GPU device is opened lazily, by the first tensor on it.
pub fn device(choice: DeviceChoice) -> Result<burn::tensor::Device, MissingBackend> {
    match choice {
        DeviceChoice::Cpu => Ok(cpu_device()),
        #[cfg(feature = "cuda")]
        DeviceChoice::Cuda => Ok(burn::tensor::Device::cuda(0)),
        #[cfg(feature = "wgpu")]
        DeviceChoice::Wgpu => Ok(burn::tensor::Device::wgpu(
            burn::tensor::DeviceKind::DefaultDevice,
        )),
        // burn 0.22 marks LibTorch deprecated in favour of its CubeCL backends, but their CPU
        // one (burn-cpu) builds on tracel-llvm-bundler, which downloads LLVM from outside
        // crates.io at build time (docs/gpu.md); LibTorch builds from the registries.
        #[cfg(feature = "libtorch")]
        #[allow(deprecated)]
        DeviceChoice::LibTorch => Ok(burn::tensor::Device::libtorch()),
        #[allow(unreachable_patterns)]
        other => Err(MissingBackend {
            feature: other.feature().unwrap_or("cpu"),
        }),
    }
}

#[cfg(test)]
mod device_tests {
    use super::*;

    #[test]
    fn the_cpu_is_always_there_and_a_missing_backend_says_which_feature() {
        assert!(device(DeviceChoice::Cpu).is_ok());
        for choice in [
            DeviceChoice::Cuda,
            DeviceChoice::Wgpu,
            DeviceChoice::LibTorch,
        ] {
            match device(choice) {
                Ok(_) => assert!(choice.compiled_in()),
                Err(e) => {
                    assert!(!choice.compiled_in());
                    let feature = choice.feature().unwrap_or_default();
                    assert!(
                        e.to_string().contains(&format!("no {feature} support")),
                        "{e}"
                    );
                }
            }
        }
    }
}
