//! The images manifest: a TOML file (format "pcuvd-images", SI units with the unit in each key)
//! that describes beamformed IQ images formed elsewhere (a functional-ultrasound scanner's
//! compound images, another beamformer's output) and names the `.npy` file that holds them. What
//! Doppler needs of them is their frame rate, the frequency their IQ was demodulated at (which
//! turns phase into velocity), the speed of sound, the pixels' positions and the steering angle
//! of each series; nothing of the probe or the transmit sequence is needed, since the images are
//! already formed. See `crates/pcuvd-io/examples/images.toml`.

use std::ops::Range;
use std::path::Path;

use ndarray::Array3;
use num_complex::Complex32;
use pcuvd::core::grid::Grid;
use pcuvd::form::images::{AngleImages, ImageFrames};
use serde::Deserialize;

use crate::array::Block;
use crate::error::IoError;
use crate::params::{ParamSource, Parameter};
use crate::recording::{SourceInfo, StoredSamples};

/// The format string an images manifest starts with.
pub const FORMAT: &str = "pcuvd-images";

/// The newest version of the images manifest this reader reads.
pub const VERSION: u32 = 1;

/// The axes an images array may have, in any order: slow time, depth, lateral, and optionally
/// one series per steering angle.
const AXES: [&str; 4] = ["frames", "z", "x", "angles"];

/// The manifest as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    format: String,
    version: u32,
    images: ImagesSection,
    cardiac: Option<crate::cardiac::CardiacSection>,
    #[serde(default)]
    #[allow(dead_code)] // free-form, kept for people: read so that it is not an unknown key
    provenance: toml::Table,
}

/// `[images]`: the array and what Doppler needs to read it.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImagesSection {
    file: String,
    axes: Vec<String>,
    frame_rate_hz: f64,
    demod_frequency_hz: f64,
    #[serde(default = "default_sound_speed")]
    sound_speed_m_s: f64,
    angles_deg: Option<Vec<f64>>,
    x_m: [f64; 2],
    z_m: [f64; 2],
    #[serde(default)]
    conjugate: bool,
    aperture_m: Option<[f64; 2]>,
}

fn default_sound_speed() -> f64 {
    1540.0
}

/// Beamformed images read from an images manifest, and what was read.
#[derive(Debug, Clone)]
pub struct ImagesRecording {
    /// The image series, one per steering angle, on their grid, with their frame rate (Hz),
    /// demodulation frequency (Hz) and speed of sound (m/s).
    pub images: AngleImages,
    /// The manifest and its images file, the format, every parameter with where it came from.
    pub info: SourceInfo,
}

/// True when a file's first bytes `head` name the images manifest's format.
pub fn is_images_manifest(head: &[u8]) -> bool {
    let text = String::from_utf8_lossy(&head[..head.len().min(4096)]);
    text.contains(&format!("\"{FORMAT}\"")) || text.contains(&format!("'{FORMAT}'"))
}

/// The manifest at `path`, parsed and its format and version checked, and its text.
fn parse(path: &Path) -> Result<(Manifest, String), IoError> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, "read", e))?;
    let manifest: Manifest = toml::from_str(&text).map_err(|e| {
        IoError::malformed(
            path,
            format!("not a valid images manifest: {}", crate::error::flat(e)),
        )
    })?;
    if manifest.format != FORMAT {
        return Err(IoError::invalid(
            path,
            "format",
            format!(
                "is {:?}; an images manifest says {FORMAT:?}",
                manifest.format
            ),
        ));
    }
    if manifest.version == 0 || manifest.version > VERSION {
        return Err(IoError::invalid(
            path,
            "version",
            format!(
                "is {}; this pcuvd reads version {VERSION} (a newer pcuvd may read it)",
                manifest.version
            ),
        ));
    }
    Ok((manifest, text))
}

/// The images file the manifest at `path` names, resolved against the manifest's folder.
fn images_file(path: &Path, section: &ImagesSection) -> Result<std::path::PathBuf, IoError> {
    let file = path.parent().unwrap_or(Path::new(".")).join(&section.file);
    crate::paths::check_regular_file(&file)?;
    Ok(file)
}

/// What an images manifest says of its images, from the manifest and the `.npy` file's header
/// alone (nothing of the images is read): for `pcuvd info`, and for a memory check before
/// [`ImagesHeader::read_images`].
#[derive(Debug, Clone)]
pub struct ImagesHeader {
    /// The manifest and its images file, the format, every parameter with where it came from,
    /// the stored array (shape, axes, dtype) and the cardiac triggers.
    pub info: SourceInfo,
    /// Steering angle of each series (rad).
    pub angles: Vec<f64>,
    /// Frames of each series.
    pub frames: usize,
    /// The pixels' positions (m).
    pub grid: Grid,
    /// Slow-time sampling rate (Hz).
    pub frame_rate: f64,
    /// The frequency the IQ was demodulated at (Hz).
    pub demodulation_frequency: f64,
    /// Speed of sound (m/s).
    pub sound_speed: f64,
    /// The manifest (or store), which errors about its images name.
    pub(crate) manifest: std::path::PathBuf,
    /// Where the images are stored.
    pub(crate) stored: Stored,
    /// True when the stored IQ is conjugated on reading.
    pub(crate) conjugate: bool,
    /// The x (m) of the array's first and last element centres, when given: each steered plane
    /// wave's reach follows from it.
    pub(crate) aperture: Option<(f64, f64)>,
}

