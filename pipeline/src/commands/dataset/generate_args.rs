//! `pipeline dataset generate`'s options and the generation config they make.

use std::path::PathBuf;

use anyhow::Result;
use datasets::generate::GenerateConfig;
use datasets::render::TopdownConfig;

use crate::error::CliError;

#[derive(Debug, clap::Args)]
pub struct GenerateArgs {
    /// A map (map.json, map.bin or a map folder from `pipeline map import`), or an OSM file
    /// (.osm, .osm.gz, .osm.pbf) imported on the fly with the default car profile
    /// [default: the bundled campus, Northwestern University and Evanston
    /// (northwestern_nu.osm.pbf, embedded in the binary; © OpenStreetMap contributors, ODbL
    /// 1.0), recorded in the card as `bundled:northwestern_nu.osm.pbf`].
    #[arg(long, value_name = "MAP|OSM")]
    pub map: Option<PathBuf>,

    /// Output folder (written atomically; replaced if it holds an earlier dataset).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Number of images.
    #[arg(long, default_value_t = 100)]
    pub count: u64,

    /// Generation settings, TOML: any of the `camera`, `scenery`, `traffic` and `randomise`
    /// tables and `draw_distance_m` (docs/datasets.md lists them; unset keys keep their
    /// defaults, an unknown key is an error). The options below override it.
    #[arg(long, value_name = "FILE")]
    pub settings: Option<PathBuf>,

    /// Image size, WIDTHxHEIGHT [default: 480x270].
    #[arg(long, value_name = "WxH")]
    pub size: Option<String>,

    /// Camera height above the road, metres [default: 1.6].
    #[arg(long, value_name = "M")]
    pub camera_height: Option<f64>,

    /// Downward tilt of the camera, degrees [default: 4].
    #[arg(long, value_name = "DEG", allow_hyphen_values = true)]
    pub pitch: Option<f64>,

    /// Horizontal field of view, degrees [default: 69].
    #[arg(long, value_name = "DEG")]
    pub fov: Option<f64>,

    /// Pedestrians in a view, MIN-MAX (uniform, inclusive) [default: 0-10].
    #[arg(long, value_name = "MIN-MAX")]
    pub pedestrians: Option<String>,

    /// Share of pedestrians that cross the road at an intersection when one is in view
    /// [default: 0.3].
    #[arg(long, value_name = "SHARE")]
    pub crossing_share: Option<f64>,

    /// Road users (vehicles and pedestrians) stand within this distance of the camera,
    /// metres [default: 70]; a shorter range gives nearer, larger people and cars.
    #[arg(long, value_name = "M")]
    pub range: Option<f64>,

    /// Also write the top-down label view of each scene (topdown/<id>.png, ego-centred).
    #[arg(long)]
    pub topdown: bool,

    /// Also write colour previews of the labels (previews/<id>.png).
    #[arg(long)]
    pub previews: bool,

    /// One plain look for every image (no colour, weather, wear or camera jitter).
    #[arg(long)]
    pub no_randomise: bool,

    /// Make only shard i of n of the --count items (for running across machines); merge
    /// the n shard folders with `pipeline dataset merge --shards` (docs/scaling.md).
    #[arg(long, value_name = "i/n", value_parser = datasets::shard::Shard::parse)]
    pub shard: Option<datasets::shard::Shard>,
}

/// "480x270" to (480, 270).
fn parse_size(s: &str) -> std::result::Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT such as 480x270, not `{s}`"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|_| format!("expected WIDTHxHEIGHT such as 480x270, not `{s}`"))
    };
    Ok((parse(w)?, parse(h)?))
}

/// The generation config from the defaults and the command line.
pub fn resolve_config(args: &GenerateArgs) -> Result<GenerateConfig> {
    if args.count == 0 {
        return Err(CliError::new(
            "--count 0: there is nothing to generate",
            "--count must be at least 1 (the number of images; with --shard i/n, of all the shards together)",
        )
        .into());
    }
    let mut config = match &args.settings {
        Some(path) => read_settings(path)?,
        None => GenerateConfig::default(),
    };
    if let Some(size) = &args.size {
        let (w, h) = parse_size(size)
            .map_err(|m| CliError::new(format!("--size: {m}"), "e.g. --size 512x512"))?;
        config.camera.width = w;
        config.camera.height = h;
    }
    if let Some(v) = args.camera_height {
        config.camera.height_m = v;
    }
    if let Some(v) = args.pitch {
        config.camera.pitch_deg = v;
    }
    if let Some(v) = args.fov {
        config.camera.hfov_deg = v;
    }
    if let Some(range) = &args.pedestrians {
        config.traffic.pedestrians = parse_range(range)
            .map_err(|m| CliError::new(format!("--pedestrians: {m}"), "e.g. --pedestrians 4-16"))?;
    }
    if let Some(v) = args.crossing_share {
        config.traffic.crossing_share = v;
    }
    if let Some(v) = args.range {
        config.traffic.range_m = v;
    }
    if args.topdown {
        config.topdown = Some(TopdownConfig::default());
    }
    if args.no_randomise {
        config.randomise.enabled = false;
    }
    config.check().map_err(|e| {
        CliError::new(
            e.to_string(),
            "see `pipeline dataset generate --help` for the ranges",
        )
    })?;
    Ok(config)
}

/// A generation settings file.
fn read_settings(path: &std::path::Path) -> Result<GenerateConfig> {
    let hint = "see docs/datasets.md for the settings, or configs/ for examples";
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::file(path, format!("cannot read: {e}"), hint))?;
    Ok(toml::from_str(&text).map_err(|e| {
        CliError::file(
            path,
            format!("not generation settings: {}", e.message()),
            hint,
        )
    })?)
}

/// "4-16" to (4, 16).
fn parse_range(s: &str) -> std::result::Result<(u32, u32), String> {
    let bad = || format!("expected MIN-MAX such as 0-10, not `{s}`");
    let (lo, hi) = s.split_once('-').ok_or_else(bad)?;
    let parse = |v: &str| v.trim().parse::<u32>().map_err(|_| bad());
    Ok((parse(lo)?, parse(hi)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("480x270"), Ok((480, 270)));
        assert_eq!(parse_size("512X512"), Ok((512, 512)));
        assert!(parse_size("512").is_err());
        assert!(parse_size("ax2").is_err());
    }

    #[test]
    fn pedestrian_ranges_parse_and_bad_traffic_is_refused() {
        assert_eq!(parse_range("4-16"), Ok((4, 16)));
        assert!(parse_range("4").is_err());
        assert!(parse_range("-3-4").is_err());
        let mut config = GenerateConfig::default();
        config.traffic.pedestrians = (9, 3);
        assert!(config.check().is_err());
        config.traffic.pedestrians = (3, 9);
        config.traffic.crossing_share = 1.5;
        assert!(config.check().is_err());
        config.traffic.crossing_share = 0.6;
        assert!(config.check().is_ok());
        config.traffic.range_m = 0.0;
        assert!(config.check().is_err());
        config.traffic.range_m = 25.0;
        assert!(config.check().is_ok());
    }
}
