//! Traffic at a roundabout measured from frames of road users, recorded or simulated
//! alike: the same code reads a converted INTERACTION recording and the world's own
//! traffic, so that their figures compare like with like.
//!
//! - A vehicle **circulates** where its centre lies within the ring's band (the ring lanes'
//!   distances from the centre, 2 m either side) heading along the ring (its heading within
//!   60° of the tangent).
//! - It **enters** at an entry when its centre crosses that entry's yield line towards the
//!   centre (as [`crate::decisions`] finds approaches).
//! - A vehicle **merges** when it first circulates after crossing its line; an entry's merge
//!   angle is the mean polar angle round the centre at which its vehicles merged (the angle
//!   of the line's middle when none did).
//! - A circulating vehicle **passes** an entry when its polar angle round the centre goes
//!   past the entry's merge angle. Vehicles that entered at an entry never count as passing
//!   it.
//! - A driver is **at the line** from the moment its centre is [`PRESENCE_M`] from the
//!   line (by its own track), or from when the vehicle ahead of it at the same entry crossed
//!   the line if that is later (it is then first in the queue). The gaps it was offered are
//!   the intervals between successive passes while it was at the line (the first measured
//!   from its arrival: a lag): those that ended before it merged rejected, the one in which
//!   it merged accepted (Brilon, Koenig and Troutbeck 1999, "Useful estimation
//!   procedures for critical gaps").
//! - A **follow-up headway** is the time between two vehicles crossing the same line one
//!   after the other when the second was queued behind the first (its centre within
//!   [`QUEUE_M`] of the line as the first crossed) and no vehicle passed in between.

use std::collections::BTreeMap;

use maps::geometry::Point;
use maps::{Map, RoundaboutId};
use serde::{Deserialize, Serialize};

use crate::decisions::crosses;
use logs::project::{LogFrame, central_speeds};

/// A driver is at its yield line once its centre is this far from it or nearer, m.
pub const PRESENCE_M: f64 = 10.0;
/// A driver is queued behind the one that crossed before it when its centre is this far
/// from the line or nearer as the other crosses, m.
pub const QUEUE_M: f64 = 15.0;
/// Gaps at or above this are counted at this value (the traffic offered no constraint), s.
pub const GAP_CAP_S: f64 = 12.0;
/// The approach over which delay and stops are measured: this much driving before the line, m.
pub const APPROACH_M: f64 = 20.0;
/// Below this a vehicle has stopped, m/s.
pub const STOP_MPS: f64 = 0.5;
/// Follow-up headways longer than this are not counted (the queue had gone), s.
pub const FOLLOW_UP_MAX_S: f64 = 10.0;
/// A circulating vehicle is followed by one this far behind it along the ring or nearer
/// (bumper to bumper), m.
const FOLLOWING_MAX_GAP_M: f64 = 40.0;
/// A vehicle passing the same merge point again this soon is the same pass, s.
const REPASS_S: f64 = 1.0;
/// Half-steps of the central difference of speeds giving an acceleration.
const ACCEL_HALF_SPAN: usize = 3;

/// The ring and its entries, as the measurements need them.
#[derive(Debug, Clone, PartialEq)]
pub struct RingGeometry {
    pub roundabout: RoundaboutId,
    pub centre: Point,
    /// Mean distance of the ring lanes' centre lines from the centre, m.
    pub radius_m: f64,
    /// Distances from the centre within which a vehicle may be circulating, m.
    pub band_m: (f64, f64),
    /// +1 when traffic turns counter-clockwise round the centre, −1 clockwise.
    pub turn: f64,
    /// One per yield line of the ring, in the map's order.
    pub entries: Vec<EntryLine>,
}

/// One entry's yield line.
#[derive(Debug, Clone, PartialEq)]
pub struct EntryLine {
    pub line: Vec<Point>,
    /// The lanes whose traffic gives way there.
    pub lanes: Vec<u32>,
    /// Polar angle of the line's middle round the centre, rad.
    pub angle: f64,
}

