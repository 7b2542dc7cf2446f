//! Times log projection (the goal: at least 20,000 frames per second on 2
//! cores): an MCAP log (e.g. an INTERACTION recording through `pipeline logs convert`) is
//! read and decoded once, untimed; then every track in turn is the ego and all its frames
//! are drawn in the bird's-eye representation (84 × 84, four layers) on a rayon pool of
//! `--threads` threads, as `pipeline logs project` does. Prints one JSON object: frames
//! drawn per run, seconds and frames per second of each run, and the median.
//!
//! Usage: `bench_project --log ft_000.mcap --map DR_USA_Roundabout_FT.osm [--runs 5] [--threads 2]`

#![allow(clippy::print_stdout)]

use std::path::PathBuf;
use std::time::Instant;

use clap::Parser;
use logs::decode::read_decoded;
use logs::noise::NoiseConfig;
use logs::project::{log_frames, project, track_lengths};
use logs::source::{Log, ReadOptions};
use sim::render::{BevConfig, BevRenderer};

#[derive(Debug, Parser)]
struct Args {
    #[arg(long)]
    log: PathBuf,
    /// The log's map (Lanelet2 .osm, or any OSM file).
    #[arg(long)]
    map: PathBuf,
    #[arg(long, default_value_t = 5)]
    runs: usize,
    #[arg(long, default_value_t = 2)]
    threads: usize,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    let map = maps::import_file(&args.map, &maps::ImportOptions::default())?;
    let log = Log::open(&args.log)?;
    let frames = log_frames(&read_decoded(&log, &ReadOptions::default())?, None);
    let tracks: Vec<u32> = track_lengths(&frames).into_keys().collect();
    let renderer = BevRenderer::new(&map, map.bounds(), BevConfig::default())?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads)
        .build()?;
    let mut runs = Vec::new();
    let mut drawn = 0usize;
    for _ in 0..args.runs {
        let start = Instant::now();
        drawn = pool.install(|| {
            tracks
                .iter()
                .map(|&ego| {
                    project(&map, &renderer, &frames, ego, &NoiseConfig::default())
                        .0
                        .len()
                })
                .sum()
        });
        let seconds = start.elapsed().as_secs_f64();
        runs.push((seconds, drawn as f64 / seconds));
    }
    let mut rates: Vec<f64> = runs.iter().map(|r| r.1).collect();
    rates.sort_by(f64::total_cmp);
    let median = rates[rates.len() / 2];
    println!(
        "{}",
        serde_json::json!({
            "log": args.log, "tracks": tracks.len(), "frames_per_run": drawn,
            "threads": args.threads,
            "runs": runs.iter().map(|(s, r)| serde_json::json!({"seconds": s, "frames_per_second": r})).collect::<Vec<_>>(),
            "median_frames_per_second": median,
        })
    );
    Ok(())
}
