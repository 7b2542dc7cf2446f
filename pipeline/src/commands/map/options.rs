//! `map import`'s settings: the command line over `[map.import]` of the config file over
//! the defaults.

use std::path::Path;

use anyhow::Result;
use maps::build::UTurns;
use maps::profile::RoadProfile;
use maps::{DrivingSide, ImportOptions};

use super::args::{DrivingSideArg, ImportArgs, UTurnsArg};
use crate::clip::{parse_bbox, parse_lat_lon, read_polygon_file};
use crate::commands::Context;
use crate::error::CliError;

/// The import settings in effect, from the command line over the config file over defaults.
#[derive(Debug)]
pub struct ResolvedImport {
    pub options: ImportOptions,
    /// Where the profile came from: a built-in name or a file name.
    pub profile_source: String,
}

/// Merges `map import`'s options with `[map.import]` of the config file.
pub fn resolve_import_options(ctx: &Context<'_>, args: &ImportArgs) -> Result<ResolvedImport> {
    let cfg = &ctx.config.map.import;
    let config_file = || ctx.global.config.clone().unwrap_or_default();
    let bad_option = |what: &str, msg: String| {
        CliError::new(format!("{what}: {msg}"), "see `pipeline map import --help`")
    };
    let bad_config = |key: &str, msg: String| {
        CliError::file(
            &config_file(),
            format!("[map.import] {key}: {msg}"),
            "fix the config file or override it on the command line",
        )
    };

    let mut options = ImportOptions::default();

    let (profile, profile_source) = match (&args.profile, &cfg.profile) {
        (Some(p), _) => load_profile(p, Path::new(p)).map_err(|m| bad_option("--profile", m))?,
        (None, Some(p)) => load_profile(p, &ctx.config.resolve(Path::new(p)))
            .map_err(|m| bad_config("profile", m))?,
        (None, None) => (RoadProfile::car(), "car".to_owned()),
    };
    options.profile = profile;

    options.clip = match (&args.clip_bbox, &args.clip_polygon) {
        (Some(b), _) => Some(parse_bbox(b).map_err(|m| bad_option("--clip-bbox", m))?),
        (None, Some(p)) => Some(read_polygon_file(p).map_err(|m| {
            CliError::file(
                p,
                m,
                "give a GeoJSON Polygon or an Osmosis .poly file to --clip-polygon",
            )
        })?),
        (None, None) => match (&cfg.clip_bbox, &cfg.clip_polygon) {
            (Some(b), _) => Some(parse_bbox(b).map_err(|m| bad_config("clip_bbox", m))?),
            (None, Some(p)) => {
                let p = ctx.config.resolve(p);
                Some(read_polygon_file(&p).map_err(|m| {
                    CliError::file(
                        &p,
                        m,
                        "fix `clip_polygon` in the config file (GeoJSON Polygon or .poly)",
                    )
                })?)
            }
            (None, None) => None,
        },
    };

    options.driving_side = match (args.driving_side, &cfg.driving_side) {
        (Some(DrivingSideArg::Left), _) => Some(DrivingSide::Left),
        (Some(DrivingSideArg::Right), _) => Some(DrivingSide::Right),
        (None, Some(s)) => Some(match s.as_str() {
            "left" => DrivingSide::Left,
            "right" => DrivingSide::Right,
            _ => {
                return Err(bad_config(
                    "driving_side",
                    format!("expected left or right, not `{s}`"),
                )
                .into());
            }
        }),
        (None, None) => None,
    };

    options.u_turns = match (args.u_turns, &cfg.u_turns) {
        (Some(UTurnsArg::Never), _) => UTurns::Never,
        (Some(UTurnsArg::DeadEnds), _) => UTurns::DeadEnds,
        (Some(UTurnsArg::Everywhere), _) => UTurns::Everywhere,
        (None, Some(s)) => match s.as_str() {
            "never" => UTurns::Never,
            "dead-ends" | "dead_ends" => UTurns::DeadEnds,
            "everywhere" => UTurns::Everywhere,
            _ => {
                return Err(bad_config(
                    "u_turns",
                    format!("expected never, dead-ends or everywhere, not `{s}`"),
                )
                .into());
            }
        },
        (None, None) => UTurns::default(),
    };

    options.guess_roundabouts = !args.no_guess_roundabouts && cfg.guess_roundabouts.unwrap_or(true);
    options.check_invariants = args.check_every_step;

    options.origin = match (&args.origin, &cfg.origin) {
        (Some(o), _) => Some(parse_lat_lon(o).map_err(|m| bad_option("--origin", m))?),
        (None, Some(o)) => Some(parse_lat_lon(o).map_err(|m| bad_config("origin", m))?),
        (None, None) => None,
    };

    Ok(ResolvedImport {
        options,
        profile_source,
    })
}

