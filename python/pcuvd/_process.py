"""`pcuvd.process`: the chain of `pcuvd process`, with its defaults, from Python."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from . import _checks, _pcuvd
from ._recording import Recording, reader_overrides

# What each array of a result is, for docs and `to_xarray`: (dimensions, description).
MAPS: dict[str, tuple[tuple[str, ...], str]] = {
    "x": (("x",), "pixel columns (m)"),
    "z": (("z",), "pixel rows, depth (m)"),
    "bmode_db": (("z", "x"), "B-mode (dB, 0 at the brightest pixel)"),
    "power_doppler": (("z", "x"), "power Doppler of the compounded, filtered series (|IQ|²)"),
    "color_doppler": (("z", "x"), "axial velocity (m/s, > 0 moving away from the probe)"),
    "signed_power_doppler": (
        ("z", "x"),
        "power Doppler signed by the colour Doppler (|IQ|², > 0 moving away from the probe)",
    ),
    "projections": (("angle", "z", "x"), "per-angle projection velocity V_θ (m/s; NaN unreached)"),
    "projection_nyquist": (
        ("angle", "z", "x"),
        "Nyquist velocity v_N of each projection (m/s; from its mean frequency with Loupas)",
    ),
    "vx": (("z", "x"), "lateral velocity, PC-UVD IRLS-WLS (m/s, > 0 toward +x)"),
    "vz": (("z", "x"), "axial velocity, PC-UVD IRLS-WLS (m/s, > 0 deeper)"),
    "speed": (("z", "x"), "speed, PC-UVD IRLS-WLS (m/s)"),
    "vx_ls": (("z", "x"), "lateral velocity, UVD least squares (m/s)"),
    "vz_ls": (("z", "x"), "axial velocity, UVD least squares (m/s)"),
    "speed_ls": (("z", "x"), "speed, UVD least squares (m/s)"),
    "alias_counts": (("angle", "z", "x"), "alias count k per angle, PC-UVD (V_θ + 2k·v_N)"),
    "alias_counts_ls": (("angle", "z", "x"), "alias count k per angle, UVD least squares"),
    "ri": (("z", "x"), "resistivity index (PSV − EDV)/PSV (NaN outside vessels)"),
    "psv": (("z", "x"), "peak systolic speed (m/s; one steering angle: of |Vz|)"),
    "edv": (("z", "x"), "end-diastolic speed (m/s; one steering angle: of |Vz|)"),
    "psv_spread": (("z", "x"), "standard deviation of PSV across cardiac cycles (m/s)"),
    "edv_spread": (("z", "x"), "standard deviation of EDV across cardiac cycles (m/s)"),
    "ri_spread": (("z", "x"), "standard deviation of RI across cardiac cycles"),
    "vessel_class": (("z", "x"), "0 background, 1 arteriole, 2 venule, 3 undetermined"),
    "flow_up": (("z", "x"), "1 where the mean flow is toward the probe"),
    "speed_series": (
        ("time", "z", "x"),
        "speed in sliding windows (m/s; one steering angle: the colour-Doppler speed |Vz|)",
    ),
    "times": (("time",), "window centres (s)"),
    "ensemble_power_doppler": (("ensemble", "z", "x"), "power Doppler of each ensemble"),
    "ensemble_color_doppler": (("ensemble", "z", "x"), "axial velocity of each ensemble (m/s)"),
    "ensemble_signed_power_doppler": (
        ("ensemble", "z", "x"),
        "signed power Doppler of each ensemble (|IQ|², > 0 moving away from the probe)",
    ),
    "ensemble_vx": (("ensemble", "z", "x"), "lateral velocity of each ensemble (m/s)"),
    "ensemble_vz": (("ensemble", "z", "x"), "axial vector velocity of each ensemble (m/s)"),
    "ensemble_speed": (("ensemble", "z", "x"), "speed of each ensemble (m/s)"),
    "ensemble_times": (("ensemble",), "ensemble centre times (s)"),
    "clutter_block_cut_offs": (
        ("segment", "angle", "block_row", "block_column", "cut"),
        "the block-wise clutter filter's cut-offs of every block: first tissue component kept"
        " (low) and first noise component removed (high), per segment and angle",
    ),
    "site_spectrograms": (
        ("site", "site_time", "site_velocity_bin"),
        "Doppler spectrogram at each site (dB re its maximum; NaN without signal)",
    ),
    "site_velocities": (
        ("site", "site_velocity_bin"),
        "axial velocity of each spectrogram column (m/s, > 0 deeper)",
    ),
    "site_times": (("site_time",), "spectrogram window centres (s)"),
    "site_mean_velocity": (
        ("site", "site_time"),
        "mean Doppler velocity of each spectrogram window (m/s, > 0 deeper)",
    ),
}

# The arrays of `sites_mm`, computed together from the sites' spectrograms.
SITE_ARRAYS = tuple(name for name in MAPS if name.startswith("site_"))


def process_option_names() -> list[str]:
    """The keyword options `process` accepts (the settings' names: the CLI's options with `_`
    for `-`)."""
    return sorted(_pcuvd.option_names_of("process"))


class ProcessResult:
    """What `process` returns: the maps (numpy, SI units), the summary, `save` and `to_xarray`.

    Maps are attributes named as the files `pcuvd process` writes: `bmode_db`, `power_doppler`,
    `color_doppler`, `signed_power_doppler` (nz, nx); `projections` and `projection_nyquist`
    (angles, nz, nx); `vx`, `vz`, `speed` (PC-UVD) and
    `vx_ls`, `vz_ls`, `speed_ls` (UVD) with two or more angles; `alias_counts`,
    `alias_counts_ls` (angles, nz, nx) int8 with `dealias` on; `ri`, `psv`, `edv`,
    `psv_spread`, `edv_spread`, `ri_spread` (across cardiac cycles), `vessel_class`, `flow_up`
    (nz, nx), `speed_series` (windows, nz, nx) and `times` when the
    dynamics stage ran; `ensemble_power_doppler`, `ensemble_color_doppler`,
    `ensemble_signed_power_doppler`, `ensemble_vx`,
    `ensemble_vz`, `ensemble_speed` (ensembles, nz, nx) and `ensemble_times` with
    `ensemble_frames=N`; `site_spectrograms` (sites, windows, velocities, dB), `site_velocities`
    (sites, velocities), `site_times` and `site_mean_velocity` (sites, windows) with
    `sites_mm=[(x, z), ...]`; `clutter_block_cut_offs` (segments, angles, block rows, block
    columns, 2) with the block-wise clutter filter (the default); `x` (nx) and `z` (nz) in m.
    """

    def __init__(self, native: Any):
        self._native = native
        # The maps made so far, by name: each made once, when first asked for (a long
        # recording's speed series is the size of its velocity windows).
        self._maps: dict[str, np.ndarray] = {}

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        """Every map by name (a dict of numpy arrays)."""
        missing = [name for name in self._native.array_names() if name not in self._maps]
        if missing:
            self._maps.update(self._native.arrays_named(missing))
        return self._maps

    def __getattr__(self, name: str) -> np.ndarray:
        if name.startswith("_"):
            raise AttributeError(name)
        if name not in self._maps:
            # The site arrays are made together: asking for one keeps the others.
            together = SITE_ARRAYS if name in SITE_ARRAYS else (name,)
            self._maps.update(
                self._native.arrays_named([n for n in together if n not in self._maps])
            )
        if name in self._maps:
            return self._maps[name]
        if name in MAPS:
            raise AttributeError(
                f"this result has no {name!r} ({MAPS[name][1]}): see summary['dynamics'] "
                "or the angle count"
            )
        raise AttributeError(name)

    def __dir__(self) -> list[str]:
        return sorted(set(super().__dir__()) | set(self._native.array_names()))

    @property
    def summary(self) -> dict:
        """The summary.json `save` writes (every parameter, Nyquist velocity, clutter cut-offs,
        stage timings, dynamics, provenance), as a dict."""
        return json.loads(self._native.summary_json())

    def against_truth(self, truth: Any) -> dict:
        """These maps scored against a simulation's truth: `truth` as `pcuvd.simulate` returns it
        (or its scenario as TOML text). The truth is computed again from the scenario on this
        result's grid, averaged over the recording as a whole-recording map averages a pulsing
        flow; the dict is what summary.json's `against_truth` holds for a simulated recording
        processed from its folder (vector and colour-Doppler RMSE in mm/s, the share within
        10 % of the peak speed, flow drawn inside and outside the vessels, RI against the cardiac
        cycle's truth, every definition), or `not_scored` with the reason where the scenario
        does not describe this recording."""
        scenario = truth if isinstance(truth, str) else getattr(truth, "scenario", None)
        if not isinstance(scenario, str) or not scenario:
            raise TypeError(
                "against_truth(truth): the truth pcuvd.simulate returned, or its scenario as "
                f"TOML text, not {type(truth).__name__}"
            )
        return json.loads(self._native.against_truth_json(scenario))

    def save(
        self,
        folder: str | os.PathLike,
        force: bool = False,
        *,
        nifti: bool = False,
        bids_subject: str | None = None,
        bids_session: str | None = None,
        bids_task: str | None = None,
        zarr: bool = False,
    ) -> list[Path]:
        """Writes exactly what `pcuvd process` writes into `folder`: maps as .npy, figures,
        summary.json last. A folder that holds anything is refused unless `force`, which first
        removes pcuvd's own outputs there (never other files). `nifti=True` (`--nifti`) also
        writes NIfTI images with fUSI-BIDS sidecars; `bids_subject=` and friends name them by
        BIDS entities (`--bids-subject`...). `zarr=True` (`--zarr`) also writes the run as one
        Zarr store, `pcuvd.zarr` (open it with `xarray.open_zarr`). Returns the figures written."""
        bids = (bids_subject, bids_session, bids_task)
        for label in bids:
            if label is not None and not isinstance(label, str):
                raise TypeError(f"save(): a BIDS label is a str, got {type(label).__name__}")
        return [
            Path(p)
            for p in self._native.save(
                os.fspath(folder), bool(force), bool(nifti), bids, bool(zarr)
            )
        ]

    def to_xarray(self) -> Any:
        """The maps as an `xarray.Dataset` with coordinates x, z (m), angle (rad), time (s)."""
        try:
            import xarray as xr
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("to_xarray needs xarray: pip install xarray") from e
        arrays = self.arrays
        summary = self.summary
        coords: dict[str, Any] = {"x": ("x", arrays["x"]), "z": ("z", arrays["z"])}
        # A recording's angles, or those of images formed elsewhere.
        read = summary.get("acquisition") or summary["images"]
        coords["angle"] = ("angle", np.radians(read["angles_deg"]))
        if "times" in arrays:
            coords["time"] = ("time", arrays["times"])
        if "ensemble_times" in arrays:
            coords["ensemble"] = ("ensemble", arrays["ensemble_times"])
        if "site_times" in arrays:
            coords["site_time"] = ("site_time", arrays["site_times"])
        data_vars = {
            name: (MAPS[name][0], value, {"description": MAPS[name][1]})
            for name, value in arrays.items()
            if name not in ("x", "z", "times", "ensemble_times", "site_times")
        }
        return xr.Dataset(data_vars, coords=coords, attrs={"summary": json.dumps(summary)})

    def __repr__(self) -> str:
        maps = ", ".join(sorted(k for k in self._native.array_names() if k not in ("x", "z")))
        nz, nx = len(self.z), len(self.x)
        return f"<pcuvd.ProcessResult {nz}×{nx} pixels: {maps}>"


class DynamicsError(ValueError):
    """The RI maps a dynamics setting asked for (`dynamics="on"`, a heart rate, windows) could
    not be made from the recording: found only after the work (no cardiac cycle in its vessels'
    speed, say). `result` holds the run's other maps; `result.save(folder)` writes them (None
    where the error came from another process, a Dask worker's: the maps stay where they were
    made)."""

    def __init__(self, message: str, result: ProcessResult | None):
        super().__init__(message)
        self.result = result

    def __reduce__(self) -> tuple:
        # Pickled (a worker's error sent to its client) as the message alone: a result holds
        # the native run, which does not travel.
        return (DynamicsError, (str(self), None))


def _checked(native: Any) -> ProcessResult:
    """The result of a native run, or the DynamicsError that carries it."""
    result = ProcessResult(native)
    failure = native.dynamics_failure()
    if failure is not None:
        raise DynamicsError(failure, result)
    return result


def dynamics(result: ProcessResult, *, quiet: bool = False, **options: Any) -> ProcessResult:
    """The dynamics stage (sliding-window vectors, heart rate, PSV/EDV/RI maps, vessel classes)
    run again on a processed recording with other settings, without processing it again.

    options: the CLI's dynamics options, e.g. `heart_rate_hz=5.5`, `window_ms=20`,
    `window_step_ms=5`, `artery_ri_min=0.55`, `vein_ri_max=0.5`, `pool_along_mm=0`,
    `dynamics="on"` (an error rather than a skipped stage when RI cannot be measured: a
    DynamicsError, which carries the result without RI maps).
    Returns a new result with the same maps and the new RI maps (`ri`, `psv`, `edv`, ...).
    Where the windows stay as the result made them (the same `window_ms`, `window_step_ms`,
    `dynamics_kernel`, `dynamics_partial_volume`), the RI maps are made again from its velocity
    windows: the only way for a recording processed in segments, whose filtered series were
    not kept (new windows there raise ValueError), and quicker for any. Windows the run spaced
    further apart for memory (`summary["dynamics"]["step_spaced_for_memory"]`) stay so unless
    `window_ms` or `window_step_ms` is given.
    """
    if not isinstance(result, ProcessResult):
        raise TypeError(
            f"dynamics() expects the ProcessResult of pcuvd.process, got {type(result).__name__}"
        )
    given = _checks.to_options("dynamics", options, _pcuvd.option_names_of("dynamics"))
    return _checked(result._native.with_dynamics(given, bool(quiet)))


def process(
    recording: Recording | str | os.PathLike,
    *,
    overrides: dict[str, Any] | None = None,
    quiet: bool = False,
    **options: Any,
) -> ProcessResult:
    """Runs `pcuvd process`'s chain (decode, demodulate, beamform, SVD clutter filter, power /
    colour / vector Doppler, dynamics) on a recording, with the CLI's defaults.

    recording: a `Recording`, or a path, whose file is then read a block of frames at a time as
    the command reads it (the run's memory bounded by a block; `read_recording` reads it
    whole). overrides (with a path): the reader's acquisition overrides (`t0_s`,
    `sound_speed_m_s`, `event_prf_hz`, `sampling_freq_hz`, `center_freq_hz`, `angles_rad`,
    `pulse_cycles`, `bandwidth`, `track`), as `read_recording` takes them; a `Recording` carries
    its own. options: the CLI's options with `_` for `-`, e.g. `grid_mm=(-6, 6, 2, 14, 0.05)`
    (x_min, x_max, z_min, z_max, step in mm; `grid_m` takes metres), `svd_low="auto"`,
    `doppler_kernel=(3, 3)`,
    `dynamics="off"`, `dealias="auto"` (or K: unwrap projections beyond the Nyquist velocity;
    for conventional recordings: on a Hadamard-coded one a UserWarning says it cannot help),
    `doppler_estimator="kasai"` (divide the Doppler phase by the nominal centre frequency; the
    default "loupas" divides it by each pixel's measured mean frequency and needs an axial grid
    step of at most about a wavelength), `partial_volume="on"` (move each angle's projection
    from its resolution cell's power centroid back to the pixel before the vector fit),
    `heart_rate_hz=5.5`, `window_ms=20`, `ensemble_frames=64`,
    `ensemble_step=16` (a Doppler time series), `sites_mm=[(x, z), ...]` (points in mm whose
    Doppler spectrograms the result gives as `site_spectrograms`, `site_velocities`,
    `site_times`, `site_mean_velocity`, and `save` draws in `sites.png`; `site_radius_mm=0.2`
    reads each over a sample volume of that radius); see
    `process_option_names()`.
    The path of an images manifest (beamformed IQ images formed elsewhere, format
    "pcuvd-images": docs/guide/inputs.md), or of ConfUSIus's Zarr store of IQ (a `.zarr`
    folder with an `iq` array), runs the chain from the clutter filter on, as the command does;
    its summary has an `images` record in place of the probe and acquisition.
    A recording `pcuvd simulate` wrote (its `scenario.toml` beside it), or one `pcuvd.simulate`
    made in memory (it carries its scenario), is scored against its truth:
    `result.summary["against_truth"]`, and `save` draws `against_truth.png`.
    Progress goes to stderr (`quiet=True` for none). Raises ValueError with the CLI's message
    (its options named as keywords: `f_number=-1.0: ...`) for a bad option or recording, before any work where the CLI would; where only the data
    could tell that the RI maps a dynamics setting asked for cannot be made, a DynamicsError
    (a ValueError) whose `result` holds the run's other maps.
    """
    if not isinstance(recording, (Recording, str, os.PathLike)):
        raise TypeError(
            "process() expects a Recording or the path of a recording, got "
            f"{type(recording).__name__} (arrays: pcuvd.Recording.from_arrays)"
        )
    given = process_options("process", options)
    if not isinstance(recording, Recording):
        # Read a block of frames at a time, as the command reads it: the memory a run takes is
        # a block's, whatever the recording's length.
        read = reader_overrides(overrides)
        return _checked(_pcuvd.process_file(os.fspath(recording), read, given, bool(quiet)))
    if overrides:
        raise ValueError(
            "overrides apply to a recording read from its path; a Recording carries its "
            "acquisition: read it with pcuvd.read_recording(path, **overrides)"
        )
    return _checked(_pcuvd.process(recording._native, given, bool(quiet)))


def process_options(function: str, options: dict[str, Any]) -> str:
    """`process`'s keyword options as the JSON the native half reads (`grid_m` in millimetres),
    an unknown keyword a TypeError naming `function`."""
    options = dict(options)
    if "grid_m" in options:
        grid_m = options.pop("grid_m")
        if "grid_mm" in options or "grid" in options:
            raise TypeError(f"{function}(): give one of grid_m, grid_mm")
        if grid_m is not None:
            values = [_checks.finite_number("grid_m", v, positive=False) for v in grid_m]
            options["grid_mm"] = [v * 1e3 for v in values]
    return _checks.to_options(function, options, _pcuvd.option_names_of("process"))
