//! The roundabout-insertion world on the multi-lane rings of the Andorra extract (shared
//! data, skipped when absent): episodes with rule baselines, and long runs of the traffic
//! alone, must run without panics, without vehicles stuck for no reason, with every vehicle
//! leaving the ring by its route's exit, and with every overlap of the ego counted as a
//! crash. The world counts no collision between its own vehicles; their overlaps are
//! printed and held under a ceiling (cars side by side where one changes lanes, and lanes
//! of the imported geometry that touch near junctions, still make some).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::print_stdout)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::Arc;

use maps::geometry::project_onto_polyline;
use maps::{Map, RoundaboutId};
use sim::baselines::{Baseline, PolicyInput};
use sim::roundabout::RoundaboutLayout;
use sim::tasks::{InsertionConfig, InsertionSetup, RoundaboutInsertion, Task};
use sim::world::{EgoConfig, TrafficConfig, TrafficLevel, World};
use sim::{Env, Outcome};

/// Episodes per ring (split over the baselines below).
const EPISODES_PER_RING: u64 = 200;
/// Seconds of traffic alone per ring.
const TRAFFIC_RUN_S: f64 = 600.0;
/// A vehicle standing this long with nothing to wait for is stuck, s.
const STUCK_LIMIT_S: f64 = 60.0;
/// Ceilings on pairs of world vehicles overlapping: per episode, and per ring's run of
/// traffic alone.
const MAX_OVERLAPS_PER_EPISODE: f64 = 0.4;
const MAX_OVERLAPS_PER_TRAFFIC_RUN: f64 = 4.5;

fn shared_data() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    dir.is_dir().then_some(dir)
}

/// Problems found on one ring.
#[derive(Debug, Default, Clone, Copy)]
struct Figures {
    episodes: u64,
    crashes: u64,
    /// Pairs of world vehicles overlapping (the world counts no collision between them),
    /// counted once per pair.
    uncounted_overlaps: u64,
    /// The ego overlapping a vehicle without the episode ending in a crash.
    uncounted_ego_overlaps: u64,
    stuck: u64,
    wrong_exits: u64,
    left_ring: u64,
}

impl std::ops::AddAssign for Figures {
    fn add_assign(&mut self, o: Self) {
        self.episodes += o.episodes;
        self.crashes += o.crashes;
        self.uncounted_overlaps += o.uncounted_overlaps;
        self.uncounted_ego_overlaps += o.uncounted_ego_overlaps;
        self.stuck += o.stuck;
        self.wrong_exits += o.wrong_exits;
        self.left_ring += o.left_ring;
    }
}

/// Watches a world between steps: stopped vehicles, overlaps and where vehicles leave the
/// ring.
#[derive(Default)]
struct Watch {
    /// Per vehicle id: when it stopped with nothing to wait for.
    stopped_since: BTreeMap<u32, f64>,
    stuck: BTreeSet<u32>,
    overlapping: BTreeSet<(u32, u32)>,
    /// Vehicles whose centre passed their exit point, checked once.
    exited: BTreeMap<u32, bool>,
}

impl Watch {
    fn look(&mut self, map: &Map, world: &World) {
        let now = world.time_s();
        for (i, v) in world.vehicles().iter().enumerate() {
            if v.is_ego() {
                continue;
            }
            let route = world.route(v);
            let waiting_at_line = !v.committed && route.yield_s - (v.s + v.length / 2.0) < 4.0;
            let has_reason = waiting_at_line
                || world.leader(i).is_some_and(|l| l.gap_m < 15.0)
                || world.merging_leader(i).is_some()
                || world.obstacle_on_path(i, 12.0).is_some();
            if v.speed < 0.1 && !has_reason {
                let since = *self.stopped_since.entry(v.id).or_insert(now);
                if now - since > STUCK_LIMIT_S {
                    self.stuck.insert(v.id);
                }
            } else {
                self.stopped_since.remove(&v.id);
            }
            // Checked once, on the exit lane's first metres past the ring (a vehicle first
            // seen farther on, after the warm-up, is not checked).
            let exit = &world.layout().exits[route.exit];
            if let Some(lane) = map.lanes.get(&exit.lane)
                && v.s > route.exit_s + 1.0
                && v.s < route.exit_s + lane.length_m.min(6.0)
                && !self.exited.contains_key(&v.id)
            {
                let on_it = project_onto_polyline(&lane.centre, v.position).1 < 1.5;
                self.exited.insert(v.id, on_it);
            }
        }
        for (a, b) in world.overlapping_others() {
            self.overlapping.insert((a, b));
        }
    }

    fn figures(&self) -> Figures {
        Figures {
            stuck: self.stuck.len() as u64,
            uncounted_overlaps: self.overlapping.len() as u64,
            wrong_exits: self.exited.values().filter(|ok| !**ok).count() as u64,
            left_ring: self.exited.len() as u64,
            ..Figures::default()
        }
    }
}

