//! Sanity checks of the traffic world on the bundled montlake_roundabout map (five entries
//! into a mini roundabout) and on the shared real maps when present.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::print_stderr)]

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use sim::roundabout::{LayoutConfig, RoundaboutLayout};
use sim::world::{Driver, DriverConfig, EgoConfig, TrafficConfig, TrafficLevel, World};

/// Worlds the gridlock test runs (three simulated minutes each).
const SEEDS: u64 = 30;

/// The default traffic at the high level (at most 8 other vehicles).
fn high_traffic() -> TrafficConfig {
    TrafficConfig {
        level: TrafficLevel::High,
        ..TrafficConfig::default()
    }
}

fn montlake_layout() -> Arc<RoundaboutLayout> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/osm/montlake_roundabout.osm.pbf");
    let map = maps::import_file(&path, &Default::default()).unwrap();
    Arc::new(RoundaboutLayout::first_in(&map, &LayoutConfig::default()).unwrap())
}

/// IDM on a straight lane: whatever the leader does (brake hard to a stop, crawl, speed
/// up again), a follower of any aggressiveness never closes the gap to zero.
#[test]
fn idm_never_drives_a_follower_into_its_leader() {
    let config = DriverConfig::default();
    let dt = 0.1;
    for aggressiveness in [0.0, 0.25, 0.5, 0.75, 1.0] {
        let driver = Driver::new(&config, aggressiveness);
        let (mut lead_x, mut lead_v) = (30.0f64, 12.0f64);
        let (mut x, mut v) = (0.0f64, 14.0f64);
        let mut min_gap = f64::INFINITY;
        for step in 0..1200 {
            let t = step as f64 * dt;
            // Leader: cruise, emergency stop, wait, accelerate, stop again.
            let lead_a = match t {
                t if t < 10.0 => 0.0,
                t if t < 20.0 => -6.0,
                t if t < 40.0 => 1.5,
                t if t < 60.0 => -3.0,
                t if t < 80.0 => 0.0,
                _ => 2.0,
            };
            lead_v = (lead_v + lead_a * dt).clamp(0.0, 15.0);
            lead_x += lead_v * dt;
            let gap = lead_x - x - 4.5;
            let a = driver
                .idm(v, 14.0, Some((gap, v - lead_v)))
                .clamp(-config.max_brake_mps2, driver.max_accel_mps2);
            v = (v + a * dt).max(0.0);
            x += v * dt;
            min_gap = min_gap.min(lead_x - x - 4.5);
        }
        assert!(
            min_gap > 0.5,
            "aggressiveness {aggressiveness}: gap fell to {min_gap}"
        );
    }
}

/// Over four simulated minutes of high traffic: vehicles keep entering the ring, going
/// round, and leaving at their exits; nobody stalls in the ring, others rarely collide (a
/// collision every 40 s at most), and only those that collided leave before their exit.
#[test]
fn circulating_vehicles_go_round_and_leave_at_exits() {
    let layout = montlake_layout();
    let config = high_traffic();
    let mut world = World::new(Arc::clone(&layout), config, EgoConfig::default(), 7);
    // id -> (route, last s, time entered the ring, seconds stopped in the ring so far)
    let mut seen: BTreeMap<u32, (usize, f64, Option<f64>, f64)> = BTreeMap::new();
    let steps = 2400;
    for _ in 0..steps {
        world.step(0.0);
        for v in world.vehicles() {
            let r = world.route(v);
            let e = seen.entry(v.id).or_insert((v.route, v.s, None, 0.0));
            e.1 = v.s;
            e.2 = v.entered_ring_at;
            let in_ring = v.s >= r.merge_s && v.s < r.exit_s;
            if in_ring && v.speed < 0.1 {
                e.3 += 0.1;
            }
        }
        assert!(
            world.overlapping_others().is_empty(),
            "an overlap left in the world"
        );
    }
    let alive: Vec<u32> = world.vehicles().iter().map(|v| v.id).collect();
    let gone: Vec<_> = seen.iter().filter(|(id, _)| !alive.contains(id)).collect();
    assert!(
        gone.len() > 40,
        "only {} vehicles left the roundabout in 4 minutes",
        gone.len()
    );
    let stats = world.stats();
    let mut left_early = 0;
    for (id, (route, last_s, entered, _)) in &gone {
        let r = &layout.routes[*route];
        if *last_s <= r.exit_s {
            left_early += 1;
            continue;
        }
        assert!(
            entered.is_some(),
            "vehicle {id} left without entering the ring"
        );
    }
    assert!(
        left_early <= stats.crashed,
        "{left_early} vehicles gone before their exit, {} crashed",
        stats.crashed
    );
    let most_stopped = seen.values().map(|e| e.3).fold(0.0, f64::max);
    assert!(
        most_stopped < 5.0,
        "a vehicle stood {most_stopped} s in the ring"
    );
    // Mini-roundabout geometry (arms every 8 m round a 6 m ring) lets bodies touch now
    // and then where paths cross; it must stay rare.
    eprintln!("{stats:?}");
    assert!(
        stats.collisions * 400 <= steps as u64,
        "{} collisions in {steps} steps",
        stats.collisions
    );
    assert_eq!((stats.despawned + stats.crashed) as usize, gone.len());
}

