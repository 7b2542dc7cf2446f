//! End-to-end tests of `pipeline dataset generate` on the bundled OSM data (no
//! ../shared/data needed): byte-identical output across runs and thread counts, the
//! dataset's files and label values, the required image sizes, shards that merge into the
//! unsharded run's folder, and bad input.

#![allow(clippy::unwrap_used, clippy::print_stdout)]

mod common;

use std::path::{Path, PathBuf};

use common::{assert_same_files, assert_success, entries, files, pipeline, read_json, stderr};

/// The bundled map every test renders from.
fn bundled_map() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/osm/northwestern_nu.osm.pbf")
}

/// Runs `dataset generate` with `threads` rayon threads.
fn generate(map: &Path, out: &Path, threads: &str, extra: &[&str]) -> std::process::Output {
    let mut cmd = pipeline();
    cmd.env("RAYON_NUM_THREADS", threads).args([
        "--rerun", "off", "--seed", "11", "dataset", "generate", "--map",
    ]);
    cmd.arg(map).arg("--out").arg(out).args(extra);
    cmd.output().unwrap()
}

#[test]
fn generation_is_byte_identical_across_runs_and_thread_counts() {
    let tmp = tempfile::tempdir().unwrap();
    // Import once, then render from the map folder; the first run imports on the fly.
    let map_dir = tmp.path().join("map");
    let out = pipeline()
        .args(["--rerun", "off", "map", "import"])
        .arg(bundled_map())
        .arg("--out")
        .arg(&map_dir)
        .output()
        .unwrap();
    assert_success(&out, "map import");
    let args = [
        "--count",
        "24",
        "--size",
        "256x256",
        "--topdown",
        "--previews",
    ];
    let runs = [
        (bundled_map(), "1", "from_osm_1_thread"),
        (map_dir.clone(), "2", "from_map_2_threads"),
        (map_dir.clone(), "1", "from_map_1_thread"),
    ];
    let mut outputs = Vec::new();
    for (map, threads, name) in &runs {
        // The same folder name in each run: the card is named after it.
        let dir = tmp.path().join(name).join("ds");
        let out = generate(map, &dir, threads, &args);
        assert_success(&out, name);
        outputs.push(files(&dir));
    }
    let first = &outputs[0];
    // 24 items × (image, label, top-down, preview) + manifest + card.
    assert_eq!(
        first.len(),
        24 * 4 + 2,
        "{:?}",
        first.keys().collect::<Vec<_>>()
    );
    for (other, (_, _, name)) in outputs.iter().zip(&runs).skip(1) {
        assert_eq!(
            first.keys().collect::<Vec<_>>(),
            other.keys().collect::<Vec<_>>()
        );
        for (path, bytes) in first {
            // The card names its input, which differs between the OSM file and the map.
            if path != "card.json" {
                assert!(other[path] == *bytes, "{path} differs in {name}");
            }
        }
    }
    assert!(outputs[1]["card.json"] == outputs[2]["card.json"]);

    // Another seed gives other images.
    let dir = tmp.path().join("seed12");
    let mut cmd = pipeline();
    cmd.args([
        "--rerun", "off", "--seed", "12", "dataset", "generate", "--map",
    ])
    .arg(&map_dir)
    .arg("--out")
    .arg(&dir)
    .args(["--count", "2", "--size", "256x256"]);
    assert_success(&cmd.output().unwrap(), "seed 12");
    assert_ne!(
        std::fs::read(dir.join("images/gen_000000.png")).unwrap(),
        first["images/gen_000000.png"]
    );
}

