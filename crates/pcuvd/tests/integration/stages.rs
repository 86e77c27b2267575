//! Stage tests against analytic truth: Hadamard coding round trip, point-scatterer beamforming.

use ndarray::{Array3, Array4, Axis};
use num_complex::Complex32;
use pcuvd::acquisition::channel::{
    Acquisition, AngleSamples, AngleSamplesView, ChannelData, Samples,
};
use pcuvd::core::geometry::round_trip_delay;
use pcuvd::core::grid::Grid;
use pcuvd::form::beamform::{self, DasParams};
use pcuvd::form::decode::{Decoder, EventAlignment, encode, encode_code};
use pcuvd::form::iq;
use pcuvd::{Coding, Hadamard, Probe, Sequence, TransmitCode};
use proptest::prelude::*;

/// The whole recording decoded by the [`Decoder`] of its sequence, aligned as `alignment` says.
fn decode_aligned(data: &ChannelData, alignment: EventAlignment) -> pcuvd::Result<AngleSamples> {
    Decoder::new(data, alignment)?.decode(&data.samples)
}

/// [`decode_aligned`] with coded events taken as simultaneous.
fn decode(data: &ChannelData) -> pcuvd::Result<AngleSamples> {
    decode_aligned(data, EventAlignment::Simultaneous)
}

/// Band-limited random traces: random tones inside the probe band under a Gaussian envelope.
fn random_traces(
    seed: u64,
    n: usize,
    channels: usize,
    active: usize,
    samples: usize,
) -> Array3<f32> {
    let mut state = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut x = Array3::<f32>::zeros((n, channels, samples));
    for k in 0..n {
        for c in 0..channels {
            let tones: Vec<(f64, f64, f64)> = (0..6)
                .map(|_| (0.1 + 0.25 * next(), next() * std::f64::consts::TAU, next()))
                .collect();
            for t in 0..samples {
                // A Gaussian envelope: smooth, so its spectrum is band-limited to float precision.
                let u = (t as f64 - active as f64 / 2.0) / (active as f64 / 8.0);
                let taper = (-0.5 * u * u).exp();
                let v: f64 = tones
                    .iter()
                    .map(|&(f, p, a)| a * (std::f64::consts::TAU * f * t as f64 + p).cos())
                    .sum();
                x[[k, c, t]] = (v * taper) as f32;
            }
        }
    }
    x
}

fn coded_recording(events: Array3<f32>, n: usize, slot_delay: f64, fs: f64) -> ChannelData {
    let probe = Probe {
        n_elements: events.dim().1,
        ..Probe::l22_14vx()
    };
    ChannelData {
        acquisition: Acquisition {
            probe,
            sequence: Sequence {
                angles: Sequence::evenly_spaced_angles(n, 0.2),
                event_prf: 1e4,
                coding: Coding::Hadamard { slot_delay },
                pulse_cycles: 2.0,
                pulse: None,
            },
            sampling_frequency: fs,
            sound_speed: 1540.0,
            t0: 0.0,
        },
        samples: Samples::Rf(events),
    }
}

fn relative_error(a: &Array3<f32>, b: &Array3<f32>) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den).sqrt()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]
    /// decode(encode(x)) = n·x for a still medium, at integer and fractional slot delays.
    #[test]
    fn decode_inverts_encode(seed in 0u64..1000, order_index in 0usize..5, fractional in proptest::bool::ANY) {
        let n = [1usize, 2, 4, 8, 12][order_index];
        let fs = 65e6;
        let slot_delay = if fractional { 0.77e-6 } else { 1e-6 };
        // The record is long enough to hold every slot's delayed echo, as a real receive window is.
        let record = 600 + ((n - 1) as f64 * slot_delay * fs).ceil() as usize + 50;
        let x = random_traces(seed, n, 3, 600, record);
        let h = Hadamard::new(n).unwrap();
        let events = encode(x.view(), &h, slot_delay * fs).unwrap();
        let decoded = match decode(&coded_recording(events, n, slot_delay, fs)).unwrap() {
            AngleSamples::Rf(d) => d,
            _ => unreachable!(),
        };
        let got = decoded.index_axis(ndarray::Axis(1), 0).to_owned() / n as f32;
        let err = relative_error(&got, &x);
        prop_assert!(err < 1e-4, "n {}, fractional {}: relative error {}", n, fractional, err);
    }
}

