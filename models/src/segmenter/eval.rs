//! Evaluation of a model on datasets: a confusion matrix over all of them and one per
//! source, with the rule for classes a source cannot label applied to the predictions.

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
    for source in sources {
        let mut matrix = ConfusionMatrix::new(config.classes);
        let count = limit.map_or(source.items.len(), |l| l.min(source.items.len()));
        for &item in &source.items[..count] {
            let sample = source.load(item)?;
            let mut pixels =
                predict_label(model, config, &sample.image, inference, device).into_raw();
            credit_unlabelable(sample.label.as_raw(), &mut pixels, &source.unlabelable);
            matrix.add(sample.label.as_raw(), &pixels);
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
    })
}
