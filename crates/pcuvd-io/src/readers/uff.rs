//! USTB UFF channel data (HDF5): `/channel_data` with `data` (frames, waves, channels, samples —
//! MATLAB's time × channel × wave × frame reversed; complex data as a group of `real` and `imag`),
//! `sampling_frequency`, `initial_time`, `sound_speed`, `modulation_frequency` (0 = RF, else IQ
//! demodulated at it), `PRF` (or `prf`), `pulse/center_frequency`, `pulse/fractional_bandwidth`,
//! `probe/geometry` (7 × N: x, y, z, θ, φ, width, height), and `sequence/sequence_000k`, each a
//! plane wave (`wavefront` 0) steered by `source/azimuth`, with `delay`.
//!
//! Time: USTB's time zero is the instant a wave crosses the origin; sample n of wave k is at
//! `initial_time + delay_k + n/fs` after it. pcuvd's t0 counts from the first element's firing,
//! which precedes the crossing by (N−1)/2·pitch·|sin θ|/c, so t0 = initial_time + delay_k + that
//! (the same for every wave, checked). The waves of the sequence are the events of a compound
//! frame, in order; the PRF is taken per transmit event.

use std::path::Path;

use serde_json::json;

use crate::array::{ArrayFrames, Axis};
use crate::error::IoError;
use crate::hdf5::Hdf5;
use crate::layout::{common_t0, crossing_time, linear_array, positive, scalar};
use crate::params::{Overrides, ParamSource, Resolver, derived, field, missing_prf, missing_t0};
pub use crate::recording::DEFAULT_BANDWIDTH;
use crate::recording::resolve_bandwidth;
use crate::recording::{
    DEFAULT_PULSE_CYCLES, OpenedRecording, PlaneWaveAcquisition, SourceInfo, StoredSamples,
};

