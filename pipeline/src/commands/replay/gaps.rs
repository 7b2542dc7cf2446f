//! `pipeline replay gaps`: gap acceptance at the yield lines of recordings, and the policies
//! (the fitted critical gaps, the distance rules, always accept, behaviour cloning, an agent)
//! scored on every offered gap. The extraction, fits and scores are `judge::gaps`'; this
//! command reads the recordings, calls it and writes `gaps.json`, `gaps.md`, `gaps.csv` and
//! the recording.

use std::fmt::Write as _;

use anyhow::Result;
use judge::ReplayLog;
use judge::gaps::policies::{GapDecision, fit, rules};
use judge::gaps::score::{GapsReport, decide, markdown, score};
use traffic::gaps::{Features, OfferedGap, RecordingGaps, offered_gaps};

use super::GapsArgs;
use crate::commands::Context;
use crate::error::CliError;
use crate::log_args::{load_replay_agent, replay_views};
use crate::output::{AtomicDir, Markers, write_file_atomic, write_json};
use crate::recordings::{Measured, measure_recordings};

pub const GAPS_JSON: &str = "gaps.json";
pub const GAPS_MD: &str = "gaps.md";
pub const GAPS_CSV: &str = "gaps.csv";
const MARKERS: Markers = &[GAPS_JSON];

pub fn run(ctx: &Context<'_>, args: &GapsArgs) -> Result<()> {
    let r = &args.recordings;
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    if args.train_map.is_some() && args.train_logs.is_empty() {
        return Err(CliError::new(
            "--train-map names the map of --train-log recordings, and none is given",
            "add --train-log recordings made on that map, or leave --train-map out",
        )
        .into());
    }
    if let Some(both) = args.train_logs.iter().find(|t| r.logs.contains(t)) {
        return Err(CliError::file(
            both,
            "is given both to score (--log) and to fit on (--train-log)",
            "fit on other recordings than the ones scored",
        )
        .into());
    }
    // Recordings of one map are measured together (the ring they enter most); training
    // recordings of another map (--train-map) at that map's ring.
    let same_map = args.train_map.is_none();
    let all: Vec<_> = if same_map {
        r.logs.iter().chain(&args.train_logs).cloned().collect()
    } else {
        r.logs.clone()
    };
    let measured = measure_recordings(ctx, &r.map, r.roundabout, &all, "replay gaps")?;
    // The drivers are the approaches `replay eval` finds, with the same labels.
    let labels = ctx.config.logs.decisions.clone();
    let mut recordings = recordings_gaps(&measured, &all, &labels);
    if let (Some(train_map), false) = (&args.train_map, args.train_logs.is_empty()) {
        let other = measure_recordings(ctx, train_map, None, &args.train_logs, "replay gaps")?;
        recordings.extend(recordings_gaps(&other, &args.train_logs, &labels));
    }
    let mut progress = ctx.ui.progress("replay gaps");
    let (scored, train) = recordings.split_at(r.logs.len());
    let gaps: Vec<OfferedGap> = scored.iter().flat_map(|r| r.gaps.clone()).collect();
    if gaps.is_empty() {
        return Err(CliError::new(
            format!(
                "no gap was offered at roundabout {} in the --log recordings",
                measured.geometry.roundabout.0
            ),
            "give recordings in which vehicles enter the roundabout",
        )
        .into());
    }

    // The fits: on the training recordings, else (as a description only) the scored ones.
    progress.step("fitting the critical gaps");
    let fit_on = if train.is_empty() { scored } else { train };
    let fitted = fit(fit_on, ctx.global.seed).map_err(|e| {
        CliError::new(
            format!("cannot fit the critical gap: {e}"),
            "give more recordings (--train-log, repeated)",
        )
    })?;
    let policies = if train.is_empty() {
        rules()
    } else {
        fitted.policies()
    };
    let mut decisions = decide(&gaps, &policies);
    if !train.is_empty() {
        decisions.push((
            "critical gap (maximum likelihood) on the true gap: hindsight, not a policy".into(),
            fitted.hindsight(&gaps),
        ));
    }

    if let Some(dir) = &args.agent {
        progress.step(&format!("the agent {}", dir.display()));
        let device = models::cpu_device();
        let (policy, task) = load_replay_agent(dir, &device, &mut |s| progress.note(s))?;
        let views = replay_views(&measured.map, &r.map, task, args.target_speed)?;
        let mut agent: Vec<GapDecision> = Vec::with_capacity(gaps.len());
        for (recording, frames) in scored.iter().zip(&measured.frames) {
            let log = ReplayLog::new(
                recording.name.clone(),
                frames.clone(),
                &measured.map,
                &labels,
            );
            agent.extend(judge::gaps::agent_decisions(
                &measured.map,
                &views,
                &log,
                &recording.gaps,
                &policy,
                args.aggressiveness,
            ));
        }
        decisions.push((
            format!("agent, aggressiveness {}", args.aggressiveness),
            agent,
        ));
    }

    progress.step("scoring");
    let scores = score(&gaps, &decisions, ctx.global.seed);
    // The approaches offered a gap (its drivers), of all the approaches found.
    let offered_a_gap = gaps
        .iter()
        .map(|g| (&g.recording, g.track))
        .collect::<std::collections::BTreeSet<_>>()
        .len() as u64;
    let approaches: u64 = scored.iter().map(|r| r.approaches).sum();
    let report = GapsReport {
        offered: gaps.len() as u64,
        accepted: gaps.iter().filter(|g| g.accepted).count() as u64,
        roundabout: measured.geometry.roundabout.0,
        approaches,
        approaches_offered_a_gap: offered_a_gap,
        approaches_without_a_known_gap: approaches.saturating_sub(offered_a_gap),
        crossings_without_an_approach: scored.iter().map(|r| r.without_approach).sum(),
        approach_definition: traffic::decisions::APPROACH_DEFINITION,
        critical_gap_s: fitted.critical_gap.median_s,
        critical_gap_ci95_s: fitted.critical_gap.median_ci95_s,
        raff_critical_gap_s: fitted.raff_s,
        follow_up_headway_s: fitted.follow_up_headway_s,
        fitted_on: train.iter().map(|r| r.name.clone()).collect(),
        scored: scored.iter().map(|r| r.name.clone()).collect(),
        classifier_l2: fitted.l2_choice.clone(),
        policies: scores,
    };
    let md = markdown(&report);
    let dir = AtomicDir::create(&out, MARKERS)?;
    write_json(&dir.path().join(GAPS_JSON), &report)?;
    write_file_atomic(&dir.path().join(GAPS_MD), md.as_bytes())?;
    write_file_atomic(
        &dir.path().join(GAPS_CSV),
        gaps_csv(&gaps, &decisions).as_bytes(),
    )?;
    let recording = ctx.open_recording(Some(dir.path()))?;
    if let Some(rec) = recording.stream() {
        let rerun_error = |e: rerun::RecordingStreamError| {
            CliError::new(
                format!("rerun: cannot log the gaps: {e}"),
                "use --rerun off",
            )
        };
        rec.log_static(
            "replay/gaps/table",
            &rerun::TextDocument::from_markdown(md.clone()),
        )
        .map_err(rerun_error)?;
        for (i, g) in gaps.iter().enumerate() {
            rec.set_duration_secs("recording_time", g.offered_s);
            let verdicts: Vec<String> = decisions
                .iter()
                .map(|(name, ds)| {
                    format!("{name}: {}", if ds[i].accept { "accept" } else { "reject" })
                })
                .collect();
            rec.log(
                format!(
                    "replay/gaps/{}/entry_{}",
                    g.recording.replace('.', "_"),
                    g.entry
                ),
                &rerun::TextLog::new(format!(
                    "track {} gap {} ({:.1} s, next vehicle in {:.1} s): driver {}; {}",
                    g.track,
                    g.index,
                    g.length_s,
                    g.features.eta_s,
                    if g.accepted { "accepted" } else { "rejected" },
                    verdicts.join(", ")
                )),
            )
            .map_err(rerun_error)?;
        }
        rec.reset_time();
    }
    recording.finish()?;
    let dest = dir.commit()?;
    drop(progress);
    ctx.ui.result(&md);
    ctx.ui.info(&format!("wrote {}", dest.display()));
    Ok(())
}

