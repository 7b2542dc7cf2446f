//! What a replay run found: its settings and counts (the same figures whether the run was
//! sharded or not), the report with the rates (`replay.json`) and its markdown
//! (`replay.md`), and the shards of one run added up.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use datasets::DatasetError;
use datasets::shard::{Shard, in_order};
use models::bc::BcSummary;
use serde::{Deserialize, Serialize};

use super::REPLAY_SHARD_JSON;
use super::tally::{LoopScore, LoopTally, Score, Tally};
use traffic::decisions::{APPROACH_DEFINITION, LabelConfig};

/// What a run evaluated, the same in every shard of it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    pub logs: Vec<PathBuf>,
    pub map: PathBuf,
    pub agent: Option<PathBuf>,
    /// Logs behaviour cloning learnt from.
    pub train_logs: Vec<PathBuf>,
    pub labels: LabelConfig,
    pub behaviour_cloning: Option<BcSummary>,
}

/// The counts of a run or of a shard of it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Counts {
    pub approaches: usize,
    pub approaches_with_a_stop: usize,
    pub frames: BTreeMap<String, u64>,
    pub policies: Vec<Tally>,
    /// With --closed-loop.
    #[serde(default)]
    pub closed_loop: Vec<LoopTally>,
}

/// Why a shard's counts cannot be added to shard 0's ([`Counts::absorb`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CountsDiffer {
    #[error("other policies ({theirs:?}) than shard 0 ({ours:?})")]
    Policies {
        theirs: Vec<String>,
        ours: Vec<String>,
    },
    #[error("another closed-loop setting")]
    ClosedLoop,
}

impl Counts {
    /// Adds a later shard's counts; the policies must be the same.
    pub fn absorb(&mut self, other: &Counts) -> Result<(), CountsDiffer> {
        let names = |c: &Counts| {
            c.policies
                .iter()
                .map(|t| t.policy.clone())
                .collect::<Vec<_>>()
        };
        if names(self) != names(other) {
            return Err(CountsDiffer::Policies {
                theirs: names(other),
                ours: names(self),
            });
        }
        self.approaches += other.approaches;
        self.approaches_with_a_stop += other.approaches_with_a_stop;
        for (k, n) in &other.frames {
            *self.frames.entry(k.clone()).or_default() += n;
        }
        for (mine, theirs) in self.policies.iter_mut().zip(&other.policies) {
            mine.absorb(theirs);
        }
        if self.closed_loop.len() != other.closed_loop.len() {
            return Err(CountsDiffer::ClosedLoop);
        }
        for (mine, theirs) in self.closed_loop.iter_mut().zip(&other.closed_loop) {
            mine.absorb(theirs);
        }
        Ok(())
    }
}

/// `replay_shard.json`.
#[derive(Debug, Serialize, Deserialize)]
pub struct ShardFile {
    pub shard: Shard,
    pub settings: Settings,
    pub counts: Counts,
}

/// `replay.json`.
#[derive(Debug, Serialize)]
pub struct Report {
    pub logs: Vec<PathBuf>,
    pub map: PathBuf,
    pub agent: Option<PathBuf>,
    /// Logs behaviour cloning learnt from.
    pub train_logs: Vec<PathBuf>,
    pub labels: LabelConfig,
    pub behaviour_cloning: Option<BcSummary>,
    /// Approaches to the yield lines of the map's roundabouts, each with its frames labelled
    /// (`replay gaps` counts the same approaches of the roundabout it measures).
    pub approaches: usize,
    pub approaches_with_a_stop: usize,
    /// What an approach is ([`APPROACH_DEFINITION`]).
    pub approach_definition: &'static str,
    pub frames: BTreeMap<String, u64>,
    pub policies: Vec<Score>,
    /// With --closed-loop.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub closed_loop: Vec<LoopScore>,
}

impl Report {
    pub fn new(settings: Settings, counts: Counts) -> Report {
        Report {
            logs: settings.logs,
            map: settings.map,
            agent: settings.agent,
            train_logs: settings.train_logs,
            labels: settings.labels,
            behaviour_cloning: settings.behaviour_cloning,
            approaches: counts.approaches,
            approaches_with_a_stop: counts.approaches_with_a_stop,
            approach_definition: APPROACH_DEFINITION,
            frames: counts.frames,
            policies: counts.policies.into_iter().map(Tally::score).collect(),
            closed_loop: counts.closed_loop.iter().map(LoopTally::score).collect(),
        }
    }
}

/// Why the shards of a run do not add up.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    /// A shard file could not be read.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A file is not a shard file.
    #[error("{}: not a replay shard: {source}", path.display())]
    NotAShard {
        path: PathBuf,
        source: serde_json::Error,
    },
    /// The shards are not each of `0..n` once.
    #[error("{0}")]
    Order(DatasetError),
    #[error("no shard given")]
    NoShard,
    /// A shard was made with other settings or policies than shard 0.
    #[error("{}: shard {}/{} was made with {what} than shard 0", path.display(), shard.index, shard.count)]
    Differs {
        path: PathBuf,
        shard: Shard,
        what: String,
    },
}

