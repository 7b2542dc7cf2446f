//! `pipeline replay eval`: policies judged against what real drivers did at roundabout
//! entries (open loop).
//!
//! Each log (objects as vision_msgs/Detection3DArray, e.g. INTERACTION tracks through
//! `logs convert`) is read; every vehicle's approach to a yield line of the map's
//! roundabouts is labelled go / wait / ambiguous frame by frame from what its driver did
//! (`logs::decisions`). At each labelled frame every policy decides from what
//! the driver could see then: the rules from the distance to the nearest vehicle on the
//! ring, the agent from the bird's-eye frames around the vehicle (its own recorded path,
//! four frames stacked) and its scalars. Caution counts as wait, as in the Parma study.
//! Agreement is over the go and wait frames; ambiguous and queued frames are counted, not
//! scored.
//!
//! With `--shard i/n` only shard `i`'s share of the approaches (numbered over the logs in
//! the order given) is evaluated, and the folder holds `replay_shard.json`: the settings
//! and the counts (frames, confusion matrices, matches per log, go delays in approach
//! order), which `pipeline replay merge --shards` adds up into the unsharded run's
//! `replay.json` and `replay.md`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::{Args, Subcommand};
use datasets::shard::{Shard, in_order};
use logs::closed_loop::{
    ClosedLoopConfig, ClosedLoopEpisode, ClosedLoopOutcome, ClosedLoopView, Command, drive,
};
use logs::decisions::{Approach, Decision, LabelConfig, approaches};
use logs::decode::read_decoded;
use logs::noise::NoiseConfig;
use logs::project::{LogFrame, log_frames, project};
use logs::source::{Log, ReadOptions};
use models::bc::{self, BcConfig};
use models::dqn::{greedy_action, load_network, read_agent_description};
use models::policy::QPolicy;
use serde::{Deserialize, Serialize};
use sim::render::{BevConfig, BevRenderer, FrameStack};
use sim::tasks::insertion::{
    Action, InsertionConfig, MotionHistory, RULE_SCALARS, observation_scalars, rule_scalars_of,
};
use sim::{Observation, ObservationSpec};

use super::Context;
use super::logs::{RoleArgs, log_error, objects_topic};
use crate::agent_folder::{TASK_FILE, models_error, read_task};
use crate::error::CliError;
use crate::inputs::load_or_import_map;
use crate::output::write_json;
use crate::output::{AtomicDir, Markers, write_file_atomic};

pub const REPLAY_JSON: &str = "replay.json";
pub const REPLAY_MD: &str = "replay.md";
/// A shard's counts (`replay eval --shard i/n`).
pub const REPLAY_SHARD_JSON: &str = "replay_shard.json";
const MARKERS: Markers = &[REPLAY_JSON, REPLAY_SHARD_JSON];
/// Vehicles this close to the ring's centre line (in distance from the roundabout's
/// centre) count as circulating, m.
const RING_HALF_WIDTH_M: f64 = 4.0;

#[derive(Debug, Subcommand)]
pub enum ReplayCommand {
    /// Agreement of policies (an agent, the gap rules, always go) with real drivers' go /
    /// wait decisions at roundabout entries, frame by frame.
    Eval(EvalArgs),
    /// Add up the shards of one `replay eval --shard i/n` run into its replay.json and
    /// replay.md (the unsharded run's, byte for byte).
    Merge(MergeArgs),
}

#[derive(Debug, Args)]
pub struct MergeArgs {
    /// The shard folders of one `replay eval --shard i/n` run, each of 0..n once (any
    /// order).
    #[arg(long, value_name = "DIR", num_args = 1.., required = true)]
    pub shards: Vec<PathBuf>,

    /// Output folder: replay.json and replay.md (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Logs to replay (MCAP from `logs convert`, or any log with object detections).
    #[arg(long = "log", value_name = "FILE", required = true)]
    pub logs: Vec<PathBuf>,

    /// The map the logs were recorded on (a Lanelet2 .osm, or a map folder).
    #[arg(long, value_name = "MAP|OSM")]
    pub map: PathBuf,

    /// An agent folder from `agent train` [default: only the baselines].
    #[arg(long, value_name = "DIR")]
    pub agent: Option<PathBuf>,

    /// The agent's aggressiveness input, one evaluation per level.
    #[arg(long, value_name = "A,B,...", value_delimiter = ',', default_values_t = [0.0, 0.5, 1.0], allow_hyphen_values = true)]
    pub aggressiveness: Vec<f64>,

    /// The target speed the agent is told (the simulator gives the route's speed), m/s.
    #[arg(long, value_name = "MPS", default_value_t = 8.0)]
    pub target_speed: f64,

    /// Logs to train a behaviour-cloning classifier of go / wait on (the same inputs as
    /// the agent), evaluated beside the other policies; use other recordings than --log.
    #[arg(long = "train-log", value_name = "FILE")]
    pub train_logs: Vec<PathBuf>,

    /// Behaviour cloning learns from every N-th go or wait frame of an approach.
    #[arg(long, value_name = "N", default_value_t = 2)]
    pub bc_stride: usize,

    /// Output folder: replay.json and replay.md (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Evaluate only shard i of n of the approaches (for running across machines); the
    /// folder gets replay_shard.json, which `pipeline replay merge --shards` adds up
    /// (docs/scaling.md). Each shard trains behaviour cloning itself (the same network).
    #[arg(long, value_name = "i/n", value_parser = Shard::parse)]
    pub shard: Option<Shard>,

    /// Also closed loop: each policy drives each approach's vehicle along its driver's path
    /// while the other road users replay the log (reaches, crashes, time-overs, log
    /// divergence).
    #[arg(long)]
    pub closed_loop: bool,
}

pub fn run(ctx: &Context<'_>, command: &ReplayCommand) -> Result<()> {
    match command {
        ReplayCommand::Eval(args) => eval(ctx, args),
        ReplayCommand::Merge(args) => merge(ctx, args),
    }
}

