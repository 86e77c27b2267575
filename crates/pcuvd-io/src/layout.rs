//! Checks the readers share (the HDF5 ones above all): element positions that make a uniform
//! linear array, one t0 for every transmit, the frame timing of per-event intervals, values that
//! must be positive, and scalars read from a dataset of any of the shapes writers use.

use std::path::Path;

use crate::error::IoError;
use crate::hdf5::Hdf5;

/// (elements, pitch in m) of the element centres `x` (m), which must be evenly spaced along x
/// (pcuvd's beamformer knows linear arrays); `field` names them in errors.
pub fn linear_array(
    path: &Path,
    field: &str,
    x: &[f64],
    off_axis: &[f64],
) -> Result<(usize, f64), IoError> {
    let n = x.len();
    if n < 2 {
        return Err(IoError::invalid(
            path,
            field,
            format!("holds {n} element(s); at least 2 are needed"),
        ));
    }
    if let Some(v) = x.iter().chain(off_axis).find(|v| !v.is_finite()) {
        return Err(IoError::invalid(
            path,
            field,
            format!("holds a non-finite position ({v})"),
        ));
    }
    let pitch = (x[n - 1] - x[0]) / (n - 1) as f64;
    if pitch <= 0.0 {
        return Err(IoError::invalid(
            path,
            field,
            "does not increase along x with the element index (pcuvd's x axis follows the elements)",
        ));
    }
    let worst = x
        .iter()
        .enumerate()
        .map(|(i, &xi)| (xi - (x[0] + i as f64 * pitch)).abs())
        .fold(0.0, f64::max);
    if worst > 0.01 * pitch {
        return Err(IoError::invalid(
            path,
            field,
            format!(
                "is not a uniform linear array (an element sits {:.3} µm off the even spacing of \
                 {:.3} µm): pcuvd reads linear arrays",
                worst * 1e6,
                pitch * 1e6
            ),
        ));
    }
    if let Some(v) = off_axis.iter().find(|v| v.abs() > 0.01 * pitch) {
        return Err(IoError::invalid(
            path,
            field,
            format!(
                "puts an element {:.3} mm off the array's line (y or z ≠ 0): pcuvd reads flat \
                 linear arrays, not curved or matrix ones",
                v * 1e3
            ),
        ));
    }
    Ok((n, pitch))
}

/// The one t0 (s) of `per_transmit` values; they must agree within a hundredth of a sample.
pub fn common_t0(path: &Path, field: &str, per_transmit: &[f64], fs: f64) -> Result<f64, IoError> {
    let (lo, hi) = per_transmit
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    if per_transmit.is_empty() || !lo.is_finite() || !hi.is_finite() {
        return Err(IoError::invalid(path, field, "holds no finite time"));
    }
    if hi - lo > 0.01 / fs {
        return Err(IoError::invalid(
            path,
            field,
            format!(
                "gives transmits first samples at different times after their first element \
                 fires ({:.4} to {:.4} µs): pcuvd needs one t0 for every transmit",
                lo * 1e6,
                hi * 1e6
            ),
        ));
    }
    Ok(per_transmit.iter().sum::<f64>() / per_transmit.len() as f64)
}

/// A scalar dataset (shape (), (1,) or (1, 1)), `None` when absent.
pub fn scalar(h5: &Hdf5, path: &str) -> Result<Option<f64>, IoError> {
    if !h5.is_dataset(path) {
        return Ok(None);
    }
    let (_, v) = h5.read_f64(path)?;
    match v.as_slice() {
        [x] => Ok(Some(*x)),
        _ => Err(IoError::invalid(
            &h5.path,
            path,
            format!("must be one number, found {} values", v.len()),
        )),
    }
}

/// Values of a dataset that must hold one per transmit, or one for all (broadcast to `n`).
pub fn per_transmit(h5: &Hdf5, path: &str, n: usize) -> Result<Option<Vec<f64>>, IoError> {
    if !h5.is_dataset(path) {
        return Ok(None);
    }
    let (_, v) = h5.read_f64(path)?;
    match v.len() {
        1 => Ok(Some(vec![v[0]; n])),
        k if k == n => Ok(Some(v)),
        k => Err(IoError::invalid(
            &h5.path,
            path,
            format!("holds {k} values; expected one, or one per transmit ({n})"),
        )),
    }
}

/// Checks a value that must be finite and > 0.
pub fn positive(path: &Path, name: &str, v: f64) -> Result<f64, IoError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(IoError::invalid(
            path,
            name,
            format!("must be finite and > 0, got {v}"),
        ))
    }
}

/// Time (s) from the first element's firing until a plane wave steered by `angle` (rad) crosses
/// the centre of an array of `n` elements of `pitch` (m) in a medium of sound speed `c`: USTB's
/// time origin is that crossing, pcuvd's the first firing.
pub fn crossing_time(angle: f64, n: usize, pitch: f64, c: f64) -> f64 {
    (n as f64 - 1.0) / 2.0 * pitch * angle.sin().abs() / c
}

