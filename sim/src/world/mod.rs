//! The traffic world around one roundabout: vehicles on the routes of a
//! [`RoundaboutLayout`], moved every fixed step.
//!
//! - Other vehicles drive their route exactly (position = arc length along it): IDM
//!   car-following behind the nearest vehicle ahead on their path, where "ahead" includes a
//!   committed vehicle about to merge into a lane they are about to enter and that is nearer
//!   to the merge point; before the yield line an uncommitted vehicle stops at the line
//!   until it accepts a gap in circulating traffic (gap acceptance with a critical gap).
//! - Each driver has an aggressiveness in [0, 1]: higher means a higher desired speed,
//!   shorter headways, harder acceleration and shorter accepted gaps.
//! - Vehicles enter at the upstream end of an approach and leave at the downstream end of
//!   an exit; at most [`TrafficConfig::cap`] others are in the roundabout (its
//!   approaches, ring and exits) at once.
//! - The ego (optional) is a kinematic bicycle: the caller chooses its acceleration (or
//!   lets the ego's own driver model choose it, IDM and gap acceptance as for the others)
//!   and its steering (or lets a pure pursuit controller steer it along its route).
//!
//! Everything random comes from one ChaCha8 generator seeded at [`World::new`]; vehicles
//! live in a `Vec` in spawn order, so a seed always gives the same world.
//!
//! By concern: [`World`] and its step here; the settings in `config.rs` (levels, flows,
//! the capacity model, [`CalibratedWorld`], the ego), the drivers in `drivers.rs`, car
//! following in `following.rs`, gap acceptance and lane changes at the ring in
//! `priority.rs`, arrivals and departures in `arrivals.rs`, collisions in
//! `collisions.rs`.

use std::sync::Arc;

use maps::{LaneId, Point};
use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::kinematics::{Bicycle, advance_speed};
use crate::path::PieceKey;
use crate::roundabout::{LayoutConfig, RingRoute, RoundaboutLayout};
use crate::scene::{Actor, ActorKind, OrientedBox};
use crate::spatial::UniformGrid;

mod arrivals;
mod collisions;
mod config;
mod drivers;
mod following;
mod priority;

pub use config::{
    CalibratedWorld, CapacityModel, EgoCommand, EgoConfig, EntryFlow, ExitShare, TrafficConfig,
    TrafficLevel,
};
pub use drivers::{CriticalGap, Driver, DriverConfig, DriverGap, GapAcceptance, Span};

/// See [`World::standing_mps`], m/s.
const CROSSING_MPS: f64 = f64::INFINITY;
/// Drivers with a measured critical gap never take a gap closing sooner than this after
/// they would have cleared the merge point (or the zone where cars leaving the ring cross
/// their entry), s.
const CLEARING_MARGIN_S: f64 = 0.5;
/// Drivers with a measured critical gap brake for their yield line at this share of their
/// comfortable deceleration, reaching the speed that allows within this time, s.
const ROLLING_DECEL_SHARE: f64 = 0.7;
const ROLLING_REACT_S: f64 = 0.5;
/// Drivers with a measured critical gap enter only with this much room beyond a slow car
/// (under [`QUEUE_MPS`]) just past their merge point, m.
const ROOM_TO_ENTER_M: f64 = 3.0;
const QUEUE_MPS: f64 = 3.0;
/// How far ahead other drivers look for cars covering their path, m.
const OTHERS_OBSTACLE_HORIZON_M: f64 = 8.0;
/// Below this speed a driver has stopped (and a commitment to a gap is reconsidered).
const STOPPED_MPS: f64 = 0.1;
/// A car does not spawn where another car would drive over it within this distance of
/// that car's front (on multi-lane rings), m.
const SPAWN_LOOK_M: f64 = 25.0;
/// Below this speed a car on another's path is in its way whatever its heading (on
/// multi-lane rings: see [`World::obstacle_on_path`]), m/s.
const STANDING_MPS: f64 = 0.5;
/// Drivers look for cars in the other lanes once a lane change on the ring is this close
/// ahead of their front, m.
const LANE_CHANGE_LOOK_M: f64 = 25.0;
/// A driver changes lanes in front of a car in the other lane only with at least this gap
/// to it, m, plus [`LANE_CHANGE_HEADWAY_S`] of that car's speed.
const LANE_CHANGE_GAP_M: f64 = 1.0;
const LANE_CHANGE_HEADWAY_S: f64 = 1.2;

