//! DQN (Mnih et al. 2015) and Double DQN (van Hasselt et al. 2016), CleanRL style: every
//! hyper-parameter in [`DqnConfig`], and [`train`] reads top to bottom as the algorithm.
//!
//! One iteration of [`train`]:
//!
//! 1. **act** — one batched forward pass of the online network over the current observation
//!    of every environment; ε-greedy per environment ([`EpsilonSchedule`]);
//! 2. **step and learn at the same time** — the environments step in parallel (rayon) while
//!    the learner does its gradient steps on batches sampled from the replay buffer
//!    (`envs / train_frequency` of them per iteration, after the warm-up);
//! 3. **remember** — the transitions go into the [`ReplayBuffer`] (n-step returns, optional
//!    prioritised replay);
//! 4. **target network** — copied every `every_steps` transitions (hard) or blended after
//!    every gradient step (soft, τ);
//! 5. **record** — episodes and TD losses go to the [`TrainObserver`] and the history;
//!    a [`Checkpoint`] every `checkpoint_every` transitions.
//!
//! The gradient step: `y = Rⁿ + γⁿ·Q_target(s', a*)` with `a* = argmax Q_online(s', ·)`
//! (Double) or `argmax Q_target(s', ·)` (DQN) and no bootstrap where the episode ended
//! ([`td_targets`]); loss = mean of importance weight × Huber (or squared) TD error; Adam.
//!
//! Determinism: every random draw is derived from (seed, stage, counter) — the networks'
//! initial parameters, each environment's episodes, each ε-greedy choice (by transition
//! index), each replay sample (by gradient-step index) — so the same seed and config give
//! the same run with any number of threads.
//!
//! Resuming: a [`Checkpoint`] holds both networks, Adam's state, the counters and the
//! training curves, but not the replay buffer (hundreds of megabytes) nor the environments'
//! in-flight episodes (the [`Env`] trait has no snapshot). A resumed run restarts each
//! environment's interrupted episode from its seed and refills the replay buffer for
//! `warmup_steps` transitions before learning again, so it is deterministic but not
//! identical to an uninterrupted run.

use crate::run_folder::write_json;
use std::path::Path;

use burn::module::Module;
use burn::nn::loss::HuberLossConfig;
use burn::optim::grad_clipping::GradientClippingConfig;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::store::ModuleRecord;
use burn::tensor::{Device, Int, Tensor, TensorData};
use rand::Rng;
use serde::{Deserialize, Serialize};
use sim::seed::item_rng;

use crate::averaging::blend;
use sim::{Env, Observation, ObservationSpec, Outcome};

use crate::error::ModelError;
use crate::qnet::{
    QNetwork, QNetworkConfig, batch_tensors, observations_to_tensors, tensor_values,
};
use crate::replay::{Batch, ReplayBuffer, ReplayOptions};
use crate::vec_env::VecEnv;

/// Every hyper-parameter of a training run; TOML-loadable, every field defaulted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DqnConfig {
    /// Environment transitions to train for (all environments together).
    pub total_steps: u64,
    /// Environments stepped side by side.
    pub envs: usize,
    pub network: QNetworkConfig,
    /// Double DQN: the online network picks the next action, the target network values it.
    pub double: bool,
    /// Rewards summed before bootstrapping (1 = one-step TD).
    pub n_step: usize,
    pub gamma: f32,
    pub loss: TdLoss,
    pub learning_rate: f64,
    /// When set, the learning rate falls linearly from `learning_rate` to this over the
    /// run's `total_steps` transitions, so the late checkpoints move less; unset, it stays at
    /// `learning_rate`. Online training only (offline training refuses it).
    pub learning_rate_end: Option<f64>,
    pub adam_epsilon: f32,
    /// Each parameter tensor's gradient is scaled down to at most this L2 norm (burn's
    /// per-tensor clipping); 0 turns clipping off.
    pub gradient_clip_norm: f32,
    pub batch_size: usize,
    /// Transitions the replay buffer keeps.
    pub replay_capacity: usize,
    /// Transitions collected before the first gradient step (again after a resume).
    pub warmup_steps: u64,
    /// Environment transitions per gradient step.
    pub train_frequency: usize,
    pub target_update: TargetUpdate,
    pub prioritized_replay: PrioritizedReplay,
    pub epsilon: EpsilonSchedule,
    /// A checkpoint every this many transitions (0: only at the end).
    pub checkpoint_every: u64,
}

impl Default for DqnConfig {
    fn default() -> Self {
        DqnConfig {
            total_steps: 300_000,
            envs: 8,
            network: QNetworkConfig::default(),
            double: true,
            n_step: 3,
            gamma: 0.99,
            loss: TdLoss::Huber { delta: 1.0 },
            learning_rate: 1e-4,
            learning_rate_end: None,
            adam_epsilon: 1e-8,
            gradient_clip_norm: 10.0,
            batch_size: 32,
            replay_capacity: 100_000,
            warmup_steps: 5_000,
            train_frequency: 4,
            target_update: TargetUpdate::Hard { every_steps: 4_000 },
            prioritized_replay: PrioritizedReplay::default(),
            epsilon: EpsilonSchedule::Linear {
                start: 1.0,
                end: 0.05,
                steps: 100_000,
            },
            checkpoint_every: 25_000,
        }
    }
}

/// The per-sample loss on the TD error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum TdLoss {
    /// Quadratic within ±delta, linear outside (PyTorch's `smooth_l1_loss` for delta = 1).
    Huber { delta: f32 },
    /// Squared error.
    Mse,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum TargetUpdate {
    /// Copy the online network every this many transitions.
    Hard { every_steps: u64 },
    /// After every gradient step: target ← τ·online + (1 − τ)·target.
    Soft { tau: f64 },
}

/// Prioritised experience replay (Schaul et al. 2016), proportional variant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PrioritizedReplay {
    pub enabled: bool,
    /// Priority exponent: 0 is uniform.
    pub alpha: f32,
    /// Importance-sampling exponent, annealed linearly from start to end over the run.
    pub beta_start: f32,
    pub beta_end: f32,
    /// Added to |TD error| so no transition gets priority 0.
    pub epsilon: f32,
}