#[test]
fn a_dataset_with_valid_labels_manifest_and_card() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ds");
    let out = generate(
        &bundled_map(),
        &dir,
        "2",
        &["--count", "16", "--size", "256x256", "--topdown"],
    );
    assert_success(&out, "generate");
    assert_eq!(
        entries(&dir),
        ["card.json", "images", "labels", "manifest.jsonl", "topdown"]
    );
    let manifest = std::fs::read_to_string(dir.join("manifest.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = manifest
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 16);
    let mut shares = [0u64; 256];
    for item in &lines {
        let id = item["id"].as_str().unwrap();
        assert_eq!(item["source"], "generate");
        assert_eq!(
            (item["width"].as_u64(), item["height"].as_u64()),
            (Some(256), Some(256))
        );
        for key in ["seed", "ego", "camera", "look", "actors"] {
            assert!(item["params"].get(key).is_some(), "params.{key} of {id}");
        }
        let image = image::open(dir.join(item["image"].as_str().unwrap())).unwrap();
        assert_eq!(image.color(), image::ColorType::Rgb8);
        let label = image::open(dir.join(item["label"].as_str().unwrap())).unwrap();
        let label = label.as_luma8().expect("labels are single-channel 8-bit");
        assert_eq!(label.dimensions(), (256, 256));
        for &v in label.as_raw() {
            shares[usize::from(v)] += 1;
        }
        let top = image::open(dir.join(format!("topdown/{id}.png"))).unwrap();
        let top = top
            .as_luma8()
            .expect("top-down labels are single-channel 8-bit");
        assert!(top.as_raw().iter().all(|&v| v < 5));
        // The ego stands on its lane: the top-down view's centre is road or marking.
        let centre = top.get_pixel(top.width() / 2, top.height() / 2).0[0];
        assert!(centre <= 1, "top-down centre of {id} is class {centre}");
    }
    // Only class ids (and 255, which generation never needs) appear; road, marking and
    // other always, road users in some images.
    assert!(
        shares
            .iter()
            .enumerate()
            .all(|(v, &n)| n == 0 || v < 5 || v == 255)
    );
    for class in 0..5 {
        assert!(
            shares[class] > 0,
            "class {class} never appears: {:?}",
            &shares[..5]
        );
    }
    let card = read_json(&dir.join("card.json"));
    assert_eq!(card["seed"], 11);
    assert_eq!(card["labelable"], serde_json::json!([0, 1, 2, 3, 4]));
    assert_eq!(card["config"]["count"], 16);
    assert_eq!(card["config"]["generate"]["camera"]["width"], 256);
}

#[test]
fn the_required_image_sizes_work() {
    let tmp = tempfile::tempdir().unwrap();
    for (size, w, h) in [("480x270", 480, 270), ("512x512", 512, 512)] {
        let dir = tmp.path().join(size);
        let out = generate(&bundled_map(), &dir, "2", &["--count", "2", "--size", size]);
        assert_success(&out, size);
        let label = image::open(dir.join("labels/gen_000001.png")).unwrap();
        assert_eq!((label.width(), label.height()), (w, h));
        let img = image::open(dir.join("images/gen_000001.png")).unwrap();
        assert_eq!((img.width(), img.height()), (w, h));
    }
}

#[test]
fn bad_input_names_the_file_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("out");
    let missing = tmp.path().join("no_such_map.osm.pbf");
    let out = generate(&missing, &out_dir, "1", &["--count", "2"]);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("no_such_map.osm.pbf") && err.contains("no such file"),
        "{err}"
    );
    assert!(!out_dir.exists());

    let garbage = tmp.path().join("map.json");
    std::fs::write(&garbage, "{\"not\": \"a map\"}").unwrap();
    let out = generate(&garbage, &out_dir, "1", &["--count", "2"]);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("map.json") && !err.contains("panicked"),
        "{err}"
    );
    assert!(!out_dir.exists());

    let bad_pbf = tmp.path().join("broken.osm.pbf");
    std::fs::write(&bad_pbf, b"this is not a PBF file").unwrap();
    let out = generate(&bad_pbf, &out_dir, "1", &["--count", "2"]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("broken.osm.pbf"), "{}", stderr(&out));
    assert!(!out_dir.exists());

    for bad in [["--size", "0x10"], ["--fov", "200"]] {
        let out = generate(&bundled_map(), &out_dir, "1", &bad);
        assert!(!out.status.success(), "{bad:?}");
        assert!(stderr(&out).starts_with("error:"), "{}", stderr(&out));
        assert!(!out_dir.exists());
    }
}

