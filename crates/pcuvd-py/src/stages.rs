//! The stages on plain arrays, each the function `process` runs: decoding, demodulation,
//! beamforming, clutter filtering, Doppler, vector fits and the resistivity index.

use crate::*;

pub(crate) fn alignment(name: &str) -> PyResult<EventAlignment> {
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
pub(crate) fn decode_hadamard_rf<'py>(
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
pub(crate) fn rf_to_iq<'py>(
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
pub(crate) fn grid_from(
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
pub(crate) fn beamform_iq<'py>(
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

pub(crate) fn rank_cut(text: &str, name: &str) -> PyResult<RankCut> {
    text.parse()
        .map_err(|e| PyValueError::new_err(format!("{name} {e}")))
}

/// A filtered series, the low and high cut-offs used, the singular values and each block's
/// cut-offs (block-wise filtering).
pub(crate) type Filtered<'py> = (
    Bound<'py, PyArray3<Complex32>>,
    usize,
    usize,
    Vec<f64>,
    Vec<(usize, usize)>,
    Option<(Vec<usize>, Vec<usize>)>,
);

/// SVD clutter filter of a series (nz, nx, frames): returns the filtered series and the low and
/// high cut-offs used and the singular values; `blocks` (rows, columns of pixels) filters
/// overlapping blocks of that size each on its own.
#[pyfunction]
#[pyo3(signature = (series, low, high, tissue_frequency, blocks=None))]
pub(crate) fn svd_filter<'py>(
    py: Python<'py>,
    series: PyReadonlyArray3<'py, Complex32>,
    low: &str,
    high: &str,
    tissue_frequency: f64,
    blocks: Option<(usize, usize)>,
) -> PyResult<Filtered<'py>> {
    let params = ClutterParams {
        low: rank_cut(low, "low")?,
        high: rank_cut(high, "high")?,
        tissue_frequency,
        blocks,
    };
    let mut data = series.as_array().as_standard_layout().into_owned();
    check_series_scale(data.view(), "the series")?;
    let report = py
        .detach(|| clutter::svd_filter(&mut data, &params))
        .map_err(lib_err)?;
    Ok((
        data.into_pyarray(py),
        report.low,
        report.high,
        report.singular_values,
        report.block_cut_offs,
        (report.block_layout).map(|layout| (layout.z_starts, layout.x_starts)),
    ))
}

/// Refuses a series whose peak magnitude lies outside what the stages' single-precision lag
/// products hold ([`pcuvd::core::lags::SAMPLE_PEAK_RANGE`]), naming it as `what`.
fn check_series_scale(series: ndarray::ArrayView3<'_, Complex32>, what: &str) -> PyResult<()> {
    let peak = match series.as_slice_memory_order() {
        Some(values) => pcuvd::core::lags::complex_peak_magnitude(values),
        None => pcuvd::core::lags::complex_peak_magnitude(series.iter()),
    };
    pcuvd::core::lags::check_sample_peak(peak, what).map_err(lib_err)
}

pub(crate) fn autocorrelation(
    py: Python<'_>,
    series: &PyReadonlyArray3<'_, Complex32>,
    kernel: (usize, usize),
) -> PyResult<pcuvd::estimate::doppler::Autocorrelation> {
    let view = series.as_array();
    check_series_scale(view, "the series")?;
    py.detach(|| pcuvd::estimate::doppler::autocorrelation(view, kernel))
        .map_err(lib_err)
}

/// Power Doppler (mean |S|² over frames) of a series (nz, nx, frames), averaged over `kernel` pixels.
#[pyfunction]
pub(crate) fn power_doppler<'py>(
    py: Python<'py>,
    series: PyReadonlyArray3<'py, Complex32>,
    kernel: (usize, usize),
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    Ok(autocorrelation(py, &series, kernel)?.power.into_pyarray(py))
}

/// Lag-1 (Kasai) projection velocity (m/s, positive = echo path lengthens) of a series
/// (nz, nx, frames), the autocorrelation averaged over `kernel` pixels.
#[pyfunction]
pub(crate) fn kasai<'py>(
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
pub(crate) type VectorMaps<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

/// Vector velocity (vx, vz) in m/s from projections (angles, nz, nx) at `angles_rad`; NaN
/// projections are left out. `irls`: None for least squares (UVD), else (λ mm/s, ε, iterations).
#[pyfunction]
#[pyo3(signature = (projections, angles_rad, irls=None))]
pub(crate) fn vector_fit<'py>(
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
pub(crate) fn resistivity_index<'py>(
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

