//! Every reader against files written by the format's own, independent writer
//! (`tests/fixtures/readers/make_reader_fixtures.py`: numpy, hdf5storage, pyuff-ustb, zea, scipy,
//! PyMUST; `make_urx_fixtures.py`: ultrasound-rawdata-exchange, Moduleus' URX): the real rotating disk (its first 8 transmits) in each format gives the samples and
//! the maps of the original `.mat`; a steered recording simulated by pcuvd gives back its angles,
//! PRF and t0; reading a block of frames at a time gives the frames read whole, bit for bit.

use std::path::{Path, PathBuf};

use pcuvd::acquisition::source::FrameSource;
use pcuvd::core::grid::Grid;
use pcuvd::form::decode::{Decoder, EventAlignment};
use pcuvd::pipeline::blocks::Blocks;
use pcuvd::pipeline::{self, ProcessOutput};
use pcuvd::{AngleSamples, ChannelData, Coding, Samples};
use pcuvd_io::{OpenedRecording, Overrides, ParamSource, open_recording};
use serde_json::Value;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/readers")
        .join(name)
}

fn expected() -> Value {
    serde_json::from_str(&std::fs::read_to_string(fixture("expected.json")).unwrap()).unwrap()
}

fn disk_mat() -> PathBuf {
    pcuvd_testing::disk_recording()
}

fn open(name: &str) -> OpenedRecording {
    open_recording(&fixture(name), &Overrides::default()).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// The first `events` transmits of the original disk recording.
fn disk_reference(events: usize) -> ChannelData {
    let whole = open_recording(&disk_mat(), &Overrides::default()).unwrap();
    whole.source.read_frames(0..events).unwrap()
}

fn quiet(_: pipeline::Stage, _: usize, _: usize) {}

fn maps(source: &dyn FrameSource, grid: &Grid) -> ProcessOutput {
    maps_aligned(source, grid, EventAlignment::MidFrame)
}

fn maps_aligned(source: &dyn FrameSource, grid: &Grid, alignment: EventAlignment) -> ProcessOutput {
    let mut params = pcuvd::study::process_params(grid, source.acquisition(), (1, 1), alignment);
    // The f-number the 1e-5 agreement of two decoding paths below was set at: they round
    // differently in f32, and the default F# 1.0 sums more elements per pixel (the decoded zea
    // track's Vz then differs by 1.2e-5 of its peak).
    params.das.f_number = 1.5;
    let blocks = Blocks::whole(source.n_frames());
    let (images, _) = pipeline::form_images_in_blocks(source, &params, blocks, &quiet).unwrap();
    pipeline::analyse(images, &params, &quiet).unwrap()
}

/// Asserts that the error message `message` names every one of `wanted`.
fn assert_mentions(message: &str, wanted: &[&str]) {
    for want in wanted {
        assert!(message.contains(want), "{message} (wanted {want})");
    }
}

/// Largest |a − b| over the largest |b|.
fn relative(a: &ndarray::Array2<f64>, b: &ndarray::Array2<f64>) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let diff = a
        .iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    diff / scale
}

/// The fixture `name` read from its track (zea) or recorded group (URX) `track`.
fn open_track(name: &str, track: &str) -> Result<OpenedRecording, pcuvd_io::IoError> {
    let overrides = Overrides {
        track: Some(track.into()),
        ..Overrides::default()
    };
    open_recording(&fixture(name), &overrides)
}

/// The first event's RF records (channels × samples), as a (1, channels, samples) array.
fn first_event_rf(data: &ChannelData) -> ndarray::Array3<f32> {
    let Samples::Rf(rf) = &data.samples else {
        panic!("RF expected")
    };
    rf.slice(ndarray::s![0..1, .., ..]).to_owned()
}

/// Frames read in blocks of `block` equal the frames read whole, bit for bit.
fn assert_blocks_match_whole(name: &str, source: &dyn FrameSource, block: usize) {
    let n = source.n_frames();
    let whole = source.read_frames(0..n).unwrap();
    let mut start = 0;
    while start < n {
        let end = (start + block).min(n);
        let part = source.read_frames(start..end).unwrap();
        let k = source.acquisition().sequence.n_angles();
        match (&part.samples, &whole.samples) {
            (Samples::Rf(p), Samples::Rf(w)) => assert_eq!(
                p,
                &w.slice(ndarray::s![start * k..end * k, .., ..]),
                "{name}: frames {start}..{end}"
            ),
            (Samples::Iq { data: p, .. }, Samples::Iq { data: w, .. }) => assert_eq!(
                p,
                &w.slice(ndarray::s![start * k..end * k, .., ..]),
                "{name}: frames {start}..{end}"
            ),
            _ => panic!("{name}: RF and IQ mixed"),
        }
        start = end;
    }
}

const DISK_FILES: [(&str, &str); 8] = [
    ("disk.npz", "PyMUST-style NumPy .npz"),
    (
        "disk_npz.toml",
        "pcuvd recording manifest (.toml) + NumPy .npz (RF)",
    ),
    ("disk_v73.mat", "MUST/PyMUST MATLAB v7.3 (HDF5 .mat)"),
    ("disk.uff", "USTB UFF channel data (HDF5)"),
    (
        "disk_uff.toml",
        "pcuvd recording manifest (.toml) + HDF5 dataset (/channel_data/data)",
    ),
    ("disk_zea.hdf5", "zea / OpenH-RF (HDF5)"),
    ("disk_verasonics.mat", "Verasonics workspace (MATLAB v7.3)"),
    (
        "disk.urx",
        "URX (Moduleus ultrasound raw data exchange, HDF5)",
    ),
];

