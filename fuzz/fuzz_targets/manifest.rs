//! The recording manifest parser (versions 1 and 2): any text, read with its samples and decoded.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|text: &[u8]| {
    common::samples_npy();
    let path = common::file("recording.toml", text);
    if let Ok(recording) = pcuvd_io::read_recording(&path) {
        common::decode(&recording.data);
    }
    // The block reader parses the same manifest and checks the samples' header against it.
    if let Ok(Some(frames)) = pcuvd_io::ManifestFrames::open(&path) {
        use pcuvd::acquisition::source::FrameSource;
        let _ = frames.read_frames(0..frames.n_frames());
    }
});
