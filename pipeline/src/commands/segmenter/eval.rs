//! `pipeline segmenter eval`: metrics.json, report.md and confusion.png.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, ValueEnum};
use models::segmenter::data::{SourceSpec, Split};
use models::segmenter::eval::{Evaluation, class_names, evaluate};
use models::segmenter::{ConfusionMatrix, MetricsSummary};
use serde::Serialize;

use super::{
    Context, ModelArgs, inference, model_dir, open_model, open_sources, parse_source,
    segmenter_error, with_threads,
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

    /// Output folder (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Threads [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SplitArg {
    Train,
    Val,
    All,
}

/// `metrics.json`.
#[derive(Debug, Serialize)]
pub struct EvalReport {
    pub model: PathBuf,
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
    pub per_dataset: BTreeMap<String, MetricsSummary>,
    pub classes: Vec<String>,
    /// Rows: true class; columns: predicted class; pixels.
    pub confusion_matrix: Vec<Vec<u64>>,
    pub rule: &'static str,
}

pub fn run(ctx: &Context<'_>, args: &EvalArgs) -> Result<()> {
    let out_path = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out_path, EVAL_MARKERS)?;
    let size = args.model.size("eval")?;
    let device = ctx.device()?;
    let (model, config) = open_model(&args.model.model, &device)?;
    let split = match args.split {
        SplitArg::Train => Split::Train,
        SplitArg::Val => Split::Val,
        SplitArg::All => Split::All,
    };
    let sources = open_sources(&args.data, split)?;
    if let Some(empty) = sources.iter().find(|s| s.items.is_empty()) {
        return Err(crate::error::CliError::file(
            empty.root(),
            format!("has no items in the {:?} split", args.split).to_lowercase(),
            "use --split all, or split it with `pipeline dataset split`",
        )
        .into());
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
        "mIoU {:.4}, pixel accuracy {:.4} on {}; {}",
        report.overall.miou,
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
    EvalReport {
        model: model_dir(&args.model.model),
        datasets: args.data.iter().map(|d| d.path.clone()).collect(),
        split,
        size,
        extra_sizes: args.model.extra_sizes.clone(),
        flip: args.model.flip,
        images: e.images,
        overall: e.overall.summary(&names),
        per_dataset: e
            .per_source
            .iter()
            .map(|(n, m)| (n.clone(), m.summary(&names)))
            .collect(),
        classes: classes.to_vec(),
        confusion_matrix: e.overall.rows(),
        rule: "mIoU and mean accuracy average over the classes present in the ground truth; \
               a prediction of a class a dataset cannot label (its card) counts as the pixel's label",
    }
}

fn markdown(r: &EvalReport, m: &ConfusionMatrix) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Segmenter evaluation\n");
    let _ = writeln!(
        s,
        "Model `{}`, {} of the `{}` split of {}, short side {} px{}{}.\n",
        r.model.display(),
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
    let _ = writeln!(s, "| figure | value |\n| --- | ---: |");
    for (name, v) in [
        ("mIoU", r.overall.miou),
        ("pixel accuracy", r.overall.pixel_accuracy),
        ("mean accuracy", r.overall.mean_accuracy),
        ("frequency-weighted IoU", r.overall.frequency_weighted_iou),
    ] {
        let _ = writeln!(s, "| {name} | {v:.4} |");
    }
    let _ = writeln!(
        s,
        "\n## IoU per class\n\n| class | IoU |{} \n| --- | ---: |{}",
        r.per_dataset
            .keys()
            .map(|k| format!(" {k} |"))
            .collect::<String>(),
        " ---: |".repeat(r.per_dataset.len())
    );
    for c in &r.classes {
        let cell = |m: &MetricsSummary| {
            m.per_class_iou
                .get(c)
                .map_or("–".to_owned(), |v| format!("{v:.4}"))
        };
        let _ = writeln!(
            s,
            "| {c} | {} |{}",
            cell(&r.overall),
            r.per_dataset
                .values()
                .map(|m| format!(" {} |", cell(m)))
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
        "\n{}\n\n`{CONFUSION_PNG}`: the same matrix as a picture, each cell's share of its row written in it and shaded darker for a larger share; the diagonal (correct pixels) is outlined, each row's pixel count is on the right.",
        r.rule
    );
    s
}
