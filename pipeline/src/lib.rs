//! The `pipeline` command as a library, so the binary stays a thin shell and the logic is
//! testable: [`cli`] parses, [`run`] dispatches to [`commands`], [`ui`] is the only module
//! that prints, [`output`] writes folders atomically, [`recording`] logs to rerun.

pub mod agent_folder;
pub mod agent_progress;
pub mod agent_recording;
pub mod args;
pub mod cli;
pub mod clip;
pub mod commands;
pub mod config;
pub mod context;
pub mod error;
pub mod inputs;
pub mod log_args;
pub mod output;
pub mod plots;
pub mod recording;
pub mod recordings;
pub mod tasks;
pub mod ui;

pub use cli::Cli;
pub use error::CliError;

/// The config file `pipeline run` reads when no --config is given.
pub const DEFAULT_RUN_CONFIG: &str = "pipeline.toml";

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    let ui = ui::Ui::new(cli.global.verbosity());
    let default_run_config = std::path::Path::new(DEFAULT_RUN_CONFIG);
    let config_path = match (&cli.global.config, &cli.command) {
        (Some(path), _) => Some(path.as_path()),
        (None, cli::Group::Run(_)) if default_run_config.is_file() => Some(default_run_config),
        (None, _) => None,
    };
    let config = config::Config::load(config_path)?;
    let ctx = context::Context {
        global: &cli.global,
        config: &config,
        ui: &ui,
        recording: None,
        run_argv,
    };
    // A GPU this build cannot use is refused before any work, whatever the command.
    if cli.global.device != args::DeviceArg::Cpu {
        ctx.device()?;
    }
    dispatch(&ctx, &cli.command)
}

/// Runs `command` with `ctx`.
pub fn dispatch(ctx: &context::Context<'_>, command: &cli::Group) -> anyhow::Result<()> {
    match command {
        cli::Group::Map { command } => commands::map::run(ctx, command),
        cli::Group::Agent { command } => commands::agent::run(ctx, command),
        cli::Group::Dataset { command } => commands::dataset::run(ctx, command),
        cli::Group::Logs { command } => commands::logs::run(ctx, command),
        cli::Group::Segmenter { command } => commands::segmenter::run(ctx, command),
        cli::Group::Replay { command } => commands::replay::run(ctx, command),
        cli::Group::Sim { command } => commands::sim::run(ctx, command),
        cli::Group::Run(args) => commands::run::run(ctx, args),
    }
}

/// Parses a whole command line and runs it with `ctx`'s config, ui and recording
/// ([`context::Context::run_argv`]; `pipeline run` runs its stages' commands so).
pub fn run_argv(ctx: &context::Context<'_>, argv: &[String]) -> anyhow::Result<()> {
    use clap::Parser as _;
    let child = Cli::try_parse_from(argv).map_err(|e| {
        anyhow::anyhow!(
            "internal error: stage command `{}` did not parse: {e}",
            argv.join(" ")
        )
    })?;
    let child_ctx = context::Context {
        global: &child.global,
        ..*ctx
    };
    dispatch(&child_ctx, &child.command)
}
