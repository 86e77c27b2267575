//! `pcuvd process` on beamformed IQ images formed elsewhere (an images manifest): the chain from
//! the clutter filter on, scored against the analytic truth of a synthetic pulsatile vessel, and
//! the options that set how images are formed refused with one clear line.

use std::path::{Path, PathBuf};

use super::{longest_imaged, pcuvd, pcuvd_with_progress};

use ndarray::{Array2, Array3};
use ndarray_npy::{read_npy, write_npy};
use num_complex::Complex32;

const FRAME_RATE: f64 = 1000.0;
const DEMOD: f64 = 15.625e6;
const SOUND_SPEED: f64 = 1540.0;
const HEART_RATE: f64 = 5.0;
/// The beat's peak systolic and end-diastolic velocities (m/s): RI 2/3.
const PSV: f64 = 12e-3;
const EDV: f64 = 4e-3;
/// Rows and columns of the vessel, whose blood moves away from the probe: a third of the rows it
/// crosses, so that their noise floor (a row's 30th percentile of power) is the tissue's.
const VESSEL: ([usize; 2], [usize; 2]) = ([18, 30], [8, 30]);

/// The blood's axial velocity (m/s, positive = away from the probe) at `t` (s): a cosine beat
/// between EDV and PSV.
fn velocity(t: f64) -> f64 {
    let (mean, swing) = ((PSV + EDV) / 2.0, (PSV - EDV) / 2.0);
    mean + swing * (2.0 * std::f64::consts::PI * (HEART_RATE * t - 0.2)).cos()
}

/// Complex speckle (nz, nx): white noise from a fixed seed, smoothed over 3 × 3 pixels as a
/// point-spread function would, so that neighbouring pixels correlate.
fn speckle(nz: usize, nx: usize, seed: &mut u64) -> Array2<Complex32> {
    let mut next = || {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    };
    let white = Array2::from_shape_simple_fn((nz + 2, nx + 2), || Complex32::new(next(), next()));
    Array2::from_shape_fn((nz, nx), |(z, x)| {
        white.slice(ndarray::s![z..z + 3, x..x + 3]).sum() / 9.0
    })
}

/// Compound IQ images (frames, z, x) of static tissue 30 dB above a vessel of pulsatile blood,
/// and a little noise: the blood's phase falls as it moves away (IQ demodulated by e^(−2πift)).
fn synthetic_images(frames: usize) -> Array3<Complex32> {
    let (nz, nx) = (48, 64);
    let mut seed = 7;
    let tissue = speckle(nz, nx, &mut seed) * 30.0;
    let blood = speckle(nz, nx, &mut seed);
    let mut phase = 0.0;
    let mut images = Array3::zeros((frames, nz, nx));
    for (t, mut frame) in images.outer_iter_mut().enumerate() {
        phase += 4.0 * std::f64::consts::PI * DEMOD * velocity(t as f64 / FRAME_RATE)
            / (SOUND_SPEED * FRAME_RATE);
        let turn = Complex32::from_polar(1.0, -phase as f32);
        let noise = speckle(nz, nx, &mut seed) * 0.05;
        for ((z, x), value) in frame.indexed_iter_mut() {
            let in_vessel =
                (VESSEL.0[0]..VESSEL.0[1]).contains(&z) && (VESSEL.1[0]..VESSEL.1[1]).contains(&x);
            let flow = if in_vessel {
                blood[[z, x]] * turn
            } else {
                0.0.into()
            };
            *value = tissue[[z, x]] + flow + noise[[z, x]];
        }
    }
    images
}

/// Writes `images` (frames, z, x) and their manifest, with `extra` tables, into `dir`; returns
/// the manifest's path.
fn write_images(dir: &Path, images: &Array3<Complex32>, extra: &str) -> PathBuf {
    write_npy(dir.join("iq.npy"), images).unwrap();
    write_manifest(dir, "[\"frames\", \"z\", \"x\"]", extra)
}

