//! `agent train` and `agent eval` on the tasks other than roundabout insertion, with tiny
//! budgets: the generic evaluation writes the agent and every baseline per condition, and
//! the task's metrics. Runs on the bundled campus, so it never skips.

#![allow(clippy::unwrap_used)]

mod common;

use std::path::{Path, PathBuf};

use common::{agent_eval, agent_train, assert_success, bundled_osm, read_json, run, stderr};

#[test]
fn route_following_trains_and_evaluates_with_its_baselines() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("route.toml");
    std::fs::write(
        &config,
        "[agent.dqn]\ntotal_steps = 600\nwarmup_steps = 100\nenvs = 2\nbatch_size = 8\n\
         replay_capacity = 1000\n[agent.dqn.network]\nconvolutions = []\nhidden = [16]\n\
         [agent.route]\npool_size = 16\n",
    )
    .unwrap();
    let map = bundled_osm("northwestern_nu.osm.pbf");
    let agent = dir.path().join("agent");
    let out = agent_train(&config, "route-following", Some(&map), &agent);
    assert_success(&out, "agent train --task route-following");
    let task = read_json(&agent.join("task.json"));
    assert_eq!(task["task"], "route-following");
    assert_eq!(task["config"]["pool_size"], 16);

    let eval = dir.path().join("eval");
    let out = agent_eval(&agent, 3, &[], &eval);
    assert_success(&out, "agent eval of a route-following agent");
    let report = read_json(&eval.join("eval.json"));
    let conditions = report["conditions"].as_array().unwrap();
    assert_eq!(conditions.len(), 2, "held-out and training routes");
    assert_eq!(conditions[0]["condition"], "held-out routes");
    for condition in conditions {
        let policies = condition["policies"].as_array().unwrap();
        let names: Vec<&str> = policies
            .iter()
            .map(|p| p["policy"].as_str().unwrap())
            .collect();
        assert_eq!(
            names,
            [
                "agent",
                "always forward",
                "always forward left",
                "always forward right",
                "rule: pure pursuit"
            ]
        );
        for p in policies {
            assert_eq!(p["episodes"], 3);
            let fractions: f64 = ["reaches", "crashes", "off_roads", "time_overs"]
                .iter()
                .map(|k| p[k].as_f64().unwrap())
                .sum();
            assert!((fractions - 1.0).abs() < 1e-9, "{p}");
            let metrics = p["metrics"].as_array().unwrap();
            assert_eq!(metrics[0][0], "route completion %");
        }
    }
    // Every rate with its Wilson interval; the agent paired with each baseline.
    for condition in conditions {
        for p in condition["policies"].as_array().unwrap() {
            let (lo, hi) = (
                p["reaches_ci95"][0].as_f64().unwrap(),
                p["reaches_ci95"][1].as_f64().unwrap(),
            );
            let r = p["reaches"].as_f64().unwrap();
            assert!(lo <= r && r <= hi && hi > lo, "{p}");
        }
        let paired = condition["paired"].as_array().unwrap();
        assert_eq!(paired.len(), 4, "{condition}");
        for t in paired {
            let p = t["reaches"]["p_value"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&p), "{t}");
        }
    }
    let table = std::fs::read_to_string(eval.join("eval.md")).unwrap();
    assert!(table.contains("| rule: pure pursuit | 3 |"), "{table}");
    assert!(table.contains("exact McNemar"), "{table}");

    // --roundabout is for roundabout tasks: one clear error, nothing written.
    let elsewhere = dir.path().join("eval-ring");
    let out = agent_eval(&agent, 1, &["--roundabout", "0"], &elsewhere);
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("--roundabout is for roundabout tasks"),
        "{}",
        stderr(&out)
    );
    assert!(!elsewhere.exists());
}

#[test]
fn a_map_task_without_a_map_is_one_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = run([
        "--rerun".as_ref(),
        "off".as_ref(),
        "agent".as_ref(),
        "train".as_ref(),
        "--task".as_ref(),
        "route-following".as_ref(),
        "--out".as_ref(),
        dir.path().join("agent").as_os_str(),
    ]);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("--map is required for the route-following task"),
        "{err}"
    );
    assert!(!dir.path().join("agent").exists());
}

/// Trains an obstacle-avoidance agent with `config` (a TOML text) into `dir/<name>`.
fn train_obstacle(dir: &Path, name: &str, config: &str) -> (PathBuf, std::process::Output) {
    let file = dir.join(format!("{name}.toml"));
    std::fs::write(&file, config).unwrap();
    let agent = dir.join(name);
    let out = agent_train(&file, "obstacle-avoidance", None, &agent);
    (agent, out)
}

