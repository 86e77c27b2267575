//! `pcuvd.process`: a recording processed as `pcuvd process` does it, its result's arrays, summary,
//! dynamics re-run and saving.

use crate::*;
use pcuvd_app::sites::{ARRAYS as SITE_ARRAYS, SiteSpectrograms};

/// `pcuvd process`'s options, without the input and the output folder: keywords split between
/// the processing and the dynamics settings by their names.
pub(crate) struct ProcessCall {
    pub(crate) options: ProcessingSettings,
    pub(crate) dynamics: DynamicsSettings,
    pub(crate) max_memory_gb: Option<f64>,
}

impl ProcessCall {
    pub(crate) fn from_json(options: &str) -> PyResult<Self> {
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
pub(crate) struct PyProcessResult {
    /// The processing settings it ran with (a dynamics re-run keeps them).
    pub(crate) options: ProcessingSettings,
    /// What was processed: a recording (in memory, or its file read a block at a time), or
    /// beamformed images formed elsewhere.
    pub(crate) source: RunSource,
    pub(crate) input: String,
    pub(crate) info: pcuvd_io::SourceInfo,
    pub(crate) plan: Plan,
    pub(crate) processed: Processed,
    /// What a recording simulated in memory came from: its truth scores the run.
    pub(crate) simulated: Option<Arc<SimulatedFrom>>,
}

/// What a result was processed from.
#[derive(Clone)]
pub(crate) enum RunSource {
    /// A recording of channel data.
    Recording(Arc<dyn pcuvd::acquisition::source::FrameSource + Send>),
    /// Beamformed images formed elsewhere (an images manifest).
    Images(Box<pcuvd_app::summary::ImagesRecord>),
}

impl RunSource {
    /// The run's input, as the summary and the writers take it.
    fn input(&self) -> pcuvd_app::summary::RunInput<'_> {
        match self {
            RunSource::Recording(data) => pcuvd_app::summary::RunInput::Recording(&**data),
            RunSource::Images(images) => pcuvd_app::summary::RunInput::Images(images),
        }
    }

    /// The recording, or an error saying that `what` needs one (images formed elsewhere have no
    /// simulation to score against).
    fn recording(
        &self,
        what: &str,
    ) -> anyhow::Result<&dyn pcuvd::acquisition::source::FrameSource> {
        match self {
            RunSource::Recording(data) => Ok(&**data),
            RunSource::Images(_) => Err(anyhow::anyhow!(
                "{what} needs a recording of channel data, not images formed elsewhere"
            )),
        }
    }
}

/// Runs `pcuvd process`'s chain on `recording` with the keyword options in `options` (JSON).
#[pyfunction]
pub(crate) fn process(
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
            let mut plan = Plan::new(
                &call.options,
                &call.dynamics,
                &*data,
                recording.info.cardiac_triggers_s.as_deref(),
            )?;
            pcuvd_app::memory::check_memory(&*data, &mut plan, call.max_memory_gb)?;
            let processed = pcuvd_app::run(&*data, &plan, &progress)
                .with_context(|| format!("{input}: processing failed"))?;
            Ok((plan, processed))
        })
        .map_err(to_py)?;
    let opened = Opened {
        source: data,
        info: recording.info.clone(),
        call,
        plan,
        simulated: recording.simulated.clone(),
    };
    opened.result(py, input.clone(), processed)
}

/// Runs `pcuvd process`'s chain on the recording file at `path`, read a block of frames at a
/// time as the command reads it (memory bounded by a block, not by the recording's length),
/// with the reader `overrides` and the keyword `options` (both JSON).
#[pyfunction]
pub(crate) fn process_file(
    py: Python<'_>,
    path: PathBuf,
    overrides: &str,
    options: &str,
    quiet: bool,
) -> PyResult<PyProcessResult> {
    let progress = Lines::new(quiet);
    if pcuvd_io::open::is_images_input(&path) {
        return process_images(py, path, overrides, options, &progress);
    }
    let (opened, processed) = py.detach(|| -> PyResult<_> {
        let opened = open_checked(&path, overrides, options)?;
        let processed = pcuvd_app::run(opened.source.as_ref(), &opened.plan, &progress)
            .with_context(|| format!("{}: processing failed", path.display()))
            .map_err(to_py)?;
        Ok((opened, processed))
    })?;
    opened.result(py, path.display().to_string(), processed)
}

