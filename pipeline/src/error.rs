//! Errors as the user sees them: one line naming the file and the problem, and a hint.

use std::fmt;
use std::path::Path;

use maps::MapError;

/// An error with a message that already names what it is about, and what to do about it.
/// [`crate::ui::report_error`] finds it anywhere in an `anyhow` chain for the hint.
#[derive(Debug)]
pub struct CliError {
    pub message: String,
    pub hint: Option<String>,
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for CliError {}

impl CliError {
    pub fn new(message: impl Into<String>, hint: impl Into<String>) -> Self {
        CliError {
            message: message.into(),
            hint: Some(hint.into()),
        }
    }

    /// `<file>: <problem>` with a hint.
    pub fn file(path: &Path, problem: impl fmt::Display, hint: impl Into<String>) -> Self {
        CliError {
            message: format!("{}: {problem}", path.display()),
            hint: Some(hint.into()),
        }
    }
}

/// A maps-crate error about `path` (the file being read), as a [`CliError`] whose message
/// names the file exactly once and whose hint fits the kind of problem.
pub fn map_error(path: &Path, err: MapError, reading: FileRole) -> anyhow::Error {
    let err = err.with_path(path);
    let text = err.to_string();
    let shown = path.display().to_string();
    let message = if text.contains(&shown) {
        text
    } else {
        format!("{shown}: {text}")
    };
    let hint = match (&err, reading) {
        (_, FileRole::Output) => "check that the output folder is writable and the disk is not full".to_owned(),
        (MapError::Io { .. }, _) => "check that the path exists and is readable".to_owned(),
        (MapError::Version { .. }, _) => {
            "the map was written by another version of pipeline: import it again with `pipeline map import`".to_owned()
        }
        (MapError::NoRoute(_), _) => {
            "pick points inside the largest strongly connected component (`pipeline map info` lists the components)"
                .to_owned()
        }
        (MapError::Invariant { .. }, _) => {
            "this is a bug in the importer: please report it with the input file".to_owned()
        }
        (MapError::Parse { .. } | MapError::Invalid { .. } | MapError::Serialise(_), FileRole::OsmInput) => {
            "check that the file is a complete OpenStreetMap XML, .osm.gz or PBF (or Lanelet2) file; \
             re-download or re-export it, or choose other roads with --profile / --clip-bbox"
                .to_owned()
        }
        (MapError::Parse { .. } | MapError::Invalid { .. } | MapError::Serialise(_), FileRole::MapFile) => {
            "give a map.json / map.bin written by `pipeline map import`, or the folder it wrote".to_owned()
        }
    };
    anyhow::Error::new(CliError {
        message,
        hint: Some(hint),
    })
}

/// What the file in a [`map_error`] is to the command, to choose the hint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileRole {
    OsmInput,
    MapFile,
    Output,
}
