//! `pipeline agent train`: a DQN-family agent on one of the driving tasks.
//!
//! While training, checkpoints go to `DIR.partial/checkpoint` (each written to a temporary
//! folder and renamed into place); `--resume` continues from there after a kill. At the end
//! the agent folder `DIR` appears atomically: the final checkpoint (`online.bpk` — the
//! agent —, `target.bpk`, `optimizer.bpk`, `state.json` with the training curves,
//! `agent.json` with the config), `task.json`, `summary.json` and `recording.rrd`; then
//! `DIR.partial` is removed.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context as _, Result};

use models::policy::QPolicy;
use models::training::TrainSummary;
use models::validation::{EpisodesDone, VALIDATION_FILE, validation_seed};
use sim::env::Rotating;
use sim::tasks::{Task, TaskVisitor};
use sim::world::TrafficLevel;

use super::TrainArgs;
use super::train_inputs::{check_warmup, config_error, setups_of, training_maps};
use crate::agent_folder::{
    AGENT_MARKERS, SUMMARY_FILE, TASK_FILE, TaskRecord, find_checkpoint, models_error, partial_dir,
    start_validation,
};
use crate::agent_progress::{RunSpan, TrainProgress};
use crate::agent_recording::{log_history, record_episodes};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::{AtomicDir, write_json};

/// The training curves' picture in an agent folder.
pub const CURVES_PNG: &str = "curves.png";

pub fn train(ctx: &Context<'_>, args: &TrainArgs) -> Result<()> {
    args.task.visit(Train { ctx, args })
}

/// Trains on the task of `--task`.
struct Train<'a, 'b> {
    ctx: &'a Context<'b>,
    args: &'a TrainArgs,
}

impl TaskVisitor for Train<'_, '_> {
    type Output = Result<()>;

    fn visit<T: Task>(self) -> Result<()> {
        train_task::<T>(self.ctx, self.args)
    }
}