/// What one policy did in closed loop, as counts and per-episode figures (in approach
/// order, so that shards put one after the other give the unsharded means to the bit).
#[derive(Debug, Default, Clone, PartialEq, Serialize, Deserialize)]
struct LoopTally {
    policy: String,
    episodes: u64,
    reached: u64,
    crashed: u64,
    /// Hit from behind by a replayed road user (which cannot react).
    rear_ended: u64,
    time_over: u64,
    /// Per episode: the mean distance to the driver's position, m.
    divergences_m: Vec<f64>,
    /// Per episode that entered: its crossing of the yield line minus its driver's, s.
    entry_delays_s: Vec<f64>,
}

impl LoopTally {
    fn new(policy: String) -> LoopTally {
        LoopTally {
            policy,
            ..Default::default()
        }
    }

    fn add(&mut self, episode: &ClosedLoopEpisode) {
        self.episodes += 1;
        match episode.outcome {
            ClosedLoopOutcome::Reached => self.reached += 1,
            ClosedLoopOutcome::Crashed => self.crashed += 1,
            ClosedLoopOutcome::RearEnded => self.rear_ended += 1,
            ClosedLoopOutcome::TimeOver => self.time_over += 1,
        }
        self.divergences_m.push(episode.log_divergence_m);
        self.entry_delays_s.extend(episode.entry_delay_s);
    }

    fn absorb(&mut self, other: &LoopTally) {
        self.episodes += other.episodes;
        self.reached += other.reached;
        self.crashed += other.crashed;
        self.rear_ended += other.rear_ended;
        self.time_over += other.time_over;
        self.divergences_m.extend_from_slice(&other.divergences_m);
        self.entry_delays_s.extend_from_slice(&other.entry_delays_s);
    }

    fn score(&self) -> LoopScore {
        let n = self.episodes.max(1) as f64;
        let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        LoopScore {
            policy: self.policy.clone(),
            episodes: self.episodes,
            reached: self.reached as f64 / n,
            crashed: self.crashed as f64 / n,
            rear_ended: self.rear_ended as f64 / n,
            time_over: self.time_over as f64 / n,
            mean_log_divergence_m: mean(&self.divergences_m).unwrap_or(0.0),
            mean_entry_delay_s: mean(&self.entry_delays_s),
        }
    }
}

/// How one policy did in closed loop.
#[derive(Debug, Clone, Serialize)]
struct LoopScore {
    policy: String,
    episodes: u64,
    reached: f64,
    crashed: f64,
    rear_ended: f64,
    time_over: f64,
    /// Mean over episodes of the mean distance to the driver's position at the same time, m.
    mean_log_divergence_m: f64,
    /// Mean over episodes that entered of the entry time minus the driver's, s.
    mean_entry_delay_s: Option<f64>,
}

/// What one policy did, as counts that shards add up.
#[derive(Debug, Default, Clone, PartialEq, Serialize, Deserialize)]
struct Tally {
    policy: String,
    /// `confusion[human][policy]`, human and policy each `go` or `wait`.
    confusion: BTreeMap<String, BTreeMap<String, u64>>,
    /// Per log: (frames where the policy decided as the driver did, go and wait frames).
    matches_per_log: BTreeMap<String, (u64, u64)>,
    /// Per approach with a stop (in approach order): the policy's first go minus the
    /// driver's, s.
    delays: Vec<f64>,
}

impl Tally {
    fn new(policy: String) -> Tally {
        Tally {
            policy,
            ..Default::default()
        }
    }

    fn add(&mut self, log: &str, human: Decision, go: bool) {
        let h = match human {
            Decision::Go => "go",
            Decision::Wait => "wait",
            Decision::Ambiguous | Decision::Queued => return,
        };
        let p = if go { "go" } else { "wait" };
        *self
            .confusion
            .entry(h.into())
            .or_default()
            .entry(p.into())
            .or_default() += 1;
        let e = self.matches_per_log.entry(log.into()).or_default();
        e.0 += u64::from(h == p);
        e.1 += 1;
    }

    /// Adds a later shard's counts (its delays after these).
    fn absorb(&mut self, other: &Tally) {
        for (h, row) in &other.confusion {
            for (p, n) in row {
                *self
                    .confusion
                    .entry(h.clone())
                    .or_default()
                    .entry(p.clone())
                    .or_default() += n;
            }
        }
        for (log, (m, n)) in &other.matches_per_log {
            let e = self.matches_per_log.entry(log.clone()).or_default();
            e.0 += m;
            e.1 += n;
        }
        self.delays.extend_from_slice(&other.delays);
    }

    /// The rates.
    fn score(self) -> Score {
        let (m, n) = self
            .matches_per_log
            .values()
            .fold((0, 0), |(a, b), (m, n)| (a + m, b + n));
        Score {
            policy: self.policy,
            agreement: m as f64 / n.max(1) as f64,
            confusion: self.confusion,
            per_log: self
                .matches_per_log
                .iter()
                .map(|(k, (m, n))| (k.clone(), *m as f64 / (*n).max(1) as f64))
                .collect(),
            mean_go_delay_s: (!self.delays.is_empty())
                .then(|| self.delays.iter().sum::<f64>() / self.delays.len() as f64),
        }
    }
}

/// How one policy did.
#[derive(Debug, Default, Clone, Serialize)]
struct Score {
    policy: String,
    /// Of the go and wait frames, the share where the policy decided as the driver did.
    agreement: f64,
    /// `confusion[human][policy]`, human and policy each `go` or `wait`.
    confusion: BTreeMap<String, BTreeMap<String, u64>>,
    /// Per log: agreement.
    per_log: BTreeMap<String, f64>,
    /// Over approaches where the driver stopped: the policy's first go minus the driver's
    /// (first go-labelled frame), s; positive = the policy went later.
    mean_go_delay_s: Option<f64>,
}

