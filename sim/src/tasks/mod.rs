//! Driving tasks: actions, reward, termination, metrics and baselines on the traffic world.

pub mod insertion;

pub use insertion::{
    Action, EpisodeSummary, InsertionConfig, InsertionSetup, InsertionState, RewardConfig,
    RoundaboutInsertion,
};
