//! Priority at the ring: drivers at their yield lines accept or reject gaps in circulating
//! traffic (and withdraw from a closing one), the lags they judge, and lane changes on
//! multi-lane rings.

use super::*;

impl World {
    /// A driver who committed to a gap but had to stop before reaching the yield line
    /// (behind a queue, or behind a car merging ahead) has lost that gap: the commitment
    /// is dropped and the driver decides again at the line. Kept, it makes circulating
    /// drivers yield to a car that is not coming, and chains of such yields closed into
    /// gridlocks (the ring stopped for the rest of an episode). The ego under the agent's
    /// control is committed only past its line, so this never touches it.
    pub(super) fn reconsider_stopped_commitments(&mut self) {
        for v in &mut self.vehicles {
            let route = &self.layout.routes[v.route];
            if v.committed && v.speed < STOPPED_MPS && v.front_s() < route.yield_s {
                v.committed = false;
            }
        }
    }

    /// Gap acceptance: uncommitted drivers near their yield line commit when every
    /// circulating vehicle heading for their merge point is far enough away in time. The
    /// ego decides this way only when its driver model drives it (`ego_driven`).
    pub(super) fn decide_gaps(&mut self, ego_driven: bool) {
        self.reconsider_stopped_commitments();
        let (mut commit, mut withdraw) = (Vec::new(), Vec::new());
        for (i, v) in self.vehicles.iter().enumerate() {
            if v.is_ego() && (v.committed || !ego_driven) {
                continue;
            }
            let route = &self.layout.routes[v.route];
            let to_line = route.yield_s - v.front_s();
            if to_line > self.config.decision_distance_m {
                continue;
            }
            // On a multi-lane ring (or with measured critical gaps, judged from far off), a
            // committed driver who could still stop comfortably short of the line keeps
            // looking, and withdraws when the gap has closed (a circulating car sped up, or
            // the driver was held up on the way).
            let stopping_m = v.speed * v.speed / (2.0 * v.driver.comfort_decel_mps2);
            let reconsiders = self.multi_lane || v.driver.critical_gap.lag_s().is_some();
            if v.committed && (!reconsiders || to_line < stopping_m + 0.5) {
                continue;
            }
            // A driver with a measured critical gap judges gaps only at the head of its queue:
            // behind a driver still waiting at the line, it waits too.
            if v.driver.critical_gap.lag_s().is_some()
                && to_line >= -0.5
                && self
                    .leader(i)
                    .is_some_and(|l| !self.vehicles[l.index].committed)
            {
                if v.committed {
                    withdraw.push(i);
                }
                continue;
            }
            if to_line < -0.5 {
                // Over the line already (it could not stop): it is in the way either way.
                commit.push(i);
                continue;
            }
            // Time to get the whole car past the merge point from the current speed at full
            // acceleration: how long the gap must stay open, on top of the critical gap.
            let to_clear = (route.merge_s - v.front_s()).max(0.0) + v.length;
            let (speed, accel) = (v.speed, v.driver.max_accel_mps2);
            let my_time = ((speed * speed + 2.0 * accel * to_clear).sqrt() - speed) / accel;
            let line = to_line.max(0.0);
            let to_line_s = ((speed * speed + 2.0 * accel * line).sqrt() - speed) / accel;
            let clear = self.vehicles.iter().enumerate().all(|(j, o)| {
                if j == i || !o.committed {
                    return true;
                }
                // A driver with a measured critical gap looks at the ring: a car still before
                // its own yield line is not in the ring's traffic yet.
                if v.driver.critical_gap.lag_s().is_some()
                    && o.front_s() < self.layout.routes[o.route].yield_s
                {
                    return true;
                }
                // Stopped for this very car, standing in its way: it waits for this car to
                // go (see `obstacle_on_path`).
                if self.careful()
                    && o.speed < STOPPED_MPS
                    && self
                        .obstacle_on_path(j, OTHERS_OBSTACLE_HORIZON_M)
                        .is_some_and(|l| l.index == i)
                {
                    return true;
                }
                // Where its car touches one entering here (a route not driving the merge
                // lane: leaving the ring at this arm, or on a lane the entry crosses): wait
                // while it is in or near that zone.
                let zone_clear = route
                    .entry_conflicts
                    .iter()
                    .find(|c| c.route == o.route)
                    .is_none_or(|c| {
                        // Drivers judging from far off expect a car leaving the ring to speed
                        // up to its desired speed at the zone.
                        let speed = if v.driver.critical_gap.lag_s().is_some() {
                            let path = &self.layout.routes[o.route].path;
                            o.speed.max(path.speed_at(c.from_s) * o.driver.speed_factor)
                        } else {
                            o.speed
                        };
                        o.s > c.to_s
                            || (o.s < c.from_s
                                && (c.from_s - o.s) / speed.max(2.0)
                                    > v.driver.needed_lag_s(my_time, to_line_s))
                    });
                // Along its route to the first of the lanes this entry gives way to (the merge
                // lane, and the lanes an entry into an inner lane crosses) that it drives.
                let Some(d) = route
                    .yield_lanes()
                    .find_map(|lane| self.to_lane_start(o, lane))
                else {
                    return zone_clear;
                };
                if !zone_clear {
                    return false;
                }
                if d >= self.config.horizon_m {
                    return true;
                }
                // Front of the other vehicle to the merge point; negative while it straddles it.
                let front_to_merge = d - o.length / 2.0;
                if d <= 0.0 && d > -o.length {
                    return false; // on the merge lane right at the merge point
                }
                // A driver with a measured critical gap needs room past the merge point: not
                // into a queue standing on the ring (that is how rings lock up).
                if v.driver.critical_gap.lag_s().is_some()
                    && d <= 0.0
                    && d > -(o.length + v.length + ROOM_TO_ENTER_M)
                    && o.speed < QUEUE_MPS
                {
                    return false;
                }
                if d <= 0.0 {
                    return true;
                }
                // A committed car may speed up: assume at least 2 m/s.
                front_to_merge > 2.0
                    && front_to_merge / o.speed.max(2.0) > v.driver.needed_lag_s(my_time, to_line_s)
            });
            match (clear, v.committed) {
                (true, false) => commit.push(i),
                (false, true) => withdraw.push(i),
                _ => {}
            }
        }
        for i in commit {
            self.vehicles[i].committed = true;
        }
        for i in withdraw {
            self.vehicles[i].committed = false;
        }
    }

