use std::path::{Path, PathBuf};

use ndarray::{Array, Array3, Array4};
use num_complex::Complex32;
use pcuvd::{Acquisition, Coding, Hadamard, Probe, Samples, Sequence, TransmitCode, TransmitPulse};

use super::*;
use crate::npy::write_npy;

fn acquisition(n_angles: usize, coding: Coding, probe: Probe) -> Acquisition {
    Acquisition {
        probe,
        sequence: Sequence {
            angles: Sequence::evenly_spaced_angles(n_angles, 15f64.to_radians()),
            event_prf: 14.4e3,
            coding,
            pulse_cycles: 2.0,
            pulse: None,
        },
        sampling_frequency: 62.5e6,
        sound_speed: 1540.0,
        t0: 1.3e-7,
    }
}

fn small_probe() -> Probe {
    Probe {
        name: "tiny test array".into(),
        n_elements: 6,
        pitch: 2.1e-4,
        element_width: 1.9e-4,
        center_frequency: 7.1e6,
        bandwidth: 0.61,
    }
}

fn rf(events: usize, ch: usize, s: usize) -> Array3<f32> {
    Array::from_shape_fn((events, ch, s), |(e, c, k)| {
        ((e * 131 + c * 17 + k * 7) % 97) as f32 * 0.37 - 11.0
    })
}

#[test]
fn round_trip_rf_and_iq_coded_and_conventional() {
    let dir = tempfile::tempdir().unwrap();
    let mut prov = toml::Table::new();
    prov.insert("seed".into(), toml::Value::Integer(7));
    let mut sub = toml::Table::new();
    sub.insert("noise_snr_db".into(), toml::Value::Float(20.0));
    prov.insert("noise".into(), toml::Value::Table(sub));
    let cases = [
        (
            acquisition(4, Coding::Hadamard { slot_delay: 1e-6 }, small_probe()),
            true,
        ),
        (acquisition(3, Coding::Conventional, small_probe()), false),
        (acquisition(3, Coding::Conventional, small_probe()), true),
        (
            acquisition(8, Coding::Hadamard { slot_delay: 1e-6 }, Probe::l22_14vx()),
            false,
        ),
    ];
    for (i, (acq, iq)) in cases.into_iter().enumerate() {
        let n = acq.sequence.n_angles();
        let ch = acq.probe.n_elements;
        let r = rf(2 * n, ch, 9);
        let samples = if iq {
            Samples::Iq {
                data: r.mapv(|v| Complex32::new(v, -0.5 * v)),
                demod_frequency: 7.1e6,
            }
        } else {
            Samples::Rf(r)
        };
        let data = ChannelData {
            acquisition: acq,
            samples,
        };
        let stem = format!("rec{i}");
        let path = write_recording(dir.path(), &stem, &data, &prov).unwrap();
        assert_eq!(path, dir.path().join(format!("{stem}.toml")));
        let back = read_recording(&path).unwrap();
        assert_eq!(
            back.data,
            data,
            "case {i}:\n{}",
            std::fs::read_to_string(&path).unwrap()
        );
        assert_eq!(back.provenance, prov);
        assert_eq!(back.data_path, dir.path().join(format!("{stem}.npy")));
        assert_eq!(read_manifest(&path).unwrap(), data);
        // The npy is frames × angles × channels × samples.
        let arr = crate::npy::read_npy(&back.data_path).unwrap();
        assert_eq!(arr.shape(), &[2, n, ch, 9]);
    }
    // Empty provenance: no table written, empty table read.
    let data = ChannelData {
        acquisition: acquisition(2, Coding::Conventional, small_probe()),
        samples: Samples::Rf(rf(2, 6, 4)),
    };
    let path = write_recording(dir.path(), "bare", &data, &toml::Table::new()).unwrap();
    assert!(read_recording(&path).unwrap().provenance.is_empty());
    assert!(write_recording(dir.path(), "a/b", &data, &prov).is_err());
    let mut bad = data.clone();
    bad.acquisition.sound_speed = -1.0;
    assert!(write_recording(dir.path(), "bad", &bad, &prov).is_err());
}

/// Writes the example manifest next to a generated rf.npy; returns the manifest path.
fn example_in(dir: &Path, shape: (usize, usize, usize, usize)) -> PathBuf {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/recording.toml"
    ))
    .unwrap();
    let path = dir.join("recording.toml");
    std::fs::write(&path, text).unwrap();
    let a = Array4::from_shape_fn(shape, |(f, a, c, s)| (f + 2 * a + 3 * c + 5 * s) as f32);
    write_npy(&dir.join("rf.npy"), &a).unwrap();
    path
}

#[test]
fn the_example_manifest_parses() {
    let dir = tempfile::tempdir().unwrap();
    let path = example_in(dir.path(), (2, 8, 128, 16));
    let rec = read_recording(&path).unwrap();
    let a = &rec.data.acquisition;
    assert_eq!(a.probe, Probe::l22_14vx());
    assert_eq!(a.sequence.n_angles(), 8);
    assert!((a.sequence.angles[0] + 15f64.to_radians()).abs() < 1e-15);
    assert_eq!(a.sequence.coding, Coding::Hadamard { slot_delay: 1e-6 });
    assert_eq!(rec.data.samples.dim(), (16, 128, 16));
    assert_eq!(rec.data.n_frames(), 2);
    assert_eq!(rec.provenance["seed"].as_integer(), Some(42));
    // events = frame · n_angles + angle.
    if let Samples::Rf(x) = &rec.data.samples {
        let (f, an, c, s) = (1, 3, 10, 4);
        assert_eq!(x[[f * 8 + an, c, s]], (f + 2 * an + 3 * c + 5 * s) as f32);
    }
}

