//! `pipeline agent train --offline --log FILE...`: a roundabout-insertion agent learnt from
//! recorded drivers instead of the simulator. The drivers' approaches become transitions in
//! `judge::offline` (its docs say how: observations, actions, rewards); this command reads the
//! map and the logs, trains with `models::offline`, and writes an agent folder with the same
//! files as an online agent's, plus `offline.json`.

use std::time::{Duration, Instant};

use anyhow::Result;
use judge::offline::{LoggedEpisodes, OFFLINE_FILE, OfflineRun, ignore_unlogged_inputs};
use models::offline::{self, OfflineRecord};
use sim::tasks::insertion::Action;
use sim::world::TrafficLevel;

use super::TrainArgs;
use crate::agent_folder::{AGENT_MARKERS, TASK_FILE, Task, TaskRecord, models_error};
use crate::commands::Context;
use crate::error::CliError;
use crate::inputs::load_or_import_map;
use crate::log_args::{read_replay_log, refuse_unprojectable, replay_views, require_roundabout};
use crate::output::AtomicDir;
use crate::output::write_json;

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
    let Some(map_path) = args.map.first() else {
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
    ignore_unlogged_inputs(&mut dqn);
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
    let mut episodes = LoggedEpisodes::new(&views, task_config.reward, args.target_speed);
    for path in &args.logs {
        progress.step(&format!("reading {}", path.display()));
        let log = read_replay_log(ctx, &map, map_path, path, &labels)?;
        episodes
            .add_log(&map, &views, &log)
            .map_err(|e| models_error(e, path))?;
    }
    let LoggedEpisodes {
        set,
        approaches,
        frames,
        ..
    } = episodes;
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
        "{}: {} transitions from {approaches} approaches ({} frames); {} gradient steps",
        config.algorithm.name(),
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
        ctx.global.seed,
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
        maps: Vec::new(),
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
        "agent: {}\n  {} on {} transitions ({} approaches; actions permitted / not permitted: {} / {}), \
         {} gradient steps in {wall_seconds:.0} s\n  the greedy action is the driver's on {:.1} % of the training transitions",
        dest.display(),
        config.algorithm.name(),
        summary.transitions,
        approaches,
        summary.action_counts[Action::Permitted as usize],
        summary.action_counts[Action::NotPermitted as usize],
        summary.gradient_steps,
        100.0 * summary.train_agreement,
    ));
    Ok(())
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
