//! What the policies that read the bird's-eye view see at a log frame: the layer stack around
//! the vehicle (its recorded path, the task's frames stacked), its speed and the task's
//! scalar inputs (rule inputs, motion inputs), as they see it in the simulator.

use maps::Map;
use sim::render::{BevRenderer, FrameStack};
use sim::tasks::insertion::{
    Action, InsertionConfig, MotionHistory, RULE_SCALARS, observation_scalars, rule_scalars_of,
};
use sim::{Observation, ObservationSpec, SimError};

use crate::closed_loop::ClosedLoopView;
use logs::noise::NoiseConfig;
use logs::project::{LogFrame, project};
use traffic::decisions::{Approach, nearest_circulating};

/// What the policies that read the bird's-eye view (the agent, behaviour cloning) see;
/// offline training (`agent train --offline`) learns from the same.
#[derive(Debug)]
pub struct Views {
    /// The task the policies were trained on: its view, frame spacing and scalar inputs.
    task: InsertionConfig,
    pub(crate) renderer: BevRenderer,
    /// The route's nominal speed the policies are told (before the ego's style scales it).
    target_speed_mps: f64,
}

impl Views {
    /// The views of `task`'s observation over `map`, their stacked
    /// frames `task.frame_spacing()` log frames apart, with the route's nominal speed
    /// `target_speed_mps` in the scalars.
    pub fn new(map: &Map, task: InsertionConfig, target_speed_mps: f64) -> Result<Views, SimError> {
        let renderer = BevRenderer::new(map, map.bounds(), task.observation.clone())?;
        Ok(Views {
            task,
            renderer,
            target_speed_mps,
        })
    }

    /// Per frame of the approach: what a policy sees there ([`FrameInput`]): the layer
    /// stack (oldest first, `frame_spacing` log frames apart, the first frame repeated at the
    /// start), the vehicle's speed and, as the task asks, its rule and motion inputs.
    pub fn inputs(&self, map: &Map, frames: &[LogFrame], approach: &Approach) -> Vec<FrameInput> {
        let (projected, layers) = project(
            map,
            &self.renderer,
            frames,
            approach.track,
            &NoiseConfig::default(),
        );
        let frame_len = self.task.observation.frame_len();
        let stacks = stacks_at(
            projected
                .iter()
                .zip(layers.chunks_exact(frame_len))
                .map(|(figures, frame)| (figures.log_frame, frame)),
            frame_len,
            self.task.observation.stack,
            self.task.frame_spacing(),
            &approach.frames,
        );
        // The driven distance along the track from each projected frame to the frame where
        // its centre crossed the yield line (negative after it), for the rule inputs.
        let mut arc = Vec::with_capacity(projected.len());
        let mut length = 0.0;
        for (j, f) in projected.iter().enumerate() {
            if let Some(prev) = j.checked_sub(1).map(|i| &projected[i]) {
                length += (f.x - prev.x).hypot(f.y - prev.y);
            }
            arc.push(length);
        }
        let crossing_arc = projected
            .iter()
            .position(|f| f.log_frame >= approach.crossed_at)
            .map_or(length, |j| arc[j]);
        // The episode (and its motion history) begins at the approach's first frame.
        let mut motion = self
            .task
            .motion_inputs
            .then(|| MotionHistory::new(self.task.traffic.step_s));
        let first = approach.frames.first().copied().unwrap_or(usize::MAX);
        let mut wanted = stacks.into_iter().peekable();
        let mut out = Vec::with_capacity(approach.frames.len());
        for (j, f) in projected.iter().enumerate() {
            if f.log_frame < first {
                continue;
            }
            if let Some(history) = &mut motion {
                history.push(f.speed_mps);
            }
            let Some((_, layers)) = wanted.next_if(|(at, _)| *at == j) else {
                continue;
            };
            let mut extra = Vec::new();
            if self.task.rule_inputs {
                let frame = &frames[f.log_frame];
                let length_m = frame
                    .actors
                    .iter()
                    .find(|a| a.id == approach.track)
                    .map_or(0.0, |a| a.length_m);
                extra.extend(log_rule_scalars(
                    map,
                    frame,
                    approach.track,
                    crossing_arc - arc[j],
                    length_m,
                ));
            }
            if let Some(history) = &motion {
                extra.extend(history.scalars(self.task.speed_scale_mps));
            }
            out.push(FrameInput {
                layers,
                speed_mps: f.speed_mps,
                extra,
            });
        }
        out
    }

