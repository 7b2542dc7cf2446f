//! Intervals and paired tests for evaluations: every rate an evaluation reports comes with a
//! 95 % interval, and every comparison of two policies on the same episodes (or the same
//! recorded approaches) with a paired test.
//!
//! - [`wilson`]: the Wilson score interval of a binomial rate (Wilson 1927), good at rates
//!   near 0 and 1 where the normal interval is not.
//! - [`mcnemar_exact`]: the exact (binomial) McNemar test on the discordant pairs of two
//!   policies' paired binary outcomes.
//! - [`bootstrap_mean`] and [`paired_bootstrap`]: percentile bootstrap intervals of a mean and
//!   of the mean difference of paired values, with the two-sided bootstrap p-value of no
//!   difference; seeded, so the same input gives the same interval.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use statrs::distribution::{Binomial, DiscreteCDF};

/// The normal quantile of a two-sided 95 % interval.
const Z95: f64 = 1.959_963_984_540_054;

/// The 95 % Wilson score interval of `k` successes in `n` trials, as rates in [0, 1];
/// (0, 1) when `n` is 0.
pub fn wilson(k: u64, n: u64) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let (k, n, z) = (k.min(n) as f64, n as f64, Z95);
    let p = k / n;
    let denominator = 1.0 + z * z / n;
    let centre = (p + z * z / (2.0 * n)) / denominator;
    let half = z * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt() / denominator;
    // At 0 or n successes the bound is exactly 0 or 1 (the formula leaves rounding there).
    let lo = if k == 0.0 {
        0.0
    } else {
        (centre - half).max(0.0)
    };
    let hi = if k == n {
        1.0
    } else {
        (centre + half).min(1.0)
    };
    (lo, hi)
}

/// The two-sided p-value of the exact McNemar test: of the pairs where the two policies
/// differ, `b` favour the first and `c` the second; under no difference `b` is
/// Binomial(b + c, ½). 1 when there is no discordant pair.
pub fn mcnemar_exact(b: u64, c: u64) -> f64 {
    let n = b + c;
    if n == 0 {
        return 1.0;
    }
    let Ok(binomial) = Binomial::new(0.5, n) else {
        return 1.0;
    };
    (2.0 * binomial.cdf(b.min(c))).min(1.0)
}

/// A paired comparison of two policies' binary outcomes on the same trials.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PairedRates {
    /// Trials where the first succeeded and the second did not.
    pub only_first: u64,
    /// Trials where the second succeeded and the first did not.
    pub only_second: u64,
    /// Exact McNemar p-value.
    pub p_value: f64,
}

/// The exact McNemar comparison of paired outcomes `first[i]` and `second[i]` (the shorter
/// length is used).
pub fn paired_rates(first: &[bool], second: &[bool]) -> PairedRates {
    let (mut b, mut c) = (0, 0);
    for (&x, &y) in first.iter().zip(second) {
        match (x, y) {
            (true, false) => b += 1,
            (false, true) => c += 1,
            _ => {}
        }
    }
    PairedRates {
        only_first: b,
        only_second: c,
        p_value: mcnemar_exact(b, c),
    }
}

/// A bootstrap estimate: the point value and its 95 % percentile interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Interval {
    pub value: f64,
    pub ci95: (f64, f64),
}

/// The mean of `xs` with its 95 % percentile-bootstrap interval (`replicates` resamples,
/// ChaCha8 seeded by `seed`); NaN and an interval of NaN when `xs` is empty.
pub fn bootstrap_mean(xs: &[f64], replicates: usize, seed: u64) -> Interval {
    if xs.is_empty() {
        return Interval {
            value: f64::NAN,
            ci95: (f64::NAN, f64::NAN),
        };
    }
    let value = xs.iter().sum::<f64>() / xs.len() as f64;
    let mut means = resampled_means(xs, replicates, seed);
    Interval {
        value,
        ci95: percentile_interval(&mut means, value),
    }
}

/// A paired bootstrap comparison: the mean difference, its 95 % interval and the p-value.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PairedDifference {
    /// Mean of `first − second`.
    pub difference: f64,
    pub ci95: (f64, f64),
    /// Two-sided bootstrap p-value of no difference: twice the smaller share of replicates
    /// on either side of 0 (at least 1 / replicates, at most 1).
    pub p_value: f64,
}

