//! The `pipeline` command as a library, so the binary stays a thin shell and the logic is
//! testable: [`cli`] parses, [`run`] dispatches to [`commands`], [`ui`] is the only module
//! that prints, [`output`] writes folders atomically, [`recording`] logs to rerun.

pub mod cli;
pub mod clip;
pub mod commands;
pub mod config;
pub mod error;
pub mod output;
pub mod recording;
pub mod ui;

pub use cli::Cli;
pub use error::CliError;

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    let ui = ui::Ui::new(cli.verbosity());
    let config = config::Config::load(cli.config.as_deref())?;
    let ctx = commands::Context {
        cli: &cli,
        config: &config,
        ui: &ui,
    };
    match &cli.command {
        cli::Group::Map { command } => commands::map::run(&ctx, command),
        cli::Group::Agent { command } => commands::agent::run(&ctx, command),
        cli::Group::Dataset { command } => commands::dataset::run(&ctx, command),
        cli::Group::Logs { command } => commands::logs::run(&ctx, command),
        cli::Group::Segmenter { command } => commands::segmenter::run(&ctx, command),
    }
}