/// A driver waiting at its yield line does not go while a circulating car is about to
/// pass its merge point, and goes once it has passed; with the ring empty it goes at once.
#[test]
fn gap_acceptance_waits_for_a_near_circulating_car() {
    let layout = montlake_layout();
    let config = TrafficConfig {
        arrivals_per_s: 0.0,
        ..TrafficConfig::default()
    };
    // A waiting route and a route from another entry that drives through its merge lane.
    let (waiting, through, lane_start) = layout
        .routes
        .iter()
        .enumerate()
        .find_map(|(w, wr)| {
            layout.routes.iter().enumerate().find_map(|(t, tr)| {
                let start = tr.ring_lane_start(wr.merge_lane)?;
                (tr.entry != wr.entry && start - 10.0 >= tr.merge_s).then_some((w, t, start))
            })
        })
        .expect("two routes that share a ring lane");
    let wr = &layout.routes[waiting];
    let waiting_s = wr.yield_s - 2.5;

    // Empty ring: it commits within a second.
    let mut world = World::new(Arc::clone(&layout), config.clone(), EgoConfig::default(), 1);
    let w = world.insert_vehicle(waiting, waiting_s, 0.0, 0.5, false);
    for _ in 0..10 {
        world.step(0.0);
    }
    assert!(
        world
            .vehicles()
            .iter()
            .find(|v| v.id == w)
            .unwrap()
            .committed
    );

    // A car 10 m before the merge point at 4 m/s (2.5 s away): the driver waits.
    let mut world = World::new(Arc::clone(&layout), config, EgoConfig::default(), 1);
    let w = world.insert_vehicle(waiting, waiting_s, 0.0, 0.5, false);
    let c = world.insert_vehicle(through, lane_start - 10.0, 4.0, 0.5, true);
    let mut committed_while_near = false;
    let mut committed_after = false;
    for _ in 0..100 {
        world.step(0.0);
        let Some(waiting_car) = world.vehicles().iter().find(|v| v.id == w) else {
            break; // it went through and left
        };
        let circulating = world.vehicles().iter().find(|v| v.id == c);
        // Passed: its rear is past the merge point.
        let passed = circulating.is_none_or(|v| v.s - v.length / 2.0 > lane_start);
        if waiting_car.committed && !passed {
            committed_while_near = true;
        }
        if waiting_car.committed && passed {
            committed_after = true;
        }
    }
    assert!(
        !committed_while_near,
        "entered in front of a car 2.5 s away"
    );
    assert!(committed_after, "never entered after the car had passed");
}

