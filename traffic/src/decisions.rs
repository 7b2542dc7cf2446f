//! What real drivers decided at roundabout entries: each vehicle's approach to a yield
//! line, every frame labelled go or wait from what the driver then did.
//!
//! An approach is the part of a track before it crosses a roundabout's yield line towards
//! the ring, up to `approach_m` of driving before the line, when it spans at least
//! `min_approach_s` ([`APPROACH_DEFINITION`]); `replay eval` labels these and `replay gaps`
//! takes the same approaches' drivers. Its frames are labelled:
//! - when the driver stopped (speed under `stop_mps`) before the line: wait from the onset
//!   of the braking that ended in the first stop up to the last stopped frame, ambiguous for
//!   `decision_s` after it (the moment the driver decided to go is not seen exactly), go
//!   afterwards. Frames before that braking began are ambiguous too: the driver was still
//!   rolling on towards the line, and whether a gap would come before they reached it was
//!   not yet decided in anything a frame shows (`wait_from`; the issue's wait is "stopped /
//!   braking to stop before the line");
//! - when the driver slowed to a crawl (under `crawl_mps`) without stopping: ambiguous up
//!   to the slowest frame (yielding or just braking for the curve?), go afterwards;
//! - otherwise go throughout.
//!
//! A wait frame in which another vehicle stands right ahead of the driver (within
//! `queue_gap_m` of its front, in its lane) is `Queued` instead: the driver waited behind
//! a car, not for a gap in the ring, and no entry decision was made. Queued and ambiguous
//! frames are counted, not scored.

use maps::Map;
use maps::geometry::Point;
use serde::{Deserialize, Serialize};

use logs::project::{LogFrame, central_speeds};

/// A driver's decision at one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Decision {
    Go,
    Wait,
    Ambiguous,
    /// Stopped behind another vehicle.
    Queued,
}

/// The labelling thresholds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LabelConfig {
    /// Driving before the yield line that counts as the approach, m.
    pub approach_m: f64,
    /// Below this the vehicle is stopped, m/s.
    pub stop_mps: f64,
    /// Below this (without stopping) the driver may have been yielding, m/s.
    pub crawl_mps: f64,
    /// Frames this long after the last stop are ambiguous, s.
    pub decision_s: f64,
    /// Approaches shorter than this are dropped (a track that starts at the line has no
    /// approach, in `replay eval` and `replay gaps` alike), s.
    pub min_approach_s: f64,
    /// A vehicle whose centre is this far ahead of the driver's centre or less (and
    /// within half a lane sideways) makes a wait frame queued, m.
    pub queue_gap_m: f64,
    /// Where the wait frames of an approach with a stop begin.
    pub wait_from: WaitFrom,
    /// With `wait_from = "braking"`: the braking begins at the last frame before the first
    /// stop whose speed is within this of the fastest frame before that stop, m/s.
    pub braking_drop_mps: f64,
}

/// Where the wait frames of an approach that stops before the line begin.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WaitFrom {
    /// At the onset of the braking that ends in the first stop; earlier frames are
    /// ambiguous.
    Braking,
    /// At the approach's first frame (the labels before 2026-11-26).
    ApproachStart,
}

impl Default for LabelConfig {
    fn default() -> Self {
        LabelConfig {
            approach_m: 30.0,
            stop_mps: 0.5,
            crawl_mps: 2.0,
            decision_s: 1.0,
            min_approach_s: 1.0,
            queue_gap_m: 8.0,
            wait_from: WaitFrom::Braking,
            braking_drop_mps: 0.5,
        }
    }
}

/// What an approach is, in the words of the reports that count them (`replay.json` and
/// `gaps.json` carry it beside their counts).
pub const APPROACH_DEFINITION: &str = "a track's first crossing of a yield line of a \
roundabout towards its ring, with at least min_approach_s of the track within approach_m of \
driving before the line (labels / [logs.decisions]); a track first seen nearer the line has \
no approach";

/// One vehicle's approach to a yield line.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Approach {
    pub track: u32,
    pub roundabout: u64,
    /// Log frame indices of the approach, in time order.
    pub frames: Vec<usize>,
    pub labels: Vec<Decision>,
    /// Speeds at those frames, m/s.
    pub speeds: Vec<f64>,
    /// The log frame at which the track crossed the line.
    pub crossed_at: usize,
    pub stopped: bool,
}

