//! `pipeline dataset check`: reports what would make a dataset silently wrong; exits
//! non-zero when anything is found.

use std::path::PathBuf;

use anyhow::Result;
use datasets::check::check_dataset;

use super::open_dataset;
use crate::commands::Context;
use crate::error::CliError;
use crate::output::write_file_atomic;

#[derive(Debug, clap::Args)]
pub struct CheckArgs {
    /// The dataset folder.
    pub dataset: PathBuf,

    /// Also write the report as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
}

pub fn run(ctx: &Context<'_>, args: &CheckArgs) -> Result<()> {
    let dataset = open_dataset(&args.dataset)?;
    let mut progress = ctx.ui.progress("dataset check");
    progress.step(&format!("checking {} items", dataset.items.len()));
    let report = check_dataset(&dataset);
    drop(progress);
    if let Some(path) = &args.json {
        let mut json = serde_json::to_string_pretty(&report)?;
        json.push('\n');
        write_file_atomic(&ctx.output_path(path), json.as_bytes())?;
    }
    let mut text = String::new();
    for p in &report.problems {
        text.push_str(&format!("{:?}: {}: {}\n", p.kind, p.id, p.message));
    }
    if report.is_clean() {
        ctx.ui.result(&format!(
            "{}: {} items, no problems",
            args.dataset.display(),
            report.items
        ));
        return Ok(());
    }
    ctx.ui.result(&text);
    let counts: Vec<String> = report
        .counts
        .iter()
        .map(|(k, v)| format!("{v} {k}"))
        .collect();
    Err(CliError::file(
        &args.dataset,
        format!("{} problem(s) in {} items: {}", report.problems.len(), report.items, counts.join(", ")),
        "fix or remove the items listed above (`dataset import --on-error skip` leaves broken ones out)",
    )
    .into())
}