/// On montlake, cars leaving the ring sweep the mouths of entries at their arm. A driver
/// waiting there does not go while such a car is in the swept stretch (it would drive into
/// its side), and goes once the car has left it.
#[test]
fn a_waiting_driver_lets_a_car_leaving_at_its_arm_clear_the_mouth() {
    let layout = montlake_layout();
    let entries_swept_by_leaving_cars: BTreeSet<usize> = layout
        .routes
        .iter()
        .filter(|r| {
            r.entry_conflicts.iter().any(|c| {
                let q = &layout.routes[c.route];
                layout.exits[q.exit].road == layout.entries[r.entry].road
            })
        })
        .map(|r| r.entry)
        .collect();
    assert!(
        entries_swept_by_leaving_cars.len() >= 2,
        "{entries_swept_by_leaving_cars:?}"
    );
    let config = TrafficConfig {
        arrivals_per_s: 0.0,
        ..TrafficConfig::default()
    };
    let (waiting, conflict) = layout
        .routes
        .iter()
        .enumerate()
        .find_map(|(w, wr)| wr.entry_conflicts.first().map(|c| (w, *c)))
        .expect("a route with an entry conflict");
    let wr = &layout.routes[waiting];
    let mut world = World::new(Arc::clone(&layout), config, EgoConfig::default(), 1);
    let w = world.insert_vehicle(waiting, wr.yield_s - 2.5, 0.0, 0.5, false);
    // The leaving car starts 6 m before the swept stretch at 4 m/s.
    let c = world.insert_vehicle(conflict.route, conflict.from_s - 6.0, 4.0, 0.5, true);
    let (mut committed_while_near, mut committed_after) = (false, false);
    for _ in 0..150 {
        world.step(0.0);
        let Some(waiting_car) = world.vehicles().iter().find(|v| v.id == w) else {
            break;
        };
        let leaving = world.vehicles().iter().find(|v| v.id == c);
        let cleared = leaving.is_none_or(|v| v.s > conflict.to_s);
        committed_while_near |= waiting_car.committed && !cleared;
        committed_after |= waiting_car.committed && cleared;
    }
    assert!(
        !committed_while_near,
        "entered while a leaving car swept the mouth"
    );
    assert!(
        committed_after,
        "never entered after the leaving car had gone"
    );
}

/// The world builds routes on every shared roundabout map and moves traffic through it.
#[test]
fn traffic_flows_on_the_shared_roundabout_maps() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    let files = [
        "osm/tiny_roundabout.osm",
        "osm/leeds_cycleway.osm",
        "trajectories/interaction/maps/DR_USA_Roundabout_FT.osm",
        "trajectories/interaction/maps/DR_DEU_Roundabout_OF.osm",
    ];
    for file in files {
        let path = root.join(file);
        if !path.exists() {
            eprintln!(
                "skipped: {}: {} not found",
                std::thread::current().name().unwrap_or("-"),
                path.display()
            );
            continue;
        }
        let map = maps::import_file(&path, &Default::default()).unwrap();
        let layout = Arc::new(RoundaboutLayout::first_in(&map, &LayoutConfig::default()).unwrap());
        assert!(
            layout.usable_entries().count() >= 2,
            "{file}: fewer than two usable entries"
        );
        let mut world = World::new(layout, TrafficConfig::default(), EgoConfig::default(), 3);
        world.warm_up(120.0);
        assert!(world.stats().despawned >= 5, "{file}: {:?}", world.stats());
    }
}

/// No gridlock: in many worlds of high traffic, nobody stands in the ring for long. Drivers
/// that committed to a gap and then had to stop before their line once kept their
/// commitment; circulating drivers yielded to them as to cars merging ahead, and chains of
/// such yields stopped the ring for good (a time-over for every policy of the ego).
#[test]
fn the_ring_never_gridlocks() {
    let layout = montlake_layout();
    let config = high_traffic();
    for seed in 0..SEEDS {
        let mut world = World::new(
            Arc::clone(&layout),
            config.clone(),
            EgoConfig::default(),
            seed,
        );
        // id -> seconds stood still in the ring without a break
        let mut standing: BTreeMap<u32, f64> = BTreeMap::new();
        for step in 0..1800 {
            world.step(0.0);
            for v in world.vehicles() {
                let r = world.route(v);
                let in_ring = v.s >= r.merge_s && v.s < r.exit_s;
                let t = standing.entry(v.id).or_insert(0.0);
                *t = if in_ring && v.speed < 0.1 {
                    *t + 0.1
                } else {
                    0.0
                };
                assert!(
                    *t < 20.0,
                    "seed {seed}: vehicle {} has stood 20 s in the ring at {:.1} s",
                    v.id,
                    step as f64 * 0.1
                );
            }
        }
    }
}
