//! ROS 2 message definitions (`ros2msg` schema text) for the types we write: each type's own
//! fields once, and the full schema assembled as ROS 2 tools do — the root definition, then a
//! `MSG: pkg/Type` section for every nested type, depth first, each once.

/// (type, its fields) for every type the writers need, fully qualified.
const DEFINITIONS: [(&str, &str); 19] = [
    ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec"),
    (
        "std_msgs/Header",
        "builtin_interfaces/Time stamp\nstring frame_id",
    ),
    ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z"),
    ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z"),
    (
        "geometry_msgs/Quaternion",
        "float64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    ),
    (
        "geometry_msgs/Pose",
        "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    ),
    (
        "geometry_msgs/PoseWithCovariance",
        "geometry_msgs/Pose pose\nfloat64[36] covariance",
    ),
    (
        "geometry_msgs/Twist",
        "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    ),
    (
        "geometry_msgs/TwistWithCovariance",
        "geometry_msgs/Twist twist\nfloat64[36] covariance",
    ),
    (
        "nav_msgs/Odometry",
        "std_msgs/Header header\nstring child_frame_id\n\
         geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist",
    ),
    ("sensor_msgs/NavSatStatus", "int8 status\nuint16 service"),
    (
        "sensor_msgs/NavSatFix",
        "std_msgs/Header header\nsensor_msgs/NavSatStatus status\nfloat64 latitude\n\
         float64 longitude\nfloat64 altitude\nfloat64[9] position_covariance\n\
         uint8 position_covariance_type",
    ),
    (
        "vision_msgs/ObjectHypothesis",
        "string class_id\nfloat64 score",
    ),
    (
        "vision_msgs/ObjectHypothesisWithPose",
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose",
    ),
    (
        "vision_msgs/BoundingBox3D",
        "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size",
    ),
    (
        "vision_msgs/Detection3D",
        "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n\
         vision_msgs/BoundingBox3D bbox\nstring id",
    ),
    (
        "vision_msgs/Detection3DArray",
        "std_msgs/Header header\nvision_msgs/Detection3D[] detections",
    ),
    (
        "geometry_msgs/Transform",
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation",
    ),
    (
        "geometry_msgs/TransformStamped",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform",
    ),
];

const SEPARATOR: &str =
    "================================================================================";

fn fields(ty: &str) -> Option<&'static str> {
    DEFINITIONS.iter().find(|(t, _)| *t == ty).map(|(_, f)| *f)
}

/// The nested (non-primitive) types a definition uses, in field order.
fn nested(fields: &str) -> impl DoubleEndedIterator<Item = &str> {
    fields.lines().filter_map(|line| {
        let ty = line.split_whitespace().next()?;
        let ty = ty.split('[').next()?;
        ty.contains('/').then_some(ty)
    })
}

/// The `ros2msg` schema of `ty` (`pkg/msg/Type` or `pkg/Type`), or `None` for a type not in
/// the table.
pub fn ros2msg_schema(ty: &str) -> Option<String> {
    let short = ty.replacen("/msg/", "/", 1);
    let mut text = fields(&short)?.to_owned();
    let mut done = vec![short.clone()];
    let mut stack: Vec<String> = nested(fields(&short)?).rev().map(str::to_owned).collect();
    while let Some(t) = stack.pop() {
        if done.contains(&t) {
            continue;
        }
        let f = fields(&t)?;
        text.push_str(&format!("\n{SEPARATOR}\nMSG: {t}\n{f}"));
        stack.extend(nested(f).rev().map(str::to_owned));
        done.push(t);
    }
    text.push('\n');
    Some(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_nested_type_is_defined_once() {
        for (ty, _) in DEFINITIONS {
            let text = ros2msg_schema(ty).unwrap_or_default();
            assert!(!text.is_empty(), "{ty}");
            for (other, _) in DEFINITIONS {
                assert!(text.matches(&format!("MSG: {other}\n")).count() <= 1);
            }
        }
        let odom = ros2msg_schema("nav_msgs/msg/Odometry").unwrap_or_default();
        assert!(odom.starts_with("std_msgs/Header header\n"));
        for t in [
            "std_msgs/Header",
            "builtin_interfaces/Time",
            "geometry_msgs/Twist",
        ] {
            assert!(odom.contains(&format!("MSG: {t}\n")), "{t}");
        }
        assert_eq!(ros2msg_schema("std_msgs/msg/String"), None);
    }
}
