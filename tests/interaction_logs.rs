//! Real INTERACTION recordings of the roundabout FT, converted to MCAP (`logs convert`):
//! - `logs project` around one vehicle: every frame has the ego's
//!   footprint at its centre, on the drivable area of the real map, and the frame
//!   dataset's files agree with each other;
//! - `replay eval`: approaches found and labelled, the
//!   scores consistent with the labels;
//! - `replay eval` and `replay gaps` count the same approaches.
//!
//! Skips when ../shared/data is absent.

#![allow(clippy::unwrap_used, clippy::print_stdout)]

mod common;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};

use common::{assert_refused, assert_success, pipeline, read_json, shared_data, stderr};

/// The FT map, and recording `n` converted into `dir` (None without ../shared/data).
fn ft_recording(dir: &Path, n: u32) -> Option<(PathBuf, PathBuf)> {
    let Some(data) = shared_data() else {
        println!(
            "skipped: {}: ../shared/data is absent",
            std::thread::current().name().unwrap_or("-")
        );
        return None;
    };
    let base = data.join("trajectories/interaction");
    let map = base.join("maps/DR_USA_Roundabout_FT.osm");
    let tracks = base.join(format!(
        "recorded_trackfiles/DR_USA_Roundabout_FT/vehicle_tracks_{n:03}.csv.gz"
    ));
    let log = dir.join(format!("ft_{n:03}.mcap"));
    let out = pipeline()
        .args(["--rerun", "off", "logs", "convert"])
        .arg(&tracks)
        .arg("--map")
        .arg(&map)
        .arg("--out")
        .arg(&log)
        .output()
        .unwrap();
    assert_success(&out, "logs convert");
    Some((map, log))
}

#[test]
fn interaction_tracks_project_onto_the_real_roundabout() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((map, log)) = ft_recording(tmp.path(), 0) else {
        return;
    };
    let frames_dir = tmp.path().join("frames");
    let out = pipeline()
        .args(["--rerun", "off", "logs", "project"])
        .arg(&log)
        .arg("--map")
        .arg(&map)
        .args(["--ego", "60", "--previews", "2", "--out"])
        .arg(&frames_dir)
        .output()
        .unwrap();
    assert_success(&out, "logs project");

    let card = read_json(&frames_dir.join("frames.json"));
    let (w, h) = (
        card["width"].as_u64().unwrap() as usize,
        card["height"].as_u64().unwrap() as usize,
    );
    let layers: Vec<String> = card["layers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_owned())
        .collect();
    let frames = card["frames"].as_u64().unwrap() as usize;
    // Track 60 of FT 000 is in 547 of the recording's 3,008 frames (10 Hz).
    assert_eq!(frames, 547);
    assert_eq!(card["log_frames"].as_u64(), Some(3008));
    let lines = std::fs::read_to_string(frames_dir.join("frames.jsonl")).unwrap();
    assert_eq!(lines.lines().count(), frames);
    let bytes = std::fs::read(frames_dir.join("layers.bin")).unwrap();
    let frame_len = layers.len() * w * h;
    assert_eq!(bytes.len(), frames * frame_len);

    let layer = |name: &str| layers.iter().position(|l| l == name).unwrap();
    let (navigable, obstacles) = (layer("navigable"), layer("obstacles"));
    let centre = (h / 2) * w + w / 2;
    let mut on_road = 0;
    for frame in bytes.chunks_exact(frame_len) {
        // The ego sits at the centre of its own frame.
        assert_eq!(frame[obstacles * w * h + centre], 255);
        on_road += usize::from(frame[navigable * w * h + centre] == 255);
    }
    // Where the drone saw the car, the Lanelet2 map has road: the tracks and the map line up.
    assert!(
        on_road as f64 >= 0.95 * frames as f64,
        "{on_road} of {frames} frames have the ego on the navigable area"
    );
    // Speeds are those of a car in a roundabout.
    let max_speed = lines
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["speed_mps"]
                .as_f64()
                .unwrap()
        })
        .fold(0.0, f64::max);
    assert!((3.0..25.0).contains(&max_speed), "{max_speed}");
    assert_eq!(
        std::fs::read_dir(frames_dir.join("previews"))
            .unwrap()
            .count(),
        2
    );

    // Perception noise: the same seed gives the same frames with 1 or 2 threads, other
    // frames than the clean ones, and the ego still at the centre of each.
    let noisy = |name: &str, threads: &str| {
        let dir = tmp.path().join(name);
        let out = pipeline()
            .env("RAYON_NUM_THREADS", threads)
            .args(["--rerun", "off", "--seed", "3", "logs", "project"])
            .arg(&log)
            .arg("--map")
            .arg(&map)
            .args(["--ego", "60", "--previews", "0", "--position-noise", "0.5"])
            .args(["--heading-noise", "5", "--path-noise", "1.5", "--out"])
            .arg(&dir)
            .output()
            .unwrap();
        assert_success(&out, name);
        std::fs::read(dir.join("layers.bin")).unwrap()
    };
    let (one, two) = (noisy("noisy1", "1"), noisy("noisy2", "2"));
    assert!(one == two, "noisy frames differ between thread counts");
    assert_eq!(one.len(), bytes.len());
    assert!(one != bytes, "noise changed nothing");
    for frame in one.chunks_exact(frame_len) {
        assert_eq!(frame[obstacles * w * h + centre], 255);
    }

    // An ego the log does not have: one clear error, nothing written.
    let bad = tmp.path().join("bad");
    let out = pipeline()
        .args(["--rerun", "off", "logs", "project"])
        .arg(&log)
        .arg("--map")
        .arg(&map)
        .args(["--ego", "99999", "--out"])
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("has no track 99999"),
        "{}",
        stderr(&out)
    );
    assert!(!bad.exists());
}

