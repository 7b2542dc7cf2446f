//! The `--config` TOML file: defaults for commands, overridden by the command line.
//!
//! ```toml
//! [map.import]
//! profile = "passenger"            # car | passenger | all | a profile TOML file
//! clip_bbox = "-87.69,42.05,-87.66,42.07"
//! # clip_polygon = "campus.poly"   # GeoJSON or Osmosis .poly
//! driving_side = "right"           # left | right
//! u_turns = "dead-ends"            # never | dead-ends | everywhere
//! guess_roundabouts = true
//! origin = "42.0561,-87.6752"      # lat,lon
//! ```
//!
//! Unknown keys are errors, so a typo does not silently fall back to a default. Relative
//! paths in the file are relative to the file itself.

use std::path::{Path, PathBuf};

use anyhow::Result;
use serde::{Deserialize, Serialize};

use crate::error::CliError;

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    #[serde(default)]
    pub map: MapConfig,
    /// `[agent.dqn]` (hyper-parameters), `[agent.task]` (insertion's settings) and
    /// `[agent.roundabout_driving]`.
    #[serde(default)]
    pub agent: crate::tasks::AgentConfig,
    /// `[run]`: the maps and stage sizes of `pipeline run`.
    #[serde(default)]
    pub run: crate::commands::run::settings::RunConfig,
    /// `[logs.roles]`: which topic of a log is the ego pose, the GPS, the objects, the camera;
    /// `[logs.decisions]`: how drivers' go / wait decisions are labelled.
    #[serde(default)]
    pub logs: LogsConfig,
    /// `[traffic]` (with `[traffic.drivers]`) and `[layout]`: the world's traffic and route
    /// layout for every task that drives among traffic, in place of the tasks' own tables (a
    /// calibration written by `pipeline sim calibrate`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub traffic: Option<sim::world::TrafficConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub layout: Option<sim::roundabout::LayoutConfig>,
    /// `[recorded]`: the recordings' flows on their roundabout's entry lanes, for `--traffic
    /// recorded` (written by `sim calibrate`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recorded: Option<RecordedFlows>,
    /// A calibration file (`sim calibrate --out`) whose `[traffic]`, `[layout]` and
    /// `[recorded]` apply where this file has none; relative to this file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<PathBuf>,
    /// The folder of the file, for its relative paths (not part of the TOML).
    #[serde(skip)]
    pub base_dir: PathBuf,
}

/// `[recorded]` of a calibration: the recordings' arrival flows.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordedFlows {
    /// The roundabout of the recordings' map the lanes belong to.
    pub roundabout: u32,
    pub flows: Vec<sim::world::EntryFlow>,
}

/// `[logs]` of the config.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LogsConfig {
    /// Topics named for roles; the others are detected (`logs::roles`).
    pub roles: logs::roles::RoleConfig,
    /// The go / wait labelling of `replay eval` and `agent train --offline`.
    pub decisions: traffic::decisions::LabelConfig,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapConfig {
    #[serde(default)]
    pub import: ImportConfig,
}

/// `[map.import]`: the same settings as `pipeline map import`'s options, in the same syntax.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImportConfig {
    pub profile: Option<String>,
    pub clip_bbox: Option<String>,
    pub clip_polygon: Option<PathBuf>,
    pub driving_side: Option<String>,
    #[serde(alias = "u-turns")]
    pub u_turns: Option<String>,
    pub guess_roundabouts: Option<bool>,
    pub origin: Option<String>,
}

impl Config {
    /// Reads the file, or gives the defaults when there is none.
    pub fn load(path: Option<&Path>) -> Result<Config> {
        let Some(path) = path else {
            return Ok(Config::default());
        };
        let text = std::fs::read_to_string(path).map_err(|e| {
            CliError::file(
                path,
                format!("cannot read config: {e}"),
                "check the --config path",
            )
        })?;
        let mut config = Self::parse(&text).map_err(|e| {
            CliError::file(
                path,
                format!("invalid config: {e}"),
                "see `pipeline --help` and README.md for the keys",
            )
        })?;
        config.base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        if let Some(file) = config.calibration.clone() {
            let file = config.resolve(&file);
            let calibration = Self::load(Some(&file))?;
            config.traffic = config.traffic.take().or(calibration.traffic);
            config.layout = config.layout.take().or(calibration.layout);
            config.recorded = config.recorded.take().or(calibration.recorded);
        }
        config.apply_world();
        Ok(config)
    }

    /// The traffic world this config gives (`[traffic]`, `[recorded]`'s flows, `[layout]`),
    /// which replaces the tasks' own.
    pub fn world(&self) -> sim::world::CalibratedWorld {
        sim::world::CalibratedWorld {
            traffic: self.traffic.clone(),
            flows: self.recorded.as_ref().map(|r| r.flows.clone()),
            layout: self.layout,
        }
    }

    /// Puts the config's traffic world ([`Config::world`]) into every task's settings that
    /// runs the traffic world ([`sim::tasks::Task::in_world`]).
    pub fn apply_world(&mut self) {
        let world = self.world();
        for id in sim::tasks::TaskId::ALL {
            id.visit(crate::tasks::InWorld {
                agent: &mut self.agent,
                world: &world,
            });
        }
    }

