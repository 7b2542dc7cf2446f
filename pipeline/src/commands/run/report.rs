//! `report.md`: each stage's key figures, read from the files its commands wrote, with
//! links to the pictures they made. Written after every `pipeline run`, skipped stages
//! included (their outputs are still there).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;
use judge::REPLAY_MD;
use logs::simulated::PROJECTION_JSON;
use serde_json::Value;

use super::manifest::Manifest;
use super::stages::{
    AGENT_EVAL, AGENT_MODEL, AUGMENTED, CAMPUS_MAP, GENERATED, REPLAY, ROUNDABOUT_MAP,
    SEGMENTER_EVAL, SEGMENTER_MODEL, SIMULATED_LOG, StageName,
};
use super::{MANIFEST_FILE, StageOutcome};
use crate::output::write_file_atomic;
use crate::recording::RECORDING_FILE;

pub const REPORT_FILE: &str = "report.md";

fn json(path: &Path) -> Option<Value> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
}

/// A number at a JSON pointer, formatted, or "n/a".
fn number(v: &Option<Value>, pointer: &str, decimals: usize) -> String {
    v.as_ref()
        .and_then(|v| v.pointer(pointer))
        .and_then(Value::as_f64)
        .map_or("n/a".into(), |x| format!("{x:.decimals$}"))
}

/// Items in a dataset folder's manifest (0 when it cannot be read).
fn items_in(dataset: &Path) -> usize {
    datasets::manifest::read_manifest(&dataset.join(datasets::manifest::MANIFEST_FILE))
        .map_or(0, |items| items.len())
}

/// Markdown image links (relative to the run folder) to those of `pictures` that exist, on one
/// line after a blank one (ending the paragraph before); empty when none does.
fn pictures(run_dir: &Path, pictures: &[(&str, &str)]) -> String {
    let links: Vec<String> = pictures
        .iter()
        .filter(|(_, rel)| run_dir.join(rel).is_file())
        .map(|(alt, rel)| format!("![{alt}]({rel})"))
        .collect();
    if links.is_empty() {
        String::new()
    } else {
        format!("\n\n{}", links.join(" "))
    }
}

/// A markdown page another command wrote, without its `# ` title.
fn page_without_title(path: &Path) -> String {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.starts_with("# "))
        .collect::<Vec<_>>()
        .join("\n")
        .trim_end()
        .to_owned()
}

