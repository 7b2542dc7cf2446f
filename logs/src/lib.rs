//! Real driving logs: MCAP files and ROS 2 bags (sqlite3 or MCAP storage) read into typed
//! messages, `logs info` summaries, and INTERACTION track files converted into MCAP.
//!
//! - [`source::Log`] opens any of the storage forms and streams raw messages in storage order
//!   ([`mcap_read`] for MCAP, [`bag`] for rosbag2);
//! - [`decode`] picks a decoder per topic: ROS messages in CDR or ROS 1 ([`msgs`] over
//!   [`cdr`]), Foxglove schemas in protobuf or JSON ([`foxglove`]); unknown types are counted;
//! - [`info`] summarises a log like `ros2 bag info`;
//! - [`interaction`] reads INTERACTION track CSVs and [`convert`] writes them as MCAP;
//! - [`roles`] says which topic is the ego pose, the GPS, the objects, the camera (given or
//!   detected);
//! - [`project`] draws log frames in the simulator's bird's-eye representation, with
//!   [`noise`] for perception noise, and [`frames`] is the folder they are written to;
//! - [`on_map`] is the one check that a recording was made on a given map;
//! - [`simulated`] writes simulated traffic as logs and reads it back, to check that a log
//!   gives the frames the simulator gave;
//! - [`ego`] takes the ego's track from its pose or GPS topic into a map's frame, resamples
//!   it and matches it to lanes.
//!
//! What the drivers of a recording did and the world calibrated to them are the `traffic`
//! crate's; policies judged against them, the `judge` crate's.

pub mod bag;
pub mod cdr;
pub mod convert;
pub mod decode;
pub mod ego;
pub mod error;
pub mod foxglove;
pub mod frames;
pub mod info;
pub mod interaction;
pub mod kind;
pub mod mcap_read;
pub mod msgdefs;
pub mod msgs;
pub mod noise;
pub mod on_map;
pub mod project;
pub mod raw;
pub mod roles;
pub mod scenes;
pub mod simulated;
pub mod source;

pub use decode::{Codec, Decoded, DecodedLog, DecodedMessage, MessageKind, read_decoded};
pub use error::{DecodeError, LogError, LogResult};
pub use source::{Log, RawMessage, ReadOptions, ReadReport, StorageKind, Topic};
