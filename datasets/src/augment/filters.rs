//! Filters and degradations of the image (the label is left alone): Gaussian and motion
//! blur, Gaussian noise, JPEG artefacts. Integer arithmetic where it matters for speed;
//! every result is deterministic.

use std::io::Cursor;

use image::RgbImage;
use image::codecs::jpeg::JpegEncoder;
use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Kernel radius for a Gaussian of `sigma`: ⌈3σ⌉, at least 1 (the same rule the benchmark
/// gives albumentations: kernel size 2·radius + 1).
pub fn gaussian_radius(sigma: f64) -> usize {
    ((3.0 * sigma).ceil() as usize).max(1)
}

/// Fixed-point weights (sum exactly 2^14) of a sampled, normalised Gaussian.
fn gaussian_weights(sigma: f64) -> Vec<u32> {
    let r = gaussian_radius(sigma) as i64;
    let raw: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = raw.iter().sum();
    let mut w: Vec<u32> = raw
        .iter()
        .map(|v| (v / sum * 16384.0).round() as u32)
        .collect();
    // Put the rounding remainder on the centre tap so the weights sum to exactly 2^14.
    let total: u32 = w.iter().sum();
    let centre = r as usize;
    w[centre] = (w[centre] + 16384).saturating_sub(total);
    w
}

/// Index into `0..n` with mirrored borders (`dcb|abcd|cba`, OpenCV's BORDER_REFLECT_101).
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let period = 2 * (n - 1);
    let m = i.rem_euclid(period);
    (if m < n { m } else { period - m }) as usize
}

/// Separable Gaussian blur (reflected borders). Horizontal pass into 8 extra bits of
/// precision, vertical pass rounding back to u8.
pub fn gaussian_blur(image: &mut RgbImage, sigma: f64) {
    if sigma <= 0.0 {
        return;
    }
    let weights = gaussian_weights(sigma);
    let r = weights.len() / 2;
    let (w, h) = (image.width() as usize, image.height() as usize);
    let src = image.as_raw();
    // Horizontal: u8 -> u16 holding value·256.
    let mut mid = vec![0u16; w * h * 3];
    let mut padded = vec![0u8; (w + 2 * r) * 3];
    for y in 0..h {
        let row = &src[y * w * 3..(y + 1) * w * 3];
        for (px, chunk) in padded.chunks_exact_mut(3).enumerate() {
            let sx = reflect(px as isize - r as isize, w);
            chunk.copy_from_slice(&row[sx * 3..sx * 3 + 3]);
        }
        let out = &mut mid[y * w * 3..(y + 1) * w * 3];
        for (i, o) in out.iter_mut().enumerate() {
            let mut acc = 0u32;
            for (k, &wk) in weights.iter().enumerate() {
                acc += wk * u32::from(padded[i + k * 3]);
            }
            *o = ((acc + (1 << 5)) >> 6) as u16;
        }
    }
    // Vertical: u16 -> u8.
    let dst = image.as_mut();
    let rows: Vec<usize> = (0..h + 2 * r)
        .map(|py| reflect(py as isize - r as isize, h))
        .collect();
    let stride = w * 3;
    let mut acc = vec![0u32; stride];
    for y in 0..h {
        acc.iter_mut().for_each(|a| *a = 0);
        for (k, &wk) in weights.iter().enumerate() {
            let src_row = &mid[rows[y + k] * stride..rows[y + k] * stride + stride];
            for (a, &v) in acc.iter_mut().zip(src_row) {
                *a += wk * u32::from(v);
            }
        }
        for (d, &a) in dst[y * stride..(y + 1) * stride].iter_mut().zip(&acc) {
            *d = ((a + (1 << 21)) >> 22).min(255) as u8;
        }
    }
}

/// Motion blur: the mean of `length` copies shifted along a line at `degrees` (0 =
/// horizontal), centred on the pixel; borders clamp.
pub fn motion_blur(image: &mut RgbImage, length: u32, degrees: f64) {
    let n = length.max(1) as i64;
    if n == 1 {
        return;
    }
    let (s, c) = degrees.to_radians().sin_cos();
    let offsets: Vec<(i64, i64)> = (0..n)
        .map(|i| {
            let t = i as f64 - (n - 1) as f64 / 2.0;
            ((t * c).round() as i64, (-t * s).round() as i64)
        })
        .collect();
    let (w, h) = (i64::from(image.width()), i64::from(image.height()));
    let src = image.as_raw().clone();
    let dst = image.as_mut();
    let half = (n / 2) as u32;
    let mut acc = vec![0u32; (w * 3) as usize];
    for y in 0..h {
        acc.iter_mut().for_each(|a| *a = 0);
        for &(dx, dy) in &offsets {
            let sy = (y + dy).clamp(0, h - 1);
            let row = &src[(sy * w * 3) as usize..((sy + 1) * w * 3) as usize];
            for x in 0..w {
                let sx = (x + dx).clamp(0, w - 1) as usize;
                let a = &mut acc[(x * 3) as usize..(x * 3 + 3) as usize];
                for k in 0..3 {
                    a[k] += u32::from(row[sx * 3 + k]);
                }
            }
        }
        let out = &mut dst[(y * w * 3) as usize..((y + 1) * w * 3) as usize];
        for (d, &a) in out.iter_mut().zip(&acc) {
            *d = ((a + half) / n as u32) as u8;
        }
    }
}