    /// The task's observation of `input`, the target speed that of an ego of
    /// `aggressiveness` in the task, `last` the last action (None: all zero).
    pub fn observation(
        &self,
        input: FrameInput,
        aggressiveness: f64,
        last: Option<Action>,
    ) -> Observation {
        let mut scalars = observation_scalars(
            input.speed_mps,
            self.target_speed_mps * self.task.ego_speed_factor(aggressiveness),
            self.task.speed_scale_mps,
            aggressiveness,
            last,
        );
        scalars.extend_from_slice(&input.extra);
        Observation {
            layers: input.layers,
            scalars,
        }
    }

    pub fn spec(&self) -> ObservationSpec {
        self.task
            .observation
            .observation_spec(self.task.scalar_count())
    }

    /// A closed-loop policy's [`FrameInput`]s, frame after frame of one episode (a new one
    /// for each episode: the motion history starts empty).
    pub fn closed_loop_inputs(&self) -> ClosedLoopInputs<'_> {
        ClosedLoopInputs {
            views: self,
            motion: self
                .task
                .motion_inputs
                .then(|| MotionHistory::new(self.task.traffic.step_s)),
        }
    }
}

/// The rule inputs of `track` in `frame` ([`rule_scalars_of`]): the nearest vehicle on the
/// ring, and its front's distance to the yield line from its centre's distance along its
/// path to where the driver's centre crossed it (`centre_to_crossing_m`, negative past it).
fn log_rule_scalars(
    map: &Map,
    frame: &LogFrame,
    track: u32,
    centre_to_crossing_m: f64,
    length_m: f64,
) -> [f32; RULE_SCALARS] {
    let front_to_line = centre_to_crossing_m - length_m / 2.0;
    rule_scalars_of(
        nearest_circulating(map, frame, track),
        front_to_line,
        front_to_line < 0.0,
    )
}

/// What a policy sees at one log frame: the bird's-eye layer stack, the vehicle's speed,
/// and the scalar inputs the task adds after the standard ones (rule inputs, motion inputs).
#[derive(Debug, Clone)]
pub struct FrameInput {
    pub layers: Vec<u8>,
    pub speed_mps: f64,
    pub extra: Vec<f32>,
}

/// [`FrameInput`]s of a vehicle driven closed loop: its motion history goes on from view
/// to view.
#[derive(Debug)]
pub struct ClosedLoopInputs<'a> {
    views: &'a Views,
    motion: Option<MotionHistory>,
}

impl ClosedLoopInputs<'_> {
    /// The input at `view` (the episode's views in order, the first one first).
    pub fn at(&mut self, map: &Map, track: u32, view: &ClosedLoopView<'_>) -> FrameInput {
        let task = &self.views.task;
        let mut extra = Vec::new();
        if task.rule_inputs {
            extra.extend(log_rule_scalars(
                map,
                view.frame,
                track,
                view.to_crossing_m,
                view.frame.actors[view.ego].length_m,
            ));
        }
        if let Some(history) = &mut self.motion {
            history.push(view.speed_mps);
            extra.extend(history.scalars(task.speed_scale_mps));
        }
        FrameInput {
            layers: view.layers.to_vec(),
            speed_mps: view.speed_mps,
            extra,
        }
    }
}

