//! `pipeline dataset generate`: labelled front-camera images rendered from a drivable map.
//!
//! Items are made in parallel (rayon); each depends only on (seed, config, map, index), so
//! the folder's bytes are the same whatever the thread count. The folder is written
//! atomically: `images/`, `labels/`, optional `topdown/` and `previews/`, then
//! `manifest.jsonl` and `card.json`.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::{Context as _, Result};
use datasets::classes::Class;
use datasets::generate::{GENERATE_STAGE, GenerateConfig, GeneratedItem, Generator, Workspace};
use datasets::image_io::{colorize_label, encode_label_png, encode_rgb_png};
use datasets::manifest::{
    CARD_FILE, Card, IMAGES_DIR, Item, LABELS_DIR, MANIFEST_FILE, PREVIEWS_DIR, write_dataset_files,
};
use datasets::render::TopdownConfig;
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use serde_json::json;

use crate::commands::Context;
use crate::error::CliError;
use crate::inputs::load_or_import_map;
use crate::output::{AtomicDir, Markers};
use crate::recording;

/// The map used when `--map` is not given (bundled with the repository).
pub const DEFAULT_MAP: &str = "data/osm/northwestern_nu.osm.pbf";
/// Folder of the top-down label views.
pub const TOPDOWN_DIR: &str = "topdown";
/// A folder holding either file is an earlier dataset that may be replaced.
const DATASET_MARKERS: Markers = &[CARD_FILE, MANIFEST_FILE];
/// How many items are logged to the rerun recording.
const RECORDED_SAMPLES: u64 = 8;

#[derive(Debug, clap::Args)]
pub struct GenerateArgs {
    /// A map (map.json, map.bin or a map folder from `pipeline map import`), or an OSM file
    /// (.osm, .osm.gz, .osm.pbf) imported on the fly with the default car profile.
    #[arg(long, value_name = "MAP|OSM", default_value = DEFAULT_MAP)]
    pub map: PathBuf,

    /// Output folder (written atomically; replaced if it holds an earlier dataset).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Number of images.
    #[arg(long, default_value_t = 100)]
    pub count: u64,

    /// Image size, WIDTHxHEIGHT [default: 480x270].
    #[arg(long, value_name = "WxH")]
    pub size: Option<String>,

    /// Camera height above the road, metres [default: 1.6].
    #[arg(long, value_name = "M")]
    pub camera_height: Option<f64>,

    /// Downward tilt of the camera, degrees [default: 4].
    #[arg(long, value_name = "DEG", allow_hyphen_values = true)]
    pub pitch: Option<f64>,

    /// Horizontal field of view, degrees [default: 69].
    #[arg(long, value_name = "DEG")]
    pub fov: Option<f64>,

    /// Pedestrians in a view, MIN-MAX (uniform, inclusive) [default: 0-10].
    #[arg(long, value_name = "MIN-MAX")]
    pub pedestrians: Option<String>,

    /// Share of pedestrians that cross the road at an intersection when one is in view
    /// [default: 0.3].
    #[arg(long, value_name = "SHARE")]
    pub crossing_share: Option<f64>,

    /// Road users (vehicles and pedestrians) stand within this distance of the camera,
    /// metres [default: 70]; a shorter range gives nearer, larger people and cars.
    #[arg(long, value_name = "M")]
    pub range: Option<f64>,

    /// Also write the top-down label view of each scene (topdown/<id>.png, ego-centred).
    #[arg(long)]
    pub topdown: bool,

    /// Also write colour previews of the labels (previews/<id>.png).
    #[arg(long)]
    pub previews: bool,

    /// One plain look for every image (no colour, weather, wear or camera jitter).
    #[arg(long)]
    pub no_randomise: bool,

    /// Make only shard i of n of the --count items (for running across machines); merge
    /// the n shard folders with `pipeline dataset merge --shards` (docs/scaling.md).
    #[arg(long, value_name = "i/n", value_parser = datasets::shard::Shard::parse)]
    pub shard: Option<datasets::shard::Shard>,
}

/// "480x270" to (480, 270).
fn parse_size(s: &str) -> std::result::Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT such as 480x270, not `{s}`"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|_| format!("expected WIDTHxHEIGHT such as 480x270, not `{s}`"))
    };
    Ok((parse(w)?, parse(h)?))
}

