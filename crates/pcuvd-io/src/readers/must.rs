//! MUST/PyMUST-style recordings: `RF` (samples × elements × transmits, real) or `IQ` (the same,
//! complex, from `rf2iq(RF, param)`) and a `param` struct (fs, fc, c, pitch, width, t0, PRF,
//! TXdelay, Nelements, bandwidth), in a MATLAB v5 or v7.3 file or a PyMUST-style `.npz` (the
//! arrays and the `param` fields side by side).
//!
//! Steered plane waves: `param.TXdelay` holds one delay law per row (MUST's `txdelay(param,
//! tilt)` with a vector of tilts); transmit i fires row i (or row i mod rows when fewer rows than
//! transmits are given); each row's steering angle is fitted and checked to be a plane wave, and
//! the transmits must cycle through a set of distinct angles: those are the compound frame.
//! MUST's time origin is the instant of zero delay, so a delay law whose earliest element fires
//! at d₀ > 0 gives pcuvd's t0 (first sample after the first element fires) = `param.t0` − d₀.
//! IQ samples follow PyMUST's `rf2iq(RF, param)`: mixed with exp(−2πi·fc·t), t = param.t0 + n/fs
//! (pcuvd's convention), demodulated at `param.fc`.

use std::collections::BTreeMap;
use std::path::Path;

use pcuvd::{ChannelData, Probe};
use serde_json::json;

use crate::array::{ArrayFrames, Axis, Backing, Dtype, StoredArray};
use crate::error::IoError;
use crate::layout::positive;
use crate::mat::{MatFile, MatValue, read_mat};
use crate::params::{Overrides, ParamSource, Resolver, derived, field, missing_prf, missing_t0};
pub use crate::recording::{DEFAULT_PULSE_CYCLES, plane_wave_angle};
use crate::recording::{
    OpenedRecording, PlaneWaveAcquisition, SourceInfo, StoredSamples, resolve_bandwidth,
};

/// MUST's default fractional bandwidth when `param.bandwidth` is absent (%).
pub const DEFAULT_BANDWIDTH_PERCENT: f64 = 75.0;
/// MUST's default speed of sound when `param.c` is absent (m/s).
pub const DEFAULT_SOUND_SPEED: f64 = 1540.0;
/// A parameter array in C order over its dimensions (MATLAB's dimensions for a MAT-file).
#[derive(Debug, Clone)]
struct ParamArray {
    dims: Vec<usize>,
    values: Vec<f64>,
}

/// The `param` fields of a MUST recording and how they are named in messages.
struct MustParams {
    /// "param." in a MAT-file, "" in an `.npz` (fields are arrays of their own).
    prefix: &'static str,
    fields: BTreeMap<String, ParamArray>,
}

/// Column-major values of `dims` to C order.
fn column_to_row_major(dims: &[usize], values: &[f64]) -> Vec<f64> {
    let n = values.len();
    if dims.len() < 2 || dims.iter().filter(|&&d| d > 1).count() < 2 {
        return values.to_vec();
    }
    let nd = dims.len();
    let mut out = Vec::with_capacity(n);
    let mut idx = vec![0usize; nd];
    for _ in 0..n {
        let mut lin = 0;
        let mut stride = 1;
        for k in 0..nd {
            lin += idx[k] * stride;
            stride *= dims[k];
        }
        out.push(values.get(lin).copied().unwrap_or(f64::NAN));
        for k in (0..nd).rev() {
            idx[k] += 1;
            if idx[k] < dims[k] {
                break;
            }
            idx[k] = 0;
        }
    }
    out
}

