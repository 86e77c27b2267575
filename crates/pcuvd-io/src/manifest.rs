//! The recording manifest: a TOML file (format "pcuvd-recording", version 1, SI units with the
//! unit in each key name) that describes the acquisition and points at a `.npy` file of samples.
//!
//! See `crates/pcuvd-io/examples/recording.toml` for a complete, commented example. Angles may be
//! given as `angles_deg` or `angles_rad` (exactly one); [`write_recording`] writes `angles_rad`
//! so that a written recording reads back bit for bit.

use std::path::{Path, PathBuf};

use ndarray::{Array3, Array4, ArrayD};
use pcuvd::{Acquisition, ChannelData, Coding, Probe, Samples, Sequence};
use serde::Deserialize;

use crate::error::IoError;
use crate::npy::{NpyArray, write_npy};

/// The value of the manifest's `format` key.
pub const FORMAT: &str = "pcuvd-recording";
/// The manifest version this crate reads and writes.
pub const VERSION: i64 = 1;

/// A recording read from a manifest: the channel data, the free-form provenance, and where it was.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The channel data, validated.
    pub data: ChannelData,
    /// The `[provenance]` table (empty when absent): simulator settings, noise, seed...
    pub provenance: toml::Table,
    /// The manifest file, as given.
    pub manifest_path: PathBuf,
    /// The samples file, resolved against the manifest's folder.
    pub data_path: PathBuf,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ManifestFile {
    #[serde(rename = "format")]
    _format: serde::de::IgnoredAny,
    #[serde(rename = "version")]
    _version: serde::de::IgnoredAny,
    probe: Option<ProbeSection>,
    acquisition: Option<AcquisitionSection>,
    data: Option<DataSection>,
    #[serde(default)]
    provenance: toml::Table,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ProbeSection {
    preset: Option<String>,
    name: Option<String>,
    n_elements: Option<usize>,
    pitch_m: Option<f64>,
    element_width_m: Option<f64>,
    center_frequency_hz: Option<f64>,
    bandwidth: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AcquisitionSection {
    sampling_frequency_hz: Option<f64>,
    sound_speed_m_s: Option<f64>,
    t0_s: Option<f64>,
    event_prf_hz: Option<f64>,
    angles_deg: Option<Vec<f64>>,
    angles_rad: Option<Vec<f64>>,
    pulse_cycles: Option<f64>,
    coding: Option<String>,
    slot_delay_s: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DataSection {
    file: Option<String>,
    kind: Option<String>,
    axes: Option<Vec<String>>,
    demod_frequency_hz: Option<f64>,
}

/// Reads a recording manifest and its samples into validated channel data.
pub fn read_manifest(path: &Path) -> Result<ChannelData, IoError> {
    read_recording(path).map(|r| r.data)
}

/// Line and column (1-based) of a byte offset in a text.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = text.get(..offset.min(text.len())).unwrap_or("");
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

fn toml_error(path: &Path, text: &str, e: &toml::de::Error) -> IoError {
    let msg = e.message().trim().replace('\n', " ");
    match e.span() {
        Some(span) => {
            let (line, col) = line_col(text, span.start);
            IoError::malformed(path, format!("line {line}, column {col}: {msg}"))
        }
        None => IoError::malformed(path, msg),
    }
}

/// Reads a recording manifest, its samples and its provenance.
pub fn read_recording(path: &Path) -> Result<Recording, IoError> {
    let parsed = parse_manifest(path)?;
    let Parsed {
        acquisition,
        provenance,
        data_path,
        data_member,
        axes,
        perm,
        demod,
    } = parsed;
    let array = crate::datafile::read_whole(&crate::datafile::DataSpec {
        path: data_path.clone(),
        member: data_member,
    })?;
    let shape = array.shape().to_vec();
    let (events, channels, samples) =
        event_shape(path, &acquisition, &data_path, &axes, &perm, &shape)?;
    let reshape_err = |e: ndarray::ShapeError| {
        IoError::invalid(path, "[data].axes", format!("cannot be applied ({e})"))
    };
    let samples = match (array, demod) {
        (NpyArray::Real(a), None) => {
            Samples::Rf(to_events(a, &perm, (events, channels, samples)).map_err(reshape_err)?)
        }
        (NpyArray::Complex(a), Some(demod_frequency)) => Samples::Iq {
            data: to_events(a, &perm, (events, channels, samples)).map_err(reshape_err)?,
            demod_frequency,
        },
        (NpyArray::Real(_), Some(_)) => return Err(kind_error(path, &data_path, true)),
        (NpyArray::Complex(_), None) => return Err(kind_error(path, &data_path, false)),
    };
    let data = ChannelData {
        acquisition,
        samples,
    };
    data.validate().map_err(|source| IoError::Recording {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(Recording {
        data,
        provenance,
        manifest_path: path.to_path_buf(),
        data_path,
    })
}

/// The error for samples whose values do not match `[data].kind` (`iq` said, real found, or the
/// reverse).
pub(crate) fn kind_error(path: &Path, data_path: &Path, iq_said: bool) -> IoError {
    if iq_said {
        IoError::invalid(
            path,
            "[data].kind",
            format!(
                "is \"iq\" but {} holds real values (complex64/complex128 expected)",
                data_path.display()
            ),
        )
    } else {
        IoError::invalid(
            path,
            "[data].kind",
            format!(
                "is \"rf\" but {} holds complex values (float32/float64/int16/int32 expected)",
                data_path.display()
            ),
        )
    }
}

/// A manifest read and checked, its samples not yet: what [`read_recording`] and
/// [`crate::frames::ManifestFrames`] share.
pub(crate) struct Parsed {
    pub(crate) acquisition: Acquisition,
    pub(crate) provenance: toml::Table,
    pub(crate) data_path: PathBuf,
    /// The array inside the samples file (`"rec.npz:RF"`, `"rec.h5:/dataset"`), if named.
    pub(crate) data_member: Option<String>,
    pub(crate) axes: Vec<String>,
    /// For each canonical axis, its index among the named axes.
    pub(crate) perm: Vec<usize>,
    /// The demodulation frequency of IQ samples; `None` for RF.
    pub(crate) demod: Option<f64>,
}

/// Reads and checks a manifest, up to (not including) its samples.
pub(crate) fn parse_manifest(path: &Path) -> Result<Parsed, IoError> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, "read", e))?;
    let table: toml::Table = toml::from_str(&text).map_err(|e| toml_error(path, &text, &e))?;
    match table.get("format") {
        None => return Err(IoError::missing(path, "the manifest", "key 'format'")),
        Some(toml::Value::String(s)) if s == FORMAT => {}
        Some(v) => {
            return Err(IoError::invalid(
                path,
                "format",
                format!("is {v}; expected \"{FORMAT}\" (this is not a pcuvd recording manifest)"),
            ));
        }
    }
    match table.get("version") {
        None => return Err(IoError::missing(path, "the manifest", "key 'version'")),
        Some(toml::Value::Integer(v)) if *v == VERSION => {}
        Some(v) => {
            return Err(IoError::invalid(
                path,
                "version",
                format!("is {v}; this reader knows version {VERSION} only"),
            ));
        }
    }
    let m: ManifestFile = toml::from_str(&text).map_err(|e| toml_error(path, &text, &e))?;
    let miss = |table: &str, key: &str| {
        IoError::missing(path, format!("table [{table}]"), format!("key '{key}'"))
    };
    let no_table = |table: &str| IoError::missing(path, "the manifest", format!("table [{table}]"));

    // [probe]
    let ps = m.probe.ok_or_else(|| no_table("probe"))?;
    let preset = match &ps.preset {
        Some(name) => Some(Probe::preset(name).map_err(|e| {
            IoError::invalid(path, "[probe].preset", format!("is not usable: {e}"))
        })?),
        None => None,
    };
    let pick_f = |v: Option<f64>, key: &str, from: fn(&Probe) -> f64| -> Result<f64, IoError> {
        v.or(preset.as_ref().map(from))
            .ok_or_else(|| miss("probe", key))
    };
    let probe = Probe {
        name: ps
            .name
            .clone()
            .or(preset.as_ref().map(|p| p.name.clone()))
            .unwrap_or_else(|| "custom".into()),
        n_elements: ps
            .n_elements
            .or(preset.as_ref().map(|p| p.n_elements))
            .ok_or_else(|| miss("probe", "n_elements"))?,
        pitch: pick_f(ps.pitch_m, "pitch_m", |p| p.pitch)?,
        element_width: pick_f(ps.element_width_m, "element_width_m", |p| p.element_width)?,
        center_frequency: pick_f(ps.center_frequency_hz, "center_frequency_hz", |p| {
            p.center_frequency
        })?,
        bandwidth: pick_f(ps.bandwidth, "bandwidth", |p| p.bandwidth)?,
    };

    // [acquisition]
    let acq = m.acquisition.ok_or_else(|| no_table("acquisition"))?;
    let req = |v: Option<f64>, key: &str| v.ok_or_else(|| miss("acquisition", key));
    let angles = match (&acq.angles_deg, &acq.angles_rad) {
        (Some(d), None) => d.iter().map(|a| a.to_radians()).collect(),
        (None, Some(r)) => r.clone(),
        (None, None) => return Err(miss("acquisition", "angles_deg")),
        (Some(_), Some(_)) => {
            return Err(IoError::invalid(
                path,
                "[acquisition].angles_rad",
                "is given together with angles_deg; give exactly one",
            ));
        }
    };
    let coding = match acq.coding.as_deref() {
        None => return Err(miss("acquisition", "coding")),
        Some("none") => {
            if acq.slot_delay_s.is_some() {
                return Err(IoError::invalid(
                    path,
                    "[acquisition].slot_delay_s",
                    "is only meaningful with coding = \"hadamard\"",
                ));
            }
            Coding::Conventional
        }
        Some("hadamard") => Coding::Hadamard {
            slot_delay: req(acq.slot_delay_s, "slot_delay_s")?,
        },
        Some(other) => {
            return Err(IoError::invalid(
                path,
                "[acquisition].coding",
                format!("is \"{other}\"; expected \"none\" or \"hadamard\""),
            ));
        }
    };
    let acquisition = Acquisition {
        probe,
        sequence: Sequence {
            angles,
            event_prf: req(acq.event_prf_hz, "event_prf_hz")?,
            coding,
            pulse_cycles: req(acq.pulse_cycles, "pulse_cycles")?,
        },
        sampling_frequency: req(acq.sampling_frequency_hz, "sampling_frequency_hz")?,
        sound_speed: req(acq.sound_speed_m_s, "sound_speed_m_s")?,
        t0: req(acq.t0_s, "t0_s")?,
    };
    acquisition
        .validate()
        .map_err(|source| IoError::Recording {
            path: path.to_path_buf(),
            source,
        })?;

    // [data]
    let ds = m.data.ok_or_else(|| no_table("data"))?;
    let file = ds.file.ok_or_else(|| miss("data", "file"))?;
    let kind = ds.kind.ok_or_else(|| miss("data", "kind"))?;
    let axes = ds.axes.ok_or_else(|| miss("data", "axes"))?;
    let demod = match (kind.as_str(), ds.demod_frequency_hz) {
        ("rf", None) => None,
        ("rf", Some(_)) => {
            return Err(IoError::invalid(
                path,
                "[data].demod_frequency_hz",
                "is only meaningful with kind = \"iq\"",
            ));
        }
        ("iq", None) => return Err(miss("data", "demod_frequency_hz")),
        ("iq", Some(f)) if f.is_finite() && f >= 0.0 => Some(f),
        ("iq", Some(f)) => {
            return Err(IoError::invalid(
                path,
                "[data].demod_frequency_hz",
                format!("must be finite and ≥ 0, got {f}"),
            ));
        }
        (other, _) => {
            return Err(IoError::invalid(
                path,
                "[data].kind",
                format!("is \"{other}\"; expected \"rf\" or \"iq\""),
            ));
        }
    };
    let perm = axis_permutation(&axes).map_err(|p| IoError::invalid(path, "[data].axes", p))?;
    let data = crate::datafile::parse_data_file(path, &file)?;
    Ok(Parsed {
        acquisition,
        provenance: m.provenance,
        data_path: data.path,
        data_member: data.member,
        axes,
        perm,
        demod,
    })
}

/// (events, channels, samples) of samples of `shape` whose axes are `axes`, checked against the
/// acquisition: angles and elements.
pub(crate) fn event_shape(
    path: &Path,
    acquisition: &Acquisition,
    data_path: &Path,
    axes: &[String],
    perm: &[usize],
    shape: &[usize],
) -> Result<(usize, usize, usize), IoError> {
    if shape.len() != axes.len() {
        return Err(IoError::invalid(
            path,
            "[data].axes",
            format!(
                "names {} axes but {} has {} (shape {shape:?})",
                axes.len(),
                data_path.display(),
                shape.len()
            ),
        ));
    }
    let n_angles = acquisition.sequence.n_angles();
    let n_elements = acquisition.probe.n_elements;
    let canonical: Vec<usize> = perm.iter().map(|&i| shape[i]).collect();
    let (events, channels, samples) = match canonical.as_slice() {
        [f, a, c, s] => {
            if *a != n_angles {
                return Err(IoError::invalid(
                    path,
                    "[acquisition].angles",
                    format!(
                        "lists {n_angles} angles but the 'angles' axis of {} has {a} (shape {shape:?})",
                        data_path.display()
                    ),
                ));
            }
            (f.checked_mul(*a).unwrap_or(usize::MAX), *c, *s)
        }
        [e, c, s] => (*e, *c, *s),
        _ => {
            return Err(IoError::invalid(
                path,
                "[data].axes",
                "must name 3 or 4 axes",
            ));
        }
    };
    if channels != n_elements {
        return Err(IoError::invalid(
            path,
            "[probe].n_elements",
            format!(
                "is {n_elements} but the 'channels' axis of {} has {channels} (shape {shape:?})",
                data_path.display()
            ),
        ));
    }
    Ok((events, channels, samples))
}

/// For each canonical axis (frames, angles, channels, samples) or (events, channels, samples), its
/// index among the named axes.
fn axis_permutation(axes: &[String]) -> Result<Vec<usize>, String> {
    const FOUR: [&str; 4] = ["frames", "angles", "channels", "samples"];
    const THREE: [&str; 3] = ["events", "channels", "samples"];
    let canonical: &[&str] = if axes.len() == 4 { &FOUR } else { &THREE };
    let is_perm = (axes.len() == 3 || axes.len() == 4)
        && canonical
            .iter()
            .all(|c| axes.iter().filter(|a| a.as_str() == *c).count() == 1);
    if !is_perm {
        return Err(format!(
            "is {axes:?}; expected an ordering of [\"frames\", \"angles\", \"channels\", \"samples\"] \
             or of [\"events\", \"channels\", \"samples\"]"
        ));
    }
    Ok(canonical
        .iter()
        .map(|c| axes.iter().position(|a| a == c).unwrap_or(0))
        .collect())
}

/// Permutes named axes into canonical order and merges (frames, angles) into events.
fn to_events<T: Clone>(
    a: ArrayD<T>,
    perm: &[usize],
    shape: (usize, usize, usize),
) -> Result<Array3<T>, ndarray::ShapeError> {
    // Samples already in canonical order (what pcuvd writes) are only reshaped, not copied: a
    // copy would double the memory a long recording takes while it is read.
    if perm.iter().enumerate().all(|(i, &p)| i == p) && a.is_standard_layout() {
        return a.into_shape_with_order(shape);
    }
    let p = a.permuted_axes(perm.to_vec());
    let values: Vec<T> = p.iter().cloned().collect();
    Array3::from_shape_vec(shape, values)
}

/// A float as TOML text that reads back to the same bits (finite values; TOML spellings otherwise).
fn toml_f64(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf".into() } else { "-inf".into() }
    } else {
        format!("{v:?}")
    }
}

fn toml_str(s: &str) -> String {
    toml::Value::String(s.to_string()).to_string()
}

/// Writes `{stem}.npy` (float32 RF or complex64 IQ, axes frames × angles × channels × samples) and
/// `{stem}.toml` in `dir` (created if needed); returns the manifest's path.
pub fn write_recording(
    dir: &Path,
    stem: &str,
    data: &ChannelData,
    provenance: &toml::Table,
) -> Result<PathBuf, IoError> {
    let (manifest_path, npy_name, npy_path) = recording_paths(dir, stem)?;
    data.validate().map_err(|source| IoError::Recording {
        path: manifest_path.clone(),
        source,
    })?;
    let acq = &data.acquisition;
    prepare_recording(dir, &manifest_path)?;

    let n_angles = acq.sequence.n_angles();
    let (events, channels, samples) = data.samples.dim();
    let shape4 = (events / n_angles, n_angles, channels, samples);
    let kind_lines = match &data.samples {
        Samples::Rf(a) => {
            let a4 = Array4::from_shape_vec(shape4, a.iter().copied().collect())
                .map_err(|e| IoError::invalid(&npy_path, "the samples", e.to_string()))?;
            write_npy(&npy_path, &a4)?;
            RF_KIND.to_string()
        }
        Samples::Iq {
            data: a,
            demod_frequency,
        } => {
            let a4 = Array4::from_shape_vec(shape4, a.iter().copied().collect())
                .map_err(|e| IoError::invalid(&npy_path, "the samples", e.to_string()))?;
            write_npy(&npy_path, &a4)?;
            format!(
                "kind = \"iq\"\ndemod_frequency_hz = {}\n",
                toml_f64(*demod_frequency)
            )
        }
    };
    write_manifest(&manifest_path, acq, &npy_name, &kind_lines, provenance)?;
    Ok(manifest_path)
}

/// The `[data]` kind lines of an RF recording.
const RF_KIND: &str = "kind = \"rf\"\n";

/// The manifest, samples file name and samples path of recording `stem` in `dir`, or an error
/// when `stem` is not a plain file name.
fn recording_paths(dir: &Path, stem: &str) -> Result<(PathBuf, String, PathBuf), IoError> {
    let manifest_path = dir.join(format!("{stem}.toml"));
    if stem.is_empty() || stem == "." || stem == ".." || stem.contains(['/', '\\']) {
        return Err(IoError::invalid(
            &manifest_path,
            "the file stem",
            format!("{stem:?} is not a plain file name"),
        ));
    }
    let npy_name = format!("{stem}.npy");
    let npy_path = dir.join(&npy_name);
    Ok((manifest_path, npy_name, npy_path))
}

/// Creates `dir` and removes an earlier manifest at `manifest_path`: if writing stops between the
/// samples and the new manifest, no manifest describes samples it was not written for.
fn prepare_recording(dir: &Path, manifest_path: &Path) -> Result<(), IoError> {
    std::fs::create_dir_all(dir).map_err(|e| IoError::io(dir, "create", e))?;
    match std::fs::remove_file(manifest_path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(IoError::io(manifest_path, "remove", e))
        }
        _ => Ok(()),
    }
}

