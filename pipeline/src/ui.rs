//! Everything the binary shows a person: results on stdout, progress and log lines on
//! stderr, errors as one line plus a hint. The only module that prints, so the rest of the
//! code (and every library) stays quiet and testable: libraries emit `tracing` events (and
//! burn or the rerun SDK `log` records), which [`init_logging`] shows here.
//!
//! On a terminal, progress is an indicatif bar: a counted bar (position, total, rate, ETA,
//! and figures such as a training loss) for work that can be counted, a spinner naming the
//! current step otherwise; log lines are printed above the bars, so neither garbles the
//! other. Off a terminal (CI, pipes, log files) each step is a plain line
//! `[  1.2s] map import: step`, and counted work adds a line each tenth of the way, because
//! bar redraws would fill a log with control characters.
//!
//! Verbosity: `-q` errors only; by default warnings and our crates' info lines; `-v` our
//! crates' debug lines (step timings); `-vv` their trace lines and other crates' info;
//! `RUST_LOG` (tracing's env-filter syntax) overrides all of these.

#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::fmt;
use std::io::{IsTerminal, Write};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use tracing::{Event, Level, Subscriber};
use tracing_log::NormalizeEvent;
use tracing_subscriber::EnvFilter;
use tracing_subscriber::fmt::format::Writer;
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields, MakeWriter};
use tracing_subscriber::registry::LookupSpan;
use tracing_subscriber::util::SubscriberInitExt;

use crate::error::CliError;

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Verbosity {
    Quiet,
    Normal,
    Verbose,
    /// `-vv`: trace lines of our crates, info lines of the others.
    Trace,
}

/// The crates whose info lines are shown by default (targets start with these names).
const OUR_CRATES: [&str; 5] = ["pipeline", "maps", "sim", "datasets", "models"];

/// The target of the lines [`Ui`] logs.
const UI_TARGET: &str = "pipeline";

/// The terminal's progress bars; log lines are printed above them.
static BARS: OnceLock<MultiProgress> = OnceLock::new();

fn bars() -> &'static MultiProgress {
    BARS.get_or_init(|| MultiProgress::with_draw_target(ProgressDrawTarget::stderr()))
}

/// The filter of a verbosity, in `RUST_LOG` syntax.
pub fn default_filter(verbosity: Verbosity) -> String {
    let (ours, others) = match verbosity {
        Verbosity::Quiet => ("error", "error"),
        Verbosity::Normal => ("info", "warn"),
        Verbosity::Verbose => ("debug", "warn"),
        Verbosity::Trace => ("trace", "info"),
    };
    let mut filter = others.to_owned();
    for name in OUR_CRATES {
        filter.push_str(&format!(",{name}={ours}"));
    }
    filter
}

/// Shows `tracing` events (and `log` records, through the bridge) on stderr, above the
/// progress bars, filtered by `verbosity` or by `RUST_LOG` when it is set. Call it once, first
/// thing; a second call changes nothing.
pub fn init_logging(verbosity: Verbosity) {
    let filter = match std::env::var("RUST_LOG") {
        Ok(spec) if !spec.trim().is_empty() => EnvFilter::try_new(spec.trim()),
        _ => EnvFilter::try_new(default_filter(verbosity)),
    }
    .unwrap_or_else(|e| {
        eprintln!("warning: RUST_LOG: {e}; using the default filter");
        EnvFilter::new(default_filter(verbosity))
    });
    let stamp = !std::io::stderr().is_terminal();
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(AboveBars)
        .with_ansi(false)
        .event_format(Lines {
            start: Instant::now(),
            stamp,
        })
        .finish()
        .try_init();
}

/// How a log line looks: `warning: ...` and `error: ...` for those levels, plain lines (with
/// the time since the start off a terminal) for the others; lines of other crates name
/// their target.
struct Lines {
    start: Instant,
    stamp: bool,
}

