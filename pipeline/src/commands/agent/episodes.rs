//! A few greedy episodes of an agent in the rerun recording: on the `step` (and `sim_time`)
//! timeline, the bird's-eye layers the agent saw, every vehicle as a box on the map, the
//! ego's trajectory, the Q-values and the chosen action.
//!
//! Entities: `agent/episode_<k>/layers/<layer>`, `agent/episode_<k>/q/<action>`,
//! `agent/episode_<k>/action` (text), `world/agent/episode_<k>/vehicles` and
//! `world/agent/episode_<k>/trajectory` (with the map under `world/map`).

use std::sync::Arc;

use crate::recording::Stream;
use anyhow::{Context as _, Result};
use models::dqn::greedy_action;
use models::policy::QPolicy;
use sim::Env;
use sim::eval::{Condition, EVAL_STAGE};
use sim::seed::derive_seed;
use sim::tasks::{InsertionSetup, RoundaboutInsertion};

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
        let action_names = env.action_names();
        let mut observation = env.reset(derive_seed(seed, EVAL_STAGE, k as u64));
        let base = format!("agent/episode_{k}");
        let world = format!("world/agent/episode_{k}");
        for step in 0.. {
            let q = policy.q_values(&[&observation]);
            let action = greedy_action(&q);
            rec.set_time_sequence("step", step);
            if let Some(scene) = env.scene() {
                rec.set_duration_secs("sim_time", scene.time_s);
                log_actors(rec, &format!("{world}/vehicles"), &scene.actors, scene.ego)?;
            }
            log_path(rec, &format!("{world}/trajectory"), env.trajectory())?;
            log_layers(
                rec,
                &format!("{base}/layers"),
                env.newest_frame(),
                &layer_names,
                bev.width,
                bev.height,
            )?;
            let q_series: Vec<(String, f64)> = action_names
                .iter()
                .zip(&q)
                .map(|(name, v)| (format!("{base}/q/{name}"), f64::from(*v)))
                .collect();
            let q_series: Vec<(&str, f64)> =
                q_series.iter().map(|(p, v)| (p.as_str(), *v)).collect();
            log_scalars(rec, &q_series)?;
            let name = action_names.get(action).copied().unwrap_or("?");
            rec.log(format!("{base}/action"), &rerun::TextLog::new(name))
                .context("rerun: cannot log an action")?;
            let result = env.step(action);
            observation = result.observation;
            if let Some(outcome) = result.outcome {
                rec.set_time_sequence("step", step + 1);
                log_path(rec, &format!("{world}/trajectory"), env.trajectory())?;
                rec.log(
                    format!("{base}/action"),
                    &rerun::TextLog::new(format!("episode ended: {outcome:?}")),
                )
                .context("rerun: cannot log an outcome")?;
                break;
            }
        }
    }
    Ok(())
}
