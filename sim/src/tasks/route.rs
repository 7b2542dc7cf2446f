//! Campus route following (the AIT lane-keeping study with the MTSU route goal): the ego
//! follows a planned route over an imported map, keeping in its lane among other traffic.
//!
//! - Routes: a pool of fastest routes between random lanes of the map (`maps::route`),
//!   `route_length_m` long, drawn once per map from `pool_seed`. A fixed share of them
//!   (`held_out_fraction`, chosen by a hash of their end lanes) is held out: training
//!   episodes never see them, evaluation on [`RouteSplit::HeldOut`] uses only them.
//! - Actions ([`SteerAction`], as roundabout driving's, but on steering increments):
//!   **forward** (steering kept), **forward+left**
//!   (steering + `steer_increment_rad`), **forward+right** (− the same), within
//!   ±`max_steer_rad`. Speed is not the agent's: the ego accelerates to `max_speed_kmh`
//!   (8 km/h by default, the study's campus speed) and brakes (IDM) behind a vehicle in its
//!   lane ahead.
//! - Other traffic: `other_vehicles` vehicles on other routes of the pool near the ego's
//!   and on the ego's own route ahead of it, each driving its route at its own steady speed
//!   (they do not react to the ego: a road user that does not yield, as on a campus).
//! - Reward per decision: `speed / max_speed + in-lane fraction` (the share of the ego's
//!   width within its lane), replaced by `below_lane_penalty` (−1) when the fraction is
//!   under `in_lane_threshold` (0.98); `steer_change_penalty` (−0.2) on a steering change;
//!   `terminal_penalty` (−4) when the ego goes off road or hits a vehicle.
//! - Termination: Reached (the route's end), Crashed, OffRoad (the ego's centre more than
//!   `off_road_m` beyond its lane's edge), TimeOver (`time_limit_factor` × the route's
//!   time at the maximum speed, plus 10 s).
//! - Observation: the route ahead in the ego's frame (lateral offsets of the route's centre
//!   line at `lookahead_m` metres along it), the lane's half width, speed and steering
//!   angle, and the nearest other vehicle within 20 m (ego-frame position): a navigation
//!   system gives a driver the route the same way. Layers by `view`: none (`"scalars"`, the
//!   default), the bird's-eye layers of the scene around the ego (`"bev"`, the `bev` table;
//!   the route is the `path` layer), or the front camera's segmented view
//!   (`"camera-segmentation"`, the `camera` table, drawn by an observer given to
//!   [`RouteSetup::with_observer`]).
//! - Metrics: route completion (share of the route driven), lane-centre RMS error (m),
//!   time in lane (share of decisions at or above the in-lane threshold).

use std::sync::Arc;

use maps::route::Router;
use maps::{LaneId, Map, Point};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::env::{Observation, ObservationSpec, Outcome};
use crate::error::SimError;
use crate::kinematics::{Bicycle, advance_speed, direction};
use crate::observer::{CameraViewConfig, SceneObserver, View, checked_observer};
use crate::path::{Path, PieceKey, SpeedProfile, wrap_angle};
use crate::render::{BevConfig, BevRenderer};
use crate::scene::{Actor, ActorKind, OrientedBox, Scene};
use crate::seed::derive_seed;
use crate::tasks::ring_driving::SteerAction;
use crate::tasks::roundabouts::EgoView;
use crate::tasks::{
    ConditionChoice, Driving, Episode, PolicyFactory, Task, TaskId, TaskPolicy, TaskSetup,
    TaskSummary, baselines_with_rule, required_map,
};
use crate::world::{Driver, DriverConfig, EgoConfig, TrafficLevel};

/// Distance within which the nearest other vehicle is an input, m.
const NEAR_M: f64 = 20.0;

/// Reward constants (the AIT study's).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RouteReward {
    pub in_lane_threshold: f64,
    pub below_lane_penalty: f64,
    pub terminal_penalty: f64,
    pub steer_change_penalty: f64,
}

impl Default for RouteReward {
    fn default() -> Self {
        RouteReward {
            in_lane_threshold: 0.98,
            below_lane_penalty: -1.0,
            terminal_penalty: -4.0,
            steer_change_penalty: -0.2,
        }
    }
}

/// `[agent.route]`: the route-following task's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RouteConfig {
    /// The ego's size, wheelbase and steering limit (`max_steer_rad`).
    pub ego: EgoConfig,
    pub max_speed_kmh: f64,
    /// Simulation step, s.
    pub step_s: f64,
    /// Simulation steps per decision.
    pub action_repeat: usize,
    pub steer_increment_rad: f64,
    /// Length range of the routes in the pool, m (the MTSU routes were about 128 m).
    pub route_length_m: (f64, f64),
    /// Routes in the pool.
    pub pool_size: usize,
    /// Seed of the pool (fixed, so a map always has the same routes and held-out set).
    pub pool_seed: u64,
    /// Share of the pool held out of training.
    pub held_out_fraction: f64,
    pub other_vehicles: usize,
    /// Speed range of the other vehicles, m/s.
    pub other_speed_mps: (f64, f64),
    /// Lateral distances of the route's centre line are given at these distances ahead, m.
    pub lookahead_m: Vec<f64>,
    /// Beyond the lane's edge, m, the ego is off road.
    pub off_road_m: f64,
    pub time_limit_factor: f64,
    pub reward: RouteReward,
    /// Which layers the agent sees besides its scalars: `scalars` (none), `bev` (the `bev`
    /// table, or [`RouteConfig::default_bev`]) or `camera-segmentation` (the `camera` table).
    #[serde(skip_serializing_if = "is_scalars")]
    pub view: View,
    /// The bird's-eye layers of `view = "bev"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bev: Option<BevConfig>,
    /// The camera-segmentation view's settings (`segmenter` is required for that view).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraViewConfig>,
}

