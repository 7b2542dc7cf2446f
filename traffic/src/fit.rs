//! Numeric routines for traffic calibration: descriptive statistics, distribution
//! distances, a maximum-likelihood critical-gap fit and a least-squares IDM fit,
//! with percentile-bootstrap confidence intervals.
//!
//! Everything is deterministic: the same inputs (and seed) give bit-identical
//! outputs. No function panics on any input; fits return `Err(String)` instead.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::stats::percentile_interval;
use statrs::function::erf::{erfc, erfc_inv};
use std::collections::BTreeMap;

// ---------------------------------------------------------------------------
// Descriptive statistics and distances
// ---------------------------------------------------------------------------

/// n, mean, 10th/50th/90th percentiles (linear interpolation between order
/// statistics, like numpy's default). Non-finite inputs are ignored.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Number of finite values summarised.
    pub n: usize,
    /// Arithmetic mean.
    pub mean: f64,
    /// 10th percentile.
    pub p10: f64,
    /// Median.
    pub p50: f64,
    /// 90th percentile.
    pub p90: f64,
}

/// Summarises the finite values of `xs`; `n = 0` gives all-zero fields (no NaN).
pub fn summary(xs: &[f64]) -> Summary {
    let s = sorted_finite(xs);
    if s.is_empty() {
        return Summary {
            n: 0,
            mean: 0.0,
            p10: 0.0,
            p50: 0.0,
            p90: 0.0,
        };
    }
    Summary {
        n: s.len(),
        mean: s.iter().sum::<f64>() / s.len() as f64,
        p10: quantile(&s, 0.1),
        p50: quantile(&s, 0.5),
        p90: quantile(&s, 0.9),
    }
}

/// Quantile `q` of an ascending-sorted slice, interpolating linearly between
/// order statistics (numpy's default). `q` is clamped to [0, 1] (NaN → 0);
/// an empty slice gives 0.0.
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let n = sorted.len();
    if n == 0 {
        return 0.0;
    }
    let q = if q.is_nan() { 0.0 } else { q.clamp(0.0, 1.0) };
    let h = (n - 1) as f64 * q;
    let lo = (h.floor() as usize).min(n - 1);
    let hi = (lo + 1).min(n - 1);
    let frac = h - lo as f64;
    if frac == 0.0 || lo == hi {
        sorted[lo]
    } else {
        sorted[lo] + frac * (sorted[hi] - sorted[lo])
    }
}

/// Finite values of `xs`, sorted ascending.
fn sorted_finite(xs: &[f64]) -> Vec<f64> {
    let mut v: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    v
}

/// Walks the distinct values of two sorted samples in ascending order, calling
/// `visit(previous value, value, F_a before value, F_b before value, F_a after, F_b after)`.
fn merge_ecdfs(a: &[f64], b: &[f64], mut visit: impl FnMut(Option<f64>, f64, f64, f64, f64, f64)) {
    let (na, nb) = (a.len() as f64, b.len() as f64);
    let (mut i, mut j) = (0usize, 0usize);
    let mut prev: Option<f64> = None;
    while i < a.len() || j < b.len() {
        let v = match (a.get(i), b.get(j)) {
            (Some(&x), Some(&y)) => x.min(y),
            (Some(&x), None) => x,
            (None, Some(&y)) => y,
            (None, None) => break,
        };
        let (fa0, fb0) = (i as f64 / na, j as f64 / nb);
        while a.get(i) == Some(&v) {
            i += 1;
        }
        while b.get(j) == Some(&v) {
            j += 1;
        }
        visit(prev, v, fa0, fb0, i as f64 / na, j as f64 / nb);
        prev = Some(v);
    }
}

/// Two-sample Kolmogorov–Smirnov statistic D = sup |F_a − F_b| (handles ties
/// correctly: both ECDFs are evaluated after each distinct value). Non-finite
/// values are ignored; 1.0 if either side is empty.
pub fn ks_distance(a: &[f64], b: &[f64]) -> f64 {
    let (a, b) = (sorted_finite(a), sorted_finite(b));
    if a.is_empty() || b.is_empty() {
        return 1.0;
    }
    let mut d = 0.0f64;
    merge_ecdfs(&a, &b, |_, _, _, _, fa, fb| d = d.max((fa - fb).abs()));
    d
}

/// 1-Wasserstein distance between the two empirical distributions (integral of
/// |F_a − F_b|). Non-finite values are ignored; NaN-free; `f64::INFINITY` if
/// either side is empty.
pub fn wasserstein1(a: &[f64], b: &[f64]) -> f64 {
    let (a, b) = (sorted_finite(a), sorted_finite(b));
    if a.is_empty() || b.is_empty() {
        return f64::INFINITY;
    }
    let mut total = 0.0;
    merge_ecdfs(&a, &b, |prev, v, fa, fb, _, _| {
        let diff = (fa - fb).abs();
        if let Some(p) = prev
            && diff > 0.0
        {
            total += diff * (v - p);
        }
    });
    total
}

