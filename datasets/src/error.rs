//! The datasets crate's errors. Every variant names the file it is about, so the binary can
//! show one line that says which file and what is wrong with it.

use std::path::{Path, PathBuf};

/// Result with a [`DatasetError`].
pub type Result<T, E = DatasetError> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file or folder could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A file is not an image, or not the kind of image expected (e.g. an RGB label).
    #[error("{}: {message}", path.display())]
    Image { path: PathBuf, message: String },
    /// A line of a manifest or another line-oriented file is malformed.
    #[error("{}:{line}: {message}", path.display())]
    Line {
        path: PathBuf,
        line: usize,
        message: String,
    },
    /// A file was read but its content is wrong (card, class map, label values, sizes).
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    /// A setting given by the caller is unusable (not tied to one file).
    #[error("{0}")]
    Config(String),
}

impl DatasetError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        DatasetError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub fn image(path: &Path, message: impl Into<String>) -> Self {
        DatasetError::Image {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    pub fn invalid(path: &Path, message: impl Into<String>) -> Self {
        DatasetError::Invalid {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// The file the error is about, when there is one.
    pub fn path(&self) -> Option<&Path> {
        match self {
            DatasetError::Io { path, .. }
            | DatasetError::Image { path, .. }
            | DatasetError::Line { path, .. }
            | DatasetError::Invalid { path, .. } => Some(path),
            DatasetError::Config(_) => None,
        }
    }
}

/// What to do with an item whose files are broken.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OnError {
    /// Stop at the first broken item (in id order) with its error.
    #[default]
    Fail,
    /// Leave broken items out, and count and list them in the report.
    Skip,
}

/// An item left out under [`OnError::Skip`], and why.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Skipped {
    pub id: String,
    pub reason: String,
}

/// Splits per-item results (in item order) by the policy: under `Fail` the first error
/// is returned; under `Skip` the good values come back with the skipped items listed.
pub fn apply_policy<T>(
    results: Vec<(String, Result<T>)>,
    policy: OnError,
) -> Result<(Vec<T>, Vec<Skipped>)> {
    let mut good = Vec::with_capacity(results.len());
    let mut skipped = Vec::new();
    for (id, result) in results {
        match (result, policy) {
            (Ok(v), _) => good.push(v),
            (Err(e), OnError::Fail) => return Err(e),
            (Err(e), OnError::Skip) => skipped.push(Skipped {
                id,
                reason: e.to_string(),
            }),
        }
    }
    Ok((good, skipped))
}
