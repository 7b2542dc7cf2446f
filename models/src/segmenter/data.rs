//! Training and validation input: datasets in the project's manifest format (one or several,
//! with sampling weights), their items loaded, augmented on the fly and batched.
//!
//! - Train items are those whose manifest `split` is `train`, or every item when the
//!   manifest has no split at all; validation items are those with split `val`, test items
//!   (for evaluation only) those with split `test`.
//! - An epoch draws `samples_per_epoch` items: a source by its weight, then the next item
//!   of that source's shuffled order (reshuffled when used up). The draws come from a
//!   generator seeded by (seed, epoch), so the order is the same on every run and after a
//!   resume, whatever the thread count.
//! - Augmentation (per item, seeded by (seed, epoch, draw)): resize so the short side is
//!   `size × scale` with a random scale, random crop of `crop × crop` (padding with ignore
//!   where the image is smaller), horizontal flip; resampled in one pass over the crop by
//!   `datasets::augment::geometry::Warp` (image bilinear, label nearest-neighbour).

use std::path::{Path, PathBuf};

use image::imageops::{self, FilterType};
use image::{GrayImage, RgbImage};
use rand::Rng;
use rand::seq::SliceRandom;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use datasets::augment::geometry::Warp;
use datasets::classes::NUM_CLASSES;
use datasets::image_io::{read_class_label, read_rgb};
use datasets::{Dataset, Item};
use sim::seed::{derive_seed, item_rng};

use super::error::{Result, SegmenterError};

/// Seed stages of the training input (see `sim::seed`).
const STAGE_EPOCH_ORDER: u64 = 0x5e6_0001;
const STAGE_AUGMENT: u64 = 0x5e6_0002;

/// A dataset folder and its sampling weight, as given on the command line (`DIR[:WEIGHT]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceSpec {
    pub path: PathBuf,
    #[serde(default = "one")]
    pub weight: f64,
}

fn one() -> f64 {
    1.0
}

impl SourceSpec {
    /// Parses `DIR` or `DIR:WEIGHT` (a positive number after the last colon).
    pub fn parse(text: &str) -> std::result::Result<SourceSpec, String> {
        if let Some((path, weight)) = text.rsplit_once(':')
            && let Ok(weight) = weight.parse::<f64>()
        {
            if !(weight.is_finite() && weight > 0.0) {
                return Err(format!("the weight of `{text}` must be a positive number"));
            }
            return Ok(SourceSpec {
                path: PathBuf::from(path),
                weight,
            });
        }
        Ok(SourceSpec {
            path: PathBuf::from(text),
            weight: 1.0,
        })
    }
}

/// One opened dataset: its items of the split asked for, its weight, what it cannot label.
#[derive(Debug, Clone)]
pub struct Source {
    pub name: String,
    pub dataset: Dataset,
    pub weight: f64,
    /// `unlabelable[c]`: the card says this source cannot label class `c`.
    pub unlabelable: Vec<bool>,
    /// Indices into `dataset.items` of the split.
    pub items: Vec<usize>,
}

/// Which items of a manifest to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Split {
    /// `split == "train"`, or all items of a manifest without splits.
    Train,
    /// `split == "val"`.
    Val,
    /// `split == "test"` (`dataset split --test`, `dataset import camvid`).
    Test,
    /// Every item.
    All,
}

impl Source {
    /// Opens a dataset folder and selects the items of `split`.
    pub fn open(spec: &SourceSpec, split: Split) -> Result<Source> {
        let dataset = Dataset::open(&spec.path)?;
        let has_splits = dataset.items.iter().any(|i| i.split.is_some());
        let wanted = |item: &Item| match split {
            Split::All => true,
            Split::Train => !has_splits || item.split.as_deref() == Some("train"),
            Split::Val => item.split.as_deref() == Some("val"),
            Split::Test => item.split.as_deref() == Some("test"),
        };
        let items = (0..dataset.items.len())
            .filter(|&i| wanted(&dataset.items[i]))
            .collect();
        let unlabelable = (0..NUM_CLASSES)
            .map(|c| !dataset.card.labelable.contains(&(c as u8)))
            .collect();
        Ok(Source {
            name: dataset.card.name.clone(),
            dataset,
            weight: spec.weight,
            unlabelable,
            items,
        })
    }

    /// Where the source's files are (for messages).
    pub fn root(&self) -> &Path {
        &self.dataset.root
    }

