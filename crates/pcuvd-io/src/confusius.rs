//! ConfUSIus's beamformed IQ in a Zarr v3 store: the folder ConfUSIus (the Python fUS toolbox)
//! writes when it converts a scanner's IQ (`convert_echoframe_dat_to_zarr`, `io.save`): a group
//! whose `iq` array holds complex images of dims (time, k, j, i), chunked along time, with the
//! voxel-to-world affine and the acquisition in its attributes (`compound_sampling_frequency`,
//! `transmit_frequency`, `beamforming_sound_velocity`, `plane_wave_angles`). Read as an images
//! manifest's images are ([`crate::images`]): one compound series, a range of frames at a time.
//!
//! ConfUSIus's world axes are (z, y, x) = (elevation, depth, lateral): voxel axis k runs across
//! the image plane, j down into the tissue and i along the array, so a plane's pixel (j, i) is
//! pcuvd's (z, x) pixel.

use std::path::Path;

use serde_json::Value;

use crate::error::IoError;
use crate::images::{ImagesHeader, Stored};
use crate::params::{ParamSource, Parameter};
use crate::recording::{SourceInfo, StoredSamples};

/// The array in the store that holds the IQ.
pub const IQ_ARRAY: &str = "iq";

/// The dims ConfUSIus gives beamformed IQ, in its order (`pose` only for multi-pose data).
const DIMS: [&str; 4] = ["time", "k", "j", "i"];

/// True when `path` is a folder holding a Zarr v3 group with an `iq` array (ConfUSIus's IQ).
pub fn is_store(path: &Path) -> bool {
    path.is_dir()
        && path.join("zarr.json").is_file()
        && path.join(IQ_ARRAY).join("zarr.json").is_file()
}

