//! What steers an import ([`ImportOptions`]): the road profile, a clip region, driving side,
//! U-turns, roundabout guessing, the projection origin and invariant checks. Shared by the OSM
//! road pipeline ([`crate::build`]) and the Lanelet2 import ([`crate::lanelet2`]).

use serde::{Deserialize, Serialize};

use crate::model::DrivingSide;
use crate::profile::RoadProfile;
use crate::projection::LatLon;

/// Where U-turns are allowed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UTurns {
    /// Nowhere.
    Never,
    /// Only at dead ends (turning round at the end of a street).
    #[default]
    DeadEnds,
    /// At every junction.
    Everywhere,
}

/// A region to keep: a bounding box, or polygons with holes, in WGS84.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Clip {
    /// Everything between two corners (inclusive).
    BoundingBox {
        /// The south-west corner.
        min: LatLon,
        /// The north-east corner.
        max: LatLon,
    },
    /// Polygons (a GeoJSON Polygon or MultiPolygon, an Osmosis `.poly` file): a point is kept
    /// when it lies inside one polygon's outer ring and inside none of that polygon's holes.
    Polygons {
        /// The polygons; a point inside any of them is kept.
        polygons: Vec<ClipPolygon>,
    },
}

/// One polygon of a clip region: an outer ring and its holes, each closed (the last point
/// may repeat the first).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClipPolygon {
    /// The outer ring.
    pub outer: Vec<LatLon>,
    /// Rings cut out of the outer one.
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

    /// Whether `p` lies in the region (builds the region for this one test; use
    /// [`Clip::region`] for many).
    pub fn contains(&self, p: LatLon) -> bool {
        self.region().contains(p)
    }
}

/// A [`Clip`] ready for point tests (the polygons built once, as `geo` polygons).
#[derive(Debug, Clone)]
pub enum ClipRegion {
    /// Everything between two corners (inclusive).
    BoundingBox {
        /// The south-west corner.
        min: LatLon,
        /// The north-east corner.
        max: LatLon,
    },
    /// Polygons with holes, longitude as x and latitude as y.
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
    /// Which ways are roads, and their default lanes and speeds.
    pub profile: RoadProfile,
    /// Keep only what lies in this region (None: everything).
    pub clip: Option<Clip>,
    /// None: from the map's location (left-hand traffic regions are listed in `tags`).
    pub driving_side: Option<DrivingSide>,
    /// Where U-turn connections are made.
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
