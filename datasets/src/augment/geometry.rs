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
        self.resize(w, h)
    }

    /// Resizes to `width × height`, edge to edge.
    pub fn resize(self, width: u32, height: u32) -> Warp {
        let (w, h) = (width.max(1), height.max(1));
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
        let (w, h) = (self.width as usize, self.height as usize);
        let mut out_image = vec![0u8; w * h * 3];
        let mut out_label = vec![IGNORE; w * h];
        // (A label of another size than its image, never made by this crate, gives padding.)
        if let Some(source) = Source::new(image, label) {
            let m = &self.to_source;
            let affine = m[2] == [0.0, 0.0, 1.0];
            let rows = out_image
                .chunks_exact_mut(w * 3)
                .zip(out_label.chunks_exact_mut(w));
            let mut warm = Warmer::default();
            for (y, (image_row, label_row)) in rows.enumerate() {
                let py = y as f64 + 0.5;
                if affine {
                    warm.rows_of(&source, m, py, w as f64);
                    source.affine_row(m, py, image_row, label_row);
                } else {
                    source.perspective_row(m, py, image_row, label_row);
                }
            }
        }
        (
            RgbImage::from_raw(self.width, self.height, out_image).unwrap_or_default(),
            GrayImage::from_raw(self.width, self.height, out_label).unwrap_or_default(),
        )
    }
}

/// Reads the input rows an affine warp is about to need in order, a little ahead, one byte
/// per cache line: a rotated row walks the input diagonally, touching each input row at a
/// few places, which the hardware prefetcher cannot follow, while a plain pass over whole
/// rows streams them into the cache.
#[derive(Debug, Default)]
struct Warmer {
    /// Input rows `0..next` have been read (or will not be needed).
    next: i64,
}

impl Warmer {
    /// Rows read beyond the lowest one the current output row needs.
    const AHEAD: i64 = 4;

    fn rows_of(&mut self, source: &Source, m: &Mat3, py: f64, width: f64) {
        let y_at = |px: f64| m[1][0] * px + m[1][1] * py + m[1][2];
        let (a, b) = (y_at(0.0), y_at(width));
        if !(a.is_finite() && b.is_finite()) {
            return;
        }
        let lo = (a.min(b).floor() as i64 - 1).clamp(0, source.height);
        let hi = (a.max(b).floor() as i64 + 1 + Self::AHEAD).clamp(0, source.height);
        self.next = self.next.max(lo);
        if self.next >= hi {
            return;
        }
        let stride = source.width as usize * 3;
        let (start, end) = (self.next as usize * stride, hi as usize * stride);
        let mut sum = 0u8;
        for chunk in source.image[start..end].chunks(64) {
            sum = sum.wrapping_add(chunk[0]);
        }
        let label_stride = source.width as usize;
        let (start, end) = (
            self.next as usize * label_stride,
            hi as usize * label_stride,
        );
        for chunk in source.label[start..end].chunks(64) {
            sum = sum.wrapping_add(chunk[0]);
        }
        std::hint::black_box(sum);
        self.next = hi;
    }
}

/// Fractional bits of the fixed-point source coordinates.
const FRAC: u32 = 32;
/// Bits of each axis' bilinear weight (OpenCV's `warpAffine` uses 5).
const WBITS: u32 = 11;
/// The weight of a whole pixel.
const WONE: u32 = 1 << WBITS;
/// Source coordinates are clamped to ±2^24 pixels (far outside any image: padding), so a
/// fixed-point coordinate and a row's steps stay well inside i64.
const LIMIT: f64 = (1u64 << 24) as f64;

/// A source coordinate in fixed point, clamped (NaN becomes 0).
fn to_fixed(v: f64) -> i64 {
    (v.clamp(-LIMIT, LIMIT) * (1u64 << FRAC) as f64) as i64
}

/// The input of a warp as flat buffers.
struct Source<'a> {
    image: &'a [u8],
    label: &'a [u8],
    width: i64,
    height: i64,
}

