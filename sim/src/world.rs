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

/// Traffic density. Uncalibrated (no [`TrafficConfig::capacity`]), as in the Parma study:
/// at most 4 / 6 / 8 other vehicles in the roundabout (its approaches, ring and exits) at
/// once. With a capacity model (a calibrated world), each usable entry gets the same Poisson
/// arrivals, the flow at which the busiest entry runs at [`TrafficLevel::saturation`] of its
/// capacity. `Recorded` is the recordings' own flows ([`TrafficConfig::flows`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrafficLevel {
    Low,
    Medium,
    High,
    Recorded,
}

impl TrafficLevel {
    /// The named levels (not `Recorded`, which needs recordings).
    pub const ALL: [TrafficLevel; 3] =
        [TrafficLevel::Low, TrafficLevel::Medium, TrafficLevel::High];

    /// The level's cap on other vehicles in an uncalibrated world (none at `Recorded`).
    pub fn max_vehicles(self) -> usize {
        match self {
            TrafficLevel::Low => 4,
            TrafficLevel::Medium => 6,
            TrafficLevel::High => 8,
            TrafficLevel::Recorded => usize::MAX,
        }
    }

    /// The busiest entry's demand over its capacity in a world with a capacity model.
    pub fn saturation(self) -> Option<f64> {
        match self {
            TrafficLevel::Low => Some(0.3),
            TrafficLevel::Medium => Some(0.6),
            TrafficLevel::High => Some(0.9),
            TrafficLevel::Recorded => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            TrafficLevel::Low => "low",
            TrafficLevel::Medium => "medium",
            TrafficLevel::High => "high",
            TrafficLevel::Recorded => "recorded",
        }
    }
}

impl std::str::FromStr for TrafficLevel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "low" => Ok(TrafficLevel::Low),
            "medium" => Ok(TrafficLevel::Medium),
            "high" => Ok(TrafficLevel::High),
            "recorded" => Ok(TrafficLevel::Recorded),
            other => Err(format!(
                "unknown traffic level `{other}` (low, medium, high or recorded)"
            )),
        }
    }
}

/// An entry's capacity from its drivers' gap acceptance (the HCM's exponential form,
/// Highway Capacity Manual 6th ed., eq. 22-1 with A = 3600 / t_f, B = (t_c − t_f / 2) /
/// 3600): `c = 3600 / t_f · exp(−(t_c − t_f / 2) · v_c / 3600)` vehicles per hour at a
/// conflicting flow of `v_c` vehicles per hour.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapacityModel {
    /// Critical gap, s.
    pub critical_gap_s: f64,
    /// Follow-up headway, s.
    pub follow_up_s: f64,
}

impl CapacityModel {
    /// Entry capacity at conflicting flow `conflicting_vph`, veh/h.
    pub fn entry_capacity_vph(&self, conflicting_vph: f64) -> f64 {
        3600.0 / self.follow_up_s
            * (-(self.critical_gap_s - self.follow_up_s / 2.0) * conflicting_vph / 3600.0).exp()
    }

    /// The arrival flow per usable entry of `layout` (the same on each, routes drawn alike)
    /// at which the busiest entry's demand is `saturation` of its capacity, veh/h.
    pub fn entry_flow_vph(&self, layout: &RoundaboutLayout, saturation: f64) -> f64 {
        // Per entry: how many entries' worth of flow passes its merge point (each other
        // entry's share of routes that drive the merge lane, on the way round).
        let entries: Vec<usize> = layout.usable_entries().collect();
        let passing = entries
            .iter()
            .map(|&e| {
                let Some(&first) = layout.routes_by_entry[e].first() else {
                    return 0.0;
                };
                let lane = layout.routes[first].merge_lane;
                entries
                    .iter()
                    .filter(|&&o| o != e)
                    .map(|&o| {
                        let routes = &layout.routes_by_entry[o];
                        let through = routes
                            .iter()
                            .filter(|&&r| {
                                let route = &layout.routes[r];
                                route.merge_lane != lane && route.ring_lane_start(lane).is_some()
                            })
                            .count();
                        through as f64 / routes.len().max(1) as f64
                    })
                    .sum::<f64>()
            })
            .fold(0.0, f64::max);
        // Demand over capacity rises with the flow: bisect for `saturation`.
        let (mut lo, mut hi) = (0.0, 3600.0 / self.follow_up_s.max(0.1));
        for _ in 0..60 {
            let q = (lo + hi) / 2.0;
            if q / self.entry_capacity_vph(q * passing) < saturation {
                lo = q;
            } else {
                hi = q;
            }
        }
        (lo + hi) / 2.0
    }
}

