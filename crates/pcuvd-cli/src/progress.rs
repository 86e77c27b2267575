//! Progress on stderr for the stages that take more than a moment.
//!
//! In a terminal, bars redraw in place; anywhere else (a log file, a notebook, `subprocess`, a job
//! scheduler) the same progress comes as plain lines on stderr: when a task starts, at most every
//! [`LOG_INTERVAL`] while it runs, and when it ends, each with the fraction done, the time elapsed
//! and an estimate of the time left. `--quiet` silences both.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use pcuvd_app::progress::LogLine;

pub use pcuvd_app::progress::LOG_INTERVAL;

static QUIET: AtomicBool = AtomicBool::new(false);

/// Silences every progress report of this process (`--quiet`).
pub fn set_quiet(quiet: bool) {
    QUIET.store(quiet, Ordering::Relaxed);
}

/// Progress of one task of `total` steps, shown as a bar in a terminal and as log lines elsewhere.
pub struct Bar {
    label: String,
    total: u64,
    view: View,
}

enum View {
    Terminal(ProgressBar),
    Log(LogLine),
    Quiet,
}

/// A progress report of `total` steps labelled `label`, on stderr.
pub fn bar(label: &str, total: u64) -> Bar {
    bar_in(label, total, None)
}

/// As [`bar`]; in a terminal, drawn in `lines` beside the other bars there.
fn bar_in(label: &str, total: u64, lines: Option<&MultiProgress>) -> Bar {
    let view = if QUIET.load(Ordering::Relaxed) {
        View::Quiet
    } else if std::io::stderr().is_terminal() {
        let bar = match lines {
            Some(lines) => lines.add(ProgressBar::new(total)),
            None => ProgressBar::new(total),
        };
        bar.set_style(
            ProgressStyle::with_template("{prefix:>24} [{bar:32}] {pos}/{len} {elapsed_precise}")
                .expect("static template")
                .progress_chars("=> "),
        );
        bar.set_prefix(label.to_string());
        View::Terminal(bar)
    } else {
        View::Log(LogLine::new(label, total))
    };
    Bar {
        label: label.to_string(),
        total,
        view,
    }
}

impl Bar {
    /// The task's label.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// Reports that `done` of the task's steps are done.
    pub fn set_position(&self, done: u64) {
        match &self.view {
            View::Terminal(bar) => bar.set_position(done),
            View::Log(line) => line.set_position(done),
            View::Quiet => {}
        }
    }

    /// Reports the task complete (once; later calls do nothing).
    pub fn finish(&self) {
        match &self.view {
            View::Terminal(bar) => bar.finish(),
            View::Log(line) => line.finish(),
            View::Quiet => {}
        }
    }
}

/// Progress on stderr for every task of a run (pipeline stages, simulations, studies): one bar
/// per task. Tasks interleave (a block's decoding, then its beamforming, then the next block's;
/// a long recording's segments each run every stage), so each task keeps its bar until its own
/// work is done; a task that starts over with another count (a study's next recording) gets a
/// new bar.
pub struct Bars {
    bars: Mutex<Vec<Bar>>,
    lines: MultiProgress,
    tag: String,
}

impl Bars {
    /// Bars labelled with `tag` (e.g. the recording's name) before each task's name.
    pub fn new(tag: &str) -> Self {
        Bars {
            bars: Mutex::new(Vec::new()),
            lines: MultiProgress::new(),
            tag: tag.to_string(),
        }
    }
}

impl pcuvd_app::Progress for Bars {
    fn update(&self, task: &str, done: usize, total: usize) {
        let mut bars = self.bars.lock().unwrap_or_else(|e| e.into_inner());
        let label = format!("{}{}", self.tag, task);
        let index = match bars
            .iter()
            .position(|b| b.label == label && b.total == total as u64)
        {
            Some(index) => index,
            None => {
                bars.retain(|b| b.label != label);
                bars.push(bar_in(&label, total as u64, Some(&self.lines)));
                bars.len() - 1
            }
        };
        let bar = &bars[index];
        bar.set_position(done as u64);
        if done == total {
            bar.finish();
        }
    }
}