/// Whether segments ab and cd cross (strictly).
pub(crate) fn crosses(a: Point, b: Point, c: Point, d: Point) -> bool {
    let side = |p: Point, q: Point, r: Point| q.sub(p).cross(r.sub(p));
    let (d1, d2) = (side(c, d, a), side(c, d, b));
    let (d3, d4) = (side(a, b, c), side(a, b, d));
    d1 * d2 < 0.0 && d3 * d4 < 0.0
}

/// The approaches of every track of `frames` to the yield lines of `map`'s roundabouts.
pub fn approaches(map: &Map, frames: &[LogFrame], config: &LabelConfig) -> Vec<Approach> {
    // Per track: (log frame, time, position).
    let mut tracks: std::collections::BTreeMap<u32, Vec<(usize, u64, Point)>> =
        std::collections::BTreeMap::new();
    for (k, f) in frames.iter().enumerate() {
        for a in &f.actors {
            tracks
                .entry(a.id)
                .or_default()
                .push((k, f.time_ns, a.position));
        }
    }
    let lines: Vec<(u64, Point, &[Point])> = map
        .roundabouts
        .values()
        .flat_map(|r| {
            r.yield_lines
                .iter()
                .filter_map(|id| map.stop_lines.get(id))
                .map(move |s| (u64::from(r.id.0), r.centre, s.line.as_slice()))
        })
        .collect();
    let mut out = Vec::new();
    for (track, points) in &tracks {
        let speeds = central_speeds(&points.iter().map(|p| (p.1, p.2)).collect::<Vec<_>>());
        // The first crossing of a yield line towards its ring.
        let crossing = points.windows(2).enumerate().find_map(|(j, w)| {
            let (a, b) = (w[0].2, w[1].2);
            lines.iter().find_map(|(roundabout, centre, line)| {
                let towards = b.distance(*centre) < a.distance(*centre);
                let hit = line.windows(2).any(|l| crosses(a, b, l[0], l[1]));
                (towards && hit).then_some((j + 1, *roundabout))
            })
        });
        let Some((cross, roundabout)) = crossing else {
            continue;
        };
        // Back from the crossing while within approach_m of driving.
        let mut start = cross;
        let mut driven = 0.0;
        while start > 0 {
            driven += points[start].2.distance(points[start - 1].2);
            if driven > config.approach_m {
                break;
            }
            start -= 1;
        }
        let span_s = (points[cross].1.saturating_sub(points[start].1)) as f64 * 1e-9;
        if cross <= start || span_s < config.min_approach_s {
            continue;
        }
        let range = start..cross;
        let v: Vec<f64> = speeds[range.clone()].to_vec();
        let t: Vec<f64> = points[range.clone()]
            .iter()
            .map(|p| p.1 as f64 * 1e-9)
            .collect();
        let last_stop = v.iter().rposition(|s| *s < config.stop_mps);
        let wait_start = braking_onset(&v, config);
        let labels: Vec<Decision> = match last_stop {
            Some(stop) => (0..v.len())
                .map(|i| {
                    if i < wait_start {
                        Decision::Ambiguous
                    } else if i <= stop {
                        Decision::Wait
                    } else if t[i] - t[stop] <= config.decision_s {
                        Decision::Ambiguous
                    } else {
                        Decision::Go
                    }
                })
                .collect(),
            None => {
                let slowest = (0..v.len())
                    .min_by(|a, b| v[*a].total_cmp(&v[*b]))
                    .unwrap_or(0);
                (0..v.len())
                    .map(|i| {
                        if v[slowest] < config.crawl_mps && i <= slowest {
                            Decision::Ambiguous
                        } else {
                            Decision::Go
                        }
                    })
                    .collect()
            }
        };
        let mut labels = labels;
        for (label, p) in labels.iter_mut().zip(&points[range.clone()]) {
            if *label == Decision::Wait && has_leader(&frames[p.0], *track, config.queue_gap_m) {
                *label = Decision::Queued;
            }
        }
        out.push(Approach {
            track: *track,
            roundabout,
            frames: points[range].iter().map(|p| p.0).collect(),
            labels,
            speeds: v,
            crossed_at: points[cross].0,
            stopped: last_stop.is_some(),
        });
    }
    out
}

