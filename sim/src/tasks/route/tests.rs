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
