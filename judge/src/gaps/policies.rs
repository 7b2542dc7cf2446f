//! The policies that judge offered gaps, and their fits on training recordings.
//!
//! - **Critical gap (maximum likelihood)**: Troutbeck's estimator
//!   ([`traffic::fit::fit_critical_gap`]) on each training driver's accepted and
//!   largest rejected gap; the rule accepts when the estimated time to the next conflicting
//!   vehicle is at least the median critical gap, and gives as probability the share of
//!   drivers whose critical gap is shorter (the fitted lognormal's CDF).
//! - **Critical gap (Raff)**: Raff's (1950) critical gap, where as many accepted gaps are
//!   shorter as rejected gaps are longer; the same rule.
//! - **Distance rules**: accept when the nearest vehicle on the ring is further than 10, 15,
//!   20 or 25 m (the simulator's and `replay eval`'s rules); **always accept**.
//! - **Behaviour cloning**: logistic regression on [`super::Features`] (standardised), its
//!   L2 weight chosen by leave-one-recording-out over the training recordings only.

use serde::{Deserialize, Serialize};

use traffic::calibrate::gap_observations;
use traffic::fit::{CriticalGapFit, fit_critical_gap, phi};
use traffic::gaps::{Features, OfferedGap, RecordingGaps};

/// The distance rules' thresholds, m.
pub const DISTANCE_RULES_M: [f64; 4] = [10.0, 15.0, 20.0, 25.0];
/// The L2 weights the classifier's fit chooses among.
pub const L2_GRID: [f64; 5] = [1e-4, 1e-3, 1e-2, 1e-1, 1.0];
/// Bootstrap replicates of the critical-gap fit.
const FIT_BOOTSTRAP: usize = 200;

/// A policy's decision on one gap: accept or not, and its probability of accepting when it
/// gives one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GapDecision {
    pub accept: bool,
    pub probability: Option<f64>,
}

/// A policy over offered gaps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum GapPolicy {
    /// Accept when the estimated time to the next conflicting vehicle is at least the
    /// median of a lognormal critical gap (mu, sigma of its logarithm).
    CriticalGap {
        mu: f64,
        sigma: f64,
    },
    /// Accept when the estimated time is at least `critical_s`.
    Threshold {
        critical_s: f64,
    },
    /// Accept when the nearest vehicle on the ring is further than `metres`.
    Distance {
        metres: f64,
    },
    AlwaysAccept,
    Logistic(Logistic),
}

impl GapPolicy {
    pub fn decide(&self, f: &Features) -> GapDecision {
        match self {
            GapPolicy::CriticalGap { mu, sigma } => GapDecision {
                accept: f.eta_s >= mu.exp(),
                probability: Some(phi((f.eta_s.max(1e-3).ln() - mu) / sigma.max(1e-6))),
            },
            GapPolicy::Threshold { critical_s } => GapDecision {
                accept: f.eta_s >= *critical_s,
                probability: None,
            },
            GapPolicy::Distance { metres } => GapDecision {
                accept: f.nearest_m > *metres,
                probability: None,
            },
            GapPolicy::AlwaysAccept => GapDecision {
                accept: true,
                probability: None,
            },
            GapPolicy::Logistic(model) => {
                let p = model.probability(f);
                GapDecision {
                    accept: p >= 0.5,
                    probability: Some(p),
                }
            }
        }
    }
}

/// Everything fitted on the training recordings, and the policies built from it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fitted {
    pub critical_gap: CriticalGapFit,
    /// Raff's critical gap, s.
    pub raff_s: f64,
    /// Mean follow-up headway of the training recordings, s (None when none was measured).
    pub follow_up_headway_s: Option<f64>,
    /// The classifier, None when the training recordings hold no decision of either kind.
    pub classifier: Option<Logistic>,
    /// The classifier's L2 weight and its mean held-out log-loss per weight tried.
    pub l2_choice: Vec<(f64, f64)>,
}

impl Fitted {
    /// The maximum-likelihood rule applied to each gap's true length rather than to what
    /// could be seen when it was offered: a reference of what knowing the gap gives, not a
    /// policy (it reads the future).
    pub fn hindsight(&self, gaps: &[OfferedGap]) -> Vec<GapDecision> {
        let rule = GapPolicy::CriticalGap {
            mu: self.critical_gap.mu,
            sigma: self.critical_gap.sigma,
        };
        gaps.iter()
            .map(|g| {
                let mut f = g.features;
                f.eta_s = g.length_s;
                rule.decide(&f)
            })
            .collect()
    }

