//! What every command runs with: the global options, the config file's settings, the one
//! place that prints ([`Ui`]) and the rerun recording a `pipeline run` shares with its stages.

use std::path::{Path, PathBuf};

use crate::args::GlobalArgs;
use crate::config::Config;
use crate::recording::{Recording, Stream};
use crate::ui::Ui;

/// What every command gets: the global options, the config file, the terminal.
#[derive(Debug, Clone, Copy)]
pub struct Context<'a> {
    pub global: &'a GlobalArgs,
    pub config: &'a Config,
    pub ui: &'a Ui,
    /// Inside `pipeline run`: the run's recording, under the stage's entity prefix.
    pub recording: Option<&'a Stream>,
    /// Runs a whole `pipeline ...` command line (`argv[0]` is the program) with this
    /// context's config, ui and recording: how `pipeline run` runs its stages' commands
    /// without the commands importing the command line they belong to.
    pub run_argv: RunArgv,
}

/// See [`Context::run_argv`].
pub type RunArgv = fn(&Context<'_>, &[String]) -> anyhow::Result<()>;

impl Context<'_> {
    /// The command's rerun recording: the run's shared one inside `pipeline run`, else what
    /// `--rerun` asks for (`save_dir` is where `--rerun save` writes `recording.rrd`).
    pub fn open_recording(&self, save_dir: Option<&Path>) -> anyhow::Result<Recording> {
        match self.recording {
            Some(stream) => Ok(Recording::shared(stream, &self.global.rerun)),
            None => Recording::open(&self.global.rerun, save_dir),
        }
    }

    /// The burn device of `--device`; a clear error when this build lacks its backend.
    pub fn device(&self) -> anyhow::Result<burn::tensor::Device> {
        models::device(self.global.device.into()).map_err(|e| {
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
        match &self.global.run_dir {
            Some(dir) if p.is_relative() => dir.join(p),
            _ => p.to_path_buf(),
        }
    }
}