impl<'a> Source<'a> {
    /// None for an empty input or an image and label of different sizes.
    fn new(image: &'a RgbImage, label: &'a GrayImage) -> Option<Source<'a>> {
        (image.dimensions() == label.dimensions() && image.width() > 0 && image.height() > 0).then(
            || Source {
                image: image.as_raw(),
                label: label.as_raw(),
                width: i64::from(image.width()),
                height: i64::from(image.height()),
            },
        )
    }

    /// One output row of an affine warp. The source point moves by a constant step along
    /// the row, so it is stepped in fixed point; where all four bilinear taps are inside the
    /// input (the row's interior span, solved exactly) a loop without border tests runs.
    fn affine_row(&self, m: &Mat3, py: f64, image_row: &mut [u8], label_row: &mut [u8]) {
        let n = label_row.len();
        // Fixed-point coordinates are those of the point minus half a pixel: their integer
        // part is the top-left tap, their fraction the bilinear weight.
        let qx = m[0][0] * 0.5 + m[0][1] * py + m[0][2] - 0.5;
        let qy = m[1][0] * 0.5 + m[1][1] * py + m[1][2] - 0.5;
        let end = n as f64;
        let in_range = |v: f64| v.abs() < LIMIT;
        if ![qx, qy, qx + m[0][0] * end, qy + m[1][0] * end]
            .into_iter()
            .all(in_range)
        {
            // Far outside (or not finite): per pixel, with clamping.
            return self.perspective_row(m, py, image_row, label_row);
        }
        let (fx, fy) = (to_fixed(qx), to_fixed(qy));
        let (dx, dy) = (to_fixed(m[0][0]), to_fixed(m[1][0]));
        let (lo, hi) =
            interior_span(fx, dx, self.width, n).intersect(interior_span(fy, dy, self.height, n));
        let (lo, hi) = (lo.min(n), hi.clamp(lo.min(n), n));
        let point = |x: usize| (fx + x as i64 * dx, fy + x as i64 * dy);
        for x in (0..lo).chain(hi..n) {
            let (px, py) = point(x);
            let (pixel, label) = self.sample_edge(px, py);
            image_row[x * 3..x * 3 + 3].copy_from_slice(&pixel);
            label_row[x] = label;
        }
        let (px, py) = point(lo);
        self.interior(
            px,
            py,
            dx,
            dy,
            &mut image_row[lo * 3..hi * 3],
            &mut label_row[lo..hi],
        );
    }

    /// One output row of a general (perspective) warp: each point mapped on its own.
    fn perspective_row(&self, m: &Mat3, py: f64, image_row: &mut [u8], label_row: &mut [u8]) {
        for (x, (pixel, label)) in image_row
            .chunks_exact_mut(3)
            .zip(label_row.iter_mut())
            .enumerate()
        {
            let (qx, qy) = apply(m, x as f64 + 0.5, py);
            let (p, l) = self.sample_edge(to_fixed(qx - 0.5), to_fixed(qy - 0.5));
            pixel.copy_from_slice(&p);
            *label = l;
        }
    }

    /// Bilinear image value and nearest label at fixed-point point `(fx, fy)` (minus half a
    /// pixel). A point outside the input is black and ignored; a point inside whose taps
    /// reach past the edge takes the edge pixels (as image's resize does), so the image is
    /// black exactly where the label is ignore, and an enlarged image keeps its border.
    fn sample_edge(&self, fx: i64, fy: i64) -> ([u8; 3], u8) {
        let (x0, y0) = (fx >> FRAC, fy >> FRAC);
        let (wx, wy) = (weight(fx), weight(fy));
        let inside = |x: i64, y: i64| x >= 0 && y >= 0 && x < self.width && y < self.height;
        // The pixel containing the point: the nearer tap on each axis.
        let (lx, ly) = (
            x0 + i64::from(wx >= WONE / 2),
            y0 + i64::from(wy >= WONE / 2),
        );
        if !inside(lx, ly) {
            return ([0; 3], IGNORE);
        }
        let tap = |x: i64, y: i64| -> [u32; 3] {
            let (x, y) = (x.clamp(0, self.width - 1), y.clamp(0, self.height - 1));
            let i = (y * self.width + x) as usize * 3;
            [0, 1, 2].map(|k| u32::from(self.image[i + k]))
        };
        let (a, b, c, d) = (
            tap(x0, y0),
            tap(x0 + 1, y0),
            tap(x0, y0 + 1),
            tap(x0 + 1, y0 + 1),
        );
        let pixel = [0, 1, 2].map(|k| bilinear(a[k], b[k], c[k], d[k], wx, wy));
        (pixel, self.label[(ly * self.width + lx) as usize])
    }

    /// The interior of an affine row: every point's four taps are inside the input.
    fn interior(
        &self,
        mut fx: i64,
        mut fy: i64,
        dx: i64,
        dy: i64,
        image_row: &mut [u8],
        label_row: &mut [u8],
    ) {
        let stride = self.width as usize * 3;
        let label_stride = self.width as usize;
        for (pixel, label) in image_row.chunks_exact_mut(3).zip(label_row.iter_mut()) {
            let (x0, y0) = ((fx >> FRAC) as usize, (fy >> FRAC) as usize);
            let (wx, wy) = (weight(fx), weight(fy));
            let i = y0 * stride + x0 * 3;
            let top = &self.image[i..i + 6];
            let bottom = &self.image[i + stride..i + stride + 6];
            for k in 0..3 {
                pixel[k] = bilinear(
                    u32::from(top[k]),
                    u32::from(top[k + 3]),
                    u32::from(bottom[k]),
                    u32::from(bottom[k + 3]),
                    wx,
                    wy,
                );
            }
            let (lx, ly) = (
                x0 + usize::from(wx >= WONE / 2),
                y0 + usize::from(wy >= WONE / 2),
            );
            *label = self.label[ly * label_stride + lx];
            fx += dx;
            fy += dy;
        }
    }
}

