//! `pipeline map import | info | route`.

use std::io::Read;
use std::path::Path;

use anyhow::{Context as _, Result};
use maps::build::UTurns;
use maps::geometry::Point;
use maps::io::MapFileForm;
use maps::osm::InputFormat;
use maps::profile::RoadProfile;
use maps::summary::MapSummary;
use maps::{DrivingSide, ImportOptions, Map};
use serde::Serialize;
use sha2::{Digest, Sha256};

use super::Context;
use crate::cli::{
    DrivingSideArg, ImportArgs, InfoArgs, MapCommand, RerunMode, RouteArgs, UTurnsArg,
};
use crate::clip::{parse_bbox, parse_lat_lon, parse_pair, read_polygon_file};
use crate::error::{CliError, FileRole, map_error};
use crate::inputs::load_map;
use crate::output::{AtomicDir, Markers, write_file_atomic};
use crate::recording;
use crate::ui::plural;

/// The files `map import` writes.
pub use crate::inputs::{MAP_BIN, MAP_JSON};
pub const MAP_GEOJSON: &str = "map.geojson";
pub const PREVIEW_PNG: &str = "preview.png";
pub const SUMMARY_JSON: &str = "summary.json";

/// A folder holding any of these is an earlier import that may be replaced.
const IMPORT_MARKERS: Markers = &[SUMMARY_JSON, MAP_JSON, MAP_BIN];

/// How far a route's end may lie from the nearest car lane: further away it is almost
/// certainly a mistake (wrong frame, swapped coordinates), not a place on this map.
const MAX_SNAP_DISTANCE_M: f64 = 100.0;

/// Longer side of `preview.png`, pixels.
const PREVIEW_MAX_PX: u32 = 1024;

pub fn run(ctx: &Context<'_>, command: &MapCommand) -> Result<()> {
    match command {
        MapCommand::Import(args) => import(ctx, args),
        MapCommand::Info(args) => info(ctx, args),
        MapCommand::Route(args) => route(ctx, args),
    }
}

/// The import settings in effect, from the command line over the config file over defaults.
#[derive(Debug)]
pub struct ResolvedImport {
    pub options: ImportOptions,
    /// Where the profile came from: a built-in name or a file name.
    pub profile_source: String,
}

/// Merges `map import`'s options with `[map.import]` of the config file.
pub fn resolve_import_options(ctx: &Context<'_>, args: &ImportArgs) -> Result<ResolvedImport> {
    let cfg = &ctx.config.map.import;
    let config_file = || ctx.cli.config.clone().unwrap_or_default();
    let bad_option = |what: &str, msg: String| {
        CliError::new(format!("{what}: {msg}"), "see `pipeline map import --help`")
    };
    let bad_config = |key: &str, msg: String| {
        CliError::file(
            &config_file(),
            format!("[map.import] {key}: {msg}"),
            "fix the config file or override it on the command line",
        )
    };

    let mut options = ImportOptions::default();

    let (profile, profile_source) = match (&args.profile, &cfg.profile) {
        (Some(p), _) => load_profile(p, Path::new(p)).map_err(|m| bad_option("--profile", m))?,
        (None, Some(p)) => load_profile(p, &ctx.config.resolve(Path::new(p)))
            .map_err(|m| bad_config("profile", m))?,
        (None, None) => (RoadProfile::car(), "car".to_owned()),
    };
    options.profile = profile;

    options.clip = match (&args.clip_bbox, &args.clip_polygon) {
        (Some(b), _) => Some(parse_bbox(b).map_err(|m| bad_option("--clip-bbox", m))?),
        (None, Some(p)) => Some(read_polygon_file(p).map_err(|m| {
            CliError::file(
                p,
                m,
                "give a GeoJSON Polygon or an Osmosis .poly file to --clip-polygon",
            )
        })?),
        (None, None) => match (&cfg.clip_bbox, &cfg.clip_polygon) {
            (Some(b), _) => Some(parse_bbox(b).map_err(|m| bad_config("clip_bbox", m))?),
            (None, Some(p)) => {
                let p = ctx.config.resolve(p);
                Some(read_polygon_file(&p).map_err(|m| {
                    CliError::file(
                        &p,
                        m,
                        "fix `clip_polygon` in the config file (GeoJSON Polygon or .poly)",
                    )
                })?)
            }
            (None, None) => None,
        },
    };

    options.driving_side = match (args.driving_side, &cfg.driving_side) {
        (Some(DrivingSideArg::Left), _) => Some(DrivingSide::Left),
        (Some(DrivingSideArg::Right), _) => Some(DrivingSide::Right),
        (None, Some(s)) => Some(match s.as_str() {
            "left" => DrivingSide::Left,
            "right" => DrivingSide::Right,
            _ => {
                return Err(bad_config(
                    "driving_side",
                    format!("expected left or right, not `{s}`"),
                )
                .into());
            }
        }),
        (None, None) => None,
    };

    options.u_turns = match (args.u_turns, &cfg.u_turns) {
        (Some(UTurnsArg::Never), _) => UTurns::Never,
        (Some(UTurnsArg::DeadEnds), _) => UTurns::DeadEnds,
        (Some(UTurnsArg::Everywhere), _) => UTurns::Everywhere,
        (None, Some(s)) => match s.as_str() {
            "never" => UTurns::Never,
            "dead-ends" | "dead_ends" => UTurns::DeadEnds,
            "everywhere" => UTurns::Everywhere,
            _ => {
                return Err(bad_config(
                    "u_turns",
                    format!("expected never, dead-ends or everywhere, not `{s}`"),
                )
                .into());
            }
        },
        (None, None) => UTurns::default(),
    };

    options.guess_roundabouts = !args.no_guess_roundabouts && cfg.guess_roundabouts.unwrap_or(true);
    options.check_invariants = args.check_every_step;

    options.origin = match (&args.origin, &cfg.origin) {
        (Some(o), _) => Some(parse_lat_lon(o).map_err(|m| bad_option("--origin", m))?),
        (None, Some(o)) => Some(parse_lat_lon(o).map_err(|m| bad_config("origin", m))?),
        (None, None) => None,
    };

    Ok(ResolvedImport {
        options,
        profile_source,
    })
}

