"""Bad input raises ValueError / OSError / TypeError with the CLI's message, never crashes."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

import pcuvd
from conftest import run_cli


def _cli_error(cli, *args) -> str:
    done = run_cli(cli, *args)
    assert done.returncode != 0
    line = done.stderr.strip().splitlines()[-1]
    assert line.startswith("error: "), done.stderr
    return line.removeprefix("error: ")


def _as_keywords(message: str) -> str:
    """The CLI's message as the package words it: each `--flag` the keyword a Python user gave
    (`-` as `_`), with the value the message gives it (a number, a quoted string, on/off/auto, or
    any word before a colon) as `flag=VALUE` (a bare word quoted)."""

    def keyword(match: re.Match) -> str:
        name, value = match.group(1).replace("-", "_"), match.group(2)
        # The package documents these with the unit in the name.
        name = {"grid": "grid_mm", "sites": "sites_mm"}.get(name, name)
        if value is None:
            return name
        value = value.strip()
        if not re.fullmatch(r"[-+.\d].*|\".*", value):
            value = f'"{value}"'
        return f"{name}={value}"

    value = r"""-?[\d.][^\s:,;)]*|"[^\s:,;)]*|(?:on|off|auto|whole|none|simultaneous|kasai|loupas)\b|[^\s:]+(?=:)"""
    flag = r"(?<![^\s(\[`'\",;])--([a-z][a-z0-9-]*[a-z0-9])"
    return re.sub(flag + f"(?: ({value}))?", keyword, message)


def test_a_bad_option_value_gives_the_cli_message(disk, cli, tmp_path):
    expected = _cli_error(cli, "process", disk, "--out", tmp_path / "o", "--svd-low=banana")
    assert "--svd-low" in expected
    with pytest.raises(ValueError) as raised:
        pcuvd.process(disk, svd_low="banana")
    assert str(raised.value) == _as_keywords(expected)
    assert "svd_low" in str(raised.value) and "--" not in str(raised.value)


@pytest.mark.parametrize(
    "kwargs, says",
    [
        ({"f_number": -1}, "f_number=-1.0: must be within [0.1, 100] (depth / receive aperture width)"),
        ({"doppler_kernel": "7"}, 'doppler_kernel="7": expected ROWSxCOLS, e.g. 3x3'),
        ({"svd_block_mm": -2}, 'svd_block_mm=-2: must be a positive width (mm) or "whole"'),
        ({"max_memory_gb": 0}, "max_memory_gb=0.0: must be a positive number of GB"),
    ],
)
def test_a_bad_value_names_the_keyword_and_the_value_given(disk, kwargs, says):
    """The messages are the command's, which names its flags (`--f-number -1.0: ...`); a Python
    user gave a keyword, and reads it back."""
    with pytest.raises(ValueError) as raised:
        pcuvd.process(disk, quiet=True, **kwargs)
    assert str(raised.value) == says


def test_sites_off_the_grid_name_the_keyword_as_documented(disk, cli, tmp_path):
    expected = _cli_error(cli, "process", disk, "--out", tmp_path / "o", "--sites=100,100")
    with pytest.raises(ValueError) as raised:
        pcuvd.process(disk, sites_mm=[(100, 100)], quiet=True)
    assert str(raised.value) == _as_keywords(expected)
    assert str(raised.value).startswith('sites_mm="100,100": (100, 100) mm lies outside the imaged grid')


def test_a_grid_beyond_the_recording_gives_the_cli_message(disk, cli, tmp_path):
    grid = "-5,5,200,210,0.1"
    expected = _cli_error(cli, "process", disk, "--out", tmp_path / "o", f"--grid={grid}")
    with pytest.raises(ValueError) as raised:
        pcuvd.process(disk, grid_mm=(-5, 5, 200, 210, 0.1), quiet=True)
    assert str(raised.value) == _as_keywords(expected)