/// Fixtures whose format records no bandwidth (URX):
/// `a_file_without_a_bandwidth_reads_with_the_band_its_sampling_holds` checks the band they read.
const NO_BANDWIDTH: [&str; 3] = [
    "disk_no_bandwidth.uff",
    "disk_no_bandwidth_zea.hdf5",
    "disk.urx",
];

#[test]
fn every_format_of_the_disk_gives_the_samples_of_the_mat() {
    let events = expected()["disk"]["transmits"].as_u64().unwrap() as usize;
    let reference = disk_reference(events);
    for (name, format) in DISK_FILES {
        let opened = open(name);
        assert_eq!(opened.info.format, format, "{name}");
        let data = opened.read_all().unwrap();
        let (a, b) = (&data.acquisition, &reference.acquisition);
        assert_eq!(a.sequence.angles, b.sequence.angles, "{name}");
        assert_eq!(a.probe.n_elements, b.probe.n_elements, "{name}");
        // Parameters pass through float32 in zea and through MHz/wavelengths in Verasonics.
        let close = |x: f64, y: f64, what: &str| {
            assert!((x - y).abs() <= 1e-6 * y.abs(), "{name}: {what} {x} vs {y}")
        };
        close(a.sampling_frequency, b.sampling_frequency, "f_s");
        close(a.sound_speed, b.sound_speed, "c");
        close(a.t0, b.t0, "t0");
        close(a.sequence.event_prf, b.sequence.event_prf, "PRF");
        close(a.probe.pitch, b.probe.pitch, "pitch");
        close(a.probe.center_frequency, b.probe.center_frequency, "f_c");
        if !NO_BANDWIDTH.contains(&name) {
            close(a.probe.bandwidth, b.probe.bandwidth, "bandwidth");
        }
        close(
            a.probe.element_width,
            b.probe.element_width,
            "element width",
        );
        assert_eq!(data.samples, reference.samples, "{name}: samples");
        assert_blocks_match_whole(name, opened.source.as_ref(), 3);
    }
}

#[test]
fn every_format_of_the_disk_gives_the_maps_of_the_mat() {
    let events = expected()["disk"]["transmits"].as_u64().unwrap() as usize;
    let reference = disk_reference(events);
    let grid = Grid::new(-10e-3, 10e-3, 12e-3, 32e-3, 0.2e-3).unwrap();
    for (name, _) in DISK_FILES {
        let opened = open(name);
        // zea stores f_s, t0 and c as float32 (its schema): the reference takes the parameters
        // as the file holds them (the samples test checks them against the .mat to 1e-6), so
        // that what is compared is the samples and how the reader lays them out.
        let mut same = reference.clone();
        same.acquisition = opened.source.acquisition().clone();
        let want = maps(&same, &grid);
        let got = maps(opened.source.as_ref(), &grid);
        let power = relative(&got.maps.power_doppler, &want.maps.power_doppler);
        let color = relative(&got.maps.color_doppler, &want.maps.color_doppler);
        assert!(
            power <= 1e-5 && color <= 1e-5,
            "{name}: power {power:e}, colour {color:e}"
        );
    }
}

/// UFF and zea may leave the bandwidth out, and URX has none. pcuvd's 67 % would fold at the disk's 6.67 MHz
/// sampling (it was refused); the reader takes the widest band centred on f_c that one Nyquist
/// zone holds, says so, and the recording gives the maps of the `.mat` (the bandwidth only decides
/// whether the sampling folds). `--bandwidth` states the probe's; a stated band that folds is
/// still refused.
#[test]
fn a_file_without_a_bandwidth_reads_with_the_band_its_sampling_holds() {
    let events = expected()["disk"]["transmits"].as_u64().unwrap() as usize;
    let reference = disk_reference(events);
    let grid = Grid::new(-10e-3, 10e-3, 12e-3, 32e-3, 0.2e-3).unwrap();
    for name in NO_BANDWIDTH {
        let opened = open(name);
        let acq = opened.source.acquisition().clone();
        let (fc, fs) = (acq.probe.center_frequency, acq.sampling_frequency);
        // f_c = 5 MHz lies in the zone [f_s/2, f_s] = [3.33, 6.67] MHz, 1.67 MHz from either edge.
        let widest = 2.0 * (fc - fs / 2.0).min(fs - fc) / fc;
        assert!(
            (acq.probe.bandwidth - widest).abs() < 1e-6 && widest < 0.67,
            "{name}: {} vs {widest}",
            acq.probe.bandwidth
        );
        let param = opened.info.parameter("bandwidth").unwrap();
        assert!(
            matches!(&param.source, ParamSource::Default { note } if note.contains("widest band")
                && note.contains("--bandwidth")),
            "{name}: {:?}",
            param.source
        );
        let mut same = reference.clone();
        same.acquisition = acq.clone();
        same.acquisition.probe.bandwidth = reference.acquisition.probe.bandwidth;
        let want = maps(&same, &grid);
        let got = maps(opened.source.as_ref(), &grid);
        let power = relative(&got.maps.power_doppler, &want.maps.power_doppler);
        let color = relative(&got.maps.color_doppler, &want.maps.color_doppler);
        assert!(
            power <= 1e-5 && color <= 1e-5,
            "{name}: power {power:e}, colour {color:e}"
        );

        let stated = |bandwidth: f64| {
            let overrides = Overrides {
                bandwidth: Some(bandwidth),
                ..Overrides::default()
            };
            open_recording(&fixture(name), &overrides).unwrap()
        };
        let given = stated(0.15);
        assert_eq!(given.source.acquisition().probe.bandwidth, 0.15, "{name}");
        let param = given.info.parameter("bandwidth");
        assert_eq!(param.unwrap().source, ParamSource::Override, "{name}");
        let folds = stated(0.9).read_all().unwrap_err().to_string();
        assert!(folds.contains("folds the RF band"), "{name}: {folds}");
    }
}