fn is_scalars(view: &View) -> bool {
    *view == View::Scalars
}

impl Default for RouteConfig {
    fn default() -> Self {
        RouteConfig {
            ego: EgoConfig::default(),
            max_speed_kmh: 8.0,
            step_s: 0.1,
            action_repeat: 2,
            steer_increment_rad: 0.1,
            route_length_m: (80.0, 200.0),
            pool_size: 200,
            pool_seed: 7,
            held_out_fraction: 0.25,
            other_vehicles: 4,
            other_speed_mps: (1.0, 4.0),
            lookahead_m: vec![0.0, 2.0, 4.0, 6.0, 8.0, 11.0, 14.0, 18.0],
            off_road_m: 1.5,
            time_limit_factor: 2.0,
            reward: RouteReward::default(),
            view: View::Scalars,
            bev: None,
            camera: None,
        }
    }
}

impl RouteConfig {
    fn validate(&self) -> Result<(), SimError> {
        let (lo, hi) = self.route_length_m;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let problem = if !positive(self.max_speed_kmh) {
            Some("max_speed_kmh must be positive")
        } else if !positive(self.step_s) || self.action_repeat == 0 {
            Some("step_s and action_repeat must be positive")
        } else if !positive(lo) || hi.is_nan() || hi < lo {
            Some("route_length_m must be (min, max) with 0 < min <= max")
        } else if self.pool_size == 0 {
            Some("pool_size must be positive")
        } else if !(0.0..1.0).contains(&self.held_out_fraction) {
            Some("held_out_fraction must be in [0, 1)")
        } else if self.lookahead_m.is_empty() {
            Some("lookahead_m needs at least one distance")
        } else if self.view == View::CameraSegmentation && self.camera.is_none() {
            Some(
                "view = \"camera-segmentation\" needs a [agent.route.camera] table with \
                 segmenter = \"<model folder>\"",
            )
        } else {
            None
        };
        if let Some(p) = problem {
            return Err(SimError::Config(format!("[agent.route]: {p}")));
        }
        match self.view {
            View::Scalars => Ok(()),
            View::Bev => self.bev_config().validate(),
            View::CameraSegmentation => self.camera.as_ref().map_or(Ok(()), |c| c.validate()),
        }
    }

    /// The bird's-eye view of a campus drive when no `bev` table is given: 42 × 42 pixels
    /// over 24 m (0.57 m a pixel), navigable area, route (1.5 m wide), vehicles; 2 frames.
    pub fn default_bev() -> BevConfig {
        BevConfig {
            width: 42,
            height: 42,
            forward_m: 24.0,
            lateral_m: 24.0,
            layers: vec![
                crate::render::Layer::Navigable,
                crate::render::Layer::Path,
                crate::render::Layer::Obstacles,
            ],
            stack: 2,
            map_resolution_m: 0.25,
            path_width_m: 1.5,
            ..BevConfig::default()
        }
    }

    /// The bird's-eye view used by `view = "bev"`.
    pub fn bev_config(&self) -> BevConfig {
        self.bev.clone().unwrap_or_else(Self::default_bev)
    }

    /// Scalar inputs: the route offsets, lane half width, speed, steering, nearest vehicle.
    pub fn scalars(&self) -> usize {
        self.lookahead_m.len() + 5
    }

    /// The shape of the task's observations with this config.
    pub fn observation_spec(&self) -> ObservationSpec {
        let scalars = self.scalars();
        match (self.view, &self.camera) {
            (View::Bev, _) => self.bev_config().observation_spec(scalars),
            (View::CameraSegmentation, Some(camera)) => camera.observation_spec(scalars),
            _ => ObservationSpec {
                channels: 0,
                height: 0,
                width: 0,
                scalars,
            },
        }
    }

    fn max_speed_mps(&self) -> f64 {
        self.max_speed_kmh / 3.6
    }
}

/// Which routes of the pool episodes draw from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RouteSplit {
    /// The routes training sees.
    Training,
    /// The routes training never sees.
    HeldOut,
}

/// One planned route: its path and the lane width along it.
#[derive(Debug)]
struct PlannedRoute {
    path: Path,
    /// Lane width every metre along the path.
    widths: Vec<f64>,
    held_out: bool,
}

impl PlannedRoute {
    fn half_width(&self, s: f64) -> f64 {
        let i = (s.max(0.0) as usize).min(self.widths.len() - 1);
        self.widths[i] / 2.0
    }
}

/// The map and its route pool, shared by every environment on it.
#[derive(Debug)]
pub struct RouteSetup {
    map: Arc<Map>,
    config: RouteConfig,
    routes: Vec<PlannedRoute>,
    /// The car-following model everyone drives by (a middling driver).
    driver: Driver,
    /// The bird's-eye renderer of the whole map (`view = "bev"`).
    renderer: Option<BevRenderer>,
    /// Draws the layers of a camera view.
    observer: Option<Arc<dyn SceneObserver>>,
}

