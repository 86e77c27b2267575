//! The manifest's TOML tables as serde reads and writes them: every key optional, unknown keys
//! refused, so that the checks in [`super::read`] and [`super::acquisition`] can name what is
//! missing or wrong; [`super::write`] fills the same tables (an absent key is not written).

use serde::{Deserialize, Serialize};

/// A manifest as its TOML reads, every key optional (the checks name what is missing).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ManifestFile {
    #[serde(rename = "format")]
    pub(super) _format: serde::de::IgnoredAny,
    #[serde(rename = "version")]
    pub(super) _version: serde::de::IgnoredAny,
    pub(super) probe: Option<ProbeSection>,
    pub(super) acquisition: Option<AcquisitionSection>,
    pub(super) data: Option<DataSection>,
    pub(super) cardiac: Option<CardiacSection>,
    #[serde(default)]
    pub(super) provenance: toml::Table,
}

pub(super) use crate::cardiac::CardiacSection;

/// `[probe]`: a preset, or the probe's own keys (which override the preset's).
#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ProbeSection {
    pub(super) preset: Option<String>,
    pub(super) name: Option<String>,
    pub(super) n_elements: Option<usize>,
    pub(super) pitch_m: Option<f64>,
    pub(super) element_width_m: Option<f64>,
    pub(super) center_frequency_hz: Option<f64>,
    pub(super) bandwidth: Option<f64>,
}

/// `[acquisition]`: the transmit sequence and the sampling.
#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AcquisitionSection {
    pub(super) sampling_frequency_hz: Option<f64>,
    pub(super) sound_speed_m_s: Option<f64>,
    pub(super) t0_s: Option<f64>,
    pub(super) event_prf_hz: Option<f64>,
    pub(super) angles_deg: Option<Vec<f64>>,
    pub(super) angles_rad: Option<Vec<f64>>,
    pub(super) pulse_cycles: Option<f64>,
    pub(super) coding: Option<String>,
    pub(super) slot_delay_s: Option<f64>,
    // Version 2 only.
    pub(super) slot_delays_s: Option<Vec<f64>>,
    pub(super) code_matrix: Option<Vec<Vec<f64>>>,
    pub(super) transmit_delays_s: Option<Vec<Vec<f64>>>,
    pub(super) polarity: Option<Vec<f64>>,
    pub(super) pulse: Option<PulseSection>,
}

/// `[acquisition.pulse]` (version 2): the transmit pulse as samples.
#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct PulseSection {
    pub(super) sampling_frequency_hz: Option<f64>,
    pub(super) samples: Option<Vec<f64>>,
}

/// `[data]`: the samples file, their kind and the order of their axes.
#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub(super) struct DataSection {
    pub(super) file: Option<String>,
    pub(super) kind: Option<String>,
    pub(super) axes: Option<Vec<String>>,
    pub(super) demod_frequency_hz: Option<f64>,
}
