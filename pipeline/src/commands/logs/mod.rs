//! `pipeline logs info | convert | project | merge`: summaries of MCAP files and ROS 2
//! bags, INTERACTION track files written as MCAP logs, logs projected into the bird's-eye
//! representation, and the shards of a projection merged.

mod convert;
mod ego;
mod info;
mod merge;
mod project;

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, Subcommand};

use super::Context;
use crate::log_args::RoleArgs;

#[derive(Debug, Subcommand)]
pub enum LogsCommand {
    /// Summarise a log (MCAP file, ROS 2 bag folder, metadata.yaml or .db3): files, storage,
    /// compression, time span, and per topic the type, count, rate and decoder.
    Info(InfoArgs),
    /// Convert an INTERACTION track file (with its Lanelet2 map) into an MCAP log: every
    /// vehicle a detection, one of them the ego's odometry.
    Convert(ConvertArgs),
    /// Draw a log's object frames in the bird's-eye representation around one vehicle
    /// (the same layers the simulator draws), as a frame dataset.
    Project(project::ProjectArgs),
    /// Put the frame folders of one `logs project --shard i/n` run back together (the
    /// unsharded run's folder, byte for byte).
    Merge(merge::MergeArgs),
    /// The ego's track from the ego-pose or GPS topic in a map's frame, resampled to a
    /// fixed rate and matched to the map's lanes, as JSON.
    Ego(ego::EgoArgs),
}

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// The log: an .mcap file, a bag folder, its metadata.yaml, or a .db3 file.
    pub log: PathBuf,

    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,

    #[command(flatten)]
    pub roles: RoleArgs,
}

#[derive(Debug, Args)]
pub struct ConvertArgs {
    /// INTERACTION track file (`vehicle_tracks_NNN.csv`, or `.csv.gz`).
    pub tracks: PathBuf,

    /// The scenario's Lanelet2 map (`.osm`): its projection defines the map frame.
    #[arg(long, value_name = "FILE")]
    pub map: PathBuf,

    /// The output MCAP file (written atomically).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,

    /// Track id of the vehicle that is the ego (also written as nav_msgs/Odometry and a
    /// GPS fix).
    #[arg(long, value_name = "TRACK_ID")]
    pub ego: Option<u32>,

    /// Chunk compression.
    #[arg(long, value_enum, default_value = "zstd")]
    pub compression: CompressionArg,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum CompressionArg {
    Zstd,
    Lz4,
    None,
}

pub fn run(ctx: &Context<'_>, command: &LogsCommand) -> Result<()> {
    match command {
        LogsCommand::Info(args) => info::run(ctx, args),
        LogsCommand::Convert(args) => convert::run(ctx, args),
        LogsCommand::Project(args) => project::run(ctx, args),
        LogsCommand::Merge(args) => merge::run(ctx, args),
        LogsCommand::Ego(args) => ego::run(ctx, args),
    }
}
