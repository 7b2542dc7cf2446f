//! Policies judged against what real drivers did at roundabout entries (`pipeline replay eval`,
//! `pipeline replay gaps`), and the drivers' approaches turned into transitions to learn from.
//!
//! Every vehicle's approach to a yield line of the map's roundabouts is labelled go / wait /
//! ambiguous frame by frame from what its driver did ([`traffic::decisions`]). At each labelled
//! frame every policy decides from what the driver could see then: the rules from the
//! distance to the nearest vehicle on the ring, the agent and behaviour cloning from the
//! bird's-eye frames around the vehicle (its own recorded path, the task's frames stacked)
//! and its scalars ([`views`]). Caution counts as wait, as in the Parma study. Agreement is
//! over the go and wait frames; ambiguous and queued frames are counted, not scored
//! ([`tally`]).
//!
//! - [`eval`] runs the policies over the approaches (open loop, and closed loop among the
//!   replayed traffic with [`closed_loop`]);
//! - [`report`] holds what a run or a shard of it found, the report (`replay.json`) and its
//!   markdown (`replay.md`), and adds the shards of one run up, byte for byte the unsharded
//!   run's report;
//! - [`gaps`] scores gap-acceptance policies on every gap a driver was offered at a yield line;
//! - [`offline`] turns the drivers' approaches into transitions to learn from.

pub mod closed_loop;
pub mod eval;
pub mod gaps;
pub mod offline;
pub mod report;
pub mod tally;
pub mod views;

use std::collections::BTreeMap;

use maps::Map;
use sim::render::BevConfig;
use sim::tasks::insertion::InsertionConfig;

use logs::project::LogFrame;
use traffic::decisions::{Approach, LabelConfig, approaches};
use traffic::measure::{Measurements, RingGeometry, measure};

pub use eval::{BC_AGGRESSIVENESS, BcExamples, Policies, RULE_THRESHOLDS, agent_goes, evaluate};
pub use report::{Counts, MergeError, Report, Settings, ShardFile, markdown, merge_shard_dirs};
pub use tally::{LoopScore, LoopTally, Score, Tally};
pub use traffic::decisions::nearest_circulating;
pub use views::{ClosedLoopInputs, FrameInput, Views};

/// The report of a run.
pub const REPLAY_JSON: &str = "replay.json";
/// The report's table.
pub const REPLAY_MD: &str = "replay.md";
/// A shard's counts (`replay eval --shard i/n`).
pub const REPLAY_SHARD_JSON: &str = "replay_shard.json";

/// A log read into frames, with its approaches.
#[derive(Debug, Clone)]
pub struct ReplayLog {
    /// The log's file name, the key of its per-log figures.
    pub name: String,
    pub frames: Vec<LogFrame>,
    pub approaches: Vec<Approach>,
    /// The traffic measured at each of the map's roundabouts that can be measured.
    pub rings: Vec<Measurements>,
    /// Where each track entered a ring.
    pub entered: BTreeMap<u32, Entered>,
}

/// Where a driver entered a ring, as the gap it accepted needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Entered {
    /// Index into [`ReplayLog::rings`].
    pub ring: usize,
    pub entry: usize,
    pub at_line_s: f64,
    pub crossed_s: f64,
}

impl ReplayLog {
    /// The log `name` of `frames` with its approaches to `map`'s yield lines, labelled by
    /// `labels`.
    pub fn new(name: String, frames: Vec<LogFrame>, map: &Map, labels: &LabelConfig) -> Self {
        let approaches = approaches(map, &frames, labels);
        let mut rings = Vec::new();
        let mut entered = BTreeMap::new();
        for &id in map.roundabouts.keys() {
            let Ok(geometry) = RingGeometry::new(map, id) else {
                continue;
            };
            let measured = measure(&geometry, &frames);
            for e in &measured.entering {
                entered.entry(e.track).or_insert(Entered {
                    ring: rings.len(),
                    entry: e.entry,
                    at_line_s: e.at_line_s,
                    crossed_s: e.crossed_s,
                });
            }
            rings.push(measured);
        }
        ReplayLog {
            name,
            frames,
            approaches,
            rings,
            entered,
        }
    }

    /// Vehicles that crossed a yield line of a ring towards it without an approach (less
    /// than `min_approach_s` of their track before the line), counted by neither `replay
    /// eval` nor `replay gaps`.
    pub fn crossings_without_approach(&self) -> usize {
        self.entered
            .keys()
            .filter(|t| !self.approaches.iter().any(|a| a.track == **t))
            .count()
    }

    /// The gap `track`'s vehicle accepted crossing its line `delay_s` after its driver did
    /// (0: the driver's own), measured as [`Measurements::gap_at`] does; None when the
    /// track entered no ring or the log ends first.
    pub fn accepted_gap(&self, track: u32, delay_s: f64) -> Option<f64> {
        let e = self.entered.get(&track)?;
        self.rings
            .get(e.ring)?
            .gap_at(e.entry, track, e.at_line_s, e.crossed_s + delay_s)
    }
}

/// The task whose view the policies get when no agent gives one: behaviour cloning then
/// sees two stacked frames of 42 × 42 pixels.
pub fn default_task() -> InsertionConfig {
    InsertionConfig {
        observation: BevConfig {
            width: 42,
            height: 42,
            stack: 2,
            ..BevConfig::default()
        },
        ..InsertionConfig::default()
    }
}

/// A task that decides every several steps, which projected logs cannot give.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "has `action_repeat = {action_repeat}`: it decides every {action_repeat} steps, and \
     projected logs give a decision every step"
)]
pub struct Unprojectable {
    pub action_repeat: usize,
}

/// Projected logs give the bird's-eye layers, the speed, the rule inputs and the motion
/// inputs of every log frame (one frame per world step), not decisions every several steps
/// ([`InsertionConfig::action_repeat`]): an error for a task that asks for that. Frames
/// stacked several steps apart ([`InsertionConfig::frame_steps`]) are stacked that many log
/// frames apart.
pub fn check_projectable(config: &InsertionConfig) -> Result<(), Unprojectable> {
    if config.action_repeat != 1 {
        return Err(Unprojectable {
            action_repeat: config.action_repeat,
        });
    }
    Ok(())
}
