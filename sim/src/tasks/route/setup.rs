//! Route following's setup on a map: the pool of planned routes (the held-out ones
//! marked) and the bird's-eye renderer.

use super::*;

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
pub(super) struct PlannedRoute {
    pub(super) path: Path,
    /// Lane width every metre along the path.
    pub(super) widths: Vec<f64>,
    pub(super) held_out: bool,
}

impl PlannedRoute {
    pub(super) fn half_width(&self, s: f64) -> f64 {
        let i = (s.max(0.0) as usize).min(self.widths.len() - 1);
        self.widths[i] / 2.0
    }
}

/// The map and its route pool, shared by every environment on it.
#[derive(Debug)]
pub struct RouteSetup {
    pub(super) map: Arc<Map>,
    pub(super) config: RouteConfig,
    pub(super) routes: Vec<PlannedRoute>,
    /// The car-following model everyone drives by (a middling driver).
    pub(super) driver: Driver,
    /// The bird's-eye renderer of the whole map (`view = "bev"`).
    pub(super) renderer: Option<BevRenderer>,
    /// Draws the layers of a camera view.
    pub(super) observer: Option<Arc<dyn SceneObserver>>,
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
pub(super) fn has_u_turn(waypoints: &[maps::route::Waypoint]) -> bool {
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