#[test]
fn any_axis_order_and_dtype() {
    let dir = tempfile::tempdir().unwrap();
    let path = example_in(dir.path(), (2, 8, 128, 16));
    let reference = read_manifest(&path).unwrap();
    let Samples::Rf(r) = &reference.samples else {
        unreachable!()
    };
    let r4 = r.clone().into_shape_with_order((2, 8, 128, 16)).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    // samples, channels, angles, frames stored as f64.
    let p = r4.view().permuted_axes([3, 2, 1, 0]).mapv(f64::from);
    write_npy(&dir.path().join("rf.npy"), &p).unwrap();
    let t2 = text.replace(
        "axes = [\"frames\", \"angles\", \"channels\", \"samples\"]",
        "axes = [\"samples\", \"channels\", \"angles\", \"frames\"]",
    );
    std::fs::write(&path, &t2).unwrap();
    assert_eq!(read_manifest(&path).unwrap(), reference);
    // events × samples × channels as i16.
    let e = r.view().permuted_axes([0, 2, 1]).mapv(|v| v as i16);
    write_npy(&dir.path().join("rf.npy"), &e).unwrap();
    let t3 = text.replace(
        "axes = [\"frames\", \"angles\", \"channels\", \"samples\"]",
        "axes = [\"events\", \"samples\", \"channels\"]",
    );
    std::fs::write(&path, &t3).unwrap();
    assert_eq!(read_manifest(&path).unwrap(), reference);
}

#[test]
fn errors_name_the_file_and_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = example_in(dir.path(), (2, 8, 128, 16));
    let text = std::fs::read_to_string(&path).unwrap();
    let check = |edit: &dyn Fn(&str) -> String, wants: &[&str]| {
        let t = edit(&text);
        assert_ne!(t, text, "edit changed nothing (wanted {wants:?})");
        std::fs::write(&path, t).unwrap();
        let e = read_manifest(&path).unwrap_err().to_string();
        assert!(e.starts_with(&path.display().to_string()), "{e}");
        for w in wants {
            assert!(e.contains(w), "{e} (wanted {w})");
        }
    };
    let line_of = |needle: &str| {
        format!(
            "line {}",
            text.lines().position(|l| l.starts_with(needle)).unwrap() + 1
        )
    };
    let colour_line = format!(
        "line {}",
        text.lines()
            .position(|l| l.starts_with("n_elements"))
            .unwrap()
            + 2
    );
    let rep = |a: &'static str, b: &'static str| move |t: &str| t.replacen(a, b, 1);
    check(
        &rep("format = \"pcuvd-recording\"", "format = \"other\""),
        &["format is \"other\""],
    );
    check(
        &rep("version = 1 ", "version = 3 "),
        &["version is 3", "versions 1 to 2"],
    );
    // A percentage where a fraction is meant is refused, with the fraction suggested.
    let bandwidth_line = text
        .lines()
        .find(|l| l.starts_with("bandwidth"))
        .unwrap()
        .to_string();
    check(
        &|t: &str| t.replacen(&bandwidth_line, "bandwidth = 67", 1),
        &["bandwidth", "did you mean 0.67"],
    );
    check(
        &rep("format = \"pcuvd-recording\"", ""),
        &["has no key 'format'"],
    );
    check(
        &rep("n_elements = 128", "n_elements = 128\ncolour = 3"),
        &["unknown field `colour`", &colour_line],
    );
    check(
        &rep("sound_speed_m_s = 1540.0", ""),
        &["table [acquisition] has no key 'sound_speed_m_s'"],
    );
    check(
        &|t: &str| {
            t.replacen("preset = \"L22-14vX\"\n", "", 1)
                .replacen("pitch_m = 1.0e-4", "", 1)
        },
        &["table [probe] has no key 'pitch_m'"],
    );
    check(
        &rep("preset = \"L22-14vX\"", "preset = \"L99\""),
        &["[probe].preset", "L99"],
    );
    check(
        &rep(
            "\"frames\", \"angles\", \"channels\", \"samples\"]\n# demod",
            "\"frames\", \"angle\", \"channels\", \"samples\"]\n# demod",
        ),
        &["[data].axes is"],
    );
    check(
        &rep(
            "axes = [\"frames\", \"angles\", \"channels\", \"samples\"]\n# demod",
            "axes = [\"events\", \"channels\", \"samples\"]\n# demod",
        ),
        &["[data].axes names 3 axes", "has 4"],
    );
    check(
        &|t: &str| {
            t.replacen("angles_deg = [-15.0, ", "angles_deg = [", 1)
                .replacen("coding = \"hadamard\"", "coding = \"none\"", 1)
                .replacen("slot_delay_s = 1.0e-6", "", 1)
        },
        &["lists 7 angles", "has 8"],
    );
    check(
        &rep("angles_deg = [-15.0, ", "angles_deg = ["),
        &["no Hadamard matrix of order 7"],
    );
    check(
        &rep("n_elements = 128", "n_elements = 64"),
        &["[probe].n_elements is 64", "has 128"],
    );
    check(
        &rep("file = \"rf.npy\"", "file = \"nope.npy\""),
        &["[data].file", "nope.npy", "does not exist"],
    );
    check(
        &rep("kind = \"rf\"", "kind = \"iq\""),
        &["demod_frequency_hz"],
    );
    check(
        &rep("kind = \"rf\"", "kind = \"iq\"\ndemod_frequency_hz = 1.0e6"),
        &["holds real values"],
    );
    check(
        &rep("coding = \"hadamard\"", "coding = \"fancy\""),
        &["[acquisition].coding"],
    );
    check(
        &rep("coding = \"hadamard\"", "coding = \"none\""),
        &["slot_delay_s"],
    );
    check(
        &rep(
            "sampling_frequency_hz = 62.5e6",
            "sampling_frequency_hz = -62.5e6",
        ),
        &["sampling frequency"],
    );
    check(
        &rep("t0_s = 0.0", "t0_s = \"zero\""),
        &[&line_of("t0_s"), "invalid type"],
    );
    check(&rep("[data]", "[data"), &["line"]);
    let e = read_manifest(&dir.path().join("absent.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("absent.toml") && e.contains("cannot read"),
        "{e}"
    );
}

