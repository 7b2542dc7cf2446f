//! Bad input gives one clear error line naming the file, a non-zero exit, and no output
//! folder (nor a temporary one) left behind. Never a panic.

#![allow(clippy::print_stdout, clippy::print_stderr, clippy::unwrap_used)]

mod common;

use std::path::Path;

use common::*;

/// Imports `input` into `<tmp>/out` and checks the failure is clean; returns the error line.
fn assert_clean_failure(tmp: &Path, input: &Path, extra: &[&str]) -> String {
    let out = tmp.join("out");
    let mut args: Vec<std::ffi::OsString> = vec![
        "map".into(),
        "import".into(),
        input.into(),
        "--out".into(),
        out.clone().into(),
    ];
    args.extend(extra.iter().map(Into::into));
    let result = run(args);
    let err = stderr(&result);
    assert!(
        !result.status.success(),
        "import of {} succeeded:\n{err}",
        input.display()
    );
    assert_eq!(
        result.status.code(),
        Some(1),
        "exit code for {}:\n{err}",
        input.display()
    );
    assert!(
        !err.contains("panicked"),
        "panic on {}:\n{err}",
        input.display()
    );
    let error_lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(error_lines.len(), 1, "one error line expected:\n{err}");
    let name = input.file_name().unwrap().to_string_lossy();
    assert!(
        error_lines[0].contains(name.as_ref()),
        "the error names the file {name}:\n{err}"
    );
    assert!(
        err.lines().any(|l| l.starts_with("hint:")),
        "a hint follows:\n{err}"
    );
    assert!(
        !out.exists(),
        "an output folder was left behind for {}",
        input.display()
    );
    let leftovers: Vec<String> = entries(tmp)
        .into_iter()
        .filter(|n| n.starts_with(".out"))
        .collect();
    assert!(
        leftovers.is_empty(),
        "temporary folders left behind: {leftovers:?}"
    );
    error_lines[0].to_owned()
}

fn write(tmp: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let path = tmp.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

#[test]
fn malformed_xml() {
    let tmp = tempfile::tempdir().unwrap();
    let input = write(
        tmp.path(),
        "malformed.osm",
        b"<?xml version='1.0'?>\n<osm version=\"0.6\">\n  <node id=\"1\" lat=\"42.0\" lon=\"-87.6\">\n  <way id=\"2\"><nd ref=",
    );
    let line = assert_clean_failure(tmp.path(), &input, &[]);
    println!("{line}");
}

#[test]
fn not_osm_at_all() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, bytes) in [
        ("empty.osm", &b""[..]),
        ("html.osm", b"<html><body>404 Not Found</body></html>"),
        ("binary.osm", &[0u8, 159, 146, 150, 255, 0, 1, 2][..]),
        ("fake.osm.pbf", b"this is not a protobuf file at all"),
        (
            "broken.osm.gz",
            &[0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3, 1, 2, 3][..],
        ),
    ] {
        let input = write(tmp.path(), name, bytes);
        println!("{}", assert_clean_failure(tmp.path(), &input, &[]));
    }
}

#[test]
fn missing_input_file() {
    let tmp = tempfile::tempdir().unwrap();
    println!(
        "{}",
        assert_clean_failure(tmp.path(), &tmp.path().join("nowhere.osm.pbf"), &[])
    );
}

#[test]
fn truncated_and_corrupt_pbf() {
    let Some(real) = osm_file("montlake_roundabout.osm.pbf") else {
        return;
    };
    let bytes = std::fs::read(real).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    for (i, cut) in [bytes.len() / 2, bytes.len() - 10, 40]
        .into_iter()
        .enumerate()
    {
        let input = write(tmp.path(), &format!("truncated{i}.osm.pbf"), &bytes[..cut]);
        println!("{}", assert_clean_failure(tmp.path(), &input, &[]));
    }
    // Bytes flipped inside the compressed data block.
    let mut corrupt = bytes.clone();
    let mid = corrupt.len() * 2 / 3;
    for b in &mut corrupt[mid..mid + 64] {
        *b ^= 0x5a;
    }
    let input = write(tmp.path(), "corrupt.osm.pbf", &corrupt);
    println!("{}", assert_clean_failure(tmp.path(), &input, &[]));
}

