//! `pcuvd simulate` writes recordings that `pcuvd process` reads; bad input is refused clearly.

use std::process::Command;

use super::{longest_imaged, pcuvd_with_progress};

/// The truth `pcuvd simulate --preset tube` writes for one conventional noiseless frame of two
/// angles with `tube_options`: (Vx, Vz) in m/s, the lumen mask, x and z (m), and the folder.
struct TubeTruth {
    vx: ndarray::Array2<f64>,
    vz: ndarray::Array2<f64>,
    mask: ndarray::Array2<u8>,
    x: ndarray::Array1<f64>,
    z: ndarray::Array1<f64>,
    dir: tempfile::TempDir,
}

fn simulated_tube(tube_options: &[&str]) -> TubeTruth {
    simulated_tube_of("1", tube_options)
}

/// [`simulated_tube`] with `frames` frames.
fn simulated_tube_of(frames: &str, tube_options: &[&str]) -> TubeTruth {
    simulated_tube_at(frames, "2", tube_options)
}

/// [`simulated_tube_of`] with `angles` plane-wave angles.
fn simulated_tube_at(frames: &str, angles: &str, tube_options: &[&str]) -> TubeTruth {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let fixed = [
        "--quiet",
        "simulate",
        "--preset",
        "tube",
        "--mode",
        "conventional",
        "--frames",
        frames,
        "--angles",
        angles,
        "--noise-db",
        "off",
        "--out",
        d,
    ];
    let (ok, _, stderr) = pcuvd_with_progress(&[&fixed[..], tube_options].concat());
    assert!(ok, "{stderr}");
    let path = |name: &str| dir.path().join(name);
    TubeTruth {
        vx: ndarray_npy::read_npy(path("truth_vx.npy")).unwrap(),
        vz: ndarray_npy::read_npy(path("truth_vz.npy")).unwrap(),
        mask: ndarray_npy::read_npy(path("truth_mask.npy")).unwrap(),
        x: ndarray_npy::read_npy(path("truth_x.npy")).unwrap(),
        z: ndarray_npy::read_npy(path("truth_z.npy")).unwrap(),
        dir,
    }
}

