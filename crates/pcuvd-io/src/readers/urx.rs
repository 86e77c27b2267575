//! URX (Moduleus' ultrasound raw data exchange, HDF5): `dataset/acquisition` holds `probes`,
//! `excitations`, `groups` (each a `sequence` of events: a transmit setup and a receive setup) and
//! `groups_data` (each a recorded execution of a group: `raw_data`, `sequence_timestamps`,
//! `event_timestamps`). Lists are groups of members named by their 8-digit index; a reference to a
//! list's item is its index.
//!
//! pcuvd reads one recorded group (the first, or the one `--track` names by index or by its
//! group's description) whose events each transmit one plane wave with a flat linear array and
//! receive on its elements in order. `raw_data` is one row per sample (two columns, the real and
//! imaginary parts, for IQ), addressed sequence, event, channel, sample (URX's
//! `GroupDataReader::offset`): a sequence is a compound frame, its events the angles.
//!
//! Time: a plane wave's `wave/parameters` is its direction (sin θ, 0, cos θ), and `wave/time_zero`
//! the instant its pulse's centre crosses `wave/time_zero_reference_point`, after the transmit's
//! start (the event's start plus the transmit's `time_offset`); the receive setup's
//! `time_offset` is the first sample's time after the event's start. pcuvd's t0 counts from the
//! first element's firing, its pulse centred there: the wave crosses that element
//! d·(r − e)/c before the reference point r (d its direction), so
//! t0 = rx time_offset − (tx time_offset + time_zero − max_e d·(r − e)/c) over the transmit's
//! active elements e. The `delays` (each element's excitation start) are only checked to steer
//! the angle the direction gives. The event PRF is the events per sequence over the median
//! interval between sequences, from `event_timestamps` ([`frame_timing`]).

use std::path::Path;

use serde_json::json;

use crate::array::{ArrayFrames, Axis, Backing, StoredArray};
use crate::error::IoError;
use crate::hdf5::Hdf5;
use crate::layout::{common_t0, frame_timing, linear_array, positive, scalar};
use crate::params::{
    Overrides, ParamSource, Resolver, derived, field, missing_prf, missing_t0, underivable_prf,
};
use crate::recording::{
    DEFAULT_BANDWIDTH, DEFAULT_PULSE_CYCLES, OpenedRecording, PlaneWaveAcquisition, SourceInfo,
    StoredSamples, resolve_bandwidth,
};

/// The group every URX file's acquisition lies in.
pub const ACQUISITION: &str = "dataset/acquisition";

/// The members of list `group` (named by their index), in index order.
fn list(h5: &Hdf5, group: &str) -> Result<Vec<String>, IoError> {
    if !h5.is_group(group) {
        return Ok(Vec::new());
    }
    let mut names = h5.members(group)?;
    names.sort_by_key(|m| m.parse::<u64>().unwrap_or(u64::MAX));
    Ok(names.into_iter().map(|m| format!("{group}/{m}")).collect())
}

/// The item of list `group` that the index stored at `reference` names.
fn item(h5: &Hdf5, group: &str, reference: &str) -> Result<String, IoError> {
    let index = scalar(h5, reference)?
        .ok_or_else(|| IoError::missing(&h5.path, reference, "the index it refers by"))?;
    let items = list(h5, group)?;
    let k = index as usize;
    if index < 0.0 || index.fract() != 0.0 || k >= items.len() {
        return Err(IoError::invalid(
            &h5.path,
            reference,
            format!(
                "refers to item {index} of {group}, which holds {}",
                items.len()
            ),
        ));
    }
    Ok(items[k].clone())
}

/// The string at `path`, if it is a string dataset.
fn string(h5: &Hdf5, path: &str) -> Option<String> {
    h5.dataset(path)
        .ok()
        .and_then(|d| crate::hdf5::guard(&h5.path, path, || d.read_strings()).ok())
        .and_then(|v| v.into_iter().next())
}

/// A number that must be present (NaN counts as absent, as URX writes unset values).
fn number(h5: &Hdf5, path: &str) -> Result<Option<f64>, IoError> {
    Ok(scalar(h5, path)?.filter(|v| !v.is_nan()))
}

