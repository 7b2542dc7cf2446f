//! `pipeline logs project`: a log's object frames drawn in the bird's-eye representation
//! around one vehicle, as a frame dataset.
//!
//! The output folder holds `frames.json`, `frames.jsonl`, `layers.bin` and a few
//! `previews/*.png` (`logs::frames` describes them), and the rerun recording (the map,
//! every vehicle as a box, the layers).
//!
//! With `--shard i/n` only shard `i`'s share of the ego's frames is drawn, and the folder
//! holds `frames.json` (with the shard record), `frames.jsonl` and `layers.bin`, no
//! previews and no recording; `pipeline logs merge --shards` puts the shards together.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context as _, Result};
use clap::Args;
use datasets::shard::{SHARD_KEY, Shard};
use logs::decode::read_decoded;
use logs::frames::{
    FRAMES_JSON, FRAMES_JSONL, LAYERS_BIN, SHARD_PREVIEWS_KEY, write_card, write_previews,
};
use logs::noise::NoiseConfig;
use logs::project::{LogFrame, log_frames, project_shard, track_lengths};
use logs::source::{Log, ReadOptions};
use serde_json::json;
use sim::render::{BevConfig, BevRenderer};

use crate::commands::Context;
use crate::error::CliError;
use crate::inputs::load_or_import_map;
use crate::log_args::{RoleArgs, check_on_map, log_error, objects_topic, write_error};
use crate::output::AtomicDir;
use crate::recording::{log_actors, log_layers, log_map};

const MARKERS: crate::output::Markers = &[FRAMES_JSON];

#[derive(Debug, Args)]
pub struct ProjectArgs {
    /// The log: an .mcap file (e.g. from `logs convert`), a bag folder or a .db3 file.
    pub log: PathBuf,

    /// The map the log was recorded on: a map folder or file, or an OSM / Lanelet2 file.
    #[arg(long, value_name = "MAP|OSM")]
    pub map: PathBuf,

    /// Output folder (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Track id of the vehicle to centre the frames on [default: the longest track].
    #[arg(long, value_name = "TRACK_ID")]
    pub ego: Option<u32>,

    #[command(flatten)]
    pub roles: RoleArgs,

    /// PNG previews written (evenly spread over the frames).
    #[arg(long, value_name = "N", default_value_t = 4)]
    pub previews: usize,

    /// Frames logged to the rerun recording (from the first).
    #[arg(long, value_name = "N", default_value_t = 300)]
    pub record_frames: usize,

    /// Perception noise: standard deviation of the other users' positions (each
    /// coordinate), m.
    #[arg(long, value_name = "M", default_value_t = 0.0)]
    pub position_noise: f64,

    /// Perception noise: standard deviation of the other users' length and width, m.
    #[arg(long, value_name = "M", default_value_t = 0.0)]
    pub size_noise: f64,

    /// Perception noise: standard deviation of the other users' heading, degrees.
    #[arg(long, value_name = "DEG", default_value_t = 0.0)]
    pub heading_noise: f64,

    /// Perception noise: the ego's path bent by a Bézier curve whose inner control points
    /// move sideways by this standard deviation, m.
    #[arg(long, value_name = "M", default_value_t = 0.0)]
    pub path_noise: f64,

    /// Draw only shard i of n of the ego's frames (for running across machines); merge the
    /// n shard folders with `pipeline logs merge --shards` (docs/scaling.md).
    #[arg(long, value_name = "i/n", value_parser = Shard::parse)]
    pub shard: Option<Shard>,
}

