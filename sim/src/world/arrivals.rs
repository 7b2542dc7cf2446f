//! Arrivals and departures: vehicles leave at the end of their route, and new ones arrive
//! on the approaches, at the level's rate under its cap or at each entry's flow.

use super::*;

impl World {
    /// Removes vehicles whose front has reached the end of their route.
    pub(super) fn despawn(&mut self) {
        let before = self.vehicles.len();
        let layout = &self.layout;
        self.vehicles
            .retain(|v| v.is_ego() || v.front_s() < layout.routes[v.route].path.length());
        self.stats.despawned += (before - self.vehicles.len()) as u64;
    }

    /// Below the cap, a new vehicle arrives with probability `arrivals_per_s * step` on a
    /// random approach (uniform over entries, then routes), if its start is free; with
    /// per-entry flows, see [`World::spawn_flows`].
    pub(super) fn spawn(&mut self) {
        if self.config.per_entry_arrivals() {
            self.spawn_flows();
            return;
        }
        if self.others_count() >= self.config.cap() {
            return;
        }
        let p = (self.config.arrivals_per_s * self.config.step_s).clamp(0.0, 1.0);
        // Every draw is made whether or not it is used, so one choice never shifts the next.
        let arrive = self.rng.random::<f64>() < p;
        let entry_draw: f64 = self.rng.random();
        let draws = self.spawn_draws();
        if !arrive {
            return;
        }
        let entries: Vec<usize> = self
            .layout
            .usable_entries()
            .filter(|&e| self.roomy_routes(e).next().is_some())
            .collect();
        if entries.is_empty() {
            return;
        }
        let entry = entries[((entry_draw * entries.len() as f64) as usize).min(entries.len() - 1)];
        self.try_spawn(entry, draws);
    }

    /// Per-entry flows: each entry's arrivals are a Poisson process at its rate; an arrival
    /// that cannot enter its approach yet waits (off the map) and spawns at the first step
    /// its start is free, so that the entry's flow is kept whatever the queue.
    pub(super) fn spawn_flows(&mut self) {
        for entry in 0..self.flow_rates.len() {
            let p = (self.flow_rates[entry] / 3600.0 * self.config.step_s).clamp(0.0, 1.0);
            let arrive = self.rng.random::<f64>() < p;
            let draws = self.spawn_draws();
            if arrive {
                self.pending[entry] += 1;
            }
            if self.pending[entry] > 0
                && self.others_count() < self.config.cap()
                && self.roomy_routes(entry).next().is_some()
                && self.try_spawn(entry, draws)
            {
                self.pending[entry] -= 1;
            }
        }
    }

    /// The random draws of one spawn (route, aggressiveness, length, width), in [0, 1).
    pub(super) fn spawn_draws(&mut self) -> [f64; 4] {
        [
            self.rng.random(),
            self.rng.random(),
            self.rng.random(),
            self.rng.random(),
        ]
    }

