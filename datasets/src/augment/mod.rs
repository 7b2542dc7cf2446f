//! Joint image-and-label augmentation.
//!
//! An [`AugmentConfig`] says which transforms may happen, how likely and in what range;
//! for each output it is sampled into a list of concrete [`Op`]s with the item's own
//! generator (seeded from (global seed, `augment`, item index, copy)), and [`apply`] runs
//! that list. The list is stored in the manifest's `params`, so [`apply`] on the source
//! item gives the same bytes again (replay).
//!
//! Geometric ops (crop, scale, rotate, flip, perspective) move image and label together:
//! consecutive ones are composed into one warp ([`geometry`]); the image is resampled
//! bilinearly, the label nearest-neighbour, and padding is black / ignore (255). The other
//! ops change the image only.

pub mod colour;
pub mod filters;
pub mod geometry;
#[cfg(test)]
mod properties;

use std::borrow::Cow;
use std::path::Path;

use image::{GrayImage, RgbImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{DatasetError, OnError, Result, Skipped, apply_policy};
use crate::image_io::{encode_label_png, encode_rgb_png, read_class_label, read_rgb, write_bytes};
use crate::manifest::{Card, Dataset, Item, write_dataset_files};
use crate::shard::{SHARD_KEY, Shard};
use geometry::Warp;

/// One concrete transform, as stored in `params.ops`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case", deny_unknown_fields)]
pub enum Op {
    /// The window at (x, y) of this size; the output has the window's size.
    Crop {
        x: u32,
        y: u32,
        width: u32,
        height: u32,
    },
    /// Resize by a factor.
    Scale {
        factor: f64,
    },
    /// Counter-clockwise rotation about the centre, same size.
    Rotate {
        degrees: f64,
    },
    HorizontalFlip,
    /// The output's corners (TL, TR, BR, BL) show these input points (pixels).
    Perspective {
        corners: [[f64; 2]; 4],
    },
    /// Add `delta · 255`.
    Brightness {
        delta: f64,
    },
    /// Scale around the mean grey.
    Contrast {
        factor: f64,
    },
    Gamma {
        gamma: f64,
    },
    /// Hue rotation in degrees.
    Hue {
        degrees: f64,
    },
    Saturation {
        factor: f64,
    },
    Fog {
        density: f64,
        horizon: f64,
    },
    /// Darken a polygon (corners as fractions of width and height).
    Shadow {
        polygon: Vec<[f64; 2]>,
        darkness: f64,
    },
    GaussianBlur {
        sigma: f64,
    },
    MotionBlur {
        length: u32,
        degrees: f64,
    },
    /// Noise of this standard deviation (0..255 scale) from a generator with this seed.
    GaussianNoise {
        sigma: f64,
        seed: u64,
    },
    Jpeg {
        quality: u8,
    },
}

impl Op {
    pub fn is_geometric(&self) -> bool {
        matches!(
            self,
            Op::Crop { .. }
                | Op::Scale { .. }
                | Op::Rotate { .. }
                | Op::HorizontalFlip
                | Op::Perspective { .. }
        )
    }
}

/// Applies ops to an image and its label (see the module docs). Errors only for ops that
/// cannot be carried out (a degenerate perspective, a failed JPEG round trip).
pub fn apply(ops: &[Op], image: &RgbImage, label: &GrayImage) -> Result<(RgbImage, GrayImage)> {
    // Borrowed until an op changes them: a warp writes new buffers, so the input is never
    // copied when the chain starts with one.
    let mut image = Cow::Borrowed(image);
    let mut label = Cow::Borrowed(label);
    let mut warp: Option<Warp> = None;
    for op in ops {
        if op.is_geometric() {
            let w = warp.unwrap_or_else(|| Warp::identity(image.width(), image.height()));
            warp = Some(match op {
                Op::Crop {
                    x,
                    y,
                    width,
                    height,
                } => w.crop(*x, *y, *width, *height),
                Op::Scale { factor } => w.scale(*factor),
                Op::Rotate { degrees } => w.rotate(*degrees),
                Op::HorizontalFlip => w.hflip(),
                Op::Perspective { corners } => w.perspective(corners).ok_or_else(|| {
                    DatasetError::Config(format!("degenerate perspective corners {corners:?}"))
                })?,
                _ => w,
            });
            continue;
        }
        if let Some(w) = warp.take() {
            let (i, l) = w.run(&image, &label);
            (image, label) = (Cow::Owned(i), Cow::Owned(l));
        }
        let image = image.to_mut();
        match op {
            Op::Brightness { delta } => colour::brightness(image, *delta),
            Op::Contrast { factor } => colour::contrast(image, *factor),
            Op::Gamma { gamma } => colour::gamma(image, *gamma),
            Op::Hue { degrees } => colour::hue(image, *degrees),
            Op::Saturation { factor } => colour::saturation(image, *factor),
            Op::Fog { density, horizon } => colour::fog(image, *density, *horizon),
            Op::Shadow { polygon, darkness } => colour::shadow(image, polygon, *darkness),
            Op::GaussianBlur { sigma } => filters::gaussian_blur(image, *sigma),
            Op::MotionBlur { length, degrees } => filters::motion_blur(image, *length, *degrees),
            Op::GaussianNoise { sigma, seed } => filters::gaussian_noise(image, *sigma, *seed),
            Op::Jpeg { quality } => {
                filters::jpeg(image, *quality).map_err(|e| DatasetError::Config(e.to_string()))?
            }
            _ => {}
        }
    }
    if let Some(w) = warp {
        return Ok(w.run(&image, &label));
    }
    Ok((image.into_owned(), label.into_owned()))
}

/// A transform's chance and its parameter range `[low, high]` (drawn uniformly).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Chance {
    /// Probability of applying it, 0..1.
    pub p: f64,
    #[serde(default)]
    pub range: [f64; 2],
}