    /// Along `o`'s route, from its centre to where it enters ring lane `lane` (negative once
    /// past; the lane may be shorter than a car); None if its route does not drive that lane.
    pub(super) fn to_lane_start(&self, o: &Vehicle, lane: LaneId) -> Option<f64> {
        Some(self.layout.routes[o.route].ring_lane_start(lane)? - o.s)
    }

    /// The gap vehicle `i` has in front of the circulating traffic at its merge point: the
    /// least time a committed vehicle within the horizon needs for its front to reach that
    /// point ([`World::merge_lags_s`]), 0 while one straddles it; None when none is coming.
    /// Read as the ego enters, it is the gap the ego accepted.
    pub fn merge_lag_s(&self, i: usize) -> Option<f64> {
        self.merge_lags_s(i)
            .map(|(_, lag)| lag)
            .min_by(f64::total_cmp)
    }

    /// Every committed vehicle within the horizon still coming to vehicle `i`'s merge point
    /// (or to where its entry crosses an outer ring lane, on the way into an inner one),
    /// with the time its front needs to reach that point (at its speed, but at least 2 m/s
    /// as gap acceptance assumes; 0 while it straddles the point), by index.
    pub fn merge_lags_s(&self, i: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let route = &self.layout.routes[self.vehicles[i].route];
        self.vehicles
            .iter()
            .enumerate()
            .filter(move |&(j, o)| j != i && o.committed)
            .filter_map(move |(j, o)| {
                let d = route
                    .yield_lanes()
                    .find_map(|lane| self.to_lane_start(o, lane))?;
                if d >= self.config.horizon_m || d <= -o.length {
                    return None; // far away, or past the merge point
                }
                Some((j, (d - o.length / 2.0).max(0.0) / o.speed.max(2.0)))
            })
    }

