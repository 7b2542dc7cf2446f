//! A toy task a correct DQN must solve, for the learner's tests: wait at a line for a gap
//! in a stream of cars, then go.
//!
//! Cars move one cell per step along a lane of [`LANE`] cells towards the conflict cell 0
//! (and leave after it); a new car enters at the far end with probability [`ARRIVAL`]
//! every step. Going is safe when cells 0 and 1 are empty (the ego needs two steps to
//! clear the conflict cell): then the episode ends Reached (+1), otherwise Crashed (−1).
//! Waiting costs 0.01 a step; after [`LIMIT`] steps the episode ends TimeOver (−1).
//! The observation is the lane as one row of `u8` cells (255 = car) plus the elapsed time.
//! A uniformly random policy reaches the goal about half the time; waiting for the gap
//! reaches it almost always.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sim::{Env, Observation, ObservationSpec, Outcome, Step};

pub const LANE: usize = 10;
pub const ARRIVAL: f64 = 0.35;
pub const LIMIT: usize = 40;
pub const WAIT: usize = 0;
pub const GO: usize = 1;

#[derive(Debug, Clone)]
pub struct GapEnv {
    rng: ChaCha8Rng,
    cars: [bool; LANE],
    steps: usize,
    ended: Option<Outcome>,
}

impl Default for GapEnv {
    fn default() -> Self {
        GapEnv {
            rng: ChaCha8Rng::seed_from_u64(0),
            cars: [false; LANE],
            steps: 0,
            ended: None,
        }
    }
}

impl GapEnv {
    fn observe(&self) -> Observation {
        Observation {
            layers: self.cars.iter().map(|&c| if c { 255 } else { 0 }).collect(),
            scalars: vec![self.steps as f32 / LIMIT as f32],
        }
    }

    fn advance_traffic(&mut self) {
        self.cars.rotate_left(1);
        self.cars[LANE - 1] = self.rng.random_bool(ARRIVAL);
    }

    /// Whether going now is safe.
    pub fn gap(&self) -> bool {
        !self.cars[0] && !self.cars[1]
    }
}

impl Env for GapEnv {
    fn observation_spec(&self) -> ObservationSpec {
        ObservationSpec {
            channels: 1,
            height: 1,
            width: LANE,
            scalars: 1,
        }
    }

    fn action_count(&self) -> usize {
        2
    }

    fn action_names(&self) -> &'static [&'static str] {
        &["wait", "go"]
    }

    fn reset(&mut self, seed: u64) -> Observation {
        self.rng = ChaCha8Rng::seed_from_u64(seed);
        self.cars = [false; LANE];
        for _ in 0..LANE {
            self.advance_traffic();
        }
        self.steps = 0;
        self.ended = None;
        self.observe()
    }

    fn step(&mut self, action: usize) -> Step {
        if let Some(outcome) = self.ended {
            return Step {
                observation: self.observe(),
                reward: 0.0,
                outcome: Some(outcome),
            };
        }
        self.steps += 1;
        let (reward, outcome) = if action == GO {
            if self.gap() {
                (1.0, Some(Outcome::Reached))
            } else {
                (-1.0, Some(Outcome::Crashed))
            }
        } else if self.steps >= LIMIT {
            (-1.0, Some(Outcome::TimeOver))
        } else {
            (-0.01, None)
        };
        self.advance_traffic();
        self.ended = outcome;
        Step {
            observation: self.observe(),
            reward,
            outcome,
        }
    }
}
