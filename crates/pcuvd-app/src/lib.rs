//! pcuvd-app — the application layer every front end shares: the command line (`pcuvd-cli`) and
//! the Python package (`pcuvd-py`) map their options into the same typed settings and run the
//! same plan, so a result is the same whichever front end asked for it.
//!
//! - [`settings`]: processing and dynamics settings in the units people give them (serde; with
//!   the `clap` feature, the command's options), `Default` = the command's defaults;
//! - [`input`]: opening a recording, any format, with the user's overrides;
//! - [`run`]: the [`run::Plan`] (every check before work), [`run::run`] and its result;
//! - [`memory`]: the memory check before work;
//! - [`summary`]: `summary.json`, the maps as `.npy`, figures: [`summary::save`];
//! - [`outputs`]: output folders (what is pcuvd's, what to clear) and input fingerprints;
//! - [`figures`]: the figures of a run;
//! - [`scenario`]: simulation scenarios (TOML files) and the shipped ones;
//! - [`simulation`]: simulated recordings with ground truth;
//! - [`study`]: the paper's studies' settings;
//! - [`progress`]: the one [`progress::Progress`] trait;
//! - [`keywords`]: the command's flags in messages, as a keyword front end names them.
//!
//! No command-line parsing, no terminal bars, no signal handling here.

#![warn(missing_docs)]

pub mod against_truth;
pub mod brain;
pub mod figures;
pub mod input;
pub mod keywords;
pub mod map_kinds;
pub mod memory;
pub mod nifti;
pub mod outputs;
pub mod progress;
pub mod run;
pub mod scenario;
pub mod settings;
pub mod simulation;
pub mod sites;
pub mod study;
pub mod summary;
pub mod zarr;

pub use progress::{Progress, Silent};
pub use run::{Plan, Processed, run, run_into};
pub use settings::{DynamicsSettings, ProcessingSettings};

/// The cause chain on one line (line breaks inside a cause become spaces), without the captured
/// backtrace, skipping a cause whose text an outer message already quotes.
pub fn one_line(error: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in error.chain() {
        // One line, whatever a cause's own message holds.
        let text = cause
            .to_string()
            .split_whitespace()
            .collect::<Vec<_>>()
            .join(" ");
        if !line.contains(&text) {
            if !line.is_empty() {
                line.push_str(": ");
            }
            line.push_str(&text);
        }
    }
    line
}
