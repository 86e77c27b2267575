"""`pcuvd.study` returns the numbers `pcuvd paper` writes, at reduced size."""

from __future__ import annotations

import json

import pytest

import pcuvd
from conftest import run_cli


def _without_timings(value):
    """The metrics less their wall-clock timings (which differ between any two runs)."""
    if isinstance(value, dict):
        return {
            k: _without_timings(v) for k, v in value.items() if k not in ("timing_s", "total_s")
        }
    return value


STUDIES = {
    "spiral": (
        ["--frames", "8", "--grid-step", "0.2", "--sweep=-10,5"],
        {"frames": 8, "grid_step": 0.2, "sweep": (-10, 5)},
    ),
    # A fast heart makes one cardiac cycle fit in 130 frames, so RI can be measured quickly.
    "network": (
        ["--network-frames", "130", "--heart-rate", "20", "--grid-step", "0.2"],
        {"network_frames": 130, "heart_rate": 20, "grid_step": 0.2},
    ),
}


@pytest.mark.parametrize("which", sorted(STUDIES))
def test_study_numbers_equal_pcuvd_paper(which, cli, tmp_path):
    args, kwargs = STUDIES[which]
    done = run_cli(cli, "paper", "--part", which, *args, "--out", tmp_path)
    assert done.returncode == 0, done.stderr
    written = json.loads((tmp_path / "metrics.json").read_text())
    metrics = getattr(pcuvd.study, which)(quiet=True, **kwargs)
    assert metrics, "no metrics"
    expected = {k: written[k] for k in metrics}
    assert _without_timings(metrics) == _without_timings(expected)


def test_study_refuses_an_unknown_option_and_a_bad_value():
    with pytest.raises(TypeError, match="unexpected keyword 'frame'"):
        pcuvd.study.spiral(frame=8)
    with pytest.raises(ValueError, match="frames"):
        pcuvd.study.spiral(frames=1, quiet=True)
