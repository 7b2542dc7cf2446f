//! How the stages of `pipeline run` run. Each declares the files outside the run it reads
//! and the settings that shape its outputs; it runs as the same `pipeline` commands a user
//! would type, so a stage's outputs are exactly what those commands write.

use std::path::{Path, PathBuf};

use anyhow::Result;

use super::settings::ProfileSettings;
use super::stages::{
    AGENT_EVAL, AGENT_MODEL, AUGMENTED, CAMPUS_MAP, GENERATED, REPLAY, ROUNDABOUT_MAP,
    SEGMENTER_EVAL, SEGMENTER_MODEL, SIMULATED_LOG, StageName,
};
use crate::args::RerunMode;
use crate::commands::Context;
use crate::config::Config;
use crate::recording::Stream;
use crate::ui::Verbosity;

/// `pipeline` arguments from anything printable.
macro_rules! args {
    ($($arg:expr),* $(,)?) => { [$($arg.to_string()),*] };
}

/// Everything a stage needs to run.
#[derive(Debug)]
pub struct StageEnv<'a> {
    pub ctx: &'a Context<'a>,
    pub run_dir: &'a Path,
    pub profile: &'a ProfileSettings,
    pub campus: &'a Path,
    pub roundabout: &'a Path,
    /// The run's recording under this stage's entity prefix.
    pub recording: Option<&'a Stream>,
}

