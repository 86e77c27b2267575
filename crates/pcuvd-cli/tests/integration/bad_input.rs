//! Bad input gives one clear message naming the file, the field and the problem, exit code 2, and
//! never a panic or a backtrace (with `RUST_BACKTRACE=1` set, as on the machines that run this).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use pcuvd_io::{MatValue, write_mat};

/// Runs `pcuvd process INPUT --out …` with extra args; returns (success, stderr). A failure must
/// exit with code 2.
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
    if !result.status.success() {
        assert_eq!(result.status.code(), Some(2), "exit code: {stderr}");
    }
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

/// A small valid MUST-style recording (64 samples × 4 elements × 2 transmits), mutated by `edit`,
/// written compressed.
fn must_file(
    dir: &Path,
    name: &str,
    edit: impl FnOnce(&mut MatValue, &mut BTreeMap<String, MatValue>),
) -> PathBuf {
    must_file_as(dir, name, edit, true)
}

/// As [`must_file`], compressed or not.
fn must_file_as(
    dir: &Path,
    name: &str,
    edit: impl FnOnce(&mut MatValue, &mut BTreeMap<String, MatValue>),
    compress: bool,
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
    write_mat(&path, &[("RF", &rf), ("param", &param)], compress).unwrap();
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
        real.as_f64_mut()[10] = f64::NAN;
    });
    let (ok, stderr) = process(&nan, &[]);
    assert!(
        !ok && stderr.contains("nan.mat")
            && (stderr.contains("NaN") || stderr.contains("non-finite")),
        "{stderr}"
    );
}

/// A NaN in a later frame of a manifest's samples is found when its block is read, after the
/// output folder was made: the folder this run made, still empty, is removed with the refusal.
#[test]
fn a_refusal_after_planning_leaves_no_empty_folder() {
    let dir = tempfile::tempdir().unwrap();
    let path = pcuvd_io::write_recording(
        dir.path(),
        "late_nan",
        &base_recording(),
        &toml::Table::new(),
    )
    .unwrap();
    // The file's last sample (little-endian f32) is the second frame's: frame 0, which planning
    // reads, stays clean. pcuvd writes no NaN, so it is put in the file afterwards.
    let samples = dir.path().join("late_nan.npy");
    let mut bytes = std::fs::read(&samples).unwrap();
    let end = bytes.len();
    bytes[end - 4..].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&samples, bytes).unwrap();
    let out = dir.path().join("out");
    let run = |out: &Path| {
        Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .args(["--quiet", "process"])
            .arg(&path)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    let refused = run(&out);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("processing failed") && stderr.contains("NaN"),
        "{stderr}"
    );
    assert!(!out.exists(), "{} left behind", out.display());
    // A folder the user made stays, empty as it was.
    std::fs::create_dir(&out).unwrap();
    assert_eq!(run(&out).status.code(), Some(2));
    assert!(out.is_dir());
}

/// RF at Field II's scale (10⁻²² here) or far above any scanner's is refused, naming the
/// samples' peak and a factor into the range pcuvd's single-precision products hold, where it
/// would have given maps of noise or infinite power, before the output folder is made.
#[test]
fn samples_outside_the_single_precision_range() {
    let dir = tempfile::tempdir().unwrap();
    for (name, scale, needle) in [("tiny.mat", 1e-22, "below"), ("huge.mat", 1e17, "above")] {
        let path = must_file(dir.path(), name, |rf, _| {
            let MatValue::Numeric { real, .. } = rf else {
                unreachable!()
            };
            real.as_f64_mut().iter_mut().for_each(|v| *v *= scale);
        });
        expect_error(
            &path,
            &[],
            &[name, "sample scale", needle, "scale the samples into it"],
        );
        // Refused while planning, from frame 0: no output folder is left behind.
        let out = dir.path().join(format!("{name}-out"));
        let refused = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .args(["--quiet", "process"])
            .arg(&path)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert_eq!(refused.status.code(), Some(2));
        assert!(!out.exists(), "{} made for a refused run", out.display());
        // `pcuvd info` says so before any run.
        let info = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .arg("info")
            .arg(&path)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&info.stdout);
        assert!(info.status.success(), "{text}");
        assert!(
            text.contains("warning: process would refuse it: the samples of frame 0 peak at")
                && text.contains(needle),
            "{text}"
        );
    }
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
    // A grid in metres, read as millimetres: 10 µm wide in steps of 0.1 µm (it was imaged).
    expect_error(
        &ok,
        &["--grid=-0.005,0.005,0.005,0.006,0.0001"],
        &["--grid", "under a wavelength", "give it in millimetres"],
    );
    expect_error(&ok, &["--svd-low", "many"], &["--svd-low"]);
    expect_error(
        &ok,
        &["--svd-block-mm", "0"],
        &["--svd-block-mm", "positive"],
    );
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
    expect_error(&ok, &["--max-memory-gb=-1"], &["--max-memory-gb -1"]);
}

