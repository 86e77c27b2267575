//! `pcuvd._pcuvd`: the native half of the `pcuvd` Python package.
//!
//! Every entry calls the library (`pcuvd`, `pcuvd-io`) or the application layer every front end
//! shares (`pcuvd_app`): keyword options arrive as a dict (JSON) that becomes the same typed
//! settings the command line's options are, so a result from Python is the one `pcuvd process` /
//! `simulate` / `paper` gives, with the same defaults and the same messages. Computation runs with the GIL released, on the Rust thread
//! pool. The Python half (`python/pcuvd/`) checks dtypes and shapes, casts, and documents.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use ndarray::{Array2, Axis};
use num_complex::Complex32;
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArray4, PyReadonlyArray2, PyReadonlyArray3,
    ToPyArray,
};
use pcuvd::core::grid::Grid;
use pcuvd::estimate::clutter::{self, ClutterParams, RankCut};
use pcuvd::estimate::vector::{self, Estimator, IrlsParams};
use pcuvd::form::beamform::{self, Apodization, DasParams};
use pcuvd::form::decode::{self, EventAlignment};
use pcuvd::form::iq;
use pcuvd::{AngleSamples, ChannelData, Coding, Probe, Samples, Sequence};
use pcuvd_app::Progress;
use pcuvd_app::progress::Lines;
use pcuvd_app::run::{DynamicsOutcome, Plan, Processed};
use pcuvd_app::settings::{DynamicsSettings, ProcessingSettings};
use pcuvd_app::simulation::SimulationSettings;
use pcuvd_app::study::StudySettings;
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde::Serialize;
use serde::de::DeserializeOwned;
use serde_json::{Value, json};

/// A `ValueError` (or `OSError` when the operating system refused a file) with the message the
/// command line prints for the same error.
fn to_py(error: anyhow::Error) -> PyErr {
    let message = pcuvd_app::one_line(&error);
    // What the file system refused (a missing file, a folder, a pipe, a read error) is an
    // OSError, a missing file a FileNotFoundError, as Python's own open() raises them.
    let missing = error.chain().any(|cause| {
        matches!(
            cause.downcast_ref::<pcuvd_io::IoError>(),
            Some(pcuvd_io::IoError::NotFound { .. })
        )
    });
    let os_refused = error.chain().any(|cause| {
        cause.downcast_ref::<std::io::Error>().is_some()
            || matches!(
                cause.downcast_ref::<pcuvd_io::IoError>(),
                Some(pcuvd_io::IoError::Io { .. } | pcuvd_io::IoError::NotAFile { .. })
            )
    });
    if missing {
        PyFileNotFoundError::new_err(message)
    } else if os_refused {
        PyOSError::new_err(message)
    } else {
        PyValueError::new_err(message)
    }
}

fn lib_err(error: pcuvd::Error) -> PyErr {
    to_py(error.into())
}

/// Settings from keyword options, given as a JSON object by the Python half (`None` values
/// dropped there): a field it does not know, or a value of the wrong kind, is a `ValueError` that
/// names it; checks of the values themselves come later, with the command line's messages.
fn settings<T: DeserializeOwned>(options: &str) -> PyResult<T> {
    serde_json::from_str(options).map_err(|e| PyValueError::new_err(format!("options: {e}")))
}

/// The keyword names settings `T` takes: its fields (as its `Default` serialises them) and
/// `aliases`.
fn field_names<T: Serialize + Default>(aliases: &[&str]) -> Vec<String> {
    let fields = match serde_json::to_value(T::default()) {
        Ok(Value::Object(map)) => map.keys().cloned().collect(),
        _ => Vec::new(),
    };
    fields
        .into_iter()
        .chain(aliases.iter().map(|a| a.to_string()))
        .collect()
}

/// The keyword aliases of [`ProcessingSettings`]: units in the name, as the command line's
/// visible aliases.
const PROCESSING_ALIASES: [&str; 1] = ["grid_mm"];
/// The keyword aliases of [`DynamicsSettings`].
const DYNAMICS_ALIASES: [&str; 1] = ["heart_rate_hz"];

// ---------------------------------------------------------------------------------------------
// Recordings

/// A recording: acquisition parameters and samples, held by the Rust library.
#[pyclass(frozen, name = "Recording", module = "pcuvd._pcuvd")]
struct PyRecording {
    data: Arc<ChannelData>,
    /// What it was read or made from, as given.
    input: String,
    /// What the reader reported: files (empty for arrays or a simulation), format, reader, every
    /// acquisition parameter with its source, warnings.
    info: pcuvd_io::SourceInfo,
}

