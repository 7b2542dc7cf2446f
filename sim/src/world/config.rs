//! The settings of a traffic world: its level and cap, the arrival flows of a calibration
//! and their capacity model, a calibrated world as a config gives it, and the ego.

use super::*;

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
    /// `World::spawn_flows`): every entry listed gets its flow, the others none.
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

    /// Whether arrivals come per entry (`World::spawn_flows`): at the `recorded` level, or
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

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn traffic_levels_read_their_names() {
        for level in TrafficLevel::ALL {
            assert_eq!(level.name().parse::<TrafficLevel>(), Ok(level));
        }
        assert!("busy".parse::<TrafficLevel>().is_err());
    }

    #[test]
    fn entry_capacity_falls_as_the_conflicting_flow_rises() {
        let model = CapacityModel {
            critical_gap_s: 4.0,
            follow_up_s: 3.0,
        };
        assert!((model.entry_capacity_vph(0.0) - 1200.0).abs() < 1e-9);
        let caps: Vec<f64> = [0.0, 300.0, 600.0, 1200.0]
            .iter()
            .map(|&q| model.entry_capacity_vph(q))
            .collect();
        assert!(caps.windows(2).all(|w| w[1] < w[0]), "{caps:?}");
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