/// What a run evaluated, the same in every shard of it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Settings {
    logs: Vec<PathBuf>,
    map: PathBuf,
    agent: Option<PathBuf>,
    /// Logs behaviour cloning learnt from.
    train_logs: Vec<PathBuf>,
    labels: LabelConfig,
    behaviour_cloning: Option<bc::BcSummary>,
}

/// The counts of a run or of a shard of it.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Counts {
    approaches: usize,
    approaches_with_a_stop: usize,
    frames: BTreeMap<String, u64>,
    policies: Vec<Tally>,
    /// With --closed-loop.
    #[serde(default)]
    closed_loop: Vec<LoopTally>,
}

impl Counts {
    /// Adds a later shard's counts; the policies must be the same.
    fn absorb(&mut self, other: &Counts) -> std::result::Result<(), String> {
        let names = |c: &Counts| {
            c.policies
                .iter()
                .map(|t| t.policy.clone())
                .collect::<Vec<_>>()
        };
        if names(self) != names(other) {
            return Err(format!(
                "other policies ({:?}) than shard 0 ({:?})",
                names(other),
                names(self)
            ));
        }
        self.approaches += other.approaches;
        self.approaches_with_a_stop += other.approaches_with_a_stop;
        for (k, n) in &other.frames {
            *self.frames.entry(k.clone()).or_default() += n;
        }
        for (mine, theirs) in self.policies.iter_mut().zip(&other.policies) {
            mine.absorb(theirs);
        }
        if self.closed_loop.len() != other.closed_loop.len() {
            return Err("another closed-loop setting".into());
        }
        for (mine, theirs) in self.closed_loop.iter_mut().zip(&other.closed_loop) {
            mine.absorb(theirs);
        }
        Ok(())
    }
}

/// `replay_shard.json`.
#[derive(Debug, Serialize, Deserialize)]
struct ShardFile {
    shard: Shard,
    settings: Settings,
    counts: Counts,
}

#[derive(Debug, Serialize)]
struct Report {
    logs: Vec<PathBuf>,
    map: PathBuf,
    agent: Option<PathBuf>,
    /// Logs behaviour cloning learnt from.
    train_logs: Vec<PathBuf>,
    labels: LabelConfig,
    behaviour_cloning: Option<bc::BcSummary>,
    approaches: usize,
    approaches_with_a_stop: usize,
    frames: BTreeMap<String, u64>,
    policies: Vec<Score>,
    /// With --closed-loop.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    closed_loop: Vec<LoopScore>,
}

impl Report {
    fn new(settings: Settings, counts: Counts) -> Report {
        Report {
            logs: settings.logs,
            map: settings.map,
            agent: settings.agent,
            train_logs: settings.train_logs,
            labels: settings.labels,
            behaviour_cloning: settings.behaviour_cloning,
            approaches: counts.approaches,
            approaches_with_a_stop: counts.approaches_with_a_stop,
            frames: counts.frames,
            policies: counts.policies.into_iter().map(Tally::score).collect(),
            closed_loop: counts.closed_loop.iter().map(LoopTally::score).collect(),
        }
    }
}

/// What the policies that read the bird's-eye view (the agent, behaviour cloning) see;
/// offline training (`agent train --offline`) learns from the same.
pub(crate) struct Views {
    /// The task the policies were trained on: its view, frame spacing and scalar inputs.
    task: InsertionConfig,
    renderer: BevRenderer,
    /// The route's nominal speed the policies are told (before the ego's style scales it).
    target_speed_mps: f64,
}

impl Views {
    /// The views of `task`'s observation over `map` (read from `map_path`), their stacked
    /// frames `task.frame_spacing()` log frames apart, with the route's nominal speed
    /// `target_speed_mps` in the scalars.
    pub(crate) fn new(
        map: &maps::Map,
        map_path: &Path,
        task: InsertionConfig,
        target_speed_mps: f64,
    ) -> Result<Views> {
        let renderer =
            BevRenderer::new(map, map.bounds(), task.observation.clone()).map_err(|e| {
                CliError::file(
                    map_path,
                    e.to_string(),
                    "give the map the logs were recorded on",
                )
            })?;
        Ok(Views {
            task,
            renderer,
            target_speed_mps,
        })
    }

    /// Per frame of the approach: what a policy sees there ([`FrameInput`]): the layer
    /// stack (oldest first, `frame_spacing` log frames apart, the first frame repeated at the
    /// start), the vehicle's speed and, as the task asks, its rule and motion inputs.
    pub(crate) fn inputs(
        &self,
        map: &maps::Map,
        frames: &[LogFrame],
        approach: &Approach,
    ) -> Vec<FrameInput> {
        let (projected, layers) = project(
            map,
            &self.renderer,
            frames,
            approach.track,
            &NoiseConfig::default(),
        );
        let frame_len = self.task.observation.frame_len();
        let stacks = stacks_at(
            projected
                .iter()
                .zip(layers.chunks_exact(frame_len))
                .map(|(figures, frame)| (figures.log_frame, frame)),
            frame_len,
            self.task.observation.stack,
            self.task.frame_spacing(),
            &approach.frames,
        );
        // The driven distance along the track from each projected frame to the frame where
        // its centre crossed the yield line (negative after it), for the rule inputs.
        let mut arc = Vec::with_capacity(projected.len());
        let mut length = 0.0;
        for (j, f) in projected.iter().enumerate() {
            if let Some(prev) = j.checked_sub(1).map(|i| &projected[i]) {
                length += (f.x - prev.x).hypot(f.y - prev.y);
            }
            arc.push(length);
        }
        let crossing_arc = projected
            .iter()
            .position(|f| f.log_frame >= approach.crossed_at)
            .map_or(length, |j| arc[j]);
        // The episode (and its motion history) begins at the approach's first frame.
        let mut motion = self
            .task
            .motion_inputs
            .then(|| MotionHistory::new(self.task.traffic.step_s));
        let first = approach.frames.first().copied().unwrap_or(usize::MAX);
        let mut wanted = stacks.into_iter().peekable();
        let mut out = Vec::with_capacity(approach.frames.len());
        for (j, f) in projected.iter().enumerate() {
            if f.log_frame < first {
                continue;
            }
            if let Some(history) = &mut motion {
                history.push(f.speed_mps);
            }
            let Some((_, layers)) = wanted.next_if(|(at, _)| *at == j) else {
                continue;
            };
            let mut extra = Vec::new();
            if self.task.rule_inputs {
                let frame = &frames[f.log_frame];
                let length_m = frame
                    .actors
                    .iter()
                    .find(|a| a.id == approach.track)
                    .map_or(0.0, |a| a.length_m);
                extra.extend(log_rule_scalars(
                    map,
                    frame,
                    approach.track,
                    crossing_arc - arc[j],
                    length_m,
                ));
            }
            if let Some(history) = &motion {
                extra.extend(history.scalars(self.task.speed_scale_mps));
            }
            out.push(FrameInput {
                layers,
                speed_mps: f.speed_mps,
                extra,
            });
        }
        out
    }

