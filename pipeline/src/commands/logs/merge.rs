//! `pipeline logs merge --shards`: the frame folders of one `logs project --shard i/n` run
//! put back together: frames in order, then the previews, as the unsharded run writes them
//! (byte for byte; the merge writes no rerun recording).

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use datasets::shard::{SHARD_KEY, Shard, in_order, shard_record};
use serde_json::Value;
use sim::render::BevConfig;

use super::project::{
    FRAMES_JSON, FRAMES_JSONL, LAYERS_BIN, MARKERS, SHARD_PREVIEWS_KEY, write_frames_card,
    write_previews,
};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::AtomicDir;

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

/// One shard folder, read and checked.
struct FrameShard {
    dir: PathBuf,
    card: Value,
    lines: Vec<u8>,
    layers: Vec<u8>,
}

fn bad(path: &Path, problem: impl std::fmt::Display) -> anyhow::Error {
    CliError::file(
        path,
        problem.to_string(),
        "give the shard folders of one `pipeline logs project --shard i/n` run",
    )
    .into()
}

fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| bad(path, format!("cannot read: {e}")))
}

/// Reads a shard folder and checks that its files agree with its card.
fn read_shard(dir: &Path) -> Result<(Shard, FrameShard)> {
    let card_path = dir.join(FRAMES_JSON);
    let card: Value = serde_json::from_slice(&read(&card_path)?)
        .map_err(|e| bad(&card_path, format!("not JSON: {e}")))?;
    let shard = shard_record(&card).ok_or_else(|| {
        bad(
            &card_path,
            "is not a shard (no `shard` record; made without --shard?)",
        )
    })?;
    let frames = card.get("frames").and_then(Value::as_u64);
    let bev = card
        .get("bev")
        .cloned()
        .and_then(|v| serde_json::from_value::<BevConfig>(v).ok());
    let (Some(frames), Some(bev)) = (frames, bev) else {
        return Err(bad(&card_path, "has no `frames` count or `bev` settings"));
    };
    let lines = read(&dir.join(FRAMES_JSONL))?;
    let layers = read(&dir.join(LAYERS_BIN))?;
    let line_count = lines.iter().filter(|b| **b == b'\n').count() as u64;
    if line_count != frames {
        return Err(bad(
            &dir.join(FRAMES_JSONL),
            format!("has {line_count} lines but frames.json says {frames} frames"),
        ));
    }
    if layers.len() as u64 != frames * bev.frame_len() as u64 {
        return Err(bad(
            &dir.join(LAYERS_BIN),
            format!(
                "has {} bytes, not {frames} frames of {} bytes",
                layers.len(),
                bev.frame_len()
            ),
        ));
    }
    Ok((
        shard,
        FrameShard {
            dir: dir.to_path_buf(),
            card,
            lines,
            layers,
        },
    ))
}

/// A card without what differs between the shards of one run.
fn common_part(card: &Value) -> Value {
    let mut card = datasets::shard::without_shard(card);
    if let Some(object) = card.as_object_mut() {
        object.remove("frames");
    }
    card
}

pub fn run(ctx: &Context<'_>, args: &MergeArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    let shards = args
        .shards
        .iter()
        .map(|d| read_shard(d))
        .collect::<Result<Vec<_>>>()?;
    let shards = in_order(shards)
        .map_err(|e| CliError::new(e.to_string(), "give every shard folder of one run"))?;
    let first = common_part(&shards[0].1.card);
    for (shard, s) in &shards[1..] {
        if common_part(&s.card) != first {
            return Err(bad(
                &s.dir.join(FRAMES_JSON),
                format!(
                    "shard {}/{} was made with other settings than shard 0 (its frames.json differs)",
                    shard.index, shard.count
                ),
            ));
        }
    }
    let previews = first
        .get(SHARD_PREVIEWS_KEY)
        .and_then(Value::as_u64)
        .unwrap_or(0) as usize;
    let bev: BevConfig = first
        .get("bev")
        .cloned()
        .map(serde_json::from_value)
        .transpose()?
        .unwrap_or_default();

    let mut lines = Vec::new();
    let mut layers = Vec::new();
    let mut frames = 0u64;
    for (_, s) in &shards {
        lines.extend_from_slice(&s.lines);
        layers.extend_from_slice(&s.layers);
        frames += s.card.get("frames").and_then(Value::as_u64).unwrap_or(0);
    }
    let mut card = first;
    if let Some(object) = card.as_object_mut() {
        object.remove(SHARD_PREVIEWS_KEY);
        object.remove(SHARD_KEY);
        object.insert("frames".into(), frames.into());
    }

    let dir = AtomicDir::create(&out, MARKERS)?;
    write_frames_card(dir.path(), &card)?;
    for (name, bytes) in [(FRAMES_JSONL, &lines), (LAYERS_BIN, &layers)] {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).map_err(|e| {
            CliError::file(
                &out.join(name),
                format!("cannot write: {e}"),
                "check free disk space and permissions",
            )
        })?;
    }
    write_previews(dir.path(), &layers, previews, &bev)?;
    let dest = dir.commit()?;
    ctx.ui.result(&format!(
        "{frames} frames from {} shards; wrote {}",
        shards.len(),
        dest.display()
    ));
    Ok(())
}
