//! `pipeline segmenter predict`: an image or a folder of images to label PNGs (class ids)
//! and overlays.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use datasets::image_io::{encode_label_png, encode_rgb_png, overlay_label, read_rgb};
use models::segmenter::infer::predict_label;

use super::{Context, ModelArgs, inference, with_threads};
use crate::args::OnErrorArg;
use crate::error::CliError;
use crate::output::{AtomicDir, Markers, write_file_atomic};
use crate::ui::plural;

pub const LABELS_DIR: &str = "labels";
pub const OVERLAYS_DIR: &str = "overlays";
const PREDICT_MARKERS: Markers = &[LABELS_DIR];

/// Share of the class colour in an overlay.
const OVERLAY_ALPHA: f32 = 0.5;

#[derive(Debug, Args)]
pub struct PredictArgs {
    #[command(flatten)]
    pub model: ModelArgs,

    /// An image (PNG or JPEG), or a folder of them (not recursive).
    pub input: PathBuf,

    /// Output folder: labels/<name>.png (class ids 0-4) and overlays/<name>.png (written
    /// atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// What to do with an image that cannot be read: stop with its error (nothing is
    /// written), or leave it out, counted and named in warnings (as `dataset import`).
    #[arg(long, value_enum, default_value = "fail")]
    pub on_error: OnErrorArg,

    /// Threads [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
}

/// The images to label: the file, or the folder's PNG / JPEG files sorted by name.
fn inputs(input: &Path) -> Result<Vec<PathBuf>> {
    if input.is_file() {
        return Ok(vec![input.to_path_buf()]);
    }
    let entries = std::fs::read_dir(input).map_err(|e| {
        CliError::file(
            input,
            format!("cannot read: {e}"),
            "give an image file or a folder of images",
        )
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                    matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg")
                })
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(CliError::file(
            input,
            "holds no PNG or JPEG images",
            "give an image file or a folder of images",
        )
        .into());
    }
    Ok(files)
}

pub fn run(ctx: &Context<'_>, args: &PredictArgs) -> Result<()> {
    let out_path = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out_path, PREDICT_MARKERS)?;
    let size = args.model.size("predict")?;
    let files = inputs(&args.input)?;
    let device = ctx.device()?;
    let (model, config) = args.model.open(&device)?;
    let inference = inference(size, &args.model);
    let dir = AtomicDir::create(&out_path, PREDICT_MARKERS)?;
    for sub in [LABELS_DIR, OVERLAYS_DIR] {
        std::fs::create_dir_all(dir.path().join(sub))?;
    }
    let mut progress = ctx.ui.progress("segmenter predict");
    progress.counted("labelling", files.len() as u64, "images");
    let mut skipped = Vec::new();
    let mut names = std::collections::BTreeSet::new();
    for (done, file) in files.iter().enumerate() {
        progress.set_position(done as u64);
        let image = match read_rgb(file) {
            Ok(image) => image,
            Err(e) if args.on_error == OnErrorArg::Skip => {
                skipped.push(e.to_string());
                continue;
            }
            Err(e) => {
                let hint = if files.len() > 1 {
                    "give a PNG or JPEG image, or pass --on-error skip to label the others (the skipped ones are counted)"
                } else {
                    "give a PNG or JPEG image"
                };
                return Err(CliError::new(e.to_string(), hint).into());
            }
        };
        let stem = file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if !names.insert(stem.clone()) {
            return Err(CliError::file(
                file,
                format!("a second image named `{stem}`"),
                "rename one of them",
            )
            .into());
        }
        let label = with_threads(args.threads, || {
            predict_label(&model, &config, &image, &inference, &device)
        })?;
        let name = format!("{stem}.png");
        write_file_atomic(
            &dir.path().join(LABELS_DIR).join(&name),
            &encode_label_png(&label),
        )?;
        let overlay = overlay_label(&image, &label, OVERLAY_ALPHA);
        write_file_atomic(
            &dir.path().join(OVERLAYS_DIR).join(&name),
            &encode_rgb_png(&overlay),
        )?;
    }
    progress.set_position(files.len() as u64);
    if skipped.len() == files.len() {
        return Err(CliError::file(
            &args.input,
            "none of its images could be read",
            "give PNG or JPEG images",
        )
        .into());
    }
    let dest = dir.commit()?;
    drop(progress);
    if !skipped.is_empty() {
        ctx.ui.warn(&format!(
            "skipped {} (--on-error skip)",
            plural(skipped.len(), "unreadable image")
        ));
        for reason in skipped.iter().take(10) {
            ctx.ui.warn(&format!("  {reason}"));
        }
    }
    ctx.ui.result(&format!(
        "{} labelled{} in {}",
        plural(files.len() - skipped.len(), "image"),
        if skipped.is_empty() {
            String::new()
        } else {
            format!(", {} unreadable skipped", skipped.len())
        },
        dest.display()
    ));
    Ok(())
}
