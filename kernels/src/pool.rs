//! 2-D max pooling on the CPU in f32, NCHW: the forward pass and its backward pass, one plane
//! per task (rayon). The backward pass finds each window's maximum again rather than keeping
//! indices (the first maximum in row-major order, as burn's and PyTorch's kernels pick it).
//!
//! burn-flex 0.22 pools through its 3-D kernel with indices, even in inference, at about a
//! sixth of a default segmenter's inference on two threads (`perf`); this module is written
//! so it could replace that path upstream (no burn type in it). Measured in
//! docs/benchmarks.md.

use rayon::prelude::*;

/// The geometry of a 2-D max pooling (no dilation; windows clipped to the input, padding
/// never chosen).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pool2dGeometry {
    /// Batch times channels.
    pub planes: usize,
    pub height: usize,
    pub width: usize,
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    pub padding: [usize; 2],
}

impl Pool2dGeometry {
    /// `[H_out, W_out]` (floor mode).
    pub fn output_size(&self) -> [usize; 2] {
        let size = |input: usize, axis: usize| {
            (input + 2 * self.padding[axis]).saturating_sub(self.kernel[axis]) / self.stride[axis]
                + 1
        };
        [size(self.height, 0), size(self.width, 1)]
    }

    pub fn input_len(&self) -> usize {
        self.planes * self.height * self.width
    }

    pub fn output_len(&self) -> usize {
        let [h, w] = self.output_size();
        self.planes * h * w
    }

    /// Whether every window holds at least one input element (padding below the kernel).
    pub fn is_valid(&self) -> bool {
        (0..2).all(|a| self.stride[a] > 0 && self.kernel[a] > 0 && self.padding[a] < self.kernel[a])
            && self.height + 2 * self.padding[0] >= self.kernel[0]
            && self.width + 2 * self.padding[1] >= self.kernel[1]
    }

    /// The input rows (or columns, `axis` 1) of output row `o`: `[lo, hi)`, never empty.
    fn window(&self, axis: usize, o: usize) -> (usize, usize) {
        let size = if axis == 0 { self.height } else { self.width };
        let start = o * self.stride[axis];
        let lo = start.saturating_sub(self.padding[axis]);
        let hi = (start + self.kernel[axis])
            .saturating_sub(self.padding[axis])
            .min(size);
        (lo, hi.max(lo + 1).min(size))
    }
}

/// `out[planes, H_out, W_out]`: the maximum of each window of `x[planes, H, W]`.
pub fn max_pool2d_forward(g: &Pool2dGeometry, x: &[f32], out: &mut [f32]) {
    check(g, x.len(), out.len());
    let [oh, ow] = g.output_size();
    let plane = g.height * g.width;
    out.par_chunks_mut(oh * ow)
        .zip(x.par_chunks(plane))
        .for_each(|(out, x)| {
            // The maximum over each window's rows first (whole rows at once), then along them.
            let mut rows = vec![f32::NEG_INFINITY; g.width];
            for oy in 0..oh {
                let (y0, y1) = g.window(0, oy);
                rows.copy_from_slice(&x[y0 * g.width..(y0 + 1) * g.width]);
                for y in y0 + 1..y1 {
                    for (m, &v) in rows.iter_mut().zip(&x[y * g.width..(y + 1) * g.width]) {
                        *m = max(*m, v);
                    }
                }
                for (ox, o) in out[oy * ow..(oy + 1) * ow].iter_mut().enumerate() {
                    let (x0, x1) = g.window(1, ox);
                    *o = rows[x0 + 1..x1].iter().fold(rows[x0], |m, &v| max(m, v));
                }
            }
        });
}