pub fn run(ctx: &Context<'_>, args: &ProjectArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    let mut progress = ctx.ui.progress("logs project");
    progress.step(&format!("reading {}", args.map.display()));
    let map = Arc::new(load_or_import_map(&args.map)?);
    progress.step(&format!("reading {}", args.log.display()));
    let log = Log::open(&args.log).map_err(log_error)?;
    let decoded = read_decoded(&log, &ReadOptions::default()).map_err(log_error)?;
    let objects = objects_topic(ctx, &args.log, &decoded, &args.roles)?;
    let frames: Vec<LogFrame> = log_frames(&decoded, Some(&objects));
    if frames.is_empty() {
        return Err(CliError::file(
            &args.log,
            format!("has no vision_msgs/Detection3DArray frames on {objects}"),
            "give --objects-topic (see `pipeline logs info`), or convert tracks with `pipeline logs convert`",
        )
        .into());
    }
    check_on_map(
        &args.log,
        &map,
        &args.map,
        logs::on_map::vehicle_positions(&frames),
    )?;
    let lengths = track_lengths(&frames);
    let ego = match args.ego {
        Some(id) if lengths.contains_key(&id) => id,
        Some(id) => {
            return Err(CliError::file(
                &args.log,
                format!("has no track {id} ({} tracks)", lengths.len()),
                "give --ego one of the log's track ids (the detections' id field)",
            )
            .into());
        }
        // The longest track; ties to the smallest id.
        None => lengths
            .iter()
            .max_by_key(|(id, n)| (**n, std::cmp::Reverse(**id)))
            .map(|(id, _)| *id)
            .unwrap_or_default(),
    };
    let config = BevConfig::default();
    let renderer = BevRenderer::new(&map, map.bounds(), config.clone()).map_err(|e| {
        CliError::file(
            &args.map,
            e.to_string(),
            "give the map the log was recorded on",
        )
    })?;

    progress.step(&format!(
        "projecting {} frames around track {ego}",
        lengths[&ego]
    ));
    let start = Instant::now();
    for (flag, v) in [
        ("--position-noise", args.position_noise),
        ("--size-noise", args.size_noise),
        ("--heading-noise", args.heading_noise),
        ("--path-noise", args.path_noise),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(CliError::new(
                format!("{flag} {v}: a standard deviation must be 0 or more"),
                "e.g. --position-noise 0.3",
            )
            .into());
        }
    }
    let noise = NoiseConfig {
        position_sigma_m: args.position_noise,
        size_sigma_m: args.size_noise,
        heading_sigma_deg: args.heading_noise,
        path_sigma_m: args.path_noise,
        seed: ctx.global.seed,
    };
    let (figures, layers) = project_shard(&map, &renderer, &frames, ego, &noise, args.shard);
    let seconds = start.elapsed().as_secs_f64();

    let dir = AtomicDir::create(&out, MARKERS)?;
    let write = |name: &str, bytes: &[u8]| -> Result<()> {
        std::fs::write(dir.path().join(name), bytes)
            .with_context(|| format!("{}: cannot write {name}", out.display()))
    };
    let layer_names: Vec<&str> = config.layers.iter().map(|l| l.name()).collect();
    let mut card = json!({
        "tool": "pipeline logs project",
        "pipeline_version": env!("CARGO_PKG_VERSION"),
        "log": args.log.file_name().map(|n| n.to_string_lossy().into_owned()),
        "map": args.map.file_name().map(|n| n.to_string_lossy().into_owned()),
        "ego": ego,
        "frames": figures.len(),
        "log_frames": frames.len(),
        "tracks": lengths.len(),
        "layers": layer_names,
        "width": config.width,
        "height": config.height,
        "bev": config,
        "noise": noise,
        "layers_file": LAYERS_BIN,
    });
    if let (Some(shard), Some(object)) = (args.shard, card.as_object_mut()) {
        object.insert(SHARD_KEY.into(), json!(shard));
        object.insert(SHARD_PREVIEWS_KEY.into(), json!(args.previews));
    }
    write_card(dir.path(), &card).map_err(write_error)?;
    let mut lines = String::new();
    for f in &figures {
        lines.push_str(&serde_json::to_string(f)?);
        lines.push('\n');
    }
    write(FRAMES_JSONL, lines.as_bytes())?;
    write(LAYERS_BIN, &layers)?;
    let frame_len = config.frame_len();
    if let Some(shard) = args.shard {
        // The merge draws the previews; shards write no recording.
        let dest = dir.commit()?;
        drop(progress);
        ctx.ui.result(&format!(
            "{} frames around track {ego} in {seconds:.2} s (shard {}/{}); wrote {}",
            figures.len(),
            shard.index,
            shard.count,
            dest.display()
        ));
        return Ok(());
    }
    write_previews(dir.path(), &layers, args.previews, &config).map_err(write_error)?;

    let recording = ctx.open_recording(Some(dir.path()))?;
    if let Some(rec) = recording.stream() {
        log_map(rec, &map)?;
        for (j, f) in figures.iter().enumerate().take(args.record_frames) {
            rec.set_time_sequence("frame", j as i64);
            rec.set_duration_secs("sim_time", f.time_ns as f64 * 1e-9);
            let actors = &frames[f.log_frame].actors;
            let ego_index = actors.iter().position(|a| a.id == ego).unwrap_or(0);
            log_actors(rec, "world/logs/vehicles", actors, ego_index)?;
            log_layers(
                rec,
                "logs/bev",
                &layers[j * frame_len..(j + 1) * frame_len],
                &layer_names,
                config.width,
                config.height,
            )?;
        }
    }
    recording.finish()?;
    let dest = dir.commit()?;
    drop(progress);
    ctx.ui.result(&format!(
        "{} frames around track {ego} ({} log frames, {} tracks) in {seconds:.2} s ({:.0} frames/s on {} threads); wrote {}",
        figures.len(),
        frames.len(),
        lengths.len(),
        figures.len() as f64 / seconds.max(1e-9),
        rayon::current_num_threads(),
        dest.display()
    ));
    Ok(())
}