/// One vehicle of the world.
#[derive(Debug, Clone)]
pub struct Vehicle {
    pub id: u32,
    /// Index into the layout's routes.
    pub route: usize,
    /// Arc length of the vehicle's centre along its route, m.
    pub s: f64,
    pub speed: f64,
    /// Acceleration applied in the last step, m/s².
    pub accel: f64,
    pub length: f64,
    pub width: f64,
    pub driver: Driver,
    /// Past gap acceptance: the vehicle will enter the ring (others treat it as merging).
    pub committed: bool,
    pub position: Point,
    pub heading: f64,
    /// Index of the route piece under the centre.
    pub piece: usize,
    /// When the vehicle's centre first passed its merge point, s of world time.
    pub entered_ring_at: Option<f64>,
    /// The ego's bicycle state; None for the others.
    bicycle: Option<Bicycle>,
}

impl Vehicle {
    pub fn is_ego(&self) -> bool {
        self.bicycle.is_some()
    }

    pub fn footprint(&self) -> OrientedBox {
        OrientedBox::new(self.position, self.heading, self.length, self.width)
    }

    fn front_s(&self) -> f64 {
        self.s + self.length / 2.0
    }
}

/// Counters over a world's life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct WorldStats {
    pub spawned: u64,
    /// Vehicles that left by the end of their route.
    pub despawned: u64,
    /// Spawns skipped because the chosen approach was occupied near its start.
    pub spawns_blocked: u64,
    /// Collisions between other vehicles (not the ego): pairs whose footprints came to
    /// overlap, each pair counted once (see [`World::step_ego`]).
    pub collisions: u64,
    /// Other vehicles taken out of the world after a collision.
    pub crashed: u64,
}

/// The nearest vehicle ahead of another: its index, the bumper-to-bumper gap and how fast
/// the follower closes in on it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Leader {
    pub index: usize,
    pub gap_m: f64,
    pub closing_mps: f64,
    /// Found as a vehicle merging in from another piece (not yet on the follower's path).
    pub merging: bool,
}

/// Where a vehicle's route goes next: each piece ahead within the horizon with the
/// distance from the vehicle's centre to the piece's start (negative for the current one).
type Lookahead = Vec<(PieceKey, f64)>;

/// The traffic around one roundabout.
#[derive(Debug, Clone)]
pub struct World {
    layout: Arc<RoundaboutLayout>,
    config: TrafficConfig,
    ego_config: EgoConfig,
    rng: ChaCha8Rng,
    vehicles: Vec<Vehicle>,
    next_id: u32,
    time_s: f64,
    stats: WorldStats,
    grid: UniformGrid,
    /// Scratch: what each vehicle sees ahead, refreshed each step.
    lookahead: Vec<Lookahead>,
    /// The ring has lanes side by side somewhere (see [`World::entering_across`]).
    multi_lane: bool,
    found: Vec<u32>,
    /// Pairs of other vehicles (ids, lower first) counted as a collision and still
    /// overlapping (left in place because one of them touches the ego).
    colliding: Vec<(u32, u32)>,
    /// Per vehicle, whether it waits to change lanes ([`World::lane_change_wait`]),
    /// refreshed with the lookahead.
    waiting_to_change: Vec<bool>,
    /// With per-entry flows: each layout entry's arrival rate, veh/h, and the arrivals
    /// waiting off the map for room on its approach.
    flow_rates: Vec<f64>,
    pending: Vec<u32>,
    /// With per-entry flows that say where their vehicles go: each route's weight.
    route_weights: Vec<f64>,
}

