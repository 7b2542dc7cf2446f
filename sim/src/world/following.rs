//! Car following: the vehicle ahead of each (on its path, or merging into it), anything
//! covering its path, and the acceleration its driver chooses.

use super::*;

impl World {
    /// The nearest vehicle ahead of vehicle `i` on its path (on a piece of its route).
    pub fn leader(&self, i: usize) -> Option<Leader> {
        self.nearest_ahead(i, false)
    }

    /// The nearest committed vehicle about to merge, from another piece, into a lane that
    /// vehicle `i` is about to enter, and nearer to that lane's start: it will be ahead once
    /// both are on the lane.
    pub fn merging_leader(&self, i: usize) -> Option<Leader> {
        self.nearest_ahead(i, true)
    }

    /// The nearest other vehicle whose footprint lies on vehicle `i`'s path within
    /// `horizon_m` ahead of its front, heading within 75° of the path there: a car leaving
    /// the ring just ahead whose rear still covers the lane, which [`World::leader`] no
    /// longer finds once that car is on its exit piece. The gap runs from `i`'s front to
    /// the first sampled point of the path (every 0.5 m) inside the footprint, grown by
    /// half of `i`'s width.
    ///
    /// On a multi-lane ring a standing car is in the way at any heading, except for a car
    /// that has not merged yet when the standing one, past its own merge point, stands for
    /// it (it waits for that car to go: the one entering goes first).
    pub fn obstacle_on_path(&self, i: usize, horizon_m: f64) -> Option<Leader> {
        self.obstacle_on_path_for(i, horizon_m, true)
    }

    /// [`World::obstacle_on_path`]; `look_back` whether to check that a standing car stands
    /// for `i`.
    pub(super) fn obstacle_on_path_for(
        &self,
        i: usize,
        horizon_m: f64,
        look_back: bool,
    ) -> Option<Leader> {
        const STEP_M: f64 = 0.5;
        let me = &self.vehicles[i];
        let path = &self.layout.routes[me.route].path;
        let front = me.front_s();
        // The path ahead, sampled once: (distance from the front, point, heading).
        let ahead: Vec<(f64, Point, f64)> = (0..=(horizon_m / STEP_M).ceil() as usize)
            .map(|k| {
                let d = k as f64 * STEP_M;
                let (p, heading) = path.pose_at(front + d);
                (d, p, heading)
            })
            .collect();
        let reach = horizon_m + me.length + 5.0;
        let forward = crate::kinematics::direction(me.heading);
        let mut best: Option<Leader> = None;
        for (j, other) in self.vehicles.iter().enumerate() {
            let offset = other.position.sub(me.position);
            // Only cars near and not behind (the path ahead may curve, hence the margin).
            if j == i || offset.norm() > reach || offset.dot(forward) < -other.length {
                continue;
            }
            let zone = OrientedBox::new(
                other.position,
                other.heading,
                other.length + me.width,
                other.width + me.width,
            );
            // On a multi-lane ring (or among drivers with measured critical gaps) a car
            // standing on the path is in the way at any angle: imported arms whose entry and
            // exit lanes meet short of the ring put cars waiting to enter on the way of cars
            // leaving.
            let standing = self.careful() && other.speed < self.standing_mps();
            let hit = ahead.iter().find_map(|&(d, p, heading)| {
                (zone.contains(p)
                    && (standing
                        || crate::path::wrap_angle(other.heading - heading).abs()
                            < 75f64.to_radians()))
                .then_some(d)
            });
            let merged = |v: &Vehicle| v.s >= self.layout.routes[v.route].merge_s;
            if hit.is_some()
                && standing
                && look_back
                && !merged(me)
                && merged(other)
                && self
                    .obstacle_on_path_for(j, OTHERS_OBSTACLE_HORIZON_M, false)
                    .is_some_and(|l| l.index == i)
            {
                continue;
            }
            if let Some(gap) = hit
                && best.is_none_or(|b| gap < b.gap_m)
            {
                best = Some(Leader {
                    index: j,
                    gap_m: gap,
                    closing_mps: me.speed - other.speed,
                    merging: false,
                });
            }
        }
        best
    }

    pub(super) fn nearest_ahead(&self, i: usize, merging: bool) -> Option<Leader> {
        let me = &self.vehicles[i];
        let mut best: Option<Leader> = None;
        let mut consider = |j: usize, centre_distance: f64| {
            let other = &self.vehicles[j];
            let gap = centre_distance - (me.length + other.length) / 2.0;
            if best.is_none_or(|b| gap < b.gap_m) {
                best = Some(Leader {
                    index: j,
                    gap_m: gap,
                    closing_mps: me.speed - other.speed,
                    merging,
                });
            }
        };
        for (k, &(key, start)) in self.lookahead[i].iter().enumerate() {
            for (j, other) in self.vehicles.iter().enumerate() {
                if j == i {
                    continue;
                }
                let Some(&(their_key, their_start)) = self.lookahead[j].first() else {
                    continue;
                };
                if !merging && their_key == key {
                    // On the same piece: ahead when farther along it.
                    let d = start - their_start;
                    if k > 0 || d > 0.0 {
                        consider(j, d);
                    }
                } else if merging
                    && their_key != key
                    && k > 0
                    && other.committed
                    && !self.waiting_to_change.get(j).copied().unwrap_or(false)
                    && matches!(key, PieceKey::Lane(_))
                    && let Some(their_d) = self
                        .distance_to_piece(j, key)
                        .filter(|&d| d > 0.0 && d < start)
                    && (!self.careful()
                        || self.vehicles[i].id < other.id
                        || !self.merges_ahead_of(i, j))
                {
                    consider(j, start - their_d);
                }
            }
        }
        best
    }

