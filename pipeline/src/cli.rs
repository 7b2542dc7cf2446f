//! The command line, as in ARCHITECTURE.md:
//!
//! ```text
//! pipeline [--config FILE] [--run-dir DIR] [--seed N] [-v | -q] [--rerun save|spawn|connect[=ADDR]|off] <group> <command>
//! ```
//!
//! Global options may also follow the group or command (clap's `global`), so
//! `pipeline map import x.osm --out o -q` works as well. Only commands that work exist.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, ValueEnum};

use crate::ui::Verbosity;

/// Drivable maps, segmentation data, segmenters and driving agents for real places.
#[derive(Debug, Parser)]
#[command(
    name = "pipeline",
    version,
    propagate_version = true,
    max_term_width = 100,
    mut_subcommand("segmenter", |group| with_device(group, DEVICE_COMMANDS)),
    mut_subcommand("agent", |group| with_device(group, DEVICE_COMMANDS)),
    mut_subcommand("run", device_arg)
)]
pub struct Cli {
    /// TOML file with defaults for commands (e.g. a `[map.import]` table); options given on
    /// the command line win.
    #[arg(long, global = true, value_name = "FILE")]
    pub config: Option<PathBuf>,

    /// Folder that relative output paths (`--out`) are resolved in [default: the current folder].
    #[arg(long, global = true, value_name = "DIR")]
    pub run_dir: Option<PathBuf>,

    /// Seed of every random draw; recorded in each output.
    #[arg(long, global = true, value_name = "N", default_value_t = 0)]
    pub seed: u64,

    /// More detail (timings, per-step figures); -vv for even more. RUST_LOG (e.g.
    /// `RUST_LOG=models=debug,burn=info`) overrides -q and -v.
    #[arg(short, long, global = true, action = clap::ArgAction::Count, conflicts_with = "quiet")]
    pub verbose: u8,

    /// Only errors.
    #[arg(short, long, global = true)]
    pub quiet: bool,

    /// Where the rerun recording goes: `save` (recording.rrd in the output folder), `spawn` (a
    /// new viewer), `connect[=ADDR]` (a running viewer, default 127.0.0.1:9876), or `off`.
    #[arg(long, global = true, value_name = "MODE", default_value = "save", value_parser = parse_rerun)]
    pub rerun: RerunMode,

    /// Where networks train and run. Shown in the help of the commands that use it
    /// ([`DEVICE_COMMANDS`]), which have their own `--device` with this id; elsewhere it is
    /// accepted but hidden.
    #[arg(long, global = true, value_enum, default_value = "cpu", hide = true)]
    pub device: DeviceArg,

    #[command(subcommand)]
    pub command: Group,
}

/// `--device`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceArg {
    /// burn's flex backend on the CPU (every build).
    Cpu,
    /// The first CUDA GPU (a build with `--features cuda`).
    Cuda,
    /// The default wgpu adapter: Vulkan, Metal or DX12 (a build with `--features wgpu`).
    Wgpu,
    /// burn's LibTorch backend on the CPU (a build with `--features libtorch`).
    Libtorch,
}

/// The commands that train or run networks on `--device` (`pipeline run` passes it on to its
/// stages): only their help shows the option.
pub const DEVICE_COMMANDS: &[(&str, &str)] = &[
    ("segmenter", "train"),
    ("segmenter", "eval"),
    ("segmenter", "predict"),
    ("segmenter", "bench"),
    ("segmenter", "recalibrate"),
    ("agent", "train"),
];

/// Adds `--device` to the commands of `group` listed in `commands`.
fn with_device(group: clap::Command, commands: &[(&str, &str)]) -> clap::Command {
    let name = group.get_name().to_owned();
    commands
        .iter()
        .filter(|(g, _)| *g == name)
        .fold(group, |group, (_, command)| {
            group.mut_subcommand(*command, device_arg)
        })
}

/// A command's own `--device`: the same id as the hidden global option, so the value given
/// reaches [`Cli::device`] wherever it is written.
fn device_arg(command: clap::Command) -> clap::Command {
    command.arg(
        clap::Arg::new("device")
            .long("device")
            .value_name("DEVICE")
            .value_parser(clap::builder::EnumValueParser::<DeviceArg>::new())
            .default_value("cpu")
            .help(
                "Where networks train and run: `cpu`, or a GPU through burn's `cuda` or `wgpu` \
                 backend in a build with that cargo feature, or `libtorch` (PyTorch's kernels on \
                 the CPU; docs/gpu.md).",
            ),
    )
}

