//! `pcuvd process` runs the dynamics stage on a recording that holds a cardiac cycle and writes RI,
//! PSV, EDV and vessel-class maps (the arteriole more resistive than the venule); recordings and
//! settings that cannot give RI maps are refused with one clear line.

use super::pcuvd;
use std::path::Path;

use ndarray::{Array1, Array2};
use ndarray_npy::read_npy;
use pcuvd::dynamics::{ARTERIOLE, VENULE};
use pcuvd::simulate::phantom::network::{NetworkPhantom, NetworkSpec, VesselKind, VesselSpec};
use pcuvd::simulate::{self, SimParams};
use pcuvd::{Coding, Probe, Sequence};

const HEART_RATE: f64 = 12.0;

fn vessel(name: &str, kind: VesselKind, x_mm: f64, angle_deg: f64) -> VesselSpec {
    let (psv, ri) = match kind {
        VesselKind::Arteriole => (25e-3, 0.7),
        VesselKind::Venule => (12e-3, 0.3),
    };
    VesselSpec {
        name: name.into(),
        kind,
        centre: [x_mm * 1e-3, 6.5e-3],
        angle: angle_deg.to_radians(),
        length: 2.5e-3,
        radius: 0.25e-3,
        psv,
        ri,
        delay_s: 0.01,
    }
}

/// A 64-element, 4-angle conventional recording (1.8 kHz compound rate, 200 frames = 0.11 s, one
/// 12 Hz beat) of an arteriole flowing down and a venule flowing up, noise off; returns the
/// manifest path.
fn write_recording(dir: &Path) -> std::path::PathBuf {
    let angles = Sequence::evenly_spaced_angles(4, 15f64.to_radians());
    let (manifest, phantom) =
        simulate_network(dir, "pulsatile", vec![], angles, 7.2e3, 200, 8.5e-3);
    let grid_x: Vec<f64> = (0..31).map(|i| -1.5e-3 + i as f64 * 0.1e-3).collect();
    let grid_z: Vec<f64> = (0..21).map(|i| 5.5e-3 + i as f64 * 0.1e-3).collect();
    let truth = phantom.cycle_truth(&grid_x, &grid_z);
    pcuvd_io::write_npy(&dir.join("truth_class.npy"), &truth.vessel_class).unwrap();
    manifest
}

/// The slow tier's arteriole flowing down and venule flowing up, and the `more` vessels given,
/// simulated on 64 elements of the L22-14vX at the steering `angles` (rad; conventional, events
/// at `event_prf` Hz, `frames` compound frames, echoes from 4.5 mm to `deepest` m), noise off,
/// written as `name` into `dir`: the manifest's path, and the phantom for its truth.
fn simulate_network(
    dir: &Path,
    name: &str,
    more: Vec<VesselSpec>,
    angles: Vec<f64>,
    event_prf: f64,
    frames: usize,
    deepest: f64,
) -> (std::path::PathBuf, NetworkPhantom) {
    let mut vessels = vec![
        vessel("A", VesselKind::Arteriole, -0.6, 70.0),
        vessel("V", VesselKind::Venule, 0.6, -110.0),
    ];
    vessels.extend(more);
    let spec = NetworkSpec {
        vessels,
        heart_rate_hz: HEART_RATE,
        density: 3e8,
    };
    let phantom = NetworkPhantom::new(spec, 2).unwrap();
    let mut probe = Probe::l22_14vx();
    probe.n_elements = 64;
    let sequence = Sequence {
        angles,
        event_prf,
        coding: Coding::Conventional,
        pulse_cycles: 2.0,
        pulse: None,
    };
    let params = SimParams::new(probe, sequence, 65e6, 1540.0, (4.5e-3, deepest)).unwrap();
    let data = simulate::simulate(&phantom, &params, frames, &|_, _| {}).unwrap();
    pcuvd_io::write_recording(dir, name, &data, &toml::Table::new()).unwrap();
    (dir.join(format!("{name}.toml")), phantom)
}

