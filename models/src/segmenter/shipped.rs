//! The segmenter shipped inside the binary, so `segmenter eval` and `segmenter predict` work
//! without a `--model`. Its files are those of `models/weights/segmenter/` (see the README
//! there for how it was trained), embedded at build time:
//!
//! ```text
//! model.json          PspNetConfig, as `save_model` writes it
//! model.safetensors   its tensors under PyTorch names, as `export_safetensors` writes them
//! train.json          the TrainingConfig of its run: the short side it was trained at
//! ```
//!
//! Replacing the files and rebuilding ships another model.

use std::path::Path;

use burn::tensor::Device;

use super::error::{Result, SegmenterError};
use super::files::{config_from_value, import_safetensors_bytes};
use super::model::{PspNet, PspNetConfig};
use super::train::{TrainingConfig, load_training_config_text};

/// What metrics and messages call the shipped model.
pub const SHIPPED_MODEL_NAME: &str = "shipped";

/// Where the embedded files come from, relative to the repository (named in errors).
pub const SHIPPED_MODEL_DIR: &str = "models/weights/segmenter";

const MODEL_JSON: &str = include_str!("../../weights/segmenter/model.json");
const MODEL_SAFETENSORS: &[u8] = include_bytes!("../../weights/segmenter/model.safetensors");
const TRAIN_JSON: &str = include_str!("../../weights/segmenter/train.json");

fn shipped_file(name: &str) -> std::path::PathBuf {
    Path::new(SHIPPED_MODEL_DIR).join(name)
}

/// The shipped model's config (its `model.json`).
pub fn shipped_config() -> Result<PspNetConfig> {
    let path = shipped_file("model.json");
    let value: serde_json::Value = serde_json::from_str(MODEL_JSON)
        .map_err(|e| SegmenterError::invalid(&path, format!("not JSON: {e}")))?;
    let config = config_from_value(value, &PspNetConfig::new())
        .map_err(|e| SegmenterError::invalid(&path, format!("not a segmenter config: {e}")))?;
    config
        .validate()
        .map_err(|e| SegmenterError::invalid(&path, e.to_string()))?;
    Ok(config)
}

/// The shipped model on `device`, with its config.
pub fn shipped_model(device: &Device) -> Result<(PspNet, PspNetConfig)> {
    let config = shipped_config()?;
    let model = import_safetensors_bytes(
        MODEL_SAFETENSORS,
        &shipped_file("model.safetensors"),
        config.init(device)?,
    )?;
    Ok((model, config))
}

/// The training config of the shipped model's run (its `train.json`).
pub fn shipped_training_config() -> Result<TrainingConfig> {
    load_training_config_text(TRAIN_JSON).map_err(|e| {
        SegmenterError::invalid(
            &shipped_file("train.json"),
            format!("not a training config: {e}"),
        )
    })
}

/// The short side, in pixels, the shipped model was trained at: the size to run it at.
pub fn shipped_short_side() -> Result<u32> {
    Ok(shipped_training_config()?.size)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segmenter::infer::{Inference, predict_label};
    use image::{Rgb, RgbImage};

    #[test]
    fn the_shipped_model_loads_and_labels_an_image() {
        let device = Device::flex();
        let (model, config) = shipped_model(&device).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(config.classes, datasets::classes::NUM_CLASSES);
        let training = shipped_training_config().unwrap_or_else(|e| panic!("{e}"));
        // The run's network is the one shipped.
        assert_eq!(training.model, config);
        let short = shipped_short_side().unwrap_or_else(|e| panic!("{e}"));
        assert!((16..=4096).contains(&short), "{short}");

        let image = RgbImage::from_fn(40, 24, |x, y| Rgb([(x * 6) as u8, (y * 10) as u8, 90]));
        let label = predict_label(
            &model,
            &config,
            &image,
            &Inference {
                short: Some(short),
                ..Inference::default()
            },
            &device,
        );
        assert_eq!(label.dimensions(), (40, 24));
        assert!(label.pixels().all(|p| usize::from(p[0]) < config.classes));
        // The embedded files are those of the folder, which `load_model` reads as well (it
        // has no burn record: from its safetensors).
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("weights/segmenter");
        let (from_folder, folder_config) =
            crate::segmenter::files::load_model(&dir, &device).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(folder_config, config);
        let again = predict_label(
            &from_folder,
            &folder_config,
            &image,
            &Inference {
                short: Some(short),
                ..Inference::default()
            },
            &device,
        );
        assert_eq!(again, label);
    }
}