#[test]
fn simulated_tube_round_trips_through_process() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let (ok, _, stderr) = pcuvd_with_progress(&[
        "simulate", "--preset", "tube", "--mode", "coded", "--frames", "6", "--angles", "4",
        "--out", d,
    ]);
    assert!(ok, "{stderr}");
    for f in [
        "coded.toml",
        "coded.npy",
        "truth_vx.npy",
        "truth_vz.npy",
        "truth_mask.npy",
    ] {
        assert!(dir.path().join(f).exists(), "{f} missing");
    }
    let manifest = std::fs::read_to_string(dir.path().join("coded.toml")).unwrap();
    assert!(
        manifest.contains("pcuvd-recording")
            && manifest.contains("hadamard")
            && manifest.contains("noise_definition")
    );
    let out = dir.path().join("out");
    let (ok, _, stderr) = pcuvd_with_progress(&[
        "process",
        dir.path().join("coded.toml").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        // 0.08 mm: fine enough for the default (Loupas) estimator, which reads the echo's mean
        // frequency from the axial lag and refuses steps over 98.7 µm at 15.6 MHz.
        "--grid=-2,2,6,10,0.08",
        "--svd-low",
        "off",
    ]);
    assert!(ok, "{stderr}");
    for f in [
        "vx.npy",
        "vz.npy",
        "speed.npy",
        "vector.png",
        "summary.json",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    // Signed power Doppler: the power, carrying the sign of the flow's axial direction. The
    // straight tube's flow has one axial direction (truth_vz, > 0 deeper = away from the probe):
    // the lumen's pixels (power within 6 dB of the peak) carry its sign.
    let power: ndarray::Array2<f64> = ndarray_npy::read_npy(out.join("power_doppler.npy")).unwrap();
    let signed: ndarray::Array2<f64> =
        ndarray_npy::read_npy(out.join("signed_power_doppler.npy")).unwrap();
    let truth_vz: ndarray::Array2<f64> =
        ndarray_npy::read_npy(dir.path().join("truth_vz.npy")).unwrap();
    let truth_mask: ndarray::Array2<u8> =
        ndarray_npy::read_npy(dir.path().join("truth_mask.npy")).unwrap();
    let away = truth_vz
        .iter()
        .zip(&truth_mask)
        .filter(|(_, m)| **m != 0)
        .map(|(v, _)| v.signum())
        .sum::<f64>()
        .signum();
    assert!(away != 0.0);
    let peak = power.iter().cloned().fold(0.0, f64::max);
    let lumen: Vec<f64> = power
        .iter()
        .zip(&signed)
        .filter(|(p, _)| **p >= peak / 4.0)
        .map(|(p, s)| {
            assert_eq!(s.abs(), *p, "|signed power| is the power");
            s.signum()
        })
        .collect();
    let along = lumen.iter().filter(|&&s| s == away).count();
    assert!(
        along * 10 >= lumen.len() * 9,
        "{along} of {} lumen pixels carry the flow's sign {away}",
        lumen.len()
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(
        summary["acquisition"]["coding"]["event_alignment"], "mid-frame",
        "coded events are aligned to mid-frame by default"
    );

    // A grid too coarse for Loupas is refused before any work, saying what to do instead.
    let (ok, _, stderr) = pcuvd_with_progress(&[
        "--quiet",
        "process",
        dir.path().join("coded.toml").to_str().unwrap(),
        "--out",
        dir.path().join("coarse").to_str().unwrap(),
        "--grid=-2,2,6,10,0.1",
    ]);
    assert!(!ok, "a 0.1 mm axial step is too coarse for Loupas");
    assert!(
        stderr.contains("--doppler-estimator loupas")
            && stderr.contains("finer grid")
            && stderr.contains("kasai")
            && stderr.trim_end().lines().count() == 1,
        "{stderr}"
    );
    assert!(
        !dir.path().join("coarse").exists(),
        "refused after the output folder was made"
    );

    // A recording whose samples file is named like an output, processed into its own folder: the
    // output would overwrite the input, so pcuvd refuses, --force or not, and the samples stay.
    let toml = std::fs::read_to_string(dir.path().join("coded.toml")).unwrap();
    std::fs::rename(dir.path().join("coded.npy"), dir.path().join("speed.npy")).unwrap();
    std::fs::write(
        dir.path().join("coded.toml"),
        toml.replace("\"coded.npy\"", "\"speed.npy\""),
    )
    .unwrap();
    let before = std::fs::read(dir.path().join("speed.npy")).unwrap();
    let (ok, _, stderr) = pcuvd_with_progress(&[
        "--quiet",
        "process",
        dir.path().join("coded.toml").to_str().unwrap(),
        "--out",
        dir.path().to_str().unwrap(),
        "--force",
    ]);
    assert!(
        !ok && stderr.contains("would overwrite the input"),
        "{stderr}"
    );
    assert_eq!(std::fs::read(dir.path().join("speed.npy")).unwrap(), before);
}

/// The scores `against_truth` should hold for the run in `out`, which covers the pixels `rows`,
/// `cols` of the default grid, computed here from the maps it wrote and the truth files beside
/// the recording (a steady tube: its truth averaged over the recording is the truth at its
/// start that the files hold).
fn check_scores(
    scored: &serde_json::Value,
    out: &std::path::Path,
    tube: &TubeTruth,
    rows: std::ops::Range<usize>,
    cols: std::ops::Range<usize>,
) {
    use ndarray::{Array1, Array2, Zip, s};
    let map = |name: &str| -> Array2<f64> { ndarray_npy::read_npy(out.join(name)).unwrap() };
    let axis = |name: &str| -> Array1<f64> { ndarray_npy::read_npy(out.join(name)).unwrap() };
    let close = |a: f64, b: f64, what: &str| {
        assert!(
            (a - b).abs() <= 1e-9 * b.abs().max(1e-6),
            "{what}: {a} against {b}"
        );
    };
    for (run, truth) in [
        (axis("x.npy"), tube.x.slice(s![cols.clone()])),
        (axis("z.npy"), tube.z.slice(s![rows.clone()])),
    ] {
        assert_eq!(run.len(), truth.len());
        Zip::from(&run)
            .and(&truth)
            .for_each(|a, b| assert!((a - b).abs() < 1e-12, "{a} against {b}"));
    }
    let block = s![rows, cols];
    let (tvx, tvz) = (tube.vx.slice(block), tube.vz.slice(block));
    let mask = tube.mask.slice(block).mapv(|m| m != 0);
    let vessel_pixels = mask.iter().filter(|&&m| m).count();
    assert!(vessel_pixels > 100, "{vessel_pixels} vessel pixels");
    assert_eq!(scored["vessel_pixels"].as_u64(), Some(vessel_pixels as u64));
    let rmse = |estimate: &Array2<f64>, truth: ndarray::ArrayView2<f64>| {
        let mut sum = 0.0;
        Zip::from(estimate)
            .and(truth)
            .and(&mask)
            .for_each(|&e, &t, &m| {
                if m {
                    let error = if e.is_finite() { e - t } else { t };
                    sum += error * error;
                }
            });
        (sum / vessel_pixels as f64).sqrt() * 1e3
    };
    let mut peak = 0.0_f64;
    Zip::from(&tvx).and(&tvz).and(&mask).for_each(|&x, &z, &m| {
        if m {
            peak = peak.max(x.hypot(z));
        }
    });
    close(
        scored["peak_speed_mm_s"].as_f64().unwrap(),
        peak * 1e3,
        "peak",
    );
    close(
        scored["color_doppler_rmse_mm_s"].as_f64().unwrap(),
        rmse(&map("color_doppler.npy"), tvz),
        "colour Doppler",
    );
    for (estimator, suffix) in [("irls", ""), ("ls", "_ls")] {
        let (vx, vz) = (
            map(&format!("vx{suffix}.npy")),
            map(&format!("vz{suffix}.npy")),
        );
        let rmse_of = &scored["vector_rmse_mm_s"][estimator];
        close(rmse_of["vx"].as_f64().unwrap(), rmse(&vx, tvx), estimator);
        close(rmse_of["vz"].as_f64().unwrap(), rmse(&vz, tvz), estimator);
        let mut within = 0usize;
        Zip::from(&vx)
            .and(&vz)
            .and(&tvx)
            .and(&tvz)
            .and(&mask)
            .for_each(|&ex, &ez, &tx, &tz, &m| {
                within += usize::from(m && (ex - tx).hypot(ez - tz) <= 0.1 * peak);
            });
        close(
            scored["vector_within_10_percent_of_peak"][estimator]
                .as_f64()
                .unwrap(),
            within as f64 / vessel_pixels as f64,
            estimator,
        );
    }
    assert_eq!(
        scored["ri"], "the scenario's flow is steady: no cardiac cycle",
        "a steady tube has no RI truth"
    );
    assert!(scored["definitions"]["vector_rmse"].is_string());
    assert!(out.join("against_truth.png").is_file());
}

/// `pcuvd process` scores a simulated recording against the truth of the scenario beside it, on
/// the default grid and on a grid of the user's; a scenario that no longer describes the
/// recording gives the reason instead of scores.
#[test]
fn a_simulated_recording_is_scored_against_its_truth() {
    // Eight frames: one is too short for Doppler.
    let tube = simulated_tube_of("8", &[]);
    let d = tube.dir.path();
    let recording = d.join("conventional.toml");
    let run = |name: &str, extra: &[&str]| {
        let out = d.join(name);
        let (ok, stdout, stderr) = pcuvd_with_progress(
            &[
                &[
                    "--quiet",
                    "process",
                    recording.to_str().unwrap(),
                    "--out",
                    out.to_str().unwrap(),
                    "--dynamics",
                    "off",
                ],
                extra,
            ]
            .concat(),
        );
        assert!(ok, "{stderr}");
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        (summary["against_truth"].clone(), stdout, out)
    };
    let simulated = || {
        let (ok, stdout, stderr) =
            pcuvd_with_progress(&["info", "--json", recording.to_str().unwrap()]);
        assert!(ok, "{stderr}");
        serde_json::from_str::<serde_json::Value>(&stdout).unwrap()["simulated_scenario"].clone()
    };
    let scenario = d.join("scenario.toml");
    assert_eq!(
        simulated(),
        scenario.to_str().unwrap(),
        "info names the scenario"
    );
    let (nz, nx) = tube.mask.dim();
    let (scored, stdout, out) = run("whole", &[]);
    check_scores(&scored, &out, &tube, 0..nz, 0..nx);
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(
        report.contains("Against the simulation&#39;s truth"),
        "the report's section"
    );
    assert!(
        stdout.contains(&format!(
            "({} vessel pixels",
            scored["vessel_pixels"].as_u64().unwrap()
        )),
        "{stdout}"
    );

    // A grid of the user's, cut from the default one: scored on its own pixels.
    let (rows, cols) = (80..300, 30..190);
    let mm = |v: f64| format!("{}", v * 1e3);
    let grid = format!(
        "--grid={},{},{},{},{}",
        mm(tube.x[cols.start]),
        mm(tube.x[cols.end - 1]),
        mm(tube.z[rows.start]),
        mm(tube.z[rows.end - 1]),
        mm(tube.x[1] - tube.x[0])
    );
    let (scored, _, out) = run("cut", &[&grid]);
    check_scores(&scored, &out, &tube, rows, cols);

    // The scenario beside the recording edited since: a reason, not scores against it.
    let text = std::fs::read_to_string(&scenario).unwrap();
    assert!(text.contains("frames = 8"), "{text}");
    std::fs::write(&scenario, text.replace("frames = 8", "frames = 9")).unwrap();
    let (scored, stdout, _) = run("edited", &[]);
    assert!(
        scored["not_scored"]
            .as_str()
            .is_some_and(|why| why.contains("describes other recordings")),
        "{scored}"
    );
    assert!(
        stdout.contains("not scored against the truth of"),
        "{stdout}"
    );

    // A file of that name that pcuvd did not write is not a simulation's scenario.
    std::fs::write(&scenario, "# the lab's own notes\nprobe = \"L22-14v\"\n").unwrap();
    let (scored, stdout, _) = run("notes", &[]);
    assert!(scored.is_null(), "{scored}");
    assert!(!stdout.contains("truth"), "{stdout}");
    assert!(simulated().is_null());
}

#[test]
fn a_plug_tube_moves_at_its_peak_speed_up_to_the_wall() {
    let TubeTruth { vx, vz, mask, .. } =
        simulated_tube(&["--tube-profile", "plug", "--peak-velocity-mm-s", "90"]);
    let lumen = mask.iter().filter(|&&m| m == 1).count();
    assert!(lumen > 100, "{lumen} lumen pixels");
    for ((&m, &x), &z) in mask.iter().zip(&vx).zip(&vz) {
        let speed = x.hypot(z);
        if m == 1 {
            assert!(
                (speed - 0.09).abs() < 1e-9,
                "speed {speed} m/s inside a plug tube"
            );
        }
    }
}

#[test]
fn a_tube_placed_by_its_options_is_where_its_truth_and_provenance_say() {
    // A vertical tube (90°: flowing deeper) of radius 0.3 mm and 4 mm long through (1, 7) mm.
    let TubeTruth {
        vx,
        vz,
        mask,
        x,
        z,
        dir,
    } = simulated_tube(&[
        "--tube-angle-deg",
        "90",
        "--tube-centre-mm",
        "1,7",
        "--tube-radius-mm",
        "0.3",
        "--tube-length-mm",
        "4",
    ]);
    let mut lumen = 0;
    let mut peak = 0f64;
    for ((iz, ix), &m) in mask.indexed_iter() {
        let (dx, dz) = (x[ix] - 1e-3, z[iz] - 7e-3);
        let inside = dx.abs() <= 0.3e-3 && dz.abs() <= 2e-3;
        // Pixels on the wall itself may fall either side of it.
        let on_edge = (dx.abs() - 0.3e-3).abs() < 1e-9 || (dz.abs() - 2e-3).abs() < 1e-9;
        if !on_edge {
            assert_eq!(
                m == 1,
                inside,
                "pixel ({}, {}) mm",
                x[ix] * 1e3,
                z[iz] * 1e3
            );
        }
        if m == 1 {
            lumen += 1;
            assert!(vx[(iz, ix)].abs() < 1e-12, "a vertical tube has no Vx");
            let parabolic = 25e-3 * (1.0 - (dx / 0.3e-3).powi(2));
            assert!(
                (vz[(iz, ix)] - parabolic).abs() < 1e-9,
                "Vz {}",
                vz[(iz, ix)]
            );
            peak = peak.max(vz[(iz, ix)]);
        }
    }
    assert!(lumen > 100, "{lumen} lumen pixels");
    assert!(peak > 24e-3, "centreline speed {peak} m/s");
    let manifest: toml::Table =
        toml::from_str(&std::fs::read_to_string(dir.path().join("conventional.toml")).unwrap())
            .unwrap();
    let tube = &manifest["provenance"]["tube"];
    let number = |key: &str| tube[key].as_float().unwrap();
    for (key, expected) in [
        ("angle_deg", 90.0),
        ("radius_mm", 0.3),
        ("length_mm", 4.0),
        ("peak_velocity_mm_s", 25.0),
    ] {
        assert!(
            (number(key) - expected).abs() < 1e-9,
            "{key} {}",
            number(key)
        );
    }
    assert_eq!(tube["profile"].as_str(), Some("parabolic"));
    let centre: Vec<f64> = tube["centre_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_float().unwrap())
        .collect();
    assert!(
        (centre[0] - 1.0).abs() < 1e-9 && (centre[1] - 7.0).abs() < 1e-9,
        "{centre:?}"
    );
}

#[test]
fn bad_simulation_requests_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let tube = ["simulate", "--preset", "tube", "--frames", "1", "--out", d];
    // A folder inside a file can be made on no system.
    let file = tempfile::NamedTempFile::new().unwrap();
    let unwritable = file.path().join("pcuvd-cannot-write-here");
    let unwritable = unwritable.to_str().unwrap();
    let cases: [(&[&str], &str); 14] = [
        (&["simulate", "--preset", "nope", "--out", d], "nope"),
        (
            &[
                "simulate",
                "--preset",
                "paper-spiral",
                "--tube-profile",
                "plug",
                "--out",
                d,
            ],
            "--tube-profile applies to --preset tube only",
        ),
        (&["simulate", "--frames", "0", "--out", d], "--frames"),
        (
            &[
                "simulate", "--mode", "coded", "--angles", "6", "--frames", "1", "--out", d,
            ],
            "Hadamard",
        ),
        (
            &[
                "simulate",
                "--mode",
                "coded",
                "--slot-delay-us",
                "6",
                "--frames",
                "1",
                "--out",
                d,
            ],
            "overlap",
        ),
        (
            &["simulate", "--frames", "1", "--out", unwritable],
            "pcuvd-cannot-write-here",
        ),
        (
            &["simulate", "--tube-angle-deg", "45", "--out", d],
            "--tube-angle-deg applies to --preset tube only",
        ),
        (
            &[&tube[..], &["--tube-centre-mm", "1"]].concat(),
            "--tube-centre-mm \"1\": expected two finite numbers",
        ),
        (
            &[&tube[..], &["--tube-radius-mm", "0"]].concat(),
            "--tube-radius-mm 0: must be a finite length > 0 mm",
        ),
        (
            &[&tube[..], &["--tube-length-mm", "-2"]].concat(),
            "--tube-length-mm -2: must be a finite length > 0 mm",
        ),
        // Noise whose samples single precision cannot hold: refused before simulating, not
        // found as infinities in the file written.
        (
            &[&tube[..], &["--noise-db", "1000"]].concat(),
            "beyond the single precision",
        ),
        // Tissue whose echoes `process` could not hold (300 dB peaked at 3e16 on the tube):
        // refused before simulating, not written for `process` to refuse.
        (
            &[&tube[..], &["--tissue-db", "300"]].concat(),
            "--tissue-db 300: must be a finite number of dB, at most 150 above",
        ),
        // The tube's dura-like layer stands 10 dB above its tissue.
        (
            &[&tube[..], &["--tissue-db", "145"]].concat(),
            "would echo 155 dB above the blood, beyond 150",
        ),
        // Petabytes of recording: refused before a byte is written, not written until the
        // disk is full.
        (
            &["simulate", "--frames", "1000000000", "--out", d],
            "of disk but",
        ),
    ];
    for (args, needle) in cases {
        let (ok, _, stderr) = pcuvd_with_progress(args);
        assert!(!ok, "{args:?} should fail");
        assert!(
            stderr.contains(needle),
            "{args:?}: {needle:?} missing from {stderr}"
        );
    }
    assert_eq!(std::fs::read_dir(d).unwrap().count(), 0, "nothing written");
}

#[test]
fn a_reused_folder_keeps_no_stale_truth_or_recording() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let small = ["--frames", "1", "--angles", "2", "--noise-db", "off"];
    let (ok, _, stderr) = pcuvd_with_progress(
        &[
            &[
                "simulate",
                "--preset",
                "rat-network",
                "--mode",
                "both",
                "--out",
                d,
            ][..],
            &small,
        ]
        .concat(),
    );
    assert!(ok, "{stderr}");
    for f in [
        "truth_ri.npy",
        "truth_vessel_class.npy",
        "truth_class_share.npy",
        "truth_axis_profile.npy",
        "conventional.toml",
        "coded.npy",
    ] {
        assert!(
            dir.path().join(f).exists(),
            "{f} missing after the network run"
        );
    }
    let network_z = std::fs::read(dir.path().join("truth_z.npy")).unwrap();
    // A request refused for its second mode (6 angles: no Hadamard order) touches nothing.
    let conventional = std::fs::read(dir.path().join("conventional.toml")).unwrap();
    let (ok, _, stderr) = pcuvd_with_progress(
        &[
            &["simulate", "--preset", "tube", "--mode", "both", "--out", d][..],
            &["--frames", "1", "--angles", "6", "--noise-db", "off"],
        ]
        .concat(),
    );
    assert!(!ok && stderr.contains("Hadamard"), "{stderr}");
    assert!(dir.path().join("truth_ri.npy").exists());
    assert_eq!(
        std::fs::read(dir.path().join("conventional.toml")).unwrap(),
        conventional
    );
    // A user's files, including one that looks like a truth file but is not of simulate's naming.
    std::fs::write(dir.path().join("notes.txt"), "mine").unwrap();
    std::fs::write(dir.path().join("truth_extra.npy"), "mine too").unwrap();

    let (ok, stdout, stderr) = pcuvd_with_progress(
        &[
            &[
                "simulate", "--preset", "tube", "--mode", "coded", "--out", d,
            ][..],
            &small,
        ]
        .concat(),
    );
    assert!(ok, "{stderr}");
    for f in [
        "truth_ri.npy",
        "truth_psv.npy",
        "truth_edv.npy",
        "truth_vessel_class.npy",
        "truth_flow_up.npy",
        "truth_class_share.npy",
        "truth_axis_profile.npy",
        "conventional.toml",
        "conventional.npy",
    ] {
        assert!(!dir.path().join(f).exists(), "stale {f} left behind");
        assert!(
            stdout.contains(f),
            "the removal of {f} is not reported: {stdout}"
        );
    }
    for f in ["coded.toml", "coded.npy", "truth_vx.npy", "truth_mask.npy"] {
        assert!(
            dir.path().join(f).exists(),
            "{f} missing after the tube run"
        );
    }
    // The network's receive window (0–13 mm) is not the tube's: its truth grid was rewritten.
    let tube_z = std::fs::read(dir.path().join("truth_z.npy")).unwrap();
    assert_ne!(tube_z, network_z, "truth_z.npy is still the network's");
    assert_eq!(
        std::fs::read_to_string(dir.path().join("notes.txt")).unwrap(),
        "mine"
    );
    assert_eq!(
        std::fs::read_to_string(dir.path().join("truth_extra.npy")).unwrap(),
        "mine too"
    );
}

