//! The roundabout-driving baselines on a map: one row per constant action and the rule,
//! the same episodes for each.
//!
//!     cargo run --release -p sim --example ring_driving_table -- <map> [episodes] [traffic]
#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::sync::Arc;

use sim::eval::{TaskResult, run_episodes, task_table};
use sim::tasks::{RingDriving, RingDrivingConfig, RingDrivingSetup, Task};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let map_path = args
        .next()
        .ok_or("usage: ring_driving_table <map> [episodes] [traffic]")?;
    let episodes: u64 = args.next().map_or(Ok(300), |a| a.parse())?;
    let mut config = RingDrivingConfig::default();
    if let Some(level) = args.next() {
        config.traffic.level = level.parse()?;
    }
    let map = maps::import_file(std::path::Path::new(&map_path), &Default::default())?;
    let setup = RingDrivingSetup::new(Arc::new(map), config)?;
    let seeds: Vec<u64> = (0..episodes).collect();
    let mut rows = Vec::new();
    for (name, make_policy) in RingDriving::baselines() {
        let make_env = || {
            let mut env = RingDriving::new(Arc::clone(&setup));
            env.set_rendering(false);
            env
        };
        let summaries = run_episodes(make_env, &make_policy, &seeds, 16);
        rows.push((name, TaskResult::of(&summaries)));
    }
    print!("{}", task_table(&rows));
    Ok(())
}
