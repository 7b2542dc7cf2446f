//! Policies scored on offered gaps: accuracy, balanced accuracy (the mean of the accepted
//! and the rejected gaps' accuracies, which always-accept cannot game), log-loss where the
//! policy gives a probability, the confusion matrix and the figures per recording, with 95 %
//! percentile-bootstrap intervals over approaches (a driver's gaps are resampled together:
//! they are not independent), and each policy paired with the reference rule (the fitted
//! critical gap) on the same gaps: a bootstrap over approaches of the accuracy difference,
//! and the exact McNemar test over gaps.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use sim::stats::{paired_rates, percentile_interval};

use super::policies::{GapDecision, GapPolicy, log_loss};
use traffic::gaps::OfferedGap;

/// Bootstrap replicates of every interval and paired test.
pub const BOOTSTRAP: usize = 2000;

/// Accepted and rejected gaps against what a policy decided.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Confusion {
    /// Accepted by the driver and by the policy.
    pub accepted_accepted: u64,
    /// Accepted by the driver, rejected by the policy.
    pub accepted_rejected: u64,
    /// Rejected by the driver, accepted by the policy.
    pub rejected_accepted: u64,
    pub rejected_rejected: u64,
}

impl Confusion {
    fn add(&mut self, driver: bool, policy: bool) {
        match (driver, policy) {
            (true, true) => self.accepted_accepted += 1,
            (true, false) => self.accepted_rejected += 1,
            (false, true) => self.rejected_accepted += 1,
            (false, false) => self.rejected_rejected += 1,
        }
    }

    pub fn total(&self) -> u64 {
        self.accepted_accepted
            + self.accepted_rejected
            + self.rejected_accepted
            + self.rejected_rejected
    }

    pub fn accuracy(&self) -> f64 {
        (self.accepted_accepted + self.rejected_rejected) as f64 / self.total().max(1) as f64
    }

    /// The mean of the accuracies on accepted and on rejected gaps (of those present).
    pub fn balanced_accuracy(&self) -> f64 {
        let acc = self.accepted_accepted + self.accepted_rejected;
        let rej = self.rejected_accepted + self.rejected_rejected;
        let mut parts = Vec::new();
        if acc > 0 {
            parts.push(self.accepted_accepted as f64 / acc as f64);
        }
        if rej > 0 {
            parts.push(self.rejected_rejected as f64 / rej as f64);
        }
        parts.iter().sum::<f64>() / parts.len().max(1) as f64
    }
}

/// One recording's figures for a policy.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RecordingScore {
    pub recording: String,
    pub offered: u64,
    pub accuracy: f64,
    pub balanced_accuracy: f64,
}

/// The policy against the reference rule on the same gaps.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Paired {
    pub against: String,
    /// Accuracy minus the reference's.
    pub difference: f64,
    pub ci95: (f64, f64),
    /// Two-sided bootstrap p-value over approaches.
    pub p_value: f64,
    /// Gaps only this policy judged right / only the reference did, and the exact McNemar
    /// p-value over gaps (which takes them as independent).
    pub only_this: u64,
    pub only_reference: u64,
    pub mcnemar_p: f64,
}

/// One policy's score.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PolicyScore {
    pub policy: String,
    pub accuracy: f64,
    pub balanced_accuracy: f64,
    /// 95 % bootstrap interval of the accuracy over approaches.
    pub ci95: (f64, f64),
    pub balanced_ci95: (f64, f64),
    /// Mean log-loss, when the policy gives probabilities.
    pub log_loss: Option<f64>,
    pub confusion: Confusion,
    pub per_recording: Vec<RecordingScore>,
    /// None for the reference itself.
    pub paired: Option<Paired>,
}

/// Each policy's decision on each of `gaps`.
pub fn decide(
    gaps: &[OfferedGap],
    policies: &[(String, GapPolicy)],
) -> Vec<(String, Vec<GapDecision>)> {
    policies
        .iter()
        .map(|(name, p)| {
            (
                name.clone(),
                gaps.iter().map(|g| p.decide(&g.features)).collect(),
            )
        })
        .collect()
}