/// Where beamformed images are stored.
#[derive(Debug, Clone)]
pub(crate) enum Stored {
    /// A NumPy `.npy` file whose axes (in the file's order) the manifest names.
    Npy {
        file: std::path::PathBuf,
        axes: Vec<String>,
    },
    /// A Zarr v3 store's `array` (its path in the store): (time, k, j, i) with k of length 1,
    /// as ConfUSIus writes IQ (`crate::confusius`).
    Zarr {
        store: std::path::PathBuf,
        array: String,
        /// True when its values are complex128 (read into complex64), else complex64.
        complex128: bool,
    },
}

impl ImagesHeader {
    /// Bytes `frames` frames of every series take once read (complex64): for a memory check
    /// before they are read (all of them, or a segment's).
    pub fn bytes_of_frames(&self, frames: usize) -> u64 {
        let (nz, nx) = self.grid.shape();
        (self.angles.len() * nz * nx * frames * std::mem::size_of::<Complex32>()) as u64
    }
}

/// Reads the images manifest at `path` and its images file's header, and checks that they agree
/// (axes, angles, at least 2 frames of 2 × 2 pixels). Any images input, a manifest or a Zarr
/// store: [`crate::open::read_images_header`].
pub fn read_header(path: &Path) -> Result<ImagesHeader, IoError> {
    let (manifest, text) = parse(path)?;
    let section = manifest.images;
    // The ranges a recording's numbers are held to: outside them a value is in another unit
    // (kHz, mm/µs) or a mistake, which would read as velocities off by as much.
    let within = |field: &str, value: f64, range: (f64, f64), unit: &str| {
        IoError::require_range(path, &format!("[images].{field}"), value, range, unit)
    };
    let frame_rate = within(
        "frame_rate_hz",
        section.frame_rate_hz,
        FRAME_RATE_RANGE,
        "Hz",
    )?;
    let demodulation_frequency = within(
        "demod_frequency_hz",
        section.demod_frequency_hz,
        pcuvd::acquisition::probe::CENTER_FREQUENCY_RANGE,
        "Hz",
    )?;
    let sound_speed = within(
        "sound_speed_m_s",
        section.sound_speed_m_s,
        pcuvd::acquisition::channel::SOUND_SPEED_RANGE,
        "m/s",
    )?;
    let axes = axes_order(path, &section.axes)?;
    let cardiac_triggers_s = crate::cardiac::triggers_of_section(path, manifest.cardiac)?;
    let file = images_file(path, &section)?;
    let reader = std::fs::File::open(&file).map_err(|e| IoError::io(&file, "read", e))?;
    let header =
        ndarray_npy::npy::header::Header::from_reader(&mut std::io::BufReader::new(reader))
            .map_err(|e| {
                IoError::malformed(
                    &file,
                    format!("not a valid .npy file ({})", crate::error::flat(e)),
                )
            })?;
    let dtype = stored_dtype(&header);
    if !dtype.starts_with("complex") {
        return Err(IoError::invalid(
            path,
            "[images].file",
            format!(
                "{} holds {dtype}: beamformed IQ images are complex (complex64 or complex128)",
                section.file
            ),
        ));
    }
    let shape = header.shape.clone();
    if shape.len() != axes.len() {
        return Err(IoError::invalid(
            path,
            "[images].axes",
            format!(
                "names {} axes but {} has {} (shape {shape:?})",
                axes.len(),
                section.file,
                shape.len(),
            ),
        ));
    }
    let length = |name: &str| axes.iter().position(|a| a == name).map(|i| shape[i]);
    let (n_angles, nz, nx, frames) = (
        length("angles").unwrap_or(1),
        length("z").unwrap_or(0),
        length("x").unwrap_or(0),
        length("frames").unwrap_or(0),
    );
    let angles_deg = section.angles_deg.clone().unwrap_or_else(|| vec![0.0]);
    if angles_deg.len() != n_angles || angles_deg.iter().any(|a| !a.is_finite() || a.abs() >= 90.0)
    {
        return Err(IoError::invalid(
            path,
            "[images].angles_deg",
            format!(
                "gives {} angle(s) {angles_deg:?}; the images hold {n_angles} series (the \
                 \"angles\" axis, or one without it), each steered within ±90°",
                angles_deg.len()
            ),
        ));
    }
    if frames < 2 || nz < 2 || nx < 2 {
        return Err(IoError::invalid(
            path,
            "[images].file",
            format!(
                "{} holds {frames} frame(s) of {nz} × {nx} pixels: Doppler needs 2 frames or more \
                 of 2 × 2 pixels or more",
                section.file
            ),
        ));
    }
    let x = pixel_positions(path, "x_m", section.x_m, nx)?;
    let aperture = match section.aperture_m {
        Some([first, last]) if first.is_finite() && last.is_finite() && last > first => {
            Some((first, last))
        }
        Some([first, last]) => {
            return Err(IoError::invalid(
                path,
                "[images].aperture_m",
                format!(
                    "is [{first}, {last}]; give the x of the array's first and last element \
                     centres (m), the last the greater"
                ),
            ));
        }
        None => None,
    };
    let z = pixel_positions(path, "z_m", section.z_m, nz)?;
    let from_file = |name: &str, value: serde_json::Value, field: &str| Parameter {
        name: name.into(),
        value,
        source: ParamSource::File {
            field: format!("[images].{field}"),
        },
    };
    let mut parameters = vec![
        from_file("frame_rate_hz", frame_rate.into(), "frame_rate_hz"),
        from_file(
            "demod_frequency_hz",
            demodulation_frequency.into(),
            "demod_frequency_hz",
        ),
        from_file("x_m", serde_json::json!(section.x_m), "x_m"),
        from_file("z_m", serde_json::json!(section.z_m), "z_m"),
    ];
    let defaulted = |name: &str, value: serde_json::Value, what: &str| Parameter {
        name: name.into(),
        value,
        source: ParamSource::Default { note: what.into() },
    };
    parameters.push(match &section.angles_deg {
        Some(given) => from_file("angles_deg", serde_json::json!(given), "angles_deg"),
        None => defaulted(
            "angles_deg",
            serde_json::json!([0.0]),
            "one series, read as a 0° plane wave's (a compound of small angles reads within \
             1 − cos θ of it)",
        ),
    });
    if let Some(given) = section.aperture_m {
        parameters.push(from_file(
            "aperture_m",
            serde_json::json!(given),
            "aperture_m",
        ));
    }
    if section.conjugate {
        parameters.push(from_file("conjugate", true.into(), "conjugate"));
    }
    parameters.push(if text.contains("sound_speed_m_s") {
        from_file("sound_speed_m_s", sound_speed.into(), "sound_speed_m_s")
    } else {
        defaulted("sound_speed_m_s", sound_speed.into(), "soft tissue")
    });
    let info = SourceInfo {
        files: vec![path.to_path_buf(), file.clone()],
        format: "pcuvd images manifest (TOML) with NumPy .npy images".into(),
        reader: "pcuvd_io::images (a range of frames at a time)".into(),
        parameters,
        stored: Some(StoredSamples {
            array: section.file.clone(),
            shape,
            axes: axes.clone(),
            dtype,
            kind: "beamformed iq".into(),
        }),
        warnings: Vec::new(),
        cardiac_triggers_s,
    };
    Ok(ImagesHeader {
        info,
        angles: angles_deg.iter().map(|a| a.to_radians()).collect(),
        frames,
        grid: Grid { x, z },
        frame_rate,
        demodulation_frequency,
        sound_speed,
        manifest: path.to_path_buf(),
        stored: Stored::Npy { file, axes },
        conjugate: section.conjugate,
        aperture,
    })
}