/// The dynamics stage on clutter-filtered image series formed elsewhere: `series` one (nz, nx,
/// frames) per steering angle at `angles_rad` (one: RI of the colour-Doppler speed), on the
/// grid `grid_m` (x_min, x_max, z_min, z_max, step, m) or the pixel positions `x_m`, `z_m`, at
/// `frame_rate_hz`, `center_freq_hz` and `sound_speed_m_s`; `processing`: the Doppler
/// keywords (estimator, kernel, IRLS, dealiasing; JSON), `options`: the dynamics keywords (JSON).
/// Returns the RI maps and the windows' series, named as `process`'s.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (series, angles_rad, frame_rate_hz, center_freq_hz, sound_speed_m_s, processing, options, grid_m=None, x_m=None, z_m=None))]
pub(crate) fn ri_maps_of_images<'py>(
    py: Python<'py>,
    series: Vec<PyReadonlyArray3<'py, Complex32>>,
    angles_rad: Vec<f64>,
    frame_rate_hz: f64,
    center_freq_hz: f64,
    sound_speed_m_s: f64,
    processing: &str,
    options: &str,
    grid_m: Option<[f64; 5]>,
    x_m: Option<Vec<f64>>,
    z_m: Option<Vec<f64>>,
) -> PyResult<Bound<'py, PyDict>> {
    let processing: ProcessingSettings = settings(processing)?;
    let grid = grid_from(grid_m, x_m, z_m)?;
    let shape = grid.shape();
    let series: Vec<_> = series
        .iter()
        .map(|s| s.as_array().as_standard_layout().into_owned())
        .collect();
    for (k, one) in series.iter().enumerate() {
        check_series_scale(one.view(), &format!("series {k}"))?;
    }
    if let Some(bad) = series.iter().find(|s| (s.dim().0, s.dim().1) != shape) {
        return Err(PyValueError::new_err(format!(
            "a series of {} × {} pixels on a grid of {} × {} (nz, nx)",
            bad.dim().0,
            bad.dim().1,
            shape.0,
            shape.1
        )));
    }
    let images = pcuvd::form::images::AngleImages {
        grid,
        angles: angles_rad,
        frame_rate: frame_rate_hz,
        sound_speed: sound_speed_m_s,
        demodulation_frequency: center_freq_hz,
        coverage: None,
        series,
    };
    let dynamics: DynamicsSettings = settings(options)?;
    let (series, maps) = py
        .detach(|| pcuvd_app::run::dynamics_of_images(&images, &processing, &dynamics))
        .map_err(to_py)?;
    let dict = PyDict::new(py);
    put_ri_maps(&dict, &maps, &series, &|_| true)?;
    dict.set_item("heart_rate_hz", maps.heart_rate_hz)?;
    dict.set_item("cycles", maps.cycles)?;
    dict.set_item("cycles_from", maps.cycle_source.describe())?;
    dict.set_item("axial_only", series.axial_only)?;
    Ok(dict)
}

/// The dynamics stage's maps and speed series whose names `want` takes into `dict`, under the
/// names `process` gives them (the speed series, the size of the windows, made only if taken).
pub(crate) fn put_ri_maps(
    dict: &Bound<'_, PyDict>,
    maps: &pcuvd::dynamics::RiMaps,
    series: &pcuvd::dynamics::VelocitySeries,
    want: &dyn Fn(&str) -> bool,
) -> PyResult<()> {
    let py = dict.py();
    let float_maps = [
        ("ri", &maps.ri),
        ("psv", &maps.psv),
        ("edv", &maps.edv),
        ("psv_spread", &maps.psv_spread),
        ("edv_spread", &maps.edv_spread),
        ("ri_spread", &maps.ri_spread),
    ];
    for (name, map) in float_maps {
        if want(name) {
            dict.set_item(name, map.to_pyarray(py))?;
        }
    }
    if want("vessel_class") {
        dict.set_item("vessel_class", maps.vessel_class.to_pyarray(py))?;
    }
    if want("flow_up") {
        dict.set_item("flow_up", maps.flow_up.mapv(u8::from).into_pyarray(py))?;
    }
    if want("speed_series") {
        dict.set_item("speed_series", series.speed().into_pyarray(py))?;
    }
    if want("times") {
        dict.set_item("times", PyArray1::from_slice(py, &series.times_s))?;
    }
    Ok(())
}
