//! Roundabout insertion's reward and termination: the danger terms of a world step, the
//! cost of a short entry, and how an episode ends.

use super::*;

/// The danger the reward penalises, in one world step.
#[derive(Debug, Clone, Copy)]
pub(super) struct Danger {
    pub(super) close_following: bool,
    pub(super) cut_in: bool,
}

impl RoundaboutInsertion {
    /// What the danger terms are multiplied by: σ to `danger_sigma_power`.
    pub(super) fn danger_scale(&self) -> f64 {
        (1.0 - self.aggressiveness).powf(self.config.reward.danger_sigma_power)
    }

    /// The one-time cost of the entry just made, from its lag (`short_entry_penalty`).
    pub(super) fn short_entry_cost(&self) -> f64 {
        let r = &self.config.reward;
        match self.entry_lag_s {
            Some(lag) if lag < r.short_entry_s => {
                r.short_entry_penalty * (1.0 - lag / r.short_entry_s) * self.danger_scale()
            }
            _ => 0.0,
        }
    }

    /// Reward terms that apply every step: speed, indecision, and r_danger for `danger`.
    pub(super) fn step_reward(
        &self,
        world: &World,
        ego: usize,
        action: Action,
        danger: Danger,
    ) -> f64 {
        let r = &self.config.reward;
        let me = &world.vehicles()[ego];
        let danger_scale = self.danger_scale();
        let mut reward = r.speed * me.speed / self.target_speed(world, ego);
        if self.last_action == Action::Permitted {
            reward -= match action {
                Action::Caution => r.to_caution_penalty,
                Action::NotPermitted => r.to_not_permitted_penalty,
                Action::Permitted => 0.0,
            };
        }
        if danger.close_following {
            reward -= r.headway_penalty * danger_scale;
        }
        if danger.cut_in {
            reward -= r.cut_in_penalty * danger_scale;
        }
        reward
    }

    /// Which of r_danger's situations the ego is in: following closer than `headway_s`,
    /// or in the ring just in front of a circulating vehicle.
    pub(super) fn danger(&self, world: &World, ego: usize) -> Danger {
        let r = &self.config.reward;
        let me = &world.vehicles()[ego];
        let close_following = world
            .leader(ego)
            .is_some_and(|l| l.gap_m < me.speed * r.headway_s);
        let in_ring = me.committed && me.s < world.route(me).exit_s;
        Danger {
            close_following,
            cut_in: in_ring && self.cut_in(world, ego),
        }
    }

    /// Whether a circulating vehicle has the ego as the vehicle ahead of it and would
    /// reach it within `cut_in_s` at its speed (with `cut_in_only_cut_off`, one the ego
    /// entered in front of).
    pub(super) fn cut_in(&self, world: &World, ego: usize) -> bool {
        let r = &self.config.reward;
        let limit = r.cut_in_s;
        (0..world.vehicles().len()).any(|j| {
            let v = &world.vehicles()[j];
            if v.is_ego()
                || !v.committed
                || (r.cut_in_only_cut_off && !self.cut_off.contains(&v.id))
            {
                return false;
            }
            [world.leader(j), world.merging_leader(j)]
                .into_iter()
                .flatten()
                .any(|l| l.index == ego && l.gap_m.max(0.0) < limit * v.speed)
        })
    }
}
impl RoundaboutInsertion {
    /// After a world step: the reward and whether (and how) the episode ended.
    pub(super) fn resolve(&mut self, world: &mut World, action: Action) -> (f64, Option<Outcome>) {
        let Some(ego) = world.ego_index() else {
            return (0.0, Some(Outcome::TimeOver));
        };
        self.episode.steps += 1;
        let (speed, position, s, committed) = {
            let me = &world.vehicles()[ego];
            (me.speed, me.position, me.s, me.committed)
        };
        self.speed_sum += speed;
        self.episode.trajectory.push(position);
        self.motion.push(speed);
        let elapsed = world.time_s() - self.start_time_s;
        let just_entered = committed && self.entered_at_s.is_none();
        if just_entered {
            self.entered_at_s = Some(elapsed);
            self.entry_lag_s = world.merge_lag_s(ego);
            let limit = self.config.reward.cut_in_s;
            self.cut_off = world
                .merge_lags_s(ego)
                .filter(|&(_, lag)| lag < limit)
                .map(|(j, _)| world.vehicles()[j].id)
                .collect();
        }
        let danger = self.danger(world, ego);
        self.close_following_steps += usize::from(danger.close_following);
        self.cut_in_steps += usize::from(danger.cut_in);
        let mut reward = self.step_reward(world, ego, action, danger);
        if just_entered {
            reward -= self.short_entry_cost();
        }
        let r = self.config.reward;
        let sigma = 1.0 - self.aggressiveness;
        let raster = self.setup.roundabouts.renderer(self.roundabout).raster();
        let outcome = if world.collision_with(ego).is_some() {
            Some(Outcome::Crashed)
        } else if !raster.navigable(position) {
            Some(Outcome::OffRoad)
        } else if s >= self.goal_s {
            Some(Outcome::Reached)
        } else if elapsed >= self.time_limit_s - 1e-9 {
            Some(Outcome::TimeOver)
        } else {
            None
        };
        reward += match outcome {
            Some(Outcome::Reached) => r.reach,
            Some(Outcome::Crashed | Outcome::OffRoad) => -(r.crash_base + r.crash_sigma * sigma),
            Some(Outcome::TimeOver) => -r.time_over,
            None => 0.0,
        };
        (reward, outcome)
    }
}
