//! zea / OpenH-RF HDF5: `data/raw_data` (n_frames, n_tx, n_ax, n_el, n_ch; n_ch 1 = RF, 2 = IQ
//! as real and imaginary parts), in the legacy single-track layout (`/data`, `/scan`) or the
//! first track that holds raw data (`/tracks/track_N/{data, scan}`); `scan/` sampling_frequency,
//! center_frequency, demodulation_frequency, initial_times (the first sample after the first
//! element fires: pcuvd's t0), polar_angles, t0_delays (checked against the angles), sound_speed,
//! time_to_next_transmit; `probe/probe_geometry` (n_el, 3), element_width,
//! probe_bandwidth_percent.
//!
//! The PRF is per transmit: `time_to_next_transmit` holds the time from each transmit to the next
//! ((n_frames, n_tx), or flat n_frames·n_tx − 1), so a compound frame lasts the sum of a row, and
//! pcuvd's event PRF is n_tx / that frame period (each angle's slow-time rate is then right even
//! when frames are separated by a pause). Summing it gives the frame rate, not the PRF.
//!
//! A coded acquisition (Hadamard) is stored decoded: one transmit per angle, the angles of a
//! frame at one time (its decoding time: `time_to_next_transmit` 0 within a frame, the frame
//! period after its last transmit), the code's polarity kept in `tx_apodizations` (negative =
//! opposite polarity). pcuvd reads such a track as [`Coding::Decoded`]: the polarity turned
//! back, the frame rate the coded sequence's, nothing decoded again. Either sign says it; a
//! track with neither is conventional, one transmit per event.
//!
//! zea's colour Doppler is positive toward the transducer; pcuvd's `color_doppler.npy` is
//! positive away from it.

use std::path::Path;

use pcuvd::Coding;
use serde_json::json;

use crate::array::{ArrayFrames, Axis};
use crate::error::IoError;
use crate::hdf5::Hdf5;
// Where frame timing was public before it moved to `layout` (URX shares it).
pub use crate::layout::{FrameTiming, frame_timing};
use crate::layout::{common_t0, linear_array, per_transmit, positive, scalar};
use crate::params::{Overrides, ParamSource, Resolver, derived, field, missing_prf, missing_t0};
use crate::recording::{
    DEFAULT_BANDWIDTH, DEFAULT_PULSE_CYCLES, OpenedRecording, PlaneWaveAcquisition, SourceInfo,
    StoredSamples, plane_wave_angle, resolve_bandwidth,
};

/// The polarity (±1) of each transmit from zea's `tx_apodizations` (n_tx rows of `n_el`, in
/// [−1, 1], negative = fired with opposite polarity): the sign shared by the elements that fire.
/// A row whose elements fire with both polarities (an element-coded transmit) is not a plane
/// wave pcuvd can beamform, and a row of zeros fires nothing: both are refused.
pub fn transmit_polarity(apodizations: &[f64], n_el: usize) -> Result<Vec<f64>, String> {
    apodizations
        .chunks_exact(n_el.max(1))
        .enumerate()
        .map(|(k, row)| {
            let positive = row.iter().any(|&a| a > 0.0);
            let negative = row.iter().any(|&a| a < 0.0);
            match (positive, negative) {
                (true, false) => Ok(1.0),
                (false, true) => Ok(-1.0),
                (true, true) => Err(format!(
                    "row {} fires some elements with one polarity and some with the other (an \
                     element-coded transmit): pcuvd reads plane waves, each fired with one \
                     polarity",
                    k + 1
                )),
                (false, false) => Err(format!("row {} fires no element (all zero)", k + 1)),
            }
        })
        .collect()
}

/// The track a reader reads and why: its group name (`track_N`), the parameter source that says
/// so (the user's choice, or the first of several, listing them all), and the warning to give
/// when the file holds others that were not chosen.
struct ChosenTrack {
    name: String,
    source: ParamSource,
    warning: Option<String>,
}

