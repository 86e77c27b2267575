//! NumPy .npy samples: any bytes, read whole and a block of frames at a time under a valid
//! manifest.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;

const MANIFEST: &str = r#"format = "pcuvd-recording"
version = 1
[probe]
n_elements = 4
pitch_m = 3e-4
element_width_m = 2.5e-4
center_frequency_hz = 5e6
bandwidth = 0.6
[acquisition]
sampling_frequency_hz = 20e6
sound_speed_m_s = 1540.0
t0_s = 0.0
event_prf_hz = 5000.0
angles_deg = [-6, -2, 2, 6]
pulse_cycles = 2.0
coding = "hadamard"
slot_delay_s = 1e-7
[data]
file = "fuzzed.npy"
kind = "rf"
axes = ["frames", "angles", "channels", "samples"]
"#;

fuzz_target!(|bytes: &[u8]| {
    let npy = common::file("fuzzed.npy", bytes);
    let _ = pcuvd_io::npy::read_npy(&npy);
    let manifest = common::file("fuzzed.toml", MANIFEST.as_bytes());
    if let Ok(recording) = pcuvd_io::read_recording(&manifest) {
        common::decode(&recording.data);
    }
    if let Ok(Some(frames)) = pcuvd_io::ManifestFrames::open(&manifest) {
        use pcuvd::source::FrameSource;
        let _ = frames.read_frames(0..frames.n_frames());
    }
});
