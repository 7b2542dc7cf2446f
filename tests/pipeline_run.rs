//! End-to-end test of `pipeline run` (the main job) on the bundled maps with a tiny budget:
//! every stage runs and shows up in report.md; a second run skips every stage; changing one
//! stage's settings reruns that stage and the stages that read its outputs, nothing else;
//! a stage whose output was damaged runs again.

#![allow(clippy::unwrap_used, clippy::print_stdout)]

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use common::{assert_success, pipeline, read_json, stderr};

/// A tiny profile: seconds per stage in a debug build. The agent decides every 3 steps, as
/// the bundled quick profile's does, so the replay stage asks it at every log frame.
fn tiny_config(images: u32) -> String {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let profile = format!(
        r#"
[dataset]
images = {images}
size = "96x64"
augment_copies = 1
[segmenter]
epochs = 1
max_minutes = 1.0
size = 64
width = 0.25
batch_size = 4
eval_images = 4
[agent]
steps = 120
warmup_steps = 60
eval_episodes = 4
[logs]
seconds = 5.0
"#
    );
    let with_prefix = |name: &str| profile.replace("\n[", &format!("\n[run.{name}."));
    format!(
        "[run]\ncampus = \"{}\"\nroundabout = \"{}\"\n{}{}\n[agent.dqn]\nenvs = 2\nbatch_size = 8\nreplay_capacity = 1000\n[agent.task]\naction_repeat = 3\n",
        repo.join("data/osm/northwestern_nu.osm.pbf").display(),
        repo.join("data/osm/montlake_roundabout.osm.pbf").display(),
        with_prefix("quick"),
        with_prefix("full"),
    )
}

/// Runs `pipeline run` and returns what report.md says of each stage this time.
fn run(config: &Path, out: &Path) -> BTreeMap<String, String> {
    let result = pipeline()
        .args(["--config"])
        .arg(config)
        .args(["run", "--out"])
        .arg(out)
        .output()
        .unwrap();
    assert_success(&result, "pipeline run");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let mut stages = BTreeMap::new();
    for line in report.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.len() == 5
            && [
                "maps",
                "dataset",
                "augment",
                "segmenter",
                "agent",
                "logs",
                "replay",
            ]
            .contains(&cells[1])
        {
            stages.insert(cells[1].to_owned(), cells[2].to_owned());
        }
    }
    assert_eq!(stages.len(), 7, "{report}\n{}", stderr(&result));
    stages
}

fn all(status: &str) -> BTreeMap<String, String> {
    [
        "agent",
        "augment",
        "dataset",
        "logs",
        "maps",
        "replay",
        "segmenter",
    ]
    .iter()
    .map(|s| ((*s).to_owned(), status.to_owned()))
    .collect()
}