impl TaskSetup for RouteSetup {
    type Config = RouteConfig;

    fn prepare(
        map: Option<Arc<Map>>,
        config: RouteConfig,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self>, SimError> {
        RouteSetup::with_observer(required_map(map, TaskId::RouteFollowing)?, config, observer)
    }

    fn map(&self) -> &Map {
        &self.map
    }
}

impl RouteSetup {
    /// Plans the route pool on `map`. Fails when the map has too few routes of the length
    /// asked for, or the configuration is invalid.
    pub fn new(map: Arc<Map>, config: RouteConfig) -> Result<Arc<Self>, SimError> {
        Self::with_observer(map, config, None)
    }

    /// As [`RouteSetup::new`], with the observer that draws the layers of
    /// `view = "camera-segmentation"` (required by that view, unused by the others; its
    /// frame shape must be the `camera` table's).
    pub fn with_observer(
        map: Arc<Map>,
        config: RouteConfig,
        observer: Option<Arc<dyn SceneObserver>>,
    ) -> Result<Arc<Self>, SimError> {
        config.validate()?;
        let observer =
            checked_observer("agent.route", config.view, config.camera.as_ref(), observer)?;
        let renderer = if config.view == View::Bev {
            let bev = config.bev_config();
            let mut region = map.bounds();
            let margin = bev.view_radius_m() + 2.0;
            region.extend(Point::new(region.min.x - margin, region.min.y - margin));
            region.extend(Point::new(region.max.x + margin, region.max.y + margin));
            Some(BevRenderer::new(&map, region, bev)?)
        } else {
            None
        };
        let router = Router::new(&map);
        let mut lanes: Vec<LaneId> = map.lanes.keys().copied().collect();
        lanes.sort();
        if lanes.len() < 2 {
            return Err(SimError::Config("the map has fewer than two lanes".into()));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(config.pool_seed);
        let (min_m, max_m) = config.route_length_m;
        let mut routes = Vec::with_capacity(config.pool_size);
        // Random lane pairs; most are too long or unreachable, so try many.
        for _ in 0..config.pool_size * 200 {
            if routes.len() == config.pool_size {
                break;
            }
            let from = lanes[rng.random_range(0..lanes.len())];
            let to = lanes[rng.random_range(0..lanes.len())];
            if from == to {
                continue;
            }
            let Ok(route) = router.route_lanes(from, to) else {
                continue;
            };
            if !(min_m..=max_m).contains(&route.length_m) || has_u_turn(&route.waypoints) {
                continue;
            }
            let points: Vec<Point> = route.waypoints.iter().map(|w| w.position).collect();
            let speed = config.max_speed_mps();
            let Some(path) = Path::from_geometry(
                &[(PieceKey::Lane(from), points, speed)],
                SpeedProfile::default(),
            ) else {
                continue;
            };
            let mut widths = Vec::with_capacity(route.waypoints.len());
            let mut last = 3.5;
            for w in &route.waypoints {
                if let Some(lane) = w.lane.and_then(|l| map.lanes.get(&l)) {
                    last = lane.width_m;
                }
                widths.push(last);
            }
            let held_out = (derive_seed(config.pool_seed, from.0 as u64, to.0 as u64) % 1000)
                < (config.held_out_fraction * 1000.0) as u64;
            routes.push(PlannedRoute {
                path,
                widths,
                held_out,
            });
        }
        let held_out = routes.iter().filter(|r| r.held_out).count();
        if routes.len() < 4 || held_out == 0 || held_out == routes.len() {
            return Err(SimError::Map(format!(
                "the map gives only {} routes of {min_m}-{max_m} m ({held_out} held out); \
                 import a larger map or widen route_length_m",
                routes.len()
            )));
        }
        Ok(Arc::new(RouteSetup {
            map,
            config,
            routes,
            driver: Driver::new(&DriverConfig::default(), 0.5),
            renderer,
            observer,
        }))
    }

    pub fn map(&self) -> &Arc<Map> {
        &self.map
    }

    pub fn config(&self) -> &RouteConfig {
        &self.config
    }

    /// Routes in the pool: (training, held out).
    pub fn route_counts(&self) -> (usize, usize) {
        let held_out = self.routes.iter().filter(|r| r.held_out).count();
        (self.routes.len() - held_out, held_out)
    }

    pub fn observation_spec(&self) -> ObservationSpec {
        self.config.observation_spec()
    }
}

/// Whether the route turns back on itself within a few metres (a U-turn through a
/// junction, which the lane graph allows but a car with a 4 m turning radius cannot drive).
fn has_u_turn(waypoints: &[maps::route::Waypoint]) -> bool {
    const WINDOW_M: f64 = 10.0;
    let mut j = 0;
    for (i, w) in waypoints.iter().enumerate() {
        j = j.max(i);
        while j + 1 < waypoints.len() && waypoints[j + 1].s_m - w.s_m <= WINDOW_M {
            j += 1;
        }
        let mut turned = 0.0;
        for k in i..j {
            turned += wrap_angle(waypoints[k + 1].heading_rad - waypoints[k].heading_rad);
        }
        if turned.abs() > 2.0 * std::f64::consts::FRAC_PI_3 {
            return true;
        }
    }
    false
}

/// Another road user: a box driving a route of the pool at a steady speed.
#[derive(Debug, Clone)]
struct Other {
    route: usize,
    s: f64,
    speed: f64,
    desired_speed: f64,
    length: f64,
    width: f64,
}

/// A vehicle as the car-following sees it.
#[derive(Debug, Clone, Copy)]
struct Mover {
    route: usize,
    s: f64,
    position: Point,
    heading: f64,
    speed: f64,
    length: f64,
    width: f64,
}

/// How one episode went.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RouteSummary {
    pub outcome: Outcome,
    pub steps: usize,
    pub episode_return: f64,
    pub route_length_m: f64,
    /// Share of the route driven when the episode ended.
    pub completion: f64,
    pub lane_rms_error_m: f64,
    /// Share of decisions with the in-lane fraction at or above the threshold.
    pub time_in_lane: f64,
    pub mean_speed_kmh: f64,
}

impl TaskSummary for RouteSummary {
    fn outcome(&self) -> Outcome {
        self.outcome
    }

