//! The camera renderer: labelled front-camera images of a drivable map.
//!
//! Built for pixel-exact labels and speed on a CPU:
//!
//! - [`scene`]: once per map, the ground as polygons in painting order (sidewalks, kerbs,
//!   road surfaces, markings, stop lines) and procedural buildings and trees, each with a
//!   uniform grid so a view only touches what is near it; shared read-only by all threads.
//! - [`camera`]: a pinhole camera (height, pitch, roll, field of view, image size); the
//!   inverse depth of any plane is affine in the pixel position.
//! - [`raster`]: polygons are clipped at the near plane, projected and filled at pixel
//!   centres; faces of 3D solids go through an exact per-pixel depth test against
//!   everything drawn so far, the ground included.
//! - [`solids`]: boxes and prisms with outward normals: vehicles (body, glass cabin, wheels,
//!   tail lights), people (legs, body, head), buildings, trees; road users enter as
//!   [`solids::Actor`] oriented boxes, as a traffic scene would give them.
//! - [`placement`]: ego poses on car lanes, vehicles on nearby lanes, people on sidewalks
//!   and crossings, only where the camera sees them and never overlapping.
//! - [`look`]: domain randomisation (colours, paint wear, texture, sun, sky, shadows, fog,
//!   rain, exposure, sensor noise).
//! - [`view`]: one view's surfaces, then its label and its colour image; [`topdown`]: the
//!   same scene's labels from above.
//!
//! Every pixel holds one surface id, and both the label and the colour come from it, so
//! they always agree; labels are never blended or antialiased.

pub mod camera;
pub mod look;
pub mod placement;
pub mod raster;
pub mod scene;
pub mod solids;
pub mod topdown;
pub mod view;

pub use camera::{Camera, CameraConfig, CameraPose, Vec3};
pub use look::{Look, RandomiseConfig};
pub use placement::TrafficConfig;
pub use scene::{MapScene, SceneryConfig};
pub use solids::{Actor, ActorKind};
pub use topdown::TopdownConfig;
