"""`pcuvd.dynamics`: the dynamics stage re-run on a processed result, and the cardiac cycles a
manifest records, on a steady coded tube."""

from __future__ import annotations

from pathlib import Path

import pytest

import pcuvd
from conftest import assert_same_array, run_cli

STEADY_GRID = {"grid_mm": (-1.5, 1.5, 6.5, 9.5, 0.08)}
STEADY_WINDOWS = {"window_ms": 5, "window_step_ms": 1}
BEAT = {"heart_rate_hz": 40, **STEADY_WINDOWS}


@pytest.fixture(scope="module")
def steady_tube(tmp_path_factory, cli) -> Path:
    """A steady coded tube 6 mm long (its ends outside the grid), 4 angles (3.6 kHz frames), 120
    frames (33 ms) without noise, written by `pcuvd simulate`: `coded.toml`,
    the same recording with one cardiac cycle's triggers in its manifest (`with_triggers.toml`)
    and those triggers as a text file (`triggers.txt`)."""
    folder = tmp_path_factory.mktemp("steady_tube")
    done = run_cli(cli, "simulate", "--preset", "tube", "--mode", "coded", "--frames", "120",
                   "--angles", "4", "--noise-db", "off", "--tube-length-mm", "6", "--out", folder)
    assert done.returncode == 0, done.stderr
    plain = folder / "coded.toml"
    (folder / "with_triggers.toml").write_text(
        plain.read_text() + "\n[cardiac]\ntriggers_s = [0.002, 0.027]\n"
    )
    (folder / "triggers.txt").write_text("0.002\n0.027\n")
    return folder


@pytest.fixture(scope="module")
def steady_without_dynamics(steady_tube):
    return pcuvd.process(str(steady_tube / "coded.toml"), dynamics="off", quiet=True, **STEADY_GRID)


def test_dynamics_rerun_equals_processing_with_those_settings(
    steady_tube, steady_without_dynamics
):
    """pcuvd.dynamics re-runs only the dynamics stage: the same RI maps as a full process."""
    without = steady_without_dynamics
    assert without.summary["dynamics"] == {"skipped": "--dynamics off"}
    with pytest.raises(AttributeError, match="dynamics"):
        without.ri
    rerun = pcuvd.dynamics(without, quiet=True, **BEAT)
    full = pcuvd.process(str(steady_tube / "coded.toml"), quiet=True, **STEADY_GRID, **BEAT)
    for name in ("ri", "psv", "edv", "vessel_class", "flow_up", "speed_series", "times", "vx"):
        assert_same_array(getattr(rerun, name), getattr(full, name), name)
    assert rerun.summary["dynamics"] == full.summary["dynamics"]
    with pytest.raises(TypeError, match="unexpected keyword 'grid_mm'"):
        pcuvd.dynamics(without, grid_mm=(-1, 1, 4, 5, 0.1))
    with pytest.raises(ValueError, match="window"):
        pcuvd.dynamics(without, heart_rate_hz=40, window_ms=-1)
    with pytest.raises(TypeError, match="ProcessResult"):
        pcuvd.dynamics(without.power_doppler)


def test_triggers_recorded_in_the_manifest_are_used(steady_tube, steady_without_dynamics):
    """A manifest's [cardiac] triggers give the dynamics stage its cycles without any keyword,
    exactly as `cardiac_triggers=` with the same times does; a heart rate given wins. (The
    stage re-run gives what processing gives: the test above.)"""
    from_manifest = pcuvd.process(
        str(steady_tube / "with_triggers.toml"), quiet=True, **STEADY_GRID, **STEADY_WINDOWS
    )
    dynamics = from_manifest.summary["dynamics"]
    assert "manifest" in dynamics["triggers_from"] and dynamics["cycles_count"] == 1, dynamics
    given = pcuvd.dynamics(
        steady_without_dynamics,
        quiet=True,
        cardiac_triggers=str(steady_tube / "triggers.txt"),
        **STEADY_WINDOWS,
    )
    assert given.summary["dynamics"]["triggers_from"] == "--cardiac-triggers"
    assert_same_array(from_manifest.ri, given.ri, "ri")
    rate = pcuvd.dynamics(from_manifest, quiet=True, **BEAT)
    assert rate.summary["dynamics"].get("triggers_from") is None
    assert rate.summary["dynamics"]["heart_rate_hz"] == 40


def test_ri_settings_change_on_the_windows_of_a_run_in_segments(steady_tube):
    """A recording processed in segments keeps its velocity windows, not its filtered series:
    `pcuvd.dynamics` with other RI settings on the same windows gives what processing in
    segments with those settings gives; new windows, or a run that made none, are refused
    naming what may change."""
    path = str(steady_tube / "coded.toml")
    segmented = {"segment_frames": 40, **STEADY_GRID}
    first = pcuvd.process(path, quiet=True, **segmented, **BEAT)
    assert first.summary["segments"]["count"] >= 3, first.summary["segments"]
    other = {"heart_rate_hz": 45, "artery_ri_min": 0.2, "vein_ri_max": 0.1, "pool_along_mm": 0,
             "pool_across_mm": 0, **STEADY_WINDOWS}
    rerun = pcuvd.dynamics(first, quiet=True, **other)
    full = pcuvd.process(path, quiet=True, **segmented, **other)
    for name in ("ri", "psv", "edv", "vessel_class", "flow_up", "speed_series", "times", "vx"):
        assert_same_array(getattr(rerun, name), getattr(full, name), name)
    assert rerun.summary["dynamics"] == full.summary["dynamics"]
    assert rerun.summary["dynamics"]["heart_rate_hz"] == 45
    assert rerun.summary["dynamics"] != first.summary["dynamics"]
    with pytest.raises(ValueError, match=r"give the run's window_ms \(5 ms\), window_step_ms"):
        pcuvd.dynamics(first, heart_rate_hz=40, window_ms=4, window_step_ms=1)
    without = pcuvd.process(path, quiet=True, dynamics="off", **segmented)
    with pytest.raises(ValueError, match=r"made none \(dynamics=\"off\"\)"):
        pcuvd.dynamics(without, **BEAT)


def test_one_map_is_made_alone_and_every_map_is_listed(steady_tube):
    """An attribute makes its map alone (a long recording's speed series only when asked for),
    equal to the one `arrays` gives; `repr` and `dir` list the maps without making them."""
    result = pcuvd.process(
        str(steady_tube / "coded.toml"), quiet=True, ensemble_frames=40, **STEADY_GRID, **BEAT
    )
    asked = ("ri", "speed_series", "ensemble_speed", "clutter_block_cut_offs", "x")
    for name in asked:
        getattr(result, name)
    assert "speed_series" in repr(result) and "ensemble_speed" in dir(result)
    assert sorted(result._maps) == sorted(asked + ("z",)), "an attribute or repr made other maps"
    named = {name: getattr(result, name) for name in result._native.array_names()}
    assert sorted(named) == sorted(result.arrays)
    for name, value in result.arrays.items():
        assert_same_array(named[name], value, name)
    with pytest.raises(AttributeError):
        result.no_such_map
