//! Evaluation of a model on datasets: a confusion matrix over all of them, one per source
//! and one per image (for intervals over images, [`super::metrics::bootstrap_iou`]), with
//! the rule for classes a source cannot label applied to the predictions.

use burn::tensor::Device;
use datasets::classes::Class;
use image::GrayImage;

use super::data::{Sample, Source};
use super::error::Result;
use super::infer::{Inference, credit_unlabelable, predict_label};
use super::metrics::ConfusionMatrix;
use super::model::{PspNet, PspNetConfig};

/// Confusion matrices of an evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    pub overall: ConfusionMatrix,
    /// By source (card name), in the order given.
    pub per_source: Vec<(String, ConfusionMatrix)>,
    pub images: usize,
    /// Each evaluated image's matrix, in the order evaluated.
    pub per_image: Vec<ImageConfusion>,
}

/// The confusion matrix of one evaluated image.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageConfusion {
    /// Index of its source in [`Evaluation::per_source`].
    pub source: usize,
    /// The item's id.
    pub id: String,
    pub matrix: ConfusionMatrix,
}

impl Evaluation {
    /// The images' matrices: all of them, or those of source `source`.
    pub fn image_matrices(&self, source: Option<usize>) -> Vec<&ConfusionMatrix> {
        self.per_image
            .iter()
            .filter(|i| source.is_none_or(|s| i.source == s))
            .map(|i| &i.matrix)
            .collect()
    }
}

/// Names of the classes of a `classes`-way model: the project's table for 5, numbers
/// otherwise.
pub fn class_names(classes: usize) -> Vec<String> {
    (0..classes)
        .map(|c| match Class::from_id(c as u8) {
            Some(class) if classes == Class::ALL.len() => class.name().to_owned(),
            _ => c.to_string(),
        })
        .collect()
}

/// An evaluated item: the sample and the prediction, for previews.
#[derive(Debug, Clone)]
pub struct Prediction {
    pub sample: Sample,
    pub prediction: GrayImage,
}

/// Evaluates `model` on the items of `sources` (at most `limit` per source), each predicted
/// as `inference` says. `on_item(done, total, &prediction)` is called after each image.
pub fn evaluate(
    model: &PspNet,
    config: &PspNetConfig,
    sources: &[Source],
    inference: &Inference,
    limit: Option<usize>,
    device: &Device,
    mut on_item: impl FnMut(usize, usize, &Prediction),
) -> Result<Evaluation> {
    let mut overall = ConfusionMatrix::new(config.classes);
    let mut per_source = Vec::new();
    let total: usize = sources
        .iter()
        .map(|s| limit.map_or(s.items.len(), |l| l.min(s.items.len())))
        .sum();
    let mut done = 0;
    let mut per_image = Vec::with_capacity(total);
    for (index, source) in sources.iter().enumerate() {
        let mut matrix = ConfusionMatrix::new(config.classes);
        let count = limit.map_or(source.items.len(), |l| l.min(source.items.len()));
        for &item in &source.items[..count] {
            let sample = source.load(item)?;
            let mut pixels =
                predict_label(model, config, &sample.image, inference, device).into_raw();
            credit_unlabelable(sample.label.as_raw(), &mut pixels, &source.unlabelable);
            let mut image = ConfusionMatrix::new(config.classes);
            image.add(sample.label.as_raw(), &pixels);
            matrix.merge(&image);
            per_image.push(ImageConfusion {
                source: index,
                id: sample.id.clone(),
                matrix: image,
            });
            let (w, h) = sample.label.dimensions();
            let prediction =
                GrayImage::from_raw(w, h, pixels).unwrap_or_else(|| GrayImage::new(w, h));
            done += 1;
            on_item(done, total, &Prediction { sample, prediction });
        }
        overall.merge(&matrix);
        per_source.push((source.name.clone(), matrix));
    }
    Ok(Evaluation {
        overall,
        per_source,
        images: done,
        per_image,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segmenter::data::{SourceSpec, Split};
    use crate::segmenter::synthetic::write_synthetic_dataset;

    #[test]
    fn each_image_keeps_its_matrix_and_they_sum_to_the_totals() {
        let tmp = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let device = Device::flex();
        let config = crate::segmenter::model::tiny_test_config();
        let model = config
            .init_seeded(&device, 1)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut sources = Vec::new();
        for (name, count) in [("a", 3), ("b", 2)] {
            let dir = tmp.path().join(name);
            write_synthetic_dataset(&dir, count, 32, 5, None).unwrap_or_else(|e| panic!("{e}"));
            let spec = SourceSpec {
                path: dir,
                weight: 1.0,
            };
            sources.push(Source::open(&spec, Split::All).unwrap_or_else(|e| panic!("{e}")));
        }
        let e = evaluate(
            &model,
            &config,
            &sources,
            &Inference::default(),
            None,
            &device,
            |_, _, _| {},
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((e.images, e.per_image.len()), (5, 5));
        let ids: Vec<(usize, &str)> = e
            .per_image
            .iter()
            .map(|i| (i.source, i.id.as_str()))
            .collect();
        assert_eq!(
            ids,
            [
                (0, "scene0000"),
                (0, "scene0001"),
                (0, "scene0002"),
                (1, "scene0000"),
                (1, "scene0001")
            ]
        );
        let sum = |images: Vec<&ConfusionMatrix>| {
            let mut m = ConfusionMatrix::new(config.classes);
            for image in images {
                assert_eq!(image.total(), 32 * 32);
                m.merge(image);
            }
            m
        };
        assert_eq!(sum(e.image_matrices(None)), e.overall);
        for (index, (_, matrix)) in e.per_source.iter().enumerate() {
            assert_eq!(&sum(e.image_matrices(Some(index))), matrix);
        }
    }
}
