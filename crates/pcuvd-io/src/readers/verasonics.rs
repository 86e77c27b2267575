//! A Verasonics Vantage workspace saved with `save(..., '-v7.3')` (HDF5 behind MATLAB's user
//! block). What is read, and nothing else:
//! - `RcvData{1}`: the receive buffer, int16, MATLAB (rows, channels, frames); element e's
//!   channel is `Trans.ConnectorES(e)`, else `Trans.Connector(e)` (1-based, as Verasonics'
//!   scripts index `RcvData(:, Trans.Connector, :)`), else channel e (a warning says so);
//! - `Resource.RcvBuffer(1).numFrames` and `.lastFrame` (1-based, the newest frame of the circular
//!   buffer: chronological frame k sits in slot (lastFrame + k) mod numFrames);
//! - `Resource.Parameters.speedOfSound` (m/s);
//! - `Receive(i)` of buffer 1 and frame 1 (`bufnum`, `framenum`), in event order: `startSample`,
//!   `endSample` (1-based rows of the frame), `decimSampleRate` (MHz) / `quadDecim`, `sampleMode`
//!   (see below), `demodFrequency` (MHz, checked in the interleaved modes), `startDepth`
//!   (wavelengths), `Apod` (an element it sets to 0 did not receive: whatever its channel holds
//!   there reads as zero); every frame repeats frame 1's acquisitions;
//! - `Event(j).tx`, `.rcv`, `.seqControl` (which transmit each acquisition fires, in order, and
//!   its `SeqControl(k)` of command `timeToNextAcq`, argument in µs: the event PRF); without
//!   `Event`, `Receive(i)` fires `TX(i)` (or the one `TX`);
//! - `TX(t).Steer(1)` (rad, the plane wave's steering), `TX(t).focus` (0 = plane wave);
//! - `Trans.frequency` (MHz), `Trans.units` ('mm' or 'wavelengths'), `Trans.ElementPos` (x, y, z
//!   of each element in those units), `Trans.elementWidth` (same units), `Trans.Bandwidth`
//!   ([low high] MHz), `Trans.lensCorrection` (one-way wavelengths);
//! - `TW(1).Parameters(3)` (half cycles of the parametric pulse), `TW(w).peak` (wavelengths) of
//!   each transmit's waveform w = `TX(t).waveform`.
//!
//! t0 = 2·startDepth·λ/c − 2·lensCorrection·λ/c − TW(w).peak·λ/c (λ = c / Trans.frequency):
//! the receive window opens startDepth wavelengths deep (round trip) after the first element
//! fires, and the transmit waveform peaks `peak` wavelengths (periods) after that (USTB's
//! Verasonics reader takes the same offset).
//!
//! Sample modes: NS200BW, BS67BW and custom store RF at decimSampleRate / quadDecim (BS67BW
//! band-pass sampled); others (NS200BWI, two acquisitions interleaved) are refused. The
//! interleaved modes BS100BW and BS50BW sample at 4 f_d (f_d = `Receive.demodFrequency`) and
//! keep, of every 4 (BS100BW) or 8 (BS50BW) samples, the first two, stored one after the other:
//! a pair a quarter period apart, so the IQ rate is f_d or f_d / 2. decimSampleRate / quadDecim
//! must agree: as the stored samples' rate (twice the IQ rate) or as the A/D's (4 f_d). With
//! s = A cos(2π f_d t + φ) the pair's first sample is A cos(2π f_d t + φ) and its second
//! −A sin(2π f_d t + φ), so I − jQ is the analytic signal at the first, read (as zea's converter
//! reads it) as if both were taken then. pcuvd's IQ is baseband at absolute time,
//! IQ(t) = analytic(t)·e^{−2πi f_d t}: at the pairs' instants t0 + k/f_d (or 2k/f_d) that factor
//! is e^{−2πi f_d t0}, one rotation for the whole recording.

use std::ops::Range;
use std::path::{Path, PathBuf};

use ndarray::Array3;
use num_complex::Complex32;
use pcuvd::acquisition::source::FrameSource;
use pcuvd::{Acquisition, ChannelData, Samples};
use serde_json::json;

use crate::error::IoError;
use crate::hdf5::Hdf5;
use crate::layout::{common_t0, linear_array, positive};
use crate::mat::MatValue;
use crate::params::{Overrides, ParamSource, Resolver, derived, field, missing_prf};
use crate::recording::{
    DEFAULT_BANDWIDTH, DEFAULT_PULSE_CYCLES, OpenedRecording, PlaneWaveAcquisition, SourceInfo,
    StoredSamples, resolve_bandwidth,
};