pub fn write(
    run_dir: &Path,
    manifest: &Manifest,
    outcomes: &BTreeMap<StageName, StageOutcome>,
    profile: &str,
) -> Result<PathBuf> {
    let mut md = String::new();
    let _ = writeln!(md, "# Pipeline run ({profile} profile)\n");
    let _ = writeln!(
        md,
        "Run folder `{}`; stage inputs, settings and output hashes in [`{MANIFEST_FILE}`]({MANIFEST_FILE}); \
         the stages run by this invocation are in [`{RECORDING_FILE}`]({RECORDING_FILE}) (`rerun {RECORDING_FILE}`).\n",
        run_dir.display()
    );
    let _ = writeln!(
        md,
        "| stage | this run | last run took |\n| --- | --- | ---: |"
    );
    for (stage, outcome) in outcomes {
        let status = match outcome {
            StageOutcome::Ran => "ran",
            StageOutcome::Skipped => "up to date (skipped)",
            StageOutcome::NotSelected => "not selected",
        };
        let took = manifest
            .stages
            .get(stage.as_str())
            .map_or("not finished".into(), |r| format!("{:.1} s", r.seconds));
        let _ = writeln!(md, "| {} | {status} | {took} |", stage.as_str());
    }

    let finished = |s: StageName| manifest.stages.contains_key(s.as_str());
    if finished(StageName::Maps) {
        let _ = writeln!(
            md,
            "\n## Maps\n\n| map | lanes | lane km | junctions | stop / give-way lines | roundabouts |\n| --- | ---: | ---: | ---: | ---: | ---: |"
        );
        for rel in [CAMPUS_MAP, ROUNDABOUT_MAP] {
            let s = json(&run_dir.join(rel).join("summary.json"));
            let km = s
                .as_ref()
                .and_then(|v| v.pointer("/lane_length_m"))
                .and_then(Value::as_f64)
                .map_or("n/a".into(), |m| format!("{:.1}", m / 1000.0));
            let roundabouts = s
                .as_ref()
                .and_then(|v| v.pointer("/roundabouts"))
                .and_then(Value::as_array)
                .map_or("n/a".into(), |a| a.len().to_string());
            let _ = writeln!(
                md,
                "| `{rel}` | {} | {km} | {} | {} | {roundabouts} |",
                number(&s, "/lanes", 0),
                number(&s, "/junctions", 0),
                number(&s, "/stop_lines/total", 0)
            );
        }
        let _ = write!(
            md,
            "{}",
            pictures(
                run_dir,
                &[
                    ("campus", &format!("{CAMPUS_MAP}/preview.png")),
                    ("roundabout", &format!("{ROUNDABOUT_MAP}/preview.png")),
                ]
            )
            .replacen('\n', "", 1)
        );
        md.push('\n');
    }
    if finished(StageName::Dataset) {
        let split = json(&run_dir.join(GENERATED).join("split.json"));
        let mut sentence = format!(
            "{} images rendered on the campus (`{GENERATED}`), split {} train / {} val",
            items_in(&run_dir.join(GENERATED)),
            number(&split, "/counts/train", 0),
            number(&split, "/counts/val", 0),
        );
        if finished(StageName::Augment) {
            let _ = write!(
                sentence,
                "; {} items after augmentation (`{AUGMENTED}`, thesis preset, originals included)",
                items_in(&run_dir.join(AUGMENTED))
            );
        }
        let _ = writeln!(md, "\n## Segmentation data\n\n{sentence}.");
    }
    if finished(StageName::Segmenter) {
        let m = json(&run_dir.join(SEGMENTER_EVAL).join("metrics.json"));
        let _ = writeln!(
            md,
            "\n## Segmenter\n\nModel `{SEGMENTER_MODEL}/best`; on {} validation images: mIoU **{}**, pixel accuracy {}.\n\n\
             | road | lane marking | vehicle | human | other |\n| ---: | ---: | ---: | ---: | ---: |\n| {} | {} | {} | {} | {} |{}",
            number(&m, "/images", 0),
            number(&m, "/miou", 3),
            number(&m, "/pixel_accuracy", 3),
            number(&m, "/per_class_iou/road", 3),
            number(&m, "/per_class_iou/lane_marking", 3),
            number(&m, "/per_class_iou/vehicle", 3),
            number(&m, "/per_class_iou/human", 3),
            number(&m, "/per_class_iou/other", 3),
            pictures(
                run_dir,
                &[
                    ("training curves", &format!("{SEGMENTER_MODEL}/curves.png")),
                    (
                        "confusion matrix",
                        &format!("{SEGMENTER_EVAL}/confusion.png")
                    ),
                ]
            ),
        );
    }
    if finished(StageName::Agent) {
        let summary = json(&run_dir.join(AGENT_MODEL).join("summary.json"));
        // The evaluation's own page, without its title.
        let table = page_without_title(&run_dir.join(AGENT_EVAL).join("eval.md"));
        let _ = writeln!(
            md,
            "\n## Roundabout-insertion agent\n\nTrained for {} transitions in {} s (`{AGENT_MODEL}`); evaluation (`{AGENT_EVAL}`):\n{}{}",
            number(&summary, "/steps", 0),
            number(&summary, "/wall_seconds", 0),
            table,
            pictures(
                run_dir,
                &[
                    ("training curves", &format!("{AGENT_MODEL}/curves.png")),
                    ("agent and baselines", &format!("{AGENT_EVAL}/eval.png")),
                ]
            ),
        );
    }
    if finished(StageName::Logs) {
        let p = json(&run_dir.join(SIMULATED_LOG).join(PROJECTION_JSON));
        let episodes = p
            .as_ref()
            .and_then(|v| v.pointer("/episodes"))
            .and_then(Value::as_array)
            .map_or(0, Vec::len);
        let agreement = p
            .as_ref()
            .and_then(|v| v.pointer("/layer_agreement"))
            .and_then(Value::as_object)
            .map(|o| {
                o.iter()
                    .map(|(k, v)| format!("{k} {:.4}", v.as_f64().unwrap_or(f64::NAN)))
                    .collect::<Vec<_>>()
                    .join(", ")
            })
            .unwrap_or_else(|| "n/a".into());
        let _ = writeln!(
            md,
            "\n## Logs\n\nSimulated drives written as MCAP logs: {episodes} (`{SIMULATED_LOG}`): {} frames, {} messages. \
             Read back and projected: largest footprint error {} m; bird's-eye pixels equal to the simulator's: {agreement}.\n\n\
             Real logs (INTERACTION tracks, ROS 2 bags) are not bundled: convert them with `pipeline logs convert` and \
             inspect them with `pipeline logs info`, project them with `pipeline logs project` (docs/logs.md).",
            number(&p, "/frames", 0),
            number(&p, "/messages", 0),
            number(&p, "/max_position_error_m", 6),
        );
    }
    if finished(StageName::Replay) {
        let body = page_without_title(&run_dir.join(REPLAY).join(REPLAY_MD));
        let _ = writeln!(
            md,
            "\n## Replay\n\nThe agent and the baselines against the simulated drivers' go / wait decisions in the logs above \
             (`{REPLAY}`; the same command judges them against real drivers: `pipeline replay eval --log <INTERACTION \
             track file converted with logs convert> --map <its Lanelet2 map> --agent {AGENT_MODEL}`):\n{}",
            body
        );
    }
    let path = run_dir.join(REPORT_FILE);
    write_file_atomic(&path, md.as_bytes())?;
    Ok(path)
}
