//! `[run]` of `pipeline.toml`: the bundled maps the run starts from, and per profile how big
//! each stage is. The bundled `pipeline.toml` at the repository's root spells out these
//! defaults (a test checks that it parses to them).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunConfig {
    /// The campus the segmentation data is rendered on (relative to the config file).
    pub campus: PathBuf,
    /// The roundabout the agent drives and the simulated log is recorded on.
    pub roundabout: PathBuf,
    pub quick: ProfileSettings,
    pub full: ProfileSettings,
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig {
            campus: "data/osm/northwestern_nu.osm.pbf".into(),
            roundabout: "data/osm/montlake_roundabout.osm.pbf".into(),
            quick: ProfileSettings::quick(),
            full: ProfileSettings::full(),
        }
    }
}

/// How big each stage is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileSettings {
    pub dataset: DatasetSettings,
    pub segmenter: SegmenterSettings,
    pub agent: AgentSettings,
    pub logs: LogSettings,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetSettings {
    /// Images rendered from the campus.
    pub images: u64,
    /// `WxH`.
    pub size: String,
    /// Augmented copies of each training image (the thesis preset).
    pub augment_copies: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmenterSettings {
    /// The training recipe (`segmenter train --settings`, a file of `configs/`), relative to
    /// the config file; the keys below override it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settings: Option<PathBuf>,
    pub epochs: usize,
    /// Stops earlier when training has taken this long.
    pub max_minutes: f64,
    /// Short side the images are resized to.
    pub size: u32,
    /// Side of the square training crops [default: `size`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crop: Option<u32>,
    /// Channel multiplier of the encoder.
    pub width: f64,
    pub batch_size: usize,
    /// Validation images evaluated.
    pub eval_images: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AgentSettings {
    /// The agent's recipe: a config file whose `[agent]` tables replace those of the run's
    /// config (a file of `configs/`), relative to the config file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config: Option<PathBuf>,
    /// Environment transitions of training [default: the recipe's `total_steps`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steps: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warmup_steps: Option<u64>,
    /// Evaluation episodes at medium traffic and aggressiveness 0.5.
    pub eval_episodes: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LogSettings {
    /// Simulated seconds of traffic written as a log.
    pub seconds: f64,
}

impl ProfileSettings {
    /// Minutes on 2 cores: enough to see every stage work, not to reach the documented figures.
    pub fn quick() -> Self {
        ProfileSettings {
            dataset: DatasetSettings {
                images: 200,
                size: "256x256".into(),
                augment_copies: 1,
            },
            segmenter: SegmenterSettings {
                settings: Some("configs/segmenter_quick.toml".into()),
                epochs: 12,
                max_minutes: 8.0,
                size: 192,
                crop: Some(128),
                width: 0.5,
                batch_size: 8,
                eval_images: 60,
            },
            agent: AgentSettings {
                config: Some("configs/insertion_quick.toml".into()),
                steps: None,
                warmup_steps: None,
                eval_episodes: 100,
            },
            logs: LogSettings { seconds: 60.0 },
        }
    }

    /// The documented results' sizes (hours on 2 cores).
    pub fn full() -> Self {
        ProfileSettings {
            dataset: DatasetSettings {
                images: 2000,
                size: "256x256".into(),
                augment_copies: 7,
            },
            segmenter: SegmenterSettings {
                settings: Some("configs/segmenter_generated_depth4_noaux.toml".into()),
                epochs: 40,
                max_minutes: 120.0,
                size: 384,
                crop: Some(256),
                width: 0.5,
                batch_size: 4,
                eval_images: 600,
            },
            agent: AgentSettings {
                config: Some("configs/insertion_1h.toml".into()),
                steps: None,
                warmup_steps: None,
                eval_episodes: 3000,
            },
            logs: LogSettings { seconds: 600.0 },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bundled pipeline.toml spells out the defaults.
    #[test]
    fn bundled_pipeline_toml_is_the_defaults() -> Result<(), String> {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../pipeline.toml");
        let text = std::fs::read_to_string(path).map_err(|e| format!("{path}: {e}"))?;
        let config = crate::config::Config::parse(&text)?;
        assert_eq!(config.run, RunConfig::default());
        // A profile given in the file gives all of its sections (no silent mix of profiles).
        assert!(crate::config::Config::parse("[run.quick.dataset]\nimages = 5\n").is_err());
        assert!(crate::config::Config::parse("[run]\ncampuss = \"x.osm\"\n").is_err());
        Ok(())
    }
}