impl StageEnv<'_> {
    fn path(&self, rel: &str) -> String {
        self.run_dir.join(rel).to_string_lossy().into_owned()
    }

    /// The config the stage's commands see: the run's, with the profile's agent recipe and
    /// budget.
    pub fn config(&self) -> Result<Config> {
        let mut config = self.ctx.config.clone();
        let agent = &self.profile.agent;
        if let Some(file) = &agent.config {
            config.agent = Config::load(Some(&self.ctx.config.resolve(file)))?.agent;
            config.apply_world();
        }
        if let Some(steps) = agent.steps {
            config.agent.dqn.total_steps = steps;
        }
        if let Some(steps) = agent.warmup_steps {
            config.agent.dqn.warmup_steps = steps;
        }
        Ok(config)
    }

    /// The segmenter recipe file of the profile, resolved against the config file.
    pub(super) fn segmenter_settings(&self) -> Option<PathBuf> {
        let file = self.profile.segmenter.settings.as_ref()?;
        Some(self.ctx.config.resolve(file))
    }

    /// Runs `pipeline <args>` in this process with the run's seed, verbosity and recording.
    fn command(&self, args: &[String]) -> Result<()> {
        self.command_under(None, args)
    }

    /// As [`command`](Self::command), logging under `sub` within the stage's entity path
    /// (when a stage runs the same command twice, as `maps` does).
    fn command_under(&self, sub: Option<&str>, args: &[String]) -> Result<()> {
        let cli = self.ctx.global;
        let mut argv: Vec<String> = vec!["pipeline".into(), "--seed".into(), cli.seed.to_string()];
        argv.push("--rerun".into());
        argv.push(match (&cli.rerun, self.recording) {
            (RerunMode::Off, _) | (_, None) => "off".into(),
            _ => "save".into(),
        });
        if let Some(device) = clap::ValueEnum::to_possible_value(&cli.device) {
            argv.extend(["--device".into(), device.get_name().to_owned()]);
        }
        match self.ctx.ui.verbosity() {
            Verbosity::Quiet => argv.push("-q".into()),
            Verbosity::Verbose => argv.push("-v".into()),
            Verbosity::Trace => argv.push("-vv".into()),
            Verbosity::Normal => {}
        }
        argv.extend(args.iter().cloned());
        let config = self.config()?;
        let recording = match (self.recording, sub) {
            (Some(stream), Some(sub)) => Some(stream.under(sub)),
            (stream, _) => stream.cloned(),
        };
        let stage_ctx = Context {
            config: &config,
            recording: recording.as_ref(),
            ..*self.ctx
        };
        (self.ctx.run_argv)(&stage_ctx, &argv)
    }

    /// Runs the stage; its output folders do not exist when it starts.
    pub fn run(&self, stage: StageName) -> Result<()> {
        let p = self.profile;
        match stage {
            StageName::Maps => {
                for (name, input, out) in [
                    ("campus", self.campus, CAMPUS_MAP),
                    ("roundabout", self.roundabout, ROUNDABOUT_MAP),
                ] {
                    self.command_under(
                        Some(name),
                        &args![
                            "map",
                            "import",
                            input.to_string_lossy().into_owned(),
                            "--out",
                            self.path(out)
                        ],
                    )?;
                }
                Ok(())
            }
            StageName::Dataset => {
                self.command(&args![
                    "dataset",
                    "generate",
                    "--map",
                    self.path(CAMPUS_MAP),
                    "--out",
                    self.path(GENERATED),
                    "--count",
                    p.dataset.images,
                    "--size",
                    p.dataset.size,
                ])?;
                self.command(&args!["dataset", "split", self.path(GENERATED)])
            }
            StageName::Augment => self.command(&args![
                "dataset",
                "augment",
                self.path(GENERATED),
                "--out",
                self.path(AUGMENTED),
                "--copies",
                p.dataset.augment_copies,
                "--preset",
                "thesis",
                "--include-originals",
            ]),
            StageName::Segmenter => {
                let t = &p.segmenter;
                let mut train = args!["segmenter", "train"].to_vec();
                if let Some(file) = self.segmenter_settings() {
                    train.extend(args!["--settings", file.to_string_lossy()]);
                }
                train.extend(args![
                    "--data",
                    self.path(AUGMENTED),
                    "--val",
                    self.path(GENERATED),
                    "--out",
                    self.path(SEGMENTER_MODEL),
                    "--epochs",
                    t.epochs,
                    "--max-minutes",
                    t.max_minutes,
                    "--size",
                    t.size,
                    "--crop",
                    t.crop.unwrap_or(t.size),
                    "--width",
                    t.width,
                    "--batch-size",
                    t.batch_size,
                    "--val-limit",
                    t.eval_images,
                ]);
                self.command(&train)?;
                self.command(&args![
                    "segmenter",
                    "eval",
                    "--model",
                    self.path(&format!("{SEGMENTER_MODEL}/best")),
                    "--size",
                    t.size,
                    "--data",
                    self.path(GENERATED),
                    "--split",
                    "val",
                    "--limit",
                    t.eval_images,
                    "--out",
                    self.path(SEGMENTER_EVAL),
                ])
            }
            StageName::Agent => {
                self.command(&args![
                    "agent",
                    "train",
                    "--task",
                    "roundabout-insertion",
                    "--map",
                    self.path(ROUNDABOUT_MAP),
                    "--out",
                    self.path(AGENT_MODEL),
                    "--traffic",
                    "medium",
                ])?;
                self.command(&args![
                    "agent",
                    "eval",
                    "--agent",
                    self.path(AGENT_MODEL),
                    "--map",
                    self.path(ROUNDABOUT_MAP),
                    "--episodes",
                    p.agent.eval_episodes,
                    "--traffic",
                    "medium",
                    "--aggressiveness",
                    "0.5",
                    "--out",
                    self.path(AGENT_EVAL),
                ])
            }
            StageName::Logs => super::simlog::record_and_project(
                self.run_dir,
                self.config()?.agent.task,
                p.logs.seconds,
                self.ctx.global.seed,
                self.recording,
                &self.run_dir.join(SIMULATED_LOG),
            ),
            StageName::Replay => {
                let mut argv = args!["replay", "eval"].to_vec();
                for log in super::simlog::logs_in(&self.run_dir.join(SIMULATED_LOG))? {
                    argv.push("--log".into());
                    argv.push(log.to_string_lossy().into_owned());
                }
                argv.extend(args![
                    "--map",
                    self.path(ROUNDABOUT_MAP),
                    "--agent",
                    self.path(AGENT_MODEL),
                    "--out",
                    self.path(REPLAY),
                ]);
                self.command(&argv)
            }
        }
    }
}