impl PyRecording {
    fn new(data: ChannelData, files: Vec<PathBuf>, input: String, format: (&str, &str)) -> Self {
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
        }
    }
}

fn probe_json(probe: &Probe) -> Value {
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
fn read_recording(py: Python<'_>, path: PathBuf, overrides: &str) -> PyResult<PyRecording> {
    let overrides: serde_json::Map<String, Value> =
        serde_json::from_str(overrides).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let reader_overrides = reader_overrides(&overrides)
        .with_context(|| format!("{}: overrides", path.display()))
        .map_err(to_py)?;
    let (mut data, info) = py
        .detach(|| -> anyhow::Result<_> {
            let opened = pcuvd_io::open_recording(&path, &reader_overrides)?;
            Ok((opened.read_all()?, opened.info))
        })
        .map_err(to_py)?;
    apply_overrides(&mut data, &overrides)
        .with_context(|| format!("{}: overrides", path.display()))
        .map_err(to_py)?;
    Ok(PyRecording {
        data: Arc::new(data),
        input: path.display().to_string(),
        info,
    })
}

/// The overrides the reader applies itself (so that it records them as the parameters'
/// source, and a file without t0 can be read with `t0_s=`).
fn reader_overrides(map: &serde_json::Map<String, Value>) -> anyhow::Result<pcuvd_io::Overrides> {
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

fn number(map: &serde_json::Map<String, Value>, key: &str) -> anyhow::Result<Option<f64>> {
    match map.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => v
            .as_f64()
            .map(Some)
            .with_context(|| format!("{key}: expected a number, got {v}")),
    }
}

/// The acquisition fields a user may set or override, in SI units.
const ACQUISITION_KEYS: [&str; 11] = [
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

fn apply_overrides(
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

fn parse_probe(value: &Value) -> anyhow::Result<Probe> {
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
fn recording_from_arrays(
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

// ---------------------------------------------------------------------------------------------
// process

/// `pcuvd process`'s options, without the input and the output folder: keywords split between
/// the processing and the dynamics settings by their names.
struct ProcessCall {
    options: ProcessingSettings,
    dynamics: DynamicsSettings,
    max_memory_gb: Option<f64>,
}

impl ProcessCall {
    fn from_json(options: &str) -> PyResult<Self> {
        let mut map: serde_json::Map<String, Value> = settings(options)?;
        let max_memory_gb = match map.remove("max_memory_gb") {
            None | Some(Value::Null) => None,
            Some(v) => Some(v.as_f64().ok_or_else(|| {
                PyValueError::new_err(format!("max_memory_gb: expected a number, got {v}"))
            })?),
        };
        let dynamics_keys = field_names::<DynamicsSettings>(&DYNAMICS_ALIASES);
        let (dynamics, processing): (serde_json::Map<_, _>, serde_json::Map<_, _>) = map
            .into_iter()
            .partition(|(key, _)| dynamics_keys.contains(key));
        Ok(ProcessCall {
            options: settings(&Value::Object(processing).to_string())?,
            dynamics: settings(&Value::Object(dynamics).to_string())?,
            max_memory_gb,
        })
    }
}

/// What `pcuvd.process` returns: the maps, the summary, and `save` writing what the CLI writes.
#[pyclass(frozen, name = "ProcessResult", module = "pcuvd._pcuvd")]
struct PyProcessResult {
    /// The processing settings it ran with (a dynamics re-run keeps them).
    options: ProcessingSettings,
    recording: Arc<ChannelData>,
    input: String,
    info: pcuvd_io::SourceInfo,
    plan: Plan,
    processed: Processed,
}

/// Runs `pcuvd process`'s chain on `recording` with the keyword options in `options` (JSON).
#[pyfunction]
fn process(
    py: Python<'_>,
    recording: &PyRecording,
    options: &str,
    quiet: bool,
) -> PyResult<PyProcessResult> {
    let call = ProcessCall::from_json(options)?;
    let data = recording.data.clone();
    let progress = Lines::new(quiet);
    let input = &recording.input;
    let (plan, processed) = py
        .detach(|| -> anyhow::Result<(Plan, Processed)> {
            // As `pcuvd process`: options and memory are checked before any work.
            let plan = Plan::new(
                &call.options,
                &call.dynamics,
                &*data,
                recording.info.cardiac_triggers_s.as_deref(),
            )?;
            pcuvd_app::memory::check_memory(&*data, &plan, call.max_memory_gb)?;
            let processed = pcuvd_app::run(&*data, &plan, &progress)
                .with_context(|| format!("{input}: processing failed"))?;
            Ok((plan, processed))
        })
        .map_err(to_py)?;
    let coded = data.acquisition.sequence.is_coded();
    if let Some(warning) =
        pcuvd::pipeline::dealias_warning(plan.params.dealias, coded, &processed.out)
    {
        let message = std::ffi::CString::new(format!("{input}: {warning}"))
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        PyErr::warn(
            py,
            &py.get_type::<pyo3::exceptions::PyUserWarning>(),
            &message,
            1,
        )?;
    }
    Ok(PyProcessResult {
        options: call.options,
        recording: data,
        input: recording.input.clone(),
        info: recording.info.clone(),
        plan,
        processed,
    })
}

impl PyProcessResult {
    fn source(&self) -> anyhow::Result<pcuvd_app::summary::Provenance> {
        pcuvd_app::summary::provenance(
            &self.input,
            &self.info,
            &self.plan.options_text,
            vec![format!("python: pcuvd.process({:?})", self.input)],
            pcuvd_app::outputs::Checksum::default(),
        )
    }
}

#[pymethods]
impl PyProcessResult {
    /// Every map `pcuvd process` writes as .npy, by file stem: numpy arrays in SI units.
    fn arrays<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let out = &self.processed.out;
        let dict = PyDict::new(py);
        dict.set_item("x", PyArray1::from_slice(py, &out.grid.x))?;
        dict.set_item("z", PyArray1::from_slice(py, &out.grid.z))?;
        dict.set_item("bmode_db", out.bmode_db.to_pyarray(py))?;
        dict.set_item("power_doppler", out.power_doppler.to_pyarray(py))?;
        dict.set_item("color_doppler", out.color_doppler.to_pyarray(py))?;
        let signed = out.signed_power_doppler();
        dict.set_item("signed_power_doppler", signed.into_pyarray(py))?;
        dict.set_item("projections", out.projections.to_pyarray(py))?;
        dict.set_item("projection_nyquist", out.projection_nyquist.to_pyarray(py))?;
        if let (Some(ls), Some(irls)) = (&out.vector_ls, &out.vector_irls) {
            dict.set_item("vx", irls.vx.to_pyarray(py))?;
            dict.set_item("vz", irls.vz.to_pyarray(py))?;
            dict.set_item("speed", irls.speed().into_pyarray(py))?;
            dict.set_item("vx_ls", ls.vx.to_pyarray(py))?;
            dict.set_item("vz_ls", ls.vz.to_pyarray(py))?;
            dict.set_item("speed_ls", ls.speed().into_pyarray(py))?;
        }
        if let Some(done) = &out.dealias {
            dict.set_item("alias_counts", done.irls.alias_counts.to_pyarray(py))?;
            dict.set_item("alias_counts_ls", done.ls.alias_counts.to_pyarray(py))?;
        }
        if let DynamicsOutcome::Done { series, maps } = &self.processed.dynamics {
            dict.set_item("ri", maps.ri.to_pyarray(py))?;
            dict.set_item("psv", maps.psv.to_pyarray(py))?;
            dict.set_item("edv", maps.edv.to_pyarray(py))?;
            dict.set_item("psv_spread", maps.psv_spread.to_pyarray(py))?;
            dict.set_item("edv_spread", maps.edv_spread.to_pyarray(py))?;
            dict.set_item("ri_spread", maps.ri_spread.to_pyarray(py))?;
            dict.set_item("vessel_class", maps.vessel_class.to_pyarray(py))?;
            dict.set_item("flow_up", maps.flow_up.mapv(u8::from).into_pyarray(py))?;
            dict.set_item("speed_series", series.speed().into_pyarray(py))?;
            dict.set_item("times", PyArray1::from_slice(py, &series.times_s))?;
        }
        if let Some(ensembles) = &self.processed.ensembles {
            let maps = [
                (
                    "ensemble_power_doppler",
                    Some(ensembles.power_doppler.clone()),
                ),
                (
                    "ensemble_color_doppler",
                    Some(ensembles.color_doppler.clone()),
                ),
                (
                    "ensemble_signed_power_doppler",
                    Some(ensembles.signed_power_doppler()),
                ),
                ("ensemble_vx", ensembles.vx.clone()),
                ("ensemble_vz", ensembles.vz.clone()),
                ("ensemble_speed", ensembles.speed()),
            ];
            for (name, map) in maps {
                if let Some(map) = map {
                    dict.set_item(name, map.into_pyarray(py))?;
                }
            }
            dict.set_item(
                "ensemble_times",
                PyArray1::from_slice(py, &ensembles.times_s),
            )?;
        }
        Ok(dict)
    }

    /// The same maps with the dynamics stage run again with the keyword options in `options`
    /// (JSON: heart rate, windows, RI thresholds, vessel tests, pooling).
    fn with_dynamics(&self, py: Python<'_>, options: &str, quiet: bool) -> PyResult<Self> {
        let dynamics: DynamicsSettings = settings(options)?;
        let progress = Lines::new(quiet);
        let (plan, dynamics, seconds) = py
            .detach(|| -> anyhow::Result<_> {
                let plan = Plan::new(
                    &self.options,
                    &dynamics,
                    &*self.recording,
                    self.info.cardiac_triggers_s.as_deref(),
                )?;
                let clock = std::time::Instant::now();
                let dynamics = pcuvd_app::run::run_dynamics(&self.processed.out, &plan, &progress)?;
                Ok((plan, dynamics, clock.elapsed().as_secs_f64()))
            })
            .map_err(to_py)?;
        Ok(PyProcessResult {
            options: self.options.clone(),
            recording: self.recording.clone(),
            input: self.input.clone(),
            info: self.info.clone(),
            plan,
            processed: Processed {
                out: self.processed.out.clone(),
                dynamics,
                dynamics_s: seconds,
                ensembles: self.processed.ensembles.clone(),
                blocks: self.processed.blocks,
                segments: self.processed.segments.clone(),
            },
        })
    }

    /// The summary.json this result would be saved with (less the writing timings), as JSON.
    fn summary_json(&self) -> PyResult<String> {
        let source = self.source().map_err(to_py)?;
        let summary =
            pcuvd_app::summary::Summary::of(&*self.recording, &self.plan, &self.processed, source);
        serde_json::to_string(&summary).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// Writes into `folder` exactly what `pcuvd process` writes (maps, figures, summary.json last);
    /// a folder that holds anything is refused unless `force`. `nifti`: also the NIfTI images,
    /// named by map, or by BIDS entities `bids` = (subject, session, task). Returns the figures.
    #[pyo3(signature = (folder, force, nifti=false, bids=(None, None, None)))]
    fn save(
        &self,
        py: Python<'_>,
        folder: PathBuf,
        force: bool,
        nifti: bool,
        bids: (Option<String>, Option<String>, Option<String>),
    ) -> PyResult<Vec<PathBuf>> {
        let (subject, session, task) = bids;
        let naming = pcuvd_app::nifti::NiftiNaming::requested(nifti, subject, session, task)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        py.detach(|| -> anyhow::Result<Vec<PathBuf>> {
            let clock = std::time::Instant::now();
            let source = self.source()?;
            let checksum_s = clock.elapsed().as_secs_f64();
            pcuvd_app::outputs::prepare(
                &folder,
                pcuvd_app::outputs::PROCESS_OUTPUTS,
                &self.info.files,
                force,
            )?;
            let name = std::path::Path::new(&self.input)
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            pcuvd_app::summary::save(
                &folder,
                &*self.recording,
                &self.plan,
                &self.processed,
                pcuvd_app::summary::Record {
                    source,
                    name: &name,
                    extra_timings: &[("checksum", checksum_s)],
                    nifti: naming.as_ref(),
                },
                &Lines::new(true),
            )
        })
        .map_err(to_py)
    }
}

// ---------------------------------------------------------------------------------------------
// Stage functions on plain arrays

fn alignment(name: &str) -> PyResult<EventAlignment> {
    match name {
        "mid-frame" | "mid_frame" => Ok(EventAlignment::MidFrame),
        "simultaneous" => Ok(EventAlignment::Simultaneous),
        other => Err(PyValueError::new_err(format!(
            "alignment {other:?}: expected \"mid-frame\" or \"simultaneous\""
        ))),
    }
}

/// Decodes Hadamard-coded RF (events, channels, samples) of `n_angles` slots `slot_delay_s`
/// apart into per-angle RF (angles, frames, channels, samples).
#[pyfunction]
fn decode_hadamard_rf<'py>(
    py: Python<'py>,
    rf: PyReadonlyArray3<'py, f32>,
    n_angles: usize,
    slot_delay_s: f64,
    sampling_freq_hz: f64,
    alignment_name: &str,
) -> PyResult<Bound<'py, PyArray4<f32>>> {
    let align = alignment(alignment_name)?;
    let samples = Samples::Rf(rf.as_array().to_owned());
    let decoded = py
        .detach(|| {
            decode::Decoder::hadamard(
                n_angles,
                Some(slot_delay_s * sampling_freq_hz),
                sampling_freq_hz,
                align,
            )?
            .decode(&samples)
        })
        .map_err(lib_err)?;
    match decoded {
        AngleSamples::Rf(a) => Ok(a.into_pyarray(py)),
        AngleSamples::Iq { .. } => unreachable!("RF in, RF out"),
    }
}

/// Demodulates RF (frames, channels, samples) to IQ of the same shape (complex64), as the
/// pipeline does: mixing at `demod_freq_hz` with time origin `t0_s`, then the zero-phase low-pass.
#[pyfunction]
#[pyo3(signature = (rf, sampling_freq_hz, demod_freq_hz, t0_s, cutoff_hz=None))]
fn rf_to_iq<'py>(
    py: Python<'py>,
    rf: PyReadonlyArray3<'py, f32>,
    sampling_freq_hz: f64,
    demod_freq_hz: f64,
    t0_s: f64,
    cutoff_hz: Option<f64>,
) -> PyResult<Bound<'py, PyArray3<Complex32>>> {
    let samples = AngleSamples::Rf(rf.as_array().to_owned().insert_axis(Axis(0)));
    let iq = py
        .detach(|| {
            iq::demodulate(
                &samples,
                0,
                t0_s,
                sampling_freq_hz,
                demod_freq_hz,
                cutoff_hz,
            )
        })
        .map_err(lib_err)?;
    // (channels, samples, frames) → (frames, channels, samples).
    let out = iq
        .data
        .permuted_axes([2, 0, 1])
        .as_standard_layout()
        .into_owned();
    Ok(out.into_pyarray(py))
}

/// The pixel grid of `grid_m` (x_min, x_max, z_min, z_max, step; m) or of explicit coordinates
/// `x_m`, `z_m` (m, increasing, as a result's `x` and `z`).
fn grid_from(
    grid_m: Option<[f64; 5]>,
    x_m: Option<Vec<f64>>,
    z_m: Option<Vec<f64>>,
) -> PyResult<Grid> {
    match (grid_m, x_m, z_m) {
        (Some(g), None, None) => Grid::new(g[0], g[1], g[2], g[3], g[4]).map_err(lib_err),
        (None, Some(x), Some(z)) => {
            for (name, axis) in [("x_m", &x), ("z_m", &z)] {
                let increasing = axis.windows(2).all(|w| w[1] > w[0]);
                if axis.is_empty() || !increasing || axis.iter().any(|v| !v.is_finite()) {
                    return Err(PyValueError::new_err(format!(
                        "{name}: pixel positions must be finite and increasing"
                    )));
                }
            }
            if z[0] < 0.0 {
                return Err(PyValueError::new_err(format!(
                    "z_m: {} m lies behind the probe face (z < 0)",
                    z[0]
                )));
            }
            if x.len().saturating_mul(z.len()) > pcuvd::core::grid::MAX_PIXELS {
                return Err(PyValueError::new_err(format!(
                    "{} × {} pixels is too many (at most {})",
                    z.len(),
                    x.len(),
                    pcuvd::core::grid::MAX_PIXELS
                )));
            }
            Ok(Grid { x, z })
        }
        _ => Err(PyValueError::new_err(
            "give the grid as grid_m = (x_min, x_max, z_min, z_max, step) or as x_m and z_m",
        )),
    }
}

/// Delay-and-sum of one steered plane wave's IQ (frames, channels, samples) onto a grid
/// (x_min, x_max, z_min, z_max, step, m) or coordinates: complex image series (nz, nx, frames).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn beamform_iq<'py>(
    py: Python<'py>,
    iq_samples: PyReadonlyArray3<'py, Complex32>,
    probe: &str,
    angle_rad: f64,
    sampling_freq_hz: f64,
    demod_freq_hz: f64,
    t0_s: f64,
    sound_speed_m_s: f64,
    grid_m: Option<[f64; 5]>,
    x_m: Option<Vec<f64>>,
    z_m: Option<Vec<f64>>,
    f_number: f64,
    apodization: &str,
) -> PyResult<Bound<'py, PyArray3<Complex32>>> {
    let probe: Value =
        serde_json::from_str(probe).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let probe = parse_probe(&probe).map_err(to_py)?;
    let grid = grid_from(grid_m, x_m, z_m)?;
    let apodization = match apodization {
        "hann" => Apodization::Hann,
        "boxcar" => Apodization::Boxcar,
        other => {
            return Err(PyValueError::new_err(format!(
                "apodization {other:?}: expected \"hann\" or \"boxcar\""
            )));
        }
    };
    let (_, channels, _) = iq_samples.as_array().dim();
    if channels != probe.n_elements {
        return Err(PyValueError::new_err(format!(
            "the IQ data has {channels} channels but the probe has {} elements",
            probe.n_elements
        )));
    }
    if !(f_number.is_finite() && f_number > 0.0) {
        return Err(PyValueError::new_err(format!(
            "f_number must be finite and > 0, got {f_number}"
        )));
    }
    // The image series is nz × nx × frames complex samples: refuse what would not fit rather
    // than abort the interpreter on allocation.
    let (nz, nx) = grid.shape();
    let frames = iq_samples.as_array().dim().0;
    let bytes = (nz * nx) as f64 * frames as f64 * std::mem::size_of::<Complex32>() as f64;
    if let Some(room) = pcuvd_app::memory::memory_room()
        && bytes > room.bytes
    {
        return Err(PyValueError::new_err(format!(
            "the image series would need {:.1} GB ({nz} × {nx} pixels × {frames} frames) but \
             {:.1} GB are available ({}): use a coarser or smaller grid, or fewer frames",
            bytes / 1e9,
            room.bytes.max(0.0) / 1e9,
            room.bound
        )));
    }
    let channels_first = iq_samples
        .as_array()
        .permuted_axes([1, 2, 0])
        .as_standard_layout()
        .into_owned();
    let iq = iq::IqChannels {
        data: channels_first,
        sampling_frequency: sampling_freq_hz,
        t0: t0_s,
        demod_frequency: demod_freq_hz,
    };
    let params = DasParams {
        f_number,
        apodization,
        sound_speed: sound_speed_m_s,
    };
    let image = py
        .detach(|| {
            pcuvd::core::error::require_positive("sampling frequency", sampling_freq_hz)?;
            pcuvd::core::error::require_positive("speed of sound", sound_speed_m_s)?;
            beamform::beamform(&iq, &probe, angle_rad, &grid, &params)
        })
        .map_err(lib_err)?;
    Ok(image.into_pyarray(py))
}

