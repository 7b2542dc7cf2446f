//! 2-D convolution on the CPU in f32, NCHW: the forward pass and both backward passes (input
//! and weight), as matrix products by the `gemm` crate (the one burn's flex backend multiplies
//! with) and rayon.
//!
//! A convolution is `out[C_out, N] = W[C_out, K] · col[K, N]` with `K = C_in · k_h · k_w` and
//! `N` the output pixels: row `(c, i, j)` of `col` is input plane `c` shifted by the kernel
//! offset `(i, j)` (zero where it falls outside), so it is built from NCHW by row copies and
//! the product lands in NCHW. Small feature maps put several images side by side in `col`
//! (about [`GROUP_COLUMNS`] columns a product); a horizontal stride first splits each input
//! row into its phases so that the copies stay contiguous; a 1 × 1 convolution with stride 1
//! and no padding multiplies the input itself. The backward passes are the adjoints:
//! `grad_col = Wᵀ · grad_out` added back into the planes (col2im), and `grad_Wᵀ = col ·
//! grad_outᵀ`, summed over fixed slices of columns, one task each, in order.
//!
//! burn-flex 0.22 builds its columns from a channels-last copy made on one thread, with a
//! bounds test per element, and scatters each product back element by element; this module
//! could replace that path upstream (it holds no burn type). Measured in docs/benchmarks.md.

use rayon::prelude::*;

/// The geometry of a 2-D convolution (one group), NCHW.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Conv2dGeometry {
    pub batch: usize,
    pub channels_in: usize,
    pub height: usize,
    pub width: usize,
    pub channels_out: usize,
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    pub padding: [usize; 2],
    pub dilation: [usize; 2],
}

impl Conv2dGeometry {
    /// `[H_out, W_out]`.
    pub fn output_size(&self) -> [usize; 2] {
        let size = |input: usize, axis: usize| {
            let span = self.dilation[axis] * (self.kernel[axis] - 1) + 1;
            (input + 2 * self.padding[axis]).saturating_sub(span) / self.stride[axis] + 1
        };
        [size(self.height, 0), size(self.width, 1)]
    }

    /// Rows of `col`: `C_in · k_h · k_w`.
    pub fn patch_len(&self) -> usize {
        self.channels_in * self.kernel[0] * self.kernel[1]
    }

    fn output_plane(&self) -> usize {
        let [h, w] = self.output_size();
        h * w
    }

    /// An input plane split into the horizontal stride's phases: `[H, stride, ⌈W / stride⌉]`.
    fn phased_plane(&self) -> usize {
        self.height * self.width.div_ceil(self.stride[1]) * self.stride[1]
    }

    fn input_plane(&self) -> usize {
        self.height * self.width
    }

    /// Whether `col` is the input itself (1 × 1, stride 1, no padding).
    fn is_pointwise(&self) -> bool {
        self.kernel == [1, 1] && self.stride == [1, 1] && self.padding == [0, 0]
    }

    pub fn input_len(&self) -> usize {
        self.batch * self.channels_in * self.input_plane()
    }

    pub fn weight_len(&self) -> usize {
        self.channels_out * self.patch_len()
    }

    pub fn output_len(&self) -> usize {
        self.batch * self.channels_out * self.output_plane()
    }
}

/// Output columns per task in the weight gradient's sum.
const WEIGHT_SLICE: usize = 512;

/// Columns (output pixels over the images) a product should have at least.
const GROUP_COLUMNS: usize = 1024;

/// Below this many multiply-adds a product runs on the calling thread.
const PARALLEL_MACS: usize = 1 << 18;

fn parallelism(m: usize, n: usize, k: usize) -> gemm::Parallelism {
    let threads = rayon::current_num_threads();
    if threads > 1 && m * n * k >= PARALLEL_MACS {
        gemm::Parallelism::Rayon(threads)
    } else {
        gemm::Parallelism::None
    }
}

