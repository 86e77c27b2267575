"""`pcuvd.simulate`: the simulator of `pcuvd simulate`, returning recordings and ground truth."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import _checks, _pcuvd
from ._recording import Recording


@dataclass(frozen=True)
class Truth:
    """Ground truth of a simulation on the default processing grid (SI units).

    x (nx), z (nz) in m; vx, vz (nz, nx) in m/s at t = 0 (vx > 0 toward +x, vz > 0 deeper);
    mask (nz, nx) True inside the moving medium. For the vessel network also `cycle`: ri, psv,
    edv (m/s), vessel_class (0 background, 1 arteriole, 2 venule, 3 undetermined), flow_up.
    With tissue (tissue_db=..., or the rat brain) also `tissue`: its velocity vx, vz (nz, nx) in
    m/s at t = 0. For the three-dimensional rat brain also vy (nz, nx), the out-of-plane velocity
    (m/s), and blood_fraction (nz, nx), the blood's share of each pixel's elevation beam; its
    velocities are the elevation-beam-weighted means over the blood each pixel sees.
    """

    x: np.ndarray
    z: np.ndarray
    vx: np.ndarray
    vz: np.ndarray
    mask: np.ndarray
    cycle: dict[str, np.ndarray] = field(default_factory=dict)
    tissue: dict[str, np.ndarray] = field(default_factory=dict)
    vy: np.ndarray | None = None
    blood_fraction: np.ndarray | None = None


def simulate_option_names() -> list[str]:
    """The keyword options `simulate` accepts."""
    return sorted(_pcuvd.option_names_of("simulate"))


def simulate(
    preset: str = "paper-spiral",
    mode: str = "coded",
    frames: int | None = None,
    noise_db: float | None = -10.0,
    seed: int = 1,
    *,
    quiet: bool = False,
    **options: Any,
) -> tuple[Recording | dict[str, Recording], Truth]:
    """Simulates RF recordings as `pcuvd simulate` does.

    preset: "paper-spiral", "tube", "rat-network" or "rat-brain" (see `pcuvd simulate --help`); mode:
    "coded" (Hadamard), "conventional" or "both"; frames: compound frames (default: the
    preset's); noise_db: noise level in dB (None: no noise); seed of scatterers and noise;
    options: the other `simulate` options (angles, slot_delay_us, peak_velocity_mm_s,
    tube_profile="plug" for the tube without a gradient across it, tube_angle_deg,
    tube_centre_mm=(x, z), tube_length_mm, tube_radius_mm; tissue_db=40 for moving tissue
    around the vessels, tissue_motion="rat" or "still"). Returns (recording, truth),
    or ({"conventional": ..., "coded": ...}, truth) for mode "both".
    """
    given = dict(options)
    given.update(
        preset=preset,
        mode=mode,
        frames=frames,
        noise_db="off" if noise_db is None else noise_db,
        seed=seed,
    )
    settings = _checks.to_options("simulate", given, _pcuvd.option_names_of("simulate"))
    recordings, arrays = _pcuvd.simulate(settings, bool(quiet))
    cycle_keys = ("ri", "psv", "edv", "vessel_class", "flow_up")
    truth = Truth(
        x=arrays["x"],
        z=arrays["z"],
        vx=arrays["vx"],
        vz=arrays["vz"],
        mask=arrays["mask"],
        cycle={k: arrays[k] for k in cycle_keys if k in arrays},
        tissue={k.removeprefix("tissue_"): arrays[k] for k in ("tissue_vx", "tissue_vz") if k in arrays},
        vy=arrays.get("vy"),
        blood_fraction=arrays.get("blood_fraction"),
    )
    made = {name: Recording(native) for name, native in recordings}
    if mode == "both":
        return made, truth
    return next(iter(made.values())), truth