    fn episode_return(&self) -> f64 {
        self.episode_return
    }

    fn metrics(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("route completion %", 100.0 * self.completion),
            ("lane-centre RMS m", self.lane_rms_error_m),
            ("time in lane %", 100.0 * self.time_in_lane),
            ("mean speed km/h", self.mean_speed_kmh),
            ("route m", self.route_length_m),
        ]
    }
}

/// The route-following task as an [`Env`].
#[derive(Debug)]
pub struct RouteFollowing {
    setup: Arc<RouteSetup>,
    split: RouteSplit,
    route: usize,
    bike: Bicycle,
    speed: f64,
    steer: f64,
    /// Arc length of the ego's centre along its route.
    s: f64,
    others: Vec<Other>,
    time_s: f64,
    time_limit_s: f64,
    /// Decisions, return, outcome and the ego's positions (one per decision).
    episode: Episode,
    squared_error_sum: f64,
    in_lane_steps: usize,
    speed_sum: f64,
    /// The ego's stacked layers (None for `view = "scalars"`).
    view: Option<EgoView>,
}

impl RouteFollowing {
    pub fn new(setup: Arc<RouteSetup>) -> Self {
        let wheelbase = setup.config.ego.wheelbase_m;
        let view = match (&setup.observer, &setup.config.camera, &setup.renderer) {
            (Some(observer), Some(camera), _) => {
                Some(EgoView::observed(Arc::clone(observer), camera.stack))
            }
            (None, _, Some(renderer)) => Some(EgoView::new(renderer.config())),
            _ => None,
        };
        RouteFollowing {
            setup,
            split: RouteSplit::Training,
            route: 0,
            bike: Bicycle::at_centre(Point::new(0.0, 0.0), 0.0, wheelbase),
            speed: 0.0,
            steer: 0.0,
            s: 0.0,
            others: Vec::new(),
            time_s: 0.0,
            time_limit_s: 0.0,
            episode: Episode::default(),
            squared_error_sum: 0.0,
            in_lane_steps: 0,
            speed_sum: 0.0,
            view,
        }
    }

    /// Draws the current scene into the layers: the first frame of an episode, or the next.
    fn draw(&mut self, first: bool) {
        let Some(mut view) = self.view.take() else {
            return;
        };
        let setup = Arc::clone(&self.setup);
        view.draw_with(setup.renderer.as_ref(), self.scene(), first);
        self.view = Some(view);
    }

    /// Which routes the next episodes draw from.
    pub fn set_split(&mut self, split: RouteSplit) {
        self.split = split;
    }

    /// Whether the current episode's route is one of the held-out routes.
    pub fn route_is_held_out(&self) -> bool {
        self.route().held_out
    }

    fn route(&self) -> &PlannedRoute {
        &self.setup.routes[self.route]
    }

    fn config(&self) -> &RouteConfig {
        &self.setup.config
    }

    /// The ego's signed lateral offset from the route (left positive) and heading error.
    fn deviation(&self) -> (f64, f64) {
        let path = &self.route().path;
        let centre = self.bike.centre();
        let (p, heading) = path.pose_at(self.s);
        let offset = centre.sub(p).dot(direction(heading).perp());
        (offset, wrap_angle(self.bike.heading - heading))
    }

    /// The share of the ego's width inside its lane.
    fn in_lane_fraction(&self) -> f64 {
        let (offset, heading_error) = self.deviation();
        let ego = &self.config().ego;
        let half_extent = ego.width_m / 2.0 * heading_error.cos().abs()
            + ego.length_m / 2.0 * heading_error.sin().abs();
        let half_lane = self.route().half_width(self.s);
        let inside = (offset + half_extent).min(half_lane) - (offset - half_extent).max(-half_lane);
        (inside / (2.0 * half_extent)).clamp(0.0, 1.0)
    }

    fn other_pose(&self, other: &Other) -> (Point, f64) {
        self.setup.routes[other.route].path.pose_at(other.s)
    }

    fn ego_box(&self) -> OrientedBox {
        let ego = &self.config().ego;
        OrientedBox::new(
            self.bike.centre(),
            self.bike.heading,
            ego.length_m,
            ego.width_m,
        )
    }