/// Reads the images manifest at `path` and the complex images it names (complex64 or
/// complex128, any axis order the manifest gives).
pub fn read_images(path: &Path) -> Result<ImagesRecording, IoError> {
    read_header(path)?.read_images()
}

impl ImagesHeader {
    /// Reads the images this header describes whole (their memory can be checked first,
    /// [`ImagesHeader::bytes_of_frames`]).
    pub fn read_images(self) -> Result<ImagesRecording, IoError> {
        let images = self.images_file()?.read(0..self.frames)?;
        Ok(ImagesRecording {
            images,
            info: self.info,
        })
    }

    /// The images this header describes, to read a range of frames at a time.
    pub fn images_file(&self) -> Result<ImagesFile, IoError> {
        let (nz, nx) = self.grid.shape();
        let changed = |path: &Path| {
            IoError::malformed(
                path,
                "changed since its header was read: its shape or type differs",
            )
        };
        let frames_of = match &self.stored {
            Stored::Npy { file, axes } => {
                let array = crate::npz::open_npy(file)?;
                let length = |name: &str| {
                    axes.iter()
                        .position(|a| a == name)
                        .map(|i| array.shape.get(i).copied())
                };
                if array.shape.len() != axes.len()
                    || length("frames") != Some(Some(self.frames))
                    || length("z") != Some(Some(nz))
                    || length("x") != Some(Some(nx))
                    || length("angles").is_some_and(|n| n != Some(self.angles.len()))
                    || !array.is_complex()
                {
                    return Err(changed(file));
                }
                // (angles, z, x, frames): the series' own order (nz, nx, frames), an angle at a
                // time.
                let order: Vec<usize> = ["angles", "z", "x", "frames"]
                    .iter()
                    .filter_map(|name| axes.iter().position(|a| a == name))
                    .collect();
                StoredFrames::Npy {
                    array,
                    order,
                    angles_axis: axes.iter().position(|a| a == "angles"),
                    frames_axis: axes.iter().position(|a| a == "frames").unwrap_or(0),
                }
            }
            Stored::Zarr {
                store,
                array,
                complex128,
            } => {
                let opened = zarr_array(store, array)?;
                let shape = opened.shape();
                let expected = [self.frames, 1, nz, nx];
                // (time, k, j, i), or (time, pose, k, j, i) of one pose.
                let plane: Vec<u64> = match shape.len() {
                    4 => shape.to_vec(),
                    5 if shape[1] == 1 => [shape[0], shape[2], shape[3], shape[4]].to_vec(),
                    _ => return Err(changed(store)),
                };
                if plane.iter().zip(expected).any(|(&a, b)| a != b as u64) {
                    return Err(changed(store));
                }
                StoredFrames::Zarr {
                    array: std::sync::Arc::new(opened),
                    complex128: *complex128,
                }
            }
        };
        Ok(ImagesFile {
            frames_of,
            description: AngleImages {
                grid: self.grid.clone(),
                angles: self.angles.clone(),
                frame_rate: self.frame_rate,
                sound_speed: self.sound_speed,
                demodulation_frequency: self.demodulation_frequency,
                coverage: self.aperture.map(|aperture| self.coverage(aperture)),
                series: Vec::new(),
            },
            frames: self.frames,
            conjugate: self.conjugate,
            manifest: self.manifest.clone(),
        })
    }
}