/// A row-major or transposed view of a matrix for [`matmul`]: element `(r, c)` at
/// `data[r * row_stride + c * col_stride]`.
#[derive(Clone, Copy)]
struct View<'a> {
    data: &'a [f32],
    row_stride: usize,
    col_stride: usize,
}

/// `dst[m, n] (row-major, row stride n) = (accumulate ? dst : 0) + a[m, k] · b[k, n]`.
fn matmul(
    dst: &mut [f32],
    accumulate: bool,
    a: View<'_>,
    b: View<'_>,
    m: usize,
    n: usize,
    k: usize,
) {
    matmul_into(dst, [n, 1], accumulate, a, b, m, n, k);
}

/// [`matmul`] with `dst[r, c]` at `dst[r * strides[0] + c * strides[1]]`.
#[allow(clippy::too_many_arguments)]
fn matmul_into(
    dst: &mut [f32],
    strides: [usize; 2],
    accumulate: bool,
    a: View<'_>,
    b: View<'_>,
    m: usize,
    n: usize,
    k: usize,
) {
    matmul_with(
        dst,
        strides,
        accumulate,
        a,
        b,
        [m, n, k],
        parallelism(m, n, k),
    );
}

/// [`matmul_into`] with the threading given.
fn matmul_with(
    dst: &mut [f32],
    strides: [usize; 2],
    accumulate: bool,
    a: View<'_>,
    b: View<'_>,
    [m, n, k]: [usize; 3],
    parallelism: gemm::Parallelism,
) {
    if m == 0 || n == 0 {
        return;
    }
    let last = |v: &View<'_>, rows: usize, cols: usize| {
        (rows - 1) * v.row_stride + (cols - 1) * v.col_stride
    };
    let d = View {
        data: dst,
        row_stride: strides[0],
        col_stride: strides[1],
    };
    assert!(last(&d, m, n) < dst.len(), "matmul: destination too small");
    if k == 0 {
        if !accumulate {
            dst.fill(0.0);
        }
        return;
    }
    assert!(
        last(&a, m, k) < a.data.len(),
        "matmul: left operand too small"
    );
    assert!(
        last(&b, k, n) < b.data.len(),
        "matmul: right operand too small"
    );
    // SAFETY: the asserts above keep every index gemm reads or writes inside the slices.
    #[allow(unsafe_code)]
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            strides[1] as isize,
            strides[0] as isize,
            accumulate,
            a.data.as_ptr(),
            a.col_stride as isize,
            a.row_stride as isize,
            b.data.as_ptr(),
            b.col_stride as isize,
            b.row_stride as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            parallelism,
        );
    }
}

/// The output columns `[lo, hi)` whose input column `o · stride - pad + offset` lies in
/// `[0, size)`.
fn valid_range(
    out: usize,
    size: usize,
    stride: usize,
    pad: usize,
    offset: usize,
) -> (usize, usize) {
    // o · stride + offset ≥ pad  and  o · stride + offset < size + pad
    let lo = pad.saturating_sub(offset).div_ceil(stride).min(out);
    let hi = if size + pad > offset {
        (size + pad - offset).div_ceil(stride).min(out)
    } else {
        0
    };
    (lo, hi.max(lo))
}

/// Every row of `col` as `(row, c, i, j)`.
#[cfg(test)]
fn rows(g: &Conv2dGeometry) -> impl Iterator<Item = (usize, usize, usize, usize)> {
    let [kh, kw] = g.kernel;
    (0..g.channels_in).flat_map(move |c| {
        (0..kh).flat_map(move |i| (0..kw).map(move |j| ((c * kh + i) * kw + j, c, i, j)))
    })
}