/// [`process_file`] on an images manifest: beamformed images formed elsewhere, read whole or a
/// segment at a time, their chain from the clutter filter on, as `pcuvd process` runs it.
fn process_images(
    py: Python<'_>,
    path: PathBuf,
    overrides: &str,
    options: &str,
    progress: &Lines,
) -> PyResult<PyProcessResult> {
    let input = path.display().to_string();
    let (opened, processed) = py.detach(|| -> PyResult<_> {
        let opened = OpenedImages::open(&path, overrides, options, true)?;
        let processed =
            pcuvd_app::run::run_images(&opened.images.images, &opened.images.plan, progress)
                .with_context(|| format!("{input}: processing failed"))
                .map_err(to_py)?;
        Ok((opened, processed))
    })?;
    opened.result(py, input, processed)
}

/// An images manifest opened and its run planned (and memory checked, as `pcuvd process` does)
/// with the call's settings.
pub(crate) struct OpenedImages {
    pub(crate) images: pcuvd_app::input::OpenedImages,
    pub(crate) call: ProcessCall,
}

impl OpenedImages {
    /// Opens the images manifest at `path` for a run with the keyword `options` (JSON), its
    /// memory checked when `checked`; reader `overrides` (JSON) are refused, since they are for
    /// channel data.
    pub(crate) fn open(
        path: &std::path::Path,
        overrides: &str,
        options: &str,
        checked: bool,
    ) -> PyResult<Self> {
        let given: serde_json::Map<String, Value> =
            serde_json::from_str(overrides).map_err(|e| PyValueError::new_err(e.to_string()))?;
        if !given.is_empty() {
            return Err(PyValueError::new_err(format!(
                "{}: overrides are for recordings of channel data; the images are formed",
                path.display()
            )));
        }
        let call = ProcessCall::from_json(options)?;
        let mut images =
            pcuvd_app::input::open_images(path, &call.options, &call.dynamics).map_err(to_py)?;
        if checked {
            images
                .check_memory(call.max_memory_gb)
                .with_context(|| path.display().to_string())
                .map_err(to_py)?;
        }
        Ok(OpenedImages { images, call })
    }

    /// The result of the run on these images, `input` naming them, after the warning `pcuvd
    /// process` prints where dealiasing was asked of one angle.
    pub(crate) fn result(
        self,
        py: Python<'_>,
        input: String,
        processed: Processed,
    ) -> PyResult<PyProcessResult> {
        let opened = self.images;
        warn_of_dealiasing(py, &input, &opened.plan, &processed, false)?;
        Ok(PyProcessResult {
            options: self.call.options,
            source: RunSource::Images(Box::new(opened.record)),
            input,
            info: opened.info,
            plan: opened.plan,
            processed,
            simulated: None,
        })
    }
}

/// The warning `pcuvd process` prints where dealiasing was asked of a recording it cannot help
/// (one angle; a `coded` one), as a Python UserWarning naming `input`.
fn warn_of_dealiasing(
    py: Python<'_>,
    input: &str,
    plan: &Plan,
    processed: &Processed,
    coded: bool,
) -> PyResult<()> {
    if let Some(warning) =
        pcuvd::pipeline::dealias_warning(plan.params.dealias, coded, &processed.out)
    {
        let message = std::ffi::CString::new(format!("{input}: {}", keywords::as_python(&warning)))
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        PyErr::warn(
            py,
            &py.get_type::<pyo3::exceptions::PyUserWarning>(),
            &message,
            1,
        )?;
    }
    Ok(())
}