impl RingGeometry {
    /// The geometry of roundabout `id` of `map`; an error when it has no yield line or no
    /// ring lane.
    pub fn new(map: &Map, id: RoundaboutId) -> Result<Self, String> {
        let ring = map
            .roundabouts
            .get(&id)
            .ok_or_else(|| format!("the map has no roundabout {}", id.0))?;
        let distances: Vec<f64> = ring
            .ring_lanes
            .iter()
            .filter_map(|l| map.lanes.get(l))
            .flat_map(|l| l.centre.iter().map(|p| p.distance(ring.centre)))
            .collect();
        if distances.is_empty() {
            return Err(format!("roundabout {} has no ring lane on the map", id.0));
        }
        let radius_m = distances.iter().sum::<f64>() / distances.len() as f64;
        let (lo, hi) = distances
            .iter()
            .fold((f64::MAX, f64::MIN), |(lo, hi), &d| (lo.min(d), hi.max(d)));
        let entries: Vec<EntryLine> = ring
            .yield_lines
            .iter()
            .filter_map(|s| map.stop_lines.get(s))
            .filter(|s| s.line.len() >= 2)
            .map(|s| {
                let mid = s.line[0].add(s.line[s.line.len() - 1]).scale(0.5);
                EntryLine {
                    line: s.line.clone(),
                    lanes: s.lanes.iter().map(|l| l.0).collect(),
                    angle: polar(ring.centre, mid),
                }
            })
            .collect();
        if entries.is_empty() {
            return Err(format!("roundabout {} has no yield line on the map", id.0));
        }
        Ok(RingGeometry {
            roundabout: id,
            centre: ring.centre,
            radius_m,
            band_m: ((lo - 2.0).max(0.0), hi + 2.0),
            turn: if ring.clockwise { -1.0 } else { 1.0 },
            entries,
        })
    }

    /// Whether a vehicle at `p` heading `heading` circulates.
    pub fn circulates(&self, p: Point, heading: f64) -> bool {
        let r = p.distance(self.centre);
        if r < self.band_m.0 || r > self.band_m.1 || r < 1e-6 {
            return false;
        }
        let radial = p.sub(self.centre).scale(1.0 / r);
        let along = Point::new(heading.cos(), heading.sin());
        radial.dot(along).abs() < 0.5
    }
}

/// Polar angle of `p` round `c`.
pub(crate) fn polar(c: Point, p: Point) -> f64 {
    let d = p.sub(c);
    d.y.atan2(d.x)
}

/// `a` wrapped into (−π, π].
pub(crate) fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let w = a.rem_euclid(t);
    if w > std::f64::consts::PI { w - t } else { w }
}

/// One position of a track.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Sample {
    pub(crate) t: f64,
    pub(crate) p: Point,
    pub(crate) heading: f64,
    pub(crate) speed: f64,
    accel: f64,
    pub(crate) on_ring: bool,
    /// Polar angle round the centre.
    pub(crate) angle: f64,
}

/// A track as read: length, width, and (time in ns from the first frame, position, heading)
/// per frame.
type RawTrack = (f64, f64, Vec<(u64, Point, f64)>);

/// One vehicle's track.
#[derive(Debug, Clone)]
pub(crate) struct Track {
    pub(crate) id: u32,
    length_m: f64,
    width_m: f64,
    pub(crate) samples: Vec<Sample>,
}

/// One vehicle entering the ring.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Entering {
    pub track: u32,
    /// Index into [`RingGeometry::entries`].
    pub entry: usize,
    /// When its centre crossed the line, s.
    pub crossed_s: f64,
    /// When it first circulated after that, and its polar angle round the centre then.
    pub merged: Option<(f64, f64)>,
    /// Its polar angle round the centre when it last circulated, if its track goes on
    /// beyond the ring afterwards (where it left the ring).
    pub left_angle: Option<f64>,
    pub speed_at_line_mps: f64,
    /// Whether it stopped within [`APPROACH_M`] of the line.
    pub stopped: bool,
    /// Time over the last [`APPROACH_M`] beyond what that distance takes at its speed there
    /// (or at the line, if faster); None when its track starts nearer, s.
    pub delay_s: Option<f64>,
    /// When it was first at the line (see the module docs), s.
    pub at_line_s: f64,
    /// The gap it accepted, capped at [`GAP_CAP_S`]; None when the recording ends first.
    pub accepted_s: Option<f64>,
    /// The gaps it rejected, in order.
    pub rejected_s: Vec<f64>,
    /// When each gap it was offered began: its arrival at the line (the lag), then each
    /// pass while it waited; the last is the accepted gap's (one more than `rejected_s`).
    #[serde(default)]
    pub gap_starts_s: Vec<f64>,
    /// The headway to the vehicle that crossed the line just before it, when it followed
    /// that one out of a queue.
    pub follow_up_s: Option<f64>,
}