/// Median RI over the lumen pixels of class `kind` in `truth`; every one must have an RI.
fn median_ri_of(truth: &Array2<u8>, ri: &Array2<f64>, kind: u8) -> f64 {
    let mut v: Vec<f64> = truth
        .iter()
        .zip(ri)
        .filter(|(t, _)| **t == kind)
        .map(|(_, r)| *r)
        .collect();
    assert!(v.iter().all(|r| r.is_finite()), "lumen pixel without RI");
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn process_writes_ri_maps_and_refuses_what_cannot_work() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = write_recording(dir.path());
    let input = manifest.to_str().unwrap();
    let out = dir.path().join("out");
    let o = out.to_str().unwrap();
    // The 0.1 mm grid the pooling ellipse's pixel sizes below are checked on. Loupas (the
    // default) refuses axial steps over 98.7 µm at 15.6 MHz; RI is a ratio of speeds, which the
    // scale of Kasai's nominal frequency leaves alone, so Kasai keeps this test's figures.
    let grid = "--grid=-1.5,1.5,5.5,7.5,0.1";
    let estimator = "--doppler-estimator=kasai";
    let (ok, stdout, stderr) = pcuvd(&[
        "process",
        input,
        "--out",
        o,
        grid,
        estimator,
        "--svd-low",
        "off",
        "--heart-rate",
        "12",
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("RI maps"), "{stdout}");
    for f in [
        "ri.npy",
        "psv.npy",
        "edv.npy",
        "vessel_class.npy",
        "flow_up.npy",
        "speed_series.npy",
        "times.npy",
        "ri.png",
        "waveform.png",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["dynamics"]["heart_rate_hz"], 12.0);
    assert_eq!(summary["dynamics"]["axial_only"], false);
    let pooling = &summary["dynamics"]["vessel_pooling"];
    // Default ellipse: 2 mm along the flow, 0.25 mm across, on the 0.1 mm grid.
    assert_eq!(pooling["half_length_along_flow_px"], 20.0, "{pooling}");
    assert_eq!(pooling["half_width_across_flow_px"], 2.5, "{pooling}");
    assert!(
        (pooling["max_angle_deg"].as_f64().unwrap() - 30.0).abs() < 1e-9,
        "{pooling}"
    );
    assert_eq!(summary["dynamics"]["vessel_local_db"], 20.0);
    assert_eq!(summary["dynamics"]["vessel_local_radius_mm"], 1.0);
    assert_eq!(summary["dynamics"]["partial_volume"], false);
    // The accuracy of the RI maps under noise is checked in the library's network test and by
    // `pcuvd paper`; this small noise-free 4-angle recording checks the command with its default
    // kernel and vessel pooling, and that both vessels read their RI everywhere in the lumen. (With
    // 32 elements, a 3.2 mm aperture at 6.5 mm depth, the venule read RI 0.5: the lateral velocity
    // needs the aperture.)
    let class: Array2<u8> = read_npy(out.join("vessel_class.npy")).unwrap();
    let ri: Array2<f64> = read_npy(out.join("ri.npy")).unwrap();
    let truth: Array2<u8> = read_npy(dir.path().join("truth_class.npy")).unwrap();
    assert_eq!((class.dim(), ri.dim()), (truth.dim(), truth.dim()));
    let (artery, vein) = (
        median_ri_of(&truth, &ri, ARTERIOLE),
        median_ri_of(&truth, &ri, VENULE),
    );
    // Noise off: the errors left are the estimator's (20 ms windows, 4 angles, the lumen's
    // velocity gradient within the averaging kernel), a few hundredths of RI.
    assert!(
        (artery - 0.7).abs() < 0.06 && (vein - 0.3).abs() < 0.06,
        "arteriole RI {artery} (true 0.7), venule RI {vein} (true 0.3)"
    );
    let times: Array1<f64> = read_npy(out.join("times.npy")).unwrap();
    assert!((times[1] - times[0] - 0.005).abs() < 1e-9);

    // Cycle start times given beside the recording (an ECG's R-waves, say): one 12 Hz cycle,
    // its systole 10 ms in (the waveform's delay) with the cycle starting 2 ms after it.
    let triggers = dir.path().join("r_waves.txt");
    std::fs::write(&triggers, "0.012\n0.095333\n").unwrap();
    let triggered = dir.path().join("triggered");
    let (ok, _, stderr) = pcuvd(&[
        "process",
        input,
        "--out",
        triggered.to_str().unwrap(),
        grid,
        estimator,
        "--svd-low",
        "off",
        "--cardiac-triggers",
        triggers.to_str().unwrap(),
        // The windows corrected too: RI stays right.
        "--partial-volume",
        "on",
        "--dynamics-partial-volume",
        "on",
    ]);
    assert!(ok, "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(triggered.join("summary.json")).unwrap())
            .unwrap();
    let dynamics = &summary["dynamics"];
    assert_eq!(dynamics["partial_volume"], true);
    assert!(
        dynamics["cycles_from"]
            .as_str()
            .unwrap()
            .contains("triggers"),
        "{dynamics}"
    );
    assert_eq!(dynamics["cycles_count"], 1);
    assert!((dynamics["heart_rate_hz"].as_f64().unwrap() - 12.0).abs() < 0.1);
    let spread: Array2<f64> = read_npy(triggered.join("ri_spread.npy")).unwrap();
    assert!(spread.iter().all(|v| v.is_nan()), "one cycle has no spread");
    let ri_triggered: Array2<f64> = read_npy(triggered.join("ri.npy")).unwrap();
    let (artery_t, vein_t) = (
        median_ri_of(&truth, &ri_triggered, ARTERIOLE),
        median_ri_of(&truth, &ri_triggered, VENULE),
    );
    assert!(
        (artery_t - 0.7).abs() < 0.06 && (vein_t - 0.3).abs() < 0.06,
        "with triggers: arteriole RI {artery_t} (true 0.7), venule RI {vein_t} (true 0.3)"
    );

    // The same triggers recorded with the recording, in its manifest's [cardiac] table (a file
    // beside it, or the times inline): used without any trigger option, and the same RI bit for
    // bit.
    // `pcuvd process INPUT --out OUT` as above plus `extra`, which must succeed: its summary.json.
    let process_ok = |input: &std::path::Path, out: &std::path::Path, extra: &[&str]| {
        let mut args = vec![
            "process",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            grid,
            estimator,
            "--svd-low",
            "off",
        ];
        args.extend_from_slice(extra);
        let (ok, _, stderr) = pcuvd(&args);
        assert!(ok, "{args:?}: {stderr}");
        serde_json::from_str::<serde_json::Value>(
            &std::fs::read_to_string(out.join("summary.json")).unwrap(),
        )
        .unwrap()
    };
    let text = std::fs::read_to_string(&manifest).unwrap();
    for (name, table) in [
        (
            "with_file.toml",
            "[cardiac]\ntriggers_file = \"r_waves.txt\"\n",
        ),
        ("inline.toml", "[cardiac]\ntriggers_s = [0.012, 0.095333]\n"),
    ] {
        let recorded = dir.path().join(name);
        std::fs::write(&recorded, format!("{text}\n{table}")).unwrap();
        let out_recorded = dir.path().join(format!("out_{name}"));
        let corrected = ["--partial-volume", "on", "--dynamics-partial-volume", "on"];
        let summary = process_ok(&recorded, &out_recorded, &corrected);
        let dynamics = &summary["dynamics"];
        assert!(
            dynamics["triggers_from"]
                .as_str()
                .unwrap()
                .contains("manifest")
                && dynamics["cycles_count"] == 1,
            "{name}: {dynamics}"
        );
        let ri_recorded: Array2<f64> = read_npy(out_recorded.join("ri.npy")).unwrap();
        assert!(
            pcuvd_testing::same_bits(&ri_recorded, &ri_triggered),
            "{name}: RI differs from --cardiac-triggers'"
        );
    }
    // A heart rate given on the command line wins over the recorded triggers.
    let summary = process_ok(
        &dir.path().join("inline.toml"),
        &dir.path().join("over"),
        &["--heart-rate", "12"],
    );
    assert!(summary["dynamics"]["triggers_from"].is_null(), "{summary}");
    assert_eq!(summary["dynamics"]["heart_rate_hz"], 12.0);
    // Recorded triggers that cannot be cycles are refused, naming the key.
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        format!("{text}\n[cardiac]\ntriggers_s = [0.09, 0.01]\n"),
    )
    .unwrap();
    let (ok, _, stderr) = pcuvd(&["process", bad.to_str().unwrap(), "--out", o, grid]);
    assert!(
        !ok && stderr.starts_with("error: ") && stderr.contains("[cardiac].triggers_s"),
        "{stderr}"
    );

    // Refusals: one line, naming the problem.
    // --force: each run reuses the folder of the first (the earlier run's outputs are replaced).
    let base = [
        "process",
        input,
        "--out",
        o,
        grid,
        estimator,
        "--svd-low",
        "off",
        "--force",
    ];
    let refuse = |extra: &[&str], needle: &str| {
        let args: Vec<&str> = base.iter().chain(extra).copied().collect();
        let (ok, _, stderr) = pcuvd(&args);
        assert!(!ok, "{extra:?} should fail");
        assert!(stderr.starts_with("error: "), "{stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
        assert!(stderr.contains(needle), "{needle:?} missing: {stderr}");
    };
    refuse(&["--heart-rate", "4"], "RI needs at least one whole cycle");
    refuse(
        &[
            "--heart-rate",
            "12",
            "--cardiac-triggers",
            triggers.to_str().unwrap(),
        ],
        "give one",
    );
    let backwards = dir.path().join("backwards.txt");
    std::fs::write(&backwards, "0.09 0.01").unwrap();
    refuse(
        &["--cardiac-triggers", backwards.to_str().unwrap()],
        "backwards.txt",
    );
    refuse(&["--window-ms", "500"], "window");
    refuse(&["--heart-rate", "400"], "heart rate");
    refuse(&["--heart-rate=-3"], "--heart-rate");
    refuse(&["--window-ms", "0.1"], "--window-ms");
    refuse(&["--dynamics", "on"], "heart rate");
    refuse(
        &["--heart-rate", "12", "--pool-max-angle-deg", "200"],
        "0–180",
    );
    refuse(&["--heart-rate", "12", "--pool-along-mm=-1"], "half-length");
    refuse(
        &["--heart-rate", "12", "--vessel-margin-db", "loud"],
        "--vessel-margin-db",
    );
    refuse(
        &["--heart-rate", "12", "--vessel-local-db=-5"],
        "--vessel-local-db",
    );
    refuse(
        &["--heart-rate", "12", "--vessel-local-radius-mm=-1"],
        "local radius",
    );

    // Without dynamics settings, a recording that cannot give RI maps is processed with a note.
    let (ok, _, stderr) = pcuvd(&base);
    assert!(ok, "{stderr}");
    assert!(stderr.contains("note: no RI maps"), "{stderr}");
    // How to silence it, in the command's words (Python's note names its keyword instead).
    assert!(
        stderr.contains("(--dynamics off silences this)"),
        "{stderr}"
    );
}

/// A small valid coded recording without flow where the grid lies (16 elements, 4 angles, 64
/// frames at 1 kHz, every echo from beyond the grid's depths) processed with dynamics settings
/// given: the maps are written and the missing RI maps are a note and a line of summary.json, not
/// a failed run (it failed with "no pixel has power").
#[test]
fn a_recording_without_flow_is_processed_with_a_note_on_its_ri_maps() {
    use pcuvd::{Acquisition, ChannelData, Samples};
    let dir = tempfile::tempdir().unwrap();
    let (elements, angles, frames) = (16, 4, 64);
    let acquisition = Acquisition {
        probe: Probe {
            name: "small".into(),
            n_elements: elements,
            pitch: 3e-4,
            element_width: 2.5e-4,
            center_frequency: 5e6,
            bandwidth: 0.6,
        },
        sequence: Sequence {
            angles: Sequence::evenly_spaced_angles(angles, 10f64.to_radians()),
            event_prf: 1e3 * angles as f64,
            coding: Coding::Hadamard { slot_delay: 1e-6 },
            pulse_cycles: 2.0,
            pulse: None,
        },
        sampling_frequency: 20e6,
        sound_speed: 1540.0,
        t0: 0.0,
    };
    // Scrambled values in [−1, 1), no two events alike, in the last 20 samples of each trace
    // only: echoes from beyond 9 mm, which no pixel of the grid below (1–4 mm) reaches.
    let samples = ndarray::Array3::from_shape_fn((frames * angles, elements, 256), |(e, c, s)| {
        let scrambled = ((e * 7919 + c * 104_729 + s * 15_485_863) % 1000) as f32;
        if s >= 236 {
            scrambled / 500.0 - 1.0
        } else {
            0.0
        }
    });
    let data = ChannelData {
        acquisition,
        samples: Samples::Rf(samples),
    };
    pcuvd_io::write_recording(dir.path(), "silent", &data, &toml::Table::new()).unwrap();
    let input = dir.path().join("silent.toml");
    let out = dir.path().join("out");
    let (ok, _, stderr) = pcuvd(&[
        "process",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--heart-rate",
        "40",
        "--window-ms",
        "10",
        "--window-step-ms",
        "2",
        "--grid=-1,1,1,4,0.1",
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("no RI maps: no flow to analyse"),
        "{stderr}"
    );
    assert!(out.join("power_doppler.npy").exists());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let skipped = summary["dynamics"]["skipped"].as_str().unwrap_or_default();
    assert!(skipped.contains("no flow"), "{}", summary["dynamics"]);
}

/// One steering angle (64 elements, 0°, a 1.8 kHz frame rate, 400 frames: 2.7 beats at 12 Hz,
/// noise off) of the slow tier's arteriole and venule, 20° off the beam, and a third vessel across
/// the beam: RI is read from the colour-Doppler speed, which keeps each oblique vessel's RI (a
/// ratio, blind to the cosine that scales its waveform), while the vessel across the beam, whose
/// projection is nothing but the windows' scatter about zero, is left undetermined with no RI.
#[test]
#[ignore = "slow tier: cargo test -- --include-ignored"]
fn one_angle_gives_ri_maps_from_the_colour_doppler_speed() {
    let dir = tempfile::tempdir().unwrap();
    let across = VesselSpec {
        centre: [0.0, 8.2e-3],
        angle: 0.0,
        length: 2.0e-3,
        ..vessel("X", VesselKind::Arteriole, 0.0, 0.0)
    };
    let (manifest, phantom) = simulate_network(
        dir.path(),
        "one",
        vec![across],
        vec![0.0],
        1.8e3,
        400,
        9.0e-3,
    );
    let grid_x: Vec<f64> = (0..31).map(|i| -1.5e-3 + i as f64 * 0.1e-3).collect();
    let grid_z: Vec<f64> = (0..36).map(|i| 5.2e-3 + i as f64 * 0.1e-3).collect();
    let truth = phantom.cycle_truth(&grid_x, &grid_z);

    let out = dir.path().join("out");
    let (ok, stdout, stderr) = pcuvd(&[
        "process",
        manifest.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--grid=-1.5,1.5,5.2,8.7,0.1",
        "--doppler-estimator=kasai",
        "--svd-low",
        "off",
        "--heart-rate",
        "12",
        "--zarr",
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("RI maps"), "{stdout}");
    // The store's windows hold the colour-Doppler velocity and power, and no array of NaN for
    // the lateral velocity one angle cannot give.
    let store = out.join("pcuvd.zarr");
    assert!(store.join("window_vz").is_dir() && store.join("window_power").is_dir());
    assert!(!store.join("window_vx").exists());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let dynamics = &summary["dynamics"];
    assert_eq!(dynamics["axial_only"], true, "{dynamics}");
    assert!(
        dynamics["speed"]
            .as_str()
            .unwrap()
            .contains("colour-Doppler"),
        "{dynamics}"
    );
    assert!(
        dynamics["vessel_pooling"]
            .as_str()
            .unwrap()
            .starts_with("off: "),
        "{dynamics}"
    );
    let class: Array2<u8> = read_npy(out.join("vessel_class.npy")).unwrap();
    let ri: Array2<f64> = read_npy(out.join("ri.npy")).unwrap();
    assert_eq!(class.dim(), truth.vessel_class.dim());
    // Each vessel's lumen pixels (the truth's vessel index: the spec's order).
    let lumen_of = |index: usize| -> Vec<(usize, usize)> {
        truth
            .vessel_index
            .indexed_iter()
            .filter(|(_, i)| **i == index)
            .map(|(p, _)| p)
            .collect()
    };
    let median = |mut v: Vec<f64>| {
        assert!(v.iter().all(|r| r.is_finite()), "lumen pixel without RI");
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    };
    let artery = median(lumen_of(0).iter().map(|&p| ri[p]).collect());
    let vein = median(lumen_of(1).iter().map(|&p| ri[p]).collect());
    assert!(
        (artery - 0.7).abs() < 0.06 && (vein - 0.3).abs() < 0.06,
        "one angle: arteriole RI {artery} (true 0.7), venule RI {vein} (true 0.3)"
    );
    let crossing = lumen_of(2);
    let undetermined = crossing
        .iter()
        .filter(|&&p| class[p] == pcuvd::dynamics::UNDETERMINED && ri[p].is_nan())
        .count();
    assert!(
        undetermined * 10 >= crossing.len() * 9,
        "{undetermined} of the {} pixels across the beam undetermined",
        crossing.len()
    );
}
