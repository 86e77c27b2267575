"""The paper's studies, as `pcuvd paper` runs them: the numbers it writes to metrics.json."""

from __future__ import annotations

import json
from typing import Any

from . import _checks, _pcuvd


def option_names() -> list[str]:
    """The keyword options the studies accept (`pcuvd paper`'s, with `_` for `-`)."""
    return sorted(_pcuvd.option_names_of("study"))


def settings(**options: Any) -> dict:
    """The settings each study ("spiral", "network", "dealias", "brain") would run with for these
    options, every default filled in and every check made: what `pcuvd paper --print-settings`
    prints for the same options. Raises ValueError for a value the studies refuse."""
    given = _checks.to_options("settings", options, _pcuvd.option_names_of("study"))
    return json.loads(_pcuvd.study_settings(given))


def spiral(*, quiet: bool = False, **options: Any) -> dict:
    """The spiral-flow study (Fig. 2–5): simulate conventional and coded recordings, process,
    compare with the truth. options: `pcuvd paper`'s, e.g. frames=100, seed=1, noise_db=-10,
    sweep=(-30, -20, ...), grid_step=0.05 (mm), motion="per-event",
    event_alignment="mid-frame", doppler_kernel=(5, 1), partial_volume="on", f_number=1.0. Returns its metrics (SNR gain, RMSE
    per estimator in mm/s, improvements, noise sweep, definitions, timings) as a dict."""
    given = _checks.to_options("spiral", options, _pcuvd.option_names_of("study"))
    return json.loads(_pcuvd.study("spiral", given, bool(quiet)))


def network(*, quiet: bool = False, **options: Any) -> dict:
    """The in-vivo-like vessel-network study (Fig. 6–8): RI maps of arterioles and venules by
    UVD and PC-UVD against the truth. options: `pcuvd paper`'s, e.g. network_frames=360,
    network_noise_db=5, heart_rate=5.5 (Hz), seed=1, grid_step=0.05 (mm). Returns its metrics
    as a dict."""
    given = _checks.to_options("network", options, _pcuvd.option_names_of("study"))
    return json.loads(_pcuvd.study("network", given, bool(quiet)))


def brain(*, quiet: bool = False, **options: Any) -> dict:
    """The paper's in vivo experiment (Fig. 6–8) on the virtual rat brain: the brain simulated
    conventional and coded (once: the recordings are cached by scenario, in `brain_cache`,
    default `pcuvd-cache` in the working folder), processed with the clutter filter on, and
    scored against the truth. options: `pcuvd paper`'s, e.g. brain_scenario="rat-brain" (or a
    TOML file), brain_frames=360, brain_svd_low="auto" (or "similarity"), brain_svd_block_mm=2
    (the clutter filter's blocks, mm; the default, or "whole" for one filter of the whole
    image), quick=True (the small brain, `rat-brain-small`, for a first
    look). Returns its metrics:
    vector RMSE and direction error by depth band and vessel diameter, RI scores, the
    vessel-to-background ratio by depth, each with its definition."""
    given = _checks.to_options("brain", options, _pcuvd.option_names_of("study"))
    return json.loads(_pcuvd.study("brain", given, bool(quiet)))