/// Writes the manifest of `iq.npy` in `dir`, its axes `axes`, with `extra` tables.
fn write_manifest(dir: &Path, axes: &str, extra: &str) -> PathBuf {
    let manifest = dir.join("images.toml");
    std::fs::write(
        &manifest,
        format!(
            "format = \"pcuvd-images\"\nversion = 1\n[images]\nfile = \"iq.npy\"\n\
             axes = {axes}\nframe_rate_hz = {FRAME_RATE}\n\
             demod_frequency_hz = {DEMOD}\nx_m = [-1.6e-3, 1.55e-3]\nz_m = [5.0e-3, 7.35e-3]\n\
             {extra}"
        ),
    )
    .unwrap();
    manifest
}

/// The vessel's inside, clear of the Doppler kernel's reach past its walls.
fn vessel_inside() -> Vec<(usize, usize)> {
    (VESSEL.0[0] + 2..VESSEL.0[1] - 2)
        .flat_map(|z| (VESSEL.1[0] + 1..VESSEL.1[1] - 1).map(move |x| (z, x)))
        .collect()
}

/// The blood's mean velocity over `frames` frames (m/s): what colour Doppler reads.
fn mean_blood_velocity(frames: usize) -> f64 {
    (0..frames)
        .map(|t| velocity(t as f64 / FRAME_RATE))
        .sum::<f64>()
        / frames as f64
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

#[test]
fn beamformed_images_give_colour_doppler_and_ri_as_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let frames = 400; // two beats
    // The scanner's triggers at the beats' starts, as an ECG would give them.
    let manifest = write_images(
        dir.path(),
        &synthetic_images(frames),
        "[cardiac]\ntriggers_s = [0.0, 0.2]\n",
    );
    let out = dir.path().join("out");
    // 9.8 MB of images (29.5 MB to hold and filter) fit in 32 MB, but not with the dynamics
    // windows' 3.8 MB (77 windows of 20 frames every 5; one angle: 2 maps of 3,072 pixels):
    // without a dynamics setting the run starts them every 10 frames (1.9 MB), and refuses with
    // one; in 30 MB not even side by side (1.0 MB) fit, and the run goes on without them.
    let within = |limit_gb: &str, extra: &[&str]| {
        let mut args = vec![
            "process",
            manifest.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--max-memory-gb",
            limit_gb,
            "--force",
        ];
        args.extend_from_slice(extra);
        pcuvd(&args)
    };
    let (ok, _, stderr) = within("0.032", &[]);
    assert!(
        ok && stderr.contains("note: RI maps from dynamics windows every 10.0 ms"),
        "{stderr}"
    );
    assert!(out.join("ri.npy").exists());
    let (ok, _, stderr) = within("0.030", &[]);
    assert!(ok && stderr.contains("no RI maps"), "{stderr}");
    assert!(!out.join("ri.npy").exists());
    let (ok, _, stderr) = within("0.032", &["--dynamics", "on"]);
    assert!(!ok && stderr.contains("--dynamics off"), "{stderr}");
    // `info` says so before: within that memory, and not where the machine leaves more.
    let warnings = |extra: &[&str]| {
        let mut args = vec!["info", manifest.to_str().unwrap(), "--json"];
        args.extend_from_slice(extra);
        let (ok, stdout, stderr) = pcuvd(&args);
        assert!(ok, "{stderr}");
        let info: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        info["warnings"].to_string()
    };
    assert!(
        warnings(&["--max-memory-gb", "0.030"]).contains("would run without RI maps"),
        "{}",
        warnings(&["--max-memory-gb", "0.030"])
    );
    assert!(
        warnings(&["--max-memory-gb", "0.032"])
            .contains("would make its RI maps from dynamics windows every 10.0 ms"),
        "{}",
        warnings(&["--max-memory-gb", "0.032"])
    );
    assert!(warnings(&["--max-memory-gb", "0.02"]).contains("would refuse"));
    assert!(!warnings(&[]).contains("`pcuvd process` would"));
    let (ok, stdout, stderr) = pcuvd(&[
        "process",
        manifest.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--force",
        "--nifti",
        "--zarr",
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("beamformed images, 1 angle, 400 frames"),
        "{stdout}"
    );
    // fUSI-BIDS sidecars say what images give (their rate, angles and depths) and leave out
    // the probe and transmit fields they do not.
    let sidecar: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("power_doppler.json")).unwrap())
            .unwrap();
    assert_eq!(sidecar["CompoundSamplingFrequency"], FRAME_RATE);
    assert_eq!(sidecar["PlaneWaveAngles"], serde_json::json!([0.0]));
    assert!(sidecar.get("ProbeCentralFrequency").is_none(), "{sidecar}");
    assert!(out.join("power_doppler.nii.gz").is_file() && out.join("ri.nii.gz").is_file());
    // The Zarr store's attributes, likewise, hold what images give.
    let group: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("pcuvd.zarr").join("zarr.json")).unwrap(),
    )
    .unwrap();
    let attributes = &group["attributes"];
    assert_eq!(attributes["compound_sampling_frequency"], FRAME_RATE);
    assert_eq!(attributes["demodulation_frequency"], DEMOD);
    assert!(attributes.get("probe_pitch").is_none(), "{attributes}");
    assert!(out.join("pcuvd.zarr").join("ri").is_dir());
    let map = |name: &str| -> Array2<f64> { read_npy(out.join(name)).unwrap() };
    let (colour, ri, class) = (
        map("color_doppler.npy"),
        map("ri.npy"),
        read_npy::<_, Array2<u8>>(out.join("vessel_class.npy")).unwrap(),
    );
    let (inside, mean_velocity) = (vessel_inside(), mean_blood_velocity(frames));
    let read = median(inside.iter().map(|&p| colour[p]).collect());
    assert!(
        (read - mean_velocity).abs() < 0.03 * mean_velocity,
        "colour Doppler {read} m/s against the mean velocity {mean_velocity} m/s"
    );
    let truth_ri = 1.0 - EDV / PSV;
    let ri_read = median(inside.iter().map(|&p| ri[p]).collect());
    assert!(
        (ri_read - truth_ri).abs() < 0.03,
        "RI {ri_read} against {truth_ri}"
    );
    let arterioles = inside
        .iter()
        .filter(|&&p| class[p] == pcuvd::dynamics::ARTERIOLE)
        .count();
    assert!(
        arterioles as f64 >= 0.95 * inside.len() as f64,
        "{arterioles} of {} inside pixels classed arterioles",
        inside.len()
    );
    // Tissue alone, three rows or more from the vessel: never a vessel.
    let far = class
        .indexed_iter()
        .filter(|((z, _), _)| *z + 3 < VESSEL.0[0] || *z >= VESSEL.0[1] + 3)
        .filter(|(_, c)| **c != 0)
        .count();
    assert_eq!(far, 0, "{far} tissue pixels classed as vessels");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["images"]["frames"], 400);
    let triggers_from = summary["dynamics"]["triggers_from"].as_str().unwrap();
    assert!(triggers_from.contains("[cardiac]"), "{triggers_from}");
    assert_eq!(summary["images"]["frame_rate_hz"], FRAME_RATE);
    assert!(summary.get("probe").is_none() && summary.get("beamforming").is_none());
    assert_eq!(summary["source"]["files"].as_array().unwrap().len(), 2);
    assert!(out.join("report.html").is_file() && out.join("ri.png").is_file());
}

