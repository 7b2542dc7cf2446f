//! Geometric transforms as one warp: consecutive crop, scale, rotation, flip and
//! perspective operations compose into a single 3×3 matrix from output to input pixel
//! coordinates, so an image is resampled once, however many of them a chain has.
//!
//! Coordinates are continuous: pixel `(col, row)` covers `[col, col+1) × [row, row+1)`.
//! For output pixel centre `p`, the matrix gives the input point `q`; the image is sampled
//! bilinearly around `q` (taps at the four pixel centres nearest to it), the label takes the
//! pixel that contains `q` — one of those four taps — so both look at the same place.
//! Outside the input the image is black and the label is ignore (255).
//!
//! A warp that is only an integer shift and/or a mirror (crops, flips) is an exact copy.

use image::{GrayImage, RgbImage};

use crate::classes::IGNORE;

/// A 3×3 matrix (row-major) mapping homogeneous output coordinates to input ones.
pub type Mat3 = [[f64; 3]; 3];

pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// Maps a point through a matrix.
pub fn apply(m: &Mat3, x: f64, y: f64) -> (f64, f64) {
    let w = m[2][0] * x + m[2][1] * y + m[2][2];
    (
        (m[0][0] * x + m[0][1] * y + m[0][2]) / w,
        (m[1][0] * x + m[1][1] * y + m[1][2]) / w,
    )
}

/// A pending resampling: output size and the matrix from output to source coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Warp {
    pub width: u32,
    pub height: u32,
    pub to_source: Mat3,
}

impl Warp {
    /// No change to an image of this size.
    pub fn identity(width: u32, height: u32) -> Warp {
        Warp {
            width,
            height,
            to_source: IDENTITY,
        }
    }

    /// Follows this warp by a step whose output has `size` and maps into this warp's output
    /// through `step`.
    fn then(self, (width, height): (u32, u32), step: &Mat3) -> Warp {
        Warp {
            width: width.max(1),
            height: height.max(1),
            to_source: mul(&self.to_source, step),
        }
    }

    /// A window `width × height` whose top-left corner is at `(x, y)`.
    pub fn crop(self, x: u32, y: u32, width: u32, height: u32) -> Warp {
        let step = [
            [1.0, 0.0, f64::from(x)],
            [0.0, 1.0, f64::from(y)],
            [0.0, 0.0, 1.0],
        ];
        self.then((width, height), &step)
    }

    /// Resizes by `factor` (output size rounded; the image still maps edge to edge).
    pub fn scale(self, factor: f64) -> Warp {
        let w = (f64::from(self.width) * factor).round().max(1.0) as u32;
        let h = (f64::from(self.height) * factor).round().max(1.0) as u32;
        let sx = f64::from(self.width) / f64::from(w);
        let sy = f64::from(self.height) / f64::from(h);
        self.then((w, h), &[[sx, 0.0, 0.0], [0.0, sy, 0.0], [0.0, 0.0, 1.0]])
    }

    /// Rotates the content by `degrees` counter-clockwise as seen, about the centre; the
    /// size stays, corners come in as padding.
    pub fn rotate(self, degrees: f64) -> Warp {
        let (s, c) = degrees.to_radians().sin_cos();
        let (cx, cy) = (f64::from(self.width) / 2.0, f64::from(self.height) / 2.0);
        // Output p = centre + R (q - centre) with R the visual counter-clockwise turn in
        // y-down coordinates; its inverse maps outputs back: q = centre + Rᵀ (p - centre).
        let step = [
            [c, -s, cx - c * cx + s * cy],
            [s, c, cy - s * cx - c * cy],
            [0.0, 0.0, 1.0],
        ];
        self.then((self.width, self.height), &step)
    }

