"""`pcuvd.simulate`: the simulator of `pcuvd simulate`, returning recordings and ground truth."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import _checks, _pcuvd
from ._recording import Recording


@dataclass(frozen=True)
class Truth:
    """Ground truth of a simulation on the default processing grid (SI units).

    x (nx), z (nz) in m; vx, vz (nz, nx) in m/s at t = 0 (vx > 0 toward +x, vz > 0 deeper);
    mean_vx, mean_vz (nz, nx): the velocity averaged over the recording (24 times, at each pixel
    over those it holds blood), what a whole-recording vector map estimates: a pulsing vessel's
    mean, not its speed at the start; mask (nz, nx) True inside the moving medium. For the vessel network also `cycle`: ri, psv,
    edv (m/s), vessel_class (0 background, 1 arteriole, 2 venule, 3 undetermined), flow_up, and
    class_share: the share of each pixel's blood of the class named (below 1 where an artery and
    a vein share the elevation beam of the rat brain), and axis_profile: where in its vessel the
    pixel's blood lies, the mean of 1 - (r/R)^2 over it (1 on the axis, 0 at the wall).
    With tissue (tissue_db=..., or the rat brain) also `tissue`: its velocity vx, vz (nz, nx) in
    m/s at t = 0, and its displacement from t = 0 (frames, nz, 3: x, y, z) in m at each frame. For the three-dimensional rat brain also vy (nz, nx), the out-of-plane velocity
    (m/s), and blood_fraction (nz, nx), the blood's share of each pixel's elevation beam; its
    velocities are the elevation-beam-weighted means over the blood each pixel sees. scenario:
    the scenario simulated as TOML, every option applied (`simulate(scenario=path)` of it written
    to a file simulates the same recordings).
    """

    x: np.ndarray
    z: np.ndarray
    vx: np.ndarray
    vz: np.ndarray
    mask: np.ndarray
    mean_vx: np.ndarray | None = None
    mean_vz: np.ndarray | None = None
    cycle: dict[str, np.ndarray] = field(default_factory=dict)
    tissue: dict[str, np.ndarray] = field(default_factory=dict)
    vy: np.ndarray | None = None
    blood_fraction: np.ndarray | None = None
    scenario: str = ""


def simulate_option_names() -> list[str]:
    """The keyword options `simulate` accepts."""
    return sorted(_pcuvd.option_names_of("simulate"))


def simulate(
    preset: str | None = None,
    mode: str | None = "coded",
    frames: int | None = None,
    noise_db: float | str | None = "scenario",
    seed: int | None = None,
    *,
    scenario: str | os.PathLike[str] | None = None,
    quiet: bool = False,
    **options: Any,
) -> tuple[Recording | dict[str, Recording], Truth]:
    """Simulates RF recordings as `pcuvd simulate` does.

    scenario: a scenario file (.toml; see docs/guide/scenarios.md) or the name of a shipped one;
    preset: a shipped scenario by name, "paper-spiral" (the default), "tube", "rat-network",
    "rat-brain" or "rat-brain-small". The other arguments override the scenario's values: mode
    "coded" (Hadamard), "conventional", "both", or None for the scenario's; frames: compound
    frames; noise_db: noise level in dB, None for no noise, "scenario" for the scenario's; seed of
    scatterers and noise (None: the scenario's); options: the other `simulate` options (angles,
    slot_delay_us, peak_velocity_mm_s, tube_profile="plug" for the tube without a gradient across
    it, tube_angle_deg, tube_centre_mm=(x, z), tube_length_mm, tube_radius_mm; tissue_db=40 for
    moving tissue around the vessels, tissue_motion="rat" or "still"). Returns (recording, truth),
    or ({"conventional": ..., "coded": ...}, truth) when both modes are simulated.
    """
    given = dict(options)
    given.update(frames=frames)
    if scenario is not None:
        given.update(scenario=os.fspath(scenario))
    if preset is not None:
        given.update(preset=preset)
    if mode is not None:
        given.update(mode=mode)
    if seed is not None:
        given.update(seed=seed)
    if noise_db != "scenario":
        given.update(noise_db="off" if noise_db is None else noise_db)
    settings = _checks.to_options("simulate", given, _pcuvd.option_names_of("simulate"))
    recordings, arrays = _pcuvd.simulate(settings, bool(quiet))
    cycle_keys = ("ri", "psv", "edv", "vessel_class", "flow_up", "class_share", "axis_profile")
    truth = Truth(
        x=arrays["x"],
        z=arrays["z"],
        vx=arrays["vx"],
        vz=arrays["vz"],
        mask=arrays["mask"],
        mean_vx=arrays["mean_vx"],
        mean_vz=arrays["mean_vz"],
        cycle={k: arrays[k] for k in cycle_keys if k in arrays},
        tissue={
            k.removeprefix("tissue_"): arrays[k]
            for k in ("tissue_vx", "tissue_vz", "tissue_displacement")
            if k in arrays
        },
        vy=arrays.get("vy"),
        blood_fraction=arrays.get("blood_fraction"),
        scenario=arrays["scenario"],
    )
    made = {name: Recording(native) for name, native in recordings}
    if len(made) > 1:
        return made, truth
    return next(iter(made.values())), truth
