//! `pipeline dataset merge`: datasets into one, with sampling weights.

use std::path::PathBuf;

use anyhow::Result;

use super::{DATASET_MARKERS, open_dataset};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::AtomicDir;
use crate::ui::plural;

#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// The dataset folders to merge.
    #[arg(required = true, num_args = 1..)]
    pub datasets: Vec<PathBuf>,

    /// Output dataset folder (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Sampling weight per dataset, comma-separated, in the order given [default: all 1].
    #[arg(long, value_delimiter = ',', value_name = "W")]
    pub weights: Vec<f64>,

    /// Items in the merged set [default: the inputs' total].
    #[arg(long, value_name = "N")]
    pub total: Option<usize>,

    /// Dataset name in the card [default: the output folder's name].
    #[arg(long)]
    pub name: Option<String>,

    /// The inputs are the shards of one `dataset generate --shard i/n` or `dataset augment
    /// --shard i/n` run: put them back together in item order (the result is the unsharded
    /// run's folder, byte for byte).
    #[arg(long, conflicts_with_all = ["weights", "total"])]
    pub shards: bool,
}

pub fn run(ctx: &Context<'_>, args: &MergeArgs) -> Result<()> {
    let weights = if args.weights.is_empty() {
        vec![1.0; args.datasets.len()]
    } else {
        args.weights.clone()
    };
    if weights.len() != args.datasets.len() {
        return Err(CliError::new(
            format!(
                "--weights: {} weights for {} datasets",
                weights.len(),
                args.datasets.len()
            ),
            "give one weight per dataset, e.g. --weights 1,2",
        )
        .into());
    }
    let inputs = args
        .datasets
        .iter()
        .map(|p| open_dataset(p))
        .collect::<Result<Vec<_>>>()?;
    let refs: Vec<&datasets::Dataset> = inputs.iter().collect();
    let dest = ctx.output_path(&args.out);
    let dir = AtomicDir::create(&dest, DATASET_MARKERS)?;
    let name = args
        .name
        .clone()
        .unwrap_or_else(|| super::folder_name(&dest));
    if args.shards {
        let (items, _) = datasets::shard::merge_shards(&name, &refs, dir.path())
            .map_err(|e| CliError::new(e.to_string(), "give every shard folder of one run"))?;
        let out = dir.commit()?;
        ctx.ui.result(&format!(
            "{} from {}",
            plural(items.len(), "item"),
            plural(refs.len(), "shard")
        ));
        ctx.ui.info(&format!("wrote {}", out.display()));
        return Ok(());
    }
    if args.datasets.len() < 2 {
        return Err(CliError::new(
            "merge needs two datasets or more",
            "give another dataset folder, or --shards for the shards of one run",
        )
        .into());
    }
    let (items, card) = datasets::merge::merge(
        &name,
        &refs,
        &weights,
        args.total,
        ctx.global.seed,
        dir.path(),
    )
    .map_err(|e| {
        CliError::new(
            e.to_string(),
            "check the inputs with `pipeline dataset check`",
        )
    })?;
    let out = dir.commit()?;
    let counts = card.config.get("counts").cloned().unwrap_or_default();
    ctx.ui.result(&format!(
        "{} (per input: {counts})",
        plural(items.len(), "item")
    ));
    ctx.ui.info(&format!("wrote {}", out.display()));
    Ok(())
}