impl MustParams {
    fn from_struct(path: &Path, param: &MatValue) -> Result<MustParams, IoError> {
        let map = match param {
            MatValue::Struct(m) => m.clone(),
            MatValue::StructArray { fields, .. } if fields.len() == 1 => fields[0].clone(),
            other => {
                return Err(IoError::invalid(
                    path,
                    "variable 'param'",
                    format!("must be a 1×1 struct, found a {}", other.describe()),
                ));
            }
        };
        let mut fields = BTreeMap::new();
        for (name, v) in map {
            match v {
                MatValue::Numeric {
                    dims,
                    real,
                    imag: None,
                    ..
                } => {
                    let values = column_to_row_major(&dims, &real.to_f64());
                    fields.insert(name, ParamArray { dims, values });
                }
                MatValue::Numeric { dims, .. } => {
                    // A complex parameter is unusable; keep it so that its use is an error.
                    fields.insert(
                        name,
                        ParamArray {
                            dims,
                            values: vec![f64::NAN],
                        },
                    );
                }
                _ => {}
            }
        }
        Ok(MustParams {
            prefix: "param.",
            fields,
        })
    }

    fn name(&self, field: &str) -> String {
        format!("{}{field}", self.prefix)
    }

    fn scalar(&self, path: &Path, name: &str) -> Result<Option<(f64, ParamSource)>, IoError> {
        match self.fields.get(name) {
            None => Ok(None),
            Some(a) if a.values.len() == 1 && a.values[0].is_finite() => {
                Ok(Some((a.values[0], field(self.name(name)))))
            }
            Some(a) => Err(IoError::invalid(
                path,
                self.name(name),
                format!(
                    "must be a real scalar, found {} values (dimensions {:?})",
                    a.values.len(),
                    a.dims
                ),
            )),
        }
    }
}

/// The samples of a MUST recording: the stored array and what its axes are.
struct MustSamples {
    array: StoredArray,
    axes: Vec<Axis>,
    /// "RF" or "IQ".
    variable: &'static str,
}

/// Builds channel data from an already-read MUST-style v5 MAT-file (`path` only names it in
/// errors).
pub fn from_mat(path: &Path, file: &MatFile) -> Result<ChannelData, IoError> {
    from_mat_file(path, file.clone(), &Overrides::default())?.read_all()
}

/// Opens a MATLAB v5 MUST-style file.
pub fn open_v5(path: &Path, overrides: &Overrides) -> Result<OpenedRecording, IoError> {
    let file = read_mat(path)?;
    from_mat_file(path, file, overrides)
}

/// The recording of a MUST-style file; the samples' variable is moved out of `file`, not copied
/// (a recording's samples are most of the file).
fn from_mat_file(
    path: &Path,
    mut file: MatFile,
    overrides: &Overrides,
) -> Result<OpenedRecording, IoError> {
    let variable = if file.get("RF").is_some() { "RF" } else { "IQ" };
    let (variable, value) = match file.variables.remove(variable) {
        Some(v) => (variable, v),
        None => {
            return Err(IoError::missing(
                path,
                "the file",
                "variable 'RF' (nor 'IQ'): not a MUST-style recording",
            ));
        }
    };
    let param = file
        .get("param")
        .ok_or_else(|| IoError::missing(path, "the file", "variable 'param'"))?;
    let params = MustParams::from_struct(path, param)?;
    let described = value.describe();
    let (mut dims, real, imag) = match value {
        MatValue::Numeric {
            dims, real, imag, ..
        } => (dims, real, imag),
        other => {
            return Err(IoError::invalid(
                path,
                format!("variable '{variable}'"),
                format!("must be a numeric array, found a {}", other.describe()),
            ));
        }
    };
    if variable == "RF" && imag.is_some() {
        return Err(IoError::invalid(
            path,
            "variable 'RF'",
            "is complex; expected real RF samples (complex baseband samples go in a variable 'IQ')",
        ));
    }
    if variable == "IQ" && imag.is_none() {
        return Err(IoError::invalid(
            path,
            "variable 'IQ'",
            "is real; expected complex IQ samples (real RF samples go in a variable 'RF')",
        ));
    }
    if dims.len() == 2 {
        dims.push(1);
    }
    if dims.len() < 3 || dims.iter().skip(3).any(|&d| d != 1) {
        return Err(IoError::invalid(
            path,
            format!("variable '{variable}'"),
            format!(
                "must be samples × elements × transmits (3-D, or 2-D for one transmit), found a {described}"
            ),
        ));
    }
    dims.truncate(3);
    let label = format!("{} variable '{variable}'", path.display());
    let samples = MustSamples {
        array: crate::mat::stored_array(dims, real, imag, label),
        axes: vec![Axis::Samples, Axis::Channels, Axis::Events],
        variable,
    };
    build(
        path,
        "MUST/PyMUST MATLAB v5 (.mat)",
        "pcuvd_io::must (MATLAB v5 read whole by pcuvd's reader)",
        params,
        samples,
        overrides,
    )
}