#[test]
fn truncated_npy_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = example_in(dir.path(), (2, 8, 128, 16));
    let npy = dir.path().join("rf.npy");
    let bytes = std::fs::read(&npy).unwrap();
    std::fs::write(&npy, &bytes[..bytes.len() - 4]).unwrap();
    let e = read_manifest(&path).unwrap_err().to_string();
    assert!(e.starts_with(&npy.display().to_string()), "{e}");
}

/// A recording written a block at a time is, file for file, the one written at once; a writer
/// abandoned or finished early leaves no samples and no manifest.
#[test]
fn streamed_recording_equals_the_one_written_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let acq = acquisition(4, Coding::Hadamard { slot_delay: 1e-6 }, small_probe());
    let samples = rf(5 * 4, 6, 11);
    let mut prov = toml::Table::new();
    prov.insert("seed".into(), toml::Value::Integer(3));
    let data = ChannelData {
        acquisition: acq.clone(),
        samples: Samples::Rf(samples.clone()),
    };
    let at_once = write_recording(&dir.path().join("a"), "rec", &data, &prov).unwrap();
    let mut writer =
        RecordingWriter::create(&dir.path().join("b"), "rec", &acq, samples.dim(), &prov).unwrap();
    // Blocks of 8, 8 and 4 events (2, 2 and 1 frames).
    for start in (0..20).step_by(8) {
        let block = samples.slice(ndarray::s![start..(start + 8).min(20), .., ..]);
        writer.append(block).unwrap();
    }
    let streamed = writer.finish().unwrap();
    for name in ["rec.toml", "rec.npy"] {
        assert_eq!(
            std::fs::read(at_once.with_file_name(name)).unwrap(),
            std::fs::read(streamed.with_file_name(name)).unwrap(),
            "{name}"
        );
    }
    assert_eq!(read_recording(&streamed).unwrap().data, data);
    // A block not contiguous in memory (column-major) is written value by value, the same bytes.
    let mut column_major = ndarray::Array3::<f32>::zeros(ndarray::ShapeBuilder::f(samples.dim()));
    column_major.assign(&samples);
    let mut writer =
        RecordingWriter::create(&dir.path().join("e"), "rec", &acq, samples.dim(), &prov).unwrap();
    writer.append(column_major.view()).unwrap();
    assert_eq!(
        std::fs::read(at_once.with_file_name("rec.npy")).unwrap(),
        std::fs::read(writer.finish().unwrap().with_file_name("rec.npy")).unwrap()
    );

    let folder = dir.path().join("c");
    let mut short = RecordingWriter::create(&folder, "rec", &acq, samples.dim(), &prov).unwrap();
    short
        .append(samples.slice(ndarray::s![0..8, .., ..]))
        .unwrap();
    let err = short
        .append(samples.slice(ndarray::s![0..16, .., ..]))
        .unwrap_err();
    assert!(err.to_string().contains("does not fit"), "{err}");
    let err = short.finish().unwrap_err();
    assert!(
        err.to_string().contains("8 events written of the 20"),
        "{err}"
    );
    let left: Vec<_> = std::fs::read_dir(&folder).unwrap().collect();
    assert!(left.is_empty(), "{left:?}");
    let mut bad = samples.clone();
    bad[[3, 2, 1]] = f32::NAN;
    let mut writer = RecordingWriter::create(&folder, "rec", &acq, samples.dim(), &prov).unwrap();
    assert!(
        writer
            .append(bad.view())
            .unwrap_err()
            .to_string()
            .contains("NaN")
    );
    drop(writer);
    assert_eq!(std::fs::read_dir(&folder).unwrap().count(), 0);

    // The heartbeats recorded beside the samples go into [cardiac] and read back as they were.
    let beats = vec![0.0, 1.0 / 5.5, 2.0 / 5.5];
    let mut writer =
        RecordingWriter::create(&dir.path().join("d"), "rec", &acq, samples.dim(), &prov)
            .unwrap()
            .with_cardiac_triggers(beats.clone());
    writer.append(samples.view()).unwrap();
    let with_beats = writer.finish().unwrap();
    let parsed = super::read::parse_manifest(&with_beats).unwrap();
    assert_eq!(parsed.cardiac_triggers_s, Some(beats));
    assert_eq!(read_recording(&with_beats).unwrap().data, data);
}

/// A Hadamard-coded recording of 3 frames × 4 events on 6 channels of `n_samples`, written as a
/// manifest in `dir`: the recording, its manifest, its samples file and the samples as stored,
/// (frames, events, channels, samples).
fn coded_recording(dir: &Path, n_samples: usize) -> (ChannelData, PathBuf, PathBuf, Array4<f32>) {
    let acq = acquisition(4, Coding::Hadamard { slot_delay: 1e-6 }, small_probe());
    let samples = rf(3 * 4, 6, n_samples);
    let data = ChannelData {
        acquisition: acq,
        samples: Samples::Rf(samples.clone()),
    };
    let manifest = write_recording(dir, "rec", &data, &toml::Table::new()).unwrap();
    let npy = manifest.with_file_name("rec.npy");
    let four = samples.into_shape_with_order((3, 4, 6, n_samples)).unwrap();
    (data, manifest, npy, four)
}

