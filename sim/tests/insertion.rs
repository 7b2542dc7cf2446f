//! The roundabout-insertion task on the bundled montlake_roundabout map: determinism of
//! episodes and of the evaluation harness, and what the baselines must show.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sim::baselines::Baseline;
use sim::eval::{Condition, EvalOptions, evaluate, evaluate_episodes};
use sim::tasks::{InsertionConfig, InsertionSetup, RoundaboutInsertion};
use sim::world::TrafficLevel;
use sim::{Env, Outcome};

/// The bundled montlake_roundabout map.
fn montlake() -> Arc<maps::Map> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/osm/montlake_roundabout.osm.pbf");
    Arc::new(maps::import_file(&path, &Default::default()).unwrap())
}

/// An insertion episode on montlake at aggressiveness 0.5, the config otherwise `config`.
fn montlake_env(map: &Arc<maps::Map>, config: InsertionConfig) -> RoundaboutInsertion {
    let config = InsertionConfig {
        aggressiveness: Some(0.5),
        ..config
    };
    RoundaboutInsertion::new(InsertionSetup::new(Arc::clone(map), config).unwrap())
}

fn setup() -> Arc<InsertionSetup> {
    InsertionSetup::new(montlake(), InsertionConfig::default()).unwrap()
}

/// 1,000 steps with random actions (episodes reset as they end): rewards as bits, outcomes
/// and every observation, for the same seed twice and for another seed.
fn run(setup: &Arc<InsertionSetup>, seed: u64) -> (Vec<u32>, Vec<Option<Outcome>>, u64) {
    let mut env = RoundaboutInsertion::new(Arc::clone(setup));
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut episode = seed;
    let mut observation_hash = 0u64;
    let mut fold = |o: &sim::Observation| {
        for chunk in o.layers.chunks(8) {
            observation_hash = observation_hash.rotate_left(5)
                ^ chunk
                    .iter()
                    .fold(0u64, |h, b| h.wrapping_mul(31).wrapping_add(u64::from(*b)));
        }
        for s in &o.scalars {
            observation_hash = observation_hash.rotate_left(7) ^ u64::from(s.to_bits());
        }
    };
    fold(&env.reset(episode));
    let (mut rewards, mut outcomes) = (Vec::new(), Vec::new());
    for _ in 0..1000 {
        let step = env.step(rng.random_range(0..3));
        fold(&step.observation);
        rewards.push(step.reward.to_bits());
        outcomes.push(step.outcome);
        if step.outcome.is_some() {
            episode += 1;
            fold(&env.reset(episode));
        }
    }
    (rewards, outcomes, observation_hash)
}

#[test]
fn same_seed_gives_the_same_first_1000_steps() {
    let setup = setup();
    let a = run(&setup, 11);
    assert_eq!(a, run(&setup, 11));
    let b = run(&setup, 12);
    assert_ne!(a.0, b.0);
    assert!(
        // Episodes last at most 40 s (400 steps) on this roundabout.
        a.1.iter().filter(|o| o.is_some()).count() >= 2,
        "expected several episodes in 1000 steps"
    );
}

#[test]
fn evaluation_is_the_same_with_one_or_two_threads() {
    let setup = setup();
    let conditions = [
        Condition {
            traffic: TrafficLevel::High,
            aggressiveness: 0.5,
        },
        Condition {
            traffic: TrafficLevel::Low,
            aggressiveness: 0.0,
        },
    ];
    let options = EvalOptions {
        episodes: 20,
        seed: 5,
        lockstep: 3,
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                evaluate_episodes(&setup, || Baseline::Random, &conditions, &options, &|_| {})
            })
    };
    let (one, two) = (run(1), run(2));
    let bits = |r: &Vec<Vec<sim::tasks::EpisodeSummary>>| {
        r.iter()
            .flatten()
            .map(|e| (e.outcome, e.steps, e.episode_return.to_bits()))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(one[0].len(), 20);
}

/// The baselines behave as their names say: never going never arrives (and, waiting at
/// the line, is never hit), always going crashes in high traffic, more than any rule, and
/// takes more tight gaps than any rule; judging the gap beats acting at random.
#[test]
fn baselines_show_what_the_task_asks() {
    let setup = setup();
    let high = [Condition {
        traffic: TrafficLevel::High,
        aggressiveness: 0.5,
    }];
    let options = EvalOptions {
        episodes: 200,
        seed: 1,
        lockstep: 8,
    };
    let result = |b: Baseline| evaluate(&setup, || b, &high, &options, &|_| {}).remove(0);
    let stop = result(Baseline::AlwaysNotPermitted);
    assert_eq!(stop.reaches, 0.0);
    assert_eq!(stop.crashes, 0.0);
    assert_eq!(stop.time_overs, 1.0);
    let go = result(Baseline::AlwaysPermitted);
    assert!(
        go.crashes > 0.03,
        "always Permitted crashed in {} of high-traffic episodes",
        go.crashes
    );
    assert!(go.reaches > 0.2);
    let random = result(Baseline::Random);
    for threshold_m in [25.0, 20.0, 15.0, 10.0] {
        let rule = result(Baseline::Rule { threshold_m });
        assert!(
            rule.reaches > random.reaches,
            "rule {threshold_m} m reached {} vs random {}",
            rule.reaches,
            random.reaches
        );
        assert!(
            rule.crashes < go.crashes,
            "rule {threshold_m} m crashed in {} of episodes, always Permitted in {}",
            rule.crashes,
            go.crashes
        );
        assert!(
            rule.tight_entry_share < go.tight_entry_share,
            "rule {threshold_m} m entered tight in {} of its entries, always Permitted in {}",
            rule.tight_entry_share,
            go.tight_entry_share
        );
    }
    assert_eq!(stop.tight_entry_share, 0.0);
}

