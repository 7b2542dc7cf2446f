//! `pipeline segmenter eval`: metrics.json, report.md and confusion.png.

use std::collections::BTreeMap;

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, ValueEnum};
use models::segmenter::data::{Source, SourceSpec, Split};
use models::segmenter::eval::{Evaluation, class_names, evaluate};
use models::segmenter::metrics::{BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, bootstrap_iou};

use super::eval_report::{DatasetFigures, EvalReport, markdown, with_interval};
use super::{
    Context, ModelArgs, inference, open_sources, parse_source, segmenter_error, with_threads,
};
use crate::output::{AtomicDir, Markers, write_file_atomic};
use crate::plots::confusion_png;
use crate::ui::plural;

pub use super::eval_report::{CONFUSION_PNG, METRICS_JSON, REPORT_MD};
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
