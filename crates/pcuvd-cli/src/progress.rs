//! Progress bars on stderr for the stages that take more than a moment.

use indicatif::{ProgressBar, ProgressStyle};
use pcuvd::pipeline::Stage;

/// A progress bar of `total` steps labelled `label`, drawn on stderr (hidden when stderr is not a terminal).
pub fn bar(label: &str, total: u64) -> ProgressBar {
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template("{prefix:>24} [{bar:32}] {pos}/{len} {elapsed_precise}")
            .expect("static template")
            .progress_chars("=> "),
    );
    bar.set_prefix(label.to_string());
    bar
}

/// Progress of tasks named as they go (a study's [`pcuvd::study::Progress`]): one bar per task,
/// a new bar whenever the task label changes.
pub struct TaskProgress {
    bar: std::sync::Mutex<ProgressBar>,
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
            bar: std::sync::Mutex::new(ProgressBar::hidden()),
        }
    }

    /// Reports that task `label` has done `done` of `total` steps.
    pub fn update(&self, label: &str, done: usize, total: usize) {
        let mut current = self.bar.lock().unwrap_or_else(|e| e.into_inner());
        if current.prefix() != label {
            current.finish();
            *current = bar(label, total as u64);
        }
        current.set_position(done as u64);
        if done == total {
            current.finish();
        }
    }
}

/// A callback for [`pcuvd::pipeline::process`] that shows one bar per stage.
pub struct PipelineProgress {
    tasks: TaskProgress,
    tag: String,
}

impl PipelineProgress {
    /// Bars prefixed by `tag` (e.g. the recording's name).
    pub fn new(tag: &str) -> Self {
        PipelineProgress {
            tasks: TaskProgress::new(),
            tag: tag.to_string(),
        }
    }

    /// Reports that `stage` has done `done` of `total` steps.
    pub fn update(&self, stage: Stage, done: usize, total: usize) {
        self.tasks
            .update(&format!("{}{}", self.tag, stage.label()), done, total);
    }
}
