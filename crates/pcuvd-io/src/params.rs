//! Acquisition parameters with where each came from (a file's field, a default, or the user), and
//! the overrides a user gives on the command line (`--t0-s`...) or in Python (`t0_s=`...).

use std::path::Path;

use serde::Serialize;

use crate::error::IoError;

/// Acquisition values the user sets, in SI units; each replaces what the file says (or fills what
/// it lacks) and is recorded as an override.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Overrides {
    /// Time of the first sample after the first element fires (s).
    pub t0_s: Option<f64>,
    /// Speed of sound (m/s).
    pub sound_speed_m_s: Option<f64>,
    /// Transmit-event repetition frequency (Hz).
    pub event_prf_hz: Option<f64>,
    /// Sampling frequency (Hz).
    pub sampling_freq_hz: Option<f64>,
    /// Probe centre frequency (Hz).
    pub center_freq_hz: Option<f64>,
    /// Demodulation frequency of IQ samples (Hz).
    pub demod_freq_hz: Option<f64>,
    /// Steering angle of each slot (rad).
    pub angles_rad: Option<Vec<f64>>,
    /// Transmit pulse length (cycles).
    pub pulse_cycles: Option<f64>,
    /// Probe's two-way −6 dB fractional bandwidth (0.6 = 60 %).
    pub bandwidth: Option<f64>,
    /// The track to read from a file of several (zea's `tracks/track_N`): its index N or its
    /// label.
    pub track: Option<String>,
}

/// Each numeric override: the parameter it replaces (as recorded in [`Parameter::name`]), its
/// command-line option and Python keyword for messages (either empty where only the other takes
/// it), and whether zero is a valid value.
const NUMERIC_OVERRIDES: [(&str, &str, &str, bool); 8] = [
    ("t0_s", "--t0-s", "t0_s", true),
    (
        "sound_speed_m_s",
        "--sound-speed-m-s",
        "sound_speed_m_s",
        false,
    ),
    ("event_prf_hz", "--event-prf-hz", "event_prf_hz", false),
    (
        "sampling_frequency_hz",
        "--sampling-freq-hz",
        "sampling_freq_hz",
        false,
    ),
    (
        "center_frequency_hz",
        "--center-freq-hz",
        "center_freq_hz",
        false,
    ),
    // IQ stored at baseband relative to 0 Hz is IQ of the analytic signal itself.
    ("demod_frequency_hz", "--demod-freq-hz", "", true),
    ("pulse_cycles", "", "pulse_cycles", false),
    ("bandwidth", "--bandwidth", "bandwidth", false),
];

/// How the user gave an override, for messages: "--t0-s (t0_s=)".
fn given_as(option: &str, keyword: &str) -> String {
    if option.is_empty() {
        format!("{keyword}=")
    } else if keyword.is_empty() {
        option.to_string()
    } else {
        format!("{option} ({keyword}=)")
    }
}

impl Overrides {
    /// True when nothing is overridden.
    pub fn is_empty(&self) -> bool {
        *self == Overrides::default()
    }

    /// The value given for parameter `name` (a [`NUMERIC_OVERRIDES`] name), if any.
    fn numeric(&self, name: &str) -> Option<f64> {
        match name {
            "t0_s" => self.t0_s,
            "sound_speed_m_s" => self.sound_speed_m_s,
            "event_prf_hz" => self.event_prf_hz,
            "sampling_frequency_hz" => self.sampling_freq_hz,
            "center_frequency_hz" => self.center_freq_hz,
            "demod_frequency_hz" => self.demod_freq_hz,
            "pulse_cycles" => self.pulse_cycles,
            "bandwidth" => self.bandwidth,
            _ => None,
        }
    }

