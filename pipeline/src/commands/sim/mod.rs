//! `pipeline sim calibrate | realism`: the traffic world fitted to recordings of real
//! drivers at a roundabout, and compared with them metric by metric. The measuring, fitting
//! and comparing are `traffic`'s; these commands read the map and the logs, call it
//! and write the calibration (TOML and JSON) or the realism report (JSON, Markdown, plots).

mod calibrate;
mod realism;

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, Subcommand};

use super::Context;
use crate::recordings::{Measured, Recordings, measure_recordings};

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

/// The recordings of `args` measured at their roundabout.
fn read_measured(ctx: &Context<'_>, args: &Recordings, what: &str) -> Result<Measured> {
    measure_recordings(ctx, &args.map, args.roundabout, &args.logs, what)
}
