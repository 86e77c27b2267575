//! Recordings: read from a file or built from arrays, with the acquisition they carry.

use crate::*;

/// A recording: acquisition parameters and samples, held by the Rust library.
#[pyclass(frozen, name = "Recording", module = "pcuvd._pcuvd")]
pub(crate) struct PyRecording {
    pub(crate) data: Arc<ChannelData>,
    /// What it was read or made from, as given.
    pub(crate) input: String,
    /// What the reader reported: files (empty for arrays or a simulation), format, reader, every
    /// acquisition parameter with its source, warnings.
    pub(crate) info: pcuvd_io::SourceInfo,
    /// What `pcuvd.simulate` made it from; `None` for a recording read or given as arrays.
    pub(crate) simulated: Option<Arc<SimulatedFrom>>,
}

/// What a recording `pcuvd.simulate` made came from.
pub(crate) struct SimulatedFrom {
    /// The scenario (TOML): a run is scored against its truth, as a file's run is against the
    /// scenario beside it.
    pub(crate) scenario: String,
    /// The simulator's record (scenario, seed, noise and its definition), as a simulated
    /// file's manifest holds it in `[provenance]`: summary.json's `source.simulation`.
    pub(crate) record: toml::Table,
}

impl PyRecording {
    pub(crate) fn new(
        data: ChannelData,
        files: Vec<PathBuf>,
        input: String,
        format: (&str, &str),
    ) -> Self {
        PyRecording {
            data: Arc::new(data),
            input,
            info: pcuvd_io::SourceInfo {
                files,
                format: format.0.to_string(),
                reader: format.1.to_string(),
                parameters: vec![],
                stored: None,
                warnings: vec![],
                cardiac_triggers_s: None,
            },
            simulated: None,
        }
    }
}

pub(crate) fn probe_json(probe: &Probe) -> Value {
    json!({
        "name": probe.name, "n_elements": probe.n_elements, "pitch_m": probe.pitch,
        "element_width_m": probe.element_width, "center_freq_hz": probe.center_frequency,
        "bandwidth": probe.bandwidth,
    })
}

#[pymethods]
impl PyRecording {
    /// The samples as a new numpy array (events, channels, samples): float32 RF or complex64 IQ.
    fn samples<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        match &self.data.samples {
            Samples::Rf(a) => a.to_pyarray(py).into_any(),
            Samples::Iq { data, .. } => data.to_pyarray(py).into_any(),
        }
    }

    /// Everything known of the acquisition, as JSON (the Python half exposes it as attributes).
    fn acquisition_json(&self) -> String {
        let acq = &self.data.acquisition;
        let seq = &acq.sequence;
        let (coding, slot_delay) = match seq.coding {
            Coding::Conventional => ("none", Value::Null),
            Coding::Hadamard { slot_delay } => ("hadamard", json!(slot_delay)),
            Coding::Matrix(_) => ("matrix", Value::Null),
            Coding::Decoded { .. } => ("decoded", Value::Null),
        };
        let code = seq.transmit_code().ok();
        let demod = match &self.data.samples {
            Samples::Rf(_) => Value::Null,
            Samples::Iq {
                demod_frequency, ..
            } => json!(demod_frequency),
        };
        let (events, channels, samples) = self.data.samples.dim();
        json!({
            "probe": probe_json(&acq.probe),
            "sampling_freq_hz": acq.sampling_frequency,
            "sound_speed_m_s": acq.sound_speed,
            "t0_s": acq.t0,
            "event_prf_hz": seq.event_prf,
            "frame_rate_hz": acq.frame_rate(),
            "angles_rad": seq.angles,
            "coding": coding,
            "slot_delay_s": slot_delay,
            "code_matrix": code.as_ref().map(|c| c.weights.chunks(c.order().max(1)).map(<[f64]>::to_vec).collect::<Vec<_>>()),
            "slot_starts_s": code.as_ref().map(|c| c.slot_starts.clone()),
            "pulse_cycles": seq.pulse_cycles,
            "transmit_pulse": seq.pulse.as_ref().map(|p| json!({"samples": p.samples, "sampling_freq_hz": p.sampling_frequency})),
            "demod_freq_hz": demod,
            "n_events": events, "n_channels": channels, "n_samples": samples,
            "n_frames": self.data.n_frames(),
            "n_angles": seq.n_angles(),
            "nyquist_velocity_m_s": acq.nyquist_velocity(),
            "recorded_depth_m": pcuvd::pipeline::recorded_depth(&self.data),
            "files": self.info.files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
            "input": self.input,
            "format": self.info.format,
            "reader": self.info.reader,
            "parameters": self.info.parameters,
            "stored_samples": self.info.stored,
            "warnings": self.info.warnings,
        })
        .to_string()
    }
}