fn run_episodes(map: &Arc<Map>, id: RoundaboutId) -> Option<Figures> {
    let config = InsertionConfig {
        aggressiveness: Some(0.5),
        roundabout: Some(id.0),
        ..InsertionConfig::default()
    };
    let setup = match InsertionSetup::new(Arc::clone(map), config) {
        Ok(s) => s,
        Err(e) => {
            println!("ring {id}: no insertion setup: {e}");
            return None;
        }
    };
    let baselines = [
        Baseline::Rule { threshold_m: 15.0 },
        Baseline::AlwaysPermitted,
    ];
    let mut figures = Figures::default();
    let mut env = RoundaboutInsertion::new(setup);
    env.set_traffic(TrafficLevel::High);
    env.set_rendering(false);
    for episode in 0..EPISODES_PER_RING {
        let baseline = baselines[(episode % 2) as usize];
        let seed = 1000 + episode;
        let mut observation = env.reset(seed);
        let mut watch = Watch::default();
        let mut step = 0;
        let outcome = loop {
            let state = env.state();
            let input = PolicyInput {
                slot: 0,
                episode_seed: seed,
                step,
                observation: &observation,
                state: &state,
            };
            let action = baseline.decide(&input) as usize;
            let result = env.step(action);
            step += 1;
            observation = result.observation;
            let world = env.world().expect("a world after reset");
            watch.look(map, world);
            if let Some(ego) = world.ego_index() {
                let me = world.vehicles()[ego].footprint();
                let touching = world
                    .vehicles()
                    .iter()
                    .enumerate()
                    .any(|(j, o)| j != ego && o.footprint().overlaps(&me));
                if touching && result.outcome != Some(Outcome::Crashed) {
                    figures.uncounted_ego_overlaps += 1;
                }
            }
            if let Some(o) = result.outcome {
                break o;
            }
        };
        figures.episodes += 1;
        figures.crashes += u64::from(outcome == Outcome::Crashed);
        let f = watch.figures();
        figures.uncounted_overlaps += f.uncounted_overlaps;
        figures.stuck += f.stuck;
        figures.wrong_exits += f.wrong_exits;
        figures.left_ring += f.left_ring;
    }
    Some(figures)
}

fn run_traffic(map: &Map, id: RoundaboutId) -> Option<Figures> {
    let layout = RoundaboutLayout::new(map, id, &InsertionConfig::default().layout).ok()?;
    let traffic = TrafficConfig {
        level: TrafficLevel::High,
        ..TrafficConfig::default()
    };
    let mut world = World::new(
        Arc::new(layout),
        traffic,
        EgoConfig::default(),
        7 + id.0 as u64,
    );
    let mut watch = Watch::default();
    let steps = (TRAFFIC_RUN_S / traffic.step_s) as usize;
    for _ in 0..steps {
        world.step(0.0);
        watch.look(map, &world);
    }
    Some(watch.figures())
}

#[test]
fn insertion_runs_cleanly_on_multi_lane_rings() {
    let Some(data) = shared_data() else {
        println!("skipped: insertion_runs_cleanly_on_multi_lane_rings: no shared data directory");
        return;
    };
    let path = data.join("osm/roundabouts/andorra.osm.pbf");
    if !path.is_file() {
        println!("skipped: insertion_runs_cleanly_on_multi_lane_rings: {path:?} is missing");
        return;
    }
    let map = Arc::new(maps::import_file(&path, &Default::default()).unwrap());
    let rings: Vec<RoundaboutId> = map
        .roundabouts
        .values()
        .filter(|r| r.lanes_across >= 2)
        .map(|r| r.id)
        .collect();
    assert!(!rings.is_empty(), "the extract has multi-lane rings");
    let (mut episodes, mut traffic) = (Figures::default(), Figures::default());
    let mut tested = 0;
    for &id in &rings {
        let Some(e) = run_episodes(&map, id) else {
            continue;
        };
        let t = run_traffic(&map, id).expect("a layout where the task has a setup");
        assert_eq!(e.episodes, EPISODES_PER_RING);
        println!("ring {id}: episodes {e:?}; traffic alone {t:?}");
        tested += 1;
        episodes += e;
        traffic += t;
    }
    println!(
        "{tested} of {} multi-lane rings tested; episodes {episodes:?}; traffic alone {traffic:?}",
        rings.len()
    );
    assert!(tested > 0, "no multi-lane ring could be set up");
    for f in [episodes, traffic] {
        assert_eq!(
            f.uncounted_ego_overlaps, 0,
            "ego overlaps not counted: {f:?}"
        );
        assert_eq!(f.stuck, 0, "stuck vehicles: {f:?}");
        assert_eq!(f.wrong_exits, 0, "wrong exits: {f:?}");
        assert!(f.left_ring > 0, "no vehicle left a ring: {f:?}");
    }
    assert!(
        episodes.uncounted_overlaps as f64 <= MAX_OVERLAPS_PER_EPISODE * episodes.episodes as f64,
        "world vehicles overlapping: {episodes:?}"
    );
    assert!(
        traffic.uncounted_overlaps as f64 <= MAX_OVERLAPS_PER_TRAFFIC_RUN * tested as f64,
        "world vehicles overlapping: {traffic:?}"
    );
}