fn rank_cut(text: &str, name: &str) -> PyResult<RankCut> {
    match text {
        "off" => Ok(RankCut::Off),
        "auto" => Ok(RankCut::Auto),
        n => n.parse().map(RankCut::Fixed).map_err(|_| {
            PyValueError::new_err(format!(
                "{name} {n:?}: expected \"auto\", \"off\" or a number of components"
            ))
        }),
    }
}

/// A filtered series, the low and high cut-offs used, and the singular values.
type Filtered<'py> = (Bound<'py, PyArray3<Complex32>>, usize, usize, Vec<f64>);

/// SVD clutter filter of a series (nz, nx, frames): returns the filtered series and the low and
/// high cut-offs used and the singular values.
#[pyfunction]
fn svd_filter<'py>(
    py: Python<'py>,
    series: PyReadonlyArray3<'py, Complex32>,
    low: &str,
    high: &str,
    tissue_frequency: f64,
) -> PyResult<Filtered<'py>> {
    let params = ClutterParams {
        low: rank_cut(low, "low")?,
        high: rank_cut(high, "high")?,
        tissue_frequency,
    };
    let mut data = series.as_array().as_standard_layout().into_owned();
    let report = py
        .detach(|| clutter::svd_filter(&mut data, &params))
        .map_err(lib_err)?;
    Ok((
        data.into_pyarray(py),
        report.low,
        report.high,
        report.singular_values,
    ))
}