/// Ctrl-C (SIGINT) during a long simulation stops it before the end (exit code 130, where a run
/// left alone would finish and exit 0), and leaves nothing that looks complete: no manifest, no
/// temporary file. The interrupt is sent once the simulation has said it started (its first
/// progress line), not after a fixed delay, so a busy machine changes nothing.
#[cfg(unix)]
#[test]
fn ctrl_c_stops_the_run_and_leaves_nothing_that_looks_complete() {
    use std::io::BufRead;
    use std::time::{Duration, Instant};
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .args(["simulate", "--preset", "paper-spiral", "--mode", "both"])
        .arg("--out")
        .arg(dir.path())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stderr = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut said = String::new();
    // Outside a terminal, progress is plain lines: the first one comes as the simulation starts.
    while !said.contains("simulate conventional") {
        let mut line = String::new();
        let read = stderr.read_line(&mut line).unwrap();
        assert!(
            read > 0,
            "the simulation ended before it said it started: {said}"
        );
        said.push_str(&line);
    }
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    // Only a guard against a hang: the whole run takes far longer than any interrupt.
    let guard = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        assert!(
            guard.elapsed() < Duration::from_secs(120),
            "still running 2 minutes after Ctrl-C"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(status.code(), Some(130), "{said}");
    std::io::Read::read_to_string(&mut stderr, &mut said).unwrap();
    assert!(said.contains("interrupted"), "{said}");
    let left: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        !left
            .iter()
            .any(|name| name.ends_with(".toml") || name.ends_with(".part")),
        "{left:?}"
    );
}