/// The bilinear weight of the right (lower) taps: the fraction of a fixed-point coordinate
/// in `WBITS` bits.
fn weight(f: i64) -> u32 {
    ((f >> (FRAC - WBITS)) as u32) & (WONE - 1)
}

/// Bilinear interpolation of taps `a b / c d` with weights `wx`, `wy` of `b` and `c`
/// (out of `WONE`), rounded. Equal taps give their value exactly.
fn bilinear(a: u32, b: u32, c: u32, d: u32, wx: u32, wy: u32) -> u8 {
    let top = a * (WONE - wx) + b * wx;
    let bottom = c * (WONE - wx) + d * wx;
    ((top * (WONE - wy) + bottom * wy + (1 << (2 * WBITS - 1))) >> (2 * WBITS)) as u8
}

/// The `x` in `0..n` (as `lo..hi`, maybe empty) where the fixed-point coordinate
/// `f + x·d` has both its taps, `⌊·⌋` and `⌊·⌋ + 1`, in `0..size`.
fn interior_span(f: i64, d: i64, size: i64, n: usize) -> Span {
    let (f, d) = (i128::from(f), i128::from(d));
    // 0 <= f + x·d < (size - 1)·2^FRAC.
    let limit = i128::from(size - 1) << FRAC;
    let n = n as i128;
    let (lo, hi) = if d == 0 {
        if 0 <= f && f < limit { (0, n) } else { (0, 0) }
    } else if d > 0 {
        // x >= ceil(-f / d), x <= floor((limit - 1 - f) / d).
        (-(f.div_euclid(d)), (limit - 1 - f).div_euclid(d) + 1)
    } else {
        let e = -d;
        // x <= floor(f / e), x >= floor((f - limit) / e) + 1.
        ((f - limit).div_euclid(e) + 1, f.div_euclid(e) + 1)
    };
    let clamp = |v: i128| v.clamp(0, n) as usize;
    Span(clamp(lo), clamp(hi))
}