    /// The task's observation of `input`, the target speed that of an ego of
    /// `aggressiveness` in the task, `last` the last action (None: all zero).
    pub(crate) fn observation(
        &self,
        input: FrameInput,
        aggressiveness: f64,
        last: Option<Action>,
    ) -> Observation {
        let mut scalars = observation_scalars(
            input.speed_mps,
            self.target_speed_mps * self.task.ego_speed_factor(aggressiveness),
            self.task.speed_scale_mps,
            aggressiveness,
            last,
        );
        scalars.extend_from_slice(&input.extra);
        Observation {
            layers: input.layers,
            scalars,
        }
    }

    pub(crate) fn spec(&self) -> ObservationSpec {
        self.task
            .observation
            .observation_spec(self.task.scalar_count())
    }

    /// A closed-loop policy's [`FrameInput`]s, frame after frame of one episode (a new one
    /// for each episode: the motion history starts empty).
    pub(crate) fn closed_loop_inputs(&self) -> ClosedLoopInputs<'_> {
        ClosedLoopInputs {
            views: self,
            motion: self
                .task
                .motion_inputs
                .then(|| MotionHistory::new(self.task.traffic.step_s)),
        }
    }
}

/// The rule inputs of `track` in `frame` ([`rule_scalars_of`]): the nearest vehicle on the
/// ring, and its front's distance to the yield line from its centre's distance along its
/// path to where the driver's centre crossed it (`centre_to_crossing_m`, negative past it).
fn log_rule_scalars(
    map: &maps::Map,
    frame: &LogFrame,
    track: u32,
    centre_to_crossing_m: f64,
    length_m: f64,
) -> [f32; RULE_SCALARS] {
    let front_to_line = centre_to_crossing_m - length_m / 2.0;
    rule_scalars_of(
        nearest_circulating(map, frame, track),
        front_to_line,
        front_to_line < 0.0,
    )
}

/// What a policy sees at one log frame: the bird's-eye layer stack, the vehicle's speed,
/// and the scalar inputs the task adds after the standard ones (rule inputs, motion inputs).
#[derive(Clone)]
pub(crate) struct FrameInput {
    pub(crate) layers: Vec<u8>,
    pub(crate) speed_mps: f64,
    pub(crate) extra: Vec<f32>,
}

/// [`FrameInput`]s of a vehicle driven closed loop: its motion history goes on from view
/// to view.
pub(crate) struct ClosedLoopInputs<'a> {
    views: &'a Views,
    motion: Option<MotionHistory>,
}

impl ClosedLoopInputs<'_> {
    /// The input at `view` (the episode's views in order, the first one first).
    pub(crate) fn at(
        &mut self,
        map: &maps::Map,
        track: u32,
        view: &ClosedLoopView<'_>,
    ) -> FrameInput {
        let task = &self.views.task;
        let mut extra = Vec::new();
        if task.rule_inputs {
            extra.extend(log_rule_scalars(
                map,
                view.frame,
                track,
                view.to_crossing_m,
                view.frame.actors[view.ego].length_m,
            ));
        }
        if let Some(history) = &mut self.motion {
            history.push(view.speed_mps);
            extra.extend(history.scalars(task.speed_scale_mps));
        }
        FrameInput {
            layers: view.layers.to_vec(),
            speed_mps: view.speed_mps,
            extra,
        }
    }
}

/// The layer stacks at the `wanted` log frames (in time order), with each one's position in
/// `frames`, when every frame of `frames` (log frame, layers; in time order) goes through a
/// [`FrameStack`] of `stack` frames `spacing` frames apart, as the simulator stacks the frames
/// it draws. The first frame fills the stack.
fn stacks_at<'a>(
    frames: impl IntoIterator<Item = (usize, &'a [u8])>,
    frame_len: usize,
    stack: usize,
    spacing: usize,
    wanted: &[usize],
) -> Vec<(usize, Vec<u8>)> {
    let mut frame_stack = FrameStack::spaced(frame_len, stack, spacing);
    let mut wanted = wanted.iter().peekable();
    let mut out = Vec::with_capacity(wanted.len());
    for (j, (log_frame, frame)) in frames.into_iter().enumerate() {
        if j == 0 {
            frame_stack.reset(frame);
        } else {
            frame_stack.push(frame);
        }
        if wanted.peek() == Some(&&log_frame) {
            wanted.next();
            let mut layers = Vec::new();
            frame_stack.write(&mut layers);
            out.push((j, layers));
        }
    }
    out
}

