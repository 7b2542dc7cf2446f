//! Times the segmenter's training input: one item's augmentation (resize to the short side
//! `size × scale`, random crop, flip) as `segmenter train` does it, the crop window alone
//! resampled by the datasets crate's warp, next to the way before: the whole item enlarged
//! with image's resize (Triangle filter), then cropped. Also times `load_batch` (decode and
//! augment a batch of 8) on a rayon pool of 2 threads.
//!
//! Usage (release): `bench_segmenter_input DATASET [SIZE] [CROP]`, e.g.
//! `cargo run --release -p models --example bench_segmenter_input -- runs/gen2000 384 256`;
//! prints one JSON object of milliseconds.

#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::process::ExitCode;
use std::time::Instant;

use image::imageops;
use models::segmenter::data::{
    Augment, Sample, Source, SourceSpec, Split, epoch_draws, load_batch, resize_sample,
};

/// Items decoded and augmented per timing.
const ITEMS: usize = 400;
const BATCH: usize = 8;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(dataset) = args.first() else {
        eprintln!("usage: bench_segmenter_input DATASET [SIZE] [CROP]");
        return ExitCode::FAILURE;
    };
    let number =
        |i: usize, default: u32| args.get(i).and_then(|a| a.parse().ok()).unwrap_or(default);
    let (size, crop) = (number(1, 384), number(2, 256));
    match run(dataset, size, crop) {
        Ok(json) => {
            println!("{json}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(dataset: &str, size: u32, crop: u32) -> Result<String, Box<dyn std::error::Error>> {
    let spec = SourceSpec::parse(dataset)?;
    let sources = vec![Source::open(&spec, Split::Train)?];
    let augment = Augment {
        size,
        crop,
        scale: [1.0, 1.0],
        flip: true,
        balanced_crops: 0.0,
    };
    let draws = epoch_draws(&sources, ITEMS, 1, 0);
    let samples = draws
        .iter()
        .map(|&(_, item)| sources[0].load(item))
        .collect::<Result<Vec<_>, _>>()?;
    let per_item = |start: Instant| start.elapsed().as_secs_f64() * 1000.0 / ITEMS as f64;

    let start = Instant::now();
    for (draw, sample) in samples.iter().enumerate() {
        std::hint::black_box(augment.apply(sample, 1, 0, draw as u64)?);
    }
    let crop_window = per_item(start);

    let start = Instant::now();
    for sample in &samples {
        std::hint::black_box(resize_whole_then_crop(sample, size, crop));
    }
    let whole_image = per_item(start);

    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build()?;
    let start = Instant::now();
    pool.install(|| {
        for (b, chunk) in draws.chunks(BATCH).enumerate() {
            std::hint::black_box(load_batch(&sources, chunk, b * BATCH, &augment, 1, 0)?);
        }
        Ok::<(), models::segmenter::SegmenterError>(())
    })?;
    let batch = per_item(start) * BATCH as f64;
    Ok(format!(
        "{{\"dataset\": {dataset:?}, \"size\": {size}, \"crop\": {crop}, \"items\": {ITEMS}, \
         \"augment_ms_per_item\": {crop_window:.3}, \
         \"resize_whole_then_crop_ms_per_item\": {whole_image:.3}, \
         \"load_batch_of_8_on_2_threads_ms\": {batch:.2}}}"
    ))
}

/// The way before: enlarge the whole item, then copy the crop's pixels (top-left crop; the
/// cost does not depend on where).
fn resize_whole_then_crop(sample: &Sample, size: u32, crop: u32) -> Sample {
    let resized = resize_sample(sample, size);
    Sample {
        id: sample.id.clone(),
        image: imageops::crop_imm(&resized.image, 0, 0, crop, crop).to_image(),
        label: imageops::crop_imm(&resized.label, 0, 0, crop, crop).to_image(),
    }
}
