//! Simulated traffic written as MCAP logs with standard messages, read back with the log
//! reader and projected into the bird's-eye representation again: a check that a log gives
//! the policies the frames the simulator gave them (the `logs` stage of `pipeline run`).
//!
//! Each episode of roundabout insertion (the ego driven by the 10 m gap rule, medium
//! traffic) becomes one log, `episode_<k>.mcap`: every vehicle on `/objects`
//! (vision_msgs/Detection3DArray) and `/objects/odom`, the ego on `/ego/odom` and `/ego/fix`.
//! Reading a log back, each `/objects` frame is turned into scene actors and drawn by the
//! same renderer the simulator used; [`ProjectionReport`] gives how far the read-back
//! footprints lie from the simulated ones and how many bird's-eye pixels agree. Real logs
//! go through the same reader and projection (`pipeline logs project`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use maps::Map;
use maps::geometry::Point;
use serde::Serialize;
use sim::baselines::{Baseline, PolicyInput};
use sim::render::BevConfig;
use sim::seed::derive_seed;
use sim::tasks::Task as _;
use sim::tasks::insertion::{InsertionConfig, InsertionSetup, RoundaboutInsertion};
use sim::world::TrafficLevel;
use sim::{Actor, Env, Scene, SimError};

use crate::convert::{ConvertConfig, interaction_to_mcap};
use crate::decode::read_decoded;
use crate::error::LogError;
use crate::project::log_frames;
use crate::scenes::{SceneFrame, tracks_from_scene_frames};
use crate::source::{Log, ReadOptions};

/// The report the stage writes beside the logs.
pub const PROJECTION_JSON: &str = "projection.json";
/// Seed stage of the simulated drives.
const SIMULATED_LOG_STAGE: u64 = 0x4c4f_4753;
/// The ego's policy while recording.
const RECORDING_POLICY: Baseline = Baseline::Rule { threshold_m: 10.0 };

/// What `projection.json` holds.
#[derive(Debug, Serialize)]
pub struct ProjectionReport {
    pub episodes: Vec<EpisodeLog>,
    pub frames: usize,
    pub messages: u64,
    /// Largest distance between a simulated footprint centre and the one read back, m.
    pub max_position_error_m: f64,
    /// Per bird's-eye layer: the share of pixels equal in the simulator's frame and the
    /// frame drawn from the log.
    pub layer_agreement: BTreeMap<String, f64>,
}

#[derive(Debug, Serialize)]
pub struct EpisodeLog {
    pub file: String,
    pub outcome: String,
    pub frames: usize,
    pub vehicles: u64,
    pub messages: BTreeMap<String, u64>,
}

/// One frame of the first drive as read back from its log and drawn again.
#[derive(Debug)]
pub struct ProjectedFrame {
    pub step: usize,
    pub time_s: f64,
    pub actors: Vec<Actor>,
    pub ego: usize,
    /// The bird's-eye layers drawn from the log.
    pub layers: Vec<u8>,
}

/// The logs written, their report, and the first drive read back (for a recording).
#[derive(Debug)]
pub struct SimulatedLogs {
    pub report: ProjectionReport,
    pub first_drive: Vec<ProjectedFrame>,
    /// The view the frames were drawn in.
    pub bev: BevConfig,
}

/// Why simulated logs could not be written or read back.
#[derive(Debug, thiserror::Error)]
pub enum SimulatedLogError {
    /// The map does not suit the task.
    #[error("{map}: {source}")]
    Map { map: String, source: SimError },
    #[error("the simulator has no scene after a reset")]
    NoScene,
    /// A log could not be created, written or read back.
    #[error("{}: {problem}", path.display())]
    Log { path: PathBuf, problem: String },
}

fn log_problem(path: &Path, problem: impl std::fmt::Display) -> SimulatedLogError {
    SimulatedLogError::Log {
        path: path.to_path_buf(),
        problem: problem.to_string(),
    }
}

