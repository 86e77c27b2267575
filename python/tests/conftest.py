"""Shared fixtures: the repository, the real disk recording, and the `pcuvd` command to compare with."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def disk() -> Path:
    """The measured rotating-disk recording shipped beside the repository (never skipped)."""
    path = REPO.parent / "shared" / "data" / "PWI_disk.mat"
    assert path.is_file(), f"{path} is missing: the tests need the shared disk recording"
    return path


@pytest.fixture(scope="session")
def cli() -> Path:
    """The `pcuvd` command: $PCUVD_BIN, else the newest build in target/ (CI: target/debug)."""
    given = os.environ.get("PCUVD_BIN")
    if given:
        path = Path(given)
    else:
        built = [REPO / "target" / p / "pcuvd" for p in ("release", "debug")]
        built = [p for p in built if p.is_file()]
        assert built, "no pcuvd binary: run `cargo build -p pcuvd-cli` or set PCUVD_BIN"
        path = max(built, key=lambda p: p.stat().st_mtime)
    assert path.is_file(), f"{path}: no pcuvd binary there"
    return path


def run_cli(cli: Path, *args: str | os.PathLike) -> subprocess.CompletedProcess:
    """Runs the command quietly; returns the completed process (check its returncode)."""
    return subprocess.run(
        [str(cli), "--quiet", *map(str, args)], capture_output=True, text=True, timeout=1800
    )


def assert_same_array(a: np.ndarray, b: np.ndarray, name: str) -> None:
    """Equal shape, dtype and values, NaN where the other has NaN."""
    assert a.shape == b.shape, f"{name}: shape {a.shape} vs {b.shape}"
    assert a.dtype == b.dtype, f"{name}: dtype {a.dtype} vs {b.dtype}"
    np.testing.assert_array_equal(a, b, err_msg=name)


def beamform_each_angle(recording, x_m, z_m) -> np.ndarray:
    """The conventional `recording`'s images per steering angle, (angles, z, x, frames), formed
    with the Python stages as `process` forms them (demodulated at the probe's centre frequency)
    on the pixels `x_m`, `z_m`."""
    import pcuvd

    fc = recording.probe["center_freq_hz"]
    iq = pcuvd.rf_to_iq(recording.samples, sampling_freq_hz=recording.sampling_freq_hz,
                        demod_freq_hz=fc, t0_s=recording.t0_s)
    n = recording.n_angles
    return np.stack([
        pcuvd.beamform(iq[k::n], probe=recording.probe, angle_rad=float(angle),
                       sampling_freq_hz=recording.sampling_freq_hz, demod_freq_hz=fc,
                       t0_s=recording.t0_s, x_m=x_m, z_m=z_m,
                       sound_speed_m_s=recording.sound_speed_m_s)
        for k, angle in enumerate(recording.angles_rad)
    ])


def steady_flow_manifest(folder):
    """The images manifest of 120 ms of steady flow at 1 kHz (two steered series of 24 × 20
    pixels: still speckle 30 dB over a band of blood at an 80 Hz Doppler tone, and noise), which
    holds no cardiac cycle: RI maps asked for of it (windows of 40 ms) fail for the data alone.
    Returns its path."""
    rng = np.random.default_rng(7)
    n_angles, frames, nz, nx = 2, 120, 24, 20

    def speckle(*shape):
        return rng.standard_normal(shape) + 1j * rng.standard_normal(shape)

    images = 30 * speckle(nz, nx) + 0.05 * speckle(n_angles, frames, nz, nx)
    tone = np.exp(-2j * np.pi * 80.0 * np.arange(frames) / 1000.0)
    images[:, :, 8:16, :] += speckle(nz, nx)[8:16] * tone[None, :, None, None]
    return images_manifest(
        folder, images.astype(np.complex64), ["angles", "frames", "z", "x"],
        np.linspace(-1e-3, 1e-3, nx), np.linspace(5e-3, 7e-3, nz), frame_rate_hz=1000.0,
        demod_frequency_hz=15.625e6, angles_deg=[-5.0, 5.0],
    )


def images_manifest(folder, images, axes, x_m, z_m, **numbers):
    """Saves `images` with NumPy as folder/iq.npy and writes the images manifest that describes
    them (axes, the first and last pixel centres, and `numbers`' keys); returns its path."""
    import json

    np.save(folder / "iq.npy", images)
    x, z = [float(v) for v in x_m], [float(v) for v in z_m]
    lines = ['format = "pcuvd-images"', "version = 1", "[images]", 'file = "iq.npy"',
             f"axes = {json.dumps(list(axes))}", f"x_m = [{x[0]!r}, {x[-1]!r}]",
             f"z_m = [{z[0]!r}, {z[-1]!r}]"]
    lines += [f"{key} = {json.dumps(value if isinstance(value, list) else float(value))}"
              for key, value in numbers.items()]
    manifest = folder / "images.toml"
    manifest.write_text("\n".join(lines) + "\n")
    return manifest