/// A block read from a samples file is refused when it holds a NaN or an infinity, wherever it
/// lies in the block (its first value, the first of a later run tested after reading, its last),
/// and only in the blocks that hold it; doubles beyond f32's range are infinite as f32 and
/// refused too; integer samples are read without a test (every one is finite).
#[test]
fn blocks_with_non_finite_samples_are_refused_where_they_lie() {
    use pcuvd::acquisition::source::FrameSource;
    let dir = tempfile::tempdir().unwrap();
    // 6 channels × 4,000 samples: a frame of 4 events is 384 kB of f32, so a block of two
    // frames spans three runs of 256 kB tested apart.
    let (data, manifest, npy, four) = coded_recording(dir.path(), 4000);
    let per_frame = 4 * 6 * 4000;
    let at = |i: usize| {
        let (f, rest) = (i / per_frame, i % per_frame);
        [f, rest / 24000, rest / 4000 % 6, rest % 4000]
    };
    let refused = |range: std::ops::Range<usize>| {
        let frames = crate::ManifestFrames::open(&manifest).unwrap().unwrap();
        match frames.read_frames(range) {
            Ok(_) => None,
            Err(e) => Some(e.to_string()),
        }
    };
    // Read in runs, the block is the recording.
    let clean = crate::ManifestFrames::open(&manifest).unwrap().unwrap();
    assert_eq!(
        clean.read_frames(0..3).unwrap(),
        data.read_frames(0..3).unwrap()
    );
    // Values 0, 65,536 (the second run's first, in a block from frame 0), the last of frame 1.
    for (i, bad) in [
        (0, f32::NAN),
        (65_536, f32::INFINITY),
        (2 * per_frame - 1, f32::NEG_INFINITY),
    ] {
        let mut f4 = four.clone();
        f4[at(i)] = bad;
        ndarray_npy::write_npy(&npy, &f4).unwrap();
        let err = refused(0..2).unwrap_or_else(|| panic!("{bad} at {i} passed"));
        assert!(err.contains("NaN or Inf") && err.contains("0..2"), "{err}");
        assert_eq!(
            refused(2..3),
            None,
            "{bad} at {i} refused a block without it"
        );
        let mut f8 = four.mapv(f64::from);
        f8[at(i)] = if bad.is_nan() { f64::NAN } else { 1e300 };
        ndarray_npy::write_npy(&npy, &f8).unwrap();
        assert!(refused(0..2).is_some(), "{bad} at {i} as a double passed");
        assert_eq!(refused(2..3), None);
    }
    ndarray_npy::write_npy(&npy, &four.mapv(|v| (v * 100.0).round() as i16)).unwrap();
    assert_eq!(refused(0..3), None);
}

/// A manifest's samples read a block of frames at a time are the recording read whole, for each
/// stored dtype; samples in another axis order are left to the whole reader.
#[test]
fn frames_read_in_blocks_are_the_recording() {
    use pcuvd::acquisition::source::FrameSource;
    let dir = tempfile::tempdir().unwrap();
    let (_, manifest, npy, four) = coded_recording(dir.path(), 11);
    // float32 as written, then float64 and int16 (integer values survive every dtype).
    for rewrite in 0..3 {
        match rewrite {
            1 => ndarray_npy::write_npy(&npy, &four.mapv(f64::from)).unwrap(),
            2 => ndarray_npy::write_npy(&npy, &four.mapv(|v| (v * 100.0).round() as i16)).unwrap(),
            _ => {}
        }
        let whole = read_recording(&manifest).unwrap().data;
        let frames = crate::ManifestFrames::open(&manifest)
            .unwrap()
            .expect("event order");
        assert_eq!(frames.n_frames(), 3);
        assert_eq!(frames.trace_shape(), (6, 11));
        assert_eq!(frames.resident_bytes(), 0);
        for range in [0..3, 1..2, 2..3] {
            assert_eq!(
                frames.read_frames(range.clone()).unwrap(),
                whole.read_frames(range).unwrap(),
                "dtype case {rewrite}"
            );
        }
        // Into the previous block's memory, as processing reads them: shorter, longer (beyond
        // the memory's room) and the same length again.
        let mut block = None;
        for range in [1..2, 0..3, 2..3, 0..2, 1..3] {
            frames.read_frames_into(range.clone(), &mut block).unwrap();
            assert_eq!(
                block.as_ref().unwrap(),
                &whole.read_frames(range).unwrap(),
                "dtype case {rewrite}, into a reused block"
            );
        }
        assert!(frames.read_frames(2..4).is_err());
    }
    // Another axis order: read whole instead.
    let text = std::fs::read_to_string(&manifest).unwrap().replace(
        "axes = [\"frames\", \"angles\", \"channels\", \"samples\"]",
        "axes = [\"angles\", \"frames\", \"channels\", \"samples\"]",
    );
    std::fs::write(&manifest, text).unwrap();
    ndarray_npy::write_npy(
        &npy,
        &four
            .clone()
            .permuted_axes([1, 0, 2, 3])
            .as_standard_layout(),
    )
    .unwrap();
    assert!(crate::ManifestFrames::open(&manifest).unwrap().is_none());
    // A truncated samples file is refused when opened, not half-way through processing.
    ndarray_npy::write_npy(&npy, &four).unwrap();
    let bytes = std::fs::read(&npy).unwrap();
    let text = std::fs::read_to_string(&manifest).unwrap().replace(
        "axes = [\"angles\", \"frames\", \"channels\", \"samples\"]",
        "axes = [\"frames\", \"angles\", \"channels\", \"samples\"]",
    );
    std::fs::write(&manifest, text).unwrap();
    std::fs::write(&npy, &bytes[..bytes.len() - 4]).unwrap();
    let err = crate::ManifestFrames::open(&manifest)
        .unwrap_err()
        .to_string();
    assert!(err.contains("data bytes"), "{err}");
}