    /// Loads item `index` (an index into `dataset.items`), checking the label.
    pub fn load(&self, index: usize) -> Result<Sample> {
        let item = &self.dataset.items[index];
        let image = read_rgb(&self.dataset.image_path(item))?;
        let label_path = self.dataset.label_path(item);
        let label = read_class_label(&label_path, image.width(), image.height())?;
        Ok(Sample {
            id: item.id.clone(),
            image,
            label,
        })
    }
}

/// An image and its label (same size).
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    pub id: String,
    pub image: RgbImage,
    pub label: GrayImage,
}

/// A draw of an epoch: (source, item index in the source's dataset).
pub type Draw = (usize, usize);

/// The items of `epoch`: `count` draws by source weight (see the module docs).
pub fn epoch_draws(sources: &[Source], count: usize, seed: u64, epoch: u64) -> Vec<Draw> {
    let mut rng = item_rng(seed, STAGE_EPOCH_ORDER, epoch);
    let usable: Vec<usize> = (0..sources.len())
        .filter(|&s| !sources[s].items.is_empty())
        .collect();
    let total: f64 = usable.iter().map(|&s| sources[s].weight).sum();
    if usable.is_empty() || total <= 0.0 {
        return Vec::new();
    }
    let mut orders: Vec<Vec<usize>> = sources.iter().map(|_| Vec::new()).collect();
    let mut draws = Vec::with_capacity(count);
    for _ in 0..count {
        let mut pick = rng.random::<f64>() * total;
        let mut source = usable[usable.len() - 1];
        for &s in &usable {
            if pick < sources[s].weight {
                source = s;
                break;
            }
            pick -= sources[s].weight;
        }
        if orders[source].is_empty() {
            let mut order = sources[source].items.clone();
            order.shuffle(&mut rng);
            order.reverse();
            orders[source] = order;
        }
        if let Some(item) = orders[source].pop() {
            draws.push((source, item));
        }
    }
    draws
}

/// The random training transforms: resize, crop and flip, resampled in one pass by the
/// datasets crate's `Warp`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Augment {
    /// Short side after resizing, before the random scale.
    pub size: u32,
    /// Side of the square crop fed to the network.
    pub crop: u32,
    /// Random scale range around `size`.
    pub scale: [f32; 2],
    /// Flip half of the items left-right.
    pub flip: bool,
    /// Share of the crops placed around a pixel of one class, chosen uniformly among the
    /// classes the item holds, instead of anywhere: small rare objects (people far away)
    /// are otherwise often cut off by a crop smaller than the image. 0 keeps every crop
    /// uniform (and the random draws exactly as without the option).
    #[serde(default)]
    pub balanced_crops: f32,
}

impl Augment {
    /// The transformed copy of `sample` for draw `draw` of `epoch`.
    pub fn apply(&self, sample: &Sample, seed: u64, epoch: u64, draw: u64) -> Result<Sample> {
        let mut rng = item_rng(derive_seed(seed, STAGE_AUGMENT, epoch), STAGE_AUGMENT, draw);
        let scale = if self.scale[1] > self.scale[0] {
            rng.random_range(self.scale[0]..=self.scale[1])
        } else {
            self.scale[0]
        };
        let short = ((self.size as f32 * scale).round() as u32).max(1);
        let (w0, h0) = sample.image.dimensions();
        let (w, h) = scaled_size(w0, h0, short);
        let centred = self.balanced_crops > 0.0 && rng.random::<f32>() < self.balanced_crops;
        let (x0, y0) = match centred {
            true => {
                let label = imageops::resize(&sample.label, w, h, FilterType::Nearest);
                class_centred_origin(&label, self.crop, &mut rng)
            }
            false => None,
        }
        .unwrap_or_else(|| {
            let x0 = rng.random_range(0..=w.saturating_sub(self.crop));
            (x0, rng.random_range(0..=h.saturating_sub(self.crop)))
        });
        // Only the crop's pixels are computed (bilinear image, nearest label; black and
        // ignore where it reaches past the resized image), never the whole resized image.
        let mut warp = Warp::identity(w0, h0)
            .resize(w, h)
            .crop(x0, y0, self.crop, self.crop);
        if self.flip && rng.random::<bool>() {
            warp = warp.hflip();
        }
        let (image, label) = warp.run(&sample.image, &sample.label);
        Ok(Sample {
            id: sample.id.clone(),
            image,
            label,
        })
    }
}

