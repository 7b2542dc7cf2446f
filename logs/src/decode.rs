//! From raw payloads to typed messages: which decoder a topic needs (its type name and
//! encoding), and whole-log decoding into a time-ordered stream.

use std::collections::BTreeMap;
use std::ops::ControlFlow;

use serde::Serialize;

use super::cdr::WireFormat;
use super::error::{DecodeError, LogResult};
use super::foxglove;
use super::msgs::{self, Wire};
use super::source::{Log, RawMessage, ReadOptions, ReadReport, Topic};

pub use crate::kind::MessageKind;

/// How a topic's payloads are decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Codec {
    Ros {
        kind: MessageKind,
        format: WireFormat,
    },
    FoxgloveProtobuf(MessageKind),
    FoxgloveJson(MessageKind),
}

impl Codec {
    /// The decoder for `topic`, or why there is none.
    pub fn for_topic(topic: &Topic) -> Result<Self, String> {
        let unsupported = || {
            format!(
                "{} in {} encoding",
                topic.type_name,
                display_encoding(&topic.encoding)
            )
        };
        match topic.encoding.as_str() {
            "cdr" | "ros1" => {
                let kind = MessageKind::from_ros_name(&topic.type_name).ok_or_else(unsupported)?;
                if kind == MessageKind::Detection3DArray && schema_mentions(topic, "source_cloud") {
                    return Err(format!(
                        "{} from vision_msgs before version 4 (with source_cloud)",
                        topic.type_name
                    ));
                }
                let format = if topic.encoding == "cdr" {
                    WireFormat::Cdr
                } else {
                    WireFormat::Ros1
                };
                Ok(Codec::Ros { kind, format })
            }
            "protobuf" => MessageKind::from_foxglove_name(&topic.type_name)
                .map(Codec::FoxgloveProtobuf)
                .ok_or_else(unsupported),
            "json" => MessageKind::from_foxglove_name(&topic.type_name)
                .map(Codec::FoxgloveJson)
                .ok_or_else(unsupported),
            _ => Err(unsupported()),
        }
    }

    pub fn kind(&self) -> MessageKind {
        match *self {
            Codec::Ros { kind, .. } | Codec::FoxgloveProtobuf(kind) | Codec::FoxgloveJson(kind) => {
                kind
            }
        }
    }

    /// Decodes one payload.
    pub fn decode(&self, payload: &[u8]) -> Result<Decoded, DecodeError> {
        match *self {
            Codec::Ros { kind, format } => decode_ros(kind, format, payload),
            Codec::FoxgloveProtobuf(kind) => {
                foxglove::decode_protobuf(kind, payload).map(Decoded::Foxglove)
            }
            Codec::FoxgloveJson(kind) => {
                foxglove::decode_json(kind, payload).map(Decoded::Foxglove)
            }
        }
    }
}

fn display_encoding(encoding: &str) -> &str {
    if encoding.is_empty() { "no" } else { encoding }
}

fn schema_mentions(topic: &Topic, word: &str) -> bool {
    std::str::from_utf8(&topic.schema).is_ok_and(|s| s.contains(word))
}

/// A decoded message of one of the supported types.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Decoded {
    // The covariance-carrying types are boxed so the enum stays small.
    Odometry(Box<msgs::Odometry>),
    PoseStamped(msgs::PoseStamped),
    PoseWithCovarianceStamped(Box<msgs::PoseWithCovarianceStamped>),
    NavSatFix(msgs::NavSatFix),
    Imu(Box<msgs::Imu>),
    TfMessage(msgs::TfMessage),
    Detection3DArray(msgs::Detection3DArray),
    Image(msgs::Image),
    CompressedImage(msgs::CompressedImage),
    DiagnosticArray(msgs::DiagnosticArray),
    Foxglove(foxglove::FoxgloveMessage),
}

