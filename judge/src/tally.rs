//! What each policy did, as counts that the shards of a run add up ([`Tally`] open loop,
//! [`LoopTally`] closed loop), and the rates computed from them ([`Score`], [`LoopScore`]).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use sim::stats::{PairedDifference, bootstrap_mean, paired_bootstrap};

use crate::closed_loop::{ClosedLoopEpisode, ClosedLoopOutcome};
use logs::project::LogFrame;
use traffic::decisions::{Approach, Decision};

/// What one policy did in closed loop, as counts and per-episode figures (in approach
/// order, so that shards put one after the other give the unsharded means to the bit).
#[derive(Debug, Default, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoopTally {
    pub policy: String,
    pub episodes: u64,
    pub reached: u64,
    pub crashed: u64,
    /// Hit from behind by a replayed road user (which cannot react).
    pub rear_ended: u64,
    pub time_over: u64,
    /// Per episode: the mean distance to the driver's position, m.
    pub divergences_m: Vec<f64>,
    /// Per episode that entered: its crossing of the yield line minus its driver's, s.
    pub entry_delays_s: Vec<f64>,
    /// Per episode that entered where both are known: the gap it accepted, and the gap its
    /// driver accepted, s (paired, in approach order).
    #[serde(default)]
    pub accepted_gaps_s: Vec<f64>,
    #[serde(default)]
    pub driver_gaps_s: Vec<f64>,
}

impl LoopTally {
    pub fn new(policy: String) -> LoopTally {
        LoopTally {
            policy,
            ..Default::default()
        }
    }

    pub fn add(&mut self, episode: &ClosedLoopEpisode) {
        self.episodes += 1;
        match episode.outcome {
            ClosedLoopOutcome::Reached => self.reached += 1,
            ClosedLoopOutcome::Crashed => self.crashed += 1,
            ClosedLoopOutcome::RearEnded => self.rear_ended += 1,
            ClosedLoopOutcome::TimeOver => self.time_over += 1,
        }
        self.divergences_m.push(episode.log_divergence_m);
        self.entry_delays_s.extend(episode.entry_delay_s);
    }

    /// Adds the gap one episode accepted beside its driver's.
    pub fn add_gaps(&mut self, accepted_s: f64, driver_s: f64) {
        self.accepted_gaps_s.push(accepted_s);
        self.driver_gaps_s.push(driver_s);
    }

    pub fn absorb(&mut self, other: &LoopTally) {
        self.episodes += other.episodes;
        self.reached += other.reached;
        self.crashed += other.crashed;
        self.rear_ended += other.rear_ended;
        self.time_over += other.time_over;
        self.divergences_m.extend_from_slice(&other.divergences_m);
        self.entry_delays_s.extend_from_slice(&other.entry_delays_s);
        self.accepted_gaps_s
            .extend_from_slice(&other.accepted_gaps_s);
        self.driver_gaps_s.extend_from_slice(&other.driver_gaps_s);
    }

    pub fn score(&self) -> LoopScore {
        let n = self.episodes.max(1) as f64;
        let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        LoopScore {
            policy: self.policy.clone(),
            episodes: self.episodes,
            reached: self.reached as f64 / n,
            crashed: self.crashed as f64 / n,
            rear_ended: self.rear_ended as f64 / n,
            time_over: self.time_over as f64 / n,
            mean_log_divergence_m: mean(&self.divergences_m).unwrap_or(0.0),
            mean_entry_delay_s: mean(&self.entry_delays_s),
            entry_delay_ci95_s: interval(&self.entry_delays_s),
            mean_accepted_gap_s: mean(&self.accepted_gaps_s),
            accepted_gap_ci95_s: interval(&self.accepted_gaps_s),
            drivers_mean_accepted_gap_s: mean(&self.driver_gaps_s),
            drivers_accepted_gap_ci95_s: interval(&self.driver_gaps_s),
            gap_against_drivers: (!self.accepted_gaps_s.is_empty()).then(|| {
                paired_bootstrap(&self.accepted_gaps_s, &self.driver_gaps_s, BOOTSTRAP, 0)
            }),
        }
    }
}

/// How one policy did in closed loop.
#[derive(Debug, Clone, Serialize)]
pub struct LoopScore {
    pub policy: String,
    pub episodes: u64,
    pub reached: f64,
    pub crashed: f64,
    pub rear_ended: f64,
    pub time_over: f64,
    /// Mean over episodes of the mean distance to the driver's position at the same time, m.
    pub mean_log_divergence_m: f64,
    /// Mean over episodes that entered of the entry time minus the driver's, s.
    pub mean_entry_delay_s: Option<f64>,
    /// Its 95 % bootstrap interval.
    pub entry_delay_ci95_s: Option<(f64, f64)>,
    /// Mean gap accepted (episodes that entered, where the gap is known), s, and its interval.
    pub mean_accepted_gap_s: Option<f64>,
    pub accepted_gap_ci95_s: Option<(f64, f64)>,
    /// The drivers' own accepted gaps on the same approaches.
    pub drivers_mean_accepted_gap_s: Option<f64>,
    pub drivers_accepted_gap_ci95_s: Option<(f64, f64)>,
    /// The policy's accepted gaps minus the drivers', paired by approach.
    pub gap_against_drivers: Option<PairedDifference>,
}