impl Opened {
    /// The result of this recording's run, `input` naming it, after the warning `pcuvd process`
    /// prints where dealiasing was asked of a coded recording.
    pub(crate) fn result(
        self,
        py: Python<'_>,
        input: String,
        processed: Processed,
    ) -> PyResult<PyProcessResult> {
        let coded = self.source.acquisition().sequence.is_coded();
        warn_of_dealiasing(py, &input, &self.plan, &processed, coded)?;
        Ok(PyProcessResult {
            options: self.call.options,
            source: RunSource::Recording(self.source),
            input,
            info: self.info,
            plan: self.plan,
            processed,
            simulated: self.simulated,
        })
    }
}

/// The overrides [`reader_overrides`] reads: the ones a recording read a block at a time takes.
const READER_OVERRIDES: [&str; 9] = [
    "t0_s",
    "sound_speed_m_s",
    "event_prf_hz",
    "sampling_freq_hz",
    "center_freq_hz",
    "angles_rad",
    "pulse_cycles",
    "bandwidth",
    "track",
];

/// A recording ready to run (in memory, or opened from its file and read a block at a time),
/// what its reader said of it, the call's settings and the plan of its run.
pub(crate) struct Opened {
    pub(crate) source: Arc<dyn pcuvd::acquisition::source::FrameSource + Send>,
    pub(crate) info: pcuvd_io::SourceInfo,
    pub(crate) call: ProcessCall,
    pub(crate) plan: Plan,
    /// What a recording simulated in memory came from; `None` for a file's.
    pub(crate) simulated: Option<Arc<SimulatedFrom>>,
}

/// Opens `path` with the reader `overrides` (JSON) and plans the run of the keyword `options`
/// (JSON), as `pcuvd.process` would.
pub(crate) fn open(path: &std::path::Path, overrides: &str, options: &str) -> PyResult<Opened> {
    let overrides: serde_json::Map<String, Value> =
        serde_json::from_str(overrides).map_err(|e| PyValueError::new_err(e.to_string()))?;
    if let Some(other) = overrides
        .keys()
        .find(|k| !READER_OVERRIDES.contains(&k.as_str()))
    {
        return Err(PyValueError::new_err(format!(
            "overrides: {other:?} is not one the reader applies as it reads the file a block at a \
             time ({}); read the recording with pcuvd.read_recording and use pcuvd.process",
            READER_OVERRIDES.join(", ")
        )));
    }
    let reader_overrides = reader_overrides(&overrides)
        .with_context(|| format!("{}: overrides", path.display()))
        .map_err(to_py)?;
    let call = ProcessCall::from_json(options)?;
    let opened = pcuvd_app::input::open_input(path, &reader_overrides).map_err(to_py)?;
    let plan = Plan::new(
        &call.options,
        &call.dynamics,
        opened.source.as_ref(),
        opened.info.cardiac_triggers_s.as_deref(),
    )
    .map_err(to_py)?;
    Ok(Opened {
        source: Arc::from(opened.source),
        info: opened.info,
        call,
        plan,
        simulated: None,
    })
}

/// [`open`], then the run's memory checked as `pcuvd process` checks it, before any work.
pub(crate) fn open_checked(
    path: &std::path::Path,
    overrides: &str,
    options: &str,
) -> PyResult<Opened> {
    let mut opened = open(path, overrides, options)?;
    pcuvd_app::memory::check_memory(
        opened.source.as_ref(),
        &mut opened.plan,
        opened.call.max_memory_gb,
    )
    .map_err(to_py)?;
    Ok(opened)
}

impl PyProcessResult {
    fn source(&self) -> anyhow::Result<pcuvd_app::summary::Provenance> {
        let mut source = pcuvd_app::summary::provenance(
            &self.input,
            &self.info,
            &self.plan.options_text,
            vec![format!("python: pcuvd.process({:?})", self.input)],
            pcuvd_app::outputs::Checksum::default(),
            &[],
        )?;
        source.simulation = self.simulated.as_ref().map(|s| s.record.clone());
        Ok(source)
    }
}

