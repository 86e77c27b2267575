//! The probe and the acquisition a manifest's `[probe]` and `[acquisition]` tables describe, every
//! key checked against its range; each error names the key (version 2's per-element delays
//! fitted to plane waves, explicit code matrices, slot starts and sampled pulses included).

use std::path::Path;

use pcuvd::{Acquisition, Coding, Hadamard, Probe, Sequence, TransmitCode, TransmitPulse};

use super::schema::{AcquisitionSection, ProbeSection};
use crate::error::IoError;

/// The probe a manifest's `[probe]` table `ps` describes: a preset, keys, or a preset whose keys
/// the table overrides (each error names its key).
pub(super) fn probe_of(path: &Path, ps: &ProbeSection) -> Result<Probe, IoError> {
    let miss = |key: &str| IoError::missing(path, "table [probe]", format!("key '{key}'"));
    let preset = match &ps.preset {
        Some(name) => Some(Probe::preset(name).map_err(|e| {
            IoError::invalid(path, "[probe].preset", format!("is not usable: {e}"))
        })?),
        None => None,
    };
    let pick_f = |v: Option<f64>, key: &str, from: fn(&Probe) -> f64| -> Result<f64, IoError> {
        v.or(preset.as_ref().map(from)).ok_or_else(|| miss(key))
    };
    Ok(Probe {
        name: ps
            .name
            .clone()
            .or(preset.as_ref().map(|p| p.name.clone()))
            .unwrap_or_else(|| "custom".into()),
        n_elements: ps
            .n_elements
            .or(preset.as_ref().map(|p| p.n_elements))
            .ok_or_else(|| miss("n_elements"))?,
        pitch: pick_f(ps.pitch_m, "pitch_m", |p| p.pitch)?,
        element_width: pick_f(ps.element_width_m, "element_width_m", |p| p.element_width)?,
        center_frequency: pick_f(ps.center_frequency_hz, "center_frequency_hz", |p| {
            p.center_frequency
        })?,
        bandwidth: pick_f(ps.bandwidth, "bandwidth", |p| p.bandwidth)?,
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
fn version_two_keys(acq: &AcquisitionSection) -> [(&'static str, bool); 6] {
    [
        ("[acquisition].slot_delays_s", acq.slot_delays_s.is_some()),
        ("[acquisition].polarity", acq.polarity.is_some()),
        ("[acquisition].code_matrix", acq.code_matrix.is_some()),
        (
            "[acquisition].transmit_delays_s",
            acq.transmit_delays_s.is_some(),
        ),
        ("[acquisition.pulse]", acq.pulse.is_some()),
        (
            "[acquisition].coding",
            matches!(acq.coding.as_deref(), Some("matrix" | "decoded")),
        ),
    ]
}

/// The acquisition a manifest of `version` describes with its `[acquisition]` table `acq` and
/// `probe`, every key checked (each error names its key).
pub(super) fn acquisition_of(
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
            format!("= {:?} is", acq.coding.as_deref().unwrap_or_default())
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
    pcuvd::core::error::require_range(
        "speed of sound",
        c,
        pcuvd::acquisition::channel::SOUND_SPEED_RANGE,
        "m/s",
    )
    .map_err(refuse)?;

    // Per-element transmit delays: one plane wave per slot, or an error.
    let tolerance = pcuvd::core::geometry::PLANE_WAVE_TOLERANCE_PERIODS / probe.center_frequency;
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
                let mut wave = pcuvd::core::geometry::plane_wave_from_delays(
                    row, &xs, c, tolerance,
                )
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
    if acq.polarity.is_some() && acq.coding.as_deref() != Some("decoded") {
        return Err(only_with("polarity", "decoded"));
    }
    let coding = match acq.coding.as_deref() {
        None => return Err(miss("coding")),
        Some("decoded") => {
            if let Some(k) = [
                ("slot_delay_s", acq.slot_delay_s.is_some()),
                ("slot_delays_s", acq.slot_delays_s.is_some()),
                ("code_matrix", acq.code_matrix.is_some()),
            ]
            .into_iter()
            .find_map(|(k, used)| used.then_some(k))
            {
                return Err(IoError::invalid(
                    path,
                    key(k),
                    "means nothing with coding = \"decoded\": the records are already decoded, \
                     one per angle",
                ));
            }
            if listed
                .as_ref()
                .is_some_and(|starts| starts.iter().any(|&t| t != 0.0))
            {
                return Err(IoError::invalid(
                    path,
                    key("transmit_delays_s"),
                    "start their slots at different times, which decoded records (each \
                     advanced to its own slot's firing) cannot have",
                ));
            }
            Coding::Decoded {
                polarity: acq.polarity.clone().unwrap_or_else(|| vec![1.0; n]),
            }
        }
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
                "\"none\", \"hadamard\", \"matrix\" or \"decoded\""
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
