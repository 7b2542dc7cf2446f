//! `pipeline replay merge --shards`: the shards of one `replay eval --shard i/n` run added
//! up (`judge::merge_shard_dirs`) into the unsharded run's report.

use anyhow::Result;
use judge::merge_shard_dirs;

use super::{MARKERS, MergeArgs, write_report};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::AtomicDir;

pub fn run(ctx: &Context<'_>, args: &MergeArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    let report = merge_shard_dirs(&args.shards).map_err(|e| {
        CliError::new(
            e.to_string(),
            "give the shard folders of one `pipeline replay eval --shard i/n` run",
        )
    })?;
    write_report(ctx, &out, &report)
}
