//! What the binary prints, whatever the command: a closed stdout (`pipeline ... | head -1`)
//! ends a command quietly with exit code 0; `--device` appears only in the help of the
//! commands that use one; `map info` keeps turn restrictions apart from what was skipped and
//! says `1 lane`, not `1 lanes`. Needs no shared data (the husky log when it is there).

#![allow(clippy::unwrap_used, clippy::print_stdout)]

mod common;

use std::path::Path;
use std::process::Stdio;

use common::{assert_success, pipeline, run, stderr, stdout};

/// Runs `pipeline <args>` with its stdout a pipe whose reading end is closed at once, as
/// `| head -0` would: the command's first write finds nobody reading.
fn with_stdout_closed(args: &[&std::ffi::OsStr]) -> std::process::Output {
    let mut child = pipeline()
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    child.wait_with_output().unwrap()
}

/// Runs it again, reading only its first line (`| head -1`).
fn first_line_only(args: &[&std::ffi::OsStr]) -> (String, std::process::Output) {
    use std::io::BufRead;
    let mut child = pipeline()
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    let mut reader = std::io::BufReader::new(child.stdout.take().unwrap());
    reader.read_line(&mut line).unwrap();
    drop(reader);
    (line, child.wait_with_output().unwrap())
}

fn assert_quiet_end(out: &std::process::Output, what: &str) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(0), "{what}: {err}");
    assert!(!err.contains("panicked"), "{what}: {err}");
    assert!(!err.contains("Broken pipe"), "{what}: {err}");
    assert!(!err.contains("error"), "{what}: {err}");
}

fn import_bundled_map(dir: &Path) -> std::path::PathBuf {
    let map = dir.join("nw");
    let out = run([
        "--rerun".as_ref(),
        "off".as_ref(),
        "map".as_ref(),
        "import".as_ref(),
        common::bundled_osm("northwestern_nu.osm.pbf").as_os_str(),
        "--out".as_ref(),
        map.as_os_str(),
    ]);
    assert_success(&out, "map import");
    map
}

#[test]
fn a_closed_stdout_ends_the_command_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let map = import_bundled_map(dir.path());
    let route = [
        "map".as_ref(),
        "route".as_ref(),
        map.as_os_str(),
        "--from".as_ref(),
        "-300,200".as_ref(),
        "--to".as_ref(),
        "400,-500".as_ref(),
    ];
    assert_quiet_end(&with_stdout_closed(&route), "map route | head -0");
    let (line, out) = first_line_only(&route);
    assert_eq!(line, "{\n");
    assert_quiet_end(&out, "map route | head -1");
    let info = ["map".as_ref(), "info".as_ref(), map.as_os_str()];
    assert_quiet_end(&with_stdout_closed(&info), "map info | head -0");

    if let Some(data) = common::shared_data() {
        let log = data.join("logs/husky/husky.mcap");
        let args = [
            "logs".as_ref(),
            "info".as_ref(),
            log.as_os_str(),
            "--json".as_ref(),
        ];
        assert_quiet_end(&with_stdout_closed(&args), "logs info --json | head -0");
        let (line, out) = first_line_only(&args);
        assert_eq!(line, "{\n");
        assert_quiet_end(&out, "logs info --json | head -1");
    } else {
        println!(
            "skipped: {}: no shared data for logs info",
            std::thread::current().name().unwrap_or("-")
        );
    }
}

#[test]
fn device_is_shown_only_by_the_commands_that_use_one() {
    let help = |args: &[&str]| {
        let out = run(args.iter().chain(&["--help"]));
        assert_success(&out, &args.join(" "));
        stdout(&out)
    };
    for command in [
        &["segmenter", "train"][..],
        &["segmenter", "eval"],
        &["segmenter", "predict"],
        &["segmenter", "bench"],
        &["segmenter", "recalibrate"],
        &["agent", "train"],
        &["run"],
    ] {
        let text = help(command);
        assert_eq!(
            text.matches("--device <DEVICE>").count(),
            1,
            "{command:?}:\n{text}"
        );
    }
    for command in [
        &["map", "import"][..],
        &["map", "info"],
        &["dataset", "generate"],
        &["dataset", "check"],
        &["logs", "info"],
        &["replay", "eval"],
        &["agent", "eval"],
        &[],
    ] {
        let text = help(command);
        assert!(!text.contains("--device"), "{command:?}:\n{text}");
    }
    // Still accepted anywhere (before or after the command), as before.
    let dir = tempfile::tempdir().unwrap();
    let map = import_bundled_map(dir.path());
    for args in [
        &["--device", "cpu", "map", "info"][..],
        &["map", "info", "--device", "cpu"],
    ] {
        let out = run(args.iter().map(|a| a.as_ref()).chain([map.as_os_str()]));
        assert_success(&out, &args.join(" "));
    }
}

#[test]
fn map_info_keeps_restrictions_apart_from_what_was_skipped() {
    let dir = tempfile::tempdir().unwrap();
    let map = import_bundled_map(dir.path());
    let out = run(["map".as_ref(), "info".as_ref(), map.as_os_str()]);
    assert_success(&out, "map info");
    let text = stdout(&out);
    let line = |key: &str| {
        text.lines()
            .find(|l| l.starts_with(key))
            .unwrap_or_else(|| panic!("no {key} line in\n{text}"))
            .to_owned()
    };
    assert!(line("restrictions ").contains("applied"), "{text}");
    let skipped = line("skipped ");
    assert!(!skipped.contains("restriction"), "{skipped}");
    assert!(
        !text.contains(" 1 lanes") && !text.contains(" 1 stop nodes"),
        "{text}"
    );
    assert!(
        skipped.contains("1 stop node not on a selected road"),
        "{skipped}"
    );
}