    /// Refuses a value no recording can have (not finite, or ≤ 0 for a speed, rate, frequency,
    /// length or bandwidth, < 0 for a demodulation frequency), naming the option that gave it,
    /// before any file is read: the reader's own check would blame the file's field.
    pub fn check(&self, path: &Path) -> Result<(), IoError> {
        for (name, option, keyword, zero_allowed) in NUMERIC_OVERRIDES {
            let Some(v) = self.numeric(name) else {
                continue;
            };
            let field = given_as(option, keyword);
            let refused =
                |rule: &str| Err(IoError::invalid(path, &field, format!("{rule}, got {v}")));
            match (name, zero_allowed) {
                // A time origin may precede the firing: only a number is asked of it.
                ("t0_s", _) => {
                    if !v.is_finite() {
                        return refused("must be finite");
                    }
                }
                (_, true) => {
                    if !(v.is_finite() && v >= 0.0) {
                        return refused("must be finite and ≥ 0");
                    }
                }
                (_, false) => {
                    crate::layout::positive(path, &field, v)?;
                }
            }
        }
        if let Some(angles) = &self.angles_rad
            && let Some(bad) = angles
                .iter()
                .find(|a| !a.is_finite() || a.abs() >= std::f64::consts::FRAC_PI_2)
        {
            return Err(IoError::invalid(
                path,
                "angles_rad=",
                format!("must each be finite and within ±π/2 rad, got {bad}"),
            ));
        }
        Ok(())
    }

    /// Refuses an override the recording's reader did not apply (it records every parameter it
    /// resolves; one the recording does not have, such as the demodulation frequency of RF
    /// samples, is not there to replace): a value the user gave is never silently dropped.
    pub fn check_applied(&self, path: &Path, parameters: &[Parameter]) -> Result<(), IoError> {
        for (name, option, keyword, _) in NUMERIC_OVERRIDES {
            let Some(v) = self.numeric(name) else {
                continue;
            };
            let applied = parameters
                .iter()
                .any(|p| p.name == name && p.source == ParamSource::Override);
            if !applied {
                let why = if name == "demod_frequency_hz" {
                    "the recording holds RF samples, which pcuvd demodulates at the probe's \
                     centre frequency (--center-freq-hz sets it)"
                        .to_string()
                } else {
                    format!("this recording's reader has no parameter {name} to replace")
                };
                return Err(IoError::invalid(
                    path,
                    given_as(option, keyword),
                    format!("{v} was given but is not used: {why}"),
                ));
            }
        }
        Ok(())
    }
}

/// Where an acquisition parameter's value came from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ParamSource {
    /// A field of the file, e.g. `param.fs`, `channel_data/sampling_frequency`, `[acquisition].t0_s`.
    File {
        /// The field, as the format names it.
        field: String,
    },
    /// Derived from fields of the file, e.g. the angle from `param.TXdelay`.
    Derived {
        /// How, naming the fields.
        from: String,
    },
    /// Not in the file: pcuvd's (or the format's) default.
    Default {
        /// Why this value.
        note: String,
    },
    /// Given by the user (`--t0-s`, `t0_s=`).
    Override,
}

impl std::fmt::Display for ParamSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ParamSource::File { field } => write!(f, "{field}"),
            ParamSource::Derived { from } => write!(f, "from {from}"),
            ParamSource::Default { note } => write!(f, "default ({note})"),
            ParamSource::Override => write!(f, "given by the user"),
        }
    }
}

/// One acquisition parameter: its name (SI unit in the name), value and source.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Parameter {
    /// Name, e.g. "sampling_frequency_hz".
    pub name: String,
    /// Value (a number, a list of numbers or a word).
    pub value: serde_json::Value,
    /// Where it came from.
    pub source: ParamSource,
}

/// Collects a reader's parameters, applying the user's overrides first.
#[derive(Debug, Clone)]
pub struct Resolver<'a> {
    /// The user's overrides.
    pub overrides: &'a Overrides,
    /// Every parameter resolved so far.
    pub params: Vec<Parameter>,
}

impl<'a> Resolver<'a> {
    /// A resolver applying `overrides`.
    pub fn new(overrides: &'a Overrides) -> Self {
        Resolver {
            overrides,
            params: Vec::new(),
        }
    }

    /// Records `name` = `value` from `source`.
    pub fn record(&mut self, name: &str, value: serde_json::Value, source: ParamSource) {
        self.params.retain(|p| p.name != name);
        self.params.push(Parameter {
            name: name.to_string(),
            value,
            source,
        });
    }

