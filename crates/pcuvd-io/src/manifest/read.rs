//! Reading a manifest: its TOML checked key by key (errors name the key, with line and column),
//! the probe, acquisition, data and cardiac tables turned into a [`Parsed`] manifest, and
//! [`read_recording`], which reads its samples whole.

use std::path::{Path, PathBuf};

use pcuvd::{Acquisition, ChannelData, Samples};

use super::acquisition::{acquisition_of, probe_of};
use super::axes::{axis_permutation, event_shape, to_events};
use super::schema::ManifestFile;
use super::{FORMAT, Recording, VERSION};
use crate::error::IoError;
use crate::npy::NpyArray;

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
    let probe = probe_of(path, &m.probe.ok_or_else(|| no_table("probe"))?)?;

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
    let cardiac_triggers_s = crate::cardiac::triggers_of_section(path, m.cardiac)?;
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
