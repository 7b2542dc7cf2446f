//! Which topic of a log plays which part: the ego's pose, its GPS fix, the other road users
//! (object detections) and the camera.
//!
//! A role given in the config must name a topic of the log whose type fits the role. A role
//! not given is detected where that is unambiguous:
//! 1. the candidates are the topics whose type fits the role (ego pose: `nav_msgs/Odometry`,
//!    `geometry_msgs/PoseStamped`, `PoseWithCovarianceStamped`, `foxglove.PoseInFrame`;
//!    GPS: `sensor_msgs/NavSatFix`, `foxglove.LocationFix`; objects:
//!    `vision_msgs/Detection3DArray`; camera: `sensor_msgs/Image`, `CompressedImage`,
//!    `foxglove.CompressedImage`);
//! 2. for the ego pose, topics under the objects topic (`/objects/odom` beside `/objects`:
//!    one odometry per other vehicle) are not candidates;
//! 3. one candidate: it is the role's topic; several: the one whose name says `ego`, if
//!    exactly one does; otherwise the role is ambiguous and left empty, with the candidates
//!    listed so the user can name one.

use serde::{Deserialize, Serialize};

use super::decode::MessageKind;

/// The parts a topic can play.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    EgoPose,
    Gps,
    Objects,
    Camera,
}

impl Role {
    pub const ALL: [Role; 4] = [Role::EgoPose, Role::Gps, Role::Objects, Role::Camera];

    /// The role's name in configs and output (`ego_pose`, `gps`, `objects`, `camera`).
    pub fn name(self) -> &'static str {
        match self {
            Role::EgoPose => "ego_pose",
            Role::Gps => "gps",
            Role::Objects => "objects",
            Role::Camera => "camera",
        }
    }

    /// The message kinds a topic of this role may carry.
    pub fn kinds(self) -> &'static [MessageKind] {
        match self {
            Role::EgoPose => &[
                MessageKind::Odometry,
                MessageKind::PoseStamped,
                MessageKind::PoseWithCovarianceStamped,
                MessageKind::FoxglovePoseInFrame,
            ],
            Role::Gps => &[MessageKind::NavSatFix, MessageKind::FoxgloveLocationFix],
            Role::Objects => &[MessageKind::Detection3DArray],
            Role::Camera => &[
                MessageKind::Image,
                MessageKind::CompressedImage,
                MessageKind::FoxgloveCompressedImage,
            ],
        }
    }
}

/// Topics named for roles (`[logs.roles]` of the config, or command-line options); a role
/// left out is detected.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoleConfig {
    pub ego_pose: Option<String>,
    pub gps: Option<String>,
    pub objects: Option<String>,
    pub camera: Option<String>,
}

impl RoleConfig {
    pub fn get(&self, role: Role) -> Option<&str> {
        match role {
            Role::EgoPose => self.ego_pose.as_deref(),
            Role::Gps => self.gps.as_deref(),
            Role::Objects => self.objects.as_deref(),
            Role::Camera => self.camera.as_deref(),
        }
    }
}

/// How a role got its topic.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(tag = "how", rename_all = "snake_case")]
pub enum Assignment {
    /// Named in the config.
    Given { topic: String },
    /// The only topic of a fitting type (or the only one of them named `ego`).
    Detected { topic: String },
    /// Several fitting topics and nothing to choose between them.
    Ambiguous { candidates: Vec<String> },
    /// No topic of a fitting type.
    Absent,
}

impl Assignment {
    /// The role's topic, if it has one.
    pub fn topic(&self) -> Option<&str> {
        match self {
            Assignment::Given { topic } | Assignment::Detected { topic } => Some(topic),
            Assignment::Ambiguous { .. } | Assignment::Absent => None,
        }
    }
}

/// Every role's topic.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TopicRoles {
    pub ego_pose: Assignment,
    pub gps: Assignment,
    pub objects: Assignment,
    pub camera: Assignment,
}

impl TopicRoles {
    pub fn get(&self, role: Role) -> &Assignment {
        match role {
            Role::EgoPose => &self.ego_pose,
            Role::Gps => &self.gps,
            Role::Objects => &self.objects,
            Role::Camera => &self.camera,
        }
    }

    /// The role's topic, or why there is none (to append to an error).
    pub fn require(&self, role: Role) -> Result<&str, RoleError> {
        match self.get(role) {
            Assignment::Given { topic } | Assignment::Detected { topic } => Ok(topic),
            Assignment::Ambiguous { candidates } => Err(RoleError::Ambiguous {
                role,
                candidates: candidates.clone(),
            }),
            Assignment::Absent => Err(RoleError::Absent { role }),
        }
    }
}

