"""A version 2 manifest read from Python: the explicit code, slot starts, pulse and derived angles."""

from __future__ import annotations

import shutil

import numpy as np

import pcuvd
from conftest import REPO


def test_a_v2_recording_exposes_its_code_starts_and_pulse(tmp_path):
    shutil.copy(REPO / "crates" / "pcuvd-io" / "examples" / "recording_v2.toml", tmp_path / "rec.toml")
    rng = np.random.default_rng(1)
    np.save(tmp_path / "rf.npy", rng.standard_normal((2, 4, 16, 64)).astype(np.float32))
    recording = pcuvd.read_recording(tmp_path / "rec.toml")
    assert recording.coding == "matrix"
    assert recording.slot_delay_s is None
    # Rows in the scanner's order, as the manifest lists them.
    np.testing.assert_array_equal(
        recording.code_matrix,
        [[1, -1, 1, -1], [1, 1, 1, 1], [-1, -1, 1, 1], [1, -1, -1, 1]],
    )
    # Starts and angles derived from per-element delays on a 4 ns clock.
    np.testing.assert_allclose(recording.slot_starts_s, [0.0, 1.1e-6, 2.048e-6, 3.2e-6], atol=4e-9)
    np.testing.assert_allclose(recording.angles_deg, [-10, -10 / 3, 10 / 3, 10], atol=0.05)
    samples, rate = recording.transmit_pulse
    assert samples.shape == (66,) and rate == 250e6


def test_a_conventional_recording_has_one_slot_per_event(disk):
    recording = pcuvd.read_recording(disk)
    assert recording.coding == "none"
    np.testing.assert_array_equal(recording.code_matrix, [[1.0]])
    np.testing.assert_array_equal(recording.slot_starts_s, [0.0])
    assert recording.transmit_pulse is None
