//! `pipeline sim calibrate`, `sim realism` and `replay gaps` on real INTERACTION recordings
//! of FT, and the inputs they refuse.

#![allow(clippy::print_stdout, clippy::unwrap_used)]

mod common;

use std::io::Write;
use std::path::{Path, PathBuf};

use common::{SMALL_OSM, assert_refused, assert_success, pipeline, read_json, shared_data, stderr};

/// The INTERACTION folder (None, with a notice, without ../shared/data).
fn interaction() -> Option<PathBuf> {
    let Some(data) = shared_data() else {
        println!(
            "skipped: {}: ../shared/data is absent",
            std::thread::current().name().unwrap_or("-")
        );
        return None;
    };
    Some(data.join("trajectories/interaction"))
}

/// Converts track file `tracks` with `map` into `out`.
fn convert(tracks: &Path, map: &Path, out: &Path) {
    let done = pipeline()
        .args(["--rerun", "off", "logs", "convert"])
        .arg(tracks)
        .arg("--map")
        .arg(map)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert_success(&done, "logs convert");
}

fn ft_tracks(base: &Path, n: u32) -> PathBuf {
    base.join(format!(
        "recorded_trackfiles/DR_USA_Roundabout_FT/vehicle_tracks_{n:03}.csv.gz"
    ))
}

/// FT recordings 000 to `n` − 1 converted into `dir`.
fn ft_logs(base: &Path, map: &Path, dir: &Path, n: u32) -> Vec<PathBuf> {
    (0..n)
        .map(|k| {
            let log = dir.join(format!("ft_{k:03}.mcap"));
            convert(&ft_tracks(base, k), map, &log);
            log
        })
        .collect()
}

#[test]
fn calibration_feeds_the_realism_report() {
    let Some(base) = interaction() else { return };
    let map = base.join("maps/DR_USA_Roundabout_FT.osm");
    let tmp = tempfile::tempdir().unwrap();
    let logs = ft_logs(&base, &map, tmp.path(), 3);
    let calib = tmp.path().join("calib.toml");
    let out = pipeline()
        .args(["--rerun", "off", "sim", "calibrate", "--no-refine", "--map"])
        .arg(&map)
        .args(["--log"])
        .arg(&logs[0])
        .args(["--log"])
        .arg(&logs[1])
        .arg("--out")
        .arg(&calib)
        .output()
        .unwrap();
    assert_success(&out, "sim calibrate");
    let fits = read_json(&tmp.path().join("calib.json"));
    let median = fits["critical_gap"]["median_s"].as_f64().unwrap();
    let (lo, hi) = (
        fits["critical_gap"]["median_ci95_s"][0].as_f64().unwrap(),
        fits["critical_gap"]["median_ci95_s"][1].as_f64().unwrap(),
    );
    assert!(
        (2.0..10.0).contains(&median) && lo <= median && median <= hi,
        "{fits}"
    );
    assert!(
        fits["critical_gap"]["drivers"].as_u64().unwrap() >= 30,
        "{fits}"
    );
    assert_eq!(
        fits["flows"].as_array().unwrap().len(),
        7,
        "FT has seven entries"
    );
    // The calibration is a --config file; realism on a third recording.
    let realism = |out: &Path| {
        pipeline()
            .args(["--rerun", "off", "--config"])
            .arg(&calib)
            .args(["sim", "realism", "--map"])
            .arg(&map)
            .arg("--log")
            .arg(&logs[2])
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    let report = tmp.path().join("realism");
    assert_success(&realism(&report), "sim realism");
    let json = read_json(&report.join("realism.json"));
    let metrics = json["metrics"].as_object().unwrap();
    assert_eq!(metrics.len(), 8, "{json}");
    for (name, m) in metrics {
        let ks = m["ks"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&ks), "{name}: {m}");
        assert!(m["real"]["n"].as_u64().unwrap() > 0, "{name}: {m}");
        assert!(m["sim"]["n"].as_u64().unwrap() > 0, "{name}: {m}");
        assert!(report.join(format!("{name}.png")).is_file(), "{name}.png");
    }
    let md = std::fs::read_to_string(report.join("realism.md")).unwrap();
    assert!(md.contains("| accepted_gap"), "{md}");
    // Same seed and inputs, same report.
    let again = tmp.path().join("realism_again");
    assert_success(&realism(&again), "sim realism again");
    assert_eq!(
        std::fs::read(report.join("realism.json")).unwrap(),
        std::fs::read(again.join("realism.json")).unwrap()
    );
}

