//! End-to-end tests of `pipeline map import | info | route` on real and small data.

#![allow(clippy::print_stdout, clippy::print_stderr, clippy::unwrap_used)]

mod common;

use std::path::Path;

use common::*;

/// Every file `map import` writes with the default `--rerun save`.
const ALL_FILES: &[&str] = &[
    "map.bin",
    "map.geojson",
    "map.json",
    "preview.png",
    "recording.rrd",
    "summary.json",
];

fn import(input: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args: Vec<std::ffi::OsString> = vec![
        "map".into(),
        "import".into(),
        input.into(),
        "--out".into(),
        out.into(),
    ];
    args.extend(extra.iter().map(Into::into));
    run(args)
}

fn check_import_folder(out: &Path, input_name: &str, format: &str) -> serde_json::Value {
    assert_eq!(entries(out), ALL_FILES, "files in {}", out.display());
    let summary = read_json(&out.join("summary.json"));
    assert!(summary["lanes"].as_u64().unwrap() > 0, "{summary}");
    for key in [
        "car_lane_length_m",
        "junctions",
        "components",
        "roundabouts",
        "skipped",
        "projection",
    ] {
        assert!(summary.get(key).is_some(), "summary.json lacks `{key}`");
    }
    let input = &summary["input"];
    assert_eq!(input["file"], input_name);
    assert_eq!(input["format"], format);
    assert_eq!(input["sha256"].as_str().unwrap().len(), 64);
    assert!(input["bytes"].as_u64().unwrap() > 0);
    assert!(summary["import"]["options"]["profile"]["name"].is_string());

    // Both native forms hold the same map.
    let json = maps::io::load(&out.join("map.json")).unwrap();
    let bin = maps::io::load(&out.join("map.bin")).unwrap();
    assert_eq!(json, bin);
    assert!(
        std::fs::read(out.join("map.bin"))
            .unwrap()
            .starts_with(b"DRVMAP")
    );

    // GeoJSON: a FeatureCollection of lon/lat positions.
    let gj = read_json(&out.join("map.geojson"));
    assert_eq!(gj["type"], "FeatureCollection");
    let features = gj["features"].as_array().unwrap();
    assert!(features.iter().any(|f| f["properties"]["kind"] == "road"));
    assert!(features.iter().any(|f| f["properties"]["kind"] == "lane"));
    let origin = json.projection.origin();
    let first = &features[0]["geometry"]["coordinates"][0];
    let (lon, lat) = (first[0].as_f64().unwrap(), first[1].as_f64().unwrap());
    assert!(
        (lon - origin.lon).abs() < 0.5 && (lat - origin.lat).abs() < 0.5,
        "[{lon}, {lat}] vs {origin:?}"
    );

    assert!(
        std::fs::read(out.join("preview.png"))
            .unwrap()
            .starts_with(b"\x89PNG")
    );
    assert!(
        std::fs::read(out.join("recording.rrd"))
            .unwrap()
            .starts_with(b"RRF2")
    );
    summary
}

/// No temporary siblings may be left next to an output folder.
fn assert_no_temporaries(parent: &Path) {
    let leftovers: Vec<String> = entries(parent)
        .into_iter()
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "left behind: {leftovers:?}");
}

#[test]
fn montlake_roundabout_import_writes_every_file() {
    let Some(input) = osm_file("montlake_roundabout.osm.pbf") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("montlake");
    let result = import(&input, &out, &[]);
    assert_success(&result, "map import");
    let summary = check_import_folder(&out, "montlake_roundabout.osm.pbf", "osm_pbf");
    let roundabouts = summary["roundabouts"].as_array().unwrap();
    assert_eq!(
        roundabouts.len(),
        1,
        "montlake has one tagged roundabout: {summary}"
    );
    assert_no_temporaries(tmp.path());

    // `map info --json` prints the same figures from the folder, the JSON and the binary file.
    for target in [out.clone(), out.join("map.json"), out.join("map.bin")] {
        let info = run([
            std::ffi::OsString::from("map"),
            "info".into(),
            target.clone().into(),
            "--json".into(),
        ]);
        assert_success(&info, "map info --json");
        let printed: serde_json::Value = serde_json::from_str(&stdout(&info)).unwrap();
        for (key, value) in printed.as_object().unwrap() {
            assert_eq!(
                &summary[key],
                value,
                "`{key}` of map info --json {}",
                target.display()
            );
        }
    }
    let text = run([
        std::ffi::OsString::from("map"),
        "info".into(),
        out.clone().into(),
    ]);
    assert_success(&text, "map info");
    assert!(
        stdout(&text).contains("roundabouts  1"),
        "{}",
        stdout(&text)
    );
}

