//! `pipeline logs merge --shards`: the frame folders of one `logs project --shard i/n` run
//! put back together (`logs::frames::merge_shard_dirs`): frames in order, then the
//! previews, as the unsharded run writes them (byte for byte; the merge writes no rerun
//! recording).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use logs::frames::{
    FRAMES_JSON, FRAMES_JSONL, FrameMergeError, LAYERS_BIN, merge_shard_dirs, write_card,
    write_previews,
};

use crate::commands::Context;
use crate::error::CliError;
use crate::log_args::write_error;
use crate::output::AtomicDir;

const MARKERS: crate::output::Markers = &[FRAMES_JSON];

#[derive(Debug, Args)]
pub struct MergeArgs {
    /// The shard folders of one `logs project --shard i/n` run, each of 0..n once (any
    /// order).
    #[arg(long, value_name = "DIR", num_args = 1.., required = true)]
    pub shards: Vec<PathBuf>,

    /// Output folder (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

pub fn run(ctx: &Context<'_>, args: &MergeArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    let merged = merge_shard_dirs(&args.shards).map_err(|e| {
        let hint = match e {
            FrameMergeError::Shard { .. } => {
                "give the shard folders of one `pipeline logs project --shard i/n` run"
            }
            FrameMergeError::Order(_) => "give every shard folder of one run",
        };
        CliError::new(e.to_string(), hint)
    })?;

    let dir = AtomicDir::create(&out, MARKERS)?;
    write_card(dir.path(), &merged.card).map_err(write_error)?;
    for (name, bytes) in [(FRAMES_JSONL, &merged.lines), (LAYERS_BIN, &merged.layers)] {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).map_err(|e| {
            CliError::file(
                &out.join(name),
                format!("cannot write: {e}"),
                "check free disk space and permissions",
            )
        })?;
    }
    write_previews(dir.path(), &merged.layers, merged.previews, &merged.bev)
        .map_err(write_error)?;
    let dest = dir.commit()?;
    ctx.ui.result(&format!(
        "{} frames from {} shards; wrote {}",
        merged.frames,
        merged.shards,
        dest.display()
    ));
    Ok(())
}