impl PyProcessResult {
    /// The maps whose names `want` takes, numpy arrays in SI units under the file stems of the
    /// .npy files `pcuvd process` writes.
    fn arrays_where<'py>(
        &self,
        py: Python<'py>,
        want: &dyn Fn(&str) -> bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        let out = &self.processed.out;
        let dict = PyDict::new(py);
        let put = |name: &str, make: &dyn Fn() -> PyResult<Bound<'py, PyAny>>| -> PyResult<()> {
            if want(name) {
                dict.set_item(name, make()?)?;
            }
            Ok(())
        };
        put(
            "x",
            &|| Ok(PyArray1::from_slice(py, &out.grid.x).into_any()),
        )?;
        put(
            "z",
            &|| Ok(PyArray1::from_slice(py, &out.grid.z).into_any()),
        )?;
        put("bmode_db", &|| Ok(out.bmode_db.to_pyarray(py).into_any()))?;
        put("power_doppler", &|| {
            Ok(out.maps.power_doppler.to_pyarray(py).into_any())
        })?;
        put("color_doppler", &|| {
            Ok(out.maps.color_doppler.to_pyarray(py).into_any())
        })?;
        put("signed_power_doppler", &|| {
            Ok(out.signed_power_doppler().into_pyarray(py).into_any())
        })?;
        put("projections", &|| {
            Ok(out.maps.projections.to_pyarray(py).into_any())
        })?;
        put("projection_nyquist", &|| {
            Ok(out.maps.projection_nyquist.to_pyarray(py).into_any())
        })?;
        if let (Some(ls), Some(irls)) = (&out.maps.vector_ls, &out.maps.vector_irls) {
            put("vx", &|| Ok(irls.vx.to_pyarray(py).into_any()))?;
            put("vz", &|| Ok(irls.vz.to_pyarray(py).into_any()))?;
            put("speed", &|| Ok(irls.speed().into_pyarray(py).into_any()))?;
            put("vx_ls", &|| Ok(ls.vx.to_pyarray(py).into_any()))?;
            put("vz_ls", &|| Ok(ls.vz.to_pyarray(py).into_any()))?;
            put("speed_ls", &|| Ok(ls.speed().into_pyarray(py).into_any()))?;
        }
        if let Some(done) = &out.maps.dealias {
            put("alias_counts", &|| {
                Ok(done.irls.alias_counts.to_pyarray(py).into_any())
            })?;
            put("alias_counts_ls", &|| {
                Ok(done.ls.alias_counts.to_pyarray(py).into_any())
            })?;
        }
        // `want` is asked only of the maps this result has ([`Self::array_names`]).
        let clutter = pcuvd_app::summary::clutter_by_segment(&self.processed);
        if let Some(cut_offs) = pcuvd_app::summary::block_cut_offs(&clutter).map_err(to_py)?
            && want("clutter_block_cut_offs")
        {
            dict.set_item("clutter_block_cut_offs", cut_offs.into_pyarray(py))?;
        }
        if let DynamicsOutcome::Done { series, maps } = &self.processed.dynamics {
            put_ri_maps(&dict, maps, series, want)?;
        }
        if self.plan.sites.is_some() {
            let wanted: Vec<&str> = SITE_ARRAYS.into_iter().filter(|n| want(n)).collect();
            // Made only when one of them is asked for (the names cost nothing).
            if !wanted.is_empty()
                && let Some(sites) =
                    SiteSpectrograms::of(&self.plan, &self.processed).map_err(to_py)?
            {
                for array in sites.arrays(|name| wanted.contains(&name)) {
                    dict.set_item(array.name, array.values.into_pyarray(py))?;
                }
            }
        }
        if let Some(ensembles) = &self.processed.ensembles {
            put("ensemble_power_doppler", &|| {
                Ok(ensembles.power_doppler.to_pyarray(py).into_any())
            })?;
            put("ensemble_color_doppler", &|| {
                Ok(ensembles.color_doppler.to_pyarray(py).into_any())
            })?;
            put("ensemble_signed_power_doppler", &|| {
                Ok(ensembles.signed_power_doppler().into_pyarray(py).into_any())
            })?;
            if let Some(vx) = &ensembles.vx {
                put("ensemble_vx", &|| Ok(vx.to_pyarray(py).into_any()))?;
            }
            if let Some(vz) = &ensembles.vz {
                put("ensemble_vz", &|| Ok(vz.to_pyarray(py).into_any()))?;
            }
            if ensembles.vx.is_some() && ensembles.vz.is_some() && want("ensemble_speed") {
                let speed = ensembles.speed().expect("vx and vz give the speed");
                dict.set_item("ensemble_speed", speed.into_pyarray(py))?;
            }
            put("ensemble_times", &|| {
                Ok(PyArray1::from_slice(py, &ensembles.times_s).into_any())
            })?;
        }
        Ok(dict)
    }
}