impl World {
    /// An empty world on `layout`, all draws from `seed`.
    pub fn new(
        layout: Arc<RoundaboutLayout>,
        config: TrafficConfig,
        ego_config: EgoConfig,
        seed: u64,
    ) -> Self {
        let mut region = layout.bounds;
        if !region.is_empty() {
            region.extend(Point::new(region.min.x - 10.0, region.min.y - 10.0));
            region.extend(Point::new(region.max.x + 10.0, region.max.y + 10.0));
        }
        let flow_rates = config.entry_rates(&layout);
        let route_weights = layout
            .routes
            .iter()
            .map(|r| {
                let entry_lane = layout.entries[r.entry].lane.0;
                let exit_lane = layout.exits[r.exit].lane.0;
                let flows: Vec<&EntryFlow> = config
                    .flows
                    .iter()
                    .filter(|_| config.level == TrafficLevel::Recorded)
                    .filter(|f| f.lane == entry_lane && !f.exits.is_empty())
                    .collect();
                if flows.is_empty() {
                    return 1.0;
                }
                flows
                    .iter()
                    .flat_map(|f| &f.exits)
                    .filter(|x| x.lane == exit_lane)
                    .map(|x| x.share)
                    .sum()
            })
            .collect();
        World {
            route_weights,
            pending: vec![0; flow_rates.len()],
            flow_rates,
            grid: UniformGrid::new(region, 8.0),
            multi_lane: layout.ring_lane_ranks.values().any(|r| *r > 0),
            layout,
            config,
            ego_config,
            rng: ChaCha8Rng::seed_from_u64(seed),
            vehicles: Vec::new(),
            next_id: 0,
            time_s: 0.0,
            stats: WorldStats::default(),
            lookahead: Vec::new(),
            found: Vec::new(),
            colliding: Vec::new(),
            waiting_to_change: Vec::new(),
        }
    }

    pub fn layout(&self) -> &Arc<RoundaboutLayout> {
        &self.layout
    }

    pub fn config(&self) -> &TrafficConfig {
        &self.config
    }

    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    pub fn stats(&self) -> WorldStats {
        self.stats
    }

    /// Arrivals of per-entry flows still waiting off the map for room on their approach.
    pub fn waiting_to_enter(&self) -> u64 {
        self.pending.iter().map(|&n| u64::from(n)).sum()
    }

    pub fn vehicles(&self) -> &[Vehicle] {
        &self.vehicles
    }

    pub fn route(&self, vehicle: &Vehicle) -> &RingRoute {
        &self.layout.routes[vehicle.route]
    }

    /// Whether the world takes the care multi-lane rings need: a multi-lane ring, or drivers
    /// with measured critical gaps (who commit from farther off).
    fn careful(&self) -> bool {
        self.multi_lane || self.config.drivers.critical_gap.measured().is_some()
    }

    /// Below this speed a car on another's path is in its way whatever its heading (on
    /// careful worlds): [`STANDING_MPS`] on multi-lane rings, [`CROSSING_MPS`] (any speed)
    /// among drivers with measured critical gaps: a car entering across an exit is braked
    /// for (judging gaps from farther off, they misjudge more often).
    fn standing_mps(&self) -> f64 {
        if self.multi_lane {
            STANDING_MPS
        } else {
            CROSSING_MPS
        }
    }

    /// Index of the ego in [`World::vehicles`].
    pub fn ego_index(&self) -> Option<usize> {
        self.vehicles.iter().position(Vehicle::is_ego)
    }

    /// Vehicles other than the ego.
    pub fn others_count(&self) -> usize {
        self.vehicles.iter().filter(|v| !v.is_ego()).count()
    }

