"""One long recording (or file of beamformed images) across a Dask cluster: its segments as tasks,
joined into `pcuvd.process`'s result.

A recording too long to hold whole is processed in segments whose Doppler sums, velocity windows
and ensembles add up (see `segment_frames`); here each segment is one task on a worker process,
which opens the recording from its path (shared storage) and reads only its own frames. The parts
come back to this process and are joined in recording order: the result is the one
`pcuvd.process` gives with the same options.

    from dask.distributed import Client, LocalCluster
    import pcuvd.dask

    with LocalCluster(n_workers=2, threads_per_worker=1) as cluster, Client(cluster) as client:
        result = pcuvd.dask.process("long.toml", client, segment_frames=400, quiet=True)
    result.save("long-out")
"""

from __future__ import annotations

import os
import sys
from typing import Any

from . import _pcuvd
from ._process import ProcessResult, _checked, process_options
from ._recording import reader_overrides


def process(
    recording: str | os.PathLike,
    client: Any,
    *,
    overrides: dict[str, Any] | None = None,
    quiet: bool = False,
    **options: Any,
) -> ProcessResult:
    """Runs `pcuvd.process(recording, **options)` with its segments as tasks of the Dask
    `client` (a `distributed.Client`; worker processes, each with pcuvd installed and the
    recording's path readable).

    recording: the path of a recording in any format `pcuvd process` reads, or of an images
    manifest or ConfUSIus's Zarr store of IQ (beamformed images formed elsewhere, each worker
    reading its segment's frames; overrides do not apply to them). overrides: the
    reader's acquisition overrides (`t0_s`, `sound_speed_m_s`, `event_prf_hz`,
    `sampling_freq_hz`, `center_freq_hz`, `angles_rad`, `pulse_cycles`, `bandwidth`, `track`),
    as `read_recording` takes them. options: `process`'s keywords; `segment_frames` sets the
    frames of each segment (by default as many as fit in this machine's memory, so that a
    recording that fits whole is one segment: a ValueError says to give it). The first segment
    runs before the others when it settles the velocity windows' dealiasing for them.
    """
    if not isinstance(recording, (str, os.PathLike)):
        raise TypeError(
            "pcuvd.dask.process() expects the path of a recording (each worker reads its own "
            f"frames from it), got {type(recording).__name__}"
        )
    path = os.fspath(recording)
    given = process_options("pcuvd.dask.process", options)
    read = reader_overrides(overrides)
    planned = _pcuvd.segment_count(path, read, given)
    if planned is None:
        raise ValueError(
            f"{path}: processed whole, in one segment: give segment_frames= (fewer frames than "
            "the recording's) to share its segments among the workers"
        )
    # The memory check here may space out or drop the dynamics windows of `dynamics="auto"` (the
    # windows of the whole recording, joined here, would not fit): every worker and the join
    # then run the same plan.
    count, first_settles, dynamics_fit, note = planned
    if note is not None and not quiet:
        print(f"note: {note}", file=sys.stderr)
    done = 0

    def submit(index: int, intervals: int | None) -> Any:
        return client.submit(
            _segment, path, read, given, index, intervals, dynamics_fit, pure=False
        )

    def gathered(futures: list[Any]) -> list[tuple[bytes, int | None]]:
        # Parts in submission order; a line per finished segment unless quiet.
        nonlocal done
        if not quiet:
            from distributed import as_completed

            for _ in as_completed(futures):
                done += 1
                print(f"{path}: segment {done}/{count} processed", file=sys.stderr)
        return client.gather(futures)

    if first_settles:
        # Segment 0 settles the Nyquist intervals every segment's velocity windows unwrap by.
        [(first, intervals)] = gathered([submit(0, None)])
        rest = gathered([submit(index, intervals) for index in range(1, count)])
        parts = [first] + [part for part, _ in rest]
    else:
        parts = [part for part, _ in gathered([submit(i, None) for i in range(count)])]
    return _checked(_pcuvd.join_segments(path, read, given, parts, bool(quiet), dynamics_fit))


def _segment(
    path: str,
    overrides: str,
    options: str,
    index: int,
    window_intervals: int | None,
    dynamics_fit: str | None,
) -> tuple[bytes, int | None]:
    """One task: segment `index` of the run, processed in the worker (its part as bytes)."""
    from pcuvd import _pcuvd as native

    return native.process_segment(
        path, overrides, options, index, window_intervals, dynamics_fit
    )