impl Chance {
    pub const fn new(p: f64, low: f64, high: f64) -> Chance {
        Chance {
            p,
            range: [low, high],
        }
    }
}

/// Which transforms may happen; `None` = never. Applied in the field order.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AugmentConfig {
    /// Window size as a fraction of width and height (range = the fraction's bounds;
    /// equal bounds give a fixed-size crop, like albumentations' RandomCrop).
    pub crop: Option<Chance>,
    /// Resize factor.
    pub scale: Option<Chance>,
    /// Rotation in degrees.
    pub rotate: Option<Chance>,
    /// Horizontal flip (range unused).
    pub hflip: Option<Chance>,
    /// Largest corner displacement, as a fraction of width and height.
    pub perspective: Option<Chance>,
    /// Added brightness, fraction of 255.
    pub brightness: Option<Chance>,
    /// Contrast factor.
    pub contrast: Option<Chance>,
    pub gamma: Option<Chance>,
    /// Hue rotation, degrees.
    pub hue: Option<Chance>,
    /// Saturation factor.
    pub saturation: Option<Chance>,
    /// Fog density at the top of the image, 0..1.
    pub fog: Option<Chance>,
    /// Shadow darkness, 0..1.
    pub shadow: Option<Chance>,
    /// Gaussian blur sigma, pixels.
    pub gaussian_blur: Option<Chance>,
    /// Motion blur length, pixels (rounded to an odd number).
    pub motion_blur: Option<Chance>,
    /// Gaussian noise sigma, 0..255 scale.
    pub gaussian_noise: Option<Chance>,
    /// JPEG quality.
    pub jpeg: Option<Chance>,
}

/// Named configurations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// The thesis's five: random crop (80 % of each side), rotation (±10°), horizontal flip
    /// (p 0.5), Gaussian blur (σ 0.5-1.5, p 0.5), Gaussian noise (σ 5-15, p 0.5).
    Thesis,
    /// Every transform, each with a moderate chance.
    Full,
}

impl AugmentConfig {
    pub fn preset(preset: Preset) -> AugmentConfig {
        let thesis = AugmentConfig {
            crop: Some(Chance::new(1.0, 0.8, 0.8)),
            rotate: Some(Chance::new(1.0, -10.0, 10.0)),
            hflip: Some(Chance::new(0.5, 0.0, 0.0)),
            gaussian_blur: Some(Chance::new(0.5, 0.5, 1.5)),
            gaussian_noise: Some(Chance::new(0.5, 5.0, 15.0)),
            ..AugmentConfig::default()
        };
        match preset {
            Preset::Thesis => thesis,
            Preset::Full => AugmentConfig {
                crop: Some(Chance::new(0.5, 0.7, 1.0)),
                scale: Some(Chance::new(0.3, 0.75, 1.25)),
                perspective: Some(Chance::new(0.3, 0.0, 0.08)),
                brightness: Some(Chance::new(0.5, -0.15, 0.15)),
                contrast: Some(Chance::new(0.5, 0.75, 1.25)),
                gamma: Some(Chance::new(0.3, 0.7, 1.4)),
                hue: Some(Chance::new(0.3, -15.0, 15.0)),
                saturation: Some(Chance::new(0.3, 0.6, 1.4)),
                fog: Some(Chance::new(0.15, 0.2, 0.6)),
                shadow: Some(Chance::new(0.25, 0.3, 0.6)),
                motion_blur: Some(Chance::new(0.15, 3.0, 9.0)),
                jpeg: Some(Chance::new(0.2, 30.0, 90.0)),
                ..thesis
            },
        }
    }