/// The (x, y, z) of a URX 3-D vector group.
fn vector(h5: &Hdf5, group: &str) -> Result<[f64; 3], IoError> {
    let mut v = [0.0; 3];
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        v[k] = number(h5, &format!("{group}/{axis}"))?.unwrap_or(0.0);
    }
    Ok(v)
}

/// Refuses a probe transform other than the identity: pcuvd's probe lies on the x axis.
fn untransformed(h5: &Hdf5, transform: &str) -> Result<(), IoError> {
    if !h5.is_group(transform) {
        return Ok(());
    }
    let moved = vector(h5, &format!("{transform}/rotation"))?
        .into_iter()
        .chain(vector(h5, &format!("{transform}/translation"))?)
        .any(|v| v != 0.0);
    if moved {
        return Err(IoError::invalid(
            &h5.path,
            transform,
            "rotates or moves the probe: pcuvd reads a probe at the origin, its elements along x",
        ));
    }
    Ok(())
}

/// `v` as a count or index: a finite, non-negative whole number.
fn whole(v: f64) -> Option<usize> {
    (v.is_finite() && v >= 0.0 && v.fract() == 0.0 && v <= u32::MAX as f64).then_some(v as usize)
}

/// The element indices of an `active_elements` list (one list per channel or excitation).
fn active(h5: &Hdf5, group: &str) -> Result<Vec<Vec<usize>>, IoError> {
    list(h5, group)?
        .iter()
        .map(|m| {
            let (_, v) = h5.read_f64(m)?;
            v.into_iter()
                .map(|i| {
                    whole(i).ok_or_else(|| {
                        IoError::invalid(&h5.path, m, format!("holds {i}, not an element index"))
                    })
                })
                .collect()
        })
        .collect()
}

/// The probe's element centres (x, y, z; m), in element order.
fn element_positions(h5: &Hdf5, probe: &str) -> Result<Vec<[f64; 3]>, IoError> {
    list(h5, &format!("{probe}/elements"))?
        .iter()
        .map(|e| {
            untransformed_rotation(h5, &format!("{e}/transform/rotation"))?;
            vector(h5, &format!("{e}/transform/translation"))
        })
        .collect()
}

/// Refuses a rotated element (pcuvd's elements face +z).
fn untransformed_rotation(h5: &Hdf5, rotation: &str) -> Result<(), IoError> {
    if h5.is_group(rotation) && vector(h5, rotation)?.iter().any(|&v| v != 0.0) {
        return Err(IoError::invalid(
            &h5.path,
            rotation,
            "rotates an element: pcuvd reads a flat linear array whose elements face +z",
        ));
    }
    Ok(())
}

/// One event's plane wave and timing.
struct Event {
    /// Steering angle (rad).
    angle: f64,
    /// Time of the first sample after the first element fires (s); `None` when the file leaves
    /// out a time it needs.
    t0: Option<f64>,
    sampling_frequency: f64,
    samples: usize,
    /// 0 for RF.
    modulation: f64,
    /// The excitations it fires (their groups).
    excitations: Vec<String>,
}

