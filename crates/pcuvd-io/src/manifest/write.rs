//! Writing a recording: its samples as `.npy` and its manifest, in version 1 whenever version 1
//! can say the acquisition (so such files stay as they were), else version 2; floats written so
//! that they read back bit for bit.

use std::path::{Path, PathBuf};

use ndarray::Array4;
use pcuvd::{Acquisition, ChannelData, Coding, Probe, Samples};

use super::FORMAT;
use super::axes::canonical_axes;
use crate::error::IoError;
use crate::npy::write_npy;

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
    write_manifest(
        &manifest_path,
        acq,
        &npy_name,
        &kind_lines,
        None,
        provenance,
    )?;
    Ok(manifest_path)
}

/// The `[data]` kind lines of an RF recording.
pub(super) const RF_KIND: &str = "kind = \"rf\"\n";

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
        (Coding::Matrix(_), _) | (_, Some(_)) => 2,
        _ => 1,
    }
}

/// Writes the manifest of a recording acquired as `acq` whose samples are `npy_name`
/// (frames, angles, channels, samples) of `kind_lines`, atomically.
pub(super) fn write_manifest(
    manifest_path: &Path,
    acq: &Acquisition,
    npy_name: &str,
    kind_lines: &str,
    cardiac_triggers_s: Option<&[f64]>,
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
    if let Some(times) = cardiac_triggers_s {
        t.push_str("\n[cardiac]\n");
        t.push_str(&format!("triggers_s = [{}]\n", list(times)));
    }
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
