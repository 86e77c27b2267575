//! NumPy .npy samples: any bytes, read whole and a block of frames at a time under a valid
//! manifest.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;

/// The manifest the fuzzed samples are read under.
const MANIFEST: &str = include_str!("../npy_target.toml");

fuzz_target!(|bytes: &[u8]| {
    let npy = common::file("fuzzed.npy", bytes);
    let _ = pcuvd_io::npy::read_npy(&npy);
    let manifest = common::file("fuzzed.toml", MANIFEST.as_bytes());
    if let Ok(recording) = pcuvd_io::read_recording(&manifest) {
        common::decode(&recording.data);
    }
    if let Ok(Some(frames)) = pcuvd_io::ManifestFrames::open(&manifest) {
        use pcuvd::acquisition::source::FrameSource;
        let _ = frames.read_frames(0..frames.n_frames());
    }
});
