//! The message types the crate decodes, by their ROS and Foxglove names.

use serde::Serialize;

/// The message types this crate decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub enum MessageKind {
    Odometry,
    PoseStamped,
    PoseWithCovarianceStamped,
    NavSatFix,
    Imu,
    TfMessage,
    Detection3DArray,
    Image,
    CompressedImage,
    DiagnosticArray,
    FoxgloveLocationFix,
    FoxgloveFrameTransform,
    FoxgloveFrameTransforms,
    FoxglovePoseInFrame,
    FoxgloveCompressedImage,
    FoxgloveSceneUpdate,
}

/// (kind, ROS package, ROS type) of the ROS messages.
const ROS_TYPES: [(MessageKind, &str, &str); 10] = [
    (MessageKind::Odometry, "nav_msgs", "Odometry"),
    (MessageKind::PoseStamped, "geometry_msgs", "PoseStamped"),
    (
        MessageKind::PoseWithCovarianceStamped,
        "geometry_msgs",
        "PoseWithCovarianceStamped",
    ),
    (MessageKind::NavSatFix, "sensor_msgs", "NavSatFix"),
    (MessageKind::Imu, "sensor_msgs", "Imu"),
    (MessageKind::TfMessage, "tf2_msgs", "TFMessage"),
    (
        MessageKind::Detection3DArray,
        "vision_msgs",
        "Detection3DArray",
    ),
    (MessageKind::Image, "sensor_msgs", "Image"),
    (
        MessageKind::CompressedImage,
        "sensor_msgs",
        "CompressedImage",
    ),
    (
        MessageKind::DiagnosticArray,
        "diagnostic_msgs",
        "DiagnosticArray",
    ),
];

/// Foxglove schema names (protobuf `foxglove.X`; JSON schemas use the same names).
const FOXGLOVE_TYPES: [(MessageKind, &str); 6] = [
    (MessageKind::FoxgloveLocationFix, "LocationFix"),
    (MessageKind::FoxgloveFrameTransform, "FrameTransform"),
    (MessageKind::FoxgloveFrameTransforms, "FrameTransforms"),
    (MessageKind::FoxglovePoseInFrame, "PoseInFrame"),
    (MessageKind::FoxgloveCompressedImage, "CompressedImage"),
    (MessageKind::FoxgloveSceneUpdate, "SceneUpdate"),
];

impl MessageKind {
    /// The kind of a ROS type name: `pkg/msg/Type` (ROS 2) or `pkg/Type` (ROS 1).
    pub fn from_ros_name(name: &str) -> Option<Self> {
        let (package, rest) = name.split_once('/')?;
        let ty = rest.strip_prefix("msg/").unwrap_or(rest);
        ROS_TYPES
            .iter()
            .find(|(_, p, t)| *p == package && *t == ty)
            .map(|(k, _, _)| *k)
    }

    /// The kind of a Foxglove schema name (`foxglove.LocationFix`, or `LocationFix`).
    pub fn from_foxglove_name(name: &str) -> Option<Self> {
        let ty = name.strip_prefix("foxglove.").unwrap_or(name);
        FOXGLOVE_TYPES
            .iter()
            .find(|(_, t)| *t == ty)
            .map(|(k, _)| *k)
    }

    /// The ROS 2 type name (`nav_msgs/msg/Odometry`) or the Foxglove one.
    pub fn type_name(&self) -> String {
        if let Some((_, p, t)) = ROS_TYPES.iter().find(|(k, _, _)| k == self) {
            return format!("{p}/msg/{t}");
        }
        FOXGLOVE_TYPES
            .iter()
            .find(|(k, _)| k == self)
            .map(|(_, t)| format!("foxglove.{t}"))
            .unwrap_or_default()
    }
}
