//! Real data: the rotating-disk recording (Verasonics, 32 unsteered plane waves) through
//! `pcuvd process` with default settings. A rigid rotation makes the axial velocity linear in x.

use std::process::Command;

use ndarray::{Array1, Array2};
use ndarray_npy::read_npy;

use pcuvd_testing::disk_recording as disk_file;

#[test]
fn rotating_disk_colour_doppler_is_linear_in_x() {
    let input = disk_file();
    let out = tempfile::tempdir().unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .arg("process")
        .arg(&input)
        .arg("--out")
        .arg(out.path())
        .status()
        .unwrap();
    assert!(status.success());
    // Provenance: the input, its size and checksum, the reader, the version and the command line.
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("summary.json")).unwrap())
            .unwrap();
    let source = &summary["source"];
    // A measured recording has no simulation's truth to be scored against.
    assert!(summary.get("against_truth").is_none());
    // report.html: one page that holds every figure drawn (no file or address outside it) and
    // says what was read.
    let report = std::fs::read_to_string(out.path().join("report.html")).unwrap();
    let figures = std::fs::read_dir(out.path())
        .unwrap()
        .filter(|entry| {
            let name = entry.as_ref().unwrap().file_name();
            name.to_string_lossy().ends_with(".png")
        })
        .count();
    assert!(figures >= 4, "{figures} figures");
    assert_eq!(report.matches("data:image/png;base64,").count(), figures);
    assert!(!report.contains("src=\"http") && !report.contains("src=\"/"));
    let nyquist_mm_s = summary["nyquist_velocity_m_s"].as_f64().unwrap() * 1e3;
    assert!(
        report.contains(&format!("Nyquist velocity {nyquist_mm_s:.1} mm/s")),
        "{}",
        &report[..2000.min(report.len())]
    );
    assert_eq!(
        source["files"][0]["size_bytes"].as_u64(),
        Some(std::fs::metadata(&input).unwrap().len())
    );
    // XXH3-128 by default, as xxh128sum prints it.
    let bytes = std::fs::read(&input).unwrap();
    assert_eq!(
        source["files"][0]["xxh128"].as_str(),
        Some(super::xxh128_of(&bytes).as_str())
    );
    // SHA-256 for those who check with sha256sum: the same digest as coreutils'.
    let sha_out = tempfile::tempdir().unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .args([
            "--quiet",
            "process",
            "--dynamics",
            "off",
            "--checksum",
            "sha256",
        ])
        .arg(&input)
        .arg("--out")
        .arg(sha_out.path())
        .status()
        .unwrap();
    assert!(status.success());
    let sha_summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(sha_out.path().join("summary.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        sha_summary["source"]["files"][0]["sha256"].as_str(),
        Some(super::sha256_of_file(&input).as_str())
    );
    // The format and reader as the reader reports them, and each parameter's source.
    assert_eq!(source["format"], "MUST/PyMUST MATLAB v5 (.mat)");
    assert!(
        source["reader"]
            .as_str()
            .unwrap()
            .starts_with("pcuvd_io::must"),
        "{source}"
    );
    let parameter = |name: &str| {
        source["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == name)
            .unwrap_or_else(|| panic!("no parameter {name} in {source}"))
            .clone()
    };
    assert_eq!(parameter("t0_s")["source"]["field"], "param.t0");
    assert_eq!(
        parameter("sampling_frequency_hz")["source"]["field"],
        "param.fs"
    );
    assert_eq!(parameter("pulse_cycles")["source"]["kind"], "default");
    assert_eq!(source["pcuvd_version"], env!("CARGO_PKG_VERSION"));
    assert!(source["command_line"][1] == "process", "{source}");
    assert!(summary["timings_s"]["read"].as_f64().unwrap() >= 0.0);
    // The process held the whole recording at once, so its peak is at least the file's size.
    let recording_bytes = std::fs::metadata(&input).unwrap().len();
    assert!(
        summary["peak_resident_bytes"].as_u64().unwrap() > recording_bytes,
        "{}",
        summary["peak_resident_bytes"]
    );
    let x: Array1<f64> = read_npy(out.path().join("x.npy")).unwrap();
    let z: Array1<f64> = read_npy(out.path().join("z.npy")).unwrap();
    let v: Array2<f64> = read_npy(out.path().join("color_doppler.npy")).unwrap();
    let bmode: Array2<f64> = read_npy(out.path().join("bmode_db.npy")).unwrap();
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("summary.json")).unwrap())
            .unwrap();
    let nyquist = summary["nyquist_velocity_m_s"].as_f64().unwrap();
    for name in [
        "bmode.png",
        "power_doppler.png",
        "signed_power_doppler.png",
        "color_doppler.png",
    ] {
        assert!(out.path().join(name).exists(), "{name} missing");
    }

    let (cx, cz, radius) = find_disk(&bmode, &x, &z);
    assert!(
        radius > 8e-3 && radius < 11e-3,
        "disk radius {radius} m (2 cm diameter expected)"
    );
    let (coef, r2, rows) = plane_fit(v.view(), &x, &z, (cx, cz, radius));
    let max_abs = rows.iter().map(|r| r.2.abs()).fold(0.0, f64::max);
    eprintln!(
        "disk centre ({:.2}, {:.2}) mm, radius {:.2} mm, {} pixels, R² = {r2:.4}, slope dv/dx = {:.1} s⁻¹, dv/dz = {:.1} s⁻¹, max |v| = {:.3} m/s, Nyquist {:.3} m/s",
        cx * 1e3,
        cz * 1e3,
        radius * 1e3,
        rows.len(),
        coef[1],
        coef[2],
        max_abs,
        nyquist
    );
    assert!(r2 >= 0.98, "R² = {r2}");
    assert!(max_abs < nyquist, "max |v| {max_abs} ≥ Nyquist {nyquist}");
    // Rigid rotation: the gradient is lateral, not axial.
    assert!(coef[2].abs() < 0.1 * coef[1].abs());

    // The colour Doppler figure draws the disk, not the side-lobe haze beside it nor the
    // time-gain-compensated noise beneath it, both within 25 dB of the disk's power (a level
    // re the peak alone drew 64 % of the first and 43 % of the second).
    let power: Array2<f64> = read_npy(out.path().join("power_doppler.npy")).unwrap();
    let drawn = pcuvd::estimate::masks::figure_flow_mask(
        &power,
        pcuvd::estimate::masks::FLOW_FIGURE_DB,
        z[1] - z[0],
    );
    let share = |region: &dyn Fn(f64, f64) -> bool| {
        let (mut n, mut inside) = (0usize, 0usize);
        for ((iz, ix), &d) in drawn.indexed_iter() {
            if region(x[ix], z[iz]) {
                n += 1;
                inside += usize::from(d);
            }
        }
        inside as f64 / n as f64
    };
    let from_centre = |px: f64, pz: f64| (px - cx).hypot(pz - cz);
    let disk = share(&|px, pz| from_centre(px, pz) < 0.9 * radius);
    let beside =
        share(&|px, pz| from_centre(px, pz) > 1.15 * radius && (pz - cz).abs() < 0.8 * radius);
    let beneath = share(&|_, pz| pz > cz + 1.2 * radius);
    eprintln!(
        "colour Doppler figure: disk {disk:.3}, beside {beside:.3}, beneath {beneath:.3} drawn"
    );
    assert!(disk > 0.99, "{disk}");
    assert!(beside < 0.05, "{beside}");
    assert!(beneath < 0.3, "{beneath}");
}