    /// Checks ranges and chances, naming the offending field.
    pub fn validate(&self) -> std::result::Result<(), AugmentSettingError> {
        let fields: [(&str, Option<Chance>, f64, f64); 16] = [
            ("crop", self.crop, 0.01, 1.0),
            ("scale", self.scale, 0.01, 16.0),
            ("rotate", self.rotate, -360.0, 360.0),
            ("hflip", self.hflip, f64::MIN, f64::MAX),
            ("perspective", self.perspective, 0.0, 0.45),
            ("brightness", self.brightness, -1.0, 1.0),
            ("contrast", self.contrast, 0.0, 10.0),
            ("gamma", self.gamma, 0.01, 10.0),
            ("hue", self.hue, -180.0, 180.0),
            ("saturation", self.saturation, 0.0, 10.0),
            ("fog", self.fog, 0.0, 1.0),
            ("shadow", self.shadow, 0.0, 1.0),
            ("gaussian_blur", self.gaussian_blur, 0.0, 50.0),
            ("motion_blur", self.motion_blur, 1.0, 101.0),
            ("gaussian_noise", self.gaussian_noise, 0.0, 255.0),
            ("jpeg", self.jpeg, 1.0, 100.0),
        ];
        for (name, chance, low, high) in fields {
            let Some(c) = chance else { continue };
            if !(0.0..=1.0).contains(&c.p) {
                return Err(AugmentSettingError::Chance { name, p: c.p });
            }
            let [a, b] = c.range;
            if !(a.is_finite() && b.is_finite() && a <= b && a >= low && b <= high) {
                return Err(AugmentSettingError::Range {
                    name,
                    range: [a, b],
                    within: [low, high],
                });
            }
        }
        Ok(())
    }

