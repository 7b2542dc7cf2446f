//! `pipeline dataset augment`: joint image-and-label augmentation of a dataset.

use std::path::PathBuf;

use anyhow::Result;
use clap::ValueEnum;
use datasets::augment::{
    AugmentConfig, AugmentOptions, Preset, augment_dataset_with_progress, augment_inputs,
};

use super::{DATASET_MARKERS, DatasetOutputArgs, open_dataset, record_samples, report_skipped};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::AtomicDir;
use crate::ui::plural;

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PresetArg {
    /// The thesis's five: random crop (80 %), rotation (±10°), flip, blur, Gaussian noise.
    Thesis,
    /// Every transform (geometric, colour, blur, noise, JPEG, fog, shadow), moderate chances.
    Full,
}

#[derive(Debug, clap::Args)]
pub struct AugmentArgs {
    /// The input dataset folder.
    pub dataset: PathBuf,

    /// Output dataset folder (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Augmented copies per item.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub copies: u32,

    /// Which transforms, how likely, in which ranges.
    #[arg(long, value_enum, default_value = "thesis")]
    pub preset: PresetArg,

    /// A TOML file of transforms (the `AugmentConfig` fields, e.g. `rotate = { p = 1.0,
    /// range = [-10.0, 10.0] }`), used instead of --preset.
    #[arg(long, value_name = "FILE")]
    pub transforms: Option<PathBuf>,

    /// Also copy every input item unchanged into the output.
    #[arg(long)]
    pub include_originals: bool,

    #[command(flatten)]
    pub output: DatasetOutputArgs,

    /// Augment only shard i of n of the input's items (for running across machines);
    /// merge the n shard folders with `pipeline dataset merge --shards` (docs/scaling.md).
    #[arg(long, value_name = "i/n", value_parser = datasets::shard::Shard::parse)]
    pub shard: Option<datasets::shard::Shard>,
}

fn load_transforms(args: &AugmentArgs) -> Result<AugmentConfig> {
    let config = match &args.transforms {
        None => AugmentConfig::preset(match args.preset {
            PresetArg::Thesis => Preset::Thesis,
            PresetArg::Full => Preset::Full,
        }),
        Some(path) => {
            let text = std::fs::read_to_string(path).map_err(|e| {
                CliError::file(
                    path,
                    format!("cannot read: {e}"),
                    "check the --transforms path",
                )
            })?;
            toml::from_str(&text).map_err(|e| {
                CliError::file(
                    path,
                    format!("not a transforms file: {}", e.message()),
                    "see docs/datasets.md for the fields (crop, rotate, hflip, ... each { p, range })",
                )
            })?
        }
    };
    config.validate().map_err(|m| {
        let what = args
            .transforms
            .as_ref()
            .map_or("--preset".to_owned(), |p| p.display().to_string());
        CliError::new(
            format!("{what}: {m}"),
            "fix the transform's p (0..1) or range",
        )
    })?;
    Ok(config)
}

pub fn run(ctx: &Context<'_>, args: &AugmentArgs) -> Result<()> {
    let config = load_transforms(args)?;
    let dataset = open_dataset(&args.dataset)?;
    let dest = ctx.output_path(&args.out);
    let dir = AtomicDir::create(&dest, DATASET_MARKERS)?;
    let mut progress = ctx.ui.progress("dataset augment");
    progress.note(&format!(
        "{} x {} on {}",
        plural(dataset.items.len(), "item"),
        plural(args.copies as usize, "copy"),
        plural(rayon::current_num_threads(), "thread")
    ));
    let opts = AugmentOptions {
        name: args.output.dataset_name(&dest),
        config,
        copies: args.copies,
        include_originals: args.include_originals,
        seed: ctx.global.seed,
        on_error: args.output.on_error.into(),
        shard: args.shard,
    };
    progress.counted(
        "augmenting",
        augment_inputs(&dataset, &opts) as u64,
        "items",
    );
    let outcome = augment_dataset_with_progress(&dataset, &opts, dir.path(), &|| {
        progress.inc(1);
    })
    .map_err(|e| {
        let hint = match args.output.on_error {
            super::OnErrorArg::Fail => {
                "run `pipeline dataset check` on the input, or pass --on-error skip to leave broken items out"
            }
            super::OnErrorArg::Skip => "run `pipeline dataset check` on the input to see every broken item",
        };
        CliError::new(e.to_string(), hint)
    })?;
    progress.step("logging samples");
    record_samples(
        ctx,
        dir.path(),
        &outcome.items,
        args.output.log_samples,
        "augment",
    )?;
    drop(progress);
    report_skipped(ctx, &outcome.skipped);
    let out = dir.commit()?;
    ctx.ui.result(&format!(
        "{} from {} ({} skipped)",
        plural(outcome.items.len(), "item"),
        plural(dataset.items.len(), "input"),
        outcome.skipped.len()
    ));
    ctx.ui.info(&format!("wrote {}", out.display()));
    Ok(())
}