/// Writes the manifest of a recording acquired as `acq` whose samples are `npy_name`
/// (frames, angles, channels, samples) of `kind_lines`, atomically.
fn write_manifest(
    manifest_path: &Path,
    acq: &Acquisition,
    npy_name: &str,
    kind_lines: &str,
    provenance: &toml::Table,
) -> Result<(), IoError> {
    let p = &acq.probe;
    let mut t = String::new();
    t.push_str("# pcuvd recording manifest (SI units; the unit is in each key's name).\n");
    t.push_str(&format!(
        "format = {}\nversion = {VERSION}\n\n",
        toml_str(FORMAT)
    ));
    t.push_str("[probe]\n");
    if Probe::preset(&p.name).is_ok_and(|q| q.name == p.name) {
        t.push_str(&format!("preset = {}\n", toml_str(&p.name)));
    }
    t.push_str(&format!("name = {}\n", toml_str(&p.name)));
    t.push_str(&format!("n_elements = {}\n", p.n_elements));
    t.push_str(&format!("pitch_m = {}\n", toml_f64(p.pitch)));
    t.push_str(&format!(
        "element_width_m = {}\n",
        toml_f64(p.element_width)
    ));
    t.push_str(&format!(
        "center_frequency_hz = {}\n",
        toml_f64(p.center_frequency)
    ));
    t.push_str(&format!(
        "bandwidth = {}  # two-way -6 dB fractional bandwidth\n\n",
        toml_f64(p.bandwidth)
    ));
    t.push_str("[acquisition]\n");
    t.push_str(&format!(
        "sampling_frequency_hz = {}\n",
        toml_f64(acq.sampling_frequency)
    ));
    t.push_str(&format!(
        "sound_speed_m_s = {}\n",
        toml_f64(acq.sound_speed)
    ));
    t.push_str(&format!("t0_s = {}\n", toml_f64(acq.t0)));
    t.push_str(&format!(
        "event_prf_hz = {}\n",
        toml_f64(acq.sequence.event_prf)
    ));
    let deg: Vec<String> = acq
        .sequence
        .angles
        .iter()
        .map(|a| format!("{:.4}", a.to_degrees()))
        .collect();
    let rad: Vec<String> = acq.sequence.angles.iter().map(|&a| toml_f64(a)).collect();
    t.push_str(&format!(
        "# angles in degrees: [{}]\nangles_rad = [{}]\n",
        deg.join(", "),
        rad.join(", ")
    ));
    t.push_str(&format!(
        "pulse_cycles = {}\n",
        toml_f64(acq.sequence.pulse_cycles)
    ));
    match acq.sequence.coding {
        Coding::Conventional => t.push_str("coding = \"none\"\n"),
        Coding::Hadamard { slot_delay } => t.push_str(&format!(
            "coding = \"hadamard\"\nslot_delay_s = {}\n",
            toml_f64(slot_delay)
        )),
    }
    t.push_str("\n[data]\n");
    t.push_str(&format!("file = {}\n", toml_str(npy_name)));
    t.push_str(kind_lines);
    t.push_str("axes = [\"frames\", \"angles\", \"channels\", \"samples\"]\n");
    if !provenance.is_empty() {
        #[derive(serde::Serialize)]
        struct Prov<'a> {
            provenance: &'a toml::Table,
        }
        let prov = toml::to_string(&Prov { provenance }).map_err(|e| {
            IoError::invalid(
                manifest_path,
                "[provenance]",
                format!("cannot be written ({e})"),
            )
        })?;
        t.push('\n');
        t.push_str(&prov);
    }
    crate::npy::write_atomically(manifest_path, |partial| {
        std::fs::write(partial, t).map_err(|e| IoError::io(manifest_path, "write", e))
    })
}

