//! The world's driver parameters fitted to recordings of a roundabout (`pipeline sim
//! calibrate`).
//!
//! - **Speeds** are fitted relative to the ring's radius, so that they carry to other
//!   roundabouts: the world's drivers aim at `sqrt(lateral_accel × radius)` on a curve (the
//!   layout's `lateral_accel_mps2`), times their `speed_factor`. The lateral acceleration is
//!   the median of `v² / r` over vehicles circulating freely (no vehicle within 30 m ahead
//!   most of the time), and the speed factors spread as those vehicles' speeds do (a uniform
//!   spread of the same mean and variance, since drivers' aggressiveness is uniform).
//! - **Car following**: the IDM's maximum acceleration, comfortable deceleration, time
//!   headway and minimum gap by least squares on the accelerations of vehicles following
//!   another round the ring, in motion ([`fit::fit_idm`]; each follower's desired speed is
//!   its fastest round the ring); they are the drivers' values at
//!   aggressiveness 0.5, spread across aggressiveness as the uncalibrated world spreads them.
//! - **Gap acceptance**: a lognormal critical gap by maximum likelihood from each entering
//!   driver's accepted gap and largest rejected gap (Troutbeck 1992, [`fit::fit_critical_gap`]);
//!   a driver of aggressiveness `a` has its `1 − a` quantile. The follow-up headway is
//!   measured and reported; in the world it follows from the drivers' acceleration and gaps.
//! - **Vehicle sizes** spread uniformly with the recordings' mean and variance; **flows** per
//!   entry are the vehicles crossing each yield line per hour.

use serde::Serialize;
use sim::roundabout::LayoutConfig;
use sim::world::{
    CapacityModel, CriticalGap, EntryFlow, GapAcceptance, Span, TrafficConfig, TrafficLevel,
};

use crate::fit::{self, CriticalGapFit, FollowingSample, IdmFit, MeanFit};
use crate::measure::Measurements;

/// Fewest entering drivers with a measured gap a calibration accepts.
pub const MIN_GAP_DRIVERS: usize = 30;
/// Fewest car-following samples the IDM fit accepts.
pub const MIN_FOLLOWING_SAMPLES: usize = 200;
/// Car-following samples count only in motion (a standing queue tells nothing of the
/// model's dynamics, and position noise dominates there): at least this gap, m, and speed,
/// m/s, and accelerations within ±4 m/s² (beyond, the track's noise).
const MIN_FOLLOWING_GAP_M: f64 = 2.0;
const MIN_FOLLOWING_SPEED_MPS: f64 = 2.0;
/// Calibrated drivers judge gaps from this far before their line (their critical gap is
/// what must be left when they reach it), m: about 3 s at the recordings' approach speeds.
pub const DECISION_DISTANCE_M: f64 = 25.0;
/// Calibrated arrivals enter behind a queue with this much room (the recordings' vehicles
/// appear at the map's edge at whatever headway the queue leaves), m.
pub const SPAWN_CLEARANCE_M: f64 = 3.0;
/// Bootstrap resamples of every interval.
const BOOTSTRAP: usize = 100;
const IDM_BOOTSTRAP: usize = 30;

/// Every fitted figure with its uncertainty (the companion JSON of the TOML).
#[derive(Debug, Clone, Serialize)]
pub struct CalibrationReport {
    pub recordings: usize,
    pub minutes: f64,
    pub roundabout: u32,
    pub radius_m: f64,
    /// Free circulating speed, m/s (vehicles without a leader most of their time on the ring).
    pub free_circulating_speed: MeanFit,
    /// All circulating vehicles' median speeds, m/s.
    pub circulating_speed: MeanFit,
    pub lateral_accel_mps2: f64,
    pub speed_factor: (f64, f64),
    pub approach_speed_at_line: MeanFit,
    pub idm: IdmFit,
    /// Whether the IDM fit is used (false: it ended on a bound of its search box, and the
    /// world keeps its own car following).
    pub idm_identified: bool,
    pub critical_gap: CriticalGapFit,
    pub follow_up_headway: MeanFit,
    pub vehicle_length_m: MeanFit,
    pub vehicle_width_m: MeanFit,
    /// Vehicles per hour crossing each yield line (the geometry's entries, in the map's
    /// order of yield lines).
    pub entry_flows_vph: Vec<f64>,
    /// The same flows on the layout's entry lanes (`--traffic recorded`).
    pub flows: Vec<EntryFlow>,
    /// The simulation-based step ([`refine`]), when it ran.
    pub refinement: Option<Refinement>,
}