/// The disk found in the image itself: centre (m) and radius (m) of the bright region (B-mode
/// above −12 dB) in the documented box.
fn find_disk(bmode: &Array2<f64>, x: &Array1<f64>, z: &Array1<f64>) -> (f64, f64, f64) {
    let (mut n, mut sx, mut sz) = (0.0, 0.0, 0.0);
    for ((iz, ix), &b) in bmode.indexed_iter() {
        let (px, pz) = (x[ix], z[iz]);
        if (-12.5e-3..=12.5e-3).contains(&px) && (10e-3..=35e-3).contains(&pz) && b > -12.0 {
            n += 1.0;
            sx += px;
            sz += pz;
        }
    }
    let step = x[1] - x[0];
    let radius = (n * step * step / std::f64::consts::PI).sqrt();
    (sx / n, sz / n, radius)
}

/// Least-squares plane v = a + b·x + c·z over the inner 85 % of the disk (centre, radius):
/// coefficients (m/s, s⁻¹, s⁻¹), R², and the (x, z, v) rows fitted.
fn plane_fit(
    v: ndarray::ArrayView2<f64>,
    x: &Array1<f64>,
    z: &Array1<f64>,
    (cx, cz, radius): (f64, f64, f64),
) -> ([f64; 3], f64, Vec<(f64, f64, f64)>) {
    let mut rows = Vec::new();
    for ((iz, ix), &vel) in v.indexed_iter() {
        if (x[ix] - cx).hypot(z[iz] - cz) < 0.85 * radius {
            rows.push((x[ix] - cx, z[iz] - cz, vel));
        }
    }
    let mut ata = [[0.0f64; 3]; 3];
    let mut atb = [0.0f64; 3];
    for &(px, pz, vel) in &rows {
        let basis = [1.0, px, pz];
        for i in 0..3 {
            atb[i] += basis[i] * vel;
            for j in 0..3 {
                ata[i][j] += basis[i] * basis[j];
            }
        }
    }
    let coef = solve3(ata, atb);
    let mean = rows.iter().map(|r| r.2).sum::<f64>() / rows.len() as f64;
    let (mut ss_res, mut ss_tot) = (0.0, 0.0);
    for &(px, pz, vel) in &rows {
        let fit = coef[0] + coef[1] * px + coef[2] * pz;
        ss_res += (vel - fit).powi(2);
        ss_tot += (vel - mean).powi(2);
    }
    (coef, 1.0 - ss_res / ss_tot, rows)
}