impl From<DeviceArg> for models::DeviceChoice {
    fn from(d: DeviceArg) -> Self {
        match d {
            DeviceArg::Cpu => models::DeviceChoice::Cpu,
            DeviceArg::Cuda => models::DeviceChoice::Cuda,
            DeviceArg::Wgpu => models::DeviceChoice::Wgpu,
            DeviceArg::Libtorch => models::DeviceChoice::LibTorch,
        }
    }
}

impl Cli {
    pub fn verbosity(&self) -> Verbosity {
        if self.quiet {
            Verbosity::Quiet
        } else if self.verbose > 1 {
            Verbosity::Trace
        } else if self.verbose > 0 {
            Verbosity::Verbose
        } else {
            Verbosity::Normal
        }
    }
}

/// Where a command's rerun recording goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RerunMode {
    Save,
    Spawn,
    /// A gRPC proxy URL (`rerun+http://HOST:PORT/proxy`).
    Connect(String),
    Off,
}

/// The address a viewer listens on by default (`rerun` with no arguments).
pub const DEFAULT_RERUN_URL: &str = "rerun+http://127.0.0.1:9876/proxy";

fn parse_rerun(s: &str) -> Result<RerunMode, String> {
    match s {
        "save" => Ok(RerunMode::Save),
        "spawn" => Ok(RerunMode::Spawn),
        "off" => Ok(RerunMode::Off),
        "connect" => Ok(RerunMode::Connect(DEFAULT_RERUN_URL.to_owned())),
        _ => match s.strip_prefix("connect=") {
            Some(addr) if !addr.trim().is_empty() => Ok(RerunMode::Connect(rerun_url(addr.trim()))),
            _ => Err(format!(
                "expected save, spawn, connect, connect=ADDR or off, not `{s}`"
            )),
        },
    }
}

/// `HOST:PORT` (or a full URL) to the proxy URL the rerun SDK wants.
fn rerun_url(addr: &str) -> String {
    if addr.contains("://") {
        addr.to_owned()
    } else {
        format!("rerun+http://{addr}/proxy")
    }
}

#[derive(Debug, Subcommand)]
pub enum Group {
    /// Maps: import OpenStreetMap / Lanelet2 files, inspect them, route on them.
    Map {
        #[command(subcommand)]
        command: MapCommand,
    },
    /// Driving agents: train DQN / Double DQN on a task, evaluate them next to the baselines.
    Agent {
        #[command(subcommand)]
        command: crate::commands::agent::AgentCommand,
    },
    /// Segmentation datasets: generate from a map, import, augment, statistics, split, check, merge.
    Dataset {
        #[command(subcommand)]
        command: crate::commands::dataset::DatasetCommand,
    },
    /// The PSPNet-style segmenter: train, evaluate, predict, benchmark.
    Segmenter {
        #[command(subcommand)]
        command: crate::commands::segmenter::SegmenterCommand,
    },
    /// Real logs: summarise MCAP files and ROS 2 bags, convert INTERACTION tracks to MCAP.
    Logs {
        #[command(subcommand)]
        command: crate::commands::logs::LogsCommand,
    },
    /// Judge policies against real drivers' decisions in recorded logs.
    Replay {
        #[command(subcommand)]
        command: crate::commands::replay::ReplayCommand,
    },
    /// The traffic world against real drivers: calibrate it on recordings of a roundabout,
    /// measure how far it drives from them.
    Sim {
        #[command(subcommand)]
        command: crate::commands::sim::SimCommand,
    },
    /// The main job: every stage in order on the bundled campus and roundabout, into one run
    /// folder with a report and one rerun recording; unchanged stages are skipped. Reads
    /// `pipeline.toml` from the current folder when there is no --config.
    Run(crate::commands::run::RunArgs),
}