#[test]
fn replay_labels_real_approaches_and_scores_the_baselines() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((map, log)) = ft_recording(tmp.path(), 0) else {
        return;
    };
    let out_dir = tmp.path().join("replay");
    let out = pipeline()
        .args(["--rerun", "off", "replay", "eval", "--log"])
        .arg(&log)
        .arg("--map")
        .arg(&map)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    assert_success(&out, "replay eval");
    let r = read_json(&out_dir.join("replay.json"));
    let approaches = r["approaches"].as_u64().unwrap();
    let stopped = r["approaches_with_a_stop"].as_u64().unwrap();
    assert!(
        approaches >= 50 && stopped >= 10,
        "{approaches} approaches, {stopped} with a stop"
    );
    let frames = |k: &str| r["frames"][k].as_u64().unwrap_or(0);
    let (go, wait) = (frames("go"), frames("wait"));
    assert!(go > 0 && wait > 0);
    for p in r["policies"].as_array().unwrap() {
        // Every scored frame is in the confusion matrix once.
        let c = &p["confusion"];
        let n = |h: &str, q: &str| c[h][q].as_u64().unwrap_or(0);
        assert_eq!(n("go", "go") + n("go", "wait"), go, "{p}");
        assert_eq!(n("wait", "go") + n("wait", "wait"), wait, "{p}");
        let agreement = p["agreement"].as_f64().unwrap();
        let expected = (n("go", "go") + n("wait", "wait")) as f64 / (go + wait) as f64;
        assert!((agreement - expected).abs() < 1e-12, "{p}");
    }
    // Always go agrees exactly on the go frames.
    let always = r["policies"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["policy"] == "always go")
        .unwrap();
    assert!((always["agreement"].as_f64().unwrap() - go as f64 / (go + wait) as f64).abs() < 1e-12);

    // A map without a roundabout: one clear error.
    let campus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/osm/northwestern_nu.osm.pbf");
    let out = pipeline()
        .args(["--rerun", "off", "replay", "eval", "--log"])
        .arg(&log)
        .arg("--map")
        .arg(&campus)
        .arg("--out")
        .arg(tmp.path().join("bad"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("has no roundabout"),
        "{}",
        stderr(&out)
    );
}

