//! `pipeline dataset split`: sets each item's split in the manifest, deterministically.

use std::path::PathBuf;

use anyhow::Result;
use clap::ValueEnum;
use datasets::manifest::{MANIFEST_FILE, manifest_text};
use datasets::split::{GroupBy, SplitRatios, assign_groups, split_items};

use super::open_dataset;
use crate::commands::Context;
use crate::error::CliError;
use crate::output::write_file_atomic;
use crate::ui::plural;

/// What `split` writes beside the manifest: its settings and counts.
pub const SPLIT_JSON: &str = "split.json";

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum GroupByArg {
    /// Augmented copies stay with their source item.
    Source,
    /// Items sharing the id prefix before `_` (a video sequence) stay together.
    Prefix,
    /// Every item on its own.
    None,
}

#[derive(Debug, clap::Args)]
pub struct SplitArgs {
    /// The dataset folder; its manifest is rewritten (atomically) with the splits.
    pub dataset: PathBuf,

    /// Share of items for training.
    #[arg(long, default_value_t = 0.7)]
    pub train: f64,

    /// Share of items for validation.
    #[arg(long, default_value_t = 0.3)]
    pub val: f64,

    /// Share of items for testing.
    #[arg(long, default_value_t = 0.0)]
    pub test: f64,

    /// What must stay in one split.
    #[arg(long, value_enum, default_value = "source")]
    pub group_by: GroupByArg,

    /// Put this group (e.g. a CamVid sequence with `--group-by prefix`) in validation;
    /// repeatable or comma-separated. With --val-group or --test-group, the named groups
    /// go to their splits and every other group to training (the shares are not used).
    #[arg(long, value_name = "GROUP", value_delimiter = ',')]
    pub val_group: Vec<String>,

    /// Put this group in the test split; as --val-group.
    #[arg(long, value_name = "GROUP", value_delimiter = ',')]
    pub test_group: Vec<String>,
}

pub fn run(ctx: &Context<'_>, args: &SplitArgs) -> Result<()> {
    let ratios = SplitRatios {
        train: args.train,
        val: args.val,
        test: args.test,
    };
    ratios.validate().map_err(|e| {
        CliError::new(
            e.to_string(),
            "e.g. --train 0.7 --val 0.3, or --train 0.8 --val 0.1 --test 0.1",
        )
    })?;
    let group_by = match args.group_by {
        GroupByArg::Source => GroupBy::Source,
        GroupByArg::Prefix => GroupBy::Prefix,
        GroupByArg::None => GroupBy::None,
    };
    let mut dataset = open_dataset(&args.dataset)?;
    let named = !args.val_group.is_empty() || !args.test_group.is_empty();
    let counts = if named {
        assign_groups(
            &mut dataset.items,
            group_by,
            &args.val_group,
            &args.test_group,
        )
        .map_err(|e| {
            CliError::file(
                &args.dataset,
                e.to_string(),
                "name groups its items have (with --group-by prefix, the id up to its first `_`)",
            )
        })?
    } else {
        split_items(&mut dataset.items, &ratios, ctx.global.seed, group_by)
    };
    let manifest = args.dataset.join(MANIFEST_FILE);
    let text = manifest_text(&manifest, &dataset.items)?;
    let record = if named {
        serde_json::json!({
            "group_by": group_by,
            "val_groups": args.val_group,
            "test_groups": args.test_group,
            "counts": counts,
        })
    } else {
        serde_json::json!({
            "ratios": ratios,
            "group_by": group_by,
            "seed": ctx.global.seed,
            "counts": counts,
        })
    };
    let mut json = serde_json::to_string_pretty(&record)?;
    json.push('\n');
    write_file_atomic(&args.dataset.join(SPLIT_JSON), json.as_bytes())?;
    write_file_atomic(&manifest, text.as_bytes())?;
    ctx.ui.result(&format!(
        "train {}, val {}, test {} ({})",
        counts.train,
        counts.val,
        plural(counts.test, "item"),
        plural(counts.groups, "group")
    ));
    Ok(())
}