fn autocorrelation(
    py: Python<'_>,
    series: &PyReadonlyArray3<'_, Complex32>,
    kernel: (usize, usize),
) -> PyResult<pcuvd::estimate::doppler::Autocorrelation> {
    let view = series.as_array();
    py.detach(|| pcuvd::estimate::doppler::autocorrelation(view, kernel))
        .map_err(lib_err)
}

/// Power Doppler (mean |S|² over frames) of a series (nz, nx, frames), averaged over `kernel` pixels.
#[pyfunction]
fn power_doppler<'py>(
    py: Python<'py>,
    series: PyReadonlyArray3<'py, Complex32>,
    kernel: (usize, usize),
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    Ok(autocorrelation(py, &series, kernel)?.power.into_pyarray(py))
}

/// Lag-1 (Kasai) projection velocity (m/s, positive = echo path lengthens) of a series
/// (nz, nx, frames), the autocorrelation averaged over `kernel` pixels.
#[pyfunction]
fn kasai<'py>(
    py: Python<'py>,
    series: PyReadonlyArray3<'py, Complex32>,
    sound_speed_m_s: f64,
    frame_rate_hz: f64,
    center_freq_hz: f64,
    kernel: (usize, usize),
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let r = autocorrelation(py, &series, kernel)?;
    let v = pcuvd::estimate::doppler::projection_velocity(
        &r.r1,
        sound_speed_m_s,
        frame_rate_hz,
        center_freq_hz,
    )
    .map_err(lib_err)?;
    Ok(v.into_pyarray(py))
}

