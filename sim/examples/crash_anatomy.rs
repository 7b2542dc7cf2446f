//! Where roundabout-insertion crashes happen: runs a baseline policy and, for every crash,
//! prints where the ego and the vehicle it touched were on their routes.
//!
//!     cargo run --release -p sim --example crash_anatomy -- [MAP] [EPISODES] [RULE_M]
#![allow(clippy::print_stdout, clippy::print_stderr, clippy::unwrap_used)]

use std::sync::Arc;

use sim::Env;
use sim::baselines::{Baseline, Policy, PolicyInput};
use sim::env::Outcome;
use sim::eval::EVAL_STAGE;
use sim::seed::derive_seed;
use sim::tasks::{InsertionConfig, InsertionSetup, RoundaboutInsertion, Task};
use sim::world::TrafficLevel;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let map_path = args
        .first()
        .cloned()
        .unwrap_or_else(|| "data/osm/montlake_roundabout.osm.pbf".into());
    let episodes: usize = args.get(1).map_or(Ok(300), |a| a.parse())?;
    let threshold_m: f64 = args.get(2).map_or(Ok(25.0), |a| a.parse())?;
    let map = maps::import_file(std::path::Path::new(&map_path), &Default::default())?;
    let setup = InsertionSetup::new(Arc::new(map), InsertionConfig::default())?;
    let mut policy = Baseline::Rule { threshold_m };
    let mut crashes = 0;
    for k in 0..episodes {
        let seed = derive_seed(0, EVAL_STAGE, k as u64);
        let mut env = RoundaboutInsertion::new(Arc::clone(&setup));
        env.set_traffic(TrafficLevel::Medium);
        env.set_aggressiveness(Some(0.5));
        env.set_rendering(false);
        let mut observation = env.reset(seed);
        let mut steps = 0;
        let mut actions = Vec::new();
        loop {
            let state = env.state();
            policy.act(
                &[PolicyInput {
                    slot: 0,
                    episode_seed: seed,
                    step: steps,
                    observation: &observation,
                    state: &state,
                }],
                &mut actions,
            );
            let step = env.step(actions[0]);
            steps += 1;
            observation = step.observation;
            if step.outcome.is_some() {
                break;
            }
        }
        if env.outcome() == Some(Outcome::OffRoad) {
            let world = env.world().unwrap();
            let ego = &world.vehicles()[world.ego_index().unwrap()];
            let r = world.route(ego);
            let (on_path, _) = r.path.pose_at(ego.s);
            println!(
                "ep {k:4} off-road: route {}->{} s {:.1} (yield {:.1} merge {:.1} exit {:.1} end {:.1}) off path {:.2} path point navigable {}",
                r.entry,
                r.exit,
                ego.s,
                r.yield_s,
                r.merge_s,
                r.exit_s,
                r.path.length(),
                on_path.distance(ego.position),
                env.renderer().raster().navigable(on_path)
            );
        }
        if env.outcome() != Some(Outcome::Crashed) {
            continue;
        }
        crashes += 1;
        let world = env.world().unwrap();
        let ego_i = world.ego_index().unwrap();
        let ego = &world.vehicles()[ego_i];
        let fp = ego.footprint();
        let er = world.route(ego);
        for (j, o) in world.vehicles().iter().enumerate() {
            if j == ego_i || !o.footprint().overlaps(&fp) {
                continue;
            }
            let or = world.route(o);
            if std::env::var("DEBUG_LEADER").is_ok() {
                let ep = er.path.pieces()[ego.piece];
                let op = or.path.pieces()[o.piece];
                println!(
                    "  other's leader {:?}; ego piece {:?} at {:.1} of [{:.1}, {:.1}]; other piece {:?} at {:.1} of [{:.1}, {:.1}]",
                    world.leader(j),
                    ep.key,
                    ego.s,
                    ep.s_start,
                    ep.s_end,
                    op.key,
                    o.s,
                    op.s_start,
                    op.s_end
                );
            }
            let (on_path, _) = er.path.pose_at(ego.s);
            let off = ((on_path.x - ego.position.x).powi(2) + (on_path.y - ego.position.y).powi(2))
                .sqrt();
            let (o_path, _) = or.path.pose_at(o.s);
            let o_off =
                ((o_path.x - o.position.x).powi(2) + (o_path.y - o.position.y).powi(2)).sqrt();
            let (dx, dy) = (o.position.x - ego.position.x, o.position.y - ego.position.y);
            let (c, s) = (ego.heading.cos(), ego.heading.sin());
            let (fwd, left) = (dx * c + dy * s, -dx * s + dy * c);
            println!(
                "ep {k:4} t {:5.1}s | ego: to yield {:6.1} to merge {:6.1} v {:4.1} committed {} entry {} exit {} \
                 | other: to yield {:6.1} to merge {:6.1} v {:4.1} a {:5.1} committed {} entry {} exit {} | other at fwd {:5.1} left {:5.1} rel heading {:5.0}° | ego off path {:4.2} other {:4.2}",
                steps as f64 * 0.1,
                er.yield_s - ego.s,
                er.merge_s - ego.s,
                ego.speed,
                ego.committed,
                er.entry,
                er.exit,
                or.yield_s - o.s,
                or.merge_s - o.s,
                o.speed,
                o.accel,
                o.committed,
                or.entry,
                or.exit,
                fwd,
                left,
                (o.heading - ego.heading).to_degrees().rem_euclid(360.0),
                off,
                o_off,
            );
        }
    }
    eprintln!("{crashes} crashes in {episodes} episodes");
    Ok(())
}