#[pymethods]
impl PyProcessResult {
    /// The names of the maps `pcuvd process` writes as .npy (by file stem) that this result
    /// has, without making them.
    fn array_names(&self, py: Python<'_>) -> PyResult<Vec<String>> {
        let names = std::cell::RefCell::new(Vec::new());
        self.arrays_where(py, &|name| {
            names.borrow_mut().push(name.to_string());
            false
        })?;
        Ok(names.into_inner())
    }

    /// The maps called `names` that this result has, by name (`pcuvd process` writes each as
    /// `name`.npy), made in one pass: a long recording's speed series or ensembles only when
    /// asked for, and the four site arrays from one computation of the sites' spectrograms.
    fn arrays_named<'py>(
        &self,
        py: Python<'py>,
        names: Vec<String>,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.arrays_where(py, &|wanted| names.iter().any(|n| n == wanted))
    }

    /// The error `pcuvd.process` raises, this result beside it, when the RI maps a dynamics
    /// setting asked for could not be made from the recording; `None` otherwise.
    fn dynamics_failure(&self) -> Option<String> {
        self.processed.dynamics_failure().map(|reason| {
            format!(
                "{}: the RI maps asked for (dynamics=\"on\", or a dynamics option given) could \
                 not be made: {}; the run's other maps are in this error's result \
                 (result.save(folder) writes them)",
                self.input,
                keywords::as_python(reason),
            )
        })
    }

    /// The same maps with the dynamics stage run again with the keyword options in `options`
    /// (JSON: heart rate, windows, RI thresholds, vessel tests, pooling).
    fn with_dynamics(&self, py: Python<'_>, options: &str, quiet: bool) -> PyResult<Self> {
        let dynamics: DynamicsSettings = settings(options)?;
        let progress = Lines::new(quiet);
        let (plan, dynamics, seconds) = py
            .detach(|| -> anyhow::Result<_> {
                let triggers = self.info.cardiac_triggers_s.as_deref();
                let (mut plan, n_frames) = match &self.source {
                    RunSource::Recording(data) => (
                        Plan::new(&self.options, &dynamics, &**data, triggers)?,
                        data.n_frames(),
                    ),
                    // The filtered images hold the images' grid, angles and rates.
                    RunSource::Images(images) => (
                        Plan::for_images(
                            &self.options,
                            &dynamics,
                            &self.processed.out.filtered,
                            images.frames,
                            triggers,
                        )?,
                        images.frames,
                    ),
                };
                // Windows the run spaced out for memory stay so unless new ones are asked for.
                if let Some(fit @ pcuvd_app::run::DynamicsFit::Stepped { .. }) =
                    &self.plan.dynamics_fit
                    && dynamics.window_ms.is_none()
                    && dynamics.window_step_ms.is_none()
                    && plan.dynamics.is_some()
                {
                    plan.apply_fit(fit.clone(), n_frames)?;
                }
                let clock = std::time::Instant::now();
                let dynamics =
                    pcuvd_app::run::rerun_dynamics(&self.processed, &self.plan, &plan, &progress)?;
                Ok((plan, dynamics, clock.elapsed().as_secs_f64()))
            })
            .map_err(to_py)?;
        Ok(PyProcessResult {
            options: self.options.clone(),
            source: self.source.clone(),
            input: self.input.clone(),
            info: self.info.clone(),
            plan,
            processed: Processed {
                out: self.processed.out.clone(),
                dynamics,
                dynamics_s: seconds,
                ensembles: self.processed.ensembles.clone(),
                ensembles_in_store: self.processed.ensembles_in_store,
                blocks: self.processed.blocks,
                segments: self.processed.segments.clone(),
                kept: self.processed.kept.clone(),
            },
            simulated: self.simulated.clone(),
        })
    }

    /// The summary.json this result would be saved with (less the writing timings), as JSON.
    fn summary_json(&self) -> PyResult<String> {
        let source = self.source().map_err(to_py)?;
        let against = match &self.source {
            RunSource::Recording(data) => pcuvd_app::against_truth::score_run(
                &source.input,
                self.simulated.as_ref().map(|s| s.scenario.as_str()),
                &**data,
                &self.processed,
            ),
            RunSource::Images(_) => None,
        };
        let mut summary = pcuvd_app::summary::Summary::of(
            self.source.input(),
            &self.plan,
            &self.processed,
            source,
        );
        summary.against_truth = against.map(|scored| scored.record);
        summary.sites = SiteSpectrograms::of(&self.plan, &self.processed)
            .map_err(to_py)?
            .map(|sites| sites.records(&self.processed.out.grid));
        serde_json::to_string(&summary).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// The maps scored against the truth of the simulation `scenario` (TOML, as `pcuvd.simulate`
    /// returns it with its truth) describes, as JSON: summary.json's `against_truth` for a
    /// recording simulated in memory.
    fn against_truth_json(&self, py: Python<'_>, scenario: &str) -> PyResult<String> {
        let scenario = pcuvd_app::scenario::Scenario::parse(scenario)
            .map_err(|e| PyValueError::new_err(format!("scenario: {e:#}")))?;
        let recording = self
            .source
            .recording("scoring against a simulation's truth")
            .map_err(to_py)?;
        let scored = py.detach(|| {
            pcuvd_app::against_truth::score_against(
                scenario,
                "the scenario given",
                recording,
                &self.processed,
            )
        });
        serde_json::to_string(&scored.record).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// Writes into `folder` exactly what `pcuvd process` writes (maps, figures, summary.json last);
    /// a folder that holds anything is refused unless `force`. `nifti`: also the NIfTI images,
    /// named by map, or by BIDS entities `bids` = (subject, session, task). `zarr`: also the
    /// run as one Zarr store (`pcuvd.zarr`). Returns the figures.
    #[pyo3(signature = (folder, force, nifti=false, bids=(None, None, None), zarr=false))]
    fn save(
        &self,
        py: Python<'_>,
        folder: PathBuf,
        force: bool,
        nifti: bool,
        bids: (Option<String>, Option<String>, Option<String>),
        zarr: bool,
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
            let zarr = match zarr {
                true => Some(pcuvd_app::zarr::ZarrStore::create(
                    &folder.join(pcuvd_app::zarr::STORE),
                    self.source.input(),
                    &self.plan,
                )?),
                false => None,
            };
            let name = std::path::Path::new(&self.input)
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            pcuvd_app::summary::save(
                &folder,
                self.source.input(),
                &self.plan,
                &self.processed,
                pcuvd_app::summary::Record {
                    source,
                    name: &name,
                    extra_timings: &[("checksum", checksum_s)],
                    nifti: naming.as_ref(),
                    zarr,
                    simulated_from: self.simulated.as_ref().map(|s| s.scenario.as_str()),
                },
                &Lines::new(true),
            )
            .map(|saved| saved.figures)
        })
        .map_err(to_py)
    }
}
