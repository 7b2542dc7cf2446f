//! The segmenter's errors. Variants about a file name it, so the binary can say which file
//! and what is wrong with it in one line.

use std::path::{Path, PathBuf};

/// Result with a [`SegmenterError`].
pub type Result<T, E = SegmenterError> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum SegmenterError {
    /// A setting is unusable (not tied to a file).
    #[error("{0}")]
    Config(String),
    /// A file or folder could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A file was read but its content is wrong (a config, a checkpoint, a record).
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    /// A dataset could not be read.
    #[error(transparent)]
    Dataset(#[from] datasets::DatasetError),
}

impl From<crate::run_folder::RunFolderError> for SegmenterError {
    fn from(e: crate::run_folder::RunFolderError) -> Self {
        use crate::run_folder::RunFolderError as R;
        match e {
            R::Io { path, source } => SegmenterError::Io { path, source },
            other => SegmenterError::Invalid {
                path: other.path().to_path_buf(),
                message: match other {
                    R::Invalid { message, .. } => message,
                    R::NothingToResume { marker, .. } => {
                        format!("holds no training run to resume (no {marker})")
                    }
                    _ => "is not empty".to_owned(),
                },
            },
        }
    }
}

impl SegmenterError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        SegmenterError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub fn invalid(path: &Path, message: impl Into<String>) -> Self {
        SegmenterError::Invalid {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// The file the error is about, when there is one.
    pub fn path(&self) -> Option<&Path> {
        match self {
            SegmenterError::Io { path, .. } | SegmenterError::Invalid { path, .. } => Some(path),
            SegmenterError::Dataset(e) => e.path(),
            SegmenterError::Config(_) => None,
        }
    }
}