    /// Draws the ops of one output for an input of `width × height`.
    pub fn sample(&self, rng: &mut ChaCha8Rng, width: u32, height: u32) -> Vec<Op> {
        let mut ops = Vec::new();
        let (mut w, mut h) = (width, height);
        let draw = |c: &Option<Chance>, rng: &mut ChaCha8Rng| -> Option<f64> {
            let c = c.as_ref()?;
            let hit = rng.random::<f64>() < c.p;
            let v = rng.random_range(c.range[0]..=c.range[1]);
            hit.then_some(v)
        };
        if let Some(f) = draw(&self.crop, rng) {
            let cw = ((f64::from(w) * f).round() as u32).clamp(1, w);
            let ch = ((f64::from(h) * f).round() as u32).clamp(1, h);
            let x = rng.random_range(0..=w - cw);
            let y = rng.random_range(0..=h - ch);
            ops.push(Op::Crop {
                x,
                y,
                width: cw,
                height: ch,
            });
            (w, h) = (cw, ch);
        }
        if let Some(factor) = draw(&self.scale, rng) {
            ops.push(Op::Scale { factor });
            w = (f64::from(w) * factor).round().max(1.0) as u32;
            h = (f64::from(h) * factor).round().max(1.0) as u32;
        }
        if let Some(degrees) = draw(&self.rotate, rng) {
            ops.push(Op::Rotate { degrees });
        }
        if draw(&self.hflip, rng).is_some() {
            ops.push(Op::HorizontalFlip);
        }
        if let Some(jitter) = draw(&self.perspective, rng) {
            let (fw, fh) = (f64::from(w), f64::from(h));
            let base = [[0.0, 0.0], [fw, 0.0], [fw, fh], [0.0, fh]];
            let corners = base.map(|[x, y]| {
                [
                    x + rng.random_range(-jitter..=jitter) * fw,
                    y + rng.random_range(-jitter..=jitter) * fh,
                ]
            });
            ops.push(Op::Perspective { corners });
        }
        if let Some(delta) = draw(&self.brightness, rng) {
            ops.push(Op::Brightness { delta });
        }
        if let Some(factor) = draw(&self.contrast, rng) {
            ops.push(Op::Contrast { factor });
        }
        if let Some(gamma) = draw(&self.gamma, rng) {
            ops.push(Op::Gamma { gamma });
        }
        if let Some(degrees) = draw(&self.hue, rng) {
            ops.push(Op::Hue { degrees });
        }
        if let Some(factor) = draw(&self.saturation, rng) {
            ops.push(Op::Saturation { factor });
        }
        if let Some(density) = draw(&self.fog, rng) {
            let horizon = rng.random_range(0.4..=0.7);
            ops.push(Op::Fog { density, horizon });
        }
        if let Some(darkness) = draw(&self.shadow, rng) {
            // A quadrilateral reaching from the bottom edge, like a building's shadow.
            let x0: f64 = rng.random_range(0.0..=0.8);
            let x1: f64 = (x0 + rng.random_range(0.2..=0.6_f64)).min(1.0);
            let top = rng.random_range(0.4..=0.8);
            let lean = rng.random_range(-0.2..=0.2);
            let polygon = vec![[x0, 1.0], [x1, 1.0], [x1 + lean, top], [x0 + lean, top]];
            ops.push(Op::Shadow { polygon, darkness });
        }
        if let Some(sigma) = draw(&self.gaussian_blur, rng) {
            ops.push(Op::GaussianBlur { sigma });
        }
        if let Some(length) = draw(&self.motion_blur, rng) {
            let length = (length.round() as u32) | 1;
            let degrees = rng.random_range(0.0..180.0);
            ops.push(Op::MotionBlur { length, degrees });
        }
        if let Some(sigma) = draw(&self.gaussian_noise, rng) {
            let seed = rng.random();
            ops.push(Op::GaussianNoise { sigma, seed });
        }
        if let Some(quality) = draw(&self.jpeg, rng) {
            ops.push(Op::Jpeg {
                quality: quality.round().clamp(1.0, 100.0) as u8,
            });
        }
        ops
    }
}

/// Seed-derivation stage of augmentation ("augment" as little-endian bytes).
const STAGE: u64 = u64::from_le_bytes(*b"augment\0");
/// Sub-stage for the copy number.
const COPY_STAGE: u64 = u64::from_le_bytes(*b"copy\0\0\0\0");

/// The seed of copy `copy` of item `index` under the global `seed`.
pub fn copy_seed(seed: u64, index: u64, copy: u64) -> u64 {
    sim::seed::derive_seed(sim::seed::derive_seed(seed, STAGE, index), COPY_STAGE, copy)
}

/// What `augment` is asked to do.
#[derive(Debug, Clone)]
pub struct AugmentOptions {
    pub name: String,
    pub config: AugmentConfig,
    /// Outputs per source item.
    pub copies: u32,
    /// Also copy each source item unchanged into the output.
    pub include_originals: bool,
    pub seed: u64,
    pub on_error: OnError,
    /// Augment only this shard of the input's items (recorded in the card's config); the
    /// shards merge with [`crate::shard::merge_shards`].
    pub shard: Option<Shard>,
}

/// The `params` of an augmented item.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AugmentParams {
    /// Id of the source item in the input dataset.
    pub source_id: String,
    /// Copy number (None for an unchanged original).
    pub copy: Option<u32>,
    /// The item's derived seed.
    pub seed: u64,
    pub ops: Vec<Op>,
}

/// What an augmentation made.
#[derive(Debug, Clone)]
pub struct AugmentOutcome {
    pub items: Vec<Item>,
    pub card: Card,
    pub skipped: Vec<Skipped>,
}