/// A built-in profile by name, or a TOML profile file (named after the file unless it says
/// `name = ...`).
fn load_profile(spec: &str, path: &Path) -> std::result::Result<(RoadProfile, String), String> {
    if let Some(p) = RoadProfile::by_name(spec) {
        return Ok((p, spec.to_owned()));
    }
    if !path.is_file() {
        return Err(format!(
            "unknown profile `{spec}`: expected car, passenger, all, or a profile .toml file"
        ));
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    let table: toml::Table =
        toml::from_str(&text).map_err(|e| format!("{}: {}", path.display(), e.message()))?;
    let named = table.contains_key("name");
    let mut profile: RoadProfile = toml::from_str(&text)
        .map_err(|e| format!("{}: not a road profile: {}", path.display(), e.message()))?;
    if !named {
        profile.name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "custom".into());
    }
    if profile.highways.is_empty() {
        return Err(format!(
            "{}: the profile selects no `highways`",
            path.display()
        ));
    }
    let source = path
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok((profile, source))
}

/// What `summary.json` says about the input file.
#[derive(Debug, Clone, Serialize)]
pub struct InputInfo {
    /// File name only, so the summary does not depend on where the file was.
    pub file: String,
    pub format: InputFormat,
    pub lanelet2: bool,
    pub bytes: u64,
    pub sha256: String,
}

/// How the map was made: the effective options and the seed.
#[derive(Debug, Clone, Serialize)]
pub struct ImportRecord<'a> {
    pub options: &'a ImportOptions,
    pub profile_source: &'a str,
    pub seed: u64,
    pub pipeline_version: &'static str,
    pub map_format_version: u32,
}

/// `summary.json`: the map's summary, then the input and how it was imported.
#[derive(Debug, Serialize)]
struct SummaryFile<'a> {
    #[serde(flatten)]
    summary: &'a MapSummary,
    input: &'a InputInfo,
    import: ImportRecord<'a>,
}

fn sha256_file(path: &Path) -> Result<(u64, String)> {
    let read_err = |e: std::io::Error| {
        anyhow::Error::new(CliError::file(
            path,
            format!("cannot read: {e}"),
            "check that the path exists and is readable",
        ))
    };
    let mut file = std::fs::File::open(path).map_err(read_err)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut bytes = 0u64;
    loop {
        let n = file.read(&mut buf).map_err(read_err)?;
        if n == 0 {
            break;
        }
        bytes += n as u64;
        hasher.update(&buf[..n]);
    }
    let hex = hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    Ok((bytes, hex))
}