/// Reads a recording file (any format `pcuvd process` reads), then applies `overrides` (JSON of
/// acquisition fields in SI units) and checks the result.
#[pyfunction]
pub(crate) fn read_recording(
    py: Python<'_>,
    path: PathBuf,
    overrides: &str,
) -> PyResult<PyRecording> {
    let overrides: serde_json::Map<String, Value> =
        serde_json::from_str(overrides).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let reader_overrides = reader_overrides(&overrides)
        .with_context(|| format!("{}: overrides", path.display()))
        .map_err(to_py)?;
    let (mut data, mut info) = py
        .detach(|| -> anyhow::Result<_> {
            let opened = pcuvd_io::open_recording(&path, &reader_overrides)?;
            Ok((opened.read_all()?, opened.info))
        })
        .map_err(to_py)?;
    // The reader names how it reads blocks; this recording was read whole, and the summary of a
    // run from it should not say otherwise.
    info.reader = format!("{}, read whole by pcuvd.read_recording", info.reader);
    apply_overrides(&mut data, &overrides)
        .with_context(|| format!("{}: overrides", path.display()))
        .map_err(to_py)?;
    Ok(PyRecording {
        data: Arc::new(data),
        input: path.display().to_string(),
        info,
        simulated: None,
    })
}

/// The overrides the reader applies itself (so that it records them as the parameters'
/// source, and a file without t0 can be read with `t0_s=`).
pub(crate) fn reader_overrides(
    map: &serde_json::Map<String, Value>,
) -> anyhow::Result<pcuvd_io::Overrides> {
    let angles = match map.get("angles_rad").filter(|v| !v.is_null()) {
        Some(v) => Some(
            serde_json::from_value(v.clone())
                .with_context(|| format!("angles_rad: expected a list of numbers, got {v}"))?,
        ),
        None => None,
    };
    Ok(pcuvd_io::Overrides {
        t0_s: number(map, "t0_s")?,
        sound_speed_m_s: number(map, "sound_speed_m_s")?,
        event_prf_hz: number(map, "event_prf_hz")?,
        sampling_freq_hz: number(map, "sampling_freq_hz")?,
        center_freq_hz: number(map, "center_freq_hz")?,
        demod_freq_hz: None,
        angles_rad: angles,
        pulse_cycles: number(map, "pulse_cycles")?,
        bandwidth: number(map, "bandwidth")?,
        track: match map.get("track") {
            None | Some(Value::Null) => None,
            Some(Value::String(label)) => Some(label.clone()),
            Some(Value::Number(n)) if n.is_u64() => Some(n.to_string()),
            Some(v) => anyhow::bail!("track: expected a track's index or label, got {v}"),
        },
    })
}

pub(crate) fn number(
    map: &serde_json::Map<String, Value>,
    key: &str,
) -> anyhow::Result<Option<f64>> {
    match map.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => v
            .as_f64()
            .map(Some)
            .with_context(|| format!("{key}: expected a number, got {v}")),
    }
}

/// The acquisition fields a user may set or override, in SI units.
pub(crate) const ACQUISITION_KEYS: [&str; 11] = [
    "sampling_freq_hz",
    "sound_speed_m_s",
    "t0_s",
    "event_prf_hz",
    "center_freq_hz",
    "angles_rad",
    "coding",
    "slot_delay_s",
    "pulse_cycles",
    "bandwidth",
    "track",
];

pub(crate) fn apply_overrides(
    data: &mut ChannelData,
    map: &serde_json::Map<String, Value>,
) -> anyhow::Result<()> {
    if let Some(key) = map.keys().find(|k| !ACQUISITION_KEYS.contains(&k.as_str())) {
        anyhow::bail!(
            "unknown acquisition field {key:?}; known: {}",
            ACQUISITION_KEYS.join(", ")
        );
    }
    let acq = &mut data.acquisition;
    if let Some(v) = number(map, "sampling_freq_hz")? {
        acq.sampling_frequency = v;
    }
    if let Some(v) = number(map, "sound_speed_m_s")? {
        acq.sound_speed = v;
    }
    if let Some(v) = number(map, "t0_s")? {
        acq.t0 = v;
    }
    if let Some(v) = number(map, "event_prf_hz")? {
        acq.sequence.event_prf = v;
    }
    if let Some(v) = number(map, "center_freq_hz")? {
        acq.probe.center_frequency = v;
    }
    if let Some(v) = number(map, "pulse_cycles")? {
        acq.sequence.pulse_cycles = v;
    }
    if let Some(v) = number(map, "bandwidth")? {
        acq.probe.bandwidth = v;
    }
    if let Some(v) = map.get("angles_rad").filter(|v| !v.is_null()) {
        acq.sequence.angles = serde_json::from_value(v.clone())
            .with_context(|| format!("angles_rad: expected a list of numbers, got {v}"))?;
    }
    let slot_delay = number(map, "slot_delay_s")?;
    match map.get("coding").and_then(Value::as_str) {
        Some("none" | "conventional") => acq.sequence.coding = Coding::Conventional,
        Some("hadamard") => {
            acq.sequence.coding = Coding::Hadamard {
                slot_delay: slot_delay.context("coding \"hadamard\" needs slot_delay_s")?,
            }
        }
        Some(other) => anyhow::bail!("coding: expected \"none\" or \"hadamard\", got {other:?}"),
        None => {
            if let (Some(d), Coding::Hadamard { slot_delay }) =
                (slot_delay, &mut acq.sequence.coding)
            {
                *slot_delay = d;
            }
        }
    }
    data.validate()?;
    Ok(())
}

