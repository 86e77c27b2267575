//! Inputs the fuzzer (scripts/fuzz, targets in fuzz/) found crashing a reader, kept as tests: each
//! is read the way its target reads it and must give a result or an error naming the file, never
//! a panic. `fixtures/fuzz/TARGET/` holds them; the fuzzer's seeds (valid inputs of each target)
//! run too and must be read without error.

use std::path::{Path, PathBuf};

use pcuvd::acquisition::source::FrameSource;

/// The samples a fuzzed manifest points at (`rf.npy`): the fuzz targets' own.
fn samples_npy(dir: &Path) {
    let a = ndarray::Array4::from_shape_fn((2, 4, 4, 32), |(f, e, c, s)| {
        ((f * 7 + e * 5 + c * 3 + s) % 11) as f32 - 5.0
    });
    pcuvd_io::write_npy(&dir.join("rf.npy"), &a).unwrap();
}

/// The npy target's manifest, reading `fuzzed.npy`.
const NPY_MANIFEST: &str = include_str!("../../../../fuzz/npy_target.toml");

fn decode(data: &pcuvd::ChannelData) -> Result<(), pcuvd::Error> {
    pcuvd::pipeline::check_record(&data.acquisition, data.samples.dim().2)?;
    let alignment = pcuvd::form::decode::EventAlignment::MidFrame;
    pcuvd::form::decode::Decoder::new(data, alignment)?
        .decode(&data.samples)
        .map(|_| ())
}

/// Reads `bytes` as target `target` does; Ok(()) when every reader accepted it.
fn run(target: &str, bytes: &[u8], dir: &Path) -> Result<(), String> {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    match target {
        "manifest" => {
            samples_npy(dir);
            let path = dir.join("recording.toml");
            std::fs::write(&path, bytes).unwrap();
            let recording = pcuvd_io::read_recording(&path).map_err(|e| err(&e))?;
            decode(&recording.data).map_err(|e| err(&e))?;
            if let Some(frames) = pcuvd_io::ManifestFrames::open(&path).map_err(|e| err(&e))? {
                frames
                    .read_frames(0..frames.n_frames())
                    .map_err(|e| err(&e))?;
            }
            Ok(())
        }
        "npy" => {
            std::fs::write(dir.join("fuzzed.npy"), bytes).unwrap();
            pcuvd_io::npy::read_npy(&dir.join("fuzzed.npy")).map_err(|e| err(&e))?;
            let manifest = dir.join("fuzzed.toml");
            std::fs::write(&manifest, NPY_MANIFEST).unwrap();
            let recording = pcuvd_io::read_recording(&manifest).map_err(|e| err(&e))?;
            decode(&recording.data).map_err(|e| err(&e))?;
            if let Some(frames) = pcuvd_io::ManifestFrames::open(&manifest).map_err(|e| err(&e))? {
                frames
                    .read_frames(0..frames.n_frames())
                    .map_err(|e| err(&e))?;
            }
            Ok(())
        }
        "mat" => {
            let path = dir.join("fuzzed.mat");
            std::fs::write(&path, bytes).unwrap();
            let file = pcuvd_io::read_mat(&path).map_err(|e| err(&e))?;
            let data = pcuvd_io::must::from_mat(&path, &file).map_err(|e| err(&e))?;
            decode(&data).map_err(|e| err(&e))
        }
        "open" => {
            let path = dir.join("fuzzed.bin");
            std::fs::write(&path, bytes).unwrap();
            let opened = pcuvd_io::open_recording(&path, &pcuvd_io::Overrides::default())
                .map_err(|e| err(&e))?;
            let data = opened.read_all().map_err(|e| err(&e))?;
            decode(&data).map_err(|e| err(&e))
        }
        other => panic!("no fuzz target {other}"),
    }
}

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.retain(|p| p.is_file());
    files.sort();
    files
}

const TARGETS: [&str; 4] = ["manifest", "npy", "mat", "open"];

/// Every crashing input the fuzzer found reads to a result or an error, without a panic.
#[test]
fn crashing_inputs_found_by_the_fuzzer_are_refused_or_read() {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/fuzz");
    for target in TARGETS {
        for input in files(&fixtures.join(target)) {
            let dir = tempfile::tempdir().unwrap();
            let bytes = std::fs::read(&input).unwrap();
            if let Err(e) = run(target, &bytes, dir.path()) {
                // An error must name the file it is about.
                assert!(
                    e.contains(&*dir.path().to_string_lossy()),
                    "{}: {e}",
                    input.display()
                );
            }
        }
    }
}

/// The fuzzer's seeds are valid inputs: each target reads them without error (the MAT seeds
/// include files that are not MUST recordings, and .npy seeds whose type or shape the target's
/// RF manifest refuses: those only parse).
#[test]
fn the_fuzzers_seeds_are_read() {
    let seeds = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/seeds");
    for target in TARGETS {
        let mut inputs = files(&seeds.join(target));
        if target == "open" {
            // scripts/fuzz seeds `open` with the readers' fixtures too: the self-describing ones.
            let readers = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/readers");
            inputs.extend(files(&readers).into_iter().filter(|p| {
                let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
                matches!(ext, "mat" | "uff" | "hdf5")
            }));
        }
        assert!(!inputs.is_empty(), "no seeds for {target}");
        for input in inputs {
            let dir = tempfile::tempdir().unwrap();
            let bytes = std::fs::read(&input).unwrap();
            match run(target, &bytes, dir.path()) {
                Ok(()) => {}
                Err(e) if target == "mat" && e.contains("no variable 'RF'") => {
                    pcuvd_io::read_mat(&dir.path().join("fuzzed.mat")).unwrap();
                }
                // The .npy seeds exercise the parser (complex, 3-D, Fortran order); the fuzz
                // target's fixed RF manifest may then refuse their type or shape, by name.
                Err(e) if target == "npy" => {
                    pcuvd_io::npy::read_npy(&dir.path().join("fuzzed.npy")).unwrap();
                    assert!(e.contains("fuzzed."), "{}: {e}", input.display());
                }
                Err(e) => panic!("{}: {e}", input.display()),
            }
        }
    }
}