/// One car-following instant on the ring (see [`crate::fit::FollowingSample`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Following {
    pub track: u32,
    /// The follower's fastest speed round the ring (its desired speed there, as far as the
    /// track shows), m/s.
    pub fastest: f64,
    pub speed: f64,
    pub closing: f64,
    pub gap_m: f64,
    pub accel: f64,
}

/// Everything measured in one recording (or one simulated run).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Measurements {
    /// From the first frame to the last, s.
    pub duration_s: f64,
    pub entering: Vec<Entering>,
    /// Per vehicle that circulated for at least a second: its median speed on the ring,
    /// m/s, with whether it had a vehicle ahead within 30 m most of that time.
    pub circulating: Vec<(f64, bool)>,
    pub following: Vec<Following>,
    /// Per vehicle: length and width, m.
    pub sizes: Vec<(f64, f64)>,
    /// Per entry: how many vehicles crossed its line.
    pub entries_crossed: Vec<u32>,
    /// Per entry and minute of the recording: vehicles crossing its line.
    pub per_minute: Vec<Vec<u32>>,
    /// Per entry: its merge angle round the centre, rad (see the module docs).
    #[serde(default)]
    pub merge_angles: Vec<f64>,
    /// Per entry: every pass of its merge point (time s, track), in time order.
    #[serde(default, skip_serializing)]
    pub passes: Vec<Vec<(f64, u32)>>,
}

impl Measurements {
    /// The gap a driver entering at `entry` (its track `track`, at its line from
    /// `at_line_s`) accepted by crossing its line at `crossed_s`: from the later of its
    /// arrival and the last pass before, to the first pass after, capped at [`GAP_CAP_S`];
    /// None when the recording ends first (unless the cap is reached).
    pub fn gap_at(&self, entry: usize, track: u32, at_line_s: f64, crossed_s: f64) -> Option<f64> {
        let passes: Vec<f64> = self
            .passes
            .get(entry)?
            .iter()
            .filter(|(_, id)| *id != track)
            .map(|(t, _)| *t)
            .collect();
        let start = passes
            .iter()
            .copied()
            .filter(|&t| t <= crossed_s)
            .fold(at_line_s, f64::max);
        match passes.iter().find(|&&t| t > crossed_s) {
            Some(&end) => Some((end - start).min(GAP_CAP_S)),
            None if self.duration_s - start >= GAP_CAP_S => Some(GAP_CAP_S),
            None => None,
        }
    }
}

/// Vehicles per hour crossing each entry's line, pooled over `measured`.
pub fn entry_flows_vph(measured: &[Measurements]) -> Vec<f64> {
    let seconds: f64 = measured.iter().map(|m| m.duration_s).sum();
    let n = measured
        .iter()
        .map(|m| m.entries_crossed.len())
        .max()
        .unwrap_or(0);
    (0..n)
        .map(|k| {
            let crossed: u32 = measured
                .iter()
                .filter_map(|m| m.entries_crossed.get(k))
                .sum();
            if seconds > 0.0 {
                f64::from(crossed) / seconds * 3600.0
            } else {
                0.0
            }
        })
        .collect()
}

