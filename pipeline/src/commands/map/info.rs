//! `pipeline map info`: a map's summary, for a person or as JSON.

use std::path::Path;

use anyhow::{Context as _, Result};
use maps::DrivingSide;
use maps::io::MapFileForm;
use maps::model::RoundaboutKind;
use maps::summary::MapSummary;

use super::args::InfoArgs;
use crate::commands::Context;
use crate::inputs::load_map;
use crate::ui::plural;

pub fn info(ctx: &Context<'_>, args: &InfoArgs) -> Result<()> {
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
fn format_summary(file: &Path, form: MapFileForm, s: &MapSummary) -> String {
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
    let minis = s
        .roundabouts
        .iter()
        .filter(|r| r.kind == RoundaboutKind::MiniRoundabout)
        .count();
    let _ = writeln!(
        t,
        "roundabouts  {} ({} two or more lanes wide), {}",
        s.roundabouts.len() - minis,
        s.roundabouts.iter().filter(|r| r.ring_lanes >= 2).count(),
        plural(minis, "mini-roundabout")
    );
    for r in &s.roundabouts {
        let kind = r.kind.words();
        let priority = r.priority.words(r.priority_source);
        let osm = match r.osm_node_id {
            Some(node) => format!("OSM node {node}"),
            None => format!("OSM ways {:?}", r.osm_way_ids),
        };
        if r.kind == RoundaboutKind::MiniRoundabout {
            let _ = writeln!(
                t,
                "  #{} {kind}: {}, {}, {priority}, {osm}",
                r.id,
                plural(r.entries, "entry"),
                plural(r.exits, "exit"),
            );
            continue;
        }
        let _ = writeln!(
            t,
            "  #{} {kind}: {}, {}, {}, {} ({} wide), radius {:.1} m, {}, {priority}{}, {osm}",
            r.id,
            plural(r.entries, "entry"),
            plural(r.exits, "exit"),
            plural(r.yield_lines, "yield line"),
            plural(r.circulating_lanes, "circulating lane"),
            plural(r.ring_lanes as usize, "lane"),
            r.radius_m,
            if r.clockwise {
                "clockwise"
            } else {
                "counter-clockwise"
            },
            if r.guessed { ", guessed" } else { "" },
        );
    }
    for p in &s.ring_problems {
        let _ = writeln!(
            t,
            "  {}: {}",
            if p.imported {
                "imported with a note"
            } else {
                "not imported"
            },
            p.reason
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