    /// The routes of `entry` where the longest car fits before its yield line: on a shorter
    /// approach (cut at a junction next to the ring) a car would appear already over its
    /// line, on top of the cars entering there.
    pub(super) fn roomy_routes(&self, entry: usize) -> impl Iterator<Item = usize> + '_ {
        let room = self
            .config
            .vehicle_length_m
            .at(0.0)
            .max(self.config.vehicle_length_m.at(1.0));
        self.layout.routes_by_entry[entry]
            .iter()
            .copied()
            .filter(move |&r| self.layout.routes[r].yield_s >= room)
    }

    /// Route `route`'s weight among its entry's routes (per-entry flows).
    pub(super) fn route_weight(&self, route: usize) -> f64 {
        self.route_weights
            .get(route)
            .copied()
            .unwrap_or(1.0)
            .max(0.0)
    }

    /// Spawns a vehicle on `entry` (a route of it, its driver and size from `draws`) if its
    /// start is free; counts a blocked spawn otherwise. Whether it spawned.
    pub(super) fn try_spawn(&mut self, entry: usize, draws: [f64; 4]) -> bool {
        let [route_draw, aggressiveness, length_draw, width_draw] = draws;
        let routes: Vec<usize> = self.roomy_routes(entry).collect();
        if routes.is_empty() {
            return false;
        }
        let total: f64 = routes.iter().map(|&r| self.route_weight(r)).sum();
        let route_index = if !self.config.per_entry_arrivals() || total <= 0.0 {
            routes[((route_draw * routes.len() as f64) as usize).min(routes.len() - 1)]
        } else {
            // The routes by their weights (where the entry's vehicles go).
            let mut left = route_draw * total;
            *routes
                .iter()
                .find(|&&r| {
                    left -= self.route_weight(r);
                    left < 0.0
                })
                .unwrap_or(&routes[routes.len() - 1])
        };
        let length = self.config.vehicle_length_m.at(length_draw);
        let width = self.config.vehicle_width_m.at(width_draw);
        let s = length / 2.0;
        let driver = Driver::new(&self.config.drivers, aggressiveness);
        // Nearest vehicle ahead on the same approach (same geometry up to the merge point).
        let layout = &self.layout;
        let ahead = self
            .vehicles
            .iter()
            .filter(|o| {
                layout.routes[o.route].entry == entry && o.s < layout.routes[o.route].merge_s
            })
            .map(|o| (o.s - o.length / 2.0 - length, o.speed))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        // Nor on top of a car of another route passing by.
        let (p, h) = layout.routes[route_index].path.pose_at(s);
        let footprint = OrientedBox::new(p, h, length, width);
        let touching = self
            .vehicles
            .iter()
            .any(|o| o.footprint().overlaps(&footprint));
        // On a multi-lane ring, nor where a car of another route is about to drive (where
        // an exit runs over the start of another arm's approach): it would stop there for
        // the new car, which waits behind the queue that car holds up.
        let in_the_way = self.multi_lane
            && self.vehicles.iter().any(|o| {
                let path = &layout.routes[o.route].path;
                let front = o.s + o.length / 2.0;
                let to = (front + SPAWN_LOOK_M).min(path.length());
                let steps = ((to - o.s) / 1.0).ceil().max(0.0) as usize;
                (1..=steps).any(|k| {
                    let (q, g) = path.pose_at((o.s + k as f64).min(to));
                    OrientedBox::new(q, g, o.length, o.width).overlaps(&footprint)
                })
            });
        let touching = touching || in_the_way;
        if touching || ahead.is_some_and(|(gap, _)| gap < self.config.spawn_clearance_m) {
            self.stats.spawns_blocked += 1;
            return false;
        }
        let route = &self.layout.routes[route_index];
        let v0 = route.path.speed_at(s) * driver.speed_factor;
        // Arrive no faster than lets the driver stop behind whoever is ahead.
        let speed = match ahead {
            Some((gap, lead_speed)) => {
                v0.min(lead_speed + (2.0 * driver.comfort_decel_mps2 * gap).sqrt())
            }
            None => v0,
        };
        let vehicle = self.new_vehicle(route_index, s, speed, (length, width), driver);
        self.vehicles.push(vehicle);
        self.stats.spawned += 1;
        true
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn arrivals_follow_the_configured_flow_over_a_long_run() {
        let layout = crate::test_maps::montlake_layout();
        let entry = layout.usable_entries().next().unwrap();
        let traffic = TrafficConfig {
            level: TrafficLevel::Recorded,
            flows: vec![EntryFlow {
                lane: layout.entries[entry].lane.0,
                vph: 360.0,
                exits: Vec::new(),
            }],
            ..TrafficConfig::default()
        };
        let mut world = World::new(Arc::clone(&layout), traffic, EgoConfig::default(), 5);
        let mut entries = std::collections::BTreeSet::new();
        // Twenty minutes at 360 veh/h: 120 arrivals expected (Poisson, sd 11).
        let steps = (1200.0 / world.config().step_s).round() as usize;
        for _ in 0..steps {
            world.step(0.0);
            entries.extend(
                world
                    .vehicles()
                    .iter()
                    .map(|v| layout.routes[v.route].entry),
            );
        }
        let spawned = world.stats().spawned;
        assert!((90..=150).contains(&spawned), "{spawned} arrivals");
        assert_eq!(
            entries.into_iter().collect::<Vec<_>>(),
            vec![entry],
            "only the entry with a flow"
        );
        assert!(
            world.stats().despawned > spawned / 2,
            "they leave at their exits"
        );
    }

    #[test]
    fn the_level_caps_the_vehicles_in_the_roundabout() {
        let layout = crate::test_maps::montlake_layout();
        let traffic = TrafficConfig {
            level: TrafficLevel::Low,
            arrivals_per_s: 2.0,
            ..TrafficConfig::default()
        };
        let cap = traffic.cap();
        let mut world = World::new(layout, traffic, EgoConfig::default(), 2);
        let mut most = 0;
        for _ in 0..600 {
            world.step(0.0);
            most = most.max(world.others_count());
        }
        assert_eq!(most, cap, "filled up to the cap, never beyond");
    }
}
