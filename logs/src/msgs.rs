//! The standard ROS messages a driving log carries, as typed structs that read and write
//! themselves in CDR (and ROS 1 where the log is ROS 1).
//!
//! Field names are the ROS field names, so a message serialises to the same JSON that
//! `mcap-ros2-support` or `rosbags` produce. Each struct lists its fields in declaration
//! order, which is the wire order; [`ros_message!`] turns that list into the reader and
//! writer, so the order is written once.

use serde::{Deserialize, Serialize};

use super::cdr::{Reader, Writer};
use super::error::DecodeError;

type Result<T> = std::result::Result<T, DecodeError>;

/// A value that has a ROS wire form.
pub trait Wire: Sized {
    /// The fewest bytes one value takes (bounds sequence counts before allocating).
    const MIN_BYTES: usize;
    fn read(r: &mut Reader<'_>) -> Result<Self>;
    fn write(&self, w: &mut Writer);
}

macro_rules! wire_primitive {
    ($($t:ident),*) => {$(
        impl Wire for $t {
            const MIN_BYTES: usize = std::mem::size_of::<$t>();
            #[inline]
            fn read(r: &mut Reader<'_>) -> Result<Self> {
                r.$t()
            }
            #[inline]
            fn write(&self, w: &mut Writer) {
                w.$t(*self)
            }
        }
    )*};
}
wire_primitive!(u8, i8, u16, i16, u32, i32, u64, i64, f32, f64);

impl Wire for bool {
    const MIN_BYTES: usize = 1;
    fn read(r: &mut Reader<'_>) -> Result<Self> {
        r.bool()
    }
    fn write(&self, w: &mut Writer) {
        w.bool(*self)
    }
}

impl Wire for String {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self> {
        r.string()
    }
    fn write(&self, w: &mut Writer) {
        w.string(self)
    }
}

impl<T: Wire> Wire for Vec<T> {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self> {
        let n = r.sequence_len(T::MIN_BYTES, "sequence")?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            out.push(T::read(r)?);
        }
        Ok(out)
    }
    fn write(&self, w: &mut Writer) {
        w.sequence_len(self.len());
        for item in self {
            item.write(w);
        }
    }
}

/// A fixed-size `float64[N]` (covariances). Serialises as a JSON array.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Array<const N: usize>(pub [f64; N]);

impl<const N: usize> Default for Array<N> {
    fn default() -> Self {
        Array([0.0; N])
    }
}

impl<const N: usize> Wire for Array<N> {
    const MIN_BYTES: usize = 8 * N;
    fn read(r: &mut Reader<'_>) -> Result<Self> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = r.f64()?;
        }
        Ok(Array(out))
    }
    fn write(&self, w: &mut Writer) {
        for v in &self.0 {
            w.f64(*v);
        }
    }
}

impl<const N: usize> Serialize for Array<N> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.collect_seq(self.0.iter())
    }
}

impl<'de, const N: usize> Deserialize<'de> for Array<N> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let v = Vec::<f64>::deserialize(d)?;
        let len = v.len();
        let a: [f64; N] = v
            .try_into()
            .map_err(|_| serde::de::Error::custom(format!("expected {N} numbers, found {len}")))?;
        Ok(Array(a))
    }
}

/// A `uint8[]` field (image data), read and written in one copy.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Bytes(pub Vec<u8>);

impl Wire for Bytes {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self> {
        Ok(Bytes(r.byte_sequence()?))
    }
    fn write(&self, w: &mut Writer) {
        w.byte_sequence(&self.0)
    }
}