impl ImagesHeader {
    /// Per steering angle, the pixels its plane wave reaches from an array spanning `aperture`
    /// (m) (angles, nz, nx): a recording's run leaves the others out of the vector fit, where a
    /// steered wave missed and the images hold only edge waves or noise.
    fn coverage(&self, aperture: (f64, f64)) -> Array3<bool> {
        let (nz, nx) = self.grid.shape();
        Array3::from_shape_fn((self.angles.len(), nz, nx), |(k, iz, ix)| {
            pcuvd::core::geometry::insonified(
                self.grid.x[ix],
                self.grid.z[iz],
                self.angles[k],
                aperture,
            )
        })
    }
}

/// The array `array` of the Zarr store at `store`, opened (its metadata read).
pub(crate) fn zarr_array(
    store: &Path,
    array: &str,
) -> Result<zarrs::array::Array<zarrs::filesystem::FilesystemStore>, IoError> {
    let failed = |e: String| {
        IoError::malformed(
            store,
            format!(
                "its {array} array cannot be opened as Zarr ({})",
                crate::error::flat(e)
            ),
        )
    };
    let storage =
        zarrs::filesystem::FilesystemStore::new(store).map_err(|e| failed(e.to_string()))?;
    zarrs::array::Array::open(std::sync::Arc::new(storage), &format!("/{array}"))
        .map_err(|e| failed(e.to_string()))
}

/// How an [`ImagesFile`] reads its frames.
#[derive(Clone)]
enum StoredFrames {
    /// A `.npy` file's array: its axes of (angles, z, x, frames) in `order`, "angles" left out
    /// when the file has none.
    Npy {
        array: crate::array::StoredArray,
        order: Vec<usize>,
        angles_axis: Option<usize>,
        frames_axis: usize,
    },
    /// ConfUSIus's `iq` array (time, k, j, i), chunks read and decoded by zarrs; complex128
    /// values are read into complex64.
    Zarr {
        array: std::sync::Arc<zarrs::array::Array<zarrs::filesystem::FilesystemStore>>,
        complex128: bool,
    },
}

impl std::fmt::Debug for StoredFrames {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StoredFrames::Npy { array, .. } => write!(f, "Npy({})", array.label),
            StoredFrames::Zarr { array, .. } => write!(f, "Zarr({:?})", array.shape()),
        }
    }
}

/// Beamformed images on file, as an images manifest (or ConfUSIus's store) describes them, read
/// a range of frames at a time: a run in segments holds one segment's frames, not the
/// recording's.
#[derive(Debug, Clone)]
pub struct ImagesFile {
    frames_of: StoredFrames,
    description: AngleImages,
    frames: usize,
    conjugate: bool,
    /// The manifest, which errors name.
    manifest: std::path::PathBuf,
}

