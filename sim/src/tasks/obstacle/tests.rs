use super::*;
use crate::env::Env;
use crate::eval::{TaskResult, run_episodes};

fn env(scenario: Scenario) -> ObstacleAvoidance {
    let setup = ObstacleSetup::new(ObstacleConfig {
        scenario,
        ..ObstacleConfig::default()
    });
    #[allow(clippy::unwrap_used)]
    ObstacleAvoidance::new(setup.unwrap())
}

fn run<P: TaskPolicy<ObstacleAvoidance>>(
    scenario: Scenario,
    policy: impl Fn() -> P + Sync,
    n: u64,
) -> Vec<ObstacleSummary> {
    let seeds: Vec<u64> = (0..n).collect();
    run_episodes(|| env(scenario), policy, &seeds, 8)
}

#[test]
fn reward_shapes_match_the_study() {
    assert_eq!(study_main_reward(0.0, 100.0), 3000.0);
    assert_eq!(study_main_reward(100.0, 100.0), -9500.0);
    // The printed coefficients would give this at 100 m.
    assert_eq!(-2.0 * 100.0f64.powi(2) - 98.0 * 100.0 + 3000.0, -26_800.0);
    assert!((lidar_penalty(0.0) + 3040.0).abs() < 1e-9);
    assert!((lidar_penalty(40.0) + 1016.0).abs() < 1e-6);
    // Monotone over the range: closer is always worse.
    let values: Vec<f64> = (0..=400).map(|i| lidar_penalty(i as f64 / 10.0)).collect();
    assert!(values.windows(2).all(|w| w[1] > w[0]));
    assert_eq!(stop_bonus(10.0), 200.0);
    assert_eq!(stop_bonus(0.0), 2200.0);
}

#[test]
fn lidar_sees_a_box_ahead_and_nothing_outside_the_window() {
    let lidar = LidarConfig::default();
    let ahead = OrientedBox::new(Point::new(20.0, 0.0), 0.0, 4.0, 2.0);
    let hit = scan(&lidar, Point::new(0.0, 0.0), 0.0, &[ahead]);
    let hit = hit.unwrap_or(LidarHit {
        distance_m: f64::NAN,
        longitudinal_m: f64::NAN,
        lateral_m: f64::NAN,
    });
    assert!((hit.distance_m - 18.0).abs() < 1e-9, "{hit:?}");
    assert!((hit.longitudinal_m - 18.0).abs() < 1e-9 && hit.lateral_m.abs() < 1e-9);
    // The same box rotated with the ego: the offsets are in the ego frame.
    let turned = OrientedBox::new(Point::new(0.0, 20.0), FRAC_PI_2, 4.0, 2.0);
    let hit = scan(&lidar, Point::new(0.0, 0.0), FRAC_PI_2, &[turned]);
    assert!(hit.is_some_and(|h| (h.longitudinal_m - 18.0).abs() < 1e-9));
    // Beside the window (its near side 4 m off the axis), behind, beyond the range.
    let beside = OrientedBox::new(Point::new(10.0, 5.0), 0.0, 4.0, 2.0);
    let behind = OrientedBox::new(Point::new(-10.0, 0.0), 0.0, 4.0, 2.0);
    let far = OrientedBox::new(Point::new(45.0, 0.0), 0.0, 4.0, 2.0);
    assert_eq!(
        scan(&lidar, Point::new(0.0, 0.0), 0.0, &[beside, behind, far]),
        None
    );
    // Partly inside: the nearest hit is at the window's edge or within it.
    let edge = OrientedBox::new(Point::new(10.0, 3.5), 0.0, 4.0, 2.0);
    let hit = scan(&lidar, Point::new(0.0, 0.0), 0.0, &[edge]);
    assert!(
        hit.is_some_and(|h| h.lateral_m <= 3.0 && h.lateral_m >= 2.5),
        "{hit:?}"
    );
}

#[test]
fn motion_inputs_tell_a_crossing_vehicle_from_a_parked_one() {
    let lateral_rates = |scenario: Scenario| -> Vec<f32> {
        let setup = ObstacleSetup::new(ObstacleConfig {
            scenario,
            motion_inputs: true,
            ..ObstacleConfig::default()
        });
        #[allow(clippy::unwrap_used)]
        let mut env = ObstacleAvoidance::new(setup.unwrap());
        assert_eq!(env.observation_spec().scalars, SCALARS + MOTION_SCALARS);
        let first = env.reset(5);
        assert_eq!(
            first.scalars[SCALARS..],
            [0.0, 0.0],
            "no motion before a second return"
        );
        // Drive on until the obstacle is in view, then brake so the ego stays behind it
        // while a crossing one passes in front.
        let mut seen = false;
        let mut rates = Vec::new();
        for _ in 0..100 {
            let action = if seen {
                Action::Brake
            } else {
                Action::Straight
            };
            let step = env.step(action as usize);
            seen |= step.observation.scalars[4] < 1.0;
            rates.push(step.observation.scalars[SCALARS]);
            if step.outcome.is_some() {
                break;
            }
        }
        assert!(seen, "{scenario:?}: the obstacle came into view");
        rates
    };
    let parked = lateral_rates(Scenario::Static);
    let crossing = lateral_rates(Scenario::Crossing);
    assert!(parked.iter().all(|r| r.abs() < 0.02), "{parked:?}");
    // 1.5-3 m/s across the road over 5 m/s (once in view).
    assert!(crossing.iter().any(|r| r.abs() > 0.2), "{crossing:?}");
}

