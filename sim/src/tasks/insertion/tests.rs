use super::reward::Danger;
use super::*;
use crate::env::Env;

/// An ego that has entered the ring and meets a car merging in front of it from a later
/// entry brakes for it, as the world's drivers do (before, it drove on into it).
#[test]
fn an_entered_ego_brakes_for_a_car_merging_ahead() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/osm/montlake_roundabout.osm.pbf");
    let map = maps::import_file(&path, &Default::default()).expect("montlake imports");
    let setup = InsertionSetup::new(Arc::new(map), InsertionConfig::default())
        .expect("montlake has a roundabout");
    let env = RoundaboutInsertion::new(Arc::clone(&setup));
    let layout = Arc::clone(setup.layouts().next().expect("a layout"));
    // The ego's route drives the merge lane of a route from another entry.
    let (ego_route, other_route, merge_lane_start) = layout
        .routes
        .iter()
        .enumerate()
        .find_map(|(a, ra)| {
            layout.routes.iter().enumerate().find_map(|(b, rb)| {
                let start = ra.ring_lane_start(rb.merge_lane)?;
                (rb.entry != ra.entry && start - ra.merge_s > 12.0).then_some((a, b, start))
            })
        })
        .expect("two routes meeting in the ring");
    let config = &setup.config;
    let other = &layout.routes[other_route];
    // The ego's Permitted acceleration one step after it is put 9 m before that merge
    // lane (past its own line, so it counts as entered), with or without a car about
    // to merge there.
    let permitted = |with_other: bool| {
        let mut world = World::new(Arc::clone(&layout), config.traffic.clone(), config.ego, 7);
        world.insert_ego(ego_route, merge_lane_start - 9.0, 4.0, 0.0);
        if with_other {
            world.insert_vehicle(other_route, other.merge_s - 2.5, 2.0, 0.5, true);
        }
        world.step(0.0);
        let ego = world.ego_index().expect("the ego");
        assert!(world.vehicles()[ego].committed);
        assert!(world.leader(ego).is_none(), "nobody in the ego's lane");
        if with_other {
            let merging = world.merging_leader(ego).expect("the car merging ahead");
            assert!(merging.gap_m < 8.0, "{merging:?}");
        }
        env.ego_accel(&world, ego, Action::Permitted)
    };
    let (free, cut_in) = (permitted(false), permitted(true));
    assert!(
        cut_in < free - 1.0 && cut_in < 0.0,
        "Permitted gives {cut_in} m/s² towards a car cutting in, {free} m/s² without it"
    );
}

/// Deciding every step on frames 3 steps apart, with the actions held for 3 steps, sees
/// and earns exactly what deciding every 3 steps does (how the stack moves in between is
/// `render::tests::spaced_frame_stack_picks_every_spacing_th_frame`).
#[test]
fn deciding_every_step_keeps_the_trained_frame_spacing() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/osm/montlake_roundabout.osm.pbf");
    let map = Arc::new(maps::import_file(&path, &Default::default()).expect("montlake"));
    // Frames a decision apart (drawn per decision), two decisions apart (per decision,
    // every other one stacked) and 4 steps apart (drawn every step).
    for frame_steps in [None, Some(6), Some(4)] {
        let mut trained = InsertionConfig {
            action_repeat: 3,
            frame_steps,
            ..InsertionConfig::default()
        };
        trained.observation.width = 42;
        trained.observation.height = 42;
        trained.observation.stack = 3;
        let every_step = trained.deciding_every(1);
        assert_eq!(every_step.action_repeat, 1);
        assert_eq!(every_step.frame_steps, Some(frame_steps.unwrap_or(3)));
        let env = |config: &InsertionConfig| {
            let setup = InsertionSetup::new(Arc::clone(&map), config.clone()).expect("setup");
            let mut env = RoundaboutInsertion::new(setup);
            env.set_traffic(TrafficLevel::High);
            env
        };
        let (mut coarse, mut fine) = (env(&trained), env(&every_step));
        assert_eq!(coarse.reset(11), fine.reset(11));
        let actions = [Action::Caution, Action::NotPermitted, Action::Permitted];
        for action in actions.into_iter().cycle().take(7) {
            let want = coarse.step(action as usize);
            let mut reward = 0.0;
            let mut got = None;
            for _ in 0..3 {
                let step = fine.step(action as usize);
                reward += step.reward;
                got = Some(step.observation);
            }
            assert_eq!(
                got.as_ref(),
                Some(&want.observation),
                "{frame_steps:?}, {action:?}"
            );
            assert!(
                (reward - want.reward).abs() < 1e-6,
                "{reward} against {}",
                want.reward
            );
        }
        // The returns are summed in another order: equal up to rounding.
        let (a, b) = (coarse.summary(), fine.summary());
        assert!((a.episode_return - b.episode_return).abs() < 1e-9);
        assert_eq!(
            EpisodeSummary {
                episode_return: 0.0,
                ..a
            },
            EpisodeSummary {
                episode_return: 0.0,
                ..b
            }
        );
    }
}