pub(crate) fn parse_probe(value: &Value) -> anyhow::Result<Probe> {
    if let Some(name) = value.as_str() {
        return Ok(Probe::preset(name)?);
    }
    let map = value
        .as_object()
        .context("probe: expected a preset name or a dict")?;
    const KEYS: [&str; 7] = [
        "preset",
        "name",
        "n_elements",
        "pitch_m",
        "element_width_m",
        "center_freq_hz",
        "bandwidth",
    ];
    if let Some(key) = map.keys().find(|k| !KEYS.contains(&k.as_str())) {
        anyhow::bail!("probe: unknown field {key:?}; known: {}", KEYS.join(", "));
    }
    let base = match map.get("preset").and_then(Value::as_str) {
        Some(name) => Some(Probe::preset(name)?),
        None => None,
    };
    let field = |key: &str, from_base: Option<f64>| -> anyhow::Result<f64> {
        number(map, key)?
            .or(from_base)
            .with_context(|| format!("probe: {key} is required (or a preset)"))
    };
    let n_elements = match map.get("n_elements") {
        Some(v) => v
            .as_u64()
            .with_context(|| format!("probe: n_elements must be a whole number, got {v}"))?
            as usize,
        None => base
            .as_ref()
            .map(|p| p.n_elements)
            .context("probe: n_elements is required (or a preset)")?,
    };
    let probe = Probe {
        name: map
            .get("name")
            .and_then(Value::as_str)
            .map(str::to_string)
            .or(base.as_ref().map(|p| p.name.clone()))
            .unwrap_or_else(|| "custom".into()),
        n_elements,
        pitch: field("pitch_m", base.as_ref().map(|p| p.pitch))?,
        element_width: field("element_width_m", base.as_ref().map(|p| p.element_width))?,
        center_frequency: field("center_freq_hz", base.as_ref().map(|p| p.center_frequency))?,
        bandwidth: field("bandwidth", base.as_ref().map(|p| p.bandwidth))?,
    };
    probe.validate()?;
    Ok(probe)
}

/// Makes a recording from arrays the user holds: RF float32 or IQ complex64 samples (events,
/// channels, samples) and the acquisition as JSON (probe, f_s, c, t0, event PRF, angles, coding).
#[pyfunction]
#[pyo3(signature = (rf=None, iq=None, demod_freq_hz=None, acquisition="{}"))]
pub(crate) fn recording_from_arrays(
    rf: Option<PyReadonlyArray3<'_, f32>>,
    iq: Option<PyReadonlyArray3<'_, Complex32>>,
    demod_freq_hz: Option<f64>,
    acquisition: &str,
) -> PyResult<PyRecording> {
    let build = || -> anyhow::Result<ChannelData> {
        let map: serde_json::Map<String, Value> = serde_json::from_str(acquisition)?;
        let probe = parse_probe(map.get("probe").context("probe is required")?)?;
        let mut fields = map.clone();
        fields.remove("probe");
        let samples = match (rf, iq) {
            (Some(rf), None) => Samples::Rf(rf.as_array().to_owned()),
            (None, Some(iq)) => Samples::Iq {
                data: iq.as_array().to_owned(),
                demod_frequency: demod_freq_hz.context("IQ samples need demod_freq_hz")?,
            },
            _ => anyhow::bail!("give exactly one of RF or IQ samples"),
        };
        let required = |key: &str| -> anyhow::Result<f64> {
            number(&fields, key)?.with_context(|| format!("{key} is required"))
        };
        let angles: Vec<f64> = serde_json::from_value(
            fields
                .get("angles_rad")
                .cloned()
                .context("angles_rad is required")?,
        )
        .context("angles_rad: expected a list of numbers")?;
        let mut data = ChannelData {
            acquisition: pcuvd::Acquisition {
                probe,
                sequence: Sequence {
                    angles,
                    event_prf: required("event_prf_hz")?,
                    coding: Coding::Conventional,
                    pulse_cycles: number(&fields, "pulse_cycles")?.unwrap_or(2.0),
                    pulse: None,
                },
                sampling_frequency: required("sampling_freq_hz")?,
                sound_speed: number(&fields, "sound_speed_m_s")?.unwrap_or(1540.0),
                t0: required("t0_s")?,
            },
            samples,
        };
        apply_overrides(&mut data, &fields)?;
        Ok(data)
    };
    let data = build().context("recording from arrays").map_err(to_py)?;
    Ok(PyRecording::new(
        data,
        vec![],
        "arrays".into(),
        ("numpy arrays", "pcuvd.Recording.from_arrays"),
    ))
}