/// Reads what the ConfUSIus store at `path` says of its IQ (nothing of the images is read):
/// their shape and type, frame rate, demodulation frequency, speed of sound and pixel positions,
/// each checked, into the header an images manifest gives.
pub fn read_header(path: &Path) -> Result<ImagesHeader, IoError> {
    // zarrs parses and checks the whole metadata document (codecs, chunk grid, fill value), so a
    // store the reader could not decode is refused here, before any work, as `info` reads it.
    let array = crate::images::zarr_array(path, IQ_ARRAY)?;
    let zarrs::array::ArrayMetadata::V3(metadata) = array.metadata() else {
        return Err(IoError::malformed(
            path,
            format!("its {IQ_ARRAY} array is not Zarr v3, which ConfUSIus writes"),
        ));
    };
    let field = |name: &str| format!("{IQ_ARRAY}/zarr.json {name}");
    let dtype = metadata.data_type.name().to_string();
    let complex128 = dtype == "complex128";
    if dtype != "complex64" && !complex128 {
        return Err(IoError::invalid(
            path,
            field("data_type"),
            format!("is {dtype:?}: beamformed IQ images are complex (complex64 or complex128)"),
        ));
    }
    let shape: Vec<usize> = metadata.shape.iter().map(|&n| n as usize).collect();
    let dims: Vec<String> = metadata
        .dimension_names
        .iter()
        .flatten()
        .map(|name| name.clone().unwrap_or_default())
        .collect();
    // Multi-pose data of one pose is one plane too; (time, pose, k, j, i) is read past its pose.
    let plane_dims: Vec<&str> = dims
        .iter()
        .map(String::as_str)
        .filter(|d| *d != "pose")
        .collect();
    let pose_axis = dims.iter().position(|d| d == "pose");
    let pose_length = pose_axis.and_then(|p| shape.get(p).copied()).unwrap_or(1);
    // ConfUSIus's order: the pose, when there is one, right after time.
    if plane_dims != DIMS || shape.len() != dims.len() || pose_axis.is_some_and(|p| p != 1) {
        return Err(IoError::invalid(
            path,
            field("dimension_names"),
            format!(
                "are {dims:?} for shape {shape:?}; ConfUSIus's IQ has dims {DIMS:?} (time, \
                 elevation, depth, lateral)"
            ),
        ));
    }
    let length = |name: &str| dims.iter().position(|d| d == name).map_or(0, |p| shape[p]);
    let (frames, planes, nz, nx) = (length("time"), length("k"), length("j"), length("i"));
    if planes != 1 || pose_length != 1 {
        return Err(IoError::invalid(
            path,
            field("shape"),
            format!(
                "{shape:?} holds {planes} plane(s) of {pose_length} pose(s); pcuvd images one plane \
                 (k and pose of length 1)"
            ),
        ));
    }
    if frames < 2 || nz < 2 || nx < 2 {
        return Err(IoError::invalid(
            path,
            field("shape"),
            format!(
                "{shape:?} holds {frames} frame(s) of {nz} × {nx} pixels: Doppler needs 2 frames \
                 or more of 2 × 2 pixels or more"
            ),
        ));
    }
    let attributes = &metadata.attributes;
    let attribute = |name: &str| attributes.get(name).and_then(Value::as_f64);
    // The ranges an images manifest's numbers are held to: outside them, another unit.
    let within = |name: &str, what: &str, range: (f64, f64), unit: &str| match attribute(name) {
        Some(v) => {
            IoError::require_range(path, &field(&format!("attributes.{name}")), v, range, unit)
        }
        None => Err(IoError::missing(
            path,
            format!("{IQ_ARRAY}/zarr.json attributes"),
            format!("{name} ({what} ({unit})), which ConfUSIus's converters write"),
        )),
    };
    let frame_rate = within(
        "compound_sampling_frequency",
        "the frame rate",
        crate::images::FRAME_RATE_RANGE,
        "Hz",
    )?;
    let demodulation_frequency = within(
        "transmit_frequency",
        "the frequency the IQ was demodulated at",
        pcuvd::acquisition::probe::CENTER_FREQUENCY_RANGE,
        "Hz",
    )?;
    let (sound_speed, speed_given) = match attribute("beamforming_sound_velocity") {
        Some(_) => (
            within(
                "beamforming_sound_velocity",
                "the speed of sound",
                pcuvd::acquisition::channel::SOUND_SPEED_RANGE,
                "m/s",
            )?,
            true,
        ),
        None => (1540.0, false),
    };
    let (z, x) = pixel_positions(path, attributes, nz, nx)?;

    let from_store = |name: &str, value: Value, key: &str| Parameter {
        name: name.into(),
        value,
        source: ParamSource::File {
            field: format!("{IQ_ARRAY} attributes.{key}"),
        },
    };
    let mut parameters = vec![
        from_store(
            "frame_rate_hz",
            frame_rate.into(),
            "compound_sampling_frequency",
        ),
        from_store(
            "demod_frequency_hz",
            demodulation_frequency.into(),
            "transmit_frequency (the IQ taken as demodulated at the transmit frequency)",
        ),
        from_store(
            "x_m",
            serde_json::json!([x[0], x[nx - 1]]),
            "voxel_to_world (i)",
        ),
        from_store(
            "z_m",
            serde_json::json!([z[0], z[nz - 1]]),
            "voxel_to_world (j)",
        ),
        Parameter {
            name: "angles_deg".into(),
            value: serde_json::json!([0.0]),
            source: ParamSource::Default {
                note: format!(
                    "one compound series, read as a 0° plane wave's{}",
                    match attributes.get("plane_wave_angles") {
                        Some(angles) => format!(" (compounded from {angles} °)"),
                        None => String::new(),
                    }
                ),
            },
        },
    ];
    parameters.push(match speed_given {
        true => from_store(
            "sound_speed_m_s",
            sound_speed.into(),
            "beamforming_sound_velocity",
        ),
        false => Parameter {
            name: "sound_speed_m_s".into(),
            value: sound_speed.into(),
            source: ParamSource::Default {
                note: "soft tissue".into(),
            },
        },
    });
    let mut warnings = Vec::new();
    let chunk_frames = array
        .chunk_shape(&vec![0; shape.len()])
        .map_or(0, |chunk| chunk[0].get() as usize);
    let segment = pcuvd::pipeline::segments::MAX_SEGMENT_FRAMES;
    if chunk_frames > segment && frames > segment {
        warnings.push(format!(
            "the iq array's chunks hold {chunk_frames} frames each: a run in segments (of at most \
             {segment} frames by default) decodes whole chunks for each segment's frames, so each \
             chunk is read several times and held whole while read; rechunk along time (ConfUSIus's \
             volumes_per_chunk, or zarr's rechunking) for a long store"
        ));
    }
    let info = SourceInfo {
        files: store_files(path)?,
        format: "ConfUSIus beamformed IQ (Zarr v3)".into(),
        reader: "pcuvd_io::confusius (a range of frames at a time)".into(),
        parameters,
        stored: Some(StoredSamples {
            array: IQ_ARRAY.into(),
            shape,
            axes: dims,
            dtype,
            kind: "beamformed iq".into(),
        }),
        warnings,
        cardiac_triggers_s: None,
    };
    Ok(ImagesHeader {
        info,
        angles: vec![0.0],
        frames,
        grid: pcuvd::core::grid::Grid { x, z },
        frame_rate,
        demodulation_frequency,
        sound_speed,
        manifest: path.to_path_buf(),
        stored: Stored::Zarr {
            store: path.to_path_buf(),
            array: IQ_ARRAY.into(),
            complex128,
        },
        conjugate: false,
        aperture: None,
    })
}

