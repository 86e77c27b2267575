"""`pcuvd.process` against `pcuvd process`: the same arrays, summary and figures."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import pcuvd
from conftest import assert_same_array, run_cli

# The reader fixtures, files written by each format's own tools.
READER_FIXTURES = Path(__file__).resolve().parents[2] / "crates/pcuvd-io/tests/fixtures/readers"


def _outputs(folder: Path) -> dict[str, np.ndarray]:
    return {p.stem: np.load(p) for p in sorted(folder.glob("*.npy"))}


def _without_run_details(summary: dict) -> dict:
    """The summary less what differs between two runs of the same work: timings, peak memory
    and command line."""
    summary = json.loads(json.dumps(summary))
    summary.pop("timings_s")
    summary.pop("peak_resident_bytes")
    summary["source"].pop("command_line")
    return summary


@pytest.fixture(scope="module")
def tube(tmp_path_factory, cli) -> Path:
    """A small coded tube recording (8 angles) written by `pcuvd simulate`."""
    folder = tmp_path_factory.mktemp("tube")
    done = run_cli(
        cli, "simulate", "--preset", "tube", "--mode", "coded", "--frames", "10", "--out", folder
    )
    assert done.returncode == 0, done.stderr
    return folder / "coded.toml"


@pytest.mark.filterwarnings("ignore:.*dealiasing cannot recover")  # the coded tube; tested below
@pytest.mark.parametrize("which", ["disk", "tube", "tube in segments", "tube in blocks"])
def test_process_equals_cli_array_for_array(which, disk, tube, cli, tmp_path):
    source = disk if which == "disk" else tube
    tube_options = [
        "--grid=-3,3,4,10,0.08",
        "--dynamics=off",
        "--ensemble-frames=4",
        "--ensemble-step=3",
        "--dealias=auto",
        "--sites=0,8;-1,7",
    ]
    options = tube_options if which == "tube" else []
    if which == "tube in segments":
        # Segments of 8 frames: 6-frame cores, each imaged with the 2 frames its ensembles reach.
        options = tube_options[:2] + [
            "--ensemble-frames=4",
            "--ensemble-step=2",
            "--segment-frames=8",
            "--dealias=auto",
            "--sites=0,8;-1,7",
            "--site-radius-mm=0.1",
        ]
    if which == "tube in blocks":
        # The block-wise clutter filter (1.2 mm: 15 pixels, made 16) in two segments.
        options = tube_options[:2] + ["--svd-block-mm=1.2", "--segment-frames=5", "--dealias=auto"]
    by_cli = tmp_path / "cli"
    done = run_cli(cli, "process", source, "--out", by_cli, *options)
    assert done.returncode == 0, done.stderr

    tube_kwargs = {
        "grid_mm": (-3, 3, 4, 10, 0.08),
        "dynamics": "off",
        "ensemble_frames": 4,
        "ensemble_step": 3,
        "dealias": "auto",
        "sites_mm": [(0, 8), (-1, 7)],
    }
    kwargs = tube_kwargs if which == "tube" else {}
    if which == "tube in segments":
        kwargs = {**tube_kwargs, "ensemble_step": 2, "segment_frames": 8, "site_radius_mm": 0.1}
    if which == "tube in blocks":
        kwargs = {"grid_mm": (-3, 3, 4, 10, 0.08), "dynamics": "off", "svd_block_mm": 1.2,
                  "segment_frames": 5, "dealias": "auto"}
    result = pcuvd.process(source, quiet=True, **kwargs)
    by_python = tmp_path / "python"
    figures = result.save(by_python)

    cli_arrays, py_arrays = _outputs(by_cli), _outputs(by_python)
    assert set(cli_arrays) == set(py_arrays)
    assert {"bmode_db", "power_doppler", "color_doppler", "projections", "x", "z"} <= set(
        cli_arrays
    )
    if which == "tube":
        assert {"vx", "vz", "speed", "vx_ls", "vz_ls", "speed_ls"} <= set(cli_arrays)
        assert cli_arrays["alias_counts"].shape == (8, *cli_arrays["vx"].shape)
        # A Doppler time series of 3 ensembles (frames 0–3, 3–6, 6–9 of 10).
        assert cli_arrays["ensemble_vx"].shape == (3, *cli_arrays["vx"].shape)
        assert list(cli_arrays["ensemble_times"] * 1800) == [1.5, 4.5, 7.5]
    if which == "tube in segments":
        # Ensembles every 2 frames (0–3, 2–5, 4–7, 6–9) from the cores 0–5 and 6–9.
        assert cli_arrays["ensemble_vx"].shape == (4, *cli_arrays["vx"].shape)
        segments = json.loads((by_cli / "summary.json").read_text())["segments"]
        assert segments["own_frames"] == [[0, 6], [6, 10]]
    if which in ("tube", "tube in segments"):
        # Two sites' spectrograms: 8-frame windows every 2 frames of the 10 (a recording
        # shorter than four 20 ms windows takes a quarter of its frames, at least 8).
        windows, columns = 2, 64
        assert cli_arrays["site_spectrograms"].shape == (2, windows, columns)
        assert cli_arrays["site_velocities"].shape == (2, columns)
        assert cli_arrays["site_mean_velocity"].shape == (2, windows)
        sites = json.loads((by_cli / "summary.json").read_text())["sites"]
        assert [(s["x_mm"], s["z_mm"]) for s in sites] == [(0, 8), (-1, 7)]
        # In segments, over a sample volume of 0.1 mm: the cross of five at 0.08 mm steps.
        assert [s["gate_pixels"] for s in sites] == ([5, 5] if which != "tube" else [1, 1])
        assert (by_cli / "sites.png").is_file()
    else:
        assert "site_spectrograms" not in cli_arrays
    if which == "tube in blocks":
        # Each segment's and angle's blocks: 9 rows and 9 columns of them on the 76-pixel grid
        # (16-pixel blocks at 8-pixel steps, the last flush with the edge at 60).
        assert cli_arrays["clutter_block_cut_offs"].shape == (2, 8, 9, 9, 2)
    for name in cli_arrays:
        assert_same_array(py_arrays[name], cli_arrays[name], name)
        # The in-memory maps are the saved ones.
        assert_same_array(np.asarray(getattr(result, name)), cli_arrays[name], name)
    assert sorted(p.name for p in by_cli.glob("*.png")) == sorted(p.name for p in figures)
    # Where dealiasing unwrapped is drawn only when it ran.
    assert ((by_cli / "dealias.png").exists()) == (which != "disk")

    cli_summary = json.loads((by_cli / "summary.json").read_text())
    py_summary = json.loads((by_python / "summary.json").read_text())
    assert _without_run_details(py_summary) == _without_run_details(cli_summary)
    # The simulated tube is scored against the truth of the scenario beside it, the same way
    # from Python; the measured disk has none.
    if which == "disk":
        assert "against_truth" not in cli_summary
    else:
        assert cli_summary["against_truth"]["vessel_pixels"] > 0
        assert (by_python / "against_truth.png").is_file()
    assert (by_python / "report.html").is_file() and (by_cli / "report.html").is_file()
    # The summary in memory is the saved one, less the timings of reading and writing.
    assert _without_run_details(result.summary) == _without_run_details(py_summary)


@pytest.mark.filterwarnings("ignore:.*dealiasing cannot recover")  # the coded tube
def test_a_path_is_read_a_block_at_a_time_as_a_recording_in_memory_is_processed(tube):
    """A path is processed from its file a block of frames at a time, as the command reads it;
    a recording read whole is processed from memory, each block copied into the previous one's
    memory: the same maps either way, over several segments and blocks."""
    options = {"grid_mm": (-3, 3, 4, 10, 0.08), "dynamics": "off", "segment_frames": 4}
    streamed = pcuvd.process(tube, quiet=True, **options)
    in_memory = pcuvd.process(pcuvd.read_recording(tube), quiet=True, **options)
    assert streamed.summary["segments"]["own_frames"] == [[0, 4], [4, 10]]
    # The memory a run is checked against counts a recording in memory, not a file read a
    # block at a time: the two estimates differ by the samples' bytes (GB to 3 decimals).
    needed = {}
    for which, recording in (("file", tube), ("memory", pcuvd.read_recording(tube))):
        with pytest.raises(ValueError, match="processing needs about") as refused:
            pcuvd.process(recording, quiet=True, max_memory_gb=1e-6, **options)
        needed[which] = float(str(refused.value).split("needs about ")[1].split(" GB")[0])
    samples = pcuvd.read_recording(tube).samples
    assert samples.nbytes > 10e6
    assert abs(needed["memory"] - needed["file"] - samples.nbytes / 1e9) <= 0.0011
    for name in ("bmode_db", "power_doppler", "color_doppler", "projections", "vx", "vz"):
        assert_same_array(getattr(streamed, name), getattr(in_memory, name), name)


def test_save_refuses_a_used_folder_unless_forced(disk, tmp_path):
    result = pcuvd.process(disk, quiet=True)
    result.save(tmp_path)
    # The command's "--force", as the Python user gives it.
    with pytest.raises(ValueError, match=r"pass force=True to replace") as refused:
        result.save(tmp_path)
    assert "--" not in str(refused.value)
    (tmp_path / "mine.txt").write_text("kept")
    result.save(tmp_path, force=True)
    assert (tmp_path / "mine.txt").read_text() == "kept"
    assert (tmp_path / "summary.json").is_file()


def test_recording_describes_the_disk(disk):
    recording = pcuvd.read_recording(disk)
    assert recording.shape == recording.samples.shape == (32, 128, 334)
    assert recording.samples.dtype == np.float32
    assert not recording.samples.flags.writeable
    assert recording.n_frames == 32 and recording.n_angles == 1
    assert recording.coding == "none"
    assert recording.probe["n_elements"] == 128
    assert recording.frame_rate_hz == recording.event_prf_hz
    # The Nyquist velocity is c·f_frame/(4 f_c), computed here independently.
    expected = recording.sound_speed_m_s * recording.frame_rate_hz / (
        4 * recording.probe["center_freq_hz"]
    )
    assert recording.nyquist_velocity_m_s == pytest.approx(expected, rel=1e-12)
    assert recording.files == [str(disk)]


def test_overrides_change_the_acquisition(disk):
    recording = pcuvd.read_recording(disk, sound_speed_m_s=1480.0, t0_s=0.0)
    assert recording.sound_speed_m_s == 1480.0 and recording.t0_s == 0.0
    with pytest.raises(ValueError, match="unknown acquisition field"):
        pcuvd.read_recording(disk, speed_of_sound=1480.0)
    # A path processed a block at a time takes the same overrides, as the reader applies them.
    overrides = {"sound_speed_m_s": 1480.0, "t0_s": 0.0}
    streamed = pcuvd.process(disk, overrides=overrides, quiet=True)
    read_whole = pcuvd.process(recording, quiet=True)
    assert streamed.summary["acquisition"]["sound_speed_m_s"] == 1480.0
    for name in ("bmode_db", "power_doppler", "color_doppler"):
        assert_same_array(getattr(streamed, name), getattr(read_whole, name), name)
    assert not np.array_equal(
        streamed.color_doppler, pcuvd.process(disk, quiet=True).color_doppler, equal_nan=True
    )
    with pytest.raises(ValueError, match="is not one the reader applies"):
        pcuvd.process(disk, overrides={"coding": "none"}, quiet=True)
    with pytest.raises(ValueError, match="a Recording carries its acquisition"):
        pcuvd.process(recording, overrides={"t0_s": 0.0}, quiet=True)
    # JSON has no NaN: a value that is not finite is named before it reaches the reader.
    with pytest.raises(ValueError, match="t0_s: expected finite numbers, got nan"):
        pcuvd.read_recording(disk, t0_s=float("nan"))
    with pytest.raises(ValueError, match="angles_rad: expected finite numbers"):
        pcuvd.process(disk, overrides={"angles_rad": np.array([0.0, np.inf])}, quiet=True)


def test_parameters_say_where_they_came_from(disk):
    recording = pcuvd.read_recording(disk)
    assert recording.parameters["t0_s"]["source"] == {"kind": "file", "field": "param.t0"}
    # The file's reader reads blocks; this recording was read whole, and says so.
    assert recording.reader.endswith(", read whole by pcuvd.read_recording")
    assert recording.parameters["pulse_cycles"]["source"]["kind"] == "default"
    given = pcuvd.read_recording(disk, t0_s=1e-6)
    assert given.t0_s == 1e-6
    assert given.parameters["t0_s"] == {"value": 1e-6, "source": {"kind": "override"}}


def test_every_format_reads_through_the_same_reader(disk):
    # The disk written by pyuff-ustb (its first 8 transmits): the .mat's samples, read by the
    # reader `pcuvd process` uses.
    uff = pcuvd.read_recording(READER_FIXTURES / "disk.uff")
    assert uff.format == "USTB UFF channel data (HDF5)"
    assert uff.parameters["event_prf_hz"]["source"] == {"kind": "file", "field": "channel_data/PRF"}
    mat = pcuvd.read_recording(disk)
    np.testing.assert_array_equal(uff.samples, mat.samples[:8])
    # The same transmits written by Moduleus' own URX writer (ultrasound-rawdata-exchange).
    urx = pcuvd.read_recording(READER_FIXTURES / "disk.urx")
    assert urx.format.startswith("URX")
    np.testing.assert_array_equal(urx.samples, mat.samples[:8])
    assert urx.t0_s == pytest.approx(mat.t0_s, rel=1e-12)


def test_bandwidth_is_a_keyword_for_files_that_do_not_state_it():
    # UFF written by pyuff-ustb without pulse/fractional_bandwidth: read with the band the
    # sampling holds (a note says so), or with the probe's own given as bandwidth=.
    unstated = pcuvd.read_recording(READER_FIXTURES / "disk_no_bandwidth.uff")
    assert "widest band" in unstated.parameters["bandwidth"]["source"]["note"]
    given = pcuvd.read_recording(READER_FIXTURES / "disk_no_bandwidth.uff", bandwidth=0.15)
    assert given.parameters["bandwidth"] == {"value": 0.15, "source": {"kind": "override"}}
    assert given.probe["bandwidth"] == 0.15


def test_a_zea_track_is_a_keyword():
    two = READER_FIXTURES / "disk_two_tracks_zea.hdf5"
    assert pcuvd.read_recording(two).n_frames == 4
    for track in (1, "disk"):
        chosen = pcuvd.read_recording(two, track=track)
        assert chosen.n_frames == 8
        assert chosen.parameters["track"] == {"value": "track_1", "source": {"kind": "override"}}
    with pytest.raises(ValueError, match="not tracks to choose from"):
        pcuvd.read_recording(READER_FIXTURES / "disk.uff", track=1)


def test_a_urx_recorded_group_is_the_track_keyword():
    # A URX file of a B-mode group then a Doppler group: the first unless track= names another
    # by index or by its group's description.
    two = READER_FIXTURES / "urx_two_groups.urx"
    assert pcuvd.read_recording(two).n_frames == 1
    for track in (1, "doppler"):
        chosen = pcuvd.read_recording(two, track=track)
        assert chosen.n_frames == 2
        assert chosen.parameters["track"] == {"value": 1, "source": {"kind": "override"}}
    with pytest.raises(ValueError, match=r"no recorded group \"flow\": give track one of 0"):
        pcuvd.read_recording(two, track="flow")


def test_a_decoded_hadamard_zea_track_processes_as_the_coded_recording():
    # The coded events (a pcuvd manifest) and the same events decoded with NumPy, stored by zea
    # with the code's polarity: processing both (events aligned as eq. 2 takes them) gives one
    # set of maps.
    decoded = pcuvd.read_recording(
        READER_FIXTURES / "decoded_hadamard_zea.hdf5", track="hadamard-decoded"
    )
    assert decoded.coding == "decoded"
    np.testing.assert_array_equal(np.diag(decoded.code_matrix), [1, -1, 1, -1])
    coded = pcuvd.read_recording(READER_FIXTURES / "coded_hadamard.toml")
    assert decoded.frame_rate_hz == pytest.approx(coded.frame_rate_hz, rel=1e-6)
    grid = dict(grid_mm=(-4, 4, 9, 15, 0.2), dynamics="off", quiet=True)
    ours = pcuvd.process(coded, event_alignment="simultaneous", **grid)
    theirs = pcuvd.process(decoded, **grid)
    scale = np.abs(ours.power_doppler).max()
    assert np.abs(theirs.power_doppler - ours.power_doppler).max() <= 1e-5 * scale
    np.testing.assert_allclose(theirs.vx, ours.vx, rtol=0, atol=1e-5 * np.nanmax(np.abs(ours.vx)))


def test_from_arrays_equals_the_file(disk):
    recording = pcuvd.read_recording(disk)
    samples = np.transpose(recording.samples, (2, 0, 1))  # (samples, events, channels)
    again = pcuvd.Recording.from_arrays(
        samples,
        axes=("samples", "events", "channels"),
        probe=recording.probe,
        sampling_freq_hz=recording.sampling_freq_hz,
        t0_s=recording.t0_s,
        event_prf_hz=recording.event_prf_hz,
        angles_rad=recording.angles_rad,
        sound_speed_m_s=recording.sound_speed_m_s,
    )
    a, b = pcuvd.process(recording, quiet=True), pcuvd.process(again, quiet=True)
    for name in ("power_doppler", "color_doppler", "bmode_db"):
        assert_same_array(getattr(a, name), getattr(b, name), name)


def test_int16_samples_are_cast_not_truncated(disk):
    recording = pcuvd.read_recording(disk)
    scaled = np.round(recording.samples / np.abs(recording.samples).max() * 30000)
    as_int16 = scaled.astype(np.int16)
    kwargs = dict(
        probe=recording.probe,
        sampling_freq_hz=recording.sampling_freq_hz,
        t0_s=recording.t0_s,
        event_prf_hz=recording.event_prf_hz,
        angles_rad=recording.angles_rad,
    )
    from_int = pcuvd.Recording.from_arrays(as_int16, **kwargs)
    from_float = pcuvd.Recording.from_arrays(scaled.astype(np.float64), **kwargs)
    assert from_int.samples.dtype == np.float32
    np.testing.assert_array_equal(from_int.samples, from_float.samples)


def test_to_xarray_has_coordinates_in_metres(disk):
    xr = pytest.importorskip("xarray")
    result = pcuvd.process(disk, quiet=True, sites_mm=[(0, 25), (-5, 20)])
    dataset = result.to_xarray()
    assert isinstance(dataset, xr.Dataset)
    # The sites' spectrograms, on their windows' times.
    assert dataset["site_spectrograms"].dims == ("site", "site_time", "site_velocity_bin")
    np.testing.assert_array_equal(dataset["site_time"].values, result.site_times)
    assert dataset["site_mean_velocity"].shape == (2, len(result.site_times))
    np.testing.assert_array_equal(dataset["x"].values, result.x)
    np.testing.assert_array_equal(dataset["z"].values, result.z)
    assert dataset["color_doppler"].dims == ("z", "x")
    assert dataset["projections"].dims == ("angle", "z", "x")
    # The default clutter filter works in blocks: their cut-offs come along.
    assert dataset["clutter_block_cut_offs"].dims == (
        "segment", "angle", "block_row", "block_column", "cut"
    )
    # Depths of the disk recording are centimetres, i.e. a few hundredths of a metre.
    assert 0 < float(dataset["z"].max()) < 0.1


def test_threads_run_at_once_and_agree(disk):
    """The GIL is released during computation: two threads process the same recording."""
    from concurrent.futures import ThreadPoolExecutor

    recording = pcuvd.read_recording(disk)
    with ThreadPoolExecutor(2) as pool:
        results = list(pool.map(lambda _: pcuvd.process(recording, quiet=True), range(2)))
    assert_same_array(results[0].power_doppler, results[1].power_doppler, "power_doppler")


# The middle of the steady tube (centred at 8 mm depth) is enough to compare runs; the tube read
# as if a 40 Hz heart beat: one 25 ms cycle in the 33 ms recording.
TUBE_GRID_MM = (-3, 3, 4, 10, 0.08)


def tube_by_python_and_cli(tube, cli, out, **option):
    """The tube on a 0.08 mm grid without dynamics, with the one keyword `option`: the Python
    result, and the command's completed process with the same option, writing into `out`."""
    ((name, value),) = option.items()
    result = pcuvd.process(tube, grid_mm=TUBE_GRID_MM, dynamics="off", quiet=True, **option)
    done = run_cli(
        cli, "process", tube, "--out", out, "--grid=" + ",".join(map(str, TUBE_GRID_MM)),
        "--dynamics=off", f"--{name.replace('_', '-')}={value}",
    )
    assert done.returncode == 0, done.stderr
    return result, done


