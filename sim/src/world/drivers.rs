//! The drivers of the traffic world: their parameters from their aggressiveness
//! ([`DriverConfig`], [`Driver`]), how they accept gaps ([`GapAcceptance`]) and the
//! intelligent driver model they follow with.

use super::*;

/// A driver parameter at aggressiveness 0 and at 1 (linear in between).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Span {
    pub passive: f64,
    pub aggressive: f64,
}

impl Span {
    pub(super) const fn new(passive: f64, aggressive: f64) -> Self {
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
pub(super) struct DriverConfigFile {
    pub(super) speed_factor: Span,
    pub(super) time_headway_s: Span,
    pub(super) min_gap_m: Span,
    pub(super) max_accel_mps2: Span,
    pub(super) comfort_decel_mps2: Span,
    pub(super) critical_gap_s: Span,
    pub(super) merge_brake_mps2: Span,
    pub(super) max_brake_mps2: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) critical_gap: Option<CriticalGap>,
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
    /// to clear the merge point and `CLEARING_MARGIN_S` (a driver with a measured critical
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

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn middle_driver(critical_gap: GapAcceptance) -> Driver {
        let config = DriverConfig {
            critical_gap,
            ..DriverConfig::default()
        };
        Driver::new(&config, 0.5)
    }

    #[test]
    fn a_driver_on_a_free_road_accelerates_to_its_desired_speed() {
        let driver = Driver::new(&DriverConfig::default(), 0.5);
        let (mut v, dt) = (0.0, 0.1);
        for _ in 0..600 {
            let a = driver.idm(v, 10.0, None);
            assert!(
                a >= -1e-9,
                "brakes on a free road below its speed: {a} at {v}"
            );
            v += a * dt;
        }
        assert!((v - 10.0).abs() < 0.2, "{v}");
        assert!(
            driver.idm(12.0, 10.0, None) < 0.0,
            "slows down above its speed"
        );
    }

    #[test]
    fn a_driver_brakes_for_a_slower_car_close_ahead() {
        let driver = Driver::new(&DriverConfig::default(), 0.5);
        let free = driver.idm(10.0, 10.0, None);
        let behind = driver.idm(10.0, 10.0, Some((5.0, 5.0)));
        assert!(
            behind < free - 1.0,
            "{behind} against {free} on a free road"
        );
    }

    #[test]
    fn a_gap_shorter_than_the_critical_gap_is_rejected() {
        let gap = CriticalGap {
            median_s: 3.0,
            sigma: 0.3,
        };
        let driver = middle_driver(GapAcceptance::Measured(gap));
        assert_eq!(driver.critical_gap, DriverGap::Lag(gap.of(0.5)));
        // At its line, clearing the merge point in 1 s: it needs its critical gap, the median.
        let needed = driver.needed_lag_s(1.0, 0.0);
        assert!((needed - 3.0).abs() < 1e-9, "{needed}");
        assert!(2.5 < needed, "a 2.5 s gap is accepted");
        // Farther from its line, the time to reach it adds to the gap it needs; and never
        // less than the time to clear the merge point and a margin.
        assert!((driver.needed_lag_s(1.0, 2.0) - 5.0).abs() < 1e-9);
        let slow = driver.needed_lag_s(4.0, 0.0);
        assert!((slow - (4.0 + CLEARING_MARGIN_S)).abs() < 1e-9, "{slow}");
        // Uncalibrated: the margin at aggressiveness 0.5 beyond the clearing time.
        let margin = middle_driver(GapAcceptance::Margin(Span::new(2.0, 0.5)));
        assert!((margin.needed_lag_s(1.0, 9.0) - 2.25).abs() < 1e-9);
    }

    #[test]
    fn aggressive_drivers_accept_shorter_gaps() {
        let gap = CriticalGap {
            median_s: 3.0,
            sigma: 0.3,
        };
        assert!(gap.of(0.0) > gap.of(0.5) && gap.of(0.5) > gap.of(1.0));
        assert!((gap.of(0.5) - 3.0).abs() < 1e-9);
        let (passive, aggressive) = (
            Driver::new(&DriverConfig::default(), 0.0),
            Driver::new(&DriverConfig::default(), 1.0),
        );
        assert!(aggressive.needed_lag_s(1.0, 0.0) < passive.needed_lag_s(1.0, 0.0));
    }

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
}
