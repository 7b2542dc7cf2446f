//! Public label sets into our classes: CamVid, Cityscapes, Mapillary Vistas, CARLA renders,
//! binary lane masks and plain image/label folders, each through a [`ClassMap`].
//!
//! Each item's image is copied byte for byte when it is an RGB PNG or JPEG (re-encoded as
//! PNG otherwise), and its label is mapped and written as an L8 PNG. The report counts
//! pixels per source class and per target class; shares are percent of *all* pixels of
//! the written labels, ignore (255) included in the denominator, as CamVid's published
//! shares are (a second figure leaves ignore out).

pub mod classmap;
pub mod layout;

use std::path::{Path, PathBuf};

use image::{DynamicImage, GrayImage};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use classmap::{ClassMap, Encoding, SourceClass};
pub use layout::{LayoutOptions, SourceFormat, SourcePair, list_pairs};

use crate::classes::{Class, IGNORE, label_name};
use crate::error::{DatasetError, OnError, Result, Skipped, apply_policy};
use crate::image_io::{decode_image, encode_label_png, encode_rgb_png, write_bytes};
use crate::manifest::{Card, IMAGES_DIR, Item, LABELS_DIR, write_dataset_files};
use crate::stats::LabelHistogram;

/// The report's file name in the output folder.
pub const IMPORT_REPORT: &str = "import_report.json";

/// What `import` does.
#[derive(Debug, Clone)]
pub struct ImportOptions {
    /// Dataset name for the card.
    pub name: String,
    pub format: SourceFormat,
    pub layout: LayoutOptions,
    pub class_map: ClassMap,
    /// A Mapillary-style config JSON to check the class map's names against.
    pub source_config: Option<PathBuf>,
    /// Binary lane masks (`<dir>/<item id>.png`) merged onto the road pixels.
    pub lane_masks: Option<PathBuf>,
    pub on_error: OnError,
}

/// Pixels of one source class.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceClassPixels {
    pub id: u8,
    pub name: String,
    pub target: String,
    pub pixels: u64,
    pub percent_of_all: f64,
}

/// Pixels of one target label value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TargetClassPixels {
    pub id: u8,
    pub name: String,
    pub pixels: u64,
    /// Percent of all pixels of the written labels (ignore included in the denominator).
    pub percent_of_all: f64,
    /// Percent of non-ignore pixels (None for the ignore row).
    pub percent_of_labelled: Option<f64>,
}

/// `import_report.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImportReport {
    pub format: SourceFormat,
    pub class_map: String,
    pub items: usize,
    pub skipped: Vec<Skipped>,
    pub pixels: u64,
    pub share_definition: String,
    /// Every source class of the map with its pixels (before lane-mask merging).
    pub source_classes: Vec<SourceClassPixels>,
    /// Source classes with pixels that the map sends to ignore (no class of ours).
    pub unmapped_source_classes: Vec<SourceClassPixels>,
    /// Our classes and ignore, in the written labels.
    pub target_classes: Vec<TargetClassPixels>,
    /// Target classes the source labels at all (the card's `labelable`).
    pub labelable: Vec<String>,
    /// Lane-mask pixels merged onto road, when lane masks were given.
    pub lane_mask_pixels_merged: Option<u64>,
}

pub const SHARE_DEFINITION: &str = "percent_of_all = 100 * pixels / all pixels of the written labels (ignore 255 included in the denominator, as CamVid's published shares include Unlabelled); percent_of_labelled leaves ignore pixels out";

/// What one pair gave.
#[derive(Debug)]
struct Imported {
    item: Item,
    source: LabelHistogram,
    target: LabelHistogram,
    merged: u64,
}

/// Everything an import made (the files are already written).
#[derive(Debug, Clone)]
pub struct ImportOutcome {
    pub items: Vec<Item>,
    pub card: Card,
    pub report: ImportReport,
}

/// Imports a source into `out_dir` (which must exist): images, labels, manifest, card and
/// report. With [`OnError::Fail`] the first broken item (in id order) is the error.
pub fn import(opts: &ImportOptions, out_dir: &Path) -> Result<ImportOutcome> {
    import_with_progress(opts, out_dir, &|| {})
}