/// With `cut_in_only_cut_off`, the cut-in term counts only the cars the ego entered in
/// front of: the episodes do not change, no episode counts more cut-in steps than without,
/// and the 25 m rule, which waits for long gaps, loses most of its cut-in steps and now
/// counts fewer than always Permitted (without, it counts more: 1,432 against 1,282 here).
#[test]
fn cut_in_counts_only_the_cars_cut_off_when_asked() {
    let map = montlake();
    let conditions = [Condition {
        traffic: TrafficLevel::Medium,
        aggressiveness: 0.5,
    }];
    let options = EvalOptions {
        episodes: 100,
        seed: 3,
        lockstep: 8,
    };
    let episodes = |only_cut_off: bool, baseline: Baseline| {
        let mut config = InsertionConfig::default();
        config.reward.cut_in_only_cut_off = only_cut_off;
        let setup = InsertionSetup::new(Arc::clone(&map), config).unwrap();
        evaluate_episodes(&setup, || baseline, &conditions, &options, &|_| {}).remove(0)
    };
    let total = |e: &[sim::tasks::EpisodeSummary]| e.iter().map(|e| e.cut_in_steps).sum::<usize>();
    let mut totals = Vec::new(); // (any, cut off) for the rule, then for always Permitted
    for baseline in [
        Baseline::Rule { threshold_m: 25.0 },
        Baseline::AlwaysPermitted,
    ] {
        let (any, cut_off) = (episodes(false, baseline), episodes(true, baseline));
        for (a, c) in any.iter().zip(&cut_off) {
            assert_eq!((a.outcome, a.steps), (c.outcome, c.steps));
            assert!(c.cut_in_steps <= a.cut_in_steps);
        }
        totals.push((total(&any), total(&cut_off)));
    }
    let [(rule_any, rule_cut_off), (_, go_cut_off)] = totals[..] else {
        unreachable!()
    };
    assert!(
        rule_cut_off < go_cut_off && 2 * rule_cut_off < rule_any,
        "cut-in steps (any car, cars cut off): rule 25 m {:?}, always Permitted {:?}",
        totals[0],
        totals[1]
    );
}

/// With `rule_inputs`, the scalar inputs end with what the rule-based baselines see, the
/// observation shape says so, and the episode itself does not change (same rewards and
/// outcomes as without).
#[test]
fn rule_inputs_give_the_agent_what_the_rules_see() {
    use sim::tasks::insertion::{RULE_SCALARS, SCALARS, rule_scalars};
    let map = montlake();
    let mut plain = montlake_env(&map, InsertionConfig::default());
    let with_rule_inputs = InsertionConfig {
        rule_inputs: true,
        ..InsertionConfig::default()
    };
    let mut with_rule = montlake_env(&map, with_rule_inputs);
    assert_eq!(plain.observation_spec().scalars, SCALARS);
    assert_eq!(with_rule.observation_spec().scalars, SCALARS + RULE_SCALARS);
    let first = with_rule.reset(3);
    plain.reset(3);
    assert_eq!(first.scalars.len(), SCALARS + RULE_SCALARS);
    let (mut saw_a_car, mut entered) = (false, false);
    for _ in 0..400 {
        let a = plain.step(0);
        let b = with_rule.step(0);
        assert_eq!((a.reward, a.outcome), (b.reward, b.outcome));
        assert_eq!(b.observation.scalars[..SCALARS], a.observation.scalars[..]);
        let state = with_rule.state();
        assert_eq!(
            b.observation.scalars[SCALARS..],
            rule_scalars(&state)[..],
            "{state:?}"
        );
        saw_a_car |= b.observation.scalars[SCALARS] < 1.0;
        entered |= b.observation.scalars[SCALARS + 2] == 1.0;
        if b.outcome.is_some() {
            break;
        }
    }
    assert!(
        saw_a_car && entered,
        "a car within 50 m: {saw_a_car}, entered: {entered}"
    );
}