/// A recording written a block of events at a time (RF, float32), so that a long simulation
/// never holds the whole recording: [`RecordingWriter::create`], then [`append`](Self::append)
/// every event in order, then [`finish`](Self::finish) writes the manifest. Until then the
/// samples sit under a temporary name and no manifest describes them.
pub struct RecordingWriter {
    manifest_path: PathBuf,
    npy_name: String,
    npy_path: PathBuf,
    partial: PathBuf,
    file: std::io::BufWriter<std::fs::File>,
    acquisition: Acquisition,
    provenance: toml::Table,
    /// (events, channels, samples) the recording will hold.
    shape: (usize, usize, usize),
    written: usize,
}

impl RecordingWriter {
    /// Starts recording `stem` in `dir` of `events` RF events of (channels, samples) each,
    /// acquired as `acquisition`.
    pub fn create(
        dir: &Path,
        stem: &str,
        acquisition: &Acquisition,
        shape: (usize, usize, usize),
        provenance: &toml::Table,
    ) -> Result<RecordingWriter, IoError> {
        let (manifest_path, npy_name, npy_path) = recording_paths(dir, stem)?;
        acquisition
            .validate()
            .map_err(|source| IoError::Recording {
                path: manifest_path.clone(),
                source,
            })?;
        let (events, channels, samples) = shape;
        let n = acquisition.sequence.n_angles();
        if events == 0 || events % n != 0 || channels != acquisition.probe.n_elements {
            return Err(IoError::invalid(
                &npy_path,
                "the samples",
                format!(
                    "{events} events of {channels} channels are not whole frames of {n} events \
                     from {} elements",
                    acquisition.probe.n_elements
                ),
            ));
        }
        prepare_recording(dir, &manifest_path)?;
        let partial = dir.join(format!(".{npy_name}.part"));
        crate::npy::track_partial(&partial, true);
        let file =
            std::fs::File::create(&partial).map_err(|e| IoError::io(&partial, "create", e))?;
        let mut file = std::io::BufWriter::new(file);
        let header = ndarray_npy::npy::header::Header {
            type_descriptor: <f32 as ndarray_npy::WritableElement>::type_descriptor(),
            layout: ndarray_npy::npy::header::Layout::Standard,
            shape: vec![events / n, n, channels, samples],
        };
        header
            .write(&mut file)
            .map_err(|e| IoError::malformed(&npy_path, format!("cannot write the header: {e}")))?;
        Ok(RecordingWriter {
            manifest_path,
            npy_name,
            npy_path,
            partial,
            file,
            acquisition: acquisition.clone(),
            provenance: provenance.clone(),
            shape,
            written: 0,
        })
    }