def test_doppler_estimator_is_the_cli_option(tube, cli, tmp_path):
    """`doppler_estimator=` is `--doppler-estimator`. Both estimators share the lag-1 phase and
    differ in the frequency they divide it by: Kasai the nominal f_0, Loupas (the default) each
    pixel's measured mean frequency, which on these attenuated echoes is below f_0 (the image's
    harmonic mean and the attenuation's downshift), so Loupas reads faster by f_0 / f̄."""
    loupas = pcuvd.process(tube, grid_mm=TUBE_GRID_MM, dynamics="off", quiet=True)
    by_cli = tmp_path / "cli"
    kasai, _ = tube_by_python_and_cli(tube, cli, by_cli, doppler_estimator="kasai")
    assert loupas.summary["doppler"]["estimator"] == "loupas"
    assert kasai.summary["doppler"]["estimator"] == "kasai"
    assert_same_array(kasai.projections, np.load(by_cli / "projections.npy"), "projections")
    moving = np.isfinite(kasai.projections) & (np.abs(kasai.projections) > 2e-3)
    ratio = np.median(loupas.projections[moving] / kasai.projections[moving])
    assert 1.0 < ratio < 1.2, ratio
    # Each projection's Nyquist velocity: Kasai's the summary's everywhere, Loupas's from each
    # pixel's mean frequency, so a projection (a phase within ±π) never exceeds its own, and the
    # two differ by the same ratio as the projections.
    assert_same_array(
        kasai.projection_nyquist, np.load(by_cli / "projection_nyquist.npy"), "projection_nyquist"
    )
    np.testing.assert_allclose(kasai.projection_nyquist, kasai.summary["nyquist_velocity_m_s"])
    reached = np.isfinite(loupas.projections)
    assert np.all(np.abs(loupas.projections[reached]) <= loupas.projection_nyquist[reached])
    nyquist_ratio = loupas.projection_nyquist[moving] / kasai.projection_nyquist[moving]
    np.testing.assert_allclose(
        nyquist_ratio, loupas.projections[moving] / kasai.projections[moving], rtol=1e-9
    )
    # A grid too coarse for Loupas's axial lag: the command's message, before any work.
    with pytest.raises(ValueError, match="doppler_estimator=\"loupas\" on a 100.0 µm axial grid step"):
        pcuvd.process(tube, grid_mm=(-3, 3, 4, 10, 0.1), dynamics="off", quiet=True)


