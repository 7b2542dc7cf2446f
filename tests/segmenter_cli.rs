//! The segmenter's and the dataset commands' rough edges, end to end on a tiny generated set:
//! sizes the network cannot take are refused the same way by every segmenter command;
//! `eval` announces the images it predicts; `train` draws curves.png and `eval` a labelled
//! confusion.png; `predict` treats an unreadable image as `dataset import` treats a broken
//! item; off a terminal, progress is a few lines per command, not one per step; `dataset
//! check` says an expected mix of sources once, in words; `dataset import` with a missing
//! folder says what to give. Needs no shared data.

#![allow(clippy::unwrap_used, clippy::print_stdout)]

mod common;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};

use common::{assert_success, run, stderr, stdout};

/// `pipeline --rerun off <args>`.
fn pipeline<I: IntoIterator<Item = S>, S: AsRef<OsStr>>(args: I) -> std::process::Output {
    run(["--rerun".as_ref(), "off".as_ref()]
        .into_iter()
        .map(OsStr::to_os_string)
        .chain(args.into_iter().map(|a| a.as_ref().to_os_string())))
}

fn generate(dir: &Path, count: u32) -> PathBuf {
    let out = dir.join(format!("generated{count}"));
    let map = common::bundled_osm("northwestern_nu.osm.pbf");
    let result = pipeline([
        "dataset".as_ref(),
        "generate".as_ref(),
        "--map".as_ref(),
        map.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
        "--count".as_ref(),
        count.to_string().as_ref(),
        "--size".as_ref(),
        "96x64".as_ref(),
    ]);
    assert_success(&result, "dataset generate");
    let split = pipeline(["dataset".as_ref(), "split".as_ref(), out.as_os_str()]);
    assert_success(&split, "dataset split");
    out
}

/// The one-line refusal every segmenter command gives for a size the network cannot take.
fn assert_size_refused(out: &std::process::Output, option: &str, size: &str) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.starts_with(&format!(
            "error: {option} {size}: the network takes short sides of 16 to 4096 px\nhint: "
        )),
        "{err}"
    );
}