/// Images too long to hold within the memory given are read and processed a segment at a time,
/// here from a file whose frames are its fastest axis (each segment's frames strided through
/// it): the colour Doppler and RI still read the truth, and the segments are recorded.
#[test]
fn images_too_long_to_hold_are_processed_in_segments() {
    let dir = tempfile::tempdir().unwrap();
    let frames = 400;
    let images = synthetic_images(frames);
    // Stored (z, x, frames), as MATLAB-minded tools save them.
    let z_x_frames = images.view().permuted_axes([1, 2, 0]);
    write_npy(dir.path().join("iq.npy"), &z_x_frames.as_standard_layout()).unwrap();
    let manifest = write_manifest(dir.path(), "[\"z\", \"x\", \"frames\"]", "");
    let manifest = manifest.to_str().unwrap();
    let out = dir.path().join("out");
    let out = out.to_str().unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec!["process", manifest, "--out", out, "--heart-rate", "5"];
        args.extend_from_slice(extra);
        pcuvd(&args)
    };
    // Whole, the 9.8 MB of images and the windows' 9.5 MB do not fit in 25 MB; the message
    // says how to hold fewer frames.
    let (ok, _, stderr) = run(&["--max-memory-gb", "0.025"]);
    assert!(!ok && stderr.contains("--segment-frames"), "{stderr}");
    let (ok, _, stderr) = run(&["--max-memory-gb", "0.025", "--segment-frames", "150"]);
    assert!(ok, "{stderr}");
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("out/summary.json")).unwrap(),
    )
    .unwrap();
    let segments = &summary["segments"];
    assert!(segments["count"].as_u64().unwrap() >= 3, "{segments}");
    let colour: Array2<f64> = read_npy(dir.path().join("out/color_doppler.npy")).unwrap();
    let ri: Array2<f64> = read_npy(dir.path().join("out/ri.npy")).unwrap();
    let (inside, mean_velocity) = (vessel_inside(), mean_blood_velocity(frames));
    let read = median(inside.iter().map(|&p| colour[p]).collect());
    assert!(
        (read - mean_velocity).abs() < 0.03 * mean_velocity,
        "colour Doppler {read} m/s against the mean velocity {mean_velocity} m/s"
    );
    let ri_read = median(inside.iter().map(|&p| ri[p]).collect());
    assert!(
        (ri_read - (1.0 - EDV / PSV)).abs() < 0.03,
        "RI {ri_read} against {}",
        1.0 - EDV / PSV
    );
    assert!(
        summary["timings_s"]["read images"].as_f64().is_some(),
        "{}",
        summary["timings_s"]
    );
}