/// Opens a MATLAB v7.3 MUST-style file: `param` read whole, `RF`/`IQ` a block at a time.
pub fn open_v73(
    path: &Path,
    h5: &crate::hdf5::Hdf5,
    overrides: &Overrides,
) -> Result<OpenedRecording, IoError> {
    let variable = if h5.exists("RF") { "RF" } else { "IQ" };
    let param = crate::mat73::read_value(h5, "param")?;
    let params = MustParams::from_struct(path, &param)?;
    let (shape, kind) = h5.describe(variable)?;
    let dtype = match kind {
        crate::hdf5::H5Kind::Int {
            size: 2,
            signed: true,
        } => Dtype::I16,
        crate::hdf5::H5Kind::Float { size: 4 } => Dtype::F32,
        crate::hdf5::H5Kind::Float { size: 8 } => Dtype::F64,
        crate::hdf5::H5Kind::Complex { size: 4 } => Dtype::C64,
        crate::hdf5::H5Kind::Complex { size: 8 } => Dtype::C128,
        crate::hdf5::H5Kind::Int { .. } => Dtype::I32,
        other => {
            return Err(IoError::invalid(
                path,
                format!("variable '{variable}'"),
                format!("holds {other:?} values; expected numbers"),
            ));
        }
    };
    if shape.len() != 3 {
        return Err(IoError::invalid(
            path,
            format!("variable '{variable}'"),
            format!(
                "must be samples × elements × transmits (3-D), found HDF5 shape {shape:?} \
                 (MATLAB dimensions reversed)"
            ),
        ));
    }
    let samples = MustSamples {
        array: StoredArray {
            shape,
            dtype,
            fortran: false,
            backing: Backing::Hdf5 {
                path: path.to_path_buf(),
                dataset: variable.to_string(),
                imag: None,
            },
            label: format!("{} variable '{variable}'", path.display()),
        },
        // HDF5 holds MATLAB's dimensions reversed.
        axes: vec![Axis::Events, Axis::Channels, Axis::Samples],
        variable,
    };
    build(
        path,
        "MUST/PyMUST MATLAB v7.3 (HDF5 .mat)",
        "pcuvd_io::must (MATLAB v7.3 through rust-hdf5, a block of frames at a time)",
        params,
        samples,
        overrides,
    )
}

