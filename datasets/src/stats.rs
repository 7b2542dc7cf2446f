//! Dataset statistics: exact per-channel mean and standard deviation, class pixel
//! frequencies and suggested class weights.
//!
//! Exact: pixel values are summed as integers (sums and sums of squares in `u128`), so the
//! totals do not depend on the order rayon adds the images in, and the mean and the
//! population standard deviation `sqrt((N·Σx² − (Σx)²)) / N` are computed from exact
//! integers and rounded once to f64.
//!
//! Class weights: median frequency balancing (Eigen & Fergus 2015, as SegNet used for
//! CamVid): `freq(c) = pixels of c / pixels of the images that contain c`, and
//! `weight(c) = median over present classes of freq / freq(c)`. Ignore pixels count in
//! neither; a class that never occurs gets no weight.

use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::classes::{Class, IGNORE, NUM_CLASSES};
use crate::error::Result;
use crate::image_io::{read_class_label, read_rgb};
use crate::manifest::Dataset;

/// How many pixels of each label value a set of labels holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LabelHistogram {
    pub counts: [u64; 256],
}

impl Default for LabelHistogram {
    fn default() -> Self {
        LabelHistogram { counts: [0; 256] }
    }
}

impl LabelHistogram {
    pub fn of(label: &GrayImage) -> Self {
        let mut h = LabelHistogram::default();
        h.add(label.as_raw());
        h
    }

    pub fn add(&mut self, values: &[u8]) {
        for &v in values {
            self.counts[usize::from(v)] += 1;
        }
    }

    pub fn merge(mut self, other: &LabelHistogram) -> Self {
        for (a, b) in self.counts.iter_mut().zip(other.counts.iter()) {
            *a += b;
        }
        self
    }

    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    pub fn count(&self, value: u8) -> u64 {
        self.counts[usize::from(value)]
    }

    /// Percent of all pixels (ignore included in the denominator) with this value.
    pub fn percent_of_all(&self, value: u8) -> f64 {
        percent(self.count(value), self.total())
    }

    /// Percent of the non-ignore pixels with this value.
    pub fn percent_of_labelled(&self, value: u8) -> f64 {
        percent(self.count(value), self.total() - self.count(IGNORE))
    }
}

fn percent(part: u64, whole: u64) -> f64 {
    if whole == 0 {
        0.0
    } else {
        100.0 * part as f64 / whole as f64
    }
}

/// Exact sums of an image set's pixel values per channel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChannelSums {
    pub pixels: u64,
    pub sum: [u128; 3],
    pub sum_sq: [u128; 3],
}

impl ChannelSums {
    pub fn of(image: &RgbImage) -> Self {
        // Per-image sums fit in u64 easily (255² · 2^32 < 2^64 for images up to 4 Gpx).
        let mut sum = [0u64; 3];
        let mut sum_sq = [0u64; 3];
        for px in image.as_raw().chunks_exact(3) {
            for c in 0..3 {
                let v = u64::from(px[c]);
                sum[c] += v;
                sum_sq[c] += v * v;
            }
        }
        ChannelSums {
            pixels: u64::from(image.width()) * u64::from(image.height()),
            sum: sum.map(u128::from),
            sum_sq: sum_sq.map(u128::from),
        }
    }

    pub fn merge(mut self, other: &ChannelSums) -> Self {
        self.pixels += other.pixels;
        for c in 0..3 {
            self.sum[c] += other.sum[c];
            self.sum_sq[c] += other.sum_sq[c];
        }
        self
    }

    pub fn mean(&self) -> [f64; 3] {
        let n = self.pixels.max(1) as f64;
        self.sum.map(|s| s as f64 / n)
    }

    /// Population standard deviation (divides by N, as numpy's default).
    pub fn std(&self) -> [f64; 3] {
        let n = u128::from(self.pixels.max(1));
        std::array::from_fn(|c| {
            // N·Σx² ≥ (Σx)² always (Cauchy–Schwarz), so this cannot underflow.
            let scaled_var = n * self.sum_sq[c] - self.sum[c] * self.sum[c];
            (scaled_var as f64).sqrt() / n as f64
        })
    }
}

/// Figures of one class.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassStats {
    pub id: u8,
    pub name: String,
    pub pixels: u64,
    /// Percent of all pixels, ignore included in the denominator.
    pub percent_of_all: f64,
    /// Percent of non-ignore pixels.
    pub percent_of_labelled: f64,
    /// Images with at least one pixel of the class.
    pub images: u64,
    /// Median frequency balancing weight; None when the class never occurs.
    pub weight: Option<f64>,
    /// Whether the card says the source labels this class at all.
    pub labelable: bool,
}

/// What `dataset stats` writes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetStats {
    pub dataset: String,
    pub images: u64,
    pub pixels: u64,
    /// Per channel R, G, B on the 0..255 scale.
    pub mean_rgb: [f64; 3],
    /// Population standard deviation per channel, 0..255.
    pub std_rgb: [f64; 3],
    pub classes: Vec<ClassStats>,
    pub ignore_pixels: u64,
    pub ignore_percent_of_all: f64,
    pub weight_formula: String,
}

pub const WEIGHT_FORMULA: &str = "median frequency balancing: freq(c) = pixels of c / pixels of images containing c; weight(c) = median(freq) / freq(c); ignore pixels excluded";

/// Sums of one image and its label.
#[derive(Debug, Clone, Default)]
struct Partial {
    channels: ChannelSums,
    labels: LabelHistogram,
    /// Per class: images that contain it, and the pixels of those images.
    images_with: [u64; NUM_CLASSES],
    pixels_of_images_with: [u64; NUM_CLASSES],
}

