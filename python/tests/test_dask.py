"""Dask: a batch of recordings (one recording = one task) equals a serial loop, and one recording's
segments as tasks (`pcuvd.dask.process`) equal `pcuvd.process`."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

import pcuvd
from conftest import (
    assert_same_array,
    beamform_each_angle,
    images_manifest,
    run_cli,
    steady_flow_manifest,
)

dask = pytest.importorskip("dask")
distributed = pytest.importorskip("distributed")
import dask.bag as db  # noqa: E402


def process_one(job: tuple[str, str, dict]) -> dict:
    """The unit of work: read, process, save one recording; its maps' checksums and figures."""
    path, out_root, options = job
    result = pcuvd.process(path, quiet=True, **options)
    folder = Path(out_root) / Path(path).stem
    result.save(folder, force=True)
    return {
        "recording": Path(path).name,
        "maps": {
            name: hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest()
            for name, value in result.arrays.items()
        },
        "files": sorted(p.name for p in folder.iterdir()),
    }


@pytest.fixture(scope="module")
def batch(tmp_path_factory, disk, cli) -> list[tuple[str, dict]]:
    folder = tmp_path_factory.mktemp("sims")
    done = run_cli(
        cli, "simulate", "--preset", "tube", "--mode", "both", "--frames", "8", "--out", folder
    )
    assert done.returncode == 0, done.stderr
    small = {"grid_mm": (-3, 3, 4, 10, 0.08), "dynamics": "off"}
    return [
        (str(disk), {}),
        (str(folder / "coded.toml"), small),
        (str(folder / "conventional.toml"), small),
    ]


def test_dask_batch_equals_a_serial_loop(batch, tmp_path):
    serial = [process_one((path, str(tmp_path / "serial"), opts)) for path, opts in batch]
    jobs = [(path, str(tmp_path / "dask"), opts) for path, opts in batch]
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        parallel = db.from_sequence(jobs, npartitions=len(jobs)).map(process_one).compute()
    assert parallel == serial
    assert all("summary.json" in r["files"] for r in parallel)
    assert {r["recording"] for r in parallel} == {"PWI_disk.mat", "coded.toml", "conventional.toml"}


# One recording across the cluster: its segments as tasks, the parts joined. A 4-angle coded tube
# (3.6 kHz frames) of 48 frames, 13 ms: a 10 ms cardiac cycle, windows of 2 ms.
SEGMENTED = {
    "grid_mm": (-1.5, 1.5, 6.5, 9.5, 0.08),
    "segment_frames": 20,
    "heart_rate_hz": 100,
    "window_ms": 2,
    "window_step_ms": 1,
    "ensemble_frames": 8,
    "ensemble_step": 4,
}


@pytest.fixture(scope="module")
def long_tube(tmp_path_factory, cli) -> Path:
    """A coded tube (4 angles) of 48 frames, 6 mm long (its ends outside the grid)."""
    folder = tmp_path_factory.mktemp("long_tube")
    done = run_cli(
        cli, "simulate", "--preset", "tube", "--mode", "coded", "--frames", "48", "--angles", "4",
        "--tube-length-mm", "6", "--out", folder,
    )
    assert done.returncode == 0, done.stderr
    return folder / "coded.toml"


@pytest.mark.filterwarnings("ignore:.*dealiasing cannot recover")  # a coded recording, dealiased
def test_one_recording_across_a_cluster_equals_one_process(long_tube):
    """Two worker processes each read their segments' frames from the file; the joined maps,
    velocity windows, RI maps and time series are those of `pcuvd.process` (the same sums in the
    same order: equal, not just close). With dealias="auto" the first segment settles the
    windows' Nyquist intervals for the others (and runs first); with "off" all run at once, here
    with 1 mm clutter blocks, whose every block's cut-offs cross between the processes (with
    "auto", the whole image's filter)."""
    import pcuvd.dask

    # Two spectrogram sites, their series kept by each worker from its segments and joined.
    sites = [(0, 8), (0.5, 7.5)]
    runs = {
        d: {**SEGMENTED, "dealias": d, "sites_mm": sites, "site_radius_mm": 0.1}
        for d in ("off", "auto")
    }
    runs["off"]["svd_block_mm"] = 1.0
    runs["auto"]["svd_block_mm"] = "whole"
    serial = {d: pcuvd.process(str(long_tube), quiet=True, **o) for d, o in runs.items()}
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        joined = {d: pcuvd.dask.process(long_tube, client, quiet=True, **o) for d, o in runs.items()}
    for dealias, one in serial.items():
        segments = one.summary["segments"]["own_frames"]
        assert len(segments) >= 3, segments
        both = joined[dealias]
        assert sorted(both.arrays) == sorted(one.arrays)
        for name in ("ri", "speed_series", "ensemble_power_doppler", "vx", "power_doppler",
                     "site_spectrograms", "site_mean_velocity"):
            assert name in one.arrays, name
        assert ("clutter_block_cut_offs" in one.arrays) == (dealias == "off")
        for name, value in one.arrays.items():
            assert_same_array(both.arrays[name], value, f"{name} (dealias {dealias})")
        assert both.summary["segments"] == one.summary["segments"]
        assert both.summary["ensembles"] == one.summary["ensembles"]
        assert both.summary["dynamics"] == one.summary["dynamics"]
        assert both.summary["sites"] == one.summary["sites"]
        assert [(s["x_mm"], s["z_mm"]) for s in one.summary["sites"]] == sites