/// Writes the version 2 example manifest next to a generated rf.npy of `frames` frames; returns
/// the manifest path.
fn example_v2_in(dir: &Path, frames: usize, samples: usize) -> PathBuf {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/recording_v2.toml"
    ))
    .unwrap();
    let path = dir.join("recording.toml");
    std::fs::write(&path, text).unwrap();
    let a = Array4::from_shape_fn((frames, 4, 16, samples), |(f, e, c, s)| {
        (f + 2 * e + 3 * c + 5 * s) as f32
    });
    write_npy(&dir.join("rf.npy"), &a).unwrap();
    path
}

/// The version 2 example: angles and slot starts derived from delays on a 4 ns clock (within
/// that clock of the angles and starts the delays were made from), the code matrix in the
/// scanner's row order, the sampled pulse, and the per-frame "events" axis.
#[test]
fn the_v2_example_manifest_parses() {
    let dir = tempfile::tempdir().unwrap();
    let path = example_v2_in(dir.path(), 2, 32);
    let rec = read_recording(&path).unwrap();
    let a = &rec.data.acquisition;
    let seq = &a.sequence;
    let nominal = [-10.0, -10.0 / 3.0, 10.0 / 3.0, 10.0];
    let starts = [0.0, 1.1e-6, 2.048e-6, 3.2e-6];
    // 2 ns of delay error over the 4.5 mm aperture is 0.04° at most.
    for (k, angle) in seq.angles.iter().enumerate() {
        assert!(
            (angle.to_degrees() - nominal[k]).abs() < 0.05,
            "slot {k}: {}°",
            angle.to_degrees()
        );
    }
    let Coding::Matrix(code) = &seq.coding else {
        panic!("{:?}", seq.coding)
    };
    for (k, start) in code.slot_starts.iter().enumerate() {
        assert!((start - starts[k]).abs() < 4e-9, "slot {k}: {start}");
    }
    assert_eq!(code.weights[..4], [1.0, -1.0, 1.0, -1.0]);
    assert_eq!(code.weights[8..12], [-1.0, -1.0, 1.0, 1.0]);
    assert_eq!(code.decoding_gain(), 4.0);
    let pulse = seq.pulse.as_ref().unwrap();
    assert_eq!(pulse.samples.len(), 66);
    assert_eq!(pulse.sampling_frequency, 250e6);
    // pulse_cycles left out: the pulse's length in cycles of f_c.
    assert!((seq.pulse_cycles - 66.0 / 250e6 * 7.6e6).abs() < 1e-12);
    assert_eq!(rec.data.samples.dim(), (8, 16, 32));
    // events = frame · 4 + event of the frame.
    if let Samples::Rf(x) = &rec.data.samples {
        let (f, e, c, s) = (1, 2, 10, 4);
        assert_eq!(x[[f * 4 + e, c, s]], (f + 2 * e + 3 * c + 5 * s) as f32);
    }
}

/// A version 2 recording written and read back is the one written, bit for bit: explicit codes
/// (a scrambled Hadamard with uneven starts, one slot per event with late starts), a sampled
/// pulse, RF and IQ; the manifest says version 2 and names the "events" axis. A recording version
/// 1 can say is still written as version 1.
#[test]
fn v2_recordings_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let h = Hadamard::new(4).unwrap();
    let scrambled = TransmitCode {
        weights: (0..16)
            .map(|j| [1.0, -1.0, -1.0, 1.0][j / 4] * h.get([1, 3, 0, 2][j / 4], j % 4) as f64)
            .collect(),
        slot_starts: vec![0.25e-6, 1.0e-6, 2.125e-6, 2.9e-6],
    };
    let pulse = TransmitPulse {
        samples: vec![0.0, 0.7, 1.0, -0.3, -1.0, -0.6, 0.2, 0.0],
        sampling_frequency: 100e6,
    };
    let mut cases = Vec::new();
    let mut acq = acquisition(4, Coding::Matrix(scrambled.clone()), small_probe());
    cases.push((acq.clone(), false));
    acq.sequence.pulse = Some(pulse.clone());
    cases.push((acq.clone(), true));
    let late = TransmitCode::one_per_event(vec![0.0, 0.5e-6, 1e-6]);
    cases.push((acquisition(3, Coding::Matrix(late), small_probe()), false));
    let decoded = Coding::Decoded {
        polarity: vec![1.0, -1.0, 1.0, -1.0],
    };
    cases.push((acquisition(4, decoded, small_probe()), true));
    let mut pulsed = acquisition(2, Coding::Conventional, small_probe());
    pulsed.sequence.pulse = Some(pulse);
    cases.push((pulsed, false));
    for (i, (acq, iq)) in cases.into_iter().enumerate() {
        let n = acq.sequence.n_angles();
        let r = rf(3 * n, 6, 9);
        let samples = if iq {
            Samples::Iq {
                data: r.mapv(|v| Complex32::new(v, 0.25 * v)),
                demod_frequency: 7.1e6,
            }
        } else {
            Samples::Rf(r)
        };
        let data = ChannelData {
            acquisition: acq,
            samples,
        };
        let path =
            write_recording(dir.path(), &format!("v2_{i}"), &data, &toml::Table::new()).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("version = 2\n"), "{text}");
        assert!(
            text.contains("axes = [\"frames\", \"events\", \"channels\", \"samples\"]"),
            "{text}"
        );
        assert_eq!(
            read_recording(&path).unwrap().data,
            data,
            "case {i}:\n{text}"
        );
    }
    let v1 = ChannelData {
        acquisition: acquisition(4, Coding::Hadamard { slot_delay: 1e-6 }, small_probe()),
        samples: Samples::Rf(rf(8, 6, 9)),
    };
    let path = write_recording(dir.path(), "v1", &v1, &toml::Table::new()).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(
        text.contains("version = 1\n") && text.contains("\"angles\""),
        "{text}"
    );
}

