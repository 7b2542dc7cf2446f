//! `pipeline run`: every stage in order on the bundled campus and roundabout, into one run
//! folder with one rerun recording and a `report.md`.
//!
//! Like `dvc repro`, a stage whose settings and inputs are unchanged since it last finished,
//! and whose outputs still hash as recorded in `manifest.json`, is skipped. Inputs are the
//! bundled files a stage reads and the outputs of the stages it needs, so changing a stage's
//! settings reruns that stage and the stages that read its outputs, and nothing else.
//!
//! Every stage writes into folders it owns in the run; they are removed before it runs,
//! and its manifest entry is written only after it finished, so after a kill the next run
//! repeats the interrupted stage from the start and keeps the finished ones.

mod manifest;
mod report;
pub mod settings;
mod simlog;
mod stage_env;
mod stage_key;
pub mod stages;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Result;
use clap::{Args, ValueEnum};

pub use manifest::{MANIFEST_FILE, Manifest, StageRecord, content_hash};
pub use report::REPORT_FILE;
use settings::ProfileSettings;
use stage_env::StageEnv;
pub use stages::StageName;

use crate::commands::Context;
use crate::error::CliError;
use crate::recording::Recording;

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Profile {
    /// Minutes on 2 cores: every stage, small.
    Quick,
    /// The sizes of the documented results (hours).
    Full,
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Stage sizes: `quick` or `full` ([run.quick] / [run.full] of the config).
    #[arg(long, value_enum, default_value = "quick")]
    pub profile: Profile,

    /// The run folder [default: runs/<profile>].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// Start at this stage (earlier ones must have finished in this run folder).
    #[arg(long, value_enum, value_name = "STAGE", conflicts_with = "only")]
    pub from: Option<StageName>,

    /// Stop after this stage.
    #[arg(long, value_enum, value_name = "STAGE", conflicts_with = "only")]
    pub to: Option<StageName>,

    /// Run this stage only.
    #[arg(long, value_enum, value_name = "STAGE")]
    pub only: Option<StageName>,

    /// Run the selected stages even when nothing they depend on changed.
    #[arg(long)]
    pub force: bool,
}

/// What happened to one stage in this invocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StageOutcome {
    Ran,
    Skipped,
    NotSelected,
}

pub fn run(ctx: &Context<'_>, args: &RunArgs) -> Result<()> {
    let profile_name = match args.profile {
        Profile::Quick => "quick",
        Profile::Full => "full",
    };
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs").join(profile_name));
    let run_dir = ctx.output_path(&out);
    std::fs::create_dir_all(&run_dir).map_err(|e| {
        CliError::file(
            &run_dir,
            format!("cannot create the run folder: {e}"),
            "check --out",
        )
    })?;
    let run_config = &ctx.config.run;
    let profile: &ProfileSettings = match args.profile {
        Profile::Quick => &run_config.quick,
        Profile::Full => &run_config.full,
    };
    let campus = ctx.config.resolve(&run_config.campus);
    let roundabout = ctx.config.resolve(&run_config.roundabout);
    for (what, path) in [("campus", &campus), ("roundabout", &roundabout)] {
        if !path.is_file() {
            return Err(CliError::file(
                path,
                format!("the {what} map to import does not exist"),
                "run from the repository's root (where pipeline.toml is), or set [run] campus / roundabout in the config",
            )
            .into());
        }
    }

    let selected: Vec<StageName> = StageName::ALL
        .into_iter()
        .filter(|s| match args.only {
            Some(only) => *s == only,
            None => args.from.is_none_or(|f| *s >= f) && args.to.is_none_or(|t| *s <= t),
        })
        .collect();

    let again = invocation(ctx, args);
    let mut manifest = Manifest::load(&run_dir)?;
    let recording = Recording::open(&ctx.global.rerun, Some(&run_dir))?;
    let mut outcomes: BTreeMap<StageName, StageOutcome> = BTreeMap::new();
    let started = Instant::now();
    for stage in StageName::ALL {
        if !selected.contains(&stage) {
            outcomes.insert(stage, StageOutcome::NotSelected);
            continue;
        }
        let stream = recording.stream().map(|s| s.stage(stage.as_str()));
        let env = StageEnv {
            ctx,
            run_dir: &run_dir,
            profile,
            campus: &campus,
            roundabout: &roundabout,
            recording: stream.as_ref(),
        };
        let (key, settings, inputs) = stage_key(&env, &manifest, stage, &again)?;
        if !args.force && is_up_to_date(&run_dir, &manifest, stage, &key)? {
            ctx.ui
                .info(&format!("stage {}: up to date, skipped", stage.as_str()));
            outcomes.insert(stage, StageOutcome::Skipped);
            continue;
        }
        ctx.ui.info(&format!("stage {}: running", stage.as_str()));
        // The manifest forgets the stage before its outputs go: a kill from here on
        // leaves it to be run again.
        if manifest.stages.remove(stage.as_str()).is_some() {
            manifest.save(&run_dir)?;
        }
        for rel in stage.outputs() {
            // `agent train` keeps checkpoints beside its folder while it trains.
            remove_output(&run_dir.join(rel))?;
            remove_output(&run_dir.join(format!("{rel}.partial")))?;
        }
        let stage_start = Instant::now();
        env.run(stage)?;
        let mut outputs = BTreeMap::new();
        for rel in stage.outputs() {
            outputs.insert((*rel).to_owned(), content_hash(&run_dir.join(rel))?);
        }
        let seconds = stage_start.elapsed().as_secs_f64();
        manifest.stages.insert(
            stage.as_str().to_owned(),
            StageRecord {
                key,
                settings,
                inputs,
                outputs,
                seconds,
            },
        );
        manifest.save(&run_dir)?;
        ctx.ui
            .info(&format!("stage {}: done in {seconds:.1} s", stage.as_str()));
        outcomes.insert(stage, StageOutcome::Ran);
    }
    let report_path = report::write(&run_dir, &manifest, &outcomes, profile_name)?;
    recording.finish()?;
    ctx.ui.result(&format!(
        "run {} ({profile_name}) in {:.1} s: {} ran, {} up to date; report {}",
        run_dir.display(),
        started.elapsed().as_secs_f64(),
        outcomes
            .values()
            .filter(|o| **o == StageOutcome::Ran)
            .count(),
        outcomes
            .values()
            .filter(|o| **o == StageOutcome::Skipped)
            .count(),
        report_path.display()
    ));
    Ok(())
}