/// (vx, vz) maps in m/s.
type VectorMaps<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

/// Vector velocity (vx, vz) in m/s from projections (angles, nz, nx) at `angles_rad`; NaN
/// projections are left out. `irls`: None for least squares (UVD), else (λ mm/s, ε, iterations).
#[pyfunction]
#[pyo3(signature = (projections, angles_rad, irls=None))]
fn vector_fit<'py>(
    py: Python<'py>,
    projections: PyReadonlyArray3<'py, f64>,
    angles_rad: Vec<f64>,
    irls: Option<(f64, f64, usize)>,
) -> PyResult<VectorMaps<'py>> {
    let estimator = match irls {
        None => Estimator::LeastSquares,
        Some((lambda_mm_s, epsilon, max_iterations)) => Estimator::Irls(IrlsParams {
            lambda_mm_s,
            epsilon,
            max_iterations,
        }),
    };
    let view = projections.as_array();
    let field = py
        .detach(|| vector::vector_velocity(&angles_rad, view, &estimator))
        .map_err(lib_err)?;
    Ok((field.vx.into_pyarray(py), field.vz.into_pyarray(py)))
}

/// Resistivity index (PSV − EDV)/PSV, element by element (NaN where undefined).
#[pyfunction]
fn resistivity_index<'py>(
    py: Python<'py>,
    psv: PyReadonlyArray2<'py, f64>,
    edv: PyReadonlyArray2<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (p, e) = (psv.as_array(), edv.as_array());
    if p.dim() != e.dim() {
        return Err(PyValueError::new_err(format!(
            "psv {:?} and edv {:?} differ in shape",
            p.dim(),
            e.dim()
        )));
    }
    let ri: Array2<f64> = ndarray::Zip::from(p)
        .and(e)
        .map_collect(|&p, &e| pcuvd::dynamics::resistivity_index(p, e));
    Ok(ri.into_pyarray(py))
}

