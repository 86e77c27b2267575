"""Scenario files from Python: a shipped scenario, a file of one's own, and the scenario a
simulation reports, which simulates the same recording again."""

import numpy as np
import pytest

import pcuvd

SMALL = """
seed = 3
[probe]
preset = "L22-14vX"
[sequence]
transmit = "conventional"
angles = 2
event_prf_hz = 1e4
slot_delay_s = 1e-6
pulse_cycles = 2.0
frames = 2
[receive]
sampling_frequency_hz = 65e6
depth_m = [5e-3, 11e-3]
[vessels]
kind = "tube"
peak_velocity_m_s = 0.01
"""


def test_a_scenario_file_sets_what_the_defaults_would_not(tmp_path):
    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    recording, truth = pcuvd.simulate(scenario=path, mode=None, quiet=True)
    # The file's own settings, not the preset's: 2 angles × 2 frames, no noise, a slow tube.
    assert recording.samples.shape[0] == 4
    assert recording.event_prf_hz == 1e4
    speeds = np.hypot(truth.vx, truth.vz)[truth.mask]
    assert speeds.max() == pytest.approx(0.01, rel=0.05)
    # What it reports simulating, written back to a file, simulates the very same samples.
    again = tmp_path / "again.toml"
    again.write_text(truth.scenario)
    copy, _ = pcuvd.simulate(scenario=again, mode=None, quiet=True)
    np.testing.assert_array_equal(copy.samples, recording.samples)


def test_options_override_the_scenario_and_bad_keys_are_named(tmp_path):
    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    recording, truth = pcuvd.simulate(scenario=path, mode=None, frames=1, seed=4, quiet=True)
    assert recording.samples.shape[0] == 2
    assert "seed = 4" in truth.scenario
    path.write_text(SMALL.replace("frames = 2", "frames = 2\nrepeats = 3"))
    with pytest.raises(ValueError, match="repeats"):
        pcuvd.simulate(scenario=path, quiet=True)
    path.write_text(SMALL.replace("depth_m = [5e-3, 11e-3]", "depth_m = [11e-3, 5e-3]"))
    with pytest.raises(ValueError, match=r"\[receive\]\.depth_m"):
        pcuvd.simulate(scenario=path, quiet=True)
    with pytest.raises(ValueError, match="not both"):
        pcuvd.simulate("tube", scenario=path, quiet=True)