#[test]
fn runs_every_stage_then_skips_what_did_not_change() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("pipeline.toml");
    let out = dir.path().join("run");
    std::fs::write(&config, tiny_config(12)).unwrap();

    // First run: every stage, with its figures in the report.
    assert_eq!(run(&config, &out), all("ran"));
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for section in [
        "## Maps",
        "## Segmentation data",
        "## Segmenter",
        "## Roundabout-insertion agent",
        "## Logs",
        "## Replay",
    ] {
        assert!(report.contains(section), "no {section} in\n{report}");
    }
    assert!(report.contains("12 images rendered"), "{report}");
    // The pictures the stages drew, linked where they are.
    for picture in [
        "maps/campus/preview.png",
        "segmenter/model/curves.png",
        "segmenter/eval/confusion.png",
    ] {
        assert!(out.join(picture).is_file(), "no {picture}");
        assert!(
            report.contains(&format!("]({picture})")),
            "{picture} not in\n{report}"
        );
    }
    assert!(out.join("recording.rrd").is_file());
    // One recording, every stage under its own entity path (when rerun's CLI is installed).
    if let Some(exe) = common::rerun_cli() {
        let rrd = out.join("recording.rrd");
        let print = common::rerun(
            &exe,
            &[
                "rrd".as_ref(),
                "print".as_ref(),
                "-v".as_ref(),
                rrd.as_os_str(),
            ],
        );
        let text = format!("{}{}", common::stdout(&print), stderr(&print));
        assert!(print.status.success(), "rerun rrd print failed:\n{text}");
        for entity in [
            "maps/campus/world/map/lanes",
            "maps/roundabout/world/map/roundabouts",
            "dataset/generate/image",
            "dataset/augment/image",
            "segmenter/train/loss",
            "agent/",
            "logs/episode_000/layers/obstacles",
            "replay/table",
        ] {
            assert!(
                text.contains(entity),
                "`{entity}` not in the run's recording"
            );
        }
        // Each stage's commands keep their own paths: no stage name twice.
        for repeated in [
            "dataset/dataset/",
            "augment/dataset/",
            "segmenter/segmenter/",
            "agent/agent/",
            "replay/replay/",
        ] {
            assert!(
                !text.contains(repeated),
                "`{repeated}` in the run's recording"
            );
        }
    } else {
        println!(
            "skipped: {}: rerun CLI not installed",
            std::thread::current().name().unwrap_or("-")
        );
    }
    // Every evaluation episode of every policy, one line each, agreeing with eval.json.
    let eval = read_json(&out.join("agent/eval/eval.json"));
    let csv = std::fs::read_to_string(out.join("agent/eval/episodes.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some(
            "policy,traffic,aggressiveness,episode,outcome,steps,return,mean_speed_mps,time_to_enter_s,\
             close_following_steps,cut_in_steps,entry_lag_s"
        )
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let policies = eval["conditions"][0]["policies"].as_array().unwrap();
    let episodes = eval["episodes"].as_u64().unwrap() as usize;
    assert_eq!(rows.len(), policies.len() * episodes);
    for p in policies {
        let name = p["policy"].as_str().unwrap();
        let mine: Vec<&Vec<&str>> = rows.iter().filter(|r| r[0] == name).collect();
        assert_eq!(mine.len(), episodes, "{name}");
        for (key, outcome) in [
            ("reaches", "reached"),
            ("crashes", "crashed"),
            ("time_overs", "time_over"),
        ] {
            let count = mine.iter().filter(|r| r[4] == outcome).count();
            let fraction = p[key].as_f64().unwrap();
            assert!(
                (count as f64 / episodes as f64 - fraction).abs() < 1e-9,
                "{name}: {count} {outcome} against {key} {fraction}"
            );
        }
        let total = |column: usize| -> usize {
            mine.iter()
                .map(|r| r[column].parse::<usize>().unwrap())
                .sum()
        };
        let close_following = p["close_following_share"].as_f64().unwrap();
        assert!(
            (total(9) as f64 / total(5).max(1) as f64 - close_following).abs() < 1e-9,
            "{name}: {} close-following steps of {} against {close_following}",
            total(9),
            total(5)
        );
    }

    // The simulated log reads back exactly and projects to the simulator's own frames.
    let projection = read_json(&out.join("logs/simulated/projection.json"));
    assert!(projection["frames"].as_u64().unwrap() > 0);
    assert_eq!(projection["max_position_error_m"].as_f64(), Some(0.0));
    for (layer, share) in projection["layer_agreement"].as_object().unwrap() {
        assert_eq!(share.as_f64(), Some(1.0), "layer {layer}");
    }

    // Nothing changed: nothing runs.
    assert_eq!(run(&config, &out), all("up to date (skipped)"));

    // More images: the dataset and what reads it run again; maps, agent and logs do not.
    std::fs::write(&config, tiny_config(14)).unwrap();
    let third = run(&config, &out);
    for stage in ["dataset", "augment", "segmenter"] {
        assert_eq!(third[stage], "ran", "{third:?}");
    }
    for stage in ["maps", "agent", "logs", "replay"] {
        assert_eq!(third[stage], "up to date (skipped)", "{third:?}");
    }

    // A damaged output (or one a killed stage left half-written) makes its stage run again.
    std::fs::write(out.join("logs/simulated/projection.json"), "{").unwrap();
    let fourth = run(&config, &out);
    assert_eq!(fourth["logs"], "ran", "{fourth:?}");
    // The logs came out the same, so the replay that reads them is still up to date.
    assert_eq!(fourth["replay"], "up to date (skipped)", "{fourth:?}");
    assert_eq!(fourth["agent"], "up to date (skipped)", "{fourth:?}");
    assert_eq!(
        read_json(&out.join("logs/simulated/projection.json"))["max_position_error_m"].as_f64(),
        Some(0.0)
    );
}

#[test]
fn a_stage_whose_inputs_never_finished_says_what_to_run() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("pipeline.toml");
    std::fs::write(&config, tiny_config(12)).unwrap();
    let result = pipeline()
        .args(["--config"])
        .arg(&config)
        .args(["run", "--only", "dataset", "--out"])
        .arg(dir.path().join("run"))
        .output()
        .unwrap();
    assert!(!result.status.success());
    let err = stderr(&result);
    assert!(err.contains("needs the outputs of stage maps"), "{err}");
    // The hint is this run's command line (its config and run folder) with --to.
    let hint = format!(
        "hint: run it first: pipeline --config {} run --out {} --to maps",
        config.display(),
        dir.path().join("run").display()
    );
    assert!(err.contains(&hint), "{err}");
}