    /// Appends the next events, shape (events, channels, samples); refuses a wrong shape, more
    /// events than announced, and NaN or Inf samples.
    pub fn append(&mut self, events: ndarray::ArrayView3<f32>) -> Result<(), IoError> {
        use std::io::Write;
        let (count, channels, samples) = events.dim();
        if (channels, samples) != (self.shape.1, self.shape.2)
            || self.written + count > self.shape.0
        {
            return Err(IoError::invalid(
                &self.npy_path,
                "the samples",
                format!(
                    "a block of {:?} after {} events does not fit {:?}",
                    events.dim(),
                    self.written,
                    self.shape
                ),
            ));
        }
        if events.iter().any(|v| !v.is_finite()) {
            return Err(IoError::invalid(
                &self.npy_path,
                "the samples",
                "hold NaN or Inf",
            ));
        }
        for v in events.iter() {
            self.file
                .write_all(&v.to_le_bytes())
                .map_err(|e| IoError::io(&self.partial, "write", e))?;
        }
        self.written += count;
        Ok(())
    }

    /// Completes the samples file (renamed into place) and writes the manifest; returns the
    /// manifest's path. Refuses a recording with fewer events than announced.
    pub fn finish(mut self) -> Result<PathBuf, IoError> {
        use std::io::Write;
        if self.written != self.shape.0 {
            return Err(IoError::invalid(
                &self.npy_path,
                "the samples",
                format!(
                    "{} events written of the {} announced",
                    self.written, self.shape.0
                ),
            ));
        }
        self.file
            .flush()
            .and_then(|()| self.file.get_ref().sync_all())
            .map_err(|e| IoError::io(&self.partial, "write", e))?;
        std::fs::rename(&self.partial, &self.npy_path)
            .map_err(|e| IoError::io(&self.npy_path, "write", e))?;
        crate::npy::track_partial(&self.partial, false);
        write_manifest(
            &self.manifest_path,
            &self.acquisition,
            &self.npy_name,
            RF_KIND,
            &self.provenance,
        )?;
        Ok(self.manifest_path.clone())
    }
}

impl Drop for RecordingWriter {
    fn drop(&mut self) {
        // Abandoned before finish (an error, a panic): no half-written samples stay behind. After
        // finish the partial name no longer exists and this does nothing.
        let _ = std::fs::remove_file(&self.partial);
        crate::npy::track_partial(&self.partial, false);
    }
}

#[cfg(test)]
mod tests;