def test_cut_offs_that_keep_nothing_give_the_cli_message(disk, cli, tmp_path):
    expected = _cli_error(
        cli, "process", disk, "--out", tmp_path / "o", "--svd-low=30", "--svd-high=5"
    )
    assert "keep no component" in expected
    with pytest.raises(ValueError) as raised:
        pcuvd.process(disk, svd_low=30, svd_high=5, quiet=True)
    assert str(raised.value) == _as_keywords(expected)


def test_ri_the_recording_cannot_give_is_refused_before_processing(disk, cli, tmp_path, capfd):
    # The disk's 3.2 ms hold one 2 ms window: no speed waveform to read RI from.
    expected = _cli_error(cli, "process", disk, "--out", tmp_path / "o", "--window-ms=2")
    assert "at least 2 windows" in expected
    capfd.readouterr()
    with pytest.raises(ValueError) as raised:
        pcuvd.process(disk, window_ms=2)
    assert str(raised.value) == _as_keywords(expected)
    assert "decode" not in capfd.readouterr().err


def test_the_note_on_ri_maps_names_the_keyword_that_silences_it(disk, cli, tmp_path, capfd):
    """The disk's 3.2 ms hold no dynamics window: the run goes on without RI maps and says so, the
    command naming its flag, Python the keyword (the note is the command's, printed by the
    native half)."""
    done = run_cli(cli, "process", disk, "--out", tmp_path / "o")
    assert done.returncode == 0, done.stderr
    (said,) = [line for line in done.stderr.splitlines() if line.startswith("note: no RI maps")]
    assert said.endswith("(--dynamics off silences this)"), said
    capfd.readouterr()
    pcuvd.process(disk, quiet=True)
    notes = [line for line in capfd.readouterr().err.splitlines() if line.startswith("note:")]
    assert notes == [_as_keywords(said)], notes
    assert notes[0].endswith('(dynamics="off" silences this)'), notes


def test_an_impossible_override_names_the_keyword(disk):
    with pytest.raises(ValueError, match=r"sound_speed_m_s=\) must be finite and > 0, got 0"):
        pcuvd.read_recording(disk, sound_speed_m_s=0)
    with pytest.raises(ValueError, match="angles_rad= must each be finite and within"):
        pcuvd.read_recording(disk, angles_rad=[15.0])


def test_a_memory_bomb_grid_is_refused_before_any_work(disk):
    with pytest.raises(ValueError, match="too many"):
        pcuvd.process(disk, grid_m=(-1, 1, 0, 1, 1e-6))


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"svd_lo": "auto"}, TypeError, "unexpected keyword 'svd_lo'"),
        ({"f_number": -1}, ValueError, "f-number|f_number|F#"),
        ({"doppler_kernel": (2, 2)}, ValueError, "odd"),
        ({"irls_max_iterations": 0}, ValueError, "iteration"),
        ({"dynamics": "sometimes"}, ValueError, "sometimes"),
        ({"max_memory_gb": -3}, ValueError, "max_memory_gb=-3"),
        ({"grid_m": (0, 1)}, ValueError, "five numbers|expected"),
        ({"grid_m": (-1, 1, 0, 1, 0.1), "grid_mm": (-1, 1, 0, 1, 0.1)}, TypeError, "one of"),
        # JSON has no NaN or infinity: the keyword is named, not the place a parse failed.
        ({"heart_rate_hz": float("nan")}, ValueError, "heart_rate_hz: expected finite numbers"),
        ({"window_ms": np.float32("inf")}, ValueError, "window_ms: expected finite numbers"),
        ({"grid_mm": (-1, 1, 5, 9, np.nan)}, ValueError, "grid_mm: expected finite numbers"),
        # A value of the wrong kind names its keyword, not a place in the package's JSON.
        ({"ensemble_frames": 10**30}, ValueError, r"^ensemble_frames: invalid type: floating point `1e\+30`, expected usize$"),
        ({"segment_frames": -3}, ValueError, r"^segment_frames: invalid value: integer `-3`"),
    ],
)
def test_bad_process_options(disk, kwargs, error, match):
    with pytest.raises(error, match=match):
        pcuvd.process(disk, quiet=True, **kwargs)


