//! What every reader returns, and the vocabulary they share: an [`OpenedRecording`] (the frames,
//! read a block at a time, and the [`SourceInfo`] that says what was read and where each
//! parameter came from), how the samples are stored ([`StoredSamples`]), the defaults a reader
//! takes when a file does not say ([`DEFAULT_PULSE_CYCLES`], [`DEFAULT_BANDWIDTH`]) and the
//! plane-wave fit of a transmit delay law ([`plane_wave_angle`]). Nothing here knows a format:
//! the readers ([`crate::readers`]) import it, and it imports none of them.

use std::path::{Path, PathBuf};

use pcuvd::acquisition::source::FrameSource;
use pcuvd::{Acquisition, ChannelData, Coding, Probe, Sequence};
use serde::Serialize;

use crate::array::{Axis, StoredArray};
use crate::error::IoError;
use crate::params::{ParamSource, Parameter, Resolver};

/// Transmit pulse length (cycles) a reader assumes when the file does not record it (MUST's
/// default when `param.TXnow` is absent).
pub const DEFAULT_PULSE_CYCLES: f64 = 2.0;

/// pcuvd's fractional bandwidth when the file does not record it (UFF's
/// `pulse/fractional_bandwidth`, zea's `probe_bandwidth_percent`, Verasonics' `Trans.Bandwidth`)
/// and the sampling holds it ([`unstated_bandwidth`]).
pub const DEFAULT_BANDWIDTH: f64 = 0.67;

/// The fractional bandwidth to take when a file does not state it: `default` (with its `note`)
/// when RF sampled at `sampling_frequency` (Hz) holds that band around `center_frequency` (Hz),
/// else the widest band centred on f_c that one Nyquist zone of the sampling holds, with a note
/// saying so. The bandwidth only decides whether the sampling folds the band (processing never
/// filters by it), so a file that does not state it must not be refused for a guess that folds;
/// the user states the probe's own with `--bandwidth` (Python: `bandwidth=`).
fn unstated_bandwidth(
    default: f64,
    note: &str,
    center_frequency: f64,
    sampling_frequency: f64,
) -> (f64, String) {
    let half = sampling_frequency / 2.0;
    if !(center_frequency > 0.0 && half > 0.0) {
        return (default, note.to_string());
    }
    let zone = (center_frequency / half).floor();
    let room = (center_frequency - zone * half).min((zone + 1.0) * half - center_frequency);
    let widest = 2.0 * room / center_frequency;
    // Just inside the zone, so that rounding never puts a band edge across it.
    let widest = widest * (1.0 - 1e-9);
    if default <= widest || widest <= 0.0 {
        (default, note.to_string())
    } else {
        (
            widest,
            format!(
                "{note}, narrowed to {:.1} %, the widest band around f_c {:.3} MHz that sampling \
                 at {:.4} MHz holds without folding; state the probe's with --bandwidth \
                 (Python: bandwidth=)",
                widest * 100.0,
                center_frequency * 1e-6,
                sampling_frequency * 1e-6
            ),
        )
    }
}

/// Resolves a reader's fractional bandwidth and records it in `r`: the user's (`--bandwidth`),
/// else `found` in the file, else `default` (with its `note`) narrowed to what the sampling holds
/// ([`unstated_bandwidth`]); f_c and f_s in Hz.
pub fn resolve_bandwidth(
    r: &mut Resolver<'_>,
    found: Option<(f64, ParamSource)>,
    (default, note): (f64, &str),
    center_frequency: f64,
    sampling_frequency: f64,
) -> f64 {
    let (value, source) = match (r.overrides.bandwidth, found) {
        (Some(given), _) => (given, ParamSource::Override),
        (None, Some(found)) => found,
        (None, None) => {
            let (value, note) =
                unstated_bandwidth(default, note, center_frequency, sampling_frequency);
            (value, ParamSource::Default { note })
        }
    };
    r.record("bandwidth", serde_json::json!(value), source);
    value
}

/// How the samples are stored in the file.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StoredSamples {
    /// The array, as the file names it (file and variable, member or dataset).
    pub array: String,
    /// Its shape, in the file's order.
    pub shape: Vec<usize>,
    /// What each axis is ("frames", "angles", "events", "channels", "samples"...).
    pub axes: Vec<String>,
    /// Element type as stored ("int16", "float32", "complex64"...).
    pub dtype: String,
    /// "rf" or "iq".
    pub kind: String,
}