    pub fn parse(text: &str) -> std::result::Result<Config, String> {
        toml::from_str(text).map_err(|e| e.message().to_owned())
    }

    /// A path from the file, made relative to the file's folder.
    pub fn resolve(&self, p: &Path) -> PathBuf {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.base_dir.join(p)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_map_import_defaults_and_rejects_typos() -> Result<(), String> {
        let c = Config::parse(
            "[map.import]\nprofile = \"all\"\nu_turns = \"never\"\nguess_roundabouts = false\n",
        )?;
        assert_eq!(c.map.import.profile.as_deref(), Some("all"));
        assert_eq!(c.map.import.guess_roundabouts, Some(false));
        assert!(Config::parse("[map.import]\nprofiel = \"all\"\n").is_err());
        assert!(Config::parse("[mapp]\n").is_err());
        assert_eq!(Config::parse(""), Ok(Config::default()));
        Ok(())
    }

    /// What a file of `configs/` is for, by its name's prefix.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum Recipe {
        /// `segmenter_*.toml`: `segmenter train --settings`.
        Segmenter,
        /// `augment_*.toml`: `dataset augment --transforms`.
        Transforms,
        /// The others: `--config` files.
        Pipeline,
    }

    /// The TOML files of `configs/` (the recipes the docs present) of one kind, sorted.
    fn documented_configs(kind: Recipe) -> Result<Vec<PathBuf>, String> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .map_err(|e| format!("{}: {e}", dir.display()))?
            .filter_map(|entry| entry.ok().map(|e| e.path()))
            .filter(|path| path.extension().is_some_and(|e| e == "toml"))
            .filter(|path| {
                let name = path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let of = if name.starts_with("segmenter_") {
                    Recipe::Segmenter
                } else if name.starts_with("augment_") {
                    Recipe::Transforms
                } else {
                    Recipe::Pipeline
                };
                of == kind
            })
            .collect();
        files.sort();
        Ok(files)
    }

    /// The files of `configs/` are how the docs' results are rerun: a renamed key or a
    /// removed option must fail here, not months later in someone's hour-long training run.
    #[test]
    fn every_documented_config_file_reads_and_its_dqn_settings_validate() -> Result<(), String> {
        let files = documented_configs(Recipe::Pipeline)?;
        assert!(!files.is_empty(), "no config files in configs/");
        for file in &files {
            let config = Config::load(Some(file)).map_err(|e| format!("{e:#}"))?;
            config
                .agent
                .dqn
                .validate()
                .map_err(|e| format!("{}: [agent.dqn]: {e}", file.display()))?;
        }
        Ok(())
    }

    /// The segmenter settings of `configs/` (`segmenter train --settings FILE`) must
    /// still read as a training config and pass its checks.
    #[test]
    fn every_documented_segmenter_settings_file_reads_and_validates() -> Result<(), String> {
        let files = documented_configs(Recipe::Segmenter)?;
        assert!(!files.is_empty(), "no segmenter settings in configs/");
        for file in &files {
            let config = models::segmenter::train::load_training_config(file)
                .map_err(|e| format!("{}: {e}", file.display()))?;
            config
                .validate()
                .map_err(|e| format!("{}: {e}", file.display()))?;
        }
        Ok(())
    }

    /// The augmentation transforms of `configs/` (`dataset augment --transforms FILE`) must
    /// still read (an unknown key is an error) and pass their checks.
    #[test]
    fn every_documented_transforms_file_reads_and_validates() -> Result<(), String> {
        let read = |file: &PathBuf| {
            std::fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))
        };
        let transforms = documented_configs(Recipe::Transforms)?;
        assert!(
            !transforms.is_empty(),
            "no augmentation transforms in configs/"
        );
        for file in &transforms {
            let config: datasets::augment::AugmentConfig =
                toml::from_str(&read(file)?).map_err(|e| format!("{}: {e}", file.display()))?;
            config
                .validate()
                .map_err(|e| format!("{}: {e}", file.display()))?;
        }
        Ok(())
    }

    /// The main job's `pipeline.toml` names the committed calibration: every task that runs
    /// the traffic world gets its traffic and layout, and its recorded flows.
    #[test]
    fn the_main_job_runs_the_calibrated_world() -> Result<(), String> {
        let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml");
        let mut config = Config::load(Some(&file)).map_err(|e| format!("{e:#}"))?;
        let traffic = config
            .traffic
            .clone()
            .ok_or("pipeline.toml: no calibrated traffic")?;
        let gap = traffic
            .drivers
            .critical_gap
            .measured()
            .ok_or("the calibration has no critical gap")?;
        assert!((1.0..10.0).contains(&gap.median_s), "{gap:?}");
        assert!(traffic.capacity.is_some(), "no capacity model");
        assert_eq!(config.agent.task.traffic.drivers, traffic.drivers);
        assert_eq!(
            config.agent.roundabout_driving.traffic.drivers,
            traffic.drivers
        );
        assert_eq!(Some(config.agent.task.layout), config.layout);
        assert!(
            !config.agent.task.traffic.flows.is_empty(),
            "no recorded flows"
        );
        // A profile's agent recipe replaces [agent]; the world is put back.
        config.agent = crate::tasks::AgentConfig::default();
        config.apply_world();
        assert_eq!(config.agent.task.traffic.drivers, traffic.drivers);
        Ok(())
    }
}