impl<S, N> FormatEvent<S, N> for Lines
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &FmtContext<'_, S, N>,
        mut writer: Writer<'_>,
        event: &Event<'_>,
    ) -> fmt::Result {
        let normalized = event.normalized_metadata();
        let meta = normalized.as_ref().unwrap_or_else(|| event.metadata());
        match *meta.level() {
            Level::ERROR => write!(writer, "error: ")?,
            Level::WARN => write!(writer, "warning: ")?,
            _ if self.stamp => write!(writer, "{}", stamp(self.start.elapsed()))?,
            _ => {}
        }
        let target = meta.target();
        let ours = OUR_CRATES
            .iter()
            .any(|c| target == *c || target.starts_with(&format!("{c}::")));
        if !ours {
            write!(writer, "{target}: ")?;
        }
        ctx.field_format().format_fields(writer.by_ref(), event)?;
        writeln!(writer)
    }
}

fn stamp(elapsed: Duration) -> String {
    format!("[{:>6.1}s] ", elapsed.as_secs_f64())
}

/// Writes each log line in one piece, with the progress bars cleared meanwhile.
struct AboveBars;

impl<'a> MakeWriter<'a> for AboveBars {
    type Writer = LineBuffer;

    fn make_writer(&'a self) -> LineBuffer {
        LineBuffer(Vec::new())
    }
}

/// One event's text, written to stderr when dropped.
struct LineBuffer(Vec<u8>);

impl Write for LineBuffer {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for LineBuffer {
    fn drop(&mut self) {
        if self.0.is_empty() {
            return;
        }
        let write = || {
            let _ = std::io::stderr().lock().write_all(&self.0);
        };
        match BARS.get() {
            Some(bars) => bars.suspend(write),
            None => write(),
        }
    }
}

#[derive(Debug)]
pub struct Ui {
    verbosity: Verbosity,
    terminal: bool,
}

impl Ui {
    pub fn new(verbosity: Verbosity) -> Self {
        Ui {
            verbosity,
            terminal: std::io::stderr().is_terminal(),
        }
    }

    pub fn verbosity(&self) -> Verbosity {
        self.verbosity
    }

    /// A line of log on stderr, unless quiet.
    pub fn info(&self, message: &str) {
        tracing::info!(target: UI_TARGET, "{message}");
    }

    /// A line of log shown only with -v.
    pub fn detail(&self, message: &str) {
        tracing::debug!(target: UI_TARGET, "{message}");
    }

    /// A warning: shown unless quiet.
    pub fn warn(&self, message: &str) {
        tracing::warn!(target: UI_TARGET, "{message}");
    }

    /// A command's result, on stdout (always, even with -q: it is what was asked for). When
    /// stdout is closed (`pipeline ... | head -1`), the command ends quietly with exit code
    /// 0, as other Unix tools do.
    pub fn result(&self, text: &str) {
        let write = || {
            let mut out = std::io::stdout().lock();
            out.write_all(text.as_bytes())
                .and_then(|()| {
                    if text.ends_with('\n') {
                        Ok(())
                    } else {
                        out.write_all(b"\n")
                    }
                })
                .and_then(|()| out.flush())
        };
        // A bar still drawn on the same terminal is cleared meanwhile.
        let written = match BARS.get() {
            Some(bars) => bars.suspend(write),
            None => write(),
        };
        match written {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
                // Nobody reads any more: the rest of the output is not wanted.
                std::process::exit(0);
            }
            Err(e) => {
                eprintln!("error: cannot write the result to stdout: {e}");
                std::process::exit(1);
            }
        }
    }

    /// Progress of one command: a bar or spinner on a terminal, log lines otherwise.
    pub fn progress(&self, command: &str) -> Progress<'_> {
        let shown = self.terminal && self.verbosity >= Verbosity::Normal;
        let bar = if shown {
            let bar = bars().add(ProgressBar::no_length());
            bar.set_style(spinner_style());
            bar.set_prefix(command.to_owned());
            bar.enable_steady_tick(Duration::from_millis(100));
            bar
        } else {
            // Not drawn; it keeps the position, rate and ETA for the log lines.
            ProgressBar::hidden()
        };
        Progress {
            ui: self,
            command: command.to_owned(),
            bar,
            shown,
            step_start: Instant::now(),
            counted: Mutex::new(Counted::default()),
            logged_tenths: AtomicU64::new(0),
        }
    }
}