    /// Other vehicles on the ring (between their merge point and their exit).
    pub fn circulating(&self) -> usize {
        self.vehicles
            .iter()
            .filter(|v| {
                let r = &self.layout.routes[v.route];
                !v.is_ego() && v.s >= r.merge_s && v.s < r.exit_s
            })
            .count()
    }

    /// Simulates `seconds` of traffic (used before the ego appears).
    pub fn warm_up(&mut self, seconds: f64) {
        let steps = (seconds / self.config.step_s).round().max(0.0) as usize;
        for _ in 0..steps {
            self.step(0.0);
        }
    }

    /// A vehicle (not yet in the world) on `route` with its centre at `s`, uncommitted,
    /// with the next id.
    fn new_vehicle(
        &mut self,
        route: usize,
        s: f64,
        speed: f64,
        (length, width): (f64, f64),
        driver: Driver,
    ) -> Vehicle {
        let path = &self.layout.routes[route].path;
        let (position, heading) = path.pose_at(s);
        let id = self.next_id;
        self.next_id += 1;
        Vehicle {
            id,
            route,
            s,
            speed,
            accel: 0.0,
            length,
            width,
            driver,
            committed: false,
            position,
            heading,
            piece: path.piece_at(s, 0),
            entered_ring_at: None,
            bicycle: None,
        }
    }

    /// Adds another vehicle on route `route` with its centre at `s` (for tests and for
    /// scenarios replayed from logs); `committed` marks it as past gap acceptance. Returns
    /// its id.
    pub fn insert_vehicle(
        &mut self,
        route: usize,
        s: f64,
        speed: f64,
        aggressiveness: f64,
        committed: bool,
    ) -> u32 {
        let size = (
            self.config.vehicle_length_m.at(0.5),
            self.config.vehicle_width_m.at(0.5),
        );
        let driver = Driver::new(&self.config.drivers, aggressiveness);
        let vehicle = self.new_vehicle(route, s, speed, size, driver);
        let id = vehicle.id;
        self.vehicles.push(Vehicle {
            committed,
            ..vehicle
        });
        self.refresh_lookahead();
        id
    }

    /// Puts the ego on route `route` with its centre at `s`, driving at `speed`. Other
    /// vehicles on the same approach within `clear_m` of it, or touching it, are removed.
    /// Replaces any previous ego.
    pub fn insert_ego(&mut self, route: usize, s: f64, speed: f64, clear_m: f64) {
        self.vehicles.retain(|v| !v.is_ego());
        let r = &self.layout.routes[route];
        let (position, heading) = r.path.pose_at(s);
        let cfg = self.ego_config;
        let ego_box = OrientedBox::new(position, heading, cfg.length_m + 4.0, cfg.width_m + 2.0);
        let layout = Arc::clone(&self.layout);
        self.vehicles.retain(|v| {
            let same_approach =
                layout.routes[v.route].entry == r.entry && v.s < layout.routes[v.route].merge_s;
            let near = same_approach && (v.s - s).abs() < clear_m + (v.length + cfg.length_m) / 2.0;
            !(near || v.footprint().overlaps(&ego_box))
        });
        let driver = Driver::new(&self.config.drivers, 0.5);
        let vehicle = self.new_vehicle(route, s, speed, (cfg.length_m, cfg.width_m), driver);
        self.vehicles.push(Vehicle {
            bicycle: Some(Bicycle::at_centre(position, heading, cfg.wheelbase_m)),
            ..vehicle
        });
        self.refresh_lookahead();
    }

    /// Advances one step: the ego (if any) with acceleration `ego_accel` (clamped to its
    /// limits), everyone else by their driver model; then vehicles past their exit leave,
    /// new ones may arrive, and collisions between others are counted and cleared (see
    /// [`World::step_ego`]).
    pub fn step(&mut self, ego_accel: f64) {
        self.step_ego(EgoCommand {
            accel: Some(ego_accel),
            steer_rad: None,
        });
    }

