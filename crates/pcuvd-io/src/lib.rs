//! pcuvd-io — reading and writing pcuvd recordings and results.
//!
//! - [`mat`]: a MATLAB v5 MAT-file reader (numeric, logical, char, struct, cell; compressed or not)
//!   and a small writer;
//! - [`must`]: MUST/PyMUST-style recordings (`RF` + `param`) as [`pcuvd::ChannelData`];
//! - [`manifest`]: the "pcuvd-recording" TOML manifest + `.npy` samples, read and write;
//! - [`frames`]: a manifest's samples read a block of frames at a time;
//! - [`cardiac`]: cardiac cycle start times (ECG R-waves, triggers) recorded beside a recording;
//! - [`npy`]: thin `.npy`/JSON writers for results;
//! - [`open`]: [`open_recording`], the one entry point that recognises any supported recording
//!   from its content (MUST v5/v7.3/npz, UFF, zea, Verasonics, manifests) and reads it a block of
//!   frames at a time, with every acquisition parameter's source ([`params`]);
//! - [`array`], [`npz`], [`hdf5`], [`mat73`], [`datafile`]: the stored arrays those readers share;
//! - [`paths`]: what a path names (a folder, a pipe, a link loop), said before it is opened.
//!
//! Every error is an [`IoError`] whose message names the file, the field and the problem.

#![warn(missing_docs)]

pub mod array;
pub mod cardiac;
pub mod container;
pub mod datafile;
pub mod error;
pub mod hdf5;
pub mod layout;
pub mod manifest;
pub mod mat;
pub mod mat73;
pub mod npy;
pub mod npz;
pub mod open;
pub mod params;
pub mod paths;
pub mod readers;
pub mod recording;

pub use readers::manifest::frames;
pub use readers::{uff, verasonics, zea};

/// MUST/PyMUST-style recordings: the reader [`readers::must`], and [`read_must_mat`], which reads
/// one whole through the format detection ([`open_recording`]) above the readers.
pub mod must {
    pub use crate::open::read_must_mat;
    pub use crate::readers::must::*;
}

pub use cardiac::read_trigger_times;
pub use error::IoError;
pub use frames::ManifestFrames;
pub use manifest::{Recording, RecordingWriter, read_manifest, read_recording, write_recording};
pub use mat::{MatFile, MatValue, NumericClass, read_mat, write_mat};
pub use npy::{remove_partial_files, write_atomically, write_json, write_npy};
pub use open::read_must_mat;
pub use open::{OpenedRecording, SourceInfo, StoredSamples, open_recording};
pub use params::{Overrides, ParamSource, Parameter};
pub use paths::check_regular_file;