/// `replay eval` and `replay gaps` on FT 000 count the same approaches (docs/logs.md): the
/// same number under the same name and definition in replay.json and gaps.json, and
/// gaps.json's other counts relate to it exactly as documented: the approaches offered a gap
/// (the distinct drivers of gaps.csv) and those offered none whose outcome the recording
/// shows add up to the approaches; the vehicles that crossed a yield line with too little of
/// their track before it to have an approach are counted apart, in neither.
#[test]
fn replay_eval_and_replay_gaps_count_the_same_approaches() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((map, log)) = ft_recording(tmp.path(), 0) else {
        return;
    };
    let run = |command: &str| {
        let dir = tmp.path().join(command);
        let out = pipeline()
            .args(["--rerun", "off", "replay", command, "--log"])
            .arg(&log)
            .arg("--map")
            .arg(&map)
            .arg("--out")
            .arg(&dir)
            .output()
            .unwrap();
        assert_success(&out, &format!("replay {command}"));
        dir
    };
    let (eval_dir, gaps_dir) = (run("eval"), run("gaps"));
    let replay = read_json(&eval_dir.join("replay.json"));
    let gaps = read_json(&gaps_dir.join("gaps.json"));
    let count = |report: &serde_json::Value, key: &str| {
        report[key]
            .as_u64()
            .unwrap_or_else(|| panic!("no {key} in {report}"))
    };

    // The same thing, the same number and the same words.
    let approaches = count(&replay, "approaches");
    assert_eq!(count(&gaps, "approaches"), approaches, "{gaps}");
    let definition = replay["approach_definition"].as_str().unwrap();
    assert!(definition.contains("min_approach_s"), "{definition}");
    assert_eq!(gaps["approach_definition"].as_str(), Some(definition));

    // The gaps' drivers are the approaches offered a gap; the rest were offered none whose
    // outcome the recording shows.
    let offered_a_gap = count(&gaps, "approaches_offered_a_gap");
    let without = count(&gaps, "approaches_without_a_known_gap");
    assert_eq!(offered_a_gap + without, approaches, "{gaps}");
    let csv = std::fs::read_to_string(gaps_dir.join("gaps.csv")).unwrap();
    let drivers: std::collections::BTreeSet<(String, String)> = csv
        .lines()
        .skip(1)
        .map(|l| {
            let mut f = l.split(',');
            (f.next().unwrap().to_owned(), f.next().unwrap().to_owned())
        })
        .collect();
    assert_eq!(drivers.len() as u64, offered_a_gap);
    assert_eq!(csv.lines().count() as u64 - 1, count(&gaps, "offered"));

    // FT 000: 139 vehicles crossed a yield line towards the ring; 37 of them were first seen
    // under a second before it (entries 1 and 3, where the recorded area ends at the line)
    // and have no approach; of the 102 approaches, 3 cross in the recording's last seconds,
    // before the outcome of their gap is known.
    assert_eq!(
        (
            approaches,
            offered_a_gap,
            without,
            count(&gaps, "crossings_without_an_approach")
        ),
        (102, 99, 3, 37),
        "{gaps}"
    );

    // The summaries say so.
    let replay_md = std::fs::read_to_string(eval_dir.join("replay.md")).unwrap();
    assert!(
        replay_md.contains("102 approaches to a yield line"),
        "{replay_md}"
    );
    let gaps_md = std::fs::read_to_string(gaps_dir.join("gaps.md")).unwrap();
    assert!(
        gaps_md.contains("to the drivers of 99 approaches")
            && gaps_md.contains("Approaches: 102 to the yield lines")
            && gaps_md.contains("3 of them offered no gap")
            && gaps_md.contains("37 more vehicles crossed a yield line"),
        "{gaps_md}"
    );
}

