//! The entry conflicts of a roundabout's routes: for each route, the routes from other
//! entries whose cars touch a car entering on it without coming round to its merge lane
//! (cars leaving the ring at its arm, mostly), and where along their paths they do.
//!
//!     cargo run --release -p sim --example arm_conflicts -- [MAP]
#![allow(clippy::print_stdout)]

use sim::roundabout::{LayoutConfig, RoundaboutLayout};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let map_path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "data/osm/montlake_roundabout.osm.pbf".into());
    let map = maps::import_file(std::path::Path::new(&map_path), &Default::default())?;
    let layout = RoundaboutLayout::first_in(&map, &LayoutConfig::default())?;
    for (ri, r) in layout.routes.iter().enumerate() {
        for c in &r.entry_conflicts {
            let q = &layout.routes[c.route];
            let leaves_here = layout.exits[q.exit].road == layout.entries[r.entry].road;
            println!(
                "route {ri:2} ({} -> {}) waits for route {:2} ({} -> {}) from {:+.1} to {:+.1} m past its exit{}",
                r.entry,
                r.exit,
                c.route,
                q.entry,
                q.exit,
                c.from_s - q.exit_s,
                c.to_s - q.exit_s,
                if leaves_here {
                    " (leaving at this arm)"
                } else {
                    ""
                }
            );
        }
    }
    Ok(())
}