    /// Every vehicle, the ego first (index 0), then the others.
    fn vehicles(&self) -> Vec<Mover> {
        let ego = &self.config().ego;
        let mut all = Vec::with_capacity(self.others.len() + 1);
        all.push(Mover {
            route: self.route,
            s: self.s,
            position: self.bike.centre(),
            heading: self.bike.heading,
            speed: self.speed,
            length: ego.length_m,
            width: ego.width_m,
        });
        for o in &self.others {
            let (position, heading) = self.other_pose(o);
            all.push(Mover {
                route: o.route,
                s: o.s,
                position,
                heading,
                speed: o.speed,
                length: o.length,
                width: o.width,
            });
        }
        all
    }

    /// For vehicle `i` of `vehicles`: gap to and closing speed on the nearest vehicle ahead
    /// (the leader of its IDM): ahead on the same route (measured along it, so curves do
    /// not hide it), or in the straight corridor of its lane ahead (crossing traffic).
    fn leader(vehicles: &[Mover], i: usize, half_lane: f64) -> Option<(f64, f64)> {
        let me = &vehicles[i];
        let axis = direction(me.heading);
        vehicles
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .filter_map(|(_, other)| {
                let half_lengths = (me.length + other.length) / 2.0;
                if other.route == me.route && other.s > me.s {
                    let gap = other.s - me.s - half_lengths;
                    return (gap < 30.0).then_some((gap.max(0.0), me.speed - other.speed));
                }
                let rel = other.position.sub(me.position);
                let ahead = rel.dot(axis);
                let lateral = rel.dot(axis.perp()).abs();
                (ahead > 0.0 && ahead < 30.0 && lateral < half_lane + other.width / 2.0).then(
                    || {
                        let along = other.speed * wrap_angle(other.heading - me.heading).cos();
                        ((ahead - half_lengths).max(0.0), me.speed - along)
                    },
                )
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
    }

    fn summary_now(&self) -> RouteSummary {
        let length = self.route().path.length();
        let steps = self.episode.steps.max(1) as f64;
        RouteSummary {
            outcome: self.episode.final_outcome(),
            steps: self.episode.steps,
            episode_return: self.episode.episode_return,
            route_length_m: length,
            completion: if self.episode.outcome == Some(Outcome::Reached) {
                1.0
            } else {
                (self.s / length).clamp(0.0, 1.0)
            },
            lane_rms_error_m: (self.squared_error_sum / steps).sqrt(),
            time_in_lane: self.in_lane_steps as f64 / steps,
            mean_speed_kmh: 3.6 * self.speed_sum / steps,
        }
    }

    /// One simulation step of everyone; the outcome if the episode ended.
    fn advance(&mut self) -> Option<Outcome> {
        // The setup, not its config, is cloned: an Arc, cheap at every step.
        let setup = Arc::clone(&self.setup);
        let config = &setup.config;
        let dt = config.step_s;
        // Everyone drives by the IDM behind whoever is ahead in their lane, the ego included.
        let driver = &setup.driver;
        let vehicles = self.vehicles();
        let accels: Vec<f64> = (0..vehicles.len())
            .map(|i| {
                let (half_lane, desired) = if i == 0 {
                    (self.route().half_width(self.s), config.max_speed_mps())
                } else {
                    let o = &self.others[i - 1];
                    (self.setup.routes[o.route].half_width(o.s), o.desired_speed)
                };
                driver.idm(
                    vehicles[i].speed,
                    desired,
                    Self::leader(&vehicles, i, half_lane),
                )
            })
            .collect();
        for (o, &a) in self.others.iter_mut().zip(&accels[1..]) {
            let (speed, ds) = advance_speed(o.speed, a.clamp(-8.0, 3.0), dt);
            o.speed = speed;
            o.s += ds;
        }
        // Others leave at the end of their route.
        let routes = &self.setup.routes;
        self.others
            .retain(|o| o.s < routes[o.route].path.length() - 0.5);
        let (speed, travelled) = advance_speed(
            self.speed,
            accels[0].clamp(-config.ego.max_brake_mps2, config.ego.max_accel_mps2),
            dt,
        );
        self.bike.advance(travelled, self.steer);
        self.speed = speed;
        self.time_s += dt;
        let path = &self.setup.routes[self.route].path;
        let (s, distance) = path.project(self.bike.centre(), self.s, 1.0, travelled + 2.0);
        self.s = s.max(self.s);
        let ego_box = self.ego_box();
        let hit = self.others.iter().any(|o| {
            let (p, h) = self.other_pose(o);
            OrientedBox::new(p, h, o.length, o.width).overlaps(&ego_box)
        });
        if hit {
            return Some(Outcome::Crashed);
        }
        if distance > self.route().half_width(self.s) + config.off_road_m {
            return Some(Outcome::OffRoad);
        }
        if self.s >= path.length() - 0.5 {
            return Some(Outcome::Reached);
        }
        (self.time_s >= self.time_limit_s).then_some(Outcome::TimeOver)
    }

    /// Puts other vehicles on routes of the pool that pass near the ego's, and on the
    /// ego's route ahead of it.
    fn place_others(&mut self, rng: &mut ChaCha8Rng) {
        let config = &self.setup.config;
        let start = self.bike.centre();
        let near: Vec<usize> = (0..self.setup.routes.len())
            .filter(|&r| r != self.route)
            .filter(|&r| {
                let path = &self.setup.routes[r].path;
                path.outline().iter().any(|p| p.distance(start) < 60.0)
            })
            .collect();
        let (lo, hi) = config.other_speed_mps;
        let ego = config.ego;
        for k in 0..config.other_vehicles {
            let own = k % 2 == 1 || near.is_empty();
            let route = if own {
                self.route
            } else {
                near[rng.random_range(0..near.len())]
            };
            let length = self.setup.routes[route].path.length();
            let s = if own {
                // Ahead of the ego, slower than it: it must follow, not drive through.
                (rng.random_range(15.0..40.0) + 12.0 * k as f64).min(length - 1.0)
            } else {
                rng.random_range(0.0..length)
            };
            let speed = if own {
                rng.random_range(lo..hi).min(0.6 * config.max_speed_mps())
            } else {
                rng.random_range(lo..hi)
            };
            let other = Other {
                route,
                s,
                speed,
                desired_speed: speed,
                length: ego.length_m,
                width: ego.width_m,
            };
            let (p, h) = self.other_pose(&other);
            let clear = OrientedBox::new(p, h, other.length + 6.0, other.width + 2.0);
            if !clear.overlaps(&self.ego_box()) {
                self.others.push(other);
            }
        }
    }
}

impl Driving for RouteFollowing {
    type Summary = RouteSummary;
    type Action = SteerAction;
    const FALLBACK: SteerAction = SteerAction::Forward;

    fn spec(&self) -> ObservationSpec {
        self.setup.observation_spec()
    }

    episode_in_field!();

    fn started(&self) -> bool {
        true
    }

    fn begin(&mut self, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let want_held_out = self.split == RouteSplit::HeldOut;
        let candidates: Vec<usize> = (0..self.setup.routes.len())
            .filter(|&r| self.setup.routes[r].held_out == want_held_out)
            .collect();
        self.route = candidates[rng.random_range(0..candidates.len())];
        let (p, heading) = self.route().path.pose_at(0.0);
        self.bike = Bicycle::at_centre(p, heading, self.config().ego.wheelbase_m);
        self.speed = 0.0;
        self.steer = 0.0;
        self.s = 0.0;
        self.others.clear();
        self.place_others(&mut rng);
        self.time_s = 0.0;
        self.time_limit_s = self.config().time_limit_factor * self.route().path.length()
            / self.config().max_speed_mps()
            + 10.0;
        self.episode.reset(Some(self.bike.centre()));
        self.squared_error_sum = 0.0;
        self.in_lane_steps = 0;
        self.speed_sum = 0.0;
        self.draw(true);
    }

    fn decide(&mut self, action: SteerAction) -> (f64, Option<Outcome>) {
        // The setup, not its config, is cloned: an Arc, cheap at every step.
        let setup = Arc::clone(&self.setup);
        let config = &setup.config;
        let change = match action {
            SteerAction::ForwardLeft => config.steer_increment_rad,
            SteerAction::ForwardRight => -config.steer_increment_rad,
            SteerAction::Forward => 0.0,
        };
        let max_steer = config.ego.max_steer_rad;
        let new_steer = (self.steer + change).clamp(-max_steer, max_steer);
        let changed = new_steer != self.steer;
        self.steer = new_steer;
        let mut outcome = None;
        for _ in 0..config.action_repeat {
            outcome = self.advance();
            if outcome.is_some() {
                break;
            }
        }
        self.episode.steps += 1;
        self.episode.trajectory.push(self.bike.centre());
        let (offset, _) = self.deviation();
        self.squared_error_sum += offset * offset;
        self.speed_sum += self.speed;
        let fraction = self.in_lane_fraction();
        if fraction >= config.reward.in_lane_threshold {
            self.in_lane_steps += 1;
        }
        let mut reward = if fraction < config.reward.in_lane_threshold {
            config.reward.below_lane_penalty
        } else {
            self.speed / config.max_speed_mps() + fraction
        };
        if changed {
            reward += config.reward.steer_change_penalty;
        }
        if matches!(outcome, Some(Outcome::Crashed | Outcome::OffRoad)) {
            reward += config.reward.terminal_penalty;
        }
        self.draw(false);
        (reward, outcome)
    }

    fn observe(&self) -> Observation {
        let config = self.config();
        let path = &self.route().path;
        let centre = self.bike.centre();
        let axis = direction(self.bike.heading);
        let mut scalars = Vec::with_capacity(config.lookahead_m.len() + 5);
        for &ahead in &config.lookahead_m {
            let (p, _) = path.pose_at((self.s + ahead).min(path.length()));
            // Lateral distance of the route in the ego's frame, over 5 m.
            scalars.push((p.sub(centre).dot(axis.perp()) / 5.0) as f32);
        }
        scalars.push((self.route().half_width(self.s) / 2.0) as f32);
        scalars.push((self.speed / config.max_speed_mps()) as f32);
        scalars.push((self.steer / config.ego.max_steer_rad) as f32);
        let nearest = self
            .others
            .iter()
            .map(|o| self.other_pose(o).0.sub(centre))
            .filter(|rel| rel.norm() < NEAR_M)
            .min_by(|a, b| a.norm().total_cmp(&b.norm()));
        let (x, y) = nearest.map_or((1.0, 0.0), |rel| {
            (rel.dot(axis) / NEAR_M, rel.dot(axis.perp()) / NEAR_M)
        });
        scalars.push(x as f32);
        scalars.push(y as f32);
        Observation {
            layers: self.view.as_ref().map(EgoView::layers).unwrap_or_default(),
            scalars,
        }
    }

    fn summary(&self) -> RouteSummary {
        self.summary_now()
    }
}

const HELD_OUT: &str = "held-out routes";
const TRAINING_ROUTES: &str = "training routes";

impl Task for RouteFollowing {
    type Config = RouteConfig;
    type Setup = RouteSetup;
    /// The routes episodes draw from.
    type Condition = RouteSplit;

    const ID: TaskId = TaskId::RouteFollowing;

    fn camera_view(config: &RouteConfig) -> Option<&CameraViewConfig> {
        config.view.camera(config.camera.as_ref())
    }

    fn camera_mut(config: &mut RouteConfig) -> Option<&mut CameraViewConfig> {
        config.camera.as_mut()
    }

    /// On training routes, whatever the traffic (the other vehicles are the config's).
    fn training_env(setup: &Arc<RouteSetup>, _: TrafficLevel) -> Self {
        Self::env(setup, &RouteSplit::Training)
    }

    fn env(setup: &Arc<RouteSetup>, split: &RouteSplit) -> Self {
        let mut env = RouteFollowing::new(Arc::clone(setup));
        env.set_split(*split);
        env
    }

    /// The held-out routes, then the training ones.
    fn conditions(_: &ConditionChoice) -> Vec<RouteSplit> {
        vec![RouteSplit::HeldOut, RouteSplit::Training]
    }

    fn condition_name(split: &RouteSplit) -> String {
        match split {
            RouteSplit::HeldOut => HELD_OUT,
            RouteSplit::Training => TRAINING_ROUTES,
        }
        .to_owned()
    }

    /// On training routes only: the held-out routes are for evaluation.
    fn validation_conditions(_: TrafficLevel) -> Vec<(String, RouteSplit)> {
        vec![(TRAINING_ROUTES.to_owned(), RouteSplit::Training)]
    }

    fn recorded_condition(_: TrafficLevel) -> RouteSplit {
        RouteSplit::HeldOut
    }

    fn baselines() -> Vec<(String, PolicyFactory<Self>)> {
        baselines_with_rule::<Self, PursuitRule>(&SteerAction::NAMES, "rule: pure pursuit")
    }

    fn scene(&self) -> Option<Scene<'_>> {
        let ego = &self.config().ego;
        let mut actors = vec![Actor {
            id: 0,
            kind: ActorKind::Car,
            position: self.bike.centre(),
            heading_rad: self.bike.heading,
            speed_mps: self.speed,
            length_m: ego.length_m,
            width_m: ego.width_m,
            lane: None,
            aggressiveness: None,
        }];
        for (i, o) in self.others.iter().enumerate() {
            let (p, h) = self.other_pose(o);
            actors.push(Actor {
                id: i as u32 + 1,
                kind: ActorKind::Car,
                position: p,
                heading_rad: h,
                speed_mps: o.speed,
                length_m: o.length,
                width_m: o.width,
                lane: None,
                aggressiveness: None,
            });
        }
        Some(Scene {
            map: &self.setup.map,
            time_s: self.time_s,
            actors,
            ego: 0,
            ego_path: self.route().path.outline(),
        })
    }

    /// Nothing to draw with `view = "scalars"`.
    fn set_rendering(&mut self, on: bool) {
        if let Some(view) = &mut self.view {
            view.set_rendering(on);
        }
    }
}

/// Pure pursuit on the route, turned into steering increments: an upper bound that reads
/// the route exactly.
#[derive(Debug, Clone, Copy, Default)]
pub struct PursuitRule;

impl PursuitRule {
    fn decide(env: &RouteFollowing) -> SteerAction {
        let config = env.config();
        let lookahead = 3.0 + 0.5 * env.speed;
        let path = &env.route().path;
        let (target, _) = path.pose_at((env.s + lookahead).min(path.length()));
        let wanted = env.bike.pure_pursuit(target, config.ego.max_steer_rad);
        let half_step = config.steer_increment_rad / 2.0;
        if wanted > env.steer + half_step {
            SteerAction::ForwardLeft
        } else if wanted < env.steer - half_step {
            SteerAction::ForwardRight
        } else {
            SteerAction::Forward
        }
    }
}

impl TaskPolicy<RouteFollowing> for PursuitRule {
    fn act(&mut self, envs: &[&RouteFollowing], _: &[&Observation], actions: &mut Vec<usize>) {
        actions.clear();
        actions.extend(envs.iter().map(|env| Self::decide(env) as usize));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::Env;
    use crate::eval::run_episodes;

    /// The bundled campus (ODbL, in the repository), with a small route pool.
    fn campus() -> Arc<RouteSetup> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../data/osm/northwestern_nu.osm.pbf");
        let map = maps::build::import_file(&path, &maps::ImportOptions::default())
            .expect("the bundled campus imports");
        let config = RouteConfig {
            pool_size: 24,
            ..RouteConfig::default()
        };
        RouteSetup::new(Arc::new(map), config).expect("the campus has routes")
    }

