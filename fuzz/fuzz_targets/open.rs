//! Any file, recognised by its content as `pcuvd process` does (NumPy .npy/.npz, MATLAB v5 and
//! v7.3, MUST, USTB UFF, zea, Verasonics), every frame read, then decoded.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|bytes: &[u8]| {
    // The HDF5 readers run the HDF5 crate under catch_unwind and turn its panics into errors
    // naming the file; libFuzzer's hook would abort on those caught panics. A panic that escapes
    // a reader still aborts: libfuzzer-sys catches it around this closure.
    static QUIET: std::sync::Once = std::sync::Once::new();
    QUIET.call_once(|| std::panic::set_hook(Box::new(|_| {})));
    let path = common::file("fuzzed.bin", bytes);
    if let Ok(opened) = pcuvd_io::open_recording(&path, &pcuvd_io::Overrides::default())
        && let Ok(data) = opened.read_all()
    {
        common::decode(&data);
    }
});