/// Quantiles of the standard normal at `(i + 0.5) / 65536`: sampling an index uniformly
/// draws from the normal distribution quantised to 65,536 equally likely levels (tails
/// cut at ±4.3σ, which a 0..255 image cannot show anyway).
fn normal_table() -> &'static [f32; 65536] {
    static TABLE: std::sync::OnceLock<Box<[f32; 65536]>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = Box::new([0f32; 65536]);
        for (i, v) in t.iter_mut().enumerate() {
            *v = inverse_normal_cdf((i as f64 + 0.5) / 65536.0) as f32;
        }
        t
    })
}

/// Acklam's rational approximation of the standard normal quantile (relative error
/// below 1.2e-9), refined by one Halley step.
fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// Adds independent Gaussian noise of standard deviation `sigma` (0..255 scale) to every
/// value, drawn from a ChaCha8 stream seeded with `seed`.
pub fn gaussian_noise(image: &mut RgbImage, sigma: f64, seed: u64) {
    let table = normal_table();
    let s = sigma as f32;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut bits = [0u8; 4096];
    for chunk in image.as_mut().chunks_mut(bits.len() / 2) {
        rng.fill_bytes(&mut bits[..chunk.len() * 2]);
        for (v, b) in chunk.iter_mut().zip(bits.chunks_exact(2)) {
            let z = table[usize::from(u16::from_le_bytes([b[0], b[1]]))];
            *v = super::colour::to_u8(f32::from(*v) + s * z);
        }
    }
}

/// Compresses as JPEG at `quality` (1-100) and decodes again.
pub fn jpeg(image: &mut RgbImage, quality: u8) -> Result<(), String> {
    let mut bytes = Vec::new();
    JpegEncoder::new_with_quality(&mut bytes, quality.clamp(1, 100))
        .encode_image(&*image)
        .map_err(|e| format!("JPEG encoding failed: {e}"))?;
    let decoded = image::load(Cursor::new(&bytes), image::ImageFormat::Jpeg)
        .map_err(|e| format!("JPEG decoding failed: {e}"))?
        .into_rgb8();
    if decoded.dimensions() != image.dimensions() {
        return Err("JPEG round trip changed the size".into());
    }
    *image = decoded;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_keeps_flat_images_and_sums_to_one() {
        for sigma in [0.5, 1.0, 1.5, 3.2] {
            assert_eq!(gaussian_weights(sigma).iter().sum::<u32>(), 16384);
            let mut i = RgbImage::from_pixel(9, 7, image::Rgb([10, 128, 255]));
            gaussian_blur(&mut i, sigma);
            assert!(i.pixels().all(|p| p.0 == [10, 128, 255]), "sigma {sigma}");
            let mut m = i.clone();
            motion_blur(&mut m, 5, 30.0);
            assert_eq!(m, i);
        }
    }

    #[test]
    fn blur_spreads_a_dot_symmetrically() {
        let mut i = RgbImage::new(11, 11);
        i.put_pixel(5, 5, image::Rgb([255, 255, 255]));
        gaussian_blur(&mut i, 1.0);
        let c = i.get_pixel(5, 5).0[0];
        assert!(c > 30 && c < 50, "{c}"); // 255 / (2π) ≈ 40.6
        assert_eq!(i.get_pixel(4, 5), i.get_pixel(6, 5));
        assert_eq!(i.get_pixel(5, 4), i.get_pixel(4, 5));
    }

    #[test]
    fn noise_has_the_asked_spread_and_is_seeded() {
        let base = RgbImage::from_pixel(200, 100, image::Rgb([128, 128, 128]));
        let mut a = base.clone();
        gaussian_noise(&mut a, 10.0, 42);
        let mut b = base.clone();
        gaussian_noise(&mut b, 10.0, 42);
        assert_eq!(a, b);
        let n = a.as_raw().len() as f64;
        let mean = a.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let var = a
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / n;
        assert!((mean - 128.0).abs() < 0.2, "{mean}");
        // Rounding to integers adds 1/12 to the variance.
        assert!((var.sqrt() - 10.0).abs() < 0.2, "{}", var.sqrt());
        assert!((inverse_normal_cdf(0.975) - 1.959_964).abs() < 1e-5);
    }

    #[test]
    fn jpeg_round_trip_keeps_the_size() -> Result<(), String> {
        let mut i = RgbImage::from_fn(33, 17, |x, y| image::Rgb([x as u8 * 7, y as u8 * 13, 99]));
        jpeg(&mut i, 30)?;
        assert_eq!(i.dimensions(), (33, 17));
        Ok(())
    }
}
