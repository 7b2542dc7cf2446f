//! Bad input to `pipeline dataset import` gives one clear error that
//! names the file, exit code 1 and no output folder; under `--on-error skip` the broken
//! items are left out and counted, and the good ones are imported. Needs no shared data.

#![allow(clippy::unwrap_used, clippy::print_stdout)]

mod common;

use std::path::{Path, PathBuf};

use common::{assert_success, entries, pipeline, read_json, stderr};
use image::{GrayImage, Luma, Rgb, RgbImage};

const W: u32 = 32;
const H: u32 = 24;

/// A source folder with `images/` and `labels/` in our class ids: three good pairs.
fn good_source(root: &Path) -> PathBuf {
    let src = root.join("src");
    std::fs::create_dir_all(src.join("images")).unwrap();
    std::fs::create_dir_all(src.join("labels")).unwrap();
    for i in 0..3u8 {
        RgbImage::from_pixel(W, H, Rgb([40 * i, 90, 200]))
            .save(src.join(format!("images/good{i}.png")))
            .unwrap();
        GrayImage::from_fn(W, H, |x, _| Luma([if x < W / 2 { 0 } else { 4 }]))
            .save(src.join(format!("labels/good{i}.png")))
            .unwrap();
    }
    src
}

fn import(src: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    pipeline()
        .args(["--rerun", "off", "dataset", "import", "folders"])
        .arg(src)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// The run failed cleanly: exit 1, one `error:` line naming `file`, a hint, no panic, and
/// nothing written (no output folder, no temporary sibling).
fn assert_clean_failure(out: &std::process::Output, root: &Path, dest: &Path, file: &str) {
    let err = stderr(out);
    println!("{file}: {err}");
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(errors.len(), 1, "one error line expected:\n{err}");
    assert!(errors[0].contains(file), "the error names {file}:\n{err}");
    assert!(err.lines().any(|l| l.starts_with("hint:")), "{err}");
    assert!(!dest.exists(), "an output folder was left behind");
    let name = dest.file_name().unwrap().to_string_lossy().into_owned();
    let leftovers: Vec<String> = entries(root)
        .into_iter()
        .filter(|n| n.starts_with('.') && n.contains(&name))
        .collect();
    assert!(
        leftovers.is_empty(),
        "temporary folders left behind: {leftovers:?}"
    );
}

#[test]
fn each_kind_of_broken_item_is_a_clear_error_or_a_counted_skip() {
    // (what breaks, the file the error must name, how to break it)
    type Breakage = (&'static str, &'static str, fn(&Path));
    let cases: [Breakage; 5] = [
        ("label of the wrong size", "bad.png", |src| {
            RgbImage::new(W, H)
                .save(src.join("images/bad.png"))
                .unwrap();
            GrayImage::new(W / 2, H)
                .save(src.join("labels/bad.png"))
                .unwrap();
        }),
        ("label with an unknown id", "bad.png", |src| {
            RgbImage::new(W, H)
                .save(src.join("images/bad.png"))
                .unwrap();
            GrayImage::from_pixel(W, H, Luma([7]))
                .save(src.join("labels/bad.png"))
                .unwrap();
        }),
        ("missing image", "bad", |src| {
            // A label whose image is missing: the pair is listed from the labels folder.
            GrayImage::new(W, H)
                .save(src.join("labels/bad.png"))
                .unwrap();
        }),
        ("image file that is not an image", "bad.png", |src| {
            std::fs::write(src.join("images/bad.png"), b"this is not a PNG").unwrap();
            GrayImage::new(W, H)
                .save(src.join("labels/bad.png"))
                .unwrap();
        }),
        // Cut in its scan data: the image crate alone decodes it into a grey-bottomed
        // picture, and the importer copies a JPEG's bytes through.
        ("truncated JPEG image", "bad.jpg", |src| {
            let picture = RgbImage::from_fn(W * 4, H * 4, |x, y| {
                Rgb([(x * 3 + y) as u8, ((x ^ y) * 5) as u8, (x * y % 251) as u8])
            });
            let mut jpeg = Vec::new();
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
                .encode_image(&picture)
                .unwrap();
            std::fs::write(src.join("images/bad.jpg"), &jpeg[..jpeg.len() / 2]).unwrap();
            GrayImage::new(W * 4, H * 4)
                .save(src.join("labels/bad.png"))
                .unwrap();
        }),
    ];
    for (what, file, breakage) in cases {
        println!("== {what}");
        let tmp = tempfile::tempdir().unwrap();
        let src = good_source(tmp.path());
        breakage(&src);
        let dest = tmp.path().join("out");

        let failed = import(&src, &dest, &[]);
        assert_clean_failure(&failed, tmp.path(), &dest, file);

        let skipped = import(&src, &dest, &["--on-error", "skip"]);
        assert_success(&skipped, what);
        let report = read_json(&dest.join("import_report.json"));
        assert_eq!(report["items"], 3, "{what}: the good items are imported");
        let skips = report["skipped"].as_array().unwrap();
        assert_eq!(skips.len(), 1, "{what}: one counted skip: {skips:?}");
        assert!(skips[0].to_string().contains("bad"), "{what}: {skips:?}");
        assert!(
            stderr(&skipped).contains("skipped"),
            "{what}: the skip is reported"
        );
    }
}

#[test]
fn an_unreadable_class_map_is_an_error_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let src = good_source(tmp.path());
    let map = tmp.path().join("broken_map.toml");
    std::fs::write(
        &map,
        "name = \"x\"\nclass = [ { id = 0, target = \"nowhere\" } ]\n",
    )
    .unwrap();
    let dest = tmp.path().join("out");
    let out = import(&src, &dest, &["--class-map", map.to_str().unwrap()]);
    assert_clean_failure(&out, tmp.path(), &dest, "broken_map.toml");
    let missing = import(&src, &dest, &["--class-map", "no_such_map.toml"]);
    assert_clean_failure(&missing, tmp.path(), &dest, "no_such_map.toml");
}