/// Reads event `ev`, which must transmit and receive with `probe`, whose element centres are
/// `elements`, in a medium of sound speed `c` (m/s).
fn event(
    h5: &Hdf5,
    ev: &str,
    probe: &str,
    elements: &[[f64; 3]],
    c: f64,
) -> Result<Event, IoError> {
    let path = &h5.path;
    let tx = format!("{ev}/transmit_setup");
    let rx = format!("{ev}/receive_setup");
    let probes = format!("{ACQUISITION}/probes");
    for setup in [&tx, &rx] {
        if item(h5, &probes, &format!("{setup}/probe"))? != probe {
            return Err(IoError::invalid(
                path,
                format!("{setup}/probe"),
                "differs from the first event's transmitting probe: pcuvd reads one probe",
            ));
        }
        untransformed(h5, &format!("{setup}/probe_transform"))?;
    }
    let kind = string(h5, &format!("{tx}/wave/type")).unwrap_or_default();
    if kind != "PLANE_WAVE" {
        return Err(IoError::invalid(
            path,
            format!("{tx}/wave/type"),
            format!("is {kind:?}: pcuvd reads plane-wave events (PLANE_WAVE)"),
        ));
    }
    let parameters = format!("{tx}/wave/parameters");
    let (_, direction) = h5.read_f64(&parameters)?;
    let [sx, sy, sz] = direction[..] else {
        return Err(IoError::invalid(
            path,
            &parameters,
            format!(
                "holds {} values; a plane wave's are its direction (x, y, z)",
                direction.len()
            ),
        ));
    };
    let norm = (sx * sx + sy * sy + sz * sz).sqrt();
    if !(norm > 0.0 && sz > 0.0 && sy.abs() <= 1e-6 * norm) {
        return Err(IoError::invalid(
            path,
            &parameters,
            format!(
                "is the direction ({sx}, {sy}, {sz}): pcuvd reads plane waves steered in the \
                 x-z plane, travelling into the medium (z > 0)"
            ),
        ));
    }
    let angle = sx.atan2(sz);
    let (dx, dz) = (sx / norm, sz / norm);
    // The transmit's active elements (one list per excitation), with a delay each.
    let firing: Vec<usize> = active(h5, &format!("{tx}/active_elements"))?
        .into_iter()
        .flatten()
        .collect();
    if firing.is_empty() || firing.iter().any(|&i| i >= elements.len()) {
        return Err(IoError::invalid(
            path,
            format!("{tx}/active_elements"),
            format!("must name elements of the probe's {}", elements.len()),
        ));
    }
    let reference = vector(h5, &format!("{tx}/wave/time_zero_reference_point"))?;
    let time_zero = number(h5, &format!("{tx}/wave/time_zero"))?;
    let tx_offset = number(h5, &format!("{tx}/time_offset"))?.unwrap_or(0.0);
    let rx_offset = number(h5, &format!("{rx}/time_offset"))?;
    // From the first element's firing to the wave's crossing of the reference point.
    let lead = firing
        .iter()
        .map(|&i| (dx * (reference[0] - elements[i][0]) + dz * (reference[2] - elements[i][2])) / c)
        .fold(f64::NEG_INFINITY, f64::max);
    let t0 = time_zero
        .zip(rx_offset)
        .map(|(time_zero, rx_offset)| rx_offset - (tx_offset + time_zero - lead));
    // The delays must steer the direction's angle: their slope along x is sin θ / c.
    let (_, delays) = h5.read_f64(&format!("{tx}/delays"))?;
    if delays.len() == firing.len() && firing.len() >= 2 {
        let x: Vec<f64> = firing.iter().map(|&i| elements[i][0]).collect();
        let n = x.len() as f64;
        let (mx, md) = (x.iter().sum::<f64>() / n, delays.iter().sum::<f64>() / n);
        let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
        let sxd: f64 = x
            .iter()
            .zip(&delays)
            .map(|(v, d)| (v - mx) * (d - md))
            .sum();
        let steered = (c * sxd / sxx).clamp(-1.0, 1.0).asin();
        if (steered - angle).abs() > 1e-3 {
            return Err(IoError::invalid(
                path,
                format!("{tx}/delays"),
                format!(
                    "steer {:.3}° but wave/parameters say {:.3}°: pcuvd needs the two to agree",
                    steered.to_degrees(),
                    angle.to_degrees()
                ),
            ));
        }
    }
    let channels = active(h5, &format!("{rx}/active_elements"))?;
    let in_order = channels.iter().enumerate().all(|(k, c)| c == &[k]);
    if !in_order || channels.len() != elements.len() {
        return Err(IoError::invalid(
            path,
            format!("{rx}/active_elements"),
            format!(
                "maps its {} channels to elements otherwise than channel k to element k of the \
                 probe's {}: pcuvd reads every element, in order",
                channels.len(),
                elements.len()
            ),
        ));
    }
    let excitations = list(h5, &format!("{tx}/excitations"))?
        .iter()
        .map(|m| item(h5, &format!("{ACQUISITION}/excitations"), m))
        .collect::<Result<_, _>>()?;
    let sampling_frequency = number(h5, &format!("{rx}/sampling_frequency"))?
        .ok_or_else(|| IoError::missing(path, &rx, "dataset 'sampling_frequency'"))?;
    let number_samples = format!("{rx}/number_samples");
    let samples = scalar(h5, &number_samples)?
        .ok_or_else(|| IoError::missing(path, &rx, "dataset 'number_samples'"))?;
    let samples = whole(samples).filter(|&n| n > 0).ok_or_else(|| {
        IoError::invalid(
            path,
            &number_samples,
            format!("is {samples}: a receive records a whole number of samples, at least one"),
        )
    })?;
    Ok(Event {
        angle,
        t0,
        sampling_frequency,
        samples,
        modulation: number(h5, &format!("{rx}/modulation_frequency"))?.unwrap_or(0.0),
        excitations,
    })
}

