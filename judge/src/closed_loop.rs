//! Closed-loop replay: a policy drives one recorded vehicle from where its approach to a
//! yield line began, along its driver's own path, while every other road user replays the
//! log (Waymax's log playback). The policy decides go / wait / caution at every log frame
//! from the bird's-eye view the simulator would draw (its frames stacked) and the frame's
//! road users; the vehicle then moves along the path with the insertion task's longitudinal
//! control, and behind a road user on its path it follows it as the simulator's drivers do
//! (the intelligent driver model caps every command's acceleration). An episode ends when the vehicle is `goal_past_crossing_m` past the yield line
//! (reached), when its footprint overlaps another road user's (crashed), or when the time
//! limit or the log runs out (time over).
//!
//! The replayed road users cannot react: a car that was behind the driver drives on into a
//! vehicle that waits longer than the driver did. Such a crash (the other road user's centre
//! behind the vehicle's) is counted apart as `rear_ended`.
//!
//! Log divergence: the mean distance between the vehicle and where its driver was at the
//! same frame (while the driver is in the log), as Waymax reports it.

use maps::Map;
use maps::geometry::{Point, direction_at, point_at, polyline_length};
use serde::{Deserialize, Serialize};
use sim::render::{BevRenderer, FrameStack};
use sim::scene::Scene;
use sim::world::{Driver, DriverConfig};

use logs::project::LogFrame;
use traffic::decisions::Approach;

/// What the policy decides at a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Drive on towards the target speed.
    Go,
    /// Brake to a stop.
    Wait,
    /// Hold half the target speed.
    Caution,
}

/// The vehicle's control and the episode's limits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClosedLoopConfig {
    pub target_speed_mps: f64,
    pub accel_mps2: f64,
    pub decel_mps2: f64,
    /// The hardest braking, when following a road user demands more than `decel_mps2`.
    pub max_brake_mps2: f64,
    /// Reached this far along the path past the yield line, m.
    pub goal_past_crossing_m: f64,
    /// The time limit: this times the driver's own time from the start to the goal, but at
    /// least `min_time_limit_s`.
    pub time_limit_factor: f64,
    pub min_time_limit_s: f64,
}

impl Default for ClosedLoopConfig {
    fn default() -> Self {
        ClosedLoopConfig {
            target_speed_mps: 8.0,
            accel_mps2: 2.0,
            decel_mps2: 2.5,
            max_brake_mps2: 8.0,
            goal_past_crossing_m: 15.0,
            time_limit_factor: 2.0,
            min_time_limit_s: 20.0,
        }
    }
}

/// How an episode ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ClosedLoopOutcome {
    Reached,
    Crashed,
    /// Hit from behind by a replayed road user that could not react.
    RearEnded,
    TimeOver,
}

/// One episode.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ClosedLoopEpisode {
    pub track: u32,
    pub outcome: ClosedLoopOutcome,
    pub steps: usize,
    pub time_s: f64,
    /// Mean distance to the driver's position at the same frame, m.
    pub log_divergence_m: f64,
    /// When the vehicle crossed the yield line minus when its driver did, s (None: did not
    /// cross).
    pub entry_delay_s: Option<f64>,
}

/// What the policy sees at a frame.
#[derive(Debug)]
pub struct ClosedLoopView<'a> {
    /// The frame's road users, the vehicle at its driven pose (index `ego`).
    pub frame: &'a LogFrame,
    pub ego: usize,
    /// The bird's-eye frames, oldest first (the renderer's stack).
    pub layers: &'a [u8],
    pub speed_mps: f64,
    /// Along the driver's path from the vehicle's centre to where the driver's centre
    /// crossed the yield line (negative past it), m.
    pub to_crossing_m: f64,
}