/// Defines a message struct whose fields are read and written in the order listed.
macro_rules! ros_message {
    ($(#[$meta:meta])* $name:ident { $($(#[$fmeta:meta])* $field:ident : $ty:ty),* $(,)? }) => {
        $(#[$meta])*
        #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
        pub struct $name {
            $($(#[$fmeta])* pub $field: $ty,)*
        }

        impl Wire for $name {
            const MIN_BYTES: usize = 0 $(+ <$ty as Wire>::MIN_BYTES)*;
            fn read(r: &mut Reader<'_>) -> Result<Self> {
                // Struct expressions evaluate their fields in the order written: wire order.
                Ok($name { $($field: <$ty as Wire>::read(r)?,)* })
            }
            fn write(&self, w: &mut Writer) {
                $(self.$field.write(w);)*
            }
        }
    };
}

/// `builtin_interfaces/Time` (ROS 1 `time`: two u32).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// Nanoseconds since the epoch (negative before 1970).
    pub fn nanos(&self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }

    /// The time `ns` nanoseconds after the epoch (saturating outside the i32 seconds range).
    pub fn from_nanos(ns: i64) -> Self {
        let sec = ns.div_euclid(1_000_000_000);
        let nanosec = ns.rem_euclid(1_000_000_000) as u32;
        Time {
            sec: sec.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32,
            nanosec,
        }
    }
}

impl Wire for Time {
    const MIN_BYTES: usize = 8;
    fn read(r: &mut Reader<'_>) -> Result<Self> {
        if r.is_ros1() {
            let sec = r.u32()?;
            let nanosec = r.u32()?;
            let sec = i32::try_from(sec).map_err(|_| {
                DecodeError::Invalid(format!("ROS 1 time of {sec} s is past the year 2038"))
            })?;
            Ok(Time { sec, nanosec })
        } else {
            Ok(Time {
                sec: r.i32()?,
                nanosec: r.u32()?,
            })
        }
    }
    fn write(&self, w: &mut Writer) {
        w.i32(self.sec);
        w.u32(self.nanosec);
    }
}

/// `std_msgs/Header`. ROS 1's `seq` is read and dropped, as ROS 2 (and rosbags' conversion)
/// has no such field.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Wire for Header {
    const MIN_BYTES: usize = 12;
    fn read(r: &mut Reader<'_>) -> Result<Self> {
        if r.is_ros1() {
            let _seq = r.u32()?;
        }
        Ok(Header {
            stamp: Time::read(r)?,
            frame_id: r.string()?,
        })
    }
    fn write(&self, w: &mut Writer) {
        self.stamp.write(w);
        w.string(&self.frame_id);
    }
}

ros_message!(
    /// `geometry_msgs/Vector3`.
    Vector3 { x: f64, y: f64, z: f64 }
);
ros_message!(
    /// `geometry_msgs/Point`.
    Point { x: f64, y: f64, z: f64 }
);
ros_message!(
    /// `geometry_msgs/Quaternion`.
    Quaternion { x: f64, y: f64, z: f64, w: f64 }
);
ros_message!(
    /// `geometry_msgs/Pose`.
    Pose { position: Point, orientation: Quaternion }
);
ros_message!(
    /// `geometry_msgs/PoseWithCovariance` (row-major 6×6 over x, y, z, roll, pitch, yaw).
    PoseWithCovariance { pose: Pose, covariance: Array<36> }
);
ros_message!(
    /// `geometry_msgs/Twist`.
    Twist { linear: Vector3, angular: Vector3 }
);
ros_message!(
    /// `geometry_msgs/TwistWithCovariance`.
    TwistWithCovariance { twist: Twist, covariance: Array<36> }
);
ros_message!(
    /// `nav_msgs/Odometry`: pose in `header.frame_id`, twist in `child_frame_id`.
    Odometry {
        header: Header,
        child_frame_id: String,
        pose: PoseWithCovariance,
        twist: TwistWithCovariance,
    }
);
ros_message!(
    /// `geometry_msgs/PoseStamped`.
    PoseStamped { header: Header, pose: Pose }
);
ros_message!(
    /// `geometry_msgs/PoseWithCovarianceStamped`.
    PoseWithCovarianceStamped { header: Header, pose: PoseWithCovariance }
);
ros_message!(
    /// `sensor_msgs/NavSatStatus`.
    NavSatStatus { status: i8, service: u16 }
);
ros_message!(
    /// `sensor_msgs/NavSatFix`: WGS84 degrees and metres above the ellipsoid.
    NavSatFix {
        header: Header,
        status: NavSatStatus,
        latitude: f64,
        longitude: f64,
        altitude: f64,
        position_covariance: Array<9>,
        position_covariance_type: u8,
    }
);
ros_message!(
    /// `sensor_msgs/Imu`.
    Imu {
        header: Header,
        orientation: Quaternion,
        orientation_covariance: Array<9>,
        angular_velocity: Vector3,
        angular_velocity_covariance: Array<9>,
        linear_acceleration: Vector3,
        linear_acceleration_covariance: Array<9>,
    }
);
ros_message!(
    /// `geometry_msgs/Transform`.
    Transform { translation: Vector3, rotation: Quaternion }
);
ros_message!(
    /// `geometry_msgs/TransformStamped`.
    TransformStamped { header: Header, child_frame_id: String, transform: Transform }
);
ros_message!(
    /// `tf2_msgs/TFMessage`.
    TfMessage { transforms: Vec<TransformStamped> }
);
ros_message!(
    /// `vision_msgs/ObjectHypothesis` (vision_msgs 4, ROS 2 Humble and later).
    ObjectHypothesis { class_id: String, score: f64 }
);
ros_message!(
    /// `vision_msgs/ObjectHypothesisWithPose`.
    ObjectHypothesisWithPose { hypothesis: ObjectHypothesis, pose: PoseWithCovariance }
);
ros_message!(
    /// `vision_msgs/BoundingBox3D`: centre pose and full extents (x length, y width, z height).
    BoundingBox3D { center: Pose, size: Vector3 }
);
ros_message!(
    /// `vision_msgs/Detection3D` (vision_msgs 4: `id` is the tracking id).
    Detection3D {
        header: Header,
        results: Vec<ObjectHypothesisWithPose>,
        bbox: BoundingBox3D,
        id: String,
    }
);
ros_message!(
    /// `vision_msgs/Detection3DArray`.
    Detection3DArray { header: Header, detections: Vec<Detection3D> }
);
ros_message!(
    /// `sensor_msgs/Image`.
    Image {
        header: Header,
        height: u32,
        width: u32,
        encoding: String,
        is_bigendian: u8,
        step: u32,
        data: Bytes,
    }
);
ros_message!(
    /// `sensor_msgs/CompressedImage` (`format`: jpeg, png, ...).
    CompressedImage { header: Header, format: String, data: Bytes }
);
ros_message!(
    /// `diagnostic_msgs/KeyValue`.
    KeyValue { key: String, value: String }
);
ros_message!(
    /// `diagnostic_msgs/DiagnosticStatus`.
    DiagnosticStatus {
        level: u8,
        name: String,
        message: String,
        hardware_id: String,
        values: Vec<KeyValue>,
    }
);
ros_message!(
    /// `diagnostic_msgs/DiagnosticArray`.
    DiagnosticArray { header: Header, status: Vec<DiagnosticStatus> }
);

impl Quaternion {
    /// The rotation about z by `yaw` radians.
    pub fn from_yaw(yaw: f64) -> Self {
        let (s, c) = (yaw / 2.0).sin_cos();
        Quaternion {
            x: 0.0,
            y: 0.0,
            z: s,
            w: c,
        }
    }

    /// Heading about z (radians, counter-clockwise from +x) of this rotation.
    pub fn yaw(&self) -> f64 {
        let Quaternion { x, y, z, w } = *self;
        (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
    }
}

/// Decodes one payload of a message type.
///
/// The message must fill the payload: CDR writers pad the end to 4 bytes at most, ROS 1 has
/// no padding. More bytes left over mean the payload is not this type, or a length field
/// inside it is corrupt (a string length of 0 still parses, and would otherwise yield a
/// silently wrong message).
pub fn decode<T: Wire>(payload: &[u8], format: super::cdr::WireFormat) -> Result<T> {
    let mut r = Reader::new(payload, format)?;
    let message = T::read(&mut r)?;
    let allowed_padding = match format {
        super::cdr::WireFormat::Ros1 => 0,
        super::cdr::WireFormat::Cdr => 3,
    };
    if r.remaining() > allowed_padding {
        return Err(DecodeError::Invalid(format!(
            "{} bytes left after the message (at most {allowed_padding} of padding expected)",
            r.remaining()
        )));
    }
    Ok(message)
}

/// Encodes one message as little-endian CDR.
pub fn encode<T: Wire>(message: &T) -> Vec<u8> {
    let mut w = Writer::new();
    message.write(&mut w);
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::super::cdr::WireFormat;
    use super::*;
    use proptest::prelude::*;

    fn header(sec: i32, nanosec: u32, frame: &str) -> Header {
        Header {
            stamp: Time { sec, nanosec },
            frame_id: frame.to_owned(),
        }
    }

    #[test]
    fn odometry_layout_matches_ros2() -> Result<()> {
        let odom = Odometry {
            header: header(1, 2, "odom"),
            child_frame_id: "base_link".into(),
            ..Default::default()
        };
        let bytes = encode(&odom);
        // After the 4-byte header: stamp 8, "odom" 4+5 -> 17, "base_link" at 20: 4+10 -> 34,
        // pose at 40: 7*8 + 36*8 -> 384, twist 6*8 + 36*8 -> 720.
        assert_eq!(bytes.len(), 4 + 720);
        assert_eq!(decode::<Odometry>(&bytes, WireFormat::Cdr)?, odom);
        Ok(())
    }

    #[test]
    fn yaw_round_trips() {
        for yaw in [-3.0, -1.0, 0.0, 0.5, 3.1] {
            assert!((Quaternion::from_yaw(yaw).yaw() - yaw).abs() < 1e-12);
        }
    }

    #[test]
    fn time_from_nanos() {
        let t = Time::from_nanos(1_432_235_498_025_043_042);
        assert_eq!((t.sec, t.nanosec), (1_432_235_498, 25_043_042));
        assert_eq!(t.nanos(), 1_432_235_498_025_043_042);
        assert_eq!(Time::from_nanos(-1).nanos(), -1);
    }

    fn arb_string() -> impl Strategy<Value = String> {
        "[a-z_/0-9]{0,12}"
    }

    prop_compose! {
        fn arb_detection()(id in arb_string(), class_id in arb_string(), score in -1e3..1e3f64,
                           x in -1e4..1e4f64, size in 0.0..20.0f64, sec in any::<i32>(),
                           nanosec in 0..1_000_000_000u32, n in 0usize..3) -> Detection3D {
            Detection3D {
                header: header(sec, nanosec, "map"),
                results: vec![ObjectHypothesisWithPose {
                    hypothesis: ObjectHypothesis { class_id, score },
                    pose: PoseWithCovariance::default(),
                }; n],
                bbox: BoundingBox3D {
                    center: Pose { position: Point { x, y: -x, z: 0.5 }, orientation: Quaternion::from_yaw(x) },
                    size: Vector3 { x: size, y: size / 2.0, z: 1.5 },
                },
                id,
            }
        }
    }

    proptest! {
        #[test]
        fn detections_round_trip(dets in proptest::collection::vec(arb_detection(), 0..5),
                                 frame in arb_string()) {
            let msg = Detection3DArray { header: header(3, 4, &frame), detections: dets };
            let bytes = encode(&msg);
            prop_assert_eq!(decode::<Detection3DArray>(&bytes, WireFormat::Cdr).ok(), Some(msg));
        }

        #[test]
        fn every_truncation_is_an_error_not_a_panic(cut in 0usize..720) {
            let odom = Odometry { header: header(1, 2, "odom"), ..Default::default() };
            let bytes = encode(&odom);
            let cut = cut.min(bytes.len() - 1);
            prop_assert!(decode::<Odometry>(&bytes[..cut], WireFormat::Cdr).is_err());
        }

        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            let _ = decode::<Detection3DArray>(&bytes, WireFormat::Cdr);
            let _ = decode::<TfMessage>(&bytes, WireFormat::Ros1);
            let _ = decode::<DiagnosticArray>(&bytes, WireFormat::Cdr);
        }
    }
}
