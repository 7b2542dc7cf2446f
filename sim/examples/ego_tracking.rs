//! How closely the ego's steering controller follows each route of a roundabout when it
//! drives alone at its route's target speed: the largest distance of its centre from the
//! path, and where along the route (relative to the exit) that happens.
//!
//!     cargo run --release -p sim --example ego_tracking -- [MAP]
#![allow(clippy::print_stdout, clippy::unwrap_used)]

use std::sync::Arc;

use sim::roundabout::{LayoutConfig, RoundaboutLayout};
use sim::world::{EgoConfig, TrafficConfig, World};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let map_path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "data/osm/montlake_roundabout.osm.pbf".into());
    let map = maps::import_file(std::path::Path::new(&map_path), &Default::default())?;
    let layout = Arc::new(RoundaboutLayout::first_in(&map, &LayoutConfig::default())?);
    let traffic = TrafficConfig {
        max_vehicles: Some(0),
        ..TrafficConfig::default()
    };
    let mut worst_all: f64 = 0.0;
    for (ri, route) in layout.routes.iter().enumerate() {
        let mut world = World::new(
            Arc::clone(&layout),
            traffic.clone(),
            EgoConfig::default(),
            0,
        );
        world.insert_ego(ri, 5.0, route.path.speed_at(5.0), 0.0);
        let mut worst = (0.0_f64, 0.0);
        for _ in 0..600 {
            let Some(e) = world.ego_index() else { break };
            let me = &world.vehicles()[e];
            let (on_path, _) = route.path.pose_at(me.s);
            let off = on_path.distance(me.position);
            if off > worst.0 {
                worst = (off, me.s - route.exit_s);
            }
            if me.s > route.path.length() - 3.0 {
                break;
            }
            let target = route.path.speed_at(me.s + me.length / 2.0);
            world.step(((target - me.speed) / 0.1).clamp(-2.5, 2.0));
        }
        worst_all = worst_all.max(worst.0);
        println!(
            "route {ri:2} ({} -> {}): largest off-path {:.2} m at {:+.1} m from the exit",
            route.entry, route.exit, worst.0, worst.1
        );
    }
    println!(
        "{} routes; largest off-path of all: {worst_all:.2} m",
        layout.routes.len()
    );
    Ok(())
}