/// Measures the traffic of `frames` at the roundabout of `geometry`.
pub fn measure(geometry: &RingGeometry, frames: &[LogFrame]) -> Measurements {
    let tracks = tracks(geometry, frames);
    let (Some(first), Some(last)) = (frames.first(), frames.last()) else {
        return Measurements::default();
    };
    let t0 = first.time_ns;
    let duration_s = (last.time_ns.saturating_sub(t0)) as f64 * 1e-9;
    let n_entries = geometry.entries.len();

    // Entries: the first crossing of a yield line towards the centre per track.
    let mut entering: Vec<Entering> = Vec::new();
    for track in &tracks {
        if let Some(e) = first_entry(geometry, track) {
            entering.push(e);
        }
    }
    entering.sort_by(|a, b| a.crossed_s.total_cmp(&b.crossed_s));
    let entered_at: BTreeMap<u32, usize> = entering.iter().map(|e| (e.track, e.entry)).collect();

    // Each entry's merge angle: the circular mean of where its vehicles merged.
    let merge_angles: Vec<f64> = (0..n_entries)
        .map(|k| {
            let (sx, sy) = entering
                .iter()
                .filter(|e| e.entry == k)
                .filter_map(|e| e.merged)
                .fold((0.0, 0.0), |(x, y), (_, a)| (x + a.cos(), y + a.sin()));
            if sx == 0.0 && sy == 0.0 {
                geometry.entries[k].angle
            } else {
                sy.atan2(sx)
            }
        })
        .collect();
    // Passes: per entry, times a circulating vehicle (not one that entered there) went by.
    let mut passes: Vec<Vec<(f64, u32)>> = vec![Vec::new(); n_entries];
    for track in &tracks {
        for w in track.samples.windows(2) {
            if !(w[0].on_ring && w[1].on_ring) {
                continue;
            }
            let step = wrap(w[1].angle - w[0].angle) * geometry.turn;
            if step <= 0.0 {
                continue;
            }
            for (k, angle) in merge_angles.iter().enumerate() {
                if entered_at.get(&track.id) == Some(&k) {
                    continue;
                }
                let to = wrap(angle - w[0].angle) * geometry.turn;
                if to >= 0.0 && to < step {
                    let f = to / step;
                    passes[k].push((w[0].t + f * (w[1].t - w[0].t), track.id));
                }
            }
        }
    }
    for p in &mut passes {
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        // A vehicle exactly at the merge angle at a sample ends one step and begins the
        // next: count it once.
        let mut last_of: BTreeMap<u32, f64> = BTreeMap::new();
        p.retain(|&(t, id)| {
            let repeat = last_of.get(&id).is_some_and(|&l| t - l < REPASS_S);
            last_of.insert(id, t);
            !repeat
        });
    }

    // Gaps and follow-up headways, entry by entry in crossing order.
    let by_id: BTreeMap<u32, &Track> = tracks.iter().map(|t| (t.id, t)).collect();
    let mut previous: Vec<Option<usize>> = vec![None; n_entries];
    for i in 0..entering.len() {
        let k = entering[i].entry;
        let ahead = previous[k];
        previous[k] = Some(i);
        let mut e = entering[i].clone();
        if let Some(j) = ahead {
            e.at_line_s = e.at_line_s.max(entering[j].crossed_s);
        }
        let mine: Vec<f64> = passes[k]
            .iter()
            .filter(|(_, id)| *id != e.track)
            .map(|(t, _)| *t)
            .collect();
        let merged_s = e.merged.map_or(e.crossed_s, |m| m.0);
        let during: Vec<f64> = mine
            .iter()
            .copied()
            .filter(|&t| t > e.at_line_s && t <= merged_s)
            .collect();
        let mut start = e.at_line_s;
        let mut rejected = Vec::new();
        let mut starts = vec![start];
        for &t in &during {
            rejected.push((t - start).min(GAP_CAP_S));
            start = t;
            starts.push(t);
        }
        e.gap_starts_s = starts;
        let next = mine.iter().find(|&&t| t > merged_s).copied();
        e.accepted_s = match next {
            Some(t) => Some((t - start).min(GAP_CAP_S)),
            None if duration_s - (start - 0.0) >= GAP_CAP_S => Some(GAP_CAP_S),
            None => None,
        };
        e.rejected_s = rejected;
        if let Some(j) = ahead {
            let lead = entering[j].crossed_s;
            let queued = by_id
                .get(&e.track)
                .and_then(|t| distance_to_line_at(t, e.crossed_s, lead))
                .is_some_and(|d| d <= QUEUE_M);
            let passed_between = mine.iter().any(|&t| t > lead && t < e.crossed_s);
            let headway = e.crossed_s - lead;
            if queued && !passed_between && headway <= FOLLOW_UP_MAX_S {
                e.follow_up_s = Some(headway);
            }
        }
        entering[i] = e;
    }

    let mut entries_crossed = vec![0u32; n_entries];
    let minutes = (duration_s / 60.0).floor().max(0.0) as usize;
    let mut per_minute = vec![vec![0u32; minutes]; n_entries];
    for e in &entering {
        entries_crossed[e.entry] += 1;
        let m = (e.crossed_s / 60.0) as usize;
        if m < minutes {
            per_minute[e.entry][m] += 1;
        }
    }

    let leaders = leaders_by_time(geometry, &tracks);
    Measurements {
        duration_s,
        circulating: circulating_speeds(&tracks, &leaders),
        following: leaders
            .values()
            .copied()
            .chain(approach_following(&tracks, &entering))
            .collect(),
        sizes: tracks.iter().map(|t| (t.length_m, t.width_m)).collect(),
        entering,
        entries_crossed,
        per_minute,
        merge_angles,
        passes,
    }
}

