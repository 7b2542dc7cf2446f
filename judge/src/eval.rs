//! The policies run over the approaches of the logs: the gap rules and always go, behaviour
//! cloning and an agent per aggressiveness level, open loop at every labelled frame and, when
//! asked, closed loop among the replayed traffic.

use std::collections::BTreeMap;

use burn::tensor::Device;
use datasets::shard::Shard;
use maps::Map;
use models::ModelError;
use models::bc::{self, BcConfig, BcSummary};
use models::dqn::greedy_action;
use models::policy::QPolicy;
use models::qnet::QNetwork;
use sim::Observation;
use sim::tasks::insertion::Action;

use super::ReplayLog;
use super::report::Counts;
use super::tally::{LoopTally, Tally, score_approach};
use super::views::{FrameInput, Views};
use crate::closed_loop::{ClosedLoopConfig, ClosedLoopView, Command, drive};
use traffic::decisions::nearest_circulating;
use traffic::decisions::{Approach, Decision};

/// The gap rules' thresholds (go when the nearest vehicle on the ring is further than this,
/// m), then always go (no threshold).
pub const RULE_THRESHOLDS: [Option<f64>; 5] =
    [Some(25.0), Some(20.0), Some(15.0), Some(10.0), None];

/// Aggressiveness given to behaviour cloning (the drivers' own is unknown). It gets no last
/// action: in training that would be the driver's previous decision, which nearly always
/// equals the current one, so the classifier would learn to repeat it and, fed its own
/// decisions, never change its mind.
pub const BC_AGGRESSIVENESS: f64 = 0.5;

/// The learnt policies evaluated beside the rules.
#[derive(Debug)]
pub struct Policies<'a> {
    /// A behaviour-cloning classifier of go / wait ([`BcExamples::train`]).
    pub bc: Option<&'a QNetwork>,
    /// An agent, evaluated once per level of `levels`.
    pub agent: Option<&'a QPolicy>,
    /// The agent's aggressiveness input, one evaluation per level.
    pub levels: &'a [f64],
    pub device: &'a Device,
}

impl Policies<'_> {
    /// The agent's levels (none without an agent).
    fn levels(&self) -> &[f64] {
        if self.agent.is_some() {
            self.levels
        } else {
            &[]
        }
    }
}

/// Go and wait frames of training logs, as behaviour cloning learns from them.
#[derive(Debug, Default)]
pub struct BcExamples {
    observations: Vec<Observation>,
    go: Vec<bool>,
}

impl BcExamples {
    /// Adds every `stride`-th go or wait frame of each approach of `log`.
    pub fn add(&mut self, map: &Map, views: &Views, log: &ReplayLog, stride: usize) {
        for approach in &log.approaches {
            let inputs = views.inputs(map, &log.frames, approach);
            for (i, (input, label)) in inputs.into_iter().zip(&approach.labels).enumerate() {
                let decision = match label {
                    Decision::Go => true,
                    Decision::Wait => false,
                    Decision::Ambiguous | Decision::Queued => continue,
                };
                if i % stride.max(1) == 0 {
                    self.observations
                        .push(views.observation(input, BC_AGGRESSIVENESS, None));
                    self.go.push(decision);
                }
            }
        }
    }

    /// Frames gathered.
    pub fn len(&self) -> usize {
        self.observations.len()
    }

    pub fn is_empty(&self) -> bool {
        self.observations.is_empty()
    }

    /// A classifier of go / wait trained on the frames (default settings).
    pub fn train(
        &self,
        views: &Views,
        seed: u64,
        device: &Device,
    ) -> Result<(QNetwork, BcSummary), ModelError> {
        bc::train(
            &self.observations,
            &self.go,
            &views.spec(),
            &BcConfig::default(),
            seed,
            device,
        )
    }
}

