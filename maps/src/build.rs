//! OSM data to a [`Map`]: a sequence of small named transformations, each followed by an
//! invariant check.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::MapError;
use crate::model::{DrivingSide, Map};
use crate::osm::{OsmData, read_osm_file};
use crate::profile::RoadProfile;
use crate::projection::LatLon;

mod connect;
mod mini;
mod roundabouts;
mod select;
mod shape;
mod stops;

use select::Builder;

/// Where U-turns are allowed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UTurns {
    Never,
    /// Only at dead ends (turning round at the end of a street).
    #[default]
    DeadEnds,
    Everywhere,
}

/// A region to keep: a bounding box, or polygons with holes, in WGS84.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Clip {
    BoundingBox {
        min: LatLon,
        max: LatLon,
    },
    /// Polygons (a GeoJSON Polygon or MultiPolygon, an Osmosis `.poly` file): a point is kept
    /// when it lies inside one polygon's outer ring and inside none of that polygon's holes.
    Polygons {
        polygons: Vec<ClipPolygon>,
    },
}

/// One polygon of a clip region: an outer ring and its holes, each closed (the last point
/// may repeat the first).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClipPolygon {
    pub outer: Vec<LatLon>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub holes: Vec<Vec<LatLon>>,
}

impl Clip {
    /// A single polygon without holes.
    pub fn polygon(ring: Vec<LatLon>) -> Self {
        Clip::Polygons {
            polygons: vec![ClipPolygon {
                outer: ring,
                holes: Vec::new(),
            }],
        }
    }

    /// The region prepared for many [`ClipRegion::contains`] calls.
    pub fn region(&self) -> ClipRegion {
        match self {
            Clip::BoundingBox { min, max } => ClipRegion::BoundingBox {
                min: *min,
                max: *max,
            },
            Clip::Polygons { polygons } => {
                let ring = |r: &[LatLon]| -> geo::LineString<f64> {
                    r.iter()
                        .map(|p| geo::coord! { x: p.lon, y: p.lat })
                        .collect()
                };
                ClipRegion::Polygons(geo::MultiPolygon(
                    polygons
                        .iter()
                        .map(|p| {
                            geo::Polygon::new(
                                ring(&p.outer),
                                p.holes.iter().map(|h| ring(h)).collect(),
                            )
                        })
                        .collect(),
                ))
            }
        }
    }

    pub fn contains(&self, p: LatLon) -> bool {
        self.region().contains(p)
    }
}

/// A [`Clip`] ready for point tests (the polygons built once, as `geo` polygons).
#[derive(Debug, Clone)]
pub enum ClipRegion {
    BoundingBox { min: LatLon, max: LatLon },
    Polygons(geo::MultiPolygon<f64>),
}

impl ClipRegion {
    /// Whether `p` lies in the region (a point on a polygon's edge counts as inside).
    pub fn contains(&self, p: LatLon) -> bool {
        match self {
            ClipRegion::BoundingBox { min, max } => {
                p.lat >= min.lat && p.lat <= max.lat && p.lon >= min.lon && p.lon <= max.lon
            }
            ClipRegion::Polygons(polygons) => {
                use geo::Intersects as _;
                polygons.intersects(&geo::Point::new(p.lon, p.lat))
            }
        }
    }
}

/// Everything that steers an import. `Default` is the car profile, auto-detected driving
/// side, U-turns at dead ends, roundabout guessing on, invariant checks on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ImportOptions {
    pub profile: RoadProfile,
    pub clip: Option<Clip>,
    /// None: from the map's location (left-hand traffic regions are listed in `tags`).
    pub driving_side: Option<DrivingSide>,
    pub u_turns: UTurns,
    /// Report untagged near-circular one-way loops as (guessed) roundabouts.
    pub guess_roundabouts: bool,
    /// Projection origin. None: the centre of the selected roads (OSM), or (0, 0) with
    /// Lanelet2's UTM convention (Lanelet2, as the INTERACTION dataset does).
    pub origin: Option<LatLon>,
    /// Run `check_invariants` after every transformation (on by default, and in every test);
    /// when off, the finished map is still checked once.
    pub check_invariants: bool,
}

impl Default for ImportOptions {
    fn default() -> Self {
        ImportOptions {
            profile: RoadProfile::car(),
            clip: None,
            driving_side: None,
            u_turns: UTurns::DeadEnds,
            guess_roundabouts: true,
            origin: None,
            check_invariants: true,
        }
    }
}

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
