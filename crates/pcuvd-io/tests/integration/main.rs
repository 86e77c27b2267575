//! The readers' integration tests: files written by each format's own tools.
//!
//! One test binary for the crate (one build and one link of everything the tests share,
//! instead of one per file); each file is a module.

mod confusius;
mod fuzz_regressions;
mod public_paths;
mod readers;
mod scipy_mat;