/// The outputs of one source item.
fn augment_item(
    dataset: &Dataset,
    index: usize,
    opts: &AugmentOptions,
    out_dir: &Path,
) -> Result<Vec<Item>> {
    let source = &dataset.items[index];
    let image = read_rgb(&dataset.image_path(source))?;
    let label = read_class_label(&dataset.label_path(source), image.width(), image.height())?;
    if image.dimensions() != (source.width, source.height) {
        return Err(DatasetError::invalid(
            &dataset.image_path(source),
            format!(
                "image is {}x{} but the manifest says {}x{}",
                image.width(),
                image.height(),
                source.width,
                source.height
            ),
        ));
    }
    let mut outputs = Vec::new();
    let mut emit = |id: String, copy: Option<u32>, seed: u64, ops: Vec<Op>| -> Result<()> {
        let (img, lab) = apply(&ops, &image, &label)?;
        let params = AugmentParams {
            source_id: source.id.clone(),
            copy,
            seed,
            ops,
        };
        let params = serde_json::to_value(&params)
            .map_err(|e| DatasetError::Config(format!("cannot encode params: {e}")))?;
        let mut item = Item::new(
            id,
            format!("augment:{}", source.source),
            img.dimensions(),
            params,
        );
        item.split.clone_from(&source.split);
        write_bytes(&out_dir.join(&item.image), &encode_rgb_png(&img))?;
        write_bytes(&out_dir.join(&item.label), &encode_label_png(&lab))?;
        outputs.push(item);
        Ok(())
    };
    if opts.include_originals {
        emit(source.id.clone(), None, 0, Vec::new())?;
    }
    for copy in 0..opts.copies {
        let seed = copy_seed(opts.seed, index as u64, u64::from(copy));
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let ops = opts.config.sample(&mut rng, image.width(), image.height());
        emit(format!("{}.aug{copy}", source.id), Some(copy), seed, ops)?;
    }
    Ok(outputs)
}

/// Augments every item of `dataset` (or those of `opts.shard`) into `out_dir` (which must
/// exist), in parallel; the bytes do not depend on the thread count. Each item's draws are
/// seeded by its index in the input, so a shard makes the same items as the whole run.
pub fn augment_dataset(
    dataset: &Dataset,
    opts: &AugmentOptions,
    out_dir: &Path,
) -> Result<AugmentOutcome> {
    augment_dataset_with_progress(dataset, opts, out_dir, &|| {})
}

/// The input items [`augment_dataset`] works on: all, or those of `opts.shard`.
pub fn augment_inputs(dataset: &Dataset, opts: &AugmentOptions) -> usize {
    let all = dataset.items.len() as u64;
    let indices = opts.shard.map_or(0..all, |shard| shard.range(all));
    (indices.end - indices.start) as usize
}

/// [`augment_dataset`], calling `item_done` after each input item (from the worker threads).
pub fn augment_dataset_with_progress(
    dataset: &Dataset,
    opts: &AugmentOptions,
    out_dir: &Path,
    item_done: &(dyn Fn() + Sync),
) -> Result<AugmentOutcome> {
    opts.config
        .validate()
        .map_err(|e| DatasetError::Config(e.to_string()))?;
    let all = dataset.items.len() as u64;
    let indices = opts.shard.map_or(0..all, |shard| shard.range(all));
    let results: Vec<(String, Result<Vec<Item>>)> = (indices.start as usize..indices.end as usize)
        .into_par_iter()
        .map(|i| {
            let made = augment_item(dataset, i, opts, out_dir);
            item_done();
            (dataset.items[i].id.clone(), made)
        })
        .collect();
    let (made, skipped) = apply_policy(results, opts.on_error)?;
    let items: Vec<Item> = made.into_iter().flatten().collect();
    // A shard may make nothing (fewer items than shards, or every item of its share
    // skipped). The whole run's "nothing could be augmented" error is not repeated when
    // the shards are merged.
    if items.is_empty() && opts.shard.is_none() {
        return Err(DatasetError::invalid(
            &dataset.root,
            format!("no item could be augmented ({} skipped)", skipped.len()),
        ));
    }
    let labelable: Vec<crate::Class> = dataset
        .card
        .labelable
        .iter()
        .filter_map(|&id| crate::Class::from_id(id))
        .collect();
    let card = Card::new(
        opts.name.clone(),
        &labelable,
        serde_json::json!({
            "tool": "pipeline dataset augment",
            "version": env!("CARGO_PKG_VERSION"),
            "source_dataset": dataset.card.name,
            "source_path": dataset.root.display().to_string(),
            "source_provenance": dataset.card.provenance,
            // Items left out under --on-error skip, with why: the dataset says what it lacks.
            "skipped": skipped,
        }),
        {
            let mut config = serde_json::json!({
                "transforms": opts.config,
                "copies": opts.copies,
                "include_originals": opts.include_originals,
                "on_error": opts.on_error,
            });
            if let (Some(shard), Some(object)) = (opts.shard, config.as_object_mut()) {
                object.insert(SHARD_KEY.to_owned(), serde_json::json!(shard));
            }
            config
        },
        opts.seed,
    );
    write_dataset_files(out_dir, &card, &items)?;
    Ok(AugmentOutcome {
        items,
        card,
        skipped,
    })
}

