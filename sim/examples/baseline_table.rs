//! Baseline table of the roundabout-insertion task: every standard baseline under the
//! chosen conditions, as markdown on stdout (and JSON with `--json FILE`).
//!
//!     cargo run --release -p sim --example baseline_table -- \
//!         --map data/osm/montlake_roundabout.osm.pbf --traffic medium --aggressiveness 0.5 --episodes 3000
//!
//! `--action-repeat N` lets every policy decide every N world steps (`InsertionConfig::action_repeat`).
//! `--failures` also lists, per policy and condition, the episodes that did not reach the goal.
//! `--world FILE` runs the calibrated world of a `pipeline sim calibrate` file (its `[traffic]`,
//! `[layout]` and `[recorded]` flows), adds its critical-gap rule and prints what each traffic
//! level means in vehicles per hour on the map's roundabout.
#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::sync::Arc;

use sim::baselines::Baseline;
use sim::env::Outcome;
use sim::eval::{Condition, EvalOptions, evaluate_episodes, markdown_table, summarise_conditions};
use sim::tasks::{InsertionConfig, InsertionSetup};
use sim::world::TrafficLevel;

#[path = "common/world.rs"]
mod world;
use world::world;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut map_path = String::from("data/osm/montlake_roundabout.osm.pbf");
    let mut traffic: Vec<TrafficLevel> = Vec::new();
    let mut aggressiveness: Vec<f64> = Vec::new();
    let mut options = EvalOptions {
        episodes: 300,
        ..EvalOptions::default()
    };
    let mut json: Option<String> = None;
    let mut failures = false;
    let mut config = InsertionConfig::default();
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let mut value = || args.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--map" => map_path = value()?,
            "--traffic" => traffic.push(value()?.parse()?),
            "--aggressiveness" => aggressiveness.push(value()?.parse()?),
            "--episodes" => options.episodes = value()?.parse()?,
            "--seed" => options.seed = value()?.parse()?,
            "--json" => json = Some(value()?),
            "--action-repeat" => config.action_repeat = value()?.parse()?,
            "--failures" => failures = true,
            "--world" => world(&value()?, &mut config)?,
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    if traffic.is_empty() {
        traffic.push(TrafficLevel::Medium);
    }
    if aggressiveness.is_empty() {
        aggressiveness.push(0.5);
    }
    let conditions: Vec<Condition> = traffic
        .iter()
        .flat_map(|&t| {
            aggressiveness.iter().map(move |&a| Condition {
                traffic: t,
                aggressiveness: a,
            })
        })
        .collect();
    let map = maps::import_file(std::path::Path::new(&map_path), &Default::default())
        .map_err(|e| format!("{map_path}: {e}"))?;
    let setup = InsertionSetup::new(Arc::new(map), config)?;
    let mut baselines = Baseline::STANDARD.to_vec();
    if let Some(gap) = setup.config().traffic.drivers.critical_gap.measured() {
        baselines.push(Baseline::CriticalGap {
            seconds: gap.median_s,
        });
    }
    if let Some(capacity) = setup.config().traffic.capacity {
        for layout in setup.layouts() {
            let entries = layout.usable_entries().count();
            let levels: Vec<String> = TrafficLevel::ALL
                .iter()
                .map(|l| {
                    let q = capacity.entry_flow_vph(layout, l.saturation().unwrap_or(0.0));
                    format!(
                        "{} {q:.0} veh/h per entry ({:.0} in all)",
                        l.name(),
                        q * entries as f64
                    )
                })
                .collect();
            eprintln!("roundabout {}: {}", layout.roundabout.0, levels.join(", "));
        }
    }
    let started = std::time::Instant::now();
    let mut rows = Vec::new();
    for baseline in baselines {
        let episodes = evaluate_episodes(&setup, || baseline, &conditions, &options, &|_| {});
        if failures {
            for (condition, summaries) in conditions.iter().zip(&episodes) {
                let failed: Vec<String> = summaries
                    .iter()
                    .enumerate()
                    .filter(|(_, e)| e.outcome != Outcome::Reached)
                    .map(|(k, e)| format!("{k} {}", e.outcome.name()))
                    .collect();
                eprintln!(
                    "{} at {} traffic, aggressiveness {}: did not reach in {}",
                    baseline.name(),
                    condition.traffic.name(),
                    condition.aggressiveness,
                    failed.join(", ")
                );
            }
        }
        rows.push((
            baseline.name(),
            summarise_conditions(&conditions, &episodes),
        ));
    }
    println!("{}", markdown_table(&rows));
    eprintln!(
        "{} episodes per condition and policy, seed {}, {:.1} s wall",
        options.episodes,
        options.seed,
        started.elapsed().as_secs_f64()
    );
    if let Some(path) = json {
        let value: Vec<_> = rows
            .iter()
            .map(|(name, results)| serde_json::json!({"policy": name, "conditions": results}))
            .collect();
        std::fs::write(&path, serde_json::to_string_pretty(&value)?)?;
    }
    Ok(())
}
