//! Bad input gives one clear message naming the file, the field and the problem, a non-zero exit
//! code, and never a panic or a backtrace.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use pcuvd_io::{MatValue, write_mat};

/// Runs `pcuvd process INPUT --out …` with extra args; returns (success, stderr).
fn process(input: &Path, extra: &[&str]) -> (bool, String) {
    let out = tempfile::tempdir().unwrap();
    // --quiet: progress lines (printed when stderr is not a terminal) would precede the error.
    let result = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .arg("--quiet")
        .arg("process")
        .arg(input)
        .arg("--out")
        .arg(out.path().join("o"))
        .args(extra)
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr).into_owned();
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    assert!(
        !stderr.to_lowercase().contains("backtrace"),
        "backtrace: {stderr}"
    );
    (result.status.success(), stderr)
}

fn expect_error(input: &Path, extra: &[&str], needles: &[&str]) {
    let (ok, stderr) = process(input, extra);
    assert!(!ok, "expected failure for {}", input.display());
    assert!(stderr.starts_with("error: "), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "one line: {stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "{needle:?} missing from: {stderr}");
    }
}

/// A small valid MUST-style recording (64 samples × 4 elements × 2 transmits), mutated by `edit`.
fn must_file(
    dir: &Path,
    name: &str,
    edit: impl FnOnce(&mut MatValue, &mut BTreeMap<String, MatValue>),
) -> PathBuf {
    let (ns, ne, nt) = (64usize, 4usize, 2usize);
    let data: Vec<f64> = (0..ns * ne * nt)
        .map(|i| ((i * 37) % 19) as f64 - 9.0)
        .collect();
    let mut rf = MatValue::double(vec![ns, ne, nt], data).unwrap();
    let mut param = BTreeMap::new();
    for (k, v) in [
        ("fs", 20e6),
        ("fc", 5e6),
        ("c", 1540.0),
        ("pitch", 3e-4),
        ("width", 2.5e-4),
        ("t0", 0.0),
        ("PRF", 5e3),
        ("Nelements", ne as f64),
    ] {
        param.insert(k.to_string(), MatValue::scalar(v));
    }
    param.insert(
        "TXdelay".into(),
        MatValue::double(vec![1, ne], vec![0.0; ne]).unwrap(),
    );
    edit(&mut rf, &mut param);
    let path = dir.join(name);
    let param = MatValue::Struct(param);
    write_mat(&path, &[("RF", &rf), ("param", &param)], true).unwrap();
    path
}

#[test]
fn a_valid_small_recording_processes() {
    let dir = tempfile::tempdir().unwrap();
    let ok = must_file(dir.path(), "ok.mat", |_, _| {});
    let (success, stderr) = process(&ok, &[]);
    assert!(success, "{stderr}");
}

#[test]
fn missing_variable_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("no_rf.mat");
    let mut param = BTreeMap::new();
    param.insert("fs".to_string(), MatValue::scalar(1e6));
    write_mat(&path, &[("param", &MatValue::Struct(param))], false).unwrap();
    expect_error(&path, &[], &["no_rf.mat", "RF"]);

    let no_fs = must_file(dir.path(), "no_fs.mat", |_, p| {
        p.remove("fs");
    });
    expect_error(&no_fs, &[], &["no_fs.mat", "fs"]);
}

#[test]
fn wrong_shape_and_type() {
    let dir = tempfile::tempdir().unwrap();
    let four_d = must_file(dir.path(), "rf4d.mat", |rf, _| {
        *rf = MatValue::double(vec![8, 4, 2, 2], vec![1.0; 128]).unwrap();
    });
    expect_error(&four_d, &[], &["rf4d.mat", "RF"]);
    let text_fs = must_file(dir.path(), "text_fs.mat", |_, p| {
        p.insert("fs".into(), MatValue::Char("fast".into()));
    });
    expect_error(&text_fs, &[], &["text_fs.mat", "fs"]);
    let wrong_count = must_file(dir.path(), "count.mat", |_, p| {
        p.insert("Nelements".into(), MatValue::scalar(128.0));
    });
    expect_error(&wrong_count, &[], &["count.mat", "Nelements"]);
}

