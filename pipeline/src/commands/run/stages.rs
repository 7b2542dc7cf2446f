//! The stages of `pipeline run`, in order. Each declares what it reads (files outside the
//! run, earlier stages' outputs), what it writes (folders in the run), and the settings
//! that shape its outputs; it runs as the same `pipeline` commands a user would type, so a
//! stage's outputs are exactly what those commands write.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::ValueEnum;
use serde::Serialize;

use super::settings::ProfileSettings;
use clap::Parser;

use crate::cli::{Cli, RerunMode};
use crate::commands::Context;
use crate::config::Config;
use crate::recording::Stream;
use crate::ui::Verbosity;

/// `pipeline` arguments from anything printable.
macro_rules! args {
    ($($arg:expr),* $(,)?) => { [$($arg.to_string()),*] };
}

/// The stages, in the order they run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, ValueEnum, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StageName {
    /// Import the bundled campus and roundabout maps.
    Maps,
    /// Render labelled camera images on the campus and split them 70 / 30.
    Dataset,
    /// Augmented copies of the rendered images (the thesis preset).
    Augment,
    /// Train the segmenter on the augmented set, evaluate it on the rendered validation split.
    Segmenter,
    /// Train a roundabout-insertion agent, evaluate it beside the baselines.
    Agent,
    /// Record simulated traffic as an MCAP log, read it back and project it.
    Logs,
    /// Judge the agent and the baselines against the simulated drivers' go / wait decisions
    /// in those logs.
    Replay,
}

impl StageName {
    pub const ALL: [StageName; 7] = [
        StageName::Maps,
        StageName::Dataset,
        StageName::Augment,
        StageName::Segmenter,
        StageName::Agent,
        StageName::Logs,
        StageName::Replay,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            StageName::Maps => "maps",
            StageName::Dataset => "dataset",
            StageName::Augment => "augment",
            StageName::Segmenter => "segmenter",
            StageName::Agent => "agent",
            StageName::Logs => "logs",
            StageName::Replay => "replay",
        }
    }

    /// The earlier stages whose outputs this one reads.
    pub fn needs(self) -> &'static [StageName] {
        match self {
            StageName::Maps => &[],
            StageName::Dataset => &[StageName::Maps],
            StageName::Augment => &[StageName::Dataset],
            StageName::Segmenter => &[StageName::Dataset, StageName::Augment],
            StageName::Agent | StageName::Logs => &[StageName::Maps],
            StageName::Replay => &[StageName::Maps, StageName::Agent, StageName::Logs],
        }
    }

    /// The folders it writes, relative to the run folder.
    pub fn outputs(self) -> &'static [&'static str] {
        match self {
            StageName::Maps => &[CAMPUS_MAP, ROUNDABOUT_MAP],
            StageName::Dataset => &[GENERATED],
            StageName::Augment => &[AUGMENTED],
            StageName::Segmenter => &[SEGMENTER_MODEL, SEGMENTER_EVAL],
            StageName::Agent => &[AGENT_MODEL, AGENT_EVAL],
            StageName::Logs => &[SIMULATED_LOG],
            StageName::Replay => &[REPLAY],
        }
    }
}

pub const CAMPUS_MAP: &str = "maps/campus";
pub const ROUNDABOUT_MAP: &str = "maps/roundabout";
pub const GENERATED: &str = "dataset/generated";
pub const AUGMENTED: &str = "dataset/augmented";
pub const SEGMENTER_MODEL: &str = "segmenter/model";
pub const SEGMENTER_EVAL: &str = "segmenter/eval";
pub const AGENT_MODEL: &str = "agent/model";
pub const AGENT_EVAL: &str = "agent/eval";
pub const SIMULATED_LOG: &str = "logs/simulated";
pub const REPLAY: &str = "replay";

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

    /// The config the stage's commands see: the run's, with the profile's agent budget.
    fn config(&self) -> Config {
        let mut config = self.ctx.config.clone();
        config.agent.dqn.total_steps = self.profile.agent.steps;
        config.agent.dqn.warmup_steps = self.profile.agent.warmup_steps;
        config
    }

    /// Runs `pipeline <args>` in this process with the run's seed, verbosity and recording.
    fn command(&self, args: &[String]) -> Result<()> {
        self.command_under(None, args)
    }

    /// As [`command`](Self::command), logging under `sub` within the stage's entity path
    /// (when a stage runs the same command twice, as `maps` does).
    fn command_under(&self, sub: Option<&str>, args: &[String]) -> Result<()> {
        let cli = self.ctx.cli;
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
        let child = Cli::try_parse_from(&argv).map_err(|e| {
            anyhow::anyhow!(
                "internal error: stage command `{}` did not parse: {e}",
                argv.join(" ")
            )
        })?;
        let config = self.config();
        let recording = match (self.recording, sub) {
            (Some(stream), Some(sub)) => Some(stream.under(sub)),
            (stream, _) => stream.cloned(),
        };
        let child_ctx = Context {
            cli: &child,
            config: &config,
            ui: self.ctx.ui,
            recording: recording.as_ref(),
        };
        crate::dispatch(&child_ctx)
    }

    /// The settings that shape this stage's outputs (part of its key).
    pub fn settings(&self, stage: StageName) -> Result<serde_json::Value> {
        let p = self.profile;
        let seed = self.ctx.cli.seed;
        let version = env!("CARGO_PKG_VERSION");
        Ok(match stage {
            StageName::Maps => serde_json::json!({
                "version": version,
                "import": serde_json::to_value(&self.ctx.config.map.import)?,
            }),
            StageName::Dataset => serde_json::json!({
                "version": version, "seed": seed,
                "images": p.dataset.images, "size": p.dataset.size,
            }),
            StageName::Augment => serde_json::json!({
                "version": version, "seed": seed, "copies": p.dataset.augment_copies,
            }),
            StageName::Segmenter => serde_json::json!({
                "version": version, "seed": seed, "segmenter": serde_json::to_value(&p.segmenter)?,
            }),
            StageName::Agent => serde_json::json!({
                "version": version, "seed": seed,
                "eval_episodes": p.agent.eval_episodes,
                "agent": serde_json::to_value(&self.config().agent)?,
            }),
            StageName::Logs => serde_json::json!({
                "version": version, "seed": seed,
                "logs": serde_json::to_value(&p.logs)?,
                "task": serde_json::to_value(&self.ctx.config.agent.task)?,
            }),
            StageName::Replay => serde_json::json!({ "version": version }),
        })
    }

    /// Files outside the run folder the stage reads.
    pub fn external_inputs(&self, stage: StageName) -> Vec<PathBuf> {
        match stage {
            StageName::Maps => vec![self.campus.to_path_buf(), self.roundabout.to_path_buf()],
            _ => Vec::new(),
        }
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
                self.command(&args![
                    "segmenter",
                    "train",
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
                    t.size,
                    "--width",
                    t.width,
                    "--batch-size",
                    t.batch_size,
                    "--val-limit",
                    t.eval_images,
                ])?;
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
            StageName::Logs => {
                super::simlog::record_and_project(self, &self.run_dir.join(SIMULATED_LOG))
            }
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