/// decode(encode(x)) = g·x for explicit codes, through the recording's own decoding: H_4 with its
/// rows in another order, two of them sign-flipped, and uneven fractional slot starts (g = 4, the
/// Hadamard convention n·x), and a code whose rows are not orthogonal (g = 2, decoded with its
/// inverse).
#[test]
fn explicit_codes_decode_what_they_encode() {
    let fs = 65e6f64;
    let h = Hadamard::new(4).unwrap();
    let (order, signs) = ([3usize, 1, 0, 2], [-1.0, 1.0, 1.0, -1.0]);
    let scrambled = TransmitCode {
        weights: (0..16)
            .map(|j| signs[j / 4] * h.get(order[j / 4], j % 4) as f64)
            .collect(),
        slot_starts: vec![0.4e-6, 1.37e-6, 2.0e-6, 3.81e-6],
    };
    let uneven = TransmitCode {
        weights: vec![1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0],
        slot_starts: vec![0.0, 0.9e-6, 2.3e-6],
    };
    for (code, gain) in [(scrambled, 4.0f32), (uneven, 2.0)] {
        let n = code.order();
        let record = 600 + (4e-6 * fs).ceil() as usize + 50;
        let x = random_traces(7, n, 3, 600, record);
        let events = encode_code(x.view(), &code, fs).unwrap();
        let mut rec = coded_recording(events, n, 1e-6, fs);
        rec.acquisition.sequence.coding = Coding::Matrix(code.clone());
        for alignment in [EventAlignment::Simultaneous, EventAlignment::MidFrame] {
            let AngleSamples::Rf(decoded) = decode_aligned(&rec, alignment).unwrap() else {
                unreachable!()
            };
            let got = decoded.index_axis(ndarray::Axis(1), 0).to_owned() / gain;
            let err = relative_error(&got, &x);
            assert!(err < 1e-4, "order {n}, {alignment:?}: relative error {err}");
        }
    }
}

#[test]
fn conventional_events_are_split_by_angle() {
    let x = Array3::from_shape_fn((6, 2, 5), |(e, c, s)| (e * 100 + c * 10 + s) as f32);
    let mut rec = coded_recording(x, 3, 1e-6, 65e6);
    rec.acquisition.probe.n_elements = 2;
    rec.acquisition.sequence.coding = Coding::Conventional;
    let AngleSamples::Rf(d) = decode(&rec).unwrap() else {
        unreachable!()
    };
    assert_eq!(d.dim(), (3, 2, 2, 5));
    assert_eq!(d[[2, 1, 0, 4]], (5 * 100 + 4) as f32); // angle 2 of frame 1 = event 5
}