/// The danger terms fall with σ to `danger_sigma_power`: at aggressiveness 0.5 a cut-in
/// step costs half the term with the paper's power 1 and a quarter of it with power 2,
/// and the other reward terms do not change.
#[test]
fn the_danger_terms_scale_with_sigma_to_the_configured_power() {
    let map = Arc::new(crate::test_maps::montlake());
    let cut_in_cost = |power: f64| {
        let mut config = InsertionConfig {
            aggressiveness: Some(0.5),
            ..InsertionConfig::default()
        };
        config.reward.cut_in_penalty = 0.08;
        config.reward.danger_sigma_power = power;
        let setup = InsertionSetup::new(Arc::clone(&map), config).expect("setup");
        let mut env = RoundaboutInsertion::new(setup);
        env.set_rendering(false);
        env.reset(5);
        let world = env.world.as_ref().expect("a world after reset");
        let ego = world.ego_index().expect("the ego");
        let reward = |cut_in| {
            let danger = Danger {
                close_following: false,
                cut_in,
            };
            env.step_reward(world, ego, env.last_action, danger)
        };
        reward(false) - reward(true)
    };
    assert!(
        (cut_in_cost(1.0) - 0.04).abs() < 1e-12,
        "{}",
        cut_in_cost(1.0)
    );
    assert!(
        (cut_in_cost(2.0) - 0.02).abs() < 1e-12,
        "{}",
        cut_in_cost(2.0)
    );
    let mut config = InsertionConfig::default();
    config.reward.danger_sigma_power = 0.0;
    assert!(InsertionSetup::new(Arc::clone(&map), config).is_err());
}

/// The short-entry term is charged once, at the entry, and grows as the lag taken
/// shrinks: always-Permitted episodes with and without it drive the same and their
/// returns differ by exactly penalty · (1 − lag / short_entry_s) · σ for the episodes
/// that entered less than `short_entry_s` in front of a car, and not at all otherwise.
#[test]
fn a_short_entry_costs_once_and_more_the_shorter_the_lag() {
    let map = Arc::new(crate::test_maps::montlake());
    let episode = |penalty: f64, seed: u64| {
        let mut config = InsertionConfig {
            aggressiveness: Some(0.5),
            ..InsertionConfig::default()
        };
        config.reward.short_entry_penalty = penalty;
        config.reward.short_entry_s = 2.0;
        let setup = InsertionSetup::new(Arc::clone(&map), config).expect("setup");
        let mut env = RoundaboutInsertion::new(setup);
        env.set_traffic(TrafficLevel::High);
        env.set_rendering(false);
        env.reset(seed);
        while env.step(Action::Permitted as usize).outcome.is_none() {}
        env.summary()
    };
    let (mut short, mut long) = (0, 0);
    for seed in 0..40 {
        let (without, with) = (episode(0.0, seed), episode(0.6, seed));
        assert_eq!(without.steps, with.steps);
        assert_eq!(without.entry_lag_s, with.entry_lag_s);
        let charged = without.episode_return - with.episode_return;
        let want = match with.entry_lag_s {
            Some(lag) if lag < 2.0 => {
                short += 1;
                0.6 * (1.0 - lag / 2.0) * 0.5
            }
            _ => {
                long += 1;
                0.0
            }
        };
        assert!(
            (charged - want).abs() < 1e-9,
            "seed {seed}: {charged} against {want}"
        );
    }
    assert!(
        short > 0 && long > 0,
        "{short} short entries, {long} others"
    );
}

/// With `ego_style_from_aggressiveness`, an aggressive ego aims faster and drives a
/// whole always-Permitted episode faster than a passive one; without it, aggressiveness
/// changes the reward only and the two episodes drive the same.
#[test]
fn the_ego_drives_in_its_aggressiveness_style_only_when_asked() {
    let map = Arc::new(crate::test_maps::montlake());
    let episode = |style: bool, aggressiveness: f64| {
        let config = InsertionConfig {
            ego_style_from_aggressiveness: style,
            aggressiveness: Some(aggressiveness),
            ..InsertionConfig::default()
        };
        let setup = InsertionSetup::new(Arc::clone(&map), config).expect("setup");
        let mut env = RoundaboutInsertion::new(setup);
        env.set_traffic(TrafficLevel::Low);
        env.set_rendering(false);
        let target = env.reset(3).scalars[1];
        while env.step(Action::Permitted as usize).outcome.is_none() {}
        (target, env.summary(), env.trajectory().to_vec())
    };
    let (passive_target, passive, passive_path) = episode(true, 0.0);
    let (aggressive_target, aggressive, _) = episode(true, 1.0);
    let ratio = f64::from(aggressive_target / passive_target);
    let span = InsertionConfig::default().traffic.drivers.speed_factor;
    assert!(
        (ratio - span.aggressive / span.passive).abs() < 1e-3,
        "target speeds {aggressive_target} and {passive_target}"
    );
    assert!(
        aggressive.mean_speed_mps > passive.mean_speed_mps * 1.05,
        "{aggressive:?} against {passive:?}"
    );
    let (_, plain_passive, plain_passive_path) = episode(false, 0.0);
    let (_, plain_aggressive, plain_aggressive_path) = episode(false, 1.0);
    assert_eq!(plain_passive_path, plain_aggressive_path);
    assert_eq!(plain_passive.steps, plain_aggressive.steps);
    assert_ne!(plain_passive_path, passive_path);
}