/// Trains an agent on task `T`.
fn train_task<T: Task>(ctx: &Context<'_>, args: &TrainArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, AGENT_MARKERS)?;
    let partial = partial_dir(&out)?;
    let mut progress = ctx.ui.progress("agent train");

    // What to train: from --config, or what the checkpoint was started with.
    let resume = if args.resume {
        progress.step("reading the checkpoint");
        Some(find_checkpoint(&out, &partial)?)
    } else {
        None
    };
    let (mut dqn, task_config, validation_config, seed) = match &resume {
        Some((checkpoint, task, file)) => {
            if task.task != args.task {
                return Err(CliError::file(
                    file,
                    format!(
                        "the checkpoint was trained on {:?}, not {:?}",
                        task.task, args.task
                    ),
                    "resume with the --task it was started with",
                )
                .into());
            }
            (
                checkpoint.config.clone(),
                task.task_config::<T>(file)?,
                task.validation,
                checkpoint.state.seed,
            )
        }
        None => (
            ctx.config.agent.dqn.clone(),
            crate::tasks::config::<T>(&ctx.config.agent),
            ctx.config.agent.validation,
            ctx.global.seed,
        ),
    };
    if resume.is_some() && seed != ctx.global.seed {
        ctx.ui.warn(&format!(
            "resuming with the checkpoint's seed {seed} (--seed {} is ignored)",
            ctx.global.seed
        ));
    }
    if let Some(steps) = args.steps {
        dqn.total_steps = steps;
    }
    dqn.validate().map_err(|e| config_error(ctx, e))?;
    let first_step = resume.as_ref().map_or(0, |(c, _, _)| c.state.steps);
    check_warmup(&dqn, first_step)?;
    if !validation_config.is_off() && dqn.checkpoint_every == 0 {
        return Err(CliError::new(
            "[agent.validation] validates every checkpoint, but checkpoint_every of [agent.dqn] is 0",
            "set checkpoint_every (e.g. 25000) or leave [agent.validation] out",
        )
        .into());
    }
    let traffic = TrafficLevel::from(args.traffic);
    let maps = training_maps(args)?;
    let first_map = maps.first().map(|m| m.path.clone());
    if traffic == TrafficLevel::Recorded {
        if maps.len() > 1 {
            return Err(CliError::new(
                "--traffic recorded runs the calibration's flows, which belong to one map",
                "train on one --map, or at low, medium or high traffic",
            )
            .into());
        }
        super::eval::require_recorded(ctx, first_map.as_deref())?;
    }

    // One setup per training map (and ring); the first also records the greedy episodes.
    if let Some(first) = &first_map {
        progress.step(&format!(
            "loading {} and {} more map(s)",
            first.display(),
            maps.len() - 1
        ));
    }
    let setups = setups_of::<T>(&maps, &task_config)?;
    let setup = Arc::clone(&setups[0]);
    let envs: Vec<Rotating<T>> = (0..dqn.envs)
        .map(|_| Rotating::new(setups.iter().map(|s| T::training_env(s, traffic)).collect()))
        .collect::<Option<_>>()
        .ok_or_else(|| {
            CliError::new(
                "the training maps give different observations or actions",
                "train on maps of one task with one --config",
            )
        })?;
    let task = TaskRecord {
        task: args.task,
        map: first_map.clone(),
        maps: if maps.len() > 1 || maps.iter().any(|m| m.roundabout.is_some()) {
            maps.clone()
        } else {
            Vec::new()
        },
        traffic,
        config: serde_json::to_value(&task_config)
            .context("the task's config cannot be written as JSON")?,
        validation: validation_config,
    };
    // Episodes of one validation (every condition on every training map).
    let mut validation_episodes = 0;
    let validation = if validation_config.is_off() {
        None
    } else {
        let validation_setups = match validation_config.action_repeat {
            Some(steps) => {
                let config = T::deciding_every(&task_config, steps).ok_or_else(|| {
                    CliError::new(
                        "[agent.validation] action_repeat is for roundabout-insertion agents",
                        "leave action_repeat out of [agent.validation]",
                    )
                })?;
                setups_of::<T>(&maps, &config)?
            }
            None => setups.clone(),
        };
        let episodes = validation_config.episodes;
        validation_episodes =
            (episodes * T::validation_conditions(traffic).len() * validation_setups.len()) as u64;
        let validation_seed = validation_seed(seed);
        // Each training map's validation episodes; the shares averaged over the maps.
        let run = Box::new(move |policy: &QPolicy, done: &EpisodesDone<'_>| {
            let mut shares: Vec<(String, f64)> = Vec::new();
            for setup in &validation_setups {
                let per = sim::eval::reached_shares::<T, _>(
                    setup,
                    policy,
                    traffic,
                    episodes,
                    validation_seed,
                    done,
                );
                if shares.is_empty() {
                    shares = per;
                } else {
                    for ((_, total), (_, share)) in shares.iter_mut().zip(per) {
                        *total += share;
                    }
                }
            }
            let n = validation_setups.len().max(1) as f64;
            shares.into_iter().map(|(name, s)| (name, s / n)).collect()
        });
        let resumed = resume.as_ref().map(|(c, _, _)| c);
        Some(start_validation(
            validation_config,
            run,
            &partial,
            &out,
            resumed,
        )?)
    };

    let dir = AtomicDir::create(&out, AGENT_MARKERS)?;
    let recording = ctx.open_recording(Some(dir.path()))?;
    if let Some(rec) = recording.stream() {
        crate::recording::log_map(rec, T::map(&setup))?;
        if let Some((checkpoint, _, _)) = &resume {
            log_history(rec, &checkpoint.state)?;
        }
    }

    let started = Instant::now();
    progress.step(&format!(
        "training for {} transitions in {} environments ({} traffic)",
        dqn.total_steps,
        dqn.envs,
        traffic.name()
    ));
    let span = RunSpan {
        first_step,
        total_steps: dqn.total_steps,
        verbose: ctx.ui.verbosity() >= crate::ui::Verbosity::Verbose,
    };
    let rec = recording.stream();
    let mut observer = TrainProgress::new(&mut progress, rec, &partial, &task, span, validation);
    observer.validation_episodes = validation_episodes;
    let result = models::dqn::train(
        &dqn,
        seed,
        envs,
        resume.map(|(c, _, _)| c),
        &ctx.device()?,
        &mut observer,
    );
    if let Some(e) = observer.error.take() {
        return Err(e);
    }
    let validation = observer.validation.take();
    let last = result.map_err(|e| models_error(e, &partial))?;
    let curves = crate::agent_recording::curves_png(&last.state)?;
    let elapsed = started.elapsed().as_secs_f64();
    let mut summary = TrainSummary::new(&last.state, first_step, elapsed);
    let checkpoint = match validation {
        Some(_) if last.state.updates == 0 => {
            // Every checkpoint is the untrained network: there is nothing to choose.
            ctx.ui.warn(&format!(
                "no gradient step in {} transitions (warmup_steps = {} of [agent.dqn]): the agent \
                 is the untrained network, not chosen by validation",
                last.state.steps, dqn.warmup_steps
            ));
            last
        }
        Some(validation) => {
            if validation.needs(&last) {
                progress.counted(
                    "validating the final network:",
                    validation_episodes,
                    "episodes",
                );
            }
            let (chosen, history) = validation.choose(last, &|n| progress.inc(n));
            if let Some(point) = history.best() {
                progress.note(&format!(
                    "the agent: the checkpoint of the best {}",
                    point.describe()
                ));
            }
            write_json(&dir.path().join(VALIDATION_FILE), &history)?;
            summary.chosen_steps = Some(chosen.state.steps);
            chosen
        }
        None => last,
    };

    progress.step("writing the agent");
    checkpoint
        .save(dir.path())
        .map_err(|e| models_error(e, dir.path()))?;
    write_json(&dir.path().join(TASK_FILE), &task)?;
    write_json(&dir.path().join(SUMMARY_FILE), &summary)?;
    crate::plots::write_png(&dir.path().join(CURVES_PNG), &curves)?;

    if let Some(rec) = recording.stream()
        && args.record_episodes > 0
    {
        progress.step("recording greedy episodes");
        let policy = QPolicy::new(
            checkpoint.online.clone(),
            checkpoint.shape.spec(),
            checkpoint.shape.actions,
            models::cpu_device(),
        );
        let condition = T::recorded_condition(traffic);
        let make_env = || T::env(&setup, &condition);
        record_episodes(rec, make_env, &policy, args.record_episodes, seed)?;
    }
    recording.finish()?;
    let dest = dir.commit()?;
    if partial.exists() {
        std::fs::remove_dir_all(&partial)
            .with_context(|| format!("{}: cannot remove", partial.display()))?;
    }
    drop(progress);
    ctx.ui.result(&summary.describe(&dest));
    Ok(())
}
