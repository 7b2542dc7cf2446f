//! Recordings of a roundabout read and measured, as the commands that fit to them or judge
//! policies on them take them (`sim calibrate | realism`, `replay gaps`).

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use logs::decode::read_decoded;
use logs::project::{LogFrame, log_frames};
use logs::source::{Log, ReadOptions};
use maps::{Map, RoundaboutId};
use traffic::measure::{Measurements, RingGeometry, measure};

use crate::commands::Context;
use crate::error::CliError;
use crate::log_args::{RoleArgs, check_on_map, log_error, objects_topic};

/// The recordings of a roundabout and their map, as the commands that measure them take them.
#[derive(Debug, Args)]
pub struct Recordings {
    /// A recording (MCAP from `logs convert`, or any log with object detections); repeat
    /// for several.
    #[arg(long = "log", value_name = "FILE", required = true)]
    pub logs: Vec<PathBuf>,

    /// The map the recordings were made on (a Lanelet2 / OSM file or an imported map).
    #[arg(long, value_name = "PATH")]
    pub map: PathBuf,

    /// The roundabout of the map (its id, as `map info` lists them) [default: the one the
    /// recorded vehicles enter most].
    #[arg(long, value_name = "ID")]
    pub roundabout: Option<u32>,
}

/// A recording's object frames.
pub fn read_frames(ctx: &Context<'_>, path: &Path) -> Result<Vec<LogFrame>> {
    let log = Log::open(path).map_err(log_error)?;
    let decoded = read_decoded(&log, &ReadOptions::default()).map_err(log_error)?;
    let topic = objects_topic(ctx, path, &decoded, &RoleArgs::default())?;
    let frames = log_frames(&decoded, Some(&topic));
    if frames.is_empty() {
        return Err(CliError::file(
            path,
            format!("has no object frames on {topic}"),
            "give a recording with road users (`pipeline logs convert` writes them)",
        )
        .into());
    }
    Ok(frames)
}

/// The recordings measured at their roundabout: the map, the ring's geometry and one
/// measurement per recording, each checked to lie on the map.
#[derive(Debug)]
pub struct Measured {
    pub map: Map,
    pub geometry: RingGeometry,
    pub measured: Vec<Measurements>,
    /// Each recording's frames, in the order given.
    pub frames: Vec<Vec<LogFrame>>,
}

impl Measured {
    /// The recordings' flows on the entry lanes of their roundabout's layout.
    pub fn flows(
        &self,
        layout: &sim::roundabout::LayoutConfig,
        map_path: &Path,
    ) -> Result<Vec<sim::world::EntryFlow>> {
        traffic::simulate::recorded_flows(
            &self.map,
            self.geometry.roundabout,
            layout,
            &self.geometry,
            &self.measured,
        )
        .map_err(|e| CliError::file(map_path, e, "give the map the recordings were made on").into())
    }
}

/// Reads and measures the recordings `logs` of roundabout `roundabout` of the map at
/// `map_path` (without it, the ring they enter most); each must lie on the map.
pub fn measure_recordings(
    ctx: &Context<'_>,
    map_path: &Path,
    roundabout: Option<u32>,
    logs: &[PathBuf],
    what: &str,
) -> Result<Measured> {
    let mut progress = ctx.ui.progress(what);
    progress.step(&format!("reading {}", map_path.display()));
    let map = crate::inputs::load_or_import_map(map_path)?;
    if map.roundabouts.is_empty() {
        return Err(CliError::file(
            map_path,
            "has no roundabout",
            "give the map of the roundabout the recordings were made at",
        )
        .into());
    }
    let candidates: Vec<RoundaboutId> = match roundabout {
        Some(id) => {
            let id = RoundaboutId(id);
            if !map.roundabouts.contains_key(&id) {
                let ids: Vec<String> = map.roundabouts.keys().map(|r| r.0.to_string()).collect();
                return Err(CliError::file(
                    map_path,
                    format!(
                        "has no roundabout {} (its roundabouts: {})",
                        id.0,
                        ids.join(", ")
                    ),
                    "see `pipeline map info` for the ids",
                )
                .into());
            }
            vec![id]
        }
        None => map.roundabouts.keys().copied().collect(),
    };
    // Without --roundabout, rings that cannot be measured (no yield line) are left out; the
    // error names the first problem when none can.
    let found: Vec<Result<RingGeometry, String>> = candidates
        .iter()
        .map(|&id| RingGeometry::new(&map, id))
        .collect();
    let first_problem = found.iter().find_map(|g| g.as_ref().err().cloned());
    let mut geometries: Vec<RingGeometry> = found.into_iter().filter_map(Result::ok).collect();
    if geometries.is_empty() {
        return Err(CliError::file(
            map_path,
            first_problem.unwrap_or_else(|| "has no roundabout to measure".into()),
            "give a map whose roundabout has yield lines",
        )
        .into());
    }
    progress.counted("measuring", logs.len() as u64, "recordings");
    // Per recording, per candidate roundabout.
    let mut all: Vec<Vec<Measurements>> = Vec::new();
    let mut kept = Vec::new();
    for path in logs {
        let frames = read_frames(ctx, path)?;
        check_on_map(
            path,
            &map,
            map_path,
            logs::on_map::vehicle_positions(&frames),
        )?;
        all.push(geometries.iter().map(|g| measure(g, &frames)).collect());
        kept.push(frames);
        progress.inc(1);
    }
    let best = (0..geometries.len())
        .max_by_key(|&g| all.iter().map(|per| per[g].entering.len()).sum::<usize>())
        .unwrap_or(0);
    let measured: Vec<Measurements> = all
        .into_iter()
        .map(|mut per| per.swap_remove(best))
        .collect();
    if measured.iter().all(|m| m.entering.is_empty()) {
        return Err(CliError::new(
            format!(
                "no recorded vehicle enters roundabout {} of {}",
                geometries[best].roundabout.0,
                map_path.display()
            ),
            "give recordings of that roundabout, or choose another with --roundabout",
        )
        .into());
    }
    Ok(Measured {
        map,
        geometry: geometries.swap_remove(best),
        measured,
        frames: kept,
    })
}
