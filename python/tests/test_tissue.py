"""Moving tissue around the simulated vessels, from Python: the same option as `pcuvd simulate
--tissue-db`, with its motion in the truth."""

from __future__ import annotations

import numpy as np
import pytest

import pcuvd


def _power(recording) -> float:
    return float(np.mean(np.asarray(recording.samples, dtype=np.float64) ** 2))


def test_tissue_brightens_the_echo_and_its_motion_is_in_the_truth():
    # The tube alone against the tube in tissue 40 dB brighter than blood per unit area: the
    # tissue fills ~13 times the tube's area, so the whole echo rises by ~51 dB.
    blood, _ = pcuvd.simulate("tube", "conventional", frames=1, noise_db=None, angles=1)
    both, truth = pcuvd.simulate(
        "tube", "conventional", frames=1, noise_db=None, angles=1, tissue_db=40
    )
    rise = 10 * np.log10(_power(both) / _power(blood))
    assert 45 < rise < 57, rise
    assert set(truth.tissue) == {"vx", "vz", "displacement"}
    assert truth.tissue["vz"].shape == truth.vz.shape
    assert truth.tissue["displacement"].shape == (1, truth.z.size, 3)
    # At t = 0 the rat's breathing (phase 0.5 rad) and heartbeat move the tissue: the axial
    # speed is 2π·(5.5 Hz·3 µm + 1 Hz·20 µm·cos 0.5·(1 + 10 %/mm below 1 mm)), tens of µm/s.
    assert np.all(truth.tissue["vz"] > 1e-4) and np.all(truth.tissue["vz"] < 1e-3)
    # The vessel moves with the tissue: its truth is the flow plus the tissue's velocity.
    inside = truth.mask
    _, still = pcuvd.simulate("tube", "conventional", frames=1, noise_db=None, angles=1)
    added = truth.vz[inside] - still.vz[inside]
    assert np.allclose(added, truth.tissue["vz"][inside])


def test_the_virtual_rat_brain_has_tissue_a_tree_crossing_the_plane_and_its_ri():
    # One angle, two frames of the small brain: the set-up (tree, flow, tissue, elevation truth)
    # of the full one, on a 3 mm slab of cortex.
    few = dict(frames=2, noise_db=None, angles=1)
    brain, truth = pcuvd.simulate("rat-brain-small", "conventional", **few)
    blood, _ = pcuvd.simulate("rat-brain-small", "conventional", tissue_db=-200, **few)
    # The tissue's echo, 40 dB per unit volume above the blood's over ~2,000 times its volume.
    assert 10 * np.log10(_power(brain) / _power(blood)) > 30
    inside = truth.mask
    assert inside.any()
    assert truth.vy is not None and truth.blood_fraction is not None
    assert np.all((truth.blood_fraction >= 0) & (truth.blood_fraction <= 1))
    assert np.all(truth.blood_fraction[~inside] == 0)
    # Penetrating vessels cross the plane: some pixels see mostly out-of-plane flow.
    in_plane = np.hypot(truth.vx, truth.vz)
    assert np.any(np.abs(truth.vy[inside]) > in_plane[inside] + 1e-3)
    # Arteries and veins carry their own RI: the paper's ranges (arterioles 0.55-0.9,
    # venules below 0.5), from the compliant tree, not imposed.
    cls, ri = truth.cycle["vessel_class"], truth.cycle["ri"]
    assert 0.55 < np.median(ri[cls == 1]) < 0.9
    assert np.median(ri[cls == 2]) < 0.5
    # The pial artery and vein run side by side in elevation: the pixels on them hold both, and
    # the class named holds only a share of their blood; elsewhere a vessel's class holds all.
    share = truth.cycle["class_share"]
    assert np.all((share[inside] > 0) & (share[inside] <= 1)) and np.all(share[~inside] == 0)
    assert np.any(share[inside] < 0.9) and np.median(share[inside]) == 1.0
    # Where in its vessel each pixel's blood lies: the mean of 1 - (r/R)^2, from the wall (0) to
    # the axis (1); the lumen's pixels span both.
    profile = truth.cycle["axis_profile"]
    assert np.all((profile[inside] >= 0) & (profile[inside] <= 1)) and np.all(profile[~inside] == 0)
    assert np.any(profile[inside] < 1 / 3) and np.any(profile[inside] > 1 / 3)
    # The displacement over the recording starts at 0, and one frame (1/14.4 kHz with one angle)
    # later it is the velocity map's times the frame period, to the motion's curvature over so
    # short a time.
    moved = truth.tissue["displacement"]
    assert moved.shape == (2, truth.z.size, 3)
    assert np.all(moved[0] == 0)
    column = truth.x.size // 2
    for axis, velocity in ((0, truth.tissue["vx"]), (2, truth.tissue["vz"])):
        np.testing.assert_allclose(moved[1, :, axis], velocity[:, column] / brain.frame_rate_hz, rtol=1e-2)


def _write_tables(folder, boundary: str) -> None:
    (folder / "vertices.csv").write_text("x_um,y_um,z_um\n0,0,1000\n0,0,2000\n")
    (folder / "edges.csv").write_text("v1,v2,diameter_um,length_um,class\n0,1,40,,arteriole\n")
    (folder / "boundary.csv").write_text(boundary)


def test_the_rat_brain_takes_its_vessels_from_three_tables(tmp_path):
    # One 40 µm arteriole straight down from 1 to 2 mm, 267 Pa mean drop: Poiseuille gives a
    # mean speed of ΔP d² / (32 μ L) = 3.8 mm/s (centreline 7.6 mm/s, pulsing with the inlet).
    _write_tables(tmp_path, "vertex,type,value,pulse\n0,pressure,1600,300\n1,pressure,1333,0\n")
    _, truth = pcuvd.simulate(
        "rat-brain-small", "conventional", frames=1, noise_db=None, angles=1,
        vessel_tables=str(tmp_path),
    )
    x, z = np.meshgrid(truth.x, truth.z)
    inside = truth.mask
    assert inside.any()
    assert np.all(np.abs(x[inside]) < 0.1e-3)
    assert np.all((z[inside] > 0.95e-3) & (z[inside] < 2.05e-3))
    # Flowing deeper (vz > 0), the beam-weighted mean of a laminar profile below its centreline.
    assert 1e-3 < truth.vz[inside].max() < 12e-3
    assert np.all(truth.cycle["vessel_class"][inside] == 1)


def test_bad_vessel_tables_name_the_file_and_what_is_wrong(tmp_path):
    _write_tables(tmp_path, "vertex,type,value,pulse\n0,pressure,1600,300\n7,pressure,1333,0\n")
    with pytest.raises(ValueError, match=r"\[vessels\].tables, vessel_tables\)"):
        pcuvd.simulate("rat-brain", "conventional", frames=1, angles=1, vessel_tables=str(tmp_path))
    # A missing file is an OSError, as Python's own open() raises it.
    with pytest.raises(OSError, match="vertices.csv"):
        pcuvd.simulate(
            "rat-brain", "conventional", frames=1, angles=1, vessel_tables=str(tmp_path / "none")
        )
    with pytest.raises(ValueError, match="rat-brain only"):
        pcuvd.simulate("tube", frames=1, vessel_tables=str(tmp_path))
