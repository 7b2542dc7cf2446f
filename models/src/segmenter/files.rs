//! Model files: a folder with the burn record, the config and a safetensors export.
//!
//! ```text
//! <model>/
//!   model.json           PspNetConfig (burn Config JSON)
//!   model.bpk            burn record (burnpack): parameters and batch-norm statistics
//!   model.safetensors    the same tensors under PyTorch names (BatchNorm weight / bias),
//!                        loadable by scripts/segmenter_reference.py's PspNet
//! ```
//!
//! A folder without `model.bpk` is read from its `model.safetensors` (the shipped model of
//! [`super::shipped`] is such a folder).

use std::path::Path;

use burn::config::Config;
use burn::module::Module;
use burn::store::{
    BurnToPyTorchAdapter, ModuleRecord, ModuleSnapshot, PyTorchToBurnAdapter, SafetensorsStore,
};
use burn::tensor::Device;

use super::error::{Result, SegmenterError};
use super::model::{PspNet, PspNetConfig};
use crate::run_folder::write_atomic;

pub const MODEL_CONFIG_FILE: &str = "model.json";
pub const MODEL_RECORD_FILE: &str = "model.bpk";
pub const MODEL_SAFETENSORS_FILE: &str = "model.safetensors";

/// Why a settings file could not be read ([`load_config`]); the caller names the file.
#[derive(Debug, thiserror::Error)]
pub enum ConfigFileError {
    #[error("{0}")]
    Read(#[from] std::io::Error),
    #[error("{0}")]
    Json(#[from] serde_json::Error),
    #[error("{0}")]
    Toml(String),
    #[error("unknown setting `{0}`")]
    UnknownSetting(String),
}

/// Reads a config file (`model.json`, `train.json`, or settings written as TOML) written by
/// this or an earlier version: keys the file lacks (settings added since it was written) take
/// their values from `defaults`, the value that reproduces the earlier behaviour. burn's
/// `Config::load` would reject such a file. A `.toml` file is read as TOML, whose keys must
/// all be settings (a typo is an error, not a silent default); anything else as JSON. Errors
/// are messages for the caller to attach the path to.
pub fn load_config<C>(path: &Path, defaults: &C) -> std::result::Result<C, ConfigFileError>
where
    C: serde::Serialize + serde::de::DeserializeOwned,
{
    let text = std::fs::read_to_string(path)?;
    let is_toml = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    if !is_toml {
        let file: serde_json::Value = serde_json::from_str(&text)?;
        return config_from_value(file, defaults);
    }
    let table: toml::Table =
        toml::from_str(&text).map_err(|e| ConfigFileError::Toml(e.message().to_owned()))?;
    let file = serde_json::to_value(table)?;
    let known = serde_json::to_value(defaults)?;
    if let Some(key) = unknown_key(&known, &file, "") {
        return Err(ConfigFileError::UnknownSetting(key));
    }
    config_from_value(file, defaults)
}

/// The first key of `file` (as a dotted path) that `known`, the serialised defaults, lacks,
/// looking into tables. Unset settings are in `known` too, as `null`.
fn unknown_key(
    known: &serde_json::Value,
    file: &serde_json::Value,
    prefix: &str,
) -> Option<String> {
    let (serde_json::Value::Object(known), serde_json::Value::Object(file)) = (known, file) else {
        return None;
    };
    file.iter().find_map(|(key, value)| match known.get(key) {
        None => Some(format!("{prefix}{key}")),
        Some(inner) => unknown_key(inner, value, &format!("{prefix}{key}.")),
    })
}

/// [`load_config`] on a parsed JSON value.
pub fn config_from_value<C>(
    value: serde_json::Value,
    defaults: &C,
) -> std::result::Result<C, ConfigFileError>
where
    C: serde::Serialize + serde::de::DeserializeOwned,
{
    let mut merged = serde_json::to_value(defaults)?;
    overlay(&mut merged, value);
    Ok(serde_json::from_value(merged)?)
}

/// Puts `top` over `base`: objects key by key (recursively), anything else replaced.
fn overlay(base: &mut serde_json::Value, top: serde_json::Value) {
    match (base, top) {
        (serde_json::Value::Object(base), serde_json::Value::Object(top)) => {
            for (key, value) in top {
                match base.get_mut(&key) {
                    Some(slot) => overlay(slot, value),
                    None => {
                        base.insert(key, value);
                    }
                }
            }
        }
        (base, top) => *base = top,
    }
}

/// Writes a model folder's three files (the folder must exist).
pub fn save_model(dir: &Path, model: &PspNet, config: &PspNetConfig) -> Result<()> {
    let config_path = dir.join(MODEL_CONFIG_FILE);
    write_atomic(&config_path, |tmp| {
        config.save(tmp).map_err(|e| SegmenterError::io(tmp, e))
    })?;
    save_record(&dir.join(MODEL_RECORD_FILE), model)?;
    export_safetensors(&dir.join(MODEL_SAFETENSORS_FILE), model)
}

/// Writes the burn record of `model`.
pub fn save_record<M: Module>(path: &Path, model: &M) -> Result<()> {
    write_atomic(path, |tmp| {
        model
            .clone()
            .into_record()
            .save(tmp)
            .map_err(|e| SegmenterError::invalid(tmp, format!("cannot write the record: {e}")))
    })
}

/// Loads a burn record into `model` (which must have the record's architecture).
pub fn load_record<M: Module>(path: &Path, model: M) -> Result<M> {
    let record = ModuleRecord::load(path)
        .map_err(|e| SegmenterError::invalid(path, format!("not a readable burn record: {e}")))?;
    model
        .try_load_record(record)
        .map_err(|e| SegmenterError::invalid(path, format!("does not fit the model's config: {e}")))
}

/// Reads a model folder (see the module docs) onto `device`: its burn record, else its
/// safetensors.
pub fn load_model(dir: &Path, device: &Device) -> Result<(PspNet, PspNetConfig)> {
    let config_path = dir.join(MODEL_CONFIG_FILE);
    if !config_path.is_file() {
        return Err(SegmenterError::invalid(
            dir,
            format!(
                "is not a model folder (no {MODEL_CONFIG_FILE}; `pipeline segmenter train` writes one)"
            ),
        ));
    }
    let config = load_config(&config_path, &PspNetConfig::new()).map_err(|e| {
        SegmenterError::invalid(&config_path, format!("not a segmenter config: {e}"))
    })?;
    config
        .validate()
        .map_err(|e| SegmenterError::invalid(&config_path, e.to_string()))?;
    let record = dir.join(MODEL_RECORD_FILE);
    let safetensors = dir.join(MODEL_SAFETENSORS_FILE);
    let model = if record.is_file() || !safetensors.is_file() {
        load_record(&record, config.init(device)?)?
    } else {
        import_safetensors(&safetensors, config.init(device)?)?
    };
    Ok((model, config))
}

/// Writes the model's tensors as safetensors under PyTorch names.
pub fn export_safetensors(path: &Path, model: &PspNet) -> Result<()> {
    write_atomic(path, |tmp| {
        // No metadata: burn keeps it in a hash map, whose order would change the bytes.
        let mut store = SafetensorsStore::from_file(tmp)
            .with_to_adapter(BurnToPyTorchAdapter)
            .clear_metadata();
        model
            .save_into(&mut store)
            .map_err(|e| SegmenterError::invalid(tmp, format!("cannot write safetensors: {e}")))
    })
}

/// Loads safetensors with PyTorch names (the export above, or
/// `scripts/segmenter_reference.py`'s weights) into `model`; every tensor must match.
pub fn import_safetensors(path: &Path, model: PspNet) -> Result<PspNet> {
    let store = SafetensorsStore::from_file(path);
    load_safetensors(store, model).map_err(|e| SegmenterError::invalid(path, e))
}

/// [`import_safetensors`] from the bytes of a safetensors file; errors name `what` (the
/// file the bytes came from).
pub fn import_safetensors_bytes(bytes: &[u8], what: &Path, model: PspNet) -> Result<PspNet> {
    let store = SafetensorsStore::from_bytes(Some(bytes.to_vec()));
    load_safetensors(store, model).map_err(|e| SegmenterError::invalid(what, e))
}

fn load_safetensors(
    store: SafetensorsStore,
    mut model: PspNet,
) -> std::result::Result<PspNet, String> {
    let mut store = store.with_from_adapter(PyTorchToBurnAdapter);
    let result = model
        .load_from(&mut store)
        .map_err(|e| format!("cannot load safetensors: {e}"))?;
    if !result.errors.is_empty() || !result.missing.is_empty() || !result.unused.is_empty() {
        return Err(format!(
            "does not fit the model: missing {:?}, unused {:?}, errors {:?}",
            result.missing.iter().map(|m| &m.0).collect::<Vec<_>>(),
            result.unused,
            result.errors
        ));
    }
    Ok(model)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Tensor;

    #[test]
    fn a_folder_without_a_record_is_read_from_its_safetensors() {
        let tmp = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let device = Device::flex();
        let config = crate::segmenter::model::tiny_test_config();
        let model = config
            .init_seeded(&device, 3)
            .unwrap_or_else(|e| panic!("{e}"));
        save_model(tmp.path(), &model, &config).unwrap_or_else(|e| panic!("{e}"));
        std::fs::remove_file(tmp.path().join(MODEL_RECORD_FILE)).unwrap_or_else(|e| panic!("{e}"));
        let (loaded, loaded_config) =
            load_model(tmp.path(), &device).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(loaded_config, config);
        let input = || Tensor::<4>::ones([1, 3, 32, 32], &device);
        let output = |m: &PspNet| {
            m.forward(input())
                .into_data()
                .try_to_vec::<f32>()
                .unwrap_or_else(|e| panic!("{e:?}"))
        };
        assert_eq!(output(&loaded), output(&model));
        // Neither file: the error names the record.
        std::fs::remove_file(tmp.path().join(MODEL_SAFETENSORS_FILE))
            .unwrap_or_else(|e| panic!("{e}"));
        let err = load_model(tmp.path(), &device).err().map(|e| e.to_string());
        assert!(
            err.as_deref()
                .is_some_and(|e| e.contains(MODEL_RECORD_FILE)),
            "{err:?}"
        );
    }
}