    /// Like [`World::step`], with the ego's steering optionally chosen by the caller
    /// instead of the pure pursuit controller.
    ///
    /// At the end of the step, every pair of other vehicles (not the ego) whose footprints
    /// overlap and did not already at the end of the last step counts as one collision
    /// ([`WorldStats::collisions`]), and both vehicles are taken out of the world
    /// ([`WorldStats::crashed`]), as a crash ends the ego's episode: no overlap goes on
    /// uncounted, and no wreck is left to block the ring. A vehicle touching the ego is left
    /// where it is, so that the caller sees the ego's crash ([`World::collision_with`]); its
    /// pair with another vehicle is not counted again while they still overlap.
    pub fn step_ego(&mut self, ego: EgoCommand) {
        let dt = self.config.step_s;
        let ego_driven = ego.accel.is_none();
        self.decide_gaps(ego_driven);
        let accels: Vec<f64> = (0..self.vehicles.len())
            .map(|i| match (self.vehicles[i].is_ego(), ego.accel) {
                (true, Some(a)) => a,
                _ => self.driver_accel(i),
            })
            .collect();
        let brake = self.config.drivers.max_brake_mps2;
        for (i, a) in accels.into_iter().enumerate() {
            if self.vehicles[i].is_ego() {
                self.move_ego(i, a, ego.steer_rad, dt);
            } else {
                let v = &mut self.vehicles[i];
                let a = a.clamp(-brake, v.driver.max_accel_mps2);
                let (new_speed, ds) = advance_speed(v.speed, a, dt);
                v.s += ds;
                v.speed = new_speed;
                v.accel = a;
                let route = &self.layout.routes[v.route];
                let (p, h) = route.path.pose_at(v.s);
                v.position = p;
                v.heading = h;
                v.piece = route.path.piece_at(v.s, v.piece);
            }
        }
        self.time_s += dt;
        for v in &mut self.vehicles {
            if v.entered_ring_at.is_none() && v.s >= self.layout.routes[v.route].merge_s {
                v.entered_ring_at = Some(self.time_s);
            }
        }
        self.despawn();
        self.spawn();
        self.clear_collisions();
        self.refresh_lookahead();
    }

    /// Moves the ego one step with acceleration `accel`: the commanded steering, or pure
    /// pursuit on its route.
    fn move_ego(&mut self, i: usize, accel: f64, steer_rad: Option<f64>, dt: f64) {
        let cfg = self.ego_config;
        let layout = Arc::clone(&self.layout);
        let v = &mut self.vehicles[i];
        let Some(mut bike) = v.bicycle else { return };
        let path = &layout.routes[v.route].path;
        let a = accel.clamp(-cfg.max_brake_mps2, cfg.max_accel_mps2);
        let (new_speed, travelled) = advance_speed(v.speed, a, dt);
        let steer = match steer_rad {
            Some(steer) => steer.clamp(-cfg.max_steer_rad, cfg.max_steer_rad),
            None => {
                let front_hint = v.s + cfg.wheelbase_m / 2.0;
                let (s_front, _) = path.project(bike.front(), front_hint, 2.0, 2.0);
                let (point, heading) = path.pose_at(s_front);
                bike.stanley(point, heading, v.speed, cfg.stanley_gain, cfg.max_steer_rad)
            }
        };
        bike.advance(travelled, steer);
        v.position = bike.centre();
        v.heading = bike.heading;
        v.bicycle = Some(bike);
        v.speed = new_speed;
        v.accel = a;
        let (s, _) = path.project(v.position, v.s, 1.0, travelled + 2.0);
        v.s = s.max(v.s);
        v.piece = path.piece_at(v.s, v.piece);
        let route = &layout.routes[v.route];
        // The ego is committed once its front is clearly past the yield line (or once its
        // driver model accepted a gap; `s` never decreases, so this stays set either way).
        v.committed = v.committed || v.front_s() > route.yield_s + 0.5;
    }

