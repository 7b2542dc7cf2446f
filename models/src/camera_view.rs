//! The camera-segmentation observation (after the ITS and AIT studies): the ego's front
//! camera view of a task's scene, rendered by the dataset renderer
//! ([`datasets::render`]) and labelled by a trained segmenter ([`crate::segmenter`]), as
//! per-class layers for a Q-network.
//!
//! [`CameraSegmentation`] is a [`sim::observer::SceneObserver`]: built once per map (its
//! ground and scenery, the segmenter), shared read-only by every environment, it turns a
//! [`sim::Scene`] into one frame of layers. The camera stands `forward_m` ahead of the
//! ego's centre on its heading; every other actor of the scene is drawn as a vehicle (or a
//! person) box; the look is the renderer's plain one (clear noon, fresh paint, no sensor
//! noise, its texture from a fixed seed), so one scene always gives the same image. The segmenter runs on that one
//! image (batch 1), so a frame's labels do not depend on which other environments are
//! stepped with it or on the thread count.

use burn::tensor::Device;
use datasets::render::camera::{Camera, CameraConfig, CameraPose, Vec3};
use datasets::render::look::Look;
use datasets::render::scene::{MapScene, SceneryConfig};
use datasets::render::solids::{Actor, ActorColours, ActorKind, Solid};
use datasets::render::view::{
    NoiseTexture, ViewBuffers, ViewInput, colour_image, label_image, render_view,
};
use image::RgbImage;
use maps::Map;
use sim::Scene;
use sim::observer::{CameraViewConfig, SceneObserver};

use crate::segmenter::infer::{argmax_labels, normalise};
use crate::segmenter::{PspNet, PspNetConfig, SegmenterError, files};

/// The colours every actor is drawn with (a mid-grey car; the segmenter was trained on
/// random paints, so one fixed paint is as good as any).
const VEHICLE_COLOURS: ActorColours = ActorColours {
    main: [0.45, 0.47, 0.5],
    second: [0.12, 0.14, 0.18],
    third: [0.07, 0.07, 0.07],
};
const PERSON_COLOURS: ActorColours = ActorColours {
    main: [0.6, 0.2, 0.2],
    second: [0.15, 0.15, 0.3],
    third: [0.8, 0.62, 0.5],
};
/// Height of a drawn car, m (the scene has only footprints).
const CAR_HEIGHT_M: f64 = 1.5;
const PERSON_HEIGHT_M: f64 = 1.7;

/// How the labels of a frame are made.
#[derive(Debug)]
enum Labeller {
    /// The trained segmenter on the colour image.
    Segmenter {
        model: Box<PspNet>,
        config: Box<PspNetConfig>,
        device: Device,
    },
    /// The renderer's exact labels (no segmenter): the upper bound of the view.
    Exact,
}

/// The camera-segmentation observer of one map (see the module docs).
#[derive(Debug)]
pub struct CameraSegmentation {
    config: CameraViewConfig,
    camera: CameraConfig,
    scene: MapScene,
    noise: NoiseTexture,
    look: Look,
    labeller: Labeller,
}

impl CameraSegmentation {
    /// Prepares `map`'s scene and loads the segmenter of `config.segmenter` onto `device`.
    /// Errors name the file: a folder without `model.json`, an unreadable record, a model
    /// that does not give the 5 classes.
    pub fn new(
        map: &Map,
        config: &CameraViewConfig,
        device: &Device,
    ) -> Result<Self, SegmenterError> {
        config
            .validate()
            .map_err(|e| SegmenterError::Config(e.to_string()))?;
        let (model, seg_config) = files::load_model(&config.segmenter, device)?;
        if seg_config.classes <= usize::from(config.classes.iter().copied().max().unwrap_or(0)) {
            return Err(SegmenterError::invalid(
                &config.segmenter.join(files::MODEL_CONFIG_FILE),
                format!(
                    "the segmenter gives {} classes; the view asks for class ids {:?}",
                    seg_config.classes, config.classes
                ),
            ));
        }
        Self::build(
            map,
            config,
            Labeller::Segmenter {
                model: Box::new(model),
                config: Box::new(seg_config),
                device: device.clone(),
            },
        )
    }

    /// The same view labelled exactly by the renderer instead of a segmenter (for tests
    /// and as the view's upper bound); `config.segmenter` is not read.
    pub fn exact(map: &Map, config: &CameraViewConfig) -> Result<Self, SegmenterError> {
        Self::build(map, config, Labeller::Exact)
    }