/// Under an address-space limit (`ulimit -v`, as a batch scheduler sets), a grid that the machine
/// could hold but the process may not is refused with what it needs and what bounds it, not
/// aborted on a failed allocation.
#[cfg(unix)]
#[test]
fn a_process_memory_limit_is_honoured() {
    let dir = tempfile::tempdir().unwrap();
    let frames = 8;
    let eight_frames = must_file(dir.path(), "eight.mat", |rf, _| {
        let (ns, ne) = (64usize, 4usize);
        let data: Vec<f64> = (0..ns * ne * frames)
            .map(|i| ((i * 37) % 19) as f64 - 9.0)
            .collect();
        *rf = MatValue::double(vec![ns, ne, frames], data).unwrap();
    });
    // 20001 × 2001 = 4·10⁷ pixels × 8 frames × 16 bytes ≈ 5 GB (2.6 GB in segments), against
    // 1.5 GB of address space.
    let out = dir.path().join("o");
    let result = Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 1500000 && exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_pcuvd"))
        .args(["--quiet", "process"])
        .arg(&eight_frames)
        .arg("--out")
        .arg(&out)
        .arg("--grid=-5,5,1,2,0.0005")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.code(), Some(2), "{stderr}");
    for needle in [
        "needs about 2.",
        "address-space limit (ulimit -v) of 1.536 GB",
        "--grid",
    ] {
        assert!(stderr.contains(needle), "{needle:?} missing from: {stderr}");
    }
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

/// A case of the table below: a label, the command's arguments, and what the message must say.
struct Case {
    label: String,
    args: Vec<std::ffi::OsString>,
    needles: Vec<String>,
}

/// The cases' files, in one folder.
struct Cases {
    dir: PathBuf,
    list: Vec<Case>,
}

impl Cases {
    /// `pcuvd process INPUT --out DIR/out_LABEL EXTRA…` must be refused with `needles`.
    fn process(&mut self, label: &str, input: &Path, extra: &[&str], needles: &[&str]) {
        let mut args: Vec<std::ffi::OsString> = vec!["process".into(), input.into()];
        args.push("--out".into());
        args.push(self.dir.join(format!("out_{label}")).into());
        args.extend(extra.iter().map(|a| a.into()));
        self.push(label, args, needles);
    }

    /// `pcuvd process INPUT --out OUT` must be refused with `needles`.
    fn process_to(&mut self, label: &str, input: &Path, out: &Path, needles: &[&str]) {
        let args = vec!["process".into(), input.into(), "--out".into(), out.into()];
        self.push(label, args, needles);
    }

    /// `pcuvd info INPUT` must be refused with `needles`.
    fn info(&mut self, label: &str, input: &Path, needles: &[&str]) {
        self.push(label, vec!["info".into(), input.into()], needles);
    }

    fn push(&mut self, label: &str, args: Vec<std::ffi::OsString>, needles: &[&str]) {
        self.list.push(Case {
            label: label.to_string(),
            args,
            needles: needles.iter().map(|n| n.to_string()).collect(),
        });
    }

    /// A manifest `LABEL.toml` holding `text` must be refused naming it and with `needles`.
    fn manifest(&mut self, label: &str, text: String, needles: &[&str]) {
        let path = self.dir.join(format!("{label}.toml"));
        std::fs::write(&path, text).unwrap();
        let mut with_name = vec![format!("{label}.toml")];
        with_name.extend(needles.iter().map(|n| n.to_string()));
        let with_name: Vec<&str> = with_name.iter().map(String::as_str).collect();
        self.process(label, &path, &[], &with_name);
    }

