//! `pipeline agent train --offline --log FILE...`: a roundabout-insertion agent learnt from
//! recorded drivers instead of the simulator.
//!
//! Every vehicle's approach to a yield line of the map's roundabout in the logs becomes an
//! episode (`logs::decisions` labels its frames): at each frame the observation
//! the agent would have had there (the bird's-eye frames around the vehicle, its recorded
//! path, its speed; `replay eval` shows agents the same), the driver's action (go =
//! Permitted, wait or queued behind another car = Not Permitted; ambiguous frames start no
//! transition) and the task's reward for it, as far as a log tells it:
//! - per step, `reward.speed` × speed / target speed;
//! - `reward.to_not_permitted_penalty` when the driver went from go back to wait;
//! - `reward.reach` at the episode's end.
//!
//! An episode goes on past the yield line for up to [`AFTER_CROSSING_S`] of the driver's
//! frames in the ring, all go (the driver drove on): in the simulator an agent that learnt
//! only the approach met the ring's views for the first time after entering and stopped there
//! (1 to 5 % reaches, 86 to 89 % time-overs over 300 FT episodes).
//!
//! The headway and cut-in penalties, crashes and time-overs are not in the data: the drivers
//! neither crashed nor timed out. The network ignores the aggressiveness input (the drivers'
//! is unknown) and the last-action input (the driver's previous decision nearly always
//! equals the current one, so a network that reads it learns to repeat itself); the inputs
//! stay in the observation so the agent runs in the simulator and in `replay eval`
//! unchanged. The agent folder has the same files as an online agent's, plus `offline.json`.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Result;
use logs::decisions::{Approach, Decision, LabelConfig};
use logs::project::LogFrame;
use models::offline::{self, OfflineConfig, OfflineRecord, OfflineSummary, TransitionSet};
use serde::Serialize;
use sim::tasks::insertion::{AGGRESSIVENESS_SCALAR, Action, LAST_ACTION_SCALARS, RewardConfig};
use sim::world::TrafficLevel;

use super::train::{AGENT_MARKERS, models_error};
use super::{TASK_FILE, Task, TaskRecord, TrainArgs};
use crate::commands::Context;
use crate::error::CliError;
use crate::inputs::load_or_import_map;
use crate::log_args::{read_replay_log, refuse_unprojectable, replay_views, require_roundabout};
use crate::output::AtomicDir;
use crate::output::write_json;

/// The offline run's description beside the agent (`offline.json`).
pub const OFFLINE_FILE: &str = "offline.json";
/// The aggressiveness written into the inputs (the network ignores it).
const LOGGED_AGGRESSIVENESS: f64 = 0.5;
/// How long a driver's frames after the yield line stay in the episode, s.
pub const AFTER_CROSSING_S: f64 = 15.0;

#[derive(Debug, Serialize)]
struct OfflineRun<'a> {
    config: &'a OfflineConfig,
    logs: &'a [PathBuf],
    map: &'a PathBuf,
    target_speed_mps: f64,
    labels: LabelConfig,
    approaches: usize,
    /// Frames per label over the episodes (the approaches, then the ring frames, all go).
    frames: BTreeMap<String, u64>,
    summary: &'a OfflineSummary,
    wall_seconds: f64,
    gradient_steps_per_second: f64,
}