/// Opens a PyMUST-style `.npz`: `RF` or `IQ` (samples, elements, transmits) and the `param`
/// fields as arrays of their own (`np.savez(f, RF=RF, **param)`).
pub fn open_npz(path: &Path, overrides: &Overrides) -> Result<OpenedRecording, IoError> {
    let names = crate::npz::npz_members(path)?;
    let has = |n: &str| names.iter().any(|m| m == n);
    let variable = if has("RF") {
        "RF"
    } else if has("IQ") {
        "IQ"
    } else {
        ""
    };
    if variable.is_empty() || !has("fs") {
        return Err(IoError::malformed(
            path,
            format!(
                "is a NumPy .npz archive (arrays: {}) but not a self-describing PyMUST-style \
                 recording (arrays RF or IQ, with the param fields fs, fc, pitch, width, t0, PRF \
                 ...). Write a pcuvd recording manifest (.toml) that describes the acquisition \
                 and names the samples as [data].file = \"{}:ARRAY\"",
                names.join(", "),
                path.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            ),
        ));
    }
    let mut fields = BTreeMap::new();
    for name in names.iter().filter(|n| n.as_str() != variable) {
        if let Ok((dims, values)) = crate::npz::read_npz_values(path, name) {
            fields.insert(name.clone(), ParamArray { dims, values });
        }
    }
    let array = crate::npz::open_npz_member(path, variable)?;
    if array.shape.len() != 3 {
        return Err(IoError::invalid(
            path,
            variable,
            format!(
                "must be samples × elements × transmits (3-D, as PyMUST), found shape {:?}",
                array.shape
            ),
        ));
    }
    // NumPy keeps PyMUST's (samples, elements, transmits) axes whatever the memory order.
    let samples = MustSamples {
        array,
        axes: vec![Axis::Samples, Axis::Channels, Axis::Events],
        variable,
    };
    build(
        path,
        "PyMUST-style NumPy .npz",
        "pcuvd_io::must (NumPy .npz through zip)",
        MustParams { prefix: "", fields },
        samples,
        overrides,
    )
}