/// `pcuvd info` says how `process` will cut images longer than a segment (512 frames by
/// default): the segments' count and their longest imaged span, as the run's summary records
/// them, the windows' reach past each segment's own frames included.
#[test]
fn info_cuts_the_segments_as_the_run_does() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = write_images(dir.path(), &synthetic_images(1010), "");
    let manifest = manifest.to_str().unwrap();
    let (ok, stdout, stderr) = pcuvd(&["info", manifest, "--json"]);
    assert!(ok, "{stderr}");
    let info: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let out = dir.path().join("out");
    let (ok, _, stderr) = pcuvd(&["process", manifest, "--out", out.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let segments = &summary["segments"];
    let longest = longest_imaged(segments);
    assert_eq!(
        info["processing"]["segments"], segments["count"],
        "{segments}"
    );
    assert_eq!(info["processing"]["segment_frames"], longest, "{segments}");
    // 1,010 frames in 3 segments of 340 frames of their own and the 15 the 20-frame windows
    // every 5 frames reach past them (355), where sharing them evenly in 512 would say 2 of 505.
    assert_eq!((segments["count"].as_u64(), longest), (Some(3), 355));
}

/// The dynamics windows of the whole recording grow with its length, the rest of a segmented run
/// does not: under `--dynamics auto` a run whose windows alone would not fit starts them further
/// apart, up to side by side, and its RI maps still read the truth; where even that does not fit
/// it goes on without the RI maps. Either is said before the run and in summary.json. With a
/// dynamics setting given it is refused, naming the window step, which, longer, brings the RI
/// maps back.
#[test]
fn windows_that_do_not_fit_are_spaced_or_dropped_under_dynamics_auto() {
    let dir = tempfile::tempdir().unwrap();
    let frames = 400;
    let manifest = write_images(dir.path(), &synthetic_images(frames), "");
    let manifest = manifest.to_str().unwrap();
    let out = dir.path().join("out");
    let out_str = out.to_str().unwrap();
    // Three segments of 135 frames are imaged with 15 more (the 20-frame window's overlap), 150
    // frames of 48 × 64 pixels: 3.7 MB as complex64, 11.1 MB to process. The windows of 20
    // frames (20 ms) of one angle hold 2 maps of f64 each: 77 every 5 frames 3.8 MB, 39 every
    // 10 frames 1.9 MB, 20 side by side 1.0 MB. In 13.5 MB the first that fits is every 10
    // frames; in 11.5 MB none does.
    let run = |limit_gb: &str, extra: &[&str]| {
        let mut args = vec![
            "process",
            manifest,
            "--out",
            out_str,
            "--force",
            "--segment-frames",
            "150",
            "--max-memory-gb",
            limit_gb,
        ];
        args.extend_from_slice(extra);
        let (ok, _, stderr) = pcuvd_with_progress(&args);
        (ok, stderr)
    };
    let summary = || -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
    };
    let said_before_the_run = |stderr: &str, start: &str| -> String {
        let note = stderr
            .lines()
            .find(|l| l.starts_with(start))
            .unwrap_or_else(|| panic!("no note starting {start:?}: {stderr}"));
        let first_stage = stderr.find("clutter filter").expect("the stages' progress");
        assert!(stderr.find(note).unwrap() < first_stage, "{stderr}");
        note.to_string()
    };
    let ri_reads_the_truth = || {
        let ri: Array2<f64> = read_npy(out.join("ri.npy")).unwrap();
        let ri_read = median(vessel_inside().iter().map(|&p| ri[p]).collect());
        assert!(
            (ri_read - (1.0 - EDV / PSV)).abs() < 0.05,
            "RI {ri_read} against {}",
            1.0 - EDV / PSV
        );
    };

    // `info` counts the windows the run would hold: whole, the 400 frames' images take 29.5 MB;
    // beside them the windows every 5 frames (3.8 MB) fit in 34 MB, every 10 frames (1.9 MB)
    // in 32 MB, none in 30 MB (side by side, 1.0 MB).
    let windows_in_info = |limit_gb: &str| {
        let (ok, stdout, stderr) =
            pcuvd(&["info", manifest, "--json", "--max-memory-gb", limit_gb]);
        assert!(ok, "{stderr}");
        let info: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        let warnings = info["warnings"].to_string();
        (
            info["processing"]["stage_memory_estimate_bytes"].clone(),
            warnings,
        )
    };
    let map_bytes = 2 * 48 * 64 * 8;
    let (bytes, warnings) = windows_in_info("0.034");
    assert_eq!(bytes, 77 * map_bytes, "{warnings}");
    let (bytes, warnings) = windows_in_info("0.032");
    assert_eq!(bytes, 39 * map_bytes, "{warnings}");
    assert!(warnings.contains("every 10.0 ms"), "{warnings}");
    let (bytes, warnings) = windows_in_info("0.030");
    assert_eq!(bytes, 0, "{warnings}");
    assert!(warnings.contains("without RI maps"), "{warnings}");

    let (ok, stderr) = run("0.0135", &[]);
    assert!(ok, "{stderr}");
    let note = said_before_the_run(&stderr, "note: RI maps from dynamics windows every 10.0 ms");
    assert!(note.contains("rather than 5.0 ms"), "{note}");
    let dynamics = &summary()["dynamics"];
    assert_eq!(dynamics["step_frames"], 10, "{dynamics}");
    assert_eq!(
        dynamics["step_spaced_for_memory"].as_str(),
        Some(note.trim_start_matches("note: ")),
        "{dynamics}"
    );
    let times: ndarray::Array1<f64> = read_npy(out.join("times.npy")).unwrap();
    assert_eq!(times.len(), (frames - 20) / 10 + 1);
    ri_reads_the_truth();
    assert!(summary()["segments"]["count"].as_u64().unwrap() >= 3);

    let (ok, stderr) = run("0.0115", &[]);
    assert!(ok, "{stderr}");
    let note = said_before_the_run(&stderr, "note: no RI maps");
    assert!(
        note.contains("dynamics windows") && note.contains("side by side"),
        "{note}"
    );
    let skipped = summary()["dynamics"]["skipped"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(note.contains(&skipped), "{skipped}");
    assert!(!out.join("ri.npy").exists() && out.join("color_doppler.npy").exists());
    // The same options where the windows fit are not the same run: not skipped as done (the
    // folder holds another run's outputs, which only --force replaces).
    let (ok, _, stderr) = pcuvd(&[
        "process",
        manifest,
        "--out",
        out_str,
        "--segment-frames",
        "150",
    ]);
    assert!(!ok && stderr.contains("--force"), "{stderr}");

    let (ok, stderr) = run("0.0135", &["--heart-rate", "5"]);
    assert!(!ok, "{stderr}");
    assert!(
        stderr.contains("the dynamics windows alone need") && stderr.contains("--dynamics off"),
        "{stderr}"
    );
    let (ok, stderr) = run("0.0135", &["--heart-rate", "5", "--window-step-ms", "25"]);
    assert!(ok, "{stderr}");
    assert!(!stderr.contains("note:"), "{stderr}");
    assert_eq!(summary()["dynamics"].get("step_spaced_for_memory"), None);
    ri_reads_the_truth();
}

/// RI maps a dynamics setting asks for that only the data can refuse (no heart rate given, half
/// a beat recorded: windows spanning 70 ms, past the 67 ms checked before the work, hold no two
/// systolic upstrokes) end the run in an error once its other outputs are written: the maps
/// those of the run without the stage, summary.json and the report saying why. Its re-run ends
/// in the same error without the work.
#[test]
fn ri_maps_the_data_cannot_give_end_the_run_in_an_error_after_its_other_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = write_images(dir.path(), &synthetic_images(100), "");
    let (asked, off) = (dir.path().join("asked"), dir.path().join("off"));
    let run = |out: &Path, dynamics: &[&str]| {
        let mut args = vec![
            "process",
            manifest.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(dynamics);
        pcuvd(&args)
    };
    let asking = ["--dynamics", "on", "--window-ms", "30"];
    let (ok, stdout, stderr) = run(&asked, &asking);
    assert!(!ok, "{stdout}");
    let error = stderr.lines().last().unwrap();
    assert!(
        error.starts_with("error: ")
            && error.contains("the RI maps asked for")
            && error.contains("could not be made")
            && error.contains("systolic upstrokes found")
            && error.contains("written to"),
        "{stderr}"
    );
    assert!(stdout.contains("wrote maps"), "{stdout}");
    let (ok, _, stderr) = run(&off, &["--dynamics", "off"]);
    assert!(ok, "{stderr}");
    for map in ["color_doppler.npy", "power_doppler.npy", "bmode_db.npy"] {
        let kept: Array2<f64> = read_npy(asked.join(map)).unwrap();
        let without: Array2<f64> = read_npy(off.join(map)).unwrap();
        assert_eq!(kept, without, "{map}");
    }
    assert!(asked.join("power_doppler.png").is_file() && !asked.join("ri.npy").exists());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(asked.join("summary.json")).unwrap())
            .unwrap();
    let failed = summary["dynamics"]["failed"].as_str().unwrap();
    assert!(error.contains(failed), "{failed}");
    let report = std::fs::read_to_string(asked.join("report.html")).unwrap();
    assert!(
        report.contains("No RI maps"),
        "the report says nothing of the RI maps"
    );
    let clock = std::time::Instant::now();
    let (ok, stdout, stderr) = run(&asked, &asking);
    assert!(
        !ok && stderr.contains("an earlier run") && stderr.contains(failed),
        "{stdout}{stderr}"
    );
    let written = std::fs::metadata(asked.join("summary.json"))
        .unwrap()
        .modified()
        .unwrap();
    assert!(
        written < std::time::SystemTime::now() - clock.elapsed(),
        "the re-run wrote again"
    );
}