/// Fills `col[K, G · N]` from the `G` images of `x[G, C_in, H, W]`: image `j`'s patches in
/// columns `j · N .. (j + 1) · N`.
fn im2col(g: &Conv2dGeometry, x: &[f32], col: &mut [f32]) {
    let n = g.output_plane();
    let images = x.len() / (g.channels_in * g.input_plane());
    let [kh, kw] = g.kernel;
    // With a horizontal stride, every input row split into its stride's phases first, so that
    // each row of `col` is made of contiguous copies.
    let phased;
    let (x, plane) = if g.stride[1] > 1 {
        let plane = g.phased_plane();
        let mut buffer = vec![0.0; images * g.channels_in * plane];
        buffer
            .par_chunks_mut(plane)
            .zip(x.par_chunks(g.input_plane()))
            .for_each(|(dst, src)| to_phases(g, src, dst));
        phased = buffer;
        (&phased[..], plane)
    } else {
        (x, g.input_plane())
    };
    col.par_chunks_mut(images * n * kw)
        .enumerate()
        .for_each(|(ci, block)| {
            let (c, i) = (ci / kh, ci % kh);
            for (j, row) in block.chunks_mut(images * n).enumerate() {
                for (b, part) in row.chunks_mut(n).enumerate() {
                    let src = &x[(b * g.channels_in + c) * plane..][..plane];
                    fill_row(g, src, part, i, j);
                }
            }
        });
}

/// `dst.copy_from_slice(src)` for the short runs of `col`'s rows (a feature map's width), in
/// register-sized pieces: a call to `memcpy` per run costs more than the copy.
fn copy_short(dst: &mut [f32], src: &[f32]) {
    const PIECE: usize = 8;
    let len = dst.len();
    if len >= 64 || len != src.len() {
        dst.copy_from_slice(src);
    } else if len >= PIECE {
        for (d, s) in dst.chunks_exact_mut(PIECE).zip(src.chunks_exact(PIECE)) {
            let piece: [f32; PIECE] = s.try_into().expect("a piece");
            d.copy_from_slice(&piece);
        }
        let tail: [f32; PIECE] = src[len - PIECE..].try_into().expect("a piece");
        dst[len - PIECE..].copy_from_slice(&tail);
    } else {
        for (d, s) in dst.iter_mut().zip(src) {
            *d = *s;
        }
    }
}

/// `dst[y, p, t] = src[y, p + stride · t]` for one plane, `p < stride` (the horizontal stride),
/// `t < ⌈W / stride⌉`; zero past the row's end.
fn to_phases(g: &Conv2dGeometry, src: &[f32], dst: &mut [f32]) {
    let sw = g.stride[1];
    let wp = g.width.div_ceil(sw);
    for (row, out) in src.chunks_exact(g.width).zip(dst.chunks_exact_mut(sw * wp)) {
        for (p, phase) in out.chunks_exact_mut(wp).enumerate() {
            for (t, v) in phase.iter_mut().enumerate() {
                *v = row.get(p + sw * t).copied().unwrap_or(0.0);
            }
        }
    }
}

/// The adjoint of [`to_phases`]: `dst[y, p + stride · t] = src[y, p, t]`.
fn from_phases(g: &Conv2dGeometry, src: &[f32], dst: &mut [f32]) {
    let sw = g.stride[1];
    let wp = g.width.div_ceil(sw);
    for (row, phases) in dst.chunks_exact_mut(g.width).zip(src.chunks_exact(sw * wp)) {
        for (p, phase) in phases.chunks_exact(wp).enumerate() {
            for (v, &s) in row.iter_mut().skip(p).step_by(sw).zip(phase) {
                *v = s;
            }
        }
    }
}

/// Row `(·, i, j)` of `col` from one input plane (split into phases when the horizontal
/// stride is above 1: [`to_phases`]).
fn fill_row(g: &Conv2dGeometry, plane: &[f32], row: &mut [f32], i: usize, j: usize) {
    let [out_h, out_w] = g.output_size();
    let [sh, sw] = g.stride;
    let [ph, pw] = g.padding;
    let (oy_lo, oy_hi) = valid_range(out_h, g.height, sh, ph, i * g.dilation[0]);
    let (ox_lo, ox_hi) = valid_range(out_w, g.width, sw, pw, j * g.dilation[1]);
    row[..oy_lo * out_w].fill(0.0);
    row[oy_hi * out_w..].fill(0.0);
    let row_len = plane.len() / g.height;
    for oy in oy_lo..oy_hi {
        let y = oy * sh + i * g.dilation[0] - ph;
        let dst = &mut row[oy * out_w..(oy + 1) * out_w];
        dst[..ox_lo].fill(0.0);
        dst[ox_hi..].fill(0.0);
        if ox_hi > ox_lo {
            let x0 = ox_lo * sw + j * g.dilation[1] - pw;
            let start = y * row_len + (x0 % sw) * (row_len / sw) + x0 / sw;
            copy_short(
                &mut dst[ox_lo..ox_hi],
                &plane[start..start + (ox_hi - ox_lo)],
            );
        }
    }
}

