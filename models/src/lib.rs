//! burn networks and their training: Q-networks and the DQN family for the driving tasks,
//! and the PSPNet-style segmenter.
//!
//! - [`segmenter`]: the PSPNet-style segmenter.
//! - [`qnet`]: the Q-network (convolutions over the bird's-eye layers + an MLP over the
//!   scalar inputs; dueling head; the ITS preset).
//! - [`dqn`]: DQN / Double DQN in one file, every hyper-parameter in [`dqn::DqnConfig`];
//!   checkpoints and resuming.
//! - [`replay`]: the replay buffer (each observation stored once, run-length packed; n-step
//!   returns; prioritised sampling over a [`sum_tree`]).
//! - [`vec_env`]: environments stepped in parallel with rayon.
//! - [`bc`]: behaviour cloning, a go / wait classifier on the agent's inputs.
//! - [`policy`]: a trained Q-network as a [`sim::baselines::Policy`] for the evaluation harness.
//!
//! Backend: burn's `flex` CPU backend by default ([`cpu_device`]); the `cuda` and `wgpu`
//! features add GPU backends.

pub mod bc;
pub mod dqn;
pub mod error;
pub mod packed;
pub mod policy;
pub mod qnet;
pub mod replay;
pub mod segmenter;
pub mod sum_tree;
pub mod vec_env;

#[cfg(test)]
mod toy;

pub use error::ModelError;

/// The default device: burn's flex CPU backend.
pub fn cpu_device() -> burn::tensor::Device {
    burn::tensor::Device::flex()
}
