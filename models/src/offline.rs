//! Offline learning from recorded driving: a fixed set of transitions (what a driver saw,
//! what they did, the task's reward for it, what they saw next) and no environment.
//!
//! Two algorithms on the same Q-network and the same [`Learner`] as online DQN:
//! - **discrete CQL** (Kumar et al. 2020, the CQL(H) loss for discrete actions): the
//!   (Double) DQN TD loss plus `alpha` × (logsumexp_a Q(s, a) − Q(s, a_data)). Plain
//!   Q-learning on a fixed dataset over-values the actions the data never took (nothing
//!   corrects their estimates); the penalty pushes those values down, so the greedy policy
//!   stays where the data gives evidence.
//! - **behaviour cloning**: the penalty term alone, i.e. the cross-entropy of softmax(Q) with
//!   the driver's action: the Q-network trained as a classifier of what the driver did.
//!
//! One iteration of [`train`]: sample a batch uniformly (with replacement, from the update's
//! own seed), one gradient step towards the [`Objective`], a hard target update every
//! `target_update_every` steps, a loss record every [`LOSS_WINDOW`] steps. The result is a
//! [`Checkpoint`] like online training's, so an offline agent is saved, evaluated in the
//! simulator and replayed against logs exactly as an online one.
//!
//! Determinism: the network from the seed, each batch from (seed, update index); the same
//! seed, data and config give the same network with any number of threads.

use burn::tensor::Device;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sim::seed::item_rng;
use sim::{Observation, ObservationSpec};

use crate::dqn::{AgentShape, Checkpoint, DqnConfig, Learner, LossRecord, Objective};
use crate::error::ModelError;
use crate::packed::PackedLayers;
use crate::qnet::{QNetwork, observations_to_tensors, tensor_values};
use crate::replay::Batch;

/// Gradient steps averaged into one loss record.
pub const LOSS_WINDOW: u64 = 100;
/// Seed stage of the batch draws.
const OFFLINE_SAMPLE_STAGE: u64 = 0x4f46_464c;

/// Which objective offline training minimises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OfflineAlgorithm {
    /// Discrete conservative Q-learning: TD loss + `conservative_weight` × penalty.
    Cql,
    /// Behaviour cloning: the cross-entropy of softmax(Q) with the driver's action.
    BehaviourCloning,
}

impl OfflineAlgorithm {
    /// The algorithm's name in messages: `CQL`, `behaviour cloning`.
    pub fn name(self) -> &'static str {
        match self {
            OfflineAlgorithm::Cql => "CQL",
            OfflineAlgorithm::BehaviourCloning => "behaviour cloning",
        }
    }
}

/// The settings of offline training beyond the network and optimiser's, which come from
/// [`DqnConfig`] (`network`, `double`, `gamma`, `loss`, `learning_rate`, `adam_epsilon`,
/// `gradient_clip_norm`, `batch_size`); TOML-loadable, every field defaulted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OfflineConfig {
    pub algorithm: OfflineAlgorithm,
    pub gradient_steps: u64,
    /// CQL's α: the weight of logsumexp_a Q(s, a) − Q(s, a_data) beside the TD loss.
    pub conservative_weight: f64,
    /// The target network is copied from the online one every this many gradient steps.
    pub target_update_every: u64,
}

impl Default for OfflineConfig {
    fn default() -> Self {
        OfflineConfig {
            algorithm: OfflineAlgorithm::Cql,
            gradient_steps: 20_000,
            conservative_weight: 1.0,
            target_update_every: 1_000,
        }
    }
}

impl OfflineConfig {
    pub fn validate(&self) -> Result<(), ModelError> {
        if self.gradient_steps == 0 || self.target_update_every == 0 {
            return Err(ModelError::Config(
                "offline: gradient_steps and target_update_every must be positive".into(),
            ));
        }
        if !(self.conservative_weight.is_finite() && self.conservative_weight >= 0.0) {
            return Err(ModelError::Config(
                "offline: conservative_weight must be a finite number ≥ 0".into(),
            ));
        }
        Ok(())
    }

