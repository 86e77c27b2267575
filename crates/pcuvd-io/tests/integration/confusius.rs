//! ConfUSIus's Zarr store of beamformed IQ, written by ConfUSIus itself
//! (`tests/fixtures/confusius/make_confusius_fixture.py`): what pcuvd reads of it against what
//! ConfUSIus says it holds, and the stores pcuvd refuses, each naming why.

use std::path::{Path, PathBuf};

use num_complex::Complex32;
use pcuvd_io::open::{is_images_input, read_images_header as read_header};
use serde_json::Value;

fn store() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/confusius/iq.zarr")
}

fn expected() -> Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/confusius/expected.json");
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn numbers(value: &Value) -> Vec<f64> {
    value
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect()
}

#[test]
fn the_header_is_what_confusius_wrote() {
    let expected = expected();
    assert!(is_images_input(&store()));
    let header = read_header(&store()).unwrap();
    let attributes = &expected["attributes"];
    assert_eq!(header.frames as u64, expected["frames"].as_u64().unwrap());
    assert_eq!(
        header.frame_rate,
        attributes["compound_sampling_frequency"].as_f64().unwrap()
    );
    assert_eq!(
        header.demodulation_frequency,
        attributes["transmit_frequency"].as_f64().unwrap()
    );
    assert_eq!(
        header.sound_speed,
        attributes["beamforming_sound_velocity"].as_f64().unwrap()
    );
    assert_eq!(header.angles, vec![0.0]);
    // ConfUSIus's own coordinates of the pixels (mm): y is depth, x lateral.
    for (read, given) in [
        (&header.grid.z, numbers(&expected["depth_mm"])),
        (&header.grid.x, numbers(&expected["lateral_mm"])),
    ] {
        assert_eq!(read.len(), given.len());
        for (r, g) in read.iter().zip(&given) {
            assert!((r - g * 1e-3).abs() < 1e-12, "{r} m against {g} mm");
        }
    }
    // Every file of the store identifies the input: its metadata and the iq array's chunk.
    let files = &header.info.files;
    assert!(
        files.iter().any(|f| f.ends_with("iq.zarr/zarr.json")),
        "{files:?}"
    );
    assert!(
        files.iter().any(|f| f.ends_with("iq.zarr/iq/zarr.json")),
        "{files:?}"
    );
    assert!(files.iter().all(|f| f.is_file()), "{files:?}");
    // Read as a recording, it says what it is and what reads it.
    let overrides = pcuvd_io::params::Overrides::default();
    let Err(error) = pcuvd_io::open_recording(&store(), &overrides) else {
        panic!("a store of images opened as a recording");
    };
    assert!(error.to_string().contains("pcuvd process"), "{error}");
}

#[test]
fn frames_read_in_ranges_are_the_arrays_numpy_holds() {
    let expected = expected();
    let header = read_header(&store()).unwrap();
    let file = header.images_file().unwrap();
    let (nz, nx) = header.grid.shape();
    let whole = file.read(0..header.frames).unwrap();
    for (t, kept) in expected["frames_kept"].as_object().unwrap() {
        let t: usize = t.parse().unwrap();
        let (re, im) = (&kept["re"], &kept["im"]);
        let one = file.read(t..t + 1).unwrap();
        for iz in 0..nz {
            for ix in 0..nx {
                let want = Complex32::new(
                    re[iz][ix].as_f64().unwrap() as f32,
                    im[iz][ix].as_f64().unwrap() as f32,
                );
                assert_eq!(
                    one.series[0][[iz, ix, 0]],
                    want,
                    "frame {t}, pixel ({iz}, {ix})"
                );
                assert_eq!(
                    whole.series[0][[iz, ix, t]],
                    want,
                    "frame {t}, pixel ({iz}, {ix})"
                );
            }
        }
    }
    let (empty, past_the_end) = (3..3, 0..header.frames + 1);
    assert!(file.read(empty).is_err() && file.read(past_the_end).is_err());
}

/// An edit of the `iq` array's metadata (`iq/zarr.json`).
type Edit = Box<dyn FnOnce(&mut serde_json::Map<String, Value>)>;

/// A copy of the store with its `iq/zarr.json` edited by `edit`.
fn edited(edit: impl FnOnce(&mut serde_json::Map<String, Value>)) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let copy = |from: &Path, to: &Path| {
        let mut folders = vec![(from.to_path_buf(), to.to_path_buf())];
        while let Some((from, to)) = folders.pop() {
            std::fs::create_dir_all(&to).unwrap();
            for entry in std::fs::read_dir(&from).unwrap() {
                let entry = entry.unwrap();
                let target = to.join(entry.file_name());
                if entry.file_type().unwrap().is_dir() {
                    folders.push((entry.path(), target));
                } else {
                    std::fs::copy(entry.path(), target).unwrap();
                }
            }
        }
    };
    let root = dir.path().join("iq.zarr");
    copy(&store(), &root);
    let metadata = root.join("iq/zarr.json");
    let mut json: serde_json::Map<String, Value> =
        serde_json::from_str(&std::fs::read_to_string(&metadata).unwrap()).unwrap();
    edit(&mut json);
    std::fs::write(&metadata, serde_json::to_string(&json).unwrap()).unwrap();
    dir
}