// ---------------------------------------------------------------------------
// Quantile functions
// ---------------------------------------------------------------------------

/// Standard normal quantile (via statrs' inverse complementary error function).
/// p ≤ 0 gives −∞, p ≥ 1 gives +∞, NaN gives NaN.
pub fn normal_quantile(p: f64) -> f64 {
    if p.is_nan() {
        f64::NAN
    } else if p <= 0.0 {
        f64::NEG_INFINITY
    } else if p >= 1.0 {
        f64::INFINITY
    } else {
        -std::f64::consts::SQRT_2 * erfc_inv(2.0 * p)
    }
}

/// Lognormal quantile exp(mu + sigma z) with z the standard normal quantile of `p`.
pub fn lognormal_quantile(mu: f64, sigma: f64, p: f64) -> f64 {
    (mu + sigma * normal_quantile(p)).exp()
}

/// Standard normal CDF Φ(z).
pub fn phi(z: f64) -> f64 {
    0.5 * erfc(-z / std::f64::consts::SQRT_2)
}

// ---------------------------------------------------------------------------
// Nelder–Mead
// ---------------------------------------------------------------------------

/// Minimises `f` with the Nelder–Mead simplex method (coefficients 1, 2, ½, ½).
///
/// The initial simplex is `x0` plus `step[i]` along each axis (a missing, zero
/// or non-finite step falls back to 5 % of |x0[i]|, or 0.00025 when x0[i] = 0).
/// Converges when both the spread of function values over the simplex and the
/// largest coordinate distance from the best vertex are ≤ `tol` (absolute);
/// it then restarts once from the best point (at most twice in total) and stops
/// when a restart improves by no more than `tol`. `max_iter` caps the total
/// number of simplex iterations across restarts. NaN values of `f` are treated
/// as +∞. Returns the best point and its (NaN-mapped) value.
pub fn nelder_mead(
    f: impl Fn(&[f64]) -> f64,
    x0: &[f64],
    step: &[f64],
    tol: f64,
    max_iter: usize,
) -> (Vec<f64>, f64) {
    let eval = |x: &[f64]| {
        let v = f(x);
        if v.is_nan() { f64::INFINITY } else { v }
    };
    let n = x0.len();
    let mut best = x0.to_vec();
    let mut best_f = eval(&best);
    if n == 0 {
        return (best, best_f);
    }
    let steps: Vec<f64> = (0..n)
        .map(|i| match step.get(i) {
            Some(&s) if s.is_finite() && s != 0.0 => s,
            _ if x0[i] != 0.0 && x0[i].is_finite() => 0.05 * x0[i].abs(),
            _ => 0.00025,
        })
        .collect();
    let mut iters = 0usize;
    for round in 0..3 {
        let mut simplex: Vec<(Vec<f64>, f64)> = vec![(best.clone(), best_f)];
        for (i, s) in steps.iter().enumerate() {
            let mut x = best.clone();
            x[i] += s;
            let fx = eval(&x);
            simplex.push((x, fx));
        }
        while iters < max_iter {
            simplex.sort_by(|p, q| p.1.total_cmp(&q.1));
            let spread_f = simplex[n].1 - simplex[0].1;
            let spread_x = simplex[1..]
                .iter()
                .flat_map(|(x, _)| x.iter().zip(&simplex[0].0).map(|(a, b)| (a - b).abs()))
                .fold(0.0f64, f64::max);
            if spread_f <= tol && spread_x <= tol {
                break;
            }
            iters += 1;
            let mut c = vec![0.0; n];
            for (x, _) in &simplex[..n] {
                for (cj, xj) in c.iter_mut().zip(x) {
                    *cj += xj / n as f64;
                }
            }
            let worst = simplex[n].clone();
            let along = |t: f64| -> Vec<f64> {
                c.iter()
                    .zip(&worst.0)
                    .map(|(cj, wj)| cj + t * (cj - wj))
                    .collect()
            };
            let xr = along(1.0);
            let fr = eval(&xr);
            if fr < simplex[0].1 {
                let xe = along(2.0);
                let fe = eval(&xe);
                simplex[n] = if fe < fr { (xe, fe) } else { (xr, fr) };
                continue;
            }
            if fr < simplex[n - 1].1 {
                simplex[n] = (xr, fr);
                continue;
            }
            let (xc, fc) = if fr < worst.1 {
                let xc = along(0.5);
                let fc = eval(&xc);
                (xc, if fc <= fr { fc } else { f64::NAN })
            } else {
                let xc = along(-0.5);
                let fc = eval(&xc);
                (xc, if fc < worst.1 { fc } else { f64::NAN })
            };
            if !fc.is_nan() {
                simplex[n] = (xc, fc);
                continue;
            }
            // Shrink towards the best vertex.
            let x_best = simplex[0].0.clone();
            for vertex in simplex.iter_mut().skip(1) {
                for (xj, bj) in vertex.0.iter_mut().zip(&x_best) {
                    *xj = bj + 0.5 * (*xj - bj);
                }
                vertex.1 = eval(&vertex.0);
            }
        }
        simplex.sort_by(|p, q| p.1.total_cmp(&q.1));
        // NaN (∞ − ∞) counts as no improvement.
        let improved = best_f - simplex[0].1 > tol;
        if simplex[0].1 < best_f {
            best = simplex[0].0.clone();
            best_f = simplex[0].1;
        }
        if iters >= max_iter || (round > 0 && !improved) {
            break;
        }
    }
    (best, best_f)
}

