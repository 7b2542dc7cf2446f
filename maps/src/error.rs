//! The one error type of the maps crate.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum MapError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}{message}", path.as_ref().map(|p| format!("{}: ", p.display())).unwrap_or_default())]
    Parse {
        path: Option<PathBuf>,
        message: String,
    },
    #[error("{}{message}", path.as_ref().map(|p| format!("{}: ", p.display())).unwrap_or_default())]
    Invalid {
        path: Option<PathBuf>,
        message: String,
    },
    #[error("map invariant broken after `{step}`: {message}")]
    Invariant { step: &'static str, message: String },
    #[error("no route: {0}")]
    NoRoute(String),
    #[error("unsupported map file version {found} (this build reads version {expected})")]
    Version { found: u32, expected: u32 },
    #[error("serialisation: {0}")]
    Serialise(String),
}

impl MapError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        MapError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
    pub fn invalid(path: &Path, message: impl Into<String>) -> Self {
        MapError::Invalid {
            path: Some(path.to_path_buf()),
            message: message.into(),
        }
    }
    /// Attaches a file to an error made without one.
    pub fn with_path(self, path: &Path) -> Self {
        match self {
            MapError::Parse {
                path: None,
                message,
            } => MapError::Parse {
                path: Some(path.to_path_buf()),
                message,
            },
            MapError::Invalid {
                path: None,
                message,
            } => MapError::Invalid {
                path: Some(path.to_path_buf()),
                message,
            },
            other => other,
        }
    }
}
