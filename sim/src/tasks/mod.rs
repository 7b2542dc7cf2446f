//! Driving tasks: actions, reward, termination, metrics and baselines on the traffic world.
//!
//! Every task implements [`Task`]: a [`Driving`] (what differs between tasks in an episode:
//! its actions, how an episode begins, what one decision does and earns, what the agent
//! observes, the episode's figures), run as an [`Env`] by the one episode runner
//! ([`runner`]), with its settings table, its setup ([`TaskSetup`]: prepared once per map
//! and shared by its environments), its evaluation conditions and its baselines. The
//! registry ([`registry`]) lists them by name; the one evaluation harness ([`crate::eval`])
//! runs any of them with any [`TaskPolicy`]: a learned policy (reading only the
//! observations), a [`ConstantAction`], or a task's own rule.
//!
//! - [`insertion`]: roundabout insertion (its evaluation: [`crate::eval::insertion`]);
//!   [`ring_driving`]: roundabout driving; [`route`]: campus route following;
//!   [`obstacle`]: obstacle avoidance. Each folder holds what is the task's own, by
//!   concern: its settings (`config.rs`), its episodes (`mod.rs`), its [`Task`] items
//!   (`task.rs`), and for insertion its reward (`reward.rs`).
//! - What they share: [`runner`] (the episode runner), [`episode`] (the bookkeeping of an
//!   episode), `actions!` (action tables), [`roundabouts`] (the prepared roundabouts and
//!   the ego's view of the roundabout tasks), [`motion_inputs`], [`id`] (the tasks' names).

