//! The frame folder `pipeline logs project` writes, and the shards of one projection put back
//! together.
//!
//! A folder holds [`FRAMES_JSON`] (what the frames are: layers, size, extent, the log, the
//! map, the ego, counts), [`FRAMES_JSONL`] (one line per frame: time, the ego's pose and
//! speed, road users), [`LAYERS_BIN`] (the frames' `u8` layers, frame after frame,
//! layer-major, `width × height` bytes per layer) and a few previews ([`PREVIEWS_DIR`],
//! layers in colour). A shard's folder has no previews; its card says how many the merged
//! folder gets ([`SHARD_PREVIEWS_KEY`]).

use std::path::{Path, PathBuf};

use datasets::DatasetError;
use datasets::shard::{SHARD_KEY, Shard, in_order, shard_record};
use image::RgbImage;
use serde_json::Value;
use sim::render::{BevConfig, Layer};

use crate::error::{LogError, LogResult};

pub const FRAMES_JSON: &str = "frames.json";
pub const FRAMES_JSONL: &str = "frames.jsonl";
pub const LAYERS_BIN: &str = "layers.bin";
pub const PREVIEWS_DIR: &str = "previews";
/// Key of a shard's `frames.json` saying how many previews the merged folder gets.
pub const SHARD_PREVIEWS_KEY: &str = "shard_previews";

/// A frame's layers in colour: navigable grey, path green, stop lines yellow, vehicles red.
pub fn preview(frame: &[u8], config: &BevConfig) -> RgbImage {
    let (w, h) = (config.width, config.height);
    let layer = |kind: Layer| {
        config
            .layers
            .iter()
            .position(|l| *l == kind)
            .map(|i| &frame[i * w * h..(i + 1) * w * h])
    };
    let (nav, path, obstacles, lines) = (
        layer(Layer::Navigable),
        layer(Layer::Path),
        layer(Layer::Obstacles),
        layer(Layer::StopLines),
    );
    let on = |l: Option<&[u8]>, i: usize| l.is_some_and(|l| l[i] != 0);
    RgbImage::from_fn(w as u32, h as u32, |x, y| {
        let i = y as usize * w + x as usize;
        image::Rgb(if on(obstacles, i) {
            [230, 60, 50]
        } else if on(lines, i) {
            [250, 220, 40]
        } else if on(path, i) {
            [60, 200, 90]
        } else if on(nav, i) {
            [120, 120, 120]
        } else {
            [20, 20, 20]
        })
    })
}

/// Writes `n` previews evenly spread over the frames of `layers` (the first and the last
/// included) into `dir/previews/frame_<j>.png`.
pub fn write_previews(dir: &Path, layers: &[u8], n: usize, config: &BevConfig) -> LogResult<()> {
    let frame_len = config.frame_len();
    let frames = layers.len() / frame_len.max(1);
    if n == 0 || frames == 0 {
        return Ok(());
    }
    let previews = dir.join(PREVIEWS_DIR);
    std::fs::create_dir_all(&previews).map_err(|e| LogError::io(&previews, e))?;
    let n = n.min(frames);
    for p in 0..n {
        let j = if n == 1 {
            0
        } else {
            p * (frames - 1) / (n - 1)
        };
        let png = datasets::image_io::encode_rgb_png(&preview(
            &layers[j * frame_len..(j + 1) * frame_len],
            config,
        ));
        let path = previews.join(format!("frame_{j:06}.png"));
        std::fs::write(&path, png).map_err(|e| LogError::io(&path, e))?;
    }
    Ok(())
}

/// Writes a frame folder's `frames.json` (pretty JSON and a newline).
pub fn write_card(dir: &Path, card: &Value) -> LogResult<()> {
    let path = dir.join(FRAMES_JSON);
    let text = serde_json::to_string_pretty(card)
        .map_err(|e| LogError::format(&path, format!("cannot serialise: {e}")))?;
    std::fs::write(&path, format!("{text}\n")).map_err(|e| LogError::io(&path, e))
}

/// Why the shards of a projection do not fit together.
#[derive(Debug, thiserror::Error)]
pub enum FrameMergeError {
    /// A shard folder's file is missing, unreadable or disagrees with its card, or the
    /// shard was made with other settings than shard 0.
    #[error("{}: {problem}", path.display())]
    Shard { path: PathBuf, problem: String },
    /// The shards are not each of `0..n` once.
    #[error("{0}")]
    Order(DatasetError),
}

fn bad(path: &Path, problem: impl std::fmt::Display) -> FrameMergeError {
    FrameMergeError::Shard {
        path: path.to_path_buf(),
        problem: problem.to_string(),
    }
}

/// One shard folder, read and checked.
#[derive(Debug)]
struct FrameShard {
    dir: PathBuf,
    card: Value,
    lines: Vec<u8>,
    layers: Vec<u8>,
}

fn read(path: &Path) -> Result<Vec<u8>, FrameMergeError> {
    std::fs::read(path).map_err(|e| bad(path, format!("cannot read: {e}")))
}

/// Reads a shard folder and checks that its files agree with its card.
fn read_shard(dir: &Path) -> Result<(Shard, FrameShard), FrameMergeError> {
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

/// The shards of one projection put together: the unsharded run's files.
#[derive(Debug)]
pub struct MergedFrames {
    /// `frames.json`.
    pub card: Value,
    /// `frames.jsonl`.
    pub lines: Vec<u8>,
    /// `layers.bin`.
    pub layers: Vec<u8>,
    /// Previews to draw.
    pub previews: usize,
    pub bev: BevConfig,
    pub frames: u64,
    pub shards: usize,
}

/// Reads the shard folders `dirs` of one `logs project --shard i/n` run (any order) and puts
/// them together in shard order.
pub fn merge_shard_dirs(dirs: &[PathBuf]) -> Result<MergedFrames, FrameMergeError> {
    let shards = dirs
        .iter()
        .map(|d| read_shard(d))
        .collect::<Result<Vec<_>, _>>()?;
    let shards = in_order(shards).map_err(FrameMergeError::Order)?;
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
        .transpose()
        .map_err(|e| bad(&shards[0].1.dir.join(FRAMES_JSON), e))?
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
    Ok(MergedFrames {
        card,
        lines,
        layers,
        previews,
        bev,
        frames,
        shards: shards.len(),
    })
}
