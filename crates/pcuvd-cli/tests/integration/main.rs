//! The `pcuvd` command's integration tests: the binary run as a user runs it.
//!
//! One test binary for the crate (one build and one link of everything the tests share,
//! instead of one per file); each file is a module.

mod bad_input;
mod disk;
mod dynamics;
mod paper;
mod simulate;