const SMALL_OBSTACLE_RUN: &str = "[agent.dqn]\ntotal_steps = 3000\ncheckpoint_every = 1000\n\
    warmup_steps = 200\nenvs = 2\nbatch_size = 8\nreplay_capacity = 3000\n\
    [agent.dqn.network]\nconvolutions = []\nhidden = [16]\n";

#[test]
fn validation_chooses_the_best_checkpoint_without_changing_training() {
    let dir = tempfile::tempdir().unwrap();
    let (validated, out) = train_obstacle(
        dir.path(),
        "validated",
        &format!("{SMALL_OBSTACLE_RUN}[agent.validation]\nepisodes = 6\n"),
    );
    assert_success(&out, "agent train with [agent.validation]");
    // Off a terminal, each validation says what it is doing and counts its episodes (6 per
    // scenario, two scenarios), then training goes on: no silent stretch.
    let err = common::stderr(&out);
    for step in [1000, 2000] {
        assert!(
            err.contains(&format!(
                "agent train: validating the checkpoint at step {step}: 12 episodes"
            )),
            "{err}"
        );
    }
    assert!(
        err.contains("agent train: validating the final network: 12 episodes"),
        "{err}"
    );
    assert!(
        err.contains("agent train: validating the final network: 12/12 episodes"),
        "{err}"
    );
    let (plain, out) = train_obstacle(dir.path(), "plain", SMALL_OBSTACLE_RUN);
    assert_success(&out, "agent train without validation");
    assert!(!dir.path().join("validated.partial").exists());

    // Every checkpoint and the final network validated, on both scenarios.
    let history = read_json(&validated.join("validation.json"));
    let points = history["points"].as_array().unwrap();
    let steps: Vec<u64> = points
        .iter()
        .map(|p| p["steps"].as_u64().unwrap())
        .collect();
    assert_eq!(steps, [1000, 2000, 3000]);
    for point in points {
        let reached = point["reached"].as_array().unwrap();
        assert_eq!(reached[0][0], "static obstacle");
        assert_eq!(reached[1][0], "crossing obstacle");
        let mean = (reached[0][1].as_f64().unwrap() + reached[1][1].as_f64().unwrap()) / 2.0;
        assert!((point["score"].as_f64().unwrap() - mean).abs() < 1e-12);
    }
    // The chosen one: the first with the highest score.
    let scores: Vec<f64> = points
        .iter()
        .map(|p| p["score"].as_f64().unwrap())
        .collect();
    let best = scores
        .iter()
        .enumerate()
        .fold(0, |best, (i, &s)| if s > scores[best] { i } else { best });
    assert_eq!(history["best_steps"].as_u64(), Some(steps[best]));
    let summary = read_json(&validated.join("summary.json"));
    assert_eq!(summary["chosen_steps"].as_u64(), Some(steps[best]));
    let agent = read_json(&validated.join("agent.json"));
    assert_eq!(agent["steps"].as_u64(), Some(steps[best]));
    assert_eq!(
        read_json(&validated.join("task.json"))["validation"]["episodes"],
        6
    );

    // Validation does not change the run: the same transitions, updates and episodes.
    let plain_summary = read_json(&plain.join("summary.json"));
    for key in [
        "steps", "updates", "episodes", "reached", "crashed", "off_road",
    ] {
        assert_eq!(summary[key], plain_summary[key], "{key}");
    }
    assert!(plain_summary.get("chosen_steps").is_none());
    assert!(!plain.join("validation.json").exists());
    if steps[best] == 3000 {
        assert_eq!(
            std::fs::read(validated.join("online.bpk")).unwrap(),
            std::fs::read(plain.join("online.bpk")).unwrap()
        );
    }
}

#[test]
fn validation_without_checkpoints_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let config = SMALL_OBSTACLE_RUN.replace("checkpoint_every = 1000", "checkpoint_every = 0")
        + "[agent.validation]\nepisodes = 6\n";
    let (agent, out) = train_obstacle(dir.path(), "agent", &config);
    common::assert_refused(&out, "checkpoint_every of [agent.dqn] is 0", &agent);
}

#[test]
fn validation_deciding_at_another_rate_is_for_insertion_only() {
    let dir = tempfile::tempdir().unwrap();
    let config =
        format!("{SMALL_OBSTACLE_RUN}[agent.validation]\nepisodes = 6\naction_repeat = 1\n");
    let (agent, out) = train_obstacle(dir.path(), "agent", &config);
    common::assert_refused(
        &out,
        "[agent.validation] action_repeat is for roundabout-insertion agents",
        &agent,
    );
}