/// Why a role has no topic ([`TopicRoles::require`], [`assign_roles`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RoleError {
    #[error("which topic holds the {} is ambiguous: {}", role_words(*role), candidates.join(", "))]
    Ambiguous { role: Role, candidates: Vec<String> },
    #[error("no topic holds the {} (types taken: {})", role_words(*role), type_names(*role))]
    Absent { role: Role },
    #[error("the {} topic {topic} is not in the log", role.name())]
    NotInLog { role: Role, topic: String },
    #[error(
        "the {} topic {topic} is {}; the role takes {}",
        role.name(),
        kind.map_or("of a type we do not decode".into(), |k| k.type_name()),
        type_names(*role)
    )]
    WrongType {
        role: Role,
        topic: String,
        kind: Option<MessageKind>,
    },
}

/// The type names `role` takes, comma-separated.
fn type_names(role: Role) -> String {
    role.kinds()
        .iter()
        .map(MessageKind::type_name)
        .collect::<Vec<_>>()
        .join(", ")
}

fn role_words(role: Role) -> &'static str {
    match role {
        Role::EgoPose => "ego's pose",
        Role::Gps => "GPS fix",
        Role::Objects => "object detections",
        Role::Camera => "camera images",
    }
}

/// The message kind of a topic from its type name and message encoding (None: not one we
/// decode).
pub fn topic_kind(type_name: &str, encoding: &str) -> Option<MessageKind> {
    match encoding {
        "cdr" | "ros1" => MessageKind::from_ros_name(type_name),
        "protobuf" | "json" => MessageKind::from_foxglove_name(type_name),
        _ => None,
    }
}

/// Assigns the roles over `topics` (name, kind): the config's where given (checked), the
/// rest detected (module docs). An error names a given topic that is missing or of a type
/// the role does not take.
pub fn assign_roles(
    topics: &[(String, Option<MessageKind>)],
    config: &RoleConfig,
) -> Result<TopicRoles, RoleError> {
    let mut assigned = Vec::with_capacity(Role::ALL.len());
    // Objects first: the ego pose's candidates depend on the objects topic.
    for role in [Role::Objects, Role::EgoPose, Role::Gps, Role::Camera] {
        let fits = |kind: &Option<MessageKind>| kind.is_some_and(|k| role.kinds().contains(&k));
        let assignment = if let Some(given) = config.get(role) {
            match topics.iter().find(|(name, _)| name == given) {
                None => {
                    return Err(RoleError::NotInLog {
                        role,
                        topic: given.to_owned(),
                    });
                }
                Some((_, kind)) if !fits(kind) => {
                    return Err(RoleError::WrongType {
                        role,
                        topic: given.to_owned(),
                        kind: *kind,
                    });
                }
                Some(_) => Assignment::Given {
                    topic: given.to_owned(),
                },
            }
        } else {
            let objects: Option<String> = assigned
                .iter()
                .find(|(r, _)| *r == Role::Objects)
                .and_then(|(_, a): &(Role, Assignment)| a.topic().map(str::to_owned));
            let candidates: Vec<&str> = topics
                .iter()
                .filter(|(_, kind)| fits(kind))
                .map(|(name, _)| name.as_str())
                .filter(|name| {
                    role != Role::EgoPose
                        || objects
                            .as_deref()
                            .is_none_or(|o| !name.starts_with(&format!("{o}/")))
                })
                .collect();
            detect(&candidates)
        };
        assigned.push((role, assignment));
    }
    let mut take = |role: Role| {
        assigned
            .iter()
            .position(|(r, _)| *r == role)
            .map_or(Assignment::Absent, |i| assigned.swap_remove(i).1)
    };
    Ok(TopicRoles {
        ego_pose: take(Role::EgoPose),
        gps: take(Role::Gps),
        objects: take(Role::Objects),
        camera: take(Role::Camera),
    })
}