/// Adds `col[K, G · N]` back into the gradient `dx[G, C_in, H, W]` of `G` images (the adjoint
/// of [`im2col`]); every plane on its own task, its rows in a fixed order.
fn col2im(g: &Conv2dGeometry, col: &[f32], dx: &mut [f32]) {
    let [out_h, out_w] = g.output_size();
    let n = out_h * out_w;
    let images = dx.len() / (g.channels_in * g.input_plane());
    let [kh, kw] = g.kernel;
    let [sh, sw] = g.stride;
    let [ph, pw] = g.padding;
    dx.par_chunks_mut(g.input_plane())
        .enumerate()
        .for_each(|(bc, dx_plane)| {
            let (b, c) = (bc / g.channels_in, bc % g.channels_in);
            let mut phased = if sw > 1 {
                vec![0.0; g.phased_plane()]
            } else {
                Vec::new()
            };
            let plane: &mut [f32] = if sw > 1 {
                &mut phased
            } else {
                dx_plane.fill(0.0);
                &mut *dx_plane
            };
            let row_len = plane.len() / g.height;
            for i in 0..kh {
                let (oy_lo, oy_hi) = valid_range(out_h, g.height, sh, ph, i * g.dilation[0]);
                for j in 0..kw {
                    let (ox_lo, ox_hi) = valid_range(out_w, g.width, sw, pw, j * g.dilation[1]);
                    if ox_hi <= ox_lo {
                        continue;
                    }
                    let row = &col[((c * kh + i) * kw + j) * images * n + b * n..][..n];
                    for oy in oy_lo..oy_hi {
                        let y = oy * sh + i * g.dilation[0] - ph;
                        let x0 = ox_lo * sw + j * g.dilation[1] - pw;
                        let src = &row[oy * out_w + ox_lo..oy * out_w + ox_hi];
                        let start = y * row_len + (x0 % sw) * (row_len / sw) + x0 / sw;
                        for (d, s) in plane[start..start + src.len()].iter_mut().zip(src) {
                            *d += *s;
                        }
                    }
                }
            }
            if sw > 1 {
                from_phases(g, &phased, dx_plane);
            }
        });
}

/// Images per product: enough that a product has about [`GROUP_COLUMNS`] columns (small
/// feature maps), one when an image alone has that many.
fn group_size(g: &Conv2dGeometry) -> usize {
    (GROUP_COLUMNS / g.output_plane().max(1)).clamp(1, g.batch.max(1))
}

/// `dst[C, G · N]` from `src[G, C, N]` (and back with `inverse`).
fn interleave(src: &[f32], dst: &mut [f32], channels: usize, n: usize, inverse: bool) {
    let images = src.len() / (channels * n);
    for b in 0..images {
        for c in 0..channels {
            let (grouped, batched) = ((c * images + b) * n, (b * channels + c) * n);
            if inverse {
                dst[batched..batched + n].copy_from_slice(&src[grouped..grouped + n]);
            } else {
                dst[grouped..grouped + n].copy_from_slice(&src[batched..batched + n]);
            }
        }
    }
}

/// `col[K, G · N]` of a block of `G` images: the block itself when `direct` (a 1 × 1
/// convolution with stride 1 and no padding, one image a product), else built in `buffer`.
fn patch_columns<'a>(
    g: &Conv2dGeometry,
    block: &'a [f32],
    direct: bool,
    buffer: &'a mut [f32],
) -> &'a [f32] {
    if direct {
        return block;
    }
    let images = block.len() / (g.channels_in * g.input_plane());
    let col = &mut buffer[..g.patch_len() * g.output_plane() * images];
    if g.is_pointwise() {
        interleave(block, col, g.patch_len(), g.output_plane(), false);
    } else {
        im2col(g, block, col);
    }
    col
}

