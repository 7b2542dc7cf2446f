//! What the logs crate's integration tests share.

#![allow(clippy::print_stdout)]

use std::path::{Path, PathBuf};

/// `../shared/data/<relative>` beside the repository, or `None` with a printed notice when
/// it is absent (a user's fresh clone), so the test skips and passes.
pub fn shared_data(relative: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(relative);
    if dir.is_dir() {
        Some(dir)
    } else {
        println!(
            "skipped: {}: {} is absent",
            std::thread::current().name().unwrap_or("-"),
            dir.display()
        );
        None
    }
}
