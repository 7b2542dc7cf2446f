//! Throughput of roundabout insertion: policy steps per CPU-second with the full
//! observation (default 4 × 84 × 84 layers) rendered at every 0.1 s step, episodes reset
//! inside the timed loop. Prints one JSON object. Used by `scripts/bench_sim.py`.
//!
//!     cargo run --release -p sim --example bench_insertion -- --steps 100000 --traffic high
//!
//! `--size N`, `--stack N`, `--layers a,b,...` and `--antialias` change the view (the keys
//! of `[agent.task.observation]`), to time a training config's rendering; `--world FILE` runs the
//! calibrated world of a `pipeline sim calibrate` file.
//!
//! CPU time is the main thread's (`/proc/thread-self/schedstat`, Linux): the environment
//! steps on one thread.
#![allow(clippy::print_stdout)]

use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sim::Env;
use sim::tasks::{InsertionConfig, InsertionSetup, RoundaboutInsertion};
use sim::world::TrafficLevel;

#[path = "common/world.rs"]
mod world;

/// CPU time of the calling thread, seconds.
fn thread_cpu_s() -> Result<f64, String> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat")
        .map_err(|e| format!("/proc/thread-self/schedstat: {e}"))?;
    let ns: u64 = text
        .split_whitespace()
        .next()
        .and_then(|f| f.parse().ok())
        .ok_or("/proc/thread-self/schedstat: unexpected content")?;
    Ok(ns as f64 * 1e-9)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut map_path = String::from("data/osm/montlake_roundabout.osm.pbf");
    let mut steps: usize = 10_000;
    let mut traffic = TrafficLevel::High;
    let mut policy = String::from("random");
    let mut seed: u64 = 0;
    let mut arrivals: Option<f64> = None;
    let mut view = sim::render::BevConfig::default();
    let mut world_file: Option<String> = None;
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let mut value = || args.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--map" => map_path = value()?,
            "--world" => world_file = Some(value()?),
            "--steps" => steps = value()?.parse()?,
            "--traffic" => traffic = value()?.parse()?,
            "--policy" => policy = value()?,
            "--seed" => seed = value()?.parse()?,
            "--arrivals-per-s" => arrivals = Some(value()?.parse()?),
            "--size" => {
                view.width = value()?.parse()?;
                view.height = view.width;
            }
            "--stack" => view.stack = value()?.parse()?,
            "--antialias" => view.antialias = true,
            "--layers" => {
                view.layers = value()?
                    .split(',')
                    .map(|name| serde_json::from_value(serde_json::Value::from(name)))
                    .collect::<Result<_, _>>()?
            }
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    let map = maps::import_file(std::path::Path::new(&map_path), &Default::default())
        .map_err(|e| format!("{map_path}: {e}"))?;
    let mut config = InsertionConfig::default();
    if let Some(file) = &world_file {
        world::world(file, &mut config)?;
    }
    config.traffic.level = traffic;
    config.observation = view;
    if let Some(a) = arrivals {
        config.traffic.arrivals_per_s = a;
    }
    let config_arrivals = config.traffic.arrivals_per_s;
    let config_antialias = config.observation.antialias;
    let setup = InsertionSetup::new(Arc::new(map), config)?;
    let mut env = RoundaboutInsertion::new(Arc::clone(&setup));
    let spec = env.observation_spec();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut episode_seed = seed;
    let choose = |rng: &mut ChaCha8Rng| match policy.as_str() {
        "random" => rng.random_range(0..3usize),
        "permitted" => 0,
        "not_permitted" => 1,
        _ => 0,
    };
    let mut layer_bytes = 0usize;
    let mut others = 0usize;
    let mut episodes = 1usize;
    let wall = std::time::Instant::now();
    let cpu0 = thread_cpu_s()?;
    std::hint::black_box(env.reset(episode_seed));
    for _ in 0..steps {
        let step = env.step(choose(&mut rng));
        layer_bytes = std::hint::black_box(&step.observation).layers.len();
        others += env.world().map_or(0, |w| w.others_count());
        if step.outcome.is_some() {
            episode_seed += 1;
            episodes += 1;
            std::hint::black_box(env.reset(episode_seed));
        }
    }
    let cpu_s = thread_cpu_s()? - cpu0;
    let wall_s = wall.elapsed().as_secs_f64();
    let out = serde_json::json!({
        "steps": steps,
        "episodes": episodes,
        "cpu_s": cpu_s,
        "wall_s": wall_s,
        "steps_per_cpu_s": steps as f64 / cpu_s,
        "mean_other_vehicles": others as f64 / steps.max(1) as f64,
        "traffic": traffic.name(),
        "arrivals_per_s": config_arrivals,
        "policy": policy,
        "observation": {"channels": spec.channels, "height": spec.height, "width": spec.width, "scalars": spec.scalars, "antialias": config_antialias},
        "layer_bytes": layer_bytes,
        "map": map_path,
    });
    println!("{out}");
    Ok(())
}
