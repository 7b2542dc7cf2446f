//! One module per command group; each command reads its inputs, calls library code, and
//! writes its outputs through [`crate::output`] and [`crate::recording`].

pub mod agent;
pub mod dataset;
pub mod logs;
pub mod map;
pub mod replay;
pub mod run;
pub mod segmenter;
pub mod sim;

pub use crate::context::Context;
