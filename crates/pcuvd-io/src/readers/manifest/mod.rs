//! A pcuvd recording manifest opened through [`crate::open_recording`]: the acquisition from the
//! manifest (each parameter's source is its key), the samples from `[data].file` (`.npy`,
//! `.npz:ARRAY`, `.h5:/dataset`, `.mat:VARIABLE`) read a block of frames at a time
//! ([`frames::ManifestFrames`] for a plain `.npy` in event order, else
//! [`crate::array::ArrayFrames`]). The manifest's format itself (schema, checks, writer) is
//! [`crate::manifest`], below this reader.

pub mod frames;

use std::path::Path;

use serde_json::json;

use crate::array::{ArrayFrames, Axis};
use crate::container::{Container, read_head, sniff};
use crate::error::IoError;
use crate::params::{Overrides, ParamSource, Resolver, field};
use crate::recording::{OpenedRecording, SourceInfo, StoredSamples, checked_acquisition};
use frames::ManifestFrames;

/// Opens the manifest at `path`.
pub fn open(path: &Path, overrides: &Overrides) -> Result<OpenedRecording, IoError> {
    let parsed = crate::manifest::parse_manifest(path)?;
    let table: toml::Table = std::fs::read_to_string(path)
        .ok()
        .and_then(|t| toml::from_str(&t).ok())
        .unwrap_or_default();
    let has = |section: &str, key: &str| {
        table
            .get(section)
            .and_then(|s| s.as_table())
            .is_some_and(|s| s.contains_key(key))
    };
    let preset = table
        .get("probe")
        .and_then(|p| p.get("preset"))
        .and_then(|p| p.as_str())
        .map(str::to_string);
    let src = |section: &str, key: &str| -> ParamSource {
        if has(section, key) {
            field(format!("[{section}].{key}"))
        } else {
            match &preset {
                Some(p) => ParamSource::Default {
                    note: format!("probe preset {p:?} ([probe].preset)"),
                },
                None => field(format!("[{section}].{key}")),
            }
        }
    };
    let mut acq = parsed.acquisition.clone();
    let mut r = Resolver::new(overrides);
    acq.sampling_frequency = r.known(
        "sampling_frequency_hz",
        (
            acq.sampling_frequency,
            src("acquisition", "sampling_frequency_hz"),
        ),
    );
    acq.probe.center_frequency = r.known(
        "center_frequency_hz",
        (
            acq.probe.center_frequency,
            src("probe", "center_frequency_hz"),
        ),
    );
    r.record(
        "n_elements",
        json!(acq.probe.n_elements),
        src("probe", "n_elements"),
    );
    r.record("pitch_m", json!(acq.probe.pitch), src("probe", "pitch_m"));
    r.record(
        "element_width_m",
        json!(acq.probe.element_width),
        src("probe", "element_width_m"),
    );
    // A manifest always states it (or its preset does): the default is never taken.
    acq.probe.bandwidth = crate::recording::resolve_bandwidth(
        &mut r,
        Some((acq.probe.bandwidth, src("probe", "bandwidth"))),
        (acq.probe.bandwidth, "[probe].bandwidth"),
        acq.probe.center_frequency,
        acq.sampling_frequency,
    );
    acq.sound_speed = r.known(
        "sound_speed_m_s",
        (acq.sound_speed, src("acquisition", "sound_speed_m_s")),
    );
    acq.t0 = r.known("t0_s", (acq.t0, src("acquisition", "t0_s")));
    acq.sequence.event_prf = r.known(
        "event_prf_hz",
        (acq.sequence.event_prf, src("acquisition", "event_prf_hz")),
    );
    let cycles_source = if !has("acquisition", "pulse_cycles") && acq.sequence.pulse.is_some() {
        crate::params::derived("[acquisition.pulse] (its length in cycles of the centre frequency)")
    } else {
        src("acquisition", "pulse_cycles")
    };
    acq.sequence.pulse_cycles = r.known("pulse_cycles", (acq.sequence.pulse_cycles, cycles_source));
    let angle_key = if has("acquisition", "angles_deg") {
        "angles_deg"
    } else if has("acquisition", "angles_rad") {
        "angles_rad"
    } else {
        // Version 2: derived from the per-element delays (each row fitted to a plane wave).
        "transmit_delays_s"
    };
    let angle_source = if angle_key == "transmit_delays_s" {
        crate::params::derived("[acquisition].transmit_delays_s (each row fitted to a plane wave)")
    } else {
        field(format!("[acquisition].{angle_key}"))
    };
    acq.sequence.angles = r.angles((acq.sequence.angles.clone(), angle_source));
    r.record(
        "coding",
        json!(match acq.sequence.coding {
            pcuvd::Coding::Conventional => "none",
            pcuvd::Coding::Hadamard { .. } => "hadamard",
            pcuvd::Coding::Matrix(_) => "matrix",
            pcuvd::Coding::Decoded { .. } => "decoded",
        }),
        field("[acquisition].coding"),
    );
    if let pcuvd::Coding::Matrix(code) = &acq.sequence.coding {
        let starts_key = if has("acquisition", "transmit_delays_s") {
            "transmit_delays_s"
        } else if has("acquisition", "slot_delays_s") {
            "slot_delays_s"
        } else {
            "slot_delay_s"
        };
        r.record(
            "slot_starts_s",
            json!(code.slot_starts),
            field(format!("[acquisition].{starts_key}")),
        );
        if has("acquisition", "code_matrix") {
            r.record(
                "code_matrix",
                json!(code.weights.chunks(code.order().max(1)).collect::<Vec<_>>()),
                field("[acquisition].code_matrix"),
            );
        }
    }
    if let pcuvd::Coding::Decoded { polarity } = &acq.sequence.coding {
        let source = if has("acquisition", "polarity") {
            field("[acquisition].polarity")
        } else {
            ParamSource::Default {
                note: "[acquisition].polarity is absent: every angle +1".into(),
            }
        };
        r.record("polarity", json!(polarity), source);
    }
    if let pcuvd::Coding::Hadamard { slot_delay } = acq.sequence.coding {
        r.record(
            "slot_delay_s",
            json!(slot_delay),
            field("[acquisition].slot_delay_s"),
        );
    }
    let demod = parsed.demod.map(|f| {
        r.known(
            "demod_frequency_hz",
            (f, field("[data].demod_frequency_hz")),
        )
    });
    let acq = checked_acquisition(path, acq)?;
    let spec = crate::datafile::DataSpec {
        path: parsed.data_path.clone(),
        member: parsed.data_member.clone(),
    };
    let files = vec![path.to_path_buf(), parsed.data_path.clone()];
    let plain_npy =
        spec.member.is_none() && sniff(&read_head(&spec.path, 16)?) == Some(Container::Npy);
    let array = crate::datafile::open_data_array(&spec)?;
    let stored = StoredSamples {
        array: array.label.clone(),
        shape: array.shape.clone(),
        axes: parsed.axes.clone(),
        dtype: array.dtype_name(),
        kind: if demod.is_some() { "iq" } else { "rf" }.into(),
    };
    let mut info = SourceInfo {
        files,
        format: format!("pcuvd recording manifest (.toml) + {}", data_format(&spec)),
        reader: String::new(),
        parameters: r.params,
        stored: Some(stored),
        warnings: vec![],
        cardiac_triggers_s: parsed.cardiac_triggers_s.clone(),
    };
    if plain_npy
        && overrides.is_empty()
        && let Some(frames) = ManifestFrames::open(path)?
    {
        info.reader = "pcuvd_io::ManifestFrames (a block of frames at a time)".into();
        return Ok(OpenedRecording {
            read_pass: Some(frames.read_pass().clone()),
            source: Box::new(frames),
            info,
        });
    }
    let axes: Vec<Axis> = parsed
        .axes
        .iter()
        .map(|a| match a.as_str() {
            "frames" => Axis::Frames,
            "angles" => Axis::Angles,
            // From version 2 the events of a compound frame are named "events" beside "frames".
            "events" if parsed.axes.len() == 4 => Axis::Angles,
            "events" => Axis::Events,
            "channels" => Axis::Channels,
            _ => Axis::Samples,
        })
        .collect();
    if (array.is_complex()) != demod.is_some() {
        return Err(crate::manifest::kind_error(
            path,
            &parsed.data_path,
            demod.is_some(),
        ));
    }
    let frames = ArrayFrames::new(path, acq, array, axes, demod)?;
    info.reader = if frames.array().resident_bytes() > 0 {
        "pcuvd_io::ArrayFrames (samples held as stored, converted a block of frames at a time)"
    } else {
        "pcuvd_io::ArrayFrames (a block of frames at a time from the file)"
    }
    .into();
    Ok(OpenedRecording {
        source: Box::new(frames),
        read_pass: None,
        info,
    })
}

fn data_format(spec: &crate::datafile::DataSpec) -> String {
    let kind = match read_head(&spec.path, 8192).ok().and_then(|h| sniff(&h)) {
        Some(Container::Npy) => "NumPy .npy",
        Some(Container::Zip) => "NumPy .npz",
        Some(Container::Hdf5 { .. }) => "HDF5 dataset",
        Some(Container::MatV5) => "MATLAB v5 variable",
        _ => "samples file",
    };
    match &spec.member {
        Some(m) => format!("{kind} ({m})"),
        None => kind.to_string(),
    }
}
