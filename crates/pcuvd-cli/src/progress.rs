//! Progress on stderr for the stages that take more than a moment.
//!
//! In a terminal, bars redraw in place; anywhere else (a log file, a notebook, `subprocess`, a job
//! scheduler) the same progress comes as plain lines on stderr: when a task starts, at most every
//! [`LOG_INTERVAL`] while it runs, and when it ends, each with the fraction done, the time elapsed
//! and an estimate of the time left. `--quiet` silences both.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use pcuvd::pipeline::Stage;

/// Time between two progress lines of a running task when stderr is not a terminal.
pub const LOG_INTERVAL: Duration = Duration::from_secs(5);

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
    Log(Mutex<LogState>),
    Quiet,
}

struct LogState {
    started: Instant,
    last_line: Option<Instant>,
    finished: bool,
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
        View::Log(Mutex::new(LogState {
            started: Instant::now(),
            last_line: None,
            finished: false,
        }))
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
            View::Log(state) => {
                let mut state = state.lock().unwrap_or_else(|e| e.into_inner());
                let due = state
                    .last_line
                    .is_none_or(|last| last.elapsed() >= LOG_INTERVAL);
                if due && !state.finished && done < self.total {
                    eprintln!("{}", self.line(done, state.started.elapsed()));
                    state.last_line = Some(Instant::now());
                }
            }
            View::Quiet => {}
        }
    }

    /// Reports the task complete (once; later calls do nothing).
    pub fn finish(&self) {
        match &self.view {
            View::Terminal(bar) => bar.finish(),
            View::Log(state) => {
                let mut state = state.lock().unwrap_or_else(|e| e.into_inner());
                if !state.finished {
                    state.finished = true;
                    eprintln!(
                        "{}: done, {} steps in {:.1} s",
                        self.label,
                        self.total,
                        state.started.elapsed().as_secs_f64()
                    );
                }
            }
            View::Quiet => {}
        }
    }

    /// "label: 40 % (4/10), 12 s elapsed, about 18 s left".
    fn line(&self, done: u64, elapsed: Duration) -> String {
        let fraction = done as f64 / self.total.max(1) as f64;
        let elapsed = elapsed.as_secs_f64();
        let left = if done > 0 {
            format!(
                ", about {:.0} s left",
                elapsed * (1.0 - fraction) / fraction
            )
        } else {
            String::new()
        };
        format!(
            "{}: {:.0} % ({done}/{}), {elapsed:.0} s elapsed{left}",
            self.label,
            100.0 * fraction,
            self.total
        )
    }
}

/// Progress of tasks named as they go (a study's [`pcuvd::study::Progress`]): one bar per task,
/// a new bar whenever the task label changes.
pub struct TaskProgress {
    bar: Mutex<Option<Bar>>,
}

impl Default for TaskProgress {
    fn default() -> Self {
        Self::new()
    }
}

impl TaskProgress {
    /// No bar until the first task reports.
    pub fn new() -> Self {
        TaskProgress {
            bar: Mutex::new(None),
        }
    }

    /// Reports that task `label` has done `done` of `total` steps.
    pub fn update(&self, label: &str, done: usize, total: usize) {
        let mut current = self.bar.lock().unwrap_or_else(|e| e.into_inner());
        if current.as_ref().is_none_or(|b| b.label() != label) {
            if let Some(previous) = current.take() {
                previous.finish();
            }
            *current = Some(bar(label, total as u64));
        }
        if let Some(bar) = current.as_ref() {
            bar.set_position(done as u64);
            if done == total {
                bar.finish();
            }
        }
    }
}

/// A callback for [`pcuvd::pipeline::process`] that shows one bar per stage. Stages interleave
/// (a block's decoding, then its beamforming, then the next block's; a long recording's segments
/// each run every stage), so each stage keeps its bar until its own work is done.
pub struct PipelineProgress {
    bars: Mutex<Vec<(Stage, Bar)>>,
    lines: MultiProgress,
    tag: String,
}

impl PipelineProgress {
    /// Bars prefixed by `tag` (e.g. the recording's name).
    pub fn new(tag: &str) -> Self {
        PipelineProgress {
            bars: Mutex::new(Vec::new()),
            lines: MultiProgress::new(),
            tag: tag.to_string(),
        }
    }

    /// Reports that `stage` has done `done` of `total` steps.
    pub fn update(&self, stage: Stage, done: usize, total: usize) {
        let mut bars = self.bars.lock().unwrap_or_else(|e| e.into_inner());
        let label = format!("{}{}", self.tag, stage.label());
        let index = match bars
            .iter()
            .position(|(s, b)| *s == stage && b.total == total as u64)
        {
            Some(index) => index,
            None => {
                // A stage that starts over with another count (a study's next recording) gets a
                // new bar.
                bars.retain(|(s, _)| *s != stage);
                bars.push((stage, bar_in(&label, total as u64, Some(&self.lines))));
                bars.len() - 1
            }
        };
        let bar = &bars[index].1;
        bar.set_position(done as u64);
        if done == total {
            bar.finish();
        }
    }
}