pub fn train(ctx: &Context<'_>, args: &TrainArgs) -> Result<()> {
    let hint = "offline training learns roundabout insertion from logs: \
                `agent train --offline --task roundabout-insertion --map MAP --log FILE...`";
    if args.task != Task::RoundaboutInsertion {
        return Err(CliError::new(
            format!(
                "--offline learns roundabout insertion, not {}",
                args.task.name()
            ),
            hint,
        )
        .into());
    }
    if args.resume {
        return Err(CliError::new(
            "--offline runs are not resumed (they take minutes); run again without --resume",
            hint,
        )
        .into());
    }
    let Some(map_path) = &args.map else {
        return Err(CliError::new(
            "--offline needs --map, the map the logs were recorded on",
            hint,
        )
        .into());
    };
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, AGENT_MARKERS)?;
    let mut progress = ctx.ui.progress("agent train --offline");

    let task_config = ctx.config.agent.task.clone();
    refuse_unprojectable(&task_config, "[agent.task]")?;
    let mut dqn = ctx.config.agent.dqn.clone();
    for ignored in std::iter::once(AGGRESSIVENESS_SCALAR).chain(LAST_ACTION_SCALARS) {
        if !dqn.network.ignored_scalars.contains(&ignored) {
            dqn.network.ignored_scalars.push(ignored);
        }
    }
    let mut config = ctx.config.agent.offline.clone();
    if let Some(algorithm) = args.algorithm {
        config.algorithm = algorithm.into();
    }
    if let Some(steps) = args.steps {
        config.gradient_steps = steps;
    }
    config
        .validate()
        .map_err(|e| CliError::new(format!("[agent.offline]: {e}"), "see docs/agents.md"))?;

    progress.step(&format!("reading {}", map_path.display()));
    let map = load_or_import_map(map_path)?;
    require_roundabout(&map, map_path)?;
    let views = replay_views(&map, map_path, task_config.clone(), args.target_speed)?;

    // The drivers' approaches as episodes.
    let labels = ctx.config.logs.decisions.clone();
    let mut set = TransitionSet::new(views.spec(), Action::ALL.len());
    let mut frames: BTreeMap<String, u64> = BTreeMap::new();
    let mut approaches = 0;
    for path in &args.logs {
        progress.step(&format!("reading {}", path.display()));
        let log = read_replay_log(ctx, &map, path, &labels)?;
        for approach in &log.approaches {
            let approach = &through_the_ring(approach, &log.frames);
            let inputs = views.inputs(&map, &log.frames, approach);
            let actions: Vec<Option<Action>> =
                approach.labels.iter().map(|&l| driver_action(l)).collect();
            let mut observations = Vec::with_capacity(inputs.len());
            let mut rewards = Vec::with_capacity(inputs.len());
            let mut previous = None;
            for (i, (input, action)) in inputs.into_iter().zip(&actions).enumerate() {
                let speed = input.speed_mps;
                observations.push(views.observation(input, LOGGED_AGGRESSIVENESS, previous));
                let last = i + 1 == actions.len();
                rewards.push(logged_reward(
                    &task_config.reward,
                    speed / args.target_speed,
                    previous,
                    *action,
                    last,
                ) as f32);
                previous = action.or(previous);
            }
            let indices: Vec<Option<usize>> =
                actions.iter().map(|a| a.map(|a| a as usize)).collect();
            set.push_episode(&observations, &indices, &rewards, true)
                .map_err(|e| models_error(e, path))?;
            for l in &approach.labels {
                *frames.entry(format!("{l:?}").to_lowercase()).or_default() += 1;
            }
            approaches += 1;
        }
    }
    if set.is_empty() {
        return Err(CliError::new(
            format!(
                "the logs hold no approach to a yield line of {}'s roundabout",
                map_path.display()
            ),
            "give logs recorded on this map (`pipeline replay eval` lists their approaches)",
        )
        .into());
    }

    let dir = AtomicDir::create(&out, AGENT_MARKERS)?;
    let recording = ctx.open_recording(Some(dir.path()))?;
    if let Some(rec) = recording.stream() {
        crate::recording::log_map(rec, &map)?;
    }
    progress.step(&format!(
        "{:?}: {} transitions from {approaches} approaches ({} frames); {} gradient steps",
        config.algorithm,
        set.len(),
        set.frames(),
        config.gradient_steps
    ));
    let started = Instant::now();
    let mut last_report = Instant::now();
    let mut log_error = None;
    let result = offline::train(
        &set,
        &dqn,
        &config,
        ctx.cli.seed,
        &ctx.device()?,
        &mut |record: &OfflineRecord| {
            if let Some(rec) = recording.stream()
                && let Err(e) = log_record(rec, record)
            {
                log_error.get_or_insert(e);
            }
            if last_report.elapsed() >= Duration::from_secs(10) {
                last_report = Instant::now();
                progress.step(&format!(
                    "step {} / {}: loss {:.4}, penalty {:.4}, mean Q {:.3}; {:.0} steps/s",
                    record.updates,
                    config.gradient_steps,
                    record.loss,
                    record.regulariser,
                    record.mean_q,
                    record.updates as f64 / started.elapsed().as_secs_f64().max(1e-9)
                ));
            }
            log_error.is_none()
        },
    );
    if let Some(e) = log_error {
        return Err(e);
    }
    let (checkpoint, summary) = result.map_err(|e| models_error(e, &out))?;
    let wall_seconds = started.elapsed().as_secs_f64();

    progress.step("writing the agent");
    checkpoint
        .save(dir.path())
        .map_err(|e| models_error(e, dir.path()))?;
    let task = TaskRecord {
        task: Task::RoundaboutInsertion,
        map: Some(map_path.clone()),
        traffic: TrafficLevel::Medium,
        config: serde_json::to_value(&task_config)?,
        validation: Default::default(),
    };
    write_json(&dir.path().join(TASK_FILE), &task)?;
    write_json(
        &dir.path().join(OFFLINE_FILE),
        &OfflineRun {
            config: &config,
            logs: &args.logs,
            map: map_path,
            target_speed_mps: args.target_speed,
            labels,
            approaches,
            frames,
            summary: &summary,
            wall_seconds,
            gradient_steps_per_second: summary.gradient_steps as f64 / wall_seconds.max(1e-9),
        },
    )?;
    recording.finish()?;
    let dest = dir.commit()?;
    drop(progress);
    ctx.ui.result(&format!(
        "agent: {}\n  {:?} on {} transitions ({} approaches; actions permitted / not permitted: {} / {}), \
         {} gradient steps in {wall_seconds:.0} s\n  the greedy action is the driver's on {:.1} % of the training transitions",
        dest.display(),
        config.algorithm,
        summary.transitions,
        approaches,
        summary.action_counts[Action::Permitted as usize],
        summary.action_counts[Action::NotPermitted as usize],
        summary.gradient_steps,
        100.0 * summary.train_agreement,
    ));
    Ok(())
}