    /// The next lane change on vehicle `i`'s route that its front has not reached, within
    /// [`LANE_CHANGE_LOOK_M`]: the ring lane it leaves, and where the connection into a
    /// ring lane of another rank (or out of the ring from an inner lane, across the outer
    /// one: see [`World::crosses_lanes`]) starts along the route.
    pub(super) fn next_lane_change(&self, i: usize) -> Option<(LaneId, f64)> {
        let v = &self.vehicles[i];
        let pieces = self.layout.routes[v.route].path.pieces();
        let front = v.front_s();
        (v.piece.max(1)..pieces.len().saturating_sub(1))
            .take_while(|&k| pieces[k].s_start - front <= LANE_CHANGE_LOOK_M)
            .filter(|&k| pieces[k].s_start > front)
            .find_map(|k| {
                let (PieceKey::Lane(from), PieceKey::Connection(_), PieceKey::Lane(to)) =
                    (pieces[k - 1].key, pieces[k].key, pieces[k + 1].key)
                else {
                    return None;
                };
                self.crosses_lanes(from, to)
                    .then_some((from, pieces[k].s_start))
            })
    }

    /// Whether going from ring lane `from` on to lane `to` crosses another lane of the
    /// ring road: a lane change, or leaving the ring from an inner lane.
    pub(super) fn crosses_lanes(&self, from: LaneId, to: LaneId) -> bool {
        let ranks = &self.layout.ring_lane_ranks;
        match (ranks.get(&from), ranks.get(&to)) {
            (Some(a), Some(b)) => a != b,
            (Some(a), None) => *a > 0,
            _ => false,
        }
    }

    /// Whether route `route` changes lanes (or leaves the ring across another lane) where
    /// it leaves ring lane `lane`.
    pub(super) fn changes_lane_after(&self, route: usize, lane: LaneId) -> bool {
        let pieces = self.layout.routes[route].path.pieces();
        let Some(k) = pieces.iter().position(|p| p.key == PieceKey::Lane(lane)) else {
            return false;
        };
        match pieces.get(k + 2).map(|p| p.key) {
            Some(PieceKey::Lane(to)) => self.crosses_lanes(lane, to),
            _ => false,
        }
    }

    /// On a multi-lane ring, the car vehicle `i` waits for before its next lane change
    /// (`World::next_lane_change`), if any: a committed car coming along another lane of
    /// the ring road that `i` leaves, towards the same junction, and not clearly in front
    /// of it; it is in the way when it would be beside `i`, or behind it closer than
    /// `LANE_CHANGE_GAP_M` plus `LANE_CHANGE_HEADWAY_S` of its speed (positions
    /// compared as distances to where each leaves the road). A car about to change lanes
    /// there too that has not started goes first when its front is ahead (the lower index
    /// on a tie), so two such never wait for each other. A driver that could no longer
    /// stop short of the change (at the hardest braking) does not wait.
    pub fn lane_change_wait(&self, i: usize) -> Option<usize> {
        if !self.multi_lane {
            return None;
        }
        let me = &self.vehicles[i];
        if !me.committed {
            return None;
        }
        let (from, start_s) = self.next_lane_change(i)?;
        let to_line = start_s - me.front_s();
        if me.speed * me.speed / (2.0 * self.config.drivers.max_brake_mps2) > to_line {
            return None;
        }
        let roads = &self.layout.ring_lane_roads;
        let road = roads.get(&from)?;
        let q_me = me.s - start_s;
        let (my_front, my_rear) = (q_me + me.length / 2.0, q_me - me.length / 2.0);
        self.vehicles
            .iter()
            .enumerate()
            .filter(|&(j, o)| j != i && o.committed)
            .find_map(|(j, o)| {
                let route = &self.layout.routes[o.route];
                let (lane, end) = route
                    .ring_lanes
                    .iter()
                    .filter(|(l, _)| *l != from && roads.get(l) == Some(road))
                    .find_map(|&(l, _)| Some((l, route.ring_lane_end(l)?)))?;
                let q = o.s - end;
                if q < -self.config.horizon_m {
                    return None;
                }
                let (front, rear) = (q + o.length / 2.0, q - o.length / 2.0);
                if front < 0.0 && self.changes_lane_after(o.route, lane) {
                    let ahead = front > my_front || (front == my_front && j < i);
                    return ahead.then_some(j);
                }
                if rear > my_front + LANE_CHANGE_GAP_M {
                    return None; // clearly in front
                }
                let behind = my_rear - front;
                (behind < LANE_CHANGE_GAP_M + o.speed * LANE_CHANGE_HEADWAY_S).then_some(j)
            })
    }