fn import(ctx: &Context<'_>, args: &ImportArgs) -> Result<()> {
    let input = &args.input;
    let out = ctx.output_path(&args.out);
    let resolved = resolve_import_options(ctx, args)?;
    let options = &resolved.options;
    if !input.is_file() {
        return Err(CliError::file(
            input,
            "no such file",
            "check the input path (an .osm, .osm.gz or .osm.pbf file)",
        )
        .into());
    }
    // A bad destination fails now, not after the import.
    AtomicDir::check_destination(&out, IMPORT_MARKERS)?;

    let mut progress = ctx.ui.progress("map import");
    progress.step(&format!("reading {}", input.display()));
    let (osm, format) =
        maps::osm::read_osm_file(input).map_err(|e| map_error(input, e, FileRole::OsmInput))?;
    let lanelet2 = osm.is_lanelet2();
    progress.note(&format!(
        "{} nodes, {} ways, {} relations{}",
        osm.nodes.len(),
        osm.ways.len(),
        osm.relations.len(),
        if lanelet2 { " (Lanelet2)" } else { "" }
    ));

    progress.step(&format!(
        "building the map (profile {})",
        options.profile.name
    ));
    // The reader parses on every core but the build mostly runs on one: meanwhile, another
    // core hashes the input for summary.json and prepares the output folder and the
    // recording (whose sink starts threads). If the build fails, dropping them removes the
    // folder, recording included.
    let prepare_outputs = || -> Result<_> {
        let hashed = sha256_file(input)?;
        let dir = AtomicDir::create(&out, IMPORT_MARKERS)?;
        let rec = match ctx.cli.rerun {
            RerunMode::Off => None,
            _ => Some(ctx.open_recording(Some(dir.path()))?),
        };
        Ok((hashed, dir, rec))
    };
    let (built, prepared) = rayon::join(|| maps::import_osm(&osm, options), prepare_outputs);
    let map = built.map_err(|e| map_error(input, e, FileRole::OsmInput))?;
    let ((bytes, sha256), dir, rec) = prepared?;
    // Freeing the parsed OSM data (hundreds of thousands of small allocations) costs more
    // than the rest of the import's bookkeeping; the process ends right after the import.
    std::mem::forget(osm);
    if map.lanes.is_empty() {
        return Err(CliError::file(
            input,
            format!("no drivable roads selected (profile {})", options.profile.name),
            "the file holds no roads for this profile: try --profile all, a larger --clip-bbox, or another file",
        )
        .into());
    }
    let summary = maps::summary::summarize(&map);
    let input_info = InputInfo {
        file: input
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        format,
        lanelet2,
        bytes,
        sha256,
    };
    let record = ImportRecord {
        options,
        profile_source: &resolved.profile_source,
        seed: ctx.cli.seed,
        pipeline_version: env!("CARGO_PKG_VERSION"),
        map_format_version: maps::model::MAP_FORMAT_VERSION,
    };

    progress.step(&format!("writing {}", out.display()));
    // The recording is independent of the files: log it while they are encoded. It is
    // finished (flushed, closed) before the rename, so the .rrd is complete when the folder appears.
    let (written, recorded) = rayon::join(
        || write_outputs(dir.path(), &map, &summary, &input_info, record),
        || -> Result<()> {
            let Some(rec) = rec else {
                return Ok(());
            };
            if let Some(stream) = rec.stream() {
                recording::log_map(stream, &map)?;
            }
            rec.finish()
        },
    );
    written?;
    recorded?;
    let dest = dir.commit()?;
    drop(progress);

    let km = summary.car_lane_length_m / 1000.0;
    ctx.ui.info(&format!(
        "map import: wrote {}: {}, {} ({km:.1} km of car lanes), {}, {}",
        dest.display(),
        plural(summary.roads, "road"),
        plural(summary.lanes, "lane"),
        plural(summary.junctions, "junction"),
        plural(summary.roundabouts.len(), "roundabout"),
    ));
    let skipped = &summary.skipped;
    if skipped.ways_missing_nodes + skipped.degenerate_ways + skipped.invalid_nodes > 0 {
        ctx.ui.warn(&format!(
            "skipped {} with missing nodes, {}, {} with invalid coordinates (see {SUMMARY_JSON})",
            plural(skipped.ways_missing_nodes, "way"),
            plural(skipped.degenerate_ways, "degenerate way"),
            plural(skipped.invalid_nodes, "node")
        ));
    }
    Ok(())
}

