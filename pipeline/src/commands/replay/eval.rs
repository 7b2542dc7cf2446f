//! `pipeline replay eval`: reads the map, the agent and the logs, trains behaviour cloning
//! when asked, has `judge` judge the policies, and writes the report (or a shard's
//! counts).

use anyhow::Result;
use judge::closed_loop::ClosedLoopConfig;
use judge::{
    BcExamples, Counts, Policies, REPLAY_SHARD_JSON, Report, Settings, ShardFile, default_task,
    evaluate,
};

use super::{EvalArgs, MARKERS, write_report};
use crate::commands::Context;
use crate::error::CliError;
use crate::inputs::load_or_import_map;
use crate::log_args::{load_replay_agent, read_replay_log, replay_views, require_roundabout};
use crate::output::{AtomicDir, write_json};

pub fn run(ctx: &Context<'_>, args: &EvalArgs) -> Result<()> {
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    let mut progress = ctx.ui.progress("replay eval");
    progress.step(&format!("reading {}", args.map.display()));
    let map = load_or_import_map(&args.map)?;
    require_roundabout(&map, &args.map)?;
    let device = models::cpu_device();
    // The agent, and the view it was trained on (behaviour cloning sees the same).
    let (agent, task) = match &args.agent {
        None => (None, default_task()),
        Some(dir) => {
            let (policy, config) = load_replay_agent(dir, &device, &mut |s| progress.note(s))?;
            (Some(policy), config)
        }
    };
    let views = replay_views(&map, &args.map, task, args.target_speed)?;
    let labels = ctx.config.logs.decisions.clone();

    // Behaviour cloning on the training logs' go and wait frames.
    let bc = if args.train_logs.is_empty() {
        None
    } else {
        let mut examples = BcExamples::default();
        for path in &args.train_logs {
            progress.step(&format!("behaviour cloning: reading {}", path.display()));
            let log = read_replay_log(ctx, &map, &args.map, path, &labels)?;
            examples.add(&map, &views, &log, args.bc_stride);
        }
        progress.step(&format!(
            "behaviour cloning: training on {} frames",
            examples.len()
        ));
        let trained = examples
            .train(&views, ctx.global.seed, &device)
            .map_err(|e| {
                CliError::new(
                    format!("behaviour cloning: {e}"),
                    "give --train-log logs with approaches to the map's roundabout",
                )
            })?;
        Some(trained)
    };

    // Every log first: a shard's approaches are numbered over all of them.
    let mut logs = Vec::with_capacity(args.logs.len());
    for path in &args.logs {
        progress.step(&format!("reading {}", path.display()));
        let log = read_replay_log(ctx, &map, &args.map, path, &labels)?;
        progress.step(&format!(
            "{}: {} approaches to a yield line ({} more vehicles crossed one with less than {} s of track before it: no approach)",
            log.name,
            log.approaches.len(),
            log.crossings_without_approach(),
            labels.min_approach_s
        ));
        logs.push(log);
    }
    let policies = Policies {
        bc: bc.as_ref().map(|(network, _)| network),
        agent: agent.as_ref(),
        levels: &args.aggressiveness,
        device: &device,
    };
    let closed_loop = args.closed_loop.then(|| ClosedLoopConfig {
        target_speed_mps: args.target_speed,
        ..ClosedLoopConfig::default()
    });
    let counts: Counts = evaluate(
        &map,
        &views,
        &logs,
        &policies,
        args.shard,
        closed_loop.as_ref(),
    );
    let settings = Settings {
        logs: args.logs.clone(),
        train_logs: args.train_logs.clone(),
        map: args.map.clone(),
        agent: args.agent.clone(),
        labels,
        behaviour_cloning: bc.map(|(_, summary)| summary),
    };
    drop(progress);
    let Some(shard) = args.shard else {
        return write_report(ctx, &out, &Report::new(settings, counts));
    };
    let dir = AtomicDir::create(&out, MARKERS)?;
    write_json(
        &dir.path().join(REPLAY_SHARD_JSON),
        &ShardFile {
            shard,
            settings,
            counts,
        },
    )?;
    let dest = dir.commit()?;
    let total: usize = logs.iter().map(|l| l.approaches.len()).sum();
    let part = shard.range(total as u64);
    ctx.ui.result(&format!(
        "shard {}/{}: approaches {}..{} of {total}; wrote {}",
        shard.index,
        shard.count,
        part.start,
        part.end,
        dest.display()
    ));
    Ok(())
}