def test_dealiasing_a_coded_recording_warns(tube, cli, tmp_path):
    """Coded flow beyond the Nyquist velocity decodes wrongly, which dealiasing cannot mend: the
    command warns on stderr, summary.json says so, and Python raises a UserWarning; dealiasing a
    conventional recording does none of that."""
    options = ["--grid=-3,3,4,10,0.08", "--dynamics=off", "--dealias=auto"]
    done = run_cli(cli, "process", tube, "--out", tmp_path / "cli", *options)
    assert done.returncode == 0, done.stderr
    assert "Hadamard-coded" in done.stderr and "44.4 mm/s" in done.stderr, done.stderr
    summary = json.loads((tmp_path / "cli" / "summary.json").read_text())
    assert "Hadamard-coded" in summary["dealias"]["warning"]
    kwargs = {"grid_mm": (-3, 3, 4, 10, 0.08), "dynamics": "off", "dealias": "auto"}
    with pytest.warns(UserWarning, match="Hadamard-coded"):
        result = pcuvd.process(tube, quiet=True, **kwargs)
    assert result.summary["dealias"]["warning"] == summary["dealias"]["warning"]

    simulate = ["simulate", "--preset", "tube", "--mode", "conventional", "--frames", "10"]
    done = run_cli(cli, *simulate, "--out", tmp_path / "conventional")
    assert done.returncode == 0, done.stderr
    conventional = tmp_path / "conventional" / "conventional.toml"
    done = run_cli(cli, "process", conventional, "--out", tmp_path / "cli2", *options)
    assert done.returncode == 0 and "warning" not in done.stderr, done.stderr
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = pcuvd.process(conventional, quiet=True, **kwargs)
    assert result.summary["dealias"]["warning"] is None


