//! Errors of the log readers and writers. Every variant that is about a file names it, so the
//! binary can print one line that says which file and what is wrong with it.

use std::path::{Path, PathBuf};

/// Result with a [`LogError`].
pub type LogResult<T, E = LogError> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum LogError {
    /// A file or folder could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The file is not a log we can read, or its structure is broken (truncated, bad magic,
    /// a length that runs past the end, a missing table).
    #[error("{}: {message}", path.display())]
    Format { path: PathBuf, message: String },
    /// A setting given by the caller is unusable (not tied to one file).
    #[error("{0}")]
    Config(String),
}

impl LogError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        LogError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub fn format(path: &Path, message: impl Into<String>) -> Self {
        LogError::Format {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// The file the error is about, when there is one.
    pub fn path(&self) -> Option<&Path> {
        match self {
            LogError::Io { path, .. } | LogError::Format { path, .. } => Some(path),
            LogError::Config(_) => None,
        }
    }
}

/// Why one message could not be decoded. Not fatal: the readers count these per topic.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// The payload ends before the field being read.
    #[error("payload ends at byte {len} while reading {what} at byte {at}")]
    Truncated {
        what: &'static str,
        at: usize,
        len: usize,
    },
    /// A length or count field promises more than the payload holds.
    #[error("{what} of {count} elements at byte {at} needs more than the {remaining} bytes left")]
    LengthTooLarge {
        what: &'static str,
        count: u64,
        at: usize,
        remaining: usize,
    },
    /// The payload is structurally wrong (encapsulation kind, string without its NUL, UTF-8,
    /// a fixed-size array of the wrong size).
    #[error("{0}")]
    Invalid(String),
    /// A type or encoding this reader does not decode (listed, not fatal).
    #[error("no decoder for {0}")]
    Unsupported(String),
}
