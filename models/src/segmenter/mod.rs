//! The PSPNet-style segmenter: the network ([`model`]), its loss ([`loss`]),
//! confusion-matrix metrics ([`metrics`]), the model shipped in the binary ([`shipped`]).

pub mod data;
pub mod error;
pub mod eval;
pub mod files;
pub mod infer;
pub mod loss;
pub mod metrics;
pub mod model;
pub mod recalibrate;
pub mod recipe;
pub mod shipped;
pub mod synthetic;
pub mod train;

pub use error::{Result, SegmenterError};
pub use metrics::{ConfusionMatrix, MetricsSummary};
pub use model::{PspNet, PspNetConfig};