// ---------------------------------------------------------------------------------------------
// Simulation and the paper's studies

/// Recordings by mode name, and the truth arrays by name.
type Simulated<'py> = (Vec<(String, PyRecording)>, Bound<'py, PyDict>);

/// Simulates as `pcuvd simulate` does (keyword options in `options`, JSON): the recordings by
/// mode name, and the ground truth arrays on the default processing grid.
#[pyfunction]
fn simulate<'py>(py: Python<'py>, options: &str, quiet: bool) -> PyResult<Simulated<'py>> {
    let options: SimulationSettings = settings(options)?;
    let progress = Lines::new(quiet);
    type Made = (
        Vec<(String, ChannelData, toml::Table)>,
        pcuvd_app::simulation::SimulatedTruth,
    );
    let (recordings, truth) = py
        .detach(|| -> anyhow::Result<Made> {
            let simulation = pcuvd_app::simulation::Simulation::new(&options)?;
            let mut made = Vec::new();
            for (index, (name, _)) in simulation.modes.iter().enumerate() {
                let task = format!("simulate {name}");
                let data = simulation
                    .recording(index, &|done, total| progress.update(&task, done, total))?;
                made.push((name.to_string(), data, simulation.provenance(index)));
            }
            let truth = simulation.truth(&made[0].1)?;
            Ok((made, truth))
        })
        .map_err(to_py)?;
    let dict = PyDict::new(py);
    dict.set_item("x", PyArray1::from_slice(py, &truth.x))?;
    dict.set_item("z", PyArray1::from_slice(py, &truth.z))?;
    dict.set_item("vx", truth.truth.vx.to_pyarray(py))?;
    dict.set_item("vz", truth.truth.vz.to_pyarray(py))?;
    dict.set_item("mask", truth.truth.mask.to_pyarray(py))?;
    if let Some(cycle) = &truth.cycle {
        dict.set_item("ri", cycle.ri.to_pyarray(py))?;
        dict.set_item("psv", cycle.psv.to_pyarray(py))?;
        dict.set_item("edv", cycle.edv.to_pyarray(py))?;
        dict.set_item("vessel_class", cycle.vessel_class.to_pyarray(py))?;
        dict.set_item("flow_up", cycle.flow_up.to_pyarray(py))?;
    }
    let recordings = recordings
        .into_iter()
        .map(|(name, data, provenance)| {
            let label = format!("pcuvd simulate ({name}): {provenance}");
            (
                name,
                PyRecording::new(data, vec![], label, ("simulation", "pcuvd.simulate")),
            )
        })
        .collect();
    Ok((recordings, dict))
}