    /// The manifest `base` reading its samples from `LABEL.npy` holding `bytes` must be refused
    /// naming the samples file (where the problem is) and with `needles`.
    fn npy(&mut self, base: &str, label: &str, bytes: Vec<u8>, needles: &[&str]) {
        let name = format!("{label}.npy");
        std::fs::write(self.dir.join(&name), bytes).unwrap();
        let mut with_name = vec![name.clone()];
        with_name.extend(needles.iter().map(|n| n.to_string()));
        let with_name: Vec<&str> = with_name.iter().map(String::as_str).collect();
        let path = self.dir.join(format!("{label}.toml"));
        std::fs::write(&path, set(base, "file", &format!("file = \"{name}\""))).unwrap();
        self.process(label, &path, &[], &with_name);
    }

    /// Writes `bytes` to `name` in the cases' folder.
    fn file(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let path = self.dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    }
}

/// A valid recording manifest written by pcuvd ([`base_recording`]), samples in `base.npy`;
/// returns its text.
fn base_manifest(dir: &Path) -> String {
    let path =
        pcuvd_io::write_recording(dir, "base", &base_recording(), &toml::Table::new()).unwrap();
    std::fs::read_to_string(path).unwrap()
}

/// A small valid recording: Hadamard order 4, 2 frames of 4 events, 4 elements, 96 samples of RF.
fn base_recording() -> pcuvd::ChannelData {
    use pcuvd::{Acquisition, ChannelData, Coding, Probe, Samples, Sequence};
    let acquisition = Acquisition {
        probe: Probe {
            name: "small".into(),
            n_elements: 4,
            pitch: 3e-4,
            element_width: 2.5e-4,
            center_frequency: 5e6,
            bandwidth: 0.6,
        },
        sequence: Sequence {
            angles: vec![-0.1, -0.03, 0.03, 0.1],
            event_prf: 5e3,
            coding: Coding::Hadamard { slot_delay: 1e-6 },
            pulse_cycles: 2.0,
            pulse: None,
        },
        sampling_frequency: 20e6,
        sound_speed: 1540.0,
        t0: 0.0,
    };
    let samples = ndarray::Array3::from_shape_fn((8, 4, 96), |(e, c, s)| {
        ((e * 31 + c * 7 + s * 13) % 17) as f32 - 8.0
    });
    ChannelData {
        acquisition,
        samples: Samples::Rf(samples),
    }
}

/// `text` with the line that starts with `key =` replaced by `line` (removed when empty).
fn set(text: &str, key: &str, line: &str) -> String {
    let mut found = false;
    let out: Vec<&str> = text
        .lines()
        .filter_map(|l| {
            if !found && l.starts_with(&format!("{key} =")) {
                found = true;
                (!line.is_empty()).then_some(line)
            } else {
                Some(l)
            }
        })
        .collect();
    assert!(found, "no line {key} in\n{text}");
    out.join("\n") + "\n"
}

/// A .npy file's bytes: `descr` ('<f4'...), `shape`, then `data`.
fn npy_bytes(descr: &str, shape: &[usize], data: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    bytes.extend_from_slice(data);
    bytes
}