/// A driver parameter at aggressiveness 0 and at 1 (linear in between).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Span {
    pub passive: f64,
    pub aggressive: f64,
}

impl Span {
    const fn new(passive: f64, aggressive: f64) -> Self {
        Span {
            passive,
            aggressive,
        }
    }
    pub fn at(&self, aggressiveness: f64) -> f64 {
        self.passive + (self.aggressive - self.passive) * aggressiveness.clamp(0.0, 1.0)
    }
}

/// How drivers behave, from passive (aggressiveness 0) to aggressive (1).
///
/// Files write the gap acceptance as they always have: `critical_gap_s` (the margin, always
/// written) and `critical_gap` (the measured distribution, when there is one); a measured
/// distribution writes the default margin beside it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "DriverConfigFile", into = "DriverConfigFile")]
pub struct DriverConfig {
    /// Desired speed as a fraction of the path's nominal speed (limit and curves).
    pub speed_factor: Span,
    /// IDM desired time headway, s.
    pub time_headway_s: Span,
    /// IDM minimum gap, m.
    pub min_gap_m: Span,
    /// IDM maximum acceleration, m/s².
    pub max_accel_mps2: Span,
    /// IDM comfortable deceleration, m/s².
    pub comfort_decel_mps2: Span,
    /// Gap acceptance: how long a circulating vehicle must be away from the merge point for
    /// a driver to enter.
    pub critical_gap: GapAcceptance,
    /// Hardest braking for a vehicle merging in ahead (drivers expect it to wait; they do
    /// not brake to a standstill for a car that cuts in), m/s².
    pub merge_brake_mps2: Span,
    /// Hardest braking any vehicle can do, m/s².
    pub max_brake_mps2: f64,
}

/// How drivers accept gaps in circulating traffic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GapAcceptance {
    /// A margin (the file's `critical_gap_s`), s: a driver enters when every circulating
    /// vehicle is at least the time it needs to get its whole car past the merge point plus
    /// this margin away from that point.
    Margin(Span),
    /// Gap acceptance as the traffic-engineering literature measures it (the file's
    /// `critical_gap`, set by `sim calibrate`): a driver enters when every circulating
    /// vehicle is at least its critical gap away in time from the merge point, the critical
    /// gaps of the drivers following this distribution.
    Measured(CriticalGap),
}

impl GapAcceptance {
    /// The uncalibrated drivers' margin.
    pub const DEFAULT_MARGIN: Span = Span::new(2.0, 0.5);

    /// The measured distribution, when drivers follow one.
    pub fn measured(&self) -> Option<CriticalGap> {
        match *self {
            GapAcceptance::Measured(gap) => Some(gap),
            GapAcceptance::Margin(_) => None,
        }
    }

    /// A driver's gap acceptance at `aggressiveness`.
    pub fn at(&self, aggressiveness: f64) -> DriverGap {
        match self {
            GapAcceptance::Margin(span) => DriverGap::Margin(span.at(aggressiveness)),
            GapAcceptance::Measured(gap) => DriverGap::Lag(gap.of(aggressiveness)),
        }
    }
}

/// [`DriverConfig`] as files write it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
struct DriverConfigFile {
    speed_factor: Span,
    time_headway_s: Span,
    min_gap_m: Span,
    max_accel_mps2: Span,
    comfort_decel_mps2: Span,
    critical_gap_s: Span,
    merge_brake_mps2: Span,
    max_brake_mps2: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    critical_gap: Option<CriticalGap>,
}

impl Default for DriverConfigFile {
    fn default() -> Self {
        DriverConfig::default().into()
    }
}