/// `agent train --offline` (offline RL): CQL on the drivers of one FT recording,
/// with two frames stacked 0.3 s apart and the rule and motion inputs, writes an agent folder like an online one's,
/// deterministically; `replay eval` and
/// `agent eval` (the simulator on the same map) take it as they take online agents, and
/// the inputs it was told to ignore (aggressiveness, last action) change nothing.
#[test]
fn offline_agents_learn_from_drivers_and_run_where_online_agents_do() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((map, log)) = ft_recording(tmp.path(), 0) else {
        return;
    };
    let config = tmp.path().join("offline.toml");
    std::fs::write(
        &config,
        "[agent.dqn]\nbatch_size = 16\n[agent.dqn.network]\nconvolutions = []\nscalar_hidden = 0\nhidden = [16]\n\
         [agent.offline]\ntarget_update_every = 50\n\
         [agent.task]\nframe_steps = 3\nrule_inputs = true\nmotion_inputs = true\n\
         [agent.task.observation]\nwidth = 21\nheight = 21\nstack = 2\n",
    )
    .unwrap();
    let train = |out: &Path, algorithm: &str| {
        let result = pipeline()
            .args(["--rerun", "off", "--seed", "4", "--config"])
            .arg(&config)
            .args([
                "agent",
                "train",
                "--offline",
                "--algorithm",
                algorithm,
                "--steps",
                "120",
            ])
            .arg("--map")
            .arg(&map)
            .arg("--log")
            .arg(&log)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        assert_success(&result, "agent train --offline");
        String::from_utf8_lossy(&result.stdout).into_owned()
    };
    let agent = tmp.path().join("cql");
    let said = train(&agent, "cql");
    // The algorithm by name, not by its name in the code.
    assert!(said.contains("\n  CQL on "), "{said}");
    let run = read_json(&agent.join("offline.json"));
    let summary = &run["summary"];
    assert_eq!(run["config"]["algorithm"], "cql");
    assert_eq!(summary["gradient_steps"], 120);
    assert_eq!(summary["curve"].as_array().unwrap().len(), 2);
    assert!(summary["curve"][0]["td_loss"].is_f64());
    let counts: Vec<u64> = summary["action_counts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_u64().unwrap())
        .collect();
    assert!(
        counts[0] > 100 && counts[1] > 100 && counts[2] == 0,
        "{counts:?}"
    );
    assert_eq!(
        summary["transitions"].as_u64().unwrap(),
        counts.iter().sum::<u64>()
    );
    let agreement = summary["train_agreement"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&agreement));
    let description = read_json(&agent.join("agent.json"));
    assert_eq!(
        description["config"]["network"]["ignored_scalars"],
        serde_json::json!([2, 3, 4, 5])
    );
    let task = read_json(&agent.join("task.json"));
    assert_eq!(task["task"], "roundabout-insertion");
    // Its two frames are 3 log frames (0.3 s) apart, in training and in the evaluations below.
    assert_eq!(task["config"]["frame_steps"], 3);

    // Same seed, same network.
    let again = tmp.path().join("cql_again");
    train(&again, "cql");
    assert_eq!(
        std::fs::read(agent.join("online.bpk")).unwrap(),
        std::fs::read(again.join("online.bpk")).unwrap()
    );
    // Behaviour cloning has no TD part.
    let bc = tmp.path().join("bc");
    let said = train(&bc, "bc");
    assert!(said.contains("\n  behaviour cloning on "), "{said}");
    let bc_run = read_json(&bc.join("offline.json"));
    assert_eq!(bc_run["config"]["algorithm"], "behaviour_cloning");
    assert!(bc_run["summary"]["curve"][0]["td_loss"].is_null());

    // Replayed against the drivers, open and closed loop: the aggressiveness levels decide
    // alike.
    let replay = tmp.path().join("replay");
    let out = pipeline()
        .args([
            "--rerun",
            "off",
            "replay",
            "eval",
            "--closed-loop",
            "--aggressiveness",
            "0,1",
            "--log",
        ])
        .arg(&log)
        .arg("--map")
        .arg(&map)
        .arg("--agent")
        .arg(&agent)
        .arg("--out")
        .arg(&replay)
        .output()
        .unwrap();
    assert_success(&out, "replay eval --agent <offline agent>");
    let r = read_json(&replay.join("replay.json"));
    let policy = |name: &str| {
        r["policies"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["policy"] == name)
            .unwrap_or_else(|| panic!("no policy {name}: {r}"))
            .clone()
    };
    assert_eq!(
        policy("agent, aggressiveness 0")["confusion"],
        policy("agent, aggressiveness 1")["confusion"]
    );
    let driven: Vec<serde_json::Value> = r["closed_loop"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["policy"].as_str().unwrap().starts_with("agent"))
        .map(|p| {
            let mut figures = p.clone();
            figures.as_object_mut().unwrap().remove("policy");
            figures
        })
        .collect();
    assert_eq!(driven.len(), 2, "{r}");
    assert!(driven[0]["episodes"].as_u64().unwrap() > 0, "{r}");
    assert_eq!(driven[0], driven[1]);
    // Every policy that entered took a gap, beside its drivers' own, each in its interval;
    // always go enters no later than the drivers on average (it never waits).
    for p in r["closed_loop"].as_array().unwrap() {
        let (Some(gap), Some(drivers)) = (
            p["mean_accepted_gap_s"].as_f64(),
            p["drivers_mean_accepted_gap_s"].as_f64(),
        ) else {
            continue;
        };
        let ci = &p["accepted_gap_ci95_s"];
        assert!(
            ci[0].as_f64().unwrap() <= gap && gap <= ci[1].as_f64().unwrap(),
            "{p}"
        );
        assert!(
            (0.0..=12.0).contains(&gap) && (0.0..=12.0).contains(&drivers),
            "{p}"
        );
        let d = p["gap_against_drivers"]["difference"].as_f64().unwrap();
        assert!((d - (gap - drivers)).abs() < 1e-9, "{p}");
    }
    let always = r["closed_loop"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["policy"] == "always go")
        .unwrap();
    assert!(
        always["mean_entry_delay_s"].as_f64().unwrap() <= 0.0,
        "{always}"
    );

    // In the simulator, on the same map.
    let eval = tmp.path().join("eval");
    let out = pipeline()
        .args([
            "--rerun",
            "off",
            "agent",
            "eval",
            "--episodes",
            "4",
            "--traffic",
            "medium",
        ])
        .args(["--aggressiveness", "0.5", "--no-baselines", "--agent"])
        .arg(&agent)
        .arg("--out")
        .arg(&eval)
        .output()
        .unwrap();
    assert_success(&out, "agent eval <offline agent>");
    assert!(eval.join("eval.json").is_file());

    // Refused before anything is written: offline learning is for roundabout insertion only,
    // and logs cannot give decisions several steps apart.
    let refused = |global: &[&OsStr], task: &[&str], message: &str| {
        let bad = tmp.path().join("bad");
        let out = pipeline()
            .args(["--rerun", "off"])
            .args(global)
            .args(["agent", "train", "--offline"])
            .args(task)
            .arg("--map")
            .arg(&map)
            .arg("--log")
            .arg(&log)
            .arg("--out")
            .arg(&bad)
            .output()
            .unwrap();
        assert_refused(&out, message, &bad);
    };
    refused(
        &[],
        &["--task", "route-following"],
        "--offline learns roundabout insertion",
    );
    // An `[agent.task]` setting logs cannot give, and its refusal.
    let config = tmp.path().join("action_repeat.toml");
    std::fs::write(&config, "[agent.task]\naction_repeat = 3\n").unwrap();
    refused(
        &["--config".as_ref(), config.as_os_str()],
        &[],
        "`action_repeat = 3`: it decides every 3 steps",
    );
}