def test_files_that_cannot_be_recordings(tmp_path):
    with pytest.raises(FileNotFoundError, match="no-such.mat"):
        pcuvd.read_recording(tmp_path / "no-such.mat")
    (tmp_path / "folder.mat").mkdir()
    with pytest.raises(OSError, match="folder.mat"):
        pcuvd.read_recording(tmp_path / "folder.mat")
    (tmp_path / "empty.mat").write_bytes(b"")
    with pytest.raises(ValueError, match="empty.mat"):
        pcuvd.read_recording(tmp_path / "empty.mat")
    (tmp_path / "garbage.mat").write_bytes(b"MATLAB 5.0" + bytes(range(256)) * 3)
    with pytest.raises(ValueError, match="garbage.mat"):
        pcuvd.read_recording(tmp_path / "garbage.mat")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ValueError, match="notes.txt"):
        pcuvd.read_recording(tmp_path / "notes.txt")


GOOD = dict(
    probe="L22-14vX",
    sampling_freq_hz=62.5e6,
    t0_s=0.0,
    event_prf_hz=10e3,
    angles_rad=[-0.1, 0.0, 0.1, 0.2],
)


def _rf(events=8, channels=128, samples=64):
    return np.random.default_rng(0).normal(size=(events, channels, samples)).astype(np.float32)


@pytest.mark.parametrize(
    "samples, changes, match",
    [
        (_rf(channels=64), {}, "64 channels"),
        (_rf(events=6), {}, "whole number of compound frames"),
        (_rf(), {"sampling_freq_hz": 0.0}, "sampling"),
        (_rf(), {"event_prf_hz": -1.0}, "PRF|prf"),
        (_rf(), {"sound_speed_m_s": float("inf")}, "sound"),
        (_rf(), {"angles_rad": [0.1, 0.1, 0.2, 0.3]}, "angle"),
        (_rf(), {"coding": "hadamard"}, "slot_delay_s"),
        (_rf(events=6), {"coding": "hadamard", "slot_delay_s": 1e-6, "angles_rad": [0, 0.1, 0.2]}, "Hadamard|order|frames"),
        (_rf(), {"probe": "no-such-probe"}, "probe"),
        (_rf(), {"probe": {"preset": "L22-14vX", "pitch_m": -1e-4}}, "pitch"),
        (_rf(), {"probe": {"preset": "L22-14vX", "colour": "red"}}, "colour"),
        (np.full((8, 128, 64), np.nan, np.float32), {}, "NaN"),
        (np.zeros((8, 128), np.float32), {}, "3 dimensions"),
        (np.zeros((8, 128, 0), np.float32), {}, "empty"),
        (np.array([["a"]]), {}, "not numeric|dimensions"),
        (_rf().astype(np.int64) * 2**30, {}, "2\\*\\*24"),
    ],
)
def test_bad_arrays_for_a_recording(samples, changes, match):
    with pytest.raises(ValueError, match=match):
        pcuvd.Recording.from_arrays(samples, **{**GOOD, **changes})


