//! One module per command group; each command reads its inputs, calls library code, and
//! writes its outputs through [`crate::output`] and [`crate::recording`].

pub mod agent;
pub mod dataset;
pub mod logs;
pub mod map;
pub mod segmenter;

use std::path::{Path, PathBuf};

use crate::cli::Cli;
use crate::config::Config;
use crate::ui::Ui;

/// What every command gets: the global options, the config file, the terminal.
#[derive(Debug)]
pub struct Context<'a> {
    pub cli: &'a Cli,
    pub config: &'a Config,
    pub ui: &'a Ui,
}

impl Context<'_> {
    /// An output path: relative ones are placed in `--run-dir` when it is given.
    pub fn output_path(&self, p: &Path) -> PathBuf {
        match &self.cli.run_dir {
            Some(dir) if p.is_relative() => dir.join(p),
            _ => p.to_path_buf(),
        }
    }
}
