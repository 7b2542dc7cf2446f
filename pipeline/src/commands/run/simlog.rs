//! The `logs` stage: simulated traffic written as MCAP logs with standard messages, read
//! back with the log reader and projected into the bird's-eye representation again.
//!
//! Each episode of roundabout insertion (the ego driven by the 10 m gap rule, medium
//! traffic) becomes one log, `episode_<k>.mcap`: every vehicle on `/objects`
//! (vision_msgs/Detection3DArray) and `/objects/odom`, the ego on `/ego/odom` and `/ego/fix`.
//! Reading a log back, each `/objects` frame is turned into scene actors and drawn by the
//! same renderer the simulator used; `projection.json` gives how far the read-back
//! footprints lie from the simulated ones and how many bird's-eye pixels agree. Real logs
//! go through the same reader; their projection command is `logs project`.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use anyhow::{Context as _, Result};
use logs::convert::{ConvertConfig, interaction_to_mcap};
use logs::decode::read_decoded;
use logs::project::log_frames;
use logs::scenes::{SceneFrame, tracks_from_scene_frames};
use logs::source::{Log, ReadOptions};
use maps::geometry::Point;
use serde::Serialize;
use sim::baselines::{Baseline, PolicyInput};
use sim::seed::derive_seed;
use sim::tasks::Task as _;
use sim::tasks::insertion::{InsertionSetup, RoundaboutInsertion};
use sim::world::TrafficLevel;
use sim::{Env, Scene};

use super::stages::{ROUNDABOUT_MAP, StageEnv};
use crate::output::AtomicDir;
use crate::recording::{log_actors, log_layers};

/// Seed stage of the simulated drives.
const SIMULATED_LOG_STAGE: u64 = 0x4c4f_4753;
pub const PROJECTION_JSON: &str = "projection.json";
const MARKERS: crate::output::Markers = &[PROJECTION_JSON];
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

/// One simulated step: the actors and the simulator's own bird's-eye frame.
struct Recorded {
    frame: SceneFrame,
    ego: usize,
    bev: Vec<u8>,
}

pub fn record_and_project(env: &StageEnv<'_>, out: &Path) -> Result<()> {
    let seconds = env.profile.logs.seconds;
    let (map, _, _) = crate::inputs::load_map(&env.run_dir.join(ROUNDABOUT_MAP))?;
    let map = Arc::new(map);
    let setup = InsertionSetup::new(Arc::clone(&map), env.ctx.config.agent.task.clone())
        .map_err(|e| anyhow::anyhow!("{}: {e}", ROUNDABOUT_MAP))?;
    let bev = setup.config().observation.clone();
    let layer_names: Vec<&str> = bev.layers.iter().map(|l| l.name()).collect();
    let plane = bev.width * bev.height;
    let step_s = setup.config().traffic.step_s;

    let dir = AtomicDir::create(out, MARKERS)?;
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
    let mut projected = Vec::new();
    let mut k = 0u64;
    while simulated_s < seconds {
        // One episode, driven by the rule, recorded step by step.
        let episode_seed = derive_seed(env.ctx.cli.seed, SIMULATED_LOG_STAGE, k);
        let mut observation = sim.reset(episode_seed);
        let mut recorded: Vec<Recorded> = Vec::new();
        let mut ego_path: Vec<Point> = Vec::new();
        let outcome = loop {
            let Some(scene) = sim.scene() else {
                anyhow::bail!("the simulator has no scene after a reset");
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
        let path = dir.path().join(&file);
        let ego_id = recorded[0].frame.actors[recorded[0].ego].id;
        let frames: Vec<SceneFrame> = recorded.iter().map(|r| r.frame.clone()).collect();
        let tracks = tracks_from_scene_frames(&frames);
        let config = ConvertConfig {
            ego: Some(ego_id),
            source_name: "simulated roundabout insertion".into(),
            map_name: ROUNDABOUT_MAP.into(),
            ..Default::default()
        };
        let writer = std::fs::File::create(&path)
            .with_context(|| format!("{}: cannot create", path.display()))?;
        let summary = interaction_to_mcap(&tracks, &map.projection, &config, writer)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;

        // Read it back and project every frame.
        let log = Log::open(&path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let decoded = read_decoded(&log, &ReadOptions::default())
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let read_back = log_frames(&decoded, None);
        if read_back.len() != recorded.len() {
            anyhow::bail!(
                "{}: {} object frames read back, {} written",
                path.display(),
                read_back.len(),
                recorded.len()
            );
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
                projected.push((step, scene.time_s, scene.actors, scene.ego, drawn.clone()));
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
    let mut text = serde_json::to_string_pretty(&report)?;
    text.push('\n');
    std::fs::write(dir.path().join(PROJECTION_JSON), text)
        .with_context(|| format!("{}: cannot write {PROJECTION_JSON}", out.display()))?;

    // The first drive as read back from its log, in the run's recording.
    if let Some(rec) = env.recording {
        for (step, time_s, actors, ego, frame) in &projected {
            rec.set_time_sequence("step", *step as i64);
            rec.set_duration_secs("sim_time", *time_s);
            log_actors(rec, "world/episode_000/vehicles", actors, *ego)?;
            log_layers(
                rec,
                "episode_000/layers",
                frame,
                &layer_names,
                bev.width,
                bev.height,
            )?;
        }
    }
    dir.commit()?;
    Ok(())
}

/// The MCAP logs the stage wrote, in name order.
pub fn logs_in(dir: &Path) -> Result<Vec<std::path::PathBuf>> {
    let mut logs: Vec<_> = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot list", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
        .collect();
    logs.sort();
    Ok(logs)
}