/// A recording given with another roundabout's map, one whose extent covers the tracks (EP's
/// for FT's), is refused by every command that reads a recording with a map, through the
/// one shared check: the same message with the same share of positions near the map's
/// lanes, the recording and the map named, a hint, one error line, nothing written.
#[test]
fn every_command_refuses_a_recording_on_another_scenarios_map() {
    let Some(data) = shared_data() else {
        println!(
            "skipped: {}: ../shared/data is absent",
            std::thread::current().name().unwrap_or("-")
        );
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let base = data.join("trajectories/interaction");
    let tracks = base.join("recorded_trackfiles/DR_USA_Roundabout_FT/vehicle_tracks_000.csv.gz");
    let ft = base.join("maps/DR_USA_Roundabout_FT.osm");
    let ep = base.join("maps/DR_USA_Roundabout_EP.osm");
    // The recording, converted on its own map with an ego (for `logs ego`).
    let log = tmp.path().join("ft_000.mcap");
    let out = pipeline()
        .args(["--rerun", "off", "logs", "convert"])
        .arg(&tracks)
        .arg("--map")
        .arg(&ft)
        .args(["--ego", "60", "--out"])
        .arg(&log)
        .output()
        .unwrap();
    assert_success(&out, "logs convert on its own map");
    let out_path = |name: &str| tmp.path().join(name);
    let log_arg = log.to_string_lossy().into_owned();
    let tracks_arg = tracks.to_string_lossy().into_owned();
    // (command, its input, its arguments before --map, what it would write)
    let cases: Vec<(&str, &Path, Vec<&str>, PathBuf)> = vec![
        (
            "logs convert",
            &tracks,
            vec!["logs", "convert", &tracks_arg],
            out_path("c.mcap"),
        ),
        (
            "logs project",
            &log,
            vec!["logs", "project", &log_arg],
            out_path("frames"),
        ),
        (
            "logs ego",
            &log,
            vec!["logs", "ego", &log_arg],
            out_path("ego.json"),
        ),
        (
            "replay eval",
            &log,
            vec!["replay", "eval", "--log", &log_arg],
            out_path("replay"),
        ),
        (
            "replay gaps",
            &log,
            vec!["replay", "gaps", "--log", &log_arg],
            out_path("gaps"),
        ),
        (
            "sim calibrate",
            &log,
            vec!["sim", "calibrate", "--no-refine", "--log", &log_arg],
            out_path("calib.toml"),
        ),
        (
            "sim realism",
            &log,
            vec!["sim", "realism", "--minutes", "1", "--log", &log_arg],
            out_path("realism"),
        ),
        (
            "agent train --offline",
            &log,
            vec![
                "agent",
                "train",
                "--offline",
                "--steps",
                "10",
                "--log",
                &log_arg,
            ],
            out_path("offline"),
        ),
    ];
    for (what, input, args, output) in cases {
        let out = pipeline()
            .args(["--rerun", "off"])
            .args(&args)
            .arg("--map")
            .arg(&ep)
            .arg("--out")
            .arg(&output)
            .output()
            .unwrap();
        let name = input.file_name().unwrap().to_string_lossy().into_owned();
        let expected = if what == "logs ego" {
            // The ego's own positions.
            format!(
                "{name}: its road users do not drive on the map {}: ",
                ep.display()
            )
        } else {
            // Every other command counts the same vehicle positions of the same recording.
            format!(
                "{name}: its road users do not drive on the map {}: 39.4 % of their",
                ep.display()
            )
        };
        assert_refused(&out, &expected, &output);
        let err = stderr(&out);
        let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        assert_eq!(errors.len(), 1, "{what}: {err}");
        assert!(
            err.lines()
                .any(|l| l.starts_with("hint: give the map the recording was made on")),
            "{what}: {err}"
        );
    }
}

/// `logs info --json` names each topic's decoder as the text form does: its name, or
/// `none (<why>)`.
#[test]
fn logs_info_json_names_each_decoder_plainly() {
    let Some(data) = shared_data() else {
        println!(
            "skipped: {}: ../shared/data is absent",
            std::thread::current().name().unwrap_or("-")
        );
        return;
    };
    let decoders = |log: &Path| -> Vec<String> {
        let out = pipeline()
            .args(["--rerun", "off", "logs", "info", "--json"])
            .arg(log)
            .output()
            .unwrap();
        assert_success(&out, "logs info --json");
        let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        info["topics"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| {
                t["decoder"]
                    .as_str()
                    .unwrap_or_else(|| panic!("not a string: {t}"))
                    .to_owned()
            })
            .collect()
    };
    assert_eq!(
        decoders(&data.join("logs/husky/husky.mcap")),
        ["Imu", "Odometry", "NavSatFix"]
    );
    let schemaless =
        data.join("logs/mcap-conformance/OneSchemalessMessage/OneSchemalessMessage-st.mcap");
    assert_eq!(decoders(&schemaless), ["none ( in text encoding)"]);
}

/// Topic roles: detected on the Husky drive (odometry and GPS, no objects), a
/// named topic of the wrong type refused, and projection without an objects topic refused
/// with the reason.
#[test]
fn topic_roles_are_detected_named_or_refused() {
    let Some(data) = shared_data() else {
        println!(
            "skipped: {}: ../shared/data is absent",
            std::thread::current().name().unwrap_or("-")
        );
        return;
    };
    let husky = data.join("logs/husky/husky.mcap");
    let out = pipeline()
        .args(["--rerun", "off", "logs", "info", "--json"])
        .arg(&husky)
        .output()
        .unwrap();
    assert_success(&out, "logs info --json");
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let roles = &info["roles"];
    assert_eq!(roles["ego_pose"]["how"], "detected");
    assert_eq!(
        roles["ego_pose"]["topic"],
        "/husky_velocity_controller/odom"
    );
    assert_eq!(roles["gps"]["topic"], "/fix");
    assert_eq!(roles["objects"]["how"], "absent");
    assert_eq!(roles["camera"]["how"], "absent");

    let out = pipeline()
        .args(["--rerun", "off", "logs", "info", "--gps-topic", "/imu/data"])
        .arg(&husky)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("sensor_msgs/msg/Imu"),
        "{}",
        stderr(&out)
    );

    let tmp = tempfile::tempdir().unwrap();
    let map = data.join("trajectories/interaction/maps/DR_USA_Roundabout_FT.osm");
    let out = pipeline()
        .args(["--rerun", "off", "logs", "project"])
        .arg(&husky)
        .arg("--map")
        .arg(&map)
        .arg("--out")
        .arg(tmp.path().join("frames"))
        .output()
        .unwrap();
    assert_refused(
        &out,
        "no topic holds the object detections",
        &tmp.path().join("frames"),
    );
}