    /// On a multi-lane ring, how far vehicle `i` can go before its footprint would touch a
    /// car entering across its way (committed, front past its yield line, not yet merged,
    /// and on a route in conflict with `i`'s: see [`RingRoute::entry_conflicts`]), where
    /// that car stands now, m. Such a car has taken its gap and may be held up on the
    /// ring's mouth (behind a queue on its merge lane); a car on an inner lane, which
    /// neither follows it nor merges behind it, waits for it as for a car standing there.
    pub(super) fn entering_across(&self, i: usize) -> Option<f64> {
        const STEP_M: f64 = 0.5;
        let me = &self.vehicles[i];
        let path = &self.layout.routes[me.route].path;
        self.vehicles
            .iter()
            .enumerate()
            .filter(|&(j, o)| j != i && o.committed)
            .filter_map(|(_, o)| {
                let r = &self.layout.routes[o.route];
                if o.front_s() <= r.yield_s || o.s >= r.merge_s + o.length / 2.0 {
                    return None;
                }
                let c = r.entry_conflicts.iter().find(|c| c.route == me.route)?;
                if me.s >= c.from_s {
                    return None;
                }
                let theirs = o.footprint();
                let steps = ((c.to_s - me.s) / STEP_M).ceil().max(0.0) as usize;
                (1..=steps).find_map(|k| {
                    let s = (me.s + k as f64 * STEP_M).min(c.to_s);
                    let (p, h) = path.pose_at(s);
                    OrientedBox::new(p, h, me.length, me.width)
                        .overlaps(&theirs)
                        .then_some(s - me.s - STEP_M)
                })
            })
            .min_by(f64::total_cmp)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// A waiting route and a route from another entry through its merge lane, with where
    /// that lane starts on the latter.
    fn crossing_routes(layout: &RoundaboutLayout) -> (usize, usize, f64) {
        layout
            .routes
            .iter()
            .enumerate()
            .find_map(|(w, wr)| {
                layout.routes.iter().enumerate().find_map(|(t, tr)| {
                    let start = tr.ring_lane_start(wr.merge_lane)?;
                    (tr.entry != wr.entry && start - 10.0 >= tr.merge_s).then_some((w, t, start))
                })
            })
            .unwrap()
    }

    #[test]
    fn a_driver_rejects_a_short_gap_and_takes_an_empty_ring() {
        let layout = crate::test_maps::montlake_layout();
        let (waiting, through, lane_start) = crossing_routes(&layout);
        let traffic = TrafficConfig {
            arrivals_per_s: 0.0,
            ..TrafficConfig::default()
        };
        let at_line = layout.routes[waiting].yield_s - 2.5;
        let world = |with_car: bool| {
            let mut world = World::new(
                Arc::clone(&layout),
                traffic.clone(),
                EgoConfig::default(),
                1,
            );
            world.insert_vehicle(waiting, at_line, 0.0, 0.5, false);
            if with_car {
                // 10 m before the merge point at 4 m/s: 2.5 s away.
                world.insert_vehicle(through, lane_start - 10.0, 4.0, 0.5, true);
            }
            for _ in 0..10 {
                world.step(0.0);
            }
            world.vehicles()[0].committed
        };
        assert!(world(false), "an empty ring: it goes");
        assert!(!world(true), "a car 2.5 s away: it waits");
    }

    #[test]
    fn the_lag_is_the_time_until_the_circulating_car_reaches_the_merge_point() {
        let layout = crate::test_maps::montlake_layout();
        let (waiting, through, lane_start) = crossing_routes(&layout);
        let traffic = TrafficConfig {
            arrivals_per_s: 0.0,
            ..TrafficConfig::default()
        };
        let mut world = World::new(Arc::clone(&layout), traffic, EgoConfig::default(), 1);
        world.insert_vehicle(
            waiting,
            layout.routes[waiting].yield_s - 2.5,
            0.0,
            0.5,
            false,
        );
        assert_eq!(world.merge_lag_s(0), None, "an empty ring");
        world.insert_vehicle(through, lane_start - 10.0, 4.0, 0.5, true);
        let lag = world.merge_lag_s(0).unwrap();
        assert!(lag > 0.0 && lag < 10.0, "{lag}");
    }
}
