//! Scenes on drivable maps: a [`maps::Map`] plus the states of the road users on it, the
//! traffic world that moves them, the driving tasks (actions, reward, termination, metrics,
//! baselines) and the bird's-eye observation renderer, which takes a scene rather than
//! simulator internals so recorded logs can be rendered the same way.

pub mod env;

pub use env::{Env, Observation, ObservationSpec, Outcome, Step};