/// Decoding only some frames (a block's, the others read only by the alignment) gives those
/// frames of the whole recording's decoding bit for bit: conventional, Hadamard-coded (RF and
/// IQ, whole-sample and fractional slot shifts) and with an explicit code, with and without
/// mid-frame alignment; into the array of an earlier block of the same shape, whose values must
/// all be overwritten; and in the recording's own memory, for the first, a middle and the last
/// frames. A range outside the recording is an error.
#[test]
fn decoding_some_frames_gives_those_frames_of_the_whole() {
    let events = Array3::from_shape_fn((4 * 7, 16, 120), |(e, c, s)| {
        (((e * 31 + c * 7 + s * 13) % 17) as f32 - 8.0) * (1.0 + 0.1 * (s as f32 * 0.3).sin())
    });
    let coded = coded_recording(events.clone(), 4, 0.3e-6, 62.5e6);
    let mut whole_samples = coded.clone();
    whole_samples.acquisition.sequence.coding = Coding::Hadamard {
        slot_delay: 2.0 / 62.5e6,
    };
    let mut conventional = coded.clone();
    conventional.acquisition.sequence.coding = Coding::Conventional;
    let mut iq = coded.clone();
    iq.samples = Samples::Iq {
        data: events.mapv(|v| Complex32::new(v, 0.5 * v - 1.0)),
        demod_frequency: 15.625e6,
    };
    let mut explicit = coded.clone();
    let h = Hadamard::new(4).unwrap();
    explicit.acquisition.sequence.coding = Coding::Matrix(TransmitCode {
        weights: (0..16).map(|j| -h.get(3 - j / 4, j % 4) as f64).collect(),
        slot_starts: vec![0.1e-6, 0.5e-6, 1.2e-6, 1.3e-6],
    });
    for rec in [&coded, &whole_samples, &conventional, &iq, &explicit] {
        for alignment in [EventAlignment::Simultaneous, EventAlignment::MidFrame] {
            let decoder = Decoder::new(rec, alignment).unwrap();
            let whole = decoder.decode(&rec.samples).unwrap();
            for kept in [0..3, 2..5, 4..7] {
                let mut in_place = rec.clone();
                (decoder.decode_in_place(&mut in_place.samples, kept.clone())).unwrap();
                let view = in_place.samples.decoded_frames(4, kept.clone()).unwrap();
                let expected = whole.frames(kept.clone());
                match (view, expected.view()) {
                    (AngleSamplesView::Rf(a), AngleSamplesView::Rf(b)) => assert_eq!(a, b),
                    (
                        AngleSamplesView::Iq { data: a, .. },
                        AngleSamplesView::Iq { data: b, .. },
                    ) => assert_eq!(a, b),
                    _ => panic!("RF in, RF out; IQ in, IQ out"),
                }
                // The events of the other frames are left as read.
                let n_events = rec.samples.dim().0;
                for e in (0..n_events).filter(|e| !kept.contains(&(e / 4))) {
                    match (&in_place.samples, &rec.samples) {
                        (Samples::Rf(a), Samples::Rf(b)) => {
                            assert_eq!(a.index_axis(Axis(0), e), b.index_axis(Axis(0), e))
                        }
                        (Samples::Iq { data: a, .. }, Samples::Iq { data: b, .. }) => {
                            assert_eq!(a.index_axis(Axis(0), e), b.index_axis(Axis(0), e))
                        }
                        _ => unreachable!(),
                    }
                }
            }
            let part = decoder.decode_frames(&rec.samples, 2..5, None).unwrap();
            assert_eq!(part, whole.frames(2..5), "{alignment:?}");
            let earlier = decoder.decode_frames(&rec.samples, 4..7, None).unwrap();
            let reused = decoder.decode_frames(&rec.samples, 2..5, Some(earlier));
            assert_eq!(reused.unwrap(), whole.frames(2..5), "{alignment:?}, reused");
            for outside in [3..3, 5..8] {
                let err = (decoder.decode_frames(&rec.samples, outside.clone(), None)).unwrap_err();
                assert!(err.to_string().contains("frames"), "{err}");
                let mut in_place = rec.samples.clone();
                let err = decoder.decode_in_place(&mut in_place, outside).unwrap_err();
                assert!(err.to_string().contains("frames"), "{err}");
            }
        }
    }
}

