//! Gaps offered to drivers at roundabout entries, and what they did with them: the measure
//! traffic engineers use for entry decisions (`pipeline replay gaps` scores policies on it).
//!
//! At a yield line a driver is offered a sequence of gaps in the circulating stream: the lag
//! from its arrival to the first conflicting vehicle passing its merge point, then each gap
//! between successive conflicting vehicles, until it enters in one ([`crate::measure`]
//! finds them: presence 10 m before the line, passes at the entry's merge angle). Each
//! offered gap is one decision, accept or reject, known from what the driver did.
//!
//! The drivers are the approaches of `replay eval` ([`crate::decisions::approaches`], with the
//! same [`LabelConfig`]) to the ring's yield lines: a vehicle that crossed a yield line with
//! less than `min_approach_s` of its track before it (first seen at the line, where the
//! recorded area ends) has no recorded arrival, so neither its lag nor the gaps it may have
//! rejected before it was seen are known; it is counted ([`RecordingGaps::without_approach`])
//! and left out. An approach whose recording ends before the outcome of any gap offered to it
//! is known gives no gap ([`RecordingGaps::approaches`] counts it all the same).
//!
//! Policies decide at the moment a gap is offered, from what is known then: the positions,
//! speeds and headings of every vehicle in that frame and the driver's own past, never a
//! later frame ([`Features`]). The gap's true length (the time to the next pass) is kept
//! for the fits and for reference, not given to the policies.
//!
//! [`offered_gaps`] lists a recording's offered gaps with their features and decisions; the
//! policies fitted and scored on them are the `judge` crate's (`judge::gaps`).

use maps::Map;
use maps::geometry::{Point, project_onto_polyline};
use serde::{Deserialize, Serialize};

use crate::decisions::{LabelConfig, approaches, nearest_circulating};
use crate::measure::{GAP_CAP_S, Measurements, RingGeometry, Sample, Track, measure, tracks, wrap};
use logs::project::LogFrame;

/// A vehicle nearer than this to the merge point along the ring is passing it now and
/// ends the previous gap rather than bounding the next, m.
const PASSING_M: f64 = 1.0;
/// Vehicles this far outside the ring's band moving round it count as joining it, m.
const RING_MARGIN_M: f64 = 3.0;
/// Arc distances beyond this count as this, m.
const DISTANCE_CAP_M: f64 = 60.0;
/// Speeds below this are taken as this when estimating arrival times, m/s.
const MIN_SPEED_MPS: f64 = 1.0;
/// A vehicle moving away from the centre faster than this is turning out to leave, m/s.
pub const LEAVING_MPS: f64 = 0.5;
/// A sample this close in time to a decision counts as the vehicle's state then, s.
const SAMPLE_TOLERANCE_S: f64 = 0.15;

/// What a policy knows when a gap is offered: the frame at that moment and the driver's
/// past.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Features {
    /// Estimated time until the next conflicting vehicle reaches the merge point (its arc
    /// distance along the ring over its speed), capped at [`GAP_CAP_S`]; the cap when none
    /// is on the ring upstream, s.
    pub eta_s: f64,
    /// The same for the conflicting vehicle after it, s.
    pub second_eta_s: f64,
    /// [`Features::eta_s`] of the vehicles at most a quarter turn upstream and not turning
    /// out (moving away from the centre slower than [`LEAVING_MPS`]), s.
    pub eta_quarter_s: f64,
    /// The same within half a turn, s.
    pub eta_half_s: f64,
    /// Arc distance of the next conflicting vehicle to the merge point (capped), m.
    pub next_distance_m: f64,
    /// Its speed, m/s (0 when none).
    pub next_speed_mps: f64,
    /// Its velocity away from the ring's centre, m/s (positive while it turns out to leave).
    pub next_outward_mps: f64,
    /// Distance to the nearest vehicle on the ring from the driver (what the distance rules
    /// read), capped, m.
    pub nearest_m: f64,
    /// Circulating vehicles upstream within [`DISTANCE_CAP_M`] of the merge point.
    pub upstream: u32,
    /// The driver's speed, m/s.
    pub own_speed_mps: f64,
    /// The driver's distance to its yield line, m.
    pub own_distance_m: f64,
    /// The time the driver needs to its line at its speed (at least [`MIN_SPEED_MPS`]),
    /// capped at [`GAP_CAP_S`], s.
    pub own_eta_s: f64,
    /// Time since the driver was at the line, s.
    pub waited_s: f64,
    /// Gaps it rejected before this one.
    pub rejected_before: u32,
}

impl Features {
    /// Names of [`Features::vector`]'s entries.
    pub const NAMES: [&'static str; 16] = [
        "eta_s",
        "ln_eta",
        "second_eta_s",
        "eta_quarter_s",
        "eta_half_s",
        "next_distance_m",
        "next_speed_mps",
        "next_outward_mps",
        "nearest_m",
        "upstream",
        "own_speed_mps",
        "own_distance_m",
        "own_eta_s",
        "margin_s",
        "waited_s",
        "rejected_before",
    ];

