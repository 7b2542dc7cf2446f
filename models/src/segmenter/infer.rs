//! Inference on images: normalisation, prediction at the original resolution, and the
//! evaluation rule for classes a source cannot label.

use burn::tensor::activation::softmax;
use burn::tensor::{Device, Int, Tensor, TensorData};
use image::{GrayImage, RgbImage, imageops};

use super::data::scaled_size;
use super::model::{PspNet, PspNetConfig, resize};

/// RGB8 images of one size to the network's input: `(pixel - mean) / std` per channel,
/// `[batch, 3, H, W]`; with `per_image_normalisation`, each image's own per-channel mean and
/// standard deviation (the latter at least 1, in 0-255 units).
pub fn normalise(images: &[&RgbImage], config: &PspNetConfig, device: &Device) -> Tensor<4> {
    let (w, h) = images.first().map_or((0, 0), |i| i.dimensions());
    let (w, h) = (w as usize, h as usize);
    let plane = w * h;
    let mut values = vec![0.0f32; images.len() * 3 * plane];
    for (b, image) in images.iter().enumerate() {
        let (mean, std) = if config.per_image_normalisation {
            image_statistics(image, plane)
        } else {
            (config.mean, config.std)
        };
        for (i, pixel) in image.as_raw().chunks_exact(3).enumerate().take(plane) {
            for c in 0..3 {
                values[(b * 3 + c) * plane + i] = (f32::from(pixel[c]) - mean[c]) / std[c];
            }
        }
    }
    Tensor::from_data(TensorData::new(values, [images.len(), 3, h, w]), device)
}

/// Per-channel mean and standard deviation (at least 1) of an image's first `plane` pixels,
/// summed in f64 so the order of the pixels does not matter.
fn image_statistics(image: &RgbImage, plane: usize) -> ([f32; 3], [f32; 3]) {
    let mut sum = [0.0f64; 3];
    let mut squares = [0.0f64; 3];
    let mut n = 0.0f64;
    for pixel in image.as_raw().chunks_exact(3).take(plane) {
        for c in 0..3 {
            let v = f64::from(pixel[c]);
            sum[c] += v;
            squares[c] += v * v;
        }
        n += 1.0;
    }
    let n = n.max(1.0);
    let mean = sum.map(|s| s / n);
    let std: [f32; 3] = std::array::from_fn(|c| {
        ((squares[c] / n - mean[c] * mean[c])
            .max(0.0)
            .sqrt()
            .max(1.0)) as f32
    });
    (mean.map(|m| m as f32), std)
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

/// How a trained network is run on an image.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Inference {
    /// The image is resized so its short side is this many pixels (None: as it is).
    pub short: Option<u32>,
    /// Multi-scale test: the image is also run at these short sides, and the class
    /// probabilities of every size, resized to the image's size, are averaged. Small
    /// objects are more pixels at a larger size, large ones fit the pyramid pooling better
    /// at a smaller one.
    pub extra_shorts: Vec<u32>,
    /// Test-time flip: the class probabilities of the image and of its mirror image (mirrored
    /// back) are averaged. Twice the work; the scene's left and right are equally likely in
    /// the data, so the two predictions err differently on thin and small objects.
    pub flip: bool,
}

impl Inference {
    /// One pass at `short`, no flip.
    pub fn at(short: Option<u32>) -> Self {
        Self {
            short,
            ..Self::default()
        }
    }

    /// Whether several predictions are averaged (as class probabilities). A single plain
    /// pass keeps the logits: the same argmax, without the softmax's cost.
    fn averages(&self) -> bool {
        self.flip || !self.extra_shorts.is_empty()
    }
}

/// Predicts the label of one image: resized as `inference` says, run through the network,
/// class scores resized back to the image's size, argmax.
pub fn predict_label(
    model: &PspNet,
    config: &PspNetConfig,
    image: &RgbImage,
    inference: &Inference,
    device: &Device,
) -> GrayImage {
    let (w, h) = image.dimensions();
    let shorts =
        std::iter::once(inference.short).chain(inference.extra_shorts.iter().map(|&s| Some(s)));
    let mut sum: Option<Tensor<4>> = None;
    for short in shorts {
        let scores = scores_at(model, config, image, short, inference, device);
        let scores = resize(scores, [h as usize, w as usize], config.align_corners);
        sum = Some(match sum {
            Some(total) => total + scores,
            None => scores,
        });
    }
    let pixels = sum
        .and_then(|scores| argmax_labels(scores).pop())
        .unwrap_or_default();
    GrayImage::from_raw(w, h, pixels).unwrap_or_else(|| GrayImage::new(w, h))
}