// ---------------------------------------------------------------------------
// Critical gap (Troutbeck maximum likelihood)
// ---------------------------------------------------------------------------

/// One entering driver's gaps at a roundabout yield line, in seconds: the gap it
/// accepted, and the largest gap it rejected before (None when it rejected none).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GapObservation {
    /// Accepted gap (s).
    pub accepted_s: f64,
    /// Largest rejected gap (s), if any gap was rejected.
    pub max_rejected_s: Option<f64>,
}

/// A lognormal critical-gap distribution fitted by maximum likelihood (Troutbeck
/// 1992, "Estimating the critical acceptance gap from traffic movements", Physical
/// Infrastructure Centre Research Report 92-5, QUT; the estimator recommended in the
/// HCM and by Brilon, Koenig & Troutbeck 1999): likelihood Π_i [F(a_i) − F(r_i)]
/// with F the lognormal CDF, a_i the accepted gap and r_i the largest rejected gap
/// (F(r_i) = 0 when none was rejected). Drivers whose largest rejected gap is not
/// smaller than the accepted one are inconsistent and are dropped (counted).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CriticalGapFit {
    /// Mean of ln(critical gap).
    pub mu: f64,
    /// Standard deviation of ln(critical gap).
    pub sigma: f64,
    /// Mean critical gap exp(mu + sigma²/2) (s).
    pub mean_s: f64,
    /// Standard deviation of the critical gap (s).
    pub sd_s: f64,
    /// Median critical gap exp(mu) (s).
    pub median_s: f64,
    /// 95 % percentile-bootstrap interval of the median (resampling drivers).
    pub median_ci95_s: (f64, f64),
    /// 95 % percentile-bootstrap interval of the mean.
    pub mean_ci95_s: (f64, f64),
    /// 95 % percentile-bootstrap interval of sigma.
    pub sigma_ci95: (f64, f64),
    /// Drivers used in the fit.
    pub drivers: usize,
    /// Of those, drivers that rejected at least one gap.
    pub with_rejections: usize,
    /// Inconsistent drivers (max rejected ≥ accepted), dropped.
    pub inconsistent: usize,
    /// Bootstrap replicates actually used (replicates without any rejecting
    /// driver have an unbounded likelihood and are skipped).
    pub bootstrap_used: usize,
}

/// Bounds on ln(sigma) inside the likelihood (sigma ∈ [~1.2e-4, ~20]).
const LN_SIGMA_RANGE: (f64, f64) = (-9.0, 3.0);

/// Negative log-likelihood of (mu, ln sigma) for drivers given as
/// (ln accepted, ln max rejected or −∞) with multiplicities `w`.
fn gap_neg_loglik(theta: &[f64], data: &[(f64, f64)], w: &[f64]) -> f64 {
    let (mu, ls) = match theta {
        [m, l, ..] => (*m, l.clamp(LN_SIGMA_RANGE.0, LN_SIGMA_RANGE.1)),
        _ => return f64::INFINITY,
    };
    let sigma = ls.exp();
    let mut nll = 0.0;
    for (&(la, lr), &wi) in data.iter().zip(w) {
        if wi == 0.0 {
            continue;
        }
        let za = (la - mu) / sigma;
        let zr = (lr - mu) / sigma; // −∞ when nothing was rejected
        // Use the upper tail when both are above the median, for precision.
        let p = if zr > 0.0 {
            phi(-zr) - phi(-za)
        } else {
            phi(za) - phi(zr)
        };
        nll -= wi * p.max(1e-300).ln();
    }
    nll
}