/// The manifest version 1 writes holds the keys and values (every float to the bit) that pcuvd
/// wrote before version 2 existed, so readers of then read recordings written now as they read
/// those written then. (Its text was laid out by hand then, by the toml crate now.)
#[test]
fn version_1_manifests_are_written_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let data = ChannelData {
        acquisition: acquisition(2, Coding::Hadamard { slot_delay: 1e-6 }, small_probe()),
        samples: Samples::Rf(rf(4, 6, 3)),
    };
    let path = write_recording(dir.path(), "old", &data, &toml::Table::new()).unwrap();
    let expected = "# pcuvd recording manifest (SI units; the unit is in each key's name).
format = \"pcuvd-recording\"
version = 1

[probe]
name = \"tiny test array\"
n_elements = 6
pitch_m = 0.00021
element_width_m = 0.00019
center_frequency_hz = 7100000.0
bandwidth = 0.61  # two-way -6 dB fractional bandwidth

[acquisition]
sampling_frequency_hz = 62500000.0
sound_speed_m_s = 1540.0
t0_s = 1.3e-7
event_prf_hz = 14400.0
# angles in degrees: [-15.0000, 15.0000]
angles_rad = [-0.2617993877991494, 0.2617993877991494]
pulse_cycles = 2.0
coding = \"hadamard\"
slot_delay_s = 1e-6

[data]
file = \"old.npy\"
kind = \"rf\"
axes = [\"frames\", \"angles\", \"channels\", \"samples\"]
";
    let written: toml::Table = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert_eq!(written, toml::from_str::<toml::Table>(expected).unwrap());
}

/// Per-element delays of exact plane waves give the recording that their angles give (the
/// same angles to 1e-12 rad, the same conventional coding: every slot starts at 0).
#[test]
fn plane_waves_as_delays_read_as_their_angles() {
    let dir = tempfile::tempdir().unwrap();
    let acq = acquisition(3, Coding::Conventional, small_probe());
    let data = ChannelData {
        acquisition: acq.clone(),
        samples: Samples::Rf(rf(6, 6, 9)),
    };
    let path = write_recording(dir.path(), "rec", &data, &toml::Table::new()).unwrap();
    let xs = acq.probe.element_x();
    let aperture = acq.probe.aperture();
    let rows: Vec<String> = acq
        .sequence
        .angles
        .iter()
        .map(|&a| {
            let d: Vec<String> = xs
                .iter()
                .map(|&x| {
                    format!(
                        "{:?}",
                        pcuvd::core::geometry::element_firing_delay(x, a, aperture, 1540.0)
                    )
                })
                .collect();
            format!("[{}]", d.join(", "))
        })
        .collect();
    let text = std::fs::read_to_string(&path).unwrap();
    let angles_line = text.lines().find(|l| l.starts_with("angles_rad")).unwrap();
    let t2 = text.replace("version = 1", "version = 2").replace(
        angles_line,
        &format!("transmit_delays_s = [{}]", rows.join(", ")),
    );
    let t2 = t2.replace("\"angles\"", "\"events\"");
    std::fs::write(&path, t2).unwrap();
    let back = read_recording(&path).unwrap().data;
    assert_eq!(back.acquisition.sequence.coding, Coding::Conventional);
    for (a, b) in back
        .acquisition
        .sequence
        .angles
        .iter()
        .zip(&acq.sequence.angles)
    {
        assert!((a - b).abs() < 1e-12, "{a} vs {b}");
    }
    assert_eq!(back.samples, data.samples);
}