fn spinner_style() -> ProgressStyle {
    ProgressStyle::with_template("{spinner} {prefix}: {wide_msg} [{elapsed}]")
        .unwrap_or_else(|_| ProgressStyle::default_spinner())
}

fn bar_style() -> ProgressStyle {
    ProgressStyle::with_template(
        "{spinner} {prefix} {bar:28.cyan/blue} {human_pos}/{human_len}{msg} [{elapsed} < {eta}, {per_sec:1}]",
    )
    .unwrap_or_else(|_| ProgressStyle::default_bar())
    .progress_chars("█▌░")
}

/// The counted work in progress, if any.
#[derive(Debug, Default)]
struct Counted {
    /// What is being done (`training`), and the unit counted (`steps`).
    what: String,
    unit: String,
    /// Figures shown with the position (`loss 0.41, val mIoU 0.52`).
    figures: String,
    active: bool,
}

/// The steps of one command. Dropping it clears its bar.
#[derive(Debug)]
pub struct Progress<'a> {
    ui: &'a Ui,
    command: String,
    bar: ProgressBar,
    /// Whether the bar is drawn (a terminal, not quiet).
    shown: bool,
    step_start: Instant,
    counted: Mutex<Counted>,
    /// Tenths of the counted work already logged (off a terminal).
    logged_tenths: AtomicU64,
}