/// (median, mean, sigma) of the lognormal with parameters (mu, ln sigma).
fn gap_stats(theta: &[f64]) -> (f64, f64, f64) {
    let mu = theta.first().copied().unwrap_or(0.0);
    let ls = theta.get(1).copied().unwrap_or(0.0);
    let sigma = ls.clamp(LN_SIGMA_RANGE.0, LN_SIGMA_RANGE.1).exp();
    (mu.exp(), (mu + 0.5 * sigma * sigma).exp(), sigma)
}

/// Fits a lognormal critical-gap distribution by Troutbeck's maximum likelihood,
/// with a percentile bootstrap over drivers (`bootstrap` replicates, ChaCha8 seeded
/// by `seed`; 0 gives intervals equal to the point estimate).
///
/// Fails (clear message naming the count) when fewer than `min_drivers` usable
/// observations remain, or when no driver rejected a gap (the likelihood is then
/// unbounded), or on a non-finite / non-positive gap (naming the first bad value;
/// the caller is expected to filter).
pub fn fit_critical_gap(
    obs: &[GapObservation],
    min_drivers: usize,
    bootstrap: usize,
    seed: u64,
) -> Result<CriticalGapFit, String> {
    let mut data: Vec<(f64, f64)> = Vec::with_capacity(obs.len());
    let mut inconsistent = 0;
    for (i, o) in obs.iter().enumerate() {
        let a = o.accepted_s;
        if !(a.is_finite() && a > 0.0) {
            return Err(format!(
                "critical gap: observation {i} has invalid accepted gap {a} (must be finite and > 0)"
            ));
        }
        let lr = match o.max_rejected_s {
            None => f64::NEG_INFINITY,
            Some(r) if r.is_finite() && r > 0.0 => {
                if r >= a {
                    inconsistent += 1;
                    continue;
                }
                r.ln()
            }
            Some(r) => {
                return Err(format!(
                    "critical gap: observation {i} has invalid max rejected gap {r} (must be finite and > 0)"
                ));
            }
        };
        data.push((a.ln(), lr));
    }
    let drivers = data.len();
    let with_rejections = data.iter().filter(|d| d.1.is_finite()).count();
    if drivers < min_drivers.max(1) {
        return Err(format!(
            "critical gap: only {drivers} usable drivers ({inconsistent} inconsistent dropped), need at least {}",
            min_drivers.max(1)
        ));
    }
    if with_rejections == 0 {
        return Err(format!(
            "critical gap: none of the {drivers} usable drivers rejected a gap; the likelihood is unbounded"
        ));
    }
    let mu0 = data
        .iter()
        .map(|&(la, lr)| {
            if lr.is_finite() {
                ((la.exp() + lr.exp()) / 2.0).ln()
            } else {
                la
            }
        })
        .sum::<f64>()
        / drivers as f64;
    let x0 = [mu0, 0.3f64.ln()];
    let ones = vec![1.0; drivers];
    let (theta, _) = nelder_mead(
        |t| gap_neg_loglik(t, &data, &ones),
        &x0,
        &[0.2, 0.3],
        1e-10,
        2000,
    );
    let (median_s, mean_s, sigma) = gap_stats(&theta);
    let sd_s = mean_s * (sigma * sigma).exp_m1().sqrt();

    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut medians, mut means, mut sigmas) = (Vec::new(), Vec::new(), Vec::new());
    let mut w = vec![0.0; drivers];
    for _ in 0..bootstrap {
        w.iter_mut().for_each(|x| *x = 0.0);
        for _ in 0..drivers {
            w[rng.random_range(0..drivers)] += 1.0;
        }
        let rejecting = data
            .iter()
            .zip(&w)
            .any(|(d, &wi)| wi > 0.0 && d.1.is_finite());
        if !rejecting {
            continue;
        }
        let (t, _) = nelder_mead(
            |t| gap_neg_loglik(t, &data, &w),
            &theta,
            &[0.05, 0.1],
            1e-9,
            600,
        );
        let (md, mn, sg) = gap_stats(&t);
        medians.push(md);
        means.push(mn);
        sigmas.push(sg);
    }
    Ok(CriticalGapFit {
        mu: theta.first().copied().unwrap_or(mu0),
        sigma,
        mean_s,
        sd_s,
        median_s,
        median_ci95_s: percentile_interval(&mut medians, median_s),
        mean_ci95_s: percentile_interval(&mut means, mean_s),
        sigma_ci95: percentile_interval(&mut sigmas, sigma),
        drivers,
        with_rejections,
        inconsistent,
        bootstrap_used: medians.len(),
    })
}

// ---------------------------------------------------------------------------
// Sample mean
// ---------------------------------------------------------------------------

/// A sample mean and spread with a 95 % interval on the mean (Student t for
/// n ≤ 30, 1.96 for n > 30).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MeanFit {
    /// Sample size.
    pub n: usize,
    /// Sample mean.
    pub mean: f64,
    /// Sample standard deviation (n − 1 denominator; 0 when n = 1).
    pub sd: f64,
    /// 95 % interval on the mean (degenerate at the mean when n = 1).
    pub ci95: (f64, f64),
}

