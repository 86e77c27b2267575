//! `pcuvd._pcuvd`: the native half of the `pcuvd` Python package.
//!
//! Every entry calls the library (`pcuvd`, `pcuvd-io`) or the application layer every front end
//! shares (`pcuvd_app`): keyword options arrive as a dict (JSON) that becomes the same typed
//! settings the command line's options are, so a result from Python is the one `pcuvd process` /
//! `simulate` / `paper` gives, with the same defaults and the same messages. Computation runs with the GIL released, on the Rust thread
//! pool. The Python half (`python/pcuvd/`) checks dtypes and shapes, casts, and documents.

#![warn(missing_docs)]

mod keywords;
mod process;
mod recording;
mod segments;
mod simulation;
mod stages;

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use keywords::PyLines as Lines;
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
    let message = keywords::as_python(&pcuvd_app::one_line(&error));
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
    let options = &mut serde_json::Deserializer::from_str(options);
    serde_path_to_error::deserialize(options).map_err(|e| {
        // The JSON is the package's own, one line long: where in it says nothing to the user;
        // the keyword does.
        let why = e.inner().to_string();
        let why = why
            .rsplit_once(" at line ")
            .map_or(why.as_str(), |(why, _)| why);
        let keyword = e.path().to_string();
        PyValueError::new_err(match keyword.as_str() {
            "." | "" => format!("options: {why}"),
            _ => format!("{keyword}: {why}"),
        })
    })
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
const PROCESSING_ALIASES: [&str; 2] = ["grid_mm", "sites_mm"];
/// The keyword aliases of [`DynamicsSettings`].
const DYNAMICS_ALIASES: [&str; 1] = ["heart_rate_hz"];

use process::*;
use recording::*;
use segments::*;
use simulation::*;
use stages::*;

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
    m.add_function(wrap_pyfunction!(process::process, m)?)?;
    m.add_function(wrap_pyfunction!(process_file, m)?)?;
    m.add_function(wrap_pyfunction!(segment_count, m)?)?;
    m.add_function(wrap_pyfunction!(process_segment, m)?)?;
    m.add_function(wrap_pyfunction!(join_segments, m)?)?;
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
    m.add_function(wrap_pyfunction!(ri_maps_of_images, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(study, m)?)?;
    Ok(())
}