/// A Doppler time series of the rotating disk: four 8-frame ensembles, each with its own clutter
/// filter. The disk turns steadily, so each ensemble's colour Doppler is the same rigid-rotation
/// plane as the whole recording's; an ensemble longer than the recording is refused at once.
#[test]
fn every_ensemble_of_the_disk_sees_the_same_rotation() {
    let out = tempfile::tempdir().unwrap();
    let run = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .args(["--quiet", "process"])
            .arg(disk_file())
            .arg("--out")
            .arg(out.path())
            .args(["--force", "--dynamics", "off"])
            .args(extra)
            .output()
            .unwrap()
    };
    let refused = run(&["--ensemble-frames", "40"]);
    assert!(!refused.status.success());
    let message = String::from_utf8_lossy(&refused.stderr);
    assert!(
        message.contains("--ensemble-frames") && message.contains("32"),
        "{message}"
    );
    assert!(!out.path().join("bmode_db.npy").exists(), "work began");

    assert!(run(&["--ensemble-frames", "8"]).status.success());
    let x: Array1<f64> = read_npy(out.path().join("x.npy")).unwrap();
    let z: Array1<f64> = read_npy(out.path().join("z.npy")).unwrap();
    let bmode: Array2<f64> = read_npy(out.path().join("bmode_db.npy")).unwrap();
    let whole: Array2<f64> = read_npy(out.path().join("color_doppler.npy")).unwrap();
    let series: ndarray::Array3<f64> =
        read_npy(out.path().join("ensemble_color_doppler.npy")).unwrap();
    let times: Array1<f64> = read_npy(out.path().join("ensemble_times.npy")).unwrap();
    assert_eq!(series.dim(), (4, z.len(), x.len()));
    // Centres of frames 0–7, 8–15, ... at 10 kHz.
    for (t, expected) in times.iter().zip([3.5e-4, 11.5e-4, 19.5e-4, 27.5e-4]) {
        assert!((t - expected).abs() < 1e-12, "{times}");
    }
    assert!(out.path().join("ensembles.png").exists());
    let disk = find_disk(&bmode, &x, &z);
    let (reference, _, _) = plane_fit(whole.view(), &x, &z, disk);
    for (e, map) in series.outer_iter().enumerate() {
        let (coef, r2, _) = plane_fit(map, &x, &z, disk);
        eprintln!(
            "ensemble {e}: dv/dx {:.1} s⁻¹ (whole recording {:.1}), R² {r2:.3}",
            coef[1], reference[1]
        );
        assert!(r2 > 0.95, "ensemble {e}: R² {r2}");
        assert!(
            (coef[1] / reference[1] - 1.0).abs() < 0.05,
            "ensemble {e}: slope {} vs {}",
            coef[1],
            reference[1]
        );
    }
}

