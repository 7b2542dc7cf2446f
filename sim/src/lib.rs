//! Scenes on drivable maps: a [`maps::Map`] plus the states of the road users on it, the
//! traffic world that moves them, the driving tasks (actions, reward, termination, metrics,
//! baselines) and the bird's-eye observation renderer, which takes a scene rather than
//! simulator internals so recorded logs can be rendered the same way.
//!
//! - [`scene`]: [`Scene`] and [`Actor`] (plain data: what the renderer and rerun logging use).
//! - [`roundabout`]: the routes through a roundabout (entry, ring, exit), prepared per map.
//! - [`world`]: the traffic world (IDM, gap acceptance, aggressiveness, spawning, the ego's
//!   kinematic bicycle), deterministic under a seed.
//! - [`render`]: the bird's-eye representation (layers, frame stack).
//! - [`tasks`]: the driving tasks, each an [`Env`] implementing [`tasks::Task`], listed in
//!   one registry ([`tasks::registry`]).
//! - [`observer`]: which layers a task observes ([`observer::View`]) and the hook for layers
//!   drawn outside `sim` (the camera-segmentation view of `models`).
//! - [`baselines`] and [`eval`]: roundabout insertion's rules, and the parallel evaluation
//!   harness of every task that learned policies plug into; [`stats`]: the intervals and
//!   paired tests their reports give.

pub mod baselines;
pub mod env;
pub mod error;
pub mod eval;
pub mod kinematics;
pub mod observer;
pub mod path;
pub mod render;
pub mod roundabout;
pub mod scene;
pub mod seed;
pub mod spatial;
pub mod stats;
pub mod synthetic;
pub mod tasks;
pub mod world;

#[cfg(test)]
pub(crate) mod test_maps;

pub use env::{Env, Observation, ObservationSpec, Outcome, Step};
pub use error::SimError;
pub use scene::{Actor, ActorKind, OrientedBox, Scene};