/// `logs ego` (GPS into the map frame, resampling, map matching): FT 000 converted
/// with track 60 as the ego; its track from the odometry and from the GPS fixes (unprojected
/// by the converter, projected back here) agree to the millimetre, lie on the map's lanes,
/// and resample to the asked rate.
#[test]
fn the_ego_track_from_pose_or_gps_lies_on_the_lanes() {
    let Some(data) = shared_data() else {
        println!(
            "skipped: {}: ../shared/data is absent",
            std::thread::current().name().unwrap_or("-")
        );
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let base = data.join("trajectories/interaction");
    let map = base.join("maps/DR_USA_Roundabout_FT.osm");
    let log = tmp.path().join("ft_000_60.mcap");
    let out = pipeline()
        .args(["--rerun", "off", "logs", "convert"])
        .arg(base.join("recorded_trackfiles/DR_USA_Roundabout_FT/vehicle_tracks_000.csv.gz"))
        .arg("--map")
        .arg(&map)
        .args(["--ego", "60", "--out"])
        .arg(&log)
        .output()
        .unwrap();
    assert_success(&out, "logs convert --ego 60");
    let ego = |source: &str, rate: &str| {
        let file = tmp.path().join(format!("ego_{source}_{rate}.json"));
        let out = pipeline()
            .args([
                "--rerun", "off", "logs", "ego", "--source", source, "--rate", rate,
            ])
            .arg(&log)
            .arg("--map")
            .arg(&map)
            .arg("--out")
            .arg(&file)
            .output()
            .unwrap();
        assert_success(&out, "logs ego");
        read_json(&file)
    };
    let pose = ego("pose", "10");
    let gps = ego("gps", "10");
    assert_eq!(pose["topic"], "/ego/odom");
    assert_eq!(gps["topic"], "/ego/fix");
    let samples = |v: &serde_json::Value| v["samples"].as_array().unwrap().clone();
    let (a, b) = (samples(&pose), samples(&gps));
    assert_eq!(a.len(), 547);
    assert_eq!(a.len(), b.len());
    for (p, q) in a.iter().zip(&b) {
        let d = (p["x"].as_f64().unwrap() - q["x"].as_f64().unwrap())
            .hypot(p["y"].as_f64().unwrap() - q["y"].as_f64().unwrap());
        assert!(d < 1e-3, "{p} vs {q}");
    }
    for v in [&pose, &gps] {
        let share = v["on_lane_share"].as_f64().unwrap();
        assert!(share > 0.95, "on a lane {share}");
    }
    // 4 Hz over the same 54.6 s: 219 samples.
    let slow = ego("pose", "4");
    assert_eq!(slow["resampling"]["resampled"], 219);
    assert_eq!(slow["resampling"]["recorded"], 547);
}
