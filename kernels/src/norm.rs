//! Batch normalisation with the batch's statistics (training) on the CPU in f32, NCHW: the
//! forward pass and its backward pass, one channel per task (rayon), two passes over the
//! activations each (burn's backend-independent formulation makes about a dozen).
//!
//! The same maths as burn's `batch_norm_train` and `batch_norm_train_backward`: the mean and
//! the biased variance of each channel over the batch and the pixels, `y = γ (x − μ) / √(σ² +
//! ε) + β`; sums in f64.

use rayon::prelude::*;

/// `[batch, channels, pixels]` of the activations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NormGeometry {
    pub batch: usize,
    pub channels: usize,
    pub pixels: usize,
}

impl NormGeometry {
    pub fn len(&self) -> usize {
        self.batch * self.channels * self.pixels
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Values per channel.
    fn count(&self) -> f64 {
        (self.batch * self.pixels) as f64
    }

    /// Channel `c`'s runs of pixels, one per image.
    fn runs<'a>(&self, data: &'a [f32], c: usize) -> impl Iterator<Item = &'a [f32]> + use<'a> {
        let (channels, pixels) = (self.channels, self.pixels);
        (0..self.batch).map(move |b| &data[(b * channels + c) * pixels..][..pixels])
    }
}

/// `Σ f(a_i, b_i)` over two equal runs, in f64 by 16-lane f32 partial sums.
fn sum2(a: &[f32], b: &[f32], f: impl Fn(f32, f32) -> f32) -> f64 {
    const LANES: usize = 16;
    let mut acc = [0.0f32; LANES];
    let (ca, cb) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(&x, &y)| f64::from(f(x, y)))
        .sum();
    for (x, y) in ca.zip(cb) {
        for l in 0..LANES {
            acc[l] += f(x[l], y[l]);
        }
    }
    acc.iter().map(|&v| f64::from(v)).sum::<f64>() + tail
}

/// Normalises `x` by each channel's batch statistics into `out`; writes each channel's mean
/// and biased variance.
#[allow(clippy::too_many_arguments)]
pub fn batch_norm_train_forward(
    g: &NormGeometry,
    x: &[f32],
    gamma: &[f32],
    beta: &[f32],
    epsilon: f64,
    out: &mut [f32],
    mean: &mut [f32],
    variance: &mut [f32],
) {
    check(g, x.len(), gamma.len(), out.len());
    assert_eq!(beta.len(), g.channels, "batch norm: beta length");
    assert!(
        mean.len() == g.channels && variance.len() == g.channels,
        "batch norm: statistics length"
    );
    let stats: Vec<(f64, f64)> = (0..g.channels)
        .into_par_iter()
        .map(|c| {
            let mu = g.runs(x, c).map(|r| sum2(r, r, |v, _| v)).sum::<f64>() / g.count();
            let m = mu as f32;
            let var = g
                .runs(x, c)
                .map(|r| sum2(r, r, |v, _| (v - m) * (v - m)))
                .sum::<f64>()
                / g.count();
            (mu, var)
        })
        .collect();
    for (c, &(mu, var)) in stats.iter().enumerate() {
        mean[c] = mu as f32;
        variance[c] = var as f32;
    }
    out.par_chunks_mut(g.pixels)
        .enumerate()
        .for_each(|(bc, run)| {
            let c = bc % g.channels;
            let (mu, var) = stats[c];
            let scale = f64::from(gamma[c]) / (var + epsilon).sqrt();
            let (scale, shift) = (scale as f32, (f64::from(beta[c]) - mu * scale) as f32);
            for (o, &v) in run.iter_mut().zip(&x[bc * g.pixels..][..g.pixels]) {
                *o = v * scale + shift;
            }
        });
}

/// The gradients of the input, `gamma` and `beta` given the output's, from the input and the
/// statistics the forward pass wrote.
#[allow(clippy::too_many_arguments)]
pub fn batch_norm_train_backward(
    g: &NormGeometry,
    x: &[f32],
    gamma: &[f32],
    mean: &[f32],
    variance: &[f32],
    epsilon: f64,
    grad: &[f32],
    dx: &mut [f32],
    dgamma: &mut [f32],
    dbeta: &mut [f32],
) {
    check(g, x.len(), gamma.len(), grad.len());
    assert_eq!(dx.len(), x.len(), "batch norm: gradient length");
    // Per channel: Σ dy and Σ dy · (x − μ).
    let sums: Vec<(f64, f64)> = (0..g.channels)
        .into_par_iter()
        .map(|c| {
            let m = mean[c];
            g.runs(grad, c)
                .zip(g.runs(x, c))
                .fold((0.0, 0.0), |(s, sx), (dy, x)| {
                    (
                        s + sum2(dy, dy, |v, _| v),
                        sx + sum2(dy, x, |d, v| d * (v - m)),
                    )
                })
        })
        .collect();
    let inv_std: Vec<f64> = variance
        .iter()
        .map(|&v| 1.0 / (f64::from(v) + epsilon).sqrt())
        .collect();
    for c in 0..g.channels {
        dbeta[c] = sums[c].0 as f32;
        dgamma[c] = (sums[c].1 * inv_std[c]) as f32;
    }
    // dx = γ / σ · (dy − mean(dy) − x̂ · mean(dy · x̂)), x̂ = (x − μ) / σ.
    dx.par_chunks_mut(g.pixels)
        .enumerate()
        .for_each(|(bc, run)| {
            let c = bc % g.channels;
            let (s, sx) = sums[c];
            let k = f64::from(gamma[c]) * inv_std[c];
            let mean_dy = (s / g.count()) as f32;
            let proj = (sx * inv_std[c] * inv_std[c] / g.count()) as f32;
            let (k, m) = (k as f32, mean[c]);
            let (x, dy) = (
                &x[bc * g.pixels..][..g.pixels],
                &grad[bc * g.pixels..][..g.pixels],
            );
            for ((o, &v), &d) in run.iter_mut().zip(x).zip(dy) {
                *o = k * (d - mean_dy - (v - m) * proj);
            }
        });
}

