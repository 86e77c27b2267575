//! Writing a recording: its samples as `.npy` and its manifest, in version 1 whenever version 1
//! can say the acquisition (so readers of version 1 read such files as before), else version 2;
//! floats written so that they read back bit for bit.

use std::path::{Path, PathBuf};

use ndarray::Array4;
use pcuvd::{Acquisition, ChannelData, Coding, Probe, Samples};

use serde::Serialize;

use super::FORMAT;
use super::axes::canonical_axes;
use super::schema::{AcquisitionSection, CardiacSection, DataSection, ProbeSection, PulseSection};
use crate::error::IoError;
use crate::npy::write_npy;

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
    let demod_frequency = match &data.samples {
        Samples::Rf(a) => {
            let a4 = Array4::from_shape_vec(shape4, a.iter().copied().collect())
                .map_err(|e| IoError::invalid(&npy_path, "the samples", e.to_string()))?;
            write_npy(&npy_path, &a4)?;
            None
        }
        Samples::Iq {
            data: a,
            demod_frequency,
        } => {
            let a4 = Array4::from_shape_vec(shape4, a.iter().copied().collect())
                .map_err(|e| IoError::invalid(&npy_path, "the samples", e.to_string()))?;
            write_npy(&npy_path, &a4)?;
            Some(*demod_frequency)
        }
    };
    write_manifest(
        &manifest_path,
        acq,
        &npy_name,
        demod_frequency,
        None,
        provenance,
    )?;
    Ok(manifest_path)
}

/// The manifest, samples file name and samples path of recording `stem` in `dir`, or an error
/// when `stem` is not a plain file name.
pub(super) fn recording_paths(
    dir: &Path,
    stem: &str,
) -> Result<(PathBuf, String, PathBuf), IoError> {
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
pub(super) fn prepare_recording(dir: &Path, manifest_path: &Path) -> Result<(), IoError> {
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
        (Coding::Matrix(_) | Coding::Decoded { .. }, _) | (_, Some(_)) => 2,
        _ => 1,
    }
}

/// A whole manifest as it is written: the tables [`super::schema`] reads, in that order.
#[derive(Serialize)]
struct ManifestOut<'a> {
    format: &'static str,
    version: i64,
    probe: ProbeSection,
    acquisition: AcquisitionSection,
    data: DataSection,
    cardiac: Option<CardiacSection>,
    #[serde(skip_serializing_if = "toml::Table::is_empty")]
    provenance: &'a toml::Table,
}

/// Writes the manifest of a recording acquired as `acq` whose samples are `npy_name` (frames,
/// angles, channels, samples): RF, or IQ demodulated at `demod_frequency` (Hz); atomically.
pub(super) fn write_manifest(
    manifest_path: &Path,
    acq: &Acquisition,
    npy_name: &str,
    demod_frequency: Option<f64>,
    cardiac_triggers_s: Option<&[f64]>,
    provenance: &toml::Table,
) -> Result<(), IoError> {
    let p = &acq.probe;
    let version = version_needed(acq);
    let sequence = &acq.sequence;
    let (coding, slot_delay_s, code_matrix, slot_delays_s) = match &sequence.coding {
        Coding::Conventional => ("none", None, None, None),
        Coding::Hadamard { slot_delay } => ("hadamard", Some(*slot_delay), None, None),
        Coding::Matrix(code) => (
            "matrix",
            None,
            Some(
                code.weights
                    .chunks(code.order().max(1))
                    .map(<[f64]>::to_vec)
                    .collect(),
            ),
            Some(code.slot_starts.clone()),
        ),
        Coding::Decoded { .. } => ("decoded", None, None, None),
    };
    let polarity = match &sequence.coding {
        Coding::Decoded { polarity } => Some(polarity.clone()),
        _ => None,
    };
    let manifest = ManifestOut {
        format: FORMAT,
        version,
        probe: ProbeSection {
            preset: Probe::preset(&p.name)
                .is_ok_and(|q| q.name == p.name)
                .then(|| p.name.clone()),
            name: Some(p.name.clone()),
            n_elements: Some(p.n_elements),
            pitch_m: Some(p.pitch),
            element_width_m: Some(p.element_width),
            center_frequency_hz: Some(p.center_frequency),
            bandwidth: Some(p.bandwidth),
        },
        acquisition: AcquisitionSection {
            sampling_frequency_hz: Some(acq.sampling_frequency),
            sound_speed_m_s: Some(acq.sound_speed),
            t0_s: Some(acq.t0),
            event_prf_hz: Some(sequence.event_prf),
            angles_rad: Some(sequence.angles.clone()),
            pulse_cycles: Some(sequence.pulse_cycles),
            coding: Some(coding.to_string()),
            slot_delay_s,
            slot_delays_s,
            code_matrix,
            polarity,
            pulse: sequence.pulse.as_ref().map(|pulse| PulseSection {
                sampling_frequency_hz: Some(pulse.sampling_frequency),
                samples: Some(pulse.samples.clone()),
            }),
            ..AcquisitionSection::default()
        },
        data: DataSection {
            file: Some(npy_name.to_string()),
            kind: Some(
                if demod_frequency.is_some() {
                    "iq"
                } else {
                    "rf"
                }
                .to_string(),
            ),
            axes: Some(
                canonical_axes(4, version)
                    .iter()
                    .map(|axis| axis.to_string())
                    .collect(),
            ),
            demod_frequency_hz: demod_frequency,
        },
        cardiac: cardiac_triggers_s.map(|times| CardiacSection {
            triggers_s: Some(times.to_vec()),
            triggers_file: None,
        }),
        provenance,
    };
    let tables = toml::to_string(&manifest).map_err(|e| {
        IoError::invalid(
            manifest_path,
            "the manifest",
            format!("cannot be written ({e})"),
        )
    })?;
    let degrees: Vec<String> = sequence
        .angles
        .iter()
        .map(|a| format!("{:.4}", a.to_degrees()))
        .collect();
    let mut text = format!(
        "# pcuvd recording manifest (SI units; the unit is in each key's name).\n\
         # bandwidth: the two-way -6 dB fractional bandwidth.\n\
         # angles_rad in degrees: [{}]\n",
        degrees.join(", ")
    );
    if matches!(sequence.coding, Coding::Matrix(_)) {
        text.push_str(
            "# code_matrix row i: the weight of each slot (angle) in event i of a compound frame.\n",
        );
    }
    text.push_str(&tables);
    crate::npy::write_atomically(manifest_path, |partial| {
        std::fs::write(partial, text).map_err(|e| IoError::io(manifest_path, "write", e))
    })
}
