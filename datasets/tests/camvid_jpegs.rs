//! Real camera JPEGs pass the check that refuses cut ones: every CamVid frame (SegNet's
//! 480x360 set, stored as baseline JPEGs by Pillow), a frame re-encoded by the image crate's
//! encoder, and the same files cut short are refused naming the file.
//!
//! Skips with a printed notice when `../shared/data` is absent.

#![allow(clippy::print_stdout, clippy::unwrap_used)]

mod common;

use std::path::{Path, PathBuf};

use datasets::image_io::{check_jpeg_whole, decode_image, read_rgb};

/// The CamVid frames (train and val), sorted.
fn frames(root: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = ["train", "val"]
        .iter()
        .flat_map(|split| std::fs::read_dir(root.join(split)).unwrap())
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "jpg"))
        .collect();
    files.sort();
    files
}

#[test]
fn camvid_jpegs_are_whole_and_cut_ones_are_refused() {
    let Some(root) = common::shared_data("segmentation/camvid") else {
        return;
    };
    let files = frames(&root);
    assert_eq!(files.len(), 367 + 101, "CamVid train + val");
    for file in &files {
        let bytes = std::fs::read(file).unwrap();
        assert_eq!(check_jpeg_whole(&bytes), Ok(()), "{}", file.display());
    }
    // Decoded in full: one frame of each sequence.
    for file in files.iter().step_by(120) {
        let image = read_rgb(file).unwrap();
        assert_eq!(image.dimensions(), (480, 360), "{}", file.display());
    }

    let first = &files[0];
    let bytes = std::fs::read(first).unwrap();
    for len in [500, bytes.len() / 2, bytes.len() - 2] {
        let err = decode_image(first, &bytes[..len]).unwrap_err().to_string();
        assert!(
            err.starts_with(&first.display().to_string())
                && err.contains("truncated JPEG: the data ends before its end-of-image marker"),
            "{err}"
        );
    }

    // The image crate's own (baseline) encoding of a real frame: read, and refused when cut.
    let frame = read_rgb(first).unwrap();
    let mut encoded = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut encoded, 85)
        .encode_image(&frame)
        .unwrap();
    let path = Path::new("reencoded.jpg");
    let read = decode_image(path, &encoded).unwrap();
    assert_eq!((read.width(), read.height()), (480, 360));
    let err = decode_image(path, &encoded[..encoded.len() - 100])
        .unwrap_err()
        .to_string();
    assert!(err.contains("reencoded.jpg: truncated JPEG"), "{err}");
}