#[test]
fn options_that_form_images_are_refused_for_images_formed_elsewhere() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = write_images(dir.path(), &synthetic_images(40), "");
    let manifest = manifest.to_str().unwrap();
    let out = dir.path().join("out");
    let out = out.to_str().unwrap();
    for (option, said) in [
        (&["--grid=-1,1,5,7,0.05"][..], "--grid"),
        (&["--f-number", "1.5"][..], "--f-number"),
        (&["--sound-speed-m-s", "1500"][..], "acquisition overrides"),
        // 40 frames of 48 × 64 pixels: 0.98 MB as complex64, three times that to process.
        (&["--max-memory-gb", "0.002"][..], "needs about"),
    ] {
        let mut args = vec!["process", manifest, "--out", out, "--dynamics", "off"];
        args.extend_from_slice(option);
        let (ok, _, stderr) = pcuvd(&args);
        assert!(!ok && stderr.contains(said), "{option:?}: {stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    }
    // `info` says what it understood of the images, from the manifest and the file's header.
    let (ok, stdout, stderr) = pcuvd(&["info", manifest, "--json"]);
    assert!(ok, "{stderr}");
    let info: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(info["images"]["frames"], 40);
    assert_eq!(info["images"]["grid_nz_nx"], serde_json::json!([48, 64]));
    // A phase of π per frame at 0°: c·PRF / (4 f).
    let nyquist = info["images"]["nyquist_velocity_m_s"].as_f64().unwrap();
    assert!((nyquist - SOUND_SPEED * FRAME_RATE / (4.0 * DEMOD)).abs() < 1e-12);
    assert_eq!(info["stored_samples"]["dtype"], "complex64");
    // Held whole; beside them, at the defaults, 5 velocity windows (20 frames every 5 of the 40)
    // of 2 maps (one angle: its velocity and power) of 48 × 64 pixels in f64.
    let processing = &info["processing"];
    assert_eq!(processing["segments"], 1);
    assert_eq!(processing["memory_estimate_bytes"], 3 * 40 * 48 * 64 * 8);
    assert_eq!(
        processing["stage_memory_estimate_bytes"],
        5 * 2 * 48 * 64 * 8
    );
    // A bare .npy says what describes it.
    let (ok, _, stderr) = pcuvd(&[
        "process",
        dir.path().join("iq.npy").to_str().unwrap(),
        "--out",
        out,
    ]);
    assert!(!ok && stderr.contains("images manifest"), "{stderr}");
}

/// ConfUSIus's Zarr store of IQ (written by ConfUSIus, `pcuvd-io`'s fixture) is processed as
/// images are: with the estimator ConfUSIus uses (Kasai, one pixel, no clutter filter) pcuvd's
/// colour Doppler is ConfUSIus's own axial velocity of it with the sign turned (ConfUSIus counts
/// a phase that advances, flow toward the probe, as positive; pcuvd flow away from it), on the
/// pixels ConfUSIus places. At the defaults the vessel's flow reads away from the probe (Loupas's
/// axial frequency is meaningless on this speckle, white from pixel to pixel, so its speed is not
/// scored here).
#[test]
fn confusius_iq_gives_confusius_own_velocity() {
    let fixtures =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../pcuvd-io/tests/fixtures/confusius");
    let store = fixtures.join("iq.zarr");
    let expected: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixtures.join("expected.json")).unwrap())
            .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let run = |extra: &[&str]| {
        let mut args = vec![
            "process",
            store.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--force",
            "--dynamics",
            "off",
        ];
        args.extend_from_slice(extra);
        let (ok, _, stderr) = pcuvd(&args);
        assert!(ok, "{stderr}");
    };
    run(&[
        "--doppler-estimator",
        "kasai",
        "--doppler-kernel",
        "1x1",
        "--svd-low",
        "off",
    ]);
    let colour: Array2<f64> = read_npy(out.join("color_doppler.npy")).unwrap();
    let theirs = &expected["confusius_axial_velocity_m_s"];
    for ((iz, ix), &v) in colour.indexed_iter() {
        let confusius = theirs[iz][ix].as_f64().unwrap();
        assert!(
            (v + confusius).abs() < 1e-7,
            "pixel ({iz}, {ix}): pcuvd {v} m/s, ConfUSIus {confusius} m/s"
        );
    }
    let z: ndarray::Array1<f64> = read_npy(out.join("z.npy")).unwrap();
    let depth = expected["depth_mm"].as_array().unwrap();
    assert!(
        z.iter()
            .zip(depth)
            .all(|(z, d)| (z - d.as_f64().unwrap() * 1e-3).abs() < 1e-12)
    );
    run(&[]);
    let colour: Array2<f64> = read_npy(out.join("color_doppler.npy")).unwrap();
    let rows = &expected["vessel_rows"];
    let (first, last) = (
        rows[0].as_u64().unwrap() as usize,
        rows[1].as_u64().unwrap() as usize,
    );
    let blood = expected["blood_velocity_m_s"].as_f64().unwrap();
    let inside: Vec<f64> = (first + 1..last - 1)
        .flat_map(|z| (1..colour.ncols() - 1).map(move |x| (z, x)))
        .map(|p| colour[p])
        .collect();
    let read = median(inside);
    assert!(
        read > 0.5 * blood && read < 1.5 * blood,
        "{read} m/s against {blood} m/s"
    );
    let (ok, stdout, stderr) = pcuvd(&["info", store.to_str().unwrap(), "--json"]);
    assert!(ok, "{stderr}");
    let info: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(info["format"], "ConfUSIus beamformed IQ (Zarr v3)");
    assert_eq!(info["images"]["grid_nz_nx"], serde_json::json!([20, 24]));
}

