//! Helpers shared by the end-to-end tests of the `pipeline` binary.
//!
//! Real data lives in `../shared/data` beside the repository; tests that need it print a
//! `skipped:` notice and pass when it is absent (a user's fresh clone). CI has it.

#![allow(
    dead_code,
    clippy::print_stdout,
    clippy::print_stderr,
    clippy::unwrap_used
)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// `../shared/data`, if present.
pub fn shared_data() -> Option<PathBuf> {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"));
    dir.is_dir()
        .then(|| dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf()))
}

/// A file under `../shared/data/osm`, or None with a printed notice.
pub fn osm_file(name: &str) -> Option<PathBuf> {
    let path = shared_data()?.join("osm").join(name);
    if path.is_file() {
        Some(path)
    } else {
        println!(
            "skipped: {}: {} not found (../shared/data is absent)",
            std::thread::current().name().unwrap_or("-"),
            path.display()
        );
        None
    }
}

/// A file of the repository's bundled OpenStreetMap extracts (`data/osm`).
pub fn bundled_osm(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/osm")
        .join(name)
}

/// `pipeline --rerun off --config CONFIG agent train --task TASK [--map MAP] --out OUT
/// --record-episodes 0`.
pub fn agent_train(config: &Path, task: &str, map: Option<&Path>, out: &Path) -> Output {
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "--rerun".as_ref(),
        "off".as_ref(),
        "--config".as_ref(),
        config.as_os_str(),
        "agent".as_ref(),
        "train".as_ref(),
        "--task".as_ref(),
        task.as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
        "--record-episodes".as_ref(),
        "0".as_ref(),
    ];
    if let Some(map) = map {
        args.extend(["--map".as_ref(), map.as_os_str()]);
    }
    run(args)
}

/// The binary under test.
pub fn pipeline() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_pipeline"));
    // No viewer, no stdin, no colours: as in CI.
    cmd.env_remove("RERUN").stdin(std::process::Stdio::null());
    cmd
}

/// `pipeline --rerun off agent eval --agent AGENT --episodes N ARGS... --out OUT`.
pub fn agent_eval(agent: &Path, episodes: usize, args: &[&str], out: &Path) -> Output {
    let episodes = episodes.to_string();
    let mut all: Vec<&std::ffi::OsStr> = vec![
        "--rerun".as_ref(),
        "off".as_ref(),
        "agent".as_ref(),
        "eval".as_ref(),
        "--agent".as_ref(),
        agent.as_os_str(),
        "--episodes".as_ref(),
        episodes.as_ref(),
    ];
    all.extend(args.iter().map(|a| std::ffi::OsStr::new(*a)));
    all.extend(["--out".as_ref(), out.as_os_str()]);
    run(all)
}

/// Runs the binary with `args`.
pub fn run<I, S>(args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    pipeline()
        .args(args)
        .output()
        .expect("the pipeline binary runs")
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

pub fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Fails the test with the command's output when it did not succeed.
pub fn assert_success(out: &Output, what: &str) {
    assert!(
        out.status.success(),
        "{what} failed ({}):\nstdout:\n{}\nstderr:\n{}",
        out.status,
        stdout(out),
        stderr(out)
    );
}

/// Fails the test unless the command failed with `message` in its stderr and `output`
/// (what it was asked to write) does not exist.
pub fn assert_refused(out: &Output, message: &str, output: &Path) {
    assert!(
        !out.status.success(),
        "expected a failure mentioning {message:?}; stdout:\n{}",
        stdout(out)
    );
    assert!(stderr(out).contains(message), "{}", stderr(out));
    assert!(!output.exists(), "{} was written", output.display());
}

/// A small valid OSM XML: a residential cross of four ways meeting at node 5, plus a
/// footway. Enough for an import that needs no shared data.
pub const SMALL_OSM: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6" generator="hand">
  <node id="1" lat="42.0550" lon="-87.6760"/>
  <node id="2" lat="42.0570" lon="-87.6760"/>
  <node id="3" lat="42.0560" lon="-87.6775"/>
  <node id="4" lat="42.0560" lon="-87.6745"/>
  <node id="5" lat="42.0560" lon="-87.6760"/>
  <node id="6" lat="42.0555" lon="-87.6750"/>
  <node id="7" lat="42.0565" lon="-87.6750"/>
  <way id="10"><nd ref="1"/><nd ref="5"/><tag k="highway" v="residential"/><tag k="name" v="South Street"/></way>
  <way id="11"><nd ref="5"/><nd ref="2"/><tag k="highway" v="residential"/><tag k="name" v="North Street"/></way>
  <way id="12"><nd ref="3"/><nd ref="5"/><tag k="highway" v="residential"/></way>
  <way id="13"><nd ref="5"/><nd ref="4"/><tag k="highway" v="tertiary"/><tag k="lanes" v="2"/></way>
  <way id="14"><nd ref="6"/><nd ref="7"/><tag k="highway" v="footway"/></way>
</osm>
"#;

/// Names of the entries of a folder, sorted.
pub fn entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

/// Every file under `dir` (relative path -> bytes).
pub fn files(dir: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut std::collections::BTreeMap<String, Vec<u8>>) {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                let rel = path
                    .strip_prefix(root)
                    .unwrap()
                    .to_string_lossy()
                    .into_owned();
                out.insert(rel, std::fs::read(&path).unwrap());
            }
        }
    }
    let mut out = std::collections::BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// Fails the test unless the folders hold the same files with the same bytes.
pub fn assert_same_files(expected: &Path, got: &Path) {
    let (expected, got) = (files(expected), files(got));
    assert_eq!(
        expected.keys().collect::<Vec<_>>(),
        got.keys().collect::<Vec<_>>()
    );
    for (path, bytes) in &expected {
        assert!(got[path] == *bytes, "{path} differs");
    }
}

/// Reads a JSON file.
pub fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The `rerun` executable on PATH (pip's rerun-sdk), if installed.
pub fn rerun_cli() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|dir| dir.join("rerun"))
        .find(|p| p.is_file())
}

/// Runs the rerun executable with `args`.
pub fn rerun(exe: &Path, args: &[&std::ffi::OsStr]) -> Output {
    Command::new(exe)
        .args(args)
        .stdin(std::process::Stdio::null())
        .output()
        .expect("the rerun executable runs")
}