/// A grid beside the disk, where no pixel has flow: the Doppler time series has no flow region
/// to plot, and the run still ends with its figure (maps only) and its summary.
#[test]
fn a_time_series_of_a_grid_without_flow_still_has_its_figure() {
    let out = tempfile::tempdir().unwrap();
    let done = process_disk(
        out.path(),
        &["--ensemble-frames", "4", "--grid=-0.2,0.2,7.5,8.5,0.01"],
    );
    assert!(
        done.status.success(),
        "{}",
        String::from_utf8_lossy(&done.stderr)
    );
    let power: ndarray::Array3<f64> =
        read_npy(out.path().join("ensemble_power_doppler.npy")).unwrap();
    assert_eq!(power.dim().0, 8, "32 frames in ensembles of 4");
    assert!(out.path().join("ensembles.png").exists());
    assert!(out.path().join("summary.json").exists());
}

/// `pcuvd --quiet process` of the disk recording into `out` (forced, dynamics off), with `extra`.
fn process_disk(out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .args(["--quiet", "process"])
        .arg(disk_file())
        .arg("--out")
        .arg(out)
        .args(["--force", "--dynamics", "off"])
        .args(extra)
        .output()
        .unwrap()
}

/// The disk processed in segments of 8 frames (8-frame ensembles, one per segment): the ensembles are the whole-recording run's exactly (the same images,
/// each ensemble filtered on its own), the whole-recording colour Doppler is the same rotation,
/// and summary.json says how the recording was cut.
#[test]
fn the_disk_in_segments_gives_the_same_maps() {
    let run = |extra: &[&str]| {
        let out = tempfile::tempdir().unwrap();
        let args = [&["--ensemble-frames", "8"][..], extra].concat();
        assert!(process_disk(out.path(), &args).status.success());
        out
    };
    let whole = run(&[]);
    let segmented = run(&["--segment-frames", "8"]);
    let read3 = |dir: &tempfile::TempDir, name: &str| -> ndarray::Array3<f64> {
        read_npy(dir.path().join(name)).unwrap()
    };
    for name in ["ensemble_color_doppler.npy", "ensemble_power_doppler.npy"] {
        assert_eq!(read3(&whole, name), read3(&segmented, name), "{name}");
    }
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(segmented.path().join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["segments"]["count"], 4, "{}", summary["segments"]);
    assert_eq!(
        summary["segments"]["imaged_frames"][0],
        serde_json::json!([0, 8])
    );
    let whole_summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(whole.path().join("summary.json")).unwrap()).unwrap();
    assert!(whole_summary["segments"].is_string());

    let x: Array1<f64> = read_npy(whole.path().join("x.npy")).unwrap();
    let z: Array1<f64> = read_npy(whole.path().join("z.npy")).unwrap();
    let bmode: Array2<f64> = read_npy(whole.path().join("bmode_db.npy")).unwrap();
    let disk = find_disk(&bmode, &x, &z);
    let colour = |dir: &tempfile::TempDir| -> Array2<f64> {
        read_npy(dir.path().join("color_doppler.npy")).unwrap()
    };
    let (reference, _, _) = plane_fit(colour(&whole).view(), &x, &z, disk);
    let (coef, r2, _) = plane_fit(colour(&segmented).view(), &x, &z, disk);
    eprintln!(
        "segments: dv/dx {:.1} s⁻¹ (whole recording {:.1}), R² {r2:.3}",
        coef[1], reference[1]
    );
    assert!(r2 > 0.95, "R² {r2}");
    assert!((coef[1] / reference[1] - 1.0).abs() < 0.02);
}

fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> [f64; 3] {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut m = a;
        for i in 0..3 {
            m[i][k] = b[i];
        }
        *xk = det(m) / d;
    }
    x
}

/// Outside a terminal (here stderr is a pipe, as in a log file, a notebook or a job scheduler),
/// progress comes as plain lines with the stage and its completion; `--quiet` silences them.
#[test]
fn progress_is_plain_lines_outside_a_terminal_and_quiet_silences_it() {
    let input = disk_file();
    let run = |quiet: bool| {
        let out = tempfile::tempdir().unwrap();
        let mut command = Command::new(env!("CARGO_BIN_EXE_pcuvd"));
        if quiet {
            command.arg("--quiet");
        }
        let result = command
            .arg("process")
            .arg(&input)
            .arg("--out")
            .arg(out.path())
            .output()
            .unwrap();
        assert!(result.status.success());
        String::from_utf8_lossy(&result.stderr).into_owned()
    };
    let stderr = run(false);
    for stage in [
        "decode",
        "demodulate + beamform",
        "clutter filter",
        "Doppler + vector",
    ] {
        assert!(
            stderr
                .lines()
                .any(|l| l.starts_with(&format!("{stage}: 0 % ("))),
            "no start line for {stage}: {stderr}"
        );
        assert!(
            stderr
                .lines()
                .any(|l| l.starts_with(&format!("{stage}: done, ")) && l.ends_with(" s")),
            "no completion line for {stage}: {stderr}"
        );
    }
    assert!(
        !stderr.contains('\r') && !stderr.contains('\u{1b}'),
        "terminal control codes: {stderr:?}"
    );
    let quiet = run(true);
    assert!(
        !quiet.contains("decode"),
        "--quiet printed progress: {quiet}"
    );
}

/// RI maps asked for (`--dynamics on` or a window setting) that the disk's 3.2 ms cannot give are
/// refused before anything is processed, saying why: one window, a given heart's cycle longer
/// than the windows, no cycle the data could show; with none of them asked for, the run goes on.
#[test]
fn ri_the_recording_cannot_give_is_refused_before_processing() {
    let input = disk_file();
    let out = tempfile::tempdir().unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec!["process", input.to_str().unwrap(), "--out"];
        args.push(out.path().to_str().unwrap());
        args.push("--force");
        args.extend_from_slice(extra);
        super::pcuvd_with_progress(&args)
    };
    for (extra, reason) in [
        (
            &["--window-ms", "2"][..],
            "hold 1 window of 20 frames (2.0 ms)",
        ),
        (
            &["--dynamics", "on", "--window-ms", "1"],
            "at least 2 windows",
        ),
        (
            &[
                "--window-ms",
                "0.5",
                "--window-step-ms",
                "0.1",
                "--heart-rate",
                "350",
            ],
            "a cycle at 350.00 Hz spans 2.9 ms (29 windows)",
        ),
        (
            &["--window-ms", "0.3", "--window-step-ms", "0.1"],
            "its 30 windows span 2.9 ms, shorter than one cardiac cycle at 15 Hz",
        ),
    ] {
        let (ok, _, stderr) = run(extra);
        assert!(!ok, "{extra:?}");
        let error = stderr
            .lines()
            .find(|l| l.starts_with("error: "))
            .unwrap_or_default();
        assert!(error.contains(reason), "{extra:?}: {stderr}");
        assert!(
            !stderr.contains("decode"),
            "{extra:?}: refused after work began: {stderr}"
        );
    }
    // The same heart with windows whose cycle fits: RI maps of the one cycle.
    let (ok, stdout, stderr) = run(&[
        "--window-ms",
        "0.5",
        "--window-step-ms",
        "0.1",
        "--heart-rate",
        "400",
    ]);
    assert!(ok && stdout.contains("1 cycle"), "{stdout}{stderr}");
}