/// One candidate, or the only one named `ego`; otherwise ambiguous (or absent).
fn detect(candidates: &[&str]) -> Assignment {
    match candidates {
        [] => Assignment::Absent,
        [only] => Assignment::Detected {
            topic: (*only).to_owned(),
        },
        several => {
            let ego: Vec<&&str> = several
                .iter()
                .filter(|name| name.to_lowercase().contains("ego"))
                .collect();
            match ego.as_slice() {
                [only] => Assignment::Detected {
                    topic: (**only).to_owned(),
                },
                _ => Assignment::Ambiguous {
                    candidates: several.iter().map(|s| (*s).to_owned()).collect(),
                },
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn topics(list: &[(&str, &str, &str)]) -> Vec<(String, Option<MessageKind>)> {
        list.iter()
            .map(|(name, ty, enc)| ((*name).to_owned(), topic_kind(ty, enc)))
            .collect()
    }

    #[test]
    fn the_husky_drive_has_an_ego_pose_and_a_gps_fix() {
        let t = topics(&[
            ("/imu/data", "sensor_msgs/msg/Imu", "cdr"),
            (
                "/husky_velocity_controller/odom",
                "nav_msgs/msg/Odometry",
                "cdr",
            ),
            ("/fix", "sensor_msgs/msg/NavSatFix", "cdr"),
        ]);
        let roles = assign_roles(&t, &RoleConfig::default()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            roles.ego_pose.topic(),
            Some("/husky_velocity_controller/odom")
        );
        assert_eq!(roles.gps.topic(), Some("/fix"));
        assert_eq!(roles.objects, Assignment::Absent);
        assert!(
            roles
                .require(Role::Objects)
                .is_err_and(|e| e.to_string().contains("Detection3DArray"))
        );
    }

    #[test]
    fn converted_tracks_keep_per_object_odometry_out_of_the_ego_pose() {
        let converted = [
            ("/objects", "vision_msgs/msg/Detection3DArray", "cdr"),
            ("/objects/odom", "nav_msgs/msg/Odometry", "cdr"),
        ];
        let roles = assign_roles(&topics(&converted), &RoleConfig::default())
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(roles.objects.topic(), Some("/objects"));
        assert_eq!(roles.ego_pose, Assignment::Absent);
        // With --ego: the ego's own odometry.
        let mut with_ego = converted.to_vec();
        with_ego.push(("/ego/odom", "nav_msgs/msg/Odometry", "cdr"));
        with_ego.push(("/ego/fix", "sensor_msgs/msg/NavSatFix", "cdr"));
        let roles = assign_roles(&topics(&with_ego), &RoleConfig::default())
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(roles.ego_pose.topic(), Some("/ego/odom"));
        assert_eq!(roles.gps.topic(), Some("/ego/fix"));
    }

    #[test]
    fn several_candidates_are_ambiguous_until_one_is_named() {
        let t = topics(&[
            ("/odom", "nav_msgs/msg/Odometry", "cdr"),
            ("/odometry/filtered", "nav_msgs/msg/Odometry", "cdr"),
            ("/cam/front", "sensor_msgs/msg/CompressedImage", "cdr"),
            ("/tf", "tf2_msgs/msg/TFMessage", "cdr"),
        ]);
        let roles = assign_roles(&t, &RoleConfig::default()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            roles.ego_pose,
            Assignment::Ambiguous {
                candidates: vec!["/odom".into(), "/odometry/filtered".into()]
            }
        );
        assert!(
            roles
                .require(Role::EgoPose)
                .is_err_and(|e| e.to_string().contains("/odometry/filtered"))
        );
        assert_eq!(roles.camera.topic(), Some("/cam/front"));
        let config = RoleConfig {
            ego_pose: Some("/odometry/filtered".into()),
            ..RoleConfig::default()
        };
        let roles = assign_roles(&t, &config).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            roles.ego_pose,
            Assignment::Given {
                topic: "/odometry/filtered".into()
            }
        );
        // A given topic must exist and fit the role.
        for (given, expected) in [
            ("/nope", "not in the log"),
            ("/tf", "tf2_msgs/msg/TFMessage"),
        ] {
            let config = RoleConfig {
                ego_pose: Some(given.into()),
                ..RoleConfig::default()
            };
            let err = assign_roles(&t, &config)
                .err()
                .map(|e| e.to_string())
                .unwrap_or_default();
            assert!(err.contains(expected), "{err}");
        }
    }

    #[test]
    fn foxglove_schemas_take_roles_too() {
        let t = topics(&[
            ("/gps", "foxglove.LocationFix", "protobuf"),
            ("/pose", "foxglove.PoseInFrame", "json"),
        ]);
        let roles = assign_roles(&t, &RoleConfig::default()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(roles.gps.topic(), Some("/gps"));
        assert_eq!(roles.ego_pose.topic(), Some("/pose"));
    }
}
