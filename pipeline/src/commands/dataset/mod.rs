//! `pipeline dataset ...`: segmentation datasets in the one manifest format
//! (`datasets::manifest`). Each command's arguments and handler live in their own file.

use anyhow::Result;
use clap::Subcommand;

use super::Context;

pub mod augment;
pub mod check;
pub mod generate;
mod generate_args;
pub mod import;
pub mod merge;
pub mod split;
pub mod stats;

#[derive(Debug, Subcommand)]
pub enum DatasetCommand {
    /// Render labelled front-camera images from a map (or an OSM file imported on the fly).
    Generate(generate::GenerateArgs),
    /// Bring a public label set (CamVid, Cityscapes, Mapillary, CARLA, lane masks, folders)
    /// into our classes through a class map.
    Import(import::ImportArgs),
    /// Joint image-and-label augmentation; `--copies 7` with the thesis preset.
    Augment(augment::AugmentArgs),
    /// Exact per-channel mean and std, class pixel frequencies and class weights, as JSON.
    Stats(stats::StatsArgs),
    /// Deterministic train / val (/ test) split, 70 / 30 by default.
    Split(split::SplitArgs),
    /// Find unknown ids, size mismatches, empty labels, duplicates and split leakage.
    Check(check::CheckArgs),
    /// Merge datasets with sampling weights.
    Merge(merge::MergeArgs),
}

pub fn run(ctx: &Context<'_>, command: &DatasetCommand) -> Result<()> {
    match command {
        DatasetCommand::Generate(args) => generate::run(ctx, args),
        DatasetCommand::Import(args) => import::run(ctx, args),
        DatasetCommand::Augment(args) => augment::run(ctx, args),
        DatasetCommand::Stats(args) => stats::run(ctx, args),
        DatasetCommand::Split(args) => split::run(ctx, args),
        DatasetCommand::Check(args) => check::run(ctx, args),
        DatasetCommand::Merge(args) => merge::run(ctx, args),
    }
}

/// Opens a dataset folder, with an error that names it and says what to do.
pub fn open_dataset(path: &std::path::Path) -> Result<datasets::Dataset> {
    datasets::Dataset::open(path).map_err(|e| {
        crate::error::CliError::new(
            e.to_string(),
            "give a dataset folder written by `pipeline dataset generate | import | augment`",
        )
        .into()
    })
}

/// A folder holding any of these is an earlier dataset output that may be replaced.
pub const DATASET_MARKERS: crate::output::Markers = &[
    datasets::manifest::MANIFEST_FILE,
    datasets::manifest::CARD_FILE,
];

/// The options of commands that write a dataset from items that may be broken.
#[derive(Debug, Clone, clap::Args)]
pub struct DatasetOutputArgs {
    /// What to do with a broken item: stop with its error, or skip it and count it.
    #[arg(long, value_enum, default_value = "fail")]
    pub on_error: OnErrorArg,

    /// Dataset name in the card [default: the output folder's name].
    #[arg(long)]
    pub name: Option<String>,

    /// How many items to log to rerun.
    #[arg(long, value_name = "N", default_value_t = 16)]
    pub log_samples: usize,
}

impl DatasetOutputArgs {
    /// `--name`, or the name of the output folder `dest`.
    pub fn dataset_name(&self, dest: &std::path::Path) -> String {
        self.name.clone().unwrap_or_else(|| folder_name(dest))
    }
}

pub use crate::args::OnErrorArg;

/// The last part of a folder path, for default dataset names.
pub fn folder_name(path: &std::path::Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".to_owned())
}

/// Warns about skipped items: how many, and the first few reasons.
pub fn report_skipped(ctx: &Context<'_>, skipped: &[datasets::error::Skipped]) {
    if skipped.is_empty() {
        return;
    }
    ctx.ui.warn(&format!(
        "skipped {} (--on-error skip)",
        crate::ui::plural(skipped.len(), "broken item")
    ));
    for s in skipped.iter().take(10) {
        ctx.ui.warn(&format!("  {}: {}", s.id, s.reason));
    }
}

/// Records the class table and the first `n` items of a dataset folder being written
/// (`dataset/<name>/image` and `/label`, one `frame` per item) in the command's rerun
/// recording (saved into `dir` by default).
pub fn record_samples(
    ctx: &Context<'_>,
    dir: &std::path::Path,
    items: &[datasets::Item],
    n: usize,
    name: &str,
) -> Result<()> {
    let recording = ctx.open_recording(Some(dir))?;
    if let Some(stream) = recording.stream() {
        crate::recording::log_class_context(stream)?;
        for (frame, item) in items.iter().take(n).enumerate() {
            let image = datasets::image_io::read_rgb(&dir.join(&item.image))?;
            let label = datasets::image_io::read_label(&dir.join(&item.label))?;
            crate::recording::log_sample(stream, name, frame as i64, &image, &label)?;
        }
    }
    recording.finish()
}
