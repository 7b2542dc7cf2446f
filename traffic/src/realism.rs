//! The world against recordings, metric by metric (`pipeline sim realism`): each metric's
//! distribution measured the same way on both ([`crate::measure`]), compared by the
//! two-sample Kolmogorov–Smirnov distance and the 1-Wasserstein distance.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::fit::{self, Summary};
use crate::measure::{Measurements, entry_flows_vph};

/// The metrics, in report order: name, what it is, unit.
pub const METRICS: [(&str, &str, &str); 8] = [
    (
        "circulating_speed",
        "median speed of each vehicle round the ring",
        "m/s",
    ),
    (
        "yield_line_speed",
        "speed of each entering vehicle as it crosses its yield line",
        "m/s",
    ),
    (
        "accepted_gap",
        "the gap each entering driver took (capped at 12 s)",
        "s",
    ),
    (
        "rejected_gap",
        "every gap a driver at the line let pass",
        "s",
    ),
    (
        "follow_up_headway",
        "time between queued vehicles entering one after the other",
        "s",
    ),
    (
        "yield_line_delay",
        "time lost over the last 20 m before the yield line",
        "s",
    ),
    (
        "entry_flow",
        "vehicles entering per hour, each entry and minute",
        "veh/h",
    ),
    (
        "stopped",
        "1 for an entering vehicle that stopped before its line, 0 otherwise",
        "share",
    ),
];

/// Each metric's sample over several recordings (or runs).
pub fn samples(measured: &[Measurements]) -> BTreeMap<&'static str, Vec<f64>> {
    let mut out: BTreeMap<&'static str, Vec<f64>> =
        METRICS.iter().map(|(n, _, _)| (*n, Vec::new())).collect();
    let mut push = |name: &'static str, v: f64| {
        if let Some(s) = out.get_mut(name) {
            s.push(v);
        }
    };
    for m in measured {
        for c in &m.circulating {
            push("circulating_speed", c.0);
        }
        for e in &m.entering {
            push("yield_line_speed", e.speed_at_line_mps);
            if let Some(a) = e.accepted_s {
                push("accepted_gap", a);
            }
            for r in &e.rejected_s {
                push("rejected_gap", *r);
            }
            if let Some(f) = e.follow_up_s {
                push("follow_up_headway", f);
            }
            if let Some(d) = e.delay_s {
                push("yield_line_delay", d);
            }
            push("stopped", if e.stopped { 1.0 } else { 0.0 });
        }
        for entry in &m.per_minute {
            for count in entry {
                push("entry_flow", f64::from(*count) * 60.0);
            }
        }
    }
    out
}

/// One metric compared.
#[derive(Debug, Clone, Serialize)]
pub struct MetricReport {
    pub ks: f64,
    pub wasserstein: f64,
    pub real: Summary,
    pub sim: Summary,
}

/// Per entry (the geometry's, by yield line): vehicles per hour in the recordings and in
/// the world.
#[derive(Debug, Clone, Serialize)]
pub struct EntryFlows {
    pub real_vph: Vec<f64>,
    pub sim_vph: Vec<f64>,
}

/// `realism.json`.
#[derive(Debug, Clone, Serialize)]
pub struct RealismReport {
    pub metrics: BTreeMap<String, MetricReport>,
    pub real_minutes: f64,
    pub sim_minutes: f64,
    pub entry_flows: EntryFlows,
}

/// Compares `sim` with `real`, metric by metric.
pub fn compare(real: &[Measurements], sim: &[Measurements]) -> RealismReport {
    let (a, b) = (samples(real), samples(sim));
    let metrics = METRICS
        .iter()
        .map(|(name, _, _)| {
            let empty = Vec::new();
            let (x, y) = (a.get(name).unwrap_or(&empty), b.get(name).unwrap_or(&empty));
            (
                (*name).to_owned(),
                MetricReport {
                    ks: fit::ks_distance(x, y),
                    wasserstein: fit::wasserstein1(x, y),
                    real: fit::summary(x),
                    sim: fit::summary(y),
                },
            )
        })
        .collect();
    RealismReport {
        metrics,
        real_minutes: minutes(real),
        sim_minutes: minutes(sim),
        entry_flows: EntryFlows {
            real_vph: entry_flows_vph(real),
            sim_vph: entry_flows_vph(sim),
        },
    }
}

fn minutes(m: &[Measurements]) -> f64 {
    m.iter().map(|m| m.duration_s).sum::<f64>() / 60.0
}

/// `realism.md`: one table row per metric, then the flows per entry.
pub fn markdown(report: &RealismReport, title: &str) -> String {
    let mut out = format!(
        "# Realism: {title}\n\n{:.1} recorded minutes against {:.1} simulated.\n\n\
         | metric | unit | KS | Wasserstein | real n, mean, p10 / p50 / p90 | sim n, mean, p10 / p50 / p90 |\n\
         | --- | --- | --- | --- | --- | --- |\n",
        report.real_minutes, report.sim_minutes
    );
    for (name, what, unit) in METRICS {
        let Some(m) = report.metrics.get(name) else {
            continue;
        };
        let s = |s: &Summary| {
            format!(
                "{}, {:.2}, {:.2} / {:.2} / {:.2}",
                s.n, s.mean, s.p10, s.p50, s.p90
            )
        };
        out += &format!(
            "| {name} ({what}) | {unit} | {:.3} | {:.3} | {} | {} |\n",
            m.ks,
            m.wasserstein,
            s(&m.real),
            s(&m.sim)
        );
    }
    out += "\n| entry | real veh/h | sim veh/h |\n| --- | --- | --- |\n";
    let f = &report.entry_flows;
    for k in 0..f.real_vph.len().max(f.sim_vph.len()) {
        out += &format!(
            "| {k} | {:.0} | {:.0} |\n",
            f.real_vph.get(k).copied().unwrap_or(0.0),
            f.sim_vph.get(k).copied().unwrap_or(0.0)
        );
    }
    out
}