/// Generation in two shards, merged, gives the unsharded run's folder byte for byte;
/// a missing or repeated shard is refused.
#[test]
fn two_shards_merge_into_the_unsharded_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let args = ["--count", "9", "--size", "96x64", "--topdown", "--previews"];
    let whole = tmp.path().join("whole").join("ds");
    assert_success(&generate(&bundled_map(), &whole, "2", &args), "unsharded");
    let mut shard_dirs = Vec::new();
    for shard in ["1/2", "0/2"] {
        let dir = tmp.path().join(format!("shard{}", &shard[..1]));
        let mut shard_args = args.to_vec();
        shard_args.extend(["--shard", shard]);
        assert_success(&generate(&bundled_map(), &dir, "1", &shard_args), shard);
        shard_dirs.push(dir);
    }
    assert_eq!(
        read_json(&shard_dirs[1].join("card.json"))["config"]["shard"],
        serde_json::json!({"index": 0, "count": 2})
    );
    let merged = tmp.path().join("merged").join("ds");
    let out = pipeline()
        .args(["--rerun", "off", "dataset", "merge", "--shards"])
        .args(&shard_dirs)
        .arg("--out")
        .arg(&merged)
        .output()
        .unwrap();
    assert_success(&out, "merge --shards");
    assert_same_files(&whole, &merged);

    // One shard twice and the other missing: refused, nothing written.
    let bad = tmp.path().join("bad");
    let out = pipeline()
        .args(["--rerun", "off", "dataset", "merge", "--shards"])
        .args([&shard_dirs[0], &shard_dirs[0]])
        .arg("--out")
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(stderr(&out).contains("exactly once"), "{}", stderr(&out));
    assert!(!bad.exists());
}

/// `--settings`: a file holding the defaults gives the same bytes as no file; street
/// furniture and parked cars change the pictures (more `other` and `vehicle` pixels over the
/// set); an unknown key is refused naming the file and the key, writing nothing.
#[test]
fn settings_files_set_the_generation() {
    let tmp = tempfile::tempdir().unwrap();
    let defaults = tmp.path().join("defaults.toml");
    std::fs::write(
        &defaults,
        "[scenery]\nfurniture_per_100m = 0.0\n\n[traffic]\nparked_rows = [0, 0]\n",
    )
    .unwrap();
    let town = tmp.path().join("town.toml");
    std::fs::write(
        &town,
        "[scenery]\nfurniture_per_100m = 12.0\n\n[traffic]\nvehicles = [0, 0]\nparked_rows = [3, 4]\n",
    )
    .unwrap();
    let args = ["--count", "12", "--size", "96x64"];
    let plain = tmp.path().join("plain").join("ds");
    assert_success(&generate(&bundled_map(), &plain, "2", &args), "plain");
    let same = tmp.path().join("same").join("ds");
    let mut with_defaults = args.to_vec();
    with_defaults.extend(["--settings", defaults.to_str().unwrap()]);
    assert_success(
        &generate(&bundled_map(), &same, "2", &with_defaults),
        "defaults",
    );
    assert_eq!(files(&plain.join("images")), files(&same.join("images")));
    assert_eq!(files(&plain.join("labels")), files(&same.join("labels")));
    let busy = tmp.path().join("busy").join("ds");
    let mut with_town = args.to_vec();
    with_town.extend(["--settings", town.to_str().unwrap()]);
    assert_success(&generate(&bundled_map(), &busy, "2", &with_town), "town");
    let vehicle_pixels = |dir: &Path| -> usize {
        files(&dir.join("labels"))
            .values()
            .map(|png| {
                let label = image::load_from_memory(png).unwrap().to_luma8();
                label.pixels().filter(|p| p.0[0] == 2).count()
            })
            .sum()
    };
    // No moving traffic at all in the town set: its vehicles are the parked rows.
    assert!(vehicle_pixels(&busy) > 0, "parked cars are drawn");
    let card = read_json(&busy.join("card.json"));
    assert_eq!(
        card["config"]["generate"]["scenery"]["furniture_per_100m"],
        serde_json::json!(12.0),
        "{card}"
    );

    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, "[scenery]\nfurniture = 3\n").unwrap();
    let refused = tmp.path().join("refused");
    let mut with_bad = args.to_vec();
    with_bad.extend(["--settings", bad.to_str().unwrap()]);
    let out = generate(&bundled_map(), &refused, "2", &with_bad);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("bad.toml") && err.contains("furniture"),
        "{err}"
    );
    assert!(!refused.exists());
}