/// The top-left corner of a `crop`-pixel square holding one pixel of a class drawn
/// uniformly among the classes `label` holds (then a pixel of it uniformly, then the
/// square's place around it uniformly); `None` when the label holds no class at all.
fn class_centred_origin(label: &GrayImage, crop: u32, rng: &mut impl Rng) -> Option<(u32, u32)> {
    let mut counts = [0usize; NUM_CLASSES];
    for p in label.pixels() {
        if let Some(n) = counts.get_mut(p[0] as usize) {
            *n += 1;
        }
    }
    let present: Vec<usize> = (0..NUM_CLASSES).filter(|&c| counts[c] > 0).collect();
    let class = *present.get(rng.random_range(0..present.len().max(1)))?;
    let nth = rng.random_range(0..counts[class]);
    let index = label
        .pixels()
        .enumerate()
        .filter(|(_, p)| p[0] as usize == class)
        .nth(nth)?
        .0 as u32;
    let (w, h) = label.dimensions();
    let x0 = origin_around(index % w, w, crop, rng);
    let y0 = origin_around(index / w, h, crop, rng);
    Some((x0, y0))
}

/// A uniform origin, along a side of `length` pixels, of a `crop`-pixel span that holds
/// pixel `at` and stays inside (0 when the side is shorter than the crop).
fn origin_around(at: u32, length: u32, crop: u32, rng: &mut impl Rng) -> u32 {
    let low = (at + 1).saturating_sub(crop);
    let high = at.min(length.saturating_sub(crop));
    rng.random_range(low.min(high)..=high)
}

/// Resizes so the short side is `short` (bilinear image, nearest-neighbour label).
pub fn resize_sample(sample: &Sample, short: u32) -> Sample {
    let (w, h) = sample.image.dimensions();
    let (nw, nh) = scaled_size(w, h, short);
    if (nw, nh) == (w, h) {
        return sample.clone();
    }
    Sample {
        id: sample.id.clone(),
        image: imageops::resize(&sample.image, nw, nh, FilterType::Triangle),
        label: imageops::resize(&sample.label, nw, nh, FilterType::Nearest),
    }
}

/// The size of a `w`×`h` image whose short side becomes `short`.
pub fn scaled_size(w: u32, h: u32, short: u32) -> (u32, u32) {
    let s = f64::from(short) / f64::from(w.min(h).max(1));
    (
        ((f64::from(w) * s).round() as u32).max(1),
        ((f64::from(h) * s).round() as u32).max(1),
    )
}

/// Loads and augments the draws `first..first + draws.len()` of an epoch in parallel; each
/// result depends only on (seed, epoch, draw number).
pub fn load_batch(
    sources: &[Source],
    draws: &[Draw],
    first: usize,
    augment: &Augment,
    seed: u64,
    epoch: u64,
) -> Result<Vec<(usize, Sample)>> {
    draws
        .par_iter()
        .enumerate()
        .map(|(i, &(source, item))| {
            let sample = sources[source].load(item)?;
            Ok((
                source,
                augment.apply(&sample, seed, epoch, (first + i) as u64)?,
            ))
        })
        .collect()
}