/// `pcuvd bench --scenario` counts the echoes a direct simulation renders: every scatterer once
/// per slot of every event (8 slots in a coded event of 8 angles, 1 in a conventional one). Its
/// times are measured, not checked: timing assertions would be flaky.
#[test]
fn bench_counts_a_scenarios_echoes() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bench.json");
    let json_arg = json.to_str().unwrap();
    let (ok, _, stderr) = pcuvd_with_progress(&[
        "bench",
        "--scenario",
        "tube",
        "--frames",
        "2",
        "--json",
        json_arg,
    ]);
    assert!(ok, "{stderr}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let blood = report["scatterers"]["blood"].as_f64().unwrap();
    assert!(blood > 0.0);
    assert_eq!(report["scatterers"]["tissue"], 0);
    // Two frames of 8 events in each mode: 16 conventional events of one slot, 16 coded of 8.
    assert_eq!(report["events"], 32);
    assert_eq!(report["echoes"].as_f64(), Some(blood * (16.0 + 16.0 * 8.0)));
    let ns = report["ns_per_echo"].as_f64().unwrap();
    let seconds = report["simulate_s"].as_f64().unwrap();
    assert!((ns * 1e-9 * blood * 144.0 - seconds).abs() <= 1e-9 * seconds);
    let (ok, _, stderr) = pcuvd_with_progress(&["bench", "--scenario", "rat-heart"]);
    assert!(!ok && stderr.contains("rat-brain"), "{stderr}");
}

