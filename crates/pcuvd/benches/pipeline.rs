//! Throughput of the pipeline's heavy stages, in release builds on the machine at hand.
//!
//! DAS: 256 × 256 pixels, 128 channels, 100 frames, full receive aperture (every channel
//! contributes to every pixel, so every counted pixel·channel·frame point is real work).
//! Decoding: a coded RF recording of 8 angles × 100 frames, 128 channels, 1000 samples (65 MHz,
//! 1 µs slots: whole-sample slot shifts, as in the rat setting), with the
//! events taken as simultaneous and aligned to mid-frame (the extra slow-time resampling).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::Array3;
use num_complex::Complex32;
use pcuvd::beamform::{Apodization, DasParams, beamform};
use pcuvd::channel::{Acquisition, ChannelData, Samples};
use pcuvd::clutter::{ClutterParams, RankCut, svd_filter};
use pcuvd::decode::{EventAlignment, decode_aligned};
use pcuvd::grid::Grid;
use pcuvd::iq::IqChannels;
use pcuvd::{Coding, Probe, Sequence};

fn das_input(probe: &Probe, frames: usize) -> IqChannels {
    let samples = 1500;
    let data = Array3::from_shape_fn((probe.n_elements, samples, frames), |(c, s, f)| {
        Complex32::from_polar(1.0, (c * 7 + s * 3 + f) as f32 * 0.1)
    });
    IqChannels {
        data,
        sampling_frequency: 65e6,
        t0: 0.0,
        demod_frequency: probe.center_frequency,
    }
}

fn das(c: &mut Criterion) {
    let probe = Probe::l22_14vx();
    let frames = 100;
    let iq = das_input(&probe, frames);
    let step = 12.8e-3 / 256.0;
    let grid = Grid::new(
        -6.4e-3,
        -6.4e-3 + 255.0 * step,
        2e-3,
        2e-3 + 255.0 * step,
        step,
    )
    .unwrap();
    assert_eq!(grid.shape(), (256, 256));
    let params = DasParams {
        f_number: 1e-3,
        apodization: Apodization::Boxcar,
        sound_speed: 1540.0,
    };
    let points = (256 * 256 * probe.n_elements * frames) as u64;
    let mut group = c.benchmark_group("das");
    group.sample_size(10);
    group.throughput(Throughput::Elements(points));
    group.bench_function("256x256px_128ch_100fr", |b| {
        b.iter(|| beamform(&iq, &probe, 0.1, &grid, &params).unwrap())
    });
    group.finish();
}

fn clutter(c: &mut Criterion) {
    let series = Array3::from_shape_fn((256, 256, 100), |(z, x, f)| {
        Complex32::from_polar(1.0 + (z % 7) as f32, (x * 3 + f * (z % 5)) as f32 * 0.2)
    });
    let params = ClutterParams {
        low: RankCut::Fixed(5),
        high: RankCut::Off,
        tissue_frequency: 0.02,
    };
    let mut group = c.benchmark_group("clutter");
    group.sample_size(10);
    group.bench_function("svd_256x256px_100fr", |b| {
        b.iter_batched(
            || series.clone(),
            |mut s| svd_filter(&mut s, &params).unwrap(),
            criterion::BatchSize::LargeInput,
        )
    });
    group.finish();
}

fn decode(c: &mut Criterion) {
    let (n, frames, samples) = (8usize, 100usize, 1000usize);
    let probe = Probe::l22_14vx();
    let events = Array3::from_shape_fn((n * frames, probe.n_elements, samples), |(e, c, s)| {
        ((e * 13 + c * 7 + s * 3) as f32 * 0.1).sin()
    });
    let data = ChannelData {
        acquisition: Acquisition {
            probe,
            sequence: Sequence {
                angles: Sequence::evenly_spaced_angles(n, 15f64.to_radians()),
                event_prf: 14.4e3,
                coding: Coding::Hadamard { slot_delay: 1e-6 },
                pulse_cycles: 2.0,
                pulse: None,
            },
            sampling_frequency: 65e6,
            sound_speed: 1540.0,
            t0: 0.0,
        },
        samples: Samples::Rf(events),
    };
    let mut group = c.benchmark_group("decode");
    group.sample_size(10);
    group.throughput(Throughput::Elements((n * frames * samples * 128) as u64));
    for (name, alignment) in [
        (
            "simultaneous_8x100fr_128ch_1000s",
            EventAlignment::Simultaneous,
        ),
        ("mid_frame_8x100fr_128ch_1000s", EventAlignment::MidFrame),
    ] {
        group.bench_function(name, |b| {
            b.iter(|| decode_aligned(&data, alignment).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, das, clutter, decode);
criterion_main!(benches);