/// `out[B, C_out, H_out, W_out] = conv(x[B, C_in, H, W], weight[C_out, C_in, k_h, k_w]) + bias`.
pub fn conv2d_forward(
    g: &Conv2dGeometry,
    x: &[f32],
    weight: &[f32],
    bias: Option<&[f32]>,
    out: &mut [f32],
) {
    check(g, x.len(), weight.len(), out.len());
    let (k, n, m) = (g.patch_len(), g.output_plane(), g.channels_out);
    let (group, in_len) = (group_size(g), g.channels_in * g.input_plane());
    let direct = g.is_pointwise() && group == 1;
    let mut col = if direct {
        Vec::new()
    } else {
        vec![0.0; k * n * group]
    };
    let mut grouped = if group > 1 {
        vec![0.0; m * n * group]
    } else {
        Vec::new()
    };
    let w = View {
        data: weight,
        row_stride: k,
        col_stride: 1,
    };
    for b0 in (0..g.batch).step_by(group) {
        let images = group.min(g.batch - b0);
        let cols = patch_columns(g, &x[b0 * in_len..(b0 + images) * in_len], direct, &mut col);
        let out_block = &mut out[b0 * m * n..(b0 + images) * m * n];
        let dst: &mut [f32] = if group > 1 {
            &mut grouped[..m * n * images]
        } else {
            out_block
        };
        if let Some(bias) = bias {
            for (row, &v) in dst.chunks_mut(n * images).zip(bias) {
                row.fill(v);
            }
        }
        let rhs = View {
            data: cols,
            row_stride: n * images,
            col_stride: 1,
        };
        matmul(dst, bias.is_some(), w, rhs, m, n * images, k);
        if group > 1 {
            let out_block = &mut out[b0 * m * n..(b0 + images) * m * n];
            interleave(&grouped[..m * n * images], out_block, m, n, true);
        }
    }
}

/// `dx[B, C_in, H, W]`: the gradient of the input given the output's, `grad[B, C_out, H_out,
/// W_out]`.
pub fn conv2d_backward_input(g: &Conv2dGeometry, grad: &[f32], weight: &[f32], dx: &mut [f32]) {
    check(g, dx.len(), weight.len(), grad.len());
    let (k, n, m) = (g.patch_len(), g.output_plane(), g.channels_out);
    let (group, in_len) = (group_size(g), g.channels_in * g.input_plane());
    let mut col = vec![0.0; k * n * group];
    let mut grouped = if group > 1 {
        vec![0.0; m * n * group]
    } else {
        Vec::new()
    };
    // Wᵀ[K, C_out]
    let wt = View {
        data: weight,
        row_stride: 1,
        col_stride: k,
    };
    for b0 in (0..g.batch).step_by(group) {
        let images = group.min(g.batch - b0);
        let grad_block = &grad[b0 * m * n..(b0 + images) * m * n];
        let go: &[f32] = if group > 1 {
            interleave(grad_block, &mut grouped[..m * n * images], m, n, false);
            &grouped[..m * n * images]
        } else {
            grad_block
        };
        let go = View {
            data: go,
            row_stride: n * images,
            col_stride: 1,
        };
        let dx_block = &mut dx[b0 * in_len..(b0 + images) * in_len];
        if g.is_pointwise() && group == 1 {
            matmul(dx_block, false, wt, go, k, n, m);
        } else {
            let col = &mut col[..k * n * images];
            matmul(col, false, wt, go, k, n * images, m);
            if g.is_pointwise() {
                interleave(col, dx_block, k, n, true);
            } else {
                col2im(g, col, dx_block);
            }
        }
    }
}

