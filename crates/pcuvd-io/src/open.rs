//! One entry point for every recording pcuvd reads: [`open_recording`] recognises the format from
//! the file's content (magic bytes, then structure; the extension only breaks ties) and hands it
//! to its reader ([`crate::readers`]), which returns a
//! [`FrameSource`](pcuvd::acquisition::source::FrameSource) that reads a block of frames at a time, with what
//! was read: the files, the format and reader, every acquisition parameter with its source, and
//! warnings. Images formed elsewhere are told apart here too ([`is_images_input`],
//! [`read_images_header`]). This module sits on top: it imports the readers, and no reader
//! imports it.

use std::path::Path;

use pcuvd::ChannelData;

pub use crate::container::{Container, read_head, sniff};
use crate::error::IoError;
use crate::params::Overrides;
pub use crate::recording::{OpenedRecording, SourceInfo, StoredSamples};

/// The formats [`open_recording`] reads, for messages.
pub const FORMATS: &str = "MUST/PyMUST MATLAB (v5 or v7.3: RF or IQ + param), a PyMUST-style \
     NumPy .npz (RF or IQ + param fields), USTB UFF (.uff, /channel_data), zea / OpenH-RF \
     (.hdf5, /data/raw_data or /tracks), a Verasonics workspace saved with -v7.3 (RcvData, \
     Receive, Trans), URX (.urx, /dataset/acquisition: plane waves, linear array), and a pcuvd \
     recording manifest (.toml) naming .npy, .npz, HDF5 or MATLAB \
     samples";

/// A short description of what an unrecognised file looks like.
fn looks_like(head: &[u8]) -> String {
    if head.is_empty() {
        return "it is empty".into();
    }
    if head.starts_with(b"MATLAB") {
        return "it starts like a MATLAB MAT-file but its header is not one pcuvd reads".into();
    }
    let printable = head
        .iter()
        .take(256)
        .all(|b| b.is_ascii_graphic() || b.is_ascii_whitespace());
    if printable {
        let first = String::from_utf8_lossy(&head[..head.len().min(40)])
            .lines()
            .next()
            .unwrap_or("")
            .to_string();
        return format!("it is text starting {first:?} (not a pcuvd recording manifest)");
    }
    let hex: Vec<String> = head.iter().take(8).map(|b| format!("{b:02x}")).collect();
    format!("it is binary starting with bytes {}", hex.join(" "))
}

/// Opens the recording at `path`, whatever its format, applying the user's `overrides`.
pub fn open_recording(path: &Path, overrides: &Overrides) -> Result<OpenedRecording, IoError> {
    if crate::confusius::is_store(path) {
        return Err(IoError::malformed(
            path,
            "is ConfUSIus's Zarr store of beamformed IQ images, not a recording of channel data: \
             `pcuvd process`, `pcuvd info` and Python's pcuvd.process(path) read it (decoding and \
             beamforming skipped); it is not read as a recording",
        ));
    }
    // A folder, a named pipe (reading one would wait forever) or a link loop is said as such.
    crate::paths::check_regular_file(path)?;
    overrides.check(path)?;
    let head = read_head(path, 8192)?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    if crate::images::is_images_manifest(&head) {
        return Err(IoError::malformed(
            path,
            "is an images manifest (beamformed IQ images, format \"pcuvd-images\"), not a \
             recording of channel data: `pcuvd process`, `pcuvd info` and Python's \
             pcuvd.process(path) read it (decoding and beamforming skipped); it is not read \
             as a recording",
        ));
    }
    let container = match sniff(&head) {
        Some(c) => c,
        // TOML has no magic: a .toml that does not name the format gets the manifest's own
        // message (which says what is missing).
        None if ext == "toml" => Container::Manifest,
        None => {
            return Err(IoError::malformed(
                path,
                format!(
                    "is not a recording pcuvd recognises: {}. pcuvd reads {FORMATS}",
                    looks_like(&head)
                ),
            ));
        }
    };
    let opened = match container {
        Container::Manifest => crate::readers::manifest::open(path, overrides),
        Container::MatV5 => crate::readers::must::open_v5(path, overrides),
        Container::Zip => crate::readers::must::open_npz(path, overrides),
        Container::Npy => Err(IoError::malformed(
            path,
            "is a bare NumPy .npy array: it holds samples but not how they were acquired. Write \
             a pcuvd recording manifest (.toml) that describes the acquisition and names this \
             file in [data].file (see crates/pcuvd-io/examples/recording.toml), or, for \
             beamformed IQ images, an images manifest (crates/pcuvd-io/examples/images.toml)",
        )),
        Container::Hdf5 { .. } => open_hdf5(path, overrides, &ext),
    }?;
    overrides.check_applied(path, &opened.info.parameters)?;
    // A track names one of several acquisitions in a file: a reader that has none to choose
    // from says so rather than ignore the choice.
    if let Some(track) = &overrides.track
        && opened.info.parameter("track").is_none()
    {
        return Err(IoError::invalid(
            path,
            "--track",
            format!(
                "{track:?}: {} holds one acquisition, not tracks to choose from",
                opened.info.format
            ),
        ));
    }
    Ok(opened)
}