/// `--steps` within the warm-up would take no gradient step, and validation would then
/// choose a "best" among untrained networks: refused before anything is written, the hint
/// naming both settings.
#[test]
fn steps_within_the_warm_up_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let config = SMALL_OBSTACLE_RUN.replace("warmup_steps = 200", "warmup_steps = 5000")
        + "[agent.validation]\nepisodes = 6\n";
    let file = dir.path().join("agent.toml");
    std::fs::write(&file, config).unwrap();
    let agent = dir.path().join("agent");
    let out = run([
        "--rerun".as_ref(),
        "off".as_ref(),
        "--config".as_ref(),
        file.as_os_str(),
        "agent".as_ref(),
        "train".as_ref(),
        "--task".as_ref(),
        "obstacle-avoidance".as_ref(),
        "--steps".as_ref(),
        "2000".as_ref(),
        "--out".as_ref(),
        agent.as_os_str(),
    ]);
    common::assert_refused(&out, "the run's 2000 transitions are all warm-up", &agent);
    let err = stderr(&out);
    assert!(
        err.contains("warmup_steps = 5000") && err.contains("more than 5000 transitions"),
        "{err}"
    );
    assert!(
        err.contains("--steps") && err.contains("[agent.dqn]"),
        "{err}"
    );
    assert!(!dir.path().join("agent.partial").exists());
}

/// Roundabout insertion trained on several maps: `--map` and a `--maps` list (with a ring
/// id), all recorded in task.json; a bad list line is one error naming the file and line.
#[test]
fn insertion_trains_on_several_maps() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("insertion.toml");
    std::fs::write(
        &config,
        "[agent.dqn]\ntotal_steps = 300\nwarmup_steps = 100\nenvs = 2\nbatch_size = 8\n\
         replay_capacity = 1000\n[agent.dqn.network]\nconvolutions = []\nhidden = [16]\n\
         [agent.task.observation]\nwidth = 16\nheight = 16\nstack = 1\n",
    )
    .unwrap();
    let map = bundled_osm("montlake_roundabout.osm.pbf");
    let list = dir.path().join("maps.txt");
    std::fs::write(
        &list,
        format!("# the same ring, named\n{} 0\n", map.display()),
    )
    .unwrap();
    let agent = dir.path().join("agent");
    let out = run([
        "--rerun".as_ref(),
        "off".as_ref(),
        "--config".as_ref(),
        config.as_os_str(),
        "agent".as_ref(),
        "train".as_ref(),
        "--map".as_ref(),
        map.as_os_str(),
        "--maps".as_ref(),
        list.as_os_str(),
        "--out".as_ref(),
        agent.as_os_str(),
        "--record-episodes".as_ref(),
        "0".as_ref(),
    ]);
    assert_success(&out, "agent train on two maps");
    let task = read_json(&agent.join("task.json"));
    let maps = task["maps"].as_array().unwrap();
    assert_eq!(maps.len(), 2, "{task}");
    assert_eq!(maps[1]["roundabout"], 0);
    assert_eq!(task["map"], maps[0]["path"]);

    // An evaluation on one ring names it in eval.json and in eval.md's title.
    let eval = dir.path().join("eval_ring");
    let out = agent_eval(
        &agent,
        1,
        &[
            "--roundabout",
            "0",
            "--traffic",
            "low",
            "--aggressiveness",
            "0.5",
            "--no-baselines",
        ],
        &eval,
    );
    assert_success(&out, "agent eval --roundabout 0");
    let report = read_json(&eval.join("eval.json"));
    assert_eq!(report["roundabouts"], serde_json::json!([0]), "{report}");
    let table = std::fs::read_to_string(eval.join("eval.md")).unwrap();
    let title = table.lines().next().unwrap_or("");
    assert!(title.ends_with(", roundabout 0"), "{title}");

    std::fs::write(&list, format!("{} zero\n", map.display())).unwrap();
    let refused = dir.path().join("refused");
    let out = run([
        "--rerun".as_ref(),
        "off".as_ref(),
        "--config".as_ref(),
        config.as_os_str(),
        "agent".as_ref(),
        "train".as_ref(),
        "--maps".as_ref(),
        list.as_os_str(),
        "--out".as_ref(),
        refused.as_os_str(),
    ]);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("maps.txt")
            && err.contains("line 1")
            && err.contains("\"zero\" is not a roundabout id"),
        "{err}"
    );
    assert!(!refused.exists());
}