/// RF of a point scatterer, synthesised analytically with the shared time-of-flight convention.
fn point_rf(
    probe: &Probe,
    angle: f64,
    point: (f64, f64),
    fs: f64,
    c: f64,
    t0: f64,
    samples: usize,
) -> Array4<f32> {
    let fc = probe.center_frequency;
    let sigma = 1.0 / (std::f64::consts::PI * fc * probe.bandwidth);
    let mut rf = Array4::<f32>::zeros((1, 1, probe.n_elements, samples));
    for (e, &xe) in probe.element_x().iter().enumerate() {
        let tau = round_trip_delay(point.0, point.1, angle, xe, probe.aperture(), c);
        for s in 0..samples {
            let t = t0 + s as f64 / fs - tau;
            let env = (-t * t / (2.0 * sigma * sigma)).exp();
            rf[[0, 0, e, s]] = (env * (std::f64::consts::TAU * fc * t).cos()) as f32;
        }
    }
    rf
}

#[test]
fn point_scatterer_beamforms_to_its_position() {
    let probe = Probe::l22_14vx();
    let (fs, c, t0) = (65e6, 1540.0, 2e-6);
    let lambda = probe.wavelength(c);
    let point = (1.3e-3, 8.2e-3);
    let grid = Grid::new(
        point.0 - 1e-3,
        point.0 + 1e-3,
        point.1 - 1e-3,
        point.1 + 1e-3,
        lambda / 20.0,
    )
    .unwrap();
    for deg in [-15.0f64, -7.5, 0.0, 7.5, 15.0] {
        let angle = deg.to_radians();
        let rf = point_rf(&probe, angle, point, fs, c, t0, 1200);
        let channels = iq::demodulate(
            &AngleSamples::Rf(rf),
            0,
            t0,
            fs,
            probe.center_frequency,
            None,
        )
        .unwrap();
        let image =
            beamform::beamform(&channels, &probe, angle, &grid, &DasParams::new(c)).unwrap();
        let (mut best, mut at) = (0.0f32, (0, 0));
        for ((iz, ix, _), v) in image.indexed_iter() {
            if v.norm() > best {
                best = v.norm();
                at = (iz, ix);
            }
        }
        let (x, z) = (grid.x[at.1], grid.z[at.0]);
        let err = (x - point.0).hypot(z - point.1);
        assert!(
            err < lambda / 4.0,
            "angle {deg}°: peak at ({x:.5}, {z:.5}), error {:.3} λ",
            err / lambda
        );
    }
}

#[test]
fn grid_rejects_nonsense() {
    assert!(Grid::new(0.0, 1e-3, 1e-3, 2e-3, 0.0).is_err());
    assert!(Grid::new(1e-3, 0.0, 1e-3, 2e-3, 1e-4).is_err());
    assert!(Grid::new(0.0, 1e-3, -1e-3, 2e-3, 1e-4).is_err());
    let g = Grid::new(-12.5e-3, 12.5e-3, 10e-3, 35e-3, 0.1e-3).unwrap();
    assert_eq!(g.shape(), (251, 251));
}

#[test]
fn compound_needs_matching_shapes() {
    let a = Array3::<Complex32>::zeros((2, 2, 2));
    let b = Array3::<Complex32>::zeros((2, 3, 2));
    assert!(beamform::compound(&[a.clone(), b]).is_err());
    assert!(beamform::compound(&[]).is_err());
    assert_eq!(
        beamform::compound(&[a.clone(), a]).unwrap().dim(),
        (2, 2, 2)
    );
}

/// Coded events of per-angle echoes that change in slow time as `echo(angle, t, channel, sample)`,
/// each event sampled at its own firing time (event e fires at e / event PRF); slot k fires k
/// samples after slot 0, so its echo arrives k samples later.
fn moving_coded_events<T, E>(n: usize, frames: usize, shape: (usize, usize), echo: E) -> Array3<T>
where
    T: Copy + num_traits::Zero + std::ops::Mul<f32, Output = T> + std::ops::AddAssign,
    E: Fn(usize, f64, usize, usize) -> T,
{
    let h = Hadamard::new(n).unwrap();
    let prf = 1e4;
    Array3::from_shape_fn((n * frames, shape.0, shape.1), |(e, c, s)| {
        let t = e as f64 / prf;
        let mut sum = T::zero();
        for k in 0..n.min(s + 1) {
            sum += echo(k, t, c, s - k) * h.get(e % n, k);
        }
        sum
    })
}