impl Default for PrioritizedReplay {
    fn default() -> Self {
        PrioritizedReplay {
            enabled: false,
            alpha: 0.6,
            beta_start: 0.4,
            beta_end: 1.0,
            epsilon: 1e-3,
        }
    }
}

/// The exploration rate over a run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum EpsilonSchedule {
    /// From `start` to `end` linearly over the first `steps` transitions (CleanRL).
    Linear { start: f64, end: f64, steps: u64 },
    /// Multiplied by `decay` every transition, down to `end` (the AIT study: 0.99999).
    PerStep { start: f64, end: f64, decay: f64 },
    /// Multiplied by `decay` every finished episode, down to `end` (the ITS study: 1 → 0.1
    /// by 0.9995).
    PerEpisode { start: f64, end: f64, decay: f64 },
}

impl EpsilonSchedule {
    /// The ITS study's schedule.
    pub const ITS: EpsilonSchedule = EpsilonSchedule::PerEpisode {
        start: 1.0,
        end: 0.1,
        decay: 0.9995,
    };
    /// The AIT study's schedule.
    pub const AIT: EpsilonSchedule = EpsilonSchedule::PerStep {
        start: 1.0,
        end: 0.1,
        decay: 0.99999,
    };

    /// ε after `steps` transitions and `episodes` finished episodes.
    pub fn value(&self, steps: u64, episodes: u64) -> f64 {
        match *self {
            EpsilonSchedule::Linear {
                start,
                end,
                steps: span,
            } => {
                let progress = if span == 0 {
                    1.0
                } else {
                    (steps as f64 / span as f64).min(1.0)
                };
                start + (end - start) * progress
            }
            EpsilonSchedule::PerStep { start, end, decay } => {
                (start * decay.powf(steps as f64)).max(end)
            }
            EpsilonSchedule::PerEpisode { start, end, decay } => {
                (start * decay.powf(episodes as f64)).max(end)
            }
        }
    }
}

impl DqnConfig {
    /// The learning rate after `steps` transitions: `learning_rate`, or the linear fall to
    /// `learning_rate_end` over `total_steps` (held at the end value after them).
    pub fn learning_rate_at(&self, steps: u64) -> f64 {
        match self.learning_rate_end {
            None => self.learning_rate,
            Some(end) => {
                let progress = (steps as f64 / self.total_steps.max(1) as f64).min(1.0);
                self.learning_rate + (end - self.learning_rate) * progress
            }
        }
    }

    pub fn validate(&self) -> Result<(), ModelError> {
        let problem = |m: &str| Err(ModelError::Config(m.into()));
        if self.envs == 0 || self.batch_size == 0 || self.train_frequency == 0 || self.n_step == 0 {
            return problem("envs, batch_size, train_frequency and n_step must be positive");
        }
        if self.replay_capacity < self.batch_size {
            return problem("replay_capacity must hold at least one batch");
        }
        if !(self.gamma > 0.0 && self.gamma <= 1.0) {
            return problem("gamma must lie in (0, 1]");
        }
        if !(self.learning_rate > 0.0 && self.learning_rate.is_finite()) {
            return problem("learning_rate must be positive");
        }
        if let Some(end) = self.learning_rate_end
            && !(end >= 0.0 && end.is_finite())
        {
            return problem("learning_rate_end must be 0 or positive");
        }
        if self.gradient_clip_norm.is_nan() || self.gradient_clip_norm < 0.0 {
            return problem("gradient_clip_norm must be 0 (off) or positive");
        }
        match self.target_update {
            TargetUpdate::Hard { every_steps: 0 } => {
                return problem("target_update.every_steps must be positive");
            }
            TargetUpdate::Soft { tau } if !(tau > 0.0 && tau <= 1.0) => {
                return problem("target_update.tau must lie in (0, 1]");
            }
            _ => {}
        }
        if let TdLoss::Huber { delta } = self.loss
            && (delta.is_nan() || delta <= 0.0)
        {
            return problem("loss.delta must be positive");
        }
        let p = &self.prioritized_replay;
        if p.enabled
            && !(p.alpha >= 0.0 && p.beta_start >= 0.0 && p.beta_end >= 0.0 && p.epsilon > 0.0)
        {
            return problem(
                "prioritized_replay: alpha and beta must be non-negative, epsilon positive",
            );
        }
        let (start, end) = match self.epsilon {
            EpsilonSchedule::Linear { start, end, .. } => (start, end),
            EpsilonSchedule::PerStep { start, end, decay }
            | EpsilonSchedule::PerEpisode { start, end, decay } => {
                if !(decay > 0.0 && decay <= 1.0) {
                    return problem("epsilon.decay must lie in (0, 1]");
                }
                (start, end)
            }
        };
        if !((0.0..=1.0).contains(&start) && (0.0..=1.0).contains(&end)) {
            return problem("epsilon.start and epsilon.end must lie in [0, 1]");
        }
        Ok(())
    }
}

/// The shape of what an agent was trained on: a network only fits a task with the same.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct AgentShape {
    pub channels: usize,
    pub height: usize,
    pub width: usize,
    pub scalars: usize,
    pub actions: usize,
}

impl AgentShape {
    pub fn of(env: &impl Env) -> Self {
        let spec = env.observation_spec();
        AgentShape {
            channels: spec.channels,
            height: spec.height,
            width: spec.width,
            scalars: spec.scalars,
            actions: env.action_count(),
        }
    }

    pub fn spec(&self) -> ObservationSpec {
        ObservationSpec {
            channels: self.channels,
            height: self.height,
            width: self.width,
            scalars: self.scalars,
        }
    }
}

/// One finished training episode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpisodeRecord {
    /// Transitions so far (all environments) when it ended.
    pub step: u64,
    pub env: usize,
    pub episode_return: f64,
    pub length: usize,
    pub outcome: OutcomeName,
    pub epsilon: f64,
}

/// [`Outcome`] as it is written in files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutcomeName {
    Reached,
    Crashed,
    OffRoad,
    TimeOver,
}

impl From<Outcome> for OutcomeName {
    fn from(o: Outcome) -> Self {
        match o {
            Outcome::Reached => OutcomeName::Reached,
            Outcome::Crashed => OutcomeName::Crashed,
            Outcome::OffRoad => OutcomeName::OffRoad,
            Outcome::TimeOver => OutcomeName::TimeOver,
        }
    }
}