impl StoredSamples {
    /// How `array`, whose axes are `axes`, is stored; `iq` for complex baseband samples.
    pub fn of(array: &StoredArray, axes: &[Axis], iq: bool) -> StoredSamples {
        StoredSamples {
            array: array.label.clone(),
            shape: array.shape.clone(),
            axes: axes.iter().map(|a| a.name().to_string()).collect(),
            dtype: array.dtype_name(),
            kind: if iq { "iq" } else { "rf" }.into(),
        }
    }
}

/// What a reader understood of a recording, besides its samples.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SourceInfo {
    /// Every file read (a manifest and its samples file, or the one file).
    pub files: Vec<PathBuf>,
    /// The format, e.g. "USTB UFF (HDF5)".
    pub format: String,
    /// The reader, e.g. "pcuvd_io::uff (a block of frames at a time)".
    pub reader: String,
    /// Every acquisition parameter with its value and source.
    pub parameters: Vec<Parameter>,
    /// How the samples are stored.
    pub stored: Option<StoredSamples>,
    /// Things the user should know (a default taken, a field ignored).
    pub warnings: Vec<String>,
    /// Cardiac cycle start times (s from the first frame) recorded with the recording (a
    /// manifest's `[cardiac]`), for the dynamics stage; `None` when it has none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cardiac_triggers_s: Option<Vec<f64>>,
}

/// A recording opened for reading: its frames and what was read.
pub struct OpenedRecording {
    /// The compound frames, read a block at a time.
    pub source: Box<dyn FrameSource + Send>,
    /// Files, format, reader, parameters and their sources, warnings.
    pub info: SourceInfo,
    /// The hook through which the reader feeds one of `info.files` to a checksum as it reads its
    /// blocks, when it reads that file in order block by block; `None` otherwise.
    pub read_pass: Option<crate::ReadPass>,
}

impl std::fmt::Debug for OpenedRecording {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenedRecording")
            .field("info", &self.info)
            .finish_non_exhaustive()
    }
}

impl SourceInfo {
    /// The acquisition parameter named `name` ("bandwidth", "t0_s"...), if the reader recorded it.
    pub fn parameter(&self, name: &str) -> Option<&Parameter> {
        self.parameters.iter().find(|p| p.name == name)
    }
}

impl OpenedRecording {
    /// Reads every frame into memory (validated), for callers that need the whole recording.
    pub fn read_all(&self) -> Result<ChannelData, IoError> {
        let path = self.info.files.first().cloned().unwrap_or_default();
        let n = self.source.n_frames();
        let data = self
            .source
            .read_frames(0..n)
            .map_err(|source| IoError::Recording {
                path: path.clone(),
                source,
            })?;
        data.validate()
            .map_err(|source| IoError::Recording { path, source })?;
        Ok(data)
    }
}

/// A conventional plane-wave acquisition as a reader finds it in a file (SI units): one plane
/// wave per transmit event, no coding, no sampled pulse — what MUST, UFF, zea and Verasonics
/// recordings describe. [`PlaneWaveAcquisition::build`] makes it a checked [`Acquisition`].
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneWaveAcquisition {
    /// The probe.
    pub probe: Probe,
    /// Steering angles of a compound frame (rad), in transmit order.
    pub angles: Vec<f64>,
    /// Transmit-event repetition frequency (Hz).
    pub event_prf: f64,
    /// How the angles were fired and are stored: one per event, or decoded in the file.
    pub coding: Coding,
    /// Transmit pulse length (cycles of the centre frequency).
    pub pulse_cycles: f64,
    /// Sampling frequency of the samples (Hz).
    pub sampling_frequency: f64,
    /// Speed of sound (m/s).
    pub sound_speed: f64,
    /// Time of the first sample after the first element fires (s).
    pub t0: f64,
}

