//! How long work reports its progress, and the lines meant for the person who runs it: one
//! trait for every front end (bars in a terminal, log lines, Python, nothing at all).

use std::sync::Mutex;
use std::time::{Duration, Instant};

use pcuvd::pipeline::Stage;

/// Where a run reports how far it has got and what a person should read.
pub trait Progress: Sync {
    /// `done` of `total` steps of `task` are complete. `task` names a pipeline stage
    /// ([`Stage::label`]) or a step of a simulation or study.
    fn update(&self, task: &str, done: usize, total: usize);

    /// A remark the person running should see, such as a stage skipped and why.
    fn note(&self, text: &str) {
        eprintln!("note: {text}");
    }

    /// A line that says what was done (a result's summary), for a person reading the output.
    fn report(&self, text: &str) {
        println!("{text}");
    }
}

/// Reports nothing: for tests and for programs that embed the run.
pub struct Silent;

impl Progress for Silent {
    fn update(&self, _task: &str, _done: usize, _total: usize) {}
    fn note(&self, _text: &str) {}
    fn report(&self, _text: &str) {}
}

/// `progress` as the pipeline's stage callback.
pub fn stages(progress: &dyn Progress) -> impl Fn(Stage, usize, usize) + Sync + '_ {
    move |stage, done, total| progress.update(stage.label(), done, total)
}

/// `progress` as a study's or simulation's task callback ([`pcuvd::study::Progress`]).
pub fn tasks(progress: &dyn Progress) -> impl Fn(&str, usize, usize) + Sync + '_ {
    move |task, done, total| progress.update(task, done, total)
}

/// Time between two progress lines of a running task.
pub const LOG_INTERVAL: Duration = Duration::from_secs(5);

/// One task's progress as plain lines on stderr (for a log file, a notebook, `subprocess`, a job
/// scheduler): a line when it starts, at most every [`LOG_INTERVAL`] while it runs, and one when
/// it ends, each with the fraction done, the time elapsed and an estimate of the time left.
pub struct LogLine {
    label: String,
    total: u64,
    state: Mutex<LogState>,
}

struct LogState {
    started: Instant,
    last_line: Option<Instant>,
    finished: bool,
}

impl LogLine {
    /// A task `label` of `total` steps, started now.
    pub fn new(label: &str, total: u64) -> Self {
        LogLine {
            label: label.to_string(),
            total,
            state: Mutex::new(LogState {
                started: Instant::now(),
                last_line: None,
                finished: false,
            }),
        }
    }

    /// The task's label.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The task's step count.
    pub fn total(&self) -> u64 {
        self.total
    }

    /// Reports that `done` of the task's steps are done (a line when one is due).
    pub fn set_position(&self, done: u64) {
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let due = state
            .last_line
            .is_none_or(|last| last.elapsed() >= LOG_INTERVAL);
        if due && !state.finished && done < self.total {
            eprintln!("{}", self.line(done, state.started.elapsed()));
            state.last_line = Some(Instant::now());
        }
    }

    /// Reports the task complete (once; later calls do nothing).
    pub fn finish(&self) {
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
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

/// Every task of a run as [`LogLine`]s on stderr; `quiet` for none (notes and reports still
/// print). A task that starts over with another count gets a new line of its own.
pub struct Lines {
    tasks: Mutex<Vec<LogLine>>,
    quiet: bool,
}

impl Lines {
    /// Log lines, or none when `quiet`.
    pub fn new(quiet: bool) -> Self {
        Lines {
            tasks: Mutex::new(Vec::new()),
            quiet,
        }
    }
}

impl Progress for Lines {
    fn update(&self, task: &str, done: usize, total: usize) {
        if self.quiet {
            return;
        }
        let mut tasks = self.tasks.lock().unwrap_or_else(|e| e.into_inner());
        let index = match tasks
            .iter()
            .position(|t| t.label == task && t.total == total as u64)
        {
            Some(index) => index,
            None => {
                tasks.retain(|t| t.label != task);
                tasks.push(LogLine::new(task, total as u64));
                tasks.len() - 1
            }
        };
        tasks[index].set_position(done as u64);
        if done == total {
            tasks[index].finish();
        }
    }
}
