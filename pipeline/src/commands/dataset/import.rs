//! `pipeline dataset import`: a public label set into our classes through a class map.

use std::path::PathBuf;

use anyhow::Result;
use clap::ValueEnum;
use datasets::import::{
    ClassMap, ImportOptions, ImportReport, LayoutOptions, SourceFormat, import_with_progress,
    list_pairs,
};

use super::{DATASET_MARKERS, DatasetOutputArgs, OnErrorArg, record_samples, report_skipped};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::AtomicDir;

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FormatArg {
    /// SegNet's CamVid (`<split>.txt` lists, 12-index label PNGs).
    Camvid,
    /// Cityscapes `leftImg8bit/` + `gtFine/` (labelIds, or trainIds with --cityscapes-ids).
    Cityscapes,
    /// Mapillary Vistas `<split>/images` + `<split>/v1.2|v2.0/labels` (label indices).
    Mapillary,
    /// CARLA semantic renders (tag in red) in --images / --labels; needs --carla-version.
    Carla,
    /// Binary lane masks (TuSimple-style) in --images / --labels: lane pixels only.
    LaneMasks,
    /// Plain image / label folders matched by file name; labels in our ids unless
    /// --class-map says otherwise.
    Folders,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CityscapesIds {
    /// `*_gtFine_labelIds.png` (34 classes).
    LabelIds,
    /// `*_gtFine_labelTrainIds.png` (19 classes + 255).
    TrainIds,
}

#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    /// What kind of source it is.
    #[arg(value_enum)]
    pub format: FormatArg,

    /// The source folder (for carla, lane-masks and folders: the folder holding `images/`
    /// and `labels/`, unless --images and --labels say otherwise).
    pub source: PathBuf,

    /// Output dataset folder (written atomically).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Splits to import, comma-separated [default: every split the source has].
    #[arg(long, value_delimiter = ',', value_name = "NAME")]
    pub split: Vec<String>,

    /// Class map: a built-in name (camvid, cityscapes_labelids, cityscapes_trainids,
    /// mapillary_v1.2, mapillary_v2.0, carla_pre_0.9.14, carla_0.9.14, lane_mask, ids) or a
    /// TOML file [default: the format's].
    #[arg(long, value_name = "NAME|FILE")]
    pub class_map: Option<String>,

    /// Image folder (carla, lane-masks, folders).
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,

    /// Label folder (carla, lane-masks, folders).
    #[arg(long, value_name = "DIR")]
    pub labels: Option<PathBuf>,

    /// Which Cityscapes label files to read.
    #[arg(long, value_enum, default_value = "label-ids")]
    pub cityscapes_ids: CityscapesIds,

    /// Mapillary Vistas label version: 1.2 or 2.0.
    #[arg(long, value_name = "VERSION", default_value = "1.2")]
    pub mapillary_version: String,

    /// CARLA version that rendered the labels, e.g. 0.9.13 or 0.9.15 (tags changed in 0.9.14).
    #[arg(long, value_name = "VERSION")]
    pub carla_version: Option<String>,

    /// A label config JSON (Mapillary's config_v*.json) to check the class map against
    /// [default for mapillary: <source>/config_v<version>.json when present].
    #[arg(long, value_name = "FILE")]
    pub source_config: Option<PathBuf>,

    /// Binary lane masks `<DIR>/<id>.png` merged onto the road pixels as lane marking.
    #[arg(long, value_name = "DIR")]
    pub lane_masks: Option<PathBuf>,

    #[command(flatten)]
    pub output: DatasetOutputArgs,
}

/// `0.9.13` < `0.9.14`: compares dotted numbers.
fn carla_is_new(version: &str) -> Result<bool, String> {
    let parts: Vec<u32> = version
        .trim_start_matches('v')
        .split('.')
        .map(|p| {
            p.parse::<u32>()
                .map_err(|_| format!("`{version}` is not a version like 0.9.13"))
        })
        .collect::<Result<_, _>>()?;
    Ok(parts.as_slice() >= [0, 9, 14].as_slice())
}

/// The class map, layout variant and layout kind a format implies.
fn resolve(args: &ImportArgs) -> Result<(ClassMap, SourceFormat, Option<String>, Option<PathBuf>)> {
    let bad = |what: &str, m: String| {
        CliError::new(
            format!("{what}: {m}"),
            "see `pipeline dataset import --help`",
        )
    };
    let (default_map, layout, variant) = match args.format {
        FormatArg::Camvid => ("camvid".to_owned(), SourceFormat::Camvid, None),
        FormatArg::Cityscapes => match args.cityscapes_ids {
            CityscapesIds::LabelIds => (
                "cityscapes_labelids".to_owned(),
                SourceFormat::Cityscapes,
                Some("labelIds"),
            ),
            CityscapesIds::TrainIds => (
                "cityscapes_trainids".to_owned(),
                SourceFormat::Cityscapes,
                Some("labelTrainIds"),
            ),
        },
        FormatArg::Mapillary => {
            let v = args.mapillary_version.trim_start_matches('v');
            if v != "1.2" && v != "2.0" {
                return Err(bad(
                    "--mapillary-version",
                    format!("expected 1.2 or 2.0, not `{v}`"),
                )
                .into());
            }
            (format!("mapillary_v{v}"), SourceFormat::Mapillary, None)
        }
        FormatArg::Carla => {
            let version = args.carla_version.as_deref().ok_or_else(|| {
                bad(
                    "--carla-version",
                    "carla needs the version that rendered the labels (tags changed in 0.9.14)"
                        .into(),
                )
            })?;
            let map = if carla_is_new(version).map_err(|m| bad("--carla-version", m))? {
                "carla_0.9.14"
            } else {
                "carla_pre_0.9.14"
            };
            (map.to_owned(), SourceFormat::Folders, None)
        }
        FormatArg::LaneMasks => ("lane_mask".to_owned(), SourceFormat::Folders, None),
        FormatArg::Folders => ("ids".to_owned(), SourceFormat::Folders, None),
    };
    let spec = args.class_map.clone().unwrap_or(default_map);
    let class_map = ClassMap::load(&spec).map_err(|e| {
        CliError::new(e.to_string(), "give a built-in class map name or a readable class-map TOML file (see docs/datasets.md)")
    })?;
    let variant = match args.format {
        FormatArg::Mapillary => Some(format!(
            "v{}",
            args.mapillary_version.trim_start_matches('v')
        )),
        _ => variant.map(str::to_owned),
    };
    let source_config = match (&args.source_config, args.format) {
        (Some(p), _) => Some(p.clone()),
        (None, FormatArg::Mapillary) => {
            let p = args.source.join(format!(
                "config_{}.json",
                variant.as_deref().unwrap_or("v1.2")
            ));
            p.is_file().then_some(p)
        }
        _ => None,
    };
    Ok((class_map, layout, variant, source_config))
}