/// A recording's frame timing, from the intervals between its transmits (zea's
/// `time_to_next_transmit`, the differences of URX's event timestamps).
#[derive(Debug, Clone, PartialEq)]
pub struct FrameTiming {
    /// pcuvd's event PRF (Hz): n_tx over the median frame period, so that each angle's slow-time
    /// rate (the frame rate) is right whatever the spacing within a frame.
    pub event_prf: f64,
    /// True when the transmits of a frame are 0 s apart: one time per frame, as a coded
    /// acquisition's angles have once decoded (the frame's decoding time).
    pub simultaneous: bool,
    /// Said when frames are separated by a pause that the spacing within a frame does not give.
    pub warning: Option<String>,
}

/// The frame timing of `intervals` (s, from each transmit to the next, frame by frame) of a
/// recording of `n_tx` transmits per frame. Intervals within a frame may be 0 (angles stored
/// decoded, at their frame's time) but not some 0 and some not; a frame must last > 0.
pub fn frame_timing(intervals: &[f64], n_tx: usize) -> Result<FrameTiming, String> {
    if n_tx == 0 || intervals.len() < n_tx.max(1) {
        return Err(format!(
            "holds {} intervals: fewer than one frame of {n_tx} transmits",
            intervals.len()
        ));
    }
    if let Some(v) = intervals.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
        return Err(format!(
            "holds an interval of {v} s (must be finite and ≥ 0)"
        ));
    }
    // Frame k starts at the sum of the intervals before transmit k·n_tx.
    let mut periods: Vec<f64> = intervals
        .chunks_exact(n_tx)
        .map(|frame| frame.iter().sum())
        .collect();
    if let Some(k) = periods.iter().position(|&p| p <= 0.0) {
        return Err(format!(
            "gives frame {} a duration of 0 s: its transmits and the next frame's are at one time",
            k + 1
        ));
    }
    periods.sort_by(f64::total_cmp);
    let period = periods[periods.len() / 2];
    let event_prf = n_tx as f64 / period;
    let mut within: Vec<f64> = intervals
        .iter()
        .enumerate()
        .filter(|(i, _)| i % n_tx != n_tx - 1)
        .map(|(_, &v)| v)
        .collect();
    let zeros = within.iter().filter(|&&v| v == 0.0).count();
    if zeros > 0 && zeros < within.len() {
        return Err(format!(
            "puts {zeros} of the {} transmit pairs within frames at one time and the others \
             apart: a frame's transmits are either all at its time (stored decoded) or fired one \
             after another",
            within.len()
        ));
    }
    let simultaneous = !within.is_empty() && zeros == within.len();
    within.sort_by(f64::total_cmp);
    let warning = within
        .get(within.len() / 2)
        .filter(|_| !simultaneous)
        .and_then(|&spacing| {
            ((spacing * n_tx as f64 - period).abs() > 0.01 * period).then(|| {
                format!(
                    "the transmits of a frame are {:.1} µs apart but frames start every {:.1} µs: \
                     pcuvd takes the frame rate (each angle's Doppler sampling rate) from the \
                     frame period, i.e. an event PRF of {:.1} Hz, not 1/{:.1} µs",
                    spacing * 1e6,
                    period * 1e6,
                    event_prf,
                    spacing * 1e6
                )
            })
        });
    Ok(FrameTiming {
        event_prf,
        simultaneous,
        warning,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prf_is_per_transmit_not_per_frame() {
        // 3 transmits 100 µs apart, frames every 300 µs: 10 kHz events, 3.33 kHz frames.
        let even = vec![100e-6; 12];
        let t = frame_timing(&even, 3).unwrap();
        assert!((t.event_prf - 10_000.0).abs() < 1e-6 && t.warning.is_none() && !t.simultaneous);
        // The same transmits with a 700 µs pause after each frame: frames every 900 µs, so each
        // angle is sampled at 1.11 kHz, i.e. pcuvd's event PRF 3/900 µs, with a warning.
        let paused: Vec<f64> = (0..12)
            .map(|i| if i % 3 == 2 { 700e-6 } else { 100e-6 })
            .collect();
        let t = frame_timing(&paused, 3).unwrap();
        assert!((t.event_prf - 3.0 / 900e-6).abs() < 1e-6, "{}", t.event_prf);
        assert!(t.warning.unwrap().contains("100.0 µs apart"));
        assert!(frame_timing(&[1e-4, -1.0, 1e-4], 3).is_err());
        assert!(frame_timing(&[1e-4], 3).is_err());
    }

    #[test]
    fn decoded_angles_share_their_frame_time() {
        // 4 decoded angles per frame, at one time, frames 500 µs apart (4 coded events at
        // 8 kHz): the frame rate is 2 kHz, pcuvd's event PRF 4 × 2 kHz, and no pause warning.
        let decoded: Vec<f64> = (0..12)
            .map(|i| if i % 4 == 3 { 500e-6 } else { 0.0 })
            .collect();
        let t = frame_timing(&decoded, 4).unwrap();
        assert!(t.simultaneous && t.warning.is_none());
        assert!((t.event_prf - 8_000.0).abs() < 1e-6, "{}", t.event_prf);
        // Some transmits of a frame at one time and others apart: neither reading holds.
        let mixed: Vec<f64> = (0..8)
            .map(|i| match i % 4 {
                0 => 0.0,
                3 => 300e-6,
                _ => 100e-6,
            })
            .collect();
        assert!(frame_timing(&mixed, 4).unwrap_err().contains("2 of the 6"));
        // A frame of zero duration.
        assert!(frame_timing(&[0.0; 8], 4).unwrap_err().contains("frame 1"));
    }
}
