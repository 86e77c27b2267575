"""RI maps from beamformed IQ, as a functional-ultrasound scanner saves it: clutter filter,
power Doppler, resistivity index and arteriole / venule classes with pcuvd's stages.

    python examples/ri_from_beamformed_iq.py IQ.npy --frame-rate-hz F --center-freq-hz F0
        --grid-mm X_MIN,X_MAX,Z_MIN,Z_MAX,STEP [--heart-rate-hz H] [--out FIGURE.png]
    python examples/ri_from_beamformed_iq.py [--out FIGURE.png]

IQ.npy holds complex compound images (time, z, x) on the grid given (pixel centres, mm). The
same maps, with pcuvd's figures, report and summary.json, come from `pcuvd process` on an images
manifest that names the file (crates/pcuvd-io/examples/images.toml, docs/guide/inputs.md). Without
a file, a recording is simulated first (the vessel network, one plane wave at a 1.8 kHz frame
rate, 400 frames) and beamformed, to stand for the scanner's, and its RI is scored against the
simulation's truth.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # write a file; no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import pcuvd  # noqa: E402

# The vessel network imaged with one plane wave at 1.8 kHz: 400 frames, 2.2 beats at 5.5 Hz.
DEMO_SCENARIO = """
description = "the vessel network, one plane wave at 1.8 kHz"
seed = 1
[probe]
preset = "L22-14vX"
[sequence]
transmit = "conventional"
angles = 1
max_angle_deg = 0.0
event_prf_hz = 1800.0
slot_delay_s = 0.000001
pulse_cycles = 2.0
frames = 400
[medium]
sound_speed_m_s = 1540.0
attenuation_db_cm_mhz = 0.5
frequency_dependent_attenuation = true
[receive]
sampling_frequency_hz = 65000000.0
depth_m = [0.0, 0.013]
[noise]
level_db = -10.0
[vessels]
kind = "rat-network"
"""


def simulated_iq() -> tuple[np.ndarray, dict, pcuvd.Truth]:
    """Beamformed IQ (time, z, x) of the demo scenario, its parameters, and its truth."""
    with tempfile.TemporaryDirectory() as folder:
        scenario = Path(folder) / "one_angle.toml"
        scenario.write_text(DEMO_SCENARIO)
        recording, truth = pcuvd.simulate(scenario=scenario, mode="conventional", quiet=True)
    fc = recording.probe["center_freq_hz"]
    iq = pcuvd.rf_to_iq(recording.samples, sampling_freq_hz=recording.sampling_freq_hz,
                        demod_freq_hz=fc, t0_s=recording.t0_s)
    images = pcuvd.beamform(iq, probe=recording.probe, angle_rad=0.0,
                            sampling_freq_hz=recording.sampling_freq_hz, demod_freq_hz=fc,
                            t0_s=recording.t0_s, x_m=truth.x, z_m=truth.z,
                            sound_speed_m_s=recording.sound_speed_m_s)
    parameters = {"frame_rate_hz": recording.frame_rate_hz, "center_freq_hz": fc,
                  "x_m": truth.x, "z_m": truth.z, "heart_rate_hz": 5.5}
    return np.moveaxis(images, 2, 0), parameters, truth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("iq", nargs="?", type=Path, help="complex images (time, z, x), .npy")
    parser.add_argument("--frame-rate-hz", type=float)
    parser.add_argument("--center-freq-hz", type=float)
    parser.add_argument("--grid-mm", help="X_MIN,X_MAX,Z_MIN,Z_MAX,STEP: the pixel centres")
    parser.add_argument("--heart-rate-hz", type=float, help="default: measured from the data")
    parser.add_argument("--out", default=Path("ri_maps.png"), type=Path)
    args = parser.parse_args()

    truth = None
    if args.iq is None:
        iq, parameters, truth = simulated_iq()
    else:
        if None in (args.frame_rate_hz, args.center_freq_hz, args.grid_mm):
            parser.error("an IQ file needs --frame-rate-hz, --center-freq-hz and --grid-mm")
        iq = np.load(args.iq)
        grid = [float(v) * 1e-3 for v in args.grid_mm.split(",")]
        parameters = {"frame_rate_hz": args.frame_rate_hz, "center_freq_hz": args.center_freq_hz,
                      "grid_m": grid, "heart_rate_hz": args.heart_rate_hz}

    # pcuvd's image series are (z, x, time); the tissue's components out, 2 mm blocks at a time
    # at 50 µm pixels (40 x 40), as `pcuvd process` filters by default.
    series = np.ascontiguousarray(np.moveaxis(iq, 0, 2))
    filtered, cut = pcuvd.svd_filter(series, low="auto", blocks=(40, 40))
    power_db = 10 * np.log10(pcuvd.power_doppler(filtered) + 1e-30)
    maps = pcuvd.ri_maps(filtered, **parameters)
    classes = maps["vessel_class"]
    counts = {name: int((classes == code).sum())
              for name, code in (("arteriole", 1), ("venule", 2), ("undetermined", 3))}
    print(f"heart rate {maps['heart_rate_hz']:.2f} Hz ({maps['cycles_from']}); pixels: {counts}")
    if truth is not None:
        lumen = truth.cycle["vessel_class"] > 0
        error = np.abs(np.where(np.isnan(maps["ri"]), 1.0, maps["ri"]) - truth.cycle["ri"])
        right = classes == truth.cycle["vessel_class"]
        print(f"against the truth: median |dRI| {np.median(error[lumen]):.3f}, "
              f"{100 * right[lumen].mean():.0f} % of the lumen classed right")

    x, z = maps_extent(parameters, series.shape)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.8), sharey=True)
    top = np.nanmax(power_db)
    shown = axes[0].imshow(power_db, cmap="hot", vmin=top - 40, vmax=top, extent=[*x, *z])
    fig.colorbar(shown, ax=axes[0], label="power Doppler (dB)")
    axes[1].set_facecolor("black")  # no RI: background, or a vessel across the beam
    shown = axes[1].imshow(maps["ri"], cmap="viridis", vmin=0, vmax=1, extent=[*x, *z])
    fig.colorbar(shown, ax=axes[1], label="RI = (PSV - EDV) / PSV")
    colours = matplotlib.colors.ListedColormap(["black", "tab:red", "tab:blue", "0.6"])
    shown = axes[2].imshow(classes, cmap=colours, vmin=-0.5, vmax=3.5, extent=[*x, *z],
                           interpolation="nearest")
    bar = fig.colorbar(shown, ax=axes[2], ticks=[0, 1, 2, 3])
    bar.ax.set_yticklabels(["background", "arteriole", "venule", "undetermined"])
    for axis, title in zip(axes, ("Power Doppler", "Resistivity index (colour-Doppler speed)",
                                  "Vessel class")):
        axis.set(title=title, xlabel="x (mm)")
    axes[0].set_ylabel("depth z (mm)")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


def maps_extent(parameters: dict, shape: tuple) -> tuple[list, list]:
    """The images' x and z extents (mm) for imshow: [left, right], [bottom, top]."""
    if "x_m" in parameters:
        x, z = parameters["x_m"], parameters["z_m"]
    else:
        x_min, x_max, z_min, z_max, _ = parameters["grid_m"]
        x, z = np.linspace(x_min, x_max, shape[1]), np.linspace(z_min, z_max, shape[0])
    return [x[0] * 1e3, x[-1] * 1e3], [z[-1] * 1e3, z[0] * 1e3]


if __name__ == "__main__":
    main()