def test_dealiasing_too_few_angles_warns(disk, cli, tmp_path):
    """Alias patterns need three or more distinct angles to be told apart: asked of the real
    single-angle disk recording, dealiasing unwraps nothing, and the command, summary.json and
    Python say so rather than leave the user to find it out from the maps; without --dealias
    nothing is said."""
    done = run_cli(cli, "process", disk, "--out", tmp_path / "cli", "--dealias=2")
    assert done.returncode == 0, done.stderr
    assert "3 or more distinct steering angles" in done.stderr, done.stderr
    assert "has 1: nothing was unwrapped" in done.stderr, done.stderr
    summary = json.loads((tmp_path / "cli" / "summary.json").read_text())
    assert "nothing was unwrapped (--dealias 2 had no effect)" in summary["dealias"]["warning"]
    # The warning names the keyword the Python user gave, not the command's flag.
    with pytest.warns(UserWarning, match=r"distinct steering angles.*\(dealias=2 had no effect\)"):
        result = pcuvd.process(disk, quiet=True, dealias=2)
    assert result.summary["dealias"]["warning"] == summary["dealias"]["warning"]
    done = run_cli(cli, "process", disk, "--out", tmp_path / "off")
    assert "dealiasing" not in done.stderr, done.stderr
    summary = json.loads((tmp_path / "off" / "summary.json").read_text())
    assert summary["dealias"]["warning"] is None


