//! Acceptance checks of the import against the real data in `../shared/data/osm` and its
//! references (tags counted independently, SUMO netconvert 1.15 figures). Each test skips
//! with a notice when the data folder is absent.
#![allow(clippy::unwrap_used, clippy::print_stderr)]

use std::path::{Path, PathBuf};

use maps::{ImportOptions, RoundaboutSource, import_file};

fn data(rel: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(rel);
    if p.exists() {
        Some(p)
    } else {
        eprintln!(
            "skipped: {}: {} not found",
            std::thread::current().name().unwrap_or("-"),
            p.display()
        );
        None
    }
}

const OSM_FILES: &[&str] = &[
    "tiny_roundabout.osm",
    "montlake_roundabout.osm",
    "montlake_roundabout.osm.pbf",
    "leeds_cycleway.osm",
    "frederiksted.osm",
    "frederiksted.osm.pbf",
    "northwestern_nu.osm",
    "northwestern_nu.osm.pbf",
    "helsinki.osm.pbf",
];

#[test]
fn every_input_imports_with_invariants_checked_after_every_step() {
    let Some(osm) = data("osm") else { return };
    for f in OSM_FILES {
        let map = import_file(&osm.join(f), &ImportOptions::default())
            .unwrap_or_else(|e| panic!("{f}: {e}"));
        assert!(map.lanes.len() > 4, "{f}");
    }
    let Some(maps_dir) = data("trajectories/interaction/maps") else {
        return;
    };
    for f in [
        "DR_USA_Roundabout_FT.osm",
        "DR_USA_Roundabout_EP.osm",
        "DR_USA_Roundabout_SR.osm",
        "DR_CHN_Roundabout_LN.osm",
        "DR_DEU_Roundabout_OF.osm",
    ] {
        let map = import_file(&maps_dir.join(f), &ImportOptions::default())
            .unwrap_or_else(|e| panic!("{f}: {e}"));
        assert_eq!(map.roundabouts.len(), 1, "{f}: one roundabout");
    }
}

#[test]
fn xml_and_pbf_twins_give_byte_identical_native_maps() {
    let Some(osm) = data("osm") else { return };
    for name in ["montlake_roundabout", "frederiksted", "northwestern_nu"] {
        let xml = import_file(&osm.join(format!("{name}.osm")), &ImportOptions::default()).unwrap();
        let pbf = import_file(
            &osm.join(format!("{name}.osm.pbf")),
            &ImportOptions::default(),
        )
        .unwrap();
        assert!(
            maps::io::to_binary_bytes(&xml).unwrap() == maps::io::to_binary_bytes(&pbf).unwrap(),
            "{name}: binary differs"
        );
        assert!(
            maps::io::to_json_bytes(&xml).unwrap() == maps::io::to_json_bytes(&pbf).unwrap(),
            "{name}: JSON differs"
        );
        // A second import of the same file is identical too.
        let again = import_file(
            &osm.join(format!("{name}.osm.pbf")),
            &ImportOptions::default(),
        )
        .unwrap();
        assert!(
            maps::io::to_binary_bytes(&again).unwrap() == maps::io::to_binary_bytes(&pbf).unwrap()
        );
    }
}

/// Every ring in `reference/roundabouts_from_tags.json` (tags counted by a separate Python
/// script) is found as one roundabout with the same ways and the same car entries and
/// exits, each entry with a yield line; nothing else is guessed in these files.
#[test]
fn tagged_roundabouts_match_the_tags() {
    let Some(reference) = data("osm/reference/roundabouts_from_tags.json") else {
        return;
    };
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&reference).unwrap()).unwrap();
    let osm = reference_dir_parent();
    let mut checked = 0;
    for (file, entry) in reference["files"].as_object().unwrap() {
        let path = osm.join(file);
        if !path.exists() {
            continue;
        }
        let map = import_file(&path, &ImportOptions::default()).unwrap();
        let ours: Vec<_> = map
            .roundabouts
            .values()
            .filter(|r| r.source == RoundaboutSource::Tagged)
            .collect();
        let rings = entry["rings"].as_array().cloned().unwrap_or_default();
        assert_eq!(ours.len(), rings.len(), "{file}: tagged roundabouts");
        assert!(
            map.roundabouts
                .values()
                .all(|r| r.source != RoundaboutSource::Guessed),
            "{file}: nothing guessed"
        );
        for ring in rings {
            let mut ways: Vec<i64> = ring["osm_way_ids"]
                .as_array()
                .unwrap()
                .iter()
                .map(|w| {
                    w.as_i64()
                        .or_else(|| w.as_str().and_then(|s| s.parse().ok()))
                        .unwrap()
                })
                .collect();
            ways.sort_unstable();
            let found = ours
                .iter()
                .find(|r| r.osm_way_ids == ways)
                .unwrap_or_else(|| panic!("{file}: ring {ways:?} not found"));
            assert_eq!(
                found.entries.len() as i64,
                ring["entries"].as_i64().unwrap(),
                "{file}: entries"
            );
            assert_eq!(
                found.exits.len() as i64,
                ring["exits"].as_i64().unwrap(),
                "{file}: exits"
            );
            assert_eq!(
                found.yield_lines.len(),
                found.entries.len(),
                "{file}: a yield line per entry"
            );
            checked += 1;
        }
    }
    assert!(checked >= 3, "checked {checked} rings");
}

fn reference_dir_parent() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/osm")
}

/// Car lane length in netconvert's passenger-car scope (the car profile minus
/// `highway=service`) is within ±10 % of netconvert 1.15's figure for every file of both
/// references (the bundled extracts', and the roundabout extracts').
#[test]
fn car_lane_length_within_ten_percent_of_netconvert() {
    for folder in ["osm", "osm/roundabouts"] {
        let Some(reference) = data(&format!("{folder}/reference/netconvert.json")) else {
            continue;
        };
        let reference: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&reference).unwrap()).unwrap();
        let dir = reference_dir_parent().join("..").join(folder);
        for (file, entry) in reference["files"].as_object().unwrap() {
            let theirs = entry["primary"]["car_lane_length_m"].as_f64().unwrap();
            let map = import_file(&dir.join(file), &ImportOptions::default()).unwrap();
            let summary = maps::summary::summarize(&map);
            let ours: f64 = summary
                .car_lane_length_by_highway_m
                .iter()
                .filter(|(h, _)| h.as_str() != "service")
                .map(|(_, v)| v)
                .sum();
            let ratio = ours / theirs;
            eprintln!("{file}: ours {ours:.0} m, netconvert {theirs:.0} m, ratio {ratio:.3}");
            assert!(
                (0.9..=1.1).contains(&ratio),
                "{file}: ours {ours:.0} m vs netconvert {theirs:.0} m"
            );
        }
    }
}
