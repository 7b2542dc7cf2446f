//! Small hand-made maps and the bundled real one for the tests of this crate.
#![allow(dead_code)]

use maps::*;

/// A map with one straight one-lane road from `a` to `b` (3.5 m wide, 50 km/h).
pub fn straight_road(a: Point, b: Point) -> Map {
    crate::synthetic::straight_road(a, b, 1, 3.5, 50.0)
}

/// The bundled montlake_roundabout map (one mini roundabout, five entries), from the
/// repository's `data/osm`.
#[allow(clippy::expect_used)]
pub fn montlake() -> Map {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/osm/montlake_roundabout.osm.pbf");
    maps::import_file(&path, &Default::default()).expect("bundled montlake map imports")
}

/// `../shared/data/<relative>` imported, or None with a skip notice when absent.
#[allow(clippy::print_stderr, clippy::expect_used)]
pub fn shared_map(relative: &str) -> Option<Map> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(relative);
    if !path.exists() {
        eprintln!(
            "skipped: {}: {} not found",
            std::thread::current().name().unwrap_or("-"),
            path.display()
        );
        return None;
    }
    Some(maps::import_file(&path, &Default::default()).expect("shared map imports"))
}

/// The routes of montlake's roundabout with the default layout.
#[allow(clippy::expect_used)]
pub fn montlake_layout() -> std::sync::Arc<crate::roundabout::RoundaboutLayout> {
    let layout = crate::roundabout::RoundaboutLayout::first_in(&montlake(), &Default::default());
    std::sync::Arc::new(layout.expect("montlake has a roundabout"))
}