impl From<DriverConfigFile> for DriverConfig {
    fn from(f: DriverConfigFile) -> Self {
        DriverConfig {
            speed_factor: f.speed_factor,
            time_headway_s: f.time_headway_s,
            min_gap_m: f.min_gap_m,
            max_accel_mps2: f.max_accel_mps2,
            comfort_decel_mps2: f.comfort_decel_mps2,
            critical_gap: f.critical_gap.map_or(
                GapAcceptance::Margin(f.critical_gap_s),
                GapAcceptance::Measured,
            ),
            merge_brake_mps2: f.merge_brake_mps2,
            max_brake_mps2: f.max_brake_mps2,
        }
    }
}

impl From<DriverConfig> for DriverConfigFile {
    fn from(c: DriverConfig) -> Self {
        let (critical_gap_s, critical_gap) = match c.critical_gap {
            GapAcceptance::Margin(span) => (span, None),
            GapAcceptance::Measured(gap) => (GapAcceptance::DEFAULT_MARGIN, Some(gap)),
        };
        DriverConfigFile {
            speed_factor: c.speed_factor,
            time_headway_s: c.time_headway_s,
            min_gap_m: c.min_gap_m,
            max_accel_mps2: c.max_accel_mps2,
            comfort_decel_mps2: c.comfort_decel_mps2,
            critical_gap_s,
            merge_brake_mps2: c.merge_brake_mps2,
            max_brake_mps2: c.max_brake_mps2,
            critical_gap,
        }
    }
}

/// A lognormal distribution of drivers' critical gaps: a driver of aggressiveness `a` has
/// the distribution's `1 − a` quantile (clamped to the 5th-95th percentiles: beyond, a
/// driver would wait all day, or take any gap), so the most aggressive drivers accept the
/// shortest gaps.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CriticalGap {
    /// The median critical gap, s.
    pub median_s: f64,
    /// Standard deviation of its logarithm.
    pub sigma: f64,
}

impl CriticalGap {
    /// The critical gap of a driver of aggressiveness `aggressiveness`, s.
    pub fn of(&self, aggressiveness: f64) -> f64 {
        use statrs::distribution::{ContinuousCDF, Normal};
        let p = (1.0 - aggressiveness).clamp(0.05, 0.95);
        let z = Normal::standard().inverse_cdf(p);
        self.median_s * (self.sigma * z).exp()
    }
}

/// Arrivals on one entry of the roundabout (see [`TrafficConfig::flows`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EntryFlow {
    /// The entry lane (as the map numbers its lanes; `RoundaboutLayout::entries`).
    pub lane: u32,
    /// Vehicles per hour.
    pub vph: f64,
    /// Where they go: each exit lane (`RoundaboutLayout::exits`) with its share of the
    /// entry's vehicles; empty, every route of the entry alike.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub exits: Vec<ExitShare>,
}

/// One exit's share of an entry's vehicles.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExitShare {
    pub lane: u32,
    pub share: f64,
}

impl Default for DriverConfig {
    fn default() -> Self {
        DriverConfig {
            speed_factor: Span::new(0.85, 1.15),
            time_headway_s: Span::new(1.6, 0.8),
            min_gap_m: Span::new(2.5, 1.5),
            max_accel_mps2: Span::new(1.2, 2.5),
            comfort_decel_mps2: Span::new(1.5, 3.0),
            critical_gap: GapAcceptance::Margin(GapAcceptance::DEFAULT_MARGIN),
            merge_brake_mps2: Span::new(8.0, 8.0),
            max_brake_mps2: 8.0,
        }
    }
}

/// A traffic world a config gives in place of a task's own (a calibration's `[traffic]`,
/// `[recorded]` flows and `[layout]`): the one way it reaches every task that runs the
/// traffic world, for training and for evaluation alike ([`crate::tasks::Task::in_world`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CalibratedWorld {
    /// The traffic, when given.
    pub traffic: Option<TrafficConfig>,
    /// Recorded arrival flows, when given: they replace the traffic's flows.
    pub flows: Option<Vec<EntryFlow>>,
    /// The layout, when given.
    pub layout: Option<LayoutConfig>,
}

