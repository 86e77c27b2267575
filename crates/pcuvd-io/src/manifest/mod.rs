//! The recording manifest: a TOML file (format "pcuvd-recording", SI units with the unit in each
//! key name) that describes the acquisition and points at a `.npy` file of samples.
//!
//! Version 1 says plane waves by angle, coding "none" or "hadamard" with evenly spaced slots, and
//! a pulse length in cycles; see `crates/pcuvd-io/examples/recording.toml`. Version 2 adds what
//! scanners' sequences need: per-element transmit delays per slot (`transmit_delays_s`, the
//! steering angle and slot start derived from them and checked to be a plane wave), an explicit
//! code matrix in the scanner's row order (`coding = "matrix"`, `code_matrix`), uneven slot
//! starts (`slot_delays_s`), the transmit pulse as samples (`[acquisition.pulse]`), and the
//! per-frame axis of the samples named `events` (an event of a coded frame fires every angle);
//! see `crates/pcuvd-io/examples/recording_v2.toml`. Every key is checked against its range, and
//! an error names the key. Angles may be given as `angles_deg` or `angles_rad` (exactly one);
//! [`write_recording`] writes `angles_rad` so that a written recording reads back bit for bit,
//! and writes version 1 whenever version 1 can say the sequence (so such files stay unchanged).
//!
//! The format, in the order a manifest is read: `schema` (the TOML tables as serde reads them),
//! `read` (the checks, up to a [`Recording`]), `acquisition` (the `[probe]` and `[acquisition]`
//! tables), `axes` (`[data].axes`); then `write` ([`write_recording`]) and `writer`
//! ([`RecordingWriter`], a block of events at a time). Opening a manifest to read it a block of
//! frames at a time is the reader's job ([`crate::readers::manifest`]), above this module.

use std::path::PathBuf;

use pcuvd::ChannelData;

/// The value of the manifest's `format` key.
pub const FORMAT: &str = "pcuvd-recording";
/// The newest manifest version this crate reads and writes (it reads every version from 1).
pub const VERSION: i64 = 2;

/// A recording read from a manifest: the channel data, the free-form provenance, and where it was.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The channel data, validated.
    pub data: ChannelData,
    /// The `[provenance]` table (empty when absent): simulator settings, noise, seed...
    pub provenance: toml::Table,
    /// The manifest file, as given.
    pub manifest_path: PathBuf,
    /// The samples file, resolved against the manifest's folder.
    pub data_path: PathBuf,
}

mod acquisition;
mod axes;
mod read;
mod schema;
mod write;
mod writer;

pub(crate) use axes::event_shape;
pub(crate) use read::{kind_error, parse_manifest};
pub use read::{read_manifest, read_recording};
pub use write::write_recording;
pub use writer::RecordingWriter;

#[cfg(test)]
mod tests;
