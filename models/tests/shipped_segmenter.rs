//! The shipped segmenter labels a committed picture as it did when it was shipped.
//!
//! `data/shipped_sample.png` is a generated image of the bundled campus (OpenStreetMap data,
//! ODbL) that the shipped model never trained on, `data/shipped_sample_label.png` its
//! generated labels, and `data/shipped_sample.json` the label histogram the shipped model
//! gave it on the default backend when it was shipped, with its pixel accuracy. A retrained
//! or broken model, a changed normalisation or a wrong resize moves the histogram.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::print_stdout)]

use std::path::PathBuf;

use burn::tensor::Device;
use models::segmenter::infer::{Inference, predict_label};
use models::segmenter::shipped::{shipped_model, shipped_short_side};

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

#[test]
fn the_shipped_model_labels_a_committed_image_to_its_histogram() {
    let image = image::open(data("shipped_sample.png")).unwrap().to_rgb8();
    let truth = image::open(data("shipped_sample_label.png"))
        .unwrap()
        .to_luma8();
    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("shipped_sample.json")).unwrap())
            .unwrap();

    let device = Device::flex();
    let (model, config) = shipped_model(&device).unwrap();
    let inference = Inference {
        short: Some(shipped_short_side().unwrap()),
        ..Inference::default()
    };
    let label = predict_label(&model, &config, &image, &inference, &device);
    assert_eq!(label.dimensions(), image.dimensions());

    let pixels = label.pixels().len() as f64;
    let mut histogram = [0u64; 5];
    for p in label.pixels() {
        histogram[usize::from(p[0])] += 1;
    }
    let recorded: Vec<u64> = expected["histogram"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    println!("histogram {histogram:?}, recorded {recorded:?}");
    // Kernels round differently across CPUs and thread counts: a pixel on a class border may
    // flip. A thousandth of the image per class is far below what any model change moves.
    for (class, (&got, &want)) in histogram.iter().zip(&recorded).enumerate() {
        let off = (got as f64 - want as f64).abs() / pixels;
        assert!(off <= 1e-3, "class {class}: {got} pixels, {want} recorded");
    }
    let correct = label
        .pixels()
        .zip(truth.pixels())
        .filter(|(p, t)| p[0] == t[0])
        .count() as f64;
    let accuracy = correct / pixels;
    let recorded_accuracy = expected["pixel_accuracy"].as_f64().unwrap();
    assert!(
        (accuracy - recorded_accuracy).abs() <= 1e-3,
        "pixel accuracy {accuracy}, recorded {recorded_accuracy}"
    );
    assert!(accuracy > 0.8, "pixel accuracy {accuracy}");
}
