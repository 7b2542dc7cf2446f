//! What makes a stage of `pipeline run` rerun: the settings that shape its outputs and the
//! files outside the run folder it reads (with the outputs of the stages it needs, its key).

use std::path::PathBuf;

use anyhow::Result;

use super::stage_env::StageEnv;
use super::stages::StageName;
use crate::error::CliError;

impl StageEnv<'_> {
    /// The settings that shape this stage's outputs (part of its key).
    pub fn settings(&self, stage: StageName) -> Result<serde_json::Value> {
        let p = self.profile;
        let seed = self.ctx.global.seed;
        let version = env!("CARGO_PKG_VERSION");
        Ok(match stage {
            StageName::Maps => serde_json::json!({
                "version": version,
                "import": serde_json::to_value(&self.ctx.config.map.import)?,
            }),
            StageName::Dataset => serde_json::json!({
                "version": version, "seed": seed,
                "images": p.dataset.images, "size": p.dataset.size,
            }),
            StageName::Augment => serde_json::json!({
                "version": version, "seed": seed, "copies": p.dataset.augment_copies,
            }),
            StageName::Segmenter => {
                let recipe = match self.segmenter_settings() {
                    Some(file) => {
                        let recipe = models::segmenter::train::load_training_config(&file)
                            .map_err(|e| {
                                CliError::file(
                                    &file,
                                    format!("not a segmenter recipe: {e}"),
                                    "fix `settings` in [run.<profile>.segmenter] of the config",
                                )
                            })?;
                        serde_json::to_value(recipe)?
                    }
                    None => serde_json::Value::Null,
                };
                serde_json::json!({
                    "version": version, "seed": seed, "segmenter": serde_json::to_value(&p.segmenter)?,
                    "recipe": recipe,
                })
            }
            StageName::Agent => serde_json::json!({
                "version": version, "seed": seed,
                "eval_episodes": p.agent.eval_episodes,
                "agent": serde_json::to_value(&self.config()?.agent)?,
            }),
            StageName::Logs => serde_json::json!({
                "version": version, "seed": seed,
                "logs": serde_json::to_value(&p.logs)?,
                "task": serde_json::to_value(&self.config()?.agent.task)?,
            }),
            StageName::Replay => serde_json::json!({ "version": version }),
        })
    }

    /// Files outside the run folder the stage reads.
    pub fn external_inputs(&self, stage: StageName) -> Vec<PathBuf> {
        match stage {
            StageName::Maps => vec![self.campus.to_path_buf(), self.roundabout.to_path_buf()],
            _ => Vec::new(),
        }
    }
}