def test_partial_volume_is_the_cli_option(tube, cli, tmp_path):
    """`partial_volume="on"` is `--partial-volume on`: the same vectors from both, recorded in
    summary.json. It moves the vectors (each projection from its cell's power centroid to its
    pixel before the fit) and leaves the projections written as they were measured."""
    off = pcuvd.process(
        tube, grid_mm=TUBE_GRID_MM, dynamics="off", partial_volume="off", quiet=True
    )
    by_cli = tmp_path / "cli"
    on, _ = tube_by_python_and_cli(tube, cli, by_cli, partial_volume="on")
    assert off.summary["doppler"]["partial_volume"] is False
    assert on.summary["doppler"]["partial_volume"] is True
    # Each angle's measured cell: the L22-14vX's is wider than it is deep (about 0.09 × 0.025 mm).
    cells = on.summary["doppler"]["partial_volume_cells"]
    assert len(cells) == 8
    assert all(0.02 < c["sigma_z_mm"] < c["sigma_x_mm"] < 0.3 for c in cells), cells
    assert_same_array(on.vx, np.load(by_cli / "vx.npy"), "vx")
    assert_same_array(on.projections, off.projections, "projections")
    both = np.isfinite(on.vx) & np.isfinite(off.vx)
    assert np.nanmax(np.abs(on.vx - off.vx)[both]) > 1e-4
