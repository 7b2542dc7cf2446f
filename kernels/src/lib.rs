//! CPU kernels in f32 for the networks' layers, NCHW, with their backward passes: the
//! convolution as one matrix product per group of images ([`conv`]) and max pooling
//! ([`pool`]). `models::layers` runs them under burn's flex backend and its autodiff.
//!
//! Threads: rayon's current pool (the caller's `ThreadPool::install` decides how many).
//! Deterministic: every output element is summed in an order fixed by the shapes and the
//! thread count.

pub mod conv;
pub mod norm;
pub mod pool;