/// The frames' tracks near the ring, each with speeds, accelerations and ring flags; times in
/// seconds from the first frame.
pub(crate) fn tracks(geometry: &RingGeometry, frames: &[LogFrame]) -> Vec<Track> {
    let Some(first) = frames.first() else {
        return Vec::new();
    };
    let t0 = first.time_ns;
    let mut raw: BTreeMap<u32, RawTrack> = BTreeMap::new();
    for f in frames {
        let t = f.time_ns.saturating_sub(t0);
        for a in &f.actors {
            if !matches!(a.kind, sim::ActorKind::Car) {
                continue;
            }
            let entry = raw
                .entry(a.id)
                .or_insert((a.length_m, a.width_m, Vec::new()));
            entry.2.push((t, a.position, a.heading_rad));
        }
    }
    raw.into_iter()
        .filter(|(_, (_, _, s))| s.len() >= 3)
        .map(|(id, (length_m, width_m, points))| {
            let n = points.len();
            let speed = central_speeds(&points.iter().map(|p| (p.0, p.1)).collect::<Vec<_>>());
            let seconds = |j: usize| points[j].0 as f64 * 1e-9;
            let samples = (0..n)
                .map(|j| {
                    let (a, b) = (
                        j.saturating_sub(ACCEL_HALF_SPAN),
                        (j + ACCEL_HALF_SPAN).min(n - 1),
                    );
                    let dt = seconds(b) - seconds(a);
                    let accel = if dt > 0.0 {
                        (speed[b] - speed[a]) / dt
                    } else {
                        0.0
                    };
                    let (_, p, heading) = points[j];
                    Sample {
                        t: seconds(j),
                        p,
                        heading,
                        speed: speed[j],
                        accel,
                        on_ring: geometry.circulates(p, heading),
                        angle: polar(geometry.centre, p),
                    }
                })
                .collect();
            Track {
                id,
                length_m,
                width_m,
                samples,
            }
        })
        .collect()
}

