//! A reduced `pcuvd paper` run (few frames, coarse grid) checks the orderings that must always
//! hold and that every output is there.

use std::process::Command;

use ndarray::Array2;
use ndarray_npy::read_npy;

fn get<'a>(m: &'a serde_json::Value, path: &[&str]) -> &'a serde_json::Value {
    path.iter().fold(m, |v, k| &v[*k])
}

#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn reduced_paper_study_orders_the_methods() {
    let out = tempfile::tempdir().unwrap();
    // An earlier full run's network figure is removed (the report would leave it out); a file
    // pcuvd did not name stays.
    std::fs::write(out.path().join("fig7_network_rois.png"), b"old").unwrap();
    std::fs::write(out.path().join("notes.png"), b"mine").unwrap();
    // High noise, where coding and robust estimation must matter.
    let status = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .args([
            "paper",
            "--part",
            "spiral",
            "--frames",
            "12",
            "--grid-step",
            "0.1",
            // Kasai, with which the bounds below were measured: the 0.1 mm grid is too coarse
            // for Loupas, the default (its axial lag needs a step of at most 99 µm at 15.6 MHz).
            "--doppler-estimator",
            "kasai",
            // The paper's pixel-wise estimate at F# 1.5, where the bounds below were measured:
            // the default 5x1 kernel averages 0.5 mm of this coarse grid, which takes most of the
            // noise out of conventional UVD too, so coding's margin here is not the paper's.
            "--f-number",
            "1.5",
            "--partial-volume",
            "off",
            "--doppler-kernel",
            "1x1",
            "--noise-db=5",
            "--sweep=-20,5,15",
            "--seed",
            "4",
            // A baseline this reduced set-up reaches (its UVD reads Vx 10.6 mm/s without noise
            // pixel-wise, 6.5–6.9 averaged, 42 at +5 dB): the paper's 5.70 lies below its floor.
            "--calibrate-uvd-vx",
            "15",
            "--out",
        ])
        .arg(out.path())
        .status()
        .unwrap();
    assert!(status.success());
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("metrics.json")).unwrap())
            .unwrap();
    for key in [
        "snr_gain_db",
        "snr_gain_db_by_depth",
        "snr_gain_theory_db",
        "rmse_mm_s",
        "improvement_pct",
        "noise_db",
        "frames",
        "seed",
        "timing_s",
        "noise_sweep",
        "noise_definition",
        "snr_definition",
        "calibrated",
        "averaging",
    ] {
        assert!(!m[key].is_null(), "metrics.json lacks {key}");
    }
    for est in ["uvd_ls", "uvd_irls", "pcuvd_ls", "pcuvd_irls"] {
        for c in ["vx", "vz"] {
            assert!(
                get(&m, &["rmse_mm_s", est, c])
                    .as_f64()
                    .unwrap()
                    .is_finite(),
                "{est}.{c}"
            );
        }
    }
    let theory = get(&m, &["snr_gain_theory_db"]).as_f64().unwrap();
    assert!((theory - 10.0 * 8f64.log10()).abs() < 1e-9);
    let gain = get(&m, &["snr_gain_db"]).as_f64().unwrap();
    assert!(
        (gain - theory).abs() < 1.0,
        "SNR gain {gain} dB, theory {theory}"
    );
    let r = |est: &str, c: &str| get(&m, &["rmse_mm_s", est, c]).as_f64().unwrap();
    for c in ["vx", "vz"] {
        assert!(
            r("pcuvd_ls", c) < r("uvd_ls", c),
            "{c}: coded LS {} vs conventional LS {}",
            r("pcuvd_ls", c),
            r("uvd_ls", c)
        );
        assert!(
            r("pcuvd_irls", c) < r("uvd_irls", c),
            "{c}: coded IRLS vs conventional IRLS"
        );
        assert!(
            r("uvd_irls", c) <= r("uvd_ls", c) * 1.02,
            "{c}: IRLS worse than LS at high noise"
        );
    }
    // Each method's own bound at this set-up (12 frames, +5 dB, 0.1 mm grid, seed 4, Kasai):
    // measured UVD 42.1 / 4.56 mm/s, PC-UVD 13.2 / 2.57 mm/s (Vx / Vz); neither may regress by
    // more than about a third of the figures first measured here (46.7 / 4.6 and 14.5 / 2.2,
    // before the simulator's frequency-dependent attenuation).
    for (est, vx_max, vz_max) in [("uvd_ls", 62.0, 6.1), ("pcuvd_irls", 19.4, 2.9)] {
        assert!(
            r(est, "vx") <= vx_max && r(est, "vz") <= vz_max,
            "{est}: RMSE {} / {} mm/s above {vx_max} / {vz_max}",
            r(est, "vx"),
            r(est, "vz")
        );
    }
    // Coding against the baseline: the paper's own claim, PC-UVD at least 30 % better than UVD in
    // each component (its 43.5 % / 30.3 %, Vx / Vz). This test once asked for "at least half",
    // reasoning that coding's 9 dB cuts a noise-limited phase error by √8 ≈ 2.8. That holds only
    // where both errors are noise-limited, and PC-UVD's Vz is not here: with frequency-dependent
    // attenuation the echo's mean frequency falls with depth (about 1 % per mm), and Kasai, which
    // divides the Doppler phase by the nominal f_0, reads the deeper flow low whatever the noise.
    // That raised the noise-free Vz floor of this set-up from 1.97 to 2.48 mm/s (−20 dB, both
    // modes; measured by switching the attenuation's frequency dependence off), above half of
    // UVD's 4.56. The old bound was an artefact of a simulator whose echoes kept f_0.
    for c in ["vx", "vz"] {
        assert!(
            r("pcuvd_irls", c) <= 0.7 * r("uvd_ls", c),
            "{c}: PC-UVD {} vs UVD {}: the paper's 30 % improvement",
            r("pcuvd_irls", c),
            r("uvd_ls", c)
        );
    }
    // And where that floor is, coding's 9 dB must bring PC-UVD's Vz to it: within 15 % of its
    // own error without noise (the sweep's −20 dB), while UVD's stays far above its floor.
    let swept = |db: f64, est: &str, c: &str| {
        m["noise_sweep"]
            .as_array()
            .unwrap()
            .iter()
            .find(|row| (row["noise_db"].as_f64().unwrap() - db).abs() < 1e-9)
            .map(|row| row[est][c].as_f64().unwrap())
            .unwrap()
    };
    let floor = swept(-20.0, "pcuvd_irls", "vz");
    assert!(
        r("pcuvd_irls", "vz") <= 1.15 * floor,
        "PC-UVD Vz {} at +5 dB against {floor} without noise",
        r("pcuvd_irls", "vz")
    );
    assert!(
        r("uvd_ls", "vz") >= 1.5 * swept(-20.0, "uvd_ls", "vz"),
        "UVD's Vz at +5 dB is not noise-limited"
    );
    assert!(
        !m["rmse_definition"].is_null(),
        "metrics.json lacks the RMSE definition"
    );
    // Spatial averaging (the defaults: 1x1, 3x1, 5x1, 7x1, 3x3): pixel-wise costs no resolution,
    // a taller kernel costs more, and averaging lowers the error floor without noise.
    let averaging = m["averaging"].as_array().unwrap();
    let kernel = |row: &serde_json::Value| {
        let k = row["kernel"].as_array().unwrap();
        (k[0].as_u64().unwrap(), k[1].as_u64().unwrap())
    };
    let kernels: Vec<_> = averaging.iter().map(kernel).collect();
    assert_eq!(kernels, [(1, 1), (3, 1), (5, 1), (7, 1), (3, 3)]);
    let blur: Vec<f64> = averaging
        .iter()
        .map(|row| get(row, &["blur_rmse_mm_s", "vx"]).as_f64().unwrap())
        .collect();
    assert!(
        blur[0] == 0.0 && blur[1] < blur[2] && blur[2] < blur[3],
        "{blur:?}"
    );
    let floor_vx = |row: &serde_json::Value| {
        get(row, &["floor_mm_s", "pcuvd_irls", "vx"])
            .as_f64()
            .unwrap()
    };
    assert!(
        floor_vx(&averaging[1]) < floor_vx(&averaging[0]),
        "3x1 floor {} against pixel-wise {}",
        floor_vx(&averaging[1]),
        floor_vx(&averaging[0])
    );
    // The main level and each kernel's are calibrated to UVD's 15 mm/s where its floor lies
    // below that. There UVD's error is half noise (its floor is 10.6), and coding's 9 dB keep
    // PC-UVD within a tenth of its own floor (the sweep's −20 dB).
    let level = get(&m, &["calibrated", "rmse_mm_s"]);
    let (uvd, pcuvd) = (
        get(level, &["uvd_ls", "vx"]).as_f64().unwrap(),
        get(level, &["pcuvd_irls", "vx"]).as_f64().unwrap(),
    );
    assert!((uvd - 15.0).abs() < 0.1, "{level}");
    assert!(
        pcuvd <= 1.1 * swept(-20.0, "pcuvd_irls", "vx"),
        "PC-UVD Vx {pcuvd} at the calibrated level against {} without noise",
        swept(-20.0, "pcuvd_irls", "vx")
    );
    for row in averaging {
        let floor = get(row, &["floor_mm_s", "uvd_ls", "vx"]).as_f64().unwrap();
        let calibrated = &row["calibrated"];
        if floor > 15.0 {
            assert!(
                calibrated["noise_db"].is_null()
                    && calibrated["note"].as_str().unwrap().contains("floor"),
                "{row}"
            );
        } else {
            let level = get(calibrated, &["rmse_mm_s", "uvd_ls", "vx"]);
            assert!((level.as_f64().unwrap() - 15.0).abs() < 0.1, "{row}");
        }
    }
    for name in [
        "report.html",
        "fig2_power_doppler_snr.png",
        "fig3_vector_maps.png",
        "fig4_profiles.png",
        "fig5_accuracy.png",
        "fig5b_accuracy_at_baseline.png",
        "fig_noise_sweep.png",
    ] {
        assert!(out.path().join(name).exists(), "{name} missing");
    }
    assert!(!out.path().join("fig7_network_rois.png").exists());
    assert!(out.path().join("notes.png").exists());
    let html = std::fs::read_to_string(out.path().join("report.html")).unwrap();
    assert!(html.contains("data:image/png;base64,") && html.contains("3.22"));
    assert!(
        html.contains("at the paper&#39;s own baseline"),
        "no baseline figure"
    );

    // Without a calibrated level there is no baseline figure, and the earlier run's goes.
    let status = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .args([
            "--quiet",
            "paper",
            "--part",
            "spiral",
            "--frames",
            "6",
            "--grid-step",
            "0.1",
            "--doppler-estimator",
            "kasai",
            "--sweep=-10",
            "--averaging-kernels",
            "off",
            "--calibrate-uvd-vx",
            "off",
            "--out",
        ])
        .arg(out.path())
        .status()
        .unwrap();
    assert!(status.success());
    assert!(out.path().join("fig5_accuracy.png").exists());
    assert!(!out.path().join("fig5b_accuracy_at_baseline.png").exists());
}

