//! `pipeline agent train`: a DQN-family agent on one of the driving tasks.
//!
//! While training, checkpoints go to `DIR.partial/checkpoint` (each written to a temporary
//! folder and renamed into place); `--resume` continues from there after a kill. At the end
//! the agent folder `DIR` appears atomically: the final checkpoint (`online.bpk` — the
//! agent —, `target.bpk`, `optimizer.bpk`, `state.json` with the training curves,
//! `agent.json` with the config), `task.json`, `summary.json` and `recording.rrd`; then
//! `DIR.partial` is removed.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::recording::Stream;
use anyhow::{Context as _, Result};
use models::ModelError;
use models::dqn::{
    AGENT_FILE, Checkpoint, EpisodeRecord, LossRecord, OutcomeName, TrainObserver, TrainState,
};
use models::policy::QPolicy;
use serde::Serialize;
use sim::world::TrafficLevel;

use super::tasks::{Insertion, Obstacle, RoundaboutDriving, Route, TaskKind, task_config};
use super::validation::{VALIDATION_FILE, Validation, ValidationPoint, validation_seed};
use super::{TASK_FILE, Task, TaskRecord, TrainArgs};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::{AtomicDir, Markers, write_json};
use crate::ui::Progress;

/// A folder holding any of these is an earlier agent that may be replaced.
pub const AGENT_MARKERS: Markers = &[AGENT_FILE, TASK_FILE];
pub const SUMMARY_FILE: &str = "summary.json";

/// Episodes the success rates on the training curves are averaged over.
const RATE_WINDOW: usize = 100;

pub fn train(ctx: &Context<'_>, args: &TrainArgs) -> Result<()> {
    if args.offline {
        return super::offline::train(ctx, args);
    }
    match args.task {
        Task::RoundaboutInsertion => train_task::<Insertion>(ctx, args),
        Task::RouteFollowing => train_task::<Route>(ctx, args),
        Task::RoundaboutDriving => train_task::<RoundaboutDriving>(ctx, args),
        Task::ObstacleAvoidance => train_task::<Obstacle>(ctx, args),
    }
}

