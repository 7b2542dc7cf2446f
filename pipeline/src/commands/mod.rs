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

use std::path::{Path, PathBuf};

use crate::cli::Cli;
use crate::config::Config;
use crate::recording::{Recording, Stream};
use crate::ui::Ui;

/// What every command gets: the global options, the config file, the terminal.
#[derive(Debug)]
pub struct Context<'a> {
    pub cli: &'a Cli,
    pub config: &'a Config,
    pub ui: &'a Ui,
    /// Inside `pipeline run`: the run's recording, under the stage's entity prefix.
    pub recording: Option<&'a Stream>,
}

impl Context<'_> {
    /// The command's rerun recording: the run's shared one inside `pipeline run`, else what
    /// `--rerun` asks for (`save_dir` is where `--rerun save` writes `recording.rrd`).
    pub fn open_recording(&self, save_dir: Option<&Path>) -> anyhow::Result<Recording> {
        match self.recording {
            Some(stream) => Ok(Recording::shared(stream, &self.cli.rerun)),
            None => Recording::open(&self.cli.rerun, save_dir),
        }
    }

    /// The burn device of `--device`; a clear error when this build lacks its backend.
    pub fn device(&self) -> anyhow::Result<burn::tensor::Device> {
        models::device(self.cli.device.into()).map_err(|e| {
            crate::error::CliError::new(
                format!(
                    "--device {0}: {e}: rebuild with `cargo build --release --features {0}`",
                    e.feature
                ),
                "or use --device cpu",
            )
            .into()
        })
    }

    /// An output path: relative ones are placed in `--run-dir` when it is given.
    pub fn output_path(&self, p: &Path) -> PathBuf {
        match &self.cli.run_dir {
            Some(dir) if p.is_relative() => dir.join(p),
            _ => p.to_path_buf(),
        }
    }
}