/// Two-sided 97.5 % Student t quantiles for 1..=30 degrees of freedom.
const T975: [f64; 30] = [
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
    2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
    2.052, 2.048, 2.045, 2.042,
];

/// Mean, sd and 95 % interval of `xs`. Errors when `xs` is empty or holds a
/// non-finite value (naming the first one).
pub fn fit_mean(xs: &[f64]) -> Result<MeanFit, String> {
    if xs.is_empty() {
        return Err("mean: no values".to_string());
    }
    if let Some((i, x)) = xs.iter().enumerate().find(|(_, x)| !x.is_finite()) {
        return Err(format!("mean: value {i} is not finite ({x})"));
    }
    let n = xs.len();
    let mean = xs.iter().sum::<f64>() / n as f64;
    if n == 1 {
        return Ok(MeanFit {
            n,
            mean,
            sd: 0.0,
            ci95: (mean, mean),
        });
    }
    let sd = (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
    let t = if n > 30 {
        1.96
    } else {
        T975.get(n - 2).copied().unwrap_or(1.96)
    };
    let half = t * sd / (n as f64).sqrt();
    Ok(MeanFit {
        n,
        mean,
        sd,
        ci95: (mean - half, mean + half),
    })
}

// ---------------------------------------------------------------------------
// IDM calibration
// ---------------------------------------------------------------------------

/// One car-following sample: the follower's speed v, closing speed dv = v − v_leader
/// (m/s), bumper-to-bumper gap s (m), its desired speed v0 (m/s, given), and its
/// observed acceleration (m/s²).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FollowingSample {
    /// Follower speed v (m/s).
    pub speed: f64,
    /// Closing speed dv = v − v_leader (m/s).
    pub closing: f64,
    /// Bumper-to-bumper gap s (m).
    pub gap_m: f64,
    /// Desired speed v0 (m/s).
    pub desired: f64,
    /// Observed acceleration (m/s²).
    pub accel: f64,
}

/// IDM parameters fitted by least squares on accelerations (as in Treiber &
/// Kesting, "Traffic Flow Dynamics", 2013, ch. 16 calibration):
/// a_IDM = a_max [1 − (v/v0)^4 − (s*/s)^2], s* = s0 + max(0, v T + v dv / (2 sqrt(a_max b))).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IdmFit {
    /// Maximum acceleration a_max (m/s²).
    pub max_accel_mps2: f64,
    /// Comfortable deceleration b (m/s²).
    pub comfort_decel_mps2: f64,
    /// Desired time headway T (s).
    pub time_headway_s: f64,
    /// Minimum gap s0 (m).
    pub min_gap_m: f64,
    /// Root-mean-square acceleration residual of the full fit (m/s²).
    pub rmse_mps2: f64,
    /// Number of samples used.
    pub samples: usize,
    /// Number of distinct vehicles (bootstrap clusters).
    pub vehicles: usize,
    /// 95 % percentile-bootstrap intervals of each parameter, same order as above.
    pub ci95: [(f64, f64); 4],
}

/// IDM acceleration; `gap` is floored at 0.01 m, `v0` at 0.1 m/s, and
/// a_max·b at 1e-12 inside the square root.
#[allow(clippy::too_many_arguments)]
pub fn idm_accel(v: f64, v0: f64, gap: f64, dv: f64, a_max: f64, b: f64, t: f64, s0: f64) -> f64 {
    let (gap, v0) = (gap.max(0.01), v0.max(0.1));
    let s_star = s0 + (v * t + v * dv / (2.0 * (a_max * b).max(1e-12).sqrt())).max(0.0);
    a_max * (1.0 - (v / v0).powi(4) - (s_star / gap).powi(2))
}

/// Parameter bounds (a_max, b, T, s0).
const IDM_LO: [f64; 4] = [0.3, 0.3, 0.3, 0.5];
const IDM_HI: [f64; 4] = [5.0, 6.0, 4.0, 6.0];

/// Parameter-independent per-sample terms, with a multiplicity weight.
struct IdmData {
    v: Vec<f64>,
    vdv: Vec<f64>,
    free: Vec<f64>,
    gap: Vec<f64>,
    acc: Vec<f64>,
    w: Vec<f64>,
}

/// Maps log-parameters to clamped parameters.
fn idm_params(x: &[f64]) -> [f64; 4] {
    let mut p = [0.0; 4];
    for (k, pk) in p.iter_mut().enumerate() {
        let xk = x.get(k).copied().unwrap_or(0.0);
        *pk = if xk.is_nan() {
            IDM_LO[k]
        } else {
            xk.exp().clamp(IDM_LO[k], IDM_HI[k])
        };
    }
    p
}

