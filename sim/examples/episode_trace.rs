//! One evaluation episode of roundabout insertion under a baseline, second by second: where the
//! ego is on its route, its speed and leader, and every other vehicle within 30 m.
//!
//!     cargo run --release -p sim --example episode_trace -- EPISODE [RULE_M] [MAP]
#![allow(clippy::print_stdout, clippy::print_stderr, clippy::unwrap_used)]

use std::sync::Arc;

use sim::Env;
use sim::baselines::{Baseline, Policy, PolicyInput};
use sim::eval::EVAL_STAGE;
use sim::seed::derive_seed;
use sim::tasks::{InsertionConfig, InsertionSetup, RoundaboutInsertion, Task};
use sim::world::{Leader, TrafficLevel};

/// A vehicle ahead as (index, gap to 0.1 m).
fn brief(ahead: Option<Leader>) -> Option<(usize, f64)> {
    ahead.map(|l| (l.index, (l.gap_m * 10.0).round() / 10.0))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let episode: u64 = args.first().ok_or("EPISODE missing")?.parse()?;
    let threshold_m: f64 = args.get(1).map_or(Ok(10.0), |a| a.parse())?;
    let map_path = args
        .get(2)
        .cloned()
        .unwrap_or_else(|| "data/osm/montlake_roundabout.osm.pbf".into());
    let map = maps::import_file(std::path::Path::new(&map_path), &Default::default())?;
    let setup = InsertionSetup::new(Arc::new(map), InsertionConfig::default())?;
    let mut policy = Baseline::Rule { threshold_m };
    let seed = derive_seed(0, EVAL_STAGE, episode);
    let mut env = RoundaboutInsertion::new(Arc::clone(&setup));
    env.set_traffic(TrafficLevel::Medium);
    env.set_aggressiveness(Some(0.5));
    env.set_rendering(false);
    let mut observation = env.reset(seed);
    let mut actions = Vec::new();
    for step in 0.. {
        let state = env.state();
        policy.act(
            &[PolicyInput {
                slot: 0,
                episode_seed: seed,
                step,
                observation: &observation,
                state: &state,
            }],
            &mut actions,
        );
        if step % 10 == 0 {
            let world = env.world().unwrap();
            let ego_i = world.ego_index().unwrap();
            let ego = &world.vehicles()[ego_i];
            let r = world.route(ego);
            println!(
                "t {:5.1} action {:?} ego {}->{} to yield {:6.1} to merge {:6.1} to exit {:6.1} to end {:6.1} v {:4.1} #{ego_i} leader {:?} merging {:?} obstacle {:?}",
                step as f64 * 0.1,
                actions[0],
                r.entry,
                r.exit,
                r.yield_s - ego.s,
                r.merge_s - ego.s,
                r.exit_s - ego.s,
                r.path.length() - ego.s,
                ego.speed,
                brief(world.leader(ego_i)),
                brief(world.merging_leader(ego_i)),
                brief(world.obstacle_on_path(ego_i, 8.0)),
            );
            for (j, o) in world.vehicles().iter().enumerate() {
                let d = o.position.distance(ego.position);
                if j == ego_i || d > 30.0 {
                    continue;
                }
                let or = world.route(o);
                println!(
                    "    #{j} id {} {}->{} d {:5.1} to yield {:6.1} to merge {:6.1} to exit {:6.1} v {:4.1} committed {} leader {:?} merging {:?} obstacle {:?}",
                    o.id,
                    or.entry,
                    or.exit,
                    d,
                    or.yield_s - o.s,
                    or.merge_s - o.s,
                    or.exit_s - o.s,
                    o.speed,
                    o.committed,
                    brief(world.leader(j)),
                    brief(world.merging_leader(j)),
                    brief(world.obstacle_on_path(j, 8.0)),
                );
            }
        }
        let outcome = env.step(actions[0]);
        observation = outcome.observation;
        if let Some(o) = outcome.outcome {
            println!("outcome {o:?} after {} steps", step + 1);
            break;
        }
    }
    Ok(())
}