/// `dw[C_out, C_in, k_h, k_w]` (and `db[C_out]` when given): the gradients of the weight and
/// bias given the output's.
pub fn conv2d_backward_weight(
    g: &Conv2dGeometry,
    x: &[f32],
    grad: &[f32],
    dw: &mut [f32],
    db: Option<&mut [f32]>,
) {
    check(g, x.len(), dw.len(), grad.len());
    let (k, n, m) = (g.patch_len(), g.output_plane(), g.channels_out);
    let (group, in_len) = (group_size(g), g.channels_in * g.input_plane());
    let direct = g.is_pointwise() && group == 1;
    let mut col = if direct {
        Vec::new()
    } else {
        vec![0.0; k * n * group]
    };
    let mut grad_grouped = vec![0.0; n * group * m];
    let mut dw_t = vec![0.0; k * m];
    let mut first = true;
    for b0 in (0..g.batch).step_by(group) {
        let images = group.min(g.batch - b0);
        let columns = images * n;
        let cols = patch_columns(g, &x[b0 * in_len..(b0 + images) * in_len], direct, &mut col);
        // dWᵀ[K, C_out] = col[K, G · N] · gradᵀ[G · N, C_out], gradᵀ read as a transposed view of
        // the images' gradients side by side. The sum over the columns runs in fixed slices, one
        // task each, added in order: the products are too small in K and C_out to share among
        // threads otherwise.
        let grad_block = &grad[b0 * m * n..(b0 + images) * m * n];
        let grouped: &[f32] = if images > 1 {
            interleave(grad_block, &mut grad_grouped[..columns * m], m, n, false);
            &grad_grouped[..columns * m]
        } else {
            grad_block
        };
        let slices = columns.div_ceil(WEIGHT_SLICE);
        let partials: Vec<Vec<f32>> = (0..slices)
            .into_par_iter()
            .map(|s| {
                let (lo, hi) = (s * WEIGHT_SLICE, ((s + 1) * WEIGHT_SLICE).min(columns));
                let a = View {
                    data: &cols[lo..],
                    row_stride: columns,
                    col_stride: 1,
                };
                let bt = View {
                    data: &grouped[lo..],
                    row_stride: 1,
                    col_stride: columns,
                };
                let mut part = vec![0.0; k * m];
                matmul_with(
                    &mut part,
                    [m, 1],
                    false,
                    a,
                    bt,
                    [k, m, hi - lo],
                    gemm::Parallelism::None,
                );
                part
            })
            .collect();
        for part in &partials {
            if first {
                dw_t.copy_from_slice(part);
                first = false;
            } else {
                dw_t.par_iter_mut()
                    .zip(part.par_iter())
                    .for_each(|(d, p)| *d += p);
            }
        }
    }
    transpose(&dw_t, k, m, dw);
    if let Some(db) = db {
        db.par_iter_mut().enumerate().for_each(|(co, v)| {
            *v = (0..g.batch)
                .map(|b| grad[(b * m + co) * n..][..n].iter().sum::<f32>())
                .sum();
        });
    }
}

/// `dst[cols, rows] = srcᵀ` for `src[rows, cols]`, in cache-sized blocks.
fn transpose(src: &[f32], rows: usize, cols: usize, dst: &mut [f32]) {
    const BLOCK: usize = 32;
    dst[..rows * cols]
        .par_chunks_mut(BLOCK * rows)
        .enumerate()
        .for_each(|(bc, out)| {
            let c0 = bc * BLOCK;
            let c1 = (c0 + BLOCK).min(cols);
            for r0 in (0..rows).step_by(BLOCK) {
                for r in r0..(r0 + BLOCK).min(rows) {
                    let row = &src[r * cols..];
                    for c in c0..c1 {
                        out[(c - c0) * rows + r] = row[c];
                    }
                }
            }
        });
}