/// Weighted mean squared residual at log-parameters `x`.
fn idm_mse(x: &[f64], d: &IdmData) -> f64 {
    let [a, b, t, s0] = idm_params(x);
    let k = 1.0 / (2.0 * (a * b).sqrt());
    let (mut sse, mut wsum) = (0.0, 0.0);
    for i in 0..d.v.len() {
        let s_star = s0 + (d.v[i] * t + d.vdv[i] * k).max(0.0);
        let r = s_star / d.gap[i];
        let e = d.acc[i] - a * (1.0 - d.free[i] - r * r);
        sse += d.w[i] * e * e;
        wsum += d.w[i];
    }
    if wsum > 0.0 {
        sse / wsum
    } else {
        f64::INFINITY
    }
}

/// Fits IDM (a_max, b, T, s0) by minimising Σ (accel − a_IDM)² in log space with
/// the parameters clamped to a_max∈[0.3,5], b∈[0.3,6], T∈[0.3,4], s0∈[0.5,6],
/// Nelder–Mead from (1.5, 2.0, 1.2, 2.0). `groups[i]` is sample i's vehicle id;
/// the bootstrap (`bootstrap` replicates, ChaCha8 seeded by `seed`) resamples
/// vehicles, not samples. Errors when fewer than `min_samples` (or zero)
/// samples, when `groups` has a different length, or on a non-finite field.
pub fn fit_idm(
    samples: &[FollowingSample],
    groups: &[usize],
    min_samples: usize,
    bootstrap: usize,
    seed: u64,
) -> Result<IdmFit, String> {
    let n = samples.len();
    if n < min_samples.max(1) {
        return Err(format!(
            "IDM: only {n} samples, need at least {}",
            min_samples.max(1)
        ));
    }
    if groups.len() != n {
        return Err(format!("IDM: {} group ids for {n} samples", groups.len()));
    }
    if let Some((i, s)) = samples.iter().enumerate().find(|(_, s)| {
        ![s.speed, s.closing, s.gap_m, s.desired, s.accel]
            .iter()
            .all(|x| x.is_finite())
    }) {
        return Err(format!("IDM: sample {i} has a non-finite field: {s:?}"));
    }
    // Vehicle ids → dense cluster indices (BTreeMap: deterministic order).
    let mut ids: BTreeMap<usize, usize> = BTreeMap::new();
    for &g in groups {
        let next = ids.len();
        ids.entry(g).or_insert(next);
    }
    let cluster: Vec<usize> = groups
        .iter()
        .map(|g| ids.get(g).copied().unwrap_or(0))
        .collect();
    let vehicles = ids.len();
    let mut data = IdmData {
        v: samples.iter().map(|s| s.speed).collect(),
        vdv: samples.iter().map(|s| s.speed * s.closing).collect(),
        free: samples
            .iter()
            .map(|s| (s.speed / s.desired.max(0.1)).powi(4))
            .collect(),
        gap: samples.iter().map(|s| s.gap_m.max(0.01)).collect(),
        acc: samples.iter().map(|s| s.accel).collect(),
        w: vec![1.0; n],
    };
    let x0: Vec<f64> = [1.5f64, 2.0, 1.2, 2.0].iter().map(|p| p.ln()).collect();
    let (x, mse) = nelder_mead(|x| idm_mse(x, &data), &x0, &[0.3; 4], 1e-10, 3000);
    let p = idm_params(&x);

    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut reps: [Vec<f64>; 4] = Default::default();
    let mut mult = vec![0.0; vehicles];
    for _ in 0..bootstrap {
        mult.iter_mut().for_each(|m| *m = 0.0);
        for _ in 0..vehicles {
            mult[rng.random_range(0..vehicles)] += 1.0;
        }
        for (wi, &c) in data.w.iter_mut().zip(&cluster) {
            *wi = mult.get(c).copied().unwrap_or(0.0);
        }
        let (xb, _) = nelder_mead(|x| idm_mse(x, &data), &x, &[0.1; 4], 1e-9, 400);
        for (r, v) in reps.iter_mut().zip(idm_params(&xb)) {
            r.push(v);
        }
    }
    let mut ci = [(0.0, 0.0); 4];
    for k in 0..4 {
        ci[k] = percentile_interval(&mut reps[k], p[k]);
    }
    Ok(IdmFit {
        max_accel_mps2: p[0],
        comfort_decel_mps2: p[1],
        time_headway_s: p[2],
        min_gap_m: p[3],
        rmse_mps2: mse.sqrt(),
        samples: n,
        vehicles,
        ci95: ci,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn ks_identical_disjoint_ties_symmetric() {
        let a = [1.0, 2.0, 2.0, 3.0];
        assert_eq!(ks_distance(&a, &a), 0.0);
        assert_eq!(ks_distance(&a, &[10.0, 11.0]), 1.0);
        assert_eq!(ks_distance(&a, &[]), 1.0);
        // After 1: .25 vs 0; after 2: .75 vs .75; after 3: 1 vs .75; after 4: 1 vs 1.
        let b = [2.0, 2.0, 2.0, 4.0];
        assert_eq!(ks_distance(&a, &b), 0.25);
        assert_eq!(ks_distance(&b, &a), 0.25);
        let c = [0.5, 2.5, 2.5, 9.0, 1.0];
        assert_eq!(ks_distance(&a, &c), ks_distance(&c, &a));
    }

    #[test]
    fn wasserstein_shift_and_hand_case() {
        let a = [1.0, 2.0, 3.5, 7.0, 7.0];
        let b: Vec<f64> = a.iter().map(|x| x + 0.75).collect();
        assert!(close(wasserstein1(&a, &b), 0.75, 1e-12));
        assert!(close(wasserstein1(&b, &a), 0.75, 1e-12));
        // {0, 1} vs {0.5}: E|X − 0.5| = 0.5.
        assert!(close(wasserstein1(&[0.0, 1.0], &[0.5]), 0.5, 1e-15));
        assert_eq!(wasserstein1(&a, &a), 0.0);
        assert_eq!(wasserstein1(&a, &[]), f64::INFINITY);
    }

    #[test]
    fn summary_and_quantile_match_numpy() {
        let s = summary(&[3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0]);
        assert_eq!(s.n, 8);
        assert!(close(s.mean, 3.875, 1e-12));
        assert!(close(s.p10, 1.0, 1e-12));
        assert!(close(s.p50, 3.5, 1e-12));
        assert!(close(s.p90, 6.9, 1e-12));
        assert!(close(quantile(&[1.0, 2.0, 3.0, 4.0], 0.25), 1.75, 1e-12));
        assert_eq!(quantile(&[1.0, 2.0], 1.0), 2.0);
        let e = summary(&[]);
        assert_eq!((e.n, e.mean, e.p10, e.p50, e.p90), (0, 0.0, 0.0, 0.0, 0.0));
    }

    #[test]
    fn quantile_functions() {
        assert!(close(normal_quantile(0.975), 1.959963984540054, 1e-9));
        assert_eq!(normal_quantile(0.5), 0.0);
        assert_eq!(normal_quantile(0.0), f64::NEG_INFINITY);
        assert!(close(
            lognormal_quantile(4.0f64.ln(), 0.25, 0.5),
            4.0,
            1e-12
        ));
    }

    #[test]
    fn mean_fit() {
        let m = fit_mean(&[1.0, 2.0, 3.0]).expect("fit");
        assert!(close(m.mean, 2.0, 1e-12) && close(m.sd, 1.0, 1e-12));
        assert!(close(m.ci95.1 - 2.0, 4.303 / 3f64.sqrt(), 1e-9));
        assert!(fit_mean(&[]).is_err());
        assert!(fit_mean(&[1.0, f64::NAN]).is_err());
    }

    #[test]
    fn nelder_mead_rosenbrock() {
        let rosen = |x: &[f64]| (1.0 - x[0]).powi(2) + 100.0 * (x[1] - x[0] * x[0]).powi(2);
        let (x, f) = nelder_mead(rosen, &[-1.2, 1.0], &[0.5, 0.5], 1e-12, 5000);
        assert!(close(x[0], 1.0, 1e-3) && close(x[1], 1.0, 1e-3), "{x:?}");
        assert!(f < 1e-8);
    }

    fn simulate_gaps(n: usize, seed: u64) -> Vec<GapObservation> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (mu, sigma, mean_headway) = (4.0f64.ln(), 0.25, 6.0);
        (0..n)
            .map(|_| {
                let u: f64 = rng.random();
                let tc = lognormal_quantile(mu, sigma, u.clamp(1e-12, 1.0 - 1e-12));
                let mut max_rej: Option<f64> = None;
                loop {
                    // Poisson stream: the lag and all later gaps are exponential.
                    let gap = -mean_headway * (1.0 - rng.random::<f64>()).ln();
                    if gap >= tc {
                        return GapObservation {
                            accepted_s: gap,
                            max_rejected_s: max_rej,
                        };
                    }
                    max_rej = Some(max_rej.map_or(gap, |m| m.max(gap)));
                }
            })
            .collect()
    }

    #[test]
    fn critical_gap_recovers_parameters() {
        let obs = simulate_gaps(400, 7);
        let fit = fit_critical_gap(&obs, 50, 100, 42).expect("fit");
        assert!(close(fit.median_s, 4.0, 0.25), "{fit:?}");
        assert!(close(fit.sigma, 0.25, 0.08), "{fit:?}");
        assert!(
            fit.median_ci95_s.0 <= 4.0 && 4.0 <= fit.median_ci95_s.1,
            "{fit:?}"
        );
        assert!(fit.sigma_ci95.0 <= fit.sigma && fit.sigma <= fit.sigma_ci95.1);
        assert_eq!(fit.drivers, 400);
        assert_eq!(fit.bootstrap_used, 100);
        assert!(fit.with_rejections > 100 && fit.with_rejections < 300);
        assert_eq!(fit, fit_critical_gap(&obs, 50, 100, 42).expect("refit"));
        let no_boot = fit_critical_gap(&obs, 50, 0, 42).expect("fit");
        assert_eq!(no_boot.median_ci95_s, (no_boot.median_s, no_boot.median_s));
    }

    #[test]
    fn critical_gap_errors() {
        let obs = simulate_gaps(20, 3);
        let err = fit_critical_gap(&obs, 50, 0, 1).expect_err("too few");
        assert!(err.contains("20"), "{err}");
        let none: Vec<GapObservation> = (0..60)
            .map(|i| GapObservation {
                accepted_s: 3.0 + i as f64 * 0.1,
                max_rejected_s: None,
            })
            .collect();
        assert!(
            fit_critical_gap(&none, 10, 0, 1)
                .expect_err("no rejections")
                .contains("rejected")
        );
        let mut bad = obs.clone();
        bad[5].accepted_s = -1.0;
        assert!(
            fit_critical_gap(&bad, 1, 0, 1)
                .expect_err("bad")
                .contains("observation 5")
        );
        let mut inc = obs;
        inc.push(GapObservation {
            accepted_s: 2.0,
            max_rejected_s: Some(5.0),
        });
        assert_eq!(
            fit_critical_gap(&inc, 1, 0, 1).expect("fit").inconsistent,
            1
        );
    }

    fn simulate_idm(
        vehicles: usize,
        per_vehicle: usize,
        seed: u64,
    ) -> (Vec<FollowingSample>, Vec<usize>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (a, b, t, s0) = (1.4, 2.2, 1.1, 2.5);
        let mut samples = Vec::new();
        let mut groups = Vec::new();
        for veh in 0..vehicles {
            for _ in 0..per_vehicle {
                let v = rng.random_range(0.0..25.0);
                let dv = rng.random_range(-4.0..4.0);
                let s_eq = s0 + v * t;
                let gap = s_eq * rng.random_range(0.7..4.0);
                // Box–Muller Gaussian noise, sd 0.1.
                let (u1, u2): (f64, f64) = (1.0 - rng.random::<f64>(), rng.random());
                let noise = 0.1 * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
                let accel = idm_accel(v, 30.0, gap, dv, a, b, t, s0) + noise;
                samples.push(FollowingSample {
                    speed: v,
                    closing: dv,
                    gap_m: gap,
                    desired: 30.0,
                    accel,
                });
                groups.push(veh * 7 + 3);
            }
        }
        (samples, groups)
    }

    #[test]
    fn idm_recovers_parameters() {
        let (samples, groups) = simulate_idm(40, 50, 11);
        let fit = fit_idm(&samples, &groups, 100, 10, 5).expect("fit");
        let truth = [1.4, 2.2, 1.1, 2.5];
        let got = [
            fit.max_accel_mps2,
            fit.comfort_decel_mps2,
            fit.time_headway_s,
            fit.min_gap_m,
        ];
        for (g, t) in got.iter().zip(truth) {
            assert!((g - t).abs() <= 0.15 * t, "{fit:?}");
        }
        assert!(close(fit.rmse_mps2, 0.1, 0.02), "{fit:?}");
        assert_eq!((fit.samples, fit.vehicles), (2000, 40));
        for (k, (lo, hi)) in fit.ci95.iter().enumerate() {
            assert!(lo <= &got[k] && &got[k] <= hi, "{fit:?}");
        }
    }

    #[test]
    fn idm_errors_and_accel() {
        let (samples, groups) = simulate_idm(2, 10, 1);
        assert!(
            fit_idm(&samples, &groups, 100, 0, 1)
                .expect_err("few")
                .contains("20")
        );
        assert!(fit_idm(&samples, &groups[1..], 1, 0, 1).is_err());
        // Free road at standstill: a_max.
        assert!(close(
            idm_accel(0.0, 30.0, 1e9, 0.0, 1.4, 2.2, 1.1, 2.5),
            1.4,
            1e-9
        ));
        assert!(idm_accel(10.0, 30.0, 0.0, 5.0, 1.4, 2.2, 1.1, 2.5).is_finite());
    }
}
