//! The `pipeline` binary: parse the command line, run it, turn an error into one line and a
//! non-zero exit code.

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = pipeline::Cli::parse();
    let verbosity = cli.verbosity();
    match pipeline::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            pipeline::ui::report_error(&err, verbosity);
            ExitCode::FAILURE
        }
    }
}