    fn objective(&self) -> Objective {
        match self.algorithm {
            OfflineAlgorithm::Cql => Objective::Conservative {
                alpha: self.conservative_weight,
            },
            OfflineAlgorithm::BehaviourCloning => Objective::Imitation,
        }
    }
}

/// One recorded step: the observation (a frame of the set), the action taken, the reward,
/// and the next frame (None where the episode ended: nothing to bootstrap from).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Transition {
    frame: usize,
    action: usize,
    reward: f32,
    next: Option<usize>,
}

/// Recorded episodes as transitions; every observation stored once, run-length packed.
#[derive(Debug)]
pub struct TransitionSet {
    spec: ObservationSpec,
    actions: usize,
    layers: Vec<PackedLayers>,
    scalars: Vec<f32>,
    transitions: Vec<Transition>,
}

impl TransitionSet {
    pub fn new(spec: ObservationSpec, actions: usize) -> Self {
        TransitionSet {
            spec,
            actions,
            layers: Vec::new(),
            scalars: Vec::new(),
            transitions: Vec::new(),
        }
    }

    /// Adds an episode: its observations in order, and per observation the action taken
    /// there (None where it is not known: no transition starts at that frame, but it is
    /// still the successor of the one before) and the reward that followed. `ended`: the
    /// episode ended after its last observation (its last transition does not bootstrap);
    /// otherwise the recording stopped there and the last observation starts no transition.
    pub fn push_episode(
        &mut self,
        observations: &[Observation],
        actions: &[Option<usize>],
        rewards: &[f32],
        ended: bool,
    ) -> Result<(), ModelError> {
        let n = observations.len();
        if actions.len() != n || rewards.len() != n {
            return Err(ModelError::Config(format!(
                "an episode of {n} observations needs as many actions and rewards ({} and {} given)",
                actions.len(),
                rewards.len()
            )));
        }
        if let Some(a) = actions.iter().flatten().find(|&&a| a >= self.actions) {
            return Err(ModelError::Config(format!(
                "action {a} given, the task has {}",
                self.actions
            )));
        }
        let first = self.layers.len();
        for obs in observations {
            if obs.layers.len() != self.spec.layer_len() || obs.scalars.len() != self.spec.scalars {
                return Err(ModelError::Config(format!(
                    "an observation of {} layer bytes and {} scalars; the task's have {} and {}",
                    obs.layers.len(),
                    obs.scalars.len(),
                    self.spec.layer_len(),
                    self.spec.scalars
                )));
            }
            self.layers.push(PackedLayers::pack(&obs.layers));
            self.scalars.extend_from_slice(&obs.scalars);
        }
        for (i, (action, &reward)) in actions.iter().zip(rewards).enumerate() {
            let Some(action) = *action else { continue };
            let last = i + 1 == n;
            if last && !ended {
                continue;
            }
            self.transitions.push(Transition {
                frame: first + i,
                action,
                reward,
                next: (!last).then_some(first + i + 1),
            });
        }
        Ok(())
    }

    pub fn len(&self) -> usize {
        self.transitions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.transitions.is_empty()
    }

    /// Observations held (transitions' frames and successors).
    pub fn frames(&self) -> usize {
        self.layers.len()
    }

    /// How many transitions took each action.
    pub fn action_counts(&self) -> Vec<u64> {
        let mut counts = vec![0; self.actions];
        for t in &self.transitions {
            counts[t.action] += 1;
        }
        counts
    }