#[test]
fn xml_and_pbf_twins_and_repeated_runs_give_identical_files() {
    let (Some(xml), Some(pbf)) = (
        osm_file("montlake_roundabout.osm"),
        osm_file("montlake_roundabout.osm.pbf"),
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let outs = [
        tmp.path().join("xml"),
        tmp.path().join("pbf"),
        tmp.path().join("pbf-again"),
    ];
    for (input, out) in [(&xml, &outs[0]), (&pbf, &outs[1]), (&pbf, &outs[2])] {
        assert_success(&import(input, out, &["--rerun", "off", "-q"]), "map import");
    }
    for name in ["map.json", "map.bin", "map.geojson", "preview.png"] {
        let read = |dir: &Path| std::fs::read(dir.join(name)).unwrap();
        assert!(
            read(&outs[0]) == read(&outs[1]),
            "{name} differs between the XML and PBF twins"
        );
        assert!(
            read(&outs[1]) == read(&outs[2]),
            "{name} differs between two runs"
        );
    }
    let summary = |dir: &Path| std::fs::read(dir.join("summary.json")).unwrap();
    assert_eq!(
        summary(&outs[1]),
        summary(&outs[2]),
        "summary.json differs between two runs"
    );
    // The twins' summaries differ only in the `input` block.
    let (mut a, mut b) = (
        read_json(&outs[0].join("summary.json")),
        read_json(&outs[1].join("summary.json")),
    );
    a.as_object_mut().unwrap().remove("input");
    b.as_object_mut().unwrap().remove("input");
    assert_eq!(a, b);
    assert_eq!(
        entries(&outs[0]),
        [
            "map.bin",
            "map.geojson",
            "map.json",
            "preview.png",
            "summary.json"
        ],
        "--rerun off"
    );
}

#[test]
fn small_map_without_shared_data() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("cross.osm");
    std::fs::write(&input, SMALL_OSM).unwrap();
    let out = tmp.path().join("runs").join("cross");
    let result = import(&input, &out, &[]);
    assert_success(&result, "map import");
    let summary = check_import_folder(&out, "cross.osm", "osm_xml");
    assert_eq!(summary["import"]["options"]["profile"]["name"], "car");
    // The footway is not a car road.
    let json = maps::io::load(&out.join("map.bin")).unwrap();
    assert!(json.roads.values().all(|r| r.highway != "footway"));
    assert!(
        json.roads
            .values()
            .flat_map(|r| &r.osm_way_ids)
            .all(|id| *id != 14)
    );

    // Importing again replaces the folder, and leaves nothing else behind.
    std::fs::write(out.join("stale.txt"), "from an earlier run").unwrap();
    assert_success(
        &import(&input, &out, &["-q", "--rerun", "off"]),
        "second map import",
    );
    assert!(!out.join("stale.txt").exists() && !out.join("recording.rrd").exists());
    assert_no_temporaries(&tmp.path().join("runs"));
}

