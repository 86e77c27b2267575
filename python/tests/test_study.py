"""`pcuvd.study` returns the numbers `pcuvd paper` writes, at reduced size."""

from __future__ import annotations

import json

import numpy as np
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


# A 0.2 mm grid keeps these quick; it is too coarse for Loupas's axial lag (at most 98.7 µm at
# 15.6 MHz), so both read velocity with Kasai, which also checks that `doppler_estimator=` is
# `--doppler-estimator`. A fast heart makes one cardiac cycle fit in the network's 104 frames.
CLI_ARGS = [
    "--frames", "8", "--grid-step", "0.2", "--sweep=-10,5", "--doppler-estimator", "kasai",
    "--network-frames", "104", "--heart-rate", "25", "--doppler-kernel", "3x1",
    "--dealias-seeds", "2,3", "--partial-volume", "off",
]
KEYWORDS = {
    "frames": 8, "grid_step": 0.2, "sweep": (-10, 5), "doppler_estimator": "kasai",
    "network_frames": 104, "heart_rate": 25, "doppler_kernel": (3, 1),
    "dealias_seeds": (2, 3), "partial_volume": "off",
}


def test_study_keywords_give_the_settings_of_pcuvd_paper(cli):
    """Every study's settings, from the command's options and from the same keywords, are the
    same once read (defaults filled in, checks made): both front ends run one settings type."""
    done = run_cli(cli, "paper", "--print-settings", *CLI_ARGS)
    assert done.returncode == 0, done.stderr
    by_cli = json.loads(done.stdout)
    by_python = pcuvd.study.settings(**KEYWORDS)
    assert by_python == by_cli
    assert by_python["spiral"]["doppler_kernel"] == [3, 1]
    assert by_python["network"]["frames"] == 104 and by_python["dealias"]["seeds"] == [2, 3]
    # And the defaults are the command's. (The network and dealiasing studies run the library's
    # `study::network::run` / `study::dealias::run` on these settings, tested in Rust's slow tier;
    # the spiral below runs from both front ends.)
    defaults = run_cli(cli, "paper", "--print-settings")
    assert pcuvd.study.settings() == json.loads(defaults.stdout)


def test_small_spiral_study_numbers_equal_pcuvd_paper(cli, tmp_path):
    """One noise level: the two front ends run one study function, so a second level would check
    the study again, not their agreement (its settings' agreement is the test above)."""
    args = ["--frames", "4", "--grid-step", "0.2", "--sweep=-10", "--doppler-estimator", "kasai"]
    done = run_cli(cli, "paper", "--part", "spiral", *args, "--out", tmp_path)
    assert done.returncode == 0, done.stderr
    written = json.loads((tmp_path / "metrics.json").read_text())
    metrics = pcuvd.study.spiral(
        quiet=True, frames=4, grid_step=0.2, sweep=(-10,), doppler_estimator="kasai"
    )
    assert metrics, "no metrics"
    expected = {k: written[k] for k in metrics}
    assert _without_timings(metrics) == _without_timings(expected)


def test_study_refuses_an_unknown_option_and_a_bad_value():
    with pytest.raises(TypeError, match="unexpected keyword 'frame'"):
        pcuvd.study.spiral(frame=8)
    with pytest.raises(ValueError, match="frames"):
        pcuvd.study.spiral(frames=1, quiet=True)
    # Loupas (the default) on a grid too coarse for it, refused before anything is simulated.
    with pytest.raises(ValueError, match="finer grid"):
        pcuvd.study.spiral(frames=8, grid_step=0.2, quiet=True)


def test_simulate_places_the_tube_where_its_options_say():
    """`tube_centre_mm` as a pair, like every list option: a vertical tube through (1, 7) mm."""
    _, truth = pcuvd.simulate(
        "tube",
        "conventional",
        frames=1,
        noise_db=None,
        angles=2,
        quiet=True,
        tube_angle_deg=90,
        tube_centre_mm=(1, 7),
        tube_radius_mm=0.3,
        tube_length_mm=4,
    )
    rows, cols = np.nonzero(truth.mask)
    x, z = truth.x[cols], truth.z[rows]
    assert abs(x.mean() - 1e-3) < 0.02e-3 and abs(z.mean() - 7e-3) < 0.05e-3
    assert x.max() - x.min() <= 0.6e-3 + 1e-9 and z.max() - z.min() <= 4e-3 + 1e-9
    # cos 90° in floating point: Vx of order 1e-18 m/s, not 0.
    assert np.abs(truth.vx[truth.mask]).max() < 1e-12 and truth.vz[truth.mask].max() > 24e-3
