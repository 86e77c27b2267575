//! `pcuvd.dask`'s native half: the segments of one recording, or of beamformed images formed
//! elsewhere (an images manifest), processed apart (each in the process that calls it, reading
//! its own frames from the file) and joined into the result `pcuvd process` gives. Every call
//! opens the input from its path and plans the run from the same options, so every process cuts
//! it the same way.

use pcuvd::pipeline::segments::SegmentSource;
use pyo3::types::PyBytes;

use crate::process::{Opened, OpenedImages, PyProcessResult, open, open_checked};
use crate::*;

/// What a segmented run reads: a recording of channel data, or images formed elsewhere.
enum Input {
    Recording(Box<Opened>),
    Images(Box<OpenedImages>),
}

impl Input {
    /// Opens the recording or images manifest at `path` with the reader `overrides` and plans
    /// the run of `options` (both JSON); `checked`: the run's memory checked as `pcuvd process`
    /// checks it, which may space the dynamics windows further apart or drop the stage
    /// ([`pcuvd_app::run::Plan::dynamics_fit`]).
    fn open(
        path: &std::path::Path,
        overrides: &str,
        options: &str,
        checked: bool,
    ) -> PyResult<Self> {
        Ok(match pcuvd_io::open::is_images_input(path) {
            true => Input::Images(Box::new(OpenedImages::open(
                path, overrides, options, checked,
            )?)),
            false if checked => Input::Recording(Box::new(open_checked(path, overrides, options)?)),
            false => Input::Recording(Box::new(open(path, overrides, options)?)),
        })
    }

    /// Opens it as [`Input::open`] does unchecked, in a worker or for the join, with the plan
    /// the run's memory check gave where it was counted ([`segment_count`]): what it did to the
    /// dynamics stage there (`dynamics_fit`, JSON) is done here too, so that every process runs
    /// one plan whatever memory it has.
    fn open_as_counted(
        path: &std::path::Path,
        overrides: &str,
        options: &str,
        dynamics_fit: Option<String>,
    ) -> PyResult<Self> {
        let mut input = Self::open(path, overrides, options, false)?;
        if let Some(fit) = dynamics_fit {
            let fit: pcuvd_app::run::DynamicsFit = serde_json::from_str(&fit)
                .map_err(|e| PyValueError::new_err(format!("dynamics_fit: {e}")))?;
            let n_frames = input.source().n_frames();
            let plan = match &mut input {
                Input::Recording(opened) => &mut opened.plan,
                Input::Images(opened) => &mut opened.images.plan,
            };
            plan.apply_fit(fit, n_frames).map_err(to_py)?;
        }
        Ok(input)
    }

    /// Where the segments' image series come from.
    fn source(&self) -> SegmentSource<'_> {
        match self {
            Input::Recording(opened) => SegmentSource::Channels(opened.source.as_ref()),
            Input::Images(opened) => SegmentSource::Images(&opened.images.images),
        }
    }

    /// The run's plan.
    fn plan(&self) -> &Plan {
        match self {
            Input::Recording(opened) => &opened.plan,
            Input::Images(opened) => &opened.images.plan,
        }
    }
}

/// How many segments the run of `path` with `options` has (its memory checked as
/// `pcuvd process` checks it), whether the later ones need segment 0's `window_intervals`, and
/// what the check did to the dynamics stage (JSON, `None` when nothing: pass it on to
/// [`process_segment`] and [`join_segments`]) with the note that says so; `None` when it is
/// processed whole.
#[pyfunction]
pub(crate) fn segment_count(
    py: Python<'_>,
    path: PathBuf,
    overrides: &str,
    options: &str,
) -> PyResult<Option<SegmentCount>> {
    py.detach(|| {
        let input = Input::open(&path, overrides, options, true)?;
        let fit = match &input.plan().dynamics_fit {
            Some(fit) => Some((
                serde_json::to_string(fit)
                    .map_err(|e| PyValueError::new_err(format!("dynamics_fit: {e}")))?,
                keywords::as_python(&fit.note()),
            )),
            None => None,
        };
        let (fit, note) = fit.unzip();
        Ok(pcuvd_app::run::segment_count(input.source(), input.plan())
            .map(|(count, settles)| (count, settles, fit, note)))
    })
}

/// [`segment_count`]'s answer: segments, whether segment 0 settles the windows' Nyquist
/// intervals, the memory check's change to the dynamics stage (JSON) and its note.
type SegmentCount = (usize, bool, Option<String>, Option<String>);

/// Segment `index` of the run of `path` with `options`, processed here: its part as bytes and,
/// from segment 0, the Nyquist intervals every later segment's velocity windows take
/// (`window_intervals`).
#[pyfunction]
pub(crate) fn process_segment<'py>(
    py: Python<'py>,
    path: PathBuf,
    overrides: &str,
    options: &str,
    index: usize,
    window_intervals: Option<u32>,
    dynamics_fit: Option<String>,
) -> PyResult<(Bound<'py, PyBytes>, Option<u32>)> {
    let (bytes, settled) = py.detach(|| -> PyResult<_> {
        let input = Input::open_as_counted(&path, overrides, options, dynamics_fit)?;
        let part = pcuvd_app::run::run_segment(
            input.source(),
            input.plan(),
            index,
            window_intervals,
            &Lines::new(true),
        )
        .with_context(|| format!("{}: segment {index}", path.display()))
        .map_err(to_py)?;
        let bytes = pcuvd_app::run::part_to_bytes(&part).map_err(to_py)?;
        Ok((bytes, part.window_intervals))
    })?;
    Ok((PyBytes::new(py, &bytes), settled))
}

/// The result of the run of `path` with `options` from every segment's part (`parts`, in any
/// order): what `pcuvd.process` gives for the same input and options.
#[pyfunction]
pub(crate) fn join_segments(
    py: Python<'_>,
    path: PathBuf,
    overrides: &str,
    options: &str,
    parts: Vec<Vec<u8>>,
    quiet: bool,
    dynamics_fit: Option<String>,
) -> PyResult<PyProcessResult> {
    let progress = Lines::new(quiet);
    let (input, processed) = py.detach(|| -> PyResult<_> {
        let input = Input::open_as_counted(&path, overrides, options, dynamics_fit)?;
        let parts = parts
            .iter()
            .map(|bytes| pcuvd_app::run::part_from_bytes(bytes))
            .collect::<anyhow::Result<Vec<_>>>()
            .map_err(to_py)?;
        let processed =
            pcuvd_app::run::join_segments(input.source(), input.plan(), parts, &progress)
                .with_context(|| format!("{}: joining its segments", path.display()))
                .map_err(to_py)?;
        Ok((input, processed))
    })?;
    let name = path.display().to_string();
    match input {
        Input::Recording(opened) => (*opened).result(py, name, processed),
        Input::Images(opened) => (*opened).result(py, name, processed),
    }
}
