//! The recording manifest: a TOML file (format "pcuvd-recording", SI units with the unit in each
//! key name) that describes the acquisition and points at a `.npy` file of samples.
//!
//! Version 1 says plane waves by angle, coding "none" or "hadamard" with evenly spaced slots, and
//! a pulse length in cycles; see `crates/pcuvd-io/examples/recording.toml`. Version 2 adds what
//! scanners' sequences need: per-element transmit delays per slot (`transmit_delays_s`, the
//! steering angle and slot start derived from them and checked to be a plane wave), an explicit
//! code matrix in the scanner's row order (`coding = "matrix"`, `code_matrix`), uneven slot
//! starts (`slot_delays_s`), the transmit pulse as samples (`[acquisition.pulse]`), and the
//! per-frame axis of the samples named `events` (an event of a coded frame fires every angle);
//! see `crates/pcuvd-io/examples/recording_v2.toml`. Every key is checked against its range, and
//! an error names the key. Angles may be given as `angles_deg` or `angles_rad` (exactly one);
//! [`write_recording`] writes `angles_rad` so that a written recording reads back bit for bit,
//! and writes version 1 whenever version 1 can say the sequence (so such files stay unchanged).

use std::path::{Path, PathBuf};

use ndarray::{Array3, Array4, ArrayD};
use pcuvd::{
    Acquisition, ChannelData, Coding, Hadamard, Probe, Samples, Sequence, TransmitCode,
    TransmitPulse,
};
use serde::Deserialize;

use crate::error::IoError;
use crate::npy::{NpyArray, write_npy};

/// The value of the manifest's `format` key.
pub const FORMAT: &str = "pcuvd-recording";
/// The newest manifest version this crate reads and writes (it reads every version from 1).
pub const VERSION: i64 = 2;

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
    cardiac: Option<CardiacSection>,
    #[serde(default)]
    provenance: toml::Table,
}

/// `[cardiac]`: the cardiac cycles recorded beside the ultrasound, for the dynamics stage.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CardiacSection {
    /// Cycle start times (s from the first frame): ECG R-waves or scanner triggers.
    triggers_s: Option<Vec<f64>>,
    /// A 1-D `.npy` or text file of such times, relative to the manifest's folder.
    triggers_file: Option<String>,
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
    // Version 2 only.
    slot_delays_s: Option<Vec<f64>>,
    code_matrix: Option<Vec<Vec<f64>>>,
    transmit_delays_s: Option<Vec<Vec<f64>>>,
    pulse: Option<PulseSection>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PulseSection {
    sampling_frequency_hz: Option<f64>,
    samples: Option<Vec<f64>>,
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
    let msg = crate::error::flat(e.message().trim());
    match e.span() {
        Some(span) => {
            let (line, col) = line_col(text, span.start);
            match key_at(text, span.start) {
                Some(key) => {
                    IoError::invalid(path, key, format!("(line {line}, column {col}): {msg}"))
                }
                None => IoError::malformed(path, format!("line {line}, column {col}: {msg}")),
            }
        }
        None => IoError::malformed(path, msg),
    }
}

/// The key (as "[table].key") whose value holds byte `offset` of a manifest's `text`, when that
/// line is a `key = value` line: a type error then names the key, not only the line.
fn key_at(text: &str, offset: usize) -> Option<String> {
    let before = text.get(..offset.min(text.len()))?;
    let start = before.rfind('\n').map_or(0, |i| i + 1);
    let line = text[start..].lines().next()?;
    let (key, _) = line.split_once('=')?;
    let key = key.trim();
    if key.is_empty() || key.starts_with(['#', '[']) || key.contains(char::is_whitespace) {
        return None;
    }
    let table = before[..start]
        .lines()
        .rev()
        .map(str::trim)
        .find(|l| l.starts_with('[') && l.ends_with(']'));
    Some(match table {
        Some(table) => format!("{table}.{key}"),
        None => key.to_string(),
    })
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
        ..
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
    data.validate().map_err(|source| match source {
        pcuvd::Error::NonFinite(_) => IoError::invalid(
            &data_path,
            "the samples",
            "hold NaN or Inf values (every sample must be finite)",
        ),
        source => IoError::Recording {
            path: path.to_path_buf(),
            source,
        },
    })?;
    Ok(Recording {
        data,
        provenance,
        manifest_path: path.to_path_buf(),
        data_path,
    })
}