/// Mean TD loss and Q-value over a window of gradient steps.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LossRecord {
    pub step: u64,
    pub updates: u64,
    pub td_loss: f64,
    /// Mean Q-value of the actions taken in the sampled batches.
    pub mean_q: f64,
}

/// Gradient steps averaged into one [`LossRecord`].
pub const LOSS_WINDOW: u64 = 100;

/// Counters and curves of a run (with the networks and Adam's state, a [`Checkpoint`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    pub seed: u64,
    /// Environment transitions so far.
    pub steps: u64,
    /// Gradient steps so far.
    pub updates: u64,
    /// Finished episodes.
    pub episodes: u64,
    /// Per environment: the episode it is in (resumed runs restart those episodes).
    pub env_episodes: Vec<u64>,
    /// Fractional gradient steps owed (`envs / train_frequency` per iteration).
    pub update_debt: f64,
    /// Steps at which the run was resumed.
    pub resumed_at: Vec<u64>,
    pub episode_history: Vec<EpisodeRecord>,
    pub loss_history: Vec<LossRecord>,
}

/// What a training run reports as it goes.
pub trait TrainObserver {
    /// After every iteration; returning false stops the run (it then ends with a checkpoint).
    fn iteration(&mut self, _state: &TrainState, _epsilon: f64) -> bool {
        true
    }
    fn episode(&mut self, _record: &EpisodeRecord) {}
    fn losses(&mut self, _record: &LossRecord) {}
    /// A checkpoint to keep (every `checkpoint_every` transitions; the final one is returned
    /// by [`train`] instead).
    fn checkpoint(&mut self, _checkpoint: &Checkpoint) -> Result<(), ModelError> {
        Ok(())
    }
}

/// An observer that only lets a run go on.
#[derive(Debug, Default)]
pub struct Quiet;
impl TrainObserver for Quiet {}

/// Seed stages of the run's draws.
const NETWORK_STAGE: u64 = 0x4e45_5457;
const EXPLORE_STAGE: u64 = 0x4558_504c;
const SAMPLE_STAGE: u64 = 0x5341_4d50;

/// Trains an agent on `envs` (one per parallel slot, `config.envs` of them), from scratch or
/// from `resume`, until `config.total_steps` transitions or until the observer stops it.
/// Returns the final checkpoint.
pub fn train<E: Env>(
    config: &DqnConfig,
    seed: u64,
    envs: Vec<E>,
    resume: Option<Checkpoint>,
    device: &Device,
    observer: &mut dyn TrainObserver,
) -> Result<Checkpoint, ModelError> {
    config.validate()?;
    let Some(first) = envs.first() else {
        return Err(ModelError::Config("no environments".into()));
    };
    if envs.len() != config.envs {
        return Err(ModelError::Config(format!(
            "{} environments given, config.envs = {}",
            envs.len(),
            config.envs
        )));
    }
    let shape = AgentShape::of(first);
    let spec = shape.spec();
    let actions = shape.actions;

    // Networks, optimiser and counters: fresh, or where the checkpoint left them.
    let mut learner = match resume {
        None => Learner::new(config, &shape, seed, device)?,
        Some(checkpoint) => Learner::resume(config, &shape, checkpoint, device)?,
    };
    let seed = learner.state.seed;
    learner
        .state
        .resumed_at
        .retain(|&s| s <= learner.state.steps);
    if learner.state.steps > 0 {
        learner.state.resumed_at.push(learner.state.steps);
    }

    // Environments and replay (a resumed run refills its replay).
    let mut envs = VecEnv::new(envs, seed, &learner.state.env_episodes);
    let mut replay = ReplayBuffer::new(
        ReplayOptions {
            capacity: config.replay_capacity,
            envs: config.envs,
            n_step: config.n_step,
            gamma: config.gamma,
            prioritized: config.prioritized_replay.enabled,
            alpha: config.prioritized_replay.alpha,
            priority_epsilon: config.prioritized_replay.epsilon,
        },
        spec,
    );
    replay.start(&envs.observations().iter().collect::<Vec<_>>());
    let learning_starts = learner.state.steps + config.warmup_steps;

    while learner.state.steps < config.total_steps {
        let steps_before = learner.state.steps;

        // 1. Act: ε-greedy on one batched forward pass.
        let epsilon = config.epsilon.value(steps_before, learner.state.episodes);
        let chosen = epsilon_greedy(
            &learner.online.valid(),
            envs.observations(),
            &spec,
            actions,
            epsilon,
            seed,
            steps_before,
            device,
        );

        // 2. Step the environments while the learner takes its gradient steps.
        let updates = if steps_before >= learning_starts && replay.len() >= config.batch_size {
            learner.state.update_debt += config.envs as f64 / config.train_frequency as f64;
            let whole = learner.state.update_debt.floor();
            learner.state.update_debt -= whole;
            whole as u64
        } else {
            0
        };
        let (step, loss_records) = rayon::join(
            || envs.step(&chosen),
            || {
                (0..updates)
                    .filter_map(|_| learner.gradient_step(&mut replay))
                    .collect::<Vec<_>>()
            },
        );

        // 3. Remember.
        let next: Vec<&Observation> = envs.observations().iter().collect();
        replay.push(&chosen, &step.rewards, &step.ended, &next);
        learner.state.steps += config.envs as u64;
        let steps = learner.state.steps;

        // 4. Target network.
        if let TargetUpdate::Hard { every_steps } = config.target_update
            && steps / every_steps != steps_before / every_steps
        {
            learner.sync_target();
        }

        // 5. Record.
        for record in loss_records {
            observer.losses(&record);
            learner.state.loss_history.push(record);
        }
        for end in &step.finished {
            learner.state.episodes += 1;
            let record = EpisodeRecord {
                step: steps,
                env: end.env,
                episode_return: end.episode_return,
                length: end.length,
                outcome: end.outcome.into(),
                epsilon,
            };
            observer.episode(&record);
            learner.state.episode_history.push(record);
        }
        learner.state.env_episodes = envs.episodes().to_vec();
        let go_on = observer.iteration(&learner.state, epsilon);
        let done = !go_on || steps >= config.total_steps;
        if !done
            && config.checkpoint_every > 0
            && steps / config.checkpoint_every != steps_before / config.checkpoint_every
        {
            observer.checkpoint(&learner.checkpoint(config, &shape))?;
        }
        if !go_on {
            break;
        }
    }
    Ok(learner.checkpoint(config, &shape))
}

