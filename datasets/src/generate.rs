//! Generation of a labelled camera dataset from a drivable map (`pipeline dataset
//! generate`).
//!
//! Item `i` is made from its own generator, seeded from (global seed, `"generate"`, `i`),
//! so an item's bytes depend only on the seed, the config and the map — never on which
//! thread made it or in which order. Steps of one item: an ego pose on a car lane, the
//! camera jittered around it, a random look, road users around it, then the view's
//! surfaces, label, colour image and (optionally) the top-down label view. Everything drawn
//! is recorded in the item's [`ItemParams`].

use image::{GrayImage, RgbImage};
use maps::Map;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::seed::derive_seed;

use crate::render::camera::{Camera, CameraConfig, CameraPose, Vec3};
use crate::render::look::{Look, RandomiseConfig};
use crate::render::placement::{EgoPose, TrafficConfig, actor_colours, place_actors, sample_ego};
use crate::render::scene::{MapScene, SceneryConfig, uniform};
use crate::render::solids::{Actor, Solid};
use crate::render::topdown::{TopdownConfig, render_topdown};
use crate::render::view::{
    NoiseTexture, ViewBuffers, ViewInput, colour_image, label_image, render_view, view_wedge,
};

/// The stage in per-item seeds (`sim::seed`): "GENE".
pub const GENERATE_STAGE: u64 = 0x4745_4e45;
/// The stage of the map's procedural scenery: "SCEN".
pub const SCENERY_STAGE: u64 = 0x5343_454e;

/// Errors of generation.
#[derive(Debug, thiserror::Error)]
pub enum GenerateError {
    #[error("the map has no car lanes of at least 4 m to place the camera on")]
    NoCarLanes,
    #[error("invalid config: {0}")]
    Config(String),
}

/// Everything that decides what is generated, apart from the map, the seed and the count.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GenerateConfig {
    pub camera: CameraConfig,
    /// Ground and scenery beyond this distance from the camera are not drawn, metres.
    pub draw_distance_m: f64,
    pub scenery: SceneryConfig,
    pub traffic: TrafficConfig,
    pub randomise: RandomiseConfig,
    /// The top-down label view, when wanted.
    pub topdown: Option<TopdownConfig>,
}

impl Default for GenerateConfig {
    fn default() -> Self {
        GenerateConfig {
            camera: CameraConfig::default(),
            draw_distance_m: 220.0,
            scenery: SceneryConfig::default(),
            traffic: TrafficConfig::default(),
            randomise: RandomiseConfig::default(),
            topdown: None,
        }
    }
}

impl GenerateConfig {
    /// Why the config cannot be used, if it cannot.
    pub fn check(&self) -> Result<(), GenerateError> {
        if let Some(p) = self.camera.problem() {
            return Err(GenerateError::Config(p));
        }
        if !(self.draw_distance_m > 1.0 && self.draw_distance_m.is_finite()) {
            return Err(GenerateError::Config(format!(
                "draw distance {} m must be more than 1 m",
                self.draw_distance_m
            )));
        }
        if let Some(p) = self.traffic.problem() {
            return Err(GenerateError::Config(p));
        }
        if let Some(t) = &self.topdown
            && (t.size_px == 0
                || t.size_px > 8192
                || t.resolution_m.is_nan()
                || t.resolution_m <= 0.0)
        {
            return Err(GenerateError::Config(format!(
                "top-down view of {} px at {} m per pixel: size must be 1..8192, resolution positive",
                t.size_px, t.resolution_m
            )));
        }
        Ok(())
    }
}

/// The camera as it was placed for an item (angles in degrees, for people).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraParams {
    pub x: f64,
    pub y: f64,
    pub height_m: f64,
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
    pub hfov_deg: f64,
}

/// What made one item: recorded in the manifest's `params`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ItemParams {
    pub seed: u64,
    pub ego: EgoPose,
    pub camera: CameraParams,
    pub look: Look,
    pub actors: Vec<Actor>,
}

