//! Imports each file given and prints its key figures: a quick look while developing.
//! `cargo run --release -p maps --example import_stats -- ../shared/data/osm/*.osm*`
#![allow(clippy::print_stdout, clippy::unwrap_used)]

fn main() {
    for arg in std::env::args().skip(1) {
        let path = std::path::Path::new(&arg);
        let t = std::time::Instant::now();
        let (osm, _) = maps::osm::read_osm_file(path).unwrap();
        let parse_ms = t.elapsed().as_secs_f64() * 1e3;
        println!(
            "{arg}: parse {parse_ms:.1} ms, {} nodes {} ways",
            osm.nodes.len(),
            osm.ways.len()
        );
        let opts = maps::ImportOptions {
            check_invariants: std::env::var("NOCHECK").is_err(),
            ..Default::default()
        };
        match maps::import_osm(&osm, &opts) {
            Ok(map) => {
                let car_len: f64 = map.car_lanes().map(|l| l.length_m).sum();
                let passenger: f64 = map
                    .car_lanes()
                    .filter(|l| map.roads[&l.road].highway != "service")
                    .map(|l| l.length_m)
                    .sum();
                let inter = map
                    .junctions
                    .values()
                    .filter(|j| j.kind == maps::JunctionKind::Intersection)
                    .count();
                println!(
                    "{arg}: {:.0} ms roads {} lanes {} car_len {:.0} passenger_len {:.0} junctions {} conns {} stops {} side {:?}",
                    t.elapsed().as_secs_f64() * 1e3,
                    map.roads.len(),
                    map.lanes.len(),
                    car_len,
                    passenger,
                    inter,
                    map.connections.len(),
                    map.stop_lines.len(),
                    map.driving_side
                );
                for r in map.roundabouts.values() {
                    println!(
                        "   roundabout {:?} ways {:?} entries {} exits {} yields {} cycle {} r {:.1} cw {}",
                        r.source,
                        r.osm_way_ids,
                        r.entries.len(),
                        r.exits.len(),
                        r.yield_lines.len(),
                        r.circulating_lanes.len(),
                        r.radius_m,
                        r.clockwise
                    );
                }
                if !map.report.notes.is_empty() {
                    println!("   notes {:?}", map.report.notes);
                }
                println!(
                    "   report: missing {} degenerate {} restr {}/{} unplaced stops {}",
                    map.report.ways_missing_nodes.len(),
                    map.report.degenerate_ways.len(),
                    map.report.restrictions_applied,
                    map.report.restrictions_skipped.len(),
                    map.report.stop_nodes_unplaced.len()
                );
            }
            Err(e) => println!("{arg}: ERROR {e}"),
        }
    }
}
