"""Stage functions: against analytic truth, independent numpy computations, and the Rust chain."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pcuvd
from conftest import assert_same_array, beamform_each_angle, images_manifest, run_cli


def test_chain_of_stages_equals_process_on_the_disk(disk):
    """rf_to_iq → beamform → svd_filter → power_doppler / kasai is exactly what process runs
    with the Kasai estimator (the default, Loupas, divides the same phase by each pixel's mean
    frequency instead of f_0)."""
    recording = pcuvd.read_recording(disk)
    # The stages are the paper's pixel-wise steps: process with its pixel-wise, uncorrected
    # estimate (the defaults average 5x1 and apply the partial-volume correction).
    result = pcuvd.process(
        recording, doppler_estimator="kasai", doppler_kernel=(1, 1), partial_volume="off",
        quiet=True,
    )
    summary = result.summary
    fc = recording.probe["center_freq_hz"]
    iq = pcuvd.rf_to_iq(
        recording.samples,
        sampling_freq_hz=recording.sampling_freq_hz,
        demod_freq_hz=fc,
        t0_s=recording.t0_s,
    )
    x, z = result.x, result.z
    series = pcuvd.beamform(
        iq,
        probe=recording.probe,
        angle_rad=0.0,
        sampling_freq_hz=recording.sampling_freq_hz,
        demod_freq_hz=fc,
        t0_s=recording.t0_s,
        x_m=x,
        z_m=z,
        sound_speed_m_s=recording.sound_speed_m_s,
    )
    assert series.shape == (len(z), len(x), recording.n_frames)
    # The default clutter filter works in blocks, of the size summary.json gives in pixels.
    blocks = summary["clutter_filter"]["block_pixels"]
    filtered, cut = pcuvd.svd_filter(series, blocks=blocks)
    assert cut["low"] == summary["clutter_filter"]["cut_offs_per_angle"][0]["low"]
    assert cut["block_starts"] == (
        summary["clutter_filter"]["block_starts_px"]["z"],
        summary["clutter_filter"]["block_starts_px"]["x"],
    )
    assert_same_array(pcuvd.power_doppler(filtered), result.power_doppler, "power")
    velocity = pcuvd.kasai(
        filtered,
        sound_speed_m_s=recording.sound_speed_m_s,
        frame_rate_hz=recording.frame_rate_hz,
        center_freq_hz=fc,
    )
    # One angle at 0°: the projection is the axial velocity, where the plane wave reaches.
    reached = np.isfinite(result.projections[0])
    assert reached.mean() > 0.9
    np.testing.assert_array_equal(velocity[reached], result.projections[0][reached])
    np.testing.assert_array_equal(velocity, result.color_doppler)


def test_vector_fits_equal_process_on_a_coded_tube(tmp_path):
    recording, truth = pcuvd.simulate("tube", "coded", frames=10, noise_db=None, quiet=True)
    # Pixel-wise and uncorrected, as the stages fit (the defaults average 5x1 and apply the
    # partial-volume correction, which no stage does).
    result = pcuvd.process(
        recording, grid_mm=(-3, 3, 4, 10, 0.08), dynamics="off", doppler_kernel=(1, 1),
        partial_volume="off", quiet=True,
    )
    vx, vz = pcuvd.vector_ls(result.projections, recording.angles_rad)
    assert_same_array(vx, result.vx_ls, "vx_ls")
    assert_same_array(vz, result.vz_ls, "vz_ls")
    vx, vz = pcuvd.vector_irls(result.projections, recording.angles_rad)
    assert_same_array(vx, result.vx, "vx")
    assert_same_array(vz, result.vz, "vz")
    assert truth.vx.shape == truth.mask.shape and truth.mask.any()


def test_a_plug_tube_moves_at_its_peak_speed_up_to_the_wall():
    _, truth = pcuvd.simulate(
        "tube", "conventional", frames=1, noise_db=None, angles=2, quiet=True,
        tube_profile="plug", peak_velocity_mm_s=90,
    )
    speed = np.hypot(truth.vx, truth.vz)[truth.mask]
    assert speed.size > 100
    np.testing.assert_allclose(speed, 0.09, rtol=1e-9)
    # Steady flow: its mean over the recording is its velocity at the start.
    np.testing.assert_allclose(truth.mean_vx, truth.vx, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(truth.mean_vz, truth.vz, rtol=1e-12, atol=1e-15)
    _, laminar = pcuvd.simulate(
        "tube", "conventional", frames=1, noise_db=None, angles=2, quiet=True,
        peak_velocity_mm_s=90,
    )
    assert np.hypot(laminar.vx, laminar.vz)[laminar.mask].min() < 0.02, "parabolic by default"


def test_a_pulsing_networks_mean_is_not_its_start():
    # 50 ms of the network, a quarter of its 5.5 Hz beat: the vessels' mean speed over it is not
    # their speed at its start, and lies within the range their speed takes.
    _, truth = pcuvd.simulate("rat-network", "conventional", frames=90, noise_db=None, angles=1,
                              quiet=True)
    inside = truth.mask
    start = np.hypot(truth.vx, truth.vz)[inside]
    mean = np.hypot(truth.mean_vx, truth.mean_vz)[inside]
    assert np.abs(mean - start).max() > 1e-3
    assert mean.max() <= truth.cycle["psv"][inside].max() * (1 + 1e-9)


def test_vector_fits_recover_an_exact_vector():
    angles = np.radians(np.linspace(-15, 15, 8))
    vx, vz = 0.012, -0.02
    # V_θ = (vx·sin θ + vz·(1 + cos θ))/2, the projection model, written independently here.
    v_theta = (vx * np.sin(angles) + vz * (1 + np.cos(angles))) / 2
    projections = np.broadcast_to(v_theta[:, None, None], (8, 3, 4)).copy()
    projections[0, 0, 0] = np.nan  # a missing angle is left out, not propagated
    for fit in (pcuvd.vector_ls, pcuvd.vector_irls):
        got_x, got_z = fit(projections, angles)
        np.testing.assert_allclose(got_x, vx, rtol=1e-9)
        np.testing.assert_allclose(got_z, vz, rtol=1e-9)


def test_irls_downweights_an_outlier_that_least_squares_follows():
    angles = np.radians(np.linspace(-15, 15, 8))
    v_theta = (0.01 * np.sin(angles) + 0.02 * (1 + np.cos(angles))) / 2
    v_theta[3] += 0.01  # one corrupted projection
    projections = v_theta[:, None, None].copy()
    ls = np.hypot(*(a[0, 0] for a in pcuvd.vector_ls(projections, angles)))
    irls = np.hypot(*(a[0, 0] for a in pcuvd.vector_irls(projections, angles)))
    truth = np.hypot(0.01, 0.02)
    assert abs(irls - truth) < 0.2 * abs(ls - truth)


def test_kasai_reads_a_doppler_tone():
    c, prf, fc, fd = 1540.0, 5000.0, 5e6, 400.0
    n = np.arange(64)
    tone = np.exp(2j * np.pi * fd * n / prf)
    series = np.broadcast_to(tone, (2, 3, 64)).astype(np.complex64)
    velocity = pcuvd.kasai(series, sound_speed_m_s=c, frame_rate_hz=prf, center_freq_hz=fc)
    # arg R(1) = 2π f_D / PRF, V = −c·f_D/(2 f_c): the echo phase advancing means approaching.
    np.testing.assert_allclose(velocity, -c * fd / (2 * fc), rtol=1e-5)
    power = pcuvd.power_doppler(3 * series)
    np.testing.assert_allclose(power, 9.0, rtol=1e-5)


def test_rf_to_iq_gives_the_analytic_baseband():
    fs, fc, t0, phase = 40e6, 5e6, 2e-6, 0.7
    t = t0 + np.arange(2000) / fs
    rf = np.cos(2 * np.pi * fc * t + phase)[None, None, :].repeat(2, axis=0)
    iq = pcuvd.rf_to_iq(rf, sampling_freq_hz=fs, demod_freq_hz=fc, t0_s=t0)
    assert iq.shape == (2, 1, 2000) and iq.dtype == np.complex64
    middle = iq[:, 0, 200:-200]
    # cos(ωt + φ)·e^{−iωt}, low-passed with gain 2, is e^{iφ}.
    np.testing.assert_allclose(middle, np.exp(1j * phase), atol=2e-3)


def test_svd_filter_removes_the_tissue_rank_as_numpy_does():
    rng = np.random.default_rng(1)
    nz, nx, frames = 12, 10, 20
    tissue = 50 * np.outer(rng.normal(size=nz * nx), np.exp(2j * np.pi * 0.001 * np.arange(frames)))
    blood = rng.normal(size=(nz * nx, frames)) + 1j * rng.normal(size=(nz * nx, frames))
    casorati = (tissue + blood).astype(np.complex64)
    series = casorati.reshape(nz, nx, frames)
    filtered, cut = pcuvd.svd_filter(series, low=1)
    assert cut["low"] == 1
    # Independent: remove the leading right singular vector with numpy's SVD.
    _, s, vh = np.linalg.svd(casorati.astype(np.complex128), full_matrices=False)
    v1 = vh[0].conj()[:, None]
    expected = casorati - (casorati @ v1) @ v1.conj().T
    np.testing.assert_allclose(filtered.reshape(-1, frames), expected, atol=1e-3 * np.abs(expected).max())
    np.testing.assert_allclose(cut["singular_values"][:3], s[:3], rtol=1e-4)


def test_block_wise_svd_filter_blends_numpy_block_projections():
    """Blocks of 8 × 6 pixels at half-block steps, each with its leading component removed,
    blended with tent weights: the same computed independently with numpy's SVD."""
    rng = np.random.default_rng(3)
    nz, nx, frames, rows, cols = 16, 12, 10, 8, 6
    t = np.arange(frames)
    # Tissue moving differently across the image, so the blocks' leading vectors differ.
    drift = 0.02 * (1 + np.arange(nx) / nx)[None, :, None]
    tissue = 40 * rng.normal(size=(nz, nx, 1)) * np.exp(2j * np.pi * drift * t)
    noise = rng.normal(size=(nz, nx, frames)) + 1j * rng.normal(size=(nz, nx, frames))
    series = (tissue + noise).astype(np.complex64)
    filtered, cut = pcuvd.svd_filter(series, low=1, blocks=(rows, cols))

    def starts(n, size):
        return sorted(set(range(0, n - size, size // 2)) | {n - size})

    def tent(size):
        return np.minimum(np.arange(size) + 1, size - np.arange(size))

    blended = np.zeros(series.shape, np.complex128)
    weights = np.zeros((nz, nx))
    for z0 in starts(nz, rows):
        for x0 in starts(nx, cols):
            block = series[z0 : z0 + rows, x0 : x0 + cols].reshape(-1, frames)
            block = block.astype(np.complex128)
            _, _, vh = np.linalg.svd(block, full_matrices=False)
            v1 = vh[0].conj()[:, None]
            kept = (block - (block @ v1) @ v1.conj().T).reshape(rows, cols, frames)
            w = np.outer(tent(rows), tent(cols))
            blended[z0 : z0 + rows, x0 : x0 + cols] += w[:, :, None] * kept
            weights[z0 : z0 + rows, x0 : x0 + cols] += w
    expected = blended / weights[:, :, None]
    np.testing.assert_allclose(filtered, expected, atol=1e-3 * np.abs(expected).max())
    assert cut["block_cut_offs"] == [(1, frames)] * (len(starts(nz, rows)) * len(starts(nx, cols)))
    assert cut["block_starts"] == (starts(nz, rows), starts(nx, cols))
    assert pcuvd.svd_filter(series, low=1)[1]["block_starts"] is None
    # Blocks smaller than the frames grow, the shorter side first, until they hold them (3 × 3
    # to 4 × 3), then an odd side gains a pixel, so that half-block steps tile the image.
    grown = pcuvd.svd_filter(series, low=1, blocks=(3, 3))[1]
    assert grown["block_starts"] == (starts(nz, 4), starts(nx, 4))


def test_decode_hadamard_inverts_a_numpy_encoding():
    """Encode per-angle RF with the Sylvester Hadamard matrix and whole-sample slot delays in
    numpy, then decode (events taken as simultaneous): n × the original records come back
    (decoding is Hᵀ·M, whose coherent sum over n events is coding's SNR gain)."""
    rng = np.random.default_rng(2)
    n, frames, channels, samples, fs = 4, 3, 5, 64, 20e6
    delay_samples = 2
    per_angle = rng.normal(size=(n, frames, channels, samples)).astype(np.float32)
    per_angle[..., -8:] = 0  # room for the delayed slots
    h = np.array([[1.0]])
    while h.shape[0] < n:
        h = np.block([[h, h], [h, -h]])
    events = np.zeros((frames * n, channels, samples), np.float32)
    for f in range(frames):
        for i in range(n):
            for k in range(n):
                shifted = np.roll(per_angle[k, f], k * delay_samples, axis=-1)
                events[f * n + i] += h[i, k] * shifted
    decoded = pcuvd.decode_hadamard(
        events, n, slot_delay_s=delay_samples / fs, sampling_freq_hz=fs, alignment="simultaneous"
    )
    assert decoded.shape == per_angle.shape
    np.testing.assert_allclose(
        decoded[..., : samples - 8], n * per_angle[..., : samples - 8], atol=1e-4
    )


def test_resistivity_index():
    psv = np.array([[0.02, 0.0], [np.nan, 0.01]])
    edv = np.array([[0.006, 0.0], [0.001, 0.01]])
    ri = pcuvd.resistivity_index(psv, edv)
    np.testing.assert_allclose(ri[0, 0], 0.7)
    assert np.isnan(ri[0, 1]) and np.isnan(ri[1, 0])
    assert ri[1, 1] == 0.0


def test_the_quickstart_example_runs_and_draws(disk, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parents[2] / "examples" / "quickstart.py"
    figure = tmp_path / "cd.png"
    done = subprocess.run(
        [sys.executable, str(example), str(disk), "--out", str(figure)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    assert figure.stat().st_size > 10_000
    assert "PWI_disk.mat" in done.stdout


def test_the_beamformed_iq_example_draws_ri_maps_close_to_the_truth(tmp_path):
    """examples/ri_from_beamformed_iq.py on its simulated one-angle network: it runs, draws, and
    its RI stays near the truth (measured 0.058 median |dRI| and 93 % classed right; the gate is
    for a break, not the method's accuracy, which docs/guide/outputs.md reports)."""
    import re
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parents[2] / "examples" / "ri_from_beamformed_iq.py"
    figure = tmp_path / "ri.png"
    done = subprocess.run(
        [sys.executable, str(example), "--out", str(figure)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    assert figure.stat().st_size > 10_000
    found = re.search(r"median \|dRI\| ([0-9.]+), ([0-9]+) % of the lumen classed right", done.stdout)
    assert found, done.stdout
    assert float(found.group(1)) < 0.1 and int(found.group(2)) >= 85, done.stdout


def test_process_on_beamformed_images_gives_the_python_stages_ri_maps(tmp_path, cli):
    """`pcuvd process` on an images manifest naming a NumPy-written .npy of beamformed IQ (time,
    z, x), the way a scanner's images reach it, gives the RI maps that the Python stages draw from
    the same images (svd_filter, then ri_maps: what examples/ri_from_beamformed_iq.py does), and
    they lie near the simulation's truth."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "examples" / "ri_from_beamformed_iq.py"
    spec = importlib.util.spec_from_file_location("ri_example", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    iq, parameters, truth = example.simulated_iq()
    manifest = images_manifest(
        tmp_path, iq.astype(np.complex64), ["frames", "z", "x"], parameters["x_m"],
        parameters["z_m"], frame_rate_hz=parameters["frame_rate_hz"],
        demod_frequency_hz=parameters["center_freq_hz"],
    )
    out = tmp_path / "out"
    done = run_cli(cli, "process", manifest, "--out", out, "--heart-rate", "5.5")
    assert done.returncode == 0, done.stderr
    series = np.ascontiguousarray(np.moveaxis(iq, 0, 2))
    filtered, _ = pcuvd.svd_filter(series, low="auto", blocks=(40, 40))
    maps = pcuvd.ri_maps(filtered, **parameters)
    classes = np.load(out / "vessel_class.npy")
    assert np.array_equal(classes, maps["vessel_class"])
    np.testing.assert_allclose(np.load(out / "ri.npy"), maps["ri"], rtol=1e-9, atol=1e-12)
    lumen = truth.cycle["vessel_class"] > 0
    error = np.abs(np.where(np.isnan(maps["ri"]), 1.0, maps["ri"]) - truth.cycle["ri"])
    assert np.median(error[lumen]) < 0.1, np.median(error[lumen])
    assert np.mean(classes[lumen] == truth.cycle["vessel_class"][lumen]) >= 0.85
    summary = json.loads((out / "summary.json").read_text())
    assert summary["images"]["frames"] == iq.shape[0] and "probe" not in summary
    # The Python package runs the same images path on the manifest's path.
    result = pcuvd.process(manifest, heart_rate_hz=5.5, quiet=True)
    assert_same_array(result.ri, np.load(out / "ri.npy"), "ri")
    assert_same_array(result.color_doppler, np.load(out / "color_doppler.npy"), "color_doppler")
    assert result.summary["images"]["frame_rate_hz"] == parameters["frame_rate_hz"]
    dataset = result.to_xarray()
    assert dataset["ri"].dims == ("z", "x") and dataset.sizes["angle"] == 1
    saved = result.save(tmp_path / "saved")
    assert (tmp_path / "saved" / "summary.json").is_file() and saved
    with pytest.raises(ValueError, match="channel data"):
        result.against_truth(truth)


def test_process_on_each_angles_images_gives_the_recordings_vectors(tmp_path, cli):
    """Images of several steering angles, beamformed with the Python stages as `process` forms
    them and saved with NumPy under an `angles` axis, give through an images manifest the
    vectors, colour and power Doppler that `process` gives on the channel recording, wherever
    every plane wave reaches (elsewhere a recording's run knows its coverage; images do not,
    unless the manifest gives the array's extent: then everywhere)."""
    recording, _ = pcuvd.simulate("tube", "conventional", frames=12, noise_db=None, angles=4,
                                  quiet=True)
    result = pcuvd.process(recording, dynamics="off", quiet=True)
    fc = recording.probe["center_freq_hz"]
    series = beamform_each_angle(recording, result.x, result.z)
    manifest = images_manifest(
        tmp_path, series, ["angles", "z", "x", "frames"], result.x, result.z,
        frame_rate_hz=recording.frame_rate_hz, demod_frequency_hz=fc,
        sound_speed_m_s=recording.sound_speed_m_s,
        angles_deg=[float(a) for a in np.degrees(recording.angles_rad)],
    )
    out = tmp_path / "out"
    done = run_cli(cli, "process", manifest, "--out", out, "--dynamics", "off")
    assert done.returncode == 0, done.stderr
    reached = np.isfinite(result.projections).all(axis=0)
    assert reached.mean() > 0.5
    for name in ("power_doppler", "color_doppler", "projections"):
        assert_same_array(np.load(out / f"{name}.npy")[..., reached],
                          getattr(result, name)[..., reached], name)
    # The partial-volume correction of the vector fits reads a neighbourhood (about 13 pixels here)
    # in which a recording's run leaves out the pixels a plane wave misses: the same 16 pixels
    # or more inside every plane wave's reach.
    inside = reached.copy()
    for _ in range(16):
        inside[1:] &= inside[:-1].copy()
        inside[:-1] &= inside[1:].copy()
        inside[:, 1:] &= inside[:, :-1].copy()
        inside[:, :-1] &= inside[:, 1:].copy()
    assert inside.mean() > 0.3
    for name in ("vx", "vz", "vx_ls", "vz_ls"):
        assert_same_array(np.load(out / f"{name}.npy")[inside], getattr(result, name)[inside],
                          name)
    # Given the array's extent (`aperture_m`), the manifest's images know each plane wave's
    # lateral reach as the recording's run does: every map is the recording's at every pixel
    # above the depth where a steep angle's record ends (which images do not say), less the
    # correction's neighbourhood.
    half = (recording.probe["n_elements"] - 1) / 2 * recording.probe["pitch_m"]
    with_reach = tmp_path / "with_reach"
    with_reach.mkdir()
    manifest = images_manifest(
        with_reach, series, ["angles", "z", "x", "frames"], result.x, result.z,
        frame_rate_hz=recording.frame_rate_hz, demod_frequency_hz=fc,
        sound_speed_m_s=recording.sound_speed_m_s,
        angles_deg=[float(a) for a in np.degrees(recording.angles_rad)],
        aperture_m=[-half, half],
    )
    out = with_reach / "out"
    done = run_cli(cli, "process", manifest, "--out", out, "--dynamics", "off")
    assert done.returncode == 0, done.stderr
    record_ended = np.isnan(result.projections) & np.isfinite(np.load(out / "projections.npy"))
    first = int(np.argmax(record_ended.any(axis=(0, 2)))) if record_ended.any() else len(result.z)
    rows = slice(0, first - 16)
    assert first - 16 > 0.8 * len(result.z), first
    assert not reached[rows].all(), "steered waves miss pixels at the edges of these rows"
    for name in ("power_doppler", "color_doppler", "projections", "vx", "vz", "vx_ls", "vz_ls"):
        assert_same_array(np.load(out / f"{name}.npy")[..., rows, :],
                          getattr(result, name)[..., rows, :], name)


def test_a_simulation_in_memory_is_scored_against_its_truth(tmp_path):
    recording, truth = pcuvd.simulate(
        "tube", "conventional", frames=8, noise_db=None, angles=2, quiet=True
    )
    result = pcuvd.process(recording, dynamics="off", quiet=True)
    scores = result.against_truth(truth)
    inside = truth.mask
    assert scores["vessel_pixels"] == inside.sum() > 100

    def rmse(estimate, true):
        error = np.where(np.isfinite(estimate), estimate - true, true)[inside]
        return np.sqrt(np.mean(error**2)) * 1e3

    for estimator, suffix in (("irls", ""), ("ls", "_ls")):
        vx, vz = getattr(result, "vx" + suffix), getattr(result, "vz" + suffix)
        got = scores["vector_rmse_mm_s"][estimator]
        np.testing.assert_allclose(got["vx"], rmse(vx, truth.mean_vx), rtol=1e-9)
        np.testing.assert_allclose(got["vz"], rmse(vz, truth.mean_vz), rtol=1e-9)
    np.testing.assert_allclose(
        scores["color_doppler_rmse_mm_s"], rmse(result.color_doppler, truth.mean_vz), rtol=1e-9
    )
    assert scores["ri"] == "the scenario's flow is steady: no cardiac cycle"
    # The recording carries its scenario: the summary and the saved folder are scored as a
    # folder `pcuvd simulate` wrote is, the truth's figure included.
    in_summary = result.summary["against_truth"]
    assert in_summary.pop("scenario") == "the scenario it was simulated with"
    assert in_summary == {k: v for k, v in scores.items() if k != "scenario"}
    folder = tmp_path / "saved"
    figures = result.save(folder)
    assert folder / "against_truth.png" in figures
    assert (folder / "against_truth.png").stat().st_size > 10_000
    saved = json.loads((folder / "summary.json").read_text())
    assert saved["against_truth"]["vessel_pixels"] == scores["vessel_pixels"]
    # The figures carry a short name; the simulator's record is kept whole beside it.
    assert saved["source"]["input"] == "pcuvd.simulate (conventional)"
    simulation = saved["source"]["simulation"]
    assert simulation["simulator"] == "pcuvd simulate" and simulation["noise_db"] == "off"
    assert simulation["scenario"]["sequence"]["frames"] == 8
    # The truth of another simulation (nine frames) does not describe these eight.
    _, other = pcuvd.simulate("tube", "conventional", frames=9, noise_db=None, angles=2, quiet=True)
    assert "describes other recordings" in result.against_truth(other)["not_scored"]
    with pytest.raises(TypeError, match="the truth pcuvd.simulate returned"):
        result.against_truth(42)


def _pulsatile_series(seed: int = 3) -> tuple[np.ndarray, dict]:
    """A one-angle filtered series (nz, nx, frames) at 1.8 kHz of 2.5 beats at 6 Hz: an arteriole
    flowing up (PSV 20, EDV 6 mm/s: RI 0.7) in rows 3–7, a venule flowing down (15 and 10.5
    mm/s: RI 0.3) in rows 11–15, and echoes that do not move (a vessel across the beam projects
    nothing) in rows 19–23, each a unit Doppler phasor over 8 columns, in complex noise 40 dB
    below. Returns the series and the blocks' (rows, columns) slices."""
    frame_rate, hr, fc, c = 1800.0, 6.0, 15.625e6, 1540.0
    frames = int(2.5 * frame_rate / hr)
    t = (np.arange(frames) + 0.5) / frame_rate
    rng = np.random.default_rng(seed)
    series = (rng.standard_normal((26, 24, frames)) + 1j * rng.standard_normal((26, 24, frames)))
    series *= np.sqrt(1e-4 / 2)

    def pulse(psv, edv):
        return edv + (psv - edv) * 0.5 * (1 - np.cos(2 * np.pi * hr * t))

    blocks = {
        "artery": (slice(3, 8), slice(4, 12)),
        "vein": (slice(11, 16), slice(12, 20)),
        "across": (slice(19, 24), slice(4, 12)),
    }
    for name, vz in (
        ("artery", -pulse(0.020, 0.006)),
        ("vein", pulse(0.015, 0.0105)),
        ("across", np.zeros(frames)),
    ):
        # Kasai's sign: a velocity away from the probe turns the phase back, 4π f_c vz / (c f_frame)
        # a frame.
        phase = np.cumsum(-4 * np.pi * fc * vz / (c * frame_rate))
        series[blocks[name]] += np.exp(1j * phase)
    return series.astype(np.complex64), blocks


def test_ri_maps_of_a_one_angle_series_formed_elsewhere():
    """ri_maps runs the dynamics stage on a series the user formed (a scanner's beamformed IQ):
    one angle reads RI from the colour-Doppler speed, which keeps each vessel's RI (a ratio), and
    leaves the echoes that project no motion undetermined rather than giving them noise's RI."""
    series, blocks = _pulsatile_series()
    grid = {"x_m": np.arange(24) * 1e-4 - 1.2e-3, "z_m": 5e-3 + np.arange(26) * 1e-4}
    maps = pcuvd.ri_maps(
        series, frame_rate_hz=1800.0, center_freq_hz=15.625e6, doppler_estimator="kasai",
        **grid,
    )
    assert maps["axial_only"] is True
    assert abs(maps["heart_rate_hz"] - 6.0) < 0.18, maps["heart_rate_hz"]
    assert maps["ri"].shape == (26, 24) and maps["speed_series"].shape[1:] == (26, 24)
    for name, ri, kind, up in (("artery", 0.7, 1, 1), ("vein", 0.3, 2, 0)):
        block = blocks[name]
        assert abs(np.median(maps["ri"][block]) - ri) < 0.05, (name, maps["ri"][block])
        assert np.mean(maps["vessel_class"][block] == kind) >= 0.95, (name, maps["vessel_class"][block])
        assert np.all(maps["flow_up"][block] == up), name
    across = blocks["across"]
    assert np.mean(maps["vessel_class"][across] == 3) >= 0.9, maps["vessel_class"][across]
    assert np.mean(np.isnan(maps["ri"][across])) >= 0.9
    # A given heart rate and the same series as a list of one angle: the same maps.
    given = pcuvd.ri_maps(
        [series], angles_rad=[0.0], frame_rate_hz=1800.0, center_freq_hz=15.625e6,
        doppler_estimator="kasai", heart_rate_hz=6.0, **grid,
    )
    assert given["cycles_from"].startswith("heart rate given"), given["cycles_from"]
    assert np.array_equal(given["vessel_class"] > 0, maps["vessel_class"] > 0)
    with pytest.raises(ValueError, match="2 angles"):
        pcuvd.ri_maps([series], angles_rad=[0.0, 0.1], frame_rate_hz=1800.0,
                      center_freq_hz=15.625e6, **grid)
    with pytest.raises(ValueError, match="grid of"):
        pcuvd.ri_maps(series, frame_rate_hz=1800.0, center_freq_hz=15.625e6,
                      doppler_estimator="kasai", grid_m=(-1e-3, 1e-3, 5e-3, 6e-3, 1e-4))
    with pytest.raises(TypeError, match="unexpected keyword 'svd_low'"):
        pcuvd.ri_maps(series, frame_rate_hz=1800.0, center_freq_hz=15.625e6, svd_low=3, **grid)
