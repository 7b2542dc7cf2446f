//! `pipeline segmenter recalibrate`: a run's model with its batch norms' running statistics
//! recomputed over training batches (`models::segmenter::recalibrate`).

use std::path::{Path, PathBuf};

use anyhow::Result;
use burn::module::Module;
use clap::{Args, ValueEnum};
use models::segmenter::data::{SourceSpec, Split};
use models::segmenter::files::{MODEL_RECORD_FILE, load_record, save_model};
use models::segmenter::recalibrate::recalibrate_batch_norms;
use models::segmenter::train::{BEST_DIR, CHECKPOINT_DIR, TRAIN_CONFIG_FILE};
use serde::Serialize;

use super::{
    Context, open_sources, parse_source, read_training_config, segmenter_error, with_threads,
};
use crate::error::CliError;
use crate::output::{AtomicDir, Markers, write_file_atomic};

const RECALIBRATION_JSON: &str = "recalibration.json";
const MARKERS: Markers = &[RECALIBRATION_JSON];

#[derive(Debug, Args)]
pub struct RecalibrateArgs {
    /// A training run folder: its train.json says how the crops are drawn.
    #[arg(long, value_name = "RUN")]
    pub run: PathBuf,

    /// Which of the run's models.
    #[arg(long, value_enum, default_value = "best")]
    pub from: WhichModel,

    /// Training dataset with its sampling weight, as given to `segmenter train`; repeat for
    /// several. Its `train` split is used.
    #[arg(long = "data", value_name = "DIR[:WEIGHT]", required = true, value_parser = parse_source)]
    pub data: Vec<SourceSpec>,

    /// Batches of the run's batch size whose statistics are averaged.
    #[arg(long, value_name = "N", default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..))]
    pub batches: u32,

    /// Output model folder (model.json, model.bpk, model.safetensors, and the run's
    /// train.json, so `segmenter eval` runs it at the trained size); written atomically.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Threads [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum WhichModel {
    /// The model of the best validation mIoU (best/).
    Best,
    /// The last epoch's (checkpoint/).
    Checkpoint,
}

/// `recalibration.json`: where the model came from and what it was recalibrated on.
#[derive(Debug, Serialize)]
struct RecalibrationReport<'a> {
    run: &'a Path,
    from: &'a str,
    datasets: Vec<&'a Path>,
    batches: u32,
    crops: usize,
}

pub fn run(ctx: &Context<'_>, args: &RecalibrateArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    let train_json = args.run.join(TRAIN_CONFIG_FILE);
    let config = read_training_config(&train_json)?;
    let (folder, from) = match args.from {
        WhichModel::Best => (BEST_DIR, "best"),
        WhichModel::Checkpoint => (CHECKPOINT_DIR, "checkpoint"),
    };
    let record = args.run.join(folder).join(MODEL_RECORD_FILE);
    let sources = open_sources(&args.data, Split::Train)?;
    let device = ctx.device()?;
    let mut progress = ctx.ui.progress("segmenter recalibrate");
    progress.step(&format!(
        "averaging the batch statistics of {} of {}",
        crate::ui::plural(args.batches as usize, "batch"),
        config.batch_size
    ));
    let (model, crops) = with_threads(args.threads, || {
        let training = device.clone().autodiff();
        let model = load_record(&record, config.model.init(&training)?)?;
        recalibrate_batch_norms(
            model,
            &config,
            &sources,
            args.batches as usize,
            0,
            &training,
        )
    })?
    .map_err(|e| segmenter_error(e, "give a run folder written by `pipeline segmenter train`"))?;
    let dir = AtomicDir::create(&out, MARKERS)?;
    save_model(dir.path(), &model.valid(), &config.model)
        .map_err(|e| segmenter_error(e, "check the --out folder"))?;
    let copy = std::fs::read(&train_json)
        .map_err(|e| CliError::file(&train_json, format!("cannot read: {e}"), "check the run"))?;
    write_file_atomic(&dir.path().join(TRAIN_CONFIG_FILE), &copy)?;
    let report = RecalibrationReport {
        run: &args.run,
        from,
        datasets: args.data.iter().map(|s| s.path.as_path()).collect(),
        batches: args.batches,
        crops,
    };
    let json = serde_json::to_string_pretty(&report)? + "\n";
    write_file_atomic(&dir.path().join(RECALIBRATION_JSON), json.as_bytes())?;
    let dest = dir.commit()?;
    drop(progress);
    ctx.ui.result(&format!(
        "batch norms recalibrated on {}; model in {}",
        crate::ui::plural(crops, "crop"),
        dest.display()
    ));
    Ok(())
}