/// A chain's setting out of range ([`AugmentConfig::validate`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AugmentSettingError {
    #[error("{name}: p = {p} is not in 0..1")]
    Chance { name: &'static str, p: f64 },
    #[error("{name}: range [{}, {}] must be ordered and within [{}, {}]", range[0], range[1], within[0], within[1])]
    Range {
        name: &'static str,
        range: [f64; 2],
        within: [f64; 2],
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_validate_and_sampling_is_seeded() {
        for preset in [Preset::Thesis, Preset::Full] {
            let config = AugmentConfig::preset(preset);
            assert_eq!(config.validate(), Ok(()));
            let a = config.sample(&mut ChaCha8Rng::seed_from_u64(5), 480, 360);
            let b = config.sample(&mut ChaCha8Rng::seed_from_u64(5), 480, 360);
            assert_eq!(a, b);
        }
        let ops = AugmentConfig::preset(Preset::Thesis).sample(
            &mut ChaCha8Rng::seed_from_u64(1),
            480,
            360,
        );
        assert!(
            matches!(
                ops[0],
                Op::Crop {
                    width: 384,
                    height: 288,
                    ..
                }
            ),
            "{ops:?}"
        );
        let mut bad = AugmentConfig::preset(Preset::Thesis);
        bad.rotate = Some(Chance::new(1.5, 0.0, 1.0));
        assert!(
            bad.validate()
                .is_err_and(|e| e.to_string().starts_with("rotate"))
        );
    }

    #[test]
    fn ops_round_trip_through_json_exactly() -> std::result::Result<(), serde_json::Error> {
        let ops =
            AugmentConfig::preset(Preset::Full).sample(&mut ChaCha8Rng::seed_from_u64(9), 97, 61);
        let text = serde_json::to_string(&ops)?;
        let back: Vec<Op> = serde_json::from_str(&text)?;
        assert_eq!(back, ops);
        Ok(())
    }

    /// A small dataset of synthetic pictures in `dir`.
    fn synthetic_dataset(dir: &Path, n: u32) -> Result<Dataset> {
        let mut items = Vec::new();
        for i in 0..n {
            let (w, h) = (40 + i * 3, 30 + i);
            let image = RgbImage::from_fn(w, h, |x, y| {
                image::Rgb([(x * 6) as u8, (y * 8) as u8, (i * 40) as u8])
            });
            let label = GrayImage::from_fn(w, h, |x, y| {
                image::Luma([[0, 1, 2, 3, 4, 255][((x / 7 + y / 5 + i) % 6) as usize]])
            });
            let item = Item::new(
                format!("s{i}"),
                "synthetic",
                (w, h),
                serde_json::json!(null),
            );
            write_bytes(&dir.join(&item.image), &encode_rgb_png(&image))?;
            write_bytes(&dir.join(&item.label), &encode_label_png(&label))?;
            items.push(item);
        }
        let card = Card::new(
            "synthetic",
            &crate::Class::ALL,
            serde_json::json!({}),
            serde_json::json!({}),
            0,
        );
        write_dataset_files(dir, &card, &items)?;
        Dataset::open(dir)
    }

    fn tmp() -> Result<tempfile::TempDir> {
        tempfile::tempdir().map_err(|e| DatasetError::io(Path::new("tmp"), e))
    }

    fn read(path: &Path) -> Result<Vec<u8>> {
        std::fs::read(path).map_err(|e| DatasetError::io(path, e))
    }

    #[test]
    fn replaying_params_gives_the_same_bytes_whatever_the_thread_count() -> Result<()> {
        let input = tmp()?;
        let dataset = synthetic_dataset(input.path(), 5)?;
        let opts = AugmentOptions {
            name: "aug".into(),
            config: AugmentConfig::preset(Preset::Full),
            copies: 4,
            include_originals: true,
            seed: 11,
            on_error: OnError::Fail,
            shard: None,
        };
        let mut outputs = Vec::new();
        for threads in [1, 2] {
            let out = tmp()?;
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .map_err(|e| DatasetError::Config(e.to_string()))?;
            let outcome = pool.install(|| augment_dataset(&dataset, &opts, out.path()))?;
            assert_eq!(outcome.items.len(), 5 * 5);
            outputs.push((out, outcome));
        }
        let (out, outcome) = &outputs[0];
        for item in &outcome.items {
            // Same bytes with 1 and 2 threads.
            for file in [&item.image, &item.label] {
                assert_eq!(
                    read(&out.path().join(file))?,
                    read(&outputs[1].0.path().join(file))?,
                    "{file}"
                );
            }
            // Replay: the recorded ops on the source item give the written bytes.
            let params: AugmentParams = serde_json::from_value(item.params.clone())
                .map_err(|e| DatasetError::Config(e.to_string()))?;
            let source = dataset
                .items
                .iter()
                .find(|s| s.id == params.source_id)
                .ok_or_else(|| DatasetError::Config("source".into()))?;
            let image = read_rgb(&dataset.image_path(source))?;
            let label =
                read_class_label(&dataset.label_path(source), image.width(), image.height())?;
            let (img, lab) = apply(&params.ops, &image, &label)?;
            assert_eq!(
                encode_rgb_png(&img),
                read(&out.path().join(&item.image))?,
                "{}",
                item.id
            );
            assert_eq!(
                encode_label_png(&lab),
                read(&out.path().join(&item.label))?,
                "{}",
                item.id
            );
        }
        let manifest = |o: &tempfile::TempDir| read(&o.path().join(crate::manifest::MANIFEST_FILE));
        assert_eq!(manifest(&outputs[0].0)?, manifest(&outputs[1].0)?);
        Ok(())
    }

    #[test]
    fn broken_items_fail_or_are_skipped_and_counted() -> Result<()> {
        let input = tmp()?;
        let dataset = synthetic_dataset(input.path(), 3)?;
        // Corrupt one label: wrong size.
        write_bytes(
            &input.path().join("labels/s1.png"),
            &encode_label_png(&GrayImage::new(5, 5)),
        )?;
        let mut opts = AugmentOptions {
            name: "aug".into(),
            config: AugmentConfig::preset(Preset::Thesis),
            copies: 1,
            include_originals: false,
            seed: 0,
            on_error: OnError::Fail,
            shard: None,
        };
        let out = tmp()?;
        let err = augment_dataset(&dataset, &opts, out.path())
            .err()
            .map(|e| e.to_string());
        assert!(
            err.as_deref()
                .is_some_and(|e| e.contains("labels/s1.png") && e.contains("5x5")),
            "{err:?}"
        );
        opts.on_error = OnError::Skip;
        let outcome = augment_dataset(&dataset, &opts, out.path())?;
        assert_eq!(outcome.items.len(), 2);
        assert_eq!(outcome.skipped.len(), 1);
        assert_eq!(outcome.skipped[0].id, "s1");
        let card = crate::manifest::read_card(&out.path().join(crate::manifest::CARD_FILE))?;
        assert_eq!(card.provenance["skipped"][0]["id"], "s1");

        // In three shards (s1, the broken one, alone in shard 1), merged: the same manifest
        // and card, the skipped list included.
        let mut shards = Vec::new();
        for index in 0..3 {
            let dir = tmp()?;
            opts.shard = Some(Shard { index, count: 3 });
            augment_dataset(&dataset, &opts, dir.path())?;
            shards.push((Dataset::open(dir.path())?, dir));
        }
        assert!(shards[1].0.items.is_empty());
        let merged = tmp()?;
        let refs: Vec<&Dataset> = shards.iter().rev().map(|(d, _)| d).collect();
        crate::shard::merge_shards("aug", &refs, merged.path())?;
        for file in [crate::manifest::CARD_FILE, crate::manifest::MANIFEST_FILE] {
            assert_eq!(
                read(&merged.path().join(file))?,
                read(&out.path().join(file))?,
                "{file}"
            );
        }
        Ok(())
    }

    #[test]
    fn copy_seeds_differ() {
        assert_ne!(copy_seed(0, 0, 0), copy_seed(0, 0, 1));
        assert_ne!(copy_seed(0, 0, 0), copy_seed(0, 1, 0));
        assert_ne!(copy_seed(0, 0, 0), copy_seed(1, 0, 0));
    }
}