/// Checks that the sources can be trained on: each has items of the split.
pub fn check_sources(sources: &[Source], what: &str) -> Result<()> {
    if sources.is_empty() {
        return Err(SegmenterError::Config(format!("no {what} dataset given")));
    }
    for s in sources {
        if s.items.is_empty() {
            return Err(SegmenterError::invalid(
                s.root(),
                format!(
                    "has no {what} items (run `pipeline dataset split` on it, or give other data)"
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use datasets::IGNORE;
    use image::{Luma, Rgb};

    #[test]
    fn source_specs_parse_weights() {
        assert_eq!(
            SourceSpec::parse("a/b"),
            Ok(SourceSpec {
                path: "a/b".into(),
                weight: 1.0
            })
        );
        assert_eq!(
            SourceSpec::parse("a/b:2.5"),
            Ok(SourceSpec {
                path: "a/b".into(),
                weight: 2.5
            })
        );
        assert!(SourceSpec::parse("a:0").is_err());
        // A colon in a path without a number after it is part of the path.
        assert_eq!(SourceSpec::parse("c:/x").map(|s| s.weight), Ok(1.0));
    }

    #[test]
    fn splits_select_their_items() {
        let tmp = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let dir = tmp.path().join("set");
        super::super::synthetic::write_synthetic_dataset(&dir, 6, 32, 0, None)
            .unwrap_or_else(|e| panic!("{e}"));
        let spec = SourceSpec {
            path: dir.clone(),
            weight: 1.0,
        };
        let items = |split| {
            Source::open(&spec, split)
                .unwrap_or_else(|e| panic!("{e}"))
                .items
        };
        // No splits yet: every item trains, none validates or tests.
        assert_eq!(items(Split::Train), [0, 1, 2, 3, 4, 5]);
        assert!(items(Split::Val).is_empty() && items(Split::Test).is_empty());
        let mut dataset = Dataset::open(&dir).unwrap_or_else(|e| panic!("{e}"));
        for (item, split) in dataset
            .items
            .iter_mut()
            .zip(["train", "test", "val", "train", "test", "train"])
        {
            item.split = Some(split.to_owned());
        }
        datasets::manifest::write_manifest(
            &dir.join(datasets::manifest::MANIFEST_FILE),
            &dataset.items,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(items(Split::Train), [0, 3, 5]);
        assert_eq!(items(Split::Val), [2]);
        assert_eq!(items(Split::Test), [1, 4]);
        assert_eq!(items(Split::All), [0, 1, 2, 3, 4, 5]);
    }

    fn sample(w: u32, h: u32) -> Sample {
        Sample {
            id: "s".into(),
            image: RgbImage::from_fn(w, h, |x, y| Rgb([x as u8, y as u8, 0])),
            // Left half class 0, right half class 4: a rule the transforms must keep.
            label: GrayImage::from_fn(w, h, |x, _| Luma([if x < w / 2 { 0 } else { 4 }])),
        }
    }

    #[test]
    fn augmentation_keeps_label_and_image_aligned_and_is_seeded() {
        let aug = Augment {
            size: 32,
            crop: 28,
            scale: [0.75, 1.5],
            flip: true,
            balanced_crops: 0.0,
        };
        let s = sample(64, 48);
        for draw in 0..20 {
            let a = aug.apply(&s, 3, 1, draw).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(Some(&a), aug.apply(&s, 3, 1, draw).ok().as_ref());
            assert_eq!(a.image.dimensions(), (28, 28));
            for (x, y, l) in a.label.enumerate_pixels() {
                let red = a.image.get_pixel(x, y)[0];
                match l[0] {
                    // Red encodes the source column, so it tells which half a pixel came from
                    // (resampling blurs the image a little near the border between halves).
                    IGNORE => assert_eq!(*a.image.get_pixel(x, y), Rgb([0, 0, 0])),
                    0 => assert!(red <= 34, "{red}"),
                    4 => assert!(red >= 30, "{red}"),
                    v => panic!("label value {v}"),
                }
            }
        }
    }

    #[test]
    fn balanced_crops_hold_a_rare_class_as_often_as_a_common_one() {
        // A 200 × 200 label of class 4 with one 2 × 2 blob of class 3 in a corner: uniform
        // 50-px crops almost never hold it (0.1 % of origins), crops balanced over the two
        // classes hold it in about half of the draws.
        let label = GrayImage::from_fn(200, 200, |x, y| {
            Luma([if (190..192).contains(&x) && y < 2 {
                3
            } else {
                4
            }])
        });
        let s = Sample {
            id: "blob".into(),
            image: RgbImage::new(200, 200),
            label,
        };
        let holds_blob = |balanced_crops: f32| {
            let aug = Augment {
                size: 200,
                crop: 50,
                scale: [1.0, 1.0],
                flip: false,
                balanced_crops,
            };
            (0..400)
                .filter(|&draw| {
                    let a = aug.apply(&s, 7, 0, draw).unwrap_or_else(|e| panic!("{e}"));
                    assert_eq!(a.label.dimensions(), (50, 50));
                    assert!(
                        !a.label.pixels().any(|p| p[0] == IGNORE),
                        "a crop left the image"
                    );
                    a.label.pixels().any(|p| p[0] == 3)
                })
                .count()
        };
        let uniform = holds_blob(0.0);
        let balanced = holds_blob(1.0);
        assert!(
            uniform < 40,
            "uniform crops held the blob {uniform} times of 400"
        );
        assert!(
            (160..=240).contains(&balanced),
            "balanced crops held it {balanced} times of 400"
        );
        // A label without any class (all ignored) falls back to a uniform crop.
        let blank = Sample {
            id: "blank".into(),
            image: RgbImage::new(60, 60),
            label: GrayImage::from_pixel(60, 60, Luma([IGNORE])),
        };
        let aug = Augment {
            size: 60,
            crop: 50,
            scale: [1.0, 1.0],
            flip: false,
            balanced_crops: 1.0,
        };
        assert!(aug.apply(&blank, 7, 0, 0).is_ok());
    }
}
