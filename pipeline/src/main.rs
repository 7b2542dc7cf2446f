//! The `pipeline` binary: parse the command line, run it, turn an error into one line and a
//! non-zero exit code.

use std::process::ExitCode;

use clap::Parser;

// An import makes hundreds of thousands of small allocations and some large ones on several
// threads; mimalloc serves them faster than the system allocator and keeps the pages it
// has touched, where glibc returns large blocks to the kernel and faults them in again.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> ExitCode {
    models::allocator::keep_freed_memory();
    // burn-flex's own convolutions, pooling and batch norms instead of the kernels crate's, to
    // compare the two (docs/benchmarks.md).
    if std::env::var_os("PIPELINE_BURN_KERNELS").is_some_and(|v| v == "1") {
        models::layers::use_own_kernels(false);
    }
    let cli = match pipeline::Cli::try_parse() {
        Ok(cli) => cli,
        // --help and --version print to stdout and exit 0.
        Err(e) if !e.use_stderr() => e.exit(),
        Err(e) => {
            let args: Vec<String> = std::env::args().skip(1).collect();
            let text = pipeline::cli::usage_error_text(&e, &args);
            let _ = std::io::Write::write_all(&mut std::io::stderr(), text.as_bytes());
            return ExitCode::from(2);
        }
    };
    let verbosity = cli.global.verbosity();
    pipeline::ui::init_logging(verbosity);
    match pipeline::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            pipeline::ui::report_error(&err, verbosity);
            ExitCode::FAILURE
        }
    }
}
