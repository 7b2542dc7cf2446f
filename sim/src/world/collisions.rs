//! Collisions in the traffic world: which vehicle's footprint overlaps another's, and the
//! other vehicles taken out after a crash.

use super::*;

impl World {
    /// Counts the new collisions between other vehicles and takes those vehicles out (see
    /// [`World::step_ego`]).
    pub(super) fn clear_collisions(&mut self) {
        let pairs = self.overlapping_others();
        if pairs.is_empty() {
            self.colliding.clear();
            return;
        }
        let touching_ego: Vec<u32> = match self.ego_index() {
            Some(e) => {
                let ego = self.vehicles[e].footprint();
                self.vehicles
                    .iter()
                    .filter(|v| !v.is_ego() && v.footprint().overlaps(&ego))
                    .map(|v| v.id)
                    .collect()
            }
            None => Vec::new(),
        };
        let mut out: Vec<u32> = Vec::new();
        let mut kept = Vec::new();
        for (a, b) in pairs {
            if !self.colliding.contains(&(a, b)) {
                self.stats.collisions += 1;
            }
            if touching_ego.contains(&a) || touching_ego.contains(&b) {
                kept.push((a, b));
            } else {
                out.extend([a, b]);
            }
        }
        self.colliding = kept;
        let before = self.vehicles.len();
        self.vehicles.retain(|v| v.is_ego() || !out.contains(&v.id));
        self.stats.crashed += (before - self.vehicles.len()) as u64;
    }

    /// Index of a vehicle whose footprint overlaps vehicle `i`'s, if any (lowest index).
    pub fn collision_with(&mut self, i: usize) -> Option<usize> {
        self.grid.clear();
        for (j, v) in self.vehicles.iter().enumerate() {
            if j != i {
                let r = v.footprint().bounding_radius();
                let p = v.position;
                self.grid.insert(
                    j as u32,
                    Point::new(p.x - r, p.y - r),
                    Point::new(p.x + r, p.y + r),
                );
            }
        }
        let me = self.vehicles[i].footprint();
        let (p, r) = (me.centre, me.bounding_radius());
        let mut found = std::mem::take(&mut self.found);
        self.grid.query(
            Point::new(p.x - r, p.y - r),
            Point::new(p.x + r, p.y + r),
            &mut found,
        );
        let hit = found
            .iter()
            .map(|&j| j as usize)
            .find(|&j| self.vehicles[j].footprint().overlaps(&me));
        self.found = found;
        hit
    }

    /// Pairs of other vehicles (not the ego) whose footprints overlap, by id (lower
    /// first). Between steps, only pairs touching the ego as well are left (see
    /// [`World::step_ego`]), already counted as collisions.
    pub fn overlapping_others(&self) -> Vec<(u32, u32)> {
        let boxes: Vec<(u32, OrientedBox)> = self
            .vehicles
            .iter()
            .filter(|v| !v.is_ego())
            .map(|v| (v.id, v.footprint()))
            .collect();
        let mut out = Vec::new();
        for (k, (a, fa)) in boxes.iter().enumerate() {
            for (b, fb) in &boxes[k + 1..] {
                let reach = fa.bounding_radius() + fb.bounding_radius();
                if fa.centre.distance(fb.centre) <= reach && fa.overlaps(fb) {
                    out.push((*a.min(b), *a.max(b)));
                }
            }
        }
        out
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn two_overlapping_vehicles_collide_and_distant_ones_do_not() {
        let layout = crate::test_maps::montlake_layout();
        let route = longest_route(&layout);
        let traffic = TrafficConfig {
            arrivals_per_s: 0.0,
            ..TrafficConfig::default()
        };
        let mut world = World::new(layout, traffic, EgoConfig::default(), 1);
        let first = world.insert_vehicle(route, 5.0, 0.0, 0.5, false);
        world.insert_vehicle(route, 20.0, 0.0, 0.5, false);
        assert_eq!(world.collision_with(0), None);
        assert!(world.overlapping_others().is_empty());
        let third = world.insert_vehicle(route, 6.0, 0.0, 0.5, false);
        assert_eq!(world.collision_with(0), Some(2));
        assert_eq!(world.collision_with(1), None);
        assert_eq!(world.overlapping_others(), vec![(first, third)]);
    }

    fn longest_route(layout: &RoundaboutLayout) -> usize {
        (0..layout.routes.len())
            .max_by(|&a, &b| {
                let length = |r: usize| layout.routes[r].path.length();
                length(a).total_cmp(&length(b))
            })
            .unwrap()
    }
}
