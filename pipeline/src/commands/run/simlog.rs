//! The `logs` stage: simulated traffic written as MCAP logs, read back and projected into
//! the bird's-eye representation again (`logs::simulated`), with `projection.json` and the
//! first drive as read back in the run's recording.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context as _, Result};
use logs::simulated::{PROJECTION_JSON, SimulatedLogs, record_and_project as simulate};

use super::stages::ROUNDABOUT_MAP;
use crate::output::AtomicDir;
use crate::recording::{log_actors, log_layers};

const MARKERS: crate::output::Markers = &[PROJECTION_JSON];

/// The `logs` stage: `seconds` of simulated traffic with `task`'s settings (on the run's
/// roundabout map in `run_dir`) written as MCAP logs to `out` and projected back, the first
/// drive logged to `recording`.
pub fn record_and_project(
    run_dir: &Path,
    task: sim::tasks::insertion::InsertionConfig,
    seconds: f64,
    seed: u64,
    recording: Option<&crate::recording::Stream>,
    out: &Path,
) -> Result<()> {
    let (map, _, _) = crate::inputs::load_map(&run_dir.join(ROUNDABOUT_MAP))?;
    let dir = AtomicDir::create(out, MARKERS)?;
    let SimulatedLogs {
        report,
        first_drive,
        bev,
    } = simulate(
        Arc::new(map),
        ROUNDABOUT_MAP,
        task,
        seconds,
        seed,
        dir.path(),
    )
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut text = serde_json::to_string_pretty(&report)?;
    text.push('\n');
    std::fs::write(dir.path().join(PROJECTION_JSON), text)
        .with_context(|| format!("{}: cannot write {PROJECTION_JSON}", out.display()))?;

    // The first drive as read back from its log, in the run's recording.
    if let Some(rec) = recording {
        let layer_names: Vec<&str> = bev.layers.iter().map(|l| l.name()).collect();
        for frame in &first_drive {
            rec.set_time_sequence("step", frame.step as i64);
            rec.set_duration_secs("sim_time", frame.time_s);
            log_actors(rec, "world/episode_000/vehicles", &frame.actors, frame.ego)?;
            log_layers(
                rec,
                "episode_000/layers",
                &frame.layers,
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
