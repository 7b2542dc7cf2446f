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
    let cli = pipeline::Cli::parse();
    let verbosity = cli.verbosity();
    pipeline::ui::init_logging(verbosity);
    match pipeline::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            pipeline::ui::report_error(&err, verbosity);
            ExitCode::FAILURE
        }
    }
}