/// The recorded group to read: the one `track` names (its index among `groups_data`, or its
/// group's description), else the first; with the parameter's source and a warning when the file
/// holds others.
fn chosen_group_data(
    h5: &Hdf5,
    track: Option<&str>,
) -> Result<(String, ParamSource, Option<String>), IoError> {
    let recorded = list(h5, &format!("{ACQUISITION}/groups_data"))?;
    if recorded.is_empty() {
        return Err(IoError::invalid(
            &h5.path,
            format!("{ACQUISITION}/groups_data"),
            "holds no recorded group: the file describes an acquisition but no samples",
        ));
    }
    let description = |gd: &str| -> String {
        item(h5, &format!("{ACQUISITION}/groups"), &format!("{gd}/group"))
            .ok()
            .and_then(|g| string(h5, &format!("{g}/description")))
            .unwrap_or_default()
    };
    let labels: Vec<String> = recorded
        .iter()
        .enumerate()
        .map(|(k, gd)| format!("{k} ({:?})", description(gd)))
        .collect();
    match track {
        Some(wanted) => {
            let k = match wanted.trim().parse::<usize>() {
                Ok(k) if k < recorded.len() => Some(k),
                _ => recorded
                    .iter()
                    .position(|gd| description(gd) == wanted.trim()),
            };
            let k = k.ok_or_else(|| {
                IoError::invalid(
                    &h5.path,
                    format!("{ACQUISITION}/groups_data"),
                    format!(
                        "holds no recorded group {wanted:?}: give --track one of {}",
                        labels.join(", ")
                    ),
                )
            })?;
            Ok((recorded[k].clone(), ParamSource::Override, None))
        }
        None => {
            let warning = (recorded.len() > 1).then(|| {
                format!(
                    "the file holds {} recorded groups, {}: pcuvd read the first; --track (index \
                     or description) picks another",
                    recorded.len(),
                    labels.join(", ")
                )
            });
            Ok((
                recorded[0].clone(),
                ParamSource::Default {
                    note: "the first of the file's recorded groups".into(),
                },
                warning,
            ))
        }
    }
}