/// One generated item: RGB8 image, class-id label, optional top-down labels, parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct GeneratedItem {
    pub index: u64,
    pub image: RgbImage,
    pub label: GrayImage,
    /// Class ids seen from above, when asked for.
    pub topdown: Option<GrayImage>,
    pub params: ItemParams,
}

impl GeneratedItem {
    /// The item's id: its index, zero-padded so ids sort like indexes.
    pub fn id(&self) -> String {
        item_id(self.index)
    }
}

/// The id of item `index`.
pub fn item_id(index: u64) -> String {
    format!("gen_{index:06}")
}

/// Makes items from one map; shareable across threads.
#[derive(Debug)]
pub struct Generator<'m> {
    map: &'m Map,
    scene: MapScene,
    config: GenerateConfig,
    seed: u64,
    noise: NoiseTexture,
}

/// Buffers one worker reuses from item to item.
#[derive(Debug, Default)]
pub struct Workspace {
    view: ViewBuffers,
}

impl<'m> Generator<'m> {
    /// Prepares the map's scene (ground, scenery, indexes) for `config` and `seed`.
    pub fn new(map: &'m Map, config: GenerateConfig, seed: u64) -> Result<Self, GenerateError> {
        config.check()?;
        let scene = MapScene::build(map, &config.scenery, derive_seed(seed, SCENERY_STAGE, 0));
        if scene.car_lanes.is_empty() {
            return Err(GenerateError::NoCarLanes);
        }
        Ok(Generator {
            map,
            scene,
            config,
            seed,
            noise: NoiseTexture::new(),
        })
    }

    pub fn config(&self) -> &GenerateConfig {
        &self.config
    }

    pub fn scene(&self) -> &MapScene {
        &self.scene
    }

    /// Makes item `index`.
    pub fn item(&self, index: u64, work: &mut Workspace) -> Result<GeneratedItem, GenerateError> {
        let seed = derive_seed(self.seed, GENERATE_STAGE, index);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let cfg = &self.config;
        let jitter = if cfg.randomise.enabled {
            cfg.randomise.camera
        } else {
            crate::render::look::CameraJitter {
                height_m: 0.0,
                pitch_deg: 0.0,
                roll_deg: 0.0,
                yaw_deg: 0.0,
                lateral_m: 0.0,
            }
        };
        let ego = sample_ego(
            self.map,
            &self.scene,
            &mut rng,
            jitter.lateral_m,
            jitter.yaw_deg.to_radians(),
        )
        .ok_or(GenerateError::NoCarLanes)?;
        let spread = |rng: &mut ChaCha8Rng, v: f64| uniform(rng, (-v, v));
        let pose = CameraPose {
            position: Vec3::new(
                ego.position.x,
                ego.position.y,
                (cfg.camera.height_m + spread(&mut rng, jitter.height_m)).max(0.05),
            ),
            yaw: ego.heading_rad,
            pitch: (cfg.camera.pitch_deg + spread(&mut rng, jitter.pitch_deg)).to_radians(),
            roll: spread(&mut rng, jitter.roll_deg).to_radians(),
        };
        let camera = Camera::new(&cfg.camera, &pose);
        let look = Look::draw(&mut rng, &cfg.randomise);
        let wedge = view_wedge(&camera, cfg.draw_distance_m);
        let actors = place_actors(self.map, &self.scene, &ego, &wedge, &cfg.traffic, &mut rng);
        let solids: Vec<Solid> = actors
            .iter()
            .map(|a| a.solid(&actor_colours(a.kind, &mut rng)))
            .collect();
        let wear_seed: u64 = rng.random();
        let noise_seed: u64 = rng.random();

        let input = ViewInput {
            scene: &self.scene,
            camera: &camera,
            look: &look,
            actors: &solids,
            draw_distance_m: cfg.draw_distance_m,
            wear_seed,
        };
        render_view(&input, &mut work.view);
        let mut label = Vec::new();
        label_image(&work.view, &mut label);
        let mut image = Vec::new();
        colour_image(&input, &work.view, &self.noise, noise_seed, &mut image);
        let topdown = match &cfg.topdown {
            Some(t) => {
                let classes = render_topdown(
                    &self.scene,
                    &look,
                    wear_seed,
                    (ego.position, ego.heading_rad),
                    &solids,
                    t,
                );
                Some(gray(t.size_px, t.size_px, classes)?)
            }
            None => None,
        };
        let (w, h) = (cfg.camera.width, cfg.camera.height);
        Ok(GeneratedItem {
            index,
            image: RgbImage::from_raw(w, h, image).ok_or_else(|| size_error(w, h))?,
            label: gray(w, h, label)?,
            topdown,
            params: ItemParams {
                seed,
                ego,
                camera: CameraParams {
                    x: pose.position.x,
                    y: pose.position.y,
                    height_m: pose.position.z,
                    yaw_deg: pose.yaw.to_degrees(),
                    pitch_deg: pose.pitch.to_degrees(),
                    roll_deg: pose.roll.to_degrees(),
                    hfov_deg: cfg.camera.hfov_deg,
                },
                look,
                actors,
            },
        })
    }
}

