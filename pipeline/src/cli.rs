//! The command line, as in ARCHITECTURE.md:
//!
//! ```text
//! pipeline [--config FILE] [--run-dir DIR] [--seed N] [-v | -q] [--rerun save|spawn|connect[=ADDR]|off] <group> <command>
//! ```
//!
//! Global options may also follow the group or command (clap's `global`), so
//! `pipeline map import x.osm --out o -q` works as well. Only commands that work exist.

use clap::{Parser, Subcommand};

use crate::args::{DeviceArg, GlobalArgs};
use crate::commands::map::args::MapCommand;

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
    #[command(flatten)]
    pub global: GlobalArgs,

    #[command(subcommand)]
    pub command: Group,
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
/// reaches [`GlobalArgs::device`] wherever it is written.
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
    fn global_options_before_and_after_the_command() -> Result<(), clap::Error> {
        let a = Cli::try_parse_from([
            "pipeline", "--seed", "7", "-q", "--rerun", "off", "map", "info", "m",
        ])?;
        assert_eq!(
            (a.global.seed, a.global.quiet, a.global.rerun),
            (7, true, crate::args::RerunMode::Off)
        );
        let b = Cli::try_parse_from([
            "pipeline", "map", "import", "x.osm", "--out", "o", "-v", "--config", "c.toml",
        ])?;
        assert_eq!(b.global.verbosity(), crate::ui::Verbosity::Verbose);
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