/// The layer stacks at the `wanted` log frames (in time order), with each one's position in
/// `frames`, when every frame of `frames` (log frame, layers; in time order) goes through a
/// [`FrameStack`] of `stack` frames `spacing` frames apart, as the simulator stacks the frames
/// it draws. The first frame fills the stack.
fn stacks_at<'a>(
    frames: impl IntoIterator<Item = (usize, &'a [u8])>,
    frame_len: usize,
    stack: usize,
    spacing: usize,
    wanted: &[usize],
) -> Vec<(usize, Vec<u8>)> {
    let mut frame_stack = FrameStack::spaced(frame_len, stack, spacing);
    let mut wanted = wanted.iter().peekable();
    let mut out = Vec::with_capacity(wanted.len());
    for (j, (log_frame, frame)) in frames.into_iter().enumerate() {
        if j == 0 {
            frame_stack.reset(frame);
        } else {
            frame_stack.push(frame);
        }
        if wanted.peek() == Some(&&log_frame) {
            wanted.next();
            let mut layers = Vec::new();
            frame_stack.write(&mut layers);
            out.push((j, layers));
        }
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// Log frames 10 to 19, each one byte long holding its own number; the stacks of frames
    /// 12, 13 and 18.
    fn stacks_of(stack: usize, spacing: usize) -> Vec<(usize, Vec<u8>)> {
        let frames: Vec<(usize, [u8; 1])> = (10..20).map(|n| (n, [n as u8])).collect();
        stacks_at(
            frames.iter().map(|(n, bytes)| (*n, &bytes[..])),
            1,
            stack,
            spacing,
            &[12, 13, 18],
        )
    }

    /// The rule and motion inputs of a real recording (FT 000, when `../shared/data` is
    /// there): along every approach the distance from the front to the yield line falls, to
    /// minus half the car's length (within a step) at the last frame before its centre
    /// crosses; it reads as entered exactly when its front is past the line; and the motion
    /// inputs are the speeds of the frames 0.5, 1 and 2 s before and the slowest so far.
    #[test]
    fn logs_give_the_rule_and_motion_inputs_along_each_approach() {
        use logs::convert::{ConvertConfig, interaction_to_mcap};
        use logs::decode::read_decoded;
        use logs::interaction::read_track_file;
        use logs::project::log_frames;
        use logs::source::{Log, ReadOptions};
        use sim::tasks::insertion::RULE_INPUT_RANGE_M;
        use std::path::Path;
        use traffic::decisions::{LabelConfig, approaches};
        let data = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/trajectories/interaction");
        if !data.is_dir() {
            #[allow(clippy::print_stdout)] // the skip notice the project's data tests print
            {
                println!(
                    "skipped: {}: ../shared/data is absent",
                    std::thread::current().name().unwrap_or("-")
                );
            }
            return;
        }
        let map_path = data.join("maps/DR_USA_Roundabout_FT.osm");
        let map = maps::import_file(&map_path, &maps::ImportOptions::default()).unwrap();
        let tracks = read_track_file(
            &data.join("recorded_trackfiles/DR_USA_Roundabout_FT/vehicle_tracks_000.csv.gz"),
        )
        .unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let log_path = tmp.path().join("ft_000.mcap");
        let file = std::fs::File::create(&log_path).unwrap();
        interaction_to_mcap(&tracks, &map.projection, &ConvertConfig::default(), file).unwrap();
        let log = Log::open(&log_path).unwrap();
        let decoded = read_decoded(&log, &ReadOptions::default()).unwrap();
        let frames = log_frames(&decoded, None);
        let task = InsertionConfig {
            rule_inputs: true,
            motion_inputs: true,
            ..InsertionConfig::default()
        };
        let scale = task.speed_scale_mps as f32;
        let views = Views::new(&map, task, 8.0).unwrap();
        let found = approaches(&map, &frames, &LabelConfig::default());
        assert!(found.len() > 50, "{} approaches", found.len());
        for approach in found.iter().take(40) {
            let inputs = views.inputs(&map, &frames, approach);
            assert_eq!(inputs.len(), approach.frames.len());
            let to_line: Vec<f32> = inputs
                .iter()
                .map(|i| i.extra[1] * RULE_INPUT_RANGE_M as f32)
                .collect();
            for w in to_line.windows(2) {
                assert!(w[1] <= w[0] + 1e-4, "track {}: {to_line:?}", approach.track);
            }
            let last = *to_line.last().unwrap();
            let step = approach.speeds.last().unwrap() * 0.1 + 0.5;
            let half_length = frames[approach.crossed_at]
                .actors
                .iter()
                .find(|a| a.id == approach.track)
                .unwrap()
                .length_m
                / 2.0;
            assert!(
                (f64::from(last) + half_length).abs() <= step,
                "track {}: front {last} m from the line at the last frame, half length {half_length}",
                approach.track
            );
            for (k, input) in inputs.iter().enumerate() {
                assert_eq!(input.extra.len(), RULE_SCALARS + 4);
                assert_eq!(input.extra[2] == 1.0, to_line[k] < 0.0);
                let speed = |back: usize| (inputs[k.saturating_sub(back)].speed_mps as f32) / scale;
                let motion = &input.extra[RULE_SCALARS..];
                for (got, want) in motion.iter().zip([speed(5), speed(10), speed(20)]) {
                    assert!(
                        (got - want).abs() < 1e-6,
                        "track {} frame {k}",
                        approach.track
                    );
                }
                let slowest = inputs[..=k]
                    .iter()
                    .map(|i| i.speed_mps as f32 / scale)
                    .fold(f32::INFINITY, f32::min);
                assert!((motion[3] - slowest).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn log_stacks_hold_the_frames_spacing_apart_oldest_first() {
        // Consecutive frames, as before frame_steps reached the logs.
        assert_eq!(
            stacks_of(2, 1),
            vec![(2, vec![11, 12]), (3, vec![12, 13]), (8, vec![17, 18])]
        );
        // Three frames three apart: the first frame fills the stack until it is old enough.
        assert_eq!(
            stacks_of(3, 3),
            vec![
                (2, vec![10, 10, 12]),
                (3, vec![10, 10, 13]),
                (8, vec![12, 15, 18])
            ]
        );
    }
}