/// [`import`], calling `item_done` after each pair of the source (from the worker threads;
/// [`list_pairs`] tells how many there are).
pub fn import_with_progress(
    opts: &ImportOptions,
    out_dir: &Path,
    item_done: &(dyn Fn() + Sync),
) -> Result<ImportOutcome> {
    if let Some(config) = &opts.source_config {
        let json = std::fs::read_to_string(config).map_err(|e| DatasetError::io(config, e))?;
        opts.class_map.check_source_config(config, &json)?;
    }
    if let Some(masks) = &opts.lane_masks
        && !masks.is_dir()
    {
        return Err(DatasetError::invalid(masks, "is not a lane-mask folder"));
    }
    let pairs = list_pairs(opts.format, &opts.layout)?;
    let lane_map = ClassMap::load("lane_mask")?;
    let results: Vec<(String, Result<Imported>)> = pairs
        .par_iter()
        .map(|pair| {
            let imported = import_pair(pair, opts, &lane_map, out_dir);
            item_done();
            (pair.id.clone(), imported)
        })
        .collect();
    let (imported, skipped) = apply_policy(results, opts.on_error)?;
    if imported.is_empty() {
        return Err(DatasetError::invalid(
            &opts.layout.root,
            format!("no item could be imported ({} skipped)", skipped.len()),
        ));
    }

    let mut source = LabelHistogram::default();
    let mut target = LabelHistogram::default();
    let mut merged = 0;
    for i in &imported {
        source = source.merge(&i.source);
        target = target.merge(&i.target);
        merged += i.merged;
    }
    let mut labelable = opts.class_map.labelable.clone();
    if opts.lane_masks.is_some() && !labelable.contains(&Class::LaneMarking) {
        labelable.push(Class::LaneMarking);
    }
    let items: Vec<Item> = imported.into_iter().map(|i| i.item).collect();
    let report = make_report(opts, &items, skipped, &source, &target, &labelable, merged);
    let card = Card::new(
        opts.name.clone(),
        &labelable,
        serde_json::json!({
            "tool": "pipeline dataset import",
            "version": env!("CARGO_PKG_VERSION"),
            "format": opts.format,
            "source": opts.layout.root.display().to_string(),
            "class_map": opts.class_map.name,
        }),
        serde_json::json!({
            "splits": opts.layout.splits,
            "variant": opts.layout.variant,
            "lane_masks": opts.lane_masks.as_ref().map(|p| p.display().to_string()),
            "on_error": opts.on_error,
        }),
        0,
    );
    write_dataset_files(out_dir, &card, &items)?;
    let mut json = serde_json::to_string_pretty(&report)
        .map_err(|e| DatasetError::Config(format!("cannot encode the import report: {e}")))?;
    json.push('\n');
    write_bytes(&out_dir.join(IMPORT_REPORT), json.as_bytes())?;
    Ok(ImportOutcome {
        items,
        card,
        report,
    })
}

fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| DatasetError::io(path, e))
}

/// Imports one pair and writes its files.
fn import_pair(
    pair: &SourcePair,
    opts: &ImportOptions,
    lane_map: &ClassMap,
    out_dir: &Path,
) -> Result<Imported> {
    if !pair.image.exists() {
        return Err(DatasetError::invalid(
            &pair.image,
            format!("missing: the label {} has no image", pair.label.display()),
        ));
    }
    let image_bytes = read(&pair.image)?;
    let image = decode_image(&pair.image, &image_bytes)?;
    let (width, height) = (image.width(), image.height());

    let label_bytes = read(&pair.label)?;
    let source_values = opts.class_map.source_values(&pair.label, &label_bytes)?;
    crate::image_io::check_label_size(&pair.label, &source_values, width, height)?;
    let mut label = opts.class_map.apply(&pair.label, &source_values)?;

    let merged = match &opts.lane_masks {
        Some(dir) => merge_lane_mask(&dir.join(format!("{}.png", pair.id)), lane_map, &mut label)?,
        None => 0,
    };

    let (image_file, image_out) = image_file(&pair.id, &pair.image, image, image_bytes);
    let label_file = format!("{LABELS_DIR}/{}.png", pair.id);
    write_bytes(&out_dir.join(&image_file), &image_out)?;
    write_bytes(&out_dir.join(&label_file), &encode_label_png(&label))?;

    let mut item = Item::new(
        pair.id.clone(),
        opts.class_map.name.clone(),
        (width, height),
        serde_json::json!({
            "source_image": pair.image.display().to_string(),
            "source_label": pair.label.display().to_string(),
        }),
    );
    item.image = image_file;
    item.label = label_file;
    item.split.clone_from(&pair.split);
    Ok(Imported {
        item,
        source: LabelHistogram::of(&source_values),
        target: LabelHistogram::of(&label),
        merged,
    })
}

