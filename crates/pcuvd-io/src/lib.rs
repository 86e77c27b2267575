//! pcuvd-io — reading and writing pcuvd recordings and results.
//!
//! - [`mat`]: a MATLAB v5 MAT-file reader (numeric, logical, char, struct, cell; compressed or not)
//!   and a small writer;
//! - [`must`]: MUST/PyMUST-style recordings (`RF` + `param`) as [`pcuvd::ChannelData`];
//! - [`manifest`]: the "pcuvd-recording" TOML manifest + `.npy` samples, read and write;
//! - [`frames`]: a manifest's samples read a block of frames at a time;
//! - [`npy`]: thin `.npy`/JSON writers for results;
//! - [`paths`]: what a path names (a folder, a pipe, a link loop), said before it is opened.
//!
//! Every error is an [`IoError`] whose message names the file, the field and the problem.

#![warn(missing_docs)]

pub mod error;
pub mod frames;
pub mod manifest;
pub mod mat;
pub mod must;
pub mod npy;
pub mod paths;

pub use error::IoError;
pub use frames::ManifestFrames;
pub use manifest::{Recording, RecordingWriter, read_manifest, read_recording, write_recording};
pub use mat::{MatFile, MatValue, NumericClass, read_mat, write_mat};
pub use must::read_must_mat;
pub use npy::{remove_partial_files, write_atomically, write_json, write_npy};
pub use paths::check_regular_file;
