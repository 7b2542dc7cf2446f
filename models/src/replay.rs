//! Experience replay for vectorised environments: every observation stored once,
//! run-length packed, n-step returns assembled when sampled, and uniform or prioritised
//! (proportional, sum-tree) sampling.
//!
//! # Layout
//!
//! The buffer is a ring of *rows*, one row per vector step, each holding one slot per
//! environment (Stable-Baselines3's memory-optimised layout): slot `(t, e)` keeps the
//! observation environment `e` saw at step `t` and the action, reward and end-of-episode
//! flag that followed it. The next observation of `(t, e)` is the observation of
//! `(t + 1, e)`, so each observation is stored once instead of twice; after an episode ends,
//! `(t + 1, e)` holds the first observation of the next episode, which is never used as a
//! successor because the transition's flag says the episode ended. Observations are packed
//! with [`PackedLayers`], about a tenth of the raw 112,896 bytes of a 4 × 4 × 84 × 84 stack.
//!
//! Transition `(t, e)` becomes sampleable once row `t + n` holds its observation (n-step
//! returns look that far ahead); it stops being sampleable when its row is overwritten.
//! Both happen in [`ReplayBuffer::push`] by setting the transition's leaf in the sum tree
//! (uniform replay is the same tree with every sampleable leaf at priority 1).

use rand::Rng;
use rayon::prelude::*;
use sim::{Observation, ObservationSpec};

use crate::packed::PackedLayers;
use crate::sum_tree::SumTree;

/// Sizes and switches of a replay buffer (from [`crate::dqn::DqnConfig`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayOptions {
    /// Transitions kept (at least; rounded up to whole rows of `envs`).
    pub capacity: usize,
    pub envs: usize,
    /// Steps summed into one return (1 = classic one-step TD).
    pub n_step: usize,
    pub gamma: f32,
    /// Prioritised replay: priority = (|TD error| + `priority_epsilon`)^`alpha`.
    pub prioritized: bool,
    pub alpha: f32,
    pub priority_epsilon: f32,
}

/// A sampled batch, laid out for the Q-network (row-major, batch first).
#[derive(Debug, Clone, Default)]
pub struct Batch {
    pub size: usize,
    /// `[size, channels, height, width]`, scaled to [0, 1].
    pub layers: Vec<f32>,
    /// `[size, scalars]`.
    pub scalars: Vec<f32>,
    pub actions: Vec<usize>,
    /// Discounted sums of the next n rewards (fewer if the episode ended).
    pub returns: Vec<f32>,
    /// γⁿ, or 0 when the episode ended within the n steps (nothing to bootstrap from).
    pub discounts: Vec<f32>,
    /// Observations n steps later (zeros where the discount is 0).
    pub next_layers: Vec<f32>,
    pub next_scalars: Vec<f32>,
    /// Importance-sampling weights (all 1 for uniform replay), normalised by the batch maximum.
    pub weights: Vec<f32>,
    /// Which transitions these were, for [`ReplayBuffer::update_priorities`].
    pub leaves: Vec<usize>,
}

#[derive(Debug)]
pub struct ReplayBuffer {
    options: ReplayOptions,
    spec: ObservationSpec,
    /// Rows in the ring.
    rows: usize,
    layers: Vec<Option<PackedLayers>>,
    scalars: Vec<f32>,
    actions: Vec<u32>,
    rewards: Vec<f32>,
    ended: Vec<bool>,
    /// Rows whose observations have been written since the start (row `t` lives at slot
    /// row `t % rows`).
    written_rows: u64,
    tree: SumTree,
    /// Sampleable transitions (leaves with a positive priority).
    ready: usize,
    max_priority: f64,
    stored_bytes: usize,
}

impl ReplayBuffer {
    pub fn new(options: ReplayOptions, spec: ObservationSpec) -> Self {
        let envs = options.envs.max(1);
        let n_step = options.n_step.max(1);
        let options = ReplayOptions {
            envs,
            n_step,
            ..options
        };
        // `capacity` transitions sampleable, plus the newest rows that wait for their
        // n-step successors and the row being written.
        let rows = options.capacity.div_ceil(envs).max(1) + n_step + 1;
        let slots = rows * envs;
        ReplayBuffer {
            options,
            spec,
            rows,
            layers: vec![None; slots],
            scalars: vec![0.0; slots * spec.scalars],
            actions: vec![0; slots],
            rewards: vec![0.0; slots],
            ended: vec![false; slots],
            written_rows: 0,
            tree: SumTree::new(slots),
            ready: 0,
            max_priority: 1.0,
            stored_bytes: 0,
        }
    }

    /// Sampleable transitions.
    pub fn len(&self) -> usize {
        self.ready
    }

    pub fn is_empty(&self) -> bool {
        self.ready == 0
    }