/// Projected logs give the bird's-eye layers, the speed, the rule inputs and the motion
/// inputs of every log frame (one frame per world step), not decisions every several steps
/// ([`InsertionConfig::action_repeat`]): one clear error for a task that asks for that.
/// Frames stacked several steps apart ([`InsertionConfig::frame_steps`]) are stacked that
/// many log frames apart.
pub(crate) fn refuse_unprojectable(config: &InsertionConfig, whose: &str) -> Result<()> {
    if config.action_repeat != 1 {
        return Err(CliError::new(
            format!(
                "{whose} has `action_repeat = {}`: it decides every {} steps, and projected logs \
                 give a decision every step",
                config.action_repeat, config.action_repeat
            ),
            "use a task with action_repeat = 1 (the default) for logs; frame_steps spaces the \
             stacked frames",
        )
        .into());
    }
    Ok(())
}

/// A log read into frames, with its approaches.
pub(crate) struct ReplayLog {
    pub(crate) name: String,
    pub(crate) frames: Vec<LogFrame>,
    pub(crate) approaches: Vec<Approach>,
}

/// Reads a log's object frames (the objects topic of `[logs.roles]`, or the one detected)
/// and finds its approaches.
pub(crate) fn read_log(
    ctx: &Context<'_>,
    map: &maps::Map,
    path: &std::path::Path,
    labels: &LabelConfig,
) -> Result<ReplayLog> {
    let name = path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let log = Log::open(path).map_err(log_error)?;
    let decoded = read_decoded(&log, &ReadOptions::default()).map_err(log_error)?;
    let objects = objects_topic(ctx, path, &decoded, &RoleArgs::default())?;
    let frames: Vec<LogFrame> = log_frames(&decoded, Some(&objects));
    let approaches = approaches(map, &frames, labels);
    Ok(ReplayLog {
        name,
        frames,
        approaches,
    })
}

/// Aggressiveness given to behaviour cloning (the drivers' own is unknown). It gets no last
/// action: in training that would be the driver's previous decision, which nearly always
/// equals the current one, so the classifier would learn to repeat it and, fed its own
/// decisions, never change its mind.
const BC_AGGRESSIVENESS: f64 = 0.5;

fn eval(ctx: &Context<'_>, args: &EvalArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    let mut progress = ctx.ui.progress("replay eval");
    progress.step(&format!("reading {}", args.map.display()));
    let map = load_or_import_map(&args.map)?;
    if map.roundabouts.is_empty() {
        return Err(CliError::file(
            &args.map,
            "has no roundabout",
            "give the roundabout's map the logs were recorded on",
        )
        .into());
    }
    let device = models::cpu_device();
    // The agent, and the view it was trained on (behaviour cloning sees the same).
    let (agent, task) = match &args.agent {
        None => (
            None,
            InsertionConfig {
                observation: BevConfig {
                    width: 42,
                    height: 42,
                    stack: 2,
                    ..BevConfig::default()
                },
                ..InsertionConfig::default()
            },
        ),
        Some(dir) => {
            progress.step(&format!("loading the agent {}", dir.display()));
            let description = read_agent_description(dir).map_err(|e| models_error(e, dir))?;
            let config = read_task(dir)?.insertion_config(&dir.join(TASK_FILE))?;
            refuse_unprojectable(&config, &format!("the agent in {}", dir.display()))?;
            let network =
                load_network(dir, &description, &device).map_err(|e| models_error(e, dir))?;
            let policy = QPolicy::new(
                network,
                description.shape.spec(),
                description.shape.actions,
                device.clone(),
            );
            (Some(policy), config)
        }
    };
    let views = Views::new(&map, &args.map, task, args.target_speed)?;
    let labels = ctx.config.logs.decisions.clone();

    // Behaviour cloning on the training logs' go and wait frames.
    let bc = if args.train_logs.is_empty() {
        None
    } else {
        let mut observations = Vec::new();
        let mut go = Vec::new();
        for path in &args.train_logs {
            progress.step(&format!("behaviour cloning: reading {}", path.display()));
            let log = read_log(ctx, &map, path, &labels)?;
            for approach in &log.approaches {
                let inputs = views.inputs(&map, &log.frames, approach);
                for (i, (input, label)) in inputs.into_iter().zip(&approach.labels).enumerate() {
                    let decision = match label {
                        Decision::Go => true,
                        Decision::Wait => false,
                        Decision::Ambiguous | Decision::Queued => continue,
                    };
                    if i % args.bc_stride.max(1) == 0 {
                        observations.push(views.observation(input, BC_AGGRESSIVENESS, None));
                        go.push(decision);
                    }
                }
            }
        }
        progress.step(&format!(
            "behaviour cloning: training on {} frames",
            observations.len()
        ));
        let config = BcConfig::default();
        let (network, summary) = bc::train(
            &observations,
            &go,
            &views.spec(),
            &config,
            ctx.cli.seed,
            &device,
        )
        .map_err(|e| {
            CliError::new(
                format!("behaviour cloning: {e}"),
                "give --train-log logs with approaches to the map's roundabout",
            )
        })?;
        Some((network, summary))
    };

    // The rules, then always go (no threshold), then the learnt policies.
    let thresholds = [Some(25.0), Some(20.0), Some(15.0), Some(10.0), None];
    let mut scores: Vec<Tally> = thresholds
        .iter()
        .map(|t| Tally::new(t.map_or("always go".into(), |t| format!("rule {t} m"))))
        .collect();
    let bc_score = bc.as_ref().map(|_| {
        scores.push(Tally::new("behaviour cloning".into()));
        scores.len() - 1
    });
    let levels = if agent.is_some() {
        args.aggressiveness.clone()
    } else {
        Vec::new()
    };
    let first_agent_score = scores.len();
    scores.extend(
        levels
            .iter()
            .map(|a| Tally::new(format!("agent, aggressiveness {a}"))),
    );
    // Closed loop: the same policies, Caution as itself.
    let mut loops: Vec<LoopTally> = if args.closed_loop {
        scores
            .iter()
            .map(|t| LoopTally::new(t.policy.clone()))
            .collect()
    } else {
        Vec::new()
    };
    let loop_config = ClosedLoopConfig {
        target_speed_mps: args.target_speed,
        ..ClosedLoopConfig::default()
    };
    let mut frame_counts: BTreeMap<String, u64> = BTreeMap::new();
    let (mut n_approaches, mut n_stopped) = (0, 0);

    // Every log first: a shard's approaches are numbered over all of them.
    let mut logs = Vec::with_capacity(args.logs.len());
    for path in &args.logs {
        progress.step(&format!("reading {}", path.display()));
        let log = read_log(ctx, &map, path, &labels)?;
        progress.step(&format!(
            "{}: {} approaches",
            log.name,
            log.approaches.len()
        ));
        logs.push(log);
    }
    let total: u64 = logs.iter().map(|l| l.approaches.len() as u64).sum();
    let part = args.shard.map_or(0..total, |s| s.range(total));
    let numbered = logs
        .iter()
        .flat_map(|log| log.approaches.iter().map(move |a| (log, a)))
        .zip(0u64..);
    for ((log, approach), _) in numbered.filter(|(_, index)| part.contains(index)) {
        n_approaches += 1;
        n_stopped += usize::from(approach.stopped);
        for l in &approach.labels {
            *frame_counts
                .entry(format!("{l:?}").to_lowercase())
                .or_default() += 1;
        }
        let nearest: Vec<f64> = approach
            .frames
            .iter()
            .map(|&k| nearest_circulating(&map, &log.frames[k], approach.track))
            .collect();
        for (score, threshold) in scores.iter_mut().zip(thresholds) {
            let goes: Vec<bool> = nearest
                .iter()
                .map(|near| threshold.is_none_or(|t| *near > t))
                .collect();
            score_approach(score, &log.name, approach, &log.frames, &goes);
        }
        if args.closed_loop {
            closed_loop(
                &map,
                &views,
                log,
                approach,
                &loop_config,
                &thresholds,
                bc.as_ref().map(|(network, _)| network),
                agent.as_ref(),
                &levels,
                &device,
                &mut loops,
            );
        }
        if bc.is_none() && agent.is_none() {
            continue;
        }
        let inputs = views.inputs(&map, &log.frames, approach);
        // Behaviour cloning, on each frame as it is.
        if let (Some((network, _)), Some(i)) = (&bc, bc_score) {
            let observations: Vec<Observation> = inputs
                .iter()
                .map(|input| views.observation(input.clone(), BC_AGGRESSIVENESS, None))
                .collect();
            let goes = bc::predict(network, &observations, &views.spec(), &device);
            score_approach(&mut scores[i], &log.name, approach, &log.frames, &goes);
        }
        // The agent, once per aggressiveness level.
        if let Some(policy) = &agent {
            for (level, score) in levels.iter().zip(&mut scores[first_agent_score..]) {
                let mut last = Action::Permitted;
                let mut goes = Vec::new();
                for input in &inputs {
                    let observation = views.observation(input.clone(), *level, Some(last));
                    let q = policy.q_values(&[&observation]);
                    last = Action::from_index(greedy_action(&q)).unwrap_or(Action::NotPermitted);
                    goes.push(last == Action::Permitted);
                }
                score_approach(score, &log.name, approach, &log.frames, &goes);
            }
        }
    }
    let settings = Settings {
        logs: args.logs.clone(),
        train_logs: args.train_logs.clone(),
        map: args.map.clone(),
        agent: args.agent.clone(),
        labels,
        behaviour_cloning: bc.map(|(_, summary)| summary),
    };
    let counts = Counts {
        approaches: n_approaches,
        approaches_with_a_stop: n_stopped,
        frames: frame_counts,
        policies: scores,
        closed_loop: loops,
    };
    drop(progress);
    match args.shard {
        None => write_report(ctx, &out, &Report::new(settings, counts)),
        Some(shard) => {
            let dir = AtomicDir::create(&out, MARKERS)?;
            write_json(
                &dir.path().join(REPLAY_SHARD_JSON),
                &ShardFile {
                    shard,
                    settings,
                    counts,
                },
            )?;
            let dest = dir.commit()?;
            ctx.ui.result(&format!(
                "shard {}/{}: approaches {}..{} of {total}; wrote {}",
                shard.index,
                shard.count,
                part.start,
                part.end,
                dest.display()
            ));
            Ok(())
        }
    }
}