/// `dx[planes, H, W]`: each output's gradient added to its window's first maximum.
pub fn max_pool2d_backward(g: &Pool2dGeometry, x: &[f32], grad: &[f32], dx: &mut [f32]) {
    check(g, x.len(), grad.len());
    assert_eq!(dx.len(), x.len(), "max_pool2d: gradient length");
    let [oh, ow] = g.output_size();
    let plane = g.height * g.width;
    dx.par_chunks_mut(plane)
        .zip(x.par_chunks(plane))
        .zip(grad.par_chunks(oh * ow))
        .for_each(|((dx, x), grad)| {
            dx.fill(0.0);
            for oy in 0..oh {
                let (y0, y1) = g.window(0, oy);
                for ox in 0..ow {
                    let (x0, x1) = g.window(1, ox);
                    let mut best = y0 * g.width + x0;
                    for y in y0..y1 {
                        for i in y * g.width + x0..y * g.width + x1 {
                            if x[i] > x[best] || (x[i].is_nan() && !x[best].is_nan()) {
                                best = i;
                            }
                        }
                    }
                    dx[best] += grad[oy * ow + ox];
                }
            }
        });
}

/// The larger of two values, NaN if either is (as burn's and PyTorch's max pooling).
fn max(a: f32, b: f32) -> f32 {
    if a.is_nan() || b > a { b } else { a }
}

fn check(g: &Pool2dGeometry, x: usize, out: usize) {
    assert!(g.is_valid(), "max_pool2d: invalid geometry {g:?}");
    assert_eq!(x, g.input_len(), "max_pool2d: input length against {g:?}");
    assert_eq!(
        out,
        g.output_len(),
        "max_pool2d: output length against {g:?}"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(len: usize) -> Vec<f32> {
        (0..len)
            .map(|i| ((i as u32).wrapping_mul(2_654_435_761) >> 8) as f32 / (1u32 << 24) as f32)
            .collect()
    }

    fn geometries() -> Vec<Pool2dGeometry> {
        let g = |h, w, k: [usize; 2], s: [usize; 2], p: [usize; 2]| Pool2dGeometry {
            planes: 3,
            height: h,
            width: w,
            kernel: k,
            stride: s,
            padding: p,
        };
        vec![
            g(9, 8, [3, 3], [2, 2], [1, 1]),
            g(8, 8, [2, 2], [2, 2], [0, 0]),
            g(7, 10, [3, 2], [1, 3], [1, 0]),
            g(5, 5, [5, 5], [1, 1], [2, 2]),
        ]
    }

    /// Every output is the maximum of its window by definition (padding excluded), and the
    /// backward pass sends each output's gradient to that element.
    #[test]
    fn pooling_matches_the_definition() {
        for g in geometries() {
            let x = values(g.input_len());
            let mut out = vec![f32::NAN; g.output_len()];
            max_pool2d_forward(&g, &x, &mut out);
            let grad: Vec<f32> = (0..g.output_len()).map(|i| 1.0 + i as f32).collect();
            let mut dx = vec![f32::NAN; g.input_len()];
            max_pool2d_backward(&g, &x, &grad, &mut dx);
            let [oh, ow] = g.output_size();
            let mut truth_dx = vec![0.0; g.input_len()];
            for p in 0..g.planes {
                for oy in 0..oh {
                    for ox in 0..ow {
                        let mut best: Option<(usize, f32)> = None;
                        for ky in 0..g.kernel[0] {
                            for kx in 0..g.kernel[1] {
                                let y = (oy * g.stride[0] + ky) as isize - g.padding[0] as isize;
                                let xx = (ox * g.stride[1] + kx) as isize - g.padding[1] as isize;
                                if y < 0
                                    || xx < 0
                                    || y >= g.height as isize
                                    || xx >= g.width as isize
                                {
                                    continue;
                                }
                                let i = (p * g.height + y as usize) * g.width + xx as usize;
                                if best.is_none_or(|(_, v)| x[i] > v) {
                                    best = Some((i, x[i]));
                                }
                            }
                        }
                        let (i, v) = best.expect("a window is never empty");
                        let o = (p * oh + oy) * ow + ox;
                        assert_eq!(out[o], v, "{g:?} output {o}");
                        truth_dx[i] += grad[o];
                    }
                }
            }
            assert_eq!(dx, truth_dx, "{g:?}");
        }
    }
}