/// `[1, classes, H', W']` scores of `image` resized to a short side of `short`: logits, or
/// class probabilities when `inference` averages several predictions (with its flip, the
/// average of the image's and its mirror's).
fn scores_at(
    model: &PspNet,
    config: &PspNetConfig,
    image: &RgbImage,
    short: Option<u32>,
    inference: &Inference,
    device: &Device,
) -> Tensor<4> {
    let (w, h) = image.dimensions();
    let resized;
    let input = match short {
        Some(s) if scaled_size(w, h, s) != (w, h) => {
            let (nw, nh) = scaled_size(w, h, s);
            resized = imageops::resize(image, nw, nh, imageops::FilterType::Triangle);
            &resized
        }
        _ => image,
    };
    let x = normalise(&[input], config, device);
    if inference.flip {
        // One batch of two: the image and its mirror; the mirror's probabilities are
        // mirrored back before the average. [2, classes, H, W] -> [1, classes, H, W].
        let probabilities = softmax(
            model.forward(Tensor::cat(vec![x.clone(), x.flip([3])], 0)),
            1,
        );
        let direct = probabilities.clone().narrow(0, 0, 1);
        let mirrored = probabilities.narrow(0, 1, 1).flip([3]);
        (direct + mirrored) / 2.0
    } else if inference.averages() {
        softmax(model.forward(x), 1)
    } else {
        model.forward(x)
    }
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
    fn per_image_normalisation_ignores_exposure_and_contrast() {
        let config = PspNetConfig::new().with_per_image_normalisation(true);
        let raw: Vec<u8> = (0..48u8).map(|v| 40 + 3 * v).collect();
        let bright = RgbImage::from_raw(4, 4, raw.clone()).unwrap_or_default();
        // The same picture at half the exposure, 10 levels up: an affine change per channel.
        let dim =
            RgbImage::from_raw(4, 4, raw.iter().map(|v| v / 2 + 10).collect()).unwrap_or_default();
        let a = normalise(&[&bright], &config, &Device::flex());
        let b = normalise(&[&dim], &config, &Device::flex());
        let (a, b) = (
            a.into_data().try_to_vec::<f32>().unwrap_or_default(),
            b.into_data().try_to_vec::<f32>().unwrap_or_default(),
        );
        let channel = &a[..16];
        let mean = channel.iter().sum::<f32>() / 16.0;
        let var = channel.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / 16.0;
        assert!(
            mean.abs() < 1e-5 && (var - 1.0).abs() < 1e-4,
            "{mean} {var}"
        );
        // Integer halving rounds, so the two agree to about one level in the spread.
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 0.05, "{x} {y}");
        }
        // Off, the two differ.
        let plain = PspNetConfig::new();
        let c = normalise(&[&dim], &plain, &Device::flex());
        let c = c.into_data().try_to_vec::<f32>().unwrap_or_default();
        assert!(c.iter().zip(&a).any(|(x, y)| (x - y).abs() > 0.5));
    }

    /// A tiny untrained network with weights from `seed`, its config and device.
    fn tiny_network(seed: u64) -> (PspNet, PspNetConfig, Device) {
        let device = Device::flex();
        let config = crate::segmenter::model::tiny_test_config();
        let model = config
            .init_seeded(&device, seed)
            .unwrap_or_else(|e| panic!("{e}"));
        (model, config, device)
    }

    /// A 40 × 24 image with no symmetry; `rotate` rotates its three colour patterns
    /// among the channels.
    fn asymmetric_image(rotate: usize) -> RgbImage {
        RgbImage::from_fn(40, 24, |x, y| {
            let mut channels = [(x * 6) as u8, (y * 10) as u8, ((x * y) % 251) as u8];
            channels.rotate_left(rotate);
            image::Rgb(channels)
        })
    }

    #[test]
    fn a_flipped_prediction_of_a_mirror_image_is_the_mirror_of_the_flipped_prediction() {
        // Untrained networks are not mirror-symmetric, so a plain prediction is not
        // equivariant; averaging with the mirror image makes it so (up to ties).
        let (model, config, device) = tiny_network(3);
        let image = asymmetric_image(0);
        let mirror = imageops::flip_horizontal(&image);
        let predict = |image: &RgbImage, flip: bool| {
            let inference = Inference {
                flip,
                ..Inference::default()
            };
            predict_label(&model, &config, image, &inference, &device)
        };
        let plain = imageops::flip_horizontal(&predict(&mirror, false));
        assert_ne!(
            plain,
            predict(&image, false),
            "the test needs an asymmetric network"
        );
        assert_eq!(
            imageops::flip_horizontal(&predict(&mirror, true)),
            predict(&image, true)
        );
    }

    #[test]
    fn extra_sizes_average_into_a_label_of_the_image_size() {
        let (model, config, device) = tiny_network(5);
        let image = asymmetric_image(2);
        let predict = |extra_shorts: Vec<u32>| {
            let inference = Inference {
                extra_shorts,
                ..Inference::default()
            };
            predict_label(&model, &config, &image, &inference, &device)
        };
        let single = predict(Vec::new());
        // The image's own size again: the same probabilities twice, the same argmax.
        assert_eq!(predict(vec![24]), single);
        // Another size is resized back to the image's and changes some pixels.
        let multi = predict(vec![48]);
        assert_eq!(multi.dimensions(), (40, 24));
        assert_ne!(multi, single);
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