/// Opens a UFF file's `/channel_data`.
pub fn open(path: &Path, h5: &Hdf5, overrides: &Overrides) -> Result<OpenedRecording, IoError> {
    let cd = "channel_data";
    let f = |name: &str| format!("{cd}/{name}");
    let mut r = Resolver::new(overrides);
    let req = |name: &str| {
        let n = f(name);
        move || {
            IoError::missing(
                path,
                "group /channel_data",
                format!("dataset '{}'", n.trim_start_matches("channel_data/")),
            )
        }
    };
    let fs = r.number(
        "sampling_frequency_hz",
        scalar(h5, &f("sampling_frequency"))?.map(|v| (v, field(f("sampling_frequency")))),
        None,
        req("sampling_frequency"),
    )?;
    let fs = positive(path, &f("sampling_frequency"), fs)?;
    let c = r.number(
        "sound_speed_m_s",
        scalar(h5, &f("sound_speed"))?.map(|v| (v, field(f("sound_speed")))),
        None,
        req("sound_speed"),
    )?;
    let c = positive(path, &f("sound_speed"), c)?;
    let modulation = scalar(h5, &f("modulation_frequency"))?.unwrap_or(0.0);
    let prf_field = if h5.is_dataset(&f("PRF")) {
        f("PRF")
    } else {
        f("prf")
    };
    let prf = r.number(
        "event_prf_hz",
        scalar(h5, &prf_field)?.map(|v| (v, field(prf_field.clone()))),
        None,
        || missing_prf(path, &f("PRF")),
    )?;
    let prf = positive(path, &prf_field, prf)?;

    // Probe.
    let geometry = f("probe/geometry");
    let (gshape, g) = h5
        .read_f64(&geometry)
        .map_err(|_| IoError::missing(path, "group /channel_data/probe", "dataset 'geometry'"))?;
    let (rows7, n_el) = match gshape.as_slice() {
        [7, n] => (true, *n),
        [n, 7] => (false, *n),
        other => {
            return Err(IoError::invalid(
                path,
                &geometry,
                format!("has shape {other:?}; expected 7 × N (x, y, z, θ, φ, width, height)"),
            ));
        }
    };
    let at = |row: usize, i: usize| {
        if rows7 {
            g[row * n_el + i]
        } else {
            g[i * 7 + row]
        }
    };
    let x: Vec<f64> = (0..n_el).map(|i| at(0, i)).collect();
    let off: Vec<f64> = (0..n_el).flat_map(|i| [at(1, i), at(2, i)]).collect();
    let (n, pitch) = linear_array(path, &geometry, &x, &off)?;
    r.record(
        "n_elements",
        json!(n),
        derived(format!("{geometry} (its N columns)")),
    );
    r.record(
        "pitch_m",
        json!(pitch),
        derived(format!("{geometry} (element x spacing)")),
    );
    let (width, wsrc) = match scalar(h5, &f("probe/element_width"))? {
        Some(w) => (w, field(f("probe/element_width"))),
        None => (at(5, 0), derived(format!("{geometry} (row 6, width)"))),
    };
    let width = positive(path, &f("probe/element_width"), width)?;
    r.record("element_width_m", json!(width), wsrc);
    let fc_field = f("pulse/center_frequency");
    let fc = r.number(
        "center_frequency_hz",
        scalar(h5, &fc_field)?
            .map(|v| (v, field(fc_field.clone())))
            .or((modulation > 0.0).then(|| (modulation, field(f("modulation_frequency"))))),
        None,
        || {
            IoError::invalid(
                path,
                &fc_field,
                "is absent (and the data is RF): give the probe's centre frequency with \
                 --center-freq-hz",
            )
        },
    )?;
    let fc = positive(path, &fc_field, fc)?;
    let bw_field = f("pulse/fractional_bandwidth");
    let bandwidth = resolve_bandwidth(
        &mut r,
        scalar(h5, &bw_field)?.map(|v| (v, field(bw_field.clone()))),
        (
            DEFAULT_BANDWIDTH,
            "pcuvd's when pulse/fractional_bandwidth is absent",
        ),
        fc,
        fs,
    );
    let bandwidth = positive(path, &bw_field, bandwidth)?;

    // Sequence: the waves of a compound frame.
    let seq = f("sequence");
    let waves: Vec<String> = if h5.exists(&format!("{seq}/source")) {
        vec![seq.clone()]
    } else {
        let mut names: Vec<String> = h5
            .members(&seq)
            .map_err(|_| IoError::missing(path, "group /channel_data", "group 'sequence'"))?
            .into_iter()
            .filter(|m| m.starts_with("sequence_"))
            .collect();
        names.sort_by_key(|m| {
            m.trim_start_matches("sequence_")
                .parse::<u64>()
                .unwrap_or(u64::MAX)
        });
        names.into_iter().map(|m| format!("{seq}/{m}")).collect()
    };
    if waves.is_empty() {
        return Err(IoError::invalid(path, &seq, "holds no wave"));
    }
    let initial = scalar(h5, &f("initial_time"))?;
    let mut angles = Vec::with_capacity(waves.len());
    let mut t0s = Vec::with_capacity(waves.len());
    for w in &waves {
        if let Some(kind) = scalar(h5, &format!("{w}/wavefront"))?
            && kind != 0.0
        {
            return Err(IoError::invalid(
                path,
                format!("{w}/wavefront"),
                format!("is {kind} (0 = plane wave): pcuvd reads plane-wave sequences only"),
            ));
        }
        let azimuth = scalar(h5, &format!("{w}/source/azimuth"))?.ok_or_else(|| {
            IoError::missing(path, format!("group /{w}"), "dataset 'source/azimuth'")
        })?;
        if let Some(d) = scalar(h5, &format!("{w}/source/distance"))?
            && d.is_finite()
        {
            return Err(IoError::invalid(
                path,
                format!("{w}/source/distance"),
                format!(
                    "is {d} m: a finite source distance is a focused or diverging wave; pcuvd reads plane waves (distance = Inf)"
                ),
            ));
        }
        let delay = scalar(h5, &format!("{w}/delay"))?.unwrap_or(0.0);
        if let Some(t) = initial {
            t0s.push(t + delay + crossing_time(azimuth, n, pitch, c));
        }
        angles.push(azimuth);
    }
    let t0_found = if initial.is_some() {
        Some((
            common_t0(
                path,
                &format!("{cd}/initial_time and the waves' delay"),
                &t0s,
                fs,
            )?,
            derived(format!(
                "{cd}/initial_time + sequence/*/delay + the time each wave takes from its first \
                 element to the origin (USTB's time zero)"
            )),
        ))
    } else {
        None
    };
    let t0 = r.number("t0_s", t0_found, None, || {
        missing_t0(path, &f("initial_time"))
    })?;
    let angles = r.angles((angles, derived(format!("{seq}/sequence_*/source/azimuth"))));
    r.record(
        "coding",
        json!("none"),
        ParamSource::Default {
            note: "UFF describes one wave per event".into(),
        },
    );
    let pulse_cycles = r.or_default(
        "pulse_cycles",
        None,
        (DEFAULT_PULSE_CYCLES, "UFF does not record the pulse length"),
    );
    let array = crate::datafile::open_hdf5_array(path, &f("data"))?;
    let iq = array.is_complex();
    let demod = if iq || modulation > 0.0 {
        Some(r.known(
            "demod_frequency_hz",
            (modulation, field(f("modulation_frequency"))),
        ))
    } else {
        None
    };
    if iq != demod.is_some_and(|m| m > 0.0) {
        return Err(IoError::invalid(
            path,
            f("modulation_frequency"),
            format!(
                "is {modulation} Hz but the data is {} (0 means RF, real; a frequency means IQ, complex)",
                if iq { "complex" } else { "real" }
            ),
        ));
    }
    let axes = match array.shape.len() {
        4 => vec![Axis::Frames, Axis::Angles, Axis::Channels, Axis::Samples],
        3 => vec![Axis::Events, Axis::Channels, Axis::Samples],
        _ => {
            return Err(IoError::invalid(
                path,
                f("data"),
                format!(
                    "has shape {:?}; expected (frames, waves, channels, samples) or (waves, channels, samples)",
                    array.shape
                ),
            ));
        }
    };
    let acquisition = PlaneWaveAcquisition {
        probe: pcuvd::Probe {
            name: h5
                .attr_string(&f("probe"), "class")
                .unwrap_or_else(|| "UFF probe".into()),
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
    let stored = StoredSamples::of(&array, &axes, iq);
    let frames = ArrayFrames::new(path, acquisition, array, axes, demod)?;
    Ok(OpenedRecording {
        source: Box::new(frames),
        read_pass: None,
        info: SourceInfo {
            files: vec![path.to_path_buf()],
            format: "USTB UFF channel data (HDF5)".into(),
            reader: "pcuvd_io::uff (rust-hdf5 hyperslabs, a block of frames at a time)".into(),
            parameters: r.params,
            stored: Some(stored),
            warnings: vec![],
            cardiac_triggers_s: None,
        },
    })
}