/// The error for RF samples whose sampling frequency folds the probe's band
/// ([`Acquisition::rf_band_sampling`]), naming the key.
fn rf_sampling_error(path: &Path, source: pcuvd::Error) -> IoError {
    match source {
        pcuvd::Error::InvalidParameter { reason, .. } => IoError::invalid(
            path,
            "[acquisition].sampling_frequency_hz",
            format!("is invalid for RF samples: {reason}"),
        ),
        source => IoError::Recording {
            path: path.to_path_buf(),
            source,
        },
    }
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
/// [`crate::readers::manifest::frames::ManifestFrames`] share.
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
    /// Cardiac cycle start times (s from the first frame) of `[cardiac]`, checked.
    pub(crate) cardiac_triggers_s: Option<Vec<f64>>,
}

/// The cycle start times of a manifest's `[cardiac]` table (inline or from its file), checked.
fn cardiac_triggers(
    path: &Path,
    cardiac: Option<CardiacSection>,
) -> Result<Option<Vec<f64>>, IoError> {
    let Some(c) = cardiac else {
        return Ok(None);
    };
    match (c.triggers_s, c.triggers_file) {
        (Some(times), None) => {
            crate::cardiac::check_times_of(path, "[cardiac].triggers_s", &times)?;
            Ok(Some(times))
        }
        (None, Some(file)) => {
            let file = path.parent().unwrap_or(Path::new("")).join(file);
            crate::cardiac::read_trigger_times(&file)
                .map(Some)
                .map_err(|e| IoError::invalid(path, "[cardiac].triggers_file", format!("{e}")))
        }
        (Some(_), Some(_)) => Err(IoError::invalid(
            path,
            "[cardiac]",
            "give triggers_s or triggers_file, not both",
        )),
        (None, None) => Err(IoError::missing(
            path,
            "table [cardiac]",
            "key 'triggers_s' or 'triggers_file'",
        )),
    }
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
    let version = match table.get("version") {
        None => return Err(IoError::missing(path, "the manifest", "key 'version'")),
        Some(toml::Value::Integer(v)) if (1..=VERSION).contains(v) => *v,
        Some(v) => {
            return Err(IoError::invalid(
                path,
                "version",
                format!("is {v}; this reader knows versions 1 to {VERSION}"),
            ));
        }
    };
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
    let acquisition = acquisition_of(path, version, &acq, probe)?;

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
    if demod.is_none() {
        acquisition
            .rf_band_sampling()
            .map_err(|e| rf_sampling_error(path, e))?;
    }
    let perm =
        axis_permutation(&axes, version).map_err(|p| IoError::invalid(path, "[data].axes", p))?;
    let data = crate::datafile::parse_data_file(path, &file)?;
    let cardiac_triggers_s = cardiac_triggers(path, m.cardiac)?;
    Ok(Parsed {
        cardiac_triggers_s,
        acquisition,
        provenance: m.provenance,
        data_path: data.path,
        data_member: data.member,
        axes,
        perm,
        demod,
    })
}

/// The manifest key that holds the quantity pcuvd's checks call `name` (see
/// [`pcuvd::Error::InvalidParameter`]), given which keys `acq` uses.
fn key_of(name: &str, acq: &AcquisitionSection) -> Option<&'static str> {
    Some(match name {
        "number of elements" => "[probe].n_elements",
        "pitch" => "[probe].pitch_m",
        "element width" => "[probe].element_width_m",
        "centre frequency" => "[probe].center_frequency_hz",
        "bandwidth" => "[probe].bandwidth",
        "sampling frequency" => "[acquisition].sampling_frequency_hz",
        "speed of sound" => "[acquisition].sound_speed_m_s",
        "t0" => "[acquisition].t0_s",
        "event PRF" => "[acquisition].event_prf_hz",
        "pulse cycles" => "[acquisition].pulse_cycles",
        "angles" if acq.angles_deg.is_some() => "[acquisition].angles_deg",
        "angles" if acq.angles_rad.is_some() => "[acquisition].angles_rad",
        "angles" => "[acquisition].transmit_delays_s",
        "slot delay" => "[acquisition].slot_delay_s",
        "slot delays" if acq.slot_delays_s.is_some() => "[acquisition].slot_delays_s",
        "slot delays" if acq.transmit_delays_s.is_some() => "[acquisition].transmit_delays_s",
        "slot delays" => "[acquisition].slot_delay_s",
        "code matrix" if acq.code_matrix.is_some() => "[acquisition].code_matrix",
        "code matrix" => "[acquisition].coding",
        "pulse samples" => "[acquisition.pulse].samples",
        "pulse sampling frequency" => "[acquisition.pulse].sampling_frequency_hz",
        _ => return None,
    })
}

