//! Golden tests: each real case under `tests/golden/<case>/` must import to exactly the
//! committed `summary.json` and `map.geojson`. `UPDATE_GOLDEN=1` rewrites them.
#![allow(clippy::unwrap_used, clippy::print_stderr)]

use std::path::{Path, PathBuf};

use maps::{ImportOptions, import_file};

fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/golden")
}

fn shared_data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

/// Compares `actual` with the committed file, or writes it under `UPDATE_GOLDEN=1`.
fn check_golden(path: &Path, actual: &str) {
    if std::env::var_os("UPDATE_GOLDEN").is_some() {
        std::fs::write(path, actual).unwrap();
        return;
    }
    let expected = std::fs::read_to_string(path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (run with UPDATE_GOLDEN=1 to create it)",
            path.display()
        )
    });
    if expected != actual {
        let first_diff = expected
            .lines()
            .zip(actual.lines())
            .position(|(a, b)| a != b);
        panic!(
            "{} differs from the import (first differing line {:?}); if the change is deliberate, rerun with UPDATE_GOLDEN=1 and review the diff",
            path.display(),
            first_diff.map(|i| i + 1)
        );
    }
}

fn run_case(case: &str, input: &Path, with_geojson: bool) {
    let map =
        import_file(input, &ImportOptions::default()).unwrap_or_else(|e| panic!("{case}: {e}"));
    let summary = serde_json::to_string_pretty(&maps::summary::summarize(&map)).unwrap() + "\n";
    let dir = golden_dir().join(case);
    check_golden(&dir.join("summary.json"), &summary);
    if with_geojson {
        let geojson = maps::geojson::to_geojson_string(&map).unwrap();
        check_golden(&dir.join("map.geojson"), &geojson);
    }
}

fn committed_input(case: &str) -> PathBuf {
    let dir = golden_dir().join(case);
    ["input.osm", "input.osm.gz", "input.osm.pbf"]
        .iter()
        .map(|name| dir.join(name))
        .find(|p| p.exists())
        .unwrap_or_else(|| panic!("no input in {}", dir.display()))
}

#[test]
fn tiny_roundabout() {
    run_case("tiny_roundabout", &committed_input("tiny_roundabout"), true);
}

#[test]
fn montlake_roundabout() {
    run_case(
        "montlake_roundabout",
        &committed_input("montlake_roundabout"),
        true,
    );
}

#[test]
fn leeds_cycleway() {
    run_case("leeds_cycleway", &committed_input("leeds_cycleway"), true);
}

#[test]
fn northwestern_nu() {
    run_case("northwestern_nu", &committed_input("northwestern_nu"), true);
}

#[test]
fn frederiksted() {
    run_case("frederiksted", &committed_input("frederiksted"), true);
}

/// A two-lane ring (primary roads without a `lanes` tag) and a mini-roundabout near it, cut
/// from the Andorra extract.
#[test]
fn andorra_rings() {
    run_case("andorra_rings", &committed_input("andorra_rings"), true);
    let map = import_file(&committed_input("andorra_rings"), &ImportOptions::default()).unwrap();
    let kinds: Vec<(maps::RoundaboutKind, u8)> = map
        .roundabouts
        .values()
        .map(|r| (r.kind, r.lanes_across))
        .collect();
    assert!(
        kinds.contains(&(maps::RoundaboutKind::Roundabout, 2)),
        "{kinds:?}"
    );
    assert!(
        kinds.contains(&(maps::RoundaboutKind::MiniRoundabout, 1)),
        "{kinds:?}"
    );
}

/// The INTERACTION map may not be copied into the repository: only its summary is golden.
#[test]
fn interaction_ft() {
    let input = shared_data().join("trajectories/interaction/maps/DR_USA_Roundabout_FT.osm");
    if !input.exists() {
        eprintln!(
            "skipped: {}: {} not found",
            std::thread::current().name().unwrap_or("-"),
            input.display()
        );
        return;
    }
    run_case("DR_USA_Roundabout_FT", &input, false);
}