/// What to give when the source is not in the format's layout.
fn layout_hint(format: FormatArg) -> &'static str {
    match format {
        FormatArg::Camvid => {
            "give SegNet's CamVid folder (train.txt, val.txt, test.txt and the folders they list); docs/datasets.md shows each layout"
        }
        FormatArg::Cityscapes => {
            "give the Cityscapes folder holding leftImg8bit/ and gtFine/; docs/datasets.md shows each layout"
        }
        FormatArg::Mapillary => {
            "give the Mapillary Vistas folder holding <split>/images and <split>/v1.2 (or v2.0)/labels; docs/datasets.md shows each layout"
        }
        FormatArg::Carla | FormatArg::LaneMasks | FormatArg::Folders => {
            "give the folder holding images/ and labels/, or name them with --images and --labels; docs/datasets.md shows each layout"
        }
    }
}

pub fn run(ctx: &Context<'_>, args: &ImportArgs) -> Result<()> {
    let (class_map, format, variant, source_config) = resolve(args)?;
    let layout = LayoutOptions {
        root: args.source.clone(),
        splits: args.split.clone(),
        images: args.images.clone(),
        labels: args.labels.clone(),
        variant,
    };
    // A source that is missing or not in the format's layout fails before anything is
    // written, with a hint about the layout (--on-error is about broken items only).
    let pairs = list_pairs(format, &layout)
        .map_err(|e| CliError::new(e.to_string(), layout_hint(args.format)))?;
    let dest = ctx.output_path(&args.out);
    let dir = AtomicDir::create(&dest, DATASET_MARKERS)?;
    let mut progress = ctx.ui.progress("dataset import");
    progress.note(&format!(
        "importing {} with class map {}",
        args.source.display(),
        class_map.name
    ));
    progress.counted("importing", pairs.len() as u64, "items");
    let opts = ImportOptions {
        name: args.output.dataset_name(&dest),
        format,
        layout,
        class_map,
        source_config,
        lane_masks: args.lane_masks.clone(),
        on_error: args.output.on_error.into(),
    };
    let outcome = import_with_progress(&opts, dir.path(), &|| progress.inc(1)).map_err(|e| {
        let hint = match args.output.on_error {
            OnErrorArg::Fail => {
                "fix or remove that file, or pass --on-error skip to leave broken items out (they are counted)"
            }
            OnErrorArg::Skip => {
                "check the class map (--class-map) and the source's files: `--on-error fail` stops at the first broken item with its error"
            }
        };
        CliError::new(e.to_string(), hint)
    })?;
    progress.step("logging samples");
    record_samples(
        ctx,
        dir.path(),
        &outcome.items,
        args.output.log_samples,
        "import",
    )?;
    drop(progress);
    report_skipped(ctx, &outcome.report.skipped);
    let out = dir.commit()?;
    ctx.ui.result(&summary(&outcome.report));
    ctx.ui.info(&format!("wrote {}", out.display()));
    Ok(())
}

/// The report as a short table.
fn summary(r: &ImportReport) -> String {
    let mut text = format!(
        "{} ({} skipped), class map {}, {} pixels\nclass          % of all  % labelled\n",
        crate::ui::plural(r.items, "item"),
        r.skipped.len(),
        r.class_map,
        r.pixels
    );
    for c in &r.target_classes {
        let labelled = c
            .percent_of_labelled
            .map_or("-".to_owned(), |p| format!("{p:.2}"));
        text.push_str(&format!(
            "{:<14} {:>8.2}  {:>10}\n",
            c.name, c.percent_of_all, labelled
        ));
    }
    if r.unmapped_source_classes.is_empty() {
        text.push_str("unmapped source classes: none\n");
    } else {
        let list: Vec<String> = r
            .unmapped_source_classes
            .iter()
            .map(|c| format!("{} ({:.2} %)", c.name, c.percent_of_all))
            .collect();
        text.push_str(&format!(
            "unmapped source classes (-> ignore): {}\n",
            list.join(", ")
        ));
    }
    text.push_str(&format!("labelable: {}\n", r.labelable.join(", ")));
    text
}
