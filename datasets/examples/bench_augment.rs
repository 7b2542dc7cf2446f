//! Times the thesis's augmentation chain in memory, for the comparison with albumentations
//! (`scripts/bench_datasets.py` runs this in release mode next to the same chain in
//! albumentations, on the same images, with the same number of threads).
//!
//! The images and labels are decoded once, untimed. One run draws the ops of every image
//! (thesis preset: crop 80 % of each side, rotation ±10°, flip p 0.5, Gaussian blur σ 0.5-1.5
//! p 0.5, Gaussian noise σ 5-15 p 0.5) from the image's own seed and applies them to image
//! and label; images run in parallel on a rayon pool of `--threads` threads.
//!
//! Usage: `bench_augment [--camvid DIR] [--images 100] [--runs 5] [--threads 2]`; prints one
//! JSON object (images per second of each run and their median).

#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::path::{Path, PathBuf};
use std::time::Instant;

use datasets::augment::{AugmentConfig, Preset, apply};
use datasets::image_io::read_rgb;
use image::GrayImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Times the thesis augmentation chain on CamVid train images.
#[derive(Debug, clap::Parser)]
struct Args {
    /// The CamVid folder (SegNet layout, with train.txt).
    #[arg(long, default_value = "../shared/data/segmentation/camvid")]
    camvid: PathBuf,
    /// How many train images (the first ones of train.txt).
    #[arg(long, default_value_t = 100)]
    images: usize,
    /// Timed runs (after one untimed warm-up).
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Threads of the rayon pool.
    #[arg(long, default_value_t = 2)]
    threads: usize,
}

fn main() {
    let args = <Args as clap::Parser>::parse();
    if let Err(e) = run(&args.camvid, args.images, args.runs, args.threads) {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run(camvid: &Path, count: usize, runs: usize, threads: usize) -> Result<(), String> {
    let list = std::fs::read_to_string(camvid.join("train.txt"))
        .map_err(|e| format!("{}: {e}", camvid.join("train.txt").display()))?;
    let mut pairs = Vec::new();
    for line in list.lines().take(count) {
        let mut parts = line.split_whitespace();
        let (Some(image), Some(label)) = (parts.next(), parts.next()) else {
            return Err(format!("train.txt: bad line {line:?}"));
        };
        let image = read_rgb(&camvid.join(image)).map_err(|e| e.to_string())?;
        let label: GrayImage = image::open(camvid.join(label))
            .map_err(|e| format!("{label}: {e}"))?
            .into_luma8();
        pairs.push((image, label));
    }
    let config = AugmentConfig::preset(Preset::Thesis);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| e.to_string())?;
    let mut rates = Vec::new();
    // One untimed warm-up run, then the timed ones.
    for run in 0..=runs {
        let start = Instant::now();
        let pixels: usize = pool.install(|| {
            pairs
                .par_iter()
                .enumerate()
                .map(|(i, (image, label))| {
                    let seed = (run as u64) << 32 | i as u64;
                    let ops = config.sample(
                        &mut ChaCha8Rng::seed_from_u64(seed),
                        image.width(),
                        image.height(),
                    );
                    match apply(&ops, image, label) {
                        Ok((out, _)) => out.as_raw().len(),
                        Err(_) => 0,
                    }
                })
                .sum()
        });
        let seconds = start.elapsed().as_secs_f64();
        if pixels == 0 {
            return Err("no image was augmented".into());
        }
        if run > 0 {
            rates.push(pairs.len() as f64 / seconds);
        }
    }
    let mut sorted = rates.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    println!(
        "{}",
        serde_json::json!({
            "tool": "ours",
            "images": pairs.len(),
            "size": [pairs[0].0.width(), pairs[0].0.height()],
            "threads": threads,
            "runs_images_per_second": rates,
            "median_images_per_second": median,
        })
    );
    Ok(())
}
