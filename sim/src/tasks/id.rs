//! The driving tasks' names and what the registry says of each: plain data, below every
//! task (the reports and the registry's dispatch, [`super::registry`], read it).

use serde::{Deserialize, Serialize};

/// A task, by name (serde writes the kebab-case name, e.g. `roundabout-insertion`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TaskId {
    RoundaboutInsertion,
    RouteFollowing,
    RoundaboutDriving,
    ObstacleAvoidance,
}

/// What the registry says of a task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskInfo {
    pub id: TaskId,
    /// The `--task` value: the name serde writes.
    pub name: &'static str,
    /// One line for `--help`.
    pub description: &'static str,
    /// What messages call it ("roundabout insertion").
    pub title: &'static str,
    /// Whether it drives on a map given to it (the others build their own road).
    pub needs_map: bool,
    /// Whether its evaluation conditions read the ego's aggressiveness.
    pub uses_aggressiveness: bool,
    /// What to check when its setup fails.
    pub setup_hint: &'static str,
}

/// Every task, in the order of [`TaskId`].
pub const TASKS: [TaskInfo; 4] = [
    TaskInfo {
        id: TaskId::RoundaboutInsertion,
        name: "roundabout-insertion",
        description: "Enter a roundabout from a yield line through circulating traffic (the Parma study)",
        title: "roundabout insertion",
        needs_map: true,
        uses_aggressiveness: true,
        setup_hint: "the map needs a roundabout with an entry, a ring and an exit (`pipeline map info` \
                     lists them); check [agent.task] in --config",
    },
    TaskInfo {
        id: TaskId::RouteFollowing,
        name: "route-following",
        description: "Follow a planned route over an imported campus, keeping in lane among other \
                      traffic (the AIT / MTSU studies)",
        title: "route following",
        needs_map: true,
        uses_aggressiveness: false,
        setup_hint: "the map needs connected car lanes with routes of [agent.route] route_length_m",
    },
    TaskInfo {
        id: TaskId::RoundaboutDriving,
        name: "roundabout-driving",
        description: "Steer along a route through a roundabout for 10 s (the ITS study)",
        title: "roundabout driving",
        needs_map: true,
        uses_aggressiveness: false,
        setup_hint: "give a map with a roundabout (e.g. data/osm/montlake_roundabout.osm.pbf) and \
                     valid [agent.roundabout_driving] settings",
    },
    TaskInfo {
        id: TaskId::ObstacleAvoidance,
        name: "obstacle-avoidance",
        description: "Pass a parked vehicle or yield to a crossing one on a straight synthetic road \
                      (the Thai CARLA study); needs no map",
        title: "obstacle avoidance",
        needs_map: false,
        uses_aggressiveness: false,
        setup_hint: "check the [agent.obstacle] table of the config",
    },
];

impl TaskId {
    pub const ALL: [TaskId; 4] = [
        TaskId::RoundaboutInsertion,
        TaskId::RouteFollowing,
        TaskId::RoundaboutDriving,
        TaskId::ObstacleAvoidance,
    ];

    pub fn info(self) -> &'static TaskInfo {
        &TASKS[self as usize]
    }

    /// The `--task` value.
    pub fn name(self) -> &'static str {
        self.info().name
    }

    pub fn from_name(name: &str) -> Option<TaskId> {
        TaskId::ALL.into_iter().find(|t| t.name() == name)
    }
}