impl Partial {
    fn of(image: &RgbImage, label: &GrayImage) -> Partial {
        let labels = LabelHistogram::of(label);
        let pixels = u64::from(label.width()) * u64::from(label.height());
        let mut p = Partial {
            channels: ChannelSums::of(image),
            labels,
            ..Partial::default()
        };
        for c in 0..NUM_CLASSES {
            if p.labels.counts[c] > 0 {
                p.images_with[c] = 1;
                p.pixels_of_images_with[c] = pixels;
            }
        }
        p
    }

    fn merge(mut self, o: Partial) -> Partial {
        self.channels = self.channels.merge(&o.channels);
        self.labels = self.labels.merge(&o.labels);
        for c in 0..NUM_CLASSES {
            self.images_with[c] += o.images_with[c];
            self.pixels_of_images_with[c] += o.pixels_of_images_with[c];
        }
        self
    }
}

/// Median-frequency-balancing weights from per-class pixel counts and the pixels of the
/// images containing each class (see the module docs). None where a class is absent.
pub fn median_frequency_weights(counts: &[u64], pixels_of_images_with: &[u64]) -> Vec<Option<f64>> {
    let freqs: Vec<Option<f64>> = counts
        .iter()
        .zip(pixels_of_images_with)
        .map(|(&n, &px)| (n > 0 && px > 0).then(|| n as f64 / px as f64))
        .collect();
    let mut present: Vec<f64> = freqs.iter().flatten().copied().collect();
    present.sort_by(f64::total_cmp);
    let median = match present.len() {
        0 => return vec![None; counts.len()],
        n if n % 2 == 1 => present[n / 2],
        n => (present[n / 2 - 1] + present[n / 2]) / 2.0,
    };
    freqs.iter().map(|f| f.map(|f| median / f)).collect()
}

/// Computes the statistics of a dataset (images in parallel; exact integer sums).
/// Labels are checked on the way: a wrong size or a value outside the table is an error.
pub fn dataset_stats(dataset: &Dataset) -> Result<DatasetStats> {
    dataset_stats_with_progress(dataset, &|| {})
}

/// [`dataset_stats`], calling `item_done` after each item (from the worker threads).
pub fn dataset_stats_with_progress(
    dataset: &Dataset,
    item_done: &(dyn Fn() + Sync),
) -> Result<DatasetStats> {
    let partials: Vec<Partial> = dataset
        .items
        .par_iter()
        .map(|item| {
            let image = read_rgb(&dataset.image_path(item))?;
            let label = read_class_label(&dataset.label_path(item), image.width(), image.height())?;
            item_done();
            Ok(Partial::of(&image, &label))
        })
        .collect::<Result<_>>()?;
    let total = partials
        .into_iter()
        .fold(Partial::default(), Partial::merge);
    Ok(summarise(dataset, &total))
}

fn summarise(dataset: &Dataset, total: &Partial) -> DatasetStats {
    let counts: Vec<u64> = (0..NUM_CLASSES).map(|c| total.labels.counts[c]).collect();
    let weights = median_frequency_weights(&counts, &total.pixels_of_images_with);
    let classes = Class::ALL
        .iter()
        .zip(weights)
        .map(|(&class, weight)| ClassStats {
            id: class.id(),
            name: class.name().to_owned(),
            pixels: total.labels.count(class.id()),
            percent_of_all: total.labels.percent_of_all(class.id()),
            percent_of_labelled: total.labels.percent_of_labelled(class.id()),
            images: total.images_with[usize::from(class.id())],
            weight,
            labelable: dataset.card.labels(class),
        })
        .collect();
    DatasetStats {
        dataset: dataset.card.name.clone(),
        images: dataset.items.len() as u64,
        pixels: total.channels.pixels,
        mean_rgb: total.channels.mean(),
        std_rgb: total.channels.std(),
        classes,
        ignore_pixels: total.labels.count(IGNORE),
        ignore_percent_of_all: total.labels.percent_of_all(IGNORE),
        weight_formula: WEIGHT_FORMULA.to_owned(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_std_are_exact() {
        // Values 0 and 255 in equal numbers: mean 127.5, std 127.5 exactly.
        let image = RgbImage::from_fn(4, 2, |x, _| {
            image::Rgb([if x % 2 == 0 { 0 } else { 255 }; 3])
        });
        let s = ChannelSums::of(&image);
        assert_eq!(s.mean(), [127.5; 3]);
        assert_eq!(s.std(), [127.5; 3]);
        // Merging is order-independent and equals the sums of the whole.
        let a = ChannelSums::of(&RgbImage::from_pixel(3, 1, image::Rgb([1, 2, 3])));
        let b = ChannelSums::of(&RgbImage::from_pixel(1, 1, image::Rgb([5, 6, 7])));
        assert_eq!(a.merge(&b), b.merge(&a));
        assert_eq!(a.merge(&b).mean(), [2.0, 3.0, 4.0]);
        assert!((a.merge(&b).std()[0] - 3f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn median_frequency_weights_follow_the_formula() {
        // freq = 0.5, 0.1, 0.2 -> median 0.2 -> weights 0.4, 2, 1; class 3 absent.
        let w = median_frequency_weights(&[50, 10, 20, 0], &[100, 100, 100, 0]);
        let expected = [Some(0.4), Some(2.0), Some(1.0), None];
        for (got, want) in w.iter().zip(expected) {
            match (got, want) {
                (Some(g), Some(e)) => assert!((g - e).abs() < 1e-12, "{g} vs {e}"),
                (g, e) => assert_eq!(*g, e),
            }
        }
    }
}
