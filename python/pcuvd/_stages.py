"""The chain's stages on plain numpy arrays: each is the function `process` runs."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from . import _checks, _pcuvd

FRAME_AXES = ("frames", "channels", "samples")
SERIES_AXES = ("z", "x", "frames")


def decode_hadamard(
    rf: Any,
    n_angles: int,
    *,
    slot_delay_s: float,
    sampling_freq_hz: float,
    alignment: str = "mid-frame",
    axes: Sequence[str] = ("events", "channels", "samples"),
) -> np.ndarray:
    """Decodes Hadamard-coded RF into one record per angle.

    rf: (events, channels, samples) real (axes in the order `axes` names), events = frames ×
    n_angles; every event fires all `n_angles` slots `slot_delay_s` apart with the polarities
    of the Hadamard matrix's rows. alignment: "mid-frame" (each event's slow-time series first
    resampled to its frame's mid-event time) or "simultaneous" (the paper's eq. 2).
    Returns float32 (angles, frames, channels, samples): Hᵀ·M, i.e. n × each angle's record for
    a still medium (the coherent sum that is coding's SNR gain), each advanced to its own slot's
    time origin.
    """
    array = _checks.reorder("rf", np.asarray(rf), axes, ("events", "channels", "samples"))
    rf32 = _checks.real32("rf", array, ("events", "channels", "samples"))
    fs = _checks.finite_number("sampling_freq_hz", sampling_freq_hz)
    delay = _checks.finite_number("slot_delay_s", slot_delay_s, positive=False)
    n_angles = _checks.whole_number("n_angles", n_angles)
    return _pcuvd.decode_hadamard_rf(rf32, n_angles, delay, fs, alignment)


def rf_to_iq(
    rf: Any,
    *,
    sampling_freq_hz: float,
    demod_freq_hz: float,
    t0_s: float = 0.0,
    cutoff_hz: float | None = None,
    axes: Sequence[str] = FRAME_AXES,
) -> np.ndarray:
    """IQ demodulation as the pipeline does it: mixing with exp(−2πi f_d t), t = t0 + n/f_s,
    then a zero-phase Hamming-windowed low-pass (default cut-off: halfway to the nearest alias
    of −2 f_d, at most f_d) with gain 2.

    rf: (frames, channels, samples) real, or (channels, samples). Returns complex64 of the same
    shape, in the order (frames, channels, samples).
    """
    array = np.asarray(rf)
    if array.ndim == 2:
        array = array[None]
        axes = FRAME_AXES
    array = _checks.reorder("rf", array, axes, FRAME_AXES)
    rf32 = _checks.real32("rf", array, FRAME_AXES)
    iq = _pcuvd.rf_to_iq(
        rf32,
        _checks.finite_number("sampling_freq_hz", sampling_freq_hz),
        _checks.finite_number("demod_freq_hz", demod_freq_hz),
        _checks.finite_number("t0_s", t0_s, positive=False),
        None if cutoff_hz is None else _checks.finite_number("cutoff_hz", cutoff_hz),
    )
    return iq[0] if np.asarray(rf).ndim == 2 else iq


def beamform(
    iq: Any,
    *,
    probe: str | dict,
    angle_rad: float,
    sampling_freq_hz: float,
    demod_freq_hz: float,
    t0_s: float,
    grid_m: Sequence[float] | None = None,
    x_m: Any = None,
    z_m: Any = None,
    sound_speed_m_s: float = 1540.0,
    f_number: float = _pcuvd.DEFAULT_F_NUMBER,
    apodization: str = "hann",
    axes: Sequence[str] = FRAME_AXES,
) -> np.ndarray:
    """Delay-and-sum of one steered plane wave's IQ channel data onto a pixel grid.

    iq: (frames, channels, samples) complex baseband (from `rf_to_iq`). probe: a preset name or
    the dict of `Recording.probe`. The pixel grid: grid_m = (x_min, x_max, z_min, z_max, step)
    in m, or the pixel positions x_m (nx) and z_m (nz) in m (e.g. a result's `x`, `z`). Receive
    f-number `f_number` (depth / aperture), Hann or boxcar apodisation.
    Returns the complex image series (nz, nx, frames), complex64.
    """
    import json

    array = _checks.reorder("iq", np.asarray(iq), axes, FRAME_AXES)
    data = _checks.complex64("iq", array, FRAME_AXES)
    grid, x, z = _grid(grid_m, x_m, z_m)
    return _pcuvd.beamform_iq(
        data,
        json.dumps(probe),
        _checks.finite_number("angle_rad", angle_rad, positive=False),
        _checks.finite_number("sampling_freq_hz", sampling_freq_hz),
        _checks.finite_number("demod_freq_hz", demod_freq_hz),
        _checks.finite_number("t0_s", t0_s, positive=False),
        _checks.finite_number("sound_speed_m_s", sound_speed_m_s),
        grid,
        x,
        z,
        _checks.finite_number("f_number", f_number),
        apodization,
    )


def _grid(grid_m: Sequence[float] | None, x_m: Any, z_m: Any) -> tuple[Any, Any, Any]:
    """A pixel grid as the native stages take it: (x_min, x_max, z_min, z_max, step) checked,
    or the pixel positions as lists."""
    grid = None
    if grid_m is not None:
        grid = [_checks.finite_number("grid_m", v, positive=False) for v in grid_m]
        if len(grid) != 5:
            raise ValueError(
                f"grid_m: expected (x_min, x_max, z_min, z_max, step), got {grid_m!r}"
            )
    x = None if x_m is None else _checks.float64("x_m", x_m, ("x",)).tolist()
    z = None if z_m is None else _checks.float64("z_m", z_m, ("z",)).tolist()
    return grid, x, z


def svd_filter(
    series: Any,
    *,
    low: int | str = "auto",
    high: int | str = "off",
    tissue_frequency: float = _pcuvd.DEFAULT_TISSUE_FREQUENCY,
    blocks: Sequence[int] | None = None,
) -> tuple[np.ndarray, dict]:
    """SVD clutter filter of an image series (nz, nx, frames).

    low: leading (tissue) components removed: a number, "auto" (from the tissue frequency
    limit `tissue_frequency` × frame rate), "similarity" or "off"; high: first trailing (noise)
    component removed, a number, "auto" (Marchenko–Pastur edge), "similarity" or "off".
    blocks: (rows, cols) pixels: filter overlapping blocks of that size each with its own
    cut-offs, blended back (block-wise SVD; a block smaller than the frames grows, the shorter
    side first, until it holds as many pixels); None filters the whole image at once.
    Returns the filtered series (complex64) and {"low", "high", "singular_values",
    "block_cut_offs", "block_starts"} (a block-wise filter: the medians of its blocks' cut-offs,
    no singular values, each block's (low, high), block rows first, and the blocks' first rows
    and columns (z_starts, x_starts); a whole-image filter: no blocks, "block_starts" None).
    """
    data = _checks.complex64("series", series, SERIES_AXES)
    if blocks is not None:
        sizes = tuple(blocks)
        if len(sizes) != 2:
            raise ValueError(f"blocks: expected positive sizes (rows, cols), got {sizes!r}")
        blocks = tuple(_checks.whole_number("blocks", b) for b in sizes)
    filtered, low_used, high_used, values, block_cut_offs, block_starts = _pcuvd.svd_filter(
        data,
        str(low),
        str(high),
        _checks.finite_number("tissue_frequency", tissue_frequency),
        blocks,
    )
    return filtered, {
        "low": low_used,
        "high": high_used,
        "singular_values": np.array(values),
        "block_cut_offs": [tuple(c) for c in block_cut_offs],
        "block_starts": None if block_starts is None else tuple(list(s) for s in block_starts),
    }


def _kernel(kernel: Sequence[int]) -> tuple[int, int]:
    sizes = tuple(kernel)
    if len(sizes) != 2:
        raise ValueError(f"kernel: expected odd sizes (rows, cols), got {sizes!r}")
    rows, cols = (_checks.whole_number("kernel", k) for k in sizes)
    if rows % 2 == 0 or cols % 2 == 0:
        raise ValueError(f"kernel: expected odd sizes (rows, cols), got {sizes!r}")
    return rows, cols


def power_doppler(series: Any, *, kernel: Sequence[int] = (1, 1)) -> np.ndarray:
    """Power Doppler: mean |S|² over frames of a series (nz, nx, frames), averaged over a
    (rows, cols) box of pixels. Returns float64 (nz, nx)."""
    data = _checks.complex64("series", series, SERIES_AXES)
    return _pcuvd.power_doppler(data, _kernel(kernel))


def kasai(
    series: Any,
    *,
    sound_speed_m_s: float,
    frame_rate_hz: float,
    center_freq_hz: float,
    kernel: Sequence[int] = (1, 1),
) -> np.ndarray:
    """Lag-1 autocorrelation (Kasai) projection velocity of a series (nz, nx, frames):
    V = −c·f_frame/(4π f_c) · arg R(1) in m/s, > 0 where the echo path lengthens (moving away).
    Returns float64 (nz, nx)."""
    data = _checks.complex64("series", series, SERIES_AXES)
    return _pcuvd.kasai(
        data,
        _checks.finite_number("sound_speed_m_s", sound_speed_m_s),
        _checks.finite_number("frame_rate_hz", frame_rate_hz),
        _checks.finite_number("center_freq_hz", center_freq_hz),
        _kernel(kernel),
    )


def _projections(projections: Any, angles_rad: Sequence[float]) -> tuple[np.ndarray, list]:
    data = _checks.float64("projections", projections, ("angles", "z", "x"))
    angles = [_checks.finite_number("angles_rad", a, positive=False) for a in angles_rad]
    if len(angles) != data.shape[0]:
        raise ValueError(
            f"projections: {data.shape[0]} maps for {len(angles)} angles (angles_rad)"
        )
    return data, angles


def vector_ls(projections: Any, angles_rad: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Conventional UVD: least-squares (vx, vz) in m/s from projections (angles, nz, nx) in m/s
    at `angles_rad`, with V_θ = (vx·sin θ + vz·(1 + cos θ))/2. NaN projections are left out."""
    data, angles = _projections(projections, angles_rad)
    return _pcuvd.vector_fit(data, angles, None)


def vector_irls(
    projections: Any,
    angles_rad: Sequence[float],
    *,
    lambda_mm_s: float = _pcuvd.DEFAULT_IRLS_LAMBDA_MM_S,
    epsilon: float = _pcuvd.DEFAULT_IRLS_EPSILON,
    max_iterations: int = _pcuvd.DEFAULT_IRLS_MAX_ITERATIONS,
) -> tuple[np.ndarray, np.ndarray]:
    """PC-UVD: iteratively reweighted least squares (vx, vz) in m/s, weights 1/(|residual| + λ)
    (λ in mm/s), stopped when no weight changes by more than `epsilon` or after
    `max_iterations`."""
    data, angles = _projections(projections, angles_rad)
    irls = (
        _checks.finite_number("lambda_mm_s", lambda_mm_s),
        _checks.finite_number("epsilon", epsilon),
        _checks.whole_number("max_iterations", max_iterations),
    )
    return _pcuvd.vector_fit(data, angles, irls)


def resistivity_index(psv: Any, edv: Any) -> np.ndarray:
    """Resistivity index (PSV − EDV)/PSV of two speed maps (nz, nx) in m/s (NaN where PSV is
    not positive or either is NaN)."""
    a = _checks.float64("psv", psv, ("z", "x"))
    b = _checks.float64("edv", edv, ("z", "x"))
    return _pcuvd.resistivity_index(a, b)


# The processing keywords that reach the dynamics stage of images formed elsewhere.
_RI_MAPS_PROCESSING = (
    "doppler_estimator",
    "doppler_kernel",
    "irls_lambda",
    "irls_epsilon",
    "irls_max_iterations",
    "dealias",
)


def ri_maps(
    filtered: Any,
    *,
    frame_rate_hz: float,
    center_freq_hz: float,
    sound_speed_m_s: float = 1540.0,
    grid_m: Sequence[float] | None = None,
    x_m: Any = None,
    z_m: Any = None,
    angles_rad: Sequence[float] = (0.0,),
    **options: Any,
) -> dict:
    """The dynamics stage (sliding-window velocity, heart rate, PSV/EDV/RI maps, vessel classes)
    on clutter-filtered image series formed elsewhere: a scanner's beamformed IQ, say, filtered
    with `svd_filter`.

    filtered: one series (nz, nx, frames) (one steering angle, or a compound image), or one per
    angle of `angles_rad` (a sequence, or an (angles, nz, nx, frames) array), complex baseband
    at `center_freq_hz` and `frame_rate_hz` (the compound frame rate). The pixel grid: grid_m =
    (x_min, x_max, z_min, z_max, step) in m, or the pixel positions x_m (nx) and z_m (nz) in m.
    One angle gives no vector: its RI is read from the colour-Doppler speed |Vz| (a ratio, so a
    vessel that keeps its direction to the beam reads its own RI; vessels across the beam are
    undetermined). options: the Doppler keywords of `pcuvd.process` (`doppler_estimator`:
    "loupas", the default, needs axial pixels no coarser than a wavelength, or "kasai";
    `doppler_kernel`, whose box also averages the power Doppler the vessel mask is drawn on;
    `irls_*`, `dealias`: "auto" decides in each window, there being no whole-recording maps to
    decide on) and the dynamics keywords of `pcuvd.dynamics` (`heart_rate_hz`,
    `window_ms`, `cardiac_triggers`, `artery_ri_min`, ...), with `process`'s defaults.
    Returns {"ri", "psv", "edv", "psv_spread", "edv_spread", "ri_spread", "vessel_class",
    "flow_up", "speed_series", "times", "heart_rate_hz", "cycles", "cycles_from",
    "axial_only"}: maps (nz, nx) in m/s where they are speeds, named as `process` names them.
    """
    if isinstance(filtered, np.ndarray) and filtered.ndim == 4:
        series = list(filtered)
    elif isinstance(filtered, (list, tuple)):
        series = list(filtered)
    else:
        series = [filtered]
    series = [_checks.complex64("filtered", s, SERIES_AXES) for s in series]
    angles = [_checks.finite_number("angles_rad", a, positive=False) for a in angles_rad]
    if len(angles) != len(series):
        raise ValueError(f"filtered: {len(series)} series for {len(angles)} angles (angles_rad)")
    grid, x, z = _grid(grid_m, x_m, z_m)
    doppler = {k: options.pop(k) for k in list(options) if k in _RI_MAPS_PROCESSING}
    dynamics = _checks.to_options(
        "ri_maps", options, [*_pcuvd.option_names_of("dynamics"), *_RI_MAPS_PROCESSING]
    )
    return _pcuvd.ri_maps_of_images(
        series,
        angles,
        _checks.finite_number("frame_rate_hz", frame_rate_hz),
        _checks.finite_number("center_freq_hz", center_freq_hz),
        _checks.finite_number("sound_speed_m_s", sound_speed_m_s),
        _checks.to_options("ri_maps", doppler, _RI_MAPS_PROCESSING),
        dynamics,
        grid,
        x,
        z,
    )
