//! `pipeline logs info | convert | project | merge`: summaries of MCAP files and ROS 2
//! bags, INTERACTION track files written as MCAP logs, logs projected into the bird's-eye
//! representation, and the shards of a projection merged.

mod convert;
mod ego;
mod info;
mod merge;
mod project;

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::{Args, Subcommand};
use logs::LogError;
use logs::roles::{Role, RoleConfig, TopicRoles, assign_roles, topic_kind};

use super::Context;
use crate::error::CliError;

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

/// Topics named for roles on the command line (over `[logs.roles]` of the config); a role
/// named nowhere is detected where that is unambiguous (docs/logs.md, "Topic roles").
#[derive(Debug, Clone, Default, Args)]
pub struct RoleArgs {
    /// Topic of the ego's pose (nav_msgs/Odometry, geometry_msgs/PoseStamped or
    /// PoseWithCovarianceStamped, foxglove.PoseInFrame).
    #[arg(long, value_name = "TOPIC")]
    pub ego_topic: Option<String>,

    /// Topic of the ego's GPS fix (sensor_msgs/NavSatFix, foxglove.LocationFix).
    #[arg(long, value_name = "TOPIC")]
    pub gps_topic: Option<String>,

    /// Topic of the other road users (vision_msgs/Detection3DArray).
    #[arg(long, value_name = "TOPIC")]
    pub objects_topic: Option<String>,

    /// Topic of the camera (sensor_msgs/Image or CompressedImage, foxglove.CompressedImage).
    #[arg(long, value_name = "TOPIC")]
    pub camera_topic: Option<String>,
}

impl RoleArgs {
    /// The roles named here, else in `config`.
    pub fn over(&self, config: &RoleConfig) -> RoleConfig {
        RoleConfig {
            ego_pose: self.ego_topic.clone().or_else(|| config.ego_pose.clone()),
            gps: self.gps_topic.clone().or_else(|| config.gps.clone()),
            objects: self
                .objects_topic
                .clone()
                .or_else(|| config.objects.clone()),
            camera: self.camera_topic.clone().or_else(|| config.camera.clone()),
        }
    }
}

/// The roles of `topics` (name, type name, message encoding) in `log`: named by `config`
/// or detected; a named topic that is missing or of the wrong type is an error naming the
/// log.
pub fn topic_roles<'a>(
    log: &Path,
    topics: impl IntoIterator<Item = (&'a str, &'a str, &'a str)>,
    config: &RoleConfig,
) -> Result<TopicRoles> {
    let topics: Vec<(String, Option<logs::MessageKind>)> = topics
        .into_iter()
        .map(|(name, ty, encoding)| (name.to_owned(), topic_kind(ty, encoding)))
        .collect();
    assign_roles(&topics, config).map_err(|e| {
        CliError::file(
            log,
            e,
            "name the topic with --ego-topic / --gps-topic / --objects-topic / --camera-topic or [logs.roles] \
             (`pipeline logs info` lists the topics and their types)",
        )
        .into()
    })
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

/// A logs-library error as a one-line message naming the file, with a hint.
pub(crate) fn log_error(err: LogError) -> anyhow::Error {
    let hint = match &err {
        LogError::Io { .. } => "check that the path exists and is readable",
        LogError::Format { .. } => {
            "give an MCAP file, a ROS 2 bag folder (with metadata.yaml) or a .db3 file; \
             a truncated or corrupt file can be cut back with `mcap recover`"
        }
        LogError::Config(_) => "see `pipeline logs --help`",
    };
    CliError::new(err.to_string(), hint).into()
}

/// The topic of `decoded`'s object detections: named by `args` or `[logs.roles]`, or
/// detected; an error naming the log when there is none or several.
pub fn objects_topic(
    ctx: &Context<'_>,
    log: &Path,
    decoded: &logs::DecodedLog,
    args: &RoleArgs,
) -> Result<String> {
    let roles = topic_roles(
        log,
        decoded
            .topics
            .iter()
            .map(|t| (t.name.as_str(), t.type_name.as_str(), t.encoding.as_str())),
        &args.over(&ctx.config.logs.roles),
    )?;
    let topic = roles.require(Role::Objects).map_err(|e| {
        CliError::file(
            log,
            e,
            "name the topic with --objects-topic or [logs.roles] objects, or convert tracks with `pipeline logs convert`",
        )
    })?;
    Ok(topic.to_owned())
}