/// Bootstrap replicates of the closed-loop intervals.
const BOOTSTRAP: usize = 2000;

/// The 95 % bootstrap interval of the mean of `xs` (None when empty).
fn interval(xs: &[f64]) -> Option<(f64, f64)> {
    (!xs.is_empty()).then(|| bootstrap_mean(xs, BOOTSTRAP, 0).ci95)
}

/// What one policy did, as counts that shards add up.
#[derive(Debug, Default, Clone, PartialEq, Serialize, Deserialize)]
pub struct Tally {
    pub policy: String,
    /// `confusion[human][policy]`, human and policy each `go` or `wait`.
    pub confusion: BTreeMap<String, BTreeMap<String, u64>>,
    /// Per log: (frames where the policy decided as the driver did, go and wait frames).
    pub matches_per_log: BTreeMap<String, (u64, u64)>,
    /// Per approach with a stop (in approach order): the policy's first go minus the
    /// driver's, s.
    pub delays: Vec<f64>,
}

impl Tally {
    pub fn new(policy: String) -> Tally {
        Tally {
            policy,
            ..Default::default()
        }
    }

    pub fn add(&mut self, log: &str, human: Decision, go: bool) {
        let h = match human {
            Decision::Go => "go",
            Decision::Wait => "wait",
            Decision::Ambiguous | Decision::Queued => return,
        };
        let p = if go { "go" } else { "wait" };
        *self
            .confusion
            .entry(h.into())
            .or_default()
            .entry(p.into())
            .or_default() += 1;
        let e = self.matches_per_log.entry(log.into()).or_default();
        e.0 += u64::from(h == p);
        e.1 += 1;
    }

    /// Adds a later shard's counts (its delays after these).
    pub fn absorb(&mut self, other: &Tally) {
        for (h, row) in &other.confusion {
            for (p, n) in row {
                *self
                    .confusion
                    .entry(h.clone())
                    .or_default()
                    .entry(p.clone())
                    .or_default() += n;
            }
        }
        for (log, (m, n)) in &other.matches_per_log {
            let e = self.matches_per_log.entry(log.clone()).or_default();
            e.0 += m;
            e.1 += n;
        }
        self.delays.extend_from_slice(&other.delays);
    }

    /// The rates.
    pub fn score(self) -> Score {
        let (m, n) = self
            .matches_per_log
            .values()
            .fold((0, 0), |(a, b), (m, n)| (a + m, b + n));
        Score {
            policy: self.policy,
            agreement: m as f64 / n.max(1) as f64,
            agreement_ci95: sim::stats::wilson(m, n),
            go_delay_ci95_s: interval(&self.delays),
            confusion: self.confusion,
            per_log: self
                .matches_per_log
                .iter()
                .map(|(k, (m, n))| (k.clone(), *m as f64 / (*n).max(1) as f64))
                .collect(),
            mean_go_delay_s: (!self.delays.is_empty())
                .then(|| self.delays.iter().sum::<f64>() / self.delays.len() as f64),
        }
    }
}

/// How one policy did.
#[derive(Debug, Default, Clone, Serialize)]
pub struct Score {
    pub policy: String,
    /// Of the go and wait frames, the share where the policy decided as the driver did.
    pub agreement: f64,
    /// Its 95 % Wilson interval over frames (frames of one approach are not independent:
    /// an interval over approaches would be wider).
    pub agreement_ci95: (f64, f64),
    /// 95 % bootstrap interval of `mean_go_delay_s`.
    pub go_delay_ci95_s: Option<(f64, f64)>,
    /// `confusion[human][policy]`, human and policy each `go` or `wait`.
    pub confusion: BTreeMap<String, BTreeMap<String, u64>>,
    /// Per log: agreement.
    pub per_log: BTreeMap<String, f64>,
    /// Over approaches where the driver stopped: the policy's first go minus the driver's
    /// (first go-labelled frame), s; positive = the policy went later.
    pub mean_go_delay_s: Option<f64>,
}

/// Scores one approach's decisions (`goes[i]` at the approach's i-th frame).
pub(crate) fn score_approach(
    score: &mut Tally,
    log: &str,
    approach: &Approach,
    frames: &[LogFrame],
    goes: &[bool],
) {
    for (label, go) in approach.labels.iter().zip(goes) {
        score.add(log, *label, *go);
    }
    if approach.stopped {
        let time = |i: usize| frames[approach.frames[i]].time_ns as f64 * 1e-9;
        let human = approach.labels.iter().position(|l| *l == Decision::Go);
        let policy = goes.iter().position(|g| *g);
        if let (Some(h), Some(p)) = (human, policy) {
            score.delays.push(time(p) - time(h));
        }
    }
}