    fn env(setup: &Arc<RouteSetup>, split: RouteSplit) -> RouteFollowing {
        let mut env = RouteFollowing::new(Arc::clone(setup));
        env.set_split(split);
        env
    }

    #[derive(Debug)]
    struct Grey((usize, usize, usize));

    impl SceneObserver for Grey {
        fn frame_shape(&self) -> (usize, usize, usize) {
            self.0
        }

        fn observe(&self, scene: &Scene<'_>, out: &mut Vec<u8>) {
            let (c, h, w) = self.0;
            out.clear();
            out.resize(c * h * w, 1 + (scene.time_s * 10.0) as u8);
        }
    }

    #[test]
    #[allow(clippy::unwrap_used)]
    fn the_views_give_the_layers_their_spec_declares() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../data/osm/northwestern_nu.osm.pbf");
        let map = Arc::new(
            maps::build::import_file(&path, &maps::ImportOptions::default())
                .expect("the bundled campus imports"),
        );
        let base = RouteConfig {
            pool_size: 12,
            ..RouteConfig::default()
        };
        // Scalars (the default): no layers, 13 scalars, as before the views existed.
        let scalars = RouteSetup::new(Arc::clone(&map), base.clone()).unwrap();
        assert_eq!(
            scalars.observation_spec(),
            ObservationSpec {
                channels: 0,
                height: 0,
                width: 0,
                scalars: 13
            }
        );
        let o = RouteFollowing::new(Arc::clone(&scalars)).reset(1);
        assert!(o.layers.is_empty());
        assert!(serde_json::to_value(&base).unwrap().get("view").is_none());

