//! Shared by the benches: where the data lives, and finding the densest window of a map.

// Each bench uses only some of these helpers.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use maps::Map;
use maps::geometry::Point;
use maps::raster::RasterSpec;

/// A file of `../shared/data/osm`, or None (with a notice) when the data folder is absent.
pub fn osm_file(name: &str) -> Option<PathBuf> {
    let path = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/osm"
    ))
    .join(name);
    if path.exists() {
        Some(path)
    } else {
        #[allow(clippy::print_stderr)]
        {
            eprintln!(
                "skipped: {}: {} not found",
                std::thread::current().name().unwrap_or("-"),
                path.display()
            );
        }
        None
    }
}

/// The `side_m` × `side_m` window (aligned to a 50 m grid) holding the most lane length,
/// at `resolution_m`: the hardest place of the map to rasterize.
pub fn densest_window(map: &Map, side_m: f64, resolution_m: f64) -> RasterSpec {
    const CELL: f64 = 50.0;
    let b = map.bounds();
    let cols = ((b.width() / CELL).ceil() as usize).max(1);
    let rows = ((b.height() / CELL).ceil() as usize).max(1);
    let mut grid = vec![0.0f64; cols * rows];
    for lane in map.lanes.values() {
        for w in lane.centre.windows(2) {
            let m = w[0].lerp(w[1], 0.5);
            let c = (((m.x - b.min.x) / CELL) as usize).min(cols - 1);
            let r = (((m.y - b.min.y) / CELL) as usize).min(rows - 1);
            grid[r * cols + c] += w[0].distance(w[1]);
        }
    }
    let k = (side_m / CELL).round() as usize;
    let mut best = (f64::NEG_INFINITY, 0, 0);
    for r0 in 0..=rows.saturating_sub(k) {
        for c0 in 0..=cols.saturating_sub(k) {
            let mut sum = 0.0;
            for r in r0..(r0 + k).min(rows) {
                sum += grid[r * cols + c0..r * cols + (c0 + k).min(cols)]
                    .iter()
                    .sum::<f64>();
            }
            if sum > best.0 {
                best = (sum, r0, c0);
            }
        }
    }
    let cells = (side_m / resolution_m).round() as u32;
    RasterSpec {
        origin: Point::new(
            b.min.x + best.2 as f64 * CELL,
            b.min.y + best.1 as f64 * CELL,
        ),
        resolution_m,
        width: cells,
        height: cells,
    }
}