fn write_outputs(
    dir: &Path,
    map: &Map,
    summary: &MapSummary,
    input: &InputInfo,
    import: ImportRecord<'_>,
) -> Result<()> {
    let write = |name: &str, bytes: &[u8]| -> Result<()> {
        let path = dir.join(name);
        std::fs::write(&path, bytes).map_err(|e| {
            anyhow::Error::new(CliError::file(
                &path,
                format!("cannot write: {e}"),
                "check free disk space and permissions",
            ))
        })
    };
    let encode_and_write = |name: &str, encoded: Result<Vec<u8>, maps::MapError>| {
        write(
            name,
            &encoded.map_err(|e| map_error(dir, e, FileRole::Output))?,
        )
    };
    // The four files are independent: encode and write them side by side; a failure is
    // reported in this fixed order.
    let ((json, bin), (geojson, png)) = rayon::join(
        || {
            rayon::join(
                || encode_and_write(MAP_JSON, maps::io::to_json_bytes(map)),
                || encode_and_write(MAP_BIN, maps::io::to_binary_bytes(map)),
            )
        },
        || {
            rayon::join(
                || {
                    let text = maps::geojson::to_geojson_string(map);
                    encode_and_write(MAP_GEOJSON, text.map(String::into_bytes))
                },
                || {
                    let png = maps::preview::render_preview_png(map, PREVIEW_MAX_PX);
                    encode_and_write(PREVIEW_PNG, png)
                },
            )
        },
    );
    json?;
    bin?;
    geojson?;
    png?;
    let file = SummaryFile {
        summary,
        input,
        import,
    };
    let mut text =
        serde_json::to_string_pretty(&file).context("summary.json: serialisation failed")?;
    text.push('\n');
    write(SUMMARY_JSON, text.as_bytes())?;
    Ok(())
}

fn info(ctx: &Context<'_>, args: &InfoArgs) -> Result<()> {
    let (map, file, form) = load_map(&args.map)?;
    let summary = maps::summary::summarize(&map);
    if args.json {
        let mut text =
            serde_json::to_string_pretty(&summary).context("summary: serialisation failed")?;
        text.push('\n');
        ctx.ui.result(&text);
    } else {
        ctx.ui.result(&format_summary(&file, form, &summary));
    }
    Ok(())
}

/// The summary for a person.
pub fn format_summary(file: &Path, form: MapFileForm, s: &MapSummary) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    let form = match form {
        MapFileForm::Json => "JSON",
        MapFileForm::Binary => "binary",
    };
    let origin = s.projection.origin();
    let projection = match s.projection {
        maps::Projection::Local { .. } => "local transverse Mercator".to_owned(),
        maps::Projection::Utm { zone, .. } => format!("UTM zone {zone}"),
    };
    let side = match s.driving_side {
        DrivingSide::Left => "left",
        DrivingSide::Right => "right",
    };
    let _ = writeln!(t, "map          {} ({form})", file.display());
    let _ = writeln!(t, "profile      {}, driving on the {side}", s.profile);
    let _ = writeln!(
        t,
        "projection   {projection}, origin {:.7}, {:.7}",
        origin.lat, origin.lon
    );
    let _ = writeln!(t, "roads        {}", s.roads);
    let _ = writeln!(
        t,
        "lanes        {} ({} for cars), {:.2} km of car lanes ({:.2} km in all)",
        s.lanes,
        s.car_lanes,
        s.car_lane_length_m / 1000.0,
        s.lane_length_m / 1000.0
    );
    let _ = writeln!(
        t,
        "junctions    {} ({} in all), {}",
        plural(s.junctions, "intersection"),
        plural(s.junctions_all, "junction"),
        plural(s.connections, "connection")
    );
    let _ = writeln!(
        t,
        "components   {} strongly connected; the largest has {}, {:.2} km",
        s.components.count,
        plural(s.components.largest_lane_count, "lane"),
        s.components.largest_lane_length_m / 1000.0
    );
    let stops: Vec<String> = s
        .stop_lines
        .iter()
        .map(|(k, v)| format!("{k} {v}"))
        .collect();
    let _ = writeln!(
        t,
        "stop lines   {}",
        if stops.is_empty() {
            "none".to_owned()
        } else {
            stops.join(", ")
        }
    );
    let _ = writeln!(t, "roundabouts  {}", s.roundabouts.len());
    for r in &s.roundabouts {
        let _ = writeln!(
            t,
            "  #{}: {}, {}, {}, {}, radius {:.1} m, {}{}, OSM ways {:?}",
            r.id,
            plural(r.entries, "entry"),
            plural(r.exits, "exit"),
            plural(r.yield_lines, "yield line"),
            plural(r.circulating_lanes, "circulating lane"),
            r.radius_m,
            if r.clockwise {
                "clockwise"
            } else {
                "counter-clockwise"
            },
            if r.guessed { ", guessed" } else { "" },
            r.osm_way_ids
        );
    }
    let k = &s.skipped;
    let _ = writeln!(
        t,
        "restrictions {} applied, {} not applicable (unknown ways, via ways)",
        k.restrictions_applied, k.restrictions_skipped
    );
    let _ = writeln!(
        t,
        "skipped      {} with missing nodes, {}, {} with invalid coordinates, {} not on a selected road",
        plural(k.ways_missing_nodes, "way"),
        plural(k.degenerate_ways, "degenerate way"),
        plural(k.invalid_nodes, "node"),
        plural(k.stop_nodes_unplaced, "stop node"),
    );
    t
}