    /// Mirrors left to right.
    pub fn hflip(self) -> Warp {
        let w = f64::from(self.width);
        self.then(
            (self.width, self.height),
            &[[-1.0, 0.0, w], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        )
    }

    /// A perspective warp: the output's corners (top-left, top-right, bottom-right,
    /// bottom-left) show these points of the input. None if they are degenerate.
    pub fn perspective(self, corners: &[[f64; 2]; 4]) -> Option<Warp> {
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let from = [[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]];
        let step = homography(&from, corners)?;
        Some(self.then((self.width, self.height), &step))
    }

    /// Whether the warp is an exact pixel copy: an integer shift, maybe mirrored.
    fn as_copy(&self) -> Option<CopyPlan> {
        let m = &self.to_source;
        let integral = |v: f64| v == v.round();
        let axis = |v: f64| v == 1.0 || v == -1.0;
        if m[2] != [0.0, 0.0, 1.0] || m[0][1] != 0.0 || m[1][0] != 0.0 {
            return None;
        }
        if !(axis(m[0][0]) && axis(m[1][1]) && integral(m[0][2]) && integral(m[1][2])) {
            return None;
        }
        // Output pixel x has centre x+0.5 -> input centre sx·(x+0.5)+tx -> column
        // sx·x + (tx + (sx-1)/2).
        Some(CopyPlan {
            sx: m[0][0] as i64,
            sy: m[1][1] as i64,
            tx: (m[0][2] + (m[0][0] - 1.0) / 2.0) as i64,
            ty: (m[1][2] + (m[1][1] - 1.0) / 2.0) as i64,
        })
    }

    /// Resamples an image and its label through the warp.
    pub fn run(&self, image: &RgbImage, label: &GrayImage) -> (RgbImage, GrayImage) {
        if let Some(plan) = self.as_copy() {
            let size = (self.width, self.height);
            let image = copy_raw(image.as_raw(), image.dimensions(), 3, size, &plan, 0);
            let label = copy_raw(label.as_raw(), label.dimensions(), 1, size, &plan, IGNORE);
            return (
                RgbImage::from_raw(size.0, size.1, image).unwrap_or_default(),
                GrayImage::from_raw(size.0, size.1, label).unwrap_or_default(),
            );
        }
        (self.warp_image(image), self.warp_label(label))
    }

    /// The source point of each output pixel centre, row by row.
    fn source_points(&self, mut f: impl FnMut(usize, f32, f32)) {
        let m = &self.to_source;
        let affine = m[2] == [0.0, 0.0, 1.0];
        let mut i = 0;
        for y in 0..self.height {
            let py = f64::from(y) + 0.5;
            for x in 0..self.width {
                let px = f64::from(x) + 0.5;
                let (qx, qy) = if affine {
                    (
                        m[0][0] * px + m[0][1] * py + m[0][2],
                        m[1][0] * px + m[1][1] * py + m[1][2],
                    )
                } else {
                    apply(m, px, py)
                };
                f(i, qx as f32, qy as f32);
                i += 1;
            }
        }
    }

    fn warp_image(&self, image: &RgbImage) -> RgbImage {
        let (w, h) = (image.width() as i32, image.height() as i32);
        let src = image.as_raw();
        let mut out = vec![0u8; self.width as usize * self.height as usize * 3];
        let tap = |x: i32, y: i32| -> [f32; 3] {
            if x < 0 || y < 0 || x >= w || y >= h {
                [0.0; 3]
            } else {
                let i = (y as usize * w as usize + x as usize) * 3;
                [
                    f32::from(src[i]),
                    f32::from(src[i + 1]),
                    f32::from(src[i + 2]),
                ]
            }
        };
        self.source_points(|i, qx, qy| {
            // Bilinear between the four pixel centres around q.
            let (fx, fy) = (qx - 0.5, qy - 0.5);
            let (x0, y0) = (floor_i32(fx), floor_i32(fy));
            let (ax, ay) = (fx - x0 as f32, fy - y0 as f32);
            if x0 < -1 || y0 < -1 || x0 >= w || y0 >= h {
                return;
            }
            let (a, b, c, d) = (
                tap(x0, y0),
                tap(x0 + 1, y0),
                tap(x0, y0 + 1),
                tap(x0 + 1, y0 + 1),
            );
            for k in 0..3 {
                let top = a[k] + (b[k] - a[k]) * ax;
                let bottom = c[k] + (d[k] - c[k]) * ax;
                out[i * 3 + k] = super::colour::to_u8(top + (bottom - top) * ay);
            }
        });
        RgbImage::from_raw(self.width, self.height, out).unwrap_or_default()
    }

    fn warp_label(&self, label: &GrayImage) -> GrayImage {
        let (w, h) = (label.width() as f32, label.height() as f32);
        let src = label.as_raw();
        let stride = label.width() as usize;
        let mut out = vec![IGNORE; self.width as usize * self.height as usize];
        self.source_points(|i, qx, qy| {
            if qx >= 0.0 && qy >= 0.0 && qx < w && qy < h {
                out[i] = src[qy as usize * stride + qx as usize];
            }
        });
        GrayImage::from_raw(self.width, self.height, out).unwrap_or_default()
    }
}

/// `v.floor() as i32` without the libm call (see `colour::to_u8`).
fn floor_i32(v: f32) -> i32 {
    let t = v as i32;
    t - i32::from((t as f32) > v)
}

/// An exact copy: output (x, y) takes input (sx·x + tx, sy·y + ty).
#[derive(Debug, Clone, Copy)]
struct CopyPlan {
    sx: i64,
    sy: i64,
    tx: i64,
    ty: i64,
}

/// Copies pixels of `channels` bytes each from a `sw × sh` buffer by the plan.
fn copy_raw(
    raw: &[u8],
    (sw, sh): (u32, u32),
    channels: usize,
    (width, height): (u32, u32),
    plan: &CopyPlan,
    fill: u8,
) -> Vec<u8> {
    let (sw, sh) = (i64::from(sw), i64::from(sh));
    let mut out = vec![fill; width as usize * height as usize * channels];
    for y in 0..i64::from(height) {
        let iy = plan.sy * y + plan.ty;
        if iy < 0 || iy >= sh {
            continue;
        }
        for x in 0..i64::from(width) {
            let ix = plan.sx * x + plan.tx;
            if ix < 0 || ix >= sw {
                continue;
            }
            let s = ((iy * sw + ix) as usize) * channels;
            let d = ((y * i64::from(width) + x) as usize) * channels;
            out[d..d + channels].copy_from_slice(&raw[s..s + channels]);
        }
    }
    out
}

/// The homography taking the four points `from` to `to` (solved exactly as an 8×8 linear
/// system); None when the points are degenerate.
pub fn homography(from: &[[f64; 2]; 4], to: &[[f64; 2]; 4]) -> Option<Mat3> {
    let mut a = [[0.0f64; 9]; 8];
    for (i, (p, q)) in from.iter().zip(to).enumerate() {
        let (x, y, u, v) = (p[0], p[1], q[0], q[1]);
        a[2 * i] = [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, u];
        a[2 * i + 1] = [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, v];
    }
    // Gaussian elimination with partial pivoting.
    for col in 0..8 {
        let pivot = (col..8).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() < 1e-12 {
            return None;
        }
        a.swap(col, pivot);
        let pivot_row = a[col];
        for (row, r) in a.iter_mut().enumerate() {
            if row != col {
                let f = r[col] / pivot_row[col];
                for (v, p) in r.iter_mut().zip(pivot_row).skip(col) {
                    *v -= f * p;
                }
            }
        }
    }
    let h: Vec<f64> = (0..8).map(|i| a[i][8] / a[i][i]).collect();
    Some([[h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], 1.0]])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn numbered(w: u32, h: u32) -> (RgbImage, GrayImage) {
        (
            RgbImage::from_fn(w, h, |x, y| image::Rgb([x as u8, y as u8, 7])),
            GrayImage::from_fn(w, h, |x, y| image::Luma([((x + y) % 5) as u8])),
        )
    }