/// An output folder is never mixed: a used one is refused without --force, --force replaces
/// pcuvd's own outputs and keeps the user's files, and an output never lands on the input.
#[test]
fn used_output_folders_are_refused_unless_forced_and_inputs_are_never_overwritten() {
    let input = disk_file();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let run = |extra: &[&str], out: &std::path::Path| {
        let result = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .arg("--quiet")
            .arg("process")
            .arg(&input)
            .arg("--out")
            .arg(out)
            .args(extra)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr).into_owned();
        (result.status.success(), stderr)
    };
    assert!(run(&[], &out).0);
    let summary = std::fs::read(out.join("summary.json")).unwrap();
    // The same input and options again (a batch re-run): skipped, the folder untouched.
    let again = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .args(["--quiet", "process"])
        .arg(&input)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(again.status.success());
    assert!(String::from_utf8_lossy(&again.stdout).contains("skipped"));
    assert_eq!(std::fs::read(out.join("summary.json")).unwrap(), summary);
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    // A stale output of pcuvd's naming that this run does not write (the disk has one angle).
    std::fs::write(out.join("vx.npy"), "stale").unwrap();
    // Other options into the used folder: refused without --force.
    let (ok, stderr) = run(&["--f-number", "2"], &out);
    assert!(
        !ok && stderr.contains("--force") && stderr.lines().count() == 1,
        "{stderr}"
    );
    let (ok, stderr) = run(&["--f-number", "2", "--force"], &out);
    assert!(ok, "{stderr}");
    assert!(
        !out.join("vx.npy").exists(),
        "stale vx.npy left beside a new summary.json"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
    assert!(out.join("summary.json").exists() && out.join("power_doppler.npy").exists());
    // No temporary file is left behind.
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".part"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

/// A folder whose summary.json identifies its input by another kind of checksum than today's
/// default (BLAKE3, the default of earlier versions) is still recognised by a re-run: the input
/// is hashed as that run hashed it. Forced, the new run takes the default.
#[test]
fn a_rerun_recognises_a_folder_identified_by_another_checksum() {
    let input = disk_file();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let run = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .args(["--quiet", "process", "--dynamics", "off"])
            .arg(&input)
            .arg("--out")
            .arg(&out)
            .args(extra)
            .output()
            .unwrap()
    };
    let files = || {
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        summary["source"]["files"][0].clone()
    };
    assert!(run(&["--checksum", "blake3"]).status.success());
    let bytes = std::fs::read(&input).unwrap();
    assert_eq!(
        files()["blake3"].as_str(),
        Some(blake3::hash(&bytes).to_hex().as_str())
    );
    let summary = std::fs::read(out.join("summary.json")).unwrap();
    let again = run(&[]);
    assert!(again.status.success());
    assert!(String::from_utf8_lossy(&again.stdout).contains("skipped"));
    assert_eq!(std::fs::read(out.join("summary.json")).unwrap(), summary);
    // Asked for by name, another kind is another identity: the folder is not this run's.
    let other = run(&["--checksum", "sha256"]);
    assert!(!other.status.success());
    assert!(String::from_utf8_lossy(&other.stderr).contains("--force"));
    assert!(run(&["--force"]).status.success());
    let file = files();
    assert!(file["blake3"].is_null(), "{file}");
    assert_eq!(
        file["xxh128"].as_str(),
        Some(super::xxh128_of(&bytes).as_str())
    );
}

/// Output read by a reader that closes early (`pcuvd info … | head`): the command ends quietly,
/// as a Unix tool does on a closed pipe, never with a panic.
#[cfg(unix)]
#[test]
fn a_closed_pipe_ends_the_command_without_a_panic() {
    use std::os::unix::process::ExitStatusExt;
    // Closed before the file is read: the first line printed meets a closed pipe.
    let result = crate::run_with_stdout_closed(
        Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .arg("info")
            .arg(disk_file()),
    );
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        result.status.success() || result.status.signal() == Some(libc::SIGPIPE),
        "{:?}: {stderr}",
        result.status
    );
}

