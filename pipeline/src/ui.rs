//! Everything the binary shows a person: results on stdout, progress and log lines on
//! stderr, errors as one line plus a hint. The only module that prints, so the rest of the
//! code (and every library) stays quiet and testable.
//!
//! On a terminal, progress is an indicatif spinner that names the current step; otherwise
//! (CI, pipes, log files) each step is a plain line `[  1.2s] map import: step`, because
//! spinner redraws would fill a log with control characters.

#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::error::CliError;

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Verbosity {
    Quiet,
    Normal,
    Verbose,
}

#[derive(Debug)]
pub struct Ui {
    verbosity: Verbosity,
    terminal: bool,
    start: Instant,
}

impl Ui {
    pub fn new(verbosity: Verbosity) -> Self {
        Ui {
            verbosity,
            terminal: std::io::stderr().is_terminal(),
            start: Instant::now(),
        }
    }

    pub fn verbosity(&self) -> Verbosity {
        self.verbosity
    }

    /// A line of log on stderr, unless quiet.
    pub fn info(&self, message: &str) {
        if self.verbosity >= Verbosity::Normal {
            eprintln!("{}", self.stamp(message));
        }
    }

    /// A line of log shown only with -v.
    pub fn detail(&self, message: &str) {
        if self.verbosity >= Verbosity::Verbose {
            eprintln!("{}", self.stamp(message));
        }
    }

    /// A warning: shown unless quiet.
    pub fn warn(&self, message: &str) {
        if self.verbosity >= Verbosity::Normal {
            eprintln!("warning: {message}");
        }
    }

    /// A command's result, on stdout (always, even with -q: it is what was asked for).
    pub fn result(&self, text: &str) {
        if text.ends_with('\n') {
            print!("{text}");
        } else {
            println!("{text}");
        }
    }

    fn stamp(&self, message: &str) -> String {
        if self.terminal {
            message.to_owned()
        } else {
            format!("[{:>6.1}s] {message}", self.start.elapsed().as_secs_f64())
        }
    }

    /// Progress of one command: a spinner on a terminal, log lines otherwise.
    pub fn progress(&self, command: &str) -> Progress<'_> {
        let bar = if self.terminal && self.verbosity >= Verbosity::Normal {
            let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
            let style = ProgressStyle::with_template("{spinner} {prefix}: {wide_msg} [{elapsed}]")
                .unwrap_or_else(|_| ProgressStyle::default_spinner());
            bar.set_style(style);
            bar.set_prefix(command.to_owned());
            bar.enable_steady_tick(Duration::from_millis(100));
            Some(bar)
        } else {
            None
        };
        Progress {
            ui: self,
            command: command.to_owned(),
            bar,
            step_start: Instant::now(),
        }
    }
}

/// The steps of one command. Dropping it clears the spinner.
#[derive(Debug)]
pub struct Progress<'a> {
    ui: &'a Ui,
    command: String,
    bar: Option<ProgressBar>,
    step_start: Instant,
}

impl Progress<'_> {
    /// Starts a step; with -v the time of the previous one is logged.
    pub fn step(&mut self, message: &str) {
        let elapsed = self.step_start.elapsed();
        self.step_start = Instant::now();
        if let Some(bar) = &self.bar {
            bar.set_message(message.to_owned());
            if self.ui.verbosity >= Verbosity::Verbose {
                bar.println(format!(
                    "{}: {message} (previous step {:.2}s)",
                    self.command,
                    elapsed.as_secs_f64()
                ));
            }
        } else if self.ui.verbosity >= Verbosity::Verbose {
            self.ui.info(&format!(
                "{}: {message} (previous step {:.2}s)",
                self.command,
                elapsed.as_secs_f64()
            ));
        } else {
            self.ui.info(&format!("{}: {message}", self.command));
        }
    }

    /// Reports that `done` of `total` items of the current step are finished: the
    /// spinner's message on a terminal, otherwise a log line each tenth of the way. Takes
    /// `&self`, so parallel workers can call it with their own counts.
    pub fn items(&self, what: &str, done: u64, total: u64) {
        match &self.bar {
            Some(bar) => bar.set_message(format!("{what} {done}/{total}")),
            None if total > 0 && done > 0 && done * 10 / total > (done - 1) * 10 / total => {
                self.ui
                    .info(&format!("{}: {what} {done}/{total}", self.command));
            }
            None => {}
        }
    }

    /// A line that stays (above the spinner on a terminal).
    pub fn note(&self, message: &str) {
        if self.ui.verbosity < Verbosity::Normal {
            return;
        }
        match &self.bar {
            Some(bar) => bar.println(format!("{}: {message}", self.command)),
            None => self.ui.info(&format!("{}: {message}", self.command)),
        }
    }
}

impl Drop for Progress<'_> {
    fn drop(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

/// Prints an error as `error: <what>: <problem>` on one line, then `hint: ...` when one is
/// known. With -v the chain of causes follows, one per line.
pub fn report_error(err: &anyhow::Error, verbosity: Verbosity) {
    let one_line = |s: String| s.split_whitespace().collect::<Vec<_>>().join(" ");
    eprintln!("error: {}", one_line(format!("{err:#}")));
    let hint = err
        .chain()
        .find_map(|e| e.downcast_ref::<CliError>())
        .and_then(|e| e.hint.clone());
    if let Some(hint) = hint {
        eprintln!("hint: {hint}");
    }
    if verbosity >= Verbosity::Verbose && err.chain().count() > 1 {
        for (i, cause) in err.chain().enumerate() {
            eprintln!("  {i}: {cause}");
        }
    }
}