/// Relative L2 error of decoded angles against n × each angle's echo at its frame's mid-event
/// time, over `frames` and the samples that every slot's echo fills.
fn mid_frame_error<T, E>(
    decoded: &Array4<T>,
    n: usize,
    frames: std::ops::Range<usize>,
    echo: E,
) -> f64
where
    T: Copy + Into<Complex32>,
    E: Fn(usize, f64, usize, usize) -> T,
{
    let prf = 1e4;
    let (mut num, mut den) = (0.0, 0.0);
    for ((k, f, c, s), &got) in decoded.indexed_iter() {
        if !frames.contains(&f) || s + n > decoded.dim().3 {
            continue;
        }
        let t = (f as f64 * n as f64 + (n as f64 - 1.0) / 2.0) / prf;
        let want: Complex32 = echo(k, t, c, s).into() * n as f32;
        num += (got.into() - want).norm_sqr() as f64;
        den += want.norm_sqr() as f64;
    }
    (num / den).sqrt()
}

fn decode_both(mut rec: ChannelData) -> (AngleSamples, AngleSamples) {
    let fs = rec.acquisition.sampling_frequency;
    rec.acquisition.sequence.coding = Coding::Hadamard {
        slot_delay: 1.0 / fs,
    };
    rec.acquisition.sequence.event_prf = 1e4;
    let still = decode_aligned(&rec, EventAlignment::Simultaneous).unwrap();
    let aligned = decode_aligned(&rec, EventAlignment::MidFrame).unwrap();
    (still, aligned)
}

/// Moving echoes (a different Doppler tone per angle, up to 0.4 × the frame rate, under a smooth
/// slow-time envelope): the paper's decoding leaks angles into each other; mid-frame alignment
/// recovers each angle's echo at the frame's mid-event time, as the still-medium decoding would.
/// The interpolator is a finite (±12-frame) Kaiser-windowed sinc with side lobes near −60 dB, so
/// tones up to 0.4 × the frame rate come back to about 10⁻³ (measured 5.4·10⁻⁴).
#[test]
fn mid_frame_alignment_undoes_the_leak_of_moving_echoes() {
    let (n, frames) = (8usize, 96usize);
    let frame_rate = 1e4 / n as f64;
    let span = frames as f64 / frame_rate;
    let echo = |k: usize, t: f64, c: usize, s: usize| -> Complex32 {
        let doppler = (k as f64 - 3.5) * 0.11 * frame_rate;
        let u = (t - span / 2.0) / (span / 9.0);
        let amplitude = (-0.5 * u * u).exp() * (1.0 + 0.3 * ((c * 7 + s * 3 + k) % 5) as f64);
        let phase = std::f64::consts::TAU * doppler * t + 0.7 * (c + 2 * s) as f64;
        Complex32::new(
            (amplitude * phase.cos()) as f32,
            (amplitude * phase.sin()) as f32,
        )
    };
    // 37 samples: the aligner's tiles of 16 series, and a partial one.
    let events = moving_coded_events(n, frames, (2, 37), echo);
    let mut rec = coded_recording(Array3::zeros((1, 2, 37)), n, 1.0, 65e6);
    rec.acquisition.probe.n_elements = 2;
    // Demodulated at f_s, so that advancing a slot by whole samples turns no phase.
    rec.samples = Samples::Iq {
        data: events,
        demod_frequency: 65e6,
    };
    let (still, aligned) = decode_both(rec);
    let (AngleSamples::Iq { data: still, .. }, AngleSamples::Iq { data: aligned, .. }) =
        (still, aligned)
    else {
        unreachable!()
    };
    let leak = mid_frame_error(&still, n, 0..frames, echo);
    let err = mid_frame_error(&aligned, n, 0..frames, echo);
    eprintln!("leak {leak}, aligned {err}");
    assert!(
        leak > 0.3,
        "the moving echoes should leak without alignment: {leak}"
    );
    assert!(
        err < 1e-3,
        "aligned decoding error {err} (without alignment {leak})"
    );
}