/// Trains an agent on task `K` (see [`TaskKind`]).
fn train_task<K: TaskKind>(ctx: &Context<'_>, args: &TrainArgs) -> Result<()> {
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
                task_config::<K>(task, file)?,
                task.validation,
                checkpoint.state.seed,
            )
        }
        None => (
            ctx.config.agent.dqn.clone(),
            K::config(&ctx.config.agent),
            ctx.config.agent.validation,
            ctx.cli.seed,
        ),
    };
    if resume.is_some() && seed != ctx.cli.seed {
        ctx.ui.warn(&format!(
            "resuming with the checkpoint's seed {seed} (--seed {} is ignored)",
            ctx.cli.seed
        ));
    }
    if let Some(steps) = args.steps {
        dqn.total_steps = steps;
    }
    dqn.validate().map_err(|e| config_error(ctx, e))?;
    if !validation_config.is_off() && dqn.checkpoint_every == 0 {
        return Err(CliError::new(
            "[agent.validation] validates every checkpoint, but checkpoint_every of [agent.dqn] is 0",
            "set checkpoint_every (e.g. 25000) or leave [agent.validation] out",
        )
        .into());
    }
    let traffic = TrafficLevel::from(args.traffic);

    if let Some(map) = &args.map {
        progress.step(&format!("loading {}", map.display()));
    }
    let setup = K::setup(args.map.as_deref(), &task_config)?;
    let envs: Vec<K::Env> = (0..dqn.envs)
        .map(|_| K::train_env(&setup, traffic))
        .collect();
    let task = TaskRecord {
        task: args.task,
        map: args.map.clone(),
        traffic,
        config: serde_json::to_value(&task_config)
            .context("the task's config cannot be written as JSON")?,
        validation: validation_config,
    };
    let validation = if validation_config.is_off() {
        None
    } else {
        let setup = match validation_config.action_repeat {
            Some(steps) => K::setup(
                args.map.as_deref(),
                &K::deciding_every(&task_config, steps)?,
            )?,
            None => Arc::clone(&setup),
        };
        let episodes = validation_config.episodes;
        let validation_seed = validation_seed(seed);
        let run = Box::new(move |policy: &QPolicy| {
            K::validate(&setup, policy, traffic, episodes, validation_seed)
        });
        let resumed = resume.as_ref().map(|(c, _, _)| c);
        Some(Validation::start(
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
        if let Some(map) = K::map(&setup) {
            crate::recording::log_map(rec, map)?;
        }
        if let Some((checkpoint, _, _)) = &resume {
            log_history(rec, &checkpoint.state)?;
        }
    }

    let started = Instant::now();
    let first_step = resume.as_ref().map_or(0, |(c, _, _)| c.state.steps);
    progress.step(&format!(
        "training for {} transitions in {} environments ({} traffic)",
        dqn.total_steps,
        dqn.envs,
        traffic.name()
    ));
    let mut observer = TrainProgress {
        progress: &mut progress,
        recording: recording.stream(),
        partial: partial.clone(),
        task: &task,
        total_steps: dqn.total_steps,
        first_step,
        started,
        last_report: Instant::now(),
        report_every: if ctx.ui.verbosity() >= crate::ui::Verbosity::Verbose {
            Duration::from_secs(10)
        } else {
            Duration::from_secs(60)
        },
        recent: VecDeque::with_capacity(RATE_WINDOW),
        validation,
        error: None,
    };
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
    let elapsed = started.elapsed().as_secs_f64();
    let mut summary = TrainSummary::new(&last.state, first_step, elapsed);
    let checkpoint = match validation {
        Some(validation) => {
            progress.step("validating the final network");
            let (chosen, history) = validation.choose(last);
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

    if let Some(rec) = recording.stream()
        && args.record_episodes > 0
    {
        progress.step("recording greedy episodes");
        let policy = models::policy::QPolicy::new(
            checkpoint.online.clone(),
            checkpoint.shape.spec(),
            checkpoint.shape.actions,
            models::cpu_device(),
        );
        K::record_episodes(rec, &setup, &policy, traffic, args.record_episodes, seed)?;
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

/// `DIR.partial` beside the agent folder `DIR`.
fn partial_dir(out: &Path) -> Result<PathBuf> {
    let name = out.file_name().ok_or_else(|| {
        CliError::file(
            out,
            "is not a folder name",
            "give --out a folder name such as runs/agent",
        )
    })?;
    Ok(out.with_file_name(format!("{}.partial", name.to_string_lossy())))
}

/// The checkpoint to resume from: the newest in `DIR.partial`, else the finished agent in
/// `DIR`; with its task record and the folder it came from.
fn find_checkpoint(out: &Path, partial: &Path) -> Result<(Checkpoint, TaskRecord, PathBuf)> {
    let candidates = [partial.join("checkpoint"), out.to_path_buf()];
    let Some(dir) = candidates.iter().find(|d| d.join(AGENT_FILE).is_file()) else {
        return Err(CliError::new(
            format!(
                "nothing to resume: neither {} nor {} holds a checkpoint",
                candidates[0].display(),
                out.display()
            ),
            "train without --resume first (checkpoints are written every checkpoint_every steps)",
        )
        .into());
    };
    let checkpoint =
        Checkpoint::load(dir, &models::cpu_device()).map_err(|e| models_error(e, dir))?;
    let task = read_task(dir)?;
    Ok((checkpoint, task, dir.join(TASK_FILE)))
}

pub fn read_task(dir: &Path) -> Result<TaskRecord> {
    let path = dir.join(TASK_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| {
        CliError::file(
            &path,
            format!("cannot read: {e}"),
            "give a folder written by `pipeline agent train`",
        )
    })?;
    Ok(serde_json::from_str(&text).map_err(|e| {
        CliError::file(
            &path,
            format!("invalid: {e}"),
            "give a folder written by `pipeline agent train`",
        )
    })?)
}

fn config_error(ctx: &Context<'_>, e: ModelError) -> anyhow::Error {
    let file = ctx
        .cli
        .config
        .clone()
        .unwrap_or_else(|| PathBuf::from("--config"));
    CliError::file(
        &file,
        format!("[agent.dqn]: {e}"),
        "fix the [agent.dqn] table (see docs/agents.md)",
    )
    .into()
}

/// A models-crate error as a one-line CLI error.
pub fn models_error(e: ModelError, context: &Path) -> anyhow::Error {
    match e {
        ModelError::File { .. } => CliError::new(
            e.to_string(),
            "check the agent folder (written by `pipeline agent train`)",
        )
        .into(),
        ModelError::Config(_) => CliError::file(context, e, "check [agent.dqn] in --config").into(),
    }
}

/// Progress line, rerun curves and checkpoints of a training run.
struct TrainProgress<'a, 'b> {
    progress: &'a mut Progress<'b>,
    recording: Option<&'a Stream>,
    partial: PathBuf,
    task: &'a TaskRecord,
    total_steps: u64,
    first_step: u64,
    started: Instant,
    last_report: Instant,
    report_every: Duration,
    /// Outcomes of the newest episodes, for the success rates.
    recent: VecDeque<OutcomeName>,
    /// Validation of every checkpoint, when `[agent.validation]` asks for it.
    validation: Option<Validation>,
    /// The first error the observer met (saving a checkpoint, logging).
    error: Option<anyhow::Error>,
}

impl TrainProgress<'_, '_> {
    fn rate(&self, outcome: OutcomeName) -> f64 {
        if self.recent.is_empty() {
            return 0.0;
        }
        self.recent.iter().filter(|&&o| o == outcome).count() as f64 / self.recent.len() as f64
    }

    fn keep(&mut self, result: Result<()>) {
        if let Err(e) = result
            && self.error.is_none()
        {
            self.error = Some(e);
        }
    }

    fn save_checkpoint(&self, checkpoint: &Checkpoint) -> Result<()> {
        std::fs::create_dir_all(&self.partial).map_err(|e| {
            CliError::file(
                &self.partial,
                format!("cannot create folder: {e}"),
                "check permissions",
            )
        })?;
        let dir = AtomicDir::create(&self.partial.join("checkpoint"), AGENT_MARKERS)?;
        checkpoint
            .save(dir.path())
            .map_err(|e| models_error(e, dir.path()))?;
        write_json(&dir.path().join(TASK_FILE), self.task)?;
        dir.commit()?;
        Ok(())
    }
}

impl TrainObserver for TrainProgress<'_, '_> {
    fn iteration(&mut self, state: &TrainState, epsilon: f64) -> bool {
        if self.last_report.elapsed() >= self.report_every || state.steps >= self.total_steps {
            self.last_report = Instant::now();
            let rate = (state.steps - self.first_step) as f64
                / self.started.elapsed().as_secs_f64().max(1e-9);
            self.progress.step(&format!(
                "step {} / {} ({:.0} %), {} episodes, ε {:.3}, last {}: reached {:.0} %, crashed {:.0} %, \
                 time over {:.0} %; {:.0} steps/s",
                state.steps,
                self.total_steps,
                100.0 * state.steps as f64 / self.total_steps.max(1) as f64,
                state.episodes,
                epsilon,
                self.recent.len(),
                100.0 * self.rate(OutcomeName::Reached),
                100.0 * self.rate(OutcomeName::Crashed),
                100.0 * self.rate(OutcomeName::TimeOver),
                rate,
            ));
        }
        self.error.is_none()
    }

    fn episode(&mut self, record: &EpisodeRecord) {
        if self.recent.len() == RATE_WINDOW {
            self.recent.pop_front();
        }
        self.recent.push_back(record.outcome);
        let rates = [
            ("reached", self.rate(OutcomeName::Reached)),
            ("crashed", self.rate(OutcomeName::Crashed)),
            ("time_over", self.rate(OutcomeName::TimeOver)),
        ];
        if let Some(rec) = self.recording {
            let result = log_episode(rec, record, &rates);
            self.keep(result);
        }
    }

    fn losses(&mut self, record: &LossRecord) {
        if let Some(rec) = self.recording {
            let result = log_losses(rec, record);
            self.keep(result);
        }
    }

    fn checkpoint(&mut self, checkpoint: &Checkpoint) -> Result<(), ModelError> {
        // Validation first: a kill before the checkpoint is written resumes from the one
        // before, whose best checkpoint is still kept (see `Validation::start`).
        if let Some(validation) = &mut self.validation {
            let (point, best) = validation.validate(checkpoint);
            self.progress.note(&format!(
                "{}{}",
                point.describe(),
                if best { ", the best so far" } else { "" }
            ));
            let saved = validation.save(&self.partial, self.task);
            if let Some(rec) = self.recording {
                let result = log_validation(rec, &point);
                self.keep(result);
            }
            self.keep(saved);
        }
        let result = self.save_checkpoint(checkpoint);
        if result.is_ok() {
            self.progress
                .note(&format!("checkpoint at step {}", checkpoint.state.steps));
            if let Some(validation) = &self.validation {
                let result = validation.prune(&self.partial);
                self.keep(result);
            }
        }
        self.keep(result);
        Ok(())
    }
}

/// The curves of an earlier part of a resumed run, so the recording shows the whole run.
fn log_history(rec: &Stream, state: &TrainState) -> Result<()> {
    let mut recent: VecDeque<OutcomeName> = VecDeque::with_capacity(RATE_WINDOW);
    for record in &state.episode_history {
        if recent.len() == RATE_WINDOW {
            recent.pop_front();
        }
        recent.push_back(record.outcome);
        let rate = |o: OutcomeName| {
            recent.iter().filter(|&&x| x == o).count() as f64 / recent.len() as f64
        };
        let rates = [
            ("reached", rate(OutcomeName::Reached)),
            ("crashed", rate(OutcomeName::Crashed)),
            ("time_over", rate(OutcomeName::TimeOver)),
        ];
        log_episode(rec, record, &rates)?;
    }
    for record in &state.loss_history {
        log_losses(rec, record)?;
    }
    Ok(())
}

fn log_episode(rec: &Stream, record: &EpisodeRecord, rates: &[(&str, f64)]) -> Result<()> {
    rec.set_time_sequence("step", record.step as i64);
    let mut scalars = vec![
        ("agent/train/return", record.episode_return),
        ("agent/train/length", record.length as f64),
        ("agent/train/epsilon", record.epsilon),
    ];
    let rate_paths: Vec<(String, f64)> = rates
        .iter()
        .map(|(name, v)| (format!("agent/train/rate/{name}"), *v))
        .collect();
    scalars.extend(rate_paths.iter().map(|(p, v)| (p.as_str(), *v)));
    crate::recording::log_scalars(rec, &scalars)
}

fn log_losses(rec: &Stream, record: &LossRecord) -> Result<()> {
    rec.set_time_sequence("step", record.step as i64);
    crate::recording::log_scalars(
        rec,
        &[
            ("agent/train/td_loss", record.td_loss),
            ("agent/train/mean_q", record.mean_q),
        ],
    )
}

/// The validation curves: the score and each condition's share reached.
fn log_validation(rec: &Stream, point: &ValidationPoint) -> Result<()> {
    rec.set_time_sequence("step", point.steps as i64);
    let entities: Vec<(String, f64)> = std::iter::once(("score".to_owned(), point.score))
        .chain(
            point
                .reached
                .iter()
                .map(|(name, r)| (name.replace(' ', "_"), *r)),
        )
        .map(|(name, value)| (format!("agent/validation/{name}"), value))
        .collect();
    let series: Vec<(&str, f64)> = entities.iter().map(|(e, v)| (e.as_str(), *v)).collect();
    crate::recording::log_scalars(rec, &series)
}

/// `summary.json` of an agent folder.
#[derive(Debug, Serialize)]
struct TrainSummary {
    seed: u64,
    steps: u64,
    updates: u64,
    episodes: u64,
    resumed_at: Vec<u64>,
    /// Of this invocation (a resumed run counts from where it resumed).
    wall_seconds: f64,
    steps_per_second: f64,
    /// Outcome fractions over the last (up to) 1,000 training episodes (with exploration).
    last_episodes: usize,
    reached: f64,
    crashed: f64,
    off_road: f64,
    time_over: f64,
    /// With `[agent.validation]`: the transitions of the checkpoint chosen as the agent
    /// (its files are that checkpoint's; the figures above are of the whole run).
    #[serde(skip_serializing_if = "Option::is_none")]
    chosen_steps: Option<u64>,
}

impl TrainSummary {
    fn new(state: &TrainState, first_step: u64, wall_seconds: f64) -> Self {
        let tail = &state.episode_history[state.episode_history.len().saturating_sub(1000)..];
        let frac = |o: OutcomeName| {
            if tail.is_empty() {
                0.0
            } else {
                tail.iter().filter(|e| e.outcome == o).count() as f64 / tail.len() as f64
            }
        };
        TrainSummary {
            seed: state.seed,
            steps: state.steps,
            updates: state.updates,
            episodes: state.episodes,
            resumed_at: state.resumed_at.clone(),
            wall_seconds,
            steps_per_second: (state.steps - first_step) as f64 / wall_seconds.max(1e-9),
            last_episodes: tail.len(),
            reached: frac(OutcomeName::Reached),
            crashed: frac(OutcomeName::Crashed),
            off_road: frac(OutcomeName::OffRoad),
            time_over: frac(OutcomeName::TimeOver),
            chosen_steps: None,
        }
    }

    fn describe(&self, dest: &Path) -> String {
        format!(
            "agent: {}\n  {} transitions, {} gradient steps, {} episodes in {:.0} s ({:.0} transitions/s)\n  \
             last {} training episodes (with exploration): reached {:.1} %, crashed {:.1} %, off road {:.1} %, \
             time over {:.1} %",
            dest.display(),
            self.steps,
            self.updates,
            self.episodes,
            self.wall_seconds,
            self.steps_per_second,
            self.last_episodes,
            100.0 * self.reached,
            100.0 * self.crashed,
            100.0 * self.off_road,
            100.0 * self.time_over,
        )
    }
}