/// A calibration: the world's traffic and layout settings, and the report.
#[derive(Debug, Clone)]
pub struct Calibration {
    pub traffic: TrafficConfig,
    pub layout: LayoutConfig,
    pub report: CalibrationReport,
}

/// Fits the world's drivers to `measured` (one per recording) at a ring of radius
/// `radius_m`; `flows` are the recordings' flows on the layout's entry lanes. Errors say
/// what is missing (too few gaps, too few following vehicles).
pub fn calibrate(
    measured: &[Measurements],
    roundabout: u32,
    radius_m: f64,
    flows: Vec<EntryFlow>,
    seed: u64,
) -> Result<Calibration, String> {
    let base = TrafficConfig::default();
    let base_layout = LayoutConfig::default();
    let minutes = measured.iter().map(|m| m.duration_s).sum::<f64>() / 60.0;

    // Gap acceptance.
    let gaps = gap_observations(measured);
    if gaps.len() < MIN_GAP_DRIVERS {
        return Err(format!(
            "only {} entering drivers with a measured gap (at least {MIN_GAP_DRIVERS} needed): \
             give longer or busier recordings",
            gaps.len()
        ));
    }
    // Speeds.
    let circulating: Vec<(f64, bool)> = measured
        .iter()
        .flat_map(|m| m.circulating.clone())
        .collect();
    let free: Vec<f64> = circulating.iter().filter(|c| !c.1).map(|c| c.0).collect();
    let free_fit = fit::fit_mean(&free)
        .map_err(|_| "no vehicle circulated freely round the ring".to_owned())?;
    let all_fit = fit::fit_mean(&circulating.iter().map(|c| c.0).collect::<Vec<_>>())
        .map_err(|e| format!("circulating speeds: {e}"))?;
    let mut squares: Vec<f64> = free.iter().map(|v| v * v / radius_m).collect();
    squares.sort_by(f64::total_cmp);
    let lateral = fit::quantile(&squares, 0.5).max(0.3);
    let cv = (free_fit.sd / free_fit.mean.max(0.1)).min(0.5);
    let spread = 3f64.sqrt() * cv;
    let speed_factor = (1.0 - spread, 1.0 + spread);

    // Car following on the ring, desired speed from the fitted lateral acceleration.
    let mut samples = Vec::new();
    let mut groups = Vec::new();
    for (m_index, m) in measured.iter().enumerate() {
        for f in m.following.iter().filter(|f| {
            f.gap_m >= MIN_FOLLOWING_GAP_M
                && f.speed >= MIN_FOLLOWING_SPEED_MPS
                && f.accel.abs() <= 4.0
        }) {
            samples.push(FollowingSample {
                speed: f.speed,
                closing: f.closing,
                gap_m: f.gap_m,
                desired: f.fastest.max(f.speed).max(1.0),
                accel: f.accel,
            });
            groups.push(m_index * 1_000_000 + f.track as usize);
        }
    }
    if samples.len() < MIN_FOLLOWING_SAMPLES {
        return Err(format!(
            "only {} car-following samples on the ring (at least {MIN_FOLLOWING_SAMPLES} needed)",
            samples.len()
        ));
    }
    let idm = fit::fit_idm(
        &samples,
        &groups,
        MIN_FOLLOWING_SAMPLES,
        IDM_BOOTSTRAP,
        seed,
    )?;

    let critical_gap = fit::fit_critical_gap(&gaps, MIN_GAP_DRIVERS, BOOTSTRAP, seed)?;
    let follow: Vec<f64> = measured
        .iter()
        .flat_map(|m| &m.entering)
        .filter_map(|e| e.follow_up_s)
        .collect();
    let follow_up = fit::fit_mean(&follow)
        .map_err(|_| "no follow-up headway (no queue discharged at any entry)".to_owned())?;
    let at_line: Vec<f64> = measured
        .iter()
        .flat_map(|m| &m.entering)
        .map(|e| e.speed_at_line_mps)
        .collect();
    let approach = fit::fit_mean(&at_line).map_err(|e| format!("speeds at the line: {e}"))?;

    // Sizes.
    let lengths: Vec<f64> = measured
        .iter()
        .flat_map(|m| m.sizes.iter().map(|s| s.0))
        .collect();
    let widths: Vec<f64> = measured
        .iter()
        .flat_map(|m| m.sizes.iter().map(|s| s.1))
        .collect();
    let length = fit::fit_mean(&lengths).map_err(|e| format!("vehicle lengths: {e}"))?;
    let width = fit::fit_mean(&widths).map_err(|e| format!("vehicle widths: {e}"))?;
    let uniform = |m: &MeanFit, lo: f64| {
        let half = 3f64.sqrt() * m.sd;
        Span {
            passive: (m.mean - half).max(lo),
            aggressive: m.mean + half,
        }
    };

    // The uncalibrated world's spread across aggressiveness, round the fitted middle.
    let d = base.drivers;
    let around = |span: Span, middle: f64| {
        let mid = span.at(0.5);
        Span {
            passive: middle * span.passive / mid,
            aggressive: middle * span.aggressive / mid,
        }
    };
    // A fit that ends on a bound of its search box is not identified by the data: the world
    // keeps its own car following then (the report says so).
    let idm_identified = !on_bound(&idm);
    let mut traffic = base.clone();
    traffic.decision_distance_m = DECISION_DISTANCE_M;
    traffic.spawn_clearance_m = SPAWN_CLEARANCE_M;
    traffic.vehicle_length_m = uniform(&length, 2.5);
    traffic.vehicle_width_m = uniform(&width, 1.4);
    traffic.drivers.speed_factor = Span {
        passive: speed_factor.0,
        aggressive: speed_factor.1,
    };
    if idm_identified {
        traffic.drivers.max_accel_mps2 = around(d.max_accel_mps2, idm.max_accel_mps2);
        traffic.drivers.comfort_decel_mps2 = around(d.comfort_decel_mps2, idm.comfort_decel_mps2);
        traffic.drivers.time_headway_s = around(d.time_headway_s, idm.time_headway_s);
        traffic.drivers.min_gap_m = around(d.min_gap_m, idm.min_gap_m);
    }
    traffic.drivers.critical_gap = GapAcceptance::Measured(CriticalGap {
        median_s: critical_gap.median_s,
        sigma: critical_gap.sigma,
    });
    traffic.capacity = Some(CapacityModel {
        critical_gap_s: critical_gap.median_s,
        follow_up_s: follow_up.mean,
    });
    let layout = LayoutConfig {
        lateral_accel_mps2: lateral,
        ..base_layout
    };
    Ok(Calibration {
        traffic,
        layout,
        report: CalibrationReport {
            recordings: measured.len(),
            minutes,
            roundabout,
            radius_m,
            free_circulating_speed: free_fit,
            circulating_speed: all_fit,
            lateral_accel_mps2: lateral,
            speed_factor,
            approach_speed_at_line: approach,
            idm,
            idm_identified,
            critical_gap,
            follow_up_headway: follow_up,
            vehicle_length_m: length,
            vehicle_width_m: width,
            entry_flows_vph: crate::measure::entry_flows_vph(measured),
            flows,
            refinement: None,
        },
    })
}