impl ImagesFile {
    /// Frames `frames` of every series, each (nz, nx, frames.len()); a value that is not finite
    /// is refused, naming where it is.
    pub fn read(&self, frames: Range<usize>) -> Result<AngleImages, IoError> {
        let path = self.manifest.as_path();
        if frames.start >= frames.end || frames.end > self.frames {
            return Err(IoError::invalid(
                path,
                "frames",
                format!(
                    "{frames:?} is not a range of the images' {} frames",
                    self.frames
                ),
            ));
        }
        // pcuvd's IQ is the RF demodulated by e^(−2πift); a scanner that demodulated by
        // e^(+2πift) stored its conjugate, whose flow would read reversed.
        let conjugate = self.conjugate;
        let series = (0..self.description.n_angles())
            .map(|angle| -> Result<Array3<Complex32>, IoError> {
                let mut one = self.read_series(angle, frames.clone())?;
                if conjugate {
                    one.mapv_inplace(|v| v.conj());
                }
                let stored = || match &self.frames_of {
                    StoredFrames::Npy { array, .. } => ("[images].file", array.label.clone()),
                    StoredFrames::Zarr { array, .. } => {
                        ("array", format!("its array {}", array.path()))
                    }
                };
                if let Some(((iz, ix, t), _)) = one.indexed_iter().find(|(_, v)| !v.is_finite()) {
                    let (field, label) = stored();
                    return Err(IoError::invalid(
                        path,
                        field,
                        format!(
                            "{label} holds a value that is not finite (NaN or infinite) at frame \
                             {}, pixel (z {iz}, x {ix}) of series {angle}",
                            frames.start + t
                        ),
                    ));
                }
                // The images are scaled as a whole: each read's first frame stands for them.
                let peak = pcuvd::core::lags::complex_peak_magnitude(
                    one.index_axis(ndarray::Axis(2), 0).iter(),
                );
                let what = format!("the images of frame {} (series {angle})", frames.start);
                if let Some(reason) = pcuvd::core::lags::sample_peak_problem(peak, &what) {
                    let (field, label) = stored();
                    return Err(IoError::invalid(path, field, format!("{label}: {reason}")));
                }
                Ok(one)
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(self.description.with_series(series))
    }

    /// Frames `frames` of series `angle` as stored, (nz, nx, frames.len()).
    fn read_series(
        &self,
        angle: usize,
        frames: Range<usize>,
    ) -> Result<Array3<Complex32>, IoError> {
        let path = self.manifest.as_path();
        let (nz, nx) = self.description.grid.shape();
        match &self.frames_of {
            StoredFrames::Npy {
                array,
                order,
                angles_axis,
                frames_axis,
            } => {
                let ranges: Vec<Range<usize>> = (0..array.shape.len())
                    .map(|axis| match axis {
                        _ if Some(axis) == *angles_axis => angle..angle + 1,
                        _ if axis == *frames_axis => frames.clone(),
                        _ => 0..array.shape[axis],
                    })
                    .collect();
                let Block::Complex(block) = array.read_ordered(&ranges, order)? else {
                    return Err(IoError::malformed(
                        Path::new(&array.label),
                        "is no longer complex: it changed while read",
                    ));
                };
                block
                    .into_shape_with_order((nz, nx, frames.len()))
                    .map_err(|e| IoError::malformed(path, format!("images array: {e}")))
            }
            StoredFrames::Zarr { array, complex128 } => {
                let mut ranges: Vec<Range<u64>> = array.shape().iter().map(|&n| 0..n).collect();
                ranges[0] = frames.start as u64..frames.end as u64;
                let subset = zarrs::array::ArraySubset::new_with_ranges(&ranges);
                let failed = |e: String| {
                    IoError::malformed(
                        path,
                        format!(
                            "frames {frames:?} of its array {} cannot be read ({})",
                            array.path(),
                            crate::error::flat(e)
                        ),
                    )
                };
                // (time, …, j, i) in C order, its plane's pixels after each frame's.
                let values: Vec<Complex32> = match complex128 {
                    true => array
                        .retrieve_array_subset::<Vec<num_complex::Complex64>>(&subset)
                        .map_err(|e| failed(e.to_string()))?
                        .into_iter()
                        .map(|v| Complex32::new(v.re as f32, v.im as f32))
                        .collect(),
                    false => array
                        .retrieve_array_subset::<Vec<Complex32>>(&subset)
                        .map_err(|e| failed(e.to_string()))?,
                };
                let by_frame =
                    Array3::from_shape_vec((frames.len(), nz, nx), values).map_err(|e| {
                        IoError::malformed(path, format!("array {}: {e}", array.path()))
                    })?;
                Ok(by_frame
                    .permuted_axes([1, 2, 0])
                    .as_standard_layout()
                    .into_owned())
            }
        }
    }
}

impl ImageFrames for ImagesFile {
    fn description(&self) -> AngleImages {
        self.description.clone()
    }

    fn n_frames(&self) -> usize {
        self.frames
    }

    fn read_frames(&self, frames: Range<usize>) -> pcuvd::Result<AngleImages> {
        self.read(frames)
            .map_err(|e| pcuvd::Error::Read(e.to_string()))
    }
}

/// NumPy's name of the element type an `.npy` header gives ("complex64"…), as stored.
fn stored_dtype(header: &ndarray_npy::npy::header::Header) -> String {
    let descr = header.type_descriptor.to_string();
    let code = descr.trim_matches(['<', '>', '=', '|', '\'', '"']);
    crate::array::Dtype::from_numpy(code).map_or(descr.clone(), |dtype| dtype.name().into())
}

/// `axes`, checked: "frames", "z" and "x" once each, "angles" at most once, nothing else.
fn axes_order(path: &Path, axes: &[String]) -> Result<Vec<String>, IoError> {
    let unknown = axes.iter().find(|a| !AXES.contains(&a.as_str()));
    let each_once = AXES
        .iter()
        .all(|name| axes.iter().filter(|a| a == name).count() <= 1);
    let required = ["frames", "z", "x"]
        .iter()
        .all(|name| axes.iter().any(|a| a == name));
    if unknown.is_some() || !each_once || !required {
        return Err(IoError::invalid(
            path,
            "[images].axes",
            format!(
                "is {axes:?}; give the array's axes in order: \"frames\", \"z\" and \"x\" once \
                 each, and \"angles\" where the array holds one series per steering angle"
            ),
        ));
    }
    Ok(axes.to_vec())
}

/// Compound frame rates an images manifest may give (Hz): from a slow functional series to
/// beyond any plane-wave sequence; outside them the value is in another unit.
pub(crate) const FRAME_RATE_RANGE: (f64, f64) = (1.0, 1e6);

/// The farthest a pixel centre may lie from the array (m): no ultrasound image reaches a metre,
/// and positions of several metres are millimetres given as metres.
const MAX_PIXEL_DISTANCE_M: f64 = 1.0;

/// `n` pixel centres from `first_last` (m), evenly spaced and increasing.
fn pixel_positions(
    path: &Path,
    field: &str,
    [first, last]: [f64; 2],
    n: usize,
) -> Result<Vec<f64>, IoError> {
    if !(first.is_finite() && last.is_finite() && last > first) {
        return Err(IoError::invalid(
            path,
            format!("[images].{field}"),
            format!(
                "is [{first:?}, {last:?}]; give the first and last pixel centres (m), the last \
                 the greater"
            ),
        ));
    }
    if first.abs().max(last.abs()) > MAX_PIXEL_DISTANCE_M {
        return Err(IoError::invalid(
            path,
            format!("[images].{field}"),
            format!(
                "is [{first:?}, {last:?}]: pixels more than {MAX_PIXEL_DISTANCE_M} m from the \
                 array; give the pixel centres in metres (millimetres divided by 1000)"
            ),
        ));
    }
    let step = (last - first) / (n - 1) as f64;
    Ok((0..n).map(|i| first + i as f64 * step).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array4, ArrayD, IxDyn};
    use std::path::PathBuf;

    const MANIFEST: &str = "format = \"pcuvd-images\"\nversion = 1\n[images]\nfile = \"iq.npy\"\n\
        frame_rate_hz = 500.0\ndemod_frequency_hz = 7.5e6\nx_m = [-1.0e-3, 1.0e-3]\n\
        z_m = [2.0e-3, 4.0e-3]\n";

    /// Writes `values` as iq.npy and a manifest with `axes` and `extra` keys; returns its path.
    fn write(dir: &Path, values: &ArrayD<Complex32>, axes: &str, extra: &str) -> PathBuf {
        ndarray_npy::write_npy(dir.join("iq.npy"), values).unwrap();
        let path = dir.join("images.toml");
        std::fs::write(&path, format!("{MANIFEST}axes = {axes}\n{extra}")).unwrap();
        path
    }

    /// A value that names its place: (angle, z, x, frame) in its digits.
    fn tagged(angle: usize, z: usize, x: usize, frame: usize) -> Complex32 {
        Complex32::new((1000 * angle + 100 * z + 10 * x + frame) as f32, 0.5)
    }

    /// Images that peak beyond what single-precision lag products hold (a scanner's IQ scaled
    /// to 10⁻²⁰, or 10¹⁷) are refused naming the file and a factor into the range; at a power of
    /// two inside it they read as written.
    #[test]
    fn images_outside_the_single_precision_range_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let values = |scale: f32| {
            ndarray::Array3::from_shape_fn((3, 4, 5), |(z, x, t)| tagged(0, z, x, t) * scale)
                .into_dyn()
        };
        let axes = "[\"z\", \"x\", \"frames\"]";
        for (scale, side) in [(1e-20f32, "below"), (1e17, "above")] {
            let path = write(dir.path(), &values(scale), axes, "");
            let error = read_images(&path).unwrap_err().to_string();
            for needle in ["iq.npy", "peak at", side, "scale the samples into it"] {
                assert!(error.contains(needle), "{needle:?} missing from: {error}");
            }
        }
        let path = write(dir.path(), &values(2f32.powi(-20)), axes, "");
        let read = read_images(&path).unwrap();
        assert_eq!(
            read.images.series[0],
            values(2f32.powi(-20)).into_dimensionality().unwrap()
        );
    }

    #[test]
    fn any_axis_order_reads_as_angle_series_of_z_x_frames() {
        let dir = tempfile::tempdir().unwrap();
        let (angles, nz, nx, frames) = (2, 3, 4, 5);
        let canonical =
            Array4::from_shape_fn((angles, nz, nx, frames), |(a, z, x, t)| tagged(a, z, x, t));
        // Stored (x, frames, angles, z), as another tool might.
        let stored = canonical.clone().permuted_axes([2, 3, 0, 1]).into_dyn();
        let stored = stored.as_standard_layout().into_owned();
        let path = write(
            dir.path(),
            &stored,
            "[\"x\", \"frames\", \"angles\", \"z\"]",
            "angles_deg = [-5.0, 5.0]\nsound_speed_m_s = 1500.0\n",
        );
        let read = read_images(&path).unwrap();
        let images = &read.images;
        assert_eq!(images.series.len(), 2);
        for (a, series) in images.series.iter().enumerate() {
            assert_eq!(series.dim(), (nz, nx, frames));
            assert!(
                series
                    .indexed_iter()
                    .all(|((z, x, t), v)| *v == tagged(a, z, x, t))
            );
        }
        assert_eq!(
            images.grid.x,
            vec![
                -1.0e-3,
                -1.0e-3 + 2.0e-3 / 3.0,
                -1.0e-3 + 4.0e-3 / 3.0,
                1.0e-3
            ]
        );
        assert_eq!(images.grid.z, vec![2.0e-3, 3.0e-3, 4.0e-3]);
        assert_eq!(
            images.angles,
            vec![(-5.0f64).to_radians(), 5.0f64.to_radians()]
        );
        assert_eq!(
            (
                images.frame_rate,
                images.demodulation_frequency,
                images.sound_speed
            ),
            (500.0, 7.5e6, 1500.0)
        );
        assert_eq!(read.info.files.len(), 2);
        // IQ demodulated by e^(+2πift), stored so, is read as its conjugate.
        std::fs::write(
            &path,
            std::fs::read_to_string(&path).unwrap() + "conjugate = true\n",
        )
        .unwrap();
        let conjugated = read_images(&path).unwrap().images;
        assert!(
            conjugated.series[1]
                .indexed_iter()
                .all(|((z, x, t), v)| *v == tagged(1, z, x, t).conj())
        );
        assert!(
            images.coverage.is_none(),
            "no array extent given: every pixel reached"
        );
        // Given the array's extent, a pixel is reached by the wave steered by θ when the ray back
        // along θ lands on the array: x − z·tan θ within it.
        std::fs::write(
            &path,
            std::fs::read_to_string(&path).unwrap() + "aperture_m = [-1.0e-3, 1.0e-3]\n",
        )
        .unwrap();
        let reached = read_images(&path).unwrap().images.coverage.unwrap();
        assert_eq!(reached.dim(), (angles, nz, nx));
        for ((k, iz, ix), &r) in reached.indexed_iter() {
            let theta = if k == 0 { -5f64 } else { 5.0 }.to_radians();
            let foot = images.grid.x[ix] - images.grid.z[iz] * theta.tan();
            assert_eq!(r, (-1.0e-3..=1.0e-3).contains(&foot), "{k} {iz} {ix}");
        }
        assert!(reached.iter().any(|&r| !r) && reached.iter().any(|&r| r));
        let stored = read.info.stored.as_ref().unwrap();
        assert_eq!(stored.shape, vec![nx, frames, angles, nz]);
        assert_eq!(stored.dtype, "complex64");
        // A range of frames read on its own is that range of the series read whole, for every
        // axis order (frames slowest, fastest, in between) and either memory order.
        for (order, axes) in [
            ([3, 0, 1, 2], "[\"frames\", \"angles\", \"z\", \"x\"]"),
            ([1, 2, 0, 3], "[\"z\", \"x\", \"angles\", \"frames\"]"),
            ([2, 3, 0, 1], "[\"x\", \"frames\", \"angles\", \"z\"]"),
        ] {
            let stored = canonical.clone().permuted_axes(order).into_dyn();
            for fortran in [false, true] {
                let stored = match fortran {
                    false => stored.as_standard_layout().into_owned(),
                    true => stored
                        .clone()
                        .reversed_axes()
                        .as_standard_layout()
                        .into_owned()
                        .reversed_axes(),
                };
                let path = write(dir.path(), &stored, axes, "angles_deg = [-5.0, 5.0]\n");
                let file = read_header(&path).unwrap().images_file().unwrap();
                assert_eq!(file.n_frames(), frames);
                for range in [0..frames, 1..4, 4..5] {
                    let part = file.read_frames(range.clone()).unwrap();
                    for (a, series) in part.series.iter().enumerate() {
                        assert_eq!(series.dim(), (nz, nx, range.len()));
                        assert!(
                            series
                                .indexed_iter()
                                .all(|((z, x, t), v)| *v == tagged(a, z, x, range.start + t)),
                            "{axes}, fortran {fortran}, frames {range:?}"
                        );
                    }
                }
                assert!(file.read_frames(3..6).is_err());
            }
        }
    }

    #[test]
    fn what_cannot_describe_the_images_is_refused_naming_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let three = ArrayD::from_shape_fn(IxDyn(&[4, 3, 2]), |d| tagged(0, d[1], d[2], d[0]));
        let frames_z_x = "[\"frames\", \"z\", \"x\"]";
        for (axes, extra, field) in [
            ("[\"frames\", \"z\", \"y\"]", "", "[images].axes"),
            ("[\"frames\", \"z\", \"z\"]", "", "[images].axes"),
            (
                "[\"frames\", \"z\", \"x\", \"angles\"]",
                "",
                "[images].axes",
            ),
            (
                frames_z_x,
                "angles_deg = [0.0, 3.0]\n",
                "[images].angles_deg",
            ),
            (
                frames_z_x,
                "sound_speed_m_s = -1.0\n",
                "[images].sound_speed_m_s",
            ),
            (
                frames_z_x,
                "aperture_m = [1.0e-3, -1.0e-3]\n",
                "[images].aperture_m",
            ),
            (frames_z_x, "colour = 1\n", "unknown field"),
        ] {
            let path = write(dir.path(), &three, axes, extra);
            let error = read_images(&path).unwrap_err().to_string();
            assert!(error.contains(field), "{axes} {extra}: {error}");
        }
        // Real numbers are not IQ.
        let real = ArrayD::<f32>::zeros(IxDyn(&[4, 3, 2]));
        let path = write(dir.path(), &three, frames_z_x, "");
        ndarray_npy::write_npy(dir.path().join("iq.npy"), &real).unwrap();
        let error = read_images(&path).unwrap_err().to_string();
        assert!(error.contains("complex"), "{error}");
        // A grid whose last pixel is not past its first.
        let path = write(dir.path(), &three, frames_z_x, "");
        let flipped = std::fs::read_to_string(&path)
            .unwrap()
            .replace("x_m = [-1.0e-3, 1.0e-3]", "x_m = [1.0e-3, -1.0e-3]");
        std::fs::write(&path, flipped).unwrap();
        let error = read_images(&path).unwrap_err().to_string();
        assert!(error.contains("[images].x_m"), "{error}");
        // Numbers in another unit: millimetres as metres, MHz as Hz, mm/µs as m/s, a rate
        // beyond any sequence (1e300 Hz printed its 301 digits in a later refusal).
        for (from, to, field, needle) in [
            (
                "x_m = [-1.0e-3, 1.0e-3]",
                "x_m = [-6.4, 6.4]",
                "[images].x_m",
                "in metres",
            ),
            (
                "z_m = [2.0e-3, 4.0e-3]",
                "z_m = [1.0, 10.0]",
                "[images].z_m",
                "in metres",
            ),
            (
                "demod_frequency_hz = 7.5e6",
                "demod_frequency_hz = 7.5",
                "demod_frequency_hz",
                "unit",
            ),
            (
                "frame_rate_hz = 500.0",
                "frame_rate_hz = 1e300",
                "frame_rate_hz",
                "1e300",
            ),
            (
                "frame_rate_hz = 500.0",
                "frame_rate_hz = 0.0",
                "frame_rate_hz",
                "[1e0, 1e6] Hz",
            ),
            (
                "x_m = [-1.0e-3, 1.0e-3]",
                "x_m = [-1.0e-3, 1.0e-3]\nsound_speed_m_s = 1.54",
                "sound_speed_m_s",
                "m/s",
            ),
        ] {
            let path = write(dir.path(), &three, frames_z_x, "");
            let text = std::fs::read_to_string(&path).unwrap();
            assert!(text.contains(from), "{from}");
            std::fs::write(&path, text.replace(from, to)).unwrap();
            let error = read_images(&path).unwrap_err().to_string();
            assert!(
                error.contains(field) && error.contains(needle),
                "{to}: {error}"
            );
        }
        // The bounds themselves pass: a metre from the array, a 1 Hz series.
        let path = write(dir.path(), &three, frames_z_x, "");
        let text = std::fs::read_to_string(&path).unwrap();
        let edges = text
            .replace("x_m = [-1.0e-3, 1.0e-3]", "x_m = [-1.0, 1.0]")
            .replace("frame_rate_hz = 500.0", "frame_rate_hz = 1.0");
        std::fs::write(&path, edges).unwrap();
        read_images(&path).unwrap();
    }
}