/// Declares a task's actions: an enum indexed from 0 with `ALL`, `NAMES` (the serde names,
/// as written in files and recordings) and `from_index`, and its [`runner::ActionSet`] with
/// the action an index out of range means (`fallback`).
macro_rules! actions {
    (
        $(#[$meta:meta])*
        $vis:vis enum $name:ident {
            $($(#[$variant_meta:meta])* $variant:ident = $index:literal => $label:literal,)+
        }
        fallback $fallback:ident;
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
        $vis enum $name {
            $($(#[$variant_meta])* #[serde(rename = $label)] $variant = $index,)+
        }

        impl $name {
            pub const ALL: [$name; [$($label),+].len()] = [$($name::$variant),+];
            pub const NAMES: [&'static str; [$($label),+].len()] = [$($label),+];

            pub fn from_index(i: usize) -> Option<$name> {
                $name::ALL.get(i).copied()
            }
        }

        impl $crate::tasks::runner::ActionSet for $name {
            const NAMES: &'static [&'static str] = &$name::NAMES;
            const FALLBACK: $name = $name::$fallback;

            fn from_index(i: usize) -> Option<$name> {
                $name::from_index(i)
            }
        }
    };
}

/// [`runner::Driving::episode`] and [`runner::Driving::episode_mut`] of a task that keeps its episode in
/// its `episode` field.
macro_rules! episode_in_field {
    () => {
        fn episode(&self) -> &$crate::tasks::Episode {
            &self.episode
        }

        fn episode_mut(&mut self) -> &mut $crate::tasks::Episode {
            &mut self.episode
        }
    };
}

/// [`TaskSummary::outcome`] and [`TaskSummary::episode_return`] of a summary that keeps them
/// in its `outcome` and `episode_return` fields.
macro_rules! outcome_and_return_fields {
    () => {
        fn outcome(&self) -> $crate::env::Outcome {
            self.outcome
        }

        fn episode_return(&self) -> f64 {
            self.episode_return
        }
    };
}

/// The accessors of [`roundabouts::RoundaboutTaskConfig`] for settings that keep them in
/// their `layout`, `observation` (the bird's-eye view), `traffic` and `roundabout` fields.
macro_rules! roundabout_fields {
    () => {
        fn layout(&self) -> &$crate::roundabout::LayoutConfig {
            &self.layout
        }

        fn bev(&self) -> &$crate::render::BevConfig {
            &self.observation
        }

        fn roundabout(&self) -> Option<maps::RoundaboutId> {
            self.roundabout.map(maps::RoundaboutId)
        }

        fn world_mut(
            &mut self,
        ) -> (
            &mut $crate::world::TrafficConfig,
            &mut $crate::roundabout::LayoutConfig,
        ) {
            (&mut self.traffic, &mut self.layout)
        }

        fn roundabout_mut(&mut self) -> &mut Option<u32> {
            &mut self.roundabout
        }
    };
}

pub mod episode;
pub mod id;
pub mod insertion;
pub mod motion_inputs;
pub mod obstacle;
pub mod registry;
pub mod ring_driving;
pub mod roundabouts;
pub mod route;
pub mod runner;
pub mod tables;

use std::fmt::Debug;
use std::sync::Arc;

use serde::Serialize;
use serde::de::DeserializeOwned;

use maps::{Map, Point};

use crate::env::{Env, Observation};
use crate::error::SimError;
use crate::eval::report::{EvalHeader, EvalReport, Evaluation, conditions_report};
use crate::observer::{CameraViewConfig, SceneObserver};
use crate::scene::Scene;
use crate::world::{CalibratedWorld, TrafficLevel};

pub use crate::eval::report::TaskSummary;
pub use episode::Episode;
pub use insertion::{
    Action, EpisodeSummary, InsertionConfig, InsertionSetup, InsertionState, RewardConfig,
    RoundaboutInsertion,
};
pub use obstacle::{ObstacleAvoidance, ObstacleConfig, ObstacleSetup, ObstacleSummary};
pub use registry::{TASKS, TaskId, TaskInfo, TaskVisitor};
pub use ring_driving::{
    PursuitRule, RingDriving, RingDrivingConfig, RingDrivingSetup, RingDrivingSummary,
    RingRewardConfig, SteerAction,
};
pub use roundabouts::{EgoView, RoundaboutSet, RoundaboutSetup, RoundaboutTaskConfig, ego_scene};
pub use runner::{ActionSet, Driving};
pub use tables::{Tables, TablesMut};

/// A driving task: an [`Env`] with everything training and evaluating an agent on it needs.
pub trait Task: Driving + Env + Sized + 'static {
    /// The task's `[agent.<table>]` settings, stored in an agent's `task.json`.
    type Config: Clone + Debug + Default + Serialize + DeserializeOwned + Send + Sync + 'static;
    /// What is prepared once (map, layouts, renderers) and shared by every environment.
    type Setup: TaskSetup<Config = Self::Config>;
    /// One evaluation condition: a traffic level, a route split, an obstacle scenario, ...
    type Condition: Clone + Debug + Send + Sync;

    /// The task's entry in the registry.
    const ID: TaskId;

    /// This task's table among every task's settings.
    fn table<'a>(tables: Tables<'a>) -> &'a Self::Config;

    /// This task's table among every task's settings, to change in place.
    fn table_mut<'a>(tables: TablesMut<'a>) -> &'a mut Self::Config;

    /// Prepares the task on `map` (None for a task that makes its own road), with the
    /// observer that draws a camera view's layers (see [`Task::camera_view`]).
    fn setup(
        map: Option<Arc<Map>>,
        config: Self::Config,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self::Setup>, SimError> {
        Self::Setup::prepare(map, config, observer)
    }

    /// The map the task drives on.
    fn map(setup: &Self::Setup) -> &Map {
        setup.map()
    }

    /// The roundabouts of the map the task runs on (their ids, as `map info` lists them);
    /// empty for a task that runs on no roundabout.
    fn roundabouts(setup: &Self::Setup) -> Vec<u32> {
        setup.roundabouts()
    }

    /// The camera table of `config` when it asks for `view = "camera-segmentation"`: what
    /// the observer given to [`Task::setup`] is built from. None by default (no camera view).
    fn camera_view(_config: &Self::Config) -> Option<&CameraViewConfig> {
        None
    }

    /// The camera table of `config`, to change in place (e.g. its segmenter folder).
    fn camera_mut(_config: &mut Self::Config) -> Option<&mut CameraViewConfig> {
        None
    }

    /// The task deciding every `steps` world steps on frames stacked as with `config`; None
    /// when the task does not hold its actions over world steps.
    fn deciding_every(_config: &Self::Config, _steps: usize) -> Option<Self::Config> {
        None
    }

    /// The task on roundabout `id` of the map only; None when the task does not run on a
    /// roundabout.
    fn on_roundabout(_config: &Self::Config, _id: u32) -> Option<Self::Config> {
        None
    }

    /// The task in the traffic world `world` (a calibration's, replacing what the config
    /// gives of its own): how a calibrated world reaches the task for training and for
    /// evaluation alike. None when the task runs no traffic world.
    fn in_world(_config: &Self::Config, _world: &CalibratedWorld) -> Option<Self::Config> {
        None
    }

    /// One environment of a training run at `traffic`.
    fn training_env(setup: &Arc<Self::Setup>, traffic: TrafficLevel) -> Self;

    /// One environment under `condition`.
    fn env(setup: &Arc<Self::Setup>, condition: &Self::Condition) -> Self;

    /// The evaluation conditions `choice` asks for (its empty lists: the task's defaults).
    fn conditions(choice: &ConditionChoice) -> Vec<Self::Condition>;

    /// What tables and reports call `condition`.
    fn condition_name(condition: &Self::Condition) -> String;

    /// The conditions a training run at `traffic` validates its checkpoints on, by name;
    /// never conditions held out for evaluation.
    fn validation_conditions(traffic: TrafficLevel) -> Vec<(String, Self::Condition)>;

    /// The condition of the greedy episodes a training run at `traffic` records.
    fn recorded_condition(traffic: TrafficLevel) -> Self::Condition;

    /// The condition of the greedy episodes an evaluation of `conditions` records: the
    /// first.
    fn recorded_eval_condition(conditions: &[Self::Condition]) -> Self::Condition {
        conditions
            .first()
            .cloned()
            .unwrap_or_else(|| Self::recorded_condition(TrafficLevel::Medium))
    }

    /// The files of an evaluation: by default a table of [`crate::eval::report::TaskResult`]s per
    /// condition.
    fn eval_report(
        header: &EvalHeader,
        evaluation: &Evaluation<Self::Condition, Self::Summary>,
    ) -> Result<EvalReport, SimError> {
        conditions_report(header, evaluation, Self::condition_name)
    }

    /// The baselines every agent of the task is reported next to: one per constant action,
    /// then the task's rules, by name.
    fn baselines() -> Vec<(String, PolicyFactory<Self>)>;

    /// The baselines on `setup`: [`Task::baselines`], and any the setup's world adds (a
    /// calibrated world's critical-gap rule).
    fn setup_baselines(_setup: &Self::Setup) -> Vec<(String, PolicyFactory<Self>)> {
        Self::baselines()
    }

    /// The current scene, for pictures and the rerun recording (None before a reset).
    fn scene(&self) -> Option<Scene<'_>>;

    /// The ego's path so far in this episode.
    fn trajectory(&self) -> &[Point] {
        &self.episode().trajectory
    }

    /// Turns drawing the layers on or off (off: observations carry empty layers; the
    /// episodes themselves do not change).
    fn set_rendering(&mut self, _on: bool) {}

    /// The newest frame of layers the recording shows of an episode, if any.
    fn recorded_layers(&self) -> Option<LayerFrame<'_>> {
        None
    }
}

/// What a task prepares once (map, layouts, renderers) and shares with every environment.
pub trait TaskSetup: Debug + Send + Sync + 'static {
    /// The task's settings.
    type Config;

    /// Prepares the task on `map` (None for a task that makes its own road), with the
    /// observer that draws a camera view's layers.
    fn prepare(
        map: Option<Arc<Map>>,
        config: Self::Config,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self>, SimError>;

    /// The map the task drives on.
    fn map(&self) -> &Map;

    /// The roundabouts of the map the task runs on (their ids); empty for none.
    fn roundabouts(&self) -> Vec<u32> {
        Vec::new()
    }
}

/// The evaluation conditions asked for (`agent eval --traffic` and `--aggressiveness`);
/// empty lists ask for the task's defaults, and a task reads only what it has conditions of.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ConditionChoice {
    pub traffic: Vec<TrafficLevel>,
    pub aggressiveness: Vec<f64>,
}

impl ConditionChoice {
    /// The traffic levels asked for, or every level.
    pub fn traffic_levels(&self) -> Vec<TrafficLevel> {
        if self.traffic.is_empty() {
            TrafficLevel::ALL.to_vec()
        } else {
            self.traffic.clone()
        }
    }
}

/// One frame of bird's-eye layers, as the recording logs it.
#[derive(Debug, Clone, Copy)]
pub struct LayerFrame<'a> {
    /// `[layer, row, column]`.
    pub layers: &'a [u8],
    pub names: &'a [crate::render::Layer],
    pub width: usize,
    pub height: usize,
}