/// The first wait frame of an approach with speeds `v`: with [`WaitFrom::Braking`], the last
/// frame before the first stop still within `braking_drop_mps` of the fastest frame before
/// it (from there the driver slowed until stopping); 0 otherwise, or without a stop.
fn braking_onset(v: &[f64], config: &LabelConfig) -> usize {
    let Some(first_stop) = v.iter().position(|s| *s < config.stop_mps) else {
        return 0;
    };
    if config.wait_from == WaitFrom::ApproachStart || first_stop == 0 {
        return 0;
    }
    let peak = v[..first_stop].iter().copied().fold(f64::MIN, f64::max);
    v[..first_stop]
        .iter()
        .rposition(|s| *s >= peak - config.braking_drop_mps)
        .unwrap_or(0)
}

/// Whether another vehicle stands right ahead of `track` in `frame`.
fn has_leader(frame: &LogFrame, track: u32, gap_m: f64) -> bool {
    let Some(me) = frame.actors.iter().find(|a| a.id == track) else {
        return false;
    };
    let (s, c) = me.heading_rad.sin_cos();
    frame.actors.iter().filter(|a| a.id != track).any(|a| {
        let d = a.position.sub(me.position);
        let ahead = d.x * c + d.y * s;
        let side = -d.x * s + d.y * c;
        ahead > 0.0 && ahead <= gap_m && side.abs() <= 1.75
    })
}

/// Vehicles this close to the ring's centre line (in distance from the roundabout's
/// centre) count as circulating, m.
const RING_HALF_WIDTH_M: f64 = 4.0;

/// Distance from `track` to the nearest other vehicle on a roundabout's ring, m.
pub fn nearest_circulating(map: &Map, frame: &LogFrame, track: u32) -> f64 {
    let Some(me) = frame.actors.iter().find(|a| a.id == track) else {
        return f64::INFINITY;
    };
    frame
        .actors
        .iter()
        .filter(|a| a.id != track)
        .filter(|a| {
            map.roundabouts
                .values()
                .any(|r| (a.position.distance(r.centre) - r.radius_m).abs() <= RING_HALF_WIDTH_M)
        })
        .map(|a| a.position.distance(me.position))
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wait_frames_begin_where_the_braking_to_the_first_stop_began() {
        // Cruising near 8 m/s, braking from frame 4, stopped at 9-10, creeping, stopped
        // again at 12, then away.
        let v = [
            7.8, 8.0, 7.7, 7.9, 7.6, 7.0, 5.0, 3.0, 1.0, 0.2, 0.1, 0.8, 0.3, 2.0, 4.0,
        ];
        let config = LabelConfig::default();
        // Frame 4 is the last within 0.5 m/s of the 8.0 peak before the first stop.
        assert_eq!(braking_onset(&v, &config), 4);
        let from_start = LabelConfig {
            wait_from: WaitFrom::ApproachStart,
            ..LabelConfig::default()
        };
        assert_eq!(braking_onset(&v, &from_start), 0);
        // No stop, or stopped from the first frame: nothing before the wait frames.
        assert_eq!(braking_onset(&[8.0, 6.0, 4.0, 3.0], &config), 0);
        assert_eq!(braking_onset(&[0.1, 0.2, 3.0], &config), 0);
    }

    #[test]
    fn segments_cross_only_when_they_do() {
        let p = Point::new;
        assert!(crosses(
            p(0.0, -1.0),
            p(0.0, 1.0),
            p(-1.0, 0.0),
            p(1.0, 0.0)
        ));
        assert!(!crosses(
            p(0.0, 0.5),
            p(0.0, 1.0),
            p(-1.0, 0.0),
            p(1.0, 0.0)
        ));
        assert!(!crosses(
            p(2.0, -1.0),
            p(2.0, 1.0),
            p(-1.0, 0.0),
            p(1.0, 0.0)
        ));
    }
}