fn check(g: &Conv2dGeometry, x: usize, w: usize, out: usize) {
    assert_eq!(x, g.input_len(), "conv2d: input length against {g:?}");
    assert_eq!(w, g.weight_len(), "conv2d: weight length against {g:?}");
    assert_eq!(out, g.output_len(), "conv2d: output length against {g:?}");
    assert!(g.stride.iter().all(|&s| s > 0) && g.dilation.iter().all(|&d| d > 0));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The convolution by its definition, in f64.
    fn naive(g: &Conv2dGeometry, x: &[f32], w: &[f32], bias: Option<&[f32]>) -> Vec<f64> {
        let [oh, ow] = g.output_size();
        let mut out = vec![0.0; g.output_len()];
        for b in 0..g.batch {
            for co in 0..g.channels_out {
                for oy in 0..oh {
                    for ox in 0..ow {
                        let mut s = bias.map_or(0.0, |v| f64::from(v[co]));
                        for (_, c, i, j) in rows(g) {
                            let y = (oy * g.stride[0] + i * g.dilation[0]) as isize
                                - g.padding[0] as isize;
                            let xx = (ox * g.stride[1] + j * g.dilation[1]) as isize
                                - g.padding[1] as isize;
                            if y < 0 || xx < 0 || y >= g.height as isize || xx >= g.width as isize {
                                continue;
                            }
                            let xi = ((b * g.channels_in + c) * g.height + y as usize) * g.width
                                + xx as usize;
                            let wi = ((co * g.channels_in + c) * g.kernel[0] + i) * g.kernel[1] + j;
                            s += f64::from(x[xi]) * f64::from(w[wi]);
                        }
                        out[((b * g.channels_out + co) * oh + oy) * ow + ox] = s;
                    }
                }
            }
        }
        out
    }

    fn values(len: usize, seed: u32) -> Vec<f32> {
        (0..len)
            .map(|i| {
                let v = (i as u32)
                    .wrapping_mul(2_654_435_761)
                    .wrapping_add(seed.wrapping_mul(40_503));
                (v >> 8) as f32 / (1u32 << 24) as f32 - 0.5
            })
            .collect()
    }

    fn geometries() -> Vec<Conv2dGeometry> {
        let g = |c_in, h, w, c_out, k: [usize; 2], s: [usize; 2], p: [usize; 2], d: [usize; 2]| {
            Conv2dGeometry {
                batch: 2,
                channels_in: c_in,
                height: h,
                width: w,
                channels_out: c_out,
                kernel: k,
                stride: s,
                padding: p,
                dilation: d,
            }
        };
        // Small maps: several images to a product.
        let mut many = g(5, 6, 7, 6, [3, 3], [2, 2], [1, 1], [1, 1]);
        many.batch = 9;
        vec![
            many,
            g(3, 13, 11, 4, [7, 7], [2, 2], [3, 3], [1, 1]),
            g(5, 9, 10, 6, [3, 3], [1, 1], [1, 1], [1, 1]),
            g(5, 9, 10, 6, [3, 3], [2, 2], [1, 1], [1, 1]),
            g(4, 8, 8, 3, [3, 3], [1, 1], [2, 2], [2, 2]),
            g(6, 7, 5, 4, [1, 1], [1, 1], [0, 0], [1, 1]),
            g(6, 7, 5, 4, [1, 1], [2, 2], [0, 0], [1, 1]),
            g(2, 12, 9, 5, [8, 4], [4, 2], [0, 1], [1, 1]),
            g(2, 3, 3, 2, [3, 3], [1, 1], [0, 0], [1, 1]),
        ]
    }

    fn assert_close(ours: &[f32], truth: &[f64], what: &str) {
        assert_eq!(ours.len(), truth.len());
        for (i, (&a, &b)) in ours.iter().zip(truth).enumerate() {
            assert!(
                (f64::from(a) - b).abs() <= 1e-4 * (1.0 + b.abs()),
                "{what}[{i}]: {a} against {b}"
            );
        }
    }

    #[test]
    fn forward_matches_the_definition() {
        for g in geometries() {
            let (x, w, bias) = (
                values(g.input_len(), 1),
                values(g.weight_len(), 2),
                values(g.channels_out, 3),
            );
            let mut out = vec![f32::NAN; g.output_len()];
            conv2d_forward(&g, &x, &w, Some(&bias), &mut out);
            assert_close(&out, &naive(&g, &x, &w, Some(&bias)), &format!("{g:?}"));
            conv2d_forward(&g, &x, &w, None, &mut out);
            assert_close(
                &out,
                &naive(&g, &x, &w, None),
                &format!("{g:?} without bias"),
            );
        }
    }

    /// The backward passes are the adjoints of the forward pass: ⟨conv(x, w), gy⟩ =
    /// ⟨x, dx(gy)⟩ = ⟨w, dw(x, gy)⟩, checked element by element through unit vectors.
    #[test]
    fn backward_passes_are_the_adjoints() {
        for g in geometries() {
            let (x, w, gy) = (
                values(g.input_len(), 4),
                values(g.weight_len(), 5),
                values(g.output_len(), 6),
            );
            let dot =
                |a: &[f64], b: &[f32]| a.iter().zip(b).map(|(a, b)| a * f64::from(*b)).sum::<f64>();
            let mut dx = vec![f32::NAN; g.input_len()];
            conv2d_backward_input(&g, &gy, &w, &mut dx);
            let truth_dx: Vec<f64> = (0..g.input_len())
                .map(|i| {
                    let mut e = vec![0.0; g.input_len()];
                    e[i] = 1.0;
                    dot(&naive(&g, &e, &w, None), &gy)
                })
                .collect();
            assert_close(&dx, &truth_dx, &format!("dx {g:?}"));
            let (mut dw, mut db) = (
                vec![f32::NAN; g.weight_len()],
                vec![f32::NAN; g.channels_out],
            );
            conv2d_backward_weight(&g, &x, &gy, &mut dw, Some(&mut db));
            let truth_dw: Vec<f64> = (0..g.weight_len())
                .map(|i| {
                    let mut e = vec![0.0; g.weight_len()];
                    e[i] = 1.0;
                    dot(&naive(&g, &x, &e, None), &gy)
                })
                .collect();
            assert_close(&dw, &truth_dw, &format!("dw {g:?}"));
            let [oh, ow] = g.output_size();
            let truth_db: Vec<f64> = (0..g.channels_out)
                .map(|co| {
                    (0..g.batch)
                        .flat_map(|b| gy[(b * g.channels_out + co) * oh * ow..][..oh * ow].iter())
                        .map(|&v| f64::from(v))
                        .sum()
                })
                .collect();
            assert_close(&db, &truth_db, &format!("db {g:?}"));
        }
    }

    /// The same bytes whatever the number of threads.
    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a pool");
            pool.install(|| {
                // The last geometry is large enough for gemm to share its products among threads.
                let mut shapes = geometries();
                shapes.push(Conv2dGeometry {
                    batch: 2,
                    channels_in: 32,
                    height: 24,
                    width: 24,
                    channels_out: 64,
                    kernel: [3, 3],
                    stride: [1, 1],
                    padding: [1, 1],
                    dilation: [1, 1],
                });
                shapes
                    .into_iter()
                    .map(|g| {
                        let (x, w, gy) = (
                            values(g.input_len(), 7),
                            values(g.weight_len(), 8),
                            values(g.output_len(), 9),
                        );
                        let mut out = vec![0.0; g.output_len()];
                        conv2d_forward(&g, &x, &w, Some(&gy[..g.channels_out]), &mut out);
                        let mut dx = vec![0.0; g.input_len()];
                        conv2d_backward_input(&g, &gy, &w, &mut dx);
                        let (mut dw, mut db) =
                            (vec![0.0; g.weight_len()], vec![0.0; g.channels_out]);
                        conv2d_backward_weight(&g, &x, &gy, &mut dw, Some(&mut db));
                        [out, dx, dw, db]
                            .concat()
                            .iter()
                            .map(|v| v.to_bits())
                            .collect::<Vec<u32>>()
                    })
                    .collect::<Vec<_>>()
            })
        };
        let one = run(1);
        assert_eq!(one, run(2));
        assert_eq!(one, run(5));
    }
}
