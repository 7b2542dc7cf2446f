//! The registry of driving tasks: each task's name (the `--task` value, and what an agent's
//! `task.json` says), description, settings table and [`Task`] type, through which
//! everything else is built (setup, environments, conditions, baselines).
//!
//! Adding a task: its folder in [`crate::tasks`] implementing [`super::Driving`] and
//! [`Task`], a variant of [`TaskId`], its [`TaskInfo`] in [`TASKS`] and its arm in
//! [`TaskId::visit`]; in `pipeline`, its `[agent.<table>]` field of the agent config.

use super::Task;
use super::insertion::RoundaboutInsertion;
use super::obstacle::ObstacleAvoidance;
use super::ring_driving::RingDriving;
use super::route::RouteFollowing;

pub use super::id::{TASKS, TaskId, TaskInfo};

/// Something done with a task's type: what [`TaskId::visit`] runs.
pub trait TaskVisitor {
    type Output;
    fn visit<T: Task>(self) -> Self::Output;
}

impl TaskId {
    /// Runs `visitor` with the task's type.
    pub fn visit<V: TaskVisitor>(self, visitor: V) -> V::Output {
        match self {
            TaskId::RoundaboutInsertion => visitor.visit::<RoundaboutInsertion>(),
            TaskId::RouteFollowing => visitor.visit::<RouteFollowing>(),
            TaskId::RoundaboutDriving => visitor.visit::<RingDriving>(),
            TaskId::ObstacleAvoidance => visitor.visit::<ObstacleAvoidance>(),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    struct Id;

    impl TaskVisitor for Id {
        type Output = TaskId;
        fn visit<T: Task>(self) -> TaskId {
            T::ID
        }
    }

    #[test]
    fn every_task_is_listed_once_under_its_serde_name() {
        for (i, id) in TaskId::ALL.into_iter().enumerate() {
            let info = id.info();
            assert_eq!(info.id, id);
            assert_eq!(TASKS[i].id, id);
            assert_eq!(serde_json::to_value(id).unwrap(), info.name);
            assert_eq!(TaskId::from_name(info.name), Some(id));
            assert_eq!(id.visit(Id), id, "{id:?} visits its own type");
        }
        assert_eq!(TaskId::from_name("nothing"), None);
    }
}