/// The paired bootstrap of the mean of `first[i] − second[i]` over `replicates` resamples
/// of the pairs (ChaCha8 seeded by `seed`).
pub fn paired_bootstrap(
    first: &[f64],
    second: &[f64],
    replicates: usize,
    seed: u64,
) -> PairedDifference {
    let d: Vec<f64> = first.iter().zip(second).map(|(a, b)| a - b).collect();
    if d.is_empty() {
        return PairedDifference {
            difference: f64::NAN,
            ci95: (f64::NAN, f64::NAN),
            p_value: 1.0,
        };
    }
    let difference = d.iter().sum::<f64>() / d.len() as f64;
    let mut means = resampled_means(&d, replicates, seed);
    let below = means.iter().filter(|&&m| m <= 0.0).count();
    let above = means.iter().filter(|&&m| m >= 0.0).count();
    let p_value = if replicates == 0 || d.iter().all(|&x| x == 0.0) {
        1.0
    } else {
        (2.0 * below.min(above).max(1) as f64 / replicates as f64).min(1.0)
    };
    PairedDifference {
        difference,
        ci95: percentile_interval(&mut means, difference),
        p_value,
    }
}

/// The means of `replicates` resamples of `xs` (with replacement, ChaCha8 seeded by `seed`).
fn resampled_means(xs: &[f64], replicates: usize, seed: u64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..replicates)
        .map(|_| {
            let s: f64 = (0..xs.len())
                .map(|_| xs[rng.random_range(0..xs.len())])
                .sum();
            s / xs.len() as f64
        })
        .collect()
}

/// 2.5 / 97.5 percentiles of `xs` (sorted in place, linear interpolation); `point` twice
/// when empty.
pub fn percentile_interval(xs: &mut [f64], point: f64) -> (f64, f64) {
    if xs.is_empty() {
        return (point, point);
    }
    xs.sort_by(f64::total_cmp);
    let at = |q: f64| {
        let pos = q * (xs.len() - 1) as f64;
        let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
        xs[lo] + (xs[hi] - xs[lo]) * (pos - lo as f64)
    };
    (at(0.025), at(0.975))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_matches_the_published_values() {
        // Newcombe (1998), Statistics in Medicine 17, table I: 81 of 263 → 0.2553 to 0.3662.
        let (lo, hi) = wilson(81, 263);
        assert!((lo - 0.2553).abs() < 5e-4, "{lo}");
        assert!((hi - 0.3662).abs() < 5e-4, "{hi}");
        // 0 of 10 → 0 to 0.2775; 10 of 10 → 0.7225 to 1.
        let (lo, hi) = wilson(0, 10);
        assert!(lo == 0.0 && (hi - 0.2775).abs() < 5e-4, "{hi}");
        let (lo, hi) = wilson(10, 10);
        assert!(
            (lo - 0.7225).abs() < 5e-4 && (hi - 1.0).abs() < 1e-12,
            "{lo}"
        );
        assert_eq!(wilson(0, 0), (0.0, 1.0));
    }

    #[test]
    fn mcnemar_is_the_binomial_tail() {
        // 9 against 5 discordant: 2 P(X ≤ 5), X ~ Bin(14, ½) = 2 · 3,473 / 16,384.
        assert!((mcnemar_exact(5, 9) - 6946.0 / 16384.0).abs() < 1e-12);
        assert!((mcnemar_exact(9, 5) - mcnemar_exact(5, 9)).abs() < 1e-15);
        // 0 against 10: 2 / 1,024.
        assert!((mcnemar_exact(0, 10) - 2.0 / 1024.0).abs() < 1e-12);
        assert_eq!(mcnemar_exact(0, 0), 1.0);
        assert_eq!(mcnemar_exact(3, 3), 1.0);
        let p = paired_rates(&[true, true, false, true], &[false, true, true, false]);
        assert_eq!((p.only_first, p.only_second), (2, 1));
        assert!((p.p_value - 1.0).abs() < 1e-12);
    }

    #[test]
    fn bootstrap_intervals_cover_the_mean_and_detect_a_shift() {
        let xs: Vec<f64> = (0..200).map(|i| f64::from(i % 10)).collect();
        let m = bootstrap_mean(&xs, 2000, 7);
        assert!((m.value - 4.5).abs() < 1e-12);
        // The mean's standard error is 2.87 / √200 = 0.203: the interval is about ±0.40.
        assert!(m.ci95.0 < 4.5 && m.ci95.1 > 4.5, "{m:?}");
        assert!((m.ci95.1 - m.ci95.0 - 0.80).abs() < 0.12, "{m:?}");
        assert_eq!(bootstrap_mean(&xs, 2000, 7), m, "seeded");

        let shifted: Vec<f64> = xs.iter().map(|x| x + 1.0).collect();
        let d = paired_bootstrap(&shifted, &xs, 1000, 1);
        assert!(
            (d.difference - 1.0).abs() < 1e-12 && d.p_value <= 0.002,
            "{d:?}"
        );
        let noise: Vec<f64> = (0..200)
            .map(|i| if i % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        let zeros = vec![0.0; 200];
        let d = paired_bootstrap(&noise, &zeros, 1000, 1);
        assert!(d.p_value > 0.5 && d.ci95.0 < 0.0 && d.ci95.1 > 0.0, "{d:?}");
        assert_eq!(paired_bootstrap(&zeros, &zeros, 100, 1).p_value, 1.0);
    }
}
