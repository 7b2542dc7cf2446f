//! What the commands that read logs share (`logs`, `replay`, `agent train --offline`): the
//! topic-role arguments, the topics they pick, the logs library's errors as one-line CLI
//! errors, and a log read into replay frames.

use std::path::Path;

use anyhow::Result;
use clap::Args;
use judge::ReplayLog;
use logs::decode::read_decoded;
use logs::project::log_frames;
use logs::roles::{Role, RoleConfig, TopicRoles, assign_roles, topic_kind};
use logs::source::{Log, ReadOptions};
use logs::{DecodedLog, LogError, MessageKind};
use traffic::decisions::LabelConfig;

use crate::commands::Context;
use crate::error::CliError;

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
    let topics: Vec<(String, Option<MessageKind>)> = topics
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

/// A logs-library error as a one-line message naming the file, with a hint.
pub fn log_error(err: LogError) -> anyhow::Error {
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

/// A logs-library error from writing an output file, as a one-line message naming it.
pub fn write_error(err: LogError) -> anyhow::Error {
    match err {
        LogError::Io { path, source } => CliError::file(
            &path,
            format!("cannot write: {source}"),
            "check free disk space and permissions",
        )
        .into(),
        err => log_error(err),
    }
}

/// The topic of `decoded`'s object detections: named by `args` or `[logs.roles]`, or
/// detected; an error naming the log when there is none or several.
pub fn objects_topic(
    ctx: &Context<'_>,
    log: &Path,
    decoded: &DecodedLog,
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

/// The one check of every command that reads a recording with a map: the recording's
/// vehicles (`positions`) must drive on the map's lanes ([`logs::on_map`]); otherwise an
/// error naming the recording and the map, before anything is measured or written.
pub fn check_on_map(
    log: &Path,
    map: &maps::Map,
    map_path: &Path,
    positions: impl IntoIterator<Item = maps::geometry::Point>,
) -> Result<()> {
    let Err(off) = logs::on_map::check_on_map(map, positions) else {
        return Ok(());
    };
    Err(CliError::file(
        log,
        format!(
            "its road users do not drive on the map {}: {off}",
            map_path.display()
        ),
        "give the map the recording was made on (for INTERACTION: maps/<scenario>.osm for \
         recorded_trackfiles/<scenario>/)",
    )
    .into())
}

/// Reads a log's object frames (the objects topic of `[logs.roles]`, or the one detected),
/// checks that they were recorded on `map` (read from `map_path`) and finds their approaches
/// to its yield lines.
pub fn read_replay_log(
    ctx: &Context<'_>,
    map: &maps::Map,
    map_path: &Path,
    path: &Path,
    labels: &LabelConfig,
) -> Result<ReplayLog> {
    let name = path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let log = Log::open(path).map_err(log_error)?;
    let decoded = read_decoded(&log, &ReadOptions::default()).map_err(log_error)?;
    let objects = objects_topic(ctx, path, &decoded, &RoleArgs::default())?;
    let frames = log_frames(&decoded, Some(&objects));
    check_on_map(
        path,
        map,
        map_path,
        logs::on_map::vehicle_positions(&frames),
    )?;
    Ok(ReplayLog::new(name, frames, map, labels))
}

/// The views of `task` over `map` (read from `map_path`), or one error naming the map.
pub fn replay_views(
    map: &maps::Map,
    map_path: &Path,
    task: sim::tasks::insertion::InsertionConfig,
    target_speed_mps: f64,
) -> Result<judge::Views> {
    judge::Views::new(map, task, target_speed_mps).map_err(|e| {
        CliError::file(
            map_path,
            e.to_string(),
            "give the map the logs were recorded on",
        )
        .into()
    })
}

/// A task the logs cannot give decisions for (`action_repeat` above 1), refused: `whose`
/// says where the task came from.
pub fn refuse_unprojectable(
    config: &sim::tasks::insertion::InsertionConfig,
    whose: &str,
) -> Result<()> {
    judge::check_projectable(config).map_err(|e| {
        CliError::new(
            format!("{whose} {e}"),
            "use a task with action_repeat = 1 (the default) for logs; frame_steps spaces the \
             stacked frames",
        )
        .into()
    })
}

/// `map_path`'s map, which must have a roundabout (replay and offline learning judge and
/// learn roundabout entries).
pub fn require_roundabout(map: &maps::Map, map_path: &Path) -> Result<()> {
    if map.roundabouts.is_empty() {
        return Err(CliError::file(
            map_path,
            "has no roundabout",
            "give the roundabout's map the logs were recorded on",
        )
        .into());
    }
    Ok(())
}

/// The agent of folder `dir` as the replay commands run it, with the task config it was
/// trained on: asked at every log frame (an agent that decided every few steps keeps its
/// frames as far apart as in training; `note` is told); an error when its view cannot be
/// drawn from logs.
pub fn load_replay_agent(
    dir: &Path,
    device: &burn::tensor::Device,
    note: &mut dyn FnMut(&str),
) -> Result<(
    models::policy::QPolicy,
    sim::tasks::insertion::InsertionConfig,
)> {
    use crate::agent_folder::{TASK_FILE, models_error, read_task};
    let description = models::dqn::read_agent_description(dir).map_err(|e| models_error(e, dir))?;
    let mut config = read_task(dir)?.insertion_config(&dir.join(TASK_FILE))?;
    if config.action_repeat > 1 {
        // Logs give a frame, so a decision, every world step: an agent trained deciding
        // every few steps is asked at every frame, on frames stacked as far apart as in
        // training (as `agent eval --action-repeat 1` does).
        note(&format!(
            "the agent decided every {} steps in training; it is asked at every log frame, its frames {} steps apart",
            config.action_repeat,
            config.frame_steps.unwrap_or(config.action_repeat)
        ));
        config = config.deciding_every(1);
    }
    refuse_unprojectable(&config, &format!("the agent in {}", dir.display()))?;
    let network =
        models::dqn::load_network(dir, &description, device).map_err(|e| models_error(e, dir))?;
    let policy = models::policy::QPolicy::new(
        network,
        description.shape.spec(),
        description.shape.actions,
        device.clone(),
    );
    Ok((policy, config))
}
