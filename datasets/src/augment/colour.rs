//! Photometric transforms: they change the image's colours and leave the label alone.
//! Values are on the 0..255 scale; every result is rounded and clamped to u8.

use image::RgbImage;

/// Rounds to the nearest u8, clamping to 0..255 (NaN gives 0). `+ 0.5` and the saturating
/// cast instead of `round()`: the same rounding here, but baseline x86-64 has no rounding
/// instruction, so `round()` is a libm call per value, a sixth of the augmentation's time.
pub(crate) fn to_u8(v: f32) -> u8 {
    (v + 0.5) as u8
}

/// Applies a per-value lookup table to every channel.
fn map_values(image: &mut RgbImage, table: &[u8; 256]) {
    for v in image.iter_mut() {
        *v = table[usize::from(*v)];
    }
}

fn table(f: impl Fn(f32) -> f32) -> [u8; 256] {
    std::array::from_fn(|v| to_u8(f(v as f32)))
}

/// Adds `delta` (a fraction of 255) to every value.
pub fn brightness(image: &mut RgbImage, delta: f64) {
    let d = (delta * 255.0) as f32;
    map_values(image, &table(|v| v + d));
}

/// Scales the distance of every value from the image's mean grey by `factor`.
pub fn contrast(image: &mut RgbImage, factor: f64) {
    let n = image.as_raw().len().max(1) as f64;
    let sum: u64 = image.as_raw().iter().map(|&v| u64::from(v)).sum();
    let mean = (sum as f64 / n) as f32;
    let f = factor as f32;
    map_values(image, &table(|v| mean + (v - mean) * f));
}

/// `255 · (v / 255)^gamma`.
pub fn gamma(image: &mut RgbImage, gamma: f64) {
    let g = gamma as f32;
    map_values(image, &table(|v| 255.0 * (v / 255.0).powf(g)));
}

/// Applies a 3×3 colour matrix to every pixel.
fn colour_matrix(image: &mut RgbImage, m: &[[f32; 3]; 3]) {
    for px in image.as_mut().chunks_exact_mut(3) {
        let [r, g, b] = [f32::from(px[0]), f32::from(px[1]), f32::from(px[2])];
        for (out, row) in px.iter_mut().zip(m) {
            *out = to_u8(row[0] * r + row[1] * g + row[2] * b);
        }
    }
}

/// Rotates hues by `degrees`: a rotation about the grey axis in YIQ space (luma kept).
pub fn hue(image: &mut RgbImage, degrees: f64) {
    let (s, c) = (degrees.to_radians() as f32).sin_cos();
    // RGB -> YIQ, rotate I/Q, YIQ -> RGB, folded into one matrix.
    const TO_YIQ: [[f32; 3]; 3] = [
        [0.299, 0.587, 0.114],
        [0.596, -0.274, -0.322],
        [0.211, -0.523, 0.312],
    ];
    const TO_RGB: [[f32; 3]; 3] = [
        [1.0, 0.956, 0.621],
        [1.0, -0.272, -0.647],
        [1.0, -1.106, 1.703],
    ];
    let rot = [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]];
    let mul = |a: &[[f32; 3]; 3], b: &[[f32; 3]; 3]| -> [[f32; 3]; 3] {
        std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
    };
    colour_matrix(image, &mul(&TO_RGB, &mul(&rot, &TO_YIQ)));
}

/// Scales every pixel's distance from its own grey (Rec. 601 luma) by `factor`.
pub fn saturation(image: &mut RgbImage, factor: f64) {
    let f = factor as f32;
    let (wr, wg, wb) = (0.299f32, 0.587f32, 0.114f32);
    // grey + f (v - grey) = f v + (1 - f) grey, as a matrix.
    let g = 1.0 - f;
    let m = [
        [f + g * wr, g * wg, g * wb],
        [g * wr, f + g * wg, g * wb],
        [g * wr, g * wg, f + g * wb],
    ];
    colour_matrix(image, &m);
}

/// Fog colour: a light bluish grey.
const FOG: [f32; 3] = [205.0, 210.0, 215.0];

