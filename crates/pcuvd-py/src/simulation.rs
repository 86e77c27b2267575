//! Simulation and the paper's studies, and the option names of each command.

use crate::*;

/// Recordings by mode name, and the truth arrays by name.
pub(crate) type Simulated<'py> = (Vec<(String, PyRecording)>, Bound<'py, PyDict>);

/// Simulates as `pcuvd simulate` does (keyword options in `options`, JSON): the recordings by
/// mode name, and the ground truth arrays on the default processing grid.
#[pyfunction]
pub(crate) fn simulate<'py>(
    py: Python<'py>,
    options: &str,
    quiet: bool,
) -> PyResult<Simulated<'py>> {
    let options: SimulationSettings = settings(options)?;
    let progress = Lines::new(quiet);
    type Made = (
        Vec<(String, ChannelData, toml::Table)>,
        pcuvd_app::simulation::SimulatedTruth,
        Option<ndarray::Array3<f64>>,
        String,
        Option<Vec<f64>>,
    );
    let (recordings, truth, displacement, scenario, triggers) = py
        .detach(|| -> anyhow::Result<Made> {
            let simulation = pcuvd_app::simulation::Simulation::new(&options)?;
            pcuvd_app::memory::check_room_for(
                simulation.samples_bytes(),
                "the simulated recordings, held in memory,",
                "fewer frames, or `pcuvd simulate`, which writes them to disk a block at a time",
            )?;
            let mut made = Vec::new();
            let levels = simulation.echo_levels()?;
            for (index, (name, _)) in simulation.modes.iter().enumerate() {
                let task = format!("simulate {name}");
                let data = simulation
                    .recording(index, &|done, total| progress.update(&task, done, total))?;
                made.push((name.to_string(), data, simulation.provenance(index, levels)));
            }
            // The truth at the start and, what a whole-recording map estimates, a pulsing
            // vessel's mean over the recording, from one evaluation of the times.
            let acquisition = &made[0].1.acquisition;
            let duration_s = simulation.frames as f64 / acquisition.frame_rate();
            let truth = simulation.truth_averaged(
                acquisition,
                made[0].1.samples.dim().2,
                &pcuvd_app::simulation::truth_times(duration_s),
            )?;
            let displacement = simulation.tissue_displacement(&truth.z);
            Ok((
                made,
                truth,
                displacement,
                simulation.scenario.to_toml()?,
                simulation.cardiac_triggers(),
            ))
        })
        .map_err(to_py)?;
    let dict = PyDict::new(py);
    dict.set_item("x", PyArray1::from_slice(py, &truth.x))?;
    dict.set_item("z", PyArray1::from_slice(py, &truth.z))?;
    let (start_vx, start_vz) = truth
        .start_velocity
        .as_ref()
        .map_or((&truth.truth.vx, &truth.truth.vz), |(vx, vz)| (vx, vz));
    dict.set_item("vx", start_vx.to_pyarray(py))?;
    dict.set_item("vz", start_vz.to_pyarray(py))?;
    dict.set_item("mask", truth.truth.mask.to_pyarray(py))?;
    dict.set_item("mean_vx", truth.truth.vx.to_pyarray(py))?;
    dict.set_item("mean_vz", truth.truth.vz.to_pyarray(py))?;
    if let Some(cycle) = &truth.cycle {
        dict.set_item("ri", cycle.ri.to_pyarray(py))?;
        dict.set_item("psv", cycle.psv.to_pyarray(py))?;
        dict.set_item("edv", cycle.edv.to_pyarray(py))?;
        dict.set_item("vessel_class", cycle.vessel_class.to_pyarray(py))?;
        dict.set_item("flow_up", cycle.flow_up.to_pyarray(py))?;
        dict.set_item("class_share", cycle.class_share.to_pyarray(py))?;
        dict.set_item("axis_profile", cycle.axis_profile.to_pyarray(py))?;
    }
    if let Some((vy, fraction)) = &truth.elevation {
        dict.set_item("vy", vy.to_pyarray(py))?;
        dict.set_item("blood_fraction", fraction.to_pyarray(py))?;
    }
    if let Some(tissue) = &truth.tissue {
        dict.set_item("tissue_vx", tissue.velocity[0].to_pyarray(py))?;
        dict.set_item("tissue_vz", tissue.velocity[2].to_pyarray(py))?;
    }
    if let Some(displacement) = &displacement {
        dict.set_item("tissue_displacement", displacement.to_pyarray(py))?;
    }
    dict.set_item("scenario", &scenario)?;
    let recordings = recordings
        .into_iter()
        .map(|(name, data, provenance)| {
            let label = format!("pcuvd.simulate ({name})");
            let mut recording =
                PyRecording::new(data, vec![], label, ("simulation", "pcuvd.simulate"));
            // The heartbeats, as an ECG beside the scanner would record them: the RI maps use
            // them as they use a manifest's [cardiac] triggers.
            recording.info.cardiac_triggers_s = triggers.clone();
            recording.simulated = Some(Arc::new(SimulatedFrom {
                scenario: scenario.clone(),
                record: provenance,
            }));
            (name, recording)
        })
        .collect();
    Ok((recordings, dict))
}

/// Runs one of the paper's studies ("spiral", "network" or "brain") with `pcuvd paper`'s options (JSON);
/// returns its metrics (the numbers `pcuvd paper` writes to metrics.json) as JSON.
#[pyfunction]
pub(crate) fn study(py: Python<'_>, which: &str, options: &str, quiet: bool) -> PyResult<String> {
    let options: StudySettings = settings::<StudySettings>(options)?.quickened();
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
            "brain" => {
                let settings = options.brain_settings(None)?;
                serde_json::to_value(pcuvd_app::brain::run(&settings, &progress)?.metrics)?
            }
            other => {
                anyhow::bail!("study {other:?}: expected \"spiral\", \"network\" or \"brain\"")
            }
        };
        Ok(value.to_string())
    })
    .map_err(to_py)
}

/// The settings each of the paper's studies would run with for the keyword options in `options`
/// (JSON), every default filled in and every check made, as `pcuvd paper --print-settings`
/// prints them: {"spiral": ..., "network": ..., "dealias": ..., "brain": ...}.
#[pyfunction]
pub(crate) fn study_settings(options: &str) -> PyResult<String> {
    let options: StudySettings = settings::<StudySettings>(options)?.quickened();
    let resolved = || -> anyhow::Result<Value> {
        Ok(json!({
            "spiral": options.spiral_settings()?,
            "network": options.network_settings()?,
            "dealias": options.dealias_settings()?,
            "brain": options.brain_settings(None)?,
        }))
    };
    Ok(resolved().map_err(to_py)?.to_string())
}

/// The keyword names (aliases included) that `command` ("process", "dynamics", "simulate" or
/// "study") accepts, for the Python half's keyword check: the settings' field names.
#[pyfunction]
pub(crate) fn option_names_of(command: &str) -> PyResult<Vec<String>> {
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