fn decode_ros(
    kind: MessageKind,
    format: WireFormat,
    payload: &[u8],
) -> Result<Decoded, DecodeError> {
    fn d<T: Wire>(payload: &[u8], format: WireFormat) -> Result<T, DecodeError> {
        msgs::decode(payload, format)
    }
    Ok(match kind {
        MessageKind::Odometry => Decoded::Odometry(Box::new(d(payload, format)?)),
        MessageKind::PoseStamped => Decoded::PoseStamped(d(payload, format)?),
        MessageKind::PoseWithCovarianceStamped => {
            Decoded::PoseWithCovarianceStamped(Box::new(d(payload, format)?))
        }
        MessageKind::NavSatFix => Decoded::NavSatFix(d(payload, format)?),
        MessageKind::Imu => Decoded::Imu(Box::new(d(payload, format)?)),
        MessageKind::TfMessage => Decoded::TfMessage(d(payload, format)?),
        MessageKind::Detection3DArray => Decoded::Detection3DArray(d(payload, format)?),
        MessageKind::Image => Decoded::Image(d(payload, format)?),
        MessageKind::CompressedImage => Decoded::CompressedImage(d(payload, format)?),
        MessageKind::DiagnosticArray => Decoded::DiagnosticArray(d(payload, format)?),
        other => {
            return Err(DecodeError::Unsupported(format!(
                "{} in ROS encoding",
                other.type_name()
            )));
        }
    })
}

/// One decoded message in a log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DecodedMessage {
    /// Index into [`DecodedLog::topics`].
    pub topic: usize,
    pub log_time: u64,
    pub message: Decoded,
}

/// Messages of a topic that were not decoded, with why.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct Undecoded {
    pub type_name: String,
    /// No decoder for the type: every message is counted here.
    pub unsupported: Option<String>,
    pub count: u64,
    /// The first decoding error, for messages of a supported type that failed.
    pub first_error: Option<String>,
}

/// A log read and decoded into one stream in storage order.
#[derive(Debug, Clone, Default)]
pub struct DecodedLog {
    pub topics: Vec<Topic>,
    pub messages: Vec<DecodedMessage>,
    /// Per topic name: what was not decoded.
    pub undecoded: BTreeMap<String, Undecoded>,
    pub report: ReadReport,
}

impl DecodedLog {
    /// The messages of one topic, in order.
    pub fn topic_messages<'a>(
        &'a self,
        name: &'a str,
    ) -> impl Iterator<Item = &'a DecodedMessage> + 'a {
        let index = self.topics.iter().position(|t| t.name == name);
        self.messages.iter().filter(move |m| Some(m.topic) == index)
    }

    /// Sorts the messages by log time; equal times keep storage order.
    pub fn sort_by_log_time(&mut self) {
        self.messages.sort_by_key(|m| m.log_time);
    }
}

/// Reads and decodes every message of `log` that passes `options`. Messages of unsupported
/// types or that fail to decode are counted per topic, not fatal.
pub fn read_decoded(log: &Log, options: &ReadOptions) -> LogResult<DecodedLog> {
    let mut codecs: Vec<Option<Result<Codec, String>>> = Vec::new();
    let mut messages = Vec::new();
    let mut undecoded: BTreeMap<String, Undecoded> = BTreeMap::new();
    let report = log.for_each_message(options, |topic, m: RawMessage<'_>| {
        if codecs.len() <= m.topic {
            codecs.resize(m.topic + 1, None);
        }
        let codec = codecs[m.topic].get_or_insert_with(|| Codec::for_topic(topic));
        let result = match codec {
            Ok(codec) => codec.decode(m.data).map_err(|e| (None, e.to_string())),
            Err(why) => Err((Some(why.clone()), String::new())),
        };
        match result {
            Ok(message) => messages.push(DecodedMessage {
                topic: m.topic,
                log_time: m.log_time,
                message,
            }),
            Err((unsupported, error)) => {
                let entry = undecoded
                    .entry(topic.name.clone())
                    .or_insert_with(|| Undecoded {
                        type_name: topic.type_name.clone(),
                        unsupported,
                        ..Default::default()
                    });
                entry.count += 1;
                if entry.unsupported.is_none() && entry.first_error.is_none() {
                    entry.first_error = Some(error);
                }
            }
        }
        ControlFlow::Continue(())
    })?;
    Ok(DecodedLog {
        topics: report.topics.clone(),
        messages,
        undecoded,
        report,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn type_names_in_both_ros_spellings() {
        assert_eq!(
            MessageKind::from_ros_name("nav_msgs/msg/Odometry"),
            Some(MessageKind::Odometry)
        );
        assert_eq!(
            MessageKind::from_ros_name("tf2_msgs/TFMessage"),
            Some(MessageKind::TfMessage)
        );
        assert_eq!(MessageKind::from_ros_name("std_msgs/msg/String"), None);
        assert_eq!(
            MessageKind::from_foxglove_name("foxglove.SceneUpdate"),
            Some(MessageKind::FoxgloveSceneUpdate)
        );
        assert_eq!(MessageKind::Imu.type_name(), "sensor_msgs/msg/Imu");
    }
}
