//! The `pcuvd` command's integration tests: the binary run as a user runs it.
//!
//! One test binary for the crate (one build and one link of everything the tests share,
//! instead of one per file); each file is a module.

mod bad_input;
mod disk;
mod dynamics;
mod images;
mod paper;
mod simulate;

/// Runs `pcuvd ARGS` as a user would, with `RUST_BACKTRACE=1` set: whether it succeeded, its
/// stdout and its stderr, which must hold neither a panic nor a backtrace. `--quiet` leaves out
/// the progress lines (printed when stderr is not a terminal), which would precede an error.
fn pcuvd(args: &[&str]) -> (bool, String, String) {
    run_pcuvd(&[&["--quiet"], args].concat())
}

/// [`pcuvd`] with the progress lines kept on stderr: for tests of what is said before, between
/// or after the stages.
fn pcuvd_with_progress(args: &[&str]) -> (bool, String, String) {
    run_pcuvd(args)
}

fn run_pcuvd(args: &[&str]) -> (bool, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .args(args)
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(!stderr.to_lowercase().contains("backtrace"), "{stderr}");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr,
    )
}

/// The most frames any segment of a run imaged, from its summary's `segments` record.
fn longest_imaged(segments: &serde_json::Value) -> u64 {
    segments["imaged_frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r[1].as_u64().unwrap() - r[0].as_u64().unwrap())
        .max()
        .unwrap()
}

/// The XXH3-128 of `bytes` in hex as `xxh128sum` prints it (the 128 bits big-endian), the digest
/// `summary.json` records by default.
fn xxh128_of(bytes: &[u8]) -> String {
    format!("{:032x}", twox_hash::xxhash3_128::Hasher::oneshot(bytes))
}

/// The SHA-256 of the file at `path` in hex, as those who check with a tool of their own get
/// it: coreutils' `sha256sum` on Unix, elsewhere the file hashed whole here.
fn sha256_of_file(path: &std::path::Path) -> String {
    if cfg!(unix) {
        let coreutils = std::process::Command::new("sha256sum")
            .arg(path)
            .output()
            .unwrap();
        String::from_utf8_lossy(&coreutils.stdout)
            .split_whitespace()
            .next()
            .unwrap()
            .to_string()
    } else {
        use sha2::Digest;
        let digest = sha2::Sha256::digest(std::fs::read(path).unwrap());
        digest.iter().map(|b| format!("{b:02x}")).collect()
    }
}

/// Runs `command` with its standard output a pipe closed before anything is read, as
/// `pcuvd … | head -0` would; its stderr is kept, and checked for panics.
#[cfg(unix)]
fn run_with_stdout_closed(command: &mut std::process::Command) -> std::process::Output {
    let mut child = command
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let result = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    result
}