/// Writes replay.json, replay.md and the recording (the table) into `out`, atomically.
fn write_report(ctx: &Context<'_>, out: &Path, report: &Report) -> Result<()> {
    let md = markdown(report);
    let dir = AtomicDir::create(out, MARKERS)?;
    write_json(&dir.path().join(REPLAY_JSON), report)?;
    write_file_atomic(&dir.path().join(REPLAY_MD), md.as_bytes())?;
    let recording = ctx.open_recording(Some(dir.path()))?;
    if let Some(rec) = recording.stream() {
        rec.log_static(
            "replay/table",
            &rerun::TextDocument::from_markdown(md.clone()),
        )
        .map_err(|e| {
            CliError::new(
                format!("rerun: cannot log the table: {e}"),
                "use --rerun off",
            )
        })?;
    }
    recording.finish()?;
    let dest = dir.commit()?;
    ctx.ui.result(&md);
    ctx.ui.info(&format!("wrote {}", dest.display()));
    Ok(())
}

/// `replay merge --shards`: the shards' counts added up, in shard order.
fn merge(ctx: &Context<'_>, args: &MergeArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    let hint = "give the shard folders of one `pipeline replay eval --shard i/n` run";
    let mut found = Vec::with_capacity(args.shards.len());
    for dir in &args.shards {
        let path = dir.join(REPLAY_SHARD_JSON);
        let text = std::fs::read_to_string(&path)
            .map_err(|e| CliError::file(&path, format!("cannot read: {e}"), hint))?;
        let file: ShardFile = serde_json::from_str(&text)
            .map_err(|e| CliError::file(&path, format!("not a replay shard: {e}"), hint))?;
        found.push((file.shard, (path, file)));
    }
    let ordered = in_order(found).map_err(|e| CliError::new(e.to_string(), hint))?;
    let mut ordered = ordered.into_iter();
    let Some((_, (_, first))) = ordered.next() else {
        return Err(CliError::new("no shard given", hint).into());
    };
    let (settings, mut counts) = (first.settings, first.counts);
    for (shard, (path, file)) in ordered {
        let differs = |what: String| {
            CliError::file(
                &path,
                format!(
                    "shard {}/{} was made with {what} than shard 0",
                    shard.index, shard.count
                ),
                hint,
            )
        };
        if file.settings != settings {
            return Err(
                differs("other settings (logs, map, agent or behaviour cloning)".into()).into(),
            );
        }
        counts.absorb(&file.counts).map_err(differs)?;
    }
    write_report(ctx, &out, &Report::new(settings, counts))
}