    /// The transitions `indices` as a batch for [`Learner::learn_with`] (one-step returns).
    fn batch(&self, indices: &[usize], gamma: f32) -> Batch {
        let (l, s) = (self.spec.layer_len(), self.spec.scalars);
        let size = indices.len();
        let chosen: Vec<Transition> = indices.iter().map(|&i| self.transitions[i]).collect();
        let mut batch = Batch {
            size,
            layers: vec![0.0; size * l],
            scalars: vec![0.0; size * s],
            actions: chosen.iter().map(|t| t.action).collect(),
            returns: chosen.iter().map(|t| t.reward).collect(),
            discounts: chosen
                .iter()
                .map(|t| if t.next.is_some() { gamma } else { 0.0 })
                .collect(),
            next_layers: vec![0.0; size * l],
            next_scalars: vec![0.0; size * s],
            weights: vec![1.0; size],
            leaves: indices.to_vec(),
        };
        for (i, t) in chosen.iter().enumerate() {
            batch.scalars[i * s..(i + 1) * s]
                .copy_from_slice(&self.scalars[t.frame * s..(t.frame + 1) * s]);
            if let Some(next) = t.next {
                batch.next_scalars[i * s..(i + 1) * s]
                    .copy_from_slice(&self.scalars[next * s..(next + 1) * s]);
            }
        }
        if l > 0 {
            batch
                .layers
                .par_chunks_mut(l)
                .zip(chosen.par_iter())
                .for_each(|(out, t)| self.layers[t.frame].unpack_scaled(out));
            batch
                .next_layers
                .par_chunks_mut(l)
                .zip(chosen.par_iter())
                .for_each(|(out, t)| {
                    if let Some(next) = t.next {
                        self.layers[next].unpack_scaled(out);
                    }
                });
        }
        batch
    }

    /// The observation of frame `frame`.
    fn observation(&self, frame: usize) -> Observation {
        let s = self.spec.scalars;
        Observation {
            layers: self.layers[frame].unpack(),
            scalars: self.scalars[frame * s..(frame + 1) * s].to_vec(),
        }
    }

    /// Share of the transitions whose action is `network`'s greedy one, in batches of 256.
    pub fn agreement(&self, network: &QNetwork, device: &Device) -> f64 {
        if self.transitions.is_empty() {
            return 0.0;
        }
        let mut agree = 0usize;
        for chunk in self.transitions.chunks(256) {
            let observations: Vec<Observation> =
                chunk.iter().map(|t| self.observation(t.frame)).collect();
            let refs: Vec<&Observation> = observations.iter().collect();
            let (layers, scalars) = observations_to_tensors(&refs, &self.spec, device);
            let q = tensor_values(network.forward(layers, scalars));
            agree += chunk
                .iter()
                .zip(q.chunks_exact(self.actions))
                .filter(|(t, q)| crate::dqn::greedy_action(q) == t.action)
                .count();
        }
        agree as f64 / self.transitions.len() as f64
    }
}

/// A point of the training curves: means over [`LOSS_WINDOW`] gradient steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OfflineRecord {
    pub updates: u64,
    pub loss: f64,
    /// The TD part (CQL).
    pub td_loss: Option<f64>,
    /// logsumexp_a Q(s, a) − Q(s, a_data): CQL's penalty, behaviour cloning's loss.
    pub regulariser: f64,
    pub mean_q: f64,
}

/// What an offline run did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OfflineSummary {
    pub transitions: usize,
    pub frames: usize,
    /// Transitions per action.
    pub action_counts: Vec<u64>,
    pub gradient_steps: u64,
    /// Share of the training transitions whose action the trained network picks.
    pub train_agreement: f64,
    pub curve: Vec<OfflineRecord>,
}