/// Scores every policy's decisions on `gaps` (aligned), the first policy the reference of
/// the paired tests; `seed` seeds the bootstraps.
pub fn score(
    gaps: &[OfferedGap],
    decisions: &[(String, Vec<GapDecision>)],
    seed: u64,
) -> Vec<PolicyScore> {
    // Approaches (clusters): gap indices per (recording, track).
    let mut clusters: std::collections::BTreeMap<(&str, u32), Vec<usize>> = Default::default();
    for (i, g) in gaps.iter().enumerate() {
        clusters
            .entry((g.recording.as_str(), g.track))
            .or_default()
            .push(i);
    }
    let clusters: Vec<Vec<usize>> = clusters.into_values().collect();
    // The same resamples for every policy, so the paired differences pair up.
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let resamples: Vec<Vec<usize>> = (0..BOOTSTRAP)
        .map(|_| {
            (0..clusters.len())
                .map(|_| rng.random_range(0..clusters.len()))
                .collect()
        })
        .collect();
    let reference = decisions.first();
    decisions
        .iter()
        .enumerate()
        .map(|(k, (name, ds))| {
            let correct: Vec<bool> = gaps
                .iter()
                .zip(ds)
                .map(|(g, d)| g.accepted == d.accept)
                .collect();
            let mut confusion = Confusion::default();
            for (g, d) in gaps.iter().zip(ds) {
                confusion.add(g.accepted, d.accept);
            }
            let log_loss = ds.iter().all(|d| d.probability.is_some()).then(|| {
                gaps.iter()
                    .zip(ds)
                    .map(|(g, d)| log_loss(d.probability.unwrap_or(0.5), g.accepted))
                    .sum::<f64>()
                    / gaps.len().max(1) as f64
            });
            let accepts: Vec<bool> = ds.iter().map(|d| d.accept).collect();
            // A resample's accuracy and balanced accuracy of the policy accepting `of`.
            let replicate = |pick: &[usize], of: &[bool]| -> (f64, f64) {
                let mut c = Confusion::default();
                for &ci in pick {
                    for &i in &clusters[ci] {
                        c.add(gaps[i].accepted, of[i]);
                    }
                }
                (c.accuracy(), c.balanced_accuracy())
            };
            let (mut accs, mut bals): (Vec<f64>, Vec<f64>) =
                resamples.iter().map(|r| replicate(r, &accepts)).unzip();
            let paired = reference.filter(|_| k > 0).map(|(ref_name, ref_ds)| {
                let ref_accepts: Vec<bool> = ref_ds.iter().map(|d| d.accept).collect();
                let ref_correct: Vec<bool> = gaps
                    .iter()
                    .zip(&ref_accepts)
                    .map(|(g, &a)| g.accepted == a)
                    .collect();
                let mut diffs: Vec<f64> = resamples
                    .iter()
                    .map(|r| replicate(r, &accepts).0 - replicate(r, &ref_accepts).0)
                    .collect();
                let right = |c: &[bool]| c.iter().filter(|&&x| x).count() as f64;
                let difference = (right(&correct) - right(&ref_correct)) / gaps.len().max(1) as f64;
                let below = diffs.iter().filter(|&&d| d <= 0.0).count();
                let above = diffs.iter().filter(|&&d| d >= 0.0).count();
                let same = correct == ref_correct;
                let p_value = if same || diffs.is_empty() {
                    1.0
                } else {
                    (2.0 * below.min(above).max(1) as f64 / diffs.len() as f64).min(1.0)
                };
                let mcnemar = paired_rates(&correct, &ref_correct);
                Paired {
                    against: ref_name.clone(),
                    difference,
                    ci95: percentile_interval(&mut diffs, difference),
                    p_value,
                    only_this: mcnemar.only_first,
                    only_reference: mcnemar.only_second,
                    mcnemar_p: mcnemar.p_value,
                }
            });
            PolicyScore {
                policy: name.clone(),
                accuracy: confusion.accuracy(),
                balanced_accuracy: confusion.balanced_accuracy(),
                ci95: percentile_interval(&mut accs, confusion.accuracy()),
                balanced_ci95: percentile_interval(&mut bals, confusion.balanced_accuracy()),
                log_loss,
                confusion,
                per_recording: per_recording(gaps, ds),
                paired,
            }
        })
        .collect()
}

fn per_recording(gaps: &[OfferedGap], ds: &[GapDecision]) -> Vec<RecordingScore> {
    let mut by: std::collections::BTreeMap<&str, Confusion> = Default::default();
    for (g, d) in gaps.iter().zip(ds) {
        by.entry(g.recording.as_str())
            .or_default()
            .add(g.accepted, d.accept);
    }
    by.into_iter()
        .map(|(recording, c)| RecordingScore {
            recording: recording.to_owned(),
            offered: c.total(),
            accuracy: c.accuracy(),
            balanced_accuracy: c.balanced_accuracy(),
        })
        .collect()
}