/// A `simulate` whose reader closes the pipe ends at its next line printed, as a Unix tool does,
/// and leaves no temporary file of the recordings it was writing (both modes' writers are open
/// when the first one's "wrote" line meets the closed pipe).
#[cfg(unix)]
#[test]
fn a_closed_pipe_leaves_no_partial_files() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim");
    let result = crate::run_with_stdout_closed(
        Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .args([
                "simulate",
                "--preset",
                "paper-spiral",
                "--mode",
                "both",
                "--frames",
                "2",
            ])
            .arg("--out")
            .arg(&out)
            .arg("--quiet"),
    );
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.signal(), Some(libc::SIGPIPE), "{stderr}");
    let left: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        left.iter().all(|name| !name.ends_with(".part")),
        "temporary files left: {left:?}"
    );
    // The first recording was complete when its line met the closed pipe; the second was not.
    assert!(left.contains(&"conventional.npy".to_string()), "{left:?}");
    assert!(!left.contains(&"coded.npy".to_string()), "{left:?}");
}

/// A recording read a block of frames at a time is identified in the reader's own pass over its
/// samples file (XXH3-128, BLAKE3; SHA-256 on a thread beside): whatever the blocks (overlapping
/// ensembles, frames no ensemble reads), the checksums in `summary.json` are those of the whole
/// file, as xxh128sum's, b3sum's and sha256sum's.
#[test]
fn a_recording_read_in_blocks_is_identified_by_the_whole_files_checksum() {
    let dir = tempfile::tempdir().unwrap();
    let sim = dir.path().join("sim");
    let (ok, _, stderr) = pcuvd_with_progress(&[
        "--quiet",
        "simulate",
        "--preset",
        "tube",
        "--mode",
        "coded",
        "--frames",
        "14",
        "--angles",
        "4",
        "--out",
        sim.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let samples = std::fs::read(sim.join("coded.npy")).unwrap();
    let blake3 = blake3::hash(&samples).to_hex().to_string();
    let xxh128 = super::xxh128_of(&samples);
    let sha256 = super::sha256_of_file(&sim.join("coded.npy"));
    let blocks: [&[&str]; 3] = [
        &[],
        // Four segments, one block each.
        &["--segment-frames", "4", "--ensemble-frames", "4"],
        // Ensembles of 5 frames every 4: blocks overlap, and the last frame is never read.
        &["--ensemble-frames", "5", "--ensemble-step", "4"],
    ];
    for (run, options) in blocks.iter().enumerate() {
        for (checksum, expected) in [
            ("xxh128", &xxh128),
            ("blake3", &blake3),
            ("sha256", &sha256),
        ] {
            let out = dir.path().join(format!("out-{run}-{checksum}"));
            let manifest = sim.join("coded.toml");
            let fixed = [
                "--quiet",
                "process",
                manifest.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--grid=-2,2,6,10,0.08",
                "--svd-low",
                "off",
                "--dynamics",
                "off",
                "--checksum",
                checksum,
            ];
            let (ok, _, stderr) = pcuvd_with_progress(&[&fixed[..], options].concat());
            assert!(ok, "{stderr}");
            let summary: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                    .unwrap();
            let source = &summary["source"];
            assert!(
                source["reader"]
                    .as_str()
                    .unwrap()
                    .starts_with("pcuvd_io::ManifestFrames"),
                "{source}"
            );
            let file = &source["files"][1];
            assert!(file["path"].as_str().unwrap().ends_with("coded.npy"));
            assert_eq!(file["size_bytes"].as_u64(), Some(samples.len() as u64));
            assert_eq!(
                file[checksum].as_str(),
                Some(expected.as_str()),
                "{options:?}"
            );
            assert!(summary["timings_s"]["checksum"].as_f64().unwrap() > 0.0);
        }
    }
}

/// `pcuvd info` on a recording longer than a segment (600 frames, more than the 512 a segment
/// holds by default) gives the segments as `process` cuts them: their count and the longest
/// span imaged, the frames the dynamics windows reach past each segment's own included.
#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn info_cuts_a_long_recording_as_process_does() {
    let tube = simulated_tube_of("600", &["--tube-length-mm", "4"]);
    let recording = tube.dir.path().join("conventional.toml");
    let recording = recording.to_str().unwrap();
    let (ok, stdout, stderr) = pcuvd_with_progress(&["info", "--json", recording]);
    assert!(ok, "{stderr}");
    let info: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let out = tube.dir.path().join("out");
    let (ok, _, stderr) = pcuvd_with_progress(&[
        "--quiet",
        "process",
        recording,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let segments = &summary["segments"];
    let longest = longest_imaged(segments);
    assert!(segments["count"].as_u64().unwrap() >= 2, "{segments}");
    assert_eq!(
        info["processing"]["segments"], segments["count"],
        "{segments}"
    );
    assert_eq!(info["processing"]["segment_frames"], longest, "{segments}");
}

/// `--sites`: the spectrogram at the axis of a tube whose flow has a known axial speed shows
/// that speed over time, and one outside the grid is refused before any work. One angle: a
/// compounded spectrum of several weights each angle's Doppler shift, which the lateral flow
/// sets apart (by 2·Vx·sin θ), by its power at the pixel.
#[test]
fn a_site_on_the_tubes_axis_shows_its_axial_speed() {
    let tube = simulated_tube_at("64", "1", &["--peak-velocity-mm-s", "100"]);
    let out = tube.dir.path().join("sites");
    let recording = tube.dir.path().join("conventional.toml");
    let (x_axis, z_axis) = (0.0, 8.0);
    let (ok, _, stderr) = pcuvd_with_progress(&[
        "process",
        recording.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--grid=-2,2,6,10,0.08",
        "--svd-low",
        "off",
        // The axis, and a point a millimetre above the tube, where its side lobes are all.
        "--sites=0,8;0,6.5",
    ]);
    assert!(ok, "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let sites = summary["sites"].as_array().unwrap();
    assert_eq!(sites.len(), 2);
    let pixel_x = sites[0]["pixel_x_mm"].as_f64().unwrap();
    let pixel_z = sites[0]["pixel_z_mm"].as_f64().unwrap();
    assert!((pixel_x - x_axis).abs() <= 0.04 && (pixel_z - z_axis).abs() <= 0.04);
    // The truth at the pixel read: the nearest sample of the truth's own grid.
    let nearest = |axis: &ndarray::Array1<f64>, v_mm: f64| {
        (0..axis.len())
            .min_by(|&a, &b| {
                (axis[a] - v_mm * 1e-3)
                    .abs()
                    .total_cmp(&(axis[b] - v_mm * 1e-3).abs())
            })
            .unwrap()
    };
    let (iz, ix) = (nearest(&tube.z, pixel_z), nearest(&tube.x, pixel_x));
    assert_eq!(tube.mask[[iz, ix]], 1, "the site lies in the lumen");
    let true_vz = tube.vz[[iz, ix]];
    // 100 mm/s at 30° below +x: about 50 mm/s deeper on the axis.
    assert!((true_vz - 0.05).abs() < 0.005, "true Vz {true_vz} m/s");

    let power: ndarray::Array3<f64> =
        ndarray_npy::read_npy(out.join("site_spectrograms.npy")).unwrap();
    let times: ndarray::Array1<f64> = ndarray_npy::read_npy(out.join("site_times.npy")).unwrap();
    let velocities: ndarray::Array2<f64> =
        ndarray_npy::read_npy(out.join("site_velocities.npy")).unwrap();
    let velocities = velocities.row(0);
    let mean: ndarray::Array2<f64> =
        ndarray_npy::read_npy(out.join("site_mean_velocity.npy")).unwrap();
    assert_eq!(power.dim(), (2, times.len(), velocities.len()));
    // Turned into velocity at the pixel's measured mean RF frequency (the default estimator,
    // Loupas), as the colour Doppler map is: below the 15.625 MHz transmitted at 8 mm.
    let frequency = sites[0]["frequency_hz"].as_f64().unwrap();
    assert!(frequency > 12e6 && frequency < 15.625e6, "{frequency} Hz");
    assert_eq!(mean.dim(), (2, times.len()));
    assert!(times.len() >= 8, "{} windows over 64 frames", times.len());
    assert!(times.windows(2).into_iter().all(|t| t[1] > t[0]));
    // The windows' mean Doppler velocities read the axis's speed within 5 % on average; each
    // window alone (a few speckle renewals of one pixel) jitters by some 20 %.
    let windows_mean = mean.row(0).mean().unwrap();
    assert!(
        (windows_mean - true_vz).abs() < 0.05 * true_vz,
        "{windows_mean} m/s against {true_vz}"
    );
    for &v in mean.row(0) {
        assert!(
            v > 0.5 * true_vz && v < 1.5 * true_vz,
            "{v} m/s against {true_vz}"
        );
    }
    // The spectrum's peak, averaged over time, lies within one resolution cell of it: the
    // window's frame rate over its frames, in velocity.
    let averaged: Vec<f64> = (0..velocities.len())
        .map(|j| {
            (0..times.len())
                .map(|t| 10f64.powf(power[[0, t, j]] / 10.0))
                .sum()
        })
        .collect();
    let peak = (0..averaged.len())
        .max_by(|&a, &b| averaged[a].total_cmp(&averaged[b]))
        .unwrap();
    let frame_rate = summary["acquisition"]["frame_rate_hz"].as_f64().unwrap();
    // A window of W frames is centred (W − 1) / 2 frames after its start.
    let window_frames = 2.0 * times[0] * frame_rate + 1.0;
    let bin = (velocities[1] - velocities[0]).abs();
    let cell = bin * velocities.len() as f64 / window_frames;
    assert!(
        (velocities[peak] - true_vz).abs() <= cell,
        "peak at {} m/s against {true_vz} (cell {cell} m/s)",
        velocities[peak]
    );
    assert!(out.join("sites.png").is_file());

    // A sample volume of 0.2 mm: the power spectra of the 21 pixels within it of the axis pixel
    // (2.5 steps of 0.08 mm), whose windows no longer jitter as one pixel's do, and whose mean
    // reads the truth averaged over the gate.
    let gated = tube.dir.path().join("gated");
    let (ok, _, stderr) = pcuvd_with_progress(&[
        "process",
        recording.to_str().unwrap(),
        "--out",
        gated.to_str().unwrap(),
        "--grid=-2,2,6,10,0.08",
        "--svd-low",
        "off",
        "--sites=0,8",
        "--site-radius-mm",
        "0.2",
    ]);
    assert!(ok, "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(gated.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["sites"][0]["gate_pixels"], 21);
    let gated_mean: ndarray::Array2<f64> =
        ndarray_npy::read_npy(gated.join("site_mean_velocity.npy")).unwrap();
    let spread = |row: ndarray::ArrayView1<f64>| row.std(0.0);
    assert!(
        spread(gated_mean.row(0)) < 0.5 * spread(mean.row(0)),
        "windows spread {} m/s in the gate against {} at its pixel",
        spread(gated_mean.row(0)),
        spread(mean.row(0))
    );
    let truth_in_gate: Vec<f64> = tube
        .vz
        .indexed_iter()
        .filter(|((iz, ix), _)| {
            (tube.z[*iz] - pixel_z * 1e-3).hypot(tube.x[*ix] - pixel_x * 1e-3) <= 0.2e-3
        })
        .map(|(_, &v)| v)
        .collect();
    let truth_gate = truth_in_gate.iter().sum::<f64>() / truth_in_gate.len() as f64;
    let read = gated_mean.row(0).mean().unwrap();
    assert!(
        (read - truth_gate).abs() < 0.05 * truth_gate,
        "{read} m/s against the gate's true {truth_gate}"
    );
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(report.contains("sites.png") || report.contains("the sites asked for"));

    let (ok, _, stderr) = pcuvd_with_progress(&[
        "process",
        recording.to_str().unwrap(),
        "--out",
        tube.dir.path().join("refused").to_str().unwrap(),
        "--grid=-2,2,6,10,0.08",
        "--sites=0,8;5,8",
    ]);
    assert!(!ok);
    assert!(
        stderr.contains("--sites") && stderr.contains("(5, 8) mm lies outside the imaged grid"),
        "{stderr}"
    );
    assert!(
        !tube
            .dir
            .path()
            .join("refused")
            .join("summary.json")
            .exists()
    );
}