/// Each entering driver's accepted gap and largest rejected gap, over every recording.
pub fn gap_observations(measured: &[Measurements]) -> Vec<fit::GapObservation> {
    measured
        .iter()
        .flat_map(|m| &m.entering)
        .filter_map(|e| {
            Some(fit::GapObservation {
                accepted_s: e.accepted_s?,
                max_rejected_s: e.rejected_s.iter().copied().reduce(f64::max),
            })
        })
        .filter(|g| g.accepted_s > 0.0)
        .collect()
}

/// Whether any IDM parameter ended on the bounds [`fit::fit_idm`] searches within.
fn on_bound(idm: &IdmFit) -> bool {
    let near = |x: f64, lo: f64, hi: f64| (x - lo).abs() < 1e-3 || (x - hi).abs() < 1e-3;
    near(idm.max_accel_mps2, 0.3, 5.0)
        || near(idm.comfort_decel_mps2, 0.3, 6.0)
        || near(idm.time_headway_s, 0.3, 4.0)
        || near(idm.min_gap_m, 0.5, 6.0)
}

/// The calibration as a `--config` file: `[traffic]`, `[traffic.drivers]` and `[layout]`
/// with each figure's fit in a comment, and the recorded flows in `[recorded]`.
pub fn to_toml(c: &Calibration, source: &str, recordings: &[String]) -> String {
    let r = &c.report;
    let t = &c.traffic;
    let d = &t.drivers;
    let span = |s: Span| {
        format!(
            "{{ passive = {:.3}, aggressive = {:.3} }}",
            s.passive, s.aggressive
        )
    };
    let ci = |x: (f64, f64)| format!("[{:.2}, {:.2}]", x.0, x.1);
    let g = &r.critical_gap;
    let mut out = String::new();
    out += &format!(
        "# The world's traffic calibrated by `pipeline sim calibrate` on {} recording(s), {:.1} minutes, of\n\
         # roundabout {} (radius {:.1} m) of {source}: {}.\n\
         # Every figure's fit with its 95 % interval is in the companion JSON. Give this file as --config.\n\n",
        r.recordings,
        r.minutes,
        r.roundabout,
        r.radius_m,
        recordings.join(", ")
    );
    out += "[layout]\n";
    out += &format!(
        "# direct estimate: median v^2/r of freely circulating vehicles ({} of them, mean speed {:.2} m/s,\n\
         # 95 % {}): {:.3} m/s^2\n",
        r.free_circulating_speed.n,
        r.free_circulating_speed.mean,
        ci(r.free_circulating_speed.ci95),
        r.lateral_accel_mps2
    );
    if let Some(f) = &r.refinement {
        out += &format!(
            "# matched by simulation: the world's median circulating speed {:.2} m/s against the recordings' {:.2}\n",
            f.sim_circulating_p50, f.real_circulating_p50
        );
    }
    out += &format!(
        "lateral_accel_mps2 = {:.3}\n\n",
        c.layout.lateral_accel_mps2
    );
    out += "[traffic]\n";
    out += &format!(
        "# vehicle lengths: mean {:.2} m, sd {:.2} ({} vehicles); widths: mean {:.2} m, sd {:.2}\n\
         vehicle_length_m = {}\nvehicle_width_m = {}\n\
         # the named traffic levels are fractions of the entries' capacity from the drivers' critical gap\n\
         # and follow-up headway (both as measured)\n\
         capacity = {{ critical_gap_s = {:.3}, follow_up_s = {:.3} }}\n\
         # drivers judge gaps from this far before their line, and arrivals enter behind a queue\n\
         # with this much room (not fitted)\n\
         decision_distance_m = {:.1}\nspawn_clearance_m = {:.1}\n\n",
        r.vehicle_length_m.mean,
        r.vehicle_length_m.sd,
        r.vehicle_length_m.n,
        r.vehicle_width_m.mean,
        r.vehicle_width_m.sd,
        span(t.vehicle_length_m),
        span(t.vehicle_width_m),
        t.capacity.map_or(f64::NAN, |c| c.critical_gap_s),
        t.capacity.map_or(f64::NAN, |c| c.follow_up_s),
        t.decision_distance_m,
        t.spawn_clearance_m
    );
    out += "[traffic.drivers]\n";
    out += &format!(
        "# free circulating speeds spread uniformly with their coefficient of variation\n\
         speed_factor = {}\n",
        span(d.speed_factor)
    );
    out += &format!(
        "# IDM by least squares on {} car-following samples of {} vehicles on the ring (rmse {:.2} m/s^2);\n\
         # at aggressiveness 0.5: a {:.2} {}, b {:.2} {}, T {:.2} {}, s0 {:.2} {}\n",
        r.idm.samples,
        r.idm.vehicles,
        r.idm.rmse_mps2,
        r.idm.max_accel_mps2,
        ci(r.idm.ci95[0]),
        r.idm.comfort_decel_mps2,
        ci(r.idm.ci95[1]),
        r.idm.time_headway_s,
        ci(r.idm.ci95[2]),
        r.idm.min_gap_m,
        ci(r.idm.ci95[3])
    );
    if !r.idm_identified {
        out +=
            "# (the fit ended on a bound of its search box: not identified by these recordings; the
# uncalibrated world's car following is kept)
";
    }
    out += &format!(
        "max_accel_mps2 = {}\ncomfort_decel_mps2 = {}\ntime_headway_s = {}\nmin_gap_m = {}\n",
        span(d.max_accel_mps2),
        span(d.comfort_decel_mps2),
        span(d.time_headway_s),
        span(d.min_gap_m)
    );
    out += &format!(
        "# critical gap, lognormal by maximum likelihood (Troutbeck 1992) over {} drivers ({} rejected a gap):\n\
         # median {:.2} s {}, mean {:.2} s, sd {:.2} s, sigma {:.3} {}\n\
         # follow-up headway (measured, not a parameter): mean {:.2} s, sd {:.2}, n {}, 95 % {}\n\
         {}critical_gap = {{ median_s = {:.3}, sigma = {:.4} }}\n",
        g.drivers,
        g.with_rejections,
        g.median_s,
        ci(g.median_ci95_s),
        g.mean_s,
        g.sd_s,
        g.sigma,
        ci(g.sigma_ci95),
        r.follow_up_headway.mean,
        r.follow_up_headway.sd,
        r.follow_up_headway.n,
        ci(r.follow_up_headway.ci95),
        r.refinement.as_ref().map_or(String::new(), |f| format!(
            "# median matched by simulation: the world's traffic, measured and fitted alike, gives {:.2} s\n",
            f.sim_critical_gap_s
        )),
        d.critical_gap.measured().map_or(g.median_s, |x| x.median_s),
        g.sigma
    );
    out += "\n# The recordings' own arrival flows on this map's entry lanes, veh/h (`--traffic recorded`).\n[recorded]\n";
    out += &format!("roundabout = {}\nflows = [\n", r.roundabout);
    for f in &r.flows {
        let exits: Vec<String> = f
            .exits
            .iter()
            .map(|x| format!("{{ lane = {}, share = {:.3} }}", x.lane, x.share))
            .collect();
        out += &format!(
            "    {{ lane = {}, vph = {:.1}, exits = [{}] }},\n",
            f.lane,
            f.vph,
            exits.join(", ")
        );
    }
    out += "]\n";
    out
}