def test_bad_arrays_for_stage_functions():
    series = np.ones((4, 5, 6), np.complex64)
    with pytest.raises(ValueError, match="complex"):
        pcuvd.rf_to_iq(series, sampling_freq_hz=40e6, demod_freq_hz=5e6)
    with pytest.raises(ValueError, match="demod_freq_hz"):
        pcuvd.rf_to_iq(np.ones((2, 3, 40)), sampling_freq_hz=40e6, demod_freq_hz=0)
    with pytest.raises(ValueError, match="cut-off"):
        pcuvd.rf_to_iq(np.ones((2, 3, 40)), sampling_freq_hz=40e6, demod_freq_hz=5e6, cutoff_hz=30e6)
    with pytest.raises(ValueError, match="odd"):
        pcuvd.power_doppler(series, kernel=(2, 1))
    with pytest.raises(ValueError, match="2 frames"):
        pcuvd.kasai(series[..., :1], sound_speed_m_s=1540, frame_rate_hz=1e3, center_freq_hz=5e6)
    with pytest.raises(ValueError, match="low"):
        pcuvd.svd_filter(series, low="many")
    with pytest.raises(ValueError, match="3 maps for 2 angles"):
        pcuvd.vector_ls(np.zeros((3, 2, 2)), [0.0, 0.1])
    with pytest.raises(ValueError, match="2 angles"):
        pcuvd.vector_irls(np.zeros((1, 2, 2)), [0.0])
    with pytest.raises(ValueError, match="max_iterations"):
        pcuvd.vector_irls(np.zeros((2, 2, 2)), [0.0, 0.1], max_iterations=0)
    with pytest.raises(ValueError, match="order|Hadamard"):
        pcuvd.decode_hadamard(np.zeros((6, 2, 8)), 3, slot_delay_s=0, sampling_freq_hz=1e6)
    with pytest.raises(ValueError, match="whole number"):
        pcuvd.decode_hadamard(np.zeros((6, 2, 8)), 4, slot_delay_s=0, sampling_freq_hz=1e6)
    with pytest.raises(ValueError, match="alignment"):
        pcuvd.decode_hadamard(np.zeros((8, 2, 8)), 4, slot_delay_s=0, sampling_freq_hz=1e6, alignment="late")
    iq = np.ones((2, 128, 50), np.complex64)
    beam = dict(probe="L22-14vX", angle_rad=0, sampling_freq_hz=62.5e6, demod_freq_hz=15.625e6, t0_s=0)
    with pytest.raises(ValueError, match="behind the probe"):
        pcuvd.beamform(iq, grid_m=(-1e-3, 1e-3, -1e-3, 1e-3, 1e-4), **beam)
    with pytest.raises(ValueError, match="grid"):
        pcuvd.beamform(iq, **beam)
    with pytest.raises(ValueError, match="64 channels"):
        pcuvd.beamform(iq[:, :64], grid_m=(-1e-3, 1e-3, 1e-3, 2e-3, 1e-4), **beam)
    with pytest.raises(ValueError, match="apodization"):
        pcuvd.beamform(iq, grid_m=(-1e-3, 1e-3, 1e-3, 2e-3, 1e-4), apodization="tukey", **beam)
    with pytest.raises(ValueError, match="shape"):
        pcuvd.resistivity_index(np.ones((2, 2)), np.ones((2, 3)))
    # Whole numbers past 64 bits, or not whole: a ValueError naming the argument (the native
    # half's conversion raised OverflowError, "int too big to convert").
    projections = np.zeros((2, 2, 2))
    for bad in (10**30, 2.5, float("inf"), "3"):
        with pytest.raises(ValueError, match=r"^max_iterations: expected a whole number ≥ 1"):
            pcuvd.vector_irls(projections, [0.0, 0.1], max_iterations=bad)
        with pytest.raises(ValueError, match=r"^n_angles: expected a whole number ≥ 1"):
            pcuvd.decode_hadamard(np.zeros((8, 2, 8)), bad, slot_delay_s=0, sampling_freq_hz=1e6)
        with pytest.raises(ValueError, match=r"^blocks: expected a whole number ≥ 1"):
            pcuvd.svd_filter(series, blocks=(bad, 2))
        with pytest.raises(ValueError, match=r"^kernel: expected a whole number ≥ 1"):
            pcuvd.power_doppler(series, kernel=(1, bad))


