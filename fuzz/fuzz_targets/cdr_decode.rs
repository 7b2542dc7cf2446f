//! Bytes -> every message decoder: each supported ROS type as CDR and as ROS 1, each Foxglove
//! type as protobuf and as JSON, through the same `Codec` that the log readers use.
//!
//! Besides "no panic": whatever decodes must survive a round trip. The message is encoded as
//! CDR, decoded again, and encoded again; both encodings must be byte-identical (compared as
//! bytes so NaN payloads compare too).

#![no_main]

use logs::cdr::WireFormat;
use logs::msgs::{self, Wire};
use logs::{Codec, MessageKind};
use libfuzzer_sys::fuzz_target;

const FOXGLOVE: [MessageKind; 6] = [
    MessageKind::FoxgloveLocationFix,
    MessageKind::FoxgloveFrameTransform,
    MessageKind::FoxgloveFrameTransforms,
    MessageKind::FoxglovePoseInFrame,
    MessageKind::FoxgloveCompressedImage,
    MessageKind::FoxgloveSceneUpdate,
];

/// Decodes `data` as `T` in both wire formats through `Codec` (which must agree with the
/// typed decoder) and checks the CDR round trip of what decodes.
fn ros<T: Wire>(kind: MessageKind, data: &[u8]) {
    for format in [WireFormat::Cdr, WireFormat::Ros1] {
        let typed = msgs::decode::<T>(data, format);
        let via_codec = Codec::Ros { kind, format }.decode(data);
        assert_eq!(typed.is_ok(), via_codec.is_ok(), "{kind:?} {format:?}");
        if let Ok(message) = typed {
            let bytes = msgs::encode(&message);
            let again = msgs::decode::<T>(&bytes, WireFormat::Cdr)
                .unwrap_or_else(|e| panic!("{kind:?}: re-encoded message does not decode: {e}"));
            assert!(
                msgs::encode(&again) == bytes,
                "{kind:?}: encode(decode(encode(m))) differs from encode(m)"
            );
        }
    }
}

fuzz_target!(|data: &[u8]| {
    ros::<msgs::Odometry>(MessageKind::Odometry, data);
    ros::<msgs::PoseStamped>(MessageKind::PoseStamped, data);
    ros::<msgs::PoseWithCovarianceStamped>(MessageKind::PoseWithCovarianceStamped, data);
    ros::<msgs::NavSatFix>(MessageKind::NavSatFix, data);
    ros::<msgs::Imu>(MessageKind::Imu, data);
    ros::<msgs::TfMessage>(MessageKind::TfMessage, data);
    ros::<msgs::Detection3DArray>(MessageKind::Detection3DArray, data);
    ros::<msgs::Image>(MessageKind::Image, data);
    ros::<msgs::CompressedImage>(MessageKind::CompressedImage, data);
    ros::<msgs::DiagnosticArray>(MessageKind::DiagnosticArray, data);
    for kind in FOXGLOVE {
        let _ = Codec::FoxgloveProtobuf(kind).decode(data);
        let _ = Codec::FoxgloveJson(kind).decode(data);
    }
});
