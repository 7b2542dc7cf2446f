//! The options every command takes (`--seed`, `--rerun`, `--device`, ...) and the value types
//! several commands share. [`crate::cli::Cli`] flattens [`GlobalArgs`] into the command line;
//! commands see it through [`crate::context::Context`].

use std::path::PathBuf;

use clap::Args;

use crate::ui::Verbosity;

/// The global options: they may stand before or after the group and command (clap's `global`).
#[derive(Debug, Clone, Args)]
pub struct GlobalArgs {
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
}

impl GlobalArgs {
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
}