def test_samples_beyond_single_precision_products_are_refused(disk):
    """Field II-scale RF (1e-22) and images far above any scanner's are refused with the peak
    and a factor into the range, where they gave maps of noise or an infinite power; a power of
    two inside the range changes no velocity."""
    recording = pcuvd.read_recording(disk)
    layout = dict(axes=("events", "channels", "samples"), probe=recording.probe,
                  sampling_freq_hz=recording.sampling_freq_hz, t0_s=recording.t0_s,
                  event_prf_hz=recording.event_prf_hz, angles_rad=recording.angles_rad)

    def scaled(factor):
        return pcuvd.Recording.from_arrays(recording.samples * np.float32(factor), **layout)

    for factor, side in ((1e-22, "below"), (1e16, "above")):
        with pytest.raises(ValueError, match=f"sample scale.*{side}.*scale the samples into it"):
            pcuvd.process(scaled(factor), dynamics="off", quiet=True)
    unit = pcuvd.process(scaled(1.0), dynamics="off", quiet=True)
    small = pcuvd.process(scaled(2.0**-40), dynamics="off", quiet=True)
    np.testing.assert_array_equal(small.color_doppler, unit.color_doppler)
    np.testing.assert_array_equal(small.power_doppler, unit.power_doppler * 2.0**-80)
    series = np.full((4, 5, 6), 1e20, np.complex64)
    for stage in (pcuvd.power_doppler, pcuvd.svd_filter):
        with pytest.raises(ValueError, match="the series peak at 1.00e20.*above"):
            stage(series)


def test_bad_simulation_requests():
    with pytest.raises(ValueError, match="nowhere"):
        pcuvd.simulate("nowhere")
    with pytest.raises(ValueError, match="angles|Hadamard"):
        pcuvd.simulate("tube", "coded", frames=2, angles=6)
    with pytest.raises(ValueError, match="frames"):
        pcuvd.simulate("tube", "coded", frames=0)
    with pytest.raises(ValueError, match=r"^frames: invalid type: floating point `1e\+30`"):
        pcuvd.simulate("tube", "coded", frames=10**30)
    # 2⁶³ steering angles panicked building their list.
    with pytest.raises(ValueError, match=r"\[sequence\]\.angles = 9223372036854775808: at most 1024"):
        pcuvd.simulate("tube", "coded", frames=2, angles=2**63)
    with pytest.raises(TypeError, match="unexpected keyword 'colour'"):
        pcuvd.simulate("tube", colour="red")
    with pytest.raises(ValueError, match="noise_db: expected finite numbers"):
        pcuvd.simulate("tube", frames=2, noise_db=float("nan"))
    # Petabytes held in memory: refused before any work, not an allocation that fails; a
    # thousand times the frames are more transmit events than any recording holds.
    with pytest.raises(ValueError, match="held in memory, need about .* GB but"):
        pcuvd.simulate("tube", frames=10**9, quiet=True)
    with pytest.raises(ValueError, match="8000000000000 transmit events at 8 angles a frame"):
        pcuvd.simulate("tube", frames=10**12, quiet=True)
    with pytest.raises(ValueError, match="tube_profile applies to preset tube only"):
        pcuvd.simulate("paper-spiral", frames=1, tube_profile="plug")


def test_a_wrong_argument_type_is_a_type_error_naming_what_is_expected():
    # An array where a process result is expected raised AttributeError on '_native'.
    with pytest.raises(TypeError, match="ProcessResult of pcuvd.process, got ndarray"):
        pcuvd.dynamics(np.zeros((4, 4)))
    with pytest.raises(TypeError, match="a Recording or the path of a recording, got ndarray"):
        pcuvd.process(np.zeros((8, 4, 64), np.float32))
    with pytest.raises(TypeError, match="the path of a recording, got int"):
        pcuvd.read_recording(3)