/// `--sites` on images whose vessel's velocity is known at every frame, processed in segments:
/// each window of the site's spectrogram reads the beat's velocity averaged over its frames, at
/// its centre time, across the segments' seams, and the vector fit's windows beside it.
#[test]
fn a_site_follows_the_beat_across_segments() {
    let dir = tempfile::tempdir().unwrap();
    let frames = 400; // two beats
    let manifest = write_images(dir.path(), &synthetic_images(frames), "");
    let out = dir.path().join("out");
    // The vessel's centre: row 24 (z 6.2 mm) and column 19 (x −0.65 mm) of the 0.05 mm grid.
    let (ok, _, stderr) = pcuvd(&[
        "process",
        manifest.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--heart-rate",
        "5",
        "--segment-frames",
        "150",
        "--sites=-0.65,6.2",
    ]);
    assert!(ok, "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert!(summary["segments"]["count"].as_u64().unwrap() >= 3);
    assert_eq!(summary["sites"][0]["pixel"], serde_json::json!([24, 19]));
    let times: ndarray::Array1<f64> = read_npy(out.join("site_times.npy")).unwrap();
    let mean: Array2<f64> = read_npy(out.join("site_mean_velocity.npy")).unwrap();
    // The dynamics stage's windows: 20 frames every 5, centred 9.5 frames after their start.
    assert_eq!(times.len(), (frames - 20) / 5 + 1);
    for (k, (&t, &read)) in times.iter().zip(mean.row(0)).enumerate() {
        assert!(
            (t - (5 * k) as f64 / FRAME_RATE - 9.5e-3).abs() < 1e-12,
            "{t} s"
        );
        // The blood's mean velocity over the window's 20 frames (its phase steps between them);
        // read within 0.3 mm/s, the tissue's residue and the noise.
        let truth = (5 * k + 1..5 * k + 20)
            .map(|f| velocity(f as f64 / FRAME_RATE))
            .sum::<f64>()
            / 19.0;
        assert!(
            (read - truth).abs() < 0.03 * PSV,
            "window {k} at {t} s: {read} m/s against {truth}"
        );
    }
    // Systole and diastole both seen: the windows span nearly the whole beat's swing.
    let (low, high) = mean
        .row(0)
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    assert!(
        low < EDV + 0.1 * (PSV - EDV) && high > PSV - 0.1 * (PSV - EDV),
        "{low}..{high}"
    );
    assert!(out.join("sites.png").is_file());
}
