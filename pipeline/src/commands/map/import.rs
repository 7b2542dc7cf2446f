//! `pipeline map import`: an OpenStreetMap or Lanelet2 file to a map folder.

use anyhow::Result;

use super::args::ImportArgs;
use super::options::resolve_import_options;
use crate::args::RerunMode;
use crate::commands::Context;
use crate::error::{CliError, FileRole, map_error};
use crate::output::{AtomicDir, Markers};
use crate::recording;
use crate::ui::plural;

use super::outputs::{
    ImportRecord, InputInfo, MAP_BIN, MAP_JSON, SUMMARY_JSON, sha256_file, write_outputs,
};

/// A folder holding any of these is an earlier import that may be replaced.
const IMPORT_MARKERS: Markers = &[SUMMARY_JSON, MAP_JSON, MAP_BIN];

pub fn import(ctx: &Context<'_>, args: &ImportArgs) -> Result<()> {
    let input = &args.input;
    let out = ctx.output_path(&args.out);
    let resolved = resolve_import_options(ctx, args)?;
    let options = &resolved.options;
    if !input.is_file() {
        return Err(CliError::file(
            input,
            "no such file",
            "check the input path (an .osm, .osm.gz or .osm.pbf file)",
        )
        .into());
    }
    // A bad destination fails now, not after the import.
    AtomicDir::check_destination(&out, IMPORT_MARKERS)?;

    let mut progress = ctx.ui.progress("map import");
    progress.step(&format!("reading {}", input.display()));
    let (osm, format) =
        maps::osm::read_osm_file(input).map_err(|e| map_error(input, e, FileRole::OsmInput))?;
    let lanelet2 = osm.is_lanelet2();
    progress.note(&format!(
        "{} nodes, {} ways, {} relations{}",
        osm.nodes.len(),
        osm.ways.len(),
        osm.relations.len(),
        if lanelet2 { " (Lanelet2)" } else { "" }
    ));

    progress.step(&format!(
        "building the map (profile {})",
        options.profile.name
    ));
    // The reader parses on every core but the build mostly runs on one: meanwhile, another
    // core hashes the input for summary.json and prepares the output folder and the
    // recording (whose sink starts threads). If the build fails, dropping them removes the
    // folder, recording included.
    let prepare_outputs = || -> Result<_> {
        let hashed = sha256_file(input)?;
        let dir = AtomicDir::create(&out, IMPORT_MARKERS)?;
        let rec = match ctx.global.rerun {
            RerunMode::Off => None,
            _ => Some(ctx.open_recording(Some(dir.path()))?),
        };
        Ok((hashed, dir, rec))
    };
    let (built, prepared) = rayon::join(|| maps::import_osm(&osm, options), prepare_outputs);
    let map = built.map_err(|e| map_error(input, e, FileRole::OsmInput))?;
    let ((bytes, sha256), dir, rec) = prepared?;
    // Freeing the parsed OSM data (hundreds of thousands of small allocations) costs more
    // than the rest of the import's bookkeeping; the process ends right after the import.
    std::mem::forget(osm);
    if map.lanes.is_empty() {
        return Err(CliError::file(
            input,
            format!("no drivable roads selected (profile {})", options.profile.name),
            "the file holds no roads for this profile: try --profile all, a larger --clip-bbox, or another file",
        )
        .into());
    }
    let summary = maps::summary::summarize(&map);
    let input_info = InputInfo {
        file: input
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        format,
        lanelet2,
        bytes,
        sha256,
    };
    let record = ImportRecord {
        options,
        profile_source: &resolved.profile_source,
        seed: ctx.global.seed,
        pipeline_version: env!("CARGO_PKG_VERSION"),
        map_format_version: maps::model::MAP_FORMAT_VERSION,
    };

    progress.step(&format!("writing {}", out.display()));
    // The recording is independent of the files: log it while they are encoded. It is
    // finished (flushed, closed) before the rename, so the .rrd is complete when the folder appears.
    let (written, recorded) = rayon::join(
        || write_outputs(dir.path(), &map, &summary, &input_info, record),
        || -> Result<()> {
            let Some(rec) = rec else {
                return Ok(());
            };
            if let Some(stream) = rec.stream() {
                recording::log_map(stream, &map)?;
            }
            rec.finish()
        },
    );
    written?;
    recorded?;
    let dest = dir.commit()?;
    drop(progress);

    let km = summary.car_lane_length_m / 1000.0;
    let minis = summary
        .roundabouts
        .iter()
        .filter(|r| r.kind == maps::model::RoundaboutKind::MiniRoundabout)
        .count();
    let rings = summary.roundabouts.len() - minis;
    ctx.ui.info(&format!(
        "map import: wrote {}: {}, {} ({km:.1} km of car lanes), {}, {}",
        dest.display(),
        plural(summary.roads, "road"),
        plural(summary.lanes, "lane"),
        plural(summary.junctions, "junction"),
        plural(rings, "roundabout"),
    ));
    if minis > 0 {
        ctx.ui
            .info(&format!("map import: {}", plural(minis, "mini-roundabout")));
    }
    for line in not_imported_lines(&summary.ring_problems) {
        ctx.ui.warn(&line);
    }
    let skipped = &summary.skipped;
    if skipped.ways_missing_nodes + skipped.degenerate_ways + skipped.invalid_nodes > 0 {
        ctx.ui.warn(&format!(
            "skipped {} with missing nodes, {}, {} with invalid coordinates (see {SUMMARY_JSON})",
            plural(skipped.ways_missing_nodes, "way"),
            plural(skipped.degenerate_ways, "degenerate way"),
            plural(skipped.invalid_nodes, "node")
        ));
    }
    Ok(())
}

