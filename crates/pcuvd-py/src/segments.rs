//! `pcuvd.dask`'s native half: the segments of one recording processed apart (each in the process
//! that calls it, reading its own frames from the file) and joined into the result `pcuvd process`
//! gives. Every call opens the recording from its path and plans the run from the same options, so
//! every process cuts the recording the same way.

use pyo3::types::PyBytes;

use crate::process::{PyProcessResult, open, open_checked};
use crate::*;

/// How many segments the run of `path` with `options` has (its memory checked as
/// `pcuvd process` checks it), and whether the later ones need segment 0's `window_intervals`;
/// `None` when it is processed whole.
#[pyfunction]
pub(crate) fn segment_count(
    py: Python<'_>,
    path: PathBuf,
    overrides: &str,
    options: &str,
) -> PyResult<Option<(usize, bool)>> {
    py.detach(|| {
        let opened = open_checked(&path, overrides, options)?;
        Ok(pcuvd_app::run::segment_count(
            opened.source.as_ref(),
            &opened.plan,
        ))
    })
}

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
) -> PyResult<(Bound<'py, PyBytes>, Option<u32>)> {
    let (bytes, settled) = py.detach(|| -> PyResult<_> {
        let opened = open(&path, overrides, options)?;
        let part = pcuvd_app::run::run_segment(
            opened.source.as_ref(),
            &opened.plan,
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
/// order): what `pcuvd.process` gives for the same recording and options.
#[pyfunction]
pub(crate) fn join_segments(
    py: Python<'_>,
    path: PathBuf,
    overrides: &str,
    options: &str,
    parts: Vec<Vec<u8>>,
    quiet: bool,
) -> PyResult<PyProcessResult> {
    let progress = Lines::new(quiet);
    let (opened, processed) = py.detach(|| -> PyResult<_> {
        let opened = open(&path, overrides, options)?;
        let parts = parts
            .iter()
            .map(|bytes| pcuvd_app::run::part_from_bytes(bytes))
            .collect::<anyhow::Result<Vec<_>>>()
            .map_err(to_py)?;
        let processed =
            pcuvd_app::run::join_segments(opened.source.as_ref(), &opened.plan, parts, &progress)
                .with_context(|| format!("{}: joining its segments", path.display()))
                .map_err(to_py)?;
        Ok((opened, processed))
    })?;
    opened.result(py, path.display().to_string(), processed)
}