/// A zea file of several tracks (OpenH-RF stores sequences so), written by zea itself: the first
/// track with raw data unless `--track` names another by index or label; the choice, and every
/// track with its label and frames, are said; a track that is not there is refused naming them.
#[test]
fn a_zea_track_is_chosen_by_index_or_label() {
    let name = "disk_two_tracks_zea.hdf5";
    let default = open(name);
    assert_eq!(default.source.n_frames(), 4);
    let listed = "track_0 \"first4\" (4 frames), track_1 \"disk\" (8 frames)";
    assert!(
        default.info.warnings.iter().any(|w| w.contains(listed)),
        "{:?}",
        default.info.warnings
    );
    let with = |track: &str| open_track(name, track);
    let events = expected()["disk"]["transmits"].as_u64().unwrap() as usize;
    let reference = disk_reference(events);
    let grid = Grid::new(-10e-3, 10e-3, 12e-3, 32e-3, 0.2e-3).unwrap();
    for track in ["1", "disk"] {
        let opened = with(track).unwrap();
        assert_eq!(opened.source.n_frames(), 8, "{track}");
        let param = opened.info.parameter("track");
        assert_eq!(param.unwrap().value, "track_1");
        assert_eq!(param.unwrap().source, ParamSource::Override);
        assert!(opened.info.warnings.iter().all(|w| !w.contains("first of")));
        let mut same = reference.clone();
        same.acquisition = opened.source.acquisition().clone();
        let want = maps(&same, &grid);
        let got = maps(opened.source.as_ref(), &grid);
        let power = relative(&got.maps.power_doppler, &want.maps.power_doppler);
        assert!(power <= 1e-5, "{track}: power {power:e}");
    }
    let missing = with("7").unwrap_err().to_string();
    assert!(
        missing.contains("--track") && missing.contains(listed),
        "{missing}"
    );
    let overrides = Overrides {
        track: Some("1".into()),
        ..Overrides::default()
    };
    for single in ["disk.uff", "disk.npz"] {
        let refused = open_recording(&fixture(single), &overrides).unwrap_err();
        assert!(
            refused.to_string().contains("not tracks to choose from"),
            "{single}: {refused}"
        );
    }
}

/// A Hadamard-coded recording stored decoded by zea (decoded with NumPy, the code's polarity kept
/// in `tx_apodizations`, a frame's angles at one time) reads as what it is: coded when fired,
/// not decoded again, the coded sequence's frame rate; its records, polarity turned back, are
/// pcuvd's own decoding of the coded events (the paper's eq. 2, events taken as simultaneous), to
/// the bit, and so are its maps.
#[test]
fn a_decoded_hadamard_zea_track_is_the_coded_recording_decoded() {
    let want = &expected()["decoded_hadamard"];
    let frames = want["frames"].as_u64().unwrap() as usize;
    let polarity: Vec<f64> = serde_json::from_value(want["polarity"].clone()).unwrap();
    let name = "decoded_hadamard_zea.hdf5";
    let overrides = Overrides {
        track: Some("hadamard-decoded".into()),
        ..Overrides::default()
    };
    let decoded = open_recording(&fixture(name), &overrides).unwrap();
    let coded = open("coded_hadamard.toml");
    let (got, fired) = (decoded.source.acquisition(), coded.source.acquisition());
    assert_eq!(
        got.sequence.coding,
        Coding::Decoded {
            polarity: polarity.clone()
        }
    );
    assert!(got.sequence.is_coded() && !got.sequence.decodes_events());
    assert!(polarity.contains(&-1.0), "the fixture must invert an angle");
    assert_eq!(decoded.source.n_frames(), frames);
    // zea stores its scan in float32: the rates to its rounding.
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * b.abs();
    assert!(
        close(got.frame_rate(), fired.frame_rate()),
        "{} Hz",
        got.frame_rate()
    );
    assert!(close(got.nyquist_velocity(), fired.nyquist_velocity()));
    for (a, b) in got.sequence.angles.iter().zip(&fired.sequence.angles) {
        assert!((a - b).abs() < 1e-6, "{a} against {b}");
    }
    assert_eq!(decoded.info.parameter("coding").unwrap().value, "decoded");

    // The samples: the file's records, polarity turned back, against pcuvd decoding the events.
    let stored = decoded.source.read_frames(0..frames).unwrap();
    let events = coded.source.read_frames(0..frames).unwrap();
    let records = |data: &ChannelData, alignment| match Decoder::new(data, alignment)
        .unwrap()
        .decode(&data.samples)
        .unwrap()
    {
        AngleSamples::Rf(a) => a,
        AngleSamples::Iq { .. } => panic!("RF expected"),
    };
    let ours = records(&events, EventAlignment::Simultaneous);
    let theirs = records(&stored, EventAlignment::MidFrame);
    assert_eq!(ours.dim(), theirs.dim());
    assert!(ours.iter().any(|&v| v != 0.0));
    assert_eq!(
        ours, theirs,
        "the decoded records differ from pcuvd's decoding"
    );
    // The polarity was there to turn back: angle 1 is stored negated.
    let Samples::Rf(raw) = &stored.samples else {
        panic!("RF expected")
    };
    let first = ours.slice(ndarray::s![1, 0, .., ..]);
    assert_eq!(raw.slice(ndarray::s![1, .., ..]), first.mapv(|v| -v));

    // The maps: those of the coded recording decoded by pcuvd.
    let grid = Grid::new(-4e-3, 4e-3, 9e-3, 15e-3, 0.2e-3).unwrap();
    let reference = maps_aligned(coded.source.as_ref(), &grid, EventAlignment::Simultaneous);
    let read = maps(decoded.source.as_ref(), &grid);
    let (vectors, want_vectors) = (
        read.maps.vector_irls.as_ref().unwrap(),
        reference.maps.vector_irls.as_ref().unwrap(),
    );
    for (what, a, b) in [
        (
            "power",
            &read.maps.power_doppler,
            &reference.maps.power_doppler,
        ),
        (
            "colour",
            &read.maps.color_doppler,
            &reference.maps.color_doppler,
        ),
        ("vx", &vectors.vx, &want_vectors.vx),
        ("vz", &vectors.vz, &want_vectors.vz),
    ] {
        let error = relative(a, b);
        assert!(error <= 1e-5, "{what}: {error:e}");
    }

    // Without --track the B-mode track is read, conventional, and the file's tracks are named.
    let default = open(name);
    assert_eq!(
        default.source.acquisition().sequence.coding,
        Coding::Conventional
    );
    let listed = "track_0 \"bmode\" (4 frames), track_1 \"hadamard-decoded\" (12 frames)";
    assert!(
        default.info.warnings.iter().any(|w| w.contains(listed)),
        "{:?}",
        default.info.warnings
    );
}