/// `gaps.json`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GapsReport {
    /// Gaps offered in the scored recordings, and of them accepted.
    pub offered: u64,
    pub accepted: u64,
    /// The roundabout (its id on the map) whose yield lines were measured.
    pub roundabout: u32,
    /// Approaches to its yield lines in the scored recordings: tracks crossing one of them
    /// towards the ring with at least `min_approach_s` of track within `approach_m` before
    /// it (`[logs.decisions]`), found as `replay eval` finds them (the same number as its
    /// `approaches` on a map with one roundabout).
    pub approaches: u64,
    /// Of them, those offered at least one gap whose outcome the recording shows: the
    /// drivers of the offered gaps (the bootstrap resamples them).
    pub approaches_offered_a_gap: u64,
    /// The others: the recording ends before the outcome of any gap offered to them is
    /// known (`approaches` − `approaches_offered_a_gap`).
    pub approaches_without_a_known_gap: u64,
    /// Vehicles that crossed a yield line of the roundabout towards it without an approach
    /// (less of their track before the line: first seen at it), counted by neither command.
    pub crossings_without_an_approach: u64,
    /// What an approach is ([`traffic::decisions::APPROACH_DEFINITION`]).
    pub approach_definition: &'static str,
    /// The median critical gap by maximum likelihood, s: fitted on the training recordings
    /// when there are any, else on the scored ones (then only a description of them).
    pub critical_gap_s: f64,
    pub critical_gap_ci95_s: (f64, f64),
    /// Raff's critical gap, s (the same recordings).
    pub raff_critical_gap_s: f64,
    /// Mean follow-up headway, s (the same recordings).
    pub follow_up_headway_s: Option<f64>,
    /// The recordings the critical gaps and the classifier were fitted on.
    pub fitted_on: Vec<String>,
    pub scored: Vec<String>,
    /// The classifier's L2 weights tried with their mean held-out log-loss.
    pub classifier_l2: Vec<(f64, f64)>,
    /// The reference first: the fitted critical-gap rule when there are training
    /// recordings, else the first distance rule.
    pub policies: Vec<PolicyScore>,
}