/// Without `--map`, generation renders the campus embedded in the binary, from any current
/// folder: the same files as `--map data/osm/northwestern_nu.osm.pbf` but for the card's
/// `provenance.map`, which says the embedded copy was used.
#[test]
fn the_default_map_is_the_embedded_campus_wherever_the_command_runs() {
    let elsewhere = tempfile::tempdir().unwrap();
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    assert!(
        !elsewhere.path().starts_with(repo.canonicalize().unwrap()),
        "the temporary folder is outside the repository"
    );
    let args = ["--count", "2", "--size", "64x48"];
    let out = pipeline()
        .current_dir(elsewhere.path())
        .env("RAYON_NUM_THREADS", "2")
        .args([
            "--rerun",
            "off",
            "--seed",
            "11",
            "dataset",
            "generate",
            "--out",
            "default/ds",
        ])
        .args(args)
        .output()
        .unwrap();
    assert_success(&out, "dataset generate without --map in another folder");
    let default = elsewhere.path().join("default/ds");
    for id in ["gen_000000", "gen_000001"] {
        let image = image::open(default.join(format!("images/{id}.png"))).unwrap();
        assert_eq!((image.width(), image.height()), (64, 48), "{id}");
        assert!(default.join(format!("labels/{id}.png")).is_file(), "{id}");
    }

    let explicit = elsewhere.path().join("explicit/ds");
    assert_success(
        &generate(&bundled_map(), &explicit, "2", &args),
        "dataset generate --map data/osm/northwestern_nu.osm.pbf",
    );
    let (from_default, from_file) = (files(&default), files(&explicit));
    assert_eq!(
        from_default.keys().collect::<Vec<_>>(),
        from_file.keys().collect::<Vec<_>>()
    );
    for (path, bytes) in &from_default {
        if path != "card.json" {
            assert!(from_file[path] == *bytes, "{path} differs");
        }
    }
    let mut card = read_json(&default.join("card.json"));
    assert_eq!(
        card["provenance"]["map"], "bundled:northwestern_nu.osm.pbf",
        "{card}"
    );
    card["provenance"]["map"] = "northwestern_nu.osm.pbf".into();
    assert_eq!(card, read_json(&explicit.join("card.json")));
}

/// `--count 0` is refused with a hint before anything is read or written, with or without
/// `--shard`; a shard that gets no item of a positive count is still made (the merge of the
/// shards is the unsharded folder).
#[test]
fn count_zero_is_refused_but_an_empty_shard_is_made() {
    let tmp = tempfile::tempdir().unwrap();
    let refused = tmp.path().join("refused");
    for extra in [&[][..], &["--shard", "0/2"][..]] {
        let mut args = vec!["--count", "0"];
        args.extend(extra);
        let out = generate(&bundled_map(), &refused, "1", &args);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.starts_with(
                "error: --count 0: there is nothing to generate\nhint: --count must be at least 1"
            ),
            "{args:?}: {err}"
        );
        assert!(!refused.exists(), "{args:?}");
    }

    // One item in two shards: shard 0 gets none of it.
    let args = ["--count", "1", "--size", "64x48"];
    let whole = tmp.path().join("whole").join("ds");
    assert_success(&generate(&bundled_map(), &whole, "1", &args), "unsharded");
    let mut shards = Vec::new();
    for shard in ["0/2", "1/2"] {
        let dir = tmp.path().join(format!("shard{}", &shard[..1]));
        let mut shard_args = args.to_vec();
        shard_args.extend(["--shard", shard]);
        assert_success(&generate(&bundled_map(), &dir, "1", &shard_args), shard);
        shards.push(dir);
    }
    assert!(entries(&shards[0].join("images")).is_empty());
    assert_eq!(entries(&shards[1].join("images")), ["gen_000000.png"]);
    let merged = tmp.path().join("merged").join("ds");
    let out = pipeline()
        .args(["--rerun", "off", "dataset", "merge", "--shards"])
        .args(&shards)
        .arg("--out")
        .arg(&merged)
        .output()
        .unwrap();
    assert_success(&out, "merge --shards with an empty shard");
    assert_same_files(&whole, &merged);
}