/// Every kind of bad input the issue names, in every format pcuvd reads, through the command:
/// each must exit with code 2 and one line naming the file, the field and the problem, without a
/// panic or a backtrace.
#[test]
fn every_bad_input_is_refused_naming_the_file_field_and_problem() {
    let tmp = tempfile::tempdir().unwrap();
    let mut cases = Cases {
        dir: tmp.path().to_path_buf(),
        list: vec![],
    };
    let dir = tmp.path().to_path_buf();

    // --- Paths that are not recording files, for every reader's extension.
    std::fs::create_dir(dir.join("folder.mat")).unwrap();
    std::fs::create_dir(dir.join("folder.toml")).unwrap();
    cases.process(
        "folder_mat",
        &dir.join("folder.mat"),
        &[],
        &["folder.mat", "is a folder"],
    );
    cases.process(
        "folder_toml",
        &dir.join("folder.toml"),
        &[],
        &["folder.toml", "is a folder"],
    );
    cases.info(
        "info_folder",
        &dir.join("folder.mat"),
        &["folder.mat", "is a folder"],
    );
    #[cfg(unix)]
    {
        let fifo = dir.join("pipe.mat");
        if std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .is_ok_and(|s| s.success())
        {
            cases.process("fifo", &fifo, &[], &["pipe.mat", "named pipe"]);
        }
        std::os::unix::fs::symlink(dir.join("loop_b.mat"), dir.join("loop_a.mat")).unwrap();
        std::os::unix::fs::symlink(dir.join("loop_a.mat"), dir.join("loop_b.mat")).unwrap();
        cases.process(
            "symlink_loop",
            &dir.join("loop_a.mat"),
            &[],
            &["loop_a.mat", "loop"],
        );
        std::os::unix::fs::symlink(dir.join("gone.mat"), dir.join("dangling.mat")).unwrap();
        cases.process(
            "dangling_link",
            &dir.join("dangling.mat"),
            &[],
            &["dangling.mat", "does not exist"],
        );
    }
    cases.process(
        "absent",
        &dir.join("absent.mat"),
        &[],
        &["absent.mat", "does not exist"],
    );
    let csv = cases.file("table.csv", b"1,2,3\n");
    cases.process(
        "unknown_extension",
        &csv,
        &[],
        &[
            "table.csv",
            "not a recording pcuvd recognises",
            "MATLAB",
            ".toml",
        ],
    );

    // --- MUST-style MATLAB v5 files.
    let ok_mat = must_file(&dir, "ok.mat", |_, _| {});
    let ok_bytes = std::fs::read(&ok_mat).unwrap();
    let empty = cases.file("empty.mat", b"");
    cases.process("mat_empty", &empty, &[], &["empty.mat", "it is empty"]);
    let short = cases.file("short.mat", &ok_bytes[..100]);
    cases.process(
        "mat_truncated_header",
        &short,
        &[],
        &["short.mat", "header"],
    );
    let cut = cases.file("cut.mat", &ok_bytes[..ok_bytes.len() / 2]);
    cases.process("mat_truncated_data", &cut, &[], &["cut.mat"]);
    let mut corrupt = ok_bytes.clone();
    for (i, b) in corrupt.iter_mut().enumerate().skip(128) {
        *b = (i * 151 % 251) as u8;
    }
    let corrupt = cases.file("corrupt.mat", &corrupt);
    cases.process("mat_corrupt", &corrupt, &[], &["corrupt.mat"]);
    let text = cases.file(
        "text.mat",
        b"this is not a MATLAB file, only some text\n"
            .repeat(8)
            .as_slice(),
    );
    cases.process("mat_not_matlab", &text, &[], &["text.mat", "MAT"]);
    let no_rf = dir.join("no_rf.mat");
    let mut param = BTreeMap::new();
    param.insert("fs".to_string(), MatValue::scalar(1e6));
    write_mat(&no_rf, &[("param", &MatValue::Struct(param))], false).unwrap();
    cases.process("mat_no_rf", &no_rf, &[], &["no_rf.mat", "RF"]);
    for field in ["fs", "pitch"] {
        let p = must_file(&dir, &format!("no_{field}.mat"), |_, p| {
            p.remove(field);
        });
        cases.process(
            &format!("mat_no_{field}"),
            &p,
            &[],
            &[&format!("no_{field}.mat"), field],
        );
    }
    let p = must_file(&dir, "rank4.mat", |rf, _| {
        *rf = MatValue::double(vec![8, 4, 2, 2], vec![1.0; 128]).unwrap();
    });
    cases.process("mat_wrong_rank", &p, &[], &["rank4.mat", "RF"]);
    let p = must_file(&dir, "char_rf.mat", |rf, _| {
        *rf = MatValue::Char("not samples".into());
    });
    cases.process("mat_wrong_dtype", &p, &[], &["char_rf.mat", "RF"]);
    let p = must_file(&dir, "text_fs.mat", |_, p| {
        p.insert("fs".into(), MatValue::Char("fast".into()));
    });
    cases.process("mat_text_field", &p, &[], &["text_fs.mat", "fs"]);
    let p = must_file(&dir, "count.mat", |_, p| {
        p.insert("Nelements".into(), MatValue::scalar(128.0));
    });
    cases.process("mat_axis_mismatch", &p, &[], &["count.mat", "Nelements"]);
    for (label, value, said) in [("nan", f64::NAN, "NaN"), ("inf", f64::INFINITY, "inf")] {
        let p = must_file(&dir, &format!("{label}.mat"), |rf, _| {
            let MatValue::Numeric { real, .. } = rf else {
                unreachable!()
            };
            real.as_f64_mut()[10] = value;
        });
        cases.process(
            &format!("mat_{label}_sample"),
            &p,
            &[],
            &[&format!("{label}.mat"), said],
        );
    }
    let p = must_file(&dir, "zeros.mat", |rf, _| {
        let MatValue::Numeric { real, .. } = rf else {
            unreachable!()
        };
        real.as_f64_mut().fill(0.0);
    });
    cases.process(
        "mat_all_zero",
        &p,
        &[],
        &["zeros.mat", "every sample is zero"],
    );
    for (field, value) in [
        ("fs", 0.0),
        ("fs", -20e6),
        ("fs", 1e13),
        ("c", -1540.0),
        ("c", 0.0),
        ("pitch", 0.0),
        ("pitch", -3e-4),
        ("PRF", 0.0),
        ("PRF", -5e3),
    ] {
        let name = format!("bad_{field}_{value}.mat").replace('-', "m");
        let p = must_file(&dir, &name, |_, p| {
            p.insert(field.into(), MatValue::scalar(value));
        });
        cases.process(&format!("mat_{field}_{value}"), &p, &[], &[&name, field]);
    }
    // 10 MHz sampling of a 5 MHz band 15 % wide: the band straddles f_s/2 = 5 MHz.
    let p = must_file(&dir, "folding.mat", |_, p| {
        p.insert("fs".into(), MatValue::scalar(10e6));
        p.insert("bandwidth".into(), MatValue::scalar(15.0));
    });
    cases.process(
        "mat_folding_band",
        &p,
        &[],
        &["folding.mat", "sampling frequency", "folds"],
    );
    // A header announcing 2³¹ − 1 samples per dimension (10²⁸ values) over a few hundred bytes.
    let small = must_file_as(&dir, "small_plain.mat", |_, _| {}, false);
    let mut bomb = std::fs::read(&small).unwrap();
    let dims: Vec<u8> = [64i32, 4, 2].iter().flat_map(|d| d.to_le_bytes()).collect();
    let at = bomb.windows(12).position(|w| w == dims.as_slice()).unwrap();
    for k in 0..3 {
        bomb[at + 4 * k..at + 4 * k + 4].copy_from_slice(&i32::MAX.to_le_bytes());
    }
    let bomb = cases.file("bomb.mat", &bomb);
    cases.process("mat_memory_bomb", &bomb, &[], &["bomb.mat"]);
    cases.process(
        "grid_below_record",
        &ok_mat,
        &["--grid=-5,5,100,110,0.1"],
        &["--grid", "deepest recorded depth"],
    );
    cases.info("info_mat_corrupt", &corrupt, &["corrupt.mat"]);

    // --- pcuvd recording manifests (.toml) and their .npy samples.
    let base = base_manifest(&dir);
    cases.manifest("toml_empty", String::new(), &["key 'format'"]);
    cases.manifest(
        "toml_binary",
        "\u{0}\u{1}\u{2}garbage\u{ff}".into(),
        &["line 1"],
    );
    cases.manifest(
        "toml_truncated",
        base[..base.len() / 2].to_string(),
        &["line"],
    );
    cases.manifest(
        "toml_wrong_format",
        set(&base, "format", "format = \"other\""),
        &["format"],
    );
    cases.manifest(
        "toml_wrong_version",
        set(&base, "version", "version = 7"),
        &["version is 7"],
    );
    cases.manifest(
        "toml_missing_table",
        base.replace("[probe]", "[probes]"),
        &["unknown field `probes`"],
    );
    cases.manifest(
        "toml_missing_key",
        set(&base, "sound_speed_m_s", ""),
        &["[acquisition]", "sound_speed_m_s"],
    );
    cases.manifest(
        "toml_unknown_key",
        set(&base, "t0_s", "t0_s = 0.0\nt0_us = 0.0"),
        &["unknown field `t0_us`", "line"],
    );
    cases.manifest(
        "toml_wrong_type",
        set(&base, "event_prf_hz", "event_prf_hz = \"fast\""),
        &["event_prf_hz", "invalid type"],
    );
    cases.manifest(
        "toml_bandwidth_percent",
        set(&base, "bandwidth", "bandwidth = 67"),
        &["[probe].bandwidth", "0.67"],
    );
    cases.manifest(
        "toml_wide_elements",
        set(&base, "element_width_m", "element_width_m = 4e-4"),
        &["[probe].element_width_m", "pitch"],
    );
    for (key, value, label) in [
        ("sampling_frequency_hz", "0.0", "zero_fs"),
        ("sampling_frequency_hz", "-2e7", "negative_fs"),
        ("sampling_frequency_hz", "1e13", "absurd_fs"),
        ("sampling_frequency_hz", "nan", "nan_fs"),
        ("sound_speed_m_s", "-1540.0", "negative_c"),
        ("sound_speed_m_s", "inf", "infinite_c"),
        ("pitch_m", "0.0", "zero_pitch"),
        ("pitch_m", "1e-300", "tiny_pitch"),
        ("event_prf_hz", "0.0", "zero_prf"),
        ("event_prf_hz", "-5e3", "negative_prf"),
        ("center_frequency_hz", "5.0", "fc_in_mhz"),
        ("t0_s", "1e300", "absurd_t0"),
        ("n_elements", "0", "no_elements"),
        ("slot_delay_s", "-1e-6", "negative_slot_delay"),
        ("slot_delay_s", "1e-3", "slots_beyond_period"),
    ] {
        let section = if ["pitch_m", "center_frequency_hz", "n_elements"].contains(&key) {
            "[probe]"
        } else {
            "[acquisition]"
        };
        cases.manifest(
            &format!("toml_{label}"),
            set(&base, key, &format!("{key} = {value}")),
            &[&format!("{section}.{key}")],
        );
    }
    let angles_line = base.lines().find(|l| l.starts_with("angles_rad")).unwrap();
    cases.manifest(
        "toml_identical_angles",
        base.replace(angles_line, "angles_rad = [-0.1, 0.0, 0.0, 0.1]"),
        &["[acquisition].angles_rad", "same steering angle"],
    );
    cases.manifest(
        "toml_no_hadamard_order",
        base.replace(angles_line, "angles_rad = [-0.1, 0.0, 0.1]"),
        &["[acquisition].coding", "no Hadamard matrix of order 3"],
    );
    cases.manifest(
        "toml_order_disagrees_with_data",
        base.replace(
            angles_line,
            "angles_rad = [-0.1, -0.05, -0.03, 0.0, 0.01, 0.03, 0.05, 0.1]",
        ),
        &["8 angles", "has 4"],
    );
    cases.manifest(
        "toml_axis_names_do_not_match_sizes",
        set(
            &base,
            "axes",
            "axes = [\"frames\", \"angles\", \"samples\", \"channels\"]",
        ),
        &["[probe].n_elements", "'channels' axis"],
    );
    cases.manifest(
        "toml_unknown_axis",
        set(
            &base,
            "axes",
            "axes = [\"frames\", \"angles\", \"channels\", \"time\"]",
        ),
        &["[data].axes"],
    );
    cases.manifest(
        "toml_axis_count",
        set(
            &base,
            "axes",
            "axes = [\"events\", \"channels\", \"samples\"]",
        ),
        &["[data].axes", "3 axes", "has 4"],
    );
    cases.manifest(
        "toml_kind_iq_for_real",
        set(&base, "kind", "kind = \"iq\"\ndemod_frequency_hz = 5e6"),
        &["[data].kind", "real values"],
    );
    cases.manifest(
        "toml_unknown_kind",
        set(&base, "kind", "kind = \"doppler\""),
        &["[data].kind"],
    );
    cases.manifest(
        "toml_folding_band",
        set(
            &base,
            "sampling_frequency_hz",
            "sampling_frequency_hz = 8e6",
        ),
        &["[acquisition].sampling_frequency_hz", "folds"],
    );
    cases.manifest(
        "toml_v2_key_in_v1",
        set(
            &base,
            "slot_delay_s",
            "slot_delays_s = [0.0, 1e-6, 2e-6, 3e-6]",
        ),
        &["[acquisition].slot_delays_s", "version 2"],
    );
    let v2 = set(
        &set(&base, "version", "version = 2"),
        "axes",
        "axes = [\"frames\", \"events\", \"channels\", \"samples\"]",
    );
    cases.manifest(
        "toml_v2_singular_code",
        set(
            &v2,
            "coding",
            "coding = \"matrix\"\ncode_matrix = [[1, 1, 1, 1], [1, 1, 1, 1], [1, -1, 1, -1], [1, 1, -1, -1]]",
        )
        .replace("slot_delay_s = 1e-6", "slot_delays_s = [0.0, 1e-6, 2e-6, 3e-6]"),
        &["[acquisition].code_matrix", "singular"],
    );
    cases.manifest(
        "toml_v2_focused_delays",
        v2.replace(
            angles_line,
            "transmit_delays_s = [[0, 1e-7, 1e-7, 0], [0, 2e-7, 2e-7, 0], [0, 3e-7, 3e-7, 0], [0, 4e-7, 4e-7, 0]]",
        )
        .replace("slot_delay_s = 1e-6\n", ""),
        &["[acquisition].transmit_delays_s", "not a plane wave"],
    );
    cases.manifest(
        "toml_v2_angles_axis",
        set(
            &v2,
            "axes",
            "axes = [\"frames\", \"angles\", \"channels\", \"samples\"]",
        ),
        &["[data].axes", "\"events\""],
    );
    cases.manifest(
        "toml_v2_slow_pulse",
        v2.replace(
            "[data]",
            "[acquisition.pulse]\nsampling_frequency_hz = 1e6\nsamples = [0, 1, -1, 0]\n\n[data]",
        ),
        &["[acquisition.pulse].sampling_frequency_hz"],
    );
    cases.manifest(
        "toml_slot_after_record",
        set(&base, "slot_delay_s", "slot_delay_s = 5e-5"),
        &["slot"],
    );
    // The samples file: absent, a folder, a loop, wrong dtype, truncated, corrupt, a memory bomb,
    // NaN, all zero.
    cases.manifest(
        "npy_absent",
        set(&base, "file", "file = \"nowhere.npy\""),
        &["[data].file", "nowhere.npy", "does not exist"],
    );
    std::fs::create_dir(dir.join("samples_folder.npy")).unwrap();
    cases.manifest(
        "npy_folder",
        set(&base, "file", "file = \"samples_folder.npy\""),
        &["[data].file", "is a folder"],
    );
    #[cfg(unix)]
    cases.manifest(
        "npy_symlink_loop",
        set(&base, "file", "file = \"loop_a.mat\""),
        &["[data].file", "loop"],
    );
    let base_npy = std::fs::read(dir.join("base.npy")).unwrap();
    let data_offset = base_npy.len() - 8 * 4 * 96 * 4;
    let payload = &base_npy[data_offset..];
    cases.npy(&base, "npy_empty", vec![], &[]);
    // One frame, valid in itself: refused before imaging, for what Doppler needs.
    std::fs::write(
        dir.join("one_frame.npy"),
        npy_bytes("<f4", &[1, 4, 4, 96], &payload[..payload.len() / 2]),
    )
    .unwrap();
    let one_frame = dir.join("one_frame.toml");
    std::fs::write(&one_frame, set(&base, "file", "file = \"one_frame.npy\"")).unwrap();
    cases.process(
        "one_frame",
        &one_frame,
        &[],
        &["holds 1 frame", "Doppler needs at least 2"],
    );
    cases.npy(
        &base,
        "npy_truncated",
        base_npy[..base_npy.len() - 100].to_vec(),
        &["data bytes"],
    );
    cases.npy(
        &base,
        "npy_garbage",
        b"\x93NUMPY\x01\x00\x10\x00{not a dict}   \n".to_vec(),
        &[],
    );
    cases.npy(
        &base,
        "npy_wrong_dtype",
        npy_bytes("|b1", &[2, 4, 4, 96], &vec![1u8; 2 * 4 * 4 * 96]),
        // The accepted types, every one of them (int8 and uint16 were read but not named).
        &[
            "b1",
            "int8, uint8, int16, uint16, int32, float32, float64, complex64 or complex128",
        ],
    );
    cases.npy(
        &base,
        "npy_wrong_rank",
        npy_bytes("<f4", &[8 * 4 * 96], payload),
        &["[data].axes"],
    );
    cases.npy(
        &base,
        "npy_memory_bomb",
        npy_bytes("<f4", &[1 << 20, 4, 4, 1 << 20], &payload[..256]),
        &["announces"],
    );
    let mut nan = payload.to_vec();
    nan[40..44].copy_from_slice(&f32::NAN.to_le_bytes());
    cases.npy(
        &base,
        "npy_nan",
        npy_bytes("<f4", &[2, 4, 4, 96], &nan),
        &["NaN"],
    );
    let mut inf = payload.to_vec();
    inf[400..404].copy_from_slice(&f32::NEG_INFINITY.to_le_bytes());
    cases.npy(
        &base,
        "npy_inf",
        npy_bytes("<f4", &[2, 4, 4, 96], &inf),
        &["NaN or Inf"],
    );
    std::fs::write(
        dir.join("all_zero.npy"),
        npy_bytes("<f4", &[2, 4, 4, 96], &vec![0u8; payload.len()]),
    )
    .unwrap();
    cases.manifest(
        "npy_all_zero",
        set(&base, "file", "file = \"all_zero.npy\""),
        &["samples", "every sample is zero"],
    );
    cases.npy(
        &base,
        "npy_big_endian_wrong_count",
        npy_bytes(">f8", &[2, 4, 4, 96], payload),
        &[],
    );

    // --- Options and output folders.
    let good = dir.join("base.toml");
    cases.process(
        "option_f_number",
        &good,
        &["--f-number", "0"],
        &["--f-number 0"],
    );
    cases.process(
        "option_window_ms",
        &good,
        &["--window-ms", "1e-300"],
        &["--window-ms 1e-300"],
    );
    cases.process(
        "option_kernel",
        &good,
        &["--doppler-kernel", "2x2"],
        &["--doppler-kernel", "odd"],
    );
    cases.process(
        "option_heart_rate",
        &good,
        &["--heart-rate", "1e-300"],
        &["--heart-rate 1e-300"],
    );
    cases.process("option_svd", &good, &["--svd-low", "lots"], &["--svd-low"]);
    cases.process(
        "option_svd_keeps_nothing",
        &good,
        &["--svd-low", "30", "--svd-high", "5"],
        &[
            "--svd-low / --svd-high",
            "low = 30, high = 5",
            "keep no component",
        ],
    );
    cases.process(
        "option_demod_of_rf",
        &good,
        &["--demod-freq-hz", "5e6"],
        &["--demod-freq-hz", "RF samples", "not used"],
    );
    cases.process(
        "option_sound_speed_zero",
        &good,
        &["--sound-speed-m-s", "0"],
        &["--sound-speed-m-s", "> 0, got 0"],
    );
    cases.process(
        "option_grid_step",
        &good,
        &["--grid=-1,1,1,6,1e-300"],
        &["--grid", "too many"],
    );
    let a_file = cases.file("not_a_folder", b"x");
    let mut args: Vec<std::ffi::OsString> = vec![
        "process".into(),
        good.clone().into(),
        "--out".into(),
        a_file.clone().into(),
    ];
    cases.push(
        "out_is_a_file",
        std::mem::take(&mut args),
        &["not_a_folder", "not a folder"],
    );
    let below_a_file = a_file.join("out");
    cases.process_to(
        "out_unwritable",
        &good,
        &below_a_file,
        &["not_a_folder", "cannot create"],
    );

    // Run them all, then report every failure at once.
    let count = cases.list.len();
    let mut failures = Vec::new();
    for case in &cases.list {
        let result = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .arg("--quiet")
            .args(&case.args)
            .env("RUST_BACKTRACE", "1")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr).into_owned();
        let mut problems = Vec::new();
        if result.status.code() != Some(2) {
            problems.push(format!("exit code {:?}", result.status.code()));
        }
        if stderr.contains("panicked") || stderr.to_lowercase().contains("backtrace") {
            problems.push("a panic or a backtrace".to_string());
        }
        if !stderr.starts_with("error: ") || stderr.trim_end().lines().count() != 1 {
            problems.push("not one line starting with \"error: \"".to_string());
        }
        for needle in &case.needles {
            if !stderr.contains(needle.as_str()) {
                problems.push(format!("no {needle:?}"));
            }
        }
        if !problems.is_empty() {
            failures.push(format!(
                "{}: {}\n    {}",
                case.label,
                problems.join(", "),
                stderr.trim_end()
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {count} cases failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert!(count >= 60, "only {count} cases");
}
