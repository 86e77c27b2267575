//! MATLAB v5 MAT-files: any bytes, parsed, then read as a MUST-style recording and decoded.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|bytes: &[u8]| {
    let path = common::file("fuzzed.mat", bytes);
    if let Ok(file) = pcuvd_io::read_mat(&path)
        && let Ok(data) = pcuvd_io::must::from_mat(&path, &file)
    {
        common::decode(&data);
    }
});