/// Drives roundabout-insertion episodes of `task` on `map` (named `map_name` in the logs)
/// until `seconds` of simulated time, seeded from `seed`; writes each as
/// `dir/episode_<k>.mcap`, reads it back and draws its frames again.
pub fn record_and_project(
    map: Arc<Map>,
    map_name: &str,
    task: InsertionConfig,
    seconds: f64,
    seed: u64,
    dir: &Path,
) -> Result<SimulatedLogs, SimulatedLogError> {
    let setup =
        InsertionSetup::new(Arc::clone(&map), task).map_err(|source| SimulatedLogError::Map {
            map: map_name.to_owned(),
            source,
        })?;
    let bev = setup.config().observation.clone();
    let layer_names: Vec<&str> = bev.layers.iter().map(|l| l.name()).collect();
    let plane = bev.width * bev.height;
    let step_s = setup.config().traffic.step_s;

    let mut sim = RoundaboutInsertion::new(setup);
    sim.set_traffic(TrafficLevel::Medium);
    sim.set_aggressiveness(Some(0.5));

    let mut report = ProjectionReport {
        episodes: Vec::new(),
        frames: 0,
        messages: 0,
        max_position_error_m: 0.0,
        layer_agreement: layer_names.iter().map(|n| ((*n).to_owned(), 0.0)).collect(),
    };
    let mut equal_pixels = vec![0u64; layer_names.len()];
    let mut simulated_s = 0.0;
    let mut first_drive = Vec::new();
    let mut k = 0u64;
    while simulated_s < seconds {
        // One episode, driven by the rule, recorded step by step.
        let episode_seed = derive_seed(seed, SIMULATED_LOG_STAGE, k);
        let mut observation = sim.reset(episode_seed);
        let mut recorded: Vec<Recorded> = Vec::new();
        let mut ego_path: Vec<Point> = Vec::new();
        let outcome = loop {
            let Some(scene) = sim.scene() else {
                return Err(SimulatedLogError::NoScene);
            };
            if ego_path.is_empty() {
                ego_path = scene.ego_path.to_vec();
            }
            recorded.push(Recorded {
                frame: SceneFrame {
                    time_s: scene.time_s,
                    actors: scene.actors.clone(),
                },
                ego: scene.ego,
                bev: sim.newest_frame().to_vec(),
            });
            let state = sim.state();
            let input = PolicyInput {
                slot: 0,
                episode_seed,
                step: recorded.len() - 1,
                observation: &observation,
                state: &state,
            };
            let step = sim.step(RECORDING_POLICY.decide(&input) as usize);
            observation = step.observation;
            if let Some(outcome) = step.outcome {
                break outcome;
            }
        };
        simulated_s += recorded.len() as f64 * step_s;

        // Write the log.
        let file = format!("episode_{k:03}.mcap");
        let path = dir.join(&file);
        let ego_id = recorded[0].frame.actors[recorded[0].ego].id;
        let frames: Vec<SceneFrame> = recorded.iter().map(|r| r.frame.clone()).collect();
        let tracks = tracks_from_scene_frames(&frames);
        let config = ConvertConfig {
            ego: Some(ego_id),
            source_name: "simulated roundabout insertion".into(),
            map_name: map_name.into(),
            ..Default::default()
        };
        let writer = std::fs::File::create(&path)
            .map_err(|e| log_problem(&path, format!("cannot create: {e}")))?;
        let summary = interaction_to_mcap(&tracks, &map.projection, &config, writer)
            .map_err(|e| log_problem(&path, e))?;

        // Read it back and project every frame.
        let read = |e: LogError| log_problem(&path, e);
        let log = Log::open(&path).map_err(read)?;
        let decoded = read_decoded(&log, &ReadOptions::default()).map_err(read)?;
        let read_back = log_frames(&decoded, None);
        if read_back.len() != recorded.len() {
            return Err(log_problem(
                &path,
                format!(
                    "{} object frames read back, {} written",
                    read_back.len(),
                    recorded.len()
                ),
            ));
        }
        let mut drawn = Vec::new();
        for (step, (original, logged)) in recorded.iter().zip(read_back).enumerate() {
            let actors = logged.actors;
            for (a, b) in original.frame.actors.iter().zip(&actors) {
                report.max_position_error_m = report
                    .max_position_error_m
                    .max(a.position.distance(b.position));
            }
            let ego = actors.iter().position(|a| a.id == ego_id).unwrap_or(0);
            let scene = Scene {
                map: &map,
                time_s: original.frame.time_s,
                actors,
                ego,
                ego_path: &ego_path,
            };
            sim.renderer().render(&scene, &mut drawn);
            for (layer, equal) in equal_pixels.iter_mut().enumerate() {
                let range = layer * plane..(layer + 1) * plane;
                *equal += drawn[range.clone()]
                    .iter()
                    .zip(&original.bev[range])
                    .filter(|(x, y)| x == y)
                    .count() as u64;
            }
            if k == 0 {
                first_drive.push(ProjectedFrame {
                    step,
                    time_s: scene.time_s,
                    actors: scene.actors,
                    ego: scene.ego,
                    layers: drawn.clone(),
                });
            }
        }
        report.frames += recorded.len();
        report.messages += summary.messages.values().sum::<u64>();
        report.episodes.push(EpisodeLog {
            file,
            outcome: format!("{outcome:?}"),
            frames: recorded.len(),
            vehicles: summary.tracks,
            messages: summary.messages,
        });
        k += 1;
    }
    let pixels = (report.frames * plane).max(1) as f64;
    for (name, equal) in layer_names.iter().zip(&equal_pixels) {
        report
            .layer_agreement
            .insert((*name).to_owned(), *equal as f64 / pixels);
    }
    Ok(SimulatedLogs {
        report,
        first_drive,
        bev,
    })
}

/// One simulated step: the actors and the simulator's own bird's-eye frame.
struct Recorded {
    frame: SceneFrame,
    ego: usize,
    bev: Vec<u8>,
}
