//! What `segmenter eval` writes: the report (`metrics.json`) and its table (`report.md`).

use std::fmt::Write as _;

use std::collections::BTreeMap;
use std::path::PathBuf;

use models::segmenter::MetricsSummary;
use models::segmenter::metrics::{ConfusionMatrix, IouIntervals};
use models::segmenter::shipped::SHIPPED_MODEL_DIR;
use serde::Serialize;

use crate::ui::plural;

pub const METRICS_JSON: &str = "metrics.json";
pub const REPORT_MD: &str = "report.md";
pub const CONFUSION_PNG: &str = "confusion.png";

/// `metrics.json`.
#[derive(Debug, Serialize)]
pub struct EvalReport {
    /// The model folder, or `shipped` for the model shipped in the binary.
    pub model: PathBuf,
    /// No `--model`: the shipped model.
    #[serde(skip)]
    pub shipped: bool,
    pub datasets: Vec<PathBuf>,
    pub split: String,
    pub size: u32,
    /// Multi-scale test (`--extra-sizes`): further short sides averaged with `size`'s.
    pub extra_sizes: Vec<u32>,
    /// Test-time flip (`--flip`): each image's prediction averaged with its mirror image's.
    pub flip: bool,
    pub images: usize,
    #[serde(flatten)]
    pub overall: MetricsSummary,
    /// 95 % intervals of `miou` and `per_class_iou` over images (`ci95_rule`).
    pub ci95: IouIntervals,
    pub per_dataset: BTreeMap<String, DatasetFigures>,
    pub classes: Vec<String>,
    /// Rows: true class; columns: predicted class; pixels.
    pub confusion_matrix: Vec<Vec<u64>>,
    pub rule: &'static str,
    pub ci95_rule: String,
}

/// One dataset's figures in `metrics.json`.
#[derive(Debug, Serialize)]
pub struct DatasetFigures {
    #[serde(flatten)]
    pub figures: MetricsSummary,
    pub ci95: IouIntervals,
}

pub(super) fn markdown(r: &EvalReport, m: &ConfusionMatrix) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Segmenter evaluation\n");
    let _ = writeln!(
        s,
        "{}, {} of the `{}` split of {}, short side {} px{}{}.\n",
        if r.shipped {
            format!("The shipped model (`{SHIPPED_MODEL_DIR}`)")
        } else {
            format!("Model `{}`", r.model.display())
        },
        plural(r.images, "image"),
        r.split,
        r.datasets
            .iter()
            .map(|d| format!("`{}`", d.display()))
            .collect::<Vec<_>>()
            .join(", "),
        r.size,
        if r.extra_sizes.is_empty() {
            String::new()
        } else {
            let sizes: Vec<String> = r.extra_sizes.iter().map(u32::to_string).collect();
            format!(", averaged with {} px (--extra-sizes)", sizes.join(", "))
        },
        if r.flip {
            ", each averaged with its mirror image (--flip)"
        } else {
            ""
        }
    );
    let _ = writeln!(
        s,
        "| figure | value [95 % interval] |\n| --- | ---: |\n| mIoU | {} |",
        with_interval(r.overall.miou, Some(r.ci95.miou))
    );
    for (name, v) in [
        ("pixel accuracy", r.overall.pixel_accuracy),
        ("mean accuracy", r.overall.mean_accuracy),
        ("frequency-weighted IoU", r.overall.frequency_weighted_iou),
    ] {
        let _ = writeln!(s, "| {name} | {v:.4} |");
    }
    let _ = writeln!(
        s,
        "\n## IoU per class\n\n| class | IoU [95 % interval] |{} \n| --- | ---: |{}",
        r.per_dataset
            .keys()
            .map(|k| format!(" {k} |"))
            .collect::<String>(),
        " ---: |".repeat(r.per_dataset.len())
    );
    for c in &r.classes {
        let cell = |m: &MetricsSummary, ci: &IouIntervals| {
            m.per_class_iou.get(c).map_or("–".to_owned(), |&v| {
                with_interval(v, ci.per_class_iou.get(c).copied())
            })
        };
        let _ = writeln!(
            s,
            "| {c} | {} |{}",
            cell(&r.overall, &r.ci95),
            r.per_dataset
                .values()
                .map(|d| format!(" {} |", cell(&d.figures, &d.ci95)))
                .collect::<String>()
        );
    }
    let _ = writeln!(
        s,
        "\n## Confusion matrix (rows: truth, columns: prediction; share of the row)\n"
    );
    let _ = writeln!(
        s,
        "| truth \\ prediction |{}\n| --- |{}",
        r.classes
            .iter()
            .map(|c| format!(" {c} |"))
            .collect::<String>(),
        " ---: |".repeat(r.classes.len())
    );
    for (t, row) in m.rows().iter().enumerate() {
        let total: u64 = row.iter().sum();
        let cells: String = row
            .iter()
            .map(|&n| {
                if total == 0 {
                    " – |".to_owned()
                } else {
                    format!(" {:.1} % |", 100.0 * n as f64 / total as f64)
                }
            })
            .collect();
        let _ = writeln!(
            s,
            "| {} |{cells}",
            r.classes.get(t).map_or("?", String::as_str)
        );
    }
    let _ = writeln!(
        s,
        "\n{}\n\nIntervals in brackets: {}.\n\n`{CONFUSION_PNG}`: the same matrix as a picture, each cell's share of its row written in it and shaded darker for a larger share; the diagonal (correct pixels) is outlined, each row's pixel count is on the right.",
        r.rule, r.ci95_rule
    );
    s
}

/// `0.7123 [0.6900, 0.7300]`: a figure and its 95 % interval.
pub(super) fn with_interval(value: f64, interval: Option<(f64, f64)>) -> String {
    match interval {
        Some((lo, hi)) => format!("{value:.4} [{lo:.4}, {hi:.4}]"),
        None => format!("{value:.4}"),
    }
}