def test_a_cluster_run_refuses_what_it_cannot_share(long_tube, disk):
    import pcuvd.dask

    class NoClient:
        def submit(self, *args, **kwargs):
            raise AssertionError("nothing should be submitted")

    with pytest.raises(ValueError, match="segment_frames"):
        pcuvd.dask.process(disk, NoClient(), quiet=True)
    with pytest.raises(ValueError, match="slot_delay_s"):
        pcuvd.dask.process(long_tube, NoClient(), overrides={"slot_delay_s": 1e-6}, **SEGMENTED)
    with pytest.raises(TypeError, match="path of a recording"):
        pcuvd.dask.process(pcuvd.read_recording(disk), NoClient())
    with pytest.raises(TypeError, match="unexpected keyword 'segment_frame'"):
        pcuvd.dask.process(long_tube, NoClient(), segment_frame=10)


@pytest.fixture(scope="module")
def long_images(tmp_path_factory, cli) -> Path:
    """The long tube's conventional twin (4 angles, 48 frames) beamformed per angle with the
    Python stages and saved with NumPy as (z, x, angles, frames), frames the fastest axis, with
    its images manifest."""
    folder = tmp_path_factory.mktemp("long_images")
    done = run_cli(
        cli, "simulate", "--preset", "tube", "--mode", "conventional", "--frames", "48",
        "--angles", "4", "--tube-length-mm", "6", "--out", folder,
    )
    assert done.returncode == 0, done.stderr
    recording = pcuvd.read_recording(folder / "conventional.toml")
    grid = pcuvd.process(recording, grid_mm=SEGMENTED["grid_mm"], dynamics="off", quiet=True)
    series = beamform_each_angle(recording, grid.x, grid.z)
    manifest = images_manifest(
        folder, np.ascontiguousarray(np.transpose(series, (1, 2, 0, 3))),
        ["z", "x", "angles", "frames"], grid.x, grid.z, frame_rate_hz=recording.frame_rate_hz,
        demod_frequency_hz=recording.probe["center_freq_hz"],
        sound_speed_m_s=recording.sound_speed_m_s,
        angles_deg=[float(a) for a in np.degrees(recording.angles_rad)],
    )
    return manifest


def test_images_across_a_cluster_equal_one_process(long_images):
    """Beamformed images formed elsewhere are cut into segments as a recording is, each read
    from the file by its own worker: the joined maps, windows, RI maps and time series are
    those of `pcuvd.process` on the manifest."""
    import pcuvd.dask

    options = {k: v for k, v in SEGMENTED.items() if k != "grid_mm"}
    one = pcuvd.process(str(long_images), quiet=True, **options)
    assert len(one.summary["segments"]["own_frames"]) >= 3, one.summary["segments"]
    assert "read images" in one.summary["timings_s"]
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        joined = pcuvd.dask.process(long_images, client, quiet=True, **options)
    assert sorted(joined.arrays) == sorted(one.arrays)
    for name in ("ri", "speed_series", "ensemble_power_doppler", "vx"):
        assert name in one.arrays, name
    for name, value in one.arrays.items():
        assert_same_array(joined.arrays[name], value, name)
    assert joined.summary["segments"] == one.summary["segments"]
    assert joined.summary["images"] == one.summary["images"]
    with pytest.raises(ValueError, match="overrides are for recordings"):
        pcuvd.dask.process(long_images, None, overrides={"t0_s": 0.0}, **options)


