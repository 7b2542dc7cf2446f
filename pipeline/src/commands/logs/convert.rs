//! `pipeline logs convert`: an INTERACTION track file and its Lanelet2 map into an MCAP log.

use std::io::Cursor;

use anyhow::Result;
use logs::convert::{ChunkCompression, ConvertConfig, interaction_to_mcap};
use logs::interaction::read_track_file;
use maps::{ImportOptions, Projection};

use super::{CompressionArg, ConvertArgs};
use crate::commands::Context;
use crate::error::{CliError, FileRole, map_error};
use crate::log_args::{check_on_map, log_error};
use crate::output::write_file_atomic;

pub fn run(ctx: &Context<'_>, args: &ConvertArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    let mut progress = ctx.ui.progress("logs convert");

    progress.step("reading tracks");
    let tracks = read_track_file(&args.tracks).map_err(log_error)?;
    if !tracks.skipped.is_empty() {
        let (line, reason) = &tracks.skipped[0];
        ctx.ui.warn(&format!(
            "{}: skipped {} malformed rows (first: line {line}: {reason})",
            args.tracks.display(),
            tracks.skipped.len()
        ));
    }

    progress.step("importing the map");
    let map = maps::import_file(&args.map, &ImportOptions::default())
        .map_err(|e| map_error(&args.map, e, FileRole::OsmInput))?;
    if !matches!(map.projection, Projection::Utm { .. }) {
        return Err(CliError::file(
            &args.map,
            "is not a Lanelet2 map (INTERACTION tracks are in a Lanelet2 map's UTM frame)",
            "give the scenario's Lanelet2 .osm file from the dataset's maps/ folder",
        )
        .into());
    }
    check_on_map(&args.tracks, &map, &args.map, tracks.positions())?;

    progress.step("writing MCAP");
    let name = |p: &std::path::Path| {
        p.file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
    };
    let config = ConvertConfig {
        ego: args.ego,
        compression: match args.compression {
            CompressionArg::Zstd => ChunkCompression::Zstd,
            CompressionArg::Lz4 => ChunkCompression::Lz4,
            CompressionArg::None => ChunkCompression::None,
        },
        source_name: name(&args.tracks),
        map_name: name(&args.map),
        ..Default::default()
    };
    let mut bytes = Cursor::new(Vec::new());
    let summary =
        interaction_to_mcap(&tracks, &map.projection, &config, &mut bytes).map_err(|e| {
            CliError::new(
                format!("{}: {e}", args.tracks.display()),
                "see `pipeline logs convert --help`",
            )
        })?;
    write_file_atomic(&out, bytes.get_ref())?;
    drop(progress);

    let topics: Vec<String> = summary
        .messages
        .iter()
        .map(|(t, n)| format!("{t} {n}"))
        .collect();
    ctx.ui.result(&format!(
        "{}: {} frames, {} tracks, {} detections; messages: {}",
        out.display(),
        summary.frames,
        summary.tracks,
        summary.detections,
        topics.join(", ")
    ));
    Ok(())
}
