//! `pipeline sim calibrate | realism`: the traffic world fitted to recordings of real
//! drivers at a roundabout, and compared with them metric by metric. The measuring, fitting
//! and comparing are `logs::traffic`'s; these commands read the map and the logs, call it
//! and write the calibration (TOML and JSON) or the realism report (JSON, Markdown, plots).

mod calibrate;
mod realism;

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::{Args, Subcommand};
use logs::decode::read_decoded;
use logs::project::{LogFrame, log_frames};
use logs::source::{Log, ReadOptions};
use logs::traffic::measure::{Measurements, RingGeometry, measure, share_on_lanes};
use maps::{Map, RoundaboutId};

use super::Context;
use crate::error::CliError;
use crate::log_args::{RoleArgs, log_error, objects_topic};

#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Fit the world's drivers (speeds, car following, gap acceptance, sizes, flows) to
    /// recordings of a roundabout; writes a --config file (TOML) and the fits with their
    /// intervals (JSON beside it).
    Calibrate(CalibrateArgs),
    /// Run the world on the recordings' roundabout with their own flows and compare it with
    /// them metric by metric: realism.json, realism.md and one plot per metric.
    Realism(RealismArgs),
}

/// The recordings and their map, as both commands take them.
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

#[derive(Debug, Args)]
pub struct CalibrateArgs {
    #[command(flatten)]
    pub recordings: Recordings,

    /// The calibration (TOML, for --config); its fits go to the same name with `.json`.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,

    /// Only the direct estimates: skip matching the lateral acceleration and the median
    /// critical gap by simulation.
    #[arg(long)]
    pub no_refine: bool,
}

#[derive(Debug, Args)]
pub struct RealismArgs {
    #[command(flatten)]
    pub recordings: Recordings,

    /// Output folder (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Simulated minutes at least [default: as many as the recordings hold].
    #[arg(long, value_name = "MIN")]
    pub minutes: Option<f64>,

    /// The world's traffic: `recorded` (the recordings' own flows per entry) is the only
    /// level realism compares at.
    #[arg(long, value_name = "LEVEL", default_value = "recorded")]
    pub traffic: String,
}

pub fn run(ctx: &Context<'_>, command: &SimCommand) -> Result<()> {
    match command {
        SimCommand::Calibrate(args) => calibrate::run(ctx, args),
        SimCommand::Realism(args) => realism::run(ctx, args),
    }
}

/// A recording's object frames.
fn read_frames(ctx: &Context<'_>, path: &Path) -> Result<Vec<LogFrame>> {
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

/// Share of a recording's positions that must lie on the map's lanes.
const MIN_ON_LANES: f64 = 0.5;

/// The recordings measured at their roundabout: the map, the ring's geometry and one
/// measurement per recording, each checked to lie on the map.
pub(crate) struct Measured {
    pub map: Map,
    pub geometry: RingGeometry,
    pub measured: Vec<Measurements>,
}

impl Measured {
    /// The recordings' flows on the entry lanes of their roundabout's layout.
    pub fn flows(
        &self,
        layout: &sim::roundabout::LayoutConfig,
        map_path: &Path,
    ) -> Result<Vec<sim::world::EntryFlow>> {
        logs::traffic::simulate::recorded_flows(
            &self.map,
            self.geometry.roundabout,
            layout,
            &self.geometry,
            &self.measured,
        )
        .map_err(|e| CliError::file(map_path, e, "give the map the recordings were made on").into())
    }
}

fn measure_recordings(ctx: &Context<'_>, args: &Recordings, what: &str) -> Result<Measured> {
    let mut progress = ctx.ui.progress(what);
    progress.step(&format!("reading {}", args.map.display()));
    let map = crate::inputs::load_or_import_map(&args.map)?;
    if map.roundabouts.is_empty() {
        return Err(CliError::file(
            &args.map,
            "has no roundabout",
            "give the map of the roundabout the recordings were made at",
        )
        .into());
    }
    let candidates: Vec<RoundaboutId> = match args.roundabout {
        Some(id) => {
            let id = RoundaboutId(id);
            if !map.roundabouts.contains_key(&id) {
                let ids: Vec<String> = map.roundabouts.keys().map(|r| r.0.to_string()).collect();
                return Err(CliError::file(
                    &args.map,
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
            &args.map,
            first_problem.unwrap_or_else(|| "has no roundabout to measure".into()),
            "give a map whose roundabout has yield lines",
        )
        .into());
    }
    progress.counted("measuring", args.logs.len() as u64, "recordings");
    // Per recording, per candidate roundabout.
    let mut all: Vec<Vec<Measurements>> = Vec::new();
    for path in &args.logs {
        let frames = read_frames(ctx, path)?;
        let share = share_on_lanes(&map, &frames);
        if share < MIN_ON_LANES {
            return Err(CliError::file(
                path,
                format!(
                    "its road users do not drive on the map {}: {:.0} % of their positions lie within 4 m of a lane",
                    args.map.display(),
                    share * 100.0
                ),
                "give the map the recording was made on (`logs convert --map`)",
            )
            .into());
        }
        all.push(geometries.iter().map(|g| measure(g, &frames)).collect());
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
                args.map.display()
            ),
            "give recordings of that roundabout, or choose another with --roundabout",
        )
        .into());
    }
    Ok(Measured {
        map,
        geometry: geometries.swap_remove(best),
        measured,
    })
}