/// Drives `approach`'s vehicle through `frames` with `policy`, the other road users replayed.
pub fn drive(
    map: &Map,
    renderer: &BevRenderer,
    frames: &[LogFrame],
    approach: &Approach,
    config: &ClosedLoopConfig,
    policy: &mut dyn FnMut(&ClosedLoopView<'_>) -> Command,
) -> Option<ClosedLoopEpisode> {
    let track = approach.track;
    let start = *approach.frames.first()?;
    // The driver's path and positions from the start on (log frame, position).
    let driven: Vec<(usize, Point)> = frames
        .iter()
        .enumerate()
        .skip(start)
        .filter_map(|(k, f)| {
            f.actors
                .iter()
                .find(|a| a.id == track)
                .map(|a| (k, a.position))
        })
        .collect();
    let mut path: Vec<Point> = Vec::new();
    let mut arc = Vec::with_capacity(driven.len());
    let mut length = 0.0;
    for &(_, p) in &driven {
        if let Some(q) = path.last() {
            length += q.distance(p);
        }
        if path.last().is_none_or(|q: &Point| q.distance(p) > 1e-6) {
            path.push(p);
        }
        arc.push(length);
    }
    let crossing_s = driven
        .iter()
        .position(|&(k, _)| k >= approach.crossed_at)
        .map(|i| arc[i])?;
    let goal_s = (crossing_s + config.goal_past_crossing_m).min(polyline_length(&path));
    let driver_goal_time = driven
        .iter()
        .zip(&arc)
        .find(|(_, s)| **s >= goal_s)
        .map(|((k, _), _)| frames[*k].time_ns)?;
    let t0 = frames[start].time_ns;
    let time_limit_s =
        (config.time_limit_factor * (driver_goal_time.saturating_sub(t0)) as f64 * 1e-9)
            .max(config.min_time_limit_s);
    let driver_crossing_time = frames[approach.crossed_at].time_ns;
    let me = frames[start].actors.iter().find(|a| a.id == track)?.clone();
    let follower = Driver::new(&DriverConfig::default(), 0.5);

    let frame_len = renderer.config().frame_len();
    let mut stack = FrameStack::new(frame_len, renderer.config().stack);
    let (mut layer, mut layers) = (Vec::with_capacity(frame_len), Vec::new());
    let mut s = 0.0;
    let mut speed = approach.speeds.first().copied().unwrap_or(0.0);
    let mut divergence = (0.0, 0usize);
    let mut crossed_at_ns = None;
    let mut outcome = ClosedLoopOutcome::TimeOver;
    let mut steps = 0;
    let mut k = start;
    while k + 1 < frames.len() {
        let time_s = (frames[k].time_ns.saturating_sub(t0)) as f64 * 1e-9;
        if time_s > time_limit_s {
            break;
        }
        // The frame with the vehicle where it has been driven.
        let mut frame = frames[k].clone();
        frame.actors.retain(|a| a.id != track);
        set_speeds_from_next_frame(&mut frame, &frames[k + 1]);
        let mut ego_actor = me.clone();
        ego_actor.position = point_at(&path, s);
        let d = direction_at(&path, s);
        ego_actor.heading_rad = d.y.atan2(d.x);
        ego_actor.speed_mps = speed;
        frame.actors.push(ego_actor.clone());
        let ego = frame.actors.len() - 1;
        if let Some(driver) = frames[k].actors.iter().find(|a| a.id == track) {
            divergence.0 += driver.position.distance(ego_actor.position);
            divergence.1 += 1;
        }
        // Collisions in this frame.
        let footprint = ego_actor.footprint();
        if let Some(other) = frame.actors[..ego]
            .iter()
            .find(|a| a.footprint().overlaps(&footprint))
        {
            let behind = other.position.sub(ego_actor.position).dot(d) < 0.0;
            outcome = if behind {
                ClosedLoopOutcome::RearEnded
            } else {
                ClosedLoopOutcome::Crashed
            };
            break;
        }
        if s >= goal_s - 1e-9 {
            outcome = ClosedLoopOutcome::Reached;
            break;
        }
        // The view and the decision.
        renderer.render(
            &Scene {
                map,
                time_s: frame.time_ns as f64 * 1e-9,
                actors: frame.actors.clone(),
                ego,
                ego_path: &path,
            },
            &mut layer,
        );
        if steps == 0 {
            stack.reset(&layer);
        } else {
            stack.push(&layer);
        }
        stack.write(&mut layers);
        let command = policy(&ClosedLoopView {
            frame: &frame,
            ego,
            layers: &layers,
            speed_mps: speed,
            to_crossing_m: crossing_s - s,
        });
        // Move to the next frame.
        let dt = (frames[k + 1].time_ns.saturating_sub(frames[k].time_ns)) as f64 * 1e-9;
        let wanted = match command {
            Command::Go => config.target_speed_mps,
            Command::Wait => 0.0,
            Command::Caution => config.target_speed_mps / 2.0,
        };
        let accel = if dt > 0.0 {
            ((wanted - speed) / dt).clamp(-config.decel_mps2, config.accel_mps2)
        } else {
            0.0
        };
        let follow = leader_on_path(&frame, ego, d).map_or(f64::INFINITY, |(gap, closing)| {
            follower.idm(speed, config.target_speed_mps, Some((gap, closing)))
        });
        let accel = accel.min(follow).max(-config.max_brake_mps2);
        let next_speed = (speed + accel * dt).max(0.0);
        s += 0.5 * (speed + next_speed) * dt;
        speed = next_speed;
        if crossed_at_ns.is_none() && s >= crossing_s {
            crossed_at_ns = Some(frames[k + 1].time_ns);
        }
        steps += 1;
        k += 1;
    }
    Some(ClosedLoopEpisode {
        track,
        outcome,
        steps,
        time_s: (frames[k].time_ns.saturating_sub(t0)) as f64 * 1e-9,
        log_divergence_m: divergence.0 / divergence.1.max(1) as f64,
        entry_delay_s: crossed_at_ns.map(|t| (t as f64 - driver_crossing_time as f64) * 1e-9),
    })
}

/// The nearest road user ahead of the vehicle `ego` of `frame` heading along `d` (its centre
/// within half a lane of the vehicle's line, at most 50 m ahead): (bumper-to-bumper gap,
/// closing speed).
fn leader_on_path(frame: &LogFrame, ego: usize, d: Point) -> Option<(f64, f64)> {
    const AHEAD_M: f64 = 50.0;
    const HALF_LANE_M: f64 = 1.75;
    let me = &frame.actors[ego];
    frame
        .actors
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != ego)
        .filter_map(|(_, other)| {
            let rel = other.position.sub(me.position);
            let along = rel.dot(d);
            let lateral = rel.cross(d).abs();
            (along > 0.0 && along <= AHEAD_M && lateral <= HALF_LANE_M).then(|| {
                let gap = along - (me.length_m + other.length_m) / 2.0;
                let their_speed = other.speed_mps * (other.heading_rad - d.y.atan2(d.x)).cos();
                (gap, me.speed_mps - their_speed)
            })
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
}

/// The road users' speeds from where they are in the next frame (detections carry none).
fn set_speeds_from_next_frame(frame: &mut LogFrame, next: &LogFrame) {
    let dt = (next.time_ns.saturating_sub(frame.time_ns)) as f64 * 1e-9;
    if dt <= 0.0 {
        return;
    }
    for actor in &mut frame.actors {
        if let Some(later) = next.actors.iter().find(|a| a.id == actor.id) {
            actor.speed_mps = later.position.distance(actor.position) / dt;
        }
    }
}