impl CalibratedWorld {
    /// Puts the world into a task's settings: the traffic (with the recorded flows) when
    /// given, else only the recorded flows when given; the layout when given.
    pub fn apply(&self, traffic: &mut TrafficConfig, layout: &mut LayoutConfig) {
        if let Some(world) = &self.traffic {
            *traffic = world.clone();
        }
        if let Some(flows) = &self.flows {
            traffic.flows = flows.clone();
        }
        if let Some(world) = self.layout {
            *layout = world;
        }
    }

    /// Whether the world replaces nothing.
    pub fn is_empty(&self) -> bool {
        self.traffic.is_none() && self.flows.is_none() && self.layout.is_none()
    }
}

/// The traffic of a world.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TrafficConfig {
    pub level: TrafficLevel,
    /// Overrides the level's cap on other vehicles when set.
    pub max_vehicles: Option<usize>,
    /// Simulation step, s.
    pub step_s: f64,
    /// While below the cap, new vehicles arrive at this mean rate (when their approach
    /// has room), 1/s.
    pub arrivals_per_s: f64,
    /// Traffic is simulated this long before the ego appears, s.
    pub warm_up_s: f64,
    /// A spawn needs this much free road ahead of the new vehicle on its approach, m.
    pub spawn_clearance_m: f64,
    /// Drivers decide on a gap once their front is this close to the yield line, m.
    pub decision_distance_m: f64,
    /// Vehicles farther along the path than this are not looked at, m.
    pub horizon_m: f64,
    pub vehicle_length_m: Span,
    pub vehicle_width_m: Span,
    pub drivers: DriverConfig,
    /// The `recorded` level's arrivals per entry (Poisson, each at its own rate; see
    /// [`World::spawn_flows`]): every entry listed gets its flow, the others none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub flows: Vec<EntryFlow>,
    /// Entry capacity from gap acceptance (set by `sim calibrate`): the named levels become
    /// fractions of it (see [`TrafficLevel`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub capacity: Option<CapacityModel>,
}

impl Default for TrafficConfig {
    fn default() -> Self {
        TrafficConfig {
            level: TrafficLevel::Medium,
            max_vehicles: None,
            step_s: 0.1,
            arrivals_per_s: 1.0,
            warm_up_s: 20.0,
            spawn_clearance_m: 12.0,
            decision_distance_m: 12.0,
            horizon_m: 60.0,
            vehicle_length_m: Span::new(3.9, 4.9),
            vehicle_width_m: Span::new(1.7, 2.0),
            drivers: DriverConfig::default(),
            flows: Vec::new(),
            capacity: None,
        }
    }
}

impl TrafficConfig {
    /// That every flow names an entry lane of `layout` with a usable route, at a finite
    /// non-negative rate; the error names the first that does not.
    pub fn check_flows(&self, layout: &RoundaboutLayout) -> Result<(), String> {
        for f in &self.flows {
            if !(f.vph.is_finite() && f.vph >= 0.0) {
                return Err(format!("the flow of lane {} is {} veh/h", f.lane, f.vph));
            }
            let usable = layout
                .usable_entries()
                .any(|e| layout.entries[e].lane.0 == f.lane);
            if !usable {
                let lanes: Vec<String> = layout
                    .usable_entries()
                    .map(|e| layout.entries[e].lane.0.to_string())
                    .collect();
                return Err(format!(
                    "lane {} is no entry of roundabout {} (its entry lanes: {})",
                    f.lane,
                    layout.roundabout.0,
                    lanes.join(", ")
                ));
            }
        }
        Ok(())
    }

    /// Whether arrivals come per entry ([`World::spawn_flows`]): at the `recorded` level, or
    /// at any level with a capacity model.
    pub fn per_entry_arrivals(&self) -> bool {
        self.level == TrafficLevel::Recorded || self.capacity.is_some()
    }

    /// Cap on other vehicles in the roundabout (none with per-entry arrivals unless
    /// `max_vehicles` sets one).
    pub fn cap(&self) -> usize {
        match (self.max_vehicles, self.per_entry_arrivals()) {
            (Some(cap), _) => cap,
            (None, false) => self.level.max_vehicles(),
            (None, true) => usize::MAX,
        }
    }

