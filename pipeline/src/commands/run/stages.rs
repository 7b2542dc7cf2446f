//! The stages of `pipeline run`, in order: what each reads (earlier stages' outputs) and
//! what it writes (folders in the run). How they run is [`super::stage_env`].

use clap::ValueEnum;
use serde::Serialize;

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