    /// How much sooner the driver could reach its line than the next conflicting vehicle
    /// its merge point, s.
    pub fn margin_s(&self) -> f64 {
        self.eta_s - self.own_eta_s
    }

    /// The features as the classifier's inputs, in [`Features::NAMES`]' order.
    pub fn vector(&self) -> [f64; 16] {
        [
            self.eta_s,
            self.eta_s.max(0.05).ln(),
            self.second_eta_s,
            self.eta_quarter_s,
            self.eta_half_s,
            self.next_distance_m,
            self.next_speed_mps,
            self.next_outward_mps,
            self.nearest_m,
            f64::from(self.upstream),
            self.own_speed_mps,
            self.own_distance_m,
            self.own_eta_s,
            self.margin_s(),
            self.waited_s,
            f64::from(self.rejected_before),
        ]
    }
}

/// One gap offered to one driver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OfferedGap {
    /// The recording's name.
    pub recording: String,
    /// The driver's track id.
    pub track: u32,
    /// Index into the ring's entries.
    pub entry: usize,
    /// 0 for the lag, then 1, 2, … for the gaps after each pass.
    pub index: u32,
    /// When it was offered, s from the recording's first frame.
    pub offered_s: f64,
    /// Its true length (to the next pass), capped at [`GAP_CAP_S`], s: for the fits, never
    /// a policy's input.
    pub length_s: f64,
    pub accepted: bool,
    pub features: Features,
}

/// One recording's gaps and what else the report gives of it.
#[derive(Debug, Clone, Default)]
pub struct RecordingGaps {
    pub name: String,
    /// The gaps offered to the approaches' drivers.
    pub gaps: Vec<OfferedGap>,
    /// The traffic measured at the ring; its `entering` holds the approaches' drivers only
    /// (what the fits of the critical gap and the follow-up headway read), its other figures
    /// are every vehicle's.
    pub measured: Measurements,
    /// Approaches to the ring's yield lines, as `replay eval` finds them
    /// ([`crate::decisions::approaches`]): the drivers of `gaps`, and those offered no gap
    /// whose outcome the recording shows (it ends first).
    pub approaches: u64,
    /// Vehicles that crossed a yield line of the ring towards it without an approach (less
    /// than `min_approach_s` of their track before the line): left out.
    pub without_approach: u64,
}

/// Every gap offered at the yield lines of `geometry`'s ring in `frames` to the drivers of
/// the approaches to them (found with `labels`, as `replay eval` finds them). Drivers whose
/// recording ends before they entered give their rejected gaps only.
pub fn offered_gaps(
    map: &Map,
    geometry: &RingGeometry,
    name: &str,
    frames: &[LogFrame],
    labels: &LabelConfig,
) -> RecordingGaps {
    let mut measured = measure(geometry, frames);
    let approached: std::collections::BTreeSet<u32> = approaches(map, frames, labels)
        .iter()
        .filter(|a| a.roundabout == u64::from(geometry.roundabout.0))
        .map(|a| a.track)
        .collect();
    let tracks = tracks(geometry, frames);
    let t0 = frames.first().map_or(0, |f| f.time_ns);
    let entered_at: std::collections::BTreeMap<u32, usize> = measured
        .entering
        .iter()
        .map(|e| (e.track, e.entry))
        .collect();
    let mut gaps = Vec::new();
    for e in measured
        .entering
        .iter()
        .filter(|e| approached.contains(&e.track))
    {
        let Some(me) = tracks.iter().find(|t| t.id == e.track) else {
            continue;
        };
        let merge_angle = measured
            .merge_angles
            .get(e.entry)
            .copied()
            .unwrap_or(geometry.entries[e.entry].angle);
        let n = e.gap_starts_s.len();
        for (i, &start) in e.gap_starts_s.iter().enumerate() {
            let last = i + 1 == n;
            let (length_s, accepted) = match (last, e.accepted_s) {
                (false, _) => (e.rejected_s.get(i).copied().unwrap_or(0.0), false),
                (true, Some(a)) => (a, true),
                (true, None) => continue,
            };
            let Some(own) = sample_at(me, start) else {
                continue;
            };
            let frame = frame_at(frames, t0, start);
            let nearest = frame.map_or(f64::INFINITY, |f| nearest_circulating(map, f, e.track));
            let conflicting = tracks
                .iter()
                .filter(|t| t.id != e.track && entered_at.get(&t.id) != Some(&e.entry))
                .filter_map(|t| sample_at(t, start))
                .filter(|s| near_ring(geometry, s));
            let upstream: Vec<Upstream> = upstream_of(geometry, merge_angle, conflicting)
                .into_iter()
                .filter(|u| u.outward_mps < LEAVING_MPS)
                .collect();
            let own_distance_m = project_onto_polyline(&geometry.entries[e.entry].line, own.p).1;
            let next = upstream.first();
            gaps.push(OfferedGap {
                recording: name.to_owned(),
                track: e.track,
                entry: e.entry,
                index: i as u32,
                offered_s: start,
                length_s,
                accepted,
                features: Features {
                    eta_s: next.map_or(GAP_CAP_S, |u| u.eta_s),
                    second_eta_s: upstream.get(1).map_or(GAP_CAP_S, |u| u.eta_s),
                    eta_quarter_s: eta_within(&upstream, std::f64::consts::FRAC_PI_2),
                    eta_half_s: eta_within(&upstream, std::f64::consts::PI),
                    next_distance_m: next.map_or(DISTANCE_CAP_M, |u| u.distance_m),
                    next_speed_mps: next.map_or(0.0, |u| u.speed_mps),
                    next_outward_mps: next.map_or(0.0, |u| u.outward_mps),
                    nearest_m: nearest.min(DISTANCE_CAP_M),
                    upstream: upstream
                        .iter()
                        .filter(|u| u.distance_m < DISTANCE_CAP_M)
                        .count() as u32,
                    own_speed_mps: own.speed,
                    own_distance_m,
                    own_eta_s: (own_distance_m / own.speed.max(MIN_SPEED_MPS)).min(GAP_CAP_S),
                    waited_s: (start - e.at_line_s).max(0.0),
                    rejected_before: i as u32,
                },
            });
        }
    }
    let crossed = measured.entering.len();
    measured.entering.retain(|e| approached.contains(&e.track));
    RecordingGaps {
        name: name.to_owned(),
        gaps,
        without_approach: (crossed - measured.entering.len()) as u64,
        measured,
        approaches: approached.len() as u64,
    }
}