/// The report of the run whose shard folders (each holding [`REPLAY_SHARD_JSON`]) are
/// `dirs`, given in any order: the shards' counts added up in shard order, which is the
/// unsharded run's report to the bit.
pub fn merge_shard_dirs(dirs: &[PathBuf]) -> Result<Report, MergeError> {
    let mut found = Vec::with_capacity(dirs.len());
    for dir in dirs {
        let path = dir.join(REPLAY_SHARD_JSON);
        let file = read_shard(&path)?;
        found.push((file.shard, (path, file)));
    }
    let mut ordered = in_order(found).map_err(MergeError::Order)?.into_iter();
    let Some((_, (_, first))) = ordered.next() else {
        return Err(MergeError::NoShard);
    };
    let (settings, mut counts) = (first.settings, first.counts);
    for (shard, (path, file)) in ordered {
        let differs = |what: String| MergeError::Differs {
            path: path.clone(),
            shard,
            what,
        };
        if file.settings != settings {
            return Err(differs(
                "other settings (logs, map, agent or behaviour cloning)".into(),
            ));
        }
        counts
            .absorb(&file.counts)
            .map_err(|e| differs(e.to_string()))?;
    }
    Ok(Report::new(settings, counts))
}

fn read_shard(path: &Path) -> Result<ShardFile, MergeError> {
    let text = std::fs::read_to_string(path).map_err(|source| MergeError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|source| MergeError::NotAShard {
        path: path.to_path_buf(),
        source,
    })
}

/// `replay.md`: the open-loop table, and the closed-loop one when there is one.
pub fn markdown(r: &Report) -> String {
    let mut md = open_loop_markdown(r);
    if !r.closed_loop.is_empty() {
        let _ = writeln!(
            md,
            "\n## Closed loop\n\nEach policy drives every approach's vehicle along its driver's path from the approach's start; the other road users replay the log and cannot react (*rear-ended*: hit from behind by one of them). Divergence: mean distance to the driver's position at the same time. Entry delay: its crossing of the yield line minus its driver's. Accepted gap: from the later of the driver's arrival at the line and the last conflicting pass before the crossing, to the next pass (as `replay gaps` measures it), beside the drivers' own on the same approaches; 95 % bootstrap intervals, and the paired bootstrap of the difference.\n\n| policy | episodes | reached | crashed | rear-ended | time over | log divergence m | entry delay s [95 %] | accepted gap s [95 %] | drivers' gap s | difference s [95 %], p |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
        );
        for l in &r.closed_loop {
            let _ = writeln!(
                md,
                "| {} | {} | {:.1} % | {:.1} % | {:.1} % | {:.1} % | {:.2} | {} | {} | {} | {} |",
                l.policy,
                l.episodes,
                100.0 * l.reached,
                100.0 * l.crashed,
                100.0 * l.rear_ended,
                100.0 * l.time_over,
                l.mean_log_divergence_m,
                with_interval(l.mean_entry_delay_s, l.entry_delay_ci95_s, true),
                with_interval(l.mean_accepted_gap_s, l.accepted_gap_ci95_s, false),
                with_interval(
                    l.drivers_mean_accepted_gap_s,
                    l.drivers_accepted_gap_ci95_s,
                    false
                ),
                l.gap_against_drivers.map_or("-".into(), |d| format!(
                    "{:+.2} [{:+.2}, {:+.2}], {}",
                    d.difference,
                    d.ci95.0,
                    d.ci95.1,
                    sim::eval::p_text(d.p_value)
                )),
            );
        }
    }
    md
}

/// "1.23 [1.01, 1.45]" (signed with `signed`), "-" without a value.
fn with_interval(value: Option<f64>, ci: Option<(f64, f64)>, signed: bool) -> String {
    match (value, ci) {
        (Some(v), Some((lo, hi))) if signed => format!("{v:+.2} [{lo:+.2}, {hi:+.2}]"),
        (Some(v), Some((lo, hi))) => format!("{v:.2} [{lo:.2}, {hi:.2}]"),
        (Some(v), None) => format!("{v:.2}"),
        _ => "-".into(),
    }
}

/// The open-loop part of replay.md.
fn open_loop_markdown(r: &Report) -> String {
    let mut md = String::new();
    let go = r.frames.get("go").copied().unwrap_or(0);
    let wait = r.frames.get("wait").copied().unwrap_or(0);
    let amb = r.frames.get("ambiguous").copied().unwrap_or(0);
    let queued = r.frames.get("queued").copied().unwrap_or(0);
    let _ = writeln!(
        md,
        "# Replay against human decisions\n\n{} logs, {} approaches to a yield line ({} with a stop); frames labelled go {go}, wait {wait}; not scored: ambiguous {amb}, queued behind another vehicle {queued}. An approach is a track's first crossing of a yield line towards the ring with at least {} s of the track within {} m before the line, its frames up to the crossing labelled; `replay gaps` counts the same approaches and scores the gaps offered to those whose recording shows the outcome.\n",
        r.logs.len(),
        r.approaches,
        r.approaches_with_a_stop,
        r.labels.min_approach_s,
        r.labels.approach_m,
    );
    let _ = writeln!(
        md,
        "The labels follow each driver's own speed (wait = stopped or braking to a stop): agreement says how often a policy moved when the driver did, not whether it judged the traffic as the driver did (`replay gaps` measures that). Intervals: 95 %, Wilson over frames, bootstrap over approaches for the delay.\n\n| policy | agreement [95 %] | human go: policy go / wait | human wait: policy go / wait | mean go delay s [95 %] |\n| --- | ---: | ---: | ---: | ---: |"
    );
    for s in &r.policies {
        let cell = |h: &str| {
            let c = s.confusion.get(h);
            let n = |p: &str| c.and_then(|c| c.get(p)).copied().unwrap_or(0);
            format!("{} / {}", n("go"), n("wait"))
        };
        let _ = writeln!(
            md,
            "| {} | {:.1} % [{:.1}, {:.1}] | {} | {} | {} |",
            s.policy,
            100.0 * s.agreement,
            100.0 * s.agreement_ci95.0,
            100.0 * s.agreement_ci95.1,
            cell("go"),
            cell("wait"),
            with_interval(s.mean_go_delay_s, s.go_delay_ci95_s, true)
        );
    }
    md
}
