//! One evaluation episode of roundabout insertion driven by a trained agent, decision by
//! decision: its Q-values, action and scalar inputs, where the ego is on its route, every
//! other vehicle within 30 m (each 5 decisions), and at the end the vehicle whose centre is
//! nearest the ego's. The episode is the one `agent eval --seed SEED` draws
//! as episode EPISODE, at medium traffic.
//!
//!     cargo run --release -p pipeline --example agent_episode_trace -- AGENT EPISODE \
//!         [--aggressiveness 0.5] [--seed 0] [--action-repeat 1] [--map MAP] [--dump STEP,...]
//!
//! `--action-repeat` as `agent eval`'s (1: deciding every 0.1 s); `--dump` prints every layer
//! of the observation at those decisions as text (`.` empty, `-` `+` `#` brighter).
#![allow(clippy::print_stdout, clippy::print_stderr, clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::sync::Arc;

use models::dqn::{load_network, read_agent_description};
use models::policy::QPolicy;
use pipeline::agent_folder::{TASK_FILE, TaskRecord};
use sim::Env;
use sim::eval::EVAL_STAGE;
use sim::seed::derive_seed;
use sim::tasks::{InsertionSetup, RoundaboutInsertion};
use sim::world::{TrafficLevel, Vehicle, World};

fn describe(world: &World, j: usize, ego: &Vehicle) -> String {
    let o = &world.vehicles()[j];
    let r = world.route(o);
    format!(
        "#{j} id {} {}->{} d {:5.1} to yield {:6.1} to merge {:6.1} to exit {:6.1} v {:4.1} committed {}",
        o.id,
        r.entry,
        r.exit,
        o.position.distance(ego.position),
        r.yield_s - o.s,
        r.merge_s - o.s,
        r.exit_s - o.s,
        o.speed,
        o.committed,
    )
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let option = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
    };
    let agent = PathBuf::from(args.first().ok_or("AGENT missing")?);
    let episode: u64 = args.get(1).ok_or("EPISODE missing")?.parse()?;
    let aggressiveness: f64 = option("--aggressiveness").map_or(Ok(0.5), |a| a.parse())?;
    let seed: u64 = option("--seed").map_or(Ok(0), |a| a.parse())?;
    let repeat: usize = option("--action-repeat").map_or(Ok(1), |a| a.parse())?;
    let map_path = option("--map")
        .cloned()
        .unwrap_or_else(|| "data/osm/montlake_roundabout.osm.pbf".into());
    let dump: Vec<usize> = option("--dump").map_or(Ok(Vec::new()), |list| {
        list.split(',').map(str::parse).collect::<Result<_, _>>()
    })?;

    let task_file = agent.join(TASK_FILE);
    let record: TaskRecord = serde_json::from_str(&std::fs::read_to_string(&task_file)?)?;
    let config = record.insertion_config(&task_file)?.deciding_every(repeat);
    let map = maps::import_file(Path::new(&map_path), &Default::default())?;
    let setup = InsertionSetup::new(Arc::new(map), config)?;
    let description = read_agent_description(&agent)?;
    let network = load_network(&agent, &description, &models::cpu_device())?;
    let policy = QPolicy::new(
        network,
        setup.observation_spec(),
        description.shape.actions,
        models::cpu_device(),
    );

    let mut env = RoundaboutInsertion::new(Arc::clone(&setup));
    env.set_traffic(TrafficLevel::Medium);
    env.set_aggressiveness(Some(aggressiveness));
    let mut observation = env.reset(derive_seed(seed, EVAL_STAGE, episode));
    let start_s = env.world().unwrap().time_s();
    for step in 0.. {
        let q = policy.q_values(&[&observation]);
        let action = models::dqn::greedy_action(&q);
        {
            let world = env.world().unwrap();
            let ego_i = world.ego_index().unwrap();
            let ego = &world.vehicles()[ego_i];
            let r = world.route(ego);
            println!(
                "decision {step:3} t {:5.1} Q {q:+.4?} action {action} ego {}->{} to yield {:6.1} to merge {:6.1} v {:4.1}",
                world.time_s() - start_s,
                r.entry,
                r.exit,
                r.yield_s - ego.s,
                r.merge_s - ego.s,
                ego.speed,
            );
            println!("    scalars {:?}", observation.scalars);
            if dump.contains(&step) {
                let spec = setup.observation_spec();
                let plane = spec.height * spec.width;
                for c in 0..spec.channels {
                    println!("    channel {c}");
                    let layer = &observation.layers[c * plane..(c + 1) * plane];
                    for row in layer.chunks(spec.width) {
                        let line: String = row
                            .iter()
                            .map(|&v| match v {
                                0 => '.',
                                1..=85 => '-',
                                86..=170 => '+',
                                _ => '#',
                            })
                            .collect();
                        println!("    {line}");
                    }
                }
            }
            if step % 5 == 0 {
                for j in 0..world.vehicles().len() {
                    let d = world.vehicles()[j].position.distance(ego.position);
                    if j != ego_i && d <= 30.0 {
                        println!("    {}", describe(world, j, ego));
                    }
                }
            }
        }
        let outcome = env.step(action);
        observation = outcome.observation;
        if let Some(o) = outcome.outcome {
            println!("outcome {o:?} after {} steps", step + 1);
            if let Some(world) = env.world() {
                let ego_i = world.ego_index().unwrap();
                let ego = &world.vehicles()[ego_i];
                let nearest =
                    (0..world.vehicles().len())
                        .filter(|&j| j != ego_i)
                        .min_by(|&a, &b| {
                            let da = world.vehicles()[a].position.distance(ego.position);
                            let db = world.vehicles()[b].position.distance(ego.position);
                            da.total_cmp(&db)
                        });
                if let Some(j) = nearest {
                    println!("  nearest at the end: {}", describe(world, j, ego));
                }
            }
            break;
        }
    }
    Ok(())
}
