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
//!   [`decisions`] labels drivers' go / wait decisions;
//!   [`closed_loop`] lets a policy drive a recorded vehicle among the replayed others;
//! - [`simulated`] writes simulated traffic as logs and reads it back, to check that a log
//!   gives the frames the simulator gave;
//! - [`ego`] takes the ego's track from its pose or GPS topic into a map's frame, resamples
//!   it and matches it to lanes;
//! - [`replay`] judges policies (gap rules, behaviour cloning, agents) against the drivers'
//!   decisions, open and closed loop, and [`offline`] turns the drivers' approaches into
//!   transitions to learn from (both with the `policies` feature, on by default).

pub mod bag;
pub mod cdr;
pub mod closed_loop;
pub mod convert;
pub mod decisions;
pub mod decode;
pub mod ego;
pub mod error;
pub mod foxglove;
pub mod frames;
pub mod gaps;
pub mod info;
pub mod interaction;
pub mod mcap_read;
pub mod msgdefs;
pub mod msgs;
pub mod noise;
#[cfg(feature = "policies")]
pub mod offline;
pub mod on_map;
pub mod project;
#[cfg(feature = "policies")]
pub mod replay;
pub mod roles;
pub mod scenes;
pub mod simulated;
pub mod source;
pub mod traffic;

pub use decode::{Codec, Decoded, DecodedLog, DecodedMessage, MessageKind, read_decoded};
pub use error::{DecodeError, LogError, LogResult};
pub use source::{Log, RawMessage, ReadOptions, ReadReport, StorageKind, Topic};