#[test]
fn paper_rejects_bad_arguments() {
    for args in [
        vec!["--frames", "1"],
        vec!["--sweep", "a,b"],
        vec!["--averaging-kernels", "3x3,2x2"],
        vec!["--grid-step", "0"],
        vec!["--part", "network", "--network-frames", "100"],
        vec!["--part", "network", "--heart-rate", "0"],
        vec!["--part", "network", "--heart-rate", "400"],
        vec!["--part", "network", "--network-noise-db", "inf"],
        // A grid too coarse for Loupas, the default estimator, in every study.
        vec!["--grid-step", "0.2"],
        vec!["--part", "network", "--grid-step", "0.2"],
        vec!["--part", "dealias", "--grid-step", "0.2"],
        // A receive aperture that cannot be, in every study.
        vec!["--f-number", "0"],
        vec!["--part", "network", "--f-number", "nan"],
        vec!["--part", "dealias", "--f-number", "-1"],
        // A brain study needs a vascular tree, a readable scenario and a clutter cut-off.
        vec!["--part", "brain", "--brain-scenario", "tube"],
        vec!["--part", "brain", "--brain-scenario", "no-such-file.toml"],
        vec!["--part", "brain", "--brain-svd-low", "banana"],
        // A billion frames: refused for what they would need, before any work (they aborted on
        // the failed allocation, or would have filled the disk).
        vec!["--part", "spiral", "--frames", "1000000000"],
        vec!["--part", "network", "--network-frames", "1000000000"],
        vec!["--part", "dealias", "--frames", "1000000000"],
        vec!["--part", "brain", "--brain-frames", "1000000000"],
    ] {
        let out = tempfile::tempdir().unwrap();
        let result = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .arg("paper")
            .args(&args)
            .arg("--out")
            .arg(out.path())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert!(
            !result.status.success()
                && stderr.starts_with("error: ")
                && !stderr.contains("panicked"),
            "{args:?}: {stderr}"
        );
        if args.contains(&"1000000000") {
            assert!(
                stderr.contains("more than this machine can allocate")
                    || stderr.contains("of disk but"),
                "{args:?}: {stderr}"
            );
        }
        if args.contains(&"--f-number") {
            assert!(stderr.contains("f-number"), "{args:?}: {stderr}");
            assert!(
                std::fs::read_dir(out.path()).unwrap().next().is_none(),
                "{args:?}: wrote before refusing"
            );
        }
        if args.contains(&"0.2") {
            // Refused before anything is simulated: nothing written, and the way out named.
            assert!(stderr.contains("finer grid"), "{args:?}: {stderr}");
            assert!(
                std::fs::read_dir(out.path()).unwrap().next().is_none(),
                "{args:?}: wrote before refusing"
            );
        }
    }
}

