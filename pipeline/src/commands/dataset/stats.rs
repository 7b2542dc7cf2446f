//! `pipeline dataset stats`: exact channel statistics, class frequencies and weights.

use std::path::PathBuf;

use anyhow::Result;
use datasets::stats::{DatasetStats, dataset_stats_with_progress};

use super::open_dataset;
use crate::commands::Context;
use crate::error::CliError;
use crate::output::write_file_atomic;

/// File name `dataset stats` writes into the dataset folder unless `--out` says otherwise.
pub const STATS_JSON: &str = "stats.json";

#[derive(Debug, clap::Args)]
pub struct StatsArgs {
    /// The dataset folder.
    pub dataset: PathBuf,

    /// Where to write the JSON [default: stats.json in the dataset folder].
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

pub fn run(ctx: &Context<'_>, args: &StatsArgs) -> Result<()> {
    let dataset = open_dataset(&args.dataset)?;
    let mut progress = ctx.ui.progress("dataset stats");
    progress.counted("reading", dataset.items.len() as u64, "images");
    let stats = dataset_stats_with_progress(&dataset, &|| progress.inc(1)).map_err(|e| {
        CliError::new(
            e.to_string(),
            "run `pipeline dataset check` on the dataset to find every broken item",
        )
    })?;
    let out = match &args.out {
        Some(p) => ctx.output_path(p),
        None => args.dataset.join(STATS_JSON),
    };
    let mut json = serde_json::to_string_pretty(&stats)?;
    json.push('\n');
    write_file_atomic(&out, json.as_bytes())?;
    drop(progress);
    ctx.ui.result(&summary(&stats));
    ctx.ui.info(&format!("wrote {}", out.display()));
    Ok(())
}

/// The figures as a short table.
fn summary(s: &DatasetStats) -> String {
    let [mr, mg, mb] = s.mean_rgb;
    let [sr, sg, sb] = s.std_rgb;
    let mut text = format!(
        "{}: {}, {} pixels\nmean ± std (0-255): R {mr:.1} ± {sr:.1}, G {mg:.1} ± {sg:.1}, B {mb:.1} ± {sb:.1}\n",
        s.dataset,
        crate::ui::plural(s.images as usize, "image"),
        s.pixels
    );
    text.push_str("class          % of all  % labelled  images  weight\n");
    for c in &s.classes {
        let weight = c.weight.map_or("-".to_owned(), |w| format!("{w:.4}"));
        let note = if c.labelable {
            ""
        } else {
            "  (not labelled by this source)"
        };
        text.push_str(&format!(
            "{:<14} {:>8.2}  {:>10.2}  {:>6}  {weight}{note}\n",
            c.name, c.percent_of_all, c.percent_of_labelled, c.images
        ));
    }
    text.push_str(&format!(
        "ignore         {:>8.2}\n",
        s.ignore_percent_of_all
    ));
    text
}