    /// The fitted policies with the rules, by name, the maximum-likelihood rule first.
    pub fn policies(&self) -> Vec<(String, GapPolicy)> {
        let mut out = vec![
            (
                "critical gap (maximum likelihood)".to_owned(),
                GapPolicy::CriticalGap {
                    mu: self.critical_gap.mu,
                    sigma: self.critical_gap.sigma,
                },
            ),
            (
                "critical gap (Raff)".to_owned(),
                GapPolicy::Threshold {
                    critical_s: self.raff_s,
                },
            ),
        ];
        out.extend(rules());
        if let Some(c) = &self.classifier {
            out.push(("behaviour cloning".into(), GapPolicy::Logistic(c.clone())));
        }
        out
    }
}

/// The rules that need no fit: the distance rules and always accept.
pub fn rules() -> Vec<(String, GapPolicy)> {
    DISTANCE_RULES_M
        .iter()
        .map(|&m| (format!("rule {m} m"), GapPolicy::Distance { metres: m }))
        .chain(std::iter::once((
            "always accept".to_owned(),
            GapPolicy::AlwaysAccept,
        )))
        .collect()
}

/// Fits the critical gaps, the follow-up headway and the classifier on `train`.
pub fn fit(train: &[RecordingGaps], seed: u64) -> Result<Fitted, String> {
    let measured: Vec<_> = train.iter().map(|r| r.measured.clone()).collect();
    let critical_gap = fit_critical_gap(&gap_observations(&measured), 10, FIT_BOOTSTRAP, seed)?;
    let gaps: Vec<&OfferedGap> = train.iter().flat_map(|r| &r.gaps).collect();
    let raff_s = raff(&gaps).ok_or_else(|| {
        "Raff's critical gap: the training recordings need accepted and rejected gaps".to_owned()
    })?;
    let follow_ups: Vec<f64> = measured
        .iter()
        .flat_map(|m| &m.entering)
        .filter_map(|e| e.follow_up_s)
        .collect();
    let follow_up_headway_s =
        (!follow_ups.is_empty()).then(|| follow_ups.iter().sum::<f64>() / follow_ups.len() as f64);
    let (classifier, l2_choice) = fit_classifier(train);
    Ok(Fitted {
        critical_gap,
        raff_s,
        follow_up_headway_s,
        classifier,
        l2_choice,
    })
}

/// Raff's critical gap of `gaps`: the length t at which the number of accepted gaps shorter
/// than t equals the number of rejected gaps longer than t (linear between the lengths where
/// the difference changes sign); None without both kinds.
pub fn raff(gaps: &[&OfferedGap]) -> Option<f64> {
    let mut accepted: Vec<f64> = gaps
        .iter()
        .filter(|g| g.accepted)
        .map(|g| g.length_s)
        .collect();
    let mut rejected: Vec<f64> = gaps
        .iter()
        .filter(|g| !g.accepted)
        .map(|g| g.length_s)
        .collect();
    if accepted.is_empty() || rejected.is_empty() {
        return None;
    }
    accepted.sort_by(f64::total_cmp);
    rejected.sort_by(f64::total_cmp);
    // d(t) = #accepted < t − #rejected > t rises from −#rejected to #accepted.
    let d = |t: f64| {
        let a = accepted.partition_point(|&x| x < t) as f64;
        let r = (rejected.len() - rejected.partition_point(|&x| x <= t)) as f64;
        a - r
    };
    let mut candidates: Vec<f64> = accepted.iter().chain(&rejected).copied().collect();
    candidates.sort_by(f64::total_cmp);
    candidates.dedup();
    let mut previous: Option<(f64, f64)> = None;
    for &t in &candidates {
        let v = d(t);
        if v == 0.0 {
            return Some(t);
        }
        if let Some((tp, vp)) = previous
            && vp < 0.0
            && v > 0.0
        {
            return Some(tp + (t - tp) * (-vp) / (v - vp));
        }
        previous = Some((t, v));
    }
    candidates.last().copied()
}

/// A logistic regression on standardised [`Features::vector`]s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Logistic {
    pub mean: Vec<f64>,
    pub scale: Vec<f64>,
    /// The weights, then the bias.
    pub weights: Vec<f64>,
    pub l2: f64,
}

impl Logistic {
    pub fn probability(&self, f: &Features) -> f64 {
        let x = f.vector();
        let mut z = self.weights.last().copied().unwrap_or(0.0);
        for (k, &v) in x.iter().enumerate() {
            z += self.weights[k] * (v - self.mean[k]) / self.scale[k];
        }
        sigmoid(z)
    }

