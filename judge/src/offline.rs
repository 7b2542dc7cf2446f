//! Transitions for learning roundabout insertion from recorded drivers instead of the
//! simulator (`pipeline agent train --offline`).
//!
//! Every vehicle's approach to a yield line of the map's roundabout in the logs becomes an
//! episode ([`traffic::decisions`] labels its frames): at each frame the observation the agent
//! would have had there (the bird's-eye frames around the vehicle, its recorded path, its
//! speed; [`crate::Views`], which `replay eval` shows agents too), the driver's action
//! (go = Permitted, wait or queued behind another car = Not Permitted; ambiguous frames start
//! no transition) and the task's reward for it, as far as a log tells it:
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
//! equals the current one, so a network that reads it learns to repeat itself;
//! [`ignore_unlogged_inputs`]); the inputs stay in the observation so the agent runs in the
//! simulator and in `replay eval` unchanged.

use std::collections::BTreeMap;
use std::path::PathBuf;

use maps::Map;
use models::ModelError;
use models::dqn::DqnConfig;
use models::offline::{OfflineConfig, OfflineSummary, TransitionSet};
use serde::Serialize;
use sim::tasks::insertion::{AGGRESSIVENESS_SCALAR, Action, LAST_ACTION_SCALARS, RewardConfig};

use crate::{ReplayLog, Views};
use logs::project::LogFrame;
use traffic::decisions::{Approach, Decision, LabelConfig};

/// The offline run's description beside the agent (`offline.json`).
pub const OFFLINE_FILE: &str = "offline.json";
/// The aggressiveness written into the inputs (the network ignores it).
pub const LOGGED_AGGRESSIVENESS: f64 = 0.5;
/// How long a driver's frames after the yield line stay in the episode, s.
pub const AFTER_CROSSING_S: f64 = 15.0;

/// `offline.json`: what an offline run learnt from, and how it went.
#[derive(Debug, Serialize)]
pub struct OfflineRun<'a> {
    pub config: &'a OfflineConfig,
    pub logs: &'a [PathBuf],
    pub map: &'a PathBuf,
    pub target_speed_mps: f64,
    pub labels: LabelConfig,
    pub approaches: usize,
    /// Frames per label over the episodes (the approaches, then the ring frames, all go).
    pub frames: BTreeMap<String, u64>,
    pub summary: &'a OfflineSummary,
    pub wall_seconds: f64,
    pub gradient_steps_per_second: f64,
}

/// Makes `dqn`'s network ignore the inputs a log cannot tell: the aggressiveness and the
/// last action.
pub fn ignore_unlogged_inputs(dqn: &mut DqnConfig) {
    for ignored in std::iter::once(AGGRESSIVENESS_SCALAR).chain(LAST_ACTION_SCALARS) {
        if !dqn.network.ignored_scalars.contains(&ignored) {
            dqn.network.ignored_scalars.push(ignored);
        }
    }
}

/// The drivers' approaches as episodes of transitions.
#[derive(Debug)]
pub struct LoggedEpisodes {
    pub set: TransitionSet,
    /// Approaches taken (one episode each).
    pub approaches: usize,
    /// Frames per label over the episodes.
    pub frames: BTreeMap<String, u64>,
    reward: RewardConfig,
    target_speed_mps: f64,
}

impl LoggedEpisodes {
    /// No episodes yet, for observations of `views` and the task's `reward`, the drivers
    /// told `target_speed_mps`.
    pub fn new(views: &Views, reward: RewardConfig, target_speed_mps: f64) -> Self {
        LoggedEpisodes {
            set: TransitionSet::new(views.spec(), Action::ALL.len()),
            approaches: 0,
            frames: BTreeMap::new(),
            reward,
            target_speed_mps,
        }
    }

    /// Adds every approach of `log` (on `map`) as an episode.
    pub fn add_log(&mut self, map: &Map, views: &Views, log: &ReplayLog) -> Result<(), ModelError> {
        for approach in &log.approaches {
            let approach = &through_the_ring(approach, &log.frames);
            let inputs = views.inputs(map, &log.frames, approach);
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
                    &self.reward,
                    speed / self.target_speed_mps,
                    previous,
                    *action,
                    last,
                ) as f32);
                previous = action.or(previous);
            }
            let indices: Vec<Option<usize>> =
                actions.iter().map(|a| a.map(|a| a as usize)).collect();
            self.set
                .push_episode(&observations, &indices, &rewards, true)?;
            for l in &approach.labels {
                *self
                    .frames
                    .entry(format!("{l:?}").to_lowercase())
                    .or_default() += 1;
            }
            self.approaches += 1;
        }
        Ok(())
    }
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