/// Blends towards fog, most at the top (far away), fading to nothing at `horizon` (a
/// fraction of the height) and below: `a(y) = density · (1 − y / (horizon·H))²`.
pub fn fog(image: &mut RgbImage, density: f64, horizon: f64) {
    let (w, h) = (image.width() as usize, image.height() as f64);
    let reach = (horizon * h).max(1.0);
    for (y, row) in image.as_mut().chunks_exact_mut(w * 3).enumerate() {
        let t = (1.0 - (y as f64 + 0.5) / reach).max(0.0);
        let a = (density * t * t) as f32;
        if a <= 0.0 {
            continue;
        }
        for px in row.chunks_exact_mut(3) {
            for (v, f) in px.iter_mut().zip(FOG) {
                *v = to_u8(f32::from(*v) * (1.0 - a) + f * a);
            }
        }
    }
}

/// Darkens the inside of a polygon (corners as fractions of width and height) by
/// `darkness` (0 = no change, 1 = black). Inside = even-odd rule at pixel centres.
pub fn shadow(image: &mut RgbImage, polygon: &[[f64; 2]], darkness: f64) {
    let (w, h) = (f64::from(image.width()), f64::from(image.height()));
    let points: Vec<(f64, f64)> = polygon.iter().map(|p| (p[0] * w, p[1] * h)).collect();
    let keep = (1.0 - darkness.clamp(0.0, 1.0)) as f32;
    let stride = image.width() as usize * 3;
    let n = points.len();
    for (y, row) in image.as_mut().chunks_exact_mut(stride).enumerate() {
        let cy = y as f64 + 0.5;
        let mut xs: Vec<f64> = (0..n)
            .filter_map(|i| {
                let (a, b) = (points[i], points[(i + 1) % n]);
                ((a.1 <= cy) != (b.1 <= cy)).then(|| a.0 + (cy - a.1) / (b.1 - a.1) * (b.0 - a.0))
            })
            .collect();
        xs.sort_by(f64::total_cmp);
        for span in xs.chunks_exact(2) {
            // Pixels whose centre lies in [span0, span1).
            let start = (span[0] - 0.5).ceil().clamp(0.0, w) as usize;
            let end = (span[1] - 0.5).ceil().clamp(0.0, w) as usize;
            for v in &mut row[start * 3..end * 3] {
                *v = to_u8(f32::from(*v) * keep);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grey(v: u8) -> RgbImage {
        RgbImage::from_pixel(4, 4, image::Rgb([v, v, v]))
    }

    #[test]
    fn neutral_parameters_change_nothing() {
        let img = RgbImage::from_fn(5, 3, |x, y| image::Rgb([x as u8 * 40, y as u8 * 90, 17]));
        let mut i = img.clone();
        brightness(&mut i, 0.0);
        contrast(&mut i, 1.0);
        gamma(&mut i, 1.0);
        saturation(&mut i, 1.0);
        fog(&mut i, 0.0, 0.5);
        shadow(&mut i, &[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]], 0.0);
        assert_eq!(i, img);
        // Hue 0 goes through YIQ and back: within one step of rounding.
        hue(&mut i, 0.0);
        for (a, b) in i.iter().zip(img.iter()) {
            assert!(a.abs_diff(*b) <= 1, "{a} vs {b}");
        }
    }

    #[test]
    fn greys_keep_their_grey_under_hue_and_saturation() {
        let mut i = grey(120);
        hue(&mut i, 77.0);
        saturation(&mut i, 0.3);
        assert!(i.iter().all(|&v| v.abs_diff(120) <= 1));
    }

    #[test]
    fn shadow_darkens_only_inside() {
        let mut i = grey(200);
        shadow(
            &mut i,
            &[[0.0, 0.0], [0.5, 0.0], [0.5, 1.0], [0.0, 1.0]],
            0.5,
        );
        assert_eq!(i.get_pixel(0, 0).0, [100; 3]);
        assert_eq!(i.get_pixel(1, 3).0, [100; 3]);
        assert_eq!(i.get_pixel(2, 0).0, [200; 3]);
    }
}