        // Bird's-eye: 3 layers × 2 frames of 42 × 42; the route is drawn ahead of the ego.
        let bev = RouteSetup::new(
            Arc::clone(&map),
            RouteConfig {
                view: View::Bev,
                ..base.clone()
            },
        )
        .unwrap();
        let spec = bev.observation_spec();
        assert_eq!((spec.channels, spec.height, spec.width), (6, 42, 42));
        let mut env = RouteFollowing::new(Arc::clone(&bev));
        let first = env.reset(1);
        assert_eq!(first.layers.len(), spec.layer_len());
        assert_eq!(
            first.scalars, o.scalars,
            "the same scalars whatever the view"
        );
        let frame = 42 * 42;
        let path_layer = &first.layers[4 * frame..5 * frame];
        assert!(
            path_layer[..frame / 2].iter().any(|&v| v > 0),
            "route ahead"
        );
        let step = env.step(0);
        assert_eq!(step.observation.layers.len(), spec.layer_len());

        // Camera: needs its table and an observer of its shape.
        let camera = RouteConfig {
            view: View::CameraSegmentation,
            ..base.clone()
        };
        assert!(RouteSetup::new(Arc::clone(&map), camera.clone()).is_err());
        let camera = RouteConfig {
            camera: Some(CameraViewConfig {
                segmenter: "model".into(),
                ..CameraViewConfig::default()
            }),
            ..camera
        };
        assert!(RouteSetup::new(Arc::clone(&map), camera.clone()).is_err());
        let shape = camera.camera.as_ref().unwrap().frame_shape();
        let observer: Arc<dyn SceneObserver> = Arc::new(Grey(shape));
        let setup = RouteSetup::with_observer(map, camera, Some(observer)).unwrap();
        let spec = setup.observation_spec();
        assert_eq!((spec.channels, spec.scalars), (2 * shape.0, 13));
        let mut env = RouteFollowing::new(setup);
        let first = env.reset(1);
        assert_eq!(first.layers.len(), spec.layer_len());
        assert!(first.layers.iter().all(|&v| v == 1));
        let step = env.step(0);
        assert_eq!(step.observation.layers.len(), spec.layer_len());
        env.set_rendering(false);
        assert!(env.reset(1).layers.is_empty());
    }

