"""pcuvd's first steps in Python: read the measured rotating disk, process it, plot the colour
Doppler.

    python examples/quickstart.py [RECORDING] [--out FIGURE.png]

RECORDING defaults to the disk recording shipped beside the repository
(../shared/data/PWI_disk.mat).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # write a file; no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import pcuvd  # noqa: E402

DISK = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "PWI_disk.mat"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", nargs="?", default=DISK, type=Path)
    parser.add_argument("--out", default=Path("color_doppler.png"), type=Path)
    args = parser.parse_args()

    # The same chain and defaults as `pcuvd process`, the file read a block of frames at a time
    # (pcuvd.read_recording gives the samples and acquisition of a recording as arrays).
    result = pcuvd.process(args.recording)

    # Colour Doppler where the power Doppler stands 10 dB above its median (the disk).
    power_db = 10 * np.log10(result.power_doppler / np.median(result.power_doppler))
    velocity = np.where(power_db > 10, result.color_doppler, np.nan)
    vmax = result.summary["nyquist_velocity_m_s"] * 1e3
    size = f"{result.z.size} x {result.x.size} pixels (depth x lateral)"
    print(f"{args.recording.name}: {size}, Nyquist velocity {vmax:.1f} mm/s")
    extent_mm = [result.x[0] * 1e3, result.x[-1] * 1e3, result.z[-1] * 1e3, result.z[0] * 1e3]

    fig, (ax_b, ax_c) = plt.subplots(1, 2, figsize=(10, 4.5), sharey=True)
    ax_b.imshow(result.bmode_db, cmap="gray", vmin=-60, vmax=0, extent=extent_mm)
    ax_b.set(title="B-mode (dB)", xlabel="x (mm)", ylabel="depth z (mm)")
    ax_c.imshow(result.bmode_db, cmap="gray", vmin=-60, vmax=0, extent=extent_mm)
    # pcuvd's colour Doppler is > 0 moving away from the probe; red = toward, as on scanners.
    image = ax_c.imshow(-velocity * 1e3, cmap="RdBu_r", vmin=-vmax, vmax=vmax, extent=extent_mm)
    ax_c.set(title="Colour Doppler", xlabel="x (mm)")
    fig.colorbar(image, ax=ax_c, label="velocity toward the probe (mm/s): red = up")
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
