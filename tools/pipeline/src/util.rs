//! Small shared helpers of the pipeline: progress reports and how much the commands say.
//!
//! On a terminal, progress is an indicatif bar. When stderr is not a terminal (a batch job's
//! log, a pipe), the bar would print nothing, so a line is printed instead at most every
//! [`PROGRESS_SECONDS_VAR`] seconds (default 10): how far, how long, and about how long is left.
//!
//! [`Verbosity`] (`-q` / `-v` on the command line) decides whether progress is shown. What a
//! stage did is a `log` event, not a print: `log::info!` for the notes, `log::debug!` for each
//! stage's wall time. Warnings go through [`warn`]: `warning: ...` on stderr, where a user must
//! see them whatever the logger. The CLI installs the logger that prints the rest
//! (`biscale-cli`'s `StderrLog`: `-q` keeps warnings only, `-v` adds the stage times); a
//! program using this crate as a library hears nothing unless it installs its own.
//!
//! A host with its own logging (the Python module) calls [`report_through_log`]: warnings
//! become `log::warn!` records and progress becomes `log::info!` lines (target
//! `biscale::progress`, at most every [`PROGRESS_SECONDS_VAR`] seconds), with no bar.

use indicatif::{ProgressBar, ProgressStyle};
use std::fmt::Display;
use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How much the commands print on stderr besides warnings and errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Verbosity {
    /// `-q`: warnings and errors only.
    Quiet,
    /// Progress and one note per stage (the default).
    Normal,
    /// `-v`: also each stage's wall time as it ends.
    Verbose,
}

static VERBOSITY: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(1);

/// Set the process's verbosity (once, from the command line).
pub fn set_verbosity(v: Verbosity) {
    VERBOSITY.store(v as u8, std::sync::atomic::Ordering::Relaxed);
}

/// The process's verbosity.
pub fn verbosity() -> Verbosity {
    match VERBOSITY.load(std::sync::atomic::Ordering::Relaxed) {
        0 => Verbosity::Quiet,
        1 => Verbosity::Normal,
        _ => Verbosity::Verbose,
    }
}

static THROUGH_LOG: AtomicBool = AtomicBool::new(false);

/// Send warnings and progress through the `log` facade instead of stderr, for a host with its
/// own logging (the Python module: `logging`); see the module docs.
pub fn report_through_log(on: bool) {
    THROUGH_LOG.store(on, Ordering::Relaxed);
}

fn through_log() -> bool {
    THROUGH_LOG.load(Ordering::Relaxed)
}

/// A warning the user must see: `warning: {msg}` on stderr, or a `log::warn!` record after
/// [`report_through_log`].
pub fn warn(msg: impl Display) {
    match through_log() {
        true => log::warn!("{msg}"),
        false => eprintln!("warning: {msg}"),
    }
}

/// A line a batch log must hold whatever the logger (the memory estimate): stderr, or a
/// `log::info!` record after [`report_through_log`].
pub fn note(msg: impl Display) {
    match through_log() {
        true => log::info!("{msg}"),
        false => eprintln!("{msg}"),
    }
}

/// One progress line: stderr, or a `log::info!` record (target `biscale::progress`).
fn progress_line(line: impl Display) {
    match through_log() {
        true => log::info!(target: "biscale::progress", "{line}"),
        false => eprintln!("{line}"),
    }
}

/// Environment variable: seconds between progress lines when stderr is not a terminal.
pub const PROGRESS_SECONDS_VAR: &str = "BISCALE_PROGRESS_SECONDS";

/// Progress of `len` steps of one stage (a bar, or lines in logs).
pub struct Progress {
    bar: ProgressBar,
    lines: Option<Lines>,
}

struct Lines {
    what: String,
    len: u64,
    start: Instant,
    every: Duration,
    /// When the last line was printed, and whether any was.
    last: Mutex<(Instant, bool)>,
}

/// A progress report for `len` steps of `what`, on stderr.
pub fn progress_bar(len: u64, what: &str) -> Progress {
    if verbosity() == Verbosity::Quiet {
        return Progress { bar: ProgressBar::hidden(), lines: None };
    }
    let bar = match through_log() {
        true => ProgressBar::hidden(),
        false => ProgressBar::new(len),
    };
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} ({elapsed} < {eta})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    let lines = (through_log() || !std::io::stderr().is_terminal()).then(|| {
        let every = std::env::var(PROGRESS_SECONDS_VAR).ok().and_then(|s| s.parse::<f64>().ok()).unwrap_or(10.0);
        let now = Instant::now();
        Lines {
            what: what.to_string(),
            len,
            start: now,
            every: Duration::from_secs_f64(every.clamp(0.0, 1e6)),
            last: Mutex::new((now, false)),
        }
    });
    Progress { bar, lines }
}

impl Progress {
    /// `pos` of the stage's steps are done (callable from any thread).
    pub fn set_position(&self, pos: u64) {
        self.bar.set_position(pos);
        if let Some(l) = &self.lines {
            let mut last = l.last.lock().unwrap_or_else(|e| e.into_inner());
            if last.0.elapsed() >= l.every {
                *last = (Instant::now(), true);
                progress_line(l.line(pos));
            }
        }
    }

    /// The stage is over: the bar goes; in logs that saw a progress line, a last one says so.
    pub fn finish_and_clear(&self) {
        self.bar.finish_and_clear();
        if let Some(l) = &self.lines {
            let last = l.last.lock().unwrap_or_else(|e| e.into_inner());
            if last.1 {
                progress_line(format_args!("{}: done in {:.1} s", l.what, l.start.elapsed().as_secs_f64()));
            }
        }
    }
}

impl Lines {
    fn line(&self, pos: u64) -> String {
        let secs = self.start.elapsed().as_secs_f64();
        let frac = pos as f64 / self.len.max(1) as f64;
        let left = match frac > 0.0 && frac < 1.0 {
            true => format!(", about {:.0} s left", secs * (1.0 - frac) / frac),
            false => String::new(),
        };
        format!("{}: {pos}/{} ({:.0}%), {secs:.1} s{left}", self.what, self.len, 100.0 * frac)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_lines_say_how_far_and_how_long_is_left() {
        let l = Lines {
            what: "transfer".into(),
            len: 200,
            start: Instant::now() - Duration::from_secs(10),
            every: Duration::ZERO,
            last: Mutex::new((Instant::now(), false)),
        };
        let line = l.line(50);
        assert!(line.starts_with("transfer: 50/200 (25%), 10.0 s, about 30 s left"), "{line}");
        assert_eq!(l.line(200), "transfer: 200/200 (100%), 10.0 s");
    }
}
