//! A few greedy episodes of an agent in the rerun recording: on the `step` (and `sim_time`)
//! timeline, every vehicle as a box on the map, the ego's trajectory, the Q-values and the
//! chosen action; for roundabout insertion also the bird's-eye layers the agent saw.
//!
//! Entities: `agent/episode_<k>/layers/<layer>` (insertion), `agent/episode_<k>/q/<action>`,
//! `agent/episode_<k>/action` (text), `world/agent/episode_<k>/vehicles` and
//! `world/agent/episode_<k>/trajectory` (with the map under `world/map`).

use std::sync::Arc;

use crate::recording::Stream;
use anyhow::{Context as _, Result};
use maps::Point;
use models::dqn::greedy_action;
use models::policy::QPolicy;
use sim::eval::{Condition, EVAL_STAGE};
use sim::seed::derive_seed;
use sim::tasks::{InsertionSetup, RoundaboutInsertion, Task};
use sim::{Env, Outcome, Scene};

use crate::recording::{log_actors, log_layers, log_path, log_scalars};

/// Logs `count` greedy episodes of `policy` under `condition`: the same episodes (seeds)
/// as the first `count` of an evaluation with `seed`.
pub fn record(
    rec: &Stream,
    setup: &Arc<InsertionSetup>,
    policy: &QPolicy,
    condition: Condition,
    count: usize,
    seed: u64,
) -> Result<()> {
    let bev = &setup.config().observation;
    let layer_names: Vec<&str> = bev.layers.iter().map(|l| l.name()).collect();
    for k in 0..count {
        let mut env = RoundaboutInsertion::new(Arc::clone(setup));
        env.set_traffic(condition.traffic);
        env.set_aggressiveness(Some(condition.aggressiveness));
        run_greedy(rec, &mut env, policy, seed, k, |env, base| {
            log_world(rec, k, env.scene(), env.trajectory())?;
            log_layers(
                rec,
                &format!("{base}/layers"),
                env.newest_frame(),
                &layer_names,
                bev.width,
                bev.height,
            )
        })?;
    }
    Ok(())
}

/// Like [`record`], for any [`Task`] made by `make_env`.
pub fn record_task<E: Task>(
    rec: &Stream,
    make_env: impl Fn() -> E,
    policy: &QPolicy,
    count: usize,
    seed: u64,
) -> Result<()> {
    for k in 0..count {
        let mut env = make_env();
        run_greedy(rec, &mut env, policy, seed, k, |env, _| {
            log_world(rec, k, env.scene(), env.trajectory())
        })?;
    }
    Ok(())
}

/// Runs greedy episode `k` (reset as evaluation episode `k` of `seed`), logging the
/// Q-values and actions, and calling `log_state(env, base entity)` before every step and
/// after the last.
fn run_greedy<E: Env>(
    rec: &Stream,
    env: &mut E,
    policy: &QPolicy,
    seed: u64,
    k: usize,
    mut log_state: impl FnMut(&E, &str) -> Result<()>,
) -> Result<()> {
    let action_names = env.action_names();
    let mut observation = env.reset(derive_seed(seed, EVAL_STAGE, k as u64));
    let base = format!("agent/episode_{k}");
    for step in 0.. {
        let q = policy.q_values(&[&observation]);
        let action = greedy_action(&q);
        rec.set_time_sequence("step", step);
        log_state(env, &base)?;
        let q_series: Vec<(String, f64)> = action_names
            .iter()
            .zip(&q)
            .map(|(name, v)| (format!("{base}/q/{name}"), f64::from(*v)))
            .collect();
        let q_series: Vec<(&str, f64)> = q_series.iter().map(|(p, v)| (p.as_str(), *v)).collect();
        log_scalars(rec, &q_series)?;
        let name = action_names.get(action).copied().unwrap_or("?");
        rec.log(format!("{base}/action"), &rerun::TextLog::new(name))
            .context("rerun: cannot log an action")?;
        let result = env.step(action);
        observation = result.observation;
        if let Some(outcome) = result.outcome {
            rec.set_time_sequence("step", step + 1);
            log_state(env, &base)?;
            log_outcome(rec, &base, outcome)?;
            break;
        }
    }
    Ok(())
}

/// The vehicles and the ego's trajectory of episode `k`.
fn log_world(rec: &Stream, k: usize, scene: Option<Scene<'_>>, trajectory: &[Point]) -> Result<()> {
    let world = format!("world/agent/episode_{k}");
    if let Some(scene) = scene {
        rec.set_duration_secs("sim_time", scene.time_s);
        log_actors(rec, &format!("{world}/vehicles"), &scene.actors, scene.ego)?;
    }
    log_path(rec, &format!("{world}/trajectory"), trajectory)
}

fn log_outcome(rec: &Stream, base: &str, outcome: Outcome) -> Result<()> {
    rec.log(
        format!("{base}/action"),
        &rerun::TextLog::new(format!("episode ended: {outcome:?}")),
    )
    .context("rerun: cannot log an outcome")
}
