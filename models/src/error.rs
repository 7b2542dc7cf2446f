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

impl From<crate::run_folder::RunFolderError> for ModelError {
    fn from(e: crate::run_folder::RunFolderError) -> Self {
        use crate::run_folder::RunFolderError as R;
        let message = match &e {
            R::Io { source, .. } => source.to_string(),
            R::Invalid { message, .. } => message.clone(),
            R::NothingToResume { marker, .. } => {
                format!("holds no training run to resume (no {marker})")
            }
            R::NotEmpty { .. } => "is not empty".to_owned(),
        };
        ModelError::file(e.path(), message)
    }
}