/// The policies' tallies over the approaches of `logs` (numbered over the logs in the order
/// given; with `shard`, only its share of them): the rules, always go, behaviour cloning,
/// then the agent per level; with `closed_loop`, each of them also drives each approach's
/// vehicle among the replayed others.
pub fn evaluate(
    map: &Map,
    views: &Views,
    logs: &[ReplayLog],
    policies: &Policies<'_>,
    shard: Option<Shard>,
    closed_loop: Option<&ClosedLoopConfig>,
) -> Counts {
    let levels = policies.levels();
    let mut scores: Vec<Tally> = RULE_THRESHOLDS
        .iter()
        .map(|t| Tally::new(t.map_or("always go".into(), |t| format!("rule {t} m"))))
        .collect();
    let bc_score = policies.bc.map(|_| {
        scores.push(Tally::new("behaviour cloning".into()));
        scores.len() - 1
    });
    let first_agent_score = scores.len();
    scores.extend(
        levels
            .iter()
            .map(|a| Tally::new(format!("agent, aggressiveness {a}"))),
    );
    // Closed loop: the same policies, Caution as itself.
    let mut loops: Vec<LoopTally> = if closed_loop.is_some() {
        scores
            .iter()
            .map(|t| LoopTally::new(t.policy.clone()))
            .collect()
    } else {
        Vec::new()
    };
    let mut frame_counts: BTreeMap<String, u64> = BTreeMap::new();
    let (mut n_approaches, mut n_stopped) = (0, 0);

    let total: u64 = logs.iter().map(|l| l.approaches.len() as u64).sum();
    let part = shard.map_or(0..total, |s| s.range(total));
    let numbered = logs
        .iter()
        .flat_map(|log| log.approaches.iter().map(move |a| (log, a)))
        .zip(0u64..);
    for ((log, approach), _) in numbered.filter(|(_, index)| part.contains(index)) {
        n_approaches += 1;
        n_stopped += usize::from(approach.stopped);
        for l in &approach.labels {
            *frame_counts
                .entry(format!("{l:?}").to_lowercase())
                .or_default() += 1;
        }
        let nearest: Vec<f64> = approach
            .frames
            .iter()
            .map(|&k| nearest_circulating(map, &log.frames[k], approach.track))
            .collect();
        for (score, threshold) in scores.iter_mut().zip(RULE_THRESHOLDS) {
            let goes: Vec<bool> = nearest
                .iter()
                .map(|near| threshold.is_none_or(|t| *near > t))
                .collect();
            score_approach(score, &log.name, approach, &log.frames, &goes);
        }
        if let Some(config) = closed_loop {
            drive_closed_loop(map, views, log, approach, config, policies, &mut loops);
        }
        if policies.bc.is_none() && policies.agent.is_none() {
            continue;
        }
        let inputs = views.inputs(map, &log.frames, approach);
        // Behaviour cloning, on each frame as it is.
        if let (Some(network), Some(i)) = (policies.bc, bc_score) {
            let observations: Vec<Observation> = inputs
                .iter()
                .map(|input| views.observation(input.clone(), BC_AGGRESSIVENESS, None))
                .collect();
            let goes = bc::predict(network, &observations, &views.spec(), policies.device);
            score_approach(&mut scores[i], &log.name, approach, &log.frames, &goes);
        }
        // The agent, once per aggressiveness level.
        if let Some(policy) = policies.agent {
            for (level, score) in levels.iter().zip(&mut scores[first_agent_score..]) {
                let goes = agent_goes(views, &inputs, policy, *level);
                score_approach(score, &log.name, approach, &log.frames, &goes);
            }
        }
    }
    Counts {
        approaches: n_approaches,
        approaches_with_a_stop: n_stopped,
        frames: frame_counts,
        policies: scores,
        closed_loop: loops,
    }
}

/// The agent's go (Permitted) or not at each of an approach's frames `inputs`, deciding
/// frame after frame with its last action as input, at aggressiveness `level`.
pub fn agent_goes(views: &Views, inputs: &[FrameInput], policy: &QPolicy, level: f64) -> Vec<bool> {
    let mut last = Action::Permitted;
    let mut goes = Vec::with_capacity(inputs.len());
    for input in inputs {
        let observation = views.observation(input.clone(), level, Some(last));
        let q = policy.q_values(&[&observation]);
        last = Action::from_index(greedy_action(&q)).unwrap_or(Action::NotPermitted);
        goes.push(last == Action::Permitted);
    }
    goes
}

/// Drives `approach` closed loop with every policy (in the order of `loops`: the rules and
/// always go, behaviour cloning, the agent per level) and adds the episodes up.
fn drive_closed_loop(
    map: &Map,
    views: &Views,
    log: &ReplayLog,
    approach: &Approach,
    config: &ClosedLoopConfig,
    policies: &Policies<'_>,
    loops: &mut [LoopTally],
) {
    let mut tallies = loops.iter_mut();
    let mut run = |policy: &mut dyn FnMut(&ClosedLoopView<'_>) -> Command| {
        if let (Some(tally), Some(episode)) = (
            tallies.next(),
            drive(map, &views.renderer, &log.frames, approach, config, policy),
        ) {
            tally.add(&episode);
            if let Some(delay) = episode.entry_delay_s
                && let (Some(gap), Some(driver)) = (
                    log.accepted_gap(approach.track, delay),
                    log.accepted_gap(approach.track, 0.0),
                )
            {
                tally.add_gaps(gap, driver);
            }
        }
    };
    for threshold in RULE_THRESHOLDS {
        run(&mut |view: &ClosedLoopView<'_>| {
            let near = nearest_circulating(map, view.frame, approach.track);
            if threshold.is_none_or(|t| near > t) {
                Command::Go
            } else {
                Command::Wait
            }
        });
    }
    if let Some(network) = policies.bc {
        let mut inputs = views.closed_loop_inputs();
        run(&mut |view: &ClosedLoopView<'_>| {
            let input = inputs.at(map, approach.track, view);
            let observation = views.observation(input, BC_AGGRESSIVENESS, None);
            let go = bc::predict(network, &[observation], &views.spec(), policies.device);
            if go.first() == Some(&true) {
                Command::Go
            } else {
                Command::Wait
            }
        });
    }
    if let Some(policy) = policies.agent {
        for &level in policies.levels() {
            let mut last = Action::Permitted;
            let mut inputs = views.closed_loop_inputs();
            run(&mut |view: &ClosedLoopView<'_>| {
                let input = inputs.at(map, approach.track, view);
                let observation = views.observation(input, level, Some(last));
                let q = policy.q_values(&[&observation]);
                last = Action::from_index(greedy_action(&q)).unwrap_or(Action::NotPermitted);
                match last {
                    Action::Permitted => Command::Go,
                    Action::NotPermitted => Command::Wait,
                    Action::Caution => Command::Caution,
                }
            });
        }
    }
}
