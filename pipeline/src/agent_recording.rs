//! What the rerun recording shows of agents: the curves of a training run, and a few greedy
//! episodes of an agent.
//!
//! Curves, on the `step` timeline: `agent/train/{return,length,epsilon}` per episode,
//! `agent/train/rate/{reached,crashed,time_over}` over the newest episodes
//! ([`models::training::OutcomeRates`]), `agent/train/{td_loss,mean_q}`, and
//! `agent/validation/{score,<condition>}` per validated checkpoint.
//!
//! Greedy episodes, on the `step` (and `sim_time`) timeline: every vehicle as a box on the
//! map, the ego's trajectory, the Q-values and the chosen action; for roundabout insertion
//! also the bird's-eye layers the agent saw. Entities: `agent/episode_<k>/layers/<layer>`,
//! `agent/episode_<k>/q/<action>`, `agent/episode_<k>/action` (text),
//! `world/agent/episode_<k>/vehicles` and `world/agent/episode_<k>/trajectory` (with the map
//! under `world/map`).

use anyhow::{Context as _, Result};
use maps::Point;
use models::dqn::{EpisodeRecord, LossRecord, TrainState, greedy_action};
use models::policy::QPolicy;
use models::training::OutcomeRates;
use models::validation::ValidationPoint;
use sim::eval::EVAL_STAGE;
use sim::seed::derive_seed;
use sim::tasks::Task;
use sim::{Outcome, Scene};

use crate::recording::{Stream, log_actors, log_layers, log_path, log_scalars};

/// The curves of an earlier part of a resumed run, so the recording shows the whole run.
pub fn log_history(rec: &Stream, state: &TrainState) -> Result<()> {
    let rates = OutcomeRates::along(&state.episode_history);
    for (record, rates) in state.episode_history.iter().zip(&rates) {
        log_episode(rec, record, rates)?;
    }
    for record in &state.loss_history {
        log_losses(rec, record)?;
    }
    Ok(())
}

/// One finished training episode, with the rates after it.
pub fn log_episode(rec: &Stream, record: &EpisodeRecord, rates: &[(&str, f64)]) -> Result<()> {
    rec.set_time_sequence("step", record.step as i64);
    let mut scalars = vec![
        ("agent/train/return", record.episode_return),
        ("agent/train/length", record.length as f64),
        ("agent/train/epsilon", record.epsilon),
    ];
    let rate_paths: Vec<(String, f64)> = rates
        .iter()
        .map(|(name, v)| (format!("agent/train/rate/{name}"), *v))
        .collect();
    scalars.extend(rate_paths.iter().map(|(p, v)| (p.as_str(), *v)));
    log_scalars(rec, &scalars)
}

pub fn log_losses(rec: &Stream, record: &LossRecord) -> Result<()> {
    rec.set_time_sequence("step", record.step as i64);
    log_scalars(
        rec,
        &[
            ("agent/train/td_loss", record.td_loss),
            ("agent/train/mean_q", record.mean_q),
        ],
    )
}

/// The validation curves: the score and each condition's share reached.
pub fn log_validation(rec: &Stream, point: &ValidationPoint) -> Result<()> {
    rec.set_time_sequence("step", point.steps as i64);
    let entities: Vec<(String, f64)> = std::iter::once(("score".to_owned(), point.score))
        .chain(
            point
                .reached
                .iter()
                .map(|(name, r)| (name.replace(' ', "_"), *r)),
        )
        .map(|(name, value)| (format!("agent/validation/{name}"), value))
        .collect();
    let series: Vec<(&str, f64)> = entities.iter().map(|(e, v)| (e.as_str(), *v)).collect();
    log_scalars(rec, &series)
}

/// Logs `count` greedy episodes of `policy` in environments from `make_env`: the same
/// episodes (seeds) as the first `count` of an evaluation with `seed`.
pub fn record_episodes<T: Task>(
    rec: &Stream,
    make_env: impl Fn() -> T,
    policy: &QPolicy,
    count: usize,
    seed: u64,
) -> Result<()> {
    for k in 0..count {
        let mut env = make_env();
        run_greedy(rec, &mut env, policy, seed, k, |env, base| {
            log_world(rec, k, env.scene(), env.trajectory())?;
            match env.recorded_layers() {
                Some(frame) => {
                    let names: Vec<&str> = frame.names.iter().map(|l| l.name()).collect();
                    let entity = format!("{base}/layers");
                    log_layers(
                        rec,
                        &entity,
                        frame.layers,
                        &names,
                        frame.width,
                        frame.height,
                    )
                }
                None => Ok(()),
            }
        })?;
    }
    Ok(())
}

/// Runs greedy episode `k` (reset as evaluation episode `k` of `seed`), logging the
/// Q-values and actions, and calling `log_state(env, base entity)` before every step and
/// after the last.
fn run_greedy<E: Task>(
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

/// `curves.png` of a training run: the return of each episode (averaged over the last
/// [`CURVE_WINDOW`] episodes) and the reach and crash rates, against transitions.
pub fn curves_png(state: &TrainState) -> Result<Vec<u8>> {
    let history = &state.episode_history;
    let rates = OutcomeRates::along(history);
    // At most about 600 points a series: the curves are averages over windows already.
    let stride = (history.len() / 600).max(1);
    let mut curves = crate::plots::AgentCurves::default();
    let mut window: std::collections::VecDeque<f64> = std::collections::VecDeque::new();
    let mut sum = 0.0;
    for (i, (record, rates)) in history.iter().zip(&rates).enumerate() {
        window.push_back(record.episode_return);
        sum += record.episode_return;
        if window.len() > CURVE_WINDOW {
            sum -= window.pop_front().unwrap_or(0.0);
        }
        if i % stride != 0 && i + 1 != history.len() {
            continue;
        }
        let rate = |name: &str| rates.iter().find(|(n, _)| *n == name).map_or(0.0, |r| r.1);
        curves
            .returns
            .push((record.step, sum / window.len() as f64));
        curves.reach_rate.push((record.step, rate("reached")));
        curves.crash_rate.push((record.step, rate("crashed")));
    }
    crate::plots::agent_curves_png(&curves)
}

/// Episodes the return curve of `curves.png` is averaged over (as the outcome rates are).
pub const CURVE_WINDOW: usize = models::training::RATE_WINDOW;