/// Opens a URX file's recorded plane-wave group.
pub fn open(path: &Path, h5: &Hdf5, overrides: &Overrides) -> Result<OpenedRecording, IoError> {
    let mut r = Resolver::new(overrides);
    let mut warnings = Vec::new();
    let (gd, gd_source, warning) = chosen_group_data(h5, overrides.track.as_deref())?;
    warnings.extend(warning);
    r.record(
        "track",
        json!(gd.rsplit('/').next().and_then(|m| m.parse::<u64>().ok())),
        gd_source,
    );
    let group = item(h5, &format!("{ACQUISITION}/groups"), &format!("{gd}/group"))?;
    let events = list(h5, &format!("{group}/sequence"))?;
    if events.is_empty() {
        return Err(IoError::invalid(
            path,
            format!("{group}/sequence"),
            "holds no event",
        ));
    }
    let c = r.number(
        "sound_speed_m_s",
        number(h5, &format!("{group}/sound_speed"))?
            .map(|v| (v, field(format!("{group}/sound_speed")))),
        None,
        || IoError::missing(path, &group, "dataset 'sound_speed'"),
    )?;
    let c = positive(path, &format!("{group}/sound_speed"), c)?;

    // The probe, as the first event's transmit names it.
    let probe = item(
        h5,
        &format!("{ACQUISITION}/probes"),
        &format!("{}/transmit_setup/probe", events[0]),
    )?;
    let positions = element_positions(h5, &probe)?;
    let x: Vec<f64> = positions.iter().map(|p| p[0]).collect();
    let off: Vec<f64> = positions.iter().flat_map(|p| [p[1], p[2]]).collect();
    let elements_field = format!("{probe}/elements");
    let (n, pitch) = linear_array(path, &elements_field, &x, &off)?;
    r.record(
        "n_elements",
        json!(n),
        derived(format!("{elements_field} (their count)")),
    );
    r.record(
        "pitch_m",
        json!(pitch),
        derived(format!(
            "{elements_field}/*/transform/translation (x spacing)"
        )),
    );
    let geometry = item(
        h5,
        &format!("{probe}/element_geometries"),
        &format!("{elements_field}/00000000/element_geometry"),
    )
    .ok();
    let perimeter_width = match &geometry {
        Some(g) => {
            let corners: Vec<f64> = list(h5, &format!("{g}/perimeter"))?
                .iter()
                .map(|v| vector(h5, v).map(|p| p[0]))
                .collect::<Result<_, _>>()?;
            let (lo, hi) = corners
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
                    (l.min(v), h.max(v))
                });
            (hi > lo).then_some(hi - lo)
        }
        None => None,
    };
    let width = match perimeter_width {
        Some(w) => {
            r.record(
                "element_width_m",
                json!(w),
                derived(format!(
                    "{}/perimeter (x extent)",
                    geometry.as_deref().unwrap_or_default()
                )),
            );
            w
        }
        None => {
            r.record(
                "element_width_m",
                json!(pitch),
                ParamSource::Default {
                    note: "the pitch: the element geometry has no perimeter".into(),
                },
            );
            pitch
        }
    };

    let read: Vec<Event> = events
        .iter()
        .map(|ev| event(h5, ev, &probe, &positions, c))
        .collect::<Result<_, _>>()?;
    let first = &read[0];
    for (ev, e) in events.iter().zip(&read) {
        let differs = |what: &str| {
            IoError::invalid(
                path,
                format!("{ev}/receive_setup/{what}"),
                format!("differs from the first event's: pcuvd needs one {what} for the recording"),
            )
        };
        if e.sampling_frequency != first.sampling_frequency {
            return Err(differs("sampling_frequency"));
        }
        if e.samples != first.samples {
            return Err(differs("number_samples"));
        }
        if e.modulation != first.modulation {
            return Err(differs("modulation_frequency"));
        }
    }
    let fs = r.known(
        "sampling_frequency_hz",
        (
            first.sampling_frequency,
            field(format!("{}/receive_setup/sampling_frequency", events[0])),
        ),
    );
    let fs = positive(path, "receive_setup/sampling_frequency", fs)?;
    let timing = format!("{group}/sequence/*: receive and transmit time_offset, wave/time_zero");
    let t0_found = match read.iter().map(|e| e.t0).collect::<Option<Vec<f64>>>() {
        Some(t0s) => Some((
            common_t0(path, &timing, &t0s, fs)?,
            derived(
                "receive_setup/time_offset − transmit_setup/time_offset − wave/time_zero + the \
                 time from the first element's firing to the wave's crossing of \
                 wave/time_zero_reference_point",
            ),
        )),
        None => None,
    };
    let t0 = r.number("t0_s", t0_found, None, || {
        missing_t0(
            path,
            &format!(
                "{group}/sequence/*/transmit_setup/wave/time_zero (or receive_setup/time_offset)"
            ),
        )
    })?;
    let angles = r.angles((
        read.iter().map(|e| e.angle).collect(),
        derived(format!(
            "{group}/sequence/*/transmit_setup/wave/parameters (the direction)"
        )),
    ));

    // The centre frequency: the excitations' transmit frequency.
    let excitations: Vec<&String> = read.iter().flat_map(|e| &e.excitations).collect();
    let mut frequencies = Vec::new();
    for ex in &excitations {
        if let Some(f) = number(h5, &format!("{ex}/transmit_frequency"))? {
            frequencies.push((f, format!("{ex}/transmit_frequency")));
        }
    }
    if let Some((f, name)) = frequencies.iter().find(|(f, _)| *f != frequencies[0].0) {
        return Err(IoError::invalid(
            path,
            name,
            format!(
                "is {f} Hz where another excitation's is {} Hz: pcuvd needs one centre frequency",
                frequencies[0].0
            ),
        ));
    }
    let modulation = first.modulation;
    let fc = r.number(
        "center_frequency_hz",
        frequencies
            .first()
            .map(|(f, name)| (*f, field(name.clone())))
            .or((modulation > 0.0).then(|| {
                (
                    modulation,
                    field(format!("{}/receive_setup/modulation_frequency", events[0])),
                )
            })),
        None,
        || {
            IoError::invalid(
                path,
                format!("{ACQUISITION}/excitations"),
                "give no transmit_frequency (and the data is RF): give the probe's centre \
                 frequency with --center-freq-hz",
            )
        },
    )?;
    let fc = positive(path, "excitations/*/transmit_frequency", fc)?;
    let bandwidth = resolve_bandwidth(
        &mut r,
        None,
        (
            DEFAULT_BANDWIDTH,
            "URX does not record the probe's bandwidth",
        ),
        fc,
        fs,
    );
    let pulse_cycles = r.or_default(
        "pulse_cycles",
        None,
        (
            DEFAULT_PULSE_CYCLES,
            "URX records the excitation's drive waveform, not the pulse's length",
        ),
    );
    r.record(
        "coding",
        json!("none"),
        ParamSource::Default {
            note: "URX describes one plane wave per event".into(),
        },
    );

    // The samples: raw_data, addressed sequence, event, channel, sample.
    let raw = format!("{gd}/raw_data");
    let stored = crate::datafile::open_hdf5_array(path, &raw)?;
    let (rows, columns) = match stored.shape[..] {
        [rows] => (rows, None),
        [rows, k @ (1 | 2)] => (rows, Some(k)),
        ref other => {
            return Err(IoError::invalid(
                path,
                &raw,
                format!("has shape {other:?}; expected (N,), (N, 1) or (N, 2) (real, imaginary)"),
            ));
        }
    };
    if stored.dtype.is_complex() {
        return Err(IoError::invalid(
            path,
            &raw,
            "holds complex HDF5 values; URX stores IQ as (N, 2) real numbers",
        ));
    }
    let iq = columns == Some(2);
    if iq != (modulation > 0.0) {
        return Err(IoError::invalid(
            path,
            format!("{}/receive_setup/modulation_frequency", events[0]),
            format!(
                "is {modulation} Hz but the samples are {} (0 means RF, real; a frequency \
                 means IQ, two columns)",
                if iq { "complex" } else { "real" }
            ),
        ));
    }
    let per_sequence = events
        .len()
        .checked_mul(n)
        .and_then(|v| v.checked_mul(first.samples))
        .unwrap_or(0);
    if per_sequence == 0 || rows % per_sequence != 0 {
        return Err(IoError::invalid(
            path,
            &raw,
            format!(
                "holds {rows} samples, not a whole number of sequences of {} events × {n} \
                 channels × {} samples",
                events.len(),
                first.samples
            ),
        ));
    }
    let sequences = rows / per_sequence;
    let demod = if iq {
        Some(r.known(
            "demod_frequency_hz",
            (
                modulation,
                field(format!("{}/receive_setup/modulation_frequency", events[0])),
            ),
        ))
    } else {
        None
    };

    // The event PRF: events per sequence over the interval between sequences.
    let stamps_field = format!("{gd}/event_timestamps");
    let stamps: Vec<f64> = list(h5, &stamps_field)?
        .iter()
        .map(|m| h5.read_f64(m).map(|(_, v)| v))
        .collect::<Result<Vec<_>, _>>()?
        .concat();
    let mut intervals: Vec<f64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
    let prf_found = if stamps.len() == sequences * events.len() && sequences >= 2 {
        let timing = frame_timing(&intervals, events.len())
            .map_err(|e| IoError::invalid(path, &stamps_field, e))?;
        if timing.simultaneous {
            return Err(IoError::invalid(
                path,
                &stamps_field,
                "puts the events of a sequence at one time: pcuvd reads URX events as fired one \
                 after another",
            ));
        }
        warnings.extend(timing.warning);
        Some((
            timing.event_prf,
            derived(format!(
                "{stamps_field} (events per sequence over the median interval between sequences)"
            )),
        ))
    } else if stamps.len() == events.len() && stamps.len() >= 2 {
        // One sequence: its events' spacing is all the file says of the event rate.
        intervals.sort_by(f64::total_cmp);
        let interval = intervals[intervals.len() / 2];
        (interval > 0.0).then(|| {
            (
                1.0 / interval,
                derived(format!(
                    "{stamps_field} (one sequence: 1 / the median interval between its events)"
                )),
            )
        })
    } else {
        None
    };
    let prf = r.number("event_prf_hz", prf_found, None, || {
        if stamps.is_empty() {
            missing_prf(path, &stamps_field)
        } else {
            underivable_prf(
                path,
                &stamps_field,
                &format!(
                    "holds {} event time(s) for {sequences} sequence(s) of {} event(s): no \
                     interval between events to take the event rate from",
                    stamps.len(),
                    events.len()
                ),
            )
        }
    })?;
    let prf = positive(path, &stamps_field, prf)?;

    let acquisition = PlaneWaveAcquisition {
        probe: pcuvd::Probe {
            name: string(h5, &format!("{probe}/description"))
                .filter(|d| !d.is_empty())
                .unwrap_or_else(|| "URX probe".into()),
            n_elements: n,
            pitch,
            element_width: width,
            center_frequency: fc,
            bandwidth,
        },
        angles,
        event_prf: prf,
        coding: pcuvd::Coding::Conventional,
        pulse_cycles,
        sampling_frequency: fs,
        sound_speed: c,
        t0,
    }
    .build(path)?;
    let mut shape = vec![sequences, events.len(), n, first.samples];
    let mut axes = vec![Axis::Frames, Axis::Angles, Axis::Channels, Axis::Samples];
    if let Some(k) = columns {
        shape.push(k);
        axes.push(if iq { Axis::ReIm } else { Axis::Unit });
    }
    let array = StoredArray {
        shape,
        dtype: stored.dtype,
        fortran: false,
        backing: Backing::Hdf5Flat {
            path: path.to_path_buf(),
            dataset: raw.clone(),
            columns,
        },
        label: stored.label,
    };
    let stored = StoredSamples::of(&array, &axes, iq);
    let frames = ArrayFrames::new(path, acquisition, array, axes, demod)?;
    Ok(OpenedRecording {
        source: Box::new(frames),
        read_pass: None,
        info: SourceInfo {
            files: vec![path.to_path_buf()],
            format: "URX (Moduleus ultrasound raw data exchange, HDF5)".into(),
            reader: "pcuvd_io::urx (rust-hdf5 row ranges of raw_data, a block of frames at a time)"
                .into(),
            parameters: r.params,
            stored: Some(stored),
            warnings,
            cardiac_triggers_s: None,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::whole;

    /// URX stores counts and indices as uint32; a file that stores them otherwise is refused
    /// rather than read with a truncated value.
    #[test]
    fn counts_and_indices_are_whole_non_negative_numbers() {
        assert_eq!(whole(0.0), Some(0));
        assert_eq!(whole(127.0), Some(127));
        assert_eq!(whole(u32::MAX as f64), Some(u32::MAX as usize));
        for bad in [-1.0, 2.5, f64::NAN, f64::INFINITY, 1e12] {
            assert_eq!(whole(bad), None, "{bad}");
        }
    }
}