    /// For each vehicle, the pieces of its route within the horizon. Kept fresh between
    /// steps (refreshed at the end of every change of the vehicles).
    fn refresh_lookahead(&mut self) {
        let horizon = self.config.horizon_m;
        self.lookahead.resize_with(self.vehicles.len(), Vec::new);
        for (v, out) in self.vehicles.iter().zip(&mut self.lookahead) {
            out.clear();
            let pieces = self.layout.routes[v.route].path.pieces();
            for p in &pieces[v.piece.min(pieces.len() - 1)..] {
                let d = p.s_start - v.s;
                if d > horizon {
                    break;
                }
                out.push((p.key, d));
            }
        }
        self.waiting_to_change = (0..self.vehicles.len())
            .map(|i| self.lane_change_wait(i).is_some())
            .collect();
    }

    /// Where vehicle `j`'s route starts piece `key` relative to `j`'s centre, if ahead
    /// within the horizon (or the current piece: negative).
    fn distance_to_piece(&self, j: usize, key: PieceKey) -> Option<f64> {
        self.lookahead[j]
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, d)| *d)
    }

    /// The road users as scene actors, in vehicle order.
    pub fn actors(&self) -> Vec<Actor> {
        self.vehicles
            .iter()
            .map(|v| {
                let route = &self.layout.routes[v.route];
                Actor {
                    id: v.id,
                    kind: ActorKind::Car,
                    position: v.position,
                    heading_rad: v.heading,
                    speed_mps: v.speed,
                    length_m: v.length,
                    width_m: v.width,
                    lane: match route.path.pieces().get(v.piece).map(|p| p.key) {
                        Some(PieceKey::Lane(l)) => Some(l),
                        _ => None,
                    },
                    aggressiveness: (!v.is_ego()).then_some(v.driver.aggressiveness),
                }
            })
            .collect()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn busy_world(seed: u64) -> World {
        let traffic = TrafficConfig {
            level: TrafficLevel::High,
            ..TrafficConfig::default()
        };
        World::new(
            crate::test_maps::montlake_layout(),
            traffic,
            EgoConfig::default(),
            seed,
        )
    }

    fn positions(world: &World) -> Vec<(u32, f64, f64)> {
        world
            .vehicles()
            .iter()
            .map(|v| (v.id, v.position.x, v.position.y))
            .collect()
    }

    #[test]
    fn a_seed_always_gives_the_same_world() {
        let (mut a, mut b, mut other) = (busy_world(3), busy_world(3), busy_world(4));
        for world in [&mut a, &mut b, &mut other] {
            world.warm_up(60.0);
        }
        assert!(!a.vehicles().is_empty(), "traffic arrived");
        assert_eq!(positions(&a), positions(&b));
        assert_eq!(a.stats(), b.stats());
        assert_ne!(positions(&a), positions(&other));
        assert!((a.time_s() - 60.0).abs() < 1e-6, "{}", a.time_s());
    }

    #[test]
    fn the_ego_drives_its_route_at_the_acceleration_it_is_given() {
        let mut world = World::new(
            crate::test_maps::montlake_layout(),
            TrafficConfig {
                arrivals_per_s: 0.0,
                ..TrafficConfig::default()
            },
            EgoConfig::default(),
            1,
        );
        assert_eq!(world.ego_index(), None);
        world.insert_ego(0, 5.0, 0.0, 8.0);
        let ego = world.ego_index().unwrap();
        let start = world.vehicles()[ego].position;
        for _ in 0..10 {
            world.step(1.0);
        }
        let v = &world.vehicles()[world.ego_index().unwrap()];
        assert!(
            (v.speed - 1.0).abs() < 0.05,
            "{} m/s after 1 s at 1 m/s²",
            v.speed
        );
        let moved = v.position.distance(start);
        assert!((0.3..0.7).contains(&moved), "{moved} m");
        assert_eq!(world.others_count(), 0);
    }
}