/// The acquisition of a MUST recording from its `param` and samples, checked, as a source.
fn build(
    path: &Path,
    format: &str,
    reader: &str,
    params: MustParams,
    samples: MustSamples,
    overrides: &Overrides,
) -> Result<OpenedRecording, IoError> {
    let var = samples.variable;
    let size = |a: Axis| {
        samples
            .axes
            .iter()
            .position(|&b| b == a)
            .map_or(0, |i| samples.array.shape[i])
    };
    let (n_samples, n_elements, n_transmits) = (
        size(Axis::Samples),
        size(Axis::Channels),
        size(Axis::Events),
    );
    if n_samples == 0 || n_elements == 0 || n_transmits == 0 {
        return Err(IoError::invalid(
            path,
            format!("variable '{var}'"),
            format!("is empty (dimensions {:?})", samples.array.shape),
        ));
    }
    let mut r = Resolver::new(overrides);
    let p = &params;
    let req = |name: &str| {
        let field = p.name(name);
        move || {
            IoError::missing(
                path,
                "variable 'param'",
                format!("field '{}'", field.trim_start_matches("param.")),
            )
        }
    };
    let fs = r.number(
        "sampling_frequency_hz",
        p.scalar(path, "fs")?,
        None,
        req("fs"),
    )?;
    let fs = positive(path, &p.name("fs"), fs)?;
    let fc = r.number(
        "center_frequency_hz",
        p.scalar(path, "fc")?,
        None,
        req("fc"),
    )?;
    let fc = positive(path, &p.name("fc"), fc)?;
    let pitch = positive(
        path,
        &p.name("pitch"),
        r.number("pitch_m", p.scalar(path, "pitch")?, None, req("pitch"))?,
    )?;
    let width = positive(
        path,
        &p.name("width"),
        r.number(
            "element_width_m",
            p.scalar(path, "width")?,
            None,
            req("width"),
        )?,
    )?;
    let c = positive(
        path,
        &p.name("c"),
        r.number(
            "sound_speed_m_s",
            p.scalar(path, "c")?,
            Some((DEFAULT_SOUND_SPEED, "MUST's default when param.c is absent")),
            req("c"),
        )?,
    )?;
    let bandwidth = positive(
        path,
        &p.name("bandwidth"),
        resolve_bandwidth(
            &mut r,
            p.scalar(path, "bandwidth")?.map(|(v, _)| {
                (
                    v / 100.0,
                    derived(format!("{} (%) / 100", p.name("bandwidth"))),
                )
            }),
            (
                DEFAULT_BANDWIDTH_PERCENT / 100.0,
                &format!("MUST's {DEFAULT_BANDWIDTH_PERCENT} % when param.bandwidth is absent"),
            ),
            fc,
            fs,
        ),
    )?;
    let pulse_cycles = positive(
        path,
        &p.name("TXnow"),
        r.number(
            "pulse_cycles",
            p.scalar(path, "TXnow")?,
            Some((
                DEFAULT_PULSE_CYCLES,
                "MUST's default when param.TXnow is absent",
            )),
            req("TXnow"),
        )?,
    )?;
    let prf = r.number("event_prf_hz", p.scalar(path, "PRF")?, None, || {
        missing_prf(path, &p.name("PRF"))
    })?;
    let prf = positive(path, &p.name("PRF"), prf)?;
    if let Some((ne, _)) = p.scalar(path, "Nelements")?
        && ne != n_elements as f64
    {
        return Err(IoError::invalid(
            path,
            p.name("Nelements"),
            format!("is {ne} but {var} has {n_elements} elements (its second dimension)"),
        ));
    }
    r.record(
        "n_elements",
        json!(n_elements),
        derived(format!("the second dimension of {var}")),
    );
    let probe = Probe {
        name: "from MAT file".into(),
        n_elements,
        pitch,
        element_width: width,
        center_frequency: fc,
        bandwidth,
    };
    let steering = transmit_angles(path, p, &probe.element_x(), c, n_transmits, fs)?;
    let t0_field = p.scalar(path, "t0")?.map(|(t0, src)| {
        if steering.offset == 0.0 {
            (t0, src)
        } else {
            (
                t0 - steering.offset,
                derived(format!(
                    "{} − the earliest delay of {} ({:.4} µs)",
                    p.name("t0"),
                    p.name("TXdelay"),
                    steering.offset * 1e6
                )),
            )
        }
    });
    let t0 = r.number("t0_s", t0_field, None, || missing_t0(path, &p.name("t0")))?;
    if !t0.is_finite() {
        return Err(IoError::invalid(
            path,
            p.name("t0"),
            format!("must be finite, got {t0}"),
        ));
    }
    let angles = r.angles((steering.angles, steering.source));
    r.record(
        "coding",
        json!("none"),
        ParamSource::Default {
            note: "MUST transmits one plane wave per event".into(),
        },
    );
    let demod = if var == "IQ" {
        let f = r.number(
            "demod_frequency_hz",
            Some((
                fc,
                derived(format!(
                    "{} (PyMUST's rf2iq(RF, param) demodulates at param.fc)",
                    p.name("fc")
                )),
            )),
            None,
            || IoError::missing(path, "variable 'param'", "field 'fc'"),
        )?;
        Some(f)
    } else {
        None
    };
    let acquisition = PlaneWaveAcquisition {
        probe,
        angles,
        event_prf: prf,
        coding: pcuvd::Coding::Conventional,
        pulse_cycles,
        sampling_frequency: fs,
        sound_speed: c,
        t0,
    }
    .build(path)?;
    let n = acquisition.sequence.n_angles();
    if n_samples < 2 {
        return Err(IoError::Recording {
            path: path.to_path_buf(),
            source: pcuvd::Error::Shape(format!(
                "each trace needs at least 2 samples, got {n_samples}"
            )),
        });
    }
    let stored = StoredSamples::of(&samples.array, &samples.axes, demod.is_some());
    let frames = ArrayFrames::new(path, acquisition, samples.array, samples.axes, demod)?;
    let mut warnings = Vec::new();
    if n_transmits % n != 0 {
        warnings.push(format!(
            "{n_transmits} transmits are not whole frames of {n}"
        ));
    }
    let opened = OpenedRecording {
        source: Box::new(frames),
        read_pass: None,
        info: SourceInfo {
            files: vec![path.to_path_buf()],
            format: format.into(),
            reader: reader.into(),
            parameters: r.params,
            stored: Some(stored),
            warnings,
            cardiac_triggers_s: None,
        },
    };
    // A block holds whole frames only: check finiteness of every sample up front for files read
    // whole into memory (cheap there), so that a NaN is reported before any processing.
    if opened.source.resident_bytes() > 0 {
        opened.read_all()?;
    }
    Ok(opened)
}