/// Makes one policy instance per chunk of episodes (policies are `Send`, not `Sync`).
pub type PolicyFactory<E> = Box<dyn Fn() -> Box<dyn TaskPolicy<E>> + Send + Sync>;

/// The [`PolicyFactory`] of each constant action of `E`.
pub fn constant_baselines<E: Task>(action_names: &[&str]) -> Vec<(String, PolicyFactory<E>)> {
    action_names
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let make: PolicyFactory<E> = Box::new(move || Box::new(ConstantAction(i)));
            (format!("always {}", name.replace('_', " ")), make)
        })
        .collect()
}

/// A decision rule for a batch of episodes of task `E`, stepped side by side so a network
/// runs one forward pass per step. A learned policy must read only `observations`; rules
/// may read the environments' privileged state.
pub trait TaskPolicy<E>: Send {
    /// One action per environment, in order, into `actions` (cleared first).
    fn act(&mut self, envs: &[&E], observations: &[&Observation], actions: &mut Vec<usize>);

    /// As [`TaskPolicy::act`], told each environment's place in the policy's batch (stable
    /// over its episode): what the harness calls. By default, `act`.
    fn act_in_slots(
        &mut self,
        _slots: &[usize],
        envs: &[&E],
        observations: &[&Observation],
        actions: &mut Vec<usize>,
    ) {
        self.act(envs, observations, actions);
    }