/// `gaps.md`: the fits, then one row per policy.
pub fn markdown(r: &GapsReport) -> String {
    let pct = |x: f64| format!("{:.1}", 100.0 * x);
    let mut out = format!(
        "# Gap acceptance\n\n{} gaps offered to the drivers of {} approaches in {}, {} accepted. \
         Approaches: {} to the yield lines of roundabout {} (tracks crossing one towards the ring \
         with at least `min_approach_s` of track before it, as `replay eval` counts them), {} of \
         them offered no gap whose outcome the recording shows (it ends first); {} more vehicles \
         crossed a yield line with less of their track before it (no approach) and are left out. \
         Critical gap {:.2} s \
         (95 % {:.2}-{:.2}, maximum likelihood), Raff {:.2} s, follow-up headway {}, fitted on {}.\n\n\
         Each policy decides when a gap is offered, from that moment's frame. Intervals: 95 % bootstrap \
         over the approaches offered a gap; paired with **{}** on the same gaps (bootstrap over \
         those approaches, and exact McNemar over gaps).\n\n\
         | policy | accuracy % [95 %] | balanced % [95 %] | log-loss | accepted: judged accept / reject | rejected: judged accept / reject | vs reference, points [95 %] | p | McNemar p |\n\
         | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
        r.offered,
        r.approaches_offered_a_gap,
        r.scored.join(", "),
        r.accepted,
        r.approaches,
        r.roundabout,
        r.approaches_without_a_known_gap,
        r.crossings_without_an_approach,
        r.critical_gap_s,
        r.critical_gap_ci95_s.0,
        r.critical_gap_ci95_s.1,
        r.raff_critical_gap_s,
        r.follow_up_headway_s
            .map_or("-".into(), |h| format!("{h:.2} s")),
        if r.fitted_on.is_empty() {
            "the scored recordings (no --train-log)".to_owned()
        } else {
            r.fitted_on.join(", ")
        },
        r.policies.first().map_or("-", |p| p.policy.as_str()),
    );
    for p in &r.policies {
        let c = &p.confusion;
        let (vs, pv, mc) = p.paired.as_ref().map_or(
            ("reference".to_owned(), "-".to_owned(), "-".to_owned()),
            |d| {
                (
                    format!(
                        "{:+.1} [{:+.1}, {:+.1}]",
                        100.0 * d.difference,
                        100.0 * d.ci95.0,
                        100.0 * d.ci95.1
                    ),
                    sim::eval::p_text(d.p_value),
                    sim::eval::p_text(d.mcnemar_p),
                )
            },
        );
        out.push_str(&format!(
            "| {} | {} [{}, {}] | {} [{}, {}] | {} | {} / {} | {} / {} | {vs} | {pv} | {mc} |\n",
            p.policy,
            pct(p.accuracy),
            pct(p.ci95.0),
            pct(p.ci95.1),
            pct(p.balanced_accuracy),
            pct(p.balanced_ci95.0),
            pct(p.balanced_ci95.1),
            p.log_loss.map_or("-".into(), |l| format!("{l:.3}")),
            c.accepted_accepted,
            c.accepted_rejected,
            c.rejected_accepted,
            c.rejected_rejected,
        ));
    }
    if r.scored.len() > 1 {
        out.push_str("\nAccuracy per recording, %:\n\n| policy |");
        for s in &r.scored {
            out.push_str(&format!(" {s} |"));
        }
        out.push_str(&format!("\n|{}\n", " --- |".repeat(r.scored.len() + 1)));
        for p in &r.policies {
            out.push_str(&format!("| {} |", p.policy));
            for s in &r.scored {
                let a = p
                    .per_recording
                    .iter()
                    .find(|x| &x.recording == s)
                    .map_or("-".into(), |x| pct(x.accuracy));
                out.push_str(&format!(" {a} |"));
            }
            out.push('\n');
        }
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use traffic::gaps::Features;

    fn gap(recording: &str, track: u32, accepted: bool) -> OfferedGap {
        OfferedGap {
            recording: recording.into(),
            track,
            entry: 0,
            index: 0,
            offered_s: 0.0,
            length_s: 1.0,
            accepted,
            features: Features {
                eta_s: 1.0,
                second_eta_s: 1.0,
                eta_quarter_s: 1.0,
                eta_half_s: 1.0,
                next_distance_m: 1.0,
                next_speed_mps: 1.0,
                next_outward_mps: 0.0,
                nearest_m: 1.0,
                upstream: 0,
                own_speed_mps: 0.0,
                own_distance_m: 0.0,
                own_eta_s: 0.0,
                waited_s: 0.0,
                rejected_before: 0,
            },
        }
    }

    fn decisions(accepts: &[bool]) -> Vec<GapDecision> {
        accepts
            .iter()
            .map(|&accept| GapDecision {
                accept,
                probability: Some(if accept { 0.8 } else { 0.2 }),
            })
            .collect()
    }

    #[test]
    fn the_figures_are_the_counts_by_hand() {
        // 6 accepted and 4 rejected gaps over 5 approaches.
        let driver = [
            true, true, true, true, true, true, false, false, false, false,
        ];
        let gaps: Vec<OfferedGap> = driver
            .iter()
            .enumerate()
            .map(|(i, &a)| gap(if i < 5 { "a" } else { "b" }, i as u32 / 2, a))
            .collect();
        let always = vec![true; 10];
        let good = [
            true, true, true, true, true, false, false, false, false, true,
        ];
        let scores = score(
            &gaps,
            &[
                ("always".into(), decisions(&always)),
                ("good".into(), decisions(&good)),
                ("same".into(), decisions(&always)),
            ],
            3,
        );
        let (a, g, s) = (&scores[0], &scores[1], &scores[2]);
        assert!((a.accuracy - 0.6).abs() < 1e-12 && (a.balanced_accuracy - 0.5).abs() < 1e-12);
        // good: 5 of 6 accepted right, 3 of 4 rejected right.
        assert!((g.accuracy - 0.8).abs() < 1e-12);
        assert!((g.balanced_accuracy - (5.0 / 6.0 + 0.75) / 2.0).abs() < 1e-12);
        assert_eq!(
            (g.confusion.accepted_accepted, g.confusion.accepted_rejected),
            (5, 1)
        );
        assert_eq!(
            (g.confusion.rejected_accepted, g.confusion.rejected_rejected),
            (1, 3)
        );
        // Log-loss of 0.8 on the right and 0.2 on the wrong: −(8 ln 0.8 + 2 ln 0.2) / 10.
        let expected = -(8.0 * 0.8f64.ln() + 2.0 * 0.2f64.ln()) / 10.0;
        assert!((g.log_loss.unwrap() - expected).abs() < 1e-12);
        assert!(g.ci95.0 <= 0.8 && g.ci95.1 >= 0.8);
        let p = g.paired.as_ref().unwrap();
        assert!((p.difference - 0.2).abs() < 1e-12);
        assert_eq!((p.only_this, p.only_reference), (3, 1));
        // The same decisions as the reference: no difference, p = 1.
        let p = s.paired.as_ref().unwrap();
        assert_eq!((p.difference, p.p_value, p.mcnemar_p), (0.0, 1.0, 1.0));
        assert!(a.paired.is_none());
        assert_eq!(g.per_recording.len(), 2);
        assert!((g.per_recording[0].accuracy - 1.0).abs() < 1e-12);
        assert!((g.per_recording[1].accuracy - 0.6).abs() < 1e-12);
    }
}