/// The steering of a MUST recording's transmits: the angles of a compound frame, the earliest
/// delay of the delay laws (s) and where the angles came from.
struct Steering {
    angles: Vec<f64>,
    offset: f64,
    source: ParamSource,
}

/// Derives the compound frame's angles from `param.TXdelay` (one row per transmit, or per angle
/// with transmits cycling through the rows).
fn transmit_angles(
    path: &Path,
    p: &MustParams,
    element_x: &[f64],
    c: f64,
    n_transmits: usize,
    fs: f64,
) -> Result<Steering, IoError> {
    let name = p.name("TXdelay");
    let Some(a) = p.fields.get("TXdelay") else {
        return Ok(Steering {
            angles: vec![0.0],
            offset: 0.0,
            source: ParamSource::Default {
                note: format!("no {name}: one unsteered plane wave"),
            },
        });
    };
    let n_el = element_x.len();
    let fail = |problem: String| IoError::invalid(path, name.clone(), problem);
    let rows: Vec<&[f64]> = match a.dims.as_slice() {
        [e] if *e == n_el => vec![&a.values[..]],
        [1, e] | [e, 1] if *e == n_el => vec![&a.values[..]],
        [r, e] if *e == n_el && *r >= 1 => a.values.chunks_exact(n_el).collect(),
        dims => {
            return Err(fail(format!(
                "has dimensions {dims:?}; expected one row of {n_el} delays (one per element) \
                 per transmit"
            )));
        }
    };
    if !n_transmits.is_multiple_of(rows.len()) {
        return Err(fail(format!(
            "has {} rows (delay laws) but the recording has {n_transmits} transmits: give one \
             row per transmit, or one per angle when the transmits cycle through them",
            rows.len()
        )));
    }
    let mut angles = Vec::with_capacity(rows.len());
    let mut offsets = Vec::with_capacity(rows.len());
    for (k, row) in rows.iter().enumerate() {
        let angle = plane_wave_angle(row, element_x, c).map_err(|e| {
            if rows.len() == 1 {
                fail(e)
            } else {
                fail(format!("row {} {e}", k + 1))
            }
        })?;
        angles.push(angle);
        offsets.push(row.iter().copied().fold(f64::INFINITY, f64::min));
    }
    let angle_of = |i: usize| angles[i % angles.len()];
    // The compound frame: the shortest period the transmits' angles repeat with.
    let period = (1..=n_transmits)
        .filter(|n| n_transmits.is_multiple_of(*n))
        .find(|&n| (0..n_transmits).all(|i| (angle_of(i) - angle_of(i % n)).abs() < 1e-6))
        .unwrap_or(n_transmits);
    let frame: Vec<f64> = (0..period).map(angle_of).collect();
    let (lo, hi) = offsets
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &d| {
            (l.min(d), h.max(d))
        });
    if hi - lo > 0.01 / fs {
        return Err(fail(format!(
            "rows start at different times (earliest delays from {:.4} to {:.4} µs): pcuvd needs \
             every transmit's first element to fire at the same time after the event starts",
            lo * 1e6,
            hi * 1e6
        )));
    }
    Ok(Steering {
        angles: frame,
        offset: lo,
        source: derived(if rows.len() == 1 {
            format!("{name} (the plane-wave steering of its delay law)")
        } else {
            format!(
                "{name} ({} delay laws, each checked to be a plane wave; the transmits cycle \
                 through {period} angles)",
                rows.len()
            )
        }),
    })
}

#[cfg(test)]
mod tests;