    /// Fits the regression to `gaps` by Newton's method with L2 weight `l2` (the bias not
    /// penalised); None without both accepted and rejected gaps.
    pub fn fit(gaps: &[&OfferedGap], l2: f64) -> Option<Logistic> {
        let n = gaps.len();
        let positives = gaps.iter().filter(|g| g.accepted).count();
        if positives == 0 || positives == n {
            return None;
        }
        let xs: Vec<_> = gaps.iter().map(|g| g.features.vector()).collect();
        let d = Features::NAMES.len();
        let mut mean = vec![0.0; d];
        for x in &xs {
            for k in 0..d {
                mean[k] += x[k] / n as f64;
            }
        }
        let mut scale = vec![0.0; d];
        for x in &xs {
            for k in 0..d {
                scale[k] += (x[k] - mean[k]).powi(2) / n as f64;
            }
        }
        for s in &mut scale {
            *s = if *s > 1e-12 { s.sqrt() } else { 1.0 };
        }
        let rows: Vec<Vec<f64>> = xs
            .iter()
            .map(|x| {
                let mut r: Vec<f64> = (0..d).map(|k| (x[k] - mean[k]) / scale[k]).collect();
                r.push(1.0);
                r
            })
            .collect();
        let y: Vec<f64> = gaps
            .iter()
            .map(|g| if g.accepted { 1.0 } else { 0.0 })
            .collect();
        let m = d + 1;
        let mut w = vec![0.0; m];
        let lambda = l2 * n as f64;
        for _ in 0..50 {
            let mut grad = vec![0.0; m];
            let mut hess = vec![vec![0.0; m]; m];
            for (r, &yi) in rows.iter().zip(&y) {
                let p = sigmoid(r.iter().zip(&w).map(|(a, b)| a * b).sum());
                let s = (p * (1.0 - p)).max(1e-9);
                for i in 0..m {
                    grad[i] += (p - yi) * r[i];
                    for j in 0..m {
                        hess[i][j] += s * r[i] * r[j];
                    }
                }
            }
            for i in 0..d {
                grad[i] += lambda * w[i];
                hess[i][i] += lambda;
            }
            hess[d][d] += 1e-9;
            let step = solve(hess, grad)?;
            let size: f64 = step.iter().map(|s| s.abs()).fold(0.0, f64::max);
            for (wi, si) in w.iter_mut().zip(&step) {
                *wi -= si;
            }
            if size < 1e-9 {
                break;
            }
        }
        w.iter().all(|v| v.is_finite()).then_some(Logistic {
            mean,
            scale,
            weights: w,
            l2,
        })
    }
}

/// The classifier fitted on every training gap with the L2 weight of least mean held-out
/// log-loss, leaving one training recording out at a time (the grid's middle weight when
/// there is only one recording); with the log-loss per weight tried.
fn fit_classifier(train: &[RecordingGaps]) -> (Option<Logistic>, Vec<(f64, f64)>) {
    let all: Vec<&OfferedGap> = train.iter().flat_map(|r| &r.gaps).collect();
    let usable: Vec<&RecordingGaps> = train.iter().filter(|r| !r.gaps.is_empty()).collect();
    if usable.len() < 2 {
        return (Logistic::fit(&all, L2_GRID[2]), Vec::new());
    }
    let mut tried = Vec::new();
    for &l2 in &L2_GRID {
        let (mut loss, mut count) = (0.0, 0usize);
        for held in &usable {
            let rest: Vec<&OfferedGap> = usable
                .iter()
                .filter(|r| r.name != held.name)
                .flat_map(|r| &r.gaps)
                .collect();
            let Some(model) = Logistic::fit(&rest, l2) else {
                continue;
            };
            for g in &held.gaps {
                loss += log_loss(model.probability(&g.features), g.accepted);
                count += 1;
            }
        }
        tried.push((l2, loss / count.max(1) as f64));
    }
    let best = tried
        .iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(L2_GRID[2], |t| t.0);
    (Logistic::fit(&all, best), tried)
}

/// The log-loss of probability `p` of accepting when the driver did (`accepted`) or not,
/// with `p` clipped to [1e-6, 1 − 1e-6].
pub fn log_loss(p: f64, accepted: bool) -> f64 {
    let p = p.clamp(1e-6, 1.0 - 1e-6);
    if accepted { -p.ln() } else { -(1.0 - p).ln() }
}

fn sigmoid(z: f64) -> f64 {
    if z >= 0.0 {
        1.0 / (1.0 + (-z).exp())
    } else {
        let e = z.exp();
        e / (1.0 + e)
    }
}