/// A small brain: 32 elements, a 3 mm slab of cortex with one deep pair, 32 frames (too short for
/// a cardiac cycle: the RI stage is skipped and said so), noise 0 dB as the shipped brain.
fn small_brain() -> String {
    include_str!("../../../pcuvd-app/scenarios/rat-brain.toml")
        .replacen(
            "preset = \"L22-14vX\"\n",
            "preset = \"L22-14vX\"\nn_elements = 32\n",
            1,
        )
        .replacen("frames = 360", "frames = 32", 1)
        .replacen("depth_m = [0.0, 13e-3]", "depth_m = [0.0, 8e-3]", 1)
        .replacen("width_m = 10e-3", "width_m = 3e-3", 1)
        .replacen("deep_pairs = 4 ", "deep_pairs = 1 ", 1)
        .replacen("deep_depth_m = 9e-3", "deep_depth_m = 6e-3", 1)
        .replacen("deep_reach_m = 4e-3", "deep_reach_m = 2.5e-3", 1)
        .replacen(
            "depth_m = [0.9e-3, 13.5e-3]",
            "depth_m = [0.9e-3, 8.5e-3]",
            1,
        )
}

#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn the_brain_part_scores_both_methods_and_reuses_its_simulation() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("small-brain.toml");
    std::fs::write(&scenario, small_brain()).unwrap();
    let out = dir.path().join("out");
    // One clutter filter for the whole image: on this brain 2 mm blocks (the default) leave the
    // coded recording a tissue component at 4-6 mm, where the deep pair's blood is strong and
    // the blocks there cut 2 where the whole image cuts 3 (coded vessels 21.4-21.6 dB over their
    // background against 25.2-26.4), which is no measure of what coding gains.
    let run = || {
        let done = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .args(["paper", "--part", "brain", "--brain-svd-block-mm", "whole"])
            .arg("--brain-scenario")
            .arg(&scenario)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&done.stdout).to_string();
        let stderr = String::from_utf8_lossy(&done.stderr).to_string();
        assert!(done.status.success(), "{stdout}{stderr}");
        let text = std::fs::read_to_string(out.join("metrics.json")).unwrap();
        let mut m: serde_json::Value = serde_json::from_str(&text).unwrap();
        m["brain"]["timing_s"] = serde_json::Value::Null;
        m["total_s"] = serde_json::Value::Null;
        (stdout, stderr, m)
    };
    let (first, stderr, m) = run();
    assert!(!first.contains("cached"), "{first}");
    // No cardiac cycle in 32 frames: the summary line says so, once, and the processing's own
    // note, which names `process`'s options, is not repeated for each recording.
    assert!(first.contains("; no RI maps: "), "{first}");
    assert!(!stderr.contains("no RI maps"), "{stderr}");
    let brain = &m["brain"];
    let all = &brain["vector_all"];
    let pixels = all["uvd"]["pixels"].as_u64().unwrap();
    assert!(pixels > 20, "{pixels} lumen pixels");
    // The wall groups split the lumen in two: the truth's axis profile puts every lumen pixel
    // either near its vessel's wall or toward its axis, and both hold some.
    let wall = brain["vector_by_wall"].as_array().unwrap();
    let wall_pixels = |k: usize| wall[k]["uvd"]["pixels"].as_u64().unwrap();
    assert_eq!(wall_pixels(0) + wall_pixels(1), pixels, "{wall:?}");
    assert!(wall_pixels(0) > 0 && wall_pixels(1) > 0, "{wall:?}");
    assert!(wall_pixels(2) + wall_pixels(3) <= pixels, "{wall:?}");
    // Coding and IRLS apart, on the pixels both vessel masks hold: as many lumen pixels as
    // the whole lumen, detected no more often than by either method alone, and each recording's
    // two estimators read differently.
    let estimators = &brain["vector_by_estimator"][0];
    let score = |key: &str, field: &str| estimators[key][field].as_f64().unwrap();
    let detected = |method: &str| all[method]["detected"].as_f64().unwrap();
    assert_eq!(estimators["coded_irls"]["pixels"], all["pcuvd"]["pixels"]);
    for key in [
        "conventional_ls",
        "conventional_irls",
        "coded_ls",
        "coded_irls",
    ] {
        assert!(score(key, "detected") <= detected("uvd").min(detected("pcuvd")) + 1e-12);
    }
    assert_ne!(
        score("coded_ls", "rmse_mm_s"),
        score("coded_irls", "rmse_mm_s")
    );
    assert_ne!(
        score("conventional_ls", "rmse_mm_s"),
        score("conventional_irls", "rmse_mm_s")
    );
    // The deepest third by diameter class: every deep lumen pixel in one class.
    let deep: u64 = brain["vector_deep_by_diameter"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| g["uvd"]["pixels"].as_u64().unwrap())
        .sum();
    let deepest = brain["vector_by_depth"][2]["uvd"]["pixels"]
        .as_u64()
        .unwrap();
    assert_eq!(deep, deepest, "{brain}");
    // Coding gains SNR where noise limits (0 dB re the blood's echo): PC-UVD's vectors are the
    // closer to the truth, and below the cortex (1-3 mm) each band's vessels stand higher over
    // their background by most of the 9.03 dB of eight coded angles, never more (plus a decibel
    // of the estimate's spread). The cortex's first millimetre, under the bright dura, is
    // limited by the clutter filter's residue, which coding raises with the blood: there the
    // gain is smaller (measured 1.2 dB here, 7-8.5 dB deeper).
    let rmse = |method: &str| all[method]["rmse_mm_s"].as_f64().unwrap();
    assert!(rmse("pcuvd") < rmse("uvd"), "{all}");
    let bands = brain["contrast_by_depth"].as_array().unwrap();
    let gain_from = |depth_mm: f64| {
        bands
            .iter()
            .filter(|b| b["depth_mm"][0].as_f64().unwrap() >= depth_mm)
            .filter(|b| b["lumen_pixels"].as_u64().unwrap() >= 20)
            .map(|b| b["gain_db"].as_f64().unwrap())
            .collect::<Vec<_>>()
    };
    let deep = gain_from(3.0);
    assert!(deep.len() >= 2, "{bands:?}");
    for gain in &deep {
        assert!((5.0..10.0).contains(gain), "{bands:?}");
    }
    let cortex = bands[0]["gain_db"].as_f64().unwrap();
    assert!(
        cortex < deep.iter().cloned().fold(f64::INFINITY, f64::min),
        "{bands:?}"
    );
    // The recording holds no cardiac cycle: no RI maps, and the scores say why.
    assert!(
        brain["ri_skipped"].as_array().unwrap().len() == 2,
        "{brain}"
    );
    for name in [
        "fig6_brain_doppler.png",
        "fig6gh_brain_profiles.png",
        "fig7_brain_rois.png",
        "fig8_brain_ri.png",
    ] {
        assert!(out.join(name).exists(), "{name} missing");
    }
    // 32 frames are shorter than one spectrogram window (36): no spectrogram figure.
    assert!(!out.join("fig8b_brain_spectrograms.png").exists());
    // The maps the scores come from: the lumen as many pixels as scored, and PC-UVD's in-plane
    // RMSE over its detected lumen pixels recomputed from them as metrics.json has it.
    let maps = out.join("brain_maps");
    let flags = |name: &str| -> Array2<u8> { read_npy(maps.join(format!("{name}.npy"))).unwrap() };
    let field = |name: &str| -> Array2<f64> { read_npy(maps.join(format!("{name}.npy"))).unwrap() };
    let lumen = flags("lumen");
    let lumen_pixels = lumen.iter().filter(|&&l| l == 1).count() as u64;
    assert_eq!(lumen_pixels, brain["lumen_pixels"].as_u64().unwrap());
    let (vx, vz, detected) = (
        field("pcuvd_vx"),
        field("pcuvd_vz"),
        flags("pcuvd_detected"),
    );
    let (true_vx, true_vz) = (field("truth_vx"), field("truth_vz"));
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, &l) in lumen.indexed_iter() {
        if l == 1 && detected[i] == 1 {
            sum += (vx[i] - true_vx[i]).powi(2) + (vz[i] - true_vz[i]).powi(2);
            n += 1;
        }
    }
    let recomputed_mm_s = 1e3 * (sum / n as f64).sqrt();
    assert!(
        (recomputed_mm_s - rmse("pcuvd")).abs() < 1e-9,
        "{recomputed_mm_s} {all}"
    );
    assert_eq!(field("diameter_m").dim(), lumen.dim());
    // The wall scores' pixels, recounted from the axis profile the maps carry (near the wall:
    // below 1/3, the blood beyond about 0.8 of the radius); the blood fraction is a share of
    // the beam, blood only where the truth has blood.
    let profile = field("truth_axis_profile");
    let near_wall = lumen
        .indexed_iter()
        .filter(|&(i, &l)| l == 1 && profile[i] < 1.0 / 3.0)
        .count() as u64;
    let walls = &brain["vector_by_wall"];
    assert_eq!(walls[0]["group"], "near the wall");
    assert_eq!(walls[0]["uvd"]["pixels"].as_u64().unwrap(), near_wall);
    assert_eq!(
        walls[1]["uvd"]["pixels"].as_u64().unwrap(),
        lumen_pixels - near_wall
    );
    assert!(near_wall > 0 && near_wall < lumen_pixels, "{walls}");
    // Each mode's resolution cells, one per angle, as the partial-volume correction (on by
    // default) measured them from the speckle: a 2-cycle pulse at 15.6 MHz received at F# 1 makes
    // a cell longer laterally than axially, each under a wavelength (0.1 mm) in σ.
    let cells = brain["resolution_cells"].as_array().unwrap();
    assert_eq!(cells.len(), 2, "{cells:?}");
    for mode in cells {
        let angles = mode.as_array().unwrap();
        assert_eq!(angles.len(), 8, "{mode}");
        for cell in angles {
            let (sx, sz) = (
                cell["sigma_x_mm"].as_f64().unwrap(),
                cell["sigma_z_mm"].as_f64().unwrap(),
            );
            assert!(sz > 0.0 && sz < sx && sx < 0.1, "{cell}");
        }
    }
    let (fraction, blood) = (field("truth_blood_fraction"), flags("blood"));
    for (i, &f) in fraction.indexed_iter() {
        assert!((0.0..=1.0).contains(&f), "{f}");
        assert_eq!(f > 0.0, blood[i] == 1, "{i:?}");
    }
    // Without RI maps, no RI files.
    assert!(!maps.join("pcuvd_ri.npy").exists() && !maps.join("uvd_ri.npy").exists());
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("Virtual rat brain"));

    // Again: the simulation comes from the cache, and every number is the same.
    let (second, _, again) = run();
    assert!(second.contains("cached"), "{second}");
    assert_eq!(again, m);
}