/// Where and when `track` first crossed a yield line of the ring towards the centre.
fn first_entry(geometry: &RingGeometry, track: &Track) -> Option<Entering> {
    let s = &track.samples;
    let (j, k, f) = s.windows(2).enumerate().find_map(|(j, w)| {
        let (a, b) = (w[0].p, w[1].p);
        let towards = b.distance(geometry.centre) < a.distance(geometry.centre);
        if !towards {
            return None;
        }
        geometry.entries.iter().enumerate().find_map(|(k, e)| {
            e.line.windows(2).find_map(|l| {
                crosses(a, b, l[0], l[1]).then(|| (j, k, crossing_fraction(a, b, l[0], l[1])))
            })
        })
    })?;
    let crossed_s = s[j].t + f * (s[j + 1].t - s[j].t);
    let speed_at_line_mps = s[j].speed + f * (s[j + 1].speed - s[j].speed);
    // Back along the track from the crossing: driven distance of each earlier sample.
    let mut driven = vec![0.0; j + 1];
    let mut acc = s[j].p.distance(s[j].p.add(s[j + 1].p.sub(s[j].p).scale(f)));
    driven[j] = acc;
    for i in (0..j).rev() {
        acc += s[i].p.distance(s[i + 1].p);
        driven[i] = acc;
    }
    let at_line_s = (0..=j)
        .find(|&i| driven[i] <= PRESENCE_M)
        .map_or(crossed_s, |i| s[i].t);
    let from = (0..=j).rev().find(|&i| driven[i] >= APPROACH_M);
    let window = from.unwrap_or(0)..=j;
    let stopped = s[window].iter().any(|x| x.speed < STOP_MPS);
    let delay_s = from.map(|i| {
        let reference = s[i].speed.max(speed_at_line_mps).max(1.0);
        ((crossed_s - s[i].t) - driven[i] / reference).max(0.0)
    });
    let merged = s[j + 1..]
        .iter()
        .find(|x| x.on_ring)
        .map(|x| (x.t, x.angle));
    let left_angle = s[j + 1..]
        .iter()
        .rposition(|x| x.on_ring)
        .filter(|&last| j + 2 + last < s.len() && merged.is_some())
        .map(|last| s[j + 1 + last].angle);
    Some(Entering {
        track: track.id,
        entry: k,
        crossed_s,
        merged,
        left_angle,
        speed_at_line_mps,
        stopped,
        delay_s,
        at_line_s,
        accepted_s: None,
        rejected_s: Vec::new(),
        follow_up_s: None,
        gap_starts_s: Vec::new(),
    })
}

/// Where along ab the segment cd crosses it, as a fraction of ab.
fn crossing_fraction(a: Point, b: Point, c: Point, d: Point) -> f64 {
    let r = b.sub(a);
    let q = d.sub(c);
    let denom = r.cross(q);
    if denom.abs() < 1e-12 {
        return 0.5;
    }
    (c.sub(a).cross(q) / denom).clamp(0.0, 1.0)
}

/// How far (driven) `track` was from where it crossed its line at `crossed_s`, at time `t`;
/// None when the track has no sample then.
fn distance_to_line_at(track: &Track, crossed_s: f64, t: f64) -> Option<f64> {
    let s = &track.samples;
    let at = s.iter().position(|x| x.t >= t)?;
    let cross = s.iter().position(|x| x.t >= crossed_s)?;
    if at > cross {
        return Some(0.0);
    }
    Some(
        s[at..=cross]
            .windows(2)
            .map(|w| w[0].p.distance(w[1].p))
            .sum(),
    )
}

/// Per vehicle circulating for at least a second: its median speed on the ring and whether
/// it had a vehicle close ahead (within 30 m along the ring) most of that time.
fn circulating_speeds(tracks: &[Track], leaders: &Leaders) -> Vec<(f64, bool)> {
    tracks
        .iter()
        .filter_map(|t| {
            let ring: Vec<&Sample> = t.samples.iter().filter(|s| s.on_ring).collect();
            if ring.len() < 2 || ring[ring.len() - 1].t - ring[0].t < 1.0 {
                return None;
            }
            let mut speeds: Vec<f64> = ring.iter().map(|s| s.speed).collect();
            speeds.sort_by(f64::total_cmp);
            let followed = ring
                .iter()
                .filter(|s| {
                    leaders
                        .get(&(t.id, time_key(s.t)))
                        .is_some_and(|l| l.gap_m <= 30.0)
                })
                .count();
            Some((speeds[speeds.len() / 2], followed * 2 > ring.len()))
        })
        .collect()
}

fn time_key(t: f64) -> i64 {
    (t * 1000.0).round() as i64
}