/// `pcuvd info` reports what the reader understood, in text and as JSON, without processing.
#[test]
fn info_reports_the_acquisition_without_processing() {
    let input = disk_file();
    let run = |extra: &[&str]| {
        let result = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .arg("info")
            .arg(&input)
            .args(extra)
            .output()
            .unwrap();
        assert!(result.status.success());
        String::from_utf8_lossy(&result.stdout).into_owned()
    };
    let text = run(&[]);
    assert!(
        text.contains("32 events × 128 channels × 334 samples"),
        "{text}"
    );
    assert!(text.contains("band-pass sampled"), "{text}");
    let info: serde_json::Value = serde_json::from_str(&run(&["--json"])).unwrap();
    let acq = &info["acquisition"];
    // 32 unsteered plane waves at 10 kHz, one angle: frame rate = PRF, and the projection Nyquist
    // velocity c·f_frame/(4 f_c) = 1480 · 10⁴ / (4 · 5·10⁶) = 0.74 m/s.
    assert_eq!(acq["frames"], 32);
    assert!(
        (acq["frame_rate_hz"].as_f64().unwrap() - 1e4).abs() < 1e-6,
        "{acq}"
    );
    assert!(
        (acq["nyquist_velocity_m_s"].as_f64().unwrap() - 0.74).abs() < 1e-9,
        "{acq}"
    );
    // The receive f-number at the element's −3 dB directivity edge: the element's soft-baffle
    // directivity sinc(π w sin θ / λ)·cos θ, computed here from the probe info reports, is at
    // −3 dB at the angle 1/(2 F#) subtends.
    let probe = &info["probe"];
    let f_number = info["processing"]["directivity_f_number"].as_f64().unwrap();
    let lambda =
        acq["sound_speed_m_s"].as_f64().unwrap() / probe["center_frequency_hz"].as_f64().unwrap();
    let edge = (0.5 / f_number).atan();
    let x = std::f64::consts::PI * probe["element_width_m"].as_f64().unwrap() * edge.sin() / lambda;
    let directivity = x.sin() / x * edge.cos();
    assert!(
        (20.0 * directivity.log10() + 3.0).abs() < 1e-6,
        "{f_number}: {directivity}"
    );
    assert!(
        text.contains(&format!("directivity edge is at F# {f_number:.2}")),
        "{text}"
    );
    // Recorded depth: c·(t0 + (n − 1)/f_s)/2.
    let (c, t0, fs) = (
        acq["sound_speed_m_s"].as_f64().unwrap(),
        acq["t0_s"].as_f64().unwrap(),
        acq["sampling_frequency_hz"].as_f64().unwrap(),
    );
    let depth = 0.5 * c * (t0 + 333.0 / fs);
    assert!((acq["recorded_depth_m"].as_f64().unwrap() - depth).abs() < 1e-12);
    // The first frame's peak, which `process` checks: the largest |sample| of the file's first
    // transmit (RF is samples × elements × transmits, column-major, so its first 334 × 128
    // values), and within the range (no warning of a refusal).
    let file = pcuvd_io::read_mat(&input).unwrap();
    let Some(pcuvd_io::MatValue::Numeric { real, .. }) = file.get("RF") else {
        panic!("the disk's RF")
    };
    let first = real.to_f64()[..334 * 128]
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs())) as f32;
    assert_eq!(
        info["samples"]["peak_of_first_frame"].as_f64(),
        Some(first as f64),
        "{}",
        info["samples"]
    );
    assert!(
        text.contains(&format!("peak {first:.3e} in frame 0")),
        "{text}"
    );
    assert!(!text.contains("would refuse"), "{text}");
}

