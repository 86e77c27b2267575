//! The readers, one per format, each over the shared vocabulary of [`crate::recording`]: each
//! opens a recording of its format as an [`crate::OpenedRecording`] that reads a block of frames at
//! a time. No reader imports another, nor the format detection above them ([`crate::open`]).
//!
//! - [`must`]: MUST/PyMUST MATLAB v5 and v7.3 files and PyMUST-style `.npz` archives;
//! - [`uff`]: USTB UFF channel data (HDF5);
//! - [`zea`]: zea / OpenH-RF (HDF5);
//! - [`urx`]: URX, Moduleus' ultrasound raw data exchange (HDF5);
//! - [`verasonics`]: a Verasonics workspace saved with `-v7.3`;
//! - [`manifest`]: a pcuvd recording manifest (`.toml`) and the samples file it names.

pub mod manifest;
pub mod must;
pub mod uff;
pub mod urx;
pub mod verasonics;
pub mod zea;