/// With `motion_inputs` (after the rule inputs), the scalar inputs end with the ego's speed
/// 0.5, 1 and 2 s ago and its slowest this episode, read off the episode's own speeds; the
/// episode itself does not change.
#[test]
fn motion_inputs_give_the_agent_its_own_recent_speeds() {
    use sim::tasks::insertion::{MOTION_SCALARS, RULE_SCALARS, SCALARS};
    let map = montlake();
    let config = InsertionConfig::default();
    let scale = config.speed_scale_mps as f32;
    let mut plain = montlake_env(&map, config.clone());
    let mut with_motion = montlake_env(
        &map,
        InsertionConfig {
            rule_inputs: true,
            motion_inputs: true,
            ..config
        },
    );
    let extra = SCALARS + RULE_SCALARS;
    assert_eq!(
        with_motion.observation_spec().scalars,
        extra + MOTION_SCALARS
    );
    let first = with_motion.reset(3);
    plain.reset(3);
    // The speeds of the episode so far, in the scalar's units, the first at the reset.
    let mut speeds = vec![first.scalars[0]];
    assert_eq!(first.scalars[extra..], [speeds[0]; MOTION_SCALARS]);
    // Not Permitted first (the ego brakes towards its line), then Permitted.
    for k in 0..300 {
        let action = if k < 60 { 1 } else { 0 };
        let a = plain.step(action);
        let b = with_motion.step(action);
        assert_eq!((a.reward, a.outcome), (b.reward, b.outcome));
        assert_eq!(b.observation.scalars[..SCALARS], a.observation.scalars[..]);
        speeds.push(b.observation.scalars[0]);
        let now = speeds.len() - 1;
        let back = |steps: usize| speeds[now.saturating_sub(steps)];
        let slowest = speeds.iter().copied().fold(f32::INFINITY, f32::min);
        let want = [back(5), back(10), back(20), slowest];
        for (got, want) in b.observation.scalars[extra..].iter().zip(want) {
            assert!(
                (got - want).abs() < 1e-6,
                "step {k}: {:?} against {want:?}",
                &b.observation.scalars[extra..]
            );
        }
        if b.outcome.is_some() {
            break;
        }
    }
    let slowest = speeds.iter().copied().fold(f32::INFINITY, f32::min);
    assert!(
        slowest * scale < 1.0 && speeds.len() > 80,
        "the ego braked (slowest {} m/s) and drove on ({} steps)",
        slowest * scale,
        speeds.len()
    );
}

/// With `action_repeat = 3` one decision is three world steps under the same action: the
/// same world, the rewards summed, the same outcome and the same newest frame as three
/// single steps, and an episode ends within the decision where it ends.
#[test]
fn action_repeat_holds_the_action_for_that_many_steps() {
    let map = montlake();
    let mut single = montlake_env(&map, InsertionConfig::default());
    let three_steps = InsertionConfig {
        action_repeat: 3,
        ..InsertionConfig::default()
    };
    let mut repeated = montlake_env(&map, three_steps);
    let mut ended = 0;
    for episode in 0..6u64 {
        single.reset(episode);
        repeated.reset(episode);
        for decision in 0..200 {
            // Wait for a while, then go: both outcomes and several action changes occur.
            let action = usize::from(decision < 8 + 3 * episode as usize);
            let b = repeated.step(action);
            let (mut reward, mut outcome) = (0.0f64, None);
            for _ in 0..3 {
                let a = single.step(action);
                reward += f64::from(a.reward);
                outcome = a.outcome;
                if outcome.is_some() {
                    break;
                }
            }
            assert_eq!(b.outcome, outcome, "episode {episode}, decision {decision}");
            assert!(
                (f64::from(b.reward) - reward).abs() < 1e-6,
                "episode {episode}, decision {decision}: {} against {reward}",
                b.reward
            );
            assert_eq!(repeated.state(), single.state());
            assert_eq!(repeated.newest_frame(), single.newest_frame());
            if outcome.is_some() {
                ended += 1;
                break;
            }
        }
    }
    assert_eq!(ended, 6, "every episode ends within 200 decisions");
    assert!(
        InsertionSetup::new(
            Arc::clone(&map),
            InsertionConfig {
                action_repeat: 0,
                ..InsertionConfig::default()
            }
        )
        .is_err()
    );
}

#[test]
fn the_task_runs_on_the_roundabout_the_config_names() {
    let map = montlake();
    let first = *map.roundabouts.keys().next().unwrap();
    let only = InsertionConfig {
        roundabout: Some(first.0),
        ..InsertionConfig::default()
    };
    let setup = InsertionSetup::new(Arc::clone(&map), only).unwrap();
    assert!(setup.layouts().all(|l| l.roundabout == first));
    let missing = InsertionConfig {
        roundabout: Some(u32::MAX),
        ..InsertionConfig::default()
    };
    assert!(InsertionSetup::new(map, missing).is_err());
}
