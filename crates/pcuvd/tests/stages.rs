//! Stage tests against analytic truth: Hadamard coding round trip, point-scatterer beamforming.

use ndarray::{Array3, Array4};
use num_complex::Complex32;
use pcuvd::beamform::{self, DasParams, Grid};
use pcuvd::channel::{Acquisition, AngleSamples, ChannelData, Samples};
use pcuvd::decode::{decode, encode};
use pcuvd::geometry::round_trip_delay;
use pcuvd::{Coding, Hadamard, Probe, Sequence, iq};
use proptest::prelude::*;

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