    #[test]
    fn route_following_on_the_campus() {
        let setup = campus();
        let (training, held_out) = setup.route_counts();
        assert!(training > 0 && held_out > 0, "{training} / {held_out}");

        // Splits: held-out routes only in held-out episodes, never in training ones.
        let mut e = env(&setup, RouteSplit::Training);
        for seed in 0..20 {
            e.reset(seed);
            assert!(!e.route_is_held_out());
        }
        let mut e = env(&setup, RouteSplit::HeldOut);
        let first = e.reset(3);
        assert!(e.route_is_held_out());
        // At the start the ego sits on the route's centre line, aligned with it.
        assert!(e.in_lane_fraction() > 0.999, "{}", e.in_lane_fraction());
        assert!(first.scalars[0].abs() < 1e-6, "{:?}", first.scalars);
        assert_eq!(first.scalars.len(), setup.observation_spec().scalars);

        let seeds: Vec<u64> = (0..12).collect();
        let run = |policy: usize| {
            let baselines = RouteFollowing::baselines();
            run_episodes(
                || env(&setup, RouteSplit::HeldOut),
                &baselines[policy].1,
                &seeds,
                4,
            )
        };
        // Pure pursuit (the rule, last) finishes most routes near the lane centre; holding
        // the wheel turned left (index 1) leaves the road every time.
        let rule = run(3);
        let reached = rule
            .iter()
            .filter(|s| s.outcome == Outcome::Reached)
            .count();
        assert!(reached >= 9, "the rule reached {reached} of 12: {rule:?}");
        assert!(rule.iter().all(|s| s.lane_rms_error_m < 1.0), "{rule:?}");
        let left = run(1);
        assert!(
            left.iter().all(|s| s.outcome == Outcome::OffRoad),
            "{left:?}"
        );
        assert!(left.iter().all(|s| s.completion < 0.5));

        // Same seed, same episode.
        assert_eq!(run(3), rule);
    }
}
