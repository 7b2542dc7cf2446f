//! Scale-out: the data-parallel stages run as shards that merge into the
//! unsharded run's output byte for byte (docs/scaling.md's local examples):
//! - `dataset augment --shard i/n` + `dataset merge --shards` (bundled map, no shared data);
//! - `logs project --shard i/n` + `logs merge --shards` and `replay eval --shard i/n` +
//!   `replay merge --shards` on a real INTERACTION recording (skip without ../shared/data).
//!
//! Shards run with 1 thread and the unsharded runs with 2, so the comparison also covers
//! the thread count. `--rerun off`: a recording's bytes are never reproducible.

#![allow(clippy::unwrap_used, clippy::print_stdout)]

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::{assert_same_files, assert_success, pipeline, read_json, shared_data, stderr};

/// Runs `pipeline --rerun off --seed 5 <args>` with `threads` rayon threads.
fn run(threads: &str, args: &[&str], paths: &[(&str, &Path)]) -> Output {
    let mut cmd = pipeline();
    cmd.env("RAYON_NUM_THREADS", threads)
        .args(["--rerun", "off", "--seed", "5"])
        .args(args);
    for (flag, path) in paths {
        if !flag.is_empty() {
            cmd.arg(flag);
        }
        cmd.arg(path);
    }
    cmd.output().unwrap()
}

/// `<flag> dir...` for the shard folders.
fn merge(args: &[&str], shards: &[PathBuf], out: &Path) -> Output {
    pipeline()
        .args(["--rerun", "off"])
        .args(args)
        .args(shards)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn augment_shards_merge_into_the_unsharded_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let map = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/osm/northwestern_nu.osm.pbf");
    let input = tmp.path().join("input");
    let out = run(
        "2",
        &["dataset", "generate", "--count", "5", "--size", "96x64"],
        &[("--map", &map), ("--out", &input)],
    );
    assert_success(&out, "dataset generate");
    let augment = ["dataset", "augment", "--copies", "2", "--preset", "full"];

    let whole = tmp.path().join("whole").join("aug");
    let out = run("2", &augment, &[("", &input), ("--out", &whole)]);
    assert_success(&out, "unsharded augment");
    // Three shards of five items: 1, 2 and 2 items.
    let mut shards = Vec::new();
    for shard in ["2/3", "0/3", "1/3"] {
        let dir = tmp.path().join(format!("shard{}", &shard[..1]));
        let mut args = augment.to_vec();
        args.extend(["--shard", shard]);
        assert_success(&run("1", &args, &[("", &input), ("--out", &dir)]), shard);
        shards.push(dir);
    }
    assert_eq!(
        read_json(&tmp.path().join("shard0/card.json"))["config"]["shard"],
        serde_json::json!({"index": 0, "count": 3})
    );
    assert_eq!(
        std::fs::read_to_string(tmp.path().join("shard0/manifest.jsonl"))
            .unwrap()
            .lines()
            .count(),
        2
    );
    let merged = tmp.path().join("merged").join("aug");
    assert_success(
        &merge(&["dataset", "merge", "--shards"], &shards, &merged),
        "dataset merge --shards",
    );
    assert_same_files(&whole, &merged);

    // Two of the three shards: refused, nothing written.
    let bad = tmp.path().join("bad");
    let out = merge(&["dataset", "merge", "--shards"], &shards[..2], &bad);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("exactly once"), "{}", stderr(&out));
    assert!(!bad.exists());
}

/// The FT map and recording 000 converted to MCAP (None without ../shared/data).
fn ft_recording(dir: &Path) -> Option<(PathBuf, PathBuf)> {
    let Some(data) = shared_data() else {
        println!(
            "skipped: {}: ../shared/data is absent",
            std::thread::current().name().unwrap_or("-")
        );
        return None;
    };
    let base = data.join("trajectories/interaction");
    let map = base.join("maps/DR_USA_Roundabout_FT.osm");
    let tracks = base.join("recorded_trackfiles/DR_USA_Roundabout_FT/vehicle_tracks_000.csv.gz");
    let log = dir.join("ft_000.mcap");
    let out = run(
        "2",
        &["logs", "convert"],
        &[("", &tracks), ("--map", &map), ("--out", &log)],
    );
    assert_success(&out, "logs convert");
    Some((map, log))
}

#[test]
fn log_projection_shards_merge_into_the_unsharded_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((map, log)) = ft_recording(tmp.path()) else {
        return;
    };
    // Track 60 of FT 000 (547 frames), with perception noise so the per-frame draws count.
    let project = [
        "logs",
        "project",
        "--ego",
        "60",
        "--previews",
        "3",
        "--position-noise",
        "0.3",
        "--path-noise",
        "1.0",
    ];
    let call = |threads: &str, args: &[&str], out: &Path| {
        run(
            threads,
            args,
            &[
                ("", log.as_path()),
                ("--map", map.as_path()),
                ("--out", out),
            ],
        )
    };
    let whole = tmp.path().join("whole");
    assert_success(&call("2", &project, &whole), "unsharded logs project");
    let mut shards = Vec::new();
    for shard in ["1/2", "0/2"] {
        let dir = tmp.path().join(format!("shard{}", &shard[..1]));
        let mut args = project.to_vec();
        args.extend(["--shard", shard]);
        assert_success(&call("1", &args, &dir), shard);
        shards.push(dir);
    }
    let card = read_json(&tmp.path().join("shard0/frames.json"));
    assert_eq!(card["frames"], 273, "{card}");
    assert!(!tmp.path().join("shard0/previews").exists());
    let merged = tmp.path().join("merged");
    assert_success(
        &merge(&["logs", "merge", "--shards"], &shards, &merged),
        "logs merge --shards",
    );
    assert_same_files(&whole, &merged);
    assert_eq!(read_json(&merged.join("frames.json"))["frames"], 547);

    // One shard twice: refused. A shard made with other noise: refused, naming its file.
    let bad = tmp.path().join("bad");
    let out = merge(
        &["logs", "merge", "--shards"],
        &[shards[0].clone(), shards[0].clone()],
        &bad,
    );
    assert!(!out.status.success());
    assert!(stderr(&out).contains("exactly once"), "{}", stderr(&out));
    let other = tmp.path().join("other");
    let mut args = project.to_vec();
    args[7] = "0.5";
    args.extend(["--shard", "0/2"]);
    assert_success(&call("1", &args, &other), "other noise");
    let out = merge(
        &["logs", "merge", "--shards"],
        &[other.clone(), shards[0].clone()],
        &bad,
    );
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("frames.json") && err.contains("other settings"),
        "{err}"
    );
    // A truncated layers file: refused, naming it.
    let layers = shards[1].join("layers.bin");
    let bytes = std::fs::read(&layers).unwrap();
    std::fs::write(&layers, &bytes[..bytes.len() - 1]).unwrap();
    let out = merge(&["logs", "merge", "--shards"], &shards, &bad);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("layers.bin"), "{}", stderr(&out));
    assert!(!bad.exists());
}

