//! The science crate's integration tests: simulated recordings through the chain, against analytic truth.
//!
//! One test binary for the crate (one build and one link of everything the tests share,
//! instead of one per file); each file is a module.

mod blocks;
mod coverage;
mod dynamics;
mod network;
mod roundtrip;
mod scale;
mod segments;
mod simulate;
mod stages;
mod tissue;