#[test]
fn config_file_run_dir_and_options() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("cross.osm");
    std::fs::write(&input, SMALL_OSM).unwrap();
    let config = tmp.path().join("pipeline.toml");
    std::fs::write(
        &config,
        "[map.import]\nprofile = \"all\"\nu_turns = \"never\"\ndriving_side = \"left\"\n",
    )
    .unwrap();
    let run_dir = tmp.path().join("run");
    let out = run([
        std::ffi::OsString::from("--config"),
        config.into(),
        "--run-dir".into(),
        run_dir.clone().into(),
        "--seed".into(),
        "42".into(),
        "--rerun".into(),
        "off".into(),
        "map".into(),
        "import".into(),
        input.into(),
        "--out".into(),
        "cross".into(),
        "--u-turns".into(),
        "everywhere".into(),
    ]);
    assert_success(&out, "map import with a config file");
    let summary = read_json(&run_dir.join("cross").join("summary.json"));
    let import = &summary["import"];
    assert_eq!(
        import["options"]["profile"]["name"], "all",
        "from the config file"
    );
    assert_eq!(
        import["options"]["u_turns"], "everywhere",
        "the command line wins"
    );
    assert_eq!(import["options"]["driving_side"], "left");
    assert_eq!(import["seed"], 42);
    assert_eq!(summary["driving_side"], "left");
    // With the `all` profile the footway is a road too.
    let map = maps::io::load(&run_dir.join("cross").join("map.json")).unwrap();
    assert!(map.roads.values().any(|r| r.highway == "footway"));
}

#[test]
fn route_between_two_points_of_a_lane() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("cross.osm");
    std::fs::write(&input, SMALL_OSM).unwrap();
    let out = tmp.path().join("cross");
    assert_success(
        &import(&input, &out, &["-q", "--rerun", "off"]),
        "map import",
    );
    let map = maps::io::load(&out.join("map.bin")).unwrap();
    let lane = map
        .car_lanes()
        .max_by(|a, b| a.length_m.total_cmp(&b.length_m))
        .unwrap();
    let a = maps::geometry::point_at(&lane.centre, lane.length_m * 0.25);
    let b = maps::geometry::point_at(&lane.centre, lane.length_m * 0.75);

    let printed = run([
        std::ffi::OsString::from("map"),
        "route".into(),
        out.clone().into(),
        "--from".into(),
        format!("{},{}", a.x, a.y).into(),
        "--to".into(),
        format!("{},{}", b.x, b.y).into(),
    ]);
    assert_success(&printed, "map route");
    let route: serde_json::Value = serde_json::from_str(&stdout(&printed)).unwrap();
    let length = route["length_m"].as_f64().unwrap();
    assert!(
        (length - lane.length_m * 0.5).abs() < 1.0,
        "route of {length} m along a {} m lane",
        lane.length_m
    );
    assert!(route["waypoints"].as_array().unwrap().len() >= 2);

    // The same in WGS84, written as GeoJSON.
    let projector = map.projection.projector();
    let (la, lb) = (projector.unproject(a), projector.unproject(b));
    let file = tmp.path().join("route.geojson");
    let written = run([
        std::ffi::OsString::from("map"),
        "route".into(),
        out.join("map.json").into(),
        "--lat-lon".into(),
        "--from".into(),
        format!("{},{}", la.lat, la.lon).into(),
        "--to".into(),
        format!("{},{}", lb.lat, lb.lon).into(),
        "--out".into(),
        file.clone().into(),
    ]);
    assert_success(&written, "map route --lat-lon --out route.geojson");
    let gj = read_json(&file);
    assert_eq!(gj["features"][0]["geometry"]["type"], "LineString");
    let start = &gj["features"][0]["geometry"]["coordinates"][0];
    assert!(
        (start[0].as_f64().unwrap() - la.lon).abs() < 1e-4
            && (start[1].as_f64().unwrap() - la.lat).abs() < 1e-4
    );
}