/// A half-open range of output columns.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Span(usize, usize);

impl Span {
    fn intersect(self, other: Span) -> (usize, usize) {
        (self.0.max(other.0), self.1.min(other.1))
    }
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

    /// The warp computed the plain way: each output pixel centre mapped in f64, the label
    /// from the pixel containing the point, bilinear taps in f64 clamped to the input where
    /// the point is inside it, black and ignore where it is not.
    /// Also returns, per pixel, whether the point lies within 1e-6 of a pixel edge (where
    /// fixed-point rounding may pick the neighbouring label).
    fn reference(warp: &Warp, img: &RgbImage, lab: &GrayImage) -> (RgbImage, GrayImage, Vec<bool>) {
        let (w, h) = (i64::from(img.width()), i64::from(img.height()));
        let mut out = RgbImage::new(warp.width, warp.height);
        let mut out_lab = GrayImage::from_pixel(warp.width, warp.height, image::Luma([IGNORE]));
        let mut ambiguous = Vec::new();
        for y in 0..warp.height {
            for x in 0..warp.width {
                let (qx, qy) = apply(&warp.to_source, f64::from(x) + 0.5, f64::from(y) + 0.5);
                let (fx, fy) = (qx - 0.5, qy - 0.5);
                let (x0, y0) = (fx.floor(), fy.floor());
                let (ax, ay) = (fx - x0, fy - y0);
                let (x0, y0) = (x0 as i64, y0 as i64);
                let tap = |tx: i64, ty: i64, k: usize| {
                    let (tx, ty) = (tx.clamp(0, w - 1), ty.clamp(0, h - 1));
                    f64::from(img.get_pixel(tx as u32, ty as u32).0[k])
                };
                let (lx, ly) = (qx.floor() as i64, qy.floor() as i64);
                if lx >= 0 && ly >= 0 && lx < w && ly < h {
                    out_lab.put_pixel(x, y, *lab.get_pixel(lx as u32, ly as u32));
                    let p = [0, 1, 2].map(|k| {
                        let top = tap(x0, y0, k) * (1.0 - ax) + tap(x0 + 1, y0, k) * ax;
                        let bottom = tap(x0, y0 + 1, k) * (1.0 - ax) + tap(x0 + 1, y0 + 1, k) * ax;
                        (top * (1.0 - ay) + bottom * ay).round() as u8
                    });
                    out.put_pixel(x, y, image::Rgb(p));
                }
                let near_edge = |v: f64| (v - v.round()).abs() < 1e-6;
                ambiguous.push(near_edge(qx) || near_edge(qy));
            }
        }
        (out, out_lab, ambiguous)
    }

