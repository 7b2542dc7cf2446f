//! The one error type of the sim crate.

/// What can go wrong when preparing a world or a task on a map.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The map has nothing the task needs (no roundabout, no usable entry, ...).
    #[error("map unsuitable: {0}")]
    Map(String),
    /// A configuration value is out of its range.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// An evaluation report could not be written as JSON.
    #[error("cannot write the report: {0}")]
    Report(#[from] serde_json::Error),
}