/// The offered gaps of each recording of `measured` (read from `paths`, in order) to the
/// drivers of its approaches found with `labels`.
fn recordings_gaps(
    measured: &Measured,
    paths: &[std::path::PathBuf],
    labels: &traffic::decisions::LabelConfig,
) -> Vec<RecordingGaps> {
    paths
        .iter()
        .zip(&measured.frames)
        .map(|(path, frames)| {
            let name = path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
            offered_gaps(&measured.map, &measured.geometry, &name, frames, labels)
        })
        .collect()
}

/// `gaps.csv`: one line per offered gap: where and when, its true length, the driver's
/// decision, the features, then each policy's decision (1 accept, 0 reject).
fn gaps_csv(gaps: &[OfferedGap], decisions: &[(String, Vec<GapDecision>)]) -> String {
    let mut out = String::from("recording,track,entry,index,offered_s,length_s,accepted");
    for name in Features::NAMES {
        let _ = write!(out, ",{name}");
    }
    for (name, _) in decisions {
        let _ = write!(out, ",\"{name}\"");
    }
    out.push('\n');
    for (i, g) in gaps.iter().enumerate() {
        let _ = write!(
            out,
            "{},{},{},{},{:.3},{:.3},{}",
            g.recording,
            g.track,
            g.entry,
            g.index,
            g.offered_s,
            g.length_s,
            u8::from(g.accepted)
        );
        for v in g.features.vector() {
            let _ = write!(out, ",{v:.4}");
        }
        for (_, ds) in decisions {
            let _ = write!(out, ",{}", u8::from(ds[i].accept));
        }
        out.push('\n');
    }
    out
}