    /// The override of parameter `name`, if the user gave one.
    fn override_of(&self, name: &str) -> Option<f64> {
        self.overrides.numeric(name)
    }

    /// Resolves number `name`: the user's override, else `found` (value and source), else
    /// `default` (value and note), else `missing()`, the error to give. Records the result.
    pub fn number(
        &mut self,
        name: &str,
        found: Option<(f64, ParamSource)>,
        default: Option<(f64, &str)>,
        missing: impl FnOnce() -> IoError,
    ) -> Result<f64, IoError> {
        let (value, source) = if let Some(v) = self.override_of(name) {
            (v, ParamSource::Override)
        } else if let Some(found) = found {
            found
        } else if let Some((v, note)) = default {
            (
                v,
                ParamSource::Default {
                    note: note.to_string(),
                },
            )
        } else {
            return Err(missing());
        };
        self.record(name, serde_json::json!(value), source);
        Ok(value)
    }

    /// Resolves number `name` that the file always gives: the user's override, else `found`
    /// (value and source). Records the result.
    pub fn known(&mut self, name: &str, found: (f64, ParamSource)) -> f64 {
        let (value, source) = match self.override_of(name) {
            Some(v) => (v, ParamSource::Override),
            None => found,
        };
        self.record(name, serde_json::json!(value), source);
        value
    }

    /// Resolves number `name` that has a default: the user's override, else `found` (value and
    /// source), else `default` (value and note). Records the result.
    pub fn or_default(
        &mut self,
        name: &str,
        found: Option<(f64, ParamSource)>,
        default: (f64, &str),
    ) -> f64 {
        let (value, note) = default;
        let found = found.unwrap_or_else(|| {
            (
                value,
                ParamSource::Default {
                    note: note.to_string(),
                },
            )
        });
        self.known(name, found)
    }

    /// Resolves the steering angles: the user's, else `found` (rad). Records them in degrees.
    pub fn angles(&mut self, found: (Vec<f64>, ParamSource)) -> Vec<f64> {
        let (angles, source) = match &self.overrides.angles_rad {
            Some(a) => (a.clone(), ParamSource::Override),
            None => found,
        };
        let deg: Vec<f64> = angles.iter().map(|a| a.to_degrees()).collect();
        self.record("angles_deg", serde_json::json!(deg), source);
        angles
    }
}

/// A field of the file, as a parameter source.
pub fn field(name: impl Into<String>) -> ParamSource {
    ParamSource::File { field: name.into() }
}

/// A value derived from fields of the file, as a parameter source.
pub fn derived(from: impl Into<String>) -> ParamSource {
    ParamSource::Derived { from: from.into() }
}

/// The error for a t0 that the file does not hold: it names the field, what a wrong t0 does to the
/// image and how to give it.
pub fn missing_t0(path: &Path, field: &str) -> IoError {
    IoError::invalid(
        path,
        field,
        "is absent: pcuvd needs the time of the first sample after the first element fires (t0); \
         taking 0 instead would move the image by c·Δt/2 (0.77 mm per µs at 1540 m/s). Give it \
         with --t0-s SECONDS (pcuvd process / pcuvd info), t0_s= (Python read_recording) or \
         [acquisition].t0_s in a manifest",
    )
}

/// The error for an event PRF that the file does not hold.
pub fn missing_prf(path: &Path, field: &str) -> IoError {
    underivable_prf(path, field, "is absent")
}

/// The error for an event PRF that `field` cannot give, `why` saying what it holds instead.
pub fn underivable_prf(path: &Path, field: &str, why: &str) -> IoError {
    IoError::invalid(
        path,
        field,
        format!(
            "{why}: pcuvd needs the transmit-event repetition frequency (every Doppler velocity \
             scales with it). Give it with --event-prf-hz HZ (pcuvd process / pcuvd info), \
             event_prf_hz= (Python read_recording) or [acquisition].event_prf_hz in a manifest"
        ),
    )
}
