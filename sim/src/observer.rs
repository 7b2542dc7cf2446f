//! What an agent sees besides its scalars, and the hook through which layers drawn outside
//! `sim` (the camera-segmentation view: the `datasets` camera renderer composed with the
//! `models` segmenter) reach a task.
//!
//! `sim` knows only the settings of the camera view ([`CameraViewConfig`], plain data) and
//! the [`SceneObserver`] trait; `models::camera_view` implements it, and the binary hands
//! an observer to the task's setup. So no crate depends on one below it.

use std::path::PathBuf;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::error::SimError;
use crate::scene::Scene;

/// Which layers a task observes (`view = "..."` in its config table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum View {
    /// No layers: the task's scalars only.
    Scalars,
    /// The bird's-eye layers of [`crate::render`] (the task's `observation` / `bev` table).
    #[default]
    Bev,
    /// The ego's front camera view, rendered from the scene and labelled by a trained
    /// segmenter: one layer per class (see [`CameraViewConfig`]).
    CameraSegmentation,
}

impl View {
    /// The camera table of a task's config when this view is the camera's: what a task's
    /// [`crate::tasks::Task::camera_view`] gives.
    pub fn camera(self, camera: Option<&CameraViewConfig>) -> Option<&CameraViewConfig> {
        match self {
            View::CameraSegmentation => camera,
            View::Bev | View::Scalars => None,
        }
    }

    /// The config value.
    pub fn name(self) -> &'static str {
        match self {
            View::Scalars => "scalars",
            View::Bev => "bev",
            View::CameraSegmentation => "camera-segmentation",
        }
    }
}

/// The camera-segmentation view's settings: where the camera is on the ego, the image it
/// renders and segments, and the layers the agent gets.
///
/// Each step the front camera's colour image (`width` × `height`, the dataset renderer's
/// plain look) is labelled by the segmenter at `segmenter`; the labels become
/// `classes.len()` layers of `width / pool` × `height / pool` pixels, each pixel the share of
/// its `pool` × `pool` block given that class (0–255), row 0 at the top of the image;
/// `stack` frames, oldest first.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraViewConfig {
    /// A segmenter model folder (`model.json` + `model.bpk`, from `pipeline segmenter train`).
    pub segmenter: PathBuf,
    /// Rendered and segmented image size, pixels.
    pub width: u32,
    pub height: u32,
    /// The labels are pooled by this factor in each direction for the layers (1: none).
    pub pool: u32,
    /// Class ids given a layer each, in order (the dataset class table: 0 road, 1 lane
    /// marking, 2 vehicle, 3 human, 4 other).
    pub classes: Vec<u8>,
    /// Height of the optical centre above the road, m.
    pub height_m: f64,
    /// Downward tilt of the optical axis, degrees.
    pub pitch_deg: f64,
    /// Horizontal field of view, degrees.
    pub hfov_deg: f64,
    /// The camera sits this far ahead of the ego's centre, m.
    pub forward_m: f64,
    /// Ground and scenery beyond this distance are not drawn, m.
    pub draw_distance_m: f64,
    /// Frames stacked, oldest first.
    pub stack: usize,
    /// Seed of the map's procedural scenery (buildings, trees, kerbs).
    pub scenery_seed: u64,
}

impl Default for CameraViewConfig {
    fn default() -> Self {
        CameraViewConfig {
            segmenter: PathBuf::new(),
            width: 128,
            height: 64,
            pool: 2,
            classes: vec![0, 1, 2],
            // The dataset generator's front camera (`datasets::render::CameraConfig`).
            height_m: 1.6,
            pitch_deg: 4.0,
            hfov_deg: 69.0,
            forward_m: 1.0,
            draw_distance_m: 120.0,
            stack: 2,
            scenery_seed: 0,
        }
    }
}

impl CameraViewConfig {
    /// One frame's layers: `(channels, height, width)`.
    pub fn frame_shape(&self) -> (usize, usize, usize) {
        let pool = self.pool.max(1);
        (
            self.classes.len(),
            (self.height / pool) as usize,
            (self.width / pool) as usize,
        )
    }

    /// The observation shape with `scalars` scalar inputs.
    pub fn observation_spec(&self, scalars: usize) -> crate::ObservationSpec {
        let (channels, height, width) = self.frame_shape();
        crate::ObservationSpec {
            channels: channels * self.stack,
            height,
            width,
            scalars,
        }
    }

    /// Why the settings cannot make a view, if they cannot (the segmenter folder is
    /// checked where the observer is built).
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |m: String| Err(SimError::Config(format!("[camera]: {m}")));
        if self.width == 0 || self.height == 0 || self.width > 2048 || self.height > 2048 {
            return bad(format!(
                "image size {}x{} must be between 1x1 and 2048x2048",
                self.width, self.height
            ));
        }
        if self.pool == 0
            || !self.width.is_multiple_of(self.pool)
            || !self.height.is_multiple_of(self.pool)
        {
            return bad(format!(
                "pool {} must be positive and divide the image size {}x{}",
                self.pool, self.width, self.height
            ));
        }
        if self.classes.is_empty() || self.classes.iter().any(|&c| c > 4) {
            return bad(format!(
                "classes {:?} must be one or more class ids of 0-4",
                self.classes
            ));
        }
        if self.stack == 0 {
            return bad("stack must be at least 1".into());
        }
        if !(self.forward_m.is_finite() && self.draw_distance_m > 1.0) {
            return bad(format!(
                "forward_m {} must be finite and draw_distance_m {} more than 1 m",
                self.forward_m, self.draw_distance_m
            ));
        }
        if self.segmenter.as_os_str().is_empty() {
            return bad(
                "segmenter is not set: give a model folder from `pipeline segmenter train`".into(),
            );
        }
        Ok(())
    }
}

/// Draws one frame of layers from a scene seen from its ego. Shared read-only by every
/// environment (and thread); the same scene must always give the same bytes.
pub trait SceneObserver: Send + Sync + std::fmt::Debug {
    /// One frame's layers: `(channels, height, width)`.
    fn frame_shape(&self) -> (usize, usize, usize);

    /// Writes one frame (`channels × height × width` bytes, channel-major) into `out`.
    fn observe(&self, scene: &Scene<'_>, out: &mut Vec<u8>);
}

/// The observer a task with `view` keeps: for the camera view, `observer`, which must be
/// there and draw the frames `camera` asks for (`camera` is the task's camera table, required
/// by that view); nothing for the other views. `table` names the config table in errors.
pub fn checked_observer(
    table: &str,
    view: View,
    camera: Option<&CameraViewConfig>,
    observer: Option<Arc<dyn SceneObserver>>,
) -> Result<Option<Arc<dyn SceneObserver>>, SimError> {
    if view != View::CameraSegmentation {
        return Ok(None);
    }
    let Some(camera) = camera else {
        return Err(SimError::Config(format!(
            "[{table}]: view = \"camera-segmentation\" needs a [{table}.camera] table with \
             segmenter = \"<model folder>\""
        )));
    };
    let Some(observer) = observer else {
        return Err(SimError::Config(format!(
            "[{table}]: view = \"camera-segmentation\" needs a camera observer \
             (models::camera_view; `pipeline agent` builds it from the camera table)"
        )));
    };
    let wanted = camera.frame_shape();
    if observer.frame_shape() != wanted {
        return Err(SimError::Config(format!(
            "[{table}]: the camera observer draws frames of {:?}, the camera table asks for {wanted:?}",
            observer.frame_shape()
        )));
    }
    Ok(Some(observer))
}