/// Version 2's keys, checked: each error names the key and says what is wrong.
#[test]
fn v2_errors_name_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let path = example_v2_in(dir.path(), 2, 32);
    let text = std::fs::read_to_string(&path).unwrap();
    let check = |edit: &dyn Fn(&str) -> String, wants: &[&str]| {
        let t = edit(&text);
        assert_ne!(t, text, "edit changed nothing (wanted {wants:?})");
        std::fs::write(&path, t).unwrap();
        let e = read_manifest(&path).unwrap_err().to_string();
        assert!(e.starts_with(&path.display().to_string()), "{e}");
        for w in wants {
            assert!(e.contains(w), "{e} (wanted {w})");
        }
    };
    let rep = |a: &'static str, b: &'static str| move |t: &str| t.replacen(a, b, 1);
    check(
        &rep("version = 2", "version = 1"),
        &["[acquisition].code_matrix", "version 2"],
    );
    // A focused row: element 7's delay 0.5 µs late.
    check(
        &rep("1200e-9, 1192e-9", "1700e-9, 1192e-9"),
        &[
            "[acquisition].transmit_delays_s",
            "row 1",
            "not a plane wave",
        ],
    );
    check(
        &rep("    [508e-9, 472e-9", "    [508e-9, 472e-9, 1e-9"),
        &["transmit_delays_s", "row 0", "17 delays", "16 elements"],
    );
    check(
        &rep(
            "coding = \"matrix\"",
            "angles_deg = [-10, -3.33, 3.33, 12]\ncoding = \"matrix\"",
        ),
        &["[acquisition].angles_deg", "slot 3", "12.0000°"],
    );
    check(
        &rep(
            "coding = \"matrix\"",
            "slot_delays_s = [0, 1e-6, 2e-6, 3e-6]\ncoding = \"matrix\"",
        ),
        &[
            "[acquisition].transmit_delays_s",
            "together with slot_delays_s",
        ],
    );
    check(
        &rep("    [1, 1, 1, 1],\n", ""),
        &["[acquisition].code_matrix", "3 rows", "4 rows of 4"],
    );
    check(
        &rep("    [1, 1, 1, 1],", "    [1, -1, 1, -1],"),
        &["[acquisition].code_matrix", "singular"],
    );
    check(
        &rep("    [1, 1, 1, 1],", "    [1, -1, 1, -0.999999],"),
        &["[acquisition].code_matrix", "ill-conditioned"],
    );
    // Decoded records: no code, no slot starts, a polarity of ±1 per angle.
    let decoded = |t: &str| {
        let start = t.find("transmit_delays_s = [").unwrap();
        let end = start + t[start..].find("],\n]\n").unwrap() + 5;
        let cut = format!(
            "{}angles_deg = [-10, -3.33, 3.33, 10]\n{}",
            &t[..start],
            &t[end..]
        );
        let start = cut.find("code_matrix = [").unwrap();
        let end = start + cut[start..].find("],\n]\n").unwrap() + 5;
        format!("{}{}", &cut[..start], &cut[end..]).replacen(
            "coding = \"matrix\"",
            "coding = \"decoded\"",
            1,
        )
    };
    let with =
        |extra: &'static str| move |t: &str| decoded(t).replacen("coding = \"decoded\"", extra, 1);
    check(
        &with("coding = \"decoded\"\nslot_delay_s = 1e-6"),
        &["[acquisition].slot_delay_s", "already decoded"],
    );
    check(
        &with("coding = \"decoded\"\npolarity = [1, -1, 1]"),
        &["polarity", "3 values", "4 angles"],
    );
    check(
        &with("coding = \"decoded\"\npolarity = [1, -1, 0.5, 1]"),
        &["polarity", "angle 2", "+1 or −1"],
    );
    check(
        &with("coding = \"hadamard\"\nslot_delay_s = 1e-6\npolarity = [1, 1, 1, 1]"),
        &["[acquisition].polarity", "coding = \"decoded\""],
    );
    check(
        &|t: &str| {
            let t = decoded(t).replacen("version = 2", "version = 1", 1);
            let (start, end) = (
                t.find("[acquisition.pulse]").unwrap(),
                t.find("[data]").unwrap(),
            );
            format!("{}{}", &t[..start], &t[end..])
        },
        &[
            "[acquisition].coding",
            "= \"decoded\" is only known to version 2",
        ],
    );
    std::fs::write(
        &path,
        with("coding = \"decoded\"\npolarity = [1, -1, 1, -1]")(&text),
    )
    .unwrap();
    assert_eq!(
        read_manifest(&path).unwrap().acquisition.sequence.coding,
        Coding::Decoded {
            polarity: vec![1.0, -1.0, 1.0, -1.0]
        }
    );
    check(
        &rep("coding = \"matrix\"", "coding = \"zigzag\""),
        &["[acquisition].coding", "\"matrix\""],
    );
    check(
        &rep(
            "sampling_frequency_hz = 250e6",
            "sampling_frequency_hz = 10e6",
        ),
        &["[acquisition.pulse].sampling_frequency_hz", "twice the top"],
    );
    check(
        &rep("sampling_frequency_hz = 250e6\n", ""),
        &["table [acquisition.pulse] has no key 'sampling_frequency_hz'"],
    );
    check(
        &rep("samples = [0, 0, 1,", "samples = [0, 0, nan,"),
        &["[acquisition.pulse].samples", "sample 2"],
    );
    check(
        &rep(
            "axes = [\"frames\", \"events\"",
            "axes = [\"frames\", \"angles\"",
        ),
        &["[data].axes", "named \"events\""],
    );
    check(
        &rep("[acquisition.pulse]", "[acquisition.pulse]\nshape = 2"),
        &["unknown field `shape`"],
    );
    // Without the delays: the angles, and when each slot fires, are required.
    let without_delays = |t: &str| {
        let a = t.find("transmit_delays_s = [").unwrap();
        let b = a + t[a..].find("],\n]\n").unwrap() + 5;
        format!("{}{}", &t[..a], &t[b..])
    };
    check(&without_delays, &["has no key 'angles_deg'"]);
    check(
        &|t: &str| {
            without_delays(t).replacen("coding = ", "angles_deg = [-9, -3, 3, 9]\ncoding = ", 1)
        },
        &["has no key 'slot_delays_s'"],
    );
    check(
        &|t: &str| {
            without_delays(t).replacen(
                "coding = ",
                "angles_deg = [-9, -3, 3, 9]\nslot_delays_s = [0, 1e-6]\ncoding = ",
                1,
            )
        },
        &["[acquisition].slot_delays_s", "2 slot starts for 4 angles"],
    );
    check(
        &|t: &str| {
            without_delays(t).replacen(
                "coding = ",
                "angles_deg = [-9, -3, 3, 9]\nslot_delays_s = [0, 1e-6, 2e-6, 200e-6]\ncoding = ",
                1,
            )
        },
        &[
            "[acquisition].slot_delays_s",
            "longer than the event period",
        ],
    );
}