    #[test]
    fn fixed_point_warps_match_the_plain_computation() {
        let scene = |w: u32, h: u32| {
            (
                RgbImage::from_fn(w, h, |x, y| {
                    image::Rgb([
                        (x * 37 + y * 11) as u8,
                        (x * x + 3 * y) as u8,
                        (y * 53) as u8,
                    ])
                }),
                GrayImage::from_fn(w, h, |x, y| image::Luma([((x * 7 + y * 3) % 5) as u8])),
            )
        };
        let corners = [[3.0, -2.0], [40.0, 4.0], [35.0, 30.0], [-4.0, 27.0]];
        let mut cases = Vec::new();
        for (w, h) in [(37, 29), (1, 1), (2, 3), (5, 1)] {
            let id = Warp::identity(w, h);
            cases.push((w, h, id.rotate(7.3)));
            cases.push((w, h, id.rotate(-9.9).hflip()));
            cases.push((w, h, id.crop(1, 0, w.max(2) - 1, h).rotate(3.0).hflip()));
            cases.push((w, h, id.scale(1.7).rotate(45.0)));
            cases.push((w, h, id.scale(0.4)));
            cases.push((w, h, id.scale(2.0)));
            cases.push((w, h, id.rotate(180.0)));
            cases.push((w, h, id.rotate(90.0).scale(1.3)));
            cases.push((w, h, id.crop(0, 0, w + 9, h + 4).rotate(1.0)));
            if let Some(p) = id.perspective(&corners) {
                cases.push((w, h, p));
            }
        }
        // Entirely outside the input.
        cases.push((
            9,
            9,
            Warp {
                width: 6,
                height: 5,
                to_source: [[0.9, 0.1, 50.0], [-0.1, 1.0, -30.0], [0.0, 0.0, 1.0]],
            },
        ));
        for (w, h, warp) in cases {
            let (img, lab) = scene(w, h);
            let (fast, fast_lab) = warp.run(&img, &lab);
            let (slow, slow_lab, ambiguous) = reference(&warp, &img, &lab);
            assert_eq!(fast.dimensions(), slow.dimensions());
            for (i, ((f, s), (fl, sl))) in fast
                .pixels()
                .zip(slow.pixels())
                .zip(fast_lab.pixels().zip(slow_lab.pixels()))
                .enumerate()
            {
                // On a pixel edge, the two may disagree on whether the point is inside.
                for k in 0..3 {
                    let diff = (i32::from(f.0[k]) - i32::from(s.0[k])).abs();
                    assert!(
                        diff <= 1 || ambiguous[i],
                        "{w}x{h} {warp:?} pixel {i}: {f:?} vs {s:?}"
                    );
                }
                assert!(
                    fl == sl || ambiguous[i],
                    "{w}x{h} {warp:?} label {i}: {fl:?} vs {sl:?}"
                );
            }
        }
    }

    #[test]
    fn interior_spans_are_exact() {
        let one = 1i64 << FRAC;
        for size in [1i64, 2, 3, 10] {
            for f in [
                -3 * one - 5,
                -one,
                -1,
                0,
                1,
                one / 2,
                one,
                4 * one + 7,
                20 * one,
            ] {
                for d in [
                    0,
                    1,
                    -1,
                    one / 3,
                    -one / 3,
                    one,
                    -one,
                    3 * one,
                    -2 * one - 1,
                ] {
                    let n = 12;
                    let Span(lo, hi) = interior_span(f, d, size, n);
                    for x in 0..n {
                        let t = (f + x as i64 * d) >> FRAC;
                        let inside = t >= 0 && t + 1 < size;
                        assert_eq!(
                            inside,
                            (lo..hi).contains(&x),
                            "f {f} d {d} size {size} x {x}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn an_enlarged_image_keeps_its_border() {
        // Enlarged 1.5 times, the outermost output pixels' taps reach past the input's
        // edge: they take the edge pixels, not a blend with black.
        let img = RgbImage::from_pixel(8, 6, image::Rgb([200, 100, 50]));
        let lab = GrayImage::from_pixel(8, 6, image::Luma([3]));
        let (i, l) = Warp::identity(8, 6).resize(12, 9).run(&img, &lab);
        assert_eq!(i.dimensions(), (12, 9));
        assert!(i.pixels().all(|p| p.0 == [200, 100, 50]));
        assert!(l.pixels().all(|p| p.0 == [3]));
        // A crop reaching past the enlarged image is padded there.
        let (i, l) = Warp::identity(8, 6)
            .resize(12, 9)
            .crop(4, 2, 10, 10)
            .run(&img, &lab);
        assert_eq!(
            (i.get_pixel(7, 6).0, l.get_pixel(7, 6).0),
            ([200, 100, 50], [3])
        );
        assert_eq!(
            (i.get_pixel(8, 6).0, l.get_pixel(8, 6).0),
            ([0, 0, 0], [IGNORE])
        );
        assert_eq!(
            (i.get_pixel(7, 7).0, l.get_pixel(7, 7).0),
            ([0, 0, 0], [IGNORE])
        );
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