#[test]
fn way_referencing_missing_nodes_only() {
    let tmp = tempfile::tempdir().unwrap();
    let input = write(
        tmp.path(),
        "missing_nodes.osm",
        br#"<osm version="0.6">
  <way id="1"><nd ref="100"/><nd ref="101"/><tag k="highway" v="residential"/></way>
</osm>"#,
    );
    println!("{}", assert_clean_failure(tmp.path(), &input, &[]));
}

#[test]
fn empty_selection() {
    let tmp = tempfile::tempdir().unwrap();
    let input = write(
        tmp.path(),
        "footways.osm",
        br#"<osm version="0.6">
  <node id="1" lat="42.0550" lon="-87.6760"/>
  <node id="2" lat="42.0570" lon="-87.6760"/>
  <node id="3" lat="42.0570" lon="-87.6740"/>
  <way id="1"><nd ref="1"/><nd ref="2"/><tag k="highway" v="footway"/></way>
  <way id="2"><nd ref="2"/><nd ref="3"/><tag k="highway" v="cycleway"/></way>
  <way id="3"><nd ref="1"/><nd ref="3"/><tag k="building" v="yes"/></way>
</osm>"#,
    );
    println!("{}", assert_clean_failure(tmp.path(), &input, &[]));
    // A valid file clipped to a box that holds none of its roads.
    let cross = write(tmp.path(), "cross.osm", SMALL_OSM.as_bytes());
    println!(
        "{}",
        assert_clean_failure(tmp.path(), &cross, &["--clip-bbox", "10,10,10.1,10.1"])
    );
}

#[test]
fn absurd_coordinates() {
    let tmp = tempfile::tempdir().unwrap();
    let input = write(
        tmp.path(),
        "absurd.osm",
        br#"<osm version="0.6">
  <node id="1" lat="1000.0" lon="-87.6760"/>
  <node id="2" lat="42.0570" lon="-500.0"/>
  <node id="3" lat="NaN" lon="inf"/>
  <way id="1"><nd ref="1"/><nd ref="2"/><nd ref="3"/><tag k="highway" v="residential"/></way>
</osm>"#,
    );
    println!("{}", assert_clean_failure(tmp.path(), &input, &[]));
}

#[test]
fn a_few_broken_ways_among_good_ones_are_skipped_and_counted() {
    let tmp = tempfile::tempdir().unwrap();
    let text = SMALL_OSM.replace(
        "</osm>",
        r#"  <way id="20"><nd ref="5"/><nd ref="999"/><tag k="highway" v="residential"/></way>
</osm>"#,
    );
    let input = write(tmp.path(), "mostly_good.osm", text.as_bytes());
    let out = tmp.path().join("out");
    let result = run([
        std::ffi::OsString::from("map"),
        "import".into(),
        input.into(),
        "--out".into(),
        out.clone().into(),
    ]);
    assert_success(&result, "import with one broken way");
    let summary = read_json(&out.join("summary.json"));
    assert_eq!(
        summary["skipped"]["ways_missing_nodes"], 1,
        "{}",
        summary["skipped"]
    );
}

