//! pcuvd-io — reading and writing pcuvd recordings and results.
//!
//! Readers over one vocabulary, in layers that import only downward:
//! - on top, [`open`]: [`open_recording`], the one entry point that recognises any supported
//!   recording from its content (MUST v5/v7.3/npz, UFF, zea, Verasonics, URX, manifests) and hands it
//!   to its reader;
//! - [`readers`]: one reader per format ([`must`], [`uff`], [`zea`], [`verasonics`], and
//!   [`readers::manifest`] with [`frames`]), each reading a block of frames at a time; no reader
//!   imports another;
//! - [`recording`]: what every reader returns ([`OpenedRecording`], [`SourceInfo`],
//!   [`StoredSamples`]), the defaults they share, and the one acquisition builder they all use
//!   ([`recording::PlaneWaveAcquisition`]); with [`params`], every acquisition parameter's source;
//! - the formats and stored arrays below: [`manifest`] (the "pcuvd-recording" TOML manifest,
//!   read and write), [`datafile`] (a manifest's samples file), [`container`] (what a file's first
//!   bytes say it is), [`mat`] (a MATLAB v5 MAT-file reader and a small writer), [`mat73`],
//!   [`hdf5`], [`npz`], [`array`](mod@array), [`layout`];
//! - beside them: [`read_pass`] (a samples file fed to a checksum as its blocks are read),
//!   [`cardiac`] (cardiac cycle start times recorded beside a recording), [`images`] (the
//!   "pcuvd-images" manifest of beamformed IQ images formed elsewhere), [`confusius`]
//!   (ConfUSIus's Zarr store of beamformed IQ, read as images), [`npy`]
//!   (thin `.npy`/JSON writers for results), [`paths`] (what a path names, said before it is
//!   opened).
//!
//! Every error is an [`IoError`] whose message names the file, the field and the problem.

#![warn(missing_docs)]

pub mod array;
pub mod cardiac;
pub mod confusius;
pub mod container;
pub mod datafile;
pub mod error;
pub mod hdf5;
pub mod images;
pub mod layout;
pub mod manifest;
pub mod mat;
pub mod mat73;
pub mod npy;
pub mod npz;
pub mod open;
pub mod params;
pub mod paths;
pub mod read_pass;
pub mod readers;
pub mod recording;

pub use readers::manifest::frames;
pub use readers::{uff, urx, verasonics, zea};

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
pub use mat::{MatFile, MatValue, Numbers, NumericClass, read_mat, write_mat};
pub use npy::{remove_partial_files, write_atomically, write_json, write_npy, write_npy_by_slices};
pub use open::{open_recording, read_must_mat};
pub use params::{Overrides, ParamSource, Parameter};
pub use paths::check_regular_file;
pub use read_pass::{ChecksumSink, Checksummed, ReadPass};
pub use recording::{OpenedRecording, SourceInfo, StoredSamples};