#[test]
fn every_shared_osm_file_imports() {
    let Some(data) = shared_data() else {
        println!(
            "skipped: {}: ../shared/data is absent",
            std::thread::current().name().unwrap_or("-")
        );
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let mut inputs: Vec<_> = entries(&data.join("osm"))
        .into_iter()
        .filter(|n| n.ends_with(".osm") || n.ends_with(".osm.pbf"))
        .map(|n| data.join("osm").join(n))
        .collect();
    let maps_dir = data.join("trajectories").join("interaction").join("maps");
    inputs.extend(
        entries(&maps_dir)
            .into_iter()
            .filter(|n| n.ends_with(".osm"))
            .map(|n| maps_dir.join(n)),
    );
    for (i, input) in inputs.iter().enumerate() {
        let out = tmp.path().join(format!("out{i}"));
        let result = import(input, &out, &["-q", "--rerun", "off"]);
        assert_success(&result, &format!("map import {}", input.display()));
        let summary = read_json(&out.join("summary.json"));
        println!(
            "{}: {} lanes, {} m of car lanes, {} roundabouts",
            input.display(),
            summary["lanes"],
            summary["car_lane_length_m"],
            summary["roundabouts"].as_array().map_or(0, Vec::len)
        );
    }
}

/// The README's first command on the bundled default data works on a fresh clone.
#[test]
fn bundled_campus_imports() {
    let input = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/osm/northwestern_nu.osm.pbf"
    ));
    if !input.is_file() {
        println!(
            "skipped: {}: {} not bundled",
            std::thread::current().name().unwrap_or("-"),
            input.display()
        );
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("runs").join("northwestern");
    assert_success(
        &import(input, &out, &[]),
        "map import of the bundled campus",
    );
    let summary = check_import_folder(&out, "northwestern_nu.osm.pbf", "osm_pbf");
    assert!(
        summary["car_lane_length_m"].as_f64().unwrap() > 10_000.0,
        "{summary}"
    );
}

/// `map info` tells the kinds apart on a real extract with two-lane rings and
/// mini-roundabouts: the header counts them, every mini-roundabout is listed with its OSM
/// node, and the rings two or more lanes wide are counted.
#[test]
fn map_info_lists_multi_lane_rings_and_mini_roundabouts() {
    let Some(data) = shared_data() else {
        println!(
            "skipped: {}: ../shared/data is absent",
            std::thread::current().name().unwrap_or("-")
        );
        return;
    };
    let input = data.join("osm/roundabouts/andorra.osm.pbf");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("andorra");
    let imported = import(&input, &out, &["--rerun", "off"]);
    assert_success(&imported, "map import andorra");
    // Every tagged ring is found; the two tagged mini-roundabout nodes left as plain
    // junctions are warned about as such, with a reason, not as rings.
    let warnings = stderr(&imported);
    assert!(!warnings.contains("tagged ring"), "{warnings}");
    assert!(
        warnings.contains("2 tagged mini-roundabout nodes driven as ordinary junctions (first: mini-roundabout node "),
        "{warnings}"
    );
    let info = run([
        std::ffi::OsString::from("map"),
        "info".into(),
        out.clone().into(),
    ]);
    assert_success(&info, "map info");
    let text = stdout(&info);
    let summary = read_json(&out.join("summary.json"));
    let rings = summary["roundabouts"].as_array().unwrap();
    let minis = rings
        .iter()
        .filter(|r| r["kind"] == "mini_roundabout")
        .count();
    let wide = rings
        .iter()
        .filter(|r| r["kind"] != "mini_roundabout" && r["ring_lanes"].as_u64() >= Some(2))
        .count();
    assert!(minis > 0 && wide > 0, "{text}");
    let header = format!(
        "roundabouts  {} ({wide} two or more lanes wide), {minis} mini-roundabouts",
        rings.len() - minis
    );
    assert!(text.contains(&header), "no `{header}` in\n{text}");
    let listed = text
        .lines()
        .filter(|l| l.contains(" mini-roundabout: ") && l.contains("OSM node "))
        .count();
    assert_eq!(listed, minis, "{text}");
    // The GeoJSON has a point per mini-roundabout and the kind and width of every ring.
    let geojson = read_json(&out.join("map.geojson"));
    let features = geojson["features"].as_array().unwrap();
    let points = features
        .iter()
        .filter(|f| {
            f["properties"]["kind"] == "mini_roundabout" && f["geometry"]["type"] == "Point"
        })
        .count();
    assert_eq!(points, minis);
    let wide_features = features
        .iter()
        .filter(|f| f["properties"]["kind"] == "roundabout")
        .filter(|f| f["properties"]["ring_lanes"].as_u64() >= Some(2))
        .count();
    assert_eq!(wide_features, wide);
}