/// Runs one of the paper's studies ("spiral" or "network") with `pcuvd paper`'s options (JSON);
/// returns its metrics (the numbers `pcuvd paper` writes to metrics.json) as JSON.
#[pyfunction]
fn study(py: Python<'_>, which: &str, options: &str, quiet: bool) -> PyResult<String> {
    let options: StudySettings = settings(options)?;
    let which = which.to_string();
    py.detach(|| -> anyhow::Result<String> {
        let progress = Lines::new(quiet);
        let report = pcuvd_app::progress::tasks(&progress);
        let value = match which.as_str() {
            "spiral" => {
                let settings = options.spiral_settings()?;
                serde_json::to_value(pcuvd::study::spiral::run(&settings, &report)?.metrics)?
            }
            "network" => {
                let settings = options.network_settings()?;
                serde_json::to_value(pcuvd::study::network::run(&settings, &report)?.metrics)?
            }
            other => anyhow::bail!("study {other:?}: expected \"spiral\" or \"network\""),
        };
        Ok(value.to_string())
    })
    .map_err(to_py)
}

/// The settings each of the paper's studies would run with for the keyword options in `options`
/// (JSON), every default filled in and every check made, as `pcuvd paper --print-settings`
/// prints them: {"spiral": ..., "network": ..., "dealias": ...}.
#[pyfunction]
fn study_settings(options: &str) -> PyResult<String> {
    let options: StudySettings = settings(options)?;
    let resolved = || -> anyhow::Result<Value> {
        Ok(json!({
            "spiral": options.spiral_settings()?,
            "network": options.network_settings()?,
            "dealias": options.dealias_settings()?,
        }))
    };
    Ok(resolved().map_err(to_py)?.to_string())
}

