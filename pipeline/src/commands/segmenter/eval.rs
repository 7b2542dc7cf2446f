//! `pipeline segmenter eval`: metrics.json, report.md and confusion.png.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, ValueEnum};
use models::segmenter::data::{Source, SourceSpec, Split};
use models::segmenter::eval::{Evaluation, class_names, evaluate};
use models::segmenter::metrics::{
    BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, IouIntervals, bootstrap_iou,
};
use models::segmenter::shipped::SHIPPED_MODEL_DIR;
use models::segmenter::{ConfusionMatrix, MetricsSummary};
use serde::Serialize;

use super::{
    Context, ModelArgs, inference, open_sources, parse_source, segmenter_error, with_threads,
};
use crate::output::{AtomicDir, Markers, write_file_atomic};
use crate::plots::confusion_png;
use crate::ui::plural;

pub const METRICS_JSON: &str = "metrics.json";
pub const REPORT_MD: &str = "report.md";
pub const CONFUSION_PNG: &str = "confusion.png";
const EVAL_MARKERS: Markers = &[METRICS_JSON];

#[derive(Debug, Args)]
pub struct EvalArgs {
    #[command(flatten)]
    pub model: ModelArgs,

    /// Dataset to evaluate on; repeat for several (each also gets its own figures).
    #[arg(long = "data", value_name = "DIR", required = true, value_parser = parse_source)]
    pub data: Vec<SourceSpec>,

    /// Which items of the datasets.
    #[arg(long, value_enum, default_value = "val")]
    pub split: SplitArg,

    /// At most this many images per dataset [default: all].
    #[arg(long, value_name = "N")]
    pub limit: Option<usize>,

    /// Resamples of the images drawn for the 95 % intervals of mIoU and the IoUs.
    #[arg(long, value_name = "N", default_value_t = BOOTSTRAP_RESAMPLES, value_parser = resamples)]
    pub resamples: usize,

    /// Output folder (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Threads [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SplitArg {
    /// The `train` split (every item of a dataset without splits).
    Train,
    /// The `val` split.
    Val,
    /// The `test` split (`dataset split --test` or `--test-group`; `dataset import camvid` of a
    /// copy with a test/ folder).
    Test,
    /// Every item.
    All,
}

fn resamples(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(n) if n > 0 => Ok(n),
        _ => Err("give a whole number of resamples above 0 (1000 is usual)".to_owned()),
    }
}

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

/// The problem and the hint for a dataset with no item in the `split` asked for: what
/// splits it has, and how to choose one or make the one asked for.
fn empty_split_message(source: &Source, split: SplitArg) -> (String, String) {
    let name = format!("{split:?}").to_lowercase();
    let items = &source.dataset.items;
    if items.is_empty() {
        return (
            "has no items".into(),
            "give a dataset with items (`pipeline dataset generate | import`)".into(),
        );
    }
    let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
    for item in items {
        *counts
            .entry(item.split.as_deref().unwrap_or("none"))
            .or_default() += 1;
    }
    let held: Vec<String> = counts.iter().map(|(s, n)| format!("{s} {n}")).collect();
    let choices: Vec<&str> = counts
        .keys()
        .copied()
        .filter(|s| *s != "none")
        .chain(["all"])
        .collect();
    (
        format!(
            "has no items in the {name} split (its items: {})",
            held.join(", ")
        ),
        format!(
            "choose a split it has with --split {}, or make a {name} split with `pipeline dataset split {} --{name} 0.2` \
             (or --group-by prefix --{name}-group GROUP for whole sequences; docs/datasets.md)",
            choices.join("|"),
            source.root().display()
        ),
    )
}

