//! The `.rrd` of an import is readable by rerun's own tooling (`rerun rrd verify` and
//! `rerun rrd print` of rerun-sdk 0.36.3) and holds the `world/map/...` entities. Skipped
//! with a notice when the `rerun` executable is not installed; CI installs it.

#![allow(clippy::print_stdout, clippy::print_stderr, clippy::unwrap_used)]

mod common;

use common::*;

#[test]
fn recording_is_readable_by_rerun_and_shows_the_map() {
    let Some(exe) = rerun_cli() else {
        println!(
            "skipped: {}: rerun CLI not installed",
            std::thread::current().name().unwrap_or("-")
        );
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // Real data when present (a roundabout and stop lines), the small cross otherwise.
    let montlake = osm_file("montlake_roundabout.osm.pbf");
    let on_montlake = montlake.is_some();
    let input = match montlake {
        Some(p) => p,
        None => {
            let p = tmp.path().join("cross.osm");
            std::fs::write(&p, SMALL_OSM).unwrap();
            p
        }
    };
    let out = tmp.path().join("map");
    let result = run([
        std::ffi::OsString::from("map"),
        "import".into(),
        input.into(),
        "--out".into(),
        out.clone().into(),
    ]);
    assert_success(&result, "map import");
    let rrd = out.join("recording.rrd");
    assert!(rrd.is_file());

    let verify = rerun(&exe, &["rrd".as_ref(), "verify".as_ref(), rrd.as_os_str()]);
    assert!(
        verify.status.success(),
        "rerun rrd verify failed:\n{}\n{}",
        stdout(&verify),
        stderr(&verify)
    );

    let print = rerun(
        &exe,
        &[
            "rrd".as_ref(),
            "print".as_ref(),
            "-v".as_ref(),
            rrd.as_os_str(),
        ],
    );
    let text = format!("{}{}", stdout(&print), stderr(&print));
    assert!(print.status.success(), "rerun rrd print failed:\n{text}");
    for entity in [
        "world/map/lanes",
        "world/map/lane_boundaries",
        "world/map/junctions",
        "world/map/markings",
    ] {
        assert!(
            text.contains(entity),
            "`{entity}` missing from rerun rrd print:\n{text}"
        );
    }
    let summary = read_json(&out.join("summary.json"));
    if on_montlake {
        // Its ring and five give-way lines: the checks below must not pass vacuously.
        assert_eq!(summary["roundabouts"].as_array().map(Vec::len), Some(1));
        assert_eq!(summary["stop_lines"]["total"].as_u64(), Some(5));
    }
    if summary["roundabouts"]
        .as_array()
        .is_some_and(|r| !r.is_empty())
    {
        assert!(text.contains("world/map/roundabouts"), "{text}");
    }
    // Every ring's lanes and label, each under its own entity.
    for r in summary["roundabouts"].as_array().into_iter().flatten() {
        if r["circulating_lanes"].as_u64().unwrap_or(0) == 0 {
            continue;
        }
        let id = r["id"].as_u64().unwrap();
        for part in ["ring_lanes", "label"] {
            let entity = format!("world/map/roundabouts/{id}/{part}");
            assert!(
                text.contains(&entity),
                "`{entity}` missing from rerun rrd print:\n{text}"
            );
        }
    }
    if summary["stop_lines"]["total"].as_u64().unwrap_or(0) > 0 {
        assert!(text.contains("world/map/stop_lines"), "{text}");
    }
}
