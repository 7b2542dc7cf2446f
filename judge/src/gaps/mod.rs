//! Gap acceptance at roundabout entries (`pipeline replay gaps`): policies fitted and scored
//! on the gaps drivers were offered ([`traffic::gaps`]).
//!
//! - [`policies`] fits the critical gap (Troutbeck's maximum likelihood, Raff's method) and a
//!   behaviour-cloning classifier (logistic regression) on training recordings, and holds the
//!   rules;
//! - [`score`] scores the policies (accuracy, balanced accuracy, log-loss, confusion matrix,
//!   per recording, bootstrap intervals over approaches, paired tests) into `gaps.json` and
//!   `gaps.md`;
//! - [`agent_decisions`] asks a trained agent about each offered gap.

pub mod policies;
pub mod score;

use maps::Map;
use traffic::gaps::OfferedGap;

/// The agent's decision at each of `gaps` of one recording (`log`, the same recording's
/// frames and approaches): it drives each approach frame after frame as in `replay eval`,
/// and its decision at a gap is the one at the last frame at or before the gap was offered
/// (Permitted accepts; Caution and Not permitted reject). Every gap [`traffic::gaps::offered_gaps`] finds
/// has its driver's approach in `log` when both were found with the same labels; a gap
/// without one (other labels) is rejected (counted by the caller as any other).
pub fn agent_decisions(
    map: &Map,
    views: &crate::Views,
    log: &crate::ReplayLog,
    gaps: &[OfferedGap],
    policy: &models::policy::QPolicy,
    aggressiveness: f64,
) -> Vec<policies::GapDecision> {
    let t0 = log.frames.first().map_or(0, |f| f.time_ns);
    let mut goes_of: std::collections::BTreeMap<u32, (Vec<u64>, Vec<bool>)> = Default::default();
    gaps.iter()
        .map(|g| {
            let (times, goes) = goes_of.entry(g.track).or_insert_with(|| {
                let Some(approach) = log.approaches.iter().find(|a| a.track == g.track) else {
                    return (Vec::new(), Vec::new());
                };
                let inputs = views.inputs(map, &log.frames, approach);
                let goes = crate::agent_goes(views, &inputs, policy, aggressiveness);
                let times = approach
                    .frames
                    .iter()
                    .map(|&k| log.frames[k].time_ns)
                    .collect();
                (times, goes)
            });
            let at = t0 + (g.offered_s.max(0.0) * 1e9).round() as u64;
            let k = times.partition_point(|&t| t <= at);
            let accept = k
                .checked_sub(1)
                .and_then(|j| goes.get(j))
                .copied()
                .unwrap_or(false);
            policies::GapDecision {
                accept,
                probability: None,
            }
        })
        .collect()
}