pub fn run(ctx: &Context<'_>, args: &EvalArgs) -> Result<()> {
    let out_path = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out_path, EVAL_MARKERS)?;
    let size = args.model.size("eval")?;
    let device = ctx.device()?;
    let (model, config) = args.model.open(&device)?;
    let split = match args.split {
        SplitArg::Train => Split::Train,
        SplitArg::Val => Split::Val,
        SplitArg::Test => Split::Test,
        SplitArg::All => Split::All,
    };
    let sources = open_sources(&args.data, split)?;
    if let Some(empty) = sources.iter().find(|s| s.items.is_empty()) {
        let (problem, hint) = empty_split_message(empty, args.split);
        return Err(crate::error::CliError::file(empty.root(), problem, hint).into());
    }
    let mut progress = ctx.ui.progress("segmenter eval");
    // The images predicted: each dataset's, up to --limit.
    let images: usize = sources
        .iter()
        .map(|s| args.limit.map_or(s.items.len(), |l| l.min(s.items.len())))
        .sum();
    progress.counted("predicting", images as u64, "images");
    let evaluation = with_threads(args.threads, || {
        evaluate(
            &model,
            &config,
            &sources,
            &inference(size, &args.model),
            args.limit,
            &device,
            |done, _, _| progress.set_position(done as u64),
        )
    })?
    .map_err(|e| segmenter_error(e, "check the dataset"))?;
    progress.step("writing the report");

    let classes = class_names(config.classes);
    let report = eval_report(args, size, &evaluation, &classes, split_name(args.split));
    let dir = AtomicDir::create(&out_path, EVAL_MARKERS)?;
    let json = serde_json::to_string_pretty(&report)? + "\n";
    write_file_atomic(&dir.path().join(METRICS_JSON), json.as_bytes())?;
    write_file_atomic(
        &dir.path().join(REPORT_MD),
        markdown(&report, &evaluation.overall).as_bytes(),
    )?;
    let png = confusion_png(
        &format!(
            "Confusion matrix: {} of the {} split",
            plural(report.images, "image"),
            report.split
        ),
        &classes,
        &evaluation.overall.rows(),
    )?;
    write_file_atomic(&dir.path().join(CONFUSION_PNG), &png)?;
    let dest = dir.commit()?;
    drop(progress);
    ctx.ui.result(&format!(
        "mIoU {}, pixel accuracy {:.4} on {}; {}",
        with_interval(report.overall.miou, Some(report.ci95.miou)),
        report.overall.pixel_accuracy,
        plural(report.images, "image"),
        dest.display()
    ));
    Ok(())
}

fn split_name(split: SplitArg) -> String {
    match split {
        SplitArg::Train => "train",
        SplitArg::Val => "val",
        SplitArg::Test => "test",
        SplitArg::All => "all",
    }
    .to_owned()
}

fn eval_report(
    args: &EvalArgs,
    size: u32,
    e: &Evaluation,
    classes: &[String],
    split: String,
) -> EvalReport {
    let names: Vec<&str> = classes.iter().map(String::as_str).collect();
    let ci95 = |source| {
        bootstrap_iou(
            &e.image_matrices(source),
            &names,
            args.resamples,
            BOOTSTRAP_SEED,
        )
    };
    EvalReport {
        model: args.model.name(),
        shipped: args.model.model.is_none(),
        datasets: args.data.iter().map(|d| d.path.clone()).collect(),
        split,
        size,
        extra_sizes: args.model.extra_sizes.clone(),
        flip: args.model.flip,
        images: e.images,
        overall: e.overall.summary(&names),
        ci95: ci95(None),
        per_dataset: e
            .per_source
            .iter()
            .enumerate()
            .map(|(i, (n, m))| {
                let figures = DatasetFigures {
                    figures: m.summary(&names),
                    ci95: ci95(Some(i)),
                };
                (n.clone(), figures)
            })
            .collect(),
        classes: classes.to_vec(),
        confusion_matrix: e.overall.rows(),
        rule: "mIoU and mean accuracy average over the classes present in the ground truth; \
               a prediction of a class a dataset cannot label (its card) counts as the pixel's label",
        ci95_rule: format!(
            "95 % percentile bootstrap over images: {} resamples of the images with \
             replacement (ChaCha8, seed {BOOTSTRAP_SEED}), their confusion matrices summed; \
             a class absent from a resample's ground truth is skipped for that resample",
            args.resamples
        ),
    }
}

fn markdown(r: &EvalReport, m: &ConfusionMatrix) -> String {
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
fn with_interval(value: f64, interval: Option<(f64, f64)>) -> String {
    match interval {
        Some((lo, hi)) => format!("{value:.4} [{lo:.4}, {hi:.4}]"),
        None => format!("{value:.4}"),
    }
}