/// One action per environment: random with probability ε (drawn from the transition's own
/// seed), otherwise the greedy action of `policy`.
#[allow(clippy::too_many_arguments)]
fn epsilon_greedy(
    policy: &QNetwork,
    observations: &[Observation],
    spec: &ObservationSpec,
    actions: usize,
    epsilon: f64,
    seed: u64,
    first_step: u64,
    device: &Device,
) -> Vec<usize> {
    let q = if epsilon < 1.0 {
        let refs: Vec<&Observation> = observations.iter().collect();
        let (layers, scalars) = observations_to_tensors(&refs, spec, device);
        tensor_values(policy.forward(layers, scalars))
    } else {
        vec![0.0; observations.len() * actions]
    };
    (0..observations.len())
        .map(|e| {
            let mut rng = item_rng(seed, EXPLORE_STAGE, first_step + e as u64);
            if rng.random::<f64>() < epsilon {
                rng.random_range(0..actions)
            } else {
                greedy_action(&q[e * actions..(e + 1) * actions])
            }
        })
        .collect()
}

/// The index of the largest Q-value (the first of equals).
pub fn greedy_action(q: &[f32]) -> usize {
    let mut best = 0;
    for (i, &v) in q.iter().enumerate() {
        if v > q[best] {
            best = i;
        }
    }
    best
}

/// TD targets `y = R + d · Q_target(s', a*)` for a batch (`d` = γⁿ, or 0 where the episode
/// ended), with `a* = argmax Q_online(s', ·)` when `next_q_online` is given (Double DQN) and
/// `argmax Q_target(s', ·)` otherwise. Q-values are `[batch, actions]` row-major.
pub fn td_targets(
    returns: &[f32],
    discounts: &[f32],
    next_q_target: &[f32],
    next_q_online: Option<&[f32]>,
    actions: usize,
) -> Vec<f32> {
    returns
        .iter()
        .zip(discounts)
        .enumerate()
        .map(|(i, (&r, &d))| {
            let row = i * actions..(i + 1) * actions;
            let target_row = &next_q_target[row.clone()];
            let best = match next_q_online {
                Some(online) => greedy_action(&online[row]),
                None => greedy_action(target_row),
            };
            if d == 0.0 {
                r
            } else {
                r + d * target_row[best]
            }
        })
        .collect()
}

/// What a gradient step minimises.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Objective {
    /// The TD error (DQN, Double DQN).
    Td,
    /// The TD error plus `alpha` × (logsumexp_a Q(s, a) − Q(s, a_data)): discrete
    /// conservative Q-learning (CQL(H), Kumar et al. 2020), which pushes down the values of
    /// actions the data did not take, for learning from a fixed dataset.
    Conservative { alpha: f64 },
    /// logsumexp_a Q(s, a) − Q(s, a_data) alone: the cross-entropy of softmax(Q) with the
    /// data's action, i.e. behaviour cloning with the Q-network as classifier.
    Imitation,
}

/// What one gradient step measured.
#[derive(Debug, Clone, PartialEq)]
pub struct LearnStep {
    /// The loss minimised.
    pub loss: f64,
    /// The TD part (None for imitation).
    pub td_loss: Option<f64>,
    /// The logsumexp − Q(s, a_data) part (None for plain TD).
    pub regulariser: Option<f64>,
    /// Mean Q of the taken actions.
    pub mean_q: f64,
    /// Per sample, Q(s, a) − target (empty for imitation).
    pub td_errors: Vec<f32>,
}

/// `log Σ_a exp(q[·, a])` per row of `[batch, actions]`, as `[batch, 1]` (shifted by the
/// row maximum so large values do not overflow).
fn log_sum_exp(q: Tensor<2>) -> Tensor<2> {
    let max = q.clone().max_dim(1).detach();
    (q - max.clone()).exp().sum_dim(1).log() + max
}

/// The networks, the optimiser and the counters of a run. Public so that the speed
/// comparison with PyTorch (`examples/bench_qnet_step.rs`) times exactly the gradient step
/// training runs.
pub struct Learner<'a> {
    config: &'a DqnConfig,
    spec: ObservationSpec,
    actions: usize,
    /// Inference device (the target network and the Q-values that need no gradient).
    device: Device,
    /// The same device with autodiff, where the online network trains.
    train_device: Device,
    online: QNetwork,
    target: QNetwork,
    optimizer: ModuleOptimizer,
    state: TrainState,
    window: LossWindow,
}

impl<'a> Learner<'a> {
    /// A fresh online network (parameters from `seed`), its target copy and Adam.
    pub fn new(
        config: &'a DqnConfig,
        shape: &AgentShape,
        seed: u64,
        device: &Device,
    ) -> Result<Self, ModelError> {
        let train_device = device.clone().autodiff();
        let network_seed = sim::seed::derive_seed(seed, NETWORK_STAGE, 0);
        let online = config
            .network
            .init(&shape.spec(), shape.actions, network_seed, &train_device)
            .map_err(ModelError::Config)?;
        let target = online.valid();
        Ok(Learner {
            config,
            spec: shape.spec(),
            actions: shape.actions,
            device: device.clone(),
            train_device,
            online,
            target,
            optimizer: adam(config),
            state: TrainState {
                seed,
                steps: 0,
                updates: 0,
                episodes: 0,
                env_episodes: vec![0; config.envs],
                update_debt: 0.0,
                resumed_at: Vec::new(),
                episode_history: Vec::new(),
                loss_history: Vec::new(),
            },
            window: LossWindow::default(),
        })
    }

