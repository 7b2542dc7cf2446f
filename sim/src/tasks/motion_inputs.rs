//! The ego's own recent motion as scalar inputs ([`super::InsertionConfig::motion_inputs`]):
//! its speed half a second, one and two seconds ago and the slowest it has been since the
//! episode began.
//!
//! Why: whether a driver approaching a yield line will stop shows first in how its speed
//! has been changing, and whether it has already stopped tells a driver about to go from
//! one still waiting. One speed and two stacked frames at 1.2 m a pixel hardly show either
//! (a difference of 1 m/s over 0.1 s moves a car a tenth of a pixel). The simulator and
//! projected logs both feed a [`MotionHistory`] once per world step (log frame), so the
//! inputs mean the same in both.

use std::collections::VecDeque;

/// How far back the past speeds are taken, s.
pub const LOOKBACK_S: [f64; 3] = [0.5, 1.0, 2.0];
/// Number of motion inputs: the past speeds, then the slowest speed so far.
pub const MOTION_SCALARS: usize = LOOKBACK_S.len() + 1;

/// The speeds of one vehicle since its episode began, one per step.
#[derive(Debug, Clone)]
pub struct MotionHistory {
    /// Steps back of each of [`LOOKBACK_S`].
    lookback_steps: [usize; LOOKBACK_S.len()],
    /// The newest last; at most the longest lookback plus one.
    speeds: VecDeque<f64>,
    slowest: f64,
}

impl MotionHistory {
    /// An empty history of a vehicle observed every `step_s` seconds.
    pub fn new(step_s: f64) -> MotionHistory {
        let lookback_steps = LOOKBACK_S.map(|s| (s / step_s.max(1e-6)).round().max(1.0) as usize);
        MotionHistory {
            lookback_steps,
            speeds: VecDeque::with_capacity(lookback_steps[LOOKBACK_S.len() - 1] + 1),
            slowest: f64::INFINITY,
        }
    }

    /// Starts an episode over at `speed_mps`, forgetting the one before.
    pub fn reset(&mut self, speed_mps: f64) {
        self.speeds.clear();
        self.slowest = f64::INFINITY;
        self.push(speed_mps);
    }

    /// The speed one step later; on an empty history, the episode's first.
    pub fn push(&mut self, speed_mps: f64) {
        let keep = self.lookback_steps[LOOKBACK_S.len() - 1] + 1;
        if self.speeds.len() == keep {
            self.speeds.pop_front();
        }
        self.speeds.push_back(speed_mps);
        self.slowest = self.slowest.min(speed_mps);
    }

    /// The inputs over `speed_scale_mps`: the speed each lookback ago (the first speed of
    /// the episode while it is younger than that), then the slowest since it began. All zero
    /// on an empty history.
    pub fn scalars(&self, speed_scale_mps: f64) -> [f32; MOTION_SCALARS] {
        let mut out = [0.0f32; MOTION_SCALARS];
        let Some(&oldest) = self.speeds.front() else {
            return out;
        };
        let newest = self.speeds.len() - 1;
        for (o, &back) in out.iter_mut().zip(&self.lookback_steps) {
            let speed = newest.checked_sub(back).map_or(oldest, |i| self.speeds[i]);
            *o = (speed / speed_scale_mps) as f32;
        }
        out[LOOKBACK_S.len()] = (self.slowest / speed_scale_mps) as f32;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn past_speeds_are_taken_the_lookbacks_ago_and_the_slowest_is_kept() {
        let mut h = MotionHistory::new(0.1);
        assert_eq!(h.scalars(10.0), [0.0; MOTION_SCALARS]);
        h.reset(8.0);
        // Younger than every lookback: the first speed stands in for the past.
        assert_eq!(h.scalars(10.0), [0.8, 0.8, 0.8, 0.8]);
        // Speeds 8, 7.9, ..., down to 0 over 80 steps, then 1 m/s for 5 steps.
        for k in 1..=80 {
            h.push(8.0 - 0.1 * f64::from(k));
        }
        for _ in 0..5 {
            h.push(1.0);
        }
        let s = h.scalars(10.0);
        // Now is step 85 (1 m/s); 5 steps back step 80 (0), 10 back step 75 (0.5), 20 back
        // step 65 (1.5 m/s); the slowest was 0.
        let expected = [0.0, 0.05, 0.15, 0.0];
        for (got, want) in s.iter().zip(expected) {
            assert!((got - want).abs() < 1e-5, "{s:?}");
        }
        // A reset forgets the stop.
        h.reset(3.0);
        assert_eq!(h.scalars(10.0), [0.3; MOTION_SCALARS]);
    }

    #[test]
    fn lookbacks_follow_the_step_length() {
        let mut h = MotionHistory::new(0.5);
        h.reset(0.0);
        for k in 1..=4 {
            h.push(f64::from(k));
        }
        // 0.5 s = 1 step back (3), 1 s = 2 back (2), 2 s = 4 back (0).
        assert_eq!(h.scalars(1.0), [3.0, 2.0, 0.0, 0.0]);
    }
}