/// Drives `approach` closed loop with every policy (in the order of `loops`: the rules and
/// always go, behaviour cloning, the agent per level) and adds the episodes up.
#[allow(clippy::too_many_arguments)]
fn closed_loop(
    map: &maps::Map,
    views: &Views,
    log: &ReplayLog,
    approach: &Approach,
    config: &ClosedLoopConfig,
    thresholds: &[Option<f64>],
    bc: Option<&models::qnet::QNetwork>,
    agent: Option<&QPolicy>,
    levels: &[f64],
    device: &burn::tensor::Device,
    loops: &mut [LoopTally],
) {
    let mut tallies = loops.iter_mut();
    let mut run = |policy: &mut dyn FnMut(&ClosedLoopView<'_>) -> Command| {
        if let (Some(tally), Some(episode)) = (
            tallies.next(),
            drive(map, &views.renderer, &log.frames, approach, config, policy),
        ) {
            tally.add(&episode);
        }
    };
    for threshold in thresholds {
        run(&mut |view: &ClosedLoopView<'_>| {
            let near = nearest_circulating(map, view.frame, approach.track);
            if threshold.is_none_or(|t| near > t) {
                Command::Go
            } else {
                Command::Wait
            }
        });
    }
    if let Some(network) = bc {
        let mut inputs = views.closed_loop_inputs();
        run(&mut |view: &ClosedLoopView<'_>| {
            let input = inputs.at(map, approach.track, view);
            let observation = views.observation(input, BC_AGGRESSIVENESS, None);
            let go = bc::predict(network, &[observation], &views.spec(), device);
            if go.first() == Some(&true) {
                Command::Go
            } else {
                Command::Wait
            }
        });
    }
    if let Some(policy) = agent {
        for &level in levels {
            let mut last = Action::Permitted;
            let mut inputs = views.closed_loop_inputs();
            run(&mut |view: &ClosedLoopView<'_>| {
                let input = inputs.at(map, approach.track, view);
                let observation = views.observation(input, level, Some(last));
                let q = policy.q_values(&[&observation]);
                last = Action::from_index(greedy_action(&q)).unwrap_or(Action::NotPermitted);
                match last {
                    Action::Permitted => Command::Go,
                    Action::NotPermitted => Command::Wait,
                    Action::Caution => Command::Caution,
                }
            });
        }
    }
}

/// Scores one approach's decisions (`goes[i]` at the approach's i-th frame).
fn score_approach(
    score: &mut Tally,
    log: &str,
    approach: &Approach,
    frames: &[LogFrame],
    goes: &[bool],
) {
    for (label, go) in approach.labels.iter().zip(goes) {
        score.add(log, *label, *go);
    }
    if approach.stopped {
        let time = |i: usize| frames[approach.frames[i]].time_ns as f64 * 1e-9;
        let human = approach.labels.iter().position(|l| *l == Decision::Go);
        let policy = goes.iter().position(|g| *g);
        if let (Some(h), Some(p)) = (human, policy) {
            score.delays.push(time(p) - time(h));
        }
    }
}

/// Distance from `track` to the nearest other vehicle on a roundabout's ring, m.
fn nearest_circulating(map: &maps::Map, frame: &LogFrame, track: u32) -> f64 {
    let Some(me) = frame.actors.iter().find(|a| a.id == track) else {
        return f64::INFINITY;
    };
    frame
        .actors
        .iter()
        .filter(|a| a.id != track)
        .filter(|a| {
            map.roundabouts
                .values()
                .any(|r| (a.position.distance(r.centre) - r.radius_m).abs() <= RING_HALF_WIDTH_M)
        })
        .map(|a| a.position.distance(me.position))
        .fold(f64::INFINITY, f64::min)
}

fn markdown(r: &Report) -> String {
    let mut md = open_loop_markdown(r);
    if !r.closed_loop.is_empty() {
        let _ = writeln!(
            md,
            "\n## Closed loop\n\nEach policy drives every approach's vehicle along its driver's path from the approach's start; the other road users replay the log and cannot react (*rear-ended*: hit from behind by one of them). Divergence: mean distance to the driver's position at the same time.\n\n| policy | episodes | reached | crashed | rear-ended | time over | log divergence m | entry delay s |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
        );
        for l in &r.closed_loop {
            let _ = writeln!(
                md,
                "| {} | {} | {:.1} % | {:.1} % | {:.1} % | {:.1} % | {:.2} | {} |",
                l.policy,
                l.episodes,
                100.0 * l.reached,
                100.0 * l.crashed,
                100.0 * l.rear_ended,
                100.0 * l.time_over,
                l.mean_log_divergence_m,
                l.mean_entry_delay_s
                    .map_or("-".into(), |d| format!("{d:+.2}"))
            );
        }
    }
    md
}