def test_nothing_crashes_the_interpreter(disk):
    """A battery of bad calls in a fresh interpreter: it ends normally, having raised each time."""
    script = f"""
import numpy as np, pcuvd
calls = [
    lambda: pcuvd.read_recording({str(disk)!r}, t0_s=float('nan')),
    lambda: pcuvd.process({str(disk)!r}, grid_mm=(1e300, 1e301, 0, 1, 1e-300)),
    lambda: pcuvd.process({str(disk)!r}, window_ms=-5, dynamics='on'),
    lambda: pcuvd.kasai(np.ones((2, 2, 3)), sound_speed_m_s=0, frame_rate_hz=1, center_freq_hz=1),
    lambda: pcuvd.svd_filter(np.ones((1, 1, 2)), low=10**30),
    lambda: pcuvd.rf_to_iq(np.ones((1, 2, 10)), sampling_freq_hz=1e7, demod_freq_hz=1e-300),
    lambda: pcuvd.rf_to_iq(np.ones((1, 2, 10)), sampling_freq_hz=1e300, demod_freq_hz=5e6),
    lambda: pcuvd.beamform(np.ones((400, 128, 4), np.complex64), probe='L22-14vX', angle_rad=0,
                           sampling_freq_hz=1e7, demod_freq_hz=5e6, t0_s=0,
                           grid_m=(-0.02, 0.02, 0.001, 0.021, 1e-5)),
    lambda: pcuvd.vector_irls(np.full((2, 1, 1), np.inf), [0.0, 0.1], lambda_mm_s=float('nan')),
    lambda: pcuvd.beamform(np.ones((1, 128, 4)), probe={{'preset': 'L22-14vX', 'n_elements': 10**12}},
                           angle_rad=0, sampling_freq_hz=1e7, demod_freq_hz=5e6, t0_s=0,
                           grid_m=(0, 1e-3, 1e-3, 2e-3, 1e-4)),
]
for call in calls:
    try:
        call()
    except (ValueError, TypeError, OSError, OverflowError) as error:
        print(type(error).__name__, str(error)[:120])
    else:
        raise SystemExit("a bad call did not raise")
print("survived")
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "survived" in done.stdout


def test_ri_only_the_data_refuses_raises_with_the_other_maps(cli, tmp_path):
    """RI maps asked for (`dynamics="on"`, no heart rate) that only the data can refuse (120 ms
    of steady flow: windows spanning 85 ms pass the check before the work, but hold no two
    systolic upstrokes) raise a DynamicsError, a ValueError with the CLI's reason, whose result
    holds the maps of the run without the stage; the command writes those maps, then ends in
    the same error."""
    from conftest import steady_flow_manifest

    manifest = steady_flow_manifest(tmp_path)
    with pytest.raises(pcuvd.DynamicsError, match="systolic upstrokes found") as raised:
        pcuvd.process(manifest, dynamics="on", window_ms=40, quiet=True)
    assert isinstance(raised.value, ValueError)
    kept = raised.value.result
    without = pcuvd.process(manifest, dynamics="off", quiet=True)
    for name in ("color_doppler", "power_doppler", "vx", "vz"):
        np.testing.assert_array_equal(getattr(kept, name), getattr(without, name), err_msg=name)
    assert "ri" not in kept.arrays and "systolic" in kept.summary["dynamics"]["failed"]
    # The dynamics stage run again on a result: the same error, the same maps beside it.
    with pytest.raises(pcuvd.DynamicsError, match="systolic upstrokes found") as again:
        pcuvd.dynamics(without, dynamics="on", window_ms=40, quiet=True)
    np.testing.assert_array_equal(again.value.result.vz, without.vz)
    kept.save(tmp_path / "saved")
    assert (tmp_path / "saved" / "vz.npy").is_file()
    # A Dask worker's error reaches its client pickled: the message, without the maps.
    import pickle

    sent = pickle.loads(pickle.dumps(raised.value))
    assert isinstance(sent, pcuvd.DynamicsError) and str(sent) == str(raised.value)
    assert sent.result is None
    out = tmp_path / "out"
    done = run_cli(cli, "process", manifest, "--out", out, "--dynamics", "on", "--window-ms", 40)
    assert done.returncode != 0 and kept.summary["dynamics"]["failed"] in done.stderr
    np.testing.assert_array_equal(np.load(out / "vz.npy"), kept.vz)
