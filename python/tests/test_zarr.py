"""`pcuvd process --zarr` and `ProcessResult.save(zarr=True)`: the run as one Zarr v3 store that
`zarr` and `xarray.open_zarr` read without pcuvd (named dimensions, coordinates in metres and
seconds, the acquisition in attributes), its time series appended segment by segment."""

import json

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import xarray as xr  # noqa: E402
import zarr  # noqa: E402

import pcuvd  # noqa: E402
from conftest import REPO, run_cli  # noqa: E402

FRAMES, ANGLES, ELEMENTS, SAMPLES = 1800, 2, 16, 128
FS, F0, C, FRAME_RATE = 20e6, 5e6, 1540.0, 1000.0
PITCH = 3e-4
ANGLES_RAD = np.radians([-5.0, 5.0])
HEART_HZ = 5.0


def _echoes() -> np.ndarray:
    """RF (frames, angles, channels, samples) of a 16-element probe: a plane wave per angle and
    point echoes (a 2-cycle 5 MHz Gaussian pulse) from still scatterers and from scatterers
    flowing along a vessel 45° to the probe at a pulsatile speed (mean 6 mm/s, ±50 % at 5 Hz),
    each re-entering the vessel's 3 mm as it leaves it."""
    rng = np.random.default_rng(7)
    elements_x = (np.arange(ELEMENTS) - (ELEMENTS - 1) / 2) * PITCH
    frame_t = np.arange(FRAMES) / FRAME_RATE
    # Distance flowed: the integral of 6 mm/s (1 + 0.5 sin(2π f t)).
    flowed = 6e-3 * (
        frame_t + 0.5 * (1 - np.cos(2 * np.pi * HEART_HZ * frame_t)) / (2 * np.pi * HEART_HZ)
    )
    direction = np.array([1.0, 1.0]) / np.sqrt(2.0)
    normal = np.array([-1.0, 1.0]) / np.sqrt(2.0)
    centre, length = np.array([0.0, 2.5e-3]), 3e-3
    scatterers = []  # (x, z) per frame, amplitude
    for _ in range(16):
        position = np.array([rng.uniform(-1.5e-3, 1.5e-3), rng.uniform(1.5e-3, 3.5e-3)])
        scatterers.append((np.tile(position, (FRAMES, 1)), 3.0))
    for _ in range(40):
        along = (rng.uniform(0, length) + flowed) % length - length / 2
        across = rng.uniform(-2e-4, 2e-4)
        path = centre + along[:, None] * direction + across * normal
        scatterers.append((path, 1.0))
    rf = np.zeros(FRAMES * ANGLES * ELEMENTS * SAMPLES, np.float32)
    sigma, offsets = 1.0 / F0, np.arange(-12, 13)  # the pulse's samples within ±3 σ
    frames, channels = np.meshgrid(np.arange(FRAMES), np.arange(ELEMENTS), indexing="ij")
    for a, angle in enumerate(ANGLES_RAD):
        row = ((frames * ANGLES + a) * ELEMENTS + channels)[..., None] * SAMPLES
        for path, amplitude in scatterers:
            x, z = path[:, :1], path[:, 1:]
            tau = (z * np.cos(angle) + x * np.sin(angle) + np.hypot(x - elements_x, z)) / C
            n = np.round(tau * FS).astype(int)[..., None] + offsets  # (frames, channels, 25)
            lag = (n / FS - tau[..., None]).astype(np.float32)
            value = amplitude * np.exp(np.float32(-0.5 / sigma**2) * lag**2) * np.cos(np.float32(2 * np.pi * F0) * lag)
            inside = (n >= 0) & (n < SAMPLES)
            # One scatterer's samples are distinct: plain indexed addition adds each once.
            rf[(row + n)[inside]] += value[inside]
    rf = rf.reshape(FRAMES, ANGLES, ELEMENTS, SAMPLES)
    rf += rng.normal(scale=0.01, size=rf.shape).astype(np.float32)
    return rf


@pytest.fixture(scope="module")
def pulsing(tmp_path_factory):
    """A 1,800-frame conventional two-angle recording as a pcuvd manifest."""
    folder = tmp_path_factory.mktemp("zarr_recording")
    np.save(folder / "rf.npy", _echoes())
    (folder / "pulsing.toml").write_text(
        f"""format = "pcuvd-recording"
version = 1
[probe]
n_elements = {ELEMENTS}
pitch_m = {PITCH}
element_width_m = 2.5e-4
center_frequency_hz = {F0}
bandwidth = 0.6
[acquisition]
sampling_frequency_hz = {FS}
sound_speed_m_s = {C}
t0_s = 0.0
event_prf_hz = {FRAME_RATE * ANGLES}
angles_rad = {json.dumps(list(ANGLES_RAD))}
pulse_cycles = 2.0
coding = "none"
[data]
file = "rf.npy"
kind = "rf"
axes = ["frames", "angles", "channels", "samples"]
"""
    )
    return folder / "pulsing.toml"