#[test]
fn driving_straight_hits_a_parked_vehicle_and_a_crossing_one() {
    for scenario in [Scenario::Static, Scenario::Crossing] {
        let episodes = run(scenario, || ConstantAction(Action::Straight as usize), 20);
        assert!(
            episodes.iter().all(|e| e.outcome == Outcome::Crashed),
            "{scenario:?}: {:?}",
            episodes.iter().map(|e| e.outcome).collect::<Vec<_>>()
        );
        assert!(episodes.iter().all(|e| e.min_gap_m == 0.0));
    }
}

#[test]
fn the_rule_reaches_the_destination_in_both_scenarios() {
    for scenario in [Scenario::Static, Scenario::Crossing] {
        let episodes = run(scenario, || PassOrYield, 100);
        let result = TaskResult::of(&episodes);
        assert!(result.reaches >= 0.95, "{scenario:?}: {result:?}");
    }
    // The rule stops for crossing vehicles, not for parked ones.
    let crossing = run(Scenario::Crossing, || PassOrYield, 20);
    assert!(crossing.iter().any(|e| e.stopping_gap_m.is_some()));
}

#[test]
fn episodes_are_deterministic_and_the_scenario_only_picks_the_obstacle() {
    let a = run(Scenario::Mixed, || PassOrYield, 16);
    let b = run(Scenario::Mixed, || PassOrYield, 16);
    assert_eq!(a, b);
    let kinds: Vec<ObstacleKind> = a.iter().map(|e| e.kind).collect();
    assert!(kinds.contains(&ObstacleKind::Parked) && kinds.contains(&ObstacleKind::Crossing));
    let mut one = env(Scenario::Static);
    let first = one.reset(3);
    one.step(Action::SteerLeft as usize);
    assert_eq!(one.reset(3), first);
}

#[test]
fn any_action_index_and_steps_after_the_end_are_safe() {
    let mut e = env(Scenario::Crossing);
    // Before any reset: a finished step, no panic.
    assert!(e.step(0).outcome.is_some());
    e.reset(1);
    let mut last = None;
    for i in 0..1000 {
        let step = e.step(i * 7919 % 11);
        assert!(step.observation.scalars.iter().all(|v| v.is_finite()));
        assert_eq!(step.observation.scalars.len(), SCALARS);
        if step.outcome.is_some() {
            last = step.outcome;
            break;
        }
    }
    assert!(last.is_some());
    let again = e.step(0);
    assert_eq!((again.reward, again.outcome), (0.0, last));
}

#[test]
fn normalised_rewards_are_small_and_study_ones_follow_the_terms() {
    let mut e = env(Scenario::Static);
    e.reset(5);
    let mut total = 0.0;
    loop {
        let step = e.step(Action::Straight as usize);
        assert!(step.reward.abs() < 5.0, "{}", step.reward);
        total += f64::from(step.reward);
        if step.outcome.is_some() {
            break;
        }
    }
    // Driving into the parked vehicle loses every bit of progress: the potential
    // returns to the farthest point's, minus the danger terms.
    assert!(total < 0.0, "{total}");
    e.set_reward(RewardKind::Study);
    e.reset(5);
    let mut study = 0.0;
    let mut crashed = false;
    while !crashed {
        let step = e.step(Action::Straight as usize);
        study += f64::from(step.reward);
        crashed = step.outcome.is_some();
    }
    assert!(study < -9500.0, "{study}");
}

#[test]
fn invalid_configs_are_refused() {
    let bad = [
        ObstacleConfig {
            steer_deg: 40.0,
            ..ObstacleConfig::default()
        },
        ObstacleConfig {
            step_s: 0.0,
            ..ObstacleConfig::default()
        },
        ObstacleConfig {
            static_distance_m: (70.0, 30.0),
            ..ObstacleConfig::default()
        },
    ];
    for config in bad {
        assert!(ObstacleSetup::new(config).is_err());
    }
}

use crate::tasks::ConstantAction;