/// The warnings for the tagged rings and mini-roundabout nodes left out of the roundabouts,
/// each kind counted on its own with its first reason.
fn not_imported_lines(problems: &[maps::model::RingProblem]) -> Vec<String> {
    let (nodes, rings): (Vec<_>, Vec<_>) = problems
        .iter()
        .filter(|p| !p.imported)
        .partition(|p| p.osm_node_id.is_some());
    let mut lines = Vec::new();
    if let Some(first) = rings.first() {
        lines.push(format!(
            "{} not imported as {} (first: {}; every reason in {SUMMARY_JSON}, `pipeline map info`)",
            plural(rings.len(), "tagged ring"),
            if rings.len() == 1 { "a roundabout" } else { "roundabouts" },
            first.reason
        ));
    }
    if let Some(first) = nodes.first() {
        lines.push(format!(
            "{} driven as ordinary junctions (first: {}; every reason in {SUMMARY_JSON}, `pipeline map info`)",
            plural(nodes.len(), "tagged mini-roundabout node"),
            first.reason.trim_end_matches("; driven as an ordinary junction")
        ));
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;
    use maps::model::RingProblem;

    fn problem(node: Option<i64>, reason: &str, imported: bool) -> RingProblem {
        RingProblem {
            osm_way_ids: if node.is_some() { vec![] } else { vec![7] },
            osm_node_id: node,
            reason: reason.into(),
            imported,
        }
    }

    #[test]
    fn rings_and_mini_roundabout_nodes_are_counted_apart() {
        let lines = not_imported_lines(&[
            problem(
                Some(5),
                "mini-roundabout node 5: way 9 ends within 4.0 m of it; driven as an ordinary junction",
                false,
            ),
            problem(
                Some(6),
                "mini-roundabout node 6: x; driven as an ordinary junction",
                false,
            ),
            problem(None, "ring way 7 has 3 nodes missing", false),
            problem(None, "ring way 8: lanes=abc, taken as 1", true),
        ]);
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(
            lines[0].starts_with("1 tagged ring not imported as a roundabout (first: ring way 7"),
            "{}",
            lines[0]
        );
        assert!(
            lines[1].starts_with(
                "2 tagged mini-roundabout nodes driven as ordinary junctions (first: mini-roundabout node 5: way 9 ends within 4.0 m of it;"
            ),
            "{}",
            lines[1]
        );
        assert!(not_imported_lines(&[problem(None, "x", true)]).is_empty());
    }
}