/// Ranges of the keys both versions have: absurd values are refused naming the key.
#[test]
fn absurd_values_name_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let path = example_in(dir.path(), (2, 8, 128, 16));
    let text = std::fs::read_to_string(&path).unwrap();
    for (from, to, wants) in [
        (
            "sampling_frequency_hz = 62.5e6",
            "sampling_frequency_hz = 1e13",
            &["[acquisition].sampling_frequency_hz", "1e13"][..],
        ),
        (
            "sampling_frequency_hz = 62.5e6",
            "sampling_frequency_hz = 20e6",
            &["[acquisition].sampling_frequency_hz", "folds the RF band"],
        ),
        ("pitch_m = 1.0e-4", "pitch_m = 1e-300", &["[probe].pitch_m"]),
        ("pitch_m = 1.0e-4", "pitch_m = inf", &["[probe].pitch_m"]),
        (
            "element_width_m = 8.0e-5",
            "element_width_m = 2e-4",
            &["[probe].element_width_m", "wider than the pitch"],
        ),
        (
            "center_frequency_hz = 15.625e6",
            "center_frequency_hz = 15.625",
            &["[probe].center_frequency_hz", "5e6"],
        ),
        (
            "sound_speed_m_s = 1540.0",
            "sound_speed_m_s = 1.54",
            &["[acquisition].sound_speed_m_s"],
        ),
        (
            "event_prf_hz = 14400.0",
            "event_prf_hz = -1.0",
            &["[acquisition].event_prf_hz"],
        ),
        (
            "t0_s = 0.0",
            "t0_s = 1.0",
            &["[acquisition].t0_s", "event period"],
        ),
        (
            "pulse_cycles = 2.0",
            "pulse_cycles = 0.0",
            &["[acquisition].pulse_cycles"],
        ),
        (
            "slot_delay_s = 1.0e-6",
            "slot_delay_s = 1.0e-4",
            &["[acquisition].slot_delay_s", "event period"],
        ),
        (
            "angles_deg = [-15.0, ",
            "angles_deg = [-90.0, ",
            &["[acquisition].angles_deg", "−90"],
        ),
        (
            "angles_deg = [-15.0, -10.714285714285714",
            "angles_deg = [-15.0, -15.0",
            &["[acquisition].angles_deg", "same steering angle"],
        ),
        (
            "n_elements = 128",
            "n_elements = 0",
            &["[probe].n_elements"],
        ),
        (
            "kind = \"rf\"",
            "kind = \"iq\"\ndemod_frequency_hz = -5.0",
            &["[data].demod_frequency_hz"],
        ),
    ] {
        let t = text.replacen(from, to, 1);
        assert_ne!(t, text, "{from}");
        std::fs::write(&path, t).unwrap();
        let e = read_manifest(&path).unwrap_err().to_string();
        for w in wants {
            assert!(e.contains(w), "{e} (wanted {w})");
        }
    }
}

/// A block read in runs on every core feeds an attached checksum every byte once, in order, each
/// run from the block's own memory as it is read: none is read from the file again as a gap
/// (which a run offered before the runs ahead of it would be). The file's tail, which no block
/// reads, comes at the end.
// Runs are read where the system reads a file at an offset from several cores (Unix).
#[cfg(unix)]
#[test]
fn a_block_is_fed_to_the_checksum_run_by_run_in_the_files_order() {
    use pcuvd::acquisition::source::FrameSource;
    use std::sync::{Arc, Mutex};
    /// Keeps each piece it is fed, and where in memory it was.
    type Fed = Arc<Mutex<Vec<(usize, Vec<u8>)>>>;
    struct Pieces(Fed);
    impl crate::ChecksumSink for Pieces {
        fn update(&mut self, bytes: &[u8]) {
            let at = bytes.as_ptr() as usize;
            self.0.lock().unwrap().push((at, bytes.to_vec()));
        }
        fn hex(self: Box<Self>) -> String {
            String::new()
        }
    }
    let dir = tempfile::tempdir().unwrap();
    // A frame of 4 events on 6 channels of 40,000 samples is 3.84 MB of f32: the first two
    // frames span 30 runs of 256 KiB, read into the block's own samples (f32, as stored).
    let (_, manifest, npy, _) = coded_recording(dir.path(), 40_000);
    let file = std::fs::read(&npy).unwrap();
    let frames = crate::ManifestFrames::open(&manifest).unwrap().unwrap();
    let fed: Fed = Arc::default();
    frames.read_pass().attach(Box::new(Pieces(fed.clone())));
    let block = frames.read_frames(0..2).unwrap();
    let Samples::Rf(samples) = &block.samples else {
        panic!("RF samples")
    };
    let memory = samples.as_ptr() as usize..samples.as_ptr() as usize + samples.len() * 4;
    // The same frames again add nothing.
    frames.read_frames(0..2).unwrap();
    let done = frames.read_pass().finish().unwrap().unwrap();
    assert_eq!(done.size_bytes, file.len() as u64);
    let fed = fed.lock().unwrap();
    let bytes: Vec<u8> = fed.iter().flat_map(|(_, b)| b.iter().copied()).collect();
    assert!(bytes == file, "every byte once, in order");
    let header = file.len() - 3 * 4 * 6 * 40_000 * 4;
    assert_eq!(fed[0].1.len(), header, "the header first, as a gap");
    let runs = &fed[1..fed.len() - 1];
    assert_eq!(runs.len(), memory.len().div_ceil(256 << 10));
    assert!(
        runs.iter().all(|(at, _)| memory.contains(at)),
        "a run read from the file again"
    );
    assert!(
        !memory.contains(&fed.last().unwrap().0),
        "the tail from the file"
    );
}