/// Reads a MUST-style MAT-file (v5 or v7.3) or `.npz` into channel data (whole, validated): any
/// recording [`open_recording`] recognises, read whole.
pub fn read_must_mat(path: &Path) -> Result<ChannelData, IoError> {
    open_recording(path, &Overrides::default())?.read_all()
}

/// Recognises an HDF5 recording by its structure and opens it.
fn open_hdf5(path: &Path, overrides: &Overrides, ext: &str) -> Result<OpenedRecording, IoError> {
    let h5 = crate::hdf5::Hdf5::open(path)?;
    let top = h5.members("/")?;
    let has = |n: &str| top.iter().any(|m| m == n);
    if has("channel_data") {
        return crate::readers::uff::open(path, &h5, overrides);
    }
    if has("RcvData") && has("Receive") && has("Trans") {
        return crate::readers::verasonics::open(path, &h5, overrides);
    }
    if (has("data") && h5.exists("data/raw_data")) || has("tracks") {
        return crate::readers::zea::open(path, &h5, overrides);
    }
    if (has("RF") || has("IQ")) && has("param") {
        return crate::readers::must::open_v73(path, &h5, overrides);
    }
    if has("dataset") && h5.is_group(crate::readers::urx::ACQUISITION) {
        return crate::readers::urx::open(path, &h5, overrides);
    }
    let ext_hint = match ext {
        "uff" => " (the .uff extension suggests USTB UFF, but there is no /channel_data group)",
        "urx" => " (the .urx extension suggests URX, but there is no /dataset/acquisition group)",
        "mat" => " (a MATLAB v7.3 file without the variables of a known layout)",
        "hdf5" | "h5" => "",
        _ => "",
    };
    Err(IoError::malformed(
        path,
        format!(
            "is an HDF5 file of none of the layouts pcuvd reads{ext_hint}: its top level holds {}. \
             pcuvd reads {FORMATS}; for other HDF5 samples write a manifest whose [data].file is \
             \"{}:/path/to/dataset\"",
            if top.is_empty() {
                "nothing".to_string()
            } else {
                top.join(", ")
            },
            path.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default()
        ),
    ))
}

/// True when `path` holds beamformed images pcuvd reads as images, not as a recording: an images
/// manifest ([`crate::images`]), or ConfUSIus's Zarr store of IQ ([`crate::confusius`]).
pub fn is_images_input(path: &Path) -> bool {
    crate::confusius::is_store(path)
        || read_head(path, 4096).is_ok_and(|head| crate::images::is_images_manifest(&head))
}

/// The header of the images at `path` (nothing of them is read): an images manifest's and its
/// `.npy` file's, or ConfUSIus's Zarr store's ([`is_images_input`]).
pub fn read_images_header(path: &Path) -> Result<crate::images::ImagesHeader, IoError> {
    match crate::confusius::is_store(path) {
        true => crate::confusius::read_header(path),
        false => crate::images::read_header(path),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn says_what_an_unrecognised_file_looks_like() {
        assert!(looks_like(b"").contains("empty"));
        assert!(looks_like(&[0u8, 1, 2]).contains("00 01 02"));
    }
}
