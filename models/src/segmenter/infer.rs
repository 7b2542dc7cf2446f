//! Inference on images: normalisation, prediction at the original resolution, and the
//! evaluation rule for classes a source cannot label.

use burn::tensor::{Device, Int, Tensor, TensorData};
use image::{GrayImage, RgbImage, imageops};

use super::data::scaled_size;
use super::model::{PspNet, PspNetConfig, resize};

/// RGB8 images of one size to the network's input: `(pixel - mean) / std` per channel,
/// `[batch, 3, H, W]`.
pub fn normalise(images: &[&RgbImage], config: &PspNetConfig, device: &Device) -> Tensor<4> {
    let (w, h) = images.first().map_or((0, 0), |i| i.dimensions());
    let (w, h) = (w as usize, h as usize);
    let plane = w * h;
    let mut values = vec![0.0f32; images.len() * 3 * plane];
    for (b, image) in images.iter().enumerate() {
        for (i, pixel) in image.as_raw().chunks_exact(3).enumerate().take(plane) {
            for c in 0..3 {
                values[(b * 3 + c) * plane + i] =
                    (f32::from(pixel[c]) - config.mean[c]) / config.std[c];
            }
        }
    }
    Tensor::from_data(TensorData::new(values, [images.len(), 3, h, w]), device)
}

/// Class ids of `[batch, classes, H, W]` logits: `batch` labels of `H × W`, row-major.
pub fn argmax_labels(logits: Tensor<4>) -> Vec<Vec<u8>> {
    let [b, _, h, w] = logits.dims();
    let ids: Tensor<3, Int> = logits.argmax(1).squeeze_dim(1);
    let flat: Vec<u8> = ids
        .into_data()
        .iter::<i64>()
        .map(|v| v.clamp(0, 255) as u8)
        .collect();
    flat.chunks(h * w).take(b).map(<[u8]>::to_vec).collect()
}

/// Predicts the label of one image: resized so its short side is `short` (None: as it is),
/// run through the network, logits resized back to the image's size, argmax.
pub fn predict_label(
    model: &PspNet,
    config: &PspNetConfig,
    image: &RgbImage,
    short: Option<u32>,
    device: &Device,
) -> GrayImage {
    let (w, h) = image.dimensions();
    let input = match short {
        Some(s) if scaled_size(w, h, s) != (w, h) => {
            let (nw, nh) = scaled_size(w, h, s);
            imageops::resize(image, nw, nh, imageops::FilterType::Triangle)
        }
        _ => image.clone(),
    };
    let logits = model.forward(normalise(&[&input], config, device));
    let logits = resize(logits, [h as usize, w as usize], config.align_corners);
    let pixels = argmax_labels(logits).pop().unwrap_or_default();
    GrayImage::from_raw(w, h, pixels).unwrap_or_else(|| GrayImage::new(w, h))
}

/// The evaluation rule for a source that cannot label some classes (see [`super::loss`]):
/// a prediction of such a class on a pixel the source calls by the class it folds into
/// (lane marking on CamVid's road) counts as that label; elsewhere it is an error.
pub fn credit_unlabelable(truth: &[u8], prediction: &mut [u8], unlabelable: &[bool]) {
    if !unlabelable.iter().any(|&u| u) {
        return;
    }
    for (p, &t) in prediction.iter_mut().zip(truth) {
        if unlabelable.get(usize::from(*p)).copied().unwrap_or(false)
            && datasets::may_stand_for(t, *p)
        {
            *p = t;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalisation_is_per_channel_and_planar() {
        let config = PspNetConfig::new()
            .with_mean([10.0, 20.0, 30.0])
            .with_std([2.0, 4.0, 5.0]);
        let image = RgbImage::from_raw(2, 1, vec![10, 20, 30, 12, 28, 40]).unwrap_or_default();
        let t = normalise(&[&image], &config, &Device::flex());
        assert_eq!(t.dims(), [1, 3, 1, 2]);
        let v = t.into_data().try_to_vec::<f32>().unwrap_or_default();
        assert_eq!(v, vec![0.0, 1.0, 0.0, 2.0, 0.0, 2.0]);
    }

    #[test]
    fn unlabelable_markings_count_as_road_only() {
        // Road, road, vehicle, ignored, other; the network says marking on all but the second.
        let truth = [0u8, 0, 2, 255, 4];
        let mut pred = [1u8, 2, 1, 1, 1];
        credit_unlabelable(&truth, &mut pred, &[false, true, false, false, false]);
        assert_eq!(pred, [0, 2, 1, 1, 1]);
        // A source that cannot label humans gets no credit for them anywhere.
        let mut pred = [3u8, 3, 3, 3, 3];
        credit_unlabelable(&truth, &mut pred, &[false, false, false, true, false]);
        assert_eq!(pred, [3; 5]);
    }
}