#[test]
fn stores_pcuvd_cannot_place_are_refused_naming_why() {
    let attributes = |json: &mut serde_json::Map<String, Value>| {
        json["attributes"].as_object_mut().unwrap().clone()
    };
    let cases: Vec<(Edit, &str)> = vec![
        (
            Box::new(|json| {
                json["attributes"]["voxel_to_world"][1][2] = 0.01.into();
            }),
            "no rotation",
        ),
        (
            Box::new(move |json| {
                let mut kept = attributes(json);
                kept.remove("compound_sampling_frequency");
                json["attributes"] = Value::Object(kept);
            }),
            "compound_sampling_frequency",
        ),
        // Numbers in another unit: the transmit frequency in MHz, the sound speed in mm/µs.
        (
            Box::new(|json| {
                json["attributes"]["transmit_frequency"] = 15.625.into();
            }),
            "attributes.transmit_frequency must be finite and within [2e4, 1e9] Hz, got \
             1.5625e1 Hz (check the unit)",
        ),
        (
            Box::new(|json| {
                json["attributes"]["beamforming_sound_velocity"] = 1.54.into();
            }),
            "attributes.beamforming_sound_velocity must be finite and within [3e2, 1e4] m/s, got \
             1.54e0 m/s (check the unit)",
        ),
        (
            Box::new(|json| {
                json["attributes"]["voxel_to_world_units"] = "furlong".into();
            }),
            "voxel_to_world_units",
        ),
        (
            Box::new(|json| {
                json["shape"][1] = 2.into();
            }),
            "one plane",
        ),
        (
            Box::new(|json| {
                json["dimension_names"] = serde_json::json!(["time", "k", "i", "j"]);
            }),
            "dimension_names",
        ),
        (
            Box::new(|json| {
                json["data_type"] = "float32".into();
                json["fill_value"] = 0.0.into();
            }),
            "complex",
        ),
        (
            Box::new(|json| {
                json["dimension_names"] = serde_json::json!(["pose", "time", "k", "j", "i"]);
                json["shape"] = serde_json::json!([1, 48, 1, 20, 24]);
                json["chunk_grid"]["configuration"]["chunk_shape"] =
                    serde_json::json!([1, 48, 1, 20, 24]);
            }),
            "dimension_names",
        ),
        // What the reader could not decode is refused with the header, as `info` reads it.
        (
            Box::new(|json| {
                json["codecs"][1]["name"] = "lz4hc".into();
            }),
            "cannot be opened as Zarr",
        ),
    ];
    for (edit, said) in cases {
        let dir = edited(edit);
        let store = dir.path().join("iq.zarr");
        let error = read_header(&store).unwrap_err().to_string();
        assert!(error.contains(said), "{said}: {error}");
        assert!(error.contains("iq.zarr"), "{error}");
    }
}

/// A store whose chunks hold more frames than a segment is read, with a warning that says what
/// that costs and how to rechunk (its metadata alone says so: nothing of the images is read).
#[test]
fn chunks_longer_than_a_segment_are_warned_of() {
    assert!(read_header(&store()).unwrap().info.warnings.is_empty());
    let dir = edited(|json: &mut serde_json::Map<String, Value>| {
        json["shape"][0] = 2000.into();
        json["chunk_grid"]["configuration"]["chunk_shape"][0] = 2000.into();
    });
    let header = read_header(&dir.path().join("iq.zarr")).unwrap();
    assert_eq!(header.frames, 2000);
    let warnings = header.info.warnings.join(" ");
    assert!(
        warnings.contains("2000 frames each") && warnings.contains("rechunk"),
        "{warnings}"
    );
}

/// A store of complex128 values is read into complex64: the same frames as the complex64 store
/// ConfUSIus wrote of the same images (whose values complex64 holds exactly).
#[test]
fn complex128_is_read_as_complex64() {
    let wide = store().with_file_name("iq_complex128.zarr");
    let header = read_header(&wide).unwrap();
    assert_eq!(header.info.stored.as_ref().unwrap().dtype, "complex128");
    let read = header.images_file().unwrap().read(0..8).unwrap();
    let narrow = read_header(&store())
        .unwrap()
        .images_file()
        .unwrap()
        .read(0..8)
        .unwrap();
    assert_eq!(read.series[0], narrow.series[0]);
}
