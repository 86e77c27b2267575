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