    /// Bytes of packed observations held.
    pub fn stored_bytes(&self) -> usize {
        self.stored_bytes
    }

    /// Stores the first observations of every environment (once, before the first
    /// [`push`](Self::push)).
    pub fn start(&mut self, observations: &[&Observation]) {
        debug_assert_eq!(self.written_rows, 0, "start is called once");
        self.write_row(observations);
    }

    /// Records one vector step: what each environment did in the newest row, and the
    /// observations that followed (the first of a new episode where one ended).
    pub fn push(
        &mut self,
        actions: &[usize],
        rewards: &[f32],
        ended: &[bool],
        next: &[&Observation],
    ) {
        let envs = self.options.envs;
        debug_assert!(self.written_rows > 0, "start comes first");
        debug_assert!(actions.len() == envs && rewards.len() == envs && ended.len() == envs);
        let row = self.slot_row(self.written_rows - 1);
        for e in 0..envs {
            let slot = row * envs + e;
            self.actions[slot] = actions[e] as u32;
            self.rewards[slot] = rewards[e];
            self.ended[slot] = ended[e];
        }
        self.write_row(next);
        // Row t = written_rows - 1 - n now has its n-step successor.
        let n = self.options.n_step as u64;
        if let Some(t) = (self.written_rows - 1).checked_sub(n) {
            let row = self.slot_row(t);
            for e in 0..envs {
                let priority = if self.options.prioritized {
                    self.max_priority
                } else {
                    1.0
                };
                self.set_priority(row * envs + e, priority);
            }
        }
    }

    /// Draws `size` transitions: proportionally to their priorities (stratified: one draw
    /// in each of `size` equal slices of the total), uniformly without priorities. `beta` is
    /// the importance-sampling exponent (ignored for uniform replay). Needs a non-empty buffer.
    pub fn sample(&self, size: usize, beta: f32, rng: &mut impl Rng) -> Batch {
        let total = self.tree.total();
        let slice = total / size as f64;
        let leaves: Vec<usize> = (0..size)
            .map(|i| self.tree.find((i as f64 + rng.random::<f64>()) * slice))
            .collect();
        let weights = if self.options.prioritized {
            let n = self.ready as f64;
            let raw: Vec<f64> = leaves
                .iter()
                .map(|&leaf| (n * self.tree.get(leaf) / total).powf(-f64::from(beta)))
                .collect();
            let max = raw.iter().copied().fold(f64::MIN_POSITIVE, f64::max);
            raw.iter().map(|w| (w / max) as f32).collect()
        } else {
            vec![1.0; size]
        };
        self.gather(leaves, weights)
    }

    /// Sets the priorities of sampled transitions from their new absolute TD errors (no-op
    /// for uniform replay).
    pub fn update_priorities(&mut self, leaves: &[usize], td_errors: &[f32]) {
        if !self.options.prioritized {
            return;
        }
        for (&leaf, &error) in leaves.iter().zip(td_errors) {
            if self.tree.get(leaf) <= 0.0 {
                continue; // overwritten since it was sampled
            }
            let priority = (f64::from(error.abs()) + f64::from(self.options.priority_epsilon))
                .powf(f64::from(self.options.alpha));
            if priority.is_finite() && priority > 0.0 {
                self.max_priority = self.max_priority.max(priority);
                self.tree.set(leaf, priority);
            }
        }
    }

    fn slot_row(&self, t: u64) -> usize {
        (t % self.rows as u64) as usize
    }

    /// Step index of the data in slot row `row` (the newest written step that maps there).
    fn step_of_row(&self, row: usize) -> u64 {
        let newest = self.written_rows - 1;
        newest - (newest + self.rows as u64 - row as u64) % self.rows as u64
    }

    fn set_priority(&mut self, leaf: usize, priority: f64) {
        let was_ready = self.tree.get(leaf) > 0.0;
        let is_ready = priority > 0.0;
        self.tree.set(leaf, priority);
        match (was_ready, is_ready) {
            (false, true) => self.ready += 1,
            (true, false) => self.ready -= 1,
            _ => {}
        }
    }

    fn write_row(&mut self, observations: &[&Observation]) {
        let envs = self.options.envs;
        let s = self.spec.scalars;
        let row = self.slot_row(self.written_rows);
        for (e, obs) in observations.iter().enumerate().take(envs) {
            let slot = row * envs + e;
            // The transition stored here before is overwritten: no longer sampleable.
            self.set_priority(slot, 0.0);
            let packed = PackedLayers::pack(&obs.layers);
            self.stored_bytes += packed.stored_bytes();
            if let Some(old) = self.layers[slot].replace(packed) {
                self.stored_bytes -= old.stored_bytes();
            }
            self.scalars[slot * s..(slot + 1) * s].copy_from_slice(&obs.scalars[..s]);
            self.actions[slot] = 0;
            self.rewards[slot] = 0.0;
            self.ended[slot] = false;
        }
        self.written_rows += 1;
    }