fn check(g: &NormGeometry, x: usize, gamma: usize, out: usize) {
    assert_eq!(x, g.len(), "batch norm: input length against {g:?}");
    assert_eq!(out, g.len(), "batch norm: output length against {g:?}");
    assert_eq!(gamma, g.channels, "batch norm: gamma length against {g:?}");
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(len: usize, seed: u32) -> Vec<f32> {
        (0..len)
            .map(|i| {
                let v = (i as u32)
                    .wrapping_mul(2_654_435_761)
                    .wrapping_add(seed.wrapping_mul(40_503));
                (v >> 8) as f32 / (1u32 << 24) as f32 * 4.0 - 1.0
            })
            .collect()
    }

    /// The forward pass by its definition, in f64: the output and the loss `Σ y · r`.
    fn reference(
        g: &NormGeometry,
        x: &[f32],
        gamma: &[f32],
        beta: &[f32],
        r: &[f32],
    ) -> (Vec<f64>, f64) {
        let mut y = vec![0.0; g.len()];
        for c in 0..g.channels {
            let idx: Vec<usize> = (0..g.batch)
                .flat_map(|b| (0..g.pixels).map(move |p| (b * g.channels + c) * g.pixels + p))
                .collect();
            let n = idx.len() as f64;
            let mu = idx.iter().map(|&i| f64::from(x[i])).sum::<f64>() / n;
            let var = idx
                .iter()
                .map(|&i| (f64::from(x[i]) - mu).powi(2))
                .sum::<f64>()
                / n;
            for &i in &idx {
                y[i] = f64::from(gamma[c]) * (f64::from(x[i]) - mu) / (var + 1e-5).sqrt()
                    + f64::from(beta[c]);
            }
        }
        let loss = y.iter().zip(r).map(|(a, b)| a * f64::from(*b)).sum();
        (y, loss)
    }

    #[test]
    fn forward_and_backward_match_the_definition() {
        for g in [
            NormGeometry {
                batch: 3,
                channels: 4,
                pixels: 37,
            },
            NormGeometry {
                batch: 1,
                channels: 2,
                pixels: 5,
            },
        ] {
            let (x, gamma, beta, r) = (
                values(g.len(), 1),
                values(g.channels, 2),
                values(g.channels, 3),
                values(g.len(), 4),
            );
            let (mut y, mut mean, mut var) = (
                vec![0.0; g.len()],
                vec![0.0; g.channels],
                vec![0.0; g.channels],
            );
            batch_norm_train_forward(&g, &x, &gamma, &beta, 1e-5, &mut y, &mut mean, &mut var);
            let (truth, _) = reference(&g, &x, &gamma, &beta, &r);
            for (a, b) in y.iter().zip(&truth) {
                assert!((f64::from(*a) - b).abs() < 1e-4, "output {a} against {b}");
            }
            let (mut dx, mut dgamma, mut dbeta) = (
                vec![0.0; g.len()],
                vec![0.0; g.channels],
                vec![0.0; g.channels],
            );
            batch_norm_train_backward(
                &g,
                &x,
                &gamma,
                &mean,
                &var,
                1e-5,
                &r,
                &mut dx,
                &mut dgamma,
                &mut dbeta,
            );
            // Central differences of the loss in f64.
            let h = 1e-3;
            let numeric = |f: &dyn Fn(f32) -> (Vec<f32>, Vec<f32>, Vec<f32>)| {
                let (xp, gp, bp) = f(h as f32);
                let (xm, gm, bm) = f(-h as f32);
                (reference(&g, &xp, &gp, &bp, &r).1 - reference(&g, &xm, &gm, &bm, &r).1)
                    / (2.0 * h)
            };
            for i in 0..g.len() {
                let d = numeric(&|e| {
                    let mut x = x.clone();
                    x[i] += e;
                    (x, gamma.clone(), beta.clone())
                });
                assert!(
                    (f64::from(dx[i]) - d).abs() < 2e-2 * (1.0 + d.abs()),
                    "dx[{i}]: {} against {d}",
                    dx[i]
                );
            }
            for c in 0..g.channels {
                let dg = numeric(&|e| {
                    let mut gm = gamma.clone();
                    gm[c] += e;
                    (x.clone(), gm, beta.clone())
                });
                let db = numeric(&|e| {
                    let mut bt = beta.clone();
                    bt[c] += e;
                    (x.clone(), gamma.clone(), bt)
                });
                assert!(
                    (f64::from(dgamma[c]) - dg).abs() < 1e-2 * (1.0 + dg.abs()),
                    "dgamma[{c}]: {} against {dg}",
                    dgamma[c]
                );
                assert!(
                    (f64::from(dbeta[c]) - db).abs() < 1e-2 * (1.0 + db.abs()),
                    "dbeta[{c}]: {} against {db}",
                    dbeta[c]
                );
            }
        }
    }
}