fn size_error(w: u32, h: u32) -> GenerateError {
    GenerateError::Config(format!(
        "internal: a rendered buffer does not hold {w}x{h} pixels"
    ))
}

fn gray(w: u32, h: u32, pixels: Vec<u8>) -> Result<GrayImage, GenerateError> {
    GrayImage::from_raw(w, h, pixels).ok_or_else(|| size_error(w, h))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classes::Class;
    use crate::render::view::tests::straight_road;

    fn small() -> GenerateConfig {
        let mut c = GenerateConfig::default();
        c.camera.width = 96;
        c.camera.height = 64;
        c.topdown = Some(TopdownConfig {
            size_px: 64,
            resolution_m: 0.5,
        });
        c
    }

    #[test]
    fn items_repeat_with_the_seed_and_differ_between_indexes() {
        let map = straight_road();
        let g = Generator::new(&map, small(), 5).unwrap_or_else(|e| panic!("{e}"));
        let mut work = Workspace::default();
        let item = |g: &Generator<'_>, i, work: &mut Workspace| {
            g.item(i, work).unwrap_or_else(|e| panic!("{e}"))
        };
        let a = item(&g, 3, &mut work);
        let b = item(&g, 4, &mut work);
        // Made again after another item, with the same workspace: the same bytes.
        assert_eq!(a, item(&g, 3, &mut work));
        assert_ne!(a.image, b.image);
        assert_eq!(a.image.dimensions(), (96, 64));
        assert!(a.label.as_raw().iter().all(|&v| v < 5));
        let top = a.topdown.as_ref().map(|t| t.dimensions());
        assert_eq!(top, Some((64, 64)));
        // The ego stands on the lane, at the top-down view's centre.
        assert!(
            a.topdown
                .as_ref()
                .is_some_and(|t| t.get_pixel(32, 32).0[0] == Class::Road as u8)
        );
        // Another global seed: other items.
        let other = Generator::new(&map, small(), 6).unwrap_or_else(|e| panic!("{e}"));
        assert_ne!(a.params.seed, item(&other, 3, &mut work).params.seed);
    }

    #[test]
    fn bad_configs_and_maps_without_lanes_are_refused() {
        let mut c = small();
        c.camera.hfov_deg = f64::NAN;
        assert!(matches!(c.check(), Err(GenerateError::Config(_))));
        let mut c = small();
        c.draw_distance_m = 0.0;
        assert!(c.check().is_err());
        let mut c = small();
        c.topdown = Some(TopdownConfig {
            size_px: 10,
            resolution_m: -1.0,
        });
        assert!(c.check().is_err());
        let empty = Map::new(
            maps::Projection::local(maps::LatLon::new(0.0, 0.0)),
            maps::DrivingSide::Right,
            "car",
        );
        assert!(matches!(
            Generator::new(&empty, small(), 0),
            Err(GenerateError::NoCarLanes)
        ));
    }
}
