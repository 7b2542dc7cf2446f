//! Segmentation metrics from a confusion matrix: per-class IoU, mIoU, pixel accuracy, mean
//! accuracy and frequency-weighted IoU, as mmsegmentation and the Cityscapes scripts define
//! them.
//!
//! Rows are the true class, columns the predicted one; pixels labelled [`IGNORE`] (or any
//! value outside the class range) are not counted. A class is *present* when the ground
//! truth has at least one of its pixels; mIoU and mean accuracy average over the present
//! classes only, so a class a validation set does not contain neither helps nor hurts
//! (false positives of such a class still lower the IoU of the true classes they replace).
//!
//! [`bootstrap_iou`] gives 95 % intervals of mIoU and the per-class IoUs over images: the
//! evaluated images are resampled with replacement and their confusion matrices summed.

use std::collections::BTreeMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use datasets::IGNORE;
use sim::stats::percentile_interval;

/// Pixel counts by (true class, predicted class).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ConfusionMatrix {
    classes: usize,
    /// Row-major `classes × classes`: `counts[truth * classes + prediction]`.
    counts: Vec<u64>,
}

impl ConfusionMatrix {
    pub fn new(classes: usize) -> ConfusionMatrix {
        ConfusionMatrix {
            classes,
            counts: vec![0; classes * classes],
        }
    }

    /// A matrix from its rows (truth) of predicted counts; None if it is not square.
    pub fn from_rows(rows: &[Vec<u64>]) -> Option<ConfusionMatrix> {
        let classes = rows.len();
        if rows.iter().any(|r| r.len() != classes) {
            return None;
        }
        Some(ConfusionMatrix {
            classes,
            counts: rows.concat(),
        })
    }

    pub fn classes(&self) -> usize {
        self.classes
    }

    /// Pixels of true class `truth` predicted as `prediction`.
    pub fn count(&self, truth: usize, prediction: usize) -> u64 {
        self.counts[truth * self.classes + prediction]
    }

    /// The rows (truth) of predicted counts.
    pub fn rows(&self) -> Vec<Vec<u64>> {
        self.counts
            .chunks(self.classes.max(1))
            .map(<[u64]>::to_vec)
            .collect()
    }

    /// Counts a label and its prediction, pixel by pixel (same length). Labels outside the
    /// class range ([`IGNORE`] among them) are skipped; a prediction outside it is a bug of
    /// the caller and is skipped too.
    pub fn add(&mut self, truth: &[u8], prediction: &[u8]) {
        for (&t, &p) in truth.iter().zip(prediction) {
            let (t, p) = (usize::from(t), usize::from(p));
            if t < self.classes && p < self.classes && t != usize::from(IGNORE) {
                self.counts[t * self.classes + p] += 1;
            }
        }
    }

    /// Adds another matrix of the same size (a no-op for a different size).
    pub fn merge(&mut self, other: &ConfusionMatrix) {
        if other.classes == self.classes {
            for (a, b) in self.counts.iter_mut().zip(&other.counts) {
                *a += b;
            }
        }
    }

