//! `pipeline dataset check`: reports what would make a dataset silently wrong; exits
//! non-zero when anything is found.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Result;
use datasets::Dataset;
use datasets::check::{ProblemKind, check_dataset_with_progress, item_labelable};
use datasets::classes::Class;

use super::open_dataset;
use crate::commands::Context;
use crate::error::CliError;
use crate::output::write_file_atomic;
use crate::ui::plural;

#[derive(Debug, clap::Args)]
pub struct CheckArgs {
    /// The dataset folder.
    pub dataset: PathBuf,

    /// Also write the report as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
}

/// A problem kind in words (the JSON keeps the snake_case names).
pub fn kind_words(kind: ProblemKind) -> &'static str {
    match kind {
        ProblemKind::Unreadable => "unreadable",
        ProblemKind::SizeMismatch => "size mismatch",
        ProblemKind::UnknownIds => "unknown class ids",
        ProblemKind::EmptyLabel => "empty label",
        ProblemKind::UnlabelableClass => "class its source cannot label",
        ProblemKind::Duplicate => "duplicate",
        ProblemKind::SplitLeak => "split leak",
    }
}

/// A dataset whose sources label different classes (a merge of generated and CamVid data):
/// a note naming the classes only some items' sources label, or None.
fn mixed_sources_note(dataset: &Dataset) -> Option<String> {
    let mut labelled_by: BTreeMap<u8, usize> = BTreeMap::new();
    for item in &dataset.items {
        for id in item_labelable(dataset, item) {
            *labelled_by.entry(id).or_default() += 1;
        }
    }
    let partial: Vec<String> = Class::ALL
        .iter()
        .filter(|c| !dataset.card.labels(**c))
        .filter_map(|c| {
            let n = labelled_by.get(&c.id()).copied().unwrap_or(0);
            (n > 0).then(|| {
                format!(
                    "{} in {n} of {}",
                    c.name().replace('_', " "),
                    plural(dataset.items.len(), "item")
                )
            })
        })
        .collect();
    (!partial.is_empty()).then(|| {
        format!(
            "note: its sources label different classes ({}); each item is checked against the classes its own source labels",
            partial.join(", ")
        )
    })
}

pub fn run(ctx: &Context<'_>, args: &CheckArgs) -> Result<()> {
    let dataset = open_dataset(&args.dataset)?;
    let mut progress = ctx.ui.progress("dataset check");
    progress.counted("checking", dataset.items.len() as u64, "items");
    let report = check_dataset_with_progress(&dataset, &|| progress.inc(1));
    drop(progress);
    if let Some(path) = &args.json {
        let mut json = serde_json::to_string_pretty(&report)?;
        json.push('\n');
        write_file_atomic(&ctx.output_path(path), json.as_bytes())?;
    }
    let note = mixed_sources_note(&dataset);
    let mut text = String::new();
    for p in &report.problems {
        text.push_str(&format!(
            "{}: {}: {}\n",
            kind_words(p.kind),
            p.id,
            p.message
        ));
    }
    if report.is_clean() {
        let mut text = format!(
            "{}: {}, no problems",
            args.dataset.display(),
            plural(report.items, "item")
        );
        if let Some(note) = note {
            text.push('\n');
            text.push_str(&note);
        }
        ctx.ui.result(&text);
        return Ok(());
    }
    if let Some(note) = note {
        text.push_str(&note);
        text.push('\n');
    }
    ctx.ui.result(&text);
    let mut counts: BTreeMap<ProblemKind, usize> = BTreeMap::new();
    for p in &report.problems {
        *counts.entry(p.kind).or_default() += 1;
    }
    let counts: Vec<String> = counts
        .iter()
        .map(|(k, v)| format!("{v} {}", kind_words(*k)))
        .collect();
    Err(CliError::file(
        &args.dataset,
        format!(
            "{} in {}: {}",
            plural(report.problems.len(), "problem"),
            plural(report.items, "item"),
            counts.join(", ")
        ),
        "fix or remove the items listed above (`dataset import --on-error skip` leaves broken ones out)",
    )
    .into())
}
