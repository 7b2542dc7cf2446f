//! Roundabout insertion as a [`Task`]: its setup on a map, conditions, summary and
//! baselines.

use super::*;
use crate::tasks::tables::{Tables, TablesMut};

impl Task for RoundaboutInsertion {
    type Config = InsertionConfig;
    type Setup = InsertionSetup;
    type Condition = Condition;

    const ID: TaskId = TaskId::RoundaboutInsertion;

    fn table<'a>(tables: Tables<'a>) -> &'a Self::Config {
        tables.insertion
    }

    fn table_mut<'a>(tables: TablesMut<'a>) -> &'a mut Self::Config {
        tables.insertion
    }

    fn deciding_every(config: &InsertionConfig, steps: usize) -> Option<InsertionConfig> {
        Some(config.deciding_every(steps))
    }

    fn in_world(config: &InsertionConfig, world: &CalibratedWorld) -> Option<InsertionConfig> {
        Some(config.in_world(world))
    }

    fn on_roundabout(config: &InsertionConfig, id: u32) -> Option<InsertionConfig> {
        Some(config.on_roundabout(id))
    }

    fn training_env(setup: &Arc<InsertionSetup>, traffic: TrafficLevel) -> Self {
        let mut env = RoundaboutInsertion::new(Arc::clone(setup));
        env.set_traffic(traffic);
        env
    }

    fn env(setup: &Arc<InsertionSetup>, condition: &Condition) -> Self {
        let mut env = RoundaboutInsertion::new(Arc::clone(setup));
        env.set_traffic(condition.traffic);
        env.set_aggressiveness(Some(condition.aggressiveness));
        env
    }

    /// Traffic levels × aggressiveness values (by default every level × 0, 0.5 and 1).
    fn conditions(choice: &ConditionChoice) -> Vec<Condition> {
        let aggressiveness = if choice.aggressiveness.is_empty() {
            vec![0.0, 0.5, 1.0]
        } else {
            choice.aggressiveness.clone()
        };
        choice
            .traffic_levels()
            .into_iter()
            .flat_map(|traffic| {
                aggressiveness.iter().map(move |&aggressiveness| Condition {
                    traffic,
                    aggressiveness,
                })
            })
            .collect()
    }

    fn condition_name(condition: &Condition) -> String {
        condition.name()
    }

    /// At the training traffic, for each of the evaluation's aggressiveness values.
    fn validation_conditions(traffic: TrafficLevel) -> Vec<(String, Condition)> {
        [0.0, 0.5, 1.0]
            .map(|aggressiveness| {
                let condition = Condition {
                    traffic,
                    aggressiveness,
                };
                (format!("aggressiveness {aggressiveness}"), condition)
            })
            .to_vec()
    }

    fn recorded_condition(traffic: TrafficLevel) -> Condition {
        Condition {
            traffic,
            aggressiveness: 0.5,
        }
    }

    /// Medium traffic, aggressiveness 0.5, whatever the conditions.
    fn recorded_eval_condition(_: &[Condition]) -> Condition {
        Self::recorded_condition(TrafficLevel::Medium)
    }

    fn eval_report(
        header: &EvalHeader,
        evaluation: &Evaluation<Condition, EpisodeSummary>,
    ) -> Result<EvalReport, SimError> {
        insertion_eval::report(header, evaluation)
    }

    /// The study's baselines, and in a calibrated world the rule of its median driver's
    /// critical gap.
    fn setup_baselines(setup: &InsertionSetup) -> Vec<(String, PolicyFactory<Self>)> {
        let mut all = Self::baselines();
        if let Some(gap) = setup.config().traffic.drivers.critical_gap.measured() {
            let baseline = Baseline::CriticalGap {
                seconds: gap.median_s,
            };
            let make: PolicyFactory<Self> = Box::new(move || Box::new(InsertionPolicy(baseline)));
            all.push((baseline.name(), make));
        }
        all
    }

    /// The Parma study's rules, always Permitted, random and always Not Permitted.
    fn baselines() -> Vec<(String, PolicyFactory<Self>)> {
        Baseline::STANDARD
            .into_iter()
            .map(|baseline| {
                let make: PolicyFactory<Self> =
                    Box::new(move || Box::new(InsertionPolicy(baseline)));
                (baseline.name(), make)
            })
            .collect()
    }

    /// The current scene (None before the first reset).
    fn scene(&self) -> Option<Scene<'_>> {
        ego_scene(
            self.setup.map(),
            self.world.as_ref()?,
            self.start_time_s,
            Some(self.aggressiveness),
        )
    }

    fn set_rendering(&mut self, on: bool) {
        self.view.set_rendering(on);
    }

    /// The newest bird's-eye frame.
    fn recorded_layers(&self) -> Option<LayerFrame<'_>> {
        let bev = &self.setup.config().observation;
        Some(LayerFrame {
            layers: self.newest_frame(),
            names: &bev.layers,
            width: bev.width,
            height: bev.height,
        })
    }
}

impl TaskSummary for EpisodeSummary {
    outcome_and_return_fields!();

    fn metrics(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("mean speed m/s", self.mean_speed_mps),
            ("time to enter s", self.time_to_enter_s.unwrap_or(f64::NAN)),
            ("entry lag s", self.entry_lag_s.unwrap_or(f64::NAN)),
        ]
    }
}
