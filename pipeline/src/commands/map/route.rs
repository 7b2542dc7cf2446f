//! `pipeline map route`: the fastest route between two points, as JSON or GeoJSON.

use anyhow::{Context as _, Result};
use maps::Map;
use maps::geometry::Point;

use super::args::RouteArgs;
use crate::args::RerunMode;
use crate::clip::{parse_lat_lon, parse_pair};
use crate::commands::Context;
use crate::error::{CliError, FileRole, map_error};
use crate::inputs::load_map;
use crate::output::write_file_atomic;
use crate::recording;
use crate::ui::plural;

/// How far a route's end may lie from the nearest car lane: further away it is almost
/// certainly a mistake (wrong frame, swapped coordinates), not a place on this map.
const MAX_SNAP_DISTANCE_M: f64 = 100.0;

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

pub fn route(ctx: &Context<'_>, args: &RouteArgs) -> Result<()> {
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

    if matches!(ctx.global.rerun, RerunMode::Spawn | RerunMode::Connect(_)) {
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