/// Real RF with an odd number of samples (two real series share one complex lane, and the last
/// travels alone; 71 samples span three tiles of the aligner) and Doppler tones that do not fade
/// at the ends of the recording: away from the first and last few frames the alignment is as
/// good, and a still medium is decoded exactly.
#[test]
fn mid_frame_alignment_of_rf_at_the_recording_ends() {
    let (n, frames) = (4usize, 80usize);
    let frame_rate = 1e4 / n as f64;
    let echo = |k: usize, t: f64, c: usize, s: usize| -> f32 {
        let doppler = (k as f64 + 0.5) * 0.1 * frame_rate;
        let phase = std::f64::consts::TAU * doppler * t + 0.9 * (c + 3 * s + k) as f64;
        (phase.cos() * (1.0 + 0.2 * s as f64)) as f32
    };
    let events = moving_coded_events(n, frames, (3, 71), echo);
    let mut rec = coded_recording(events, n, 1.0, 65e6);
    rec.acquisition.probe.n_elements = 3;
    let (still, aligned) = decode_both(rec.clone());
    let (AngleSamples::Rf(still), AngleSamples::Rf(aligned)) = (still, aligned) else {
        unreachable!()
    };
    let inner = 8..frames - 8;
    let leak = mid_frame_error(&still, n, inner.clone(), echo);
    let err = mid_frame_error(&aligned, n, inner, echo);
    let whole = mid_frame_error(&aligned, n, 0..frames, echo);
    eprintln!("leak {leak}, inner {err}, whole {whole}");
    assert!(
        leak > 0.2,
        "the moving echoes should leak without alignment: {leak}"
    );
    assert!(
        err < 1e-2,
        "aligned decoding error {err} (without alignment {leak})"
    );
    assert!(
        whole < leak / 3.0,
        "aligned error over all frames {whole} vs {leak}"
    );

    // A still medium: every event of a frame sees the same echo, and alignment changes nothing.
    let still_echo = |k: usize, _t: f64, c: usize, s: usize| echo(k, 0.0, c, s);
    rec.samples = Samples::Rf(moving_coded_events(n, frames, (3, 71), still_echo));
    let (_, aligned) = decode_both(rec);
    let AngleSamples::Rf(aligned) = aligned else {
        unreachable!()
    };
    let err = mid_frame_error(&aligned, n, 0..frames, still_echo);
    assert!(err < 1e-5, "still medium, aligned decoding error {err}");
}

/// The memory estimate by hand: 8 events (4 angles × 2 frames) × 16 channels × 100 samples, and a
/// 3 × 5 pixel grid: the input, 12,800 × 4 bytes; one block, here the whole recording, of 2 frames
/// × (the events read, decoded in place: 4 angles × 1,600 samples × 4 bytes + one angle's IQ,
/// 1,600 × 8 bytes); the image series, 15 pixels × 2 frames × 4 angles × 8 bytes, filtered in
/// place; and its compound, a quarter of it.
#[test]
fn memory_estimate_counts_samples_and_image_series() {
    let rec = coded_recording(Array3::zeros((8, 16, 100)), 4, 1e-6, 20e6);
    assert_eq!(rec.n_frames(), 2);
    let grid = Grid::new(0.0, 0.4e-3, 1e-3, 1.2e-3, 0.1e-3).unwrap();
    assert_eq!(grid.shape(), (3, 5));
    assert_eq!(
        pcuvd::pipeline::memory_estimate(&rec, &grid),
        8 * 16 * 100 * 4 + 2 * (4 * 1600 * 4 + 1600 * 8) + 15 * 2 * 4 * 8 + 15 * 2 * 8
    );
}
