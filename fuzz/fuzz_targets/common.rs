//! What the targets share: a scratch folder of this process (in memory where the system has
//! one), where each input is written as the file a reader opens.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// This process's scratch folder, created once.
pub fn scratch() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let base = if Path::new("/dev/shm").is_dir() {
            PathBuf::from("/dev/shm")
        } else {
            std::env::temp_dir()
        };
        let dir = base.join(format!("pcuvd-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scratch folder");
        dir
    })
}

/// Writes `bytes` as `name` in the scratch folder; returns its path.
pub fn file(name: &str, bytes: &[u8]) -> PathBuf {
    let path = scratch().join(name);
    std::fs::write(&path, bytes).expect("scratch file");
    path
}

/// A valid little RF recording's samples (.npy, float32, 2 frames × 4 events × 4 channels × 32
/// samples), the file fuzzed manifests point at.
pub fn samples_npy() -> PathBuf {
    let path = scratch().join("rf.npy");
    if !path.exists() {
        let a = ndarray::Array4::from_shape_fn((2, 4, 4, 32), |(f, e, c, s)| {
            ((f * 7 + e * 5 + c * 3 + s) % 11) as f32 - 5.0
        });
        pcuvd_io::write_npy(&path, &a).expect("samples");
    }
    path
}

/// Decodes what a reader accepted, as processing would first do: a reader must not hand on
/// anything decoding then panics on.
pub fn decode(data: &pcuvd::ChannelData) {
    let _ = pcuvd::pipeline::check_record(&data.acquisition, data.samples.dim().2).and_then(|()| {
        pcuvd::form::decode::Decoder::new(data, pcuvd::form::decode::EventAlignment::MidFrame)
            .and_then(|decoder| decoder.decode(&data.samples))
    });
}