OPTIONS = [
    "--grid=-1.5,1.5,1.5,3.5,0.1", "--ensemble-frames=100", "--ensemble-step=50",
    "--segment-frames=400", "--heart-rate=5", "--window-ms=60", "--window-step-ms=20",
    "--svd-low=1", "--sites=0,2.5;1,2",
]


@pytest.fixture(scope="module")
def runs(pulsing, cli, tmp_path_factory):
    """The recording processed by the command in segments with --zarr, and by Python whole."""
    out = tmp_path_factory.mktemp("zarr_runs") / "out"
    done = run_cli(cli, "process", pulsing, "--out", out, *OPTIONS, "--zarr")
    assert done.returncode == 0, done.stderr
    whole = pcuvd.process(
        pulsing, quiet=True, grid_mm=(-1.5, 1.5, 1.5, 3.5, 0.1), ensemble_frames=100,
        ensemble_step=50, dynamics="off", svd_low=1, segment_frames=1800,
        sites_mm=[(0, 2.5), (1, 2)],
    )
    return out, whole


def test_the_store_opens_lazily_in_xarray_with_the_runs_values(runs, tmp_path):
    with_zarr, whole = runs
    summary = json.loads((with_zarr / "summary.json").read_text())
    assert summary["segments"]["count"] >= 3, summary["segments"]
    record = summary["zarr"]
    assert record["store"] == "pcuvd.zarr" and record["time_series_in_store_only"]
    # The series went to the store as the segments finished, and only there.
    assert not list(with_zarr.glob("ensemble_*.npy"))
    # Its figure is drawn from the store, read back once the run ended.
    assert (with_zarr / "ensembles.png").stat().st_size > 0
    ds = xr.open_zarr(with_zarr / "pcuvd.zarr")
    assert sorted(record["arrays"]) == sorted(ds.variables)
    series = ds["ensemble_power_doppler"]
    assert series.dims == ("time", "z", "x")
    assert series.chunks is not None, "opened lazily (Dask-backed)"
    assert series.attrs["units"] == "|IQ|^2"
    # A segmented run's ensembles are the whole run's (each from the segment its start is in).
    times = whole.arrays["ensemble_times"]
    np.testing.assert_allclose(ds["time"].values, times)
    assert len(times) == (FRAMES - 100) // 50 + 1
    np.testing.assert_allclose(ds["x"].values, np.load(with_zarr / "x.npy"))
    np.testing.assert_allclose(ds["z"].values, np.load(with_zarr / "z.npy"))
    assert ds["x"].attrs["units"] == "m" and ds["time"].attrs["units"] == "s"
    # float32 in the store, float64 in the .npy files and in memory.
    series_names = [
        "ensemble_power_doppler", "ensemble_signed_power_doppler", "ensemble_color_doppler",
        "ensemble_vx", "ensemble_vz",
    ]
    map_names = [
        "power_doppler", "signed_power_doppler", "color_doppler", "vx", "vz", "speed", "bmode_db",
    ]
    for name in series_names + map_names:
        expected = whole.arrays[name] if name in series_names else np.load(with_zarr / f"{name}.npy")
        stored = ds[name].values
        assert stored.dtype == np.float32, name
        np.testing.assert_allclose(stored, expected, rtol=1e-6, atol=1e-6 * np.nanmax(np.abs(expected)), err_msg=name)
    # The dynamics stage's velocity windows as a second series, its maps beside the others.
    assert "skipped" not in summary["dynamics"], summary["dynamics"]
    assert ds["window_vx"].dims == ("window_time", "z", "x")
    np.testing.assert_allclose(ds["window_time"].values, np.load(with_zarr / "times.npy"))
    np.testing.assert_array_equal(ds["vessel_class"].values, np.load(with_zarr / "vessel_class.npy"))
    speed_series = np.hypot(ds["window_vx"].values, ds["window_vz"].values)
    np.testing.assert_allclose(speed_series, np.load(with_zarr / "speed_series.npy"), rtol=1e-5, atol=1e-9)
    for name in ["ri", "psv", "edv"]:
        np.testing.assert_allclose(ds[name].values, np.load(with_zarr / f"{name}.npy"), rtol=1e-6, err_msg=name)
    # The sites' spectrograms (--sites) on an axis of their own, each site its velocity axis.
    assert ds["site_spectrograms"].dims == ("site", "site_time", "site_velocity_bin")
    assert ds["site_velocities"].dims == ("site", "site_velocity_bin")
    assert ds["site_mean_velocity"].dims == ("site", "site_time")
    np.testing.assert_allclose(ds["site_time"].values, np.load(with_zarr / "site_times.npy"))
    for name in ["site_spectrograms", "site_velocities", "site_mean_velocity"]:
        expected = np.load(with_zarr / f"{name}.npy")
        assert ds[name].shape == expected.shape, name
        np.testing.assert_allclose(ds[name].values, expected, rtol=1e-6, err_msg=name)
    assert np.isfinite(ds["site_spectrograms"].values[0]).all(), "the vessel's site has a signal"
    # The vessel's power over time, plotted from the store as a user would.
    band = series.sel(z=slice(2.3e-3, 2.7e-3), x=slice(-0.2e-3, 0.2e-3)).mean(("z", "x"))
    figure, axes = plt.subplots()
    band.plot(ax=axes)
    figure.savefig(tmp_path / "series.png")
    plt.close(figure)
    assert (tmp_path / "series.png").stat().st_size > 0
    assert np.all(np.isfinite(band.values)) and band.values.min() > 0