@pytest.mark.parametrize(
    ("limit_gb", "said"),
    [(0.0135, "RI maps from dynamics windows every 10.0 ms"), (0.0115, "no RI maps")],
)
def test_windows_fitted_to_memory_are_fitted_alike_on_every_worker(
    tmp_path, capsys, limit_gb, said
):
    """Under `dynamics="auto"` the memory check where the run is planned spaces the dynamics
    windows further apart (in 13.5 MB), or drops the RI maps (in 11.5 MB), where the windows of
    20 frames every 5 would not fit beside the segments (400 frames of 48 x 64 pixels of one
    angle in segments of 150: 11.1 MB to process a segment, 3.8 MB of windows of 2 maps; 1.9 MB
    every 10 frames, 1.0 MB side by side): every worker and the join follow it, so the cluster's
    run equals `pcuvd.process`'s, and it is said once."""
    import pcuvd.dask

    rng = np.random.default_rng(3)
    frames, nz, nx = 400, 48, 64
    tissue = 30 * (rng.standard_normal((nz, nx)) + 1j * rng.standard_normal((nz, nx)))
    blood = rng.standard_normal((nz, nx)) + 1j * rng.standard_normal((nz, nx))
    vessel = np.zeros((nz, nx), bool)
    vessel[18:30, 8:30] = True
    # 8 mm/s away from the probe on average at 1 kHz and 15.625 MHz (1.02 rad a frame), pulsing
    # ±50 % at 5 Hz: the cycles the RI maps need.
    speed = 8e-3 * (1 + 0.5 * np.sin(2 * np.pi * 5 * np.arange(frames) / 1000.0))
    turn = np.exp(-1j * np.cumsum(4 * np.pi * 15.625e6 * speed / (1540.0 * 1000.0)))
    noise = 0.05 * (rng.standard_normal((frames, nz, nx)) + 1j * rng.standard_normal((frames, nz, nx)))
    images = (tissue + (blood * vessel) * turn[:, None, None] + noise).astype(np.complex64)
    manifest = images_manifest(
        tmp_path, images, ["frames", "z", "x"], np.linspace(-1.6e-3, 1.55e-3, nx),
        np.linspace(5.0e-3, 7.35e-3, nz), frame_rate_hz=1000.0, demod_frequency_hz=15.625e6,
    )
    options = {"segment_frames": 150, "max_memory_gb": limit_gb}
    one = pcuvd.process(str(manifest), **options)
    dynamics = one.summary["dynamics"]
    if said == "no RI maps":
        assert "dynamics windows" in dynamics["skipped"], dynamics
        assert "side by side" in dynamics["skipped"], dynamics
        assert "ri" not in one.arrays and "speed_series" not in one.arrays
    else:
        assert dynamics["step_frames"] == 10, dynamics
        assert dynamics["step_spaced_for_memory"].startswith(said), dynamics
        assert "ri" in one.arrays and one.arrays["speed_series"].shape[0] == (400 - 20) // 10 + 1
        # The RI settings change on the spaced windows, as processing with them spaces them.
        rerun = pcuvd.dynamics(one, quiet=True, artery_ri_min=0.7, vein_ri_max=0.6)
        again = pcuvd.process(str(manifest), quiet=True, artery_ri_min=0.7, vein_ri_max=0.6, **options)
        assert rerun.summary["dynamics"] == again.summary["dynamics"]
        for name in ("ri", "vessel_class", "speed_series", "times"):
            assert_same_array(rerun.arrays[name], again.arrays[name], name)
    capsys.readouterr()
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        joined = pcuvd.dask.process(manifest, client, **options)
    notes = [line for line in capsys.readouterr().err.splitlines() if line.startswith("note:")]
    assert len(notes) == 1 and notes[0].startswith(f"note: {said}"), notes
    if said == "no RI maps":
        # The command's note, with the keyword a Python user gives to silence it.
        assert notes[0].endswith('(dynamics="off" silences this)'), notes
    assert joined.summary["dynamics"] == one.summary["dynamics"]
    assert sorted(joined.arrays) == sorted(one.arrays)
    for name, value in one.arrays.items():
        assert_same_array(joined.arrays[name], value, name)
    # In 16 MB with the window step five times longer the windows fit, and the RI maps are made.
    back = pcuvd.process(
        str(manifest), quiet=True, window_step_ms=25, heart_rate_hz=5, segment_frames=150,
        max_memory_gb=0.016,
    )
    assert "ri" in back.arrays, back.summary["dynamics"]


def test_ri_only_the_data_refuses_raises_on_the_client(tmp_path):
    """RI maps asked for that only the data can refuse (steady flow): a batch task's
    DynamicsError reaches the client as itself, its message whole (the maps stayed on the
    worker, which wrote nothing), and a cluster run of one recording's segments raises it with
    the joined maps, those `pcuvd.process`'s error carries."""
    import pcuvd.dask

    manifest = str(steady_flow_manifest(tmp_path))
    asked = {"dynamics": "on", "window_ms": 40}
    with pytest.raises(pcuvd.DynamicsError) as serial:
        pcuvd.process(manifest, quiet=True, **asked)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        job = (manifest, str(tmp_path / "out"), asked)
        with pytest.raises(pcuvd.DynamicsError) as sent:
            db.from_sequence([job], npartitions=1).map(process_one).compute()
        assert str(sent.value) == str(serial.value) and sent.value.result is None
        with pytest.raises(pcuvd.DynamicsError, match="systolic upstrokes found") as joined:
            pcuvd.dask.process(manifest, client, segment_frames=60, quiet=True, **asked)
    with pytest.raises(pcuvd.DynamicsError) as one:
        pcuvd.process(manifest, segment_frames=60, quiet=True, **asked)
    assert str(joined.value) == str(one.value)
    kept = one.value.result.arrays
    assert sorted(joined.value.result.arrays) == sorted(kept) and "ri" not in kept
    for name, value in kept.items():
        assert_same_array(joined.value.result.arrays[name], value, name)