    #[test]
    fn crop_and_flip_are_exact_copies() {
        let (img, lab) = numbered(6, 4);
        let warp = Warp::identity(6, 4).crop(1, 1, 3, 2).hflip();
        let (i, l) = warp.run(&img, &lab);
        assert_eq!(i.dimensions(), (3, 2));
        // Output (0,0) is input (3,1) after the flip of the 3-wide window starting at x=1.
        assert_eq!(i.get_pixel(0, 0).0, [3, 1, 7]);
        assert_eq!(i.get_pixel(2, 1).0, [1, 2, 7]);
        assert_eq!(l.get_pixel(0, 0).0, [4]); // (3 + 1) % 5
    }

    #[test]
    fn a_quarter_turn_moves_the_top_right_corner_to_the_top_left() {
        // Square image; rotating the content 90° counter-clockwise brings the top-right
        // corner to the top-left.
        let (img, lab) = numbered(4, 4);
        let (i, l) = Warp::identity(4, 4).rotate(90.0).run(&img, &lab);
        assert_eq!(i.get_pixel(0, 0).0, img.get_pixel(3, 0).0);
        assert_eq!(l.get_pixel(0, 0).0, lab.get_pixel(3, 0).0);
        assert_eq!(i.get_pixel(0, 3).0, img.get_pixel(0, 0).0);
    }

    #[test]
    fn homography_maps_its_corners() -> Result<(), String> {
        let from = [[0.0, 0.0], [10.0, 0.0], [10.0, 8.0], [0.0, 8.0]];
        let to = [[1.0, 0.5], [9.0, 1.0], [10.0, 7.0], [0.0, 8.0]];
        let h = homography(&from, &to).ok_or("degenerate")?;
        for (p, q) in from.iter().zip(&to) {
            let (x, y) = apply(&h, p[0], p[1]);
            assert!((x - q[0]).abs() < 1e-9 && (y - q[1]).abs() < 1e-9);
        }
        assert!(homography(&from, &[[0.0, 0.0]; 4]).is_none());
        Ok(())
    }

    #[test]
    fn outside_the_input_is_black_and_ignored() {
        // 16x16 halved to 8x8, turned 45°: the output's corner pixel comes from ~2 input
        // pixels beyond the edge, so all its bilinear taps are padding.
        let img = RgbImage::from_pixel(16, 16, image::Rgb([200, 100, 50]));
        let lab = GrayImage::from_pixel(16, 16, image::Luma([2]));
        let (i, l) = Warp::identity(16, 16)
            .scale(0.5)
            .rotate(45.0)
            .run(&img, &lab);
        assert_eq!(l.get_pixel(0, 0).0, [IGNORE]);
        assert_eq!(i.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(l.get_pixel(4, 4).0, [2]);
        assert_eq!(i.get_pixel(4, 4).0, [200, 100, 50]);
    }
}