/// pcuvd's refusal of the acquisition in the manifest `path`, naming the key that holds the
/// refused quantity.
fn acquisition_error(path: &Path, source: pcuvd::Error, acq: &AcquisitionSection) -> IoError {
    match &source {
        pcuvd::Error::InvalidParameter { name, reason } => match key_of(name, acq) {
            Some(key) => IoError::invalid(path, key, format!("is invalid ({name}): {reason}")),
            None => IoError::Recording {
                path: path.to_path_buf(),
                source,
            },
        },
        pcuvd::Error::HadamardOrder(n) => IoError::invalid(
            path,
            "[acquisition].coding",
            format!("is \"hadamard\" with {n} angles, but {source}"),
        ),
        _ => IoError::Recording {
            path: path.to_path_buf(),
            source,
        },
    }
}

/// The keys only version 2 knows, and whether `acq` uses each.
fn version_two_keys(acq: &AcquisitionSection) -> [(&'static str, bool); 5] {
    [
        ("[acquisition].slot_delays_s", acq.slot_delays_s.is_some()),
        ("[acquisition].code_matrix", acq.code_matrix.is_some()),
        (
            "[acquisition].transmit_delays_s",
            acq.transmit_delays_s.is_some(),
        ),
        ("[acquisition.pulse]", acq.pulse.is_some()),
        (
            "[acquisition].coding",
            acq.coding.as_deref() == Some("matrix"),
        ),
    ]
}

/// The acquisition a manifest of `version` describes with its `[acquisition]` table `acq` and
/// `probe`, every key checked (each error names its key).
fn acquisition_of(
    path: &Path,
    version: i64,
    acq: &AcquisitionSection,
    probe: Probe,
) -> Result<Acquisition, IoError> {
    let key = |k: &str| format!("[acquisition].{k}");
    let miss = |k: &str| IoError::missing(path, "table [acquisition]", format!("key '{k}'"));
    let refuse = |source: pcuvd::Error| acquisition_error(path, source, acq);
    if version < 2
        && let Some((name, _)) = version_two_keys(acq).into_iter().find(|(_, used)| *used)
    {
        let what = if name == "[acquisition].coding" {
            "= \"matrix\" is".to_string()
        } else {
            "is".to_string()
        };
        return Err(IoError::invalid(
            path,
            name,
            format!(
                "{what} only known to version 2 manifests; this one says version = 1 (set version = 2)"
            ),
        ));
    }
    probe.validate().map_err(refuse)?;
    let c = acq.sound_speed_m_s.ok_or_else(|| miss("sound_speed_m_s"))?;
    pcuvd::error::require_range(
        "speed of sound",
        c,
        pcuvd::channel::SOUND_SPEED_RANGE,
        "m/s",
    )
    .map_err(refuse)?;

    // Per-element transmit delays: one plane wave per slot, or an error.
    let tolerance = pcuvd::geometry::PLANE_WAVE_TOLERANCE_PERIODS / probe.center_frequency;
    let waves = match &acq.transmit_delays_s {
        None => None,
        Some(rows) if rows.is_empty() => {
            return Err(IoError::invalid(
                path,
                key("transmit_delays_s"),
                "is empty; give one row of per-element firing times (s) per slot",
            ));
        }
        Some(rows) => {
            let xs = probe.element_x();
            let mut waves = Vec::with_capacity(rows.len());
            for (k, row) in rows.iter().enumerate() {
                let mut wave = pcuvd::geometry::plane_wave_from_delays(row, &xs, c, tolerance)
                    .map_err(|e| {
                        IoError::invalid(path, key("transmit_delays_s"), format!("row {k} {e}"))
                    })?;
                // Delays quantised by the scanner's clock may put the first firing a hair
                // before the origin.
                if wave.start < 0.0 && wave.start >= -tolerance {
                    wave.start = 0.0;
                }
                if wave.start < 0.0 {
                    return Err(IoError::invalid(
                        path,
                        key("transmit_delays_s"),
                        format!(
                            "row {k}: the slot's first element fires at {:.4} µs, before the \
                             event's time origin; delays count from the origin of t0_s (≥ 0)",
                            wave.start * 1e6
                        ),
                    ));
                }
                waves.push(wave);
            }
            Some(waves)
        }
    };

    // Angles: given, derived from the delays, or both (then they must agree).
    let given = match (&acq.angles_deg, &acq.angles_rad) {
        (Some(d), None) => Some((
            "angles_deg",
            d.iter().map(|a| a.to_radians()).collect::<Vec<f64>>(),
        )),
        (None, Some(r)) => Some(("angles_rad", r.clone())),
        (None, None) => None,
        (Some(_), Some(_)) => {
            return Err(IoError::invalid(
                path,
                key("angles_rad"),
                "is given together with angles_deg; give exactly one",
            ));
        }
    };
    let angles = match (given, &waves) {
        (Some((_, a)), None) => a,
        (None, Some(w)) => w.iter().map(|w| w.angle).collect(),
        (None, None) => return Err(miss("angles_deg")),
        (Some((name, a)), Some(w)) => {
            if a.len() != w.len() {
                return Err(IoError::invalid(
                    path,
                    key(name),
                    format!(
                        "lists {} angles but transmit_delays_s has {} rows (one per slot)",
                        a.len(),
                        w.len()
                    ),
                ));
            }
            let (lo, hi) = probe.aperture();
            for (k, (given, wave)) in a.iter().zip(w).enumerate() {
                // The given angle's delays may differ from the fitted plane wave's by as much as
                // the delays may differ from it.
                if ((given.sin() - wave.angle.sin()) * (hi - lo) / c).abs() > tolerance {
                    return Err(IoError::invalid(
                        path,
                        key(name),
                        format!(
                            "gives slot {k} {:.4}° but row {k} of transmit_delays_s steers \
                             {:.4}°",
                            given.to_degrees(),
                            wave.angle.to_degrees()
                        ),
                    ));
                }
            }
            w.iter().map(|w| w.angle).collect()
        }
    };
    let n = angles.len();

    // Slot starts: evenly spaced, listed, or from the delays (at most one of these).
    let start_keys: Vec<&str> = [
        ("slot_delay_s", acq.slot_delay_s.is_some()),
        ("slot_delays_s", acq.slot_delays_s.is_some()),
        ("transmit_delays_s", waves.is_some()),
    ]
    .into_iter()
    .filter(|(_, used)| *used)
    .map(|(k, _)| k)
    .collect();
    if let [first, second, ..] = start_keys[..] {
        return Err(IoError::invalid(
            path,
            key(second),
            format!(
                "is given together with {first}; slot starts come from one of slot_delay_s, \
                 slot_delays_s and transmit_delays_s"
            ),
        ));
    }
    let listed = match (&acq.slot_delays_s, &waves) {
        (Some(list), _) => {
            if list.len() != n {
                return Err(IoError::invalid(
                    path,
                    key("slot_delays_s"),
                    format!(
                        "lists {} slot starts for {n} angles (one per slot)",
                        list.len()
                    ),
                ));
            }
            Some(list.clone())
        }
        (None, Some(w)) => Some(w.iter().map(|w| w.start).collect()),
        (None, None) => None,
    };
    let only_with = |k: &str, coding: &str| {
        IoError::invalid(
            path,
            key(k),
            format!("is only meaningful with coding = \"{coding}\""),
        )
    };
    let coding = match acq.coding.as_deref() {
        None => return Err(miss("coding")),
        Some("none") => {
            if acq.slot_delay_s.is_some() {
                return Err(only_with("slot_delay_s", "hadamard"));
            }
            if acq.code_matrix.is_some() {
                return Err(only_with("code_matrix", "matrix"));
            }
            match listed {
                Some(starts) if starts.iter().any(|&t| t != 0.0) => {
                    Coding::Matrix(TransmitCode::one_per_event(starts))
                }
                _ => Coding::Conventional,
            }
        }
        Some("hadamard") => {
            if acq.code_matrix.is_some() {
                return Err(only_with("code_matrix", "matrix"));
            }
            match (acq.slot_delay_s, listed) {
                (Some(slot_delay), _) => Coding::Hadamard { slot_delay },
                (None, Some(starts)) => {
                    let h = Hadamard::new(n).map_err(refuse)?;
                    Coding::Matrix(TransmitCode::hadamard(&h, starts))
                }
                (None, None) => return Err(miss("slot_delay_s")),
            }
        }
        Some("matrix") => {
            let rows = acq
                .code_matrix
                .as_ref()
                .ok_or_else(|| miss("code_matrix"))?;
            if rows.len() != n || rows.iter().any(|r| r.len() != n) {
                let lengths: Vec<usize> = rows.iter().map(Vec::len).collect();
                return Err(IoError::invalid(
                    path,
                    key("code_matrix"),
                    format!(
                        "has {} rows of lengths {lengths:?}; {n} angles need {n} rows of {n}: \
                         row i gives the weight (±1) of each slot (angle) in event i of a \
                         compound frame",
                        rows.len()
                    ),
                ));
            }
            let starts = match (acq.slot_delay_s, listed) {
                (Some(d), _) => (0..n).map(|k| k as f64 * d).collect(),
                (None, Some(starts)) => starts,
                (None, None) => {
                    return Err(IoError::missing(
                        path,
                        "table [acquisition]",
                        "key 'slot_delays_s' (or slot_delay_s, or transmit_delays_s): when each \
                         slot fires",
                    ));
                }
            };
            Coding::Matrix(TransmitCode {
                weights: rows.iter().flatten().copied().collect(),
                slot_starts: starts,
            })
        }
        Some(other) => {
            let expected = if version < 2 {
                "\"none\" or \"hadamard\""
            } else {
                "\"none\", \"hadamard\" or \"matrix\""
            };
            return Err(IoError::invalid(
                path,
                key("coding"),
                format!("is \"{other}\"; expected {expected}"),
            ));
        }
    };

    // The pulse: its length in cycles, and (version 2) its samples.
    let pulse = match &acq.pulse {
        None => None,
        Some(p) => {
            let pulse = TransmitPulse {
                samples: p.samples.clone().ok_or_else(|| {
                    IoError::missing(path, "table [acquisition.pulse]", "key 'samples'")
                })?,
                sampling_frequency: p.sampling_frequency_hz.ok_or_else(|| {
                    IoError::missing(
                        path,
                        "table [acquisition.pulse]",
                        "key 'sampling_frequency_hz'",
                    )
                })?,
            };
            pulse.validate().map_err(refuse)?;
            Some(pulse)
        }
    };
    let pulse_cycles = match (acq.pulse_cycles, &pulse) {
        (Some(cycles), _) => cycles,
        (None, Some(p)) => p.duration() * probe.center_frequency,
        (None, None) => return Err(miss("pulse_cycles")),
    };
    let req = |v: Option<f64>, k: &str| v.ok_or_else(|| miss(k));
    let acquisition = Acquisition {
        probe,
        sequence: Sequence {
            angles,
            event_prf: req(acq.event_prf_hz, "event_prf_hz")?,
            coding,
            pulse_cycles,
            pulse,
        },
        sampling_frequency: req(acq.sampling_frequency_hz, "sampling_frequency_hz")?,
        sound_speed: c,
        t0: req(acq.t0_s, "t0_s")?,
    };
    acquisition.validate().map_err(refuse)?;
    Ok(acquisition)
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
                let axis = axes.get(perm[1]).map_or("angles", String::as_str);
                return Err(IoError::invalid(
                    path,
                    "[acquisition].angles",
                    format!(
                        "lists {n_angles} angles (so {n_angles} events per compound frame) but \
                         the '{axis}' axis of {} has {a} (shape {shape:?})",
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

/// The named axes of samples in canonical order: (frames, angles, channels, samples) in a version 1
/// manifest, (frames, events, channels, samples) from version 2 (the second axis counts the events
/// of a compound frame: a coded event fires every angle), or (events, channels, samples).
fn canonical_axes(count: usize, version: i64) -> &'static [&'static str] {
    match (count, version) {
        (4, 1) => &["frames", "angles", "channels", "samples"],
        (4, _) => &["frames", "events", "channels", "samples"],
        _ => &["events", "channels", "samples"],
    }
}

/// For each canonical axis ([`canonical_axes`]), its index among the named axes.
fn axis_permutation(axes: &[String], version: i64) -> Result<Vec<usize>, String> {
    let canonical = canonical_axes(axes.len(), version);
    let is_perm = (axes.len() == 3 || axes.len() == 4)
        && canonical
            .iter()
            .all(|c| axes.iter().filter(|a| a.as_str() == *c).count() == 1);
    if !is_perm {
        let four = canonical_axes(4, version);
        let hint = if version >= 2 && axes.iter().any(|a| a == "angles") {
            " (from version 2 the axis of the events of a compound frame is named \"events\", \
             not \"angles\": a coded event fires every angle)"
        } else {
            ""
        };
        return Err(format!(
            "is {axes:?}; expected an ordering of {four:?} or of [\"events\", \"channels\", \
             \"samples\"]{hint}"
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

/// Writes `{stem}.npy` (float32 RF or complex64 IQ, axes frames × angles × channels × samples, or
/// frames × events × ... in a version 2 manifest) and `{stem}.toml` in `dir` (created if needed),
/// in manifest version 1 when it can say the acquisition, else version 2; returns the manifest's
/// path.
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

/// The manifest version a recording acquired as `acq` needs: 1 unless its sequence has an
/// explicit code or a sampled pulse (so recordings version 1 can say are written as before).
fn version_needed(acq: &Acquisition) -> i64 {
    match (&acq.sequence.coding, &acq.sequence.pulse) {
        (Coding::Matrix(_), _) | (_, Some(_)) => 2,
        _ => 1,
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
    let version = version_needed(acq);
    let mut t = String::new();
    t.push_str("# pcuvd recording manifest (SI units; the unit is in each key's name).\n");
    t.push_str(&format!(
        "format = {}\nversion = {version}\n\n",
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
    let list = |values: &[f64]| {
        values
            .iter()
            .map(|&v| toml_f64(v))
            .collect::<Vec<_>>()
            .join(", ")
    };
    match &acq.sequence.coding {
        Coding::Conventional => t.push_str("coding = \"none\"\n"),
        Coding::Hadamard { slot_delay } => t.push_str(&format!(
            "coding = \"hadamard\"\nslot_delay_s = {}\n",
            toml_f64(*slot_delay)
        )),
        Coding::Matrix(code) => {
            t.push_str("coding = \"matrix\"\n");
            t.push_str("# row i: the weight of each slot (angle) in event i of a compound frame\n");
            t.push_str("code_matrix = [\n");
            for row in code.weights.chunks(code.order().max(1)) {
                t.push_str(&format!("    [{}],\n", list(row)));
            }
            t.push_str("]\n");
            t.push_str(&format!("slot_delays_s = [{}]\n", list(&code.slot_starts)));
        }
    }
    if let Some(pulse) = &acq.sequence.pulse {
        t.push_str("\n[acquisition.pulse]\n");
        t.push_str(&format!(
            "sampling_frequency_hz = {}\n",
            toml_f64(pulse.sampling_frequency)
        ));
        t.push_str(&format!("samples = [{}]\n", list(&pulse.samples)));
    }
    t.push_str("\n[data]\n");
    t.push_str(&format!("file = {}\n", toml_str(npy_name)));
    t.push_str(kind_lines);
    t.push_str(&format!(
        "axes = {}\n",
        toml::Value::Array(
            canonical_axes(4, version)
                .iter()
                .map(|a| toml::Value::String(a.to_string()))
                .collect()
        )
    ));
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
