//! The segmenter's and the dataset commands' rough edges, end to end on a tiny generated set:
//! sizes the network cannot take are refused the same way by every segmenter command;
//! `eval` announces the images it predicts; `train` draws curves.png and `eval` a labelled
//! confusion.png; `predict` treats an unreadable image as `dataset import` treats a broken
//! item; off a terminal, progress is a few lines per command, not one per step; `dataset
//! check` says an expected mix of sources once, in words; `dataset import` with a missing
//! folder says what to give; without --model, `eval` (on a test split, with intervals over
//! images) and `predict` use the shipped model. Needs no shared data.

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

/// Without --model, `eval` and `predict` use the model shipped in the binary at its trained
/// short side; `eval --split test` evaluates the test split `dataset split --test` wrote, with
/// 95 % intervals over the images that are the same on every run.
#[test]
fn the_shipped_model_evaluates_a_test_split_and_labels_images() {
    let tmp = tempfile::tempdir().unwrap();
    let data = generate(tmp.path(), 12);
    let eval = |out: &Path| {
        pipeline([
            "segmenter".as_ref(),
            "eval".as_ref(),
            "--data".as_ref(),
            data.as_os_str(),
            "--split".as_ref(),
            "test".as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ])
    };
    // `generate` split it 70 / 30: no test items yet.
    let refused = tmp.path().join("refused");
    let out = eval(&refused);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    // The error says which splits it has; the hint offers those and how to make a test split,
    // never the split that failed.
    let err = stderr(&out);
    assert!(
        err.contains("has no items in the test split (its items: train 8, val 4)"),
        "{err}"
    );
    let hint = err.lines().find(|l| l.starts_with("hint: ")).unwrap_or("");
    assert!(
        hint.contains("--split train|val|all") && hint.contains("--test 0.2"),
        "{err}"
    );
    assert!(!refused.exists());
    let split = pipeline([
        "dataset".as_ref(),
        "split".as_ref(),
        data.as_os_str(),
        "--train".as_ref(),
        "0.5".as_ref(),
        "--val".as_ref(),
        "0.25".as_ref(),
        "--test".as_ref(),
        "0.25".as_ref(),
    ]);
    assert_success(&split, "dataset split --test");
    let manifest = std::fs::read_to_string(data.join("manifest.jsonl")).unwrap();
    let tests = manifest
        .lines()
        .filter(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["split"] == "test")
        .count();
    assert!((1..12).contains(&tests), "{manifest}");

    let first = tmp.path().join("eval");
    let out = eval(&first);
    assert_success(&out, "segmenter eval --split test (shipped model)");
    let m = common::read_json(&first.join("metrics.json"));
    assert_eq!(m["model"], "shipped");
    assert_eq!(m["split"], "test");
    assert_eq!(m["images"], tests);
    let short = models::segmenter::shipped::shipped_short_side().unwrap();
    assert_eq!(m["size"], short);
    // The interval holds the figure, for mIoU and every class with a figure, overall and
    // per dataset; the per-image matrices stay out.
    let inside = |value: &serde_json::Value, interval: &serde_json::Value| {
        let (v, lo, hi) = (
            value.as_f64().unwrap(),
            interval[0].as_f64().unwrap(),
            interval[1].as_f64().unwrap(),
        );
        assert!(lo <= v && v <= hi, "{v} outside [{lo}, {hi}]");
    };
    let datasets = m["per_dataset"].as_object().unwrap();
    assert_eq!(datasets.len(), 1);
    let dataset = &datasets["generated12"];
    for figures in [&m, dataset] {
        inside(&figures["miou"], &figures["ci95"]["miou"]);
        let classes = figures["per_class_iou"].as_object().unwrap();
        assert!(!classes.is_empty());
        for (class, iou) in classes {
            inside(iou, &figures["ci95"]["per_class_iou"][class]);
        }
        assert_eq!(
            figures["ci95"]["per_class_iou"].as_object().unwrap().len(),
            classes.len()
        );
    }
    let text = std::fs::read_to_string(first.join("metrics.json")).unwrap();
    assert!(!text.contains("per_image"), "{text}");
    let report = std::fs::read_to_string(first.join("report.md")).unwrap();
    assert!(report.contains("The shipped model"), "{report}");
    assert!(report.contains("of the `test` split"), "{report}");
    let ci = &m["ci95"]["miou"];
    let miou = format!(
        "{:.4} [{:.4}, {:.4}]",
        m["miou"].as_f64().unwrap(),
        ci[0].as_f64().unwrap(),
        ci[1].as_f64().unwrap()
    );
    assert!(
        report.contains(&format!("| mIoU | {miou} |")),
        "{miou}\n{report}"
    );
    assert!(
        stdout(&out).starts_with(&format!("mIoU {miou}, ")),
        "{}",
        stdout(&out)
    );
    // The same intervals on another run.
    let second = tmp.path().join("eval2");
    assert_success(&eval(&second), "segmenter eval again");
    assert_eq!(
        std::fs::read(second.join("metrics.json")).unwrap(),
        text.as_bytes()
    );

    // predict without --model: a label of each image's size, of class ids.
    let labels = tmp.path().join("predicted");
    let out = pipeline([
        "segmenter".as_ref(),
        "predict".as_ref(),
        data.join("images").as_os_str(),
        "--out".as_ref(),
        labels.as_os_str(),
    ]);
    assert_success(&out, "segmenter predict (shipped model)");
    let written = common::entries(&labels.join("labels"));
    assert_eq!(written.len(), 12, "{written:?}");
    for name in &written {
        let label = image::open(labels.join("labels").join(name))
            .unwrap()
            .to_luma8();
        let image = image::open(data.join("images").join(name)).unwrap();
        assert_eq!(label.dimensions(), (image.width(), image.height()));
        assert!(label.pixels().all(|p| p[0] < 5), "{name}");
    }
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

/// A JPEG cut short (a copy or download that stopped) is an unreadable image: the image
/// crate alone decodes it into a picture that is grey below the cut, which `predict` used to
/// label. Alone it is refused naming the file, writing nothing; in a folder it is refused
/// with a hint naming `--on-error skip`, which leaves it out and counts it. Shipped model.
#[test]
fn predict_refuses_a_truncated_jpeg() {
    let tmp = tempfile::tempdir().unwrap();
    let picture = image::RgbImage::from_fn(160, 120, |x, y| {
        image::Rgb([(x * 3 + y) as u8, ((x ^ y) * 5) as u8, (x * y % 251) as u8])
    });
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
        .encode_image(&picture)
        .unwrap();
    let photos = tmp.path().join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    let cut = photos.join("cut.jpg");
    std::fs::write(&cut, &jpeg[..jpeg.len() / 2]).unwrap();
    std::fs::write(photos.join("whole.jpg"), &jpeg).unwrap();
    let labels = tmp.path().join("labels");
    let predict = |input: &Path, extra: &[&str]| {
        let mut args: Vec<std::ffi::OsString> = vec![
            "segmenter".into(),
            "predict".into(),
            input.as_os_str().into(),
            "--out".into(),
            labels.clone().into_os_string(),
        ];
        args.extend(extra.iter().map(Into::into));
        pipeline(args)
    };

    let out = predict(&cut, &[]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(errors.len(), 1, "{err}");
    assert!(
        errors[0].contains("cut.jpg")
            && errors[0].contains("truncated JPEG: the data ends before its end-of-image marker"),
        "{err}"
    );
    assert!(err.lines().any(|l| l.starts_with("hint: ")), "{err}");
    assert!(!labels.exists(), "an output folder was left behind");

    let out = predict(&photos, &[]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert!(errors.len() == 1 && errors[0].contains("cut.jpg"), "{err}");
    assert!(err.contains("--on-error skip"), "{err}");
    assert!(!labels.exists(), "an output folder was left behind");

    let out = predict(&photos, &["--on-error", "skip"]);
    assert_success(&out, "segmenter predict --on-error skip");
    assert!(
        stdout(&out).starts_with("1 image labelled, 1 unreadable skipped in "),
        "{}",
        stdout(&out)
    );
    assert!(
        stderr(&out).contains("cut.jpg") && stderr(&out).contains("truncated JPEG"),
        "{}",
        stderr(&out)
    );
    assert_eq!(common::entries(&labels.join("labels")), ["whole.png"]);
}
