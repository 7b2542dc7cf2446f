//! What `agent train` does while `models::dqn::train` runs: the progress line, the rerun
//! curves, the checkpoints written into `DIR.partial`, and with `[agent.validation]` the
//! validation of every checkpoint (the best kept beside them, see [`crate::agent_folder`]).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Result;
use models::ModelError;
use models::dqn::{Checkpoint, EpisodeRecord, LossRecord, OutcomeName, TrainObserver, TrainState};
use models::training::OutcomeRates;
use models::validation::Validation;

use crate::agent_folder::{TaskRecord, prune_validation, save_validation, write_checkpoint};
use crate::agent_recording::{log_episode, log_losses, log_validation};
use crate::error::CliError;
use crate::recording::Stream;
use crate::ui::{Progress, plural};

/// Progress line, rerun curves and checkpoints of a training run.
#[derive(Debug)]
pub struct TrainProgress<'a, 'b> {
    pub progress: &'a mut Progress<'b>,
    pub recording: Option<&'a Stream>,
    /// `DIR.partial`, where checkpoints go.
    pub partial: PathBuf,
    pub task: &'a TaskRecord,
    pub total_steps: u64,
    /// Where this invocation started (a resumed run's checkpoint).
    pub first_step: u64,
    pub started: Instant,
    pub last_report: Instant,
    /// How often the bar's figures (episodes, ε, outcome rates) are updated.
    pub report_every: Duration,
    /// Outcomes of the newest episodes, for the success rates.
    pub recent: OutcomeRates,
    /// Validation of every checkpoint, when `[agent.validation]` asks for it.
    pub validation: Option<Validation>,
    /// Episodes of one validation (shown while a checkpoint is validated).
    pub validation_episodes: u64,
    /// The first error the observer met (saving a checkpoint, logging).
    pub error: Option<anyhow::Error>,
}

/// The span of a training run: transitions from `first_step` (a resumed run's checkpoint)
/// to `total_steps`; `verbose` updates the bar's figures every second rather than every two.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RunSpan {
    pub first_step: u64,
    pub total_steps: u64,
    pub verbose: bool,
}

impl<'a, 'b> TrainProgress<'a, 'b> {
    /// The observer of a run of `task` checkpointing into `partial`, validating its
    /// checkpoints with `validation`; its clock starts now.
    pub fn new(
        progress: &'a mut Progress<'b>,
        recording: Option<&'a Stream>,
        partial: &Path,
        task: &'a TaskRecord,
        span: RunSpan,
        validation: Option<Validation>,
    ) -> Self {
        progress.counted("training", span.total_steps, "transitions");
        progress.resume_at(span.first_step);
        TrainProgress {
            progress,
            recording,
            partial: partial.to_path_buf(),
            task,
            total_steps: span.total_steps,
            first_step: span.first_step,
            started: Instant::now(),
            last_report: Instant::now(),
            report_every: Duration::from_secs(if span.verbose { 1 } else { 2 }),
            recent: OutcomeRates::new(),
            validation,
            validation_episodes: 0,
            error: None,
        }
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
        write_checkpoint(&self.partial.join("checkpoint"), checkpoint, self.task)
    }
}

impl TrainObserver for TrainProgress<'_, '_> {
    fn iteration(&mut self, state: &TrainState, epsilon: f64) -> bool {
        self.progress.set_position(state.steps);
        if self.last_report.elapsed() >= self.report_every || state.steps >= self.total_steps {
            self.last_report = Instant::now();
            self.progress.set_figures(&format!(
                "{}, ε {:.3}, last {}: reached {:.0} %, crashed {:.0} %, time over {:.0} %",
                plural(state.episodes as usize, "episode"),
                epsilon,
                self.recent.len(),
                100.0 * self.recent.rate(OutcomeName::Reached),
                100.0 * self.recent.rate(OutcomeName::Crashed),
                100.0 * self.recent.rate(OutcomeName::TimeOver),
            ));
        }
        self.error.is_none()
    }

    fn episode(&mut self, record: &EpisodeRecord) {
        self.recent.push(record.outcome);
        if let Some(rec) = self.recording {
            let result = log_episode(rec, record, &self.recent.curves());
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
        // before, whose best checkpoint is still kept (see `start_validation`).
        if let Some(validation) = &mut self.validation {
            // The training bar gives way to the validation's episodes, then comes back with
            // its rate and ETA counted from here (validation time is not training time).
            let steps = checkpoint.state.steps;
            self.progress.counted(
                &format!("validating the checkpoint at step {steps}:"),
                self.validation_episodes,
                "episodes",
            );
            let progress = &*self.progress;
            let (point, best) = validation.validate(checkpoint, &|n| progress.inc(n));
            self.progress
                .count_again("training", self.total_steps, "transitions", steps);
            self.progress.note(&format!(
                "{}{}",
                point.describe(),
                if best { ", the best so far" } else { "" }
            ));
            let saved = save_validation(validation, &self.partial, self.task);
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
                let result = prune_validation(validation, &self.partial);
                self.keep(result);
            }
        }
        self.keep(result);
        Ok(())
    }
}