/// A circulating vehicle upstream of a merge point.
#[derive(Debug, Clone, Copy)]
struct Upstream {
    eta_s: f64,
    /// Angle round the centre to the merge point, rad.
    angle: f64,
    distance_m: f64,
    speed_mps: f64,
    outward_mps: f64,
}

/// The circulating vehicles `samples` upstream of the merge point at `merge_angle`, nearest
/// in time first (those passing it now left out).
fn upstream_of(
    geometry: &RingGeometry,
    merge_angle: f64,
    samples: impl Iterator<Item = Sample>,
) -> Vec<Upstream> {
    let tau = std::f64::consts::TAU;
    let mut out: Vec<Upstream> = samples
        .filter_map(|s| {
            let r = s.p.distance(geometry.centre);
            let ahead = (wrap(merge_angle - s.angle) * geometry.turn).rem_euclid(tau);
            let distance_m = ahead * r;
            if distance_m < PASSING_M {
                return None;
            }
            let radial = s.p.sub(geometry.centre).scale(1.0 / r.max(1e-6));
            let velocity = Point::new(s.heading.cos(), s.heading.sin()).scale(s.speed);
            Some(Upstream {
                angle: ahead,
                eta_s: (distance_m / s.speed.max(MIN_SPEED_MPS)).min(GAP_CAP_S),
                distance_m: distance_m.min(DISTANCE_CAP_M),
                speed_mps: s.speed,
                outward_mps: velocity.dot(radial),
            })
        })
        .collect();
    out.sort_by(|a, b| a.eta_s.total_cmp(&b.eta_s));
    out
}

/// Whether a vehicle's sample `s` is moving round the ring: circulating, or within
/// [`RING_MARGIN_M`] outside its band moving round in the ring's direction (merging into it
/// from an upstream entry).
fn near_ring(geometry: &RingGeometry, s: &Sample) -> bool {
    if s.on_ring {
        return true;
    }
    let offset = s.p.sub(geometry.centre);
    let r = offset.norm();
    if r < geometry.band_m.0 || r > geometry.band_m.1 + RING_MARGIN_M || r < 1e-6 {
        return false;
    }
    let tangent = Point::new(-offset.y, offset.x).scale(geometry.turn / r);
    let velocity = Point::new(s.heading.cos(), s.heading.sin()).scale(s.speed);
    velocity.dot(tangent) > MIN_SPEED_MPS
}

/// The soonest arrival among `upstream` of the vehicles at most `angle` upstream and not
/// turning out; [`GAP_CAP_S`] when none.
fn eta_within(upstream: &[Upstream], angle: f64) -> f64 {
    upstream
        .iter()
        .find(|u| u.angle <= angle && u.outward_mps < LEAVING_MPS)
        .map_or(GAP_CAP_S, |u| u.eta_s)
}

/// The track's sample at time `t` (the last at or before it, if within
/// [`SAMPLE_TOLERANCE_S`]).
fn sample_at(track: &Track, t: f64) -> Option<Sample> {
    let k = track.samples.partition_point(|s| s.t <= t + 1e-9);
    let s = *track.samples.get(k.checked_sub(1)?)?;
    (t - s.t <= SAMPLE_TOLERANCE_S).then_some(s)
}

/// The last frame at or before `t` s from `t0`.
fn frame_at(frames: &[LogFrame], t0: u64, t: f64) -> Option<&LogFrame> {
    let at = t0 + (t.max(0.0) * 1e9).round() as u64;
    let k = frames.partition_point(|f| f.time_ns <= at);
    frames.get(k.checked_sub(1)?)
}
