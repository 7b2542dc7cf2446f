//! Filters and degradations of the image (the label is left alone): Gaussian and motion
//! blur, Gaussian noise, JPEG artefacts. Integer arithmetic where it matters for speed;
//! every result is deterministic.

use std::io::Cursor;

use image::RgbImage;
use image::codecs::jpeg::JpegEncoder;

/// Kernel radius for a Gaussian of `sigma`: ⌈3σ⌉, at least 1 (the same rule the benchmark
/// gives albumentations: kernel size 2·radius + 1).
pub fn gaussian_radius(sigma: f64) -> usize {
    ((3.0 * sigma).ceil() as usize).max(1)
}

/// Fixed-point weights (sum exactly 256) of a sampled, normalised Gaussian: 8 fractional
/// bits, as OpenCV's bit-exact 8-bit Gaussian blur uses, so every product fits in u16.
fn gaussian_weights(sigma: f64) -> Vec<u16> {
    let r = gaussian_radius(sigma) as i64;
    let raw: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = raw.iter().sum();
    let mut w: Vec<u16> = raw
        .iter()
        .map(|v| (v / sum * 256.0).round() as u16)
        .collect();
    // Put the rounding remainder on the centre tap so the weights sum to exactly 256.
    let total: u16 = w.iter().sum();
    let centre = r as usize;
    w[centre] = (w[centre] + 256).saturating_sub(total);
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

/// Separable Gaussian blur (reflected borders), all in u16 so the loops vectorise 8 values
/// wide on baseline x86-64. Horizontal pass: u8 times 8-bit weights summing to 256 gives
/// the value·256 exactly in u16. Vertical pass: each value·256 times a weight, keeping the
/// high 16 bits (a multiply-high), summed to the result·256 (each product truncated by less
/// than 1/256), then rounded to u8. Rows go through the horizontal pass once, into a ring
/// of the 2r + 1 rows the vertical pass needs, which stays in cache.
pub fn gaussian_blur(image: &mut RgbImage, sigma: f64) {
    if sigma <= 0.0 {
        return;
    }
    let weights = gaussian_weights(sigma);
    let r = weights.len() / 2;
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w == 0 || h == 0 || weights[r] >= 256 {
        // Empty, or a kernel too narrow to move any weight off the centre: unchanged.
        return;
    }
    let stride = w * 3;
    let taps = weights.len();
    // Ring of horizontally blurred rows: input row `y` lives in slot `y % taps`. The rows
    // output row `y` needs, reflect(y - r ..= y + r), all lie in y-r ..= y+r clipped to the
    // image: at most `taps` consecutive rows, so their slots differ.
    let mut ring = vec![0u16; taps * stride];
    let mut filled = 0; // rows 0..filled are in the ring (the last `taps` of them)
    let mut padded = vec![0u8; (w + 2 * r) * 3];
    let mut acc = vec![0u16; stride];
    let rows: Vec<usize> = (0..h + 2 * r)
        .map(|py| reflect(py as isize - r as isize, h))
        .collect();
    // Input rows are read only when they enter the ring, and output row y is made after
    // row y entered it, so the output can overwrite the image in place.
    let dst = image.as_mut();
    for y in 0..h {
        let need = (y + r + 1).min(h);
        while filled < need {
            let row = &dst[filled * stride..(filled + 1) * stride];
            padded[r * 3..r * 3 + stride].copy_from_slice(row);
            for px in (0..r).chain(w + r..w + 2 * r) {
                let sx = reflect(px as isize - r as isize, w);
                padded[px * 3..px * 3 + 3].copy_from_slice(&row[sx * 3..sx * 3 + 3]);
            }
            let slot = &mut ring[(filled % taps) * stride..(filled % taps + 1) * stride];
            slot.fill(0);
            for (k, &wk) in weights.iter().enumerate() {
                for (o, &p) in slot.iter_mut().zip(&padded[k * 3..k * 3 + stride]) {
                    *o = o.wrapping_add(wk * u16::from(p));
                }
            }
            filled += 1;
        }
        acc.fill(0);
        for (k, &wk) in weights.iter().enumerate() {
            let s = rows[y + k] % taps;
            // At most 255 (a weight of 256 returned early above): fits u16 after the shift.
            let wk = u32::from(wk << 8);
            for (a, &v) in acc.iter_mut().zip(&ring[s * stride..(s + 1) * stride]) {
                *a = a.wrapping_add(((u32::from(v) * wk) >> 16) as u16);
            }
        }
        for (d, &a) in dst[y * stride..(y + 1) * stride].iter_mut().zip(&acc) {
            *d = ((u32::from(a) + 128) >> 8).min(255) as u8;
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

/// Levels of the quantised normal distribution the noise draws from.
const NORMAL_LEVELS: usize = 4096;

/// Quantiles of the standard normal at `(i + 0.5) / 4096`: sampling an index uniformly
/// draws from the normal distribution quantised to 4,096 equally likely levels (tails cut
/// at ±3.5σ, about 1 value in 2,000 beyond that).
fn normal_table() -> &'static [f32; NORMAL_LEVELS] {
    static TABLE: std::sync::OnceLock<[f32; NORMAL_LEVELS]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        std::array::from_fn(|i| inverse_normal_cdf((i as f64 + 0.5) / NORMAL_LEVELS as f64) as f32)
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

/// SplitMix64 (Steele, Lea and Flood 2014): a fast generator of well mixed 64-bit words,
/// fully determined by its starting state.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
}

/// Adds independent Gaussian noise of standard deviation `sigma` (0..255 scale) to every
/// value. Each value takes 12 bits of a SplitMix64 stream started at `seed` (five values a
/// word) as the index of a normal quantile; the quantiles are scaled by σ and rounded once
/// per call, so a value becomes `clamp(v + round(σ·z))`.
pub fn gaussian_noise(image: &mut RgbImage, sigma: f64, seed: u64) {
    let offsets = noise_offsets(sigma);
    let mut rng = SplitMix64(seed);
    // The offsets of a block are looked up first (scalar), then added with clamping in a
    // loop that vectorises. The block is a multiple of 5 values, so words split the same.
    let mut noise = [0i16; 1280];
    for chunk in image.as_mut().chunks_mut(noise.len()) {
        let noise = &mut noise[..chunk.len()];
        for five in noise.chunks_mut(5) {
            let mut bits = rng.next();
            for n in five {
                *n = offsets[(bits & (NORMAL_LEVELS as u64 - 1)) as usize];
                bits >>= 12;
            }
        }
        for (v, &n) in chunk.iter_mut().zip(noise.iter()) {
            *v = (i16::from(*v) + n).clamp(0, 255) as u8;
        }
    }
}

/// The table of `round(σ·z)` over the normal quantiles.
fn noise_offsets(sigma: f64) -> [i16; NORMAL_LEVELS] {
    let s = sigma as f32;
    // round(σz) = ⌊σz + 0.5⌋, the floor taken by truncating a shifted, non-negative value
    // (f32::floor is a libm call on baseline x86-64).
    normal_table().map(|z| ((s * z + 0.5).clamp(-1024.0, 1024.0) + 1024.0) as i16 - 1024)
}

/// Why a JPEG round trip ([`jpeg`]) failed.
#[derive(Debug, thiserror::Error)]
pub enum JpegRoundTripError {
    #[error("JPEG encoding failed: {0}")]
    Encode(image::ImageError),
    #[error("JPEG decoding failed: {0}")]
    Decode(image::ImageError),
    #[error("JPEG round trip changed the size")]
    Size,
}

/// Compresses as JPEG at `quality` (1-100) and decodes again.
pub fn jpeg(image: &mut RgbImage, quality: u8) -> Result<(), JpegRoundTripError> {
    let mut bytes = Vec::new();
    JpegEncoder::new_with_quality(&mut bytes, quality.clamp(1, 100))
        .encode_image(&*image)
        .map_err(JpegRoundTripError::Encode)?;
    let decoded = image::load(Cursor::new(&bytes), image::ImageFormat::Jpeg)
        .map_err(JpegRoundTripError::Decode)?
        .into_rgb8();
    if decoded.dimensions() != image.dimensions() {
        return Err(JpegRoundTripError::Size);
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
            assert_eq!(gaussian_weights(sigma).iter().sum::<u16>(), 256);
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
    fn noise_is_the_table_offset_of_each_value_clamped() {
        let base = RgbImage::from_fn(61, 47, |x, y| {
            image::Rgb([(x * 4) as u8, (y * 5) as u8, 250])
        });
        let mut fast = base.clone();
        gaussian_noise(&mut fast, 12.5, 7);
        // Value i takes 12-bit field i % 5 of word i / 5 of the stream.
        let offsets = noise_offsets(12.5);
        let mut rng = SplitMix64(7);
        let mut word = 0;
        for (i, (&f, &v)) in fast.iter().zip(base.iter()).enumerate() {
            if i % 5 == 0 {
                word = rng.next();
            }
            let n = offsets[((word >> (12 * (i % 5))) & 4095) as usize];
            assert_eq!(
                f,
                (i32::from(v) + i32::from(n)).clamp(0, 255) as u8,
                "value {i}"
            );
        }
        assert!(fast.contains(&255) && fast != base);
    }

    /// The blur done the plain way: the same 8-bit weights, in f64, reflected borders.
    fn reference_blur(image: &RgbImage, sigma: f64) -> RgbImage {
        let weights: Vec<f64> = gaussian_weights(sigma)
            .iter()
            .map(|&w| f64::from(w) / 256.0)
            .collect();
        let r = (weights.len() / 2) as isize;
        let (w, h) = (image.width() as usize, image.height() as usize);
        let at = |x: usize, y: usize, k: usize| f64::from(image.get_pixel(x as u32, y as u32).0[k]);
        let mut mid = vec![0.0; w * h * 3];
        for y in 0..h {
            for x in 0..w {
                for k in 0..3 {
                    mid[(y * w + x) * 3 + k] = (-r..=r)
                        .map(|d| weights[(d + r) as usize] * at(reflect(x as isize + d, w), y, k))
                        .sum();
                }
            }
        }
        RgbImage::from_fn(w as u32, h as u32, |x, y| {
            let (x, y) = (x as usize, y as usize);
            image::Rgb([0, 1, 2].map(|k| {
                let v: f64 = (-r..=r)
                    .map(|d| {
                        weights[(d + r) as usize]
                            * mid[(reflect(y as isize + d, h) * w + x) * 3 + k]
                    })
                    .sum();
                v.round() as u8
            }))
        })
    }

    #[test]
    fn blur_matches_the_plain_computation() {
        for (w, h) in [(23, 17), (1, 1), (2, 3), (7, 2), (4, 11)] {
            let image = RgbImage::from_fn(w, h, |x, y| {
                image::Rgb([
                    (x * 97 + y * 31) as u8,
                    ((x * y) % 7 * 40) as u8,
                    (y * 60) as u8,
                ])
            });
            for sigma in [0.3, 0.5, 0.9, 1.5, 2.7] {
                let mut fast = image.clone();
                gaussian_blur(&mut fast, sigma);
                let slow = reference_blur(&image, sigma);
                for (i, (&f, &s)) in fast.iter().zip(slow.iter()).enumerate() {
                    assert!(
                        (i32::from(f) - i32::from(s)).abs() <= 1,
                        "{w}x{h} sigma {sigma} value {i}: {f} vs {s}"
                    );
                }
            }
        }
    }

    #[test]
    fn jpeg_round_trip_keeps_the_size() -> Result<(), JpegRoundTripError> {
        let mut i = RgbImage::from_fn(33, 17, |x, y| image::Rgb([x as u8 * 7, y as u8 * 13, 99]));
        jpeg(&mut i, 30)?;
        assert_eq!(i.dimensions(), (33, 17));
        Ok(())
    }
}
