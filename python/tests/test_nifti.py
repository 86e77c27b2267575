"""`pcuvd process --nifti` and `--bids-*`: the maps and the time series as NIfTI images that
nibabel reads, with their voxels where the .npy maps put them, the affine in mm with depth
downwards, and fUSI-BIDS (BEP040) sidecars."""

import json

import nibabel as nib
import numpy as np
import pytest

import pcuvd
from conftest import run_cli


@pytest.fixture(scope="module")
def coded_tube(tmp_path_factory, cli):
    folder = tmp_path_factory.mktemp("nifti_tube")
    done = run_cli(
        cli, "simulate", "--preset", "tube", "--mode", "coded", "--frames", "8", "--angles", "4",
        "--out", folder,
    )
    assert done.returncode == 0, done.stderr
    return folder / "coded.toml"


GRID = "--grid=-2,2,6,10,0.08"


def test_maps_and_time_series_open_in_nibabel_where_the_npy_maps_are(coded_tube, cli, tmp_path):
    out = tmp_path / "out"
    done = run_cli(
        cli, "process", coded_tube, "--out", out, GRID, "--nifti", "--dynamics=off",
        "--ensemble-frames=4", "--ensemble-step=2", "--svd-block-mm=whole",
    )
    assert done.returncode == 0, done.stderr
    x, z = np.load(out / "x.npy"), np.load(out / "z.npy")
    for name in ["power_doppler", "signed_power_doppler", "color_doppler", "vx", "vz", "speed"]:
        image = nib.load(out / f"{name}.nii.gz")
        volume = image.get_fdata()
        expected = np.load(out / f"{name}.npy")
        assert volume.shape == (x.size, 1, z.size), name
        np.testing.assert_array_equal(volume[:, 0, :], expected.T.astype(np.float32), name)
        # Voxel (i, 0, k) lies at x[i] mm laterally and z[k] mm deep (world z = −depth).
        i, k = 7, 11
        world = image.affine @ np.array([i, 0, k, 1.0])
        np.testing.assert_allclose(world[[0, 2]], [x[i] * 1e3, -z[k] * 1e3], atol=1e-4)
        assert image.header.get_xyzt_units() == ("mm", "sec")
    sidecar = json.loads((out / "power_doppler.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    acquisition = summary["acquisition"]
    assert sidecar["ProbeCentralFrequency"] == pytest.approx(15.625)  # MHz, BEP040's unit
    assert sidecar["ProbeNumberOfElements"] == 128
    assert sidecar["PlaneWaveAngles"] == pytest.approx([-15, -5, 5, 15])
    assert sidecar["CompoundSamplingFrequency"] == pytest.approx(acquisition["frame_rate_hz"])
    # The whole recording's power Doppler integrates its 8 frames (ms).
    assert sidecar["PowerDopplerIntegrationDuration"] == pytest.approx(
        8 / acquisition["frame_rate_hz"] * 1e3
    )
    assert sidecar["ClutterFilters"][0]["FilterType"] == "Index-based SVD"
    # The time series: (x, 1, z, ensembles), one ensemble every 2 frames.
    series = nib.load(out / "ensemble_power_doppler.nii.gz")
    expected = np.load(out / "ensemble_power_doppler.npy")
    assert series.shape == (x.size, 1, z.size, expected.shape[0]) and expected.shape[0] == 3
    np.testing.assert_array_equal(
        np.transpose(series.get_fdata()[:, 0], (2, 1, 0)), expected.astype(np.float32)
    )
    step_s = 2 / acquisition["frame_rate_hz"]
    assert series.header.get_zooms()[3] == pytest.approx(step_s)
    timing = json.loads((out / "ensemble_power_doppler.json").read_text())
    assert timing["RepetitionTime"] == pytest.approx(step_s)
    assert timing["PowerDopplerIntegrationDuration"] == pytest.approx(step_s * 2 * 1e3)
    assert len(timing["ClutterCutoffsPerEnsemble"]) == 3
    assert sorted(summary["nifti"]) == sorted(p.name for p in out.glob("*.nii.gz"))
    # The whole image's filter (`--svd-block-mm whole`) has no blocks to record.
    assert "block_starts_px" not in summary["clutter_filter"]
    assert not (out / "clutter_block_cut_offs.npy").exists()
    assert not (out / "clutter_blocks.png").exists()


def test_a_block_wise_clutter_filter_is_recorded_as_such(coded_tube, cli, tmp_path):
    """`--svd-block-mm`: summary.json gives the blocks' size in pixels and each angle's range of
    block cut-offs; the sidecar names the filter block-wise and gives no single threshold."""
    out = tmp_path / "blocks"
    done = run_cli(
        cli, "process", coded_tube, "--out", out, GRID, "--nifti", "--dynamics=off",
        "--svd-block-mm", "1.2",
    )
    assert done.returncode == 0, done.stderr
    clutter = json.loads((out / "summary.json").read_text())["clutter_filter"]
    # 1.2 mm on the 0.08 mm grid: 15 pixels, made 16 so that half-block steps tile the grid.
    assert clutter["block_pixels"] == [16, 16]
    assert len(clutter["cut_offs_per_angle"]) == 4
    for cut in clutter["cut_offs_per_angle"]:
        low_range = cut["block_low_range"]
        assert low_range[0] <= cut["low"] <= low_range[1]
    filters = json.loads((out / "power_doppler.json").read_text())["ClutterFilters"]
    assert filters == [{"FilterType": "Index-based SVD, block-wise"}]
    # A block of one pixel grows, the shorter side first, until it holds the frames; its sides
    # are then made even: no smaller even block holds them.
    tiny = tmp_path / "tiny"
    done = run_cli(
        cli, "process", coded_tube, "--out", tiny, GRID, "--dynamics=off", "--svd-block-mm", "0.08",
    )
    assert done.returncode == 0, done.stderr
    summary = json.loads((tiny / "summary.json").read_text())
    rows, cols = summary["clutter_filter"]["block_pixels"]
    frames = summary["acquisition"]["frames"]
    assert rows % 2 == cols % 2 == 0 and cols <= rows <= cols + 2
    assert rows * cols >= frames > (rows - 2) * (cols - 2)
    # Processed in segments, each segment's cut-offs keep their blocks' ranges too.
    segmented = tmp_path / "segmented"
    done = run_cli(
        cli, "process", coded_tube, "--out", segmented, GRID, "--dynamics=off",
        "--svd-block-mm", "1.2", "--segment-frames", "4",
    )
    assert done.returncode == 0, done.stderr
    summary = json.loads((segmented / "summary.json").read_text())
    segments = summary["segments"]
    assert segments["count"] == 2
    for per_angle in segments["clutter_cut_offs_per_angle"]:
        assert len(per_angle) == 4
        assert all("block_low_range" in cut for cut in per_angle)
    # Every block's cut-offs, (segments, angles, block rows, block columns, low / high), the
    # blocks where summary.json says they start (16-pixel blocks at 8-pixel steps, the last
    # flush with the 51-pixel grid's edge), and their ranges those summary.json gives.
    blocks = np.load(segmented / "clutter_block_cut_offs.npy")
    starts = summary["clutter_filter"]["block_starts_px"]
    assert starts["z"] == starts["x"] == [0, 8, 16, 24, 32, 35]
    assert blocks.shape == (2, 4, 6, 6, 2)
    for segment, per_angle in zip(blocks, segments["clutter_cut_offs_per_angle"]):
        for block_cuts, cut in zip(segment, per_angle):
            assert [block_cuts[..., 0].min(), block_cuts[..., 0].max()] == cut["block_low_range"]
            assert [block_cuts[..., 1].min(), block_cuts[..., 1].max()] == cut["block_high_range"]
            assert int(np.median(block_cuts[..., 0])) == cut["low"]
    # The figure shows where blocks cut tissue components; here the whole image's `auto` cuts
    # none, so no block does, and there is nothing to show.
    assert blocks[..., 0].max() == 0
    assert not (segmented / "clutter_blocks.png").exists()
    # A fixed tissue cut (every block cuts one) is shown.
    fixed = tmp_path / "fixed"
    done = run_cli(
        cli, "process", coded_tube, "--out", fixed, GRID, "--dynamics=off",
        "--svd-block-mm", "1.2", "--svd-low", "1",
    )
    assert done.returncode == 0, done.stderr
    assert np.load(fixed / "clutter_block_cut_offs.npy")[..., 0].min() == 1
    assert (fixed / "clutter_blocks.png").is_file()
    # A time series: each ensemble's cut-offs keep their blocks' ranges, and its sidecar names
    # the filter block-wise, giving the blocks' medians per ensemble.
    series = tmp_path / "series"
    done = run_cli(
        cli, "process", coded_tube, "--out", series, GRID, "--nifti", "--dynamics=off",
        "--svd-block-mm", "1.2", "--ensemble-frames=4", "--ensemble-step=2",
    )
    assert done.returncode == 0, done.stderr
    ensembles = json.loads((series / "summary.json").read_text())["ensembles"]
    assert ensembles["count"] == 3 and len(ensembles["clutter_cut_offs_per_angle"]) == 3
    for per_angle in ensembles["clutter_cut_offs_per_angle"]:
        assert len(per_angle) == 4
        for cut in per_angle:
            assert cut["block_low_range"][0] <= cut["low"] <= cut["block_low_range"][1]
            assert cut["block_high_range"][0] <= cut["high"] <= cut["block_high_range"][1]
    timing = json.loads((series / "ensemble_power_doppler.json").read_text())
    assert timing["ClutterFilters"] == [{"FilterType": "Index-based SVD, block-wise, per ensemble"}]
    assert timing["ClutterCutoffsPerEnsemble"] == [
        [[cut["low"], cut["high"]] for cut in per_angle]
        for per_angle in ensembles["clutter_cut_offs_per_angle"]
    ]


def test_bids_names_and_refused_labels(coded_tube, cli, tmp_path):
    out = tmp_path / "bids"
    done = run_cli(
        cli, "process", coded_tube, "--out", out, GRID, "--dynamics=off",
        "--bids-subject", "01", "--bids-session", "baseline", "--bids-task", "rest",
    )
    assert done.returncode == 0, done.stderr
    stem = "sub-01_ses-baseline_task-rest"
    for name in [f"{stem}_pwd", f"{stem}_desc-signed_pwd", f"{stem}_desc-axial_vel"]:
        assert (out / f"{name}.nii.gz").is_file() and (out / f"{name}.json").is_file(), name
    power = nib.load(out / f"{stem}_pwd.nii.gz").get_fdata()[:, 0, :]
    np.testing.assert_array_equal(power, np.load(out / "power_doppler.npy").T.astype(np.float32))
    for bad, needle in [
        (["--bids-subject", "0_1"], "letters and digits"),
        (["--bids-task", "rest"], "need --bids-subject"),
    ]:
        refused = run_cli(cli, "process", coded_tube, "--out", tmp_path / "no", GRID, *bad)
        assert refused.returncode == 2 and needle in refused.stderr, refused.stderr
        assert not (tmp_path / "no").exists()


def test_python_saves_the_same_images(coded_tube, cli, tmp_path):
    result = pcuvd.process(coded_tube, grid_mm=(-2, 2, 6, 10, 0.08), dynamics="off", quiet=True)
    result.save(tmp_path / "py", bids_subject="01", bids_task="rest")
    done = run_cli(
        cli, "process", coded_tube, "--out", tmp_path / "cli", GRID, "--dynamics=off",
        "--bids-subject", "01", "--bids-task", "rest",
    )
    assert done.returncode == 0, done.stderr
    for image in sorted((tmp_path / "cli").glob("*.nii.gz")):
        np.testing.assert_array_equal(
            nib.load(tmp_path / "py" / image.name).get_fdata(), nib.load(image).get_fdata()
        )
    with pytest.raises(ValueError, match="letters and digits"):
        result.save(tmp_path / "bad", bids_subject="a-b")