impl Progress<'_> {
    /// Starts a step that is not counted (a spinner); with -v the time of the previous one
    /// is logged.
    pub fn step(&mut self, message: &str) {
        let elapsed = self.step_start.elapsed();
        self.step_start = Instant::now();
        if let Ok(mut counted) = self.counted.lock()
            && counted.active
        {
            *counted = Counted::default();
            self.bar.set_style(spinner_style());
            self.bar.unset_length();
            self.bar.set_position(0);
        }
        self.bar.set_message(message.to_owned());
        if self.ui.verbosity >= Verbosity::Verbose {
            self.ui.info(&format!(
                "{}: {message} (previous step {:.2}s)",
                self.command,
                elapsed.as_secs_f64()
            ));
        } else if !self.shown {
            self.ui.info(&format!("{}: {message}", self.command));
        }
    }

    /// Starts counted work: `total` `unit` of `what` (`counted("training", 600, "steps")`):
    /// a bar with position, rate and ETA on a terminal, a line now and then a line each tenth
    /// of the way otherwise. Move it with [`set_position`](Self::set_position) or
    /// [`inc`](Self::inc).
    pub fn counted(&mut self, what: &str, total: u64, unit: &str) {
        self.counted_with(what, total, unit, "");
    }

    /// [`counted`](Self::counted), with `about` after the announced count (`training 600
    /// steps (3 epochs of 200 batches)`).
    pub fn counted_with(&mut self, what: &str, total: u64, unit: &str, about: &str) {
        let mut line = join(&join(what, &total.to_string()), unit);
        if !about.is_empty() {
            line.push_str(&format!(" ({about})"));
        }
        self.step(&line);
        self.start_counting(what, unit, total, 0);
    }

    fn start_counting(&self, what: &str, unit: &str, total: u64, position: u64) {
        if let Ok(mut counted) = self.counted.lock() {
            *counted = Counted {
                what: what.to_owned(),
                unit: unit.to_owned(),
                figures: String::new(),
                active: true,
            };
        }
        self.bar.set_style(bar_style());
        self.bar.set_prefix(format!("{}: {what}", self.command));
        self.bar.set_message(bar_message(unit, ""));
        self.bar.set_length(total);
        self.bar.set_position(position);
        self.bar.reset_eta();
        self.logged_tenths
            .store(tenths(position, total), Ordering::Relaxed);
    }

    /// Goes back to counted work that another counted step interrupted (`training`, after a
    /// validation), at `done` of `total`: no new line, and the rate and ETA count from here.
    pub fn count_again(&self, what: &str, total: u64, unit: &str, done: u64) {
        self.start_counting(what, unit, total, done);
    }

    /// Starts the counted work at `done` (a resumed run): the rate and ETA count from here.
    pub fn resume_at(&self, done: u64) {
        self.bar.set_position(done);
        self.bar.reset_eta();
        let total = self.bar.length().unwrap_or(0);
        self.logged_tenths
            .store(tenths(done, total), Ordering::Relaxed);
    }

    /// The total of the counted work, when it changes on the way.
    pub fn set_length(&self, total: u64) {
        self.bar.set_length(total);
    }

    /// `done` items of the counted work are finished. Takes `&self`, so parallel workers
    /// can call it.
    pub fn set_position(&self, done: u64) {
        self.bar.set_position(done);
        self.log_tenth();
    }

    /// `n` more items are finished.
    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
        self.log_tenth();
    }

    /// Figures shown beside the position (a loss, a metric), on the bar and in the log lines.
    pub fn set_figures(&self, figures: &str) {
        let unit = match self.counted.lock() {
            Ok(mut counted) => {
                counted.figures = figures.to_owned();
                counted.unit.clone()
            }
            Err(_) => String::new(),
        };
        self.bar.set_message(bar_message(&unit, figures));
    }

    /// Reports that `done` of `total` items of `what` are finished (the current step's
    /// counted work): the bar on a terminal, otherwise a log line each tenth of the way.
    /// Takes `&self`, so parallel workers can call it with their own counts.
    pub fn items(&self, what: &str, done: u64, total: u64) {
        let same = self
            .counted
            .lock()
            .is_ok_and(|c| c.active && c.what == what && self.bar.length() == Some(total));
        if !same {
            self.start_counting(what, "", total, 0);
        }
        self.bar.set_position(done);
        self.log_tenth();
    }

    /// Off a terminal: a line when the counted work passes another tenth of the way.
    fn log_tenth(&self) {
        if self.shown || self.ui.verbosity < Verbosity::Normal {
            return;
        }
        let Some(total) = self.bar.length().filter(|&t| t > 0) else {
            return;
        };
        let done = self.bar.position().min(total);
        let tenth = tenths(done, total);
        let logged = self.logged_tenths.load(Ordering::Relaxed);
        if tenth <= logged
            || self
                .logged_tenths
                .compare_exchange(logged, tenth, Ordering::Relaxed, Ordering::Relaxed)
                .is_err()
        {
            return;
        }
        let (what, unit, figures) = match self.counted.lock() {
            Ok(c) => (c.what.clone(), c.unit.clone(), c.figures.clone()),
            Err(_) => Default::default(),
        };
        let rate = if done < total {
            format!(
                " ({}, ETA {})",
                rate(self.bar.per_sec()),
                human_duration(self.bar.eta())
            )
        } else {
            format!(" ({})", rate(self.bar.per_sec()))
        };
        let figures = if figures.is_empty() {
            String::new()
        } else {
            format!(", {figures}")
        };
        self.ui.info(&format!(
            "{}: {}{rate}{figures}",
            self.command,
            join(&join(&what, &format!("{done}/{total}")), &unit)
        ));
    }

    /// A line that stays (above the bar on a terminal).
    pub fn note(&self, message: &str) {
        self.ui.info(&format!("{}: {message}", self.command));
    }

    /// A line shown only with -v (timings, per-step figures).
    pub fn detail(&self, message: &str) {
        self.ui.detail(&format!("{}: {message}", self.command));
    }
}

impl Drop for Progress<'_> {
    fn drop(&mut self) {
        if self.shown {
            self.bar.finish_and_clear();
            bars().remove(&self.bar);
        }
    }
}

fn tenths(done: u64, total: u64) -> u64 {
    (done.min(total) * 10).checked_div(total).unwrap_or(0)
}

/// The counted bar's text after the position: ` steps, loss 0.41`, or nothing.
fn bar_message(unit: &str, figures: &str) -> String {
    match (unit.is_empty(), figures.is_empty()) {
        (true, true) => String::new(),
        (false, true) => format!(" {unit}"),
        (true, false) => format!(" {figures}"),
        (false, false) => format!(" {unit}, {figures}"),
    }
}

fn join(a: &str, b: &str) -> String {
    match (a.is_empty(), b.is_empty()) {
        (true, _) => b.to_owned(),
        (_, true) => a.to_owned(),
        _ => format!("{a} {b}"),
    }
}