    /// Whether committed vehicle `i` is about to merge ahead of vehicle `j`: into a lane
    /// `j` is about to enter, from another piece, nearer to its start. Two vehicles each
    /// about to merge ahead of the other (into different lanes whose connections cross)
    /// would wait for each other for ever; on a multi-lane ring (and among drivers with
    /// measured critical gaps, who commit from farther off), the older one (lower id) goes
    /// first.
    pub(super) fn merges_ahead_of(&self, i: usize, j: usize) -> bool {
        let Some(&(their_key, _)) = self.lookahead[i].first() else {
            return false;
        };
        self.vehicles[i].committed
            && !self.waiting_to_change.get(i).copied().unwrap_or(false)
            && self.lookahead[j].iter().skip(1).any(|&(key, start)| {
                key != their_key
                    && matches!(key, PieceKey::Lane(_))
                    && self
                        .distance_to_piece(i, key)
                        .is_some_and(|d| d > 0.0 && d < start)
            })
    }

    /// Acceleration from a vehicle's driver model: IDM behind its leader, and behind its
    /// yield line while uncommitted.
    pub(super) fn driver_accel(&self, i: usize) -> f64 {
        let v = &self.vehicles[i];
        let route = &self.layout.routes[v.route];
        let v0 = route.path.speed_at(v.s + v.length / 2.0) * v.driver.speed_factor;
        let mut a = v.driver.idm(
            v.speed,
            v0,
            self.leader(i).map(|l| (l.gap_m, l.closing_mps)),
        );
        // A car cutting in ahead: braked for, but only so hard (uncommitted drivers wait
        // at their line anyway).
        if v.committed
            && let Some(m) = self.merging_leader(i)
        {
            let cut_in = v.driver.idm(v.speed, v0, Some((m.gap_m, m.closing_mps)));
            a = a.min(cut_in.max(-v.driver.merge_brake_mps2));
        }
        // A car whose body still covers the path just ahead (leaving the ring in front, the
        // ego off its line) is braked for as well: it is no leader once on its exit piece.
        if v.committed
            && let Some(o) = self.obstacle_on_path(i, OTHERS_OBSTACLE_HORIZON_M)
        {
            a = a.min(v.driver.idm(v.speed, v0, Some((o.gap_m, o.closing_mps))));
        }
        if v.committed
            && self.multi_lane
            && let Some(gap) = self.entering_across(i)
        {
            a = a.min(v.driver.idm(v.speed, v0, Some((gap, v.speed))));
        }
        if self.waiting_to_change.get(i) == Some(&true)
            && let Some((_, start_s)) = self.next_lane_change(i)
        {
            // Wait short of the lane change, as at a yield line.
            let gap = start_s - v.front_s() + v.driver.min_gap_m - 0.3;
            a = a.min(v.driver.idm(v.speed, v0, Some((gap, v.speed))));
        }
        if !v.committed && v.driver.critical_gap.lag_s().is_some() {
            // A driver judging gaps on the way rolls up to the line, braking only as late as
            // it can still stop short of it at most [`ROLLING_DECEL_SHARE`] of its
            // comfortable deceleration.
            let to_line = route.yield_s - v.front_s();
            if to_line > -0.5 {
                let room = (to_line - 0.3).max(0.0);
                let allowed =
                    (2.0 * ROLLING_DECEL_SHARE * v.driver.comfort_decel_mps2 * room).sqrt();
                a = a.min((allowed - v.speed) / ROLLING_REACT_S);
            }
        } else if !v.committed {
            let to_line = route.yield_s - v.front_s();
            if to_line > -0.5 {
                // The line as a standing obstacle; the front stops just short of it.
                let gap = to_line + v.driver.min_gap_m - 0.3;
                a = a.min(v.driver.idm(v.speed, v0, Some((gap, v.speed))));
            }
        }
        a
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn a_vehicle_follows_the_one_ahead_on_its_route() {
        let layout = crate::test_maps::montlake_layout();
        let length = |r: usize| layout.routes[r].path.length();
        let route = (0..layout.routes.len())
            .max_by(|&a, &b| length(a).total_cmp(&length(b)))
            .unwrap();
        let traffic = TrafficConfig {
            arrivals_per_s: 0.0,
            ..TrafficConfig::default()
        };
        let mut world = World::new(layout, traffic, EgoConfig::default(), 1);
        world.insert_vehicle(route, 5.0, 8.0, 0.5, true);
        world.insert_vehicle(route, 17.0, 2.0, 0.5, true);
        let leader = world.leader(0).unwrap();
        assert_eq!(leader.index, 1);
        let (behind, ahead) = (&world.vehicles()[0], &world.vehicles()[1]);
        let gap = 12.0 - (behind.length + ahead.length) / 2.0;
        assert!((leader.gap_m - gap).abs() < 1e-6, "{leader:?}");
        assert!((leader.closing_mps - 6.0).abs() < 1e-9);
        assert_eq!(world.leader(1).map(|l| l.index), None);
    }
}
