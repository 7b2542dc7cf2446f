//! What `agent train` checks and prepares before training: the training maps and the
//! task set up on each, the warm-up against a resumed run, and settings errors naming the
//! config file.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Result;
use models::ModelError;
use models::dqn::DqnConfig;
use sim::tasks::Task;

use super::TrainArgs;
use crate::agent_folder::TrainingMap;
use crate::commands::Context;
use crate::error::CliError;

/// The training maps of `--map` (each on the task's own ring) and `--maps` (a list file).
pub(super) fn training_maps(args: &TrainArgs) -> Result<Vec<TrainingMap>> {
    let mut maps: Vec<TrainingMap> = args
        .map
        .iter()
        .map(|path| TrainingMap {
            path: path.clone(),
            roundabout: None,
        })
        .collect();
    let Some(list) = &args.maps else {
        return Ok(maps);
    };
    let text = std::fs::read_to_string(list).map_err(|e| {
        CliError::file(
            list,
            format!("cannot read: {e}"),
            "give a readable list of maps",
        )
    })?;
    let folder = list.parent().unwrap_or(std::path::Path::new("."));
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let mut words = line.split_whitespace();
        let (Some(path), ring, None) = (words.next(), words.next(), words.next()) else {
            return Err(CliError::file(
                list,
                format!(
                    "line {}: expected `PATH [ROUNDABOUT]`, found {line:?}",
                    n + 1
                ),
                "write one map per line, optionally followed by a roundabout id",
            )
            .into());
        };
        let roundabout = ring
            .map(|r| {
                r.parse::<u32>().map_err(|_| {
                    CliError::file(
                        list,
                        format!("line {}: {r:?} is not a roundabout id", n + 1),
                        "give the id `pipeline map info` lists",
                    )
                })
            })
            .transpose()?;
        maps.push(TrainingMap {
            path: folder.join(path),
            roundabout,
        });
    }
    if maps.is_empty() {
        return Err(CliError::file(list, "lists no map", "write one map per line").into());
    }
    Ok(maps)
}

/// Task `T` with `config` set up on each training map (on its ring), or once without a map
/// when there is none.
pub(super) fn setups_of<T: Task>(
    maps: &[TrainingMap],
    config: &T::Config,
) -> Result<Vec<Arc<T::Setup>>> {
    if maps.is_empty() {
        return Ok(vec![crate::tasks::setup::<T>(None, config)?]);
    }
    maps.iter()
        .map(|m| crate::tasks::setup::<T>(Some(&m.path), &on_ring::<T>(config, m)?))
        .collect()
}

/// `config` on the ring `map` names (unchanged when it names none).
fn on_ring<T: Task>(config: &T::Config, map: &TrainingMap) -> Result<T::Config> {
    match map.roundabout {
        None => Ok(config.clone()),
        Some(id) => T::on_roundabout(config, id).ok_or_else(|| {
            CliError::file(
                &map.path,
                format!(
                    "a roundabout ({id}) is named, but {} drives on no roundabout",
                    T::ID.info().title
                ),
                "leave the roundabout id out of the list",
            )
            .into()
        }),
    }
}

/// Refuses a run whose transitions all go to the warm-up: it would take no gradient step
/// (and a "best" validation would choose among untrained networks).
pub(super) fn check_warmup(dqn: &DqnConfig, first_step: u64) -> Result<()> {
    let to_train = dqn.total_steps.saturating_sub(first_step);
    if to_train == 0 || to_train > dqn.warmup_steps {
        return Ok(());
    }
    let span = if first_step > 0 {
        format!(" (from step {first_step} to {})", dqn.total_steps)
    } else {
        String::new()
    };
    Err(CliError::new(
        format!(
            "the run's {to_train} transitions{span} are all warm-up (warmup_steps = {} of \
             [agent.dqn]): no gradient step would be taken",
            dqn.warmup_steps
        ),
        format!(
            "train for more than {} transitions (--steps, or total_steps of [agent.dqn]), or \
             lower warmup_steps of [agent.dqn]",
            first_step + dqn.warmup_steps
        ),
    )
    .into())
}

pub(super) fn config_error(ctx: &Context<'_>, e: ModelError) -> anyhow::Error {
    let file = ctx
        .global
        .config
        .clone()
        .unwrap_or_else(|| PathBuf::from("--config"));
    CliError::file(
        &file,
        format!("[agent.dqn]: {e}"),
        "fix the [agent.dqn] table (see docs/agents.md)",
    )
    .into()
}