/// `pcuvd bench` counts the beamformer's work as other beamformers publish it (points = pixels ×
/// elements × images) on the grid `process` uses, and reports it against the stage's own median
/// time, with the processing options given. Its speeds are measured, not checked here: timing
/// assertions would be flaky.
#[test]
fn bench_counts_the_beamformers_points_on_the_process_grid() {
    let input = disk_file();
    let dir = tempfile::tempdir().unwrap();
    // One timed run with `options`, its JSON report.
    let bench = |options: &[&str]| -> serde_json::Value {
        let json = dir.path().join("bench.json");
        let done = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
            .args(["bench", "--repeat", "1"])
            .args(options)
            .arg("--json")
            .arg(&json)
            .arg(&input)
            .output()
            .unwrap();
        assert!(
            done.status.success(),
            "{}",
            String::from_utf8_lossy(&done.stderr)
        );
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap()
    };
    let report = bench(&[]);
    let info = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .args(["info", "--json"])
        .arg(&input)
        .output()
        .unwrap();
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let recording = &report["recording"];
    let grid = &info["processing"]["default_grid_nz_nx"];
    let pixels = grid[0].as_f64().unwrap() * grid[1].as_f64().unwrap();
    assert_eq!(recording["pixels"].as_f64(), Some(pixels), "{info}");
    assert_eq!(recording["elements"], 128);
    assert_eq!(recording["images"], 32);
    let beamform_s = report["median_s"]["stages"]["demodulate + beamform"]
        .as_f64()
        .unwrap();
    let points_per_s = report["throughput"]["beamform_points_per_s"]
        .as_f64()
        .unwrap();
    let expected = pixels * 128.0 * 32.0 / beamform_s;
    assert!((points_per_s - expected).abs() <= 1e-9 * expected);
    // The active aperture: some, not all, of the 128 elements reach each pixel at the default
    // f-number.
    let active = report["throughput"]["mean_active_aperture_elements"]
        .as_f64()
        .unwrap();
    assert!(active > 1.0 && active < 128.0, "{active}");
    assert!(
        report["machine"]["cpu"]
            .as_str()
            .is_some_and(|c| !c.is_empty())
    );
    let default_f_number = pcuvd::form::beamform::DasParams::DEFAULT_F_NUMBER;
    assert_eq!(report["processing"]["f_number"], default_f_number);
    // A processing option reaches the runs: at half the default f-number each pixel's receive
    // half-aperture z / (2 F#) doubles, so its element count grows, at most twice plus one
    // element (fewer where the array's edge cuts it).
    let half = default_f_number / 2.0;
    let narrow = bench(&["--f-number", &half.to_string()]);
    assert_eq!(narrow["processing"]["f_number"], half);
    let wider = narrow["throughput"]["mean_active_aperture_elements"]
        .as_f64()
        .unwrap();
    assert!(
        wider > active && wider <= 2.0 * active + 1.0,
        "{wider} against {active}"
    );
    // They time processing; a simulation takes none.
    let refused = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .args(["bench", "--scenario", "paper-spiral", "--f-number", "0.75"])
        .output()
        .unwrap();
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--scenario times a simulation"));
}

/// With `PCUVD_SIMD=portable` every kernel of `pcuvd bench`'s runs is the portable one, and the
/// report says so (beside the CPU, which keeps its features): what a CPU without AVX2 spends.
#[test]
fn bench_names_the_vector_level_that_pcuvd_simd_caps() {
    use pcuvd::core::simd::{Level, SIMD_VARIABLE};
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bench.json");
    let done = Command::new(env!("CARGO_BIN_EXE_pcuvd"))
        .env(SIMD_VARIABLE, "portable")
        .args(["bench", "--repeat", "1", "--json"])
        .arg(&json)
        .arg(disk_file())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&done.stdout);
    assert!(
        done.status.success(),
        "{}",
        String::from_utf8_lossy(&done.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let expected = if Level::detected() > Level::Portable {
        "portable (PCUVD_SIMD)"
    } else {
        "portable"
    };
    assert_eq!(report["machine"]["kernels"], expected);
    assert_eq!(report["throughput"]["beamform_kernel"], "portable");
    assert!(stdout.contains(&format!("{expected} kernels")), "{stdout}");
}