#[derive(Debug, Subcommand)]
pub enum MapCommand {
    /// Import an OSM (.osm, .osm.gz, .osm.pbf) or Lanelet2 file into a map folder.
    Import(ImportArgs),
    /// Print a map's summary (lanes, lengths, junctions, components, roundabouts).
    Info(InfoArgs),
    /// Fastest route over lanes between two points.
    Route(RouteArgs),
}

#[derive(Debug, Args)]
pub struct ImportArgs {
    /// The input file.
    pub input: PathBuf,

    /// Output folder (written atomically; replaced if it holds an earlier import).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Road selection: car, passenger, all, or a TOML profile file [default: car].
    #[arg(long, value_name = "NAME|FILE")]
    pub profile: Option<String>,

    /// Keep only what lies in this WGS84 box.
    #[arg(
        long,
        value_name = "MINLON,MINLAT,MAXLON,MAXLAT",
        conflicts_with = "clip_polygon"
    )]
    pub clip_bbox: Option<String>,

    /// Keep only what lies in this polygon (GeoJSON, or Osmosis .poly).
    #[arg(long, value_name = "FILE")]
    pub clip_polygon: Option<PathBuf>,

    /// Traffic side [default: from the map's location].
    #[arg(long, value_enum)]
    pub driving_side: Option<DrivingSideArg>,

    /// Where U-turns are allowed [default: dead-ends].
    #[arg(long, value_enum)]
    pub u_turns: Option<UTurnsArg>,

    /// Do not report untagged near-circular one-way loops as roundabouts.
    #[arg(long)]
    pub no_guess_roundabouts: bool,

    /// Check the map's invariants after every import step, not only at the end (slower;
    /// the tests always do).
    #[arg(long)]
    pub check_every_step: bool,

    /// Projection origin [default: centre of the selected roads; (0, 0) UTM for Lanelet2].
    #[arg(long, value_name = "LAT,LON")]
    pub origin: Option<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DrivingSideArg {
    Left,
    Right,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum UTurnsArg {
    Never,
    DeadEnds,
    Everywhere,
}

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// A map file (map.json or map.bin) or a map folder.
    pub map: PathBuf,

    /// Print the summary as JSON (the same keys as summary.json).
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct RouteArgs {
    /// A map file (map.json or map.bin) or a map folder.
    pub map: PathBuf,

    /// Start, in map metres `x,y` (or `lat,lon` with --lat-lon).
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    pub from: String,

    /// Destination, in map metres `x,y` (or `lat,lon` with --lat-lon).
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    pub to: String,

    /// --from and --to are WGS84 `lat,lon`.
    #[arg(long)]
    pub lat_lon: bool,

    /// Write the route here (.json, or .geojson for a LineString in WGS84) instead of printing it.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

/// `--on-error`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum OnErrorArg {
    /// Stop at the first broken item with its error; nothing is written.
    Fail,
    /// Leave broken items out; they are counted, listed and reported.
    Skip,
}

impl From<OnErrorArg> for datasets::error::OnError {
    fn from(a: OnErrorArg) -> Self {
        match a {
            OnErrorArg::Fail => datasets::error::OnError::Fail,
            OnErrorArg::Skip => datasets::error::OnError::Skip,
        }
    }
}

/// The command that `args` (the command line without the program's name) name, as far as
/// they name one: `pipeline agent eval` for `agent eval --episodes ten`.
fn command_named(args: &[String]) -> String {
    use clap::CommandFactory;
    let mut command = Cli::command();
    let mut path = vec![String::from("pipeline")];
    for arg in args.iter().filter(|a| !a.starts_with('-')) {
        let Some(sub) = command.find_subcommand(arg).cloned() else {
            continue;
        };
        path.push(sub.get_name().to_owned());
        command = sub;
        if !command.has_subcommands() {
            break;
        }
    }
    path.join(" ")
}

/// A command-line usage error (clap's) as every other error reads: one `error:` line with
/// the problem, then a `hint:` line (clap's tip, if it has one, and the command whose
/// `--help` lists the options). `args` is the command line without the program's name.
pub fn usage_error_text(err: &clap::Error, args: &[String]) -> String {
    let rendered = err.render().to_string();
    let mut problem: Vec<String> = Vec::new();
    let mut tips: Vec<String> = Vec::new();
    let mut command = command_named(args);
    for line in rendered.lines() {
        let text = line.trim();
        if let Some(rest) = text.strip_prefix("error: ") {
            problem.push(rest.to_owned());
        } else if let Some(tip) = text.strip_prefix("tip: ") {
            tips.push(tip.to_owned());
        } else if let Some(usage) = text.strip_prefix("Usage: ") {
            let words: Vec<&str> = usage
                .split_whitespace()
                .take_while(|w| !w.starts_with(['[', '<', '-']))
                .collect();
            if words.len() > command.split(' ').count() {
                command = words.join(" ");
            }
        } else if !text.is_empty() && !text.starts_with("For more information") {
            // The lines of a problem that spans several (the missing arguments).
            problem.push(text.to_owned());
        }
    }
    let problem = if problem.is_empty() {
        "the command line is not valid".to_owned()
    } else {
        problem.join(" ")
    };
    let help = format!("`{command} --help` lists the options");
    let hint = if tips.is_empty() {
        help
    } else {
        format!("{}; {help}", tips.join("; "))
    };
    format!("error: {problem}\nhint: {hint}\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rerun_modes() {
        assert_eq!(parse_rerun("save"), Ok(RerunMode::Save));
        assert_eq!(
            parse_rerun("connect"),
            Ok(RerunMode::Connect(DEFAULT_RERUN_URL.into()))
        );
        assert_eq!(
            parse_rerun("connect=127.0.0.1:9000"),
            Ok(RerunMode::Connect(
                "rerun+http://127.0.0.1:9000/proxy".into()
            ))
        );
        assert!(parse_rerun("connect=").is_err());
        assert!(parse_rerun("web").is_err());
    }

    #[test]
    fn global_options_before_and_after_the_command() -> Result<(), clap::Error> {
        let a = Cli::try_parse_from([
            "pipeline", "--seed", "7", "-q", "--rerun", "off", "map", "info", "m",
        ])?;
        assert_eq!((a.seed, a.quiet, a.rerun), (7, true, RerunMode::Off));
        let b = Cli::try_parse_from([
            "pipeline", "map", "import", "x.osm", "--out", "o", "-v", "--config", "c.toml",
        ])?;
        assert_eq!(b.verbosity(), Verbosity::Verbose);
        assert!(Cli::try_parse_from(["pipeline", "-v", "-q", "map", "info", "m"]).is_err());
        let r = Cli::try_parse_from([
            "pipeline", "map", "route", "m", "--from", "-1.5,2", "--to", "3,-4",
        ])?;
        let Group::Map {
            command: MapCommand::Route(r),
        } = r.command
        else {
            panic!("not a route")
        };
        assert_eq!((r.from.as_str(), r.to.as_str()), ("-1.5,2", "3,-4"));
        Ok(())
    }

    #[test]
    fn usage_errors_have_a_problem_line_and_a_hint() {
        let text = |args: &[&str]| match Cli::try_parse_from(args) {
            Ok(_) => panic!("{args:?} parsed"),
            Err(e) => {
                let rest: Vec<String> = args[1..].iter().map(|a| (*a).to_owned()).collect();
                usage_error_text(&e, &rest)
            }
        };
        let bad = text(&[
            "pipeline",
            "agent",
            "eval",
            "--agent",
            "a",
            "--episodes",
            "ten",
        ]);
        let lines: Vec<&str> = bad.lines().collect();
        assert_eq!(lines.len(), 2, "{bad}");
        assert!(
            lines[0].starts_with("error: invalid value 'ten' for '--episodes"),
            "{bad}"
        );
        assert_eq!(
            lines[1],
            "hint: `pipeline agent eval --help` lists the options"
        );
        let missing = text(&["pipeline", "map", "import"]);
        assert!(
            missing.starts_with("error: the following required arguments were not provided:"),
            "{missing}"
        );
        assert!(missing.contains("--out <DIR>"), "{missing}");
        assert!(
            missing.ends_with("hint: `pipeline map import --help` lists the options\n"),
            "{missing}"
        );
        let typo = text(&[
            "pipeline",
            "agent",
            "eval",
            "--agent",
            "a",
            "--episode",
            "3",
        ]);
        assert!(
            typo.contains("hint: ") && typo.contains("--episodes"),
            "{typo}"
        );
    }

    #[test]
    fn clap_definition_is_consistent() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }
}