/// Every file of the store at `path` (its metadata and chunks), in path order: what identifies
/// the input in a run's summary (each file's checksum), as a manifest and its `.npy` do.
fn store_files(path: &Path) -> Result<Vec<std::path::PathBuf>, IoError> {
    let mut files = Vec::new();
    let mut folders = vec![path.to_path_buf()];
    while let Some(folder) = folders.pop() {
        let entries = std::fs::read_dir(&folder).map_err(|e| IoError::io(&folder, "read", e))?;
        for entry in entries {
            let entry = entry.map_err(|e| IoError::io(&folder, "read", e))?;
            let kind = entry
                .file_type()
                .map_err(|e| IoError::io(&entry.path(), "read", e))?;
            if kind.is_dir() {
                folders.push(entry.path());
            } else if kind.is_file() {
                files.push(entry.path());
            }
        }
    }
    files.sort();
    Ok(files)
}

/// Depth and lateral pixel positions (m) from the `voxel_to_world` affine (4 × 4, rows z, y, x
/// of ConfUSIus's world, in `voxel_to_world_units`): the plane's pixel (j, i) lies at depth
/// y = A[1][1]·j + A[1][3] and lateral x = A[2][2]·i + A[2][3]. A rotated or oblique plane (any
/// other entry of the j and i columns not zero) is refused: pcuvd's grid is the probe's, and so
/// is a store without the affine (nothing else places its pixels).
fn pixel_positions(
    path: &Path,
    attributes: &serde_json::Map<String, Value>,
    nz: usize,
    nx: usize,
) -> Result<(Vec<f64>, Vec<f64>), IoError> {
    let field = format!("{IQ_ARRAY} attributes.voxel_to_world");
    let Some(given) = attributes.get("voxel_to_world") else {
        return Err(IoError::missing(
            path,
            format!("{IQ_ARRAY}/zarr.json attributes"),
            "voxel_to_world (the pixels' positions; ConfUSIus writes it with the IQ)",
        ));
    };
    let rows: Option<Vec<Vec<f64>>> = given.as_array().map(|rows| {
        rows.iter()
            .map(|r| {
                r.as_array()
                    .map_or(vec![], |r| r.iter().filter_map(Value::as_f64).collect())
            })
            .collect()
    });
    let affine: [[f64; 4]; 4] = match rows {
        Some(rows) if rows.len() == 4 && rows.iter().all(|r| r.len() == 4) => {
            std::array::from_fn(|i| std::array::from_fn(|j| rows[i][j]))
        }
        _ => {
            return Err(IoError::invalid(
                path,
                field,
                format!("is {given}; a 4 × 4 matrix of numbers was expected"),
            ));
        }
    };
    let scale = match attributes
        .get("voxel_to_world_units")
        .and_then(Value::as_str)
    {
        None | Some("mm") | Some("millimeter") | Some("millimetre") => 1e-3,
        Some("m") | Some("meter") | Some("metre") => 1.0,
        Some("um") | Some("µm") | Some("micrometer") | Some("micrometre") => 1e-6,
        Some(other) => {
            return Err(IoError::invalid(
                path,
                format!("{IQ_ARRAY} attributes.voxel_to_world_units"),
                format!("is {other:?}; mm, m or µm was expected"),
            ));
        }
    };
    let oblique = [(0, 1), (2, 1), (0, 2), (1, 2)]
        .iter()
        .any(|&(row, column)| affine[row][column] != 0.0);
    let (dz, dx) = (affine[1][1], affine[2][2]);
    if oblique || !(dz.is_finite() && dz > 0.0 && dx.is_finite() && dx > 0.0) {
        return Err(IoError::invalid(
            path,
            field,
            format!(
                "is {affine:?}: pcuvd reads a plane whose depth grows with j and lateral position \
                 with i (A[1][1] > 0, A[2][2] > 0, no rotation between them)"
            ),
        ));
    }
    let axis = |origin: f64, step: f64, n: usize| -> Vec<f64> {
        (0..n).map(|k| (origin + step * k as f64) * scale).collect()
    };
    Ok((axis(affine[1][3], dz, nz), axis(affine[2][3], dx, nx)))
}