/// Simulated minutes are run per recording in [`refine`], after this warm-up, s.
const REFINE_WARM_UP_S: f64 = 120.0;
/// [`refine`] simulates this many times as long as the recordings (less sampling noise on
/// the world's side).
const REFINE_LENGTH: f64 = 2.0;
/// Halvings of each search interval in [`refine`].
const REFINE_STEPS: usize = 7;

/// What [`refine`] found: each effective parameter with the simulated statistic it matched.
#[derive(Debug, Clone, Serialize)]
pub struct Refinement {
    /// The layout's lateral acceleration that makes the world's median circulating speed the
    /// recordings' (the world's routes bend tighter than the ring's radius at entries and
    /// exits, so the direct fit above underestimates it), m/s².
    pub lateral_accel_mps2: f64,
    pub real_circulating_p50: f64,
    pub sim_circulating_p50: f64,
    /// The drivers' median critical gap that makes the critical gap estimated from the
    /// world's traffic (measured and fitted as the recordings are) the recordings' estimate, s.
    pub critical_gap_median_s: f64,
    pub real_critical_gap_s: f64,
    pub sim_critical_gap_s: f64,
}

/// Simulation-based calibration of the two parameters whose direct estimates the world does
/// not reproduce as measured (indirect inference, one parameter at a time by bisection): the
/// lateral acceleration against the median circulating speed, then the median critical gap
/// against the Troutbeck estimate from the world's own traffic. Runs the world on the
/// recordings' roundabout with their flows, one run per recording, [`REFINE_LENGTH`] times as
/// long.
#[allow(clippy::too_many_arguments)]
pub fn refine(
    calibration: &mut Calibration,
    map: &maps::Map,
    geometry: &crate::measure::RingGeometry,
    measured: &[Measurements],
    seed: u64,
    mut step: impl FnMut(&str),
) -> Result<Refinement, String> {
    use rayon::prelude::*;
    let flows = calibration.report.flows.clone();
    let run =
        |traffic: &TrafficConfig, layout: &LayoutConfig| -> Result<Vec<Measurements>, String> {
            measured
                .par_iter()
                .enumerate()
                .map(|(k, m)| {
                    let s = crate::simulate::simulate(
                        map,
                        geometry.roundabout,
                        traffic,
                        layout,
                        m.duration_s * REFINE_LENGTH,
                        REFINE_WARM_UP_S,
                        sim::seed::derive_seed(seed, 0x5245_4649, k as u64),
                    )?;
                    Ok(crate::measure::measure(geometry, &s.frames))
                })
                .collect()
        };
    let median = |xs: Vec<f64>| {
        let mut xs = xs;
        xs.sort_by(f64::total_cmp);
        fit::quantile(&xs, 0.5)
    };
    let circulating = |ms: &[Measurements]| {
        median(
            ms.iter()
                .flat_map(|m| m.circulating.iter().map(|c| c.0))
                .collect(),
        )
    };
    let troutbeck = |ms: &[Measurements]| -> Result<f64, String> {
        Ok(fit::fit_critical_gap(&gap_observations(ms), MIN_GAP_DRIVERS, 0, seed)?.median_s)
    };
    let real_speed = circulating(measured);
    let real_gap = calibration.report.critical_gap.median_s;
    let mut traffic = calibration.traffic.clone();
    traffic.flows = flows;
    traffic.level = TrafficLevel::Recorded;
    let mut layout = calibration.layout;
    let mut sim_speed = f64::NAN;
    let mut sim_gap = f64::NAN;
    for round in 0..2 {
        step(&format!(
            "matching the circulating speed (round {})",
            round + 1
        ));
        let (mut lo, mut hi) = (0.5, 15.0);
        for _ in 0..REFINE_STEPS {
            layout.lateral_accel_mps2 = (lo + hi) / 2.0;
            sim_speed = circulating(&run(&traffic, &layout)?);
            if sim_speed < real_speed {
                lo = layout.lateral_accel_mps2;
            } else {
                hi = layout.lateral_accel_mps2;
            }
        }
        layout.lateral_accel_mps2 = (lo + hi) / 2.0;
        step(&format!("matching the critical gap (round {})", round + 1));
        let sigma = calibration.report.critical_gap.sigma;
        let (mut lo, mut hi) = (0.5, 15.0);
        for _ in 0..REFINE_STEPS {
            let mid = (lo + hi) / 2.0;
            traffic.drivers.critical_gap = GapAcceptance::Measured(CriticalGap {
                median_s: mid,
                sigma,
            });
            sim_gap = troutbeck(&run(&traffic, &layout)?)?;
            if sim_gap < real_gap {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        traffic.drivers.critical_gap = GapAcceptance::Measured(CriticalGap {
            median_s: (lo + hi) / 2.0,
            sigma,
        });
    }
    traffic.flows = Vec::new();
    traffic.level = calibration.traffic.level;
    let refinement = Refinement {
        lateral_accel_mps2: layout.lateral_accel_mps2,
        real_circulating_p50: real_speed,
        sim_circulating_p50: sim_speed,
        critical_gap_median_s: traffic
            .drivers
            .critical_gap
            .measured()
            .map_or(f64::NAN, |g| g.median_s),
        real_critical_gap_s: real_gap,
        sim_critical_gap_s: sim_gap,
    };
    calibration.traffic = traffic;
    calibration.layout = layout;
    calibration.report.refinement = Some(refinement.clone());
    Ok(refinement)
}