/// `approach` and the driver's frames after the yield line (up to [`AFTER_CROSSING_S`], while
/// the track is seen), labelled go.
fn through_the_ring(approach: &Approach, frames: &[LogFrame]) -> Approach {
    let mut episode = approach.clone();
    let Some(crossing) = frames.get(approach.crossed_at) else {
        return episode;
    };
    let limit_ns = (AFTER_CROSSING_S * 1e9) as u64;
    for (k, frame) in frames.iter().enumerate().skip(approach.crossed_at) {
        let seen = frame.actors.iter().any(|a| a.id == approach.track);
        if !seen || frame.time_ns.saturating_sub(crossing.time_ns) > limit_ns {
            break;
        }
        episode.frames.push(k);
        episode.labels.push(Decision::Go);
    }
    episode
}

/// The driver's action at a frame labelled `label`: go is Permitted; waiting for a gap or
/// behind another car is Not Permitted; an ambiguous frame's is unknown.
fn driver_action(label: Decision) -> Option<Action> {
    match label {
        Decision::Go => Some(Action::Permitted),
        Decision::Wait | Decision::Queued => Some(Action::NotPermitted),
        Decision::Ambiguous => None,
    }
}

/// The insertion task's reward for a logged step, from the terms a log tells (module docs).
fn logged_reward(
    reward: &RewardConfig,
    speed_over_target: f64,
    previous: Option<Action>,
    action: Option<Action>,
    last: bool,
) -> f64 {
    let mut r = reward.speed * speed_over_target;
    if previous == Some(Action::Permitted) && action == Some(Action::NotPermitted) {
        r -= reward.to_not_permitted_penalty;
    }
    if last {
        r += reward.reach;
    }
    r
}

fn log_record(rec: &crate::recording::Stream, record: &OfflineRecord) -> Result<()> {
    rec.set_time_sequence("update", record.updates as i64);
    let mut scalars = vec![
        ("agent/offline/loss", record.loss),
        ("agent/offline/penalty", record.regulariser),
        ("agent/offline/mean_q", record.mean_q),
    ];
    if let Some(td) = record.td_loss {
        scalars.push(("agent/offline/td_loss", td));
    }
    crate::recording::log_scalars(rec, &scalars)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logged_rewards_pay_speed_punish_going_back_to_wait_and_pay_the_crossing() {
        let r = RewardConfig::default();
        let plain = logged_reward(&r, 0.5, None, Some(Action::Permitted), false);
        assert!((plain - 0.5 * r.speed).abs() < 1e-12);
        let back = logged_reward(
            &r,
            0.5,
            Some(Action::Permitted),
            Some(Action::NotPermitted),
            false,
        );
        assert!((back - (plain - r.to_not_permitted_penalty)).abs() < 1e-12);
        let crossing = logged_reward(&r, 0.5, None, Some(Action::Permitted), true);
        assert!((crossing - (plain + r.reach)).abs() < 1e-12);
        assert_eq!(driver_action(Decision::Queued), Some(Action::NotPermitted));
        assert_eq!(driver_action(Decision::Ambiguous), None);
    }
}
