//! The traffic calibration on traffic the world itself generated, on the real FT
//! roundabout's map: the fit recovers the parameters the world was given, and the world
//! compared with itself is as near as sampling allows.

#![allow(clippy::print_stdout, clippy::unwrap_used)]

mod common;

use std::sync::Arc;

use common::shared_data;
use maps::{Map, RoundaboutId};
use sim::roundabout::{LayoutConfig, RoundaboutLayout};
use sim::world::{CriticalGap, EntryFlow, GapAcceptance, TrafficConfig, TrafficLevel};
use traffic::calibrate::{calibrate, refine};
use traffic::measure::{Measurements, RingGeometry, measure};
use traffic::realism::compare;
use traffic::simulate::{recorded_flows, simulate};

/// The FT map (None without ../shared/data).
fn ft_map() -> Option<Map> {
    let dir = shared_data("trajectories/interaction/maps")?;
    Some(maps::import_file(&dir.join("DR_USA_Roundabout_FT.osm"), &Default::default()).unwrap())
}

/// A world with known drivers: critical gaps round `median_s`, lateral acceleration
/// `lateral`, 180 vehicles per hour on every entry (below the entries' capacity).
fn known_world(map: &Map, median_s: f64, lateral: f64) -> (TrafficConfig, LayoutConfig) {
    let layout = LayoutConfig {
        lateral_accel_mps2: lateral,
        ..LayoutConfig::default()
    };
    let routes = RoundaboutLayout::new(map, RoundaboutId(0), &layout).unwrap();
    let mut traffic = TrafficConfig {
        level: TrafficLevel::Recorded,
        decision_distance_m: 25.0,
        spawn_clearance_m: 3.0,
        ..TrafficConfig::default()
    };
    traffic.drivers.critical_gap = GapAcceptance::Measured(CriticalGap {
        median_s,
        sigma: 0.3,
    });
    traffic.flows = routes
        .usable_entries()
        .map(|e| EntryFlow {
            lane: routes.entries[e].lane.0,
            vph: 180.0,
            exits: Vec::new(),
        })
        .collect();
    (traffic, layout)
}

/// `runs` runs of `minutes` each of the world, measured as recordings are.
fn recordings(
    map: &Map,
    geometry: &RingGeometry,
    world: &(TrafficConfig, LayoutConfig),
    runs: u64,
    minutes: f64,
    seed: u64,
) -> Vec<Measurements> {
    (0..runs)
        .map(|k| {
            let run = simulate(
                map,
                RoundaboutId(0),
                &world.0,
                &world.1,
                minutes * 60.0,
                120.0,
                seed + k,
            )
            .unwrap();
            // Drivers judging gaps from far off misjudge now and then (one entry of FT has a
            // 15 m stretch where an exit lane crosses it): at most 2 % of the vehicles.
            assert!(
                run.stats.collisions as f64 <= 0.02 * run.stats.spawned as f64,
                "{} collisions among {} vehicles",
                run.stats.collisions,
                run.stats.spawned
            );
            measure(geometry, &run.frames)
        })
        .collect()
}

#[test]
fn the_fit_recovers_the_parameters_the_world_was_given() {
    let Some(map) = ft_map() else { return };
    let geometry = RingGeometry::new(&map, RoundaboutId(0)).unwrap();
    let world = known_world(&map, 3.0, 5.0);
    let measured = recordings(&map, &geometry, &world, 8, 5.0, 100);
    let flows = recorded_flows(&map, RoundaboutId(0), &world.1, &geometry, &measured).unwrap();
    // The flows per entry: 180 veh/h given, Poisson over 40 minutes (sd about 7 %).
    let usable = Arc::new(RoundaboutLayout::new(&map, RoundaboutId(0), &world.1).unwrap());
    assert_eq!(flows.len(), usable.usable_entries().count());
    let mean = flows.iter().map(|f| f.vph).sum::<f64>() / flows.len() as f64;
    assert!((mean - 180.0).abs() < 25.0, "mean flow {mean:.0} veh/h");
    let mut c = calibrate(&measured, 0, geometry.radius_m, flows, 1).unwrap();
    // Vehicle lengths: uniform over the world's span (3.9-4.9 m).
    let length = c.report.vehicle_length_m.mean;
    assert!((length - 4.4).abs() < 0.1, "mean length {length:.2} m");
    let found = refine(&mut c, &map, &geometry, &measured, 1, |_| {}).unwrap();
    println!("{found:?}");
    assert!(
        (found.lateral_accel_mps2 - 5.0).abs() < 1.2,
        "lateral acceleration {:.2} for 5.0",
        found.lateral_accel_mps2
    );
    assert!(
        (found.critical_gap_median_s - 3.0).abs() < 0.8,
        "critical gap {:.2} s for 3.0",
        found.critical_gap_median_s
    );
}

#[test]
fn the_world_against_itself_is_as_near_as_sampling_allows() {
    let Some(map) = ft_map() else { return };
    let geometry = RingGeometry::new(&map, RoundaboutId(0)).unwrap();
    let world = known_world(&map, 3.0, 5.0);
    let a = recordings(&map, &geometry, &world, 8, 8.0, 200);
    let b = recordings(&map, &geometry, &world, 8, 8.0, 300);
    let same = compare(&a, &b);
    for (name, m) in &same.metrics {
        println!("{name}: KS {:.3} (n {} / {})", m.ks, m.real.n, m.sim.n);
        assert!(m.real.n >= 30 && m.sim.n >= 30, "{name}: too few samples");
        assert!(
            m.ks <= 0.15,
            "{name}: KS {:.3} between two runs of one world",
            m.ks
        );
    }
    // And it tells different drivers apart: critical gaps twice as long.
    let patient = known_world(&map, 6.0, 5.0);
    let c = recordings(&map, &geometry, &patient, 8, 8.0, 300);
    let other = compare(&a, &c);
    let gap = |r: &traffic::realism::RealismReport| r.metrics["accepted_gap"].ks;
    assert!(
        gap(&other) > 3.0 * gap(&same) && gap(&other) > 0.1,
        "accepted gaps: KS {:.3} against other drivers, {:.3} against the same",
        gap(&other),
        gap(&same)
    );
}
