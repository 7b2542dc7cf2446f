//! Drivable maps from OpenStreetMap (XML, `.osm.gz`, PBF) and Lanelet2 HD maps.
//!
//! The import is a sequence of small named transformations ([`build`]), each followed by
//! [`invariants::check_invariants`]. The result is a [`Map`]: roads, lanes with boundaries,
//! junction areas and lane-to-lane connections, roundabouts with their entries, exits and
//! yield lines, stop lines and markings, in a local metric frame whose WGS84 origin it keeps.
//! On top of it: routing ([`route`]), a spatial index of lanes ([`spatial`]), rasters ([`raster`]), GeoJSON ([`geojson`]), the
//! native file forms ([`io`]) and the `summary.json` figures ([`summary`]).
//!
//! A library never prints: progress and problems come back as values and [`MapError`].

pub mod build;
pub mod error;
pub mod geojson;
pub mod geometry;
pub mod graph;
pub mod invariants;
pub mod io;
pub mod lanelet2;
pub mod model;
pub mod options;
pub mod osm;
pub mod preview;
pub mod profile;
pub mod projection;
pub mod raster;
pub mod route;
pub mod samples;
pub mod spatial;
pub mod summary;
pub mod tags;

pub use build::{ImportOptions, import_file, import_osm, import_pbf_bytes};
pub use error::MapError;
pub use geometry::Point;
pub use model::*;
pub use projection::{LatLon, Projection};