#[test]
fn calibration_refuses_what_it_cannot_fit() {
    let Some(base) = interaction() else { return };
    let ft = base.join("maps/DR_USA_Roundabout_FT.osm");
    let ep = base.join("maps/DR_USA_Roundabout_EP.osm");
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("ft_000.mcap");
    convert(&ft_tracks(&base, 0), &ft, &log);
    let calibrate = |map: &Path, log: &Path, out: &Path| {
        pipeline()
            .args(["--rerun", "off", "sim", "calibrate", "--no-refine", "--map"])
            .arg(map)
            .arg("--log")
            .arg(log)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    // A recording of another roundabout.
    let out_path = tmp.path().join("on_ep.toml");
    let out = calibrate(&ep, &log, &out_path);
    assert_refused(&out, "do not drive on the map", &out_path);
    assert!(stderr(&out).contains("ft_000.mcap"), "{}", stderr(&out));
    // A map without a roundabout.
    let small = tmp.path().join("cross.osm");
    std::fs::write(&small, SMALL_OSM).unwrap();
    let out_path = tmp.path().join("cross.toml");
    let out = calibrate(&small, &log, &out_path);
    assert_refused(&out, "cross.osm: has no roundabout", &out_path);
    // Too few gaps: the first 40 seconds of a recording.
    let text = {
        let mut gz =
            flate2::read::GzDecoder::new(std::fs::File::open(ft_tracks(&base, 0)).unwrap());
        let mut s = String::new();
        std::io::Read::read_to_string(&mut gz, &mut s).unwrap();
        s
    };
    let short = tmp.path().join("vehicle_tracks_short.csv");
    let mut f = std::fs::File::create(&short).unwrap();
    for (k, line) in text.lines().enumerate() {
        let keep = k == 0
            || line
                .split(',')
                .nth(2)
                .and_then(|t| t.parse::<u64>().ok())
                .is_some_and(|ms| ms <= 40_000);
        if keep {
            writeln!(f, "{line}").unwrap();
        }
    }
    drop(f);
    let short_log = tmp.path().join("short.mcap");
    convert(&short, &ft, &short_log);
    let out_path = tmp.path().join("short.toml");
    let out = calibrate(&ft, &short_log, &out_path);
    assert_refused(
        &out,
        "entering drivers with a measured gap (at least 30 needed)",
        &out_path,
    );

    // The committed calibration's recorded flows belong to FT: another map is refused.
    let calibration =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/traffic_interaction_ft.toml");
    let montlake =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/osm/montlake_roundabout.osm.pbf");
    let agent = tmp.path().join("agent");
    let out = pipeline()
        .args(["--rerun", "off", "--config"])
        .arg(&calibration)
        .args(["agent", "train", "--traffic", "recorded", "--map"])
        .arg(&montlake)
        .arg("--out")
        .arg(&agent)
        .output()
        .unwrap();
    assert_refused(
        &out,
        "the recorded flows of --config do not fit this map",
        &agent,
    );
}

#[test]
fn replay_gaps_scores_the_policies_on_held_out_gaps() {
    let Some(base) = interaction() else { return };
    let map = base.join("maps/DR_USA_Roundabout_FT.osm");
    let tmp = tempfile::tempdir().unwrap();
    let logs = ft_logs(&base, &map, tmp.path(), 3);
    let out_dir = tmp.path().join("gaps");
    let run = |out: &Path, train: &[&PathBuf]| {
        let mut cmd = pipeline();
        cmd.args(["--rerun", "off", "replay", "gaps", "--map"])
            .arg(&map)
            .arg("--log")
            .arg(&logs[2])
            .arg("--out")
            .arg(out);
        for t in train {
            cmd.arg("--train-log").arg(t);
        }
        cmd.output().unwrap()
    };
    let done = run(&out_dir, &[&logs[0], &logs[1]]);
    assert_success(&done, "replay gaps");
    let report = read_json(&out_dir.join("gaps.json"));
    let offered = report["offered"].as_u64().unwrap();
    let accepted = report["accepted"].as_u64().unwrap();
    // Every approach offered a gap is offered at least the gap it accepted.
    assert!(
        offered >= report["approaches_offered_a_gap"].as_u64().unwrap()
            && accepted <= offered
            && accepted > 0,
        "{report}"
    );
    let critical = report["critical_gap_s"].as_f64().unwrap();
    assert!((1.0..10.0).contains(&critical), "{report}");
    let policies = report["policies"].as_array().unwrap();
    let names: Vec<&str> = policies
        .iter()
        .map(|p| p["policy"].as_str().unwrap())
        .collect();
    assert_eq!(names[0], "critical gap (maximum likelihood)", "{names:?}");
    assert!(names.contains(&"behaviour cloning") && names.contains(&"always accept"));
    for p in policies {
        let (acc, lo, hi) = (
            p["accuracy"].as_f64().unwrap(),
            p["ci95"][0].as_f64().unwrap(),
            p["ci95"][1].as_f64().unwrap(),
        );
        assert!(lo <= acc && acc <= hi && (0.0..=1.0).contains(&acc), "{p}");
        let c = &p["confusion"];
        let total: u64 = [
            "accepted_accepted",
            "accepted_rejected",
            "rejected_accepted",
            "rejected_rejected",
        ]
        .iter()
        .map(|k| c[k].as_u64().unwrap())
        .sum();
        assert_eq!(total, offered, "{p}");
    }
    // Always accept is right exactly on the accepted gaps.
    let always = policies
        .iter()
        .find(|p| p["policy"] == "always accept")
        .unwrap();
    let share = accepted as f64 / offered as f64;
    assert!((always["accuracy"].as_f64().unwrap() - share).abs() < 1e-9);
    let csv = std::fs::read_to_string(out_dir.join("gaps.csv")).unwrap();
    assert_eq!(csv.lines().count() as u64, offered + 1);
    assert!(out_dir.join("gaps.md").is_file());

    // The same seed and inputs give the same report.
    let again = tmp.path().join("again");
    assert_success(&run(&again, &[&logs[0], &logs[1]]), "replay gaps again");
    assert_eq!(
        std::fs::read(out_dir.join("gaps.json")).unwrap(),
        std::fs::read(again.join("gaps.json")).unwrap()
    );

    // A recording both scored and fitted on is refused, naming it.
    let refused = tmp.path().join("refused");
    let done = run(&refused, &[&logs[0], &logs[2]]);
    assert_refused(
        &done,
        "is given both to score (--log) and to fit on (--train-log)",
        &refused,
    );
    assert!(stderr(&done).contains("ft_002.mcap"), "{}", stderr(&done));

    // A training map without training recordings is refused.
    let done = pipeline()
        .args(["--rerun", "off", "replay", "gaps", "--map"])
        .arg(&map)
        .arg("--train-map")
        .arg(&map)
        .arg("--log")
        .arg(&logs[2])
        .arg("--out")
        .arg(&refused)
        .output()
        .unwrap();
    assert_refused(
        &done,
        "--train-map names the map of --train-log recordings",
        &refused,
    );
}