/// The receive buffer of a Verasonics workspace, read a block of frames at a time in
/// chronological order.
#[derive(Debug, Clone)]
pub struct VerasonicsFrames {
    acquisition: Acquisition,
    path: PathBuf,
    dataset: String,
    /// Buffer frames and the slot of the oldest one.
    n_buffer_frames: usize,
    first_slot: usize,
    /// Rows of each acquisition of a buffer frame, in event order (0-based, end exclusive).
    rows: Vec<Range<usize>>,
    /// The buffer column (0-based) of each element, in element order.
    columns: Vec<usize>,
    /// The elements each acquisition's `Receive.Apod` leaves out (read as zero).
    silent_elements: Vec<Vec<usize>>,
    /// Columns of the buffer (the system's receive channels).
    buffer_channels: usize,
    /// The buffer's HDF5 shape has a frame axis (3-D) or not (one frame, 2-D).
    has_frame_axis: bool,
    /// In the interleaved I/Q modes, the demodulation frequency (Hz) of the pairs; RF otherwise.
    pairs_demod_frequency: Option<f64>,
}

/// How a `Receive.sampleMode` stores its samples.
#[derive(Debug, Clone, Copy, PartialEq)]
enum SampleMode {
    /// Real RF at the decimated rate (NS200BW; BS67BW, band-pass sampled; custom, at the rate
    /// decimSampleRate states; no mode given).
    Rf,
    /// I/Q pairs, one every `every` ADC samples (BS100BW: 4, BS50BW: 8).
    Pairs { every: usize },
}

impl SampleMode {
    fn of(mode: Option<&str>) -> Option<SampleMode> {
        match mode {
            None | Some("NS200BW" | "BS67BW" | "custom") => Some(SampleMode::Rf),
            Some("BS100BW") => Some(SampleMode::Pairs { every: 4 }),
            Some("BS50BW") => Some(SampleMode::Pairs { every: 8 }),
            Some(_) => None,
        }
    }
}

fn struct_field<'a>(v: &'a MatValue, name: &str) -> Option<&'a MatValue> {
    v.field(name)
}

/// Elements of a struct or struct array.
fn elements(v: &MatValue) -> Vec<&std::collections::BTreeMap<String, MatValue>> {
    match v {
        MatValue::Struct(m) => vec![m],
        MatValue::StructArray { fields, .. } => fields.iter().collect(),
        _ => vec![],
    }
}

fn number(map: &std::collections::BTreeMap<String, MatValue>, name: &str) -> Option<f64> {
    map.get(name).and_then(MatValue::as_scalar)
}

fn numbers(v: Option<&MatValue>) -> Vec<f64> {
    match v {
        Some(MatValue::Numeric { real, .. }) => real.to_f64().into_owned(),
        _ => vec![],
    }
}

