//! Segmentation data in one class table (0 road, 1 lane marking, 2 vehicle, 3 human,
//! 4 other, 255 ignore): labelled camera images rendered from drivable maps, joint
//! image-and-label augmentation, public label sets mapped into the classes, and the
//! manifest, card and tools (stats, split, check, merge) they all share.

pub mod augment;
pub mod check;
pub mod classes;
pub mod error;
pub mod generate;
pub mod image_io;
pub mod import;
pub mod manifest;
pub mod merge;
pub mod render;
pub mod shard;
pub mod split;
pub mod stats;

pub use classes::{Class, IGNORE, may_stand_for};
pub use error::{DatasetError, Result};
pub use manifest::{Card, Dataset, Item};
