//! OSM data to a [`Map`]: a sequence of small named transformations, each followed by an
//! invariant check.

use std::path::Path;

use crate::error::MapError;
use crate::model::Map;
use crate::osm::{OsmData, read_osm_file};

// The options live below both import paths (this one and `lanelet2`); named here as before.
pub use crate::options::{Clip, ClipPolygon, ClipRegion, ImportOptions, UTurns};

mod connect;
mod mini;
mod roundabouts;
mod select;
mod shape;
mod stops;

use select::Builder;

/// Reads and imports one file (`.osm`, `.osm.gz`, `.osm.pbf`, or a Lanelet2 `.osm`).
pub fn import_file(path: &Path, options: &ImportOptions) -> Result<Map, MapError> {
    let (osm, _format) = read_osm_file(path)?;
    import_osm(&osm, options).map_err(|e| e.with_path(path))
}

/// Imports OSM PBF data held in memory (such as a map embedded in a program): the same map
/// as [`import_file`] makes from a file holding these bytes. Errors name no file.
pub fn import_pbf_bytes(bytes: &[u8], options: &ImportOptions) -> Result<Map, MapError> {
    import_osm(&crate::osm::read_pbf_bytes(bytes)?, options)
}

/// Imports parsed OSM data: Lanelet2 maps (with `type=lanelet` relations) through
/// [`crate::lanelet2`], everything else through the OSM road pipeline.
pub fn import_osm(osm: &OsmData, options: &ImportOptions) -> Result<Map, MapError> {
    let map = if osm.is_lanelet2() {
        crate::lanelet2::build_lanelet2_map(osm, options)?
    } else {
        build_osm_map(osm, options)?
    };
    // Without the check after every step, the finished map is still checked once.
    if !options.check_invariants {
        crate::invariants::check_invariants(&map, "import")?;
    }
    Ok(map)
}

fn build_osm_map(osm: &OsmData, options: &ImportOptions) -> Result<Map, MapError> {
    let minis = mini::ring_mini_roundabouts(osm, options);
    let osm = minis.as_ref().map_or(osm, |m| &m.osm);
    let mut b = Builder::select_roads(osm, options, minis.as_ref())?;
    b.check("select_roads")?;
    b.shape_junctions();
    b.check("shape_junctions")?;
    b.build_lanes();
    b.check("build_lanes")?;
    b.connect_lanes();
    b.check("connect_lanes")?;
    b.apply_turn_restrictions();
    b.check("apply_turn_restrictions")?;
    b.find_rings();
    b.check("find_rings")?;
    b.connect_rings();
    b.check("connect_rings")?;
    b.find_roundabouts();
    b.check("find_roundabouts")?;
    b.find_mini_roundabouts();
    b.check("find_mini_roundabouts")?;
    b.place_stop_lines();
    b.check("place_stop_lines")?;
    b.paint_markings();
    b.check("paint_markings")?;
    b.forget_made_ways();
    b.check("forget_made_ways")?;
    Ok(b.map)
}