#[test]
fn steered_recordings_give_back_their_angles_prf_and_t0() {
    let e = &expected()["steered"];
    let angles: Vec<f64> = e["angles_rad"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let prf = e["event_prf_hz"].as_f64().unwrap();
    let t0 = e["t0_s"].as_f64().unwrap();
    let frames = e["frames"].as_u64().unwrap() as usize;
    let grid = Grid::new(-4e-3, 4e-3, 8e-3, 16e-3, 0.1e-3).unwrap();
    let mut rf_maps: Vec<(String, ProcessOutput)> = Vec::new();
    for name in [
        "steered_must.mat",
        "steered.uff",
        "steered_zea.hdf5",
        "steered.urx",
        "steered_verasonics.mat",
        "steered_must_iq.mat",
        "steered_iq.uff",
        "steered_iq.urx",
        "steered_verasonics_bs100.mat",
        "steered_verasonics_bs50.mat",
    ] {
        let opened = open(name);
        let acq = opened.source.acquisition().clone();
        // MUST's txdelay and zea's float32 angles: within a millidegree.
        for (a, b) in acq.sequence.angles.iter().zip(&angles) {
            assert!(
                (a - b).abs() < 2e-5,
                "{name}: angles {:?}",
                acq.sequence.angles
            );
        }
        assert_eq!(acq.sequence.n_angles(), 3, "{name}");
        assert!(
            (acq.sequence.event_prf - prf).abs() < 1e-3,
            "{name}: PRF {}",
            acq.sequence.event_prf
        );
        assert!((acq.t0 - t0).abs() < 1e-12, "{name}: t0 {}", acq.t0);
        assert_eq!(opened.source.n_frames(), frames, "{name}");
        assert_blocks_match_whole(name, opened.source.as_ref(), 4);
        let out = maps(opened.source.as_ref(), &grid);
        if opened.info.parameter("demod_frequency_hz").is_some() {
            // IQ from PyMUST's rf2iq (its own filter, decimated by 4) or Verasonics' I/Q pairs
            // against pcuvd's own demodulation of the same RF: the same flow where there is
            // signal.
            let (_, rf) = &rf_maps[0];
            let scale = rf.maps.power_doppler.iter().fold(0.0f64, |m, v| m.max(*v));
            let mut diffs: Vec<f64> = out
                .maps
                .color_doppler
                .iter()
                .zip(&rf.maps.color_doppler)
                .zip(&rf.maps.power_doppler)
                .filter(|(_, p)| **p > 0.1 * scale)
                .map(|((a, b), _)| (a - b).abs())
                .collect();
            diffs.sort_by(f64::total_cmp);
            let median = diffs[diffs.len() / 2];
            assert!(
                median < 0.02 * rf.maps.nyquist_velocity,
                "{name}: colour Doppler differs from the RF's by {median} m/s (median)"
            );
        } else {
            rf_maps.push((name.to_string(), out));
        }
    }
    let (first, reference) = &rf_maps[0];
    let must = open(first).read_all().unwrap();
    for (name, out) in &rf_maps[1..] {
        // As for the disk: the reference takes the file's own (float32 in zea) parameters.
        let mut same = must.clone();
        same.acquisition = open(name).source.acquisition().clone();
        let reference = &maps(&same, &grid);
        let power = relative(&out.maps.power_doppler, &reference.maps.power_doppler);
        let color = relative(&out.maps.color_doppler, &reference.maps.color_doppler);
        assert!(
            power <= 1e-5 && color <= 1e-5,
            "{name} vs {first}: {power:e} {color:e}"
        );
    }
    // The disk turns: its colour Doppler changes sign across its centre (x = 0).
    let out = reference;
    let col = |x: f64| ((x - out.grid.x[0]) / 0.1e-3).round() as usize;
    let row = ((12e-3 - out.grid.z[0]) / 0.1e-3).round() as usize;
    let left = out.maps.color_doppler[[row, col(-1.5e-3)]];
    let right = out.maps.color_doppler[[row, col(1.5e-3)]];
    assert!(left * right < 0.0, "no rotation seen: {left} {right}");
}

/// Verasonics' interleaved modes (BS100BW, BS50BW) keep of the RF sampled at 4 f_c the first two
/// samples of every 4 or 8, a quarter period apart: read, each pair is the RF that pcuvd
/// demodulates itself (the same steered recording stored as NS200BW) at the pair's instant, to
/// within what reading a quarter-period pair as one instant costs a pulse of 60 % bandwidth.
/// The comparison is of complex values, so it holds the absolute phase (the rotation by
/// e^{−2πi f_d t0}, a quarter turn off here, would miss by √2 of the signal) as well as the
/// sign of Q (a wrong one conjugates every sample).
///
/// Measured: relative RMS difference 0.169 (BS100BW) and 0.164 (BS50BW) over the samples above
/// a tenth of the largest; without the rotation 1.42, with Q's sign flipped 1.39.
#[test]
fn verasonics_interleaved_pairs_are_the_rf_demodulated_at_their_instants() {
    let rf = open("steered_verasonics.mat");
    let acq = rf.source.acquisition().clone();
    let frames = rf.source.n_frames();
    let whole = rf.source.read_frames(0..frames).unwrap();
    let angles = Decoder::new(&whole, EventAlignment::MidFrame)
        .unwrap()
        .decode(&whole.samples)
        .unwrap();
    let n_angles = acq.sequence.n_angles();
    let fc = acq.probe.center_frequency;
    // (channels, samples, frames) of each angle, at the RF's 20 MHz.
    let demodulated: Vec<_> = (0..n_angles)
        .map(|a| {
            pcuvd::form::iq::demodulate(&angles, a, acq.t0, acq.sampling_frequency, fc, None)
                .unwrap()
                .data
        })
        .collect();
    for (name, every) in [
        ("steered_verasonics_bs100.mat", 4usize),
        ("steered_verasonics_bs50.mat", 8),
    ] {
        let pairs = open(name);
        let got = pairs.source.acquisition();
        assert_eq!(got.t0, acq.t0, "{name}");
        assert_eq!(
            got.sampling_frequency,
            acq.sampling_frequency / every as f64,
            "{name}"
        );
        assert_eq!(pairs.source.n_frames(), frames, "{name}");
        assert_blocks_match_whole(name, pairs.source.as_ref(), 4);
        let data = pairs.source.read_frames(0..frames).unwrap();
        let Samples::Iq {
            data: iq,
            demod_frequency,
        } = &data.samples
        else {
            panic!("{name}: IQ expected")
        };
        assert_eq!(*demod_frequency, fc, "{name}");
        let (events, channels, samples) = iq.dim();
        assert_eq!(events, frames * n_angles, "{name}");
        let reference =
            |e: usize, c: usize, k: usize| demodulated[e % n_angles][[c, k * every, e / n_angles]];
        let peak = (0..events)
            .flat_map(|e| (0..channels).flat_map(move |c| (0..samples).map(move |k| (e, c, k))))
            .map(|(e, c, k)| reference(e, c, k).norm())
            .fold(0.0f32, f32::max);
        let (mut diff, mut norm) = (0.0f64, 0.0f64);
        for e in 0..events {
            for c in 0..channels {
                for k in 0..samples {
                    let want = reference(e, c, k);
                    if want.norm() > 0.1 * peak {
                        diff += f64::from((iq[[e, c, k]] - want).norm_sqr());
                        norm += f64::from(want.norm_sqr());
                    }
                }
            }
        }
        let error = (diff / norm).sqrt();
        assert!(error < 0.25, "{name}: relative RMS difference {error:.3}");
    }
}

/// Verasonics workspaces written by hdf5storage that pcuvd refuses, each naming the field and
/// what it found: BS100BW pairs whose demodFrequency agrees with neither reading of
/// decimSampleRate / quadDecim (the stored samples' rate, the A/D's), the NS200BWI mode, whose
/// RF is two acquisitions interleaved, a channel map with two elements on one channel (a
/// multiplexed probe's named as such), and acquisitions accumulated (Receive.mode 1) into the
/// same rows.
#[test]
fn verasonics_sample_modes_pcuvd_cannot_read_say_why() {
    let refused = |name: &str| match open_recording(&fixture(name), &Overrides::default()) {
        Ok(_) => panic!("{name} was read"),
        Err(e) => e.to_string(),
    };
    assert_mentions(
        &refused("refused/verasonics_bs100_other_demod.mat"),
        &[
            "Receive.decimSampleRate",
            "quadDecim is 10.000000 MHz",
            "BS100BW at a demodFrequency of 4.000000 MHz",
        ],
    );
    assert_mentions(
        &refused("refused/verasonics_ns200bwi.mat"),
        &["Receive(1).sampleMode", "NS200BWI", "BS100BW"],
    );
    let two = refused("refused/verasonics_two_elements_one_channel.mat");
    assert_mentions(&two, &["Trans.Connector", "two elements on channel 2"]);
    assert!(!two.contains("HVMux"), "{two}");
    assert_mentions(
        &refused("refused/verasonics_hvmux.mat"),
        &[
            "Trans.Connector",
            "two elements on channel 1",
            "Trans.HVMux",
            "aperture",
        ],
    );
    assert_mentions(
        &refused("refused/verasonics_accumulated.mat"),
        &["Receive(2).startSample", "Receive(1)", "Receive.mode 1"],
    );
}

/// A Verasonics buffer holds the system's channels, and element e's samples lie in the column
/// `Trans.ConnectorES(e)` names, else `Trans.Connector(e)`: the steered recording's first frame
/// stored on 64 channels, its elements on channels 64, 62, ..., 2, reads back sample for sample
/// as the same frame stored one column per element, with either field (the ConnectorES file
/// also holds an identity `Connector`, which it takes precedence over). That file also gives
/// each angle a `TW` of its own (`TX.waveform`), peaking 1.5, 2.5 and 1.5 wavelengths after the
/// firing, each acquisition's window opening half that much deeper (round trip): each
/// waveform's peak delays its echoes by that many periods, so its t0 is the plain file's (and
/// with one TW's peak taken for all, the acquisitions' t0 would disagree).
#[test]
fn verasonics_elements_are_read_from_their_channels() {
    let plain = open("steered_verasonics.mat");
    let frame = plain.source.read_frames(0..1).unwrap();
    for (name, field) in [
        ("steered_verasonics_connector.mat", "Trans.Connector"),
        ("steered_verasonics_connector_es.mat", "Trans.ConnectorES"),
    ] {
        let mapped = open(name);
        assert_eq!(mapped.source.n_frames(), 1, "{name}");
        assert_eq!(
            mapped.source.trace_shape(),
            plain.source.trace_shape(),
            "{name}"
        );
        assert!(
            mapped
                .info
                .reader
                .ends_with(&format!("element channels by {field})")),
            "{}",
            mapped.info.reader
        );
        assert!(
            !mapped.info.warnings.iter().any(|w| w.contains("Connector")),
            "{name}: {:?}",
            mapped.info.warnings
        );
        let t0 = (
            mapped.source.acquisition().t0,
            plain.source.acquisition().t0,
        );
        assert!((t0.0 - t0.1).abs() < 1e-12, "{name}: t0 {t0:?}");
        let got = mapped.source.read_frames(0..1).unwrap();
        match (&got.samples, &frame.samples) {
            (Samples::Rf(a), Samples::Rf(b)) => {
                assert!(b.iter().any(|&v| v != 0.0));
                assert_eq!(a, b, "{name}");
            }
            _ => panic!("{name}: RF expected"),
        }
    }
    // Without a map the buffer's columns are the elements, and the user is told so.
    assert!(
        plain
            .info
            .warnings
            .iter()
            .any(|w| w.contains("Trans.Connector is absent"))
    );
}

/// A Verasonics buffer is read in runs of frames that share a compressed chunk (hdf5storage
/// chunks these fixtures two buffer frames deep), cut where the circular buffer wraps: blocks of
/// every size, one frame at a time included, starting on and off the chunks' edges, read the
/// same samples as the whole recording does. The 5-frame buffer (newest frame the third) has a
/// run that its chunk would carry past the buffer's last slot, and reads as the 6-frame file's
/// first five frames.
#[test]
fn verasonics_blocks_of_any_size_read_the_same_samples() {
    for name in [
        "steered_verasonics.mat",
        "steered_verasonics_bs100.mat",
        "steered_verasonics_5frames.mat",
    ] {
        let opened = open(name);
        for block in 1..=opened.source.n_frames() {
            assert_blocks_match_whole(name, opened.source.as_ref(), block);
        }
    }
    let five = open("steered_verasonics_5frames.mat")
        .source
        .read_frames(0..5)
        .unwrap();
    let six = open("steered_verasonics.mat")
        .source
        .read_frames(0..5)
        .unwrap();
    match (&five.samples, &six.samples) {
        (Samples::Rf(a), Samples::Rf(b)) => assert_eq!(a, b),
        _ => panic!("RF expected"),
    }
}

/// A channel that a Verasonics Receive's `Apod` leaves out is not written by that acquisition:
/// it holds stale samples. The steered recording's first frame, its second acquisition's
/// elements 1–8 left out and their rows filled with a constant, reads as the plain frame with
/// those eight traces zero (and the others untouched), and `info` says so.
#[test]
fn verasonics_elements_a_receive_leaves_out_read_as_zero() {
    let plain = open("steered_verasonics.mat");
    let Samples::Rf(mut want) = plain.source.read_frames(0..1).unwrap().samples else {
        panic!("RF expected")
    };
    want.slice_mut(ndarray::s![1, 0..8, ..]).fill(0.0);
    let apod = open("steered_verasonics_apod.mat");
    let Samples::Rf(got) = apod.source.read_frames(0..1).unwrap().samples else {
        panic!("RF expected")
    };
    assert!(got.slice(ndarray::s![1, 8.., ..]).iter().any(|&v| v != 0.0));
    assert_eq!(got, want);
    assert!(
        apod.info
            .warnings
            .iter()
            .any(|w| w.contains("Receive.Apod") && w.contains("1 of the frame's 3")),
        "{:?}",
        apod.info.warnings
    );
}

#[test]
fn parameters_say_where_they_came_from() {
    let opened = open("disk.uff");
    let find = |n: &str| {
        opened
            .info
            .parameter(n)
            .unwrap_or_else(|| panic!("no {n}"))
            .clone()
    };
    assert_eq!(
        find("sampling_frequency_hz").source,
        ParamSource::File {
            field: "channel_data/sampling_frequency".into()
        }
    );
    assert!(matches!(find("t0_s").source, ParamSource::Derived { .. }));
    assert!(matches!(
        find("pulse_cycles").source,
        ParamSource::Default { .. }
    ));
    let overridden = open_recording(
        &fixture("disk.uff"),
        &Overrides {
            t0_s: Some(1e-6),
            ..Overrides::default()
        },
    )
    .unwrap();
    assert_eq!(overridden.source.acquisition().t0, 1e-6);
    let t0 = overridden.info.parameter("t0_s").unwrap();
    assert_eq!(t0.source, ParamSource::Override);
    // zea: the PRF is per transmit.
    let zea = open("steered_zea.hdf5");
    let prf = zea.info.parameter("event_prf_hz").unwrap();
    assert!(
        prf.source.to_string().contains("time_to_next_transmit"),
        "{}",
        prf.source
    );
}

/// URX files written by the format's own writer that pcuvd refuses, each naming the field and
/// what it reads instead; a file without wave time zeros asks for `--t0-s` and reads with it, and
/// one of a single transmit asks for `--event-prf-hz`.
#[test]
fn urx_files_pcuvd_cannot_read_say_why() {
    let refused = |name: &str| match open_recording(&fixture(name), &Overrides::default()) {
        Ok(_) => panic!("{name} was read"),
        Err(e) => e.to_string(),
    };
    let e = refused("urx_converging.urx");
    assert_mentions(
        &e,
        &[
            "sequence/00000001/transmit_setup/wave/type",
            "plane-wave",
            "PLANE_WAVE",
        ],
    );
    let e = refused("urx_reversed_channels.urx");
    assert_mentions(
        &e,
        &["receive_setup/active_elements", "channel k to element k"],
    );
    let e = refused("urx_no_time_zero.urx");
    assert_mentions(&e, &["wave/time_zero", "--t0-s"]);
    let given = open_recording(
        &fixture("urx_no_time_zero.urx"),
        &Overrides {
            t0_s: Some(5e-6),
            ..Overrides::default()
        },
    )
    .unwrap();
    assert_eq!(given.source.acquisition().t0, 5e-6);
    assert_eq!(
        given.info.parameter("t0_s").unwrap().source,
        ParamSource::Override
    );
    // One transmit in all: no interval between events gives the event rate.
    let e = refused("urx_one_event.urx");
    assert_mentions(
        &e,
        &[
            "event_timestamps",
            "holds 1 event time(s)",
            "--event-prf-hz",
        ],
    );
}

/// A URX file of two recorded groups (one compound B-mode frame, then the two-angle Doppler
/// group): the first unless `--track` names another by index or description, the groups listed
/// in a warning; a group that is not there is refused naming them. Both groups begin with the
/// same frame, so the Doppler group's first event is compared with the B-mode group's. The
/// B-mode group's single sequence takes its event rate from its events' spacing.
#[test]
fn a_urx_group_is_chosen_by_index_or_description() {
    let name = "urx_two_groups.urx";
    let listed = "0 (\"bmode\"), 1 (\"doppler\")";
    let default = open(name);
    assert_eq!(default.source.n_frames(), 1);
    // atan2 of the stored direction (sin θ, cos θ): θ to the last bit or two.
    let two_angles = |angles: &[f64]| {
        angles.len() == 2 && (angles[0] + 0.1).abs() < 1e-15 && (angles[1] - 0.1).abs() < 1e-15
    };
    let angles = &default.source.acquisition().sequence.angles;
    assert!(two_angles(angles), "{angles:?}");
    assert!((default.source.acquisition().sequence.event_prf - 4000.0).abs() < 1e-6);
    let prf = default.info.parameter("event_prf_hz").unwrap();
    assert!(
        format!("{:?}", prf.source).contains("one sequence"),
        "{:?}",
        prf.source
    );
    assert!(
        default.info.warnings.iter().any(|w| w.contains(listed)),
        "{:?}",
        default.info.warnings
    );
    let with = |track: &str| open_track(name, track);
    let bmode = default.source.read_frames(0..1).unwrap();
    for track in ["1", "doppler"] {
        let opened = with(track).unwrap();
        let acq = opened.source.acquisition();
        assert_eq!(opened.source.n_frames(), 2, "{track}");
        assert!(
            two_angles(&acq.sequence.angles),
            "{track}: {:?}",
            acq.sequence.angles
        );
        assert!((acq.sequence.event_prf - 4000.0).abs() < 1e-6, "{track}");
        assert!((acq.t0 - 5e-6).abs() < 1e-12, "{track}: t0 {}", acq.t0);
        assert!(
            opened.info.warnings.is_empty(),
            "{:?}",
            opened.info.warnings
        );
        let param = opened.info.parameter("track").unwrap();
        assert_eq!(param.value, 1, "{track}");
        assert_eq!(param.source, ParamSource::Override, "{track}");
        let doppler = opened.source.read_frames(0..2).unwrap();
        assert_eq!(
            doppler.samples.dim(),
            (4, 4, 8),
            "{track}: events, channels, samples"
        );
        assert_eq!(first_event_rf(&doppler), first_event_rf(&bmode), "{track}");
    }
    let missing = match with("2") {
        Ok(_) => panic!("group 2 was read"),
        Err(e) => e.to_string(),
    };
    assert!(
        missing.contains("--track") && missing.contains(listed),
        "{missing}"
    );
}

#[test]
fn a_must_file_without_t0_is_an_error_that_says_how_to_give_it() {
    let dir = tempfile::tempdir().unwrap();
    let mut file = pcuvd_io::read_mat(&fixture("steered_must.mat")).unwrap();
    if let Some(pcuvd_io::MatValue::Struct(p)) = file.variables.get_mut("param") {
        p.remove("t0");
    }
    let path = dir.path().join("no_t0.mat");
    let vars: Vec<(&str, &pcuvd_io::MatValue)> = file
        .variables
        .iter()
        .map(|(k, v)| (k.as_str(), v))
        .collect();
    pcuvd_io::write_mat(&path, &vars, true).unwrap();
    let e = open_recording(&path, &Overrides::default())
        .unwrap_err()
        .to_string();
    assert_mentions(&e, &["param.t0", "is absent", "0.77 mm per µs", "--t0-s"]);
    let given = open_recording(
        &path,
        &Overrides {
            t0_s: Some(9.75e-6),
            ..Overrides::default()
        },
    )
    .unwrap();
    assert_eq!(given.source.acquisition().t0, 9.75e-6);
}

#[test]
fn unrecognised_files_say_what_they_look_like() {
    let dir = tempfile::tempdir().unwrap();
    let check = |bytes: &[u8], name: &str, want: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let e = open_recording(&path, &Overrides::default())
            .unwrap_err()
            .to_string();
        assert!(e.starts_with(&path.display().to_string()), "{e}");
        assert!(e.contains(want), "{e} (wanted {want})");
    };
    check(b"", "empty.mat", "it is empty");
    check(
        b"\x00\x01\x02\x03garbage",
        "x.bin",
        "binary starting with bytes 00 01 02 03",
    );
    check(
        b"hello world\n",
        "notes.txt",
        "text starting \"hello world\"",
    );
    check(
        b"\x93NUMPY\x01\x00",
        "bare.npy",
        "Write a pcuvd recording manifest",
    );
    let e = open_recording(dir.path(), &Overrides::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("is a folder, not a file"), "{e}");
    // An archive that is not PyMUST-style asks for a manifest.
    let e = open_recording(&fixture("disk.npz"), &Overrides::default()).map(|_| ());
    assert!(e.is_ok());
}