#[test]
fn bad_options_and_bad_map_files() {
    let tmp = tempfile::tempdir().unwrap();
    let cross = write(tmp.path(), "cross.osm", SMALL_OSM.as_bytes());
    for (extra, names) in [
        (&["--clip-bbox", "1,2,3"][..], "--clip-bbox"),
        (&["--origin", "95,0"][..], "--origin"),
        (&["--profile", "spaceship"][..], "--profile"),
        (&["--clip-polygon", "nowhere.poly"][..], "nowhere.poly"),
    ] {
        let out = tmp.path().join("out");
        let mut args: Vec<std::ffi::OsString> = vec![
            "map".into(),
            "import".into(),
            cross.clone().into(),
            "--out".into(),
            out.clone().into(),
        ];
        args.extend(extra.iter().map(Into::into));
        let result = run(args);
        let err = stderr(&result);
        assert_eq!(result.status.code(), Some(1), "{extra:?}:\n{err}");
        assert!(
            err.lines()
                .filter(|l| l.starts_with("error:"))
                .all(|l| l.contains(names)),
            "{extra:?}:\n{err}"
        );
        assert!(!out.exists());
    }

    // A folder that is not an earlier import is never replaced.
    let precious = tmp.path().join("thesis");
    std::fs::create_dir(&precious).unwrap();
    std::fs::write(precious.join("thesis.tex"), "precious").unwrap();
    let result = run([
        std::ffi::OsString::from("map"),
        "import".into(),
        cross.clone().into(),
        "--out".into(),
        precious.clone().into(),
    ]);
    assert_eq!(result.status.code(), Some(1), "{}", stderr(&result));
    assert_eq!(entries(&precious), ["thesis.tex"]);

    // map info / route on things that are not maps.
    let garbage = write(
        tmp.path(),
        "garbage.bin",
        b"DRVMAP\x01\x00\x00\x00\xff\xff\xff",
    );
    let other_version = write(tmp.path(), "old_map.json", br#"{"format_version": 999}"#);
    for file in [
        &garbage,
        &other_version,
        &cross,
        &tmp.path().join("absent.json"),
        &tmp.path().to_path_buf(),
    ] {
        let result = run([std::ffi::OsString::from("map"), "info".into(), file.into()]);
        let err = stderr(&result);
        assert_eq!(result.status.code(), Some(1), "{}:\n{err}", file.display());
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        assert_eq!(lines.len(), 1, "{err}");
        assert!(
            lines[0].contains(&*file.file_name().unwrap().to_string_lossy()),
            "{err}"
        );
        assert!(!err.contains("panicked"), "{err}");
    }
    let err = stderr(&run([
        std::ffi::OsString::from("map"),
        "info".into(),
        other_version.into(),
    ]));
    assert!(err.contains("version 999"), "{err}");

    // Usage errors are clap's (exit code 2).
    assert_eq!(
        run(["map", "route", "m", "--from", "1", "--to", "2,3"])
            .status
            .code(),
        Some(1)
    );
    assert_eq!(run(["map", "import"]).status.code(), Some(2));
    assert_eq!(run(["map", "frobnicate"]).status.code(), Some(2));
    assert_eq!(
        run(["--rerun", "web", "map", "info", "x"]).status.code(),
        Some(2)
    );
}

#[test]
fn route_ends_far_from_the_map() {
    let tmp = tempfile::tempdir().unwrap();
    let cross = write(tmp.path(), "cross.osm", SMALL_OSM.as_bytes());
    let out = tmp.path().join("cross");
    let import = run([
        std::ffi::OsString::from("-q"),
        "map".into(),
        "import".into(),
        cross.into(),
        "--out".into(),
        out.clone().into(),
    ]);
    assert_success(&import, "map import");
    let file = tmp.path().join("route.json");
    for (from, to) in [("0,0", "300000,200"), ("-5000,0", "0,0")] {
        let result = run([
            std::ffi::OsString::from("map"),
            "route".into(),
            out.clone().into(),
            "--from".into(),
            from.into(),
            "--to".into(),
            to.into(),
            "--out".into(),
            file.clone().into(),
        ]);
        let err = stderr(&result);
        assert_eq!(result.status.code(), Some(1), "{err}");
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        assert_eq!(lines.len(), 1, "{err}");
        assert!(
            lines[0].contains("from the nearest car lane") && lines[0].contains("map.bin"),
            "{err}"
        );
        assert!(!file.exists());
    }
}

/// `--device cuda | wgpu | libtorch` in a build without that backend: one clear error saying how to
/// rebuild, before any work (no output folder).
#[test]
fn a_backend_this_build_lacks_is_refused_with_the_rebuild_command() {
    let tmp = tempfile::tempdir().unwrap();
    let osm = tmp.path().join("small.osm");
    std::fs::write(&osm, SMALL_OSM).unwrap();
    for (device, built) in [
        ("cuda", cfg!(feature = "cuda")),
        ("wgpu", cfg!(feature = "wgpu")),
        ("libtorch", cfg!(feature = "libtorch")),
    ] {
        if built {
            println!(
                "skipped: {}: this build has {device}",
                std::thread::current().name().unwrap_or("-")
            );
            continue;
        }
        let out = tmp.path().join(device);
        let result = run([
            "--rerun".as_ref(),
            "off".as_ref(),
            "--device".as_ref(),
            device.as_ref(),
            "map".as_ref(),
            "import".as_ref(),
            osm.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        assert_eq!(result.status.code(), Some(1));
        let err = stderr(&result);
        assert!(
            err.starts_with(&format!(
                "error: --device {device}: this build has no {device} support: rebuild with `cargo build --release --features {device}`"
            )),
            "{err}"
        );
        assert!(!out.exists());
    }
}
