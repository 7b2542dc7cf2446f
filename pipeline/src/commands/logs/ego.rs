//! `pipeline logs ego`: the ego's track from a log's ego-pose or GPS topic in a map's frame,
//! resampled to a fixed rate and matched to the map's lanes (`logs::ego`), written
//! as JSON.

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, ValueEnum};
use logs::decode::read_decoded;
use logs::ego::{EgoSource, MatchConfig, ego_track, match_lanes, resample};
use logs::roles::Role;
use logs::source::{Log, ReadOptions};
use serde_json::json;

use crate::commands::Context;
use crate::error::CliError;
use crate::inputs::load_or_import_map;
use crate::log_args::{RoleArgs, check_on_map, log_error, topic_roles};
use crate::output::write_file_atomic;

#[derive(Debug, Args)]
pub struct EgoArgs {
    /// The log: an .mcap file, a bag folder, its metadata.yaml, or a .db3 file.
    pub log: PathBuf,

    /// The map whose frame the track is wanted in (a map folder or file, or an OSM /
    /// Lanelet2 file).
    #[arg(long, value_name = "MAP|OSM")]
    pub map: PathBuf,

    /// The JSON file to write (atomically).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,

    /// Positions from the ego-pose topic (taken to be in the map's frame) or from the GPS
    /// topic (through the map's projection).
    #[arg(long, value_enum, default_value = "pose")]
    pub source: SourceArg,

    /// Samples per second of the resampled track.
    #[arg(long, value_name = "HZ", default_value_t = 10.0)]
    pub rate: f64,

    /// No sample is interpolated across a gap in the recording longer than this, s.
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    pub max_gap: f64,

    #[command(flatten)]
    pub roles: RoleArgs,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SourceArg {
    Pose,
    Gps,
}

pub fn run(ctx: &Context<'_>, args: &EgoArgs) -> Result<()> {
    if !(args.rate.is_finite()
        && args.rate > 0.0
        && args.max_gap.is_finite()
        && args.max_gap >= 0.0)
    {
        return Err(CliError::new(
            format!(
                "--rate {} and --max-gap {}: need a positive rate and a gap ≥ 0",
                args.rate, args.max_gap
            ),
            "e.g. --rate 10 --max-gap 1",
        )
        .into());
    }
    let mut progress = ctx.ui.progress("logs ego");
    progress.step(&format!("reading {}", args.map.display()));
    let map = load_or_import_map(&args.map)?;
    progress.step(&format!("reading {}", args.log.display()));
    let log = Log::open(&args.log).map_err(log_error)?;
    let decoded = read_decoded(&log, &ReadOptions::default()).map_err(log_error)?;
    let roles = topic_roles(
        &args.log,
        decoded
            .topics
            .iter()
            .map(|t| (t.name.as_str(), t.type_name.as_str(), t.encoding.as_str())),
        &args.roles.over(&ctx.config.logs.roles),
    )?;
    let (source, role) = match args.source {
        SourceArg::Pose => (EgoSource::Pose, Role::EgoPose),
        SourceArg::Gps => (EgoSource::Gps, Role::Gps),
    };
    let topic = roles.require(role).map_err(|e| {
        CliError::file(
            &args.log,
            e,
            "name the topic with --ego-topic / --gps-topic or [logs.roles] (`pipeline logs info` lists them)",
        )
    })?;
    let recorded = ego_track(&decoded, topic, source, &map);
    if recorded.is_empty() {
        return Err(CliError::file(
            &args.log,
            format!("{topic} holds no position the reader decodes"),
            "check the topic's type with `pipeline logs info`",
        )
        .into());
    }
    check_on_map(
        &args.log,
        &map,
        &args.map,
        recorded.iter().map(|s| s.position),
    )?;
    let (samples, report) = resample(&recorded, args.rate, args.max_gap);
    progress.step(&format!("matching {} samples to lanes", samples.len()));
    let matches = match_lanes(&map, &samples, &MatchConfig::default());
    let on_lane = matches.iter().flatten().filter(|m| m.on_lane).count();
    let distances: Vec<f64> = matches.iter().flatten().map(|m| m.distance_m).collect();
    let mean_distance =
        (!distances.is_empty()).then(|| distances.iter().sum::<f64>() / distances.len() as f64);
    let rows: Vec<serde_json::Value> = samples
        .iter()
        .zip(&matches)
        .map(|(s, m)| {
            json!({
                "time_ns": s.time_ns,
                "x": s.position.x,
                "y": s.position.y,
                "heading_rad": s.heading_rad,
                "lane": m.map(|m| m.lane),
                "lane_distance_m": m.map(|m| m.distance_m),
                "on_lane": m.is_some_and(|m| m.on_lane),
            })
        })
        .collect();
    let share = on_lane as f64 / samples.len().max(1) as f64;
    let document = json!({
        "log": args.log,
        "map": args.map,
        "topic": topic,
        "source": source,
        "rate_hz": args.rate,
        "max_gap_s": args.max_gap,
        "matching": MatchConfig::default(),
        "resampling": report,
        "on_lane_share": share,
        "mean_lane_distance_m": mean_distance,
        "samples": rows,
    });
    let out = ctx.output_path(&args.out);
    let mut text = serde_json::to_string_pretty(&document)?;
    text.push('\n');
    write_file_atomic(&out, text.as_bytes())?;
    drop(progress);
    ctx.ui.result(&format!(
        "{}: {} samples from {topic} ({} recorded, {} times in gaps) at {} Hz; on a lane {:.1} %, mean distance to the lane centre {}",
        out.display(),
        report.resampled,
        report.recorded,
        report.in_gaps,
        args.rate,
        100.0 * share,
        mean_distance.map_or("-".into(), |d| format!("{d:.2} m")),
    ));
    Ok(())
}