    /// Counted pixels.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    fn true_count(&self, class: usize) -> u64 {
        (0..self.classes).map(|p| self.count(class, p)).sum()
    }

    fn predicted_count(&self, class: usize) -> u64 {
        (0..self.classes).map(|t| self.count(t, class)).sum()
    }

    /// Whether the ground truth has pixels of `class`.
    pub fn is_present(&self, class: usize) -> bool {
        self.true_count(class) > 0
    }

    /// IoU = TP / (TP + FP + FN) of each class; None where the class is neither in the
    /// truth nor predicted (0 / 0).
    pub fn iou(&self) -> Vec<Option<f64>> {
        (0..self.classes)
            .map(|c| {
                let tp = self.count(c, c);
                let union = self.true_count(c) + self.predicted_count(c) - tp;
                (union > 0).then(|| tp as f64 / union as f64)
            })
            .collect()
    }

    /// Mean IoU over the present classes (0 when nothing was counted).
    pub fn miou(&self) -> f64 {
        self.miou_over(&(0..self.classes).collect::<Vec<_>>())
    }

    /// Mean IoU over those of `classes` that are present.
    pub fn miou_over(&self, classes: &[usize]) -> f64 {
        let iou = self.iou();
        mean(
            classes
                .iter()
                .filter(|&&c| c < self.classes && self.is_present(c))
                .map(|&c| iou[c].unwrap_or(0.0)),
        )
    }

    /// Correct pixels over counted pixels.
    pub fn pixel_accuracy(&self) -> f64 {
        let correct: u64 = (0..self.classes).map(|c| self.count(c, c)).sum();
        ratio(correct, self.total())
    }

    /// Per-class recall TP / (TP + FN) averaged over the present classes.
    pub fn mean_accuracy(&self) -> f64 {
        mean(
            (0..self.classes)
                .filter(|&c| self.is_present(c))
                .map(|c| ratio(self.count(c, c), self.true_count(c))),
        )
    }

    /// IoU of each class weighted by its share of the true pixels.
    pub fn frequency_weighted_iou(&self) -> f64 {
        let total = self.total();
        let iou = self.iou();
        (0..self.classes)
            .filter(|&c| self.is_present(c))
            .map(|c| ratio(self.true_count(c), total) * iou[c].unwrap_or(0.0))
            .sum()
    }

    /// All the figures at once, classes named by `names` (by index).
    pub fn summary(&self, names: &[&str]) -> MetricsSummary {
        let iou = self.iou();
        MetricsSummary {
            miou: self.miou(),
            pixel_accuracy: self.pixel_accuracy(),
            mean_accuracy: self.mean_accuracy(),
            frequency_weighted_iou: self.frequency_weighted_iou(),
            per_class_iou: (0..self.classes)
                .filter(|&c| self.is_present(c))
                .map(|c| {
                    let name = names
                        .get(c)
                        .map_or_else(|| c.to_string(), |n| (*n).to_owned());
                    (name, iou[c].unwrap_or(0.0))
                })
                .collect(),
            pixels: self.total(),
        }
    }
}

/// The headline figures of a confusion matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricsSummary {
    pub miou: f64,
    pub pixel_accuracy: f64,
    pub mean_accuracy: f64,
    pub frequency_weighted_iou: f64,
    /// IoU of each present class, by class name.
    pub per_class_iou: BTreeMap<String, f64>,
    /// Pixels counted (not ignored).
    pub pixels: u64,
}

/// Resamples [`bootstrap_iou`] draws by default.
pub const BOOTSTRAP_RESAMPLES: usize = 1000;

/// Seed of [`bootstrap_iou`]'s generator (ChaCha8), so the intervals are the same on every run.
pub const BOOTSTRAP_SEED: u64 = 0;

/// 95 % percentile-bootstrap intervals (2.5 and 97.5 percentiles), as `[lo, hi]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IouIntervals {
    pub miou: (f64, f64),
    /// By class name: the classes present in the ground truth of all the images (those of
    /// [`MetricsSummary::per_class_iou`]).
    pub per_class_iou: BTreeMap<String, (f64, f64)>,
}