/// The keyword names (aliases included) that `command` ("process", "dynamics", "simulate" or
/// "study") accepts, for the Python half's keyword check: the settings' field names.
#[pyfunction]
fn option_names_of(command: &str) -> PyResult<Vec<String>> {
    match command {
        "process" => {
            let mut names = field_names::<ProcessingSettings>(&PROCESSING_ALIASES);
            names.extend(field_names::<DynamicsSettings>(&DYNAMICS_ALIASES));
            names.push("max_memory_gb".into());
            Ok(names)
        }
        "dynamics" => Ok(field_names::<DynamicsSettings>(&DYNAMICS_ALIASES)),
        "simulate" => Ok(field_names::<SimulationSettings>(&[])),
        "study" => Ok(field_names::<StudySettings>(&[])),
        other => Err(PyValueError::new_err(format!("no command {other:?}"))),
    }
}

/// The native module.
#[pymodule]
fn _pcuvd(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // The library's defaults, so the Python signatures cannot drift from them.
    let irls = IrlsParams::default();
    m.add("DEFAULT_F_NUMBER", DasParams::DEFAULT_F_NUMBER)?;
    m.add("DEFAULT_IRLS_LAMBDA_MM_S", irls.lambda_mm_s)?;
    m.add("DEFAULT_IRLS_EPSILON", irls.epsilon)?;
    m.add("DEFAULT_IRLS_MAX_ITERATIONS", irls.max_iterations)?;
    m.add(
        "DEFAULT_TISSUE_FREQUENCY",
        ClutterParams::default().tissue_frequency,
    )?;
    m.add_class::<PyRecording>()?;
    m.add_class::<PyProcessResult>()?;
    m.add_function(wrap_pyfunction!(read_recording, m)?)?;
    m.add_function(wrap_pyfunction!(recording_from_arrays, m)?)?;
    m.add_function(wrap_pyfunction!(process, m)?)?;
    m.add_function(wrap_pyfunction!(option_names_of, m)?)?;
    m.add_function(wrap_pyfunction!(study_settings, m)?)?;
    m.add_function(wrap_pyfunction!(decode_hadamard_rf, m)?)?;
    m.add_function(wrap_pyfunction!(rf_to_iq, m)?)?;
    m.add_function(wrap_pyfunction!(beamform_iq, m)?)?;
    m.add_function(wrap_pyfunction!(svd_filter, m)?)?;
    m.add_function(wrap_pyfunction!(power_doppler, m)?)?;
    m.add_function(wrap_pyfunction!(kasai, m)?)?;
    m.add_function(wrap_pyfunction!(vector_fit, m)?)?;
    m.add_function(wrap_pyfunction!(resistivity_index, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(study, m)?)?;
    Ok(())
}
