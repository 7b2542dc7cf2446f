//! `pipeline sim calibrate`: the world's drivers fitted to recordings.

use anyhow::Result;
use traffic::calibrate::{calibrate, to_toml};

use super::{CalibrateArgs, read_measured};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::{write_file_atomic, write_json};

pub fn run(ctx: &Context<'_>, args: &CalibrateArgs) -> Result<()> {
    let r = &args.recordings;
    let measured = read_measured(ctx, r, "sim calibrate")?;
    let mut progress = ctx.ui.progress("sim calibrate");
    progress.step("fitting");
    let layout = ctx.config.layout.unwrap_or_default();
    let flows = measured.flows(&layout, &r.map)?;
    let calibration = calibrate(
        &measured.measured,
        measured.geometry.roundabout.0,
        measured.geometry.radius_m,
        flows,
        ctx.global.seed,
    )
    .map_err(|e| {
        CliError::new(
            format!("cannot calibrate on {} recording(s): {e}", r.logs.len()),
            "give more recordings of the roundabout (--log, repeated)",
        )
    })?;
    let mut calibration = calibration;
    if !args.no_refine {
        traffic::calibrate::refine(
            &mut calibration,
            &measured.map,
            &measured.geometry,
            &measured.measured,
            ctx.global.seed,
            |s| progress.step(s),
        )
        .map_err(|e| {
            CliError::new(
                format!("cannot match the world to the recordings: {e}"),
                "try --no-refine for the direct estimates alone",
            )
        })?;
    }
    let source = r.map.file_name().map_or_else(
        || r.map.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let out = ctx.output_path(&args.out);
    let json = out.with_extension("json");
    write_json(&json, &calibration.report)?;
    let names: Vec<String> = r
        .logs
        .iter()
        .map(|p| {
            p.file_name().map_or_else(
                || p.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            )
        })
        .collect();
    write_file_atomic(&out, to_toml(&calibration, &source, &names).as_bytes())?;
    drop(progress);
    let g = &calibration.report.critical_gap;
    ctx.ui.result(&format!(
        "critical gap: median {:.2} s (95 % {:.2}-{:.2}), sigma {:.3}, {} drivers (world's median {:.2} s); \
         follow-up headway {:.2} s; lateral acceleration {:.2} m/s² (world's {:.2}); IDM a {:.2}, b {:.2}, \
         T {:.2} s, s0 {:.2} m\nwritten to {} and {}",
        g.median_s,
        g.median_ci95_s.0,
        g.median_ci95_s.1,
        g.sigma,
        g.drivers,
        calibration
            .traffic
            .drivers
            .critical_gap
            .measured()
            .map_or(g.median_s, |x| x.median_s),
        calibration.report.follow_up_headway.mean,
        calibration.report.lateral_accel_mps2,
        calibration.layout.lateral_accel_mps2,
        calibration.report.idm.max_accel_mps2,
        calibration.report.idm.comfort_decel_mps2,
        calibration.report.idm.time_headway_s,
        calibration.report.idm.min_gap_m,
        out.display(),
        json.display()
    ));
    Ok(())
}
