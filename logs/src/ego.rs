//! The ego's track from a log, in a map's frame: from the ego-pose topic (poses taken to be
//! in the map's frame, as `logs convert` writes them) or from the GPS topic (WGS84 through the
//! map's projection), resampled to a fixed rate and matched to the map's lanes.
//!
//! - [`ego_track`]: one sample per message, in time order (headings from the pose's
//!   orientation, or from the motion for GPS fixes);
//! - [`resample`]: samples at a fixed rate, linearly interpolated between the two recorded
//!   samples around each time (headings along the shorter arc); no sample where the
//!   recording has a gap longer than `max_gap_s`;
//! - [`match_lanes`]: per sample, the lane whose centre line is nearest among those running
//!   within `max_heading_deg` of the ego's heading, with the distance to it; a match when
//!   that distance is at most half the lane's width plus `tolerance_m`.

use maps::Map;
use maps::geometry::{Point, closest_on_segment};
use maps::projection::LatLon;
use serde::{Deserialize, Serialize};

use super::decode::{Decoded, DecodedLog};
use super::foxglove::FoxgloveMessage;

/// Where the ego's positions come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EgoSource {
    /// The ego-pose topic (odometry or pose messages, in the map's frame).
    Pose,
    /// The GPS topic, through the map's projection.
    Gps,
}

/// One position of the ego.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EgoSample {
    pub time_ns: u64,
    pub position: Point,
    /// Radians, counter-clockwise from +x; None for a lone GPS fix (no motion to tell it).
    pub heading_rad: Option<f64>,
}

/// The ego's samples on `topic` of `log` from `source`, in time order. Messages of other
/// types on the topic are ignored.
pub fn ego_track(log: &DecodedLog, topic: &str, source: EgoSource, map: &Map) -> Vec<EgoSample> {
    let mut samples: Vec<EgoSample> = log
        .topic_messages(topic)
        .filter_map(|m| {
            let (position, heading) = match (&m.message, source) {
                (Decoded::Odometry(o), EgoSource::Pose) => pose_of(&o.pose.pose),
                (Decoded::PoseStamped(p), EgoSource::Pose) => pose_of(&p.pose),
                (Decoded::PoseWithCovarianceStamped(p), EgoSource::Pose) => pose_of(&p.pose.pose),
                (Decoded::Foxglove(FoxgloveMessage::PoseInFrame(p)), EgoSource::Pose) => {
                    pose_of(&p.pose)
                }
                (Decoded::NavSatFix(f), EgoSource::Gps) => (
                    map.projection.project(LatLon {
                        lat: f.latitude,
                        lon: f.longitude,
                    }),
                    None,
                ),
                (Decoded::Foxglove(FoxgloveMessage::LocationFix(f)), EgoSource::Gps) => (
                    map.projection.project(LatLon {
                        lat: f.latitude,
                        lon: f.longitude,
                    }),
                    None,
                ),
                _ => return None,
            };
            position.is_finite().then_some(EgoSample {
                time_ns: m.log_time,
                position,
                heading_rad: heading,
            })
        })
        .collect();
    samples.sort_by_key(|s| s.time_ns);
    if source == EgoSource::Gps {
        fill_headings_from_motion(&mut samples);
    }
    samples
}

fn pose_of(pose: &super::msgs::Pose) -> (Point, Option<f64>) {
    (
        Point::new(pose.position.x, pose.position.y),
        Some(pose.orientation.yaw()),
    )
}

/// Each sample's heading from the sample before and after it (the first and last from
/// their one neighbour); where the ego stood still, the heading it last moved with (before
/// it first moved: the first one it moved with).
fn fill_headings_from_motion(samples: &mut [EgoSample]) {
    let positions: Vec<Point> = samples.iter().map(|s| s.position).collect();
    for (i, sample) in samples.iter_mut().enumerate() {
        let before = positions[i.saturating_sub(1)];
        let after = positions[(i + 1).min(positions.len() - 1)];
        let d = after.sub(before);
        sample.heading_rad = (d.norm() > 1e-6).then(|| d.y.atan2(d.x));
    }
    let mut last = None;
    for sample in samples.iter_mut() {
        last = sample.heading_rad.or(last);
        sample.heading_rad = last;
    }
    let first = samples.iter().find_map(|s| s.heading_rad);
    for sample in samples.iter_mut().take_while(|s| s.heading_rad.is_none()) {
        sample.heading_rad = first;
    }
}

/// What resampling did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct ResampleReport {
    pub recorded: usize,
    pub resampled: usize,
    /// Times left out because the recording had a gap there.
    pub in_gaps: usize,
}