impl PlaneWaveAcquisition {
    /// The acquisition of the recording at `path`, checked ([`checked_acquisition`]).
    pub fn build(self, path: &Path) -> Result<Acquisition, IoError> {
        checked_acquisition(
            path,
            Acquisition {
                probe: self.probe,
                sequence: Sequence {
                    angles: self.angles,
                    event_prf: self.event_prf,
                    coding: self.coding,
                    pulse_cycles: self.pulse_cycles,
                    pulse: None,
                },
                sampling_frequency: self.sampling_frequency,
                sound_speed: self.sound_speed,
                t0: self.t0,
            },
        )
    }
}

/// `acquisition` when pcuvd accepts it ([`Acquisition::validate`]), else its refusal as an
/// [`IoError::Recording`] naming the recording at `path`.
pub fn checked_acquisition(path: &Path, acquisition: Acquisition) -> Result<Acquisition, IoError> {
    acquisition
        .validate()
        .map_err(|source| IoError::Recording {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(acquisition)
}

/// Steering angle θ (rad) of a linear transmit-delay profile d_i = d_0 + x_i·sinθ/c; refuses
/// delays that are not linear in x (focused or diverging waves).
pub fn plane_wave_angle(delays: &[f64], element_x: &[f64], c: f64) -> Result<f64, String> {
    if delays.len() != element_x.len() {
        return Err(format!(
            "has {} delays but the probe has {} elements",
            delays.len(),
            element_x.len()
        ));
    }
    if let Some(d) = delays.iter().find(|d| !d.is_finite()) {
        return Err(format!("holds a non-finite delay ({d})"));
    }
    let n = delays.len() as f64;
    if delays.len() < 2 || delays.iter().all(|&d| d == delays[0]) {
        return Ok(0.0);
    }
    let mx = element_x.iter().sum::<f64>() / n;
    let md = delays.iter().sum::<f64>() / n;
    let sxx: f64 = element_x.iter().map(|x| (x - mx).powi(2)).sum();
    let sxd: f64 = element_x
        .iter()
        .zip(delays)
        .map(|(x, d)| (x - mx) * (d - md))
        .sum();
    if sxx <= 0.0 {
        return Err("cannot be fitted: the elements all share one position".into());
    }
    let slope = sxd / sxx;
    let (lo, hi) = delays
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &d| {
            (l.min(d), h.max(d))
        });
    let residual = element_x
        .iter()
        .zip(delays)
        .map(|(x, d)| (d - (md + slope * (x - mx))).abs())
        .fold(0.0, f64::max);
    // Delays quantised by a scanner's clock stay well inside 2 % of their span.
    if residual > 0.02 * (hi - lo) + 1e-12 {
        return Err(format!(
            "is not a plane-wave delay profile (not linear across the elements: the best linear fit \
             misses by up to {:.3} µs over a span of {:.3} µs; focused and diverging waves are not supported)",
            residual * 1e6,
            (hi - lo) * 1e6
        ));
    }
    let s = c * slope;
    if s.abs() >= 1.0 {
        return Err(format!(
            "implies sin θ = {s:.3} (|sin θ| must be < 1): delays too steep for c = {c} m/s"
        ));
    }
    Ok(s.asin())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steered_delays_give_the_angle() {
        let x = Probe {
            name: String::new(),
            n_elements: 64,
            pitch: 3e-4,
            element_width: 2.5e-4,
            center_frequency: 5e6,
            bandwidth: 0.7,
        }
        .element_x();
        let theta = 7f64.to_radians();
        let c = 1540.0;
        let x0 = x[0];
        let d: Vec<f64> = x.iter().map(|xi| (xi - x0) * theta.sin() / c).collect();
        assert!((plane_wave_angle(&d, &x, c).unwrap() - theta).abs() < 1e-12);
        let neg: Vec<f64> = d.iter().map(|v| d[63] - v).collect();
        assert!((plane_wave_angle(&neg, &x, c).unwrap() + theta).abs() < 1e-12);
        // Diverging wave: delays ∝ distance from a virtual source behind the array.
        let div: Vec<f64> = x
            .iter()
            .map(|xi| (xi * xi + 0.01f64.powi(2)).sqrt() / c)
            .collect();
        let e = plane_wave_angle(&div, &x, c).unwrap_err();
        assert!(e.contains("is not a plane-wave delay profile"), "{e}");
    }
}