#[test]
fn non_finite_samples() {
    let dir = tempfile::tempdir().unwrap();
    let nan = must_file(dir.path(), "nan.mat", |rf, _| {
        let MatValue::Numeric { real, .. } = rf else {
            unreachable!()
        };
        real[10] = f64::NAN;
    });
    let (ok, stderr) = process(&nan, &[]);
    assert!(
        !ok && stderr.contains("nan.mat")
            && (stderr.contains("NaN") || stderr.contains("non-finite")),
        "{stderr}"
    );
}

#[test]
fn non_positive_physical_parameters() {
    let dir = tempfile::tempdir().unwrap();
    for (field, value) in [("fs", 0.0), ("c", -1540.0), ("pitch", 0.0)] {
        let path = must_file(dir.path(), &format!("bad_{field}.mat"), |_, p| {
            p.insert(field.into(), MatValue::scalar(value));
        });
        expect_error(&path, &[], &[&format!("bad_{field}.mat"), field]);
    }
}

#[test]
fn grid_outside_the_recorded_depth_and_malformed_grid() {
    let dir = tempfile::tempdir().unwrap();
    let ok = must_file(dir.path(), "ok.mat", |_, _| {});
    expect_error(
        &ok,
        &["--grid=-5,5,100,110,0.1"],
        &["grid", "deepest recorded depth"],
    );
    expect_error(&ok, &["--grid", "1,2,3"], &["--grid", "five numbers"]);
    expect_error(&ok, &["--svd-low", "many"], &["--svd-low"]);
    // Absurd sizes are refused before any allocation (a 1e-300 m step used to overflow the pixel
    // count and panic), and absurd estimator settings before any processing.
    expect_error(&ok, &["--grid=-1,1,5,6,1e-300"], &["--grid", "too many"]);
    expect_error(
        &ok,
        &["--grid=-1e308,1e308,5,6,0.1"],
        &["--grid", "too many"],
    );
    expect_error(&ok, &["--irls-lambda", "inf"], &["--irls-lambda", "λ"]);
    expect_error(&ok, &["--irls-epsilon", "0"], &["--irls-epsilon", "ε"]);
    expect_error(&ok, &["--irls-max-iterations", "0"], &["iteration cap"]);
    // More memory than allowed: refused before any work, with the estimate and its rule. The
    // 64 × 4 × 2 recording on a 1 µm grid over 10 × 1 mm: 10001 × 1001 pixels × 2 frames × 1
    // angle × 16 bytes ≈ 0.32 GB.
    expect_error(
        &ok,
        &["--grid=-5,5,1,2,0.001", "--max-memory-gb", "0.1"],
        &["needs about 0.3", "0.100 GB are available", "--grid"],
    );
    expect_error(&ok, &["--max-memory-gb=-1"], &["--max-memory-gb"]);
}

#[test]
fn unreadable_manifest_and_missing_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("broken.toml");
    std::fs::write(&path, "format = \"pcuvd-recording\"\nversion = 1\n[probe\n").unwrap();
    expect_error(&path, &[], &["broken.toml"]);
    let wrong_version = dir.path().join("v9.toml");
    std::fs::write(
        &wrong_version,
        "format = \"pcuvd-recording\"\nversion = 9\n",
    )
    .unwrap();
    expect_error(&wrong_version, &[], &["v9.toml", "version"]);
    expect_error(&dir.path().join("absent.mat"), &[], &["absent.mat"]);
    // A file of no format pcuvd reads: what it looks like, and the formats pcuvd reads.
    let csv = dir.path().join("data.csv");
    std::fs::write(&csv, "x,y\n1,2\n").unwrap();
    expect_error(
        &csv,
        &[],
        &[
            "data.csv",
            "not a recording pcuvd recognises",
            "text",
            "USTB UFF",
            ".toml",
        ],
    );
}
