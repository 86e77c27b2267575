//! The command line's options in messages, written as the Python package's keywords.
//!
//! The run's errors and notes are the command's own (one wording for both users), and name its
//! flags: `--f-number -1.0: must be within [0.1, 100]`. A Python user typed `f_number=-1.0`, so
//! the package says `f_number=-1.0: must be within [0.1, 100]`. Only flags whose name, with `_`
//! for `-`, is a keyword of one of the package's calls are rewritten; the others (`--out`, whose
//! folder `save` takes as its argument) stay as the command spells them.

use std::collections::HashSet;
use std::sync::OnceLock;

use pcuvd_app::Progress;
use pcuvd_app::keywords::flags_as_keywords;
use pcuvd_app::progress::Lines;

use crate::recording::ACQUISITION_KEYS;
use crate::simulation::option_names_of;

/// Keyword options of `ProcessResult.save` that the command spells as flags with a value.
const SAVE_KEYWORDS: [&str; 3] = ["bids_subject", "bids_session", "bids_task"];

/// `ProcessResult.save`'s switches: a flag alone on the command line, `=True` in Python.
const SAVE_SWITCHES: [&str; 3] = ["force", "nifti", "zarr"];

/// Every keyword of `process` (`dynamics`' among them), `simulate`, `study`, `read_recording`
/// and `save`.
fn keywords() -> &'static HashSet<String> {
    static KEYWORDS: OnceLock<HashSet<String>> = OnceLock::new();
    KEYWORDS.get_or_init(|| {
        ["process", "simulate", "study"]
            .into_iter()
            .flat_map(|command| option_names_of(command).unwrap_or_default())
            .chain(
                ACQUISITION_KEYS
                    .iter()
                    .chain(&SAVE_KEYWORDS)
                    .map(|k| k.to_string()),
            )
            .collect()
    })
}

/// `text` with each `--flag` that is a Python keyword written as the keyword (a switch as
/// `force=True`), with the value the message gives it as `keyword=VALUE`
/// ([`flags_as_keywords`]).
pub(crate) fn as_python(text: &str) -> String {
    flags_as_keywords(text, |name| {
        let with_unit = format!("{name}_mm");
        if SAVE_SWITCHES.contains(&name) {
            Some(format!("{name}=True"))
        } else if crate::PROCESSING_ALIASES.contains(&with_unit.as_str()) {
            // The package documents `grid_mm=` and `sites_mm=` (the unit in the name); each
            // takes the command's text form that the message quotes.
            Some(with_unit)
        } else {
            keywords().contains(name).then(|| name.to_string())
        }
    })
}

/// Progress lines on stderr, as the command prints them, with its notes' options written as
/// Python keywords.
pub(crate) struct PyLines(Lines);

impl PyLines {
    /// Log lines, or none when `quiet` (notes still print).
    pub(crate) fn new(quiet: bool) -> Self {
        PyLines(Lines::new(quiet))
    }
}

impl Progress for PyLines {
    fn update(&self, task: &str, done: usize, total: usize) {
        self.0.update(task, done, total);
    }

    fn note(&self, text: &str) {
        self.0.note(&as_python(text));
    }

    fn report(&self, text: &str) {
        self.0.report(text);
    }
}