    /// Each entry of `layout`'s arrival rate, veh/h: the recorded flows at the `recorded`
    /// level, the capacity model's flow at a named level (none without per-entry arrivals).
    pub fn entry_rates(&self, layout: &RoundaboutLayout) -> Vec<f64> {
        match (self.level.saturation(), self.capacity) {
            (Some(saturation), Some(capacity)) => {
                let q = capacity.entry_flow_vph(layout, saturation);
                (0..layout.entries.len())
                    .map(|e| {
                        if layout.routes_by_entry[e].is_empty() {
                            0.0
                        } else {
                            q
                        }
                    })
                    .collect()
            }
            _ => layout
                .entries
                .iter()
                .map(|e| {
                    self.flows
                        .iter()
                        .filter(|f| f.lane == e.lane.0)
                        .map(|f| f.vph)
                        .sum()
                })
                .collect(),
        }
    }
}

/// A driver's parameters, drawn from its aggressiveness.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Driver {
    pub aggressiveness: f64,
    pub speed_factor: f64,
    pub time_headway_s: f64,
    pub min_gap_m: f64,
    pub max_accel_mps2: f64,
    pub comfort_decel_mps2: f64,
    /// The driver's gap acceptance.
    pub critical_gap: DriverGap,
    pub merge_brake_mps2: f64,
}

/// One driver's gap acceptance (its [`GapAcceptance`] at its aggressiveness).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DriverGap {
    /// Beyond the time to clear the merge point, s.
    Margin(f64),
    /// The critical gap as measured at a yield line (lag to the next circulating vehicle), s.
    Lag(f64),
}

impl DriverGap {
    /// The measured critical gap, when the driver has one, s.
    pub fn lag_s(&self) -> Option<f64> {
        match *self {
            DriverGap::Lag(gap) => Some(gap),
            DriverGap::Margin(_) => None,
        }
    }
}

impl Driver {
    pub fn new(config: &DriverConfig, aggressiveness: f64) -> Self {
        let a = aggressiveness.clamp(0.0, 1.0);
        Driver {
            aggressiveness: a,
            speed_factor: config.speed_factor.at(a),
            time_headway_s: config.time_headway_s.at(a),
            min_gap_m: config.min_gap_m.at(a),
            max_accel_mps2: config.max_accel_mps2.at(a),
            comfort_decel_mps2: config.comfort_decel_mps2.at(a),
            critical_gap: config.critical_gap.at(a),
            merge_brake_mps2: config.merge_brake_mps2.at(a),
        }
    }

    /// The least time a circulating vehicle must be away from the merge point for this
    /// driver to enter, given the time it needs to clear that point and to reach its yield
    /// line, s: its critical gap left when it reaches the line but never less than the time
    /// to clear the merge point and [`CLEARING_MARGIN_S`] (a driver with a measured critical
    /// gap), or the time to clear the merge point plus its margin.
    pub fn needed_lag_s(&self, clearing_s: f64, to_line_s: f64) -> f64 {
        match self.critical_gap {
            DriverGap::Lag(gap) => (to_line_s + gap).max(clearing_s + CLEARING_MARGIN_S),
            DriverGap::Margin(margin) => clearing_s + margin,
        }
    }

    /// The intelligent driver model's acceleration at speed `v` towards desired speed `v0`,
    /// behind a leader `gap` metres ahead (bumper to bumper) closing at `dv` m/s (None: free
    /// road).
    pub fn idm(&self, v: f64, v0: f64, leader: Option<(f64, f64)>) -> f64 {
        let free = 1.0 - (v / v0.max(0.1)).powi(4);
        let interaction = match leader {
            Some((gap, dv)) => {
                let wanted = self.min_gap_m
                    + (v * self.time_headway_s
                        + v * dv / (2.0 * (self.max_accel_mps2 * self.comfort_decel_mps2).sqrt()))
                    .max(0.0);
                (wanted / gap.max(0.01)).powi(2)
            }
            None => 0.0,
        };
        self.max_accel_mps2 * (free - interaction)
    }
}

