//! The arguments of `pipeline map import | info | route`.

use std::path::PathBuf;

use clap::{Args, Subcommand, ValueEnum};

#[derive(Debug, Subcommand)]
pub enum MapCommand {
    /// Import an OSM (.osm, .osm.gz, .osm.pbf) or Lanelet2 file into a map folder.
    Import(ImportArgs),
    /// Print a map's summary (lanes, lengths, junctions, components, roundabouts).
    Info(InfoArgs),
    /// Fastest route over lanes between two points.
    Route(RouteArgs),
}

#[derive(Debug, Args)]
pub struct ImportArgs {
    /// The input file.
    pub input: PathBuf,

    /// Output folder (written atomically; replaced if it holds an earlier import).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Road selection: car, passenger, all, or a TOML profile file [default: car].
    #[arg(long, value_name = "NAME|FILE")]
    pub profile: Option<String>,

    /// Keep only what lies in this WGS84 box.
    #[arg(
        long,
        value_name = "MINLON,MINLAT,MAXLON,MAXLAT",
        conflicts_with = "clip_polygon"
    )]
    pub clip_bbox: Option<String>,

    /// Keep only what lies in this polygon (GeoJSON, or Osmosis .poly).
    #[arg(long, value_name = "FILE")]
    pub clip_polygon: Option<PathBuf>,

    /// Traffic side [default: from the map's location].
    #[arg(long, value_enum)]
    pub driving_side: Option<DrivingSideArg>,

    /// Where U-turns are allowed [default: dead-ends].
    #[arg(long, value_enum)]
    pub u_turns: Option<UTurnsArg>,

    /// Do not report untagged near-circular one-way loops as roundabouts.
    #[arg(long)]
    pub no_guess_roundabouts: bool,

    /// Check the map's invariants after every import step, not only at the end (slower;
    /// the tests always do).
    #[arg(long)]
    pub check_every_step: bool,

    /// Projection origin [default: centre of the selected roads; (0, 0) UTM for Lanelet2].
    #[arg(long, value_name = "LAT,LON")]
    pub origin: Option<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DrivingSideArg {
    Left,
    Right,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum UTurnsArg {
    Never,
    DeadEnds,
    Everywhere,
}

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// A map file (map.json or map.bin) or a map folder.
    pub map: PathBuf,

    /// Print the summary as JSON (the same keys as summary.json).
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct RouteArgs {
    /// A map file (map.json or map.bin) or a map folder.
    pub map: PathBuf,

    /// Start, in map metres `x,y` (or `lat,lon` with --lat-lon).
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    pub from: String,

    /// Destination, in map metres `x,y` (or `lat,lon` with --lat-lon).
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    pub to: String,

    /// --from and --to are WGS84 `lat,lon`.
    #[arg(long)]
    pub lat_lon: bool,

    /// Write the route here (.json, or .geojson for a LineString in WGS84) instead of printing it.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}
