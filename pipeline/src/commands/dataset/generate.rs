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
use datasets::generate::{GENERATE_STAGE, GeneratedItem, Generator, Workspace};
use datasets::image_io::{colorize_label, encode_label_png, encode_rgb_png};
use datasets::manifest::{
    CARD_FILE, Card, IMAGES_DIR, Item, LABELS_DIR, MANIFEST_FILE, PREVIEWS_DIR, write_dataset_files,
};
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use serde_json::json;

pub use super::generate_args::{GenerateArgs, resolve_config};
use crate::commands::Context;
use crate::error::CliError;
use crate::inputs::{BUNDLED_CAMPUS_FILE, BUNDLED_CAMPUS_NAME, bundled_campus, load_or_import_map};
use crate::output::{AtomicDir, Markers};
use crate::recording;

/// Folder of the top-down label views.
pub const TOPDOWN_DIR: &str = "topdown";
/// A folder holding either file is an earlier dataset that may be replaced.
const DATASET_MARKERS: Markers = &[CARD_FILE, MANIFEST_FILE];
/// How many items are logged to the rerun recording.
const RECORDED_SAMPLES: u64 = 8;

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
    // The map, and what the card records of it: the file's name, or the embedded campus.
    let (map, map_shown, map_name) = match &args.map {
        Some(path) => {
            progress.step(&format!("reading {}", path.display()));
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
            (load_or_import_map(path)?, path.clone(), name)
        }
        None => {
            progress.step(&format!(
                "reading the bundled campus ({BUNDLED_CAMPUS_FILE}, embedded)"
            ));
            let shown = PathBuf::from(BUNDLED_CAMPUS_NAME);
            (
                bundled_campus()?,
                shown,
                Some(BUNDLED_CAMPUS_NAME.to_owned()),
            )
        }
    };

    progress.step("building the scene");
    let generator = Generator::new(&map, config.clone(), ctx.global.seed).map_err(|e| {
        CliError::file(
            &map_shown,
            e.to_string(),
            "give a map with car roads, or leave out --map to render the bundled campus",
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
            "map": map_name,
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
        ctx.global.seed,
    );
    write_dataset_files(dir.path(), &card, &items)
        .map_err(|e| CliError::new(e.to_string(), "check free disk space and permissions"))?;

    if ctx.global.rerun != crate::args::RerunMode::Off {
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