/// The generation config from the defaults and the command line.
pub fn resolve_config(args: &GenerateArgs) -> Result<GenerateConfig> {
    let mut config = GenerateConfig::default();
    if let Some(size) = &args.size {
        let (w, h) = parse_size(size)
            .map_err(|m| CliError::new(format!("--size: {m}"), "e.g. --size 512x512"))?;
        config.camera.width = w;
        config.camera.height = h;
    }
    if let Some(v) = args.camera_height {
        config.camera.height_m = v;
    }
    if let Some(v) = args.pitch {
        config.camera.pitch_deg = v;
    }
    if let Some(v) = args.fov {
        config.camera.hfov_deg = v;
    }
    if let Some(range) = &args.pedestrians {
        config.traffic.pedestrians = parse_range(range)
            .map_err(|m| CliError::new(format!("--pedestrians: {m}"), "e.g. --pedestrians 4-16"))?;
    }
    if let Some(v) = args.crossing_share {
        config.traffic.crossing_share = v;
    }
    if let Some(v) = args.range {
        config.traffic.range_m = v;
    }
    if args.topdown {
        config.topdown = Some(TopdownConfig::default());
    }
    config.randomise.enabled = !args.no_randomise;
    config.check().map_err(|e| {
        CliError::new(
            e.to_string(),
            "see `pipeline dataset generate --help` for the ranges",
        )
    })?;
    Ok(config)
}

/// "4-16" to (4, 16).
fn parse_range(s: &str) -> std::result::Result<(u32, u32), String> {
    let bad = || format!("expected MIN-MAX such as 0-10, not `{s}`");
    let (lo, hi) = s.split_once('-').ok_or_else(bad)?;
    let parse = |v: &str| v.trim().parse::<u32>().map_err(|_| bad());
    Ok((parse(lo)?, parse(hi)?))
}

/// The manifest entry of an item.
fn manifest_item(item: &GeneratedItem, topdown: bool) -> Result<Item> {
    let mut params =
        serde_json::to_value(&item.params).context("item params: serialisation failed")?;
    if topdown && let Some(obj) = params.as_object_mut() {
        obj.insert(
            "topdown".into(),
            json!(format!("{TOPDOWN_DIR}/{}.png", item.id())),
        );
    }
    Ok(Item::new(
        item.id(),
        "generate",
        item.image.dimensions(),
        params,
    ))
}

/// Writes one file of the dataset being made.
fn write(dir: &Path, relative: &str, bytes: &[u8]) -> Result<()> {
    let path = dir.join(relative);
    std::fs::write(&path, bytes).map_err(|e| {
        CliError::file(
            &path,
            format!("cannot write: {e}"),
            "check free disk space and permissions",
        )
        .into()
    })
}

/// Makes item `index`, writes its files, and returns its manifest entry (and the image and
/// label when it is one of the recorded samples).
fn make_item(
    generator: &Generator<'_>,
    work: &mut Workspace,
    dir: &Path,
    index: u64,
    previews: bool,
) -> Result<(Item, Option<(RgbImage, GrayImage)>)> {
    let item = generator.item(index, work).map_err(|e| {
        CliError::new(
            format!("item {index}: {e}"),
            "this is a bug; please report it",
        )
    })?;
    let id = item.id();
    write(
        dir,
        &format!("{IMAGES_DIR}/{id}.png"),
        &encode_rgb_png(&item.image),
    )?;
    write(
        dir,
        &format!("{LABELS_DIR}/{id}.png"),
        &encode_label_png(&item.label),
    )?;
    if let Some(top) = &item.topdown {
        write(
            dir,
            &format!("{TOPDOWN_DIR}/{id}.png"),
            &encode_label_png(top),
        )?;
    }
    if previews {
        write(
            dir,
            &format!("{PREVIEWS_DIR}/{id}.png"),
            &encode_rgb_png(&colorize_label(&item.label)),
        )?;
    }
    let entry = manifest_item(&item, item.topdown.is_some())?;
    let sample = (index < RECORDED_SAMPLES).then_some((item.image, item.label));
    Ok((entry, sample))
}