#[test]
fn replay_shards_add_up_to_the_unsharded_report() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((map, log)) = ft_recording(tmp.path()) else {
        return;
    };
    let eval = |threads: &str, extra: &[&str], out: &Path| {
        let mut args = vec!["replay", "eval"];
        args.extend(extra);
        run(
            threads,
            &args,
            &[
                ("--log", log.as_path()),
                ("--map", map.as_path()),
                ("--out", out),
            ],
        )
    };
    let whole = tmp.path().join("whole");
    assert_success(&eval("2", &[], &whole), "unsharded replay eval");
    let mut shards = Vec::new();
    for shard in ["0/3", "2/3", "1/3"] {
        let dir = tmp.path().join(format!("shard{}", &shard[..1]));
        assert_success(&eval("1", &["--shard", shard], &dir), shard);
        shards.push(dir);
    }
    // A shard holds counts, not rates: a third of the approaches each.
    let total = read_json(&whole.join("replay.json"))["approaches"]
        .as_u64()
        .unwrap();
    let part = read_json(&tmp.path().join("shard1/replay_shard.json"));
    assert_eq!(
        part["counts"]["approaches"],
        total / 3 + u64::from(total % 3 == 2)
    );
    assert!(
        part["counts"]["policies"][0]["confusion"].is_object(),
        "{part}"
    );
    let merged = tmp.path().join("merged");
    assert_success(
        &merge(&["replay", "merge", "--shards"], &shards, &merged),
        "replay merge --shards",
    );
    assert_same_files(&whole, &merged);

    // With behaviour cloning (trained in each shard, the same network whatever the thread
    // count) and closed loop: the same report too. FT 000 both teaches and is evaluated: a
    // check of the sums, not a figure.
    let bc = [
        "--train-log",
        log.to_str().unwrap(),
        "--bc-stride",
        "8",
        "--closed-loop",
    ];
    let whole_bc = tmp.path().join("whole_bc");
    assert_success(&eval("2", &bc, &whole_bc), "unsharded replay eval with BC");
    let mut bc_shards = Vec::new();
    for shard in ["1/2", "0/2"] {
        let dir = tmp.path().join(format!("bc_shard{}", &shard[..1]));
        let mut args = bc.to_vec();
        args.extend(["--shard", shard]);
        assert_success(&eval("1", &args, &dir), shard);
        bc_shards.push(dir);
    }
    let merged_bc = tmp.path().join("merged_bc");
    assert_success(
        &merge(&["replay", "merge", "--shards"], &bc_shards, &merged_bc),
        "replay merge --shards with BC",
    );
    assert_same_files(&whole_bc, &merged_bc);
    // Closed loop: every policy drove every approach, each episode ended one way.
    let report = read_json(&whole_bc.join("replay.json"));
    let loops = report["closed_loop"].as_array().unwrap();
    assert_eq!(loops.len(), report["policies"].as_array().unwrap().len());
    for l in loops {
        assert_eq!(l["episodes"], report["approaches"], "{l}");
        let shares: f64 = ["reached", "crashed", "rear_ended", "time_over"]
            .iter()
            .map(|k| l[*k].as_f64().unwrap())
            .sum();
        assert!((shares - 1.0).abs() < 1e-9, "{l}");
        assert!(l["mean_log_divergence_m"].as_f64().unwrap() >= 0.0, "{l}");
    }
    assert!(
        std::fs::read_to_string(merged_bc.join("replay.md"))
            .unwrap()
            .contains("## Closed loop")
    );
    assert!(
        std::fs::read_to_string(merged_bc.join("replay.md"))
            .unwrap()
            .contains("| behaviour cloning |")
    );
    // Shards of two runs (with and without behaviour cloning): refused, naming the file.
    let plain = tmp.path().join("plain_shard1");
    assert_success(&eval("1", &["--shard", "1/2"], &plain), "1/2 without BC");
    let bad = tmp.path().join("bad");
    let out = merge(
        &["replay", "merge", "--shards"],
        &[bc_shards[1].clone(), plain],
        &bad,
    );
    assert!(!out.status.success());
    assert!(stderr(&out).contains("other settings"), "{}", stderr(&out));

    // Not a shard folder: one error naming the file, nothing written.
    let out = merge(
        &["replay", "merge", "--shards"],
        std::slice::from_ref(&whole),
        &bad,
    );
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("replay_shard.json"),
        "{}",
        stderr(&out)
    );
    assert!(!bad.exists());
}