/// Solves `a x = b` by Gaussian elimination with partial pivoting; None when singular.
fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for col in 0..n {
        let pivot = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() < 1e-12 {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        let pivot_row = a[col].clone();
        for row in col + 1..n {
            let f = a[row][col] / pivot_row[col];
            for (x, p) in a[row][col..].iter_mut().zip(&pivot_row[col..]) {
                *x -= f * p;
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for row in (0..n).rev() {
        let s: f64 = (row + 1..n).map(|k| a[row][k] * x[k]).sum();
        x[row] = (b[row] - s) / a[row][row];
    }
    Some(x)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use traffic::fit::normal_quantile;
    use traffic::gaps::Features;

    /// Drivers with lognormal critical gaps (median `median_s`, sigma 0.25) offered gaps of
    /// 1-8 s one after another until one is at least their critical gap: the decisions a
    /// critical-gap driver makes, each gap estimated exactly.
    fn simulated(median_s: f64, drivers: usize, seed: u64) -> Vec<OfferedGap> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut out = Vec::new();
        for d in 0..drivers {
            let u: f64 = rng.random_range(1e-6..1.0 - 1e-6);
            let critical = (median_s.ln() + 0.25 * normal_quantile(u)).exp();
            for index in 0..20u32 {
                let gap: f64 = rng.random_range(1.0..8.0);
                let accepted = gap >= critical;
                out.push(OfferedGap {
                    recording: format!("r{}", d % 3),
                    track: d as u32,
                    entry: 0,
                    index,
                    offered_s: 0.0,
                    length_s: gap,
                    accepted,
                    features: Features {
                        eta_s: gap,
                        second_eta_s: 12.0,
                        eta_quarter_s: gap,
                        eta_half_s: gap,
                        next_distance_m: 6.0 * gap,
                        next_speed_mps: 6.0,
                        next_outward_mps: 0.0,
                        nearest_m: 6.0 * gap,
                        upstream: 1,
                        own_speed_mps: 0.0,
                        own_distance_m: 1.0,
                        own_eta_s: 1.0,
                        waited_s: 0.0,
                        rejected_before: index,
                    },
                });
                if accepted {
                    break;
                }
            }
        }
        out
    }

    #[test]
    fn raff_balances_short_accepted_against_long_rejected_gaps() {
        let gaps = simulated(3.5, 2000, 1);
        let refs: Vec<&OfferedGap> = gaps.iter().collect();
        let t = raff(&refs).unwrap();
        // At Raff's gap as many accepted gaps are shorter as rejected ones longer (within the
        // one gap the crossing falls in), and it lies among the drivers' critical gaps.
        let shorter = gaps.iter().filter(|g| g.accepted && g.length_s < t).count() as i64;
        let longer = gaps
            .iter()
            .filter(|g| !g.accepted && g.length_s > t)
            .count() as i64;
        assert!(
            (shorter - longer).abs() <= 1,
            "{t}: {shorter} against {longer}"
        );
        assert!((3.0..4.5).contains(&t), "{t}");
        // By hand: accepted {2, 5}, rejected {1, 3}: at 2.5 one accepted shorter, one
        // rejected longer.
        let mut few = simulated(3.5, 1, 2);
        few.truncate(0);
        for (len, acc) in [(2.0, true), (5.0, true), (1.0, false), (3.0, false)] {
            let mut g = simulated(3.5, 1, 3).remove(0);
            g.length_s = len;
            g.accepted = acc;
            few.push(g);
        }
        let refs: Vec<&OfferedGap> = few.iter().collect();
        let t = raff(&refs).unwrap();
        assert!((2.0..=3.0).contains(&t), "{t}");
        assert!(raff(&refs[..2]).is_none());
    }

    #[test]
    fn the_classifier_learns_a_critical_gap_rule() {
        let train = simulated(3.5, 1500, 4);
        let test = simulated(3.5, 500, 5);
        let refs: Vec<&OfferedGap> = train.iter().collect();
        let model = Logistic::fit(&refs, 1e-3).unwrap();
        let rule = GapPolicy::CriticalGap {
            mu: 3.5f64.ln(),
            sigma: 0.25,
        };
        let accuracy = |p: &GapPolicy| {
            test.iter()
                .filter(|g| p.decide(&g.features).accept == g.accepted)
                .count() as f64
                / test.len() as f64
        };
        let learnt = accuracy(&GapPolicy::Logistic(model));
        let truth = accuracy(&rule);
        // The true rule is the best any policy of the gap can do; the classifier comes near.
        assert!(truth > 0.85, "{truth}");
        assert!(learnt > truth - 0.03, "{learnt} against {truth}");
        // Always accept is right only on the accepted share.
        let always = accuracy(&GapPolicy::AlwaysAccept);
        let share = test.iter().filter(|g| g.accepted).count() as f64 / test.len() as f64;
        assert!((always - share).abs() < 1e-12);
        assert!(Logistic::fit(&refs[..1], 1e-3).is_none(), "one class only");
    }
}