pub fn run(ctx: &Context<'_>, args: &GenerateArgs) -> Result<()> {
    let config = resolve_config(args)?;
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, DATASET_MARKERS)?;
    let mut progress = ctx.ui.progress("dataset generate");
    progress.step(&format!("reading {}", args.map.display()));
    let map = load_or_import_map(&args.map)?;

    progress.step("building the scene");
    let generator = Generator::new(&map, config.clone(), ctx.cli.seed).map_err(|e| {
        CliError::file(
            &args.map,
            e.to_string(),
            "give a map with car roads (e.g. the bundled data/osm/northwestern_nu.osm.pbf)",
        )
    })?;
    let scene = generator.scene();
    progress.note(&format!(
        "{} ground polygons, {} buildings and trees, {} car lanes",
        scene.ground.len(),
        scene.props.len(),
        scene.car_lanes.len()
    ));

    let dir = AtomicDir::create(&out, DATASET_MARKERS)?;
    let mut folders = vec![IMAGES_DIR, LABELS_DIR];
    if config.topdown.is_some() {
        folders.push(TOPDOWN_DIR);
    }
    if args.previews {
        folders.push(PREVIEWS_DIR);
    }
    for f in folders {
        let p = dir.path().join(f);
        std::fs::create_dir_all(&p).map_err(|e| {
            CliError::file(
                &p,
                format!("cannot create folder: {e}"),
                "check permissions",
            )
        })?;
    }

    let indices = args
        .shard
        .map_or(0..args.count, |shard| shard.range(args.count));
    let to_render = indices.end - indices.start;
    progress.step(&format!(
        "rendering {to_render} images of {}x{}",
        config.camera.width, config.camera.height
    ));
    let start = Instant::now();
    let done = AtomicU64::new(0);
    let results: Vec<(Item, Option<(RgbImage, GrayImage)>)> = indices
        .into_par_iter()
        .map_init(Workspace::default, |work, index| {
            let r = make_item(&generator, work, dir.path(), index, args.previews);
            let n = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress.items("rendered", n, to_render);
            r
        })
        .collect::<Result<_>>()?;
    let seconds = start.elapsed().as_secs_f64();

    let mut items = Vec::with_capacity(results.len());
    let mut samples = Vec::new();
    for (item, sample) in results {
        if let Some(s) = sample {
            samples.push((item.id.clone(), s));
        }
        items.push(item);
    }
    progress.step("writing the manifest");
    let card = Card::new(
        out.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "generated".into()),
        &Class::ALL,
        json!({
            "tool": "pipeline dataset generate",
            "pipeline_version": env!("CARGO_PKG_VERSION"),
            "map": args.map.file_name().map(|n| n.to_string_lossy().into_owned()),
            "map_lanes": map.lanes.len(),
            "stage": GENERATE_STAGE,
            "licence": "map data © OpenStreetMap contributors (ODbL 1.0) when made from OSM",
        }),
        match args.shard {
            None => json!({ "count": args.count, "generate": config }),
            Some(shard) => json!({
                "count": args.count,
                "generate": config,
                datasets::shard::SHARD_KEY: shard,
            }),
        },
        ctx.cli.seed,
    );
    write_dataset_files(dir.path(), &card, &items)
        .map_err(|e| CliError::new(e.to_string(), "check free disk space and permissions"))?;

    if ctx.cli.rerun != crate::cli::RerunMode::Off {
        let rec = ctx.open_recording(Some(dir.path()))?;
        if let Some(stream) = rec.stream() {
            recording::log_class_context(stream)?;
            for (frame, (_id, (image, label))) in samples.iter().enumerate() {
                recording::log_sample(stream, "generate", frame as i64, image, label)?;
            }
        }
        rec.finish()?;
    }
    let dest = dir.commit()?;
    drop(progress);
    ctx.ui.info(&format!(
        "dataset generate: wrote {} images of {}x{} to {} in {seconds:.2} s ({:.0} images/s on {} threads)",
        items.len(),
        config.camera.width,
        config.camera.height,
        dest.display(),
        items.len() as f64 / seconds.max(1e-9),
        rayon::current_num_threads(),
    ));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("480x270"), Ok((480, 270)));
        assert_eq!(parse_size("512X512"), Ok((512, 512)));
        assert!(parse_size("512").is_err());
        assert!(parse_size("ax2").is_err());
    }

    #[test]
    fn pedestrian_ranges_parse_and_bad_traffic_is_refused() {
        assert_eq!(parse_range("4-16"), Ok((4, 16)));
        assert!(parse_range("4").is_err());
        assert!(parse_range("-3-4").is_err());
        let mut config = GenerateConfig::default();
        config.traffic.pedestrians = (9, 3);
        assert!(config.check().is_err());
        config.traffic.pedestrians = (3, 9);
        config.traffic.crossing_share = 1.5;
        assert!(config.check().is_err());
        config.traffic.crossing_share = 0.6;
        assert!(config.check().is_ok());
        config.traffic.range_m = 0.0;
        assert!(config.check().is_err());
        config.traffic.range_m = 25.0;
        assert!(config.check().is_ok());
    }
}