    fn resume(
        config: &'a DqnConfig,
        shape: &AgentShape,
        checkpoint: Checkpoint,
        device: &Device,
    ) -> Result<Self, ModelError> {
        if &checkpoint.shape != shape {
            return Err(ModelError::Config(format!(
                "the checkpoint was trained on observations/actions {:?}, the task has {:?}",
                checkpoint.shape, shape
            )));
        }
        if checkpoint.config.network != config.network || checkpoint.config.envs != config.envs {
            return Err(ModelError::Config(
                "a run resumes with the network and the number of environments it started with"
                    .into(),
            ));
        }
        let train_device = device.clone().autodiff();
        Ok(Learner {
            config,
            spec: shape.spec(),
            actions: shape.actions,
            device: device.clone(),
            online: checkpoint.online.to_device(&train_device).train(),
            target: checkpoint.target.to_device(device).valid(),
            train_device,
            optimizer: checkpoint.optimizer,
            state: checkpoint.state,
            window: LossWindow::default(),
        })
    }

    /// One gradient step on a sampled batch; updates priorities and the soft target, and
    /// returns the loss curve's next point when a window is full.
    fn gradient_step(&mut self, replay: &mut ReplayBuffer) -> Option<LossRecord> {
        let config = self.config;
        let progress = (self.state.steps as f64 / config.total_steps.max(1) as f64).min(1.0) as f32;
        let p = &config.prioritized_replay;
        let beta = p.beta_start + (p.beta_end - p.beta_start) * progress;
        let mut rng = item_rng(self.state.seed, SAMPLE_STAGE, self.state.updates);
        let batch = replay.sample(config.batch_size, beta, &mut rng);
        let leaves = batch.leaves.clone();
        let (td_loss, mean_q, td_errors) = self.learn(batch);
        replay.update_priorities(&leaves, &td_errors);
        if let TargetUpdate::Soft { tau } = config.target_update {
            self.blend_target(tau);
        }
        self.state.updates += 1;
        self.window
            .add(td_loss, mean_q, self.state.steps, self.state.updates)
    }

    /// The TD update on one batch: targets from the target network (and the online network
    /// for Double DQN), Huber or squared TD error weighted by the importance weights,
    /// backward, Adam. Returns (loss, mean Q of the taken actions, TD errors).
    pub fn learn(&mut self, batch: Batch) -> (f64, f64, Vec<f32>) {
        let step = self.learn_with(batch, Objective::Td);
        (step.loss, step.mean_q, step.td_errors)
    }

    /// One gradient step on `batch` towards `objective` (see [`Objective`]).
    pub fn learn_with(&mut self, batch: Batch, objective: Objective) -> LearnStep {
        let config = self.config;
        let (b, a) = (batch.size, self.actions);

        // Targets, without gradients (imitation needs none).
        let targets = (!matches!(objective, Objective::Imitation)).then(|| {
            let (next_layers, next_scalars) = batch_tensors(
                batch.next_layers,
                batch.next_scalars,
                b,
                &self.spec,
                &self.device,
            );
            let next_q_target = tensor_values(
                self.target
                    .forward(next_layers.clone(), next_scalars.clone()),
            );
            let next_q_online = config
                .double
                .then(|| tensor_values(self.online.valid().forward(next_layers, next_scalars)));
            td_targets(
                &batch.returns,
                &batch.discounts,
                &next_q_target,
                next_q_online.as_deref(),
                a,
            )
        });

        // Q(s, ·) and Q(s, a) of the taken actions, with gradients.
        let (layers, scalars) = batch_tensors(
            batch.layers,
            batch.scalars,
            b,
            &self.spec,
            &self.train_device,
        );
        let q = self.online.forward(layers, scalars);
        let taken: Vec<i64> = batch.actions.iter().map(|&x| x as i64).collect();
        let taken = Tensor::<2, Int>::from_data(TensorData::new(taken, [b, 1]), &self.train_device);
        let q_taken = q.clone().gather(1, taken);
        let column = |values: Vec<f32>| {
            Tensor::<2>::from_data(TensorData::new(values, [b, 1]), &self.train_device)
        };
        let weights = column(batch.weights);

        // The TD error's loss, weighted by the importance weights.
        let td = targets.map(|targets| {
            let td = q_taken.clone() - column(targets);
            let per_sample = match config.loss {
                TdLoss::Huber { delta } => HuberLossConfig::new(delta)
                    .init()
                    .forward_residuals(td.clone()),
                TdLoss::Mse => td.clone().powi_scalar(2),
            };
            (td, (per_sample * weights.clone()).mean())
        });
        // logsumexp_a Q(s, a) − Q(s, a_data): cross-entropy of softmax(Q) with the data's
        // action; CQL's penalty on the values of actions the data did not take.
        let imitation = || {
            let gap = log_sum_exp(q.clone()) - q_taken.clone();
            (gap * weights.clone()).mean()
        };
        let (loss, regulariser) = match (objective, td.as_ref()) {
            (Objective::Td, Some((_, td_loss))) => (td_loss.clone(), None),
            (Objective::Conservative { alpha }, Some((_, td_loss))) => {
                let penalty = imitation();
                (
                    td_loss.clone() + penalty.clone().mul_scalar(alpha),
                    Some(penalty),
                )
            }
            (Objective::Imitation, _) | (_, None) => {
                let penalty = imitation();
                (penalty.clone(), Some(penalty))
            }
        };

        let gradients = GradientsParams::from_grads(loss.backward(), &self.online);
        // Moved out rather than cloned, so that the optimizer may update the parameters in
        // place (models::optim on LibTorch) when nothing else holds them; the placeholder, a
        // handle on the target network, is replaced straight after.
        let online = std::mem::replace(&mut self.online, self.target.clone());
        self.online =
            self.optimizer
                .step(config.learning_rate_at(self.state.steps), online, gradients);

        let scalar =
            |t: Tensor<1>| f64::from(tensor_values(t).first().copied().unwrap_or(f32::NAN));
        let q_taken = tensor_values(q_taken);
        LearnStep {
            loss: scalar(loss),
            td_errors: td
                .as_ref()
                .map_or_else(Vec::new, |(td, _)| tensor_values(td.clone())),
            td_loss: td.map(|(_, l)| scalar(l)),
            regulariser: regulariser.map(scalar),
            mean_q: q_taken.iter().map(|&v| f64::from(v)).sum::<f64>() / b as f64,
        }
    }