/// The ego's kinematic bicycle and its path-tracking controller.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct EgoConfig {
    pub length_m: f64,
    pub width_m: f64,
    pub wheelbase_m: f64,
    pub max_steer_rad: f64,
    /// Pure pursuit look-ahead of the roundabout-driving task's rule (the world steers the
    /// ego with Stanley): `lookahead_min_m + lookahead_s * speed`, capped at 8 m.
    pub lookahead_min_m: f64,
    pub lookahead_s: f64,
    /// Gain on the cross-track error of the world's Stanley controller, which steers the
    /// ego along its route when no wheel angle is commanded, 1/s.
    pub stanley_gain: f64,
    pub max_accel_mps2: f64,
    pub max_brake_mps2: f64,
}

impl Default for EgoConfig {
    fn default() -> Self {
        EgoConfig {
            length_m: 4.5,
            width_m: 1.85,
            wheelbase_m: 2.7,
            max_steer_rad: 0.6,
            lookahead_min_m: 1.5,
            lookahead_s: 0.3,
            stanley_gain: 2.0,
            max_accel_mps2: 3.0,
            max_brake_mps2: 8.0,
        }
    }
}

/// What the caller decides for the ego in one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EgoCommand {
    /// m/s², clamped to the ego's limits; `None` lets the ego's driver model (a middle
    /// driver's IDM, yielding at its line until it accepts a gap) choose it.
    pub accel: Option<f64>,
    /// Front-wheel angle (left positive), clamped to `±max_steer_rad`; `None` lets the
    /// pure pursuit controller follow the ego's route.
    pub steer_rad: Option<f64>,
}

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

    /// Counts the new collisions between other vehicles and takes those vehicles out (see
    /// [`World::step_ego`]).
    fn clear_collisions(&mut self) {
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
    fn obstacle_on_path_for(&self, i: usize, horizon_m: f64, look_back: bool) -> Option<Leader> {
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

    fn nearest_ahead(&self, i: usize, merging: bool) -> Option<Leader> {
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
    fn merges_ahead_of(&self, i: usize, j: usize) -> bool {
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

    /// A driver who committed to a gap but had to stop before reaching the yield line
    /// (behind a queue, or behind a car merging ahead) has lost that gap: the commitment
    /// is dropped and the driver decides again at the line. Kept, it makes circulating
    /// drivers yield to a car that is not coming, and chains of such yields closed into
    /// gridlocks (the ring stopped for the rest of an episode). The ego under the agent's
    /// control is committed only past its line, so this never touches it.
    fn reconsider_stopped_commitments(&mut self) {
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
    fn decide_gaps(&mut self, ego_driven: bool) {
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
    fn to_lane_start(&self, o: &Vehicle, lane: LaneId) -> Option<f64> {
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

    /// Acceleration from a vehicle's driver model: IDM behind its leader, and behind its
    /// yield line while uncommitted.
    fn driver_accel(&self, i: usize) -> f64 {
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

    /// The next lane change on vehicle `i`'s route that its front has not reached, within
    /// [`LANE_CHANGE_LOOK_M`]: the ring lane it leaves, and where the connection into a
    /// ring lane of another rank (or out of the ring from an inner lane, across the outer
    /// one: see [`World::crosses_lanes`]) starts along the route.
    fn next_lane_change(&self, i: usize) -> Option<(LaneId, f64)> {
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
    fn crosses_lanes(&self, from: LaneId, to: LaneId) -> bool {
        let ranks = &self.layout.ring_lane_ranks;
        match (ranks.get(&from), ranks.get(&to)) {
            (Some(a), Some(b)) => a != b,
            (Some(a), None) => *a > 0,
            _ => false,
        }
    }

    /// Whether route `route` changes lanes (or leaves the ring across another lane) where
    /// it leaves ring lane `lane`.
    fn changes_lane_after(&self, route: usize, lane: LaneId) -> bool {
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
    /// ([`World::next_lane_change`]), if any: a committed car coming along another lane of
    /// the ring road that `i` leaves, towards the same junction, and not clearly in front
    /// of it; it is in the way when it would be beside `i`, or behind it closer than
    /// [`LANE_CHANGE_GAP_M`] plus [`LANE_CHANGE_HEADWAY_S`] of its speed (positions
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
    fn entering_across(&self, i: usize) -> Option<f64> {
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

    /// Removes vehicles whose front has reached the end of their route.
    fn despawn(&mut self) {
        let before = self.vehicles.len();
        let layout = &self.layout;
        self.vehicles
            .retain(|v| v.is_ego() || v.front_s() < layout.routes[v.route].path.length());
        self.stats.despawned += (before - self.vehicles.len()) as u64;
    }

    /// Below the cap, a new vehicle arrives with probability `arrivals_per_s * step` on a
    /// random approach (uniform over entries, then routes), if its start is free; with
    /// per-entry flows, see [`World::spawn_flows`].
    fn spawn(&mut self) {
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
    fn spawn_flows(&mut self) {
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
    fn spawn_draws(&mut self) -> [f64; 4] {
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
    fn roomy_routes(&self, entry: usize) -> impl Iterator<Item = usize> + '_ {
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
    fn route_weight(&self, route: usize) -> f64 {
        self.route_weights
            .get(route)
            .copied()
            .unwrap_or(1.0)
            .max(0.0)
    }

    /// Spawns a vehicle on `entry` (a route of it, its driver and size from `draws`) if its
    /// start is free; counts a blocked spawn otherwise. Whether it spawned.
    fn try_spawn(&mut self, entry: usize, draws: [f64; 4]) -> bool {
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

    #[test]
    fn a_measured_critical_gap_reads_and_writes_as_files_always_had_it() {
        let text = r#"{"critical_gap":{"median_s":2.7,"sigma":0.3}}"#;
        let config: DriverConfig = serde_json::from_str(text).unwrap();
        let gap = CriticalGap {
            median_s: 2.7,
            sigma: 0.3,
        };
        assert_eq!(config.critical_gap, GapAcceptance::Measured(gap));
        let written = serde_json::to_value(config).unwrap();
        assert_eq!(written["critical_gap_s"]["passive"], 2.0);
        assert_eq!(written["critical_gap_s"]["aggressive"], 0.5);
        assert_eq!(written["critical_gap"]["median_s"], 2.7);
        let again: DriverConfig = serde_json::from_value(written).unwrap();
        assert_eq!(again, config);
    }

    #[test]
    fn a_margin_reads_from_critical_gap_s_and_writes_no_distribution() {
        let text = r#"{"critical_gap_s":{"passive":3.0,"aggressive":1.0}}"#;
        let config: DriverConfig = serde_json::from_str(text).unwrap();
        assert_eq!(
            config.critical_gap,
            GapAcceptance::Margin(Span::new(3.0, 1.0))
        );
        assert_eq!(config.speed_factor, DriverConfig::default().speed_factor);
        let written = serde_json::to_value(config).unwrap();
        assert!(written.get("critical_gap").is_none(), "{written}");
        assert_eq!(written["critical_gap_s"]["passive"], 3.0);
        let driver = Driver::new(&config, 1.0);
        assert_eq!(driver.critical_gap, DriverGap::Margin(1.0));
        assert_eq!(driver.needed_lag_s(2.0, 5.0), 3.0);
    }

    #[test]
    fn a_calibrated_world_replaces_only_what_it_gives() {
        let flows = vec![EntryFlow {
            lane: 4,
            vph: 300.0,
            exits: Vec::new(),
        }];
        let mut traffic = TrafficConfig::default();
        let mut layout = LayoutConfig::default();
        let only_flows = CalibratedWorld {
            flows: Some(flows.clone()),
            ..CalibratedWorld::default()
        };
        only_flows.apply(&mut traffic, &mut layout);
        assert_eq!(traffic.flows, flows);
        assert_eq!(traffic.level, TrafficConfig::default().level);
        assert_eq!(layout, LayoutConfig::default());

        let world = CalibratedWorld {
            traffic: Some(TrafficConfig {
                level: TrafficLevel::High,
                ..TrafficConfig::default()
            }),
            flows: Some(flows.clone()),
            layout: None,
        };
        let mut traffic = TrafficConfig::default();
        world.apply(&mut traffic, &mut layout);
        assert_eq!(traffic.level, TrafficLevel::High);
        assert_eq!(
            traffic.flows, flows,
            "the recorded flows replace the traffic's"
        );
        assert!(CalibratedWorld::default().is_empty());
        assert!(!world.is_empty());
    }
}
