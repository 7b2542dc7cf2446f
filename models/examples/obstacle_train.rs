//! Trains a DQN agent on obstacle avoidance and evaluates it beside the baselines: the
//! tuning driver for the task until `pipeline agent train --task obstacle-avoidance`
//! exists, and a check of it after.
//!
//! Usage: `obstacle_train CONFIG.toml [--seed 1] [--episodes 500] [--out DIR]`. CONFIG
//! holds `[agent.dqn]` (models' `DqnConfig`) and `[agent.obstacle]` (sim's
//! `ObstacleConfig`), the tables the pipeline reads. Prints the training progress, the wall
//! time, and one markdown table per scenario (static, crossing) on seeds 1,000,000 + i.

#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::time::Instant;

use models::dqn::{DqnConfig, EpisodeRecord, OutcomeName, TrainObserver, TrainState, train};
use models::policy::QPolicy;
use sim::Env;
use sim::tasks::obstacle::{ObstacleAvoidance, ObstacleConfig, ObstacleSetup, Scenario};
use sim::tasks::{PolicyFactory, Task, TaskResult, run_episodes, task_table};

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Prints the reach rate of the last 200 training episodes every 20,000 transitions.
struct Progress {
    started: Instant,
    recent: std::collections::VecDeque<bool>,
    next_report: u64,
}

impl TrainObserver for Progress {
    fn iteration(&mut self, state: &TrainState, epsilon: f64) -> bool {
        if state.steps >= self.next_report {
            let rate =
                self.recent.iter().filter(|r| **r).count() as f64 / self.recent.len().max(1) as f64;
            println!(
                "{:>8} steps {:>6} episodes  eps {:.3}  reached (last {}) {:.1} %  {:.0} s",
                state.steps,
                state.episodes,
                epsilon,
                self.recent.len(),
                100.0 * rate,
                self.started.elapsed().as_secs_f64()
            );
            self.next_report += 20_000;
        }
        true
    }

    fn episode(&mut self, record: &EpisodeRecord) {
        if self.recent.len() == 200 {
            self.recent.pop_front();
        }
        self.recent
            .push_back(matches!(record.outcome, OutcomeName::Reached));
    }
}

#[derive(serde::Deserialize, Default)]
#[serde(default)]
struct Agent {
    dqn: DqnConfig,
    obstacle: ObstacleConfig,
}

#[derive(serde::Deserialize, Default)]
#[serde(default)]
struct File {
    agent: Agent,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).ok_or("usage: obstacle_train CONFIG.toml")?;
    let file: File = toml::from_str(&std::fs::read_to_string(path)?)?;
    let seed: u64 = arg(&args, "--seed", 1);
    let episodes: u64 = arg(&args, "--episodes", 500);
    let setup = ObstacleSetup::new(file.agent.obstacle.clone())?;
    let device = models::cpu_device();
    let envs: Vec<ObstacleAvoidance> = (0..file.agent.dqn.envs)
        .map(|_| ObstacleAvoidance::new(setup.clone()))
        .collect();
    let started = Instant::now();
    let mut progress = Progress {
        started,
        recent: Default::default(),
        next_report: 0,
    };
    let checkpoint = train(&file.agent.dqn, seed, envs, None, &device, &mut progress)?;
    let train_s = started.elapsed().as_secs_f64();
    println!(
        "trained {} transitions, {} episodes in {train_s:.0} s",
        checkpoint.state.steps, checkpoint.state.episodes
    );
    if let Some(out) = args
        .iter()
        .position(|a| a == "--out")
        .and_then(|i| args.get(i + 1))
    {
        std::fs::create_dir_all(out)?;
        checkpoint.save(std::path::Path::new(out))?;
    }
    let probe = ObstacleAvoidance::new(setup.clone());
    let spec = probe.observation_spec();
    let actions = probe.action_count();
    let network = checkpoint.online.clone();
    let seeds: Vec<u64> = (0..episodes).map(|i| 1_000_000 + i).collect();
    for scenario in [Scenario::Static, Scenario::Crossing] {
        let make_env = || {
            let mut env = ObstacleAvoidance::new(setup.clone());
            env.set_scenario(scenario);
            env
        };
        let agent_episodes = run_episodes(
            make_env,
            || QPolicy::new(network.clone(), spec, actions, device.clone()),
            &seeds,
            64,
        );
        let mut rows = vec![("DQN agent".to_owned(), TaskResult::of(&agent_episodes))];
        let baselines: Vec<(String, PolicyFactory<ObstacleAvoidance>)> =
            ObstacleAvoidance::baselines();
        for (name, make) in baselines {
            let episodes = run_episodes(make_env, &make, &seeds, 64);
            rows.push((name, TaskResult::of(&episodes)));
        }
        println!(
            "\n{scenario:?} ({episodes} episodes each)\n{}",
            task_table(&rows)
        );
    }
    Ok(())
}