    /// Copies the online network into the target network (a hard target update).
    pub fn sync_target(&mut self) {
        self.target = self.online.valid();
    }

    /// Blends the online network into the target network: `τ·online + (1 − τ)·target`.
    pub fn blend_target(&mut self, tau: f64) {
        self.target = blend(self.target.clone(), &self.online.valid(), tau);
    }

    /// The counters and curves (offline training keeps its own in them).
    pub fn state_mut(&mut self) -> &mut TrainState {
        &mut self.state
    }

    /// The online network, for inference.
    pub fn online(&self) -> QNetwork {
        self.online.valid()
    }

    pub fn checkpoint(&self, config: &DqnConfig, shape: &AgentShape) -> Checkpoint {
        Checkpoint {
            config: config.clone(),
            shape: shape.clone(),
            state: self.state.clone(),
            online: self.online.valid(),
            target: self.target.clone(),
            optimizer: self.optimizer.clone(),
        }
    }
}

impl std::fmt::Debug for Learner<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Learner")
            .field("spec", &self.spec)
            .field("actions", &self.actions)
            .field("steps", &self.state.steps)
            .field("updates", &self.state.updates)
            .finish_non_exhaustive()
    }
}

fn adam(config: &DqnConfig) -> ModuleOptimizer {
    let clipping = (config.gradient_clip_norm > 0.0)
        .then_some(GradientClippingConfig::Norm(config.gradient_clip_norm));
    crate::optim::adam(config.adam_epsilon, clipping)
}

/// Running means of TD loss and Q over [`LOSS_WINDOW`] gradient steps.
#[derive(Debug, Default)]
struct LossWindow {
    loss: f64,
    q: f64,
    count: u64,
}

impl LossWindow {
    fn add(&mut self, loss: f64, q: f64, step: u64, updates: u64) -> Option<LossRecord> {
        self.loss += loss;
        self.q += q;
        self.count += 1;
        (self.count == LOSS_WINDOW).then(|| {
            let record = LossRecord {
                step,
                updates,
                td_loss: self.loss / self.count as f64,
                mean_q: self.q / self.count as f64,
            };
            *self = LossWindow::default();
            record
        })
    }
}

/// Everything a run needs to go on: both networks, Adam's state, the counters and curves,
/// and the config and shape it was trained with.
#[derive(Clone)]
pub struct Checkpoint {
    pub config: DqnConfig,
    pub shape: AgentShape,
    pub state: TrainState,
    /// The online network (inference mode; [`train`] re-enables gradients when resuming).
    pub online: QNetwork,
    pub target: QNetwork,
    pub optimizer: ModuleOptimizer,
}

impl std::fmt::Debug for Checkpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Checkpoint")
            .field("config", &self.config)
            .field("shape", &self.shape)
            .field("steps", &self.state.steps)
            .finish_non_exhaustive()
    }
}

/// Files of a checkpoint folder.
pub const ONLINE_FILE: &str = "online.bpk";
pub const TARGET_FILE: &str = "target.bpk";
pub const OPTIMIZER_FILE: &str = "optimizer.bpk";
pub const STATE_FILE: &str = "state.json";
/// The agent's description: config, shape, seed (what `agent eval` reads with the online network).
pub const AGENT_FILE: &str = "agent.json";

/// `agent.json`: enough to rebuild the network and know what it was trained for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AgentDescription {
    pub config: DqnConfig,
    pub shape: AgentShape,
    pub seed: u64,
    pub steps: u64,
}

impl Checkpoint {
    /// Writes the checkpoint's files into `dir` (an existing folder; the caller makes the
    /// folder appear atomically).
    pub fn save(&self, dir: &Path) -> Result<(), ModelError> {
        let record_error =
            |file: &str, e: burn::store::RecordError| ModelError::file(dir.join(file), e);
        self.online
            .clone()
            .save_file(dir.join(ONLINE_FILE))
            .map_err(|e| record_error(ONLINE_FILE, e))?;
        self.target
            .clone()
            .save_file(dir.join(TARGET_FILE))
            .map_err(|e| record_error(TARGET_FILE, e))?;
        self.optimizer
            .save(dir.join(OPTIMIZER_FILE))
            .map_err(|e| record_error(OPTIMIZER_FILE, e))?;
        write_json(&dir.join(STATE_FILE), &self.state)?;
        Ok(write_json(&dir.join(AGENT_FILE), &self.description())?)
    }

    /// Reads a checkpoint folder written by [`save`](Self::save).
    pub fn load(dir: &Path, device: &Device) -> Result<Checkpoint, ModelError> {
        let description: AgentDescription = read_json(&dir.join(AGENT_FILE))?;
        let state: TrainState = read_json(&dir.join(STATE_FILE))?;
        let online = load_network(dir, &description, device)?;
        let target = read_network(&dir.join(TARGET_FILE), &description, device)?;
        let optimizer = adam(&description.config)
            .load(dir.join(OPTIMIZER_FILE))
            .map_err(|e| ModelError::file(dir.join(OPTIMIZER_FILE), e))?;
        Ok(Checkpoint {
            config: description.config,
            shape: description.shape,
            state,
            online,
            target,
            optimizer,
        })
    }

    pub fn description(&self) -> AgentDescription {
        AgentDescription {
            config: self.config.clone(),
            shape: self.shape.clone(),
            seed: self.state.seed,
            steps: self.state.steps,
        }
    }
}

/// The trained (online) network of an agent folder or checkpoint folder, for inference.
pub fn load_network(
    dir: &Path,
    description: &AgentDescription,
    device: &Device,
) -> Result<QNetwork, ModelError> {
    read_network(&dir.join(ONLINE_FILE), description, device)
}

fn read_network(
    path: &Path,
    description: &AgentDescription,
    device: &Device,
) -> Result<QNetwork, ModelError> {
    let shape = &description.shape;
    let network = description
        .config
        .network
        .init(&shape.spec(), shape.actions, 0, device)
        .map_err(|e| ModelError::file(path, e))?;
    let record = ModuleRecord::load(path).map_err(|e| ModelError::file(path, e))?;
    network
        .try_load_record(record)
        .map(|n| n.valid())
        .map_err(|e| {
            ModelError::file(
                path,
                format!("does not fit the network in {AGENT_FILE}: {e}"),
            )
        })
}