/// Trains a Q-network on `set` for `offline.gradient_steps` steps; `progress` hears every
/// loss record and may stop the run by returning false. Returns the final checkpoint (its
/// `state.steps` is 0: no environment transitions) and the summary.
pub fn train(
    set: &TransitionSet,
    dqn: &DqnConfig,
    offline: &OfflineConfig,
    seed: u64,
    device: &Device,
    progress: &mut dyn FnMut(&OfflineRecord) -> bool,
) -> Result<(Checkpoint, OfflineSummary), ModelError> {
    offline.validate()?;
    if set.is_empty() || dqn.batch_size == 0 {
        return Err(ModelError::Config(format!(
            "offline training needs transitions and a positive batch size ({} transitions, batch {})",
            set.len(),
            dqn.batch_size
        )));
    }
    if dqn.learning_rate_end.is_some() {
        // The fall is counted in environment transitions, and offline training has none.
        return Err(ModelError::Config(
            "offline training keeps the learning rate constant: remove learning_rate_end from [agent.dqn]"
                .into(),
        ));
    }
    let shape = AgentShape {
        channels: set.spec.channels,
        height: set.spec.height,
        width: set.spec.width,
        scalars: set.spec.scalars,
        actions: set.actions,
    };
    let mut learner = Learner::new(dqn, &shape, seed, device)?;
    let objective = offline.objective();
    let mut curve = Vec::new();
    let mut window = Vec::with_capacity(LOSS_WINDOW as usize);
    for update in 0..offline.gradient_steps {
        let mut rng = item_rng(seed, OFFLINE_SAMPLE_STAGE, update);
        let indices: Vec<usize> = (0..dqn.batch_size)
            .map(|_| rand::Rng::random_range(&mut rng, 0..set.len()))
            .collect();
        window.push(learner.learn_with(set.batch(&indices, dqn.gamma), objective));
        let updates = update + 1;
        if updates % offline.target_update_every == 0 {
            learner.sync_target();
        }
        if window.len() as u64 == LOSS_WINDOW || updates == offline.gradient_steps {
            let n = window.len() as f64;
            let mean =
                |f: &dyn Fn(&crate::dqn::LearnStep) -> f64| window.iter().map(f).sum::<f64>() / n;
            let record = OfflineRecord {
                updates,
                loss: mean(&|s| s.loss),
                td_loss: window
                    .iter()
                    .all(|s| s.td_loss.is_some())
                    .then(|| mean(&|s| s.td_loss.unwrap_or(0.0))),
                regulariser: mean(&|s| s.regulariser.unwrap_or(0.0)),
                mean_q: mean(&|s| s.mean_q),
            };
            window.clear();
            let state = learner.state_mut();
            state.updates = updates;
            state.loss_history.push(LossRecord {
                step: 0,
                updates,
                td_loss: record.loss,
                mean_q: record.mean_q,
            });
            let go_on = progress(&record);
            curve.push(record);
            if !go_on {
                break;
            }
        }
    }
    let checkpoint = learner.checkpoint(dqn, &shape);
    let summary = OfflineSummary {
        transitions: set.len(),
        frames: set.frames(),
        action_counts: set.action_counts(),
        gradient_steps: checkpoint.state.updates,
        train_agreement: set.agreement(&checkpoint.online, device),
        curve,
    };
    Ok((checkpoint, summary))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::qnet::QNetworkConfig;

    fn spec() -> ObservationSpec {
        ObservationSpec {
            channels: 1,
            height: 2,
            width: 2,
            scalars: 2,
        }
    }

    fn observation(x: f32) -> Observation {
        Observation {
            layers: vec![(x * 200.0) as u8; 4],
            scalars: vec![x, 1.0 - x],
        }
    }

    /// Episodes of a chain where the "driver" takes action 1 when x > 0.5 and action 0
    /// otherwise; the reward pays for exactly that.
    fn chain_set() -> TransitionSet {
        let mut set = TransitionSet::new(spec(), 2);
        let mut rng = item_rng(5, 1, 0);
        for _ in 0..40 {
            let xs: Vec<f32> = (0..6).map(|_| rand::Rng::random::<f32>(&mut rng)).collect();
            let observations: Vec<Observation> = xs.iter().map(|&x| observation(x)).collect();
            let actions: Vec<Option<usize>> =
                xs.iter().map(|&x| Some(usize::from(x > 0.5))).collect();
            let rewards = vec![0.1; xs.len()];
            set.push_episode(&observations, &actions, &rewards, true)
                .unwrap_or_else(|e| panic!("{e}"));
        }
        set
    }

    fn config() -> DqnConfig {
        DqnConfig {
            network: QNetworkConfig {
                convolutions: Vec::new(),
                scalar_hidden: 0,
                hidden: vec![32],
                ..QNetworkConfig::default()
            },
            batch_size: 32,
            learning_rate: 3e-3,
            gamma: 0.9,
            ..DqnConfig::default()
        }
    }

    #[test]
    fn an_episode_s_transitions_follow_its_frames_and_skip_unknown_actions() {
        let mut set = TransitionSet::new(spec(), 2);
        let obs: Vec<Observation> = [0.1, 0.2, 0.3, 0.4].map(observation).to_vec();
        set.push_episode(&obs, &[Some(0), None, Some(1), Some(1)], &[1.0; 4], true)
            .unwrap_or_else(|e| panic!("{e}"));
        // A recording cut short: its last frame starts no transition.
        set.push_episode(&obs[..2], &[Some(1), Some(0)], &[0.5; 2], false)
            .unwrap_or_else(|e| panic!("{e}"));
        let next: Vec<Option<usize>> = set.transitions.iter().map(|t| t.next).collect();
        assert_eq!(next, [Some(1), Some(3), None, Some(5)]);
        assert_eq!(set.action_counts(), [1, 3]);
        assert_eq!(set.frames(), 6);
        let batch = set.batch(&[0, 2], 0.9);
        assert_eq!(batch.discounts, [0.9, 0.0]);
        assert_eq!(batch.scalars, [0.1, 0.9, 0.4, 0.6]);
        assert!(
            set.push_episode(&obs, &[Some(2); 4], &[0.0; 4], true)
                .is_err()
        );
        assert!(set.push_episode(&obs, &[Some(0)], &[0.0], true).is_err());
    }

    #[test]
    fn cql_and_behaviour_cloning_learn_the_driver_s_choice_deterministically()
    -> Result<(), ModelError> {
        let set = chain_set();
        let device = crate::cpu_device();
        for algorithm in [OfflineAlgorithm::Cql, OfflineAlgorithm::BehaviourCloning] {
            let offline = OfflineConfig {
                algorithm,
                gradient_steps: 400,
                target_update_every: 50,
                ..OfflineConfig::default()
            };
            let (checkpoint, summary) =
                train(&set, &config(), &offline, 3, &device, &mut |_| true)?;
            assert!(summary.train_agreement > 0.9, "{algorithm:?}: {summary:?}");
            assert_eq!(summary.gradient_steps, 400);
            assert_eq!(summary.curve.len(), 4);
            assert_eq!(
                summary.curve[0].td_loss.is_some(),
                algorithm == OfflineAlgorithm::Cql
            );
            let first = summary.curve[0].regulariser;
            let last = summary.curve[3].regulariser;
            assert!(last < first, "{algorithm:?}: {first} → {last}");
            // Same seed, same network.
            let (again, _) = train(&set, &config(), &offline, 3, &device, &mut |_| true)?;
            let probe = [observation(0.8)];
            let refs: Vec<&Observation> = probe.iter().collect();
            let q = |n: &QNetwork| {
                let (l, s) = observations_to_tensors(&refs, &set.spec, &device);
                tensor_values(n.forward(l, s))
            };
            assert_eq!(q(&checkpoint.online), q(&again.online));
        }
        Ok(())
    }

    #[test]
    fn the_observer_can_stop_a_run_and_bad_settings_are_refused() -> Result<(), ModelError> {
        let set = chain_set();
        let device = crate::cpu_device();
        let offline = OfflineConfig {
            gradient_steps: 1_000,
            ..OfflineConfig::default()
        };
        let (checkpoint, summary) = train(&set, &config(), &offline, 1, &device, &mut |r| {
            r.updates < 200
        })?;
        assert_eq!(checkpoint.state.updates, 200);
        assert_eq!(summary.curve.len(), 2);
        let empty = TransitionSet::new(spec(), 2);
        assert!(train(&empty, &config(), &offline, 1, &device, &mut |_| true).is_err());
        let bad = OfflineConfig {
            conservative_weight: -1.0,
            ..OfflineConfig::default()
        };
        assert!(train(&set, &config(), &bad, 1, &device, &mut |_| true).is_err());
        let falling_rate = DqnConfig {
            learning_rate_end: Some(1e-5),
            ..config()
        };
        assert!(train(&set, &falling_rate, &offline, 1, &device, &mut |_| true).is_err());
        Ok(())
    }
}