/// Intervals of mIoU and of each class's IoU over `images`, one confusion matrix per image
/// (all of one size): `resamples` times, as many images as there are are drawn with
/// replacement (ChaCha8 seeded by `seed`), their matrices summed, and the IoUs and the mIoU
/// of the sum computed by the rule of [`ConfusionMatrix::miou`] (over the classes present
/// in the sum). A class present in the images but absent from a resample's ground truth is
/// skipped for that resample. Classes are named by `names` (by index), as in
/// [`ConfusionMatrix::summary`]. With no images, or no resamples, every interval is the
/// point value twice.
pub fn bootstrap_iou(
    images: &[&ConfusionMatrix],
    names: &[&str],
    resamples: usize,
    seed: u64,
) -> IouIntervals {
    let classes = images.first().map_or(0, |m| m.classes);
    let mut pooled = ConfusionMatrix::new(classes);
    for image in images {
        pooled.merge(image);
    }
    let present: Vec<usize> = (0..classes).filter(|&c| pooled.is_present(c)).collect();
    let mut mious = Vec::with_capacity(resamples);
    let mut ious: Vec<Vec<f64>> = vec![Vec::with_capacity(resamples); present.len()];
    if !images.is_empty() {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut sum = ConfusionMatrix::new(classes);
        for _ in 0..resamples {
            sum.counts.fill(0);
            for _ in 0..images.len() {
                sum.merge(images[rng.random_range(0..images.len())]);
            }
            mious.push(sum.miou());
            let iou = sum.iou();
            for (samples, &c) in ious.iter_mut().zip(&present) {
                if sum.is_present(c) {
                    samples.push(iou[c].unwrap_or(0.0));
                }
            }
        }
    }
    let point = pooled.iou();
    IouIntervals {
        miou: percentile_interval(&mut mious, pooled.miou()),
        per_class_iou: present
            .iter()
            .zip(&mut ious)
            .map(|(&c, samples)| {
                let name = names
                    .get(c)
                    .map_or_else(|| c.to_string(), |n| (*n).to_owned());
                (name, percentile_interval(samples, point[c].unwrap_or(0.0)))
            })
            .collect(),
    }
}

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
}

fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if n == 0 { 0.0 } else { sum / n as f64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    /// A 3-class matrix worked out by hand:
    ///
    /// ```text
    ///            pred 0  pred 1  pred 2   | truth
    /// truth 0       50      10       0    |   60
    /// truth 1        5      20       5    |   30
    /// truth 2        0       0       0    |    0   (absent)
    /// predicted     55      30       5    |   90
    /// ```
    /// IoU0 = 50 / (60 + 55 - 50) = 50/65, IoU1 = 20 / (30 + 30 - 20) = 20/40,
    /// IoU2 = 0 / (0 + 5 - 0) = 0 but class 2 is absent, so mIoU = (50/65 + 1/2) / 2.
    #[test]
    fn known_matrix_gives_hand_computed_figures() -> Result<(), String> {
        let m = ConfusionMatrix::from_rows(&[vec![50, 10, 0], vec![5, 20, 5], vec![0, 0, 0]])
            .ok_or("not square")?;
        let iou = m.iou();
        assert!(close(iou[0].unwrap_or(-1.0), 50.0 / 65.0));
        assert!(close(iou[1].unwrap_or(-1.0), 0.5));
        assert_eq!(iou[2], Some(0.0));
        assert!(close(m.miou(), (50.0 / 65.0 + 0.5) / 2.0));
        assert!(close(m.pixel_accuracy(), 70.0 / 90.0));
        assert!(close(m.mean_accuracy(), (50.0 / 60.0 + 20.0 / 30.0) / 2.0));
        assert!(close(
            m.frequency_weighted_iou(),
            60.0 / 90.0 * 50.0 / 65.0 + 30.0 / 90.0 * 0.5
        ));
        assert!(close(m.miou_over(&[1]), 0.5));
        let s = m.summary(&["road", "lane_marking", "vehicle"]);
        assert_eq!(s.per_class_iou.len(), 2);
        assert!(close(s.per_class_iou["lane_marking"], 0.5));
        assert_eq!(s.pixels, 90);
        Ok(())
    }

    #[test]
    fn adding_pixels_skips_ignore_and_merges() {
        let mut m = ConfusionMatrix::new(2);
        m.add(&[0, 0, 1, 255, 1], &[0, 1, 1, 0, 1]);
        assert_eq!(m.rows(), vec![vec![1, 1], vec![0, 2]]);
        let copy = m.clone();
        m.merge(&copy);
        assert_eq!(m.total(), 8);
        assert!(close(m.pixel_accuracy(), 0.75));
        // Perfect prediction: every figure is 1.
        let mut p = ConfusionMatrix::new(3);
        p.add(&[0, 1, 2, 2], &[0, 1, 2, 2]);
        assert!(close(p.miou(), 1.0) && close(p.frequency_weighted_iou(), 1.0));
        assert!(close(ConfusionMatrix::new(3).miou(), 0.0));
    }

    fn matrix(rows: &[Vec<u64>]) -> ConfusionMatrix {
        ConfusionMatrix::from_rows(rows).unwrap_or_else(|| panic!("not square"))
    }

    #[test]
    fn identical_images_give_a_zero_width_interval_at_the_point_value() {
        let image = matrix(&[vec![50, 10, 0], vec![5, 20, 5], vec![0, 0, 0]]);
        let images = vec![&image; 7];
        let names = ["road", "lane_marking", "vehicle"];
        let ci = bootstrap_iou(&images, &names, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED);
        let miou = (50.0 / 65.0 + 0.5) / 2.0;
        assert_eq!(ci.miou, (miou, miou));
        // The absent class has no interval, as it has no figure.
        assert_eq!(ci.per_class_iou.len(), 2);
        assert_eq!(ci.per_class_iou["road"], (50.0 / 65.0, 50.0 / 65.0));
        assert_eq!(ci.per_class_iou["lane_marking"], (0.5, 0.5));
    }

    #[test]
    fn different_images_give_an_interval_around_the_pooled_value() {
        // A: perfect; B: half wrong. Pooled: IoU 15 / 25 = 0.6 for both classes; resamples
        // of A alone give 1, of B alone 5 / 15.
        let a = matrix(&[vec![10, 0], vec![0, 10]]);
        let b = matrix(&[vec![5, 5], vec![5, 5]]);
        let ci = bootstrap_iou(&[&a, &b], &["road", "lane_marking"], 1000, 0);
        let (lo, hi) = ci.miou;
        assert!(lo < 0.6 && 0.6 < hi, "{lo} {hi}");
        assert!((lo - 1.0 / 3.0).abs() < 1e-12 && hi == 1.0, "{lo} {hi}");
        for (lo, hi) in ci.per_class_iou.values() {
            assert!(*lo < 0.6 && 0.6 < *hi, "{lo} {hi}");
        }
        // Deterministic for a seed; another seed draws other resamples.
        let many: Vec<ConfusionMatrix> = (0..20u64)
            .map(|i| matrix(&[vec![10 + i, 3 * (i % 4)], vec![i % 5, 4 + i % 7]]))
            .collect();
        let many: Vec<&ConfusionMatrix> = many.iter().collect();
        let names = ["road", "lane_marking"];
        let first = bootstrap_iou(&many, &names, 200, 0);
        assert_eq!(first, bootstrap_iou(&many, &names, 200, 0));
        assert_ne!(first, bootstrap_iou(&many, &names, 200, 1));
        assert!(first.miou.0 < first.miou.1);
    }

    #[test]
    fn a_class_a_resample_lacks_is_skipped_for_it() {
        // Class 1 is only in A (IoU 2 / 4); B is class 0 predicted right. Resamples of B
        // alone have no class 1: its interval stays at 0.5 instead of reaching down to 0,
        // and their mIoU is class 0's alone, 1.
        let a = matrix(&[vec![10, 0], vec![2, 2]]);
        let b = matrix(&[vec![10, 0], vec![0, 0]]);
        let ci = bootstrap_iou(&[&a, &b], &["road", "lane_marking"], 1000, 0);
        assert_eq!(ci.per_class_iou["lane_marking"], (0.5, 0.5));
        assert_eq!(ci.miou.1, 1.0);
        // No images: the point values, nothing per class.
        let none = bootstrap_iou(&[], &[], 1000, 0);
        assert_eq!(none.miou, (0.0, 0.0));
        assert!(none.per_class_iou.is_empty());
    }
}
