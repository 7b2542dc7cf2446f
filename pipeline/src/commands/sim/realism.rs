//! `pipeline sim realism`: the world on the recordings' roundabout, with their own flows,
//! against the recordings.

use anyhow::Result;
use rayon::prelude::*;
use sim::seed::derive_seed;
use traffic::measure::{Measurements, measure};
use traffic::realism::{METRICS, RealismReport, compare, markdown, samples};
use traffic::simulate::simulate;

use super::{RealismArgs, read_measured};
use crate::commands::Context;
use crate::error::CliError;
use crate::output::{AtomicDir, Markers, write_file_atomic, write_json};
use crate::plots::{LineChart, Series, line_charts_png};

pub const REALISM_JSON: &str = "realism.json";
pub const REALISM_MD: &str = "realism.md";
const MARKERS: Markers = &[REALISM_JSON];
/// Seed stage of the simulated runs.
const REALISM_STAGE: u64 = 0x5245_414c;
/// Traffic simulated before each run's measured time, s.
const WARM_UP_S: f64 = 120.0;

pub fn run(ctx: &Context<'_>, args: &RealismArgs) -> Result<()> {
    if args.traffic != "recorded" {
        return Err(CliError::new(
            format!(
                "--traffic {}: realism compares at the recordings' own flows",
                args.traffic
            ),
            "use --traffic recorded (the default)",
        )
        .into());
    }
    let out = ctx.output_path(&args.out);
    AtomicDir::check_destination(&out, MARKERS)?;
    let r = &args.recordings;
    let measured = read_measured(ctx, r, "sim realism")?;
    let mut traffic = ctx.config.traffic.clone().unwrap_or_default();
    let layout = ctx.config.layout.unwrap_or_default();
    traffic.level = sim::world::TrafficLevel::Recorded;
    traffic.flows = measured.flows(&layout, &r.map)?;
    // One run per recording, as long as it (longer when --minutes asks for more).
    let recorded_s: f64 = measured.measured.iter().map(|m| m.duration_s).sum();
    let scale = args
        .minutes
        .map_or(1.0, |m| (m * 60.0 / recorded_s.max(1.0)).max(1.0));
    let mut progress = ctx.ui.progress("sim realism");
    progress.counted("simulating", measured.measured.len() as u64, "runs");
    let runs: Vec<Result<Measurements, String>> = measured
        .measured
        .par_iter()
        .enumerate()
        .map(|(k, m)| {
            let seed = derive_seed(ctx.global.seed, REALISM_STAGE, k as u64);
            let run = simulate(
                &measured.map,
                measured.geometry.roundabout,
                &traffic,
                &layout,
                m.duration_s * scale,
                WARM_UP_S,
                seed,
            )?;
            progress.inc(1);
            Ok(measure(&measured.geometry, &run.frames))
        })
        .collect();
    let sim: Vec<Measurements> = runs
        .into_iter()
        .collect::<Result<_, _>>()
        .map_err(|e| CliError::file(&r.map, e, "give the map the recordings were made on"))?;
    progress.step("comparing");
    let report = compare(&measured.measured, &sim);
    let title = format!(
        "roundabout {} of {}, {} recording(s)",
        measured.geometry.roundabout.0,
        r.map.display(),
        r.logs.len()
    );
    let md = markdown(&report, &title);
    let dir = AtomicDir::create(&out, MARKERS)?;
    write_json(&dir.path().join(REALISM_JSON), &report)?;
    write_file_atomic(&dir.path().join(REALISM_MD), md.as_bytes())?;
    let (real, simulated) = (samples(&measured.measured), samples(&sim));
    let recording = ctx.open_recording(Some(dir.path()))?;
    for (name, what, unit) in METRICS {
        let chart = LineChart {
            title: format!("{name}: {what} (KS {:.3})", ks(&report, name)),
            x_label: unit.to_owned(),
            y_label: "share of the sample at or below".to_owned(),
            series: vec![
                Series::new("recorded", ecdf(real.get(name))),
                Series::new("simulated", ecdf(simulated.get(name))),
            ],
            y_range: Some((0.0, 1.0)),
            integer_x: false,
        };
        let png = line_charts_png(&[chart], 900, 420)?;
        write_file_atomic(&dir.path().join(format!("{name}.png")), &png)?;
        if let Some(rec) = recording.stream() {
            let image = image::load_from_memory(&png)?.to_rgb8();
            crate::recording::log_rgb(rec, &format!("realism/{name}"), &image)?;
            crate::recording::log_scalars(
                rec,
                &[(&format!("realism/ks/{name}"), ks(&report, name))],
            )?;
        }
    }
    recording.finish()?;
    let dest = dir.commit()?;
    drop(progress);
    ctx.ui
        .result(&format!("{md}\nwritten to {}", dest.display()));
    Ok(())
}

fn ks(report: &RealismReport, name: &str) -> f64 {
    report.metrics.get(name).map_or(f64::NAN, |m| m.ks)
}

/// The empirical distribution function of `sample` as a step line.
fn ecdf(sample: Option<&Vec<f64>>) -> Vec<(f64, f64)> {
    let mut xs: Vec<f64> = sample.map_or_else(Vec::new, |s| {
        s.iter().copied().filter(|x| x.is_finite()).collect()
    });
    xs.sort_by(f64::total_cmp);
    let n = xs.len() as f64;
    let mut points = Vec::with_capacity(xs.len() * 2);
    for (i, x) in xs.iter().enumerate() {
        points.push((*x, i as f64 / n));
        points.push((*x, (i + 1) as f64 / n));
    }
    points
}
