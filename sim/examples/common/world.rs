//! A calibration file's world, for the examples that run the traffic world.

use sim::tasks::InsertionConfig;

/// `[traffic]`, `[layout]` and `[recorded]` of a calibration file into `config`.
pub fn world(path: &str, config: &mut InsertionConfig) -> Result<(), Box<dyn std::error::Error>> {
    #[derive(serde::Deserialize)]
    struct Recorded {
        flows: Vec<sim::world::EntryFlow>,
    }
    #[derive(serde::Deserialize)]
    struct Calibration {
        traffic: sim::world::TrafficConfig,
        layout: sim::roundabout::LayoutConfig,
        recorded: Option<Recorded>,
    }
    let text = std::fs::read_to_string(path).map_err(|e| format!("{path}: {e}"))?;
    let c: Calibration = toml::from_str(&text).map_err(|e| format!("{path}: {e}"))?;
    config.traffic = c.traffic;
    config.layout = c.layout;
    if let Some(r) = c.recorded {
        config.traffic.flows = r.flows;
    }
    Ok(())
}