#[test]
fn train_eval_predict_on_a_tiny_set() {
    let tmp = tempfile::tempdir().unwrap();
    let data = generate(tmp.path(), 10);
    let model = tmp.path().join("model");
    let train_args = |extra: &[&str]| -> Vec<std::ffi::OsString> {
        let mut args: Vec<std::ffi::OsString> = [
            "segmenter",
            "train",
            "--epochs",
            "2",
            "--width",
            "0.25",
            "--batch-size",
            "2",
            "--val-limit",
            "2",
            "--samples-per-epoch",
            "4",
        ]
        .iter()
        .map(Into::into)
        .collect();
        args.extend(["--data".into(), data.clone().into_os_string()]);
        args.extend(["--out".into(), model.clone().into_os_string()]);
        args.extend(extra.iter().map(Into::into));
        args
    };
    // Sizes the network cannot take: refused before anything is written.
    for (option, size, other) in [
        ("--size", "3", "--crop"),
        ("--size", "0", "--crop"),
        ("--crop", "3", "--size"),
    ] {
        let out = pipeline(train_args(&[option, size, other, "64"]));
        assert_size_refused(&out, option, size);
        assert!(!model.exists());
    }
    for size in ["3", "0"] {
        let out = pipeline(["segmenter", "bench", "--size", size, "--iterations", "1"]);
        assert_size_refused(&out, "--size", size);
    }

    let out = pipeline(train_args(&["--size", "64", "--crop", "64"]));
    assert_success(&out, "segmenter train");
    assert!(
        stdout(&out).starts_with("2 epochs, 4 steps"),
        "{}",
        stdout(&out)
    );
    let curves = image::open(model.join("curves.png")).unwrap();
    assert_eq!((curves.width(), curves.height()), (900, 760));
    // Off a terminal: a few lines, not one per step (4 steps, 2 epochs here; a tenth of the
    // way at most for a long run).
    let err = stderr(&out);
    let progress = err.lines().filter(|l| l.contains("training ")).count();
    assert!((1..=12).contains(&progress), "{err}");
    assert!(err.contains("segmenter train: training 4 steps"), "{err}");

    // eval: the size refusal, then the count it predicts, and a labelled confusion matrix.
    let eval_dir = tmp.path().join("eval");
    let eval = |extra: &[&str]| {
        let mut args: Vec<std::ffi::OsString> = vec![
            "segmenter".into(),
            "eval".into(),
            "--model".into(),
            model.clone().into_os_string(),
            "--data".into(),
            data.clone().into_os_string(),
            "--out".into(),
            eval_dir.clone().into_os_string(),
        ];
        args.extend(extra.iter().map(Into::into));
        pipeline(args)
    };
    let out = eval(&["--size", "3"]);
    assert_size_refused(&out, "--size", "3");
    assert!(!eval_dir.exists());
    let out = eval(&["--split", "all", "--limit", "2"]);
    assert_success(&out, "segmenter eval");
    let err = stderr(&out);
    assert!(err.contains("segmenter eval: predicting 2 images"), "{err}");
    assert!(stdout(&out).contains(" on 2 images; "), "{}", stdout(&out));
    let confusion = image::open(eval_dir.join("confusion.png"))
        .unwrap()
        .to_rgb8();
    // Five classes of 100 px cells, names and figures around them.
    assert_eq!(confusion.dimensions(), (150 + 500 + 110, 110 + 500 + 30));
    let report = std::fs::read_to_string(eval_dir.join("report.md")).unwrap();
    assert!(report.contains("2 images of the `all` split"), "{report}");
    // 0 keeps the images' own size (documented), and is still accepted by eval.
    let out = eval(&["--split", "all", "--limit", "1", "--size", "0"]);
    assert_success(&out, "segmenter eval --size 0");
    assert!(stdout(&out).contains(" on 1 image; "), "{}", stdout(&out));

    // predict: an unreadable image among readable ones fails, as `dataset import` does,
    // naming the file; with --on-error skip it is left out and counted.
    let images = tmp.path().join("images");
    std::fs::create_dir_all(&images).unwrap();
    let first = std::fs::read_dir(data.join("images"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    std::fs::copy(&first, images.join("good.png")).unwrap();
    std::fs::write(images.join("broken.png"), b"not a png").unwrap();
    let labels = tmp.path().join("predicted");
    let predict = |extra: &[&str]| {
        let mut args: Vec<std::ffi::OsString> = vec![
            "segmenter".into(),
            "predict".into(),
            "--model".into(),
            model.clone().into_os_string(),
            images.clone().into_os_string(),
            "--out".into(),
            labels.clone().into_os_string(),
        ];
        args.extend(extra.iter().map(Into::into));
        pipeline(args)
    };
    let out = predict(&[]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(errors.len(), 1, "{err}");
    assert!(errors[0].contains("broken.png"), "{err}");
    assert!(err.contains("--on-error skip"), "{err}");
    assert!(!labels.exists());
    let out = predict(&["--on-error", "skip"]);
    assert_success(&out, "segmenter predict --on-error skip");
    assert!(
        stdout(&out).starts_with("1 image labelled, 1 unreadable skipped in "),
        "{}",
        stdout(&out)
    );
    assert!(stderr(&out).contains("broken.png"), "{}", stderr(&out));
    assert!(labels.join("labels/good.png").is_file());
}

#[test]
fn check_says_a_mix_of_sources_once_and_in_words() {
    let tmp = tempfile::tempdir().unwrap();
    let generated = generate(tmp.path(), 4);
    // A source that labels every class but lane markings, as CamVid.
    let source = tmp.path().join("nolanes");
    std::fs::create_dir_all(source.join("images")).unwrap();
    std::fs::create_dir_all(source.join("labels")).unwrap();
    for i in 0..3u8 {
        image::RgbImage::from_pixel(48, 32, image::Rgb([30 * i, 80, 160]))
            .save(source.join(format!("images/n{i}.png")))
            .unwrap();
        image::GrayImage::from_fn(48, 32, |x, _| image::Luma([if x < 24 { 0 } else { 4 }]))
            .save(source.join(format!("labels/n{i}.png")))
            .unwrap();
    }
    let class_map = tmp.path().join("nolanes.toml");
    std::fs::write(
        &class_map,
        "name = \"nolanes\"\nencoding = \"index\"\nlabelable = [\"road\", \"vehicle\", \"human\", \"other\"]\n\
         class = [\n  { id = 0, name = \"road\", target = \"road\" },\n  { id = 4, name = \"rest\", target = \"other\" },\n]\n",
    )
    .unwrap();
    let imported = tmp.path().join("imported");
    let out = pipeline([
        "dataset".as_ref(),
        "import".as_ref(),
        "folders".as_ref(),
        source.as_os_str(),
        "--class-map".as_ref(),
        class_map.as_os_str(),
        "--out".as_ref(),
        imported.as_os_str(),
    ]);
    assert_success(&out, "dataset import");
    assert!(
        stdout(&out).starts_with("3 items (0 skipped)"),
        "{}",
        stdout(&out)
    );
    let merged = tmp.path().join("merged");
    let out = pipeline([
        "dataset".as_ref(),
        "merge".as_ref(),
        generated.as_os_str(),
        imported.as_os_str(),
        "--out".as_ref(),
        merged.as_os_str(),
    ]);
    assert_success(&out, "dataset merge");

    let out = pipeline(["dataset".as_ref(), "check".as_ref(), merged.as_os_str()]);
    assert_success(&out, "dataset check of a merge");
    let text = stdout(&out);
    assert!(text.contains("7 items, no problems"), "{text}");
    assert_eq!(text.matches("note:").count(), 1, "{text}");
    assert!(text.contains("lane marking in 4 of 7 items"), "{text}");

    // A real problem is named in words, not as a Rust variant.
    let copy = tmp.path().join("copy");
    std::fs::create_dir_all(&copy).unwrap();
    for entry in ["card.json", "manifest.jsonl", "images", "labels"] {
        let from = generated.join(entry);
        if from.is_dir() {
            std::fs::create_dir_all(copy.join(entry)).unwrap();
            for f in std::fs::read_dir(&from).unwrap() {
                let f = f.unwrap().path();
                std::fs::copy(&f, copy.join(entry).join(f.file_name().unwrap())).unwrap();
            }
        } else {
            std::fs::copy(&from, copy.join(entry)).unwrap();
        }
    }
    let labels: Vec<PathBuf> = std::fs::read_dir(copy.join("labels"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    image::GrayImage::from_pixel(96, 64, image::Luma([255]))
        .save(&labels[0])
        .unwrap();
    let out = pipeline(["dataset".as_ref(), "check".as_ref(), copy.as_os_str()]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let text = stdout(&out);
    assert!(text.starts_with("empty label: "), "{text}");
    assert!(!text.contains("EmptyLabel"), "{text}");
    assert!(
        stderr(&out).contains("1 problem in 4 items: 1 empty label"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn importing_a_missing_folder_says_what_to_give() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("MISSING");
    let out = pipeline([
        "dataset".as_ref(),
        "import".as_ref(),
        "camvid".as_ref(),
        missing.as_os_str(),
        "--out".as_ref(),
        tmp.path().join("out").as_os_str(),
    ]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.starts_with("error: "), "{err}");
    assert!(err.contains("MISSING: is not a folder"), "{err}");
    let hint = err.lines().find(|l| l.starts_with("hint: ")).unwrap();
    assert!(!hint.contains("--on-error"), "{hint}");
    assert!(hint.contains("train.txt"), "{hint}");
    assert!(!tmp.path().join("out").exists());
}
