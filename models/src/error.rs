use std::path::PathBuf;

/// What can go wrong in the models crate: bad settings, unreadable or mismatched files.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("invalid configuration: {0}")]
    Config(String),
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
}

impl ModelError {
    pub fn file(path: impl Into<PathBuf>, message: impl std::fmt::Display) -> Self {
        ModelError::File {
            path: path.into(),
            message: message.to_string(),
        }
    }
}