/// `{"type": "Feature", ...}` of a route's waypoints in WGS84.
fn route_geojson(map: &Map, route: &maps::route::Route) -> serde_json::Value {
    let projector = map.projection.projector();
    let round = |v: f64| (v * 1e7).round() / 1e7;
    let mut coords: Vec<[f64; 2]> = Vec::with_capacity(route.waypoints.len());
    for w in &route.waypoints {
        let ll = projector.unproject(w.position);
        let c = [round(ll.lon), round(ll.lat)];
        if coords.last() != Some(&c) {
            coords.push(c);
        }
    }
    serde_json::json!({
        "type": "FeatureCollection",
        "features": [{
            "type": "Feature",
            "geometry": { "type": "LineString", "coordinates": coords },
            "properties": {
                "kind": "route",
                "length_m": route.length_m,
                "travel_time_s": route.travel_time_s,
                "lanes": route.lanes.iter().map(|l| l.0).collect::<Vec<_>>(),
            },
        }],
    })
}

fn route(ctx: &Context<'_>, args: &RouteArgs) -> Result<()> {
    let (map, file, _) = load_map(&args.map)?;
    let point = |flag: &str, s: &str| -> Result<Point> {
        if args.lat_lon {
            let ll = parse_lat_lon(s)
                .map_err(|m| CliError::new(format!("{flag}: {m}"), "give `lat,lon` in degrees"))?;
            Ok(map.projection.project(ll))
        } else {
            let (x, y) = parse_pair(s).map_err(|m| {
                CliError::new(
                    format!("{flag}: {m}"),
                    "give `x,y` in map metres, or `lat,lon` with --lat-lon",
                )
            })?;
            Ok(Point::new(x, y))
        }
    };
    let (from, to) = (point("--from", &args.from)?, point("--to", &args.to)?);
    let router = maps::route::Router::new(&map);
    for (flag, p) in [("--from", from), ("--to", to)] {
        let (_, distance) = router
            .snap(p)
            .map_err(|e| map_error(&file, e, FileRole::MapFile))?;
        if distance > MAX_SNAP_DISTANCE_M {
            return Err(CliError::new(
                format!("{flag}: the point is {distance:.0} m from the nearest car lane of {}", file.display()),
                "give a point on or near a road of the map (x,y in map metres, or lat,lon with --lat-lon)",
            )
            .into());
        }
    }
    let route = router
        .route(from, to)
        .map_err(|e| map_error(&file, e, FileRole::MapFile))?;

    if matches!(ctx.cli.rerun, RerunMode::Spawn | RerunMode::Connect(_)) {
        let rec = ctx.open_recording(None)?;
        if let Some(stream) = rec.stream() {
            recording::log_map(stream, &map)?;
            let path: Vec<Point> = route.waypoints.iter().map(|w| w.position).collect();
            recording::log_route(stream, &path)?;
        }
        rec.finish()?;
    }

    let geojson = args.out.as_ref().is_some_and(|p| {
        p.extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("geojson"))
    });
    let mut text = if geojson {
        serde_json::to_string(&route_geojson(&map, &route))
    } else {
        serde_json::to_string_pretty(&route)
    }
    .context("route: serialisation failed")?;
    text.push('\n');
    match &args.out {
        Some(out) => {
            let out = ctx.output_path(out);
            write_file_atomic(&out, text.as_bytes())?;
            ctx.ui.info(&format!(
                "map route: {:.1} m, {:.1} s over {}; wrote {}",
                route.length_m,
                route.travel_time_s,
                plural(route.lanes.len(), "lane"),
                out.display()
            ));
        }
        None => ctx.ui.result(&text),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::{Cli, Group};
    use crate::config::Config;
    use crate::ui::{Ui, Verbosity};
    use clap::Parser;
    use maps::build::Clip;

    fn import_args(cli: &Cli) -> &ImportArgs {
        match &cli.command {
            Group::Map {
                command: MapCommand::Import(a),
            } => a,
            _ => panic!("not an import"),
        }
    }

    #[test]
    fn command_line_overrides_config_overrides_defaults() -> Result<()> {
        let config = Config::parse(
            "[map.import]\nprofile = \"passenger\"\nu_turns = \"never\"\ndriving_side = \"left\"\norigin = \"1,2\"\n",
        )
        .map_err(anyhow::Error::msg)?;
        let ui = Ui::new(Verbosity::Quiet);
        let cli = Cli::try_parse_from([
            "pipeline",
            "map",
            "import",
            "x.osm",
            "--out",
            "o",
            "--u-turns",
            "everywhere",
        ])?;
        let ctx = Context {
            cli: &cli,
            config: &config,
            ui: &ui,
            recording: None,
        };
        let r = resolve_import_options(&ctx, import_args(&cli))?;
        assert_eq!(r.options.profile.name, "passenger");
        assert_eq!(r.options.u_turns, UTurns::Everywhere);
        assert_eq!(r.options.driving_side, Some(DrivingSide::Left));
        assert_eq!(r.options.origin, Some(maps::LatLon::new(1.0, 2.0)));
        assert!(r.options.guess_roundabouts);

        let cli = Cli::try_parse_from([
            "pipeline",
            "map",
            "import",
            "x.osm",
            "--out",
            "o",
            "--no-guess-roundabouts",
            "--clip-bbox",
            "1,2,3,4",
        ])?;
        let defaults = Config::default();
        let ctx = Context {
            cli: &cli,
            config: &defaults,
            ui: &ui,
            recording: None,
        };
        let r = resolve_import_options(&ctx, import_args(&cli))?;
        assert_eq!(r.options.profile.name, "car");
        assert!(!r.options.guess_roundabouts);
        assert!(matches!(r.options.clip, Some(Clip::BoundingBox { .. })));

        let cli = Cli::try_parse_from([
            "pipeline",
            "map",
            "import",
            "x.osm",
            "--out",
            "o",
            "--profile",
            "bicycle",
        ])?;
        let ctx = Context {
            cli: &cli,
            config: &defaults,
            ui: &ui,
            recording: None,
        };
        assert!(resolve_import_options(&ctx, import_args(&cli)).is_err());
        Ok(())
    }

    #[test]
    fn profile_files() -> Result<()> {
        let dir = tempfile::tempdir()?;
        let p = dir.path().join("buses.toml");
        std::fs::write(
            &p,
            "highways = [\"primary\", \"busway\"]\ncar_highways = [\"primary\"]\n",
        )?;
        let (profile, source) =
            load_profile(&p.to_string_lossy(), &p).map_err(anyhow::Error::msg)?;
        assert_eq!(
            (profile.name.as_str(), source.as_str()),
            ("buses", "buses.toml")
        );
        assert_eq!(
            profile.highways,
            vec!["primary".to_owned(), "busway".to_owned()]
        );
        std::fs::write(&p, "highways = 3\n")?;
        assert!(load_profile(&p.to_string_lossy(), &p).is_err());
        Ok(())
    }
}