/// The `label` of track `track` (a group name, `track_N`), if it has one.
fn track_label(h5: &Hdf5, track: &str) -> Option<String> {
    h5.dataset(&format!("tracks/{track}/label"))
        .ok()
        .and_then(|d| d.read_strings().ok())
        .and_then(|v| v.into_iter().next())
}

/// The tracks of a multi-track zea file that hold raw data, in index order, each with its label
/// and frame count, for messages: `track_1 "disk" (8 frames)`.
fn describe_tracks(h5: &Hdf5, tracks: &[String]) -> String {
    tracks
        .iter()
        .map(|t| {
            let label = track_label(h5, t).map_or_else(String::new, |l| format!(" {l:?}"));
            let frames = h5
                .describe(&format!("tracks/{t}/data/raw_data"))
                .ok()
                .and_then(|(shape, _)| shape.first().copied())
                .map_or_else(String::new, |n| format!(" ({n} frames)"));
            format!("{t}{label}{frames}")
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Chooses the track to read: `asked` (an index N of `track_N`, or a label), else the first that
/// holds raw data.
fn choose_track(path: &Path, h5: &Hdf5, asked: Option<&str>) -> Result<ChosenTrack, IoError> {
    let index = |t: &str| {
        t.strip_prefix("track_")
            .and_then(|n| n.parse::<usize>().ok())
    };
    let mut tracks: Vec<String> = h5
        .members("tracks")?
        .into_iter()
        .filter(|t| h5.is_dataset(&format!("tracks/{t}/data/raw_data")))
        .collect();
    tracks.sort_by_key(|t| (index(t), t.clone()));
    let listed = describe_tracks(h5, &tracks);
    let Some(asked) = asked else {
        let first = tracks.first().cloned().ok_or_else(|| {
            IoError::missing(
                path,
                "the zea file",
                "raw channel data (data/raw_data in /tracks/track_N)",
            )
        })?;
        let (note, warning) = if tracks.len() > 1 {
            let note = format!(
                "the first of {} tracks with raw data: {listed}; --track (Python: track=) \
                 chooses another, by index or label",
                tracks.len()
            );
            let warning = format!("pcuvd reads {first}, {note}");
            (note, Some(warning))
        } else {
            ("the file's one track with raw data".to_string(), None)
        };
        return Ok(ChosenTrack {
            name: first,
            source: ParamSource::Default { note },
            warning,
        });
    };
    let found = tracks.iter().find(|t| {
        asked
            .parse::<usize>()
            .ok()
            .is_some_and(|n| index(t) == Some(n))
            || track_label(h5, t).as_deref() == Some(asked)
    });
    match found {
        Some(t) => Ok(ChosenTrack {
            name: t.clone(),
            source: ParamSource::Override,
            warning: None,
        }),
        None => Err(IoError::invalid(
            path,
            "--track",
            format!(
                "{asked:?} is neither the index nor the label of a track with raw data; the \
                 file's are {listed}"
            ),
        )),
    }
}

/// Opens a zea file (the track `overrides.track` names, else the first with raw data).
pub fn open(path: &Path, h5: &Hdf5, overrides: &Overrides) -> Result<OpenedRecording, IoError> {
    let mut warnings = Vec::new();
    let mut r = Resolver::new(overrides);
    let track = if h5.is_dataset("data/raw_data") {
        if let Some(asked) = &overrides.track {
            return Err(IoError::invalid(
                path,
                "--track",
                format!("{asked:?}: the file holds one acquisition (data/raw_data), not tracks"),
            ));
        }
        String::new()
    } else {
        let chosen = choose_track(path, h5, overrides.track.as_deref())?;
        warnings.extend(chosen.warning);
        r.record("track", json!(chosen.name), chosen.source);
        format!("tracks/{}/", chosen.name)
    };
    let scan = |name: &str| format!("{track}scan/{name}");
    let raw = format!("{track}data/raw_data");
    let array = crate::datafile::open_hdf5_array(path, &raw)?;
    let [_n_frames, n_tx, _n_ax, n_el, n_ch] = array.shape[..] else {
        return Err(IoError::invalid(
            path,
            &raw,
            format!(
                "has shape {:?}; expected (n_frames, n_tx, n_ax, n_el, n_ch)",
                array.shape
            ),
        ));
    };
    let iq = match n_ch {
        1 => false,
        2 => true,
        k => {
            return Err(IoError::invalid(
                path,
                &raw,
                format!("has n_ch = {k}; expected 1 (RF) or 2 (IQ)"),
            ));
        }
    };
    let missing = |name: &str| {
        let n = scan(name);
        move || IoError::missing(path, "the zea scan group", format!("dataset '{n}'"))
    };
    let fs = r.number(
        "sampling_frequency_hz",
        scalar(h5, &scan("sampling_frequency"))?.map(|v| (v, field(scan("sampling_frequency")))),
        None,
        missing("sampling_frequency"),
    )?;
    let fs = positive(path, &scan("sampling_frequency"), fs)?;
    let one = |name: &str| -> Result<Option<f64>, IoError> {
        match per_transmit(h5, &scan(name), n_tx)? {
            None => Ok(None),
            Some(v) if v.iter().all(|&x| x == v[0]) => Ok(Some(v[0])),
            Some(_) => Err(IoError::invalid(
                path,
                scan(name),
                "differs between transmits: pcuvd needs one value for the recording",
            )),
        }
    };
    let fc = r.number(
        "center_frequency_hz",
        one("center_frequency")?.map(|v| (v, field(scan("center_frequency")))),
        None,
        missing("center_frequency"),
    )?;
    let fc = positive(path, &scan("center_frequency"), fc)?;
    let c = r.number(
        "sound_speed_m_s",
        scalar(h5, &scan("sound_speed"))?.map(|v| (v, field(scan("sound_speed")))),
        Some((1540.0, "scan/sound_speed is absent")),
        missing("sound_speed"),
    )?;
    let c = positive(path, &scan("sound_speed"), c)?;
    let t0_found = match per_transmit(h5, &scan("initial_times"), n_tx)? {
        Some(v) => Some((
            common_t0(path, &scan("initial_times"), &v, fs)?,
            field(scan("initial_times")),
        )),
        None => None,
    };
    let t0 = r.number("t0_s", t0_found, None, || {
        missing_t0(path, &scan("initial_times"))
    })?;

    // Probe.
    let geometry = "probe/probe_geometry";
    let (gshape, g) = h5
        .read_f64(geometry)
        .map_err(|_| IoError::missing(path, "the zea file", "dataset 'probe/probe_geometry'"))?;
    if gshape.len() != 2 || gshape[1] != 3 || gshape[0] != n_el {
        return Err(IoError::invalid(
            path,
            geometry,
            format!("has shape {gshape:?}; expected ({n_el}, 3): x, y, z of each element"),
        ));
    }
    let x: Vec<f64> = g.chunks_exact(3).map(|p| p[0]).collect();
    let off: Vec<f64> = g.chunks_exact(3).flat_map(|p| [p[1], p[2]]).collect();
    let (n, pitch) = linear_array(path, geometry, &x, &off)?;
    r.record(
        "n_elements",
        json!(n),
        derived(format!("{geometry} (its rows)")),
    );
    r.record(
        "pitch_m",
        json!(pitch),
        derived(format!("{geometry} (element x spacing)")),
    );
    let width = scalar(h5, "probe/element_width")?;
    let width = match width {
        Some(w) => {
            r.record("element_width_m", json!(w), field("probe/element_width"));
            positive(path, "probe/element_width", w)?
        }
        None => {
            r.record(
                "element_width_m",
                json!(pitch),
                ParamSource::Default {
                    note: "probe/element_width is absent: the pitch".into(),
                },
            );
            pitch
        }
    };
    let bandwidth = resolve_bandwidth(
        &mut r,
        scalar(h5, "probe/probe_bandwidth_percent")?
            .map(|v| (v / 100.0, derived("probe/probe_bandwidth_percent / 100"))),
        (
            DEFAULT_BANDWIDTH,
            "probe/probe_bandwidth_percent is absent: pcuvd's",
        ),
        fc,
        fs,
    );
    let bandwidth = positive(path, "probe/probe_bandwidth_percent", bandwidth)?;

    // Steering: polar angles, checked against the delay laws when both are there.
    let angles = match per_transmit(h5, &scan("polar_angles"), n_tx)? {
        Some(a) => {
            if let Some(d) = per_transmit_rows(h5, &scan("t0_delays"), n_tx, n)? {
                let xs: Vec<f64> = (0..n)
                    .map(|i| (i as f64 - (n as f64 - 1.0) / 2.0) * pitch)
                    .collect();
                for (k, row) in d.chunks_exact(n).enumerate() {
                    let fitted = plane_wave_angle(row, &xs, c).map_err(|e| {
                        IoError::invalid(path, format!("{} row {}", scan("t0_delays"), k + 1), e)
                    })?;
                    if (fitted - a[k]).abs() > 0.05f64.to_radians() {
                        warnings.push(format!(
                            "transmit {}: {} says {:.3}° but its t0_delays steer {:.3}°; pcuvd \
                             uses polar_angles",
                            k + 1,
                            scan("polar_angles"),
                            a[k].to_degrees(),
                            fitted.to_degrees()
                        ));
                    }
                }
            }
            (a, field(scan("polar_angles")))
        }
        None => {
            let d = per_transmit_rows(h5, &scan("t0_delays"), n_tx, n)?.ok_or_else(|| {
                IoError::missing(
                    path,
                    "the zea scan group",
                    format!("dataset '{}' (or t0_delays)", scan("polar_angles")),
                )
            })?;
            let xs: Vec<f64> = (0..n)
                .map(|i| (i as f64 - (n as f64 - 1.0) / 2.0) * pitch)
                .collect();
            let a = d
                .chunks_exact(n)
                .enumerate()
                .map(|(k, row)| {
                    plane_wave_angle(row, &xs, c).map_err(|e| {
                        IoError::invalid(path, format!("{} row {}", scan("t0_delays"), k + 1), e)
                    })
                })
                .collect::<Result<Vec<_>, _>>()?;
            (
                a,
                derived(format!(
                    "{} (plane-wave fit of each row)",
                    scan("t0_delays")
                )),
            )
        }
    };
    let angles = r.angles(angles);
    let ttnt = scan("time_to_next_transmit");
    let timing = if h5.is_dataset(&ttnt) {
        let (_, intervals) = h5.read_f64(&ttnt)?;
        let timing =
            frame_timing(&intervals, n_tx).map_err(|e| IoError::invalid(path, &ttnt, e))?;
        warnings.extend(timing.warning.clone());
        Some(timing)
    } else {
        None
    };
    let prf_found = timing.as_ref().map(|t| {
        (
            t.event_prf,
            derived(format!(
                "{ttnt}: n_tx / the frame period (the time to the next transmit is per transmit; \
                 its sum over a frame is the frame period)"
            )),
        )
    });
    let prf = r.number("event_prf_hz", prf_found, None, || missing_prf(path, &ttnt))?;
    let prf = positive(path, &ttnt, prf)?;
    let apodizations = scan("tx_apodizations");
    let polarity = match per_transmit_rows(h5, &apodizations, n_tx, n)? {
        Some(rows) => Some(
            transmit_polarity(&rows, n).map_err(|e| IoError::invalid(path, &apodizations, e))?,
        ),
        None => None,
    };
    let simultaneous = timing.as_ref().is_some_and(|t| t.simultaneous);
    let inverted = polarity.as_ref().is_some_and(|p| p.contains(&-1.0));
    let coding = if simultaneous || inverted {
        let polarity = polarity.unwrap_or_else(|| vec![1.0; n_tx]);
        let timing_says = format!("{ttnt} (a frame's transmits at one time)");
        let polarity_says = format!("{apodizations} (some transmits of opposite polarity)");
        let why = match (simultaneous, inverted) {
            (true, true) => format!("{timing_says} and {polarity_says}"),
            (true, false) => timing_says,
            _ => polarity_says,
        };
        r.record(
            "coding",
            json!("decoded"),
            derived(format!(
                "{why}: each transmit is an angle already decoded from a coded acquisition, at \
                 its frame's decoding time; pcuvd turns its polarity back and decodes nothing"
            )),
        );
        r.record("polarity", json!(polarity), field(apodizations.clone()));
        Coding::Decoded { polarity }
    } else {
        r.record(
            "coding",
            json!("none"),
            ParamSource::Default {
                note: "zea describes one transmit per event, each fired in turn".into(),
            },
        );
        Coding::Conventional
    };
    let pulse_cycles = r.or_default(
        "pulse_cycles",
        None,
        (DEFAULT_PULSE_CYCLES, "zea does not record the pulse length"),
    );
    let demod = if iq {
        Some(r.number(
            "demod_frequency_hz",
            one("demodulation_frequency")?.map(|v| (v, field(scan("demodulation_frequency")))),
            None,
            missing("demodulation_frequency"),
        )?)
    } else {
        None
    };
    let axes = vec![
        Axis::Frames,
        Axis::Angles,
        Axis::Samples,
        Axis::Channels,
        if iq { Axis::ReIm } else { Axis::Unit },
    ];
    let acquisition = PlaneWaveAcquisition {
        probe: pcuvd::Probe {
            name: h5
                .dataset("probe/name")
                .ok()
                .and_then(|d| crate::hdf5::guard(path, "probe/name", || d.read_strings()).ok())
                .and_then(|v| v.into_iter().next())
                .unwrap_or_else(|| "zea probe".into()),
            n_elements: n,
            pitch,
            element_width: width,
            center_frequency: fc,
            bandwidth,
        },
        angles,
        event_prf: prf,
        coding,
        pulse_cycles,
        sampling_frequency: fs,
        sound_speed: c,
        t0,
    }
    .build(path)?;
    warnings.push(
        "zea's colour Doppler is positive toward the transducer; pcuvd's color_doppler is \
         positive away from it"
            .into(),
    );
    let stored = StoredSamples::of(&array, &axes, iq);
    let frames = ArrayFrames::new(path, acquisition, array, axes, demod)?;
    Ok(OpenedRecording {
        source: Box::new(frames),
        read_pass: None,
        info: SourceInfo {
            files: vec![path.to_path_buf()],
            format: "zea / OpenH-RF (HDF5)".into(),
            reader: "pcuvd_io::zea (rust-hdf5 hyperslabs, Blosc/zstd chunks, a block of frames at a time)".into(),
            parameters: r.params,
            stored: Some(stored),
            warnings,
            cardiac_triggers_s: None,
        },
    })
}

/// A (n_tx, n_el) dataset as rows of `n_el`, or `None` when absent.
fn per_transmit_rows(
    h5: &Hdf5,
    path: &str,
    n_tx: usize,
    n_el: usize,
) -> Result<Option<Vec<f64>>, IoError> {
    if !h5.is_dataset(path) {
        return Ok(None);
    }
    let (shape, v) = h5.read_f64(path)?;
    if shape != [n_tx, n_el] {
        return Err(IoError::invalid(
            &h5.path,
            path,
            format!("has shape {shape:?}; expected ({n_tx}, {n_el})"),
        ));
    }
    Ok(Some(v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polarity_is_the_sign_the_firing_elements_share() {
        // A Hann-apodised row, a negated one, and a row with its edge elements off.
        let rows = [
            0.5, 1.0, 0.5, //
            -0.5, -1.0, -0.5, //
            0.0, -1.0, 0.0,
        ];
        assert_eq!(transmit_polarity(&rows, 3).unwrap(), vec![1.0, -1.0, -1.0]);
        let element_coded = [1.0, -1.0, 1.0];
        assert!(
            transmit_polarity(&element_coded, 3)
                .unwrap_err()
                .contains("row 1")
        );
        assert!(
            transmit_polarity(&[0.0; 3], 3)
                .unwrap_err()
                .contains("no element")
        );
    }
}