/// Opens a Verasonics workspace.
pub fn open(path: &Path, h5: &Hdf5, overrides: &Overrides) -> Result<OpenedRecording, IoError> {
    let read = |name: &str| crate::mat73::read_value(h5, name);
    let need = |v: Option<f64>, what: &str| {
        v.ok_or_else(|| IoError::missing(path, "the Verasonics workspace", what.to_string()))
    };
    let mut warnings = Vec::new();
    let mut r = Resolver::new(overrides);
    let trans = read("Trans")?;
    let resource = read("Resource")?;
    let receive = read("Receive")?;
    let tx = read("TX")?;
    let events = if h5.exists("Event") {
        Some(read("Event")?)
    } else {
        None
    };
    let seq_control = if h5.exists("SeqControl") {
        Some(read("SeqControl")?)
    } else {
        None
    };

    let c = need(
        struct_field(&resource, "Parameters")
            .and_then(|p| p.field("speedOfSound"))
            .and_then(MatValue::as_scalar),
        "Resource.Parameters.speedOfSound",
    )?;
    let c = r.known(
        "sound_speed_m_s",
        (c, field("Resource.Parameters.speedOfSound")),
    );
    let c = positive(path, "Resource.Parameters.speedOfSound", c)?;
    let f_mhz = need(
        trans.field("frequency").and_then(MatValue::as_scalar),
        "Trans.frequency",
    )?;
    let fc = r.known(
        "center_frequency_hz",
        (f_mhz * 1e6, derived("Trans.frequency (MHz) × 10⁶")),
    );
    let fc = positive(path, "Trans.frequency", fc)?;
    let wavelength = c / (f_mhz * 1e6);
    let units = trans
        .field("units")
        .and_then(MatValue::as_str)
        .unwrap_or("wavelengths")
        .to_string();
    let scale = match units.as_str() {
        "mm" => 1e-3,
        "wavelengths" => wavelength,
        other => {
            return Err(IoError::invalid(
                path,
                "Trans.units",
                format!("is {other:?}; expected 'mm' or 'wavelengths'"),
            ));
        }
    };
    // ElementPos: MATLAB N × (4 or 5), column-major: column k is values[k·N .. (k+1)·N].
    let (pos_dims, pos) = match trans.field("ElementPos") {
        Some(MatValue::Numeric { dims, real, .. }) => (dims.clone(), real.to_f64()),
        _ => return Err(IoError::missing(path, "Trans", "field 'ElementPos'")),
    };
    let n_pos = pos_dims.first().copied().unwrap_or(0);
    if pos_dims.len() != 2 || pos_dims[1] < 3 || pos.len() != n_pos * pos_dims[1] {
        return Err(IoError::invalid(
            path,
            "Trans.ElementPos",
            format!("has dimensions {pos_dims:?}; expected N × 4 or N × 5 (x, y, z, ...)"),
        ));
    }
    let x: Vec<f64> = pos[..n_pos].iter().map(|v| v * scale).collect();
    let off: Vec<f64> = pos[n_pos..3 * n_pos].iter().map(|v| v * scale).collect();
    let (n_el, pitch) = linear_array(path, "Trans.ElementPos", &x, &off)?;
    r.record(
        "n_elements",
        json!(n_el),
        derived("Trans.ElementPos (its rows)"),
    );
    r.record(
        "pitch_m",
        json!(pitch),
        derived(format!(
            "Trans.ElementPos (x spacing, in Trans.units = {units})"
        )),
    );
    let width = match trans.field("elementWidth").and_then(MatValue::as_scalar) {
        Some(w) => {
            r.record(
                "element_width_m",
                json!(w * scale),
                derived(format!("Trans.elementWidth (in {units})")),
            );
            w * scale
        }
        None => {
            r.record(
                "element_width_m",
                json!(pitch),
                ParamSource::Default {
                    note: "Trans.elementWidth is absent: the pitch".into(),
                },
            );
            pitch
        }
    };
    let width = positive(path, "Trans.elementWidth", width)?;
    let lens = trans
        .field("lensCorrection")
        .and_then(MatValue::as_scalar)
        .unwrap_or(0.0);

    // The acquisitions of frame 1 of buffer 1, in event order, and the transmit each fires.
    let receives = elements(&receive);
    let in_frame_1 = |i: usize| {
        receives.get(i).is_some_and(|m| {
            number(m, "framenum").unwrap_or(1.0) == 1.0 && number(m, "bufnum").unwrap_or(1.0) == 1.0
        })
    };
    let tx_list = elements(&tx);
    let mut order: Vec<(usize, usize, Vec<usize>)> = Vec::new(); // (receive, tx, seqControl)
    if let Some(ev) = &events {
        for e in elements(ev) {
            let (Some(t), Some(rc)) = (number(e, "tx"), number(e, "rcv")) else {
                continue;
            };
            if t < 1.0 || rc < 1.0 {
                continue;
            }
            let (t, rc) = (t as usize - 1, rc as usize - 1);
            if in_frame_1(rc) && !order.iter().any(|(q, _, _)| *q == rc) {
                let sc = numbers(e.get("seqControl"))
                    .iter()
                    .map(|v| *v as usize)
                    .collect();
                order.push((rc, t, sc));
            }
        }
    } else {
        for i in (0..receives.len()).filter(|&i| in_frame_1(i)) {
            let t = if tx_list.len() == 1 { 0 } else { i };
            order.push((i, t, vec![]));
        }
    }
    if order.is_empty() {
        return Err(IoError::invalid(
            path,
            "Receive",
            "has no acquisition of frame 1 (framenum = 1)",
        ));
    }
    let mut rows = Vec::with_capacity(order.len());
    let mut t0s = Vec::with_capacity(order.len());
    let mut fs_all = Vec::with_capacity(order.len());
    let mut angles_per_acq = Vec::with_capacity(order.len());
    let mut intervals = Vec::new();
    let mut modes = Vec::with_capacity(order.len());
    let mut demods = Vec::with_capacity(order.len());
    let mut silent_elements: Vec<Vec<usize>> = Vec::with_capacity(order.len());
    let tw = h5.exists("TW").then(|| read("TW").ok()).flatten();
    let waveforms = tw.as_ref().map(elements).unwrap_or_default();
    let mut peaks_given = false;
    let controls = seq_control.as_ref().map(elements).unwrap_or_default();
    for (rc, t, sc) in &order {
        let m = receives[*rc];
        let field_of = |n: &str| format!("Receive({}).{n}", rc + 1);
        let start = need(number(m, "startSample"), &field_of("startSample"))?;
        let end = need(number(m, "endSample"), &field_of("endSample"))?;
        if !(start >= 1.0 && end >= start && end < 1e12) {
            return Err(IoError::invalid(
                path,
                field_of("endSample"),
                format!("rows {start}..{end} are not a range of samples"),
            ));
        }
        rows.push(start as usize - 1..end as usize);
        // Channels a Receive's Apod leaves out are not written by it: they hold whatever the
        // buffer held there (zeros, or what an earlier acquisition left), not its echoes.
        let apod = numbers(m.get("Apod"));
        let silent: Vec<usize> = if apod.len() == n_el {
            (0..n_el).filter(|&e| apod[e] == 0.0).collect()
        } else {
            Vec::new()
        };
        silent_elements.push(silent);
        let rate = need(number(m, "decimSampleRate"), &field_of("decimSampleRate"))?;
        let quad = number(m, "quadDecim").unwrap_or(1.0);
        fs_all.push(rate / quad * 1e6);
        let mode_name = m.get("sampleMode").and_then(MatValue::as_str);
        let mode = SampleMode::of(mode_name).ok_or_else(|| {
            IoError::invalid(
                path,
                field_of("sampleMode"),
                format!(
                    "is {:?}; pcuvd reads NS200BW, BS67BW, custom (RF at decimSampleRate) and \
                     BS100BW, BS50BW (I/Q pairs)",
                    mode_name.unwrap_or_default()
                ),
            )
        })?;
        modes.push((mode, mode_name.unwrap_or("NS200BW").to_string()));
        demods.push(number(m, "demodFrequency"));
        let depth = need(number(m, "startDepth"), &field_of("startDepth"))?;
        let txm = tx_list.get(*t).ok_or_else(|| {
            IoError::invalid(
                path,
                format!("Event tx {}", t + 1),
                "names a TX that does not exist",
            )
        })?;
        // The transmit's waveform peaks TW.peak wavelengths (periods) after its firing, and
        // pcuvd's time origin is the pulse's centre leaving the first element.
        let waveform = number(txm, "waveform").map_or(0, |w| (w.max(1.0) as usize) - 1);
        let peak = waveforms
            .get(waveform)
            .and_then(|w| number(w, "peak"))
            .filter(|p| p.is_finite());
        peaks_given |= peak.is_some();
        t0s.push(
            2.0 * depth * wavelength / c
                - 2.0 * lens * wavelength / c
                - peak.unwrap_or(0.0) * wavelength / c,
        );
        if number(txm, "focus").is_some_and(|f| f != 0.0) {
            return Err(IoError::invalid(
                path,
                format!("TX({}).focus", t + 1),
                "is not 0: a focused or diverging transmit; pcuvd reads plane waves",
            ));
        }
        let steer = numbers(txm.get("Steer"));
        angles_per_acq.push(steer.first().copied().unwrap_or(0.0));
        for k in sc {
            if let Some(ctl) = controls.get(k.wrapping_sub(1))
                && ctl.get("command").and_then(MatValue::as_str) == Some("timeToNextAcq")
                && let Some(us) = number(ctl, "argument")
            {
                intervals.push(us * 1e-6);
            }
        }
    }
    let left_out = silent_elements.iter().filter(|s| !s.is_empty()).count();
    if left_out > 0 {
        warnings.push(format!(
            "Receive.Apod leaves elements out of {left_out} of the frame's {} acquisitions (up to \
             {} elements): their samples read as zero",
            silent_elements.len(),
            silent_elements.iter().map(Vec::len).max().unwrap_or(0)
        ));
    }
    let fs = fs_all[0];
    if fs_all.iter().any(|&f| f != fs) {
        return Err(IoError::invalid(
            path,
            "Receive.decimSampleRate",
            "differs between acquisitions",
        ));
    }
    let (mode, mode_name) = modes[0].clone();
    if modes.iter().any(|(m, _)| *m != mode) {
        return Err(IoError::invalid(
            path,
            "Receive.sampleMode",
            "differs between acquisitions",
        ));
    }
    // decimSampleRate / quadDecim: the stored samples' rate (the RF's, in the RF modes).
    let stored_rate = fs;
    let pairs_demod_frequency = match mode {
        SampleMode::Rf => None,
        SampleMode::Pairs { .. } => {
            let first = demods[0];
            if demods.iter().any(|d| *d != first) {
                return Err(IoError::invalid(
                    path,
                    "Receive.demodFrequency",
                    "differs between acquisitions",
                ));
            }
            let found = first.map(|d| {
                (
                    d * 1e6,
                    derived(format!(
                        "Receive({}).demodFrequency (MHz) × 10⁶",
                        order[0].0 + 1
                    )),
                )
            });
            let demod = r.number("demod_frequency_hz", found, None, || {
                IoError::missing(
                    path,
                    "the Verasonics workspace",
                    format!(
                        "Receive.demodFrequency, at which {mode_name}'s I/Q pairs are taken (or \
                         give --demod-freq-hz)"
                    ),
                )
            })?;
            Some(positive(path, "Receive.demodFrequency", demod)?)
        }
    };
    let (fs, fs_source) = match (mode, pairs_demod_frequency) {
        (SampleMode::Pairs { every }, Some(demod)) => {
            let periods = every / 4;
            let iq_rate = demod / periods as f64;
            let spacing = if periods == 1 {
                "period"
            } else {
                "two periods"
            };
            // Readers of these modes take decimSampleRate / quadDecim as the stored samples'
            // rate, two a pair (zea's converter), or as the A/D's, 4 f_d: either agrees with
            // the pairs; anything else describes other samples than these.
            let agrees = |rate: f64| (stored_rate - rate).abs() <= 1e-6 * rate;
            if !agrees(2.0 * iq_rate) && !agrees(4.0 * demod) {
                return Err(IoError::invalid(
                    path,
                    "Receive.decimSampleRate",
                    format!(
                        "/ quadDecim is {:.6} MHz, but {mode_name} at a demodFrequency of {:.6} \
                         MHz stores {:.6} MHz of samples (an I/Q pair every {}) from an A/D at \
                         {:.6} MHz",
                        stored_rate * 1e-6,
                        demod * 1e-6,
                        2.0 * iq_rate * 1e-6,
                        spacing,
                        4.0 * demod * 1e-6
                    ),
                ));
            }
            (
                iq_rate,
                format!(
                    "Receive(1).demodFrequency × 10⁶{} ({mode_name}: an I/Q pair every {spacing})",
                    if periods == 1 { "" } else { " / 2" },
                ),
            )
        }
        _ => (
            stored_rate,
            "Receive(1).decimSampleRate (MHz) / quadDecim × 10⁶".to_string(),
        ),
    };
    let fs = r.known("sampling_frequency_hz", (fs, derived(fs_source)));
    let fs = positive(path, "Receive.decimSampleRate", fs)?;
    let band = numbers(trans.field("Bandwidth"));
    // Resolved once the sampling is known, which decides the default's width.
    let bandwidth = resolve_bandwidth(
        &mut r,
        (band.len() == 2).then(|| {
            (
                (band[1] - band[0]) / f_mhz,
                derived("Trans.Bandwidth ([low high] MHz) / Trans.frequency"),
            )
        }),
        (DEFAULT_BANDWIDTH, "Trans.Bandwidth is absent: pcuvd's"),
        fc,
        fs,
    );
    let bandwidth = positive(path, "Trans.Bandwidth", bandwidth)?;
    // Receive.mode 1 accumulates an acquisition into rows another already filled: the buffer
    // then holds their sum, which no reading can take apart.
    for (i, a) in rows.iter().enumerate() {
        if let Some((j, _)) = rows[..i]
            .iter()
            .enumerate()
            .find(|(_, b)| a.start < b.end && b.start < a.end)
        {
            return Err(IoError::invalid(
                path,
                format!("Receive({}).startSample", order[i].0 + 1),
                format!(
                    "puts its samples in rows that Receive({}) fills too (Receive.mode 1 \
                     accumulates acquisitions): pcuvd reads one acquisition per rows",
                    order[j].0 + 1
                ),
            ));
        }
    }
    let n_rows = rows[0].len();
    if rows.iter().any(|r| r.len() != n_rows) {
        return Err(IoError::invalid(
            path,
            "Receive.endSample",
            "acquisitions of different lengths are not supported",
        ));
    }
    let n_samples = match mode {
        SampleMode::Rf => n_rows,
        SampleMode::Pairs { .. } if n_rows % 2 == 0 => n_rows / 2,
        SampleMode::Pairs { .. } => {
            return Err(IoError::invalid(
                path,
                "Receive.endSample",
                format!(
                    "{mode_name} stores I/Q pairs, but an acquisition holds {n_rows} rows, an odd count"
                ),
            ));
        }
    };
    if let Some(demod) = pairs_demod_frequency {
        // Complex samples at f_s hold a band f_s wide around f_d; the probe's wider band folds.
        let band = fc * bandwidth;
        let (low, high) = (fc - band / 2.0 - demod, fc + band / 2.0 - demod);
        if low < -fs / 2.0 || high > fs / 2.0 {
            warnings.push(format!(
                "{mode_name}'s I/Q pairs at {:.4} MHz hold {:.3}–{:.3} MHz; the probe's band \
                 {:.3}–{:.3} MHz (bandwidth {:.0} %) is wider, and its edges fold onto the band",
                fs * 1e-6,
                (demod - fs / 2.0) * 1e-6,
                (demod + fs / 2.0) * 1e-6,
                (fc - band / 2.0) * 1e-6,
                (fc + band / 2.0) * 1e-6,
                bandwidth * 100.0
            ));
        }
    }
    let t0 = r.known(
        "t0_s",
        (
            common_t0(
                path,
                if peaks_given {
                    "Receive.startDepth with TW(TX.waveform).peak"
                } else {
                    "Receive.startDepth"
                },
                &t0s,
                fs,
            )?,
            derived(if peaks_given {
                "2·Receive.startDepth·λ/c − 2·Trans.lensCorrection·λ/c − TW(TX.waveform).peak·λ/c \
                 (λ = c / Trans.frequency)"
            } else {
                "2·Receive.startDepth·λ/c − 2·Trans.lensCorrection·λ/c (λ = c / Trans.frequency; \
                 TW.peak is absent: the pulse taken as centred on its firing)"
            }),
        ),
    );
    // The compound frame: the shortest period of the acquisitions' steering.
    let apf = angles_per_acq.len();
    let period = (1..=apf)
        .filter(|n| apf % n == 0)
        .find(|&n| (0..apf).all(|i| (angles_per_acq[i] - angles_per_acq[i % n]).abs() < 1e-9))
        .unwrap_or(apf);
    let angles = r.angles((
        angles_per_acq[..period].to_vec(),
        derived("TX(Event.tx).Steer(1), in event order"),
    ));
    let prf_found = if intervals.is_empty() {
        None
    } else {
        let mut s = intervals.clone();
        s.sort_by(f64::total_cmp);
        Some((
            1.0 / s[s.len() / 2],
            derived("1 / SeqControl(Event.seqControl) timeToNextAcq (µs)"),
        ))
    };
    let prf = r.number("event_prf_hz", prf_found, None, || {
        missing_prf(path, "SeqControl timeToNextAcq")
    })?;
    let prf = positive(path, "event_prf_hz", prf)?;
    let half_cycles = waveforms
        .first()
        .map(|m| numbers(m.get("Parameters")))
        .and_then(|p| p.get(2).copied());
    let pulse_cycles = r.or_default(
        "pulse_cycles",
        half_cycles.map(|h| (h / 2.0, derived("TW(1).Parameters(3) (half cycles) / 2"))),
        (DEFAULT_PULSE_CYCLES, "TW.Parameters is absent"),
    );
    r.record(
        "coding",
        json!("none"),
        ParamSource::Default {
            note: "one transmit per Verasonics event".into(),
        },
    );

    // The receive buffer.
    let buffers = h5.references("RcvData")?;
    let dataset = buffers
        .first()
        .cloned()
        .ok_or_else(|| IoError::invalid(path, "RcvData", "is an empty cell"))?;
    let (shape, kind) = h5.describe(&dataset)?;
    if kind
        != (crate::hdf5::H5Kind::Int {
            size: 2,
            signed: true,
        })
    {
        return Err(IoError::invalid(
            path,
            "RcvData{1}",
            format!("holds {kind:?}; expected int16"),
        ));
    }
    let (n_buffer_frames, channels, buffer_rows, has_frame_axis) = match shape.as_slice() {
        [f, ch, rw] => (*f, *ch, *rw, true),
        [ch, rw] => (1, *ch, *rw, false),
        other => {
            return Err(IoError::invalid(
                path,
                "RcvData{1}",
                format!("has HDF5 shape {other:?}; expected (frames, channels, rows)"),
            ));
        }
    };
    let (columns, channel_map) = element_columns(path, &trans, n_el, channels, &mut warnings)?;
    crate::array::check_frame_size(path, rows.len(), channels.max(n_el), n_samples)?;
    if rows.iter().any(|r| r.end > buffer_rows) {
        return Err(IoError::invalid(
            path,
            "Receive.endSample",
            format!("reaches past the buffer's {buffer_rows} rows"),
        ));
    }
    let rcv_buffer = struct_field(&resource, "RcvBuffer")
        .map(elements)
        .unwrap_or_default();
    let num_frames = rcv_buffer.first().and_then(|m| number(m, "numFrames"));
    if let Some(nf) = num_frames
        && nf as usize != n_buffer_frames
    {
        warnings.push(format!("Resource.RcvBuffer.numFrames is {nf} but RcvData{{1}} holds {n_buffer_frames} frames; the data's count is used"));
    }
    let first_slot = match rcv_buffer.first().and_then(|m| number(m, "lastFrame")) {
        Some(last) if last >= 1.0 && (last as usize) <= n_buffer_frames => {
            last as usize % n_buffer_frames
        }
        Some(last) => {
            return Err(IoError::invalid(
                path,
                "Resource.RcvBuffer.lastFrame",
                format!("is {last}, outside 1..{n_buffer_frames}"),
            ));
        }
        None => {
            warnings.push("Resource.RcvBuffer.lastFrame is absent: the buffer's frames are taken in stored order".into());
            0
        }
    };
    let acquisition = PlaneWaveAcquisition {
        probe: pcuvd::Probe {
            name: trans
                .field("name")
                .and_then(MatValue::as_str)
                .unwrap_or("Verasonics")
                .to_string(),
            n_elements: n_el,
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
    let stored = StoredSamples {
        array: format!("{}:RcvData{{1}} ({dataset})", path.display()),
        shape: shape.clone(),
        axes: {
            let rows = if pairs_demod_frequency.is_some() {
                "rows (acquisitions × interleaved I/Q pairs)"
            } else {
                "rows (acquisitions × samples)"
            };
            let mut axes = vec!["channels".to_string(), rows.to_string()];
            if has_frame_axis {
                axes.insert(0, "buffer frames".into());
            }
            axes
        },
        dtype: "int16".into(),
        kind: if pairs_demod_frequency.is_some() {
            "iq".into()
        } else {
            "rf".into()
        },
    };
    let frames = VerasonicsFrames {
        acquisition,
        path: path.to_path_buf(),
        dataset,
        n_buffer_frames,
        first_slot,
        rows,
        columns,
        silent_elements,
        buffer_channels: channels,
        has_frame_axis,
        pairs_demod_frequency,
    };
    Ok(OpenedRecording {
        source: Box::new(frames),
        read_pass: None,
        info: SourceInfo {
            files: vec![path.to_path_buf()],
            format: "Verasonics workspace (MATLAB v7.3)".into(),
            reader: format!(
                "pcuvd_io::verasonics (rust-hdf5, a block of buffer frames at a time, circular \
                 buffer reordered{})",
                channel_map.map_or(String::new(), |m| format!(", element channels by {m}"))
            ),
            parameters: r.params,
            stored: Some(stored),
            warnings,
            cardiac_triggers_s: None,
        },
    })
}

/// The buffer column (0-based) of each of the `n_el` elements: `Trans.ConnectorES`, else
/// `Trans.Connector` (1-based channels, one per element, each at most once), else element e in
/// column e when the buffer has one column per element; with the field that said so.
fn element_columns(
    path: &Path,
    trans: &MatValue,
    n_el: usize,
    channels: usize,
    warnings: &mut Vec<String>,
) -> Result<(Vec<usize>, Option<String>), IoError> {
    let Some((name, map)) = ["ConnectorES", "Connector"].iter().find_map(|name| {
        let map = numbers(trans.field(name));
        (!map.is_empty()).then(|| (format!("Trans.{name}"), map))
    }) else {
        if channels != n_el {
            return Err(IoError::invalid(
                path,
                "RcvData{1}",
                format!(
                    "has {channels} channels for Trans.ElementPos's {n_el} elements, and \
                     Trans.Connector, which says which channel each element is on, is absent"
                ),
            ));
        }
        warnings.push(
            "Trans.Connector is absent: RcvData's channels are taken as the probe's elements in \
             order"
                .into(),
        );
        return Ok(((0..n_el).collect(), None));
    };
    if map.len() != n_el {
        return Err(IoError::invalid(
            path,
            &name,
            format!("lists {} channels for {n_el} elements", map.len()),
        ));
    }
    let mut columns = Vec::with_capacity(n_el);
    for (element, &channel) in map.iter().enumerate() {
        if !(channel >= 1.0 && channel <= channels as f64 && channel.fract() == 0.0) {
            return Err(IoError::invalid(
                path,
                &name,
                format!(
                    "puts element {} on channel {channel}, not one of RcvData's channels 1–{channels}",
                    element + 1
                ),
            ));
        }
        let column = channel as usize - 1;
        if columns.contains(&column) {
            let why = if trans.field("HVMux").is_some() {
                ": a multiplexed probe (Trans.HVMux), whose channels each Receive's aperture \
                 switches between elements; pcuvd reads one element per channel"
            } else {
                ""
            };
            return Err(IoError::invalid(
                path,
                &name,
                format!("puts two elements on channel {channel}{why}"),
            ));
        }
        columns.push(column);
    }
    Ok((columns, Some(name)))
}

/// A block of frames being read: RF, or IQ taken to baseband at absolute time by `rotation`.
enum Block {
    Rf(Array3<f32>),
    Iq {
        data: Array3<Complex32>,
        rotation: Complex32,
        demod_frequency: f64,
    },
}

impl VerasonicsFrames {
    /// Copies the acquisitions of buffer frame `vframe` (chronological; `frame` its slice of the
    /// buffer, columns `width` rows wide from row `lo`) that fall in `events` into `block`.
    fn copy_frame(
        &self,
        vframe: usize,
        frame: &[i16],
        width: usize,
        lo: usize,
        events: &Range<usize>,
        block: &mut Block,
    ) {
        let apf = self.rows.len();
        for (acq, rows) in self.rows.iter().enumerate() {
            let e = vframe * apf + acq;
            if !events.contains(&e) {
                continue;
            }
            let k = e - events.start;
            let rows = rows.start - lo..rows.end - lo;
            let silent = &self.silent_elements[acq];
            for (ch, &column) in self.columns.iter().enumerate() {
                if silent.contains(&ch) {
                    continue;
                }
                let trace = &frame[column * width..][rows.clone()];
                match block {
                    Block::Rf(out) => {
                        for (o, &v) in out.slice_mut(ndarray::s![k, ch, ..]).iter_mut().zip(trace) {
                            *o = f32::from(v);
                        }
                    }
                    Block::Iq { data, rotation, .. } => {
                        for (o, pair) in data
                            .slice_mut(ndarray::s![k, ch, ..])
                            .iter_mut()
                            .zip(trace.chunks_exact(2))
                        {
                            *o =
                                Complex32::new(f32::from(pair[0]), -f32::from(pair[1])) * *rotation;
                        }
                    }
                }
            }
        }
    }

    /// Samples of each trace: the rows of an acquisition, or its I/Q pairs.
    fn samples_per_trace(&self) -> usize {
        let rows = self.rows[0].len();
        if self.pairs_demod_frequency.is_some() {
            rows / 2
        } else {
            rows
        }
    }
}

impl FrameSource for VerasonicsFrames {
    fn acquisition(&self) -> &Acquisition {
        &self.acquisition
    }

    fn n_frames(&self) -> usize {
        self.n_buffer_frames * self.rows.len() / self.acquisition.sequence.n_angles()
    }

    fn trace_shape(&self) -> (usize, usize) {
        (self.columns.len(), self.samples_per_trace())
    }

    fn read_frames(&self, frames: Range<usize>) -> pcuvd::Result<ChannelData> {
        let n = self.acquisition.sequence.n_angles();
        let total = FrameSource::n_frames(self);
        if frames.start >= frames.end || frames.end > total {
            return Err(pcuvd::core::error::invalid(
                "frames",
                format!("block {frames:?} is not within the recording's {total} frames"),
            ));
        }
        let apf = self.rows.len();
        let events = frames.start * n..frames.end * n;
        let samples = self.samples_per_trace();
        let lo = self.rows.iter().map(|r| r.start).min().unwrap_or(0);
        let hi = self.rows.iter().map(|r| r.end).max().unwrap_or(0);
        let width = hi - lo;
        let err = |e: IoError| pcuvd::Error::Read(e.to_string());
        let h5 = Hdf5::open(&self.path).map_err(err)?;
        let ds = h5.dataset(&self.dataset).map_err(err)?;
        let first_vframe = events.start / apf;
        let last_vframe = (events.end - 1) / apf;
        let shape = (events.len(), self.columns.len(), samples);
        let mut block = match self.pairs_demod_frequency {
            None => Block::Rf(Array3::zeros(shape)),
            Some(demod_frequency) => {
                // I − jQ is the analytic signal at the pair's first sample; e^{−2πi f_d t0}
                // takes it to baseband at absolute time (module doc).
                let turn = -std::f64::consts::TAU * demod_frequency * self.acquisition.t0;
                Block::Iq {
                    data: Array3::zeros(shape),
                    rotation: Complex32::new(turn.cos() as f32, turn.sin() as f32),
                    demod_frequency,
                }
            }
        };
        // Buffer frames in runs that lie in one chunk of the dataset along its frame axis, each
        // run copied out before the next is read: a compressed chunk holding several frames
        // is then inflated once per block, not once per frame (a frame at a time inflated each
        // chunk as many times as it has frames), and the raw samples held stay one chunk's.
        let chunk_frames = if self.has_frame_axis {
            ds.chunk_dims()
                .and_then(|c| c.first().copied())
                .unwrap_or(1)
                .max(1)
        } else {
            1
        };
        let frame_len = self.buffer_channels * width;
        let mut vframe = first_vframe;
        while vframe <= last_vframe {
            let slot = (self.first_slot + vframe) % self.n_buffer_frames;
            // The run stops at the block's end, the buffer's end (the circular buffer wraps)
            // and the chunk's.
            let run = (last_vframe - vframe + 1)
                .min(self.n_buffer_frames - slot)
                .min(chunk_frames - slot % chunk_frames);
            let (starts, counts) = if self.has_frame_axis {
                (vec![slot, 0, lo], vec![run, self.buffer_channels, width])
            } else {
                (vec![0, lo], vec![self.buffer_channels, width])
            };
            let buf: Vec<i16> = crate::hdf5::guard(&self.path, "RcvData: read", || {
                ds.read_slice::<i16>(&starts, &counts)
            })
            .map_err(err)?;
            for (offset, frame) in buf.chunks_exact(frame_len).enumerate() {
                self.copy_frame(vframe + offset, frame, width, lo, &events, &mut block);
            }
            vframe += run;
        }
        let samples = match block {
            Block::Rf(out) => Samples::Rf(out),
            Block::Iq {
                data,
                demod_frequency,
                ..
            } => Samples::Iq {
                data,
                demod_frequency,
            },
        };
        Ok(ChannelData {
            acquisition: self.acquisition.clone(),
            samples,
        })
    }
}