    fn build(
        map: &Map,
        config: &CameraViewConfig,
        labeller: Labeller,
    ) -> Result<Self, SegmenterError> {
        let mut checked = config.clone();
        if checked.segmenter.as_os_str().is_empty() {
            checked.segmenter = "exact".into();
        }
        checked
            .validate()
            .map_err(|e| SegmenterError::Config(e.to_string()))?;
        let camera = CameraConfig {
            width: config.width,
            height: config.height,
            height_m: config.height_m,
            pitch_deg: config.pitch_deg,
            hfov_deg: config.hfov_deg,
        };
        if let Some(problem) = camera.problem() {
            return Err(SegmenterError::Config(format!("[camera]: {problem}")));
        }
        Ok(CameraSegmentation {
            config: config.clone(),
            camera,
            scene: MapScene::build(map, &SceneryConfig::default(), config.scenery_seed),
            noise: NoiseTexture::new(),
            look: Look::plain(),
            labeller,
        })
    }

    pub fn config(&self) -> &CameraViewConfig {
        &self.config
    }

    /// The camera's colour image and exact labels of `scene` (None without an ego).
    pub fn render(&self, scene: &Scene<'_>) -> Option<(RgbImage, Vec<u8>)> {
        let ego = scene.ego_actor()?;
        let c = &self.config;
        let (sin, cos) = ego.heading_rad.sin_cos();
        let pose = CameraPose {
            position: Vec3::new(
                ego.position.x + c.forward_m * cos,
                ego.position.y + c.forward_m * sin,
                c.height_m,
            ),
            yaw: ego.heading_rad,
            pitch: c.pitch_deg.to_radians(),
            roll: 0.0,
        };
        let camera = Camera::new(&self.camera, &pose);
        let solids: Vec<Solid> = scene
            .actors
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != scene.ego)
            .map(|(_, a)| {
                let (kind, height_m, colours) = match a.kind {
                    sim::ActorKind::Car => (ActorKind::Vehicle, CAR_HEIGHT_M, &VEHICLE_COLOURS),
                    sim::ActorKind::Pedestrian => {
                        (ActorKind::Pedestrian, PERSON_HEIGHT_M, &PERSON_COLOURS)
                    }
                };
                Actor {
                    kind,
                    position: a.position,
                    heading_rad: a.heading_rad,
                    length_m: a.length_m,
                    width_m: a.width_m,
                    height_m,
                }
                .solid(colours)
            })
            .collect();
        let input = ViewInput {
            scene: &self.scene,
            camera: &camera,
            look: &self.look,
            actors: &solids,
            draw_distance_m: c.draw_distance_m,
            wear_seed: 0,
        };
        let mut buffers = ViewBuffers::default();
        render_view(&input, &mut buffers);
        let mut labels = Vec::new();
        label_image(&buffers, &mut labels);
        let mut pixels = Vec::new();
        colour_image(&input, &buffers, &self.noise, 0, &mut pixels);
        let image = RgbImage::from_raw(c.width, c.height, pixels)?;
        Some((image, labels))
    }

    /// The class ids of `scene`'s camera view (`width × height`, row-major): the
    /// segmenter's, or the renderer's for [`CameraSegmentation::exact`].
    pub fn labels(&self, scene: &Scene<'_>) -> Option<Vec<u8>> {
        let (image, exact) = self.render(scene)?;
        match &self.labeller {
            Labeller::Exact => Some(exact),
            Labeller::Segmenter {
                model,
                config,
                device,
            } => {
                let logits = model.forward(normalise(&[&image], config, device));
                argmax_labels(logits).pop()
            }
        }
    }

    /// Per-class layers of a label image: the share of each `pool` × `pool` block given
    /// each of the view's classes, 0–255.
    pub fn layers_of(&self, labels: &[u8], out: &mut Vec<u8>) {
        let c = &self.config;
        let pool = c.pool.max(1) as usize;
        let (channels, h, w) = c.frame_shape();
        let width = c.width as usize;
        out.clear();
        out.resize(channels * h * w, 0);
        let area = (pool * pool) as u32;
        for (k, &class) in c.classes.iter().enumerate() {
            for y in 0..h {
                for x in 0..w {
                    let mut count = 0u32;
                    for dy in 0..pool {
                        let row = (y * pool + dy) * width + x * pool;
                        count += labels
                            .get(row..row + pool)
                            .map_or(0, |r| r.iter().filter(|&&l| l == class).count() as u32);
                    }
                    out[(k * h + y) * w + x] = ((count * 255 + area / 2) / area) as u8;
                }
            }
        }
    }
}

impl SceneObserver for CameraSegmentation {
    fn frame_shape(&self) -> (usize, usize, usize) {
        self.config.frame_shape()
    }

    fn observe(&self, scene: &Scene<'_>, out: &mut Vec<u8>) {
        match self.labels(scene) {
            Some(labels) => self.layers_of(&labels, out),
            None => {
                let (c, h, w) = self.frame_shape();
                out.clear();
                out.resize(c * h * w, 0);
            }
        }
    }
}