/// Every reader applies every acquisition override the user gives, and records it as given:
/// each fixture opened again with its own values given back as overrides (so that nothing else
/// changes) names each of them as the user's. An override the recording has no use for (a
/// demodulation frequency for RF samples) and a value no recording can have are refused,
/// naming the option, not the file's field.
#[test]
fn every_reader_applies_every_override_or_refuses_it() {
    let fixtures = [
        "disk.npz",
        "disk.uff",
        "disk.urx",
        "disk_v73.mat",
        "disk_verasonics.mat",
        "disk_zea.hdf5",
        "disk_uff.toml",
        "steered_must_iq.mat",
        "steered_iq.uff",
        "steered_iq.urx",
        "steered_verasonics_bs100.mat",
        "coded_hadamard.toml",
    ];
    for name in fixtures {
        let plain = open(name);
        let value = |p: &str| {
            plain
                .info
                .parameter(p)
                .and_then(|p| p.value.as_f64())
                .unwrap_or_else(|| panic!("{name}: no number {p}"))
        };
        let iq = plain.info.parameter("demod_frequency_hz").is_some();
        let overrides = Overrides {
            t0_s: Some(value("t0_s")),
            sound_speed_m_s: Some(value("sound_speed_m_s")),
            event_prf_hz: Some(value("event_prf_hz")),
            sampling_freq_hz: Some(value("sampling_frequency_hz")),
            center_freq_hz: Some(value("center_frequency_hz")),
            demod_freq_hz: iq.then(|| value("demod_frequency_hz")),
            pulse_cycles: Some(value("pulse_cycles")),
            bandwidth: Some(value("bandwidth")),
            ..Overrides::default()
        };
        let given =
            open_recording(&fixture(name), &overrides).unwrap_or_else(|e| panic!("{name}: {e}"));
        for p in &plain.info.parameters {
            let again = given.info.parameter(&p.name).unwrap();
            assert_eq!(again.value, p.value, "{name}: {}", p.name);
        }
        let mut overridden: Vec<&str> = given
            .info
            .parameters
            .iter()
            .filter(|p| p.source == ParamSource::Override)
            .map(|p| p.name.as_str())
            .collect();
        overridden.sort_unstable();
        let mut want = vec![
            "bandwidth",
            "center_frequency_hz",
            "event_prf_hz",
            "pulse_cycles",
            "sampling_frequency_hz",
            "sound_speed_m_s",
            "t0_s",
        ];
        if iq {
            want.push("demod_frequency_hz");
            want.sort_unstable();
        }
        assert_eq!(overridden, want, "{name}");
        if !iq {
            let rf = Overrides {
                demod_freq_hz: Some(5e6),
                ..Overrides::default()
            };
            let refused = open_recording(&fixture(name), &rf).unwrap_err().to_string();
            assert_mentions(&refused, &["--demod-freq-hz", "RF samples", "not used"]);
        }
    }
    let zero = Overrides {
        sound_speed_m_s: Some(0.0),
        ..Overrides::default()
    };
    let refused = open_recording(&fixture("disk.npz"), &zero)
        .unwrap_err()
        .to_string();
    assert_mentions(
        &refused,
        &["--sound-speed-m-s", "sound_speed_m_s=", "> 0, got 0"],
    );
    let nan = Overrides {
        t0_s: Some(f64::NAN),
        ..Overrides::default()
    };
    let refused = open_recording(&fixture("disk.uff"), &nan)
        .unwrap_err()
        .to_string();
    assert_mentions(&refused, &["--t0-s", "finite"]);
}