    /// Whether the policy reads observations; when it does not, the harness turns the
    /// environments' rendering off (the episodes are the same either way).
    fn needs_observation(&self) -> bool {
        true
    }
}

impl<E> TaskPolicy<E> for Box<dyn TaskPolicy<E>> {
    fn act(&mut self, envs: &[&E], observations: &[&Observation], actions: &mut Vec<usize>) {
        (**self).act(envs, observations, actions);
    }

    fn act_in_slots(
        &mut self,
        slots: &[usize],
        envs: &[&E],
        observations: &[&Observation],
        actions: &mut Vec<usize>,
    ) {
        (**self).act_in_slots(slots, envs, observations, actions);
    }

    fn needs_observation(&self) -> bool {
        (**self).needs_observation()
    }
}

/// The same action at every step: the constant-action baselines.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConstantAction(pub usize);

impl<E> TaskPolicy<E> for ConstantAction {
    fn act(&mut self, envs: &[&E], _: &[&Observation], actions: &mut Vec<usize>) {
        actions.clear();
        actions.resize(envs.len(), self.0);
    }
}

/// The map task `task` drives on, or the error of a task that needs one given none.
pub(crate) fn required_map(map: Option<Arc<Map>>, task: TaskId) -> Result<Arc<Map>, SimError> {
    map.ok_or_else(|| SimError::Map(format!("{} needs a map", task.info().title)))
}

/// `actions` (cleared first) with `decide`'s action for each environment: a rule's
/// [`TaskPolicy::act`].
pub(crate) fn act_each<E>(envs: &[&E], actions: &mut Vec<usize>, decide: impl Fn(&E) -> usize) {
    actions.clear();
    actions.extend(envs.iter().map(|env| decide(env)));
}

/// What a steering rule picks for the wheel angle `wanted` (positive to the left) with the
/// band `(low, high)` kept: `[left, straight, right]`'s first above the band, third below,
/// second within.
pub(crate) fn turn<A>(wanted: f64, (low, high): (f64, f64), [left, straight, right]: [A; 3]) -> A {
    if wanted > high {
        left
    } else if wanted < low {
        right
    } else {
        straight
    }
}

/// Fails with the first of `values` (settings by name) that is not a positive number.
pub(crate) fn check_positive(values: &[(&str, f64)]) -> Result<(), SimError> {
    match values.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        Some((name, v)) => Err(SimError::Config(format!("{name} = {v} must be positive"))),
        None => Ok(()),
    }
}

/// The constant baselines of `action_names`, then the task's rule `R`, named `rule_name`.
pub fn baselines_with_rule<E: Task, R: TaskPolicy<E> + Default + 'static>(
    action_names: &[&str],
    rule_name: &str,
) -> Vec<(String, PolicyFactory<E>)> {
    let mut all = constant_baselines::<E>(action_names);
    let rule: PolicyFactory<E> = Box::new(|| Box::new(R::default()));
    all.push((rule_name.to_owned(), rule));
    all
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn action_names_are_their_serde_names_in_index_order() {
        fn check<A: Serialize + Copy>(all: &[A], names: &[&str], index: impl Fn(A) -> usize) {
            assert_eq!(all.len(), names.len());
            for (i, (&action, name)) in all.iter().zip(names).enumerate() {
                assert_eq!(serde_json::to_value(action).unwrap(), *name);
                assert_eq!(index(action), i);
            }
        }
        check(&Action::ALL, &Action::NAMES, |a| a as usize);
        check(&SteerAction::ALL, &SteerAction::NAMES, |a| a as usize);
        let obstacle = obstacle::Action::ALL;
        check(&obstacle, &obstacle::Action::NAMES, |a| a as usize);
        assert_eq!(Action::from_index(2), Some(Action::Caution));
        assert_eq!(SteerAction::from_index(3), None);
    }
}