/// The image's file name in the output and its bytes: RGB PNGs and JPEGs are kept as they
/// are, anything else becomes an RGB PNG.
fn image_file(id: &str, source: &Path, image: DynamicImage, bytes: Vec<u8>) -> (String, Vec<u8>) {
    let ext = source
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let rgb = matches!(image, DynamicImage::ImageRgb8(_));
    match ext.as_str() {
        "jpg" | "jpeg" if rgb => (format!("{IMAGES_DIR}/{id}.jpg"), bytes),
        "png" if rgb => (format!("{IMAGES_DIR}/{id}.png"), bytes),
        _ => (
            format!("{IMAGES_DIR}/{id}.png"),
            encode_rgb_png(&image.into_rgb8()),
        ),
    }
}

/// Sets lane marking where the mask is non-zero and the label says road; returns the
/// number of pixels changed.
fn merge_lane_mask(mask_path: &Path, lane_map: &ClassMap, label: &mut GrayImage) -> Result<u64> {
    let mask = lane_map.source_values(mask_path, &read(mask_path)?)?;
    crate::image_io::check_label_size(mask_path, &mask, label.width(), label.height())?;
    let mut merged = 0;
    for (l, &m) in label.iter_mut().zip(mask.as_raw()) {
        if m != 0 && *l == Class::Road.id() {
            *l = Class::LaneMarking.id();
            merged += 1;
        }
    }
    Ok(merged)
}

fn make_report(
    opts: &ImportOptions,
    items: &[Item],
    skipped: Vec<Skipped>,
    source: &LabelHistogram,
    target: &LabelHistogram,
    labelable: &[Class],
    merged: u64,
) -> ImportReport {
    let total = source.total();
    let map = &opts.class_map;
    let source_classes: Vec<SourceClassPixels> = map
        .classes
        .iter()
        .enumerate()
        .map(|(index, class)| {
            let pixels: u64 = (0..=255u8)
                .filter(|&v| map.source_class_index(v) == Some(index))
                .map(|v| source.count(v))
                .sum();
            SourceClassPixels {
                id: class.id,
                name: class.name.clone(),
                target: class.target.clone(),
                pixels,
                percent_of_all: 100.0 * pixels as f64 / total.max(1) as f64,
            }
        })
        .collect();
    let unmapped_source_classes = source_classes
        .iter()
        .filter(|c| c.pixels > 0 && map.target(c.id) == Some(IGNORE))
        .cloned()
        .collect();
    let target_classes = Class::ALL
        .iter()
        .map(|c| c.id())
        .chain(std::iter::once(IGNORE))
        .map(|id| TargetClassPixels {
            id,
            name: label_name(id).unwrap_or("?").to_owned(),
            pixels: target.count(id),
            percent_of_all: target.percent_of_all(id),
            percent_of_labelled: (id != IGNORE).then(|| target.percent_of_labelled(id)),
        })
        .collect();
    ImportReport {
        format: opts.format,
        class_map: map.name.clone(),
        items: items.len(),
        skipped,
        pixels: target.total(),
        share_definition: SHARE_DEFINITION.to_owned(),
        source_classes,
        unmapped_source_classes,
        target_classes,
        labelable: labelable.iter().map(|c| c.name().to_owned()).collect(),
        lane_mask_pixels_merged: opts.lane_masks.as_ref().map(|_| merged),
    }
}
