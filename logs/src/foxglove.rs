//! Foxglove's well-known schemas in MCAP, in their protobuf and JSON encodings: LocationFix,
//! FrameTransform(s), PoseInFrame, CompressedImage and SceneUpdate (entities with their cube
//! primitives, the form other road users take; other primitives are counted).
//!
//! Protobuf is read with a small wire-format reader that knows these messages' field numbers
//! (from foxglove-sdk's `schemas/proto/foxglove/*.proto`); unknown fields are skipped as
//! protobuf requires. Every length is checked against the bytes left.

use serde::{Deserialize, Serialize};

use super::error::DecodeError;
use super::msgs::{Bytes, Point, Pose, Quaternion, Vector3};
use crate::kind::MessageKind;

type Result<T> = std::result::Result<T, DecodeError>;

/// `google.protobuf.Timestamp`, as Foxglove's JSON writes it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct Timestamp {
    pub sec: i64,
    pub nsec: u32,
}

impl Timestamp {
    pub fn nanos(&self) -> i64 {
        self.sec
            .saturating_mul(1_000_000_000)
            .saturating_add(i64::from(self.nsec))
    }
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LocationFix {
    pub timestamp: Timestamp,
    pub frame_id: String,
    pub latitude: f64,
    pub longitude: f64,
    pub altitude: f64,
    pub position_covariance: Vec<f64>,
    pub position_covariance_type: i32,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FrameTransform {
    pub timestamp: Timestamp,
    pub parent_frame_id: String,
    pub child_frame_id: String,
    pub translation: Vector3,
    pub rotation: Quaternion,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PoseInFrame {
    pub timestamp: Timestamp,
    pub frame_id: String,
    pub pose: Pose,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FoxgloveCompressedImage {
    pub timestamp: Timestamp,
    pub frame_id: String,
    #[serde(deserialize_with = "base64_bytes")]
    pub data: Bytes,
    pub format: String,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CubePrimitive {
    pub pose: Pose,
    pub size: Vector3,
}

/// A scene entity: an object with an id in a frame, drawn by primitives.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SceneEntity {
    pub timestamp: Timestamp,
    pub frame_id: String,
    pub id: String,
    pub cubes: Vec<CubePrimitive>,
    /// Arrows, spheres, lines, texts... (not decoded).
    #[serde(skip_deserializing)]
    pub other_primitives: u32,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SceneEntityDeletion {
    pub timestamp: Timestamp,
    /// 0: the entity with `id`; 1: all entities.
    #[serde(rename = "type")]
    pub kind: i32,
    pub id: String,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SceneUpdate {
    pub deletions: Vec<SceneEntityDeletion>,
    pub entities: Vec<SceneEntity>,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FrameTransforms {
    pub transforms: Vec<FrameTransform>,
}

/// A decoded Foxglove message.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum FoxgloveMessage {
    LocationFix(LocationFix),
    FrameTransform(FrameTransform),
    FrameTransforms(FrameTransforms),
    PoseInFrame(PoseInFrame),
    CompressedImage(FoxgloveCompressedImage),
    SceneUpdate(SceneUpdate),
}

fn base64_bytes<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Bytes, D::Error> {
    use base64::Engine as _;
    let text = String::deserialize(d)?;
    base64::engine::general_purpose::STANDARD
        .decode(text.as_bytes())
        .map(Bytes)
        .map_err(serde::de::Error::custom)
}

/// Decodes a JSON-encoded Foxglove message.
pub fn decode_json(kind: MessageKind, payload: &[u8]) -> Result<FoxgloveMessage> {
    fn j<T: for<'de> Deserialize<'de>>(payload: &[u8]) -> Result<T> {
        serde_json::from_slice(payload).map_err(|e| DecodeError::Invalid(format!("JSON: {e}")))
    }
    let message = match kind {
        MessageKind::FoxgloveLocationFix => FoxgloveMessage::LocationFix(j(payload)?),
        MessageKind::FoxgloveFrameTransform => FoxgloveMessage::FrameTransform(j(payload)?),
        MessageKind::FoxgloveFrameTransforms => FoxgloveMessage::FrameTransforms(j(payload)?),
        MessageKind::FoxglovePoseInFrame => FoxgloveMessage::PoseInFrame(j(payload)?),
        MessageKind::FoxgloveCompressedImage => FoxgloveMessage::CompressedImage(j(payload)?),
        MessageKind::FoxgloveSceneUpdate => FoxgloveMessage::SceneUpdate(j(payload)?),
        other => return Err(DecodeError::Unsupported(format!("{other:?} as JSON"))),
    };
    Ok(message)
}

/// Decodes a protobuf-encoded Foxglove message.
pub fn decode_protobuf(kind: MessageKind, payload: &[u8]) -> Result<FoxgloveMessage> {
    let message = match kind {
        MessageKind::FoxgloveLocationFix => FoxgloveMessage::LocationFix(location_fix(payload)?),
        MessageKind::FoxgloveFrameTransform => {
            FoxgloveMessage::FrameTransform(frame_transform(payload)?)
        }
        MessageKind::FoxgloveFrameTransforms => {
            let mut out = FrameTransforms::default();
            for field in Fields::new(payload) {
                if let (1, Value::Len(b)) = field? {
                    out.transforms.push(frame_transform(b)?);
                }
            }
            FoxgloveMessage::FrameTransforms(out)
        }
        MessageKind::FoxglovePoseInFrame => FoxgloveMessage::PoseInFrame(pose_in_frame(payload)?),
        MessageKind::FoxgloveCompressedImage => {
            FoxgloveMessage::CompressedImage(compressed_image(payload)?)
        }
        MessageKind::FoxgloveSceneUpdate => FoxgloveMessage::SceneUpdate(scene_update(payload)?),
        other => return Err(DecodeError::Unsupported(format!("{other:?} as protobuf"))),
    };
    Ok(message)
}

/// One protobuf field value.
#[derive(Debug, Clone, Copy)]
enum Value<'a> {
    Varint(u64),
    Fixed64(u64),
    /// A fixed32 (float, fixed32, sfixed32): none of the decoded fields are one.
    Fixed32,
    Len(&'a [u8]),
}

impl Value<'_> {
    fn f64(self) -> Result<f64> {
        match self {
            Value::Fixed64(bits) => Ok(f64::from_bits(bits)),
            _ => Err(DecodeError::Invalid("expected a double".into())),
        }
    }
    fn varint(self) -> Result<u64> {
        match self {
            Value::Varint(v) => Ok(v),
            _ => Err(DecodeError::Invalid("expected a varint".into())),
        }
    }
}

/// Iterates the `(field number, value)` pairs of one protobuf message.
struct Fields<'a> {
    buf: &'a [u8],
    pos: usize,
    failed: bool,
}

impl<'a> Fields<'a> {
    fn new(buf: &'a [u8]) -> Self {
        Fields {
            buf,
            pos: 0,
            failed: false,
        }
    }

    fn varint(&mut self) -> Result<u64> {
        let mut value = 0u64;
        for shift in (0..64).step_by(7) {
            let Some(&byte) = self.buf.get(self.pos) else {
                return Err(DecodeError::Truncated {
                    what: "protobuf varint",
                    at: self.pos,
                    len: self.buf.len(),
                });
            };
            self.pos += 1;
            value |= u64::from(byte & 0x7f) << shift;
            if byte & 0x80 == 0 {
                return Ok(value);
            }
        }
        Err(DecodeError::Invalid(
            "protobuf varint longer than 10 bytes".into(),
        ))
    }

    fn take(&mut self, n: u64, what: &'static str) -> Result<&'a [u8]> {
        let left = self.buf.len() - self.pos;
        if n > left as u64 {
            return Err(DecodeError::LengthTooLarge {
                what,
                count: n,
                at: self.pos,
                remaining: left,
            });
        }
        let out = &self.buf[self.pos..self.pos + n as usize];
        self.pos += n as usize;
        Ok(out)
    }

    fn field(&mut self) -> Result<(u32, Value<'a>)> {
        let key = self.varint()?;
        let number = u32::try_from(key >> 3)
            .map_err(|_| DecodeError::Invalid("protobuf field number too large".into()))?;
        let value = match key & 7 {
            0 => Value::Varint(self.varint()?),
            1 => {
                let b = self.take(8, "protobuf fixed64")?;
                Value::Fixed64(u64::from_le_bytes(b.try_into().unwrap_or_default()))
            }
            2 => {
                let n = self.varint()?;
                Value::Len(self.take(n, "protobuf length-delimited field")?)
            }
            5 => {
                self.take(4, "protobuf fixed32")?;
                Value::Fixed32
            }
            w => {
                return Err(DecodeError::Invalid(format!(
                    "protobuf wire type {w} (groups are not supported)"
                )));
            }
        };
        Ok((number, value))
    }
}

impl<'a> Iterator for Fields<'a> {
    type Item = Result<(u32, Value<'a>)>;
    fn next(&mut self) -> Option<Self::Item> {
        if self.failed || self.pos >= self.buf.len() {
            return None;
        }
        let item = self.field();
        self.failed = item.is_err();
        Some(item)
    }
}

fn len_bytes<'a>(v: Value<'a>) -> Result<&'a [u8]> {
    match v {
        Value::Len(b) => Ok(b),
        _ => Err(DecodeError::Invalid(
            "expected a length-delimited field".into(),
        )),
    }
}

fn string(v: Value<'_>) -> Result<String> {
    String::from_utf8(len_bytes(v)?.to_vec())
        .map_err(|_| DecodeError::Invalid("protobuf string is not UTF-8".into()))
}

fn timestamp(b: &[u8]) -> Result<Timestamp> {
    let mut t = Timestamp::default();
    for field in Fields::new(b) {
        match field? {
            (1, v) => t.sec = v.varint()? as i64,
            (2, v) => t.nsec = v.varint()? as u32,
            _ => {}
        }
    }
    Ok(t)
}

fn vector3(b: &[u8]) -> Result<Vector3> {
    let mut v = Vector3::default();
    for field in Fields::new(b) {
        match field? {
            (1, x) => v.x = x.f64()?,
            (2, y) => v.y = y.f64()?,
            (3, z) => v.z = z.f64()?,
            _ => {}
        }
    }
    Ok(v)
}

fn quaternion(b: &[u8]) -> Result<Quaternion> {
    let mut q = Quaternion::default();
    for field in Fields::new(b) {
        match field? {
            (1, v) => q.x = v.f64()?,
            (2, v) => q.y = v.f64()?,
            (3, v) => q.z = v.f64()?,
            (4, v) => q.w = v.f64()?,
            _ => {}
        }
    }
    Ok(q)
}

fn pose(b: &[u8]) -> Result<Pose> {
    let mut p = Pose::default();
    for field in Fields::new(b) {
        match field? {
            (1, v) => {
                let v = vector3(len_bytes(v)?)?;
                p.position = Point {
                    x: v.x,
                    y: v.y,
                    z: v.z,
                };
            }
            (2, v) => p.orientation = quaternion(len_bytes(v)?)?,
            _ => {}
        }
    }
    Ok(p)
}

/// A `repeated double`, packed (one length-delimited run) or not (one fixed64 per value).
fn push_doubles(out: &mut Vec<f64>, v: Value<'_>) -> Result<()> {
    match v {
        Value::Fixed64(bits) => out.push(f64::from_bits(bits)),
        Value::Len(b) => {
            if b.len() % 8 != 0 {
                return Err(DecodeError::Invalid(
                    "packed doubles not a multiple of 8 bytes".into(),
                ));
            }
            out.extend(
                b.chunks_exact(8)
                    .map(|c| f64::from_le_bytes(c.try_into().unwrap_or_default())),
            );
        }
        _ => return Err(DecodeError::Invalid("expected doubles".into())),
    }
    Ok(())
}

fn location_fix(b: &[u8]) -> Result<LocationFix> {
    let mut m = LocationFix::default();
    for field in Fields::new(b) {
        match field? {
            (6, v) => m.timestamp = timestamp(len_bytes(v)?)?,
            (7, v) => m.frame_id = string(v)?,
            (1, v) => m.latitude = v.f64()?,
            (2, v) => m.longitude = v.f64()?,
            (3, v) => m.altitude = v.f64()?,
            (4, v) => push_doubles(&mut m.position_covariance, v)?,
            (5, v) => m.position_covariance_type = v.varint()? as i32,
            _ => {}
        }
    }
    Ok(m)
}

fn frame_transform(b: &[u8]) -> Result<FrameTransform> {
    let mut m = FrameTransform::default();
    for field in Fields::new(b) {
        match field? {
            (1, v) => m.timestamp = timestamp(len_bytes(v)?)?,
            (2, v) => m.parent_frame_id = string(v)?,
            (3, v) => m.child_frame_id = string(v)?,
            (4, v) => m.translation = vector3(len_bytes(v)?)?,
            (5, v) => m.rotation = quaternion(len_bytes(v)?)?,
            _ => {}
        }
    }
    Ok(m)
}

fn pose_in_frame(b: &[u8]) -> Result<PoseInFrame> {
    let mut m = PoseInFrame::default();
    for field in Fields::new(b) {
        match field? {
            (1, v) => m.timestamp = timestamp(len_bytes(v)?)?,
            (2, v) => m.frame_id = string(v)?,
            (3, v) => m.pose = pose(len_bytes(v)?)?,
            _ => {}
        }
    }
    Ok(m)
}

fn compressed_image(b: &[u8]) -> Result<FoxgloveCompressedImage> {
    let mut m = FoxgloveCompressedImage::default();
    for field in Fields::new(b) {
        match field? {
            (1, v) => m.timestamp = timestamp(len_bytes(v)?)?,
            (4, v) => m.frame_id = string(v)?,
            (2, v) => m.data = Bytes(len_bytes(v)?.to_vec()),
            (3, v) => m.format = string(v)?,
            _ => {}
        }
    }
    Ok(m)
}

fn scene_entity(b: &[u8]) -> Result<SceneEntity> {
    let mut m = SceneEntity::default();
    for field in Fields::new(b) {
        match field? {
            (1, v) => m.timestamp = timestamp(len_bytes(v)?)?,
            (2, v) => m.frame_id = string(v)?,
            (3, v) => m.id = string(v)?,
            (8, v) => {
                let mut cube = CubePrimitive::default();
                for f in Fields::new(len_bytes(v)?) {
                    match f? {
                        (1, v) => cube.pose = pose(len_bytes(v)?)?,
                        (2, v) => cube.size = vector3(len_bytes(v)?)?,
                        _ => {}
                    }
                }
                m.cubes.push(cube);
            }
            (7 | 9..=14, _) => m.other_primitives += 1,
            _ => {}
        }
    }
    Ok(m)
}

fn scene_update(b: &[u8]) -> Result<SceneUpdate> {
    let mut m = SceneUpdate::default();
    for field in Fields::new(b) {
        match field? {
            (1, v) => {
                let mut d = SceneEntityDeletion::default();
                for f in Fields::new(len_bytes(v)?) {
                    match f? {
                        (1, v) => d.timestamp = timestamp(len_bytes(v)?)?,
                        (2, v) => d.kind = v.varint()? as i32,
                        (3, v) => d.id = string(v)?,
                        _ => {}
                    }
                }
                m.deletions.push(d);
            }
            (2, v) => m.entities.push(scene_entity(len_bytes(v)?)?),
            _ => {}
        }
    }
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A protobuf writer for tests only: key, then value.
    fn key(out: &mut Vec<u8>, number: u32, wire: u8) {
        varint(out, (u64::from(number) << 3) | u64::from(wire));
    }
    fn varint(out: &mut Vec<u8>, mut v: u64) {
        while v >= 0x80 {
            out.push((v as u8) | 0x80);
            v >>= 7;
        }
        out.push(v as u8);
    }
    fn double(out: &mut Vec<u8>, number: u32, v: f64) {
        key(out, number, 1);
        out.extend_from_slice(&v.to_le_bytes());
    }
    fn bytes(out: &mut Vec<u8>, number: u32, b: &[u8]) {
        key(out, number, 2);
        varint(out, b.len() as u64);
        out.extend_from_slice(b);
    }

    #[test]
    fn location_fix_from_protobuf() -> Result<()> {
        let mut ts = Vec::new();
        key(&mut ts, 1, 0);
        varint(&mut ts, 1_700_000_000);
        key(&mut ts, 2, 0);
        varint(&mut ts, 5);
        let mut msg = Vec::new();
        bytes(&mut msg, 6, &ts);
        bytes(&mut msg, 7, b"gps");
        double(&mut msg, 1, 42.5);
        double(&mut msg, 2, -71.25);
        double(&mut msg, 3, 7.0);
        let cov: Vec<u8> = (0..9).flat_map(|i| f64::from(i).to_le_bytes()).collect();
        bytes(&mut msg, 4, &cov);
        key(&mut msg, 5, 0);
        varint(&mut msg, 2);
        bytes(&mut msg, 99, b"unknown field, skipped");
        let FoxgloveMessage::LocationFix(fix) =
            decode_protobuf(MessageKind::FoxgloveLocationFix, &msg)?
        else {
            panic!("not a location fix")
        };
        assert_eq!(
            fix.timestamp,
            Timestamp {
                sec: 1_700_000_000,
                nsec: 5
            }
        );
        assert_eq!(
            (fix.latitude, fix.longitude, fix.altitude),
            (42.5, -71.25, 7.0)
        );
        assert_eq!(fix.position_covariance.len(), 9);
        assert_eq!(fix.position_covariance_type, 2);
        assert_eq!(fix.frame_id, "gps");
        Ok(())
    }

    #[test]
    fn scene_update_cubes_from_protobuf_and_json() -> Result<()> {
        let mut position = Vec::new();
        double(&mut position, 1, 10.0);
        double(&mut position, 2, 20.0);
        let mut p = Vec::new();
        bytes(&mut p, 1, &position);
        let mut size = Vec::new();
        double(&mut size, 1, 4.5);
        double(&mut size, 2, 1.8);
        let mut cube = Vec::new();
        bytes(&mut cube, 1, &p);
        bytes(&mut cube, 2, &size);
        let mut entity = Vec::new();
        bytes(&mut entity, 2, b"map");
        bytes(&mut entity, 3, b"car-7");
        bytes(&mut entity, 8, &cube);
        bytes(&mut entity, 13, b"");
        let mut update = Vec::new();
        bytes(&mut update, 2, &entity);
        let FoxgloveMessage::SceneUpdate(u) =
            decode_protobuf(MessageKind::FoxgloveSceneUpdate, &update)?
        else {
            panic!("not a scene update")
        };
        assert_eq!(u.entities.len(), 1);
        let e = &u.entities[0];
        assert_eq!(
            (e.id.as_str(), e.frame_id.as_str(), e.other_primitives),
            ("car-7", "map", 1)
        );
        assert_eq!(e.cubes[0].pose.position.x, 10.0);
        assert_eq!(e.cubes[0].size.y, 1.8);

        let json = br#"{"deletions":[],"entities":[{"timestamp":{"sec":1,"nsec":2},"frame_id":"map","id":"car-7",
            "cubes":[{"pose":{"position":{"x":10,"y":20,"z":0},"orientation":{"x":0,"y":0,"z":0,"w":1}},
            "size":{"x":4.5,"y":1.8,"z":1.5},"color":{"r":1,"g":0,"b":0,"a":1}}],"texts":[]}]}"#;
        let FoxgloveMessage::SceneUpdate(j) = decode_json(MessageKind::FoxgloveSceneUpdate, json)?
        else {
            panic!("not a scene update")
        };
        assert_eq!(j.entities[0].cubes[0].size.x, 4.5);
        Ok(())
    }

    #[test]
    fn json_image_data_is_base64() -> Result<()> {
        let json = br#"{"timestamp":{"sec":3,"nsec":0},"frame_id":"cam","data":"AAEC/w==","format":"jpeg"}"#;
        let FoxgloveMessage::CompressedImage(img) =
            decode_json(MessageKind::FoxgloveCompressedImage, json)?
        else {
            panic!("not an image")
        };
        assert_eq!(img.data.0, vec![0, 1, 2, 255]);
        Ok(())
    }

    #[test]
    fn broken_protobuf_is_an_error() {
        // A length field promising 100 bytes with 2 left.
        let msg = [0x3a, 100, b'a', b'b'];
        assert!(decode_protobuf(MessageKind::FoxgloveLocationFix, &msg).is_err());
        // Wire type 3 (group start).
        assert!(decode_protobuf(MessageKind::FoxgloveLocationFix, &[0x0b]).is_err());
        // An unterminated varint.
        assert!(decode_protobuf(MessageKind::FoxgloveLocationFix, &[0x08, 0xff]).is_err());
    }
}