/// `pipeline run` with the options that name this run (config, run folder, profile), for
/// hints that say what to run: `pipeline --config c.toml run --out DIR`.
fn invocation(ctx: &Context<'_>, args: &RunArgs) -> String {
    let quoted = |p: &Path| {
        let text = p.display().to_string();
        if text.contains(char::is_whitespace) || text.contains(['\'', '"', '$']) {
            format!("'{}'", text.replace('\'', r"'\''"))
        } else {
            text
        }
    };
    let mut line = String::from("pipeline");
    if let Some(config) = &ctx.global.config {
        line.push_str(&format!(" --config {}", quoted(config)));
    }
    if let Some(dir) = &ctx.global.run_dir {
        line.push_str(&format!(" --run-dir {}", quoted(dir)));
    }
    line.push_str(" run");
    if args.profile == Profile::Full {
        line.push_str(" --profile full");
    }
    if let Some(out) = &args.out {
        line.push_str(&format!(" --out {}", quoted(out)));
    }
    line
}

/// The stage's key: its settings and the content hashes of everything it reads. `again` is
/// the command line of this run, for the hint when an earlier stage is missing.
fn stage_key(
    env: &StageEnv<'_>,
    manifest: &Manifest,
    stage: StageName,
    again: &str,
) -> Result<(String, serde_json::Value, BTreeMap<String, String>)> {
    let settings = env.settings(stage)?;
    let mut inputs = BTreeMap::new();
    for path in env.external_inputs(stage) {
        inputs.insert(path.to_string_lossy().into_owned(), content_hash(&path)?);
    }
    for need in stage.needs() {
        let Some(record) = manifest.stages.get(need.as_str()) else {
            return Err(CliError::new(
                format!(
                    "stage {} needs the outputs of stage {}, which has not finished in {}",
                    stage.as_str(),
                    need.as_str(),
                    env.run_dir.display()
                ),
                format!("run it first: {again} --to {}", need.as_str()),
            )
            .into());
        };
        inputs.extend(record.outputs.clone());
    }
    let material = serde_json::to_string(&(&settings, &inputs))?;
    Ok((manifest::bytes_hash(material.as_bytes()), settings, inputs))
}

/// Whether the manifest has the stage with this key and its outputs still hash the same.
fn is_up_to_date(run_dir: &Path, manifest: &Manifest, stage: StageName, key: &str) -> Result<bool> {
    let Some(record) = manifest.stages.get(stage.as_str()) else {
        return Ok(false);
    };
    if record.key != key {
        return Ok(false);
    }
    for (rel, hash) in &record.outputs {
        let path = run_dir.join(rel);
        if !path.exists() || content_hash(&path)? != *hash {
            return Ok(false);
        }
    }
    Ok(true)
}

fn remove_output(path: &Path) -> Result<()> {
    let result = if path.is_dir() {
        std::fs::remove_dir_all(path)
    } else if path.exists() {
        std::fs::remove_file(path)
    } else {
        Ok(())
    };
    result.map_err(|e| {
        CliError::file(
            path,
            format!("cannot remove the stage's earlier output: {e}"),
            "check permissions",
        )
        .into()
    })
}