    /// The n-step return of transition `(t, e)`: (discounted reward sum, discount, slot of
    /// the observation n steps later or None when the episode ended first).
    fn n_step_return(&self, t: u64, e: usize) -> (f32, f32, Option<usize>) {
        let envs = self.options.envs;
        let mut sum = 0.0;
        let mut discount = 1.0;
        for k in 0..self.options.n_step as u64 {
            let slot = self.slot_row(t + k) * envs + e;
            sum += discount * self.rewards[slot];
            discount *= self.options.gamma;
            if self.ended[slot] {
                return (sum, 0.0, None);
            }
        }
        let next = self.slot_row(t + self.options.n_step as u64) * envs + e;
        (sum, discount, Some(next))
    }

    fn gather(&self, leaves: Vec<usize>, weights: Vec<f32>) -> Batch {
        let envs = self.options.envs;
        let (l, s) = (self.spec.layer_len(), self.spec.scalars);
        let size = leaves.len();
        let mut batch = Batch {
            size,
            layers: vec![0.0; size * l],
            scalars: vec![0.0; size * s],
            actions: Vec::with_capacity(size),
            returns: Vec::with_capacity(size),
            discounts: Vec::with_capacity(size),
            next_layers: vec![0.0; size * l],
            next_scalars: vec![0.0; size * s],
            weights,
            leaves: Vec::new(),
        };
        let mut next_slots = Vec::with_capacity(size);
        for (i, &leaf) in leaves.iter().enumerate() {
            let (row, e) = (leaf / envs, leaf % envs);
            let (sum, discount, next) = self.n_step_return(self.step_of_row(row), e);
            batch.actions.push(self.actions[leaf] as usize);
            batch.returns.push(sum);
            batch.discounts.push(discount);
            batch.scalars[i * s..(i + 1) * s]
                .copy_from_slice(&self.scalars[leaf * s..(leaf + 1) * s]);
            if let Some(next) = next {
                batch.next_scalars[i * s..(i + 1) * s]
                    .copy_from_slice(&self.scalars[next * s..(next + 1) * s]);
            }
            next_slots.push(next);
        }
        let unpack = |slot: Option<usize>, out: &mut [f32]| {
            if let Some(Some(packed)) = slot.map(|slot| &self.layers[slot]) {
                packed.unpack_scaled(out);
            }
        };
        if l > 0 {
            batch
                .layers
                .par_chunks_mut(l)
                .zip(leaves.par_iter())
                .for_each(|(out, &leaf)| unpack(Some(leaf), out));
            batch
                .next_layers
                .par_chunks_mut(l)
                .zip(next_slots.par_iter())
                .for_each(|(out, &next)| unpack(next, out));
        }
        batch.leaves = leaves;
        batch
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    const SPEC: ObservationSpec = ObservationSpec {
        channels: 1,
        height: 1,
        width: 2,
        scalars: 1,
    };

    /// An observation that names its environment and step: layers [e, t], scalar t.
    fn obs(e: usize, t: usize) -> Observation {
        Observation {
            layers: vec![e as u8, t as u8],
            scalars: vec![t as f32],
        }
    }

    fn options(capacity: usize, envs: usize, n_step: usize) -> ReplayOptions {
        ReplayOptions {
            capacity,
            envs,
            n_step,
            gamma: 0.5,
            prioritized: false,
            alpha: 0.6,
            priority_epsilon: 1e-3,
        }
    }

    /// Two environments; env 0's episode ends after its step 2 (reward 4); rewards are
    /// `t + 1` for env 0 and `10 (t + 1)` for env 1.
    fn filled(n_step: usize, steps: usize, capacity: usize) -> ReplayBuffer {
        let mut buffer = ReplayBuffer::new(options(capacity, 2, n_step), SPEC);
        let (o0, o1) = (obs(0, 0), obs(1, 0));
        buffer.start(&[&o0, &o1]);
        for t in 0..steps {
            let ended = [t == 2, false];
            let rewards = [(t + 1) as f32, 10.0 * (t + 1) as f32];
            let (n0, n1) = (obs(0, t + 1), obs(1, t + 1));
            buffer.push(&[t % 3, 1], &rewards, &ended, &[&n0, &n1]);
        }
        buffer
    }

    fn find(batch: &Batch, layer_values: [f32; 2]) -> Option<usize> {
        (0..batch.size).find(|&i| batch.layers[2 * i..2 * i + 2] == layer_values)
    }

    #[test]
    fn n_step_returns_by_hand() {
        let buffer = filled(3, 6, 100);
        // Rows 0..=6 written; transitions t with t + 3 <= 6 are ready: t = 0..=3, two envs.
        assert_eq!(buffer.len(), 8);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let batch = buffer.sample(64, 0.4, &mut rng);
        let v = |x: usize| x as f32 / 255.0;
        // env 1, t = 0: 10 + 0.5·20 + 0.25·30 = 27.5, bootstrap from t = 3 with γ³.
        let i = find(&batch, [v(1), v(0)]).expect("sampled");
        assert_eq!(
            (batch.returns[i], batch.discounts[i], batch.actions[i]),
            (27.5, 0.125, 1)
        );
        assert_eq!(batch.next_layers[2 * i..2 * i + 2], [v(1), v(3)]);
        assert_eq!(batch.next_scalars[i], 3.0);
        // env 0, t = 1: rewards 2, then 3 at t = 2 where the episode ends: 2 + 0.5·3, no bootstrap.
        let i = find(&batch, [v(0), v(1)]).expect("sampled");
        assert_eq!(
            (batch.returns[i], batch.discounts[i], batch.actions[i]),
            (3.5, 0.0, 1)
        );
        assert_eq!(batch.next_layers[2 * i..2 * i + 2], [0.0, 0.0]);
        // env 0, t = 3 is the first step of the next episode: 4 + 0.5·5 + 0.25·6.
        let i = find(&batch, [v(0), v(3)]).expect("sampled");
        assert_eq!((batch.returns[i], batch.discounts[i]), (8.0, 0.125));
        assert_eq!(batch.next_scalars[i], 6.0);
        // t = 4 waits for its successor at t = 7.
        assert!(find(&batch, [v(1), v(4)]).is_none());
        assert!(batch.weights.iter().all(|&w| w == 1.0));
    }

    #[test]
    fn one_step_transitions_and_ring_overwrite() {
        // Capacity 4 over 2 envs: 2 + 1 + 1 = 4 rows in the ring.
        let buffer = filled(1, 9, 4);
        // Rows 6..=9 alive; ready t with t + 1 <= 9 and t >= 6: t = 6, 7, 8.
        assert_eq!(buffer.len(), 6);
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let batch = buffer.sample(60, 0.4, &mut rng);
        let v = |x: usize| x as f32 / 255.0;
        for i in 0..batch.size {
            let t = batch.scalars[i] as usize;
            assert!(
                (6..=8).contains(&t),
                "step {t} was overwritten or not ready"
            );
            assert_eq!(batch.next_scalars[i], (t + 1) as f32);
            assert_eq!(batch.next_layers[2 * i + 1], v(t + 1));
            let e = (batch.layers[2 * i] * 255.0).round() as usize;
            let expected = if e == 0 {
                (t + 1) as f32
            } else {
                10.0 * (t + 1) as f32
            };
            assert_eq!(batch.returns[i], expected);
            assert_eq!(batch.discounts[i], 0.5);
        }
        for t in 6..=8 {
            assert!(find(&batch, [v(0), v(t)]).is_some() && find(&batch, [v(1), v(t)]).is_some());
        }
    }

    #[test]
    fn prioritised_sampling_follows_td_errors() {
        let mut buffer = ReplayBuffer::new(
            ReplayOptions {
                prioritized: true,
                alpha: 1.0,
                priority_epsilon: 0.0,
                ..options(100, 2, 1)
            },
            SPEC,
        );
        let (o0, o1) = (obs(0, 0), obs(1, 0));
        buffer.start(&[&o0, &o1]);
        let (n0, n1) = (obs(0, 1), obs(1, 1));
        buffer.push(&[0, 0], &[0.0, 0.0], &[false, false], &[&n0, &n1]);
        assert_eq!(buffer.len(), 2);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let batch = buffer.sample(2, 1.0, &mut rng);
        // Env 1's transition gets a TD error three times env 0's.
        let errors: Vec<f32> = batch
            .leaves
            .iter()
            .map(|&l| if l % 2 == 1 { 3.0 } else { 1.0 })
            .collect();
        buffer.update_priorities(&batch.leaves, &errors);
        let batch = buffer.sample(400, 1.0, &mut rng);
        let env1 = batch.leaves.iter().filter(|&&l| l % 2 == 1).count();
        assert_eq!(env1, 300, "stratified: exactly 3/4 of the draws");
        // IS weights (N P(i))^-β normalised by the max: the rarer transition weighs 1.
        for (&leaf, &w) in batch.leaves.iter().zip(&batch.weights) {
            let expected = if leaf % 2 == 1 { 1.0 / 3.0 } else { 1.0 };
            assert!((w - expected).abs() < 1e-6, "{w}");
        }
    }

    #[test]
    fn memory_counts_packed_observations_once() {
        let buffer = filled(1, 20, 10);
        // 2 envs × (5 + 1 + 1) rows, each slot 2 bytes (too short to pack: kept raw).
        assert_eq!(buffer.stored_bytes(), 2 * 7 * 2);
    }
}