/// A built-in profile by name, or a TOML profile file (named after the file unless it says
/// `name = ...`).
fn load_profile(spec: &str, path: &Path) -> std::result::Result<(RoadProfile, String), String> {
    if let Some(p) = RoadProfile::by_name(spec) {
        return Ok((p, spec.to_owned()));
    }
    if !path.is_file() {
        return Err(format!(
            "unknown profile `{spec}`: expected car, passenger, all, or a profile .toml file"
        ));
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    let table: toml::Table =
        toml::from_str(&text).map_err(|e| format!("{}: {}", path.display(), e.message()))?;
    let named = table.contains_key("name");
    let mut profile: RoadProfile = toml::from_str(&text)
        .map_err(|e| format!("{}: not a road profile: {}", path.display(), e.message()))?;
    if !named {
        profile.name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "custom".into());
    }
    if profile.highways.is_empty() {
        return Err(format!(
            "{}: the profile selects no `highways`",
            path.display()
        ));
    }
    let source = path
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok((profile, source))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::{Cli, Group};
    use crate::commands::map::args::MapCommand;
    use crate::config::Config;
    use crate::ui::{Ui, Verbosity};
    use clap::Parser;
    use maps::build::Clip;

    fn import_args(cli: &Cli) -> &ImportArgs {
        match &cli.command {
            Group::Map {
                command: MapCommand::Import(a),
            } => a,
            _ => panic!("not an import"),
        }
    }

    #[test]
    fn command_line_overrides_config_overrides_defaults() -> Result<()> {
        let config = Config::parse(
            "[map.import]\nprofile = \"passenger\"\nu_turns = \"never\"\ndriving_side = \"left\"\norigin = \"1,2\"\n",
        )
        .map_err(anyhow::Error::msg)?;
        let ui = Ui::new(Verbosity::Quiet);
        let cli = Cli::try_parse_from([
            "pipeline",
            "map",
            "import",
            "x.osm",
            "--out",
            "o",
            "--u-turns",
            "everywhere",
        ])?;
        let ctx = Context {
            global: &cli.global,
            config: &config,
            ui: &ui,
            recording: None,
            run_argv: crate::run_argv,
        };
        let r = resolve_import_options(&ctx, import_args(&cli))?;
        assert_eq!(r.options.profile.name, "passenger");
        assert_eq!(r.options.u_turns, UTurns::Everywhere);
        assert_eq!(r.options.driving_side, Some(DrivingSide::Left));
        assert_eq!(r.options.origin, Some(maps::LatLon::new(1.0, 2.0)));
        assert!(r.options.guess_roundabouts);

        let cli = Cli::try_parse_from([
            "pipeline",
            "map",
            "import",
            "x.osm",
            "--out",
            "o",
            "--no-guess-roundabouts",
            "--clip-bbox",
            "1,2,3,4",
        ])?;
        let defaults = Config::default();
        let ctx = Context {
            global: &cli.global,
            config: &defaults,
            ui: &ui,
            recording: None,
            run_argv: crate::run_argv,
        };
        let r = resolve_import_options(&ctx, import_args(&cli))?;
        assert_eq!(r.options.profile.name, "car");
        assert!(!r.options.guess_roundabouts);
        assert!(matches!(r.options.clip, Some(Clip::BoundingBox { .. })));

        let cli = Cli::try_parse_from([
            "pipeline",
            "map",
            "import",
            "x.osm",
            "--out",
            "o",
            "--profile",
            "bicycle",
        ])?;
        let ctx = Context {
            global: &cli.global,
            config: &defaults,
            ui: &ui,
            recording: None,
            run_argv: crate::run_argv,
        };
        assert!(resolve_import_options(&ctx, import_args(&cli)).is_err());
        Ok(())
    }

    #[test]
    fn profile_files() -> Result<()> {
        let dir = tempfile::tempdir()?;
        let p = dir.path().join("buses.toml");
        std::fs::write(
            &p,
            "highways = [\"primary\", \"busway\"]\ncar_highways = [\"primary\"]\n",
        )?;
        let (profile, source) =
            load_profile(&p.to_string_lossy(), &p).map_err(anyhow::Error::msg)?;
        assert_eq!(
            (profile.name.as_str(), source.as_str()),
            ("buses", "buses.toml")
        );
        assert_eq!(
            profile.highways,
            vec!["primary".to_owned(), "busway".to_owned()]
        );
        std::fs::write(&p, "highways = 3\n")?;
        assert!(load_profile(&p.to_string_lossy(), &p).is_err());
        Ok(())
    }
}