/// `12.3/s`, or `4.0 s each` when slower than one a second.
fn rate(per_sec: f64) -> String {
    if !per_sec.is_finite() || per_sec <= 0.0 {
        "starting".to_owned()
    } else if per_sec >= 1.0 {
        format!("{per_sec:.1}/s")
    } else {
        format!("{:.1} s each", 1.0 / per_sec)
    }
}

/// `45 s`, `3 min 20 s`, `2 h 05 min`.
pub fn human_duration(d: Duration) -> String {
    let s = d.as_secs();
    if s < 60 {
        format!("{s} s")
    } else if s < 3600 {
        format!("{} min {:02} s", s / 60, s % 60)
    } else {
        format!("{} h {:02} min", s / 3600, s % 3600 / 60)
    }
}

/// `1 image`, `2 images`: a count and its noun, plural unless the count is one.
pub fn plural(n: usize, noun: &str) -> String {
    if n == 1 {
        format!("1 {noun}")
    } else if let Some(stem) = noun.strip_suffix('y')
        && !stem.ends_with(['a', 'e', 'o', 'u'])
    {
        format!("{n} {stem}ies")
    } else if noun.ends_with(['s', 'x', 'z']) || noun.ends_with("tch") || noun.ends_with("sh") {
        format!("{n} {noun}es")
    } else {
        format!("{n} {noun}s")
    }
}

/// Prints an error as `error: <what>: <problem>` on one line, then `hint: ...` when one is
/// known. With -v the chain of causes follows, one per line.
pub fn report_error(err: &anyhow::Error, verbosity: Verbosity) {
    let one_line = |s: String| s.split_whitespace().collect::<Vec<_>>().join(" ");
    let mut text = format!("error: {}\n", one_line(format!("{err:#}")));
    let hint = err
        .chain()
        .find_map(|e| e.downcast_ref::<CliError>())
        .and_then(|e| e.hint.clone());
    if let Some(hint) = hint {
        text.push_str(&format!("hint: {hint}\n"));
    }
    if verbosity >= Verbosity::Verbose && err.chain().count() > 1 {
        for (i, cause) in err.chain().enumerate() {
            text.push_str(&format!("  {i}: {cause}\n"));
        }
    }
    let write = || eprint!("{text}");
    match BARS.get() {
        Some(bars) => bars.suspend(write),
        None => write(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plurals() {
        assert_eq!(plural(1, "image"), "1 image");
        assert_eq!(plural(0, "image"), "0 images");
        assert_eq!(plural(3, "entry"), "3 entries");
        assert_eq!(plural(2, "day"), "2 days");
        assert_eq!(plural(4, "batch"), "4 batches");
        assert_eq!(plural(2, "epoch"), "2 epochs");
    }

    #[test]
    fn durations_and_rates_read_as_words() {
        assert_eq!(human_duration(Duration::from_secs(45)), "45 s");
        assert_eq!(human_duration(Duration::from_secs(200)), "3 min 20 s");
        assert_eq!(human_duration(Duration::from_secs(7500)), "2 h 05 min");
        assert_eq!(rate(12.34), "12.3/s");
        assert_eq!(rate(0.25), "4.0 s each");
        assert_eq!(rate(0.0), "starting");
    }

    #[test]
    fn filters_show_our_lines_by_verbosity() {
        assert!(default_filter(Verbosity::Normal).starts_with("warn,pipeline=info"));
        assert!(default_filter(Verbosity::Quiet).contains("models=error"));
        assert!(default_filter(Verbosity::Verbose).contains("datasets=debug"));
        for v in [
            Verbosity::Quiet,
            Verbosity::Normal,
            Verbosity::Verbose,
            Verbosity::Trace,
        ] {
            assert!(EnvFilter::try_new(default_filter(v)).is_ok());
        }
    }

    #[test]
    fn tenths_of_the_way() {
        assert_eq!(tenths(0, 300), 0);
        assert_eq!(tenths(29, 300), 0);
        assert_eq!(tenths(30, 300), 1);
        assert_eq!(tenths(300, 300), 10);
        assert_eq!(tenths(5, 0), 0);
    }
}
