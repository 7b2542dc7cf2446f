//! The camera-segmentation view of roundabout driving and route following through the CLI:
//! `agent train` and `agent eval` with `view = "camera-segmentation"` and a
//! segmenter folder, and the one clear error of a bad segmenter folder. A small randomly
//! initialised segmenter stands in for a trained one, and the maps are the bundled ones,
//! so these tests never skip.

#![allow(clippy::unwrap_used)]

mod common;

use std::path::{Path, PathBuf};

use common::{agent_eval, agent_train, assert_success, bundled_osm, read_json, stderr};
use models::segmenter::{PspNetConfig, files};

/// Writes a small random segmenter into `dir`.
fn random_segmenter(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let config = PspNetConfig::new().with_width(0.25).with_psp_channels(32);
    let model = config.init_seeded(&models::cpu_device(), 1).unwrap();
    files::save_model(dir, &model, &config).unwrap();
}

/// A tiny DQN over 64 × 32 camera layers, and the task table `table` with the camera view.
fn write_config(dir: &Path, table: &str, segmenter: &Path) -> PathBuf {
    let path = dir.join(format!("{table}.toml"));
    let text = format!(
        "[agent.dqn]\ntotal_steps = 120\nwarmup_steps = 40\nenvs = 2\nbatch_size = 8\n\
         replay_capacity = 1000\ntrain_frequency = 4\n\
         [agent.dqn.network]\npooling = {{ kind = \"flatten\" }}\nhidden = [16]\n\
         [[agent.dqn.network.convolutions]]\nchannels = 4\nkernel = 4\nstride = 4\npadding = 0\n\
         [agent.{table}]\nview = \"camera-segmentation\"\n{extra}\
         [agent.{table}.camera]\nsegmenter = \"{}\"\nwidth = 128\nheight = 64\npool = 2\n",
        segmenter.display(),
        extra = if table == "route" {
            "pool_size = 12\n"
        } else {
            ""
        },
    );
    std::fs::write(&path, text).unwrap();
    path
}

fn train(config: &Path, task: &str, map: &str, out: &Path) -> std::process::Output {
    agent_train(config, task, Some(&bundled_osm(map)), out)
}

#[test]
fn roundabout_driving_and_route_following_train_and_evaluate_on_the_camera_view() {
    let dir = tempfile::tempdir().unwrap();
    let segmenter = dir.path().join("segmenter");
    random_segmenter(&segmenter);
    for (task, table, map, condition) in [
        (
            "roundabout-driving",
            "roundabout_driving",
            "montlake_roundabout.osm.pbf",
            "traffic medium",
        ),
        (
            "route-following",
            "route",
            "northwestern_nu.osm.pbf",
            "held-out routes",
        ),
    ] {
        let config = write_config(dir.path(), table, &segmenter);
        let agent = dir.path().join(task);
        let out = train(&config, task, map, &agent);
        assert_success(
            &out,
            &format!("agent train --task {task} on the camera view"),
        );
        let record = read_json(&agent.join("task.json"));
        assert_eq!(record["config"]["view"], "camera-segmentation");
        let stored = record["config"]["camera"]["segmenter"].as_str().unwrap();
        assert!(Path::new(stored).is_absolute(), "{stored}");
        // The network sees 3 classes × 2 frames of 64 × 32.
        let description = read_json(&agent.join("agent.json"));
        let text = description.to_string();
        assert!(text.contains("\"channels\":6"), "{text}");

        let eval = dir.path().join(format!("{task}_eval"));
        let mut args = vec!["--no-baselines"];
        if task == "roundabout-driving" {
            args.extend(["--traffic", "medium"]);
        }
        let out = agent_eval(&agent, 2, &args, &eval);
        assert_success(&out, &format!("agent eval of a {task} camera agent"));
        let report = read_json(&eval.join("eval.json"));
        let first = &report["conditions"][0];
        assert_eq!(first["condition"], condition);
        assert_eq!(first["policies"][0]["policy"], "agent");
        assert_eq!(first["policies"][0]["episodes"], 2);
    }
}

#[test]
fn a_bad_segmenter_folder_is_one_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no_such_segmenter");
    let config = write_config(dir.path(), "roundabout_driving", &missing);
    let agent = dir.path().join("agent");
    let out = train(
        &config,
        "roundabout-driving",
        "montlake_roundabout.osm.pbf",
        &agent,
    );
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("no_such_segmenter") && err.contains("model.json"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    assert!(!agent.exists());

    // A folder whose record is not a burn record: the error names model.bpk.
    let broken = dir.path().join("broken");
    random_segmenter(&broken);
    std::fs::write(broken.join("model.bpk"), b"garbage").unwrap();
    let config = write_config(dir.path(), "route", &broken);
    let out = train(
        &config,
        "route-following",
        "northwestern_nu.osm.pbf",
        &agent,
    );
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(err.contains("model.bpk"), "{err}");
}