/// Loads the observer for `config` on `map` with the CPU device: what the tasks use.
pub fn load(map: &Map, config: &CameraViewConfig) -> Result<CameraSegmentation, SegmenterError> {
    CameraSegmentation::new(map, config, &crate::cpu_device())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use std::sync::Arc;

    use sim::Env;
    use sim::tasks::{RingDriving, RingDrivingConfig, RingDrivingSetup, Task};

    use super::*;

    fn montlake() -> Arc<Map> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../data/osm/montlake_roundabout.osm.pbf");
        Arc::new(maps::build::import_file(&path, &maps::ImportOptions::default()).unwrap())
    }

    /// A roundabout-driving episode started before its yield line, on the straight entry.
    fn entry_env(map: &Arc<Map>, seed: u64) -> RingDriving {
        let config = RingDrivingConfig {
            ring_start_probability: 0.0,
            ..RingDrivingConfig::default()
        };
        let setup = RingDrivingSetup::new(Arc::clone(map), config).unwrap();
        let mut env = RingDriving::new(setup);
        env.set_rendering(false);
        env.reset(seed);
        env
    }

    /// A small randomly initialised segmenter written to `dir`.
    fn random_segmenter(dir: &std::path::Path) -> CameraViewConfig {
        let config = PspNetConfig::new().with_width(0.25).with_psp_channels(32);
        let model = config.init_seeded(&crate::cpu_device(), 3).unwrap();
        files::save_model(dir, &model, &config).unwrap();
        CameraViewConfig {
            segmenter: dir.to_path_buf(),
            width: 64,
            height: 32,
            pool: 2,
            classes: vec![0, 1, 2, 3, 4],
            ..CameraViewConfig::default()
        }
    }

    #[test]
    fn the_exact_view_of_an_entry_shows_the_road_ahead() {
        let map = montlake();
        let config = CameraViewConfig {
            classes: vec![0, 1, 2, 3, 4],
            ..CameraViewConfig::default()
        };
        let observer = CameraSegmentation::exact(&map, &config).unwrap();
        let (c, h, w) = observer.frame_shape();
        assert_eq!((c, h, w), (5, 32, 64));
        for seed in 0..4 {
            let env = entry_env(&map, seed);
            let scene = env.scene().unwrap();
            let mut frame = Vec::new();
            observer.observe(&scene, &mut frame);
            assert_eq!(frame.len(), c * h * w);
            // Every pixel's class shares add up to a whole pixel.
            for i in 0..h * w {
                let total: u32 = (0..c).map(|k| u32::from(frame[k * h * w + i])).sum();
                assert!((250..=260).contains(&total), "pixel {i}: {total}");
            }
            // Road fills the bottom middle of the image: the lane in front of the ego.
            let road = &frame[..h * w];
            let bottom_middle: Vec<u8> = (h * 3 / 4..h)
                .flat_map(|y| (w * 3 / 8..w * 5 / 8).map(move |x| road[y * w + x]))
                .collect();
            let mean = bottom_middle.iter().map(|&v| f64::from(v)).sum::<f64>()
                / bottom_middle.len() as f64;
            assert!(mean > 200.0, "seed {seed}: road share {mean} of 255 ahead");
            // And the top rows are above the horizon: no road there.
            assert!(road[..w].iter().all(|&v| v == 0), "seed {seed}");
            let mut again = Vec::new();
            observer.observe(&scene, &mut again);
            assert_eq!(frame, again);
        }
    }

    #[test]
    fn the_segmented_view_is_the_same_with_any_thread_count() {
        let dir = tempfile::tempdir().unwrap();
        let config = random_segmenter(dir.path());
        let map = montlake();
        let observer = CameraSegmentation::new(&map, &config, &crate::cpu_device()).unwrap();
        let env = entry_env(&map, 2);
        let scene = env.scene().unwrap();
        let frame_with = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut frame = Vec::new();
                observer.observe(&scene, &mut frame);
                frame
            })
        };
        let one = frame_with(1);
        assert_eq!(one.len(), 5 * 16 * 32);
        assert_eq!(one, frame_with(2));
        assert_eq!(one, frame_with(3));
        // A random network labels something: not every layer is empty.
        assert!(one.iter().any(|&v| v > 0));
    }

    #[test]
    fn a_missing_or_broken_segmenter_is_one_error_naming_the_file() {
        let map = montlake();
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no_such_model");
        let config = CameraViewConfig {
            segmenter: missing.clone(),
            ..CameraViewConfig::default()
        };
        let e = CameraSegmentation::new(&map, &config, &crate::cpu_device()).unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("no_such_model") && text.contains("model.json"),
            "{text}"
        );

        let broken = random_segmenter(dir.path());
        std::fs::write(dir.path().join(files::MODEL_RECORD_FILE), b"not a record").unwrap();
        let e = CameraSegmentation::new(&map, &broken, &crate::cpu_device()).unwrap_err();
        assert!(e.to_string().contains("model.bpk"), "{e}");

        let unset = CameraViewConfig::default();
        let e = CameraSegmentation::new(&map, &unset, &crate::cpu_device()).unwrap_err();
        assert!(e.to_string().contains("segmenter"), "{e}");
    }
}