/// The car-following instants on the approaches: every sample of an entering vehicle
/// before its line with another vehicle ahead in its lane (within 1.5 m of its heading line,
/// heading within 30° of it) at most [`FOLLOWING_MAX_GAP_M`] ahead, bumper to bumper.
fn approach_following(tracks: &[Track], entering: &[Entering]) -> Vec<Following> {
    let mut at: BTreeMap<i64, Vec<(usize, usize)>> = BTreeMap::new();
    for (ti, t) in tracks.iter().enumerate() {
        for si in 0..t.samples.len() {
            at.entry(time_key(t.samples[si].t))
                .or_default()
                .push((ti, si));
        }
    }
    let index: BTreeMap<u32, usize> = tracks.iter().enumerate().map(|(i, t)| (t.id, i)).collect();
    let mut out = Vec::new();
    for e in entering {
        let Some(&ti) = index.get(&e.track) else {
            continue;
        };
        let track = &tracks[ti];
        let approach: Vec<&Sample> = track.samples.iter().filter(|s| s.t < e.crossed_s).collect();
        let fastest = approach.iter().map(|s| s.speed).fold(0.0, f64::max);
        for me in approach {
            let Some(list) = at.get(&time_key(me.t)) else {
                continue;
            };
            let (sin, cos) = me.heading.sin_cos();
            let best = list
                .iter()
                .filter(|&&(tj, _)| tj != ti)
                .filter_map(|&(tj, sj)| {
                    let o = &tracks[tj].samples[sj];
                    let d = o.p.sub(me.p);
                    let ahead = d.x * cos + d.y * sin;
                    let side = -d.x * sin + d.y * cos;
                    let turn = wrap(o.heading - me.heading).abs();
                    let gap = ahead - (track.length_m + tracks[tj].length_m) / 2.0;
                    (ahead > 0.0
                        && side.abs() <= 1.5
                        && turn <= std::f64::consts::FRAC_PI_6
                        && gap > 0.3
                        && gap <= FOLLOWING_MAX_GAP_M)
                        .then_some((gap, o.speed))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((gap, lead_speed)) = best {
                out.push(Following {
                    track: track.id,
                    fastest,
                    speed: me.speed,
                    closing: me.speed - lead_speed,
                    gap_m: gap,
                    accel: me.accel,
                });
            }
        }
    }
    out
}

/// Per (track, time in ms) on the ring: the car-following instant with its nearest
/// circulating leader along the ring.
type Leaders = BTreeMap<(u32, i64), Following>;

/// The car-following instants on the ring: every circulating sample with a circulating
/// vehicle ahead within [`FOLLOWING_MAX_GAP_M`] along the ring.
fn leaders_by_time(geometry: &RingGeometry, tracks: &[Track]) -> Leaders {
    // Circulating samples by time: (track index, sample index).
    let mut at: BTreeMap<i64, Vec<(usize, usize)>> = BTreeMap::new();
    for (ti, t) in tracks.iter().enumerate() {
        for (si, s) in t.samples.iter().enumerate() {
            if s.on_ring {
                at.entry(time_key(s.t)).or_default().push((ti, si));
            }
        }
    }
    let fastest: Vec<f64> = tracks
        .iter()
        .map(|t| {
            t.samples
                .iter()
                .filter(|s| s.on_ring)
                .map(|s| s.speed)
                .fold(0.0, f64::max)
        })
        .collect();
    let mut out = BTreeMap::new();
    for (key, list) in &at {
        for &(ti, si) in list {
            let me = &tracks[ti].samples[si];
            let r = me.p.distance(geometry.centre);
            let best = list
                .iter()
                .filter(|&&(tj, _)| tj != ti)
                .filter_map(|&(tj, sj)| {
                    let other = &tracks[tj].samples[sj];
                    let ro = other.p.distance(geometry.centre);
                    if (ro - r).abs() > 2.0 {
                        return None;
                    }
                    let ahead = wrap(other.angle - me.angle) * geometry.turn;
                    if ahead <= 0.0 || ahead > std::f64::consts::FRAC_PI_2 {
                        return None;
                    }
                    let gap =
                        ahead * (r + ro) / 2.0 - (tracks[ti].length_m + tracks[tj].length_m) / 2.0;
                    (gap > 0.3 && gap <= FOLLOWING_MAX_GAP_M).then_some((gap, other.speed))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((gap, lead_speed)) = best {
                out.insert(
                    (tracks[ti].id, *key),
                    Following {
                        track: tracks[ti].id,
                        fastest: fastest[ti],
                        speed: me.speed,
                        closing: me.speed - lead_speed,
                        gap_m: gap,
                        accel: me.accel,
                    },
                );
            }
        }
    }
    out
}
