"""A batch of recordings on Dask (one recording = one task) equals a serial loop."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

import pcuvd
from conftest import run_cli

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