/// The open-loop part of replay.md.
fn open_loop_markdown(r: &Report) -> String {
    let mut md = String::new();
    let go = r.frames.get("go").copied().unwrap_or(0);
    let wait = r.frames.get("wait").copied().unwrap_or(0);
    let amb = r.frames.get("ambiguous").copied().unwrap_or(0);
    let queued = r.frames.get("queued").copied().unwrap_or(0);
    let _ = writeln!(
        md,
        "# Replay against human decisions\n\n{} logs, {} approaches to a yield line ({} with a stop); frames labelled go {go}, wait {wait}; not scored: ambiguous {amb}, queued behind another vehicle {queued}.\n",
        r.logs.len(),
        r.approaches,
        r.approaches_with_a_stop
    );
    let _ = writeln!(
        md,
        "| policy | agreement | human go: policy go / wait | human wait: policy go / wait | mean go delay s |\n| --- | ---: | ---: | ---: | ---: |"
    );
    for s in &r.policies {
        let cell = |h: &str| {
            let c = s.confusion.get(h);
            let n = |p: &str| c.and_then(|c| c.get(p)).copied().unwrap_or(0);
            format!("{} / {}", n("go"), n("wait"))
        };
        let _ = writeln!(
            md,
            "| {} | {:.1} % | {} | {} | {} |",
            s.policy,
            100.0 * s.agreement,
            cell("go"),
            cell("wait"),
            s.mean_go_delay_s.map_or("-".into(), |d| format!("{d:+.2}"))
        );
    }
    md
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// Log frames 10 to 19, each one byte long holding its own number; the stacks of frames
    /// 12, 13 and 18.
    fn stacks_of(stack: usize, spacing: usize) -> Vec<(usize, Vec<u8>)> {
        let frames: Vec<(usize, [u8; 1])> = (10..20).map(|n| (n, [n as u8])).collect();
        stacks_at(
            frames.iter().map(|(n, bytes)| (*n, &bytes[..])),
            1,
            stack,
            spacing,
            &[12, 13, 18],
        )
    }

    /// The rule and motion inputs of a real recording (FT 000, when `../shared/data` is
    /// there): along every approach the distance from the front to the yield line falls, to
    /// minus half the car's length (within a step) at the last frame before its centre
    /// crosses; it reads as entered exactly when its front is past the line; and the motion
    /// inputs are the speeds of the frames 0.5, 1 and 2 s before and the slowest so far.
    #[test]
    fn logs_give_the_rule_and_motion_inputs_along_each_approach() {
        use logs::convert::{ConvertConfig, interaction_to_mcap};
        use logs::interaction::read_track_file;
        use sim::tasks::insertion::RULE_INPUT_RANGE_M;
        let data = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/trajectories/interaction");
        if !data.is_dir() {
            #[allow(clippy::print_stdout)] // the skip notice the project's data tests print
            {
                println!("skipped: ../shared/data is absent");
            }
            return;
        }
        let map_path = data.join("maps/DR_USA_Roundabout_FT.osm");
        let map = maps::import_file(&map_path, &maps::ImportOptions::default()).unwrap();
        let tracks = read_track_file(
            &data.join("recorded_trackfiles/DR_USA_Roundabout_FT/vehicle_tracks_000.csv.gz"),
        )
        .unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let log_path = tmp.path().join("ft_000.mcap");
        let file = std::fs::File::create(&log_path).unwrap();
        interaction_to_mcap(&tracks, &map.projection, &ConvertConfig::default(), file).unwrap();
        let log = Log::open(&log_path).unwrap();
        let decoded = read_decoded(&log, &ReadOptions::default()).unwrap();
        let frames = log_frames(&decoded, None);
        let task = InsertionConfig {
            rule_inputs: true,
            motion_inputs: true,
            ..InsertionConfig::default()
        };
        let scale = task.speed_scale_mps as f32;
        let views = Views::new(&map, &map_path, task, 8.0).unwrap();
        let found = approaches(&map, &frames, &LabelConfig::default());
        assert!(found.len() > 50, "{} approaches", found.len());
        for approach in found.iter().take(40) {
            let inputs = views.inputs(&map, &frames, approach);
            assert_eq!(inputs.len(), approach.frames.len());
            let to_line: Vec<f32> = inputs
                .iter()
                .map(|i| i.extra[1] * RULE_INPUT_RANGE_M as f32)
                .collect();
            for w in to_line.windows(2) {
                assert!(w[1] <= w[0] + 1e-4, "track {}: {to_line:?}", approach.track);
            }
            let last = *to_line.last().unwrap();
            let step = approach.speeds.last().unwrap() * 0.1 + 0.5;
            let half_length = frames[approach.crossed_at]
                .actors
                .iter()
                .find(|a| a.id == approach.track)
                .unwrap()
                .length_m
                / 2.0;
            assert!(
                (f64::from(last) + half_length).abs() <= step,
                "track {}: front {last} m from the line at the last frame, half length {half_length}",
                approach.track
            );
            for (k, input) in inputs.iter().enumerate() {
                assert_eq!(input.extra.len(), RULE_SCALARS + 4);
                assert_eq!(input.extra[2] == 1.0, to_line[k] < 0.0);
                let speed = |back: usize| (inputs[k.saturating_sub(back)].speed_mps as f32) / scale;
                let motion = &input.extra[RULE_SCALARS..];
                for (got, want) in motion.iter().zip([speed(5), speed(10), speed(20)]) {
                    assert!(
                        (got - want).abs() < 1e-6,
                        "track {} frame {k}",
                        approach.track
                    );
                }
                let slowest = inputs[..=k]
                    .iter()
                    .map(|i| i.speed_mps as f32 / scale)
                    .fold(f32::INFINITY, f32::min);
                assert!((motion[3] - slowest).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn log_stacks_hold_the_frames_spacing_apart_oldest_first() {
        // Consecutive frames, as before frame_steps reached the logs.
        assert_eq!(
            stacks_of(2, 1),
            vec![(2, vec![11, 12]), (3, vec![12, 13]), (8, vec![17, 18])]
        );
        // Three frames three apart: the first frame fills the stack until it is old enough.
        assert_eq!(
            stacks_of(3, 3),
            vec![
                (2, vec![10, 10, 12]),
                (3, vec![10, 10, 13]),
                (8, vec![12, 15, 18])
            ]
        );
    }
}