pub fn read_agent_description(dir: &Path) -> Result<AgentDescription, ModelError> {
    read_json(&dir.join(AGENT_FILE))
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, ModelError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| ModelError::file(path, format!("cannot read: {e}")))?;
    serde_json::from_str(&text).map_err(|e| ModelError::file(path, format!("invalid: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::qnet::{ConvSpec, Pooling};
    use crate::toy::{GO, GapEnv, WAIT};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn td_targets_by_hand_double_versus_plain() {
        // Two transitions, three actions.
        let returns = [1.0, -0.5];
        let discounts = [0.9, 0.0]; // the second episode ended: no bootstrap
        let next_q_target = [2.0, 5.0, 3.0, /* */ 7.0, 1.0, 1.0];
        let next_q_online = [0.0, 1.0, 4.0, /* */ 9.0, 0.0, 0.0];
        // DQN: max of the target row: 1 + 0.9·5.
        let plain = td_targets(&returns, &discounts, &next_q_target, None, 3);
        assert_eq!(plain, vec![1.0 + 0.9 * 5.0, -0.5]);
        // Double: the online row picks action 2, the target values it at 3: 1 + 0.9·3.
        let double = td_targets(
            &returns,
            &discounts,
            &next_q_target,
            Some(&next_q_online),
            3,
        );
        assert_eq!(double, vec![1.0 + 0.9 * 3.0, -0.5]);
    }

    #[test]
    fn greedy_action_takes_the_first_of_equals() {
        assert_eq!(greedy_action(&[1.0, 3.0, 3.0]), 1);
        assert_eq!(greedy_action(&[-1.0]), 0);
    }

    #[test]
    fn epsilon_schedules() {
        let linear = EpsilonSchedule::Linear {
            start: 1.0,
            end: 0.1,
            steps: 100,
        };
        assert_eq!(linear.value(0, 0), 1.0);
        assert!((linear.value(50, 0) - 0.55).abs() < 1e-12);
        assert!((linear.value(1_000, 0) - 0.1).abs() < 1e-12);
        // ITS: ×0.9995 per episode, floored at 0.1 (reached after ln 0.1 / ln 0.9995 ≈ 4604 episodes).
        assert!((EpsilonSchedule::ITS.value(10_000_000, 1) - 0.9995).abs() < 1e-12);
        assert!(EpsilonSchedule::ITS.value(0, 4_600) > 0.1);
        assert_eq!(EpsilonSchedule::ITS.value(0, 4_610), 0.1);
        // AIT: ×0.99999 per step.
        assert!((EpsilonSchedule::AIT.value(100_000, 0) - 0.99999f64.powi(100_000)).abs() < 1e-12);
    }

    #[test]
    fn learning_rate_constant_or_falling_linearly_over_the_run() -> Result<(), String> {
        let constant = DqnConfig {
            total_steps: 1_000,
            learning_rate: 1e-3,
            ..DqnConfig::default()
        };
        assert_eq!(constant.learning_rate_at(0), 1e-3);
        assert_eq!(constant.learning_rate_at(5_000), 1e-3);
        let falling: DqnConfig =
            toml::from_str("total_steps = 1000\nlearning_rate = 0.001\nlearning_rate_end = 0.0001")
                .map_err(|e| e.to_string())?;
        assert_eq!(falling.learning_rate_at(0), 1e-3);
        assert!((falling.learning_rate_at(500) - 5.5e-4).abs() < 1e-15);
        assert!((falling.learning_rate_at(1_000) - 1e-4).abs() < 1e-15);
        assert!((falling.learning_rate_at(2_000) - 1e-4).abs() < 1e-15);
        let negative = DqnConfig {
            learning_rate_end: Some(-1.0),
            ..DqnConfig::default()
        };
        assert!(negative.validate().is_err());
        Ok(())
    }

    #[test]
    fn config_round_trips_through_toml_and_rejects_typos() -> Result<(), String> {
        let text = r#"
            total_steps = 1000
            double = false
            epsilon = { kind = "per_episode", start = 1.0, end = 0.1, decay = 0.9995 }
            target_update = { kind = "soft", tau = 0.005 }
            loss = { kind = "mse" }
            [prioritized_replay]
            enabled = true
            [network]
            dueling = true
            pooling = { kind = "average", height = 2, width = 2 }
        "#;
        let config: DqnConfig = toml::from_str(text).map_err(|e| e.to_string())?;
        assert_eq!(config.total_steps, 1000);
        assert!(!config.double && config.network.dueling && config.prioritized_replay.enabled);
        assert_eq!(config.epsilon, EpsilonSchedule::ITS);
        assert_eq!(config.target_update, TargetUpdate::Soft { tau: 0.005 });
        assert_eq!(config.batch_size, DqnConfig::default().batch_size);
        config.validate().map_err(|e| e.to_string())?;
        let back: DqnConfig = toml::from_str(&toml::to_string(&config).map_err(|e| e.to_string())?)
            .map_err(|e| e.to_string())?;
        assert_eq!(back, config);
        assert!(toml::from_str::<DqnConfig>("gama = 0.9").is_err());
        let bad = DqnConfig {
            gamma: 1.5,
            ..DqnConfig::default()
        };
        assert!(bad.validate().is_err());
        Ok(())
    }

    /// A small network and schedule that the toy task needs a few thousand steps of.
    fn toy_config(total_steps: u64) -> DqnConfig {
        DqnConfig {
            total_steps,
            envs: 4,
            network: QNetworkConfig {
                convolutions: vec![ConvSpec {
                    channels: 4,
                    kernel: 1,
                    stride: 1,
                    padding: 0,
                }],
                pooling: Pooling::Flatten,
                scalar_hidden: 4,
                hidden: vec![32],
                dueling: false,
                ignored_scalars: Vec::new(),
            },
            n_step: 1,
            gamma: 0.95,
            learning_rate: 2e-3,
            replay_capacity: 10_000,
            warmup_steps: 400,
            train_frequency: 2,
            target_update: TargetUpdate::Hard { every_steps: 200 },
            epsilon: EpsilonSchedule::Linear {
                start: 1.0,
                end: 0.02,
                steps: 1_500,
            },
            checkpoint_every: 0,
            ..DqnConfig::default()
        }
    }

    fn toy_envs(n: usize) -> Vec<GapEnv> {
        (0..n).map(|_| GapEnv::default()).collect()
    }

    /// Fraction of `episodes` fresh toy episodes that `choose` brings to the goal.
    fn success_rate(episodes: u64, mut choose: impl FnMut(&Observation, &GapEnv) -> usize) -> f64 {
        let mut reached = 0;
        for k in 0..episodes {
            let mut env = GapEnv::default();
            let mut obs = env.reset(1_000_000 + k);
            loop {
                let step = env.step(choose(&obs, &env));
                obs = step.observation;
                if let Some(outcome) = step.outcome {
                    reached += usize::from(outcome == Outcome::Reached);
                    break;
                }
            }
        }
        reached as f64 / episodes as f64
    }

    #[test]
    fn dqn_learns_to_wait_for_the_gap() -> Result<(), ModelError> {
        let device = crate::cpu_device();
        let checkpoint = train(
            &toy_config(4_000),
            7,
            toy_envs(4),
            None,
            &device,
            &mut Quiet,
        )?;
        let policy = crate::policy::QPolicy::new(
            checkpoint.online.clone(),
            GapEnv::default().observation_spec(),
            2,
            device,
        );
        let learned = success_rate(300, |obs, _| greedy_action(&policy.q_values(&[obs])));
        let mut coin = ChaCha8Rng::seed_from_u64(1);
        let random = success_rate(300, |_, _| coin.random_range(0..2));
        let go_at_once = success_rate(300, |_, _| GO);
        let oracle = success_rate(300, |_, env| if env.gap() { GO } else { WAIT });
        assert!(oracle > 0.99, "the task is solvable: {oracle}");
        assert!(
            random < 0.75 && go_at_once < 0.5,
            "random {random}, go at once {go_at_once}"
        );
        assert!(
            learned > 0.95,
            "learned {learned} (random {random}, go at once {go_at_once})"
        );
        assert!(checkpoint.state.updates > 1_500 && checkpoint.state.loss_history.len() >= 15);
        Ok(())
    }

    /// Episode returns of the first 1,000 transitions, with the given number of threads.
    fn first_returns(
        threads: usize,
        config: &DqnConfig,
    ) -> Result<(Vec<EpisodeRecord>, Vec<LossRecord>), ModelError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .map_err(|e| ModelError::Config(e.to_string()))?;
        let checkpoint = pool.install(|| {
            train(
                config,
                11,
                toy_envs(4),
                None,
                &crate::cpu_device(),
                &mut Quiet,
            )
        })?;
        Ok((
            checkpoint.state.episode_history,
            checkpoint.state.loss_history,
        ))
    }

    #[test]
    fn same_seed_same_first_thousand_steps_with_any_thread_count() -> Result<(), ModelError> {
        let config = DqnConfig {
            warmup_steps: 200,
            prioritized_replay: PrioritizedReplay {
                enabled: true,
                ..PrioritizedReplay::default()
            },
            target_update: TargetUpdate::Soft { tau: 0.05 },
            ..toy_config(1_000)
        };
        let (episodes_a, losses_a) = first_returns(1, &config)?;
        let (episodes_b, losses_b) = first_returns(2, &config)?;
        let (episodes_c, _) = first_returns(
            2,
            &DqnConfig {
                double: false,
                ..config.clone()
            },
        )?;
        assert!(
            episodes_a.len() > 50 && losses_a.len() >= 3,
            "{} episodes",
            episodes_a.len()
        );
        assert_eq!(episodes_a, episodes_b);
        assert_eq!(losses_a, losses_b);
        // Not a constant: learning with another target changes the returns.
        assert_ne!(episodes_a, episodes_c);
        Ok(())
    }

    /// Stops a run once it has taken `stop_at` transitions.
    struct StopAt(u64);
    impl TrainObserver for StopAt {
        fn iteration(&mut self, state: &TrainState, _epsilon: f64) -> bool {
            state.steps < self.0
        }
    }

    #[test]
    fn resume_continues_from_the_saved_checkpoint() -> Result<(), ModelError> {
        let device = crate::cpu_device();
        let config = toy_config(1_600);
        let uninterrupted = train(&config, 3, toy_envs(4), None, &device, &mut Quiet)?;
        let stopped = train(&config, 3, toy_envs(4), None, &device, &mut StopAt(800))?;
        assert_eq!(stopped.state.steps, 800);

        let dir = tempfile::tempdir().map_err(|e| ModelError::file("tempdir", e))?;
        stopped.save(dir.path())?;
        let loaded = Checkpoint::load(dir.path(), &device)?;
        assert_eq!(loaded.state, stopped.state);
        // The networks come back exactly.
        let probe = GapEnv::default().reset(5);
        let spec = GapEnv::default().observation_spec();
        let q = |net: &QNetwork| {
            crate::policy::QPolicy::new(net.clone(), spec, 2, device.clone()).q_values(&[&probe])
        };
        assert_eq!(q(&loaded.online), q(&stopped.online));
        assert_eq!(q(&loaded.target), q(&stopped.target));

        let resumed = train(
            &config,
            3,
            toy_envs(4),
            Some(loaded.clone()),
            &device,
            &mut Quiet,
        )?;
        let again = train(&config, 3, toy_envs(4), Some(loaded), &device, &mut Quiet)?;
        assert_eq!(resumed.state.steps, 1_600);
        assert_eq!(resumed.state.resumed_at, vec![800]);
        // Everything up to the stop is the uninterrupted run's.
        let before = |s: &TrainState| {
            s.episode_history
                .iter()
                .filter(|e| e.step <= 800)
                .copied()
                .collect::<Vec<_>>()
        };
        assert_eq!(before(&resumed.state), before(&uninterrupted.state));
        // After it: the replay refills for warmup_steps, so fewer gradient steps, but the run
        // is deterministic.
        assert!(resumed.state.updates > stopped.state.updates);
        assert!(resumed.state.updates < uninterrupted.state.updates);
        assert_eq!(resumed.state, again.state);
        assert_eq!(q(&resumed.online), q(&again.online));
        Ok(())
    }
}