def test_the_acquisition_is_in_the_stores_attributes_under_confusius_names(runs):
    with_zarr, _ = runs
    group = zarr.open_group(with_zarr / "pcuvd.zarr", mode="r")
    attrs = dict(group.attrs)
    assert attrs["compound_sampling_frequency"] == pytest.approx(FRAME_RATE)
    assert attrs["transmit_frequency"] == pytest.approx(F0)
    assert attrs["beamforming_sound_velocity"] == pytest.approx(C)
    assert attrs["plane_wave_angles"] == pytest.approx([-5.0, 5.0])
    assert attrs["probe_number_of_elements"] == ELEMENTS
    assert attrs["frames"] == FRAMES
    assert json.loads(attrs["processing_options"])["processing"]["ensemble_frames"] == 100
    assert group["ensemble_vx"].metadata.dimension_names == ("time", "z", "x")


def test_python_saves_the_same_store(runs, tmp_path):
    """Python's save(zarr=True) after a whole (unsegmented) run: the same arrays, written at the
    end, and the .npy series kept beside them."""
    _, result = runs
    result.save(tmp_path / "out", zarr=True)
    ds = xr.open_zarr(tmp_path / "out" / "pcuvd.zarr")
    np.testing.assert_allclose(ds["time"].values, result.arrays["ensemble_times"])
    for name in ["ensemble_power_doppler", "ensemble_vx", "power_doppler", "vx"]:
        expected = result.arrays[name]
        np.testing.assert_allclose(
            ds[name].values, expected, rtol=1e-6, atol=1e-6 * np.nanmax(np.abs(expected)), err_msg=name
        )
    assert "window_vx" not in ds.variables  # dynamics off
    for name in ["site_spectrograms", "site_velocities", "site_mean_velocity"]:
        np.testing.assert_allclose(ds[name].values, result.arrays[name], rtol=1e-6, err_msg=name)
    np.testing.assert_allclose(ds["site_time"].values, result.arrays["site_times"])
    assert (tmp_path / "out" / "ensemble_power_doppler.npy").exists()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["zarr"]["time_series_in_store_only"] is False


def test_confusius_iq_store_gives_confusius_own_velocity(tmp_path):
    """ConfUSIus's Zarr store of IQ (written by ConfUSIus: pcuvd-io's fixture) is read by
    `pcuvd.process` as images formed elsewhere; with ConfUSIus's estimator (Kasai, one pixel, no
    clutter filter) the colour Doppler is ConfUSIus's axial velocity with the sign turned
    (ConfUSIus: toward the probe positive), and zarr-python reads the store pcuvd read."""
    fixtures = REPO / "crates" / "pcuvd-io" / "tests" / "fixtures" / "confusius"
    store = fixtures / "iq.zarr"
    expected = json.loads((fixtures / "expected.json").read_text())
    assert zarr.open_group(store, mode="r")["iq"].shape == tuple(expected["shape"])
    result = pcuvd.process(
        str(store), quiet=True, dynamics="off", doppler_estimator="kasai",
        doppler_kernel="1x1", svd_low="off",
    )
    theirs = np.array(expected["confusius_axial_velocity_m_s"])
    np.testing.assert_allclose(result.arrays["color_doppler"], -theirs, rtol=0, atol=1e-7)
    np.testing.assert_allclose(result.z, np.array(expected["depth_mm"]) * 1e-3, atol=1e-12)
    result.save(tmp_path / "out")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["source"]["format"] == "ConfUSIus beamformed IQ (Zarr v3)", summary["source"]
    with pytest.raises(ValueError, match="ConfUSIus's Zarr store"):
        pcuvd.read_recording(store)