/// `samples` (in time order) at `rate_hz` from the first sample's time to the last's.
pub fn resample(
    samples: &[EgoSample],
    rate_hz: f64,
    max_gap_s: f64,
) -> (Vec<EgoSample>, ResampleReport) {
    let mut out = Vec::new();
    let mut in_gaps = 0;
    if let (Some(first), Some(last)) = (samples.first(), samples.last())
        && rate_hz > 0.0
    {
        let step_ns = 1e9 / rate_hz;
        let max_gap_ns = (max_gap_s * 1e9) as u64;
        let mut j = 0;
        let mut k = 0u64;
        loop {
            let t = first.time_ns + (k as f64 * step_ns).round() as u64;
            if t > last.time_ns {
                break;
            }
            k += 1;
            while j + 1 < samples.len() && samples[j + 1].time_ns < t {
                j += 1;
            }
            let a = samples[j];
            let b = samples.get(j + 1).copied().unwrap_or(a);
            // A time on a recorded sample is that sample, gap or not.
            if let Some(exact) = [a, b].into_iter().find(|s| s.time_ns == t) {
                out.push(exact);
                continue;
            }
            if b.time_ns.saturating_sub(a.time_ns) > max_gap_ns {
                in_gaps += 1;
                continue;
            }
            let span = b.time_ns.saturating_sub(a.time_ns);
            let f = if span == 0 {
                0.0
            } else {
                (t.saturating_sub(a.time_ns) as f64 / span as f64).clamp(0.0, 1.0)
            };
            out.push(EgoSample {
                time_ns: t,
                position: a.position.lerp(b.position, f),
                heading_rad: match (a.heading_rad, b.heading_rad) {
                    (Some(ha), Some(hb)) => Some(ha + wrap_angle(hb - ha) * f),
                    (h, None) | (None, h) => h,
                },
            });
        }
    }
    let report = ResampleReport {
        recorded: samples.len(),
        resampled: out.len(),
        in_gaps,
    };
    (out, report)
}

/// `a` in (−π, π].
fn wrap_angle(a: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    let r = a.rem_euclid(tau);
    if r > std::f64::consts::PI { r - tau } else { r }
}

/// Thresholds of [`match_lanes`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchConfig {
    /// A lane whose direction differs more from the ego's heading is not a candidate, °.
    pub max_heading_deg: f64,
    /// Beyond half the lane's width, m.
    pub tolerance_m: f64,
}

impl Default for MatchConfig {
    fn default() -> Self {
        MatchConfig {
            max_heading_deg: 45.0,
            tolerance_m: 0.5,
        }
    }
}

/// A sample's nearest lane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LaneMatch {
    pub lane: u32,
    /// From the sample to the lane's centre line, m.
    pub distance_m: f64,
    /// Within half the lane's width plus the tolerance.
    pub on_lane: bool,
}

/// Per sample, the nearest lane running the ego's way (None: no lane within the heading
/// limit, or no heading).
pub fn match_lanes(
    map: &Map,
    samples: &[EgoSample],
    config: &MatchConfig,
) -> Vec<Option<LaneMatch>> {
    let cos_limit = config.max_heading_deg.to_radians().cos();
    samples
        .iter()
        .map(|s| {
            let heading = s.heading_rad?;
            let forward = Point::new(heading.cos(), heading.sin());
            let mut best: Option<(f64, &maps::model::Lane)> = None;
            for lane in map.lanes.values() {
                for w in lane.centre.windows(2) {
                    let along = w[1].sub(w[0]);
                    let len = along.norm();
                    if len < 1e-9 || along.dot(forward) / len < cos_limit {
                        continue;
                    }
                    let (closest, _) = closest_on_segment(w[0], w[1], s.position);
                    let d = closest.distance(s.position);
                    if best.is_none_or(|(b, _)| d < b) {
                        best = Some((d, lane));
                    }
                }
            }
            best.map(|(distance_m, lane)| LaneMatch {
                lane: lane.id.0,
                distance_m,
                on_lane: distance_m <= lane.width_m / 2.0 + config.tolerance_m,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_s: f64, x: f64, heading: Option<f64>) -> EgoSample {
        EgoSample {
            time_ns: (t_s * 1e9) as u64,
            position: Point::new(x, 0.0),
            heading_rad: heading,
        }
    }

    #[test]
    fn resampling_interpolates_and_skips_gaps() {
        let samples = [
            sample(0.0, 0.0, Some(0.1)),
            sample(0.3, 3.0, Some(-0.1)),
            sample(2.0, 20.0, Some(0.0)),
        ];
        let (out, report) = resample(&samples, 10.0, 0.5);
        // 0.0 .. 2.0 s at 10 Hz: 21 times, the 16 strictly between 0.3 and 2.0 in the gap.
        assert_eq!(report.recorded, 3);
        assert_eq!(report.resampled + report.in_gaps, 21);
        assert_eq!(report.in_gaps, 16);
        assert!((out[1].position.x - 1.0).abs() < 1e-9, "{:?}", out[1]);
        let h = out[1].heading_rad.unwrap_or(f64::NAN);
        assert!((h - (0.1 - 0.2 / 3.0)).abs() < 1e-9, "{h}");
        assert_eq!(out.last().map(|s| s.position.x), Some(20.0));
    }

    #[test]
    fn headings_interpolate_across_the_half_turn() {
        let pi = std::f64::consts::PI;
        let samples = [
            sample(0.0, 0.0, Some(pi - 0.1)),
            sample(1.0, 1.0, Some(-pi + 0.1)),
        ];
        let (out, _) = resample(&samples, 2.0, 2.0);
        let mid = out[1].heading_rad.unwrap_or(f64::NAN);
        assert!(
            (wrap_angle(mid) - pi).abs() < 1e-9 || (wrap_angle(mid) + pi).abs() < 1e-9,
            "{mid}"
        );
    }

    #[test]
    fn gps_headings_come_from_the_motion() {
        let mut samples = vec![
            EgoSample {
                time_ns: 0,
                position: Point::new(0.0, 0.0),
                heading_rad: None,
            },
            EgoSample {
                time_ns: 1,
                position: Point::new(0.0, 1.0),
                heading_rad: None,
            },
        ];
        // Standing still after moving north: still heading north.
        samples.push(samples[1]);
        fill_headings_from_motion(&mut samples);
        for s in &samples {
            let h = s.heading_rad.unwrap_or(f64::NAN);
            assert!((h - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        }
    }
}
